"""Reference kinematics: thesis section 4.5, DQ vs matrix on every robot, input errors."""

import math
import re

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import derive
from derive import InputError, reference
from derive import dualquat as DQ
from derive.kinematics.fk import (
    _joint_dq,  # one joint's dual quaternion (not in the facade)
)

HOME = [0, -math.pi / 2, 0, -math.pi / 2, 0, 0]   # thesis section 4.5


def test_thesis_section_4_5_axis_angle_product():
    pair = reference.fk_pair("ur3-thesis", HOME)
    assert np.allclose(pair.q, [0, 0, 1, 0], atol=1e-15)
    assert np.allclose(pair.p, [0, -0.19425, 0.69415], atol=1e-15)
    tcp = DQ.transform_point(reference.fk("ur3-thesis", HOME), [0, -0.2, 0])
    assert np.allclose(tcp, [0, -0.39425, 0.69415], atol=1e-15)


def test_thesis_section_4_5_dh_product():
    Q = reference.fk("ur3", HOME)
    assert np.allclose(Q[:4], [0, 0, math.sqrt(0.5), -math.sqrt(0.5)], atol=1e-15)
    # the DH approach takes the TCP as (0, 0, 0.2) in its own end frame
    assert np.allclose(DQ.transform_point(Q, [0, 0, 0.2]), [0, -0.39425, 0.69415], atol=1e-15)


def test_thesis_section_4_5_per_joint_pairs():
    # the six printed dual quaternions of the record_pose() run, as pairs
    r = derive.load_robot("ur3-thesis")
    expect_p = [(0, 0, .1519), (0, 0, .24365), (-.21325, -.11235, 0), (-.08535, 0, 0), (0, -.0819, 0), (0, 0, 0)]
    expect_q = [(1, 0, 0, 0), (math.sqrt(.5), 0, math.sqrt(.5), 0), (1, 0, 0, 0),
                (math.sqrt(.5), 0, math.sqrt(.5), 0), (1, 0, 0, 0), (1, 0, 0, 0)]
    for i, j in enumerate(r.joints):
        Qi = _joint_dq(j, np.array([HOME[i]]))[0]
        pair = DQ.to_pair(Qi)
        assert np.allclose(pair.q, expect_q[i], atol=1e-15), j.name
        assert np.allclose(pair.p, expect_p[i], atol=1e-15), j.name


@pytest.mark.parametrize("name", derive.list_robots())
def test_dq_and_matrix_paths_agree(name, rng):
    robot = derive.load_robot(name)
    q = rng.uniform(-2 * math.pi, 2 * math.pi, size=(1000, robot.dof))
    for end in robot.ends:
        a = DQ.to_matrix(reference.fk(robot, q, end))
        b = reference.fk_matrix(robot, q, end)
        assert np.max(np.abs(a - b)) < 1e-12, end


@given(st.sampled_from(derive.list_robots()), st.integers(0, 2**32 - 1))
def test_dq_and_matrix_paths_agree_property(name, seed):
    robot = derive.load_robot(name)
    q = np.random.default_rng(seed).uniform(-10, 10, robot.dof)
    assert np.max(np.abs(DQ.to_matrix(reference.fk(robot, q)) - reference.fk_matrix(robot, q))) < 1e-12


def test_fk_results_are_unit_and_canonical(rng):
    q = rng.uniform(-math.pi, math.pi, size=(500, 6))
    Q = reference.fk("ur10", q)
    assert np.allclose(DQ.norm(Q), [1, 0], atol=1e-14)
    lead = Q[np.arange(500), np.argmax(np.abs(Q[:, :4]) > 1e-12, axis=1)]
    assert np.all(lead > 0)


def test_batch_matches_single(rng):
    q = rng.uniform(-3, 3, size=(5, 6))
    batch = reference.fk("ur5e", q)
    assert batch.shape == (5, 8)
    for i in range(5):
        assert np.array_equal(batch[i], reference.fk("ur5e", q[i]))
    assert reference.fk_matrix("ur5e", q).shape == (5, 4, 4)
    assert reference.joint_positions("ur5e", q).shape == (5, 8, 3)
    assert reference.joint_positions("ur5e", q[0]).shape == (8, 3)


def test_joint_positions_end_at_fk(rng):
    for name in derive.list_robots():
        r = derive.load_robot(name)
        q = rng.uniform(-3, 3, r.dof)
        pos = reference.joint_positions(r, q)
        assert pos.shape == (len(r.frame_names), 3)
        assert np.allclose(pos[0], 0)
        for k, end in enumerate(r.ends):
            m = reference.fk_matrix(r, q, end)
            assert np.allclose(pos[1 + len(r.joints) + k], m[:3, 3], atol=1e-14)


