"""Subproblem 5 (IK-Geo): three angles from a point equation with two rotations on one side."""

from __future__ import annotations

import numpy as np

from derive.ik.subproblems._common import (SubproblemSolutions, a_matrix, axis, batch_shape, dot,
                                           finish, rot, two_circles, vector)
from derive.ik.subproblems.sp1 import angle_sp1
from derive.ik.tolerances import SP_EXACT_TOL


def sp5(p0, p1, p2, p3, k1, k2, k3) -> SubproblemSolutions:
    """Solve p0 + R(k1, t1) p1 = R(k2, t2) (p2 + R(k3, t3) p3) for (t1, t2, t3): up to 4.

    IK-Geo subproblem 5 (Elias & Wen 2022, arXiv:2211.05737, section on the subproblems). The point
    v1 = p0 + R(k1, t1) p1 (a circle about k1) equals R(k2, t2) v3, v3 = p2 + R(k3, t3) p3 (a
    circle about k3), for some t2 exactly when v1 and v3 have the same height along k2 and the
    same norm (both on one circle about k2):

        k2 . v1 = k2 . v3,    |v1|^2 = |v3|^2.

    With v = c + A x (x = (sin t, cos t), |A x|^2 = |k x p|^2 constant) both are linear in x1
    and x3, so (t1, t3) solve the same two-unit-vector system as sp6 (a quartic; IK-Geo gets its
    quartic in the height H along k2 instead), and t2 = sp1(k2, v3 -> v1). Every returned solution
    has a residual within SP_EXACT_TOL; when none exists nothing is returned (no least-squares
    solution, as in IK-Geo).

    p0..p3 (..., 3) in metres, k1..k3 (..., 3) unit axes. Slots m = 4, angles j = 3
    (t1, t2, t3); ``residual`` = ||p0 + R(k1, t1) p1 - R(k2, t2)(p2 + R(k3, t3) p3)|| (m).

    Degenerate (``degenerate``): the two conditions of rank below 2 in (x1, x3) (for example k1,
    k2, k3 all parallel, or p1 on k1 and p3 on k3): a continuum or none, nothing returned; v3 on
    the axis k2 for a returned solution: t2 free, returned as 0. Wrong shapes, NaN or non-unit
    axes: InputError.
    """
    p0, p1, p2, p3 = (vector(v, f"sp5 p{i}") for i, v in enumerate((p0, p1, p2, p3)))
    k1, k2, k3 = (axis(v, f"sp5 k{i + 1}") for i, v in enumerate((k1, k2, k3)))
    shape = batch_shape(*((v, 1) for v in (p0, p1, p2, p3, k1, k2, k3)))
    p0, p1, p2, p3, k1, k2, k3 = (np.broadcast_to(v, shape + (3,)).reshape(-1, 3)
                                  for v in (p0, p1, p2, p3, k1, k2, k3))
    a1, ax1 = a_matrix(k1, p1)
    a3, ax3 = a_matrix(k3, p3)
    c1, c3 = p0 + ax1, p2 + ax3
    r1 = dot(np.cross(k1, p1), np.cross(k1, p1))
    r3 = dot(np.cross(k3, p3), np.cross(k3, p3))
    row_h = np.concatenate([np.einsum("nij,ni->nj", a1, k2), -np.einsum("nij,ni->nj", a3, k2)], -1)
    row_n = np.concatenate([2 * np.einsum("nij,ni->nj", a1, c1), -2 * np.einsum("nij,ni->nj", a3, c3)], -1)
    m = np.stack([row_h, row_n], axis=1)
    b = np.stack([dot(k2, c3) - dot(k2, c1), dot(c3, c3) + r3 - dot(c1, c1) - r1], axis=-1)
    t1, t3, ok, degenerate = two_circles(m, b)
    v1 = p0[:, None] + rot(k1[:, None], t1, p1[:, None])
    v3 = p2[:, None] + rot(k3[:, None], t3, p3[:, None])
    t2, free2 = angle_sp1(np.broadcast_to(k2[:, None], v3.shape), v3, v1)
    residual = np.linalg.norm(v1 - rot(k2[:, None], t2, v3), axis=-1)
    valid = ok & (residual <= SP_EXACT_TOL)
    degenerate = degenerate | np.any(valid & free2, axis=-1)
    out = finish(np.stack([t1, t2, t3], axis=-1), valid, residual, degenerate)
    return SubproblemSolutions(*(getattr(out, f).reshape(shape + getattr(out, f).shape[1:])
                                 for f in ("theta", "valid", "residual", "exact", "degenerate")))
