"""Dual-quaternion algebra: seed 002 (Kunze) examples and identities, the thesis pair form."""

import math

import numpy as np
import pytest
from hypothesis import assume, given
from strategies import dual_quaternions, unit_dual_quaternions, vectors

from derive import InputError, reference
from derive import dualquat as DQ
from derive import quaternion as Q

S = math.sqrt(0.5)


def qdh(theta, s, a, alpha):
    """Kunze eq. 5.13 written out component by component (the printed column form)."""
    ct, st, ca, sa = math.cos(theta / 2), math.sin(theta / 2), math.cos(alpha / 2), math.sin(alpha / 2)
    return np.array([
        ca * ct, sa * ct, sa * st, ca * st,
        -0.5 * a * sa * ct - 0.5 * s * ca * st,
        0.5 * a * ca * ct - 0.5 * s * sa * st,
        0.5 * a * ca * st + 0.5 * s * sa * ct,
        -0.5 * a * sa * st + 0.5 * s * ca * ct,
    ])


def split(a):
    return a[:4], a[4:]


# --- seed 002 worked example -------------------------------------------------
def test_kunze_eq_5_13_matches_the_product_of_eq_5_7(rng):
    for theta, s, a, alpha in rng.uniform(-3, 3, size=(20, 4)):
        prod = DQ.mul(DQ.mul(DQ.rotation([0, 0, 1], theta), DQ.translation([0, 0, s])),
                      DQ.mul(DQ.translation([a, 0, 0]), DQ.rotation([1, 0, 0], alpha)))
        assert np.allclose(prod, qdh(theta, s, a, alpha), atol=1e-15)


def test_seed002_qdh01_qdh12_qdh02():
    q01 = reference.frame_poses("kunze-2r", [0, math.pi / 2])
    base, f1, f2 = q01[0], q01[1], q01[2]
    assert np.array_equal(base, DQ.IDENTITY)
    assert np.allclose(f1, [1, 0, 0, 0, 0, 0.5, 0, 1.5], atol=1e-15)          # QDH01
    qdh12 = qdh(math.pi / 2, 0, 3, math.pi)
    assert np.allclose(qdh12, [0, S, S, 0, -1.5 * S, 0, 0, -1.5 * S], atol=1e-15)  # QDH12 (-1.061)
    assert np.allclose(f2, DQ.mul(f1, qdh12), atol=1e-15)
    assert np.allclose(f2, [0, S, S, 0, -2 * S, -1.5 * S, 1.5 * S, -S], atol=1e-15)
    # the printed QDH02 to three decimals
    assert np.allclose(f2, [0, 0.707, 0.707, 0, -1.414, -1.061, 1.061, -0.707], atol=6e-4)


def test_seed002_points():
    f1, f2 = reference.frame_poses("kunze-2r", [0, math.pi / 2])[1:3]
    assert np.allclose(DQ.transform_point(f1, [0, 0, 0]), [1, 0, 3], atol=1e-15)   # o1
    assert np.allclose(DQ.transform_point(f1, [1, 0, 0]), [2, 0, 3], atol=1e-15)   # ex1
    assert np.allclose(DQ.transform_point(f1, [0, 1, 0]), [1, 1, 3], atol=1e-15)   # ey1
    assert np.allclose(DQ.transform_point(f1, [0, 0, 1]), [1, 0, 4], atol=1e-15)   # ez1
    assert np.allclose(DQ.transform_point(f2, [0, 0, 0]), [1, 3, 3], atol=1e-15)   # o2
    assert np.allclose(DQ.transform_point(f2, [0, 0, 1]), [1, 3, 2], atol=1e-15)   # ez2


def test_seed002_orientation_angles():
    f2 = reference.fk("kunze-2r", [0, math.pi / 2])
    a, b, g = np.degrees(Q.kunze_angles(f2[:4]))
    assert (a, b, g) == pytest.approx((180.0, 0.0, -90.0), abs=1e-12)


def test_translation_extraction_eq_4_30():
    # Q_T Q_R Q-hat_R Q-hat_T = 1 + eps b (Kunze eq. 4.30)
    q = DQ.from_rt(Q.from_axis_angle([1, 2, 3], 0.4), [0.5, -1, 2])
    prod = DQ.mul(q, DQ.conj_full(q))
    assert np.allclose(prod, [1, 0, 0, 0, 0, 0.5, -1, 2], atol=1e-15)


