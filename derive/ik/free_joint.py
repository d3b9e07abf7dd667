"""Seven-joint arms with any one joint given: every IK solution of the remaining 6R (numpy
reference).

Holding joint K of a 7R arm at a value v leaves a 6R. Written in product form
``FK(q) = C1 Rz(q1) C2 Rz(q2) ... C7 Rz(q7) C8`` (:func:`chain7`, the same construction as
:func:`derive.ik.general6r.chain_form`: each C_i a constant 4x4 transform whose z axis is joint
i's axis, lengths divided by the arm's size), the held joint merges with its two neighbours
into one constant link, ``C_K Rz(v) C_{K+1}`` (:func:`locked_chain`): the 6R chain is the
7-link list with that product in place of C_K, C_{K+1}. For K = 1 or 7 the merged link is the
first or last one, so the 6R of the other joints is the same for every v and only the pose moves
(T' = (C1 Rz(v))^-1 ...); for a middle K two links of the loop change with v.

Routing (:func:`route`): where the held joint leaves a special class, that class's closed form
is used (the SRS class with joint 1, 3, 5 or 7 given: :func:`derive.ik.srs.ik_joint`; with
joint 2 or 6 given: :func:`_srs_joint2`, the same steps with the shoulder's subproblem solved
for t1, t3 at a given t2; the
Franka Panda class with joint 7 given: :func:`derive.ik.panda.ik_q7`); the SRS class's joint 4
fixes the shoulder-wrist distance (held, it leaves a one-parameter family or nothing), so it is
refused. Every other (arm, K) is solved as a general 6R by the loop-cut form of
:mod:`derive.ik.general6r` (Raghavan and Roth 1993, the 14 line equations; Manocha and Canny
1994, the 24 x 24 companion eigenproblem), with a **numeric per-value construction**: the
coefficients of both sides of the loop equations are fitted exactly per pose from 27 + 9 sample
angles (each side is multilinear in (sin, cos, 1) of its joints), so no symbolic derivation is
needed for any K and v. What is derived once per (arm, K) (:func:`plan`, cached) is only the
choice of the cut and the eigen-variable, checked on random configurations with random v
(:func:`derive.ik.general6r._check_cut`); it takes milliseconds. The numbers (docs/ik.md,
"Seven-joint arms with any joint given"): the per-value fit costs about as much as the
eigenproblem itself. The same elimination in C: :mod:`derive.codegen.free_joint`
(``derive.kernels(robot, "c", free="qK")``; on the SRS class routes that C is the class's IK
program, :func:`derive.ik.program7.srs_joint_program`).

Every candidate is polished by damped Newton steps on the 6R product form, checked on the 7R's
exact FK (:func:`derive.kinematics.fk.fk`, G6_ACCEPT), and near-duplicates merged (MERGE_TOL);
up to 16 solutions per pose and value.
"""

from __future__ import annotations

import itertools
import math
import re
import dataclasses
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from derive.algebra.angles import wrap_angle
from derive.cache import memo
from derive.errors import DeriveError, InputError
from derive.ik import finish, general6r as g6, panda, redundant, select, srs
from derive.ik.closed_form import IKSolutions
from derive.ik.tolerances import G6_ACCEPT, G6_NEAR_SINGULAR, G6_NEWTON_MAX, G6_RANK_TOL, G6_SINGULAR, TIE
from derive.kinematics.fk import _pose_error, fk
from derive.kinematics.pose import as_pose_batch
from derive.model.geometry import numeric_chain
from derive.model.robot import load_robot

#: Solutions per pose and value on the general route (a 6R has at most 16).
MAX_SOLUTIONS = 16
#: Poses per chunk of the general route (temporaries of about 60 KB per pose).
CHUNK = 1024


# --------------------------------------------------------------------------- #
# The chain and its locked 6R
# --------------------------------------------------------------------------- #
def chain7(robot):
    """(C (8, 4, 4), scale): FK(q) = C1 Rz(q1) ... C7 Rz(q7) C8 of a 7R arm, lengths divided by
    ``scale`` (the construction of :func:`derive.ik.general6r.chain_form` for seven joints)."""
    robot = load_robot(robot)
    return memo("free-joint-chain7", robot.id, lambda: _chain7(robot))


def _chain7(robot):
    chain = numeric_chain(robot)
    if chain.n != 7 or any(t != "revolute" for t in chain.types):
        raise InputError(f"{robot.name}: a joint is given for seven-joint revolute arms; this one has "
                         f"{chain.n} joints ({', '.join(sorted(set(chain.types)))})")
    points = chain.start + np.concatenate([np.zeros((1, 3)), np.cumsum(chain.links, axis=0)])
    scale = float(max(np.sum(np.linalg.norm(chain.links, axis=1)) + np.linalg.norm(chain.end_translation),
                      1e-9))
    frames = [g6._frame(chain.axes[i], points[i]) for i in range(7)]
    t0 = np.eye(4)
    t0[:3, :3] = chain.end_rotation
    t0[:3, 3] = points[7] + chain.end_translation
    cs = [frames[0]] + [g6._inv(frames[i - 1]) @ frames[i] for i in range(1, 7)] + [g6._inv(frames[6]) @ t0]
    c = np.array(cs)
    c[:, :3, 3] /= scale
    return c, scale


