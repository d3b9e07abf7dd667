"""Quaternion algebra on numpy arrays, scalar-first (w, x, y, z).

Every function accepts a single quaternion of shape (4,) or a batch of shape
(..., 4) and broadcasts over the leading axes. The public functions check their
input (shape, NaN, inf) and raise :class:`derive.errors.InputError`; the
functions whose name starts with an underscore skip the checks and are meant
for inner loops that already validated their data.

Scalar-last libraries: scipy's ``Rotation.from_quat`` and ROS
``geometry_msgs/Quaternion`` store (x, y, z, w). Use :func:`to_xyzw` and
:func:`from_xyzw` at that boundary.

References: seed 000 (product table, conjugate, sum), Kunze eq. 1.9-1.15
(product), 2.1 (conjugate), 2.15 (norm), 4.1-4.2 (rotation of a vector),
5.32 (rotation matrix), 5.33-5.35 (orientation angles); thesis eq. 3.42-3.48
(matrix and axis-angle conversions).
"""

from __future__ import annotations

import numpy as np

from derive.algebra.angles import wrap_angle
from derive.errors import InputError, as_finite_array

#: Tolerance on |q| - 1 under which a quaternion is accepted as unit without comment.
UNIT_TOL = 1e-6

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def _q(q, name="q"):
    return as_finite_array(q, name, last_dim=4)


def _v(v, name="v"):
    return as_finite_array(v, name, last_dim=3)


# --------------------------------------------------------------------------- #
# Unchecked kernels
# --------------------------------------------------------------------------- #
def hamilton(a, b) -> tuple:
    """Hamilton product of two quaternions given as 4-sequences of scalars.

    The single statement of the product rule (seed 000 product table; Kunze
    eq. 1.15), shared by the numpy kernels (components are arrays) and the
    symbolic derivation (components are sympy expressions).
    """
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def dual_hamilton(a, b) -> tuple:
    """Product of two dual quaternions given as 8-sequences [real w x y z, dual w x y z] of
    scalars (real a_r b_r, dual a_r b_d + a_d b_r; Kunze eq. 1.8), for symbolic and CasADi
    components alike."""
    real = hamilton(a[:4], b[:4])
    d1, d2 = hamilton(a[:4], b[4:]), hamilton(a[4:], b[:4])
    return tuple(real) + tuple(x + y for x, y in zip(d1, d2))


#: From this many numbers in an operand on, :func:`_mul` of float64 arrays takes the path of
#: contiguous components and in-place operations (:func:`_mul_large`).
_LARGE = 4096


