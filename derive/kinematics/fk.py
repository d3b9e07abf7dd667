"""Numeric reference kinematics, computed two independent ways.

* :func:`fk` multiplies unit dual quaternions (Kunze eq. 1.8 and 5.28: Q_06 =
  Q_01 Q_12 ... Q_56): each elementary rotation is cos(t/2) + sin(t/2) n, each
  translation 1 + eps v/2.
* :func:`fk_matrix` multiplies plain 4x4 homogeneous matrices built with
  Rodrigues' formula (Kunze eq. 5.1-5.4 for the DH case); it shares no code
  with the quaternion modules.

Both evaluate the neutral joint form of :mod:`derive.model.robot`; the test suite
requires them to agree to 1e-12 on every robot of the library.

Joint values ``q`` have shape (dof,) for one configuration or (n, dof) for a
batch; results then have shape (8,) / (n, 8), (4, 4) / (n, 4, 4), and so on.
Joint limits are not checked by FK.
"""

from __future__ import annotations

import numpy as np

from derive.algebra import dualquat as dq
from derive.algebra import quaternion as quat
from derive.errors import InputError, as_finite_array
from derive.model.robot import Op, Robot, load_robot


# --------------------------------------------------------------------------- #
# Input handling
# --------------------------------------------------------------------------- #
def _prepare(robot, q):
    robot = load_robot(robot)
    q = as_finite_array(q, "q", ndim_min=1)
    if q.ndim > 2:
        raise InputError(f"q: expected shape ({robot.dof},) or (n, {robot.dof}), got {q.shape}")
    single = q.ndim == 1
    q2 = q[None, :] if single else q
    if q2.shape[1] != robot.dof:
        raise InputError(f"q: robot {robot.name!r} has {robot.dof} joint variables "
                         f"({', '.join(robot.variable_names)}), got {q2.shape[1]}")
    return robot, q2, single


def _end(robot: Robot, end):
    name = robot.default_end if end is None else end
    if name not in robot.ends:
        raise InputError(f"end {name!r} is not an end frame of {robot.name!r}; "
                         f"choose one of {list(robot.ends)}")
    return robot.ends[name]


def _joint_values(robot: Robot, q2: np.ndarray) -> list[np.ndarray]:
    """Motion parameter (angle or displacement) of every joint, each of shape (n,)."""
    return [j.multiplier * q2[:, j.variable] + j.mimic_offset + j.offset for j in robot.joints]


def _chain(j_index: int, robot: Robot) -> list[int]:
    """Joint indices from the base to ``j_index`` (inclusive), in order."""
    out = []
    while j_index >= 0:
        out.append(j_index)
        j_index = robot.joints[j_index].parent
    return out[::-1]


# --------------------------------------------------------------------------- #
# Dual-quaternion path
# --------------------------------------------------------------------------- #
def _op_dq(op: Op) -> np.ndarray:
    if op.kind == "R":
        return dq._rotation(op.axis, op.angle)
    return dq._translation_dq(op.vector)


def _joint_dq(j, value: np.ndarray) -> np.ndarray:
    """Unit dual quaternion of one joint for the motion values ``value`` (n,)."""
    if j.type == "revolute":
        m = dq._rotation(j.axis, value)
    else:
        m = dq._translation_dq(value[:, None] * j.axis)
    out = m
    for op in reversed(j.pre):
        out = dq._mul(_op_dq(op), out)
    for op in j.post:
        out = dq._mul(out, _op_dq(op))
    return out


def _frames_dq(robot: Robot, q2: np.ndarray) -> list[np.ndarray]:
    """Pose (n, 8) of every joint frame, in joint order."""
    vals = _joint_values(robot, q2)
    n = q2.shape[0]
    frames: list[np.ndarray] = []
    for i, j in enumerate(robot.joints):
        parent = np.broadcast_to(dq.IDENTITY, (n, 8)) if j.parent < 0 else frames[j.parent]
        frames.append(dq._mul(parent, _joint_dq(j, vals[i])))
    return frames


def _end_dq(robot: Robot, frames, end) -> np.ndarray:
    e = _end(robot, end)
    out = frames[e.parent]
    for op in e.ops:
        out = dq._mul(out, _op_dq(op))
    return out


def _canonical(Q: np.ndarray) -> np.ndarray:
    """Choose the sign of the double cover so that the real part's first non-zero entry is positive."""
    p = Q[..., :4]
    idx = np.argmax(np.abs(p) > 1e-12, axis=-1)
    lead = np.take_along_axis(p, idx[..., None], axis=-1)
    return np.where(lead < 0, -Q, Q)


