"""Where a newcomer slips on the command line (issue 35): positional joint values after the
options, angles typed in degrees without --deg, and what `dq-derive robots` says ships."""

import json
import re
import sysconfig
from pathlib import Path

import numpy as np
import pytest

import derive
from derive import reference
from derive.cache import generated_root, read_manifest
from derive.codegen.loader import near_class_nominal
from derive.cli import main
from derive.errors import DeriveError
from derive.model.robot import list_robots, load_robot

ROOT = Path(__file__).resolve().parents[1]


def _ur5_urdf() -> Path:
    path = (Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "share" / "example-robot-data"
            / "robots" / "ur_description" / "urdf" / "ur5_robot.urdf")
    if not path.is_file():
        pytest.fail("example-robot-data is not installed: `pip install -e '.[test]'` installs it")
    return path


def _json(capsys, argv):
    assert main(argv) == 0
    captured = capsys.readouterr()
    return json.loads(captured.out), captured.err


# --------------------------------------------------------------------------- #
# Positional joint values (deprecated) work before and after the options
# --------------------------------------------------------------------------- #
def test_positional_joint_values_after_the_options_of_a_urdf(capsys):
    urdf = str(_ur5_urdf())
    q = [0.1, -0.7, 0.9, -0.4, 0.6, 0.3]
    robot = load_robot(urdf, base="base_link", tip="tool0")
    expected = reference.fk_matrix(robot, q)                 # the independent 4x4 product
    texts = [str(v) for v in q]
    for argv in (["fk", urdf, "--base", "base_link", "--tip", "tool0", *texts, "--json", "--matrix"],
                 ["fk", urdf, *texts, "--base", "base_link", "--tip", "tool0", "--json", "--matrix"],
                 ["fk", urdf, "--base", "base_link", "--tip", "tool0", "--q", *texts, "--json", "--matrix"]):
        data, err = _json(capsys, argv)
        assert err == ""
        assert np.allclose(data["matrix"], expected, atol=1e-12)
        assert data["q"] == q


def test_positional_joint_values_after_deg_and_both_forms_refused(capsys):
    data, _ = _json(capsys, ["fk", "ur5", "--deg", "10", "-60", "80", "-20", "45", "30", "--json"])
    ref = reference.fk(load_robot("ur5"), np.radians([10, -60, 80, -20, 45, 30]))
    assert np.allclose(data["dual_quaternion"], ref, atol=1e-12)
    assert main(["fk", "ur5", "1", "2", "3", "4", "5", "6", "--q", "0", "0", "0", "0", "0", "0"]) == 2
    assert "give the joint values once" in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:                  # an unknown option is still a usage error
        main(["fk", "ur5", "--bogus", "0", "0", "0", "0", "0", "0"])
    assert info.value.code == 2
    assert "unrecognized arguments: --bogus" in capsys.readouterr().err


# --------------------------------------------------------------------------- #
# An angle beyond 2 pi without --deg: a warning that names the option and suggests --deg
# --------------------------------------------------------------------------- #
SLIPS = [   # (argv typed in degrees without --deg, the option the warning names)
    (["ik", "ur5", "--xyz", "0.4", "0.1", "0.3", "--rpy", "180", "0", "0", "--json"], "--rpy"),
    (["fk", "ur5", "--q", "10", "-60", "80", "-20", "45", "30", "--json"], "--q"),
    (["fk", "ur5", "10", "-60", "80", "-20", "45", "30", "--json"], "joint values"),
    (["ik", "ur5", "--q", "0.1", "-1", "1.2", "-0.5", "1.1", "0.3", "--seed", "0", "-90", "90", "0", "0", "0",
      "--json"], "--seed"),
    (["ik", "panda", "--q", "0.1", "-0.5", "0.2", "-2", "0.3", "1.5", "0.4", "--free", "23", "--json"], "--free"),
    (["refine", "ur5-calibrated", "--xyz", "0.4", "0.1", "0.3", "--rpy", "180", "0", "0", "--json"], "--rpy"),
]


@pytest.mark.parametrize("argv, option", SLIPS, ids=[f"{a[0]}-{o}" for a, o in SLIPS])
def test_an_angle_beyond_two_pi_without_deg_warns(argv, option, capsys):
    main(argv)                                               # solutions or none: the exit code is not the point
    err = capsys.readouterr().err
    warnings = [line for line in err.splitlines() if "warning" in line]
    assert len(warnings) == 1, err
    assert warnings[0].startswith(f"dq-derive: warning: {option}: ") and "--deg" in warnings[0]
    assert "2 pi" in warnings[0]


