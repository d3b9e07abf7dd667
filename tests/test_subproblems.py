"""The subproblem library (derive/ik/subproblems): instances built from known angles, as IK-Geo's
own tests do; every returned solution checked with scipy's rotations (an independent rotation
path); least-squares solutions against a dense grid polished by scipy; the number of solutions
against an independent root count (sign changes of a 1-D function on a dense grid, roots by
scipy's brentq); degenerate inputs and bad inputs.

Outside reference: neither ``ik-geo`` 1.0.3 (its Python module exposes only ``Robot``) nor
``eaik`` (``eaik.pybindings.EAIK`` exposes ``Robot`` and ``IKSolution``) exposes its subproblem
solvers in Python, so scipy is the outside path here.
"""

import numpy as np
import pytest
from scipy.optimize import brentq, minimize
from scipy.spatial.transform import Rotation

from derive.algebra.angles import wrap_angle
from derive.errors import InputError
from derive.ik.subproblems import sp1, sp2, sp3, sp4, sp5, sp6
from derive.ik.tolerances import SP_EXACT_TOL

N = 200            # instances per batched test
TOL_ANGLE = 1e-10  # the generating angle among the solutions (measured worst: about 5e-12)


def unit(rng, *shape):
    v = rng.normal(size=shape + (3,))
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def R(k, t):
    """Rotation matrices by scipy (not the library's Rodrigues formula); k (..., 3), t (...)."""
    k, t = np.broadcast_arrays(np.asarray(k, float), np.asarray(t, float)[..., None])
    return Rotation.from_rotvec((k * t).reshape(-1, 3)).as_matrix().reshape(k.shape[:-1] + (3, 3))


def Rp(k, t, p):
    return np.einsum("...ij,...j->...i", R(k, t), p)


def wrapped(a, b):
    return np.abs(np.angle(np.exp(1j * (np.asarray(a) - np.asarray(b)))))


def closest_to(sol, known):
    """Per instance, the max-over-angles wrapped distance of the nearest valid solution."""
    dist = wrapped(sol.theta, known[..., None, :]).max(axis=-1)
    return np.where(sol.valid, dist, np.inf).min(axis=-1)


# --- sp1 -----------------------------------------------------------------------------------

def test_sp1_known_angle_exact():
    rng = np.random.default_rng(1)
    k, p1, t = unit(rng, N), rng.normal(size=(N, 3)), rng.uniform(-np.pi, np.pi, N)
    sol = sp1(k, p1, Rp(k, t, p1))
    assert sol.theta.shape == (N, 1, 1) and sol.valid.all()
    assert closest_to(sol, t[:, None]).max() < 1e-12
    assert sol.exact.all() and not sol.ls.any() and not sol.degenerate.any()
    assert np.abs(Rp(k, sol.theta[:, 0, 0], p1) - Rp(k, t, p1)).max() < 1e-12


def test_sp1_least_squares_minimises():
    rng = np.random.default_rng(2)
    grid = np.linspace(-np.pi, np.pi, 20001)
    for _ in range(10):
        k, p1, p2 = unit(rng), rng.normal(size=3), rng.normal(size=3)
        sol = sp1(k, p1, p2)
        assert sol.ls and not sol.exact
        cost = np.linalg.norm(Rp(k, grid, p1) - p2, axis=-1)
        best = minimize(lambda t: np.linalg.norm(Rp(k, t[0], p1) - p2), [grid[np.argmin(cost)]],
                        method="Nelder-Mead", options={"xatol": 1e-12, "fatol": 1e-15}).fun
        assert sol.residual[0] <= best + 1e-12
        assert sol.residual[0] == pytest.approx(np.linalg.norm(Rp(k, sol.theta[0, 0], p1) - p2), abs=1e-14)


def test_angles_in_half_open_interval():
    """A half turn is +pi, never -pi (atan2 gives -pi for a -0.0 sine): (-pi, pi]."""
    z, x = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    assert np.arctan2(np.cross(z, x) @ -x, x @ -x) in (np.pi, -np.pi)
    assert sp1(z, x, -x).theta[0, 0] == np.pi
    assert sp1(z, [1.0, -0.0, 0.0], [-1.0, -0.0, 0.0]).theta[0, 0] == np.pi
    assert sp4(-x, z, x, 1.0).solutions().ravel().tolist() == [np.pi, np.pi]


def test_sp1_degenerate():
    k = np.array([0.0, 0.0, 1.0])
    on_axis = sp1(k, [0, 0, 2.0], [0, 0, 2.0])          # any theta solves it
    assert on_axis.degenerate and on_axis.exact and on_axis.theta[0, 0] == 0.0
    off = sp1(k, [0, 0, 2.0], [1.0, 0, 0])              # no theta does
    assert off.degenerate and not off.exact and off.valid.all()
    zero = sp1(k, [1.0, 2.0, 0.5], [0, 0, 0.5])
    assert zero.degenerate and not np.isnan(zero.theta).any()


# --- sp2 -----------------------------------------------------------------------------------

def sp2_instance(rng, n):
    k1, k2, p2 = unit(rng, n), unit(rng, n), rng.normal(size=(n, 3))
    t = rng.uniform(-np.pi, np.pi, (n, 2))
    p1 = Rp(k1, -t[:, 0], Rp(k2, t[:, 1], p2))            # R(k1, t1) p1 = R(k2, t2) p2
    return k1, k2, p1, p2, t