def _mul_large(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`hamilton` on large float64 arrays (..., 4): the same operations in the same order
    (so the same bits), on contiguous copies of the components and into preallocated rows,
    instead of strided components and a temporary per operation."""
    ac = np.ascontiguousarray(np.moveaxis(a, -1, 0))
    bc = np.ascontiguousarray(np.moveaxis(b, -1, 0))
    aw, ax, ay, az = ac
    bw, bx, by, bz = bc
    shape = np.broadcast_shapes(a.shape[:-1], b.shape[:-1])
    res = np.empty((4,) + shape)
    tmp = np.empty(shape)
    # w = aw bw - ax bx - ay by - az bz, x = aw bx + ax bw + ay bz - az by,
    # y = aw by - ax bz + ay bw + az bx, z = aw bz + ax by - ay bx + az bw (left to right)
    for r, terms in zip(res, (((aw, bw), (ax, bx, np.subtract), (ay, by, np.subtract), (az, bz, np.subtract)),
                              ((aw, bx), (ax, bw, np.add), (ay, bz, np.add), (az, by, np.subtract)),
                              ((aw, by), (ax, bz, np.subtract), (ay, bw, np.add), (az, bx, np.add)),
                              ((aw, bz), (ax, by, np.add), (ay, bx, np.subtract), (az, bw, np.add)))):
        np.multiply(*terms[0], out=r)
        for u, v, op in terms[1:]:
            np.multiply(u, v, out=tmp)
            op(r, tmp, out=r)
    return np.ascontiguousarray(np.moveaxis(res, 0, -1))


def _mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a b on arrays (..., 4)."""
    a, b = np.asanyarray(a), np.asanyarray(b)
    if a.dtype == np.float64 and b.dtype == np.float64 and max(a.size, b.size) >= _LARGE:
        return _mul_large(a, b)
    w, x, y, z = hamilton((a[..., 0], a[..., 1], a[..., 2], a[..., 3]),
                          (b[..., 0], b[..., 1], b[..., 2], b[..., 3]))
    # the four components written into one array: what np.stack(..., axis=-1) makes, without
    # its overhead (and that of moving the axes), which dominates for a few poses
    out = np.empty(np.shape(w) + (4,), dtype=np.result_type(w, x, y, z))
    out[..., 0], out[..., 1], out[..., 2], out[..., 3] = w, x, y, z
    return out


def _conj(q: np.ndarray) -> np.ndarray:
    out = np.array(q, dtype=np.float64, copy=True)
    out[..., 1:] *= -1.0
    return out


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vector part of q (0, v) q* for a unit q (Kunze eq. 4.1)."""
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def _to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion (Kunze eq. 5.32)."""
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    r = np.empty(q.shape[:-1] + (3, 3))
    r[..., 0, 0] = 1 - 2 * (y * y + z * z)
    r[..., 0, 1] = 2 * (x * y - w * z)
    r[..., 0, 2] = 2 * (x * z + w * y)
    r[..., 1, 0] = 2 * (x * y + w * z)
    r[..., 1, 1] = 1 - 2 * (x * x + z * z)
    r[..., 1, 2] = 2 * (y * z - w * x)
    r[..., 2, 0] = 2 * (x * z - w * y)
    r[..., 2, 1] = 2 * (y * z + w * x)
    r[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return r


def _from_axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """cos(angle/2) + sin(angle/2) n for a unit axis n (thesis eq. 3.46)."""
    half = 0.5 * np.asarray(angle, dtype=np.float64)
    s = np.sin(half)[..., None]
    return np.concatenate((np.cos(half)[..., None], s * axis), axis=-1)


# --------------------------------------------------------------------------- #
# Algebra
# --------------------------------------------------------------------------- #
def add(a, b) -> np.ndarray:
    """Component-wise sum a + b (seed 000, 'Suma')."""
    return _q(a, "a") + _q(b, "b")


def mul(a, b) -> np.ndarray:
    """Hamilton product a b; not commutative (seed 000, 'Producto')."""
    return _mul(_q(a, "a"), _q(b, "b"))


def conj(q) -> np.ndarray:
    """Conjugate w - xi - yj - zk (Kunze eq. 2.1)."""
    return _conj(_q(q))


def dot(a, b) -> np.ndarray:
    """Scalar product <a, b> = w_a w_b + x_a x_b + y_a y_b + z_a z_b (Kunze eq. 2.12)."""
    return np.sum(_q(a, "a") * _q(b, "b"), axis=-1)


def norm(q) -> np.ndarray:
    """Norm sqrt(q q*) (Kunze eq. 2.15)."""
    return np.linalg.norm(_q(q), axis=-1)


def inv(q) -> np.ndarray:
    """Inverse q* / |q|^2; raises for a zero quaternion."""
    q = _q(q)
    n2 = np.sum(q * q, axis=-1, keepdims=True)
    if np.any(n2 == 0.0):
        raise InputError("q: the zero quaternion has no inverse")
    return _conj(q) / n2


def normalize(q) -> np.ndarray:
    """q / |q|; raises for a zero quaternion."""
    q = _q(q)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(n == 0.0):
        raise InputError("q: the zero quaternion cannot be normalised")
    return q / n


def check_unit(q, name: str = "q", tol: float = UNIT_TOL) -> np.ndarray:
    """Return q normalised if | |q| - 1 | <= tol, raise InputError otherwise."""
    q = _q(q, name)
    n = np.linalg.norm(q, axis=-1)
    dev = np.abs(n - 1.0)
    if np.any(dev > tol):
        worst = float(np.max(dev))
        raise InputError(f"{name}: not a unit quaternion (| |q| - 1 | = {worst:.3g} > {tol:g})")
    return q / n[..., None]


def rotate(q, v) -> np.ndarray:
    """Rotate the vector v by the unit quaternion q: vector part of q (0, v) q*.

    Kunze eq. 4.1 / seed 000 'O = Q (0, r) Q~'. q is normalised first when it is
    within :data:`UNIT_TOL` of unit length; otherwise InputError.
    """
    return _rotate(check_unit(q), _v(v))


# --------------------------------------------------------------------------- #
# Conversions
# --------------------------------------------------------------------------- #
def from_axis_angle(axis, angle) -> np.ndarray:
    """Unit quaternion of a rotation by ``angle`` (rad) about ``axis`` (thesis eq. 3.46).

    The axis is normalised; a zero axis raises InputError.
    """
    axis = _v(axis, "axis")
    n = np.linalg.norm(axis, axis=-1, keepdims=True)
    if np.any(n == 0.0):
        raise InputError("axis: the zero vector is not a rotation axis")
    angle = as_finite_array(angle, "angle", ndim_min=0)
    return _from_axis_angle(axis / n, angle)


def to_axis_angle(q) -> tuple[np.ndarray, np.ndarray]:
    """(axis, angle) of a unit quaternion, angle in [0, pi] (thesis eq. 3.47-3.48).

    Computed as 2 atan2(|v|, |w|) instead of 2 acos(w), which loses accuracy
    near 0 and pi. For the identity rotation the axis is (1, 0, 0).
    """
    q = check_unit(q)
    q = np.where(q[..., :1] < 0.0, -q, q)
    vn = np.linalg.norm(q[..., 1:], axis=-1)
    angle = 2.0 * np.arctan2(vn, q[..., 0])
    safe = np.where(vn > 0.0, vn, 1.0)[..., None]
    axis = np.where((vn > 0.0)[..., None], q[..., 1:] / safe, np.array([1.0, 0.0, 0.0]))
    return axis, angle


def to_matrix(q) -> np.ndarray:
    """3x3 rotation matrix of a unit quaternion (Kunze eq. 5.32)."""
    return _to_matrix(check_unit(q))


def _check_rotation_matrix(r, name="R", tol=1e-6) -> np.ndarray:
    r = as_finite_array(r, name, ndim_min=2)
    if r.shape[-2:] != (3, 3):
        raise InputError(f"{name}: expected shape (..., 3, 3), got {r.shape}")
    rtr = np.einsum("...ji,...jk->...ik", r, r)
    err = np.max(np.abs(rtr - np.eye(3)), axis=(-2, -1))
    det = np.linalg.det(r)
    if np.any(err > tol) or np.any(det < 0):
        raise InputError(
            f"{name}: not a rotation matrix (max |R^T R - I| = {float(np.max(err)):.3g}, "
            f"det = {float(np.min(det)):.6g})"
        )
    return r


def from_matrix(r) -> np.ndarray:
    """Unit quaternion (w >= 0) of a rotation matrix.

    Thesis eq. 3.42-3.45 select one of four inverse mappings so that the
    divisor is never small; this is the same idea in the form of Shepperd's
    method: the largest of 1 + tr R, 1 + 2 r11 - tr R, 1 + 2 r22 - tr R,
    1 + 2 r33 - tr R is used as the pivot (it is at least 1), so the result is
    accurate for every rotation, 180-degree turns included.
    """
    r = _check_rotation_matrix(r)
    r11, r12, r13 = r[..., 0, 0], r[..., 0, 1], r[..., 0, 2]
    r21, r22, r23 = r[..., 1, 0], r[..., 1, 1], r[..., 1, 2]
    r31, r32, r33 = r[..., 2, 0], r[..., 2, 1], r[..., 2, 2]
    tr = r11 + r22 + r33
    piv = np.stack((1 + tr, 1 + 2 * r11 - tr, 1 + 2 * r22 - tr, 1 + 2 * r33 - tr), axis=-1)
    k = np.argmax(piv, axis=-1)
    s = np.sqrt(np.take_along_axis(piv, k[..., None], axis=-1)[..., 0])  # = 2 |component k|
    h = 0.5 / s
    cand = np.stack(
        (
            np.stack((0.5 * s, (r32 - r23) * h, (r13 - r31) * h, (r21 - r12) * h), axis=-1),
            np.stack(((r32 - r23) * h, 0.5 * s, (r12 + r21) * h, (r13 + r31) * h), axis=-1),
            np.stack(((r13 - r31) * h, (r12 + r21) * h, 0.5 * s, (r23 + r32) * h), axis=-1),
            np.stack(((r21 - r12) * h, (r13 + r31) * h, (r23 + r32) * h, 0.5 * s), axis=-1),
        ),
        axis=-2,
    )
    q = np.take_along_axis(cand, k[..., None, None], axis=-2)[..., 0, :]
    q = np.where(q[..., :1] < 0.0, -q, q)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def to_xyzw(q) -> np.ndarray:
    """Scalar-last copy (x, y, z, w), the order of scipy and ROS."""
    return np.roll(_q(q), -1, axis=-1)


def from_xyzw(q) -> np.ndarray:
    """Scalar-first copy (w, x, y, z) of a scalar-last (x, y, z, w) quaternion."""
    return np.roll(_q(q), 1, axis=-1)


# --------------------------------------------------------------------------- #
# Orientation angles
# --------------------------------------------------------------------------- #
_GIMBAL = 1e-12


def kunze_angles(q) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orientation angles (alpha, beta, gamma) with R = Rx(alpha) Ry(beta) Rz(gamma).

    Kunze eq. 5.33-5.35, written with the C argument order atan2(y, x):
    alpha = atan2(-r23, r33), beta = asin(r13), gamma = atan2(-r12, r11).
    (The printed eq. 5.35 drops the minus sign of r12; the seed's Mathcad sheet
    has it. See docs/errata.md.) At beta = +-pi/2 only alpha + gamma (or
    alpha - gamma) is defined; gamma is then set to 0. Angles lie in (-pi, pi].
    """
    r = _to_matrix(check_unit(q))
    beta = np.arcsin(np.clip(r[..., 0, 2], -1.0, 1.0))
    cb = np.hypot(r[..., 0, 0], r[..., 0, 1])
    lock = cb < _GIMBAL
    alpha = np.where(lock, np.arctan2(r[..., 2, 1], r[..., 1, 1]),
                     np.arctan2(-r[..., 1, 2] + 0.0, r[..., 2, 2]))
    gamma = np.where(lock, 0.0, np.arctan2(-r[..., 0, 1] + 0.0, r[..., 0, 0]))
    return wrap_angle(alpha), beta, wrap_angle(gamma)


def _compose(axes: str, named_angles) -> np.ndarray:
    """Product of rotations about the coordinate axes ``axes`` (e.g. "zyx"), left to right."""
    out = None
    for axis, (name, value) in zip(axes, named_angles):
        r = _from_axis_angle(np.eye(3)["xyz".index(axis)], as_finite_array(value, name, ndim_min=0))
        out = r if out is None else _mul(out, r)
    return out


def from_kunze_angles(alpha, beta, gamma) -> np.ndarray:
    """Unit quaternion of Rx(alpha) Ry(beta) Rz(gamma) (Kunze eq. 5.30)."""
    return _compose("xyz", (("alpha", alpha), ("beta", beta), ("gamma", gamma)))


def euler_zyx(q) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ZYX Euler angles (yaw, pitch, roll) with R = Rz(yaw) Ry(pitch) Rx(roll).

    This is the aerospace / ROS ``rpy`` convention. At pitch = +-pi/2 roll is set
    to 0 and the whole rotation about the vertical goes into yaw.
    """
    r = _to_matrix(check_unit(q))
    pitch = np.arcsin(np.clip(-r[..., 2, 0], -1.0, 1.0))
    cp = np.hypot(r[..., 2, 1], r[..., 2, 2])
    lock = cp < _GIMBAL
    yaw = np.where(lock, np.arctan2(-r[..., 0, 1], r[..., 1, 1]),
                   np.arctan2(r[..., 1, 0] + 0.0, r[..., 0, 0]))
    roll = np.where(lock, 0.0, np.arctan2(r[..., 2, 1] + 0.0, r[..., 2, 2]))
    return wrap_angle(yaw), pitch, wrap_angle(roll)


def from_euler_zyx(yaw, pitch, roll) -> np.ndarray:
    """Unit quaternion of Rz(yaw) Ry(pitch) Rx(roll)."""
    return _compose("zyx", (("yaw", yaw), ("pitch", pitch), ("roll", roll)))
