"""The dq-derive command line."""

import json
import math
import re
import subprocess
import sys

import numpy as np
import pytest

from derive import reference
from derive.cli import main
from derive.reports import figures


def test_robots_lists_library(capsys):
    assert main(["robots"]) == 0
    out = capsys.readouterr().out
    for name in ("ur3", "ur3-thesis", "irb120", "seed-arm", "kunze-2r"):
        assert f"\n{name} " in out
    lines = out.splitlines()
    header = lines[0]
    # aligned: every column starts at the same place in every row
    for title in ("dof", "class", "closed-form IK", "kernels", "CasADi", "title"):
        assert title in header
    rows = {line.split()[0]: line for line in lines[1:] if line and not line.startswith("closed-form")}
    start = header.index("closed-form IK")
    assert rows["ur5"][start:].startswith("UR ")
    assert rows["irb120"][start:].startswith("OPW ")
    assert rows["seed-arm"][start:].startswith("no: refine")
    assert rows["ur5-calibrated"][start:].startswith("nominal UR + Newton polish")   # issue 30 item 3
    kstart = header.index("kernels")
    assert rows["ur5"][kstart:].startswith("FK+IK, shipped")
    assert rows["seed-arm"][kstart:].startswith("FK, on demand")
    assert rows["seed-arm"].split()[1] == "5" and rows["ur5"].split()[1] == "6"


def test_fk_prints_thesis_pose(capsys):
    assert main(["fk", "ur3-thesis", "0", "-90", "0", "-90", "0", "0", "--deg", "--matrix"]) == 0
    out = capsys.readouterr().out
    assert "-0.19425   0.69415" in out
    assert "4x4 matrix" in out


def test_fk_deg_leaves_prismatic_joints_alone(capsys):
    assert main(["fk", "seed-arm", "1", "90", "2", "90", "30", "--deg"]) == 0
    out = capsys.readouterr().out
    assert "0.00000  10.00000   1.00000" in out


@pytest.mark.parametrize("argv, message", [
    (["fk", "ur99", "0"], "unknown robot 'ur99'"),
    (["fk", "ur5", "1", "2"], "has 6 joint variables"),
    (["fk", "ur5", "0", "0", "0", "0", "0", "0", "--end", "tip"], "not an end frame"),
])
def test_errors_exit_2_with_message(argv, message, capsys):
    assert main(argv) == 2
    assert message in capsys.readouterr().err


