"""Robot identity by content, the artifact load path, decimal angles and output folders
(issue: "Robot identity by content, artifacts loaded in milliseconds, and the package in layers")."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import sympy as sp
import yaml

import derive
from derive import DeriveError, reference
from derive.algebra.angles import wrap_angle
from derive.cache import clear_memory, user_folder
from derive.cli import main
from derive.model.exact import op_form as exact_form

LIBRARY = Path(derive.__file__).resolve().parent / "robots"
GENERATED = Path(derive.__file__).resolve().parent.parent / "generated"


def _ur5(**changes) -> dict:
    data = yaml.safe_load((LIBRARY / "ur5.yaml").read_text())
    data["parameters"].update(changes.pop("parameters", {}))
    data.update(changes)
    return data


def _write(path: Path, data: dict) -> Path:
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _decimal_alphas(data: dict, value: float) -> dict:
    for j in data["joints"]:
        if str(j["alpha"]) in ("pi/2", "-pi/2"):
            j["alpha"] = -value if str(j["alpha"]).startswith("-") else value
    return data


def _same_pose(a, b):
    """Largest difference of two batches of unit dual quaternions, sign of each row aligned."""
    s = np.where(np.sum(a[:, :4] * b[:, :4], axis=1) < 0, -1.0, 1.0)[:, None]
    return float(np.max(np.abs(a * s - b)))


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """An empty user cache for this test; in-memory results forgotten before and after."""
    folder = tmp_path / "cache"
    monkeypatch.setenv("DQ_DERIVE_CACHE", str(folder))
    loaded = ("kernels", "casadi-functions", "code-digest")
    clear_memory(loaded)
    yield folder
    clear_memory(loaded)


# --------------------------------------------------------------------------- #
# Identity
# --------------------------------------------------------------------------- #
def test_identity_ignores_name_and_path_but_not_numbers(tmp_path):
    ur5 = derive.load_robot("ur5")
    copy = derive.load_robot(_write(tmp_path / "arm.yaml", _ur5(name="my-arm", title="Mine")))
    assert copy.name == "my-arm" and copy.id == ur5.id
    moved = derive.load_robot(_write(tmp_path / "d1.yaml", _ur5(parameters={"d1": 0.5})))
    assert moved.name == "ur5" and moved.id != ur5.id
    limits = _ur5()
    limits["joints"][0]["limits"] = ["-pi", "pi"]
    # the limits are not part of the identity (they have their own key part, limits_id)
    edited = derive.load_robot(_write(tmp_path / "lim.yaml", limits))
    assert edited.id == ur5.id and edited.limits_id != ur5.limits_id
    assert np.array_equal(edited.limits[0], [-np.pi, np.pi])
    # the same arm in millimetres and degrees: the numbers after units are the same
    mm = _ur5(name="ur5-mm", units={"length": "mm", "angle": "deg"},
              parameters={k: v * 1000 for k, v in _ur5()["parameters"].items()})
    for j in mm["joints"]:
        j["alpha"] = {"pi/2": 90, "-pi/2": -90, 0: 0}[j["alpha"]]
        j["limits"] = [-360, 360]
    assert derive.load_robot(_write(tmp_path / "mm.yaml", mm)).id == ur5.id
    # every library robot has its own identity, but the FR3 is the Panda with other limits
    robots = [derive.load_robot(n) for n in derive.list_robots()]
    assert len({r.id for r in robots}) == len(robots) - 1
    fr3, panda = derive.load_robot("fr3"), derive.load_robot("panda")
    assert fr3.id == panda.id and fr3.limits_id != panda.limits_id
    assert len({(r.id, r.limits_id) for r in robots}) == len(robots)


def test_identity_does_not_depend_on_the_order_of_the_end_frames(tmp_path):
    """The end frames' names do not enter the identity, and neither does their order: the CRX's
    file dumped with sorted keys (yaml.safe_dump: fanuc_flange before flange) or with its end frames
    reversed, and the seed arm's three end frames in every order, keep the library robot's identity,
    so the shipped decision of the general 6R (derive/data/general6r.json) and the caches find
    them. Another default end, or an end frame moved, is another identity."""
    from derive.ik import general6r
    crx = derive.load_robot("crx10ia")
    data = yaml.safe_load(Path(crx.path).read_text())
    dumped = tmp_path / "crx-sorted.yaml"
    dumped.write_text(yaml.safe_dump(data))                     # sorted keys
    sorted_crx = derive.load_robot(dumped)
    assert list(sorted_crx.ends) == ["fanuc_flange", "flange"] and sorted_crx.default_end == "flange"
    assert sorted_crx.id == crx.id
    assert crx.id in general6r.shipped_decisions()
    assert general6r.status(sorted_crx) == "kernels"
    # the same FK at the default end (the artifacts are made for it)
    q = np.random.default_rng(2).uniform(-3, 3, (5, 6))
    assert _same_pose(reference.fk(sorted_crx, q), reference.fk(crx, q)) < 1e-15
    rev = dict(data, ends=dict(reversed(list(data["ends"].items()))))
    assert derive.load_robot(_write(tmp_path / "crx-rev.yaml", rev)).id == crx.id
    # another default end: another robot
    other = dict(data, default_end="fanuc_flange")
    assert derive.load_robot(_write(tmp_path / "crx-other.yaml", other)).id != crx.id
    # an end frame moved: another robot
    moved = yaml.safe_load(Path(crx.path).read_text())
    moved["ends"]["fanuc_flange"]["origin"][0]["translation"] = ["l_6", 0, 0.001]
    assert derive.load_robot(_write(tmp_path / "crx-moved.yaml", moved)).id != crx.id
    seed = derive.load_robot("seed-arm")
    sdata = yaml.safe_load(Path(seed.path).read_text())
    names = list(sdata["ends"])
    ids = set()
    for k, perm in enumerate([[0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]]):
        d = dict(sdata, ends={names[i]: sdata["ends"][names[i]] for i in perm})
        r = derive.load_robot(_write(tmp_path / f"seed{k}.yaml", d))
        assert list(r.ends) == [names[i] for i in perm]
        ids.add(r.id)
    assert ids == {seed.id}


def test_a_file_robot_pickles_with_its_exact_values(tmp_path):
    """A robot read from a file crosses to another process (Dask workers of reach / place) by
    pickle: the copy has the same identity, the same numbers and the same exact values."""
    import pickle

    from derive.model import exact
    path = _write(tmp_path / "arm.yaml", _ur5(name="pickled"))
    robot = derive.load_robot(path)
    copy = pickle.loads(pickle.dumps(robot))
    assert copy.id == robot.id
    for a, b in zip(robot.joints, copy.joints):
        for op_a, op_b in zip(a.pre + a.post, b.pre + b.post):
            assert exact.op_form(op_a) == exact.op_form(op_b)
    q = np.linspace(-1, 1, 6)
    assert np.array_equal(derive.reference.fk(copy, q), derive.reference.fk(robot, q))


def test_an_edited_file_is_read_again(tmp_path):
    path = _write(tmp_path / "arm.yaml", _ur5(name="arm"))
    first = derive.load_robot(path)
    _write(path, _ur5(name="arm", parameters={"d1": 0.3}))
    second = derive.load_robot(path)
    assert first.id != second.id
    assert second.parameters["d1"] == pytest.approx(0.3)


def test_decimal_angles_snap_to_multiples_of_pi_only_within_rounding(tmp_path):
    exact = derive.load_robot(_write(tmp_path / "a.yaml",
                                     _decimal_alphas(_ur5(name="dec"), 1.5707963267948966)))
    assert exact.exact and exact.id == derive.load_robot("ur5").id
    approx = derive.load_robot(_write(tmp_path / "b.yaml", _decimal_alphas(_ur5(name="approx"), 1.5708)))
    assert not approx.exact and approx.id != exact.id
    assert not derive.load_robot("general-6r").exact and not derive.load_robot("ur5-calibrated").exact
    # within the snap tolerance the exact form is the multiple, the number stays as written:
    # derived as pi/2, but numerically another robot (its reference FK uses the file's number)
    near = derive.load_robot(_write(tmp_path / "c.yaml",
                                    _decimal_alphas(_ur5(name="near"), 1.5707963267948966 + 1e-13)))
    assert near.exact and near.id != exact.id
    assert near.joints[0].post[-1].angle == 1.5707963267948966 + 1e-13
    assert exact_form(near.joints[0].post[-1])[1] == exact_form(exact.joints[0].post[-1])[1] == sp.pi / 2


def test_exact_means_multiples_of_pi_over_12_in_any_unit_and_through_parameters(tmp_path):
    ur5 = derive.load_robot("ur5")
    deg = _ur5(name="deg", units={"length": "m", "angle": "deg"})
    for j in deg["joints"]:
        j["alpha"] = {"pi/2": 90, "-pi/2": -90, 0: 0}[j["alpha"]]
        j["limits"] = [-360, 360]
    assert derive.load_robot(_write(tmp_path / "deg.yaml", deg)).id == ur5.id
    deg["joints"][0]["alpha"] = 90.2            # a rational number of degrees, not a multiple of 15
    assert not derive.load_robot(_write(tmp_path / "deg2.yaml", deg)).exact
    par = _ur5(name="par", parameters={"tw": "pi/2"})
    for j in par["joints"]:
        j["alpha"] = {"pi/2": "tw", "-pi/2": "-tw", 0: 0}[j["alpha"]]
    robot = derive.load_robot(_write(tmp_path / "par.yaml", par))
    assert robot.exact and robot.id == ur5.id


# --------------------------------------------------------------------------- #
# Kernels of any robot file
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("backend", ["python", "numpy", "c"])
def test_file_named_ur5_with_another_d1_gets_its_own_kernels(tmp_path, cache, backend, rng):
    path = _write(tmp_path / "ur5.yaml", _ur5(parameters={"d1": 0.5}))
    q = rng.uniform(-np.pi, np.pi, (200, 6))
    k = derive.kernels(str(path), backend)
    mine = reference.fk(path, q)
    assert _same_pose(k.fk(q), mine) < 1e-12
    library = reference.fk("ur5", q)
    assert np.allclose(np.abs(derive.dualquat.to_rt(mine)[1] - derive.dualquat.to_rt(library)[1])[:, 2],
                       0.5 - 0.089159, atol=1e-12)
    sols, counts = k.ik(mine[:50])
    assert np.all(counts >= 1)
    for i in range(50):
        got = reference.fk(path, sols[i, :counts[i]])
        err = reference.pose_error(got, np.repeat(mine[i:i + 1], counts[i], axis=0))
        assert max(err[0].max(), err[1].max()) < 1e-10


def test_decimal_dh_file_under_a_new_name_gets_fk_and_ik_kernels(tmp_path, cache, rng, capfd):
    # decimal twists (snapped to pi/2 within 1e-12) and a number of its own: made on first use,
    # not shipped, from the UR class's shipped program (no derivation on its chain)
    path = _write(tmp_path / "arm.yaml", _decimal_alphas(_ur5(name="decimal-ur5", parameters={"d1": 0.1}),
                                                         1.5707963267948966))
    assert derive.load_robot(path).exact and derive.load_robot(path).id != derive.load_robot("ur5").id
    q = rng.uniform(-np.pi, np.pi, (300, 6))
    poses = reference.fk(path, q)
    for backend in ("python", "numpy", "c"):
        k = derive.kernels(path, backend)
        assert _same_pose(k.fk(q), poses) < 1e-12
        sols, counts = k.ik(poses)
        found = 0
        for i in range(len(q)):
            s = sols[i, :counts[i]]
            dp, dr = reference.pose_error(reference.fk(path, s), np.repeat(poses[i:i + 1], counts[i], axis=0))
            assert dp.max() < 1e-10 and dr.max() < 1e-10
            d = np.abs(np.mod(s - q[i] + np.pi, 2 * np.pi) - np.pi)
            found += bool(np.any(np.all(d < 1e-8, axis=1)))
        assert found == len(q)
    err = capfd.readouterr().err
    assert "[decimal-ur5] no kernels of identity" in err and "known class" in err   # progress lines
    assert "set B" not in err                                                       # nothing derived


def test_robot_that_is_not_exact_gets_polish_or_general_kernels(tmp_path, cache, rng, capfd):
    # twists 1.5708 alone keep axes 2, 3, 4 parallel and axes 5, 6 intersecting: the three-parallel
    # class, solved exactly (tests/test_parallel3.py); a twist of 1e-4 rad between axes 2 and 3 as
    # well makes a near-class arm: its kernels solve the nominal's closed form and polish
    # (derive.codegen.polish); an arm near no class gets the general 6R elimination's kernels
    data = _decimal_alphas(_ur5(name="approx-ur5"), 1.5708)
    data["joints"][1]["alpha"] = 0.0001
    path = _write(tmp_path / "arm.yaml", data)
    k = derive.kernels(path, "c")
    err = capfd.readouterr().err
    assert "[approx-ur5]" in err and "deriving" in err and "numeric product" in err
    q = rng.uniform(-np.pi, np.pi, (200, 6))
    assert _same_pose(k.fk(q), reference.fk(path, q)) < 1e-12
    assert k.has_ik and k.nominal is not None
    sols, counts = k.ik(reference.fk(path, q[:20]))
    for i in range(20):
        assert _same_pose(k.fk(sols[i, :counts[i]]), np.repeat(reference.fk(path, q[i])[None], counts[i], 0)) < 1e-10
    robot = derive.load_robot(path)
    folder = user_folder(f"{robot.id}-L{robot.limits_id}")
    assert any(f.name.startswith(folder.name + "-n") for f in folder.parent.iterdir())
    far_data = _decimal_alphas(_ur5(name="tilted-ur5"), 1.4)
    far_data["joints"][1]["alpha"] = 0.2                  # axes 2, 3 0.2 rad apart: near no class
    far = _write(tmp_path / "far.yaml", far_data)
    kf = derive.kernels(far, "c")
    # near no class: its IK kernels are the general 6R elimination's (up to 16 solutions)
    assert kf.has_ik and kf.nominal is None and kf.max_solutions == 16
    sols, counts = kf.ik(reference.fk(far, q[:10]))
    for i in range(10):
        assert counts[i] >= 1 and np.min(np.abs(wrap_angle(sols[i, :counts[i]] - q[i])).max(1)) < 1e-8
        assert _same_pose(kf.fk(sols[i, :counts[i]]), np.repeat(reference.fk(far, q[i])[None], counts[i], 0)) < 1e-10
    far_robot = derive.load_robot(far)
    assert (user_folder(f"{far_robot.id}-L{far_robot.limits_id}") / "manifest.json").is_file()


def test_derivation_stops_at_its_time_budget(tmp_path, cache, monkeypatch):
    path = _write(tmp_path / "arm.yaml", _ur5(name="budget-arm", parameters={"d4": 0.2}))
    monkeypatch.setenv("DQ_DERIVE_BUDGET", "0.001")
    with pytest.raises(DeriveError, match="time budget of 0.001 s"):
        derive.kernels(path, "numpy")
    monkeypatch.setenv("DQ_DERIVE_BUDGET", "soon")
    with pytest.raises(DeriveError, match="DQ_DERIVE_BUDGET"):
        derive.kernels(path, "numpy")


def test_library_kernels_come_from_the_shipped_folder(cache):
    k = derive.kernels("ur5", "numpy")
    assert k.folder == GENERATED / "ur5"
    manifest = json.loads((GENERATED / "ur5" / "manifest.json").read_text())
    assert manifest["id"] == derive.load_robot("ur5").id
    assert not cache.exists() or not any(cache.rglob("manifest.json"))


_NO_SYMBOLIC_WORK = r"""
import sys, os
calls = []
watched = ("derive/symbolic/", "derive/ik/extract.py", "derive/ik/program.py",
           "derive/codegen/emit.py", "derive/codegen/fk.py", "derive/reports/")