def locked_chain(c, k: int, v) -> np.ndarray:
    """The 6R chains (n, 7, 4, 4) of the 7R chain ``c`` (8, 4, 4) with joint ``k`` (1-based)
    held at the values ``v`` (n,): C_k Rz(v) C_{k+1} merged into one link."""
    v = np.atleast_1d(np.asarray(v, dtype=float))
    merged = c[k - 1] @ g6._rz(v) @ c[k]                                    # (n, 4, 4)
    out = np.empty((len(v), 7, 4, 4))
    out[:, :k - 1] = c[:k - 1]
    out[:, k - 1] = merged
    out[:, k:] = c[k + 1:]
    return out


# --------------------------------------------------------------------------- #
# Which solver a (robot, joint) uses
# --------------------------------------------------------------------------- #
def parse_joint(free) -> int | None:
    """K of a free-joint name "qK" (K = 1..7), else None."""
    m = re.fullmatch(r"q([1-7])", free) if isinstance(free, str) else None
    return int(m.group(1)) if m else None


def route(robot, joint: int) -> str:
    """"srs" (:func:`derive.ik.srs.ik_joint`), "srs-2" (:func:`_srs_joint2`, joint 2 or 6 of
    an SRS arm), "panda" (:func:`derive.ik.panda.ik_q7`) or
    "general" (the loop-cut general 6R of this module) for ``robot`` with ``joint`` given;
    InputError for a joint that cannot be given (not 1..7, or the SRS class's elbow)."""
    robot = load_robot(robot)
    if robot.dof != 7:
        raise InputError(f"free: {robot.name} has {robot.dof} joints; a joint is given only for "
                         "seven-joint arms")
    if isinstance(joint, bool) or not isinstance(joint, (int, np.integer)) or not 1 <= joint <= 7:
        raise InputError(f"free: the joint given must be one of q1 .. q7, got {joint!r}")
    kind = redundant.redundant_kind(robot)
    if kind == "srs":
        if joint == 4:
            raise InputError(f"free: {robot.name} is of the SRS class: joint 4 alone sets the "
                             "shoulder-wrist distance, so with q4 given a pose has a one-parameter "
                             "family of solutions or none; give another joint (q1, q2, q3, q5, q6, q7) "
                             "or the arm angle psi")
        if joint in srs.JOINTS_GIVEN:
            return "srs"
        return "srs-2"            # joint 2 or 6: _srs_joint2
    if kind == "panda" and joint == 7:
        return "panda"
    return "general"


@dataclass(frozen=True)
class Plan:
    """The general route of one (robot, joint): the 7R chain, the cut of the locked 6R's loop
    (e = 1 or 2, :func:`derive.ik.general6r._check_cut`), the eigen-variable, whether the 6R is
    solved reversed, and the Moebius offsets."""

    robot: str
    joint: int
    c: np.ndarray
    scale: float
    reverse: bool
    e: int
    ev: int
    offsets: np.ndarray
    d3: np.ndarray
    notes: str
    alt: "Plan | None" = None    # the rescue: another cut (or other offsets), see _general
    robot_id: str = ""           # the robot's identity (robot is its name): the caches' key


def plan(robot, joint: int) -> Plan:
    """The cut of the locked 6R of ``robot`` with ``joint`` held (cached per process): of
    (forward, reversed) x (cut at joint 1, 2 of the 6R), those whose equations hold and whose
    pencil is regular on random configurations at three random values of the held joint, the
    one with the fewest shared (multiple) roots, then the best conditioned. DeriveError
    when none is (special geometry)."""
    robot = load_robot(robot)
    out = memo("free-joint-plan", f"{robot.id}-q{joint}", lambda: _plan_or_error(robot, joint))
    if isinstance(out, DeriveError):
        raise out
    return out


def _plan_or_error(robot, joint):
    try:
        return _plan(robot, joint)
    except DeriveError as exc:
        return exc


def _plan(robot, joint):
    c, scale = chain7(robot)
    rng = np.random.default_rng(31 + joint)
    values = rng.uniform(-np.pi, np.pi, 3)
    why, options = [], []
    for reverse in (False, True):
        for e in (1, 2):
            evs, shared, worst = [], 0, float("inf")
            for v in values:
                d = locked_chain(c, joint, [v])[0]
                ok, info, extra = g6._check_cut(g6._reverse(d) if reverse else d, e)
                if not ok:
                    why.append(f"{'reversed' if reverse else 'forward'}, cut {e}: {info}")
                    break
                evs.append(extra["ev"])
                shared += int(re.search(r"(\d+) shared roots", info).group(1))
                worst = min(worst, float(re.search(r"singular value ([0-9.e+-]+)", info).group(1)))
            else:
                options.append((shared, -worst, reverse, e, max(set(evs), key=evs.count), info))
    if options:
        # the fewest multiple roots (a root shared by two solutions needs the slower path), then
        # the best conditioned pencil; the next option (else other offsets) is the rescue
        options.sort(key=lambda o: o[:2])
        rng = g6._seeded(robot.id)
        plans = []
        for shared, _, reverse, e, ev, info in (options * 2)[:2]:
            offsets = rng.uniform(-np.pi, np.pi, 3)
            plans.append(Plan(robot=robot.name, robot_id=robot.id, joint=joint, c=c, scale=scale, reverse=reverse, e=e, ev=ev,
                              offsets=offsets, d3=offsets[2] + np.array([0.0, 2.0, 4.0]),
                              notes=f"{'reversed' if reverse else 'forward'} 6R, cut at its joint {e}: {info} "
                                    f"({shared} shared roots over the 3 values)"))
        return dataclasses.replace(plans[0], alt=plans[1])
    raise DeriveError(f"{robot.name} with q{joint} given: the general 6R elimination degenerates for "
                      f"every cut ({'; '.join(why)}): special geometry that no class of dq-derive covers yet")


