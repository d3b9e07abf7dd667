"""URDF input and export, checked against Pinocchio (an independent URDF reader and FK) on the
arm URDFs that example-robot-data ships (installed by the test extra)."""

import math
import sysconfig
from pathlib import Path

import numpy as np
import pytest

import derive
import derive.ik.closed_form
from derive import RobotFileError, reference
from derive.cli import main
from derive.model import export

try:
    import pinocchio as pin
except ImportError:                        # a clear failure, not a skip: the test extra has it
    pin = None


def _data_root() -> Path:
    """example-robot-data's robots folder; a clear failure (not a skip) when it is missing."""
    for base in {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}:
        root = Path(base) / "cmeel.prefix" / "share" / "example-robot-data" / "robots"
        if root.is_dir():
            return root
    pytest.fail("example-robot-data is not installed: `pip install -e '.[test]'` installs it "
                "(the URDF tests need its arm URDFs)")


#: (file below robots/, base link, tip link, dof) of the arm URDFs of example-robot-data.
ARMS = [
    ("ur_description/urdf/ur3_robot.urdf", "base_link", "tool0", 6),
    ("ur_description/urdf/ur5_robot.urdf", "base_link", "tool0", 6),
    ("ur_description/urdf/ur10_robot.urdf", "base_link", "tool0", 6),
    ("panda_description/urdf/panda.urdf", "panda_link0", "panda_link8", 7),
    ("z1_description/urdf/z1.urdf", None, "gripperStator", 6),
    ("xarm_description/urdf/xarm7.urdf", None, None, 7),
    ("kinova_description/robots/kinova.urdf", None, "j2s6s200_end_effector", 6),
    ("so_arm_description/urdf/so100.urdf", None, "gripper", 5),
]


def _pin_fk(path: Path, robot, base: str, tip: str, q: np.ndarray) -> np.ndarray:
    """Pinocchio's placement of ``tip`` relative to ``base`` for our joint values (n, dof)."""
    if pin is None:
        pytest.fail("Pinocchio is not installed: `pip install -e '.[test]'` installs pin")
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    fb, ft = (model.getFrameId(name, pin.FrameType.BODY) for name in (base, tip))
    out = []
    for row in q:
        qp = pin.neutral(model)
        for name, v in zip(robot.variable_names, row):
            jid = model.getJointId(name)
            idx, nq = model.joints[jid].idx_q, model.joints[jid].nq
            qp[idx:idx + nq] = [math.cos(v), math.sin(v)] if nq == 2 else [v]
        pin.framesForwardKinematics(model, data, qp)
        out.append((data.oMf[fb].inverse() * data.oMf[ft]).homogeneous)
    return np.array(out)


def _within_limits(robot, n, rng):
    lim = robot.limits
    lo = np.where(np.isfinite(lim[:, 0]), lim[:, 0], -math.pi)
    hi = np.where(np.isfinite(lim[:, 1]), lim[:, 1], math.pi)
    return rng.uniform(lo, hi, size=(n, robot.dof))


@pytest.mark.parametrize("rel, base, tip, dof", ARMS, ids=[a[0].split("/")[-1] for a in ARMS])
def test_fk_equals_pinocchio_on_every_arm_urdf(rel, base, tip, dof, rng):
    path = _data_root() / rel
    robot = derive.load_robot(path, base=base, tip=tip)
    assert robot.dof == dof
    base = base or robot.source.split("chain ")[1].split(" -> ")[0]
    q = _within_limits(robot, 500, rng)
    gap = np.abs(reference.fk_matrix(robot, q) - _pin_fk(path, robot, base, robot.default_end, q)).max()
    assert gap < 1e-12, f"{rel}: |T - Pinocchio| = {gap:.3g}"
    # the dual-quaternion path agrees with the matrix path on the URDF robot too
    assert np.abs(derive.dualquat.to_matrix(reference.fk(robot, q)) - reference.fk_matrix(robot, q)).max() < 1e-12


