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
    # filled in place: the same matrices as stacking the rows, without the nested np.stack
    # calls, whose overhead dominates for the few angles of a one-pose search
    m = np.zeros(np.shape(c) + (3, 3), dtype=np.result_type(c, s))
    m[..., 0, 0], m[..., 0, 1] = c, -s
    m[..., 1, 0], m[..., 1, 1] = s, c
    m[..., 2, 2] = 1.0
    return m


def rot_y(t) -> np.ndarray:
    """Ry(t), shape t.shape + (3, 3)."""
    c, s = np.cos(t), np.sin(t)
    m = np.zeros(np.shape(c) + (3, 3), dtype=np.result_type(c, s))
    m[..., 0, 0], m[..., 0, 2] = c, s
    m[..., 1, 1] = 1.0
    m[..., 2, 0], m[..., 2, 2] = -s, c
    return m
