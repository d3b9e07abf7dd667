"""``derive.kernels(robot, backend, free="qK")``: a seven-joint arm's IK with any joint K given.

The solver is :mod:`derive.ik.free_joint` (the class's closed form where holding joint K leaves
one, else the general 6R with a numeric per-value construction of the elimination). The "python"
and "numpy" backends run that numpy solver for ``ik``, ``ik_sweep`` and ``nearest``, and the
backend's generated kernels for ``fk`` (and every other kernel: ``with_tool``, ``jacobian``, ...).
The "c" backend runs emitted C99. On the SRS class routes (q1, q2, q5, q6 or q7 given,
:func:`derive.ik.free_joint.route`) it is the class's IK program
(:func:`derive.ik.program7.srs_joint_program`, the numpy closed form as a composition of
subproblems) printed by the generated kernels' template (:func:`program_source`): the same
solution sets, branch ids and singular flags as the numpy closed form. On the general route it is
the general elimination, wherever it has a plan (:func:`derive.ik.free_joint.plan`)
(templates/free_joint.c.j2, :func:`c_source`): per pose and value the loop-cut coefficients of
both sides fitted from 27 + 9 sample angles, then the general 6R solver core of
templates/general6r.c.j2 in its runtime mode, the locked chain and those coefficients passed
through its pose argument (one copy per plan: the plan and its rescue, :func:`c_plans`: where a cut
with the held link off the triple side has a deflation that holds for every value, that cut and
the reference's plan as its rescue), the check on the 7R's FK, merge and the singular flag,
as :func:`derive.ik.free_joint._general` does; compiled on first use into the user cache's build
folder and loaded with ctypes. Where the general elimination has no plan the "c" backend has no such
IK kernel (the plan's DeriveError). The calling convention is that
of :class:`derive.codegen.loader.Kernels` with the 7R ``free=`` argument: ``ik(P, free=values)``
-> (solutions (n, 16, 7) NaN-padded, counts (n,)), ``ik_sweep(P, n)`` over joint K's range,
``nearest(P, q_seed)`` with joint K chosen for the path.
"""

from __future__ import annotations

import ctypes
import dataclasses
import math
import re

import numpy as np

from derive._version import __version__
from derive.algebra import dualquat as dq
from derive.cache import memo
from derive.errors import DeriveError, InputError
from derive.ik import free_joint, general6r as g6, redundant, select
from derive.ik.tolerances import (G6_ACCEPT, G6_GOOD_COND, G6_LEADING_COND, G6_NEWTON_MAX, G6_RANK_TOL,
                                  G6_NEAR_SINGULAR, G6_REAL_TOL, G6_SINGULAR, MERGE_TOL)
from derive.kinematics.pose import as_pose_batch

#: Solutions per pose and value at most (a 6R has at most 16).
MAX_SOLUTIONS = free_joint.MAX_SOLUTIONS


def _identifier(robot, joint: int) -> str:
    stem = robot.name.replace("-", "_").replace(".", "_")
    return (stem if stem[:1].isalpha() else "r_" + stem) + f"_free_q{joint}"


class _Context(dict):
    """A template context whose missing keys are None: the general 6R template's optional parts
    (a feature a newer template adds, named by a key this module does not set) stay off."""

    def __missing__(self, key):
        return None


#: Held values at which a baked deflation is checked (:func:`_fixed_deflation`).
_DEFLATION_VALUES = (0.0, -2.6, -1.1, 0.4, 1.9, 2.8)


def _held_on_pair_side(pl: free_joint.Plan) -> bool:
    """Whether the held joint's merged link C_K Rz(v) C_{K+1} of the locked 6R (its link K - 1,
    7 - K in the reversed chain) lies outside the loop cut's triple side: the base or tool link
    (in the pose link K6 = C7 T^-1 C1) or a link of the pair side (links e + 4 and e + 5 mod 6,
    6 the pose link). The triple side Y is then the same for every value."""
    link = 7 - pl.joint if pl.reverse else pl.joint - 1
    return link in (0, 6) or link in {(pl.e + 3) % 6 + 1, (pl.e + 4) % 6 + 1}


def _fixed_deflation(pl: free_joint.Plan, any_side: bool = False):
    """:func:`derive.ik.general6r._deflation` of the locked 6R where it holds for every held
    value: the held link off the triple side (:func:`_held_on_pair_side`; there the pencil's
    pose-independent eigenvectors, at x = +-i and at complex roots every pose shares, need not
    change with the value, and on the arms shipped they do not), computed at each of
    :data:`_DEFLATION_VALUES`; the one that removes the fewest eigenvectors (the first such,
    the value 0 where it is one of them) where its removed subspace V lies in every other value's
    (some values add pose-independent roots of their own, left to the eigen-solver) with the same
    spurious real roots. (bases, keep, spurious) or None."""
    from types import SimpleNamespace

    if not any_side and not _held_on_pair_side(pl):
        return None
    found = []
    for v in _DEFLATION_VALUES:
        d = free_joint.locked_chain(pl.c, pl.joint, [v])[0]
        if pl.reverse:
            d = g6._reverse(d)
        f = g6._deflation(SimpleNamespace(c=d, cut={"e": pl.e, "ev": pl.ev, "y": g6._triple_coefs(d, pl.e)},
                                          offsets=pl.offsets, d3=pl.d3))
        if f is None:
            return None
        found.append(f)
    best = max(found, key=lambda f: f[1])
    keep, spurious = best[1], np.asarray(best[2], dtype=float)
    for f in found:
        if f[1] == keep and (len(f[2]) != len(spurious)
                             or np.abs(np.asarray(f[2], dtype=float) - spurious).max(initial=0.0) > 1e-9):
            return None
        for k in range(len(pl.d3)):
            # V (this value's removed subspace) has no component off the other value's
            v0, vk = best[0][k][:, keep:], f[0][k][:, f[1]:]
            if np.abs(v0 - vk @ (vk.T @ v0)).max() > 1e-7:
                return None
    return best


def _pair_deflation(pl: free_joint.Plan):
    """The baked deflation of a plan with the held link off the triple side
    (:func:`_held_on_pair_side`): the one of :func:`_fixed_deflation` and :func:`_span_deflation`
    that removes more eigenvectors (the first where they tie). (bases, keep, spurious) or None.
    Once per process."""
    key = (pl.robot_id, pl.joint, pl.reverse, pl.e, pl.ev, tuple(np.round(pl.offsets, 12)))
    return memo("free-joint-pair-deflation", key, lambda: _pair_deflation_uncached(pl))


def _pair_deflation_uncached(pl: free_joint.Plan):
    fixed = _fixed_deflation(pl)
    span = _span_deflation(pl) if _held_on_pair_side(pl) else None
    if span is not None and (fixed is None or span[1] < fixed[1]):
        return span
    return fixed


def _span_deflation(pl: free_joint.Plan):
    """A deflation baked once for a plan with the held link off the triple side, from an
    invariant subspace of the companion matrix for the eigenvalues every pose shares, clusters
    taken as one eigenvalue: :func:`_shared_span` (the null space of (C - x I)^k, generalised
    eigenvectors too) or :func:`_constant_eigenvectors` (the eigenvectors every pose shares, where
    the generalised ones move with the pose). :func:`_fixed_deflation` matches the shared
    eigenvalues one by one within 1e-7; where a shared eigenvalue is multiple (x = +-i, or a
    pose-independent complex double or triple root that rounding splits by up to 1e-5: the Gen3's
    q6 with the reversed cut at joint 2) it misses some at most values (xarm7 q6: 18 x 18 left,
    gen3 q6 and panda q6: 20 x 20; with this 16, 16 and 14). The triple side Y does not depend on
    the value here, so neither does that subspace: of the spans at :data:`_DEFLATION_VALUES` (both
    kinds, invariant there within :data:`_TRIPLE_CHECK_LEAK`), the largest, then the least leak,
    that holds (:func:`_leak` at most :data:`_TRIPLE_CHECK_LEAK`) at every offset on
    :data:`_TRIPLE_CHECK_POSES` random poses at each of :data:`_DEFLATION_VALUES` and
    :data:`_TRIPLE_CHECK_VALUES` random values. Its real eigenvalues, if any, are the spurious
    real roots (in rad, at the offset d3[0]). (bases (n_d3, 24, 24) [W V], keep, spurious) or None."""
    rng = np.random.default_rng(41)
    options = []
    for v in _DEFLATION_VALUES:
        comp = _companions(pl, v, rng.uniform(-np.pi, np.pi, (4, 6)), pl.d3[0])
        if not np.all(np.isfinite(comp)):
            continue
        for b in (_shared_span(comp), _constant_eigenvectors(comp)):
            if b is not None and 2 <= b.shape[1] <= 12:
                leak = _leak(comp, b)
                if leak <= _TRIPLE_CHECK_LEAK:
                    options.append((-b.shape[1], leak, len(options), b, comp[0]))
    rots = [_offset_rotation(pl, k) for k in range(len(pl.d3))]
    checks = [(v, rng.uniform(-np.pi, np.pi, (_TRIPLE_CHECK_POSES, 6)))
              for v in np.concatenate([_DEFLATION_VALUES, rng.uniform(-np.pi, np.pi, _TRIPLE_CHECK_VALUES)])]
    for _, _, _, v0, c0 in sorted(options, key=lambda o: o[:3]):      # the most removed first, then the least leak
        if all(_leak(_companions(pl, v, q, d), rots[k] @ v0) <= _TRIPLE_CHECK_LEAK
               for v, q in checks for k, d in enumerate(pl.d3)):
            break
    else:
        return None
    best = (v0, None, c0)
    # the removed eigenvalues (of V^T C V), the real ones as angles of the eigen-variable
    lam = np.linalg.eigvals(v0.T @ best[2] @ v0)
    real = lam[np.abs(lam.imag) < G6_REAL_TOL * (1 + np.abs(lam) ** 2)].real
    spurious = tuple(sorted({round(float(g6.wrap_angle(pl.d3[0] + 2 * np.arctan(x))), 9) for x in real}))
    r = v0.shape[1]
    bases = []
    for k in range(len(pl.d3)):
        qv = np.linalg.qr(rots[k] @ v0, mode="complete")[0]
        bases.append(np.concatenate([qv[:, r:], qv[:, :r]], axis=1))
    return np.array(bases), 24 - r, spurious


def _shared_groups(comp, upper: bool = False, lams=None) -> list:
    """The eigenvalues of comp[0] that every other matrix of the stack (m, 24, 24) shares (each
    within 1e-6 (1 + |x|) of one of its eigenvalues), in clusters: an eigenvalue within
    1e-4 (1 + |x|) of a cluster's mean joins it. ``upper``: only those whose imaginary part is not
    below -1e-9 (1 + |x|) (one of each conjugate pair). ``lams``: the matrices' eigenvalues where
    the caller has them. Lists of eigenvalues, in comp[0]'s order."""
    if lams is None:
        lams = np.linalg.eigvals(comp)
    lam, others = lams[0], lams[1:]
    groups = []
    for x in lam:
        if upper and x.imag < -1e-9 * (1 + abs(x)):
            continue
        if not all(np.min(np.abs(r - x)) < 1e-6 * (1 + abs(x)) for r in others):
            continue
        for g in groups:
            if abs(np.mean(g) - x) < 1e-4 * (1 + abs(x)):
                g.append(x)
                break
        else:
            groups.append([x])
    return groups


