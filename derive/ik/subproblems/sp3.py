"""Subproblem 3 (Paden-Kahan 3): rotation to a given distance from a point."""

from __future__ import annotations

import numpy as np

from derive.errors import InputError
from derive.ik.subproblems._common import (SubproblemSolutions, a_coef, axis, batch_shape,
                                           circle_line2, dot, finish, rot, scalar, vector,
                                           wrap_pi)


def solve_sp3(k, p1, p2, d):
    """The core of ``sp3`` without input checks (arrays that broadcast; constant vectors may be
    (3,)): (theta (..., 2), two (...), free (...)) as ``circle_line`` returns them."""
    a0, a1, axial = a_coef(k, p1, p2)
    beta = (dot(p1, p1) + dot(p2, p2) - d * d) / 2 - dot(p2, axial)
    return circle_line2(a0, a1, beta)


def _sp3(k, p1, p2, d):
    """``sp3``'s two slots (..., 2) wrapped to (-pi, pi] (slot 1 repeats slot 0 where there is
    one root), without input checks or residuals: the step of the compositions."""
    return wrap_pi(solve_sp3(k, p1, p2, d)[0])


def sp3(k, p1, p2, d) -> SubproblemSolutions:
    """Solve ||R(k, theta) p1 - p2|| = d for theta: up to 2 solutions, or 1 least-squares.

    Paden-Kahan subproblem 3 (Paden 1986; Murray, Li, Sastry 1994, sec. 3.3.3); IK-Geo (Elias &
    Wen 2022, arXiv:2211.05737, subproblem 3) solves it as subproblem 4: squaring,

        p2^T R(k, theta) p1 = (|p1|^2 + |p2|^2 - d^2) / 2,

    the line a . x = b with a = A(k, p1)^T p2, b = (|p1|^2 + |p2|^2 - d^2)/2 - (p2 . k)(k . p1),
    cut with the unit circle x = (sin theta, cos theta) (see ``sp4``). Two solutions when the
    circle of R(k, theta) p1 reaches distance d from p2; otherwise one least-squares solution,
    the nearest or farthest point of the circle, which minimises | ||R p1 - p2|| - d | (``ls``).

    k (..., 3) unit axis; p1, p2 (..., 3) and d (...) >= 0 in metres. Slots m = 2, angles
    j = 1; ``residual`` = | ||R(k, theta) p1 - p2|| - d | (m).

    Degenerate (``degenerate``): |k x p1| |k x p2| below SP_FREE_ANGLE (p1 or p2 on the axis):
    the distance does not depend on theta; theta = 0 in one slot, ``exact`` if that distance is
    d. A negative d, wrong shapes, NaN or a non-unit k: InputError.
    """
    k, p1, p2 = axis(k, "sp3 k"), vector(p1, "sp3 p1"), vector(p2, "sp3 p2")
    d = scalar(d, "sp3 d")
    if np.any(d < 0):
        raise InputError(f"sp3 d: a distance must be >= 0, got {np.min(d):g}")
    shape = batch_shape((k, 1), (p1, 1), (p2, 1), (d, 0))
    k, p1, p2 = (np.broadcast_to(v, shape + (3,)) for v in (k, p1, p2))
    d = np.broadcast_to(d, shape)
    theta, two, free = solve_sp3(k, p1, p2, d)
    valid = np.stack([np.ones(shape, dtype=bool), two], axis=-1)
    dist = np.linalg.norm(rot(k[..., None, :], theta, p1[..., None, :]) - p2[..., None, :], axis=-1)
    return finish(theta[..., None], valid, np.abs(dist - d[..., None]), free)
