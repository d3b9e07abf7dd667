"""Robot description files: the library, the four conventions, validation errors."""

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

import derive
from derive import RobotFileError, UnknownRobotError, load_robot, reference
from derive import dualquat as DQ
from derive.model.robot import robot_from_dict

DATA = Path(__file__).with_name("data")
LIBRARY = ["abb-irb1600", "crx10ia", "fr3", "gen3", "general-6r", "gp8", "iiwa14", "iiwa7", "irb120", "irb1600",
           "irb6700", "jaco2-6dof", "kr210-r2700", "kr6-r900", "kunze-2r", "lrmate200id", "m710ic", "panda",
           "puma560", "rs007n", "rx160", "seed-arm", "tx2-60", "ur10", "ur10e", "ur16e", "ur3", "ur3-thesis",
           "ur3e", "ur5", "ur5-calibrated", "ur5e", "vs060", "xarm6", "xarm7", "z1"]
UR_DH = {  # d1 a2 a3 d4 d5 d6 from the issue / Universal Robots
    "ur3": (.1519, -.24365, -.21325, .11235, .08535, .0819),
    "ur5": (.089159, -.425, -.39225, .10915, .09465, .0823),
    "ur10": (.1273, -.612, -.5723, .163941, .1157, .0922),
    "ur3e": (.15185, -.24355, -.2132, .13105, .08535, .0921),
    "ur5e": (.1625, -.425, -.3922, .1333, .0997, .0996),
    "ur10e": (.1807, -.6127, -.57155, .17415, .11985, .11655),
    "ur16e": (.1807, -.4784, -.36, .17415, .11985, .11655),
}


def test_library_contents():
    assert derive.list_robots() == LIBRARY
    dofs = {n: load_robot(n).dof for n in LIBRARY}
    assert dofs == {**{n: 6 for n in LIBRARY}, "kunze-2r": 2, "seed-arm": 5, "iiwa7": 7, "iiwa14": 7,
                    "panda": 7, "fr3": 7, "xarm7": 7, "gen3": 7}


@pytest.mark.parametrize("name", sorted(UR_DH))
def test_ur_numbers_and_zero_pose(name):
    r = load_robot(name)
    d1, a2, a3, d4, d5, d6 = UR_DH[name]
    assert r.parameters == pytest.approx(dict(d1=d1, a2=a2, a3=a3, d4=d4, d5=d5, d6=d6), abs=0)
    assert [j.type for j in r.joints] == ["revolute"] * 6
    assert np.allclose(r.limits, [[-2 * math.pi, 2 * math.pi]] * 6)
    # standard DH frame 6 at the zero pose: (a2 + a3, -(d4 + d6), d1 - d5), R = Rx(pi/2)
    t = reference.fk_matrix(r, np.zeros(6))
    assert np.allclose(t[:3, 3], [a2 + a3, -(d4 + d6), d1 - d5], atol=1e-15)
    assert np.allclose(t[:3, :3], [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-15)


def test_standard_dh_matches_kunze_eq_5_4(rng):
    # Every UR joint transform against the printed DH matrix of Kunze eq. 5.4.
    for d, a, alpha in rng.uniform(-1, 1, size=(5, 3)):
        one = robot_from_dict({"name": "one", "convention": "standard_dh",
                               "joints": [{"name": "j", "d": d, "a": a, "alpha": alpha * 3}]})
        th = rng.uniform(-3, 3)
        ct, st, ca, sa = math.cos(th), math.sin(th), math.cos(alpha * 3), math.sin(alpha * 3)
        expected = np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st],
                             [0, sa, ca, d], [0, 0, 0, 1]])
        assert np.allclose(reference.fk_matrix(one, [th]), expected, atol=1e-15)
        assert np.allclose(DQ.to_matrix(reference.fk(one, [th])), expected, atol=1e-15)


@pytest.mark.parametrize("path", ["ur5-modified-dh.yaml", "ur5-kunze-mm-deg.yaml", "ur5-axis-angle.yaml"])
def test_other_conventions_describe_the_same_ur5(path, rng):
    other = load_robot(DATA / path)
    q = rng.uniform(-math.pi, math.pi, size=(200, 6))
    assert np.allclose(reference.fk(other, q), reference.fk("ur5", q), atol=1e-14)
    assert np.allclose(reference.fk_matrix(other, q), reference.fk_matrix("ur5", q), atol=1e-14)