def test_sp2_known_angles_and_every_solution():
    rng = np.random.default_rng(3)
    k1, k2, p1, p2, t = sp2_instance(rng, N)
    sol = sp2(k1, k2, p1, p2)
    assert closest_to(sol, t).max() < TOL_ANGLE
    assert sol.exact.all() and (sol.count == 2).all()
    for j in range(2):
        res = np.linalg.norm(Rp(k1, sol.theta[:, j, 0], p1) - Rp(k2, sol.theta[:, j, 1], p2), axis=-1)
        assert res.max() < 1e-12
    # the two solutions are different points (the circles cross, not touch, for these instances)
    assert wrapped(sol.theta[:, 0], sol.theta[:, 1]).max(axis=-1).min() > 1e-6


def test_sp2_least_squares_minimises():
    rng = np.random.default_rng(4)
    grid = np.linspace(-np.pi, np.pi, 721)
    checked = 0
    while checked < 6:
        k1, k2, p1, p2 = unit(rng), unit(rng), rng.normal(size=3), rng.normal(size=3)
        sol = sp2(k1, k2, p1, p2)
        assert not sol.exact                       # |p1| != |p2|: never exact
        c1, c2 = Rp(k1, grid, p1), Rp(k2, grid, p2)
        cost = np.linalg.norm(c1[:, None] - c2[None], axis=-1)
        i, j = np.unravel_index(np.argmin(cost), cost.shape)
        best = minimize(lambda t: np.linalg.norm(Rp(k1, t[0], p1) - Rp(k2, t[1], p2)),
                        [grid[i], grid[j]], method="Nelder-Mead",
                        options={"xatol": 1e-12, "fatol": 1e-15}).fun
        assert sol.residual[sol.valid].max() <= best + 1e-9
        checked += 1


def test_sp2_degenerate():
    k = np.array([0.0, 0.0, 1.0])
    coaxial = sp2(k, k, [1.0, 0, 0.3], [0, 1.0, 0.3])
    assert coaxial.degenerate and coaxial.exact            # a continuum; a representative returned
    assert np.linalg.norm(Rp(k, coaxial.theta[0, 0], [1.0, 0, 0.3])
                          - Rp(k, coaxial.theta[0, 1], [0, 1.0, 0.3])) < 1e-12
    zero = sp2(k, [1.0, 0, 0], [0, 0, 0], [0, 0, 0])
    assert zero.degenerate and zero.exact and not np.isnan(zero.theta[zero.valid]).any()


# --- sp3 and sp4: every solution, the count against an independent root count ---------------

def roots_1d(f, n=4001):
    """Roots of a 2 pi-periodic f on a grid (sign changes) polished by brentq."""
    grid = np.linspace(-np.pi, np.pi, n)
    v = f(grid)
    idx = np.flatnonzero(np.sign(v[:-1]) != np.sign(v[1:]))
    return np.array([brentq(f, grid[i], grid[i + 1], xtol=1e-15) for i in idx])


def test_sp3_known_angle_count_and_roots():
    rng = np.random.default_rng(5)
    k, p1, p2, t = unit(rng, N), rng.normal(size=(N, 3)), rng.normal(size=(N, 3)), rng.uniform(-np.pi, np.pi, N)
    d = np.linalg.norm(Rp(k, t, p1) - p2, axis=-1)
    sol = sp3(k, p1, p2, d)
    assert sol.exact.all() and closest_to(sol, t[:, None]).max() < TOL_ANGLE
    for j in range(2):
        res = np.abs(np.linalg.norm(Rp(k, sol.theta[:, j, 0], p1) - p2, axis=-1) - d)
        assert res[sol.valid[:, j]].max() < 1e-12
    for i in range(20):
        roots = roots_1d(lambda x: np.linalg.norm(Rp(k[i], x, p1[i]) - p2[i], axis=-1) - d[i])
        assert len(roots) == sol.count[i]
        assert wrapped(np.sort(roots)[:, None], sol.theta[i, :, 0][None]).min(axis=1).max() < 1e-9


def test_sp3_least_squares_and_bad_input():
    rng = np.random.default_rng(6)
    grid = np.linspace(-np.pi, np.pi, 20001)
    for far in (True, False):
        k, p1, p2 = unit(rng), rng.normal(size=3), rng.normal(size=3)
        dist = np.linalg.norm(Rp(k, grid, p1) - p2, axis=-1)
        d = dist.max() + 0.5 if far else dist.min() / 2
        sol = sp3(k, p1, p2, d)
        assert sol.ls and sol.count == 1 and not sol.degenerate
        assert sol.residual[0] <= np.abs(dist - d).min() + 1e-12
    k = np.array([0, 0, 1.0])
    deg = sp3(k, [0, 0, 1.0], [1.0, 0, 0], np.sqrt(2))
    assert deg.degenerate and deg.exact
    with pytest.raises(InputError, match="distance"):
        sp3(k, [1.0, 0, 0], [0, 1.0, 0], -1.0)


