"""The URDF form of a description: every joint's origin and every end frame as one translation
``xyz`` and one ``rpy`` triple (R = Rz(yaw) Ry(pitch) Rx(roll), the URDF specification's
``<origin>``), computed the same way everywhere, so that the export writes it
(:mod:`derive.model.export`), the URDF reader reads it back as the same numbers
(:mod:`derive.model.urdf`), and the identity hashes it (:mod:`derive.model.identity`).

Joint i's origin is the transform from its parent's frame to its own frame at zero joint value:
the parent's ``post`` operations, its own ``pre``, and its motion by its ``offset``
(T_i = post_parent pre_i Motion(axis_i, offset_i)); an end frame's is its parent's ``post`` and
its own operations. When that list is already an origin of the form a URDF origin is read
into (a translation, then rotations about z, y and x, each optional, nothing else), its
numbers are taken as they are; otherwise the list is multiplied out and the rpy taken from
the product (:func:`rpy_of`). So the form of a robot read from a URDF is the file's own
numbers, bit for bit, and exporting a robot then reading the URDF back gives the same form.

The arithmetic is plain Python floats (each operation one IEEE rounding, no BLAS, no fused
multiply-add), so the form, and the identity built on it, is the same on every machine that has
the same ``math.sin`` / ``math.cos`` / ``math.atan2``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

_EX, _EY, _EZ = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)


def _rotation(axis, angle) -> list:
    """The 3x3 rotation by ``angle`` about the unit ``axis`` (Rodrigues: c I + s [k]x + (1 - c) k k^T)."""
    x, y, z = (float(a) for a in axis)
    c, s = math.cos(angle), math.sin(angle)
    v = 1.0 - c
    return [[c + v * x * x, v * x * y - s * z, v * x * z + s * y],
            [v * y * x + s * z, c + v * y * y, v * y * z - s * x],
            [v * z * x - s * y, v * z * y + s * x, c + v * z * z]]


def _matmul(a, b) -> list:
    return [[a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j] for j in range(3)] for i in range(3)]


def product(ops) -> tuple[list, list]:
    """(R, t) of the operations applied in order (R 3x3 and t as lists of floats)."""
    r = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    t = [0.0, 0.0, 0.0]
    for op in ops:
        if op.kind == "T":
            v = [float(x) for x in op.vector]
            t = [t[i] + (r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2]) for i in range(3)]
        else:
            r = _matmul(r, _rotation(op.axis, float(op.angle)))
    return r, t


def rpy_of(m) -> tuple[float, float, float]:
    """(roll, pitch, yaw) of a rotation (3x3 or 4x4, any nested sequence) with R = Rz(yaw)
    Ry(pitch) Rx(roll), the URDF ``rpy``. Roll and pitch come from the third row (r31, r32, r33)
    = (-sin p, cos p sin r, cos p cos r), yaw from R (Ry(pitch) Rx(roll))^T = Rz(yaw): each step
    is well conditioned, so the rotation rebuilt from the three angles is R to rounding at every
    pitch, also at +-pi/2, where the textbook formula (yaw from r21, r11) divides by cos p."""
    r = [[float(m[i][j]) for j in range(3)] for i in range(3)]
    roll = math.atan2(r[2][1], r[2][2])
    pitch = math.atan2(-r[2][0], math.hypot(r[2][1], r[2][2]))
    cr, sr, cp, sp_ = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    # (R (Ry Rx)^T)[1][0] and [0][0]: rows 1 and 0 of R times rows 0 of Ry Rx
    ry_rx0 = (cp, sp_ * sr, sp_ * cr)
    r10 = r[1][0] * ry_rx0[0] + r[1][1] * ry_rx0[1] + r[1][2] * ry_rx0[2]
    r00 = r[0][0] * ry_rx0[0] + r[0][1] * ry_rx0[1] + r[0][2] * ry_rx0[2]
    yaw = math.atan2(r10, r00)
    return roll + 0.0, pitch + 0.0, yaw + 0.0


def _as_read(ops):
    """(xyz, rpy) when ``ops`` is an origin as the URDF reader builds it: an optional translation,
    then optional rotations about +z, +y, +x in that order; None otherwise."""
    xyz, rpy, k = (0.0, 0.0, 0.0), [0.0, 0.0, 0.0], 0
    ops = list(ops)
    if ops and ops[0].kind == "T":
        xyz, k = tuple(float(x) + 0.0 for x in ops[0].vector), 1
    for slot, axis in ((2, _EZ), (1, _EY), (0, _EX)):
        if k < len(ops) and ops[k].kind == "R" and tuple(float(a) for a in ops[k].axis) == axis:
            rpy[slot] = float(ops[k].angle) + 0.0
            k += 1
    return (xyz, tuple(rpy)) if k == len(ops) else None


def origin(ops) -> tuple[tuple, tuple]:
    """(xyz, rpy) of a list of operations (module docstring): the numbers themselves when the
    list is a URDF origin as read, else the product's translation and :func:`rpy_of`."""
    read = _as_read(ops)
    if read is not None:
        return read
    r, t = product(ops)
    return tuple(x + 0.0 for x in t), rpy_of(r)


class _Motion(NamedTuple):
    """An operation with the fields of :class:`derive.model.robot.Op` that :func:`product` reads."""

    kind: str
    axis: tuple = ()
    angle: float = 0.0
    vector: tuple = ()


def motion(joint, value: float) -> _Motion:
    """The joint's motion by ``value`` as one operation (a rotation about, or a translation
    along, its axis)."""
    if joint.type == "revolute":
        return _Motion("R", axis=tuple(joint.axis), angle=float(value))
    return _Motion("T", vector=tuple(float(value) * float(a) for a in joint.axis))


def joint_ops(joints, i) -> tuple:
    """The operations from joint i's parent frame to its frame at zero joint value:
    post_parent, pre_i and (when the offset is not 0) the motion by the offset."""
    j = joints[i]
    parent_post = tuple(joints[j.parent].post) if j.parent >= 0 else ()
    tail = (motion(j, float(j.offset)),) if float(j.offset) != 0.0 else ()
    return (*parent_post, *j.pre, *tail)


def end_ops(joints, end) -> tuple:
    """The operations from an end frame's parent joint frame to the end frame."""
    return (*joints[end.parent].post, *end.ops)


def urdf_form(joints, ends: dict) -> tuple[list, dict]:
    """([(xyz, rpy) per joint], {end name: (xyz, rpy)}): the URDF origins of a description."""
    return ([origin(joint_ops(joints, i)) for i in range(len(joints))],
            {name: origin(end_ops(joints, e)) for name, e in ends.items()})
