"""Cartesian path to joint path (derive.path, derive.apps.path, dq-derive path): every row's FK
is its pose, the path is continuous where the Cartesian path is smooth, events carry the pose
index, the URScript program is the joint path, and the command line end to end."""

import json
import math
import re

import numpy as np
import pytest

import derive
from derive import DeriveError, InputError, reference
from derive.algebra import dualquat as dq
from derive.apps.path import read_poses, urscript
from derive.cli import main


def _curve(q0, delta, n):
    """A smooth joint curve: q0 + t delta, t in [0, 1] at n points."""
    return np.asarray(q0, dtype=float) + np.outer(np.linspace(0.0, 1.0, n), delta)


def _matrix_error(robot, q, poses) -> float:
    """Largest entry difference between the independent 4x4 matrix FK of each row and the
    pose's matrix."""
    got = np.stack([reference.fk_matrix(robot, row) for row in q])
    want = dq.to_matrix(poses)
    return float(np.max(np.abs(got - want)))


def _pose_file(tmp_path, poses, name="poses.csv"):
    """The poses as the CSV a user writes: x,y,z,qx,qy,qz,qw."""
    rows = ["x,y,z,qx,qy,qz,qw"]
    for p in poses:
        r, t = dq.to_rt(p)
        rows.append(",".join(repr(float(v)) for v in (*t, r[1], r[2], r[3], r[0])))
    f = tmp_path / name
    f.write_text("\n".join(rows) + "\n")
    return f


@pytest.mark.parametrize("name, q0, delta", [
    ("ur5", [0.3, -1.1, 1.2, -0.4, 0.8, 0.2], [0.5, 0.3, -0.4, 0.2, 0.3, 0.5]),
    ("irb120", [0.1, 0.2, -0.3, 0.4, 0.6, -0.2], [0.4, -0.3, 0.3, -0.5, 0.4, 0.6]),
])
def test_smooth_path_is_the_generating_curve(name, q0, delta):
    robot = derive.load_robot(name)
    Q = _curve(q0, delta, 40)
    P = reference.fk(robot, Q)
    jp = derive.path(robot, P, q0)
    assert jp.complete and jp.events == ()
    assert _matrix_error(robot, jp.q, P) <= 1e-10
    # chained from the start, each configuration is the curve's own (no winding, no branch change)
    assert np.max(np.abs(jp.q - Q)) <= 1e-9
    curve_step = np.max(np.abs(np.diff(Q, axis=0)))
    assert np.nanmax(jp.step[1:]) <= curve_step + 1e-9
    assert jp.step[0] <= 1e-9 and len(set(jp.branch.tolist())) == 1


def test_seven_joint_path_chooses_the_free_parameter_continuously():
    robot = derive.load_robot("iiwa14")
    q0 = [0.2, 0.5, 0.1, -1.2, 0.3, 0.8, 0.1]
    Q = _curve(q0, [0.3, -0.2, 0.2, 0.4, -0.3, 0.2, 0.5], 16)
    P = reference.fk(robot, Q)
    jp = derive.path(robot, P, q0)
    assert jp.complete and not jp.events_of("jump") and not jp.events_of("branch")
    assert _matrix_error(robot, jp.q, P) <= 1e-10
    # the free parameter is the nearest's choice, not the curve's; still a continuous path whose
    # steps are of the size of the curve's
    assert np.nanmax(jp.step) <= 2.0 * np.max(np.abs(np.diff(Q, axis=0)))
    assert np.all((jp.q >= robot.limits[:, 0]) & (jp.q <= robot.limits[:, 1]))


def test_path_through_the_wrist_singularity_reports_it_at_its_index():
    robot = derive.load_robot("ur5")
    q0 = [0.3, -1.1, 1.2, -0.4, -0.3, 0.2]
    Q = _curve(q0, [0.2, 0.1, -0.1, 0.2, 0.6, 0.3], 21)      # q5 = 0 at pose 10 exactly
    assert Q[10, 4] == 0.0
    P = reference.fk(robot, Q)
    jp = derive.path(robot, P, q0)
    assert jp.complete
    assert _matrix_error(robot, jp.q, P) <= 1e-10
    singular = jp.events_of("singular")
    assert [e.index for e in singular] == [10] and jp.singular.tolist() == [i == 10 for i in range(21)]
    # q5 changes sign there: the wrist branch changes at the same pose, and the path stays continuous
    assert [e.index for e in jp.events_of("branch")] == [10]
    assert np.sign(jp.q[9, 4]) == -np.sign(jp.q[11, 4])
    assert np.nanmax(jp.step) <= 0.1