# --------------------------------------------------------------------------- #
# The general route: per-pose chains
# --------------------------------------------------------------------------- #
_KRON3_INV = np.linalg.inv(np.kron(np.kron(g6._BS, g6._BS), g6._BS))
_KRON2_INV = np.linalg.inv(np.kron(g6._BS, g6._BS))
_COMBOS3 = np.array(list(itertools.product(g6._SAMPLES, repeat=3)))
_COMBOS2 = np.array(list(itertools.product(g6._SAMPLES, repeat=2)))


def _links(d, target):
    """K_1..K_5 (n, 4, 4) and the pose link K_6 = C7 T^-1 C1 of per-pose chains d (n, 7, 4, 4)."""
    k = {j: d[:, j] for j in range(1, 6)}
    k[6] = d[:, 6] @ np.linalg.inv(target) @ d[:, 0]
    return k


def _coefs(d, e, target):
    """(triple (n, 14, 27), pair (n, 14, 9)): the coefficients of the two sides of the loop cut
    at joint e (:mod:`derive.ik.general6r`, "loop cut") per pose, fitted from sample angles."""
    (a, b, dd), (f, h) = g6._cut_joints(e)
    k = _links(d, target)
    rz3 = [g6._rz(_COMBOS3[:, i]) for i in range(3)]                         # (27, 4, 4)
    m = k[e][:, None]
    for i, j in enumerate((a, b, dd)):
        m = m @ rz3[i][None] @ k[j][:, None]
    vals = g6._line_eqs(np.linalg.inv(m))                                   # (n, 27, 14)
    y = np.swapaxes(_KRON3_INV @ vals, 1, 2)
    rz2 = [g6._rz(_COMBOS2[:, i]) for i in range(2)]
    p = (rz2[0][None] @ k[f][:, None]) @ (rz2[1][None] @ k[h][:, None])
    x = np.swapaxes(_KRON2_INV @ g6._line_eqs(p), 1, 2)
    return y, x


def _frames(d, q):
    """Frames before each joint's rotation (m, 6, 4, 4) and the end (m, 4, 4) of per-candidate
    chains d (m, 7, 4, 4) at q (m, 6)."""
    rz = g6._rz(q)
    a = d[:, 0].copy()
    out = []
    for i in range(6):
        if i:
            a = a @ d[:, i]
        out.append(a)
        a = a @ rz[:, i]
    return np.stack(out, 1), a @ d[:, 6]


def _errors(d, q, target):
    frames, end = _frames(d, q)
    dp = target[:, :3, 3] - end[:, :3, 3]
    rel = target[:, :3, :3] @ np.swapaxes(end[:, :3, :3], 1, 2)
    w = 0.5 * np.stack([rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0], rel[:, 1, 0] - rel[:, 0, 1]], 1)
    sn = np.linalg.norm(w, axis=1)
    ang = np.arctan2(sn, 0.5 * (np.trace(rel, axis1=1, axis2=2) - 1))
    fac = np.where(sn > 1e-12, ang / np.where(sn > 1e-12, sn, 1.0), 1.0)
    axes = frames[:, :, :3, 2]
    jac = np.concatenate([np.cross(axes, end[:, None, :3, 3] - frames[:, :, :3, 3]), axes], 2)
    return np.concatenate([dp, w * fac[:, None]], 1), jac.transpose(0, 2, 1)


def _newton(d, q, target):
    """Damped Newton steps on the product form (as :func:`derive.ik.general6r._newton`, per
    candidate chain), each candidate until its error is below 1e-13 or G6_NEWTON_MAX steps."""
    q = q.copy()
    idx = np.arange(len(q))
    for _ in range(G6_NEWTON_MAX):
        err, jac = _errors(d[idx], q[idx], target[idx])
        todo = np.max(np.abs(err), axis=1) > 1e-13
        idx, err, jac = idx[todo], err[todo], jac[todo]
        if len(idx) == 0:
            break
        jt = np.swapaxes(jac, 1, 2)
        a = jt @ jac
        lam = 1e-14 * (np.trace(a, axis1=1, axis2=2) + 1e-30)
        step_ = g6._solve_safe(a + lam[:, None, None] * np.eye(6), np.einsum("mij,mj->mi", jt, err))
        big = np.max(np.abs(step_), axis=1, keepdims=True)
        step_ = np.where(big > 0.5, step_ * (0.5 / np.maximum(big, 1e-300)), step_)
        new = q[idx] + step_
        q[idx] = np.where(np.isfinite(new), new, q[idx])
    return q


