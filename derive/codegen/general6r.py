"""Emitted kernels of the general 6R arm (issue 31, item 2): the elimination of
:mod:`derive.ik.general6r` (Raghavan-Roth's 14 equations, Manocha-Canny's 24 x 24 companion
eigenproblem) as dependency-free C99 with the robot's constants baked in.

What the emitted code does per pose (templates/general6r.c.j2; the numbers refer to the steps
of :func:`derive.ik.general6r._solve_chunk` and ``_solve_chunk_cut``, which it follows):

1. **Coefficients** (``g6_coefs(pose, params, Q, ycol)``, a function of its own so that a caller
   with extra runtime parameters can replace it): Q (14 x 8), the coefficients of the pair of
   joints eliminated linearly, and ycol (14), the pose's part of the constant column of the
   triple's side Y (14 x 27, the rest of Y is a baked constant). For the standard elimination
   (joints 1, 2 eliminated, the triple 3, 4, 5) these are the derived polynomials of degree <= 3
   in (l, p), the direction and a point of joint 6's axis, evaluated as sums of the pose
   monomials times their nonzero baked coefficients (``_sparse_sum``); for the loop cut at joint e (the CRX, the Jaco2) the pair's coefficients are
   fitted per pose from 3 sample angles per joint (the fit's 9 x 9 inverse baked in).
2. **Left null space of Q** by a Householder QR of the 14 x 8 matrix (the last 6 columns of the
   complete Q); its first 8 columns and R give q1, q2 (or the pair) by least squares later. The
   reflectors are applied to Y directly (Q^T Y; the complete Q is not formed).
3. **The 12 x 12 quadratic pencil** M(x) = M0 + x M1 + x^2 M2 (x the half-angle tangent of the
   eigen-variable moved by an offset d3, the Moebius substitution: the first of three offsets
   whose leading matrix has a 1-norm condition below G6_GOOD_COND, else the best), and the
   24 x 24 companion matrix C = [[0, I], [-M2^-1 M0, -M2^-1 M1]] (M2^-1 [M0 M1] and M2^-1, for
   the condition, by one Gauss-Jordan elimination with partial pivoting of [M2 | M0 M1 | I], run on
   [M2 | M0 M1] with M2^-1 built in the columns of M2 it clears). Its eigenvectors every pose
   shares (x = +-i and a cut's constant real roots: the plan's deflation,
   :func:`derive.ik.general6r._deflation`) are deflated as the reference does
   (:func:`derive.ik.general6r._eigvals`): with the baked orthonormal basis [W V]
   (:func:`_deflation_context`) the roots are the eigenvalues of W^T C W (16 x 16), where the
   dropped block W^T C V is zero to DEFLATE_LEAK; the whole 24 x 24 elsewhere.
4. **Eigenvalues** by balancing, reduction to upper Hessenberg form by stabilised elementary
   similarity transformations and Francis's double-shift QR iteration (Wilkinson and Reinsch,
   *Handbook for Automatic Computation II*, 1971: balance, elmhes, hqr; Golub and Van Loan,
   *Matrix Computations*, 4th ed., algorithms 7.4.2 and 7.5.1). A pose whose QR iteration does not
   converge in 30 sweeps per eigenvalue is flagged degenerate.
5. **Eigenvectors**: for each (nearly) real eigenvalue x the null vector of M(x) (the monomials
   x4^i x5^j) from M's block structure (M(x) = [[S, 0], [0, S]], S 6 x 9 shifted by three
   columns: S's null space N = [-F; I] from its reduced row echelon form [I F] by Gauss-Jordan
   elimination with column pivoting (the pivots of an LU with partial pivoting of S^T), then one
   step of inverse iteration on the 6 x 6 [N[3:9], -N[0:6]], solved the same way); where its residual |M(x) v| is above 1e-6, one step of
   inverse iteration on the whole M(x) (an LU solve with partial pivoting of M(x) + 1e-11 I),
   or, where that residual is large too, the last column of the Q of a Householder QR with
   column pivoting of M(x)^T. Eigenvalues shared by several solutions (a
   cluster within CLUSTER_TOL, as the CRX's pairs with the same q3) take the null space of that
   QR (its dimension from the small pivots) and separate the members by the shift structure of
   the monomials (Stetter's method: V[shift] c = x V[base] c), a small eigenproblem solved by the
   same Hessenberg QR.
6. **Back-substitution**: the triple's joints from x and the vector's ratios, the pair from the
   least squares of Q X2 = Y X1, the last joint from the rotations of the rest of the chain
   (two columns of the part before it, one row of the part after it).
7. **Newton polish** on the product-form FK (damped Gauss-Newton with the geometric Jacobian, at
   most G6_NEWTON_MAX steps), the **check** on the kernels' own dual-quaternion FK (position and
   rotation angle within G6_ACCEPT), the **singular** flag (Jacobian's smallest over largest
   singular value below G6_SINGULAR: clear where Newton's last |det J| / |J|_F^6 is above 100
   times that, else the last over the first pivot of a pivoted QR of J), the
   **merge** of duplicates (MERGE_TOL in every joint) and the **order** (ascending q1), at most
   16 solutions. Every value is tested with isfinite; no NaN leaves a kernel but the padding.
8. **Nearby poses** (:func:`derive.ik.general6r._perturbed`): a pose flagged degenerate by the
   steps above is solved again at G6_PERTURB_TRIALS nearby poses (the reference's fixed twists
   ``_TWISTS`` times G6_PERTURB, baked in as a quaternion and a translation each); Newton (every
   step) carries their candidates back onto the pose, they are checked and merged with the
   pose's own; the flag stays set where every nearby pose is degenerate too or a solution found
   is singular.

The rank-deficient Q of a general arm (rank < 8, ``Plan.mix``) is not emitted: DeriveError.
"""

