"""The general 6R arm: every IK solution (up to 16) by Raghavan-Roth elimination solved as a
Manocha-Canny eigenproblem (numpy reference).

Formulation (docs/ik.md, "General 6R"). The chain is written in product form
``FK(q) = C1 Rz(q1) C2 Rz(q2) ... C6 Rz(q6) C7`` (each C_i a constant 4x4 transform whose z axis
is joint i's axis, built from :func:`derive.model.geometry.numeric_chain`; lengths divided by the
arm's size, the "scale"). Following Raghavan and Roth (1993, J. Mech. Des. 115(3), eq. 2-14):

* ``Rz3 C4 Rz4 C5 Rz5 C6 [e_z, 0] = H [l, p]`` with ``H = C3^-1 Rz(-q2) C2^-1 Rz(-q1) C1^-1`` and
  (l, p) the direction and a point of joint 6's axis in the base frame (``T C7^-1``): the pose
  enters only through these six numbers. With the two vectors (the z axis and the point) of
  each side, the 14 equations are the 6 components plus p.p, p.l, p x l and (p.p) l - 2 (p.l) p
  (the Lagrange products, which keep every joint's sine and cosine at degree one).
* :func:`derive_elimination` expands them with sympy for one robot (its constants substituted,
  (l, p) symbolic), reduces s^2 = 1 - c^2 and collects ``P(q3) X1 = Q(l, p) X2``: X1 the 9
  monomials (s4, c4, 1) x (s5, c5, 1), X2 the 8 monomials (s1, c1, 1) x (s2, c2, 1) without 1,
  P linear in (s3, c3, 1) (its constant column takes the pose terms free of q1, q2), the entries
  of P and Q polynomials of degree <= 3 in (l, p).
* At run time, per pose, q1 and q2 are eliminated numerically (Manocha and Canny 1994, IEEE
  Trans. Robot. Autom. 10(5), section III): N, six rows spanning the left null space of Q (its
  SVD), gives ``N P(q3) X1 = 0``, 6 x 9. Half-angle tangents of q4 and q5 (each rotated by a
  fixed random offset, against roots at infinity) turn X1 into the 9 monomials x4^i x5^j
  (i, j <= 2); the 6 equations and the same times x4 are 12 equations in 12 monomials
  x4^i x5^j (i <= 3, j <= 2): ``M(x3) v = 0`` with M quadratic in x3 = tan((q3 - d3)/2), d3 a
  random offset chosen per pose from a few so that the leading matrix is best conditioned (the
  Moebius substitution of Manocha-Canny). det M has degree 24 (8 spurious roots at +-i).
* ``M(x3) v = 0`` is the 24 x 24 companion eigenproblem ``C = [[0, I], [-M2^-1 M0, -M2^-1 M1]]``.
  The roots every pose shares (x3 = +-i, the factor (1 + x3^2)^4 of det M, and a cut arm's
  constant spurious roots) have the same eigenvectors for every pose, found once per robot
  (:func:`_deflation`); in an orthonormal basis [W V] with V spanning them C is block
  triangular, so numpy.linalg.eigvals of W^T C W (16 x 16) gives the other roots. Real
  eigenvalues give q3, the null vectors of M(x3) q4 and q5 (ratios of the monomials), the
  14 x 8 system ``Q X2 = P X1`` q1 and q2 (its least-squares solution by the same QR), the
  remaining rotation q6.
* Every candidate is polished by Newton steps on the product-form FK (damped, the geometric
  Jacobian; the first step on the chain the back-substitution of the last joint made, a step
  below :data:`NEWTON_DONE` whose linear residual is below 1e-13 the last), checked on derive's
  dual-quaternion FK (:func:`derive.kinematics.fk.fk`'s product with its constant factors
  folded, :func:`_fk_exact`: :data:`G6_ACCEPT` m and rad), near-duplicates within
  :data:`MERGE_TOL` in every joint merged. The chain is kept in a column layout
  (:func:`_x_times`) whose thin products stay on one BLAS thread.
* A pose whose elimination degenerates (the leading matrix ill-conditioned for every offset, or
  Q rank-deficient there) is solved at nearby poses and Newton carries their solutions back
  (:func:`_perturbed`); a pose with a (near-)singular solution, or whose pencil is singular for
  every q3 (a continuum there need not show at the nearby poses), is flagged ``degenerate``.

A robot whose elimination degenerates (Q of too low rank, or det M identically zero: special
geometry) is tried in reverse order (the IK of T^-1 for the reversed chain, where q4 is the
eigen-variable), then with the loop cut at joint 2 or 1 (:func:`_check_cut`: the pair of joints
eliminated linearly holds the pose link, the triple's coefficients are constant; this solves the
Fanuc CRX-10iA, whose standard pencil has rank 10 for every q3); when all degenerate,
:func:`plan` raises DeriveError saying so.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from derive.algebra import dualquat as dq
from derive.algebra import quaternion as quat
from derive.algebra.angles import wrap_angle
from derive.cache import find_artifact, memo, peek, step, store_artifacts, task
from derive.errors import BudgetError, DeriveError
from derive.ik.tolerances import (G6_ACCEPT, G6_GOOD_COND, G6_LEADING_COND, G6_NEWTON_MAX,
                                  G6_NEAR_SINGULAR, G6_PERTURB, G6_PERTURB_TRIALS, G6_RANK_TOL,
                                  G6_REAL_TOL, G6_SINGULAR, MERGE_TOL)
from derive.ik.tolerances import G6_NEWTON_DONE, G6_NEWTON_STOP, G6_REF_NEWTON_FAR
from derive.kinematics.fk import _pose_error, fk
from derive.kinematics.pose import as_pose_batch
from derive.model.geometry import numeric_chain
from derive.model.robot import load_robot


#: Version of the derivation's stored form (the artifact is remade when it changes).
FORMAT = 1

# the pose monomials: products of (lx, ly, lz, px, py, pz) of degree <= 3
_POSE_MONOMIALS = [m for d in range(4) for m in itertools.combinations_with_replacement(range(6), d)]


# --------------------------------------------------------------------------- #
# The product form of the chain
# --------------------------------------------------------------------------- #
def _frame(axis, point):
    """A 4x4 frame with z along ``axis`` and origin ``point``."""
    z = np.asarray(axis, float) / np.linalg.norm(axis)
    h = np.array([1.0, 0, 0]) if abs(z[0]) < 0.9 else np.array([0, 1.0, 0])
    x = np.cross(h, z)
    x /= np.linalg.norm(x)
    f = np.eye(4)
    f[:3, 0], f[:3, 1], f[:3, 2], f[:3, 3] = x, np.cross(z, x), z, point
    return f


def _inv_rigid(t):
    """Batched inverse of rigid transforms (..., 4, 4)."""
    out = np.zeros_like(t)
    rt = np.swapaxes(t[..., :3, :3], -1, -2)
    out[..., :3, :3] = rt
    out[..., :3, 3] = -(rt @ t[..., :3, 3, None])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def _inv(t):
    out = np.eye(4)
    out[:3, :3] = t[:3, :3].T
    out[:3, 3] = -t[:3, :3].T @ t[:3, 3]
    return out


def chain_form(robot):
    """(C (7, 4, 4), scale): FK(q) = C1 Rz(q1) ... C6 Rz(q6) C7 with lengths divided by scale
    (the sum of the link lengths). Built from the axis-angle chain (product of exponentials:
    each joint rotates about its axis through its point at the zero pose, the frame F_i puts the
    axis on z, C_i = F_{i-1}^-1 F_i)."""
    chain = numeric_chain(robot)
    if chain.n != 6 or any(t != "revolute" for t in chain.types):
        raise DeriveError(f"{chain.robot}: the general 6R solver needs six revolute joints")
    points = chain.start + np.concatenate([np.zeros((1, 3)), np.cumsum(chain.links, axis=0)])
    scale = float(max(np.sum(np.linalg.norm(chain.links, axis=1)) + np.linalg.norm(chain.end_translation),
                      1e-9))
    frames = []
    for i in range(6):
        # origin: the point of axis i closest to axis i-1 (shorter constants), else its own point
        frames.append(_frame(chain.axes[i], points[i]))
    t0 = np.eye(4)
    t0[:3, :3] = chain.end_rotation
    t0[:3, 3] = points[6] + chain.end_translation
    cs = [frames[0]] + [_inv(frames[i - 1]) @ frames[i] for i in range(1, 6)] + [_inv(frames[5]) @ t0]
    c = np.array(cs)
    c[:, :3, 3] /= scale
    return c, scale


def _reverse(c):
    """The reversed chain: T^-1 = C7^-1 Rz(-q6) C6^-1 ... Rz(-q1) C1^-1, joints q'_k = -q_{7-k}."""
    return np.array([_inv(c[6 - k]) for k in range(7)])


def _rz(t):
    ct, st = np.cos(t), np.sin(t)
    out = np.zeros(np.shape(t) + (4, 4))
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1] = ct, -st, st, ct
    out[..., 2, 2] = out[..., 3, 3] = 1.0
    return out


def _chain_frames(c, q):
    """The frames A_i = C1 Rz(q1) ... C_i (i = 1..6, before joint i's rotation) and the end
    pose, for q (m, 6): (frames (m, 6, 4, 4), end (m, 4, 4)). A right factor Rz(q) mixes only
    the first two columns (done as such); a constant C_i is one matrix product of all rows."""
    m = q.shape[0]
    cq, sq = np.cos(q), np.sin(q)
    frames = np.empty((m, 6, 4, 4))
    a = np.broadcast_to(c[0], (m, 4, 4)).copy()
    for i in range(6):
        if i:
            a = (a.reshape(4 * m, 4) @ c[i]).reshape(m, 4, 4)
        frames[:, i] = a
        a0, a1 = a[:, :, 0].copy(), a[:, :, 1]
        ci, si = cq[:, i, None], sq[:, i, None]
        a[:, :, 0] = ci * a0 + si * a1
        a[:, :, 1] = ci * a1 - si * a0
    return frames, (a.reshape(4 * m, 4) @ c[6]).reshape(m, 4, 4)


#: Columns per block of :func:`_x_times`: OpenBLAS runs a product of more than about 2.6e5
#: multiply-adds on several threads, and for these thin products (4 x 4 times 4 x N) waking the
#: threads costs more than the product (measured: 0.3 ms on one thread, 23 ms on two while the
#: machine is busy); blocks below that size stay on the calling thread.
_MM_COLS = 12288


def _x_times(x, c):
    """The columns (4, m, 3) of the top three rows of A (m rigid 4x4 transforms: x[j] is
    column j, rows 1-3) times a constant c (4, 4): column j of A c is sum_i c[i, j] A[:, i],
    so the (4, 3 m) block is c^T times x's, in column blocks of :data:`_MM_COLS`."""
    m = x.shape[1]
    x2 = x.reshape(4, 3 * m)
    if 3 * m <= _MM_COLS:
        return (c.T @ x2).reshape(4, m, 3)
    ct = np.ascontiguousarray(c.T)
    out = np.empty((4, 3 * m))
    for s in range(0, 3 * m, _MM_COLS):
        np.matmul(ct, x2[:, s:s + _MM_COLS], out=out[:, s:s + _MM_COLS])
    return out.reshape(4, m, 3)


def _x_rot(x, cq, sq):
    """In place: A Rz(q) in the column layout of :func:`_x_times` (cq, sq: (m, 1)); Rz mixes
    columns 0 and 1 only."""
    x0 = x[0].copy()
    x[0] *= cq
    x[0] += sq * x[1]
    x[1] *= cq
    x[1] -= sq * x0


def _x_start(c0, m):
    x = np.empty((4, m, 3))
    x[:] = c0[:3, :].T[:, None, :]
    return x


def _chain_x(c, cq, sq, zs, ps, x=None, start=0, stop=6):
    """The product-form chain C1 Rz(q1) C2 ... in the column layout (:func:`_x_times`), for
    joints ``start`` .. ``stop`` - 1 (0-based) from x (A before joint ``start``'s constant; None:
    from C_{start+1} alone), writing joint i's z axis and origin (its frame before the rotation:
    the rotation keeps both) into zs[:, i], ps[:, i] (m, 6, 3). With stop = 6 the result is the
    end pose (times C7), else A before joint ``stop``'s rotation (its constant applied)."""
    m = cq.shape[0]
    for i in range(start, stop):
        x = _x_start(c[i], m) if x is None else _x_times(x, c[i])
        zs[:, i] = x[2]
        ps[:, i] = x[3]
        _x_rot(x, cq[:, i, None], sq[:, i, None])
    if stop == 6:
        return _x_times(x, c[6])
    x = _x_start(c[stop], m) if x is None else _x_times(x, c[stop])
    zs[:, stop] = x[2]
    ps[:, stop] = x[3]
    return x


