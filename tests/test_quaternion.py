"""Quaternion algebra: seed 000 and thesis examples, conversions, property tests."""

import math

import numpy as np
import pytest
from hypothesis import assume, given
from strategies import quaternions, unit_quaternions, vectors

from derive import InputError
from derive import quaternion as Q

Q1 = np.array([-3.0, 6, 7, -8])   # seed 000, examples 1-3
Q2 = np.array([1.0, 12, -7, -11])
I, J, K = np.array([0.0, 1, 0, 0]), np.array([0.0, 0, 1, 0]), np.array([0.0, 0, 0, 1])
ONE = np.array([1.0, 0, 0, 0])


# --- seed 000 --------------------------------------------------------------
def test_seed000_conjugate():
    assert np.array_equal(Q.conj(Q1), [-3, -6, -7, 8])


def test_seed000_sum():
    assert np.array_equal(Q.add(Q1, Q2), [-2, 18, 0, -19])


def test_seed000_product_components_and_erratum():
    # The seed lists the four components (-3-72+49-88), (-36+6-77-56)i,
    # (21+66+7-96)j, (33-42-84-8)k; the first one sums to -114, not the
    # printed -144 (docs/errata.md, seed 000).
    p = Q.mul(Q1, Q2)
    assert np.array_equal(p, [-114, -163, -2, -101])
    assert -3 - 72 + 49 - 88 == -114
    assert p[0] != -144


def test_seed000_unit_product_table():
    assert np.array_equal(Q.mul(I, J), K) and np.array_equal(Q.mul(J, I), -K)
    assert np.array_equal(Q.mul(J, K), I) and np.array_equal(Q.mul(K, J), -I)
    assert np.array_equal(Q.mul(K, I), J) and np.array_equal(Q.mul(I, K), -J)
    for u in (I, J, K):
        assert np.array_equal(Q.mul(u, u), -ONE)
    assert np.array_equal(Q.mul(Q.mul(I, J), K), -ONE)


def test_seed000_left_and_right_multiplication_by_i():
    w, x, y, z = 2.0, 3.0, 5.0, 7.0
    s = np.array([w, x, y, z])
    assert np.array_equal(Q.mul(I, s), [-x, w, -z, y])
    assert np.array_equal(Q.mul(s, I), [-x, w, z, -y])
    assert np.array_equal(Q.mul(Q.mul(I, s), I), [-w, -x, y, z])
    assert np.array_equal(Q.mul(Q.mul(I, s), -I), [w, x, -y, -z])


def test_thesis_rotation_example():
    # thesis section 3.4.1: (2, 1, 1) turned 90 degrees about z is (-1, 2, 1)
    q = Q.from_axis_angle([0, 0, 1], math.pi / 2)
    assert np.allclose(Q.rotate(q, [2, 1, 1]), [-1, 2, 1], atol=1e-15)


def test_seed000_rotation_formula_matches_explicit_product():
    q = Q.from_axis_angle([1, 2, 2], 0.7)
    v = np.array([0.3, -1.2, 2.0])
    literal = Q.mul(Q.mul(q, np.r_[0.0, v]), Q.conj(q))
    assert abs(literal[0]) < 1e-15
    assert np.allclose(Q.rotate(q, v), literal[1:], atol=1e-14)


# --- conversions -----------------------------------------------------------
def rx(a):
    return np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])


def ry(a):
    return np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])


def rz(a):
    return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])


def test_matrix_of_elementary_rotations():
    for axis, m in ((0, rx), (1, ry), (2, rz)):
        e = np.eye(3)[axis]
        assert np.allclose(Q.to_matrix(Q.from_axis_angle(e, 0.83)), m(0.83), atol=1e-15)


@pytest.mark.parametrize("axis", [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, -1, 1], [0.2, 0.1, -1]])
def test_from_matrix_is_robust_at_half_turns(axis):
    # 180-degree rotations make 1 + tr R = 0: the pivoting must still be exact.
    q = Q.from_axis_angle(axis, math.pi)
    r = Q.to_matrix(q)
    q2 = Q.from_matrix(r)
    assert min(np.max(np.abs(q2 - q)), np.max(np.abs(q2 + q))) < 1e-15
    assert np.allclose(Q.to_matrix(q2), r, atol=1e-15)


@given(unit_quaternions())
def test_matrix_round_trip(q):
    q2 = Q.from_matrix(Q.to_matrix(q))
    assert q2[0] >= 0
    assert min(np.max(np.abs(q2 - q)), np.max(np.abs(q2 + q))) < 1e-13


