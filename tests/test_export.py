"""`dq-derive export` round-trips (issue 35): every library robot written as YAML and as URDF
and read back. The YAML is the same robot (same identity, every frame bit for bit); the URDF,
read back with every end frame as a tip, keeps the FK of every end frame to 1e-15 and the
identity; both print their numbers so that they read back as the same doubles."""

import dataclasses
import math
import sysconfig
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from derive import reference
from derive.model import export, origins
from derive.model.identity import digest
from derive.model.robot import list_robots, load_robot

def _q(robot, n=12):
    return np.random.default_rng(35).uniform(-3.0, 3.0, size=(n, robot.dof))


@pytest.mark.parametrize("name", list_robots())
def test_export_then_load_is_the_same_robot(name, tmp_path):
    robot = load_robot(name)
    q = _q(robot)
    # YAML: the same description, so the same identity and the same FK of every frame
    text = export.to_yaml(robot)
    (tmp_path / "r.yaml").write_text(text, encoding="utf-8")
    back = load_robot(tmp_path / "r.yaml")
    assert back.id == robot.id
    assert back.exact == robot.exact
    for end in robot.ends:
        assert np.abs(reference.fk(back, q, end) - reference.fk(robot, q, end)).max() <= 1e-15
    assert np.abs(reference.joint_positions(back, q) - reference.joint_positions(robot, q)).max() <= 1e-15
    # URDF: the chain to the default end, one origin per joint; the end frame's FK to 1e-15
    text = export.to_urdf(robot)
    (tmp_path / "r.urdf").write_text(text, encoding="utf-8")
    urdf = load_robot(tmp_path / "r.urdf", tip=robot.default_end)
    cols = [robot.variable_names.index(v) for v in urdf.variable_names]     # the joints on that chain
    gap = np.abs(reference.fk(urdf, q[:, cols]) - reference.fk(robot, q)).max()
    assert gap <= 1e-15, f"{name}: URDF export moves the end frame by {gap:.2g}"
    # URDF with every end frame as a tip: the whole robot, so its identity
    tree = load_robot(tmp_path / "r.urdf", tip=list(robot.ends))
    assert tree.variable_names == robot.variable_names and list(tree.ends) == list(robot.ends)
    for end in robot.ends:
        gap = np.abs(reference.fk(tree, q, end) - reference.fk(robot, q, end)).max()
        assert gap <= 1e-15, f"{name}: URDF export moves the end frame {end} by {gap:.2g}"
    assert tree.exact == robot.exact
    assert tree.id == _with_urdf_limits(robot).id
    if all(j.limits is not None or j.type == "revolute" for j in robot.joints):
        assert tree.id == robot.id


def _with_urdf_limits(robot):
    """``robot`` with the limits its URDF must carry: a prismatic joint without limits gets
    +-PRISMATIC_RANGE (a URDF prismatic joint needs them; only the seed arm has such joints).
    The identity counts joint limits, so the URDF's robot is this one."""
    joints = tuple(dataclasses.replace(j, limits=(-export.PRISMATIC_RANGE, export.PRISMATIC_RANGE))
                   if j.type == "prismatic" and j.limits is None else j for j in robot.joints)
    return dataclasses.replace(robot, joints=joints,
                               id=digest(joints, robot.ends, robot.default_end, robot.exact))


def test_kinova_urdf_exported_does_not_move(tmp_path):
    """The URDF of issue 35: yourdfpy's rpy (pitch near pi/2) moved it by 3.6e-10."""
    paths = [Path(base) / "cmeel.prefix/share/example-robot-data/robots/kinova_description/robots/kinova.urdf"
             for base in {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}]
    path = next((p for p in paths if p.is_file()), None)
    if path is None:
        pytest.fail("example-robot-data is not installed: `pip install -e '.[test]'` installs it")
    robot = load_robot(path, tip="j2s6s200_end_effector")
    q = _q(robot, 200)
    (tmp_path / "kinova.urdf").write_text(export.to_urdf(robot), encoding="utf-8")
    back = load_robot(tmp_path / "kinova.urdf")
    assert np.abs(reference.fk(back, q) - reference.fk(robot, q)).max() <= 1e-15
    assert back.id == robot.id          # its fixed joints folded in, multiplied out once, read back as written
    (tmp_path / "kinova.yaml").write_text(export.to_yaml(robot), encoding="utf-8")
    back = load_robot(tmp_path / "kinova.yaml")
    assert back.id == robot.id
    assert np.array_equal(reference.fk(back, q), reference.fk(robot, q))


def _rz_ry_rx(roll, pitch, yaw):
    """R = Rz(yaw) Ry(pitch) Rx(roll) from scipy (extrinsic x, then y, then z): independent of
    the exporter's formulas."""
    return Rotation.from_euler("xyz", [roll, pitch, yaw]).as_matrix()


@pytest.mark.parametrize("pitch", [0.3, math.pi / 2, -math.pi / 2, math.pi / 2 - 1e-9, -math.pi / 2 + 3e-12,
                                   math.pi / 2 - 1e-6, 1.2])
def test_rpy_of_rebuilds_the_rotation_at_every_pitch(pitch):
    rng = np.random.default_rng(7)
    for roll, yaw in rng.uniform(-math.pi, math.pi, size=(50, 2)):
        r = _rz_ry_rx(roll, pitch, yaw)
        got = export.rpy_of(r)
        assert np.abs(_rz_ry_rx(*got) - r).max() <= 2e-15
    for r in Rotation.random(200, random_state=3).as_matrix():
        assert np.abs(_rz_ry_rx(*export.rpy_of(r)) - r).max() <= 2e-15


def _form_matrix(xyz, rpy) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = _rz_ry_rx(*rpy)
    m[:3, 3] = xyz
    return m


@pytest.mark.parametrize("name", list_robots())
def test_urdf_form_rebuilds_the_fk(name):
    """The URDF form (one xyz + rpy per joint origin and end frame, what the export writes and the
    identity hashes) is the robot: its chain rebuilt with scipy's rotations, each joint moving
    about its axis by its value, gives the reference FK of every end frame."""
    robot = load_robot(name)
    joint_forms, end_forms = origins.urdf_form(robot.joints, robot.ends)
    q = _q(robot, 20)
    values = np.zeros((len(q), len(robot.joints)))
    for i, j in enumerate(robot.joints):
        values[:, i] = j.multiplier * q[:, j.variable] + j.mimic_offset
    for end, e in robot.ends.items():
        chain, k = [], e.parent
        while k >= 0:
            chain.append(k)
            k = robot.joints[k].parent
        for row, v in zip(q, values):
            t = np.eye(4)
            for i in reversed(chain):
                j = robot.joints[i]
                motion = np.eye(4)
                if j.type == "revolute":
                    motion[:3, :3] = Rotation.from_rotvec(v[i] * np.asarray(j.axis)).as_matrix()
                else:
                    motion[:3, 3] = v[i] * np.asarray(j.axis)
                t = t @ _form_matrix(*joint_forms[i]) @ motion
            t = t @ _form_matrix(*end_forms[end])
            assert np.abs(t - reference.fk_matrix(robot, row, end)).max() < 1e-14, (name, end)