def test_joint_names_limits_and_continuous_joints_come_from_the_urdf():
    ur5 = derive.load_robot(_data_root() / ARMS[1][0], base="base_link", tip="tool0")
    assert ur5.variable_names == ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
                                  "wrist_1_joint", "wrist_2_joint", "wrist_3_joint")
    assert ur5.limits[2].tolist() == [-3.14159265359, 3.14159265359]
    assert ur5.default_end == "tool0" and ur5.convention == "urdf"
    xarm = derive.load_robot(_data_root() / ARMS[5][0])
    assert xarm.dof == 7 and np.all(np.isfinite(xarm.limits))


@pytest.mark.parametrize("name", ["ur5", "seed-arm", "ur5-calibrated", "kunze-2r", "irb120"])
def test_library_robot_exported_to_urdf_reads_the_same_in_pinocchio_and_back(name, tmp_path, rng):
    robot = derive.load_robot(name)
    urdf = tmp_path / f"{name}.urdf"
    export.write(robot, urdf_path=urdf, yaml_path=tmp_path / f"{name}.yaml")
    root, _, end_links, _ = export._urdf_names(robot)
    back = derive.load_robot(urdf, tip=end_links[robot.default_end])
    q = _within_limits(robot, 300, rng)
    cols = [robot.variable_names.index(v) for v in back.variable_names]      # the chain's joints
    expect = reference.fk_matrix(robot, q)
    assert np.abs(reference.fk_matrix(back, q[:, cols]) - expect).max() < 1e-12
    assert np.abs(_pin_fk(urdf, back, root, end_links[robot.default_end], q[:, cols]) - expect).max() < 1e-12
    again = derive.load_robot(tmp_path / f"{name}.yaml")
    assert again.dof == robot.dof
    assert np.abs(reference.fk_matrix(again, q) - expect).max() < 1e-12


def test_urdf_to_yaml_to_urdf_keeps_fk(tmp_path, rng):
    src = _data_root() / ARMS[3][0]
    panda = derive.load_robot(src, base="panda_link0", tip="panda_link8")
    y = tmp_path / "panda.yaml"
    export.write(panda, yaml_path=y)
    mid = derive.load_robot(y)
    u = tmp_path / "panda.urdf"
    export.write(mid, urdf_path=u)
    back = derive.load_robot(u, tip="panda_link8")
    q = _within_limits(panda, 300, rng)
    expect = reference.fk_matrix(panda, q)
    for r in (mid, back):
        assert np.abs(reference.fk_matrix(r, q) - expect).max() < 1e-12
    assert mid.variable_names == panda.variable_names == back.variable_names


def test_mimic_joint_follows_its_source(tmp_path):
    text = """<robot name="mimic-arm">
  <link name="a"/><link name="b"/><link name="c"/><link name="tip"/>
  <joint name="j1" type="revolute"><parent link="a"/><child link="b"/>
    <origin xyz="0 0 0.3" rpy="0 0 0"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="j2" type="revolute"><parent link="b"/><child link="c"/>
    <origin xyz="0.4 0 0" rpy="0 0 0"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/>
    <mimic joint="j1" multiplier="-2" offset="0.1"/></joint>
  <joint name="fixed_tip" type="fixed"><parent link="c"/><child link="tip"/><origin xyz="0.2 0 0" rpy="0 0 0"/></joint>
</robot>"""
    path = tmp_path / "mimic.urdf"
    path.write_text(text)
    robot = derive.load_robot(path)
    assert robot.dof == 1 and robot.default_end == "tip"
    for q1 in (-1.0, 0.0, 0.7):
        t = reference.fk_matrix(robot, [q1])[:3, 3]
        q2 = -2 * q1 + 0.1
        expect = [0.4 * math.cos(q1) + 0.2 * math.cos(q1 + q2), 0.4 * math.sin(q1) + 0.2 * math.sin(q1 + q2), 0.3]
        assert np.allclose(t, expect, atol=1e-14)