def test_ur3_thesis_and_ur3_differ_by_one_constant_rotation(rng):
    # Same flange point for every q; R_ur3(q) = R_ur3thesis(q) Rx(pi/2).
    q = rng.uniform(-2 * math.pi, 2 * math.pi, size=(500, 6))
    a = reference.fk_matrix("ur3", q)
    b = reference.fk_matrix("ur3-thesis", q)
    assert np.allclose(a[:, :3, 3], b[:, :3, 3], atol=1e-15)
    rx = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]])
    assert np.allclose(a[:, :3, :3], b[:, :3, :3] @ rx, atol=1e-15)


def test_irb120_tool0_at_zero():
    r = load_robot("irb120")
    assert r.default_end == "tool"
    Q = reference.fk(r, np.zeros(6))
    assert np.allclose(DQ.to_rt(Q)[1], [0.374, 0, 0.630], atol=1e-15)
    assert np.allclose(Q[:4], [0.70711, 0, 0.70711, 0], atol=5e-6)
    lim = np.degrees(r.limits)
    assert np.allclose(lim[:, 1], [165, 110, 70, 160, 120, 400])


def test_irb120_positive_directions():
    # axis 2 positive tilts the upper arm forward (+x); axis 3 positive lowers the forearm
    pos = reference.joint_positions("irb120", np.radians([0, 30, 0, 0, 0, 0]))
    elbow = pos[2]   # frames: base, axis_1 (shoulder point), axis_2 (elbow point), ...
    assert elbow[0] == pytest.approx(0.270 * math.sin(math.radians(30)), abs=1e-15)
    flange = reference.joint_positions("irb120", np.radians([0, 0, 30, 0, 0, 0]))[-1]
    assert flange[2] < 0.630
    # axis 1 positive turns the arm from +x towards +y
    flange = reference.joint_positions("irb120", np.radians([90, 0, 0, 0, 0, 0]))[-1]
    assert np.allclose(flange, [0, 0.374, 0.630], atol=1e-15)


def test_irb1600_zero_pose_is_running_sum_of_table2():
    v = np.array([[0, 150, 481], [0, 0, 700], [0, 314, 0], [0, 286, 0], [0, 42, 0], [0, 23, 0]]) / 1000
    pos = reference.joint_positions("irb1600", np.zeros(6))
    assert np.allclose(pos[1:7], np.cumsum(v, axis=0), atol=1e-15)
    # joint 1 turned 90 degrees about z: every point turns (x, y) -> (-y, x)
    pos90 = reference.joint_positions("irb1600", [math.pi / 2, 0, 0, 0, 0, 0])
    expect = np.cumsum(v, axis=0)[:, [1, 0, 2]] * [-1, 1, 1]
    assert np.allclose(pos90[1:7], expect, atol=1e-15)


def test_irb1600_chain_products_are_unit(rng):
    # seed 001, Figure 8: the absolute quaternions Q'_i stay unit (Q1, Q6 at 45 degrees)
    poses = reference.frame_poses("irb1600", rng.uniform(-3, 3, size=(100, 6)))
    assert np.allclose(np.linalg.norm(poses[..., :4], axis=-1), 1.0, atol=1e-15)
    p45 = reference.frame_poses("irb1600", [math.pi / 4, 0, 0, 0, 0, math.pi / 4])
    assert np.allclose(p45[1, :4], [math.cos(math.pi / 8), 0, 0, math.sin(math.pi / 8)], atol=1e-15)