def _constant_eigenvectors(comp):
    """The orthonormal basis (24, r) of the eigenvectors that the companion matrices comp
    (m, 24, 24) share, for the eigenvalues they all share (within 1e-6; a cluster within 1e-4 as one
    eigenvalue x, its mean): per x the null space of the stacked [C_1 - x I; ...; C_m - x I]
    (singular values below 1e-8 of the largest), real and imaginary parts; None where there is
    none. Unlike :func:`_shared_span` it keeps the eigenvectors every pose shares where the
    generalised ones move with the pose (a multiple x = +-i whose Jordan chains do: the Panda's q6)."""
    groups = _shared_groups(comp, upper=True)
    cols = []
    for g in groups:
        x = np.mean(g)
        a = np.concatenate([c - x * np.eye(24) for c in comp])
        _, s, vh = np.linalg.svd(a, full_matrices=False)
        k = int(np.sum(s < 1e-8 * s[0]))
        if k:
            cols.append(vh[-k:].conj().T)
    if not cols:
        return None
    v = np.concatenate(cols, 1)
    u, sv, _ = np.linalg.svd(np.concatenate([v.real, v.imag], 1), full_matrices=False)
    return u[:, :int(np.sum(sv > 1e-8 * sv[0]))]


def c_plans(robot, joint: int) -> list:
    """The plans of the C kernel, the plan first and its rescue second: the reference's
    (:func:`derive.ik.free_joint.plan` and its rescue), unless a cut with the held link off the
    triple side (:func:`_held_on_pair_side`: joint 1 or 7 held, any cut; joint 2 or 6, the forward or
    reversed locked 6R cut at its joint 2; never joints 3-5) removes more eigenvectors by a baked
    deflation (:func:`_pair_deflation`) than the reference's plan by the same measure
    (:func:`_pair_score`; at the same size a cut whose eigenvectors alone reach it first): that cut, where it works at every
    value of :data:`_DEFLATION_VALUES` (:func:`derive.ik.general6r._check_cut`), with the
    eigen-variable that check chose most often or another one regular there without shared real
    roots (:func:`_regular`), is then the C kernel's plan and the reference's plan its rescue
    (each pose solves a 14 x 14 to 20 x 20 eigenproblem instead of 24 x 24). With joint 3, 4 or 5
    held (the held link on the triple side of every cut) the cut and eigen-variable with the fewest
    poses sent to the rescue (:func:`_quiet_plan`), where it beats the reference's plan, with the
    reference's plan as its rescue (the rescue's share decides, but where only the reference's
    plan deflates and sends few poses more to the rescue it comes first, :func:`_deflating_first`); else, where
    the reference's plan has no deflation of its shared eigenvectors but its rescue plan has
    (:func:`_triple_deflates`), the two swap (:func:`_deflating_rescue`; also for joints 2 and 6
    when the reference's plan has the held link on the triple side and no pair-side cut
    deflates). On the general route only; once per process."""
    from derive.model.robot import load_robot
    robot = load_robot(robot)
    return memo("free-joint-c-plans", (robot.id, joint), lambda: _c_plans(robot, joint))


def _c_plans(robot, joint: int) -> list:
    from collections import Counter

    pl = free_joint.plan(robot, joint)
    plans = [pl, pl.alt if pl.alt is not None else pl]
    if free_joint.route(robot, joint) != "general":
        # a class route: the SRS routes' C is their IK program (program_source) and never comes
        # here; the Panda's q7 (reached only by calling the free-joint kernels directly, as the
        # benchmarks do) keeps the reference's plans
        return plans
    own = _pair_score(pl)
    if own is None and not any(_held_on_pair_side(dataclasses.replace(pl, reverse=r, e=e))
                               for r in (False, True) for e in (1, 2)):
        # the held link on the triple side of every cut (joints 3-5): no baked deflation; the cut
        # and eigen-variable with the fewest poses sent to the rescue (_fewest_suspects), else the
        # reference's plans, swapped where only its rescue plan deflates
        quiet = _quiet_plan(pl, robot)
        if quiet is not None:
            return _deflating_first(pl, quiet, robot)
        return _deflating_rescue(pl) or plans
    # the bar: the reference's plan by the candidates' measure (_pair_score: the size after
    # _pair_deflation, as the C kernel deflates it, and whether only _span_deflation reaches it;
    # 24 where it has none, the held link on its triple side): at the same size a cut whose
    # eigenvectors alone reach it first (on the Gen3's q1, q2 and q7 the cuts that reach 16 only
    # with _span_deflation run 15 % slower: multiple eigenvalues stay in the block)
    best, best_keep = None, (24, 0) if own is None else own
    for reverse in (False, True):
        for e in (1, 2):
            if not _held_on_pair_side(dataclasses.replace(pl, reverse=reverse, e=e)):
                continue
            evs = []
            for v in _DEFLATION_VALUES:
                d = free_joint.locked_chain(pl.c, joint, [v])[0]
                ok, _, extra = g6._check_cut(g6._reverse(d) if reverse else d, e)
                if not ok:
                    break
                evs.append(int(extra["ev"]))
            else:
                # the eigen-variable chosen most often first, then the others whose pencil is regular
                # at every value (a smaller deflated block wins)
                order = [ev for ev, _ in Counter(evs).most_common()]
                order += [ev for ev in range(3) if ev not in order and _regular(pl, reverse, e, ev)]
                for ev in order:
                    if (reverse, e, ev) == (pl.reverse, pl.e, pl.ev):
                        continue
                    cand = dataclasses.replace(
                        pl, reverse=reverse, e=e, ev=ev, alt=pl,
                        notes=f"{'reversed' if reverse else 'forward'} 6R, cut at its joint {e}, eigen-variable "
                              f"q{g6._cut_joints(e)[0][ev]} of the 6R (the held link off the triple side: the "
                              f"deflation baked; the reference's plan is the rescue)")
                    score = _pair_score(cand)
                    if score is not None and score < best_keep:
                        best, best_keep = cand, score
    if best is None and not _held_on_pair_side(pl):
        return _deflating_rescue(pl) or plans
    return plans if best is None else [best, pl]


def _pair_score(pl: free_joint.Plan):
    """(the size of the block :func:`_pair_deflation` leaves, 1 where only :func:`_span_deflation`
    reaches it else 0), the measure :func:`c_plans` ranks the plans of joints 1, 2, 6 and 7 by
    (smaller first); None where the plan has no such deflation (the held link on its triple side)."""
    found = _pair_deflation(pl)
    if found is None:
        return None
    fixed = _fixed_deflation(pl)
    return found[1], int(fixed is None or fixed[1] > found[1])


#: The share of the poses that :func:`_deflating_first` lets the reference's plan send to the
#: rescue beyond the quiet plan's: the rescue solves a 24 x 24 (or a deflated 16 x 16) again, about
#: 35 us, where deflating 24 x 24 to 16 x 16 saves about 9 us per pose
_DEFLATING_EXTRA_SUSPECTS = 0.15


def _deflating_first(pl: free_joint.Plan, quiet: free_joint.Plan, robot) -> list:
    """[quiet, pl] (:func:`_quiet_plan`'s choice, the reference's plan its rescue), unless the quiet
    plan has no deflation of its shared eigenvectors and the reference's plan has
    (:func:`_triple_deflates`) and sends at most :data:`_DEFLATING_EXTRA_SUSPECTS` of the poses more
    to the rescue (:func:`_suspects` on :func:`_fewest_suspects`' configurations): then
    [pl, quiet] (xArm7's q5: 25.7 against 34.8 us per pose, one rescued pose of 500 either way).
    The decision is kept in the user cache under "<identity>-free-q<K>-cplan-first-<tag>"
    (:func:`_choice_key`)."""
    import json
    from derive.cache import find_artifact, store_artifacts
    if _triple_deflates(quiet) or not _triple_deflates(pl):
        return [quiet, pl]
    key = _choice_key(robot, "cplan-first", pl, quiet, _SUSPECT_POSES, _DEFLATING_EXTRA_SUSPECTS)
    found = find_artifact(key, "c_plan_first")
    if found is not None:
        first = json.loads(found.read_text(encoding="utf-8"))["reference_first"]
    else:
        from derive.kinematics.fk import fk
        rng = np.random.default_rng(97 + pl.joint)          # _fewest_suspects' configurations
        q = rng.uniform(-np.pi, np.pi, (_SUSPECT_POSES, 7))
        poses, values = fk(robot, q), q[:, pl.joint - 1]
        zero = np.zeros(len(q), dtype=int)
        own = _suspects(pl, robot, poses, values, zero)[0]
        theirs = _suspects(quiet, robot, poses, values, zero)[0]
        first = bool(own - theirs <= _DEFLATING_EXTRA_SUSPECTS * len(q))
        store_artifacts(key, {"c_plan_first": ("c_plan_first.json", json.dumps({"reference_first": first}))},
                        {"robot": pl.robot, "free": f"q{pl.joint}"})
    if not first:
        return [quiet, pl]
    return [dataclasses.replace(pl, alt=dataclasses.replace(quiet, alt=None),
                                notes=pl.notes + " (its shared eigenvectors deflated per value; the plan with the "
                                "fewest poses sent to the rescue is the rescue)"), quiet]


def _deflating_rescue(pl: free_joint.Plan):
    """[the reference's rescue plan, the reference's plan] where the held link is on the triple
    side, the reference's plan has no deflation of its shared eigenvectors and its rescue plan
    has (:func:`_triple_deflates`: its span fits, the plan's does not), else None."""
    if pl.alt is None or _triple_deflates(pl) or not _triple_deflates(pl.alt):
        return None
    return [dataclasses.replace(pl.alt, alt=pl, notes=pl.alt.notes + " (its shared eigenvectors deflated per "
                                "value; the reference's plan is the rescue)"), pl]


def _triple_deflates(pl: free_joint.Plan) -> bool:
    """Whether a plan with the held link on the triple side has a deflation: baked
    (:func:`_triple_side_deflation`) or per value (:func:`value_basis`)."""
    return _triple_side_deflation(pl) is not None or value_basis(pl) is not None


#: Configurations (seeded, uniform in [-pi, pi]) on which :func:`_fewest_suspects` counts the
#: suspect poses of each cut and eigen-variable
_SUSPECT_POSES = 120


def _suspects(pl: free_joint.Plan, robot, poses, values, counts) -> tuple[int, float] | None:
    """(the poses on which the plan's candidates make :func:`derive.ik.free_joint._general` run its
    rescue: an odd count, none, the degenerate flag, two candidates merged, a candidate failing
    the check on the 7R's FK; candidates per pose), or None where the plan finds fewer solutions
    than ``counts`` (the reference's) on some pose."""
    from derive.ik import finish
    n = len(poses)
    with np.errstate(all="ignore"):
        ip, q7, degen = free_joint._candidates(dataclasses.replace(pl, alt=None), poses, values)
    cand = free_joint._grid(ip, q7, n)
    ok, _ = free_joint._check(robot, poses, cand)
    dup = finish.duplicates(cand, ok)
    count = (ok & ~dup).sum(1)
    if np.any(count < counts):
        return None
    fail = np.any(np.all(np.isfinite(cand), -1) & ~ok, 1)
    suspect = (count % 2 == 1) | (count == 0) | degen | np.any(dup, 1) | fail
    return int(suspect.sum()), len(ip) / max(n, 1)