def _bad(tmp_path, name, old, new, src=ARMS[1][0]):
    text = (_data_root() / src).read_text()
    assert old in text
    path = tmp_path / name
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize("name, old, new, kwargs, message", [
    ("xml.urdf", '<joint name="elbow_joint" type="revolute">', '<joint name="elbow_joint" type="revolute"',
     {}, r"xml\.urdf: not valid XML .*line"),
    ("number.urdf", 'xyz="0.0 0.13585 0.0"', 'xyz="0.0 abc 0.0"', {},
     r"number\.urdf: joint 'shoulder_lift_joint': <origin xyz='0\.0 abc 0\.0'> is not numeric"),
    ("link.urdf", '<child link="forearm_link"/>', '<child link="no_such_link"/>', {},
     r"link\.urdf: joint 'elbow_joint': child link 'no_such_link' is not a link"),
    ("floating.urdf", '<joint name="elbow_joint" type="revolute">', '<joint name="elbow_joint" type="floating">',
     {"base": "base_link", "tip": "tool0"}, r"floating\.urdf: joint 'elbow_joint': type 'floating' is not supported"),
    ("planar.urdf", '<joint name="wrist_2_joint" type="revolute">', '<joint name="wrist_2_joint" type="planar">',
     {"base": "base_link", "tip": "tool0"}, r"planar\.urdf: joint 'wrist_2_joint': type 'planar'"),
    ("nan.urdf", 'xyz="0.0 0.13585 0.0"', 'xyz="nan 0.13585 0.0"', {"base": "base_link", "tip": "tool0"},
     r"nan\.urdf: joint 'shoulder_lift_joint': the origin is not finite"),
    ("inf.urdf", 'rpy="0.0 1.57079632679 0.0" xyz="0.0 0.13585 0.0"', 'rpy="0.0 inf 0.0" xyz="0.0 0.13585 0.0"',
     {"base": "base_link", "tip": "tool0"}, r"inf\.urdf: joint 'shoulder_lift_joint': the origin is not finite"),
])
def test_bad_urdfs_name_the_culprit(tmp_path, name, old, new, kwargs, message):
    with pytest.raises(RobotFileError, match=message):
        derive.load_robot(_bad(tmp_path, name, old, new), **kwargs)


def test_chain_selection_errors_name_the_candidates():
    path = _data_root() / ARMS[1][0]
    with pytest.raises(RobotFileError, match=r"several leaf links \['base', 'ee_link', 'tool0'\]"):
        derive.load_robot(path)
    with pytest.raises(RobotFileError, match="tip link 'base_link' is not below base link 'tool0'"):
        derive.load_robot(path, base="tool0", tip="base_link")
    with pytest.raises(RobotFileError, match="base link 'nowhere' is not a link of the file"):
        derive.load_robot(path, base="nowhere", tip="tool0")
    with pytest.raises(RobotFileError, match="xacro"):
        derive.load_robot("arm.urdf.xacro")
    with pytest.raises(RobotFileError, match="base and tip select the chain of a URDF"):
        derive.load_robot("ur5", tip="tool0")


def test_ur5_urdf_gets_closed_form_kernels_related_to_the_library_ur5(tmp_path, monkeypatch, rng):
    monkeypatch.setenv("DQ_DERIVE_CACHE", str(tmp_path / "cache"))
    robot = derive.load_robot(_data_root() / ARMS[1][0], base="base_link", tip="tool0")
    rel = derive.ik.closed_form.closed_form_relation(robot)
    assert rel is not None and rel.other == "ur5" and np.all(rel.signs == 1)
    # ROS's base_link is the DH base turned half a turn about z; tool0 is DH frame 6
    assert np.allclose(rel.base, [0, 0, 0, 1, 0, 0, 0, 0], atol=1e-12)
    assert np.allclose(rel.tool, [1, 0, 0, 0, 0, 0, 0, 0], atol=1e-12)
    q = rng.uniform(-math.pi, math.pi, (1000, 6))
    poses = reference.fk(robot, q)
    k = derive.kernels(robot, "c")
    assert k.has_ik
    sols, counts = k.ik(poses)
    for i in range(len(q)):
        s = sols[i, :counts[i]]
        dp, dr = reference.pose_error(reference.fk(robot, s), np.repeat(poses[i:i + 1], counts[i], axis=0))
        assert dp.max() < 1e-10 and dr.max() < 1e-10
        d = np.abs(np.mod(s - q[i] + math.pi, 2 * math.pi) - math.pi)
        assert np.any(np.all(d < 1e-8, axis=1)), f"pose {i}: generating configuration not returned"
    ref = reference.ik(robot, poses[0])
    assert len(ref) == counts[0]