def test_seed_arm_positions_by_hand():
    r = load_robot("seed-arm")
    assert r.dof == 5 and r.variable_names == ("l1", "t2", "l3", "t4", "t5")
    assert r.frame_names == ("base", "l1", "t2", "l3", "t4", "t5", "t5b", "tcp", "finger_a", "finger_b")
    # all zero but the prismatic columns: a straight arm along x
    p = reference.joint_positions(r, [0.5, 0, 0.25, 0, 0])
    assert np.allclose(p[[1, 2, 3, 4, 7]], [[0, 0, .5], [5, 0, .5], [5.25, 0, .5], [6.25, 0, .5], [8.25, 0, .5]])
    # l1 = 1, t2 = 90 deg, l3 = 2, t4 = 90 deg, t5 = 30 deg:
    # O1 = (0,0,1); O2 = O1 + Rz90 (5,0,0) = (0,5,1); O3 = O2 + Rz90 (2,0,0) = (0,7,1);
    # O4 = O3 + Rz90 Rx90 (1,0,0) = (0,8,1); EF = O4 + (0,2,0) = (0,10,1);
    # finger A: R(-y,30)(2,0,0) = (1.732,0,1) -> Rx90 (1.732,-1,0) -> Rz90 (1,1.732,0)
    p = reference.joint_positions(r, [1, math.pi / 2, 2, math.pi / 2, math.pi / 6])
    s3 = math.sqrt(3)
    assert np.allclose(p[1:5], [[0, 0, 1], [0, 5, 1], [0, 7, 1], [0, 8, 1]], atol=1e-14)
    assert np.allclose(p[7], [0, 10, 1], atol=1e-14)
    assert np.allclose(p[8], [1, 8 + s3, 1], atol=1e-14)
    assert np.allclose(p[9], [-1, 8 + s3, 1], atol=1e-14)
    assert np.allclose(DQ.to_rt(reference.fk(r, [1, math.pi / 2, 2, math.pi / 2, math.pi / 6],
                                             end="finger_b"))[1], p[9], atol=1e-14)


def test_unknown_robot():
    with pytest.raises(UnknownRobotError, match="unknown robot 'ur99'.*ur5"):
        load_robot("ur99")
    with pytest.raises(UnknownRobotError, match="does not exist"):
        load_robot("no/such/file.yaml")


# --- malformed files ---------------------------------------------------------
BASE = {"name": "t", "convention": "standard_dh",
        "joints": [{"name": "j1", "d": 0.1, "a": 0.2, "alpha": "pi/2"}]}


def bad(**changes):
    return {**BASE, **changes}