def test_sp4_known_angle_count_and_roots():
    rng = np.random.default_rng(7)
    h, k, p, t = unit(rng, N), unit(rng, N), rng.normal(size=(N, 3)), rng.uniform(-np.pi, np.pi, N)
    d = np.einsum("ni,ni->n", h, Rp(k, t, p))
    sol = sp4(h, k, p, d)
    assert sol.exact.all() and (sol.count == 2).all() and closest_to(sol, t[:, None]).max() < TOL_ANGLE
    for j in range(2):
        assert np.abs(np.einsum("ni,ni->n", h, Rp(k, sol.theta[:, j, 0], p)) - d).max() < 1e-12
    for i in range(20):
        roots = roots_1d(lambda x: Rp(k[i], x, p[i]) @ h[i] - d[i])
        assert len(roots) == 2
        assert wrapped(np.sort(roots)[:, None], sol.theta[i, :, 0][None]).min(axis=1).max() < 1e-9


def test_sp4_least_squares_degenerate_and_bad_input():
    rng = np.random.default_rng(8)
    grid = np.linspace(-np.pi, np.pi, 20001)
    h, k, p = unit(rng), unit(rng), rng.normal(size=3)
    val = Rp(k, grid, p) @ h
    sol = sp4(h, k, p, val.max() + 0.3)
    assert sol.ls and sol.count == 1 and sol.residual[0] <= np.abs(val - val.max() - 0.3).min() + 1e-12
    sol = sp4(h, k, p, val.min() - 0.3)
    assert sol.ls and sol.residual[0] <= np.abs(val - val.min() + 0.3).min() + 1e-12
    par = sp4(k, k, p, k @ p)                 # h parallel to k: theta free, and exact here
    assert par.degenerate and par.exact and par.count == 1
    assert sp4(k, k, p, k @ p + 1).degenerate and not sp4(k, k, p, k @ p + 1).exact
    with pytest.raises(InputError, match="unit"):
        sp4(h, 2 * k, p, 0.0)
    with pytest.raises(InputError, match="last dimension"):
        sp4(h[:2], k, p, 0.0)
    with pytest.raises(InputError, match="NaN"):
        sp4(h, k, [np.nan, 0, 0], 0.0)
    with pytest.raises(InputError, match="broadcast"):
        sp4(np.ones((3, 3)), k, np.ones((4, 3)), 0.0)


def test_batch_shapes_broadcast():
    rng = np.random.default_rng(9)
    k, p1 = unit(rng), rng.normal(size=(5, 4, 3))
    sol = sp1(k, p1, p1)
    assert sol.theta.shape == (5, 4, 1, 1) and sol.exact.shape == (5, 4)
    assert np.abs(sol.theta).max() < 1e-12
    one = sp4(k, k, p1[0, 0], 0.1)
    assert one.theta.shape == (2, 1) and one.valid.shape == (2,) and one.exact.shape == ()


# --- sp5 and sp6 ---------------------------------------------------------------------------

def sp6_instance(rng, n):
    h, k, p = unit(rng, n, 4), unit(rng, n, 4), rng.normal(size=(n, 4, 3))
    t = rng.uniform(-np.pi, np.pi, (n, 2))
    val = np.einsum("nqi,nqi->nq", h, Rp(k, t[:, [0, 1, 0, 1]], p))
    return h, k, p, np.stack([val[:, 0] + val[:, 1], val[:, 2] + val[:, 3]], axis=-1), t


def sp6_eqs(h, k, p, d, t1, t2):
    v = [Rp(k[q], t, p[q]) @ h[q] for q, t in ((0, t1), (1, t2), (2, t1), (3, t2))]
    return v[0] + v[1] - d[0], v[2] + v[3] - d[1]


def sp6_root_count(h, k, p, d, n=20001):
    """Independent count: for t1 on a grid, equation 1 gives t2 (two branches, closed form);
    roots are the sign changes of equation 2 along each branch, polished with brentq."""
    def branch(t1, sign):
        a_s, a_c = np.cross(k[1], p[1]) @ h[1], (p[1] - (k[1] @ p[1]) * k[1]) @ h[1]
        rhs = d[0] - Rp(k[0], t1, p[0]) @ h[0] - (k[1] @ p[1]) * (k[1] @ h[1])
        amp = np.hypot(a_s, a_c)
        phi = np.arctan2(a_s, a_c)                       # a_s sin t + a_c cos t = amp cos(t - phi)
        c = np.clip(rhs / amp, -1, 1)
        t2 = phi + sign * np.arccos(c)
        return t2, np.abs(rhs / amp) <= 1
    roots = []
    grid = np.linspace(-np.pi, np.pi, n)
    for sign in (1, -1):
        t2, ok = branch(grid, sign)
        f = sp6_eqs(h, k, p, d, grid, t2)[1]
        for i in np.flatnonzero((np.sign(f[:-1]) != np.sign(f[1:])) & ok[:-1] & ok[1:]):
            g = lambda x: sp6_eqs(h, k, p, d, x, branch(x, sign)[0])[1]
            r = brentq(g, grid[i], grid[i + 1], xtol=1e-15)
            roots.append((r, branch(r, sign)[0]))
    return np.array(roots).reshape(-1, 2)


def test_sp6_known_angles_every_solution_and_count():
    rng = np.random.default_rng(10)
    h, k, p, d, t = sp6_instance(rng, N)
    sol = sp6(h, k, p, d)
    assert sol.valid.any(axis=-1).all() and sol.exact.all() and not sol.degenerate.any()
    assert closest_to(sol, t).max() < TOL_ANGLE
    for i in range(N):
        for t1, t2 in sol.solutions(i):
            assert np.abs(sp6_eqs(h[i], k[i], p[i], d[i], t1, t2)).max() < 1e-11
    assert set(np.unique(sol.count)) <= {2, 4} and (sol.count == 4).any()
    for i in range(12):
        ref = sp6_root_count(h[i], k[i], p[i], d[i])
        assert len(ref) == sol.count[i]
        assert wrapped(ref[:, None], sol.solutions(i)[None]).max(axis=-1).min(axis=1).max() < 1e-8


