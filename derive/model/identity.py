"""The identity of a robot: a hash of its normalised description.

Two descriptions have the same identity exactly when they describe the same kinematics:
the same joints (type, parent, driving variable, mimic relation, motion axis, origin) and the
same end frames, every number in SI units after the file's units are applied, and the same
exactness (whether every fixed angle is a multiple of pi/12, which decides how the equations are
derived). The robot's name, title, source, joint names, file path and joint limits do not enter:
a copy of ``ur5.yaml`` under another name is the UR5, a copy with one joint limit edited is
still the UR5 (nothing is derived again), and a copy with one length changed is another robot.

The fixed motions enter in their URDF form (:func:`kinematic`): each joint's origin (its
parent's fixed motions after the motion, its own before, and its offset) and each end frame
as one translation and one roll-pitch-yaw triple (:mod:`derive.model.origins`). So the way a
file splits the same transform into operations does not matter where the form is taken as it
is (a URDF origin), and a robot exported as URDF and read back (:mod:`derive.model.export`)
has the identity of the robot it was exported from. The end frames enter in a canonical order
(:func:`canonical_ends`: the default end first, then by parent joint and origin), not the file's.

Every cache and artifact of dq-derive is keyed by this identity (:mod:`derive.cache`). The
artifacts that embed the joint limits (the generated kernels: the C nearest-solution pass and
the extension's windings compile the limits in) add :func:`limits_digest` to their key, so a
limit edit renders and compiles them again from the derivation kept under the identity.
"""

from __future__ import annotations

import hashlib
import json

from derive.model.origins import urdf_form

#: Hex digits of the SHA-256 digest kept as the identity.
ID_LENGTH = 16


def _num(x) -> str:
    """A float as its shortest round-trip text (-0.0 as 0.0): equal floats, equal text."""
    return repr(float(x) + 0.0)


def _vec(v) -> list:
    return [_num(x) for x in v]


def _origin(form) -> list:
    xyz, rpy = form
    return [_vec(xyz), _vec(rpy)]


def kinematic(joints, ends: dict) -> tuple[list, list]:
    """The fixed motions of a description as the identity sees them: ([origin of each joint],
    [origin of each end frame]), each [xyz, rpy] (:func:`derive.model.origins.urdf_form`)."""
    joint_forms, end_forms = urdf_form(joints, ends)
    return [_origin(f) for f in joint_forms], [_origin(end_forms[name]) for name in ends]


def normalised(joints, ends: dict, default_end: str, exact: bool) -> dict:
    """The description reduced to what the kinematics depend on (see the module docstring):
    the joints and end frames of a description in the neutral form of
    :mod:`derive.model.robot`."""
    joint_origins, end_origins = kinematic(joints, ends)
    out = []
    for j, origin in zip(joints, joint_origins):
        out.append({
            "type": j.type, "parent": j.parent, "variable": j.variable,
            "multiplier": _num(j.multiplier), "mimic_offset": _num(j.mimic_offset),
            "axis": _vec(j.axis), "origin": origin,
        })
    ends_out = [{"parent": e.parent, "origin": origin, "default": name == default_end}
                for (name, e), origin in zip(ends.items(), end_origins)]
    return {"joints": out, "ends": canonical_ends(ends_out), "exact": bool(exact)}


def canonical_ends(ends_out: list) -> list:
    """The end frames in an order that does not depend on the file's: the default end first, then
    the others by parent joint and by the text of their origin. Their names do not enter the
    identity, so their order must not either (a file written with sorted keys, such as
    ``yaml.safe_dump``'s, lists them in another order). Every artifact of a robot is made for
    its default end, so two descriptions whose end frames differ only in order have the same
    artifacts. The library's robots keep their identities: each lists its default end first and
    the others (seed-arm's two fingers) by parent joint already."""
    def key(e):
        return (not e["default"], e["parent"], json.dumps(e["origin"], separators=(",", ":")))
    return sorted(ends_out, key=key)


def digest(joints, ends: dict, default_end: str, exact: bool) -> str:
    """The identity (16 hex digits) of a description's normalised form; a loaded robot
    carries it as ``Robot.id``."""
    text = json.dumps(normalised(joints, ends, default_end, exact), sort_keys=True,
                      separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:ID_LENGTH]


#: Hex digits of the SHA-256 digest kept as the limits' key part.
LIMITS_LENGTH = 8


def limits_digest(joints) -> str:
    """The key part (8 hex digits) of a description's joint limits (each joint's [lower, upper]
    in SI units, or none), for the artifacts that embed them besides ``Robot.id``."""
    text = json.dumps([None if j.limits is None else _vec(j.limits) for j in joints],
                      separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:LIMITS_LENGTH]