@pytest.mark.parametrize("data, message", [
    ([1, 2], "top level must be a mapping"),
    ({"name": "t", "joints": BASE["joints"]}, "missing required key 'convention'"),
    (bad(convention="dh"), "convention 'dh' is not one of"),
    (bad(joints=[]), "non-empty list"),
    (bad(joints=[{"name": "j1", "d": 0.1, "alpha": 0}]), "missing key 'a'"),
    (bad(joints=[{"d": 0.1, "a": 0, "alpha": 0}]), "missing or empty 'name'"),
    (bad(joints=[{"name": "j1", "d": 0.1, "a": 0, "alpha": 0, "colour": 1}]), r"unknown key\(s\) \['colour'\]"),
    (bad(joints=[{"name": "j1", "d": 0.1, "a": 0, "alpha": 0}] * 2), "used twice"),
    (bad(joints=[{"name": "j1", "type": "spherical", "d": 0, "a": 0, "alpha": 0}]), "type 'spherical'"),
    (bad(units={"length": "inch"}), "unknown length unit 'inch'"),
    (bad(units={"angle": "grad"}), "unknown angle unit"),
    (bad(joints=[{"name": "j1", "d": 151.9, "a": 0, "alpha": 0}]), "millimetres"),
    (bad(joints=[{"name": "j1", "d": 0.1, "a": 0, "alpha": 90}]), "degrees"),
    (bad(units={"angle": "deg"}), "uses pi but the file's angle unit is deg"),
    (bad(joints=[{"name": "j1", "d": "d9", "a": 0, "alpha": 0}]), "unknown name 'd9'"),
    (bad(joints=[{"name": "j1", "d": "__import__('os')", "a": 0, "alpha": 0}]), "only numbers"),
    (bad(joints=[{"name": "j1", "d": "1/0", "a": 0, "alpha": 0}]), "divides by zero"),
    (bad(joints=[{"name": "j1", "d": [1], "a": 0, "alpha": 0}]), "must be a number"),
    (bad(parameters={"d1": 0.1}), r"parameter\(s\) \['d1'\] are defined but never used"),
    (bad(joints=[{"name": "j1", "d": 0.1, "a": 0, "alpha": 0, "limits": [1, -1]}]), "must be below"),
    (bad(joints=[{"name": "j1", "d": 0.1, "a": 0, "alpha": 0, "limits": [1]}]), r"limits must be \[lower, upper\]"),
    (bad(joints=[{"name": "j1", "d": 0.1, "a": 0, "alpha": 0, "theta": 0.1, "offset": 0.2}]), "not both"),
    (bad(joints=[{"name": "j1", "d": 0.1, "a": 0, "alpha": 0, "parent": "j0"}]), "not an earlier joint"),
    (bad(tool={"translation": [0, 0]}), "list of 3 numbers"),
    (bad(tool={"rotation": {"quaternion": [2, 0, 0, 0]}}), "unit quaternion"),
    (bad(tool={"rotation": {"rpy": [0, 0, 0], "quaternion": [1, 0, 0, 0]}}), "exactly one of"),
    (bad(ends={"tip": {"parent": "j9"}}), "not a joint name"),
    (bad(default_end="tip"), "default_end 'tip'"),
    ({"name": "t", "convention": "axis_angle", "joints": [{"name": "j1", "axis": [0, 0, 0], "link": [0, 0, 1]}]},
     "zero vector"),
    ({"name": "t", "convention": "axis_angle", "joints": [{"name": "j1", "axis": [0, 0, 2], "link": [0, 0, 1]}]},
     "give a unit vector"),
    ({"name": "t", "convention": "axis_angle", "joints": [{"name": "j1", "axis": [0, 0, 1]}]}, "missing key 'link'"),
    ({"name": "t", "convention": "axis_angle", "joints": [
        {"name": "j1", "axis": [0, 0, 1], "link": [0, 0, 1]},
        {"name": "j2", "axis": [0, 0, 1], "link": [0, 0, 1], "mimic": {"joint": "j9"}}]}, "not an independent joint"),
])
def test_malformed_descriptions_raise_robot_file_error(data, message):
    with pytest.raises(RobotFileError, match=message):
        robot_from_dict(data)


def test_invalid_yaml_file(tmp_path):
    p = tmp_path / "broken.yaml"
    p.write_text("name: [unclosed\n")
    with pytest.raises(RobotFileError, match="not valid YAML"):
        load_robot(p)


def test_file_round_trip_and_units(tmp_path):
    # a user file in millimetres and degrees with a prismatic joint, a tool and two ends
    data = {"name": "mine", "convention": "standard_dh", "units": {"length": "mm", "angle": "deg"},
            "joints": [{"name": "lift", "type": "prismatic", "theta": 90, "a": 100, "alpha": 0,
                        "limits": [0, 500]},
                       {"name": "turn", "d": 50, "a": 200, "alpha": 0, "offset": 10}],
            "tool": {"translation": [0, 0, 30], "rotation": {"rpy": [0, 0, 90]}},
            "ends": {"aux": {"parent": "lift", "translation": [10, 0, 0]}}}
    p = tmp_path / "mine.yaml"
    p.write_text(yaml.safe_dump(data))
    r = load_robot(str(p))
    assert r.limits[0].tolist() == pytest.approx([0, 0.5])
    assert r.joints[1].offset == pytest.approx(math.radians(10))
    t = reference.fk_matrix(r, [0.2, math.radians(-10)])
    # lift: Rz(90) Tz(0.2) Tx(0.1): origin (0, 0.1, 0.2), x axis along +y;
    # turn at offset+q = 0: Tz(0.05) Tx(0.2): origin (0, 0.3, 0.25); tool Tz(0.03)
    assert np.allclose(t[:3, 3], [0, 0.3, 0.28], atol=1e-15)
    aux = reference.fk_matrix(r, [0.2, 0], end="aux")
    assert np.allclose(aux[:3, 3], [0, 0.11, 0.2], atol=1e-15)