def _err_jt(target, zs, ps, x):
    """(error (m, 6): the position (scaled) and the rotation vector (angle times axis) of
    R_T R^T; J^T (m, 6, 6), row i joint i's (z_i x (p - p_i), z_i): the geometric Jacobian) of
    the end x (column layout) against target (m, 4, 4). The rotation error of R_T R^T: with R_T's columns t_k and R's columns x_k,
    R_T R^T = sum_k t_k x_k^T, its vee part is 1/2 sum_k x_k x t_k, its trace sum_k t_k . x_k."""
    pe = x[3]
    dp = target[:, :3, 3] - pe
    t = target[:, :3, :3]
    # sum_k x_k x t_k and sum_k t_k . x_k, x_k and t_k the columns (x's columns are rows of xr)
    xr = x[:3].transpose(1, 0, 2)                               # (m, k, i): row k is x_k
    tr = np.einsum("mik,mki->m", t, xr)
    w = 0.5 * np.stack([np.einsum("mk,mk->m", xr[:, :, 1], t[:, 2]) - np.einsum("mk,mk->m", xr[:, :, 2], t[:, 1]),
                        np.einsum("mk,mk->m", xr[:, :, 2], t[:, 0]) - np.einsum("mk,mk->m", xr[:, :, 0], t[:, 2]),
                        np.einsum("mk,mk->m", xr[:, :, 0], t[:, 1]) - np.einsum("mk,mk->m", xr[:, :, 1], t[:, 0])], 1)
    sn = np.sqrt(np.einsum("mi,mi->m", w, w))
    ang = np.arctan2(sn, 0.5 * (tr - 1))
    fac = np.where(sn > 1e-12, ang / np.where(sn > 1e-12, sn, 1.0), 1.0)
    err = np.concatenate([dp, w * fac[:, None]], 1)
    return err, _jt(zs, ps, pe)


def _jt(zs, ps, pe):
    """J^T (m, 6, 6) of the geometric Jacobian: row i (z_i x (p - p_i), z_i), from the joints'
    z axes and origins zs, ps (m, 6, 3) and the end's origin pe (m, 3)."""
    jt = np.empty((len(pe), 6, 6))
    r = pe[:, None, :] - ps
    jt[:, :, 0] = zs[:, :, 1] * r[:, :, 2] - zs[:, :, 2] * r[:, :, 1]
    jt[:, :, 1] = zs[:, :, 2] * r[:, :, 0] - zs[:, :, 0] * r[:, :, 2]
    jt[:, :, 2] = zs[:, :, 0] * r[:, :, 1] - zs[:, :, 1] * r[:, :, 0]
    jt[:, :, 3:] = zs
    return jt


def _frames_x(c, q):
    """(zs, ps (m, 6, 3), the end in column layout) of the product-form chain at q (m, 6)."""
    m = len(q)
    zs, ps = np.empty((m, 6, 3)), np.empty((m, 6, 3))
    x = _chain_x(c, np.cos(q), np.sin(q), zs, ps)
    return zs, ps, x


# --------------------------------------------------------------------------- #
# Derivation (sympy)
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class Elimination:
    """The derived matrices of one chain: ``P(q3) X1 = Q X2``.

    ``pl`` (14, 3, 9): the constant coefficients of (s3, c3, 1) x X1; ``r0`` (14, K): the pose
    terms of the equations free of q1, q2 (they join P's (1, 1) column with a minus sign);
    ``q`` (14, 8, K): Q's entries; K runs over ``monomials``, products of (lx, ly, lz, px, py,
    pz) (indices) of degree <= 3."""

    pl: np.ndarray
    r0: np.ndarray
    q: np.ndarray
    monomials: tuple