def test_generate_prints_table(tmp_path, capsys):
    assert main(["generate", "ur5", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "ur5 q=zero" in out and "max |DQ - matrix|" in out and "took" in out


def test_module_entry_point():
    res = subprocess.run([sys.executable, "-m", "derive", "--version"], capture_output=True, text=True)
    assert res.returncode == 0 and res.stdout.startswith("dq-derive ")


# --------------------------------------------------------------------------- #
# Targets in units: the acceptance command of issue 18
# --------------------------------------------------------------------------- #
UR5_NAMES = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")
ACCEPT = ["ik", "ur5", "--xyz", "0.4", "0.1", "0.3", "--rpy", "180", "0", "0", "--deg"]


def _target_matrix():
    """Rx(180 deg) at (0.4, 0.1, 0.3), written out by hand."""
    m = np.diag([1.0, -1.0, -1.0, 1.0])
    m[:3, 3] = [0.4, 0.1, 0.3]
    return m


def test_ik_xyz_rpy_deg_prints_joint_names_in_degrees(capsys):
    assert main(ACCEPT) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "ur5: target position 0.40000 0.10000 0.30000 m, rpy 180.000 0.000 0.000 deg"
    assert lines[1] == "8 solution(s) (closed form):"
    assert lines[2].split() == ["#", *UR5_NAMES]
    assert lines[3].split() == ["(deg)"] * 6
    rows = [line.split() for line in lines[4:]]
    assert [r[0] for r in rows] == [str(i) for i in range(1, 9)]
    for r in rows:
        q = np.radians([float(v) for v in r[1:7]])
        # printed to 5 decimals of a degree: FK within 1e-6 m of the target
        assert np.allclose(reference.fk_matrix("ur5", q), _target_matrix(), atol=2e-6)
    # the base joint of this pose: atan2 of the wrist centre, two shoulder branches
    pans = sorted({r[1] for r in rows})
    assert len(pans) == 2
    assert "-0.00000" not in "\n".join(lines)


def test_ik_json_parses_with_names_units_and_numbers(capsys):
    assert main(ACCEPT + ["--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["robot"] == "ur5" and data["count"] == 8 and len(data["solutions"]) == 8
    assert [j["name"] for j in data["joints"]] == list(UR5_NAMES)
    assert {j["unit"] for j in data["joints"]} == {"deg"}
    assert data["target"]["position"] == {"value": [0.4, 0.1, 0.3], "unit": "m"}
    assert data["target"]["rpy"]["unit"] == "deg"
    assert np.allclose(data["target"]["rpy"]["value"], [180, 0, 0])
    for s in data["solutions"]:
        assert all(isinstance(v, float) for v in s["q"])
        assert np.allclose(reference.fk_matrix("ur5", np.radians(s["q"])), _target_matrix(), atol=1e-9)


def test_ik_quat_needs_its_order_and_both_orders_agree(capsys):
    base = ["ik", "ur5", "--xyz", "0.4", "0.1", "0.3", "--json", "--quat"]
    assert main(base + ["1", "0", "0", "0"]) == 2
    assert "--quat-order" in capsys.readouterr().err
    assert main(base + ["1", "0", "0", "0", "--quat-order", "xyzw"]) == 0     # Rx(pi)
    xyzw = json.loads(capsys.readouterr().out)
    assert main(base + ["0", "1", "0", "0", "--quat-order", "wxyz"]) == 0
    wxyz = json.loads(capsys.readouterr().out)
    assert np.allclose([s["q"] for s in xyzw["solutions"]], [s["q"] for s in wxyz["solutions"]], atol=1e-12)
    assert np.allclose(reference.fk_matrix("ur5", xyzw["solutions"][0]["q"]), _target_matrix(), atol=1e-9)
    # typed with 4 decimals (|q| - 1 = 2e-5): normalised, the rotation Rx(pi) Rz(pi/2)
    assert main(base + ["0", "0.7071", "0.7071", "0", "--quat-order", "wxyz"]) == 0
    sols = json.loads(capsys.readouterr().out)["solutions"]
    target = _target_matrix()
    target[:3, :3] = [[0, 1, 0], [1, 0, 0], [0, 0, -1]]
    assert len(sols) == 8
    assert all(np.allclose(reference.fk_matrix("ur5", s["q"]), target, atol=1e-9) for s in sols)


def test_ik_of_q_and_deprecated_pose_spelling(capsys):
    q = ["0.1", "-0.4", "0.7", "0.2", "0.5", "-0.3"]
    assert main(["ik", "ur5", "--q", *q, "--json"]) == 0
    new = json.loads(capsys.readouterr().out)
    assert main(["ik", "ur5", "--pose", *q, "--json"]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out) == new
    assert "--pose is deprecated, use --q" in captured.err
    assert any(np.allclose(s["q"], [float(v) for v in q], atol=1e-12) for s in new["solutions"])


def test_ik_unreachable_exits_1_and_says_why(capsys):
    assert main(["ik", "ur5", "--xyz", "3", "0", "0", "--rpy", "0", "0", "0"]) == 1
    out = capsys.readouterr().out
    assert out.startswith("ur5: no solution: unreachable")
    assert main(["ik", "ur5", "--xyz", "3", "0", "0", "--rpy", "0", "0", "0", "--json"]) == 1
    data = json.loads(capsys.readouterr().out)
    assert data["count"] == 0 and data["solutions"] == [] and data["reason"].startswith("unreachable")


@pytest.mark.parametrize("argv, message", [
    (["ik", "ur5", "--xyz", "0.4", "0.1", "0.3"], "exactly one of --rpy R P Y or --quat"),
    (["ik", "ur5", "--rpy", "0", "0", "0"], "need a target"),
    (["ik", "ur5", "--q", "0", "0", "0", "0", "0", "0", "--dq", "1", "0", "0", "0", "0", "0", "0", "0"],
     "give exactly one target"),
    (["ik", "ur5", "--dq", "2", "0", "0", "0", "0", "0", "0", "0"], "--dq"),
    (["ik", "ur5", "--xyz", "0.4", "0.1", "0.3", "--quat", "1", "1", "0", "0", "--quat-order", "wxyz"],
     "--quat: not a unit quaternion (|q| = 1.41421"),
    (["fk", "ur5", "--q", "0", "0", "nan", "0", "0", "0"], "NaN at index"),
    (["fk", "ur5", "--q", "0", "0", "0", "0", "0", "0", "0"], "got 7 value(s)"),
    (["refine", "ur5", "--q", "0", "0", "0", "0", "0", "0", "--max-iter", "0"], "max_iter: must be an integer >= 1"),
    (["refine", "ur5", "--q", "0", "0", "0", "0", "0", "0", "--tol", "nan"], "tol: must be finite"),
    (["refine", "ur5", "--q", "0", "0", "0", "0", "0", "0", "--w-rot", "-1"],
     "weights: (position, rotation), two finite numbers >= 0, not both 0; got (1, -1)"),
    (["plot", "ur5", "--out", "x.png"], "give exactly one of --q"),
])
def test_input_errors_exit_2_with_one_line(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err


@pytest.mark.parametrize("value", ["1j", "True", "0x1", "one"])
def test_non_numbers_are_usage_errors(value, capsys):
    with pytest.raises(SystemExit) as info:
        main(["fk", "ur5", "--q", "0", "0", "0", "0", "0", value])
    assert info.value.code == 2
    assert "invalid float value" in capsys.readouterr().err


def test_fk_json_and_units(capsys):
    assert main(["fk", "seed-arm", "--q", "1", "90", "2", "90", "30", "--deg", "--json", "--matrix"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert [(j["name"], j["unit"]) for j in data["joints"]] == [
        ("l1", "m"), ("t2", "deg"), ("l3", "m"), ("t4", "deg"), ("t5", "deg")]
    assert data["q"] == [1.0, 90.0, 2.0, 90.0, 30.0]
    q = [1.0, math.pi / 2, 2.0, math.pi / 2, math.pi / 6]
    assert np.allclose(data["position"]["value"], reference.fk_matrix("seed-arm", q)[:3, 3], atol=1e-12)
    assert np.allclose(data["matrix"], reference.fk_matrix("seed-arm", q), atol=1e-12)


def test_fk_table_has_prismatic_joints_in_metres(capsys):
    assert main(["fk", "seed-arm", "--q", "1", "90", "2", "90", "30", "--deg"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1].split() == ["l1", "t2", "l3", "t4", "t5"]
    assert lines[2].split() == ["(m)", "(deg)", "(m)", "(deg)", "(deg)"]
    assert lines[3].split() == ["1.0000", "90.0000", "2.0000", "90.0000", "30.0000"]


def test_no_negative_zero(capsys):
    """ur5 at (0, -90, 0, -90, 0, 0) deg: the pose and matrix hold -1e-17 and -0.0 in floating
    point (formatted plainly they print as -0.00000)."""
    q = np.radians([0, -90, 0, -90, 0, 0])
    raw = np.concatenate([reference.fk("ur5", q), reference.fk_matrix("ur5", q).ravel()])
    assert "-0.00000" in " ".join(f"{v:9.5f}" for v in raw)          # the case is real
    argv = ["fk", "ur5", "--q", "0", "-90", "0", "-90", "0", "0", "--deg", "--matrix"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert re.search(r"-0\.0+(?![0-9])", out) is None
    assert main(argv + ["--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    values = data["dual_quaternion"] + [v for row in data["matrix"] for v in row]
    assert all(math.copysign(1.0, v) > 0 for v in values if v == 0)


def test_refine_json_and_deprecated_pose(capsys):
    q = [0.1, -0.4, 0.7, 0.2, 0.5, -0.3]
    pose = reference.fk("ur5-calibrated", q)
    assert main(["refine", "ur5-calibrated", "--dq", *map(repr, pose.tolist()), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["success"] is True and data["distinct_solutions"] == 8
    assert [j["unit"] for j in data["joints"]] == ["rad"] * 6
    ok = [r for r in data["results"] if r["success"]]
    assert ok and all(r["position_error"]["unit"] == "m" and r["position_error"]["value"] < 1e-10 for r in ok)
    assert any(np.allclose(r["q"], q, atol=1e-9) for r in ok)
    assert main(["refine", "ur5-calibrated", "--pose", *map(repr, pose.tolist())]) == 0
    captured = capsys.readouterr()
    assert "--pose is deprecated, use --dq" in captured.err
    lines = captured.out.splitlines()
    assert lines[2].split()[-6:] == list(UR5_NAMES) and lines[3].split()[-6:] == ["(rad)"] * 6


# --------------------------------------------------------------------------- #
# plot
# --------------------------------------------------------------------------- #
def _png_size(path):
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big"), len(data)


@pytest.mark.parametrize("robot, q_deg", [
    ("ur5", [20, -60, 80, -110, -90, 30]),
    ("irb120", [20, 30, -20, 40, 50, 60]),
])
def test_plot_writes_both_figures(robot, q_deg, tmp_path, capsys):
    arm, sols = tmp_path / "arm.png", tmp_path / "ik.png"
    args = [str(v) for v in q_deg]
    assert main(["plot", robot, "--q", *args, "--deg", "--out", str(arm), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    q = np.radians(q_deg)
    assert data["q"] == [float(v) for v in q_deg] and len(data["frames"]) == len(data["frame_origins"]["value"])
    assert np.allclose(data["frame_origins"]["value"], reference.joint_positions(robot, q), atol=1e-12)
    assert main(["plot", robot, "--ik-of", *args, "--deg", "--out", str(sols)]) == 0
    assert capsys.readouterr().out.startswith(f"wrote {sols}: the 8 IK solution(s)")
    w, h, n = _png_size(arm)
    assert w == h >= 600 and n > 30_000
    w, h, n = _png_size(sols)
    assert w > 1.5 * h and n > 100_000


@pytest.mark.parametrize("robot, q", [
    ("ur5", [0.35, -1.05, 1.4, -1.9, -1.57, 0.5]),
    ("irb120", [0.35, 0.5, -0.35, 0.7, 0.9, 1.0]),
])
def test_figures_draw_the_reference_positions(robot, q, tmp_path):
    drawn = figures.arm_figure(robot, q, tmp_path / "a.png")
    assert np.array_equal(drawn, reference.joint_positions(robot, q))
    figures.arm_figure(robot, q, tmp_path / "again.png")
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "again.png").read_bytes()   # deterministic
    sols, drawn = figures.ik_figure(robot, q, tmp_path / "b.png")
    assert sols.shape == (8, 6) and drawn.shape[0] == 8
    target = reference.fk_matrix(robot, q)
    for s, d in zip(sols, drawn):
        assert np.allclose(reference.fk_matrix(robot, s), target, atol=1e-9)
        assert np.array_equal(d, reference.joint_positions(robot, s))
    assert any(np.allclose(s, q, atol=1e-9) for s in sols)


def test_joint_axes_are_the_motion_axes(tmp_path):
    """Rotating one joint a little moves every later frame origin perpendicular to the drawn
    axis of that joint, by the distance from the axis times the angle."""
    q = np.array([0.35, -1.05, 1.4, -1.9, -1.57, 0.5])
    points, dirs = figures.joint_axes("ur5", q)
    assert np.allclose(np.linalg.norm(dirs, axis=1), 1.0)
    for i in range(6):
        dq_ = np.zeros(6)
        dq_[i] = 1e-6
        before = reference.fk_matrix("ur5", q)[:3, 3]
        after = reference.fk_matrix("ur5", q + dq_)[:3, 3]
        expected = 1e-6 * np.cross(dirs[i], before - points[i])
        assert np.allclose(after - before, expected, atol=1e-11)


def test_refine_unreachable_exits_1(capsys):
    argv = ["refine", "ur5", "--xyz", "3", "0", "0", "--rpy", "0", "0", "0", "--max-iter", "5"]
    assert main(argv) == 1
    out = capsys.readouterr().out
    assert "0 distinct exact solution(s)" in out and "no exact solution: best residual" in out
    assert main(argv + ["--json"]) == 1
    data = json.loads(capsys.readouterr().out)
    # 3 m is beyond ur5's reach (a2 + a3 + d4 + d6 < 1.1 m): every residual over 1.5 m
    assert data["success"] is False and data["distinct_solutions"] == 0
    assert all(r["position_error"]["value"] > 1.5 for r in data["results"])
