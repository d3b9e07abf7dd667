"""Pose input: unit dual quaternions or 4x4 matrices, checked and brought to one form; poses
from and to position + quaternion (either order), position + roll pitch yaw, (R, t) and scipy."""

from __future__ import annotations

import numpy as np

from derive.algebra import dualquat as dq
from derive.algebra import quaternion as quat
from derive.errors import InputError, as_finite_array


def as_pose(pose, name: str = "pose") -> np.ndarray:
    """One pose (8,) from any of its forms: a unit dual quaternion (8,) (ours: [real w x y z,
    dual w x y z]), a 4x4 matrix, a pair (R, t) of a 3x3 rotation matrix or a
    ``scipy.spatial.transform.Rotation`` and a translation (m). For position + quaternion use
    :func:`from_position_quaternion`, which needs the quaternion order said."""
    if isinstance(pose, tuple) and len(pose) == 2:
        rot, t = pose
        if hasattr(rot, "as_matrix"):
            rot = rot.as_matrix()
        r = as_finite_array(rot, f"{name} rotation")
        t = as_finite_array(t, f"{name} translation", last_dim=3)
        if r.shape != (3, 3) or t.shape != (3,):
            raise InputError(f"{name}: (R, t) needs R (3, 3) and t (3,), got {r.shape} and {t.shape}")
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = r, t
        pose = m
    out, single = as_pose_batch(pose)
    if not single:
        raise InputError(f"{name}: expected one pose, got {out.shape[0]}")
    return out[0]


def from_position_quaternion(position, quaternion, order: str) -> np.ndarray:
    """Unit dual quaternions (8,) / (n, 8) from positions (m) and rotation quaternions in the
    given ``order``: "xyzw" (scipy, ROS geometry_msgs) or "wxyz" (ours, Eigen's constructor)."""
    if order not in ("xyzw", "wxyz"):
        raise InputError(f"order: 'xyzw' (scipy, ROS) or 'wxyz', got {order!r}")
    p = as_finite_array(position, "position", last_dim=3)
    q = as_finite_array(quaternion, "quaternion", last_dim=4)
    if order == "xyzw":
        q = np.concatenate([q[..., 3:], q[..., :3]], axis=-1)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(np.abs(n - 1.0) > 1e-6):
        raise InputError(f"quaternion: not unit (| |q| - 1 | = {float(np.max(np.abs(n - 1))):.3g})")
    return dq.from_rt(q / n, p)


def from_position_rpy(position, rpy) -> np.ndarray:
    """Unit dual quaternions (8,) / (n, 8) from positions (m) and roll, pitch, yaw angles (rad)
    in the URDF / ROS convention: R = Rz(yaw) Ry(pitch) Rx(roll), fixed axes x, y, z."""
    p = as_finite_array(position, "position", last_dim=3)
    a = as_finite_array(rpy, "rpy", last_dim=3)
    q = quat.from_euler_zyx(a[..., 2], a[..., 1], a[..., 0])
    return dq.from_rt(q, p)


def to_position_rpy(pose) -> tuple:
    """(positions (..., 3) in m, roll pitch yaw (..., 3) in rad, R = Rz(yaw) Ry(pitch) Rx(roll))
    of poses; at pitch = +-pi/2 roll is 0 (see :func:`derive.algebra.quaternion.euler_zyx`)."""
    poses, single = as_pose_batch(pose)
    yaw, pitch, roll = quat.euler_zyx(poses[:, :4])
    rpy = np.stack([roll, pitch, yaw], axis=-1)
    t = dq._translation(poses)
    return (t[0], rpy[0]) if single else (t, rpy)


def to_position_quaternion(pose, order: str) -> tuple:
    """(positions (..., 3), quaternions (..., 4) in ``order`` "xyzw" or "wxyz") of poses."""
    if order not in ("xyzw", "wxyz"):
        raise InputError(f"order: 'xyzw' (scipy, ROS) or 'wxyz', got {order!r}")
    poses, single = as_pose_batch(pose)
    q, t = poses[:, :4], dq._translation(poses)
    if order == "xyzw":
        q = np.concatenate([q[:, 1:], q[:, :1]], axis=-1)
    return (t[0], q[0]) if single else (t, q)


def to_scipy(pose) -> tuple:
    """(scipy Rotation, translations) of poses (any form :func:`as_pose_batch` takes)."""
    from scipy.spatial.transform import (
        Rotation,  # scipy only where asked for (optional)
    )
    t, q = to_position_quaternion(pose, "xyzw")
    return Rotation.from_quat(q), t


def from_scipy(rotation, translation) -> np.ndarray:
    """Unit dual quaternions from a scipy Rotation (one or n) and translations (3,) / (n, 3)."""
    return from_position_quaternion(translation, rotation.as_quat(), "xyzw")


