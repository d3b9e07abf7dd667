"""Subproblem 2 (Paden-Kahan 2): two rotations about different axes."""

from __future__ import annotations

import numpy as np

from derive.ik.subproblems._common import (SubproblemSolutions, a_coef, axis, batch_shape,
                                           circle_line2, dot, finish, rot, vector,
                                           wrap_pi)
from derive.ik.subproblems.sp1 import angle_sp1
from derive.ik.tolerances import SP_FREE_ANGLE


def _slots(v):
    """v (..., 3) with a slot axis before the last; a constant vector (3,) stays as it is."""
    return v if v.ndim == 1 else v[..., None, :]


def solve_sp2(k1, k2, p1, p2):
    """The core of ``sp2`` without input checks (arrays that broadcast; constant vectors may be
    (3,)): (t1 (..., 2), t2 (..., 2), two, free1 (...), free2 (..., 2), c (..., 2, 3) the common
    points R(k1, t1) p1)."""
    n1, n2 = np.linalg.norm(p1, axis=-1), np.linalg.norm(p2, axis=-1)
    u1 = p1 / np.where(n1 > SP_FREE_ANGLE, n1, 1.0)[..., None]
    u2 = p2 / np.where(n2 > SP_FREE_ANGLE, n2, 1.0)[..., None]
    a0, a1, axial = a_coef(k1, u1, k2)
    t1, two, free1 = circle_line2(a0, a1, dot(k2, u2) - dot(k2, axial))
    c = rot(_slots(k1), t1, _slots(p1))                                  # (..., 2, 3)
    t2, free2 = angle_sp1(_slots(k2), _slots(p2), c)
    return t1, t2, two, free1, free2, c


def _sp2(k1, k2, p1, p2):
    """``sp2``'s angles (..., 2 slots, 2) wrapped to (-pi, pi] (slot 1 repeats slot 0 where there
    is one solution), without input checks or residuals: the step of the compositions."""
    t1, t2 = solve_sp2(k1, k2, p1, p2)[:2]
    return wrap_pi(np.stack([t1, t2], axis=-1))


def sp2(k1, k2, p1, p2) -> SubproblemSolutions:
    """Solve R(k1, t1) p1 = R(k2, t2) p2 for (t1, t2): up to 2 solutions, or least-squares.

    Paden-Kahan subproblem 2 (Paden 1986; Murray, Li, Sastry 1994, sec. 3.3.3: the point where
    the circles of R(k1, .) p1 and R(k2, .) p2 meet); solved as in IK-Geo (Elias & Wen 2022,
    arXiv:2211.05737, subproblem 2): with the unit directions u_i = p_i / |p_i|, t1 solves the
    subproblem 4 equation k2^T R(k1, t1) u1 = k2^T u2 (the common point's height along k2), then
    t2 = sp1(k2, p2 -> R(k1, t1) p1) for each t1, which pairs the angles.

    Two solutions when the circles meet in two points (one, doubled, when they touch); else the
    least-squares solution, which minimises ||R(k1, t1) p1 - R(k2, t2) p2|| over both angles
    (this is maximising u1' u2' of the rotated directions, and subproblem 4's least-squares
    choice, the extreme height, does that). When |p1| != |p2| no exact solution exists and the
    returned ones (one or two) are the least-squares minimisers (``ls``).

    k1, k2 (..., 3) unit axes; p1, p2 (..., 3) in metres. Slots m = 2, angles j = 2 (t1, t2);
    ``residual`` = ||R(k1, t1) p1 - R(k2, t2) p2|| (m).

    Degenerate (``degenerate``), with representatives returned: k1 parallel to k2 (coaxial
    circles: a continuum or none; t1 = 0 and t2 from sp1), p1 on k1 or zero (t1 free: t1 = 0),
    p2 on k2 or zero (t2 free: t2 = 0). Wrong shapes, NaN or non-unit axes: InputError.
    """
    k1, k2 = axis(k1, "sp2 k1"), axis(k2, "sp2 k2")
    p1, p2 = vector(p1, "sp2 p1"), vector(p2, "sp2 p2")
    shape = batch_shape((k1, 1), (k2, 1), (p1, 1), (p2, 1))
    k1, k2, p1, p2 = (np.broadcast_to(v, shape + (3,)) for v in (k1, k2, p1, p2))
    t1, t2, two, free1, free2, c = solve_sp2(k1, k2, p1, p2)
    residual = np.linalg.norm(c - rot(k2[..., None, :], t2, p2[..., None, :]), axis=-1)
    valid = np.stack([np.ones(shape, dtype=bool), two], axis=-1)
    degenerate = free1 | np.any(free2, axis=-1)
    return finish(np.stack([t1, t2], axis=-1), valid, residual, degenerate)