@pytest.mark.parametrize("argv, option", SLIPS[:5], ids=[f"{a[0]}-{o}" for a, o in SLIPS[:5]])
def test_no_warning_with_deg(argv, option, capsys):
    main(argv + ["--deg"])
    assert "warning" not in capsys.readouterr().err


def test_no_warning_for_small_angles_or_metres(capsys):
    for argv in (["ik", "ur5", "--xyz", "0.4", "0.1", "0.3", "--rpy", "3.14159", "0", "-6.28", "--json"],
                 ["fk", "ur5", "--q", "6.28", "-6.28", "1", "0", "0", "0", "--json"],
                 # seed-arm: joints 1 and 3 are prismatic (m), 12 m is no angle
                 ["fk", "seed-arm", "--q", "12", "0.5", "-12", "1", "2", "--json"]):
        main(argv)
        assert "warning" not in capsys.readouterr().err, argv
    main(["fk", "seed-arm", "--q", "12", "7", "-12", "1", "2", "--json"])       # joint 2 is revolute
    assert "warning: --q: 7 is beyond 2 pi" in capsys.readouterr().err


# --------------------------------------------------------------------------- #
# dq-derive robots and Getting started say what ships, as the loader and generated/ find it
# --------------------------------------------------------------------------- #
def _shipped() -> dict:
    """{robot name: manifest} of the library robots whose folder in generated/ is of their
    identity and holds the C source (read from the folders, not from a list)."""
    out = {}
    for m in sorted((generated_root() or ROOT / "generated").glob("*/manifest.json")):
        data = read_manifest(m.parent)
        name = data.get("robot")
        if name in list_robots() and data.get("id") == load_robot(name).id \
                and (m.parent / data.get("files", {}).get("c_source", "-")).is_file():
            out[name] = data
    return out


def _has_ik(robot) -> bool:
    """Whether the numpy reference solves the robot's IK (a seven-joint arm with its free
    parameter given): the reference's own dispatch, not the table's. Every route it has (a special
    class, a near-class polish, the general 6R elimination) has generated kernels."""
    pose = reference.fk(robot, np.full(robot.dof, 0.3))
    # a seven-joint arm: its class's free parameter, or joint 3 given for a near-class SRS arm (the
    # other seven-joint arms with a joint given have numpy kernels only: the table says FK)
    calls = ([{"free": 0.3}] + ([{"free": 0.3, "free_name": "q3"}] if reference._near(robot) else [])
             if robot.dof == 7 else [{}])
    for kw in calls:
        try:
            reference.ik(robot, pose, **kw)
            return True
        except DeriveError:
            pass
    return False


def test_robots_table_says_what_ships(capsys):
    data, _ = _json(capsys, ["robots", "--json"])
    rows = {r["name"]: r for r in data["robots"]}
    shipped = _shipped()
    assert set(rows) == set(list_robots())
    assert {"ur5", "irb120", "panda", "iiwa14"} <= set(shipped)      # the folder scan sees them
    for name, row in rows.items():
        robot = load_robot(name)
        assert row["kernels"].endswith(", shipped") == (name in shipped), name
        if name in shipped:
            k = derive.kernels(name, "python")                     # the shipped module, as the loader reads it
            assert Path(k.folder).resolve() == (generated_root() / Path(k.folder).name).resolve()
            assert row["kernels"].startswith("FK+IK") == k.has_ik, name
            free = shipped[name].get("free")
            assert (f"({free} free)" in row["kernels"]) == (free is not None), name
            roles = shipped[name]["files"]
            assert row["casadi"].endswith(", shipped") == ("casadi/fk" in roles), name
            assert (", ik," in row["casadi"]) == ("casadi/ik" in roles), name
        else:
            # a near-class 6R arm (ur5-calibrated): its kernels run the nominal's closed form and
            # the polish, the loader finds the nominal itself; another 6R arm's the general 6R
            assert row["kernels"].startswith("FK+IK") == _has_ik(robot), name
            if reference._near(robot) and robot.dof == 6:
                assert near_class_nominal(robot) is not None, name
            assert not row["kernels"].endswith("shipped") and not row["casadi"].endswith("shipped"), name


def test_getting_started_names_the_robots_that_ship():
    text = (ROOT / "docs" / "getting-started.md").read_text(encoding="utf-8")
    [para] = [p for p in text.split("\n\n") if "ship in the repository's `generated/` folder" in p]
    named = set(re.findall(r"`([a-z0-9-]+)`", para)) & set(list_robots())
    assert named == set(_shipped())
