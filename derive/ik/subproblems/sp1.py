"""Subproblem 1 (Paden-Kahan 1): one rotation taking a point onto another."""

from __future__ import annotations

import numpy as np

from derive.ik.subproblems._common import (SubproblemSolutions, a_matrix, axis, batch_shape, finish,
                                           rot, vector)
from derive.ik.tolerances import SP_FREE_ANGLE


def angle_sp1(k, p1, p2):
    """The core of ``sp1`` without input checks, for arrays already broadcast (..., 3).

    Returns (theta (...), degenerate (...)); theta = atan2((k x p1) . p2, (p1 - (k . p1) k) . p2),
    0 where degenerate (p1 or p2 within SP_FREE_ANGLE of the axis).
    """
    a, _axial = a_matrix(k, p1)
    coef = np.einsum("...ij,...i->...j", a, p2)
    degenerate = (np.linalg.norm(np.cross(k, p1), axis=-1) <= SP_FREE_ANGLE) \
        | (np.linalg.norm(np.cross(k, p2), axis=-1) <= SP_FREE_ANGLE)
    theta = np.where(degenerate, 0.0, np.arctan2(coef[..., 0], coef[..., 1]))
    return theta, degenerate


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