def test_sp6_both_blocks_rank_one():
    """Equation 2 = (2 x the t1 term, -1 x the t2 term) of equation 1: both 2x2 blocks of M are
    rank 1, the rank-one path; the system splits into u.x1 = (d1+d2)/3, v.x2 = (2 d1 - d2)/3."""
    rng = np.random.default_rng(11)
    for _ in range(20):
        h, k, p, _d, t = sp6_instance(rng, 1)
        h, k, p = h[0], k[0], p[0]
        k[2], p[2], h[2] = k[0], p[0], 2 * h[0]
        k[3], p[3], h[3] = k[1], p[1], -h[1]
        v = [Rp(k[q], t[0, q % 2], p[q]) @ h[q] for q in range(4)]
        d = np.array([v[0] + v[1], v[2] + v[3]])
        sol = sp6(h, k, p, d)
        assert sol.exact and not sol.degenerate and sol.count == 4
        assert closest_to(sol, t[0]) < TOL_ANGLE


def test_sp6_degenerate_and_bad_input():
    rng = np.random.default_rng(12)
    h, k, p, d, t = sp6_instance(rng, 1)
    h, k, p = h[0].copy(), k[0].copy(), p[0]
    h[0], h[2] = k[0], k[2]                         # t1 enters neither equation: free
    val = [Rp(k[q], t[0, q % 2], p[q]) @ h[q] for q in range(4)]
    d = np.array([val[0] + val[1], val[2] + val[3]])
    sol = sp6(h, k, p, d)
    assert sol.degenerate and sol.exact and sol.count == 1
    assert sol.theta[0, 0] == 0.0 and wrapped(sol.theta[0, 1], t[0, 1]) < 1e-12
    assert np.abs(sp6_eqs(h, k, p, d, 0.0, sol.theta[0, 1])).max() < 1e-12
    bad = sp6(h, k, p, d + np.array([1.0, -1.0]))   # no unit x2 solves it: nothing, still flagged
    assert bad.degenerate and bad.count == 0 and not bad.exact
    with pytest.raises(InputError, match="4, 3"):
        sp6(h[:3], k[:3], p[:3], d)
    with pytest.raises(InputError, match="unit"):
        sp6(h, 2 * k, p, d)
    h[1], h[3] = k[1], k[3]                         # neither angle enters: rank 0
    none = sp6(h, k, p, d)
    assert none.degenerate and none.count == 0


def sp5_instance(rng, n):
    p1, p2, p3 = rng.normal(size=(3, n, 3))
    k1, k2, k3 = unit(rng, n), unit(rng, n), unit(rng, n)
    t = rng.uniform(-np.pi, np.pi, (n, 3))
    p0 = Rp(k2, t[:, 1], p2 + Rp(k3, t[:, 2], p3)) - Rp(k1, t[:, 0], p1)
    return p0, p1, p2, p3, k1, k2, k3, t


def sp5_res(args, t):
    p0, p1, p2, p3, k1, k2, k3 = args
    return np.linalg.norm(p0 + Rp(k1, t[..., 0], p1) - Rp(k2, t[..., 1], p2 + Rp(k3, t[..., 2], p3)), axis=-1)


def sp5_root_count(p0, p1, p2, p3, k1, k2, k3, n=20001):
    """Independent count: for t3 on a grid, the height condition k2.v1(t1) = k2.v3 gives t1
    (two branches, closed form); roots are the sign changes of |v1|^2 - |v3|^2 (brentq)."""
    a_s, a_c = np.cross(k1, p1) @ k2, (p1 - (k1 @ p1) * k1) @ k2
    amp, phi = np.hypot(a_s, a_c), np.arctan2(a_s, a_c)

    def branch(t3, sign):
        v3 = p2 + Rp(k3, t3, p3)
        rhs = v3 @ k2 - (p0 + (k1 @ p1) * k1) @ k2
        t1 = phi + sign * np.arccos(np.clip(rhs / amp, -1, 1))
        v1 = p0 + Rp(k1, t1, p1)
        return t1, np.sum(v1 * v1, -1) - np.sum(v3 * v3, -1), np.abs(rhs / amp) <= 1

    roots = []
    grid = np.linspace(-np.pi, np.pi, n)
    for sign in (1, -1):
        _t1, f, ok = branch(grid, sign)
        for i in np.flatnonzero((np.sign(f[:-1]) != np.sign(f[1:])) & ok[:-1] & ok[1:]):
            r = brentq(lambda x: branch(x, sign)[1], grid[i], grid[i + 1], xtol=1e-15)
            roots.append((branch(r, sign)[0], r))
    return np.array(roots).reshape(-1, 2)