def test_rotate_then_translate_vs_translate_then_rotate():
    # Kunze 4.28 vs 4.35: the order matters, except on a common axis (4.37)
    r = DQ.rotation([0, 0, 1], math.pi / 2)
    t = DQ.translation([1, 0, 0])
    v = [1, 0, 0]
    assert np.allclose(DQ.transform_point(DQ.mul(t, r), v), [1, 1, 0], atol=1e-15)
    assert np.allclose(DQ.transform_point(DQ.mul(r, t), v), [0, 2, 0], atol=1e-15)
    tz = DQ.translation([0, 0, 2])
    assert np.allclose(DQ.mul(tz, r), DQ.mul(r, tz), atol=1e-15)


# --- the identity table of seed 002, section 3 ------------------------------
def _pure_vec(x):
    return np.r_[0.0, x]


@given(dual_quaternions, dual_quaternions)
def test_conjugations_of_products(a, b):
    # 2.3: quaternion conjugation reverses; 2.19: dual conjugation keeps the order;
    # the full conjugation (2.20) reverses like the quaternion one.
    ab = DQ.mul(a, b)
    tol = dict(rtol=1e-12, atol=1e-9)
    assert np.allclose(DQ.conj_quaternion(ab), DQ.mul(DQ.conj_quaternion(b), DQ.conj_quaternion(a)), **tol)
    assert np.allclose(DQ.conj_dual(ab), DQ.mul(DQ.conj_dual(a), DQ.conj_dual(b)), **tol)
    assert np.allclose(DQ.conj_full(ab), DQ.mul(DQ.conj_full(b), DQ.conj_full(a)), **tol)


@given(dual_quaternions)
def test_products_with_own_conjugates(a):
    p, q = split(a)
    p0, pv, q0, qv = p[0], p[1:], q[0], q[1:]
    tol = dict(rtol=1e-12, atol=1e-9)
    # 2.13: Q Q-bar = Q-bar Q = p-bar p + 2 eps <p, q>
    qqbar = DQ.mul(a, DQ.conj_quaternion(a))
    assert np.allclose(qqbar, DQ.mul(DQ.conj_quaternion(a), a), **tol)
    assert np.allclose(qqbar, [p @ p, 0, 0, 0, 2 * (p @ q), 0, 0, 0], **tol)
    # 2.27: Q Q-hat = p p-bar + 2 eps [(p0 q - q0 p) + p x q]
    qqhat = DQ.mul(a, DQ.conj_full(a))
    assert np.allclose(qqhat, np.r_[p @ p, 0, 0, 0, _pure_vec(2 * (p0 * qv - q0 * pv + np.cross(pv, qv)))], **tol)
    # 2.34: Q Q-tilde = p0^2 - <p, p> + 2 p0 p + 2 eps q x p
    qqtil = DQ.mul(a, DQ.conj_dual(a))
    assert np.allclose(qqtil, np.r_[p0 * p0 - pv @ pv, 2 * p0 * pv, _pure_vec(2 * np.cross(qv, pv))], **tol)
    # 2.28: Q-tilde Q has the opposite dual part
    til_q = DQ.mul(DQ.conj_dual(a), a)
    assert np.allclose(til_q[:4], qqtil[:4], **tol) and np.allclose(til_q[4:], -qqtil[4:], **tol)


@given(dual_quaternions)
def test_dual_number_norm(a):
    p, q = split(a)
    assume(np.linalg.norm(p) >= 1e-3)
    n = DQ.norm(a)
    # 2.15: N(Q)^2 = Q Q-bar as a dual number: (n0 + eps n1)^2 = n0^2 + eps 2 n0 n1
    assert np.isclose(n[0] ** 2, p @ p, rtol=1e-12)
    assert np.isclose(2 * n[0] * n[1], 2 * (p @ q), rtol=1e-12, atol=1e-9)


@given(unit_dual_quaternions())
def test_unit_dq_has_unit_norm_and_inverse_is_quaternion_conjugate(a):
    assert np.allclose(DQ.norm(a), [1, 0], atol=1e-12)
    assert np.allclose(DQ.inv(a), DQ.conj_quaternion(a), atol=1e-12)