from __future__ import annotations

import ctypes

import numpy as np

from derive.errors import DeriveError
from derive.ik import general6r as g6
from derive.algebra import quaternion as quat
from derive.ik.tolerances import (G6_ACCEPT, G6_GOOD_COND, G6_LEADING_COND, G6_NEWTON_MAX, G6_PERTURB,
                                  G6_PERTURB_TRIALS, G6_RANK_TOL, G6_REAL_TOL, G6_SINGULAR, MERGE_TOL)
from derive.ik.tolerances import G6_NEAR_SINGULAR

#: The solutions a general 6R kernel returns at most (the degree of the eliminant).
MAX_SOLUTIONS = g6.MAX_SOLUTIONS


def _lit(x) -> str:
    x = float(x)
    if not np.isfinite(x):
        raise DeriveError(f"general 6R kernels: a constant is not finite ({x})")
    return repr(x) if x != 0 else "0.0"


def _arr(a) -> str:
    """A C initialiser of a numeric array (nested braces)."""
    a = np.asarray(a, dtype=float)
    if a.ndim == 1:
        return "{" + ", ".join(_lit(v) for v in a) + "}"
    return "{" + ", ".join(_arr(r) for r in a) + "}"


def _mul_by_link(c) -> list:
    """The twelve C expressions of a rigid transform's rows 0-2 times the constant link c (4 x 4,
    last row 0 0 0 1), in terms of the variable ``a[0..11]``: g6_mul4's sums in its order
    (a[4r] c[0][j] + a[4r + 1] c[1][j] + a[4r + 2] c[2][j], then + a[4r + 3] in column 3), the
    terms of exact zeros left out and the factors +-1 applied as signs. The results are g6_mul4's
    to the bit (a zero term adds nothing; a product with +-1 is exact) but for the sign of a zero."""
    c = np.asarray(c, dtype=float).reshape(4, 4)
    out = []
    for r in range(3):
        for j in range(4):
            terms = []
            for k in range(3):
                v = c[k, j]
                if v == 0.0:
                    continue
                x = f"a[{4 * r + k}]"
                sign = "-" if v < 0 else "+"
                terms.append((sign, x if abs(v) == 1.0 else f"{x} * {_lit(abs(v))}"))
            if j == 3:
                terms.append(("+", f"a[{4 * r + 3}]"))
            if not terms:
                out.append("0.0")
                continue
            e = ("-" if terms[0][0] == "-" else "") + terms[0][1]
            for sg, t in terms[1:]:
                e += f" {sg} {t}"
            out.append(e)
    return out