def test_sp5_known_angles_every_solution_and_count():
    rng = np.random.default_rng(13)
    *args, t = sp5_instance(rng, N)
    sol = sp5(*args)
    assert sol.exact.all() and not sol.degenerate.any()
    assert closest_to(sol, t).max() < TOL_ANGLE
    res = sp5_res([a[:, None] for a in args], sol.theta)
    assert res[sol.valid].max() < 1e-11
    assert set(np.unique(sol.count)) <= {2, 4} and (sol.count == 4).any()
    for i in range(12):
        ref = sp5_root_count(*(a[i] for a in args))          # (t1, t3) pairs
        assert len(ref) == sol.count[i]
        ours = sol.solutions(i)[:, [0, 2]]
        assert wrapped(ref[:, None], ours[None]).max(axis=-1).min(axis=1).max() < 1e-8


def test_sp5_no_solution_and_degenerate():
    rng = np.random.default_rng(14)
    *args, _t = sp5_instance(rng, 1)
    args = [a[0] for a in args]
    far = list(args)
    far[0] = args[0] + 100 * np.cross(args[4], args[5]) / np.linalg.norm(np.cross(args[4], args[5]))
    far[0] = far[0] + 100.0 * args[5]                         # p0 far away: no solution
    sol = sp5(*far)
    assert sol.count == 0 and not sol.exact and not sol.ls
    z = np.array([0, 0, 1.0])
    deg = sp5(args[0], args[1], args[2], args[3], z, z, z)   # all axes parallel: a continuum or none
    assert deg.degenerate and deg.count == 0


def test_every_residual_is_the_equation():
    """The reported residual is the equation's, recomputed here with scipy's rotations."""
    rng = np.random.default_rng(15)
    k, p1, p2 = unit(rng, 50), rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    sol = sp2(k, unit(rng, 50), p1, p2)
    assert np.all(sol.residual[sol.valid] > SP_EXACT_TOL)   # |p1| != |p2| almost surely
    *args, _t = sp5_instance(rng, 30)
    s5 = sp5(*args)
    ref = sp5_res([a[:, None] for a in args], s5.theta)
    assert np.abs(ref - s5.residual)[s5.valid].max() < 1e-13


# --- the C twin of sp1-sp6 (templates/subproblems.h.j2) against numpy -------------------------

C_WRAPPERS = r"""
#include "subproblems.h"
#define LOOP for (i = 0; i < n; ++i)
void b_sp1(int n, const double *k, const double *p1, const double *p2, double *t, double *r, int *f, int *c)
{ int i; LOOP c[i] = dq_sp1(k + 3 * i, p1 + 3 * i, p2 + 3 * i, t + i, r + i, f + i); }
void b_sp2(int n, const double *k1, const double *k2, const double *p1, const double *p2, double *t1,
           double *t2, double *r, int *f, int *c)
{ int i; LOOP c[i] = dq_sp2(k1 + 3 * i, k2 + 3 * i, p1 + 3 * i, p2 + 3 * i, t1 + 2 * i, t2 + 2 * i, r + 2 * i, f + i); }
void b_sp3(int n, const double *k, const double *p1, const double *p2, const double *d, double *t, double *r, int *f, int *c)
{ int i; LOOP c[i] = dq_sp3(k + 3 * i, p1 + 3 * i, p2 + 3 * i, d[i], t + 2 * i, r + 2 * i, f + i); }
void b_sp4(int n, const double *h, const double *k, const double *p, const double *d, double *t, double *r, int *f, int *c)
{ int i; LOOP c[i] = dq_sp4(h + 3 * i, k + 3 * i, p + 3 * i, d[i], t + 2 * i, r + 2 * i, f + i); }
void b_sp5(int n, const double *p0, const double *p1, const double *p2, const double *p3, const double *k1,
           const double *k2, const double *k3, double *t1, double *t2, double *t3, double *r, int *f, int *c)
{ int i; LOOP c[i] = dq_sp5(p0 + 3 * i, p1 + 3 * i, p2 + 3 * i, p3 + 3 * i, k1 + 3 * i, k2 + 3 * i, k3 + 3 * i,
                            t1 + 4 * i, t2 + 4 * i, t3 + 4 * i, r + 4 * i, f + i); }
void b_sp6(int n, const double *h, const double *k, const double *p, const double *d, double *t1, double *t2,
           double *r, int *f, int *c)
{ int i; LOOP c[i] = dq_sp6(h + 12 * i, k + 12 * i, p + 12 * i, d + 2 * i, t1 + 4 * i, t2 + 4 * i, r + 4 * i, f + i); }
"""


