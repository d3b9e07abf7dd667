"""Dual-quaternion algebra on numpy arrays.

Two forms are supported:

* the 8-vector ``[p_w p_x p_y p_z, q_w q_x q_y q_z]`` = p + eps q of Kunze
  (seed 002, eq. 1.7 and 5.17), with the real (primary) part p the rotation
  quaternion and the dual part q = 1/2 t p, t the translation written as a
  pure quaternion (Kunze eq. 4.23). This is the form every API of dq-derive
  returns.
* the thesis's pair form ``(q, p)`` (seed 004, eq. 3.49-3.57): a unit
  rotation quaternion q and a translation 3-vector p, with its own product
  (3.53) and inverse (3.51). :class:`Pair` holds it; :func:`to_pair` and
  :func:`from_pair` convert.

A unit dual quaternion Q maps a point v to the vector part of the dual part of
Q (1 + eps v) Q-hat (Kunze eq. 4.22-4.28): first rotate, then translate.
Products compose like homogeneous matrices: (A B) applied to v equals A applied
to (B applied to v).

Conversions to scalar-last libraries: apply :func:`derive.quaternion.to_xyzw`
to each half (``Q[..., :4]`` and ``Q[..., 4:]``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from derive.algebra import quaternion as quat
from derive.errors import InputError, as_finite_array

#: Tolerance for accepting a dual quaternion as unit (|p| = 1 and <p, q> = 0).
UNIT_TOL = 1e-6

IDENTITY = np.array([1.0, 0, 0, 0, 0, 0, 0, 0])


def _dq(a, name="Q"):
    return as_finite_array(a, name, last_dim=8)


def _pure(v: np.ndarray) -> np.ndarray:
    """The pure quaternion (0, v)."""
    return np.concatenate((np.zeros(v.shape[:-1] + (1,)), v), axis=-1)


# --------------------------------------------------------------------------- #
# Unchecked kernels
# --------------------------------------------------------------------------- #
def _mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(pa + eps qa)(pb + eps qb) = pa pb + eps (pa qb + qa pb)  (Kunze eq. 1.8)."""
    pa, qa = a[..., :4], a[..., 4:]
    pb, qb = b[..., :4], b[..., 4:]
    return np.concatenate((quat._mul(pa, pb), quat._mul(pa, qb) + quat._mul(qa, pb)), axis=-1)


