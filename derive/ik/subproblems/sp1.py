"""Subproblem 1 (Paden-Kahan 1): one rotation taking a point onto another."""

from __future__ import annotations

import numpy as np

from derive.ik.subproblems._common import (SubproblemSolutions, a_coef_with, axis, batch_shape, cross,
                                           dot, finish, rot, vector, wrap_pi)
from derive.ik.tolerances import SP_FREE_ANGLE


def angle_sp1(k, p1, p2):
    """The core of ``sp1`` without input checks, for arrays that broadcast (..., 3) (a constant
    axis k may be one (3,) vector).

    Returns (theta (...), degenerate (...)); theta = atan2((k x p1) . p2, (p1 - (k . p1) k) . p2),
    0 where degenerate (p1 or p2 within SP_FREE_ANGLE of the axis).
    """
    kxp1, kxp2 = cross(k, p1), cross(k, p2)
    c0, c1, _axial = a_coef_with(k, p1, p2, kxp1)
    degenerate = (dot(kxp1, kxp1) <= SP_FREE_ANGLE ** 2) | (dot(kxp2, kxp2) <= SP_FREE_ANGLE ** 2)
    theta = np.arctan2(c0, c1)
    if np.any(degenerate):
        theta = np.where(degenerate, 0.0, theta)
    return theta, degenerate


def _sp1(k, p1, p2):
    """``sp1``'s angle (...) wrapped to (-pi, pi], without input checks or residual: the step of
    the compositions (:mod:`derive.ik.closed_form`, :mod:`derive.ik.spherical`)."""
    return wrap_pi(angle_sp1(k, p1, p2)[0])


def sp1(k, p1, p2) -> SubproblemSolutions:
    """Solve R(k, theta) p1 = p2 for theta: one solution, exact or least-squares.

    Paden-Kahan subproblem 1 (Paden 1986, "Kinematics and control of robot manipulators", PhD
    thesis, Berkeley, ch. 4; Murray, Li, Sastry 1994, sec. 3.3.3); IK-Geo (Elias & Wen 2022,
    arXiv:2211.05737, subproblem 1): with A = [k x p1, p1 - (k . p1) k],

        theta = atan2((k x p1) . p2, (p1 - (k . p1) k) . p2),

    which minimises ||R(k, theta) p1 - p2|| over theta; it solves the equation exactly when
    ||p1|| = ||p2|| and k . p1 = k . p2 (``exact``).

    k (..., 3) unit axis; p1, p2 (..., 3), in metres. Result slots m = 1, angles j = 1;
    ``residual`` = ||R(k, theta) p1 - p2|| (m).

    Degenerate (``degenerate`` True): p1 or p2 parallel to k, or zero (|k x p| below
    SP_FREE_ANGLE): the cost does not depend on theta (any theta is a solution, or none is);
    theta = 0 is returned, exact when its residual is small. Wrong shapes, NaN or a non-unit k:
    InputError.
    """
    k, p1, p2 = axis(k, "sp1 k"), vector(p1, "sp1 p1"), vector(p2, "sp1 p2")
    shape = batch_shape((k, 1), (p1, 1), (p2, 1))
    k, p1, p2 = (np.broadcast_to(v, shape + (3,)) for v in (k, p1, p2))
    theta, degenerate = angle_sp1(k, p1, p2)
    residual = np.linalg.norm(rot(k, theta, p1) - p2, axis=-1)
    return finish(theta[..., None, None], np.ones(shape + (1,), dtype=bool), residual[..., None],
                  degenerate)
