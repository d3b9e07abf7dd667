"""Subproblem 4 (IK-Geo): a rotated point on a plane (a circle meeting a plane)."""

from __future__ import annotations

import numpy as np

from derive.ik.subproblems._common import (SubproblemSolutions, a_coef, axis, batch_shape,
                                           circle_line2, dot, finish, rot, scalar, vector,
                                           wrap_pi)


def solve_sp4(h, k, p, d):
    """The core of ``sp4`` without input checks (arrays that broadcast; constant vectors may be
    (3,)): (theta (..., 2), two (...), free (...)) as ``circle_line`` returns them."""
    a0, a1, axial = a_coef(k, p, h)
    return circle_line2(a0, a1, d - dot(h, axial))


def _sp4(h, k, p, d):
    """``sp4``'s two slots (..., 2) wrapped to (-pi, pi] (slot 1 repeats slot 0 where there is
    one root) and ``degenerate`` (...), without input checks or residuals: the step of the
    compositions."""
    theta, _two, free = solve_sp4(h, k, p, d)
    return wrap_pi(theta), free


def sp4(h, k, p, d) -> SubproblemSolutions:
    """Solve h^T R(k, theta) p = d for theta: up to 2 solutions, or 1 least-squares.

    IK-Geo (Elias & Wen 2022, arXiv:2211.05737, subproblem 4: a circle meeting a plane; the
    classic Paden-Kahan list in Murray, Li, Sastry 1994 has 1-3, and IK-Geo solves sp2 and sp3
    through this one): with R(k, theta) p = (k . p) k + A x,
    A = [k x p, p - (k . p) k], x = (sin theta, cos theta), the equation is the line
    a . x = b with a = A^T h, b = d - (h . k)(k . p), cut with the unit circle:

        x = (a b +- sqrt(|a|^2 - b^2) J a) / |a|^2,    J a = (a_2, -a_1)

    (two solutions; one double solution when |a| = |b|). When |b| > |a| there is none and the
    least-squares solution x = a sign(b) / |a| minimises |h^T R(k, theta) p - d| (one slot,
    ``ls``).

    h, p (..., 3) (h need not be a unit vector); k (..., 3) unit axis; d (...). Slots m = 2,
    angles j = 1; ``residual`` = |h^T R(k, theta) p - d| (units of h^T p).

    Degenerate (``degenerate``): |a| = |k x h| |k x p| below SP_FREE_ANGLE (h or p parallel to
    k, or zero): theta does not enter; theta = 0 is returned in one slot, ``exact`` if
    (h . k)(k . p) = d. Wrong shapes, NaN or a non-unit k: InputError.
    """
    h, k, p = vector(h, "sp4 h"), axis(k, "sp4 k"), vector(p, "sp4 p")
    d = scalar(d, "sp4 d")
    shape = batch_shape((h, 1), (k, 1), (p, 1), (d, 0))
    h, k, p = (np.broadcast_to(v, shape + (3,)) for v in (h, k, p))
    d = np.broadcast_to(d, shape)
    theta, two, free = solve_sp4(h, k, p, d)
    valid = np.stack([np.ones(shape, dtype=bool), two], axis=-1)
    residual = np.abs(dot(h[..., None, :], rot(k[..., None, :], theta, p[..., None, :])) - d[..., None])
    return finish(theta[..., None], valid, residual, free)