def _six(pl: Plan, d, target):
    """Candidates of the 6R chains d (n, 7, 4, 4) at targets (n, 4, 4) (scaled): (pose index
    (m,), q (m, 6) polished, degenerate (n,)); the loop-cut steps of
    :func:`derive.ik.general6r._solve_chunk_cut` with per-pose coefficients."""
    n = len(d)
    e, ev = pl.e, pl.ev
    triple, (f, h) = g6._cut_joints(e)
    y, x = _coefs(d, e, target)
    qq, rr = np.linalg.qr(x[:, :, :8], mode="complete")
    diag = np.abs(np.diagonal(rr[:, :8], axis1=1, axis2=2))
    degen = diag.min(axis=1) < G6_RANK_TOL * diag.max(axis=1)
    null = np.swapaxes(qq[:, :, 8:], 1, 2)
    yy = y.copy()
    yy[:, :, 26] -= x[:, :, 8]
    order = [ev] + [i for i in range(3) if i != ev]
    ten = np.moveaxis((null @ yy).reshape(n, 6, 3, 3, 3), [2 + i for i in order], [2, 3, 4])
    sig = (ten.reshape(n, 6, 3, 9) @ g6._t45(pl.offsets[0], pl.offsets[1])).transpose(0, 2, 1, 3)
    mats = g6._twelve(sig)
    # no deflation: the merged link changes with the held value, so no basis is kept per robot
    flat = SimpleNamespace(d3=pl.d3, deflate=None, deflate_keep=0, spurious=())
    d3, mk, lam, real, degen = g6._pencil_roots(flat, mats, degen)
    ip, ie = np.nonzero(real)
    if len(ip) == 0:
        return ip, np.zeros((0, 6)), degen
    x3 = lam[ip, ie].real
    v = g6._monomial_vectors(mk, ip, x3)
    qt, ym = g6.triple_angles(v, d3[ip] + 2 * np.arctan(x3), pl.offsets, order)
    rhs = np.einsum("mek,mk->me", yy[ip], ym)
    yv = np.einsum("mek,me->mk", qq[ip][:, :, :8], rhs)
    r8 = rr[ip, :8]
    ok8 = np.abs(np.diagonal(r8, axis1=1, axis2=2)) > G6_RANK_TOL * np.abs(r8).max(axis=(1, 2))[:, None]
    r8 = np.where(np.eye(8, dtype=bool) & ~ok8[:, :, None], 1.0, r8)
    x2 = g6._solve_safe(r8, yv)
    qc = np.zeros((len(ip), 6))
    for j, t in zip(triple, qt):
        qc[:, j - 1] = t
    qc[:, f - 1] = np.arctan2(x2[:, 2], x2[:, 5])
    qc[:, h - 1] = np.arctan2(x2[:, 6], x2[:, 7])
    # joint e from the rest: Rz(q_e) = (C1 Rz1 .. C_e)^-1 T (C_{e+1} Rz_{e+1} .. C7)^-1
    di = d[ip]
    frames, _ = _frames(di, qc)
    after = di[:, 6].copy()
    rz = g6._rz(qc)
    for j in range(6, e, -1):
        after = di[:, j - 1] @ rz[:, j - 1] @ after
    rel = np.linalg.inv(frames[:, e - 1]) @ target[ip] @ np.linalg.inv(after)
    qc[:, e - 1] = np.arctan2(rel[:, 1, 0], rel[:, 0, 0])
    return ip, _newton(di, qc, target[ip]), degen


@dataclass
class FreeJointSolutions(finish.Solutions):
    """:class:`derive.ik.finish.Solutions` (q (n, m, 7), ...; ``free`` the held joint's values)
    with ``degenerate`` (n,): the general route's pose is special for the elimination (Q of
    lower rank or the leading matrix ill-conditioned for every offset) or the elimination is
    unreliable there (an odd count, the rescue plan's set not the plan's, a solution whose
    Jacobian's smallest singular value over its largest is below G6_NEAR_SINGULAR): the solutions
    found are checked, but some may be missing (False on the class routes)."""

    degenerate: np.ndarray | None = None
    joint: int = 0


def _candidates(pl: Plan, poses, values):
    """(pose index (m,), candidates (m, 7), degenerate (n,)) of one plan."""
    n = len(poses)
    target = g6._to_matrix(poses)
    target[:, :3, 3] /= pl.scale
    d = locked_chain(pl.c, pl.joint, values)
    if pl.reverse:
        d = np.stack([g6._reverse(x) for x in d]) if n else d
        target = np.linalg.inv(target)
    ip, q6, degen = _six(pl, d, target)
    if pl.reverse:
        q6 = -q6[:, ::-1]
    return ip, np.insert(wrap_angle(q6), pl.joint - 1, values[ip], axis=1), degen