def test_unreachable_pose_is_an_event_with_its_index_not_an_error():
    robot = derive.load_robot("ur5")
    q0 = [0.3, -1.1, 1.2, -0.4, 0.8, 0.2]
    Q = _curve(q0, [0.2, 0.1, -0.1, 0.2, 0.3, 0.3], 8)
    P = reference.fk(robot, Q)
    far = dq.from_rt(dq.to_rt(P[3])[0], dq.to_rt(P[3])[1] + [3.0, 0.0, 0.0])   # 3 m beyond reach
    P[3] = far
    jp = derive.path(robot, P, q0)
    assert not jp.complete and jp.found.tolist() == [i != 3 for i in range(8)]
    [event] = jp.events
    assert (event.index, event.kind) == (3, "unreachable")
    assert event.message.startswith("the distance from shoulder to wrist is outside the range")
    assert np.all(np.isnan(jp.q[3]))
    keep = np.arange(8) != 3
    assert _matrix_error(robot, jp.q[keep], P[keep]) <= 1e-10
    assert np.max(np.abs(jp.q[keep] - Q[keep])) <= 1e-9         # chained on across the gap
    with pytest.raises(DeriveError, match="pose.s. 3 have no configuration"):
        urscript(jp)


def test_limit_stop_is_reported_with_its_index():
    robot = derive.load_robot("irb120")             # axis 5 within +-120 deg
    q = np.radians([[10, 20, -10, 30, 110, 40], [10, 20, -10, 30, 130, 40], [10, 20, -10, 30, 115, 40]])
    P = reference.fk(robot, q)
    sols, count = derive.kernels(robot, "c").ik(P[1])
    assert count > 0                                 # solutions, none inside the limits
    jp = derive.path(robot, P, q[0])
    assert [(e.index, e.kind) for e in jp.events] == [(1, "limit")]
    assert jp.found.tolist() == [True, False, True]
    assert np.max(np.abs(jp.q[[0, 2]] - q[[0, 2]])) <= 1e-9


def test_urscript_is_one_movej_per_row_with_the_joint_values():
    robot = derive.load_robot("ur5")
    q0 = [0.3, -1.1, 1.2, -0.4, 0.8, 0.2]
    jp = derive.path(robot, reference.fk(robot, _curve(q0, [0.2, 0.1, -0.1, 0.2, 0.3, 0.3], 12)), q0)
    text = urscript(jp, name="pick", accel=0.5, speed=0.25, blend=0.001)
    lines = text.strip().splitlines()
    assert lines[0] == "def pick():" and lines[-1] == "end"
    moves = [ln for ln in lines if ln.strip().startswith("movej")]
    assert len(moves) == len(jp.q) == 12
    pattern = re.compile(r"^  movej\(\[([^\]]*)\], a=([^,]+), v=([^,]+), r=([^)]+)\)$")
    for row, line in zip(jp.q, moves):
        m = pattern.match(line)
        assert m, line
        values = [float(x) for x in m.group(1).split(",")]
        assert values == row.tolist()                # exact: printed in round-trip precision
        assert (float(m.group(2)), float(m.group(3)), float(m.group(4))) == (0.5, 0.25, 0.001)
    assert all(ln.startswith(("  #", "  movej")) for ln in lines[1:-1])
    for bad in (dict(name="1x"), dict(speed=0.0), dict(accel=math.inf), dict(blend=-1.0)):
        with pytest.raises(InputError):
            urscript(jp, **bad)


def test_urscript_refuses_a_seven_joint_arm():
    robot = derive.load_robot("iiwa14")
    q0 = [0.2, 0.5, 0.1, -1.2, 0.3, 0.8, 0.1]
    jp = derive.path(robot, reference.fk(robot, np.array([q0])), q0)
    with pytest.raises(DeriveError, match="six-joint"):
        urscript(jp)