def general_context(robot) -> dict:
    """The template context of a general 6R robot's IK (``ik.general``): the plan's constants
    as C initialisers (:func:`derive.ik.general6r.plan`: the derivation, cached, with progress).
    DeriveError when the arm has no plan or one the emitted kernels do not cover."""
    pl = g6.plan(robot)
    if not g6.kernels_cover(pl.rank_q):
        raise DeriveError(f"{pl.robot}: Q has generic rank {pl.rank_q} < 8; the emitted general 6R "
                          "kernels cover rank 8 (use derive.ik.general6r.solve)")
    cut = pl.cut
    if cut:
        e = int(cut["e"])
        ev = int(cut["ev"])
        triple, pair = g6._cut_joints(e)
        chain = pl.c
        y = np.array(cut["y"])                               # (14, 27)
        last = e
        kinv = np.linalg.inv(np.kron(g6._BS, g6._BS))        # (9 samples) -> (9 coefficients)
        links = g6._links(chain)
        mode = {"kind": "cut", "e": e, "pair_links": [], "kinv": _arr(kinv),
                "samples": [_lit(v) for v in g6._SAMPLES]}
        # the pair's two links: K_j = C_{j+1} (constant) or the pose link K6 = C7 T^-1 C1
        for j in pair:
            mode["pair_links"].append({"joint": j, "pose": j == 6,
                                       "k": _arr(np.ravel(links[j])) if j != 6 else None})
        monomials, qk, r0 = [], None, None
    else:
        ev = 0
        triple, pair, last = (3, 4, 5), (1, 2), 6
        chain = g6._reverse(pl.c) if pl.reverse else pl.c
        el = pl.elim
        y = el.pl.reshape(14, 27)
        monomials = [list(m) for m in el.monomials]
        qk = el.q.reshape(112, -1)                            # (112, K)
        r0 = el.r0                                           # (14, K)
        mode = {"kind": "std", "qk": _arr(qk), "r0": _arr(r0), "k": len(monomials),
                "monomials": monomials, "c7inv": _arr(np.ravel(g6._inv(chain[6])))}
    order = [ev] + [i for i in range(3) if i != ev]
    # perm[new 9 i + 3 j + k] = old index: the eigen joint first, then the vector's two
    perm = []
    for a in range(3):
        for b in range(3):
            for c in range(3):
                old = [0, 0, 0]
                old[order[0]], old[order[1]], old[order[2]] = a, b, c
                perm.append(9 * old[0] + 3 * old[1] + old[2])
    halves = [g6._half(d) for d in pl.d3]
    # the nearby poses of a degenerate pose (derive.ik.general6r._perturbed): the pose's rotation
    # times the quaternion of the twist's rotation (body frame), its translation plus the twist's
    # translation times the arm's size (m)
    tw = np.array([g6._TWISTS[k % len(g6._TWISTS)] * G6_PERTURB for k in range(G6_PERTURB_TRIALS)]).reshape(-1, 6)
    ang = np.linalg.norm(tw[:, :3], axis=1)
    pq = quat._from_axis_angle(tw[:, :3] / np.maximum(ang, 1e-300)[:, None], ang)
    pt = tw[:, 3:] * pl.scale
    start = g6._START
    return {
        "mode": mode, "reverse": bool(pl.reverse) and not cut, "scale": _lit(pl.scale),
        "chain": _arr(np.reshape(chain, (7, 16))),
        "chain_mul": [_mul_by_link(np.reshape(chain, (7, 16))[i]) for i in range(7)], "fchain": _arr(np.reshape(pl.c, (7, 16))), "y": _arr(y), "perm": perm, "order": order,
        "triple": [j - 1 for j in triple], "pair": [j - 1 for j in pair], "last": last - 1,
        "t45": _arr(g6._t45(pl.offsets[0], pl.offsets[1])), "d4": _lit(pl.offsets[0]),
        "d5": _lit(pl.offsets[1]), "d3": [_lit(d) for d in pl.d3], "halves": [_arr(h) for h in halves],
        "n_d3": len(pl.d3), "start": _arr(start), "nudge": _lit(g6._NUDGE),
        "cluster_tol": _lit(g6.CLUSTER_TOL), "accept": _lit(G6_ACCEPT), "real_tol": _lit(G6_REAL_TOL),
        "newton_max": int(G6_NEWTON_MAX), "singular": _lit(G6_SINGULAR), "good_cond": _lit(G6_GOOD_COND),
        "near_singular": _lit(G6_NEAR_SINGULAR), "near_pair_tol": _lit(g6.NEAR_PAIR_TOL),
        "leading_cond": _lit(G6_LEADING_COND), "rank_tol": _lit(G6_RANK_TOL), "merge_tol": _lit(MERGE_TOL),
        "max_solutions": MAX_SOLUTIONS, "n_perturb": int(G6_PERTURB_TRIALS),
        "tables": tables_context(pl),
        "perturb_q": _arr(pq.reshape(-1, 4)), "perturb_t": _arr(pt.reshape(-1, 3)), "notes": [g6_comment(n) for n in pl.notes],
        "defl": _deflation_context(pl),
        "how": ("the loop cut at joint %d (pair %s eliminated linearly, triple %s, eigen-variable q%d)"
                % (cut["e"], tuple(pair), tuple(triple), triple[ev]) if cut else
                "Raghavan-Roth elimination of the %s chain (q1, q2 eliminated linearly, eigen-variable %s)"
                % ("reversed" if pl.reverse else "forward", "q4 of the reversed chain" if pl.reverse else "q3")),
    }


