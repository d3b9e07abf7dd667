"""Rotation matrices about the coordinate axes, vectorised over angles.

``rot_z(t)`` and ``rot_y(t)`` take an angle or an array of angles of any shape and return
matrices of shape ``t.shape + (3, 3)``: the right-handed rotations by t (rad) about z and y,
Rz(t) = [[c, -s, 0], [s, c, 0], [0, 0, 1]] and Ry(t) = [[c, 0, s], [0, 1, 0], [-s, 0, c]]. The
numeric IK solvers compose their steps from them (derive.ik.closed_form, spherical, panda, srs).
"""

from __future__ import annotations

import numpy as np


def rot_z(t) -> np.ndarray:
    """Rz(t), shape t.shape + (3, 3)."""
    c, s = np.cos(t), np.sin(t)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def rot_y(t) -> np.ndarray:
    """Ry(t), shape t.shape + (3, 3)."""
    c, s = np.cos(t), np.sin(t)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)
