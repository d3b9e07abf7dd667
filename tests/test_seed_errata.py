"""Seed statements that are wrong as printed: each test shows the correct value
and that the printed form disagrees with it. docs/errata.md lists them."""

import math

import numpy as np

from derive import dualquat as DQ
from derive import load_robot, reference
from derive import quaternion as Q
from derive.kinematics import fk as kin


def test_seed001_eq9_rotation_operator():
    # Printed: w = (q0^2 - |q|^2) v + 2 (q.v) q + 2 q0^2 (q x v); correct: 2 q0 (q x v).
    q = Q.from_axis_angle([1, -2, 0.5], 1.1)
    q0, qv = q[0], q[1:]
    v = np.array([0.4, 0.3, -1.0])
    correct = (q0**2 - qv @ qv) * v + 2 * (qv @ v) * qv + 2 * q0 * np.cross(qv, v)
    printed = (q0**2 - qv @ qv) * v + 2 * (qv @ v) * qv + 2 * q0**2 * np.cross(qv, v)
    assert np.allclose(Q.rotate(q, v), correct, atol=1e-15)
    assert not np.allclose(Q.rotate(q, v), printed, atol=1e-3)


def test_seed002_eq5_35_sign():
    # Printed text form gamma = atan2(1 - 2(p2^2 + p3^2), 2(p1 p2 - p0 p3)) with Mathcad's
    # atan2(x, y) argument order gives +90 deg for the example; the sheet's -2(...) gives -90.
    p0, p1, p2, p3 = reference.fk("kunze-2r", [0, math.pi / 2])[:4]
    x = 1 - 2 * (p2**2 + p3**2)
    printed = math.degrees(math.atan2(2 * (p1 * p2 - p0 * p3), x))
    sheet = math.degrees(math.atan2(-2 * (p1 * p2 - p0 * p3), x))
    assert round(printed) == 90 and round(sheet) == -90
    assert math.degrees(Q.kunze_angles([p0, p1, p2, p3])[2]) == sheet


def test_seed002_mathcad_qs_vector():
    # The sheet defines Qs(s) = [1,0,0,0,0,0,s,s/2]; a translation s along z is
    # [1,0,0,0,0,0,0,s/2] (eq. 5.10), which is what its own Qsa output shows.
    s = 3.0
    assert np.array_equal(DQ.translation([0, 0, s]), [1, 0, 0, 0, 0, 0, 0, s / 2])
    printed = np.array([1, 0, 0, 0, 0, 0, s, s / 2])
    assert not DQ.equal_pose(printed / np.linalg.norm(printed[:4]), DQ.translation([0, 0, s]))


def test_seed004_inverse_of_q5_translation():
    # Section 4.3.3 prints Q5^-1 = ([c5 + s5 k], < d6 i >); by eq. 3.51 the translation of
    # the inverse is -q5^-1 p5 q5 = < d6 j > for every theta5.
    r = load_robot("ur3-thesis")
    d6 = r.parameters["d6"]
    for t5 in (0.0, 0.7, -2.0):
        pair = DQ.to_pair(kin._joint_dq(r.joints[4], np.array([t5]))[0])
        inv = DQ.pair_inv(pair)
        assert np.allclose(inv.p, [0, d6, 0], atol=1e-15)
        assert np.allclose(inv.q, [math.cos(t5 / 2), 0, 0, math.sin(t5 / 2)], atol=1e-15)


def test_seed004_inverse_of_q4_translation():
    # Q4 = ([c4 - s4 j], < d5 s4 i - d5 c4 k >) has the inverse ([c4 + s4 j], < d5 k >).
    r = load_robot("ur3-thesis")
    d5 = r.parameters["d5"]
    for t4 in (0.0, 1.3, -0.4):
        inv = DQ.pair_inv(DQ.to_pair(kin._joint_dq(r.joints[3], np.array([t4]))[0]))
        assert np.allclose(inv.p, [0, 0, d5], atol=1e-15)
        assert np.allclose(inv.q, [math.cos(t4 / 2), 0, math.sin(t4 / 2), 0], atol=1e-15)