def test_from_matrix_rejects_non_rotation():
    with pytest.raises(InputError, match="not a rotation matrix"):
        Q.from_matrix(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(InputError, match="not a rotation matrix"):
        Q.from_matrix(2 * np.eye(3))


@given(unit_quaternions())
def test_axis_angle_round_trip(q):
    axis, angle = Q.to_axis_angle(q)
    assert 0 <= angle <= math.pi + 1e-15
    q2 = Q.from_axis_angle(axis, angle)
    assert min(np.max(np.abs(q2 - q)), np.max(np.abs(q2 + q))) < 1e-12


def test_axis_angle_identity_and_small_angle():
    axis, angle = Q.to_axis_angle(ONE)
    assert angle == 0 and np.array_equal(axis, [1, 0, 0])
    axis, angle = Q.to_axis_angle(Q.from_axis_angle([0, 1, 0], 1e-9))
    assert abs(angle - 1e-9) < 1e-22 and np.allclose(axis, [0, 1, 0])


def test_rotation_matrix_matches_rotate(rng):
    qs = rng.normal(size=(50, 4))
    qs /= np.linalg.norm(qs, axis=1, keepdims=True)
    vs = rng.normal(size=(50, 3))
    assert np.allclose(np.einsum("nij,nj->ni", Q.to_matrix(qs), vs), Q.rotate(qs, vs), atol=1e-14)


def test_scalar_last_round_trip():
    q = np.array([0.1, 0.2, 0.3, 0.4])
    assert np.array_equal(Q.to_xyzw(q), [0.2, 0.3, 0.4, 0.1])
    assert np.array_equal(Q.from_xyzw(Q.to_xyzw(q)), q)


# --- orientation angles ----------------------------------------------------
def test_kunze_angles_of_seed002_example():
    # Kunze eq. 5.37-5.38: p = (0, 0.707, 0.707, 0) gives alpha 180, beta 0, gamma -90 degrees
    p = np.array([0.0, math.sqrt(0.5), math.sqrt(0.5), 0.0])
    a, b, g = np.degrees(Q.kunze_angles(p))
    assert a == pytest.approx(180.0, abs=1e-12)
    assert b == pytest.approx(0.0, abs=1e-12)
    assert g == pytest.approx(-90.0, abs=1e-12)


def test_kunze_angles_are_rx_ry_rz(rng):
    for a, b, g in rng.uniform(-1.5, 1.5, size=(20, 3)):
        r = rx(a) @ ry(b) @ rz(g)
        got = Q.kunze_angles(Q.from_matrix(r))
        assert np.allclose(got, (a, b, g), atol=1e-12)
        assert np.allclose(Q.to_matrix(Q.from_kunze_angles(a, b, g)), r, atol=1e-14)


def test_euler_zyx(rng):
    for yaw, pitch, roll in rng.uniform(-1.5, 1.5, size=(20, 3)):
        r = rz(yaw) @ ry(pitch) @ rx(roll)
        assert np.allclose(Q.euler_zyx(Q.from_matrix(r)), (yaw, pitch, roll), atol=1e-12)
        assert np.allclose(Q.to_matrix(Q.from_euler_zyx(yaw, pitch, roll)), r, atol=1e-14)


@pytest.mark.parametrize("pitch", [math.pi / 2, -math.pi / 2])
def test_euler_zyx_gimbal_lock_reproduces_rotation(pitch):
    q = Q.from_euler_zyx(0.4, pitch, 0.3)
    yaw, p, roll = Q.euler_zyx(q)
    assert roll == 0 and abs(p - pitch) < 1e-7
    assert np.allclose(Q.to_matrix(Q.from_euler_zyx(yaw, p, roll)), Q.to_matrix(q), atol=1e-7)


# --- properties ------------------------------------------------------------
@given(quaternions, quaternions, quaternions)
def test_product_is_associative(a, b, c):
    lhs = Q.mul(Q.mul(a, b), c)
    rhs = Q.mul(a, Q.mul(b, c))
    assert np.allclose(lhs, rhs, rtol=1e-12, atol=1e-9)


@given(quaternions, quaternions)
def test_norm_is_multiplicative_and_conjugate_reverses(a, b):
    assert np.isclose(Q.norm(Q.mul(a, b)), Q.norm(a) * Q.norm(b), rtol=1e-12, atol=1e-12)
    assert np.allclose(Q.conj(Q.mul(a, b)), Q.mul(Q.conj(b), Q.conj(a)), rtol=1e-12, atol=1e-10)


@given(quaternions)
def test_inverse(a):
    assume(Q.norm(a) >= 1e-3)
    assert np.allclose(Q.mul(a, Q.inv(a)), [1, 0, 0, 0], atol=1e-12)
    assert np.allclose(Q.mul(Q.inv(a), a), [1, 0, 0, 0], atol=1e-12)


@given(unit_quaternions(), vectors)
def test_rotation_keeps_length(q, v):
    assert np.isclose(np.linalg.norm(Q.rotate(q, v)), np.linalg.norm(v), rtol=1e-12, atol=1e-12)


# --- errors ----------------------------------------------------------------
def test_errors_name_the_problem():
    with pytest.raises(InputError, match="last dimension 4"):
        Q.mul([1, 2, 3], Q2)
    with pytest.raises(InputError, match="NaN"):
        Q.conj([1, float("nan"), 0, 0])
    with pytest.raises(InputError, match="inf"):
        Q.norm([1, float("inf"), 0, 0])
    with pytest.raises(InputError, match="zero quaternion"):
        Q.inv([0, 0, 0, 0])
    with pytest.raises(InputError, match="zero vector"):
        Q.from_axis_angle([0, 0, 0], 1.0)
    with pytest.raises(InputError, match="not a unit quaternion"):
        Q.rotate([2, 0, 0, 0], [1, 0, 0])
    # within 1e-6 of unit: normalised, not an error
    assert np.allclose(Q.rotate([1 + 5e-7, 0, 0, 0], [1, 2, 3]), [1, 2, 3])