@pytest.fixture(scope="module")
def c_subproblems(tmp_path_factory):
    import ctypes
    import shutil
    import subprocess

    from derive.codegen.subproblems import subproblems_header
    cc, cxx = shutil.which("gcc"), shutil.which("g++")
    if cc is None:
        pytest.skip("no gcc")
    d = tmp_path_factory.mktemp("sp_c")
    (d / "subproblems.h").write_text(subproblems_header(), encoding="utf-8")
    (d / "wrap.c").write_text(C_WRAPPERS, encoding="utf-8")
    warn = ["-Wall", "-Wextra", "-Wpedantic", "-Werror"]
    res = subprocess.run([cc, "-std=c99", "-O2", *warn, "-fPIC", "-shared", "-o", str(d / "libsp.so"),
                          str(d / "wrap.c"), "-lm"], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    if cxx is not None:                       # the header compiles as C++ with warnings as errors
        res = subprocess.run([cxx, "-x", "c++", "-std=c++11", *warn, "-fsyntax-only", str(d / "wrap.c")],
                             capture_output=True, text=True)
        assert res.returncode == 0, res.stderr
    return ctypes.CDLL(str(d / "libsp.so"))


def call_c(lib, name, n, slots, *arrays, angles=1):
    import ctypes
    ins = [np.ascontiguousarray(a, dtype=np.float64) for a in arrays]
    outs = [np.zeros((n, slots)) for _ in range(angles)] + [np.zeros((n, slots))]
    flags, count = np.zeros(n, dtype=np.intc), np.zeros(n, dtype=np.intc)
    ptr = lambda a: a.ctypes.data_as(ctypes.c_void_p)
    getattr(lib, name)(ctypes.c_int(n), *map(ptr, ins), *map(ptr, outs), ptr(flags), ptr(count))
    return outs[:-1], outs[-1], flags, count


def agree(sol, c_angles, c_res, flags, count):
    assert np.array_equal(sol.count, count)
    assert np.array_equal(sol.exact, (flags & 1) == 1)
    assert np.array_equal(sol.degenerate, (flags & 2) == 2)
    for j, t in enumerate(c_angles):
        assert wrapped(sol.theta[..., j], t)[sol.valid].max() < 1e-12
    assert np.abs(sol.residual - c_res)[sol.valid].max() < 1e-12
    assert sol.ls.any() and sol.exact.any() and sol.degenerate.any()    # all three kinds compared


def mixed(rng, n):
    """Random vectors with a tenth on the axis (degenerate) and axes."""
    k, p = unit(rng, n), rng.normal(size=(n, 3))
    p[: n // 10] = k[: n // 10] * rng.normal(size=(n // 10, 1))
    return k, p


def test_c_sp1_sp4_agree_with_numpy(c_subproblems):
    rng = np.random.default_rng(20)
    n = 400
    k, p1 = mixed(rng, n)
    t = rng.uniform(-np.pi, np.pi, n)
    p2 = np.where(np.arange(n)[:, None] % 2 == 0, Rp(k, t, p1), rng.normal(size=(n, 3)))  # exact / ls
    k[-1], p1[-1], p2[-1] = [0, 0, 1.0], [1.0, -0.0, 0], [-1.0, -0.0, 0]   # a half turn: +pi
    angles, res, flags, count = call_c(c_subproblems, "b_sp1", n, 1, k, p1, p2)
    assert angles[0][-1, 0] == np.pi
    agree(sp1(k, p1, p2), angles, res, flags, count)

    k1, k2, q1, q2, t2 = sp2_instance(rng, n)
    q1[1::2] *= 1.3                                             # half least-squares
    k2[: n // 10] = k1[: n // 10]                               # a tenth coaxial
    angles, res, flags, count = call_c(c_subproblems, "b_sp2", n, 2, k1, k2, q1, q2, angles=2)
    agree(sp2(k1, k2, q1, q2), angles, res, flags, count)

    p2 = rng.normal(size=(n, 3))
    d = np.linalg.norm(Rp(k, t, p1) - p2, axis=-1) * np.where(np.arange(n) % 3 == 0, 3.0, 1.0)
    angles, res, flags, count = call_c(c_subproblems, "b_sp3", n, 2, k, p1, p2, d)
    agree(sp3(k, p1, p2, d), angles, res, flags, count)

    h = unit(rng, n)
    d = np.einsum("ni,ni->n", h, Rp(k, t, p1)) + np.where(np.arange(n) % 3 == 0, 2.0, 0.0)
    angles, res, flags, count = call_c(c_subproblems, "b_sp4", n, 2, h, k, p1, d)
    agree(sp4(h, k, p1, d), angles, res, flags, count)


def test_sp5_sp6_robot_like_instances():
    """Axes along +-x, +-y, +-z and offsets in quarter metres, as in robot descriptions: many
    instances have parallel or perpendicular axes, zero offsets, rank-one blocks. The generating
    angles are found in every instance that is not flagged degenerate; every returned solution of
    every instance (degenerate ones included) solves the equation."""
    rng = np.random.default_rng(21)
    n = 3000
    ax = lambda m: np.eye(3)[rng.integers(0, 3, m)] * rng.choice([-1.0, 1.0], (m, 1))
    vec = lambda m: rng.integers(-2, 3, (m, 3)) * 0.25
    p1, p2, p3, k1, k2, k3 = vec(n), vec(n), vec(n), ax(n), ax(n), ax(n)
    t = rng.uniform(-np.pi, np.pi, (n, 3))
    p0 = Rp(k2, t[:, 1], p2 + Rp(k3, t[:, 2], p3)) - Rp(k1, t[:, 0], p1)
    args = (p0, p1, p2, p3, k1, k2, k3)
    sol = sp5(*args)
    assert 0 < sol.degenerate.sum() < n
    assert closest_to(sol, t)[~sol.degenerate].max() < 1e-8
    assert sp5_res([a[:, None] for a in args], sol.theta)[sol.valid].max() < 1e-11

    h, k, p = ax(4 * n).reshape(n, 4, 3), ax(4 * n).reshape(n, 4, 3), vec(4 * n).reshape(n, 4, 3)
    t = rng.uniform(-np.pi, np.pi, (n, 2))
    val = np.einsum("nqi,nqi->nq", h, Rp(k, t[:, [0, 1, 0, 1]], p))
    d = np.stack([val[:, 0] + val[:, 1], val[:, 2] + val[:, 3]], axis=-1)
    sol = sp6(h, k, p, d)
    assert 0 < sol.degenerate.sum() < n
    assert closest_to(sol, t)[~sol.degenerate].max() < 1e-8
    tt = np.nan_to_num(sol.theta)[:, :, [0, 1, 0, 1]]                       # (n, 4 slots, 4 rows)
    v = np.einsum("nqi,nsqi->nsq", h, Rp(k[:, None], tt, p[:, None]))
    err = np.stack([v[..., 0] + v[..., 1] - d[:, None, 0], v[..., 2] + v[..., 3] - d[:, None, 1]], -1)
    assert np.abs(err)[sol.valid].max() < 1e-11


def agree_sets(sol, c_angles, c_res, flags, count):
    """sp5 / sp6: the C twin returns the exact solutions compacted (its slot order may differ from
    numpy's, whose quartic roots come from an eigen-solver): the same flags and solution sets
    (each solution matched to the nearest of the other side, angles wrapped). At a tangency (a
    double root of the quartic, split by rounding into a near-real pair) the two root finders may
    disagree on whether the pair is real; such an instance may differ in count, but only by
    solutions whose residual shows the double root (above 1e-11, where a simple root has about
    1e-15) and in at most 1 % of the instances. Matched solutions agree within 1e-6 rad, and
    within 1e-10 in at least 99 % of the instances (the rest are ill-conditioned: an angle nearly
    free, both sides' residuals still within SP_EXACT_TOL). Returns the median difference."""
    assert np.array_equal(sol.degenerate, (flags & 2) == 2)
    c = np.stack(c_angles, axis=-1)                                 # (n, 4, j)
    diffs, tangent = [], 0
    for i in range(len(count)):
        mine, theirs = c[i, :count[i]], sol.theta[i][sol.valid[i]]
        assert np.all(c_res[i, :count[i]] <= SP_EXACT_TOL)
        if len(mine) != len(theirs):
            tangent += 1
            d = np.abs(wrap_angle(mine[:, None] - theirs[None])).max(-1)
            extra_c = d.min(1, initial=np.inf) > 1e-6 if len(theirs) else np.ones(len(mine), bool)
            extra_n = d.min(0, initial=np.inf) > 1e-6 if len(mine) else np.ones(len(theirs), bool)
            assert np.all(c_res[i, :count[i]][extra_c] > 1e-11)
            assert np.all(sol.residual[i][sol.valid[i]][extra_n] > 1e-11)
            continue
        assert sol.exact[i] == bool(flags[i] & 1)
        if len(mine):
            d = np.abs(wrap_angle(mine[:, None] - theirs[None])).max(-1)  # (count, count)
            assert np.array_equal(np.sort(d.argmin(1)), np.arange(count[i]))   # one to one
            diffs.append(d.min(1).max())
    diffs = np.array(diffs)
    assert tangent <= len(count) // 100, tangent
    assert diffs.max() < 1e-6 and np.mean(diffs > 1e-10) <= 0.01, (diffs.max(), np.mean(diffs > 1e-10))
    assert np.median(diffs) < 1e-13
    return np.median(diffs)


def test_c_sp5_sp6_agree_with_numpy(c_subproblems):
    """The C twin of sp5 and sp6 (Durand-Kerner on the same quartic as numpy's eigenvalues, the
    same rank-one and free-block branches) against numpy: generic instances from known angles,
    instances with no solution, and robot-like ones (axes along +-x, +-y, +-z, offsets in quarter
    metres: rank-one blocks, free angles and continua)."""
    rng = np.random.default_rng(22)
    n = 600
    # sp6: generic (two thirds) and shifted right-hand sides (often no solution)
    h, k, p = rng.normal(size=(n, 4, 3)), unit(rng, n * 4).reshape(n, 4, 3), rng.normal(size=(n, 4, 3))
    t = rng.uniform(-np.pi, np.pi, (n, 2))
    val = np.einsum("nqi,nqi->nq", h, Rp(k, t[:, [0, 1, 0, 1]], p))
    d = np.stack([val[:, 0] + val[:, 1], val[:, 2] + val[:, 3]], axis=-1)
    d[::3] += rng.normal(size=(len(d[::3]), 2)) * 3
    sol = sp6(h, k, p, d)
    angles, res, flags, count = call_c(c_subproblems, "b_sp6", n, 4, h, k, p, d, angles=2)
    agree_sets(sol, angles, res, flags, count)
    assert (count == 0).any() and (count == 4).any() and (count == 2).any()

    ax = lambda m: np.eye(3)[rng.integers(0, 3, m)] * rng.choice([-1.0, 1.0], (m, 1))
    vec = lambda m: rng.integers(-2, 3, (m, 3)) * 0.25
    h, k, p = ax(4 * n).reshape(n, 4, 3), ax(4 * n).reshape(n, 4, 3), vec(4 * n).reshape(n, 4, 3)
    val = np.einsum("nqi,nqi->nq", h, Rp(k, t[:, [0, 1, 0, 1]], p))
    d = np.stack([val[:, 0] + val[:, 1], val[:, 2] + val[:, 3]], axis=-1)
    sol = sp6(h, k, p, d)
    angles, res, flags, count = call_c(c_subproblems, "b_sp6", n, 4, h, k, p, d, angles=2)
    agree_sets(sol, angles, res, flags, count)
    assert sol.degenerate.any() and (~sol.degenerate & (count > 0)).any()

    # sp5: generic, no solution (p0 moved far), robot-like
    p1, p2, p3, k1, k2, k3 = (rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rng.normal(size=(n, 3)),
                              unit(rng, n), unit(rng, n), unit(rng, n))
    t = rng.uniform(-np.pi, np.pi, (n, 3))
    p0 = Rp(k2, t[:, 1], p2 + Rp(k3, t[:, 2], p3)) - Rp(k1, t[:, 0], p1)
    p0[::4] += 10.0
    sol = sp5(p0, p1, p2, p3, k1, k2, k3)
    angles, res, flags, count = call_c(c_subproblems, "b_sp5", n, 4, p0, p1, p2, p3, k1, k2, k3, angles=3)
    agree_sets(sol, angles, res, flags, count)
    assert (count == 0).any() and (count >= 2).any()

    p1, p2, p3, k1, k2, k3 = vec(n), vec(n), vec(n), ax(n), ax(n), ax(n)
    p0 = Rp(k2, t[:, 1], p2 + Rp(k3, t[:, 2], p3)) - Rp(k1, t[:, 0], p1)
    sol = sp5(p0, p1, p2, p3, k1, k2, k3)
    angles, res, flags, count = call_c(c_subproblems, "b_sp5", n, 4, p0, p1, p2, p3, k1, k2, k3, angles=3)
    agree_sets(sol, angles, res, flags, count)
    assert sol.degenerate.any() and (~sol.degenerate & (count > 0)).any()


def test_rot_components_against_scipy():
    """The per-component Rodrigues ``rot`` (a constant axis (3,) or a batch of axes, slot axes
    broadcast) against scipy's rotations."""
    from derive.ik.subproblems import rot
    rng = np.random.default_rng(31)
    k, t, p = unit(rng, N), rng.uniform(-np.pi, np.pi, N), rng.normal(size=(N, 3))
    assert np.abs(rot(k, t, p) - Rp(k, t, p)).max() < 1e-14
    z = np.array([0.0, 0.0, -1.0])
    assert np.abs(rot(z, t, p) - Rp(np.broadcast_to(z, (N, 3)), t, p)).max() < 1e-14
    assert np.abs(rot(z, t, [1.0, 2.0, 3.0]) - Rp(np.broadcast_to(z, (N, 3)), t, np.array([1.0, 2.0, 3.0]))).max() < 1e-13
    t2 = rng.uniform(-np.pi, np.pi, (N, 2))
    assert np.abs(rot(k[:, None], t2, p[:, None]) - Rp(k[:, None], t2, p[:, None])).max() < 1e-14
    assert np.abs(rot(list(k[0]), 0.3, list(p[0])) - Rp(k[0], 0.3, p[0])).max() < 1e-14


def test_private_steps_are_the_public_solutions():
    """The compositions' private steps (_sp1.._sp4: constant axes (3,), no input checks, no
    residuals) return the public functions' angles, slot 1 repeating slot 0 where there is one
    root, on exact, least-squares and degenerate instances; and the angles solve the equations
    by scipy's rotations where they are exact."""
    from derive.ik.subproblems.sp1 import _sp1
    from derive.ik.subproblems.sp2 import _sp2
    from derive.ik.subproblems.sp3 import _sp3
    from derive.ik.subproblems.sp4 import _sp4
    rng = np.random.default_rng(32)
    y, z = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, -1.0])
    yb, zb = np.broadcast_to(y, (N, 3)), np.broadcast_to(z, (N, 3))
    p1, p2 = rng.normal(size=(2, N, 3))
    p1[:10] = 0.7 * z                                       # on the axis: degenerate
    d = np.abs(rng.normal(size=N)) * 2                      # some distances out of reach: ls

    def slots(sol):
        return np.where(sol.valid[..., None], sol.theta, sol.theta[:, :1])

    s = sp1(zb, p1, p2)
    assert np.array_equal(_sp1(z, p1, p2), s.theta[:, 0, 0])
    s = sp4(yb, zb, p1, d - 1)
    t4, free = _sp4(y, z, p1, d - 1)
    assert np.array_equal(t4, slots(s)[:, :, 0]) and np.array_equal(free, s.degenerate)
    assert s.ls.any() and s.degenerate.any() and s.exact.any()
    ex = s.exact
    assert np.abs(Rp(zb[ex, None], t4[ex], p1[ex, None]) @ y - (d - 1)[ex, None]).max() < 1e-12
    s = sp3(yb, p1, p2, d)
    t3 = _sp3(y, p1, p2, d)
    assert np.array_equal(t3, slots(s)[:, :, 0]) and s.ls.any() and s.exact.any()
    ex = s.exact
    dist = np.linalg.norm(Rp(yb[ex, None], t3[ex], p1[ex, None]) - p2[ex, None], axis=-1)
    assert np.abs(dist - d[ex, None]).max() < 1e-12
    u = p1 / np.linalg.norm(p1, axis=-1, keepdims=True)
    s = sp2(-yb, zb, u, y)
    t2 = _sp2(-y, z, u, y)
    assert np.array_equal(t2, slots(s)) and s.exact.any()
    ex = s.exact
    left = Rp(-yb[ex, None], t2[ex, :, 0], u[ex, None])
    assert np.abs(left - Rp(zb[ex, None], t2[ex, :, 1], np.broadcast_to(y, (ex.sum(), 2, 3)))).max() < 1e-12