def derive_elimination(c, label="general 6R") -> Elimination:
    """Expand the 14 Raghavan-Roth equations of the chain ``c`` (7, 4, 4) with sympy and collect
    their coefficients (see the module docstring). Progress lines on stderr."""
    import sympy as sp

    s = sp.symbols("s1:6")
    co = sp.symbols("c1:6")
    pose = sp.symbols("lx ly lz px py pz")

    def rz(i, sign=1):
        si, ci = sign * s[i], co[i]
        return sp.Matrix([[ci, -si, 0, 0], [si, ci, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])

    def mat(t):
        return sp.Matrix(4, 4, [sp.Float(float(v), 17) for v in t.ravel()])

    cm = [mat(t) for t in c]
    cinv = [mat(_inv(t)) for t in c]
    step("the two sides of the loop")
    left = rz(2) * cm[3] * rz(3) * cm[4] * rz(4) * cm[5]
    l_l, p_l = left[:3, 2], left[:3, 3]
    h = cinv[2] * rz(1, -1) * cinv[1] * rz(0, -1) * cinv[0]
    lv, pv = sp.Matrix(pose[:3]), sp.Matrix(pose[3:])
    l_r = h[:3, :3] * lv
    p_r = h[:3, :3] * pv + h[:3, 3]

    lgens = (s[2], co[2], s[3], co[3], s[4], co[4])
    rgens = (s[0], co[0], s[1], co[1], *pose)

    def products(lvec, pvec, gens):
        """The 14 left sides as sympy Polys (multiplied as Polys: much faster than expanding
        the products of expressions)."""
        lv_, pv_ = [sp.Poly(sp.expand(e), *gens) for e in lvec], [sp.Poly(sp.expand(e), *gens) for e in pvec]
        pp = sum((a * a for a in pv_[1:]), pv_[0] * pv_[0])
        pl = sum((a * b for a, b in zip(pv_[1:], lv_[1:])), pv_[0] * lv_[0])
        cross = [pv_[1] * lv_[2] - pv_[2] * lv_[1], pv_[2] * lv_[0] - pv_[0] * lv_[2],
                 pv_[0] * lv_[1] - pv_[1] * lv_[0]]
        return [*lv_, *pv_, pp, pl, *cross, *(pp * a - 2 * pl * b for a, b in zip(lv_, pv_))]

    step("the 14 equations (positions, directions and the Lagrange products)")
    left_eqs, right_eqs = products(l_l, p_l, lgens), products(l_r, p_r, rgens)

    def reduced(expr, gens, trig_pairs):
        """{exponent tuple: float} of expr with s_i^2 replaced by 1 - c_i^2."""
        terms = {}
        for mon, coef in expr.terms():
            stack = [(list(mon), float(coef))]
            while stack:
                e, v = stack.pop()
                k = next((si for si, _ in trig_pairs if e[si] >= 2), None)
                if k is None:
                    terms[tuple(e)] = terms.get(tuple(e), 0.0) + v
                    continue
                ci = dict(trig_pairs)[k]
                e1 = list(e)
                e1[k] -= 2
                e2 = list(e1)
                e2[ci] += 2
                stack += [(e1, v), (e2, -v)]
        return terms

    x1_basis = [(a, b) for a in range(3) for b in range(3)]          # (s4,c4,1) x (s5,c5,1)
    x2_basis = [(a, b) for a in range(3) for b in range(3)][:-1]     # (s1,c1,1) x (s2,c2,1), no 1
    mon_index = {m: k for k, m in enumerate(_POSE_MONOMIALS)}
    pl = np.zeros((14, 3, 9))
    r0 = np.zeros((14, len(_POSE_MONOMIALS)))
    qm = np.zeros((14, 8, len(_POSE_MONOMIALS)))
    drop = 1e-11

    def trig_slot(e0, e1):
        """(s, c, 1) index of a monomial's exponents (e_s, e_c), or None (degree > 1)."""
        return {(1, 0): 0, (0, 1): 1, (0, 0): 2}.get((e0, e1))

    for k in range(14):
        step(f"equation {k + 1} of 14: expand and collect")
        for e, v in reduced(left_eqs[k], lgens, [(0, 1), (2, 3), (4, 5)]).items():
            a, b4, b5 = trig_slot(*e[0:2]), trig_slot(*e[2:4]), trig_slot(*e[4:6])
            if None in (a, b4, b5):
                if abs(v) > drop:
                    raise DeriveError(f"{label}: equation {k + 1}: a term of degree > 1 in one joint "
                                      f"survives ({e}: {v:.3g}); the elimination does not apply")
                continue
            pl[k, a, x1_basis.index((b4, b5))] += v
        for e, v in reduced(right_eqs[k], rgens, [(0, 1), (2, 3)]).items():
            b1, b2 = trig_slot(*e[0:2]), trig_slot(*e[2:4])
            if None in (b1, b2):
                if abs(v) > drop:
                    raise DeriveError(f"{label}: equation {k + 1}: a term of degree > 1 in q1 or q2 "
                                      f"survives ({e}: {v:.3g}); the elimination does not apply")
                continue
            pm = tuple(sorted(i for i, n in enumerate(e[4:]) for _ in range(n)))
            if (b1, b2) == (2, 2):
                r0[k, mon_index[pm]] += v
            else:
                qm[k, x2_basis.index((b1, b2)), mon_index[pm]] += v
    used = np.nonzero(np.any(r0 != 0, axis=0) | np.any(qm != 0, axis=(0, 1)))[0]
    return Elimination(pl=pl, r0=r0[:, used], q=qm[:, :, used],
                       monomials=tuple(_POSE_MONOMIALS[i] for i in used))


# --------------------------------------------------------------------------- #
# The plan of one robot: chain, direction, derived matrices, offsets
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class Plan:
    """Everything :func:`solve` needs for one robot."""

    robot: str
    c: np.ndarray           # (7, 4, 4) forward chain (scaled)
    scale: float
    reverse: bool           # solved as the reversed chain
    elim: Elimination
    rank_q: int             # generic rank of Q (8 for a general arm)
    mix: np.ndarray         # (6, 14 - rank_q): combination of Q's left null space
    offsets: np.ndarray     # (3,) d4, d5 and the first d3
    d3: np.ndarray          # (K,) candidate offsets of q3
    notes: tuple
    cut: dict | None = None  # the loop cut at another joint (see _check_cut), or None
    #: (len(d3), 24, k): per offset of the eigen-variable, an orthonormal basis of the complement
    #: of the pencil's pose-independent eigenvectors (the roots every pose shares: x = +-i, the
    #: spurious factor (1 + x^2)^4 of det M, and for a cut the constant real roots of its
    #: special geometry); None: no deflation (see :func:`_deflation`).
    deflate: np.ndarray | None = None
    #: The number of columns of ``deflate`` that span the complement (24 less the removed roots).
    deflate_keep: int = 24
    #: The eigen-variable's pose-independent real roots (rad, in the joint's own angle), removed
    #: by the deflation; a pose whose own root falls on one gets the null-space search there.
    spurious: tuple = ()


def _seeded(robot_id: str) -> np.random.Generator:
    return np.random.default_rng(int(robot_id[:12], 16) if all(ch in "0123456789abcdef" for ch in robot_id[:12])
                                 else abs(hash(robot_id)) % 2 ** 32)


def plan(robot, progress: bool = True) -> Plan:
    """The derivation of one robot, cached: in memory (:func:`derive.cache.memo`) and as the
    artifact ``general6r`` (JSON) in the user cache; made within :func:`derive.cache.task` with
    progress lines. DeriveError when the robot is not a 6R or both directions degenerate."""
    robot = load_robot(robot)
    out = memo("general6r-plan", robot.id, lambda: _plan_or_error(robot, progress))
    if isinstance(out, DeriveError):
        raise out
    return out


def _plan_or_error(robot, progress):
    """The plan, or the DeriveError saying why there is none (kept, so the derivation is not
    tried again in this process)."""
    try:
        return _plan(robot, progress)
    except DeriveError as exc:
        if isinstance(exc, BudgetError):
            raise
        return exc


def _plan(robot, progress):
    c, scale = chain_form(robot)
    found = find_artifact(robot.id, "general6r")
    if found is not None:
        data = json.loads(found.read_text())
        if data.get("format") == FORMAT and data.get("degenerate"):
            raise DeriveError(data["degenerate"])
        if data.get("format") == FORMAT:
            return _plan_from(robot, c, scale, data)
    with task(f"general 6R {robot.name}", progress=progress):
        data = None
        why = []
        for reverse in (False, True):
            cc = _reverse(c) if reverse else c
            step(f"Raghavan-Roth elimination, {'reversed' if reverse else 'forward'} chain")
            elim = derive_elimination(cc, robot.name)
            ok, info = _check_generic(robot, cc, elim)
            step(f"{'reversed' if reverse else 'forward'} chain: {info}")
            if ok:
                data = {"format": FORMAT, "reverse": reverse, "pl": elim.pl.tolist(),
                        "r0": elim.r0.tolist(), "q": elim.q.tolist(),
                        "monomials": [list(m) for m in elim.monomials], "rank_q": info_rank(info),
                        "notes": why + [f"{'reversed' if reverse else 'forward'} chain: {info}"]}
                break
            why.append(f"{'reversed' if reverse else 'forward'} chain: {info}")
        if data is None:
            for e in (2, 1):
                step(f"the loop cut at joint {e} (the pose between the two eliminated joints)")
                ok, info, extra = _check_cut(c, e)
                step(f"cut at joint {e}: {info}")
                if ok:
                    data = {"format": FORMAT, "reverse": False, "cut": extra, "rank_q": 8,
                            "notes": why + [f"cut at joint {e}: {info}"]}
                    break
                why.append(f"cut at joint {e}: {info}")
        if data is None:
            # kept too (status(), robots and classify read it without deriving)
            message = (f"{robot.name}: the general 6R elimination degenerates in both directions "
                       f"({'; '.join(why)}): special geometry that no class of dq-derive covers yet")
            store_artifacts(robot.id, {"general6r": ("general6r.json", json.dumps(
                {"format": FORMAT, "degenerate": message, "notes": why}))}, {"robot": robot.name})
            raise DeriveError(message)
        store_artifacts(robot.id, {"general6r": ("general6r.json", json.dumps(data))},
                        {"robot": robot.name})
    return _plan_from(robot, c, scale, data)


def kernels_cover(rank_q: int) -> bool:
    """Whether the emitted general 6R kernels (:mod:`derive.codegen.general6r`) cover a plan whose
    Q has generic rank ``rank_q``: they bake in the rank-8 elimination (and the loop cut's)."""
    return int(rank_q) == 8


def _decision(robot):
    """The derivation's decision for a robot without deriving: this process's plan (or its
    DeriveError), else the stored artifact's JSON, else the decision shipped for a library arm
    of the same identity (:data:`DECISIONS`); None when none exists yet."""
    out = peek("general6r-plan", robot.id)
    if isinstance(out, Plan):
        return {"rank_q": out.rank_q, "cut": out.cut, "reverse": out.reverse, "notes": list(out.notes)}
    if isinstance(out, DeriveError):
        return {"degenerate": str(out)}
    found = find_artifact(robot.id, "general6r")
    data = json.loads(found.read_text()) if found is not None else None
    if data is not None and data.get("format") == FORMAT:
        return data
    return shipped_decisions().get(robot.id)


# --------------------------------------------------------------------------- #
# The decisions shipped for the library's general arms
# --------------------------------------------------------------------------- #
#: The shipped file: {"format": FORMAT, "robots": {identity: decision}} for the library's arms of
#: no special class, written by ``dq-derive generate`` (:func:`write_decisions`), so that
#: :func:`status` and :func:`describe` know them on a fresh install and after any code change
#: (the user cache's artifacts are keyed by a digest of the code, the shipped decision by the
#: robot's identity alone, :mod:`derive.model.identity`). An arm of another identity (a user's
#: own file, or a library file with one number changed) is not in it: "unchecked" until derived.
DECISIONS = Path(__file__).resolve().parent.parent / "data" / "general6r.json"


def decision(robot) -> dict:
    """The derivation's decision for one robot, derived now if it is not known (:func:`plan`),
    in the compact form shipped in :data:`DECISIONS`: {"robot", "rank_q", "reverse", "cut" (the
    joint the loop is cut at, or None), "notes"}, or {"robot", "degenerate" (the DeriveError's
    message), "notes"} for an arm whose elimination degenerates everywhere."""
    robot = load_robot(robot)
    try:
        pl = plan(robot, progress=False)
    except DeriveError as exc:
        if isinstance(exc, BudgetError):
            raise
        return {"robot": robot.name, "degenerate": str(exc), "notes": []}
    return {"robot": robot.name, "rank_q": int(pl.rank_q), "reverse": bool(pl.reverse),
            "cut": int(pl.cut["e"]) if pl.cut else None, "notes": list(pl.notes)}


def render_decisions(robots) -> str:
    """The text of :data:`DECISIONS` for the given robots (names or Robot objects): their
    decisions (:func:`decision`) keyed by identity, sorted keys, so the bytes are stable."""
    out = {}
    for r in robots:
        r = load_robot(r)
        out[r.id] = decision(r)
    return json.dumps({"format": FORMAT, "robots": out}, indent=1, sort_keys=True) + "\n"


def write_decisions(robots, path=None) -> str:
    """Derive the decisions of ``robots`` (:func:`render_decisions`) and write them to ``path``
    (default: the shipped file, :data:`DECISIONS`); returns the path."""
    path = DECISIONS if path is None else Path(path)
    text = render_decisions(robots)
    with open(path, "w", encoding="utf-8", newline="\n") as f:
        f.write(text)
    return str(path)


def shipped_decisions() -> dict:
    """{identity: decision} of the shipped file (read once; empty when it is missing or of
    another format)."""
    return memo("general6r-shipped", None, _read_decisions)


def _read_decisions() -> dict:
    try:
        data = json.loads(DECISIONS.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data.get("robots", {}) if data.get("format") == FORMAT else {}


def status(robot) -> str:
    """What the general 6R derivation decided for a robot of no special class, read from the
    cache without deriving (:func:`plan` derives and stores it; a degenerate arm's DeriveError is
    stored too): "kernels" (the numpy reference and the generated kernels solve it), "reference"
    (only the numpy reference: Q of rank < 8, :func:`kernels_cover`), "degenerate" (the
    elimination degenerates in every direction and cut: neither does) or "unchecked" (not
    derived yet)."""
    data = _decision(load_robot(robot))
    if data is None:
        return "unchecked"
    if data.get("degenerate"):
        return "degenerate"
    return "kernels" if kernels_cover(data["rank_q"]) else "reference"


def describe(robot) -> str:
    """Why and how the general 6R elimination solves a robot of no special class, for classify:
    the formulation its cached derivation chose (forward or reversed chain, or the loop cut and
    why), or why it degenerates, without deriving (a robot not derived yet says so)."""
    robot = load_robot(robot)
    data = _decision(robot)
    if data is not None and data.get("degenerate"):
        return ("general 6R: none of the special classes (UR, OPW, spherical wrist, three parallel) "
                "applies, and the general 6R elimination (derive.ik.general6r) does not solve it: "
                + data["degenerate"].split(": ", 1)[-1] + "; no IK kernels (FK only), use derive.refine")
    head = ("general 6R: none of the special classes (UR, OPW, spherical wrist, three parallel) "
            "applies, so derive.reference.ik solves it by the general 6R elimination "
            "(derive.ik.general6r: Raghavan-Roth's 14 equations derived with sympy for this arm, "
            "solved per pose as Manocha-Canny's eigenproblem in numpy; every solution, up to 16)")
    if data is None:
        return head + ("; derived on first use (a few seconds, then cached): whether its elimination "
                       "is regular (then it has IK kernels too) is not checked yet")
    if not kernels_cover(data["rank_q"]):
        head += f"; Q has generic rank {data['rank_q']} < 8, so it has no generated IK kernels (FK only)"
    if data.get("cut"):
        how = (f"its standard elimination degenerates ({'; '.join(data['notes'][:-1])}), so the loop is "
               f"{data['notes'][-1]}")
    else:
        how = data["notes"][-1] if data.get("notes") else ""
        how = ("solved as the reversed chain (the forward one degenerates): " if data["reverse"] else
               "solved as the forward chain: ") + how.split(": ", 1)[-1]
    return head + "; " + how


def info_rank(info: str) -> int:
    return int(info.split("rank Q = ")[1].split(",")[0])


def _plan_from(robot, c, scale, data):
    if data.get("cut"):
        rng = _seeded(robot.id)
        offsets = rng.uniform(-np.pi, np.pi, 3)
        empty = Elimination(pl=np.zeros((14, 3, 9)), r0=np.zeros((14, 0)), q=np.zeros((14, 8, 0)), monomials=())
        return _with_deflation(Plan(robot=robot.name, c=c, scale=scale, reverse=False, elim=empty, rank_q=8,
                                    mix=np.eye(6), offsets=offsets, d3=offsets[2] + np.array([0.0, 2.0, 4.0]),
                                    notes=tuple(data["notes"]), cut=data["cut"]))
    elim = Elimination(pl=np.array(data["pl"]), r0=np.array(data["r0"]).reshape(14, -1),
                       q=np.array(data["q"]).reshape(14, 8, -1),
                       monomials=tuple(tuple(m) for m in data["monomials"]))
    rng = _seeded(robot.id)
    rank_q = int(data["rank_q"])
    mix = np.linalg.qr(rng.standard_normal((14 - rank_q, 6)))[0].T if rank_q < 8 else np.eye(6)
    offsets = rng.uniform(-np.pi, np.pi, 3)
    d3 = offsets[2] + np.array([0.0, 2.0, 4.0])
    return _with_deflation(Plan(robot=robot.name, c=c, scale=scale, reverse=bool(data["reverse"]), elim=elim,
                                rank_q=rank_q, mix=mix, offsets=offsets, d3=d3, notes=tuple(data["notes"]), cut=None))


def _with_deflation(pl: Plan) -> Plan:
    """The plan with its deflation (:func:`_deflation`), or unchanged when there is none."""
    found = _deflation(pl)
    if found is None:
        return pl
    basis, keep, spurious = found
    return dataclasses.replace(pl, deflate=basis, deflate_keep=keep, spurious=spurious)


def _pencil_samples(pl: Plan, m: int = 4, seed: int = 17):
    """The pencil's coefficients (m, 3, 12, 12) at m random configurations' poses."""
    q = np.random.default_rng(seed).uniform(-np.pi, np.pi, (m, 6))
    _, target = _chain_frames(pl.c, q)
    return _cut_front(pl, target)[-1] if pl.cut else _standard_front(pl, target)[5]


def _constant_null(ms):
    """The common null space (12, k) of the matrices ms (m, 12, 12) when every one has the same
    null space (to rounding), else None."""
    u, sv, vh = np.linalg.svd(ms)
    k = np.sum(sv < 1e-10 * sv[:, :1], axis=1)
    if k.min() == 0 or k.min() != k.max():
        return None
    k = int(k[0])
    bases = np.concatenate([vh[i, -k:].conj().T for i in range(len(ms))], axis=1)
    s2 = np.linalg.svd(bases, compute_uv=False)
    if np.sum(s2 > 1e-8 * s2[0]) != k:
        return None
    return vh[0, -k:].conj().T


def _deflation(pl: Plan):
    """The pencil's pose-independent eigenvectors, removed before the eigenvalues are taken.

    det M(x) has the factor (1 + x^2)^4 for every pose (x = +-i: (s, c) of the eigen-variable
    with s^2 + c^2 = 0); a loop cut of a special arm can add real roots that every pose shares
    (the CRX's q3 = -pi/2 of the cut at joint 2, a 4-fold spurious root). When M's null space
    there is the same for every pose (checked on random poses), the companion matrix C has the
    invariant subspace V spanned by [u; x u] (u in that null space) for every pose, so in an
    orthonormal basis [W V] C is block triangular and the other eigenvalues are those of
    W^T C W: 16 x 16 for a general arm instead of 24 x 24 (the eigen-solver's work falls by
    (24/16)^3), and no spurious candidate. Returns (bases (len(d3), 24, 24) with W first, the
    number of W's columns, the spurious real roots in rad), or None."""
    mats = _pencil_samples(pl)
    # real roots every sample shares (in the eigen-variable's angle)
    d0 = pl.d3[0]
    mk = np.einsum("ak,naij->nkij", _half(d0), mats)
    comp = np.zeros((len(mats), 24, 24))
    comp[:, :12, 12:] = np.eye(12)
    inv = _inv_safe(mk[:, 2])
    comp[:, 12:, :12] = -inv @ mk[:, 0]
    comp[:, 12:, 12:] = -inv @ mk[:, 1]
    if not np.all(np.isfinite(comp)):
        return None
    lam = np.linalg.eigvals(comp)
    # roots every sample shares (x at the offset d0; x = +-i is known), one of each conjugate pair
    common = []
    for x in lam[0]:
        if abs(abs(x.imag) - 1) < 1e-6 and abs(x.real) < 1e-6 or x.imag < -1e-9 * (1 + abs(x)):
            continue
        if all(np.min(np.abs(r - x)) < 1e-7 * (1 + abs(x)) for r in lam[1:]) and \
                not any(abs(x - y) < 1e-7 * (1 + abs(x)) for y in common):
            common.append(complex(x.real, x.imag) if abs(x.imag) > 1e-9 * (1 + abs(x)) else complex(x.real, 0))
    cols = {k: [] for k in range(len(pl.d3))}
    spurious = []
    u = _constant_null(1j * mats[:, 0] + mats[:, 1])       # x = i: (s, c, 1) ~ (i, 1, 0)
    if u is not None:
        for k in range(len(pl.d3)):                         # [u; i u], real and imaginary parts
            cols[k] += [np.concatenate([u.real, -u.imag]), np.concatenate([u.imag, u.real])]
    for x in common:
        u = _constant_null(mk[:, 0] + x * mk[:, 1] + x * x * mk[:, 2])
        if u is None:
            continue
        t = d0 + 2 * np.arctan(x)                           # the eigen-variable's (complex) angle
        if x.imag == 0:
            spurious.append(float(wrap_angle(t.real)))
        for k, d in enumerate(pl.d3):                       # [cos h u; sin h u], h = (t - d) / 2
            h = 0.5 * (t - d)
            w = np.concatenate([np.cos(h) * u, np.sin(h) * u])
            cols[k] += [w.real] + ([w.imag] if x.imag != 0 else [])
    if not cols[0]:
        return None
    bases = []
    for k in range(len(pl.d3)):
        v = np.concatenate(cols[k], axis=1)
        qv, rv = np.linalg.qr(v, mode="complete")
        r = v.shape[1]
        if np.sum(np.abs(np.diag(rv[:r])) > 1e-8 * np.abs(rv).max()) != r:
            return None
        bases.append(np.concatenate([qv[:, r:], qv[:, :r]], axis=1))
    return np.array(bases), 24 - r, tuple(spurious)


def _check_generic(robot, cc, elim):
    """Whether the elimination works on random configurations of the chain ``cc``: Q's rank
    (the largest over the samples) and M(x3) nonsingular at the true q3 minus nothing (the
    pencil not identically singular)."""
    rng = np.random.default_rng(7)
    q = rng.uniform(-np.pi, np.pi, (8, 6))
    _, end = _chain_frames(cc, q)
    t7 = end @ _inv(cc[6])
    lp = np.concatenate([t7[:, :3, 2], t7[:, :3, 3]], axis=1)
    pm = _pose_monomials(lp, elim.monomials)
    qm = np.einsum("ekm,nm->nek", elim.q, pm)
    sv = np.linalg.svd(qm, compute_uv=False)
    rank = int(np.max(np.sum(sv > G6_RANK_TOL * sv[:, :1], axis=1)))
    if rank < 2:
        return False, f"rank Q = {rank}, unusable"
    # the equations must hold at the true configuration and the pencil must be regular
    r0 = np.einsum("em,nm->ne", elim.r0, pm)
    u = np.linalg.svd(qm, full_matrices=True)[0]
    null = np.swapaxes(u[:, :, rank:], 1, 2)
    p_at = (elim.pl[None, :, 0] * np.sin(q[:, 2])[:, None, None] + elim.pl[None, :, 1] * np.cos(q[:, 2])[:, None, None]
            + elim.pl[None, :, 2])
    p_at[:, :, 8] -= r0
    x1 = np.einsum("na,nb->nab", np.stack([np.sin(q[:, 3]), np.cos(q[:, 3]), np.ones(8)], 1),
                   np.stack([np.sin(q[:, 4]), np.cos(q[:, 4]), np.ones(8)], 1)).reshape(8, 9)
    resid = np.abs(np.einsum("nij,nj->ni", null @ p_at, x1)).max()
    if resid > 1e-8:
        return False, f"rank Q = {rank}, the eliminated equations miss the configuration by {resid:.1e}"
    # regular pencil: 6 x 9 rows at a random q3 have rank 6, and the 12 x 12 is nonsingular
    mix = np.linalg.qr(np.random.default_rng(3).standard_normal((14 - rank, 6)))[0].T if rank < 8 else np.eye(6)
    t = rng.uniform(-np.pi, np.pi, 8)
    p_r = (elim.pl[None, :, 0] * np.sin(t)[:, None, None] + elim.pl[None, :, 1] * np.cos(t)[:, None, None]
           + elim.pl[None, :, 2])
    p_r[:, :, 8] -= r0
    sig = mix @ null @ p_r
    m12 = _twelve(sig @ _t45(0.3, -0.7))
    sv12 = np.linalg.svd(m12, compute_uv=False)
    worst = float(np.min(sv12[:, -1] / sv12[:, 0]))
    if worst < G6_RANK_TOL:
        return False, (f"rank Q = {rank}, the 12 x 12 pencil is singular for every q3 (smallest relative "
                       f"singular value below {G6_RANK_TOL:.0e})")      # the rounding's value varies by machine
    return True, f"rank Q = {rank}, pencil regular (smallest relative singular value {worst:.1e} at random q3)"


def _pose_monomials(lp, monomials):
    """(n, K) values of the pose monomials at lp (n, 6)."""
    out = np.ones((lp.shape[0], len(monomials)))
    for k, m in enumerate(monomials):
        for i in m:
            out[:, k] *= lp[:, i]
    return out


def _half(delta):
    """B (3, 3): (s, c, 1) (1 + x^2) of delta + 2 atan(x) = B @ (1, x, x^2)."""
    sd, cd = np.sin(delta), np.cos(delta)
    return np.array([[sd, 2 * cd, -sd], [cd, -2 * sd, -cd], [1.0, 0.0, 1.0]])


def _t45(d4, d5):
    """X1 (1 + x4^2)(1 + x5^2) = T45 @ (x4^i x5^j, index 3 i + j)."""
    return np.kron(_half(d4), _half(d5))


def _twelve(sig):
    """(..., 12, 12): the 6 equations in x4^i x5^j (i, j <= 2) and the same times x4."""
    out = np.zeros(sig.shape[:-2] + (12, 12))
    out[..., :6, :9] = sig
    out[..., 6:, 3:] = sig
    return out


# --------------------------------------------------------------------------- #
# Solving
# --------------------------------------------------------------------------- #
@dataclass
class General6RSolutions:
    """Solutions of n poses: ``q`` (n, 16, 6) NaN-padded (valid rows first), ``counts`` (n,),
    ``singular`` (n, 16) (the Jacobian is rank-deficient there), ``degenerate`` (n,) (the pose
    is special for the elimination: the leading matrix ill-conditioned for every offset, or Q of
    lower rank than the arm's; solutions found are still checked, but some may be missing),
    ``reason`` (list, why a pose has no solution)."""

    q: np.ndarray
    counts: np.ndarray
    singular: np.ndarray
    degenerate: np.ndarray
    reason: list


MAX_SOLUTIONS = 16
#: Inverse iteration for the null vector: a fixed start vector and a shift of 1e-11 (relative to
#: the matrix's largest entry) that keeps the solve finite at an exact eigenvalue.
_START = np.random.default_rng(12).standard_normal(12)
_NUDGE = 1e-11


def solve(robot, poses, chunk: int = 2048) -> General6RSolutions:
    """Every real IK solution (up to 16) of each pose, poses (n, 8) unit dual quaternions or
    (n, 4, 4) matrices of the robot's end frame; see the module docstring."""
    robot = load_robot(robot)
    pl = plan(robot)
    poses, _ = as_pose_batch(poses)
    n = poses.shape[0]
    q = np.full((n, MAX_SOLUTIONS, 6), np.nan)
    counts = np.zeros(n, dtype=np.int64)
    sing = np.zeros((n, MAX_SOLUTIONS), dtype=bool)
    degen = np.zeros(n, dtype=bool)
    for s in range(0, n, chunk):
        e = min(n, s + chunk)
        q[s:e], counts[s:e], sing[s:e], degen[s:e] = (_solve_chunk_cut if pl.cut else _solve_chunk)(
            robot, pl, poses[s:e])
    todo = np.nonzero(degen)[0]
    for s in range(0, len(todo), chunk):
        t = todo[s:s + chunk]
        q[t], counts[t], sing[t], degen[t] = _perturbed(robot, pl, poses[t], q[t], counts[t])
    # a singular solution: the pose is on the singular set's image, where solutions can merge or
    # form a continuum (then only points of it are returned): flagged
    degen |= np.any(sing, axis=1)
    # off the singular set a 6R has an even number of solutions: an odd count lost or merged one
    degen |= counts % 2 == 1
    reason = ["" if k else ("degenerate: the elimination degenerates at this pose and at the nearby poses "
                            "tried; no solution found" if d else
                            "unreachable: no real root of the eliminant reproduces the pose")
              for k, d in zip(counts, degen)]
    return General6RSolutions(q=q, counts=counts, singular=sing, degenerate=degen, reason=reason)


#: Unit twists (rotation vector, translation / size) to the nearby poses of a degenerate pose.
_TWISTS = np.random.default_rng(20261205).standard_normal((8, 6))
_TWISTS /= np.linalg.norm(_TWISTS, axis=1, keepdims=True)


def _perturbed(robot, pl: Plan, poses, q0, counts0):
    """The poses whose elimination degenerates (the pencil singular or Q rank-deficient at that
    pose, though its solutions may be isolated and regular: e.g. axis-aligned configurations of
    the CRX), solved again at G6_PERTURB_TRIALS nearby poses (each moved by a random twist of
    G6_PERTURB rad and G6_PERTURB times the arm's size), whose solutions Newton carries back onto
    the pose (a regular solution moves continuously with the pose). Returns (q, counts,
    singular, degenerate) as :func:`_collect`; degenerate stays set where every nearby pose was
    degenerate too, a solution found is singular (a continuum of solutions, or a multiple root:
    some may be missing) or the pose's own pencil is singular for every q3."""
    n = len(poses)
    target = _to_matrix(poses)
    ips = [np.repeat(np.arange(n), counts0)]
    qs = [q0[np.arange(MAX_SOLUTIONS)[None, :] < counts0[:, None]]]
    every = np.ones(n, dtype=bool)
    solver = _solve_chunk_cut if pl.cut else _solve_chunk
    for k in range(G6_PERTURB_TRIALS):
        # the same twists for every pose (a pose's result does not depend on its batch)
        tw = np.broadcast_to(_TWISTS[k % len(_TWISTS)] * G6_PERTURB, (n, 6))
        moved = target.copy()
        ang = np.linalg.norm(tw[:, :3], axis=1)
        rot = quat._to_matrix(quat._from_axis_angle(tw[:, :3] / np.maximum(ang, 1e-300)[:, None], ang))
        moved[:, :3, :3] = target[:, :3, :3] @ rot
        moved[:, :3, 3] += tw[:, 3:] * pl.scale
        qp, cp, _, dp = solver(robot, pl, as_pose_batch(moved)[0])
        every &= dp
        ips.append(np.repeat(np.arange(n), cp))
        qs.append(qp[np.arange(MAX_SOLUTIONS)[None, :] < cp[:, None]])
    ip, qc = np.concatenate(ips), np.concatenate(qs)
    scaled = target.copy()
    scaled[:, :3, 3] /= pl.scale
    qc, err, jac = _newton(pl.c, qc, scaled[ip], with_error=True)
    q, counts, sing, degen = _collect(robot, pl, poses, ip, wrap_angle(qc), n, every, err, jac)
    # a pose whose pencil is singular for every q3 (its leading matrix past G6_LEADING_COND at
    # every offset tried: det M(x) = 0 identically) can have a continuum of solutions that the
    # nearby poses do not show (none of their solutions is near it: the CRX at q3 = -pi/2 with
    # axes 1 and 5 on one line, q1 - q5 free): the solutions found there are returned, flagged
    mats = _cut_front(pl, scaled)[-1] if pl.cut else _standard_front(pl, scaled)[5]
    whole = _pencil_roots(pl, mats, np.zeros(n, dtype=bool))[-1]
    return q, counts, sing, degen | np.any(sing, axis=1) | whole


def _to_matrix(poses):
    m = np.zeros((poses.shape[0], 4, 4))
    m[:, :3, :3] = quat._to_matrix(poses[:, :4])
    m[:, :3, 3] = dq._translation(poses)
    m[:, 3, 3] = 1.0
    return m


def _pencil_roots(pl, mats, degen):
    """The 12 x 12 quadratic pencil M0 + x M1 + x^2 M2 of each pose solved as a 24 x 24 companion
    eigenproblem (Manocha and Canny 1994, section 4): for each pose the first offset of the
    eigen-variable (``pl.d3``, the Moebius substitution) whose leading matrix M2 is well
    conditioned (1-norm condition below G6_GOOD_COND), else the best tried. Returns (the offset per
    pose (n,), the pencil (n, 3, 12, 12), eigenvalues (n, 24), which are real (n, 24), the
    degenerate flags with poses whose best leading matrix is still past G6_LEADING_COND added)."""
    n = len(mats)
    best_cond = np.full(n, np.inf)
    best = np.zeros(n, dtype=int)
    lead_inv = np.zeros((n, 12, 12))
    mk = np.zeros((n, 3, 12, 12))
    todo = np.arange(n)
    for k, d3 in enumerate(pl.d3):
        sub = mats if len(todo) == n else mats[todo]
        cand = (_half(d3).T @ sub.reshape(len(todo), 3, 144)).reshape(len(todo), 3, 12, 12)   # M0, M1, M2
        lead = cand[:, 2]
        exact = np.ones(len(todo), dtype=bool)
        inv = _inv_safe(lead, exact)
        with np.errstate(all="ignore"):
            cond = np.abs(lead).sum(1).max(1) * np.abs(inv).sum(1).max(1)
        # an exactly singular leading matrix (its pseudo-inverse taken, whose norm says nothing of
        # the condition) is as bad as any: before, a pose whose pencil is singular for every value
        # took such an offset as well conditioned and was not flagged (a Jaco 2 pose, two solutions lost)
        cond = np.where(np.isfinite(cond) & exact, cond, np.inf)
        better = (cond < best_cond[todo]) | (k == 0)            # the first offset at least
        idx = todo[better]
        if len(idx) == n:
            best[:], best_cond[:], lead_inv, mk = k, cond, inv, cand
        else:
            best[idx], best_cond[idx], lead_inv[idx], mk[idx] = k, cond[better], inv[better], cand[better]
        todo = todo[~(best_cond[todo] < G6_GOOD_COND)]
        if len(todo) == 0:
            break
    degen = degen | ~(best_cond < G6_LEADING_COND)
    lower = np.concatenate([-lead_inv @ mk[:, 0], -lead_inv @ mk[:, 1]], axis=2)   # C's lower rows
    if not np.all(np.isfinite(lower)):
        lower[~np.isfinite(lower)] = 0.0
    lam = _eigvals(pl, lower, best)                          # (n, 24), NaN-padded
    real = np.abs(lam.imag) < G6_REAL_TOL * (1 + np.abs(lam) ** 2)
    return pl.d3[best], mk, lam, real, degen


def _standard_front(pl: Plan, target):
    """The pencil of each pose (target: (n, 4, 4) scaled matrices of the forward chain): (c,
    target in the solved direction, the complete QR of Q, degenerate flags, the pencil's
    coefficients of (s3, c3, 1) (n, 3, 12, 12), the pose terms r0 of P's constant (n, 14))."""
    n = target.shape[0]
    c = _reverse(pl.c) if pl.reverse else pl.c
    if pl.reverse:
        target = np.linalg.inv(target)
    el = pl.elim
    t7 = target @ _inv(c[6])
    lp = np.concatenate([t7[:, :3, 2], t7[:, :3, 3]], axis=1)
    pm = _pose_monomials(lp, el.monomials)
    qm = _mm(pm, el.q.reshape(112, -1).T).reshape(n, 14, 8)
    r0 = _mm(pm, el.r0.T)                                       # (n, 14)
    # the left null space of Q (rank 8 for a general arm) and the least squares of Q X2 = b
    # (for q1, q2 below) by one complete QR
    qq, rr = np.linalg.qr(qm, mode="complete")               # (n, 14, 14), (n, 14, 8)
    diag = np.abs(np.diagonal(rr[:, :8], axis1=1, axis2=2))
    rank = pl.rank_q
    degen = diag.min(axis=1) < G6_RANK_TOL * diag.max(axis=1) if rank == 8 else np.zeros(n, dtype=bool)
    null = pl.mix @ np.swapaxes(qq[:, :, rank:], 1, 2)       # (n, 6, 14)
    t45 = _t45(pl.offsets[0], pl.offsets[1])
    pt = np.broadcast_to(el.pl @ t45, (n, 14, 3, 9)).copy()  # P (1 + x4^2)(1 + x5^2) in x4^i x5^j
    pt[:, :, 2, :] -= r0[:, :, None] * t45[8][None, None, :]
    sig = (null @ pt.reshape(n, 14, 27)).reshape(n, 6, 3, 9).transpose(0, 2, 1, 3)   # s3, c3, 1
    mats = _twelve(sig)                                      # (n, 3, 12, 12)
    return c, target, qq, rr, degen, mats, r0


#: The deflation is used for a pose when the block it drops, W^T C V, is below this relative
#: to C's largest entry (it is zero to rounding: the removed eigenvectors are the same for every
#: pose); else that pose's 24 x 24 companion is solved whole.
DEFLATE_LEAK = 1e-9


def _eigvals(pl: Plan, lower, best):
    """The eigenvalues of the companion matrices C = [[0, I], lower] (lower (n, 12, 24), offset
    index best (n,)): those of the deflated block W^T C W (:func:`_deflation`), NaN-padded to
    24, where the deflation holds; the whole matrix's elsewhere. With [W V] = B = [B1; B2]
    (rows 1-12 and 13-24), C B = [B2; lower B], so W^T C B = W1^T B2 + W2^T (lower B): no 24 x 24
    product per pose."""
    n = len(lower)

    def whole_matrix(idx):
        comp = np.zeros((len(idx), 24, 24))
        comp[:, :12, 12:] = np.eye(12)
        comp[:, 12:] = lower[idx]
        return comp

    if pl.deflate is None:
        return np.linalg.eigvals(whole_matrix(np.arange(n)))
    keep = pl.deflate_keep
    lam = np.full((n, 24), np.nan + 0j)
    whole = np.zeros(n, dtype=bool)
    for k in np.unique(best):
        idx = np.nonzero(best == k)[0]
        m = len(idx)
        b = pl.deflate[k]
        w1, w2 = b[:12, :keep], b[12:, :keep]
        low = lower[idx]
        cb = _mm(low.reshape(12 * m, 24), b).reshape(m, 12, 24)               # lower B
        t = w1.T @ b[12:] + w2.T @ cb                                         # W^T C B (m, keep, 24)
        leak = np.abs(t[:, :, keep:]).max(axis=(1, 2))                        # W^T C V
        good = leak <= DEFLATE_LEAK * np.maximum(1.0, np.abs(low).max(axis=(1, 2)))
        if np.any(good):
            lam[idx[good], :keep] = np.linalg.eigvals(t[good, :, :keep])
        whole[idx[~good]] = True
    if np.any(whole):
        lam[whole] = np.linalg.eigvals(whole_matrix(np.nonzero(whole)[0]))
    return lam


def _lsq_operator(qq, rr):
    """Per pose the operator (n, 8, 14) of the least squares of Q X2 = b by its complete QR
    (X2 = R^-1 Q1^T b, Q1 the first 8 columns; a diagonal entry of R below G6_RANK_TOL of its
    largest set to 1: the rank-deficient Q of a degenerate pose), made once per pose rather
    than solved once per candidate."""
    r8 = rr[:, :8]
    ok8 = np.abs(np.diagonal(r8, axis1=1, axis2=2)) > G6_RANK_TOL * np.abs(r8).max(axis=(1, 2))[:, None]
    r8 = np.where(np.eye(8, dtype=bool) & ~ok8[:, :, None], 1.0, r8)
    q1t = np.swapaxes(qq[:, :, :8], 1, 2)
    try:
        with np.errstate(all="ignore"):
            return np.linalg.solve(r8, q1t)
    except np.linalg.LinAlgError:
        return np.stack([np.linalg.lstsq(a, b, rcond=None)[0] for a, b in zip(r8, q1t)])


def _solve_chunk(robot, pl: Plan, poses):
    n = poses.shape[0]
    target = _to_matrix(poses)
    target[:, :3, 3] /= pl.scale
    c, target, qq, rr, degen, mats, r0 = _standard_front(pl, target)
    # the offset of q3: the first whose leading matrix is well conditioned, else the best of
    # those tried (the Moebius substitution against a singular leading matrix)
    d3, mk, lam, real, degen = _pencil_roots(pl, mats, degen)
    # candidates: (pose, eigenvalue)
    ip, ie = np.nonzero(real)
    x3 = lam[ip, ie].real
    # the null vector of M(x3) (the monomials x4^i x5^j) by one step of inverse iteration from a
    # fixed vector: M(x3) is singular to rounding, so its solution is the null vector
    v = _monomial_vectors(mk, ip, x3)
    ip, x3, v = _near_pair_candidates(mk, ip, x3, v)
    num4 = np.sum(v[:, 1:, :] * v[:, :-1, :], axis=(1, 2))
    den4 = np.sum(v[:, :-1, :] ** 2, axis=(1, 2))
    num5 = np.sum(v[:, :, 1:] * v[:, :, :-1], axis=(1, 2))
    den5 = np.sum(v[:, :, :-1] ** 2, axis=(1, 2))
    q4 = pl.offsets[0] + 2 * np.arctan2(num4, den4)
    q5 = pl.offsets[1] + 2 * np.arctan2(num5, den5)
    q3 = d3[ip] + 2 * np.arctan(x3)
    # q1, q2: least squares of Q X2 = P(q3) X1 (the SVD above)
    # P(q3) X1 = pl . ((s3, c3, 1) x X1) less r0 (the monomial 1 x 1 x 1 carries it)
    m27 = np.einsum("ma,mb,mc->mabc", np.stack([np.sin(q3), np.cos(q3), np.ones_like(q3)], 1),
                    np.stack([np.sin(q4), np.cos(q4), np.ones_like(q4)], 1),
                    np.stack([np.sin(q5), np.cos(q5), np.ones_like(q5)], 1)).reshape(-1, 27)
    rhs = _mm(m27, pl.elim.pl.reshape(14, 27).T) - r0[ip]
    x2 = np.einsum("mke,me->mk", _lsq_operator(qq, rr)[ip], rhs)
    q1 = np.arctan2(x2[:, 2], x2[:, 5])
    q2 = np.arctan2(x2[:, 6], x2[:, 7])
    qc = np.stack([q1, q2, q3, q4, q5, np.zeros_like(q1)], 1)
    # q6 from A6 = C1 Rz1 .. C6 (the frame before joint 6): Rz(q6) = A6^-1 T C7^-1, whose first
    # column is R_A6^T (R_T c), c the first column of C7^-1's rotation; the chain of q1..q5 is
    # the one Newton's first step needs (the frames before each joint's rotation), kept
    m = len(ip)
    cq, sq = np.cos(qc), np.sin(qc)
    zs, ps = np.empty((m, 6, 3)), np.empty((m, 6, 3))
    x = _chain_x(c, cq, sq, zs, ps, stop=5)
    tp = target[ip]
    u = tp[:, :3, :3] @ _inv(c[6])[:3, 0]
    q6 = np.arctan2(np.einsum("mi,mi->m", x[1], u), np.einsum("mi,mi->m", x[0], u))
    qc[:, 5] = q6
    _x_rot(x, np.cos(q6)[:, None], np.sin(q6)[:, None])
    qc, err, jac = _newton(c, qc, tp, with_error=True, first=(zs, ps, _x_times(x, c[6])),
                           far=(NEWTON_FAR, degen[ip]))
    if pl.reverse:
        qc = -qc[:, ::-1]
        jac = None                     # the reversed chain's Jacobian: the forward one is made again
    qc = wrap_angle(qc)
    return _collect(robot, pl, poses, ip, qc, n, degen, err, jac)


#: Rows of the 12 monomials x4^i x5^j (index 3 i + j) and their shifts by x4 and by x5.
_BASE4 = [3 * i + j for i in range(3) for j in range(3)]
_SHIFT4 = [3 * (i + 1) + j for i in range(3) for j in range(3)]
_BASE5 = [3 * i + j for i in range(4) for j in range(2)]
_SHIFT5 = [3 * i + j + 1 for i in range(4) for j in range(2)]
#: Eigenvalues x3 of one pose closer than this (relative to 1 + |x3|) are one multiple root.
CLUSTER_TOL = 1e-6
#: Two eigenvalues of one pose closer than this (relative to 1 + |x3|), but apart by more than
#: CLUSTER_TOL, are a near pair: two solutions with almost the same q3 (near a fold of the
#: pose's solutions). Their null vectors are nearly parallel; extra candidates are made from
#: the two-dimensional near-null space (:func:`_near_pair_candidates`).
NEAR_PAIR_TOL = 1e-4


def _monomial_vectors(mk, ip, x3):
    """(k, 4, 3): for each candidate x3 the monomial vector (x4^i x5^j) in the null space of
    M(x3). A simple root: :func:`_null_vectors`. A multiple root shared by several solutions
    (the same q3, a null space of dimension d > 1, as at symmetric poses of the CRX): the d
    monomial vectors in the null space V are found by the shift structure of the monomials
    (V[shift] c = x V[base] c, for x4 and x5 combined at random), one per member of the cluster
    (Stetter's eigenvector method)."""
    # M(x3) has the structure of _twelve (its 6 x 9 block twice): only that block is gathered
    powers = np.stack([np.ones_like(x3), x3, x3 * x3], 1)[:, None, :]            # (k, 1, 3)
    six = np.ascontiguousarray(mk[:, :, :6, :9]).reshape(len(mk), 3, 54)
    sx = (powers @ six[ip]).reshape(len(ip), 6, 9)
    scale_m = np.abs(sx).max(axis=(1, 2), keepdims=True)
    sx /= np.where(scale_m > 0, scale_m, 1.0)
    mx = _twelve(sx)
    v = _null_vectors(mx + _NUDGE * np.eye(12))
    if len(ip) < 2:
        return v
    order = np.lexsort((x3, ip))
    ips, xs = ip[order], x3[order]
    near = (ips[1:] == ips[:-1]) & (np.abs(xs[1:] - xs[:-1]) <= CLUSTER_TOL * (1 + np.abs(xs[1:])))
    if not np.any(near):
        return v
    # clusters: runs of "near"; their heads' singular values in one batch
    starts = np.nonzero(near & ~np.r_[False, near[:-1]])[0]
    ends = starts.copy()
    for i, st in enumerate(starts):
        e = st
        while e < len(near) and near[e]:
            e += 1
        ends[i] = e
    heads = order[starts]
    _, sv, vt = np.linalg.svd(mx[heads])
    dims = np.minimum(ends - starts + 1, np.maximum(1, np.sum(sv < 1e-7 * sv[:, :1], axis=1)))
    for st, en, d, vth in zip(starts, ends, dims, vt):
        if d < 2:
            continue
        members = order[st:en + 1]
        vecs = _shift_vectors(vth[-d:].T)                    # the null space basis (12, d)
        if vecs is not None:
            v[members[:d]] = vecs.reshape(d, 4, 3)
    return v


def _wide_cluster_candidates(mk, ip, x3, v, order):
    """Extra candidates for a multiple eigenvalue whose null space of M(x) is wider than its
    cluster (more null vectors than eigenvalues found there: at a singular configuration of the
    CRX, q = (pi, pi/2, pi, pi/2, pi, pi/2), a double eigenvalue with a 4-dimensional null
    space, where the monomial vectors of :func:`_monomial_vectors` from 2 of its 4 dimensions
    are wrong and the double root was lost). Stetter's eigenvector method as there, on the whole
    null space: one candidate per null vector, each with the cluster's x3 (Newton and the FK
    check decide). ``order``: lexsort of (x3, ip). Returns (ip, x3, v) with them appended (the
    first len(ip) rows unchanged)."""
    ips, xs = ip[order], x3[order]
    near = (ips[1:] == ips[:-1]) & (np.abs(xs[1:] - xs[:-1]) <= CLUSTER_TOL * (1 + np.abs(xs[1:])))
    if not np.any(near):
        return ip, x3, v
    starts = np.nonzero(near & ~np.r_[False, near[:-1]])[0]
    sizes = np.nonzero(near & ~np.r_[near[1:], False])[0] - starts + 2     # members per cluster
    heads = order[starts]
    powers = np.stack([np.ones(len(heads)), x3[heads], x3[heads] ** 2], 1)[:, None, :]
    mx = (powers @ mk.reshape(len(mk), 3, 144)[ip[heads]]).reshape(len(heads), 12, 12)
    _, sv, vt = np.linalg.svd(mx)
    dims = np.sum(sv < 1e-7 * sv[:, :1], axis=1)
    extra_i, extra_v = [], []
    for h, size, d, vth in zip(heads, sizes, dims, vt):
        if d <= size:
            continue
        basis = vth[-d:].T                                   # (12, d)
        with np.errstate(all="ignore"):
            a = (np.linalg.pinv(basis[_BASE4]) @ basis[_SHIFT4]
                 + 0.7071 * np.linalg.pinv(basis[_BASE5]) @ basis[_SHIFT5])
            _, cvec = np.linalg.eig(a)
            vecs = (basis @ cvec).T
            big = vecs[np.arange(d), np.argmax(np.abs(vecs), axis=1)]
            vecs = (vecs / np.where(big != 0, big, 1.0)[:, None]).real
        keep = np.all(np.isfinite(vecs), axis=1)
        extra_i += [h] * int(keep.sum())
        extra_v.append(vecs[keep].reshape(-1, 4, 3))
    if not extra_i:
        return ip, x3, v
    idx = np.array(extra_i)
    return np.concatenate([ip, ip[idx]]), np.concatenate([x3, x3[idx]]), np.concatenate([v, *extra_v])


def _shift_vectors(basis):
    """Stetter's eigenvector method in a basis (12, d) of (near-)null directions of M(x): the d
    monomial vectors x4^i x5^j in its span (V[shift] c = x V[base] c for x4 and x5, combined),
    each scaled to a largest entry of 1, (d, 12); None where it fails. A stack of bases
    (p, 12, d) gives (p, d, 12), with the failed ones' rows NaN."""
    with np.errstate(all="ignore"):
        a = (np.linalg.pinv(basis[..., _BASE4, :]) @ basis[..., _SHIFT4, :]
             + 0.7071 * np.linalg.pinv(basis[..., _BASE5, :]) @ basis[..., _SHIFT5, :])
        _, cvec = np.linalg.eig(a)
        vecs = np.swapaxes(basis @ cvec, -1, -2)             # (..., d, 12), complex in general
        # a real monomial vector times a complex scale: rotate each onto the real axis
        big = np.take_along_axis(vecs, np.argmax(np.abs(vecs), axis=-1)[..., None], axis=-1)
        vecs = (vecs / np.where(big != 0, big, 1.0)).real
    if basis.ndim == 2:
        return vecs if np.all(np.isfinite(vecs)) else None
    return np.where(np.all(np.isfinite(vecs), axis=(-2, -1))[:, None, None], vecs, np.nan)


#: A near chain of at most this many roots is taken whole (:func:`_near_pair_candidates`); a
#: longer one pair by pair.
NEAR_CHAIN_MAX = 4


def _near_pair_candidates(mk, ip, x3, v):
    """Extra candidates for near chains of eigenvalues: a run of real eigenvalues of one pose,
    each within :data:`NEAR_PAIR_TOL` (relative to 1 + |x3|) of the next, that is not one
    multiple root: some gap is past :data:`CLUSTER_TOL` (a near pair: two solutions with almost
    the same q3, near a fold of the pose's solutions), or a cluster in it (a run within
    CLUSTER_TOL) has fewer null directions at its head (singular values of M(x) below 1e-7 of the
    largest, :func:`_monomial_vectors`' test) than members: distinct roots closer than
    CLUSTER_TOL (the xArm6 at q = (-pi/2, pi/2, 0, 0, pi, 0): four solutions within 2e-6 rad of
    q4 = 0, two pairs of them 5e-12 and 3e-8 apart, where the cluster's two null vectors lost
    two solutions with an even count and no flag). A run of s <= :data:`NEAR_CHAIN_MAX` roots:
    the s monomial vectors in the span of M(x)'s s smallest right singular vectors (x the run's
    mean) by the shift structure (:func:`_shift_vectors`), each with each member's x3 (s * s
    candidates); a longer run: the same for each of its pairs apart by more than CLUSTER_TOL. They
    only add candidates (Newton and the FK check decide), so a solution the single null vectors
    missed (the members' nearly parallel) is found. Returns (ip, x3, v) with the extra
    candidates appended (the first len(ip) rows unchanged)."""
    if len(ip) < 2:
        return ip, x3, v
    order = np.lexsort((x3, ip))
    ip, x3, v = _wide_cluster_candidates(mk, ip, x3, v, order)
    ips, xs = ip[order], x3[order]
    gap = np.abs(xs[1:] - xs[:-1])
    rel = 1 + np.abs(xs[1:])
    same = ips[1:] == ips[:-1]
    close = same & (gap <= NEAR_PAIR_TOL * rel)
    if not np.any(close):
        return ip, x3, v
    tight = same & (gap <= CLUSTER_TOL * rel)
    mk144 = mk.reshape(len(mk), 3, 144)

    def pencils(pos, x):
        """M(x) (p, 12, 12) of the poses at sorted positions pos: (1, x, x^2) times the
        pencil's three matrices, pose by pose."""
        return (np.stack([np.ones_like(x), x, x * x], 1)[:, None, :] @ mk144[ips[pos]]).reshape(-1, 12, 12)

    # runs of close gaps: members s .. e (sorted positions), whole arrays (no loop per run)
    edge = np.diff(np.concatenate([[0], close.astype(np.int8), [0]]))
    rs, re_ = np.nonzero(edge == 1)[0], np.nonzero(edge == -1)[0]
    loose = np.concatenate([[0], np.cumsum(close & ~tight)])
    wide = loose[re_] - loose[rs] > 0                         # some gap past CLUSTER_TOL
    short = re_ - rs + 1 <= NEAR_CHAIN_MAX
    # the clusters (runs of tight gaps, each inside one run) whose heads' null directions are
    # counted: those of the runs all tight or short, all in one batched SVD
    tedge = np.diff(np.concatenate([[0], tight.astype(np.int8), [0]]))
    cs, ce = np.nonzero(tedge == 1)[0], np.nonzero(tedge == -1)[0]
    run_of = np.searchsorted(rs, cs, side="right") - 1
    keep = ~wide[run_of] | short[run_of]
    cs, ce, run_of = cs[keep], ce[keep], run_of[keep]
    narrow = np.zeros(len(rs), dtype=bool)
    if len(cs):
        sv = np.linalg.svd(pencils(cs, xs[cs]), compute_uv=False)
        few = np.sum(sv < 1e-7 * sv[:, :1], axis=1) < ce - cs + 1
        narrow[run_of[few]] = True
    # groups (contiguous sorted positions: first, size): a short run whole, a long one pair by
    # pair (its gaps past CLUSTER_TOL), in the order of the runs
    todo = wide | narrow
    gs, gd = [rs[todo & short]], [re_[todo & short] - rs[todo & short] + 1]
    for r in np.nonzero(todo & ~short)[0]:
        g = np.arange(rs[r], re_[r])
        gs.append(g[~tight[g]])
        gd.append(np.full(len(gs[-1]), 2))
    first, size = np.concatenate(gs).astype(np.int64), np.concatenate(gd).astype(np.int64)
    at_order = np.argsort(first, kind="stable")               # the runs' order, then the pairs'
    first, size = first[at_order], size[at_order]
    if len(first) == 0:
        return ip, x3, v
    mean = np.empty(len(first))
    for d in np.unique(size):
        at = np.nonzero(size == d)[0]
        mean[at] = np.mean(xs[first[at, None] + np.arange(d)], axis=1)
    vt = np.linalg.svd(pencils(first, mean))[2]
    extra_i, extra_v, extra_at = [], [], []
    for d in np.unique(size):                                 # the groups of one size at once
        at = np.nonzero(size == d)[0]
        w = _shift_vectors(np.swapaxes(vt[at, -d:], 1, 2))    # (p, d, 12)
        ok = np.all(np.isfinite(w), axis=(1, 2))
        at, w = at[ok], w[ok]
        # member j of the group with each of its d vectors: rows j * d + k
        members = order[first[at, None] + np.arange(d)]       # (p, d)
        extra_i.append(np.repeat(members, d, axis=1).ravel())
        extra_v.append(np.tile(w, (1, d, 1)).reshape(-1, 12))
        extra_at.append(np.repeat(at, d * d))
    idx = np.concatenate(extra_i)
    if len(idx) == 0:
        return ip, x3, v
    back = np.argsort(np.concatenate(extra_at), kind="stable")   # the groups' order
    idx = idx[back]
    extra = np.concatenate(extra_v)[back].reshape(-1, 4, 3)
    return np.concatenate([ip, ip[idx]]), np.concatenate([x3, x3[idx]]), np.concatenate([v, extra])


def _null_vectors(m):
    """(k, 4, 3): the null vector of each nearly singular (k, 12, 12): one step of inverse
    iteration (a batched solve), and the SVD's last right singular vector where that solve
    fails (an exactly singular pivot) or leaves a residual |M v| > 1e-6 |M| |v| (x3 then is the
    real part of a complex pair, or a double root: the SVD gives the best start for Newton)."""
    v = np.zeros((len(m), 12))
    try:
        with np.errstate(all="ignore"):
            v = np.linalg.solve(m, np.broadcast_to(_START, (len(m), 12))[..., None])[..., 0]
    except np.linalg.LinAlgError:
        if len(m) > 1:
            h = len(m) // 2
            return np.concatenate([_null_vectors(m[:h]), _null_vectors(m[h:])])
    with np.errstate(all="ignore"):
        v = v / np.linalg.norm(v, axis=1, keepdims=True)
        res = np.linalg.norm(np.einsum("kij,kj->ki", m, v), axis=1)
    bad = ~(res <= 1e-6 * np.abs(m).max(axis=(1, 2)))
    if np.any(bad):
        v[bad] = np.linalg.svd(m[bad])[2][:, -1]
    return v.reshape(-1, 4, 3)


def _inv_safe(a, exact=None):
    """Batched inverse; an exactly singular matrix gives its pseudo-inverse (never raises).
    ``exact``: a boolean array (len(a),) set False where the pseudo-inverse was taken."""
    try:
        return np.linalg.inv(a)
    except np.linalg.LinAlgError:
        if len(a) == 1:
            if exact is not None:
                exact[0] = False
            return np.linalg.pinv(a)
        h = len(a) // 2
        return np.concatenate([_inv_safe(a[:h], None if exact is None else exact[:h]),
                               _inv_safe(a[h:], None if exact is None else exact[h:])])


def _solve_safe(a, b):
    """Batched a x = b; where a is exactly singular, the least-squares solution (never raises)."""
    try:
        return np.linalg.solve(a, b[..., None])[..., 0]
    except np.linalg.LinAlgError:
        if len(a) == 1:
            return np.linalg.lstsq(a[0], b[0], rcond=None)[0][None]
        h = len(a) // 2           # find the singular ones by halves: the rest stay batched
        return np.concatenate([_solve_safe(a[:h], b[:h]), _solve_safe(a[h:], b[h:])])


# --------------------------------------------------------------------------- #
# The loop cut at another joint (arms whose standard elimination degenerates)
# --------------------------------------------------------------------------- #
# The loop Rz(q1) K1 Rz(q2) K2 ... Rz(q6) K6 = I with K_j = C_{j+1} (j = 1..5) and the pose link
# K6 = C7 T^-1 C1. Cut at joint e: G_k = Rz(q_k) K_k, G_e ... G_{e+5} = I, so with the z line of
# joint e, G_{e+4} G_{e+5} [z] = (G_{e+1} G_{e+2} G_{e+3})^-1 K_e^-1 [z]: the same 14 equations,
# the pair (e+4, e+5) eliminated linearly (it holds the pose link for e = 1, 2), the triple
# (e+1, e+2, e+3) constant. Both sides are multilinear in (s, c, 1) of their joints; their
# coefficients are fitted exactly from 3 sample angles per joint (the fit is checked at random
# angles), the pair's per pose.
_SAMPLES = np.array([0.0, 2.0, 4.0])
_BS = np.stack([np.sin(_SAMPLES), np.cos(_SAMPLES), np.ones(3)], 1)       # (sample, (s, c, 1))


def _line_eqs(m):
    """The 14 equations' left sides for transforms m (..., 4, 4) applied to the z line."""
    l, p = m[..., :3, 2], m[..., :3, 3]
    pp = np.sum(p * p, -1)[..., None]
    pl = np.sum(p * l, -1)[..., None]
    return np.concatenate([l, p, pp, pl, np.cross(p, l), pp * l - 2 * pl * p], -1)


def _cut_joints(e):
    j = [((e - 1 + k) % 6) + 1 for k in range(1, 6)]
    return j[:3], j[3:]                   # the constant triple, the pair


def _links(c, target=None):
    """K_1..K_5 (constant) and K_6 (pose link, (n, 4, 4) when target is given)."""
    k = {j: c[j] for j in range(1, 6)}
    if target is not None:
        k[6] = c[6] @ np.linalg.inv(target) @ c[0]
    return k


def _triple_coefs(c, e):
    """(14, 27) coefficients of the triple side, (s, c, 1) of the three joints in order."""
    (a, b, d), _ = _cut_joints(e)
    k = _links(c)
    combos = np.array(list(itertools.product(_SAMPLES, repeat=3)))
    g = [(_rz(combos[:, i]) @ k[j]) for i, j in enumerate((a, b, d))]
    m = np.linalg.inv(k[e] @ g[0] @ g[1] @ g[2])
    vals = _line_eqs(m)                                     # (27, 14)
    return np.linalg.solve(np.kron(np.kron(_BS, _BS), _BS), vals).T


def _pair_coefs(c, e, target):
    """(n, 14, 9) coefficients of the pair side per pose. (Computing only the z column and origin
    of the products, with the fit's inverse, is 5 us per pose faster but moves the rounding at
    the CRX's axis-aligned singular configurations: 8 instead of 4 of the 315 in
    benchmarks/bench_general6r_accuracy.py were neither found nor flagged; kept as it is.)"""
    _, (a, b) = _cut_joints(e)
    k = _links(c, target)
    out = []
    for t0, t1 in itertools.product(_SAMPLES, repeat=2):
        ga = _rz(np.full(len(target), t0)) @ (k[a] if np.ndim(k[a]) == 3 else np.broadcast_to(k[a], (len(target), 4, 4)))
        gb = _rz(np.full(len(target), t1)) @ (k[b] if np.ndim(k[b]) == 3 else np.broadcast_to(k[b], (len(target), 4, 4)))
        out.append(_line_eqs(ga @ gb))
    vals = np.stack(out, 1)                                  # (n, 9, 14)
    return np.swapaxes(np.linalg.solve(np.kron(_BS, _BS), vals), 1, 2)


def _check_cut(c, e):
    """Whether the cut at joint e works on random configurations: the fit is exact, the
    equations hold, Q has rank 8 and the 12 x 12 pencil is regular for one eigen-variable."""
    rng = np.random.default_rng(11)
    q = rng.uniform(-np.pi, np.pi, (6, 6))
    _, target = _chain_frames(c, q)
    y = _triple_coefs(c, e)
    x = _pair_coefs(c, e, target)
    (a, b, d), (f, h) = _cut_joints(e)
    tr = lambda j: np.stack([np.sin(q[:, j - 1]), np.cos(q[:, j - 1]), np.ones(6)], 1)
    ym = np.einsum("na,nb,nc->nabc", tr(a), tr(b), tr(d)).reshape(6, 27)
    xm = np.einsum("na,nb->nab", tr(f), tr(h)).reshape(6, 9)
    resid = np.abs(ym @ y.T - np.einsum("nek,nk->ne", x, xm)).max()
    if not resid < 1e-9:
        return False, f"the equations miss the configurations by {resid:.1e}", None
    qq, _ = np.linalg.qr(x[:, :, :8], mode="complete")
    null = np.swapaxes(qq[:, :, 8:], 1, 2)
    yy = np.broadcast_to(y, (6, 14, 27)).copy()
    yy[:, :, 26] -= x[:, :, 8]
    ten = (null @ yy).reshape(6, 6, 3, 3, 3)
    best = None
    for ev in range(3):
        t = np.moveaxis(ten, 2 + ev, 2)
        th = rng.uniform(-np.pi, np.pi, 6)
        sig = np.einsum("nieab,ne->niab", t, np.stack([np.sin(th), np.cos(th), np.ones(6)], 1)).reshape(6, 6, 9)
        sv = np.linalg.svd(_twelve(sig @ _t45(0.3, -0.7)), compute_uv=False)
        worst = float(np.min(sv[:, -1] / sv[:, 0]))
        if not worst > G6_RANK_TOL:
            continue
        # prefer the eigen-variable whose real roots are simple: a root shared by two solutions
        # (the same q of this joint) needs the slower multiple-root path
        mats = _twelve(t.reshape(6, 6, 3, 9).transpose(0, 2, 1, 3) @ _t45(0.3, -0.7))
        mk = np.einsum("ak,naij->nkij", _half(0.5), mats)
        inv = _inv_safe(mk[:, 2])
        comp = np.zeros((6, 24, 24))
        comp[:, :12, 12:] = np.eye(12)
        comp[:, 12:, :12] = -inv @ mk[:, 0]
        comp[:, 12:, 12:] = -inv @ mk[:, 1]
        lam = np.linalg.eigvals(np.where(np.isfinite(comp), comp, 0.0))
        shared = 0
        for row in lam:
            xr = np.sort(row[np.abs(row.imag) < G6_REAL_TOL * (1 + np.abs(row) ** 2)].real)
            shared += int(np.sum(np.abs(np.diff(xr)) <= CLUSTER_TOL * (1 + np.abs(xr[1:]))))
        if best is None or (shared, -worst) < (best[2], -best[1]):
            best = (ev, worst, shared)
    if best is None:
        return False, "the 12 x 12 pencil is singular for every q of every joint of the triple", None
    return True, (f"triple {(a, b, d)}, eigen-variable q{(a, b, d)[best[0]]}, pencil regular (smallest "
                  f"relative singular value {best[1]:.1e}), {best[2]} shared roots on 6 random poses"), \
        {"e": e, "ev": best[0], "y": y.tolist()}


def _cut_front(pl: Plan, target):
    """The pencil of each pose for the loop cut (target: (n, 4, 4) scaled): (the pair's
    coefficients (n, 14, 9), the complete QR of their Q, degenerate flags, the triple side with
    the pose terms (n, 14, 27), the triple's joints in the pencil's order, the pencil's
    coefficients (n, 3, 12, 12))."""
    n = target.shape[0]
    e, ev = pl.cut["e"], pl.cut["ev"]
    y = np.array(pl.cut["y"])
    x = _pair_coefs(pl.c, e, target)                        # (n, 14, 9)
    qx = x[:, :, :8]
    qq, rr = np.linalg.qr(qx, mode="complete")
    diag = np.abs(np.diagonal(rr[:, :8], axis1=1, axis2=2))
    degen = diag.min(axis=1) < G6_RANK_TOL * diag.max(axis=1)
    null = np.swapaxes(qq[:, :, 8:], 1, 2)
    yy = np.broadcast_to(y, (n, 14, 27)).copy()
    yy[:, :, 26] -= x[:, :, 8]
    order = [ev] + [i for i in range(3) if i != ev]         # eigen joint, then the vector's two
    ten = np.moveaxis((null @ yy).reshape(n, 6, 3, 3, 3), [2 + i for i in order], [2, 3, 4])
    sig = (ten.reshape(n, 6, 3, 9) @ _t45(pl.offsets[0], pl.offsets[1])).transpose(0, 2, 1, 3)
    return x, qq, rr, degen, yy, order, _twelve(sig)



def triple_angles(v, q_eig, offsets, order):
    """The cut's triple of joints from one eigenpair per candidate: ``q_eig`` the eigen-variable's
    angle, the other two from the monomial vector ``v`` (m, 4, 3) as ratios of consecutive
    half-angle tangent powers (least squares over the rows), each shifted by its random offset;
    ``order`` places them in the triple. Returns the three angle arrays in the triple's order and
    the 27 monomials (s, c, 1) x (s, c, 1) x (s, c, 1) of them (m, 27)."""
    num4 = np.sum(v[:, 1:, :] * v[:, :-1, :], axis=(1, 2))
    den4 = np.sum(v[:, :-1, :] ** 2, axis=(1, 2))
    num5 = np.sum(v[:, :, 1:] * v[:, :, :-1], axis=(1, 2))
    den5 = np.sum(v[:, :, :-1] ** 2, axis=(1, 2))
    vals = {order[0]: q_eig,
            order[1]: offsets[0] + 2 * np.arctan2(num4, den4),
            order[2]: offsets[1] + 2 * np.arctan2(num5, den5)}
    qt = [vals[i] for i in range(3)]
    tr = [np.stack([np.sin(t), np.cos(t), np.ones_like(t)], 1) for t in qt]
    return qt, np.einsum("ma,mb,mc->mabc", *tr).reshape(-1, 27)

def _solve_chunk_cut(robot, pl: Plan, poses):
    n = poses.shape[0]
    target = _to_matrix(poses)
    target[:, :3, 3] /= pl.scale
    c = pl.c
    e = pl.cut["e"]
    triple, (f, h) = _cut_joints(e)
    x, qq, rr, degen, yy, order, mats = _cut_front(pl, target)
    d3, mk, lam, real, degen = _pencil_roots(pl, mats, degen)
    ip, ie = np.nonzero(real)
    x3 = lam[ip, ie].real
    v = _monomial_vectors(mk, ip, x3)
    ip, x3, v = _near_pair_candidates(mk, ip, x3, v)
    qt, ym = triple_angles(v, d3[ip] + 2 * np.arctan(x3), pl.offsets, order)
    # Y ym with Y = y less the pair's constant column in column 26 (the monomial 1 x 1 x 1)
    rhs = _mm(ym, np.asarray(pl.cut["y"]).T) - x[ip, :, 8]
    x2 = np.einsum("mke,me->mk", _lsq_operator(qq, rr)[ip], rhs)
    qc = np.zeros((len(ip), 6))
    for j, t in zip(triple, qt):
        qc[:, j - 1] = t
    qc[:, f - 1] = np.arctan2(x2[:, 2], x2[:, 5])
    qc[:, h - 1] = np.arctan2(x2[:, 6], x2[:, 7])
    # joint e from the rest: the chain is A_e Rz(q_e) B (A_e = C1 Rz1 .. C_e, B = C_{e+1} .. C7),
    # so Rz(q_e) = A_e^-1 T B^-1, whose first column is R_Ae^T R_T b, b the first row of R_B;
    # the chain A_e is continued past joint e for Newton's first step
    m = len(ip)
    cq, sq = np.cos(qc), np.sin(qc)
    zs, ps = np.empty((m, 6, 3)), np.empty((m, 6, 3))
    x = _chain_x(c, cq, sq, zs, ps, stop=e - 1)
    xb = _chain_x(c, cq, sq, np.empty((m, 6, 3)), np.empty((m, 6, 3)), start=e)
    tp = target[ip]
    u = np.einsum("mij,mj->mi", tp[:, :3, :3], np.stack([xb[0][:, 0], xb[1][:, 0], xb[2][:, 0]], 1))
    qe = np.arctan2(np.einsum("mi,mi->m", x[1], u), np.einsum("mi,mi->m", x[0], u))
    qc[:, e - 1] = qe
    cq[:, e - 1], sq[:, e - 1] = np.cos(qe), np.sin(qe)
    _x_rot(x, cq[:, e - 1, None], sq[:, e - 1, None])
    x = _chain_x(c, cq, sq, zs, ps, x=x, start=e)
    qc, err, jac = _newton(c, qc, tp, with_error=True, first=(zs, ps, x), far=(NEWTON_FAR, degen[ip]))
    return _collect(robot, pl, poses, ip, wrap_angle(qc), n, degen, err, jac)


#: Newton stops after a step below this (rad, every joint): derive.ik.tolerances.G6_NEWTON_DONE.
NEWTON_DONE = G6_NEWTON_DONE
#: The first solve's Newton gives up on a far candidate of a pose not flagged degenerate from
#: this step on (:func:`_newton`'s ``far``): derive.ik.tolerances.G6_REF_NEWTON_FAR.
NEWTON_FAR = G6_REF_NEWTON_FAR


def _newton(c, q, target, steps=None, with_error=False, first=None, far=None):
    """Damped Newton steps on the product-form FK (geometric Jacobian), each candidate until its
    error (scaled lengths and rad) is below 1e-13, or after a step below :data:`NEWTON_DONE`
    from an error below it, or when G6_NEWTON_MAX steps are done. ``first``: the chain at q
    ((zs, ps, end) of :func:`_frames_x`) when the caller has it. With ``with_error``, also the
    last error measured per candidate (max of scaled position and rotation; after a last step
    below NEWTON_DONE, the bound on the error it leaves) and the Jacobian
    there (m, 6, 6) (at the returned q, or before that last step). ``far``: (step, patient (m,)
    bool): from that step on, a candidate not patient whose error is above 1e-6 and not below
    half the previous step's stops (a spurious candidate with no root near, which would take
    every step to G6_NEWTON_MAX, each step costing the whole batch's overhead, and then be
    dropped: the C kernels' rule G6_NEWTON_FAR, with more patience, :data:`NEWTON_FAR`);
    patient: the candidates of a pose already flagged degenerate, whose singular roots Newton
    approaches linearly. None: every step for every candidate."""
    q = q.copy()
    last = np.full(len(q), np.inf)
    last_jt = np.zeros((len(q), 6, 6))
    idx = np.arange(len(q))
    for k in range(G6_NEWTON_MAX + 1):
        if k == 0 and first is not None:
            err, jt = _err_jt(target, *first)
        else:
            err, jt = _err_jt(target[idx], *_frames_x(c, q[idx]))
        size = np.max(np.abs(err), axis=1)
        todo = size > G6_NEWTON_STOP
        if far is not None and k >= far[0]:
            todo &= far[1][idx] | ~((size > 1e-6) & (size > 0.5 * last[idx]))
        last[idx] = size
        if with_error:
            last_jt[idx] = jt
        if not np.all(todo):
            idx, err, jt, size = idx[todo], err[todo], jt[todo], size[todo]
        if len(idx) == 0 or k == G6_NEWTON_MAX:
            break
        a = jt @ np.swapaxes(jt, 1, 2)
        lam = 1e-14 * (np.trace(a, axis1=1, axis2=2) + 1e-30)
        a += lam[:, None, None] * np.eye(6)
        dq_ = _solve_safe(a, np.einsum("mij,mj->mi", jt, err))
        big = np.max(np.abs(dq_), axis=1)
        dq_ = np.where(big[:, None] > 0.5, dq_ * (0.5 / np.maximum(big, 1e-300))[:, None], dq_)
        new = q[idx] + dq_
        q[idx] = np.where(np.isfinite(new), new, q[idx])
        # done: a small step that the linear model says leaves an error below 1e-13 (not so
        # at a singular Jacobian, where the damped step misses part of the error)
        left = np.max(np.abs(err - np.einsum("mji,mj->mi", jt, dq_)), axis=1) + big ** 2
        done = (big < NEWTON_DONE) & (size < NEWTON_DONE) & (left < G6_NEWTON_STOP)
        last[idx[done]] = left[done]
        idx = idx[~done]
        if len(idx) == 0:
            break
    return (q, last, np.swapaxes(last_jt, 1, 2)) if with_error else q


def _right_matrix(b):
    """R (8, 8) with a b = a @ R for dual quaternions a (rows) and the constant b (8,)."""
    eye = np.eye(8)
    return np.array([dq._mul(e, b) for e in eye])


def _fk_form(robot):
    """derive's dual-quaternion FK (:func:`derive.kinematics.fk.fk`: each joint's ``pre``
    factors, its rotation cos(t/2) + sin(t/2) n, its ``post`` factors, then the end's) with the
    constant factors between two rotations multiplied once: (K_0 (8,) the constant before joint
    1, per joint the (8, 16) matrix [R(K) | R((0, n_i)) R(K)] (R(b): right multiplication by b,
    K the constant after the joint), the joints' variables, multipliers and offsets), or None
    for a chain that is not a plain serial one."""
    joints = robot.joints
    end = robot.ends[robot.default_end]
    if len(joints) != 6 or any(j.type != "revolute" or j.parent != i - 1 for i, j in enumerate(joints)) \
            or end.parent != 5:
        return None
    ident = np.array([1.0, 0, 0, 0, 0, 0, 0, 0])

    def product(ops):
        out = ident
        for op in ops:
            out = dq._mul(out, dq._rotation(op.axis, op.angle) if op.kind == "R" else dq._translation_dq(op.vector))
        return out

    consts = [product(joints[0].pre)] + [dq._mul(product(joints[i - 1].post), product(joints[i].pre))
                                         for i in range(1, 6)] + [dq._mul(product(joints[5].post), product(end.ops))]
    mats = []
    for i, j in enumerate(joints):
        kr = _right_matrix(consts[i + 1])
        nr = _right_matrix(np.concatenate([[0.0], np.asarray(j.axis, float), np.zeros(4)]))
        mats.append(np.concatenate([kr, nr @ kr], 1))
    return (consts[0], np.array(mats), np.array([j.variable for j in joints]),
            np.array([j.multiplier for j in joints]), np.array([j.mimic_offset + j.offset for j in joints]))


def _fk_exact(robot, q):
    """Unit dual quaternions (m, 8) of the end frame at q (m, 6), up to sign: derive's
    dual-quaternion product (:func:`_fk_form`; equal to :func:`derive.kinematics.fk.fk` to
    rounding) as one (m, 8) x (8, 16) product per joint: A Rot_i K = cos(t/2) A K +
    sin(t/2) A N_i K (Rot_i = cos(t/2) + sin(t/2) (0, n_i), K the constants that follow)."""
    form = memo("general6r-fk", robot.id, lambda: _fk_form(robot))
    if form is None:
        return fk(robot, q)
    k0, mats, var, mult, off = form
    half = 0.5 * (mult * q[:, var] + off)
    ch, sh = np.cos(half), np.sin(half)
    a = np.broadcast_to(k0, (len(q), 8))
    for i in range(6):
        both = _mm(a, mats[i])
        a = ch[:, i, None] * both[:, :8] + sh[:, i, None] * both[:, 8:]
    return a


def _mm(a, b):
    """a (N, k) @ b (k, l) in row blocks small enough that OpenBLAS keeps each on the calling
    thread (see :data:`_MM_COLS`)."""
    rows = max(1, 250000 // (b.shape[0] * b.shape[1]))
    if a.shape[0] <= rows:
        return a @ b
    out = np.empty((a.shape[0], b.shape[1]))
    for s in range(0, a.shape[0], rows):
        np.matmul(a[s:s + rows], b, out=out[s:s + rows])
    return out


def _collect(robot, pl, poses, ip, qc, n, degen, err=None, jac=None):
    """Check every candidate on derive's exact FK, merge duplicates, pad. ``err``: the
    product-form error Newton left (scaled lengths and rad); a candidate whose error is surely
    past G6_ACCEPT (1e-9 in metres and rad, 10 times the acceptance) is dropped before the exact
    FK (the two FKs agree to rounding). ``jac``: the forward chain's Jacobians (m, 6, 6) at qc
    (Newton's last), else made here."""
    q = np.full((n, MAX_SOLUTIONS, 6), np.nan)
    counts = np.zeros(n, dtype=np.int64)
    sing = np.zeros((n, MAX_SOLUTIONS), dtype=bool)
    if err is not None:
        near = err <= 10 * G6_ACCEPT * max(1.0, 1.0 / pl.scale)
        ip, qc = ip[near], qc[near]
        jac = None if jac is None else jac[near]
    if len(ip) == 0:
        return q, counts, sing, degen
    dpos, drot = _pose_error(_fk_exact(robot, qc), poses[ip])
    ok = (dpos < G6_ACCEPT) & (drot < G6_ACCEPT) & np.all(np.isfinite(qc), axis=1)
    ip, qc = ip[ok], qc[ok]
    if len(ip) == 0:
        return q, counts, sing, degen
    # singular flag: the Jacobian's relative smallest singular value
    # sigma_min / sigma_max >= |det J| / |J|_F^6 (sigma_min >= |det J| / sigma_max^5 and
    # sigma_max <= |J|_F): where that bound already clears G6_SINGULAR the Jacobian is regular;
    # the others get the singular values (eigenvalues of J^T J). Newton's Jacobian can be the
    # one before its last step (below NEWTON_DONE): where its bound is within a factor 10 of
    # G6_NEAR_SINGULAR, the Jacobian at qc itself is made
    with np.errstate(all="ignore"):
        if jac is None:
            redo = np.ones(len(qc), dtype=bool)
            jac = np.empty((len(qc), 6, 6))
            bound = np.zeros(len(qc))
        else:
            jac = jac[ok]
            bound = np.abs(np.linalg.det(jac)) / np.sum(jac * jac, axis=(1, 2)) ** 3
            redo = ~(bound >= 10 * G6_NEAR_SINGULAR)
        if np.any(redo):
            zs, ps, x = _frames_x(pl.c, qc[redo])
            jr = np.swapaxes(_jt(zs, ps, x[3]), 1, 2)
            jac[redo] = jr
            bound[redo] = np.abs(np.linalg.det(jr)) / np.sum(jr * jr, axis=(1, 2)) ** 3
    is_sing = ~(bound >= G6_NEAR_SINGULAR)
    near_sing = is_sing.copy()
    if np.any(is_sing):
        ev = np.linalg.eigvalsh(np.swapaxes(jac[is_sing], 1, 2) @ jac[is_sing])   # ascending
        is_sing[is_sing] = ev[:, 0] < G6_SINGULAR ** 2 * ev[:, -1]
        near_sing[near_sing] = ev[:, 0] < G6_NEAR_SINGULAR ** 2 * ev[:, -1]
    # near the singular set (solutions merging: one of a merged pair can be lost): flagged
    degen[ip[near_sing]] = True
    order = np.lexsort((qc[:, 0], ip))
    ip, qc, is_sing = ip[order], qc[order], is_sing[order]
    # duplicates: an earlier candidate of the same pose within MERGE_TOL in every joint (the
    # pairs (j, j + d) of one pose, d = 1, 2, ...)
    # pairs (j, j + d) of one pose, d = 1, 2, ...; sorted by q1, only pairs whose q1 are within
    # MERGE_TOL can be close: d grows while some are, and the pairs across +-pi (the largest q1 of
    # a pose against its smallest) are compared on their own
    dup = np.zeros(len(ip), dtype=bool)
    q1 = qc[:, 0]
    for d in range(1, len(ip)):
        j = np.nonzero((ip[d:] == ip[:-d]) & (q1[d:] - q1[:-d] < MERGE_TOL))[0]
        if len(j) == 0:
            break
        close = np.all(np.abs(wrap_angle(qc[j + d] - qc[j])) < MERGE_TOL, axis=1)
        dup[j[close] + d] = True
    hi = np.nonzero(q1 > np.pi - MERGE_TOL)[0]
    lo = np.nonzero(q1 < -np.pi + MERGE_TOL)[0]
    for a in lo:
        for b in hi[ip[hi] == ip[a]]:
            if np.all(np.abs(wrap_angle(qc[b] - qc[a])) < MERGE_TOL):
                dup[b] = True
    ip, qc, is_sing = ip[~dup], qc[~dup], is_sing[~dup]
    starts = np.searchsorted(ip, ip)
    rank = np.arange(len(ip)) - starts
    over = rank >= MAX_SOLUTIONS
    degen[ip[over]] = True
    ip, qc, is_sing, rank = ip[~over], qc[~over], is_sing[~over], rank[~over]
    q[ip, rank] = qc
    sing[ip, rank] = is_sing
    counts[:] = np.bincount(ip, minlength=n)
    return q, counts, sing, degen