def _deflation_context(pl) -> dict:
    """The deflation of the plan (:func:`derive.ik.general6r._deflation`) as baked constants,
    the context's key ``defl``: the pencil's pose-independent eigenvectors (x = +-i, and a cut's
    constant spurious real roots) removed before the eigenvalues are taken, so that each pose
    solves ``keep`` x ``keep`` (16 x 16 for a general arm) instead of 24 x 24.

    Per offset k of the eigen-variable (``d3[k]``), the orthonormal basis B_k = [W V] (24 x 24,
    W its first ``keep`` columns, V spanning the removed eigenvectors). With the companion matrix
    C = [[0, I], L] (L = -M2^-1 [M0 M1], 12 x 24) and B = [B1; B2] (rows 1-12, 13-24),
    W^T C B = W1^T B2 + W2^T (L B): its first ``keep`` columns are the deflated block whose
    eigenvalues are C's others, its last 24 - keep (``leak``) are zero to rounding where the
    deflation holds (else that pose takes the whole 24 x 24). Keys: ``on`` (whether the plan has
    a deflation), ``keep``, ``b`` (n_d3, 24, 24), ``w1tb2`` (n_d3, keep, 24) = W1^T B2,
    ``w2t`` (n_d3, keep, 12) = W2^T, ``n`` = 24 - keep (the removed dimension), ``leak_tol``
    (DEFLATE_LEAK: the largest |W^T C V| allowed, relative to max(1, L's largest entry)),
    for the C kernel ``bc`` (n_d3, 24, width) = [W, V R] and ``w1tb2c`` (n_d3, keep, width) =
    W1^T [W2, V2 R] with R = :func:`_leak_mix` (the leak on fixed combinations of V's columns;
    width = keep + R's columns),
    ``spurious`` (the removed real roots, rad). Arrays as nested C initialisers (the numpy
    template turns the braces into lists)."""
    if pl.deflate is None:
        return {"on": False, "keep": 24, "leak_tol": _lit(g6.DEFLATE_LEAK), "spurious": []}
    keep = int(pl.deflate_keep)
    b = np.asarray(pl.deflate)                                  # (n_d3, 24, 24)
    w1tb2 = np.einsum("kai,kaj->kij", b[:, :12, :keep], b[:, 12:, :])   # W1^T B2
    w2t = np.swapaxes(b[:, 12:, :keep], 1, 2)                   # W2^T
    mix = _leak_mix(24 - keep)
    bc = np.concatenate([b[:, :, :keep], b[:, :, keep:] @ mix], axis=2)
    w1tb2c = np.concatenate([w1tb2[:, :, :keep], w1tb2[:, :, keep:] @ mix], axis=2)
    return {"on": True, "keep": keep, "n": 24 - keep, "b": _arr(b), "w1tb2": _arr(w1tb2),
            "w2t": _arr(w2t), "leak_tol": _lit(g6.DEFLATE_LEAK),
            "width": keep + mix.shape[1], "bc": _arr(bc), "w1tb2c": _arr(w1tb2c),
            "spurious": [_lit(v) for v in pl.spurious]}


#: the C kernel's leak check: at most this many fixed combinations of V's columns
LEAK_MIX = 4