def _quiet_plan(pl: free_joint.Plan, robot):
    """:func:`_fewest_suspects`, its choice kept in the user cache (once per code version: it
    solves 120 poses for each cut and eigen-variable, 0.4-4 s) under "<identity>-free-q<K>-cplan-<tag>"
    (:func:`_choice_key`)."""
    import json
    from derive.cache import find_artifact, store_artifacts
    key = _choice_key(robot, "cplan", pl, _SUSPECT_POSES, _DEFLATION_VALUES)
    found = find_artifact(key, "c_plan")
    if found is not None:
        choice = json.loads(found.read_text(encoding="utf-8"))["choice"]
    else:
        choice = _fewest_suspects(pl, robot)
        store_artifacts(key, {"c_plan": ("c_plan.json", json.dumps({"choice": choice}))},
                        {"robot": pl.robot, "free": f"q{pl.joint}"})
    if choice is None:
        return None
    reverse, e, ev = choice
    return dataclasses.replace(
        pl, reverse=reverse, e=e, ev=ev, alt=pl,
        notes=f"{'reversed' if reverse else 'forward'} 6R, cut at its joint {e}, eigen-variable "
              f"q{g6._cut_joints(e)[0][ev]} of the 6R (the fewest poses sent to the rescue: the "
              f"reference's plan is the rescue)")


def _choice_key(robot, kind: str, *on) -> str:
    """The user cache's key "<identity>-free-q<K>-<kind>-<tag>" of a plan choice: ``tag`` a digest
    of this code's version and of ``on``, the plans (their joint, direction, cut, eigen-variable
    and offsets) and the constants the choice depends on. (The cache's folder carries the
    version and a digest of the package's files already, :func:`derive.cache.user_folder`: the
    tag keeps a choice made with other constants or plans in the same code, a test's or a
    benchmark's monkeypatched ones, from being taken.)"""
    import hashlib

    def part(x):
        if isinstance(x, free_joint.Plan):
            return ("plan", x.joint, bool(x.reverse), int(x.e), int(x.ev), np.asarray(x.offsets).tolist(),
                    np.asarray(x.d3).tolist())
        return np.asarray(x).tolist() if isinstance(x, (tuple, list, np.ndarray)) else x

    joint = next(x.joint for x in on if isinstance(x, free_joint.Plan))
    tag = hashlib.sha256(repr((__version__, kind, [part(x) for x in on])).encode()).hexdigest()[:16]
    return f"{robot.id}-free-q{joint}-{kind}-{tag}"


def _fewest_suspects(pl: free_joint.Plan, robot):
    """For a held joint whose link lies on the triple side of every cut (joints 3-5: no deflation
    is baked, the 24 x 24 companion keeps the pencil's 8 pose-independent eigenvalues, and where
    some of them are real, as the +-theta double roots of the Gen3's q3 with the reference's plan,
    their candidates fail the check or Newton takes them to a solution found already, so the pose
    runs the rescue plan: 19 % of the Gen3's q3 poses), the cut and eigen-variable on which the
    fewest poses run the rescue (:func:`_suspects` on :data:`_SUSPECT_POSES` seeded
    configurations with their value of the joint), among the cuts that work at three values
    (:func:`derive.ik.general6r._check_cut`) and find every solution the reference's plan finds
    there; fewer candidates per pose break ties. The reference's plan where none does better by
    a margin (a third fewer suspect poses, and 5 % of the poses fewer: the solver core's time
    depends on the pencil's eigenvalue structure too, and on the Gen3's q4 a plan with 2 % fewer
    suspect poses runs 6 % slower). [reverse, e, ev] or None."""
    from derive.kinematics.fk import fk
    rng = np.random.default_rng(97 + pl.joint)
    q = rng.uniform(-np.pi, np.pi, (_SUSPECT_POSES, 7))
    poses = fk(robot, q)
    values = q[:, pl.joint - 1]
    ref = free_joint.solve(robot, poses, pl.joint, values)
    # (the reference's plan may find fewer without its rescue: that is what the rescue is for)
    own = _suspects(pl, robot, poses, values, np.zeros_like(ref.counts))
    best, score = None, own
    for reverse in (False, True):
        for e in (1, 2):
            if any(not g6._check_cut(g6._reverse(d) if reverse else d, e)[0]
                   for d in free_joint.locked_chain(pl.c, pl.joint, list(_DEFLATION_VALUES[:3]))):
                continue
            for ev in range(3):
                if (reverse, e, ev) == (pl.reverse, pl.e, pl.ev):
                    continue
                got = _suspects(dataclasses.replace(pl, reverse=reverse, e=e, ev=ev), robot, poses, values, ref.counts)
                if got is not None and got < score:
                    best, score = [reverse, e, ev], got
    if best is None or not (score[0] <= own[0] - 0.05 * len(poses) and 3 * score[0] <= 2 * own[0]):
        return None
    return best


def _regular(pl: free_joint.Plan, reverse: bool, e: int, ev: int) -> bool:
    """Whether the locked 6R's pencil for the cut at e with eigen-variable ev is regular at every
    value of :data:`_DEFLATION_VALUES`, with simple real roots: the 12 x 12 matrix at random q of
    the eigen-variable on 6 random configurations' poses has a smallest relative singular value
    above G6_RANK_TOL and no two real eigenvalues within CLUSTER_TOL (the tests
    :func:`derive.ik.general6r._check_cut` applies to each eigen-variable)."""
    rng = np.random.default_rng(11)
    for v in _DEFLATION_VALUES:
        d = free_joint.locked_chain(pl.c, pl.joint, [v])[0]
        c = g6._reverse(d) if reverse else d
        q = rng.uniform(-np.pi, np.pi, (6, 6))
        _, target = g6._chain_frames(c, q)
        y = g6._triple_coefs(c, e)
        x = g6._pair_coefs(c, e, target)
        qq, _ = np.linalg.qr(x[:, :, :8], mode="complete")
        yy = np.broadcast_to(y, (6, 14, 27)).copy()
        yy[:, :, 26] -= x[:, :, 8]
        t = np.moveaxis((np.swapaxes(qq[:, :, 8:], 1, 2) @ yy).reshape(6, 6, 3, 3, 3), 2 + ev, 2)
        th = rng.uniform(-np.pi, np.pi, 6)
        sig = np.einsum("nieab,ne->niab", t, np.stack([np.sin(th), np.cos(th), np.ones(6)], 1)).reshape(6, 6, 9)
        sv = np.linalg.svd(g6._twelve(sig @ g6._t45(0.3, -0.7)), compute_uv=False)
        if not np.min(sv[:, -1] / sv[:, 0]) > G6_RANK_TOL:
            return False
        # and no real root shared by two solutions (the slower multiple-root path)
        mats = g6._twelve(t.reshape(6, 6, 3, 9).transpose(0, 2, 1, 3) @ g6._t45(0.3, -0.7))
        mk = np.einsum("ak,naij->nkij", g6._half(0.5), mats)
        inv = g6._inv_safe(mk[:, 2])
        comp = np.zeros((6, 24, 24))
        comp[:, :12, 12:] = np.eye(12)
        comp[:, 12:, :12] = -inv @ mk[:, 0]
        comp[:, 12:, 12:] = -inv @ mk[:, 1]
        for row in np.linalg.eigvals(np.where(np.isfinite(comp), comp, 0.0)):
            xr = np.sort(row[np.abs(row.imag) < G6_REAL_TOL * (1 + np.abs(row) ** 2)].real)
            if np.any(np.abs(np.diff(xr)) <= g6.CLUSTER_TOL * (1 + np.abs(xr[1:]))):
                return False
    return True


#: Random values and poses per value at which a deflation of a plan with the held link on the
#: triple side is checked (:func:`_triple_side_deflation`), and the largest leak |(I - V V^T) C V|
#: allowed there, relative to max(1, the companion's largest entry)
_TRIPLE_CHECK_VALUES, _TRIPLE_CHECK_POSES, _TRIPLE_CHECK_LEAK = 24, 4, 1e-10


def _companions(pl: free_joint.Plan, v: float, q, d) -> np.ndarray:
    """The companion matrices (m, 24, 24) at offset d of the locked 6R's pencil (the reference's
    loop cut, :func:`derive.ik.general6r._cut_front`) with the joint held at v, at the poses of the
    6R configurations q (m, 6); d a sequence of offsets: (len(d), m, 24, 24), one pencil built."""
    from types import SimpleNamespace

    dd = free_joint.locked_chain(pl.c, pl.joint, [v])[0]
    if pl.reverse:
        dd = g6._reverse(dd)
    p = SimpleNamespace(c=dd, cut={"e": pl.e, "ev": pl.ev, "y": g6._triple_coefs(dd, pl.e)}, offsets=pl.offsets,
                        d3=pl.d3)
    _, target = g6._chain_frames(dd, q)
    mats = g6._cut_front(p, target)[-1]
    out = []
    for dk in np.atleast_1d(d):
        mk = np.einsum("ak,naij->nkij", g6._half(dk), mats)
        with np.errstate(all="ignore"):
            low = -g6._inv_safe(mk[:, 2]) @ np.concatenate([mk[:, 0], mk[:, 1]], axis=2)
        comp = np.zeros((len(q), 24, 24))
        comp[:, :12, 12:] = np.eye(12)
        comp[:, 12:] = low
        out.append(comp)
    return out[0] if np.ndim(d) == 0 else np.array(out)


def _leak(comp, v) -> float:
    """max over the companion matrices comp (m, 24, 24) of |(I - V V^T) C V| / max(1, |C|) for the
    orthonormal V (24, r): zero where span V is invariant under each."""
    out = comp @ v - v @ (np.swapaxes(v, 0, 1) @ comp @ v)
    with np.errstate(all="ignore"):
        r = np.abs(out).max(axis=(1, 2)) / np.maximum(1.0, np.abs(comp).max(axis=(1, 2)))
    return float(np.max(np.where(np.isfinite(r), r, np.inf)))


def _shared_subspace(pl: free_joint.Plan, v: float, rng, m: int = 4):
    """(V (24, r) orthonormal, leak) at offset d3[0] and value v: the span of the companion
    matrix's eigenvectors (real and imaginary parts) whose eigenvalues m random poses share (the
    eigenvectors every pose shares: the pencil's spurious eigenpairs of the triple side alone),
    and its leak (:func:`_leak`) on those poses; (None, inf) where none is shared."""
    comp = _companions(pl, v, rng.uniform(-np.pi, np.pi, (m, 6)), pl.d3[0])
    if not np.all(np.isfinite(comp)):
        return None, np.inf
    lam, vec = np.linalg.eig(comp[0])
    others = [np.linalg.eigvals(c) for c in comp[1:]]
    sel = [i for i, x in enumerate(lam) if all(np.min(np.abs(r - x)) < 1e-6 * (1 + abs(x)) for r in others)]
    if not sel:
        return None, np.inf
    u, s, _ = np.linalg.svd(np.concatenate([vec[:, sel].real, vec[:, sel].imag], 1), full_matrices=False)
    basis = u[:, :int(np.sum(s > 1e-8 * s[0]))]
    return basis, _leak(comp, basis)


