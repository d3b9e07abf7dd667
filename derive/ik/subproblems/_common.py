"""Shared pieces of the subproblem library: input checks, the rotation, the result type and the
two small solvers the subproblems reduce to.

Notation (Elias & Wen, IK-Geo, 2022/2024, section III): for a unit axis ``k`` and a vector ``p``,

    R(k, theta) p = (k . p) k + A(k, p) x,   A(k, p) = [k x p, p - (k . p) k],
    x = (sin theta, cos theta),

the Rodrigues formula with the two columns of A orthogonal and of equal length |k x p|. Every
subproblem is linear in such unit 2-vectors x; ``circle_line`` solves one linear equation in one
of them, ``two_circles`` two linear equations in two of them (sp5, sp6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from derive.algebra.angles import wrap_angle
from derive.errors import InputError, as_finite_array
from derive.ik.tolerances import (SP_AXIS_UNIT_TOL, SP_EXACT_TOL, SP_FREE_ANGLE, SP_RANK_TOL,
                                  SP_ROOT_MODULUS)


@dataclass(frozen=True)
class SubproblemSolutions:
    """All solutions of a batch of one subproblem.

    ``theta`` (..., m, j): j angles (radians, in (-pi, pi]) for each of the m solution slots of
    each instance; ``valid`` (..., m) bool: which slots hold a solution (the others hold NaN in
    ``theta`` and ``residual``: never read without ``valid``); ``residual`` (..., m): the norm of
    the subproblem's equation residual at the slot's angles (its units are in each function's
    docstring); ``exact`` (...) bool: the returned solutions solve the equation (residual at or
    below ``SP_EXACT_TOL``), otherwise they are least-squares solutions (``ls``) or there are none;
    ``degenerate`` (...) bool: the instance is one of the subproblem's degenerate cases (a free
    angle, returned as 0, or a continuum that is not enumerated), as each docstring states.
    The leading shape (...) is the broadcast of the inputs' leading shapes.
    """

    theta: np.ndarray
    valid: np.ndarray
    residual: np.ndarray
    exact: np.ndarray
    degenerate: np.ndarray

    @property
    def count(self) -> np.ndarray:
        """Number of solutions of each instance (...)."""
        return self.valid.sum(axis=-1)

    @property
    def ls(self) -> np.ndarray:
        """(...) bool: solutions were returned and they are least-squares, not exact."""
        return self.valid.any(axis=-1) & ~self.exact

    def solutions(self, index=()) -> np.ndarray:
        """The valid solutions of one instance as an (n, j) array (``index`` into the batch)."""
        return self.theta[index][self.valid[index]]


# --- input checks --------------------------------------------------------------------------

def vector(value, name: str) -> np.ndarray:
    """A finite 3-vector or a batch (..., 3) of them, else InputError."""
    return as_finite_array(value, name, last_dim=3)


def axis(value, name: str) -> np.ndarray:
    """A unit 3-vector (or batch of them) within ``SP_AXIS_UNIT_TOL``, else InputError."""
    k = vector(value, name)
    norm = np.linalg.norm(k, axis=-1)
    bad = np.abs(norm - 1.0) > SP_AXIS_UNIT_TOL
    if np.any(bad):
        where = tuple(int(i) for i in np.argwhere(np.atleast_1d(bad))[0]) if norm.ndim else ()
        raise InputError(f"{name}: a rotation axis must be a unit vector, got norm "
                         f"{np.atleast_1d(norm)[where] if where else float(norm):.17g}"
                         + (f" at index {where}" if where else ""))
    return k


def scalar(value, name: str) -> np.ndarray:
    """A finite number or an array of them (the batch's leading shape)."""
    return as_finite_array(value, name, ndim_min=0)


def batch_shape(*arrays_and_trailing) -> tuple:
    """Broadcast leading shape of (array, number of trailing axes) pairs, else InputError."""
    shapes = [a.shape[: a.ndim - t] for a, t in arrays_and_trailing]
    try:
        return np.broadcast_shapes(*shapes)
    except ValueError:
        raise InputError("subproblem inputs: leading (batch) shapes do not broadcast: "
                         + ", ".join(str(s) for s in shapes)) from None


# --- small vector algebra (batched over leading axes) ---------------------------------------

def dot(a, b):
    """a . b over the last axis; a constant vector (3,) against a batch (n, 3) is one matrix
    product."""
    if a.ndim == 1 and b.ndim <= 2:
        return b @ a
    if b.ndim == 1 and a.ndim <= 2:
        return a @ b
    return np.einsum("...i,...i->...", a, b)


def cross(a, b):
    """a x b over the last axis: numpy's component formulas on the components (strided views),
    without np.cross's broadcast copies and moved axes; a constant axis (3,) enters as numbers."""
    shape = np.broadcast_shapes(a.shape[:-1], b.shape[:-1])
    out = np.empty(shape + (3,))
    tmp = np.empty(shape)
    for j, (i, k) in enumerate(((1, 2), (2, 0), (0, 1))):
        np.multiply(a[..., i], b[..., k], out=out[..., j])
        np.multiply(a[..., k], b[..., i], out=tmp)
        np.subtract(out[..., j], tmp, out=out[..., j])
    return out


def rot(k, theta, p):
    """R(k, theta) p by the Rodrigues formula; k (..., 3) unit, theta (...), p (..., 3).

    c p + s (k x p) + (1 - c)(k . p) k, evaluated per component (arrays of the batch's length,
    not rows of three; a constant axis (3,) enters as three numbers) into two scratch arrays:
    the same operations as the vector formula, without its temporaries."""
    k, p = np.asarray(k, dtype=float), np.asarray(p, dtype=float)
    theta = np.asarray(theta, dtype=float)
    c, s = np.cos(theta), np.sin(theta)
    w = (1.0 - c) * dot(k, p)
    shape = np.broadcast_shapes(c.shape, k.shape[:-1], p.shape[:-1])
    out = np.empty(shape + (3,))
    t1, t2 = np.empty(shape), np.empty(shape)
    for j, (a, b) in enumerate(((1, 2), (2, 0), (0, 1))):
        np.multiply(k[..., a], p[..., b], out=t1)
        np.multiply(k[..., b], p[..., a], out=t2)
        np.subtract(t1, t2, out=t1)                         # (k x p)_j
        np.multiply(s, t1, out=t1)
        np.multiply(c, p[..., j], out=t2)
        np.add(t2, t1, out=t2)
        np.multiply(w, k[..., j], out=t1)
        np.add(t2, t1, out=out[..., j])
    return out


def a_matrix(k, p):
    """A(k, p) = [k x p, p - (k . p) k] as (..., 3, 2), and the axial part (k . p) k."""
    kxp = np.cross(np.broadcast_to(k, np.broadcast_shapes(k.shape, p.shape)), p)
    axial = dot(k, p)[..., None] * k
    return np.stack([kxp, p - axial], axis=-1), axial


def a_coef(k, p, h):
    """A(k, p)^T h as its two components (h . (k x p), h . (p - (k . p) k)), and the axial
    part (k . p) k: the line a . x of ``circle_line`` without building A."""
    return a_coef_with(k, p, h, cross(k, p))


def a_coef_with(k, p, h, kxp):
    """``a_coef`` with k x p given. A constant axis k (3,) (the compositions' steps) takes two
    dot products; a batch of axes goes through A^T h as before (the same sums, bit for bit)."""
    axial = np.asarray(dot(k, p))[..., None] * k
    if k.ndim == 1:
        return dot(kxp, h), dot(p - axial, h), axial
    coef = np.einsum("...ij,...i->...j", np.stack([kxp, p - axial], axis=-1), h)
    return coef[..., 0], coef[..., 1], axial


def wrap_pi(a):
    """``wrap_angle`` of angles in [-pi, pi] (atan2's range), bit for bit, without np.mod:
    a + pi lies in [0, 2 pi] there, where np.mod is the identity but at 2 pi (exact: Sterbenz)."""
    w = np.asarray(a, dtype=float) + np.pi
    np.subtract(w, 2.0 * np.pi, out=w, where=w >= 2.0 * np.pi)
    w -= np.pi
    np.add(w, 2.0 * np.pi, out=w, where=w <= -np.pi)
    return w


def angle(x):
    """theta from x = (sin theta, cos theta) (..., 2)."""
    return np.arctan2(x[..., 0], x[..., 1])


# --- one linear equation in one unit 2-vector -----------------------------------------------

def circle_line(a, beta):
    """Solve a . x = beta with |x| = 1 for x = (sin theta, cos theta) (IK-Geo's subproblem 4 core).

    a (..., 2), beta (...). Returns (theta (..., 2), two (...) bool, free (...) bool):

    - |a|^2 > beta^2 (or equal): two solutions x = (a beta +- sqrt(|a|^2 - beta^2) J a) / |a|^2,
      J a = (a_2, -a_1), in slots 0 and 1 (``two`` True);
    - |a| < |beta|: the least-squares solution x = a sign(beta) / |a| (minimises |a . x - beta|)
      in slot 0, slot 1 a copy (``two`` False);
    - |a| below SP_FREE_ANGLE: theta does not enter the equation (``free``), slot 0 is 0.
    """
    return circle_line2(a[..., 0], a[..., 1], beta)


def circle_line2(a0, a1, beta):
    """``circle_line`` with a given as its components a0, a1 (broadcasting with beta)."""
    norm2 = a0 * a0 + a1 * a1
    free = norm2 <= SP_FREE_ANGLE ** 2
    safe = np.where(free, 1.0, norm2)
    disc = norm2 - beta * beta
    two = (disc >= 0.0) & ~free
    root = np.sqrt(np.where(two, disc, 0.0))
    b0, b1 = a0 * beta, a1 * beta
    r0, r1 = root * a1, root * a0
    theta = np.empty(np.broadcast_shapes(np.shape(norm2), np.shape(beta)) + (2,))
    np.arctan2((b0 + r0) / safe, (b1 - r1) / safe, out=theta[..., 0])
    np.arctan2((b0 - r0) / safe, (b1 + r1) / safe, out=theta[..., 1])
    if not np.all(two):                     # least-squares slots: x = a sign(beta) / |a|
        sign = np.where(beta < 0, -1.0, 1.0)
        ls = np.arctan2(a0 * sign, a1 * sign)[..., None]
        np.copyto(theta, np.broadcast_to(ls, theta.shape), where=~two[..., None])
    if np.any(free):
        np.copyto(theta, 0.0, where=free[..., None])
    return theta, two, free


# --- two linear equations in two unit 2-vectors (sp5, sp6) ----------------------------------

def _trig_roots(coef):
    """Real roots t of F(t) = A0 + A1 cos t + B1 sin t + A2 cos 2t + B2 sin 2t = 0 (up to 4).

    ``coef`` (n, 5) = (A0, A1, B1, A2, B2). The angle is shifted, t = t0 + s, so that s = pi
    (where the tangent half-angle u = tan(s/2) is infinite) is where |F| is largest among eight
    samples; with u, (1 + u^2)^2 F is the real quartic

        (A0 - A1' + A2') u^4 + (2 B1' - 4 B2') u^3 + (2 A0 - 6 A2') u^2 + (2 B1' + 4 B2') u
        + (A0 + A1' + A2'),

    (A1', B1') and (A2', B2') the coefficients rotated by t0 and 2 t0; its leading coefficient
    is F(t0 + pi), so no root is near infinity and no angle is lost at pi. Roots are the
    eigenvalues of the companion matrix; u counts as real when 2 |Im u| / (1 + |u|^2) (the
    distance of exp(i s) from the unit circle, to first order) is below SP_ROOT_MODULUS. Two
    Newton steps on F polish them. F vanishing at all eight samples is F = 0 (a trigonometric
    polynomial of degree 2 has at most 4 roots in a period): no root is reported. Returns
    t (n, 4) and ok (n, 4).
    """
    a0, a1, b1, a2, b2 = (coef[:, i] for i in range(5))
    n = coef.shape[0]
    samples = np.arange(8) * (np.pi / 4)
    f_s = (a0[:, None] + a1[:, None] * np.cos(samples) + b1[:, None] * np.sin(samples)
           + a2[:, None] * np.cos(2 * samples) + b2[:, None] * np.sin(2 * samples))
    best = np.argmax(np.abs(f_s), axis=-1)
    lead = f_s[np.arange(n), best]
    t0 = samples[best] - np.pi
    c0, s0, c20, s20 = np.cos(t0), np.sin(t0), np.cos(2 * t0), np.sin(2 * t0)
    a1r, b1r = a1 * c0 + b1 * s0, b1 * c0 - a1 * s0
    a2r, b2r = a2 * c20 + b2 * s20, b2 * c20 - a2 * s20
    scale = np.max(np.abs(coef), axis=-1)
    t = np.zeros((n, 4))
    ok = np.zeros((n, 4), dtype=bool)
    live = np.abs(lead) > 1e-12 * scale
    if np.any(live):
        poly = np.stack([2 * b1r - 4 * b2r, 2 * a0 - 6 * a2r, 2 * b1r + 4 * b2r, a0 + a1r + a2r],
                        axis=-1)[live] / lead[live, None]
        comp = np.zeros((poly.shape[0], 4, 4))
        comp[:, 0, :] = -poly
        comp[:, 1, 0] = comp[:, 2, 1] = comp[:, 3, 2] = 1.0
        u = np.linalg.eigvals(comp)
        t[live] = t0[live, None] + 2 * np.arctan(u.real)
        ok[live] = 2 * np.abs(u.imag) / (1 + np.abs(u) ** 2) < SP_ROOT_MODULUS
    for _ in range(2):
        c, s, c2, s2 = np.cos(t), np.sin(t), np.cos(2 * t), np.sin(2 * t)
        f = a0[:, None] + a1[:, None] * c + b1[:, None] * s + a2[:, None] * c2 + b2[:, None] * s2
        df = -a1[:, None] * s + b1[:, None] * c - 2 * a2[:, None] * s2 + 2 * b2[:, None] * c2
        big = np.abs(df) > 1e-8 * np.maximum(scale[:, None], 1e-300)
        step = np.where(big, f / np.where(big, df, 1.0), 0.0)
        t = np.where(ok & (np.abs(step) < 1e-3), t - step, t)
    return np.arctan2(np.sin(t), np.cos(t)), ok

def _solve_b(m, b, ta):
    """x_b of M [x_a; x_b] = b for given t_a (n, s) when M's b-block is invertible."""
    ma, mb = m[:, :, None, 0:2], m[:, :, None, 2:4]
    xa = np.stack([np.sin(ta), np.cos(ta)], axis=-1)          # (n, s, 2)
    r = b[:, :, None] - np.einsum("nrsi,nsi->nrs", np.broadcast_to(ma, (m.shape[0], 2, ta.shape[1], 2)), xa)
    det = mb[:, 0, 0, 0] * mb[:, 1, 0, 1] - mb[:, 0, 0, 1] * mb[:, 1, 0, 0]
    xb0 = (mb[:, 1, 0, 1][:, None] * r[:, 0] - mb[:, 0, 0, 1][:, None] * r[:, 1]) / det[:, None]
    xb1 = (-mb[:, 1, 0, 0][:, None] * r[:, 0] + mb[:, 0, 0, 0][:, None] * r[:, 1]) / det[:, None]
    return np.arctan2(xb0, xb1)


def _generic(m, b):
    """Both unknown unit vectors through the quartic when M's b-block is invertible (n rows)."""
    ma, mb = m[:, :, 0:2], m[:, :, 2:4]
    det = mb[:, 0, 0] * mb[:, 1, 1] - mb[:, 0, 1] * mb[:, 1, 0]
    adj = np.stack([np.stack([mb[:, 1, 1], -mb[:, 0, 1]], -1),
                    np.stack([-mb[:, 1, 0], mb[:, 0, 0]], -1)], axis=-2)
    # det x_b = adj (b - Ma x_a): |adj (b - Ma x_a)|^2 = det^2 is quadratic in (sin, cos) of t_a.
    g = np.einsum("nij,nj->ni", adj, b)
    gm = np.einsum("nij,njk->nik", adj, ma)
    pmat = np.einsum("nji,njk->nik", gm, gm)
    lin = np.einsum("nji,nj->ni", gm, g)                       # G^T g, coefficients of (s, c)
    coef = np.stack([dot(g, g) - det ** 2 + (pmat[:, 0, 0] + pmat[:, 1, 1]) / 2,
                     -2 * lin[:, 1], -2 * lin[:, 0],
                     (pmat[:, 1, 1] - pmat[:, 0, 0]) / 2, pmat[:, 0, 1]], axis=-1)
    ta, ok = _trig_roots(coef)
    tb = _solve_b(m, b, ta)
    return ta, tb, ok


def _rank_one(mi, bi):
    """One instance whose two blocks both have rank <= 1: M's b-block = s1 u1 v1^T; then
    u2^T Ma x_a = u2^T b and s1 v1^T x_b = u1^T (b - Ma x_a), two circle_line equations.
    Returns (ta (4,), tb (4,), ok (4,), degenerate)."""
    ta, tb, ok = np.zeros(4), np.zeros(4), np.zeros(4, dtype=bool)
    u, s, _vt = np.linalg.svd(mi[:, 2:4])
    if s[0] <= SP_RANK_TOL:                # rows are unit: relative
        return ta, tb, ok, True            # x_b does not enter: t_b free
    u1, u2 = u[:, 0], u[:, 1]
    th_a, two_a, free_a = circle_line(u2 @ mi[:, 0:2], np.asarray(u2 @ bi))
    if free_a:
        return ta, tb, ok, True            # M has rank 1: a continuum
    slot = 0
    for ia in range(2 if two_a else 1):
        xa = np.array([np.sin(th_a[ia]), np.cos(th_a[ia])])
        th_b, two_b, _free = circle_line(u1 @ mi[:, 2:4], np.asarray(u1 @ (bi - mi[:, 0:2] @ xa)))
        for ib in range(2 if two_b else 1):
            ta[slot], tb[slot], ok[slot] = th_a[ia], th_b[ib], True
            slot += 1
    return ta, tb, ok, False


def two_circles(m, b):
    """Solve M [x_a; x_b] = b, x_a = (sin t_a, cos t_a), x_b = (sin t_b, cos t_b): up to 4 (t_a, t_b).

    m (n, 2, 4), b (n, 2). Each row is scaled to unit norm first. The better-conditioned 2x2 block
    (|det| / squared Frobenius norm) is eliminated (``det x = adj (...)``): |x|^2 = 1 becomes a
    trigonometric polynomial of degree 2 in the other angle, whose roots are those of a real
    quartic (``_trig_roots``; IK-Geo too solves sp5 and sp6 through a quartic, with other
    unknowns). Both blocks of rank 1 (below SP_RANK_TOL): two circle_line steps. A vanishing block
    (norm below SP_RANK_TOL): that angle is free (degenerate), returned as 0, with the other unit
    vector solved from its invertible block. M of rank <= 1 (second singular value below
    SP_RANK_TOL times the first): a continuum or nothing, reported as degenerate with no
    solution. Candidates are not yet checked (the caller computes residuals).
    Returns ta (n, 4), tb (n, 4), ok (n, 4), degenerate (n,).
    """
    n = m.shape[0]
    rown = np.linalg.norm(m, axis=-1)
    degenerate = np.any(rown <= SP_FREE_ANGLE, axis=-1)
    rown = np.where(rown > SP_FREE_ANGLE, rown, 1.0)
    m = m / rown[..., None]
    b = b / rown
    # singular values of the unit-row M: s1 s2 = |r0 ^ r1| (the wedge, stable for near-parallel
    # rows), s1^2 + s2^2 = 2, so s2 / s1 = |r0 ^ r1| / s1^2
    r0, r1 = m[:, 0], m[:, 1]
    wedge = r0[:, :, None] * r1[:, None, :] - r0[:, None, :] * r1[:, :, None]
    area = np.sqrt(np.sum(wedge ** 2, axis=(-2, -1)) / 2)
    ratio = area / (1 + np.sqrt(np.maximum(1 - area ** 2, 0.0)))
    degenerate |= ratio <= SP_RANK_TOL

    def cond(block):
        det = block[:, 0, 0] * block[:, 1, 1] - block[:, 0, 1] * block[:, 1, 0]
        return np.abs(det) / np.maximum(np.sum(block ** 2, axis=(-2, -1)), 1e-300)

    # One angle enters neither equation (its block vanishes): it is free, returned as 0, and the
    # other unit vector is the block's solution (kept by the caller only if its residual is small).
    free_a = np.linalg.norm(m[:, :, 0:2], axis=(-2, -1)) <= SP_RANK_TOL
    free_b = np.linalg.norm(m[:, :, 2:4], axis=(-2, -1)) <= SP_RANK_TOL
    degenerate |= free_a | free_b
    ca = np.where(free_a, 0.0, cond(m[:, :, 0:2]))
    cb = np.where(free_b, 0.0, cond(m[:, :, 2:4]))
    swap = ca > cb
    rank1 = np.maximum(ca, cb) < SP_RANK_TOL
    ms = np.where(swap[:, None, None], m[:, :, [2, 3, 0, 1]], m)
    ta = np.zeros((n, 4))
    tb = np.zeros((n, 4))
    ok = np.zeros((n, 4), dtype=bool)
    gen = ~rank1 & ~degenerate
    if np.any(gen):
        t1, t2, k = _generic(ms[gen], b[gen])
        ta[gen], tb[gen], ok[gen] = t1, t2, k
    for i in np.flatnonzero(rank1 & ~degenerate):
        ta[i], tb[i], ok[i], deg = _rank_one(ms[i], b[i])
        degenerate[i] = deg
    for i in np.flatnonzero((free_a ^ free_b) & (np.maximum(ca, cb) >= SP_RANK_TOL)):
        x = np.linalg.solve(ms[i][:, 2:4], b[i])         # ms has the free block first
        ta[i, 0], tb[i, 0], ok[i, 0] = 0.0, np.arctan2(x[0], x[1]), True
    ta, tb = np.where(swap[:, None], tb, ta), np.where(swap[:, None], ta, tb)
    return ta, tb, ok, degenerate


def finish(theta, valid, residual, degenerate) -> SubproblemSolutions:
    """Wrap the angles to (-pi, pi], blank invalid slots with NaN (flagged by ``valid``) and set
    ``exact`` from the residuals."""
    valid = valid & np.all(np.isfinite(theta), axis=-1) & np.isfinite(residual)
    exact = np.asarray(np.all(~valid | (residual <= SP_EXACT_TOL), axis=-1) & valid.any(axis=-1))
    theta = np.where(valid[..., None], wrap_angle(np.where(valid[..., None], theta, 0.0)), np.nan)
    residual = np.where(valid, residual, np.nan)
    return SubproblemSolutions(theta=theta, valid=valid, residual=residual, exact=exact,
                               degenerate=np.asarray(degenerate, dtype=bool))


def double_root(theta, at):
    """The two roots (..., 2) of a two-slot subproblem (one angle; slot 1 NaN where it returned
    one least-squares root) with both slots set to their middle (the double root) where ``at``
    (...) holds or slot 1 is missing: a class's rule for where two roots are one (the solvers of
    :mod:`derive.ik.srs` and :mod:`derive.ik.panda` decide it on their own cosines)."""
    first = theta[..., 0]
    second = np.where(np.isnan(theta[..., 1]), first, theta[..., 1])
    mid = first + 0.5 * wrap_angle(second - first)
    return np.where(at[..., None] | np.isnan(theta[..., 1:]), mid[..., None], theta)