@given(dual_quaternions)
def test_inverse(a):
    assume(np.linalg.norm(a[:4]) >= 1e-2)
    assert np.allclose(DQ.mul(a, DQ.inv(a)), DQ.IDENTITY, atol=1e-9)
    assert np.allclose(DQ.mul(DQ.inv(a), a), DQ.IDENTITY, atol=1e-9)


@given(dual_quaternions, dual_quaternions, dual_quaternions)
def test_product_is_associative(a, b, c):
    assert np.allclose(DQ.mul(DQ.mul(a, b), c), DQ.mul(a, DQ.mul(b, c)), rtol=1e-12, atol=1e-7)


@given(unit_dual_quaternions(), unit_dual_quaternions())
def test_norm_is_multiplicative_for_unit(a, b):
    assert np.allclose(DQ.norm(DQ.mul(a, b)), [1, 0], atol=1e-12)


# --- conversions -------------------------------------------------------------
@given(unit_dual_quaternions(), vectors)
def test_point_transform_matrix_and_pair_agree(a, v):
    m = DQ.to_matrix(a)
    by_matrix = m[:3, :3] @ v + m[:3, 3]
    assert np.allclose(DQ.transform_point(a, v), by_matrix, atol=1e-11)
    assert np.allclose(DQ.pair_transform_point(DQ.to_pair(a), v), by_matrix, atol=1e-11)


@given(unit_dual_quaternions())
def test_matrix_round_trip(a):
    b = DQ.from_matrix(DQ.to_matrix(a))
    assert DQ.equal_pose(a, b, tol=1e-12)


@given(unit_dual_quaternions(), unit_dual_quaternions())
def test_pair_form_product_and_inverse_agree_with_8_vector(a, b):
    # thesis 3.53 and 3.51 against Kunze 1.8 and the DQ inverse
    pa, pb = DQ.to_pair(a), DQ.to_pair(b)
    prod = DQ.pair_mul(pa, pb)
    ab = DQ.mul(a, b)
    assert np.allclose(prod.q, ab[:4], atol=1e-12)
    assert np.allclose(prod.p, DQ.to_rt(ab)[1], atol=1e-11)
    assert DQ.equal_pose(DQ.from_pair(prod), ab, tol=1e-11)
    inv = DQ.pair_inv(pa)
    assert DQ.equal_pose(DQ.from_pair(inv), DQ.inv(a), tol=1e-11)
    # composing with the inverse gives the identity pair
    ident = DQ.pair_mul(pa, inv)
    assert np.allclose(ident.q, [1, 0, 0, 0], atol=1e-12) and np.allclose(ident.p, 0, atol=1e-11)


def test_pair_form_conversions_round_trip():
    q = Q.from_axis_angle([0, -1, 0], 0.3)
    p = np.array([0.1, -0.2, 0.3])
    a = DQ.from_pair((q, p))
    back = DQ.to_pair(a)
    assert np.allclose(back.q, q) and np.allclose(back.p, p)
    assert np.allclose(a[4:], 0.5 * Q.mul(np.r_[0, p], q))   # dual = 1/2 t real


def test_batched_product_matches_loop(rng):
    from conftest import random_unit_dq
    a, b = random_unit_dq(rng, 7), random_unit_dq(rng, 7)
    batch = DQ.mul(a, b)
    for i in range(7):
        assert np.array_equal(batch[i], DQ.mul(a[i], b[i]))


# --- errors ------------------------------------------------------------------
def test_errors_name_the_problem():
    with pytest.raises(InputError, match="last dimension 8"):
        DQ.mul(np.zeros(7), DQ.IDENTITY)
    with pytest.raises(InputError, match="NaN"):
        DQ.conj_full([1, 0, 0, 0, 0, float("nan"), 0, 0])
    with pytest.raises(InputError, match="not a unit dual quaternion"):
        DQ.to_matrix([2, 0, 0, 0, 0, 0, 0, 0])
    with pytest.raises(InputError, match="<real, dual>"):
        DQ.to_matrix([1, 0, 0, 0, 0.5, 0, 0, 0])
    with pytest.raises(InputError, match="no inverse"):
        DQ.inv(np.r_[np.zeros(4), 1, 0, 0, 0])
    with pytest.raises(InputError, match=r"\(0, 0, 0, 1\)"):
        DQ.from_matrix(np.ones((4, 4)))
    # close to unit (within 1e-6): normalised, not rejected
    near = DQ.IDENTITY * (1 + 4e-7)
    assert np.allclose(DQ.to_matrix(near), np.eye(4))