def _offset_rotation(pl: free_joint.Plan, k: int) -> np.ndarray:
    """R (24, 24) with R V_0 = V_k: the companion's eigenvector [u; x u] at offset d3[0] is,
    up to a factor, [cos h u; sin h u] with h = (t - d) / 2 (t the eigen-variable's angle), so at
    offset d3[k] it is the rotation of the two halves by (d3[k] - d3[0]) / 2."""
    a = 0.5 * (pl.d3[k] - pl.d3[0])
    c, s = np.cos(a) * np.eye(12), np.sin(a) * np.eye(12)
    return np.block([[c, s], [-s, c]])


def _triple_side_deflation(pl: free_joint.Plan):
    """A deflation baked once for a plan whose held link lies on the triple side (joints 3-5,
    :func:`_held_on_pair_side` false), where the subspace of the eigenvectors every pose shares
    does not move with the value although its eigenvalues do: (bases (n_d3, 24, 24) [W V],
    keep, ()) or None. Two candidates: :func:`_fixed_deflation`'s (the reference's
    :func:`derive.ik.general6r._deflation` at each of :data:`_DEFLATION_VALUES`; it finds the
    eigenvectors at x = +-i, the Panda's q5) and the span of the shared eigenvectors at the
    value among :data:`_DEFLATION_VALUES` where it is invariant best (:func:`_shared_subspace`;
    xArm7's q3: 8 eigenvectors whose eigenvalues move with the value but not their span); the
    one removing more that holds (:func:`_leak` at most :data:`_TRIPLE_CHECK_LEAK`) at every
    offset on :data:`_TRIPLE_CHECK_POSES` random poses at each of :data:`_DEFLATION_VALUES` and
    :data:`_TRIPLE_CHECK_VALUES` random values. Where it moves (the other arms' joints 3-5), None:
    the whole pencil."""
    key = (pl.robot_id, pl.joint, pl.reverse, pl.e, pl.ev, tuple(np.round(pl.offsets, 12)))
    return memo("free-joint-triple-deflation", key, lambda: _triple_side_deflation_uncached(pl))


def _triple_side_deflation_uncached(pl: free_joint.Plan):
    rng = np.random.default_rng(29)
    options = []
    found = _fixed_deflation(pl, any_side=True)
    if found is not None:
        options.append(np.asarray(found[0], dtype=float)[0][:, found[1]:])
    best = min((_shared_subspace(pl, v, rng) for v in _DEFLATION_VALUES), key=lambda f: f[1])
    if best[0] is not None and best[1] < _TRIPLE_CHECK_LEAK:
        options.append(best[0])
    values = np.concatenate([_DEFLATION_VALUES, rng.uniform(-np.pi, np.pi, _TRIPLE_CHECK_VALUES)])
    for v0 in sorted(options, key=lambda b: -b.shape[1]):
        if not 2 <= v0.shape[1] <= 12:
            continue
        rots = [_offset_rotation(pl, k) for k in range(len(pl.d3))]
        ok = True
        for v in values:
            q = rng.uniform(-np.pi, np.pi, (_TRIPLE_CHECK_POSES, 6))
            for k, d in enumerate(pl.d3):
                if not _leak(_companions(pl, v, q, d), rots[k] @ v0) <= _TRIPLE_CHECK_LEAK:
                    ok = False
                    break
            if not ok:
                break
        if ok:
            bases = []
            for k in range(len(pl.d3)):
                qv = np.linalg.qr(rots[k] @ v0, mode="complete")[0]
                r = v0.shape[1]
                bases.append(np.concatenate([qv[:, r:], qv[:, :r]], axis=1))
            return np.array(bases), 24 - v0.shape[1], ()
    return None


#: The seven-joint cores' Newton bound |det J| / |J|_F^6 (at the last step's start) at or above
#: which a solution is regular without fj_singular_flags' LU (templates/general6r.c.j2's G6_CLEAR in
#: the runtime mode), in units of G6_SINGULAR: 108 times it bounds sigma_min / sigma_max from below,
#: and c_source keeps its margin of 10 over G6_NEAR_SINGULAR (the last step, below 1e-6 rad, moves
#: the bound by about 1 %: a random-chain check found at most a factor 1.012)
_NEWTON_CLEAR = 10.0
#: The per-value deflation basis (:func:`value_basis`): values sampled, the degrees tried, the
#: largest fitting leak accepted at a sample and the smallest singular value of the fitted basis
_VALUE_SAMPLES, _VALUE_DEGREES, _VALUE_SAMPLE_LEAK, _VALUE_MIN_SV = 160, (1, 2, 4, 8, 12, 16, 24, 32), 1e-11, 1e-3
#: The share of the check values at which a fitted basis must hold where it does not hold at all
#: (near a value where the shared span is not analytic, or its samples inaccurate): the C kernel's
#: leak check sends the poses at the others to the whole pencil
_VALUE_MIN_SHARE = 0.75
#: The piecewise basis (:func:`_piece_basis`, where the trigonometric one does not hold at every
#: value): pieces of equal width over [-pi, pi), Chebyshev nodes sampled per piece, the degrees
#: tried, the random values checked per piece, and the random poses per sample (the span is taken
#: at the pose whose shared eigenvalues lie farthest from its others)
_PIECES, _PIECE_SAMPLES, _PIECE_DEGREES, _PIECE_CHECK, _PIECE_POSES = 16, 23, (4, 6, 8, 12, 16, 20), 6, 5
#: The stages of a piece's fit (:func:`_fit_piece`): every step-th of the :data:`_PIECE_SAMPLES`
#: nodes cos(pi k / 24) (they nest: 11, then all 23) and the degrees tried on them
_PIECE_STAGES = ((2, (4, 6, 8)), (1, (8, 12, 16, 20)))
#: The largest leak of a sample where the accurate ones are too few (:func:`_fit_piece`)
_PIECE_SAMPLE_LOOSE = 1e-10
#: A trigonometric basis of at most this many terms (2 n + 1) is taken as it is; a longer one
#: gives way to the pieces where they all hold with fewer (:func:`_value_basis`)
_FOURIER_TERMS_TAKEN = 13
#: The version of the stored value basis's fit and format, in its cache key (:func:`_value_basis_stored`)
_VALUE_BASIS_FORMAT = 3


@dataclasses.dataclass(frozen=True)
class ValueBasis:
    """A basis V(v) (24 x r, at the offset d3[0]) of the eigenvectors every pose shares at the
    held value v. ``kind`` "fourier": V(v) = sum_k h[k] h_k(v), h = (1, cos v, sin v, ...,
    cos n v, sin n v), h (2n + 1, 24, r); "pieces": v wrapped to [-pi, pi) falls in one of
    P = len(h) pieces of equal width, V = sum_k h[p, k] T_k(t) (Chebyshev polynomials of degree
    at most n, t the value's place in the piece, in [-1, 1]), h (P, n + 1, 24, r); a piece
    without a basis (``present`` false: its samples or its check failed) gives V = 0, the whole
    pencil (the C kernel's deflation takes a zero basis as none)."""
    kind: str
    h: np.ndarray
    n: int
    present: tuple = ()

    @property
    def r(self) -> int:
        return int(self.h.shape[-1])

    def at(self, v) -> np.ndarray:
        """V(v) (24, r)."""
        v = float(v)
        if self.kind == "fourier":
            return np.einsum("k,kij->ij", _value_harmonics(v, self.n)[0], self.h)
        p, t = _piece_of(v, len(self.h))
        if not self.present[p]:
            return np.zeros(self.h.shape[2:])
        return np.einsum("k,kij->ij", _chebyshev(t, self.n), self.h[p])


def _piece_of(v: float, pieces: int) -> tuple[int, float]:
    """(piece, t in [-1, 1]) of the value v wrapped to [-pi, pi), as templates/free_joint.c.j2's
    fj*_value_basis_at."""
    w = math.remainder(v, 2 * math.pi)
    width = 2 * math.pi / pieces
    p = min(max(int(math.floor((w + math.pi) / width)), 0), pieces - 1)
    return p, 2.0 * (w - (-math.pi + p * width)) / width - 1.0


def _chebyshev(t, n: int) -> np.ndarray:
    """(T_0(t), ..., T_n(t)) by the three-term recurrence (the C's order of operations)."""
    out = [1.0, t]
    for _ in range(2, n + 1):
        out.append(2.0 * t * out[-1] - out[-2])
    return np.array(out[:n + 1], dtype=float)


def value_basis(pl: free_joint.Plan):
    """The deflation of a plan whose held link lies on the triple side (joints 3-5) where the
    subspace V(v) of the eigenvectors every pose shares moves with the value v: a basis of it as
    a trigonometric polynomial in v, V(v) = sum_k H[k] h_k(v), h = (1, cos v, sin v, ...,
    cos N v, sin N v), at the offset d3[0] (the other offsets' by :func:`_offset_rotation`).
    The spurious eigenvectors depend on the value only, never on the pose, and their span is an
    analytic function of v (where no spurious eigenvalue meets another eigenvalue of the triple
    side's equations), so its Fourier series converges geometrically. Fitted by least squares to
    the spans at :data:`_VALUE_SAMPLES` equispaced values (:func:`_shared_subspace`, the best of
    the three offsets, each projected on a fixed basis V0 so that the fit is linear), the
    smallest degree of :data:`_VALUE_DEGREES` whose basis holds (:func:`_leak` at most
    :data:`_TRIPLE_CHECK_LEAK`, its smallest singular value above :data:`_VALUE_MIN_SV`) on
    :data:`_TRIPLE_CHECK_POSES` random poses at :data:`_TRIPLE_CHECK_VALUES` random values and every
    offset. (H (2N + 1, 24, r), N) or None (then the whole pencil). Once per process."""
    key = (pl.robot_id, pl.joint, pl.reverse, pl.e, pl.ev, tuple(np.round(pl.offsets, 12)))
    return memo("free-joint-value-basis", key, lambda: _value_basis_stored(pl))


def _value_basis_stored(pl: free_joint.Plan):
    """:func:`_value_basis`, kept in the user cache (a few seconds per plan; keyed by the robot's
    identity, the plan and this code's version and constants)."""
    import hashlib
    import json
    from derive.cache import find_artifact, step, store_artifacts, task
    tag = hashlib.sha256(repr((__version__, pl.joint, pl.reverse, pl.e, pl.ev, np.asarray(pl.offsets).tolist(),
                               _VALUE_SAMPLES, _VALUE_DEGREES, _VALUE_SAMPLE_LEAK, _VALUE_MIN_SV, _TRIPLE_CHECK_VALUES,
                               _TRIPLE_CHECK_POSES, _TRIPLE_CHECK_LEAK, _VALUE_MIN_SHARE, _PIECES, _PIECE_SAMPLES,
                               _PIECE_DEGREES, _PIECE_CHECK, _PIECE_POSES, _PIECE_SAMPLE_LOOSE, _PIECE_STAGES, _VALUE_BASIS_FORMAT)).encode()).hexdigest()[:16]
    key = f"{pl.robot_id}-free-q{pl.joint}-vb-{tag}"
    found = find_artifact(key, "value_basis")
    if found is not None:
        data = json.loads(found.read_text(encoding="utf-8"))
        return None if data["h"] is None else ValueBasis(data["kind"], np.array(data["h"], dtype=float), int(data["n"]),
                                                         tuple(bool(x) for x in data["present"]))
    with task(f"{pl.robot} q{pl.joint}"):
        step("fitting the deflation basis per value of the plan's loop cut")
        out = _value_basis(pl)
    text = json.dumps({"h": None, "n": None} if out is None else
                      {"kind": out.kind, "h": out.h.tolist(), "n": out.n, "present": list(out.present)})
    store_artifacts(key, {"value_basis": ("value_basis.json", text)}, {"robot": pl.robot, "free": f"q{pl.joint}"})
    return out