def test_cli_takes_urdf_with_base_and_tip(tmp_path, capsys):
    path = str(_data_root() / ARMS[1][0])
    assert main(["fk", path, "--base", "base_link", "--tip", "tool0", "--q", "0", "0", "0", "0", "0", "0"]) == 0
    out = capsys.readouterr().out
    assert "end frame 'tool0'" in out and "0.81725" in out
    assert main(["classify", path, "--base", "base_link", "--tip", "tool0"]) == 0
    out = capsys.readouterr().out
    assert "class: UR" in out and "closed-form IK through the library robot ur5" in out
    assert main(["export", "ur10e", "--urdf", str(tmp_path / "u.urdf"), "--yaml", str(tmp_path / "u.yaml")]) == 0
    capsys.readouterr()
    assert np.allclose(reference.fk_matrix(derive.load_robot(tmp_path / "u.yaml"), np.full(6, 0.3)),
                       reference.fk_matrix("ur10e", np.full(6, 0.3)), atol=1e-12)
    assert main(["fk", path, "0"]) == 2
    assert "several leaf links" in capsys.readouterr().err


def test_calibrated_urdf_without_nominal_key_is_refined_from_the_related_closed_form(tmp_path, rng):
    """A calibrated UR5 exported to URDF has no `nominal` key: its nominal geometry is found as
    the closest library robot with a closed form (fitted base and tool transforms), and
    derive.refine polishes those seeds to exact solutions of the calibrated arm."""
    path = tmp_path / "calibrated.urdf"
    export.write("ur5-calibrated", urdf_path=path)
    robot = derive.load_robot(path)
    rel = derive.ik.closed_form.nominal_relation(robot)
    assert rel is not None and rel.other == "ur5" and 0.005 < rel.error < 0.03
    assert derive.ik.closed_form.closed_form_relation(robot) is None      # not the UR5 within 1e-9
    q = rng.uniform(-math.pi, math.pi, (20, 6))
    poses = reference.fk(robot, q)
    generating = 0
    for i in range(len(q)):
        res = derive.refine(robot, poses[i])
        sols = res.solutions
        assert len(sols) >= 2
        dp, dr = reference.pose_error(reference.fk(robot, sols), np.repeat(poses[i:i + 1], len(sols), axis=0))
        assert dp.max() < 1e-10 and dr.max() < 1e-10
        d = np.abs(np.mod(sols - q[i] + math.pi, 2 * math.pi) - math.pi)
        generating += bool(np.any(np.all(d < 1e-6, axis=1)))
    assert generating >= 18


def test_classify_urdf_arms():
    ur5 = derive.classify(derive.load_robot(_data_root() / ARMS[1][0], base="base_link", tip="tool0"))
    assert ur5.cls == "UR" and not ur5.near_misses
    panda = derive.classify(derive.load_robot(_data_root() / ARMS[3][0], base="panda_link0", tip="panda_link8"))
    # 7R with a spherical shoulder at d1 = 0.333 m, but an offset wrist (a = 0.088 m): not SRS
    assert panda.n == 7 and panda.types == ("revolute",) * 7 and panda.cls == "general"
    assert panda.shoulder.spread < 1e-12 and np.allclose(panda.shoulder.point, [0, 0, 0.333], atol=1e-12)
    assert panda.wrist.spread > 0.05
    kinova = derive.classify(derive.load_robot(_data_root() / ARMS[6][0], tip="j2s6s200_end_effector"))
    assert kinova.cls == "OPW"