def _general(robot, pl: Plan, poses, values) -> FreeJointSolutions:
    """The general route: the plan's candidates, checked on the 7R's FK; where a pose looks
    incomplete (an odd number of solutions: the real roots of the eliminant come in pairs but
    for a root lost to rounding; a real eigenvalue whose candidate failed the check; two
    candidates that Newton took to one solution; no solution; the degenerate flag), the rescue
    plan's candidates (another cut, other offsets)
    are added; then merged and padded."""
    n = len(poses)
    k = pl.joint
    ip, q7, degen = _candidates(pl, poses, values)
    cand = _grid(ip, q7, n)
    ok, _ = _check(robot, poses, cand)
    dup = finish.duplicates(cand, ok)
    count = (ok & ~dup).sum(1)
    suspect = ((count % 2 == 1) | (count == 0) | degen | np.any(dup, 1)
               | np.any(np.all(np.isfinite(cand), -1) & ~ok, 1))
    disagree = np.zeros(n, dtype=bool)
    if pl.alt is not None and np.any(suspect):
        rows = np.nonzero(suspect)[0]
        ip2, q72, degen2 = _candidates(pl.alt, poses[rows], values[rows])
        cand2 = _grid(ip2, q72, len(rows))
        ok2, _ = _check(robot, poses[rows], cand2)
        disagree[rows] = (ok2 & ~finish.duplicates(cand2, ok2)).sum(1) != count[rows]
        ip, q7 = np.concatenate([ip, rows[ip2]]), np.concatenate([q7, q72])
        order = np.argsort(ip, kind="stable")
        ip, q7 = ip[order], q7[order]
        degen[rows] &= degen2
    cand = _grid(ip, q7, n)
    # check on the exact FK of the 7R, merge, pad
    ok, residual = _check(robot, poses, cand)
    dup = finish.duplicates(cand, ok)
    keep = ok & ~dup
    sing = np.zeros(ok.shape, dtype=bool)
    near = np.zeros(ok.shape, dtype=bool)
    if np.any(keep):
        sing[keep], near[keep] = _singular(pl, locked_chain(pl.c, k, values[np.nonzero(keep)[0]]),
                                           np.delete(cand[keep], k - 1, axis=1), (G6_SINGULAR, G6_NEAR_SINGULAR))
    q, counts, _, sing, res = finish.compact(cand, keep, sing, residual)
    # unreliable (templates/free_joint.c.j2 on the general route, the same rule): an odd count (the
    # real solutions come in pairs but for a lost root), the rescue plan's set not the plan's, a
    # solution near the singular set (two solutions nearly merged, one can be lost)
    degen = degen | (counts % 2 == 1) | disagree | np.any(near, 1)
    q, sing, res = q[:, :MAX_SOLUTIONS], sing[:, :MAX_SOLUTIONS], res[:, :MAX_SOLUTIONS]
    over = counts > MAX_SOLUTIONS
    degen = degen | over
    counts = np.minimum(counts, MAX_SOLUTIONS)
    if q.shape[1] < MAX_SOLUTIONS:
        pad = MAX_SOLUTIONS - q.shape[1]
        q = np.concatenate([q, np.full((n, pad, 7), np.nan)], 1)
        sing = np.concatenate([sing, np.zeros((n, pad), dtype=bool)], 1)
        res = np.concatenate([res, np.full((n, pad), np.nan)], 1)
    branch = np.full((n, MAX_SOLUTIONS), -1, dtype=np.int64)
    reason = np.array(["" if c_ else f"unreachable with q{k} given: no real root of the eliminant "
                       "reproduces the pose" for c_ in counts], dtype=object)
    return FreeJointSolutions(q=q, counts=counts, branch=branch, singular=sing, residual=res, reason=reason,
                              free=values.copy(), degenerate=degen, joint=k)


def _grid(ip, q7, n):
    """Candidates (m, 7) of the poses ip (sorted) as (n, width, 7), NaN-padded."""
    cand = np.full((n, max(int(np.bincount(ip, minlength=n).max(initial=0)), 1), 7), np.nan)
    rank = np.arange(len(ip)) - np.searchsorted(ip, ip)
    cand[ip, rank] = q7
    return cand


def _check(robot, poses, cand):
    """(ok, residual) of candidates (n, m, 7) on the exact FK within G6_ACCEPT."""
    n, m, _ = cand.shape
    valid = np.all(np.isfinite(cand), axis=-1)
    ok = np.zeros((n, m), dtype=bool)
    residual = np.full((n, m), np.nan)
    if np.any(valid):
        dp, dr = _pose_error(fk(robot, cand[valid]), np.repeat(poses[:, None], m, 1)[valid])
        ok[valid] = (dp < G6_ACCEPT) & (dr < G6_ACCEPT)
        residual[valid] = np.maximum(dp, dr)
    return ok, residual


def _singular(pl, d, q6, tols=(G6_SINGULAR,)):
    """Whether the 6R Jacobian (chains d, joints q6 of the locked 6R) is rank-deficient
    (relative smallest singular value below G6_SINGULAR), or a tuple: below each of tols."""
    _, jac = _errors(d, q6, np.broadcast_to(np.eye(4), (len(q6), 4, 4)))
    ev = np.linalg.eigvalsh(np.swapaxes(jac, 1, 2) @ jac)
    out = tuple(ev[:, 0] < t ** 2 * ev[:, -1] for t in tols)
    return out if len(tols) > 1 else out[0]