def test_pose_error():
    a = reference.fk("ur5", [0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    b = DQ.mul(DQ.translation([0.001, 0, 0]), DQ.mul(a, DQ.rotation([0, 0, 1], 0.01)))
    dp, dr = reference.pose_error(a, b)
    assert dp == pytest.approx(0.001, abs=1e-15) and dr == pytest.approx(0.01, abs=1e-14)


@pytest.mark.parametrize("q, message", [
    ([0, 0, 0], "has 6 joint variables"),
    (np.zeros((2, 5)), "has 6 joint variables"),
    (np.zeros((2, 2, 6)), r"expected shape \(6,\) or \(n, 6\)"),
    ([0, 0, float("nan"), 0, 0, 0], "NaN at index"),
    ([0, 0, 0, float("-inf"), 0, 0], "inf at index"),
    ("abc", "expected a real number, got str"),
    (5.0, "at least 1 dimension"),
])
def test_bad_joint_values(q, message):
    with pytest.raises(InputError, match=message):
        reference.fk("ur5", q)


def test_unknown_end():
    with pytest.raises(InputError, match="not an end frame.*flange"):
        reference.fk("ur5", np.zeros(6), end="tcp")


UR5_Q = np.array([0.3, -1.1, 1.4, -0.2, 0.9, 2.0])


def _robot_file(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return path


_GOOD_JOINTS = "joints:\n  - {name: j1, s: 1, a: 1, alpha: 0}\n"

# (call on tmp_path, exact exception class, standard base class or None, message pattern):
# every bad input raises a DeriveError of the right kind whose message names the problem
BAD_INPUTS = {
    "q of rank 3": (lambda tmp: reference.fk("ur5", np.zeros((2, 2, 6))), InputError, ValueError,
                    r"^q: expected shape \(6,\) or \(n, 6\), got \(2, 2, 6\)$"),
    "q of 3 values": (lambda tmp: reference.fk_matrix("ur5", [0, 0, 0]), InputError, ValueError,
                      r"^q: robot 'ur5' has 6 joint variables \(.*\), got 3$"),
    "q with NaN": (lambda tmp: reference.joint_positions("ur5", [[0] * 6, [0, 0, 0, 0, math.nan, 0]]),
                   InputError, ValueError, r"^q: contains NaN at index \(1, 4\)$"),
    "q with -inf": (lambda tmp: reference.fk_pair("ur5", [0, -math.inf, 0, 0, 0, 0]), InputError,
                    ValueError, r"^q: contains inf at index \(1,\)$"),
    "pose 0.9 x unit": (lambda tmp: reference.ik("ur5", 0.9 * reference.fk("ur5", UR5_Q)), InputError,
                        ValueError, r"^pose: not a unit dual quaternion \(\| \|real\| - 1 \| = 0\.1 > 1e-06\)$"),
    "pose matrix scaled": (lambda tmp: reference.ik("ur5", np.diag([1.1, 1.1, 1.1, 1.0])), InputError,
                           ValueError, r"^pose: the 3x3 block is not a rotation matrix \(max \|R\^T R - I\| = 0\.21\)$"),
    "pose of 7 values": (lambda tmp: reference.ik("ur5", np.zeros(7)), InputError, ValueError,
                         r"^pose: expected a dual quaternion .* got shape \(7,\)$"),
    "unknown end": (lambda tmp: reference.fk("ur5", np.zeros(6), end="tcp"), InputError, ValueError,
                    r"^end 'tcp' is not an end frame of 'ur5'; choose one of \['flange'\]$"),
    "unknown robot": (lambda tmp: reference.fk("ur99", np.zeros(6)), derive.UnknownRobotError,
                      LookupError, r"^unknown robot 'ur99'; the library has: .*\bur5\b"),
    "robot of wrong type": (lambda tmp: derive.load_robot(42), derive.UnknownRobotError, LookupError,
                            r"^robot must be a name or a path, got int$"),
    "missing robot file": (lambda tmp: derive.load_robot(tmp / "nowhere.yaml"), derive.UnknownRobotError,
                           LookupError, r"^robot file '.*nowhere\.yaml' does not exist$"),
    "robot file, unknown key": (
        lambda tmp: derive.load_robot(_robot_file(tmp, "extra.yaml", "name: x\nconvention: kunze\ncolour: red\n"
                                                  + _GOOD_JOINTS)),
        derive.RobotFileError, None, r"^extra\.yaml: unknown key\(s\) \['colour'\]; allowed: "),
    "robot file, missing joints": (
        lambda tmp: derive.load_robot(_robot_file(tmp, "nojoints.yaml", "name: x\nconvention: kunze\n")),
        derive.RobotFileError, None, r"^nojoints\.yaml: missing required key 'joints'$"),
    "robot file, bad YAML": (
        lambda tmp: derive.load_robot(_robot_file(tmp, "broken.yaml", "name: [x\n")),
        derive.RobotFileError, None, r"broken\.yaml: not valid YAML"),
}


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_every_bad_input_raises_a_derive_error_that_names_the_problem(case, tmp_path):
    call, kind, base, message = BAD_INPUTS[case]
    with pytest.raises(derive.DeriveError) as info:       # one except clause catches them all
        call(tmp_path)
    assert type(info.value) is kind, f"{case}: raised {type(info.value).__name__}: {info.value}"
    if base is not None:                                   # and the standard base class, as documented
        assert isinstance(info.value, base)
    assert re.search(message, str(info.value)), f"{case}: message {str(info.value)!r}"
