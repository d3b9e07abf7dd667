"""The dq-derive command line."""

import subprocess
import sys

import pytest

from derive.cli import main


def test_robots_lists_library(capsys):
    assert main(["robots"]) == 0
    out = capsys.readouterr().out
    for name in ("ur3", "ur3-thesis", "irb120", "seed-arm", "kunze-2r"):
        assert f"\n{name} " in out


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