# --------------------------------------------------------------------------- #
# The SRS class with joint 2 or 6 given
# --------------------------------------------------------------------------- #
def _joint2_steps(geo, rc, w, t2, free1, free3, free5):
    """Canonical angles (n, 8, 7), singular (n, 8), root exists (n, 8) of the SRS chain with
    canonical t2 given (the steps of :func:`derive.ik.srs.joint_given_steps`): the elbow t4 from
    the shoulder-wrist distance (two signs); then Rz(t1) Ry(t2) Rz(t3) v(t4) = W, v = (v_x, 0,
    v_z): its z row -sin t2 cos t3 v_x + cos t2 v_z = W_z gives cos t3 (two roots; t3 free where
    sin t2 v_x = 0: axes 1 and 3 in line, or the elbow stretched), its x-y rows
    t1 = atan2(W_y, W_x) - atan2(u_y, u_x), u = Ry(t2) Rz(t3) v (t1 free where W lies on axis 1);
    the wrist by the ZYZ decomposition of (R_s Ry(t4))^T R (two signs)."""
    n = len(w)
    theta = np.full((n, 8, 7), np.nan)
    singular = np.zeros((n, 8), dtype=bool)
    reach_all = np.zeros((n, 8), dtype=bool)
    c4 = srs.elbow_cosine(geo, w)
    ok = np.abs(c4) <= 1.0 + srs.REACH_TOL
    t4s = srs.elbow(geo, w, c4)                 # the two elbow roots, as srs.ik_joint orders them
    s2, c2 = np.sin(t2), np.cos(t2)
    on_axis = np.hypot(w[:, 0], w[:, 1]) < srs.AXIS_TOL
    for i4 in range(2):
        t4 = t4s[:, i4]
        v = srs._forearm(geo, t4)
        den = s2 * v[:, 0]
        num = c2 * v[:, 2] - w[:, 2]
        flat = np.abs(den) < srs.WRIST_SINGULAR * max(geo.d_ew, 1.0)
        c3 = num / np.where(flat, 1.0, den)
        reach = ok & np.where(flat, np.abs(num) <= srs.REACH_TOL, np.abs(c3) <= 1.0 + srs.REACH_TOL)
        a3 = np.arccos(np.clip(c3, -1.0, 1.0))
        for i, t3 in enumerate((np.where(flat, free3, a3), np.where(flat, free3, -a3))):
            a = np.stack([np.cos(t3) * v[:, 0], np.sin(t3) * v[:, 0], v[:, 2]], -1)
            u = (srs.rot_y(t2) @ a[..., None])[..., 0]
            t1 = np.where(on_axis, free1, np.arctan2(w[:, 1], w[:, 0]) - np.arctan2(u[:, 1], u[:, 0]))
            rw = srs._t(srs.zyz_matrix(t1, t2, t3) @ srs.rot_y(t4)) @ rc
            for i6, g6 in enumerate((1.0, -1.0)):
                t5, t6, t7, sing_w = srs.zyz(rw, g6, free5)
                k = 4 * i + 2 * i4 + i6
                th = np.stack([t1, t2, t3, t4, t5, t6, t7], -1)
                theta[reach, k] = th[reach]
                singular[:, k] = reach & (flat | on_axis | sing_w)
                reach_all[:, k] = reach
    return theta, singular, reach_all


def _srs_joint2(robot, poses, joint, values, q_ref):
    """All solutions (up to 8) of an SRS arm with joint 2 or 6 given (joint 6 is joint 2 of the
    reversed chain, :func:`derive.ik.srs._reverse`); the finish step of :mod:`derive.ik.srs`.
    Branch id 4 i + 2 i4 + i6: i the root of cos t3 (cos t5 for joint 6), i4 the elbow sign, i6
    the sign of the Euler decomposition solved last (first for joint 6)."""
    geo = srs.srs_geometry(robot)
    n = len(poses)
    rc, w = srs._into_canonical(geo, poses)
    reason = np.full(n, "", dtype=object)
    bad = np.abs(srs.elbow_cosine(geo, w)) > 1.0 + srs.REACH_TOL
    reason[bad] = srs.REASON_REACH
    tg = geo.signs[joint - 1] * values
    fr = np.zeros((n, 7)) if q_ref is None else q_ref * geo.signs
    if joint == 2:
        theta, singular, reach = _joint2_steps(geo, rc, w, tg, fr[:, 0], fr[:, 2], fr[:, 4])
    else:
        rgeo, rrc, rw = srs._reverse(geo, rc, w)
        phi, singular, reach = _joint2_steps(rgeo, rrc, rw, -tg, fr[:, 6], fr[:, 4], fr[:, 2])
        theta = phi[..., ::-1] * np.array([1.0, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0])
        flip = np.array([k ^ 2 for k in range(8)])
        theta, singular = theta[:, flip], singular[:, flip]
    cand = np.where(bad[:, None, None], np.nan, wrap_angle(theta * geo.signs))
    reason[~np.any(reach, 1) & (reason == "")] = srs.REASON_JOINT
    return srs._finish(robot, geo, rc, w, poses, cand, singular & ~bad[:, None], reason, values)


# --------------------------------------------------------------------------- #
# Public interface
# --------------------------------------------------------------------------- #
def _joint_values(free, n):
    return redundant.free_values(free, n)


def solve(robot, poses, joint: int, free, q_ref=None, chunk: int = CHUNK) -> FreeJointSolutions:
    """Every IK solution of poses (8,) / (n, 8) or (4, 4) / (n, 4, 4) of a 7R arm's end frame
    with joint ``joint`` (1-based) held at ``free`` (rad, a number or one per pose): the class's
    closed form where one applies (:func:`route`), else the general 6R of the module docstring
    (up to 16 solutions). ``q_ref``: the joints a singular set leaves free on the class routes.
    Joint values wrapped to (-pi, pi] (the held joint as given); limits not applied."""
    robot = load_robot(robot)
    how = route(robot, joint)
    P, _ = as_pose_batch(poses)
    n = len(P)
    f = _joint_values(free, n)
    qr = None if q_ref is None else redundant._q_ref(q_ref, n)
    if how == "srs":
        r = srs.ik_joint(robot, P, joint, f, q_ref=qr)
    elif how == "srs-2":
        r = _srs_joint2(robot, P, joint, f, qr)
    elif how == "panda":
        r = panda.ik_q7(robot, P, f, q_ref=qr)
    else:
        pl = plan(robot, joint)
        parts = [_general(robot, pl, P[s:s + chunk], f[s:s + chunk]) for s in range(0, max(n, 1), chunk)]
        if len(parts) == 1:
            return parts[0]
        fields = ("q", "counts", "branch", "singular", "residual", "reason", "free", "degenerate")
        return FreeJointSolutions(**{k: np.concatenate([getattr(p, k) for p in parts]) for k in fields},
                                  joint=joint)
    return FreeJointSolutions(q=r.q, counts=r.counts, branch=r.branch, singular=r.singular,
                              residual=r.residual, reason=r.reason, free=f.copy(),
                              degenerate=np.zeros(n, dtype=bool), joint=joint)