def test_pose_files_csv_and_json_agree(tmp_path):
    robot = derive.load_robot("ur5")
    P = reference.fk(robot, _curve([0.3, -1.1, 1.2, -0.4, 0.8, 0.2], [0.2, 0.1, -0.1, 0.2, 0.3, 0.3], 5))
    csv_poses = read_poses(_pose_file(tmp_path, P))
    sign = np.where(np.sum(csv_poses[:, :4] * P[:, :4], axis=1) < 0, -1.0, 1.0)[:, None]
    assert np.max(np.abs(csv_poses * sign - P)) <= 1e-15
    rows = [[float(x) for x in line.split(",")] for line in _pose_file(tmp_path, P).read_text().splitlines()[1:]]
    (tmp_path / "rows.json").write_text(json.dumps(rows))
    keys = ("x", "y", "z", "qx", "qy", "qz", "qw")
    (tmp_path / "objects.json").write_text(json.dumps([dict(zip(keys, r)) for r in rows]))
    assert np.array_equal(read_poses(tmp_path / "rows.json"), csv_poses)
    assert np.array_equal(read_poses(tmp_path / "objects.json"), csv_poses)


@pytest.mark.parametrize("text, message", [
    ("x,y,z,qw,qx,qy,qz\n0,0,0,1,0,0,0\n", "line 1: expected the header"),
    ("x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,1\n0,0,zero,0,0,0,1\n", "line 3: 'zero' is not a number"),
    ("x,y,z,qx,qy,qz,qw\n0,0,0,0,0,1\n", "line 2: expected 7 values, got 6"),
    ("x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,2\n", "line 2: quaternion: not unit"),
    ("x,y,z,qx,qy,qz,qw\n0,0,nan,0,0,0,1\n", "line 2: 'nan' is not a finite number"),
    ("x,y,z,qx,qy,qz,qw\n", "no poses"),
    ("[[0, 0, 0, 0, 0, 1]]", "entry 0: expected"),
    ("[{\"x\": 0}]", "entry 0: expected the keys"),
    ("[0, 0", "not valid JSON"),
])
def test_malformed_pose_files_name_the_problem(tmp_path, text, message):
    f = tmp_path / "bad.csv"
    f.write_text(text)
    with pytest.raises(InputError, match=re.escape(message)):
        read_poses(f)


def test_path_input_errors():
    robot = derive.load_robot("ur5")
    P = reference.fk(robot, np.zeros(6))
    with pytest.raises(InputError, match="q_start"):
        derive.path(robot, P, [0.0] * 5)
    with pytest.raises(InputError, match="q_start"):
        derive.path(robot, P, [0.0] * 5 + [math.nan])
    with pytest.raises(InputError, match="max_step"):
        derive.path(robot, P, np.zeros(6), max_step=0.0)
    with pytest.raises(InputError):
        derive.path(robot, np.zeros((3, 8)), np.zeros(6))                # not unit
    with pytest.raises(DeriveError, match="no IK kernels"):
        derive.path("seed-arm", reference.fk("seed-arm", np.zeros(5)), np.zeros(5))


def test_path_of_one_pose_of_a_general_6r_arm():
    """One pose (8,) is a path of one point; a general 6R arm's kernels (the elimination) solve it:
    the configuration nearest the start, on the pose."""
    q0 = np.array([0.3, -0.4, 0.5, 0.2, -0.6, 0.1])
    P = reference.fk("general-6r", q0)
    p = derive.path("general-6r", P, q0 + 0.01)
    assert p.q.shape == (1, 6) and p.found.tolist() == [True]
    assert np.abs(p.q[0] - q0).max() < 1e-8


