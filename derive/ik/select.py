"""Choosing among closed-form IK solutions: joint limits with every 2 pi winding, and the
solution nearest to a seed configuration.

Both work on batches of NaN-padded solutions (n, m, dof) with their counts, as the kernels
return them (:mod:`derive.codegen.loader`), and are plain numpy:

* :func:`within_limits`: every representation q + 2 pi k (k integer, per revolute joint) of
  each solution that lies inside the joint limits (closed intervals, 1e-12 rad of slack). A
  joint with limits +-2 pi has two values for almost every angle (three at exactly 0), so a UR
  pose has up to 8 x 2^6 solutions within its limits;
* :func:`sort_order`: the order of one pose's solutions by their distance to a configuration;
* :func:`nearest`: per pose, the solution inside the limits (windings included) whose largest
  single-joint move from the seed is smallest (then the smallest summed move; both compared in
  steps of 1e-9 (``MOVE_SCALE``), since a joint shared by several branches, often the one that
  moves most, has values that differ in their last bits; the first solution on a tie). The winding of
  each joint is chosen independently (the largest move is a maximum over joints), so no
  enumeration is needed. A joint without finite limits moves by the wrapped difference.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from derive.algebra.angles import wrap_angle
from derive.errors import InputError
from derive.ik.tolerances import LIMIT_SLACK

TWO_PI = 2.0 * np.pi
#: nearest compares moves as rint(move * MOVE_SCALE): in steps of 1e-9 (rad or m)
MOVE_SCALE = 1e9


def _limits(limits, dof):
    lim = np.asarray(limits, dtype=float).reshape(dof, 2)
    return lim[:, 0], lim[:, 1]


def _winding_values(q, lo, hi, revolute):
    """(..., dof, K) candidate values q + 2 pi k inside the limits (NaN elsewhere), K fixed."""
    finite = np.isfinite(lo) & np.isfinite(hi)
    width = np.where(finite, hi - lo, 0.0)
    kmax = int(np.max(np.ceil(width / TWO_PI))) + 1 if np.any(finite & revolute) else 0
    ks = np.arange(-kmax, kmax + 1, dtype=float)
    ks_j = np.where((finite & revolute)[:, None], ks[None, :], np.where(ks[None, :] == 0, 0.0, np.nan))
    vals = q[..., None] + TWO_PI * ks_j
    ok = (vals >= lo[:, None] - LIMIT_SLACK) & (vals <= hi[:, None] + LIMIT_SLACK)
    return np.where(ok, vals, np.nan)


#: The largest result :func:`within_limits` builds (solutions, branch ids and flags together,
#: bytes): 1 GiB, about 36 000 poses of a UR arm (8 solutions x 2^6 windings of joints limited to
#: +-2 pi: 512 rows of 6 joints, 29 184 bytes per pose). A larger call raises InputError.
MAX_RESULT_BYTES = 2 ** 30
#: Poses per chunk when counting and expanding windings (bounds the temporaries).
CHUNK = 4096


def row_bytes(dof: int) -> int:
    """Bytes of one solution row of a :func:`within_limits` result: the joints (float64), the
    branch id (int64) and the singular flag (bool)."""
    return 8 * dof + 8 + 1


def winding_counts(sols, counts, limits, revolute, chunk: int = CHUNK) -> np.ndarray:
    """(n,) the number of in-limit windings of the first ``counts[i]`` solutions of each pose (the
    counts :func:`within_limits` returns), computed in chunks without building them."""
    sols = np.asarray(sols, dtype=float)
    n, m, dof = sols.shape
    lo, hi = _limits(limits, dof)
    revolute = np.asarray(revolute, dtype=bool)
    out = np.zeros(n, dtype=np.int64)
    for s in range(0, n, chunk):
        e = min(n, s + chunk)
        per_joint = np.sum(~np.isnan(_winding_values(sols[s:e], lo, hi, revolute)), axis=-1)
        per_sol = np.prod(per_joint, axis=-1, dtype=np.int64)                # (c, m)
        valid = np.arange(m)[None, :] < np.asarray(counts[s:e])[:, None]
        out[s:e] = np.sum(np.where(valid, per_sol, 0), axis=-1)
    return out


def check_result_size(winding_count, dof: int, what: str = "within_limits") -> int:
    """The width (largest count) of a :func:`within_limits` result, or InputError when the
    result would be larger than :data:`MAX_RESULT_BYTES`."""
    cnt = np.asarray(winding_count)
    width = int(cnt.max()) if cnt.size else 0
    need = cnt.size * width * row_bytes(dof)
    if need > MAX_RESULT_BYTES:
        per_pose = width * row_bytes(dof)
        fits = max(1, MAX_RESULT_BYTES // max(per_pose, 1))
        raise InputError(
            f"{what}: {cnt.size} poses with up to {width} in-limit solutions each would need "
            f"{need / 2 ** 30:.1f} GiB ({per_pose} bytes per pose), more than the limit of "
            f"{MAX_RESULT_BYTES / 2 ** 30:g} GiB; call it on chunks of at most {fits} poses, or "
            "use nearest (one solution per pose)")
    return width


def within_limits(sols, counts, limits, revolute, branch=None, singular=None, chunk: int = 128,
                  expand=None):
    """(solutions (n, M, dof) NaN-padded, counts (n,), branch (n, M), singular (n, M)): every
    in-limit representation of every solution, in the order of the solutions and, per solution,
    of the windings (smallest values first). M is the largest count of the call. ``branch`` and
    ``singular`` (n, m) are carried along (-1 / False where not given).

    Memory: the counts come first (:func:`winding_counts`); a result larger than
    :data:`MAX_RESULT_BYTES` raises InputError before anything is built, and the result is
    written in place chunk by chunk, so the peak is the result plus one chunk. ``expand(q,
    counts, branch, singular)`` (the same four for one chunk, every in-limit winding) replaces the
    numpy expansion (the kernels' extension does it in C)."""
    sols = np.asarray(sols, dtype=float)
    n, m, dof = sols.shape
    lo, hi = _limits(limits, dof)
    revolute = np.asarray(revolute, dtype=bool)
    counts = np.asarray(counts)
    if branch is None:
        branch = np.full((n, m), -1)
    if singular is None:
        singular = np.zeros((n, m), dtype=bool)
    big = check_result_size(winding_counts(sols, counts, limits, revolute), dof)
    q = np.full((n, big, dof), np.nan)
    b = np.full((n, big), -1, dtype=np.int64)
    sg = np.zeros((n, big), dtype=bool)
    cnt = np.zeros(n, dtype=np.int64)
    if expand is not None:
        step = max(chunk, 1024)
        for s in range(0, n, step):
            e = min(n, s + step)
            cq, cc, cb, cg = expand(np.ascontiguousarray(sols[s:e]), counts[s:e], branch[s:e], singular[s:e])
            w = cq.shape[1]
            if w > q.shape[1]:              # not expected: the counts above agree with the expansion
                q = np.concatenate([q, np.full((n, w - q.shape[1], dof), np.nan)], axis=1)
                b = np.concatenate([b, np.full((n, w - b.shape[1]), -1, dtype=np.int64)], axis=1)
                sg = np.concatenate([sg, np.zeros((n, w - sg.shape[1]), dtype=bool)], axis=1)
            q[s:e, :w], b[s:e, :w], sg[s:e, :w], cnt[s:e] = cq, cb, np.asarray(cg, dtype=bool), cc
        return q, cnt, b, sg
    for s in range(0, n, chunk):
        e = min(n, s + chunk)
        vals = _winding_values(sols[s:e], lo, hi, revolute)          # (c, m, dof, K)
        for i in range(e - s):
            at = 0
            for k in range(int(counts[s + i])):
                opts = [v[~np.isnan(v)] for v in vals[i, k]]
                if any(len(o) == 0 for o in opts):
                    continue
                grid = np.stack([g.ravel() for g in np.meshgrid(*opts, indexing="ij")], axis=-1)
                q[s + i, at:at + len(grid)] = grid
                b[s + i, at:at + len(grid)] = branch[s + i, k]
                sg[s + i, at:at + len(grid)] = singular[s + i, k]
                at += len(grid)
            cnt[s + i] = at
    return q, cnt, b, sg


def sort_order(sols, ref, revolute, windings: bool) -> np.ndarray:
    """The order (stable) of one pose's solutions ``sols`` (k, dof) by their Euclidean distance
    to the configuration ``ref`` (dof,). Without ``windings`` every revolute joint's value stands
    for all its 2 pi windings (the closed form wraps to (-pi, pi]), so its difference to ``ref`` is
    wrapped first: a solution at -pi + e is next to a seed at pi - e. With ``windings`` (the rows
    of :func:`within_limits`, each a configuration the arm can take) the plain difference is the
    joint's move."""
    diff = np.asarray(sols, dtype=float) - np.asarray(ref, dtype=float)
    if not windings:
        diff = np.where(np.asarray(revolute, dtype=bool), wrap_angle(diff), diff)
    return np.argsort(np.linalg.norm(diff, axis=1), kind="stable")


def nearest_windings(sols, seeds, lo, hi) -> np.ndarray:
    """The one nearest-winding rule (:func:`nearest`, :func:`derive.ik.redundant.nearest`; the C
    extension's nearest_winding does the same): per joint of ``sols`` (..., dof), of the values
    w = seed + wrap(q - seed) and w -+ 2 pi the one nearest to ``seeds`` (broadcast) inside
    [lo - LIMIT_SLACK, hi + LIMIT_SLACK]; NaN where none is inside (or q is NaN)."""
    w = seeds + wrap_angle(sols - seeds)
    cands = np.stack([w - TWO_PI, w, w + TWO_PI], axis=-1)
    inside = (cands >= lo[:, None] - LIMIT_SLACK) & (cands <= hi[:, None] + LIMIT_SLACK)
    d = np.where(inside, np.abs(cands - np.asarray(seeds)[..., None]), np.inf)
    pick = np.argmin(d, axis=-1)
    best = np.take_along_axis(cands, pick[..., None], axis=-1)[..., 0]
    return np.where(np.take_along_axis(inside, pick[..., None], axis=-1)[..., 0], best, np.nan)


def inside_limits(q, limits) -> np.ndarray:
    """(...,) bool: every joint of q (..., dof) has a winding q + 2 pi k inside its limits
    (LIMIT_SLACK); a joint without finite lower limit is taken as it is; NaN rows are False.
    (The test of one configuration; :func:`within_limits` expands the windings.)"""
    limits = np.asarray(limits, dtype=float)
    lo, hi = limits[:, 0], limits[:, 1]
    with np.errstate(invalid="ignore"):
        k = np.ceil((lo - LIMIT_SLACK - q) / TWO_PI)
        k = np.where(np.isfinite(lo), k, 0.0)
        qq = q + TWO_PI * k
        ok = (qq >= lo - LIMIT_SLACK) & (qq <= hi + LIMIT_SLACK)
    return np.all(ok, -1)


@dataclass(frozen=True)
class Nearest:
    """Per pose: ``q`` (n, dof) the chosen solution (NaN where none), ``found`` (n,) whether one
    was found (within ``tol`` of the seed when a tolerance was given), ``max_move`` and
    ``total_move`` (n,) its largest single-joint and summed moves from the seed (rad or m),
    ``branch`` (n,) the closed form's branch index (-1: none) and ``singular`` (n,)."""

    q: np.ndarray
    found: np.ndarray
    max_move: np.ndarray
    total_move: np.ndarray
    branch: np.ndarray
    singular: np.ndarray


def nearest(sols, counts, seeds, limits, revolute, branch=None, singular=None, tol=None) -> Nearest:
    """The solution nearest to each seed (module docstring); ``seeds`` (n, dof) or (dof,). In
    chunks of CHUNK poses (the temporaries are about 4 KB per pose)."""
    sols = np.asarray(sols, dtype=float)
    n, m, dof = sols.shape
    if n > CHUNK:
        seeds = np.broadcast_to(np.asarray(seeds, dtype=float), (n, dof))
        cut = [slice(s, min(n, s + CHUNK)) for s in range(0, n, CHUNK)]
        parts = [nearest(sols[c], np.asarray(counts)[c], seeds[c], limits, revolute,
                         None if branch is None else np.asarray(branch)[c],
                         None if singular is None else np.asarray(singular)[c], tol) for c in cut]
        return Nearest(*(np.concatenate([getattr(p, f) for p in parts])
                         for f in ("q", "found", "max_move", "total_move", "branch", "singular")))
    lo, hi = _limits(limits, dof)
    revolute = np.asarray(revolute, dtype=bool)
    seeds = np.broadcast_to(np.asarray(seeds, dtype=float), (n, dof))
    best = nearest_windings(sols, seeds[:, None, :], lo, hi)
    plain = np.where((sols >= lo - LIMIT_SLACK) & (sols <= hi + LIMIT_SLACK), sols, np.nan)
    best = np.where(revolute[None, None, :], best, plain)
    move = np.abs(best - seeds[:, None, :])
    valid = (np.arange(m)[None, :] < np.asarray(counts)[:, None]) & np.all(np.isfinite(best), axis=-1)
    mx = np.where(valid, np.max(np.where(np.isnan(move), np.inf, move), axis=-1), np.inf)
    tot = np.where(valid, np.sum(np.where(np.isnan(move), np.inf, move), axis=-1), np.inf)
    # moves compared in steps of 1e-9 (the same joint value reached by two branches differs in its
    # last bits), as rint(move * 1e9) like the C kernels' pass; lexsort is stable: on a tie the
    # first solution, as there
    order = (np.lexsort((np.rint(tot * MOVE_SCALE), np.rint(mx * MOVE_SCALE)), axis=-1)[:, 0] if m
             else np.zeros(n, dtype=int))
    idx = np.arange(n)
    q = best[idx, order] if m else np.full((n, dof), np.nan)
    found = np.isfinite(mx[idx, order]) if m else np.zeros(n, dtype=bool)
    if tol is not None:
        found &= mx[idx, order] <= tol
    q = np.where(found[:, None], q, np.nan)
    br = np.full(n, -1) if branch is None else np.where(found, np.asarray(branch)[idx, order], -1)
    sg = np.zeros(n, dtype=bool) if singular is None else found & np.asarray(singular)[idx, order]
    return Nearest(q=q, found=found, max_move=np.where(found, mx[idx, order], np.nan),
                   total_move=np.where(found, tot[idx, order], np.nan), branch=br, singular=sg)