def ik_batch(robot, poses, joint: int, free, q_ref=None, details: bool = False):
    """(solutions (n, m, 7) NaN-padded, counts (n,)) with joint ``joint`` held at ``free``
    (:func:`solve`); ``details``: also (branch (n, m), singular (n, m)); branch ids are -1 on the
    general route (no branch structure)."""
    r = solve(robot, poses, joint, free, q_ref)
    return (r.q, r.counts, r.branch, r.singular) if details else (r.q, r.counts)


def ik(robot, pose, joint: int, free, q_ref=None, within_limits: bool = False, sort_by=None):
    """Every solution (k, 7) of one pose with joint ``joint`` held at ``free`` (a number), as a
    :class:`derive.ik.redundant.RedundantIKSolutions` (``.singular``, ``.reason``, ``.branch``,
    ``.free``); ``within_limits`` and ``sort_by`` as in :func:`derive.ik.closed_form.ik`."""
    robot = load_robot(robot)
    P, single = as_pose_batch(pose)
    if not single:
        raise InputError("pose: ik() takes one pose; use ik_batch() for several")
    f = _joint_values(free, 1)
    r = solve(robot, P, joint, f, q_ref)
    k = int(r.counts[0])
    sols, sing, br, reason = finish.select_one(robot, r.q[0, :k], r.singular[0, :k], r.branch[0, :k],
                                               r.reason[0], within_limits, sort_by)
    return redundant.RedundantIKSolutions(sols.reshape(-1, 7), sing, reason, br, f[0])


def joint_range(robot, joint: int) -> tuple[float, float]:
    """The held joint's range: its limits, (-pi, pi) where they are wider than a turn or missing."""
    robot = load_robot(robot)
    lo, hi = (float(x) for x in robot.limits[joint - 1])
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi - lo >= 2 * math.pi:
        return -math.pi, math.pi
    return lo, hi


def ik_sweep(robot, poses, joint: int, n: int, q_ref=None, within_limits: bool = True,
             solver=None) -> redundant.Sweep:
    """The solutions of P poses at ``n`` values of joint ``joint`` evenly over its range
    (:func:`joint_range`, the ends included: (k + 1/2) / n of it for a full turn), as a
    :class:`derive.ik.redundant.Sweep`. ``within_limits`` (default): only the solutions inside
    the joint limits, each at its in-limit winding. ``solver(poses (m, 8), free (m,))`` ->
    (q, counts, branch, singular) replaces :func:`solve` (the kernels)."""
    robot = load_robot(robot)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise InputError(f"n: expected a positive integer, got {n!r}")
    route(robot, joint)
    P, single = as_pose_batch(poses)
    m = len(P)
    lo, hi = joint_range(robot, joint)
    full = (lo, hi) == (-math.pi, math.pi)
    grid = lo + (hi - lo) * ((np.arange(n) + 0.5) / n if full or n == 1 else np.arange(n) / (n - 1))
    values = np.broadcast_to(grid, (m, n)).copy()
    pp = np.repeat(P, n, axis=0)
    fv = values.reshape(-1)
    if solver is None:
        qr = None if q_ref is None else np.repeat(redundant._q_ref(q_ref, m), n, axis=0)
        r = solve(robot, pp, joint, fv, qr)
        sq, sc, sb, sg = r.q, r.counts, r.branch, r.singular
    else:
        sq, sc, sb, sg = solver(pp, fv)
    if within_limits:
        sq, sc, sb, sg = select.within_limits(sq, sc, robot.limits, [True] * 7, branch=sb, singular=sg)
    k = sq.shape[1]
    out = redundant.Sweep(values, sq.reshape(m, n, k, 7), np.asarray(sc).reshape(m, n),
                          np.asarray(sb).reshape(m, n, k), np.asarray(sg, dtype=bool).reshape(m, n, k))
    return redundant.Sweep(*(x[0] for x in out)) if single else out