def _leak_mix(n: int) -> np.ndarray:
    """The fixed combinations (n x m, unit columns) of the n removed columns V on which the C
    kernel checks the deflation's leak W^T C V: the identity where n <= LEAK_MIX, else LEAK_MIX
    columns of a fixed generic matrix (sines at incommensurate angles: every entry nonzero, each
    row at least about 0.2 in some column for n <= 12). The C computes W^T C [W, V R] (keep + m
    columns, not 24: the products per pose a sixth smaller for a general arm) and takes the
    leak as the largest |W^T C V R|. Where the deflation holds W^T C V is zero to rounding and so
    is every combination; where it fails, a nonzero row x of W^T C V has x R = 0 only if x lies
    in the (n - m)-dimensional orthogonal complement of R's fixed columns, which a failure does
    not pick. Measured on the 20674 deflation checks of 2000 random and 1583 axis-aligned or
    near-singular poses of each of the CRX, xArm6, Jaco2 and general-6r (nearby poses included):
    with R's columns of unit length the largest |W^T C V R| is 0.22 to 1.1 times the largest
    |W^T C V|, and every deflation held with a leak below 4e-5 of the tolerance, so the
    decision (deflated or the whole 24 x 24) is the same on each."""
    if n <= LEAK_MIX:
        return np.eye(n)
    j = np.arange(n)[:, None] + 1.0
    c = np.arange(LEAK_MIX)[None, :] + 1.0
    r = np.sin(2.399963229728653 * j * c + 1.7 * c)
    return r / np.linalg.norm(r, axis=0)


def g6_comment(text: str) -> str:
    return " ".join(str(text).split()).replace("*/", "* /")


def tables_context(pl) -> dict | None:
    """The standard elimination's pose terms for the C kernels (None for a loop cut): Q's 112
    entries and the 14 pose terms are sums of coefficients times the K pose monomials; the C
    expressions the kernel emits for them, ``q_sums`` (112) and ``r0_sums`` (14), are each
    entry's sum over its nonzero coefficients only (:func:`_sparse_sum`; 85 % of xarm6's
    coefficients are exact zeros)."""
    if pl.cut:
        return None
    el = pl.elim
    qk = el.q.reshape(112, -1)
    r0 = np.asarray(el.r0)
    return {"q_sums": [_sparse_sum(row) for row in qk], "r0_sums": [_sparse_sum(row) for row in r0]}


def _sparse_sum(coefs) -> str:
    """The C expression of sum_k coefs[k] mono[k] with its terms of exact zeros left out, in the
    order of k from 0.0: the loop ``s = 0.0; s += c[k] * mono[k]`` to the bit (a zero coefficient
    times a finite monomial adds a zero, which leaves a sum that starts at +0.0 as it is)."""
    out = "0.0"
    for k, c in enumerate(np.asarray(coefs, dtype=float)):
        if c != 0.0:
            out += f" {'-' if c < 0 else '+'} {_lit(abs(c))} * mono[{k}]"
    return out


def c_ik_general(kernels, poses) -> tuple:
    """The C kernels' whole answer for poses (n, 8) through ctypes, ``<id>_ik_batch_general`` of
    templates/general6r.c.j2: (solutions (n, 16, 6) NaN-padded, counts (n,), singular flags
    (n, 16), degenerate flags (n,)), as the numpy kernels' ``ik_general`` gives them (``k.ik``
    gives no degenerate flag). ``kernels``: ``derive.kernels(robot, "c")`` of a general 6R arm."""
    kernels._load_ctypes()
    f = getattr(kernels._lib, f"{kernels._ident}_ik_batch_general")
    p = np.ascontiguousarray(poses, dtype=np.float64)
    n = len(p)
    sols, counts = np.zeros((n, 16, 6)), np.zeros(n, np.intc)
    sing, degen = np.zeros((n, 16), np.intc), np.zeros(n, np.intc)
    dp, ip = ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_int)
    f(ctypes.c_size_t(n), p.ctypes.data_as(dp), sols.ctypes.data_as(dp), counts.ctypes.data_as(ip),
      sing.ctypes.data_as(ip), degen.ctypes.data_as(ip))
    return sols, counts.astype(np.int64), sing.astype(bool), degen.astype(bool)