def _value_harmonics(v, n: int) -> np.ndarray:
    v = np.atleast_1d(np.asarray(v, dtype=float))
    cols = [np.ones_like(v)]
    for k in range(1, n + 1):
        cols += [np.cos(k * v), np.sin(k * v)]
    return np.stack(cols, -1)


def _shared_span(comp, own: bool = False, lams=None):
    """The orthonormal basis (24, r) of the invariant subspace of the companion matrices comp
    (m, 24, 24) for the eigenvalues they all share (within 1e-6, a cluster within 1e-4 taken as one
    eigenvalue of its multiplicity k: the null space of (C - x I)^k, generalised eigenvectors
    too), real and imaginary parts; None where none is shared. ``own``: only the clusters whose
    subspace every matrix maps into itself (:func:`_leak` below 1e-6 on its real and imaginary
    parts: a shared eigenvalue whose eigenvectors change with the pose, as those at x = +-i of
    some plans, is left to the eigen-solver). ``lams``: the matrices' eigenvalues where the caller
    has them."""
    groups = _shared_groups(comp, lams=lams)
    if not groups:
        return None
    cols = []
    for g in groups:
        x, k = np.mean(g), len(g)
        a = np.linalg.matrix_power(comp[0] - x * np.eye(24), k)
        g = np.linalg.svd(a)[2][-k:].conj().T
        if own:
            u, sv, _ = np.linalg.svd(np.concatenate([g.real, g.imag], 1), full_matrices=False)
            if not _leak(comp, u[:, :int(np.sum(sv > 1e-8 * sv[0]))]) < 1e-6:
                continue
        cols.append(g)
    if not cols:
        return None
    v = np.concatenate(cols, 1)
    u, sv, _ = np.linalg.svd(np.concatenate([v.real, v.imag], 1), full_matrices=False)
    return u[:, :int(np.sum(sv > 1e-8 * sv[0]))]


def _value_basis(pl: free_joint.Plan):
    """The trigonometric basis (:func:`_fourier_basis`) where it holds at every check value (the
    piecewise one instead where that holds on every piece with fewer terms), else
    the piecewise one (:func:`_piece_basis`) where its pieces cover at least half of [-pi, pi) and
    a larger share than the check values the trigonometric one holds at, else the trigonometric
    one where it holds at :data:`_VALUE_MIN_SHARE` of them; None where neither does."""
    four = _fourier_basis(pl)
    if four is not None and four[2] == 1.0:
        if 2 * four[1] + 1 <= _FOURIER_TERMS_TAKEN:
            return ValueBasis("fourier", four[0], four[1])
        # a trigonometric degree past 6: the pieces where they all hold with fewer terms (2 n + 1
        # terms per pose: 49 for gen3 q3, 65 for panda q3)
        pieces = _piece_basis(pl)
        if pieces is not None and all(pieces.present) and pieces.n + 1 < 2 * four[1] + 1:
            return pieces
        return ValueBasis("fourier", four[0], four[1])
    pieces = _piece_basis(pl)
    if pieces is not None and sum(pieces.present) >= _PIECES // 2 and (
            four is None or sum(pieces.present) / _PIECES > four[2]):
        return pieces
    return None if four is None else ValueBasis("fourier", four[0], four[1])


def _fourier_basis(pl: free_joint.Plan):
    """(h, n, the share of the check values where it holds) of the trigonometric fit, or None."""
    rng = np.random.default_rng(37)
    vs = 2 * np.pi * np.arange(_VALUE_SAMPLES) / _VALUE_SAMPLES
    rots = [_offset_rotation(pl, k) for k in range(len(pl.d3))]
    spans = []
    for v in vs:
        comps = _companions(pl, v, rng.uniform(-np.pi, np.pi, (4, 6)), pl.d3)
        best = (None, np.inf)
        for k, comp in enumerate(comps):        # the first offset whose span is accurate, else the best
            if not np.all(np.isfinite(comp)):
                continue
            b = _shared_span(comp)
            if b is None:
                continue
            leak = _leak(comp, b)
            if leak < best[1]:
                best = (rots[k].T @ b, leak)
            if leak < _VALUE_SAMPLE_LEAK:
                break
        spans.append(best)
    dims = [b.shape[1] for b, leak in spans if b is not None and leak < _VALUE_SAMPLE_LEAK]
    if len(dims) < _VALUE_SAMPLES // 2:
        return None
    r = max(set(dims), key=dims.count)
    good = [i for i, (b, leak) in enumerate(spans) if b is not None and leak < _VALUE_SAMPLE_LEAK and b.shape[1] == r]
    if not 2 <= r <= 12 or len(good) < _VALUE_SAMPLES // 2:
        return None
    # the fixed basis V0: the sample's span that every other sample's span sees best
    sv_min = [min(np.linalg.svd(spans[j][0].T @ spans[i][0], compute_uv=False).min() for j in good[::4])
              for i in good[::4]]
    v0 = spans[good[::4][int(np.argmax(sv_min))]][0]
    y = np.array([spans[i][0] @ (spans[i][0].T @ v0) for i in good])         # P(v) V0: linear in P
    test = rng.uniform(-np.pi, np.pi, _TRIPLE_CHECK_VALUES)
    test_q = rng.uniform(-np.pi, np.pi, (_TRIPLE_CHECK_VALUES, _TRIPLE_CHECK_POSES, 6))
    found, checks = None, [None] * len(test)
    for n in _VALUE_DEGREES:
        if 2 * n + 1 > len(good) // 2:
            break
        h = np.linalg.lstsq(_value_harmonics(vs[good], n), y.reshape(len(good), -1), rcond=None)[0]
        h = h.reshape(2 * n + 1, 24, r)
        passed = 0
        for j, v in enumerate(test):
            if j - passed > (1 - _VALUE_MIN_SHARE) * len(test):
                break                           # this degree cannot reach the share any more
            b = np.einsum("k,kij->ij", _value_harmonics(v, n)[0], h)
            sv = np.linalg.svd(b, compute_uv=False)
            if checks[j] is None:
                checks[j] = _companions(pl, v, test_q[j], pl.d3)
            passed += bool(sv[-1] > _VALUE_MIN_SV * sv[0]) and all(
                _leak(checks[j][k], np.linalg.qr(rots[k] @ b)[0]) <= _TRIPLE_CHECK_LEAK for k in range(len(pl.d3)))
        if passed == len(test):
            return h, n, 1.0
        if passed >= _VALUE_MIN_SHARE * len(test) and (found is None or passed > found[2]):
            found = (h, n, passed)
    return None if found is None else (found[0], found[1], found[2] / len(test))


def _separated_span(comp):
    """(V (24, r), leak) of :func:`_shared_span` (its clusters that every matrix maps into
    itself) of the companion matrices comp (m, 24, 24), the span taken at the matrix whose shared
    eigenvalues lie farthest from its other eigenvalues (near a value where pose-dependent
    eigenvalues pass close to the shared ones the span of one pose is ill-conditioned, not the
    span itself); (None, inf) where none is shared."""
    if not np.all(np.isfinite(comp)):
        return None, np.inf
    lams = np.linalg.eigvals(comp)
    near = np.abs(lams[:, :, None, None] - lams[None, None]).min(-1)       # (pose i, eigenvalue, pose j)
    sep = []
    for i, lam in enumerate(lams):
        shared = np.all(np.delete(near[i], i, axis=1) < 1e-6 * (1 + np.abs(lam))[:, None], axis=1)
        sep.append(np.min(np.abs(lam[shared][:, None] - lam[~shared][None]), initial=np.inf) if shared.any()
                   and (~shared).any() else (0.0 if not shared.any() else np.inf))
    i = int(np.argmax(sep))
    if not sep[i] > 0.0:
        return None, np.inf
    order = [i] + [j for j in range(len(comp)) if j != i]
    b = _shared_span(comp[order], own=True, lams=lams[order])
    return (None, np.inf) if b is None else (b, _leak(comp, b))


def _piece_basis(pl: free_joint.Plan):
    """The piecewise basis (:class:`ValueBasis` "pieces"): [-pi, pi) in :data:`_PIECES` pieces,
    each fitted by :func:`_fit_piece`; a piece where no fit holds is split in two halves, each
    fitted on its own; the result has 2 :data:`_PIECES` pieces of equal width where a split was
    needed (the unsplit pieces' polynomials re-expanded on their halves: exact, the same degree),
    else :data:`_PIECES`. A piece without a fit has none (the whole pencil there: next to the
    values where the shared eigenvalues come near x = +-i, where even the exact span's check
    leaks, e.g. xArm7's q4 near v = pi and -0.5, the Gen3's q4 near 0; docs/ik.md). The degree is the largest any piece needs (the others' padded with zeros: the C
    evaluates each piece to its own degree, :func:`_value_basis_context`). None where no piece
    has a basis."""
    from numpy.polynomial import chebyshev as cheb
    rng = np.random.default_rng(53)
    rots = [_offset_rotation(pl, k) for k in range(len(pl.d3))]
    width = 2 * np.pi / _PIECES
    fits, r = [], [None]
    for p in range(_PIECES):
        a = -np.pi + p * width
        f = _fit_piece(pl, a, a + width, rng, rots, r)
        fits.append(f if f is not None else [_fit_piece(pl, a + i * width / 2, a + (i + 1) * width / 2, rng, rots, r)
                                              for i in (0, 1)])
    if r[0] is None or not any(f is not None for f in fits for f in (f if isinstance(f, list) else [f])):
        return None
    if any(isinstance(f, list) for f in fits):
        halves = []
        for f in fits:
            if isinstance(f, list):
                halves += f
                continue
            n = len(f) - 1
            nodes = np.cos(np.pi * (np.arange(n + 1) + 0.5) / (n + 1))
            for s in (-1.0, 1.0):            # t' on the half is t = (t' + s) / 2 on the piece
                y = np.moveaxis(cheb.chebval((nodes + s) / 2, f), -1, 0).reshape(n + 1, -1)
                halves.append(cheb.chebfit(nodes, y, n).reshape(n + 1, 24, r[0]))
        fits = halves
    n = max(len(f) for f in fits if f is not None) - 1
    h = np.zeros((len(fits), n + 1, 24, r[0]))
    for p, f in enumerate(fits):
        if f is not None:
            h[p, :len(f)] = f
    return ValueBasis("pieces", h, n, tuple(f is not None for f in fits))


