"""Subproblem 6 (IK-Geo): two angles from two equations of the subproblem 4 kind."""

from __future__ import annotations

import numpy as np

from derive.errors import InputError
from derive.errors import as_finite_array
from derive.ik.subproblems._common import (SubproblemSolutions, a_matrix, batch_shape,
                                           dot, finish, rot, two_circles)
from derive.ik.tolerances import SP_AXIS_UNIT_TOL, SP_EXACT_TOL


def sp6(h, k, p, d) -> SubproblemSolutions:
    """Solve for (t1, t2), up to 4 solutions:

        h1^T R(k1, t1) p1 + h2^T R(k2, t2) p2 = d1
        h3^T R(k3, t1) p3 + h4^T R(k4, t2) p4 = d2

    IK-Geo subproblem 6 (Elias & Wen 2022, arXiv:2211.05737, section on the subproblems):
    with R(k, t) p = (k . p) k + A(k, p) x, both equations are linear in x1 = (sin t1, cos t1)
    and x2 = (sin t2, cos t2), M [x1; x2] = b with M 2x4, and |x1| = |x2| = 1. IK-Geo intersects
    the two ellipses of the null-space parametrisation by a quartic; here the better-conditioned
    2x2 block is eliminated (det x2 = adj(M2)(b - M1 x1)) and |x2|^2 = 1 becomes a quartic in
    the tangent half-angle of t1, shifted so that no root is near infinity (``two_circles``). Every returned solution has a residual within SP_EXACT_TOL:
    when none exists nothing is returned (no least-squares solution for sp6, as in IK-Geo).

    h, k, p (..., 4, 3): rows i = 1..4 of the equations above (k rows unit axes, h need not be
    unit); d (..., 2). Slots m = 4, angles j = 2 (t1, t2); ``residual`` = the 2-norm of the two
    equations' errors (units of h^T p).

    Degenerate (``degenerate``): an angle that enters neither equation (for example h1 and h3
    along k1 and k3): it is free, returned as 0, with the other angle from the two equations
    (one slot, when they have a solution); M of rank below 2 (the two equations proportional,
    or both angles absent): a continuum of solutions or none, nothing returned.
    Wrong shapes, NaN or non-unit axes: InputError.
    """
    h = as_finite_array(h, "sp6 h", last_dim=3, ndim_min=2)
    k = as_finite_array(k, "sp6 k", last_dim=3, ndim_min=2)
    p = as_finite_array(p, "sp6 p", last_dim=3, ndim_min=2)
    d = as_finite_array(d, "sp6 d", last_dim=2)
    for name, arr in (("h", h), ("k", k), ("p", p)):
        if arr.shape[-2] != 4:
            raise InputError(f"sp6 {name}: expected shape (..., 4, 3), got {arr.shape}")
    if np.any(np.abs(np.linalg.norm(k, axis=-1) - 1) > SP_AXIS_UNIT_TOL):
        raise InputError("sp6 k: every rotation axis must be a unit vector")
    shape = batch_shape((h, 2), (k, 2), (p, 2), (d, 1))
    h, k, p = (np.broadcast_to(v, shape + (4, 3)).reshape(-1, 4, 3) for v in (h, k, p))
    d = np.broadcast_to(d, shape + (2,)).reshape(-1, 2)
    a, axial = a_matrix(k, p)                                  # (n, 4, 3, 2), (n, 4, 3)
    coef = np.einsum("nqij,nqi->nqj", a, h)                    # (n, 4, 2)
    m = np.concatenate([coef[:, 0::2], coef[:, 1::2]], axis=-1)  # rows (1,2), (3,4); cols x1, x2
    b = d - (dot(h, axial)[:, 0::2] + dot(h, axial)[:, 1::2])
    t1, t2, ok, degenerate = two_circles(m, b)
    rows = []
    for q, t in ((0, t1), (1, t2), (2, t1), (3, t2)):
        rows.append(dot(h[:, None, q], rot(k[:, None, q], t, p[:, None, q])))
    err = np.stack([rows[0] + rows[1] - d[:, None, 0], rows[2] + rows[3] - d[:, None, 1]], axis=-1)
    residual = np.linalg.norm(err, axis=-1)
    valid = ok & (residual <= SP_EXACT_TOL)
    out = finish(np.stack([t1, t2], axis=-1), valid, residual, degenerate)
    return SubproblemSolutions(*(getattr(out, f).reshape(shape + getattr(out, f).shape[1:])
                                 for f in ("theta", "valid", "residual", "exact", "degenerate")))