def hook(frame, event, arg):
    if event == "call":
        f = frame.f_code.co_filename.replace(os.sep, "/")
        if any(w in f for w in watched):
            calls.append(f"{f}:{frame.f_code.co_name}")
import derive
from derive.algebra.angles import wrap_angle
import derive.refinement.solver   # refine's modules, imported on first use: importing is not work
sys.setprofile(hook)
k = derive.kernels("ur5", "c")
q = [0.3, -1.1, 1.2, -0.4, 0.8, 0.2]
pose = derive.reference.fk("ur5", q)
sols, n = k.ik(pose)
res = derive.refine("ur5", pose)
sys.setprofile(None)
print(n, len(res.solutions), len(calls))
print("\n".join(sorted(set(calls))[:20]))
"""


def test_warm_cache_loads_kernels_and_refine_without_symbolic_work(tmp_path):
    env = {**os.environ, "DQ_DERIVE_CACHE": str(tmp_path / "cache")}
    warm = subprocess.run([sys.executable, "-c", "import derive; derive.kernels('ur5', 'c')"],
                          env=env, capture_output=True, text=True, timeout=300)
    assert warm.returncode == 0, warm.stderr
    run = subprocess.run([sys.executable, "-c", _NO_SYMBOLIC_WORK], env=env, capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    first, *called = run.stdout.strip().splitlines()
    n, n_refined, n_calls = map(int, first.split())
    assert n == 8 and n_refined == 8
    assert n_calls == 0, "symbolic work on the load path:\n" + "\n".join(called)
    assert run.stderr == ""          # nothing derived, so no progress lines


# --------------------------------------------------------------------------- #
# Output folders
# --------------------------------------------------------------------------- #
def test_out_folder_is_the_robot_name_for_any_robot_argument(tmp_path, cache, monkeypatch, capsys):
    data = _decimal_alphas(_ur5(name="my-arm"), 1.5708)
    path = _write(tmp_path / "arm.yaml", data)
    out = tmp_path / "out"
    assert main(["kernels", str(path.resolve()), "--out", str(out)]) == 0
    assert sorted(p.name for p in (out / "my-arm").iterdir()) == [
        "CMakeLists.txt", "manifest.json", "my_arm_kinematics.c", "my_arm_kinematics.h", "my_arm_kinematics.py",
        "my_arm_kinematicsConfig.cmake", "my_arm_kinematics_numpy.py"]
    monkeypatch.chdir(tmp_path)
    assert main(["kernels", "arm.yaml", "--out", "rel"]) == 0
    assert (tmp_path / "rel" / "my-arm" / "my_arm_kinematics.c").is_file()
    assert not (tmp_path / "rel" / "arm.yaml").exists()
    capsys.readouterr()


def test_bad_robot_name_is_refused_before_any_work(tmp_path, capsys):
    path = _write(tmp_path / "arm.yaml", _ur5(name="../escape"))
    with pytest.raises(derive.RobotFileError, match="name '../escape'"):
        derive.load_robot(path)
    assert main(["kernels", str(path), "--out", str(tmp_path / "out")]) != 0
    assert "name '../escape'" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_outputs_of_another_robot_are_not_overwritten(tmp_path, capsys):
    """A file named ur5 with other numbers cannot write over the library UR5's folder."""
    out = tmp_path / "out"
    assert main(["kernels", "ur5", "--out", str(out)]) == 0
    before = (out / "ur5" / "ur5_kinematics.c").read_bytes()
    path = _write(tmp_path / "ur5.yaml", _ur5(parameters={"d1": 0.5}))
    capsys.readouterr()
    assert main(["kernels", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "holds the outputs of another robot" in err and derive.load_robot("ur5").id in err
    assert (out / "ur5" / "ur5_kinematics.c").read_bytes() == before
    assert json.loads((out / "ur5" / "manifest.json").read_text())["id"] == derive.load_robot("ur5").id


def test_non_finite_numbers_and_unwritable_outputs_are_clear_errors(tmp_path, capsys):
    for field in ("d", "a", "alpha", "offset"):
        data = _ur5(name="nan-arm")
        data["joints"][1][field] = float("nan")
        with pytest.raises(derive.RobotFileError, match=f"{field} = nan is not finite"):
            derive.load_robot(_write(tmp_path / f"{field}.yaml", data))
    data = _ur5(name="nan-arm")
    data["joints"][0]["limits"] = [float("nan"), 1.0]
    with pytest.raises(derive.RobotFileError, match="limits = nan is not finite"):
        derive.load_robot(_write(tmp_path / "lim.yaml", data))
    blocker = tmp_path / "afile"
    blocker.write_text("")
    assert main(["kernels", "ur5", "--out", str(blocker)]) == 2
    assert main(["export", "ur5", "--yaml", str(tmp_path / "no" / "such" / "dir.yaml")]) == 2
    err = capsys.readouterr().err
    assert err.count("dq-derive: error:") == 2 and "Traceback" not in err