def _piece_sample(pl: free_joint.Plan, v: float, rng, rots):
    """(V (24, r) at the offset d3[0], leak) of the shared span at the value v: per offset (the
    first whose leak is below :data:`_VALUE_SAMPLE_LEAK`, else the best) :func:`_separated_span`
    on :data:`_PIECE_POSES` random poses, or where that is not accurate at any offset the
    eigenvectors all of them share (:func:`_constant_eigenvectors`, the stacked null space: accurate where a shared
    eigenvalue is double and nearly defective at one pose, which (C - x I)^2 at that pose is not;
    xArm7's and the Gen3's q4 near v = pi and 0, where the shared eigenvalues come near x = +-i)."""
    comps = _companions(pl, v, rng.uniform(-np.pi, np.pi, (_PIECE_POSES, 6)), pl.d3)
    best = (None, np.inf)
    for k in range(len(pl.d3)):
        s, leak = _separated_span(comps[k])
        if s is not None and leak < best[1]:
            best = (rots[k].T @ s, leak)
        if leak < _VALUE_SAMPLE_LEAK:
            return best
    for k in range(len(pl.d3)):
        if np.all(np.isfinite(comps[k])):
            s = _constant_eigenvectors(comps[k])
            if s is not None and (best[0] is None or s.shape[1] == best[0].shape[1]):
                leak = _leak(comps[k], s)
                if leak < best[1]:
                    best = (rots[k].T @ s, leak)
                if leak < _VALUE_SAMPLE_LEAK:
                    break
    return best


