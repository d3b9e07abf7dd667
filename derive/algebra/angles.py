"""Angle helpers shared by the reference kinematics and the IK."""

from __future__ import annotations

import numpy as np


def wrap_angle(a):
    """Wrap angles to the half-open interval (-pi, pi].

    -pi maps to +pi, so a rotation by half a turn has one representation.
    """
    a = np.asarray(a, dtype=np.float64)
    w = np.mod(a + np.pi, 2.0 * np.pi) - np.pi  # in [-pi, pi)
    return np.where(w <= -np.pi, w + 2.0 * np.pi, w)
