"""Library names and file paths (issue 33 item 4, docs/robot-format.md "Library names and file
paths"): a bare name is a library robot, a file needs a separator or an extension, an ambiguous
name is an error naming both."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import derive
from derive.cli import main
from derive.errors import UnknownRobotError
from derive.model.robot import LIBRARY_DIR, resolve_name

#: A six-joint arm that is not the UR5 (its d1 is 1 m): FK at zero tells the two apart
OTHER = (LIBRARY_DIR / "ur5.yaml").read_text().replace("d1: 0.089159", "d1: 1.0")


@pytest.fixture
def folder(tmp_path, monkeypatch):
    """The working folder holds a file named like a library robot (``ur5``), a file named
    like none (``myarm``), both the other arm."""
    assert "d1: 1.0" in OTHER
    (tmp_path / "ur5").write_text(OTHER)
    (tmp_path / "myarm").write_text(OTHER)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _z(robot) -> float:
    """The z of the flange at q = 0, from the 4x4-matrix reference (m)."""
    return float(derive.reference.fk_matrix(robot, np.zeros(6))[2, 3])


def test_bare_name_is_the_library_robot(folder):
    ur5 = derive.load_robot("ur5")
    assert Path(ur5.path) == LIBRARY_DIR / "ur5.yaml"
    assert resolve_name("ur5") == "library"
    # the UR5's flange height at zero is d1 - d5 (0.089159 - 0.09465); the file's has d1 = 1 m
    assert _z(ur5) == pytest.approx(0.089159 - 0.09465, abs=1e-12)
    assert _z(derive.load_robot("./ur5")) == pytest.approx(1.0 - 0.09465, abs=1e-12)


def test_cli_bare_name_is_the_library_robot(folder, capsys):
    assert main(["fk", "ur5", "--q", "0", "0", "0", "0", "0", "0", "--json", "--matrix"]) == 0
    lib = json.loads(capsys.readouterr().out)
    assert main(["fk", "./ur5", "--q", "0", "0", "0", "0", "0", "0", "--json", "--matrix"]) == 0
    other = json.loads(capsys.readouterr().out)
    assert lib["matrix"][2][3] == pytest.approx(0.089159 - 0.09465, abs=1e-9)
    assert other["matrix"][2][3] == pytest.approx(1.0 - 0.09465, abs=1e-9)


def test_file_needs_separator_or_extension(folder):
    with pytest.raises(UnknownRobotError, match=r"unknown robot 'myarm'.*'\./myarm'"):
        derive.load_robot("myarm")
    assert derive.load_robot("./myarm").path == str(folder / "myarm")
    assert derive.load_robot(folder / "myarm").path == str(folder / "myarm")
    (folder / "arm.yaml").write_text(OTHER)
    assert derive.load_robot("arm.yaml").path == str(folder / "arm.yaml")
    with pytest.raises(UnknownRobotError, match=r"'ur5\.yaml' does not exist.*library robot .*'ur5'"):
        derive.load_robot("ur5.yaml")


def test_cli_bare_unknown_name_is_one_line_exit_2(folder, capsys):
    assert main(["fk", "myarm", "--q", "0", "0", "0", "0", "0", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "./myarm" in err


def test_ambiguous_name_names_both(folder):
    """A Path without a separator that names a library robot, beside a file of that name."""
    with pytest.raises(UnknownRobotError) as exc:
        derive.load_robot(Path("ur5"))
    msg = str(exc.value)
    assert "ambiguous" in msg and str(LIBRARY_DIR / "ur5.yaml") in msg and str(folder / "ur5") in msg
    # without the file, Path("ur5") is the library robot; a Path to a file not in the library loads
    (folder / "ur5").unlink()
    assert Path(derive.load_robot(Path("ur5")).path) == LIBRARY_DIR / "ur5.yaml"
    assert derive.load_robot(Path("myarm")).path == str(folder / "myarm")


def test_dotted_library_name_beside_a_file_is_ambiguous(folder, monkeypatch):
    """The name pattern allows a '.' in a library name; such a name beside a file of that name
    reads both ways."""
    import derive.model.robot as robot_module
    monkeypatch.setattr(robot_module, "list_robots", lambda: ["ur5", "arm.v2"])
    (folder / "arm.v2").write_text(OTHER)
    with pytest.raises(UnknownRobotError, match="ambiguous"):
        resolve_name("arm.v2")
    (folder / "arm.v2").unlink()
    assert resolve_name("arm.v2") == "library"