def _from_rt(q: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Rotation q followed by translation t: q + eps 1/2 t q  (Kunze eq. 4.23)."""
    dual = 0.5 * quat._mul(_pure(t), q)
    return np.concatenate((np.broadcast_to(q, dual.shape), dual), axis=-1)


def _translation(a: np.ndarray) -> np.ndarray:
    """t = 2 q p*, vector part (Kunze eq. 4.30)."""
    return 2.0 * quat._mul(a[..., 4:], quat._conj(a[..., :4]))[..., 1:]


def _rotation(axis, angle) -> np.ndarray:
    """Pure rotation about a unit axis through the origin."""
    r = quat._from_axis_angle(np.asarray(axis, dtype=np.float64), angle)
    return np.concatenate((r, np.zeros(r.shape)), axis=-1)


def _translation_dq(t) -> np.ndarray:
    """Pure translation 1 + eps t/2 (Kunze eq. 4.15)."""
    t = np.asarray(t, dtype=np.float64)
    ones = np.ones(t.shape[:-1] + (1,))
    zeros = np.zeros(t.shape[:-1] + (3,))
    return np.concatenate((ones, zeros, np.zeros(t.shape[:-1] + (1,)), 0.5 * t), axis=-1)


# --------------------------------------------------------------------------- #
# Algebra
# --------------------------------------------------------------------------- #
def mul(a, b) -> np.ndarray:
    """Dual-quaternion product a b (Kunze eq. 1.8)."""
    return _mul(_dq(a, "a"), _dq(b, "b"))


def conj_quaternion(a) -> np.ndarray:
    """Quaternion conjugate Q-bar = p-bar + eps q-bar (Kunze eq. 2.2).

    Reverses products: conj(A B) = conj(B) conj(A) (Kunze eq. 2.3).
    """
    a = _dq(a)
    return np.concatenate((quat._conj(a[..., :4]), quat._conj(a[..., 4:])), axis=-1)


def conj_dual(a) -> np.ndarray:
    """Dual conjugate Q-tilde = p - eps q (Kunze eq. 2.18); keeps product order (2.19)."""
    a = _dq(a)
    return np.concatenate((a[..., :4], -a[..., 4:]), axis=-1)


def conj_full(a) -> np.ndarray:
    """Full conjugate Q-hat = p-bar - eps q-bar (Kunze eq. 2.20), used to map points."""
    a = _dq(a)
    return np.concatenate((quat._conj(a[..., :4]), -quat._conj(a[..., 4:])), axis=-1)


def norm(a) -> np.ndarray:
    """Dual-number norm N(Q) = sqrt(p-bar p) + eps <p, q> / sqrt(p-bar p) (Kunze eq. 2.15).

    Returned as an array (..., 2): [real part, dual part]. A unit dual
    quaternion has N(Q) = [1, 0] (Kunze eq. 2.16-2.17).
    """
    a = _dq(a)
    n = np.linalg.norm(a[..., :4], axis=-1)
    if np.any(n == 0.0):
        raise InputError("Q: the real part is zero, the dual-number norm is undefined")
    d = np.sum(a[..., :4] * a[..., 4:], axis=-1) / n
    return np.stack((n, d), axis=-1)


def inv(a) -> np.ndarray:
    """Inverse (p + eps q)^-1 = p^-1 - eps p^-1 q p^-1 (real part non-zero)."""
    a = _dq(a)
    p = a[..., :4]
    n2 = np.sum(p * p, axis=-1, keepdims=True)
    if np.any(n2 == 0.0):
        raise InputError("Q: the real part is zero, the dual quaternion has no inverse")
    pinv = quat._conj(p) / n2
    return np.concatenate((pinv, -quat._mul(quat._mul(pinv, a[..., 4:]), pinv)), axis=-1)


def normalize(a) -> np.ndarray:
    """Q / N(Q): the nearest unit dual quaternion (real part unit, <p, q> = 0)."""
    a = _dq(a)
    p, q = a[..., :4], a[..., 4:]
    n = np.linalg.norm(p, axis=-1, keepdims=True)
    if np.any(n == 0.0):
        raise InputError("Q: the real part is zero and cannot be normalised")
    pq = np.sum(p * q, axis=-1, keepdims=True)
    return np.concatenate((p / n, q / n - p * pq / n**3), axis=-1)


def _unit_one(x: list, tol: float = UNIT_TOL) -> list | None:
    """The fast path of :func:`check_unit` for one dual quaternion given as 8 Python floats:
    the normalised 8 floats when the input is finite and within ``tol`` of unit, else None (the
    caller then runs the array code, which raises the error). The same operations in the same
    order as :func:`check_unit` and :func:`normalize` on an array (1, 8) (numpy's norm and sum
    over 4 entries add from the left onto 0.0, and IEEE arithmetic on Python floats is numpy's),
    so the result is bit for bit the array code's; ``n**3`` is taken by numpy's ``power`` as
    there (a vectorised pow may round differently from the C library's)."""
    if not math.isfinite(sum(x)):        # NaN, inf (or an overflowing sum): the array code decides
        return None
    p0, p1, p2, p3, q0, q1, q2, q3 = x
    n = math.sqrt(0.0 + p0 * p0 + p1 * p1 + p2 * p2 + p3 * p3)
    qn = math.sqrt(0.0 + q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    pq = 0.0 + p0 * q0 + p1 * q1 + p2 * q2 + p3 * q3
    if not (abs(n - 1.0) <= tol and qn != math.inf and abs(pq) / max(1.0, qn) <= tol):
        return None
    n3 = float(np.power(n, 3))
    return [p0 / n, p1 / n, p2 / n, p3 / n,
            q0 / n - p0 * pq / n3, q1 / n - p1 * pq / n3, q2 / n - p2 * pq / n3, q3 / n - p3 * pq / n3]


def _from_matrix_one(m: list) -> list | None:
    """The fast path of the matrix input of :func:`derive.kinematics.pose.as_pose_batch` for one
    pose, rows ``m`` (4 lists of 4 Python floats): the unit dual quaternion (8 floats) of
    :func:`from_matrix` when the matrix is finite, its rotation block clearly orthonormal (max
    |R^T R - I| below 0.999e-6, det > 0.5) and its last row (0, 0, 0, 1) within 1e-9, else None
    (the caller then runs the array code, which raises its error). Shepperd's pivot, the sign, the
    norm and the product t q are :func:`derive.algebra.quaternion.from_matrix` and
    :func:`_from_rt` operation for operation, so the result is bit for bit theirs."""
    (r11, r12, r13, t0), (r21, r22, r23, t1), (r31, r32, r33, t2), bottom = m
    if not math.isfinite(sum(m[0]) + sum(m[1]) + sum(m[2]) + sum(bottom)):
        return None
    if (abs(bottom[0]) > 1e-9 or abs(bottom[1]) > 1e-9 or abs(bottom[2]) > 1e-9
            or abs(bottom[3] - 1.0) > 1e-9):
        return None
    c1, c2, c3 = (r11, r21, r31), (r12, r22, r32), (r13, r23, r33)       # columns of R
    err = max(abs(c1[0] * c1[0] + c1[1] * c1[1] + c1[2] * c1[2] - 1.0),
              abs(c2[0] * c2[0] + c2[1] * c2[1] + c2[2] * c2[2] - 1.0),
              abs(c3[0] * c3[0] + c3[1] * c3[1] + c3[2] * c3[2] - 1.0),
              abs(c1[0] * c2[0] + c1[1] * c2[1] + c1[2] * c2[2]),
              abs(c1[0] * c3[0] + c1[1] * c3[1] + c1[2] * c3[2]),
              abs(c2[0] * c3[0] + c2[1] * c3[1] + c2[2] * c3[2]))
    det = (r11 * (r22 * r33 - r23 * r32) - r12 * (r21 * r33 - r23 * r31)
           + r13 * (r21 * r32 - r22 * r31))
    if not (err < 0.999e-6 and det > 0.5):
        return None
    tr = r11 + r22 + r33
    piv = (1 + tr, 1 + 2 * r11 - tr, 1 + 2 * r22 - tr, 1 + 2 * r33 - tr)
    k = max(range(4), key=piv.__getitem__)          # the first largest, as np.argmax
    s = math.sqrt(piv[k])
    h = 0.5 / s
    if k == 0:
        q = [0.5 * s, (r32 - r23) * h, (r13 - r31) * h, (r21 - r12) * h]
    elif k == 1:
        q = [(r32 - r23) * h, 0.5 * s, (r12 + r21) * h, (r13 + r31) * h]
    elif k == 2:
        q = [(r13 - r31) * h, (r12 + r21) * h, 0.5 * s, (r23 + r32) * h]
    else:
        q = [(r21 - r12) * h, (r13 + r31) * h, (r23 + r32) * h, 0.5 * s]
    if q[0] < 0.0:
        q = [-v for v in q]
    n = math.sqrt(0.0 + q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    q = [v / n for v in q]
    dual = quat.hamilton((0.0, t0, t1, t2), q)
    return q + [0.5 * v for v in dual]


def check_unit(a, name: str = "pose", tol: float = UNIT_TOL) -> np.ndarray:
    """Return a normalised copy of a unit dual quaternion, or raise InputError.

    Accepted when | |p| - 1 | <= tol and |<p, q>| <= tol (relative to the
    translation size); anything farther from unit is an error rather than
    silently rescaled.
    """
    if type(a) is np.ndarray and a.dtype == np.float64 and a.shape in ((8,), (1, 8)):
        out = _unit_one(a.ravel().tolist(), tol)       # one pose: the same numbers, fewer steps
        if out is not None:
            return np.array(out).reshape(a.shape)
    a = _dq(a, name)
    p, q = a[..., :4], a[..., 4:]
    dev_n = np.abs(np.linalg.norm(p, axis=-1) - 1.0)
    with np.errstate(over="ignore"):     # an overflow is reported below
        qn = np.linalg.norm(q, axis=-1)
    scale = np.maximum(1.0, qn)
    dev_o = np.abs(np.sum(p * q, axis=-1)) / scale
    if np.any(dev_n > tol):
        raise InputError(f"{name}: not a unit dual quaternion (| |real| - 1 | = "
                         f"{float(np.max(dev_n)):.3g} > {tol:g})")
    if np.any(np.isinf(qn)):      # finite values whose squares overflow: no orthogonality test
        raise InputError(f"{name}: not a unit dual quaternion (the squares of its dual part overflow)")
    if np.any(dev_o > tol):
        raise InputError(f"{name}: not a unit dual quaternion (<real, dual> = "
                         f"{float(np.max(dev_o)):.3g}, must be 0 within {tol:g})")
    return normalize(a)


# --------------------------------------------------------------------------- #
# Construction and conversion
# --------------------------------------------------------------------------- #
def from_rt(q, t) -> np.ndarray:
    """Unit dual quaternion of rotation q followed by translation t (Kunze eq. 4.23)."""
    q = quat.check_unit(q, "q")
    t = as_finite_array(t, "t", last_dim=3)
    return _from_rt(q, t)


def to_rt(a) -> tuple[np.ndarray, np.ndarray]:
    """(rotation quaternion, translation vector) of a unit dual quaternion."""
    a = check_unit(a, "Q")
    return a[..., :4].copy(), _translation(a)


def rotation(axis, angle) -> np.ndarray:
    """Pure rotation by ``angle`` about ``axis`` through the origin (Kunze eq. 4.6)."""
    q = quat.from_axis_angle(axis, angle)
    return np.concatenate((q, np.zeros(q.shape)), axis=-1)


def translation(t) -> np.ndarray:
    """Pure translation 1 + eps t/2 (Kunze eq. 4.15)."""
    return _translation_dq(as_finite_array(t, "t", last_dim=3))


def transform_point(a, v) -> np.ndarray:
    """Map the point v by the unit dual quaternion Q: Q (1 + eps v) Q-hat (Kunze eq. 4.22).

    Evaluated literally through the product and the full conjugation; the
    result's dual vector part is the transformed point (Kunze eq. 4.27).
    """
    a = check_unit(a, "Q")
    v = as_finite_array(v, "v", last_dim=3)
    point = np.concatenate((np.ones(v.shape[:-1] + (1,)), np.zeros(v.shape[:-1] + (3,)),
                            _pure(v)), axis=-1)
    hat = np.concatenate((quat._conj(a[..., :4]), -quat._conj(a[..., 4:])), axis=-1)
    return _mul(_mul(a, point), hat)[..., 5:]


def tidy(d) -> np.ndarray:
    """A unit dual quaternion (8,) with its rotation and translation rounded to 1e-13 (the
    noise of a numeric construction), the real part's first non-zero entry positive."""
    r, t = to_rt(d)
    r = np.round(r, 13)
    r = r / np.linalg.norm(r)
    lead = r[np.argmax(np.abs(r) > 0)]
    return from_rt(r if lead > 0 else -r, np.round(t, 13) + 0.0)


def to_matrix(a) -> np.ndarray:
    """4x4 homogeneous matrix of a unit dual quaternion."""
    a = check_unit(a, "Q")
    m = np.zeros(a.shape[:-1] + (4, 4))
    m[..., :3, :3] = quat._to_matrix(a[..., :4])
    m[..., :3, 3] = _translation(a)
    m[..., 3, 3] = 1.0
    return m


def from_matrix(m) -> np.ndarray:
    """Unit dual quaternion (real part with w >= 0) of a 4x4 homogeneous matrix."""
    m = as_finite_array(m, "T", ndim_min=2)
    if m.shape[-2:] != (4, 4):
        raise InputError(f"T: expected shape (..., 4, 4), got {m.shape}")
    bottom = m[..., 3, :]
    if np.any(np.abs(bottom - np.array([0.0, 0.0, 0.0, 1.0])) > 1e-9):
        raise InputError("T: the last row of a homogeneous matrix must be (0, 0, 0, 1)")
    return _from_rt(quat.from_matrix(m[..., :3, :3]), m[..., :3, 3])


def equal_pose(a, b, tol: float = 1e-9) -> np.ndarray:
    """True where a and b are the same rigid transform (Q and -Q are the same pose)."""
    a, b = _dq(a, "a"), _dq(b, "b")
    d1 = np.max(np.abs(a - b), axis=-1)
    d2 = np.max(np.abs(a + b), axis=-1)
    return np.minimum(d1, d2) <= tol


# --------------------------------------------------------------------------- #
# The thesis's pair form (q, p)
# --------------------------------------------------------------------------- #
class Pair(NamedTuple):
    """Dual quaternion as the thesis's pair ([w, <a, b, c>], <x, y, z>) (eq. 3.49).

    ``q`` is the unit rotation quaternion (..., 4), ``p`` the translation (..., 3).
    """

    q: np.ndarray
    p: np.ndarray


def to_pair(a) -> Pair:
    """Pair form (q, p) of a unit dual quaternion: q = real part, p = translation."""
    q, t = to_rt(a)
    return Pair(q, t)


def from_pair(pair) -> np.ndarray:
    """8-vector of a pair (q, p): q + eps 1/2 p q."""
    q, p = pair
    return from_rt(q, p)


def pair_mul(a, b) -> Pair:
    """Thesis eq. 3.53: (q1, p1)(q2, p2) = (q1 q2, q1 p2 q1^-1 + p1).

    The second translation is first rotated by the first rotation and then
    added (eq. 3.54).
    """
    q1 = quat.check_unit(a[0], "q1")
    q2 = quat.check_unit(b[0], "q2")
    p1 = as_finite_array(a[1], "p1", last_dim=3)
    p2 = as_finite_array(b[1], "p2", last_dim=3)
    return Pair(quat._mul(q1, q2), quat._rotate(q1, p2) + p1)


def pair_inv(a) -> Pair:
    """Thesis eq. 3.51: (q, p)^-1 = (q^-1, -q^-1 p q)."""
    q = quat.check_unit(a[0], "q")
    p = as_finite_array(a[1], "p", last_dim=3)
    qi = quat._conj(q)
    return Pair(qi, -quat._rotate(qi, p))


def pair_transform_point(a, v) -> np.ndarray:
    """Thesis eq. 3.57: v' = q v q^-1 + p."""
    q = quat.check_unit(a[0], "q")
    p = as_finite_array(a[1], "p", last_dim=3)
    return quat._rotate(q, as_finite_array(v, "v", last_dim=3)) + p