def _is_rt_pair(pose) -> bool:
    """Whether pose is a pair (R, t): a tuple of a rotation (a scipy Rotation or numbers of shape
    (3, 3) / (n, 3, 3)) and translations (3,) / (n, 3)."""
    if not (isinstance(pose, tuple) and len(pose) == 2):
        return False
    rot, t = pose
    if hasattr(rot, "as_matrix"):
        return True
    return np.shape(rot)[-2:] == (3, 3) and np.shape(t)[-1:] == (3,)


#: batches up to this size take the fast path of :func:`_few_poses` (Python floats, a few
#: microseconds a pose, against the array code's ~70 us a call)
FEW_POSES = 16


def _few_poses(arr: np.ndarray) -> tuple | None:
    """The fast path of :func:`as_pose_batch` for one pose or a few (at most :data:`FEW_POSES`),
    a float64 array (8,) / (n, 8), (4, 4) / (n, 4, 4) or (3, 4) / (n, 3, 4): (unit dual
    quaternions (n, 8), single flag), bit for bit the array code's
    (:func:`derive.algebra.dualquat._unit_one`, :func:`derive.algebra.dualquat._from_matrix_one`),
    or None where the input is not of that form or not clearly valid: the array code then
    decides, and raises its errors with their messages."""
    shape = arr.shape
    if shape[-1:] == (8,) and len(shape) <= 2:
        single, one = len(shape) == 1, dq._unit_one
    elif shape[-2:] in ((4, 4), (3, 4)) and len(shape) <= 3:
        single, one = len(shape) == 2, dq._from_matrix_one
    else:
        return None
    if not (single or 0 < shape[0] <= FEW_POSES):
        return None
    rows = [arr.tolist()] if single else arr.tolist()
    if shape[-2:] == (3, 4):
        rows = [m + [[0.0, 0.0, 0.0, 1.0]] for m in rows]
    out = []
    for row in rows:
        o = one(row)
        if o is None:
            return None
        out.append(o)
    return np.array(out), single


def as_pose_batch(pose) -> tuple:
    """Unit dual quaternions (n, 8) from (8,), (n, 8), (4, 4), (n, 4, 4), (3, 4) or (n, 3, 4)
    ([R | t]) input, or a pair (R, t) of rotations (3, 3) / (n, 3, 3) or a scipy Rotation and
    translations (3,) / (n, 3); single flag."""
    if type(pose) is np.ndarray and pose.dtype == np.float64:
        out = _few_poses(pose)
        if out is not None:
            return out
    if _is_rt_pair(pose):
        rot, t = pose
        if hasattr(rot, "as_matrix"):
            rot = rot.as_matrix()
        r = as_finite_array(rot, "pose rotation")
        t = as_finite_array(t, "pose translation", last_dim=3)
        if r.shape[-2:] != (3, 3) or r.ndim > 3 or r.shape[:-2] != t.shape[:-1]:
            raise InputError(f"pose: (R, t) needs R (3, 3) and t (3,), or R (n, 3, 3) and t (n, 3), "
                             f"got {r.shape} and {t.shape}")
        pose = np.concatenate([r, t[..., None]], axis=-1)
    arr = as_finite_array(pose, "pose", ndim_min=1)
    if arr.shape[-2:] == (3, 4) and arr.ndim <= 3:
        bottom = np.zeros(arr.shape[:-2] + (1, 4))
        bottom[..., 0, 3] = 1.0
        arr = np.concatenate([arr, bottom], axis=-2)
    if arr.shape[-2:] == (4, 4):
        if arr.ndim > 3:
            raise InputError(f"pose: expected a dual quaternion (8,) / (n, 8) or a matrix (4, 4) / "
                             f"(n, 4, 4), got shape {arr.shape}")
        single = arr.ndim == 2
        m = arr[None] if single else arr
        r = m[:, :3, :3]
        err = np.max(np.abs(np.einsum("nji,njk->nik", r, r) - np.eye(3)), axis=(1, 2))
        if np.any(err > 1e-6) or np.any(np.linalg.det(r) < 0):
            raise InputError(f"pose: the 3x3 block is not a rotation matrix "
                             f"(max |R^T R - I| = {float(np.max(err)):.3g})")
        return dq.from_matrix(m), single
    if arr.shape[-1] != 8 or arr.ndim > 2:
        raise InputError(f"pose: expected a dual quaternion (8,) / (n, 8) or a matrix (4, 4) / "
                         f"(n, 4, 4), got shape {arr.shape}")
    single = arr.ndim == 1
    return dq.check_unit(arr[None] if single else arr, "pose"), single