def _fit_piece(pl: free_joint.Plan, a: float, b: float, rng, rots, r: list):
    """The Chebyshev coefficients (n + 1, 24, r) of the basis on the values [a, b] (t = -1 at a,
    1 at b), or None: the spans (:func:`_piece_sample`, rotated back to d3[0]) at Chebyshev nodes,
    each projected on the piece's fixed basis V0 (the middle good sample's), fitted by least
    squares, the smallest degree that holds (:func:`_leak` at most :data:`_TRIPLE_CHECK_LEAK` at
    every offset, smallest singular value above :data:`_VALUE_MIN_SV`) at :data:`_PIECE_CHECK`
    random values of the piece on :data:`_TRIPLE_CHECK_POSES` random poses. In the stages of
    :data:`_PIECE_STAGES`: 11 nodes and the degrees up to 8 (most pieces), then 23 and up to 20
    (where the span turns fast: near v = pi and 0 on xArm7's and the Gen3's q4); the nodes
    cos(pi k / 24) nest, so the second stage samples only the 11 new ones; a fit of the first
    stage holds only within a tenth of that bound (on fewer samples the smallest degree that
    passes is less accurate: 1e-10 against 1e-12 with 24 samples on the Panda's q4 at v = -0.43,
    and the C's solutions move by 1e-9 rad). A sample is good
    where its leak is below :data:`_VALUE_SAMPLE_LEAK`, or after the first stage, where fewer than
    two thirds are, below :data:`_PIECE_SAMPLE_LOOSE` (near x = +-i the eigenvalues of the poses
    crowd the shared ones and no sample is more accurate). No looser check: near x = +-i (xArm7's
    q4 at v in [2.95, pi)) the check's own companion matrices leak 2e-10 for the exact span (their
    last rows solve with a nearly singular leading coefficient), and a fit accepted within 5e-10
    at 4 of 6 check values passed the C's run-time check with leaks up to 1e-9 whose perturbed
    roots flagged 3 of 200 poses the reference does not (test_free_joint_general_route_flags_stay_
    rare_on_random_poses): those pieces keep the whole pencil. r[0]: the span's dimension (set by
    the first piece with samples, the most common there)."""
    nodes = np.cos(np.pi * np.arange(1, _PIECE_SAMPLES + 1) / (_PIECE_SAMPLES + 1))     # cos(pi k / 24)
    spans = [None] * _PIECE_SAMPLES
    test = rng.uniform(a, b, _PIECE_CHECK)
    test_q = rng.uniform(-np.pi, np.pi, (_PIECE_CHECK, _TRIPLE_CHECK_POSES, 6))
    checks = [None] * _PIECE_CHECK
    for stage, (step, degrees) in enumerate(_PIECE_STAGES):
        idx = np.arange(step - 1, _PIECE_SAMPLES, step)
        for i in idx:
            if spans[i] is None:
                spans[i] = _piece_sample(pl, a + (nodes[i] + 1) * (b - a) / 2, rng, rots)
        dims = [spans[i][0].shape[1] for i in idx if spans[i][0] is not None and spans[i][1] < _VALUE_SAMPLE_LEAK]
        if r[0] is None and dims:
            r[0] = max(set(dims), key=dims.count)
        if r[0] is None or not 2 <= r[0] <= 12:
            continue
        good = [i for i in idx if spans[i][0] is not None and spans[i][1] < _VALUE_SAMPLE_LEAK
                and spans[i][0].shape[1] == r[0]]
        if stage and 3 * len(good) < 2 * len(idx):
            good = [i for i in idx if spans[i][0] is not None and spans[i][1] < _PIECE_SAMPLE_LOOSE
                    and spans[i][0].shape[1] == r[0]]
        if len(good) <= _PIECE_DEGREES[0] + 1:
            continue
        v0 = spans[good[len(good) // 2]][0]
        y = np.array([spans[i][0] @ (spans[i][0].T @ v0) for i in good]).reshape(len(good), -1)
        for n in degrees:
            if n + 2 > len(good):
                continue
            h = np.polynomial.chebyshev.chebfit(nodes[good], y, n).reshape(n + 1, 24, r[0])
            bound = _TRIPLE_CHECK_LEAK * (0.1 if stage == 0 else 1.0)
            ok = True
            for j, v in enumerate(test):
                s = np.einsum("k,kij->ij", _chebyshev(2 * (v - a) / (b - a) - 1, n), h)
                sv = np.linalg.svd(s, compute_uv=False)
                if checks[j] is None:
                    checks[j] = _companions(pl, v, test_q[j], pl.d3)
                if not (sv[-1] > _VALUE_MIN_SV * sv[0] and all(
                        _leak(checks[j][k], np.linalg.qr(rots[k] @ s)[0]) <= bound for k in range(len(pl.d3)))):
                    ok = False
                    break
            if ok:
                return h
    return None


def _deflation(pl: free_joint.Plan, robot):
    """The deflation of the pencil's pose-independent eigenvectors (as the general 6R kernel's,
    :func:`derive.ik.general6r._deflation`) where it holds for every value
    (:func:`_fixed_deflation`): joint 1 or 7 held (the held link is the first or last, so the
    locked 6R's loop links 1-5 are the same for every value and the value moves only the pose
    link), or the held link on the pair side of the cut (joint 2 or 6, :func:`c_plans`); with the
    held link on the triple side the pose-independent eigenvalues and eigenvectors change with
    the value, so there is none. ``robot`` is the plan's robot (its route, not reloaded by
    ``pl.robot``, the name: a robot from a file is not in the library, and a library robot of
    the same name may be another arm). As the general 6R kernels'
    template context ``defl`` (their ``_deflation_context`` of :mod:`derive.codegen.general6r`,
    given a plan-like record with ``deflate``, ``deflate_keep``, ``spurious``); None where that
    module has no such context (a template without the deflation)."""
    from types import SimpleNamespace

    from derive.codegen import general6r as cg6
    make = getattr(cg6, "_deflation_context", None) or getattr(cg6, "deflation_context", None)
    if make is None:
        return None
    # on a class route (the Panda's q7 only, see _c_plans) the deflation of joints 1 and 7
    general = pl.joint in (1, 7) or free_joint.route(robot, pl.joint) == "general"
    found = _pair_deflation(pl) if general else None
    if found is None and general and not _held_on_pair_side(pl):
        found = _triple_side_deflation(pl)        # joints 3-5: where the shared span stays put
    if found is None:
        off = make(SimpleNamespace(deflate=None, deflate_keep=24, spurious=()))
        vb = value_basis(pl) if general and not _held_on_pair_side(pl) else None
        if vb is not None:                        # joints 3-5: the basis per value (the caller's)
            from derive.codegen.general6r import _arr
            r = vb.r
            rot = [[np.cos(0.5 * (d - pl.d3[0])), np.sin(0.5 * (d - pl.d3[0]))] for d in pl.d3]
            off = dict(off, runtime=True, n=r, keep=24 - r, rot=_arr(np.array(rot)))
        return off
    b, keep, spurious = found
    return make(SimpleNamespace(deflate=np.asarray(b, dtype=float), deflate_keep=int(keep), spurious=tuple(spurious)))


def _core_context(pl: free_joint.Plan, robot) -> dict:
    """The context of templates/general6r.c.j2 in runtime mode for one plan of the general route
    (:func:`derive.ik.free_joint.plan`): the cut, eigen-variable, offsets and direction baked in;
    the locked chain and the coefficients are the solver core's runtime data (templates/free_joint.c.j2).
    ``robot``: the plan's robot (or its library name), for :func:`_deflation`."""
    from derive.codegen.general6r import _arr, _lit
    e, ev = int(pl.e), int(pl.ev)
    triple, pair = g6._cut_joints(e)
    order = [ev] + [i for i in range(3) if i != ev]
    perm = []
    for a in range(3):                    # perm[9 i + 3 j + k] = the triple's index: eigen joint first
        for b in range(3):
            for c in range(3):
                old = [0, 0, 0]
                old[order[0]], old[order[1]], old[order[2]] = a, b, c
                perm.append(9 * old[0] + 3 * old[1] + old[2])
    return _Context({
        "runtime": True, "mode": {"kind": "runtime"}, "defl": _deflation(pl, robot), "reverse": bool(pl.reverse), "scale": _lit(pl.scale),
        "perm": perm, "order": order, "triple": [j - 1 for j in triple], "pair": [j - 1 for j in pair],
        "last": e - 1, "t45": _arr(g6._t45(pl.offsets[0], pl.offsets[1])), "d4": _lit(pl.offsets[0]),
        "d5": _lit(pl.offsets[1]), "d3": [_lit(d) for d in pl.d3], "halves": [_arr(g6._half(d)) for d in pl.d3],
        "n_d3": len(pl.d3), "start": _arr(g6._START), "nudge": _lit(g6._NUDGE),
        "cluster_tol": _lit(g6.CLUSTER_TOL), "accept": _lit(G6_ACCEPT), "real_tol": _lit(G6_REAL_TOL),
        "newton_max": int(G6_NEWTON_MAX), "newton_clear": _lit(_NEWTON_CLEAR), "singular": _lit(G6_SINGULAR), "good_cond": _lit(G6_GOOD_COND),
        "leading_cond": _lit(G6_LEADING_COND), "rank_tol": _lit(G6_RANK_TOL), "merge_tol": _lit(MERGE_TOL),
        "max_solutions": MAX_SOLUTIONS, "n_perturb": 0, "notes": [" ".join(pl.notes.split())],
        "how": ("the loop cut at joint %d of the %s locked 6R (pair %s eliminated linearly, triple %s, "
                "eigen-variable q%d of the 6R), coefficients per pose and value"
                % (e, "reversed" if pl.reverse else "forward", tuple(pair), tuple(triple), triple[ev])),
    })


def _triple_side(pl: free_joint.Plan, v: float) -> np.ndarray:
    """(14, 27): the triple's side of the plan's loop cut with the joint held at v (it does not
    depend on the pose: the cut's triple side holds links 1-5 of the locked 6R, never the pose link)."""
    d = free_joint.locked_chain(pl.c, pl.joint, [v])[0]
    return g6._triple_coefs(g6._reverse(d) if pl.reverse else d, pl.e)


def triple_constant(pl: free_joint.Plan):
    """(14, 27): the triple side Y of a plan where it is the same at every held value (the held
    joint's link off the cut's triple side, :func:`_held_on_pair_side`), checked at
    :data:`_DEFLATION_VALUES` (equal within 1e-13 of its largest entry); else None. The C kernel
    then bakes it (templates/free_joint.c.j2) instead of evaluating its harmonics per value."""
    if not _held_on_pair_side(pl):
        return None
    y = _triple_side(pl, 0.0)
    tol = 1e-13 * max(1.0, float(np.abs(y).max()))
    if any(float(np.abs(_triple_side(pl, v) - y).max()) > tol for v in _DEFLATION_VALUES):
        return None
    return y


def _yc(pl: free_joint.Plan):
    key = (pl.robot_id, pl.joint, pl.reverse, pl.e, pl.ev)
    return memo("free-joint-triple-constant", key, lambda: triple_constant(pl))


def _harmonics(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return np.stack([np.ones_like(v), np.cos(v), np.sin(v), np.cos(2 * v), np.sin(2 * v), np.cos(3 * v),
                     np.sin(3 * v)], -1)


def triple_harmonics(pl: free_joint.Plan, samples: int = 16) -> np.ndarray:
    """(7, 378): the triple side Y(v) of a plan as a trigonometric polynomial of degree 3 in the held
    value, Y(v) = sum_k H[k] h_k(v), h = (1, cos v, sin v, cos 2v, sin 2v, cos 3v, sin 3v): the held
    joint's link C_K Rz(v) C_{K+1} enters the cut's triple at most once, so the transform whose z line
    is taken, and its inverse, have entries of degree 1 in (cos v, sin v), and the 14 line equations
    are of degree <= 3 in them (the Lagrange product (p.p) l - 2 (p.l) p). Least squares over
    ``samples`` equispaced values, checked at 5 random values (DeriveError past 1e-10)."""
    vs = 2 * np.pi * np.arange(samples) / samples
    ys = np.array([_triple_side(pl, v).ravel() for v in vs])
    coef = np.linalg.lstsq(_harmonics(vs), ys, rcond=None)[0]
    test = np.random.default_rng(5).uniform(-np.pi, np.pi, 5)
    err = max(float(np.abs(_harmonics(v) @ coef - _triple_side(pl, v).ravel()).max()) for v in test)
    if not err < 1e-10 * max(1.0, float(np.abs(ys).max())):
        raise DeriveError(f"{pl.robot} with q{pl.joint} given: the triple side is not a trigonometric "
                          f"polynomial of degree 3 in the held value (misses by {err:.1e})")
    return coef


#: The routes of :func:`derive.ik.free_joint.route` whose C is the class's IK program
#: (:func:`program_source`), not the general elimination
PROGRAM_ROUTES = ("srs", "srs-2")


def program_source(robot, joint: int) -> str:
    """The C99 source of the IK of an SRS arm with joint ``joint`` given, on the class routes of
    :func:`derive.ik.free_joint.route`: the class's IK program
    (:func:`derive.ik.program7.srs_joint_program`, the numpy closed form of
    :func:`derive.ik.srs.ik_joint` / :func:`derive.ik.free_joint._srs_joint2` as a composition of
    subproblems) printed as the generated kernels print every class's program
    (templates/kinematics.c.j2 with its header inlined; the functions are named
    ``<robot>_free_q<K>_*``: ``..._ik_batch_ex(n, poses, fv, sols (n x 8 x 7), counts, branch,
    singular)``, with the class's branch ids and singular flags). Rendered once per code version
    (about 15 s, with progress on stderr) and kept in the user cache
    (:func:`derive.cache.store_artifacts`, under "<identity>-free-q<K>-L<limits>")."""
    from derive.cache import find_artifact, step, store_artifacts, task
    from derive.model.robot import load_robot
    robot = load_robot(robot)
    key = f"{robot.id}-free-q{joint}-L{robot.limits_id}"
    found = find_artifact(key, "c_source")
    if found is not None:
        return found.read_text(encoding="utf-8")
    with task(f"{robot.name} q{joint}"):
        step("rendering the C of the class's IK program with the joint given")
        text = _render_program(robot, joint)
    store_artifacts(key, {"c_source": (f"{_identifier(robot, joint)}.c", text)},
                    {"robot": robot.name, "free": f"q{joint}"})
    return text


def _render_program(robot, joint: int) -> str:
    from derive.codegen.emit import _context
    from derive.codegen.templates import template_environment
    ident = _identifier(robot, joint)
    ctx = _context(robot, f"derive.kernels({robot.name!r}, 'c', free='q{joint}')", f"q{joint}")
    if ctx["ik"] is None or ctx["ik"].get("free") != f"q{joint}":
        why = ctx.get("ik_missing") or f"the IK program's free parameter is {(ctx['ik'] or {}).get('free')}"
        raise DeriveError(f"{robot.name} with q{joint} given: no IK program ({why})")
    ctx["id"] = ident
    env = template_environment()
    header = env.get_template("kinematics.h.j2").render(ctx)
    source = env.get_template("kinematics.c.j2").render(ctx).replace(f'#include "{ident}_kinematics.h"\n', "")
    return header + "\n" + source


def c_source(robot, joint: int) -> str:
    """The C99 source of the IK of a seven-joint arm with joint ``joint`` given: on the SRS class
    routes the class's IK program (:func:`program_source`), else the general elimination
    (templates/free_joint.c.j2; see the module docstring). DeriveError when the arm has no plan,
    InputError for a joint that cannot be given (the SRS class's q4)."""
    from derive.codegen.general6r import _arr, _lit
    from derive.codegen.templates import template_environment
    from derive.model.robot import load_robot
    robot = load_robot(robot)
    if free_joint.route(robot, joint) in PROGRAM_ROUTES:     # InputError for SRS q4
        return program_source(robot, joint)
    plans = c_plans(robot, joint)
    pl = plans[0]
    env = template_environment()
    core = env.get_template("general6r.c.j2")
    cores = []
    for i, p in enumerate(plans):
        text = core.render(ik={"general": _core_context(p, robot)})
        cores.append(re.sub(r"\bg6_", f"fj{i}_", text))
    # the width of the core's candidate rows (6 joints, and more where the core stores flags there)
    width = re.search(r"static int fj0_candidates\([^)]*\(\*DQ_RESTRICT cq\)\[(\d+)\]", cores[0])
    if width is None:
        raise DeriveError("free-joint C: the general 6R core's g6_candidates(pose, cq, degenerate) was not found")
    c7 = pl.c
    return env.get_template("free_joint.c.j2").render(
        robot=robot, k=joint, version=__version__, id=_identifier(robot, joint), cores=cores, cq_width=int(width.group(1)),
        plans=[{"notes": " ".join(p.notes.split()).replace("*/", "* /"), "reverse": bool(p.reverse), "e": int(p.e),
                "triple": g6._cut_joints(int(p.e))[0], "pair": g6._cut_joints(int(p.e))[1],
                "yh": None if _yc(p) is not None else _arr(triple_harmonics(p).reshape(7, 14, 27)),
                "y_const": None if _yc(p) is None else _arr(_yc(p)), "vb": _value_basis_context(p, robot)} for p in plans],
        # Newton's bound in the core clears a solution as regular (templates/free_joint.c.j2,
        # fj_singular_flags) where 108 x _NEWTON_CLEAR x G6_SINGULAR (its threshold, templates/
        # general6r.c.j2's G6_CLEAR in the runtime mode) leaves a margin of 10 over G6_NEAR_SINGULAR
        newton_clears=int(width.group(1)) >= 7 and 108 * _NEWTON_CLEAR * G6_SINGULAR >= 10 * G6_NEAR_SINGULAR,
        c7=_arr(np.reshape(c7, (8, 16))), scale=_lit(pl.scale), samples=[_lit(v) for v in g6._SAMPLES],
        sample_sc=_arr(np.stack([np.sin(g6._SAMPLES), np.cos(g6._SAMPLES)], 1)), k2inv=_arr(free_joint._KRON2_INV),
        accept=_lit(G6_ACCEPT), merge_tol=_lit(MERGE_TOL), singular=_lit(G6_SINGULAR), near_singular=_lit(G6_NEAR_SINGULAR),
        max_solutions=MAX_SOLUTIONS)


def _value_basis_context(pl: free_joint.Plan, robot):
    """The per-value deflation basis of a plan for templates/free_joint.c.j2 (its coefficients,
    degree and columns), where :func:`_deflation` uses it (the core's ``defl.runtime``), else None."""
    from derive.codegen.general6r import _arr
    ctx = _deflation(pl, robot)
    if not (ctx or {}).get("runtime"):
        return None
    vb = value_basis(pl)
    out = {"kind": vb.kind, "h": _arr(vb.h), "n": int(vb.n), "r": vb.r}
    if vb.kind == "pieces":
        # the pieces' coefficients one after the other, each to its own degree (its last nonzero
        # term: the others' zeros add nothing), none for a piece without a basis (degree -1)
        degrees = [int(np.max(np.nonzero(np.abs(h).reshape(len(h), -1).max(1))[0], initial=-1)) if on else -1
                   for h, on in zip(vb.h, vb.present)]
        flat = [h[:n + 1].reshape(-1) for h, n in zip(vb.h, degrees) if n >= 0]
        offsets = np.cumsum([0] + [len(f) for f in flat])
        starts = iter(offsets[:-1])
        out.update(pieces=len(vb.h), h=_arr(np.concatenate(flat)), size=int(offsets[-1]),
                   offsets=", ".join(str(int(next(starts))) if n >= 0 else "0" for n in degrees),
                   degrees=", ".join(str(n) for n in degrees))
    return out


def _load(text: str, ident: str, compile_fn):
    """(library path, ctypes library) of the C source ``text``: written once per source digest into
    the user cache's build folder ("free-joint"), compiled by ``compile_fn`` and loaded (compiled
    again once if it does not load)."""
    import hashlib
    from derive.cache import build_folder, writable_root, write_atomic
    folder = build_folder(writable_root()) / "free-joint"
    folder.mkdir(parents=True, exist_ok=True)
    src = folder / f"{ident}-{hashlib.sha256(text.encode()).hexdigest()[:16]}.c"
    if not src.exists() or src.read_text(encoding="utf-8") != text:
        write_atomic(src, text)
    path = compile_fn(src, ident)
    try:
        return path, ctypes.CDLL(str(path))
    except OSError as exc:
        path = compile_fn(src, ident, again=f"the C library {path} did not load ({exc})")
        return path, ctypes.CDLL(str(path))


def _address(a: np.ndarray) -> int:
    """The data address of a C-contiguous, non-empty array: through the buffer protocol (a third
    of the time of ``a.ctypes.data``) where the array is writable, else ``a.ctypes.data``."""
    try:
        return ctypes.addressof(ctypes.c_char.from_buffer(a))
    except TypeError:       # read-only
        return a.ctypes.data


class _CLibrary:
    """The compiled IK of one (arm, joint) on the general route, through ctypes. ``compile_fn``:
    (source path, prefix, again=None) -> shared library path, the C backend's compile step
    (:func:`derive.codegen.loader._compile`, passed in: the loader imports this module)."""

    def __init__(self, robot, joint: int, compile_fn):
        ident = _identifier(robot, joint)
        self.path, lib = _load(c_source(robot, joint), ident, compile_fn)
        f = getattr(lib, f"{ident}_ik_batch_free")
        f.argtypes = [ctypes.c_size_t] + [ctypes.c_void_p] * 6
        f.restype = None
        self._lib, self._f = lib, f

    def solve(self, poses, values):
        """(q (n, 16, 7) NaN-padded, counts (n,), singular (n, 16), degenerate (n,)) of poses (n, 8)
        with the joint at values (n,)."""
        poses = np.ascontiguousarray(poses, dtype=np.float64)
        values = np.ascontiguousarray(values, dtype=np.float64)
        n = len(poses)
        q = np.empty((n, MAX_SOLUTIONS, 7))
        ints = np.empty(n * (MAX_SOLUTIONS + 2), dtype=np.intc)     # counts, singular, degenerate
        counts, degen = ints[:n], ints[n:2 * n]
        sing = ints[2 * n:].reshape(n, MAX_SOLUTIONS)
        if n:
            iw = ctypes.sizeof(ctypes.c_int)
            at = _address(ints)
            self._f(n, _address(poses), _address(values), _address(q), at, at + 2 * n * iw, at + n * iw)
        return q, counts.astype(np.int64), sing.astype(bool), degen.astype(bool)


class _CProgram:
    """The compiled IK program of an SRS class route (:func:`program_source`), through ctypes; the
    calls of :class:`_CLibrary`, and :meth:`details` with the branch ids."""

    def __init__(self, robot, joint: int, compile_fn):
        ident = _identifier(robot, joint)
        text = program_source(robot, joint)
        self.path, lib = _load(text, ident, compile_fn)
        f = getattr(lib, f"{ident}_ik_batch_ex")
        f.argtypes = [ctypes.c_size_t] + [ctypes.c_void_p] * 6
        f.restype = None
        found = re.search(rf"#define {ident.upper()}_IK_MAX (\d+)", text)
        if found is None:
            raise DeriveError(f"{robot.name} with q{joint} given: the program's header has no "
                              f"{ident.upper()}_IK_MAX line (templates/kinematics.h.j2)")
        self.width = int(found.group(1))
        self._lib, self._f = lib, f

    def details(self, poses, values):
        """(q (n, 16, 7) NaN-padded, counts (n,), branch (n, 16) the class's branch ids (-1 in the
        padding), singular (n, 16)) of poses (n, 8) with the joint at values (n,)."""
        poses = np.ascontiguousarray(poses, dtype=np.float64)
        values = np.ascontiguousarray(values, dtype=np.float64)
        n, w = len(poses), self.width
        q = np.full((n, MAX_SOLUTIONS, 7), np.nan)
        branch = np.full((n, MAX_SOLUTIONS), -1, dtype=np.int64)
        sing = np.zeros((n, MAX_SOLUTIONS), dtype=bool)
        qw = np.empty((n, w, 7))
        ints = np.empty(n * (2 * w + 1), dtype=np.intc)      # counts, branch ids, singular flags
        counts = ints[:n]
        bw, sw = ints[n:n + n * w].reshape(n, w), ints[n + n * w:].reshape(n, w)
        if n:
            iw = ctypes.sizeof(ctypes.c_int)
            at = _address(ints)
            self._f(n, _address(poses), _address(values), _address(qw), at, at + n * iw,
                    at + (n + n * w) * iw)
        q[:, :w], branch[:, :w], sing[:, :w] = qw, bw, sw.astype(bool)
        return q, counts.astype(np.int64), branch, sing

    def solve(self, poses, values):
        """As :meth:`_CLibrary.solve`: (q, counts, singular, degenerate (n,) False: the closed form)."""
        q, counts, _, sing = self.details(poses, values)
        return q, counts, sing, np.zeros(len(q), dtype=bool)


def c_library(robot, joint: int, compile_fn) -> _CLibrary | _CProgram:
    """The compiled C IK of ``robot`` with ``joint`` given (once per process; the library is
    cached by source digest and compiler flags in the user cache's build folder): the class's IK
    program on the SRS class routes (:class:`_CProgram`), else the general elimination.
    ``compile_fn``: :func:`derive.codegen.loader._compile`."""
    from derive.model.robot import load_robot
    robot = load_robot(robot)
    if free_joint.route(robot, joint) in PROGRAM_ROUTES:
        return memo("free-joint-c-program", (robot.id, joint, compile_fn), lambda: _CProgram(robot, joint, compile_fn))
    return memo("free-joint-c", (robot.id, joint, compile_fn), lambda: _CLibrary(robot, joint, compile_fn))


class FreeJointKernels:
    """The kernels of a 7R arm whose IK takes the value of joint K (``free="qK"``)."""

    def __init__(self, robot, backend: str, joint: int, fk_kernels, compile_fn=None):
        self.robot = robot
        self.backend = backend
        self.dof = 7
        self.joint = joint
        #: the free parameter's name, as :attr:`derive.codegen.loader.Kernels.free`
        self.free = f"q{joint}"
        #: which solver holds the joint: "srs", "panda" or "general" (:func:`derive.ik.free_joint.route`)
        self.route = free_joint.route(robot, joint)
        self._c = None
        if self.route == "general":
            free_joint.plan(robot, joint)            # DeriveError now for a geometry it cannot solve
        if backend == "c":       # the class's IK program on the SRS class routes, else the general elimination
            if compile_fn is None:
                raise DeriveError("the C free-joint kernels need the C backend's compile step "
                                  "(derive.kernels passes it)")
            self._c = c_library(robot, joint, compile_fn)    # compiled on first use
        self._fk = fk_kernels
        self._tool = None

    def __getattr__(self, name):
        # fk, jacobian, ... of the backend's generated kernels (not the IK: defined below)
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self._fk, name)

    def __repr__(self) -> str:
        return f"<FreeJointKernels {self.robot.name} {self.backend} free=q{self.joint} ({self.route})>"

    @property
    def has_ik(self) -> bool:
        return True

    def with_tool(self, tool) -> "FreeJointKernels":
        """The same kernels for the end frame moved by a fixed tool transform (as
        :meth:`derive.codegen.loader.Kernels.with_tool`)."""
        import copy

        k = copy.copy(self)
        k._fk = self._fk.with_tool(tool)
        k._tool = k._fk._tool
        return k

    def fk(self, Q):
        return self._fk.fk(Q)

    def _poses(self, P):
        poses, single = as_pose_batch(P)
        if self._tool is not None:
            poses = dq._mul(poses, dq.conj_quaternion(self._tool)[None])
        return np.ascontiguousarray(poses, dtype=np.float64), single

    def _need(self, free):
        if free is None:
            lo, hi = free_joint.joint_range(self.robot, self.joint)
            raise InputError(f"{self.robot.name}: these kernels solve with joint {self.joint} given and need "
                             f"free= (q{self.joint}, rad, in [{lo:.4g}, {hi:.4g}]), a number or one per pose")

    def ik(self, P, within_limits: bool = False, details: bool = False, free=None):
        """Every solution with joint K held at ``free`` (rad, a number or one per pose):
        (solutions (n, 16, 7) NaN-padded, valid rows first, counts (n,)); one pose gives
        ((16, 7), count). ``details``: also (branch (n, 16): the class's branch ids, -1 on the
        general route (numpy and C); singular (n, 16)). ``within_limits``: every in-limit winding of each
        solution (:func:`derive.ik.select.within_limits`)."""
        self._need(free)
        poses, single = self._poses(P)
        sols, counts, branch, sing = self._solver(poses, redundant.free_values(free, len(poses)))
        if within_limits:
            sols, counts, branch, sing = select.within_limits(sols, counts, self.robot.limits, self.robot.revolute,
                                                              branch, sing)
        if single:
            sols, counts, branch, sing = sols[0], int(counts[0]), branch[0], sing[0]
        return (sols, counts, branch, sing) if details else (sols, counts)

    def _solver(self, poses, f):
        """(q, counts, branch, singular) of poses (m, 8) of the end frame at values f (m,): the C
        kernel on the "c" backend, else :func:`derive.ik.free_joint.solve`."""
        if isinstance(self._c, _CProgram):          # the class's program: its branch ids
            return self._c.details(poses, f)
        if self._c is not None:
            q, counts, sing, _ = self._c.solve(poses, f)
            branch = np.full((len(q), MAX_SOLUTIONS), -1, dtype=np.int64)     # no branch structure
            return q, counts, branch, sing
        r = free_joint.solve(self.robot, poses, self.joint, f)
        return r.q, r.counts, r.branch, r.singular

    def ik_degenerate(self, P, free=None) -> np.ndarray:
        """(n,) or a bool: the general elimination's degenerate flag of each pose at its value (the
        elimination degenerates for both plans or is unreliable there, or more than 16 solutions:
        those returned are checked, some may be missing; templates/free_joint.c.j2, fj_solve, and
        :func:`derive.ik.free_joint._general`): the C kernel's and the numpy reference's on the
        general route; False for the class's closed forms (every backend)."""
        self._need(free)
        poses, single = self._poses(P)
        f = redundant.free_values(free, len(poses))
        if self._c is not None:
            out = self._c.solve(poses, f)[3]
        elif self.route == "general":
            out = free_joint.solve(self.robot, poses, self.joint, f).degenerate
        else:
            out = np.zeros(len(poses), dtype=bool)
        return bool(out[0]) if single else out

    def ik_sweep(self, P, n: int, within_limits: bool = True) -> redundant.Sweep:
        """The solutions at ``n`` values of joint K over its range
        (:func:`derive.ik.free_joint.ik_sweep`)."""
        poses, single = self._poses(P)
        return free_joint.ik_sweep(self.robot, poses[0] if single else poses, self.joint, n,
                                   within_limits=within_limits,
                                   solver=self._solver if self._c is not None else None)

    def nearest(self, P, q_seed, tol=None) -> select.Nearest:
        """Per pose the solution nearest to the seed along a path, joint K chosen by the 1-D
        search of :func:`derive.ik.free_joint.nearest`."""
        poses, single = self._poses(P)
        return free_joint.nearest(self.robot, poses[0] if single else poses, self.joint, q_seed, tol=tol,
                                  solver=self._solver if self._c is not None else None)


def free_joint_kernels(robot, backend: str, joint: int, fk_kernels, compile_fn=None) -> FreeJointKernels:
    """:class:`FreeJointKernels`; the "c" backend on the SRS class routes (the class's IK
    program) and on the general route wherever the general elimination has a plan
    (:func:`derive.ik.free_joint.plan`; DeriveError where it has none).
    ``compile_fn``: the C backend's compile step (:func:`derive.codegen.loader._compile`)."""
    return FreeJointKernels(robot, backend, joint, fk_kernels, compile_fn)