# --------------------------------------------------------------------------- #
# dq-derive path
# --------------------------------------------------------------------------- #
def test_cli_path_end_to_end(tmp_path, capsys):
    robot = derive.load_robot("ur5")
    q0 = [0.3, -1.1, 1.2, -0.4, 0.8, 0.2]
    Q = _curve(q0, [0.2, 0.1, -0.1, 0.2, 0.3, 0.3], 10)
    poses = _pose_file(tmp_path, reference.fk(robot, Q))
    out_csv, out_ur = tmp_path / "path.csv", tmp_path / "path.script"
    rc = main(["path", "ur5", "--poses", str(poses), "--seed", *map(str, q0), "--csv", str(out_csv),
               "--urscript", str(out_ur), "--speed", "0.5", "--json"])
    assert rc == 0
    data = json.loads(capsys.readouterr().out)
    assert data["complete"] and data["events"] == [] and data["written"] == [str(out_csv), str(out_ur)]
    q = np.array(data["q"])
    assert np.max(np.abs(q - Q)) <= 1e-9
    table = [line.split(",") for line in out_csv.read_text().splitlines()]
    assert table[0] == ["index", *robot.variable_names]
    assert np.array_equal(np.array(table[1:], dtype=float)[:, 1:], q)
    moves = [ln for ln in out_ur.read_text().splitlines() if "movej" in ln]
    assert len(moves) == 10 and all("v=0.5" in m and "a=1.4" in m for m in moves)
    # the text output: a summary line, then the table of configurations (degrees with --deg)
    assert main(["path", "ur5", "--poses", str(poses), "--seed", *map(str, np.degrees(q0)), "--deg"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("ur5: 10 poses, 10 configurations")
    assert np.allclose([float(x) for x in lines[-1].split()[1:]], np.degrees(Q[-1]), atol=1e-5)


def test_cli_path_unreachable_pose_exits_1_without_a_program(tmp_path, capsys):
    robot = derive.load_robot("ur5")
    P = reference.fk(robot, _curve([0.3, -1.1, 1.2, -0.4, 0.8, 0.2], [0.2, 0.1, -0.1, 0.2, 0.3, 0.3], 5))
    r, t = dq.to_rt(P[2])
    P[2] = dq.from_rt(r, t + [0.0, 0.0, 3.0])
    poses = _pose_file(tmp_path, P)
    out_ur = tmp_path / "p.script"
    rc = main(["path", "ur5", "--poses", str(poses), "--seed", "0.3", "-1.1", "1.2", "-0.4", "0.8", "0.2",
               "--urscript", str(out_ur)])
    out, err = capsys.readouterr()
    assert rc == 1 and not out_ur.exists()
    assert "pose 2: unreachable: " in out
    assert err.strip().splitlines() == ["dq-derive: no URScript program written: pose(s) 2 have no configuration"]


@pytest.mark.parametrize("args, message", [
    (["--poses", "{bad}", "--seed", "0", "0", "0", "0", "0", "0"], "line 2: 'a' is not a number"),
    (["--poses", "{good}", "--seed", "0", "0", "0"], "--seed: robot 'ur5' has 6 joint variables"),
    (["--poses", "{missing}", "--seed", "0", "0", "0", "0", "0", "0"], "cannot be read"),
    (["--poses", "{good}", "--seed", "0", "0", "0", "0", "0", "0", "--urscript", "x.script", "--speed", "-1"],
     "speed: expected a finite number > 0"),
])
def test_cli_path_bad_input_one_line_exit_2(tmp_path, capsys, args, message):
    bad = tmp_path / "bad.csv"
    bad.write_text("x,y,z,qx,qy,qz,qw\n0.1,0.2,a,0,0,0,1\n")
    good = tmp_path / "good.csv"
    good.write_text("x,y,z,qx,qy,qz,qw\n0.4,0.1,0.3,0,0,0,1\n")
    args = [a.format(bad=bad, good=good, missing=tmp_path / "none.csv") for a in args]
    rc = main(["path", "ur5", *args])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and message in err[0], err


def test_cli_path_urscript_needs_six_joints(tmp_path, capsys):
    good = tmp_path / "good.csv"
    good.write_text("x,y,z,qx,qy,qz,qw\n0.4,0.1,0.5,0,1,0,0\n")
    rc = main(["path", "iiwa14", "--poses", str(good), "--seed", *["0.1"] * 7, "--urscript", str(tmp_path / "x")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "six-joint" in err[0]


def test_branch_change_labels_name_steps_only_for_closed_form_branches():
    """Which closed-form steps changed root between two branch ids: the bits of ids inside the
    closed form's 2^len(labels) branches (bit 0 the last label); a near-class kernel's extra slot
    (ids 8..15 of a width-16 output, derive.codegen.polish.polish_width) or -1 names none."""
    from types import SimpleNamespace

    from derive.apps.path import _labels
    k = SimpleNamespace(branch_labels=["q1", "q5", "q3"])
    assert _labels(k, 0, 1) == " (q3)"
    assert _labels(k, 0b100, 0b010) == " (q1, q5)"
    assert _labels(k, 5, 5) == ""
    assert "seed" in _labels(k, 3, 9) and "seed" in _labels(k, -1, 2)