# --------------------------------------------------------------------------- #
# Nearest along a path
# --------------------------------------------------------------------------- #
class _Problem:
    """The solutions at free values per pose, reduced to the one nearest to the seed: the
    general route has no branch ids, so the path is followed by the least move at each value
    (the 'branch' of :func:`derive.ik.redundant._refine` is ignored)."""

    def __init__(self, robot, joint, poses, seeds, solver):
        self.robot, self.joint, self.poses, self.seeds = robot, joint, poses, seeds
        self.lo, self.hi = robot.limits[:, 0], robot.limits[:, 1]
        self.solver = solver

    def solutions(self, rows, f):
        if self.solver is not None:
            q, counts, branch, singular = self.solver(self.poses[rows], f)
            return q, np.asarray(singular, dtype=bool), np.asarray(branch)
        r = solve(self.robot, self.poses[rows], self.joint, f, self.seeds[rows])
        return r.q, r.singular, r.branch

    def best(self, rows, f):
        """Per row the solution nearest to the seed at f: (winding (r, 7), largest, summed,
        summed squared move, singular, branch); inf moves where none is inside the limits."""
        q, sing, branch = self.solutions(rows, f)
        s = self.seeds[rows][:, None, :]
        w = select.nearest_windings(q, s, self.lo, self.hi)
        ok = np.all(np.isfinite(w), axis=-1)
        move = np.where(ok[..., None], np.abs(w - s), np.inf)
        mx, tot, sq = move.max(-1), move.sum(-1), (move * move).sum(-1)
        j = np.lexsort((tot, mx), axis=-1)[:, 0] if q.shape[1] else np.zeros(len(rows), dtype=int)
        k = np.arange(len(rows))
        if q.shape[1] == 0:
            inf = np.full(len(rows), np.inf)
            return np.full((len(rows), 7), np.nan), inf, inf, inf, np.zeros(len(rows), bool), np.full(len(rows), -1)
        return w[k, j], mx[k, j], tot[k, j], sq[k, j], sing[k, j], branch[k, j]

    def branch_key(self, rows, f, _branch):
        _, mx, tot, sq, _, _ = self.best(rows, f)
        return mx, tot, sq


def nearest(robot, poses, joint: int, q_seed, tol=None, solver=None) -> select.Nearest:
    """Per pose the solution nearest to the seed along a path with joint ``joint`` chosen by the
    1-D search of :func:`derive.ik.redundant.nearest` (the seed's own q_K and offsets around it,
    a scan of the joint's range, then grid refinement of the least largest move and the least
    summed squared move within (1 + SLACK) of it), following at each value the solution nearest
    to the seed (the general route has no branch ids). The record of
    :func:`derive.ik.select.nearest`; ``q_seed`` (7,) or (n, 7); one pose and one seed give
    scalars. ``solver`` as in :func:`ik_sweep`."""
    robot = load_robot(robot)
    route(robot, joint)
    P, seeds, single = redundant.nearest_inputs(poses, q_seed, tol)
    n = len(P)
    prob = _Problem(robot, joint, P, seeds, solver)
    lo, hi = (float(x) for x in robot.limits[joint - 1])
    flo, fhi = (lo, hi) if math.isfinite(lo) and math.isfinite(hi) else (-math.pi, math.pi)
    rows = np.arange(n)
    # 1. the seed's own value, offsets around it, and a scan of the range
    f0 = np.clip(seeds[:, joint - 1], flo, fhi)
    grid = flo + (fhi - flo) * (np.arange(redundant.SCAN) + 0.5) / redundant.SCAN
    vals = np.concatenate([np.clip(f0[:, None] + redundant._ALL, flo, fhi),
                           np.broadcast_to(grid, (n, redundant.SCAN))], axis=1)
    m = vals.shape[1]
    rr = np.repeat(rows, m)
    _, mx, tot, _, _, _ = prob.best(rr, vals.reshape(-1))
    mx, tot = mx.reshape(n, m), tot.reshape(n, m)
    col = np.lexsort((tot, mx), axis=-1)[:, 0]
    start, best_mx, best_tot = vals[rows, col], mx[rows, col], tot[rows, col]
    local = col < len(redundant._ALL)
    c_ = np.minimum(col, len(redundant._ALL) - 1)
    lo_off = np.where(local, redundant._LOWER[c_], -(fhi - flo) / redundant.SCAN)
    hi_off = np.where(local, redundant._UPPER[c_], (fhi - flo) / redundant.SCAN)
    live = np.isfinite(best_mx)
    best_f = start.copy()
    at = rows[live]
    dummy = np.zeros(len(at), dtype=int)
    if len(at):
        with np.errstate(invalid="ignore"):
            f, m_, _ = redundant._refine(prob, "panda", at, start[at] + lo_off[at], start[at] + hi_off[at],
                                         dummy, start[at], best_mx[at], best_tot[at], flo, fhi,
                                         lambda mx_, tot_, sq_: (mx_, tot_))
            if redundant.SLACK > 0:
                bound = (1.0 + redundant.SLACK) * m_
                reach = np.minimum(redundant.WIDE * bound, math.pi)
                _, _, sq0 = prob.branch_key(at, f, dummy)
                f, _, _ = redundant._refine(prob, "panda", at, f - reach, f + reach, dummy, f,
                                            np.zeros(len(at)), sq0, flo, fhi,
                                            lambda mx_, tot_, sq_: (np.maximum(mx_ - bound[:, None], 0.0), sq_))
        best_f[at] = f
    q = np.full((n, 7), np.nan)
    mx_out, tot_out = np.full(n, np.inf), np.full(n, np.inf)
    br_out, sg_out = np.full(n, -1, dtype=np.int64), np.zeros(n, dtype=bool)
    if len(at):
        w, mx, tot, _, sg, br = prob.best(at, best_f[at])
        ok = np.isfinite(mx)
        q[at[ok]], mx_out[at[ok]], tot_out[at[ok]] = w[ok], mx[ok], tot[ok]
        br_out[at[ok]], sg_out[at[ok]] = br[ok], sg[ok]
    return redundant.nearest_record(q, mx_out, tot_out, br_out, sg_out, tol, single, slack=TIE)


__all__ = ["chain7", "locked_chain", "parse_joint", "route", "plan", "solve", "ik_batch", "ik",
           "joint_range", "ik_sweep", "nearest", "FreeJointSolutions", "IKSolutions"]