def fk(robot, q, end: str | None = None) -> np.ndarray:
    """Unit dual quaternion (8,) or (n, 8) of the end frame, by the dual-quaternion product.

    ``end`` names one of ``robot.ends`` (default ``robot.default_end``). The
    sign of the result is chosen so that the first non-zero component of the
    real part is positive (Q and -Q are the same pose).
    """
    robot, q2, single = _prepare(robot, q)
    out = _canonical(_end_dq(robot, _frames_dq(robot, q2), end))
    return out[0] if single else out


def frame_poses(robot, q) -> np.ndarray:
    """Unit dual quaternions (m, 8) or (n, m, 8) of every frame in ``robot.frame_names``."""
    robot, q2, single = _prepare(robot, q)
    frames = _frames_dq(robot, q2)
    base = np.broadcast_to(dq.IDENTITY, (q2.shape[0], 8))
    allf = [base] + frames + [_end_dq(robot, frames, e) for e in robot.ends]
    out = _canonical(np.stack(allf, axis=1))
    return out[0] if single else out


def joint_positions(robot, q) -> np.ndarray:
    """Origins (m, 3) or (n, m, 3) of every frame in ``robot.frame_names``: the base,
    each joint frame, each end frame (for plotting and for the seed examples)."""
    poses = frame_poses(robot, q)
    return dq._translation(poses)


def fk_pair(robot, q, end: str | None = None) -> dq.Pair:
    """End pose in the thesis's pair form ([w, <a, b, c>], <x, y, z>) (thesis eq. 3.55)."""
    Q = fk(robot, q, end)
    return dq.Pair(Q[..., :4].copy(), dq._translation(Q))


# --------------------------------------------------------------------------- #
# Homogeneous-matrix path (independent of the quaternion code)
# --------------------------------------------------------------------------- #
def _rodrigues(axis: np.ndarray, angle) -> np.ndarray:
    """4x4 rotation about a unit axis: I + sin(t) K + (1 - cos(t)) K^2."""
    angle = np.atleast_1d(np.asarray(angle, dtype=float))
    x, y, z = axis
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    m = np.zeros((angle.shape[0], 4, 4))
    m[:, :3, :3] = np.eye(3) + s * k + (1.0 - c) * (k @ k)
    m[:, 3, 3] = 1.0
    return m


def _translation_matrix(v: np.ndarray) -> np.ndarray:
    v = np.atleast_2d(v)
    m = np.broadcast_to(np.eye(4), (v.shape[0], 4, 4)).copy()
    m[:, :3, 3] = v
    return m


def _op_matrix(op: Op) -> np.ndarray:
    if op.kind == "R":
        return _rodrigues(op.axis, op.angle)
    return _translation_matrix(op.vector)


def _joint_matrix(j, value: np.ndarray) -> np.ndarray:
    if j.type == "revolute":
        m = _rodrigues(j.axis, value)
    else:
        m = _translation_matrix(value[:, None] * j.axis[None, :])
    for op in reversed(j.pre):
        m = _op_matrix(op) @ m
    for op in j.post:
        m = m @ _op_matrix(op)
    return m


def fk_matrix(robot, q, end: str | None = None) -> np.ndarray:
    """4x4 homogeneous matrix (4, 4) or (n, 4, 4) of the end frame, by matrix products."""
    robot, q2, single = _prepare(robot, q)
    vals = _joint_values(robot, q2)
    n = q2.shape[0]
    frames: list[np.ndarray] = []
    for i, j in enumerate(robot.joints):
        parent = np.broadcast_to(np.eye(4), (n, 4, 4)) if j.parent < 0 else frames[j.parent]
        frames.append(parent @ _joint_matrix(j, vals[i]))
    e = _end(robot, end)
    out = frames[e.parent]
    for op in e.ops:
        out = out @ _op_matrix(op)
    return out[0] if single else out


# --------------------------------------------------------------------------- #
# Pose comparison
# --------------------------------------------------------------------------- #
def pose_error(a, b) -> tuple[np.ndarray, np.ndarray]:
    """(position error in m, rotation angle error in rad) between two unit dual quaternions."""
    return _pose_error(dq.check_unit(a, "a"), dq.check_unit(b, "b"))


def _pose_error(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unchecked :func:`pose_error` for inner loops."""
    dp = np.linalg.norm(dq._translation(a) - dq._translation(b), axis=-1)
    rel = quat._mul(quat._conj(a[..., :4]), b[..., :4])
    ang = 2.0 * np.arctan2(np.linalg.norm(rel[..., 1:], axis=-1), np.abs(rel[..., 0]))
    return dp, ang
