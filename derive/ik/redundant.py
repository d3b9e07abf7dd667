"""Seven-joint arms with one free parameter: one interface over the two closed forms, the sweep
of the free parameter, and the nearest solution along a path.

Two classes of 7R arm are solved in closed form once one parameter is fixed:

* the Franka Panda class (Panda, FR3; :mod:`derive.ik.panda`): the free parameter is joint 7,
  ``q7`` (after He & Liu, ICCCR 2021), its range the joint's limits;
* the SRS class (KUKA LBR iiwa 7 and 14; :mod:`derive.ik.srs`): the free parameter is the arm
  angle ``psi`` (Shimizu et al., IEEE T-RO 24(5), 2008, sec. III), the rotation of the arm plane
  about the shoulder-wrist line, periodic in [-pi, pi).

With the free parameter given, a pose has up to 8 solutions. :func:`solve` returns them in one
shape for both classes (:class:`Solutions`): NaN-padded rows (valid rows first), counts, branch
ids (:func:`branch_labels` says what their bits choose), singular flags and reasons, as the 6R
path (:func:`derive.ik.closed_form.ik_batch`, the kernels' ``ik(..., details=True)``) gives them.

:func:`ik_sweep` evaluates n values of the free parameter over its feasible range (q7: its joint
limits; psi: the union of the branches' feasible intervals under the joint limits,
:func:`derive.ik.srs.psi_intervals`, computed from the closed form's breakpoints, not sampled).

:func:`nearest` chooses the free parameter and the branch for a seed configuration by a 1D
search that keeps a path continuous. Every move below is that of a joint at its winding nearest
to the seed inside the limits, as in :func:`derive.ik.select.nearest`; the largest move is the
largest of the seven, the summed move their sum, the summed squared move the sum of their squares.

1. start at the seed's own free value f0 (its q7, or its arm angle :func:`derive.ik.srs.arm_angle`):
   evaluate every branch at f0, at f0 +- 1e-4, 3e-4, ..., 0.1, 0.3 (near a singular set the
   solutions turn fast with the free parameter, so f0 alone can be far off) and at 32 values
   over the range, and take the (value, branch) whose solution moves least from the seed
   (largest move, then summed move); along a path that is the seed's branch near f0, within
   about one step;
2. refine the value on that branch between the neighbours of the start in its set to the least
   largest move M (then the least summed move): successive grid refinement, 31 values per step
   and the bracket narrowed to the neighbours of the best value, down to FREE_TOL (a parallel
   form of golden-section search, J. Kiefer, "Sequential minimax search for a maximum",
   Proc. AMS 4, 1953; each step is one batched evaluation of the closed form, which costs about
   what one value costs);
3. on the same branch, take the value with the least summed squared move among the values whose
   largest move is at most (1 + SLACK) M, SLACK = 0.5 (the same refinement of the key (the
   excess of the largest move over (1 + SLACK) M, clipped at 0; then the summed squared move)
   on WIDE = 4 times (1 + SLACK) M either side of the value of step 2). The least largest move
   alone is not enough on a path: it is reached where two joints' moves are equal, a kink that
   takes the free value a little off the path's own at every step, and these errors add up to a
   drift along the self-motion (on a test trajectory of the Panda 0.6 rad of q7, into sin q2 = 0
   where two branches meet); the least summed squared move (the minimum-norm step) drifts less
   (by about a third on the test trajectories) and, on them, stays on the generating branch;
4. the chosen branch at the chosen value is checked by the class's FK (else the nearest of the
   FK-checked solutions there, by largest move then summed move, is taken).

The result is the same :class:`derive.ik.select.Nearest` record as the 6R path's; its largest
move is at most (1 + SLACK) times the least over the self-motion near the seed (so, for a seed
near a solution q, at most 1.5 times q's). The answer is the nearest solution *along the path*:
a local minimum of the move, not a global search over the whole self-motion; a path can still
drift along the self-motion, less than with the largest move alone.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from derive.algebra import dualquat as dq
from derive.algebra import quaternion as quat
from derive.cache import memo
from derive.errors import DeriveError, InputError, as_finite_array
from derive.ik import classes, finish, panda, select, srs
from derive.ik.closed_form import IKSolutions
from derive.ik.tolerances import FREE_TOL, TIE
from derive.kinematics.pose import as_pose_batch
from derive.model.robot import load_robot

TWO_PI = 2.0 * math.pi
#: Branches per value of the free parameter (both classes).
BRANCHES = 8
#: Values of the free parameter over its range in the first scan (nearest, step 1).
SCAN = 32
#: Offsets (rad) from the seed's free value tried first, both signs: near a singular set the
#: solutions turn fast with the free parameter, so the seed's own value alone can be far off.
_OFFSETS = np.array([1e-4, 3e-4, 1e-3, 3e-3, 1e-2, 3e-2, 0.1, 0.3])
_ALL = np.concatenate([[0.0], -_OFFSETS[::-1], _OFFSETS])
_SORTED = np.sort(_ALL)
#: Per tried offset: the distance down and up to its neighbours (the first bracket); 0.6 rad
#: beyond the ends.
_LOWER = np.array([(_SORTED[max(np.searchsorted(_SORTED, x) - 1, 0)] - x) or -2 * _OFFSETS[-1]
                   for x in _ALL])
_UPPER = np.array([(_SORTED[min(np.searchsorted(_SORTED, x) + 1, len(_ALL) - 1)] - x)
                   or 2 * _OFFSETS[-1] for x in _ALL])
#: Values per step of the refinement (the bracket narrows by (REFINE + 1) / 2 per step).
REFINE = 31
#: nearest, step 3: the largest move may exceed the least by this fraction, so that the summed
#: squared move decides (the least largest move alone drifts along the self-motion on a path).
#: 0 gives the least largest move itself (then a seed q + c, the same c in every joint, returns
#: q exactly where moving along the self-motion moves some joint more).
SLACK = 0.5
#: nearest, step 3: the bracket searched, WIDE x that bound either side of the value of the
#: least largest move. For the Panda class every value within the bound is within 2 x the bound
#: of it (q7 is a joint, so |q7 - the seed's q7| is at most the bound at both).
WIDE = 4.0

#: What the bits of a branch id choose, most significant first.
LABELS = {
    "panda": ["elbow q4 root (eq. E2, + / -)", "wrist q6 root (eq. W2, + / -)",
              "shoulder sign of sin q2 (+ / -)"],
    "srs": ["shoulder GC2 = sign of sin q2 (+ / -)", "elbow GC4 = sign of theta4 = s4 q4 (+ / -)",
            "wrist GC6 = sign of sin q6 (+ / -)"],
}
NAMES = {"panda": "q7", "srs": "psi"}
CLASS_NAMES = {"panda": "Franka Panda class", "srs": "SRS class (arm angle)"}


#: The result of :func:`solve`: the one result type of all classes
#: (:class:`derive.ik.finish.Solutions`; ``free`` the value of the free parameter used).
Solutions = finish.Solutions


class Sweep(NamedTuple):
    """:func:`ik_sweep` of P poses at n values: ``free`` (P, n) the values (NaN where a pose has
    no feasible value), ``q`` (P, n, M, 7) NaN-padded solutions, ``counts`` (P, n), ``branch``
    (P, n, M), ``singular`` (P, n, M). M = 8, or more when ``within_limits`` finds more windings."""

    free: np.ndarray
    q: np.ndarray
    counts: np.ndarray
    branch: np.ndarray
    singular: np.ndarray


class RedundantIKSolutions(IKSolutions):
    """:class:`derive.ik.closed_form.IKSolutions` (k, 7) of one pose with ``branch`` (k,) and the
    value ``free`` of the free parameter (its name: :func:`free_parameter`)."""

    _ROW_ATTRS = ("singular", "branch")

    def __new__(cls, q, singular, reason="", branch=None, free=float("nan")):
        obj = IKSolutions.__new__(cls, q, singular, reason)
        obj.branch = np.full(len(obj), -1) if branch is None else np.asarray(branch, dtype=np.int64)
        obj.free = float(free)
        return obj

    def __array_finalize__(self, obj):
        super().__array_finalize__(obj)
        if obj is not None:
            self.branch = getattr(obj, "branch", None)
            self.free = getattr(obj, "free", float("nan"))


# --------------------------------------------------------------------------- #
# The class of a robot and its free parameter
# --------------------------------------------------------------------------- #
def redundant_kind(robot) -> str | None:
    """"panda" (Franka Panda class), "srs" (SRS class with the arm angle) or None."""
    robot = load_robot(robot)
    if robot.dof != 7:
        return None
    return memo("redundant-kind", robot.id, lambda: _find_kind(robot))


def _find_kind(robot) -> str | None:
    """The 7R class of :func:`derive.ik.classes.detect` (the Panda class before SRS)."""
    hit = classes.detect(robot, dof=7)
    return None if hit is None else hit[0].name


def _kind(robot) -> str:
    kind = redundant_kind(robot)
    if kind is None:
        reasons = []
        for test in (panda.panda_geometry, srs.srs_geometry):
            try:
                test(robot)
            except DeriveError as exc:
                reasons.append(str(exc).split(": ", 1)[-1])
        raise InputError(f"{robot.name}: no closed form with a free parameter: neither of the "
                         f"Franka Panda class ({reasons[0]}) nor of the SRS class ({reasons[1]})")
    return kind


def free_parameter(robot) -> tuple[str, tuple[float, float]]:
    """The free parameter of a 7R arm of either class and its range (rad): ("q7", joint 7's
    limits) for the Panda class, ("psi", (-pi, pi)) for the SRS class (psi is periodic; the
    feasible intervals of one pose under the limits: :func:`derive.ik.srs.psi_intervals`).
    InputError for any other robot."""
    robot = load_robot(robot)
    kind = _kind(robot)
    if kind == "panda":
        return "q7", tuple(panda.q7_interval(robot))
    return "psi", (-math.pi, math.pi)


def branch_labels(robot) -> list[str]:
    """What the three bits of a branch id choose, most significant first."""
    return list(LABELS[_kind(load_robot(robot))])


def missing_free_message(robot) -> str:
    """The InputError text for a 7R call without its free parameter."""
    robot = load_robot(robot)
    name, (lo, hi) = free_parameter(robot)
    what = ("q7, the value of joint 7" if name == "q7" else
            "psi, the arm angle (the rotation of the arm plane about the shoulder-wrist line)")
    return (f"{robot.name} has 7 joints: its solutions form a one-parameter family, so the IK "
            f"needs free= ({what}, rad, in [{lo:.4g}, {hi:.4g}]), a number or one per pose; "
            "ik_sweep evaluates several values, nearest chooses one for a seed")


#: The free parameters each class's IK programs and kernels can take: the first is the default.
FREE_CHOICES = {"srs": ("psi", "q3"), "panda": ("q7",)}


def free_choice(robot, free: str | None) -> str | None:
    """``free`` checked against the robot's class (:data:`FREE_CHOICES`):
    None for the default parameter (given as None or by its name, "psi" / "q7"), else the
    alternative ("q3"); InputError for anything else."""
    if free is None:
        return None
    robot = load_robot(robot)
    choices = FREE_CHOICES.get(redundant_kind(robot), ())
    if free not in choices:
        raise InputError(f"free: {robot.name} offers no IK with {free!r} as the free parameter; "
                         f"its choices: {', '.join(choices) or 'none (not a 7-joint arm of a known class)'}")
    return None if free == choices[0] else free


# --------------------------------------------------------------------------- #
# Solutions at given values
# --------------------------------------------------------------------------- #
def free_values(free, n: int) -> np.ndarray:
    """The free parameter for n poses as a float64 array (n,): a number for every pose or one
    per pose; InputError for other shapes, NaN or inf."""
    if type(free) is float or type(free) is np.float64:     # one number: the checks below, fewer steps
        if math.isfinite(free):
            return np.full(n, float(free)) if n != 1 else np.array([float(free)])
    arr = as_finite_array(free, "free", ndim_min=0)
    if arr.ndim == 0 or arr.shape == (1,):
        return np.full(n, float(arr.reshape(-1)[0]))
    if arr.shape != (n,):
        raise InputError(f"free: expected a number or shape ({n},) (one per pose), got {arr.shape}")
    return arr.astype(float)


def _q_ref(q_ref, n: int) -> np.ndarray | None:
    if q_ref is None:
        return None
    arr = as_finite_array(q_ref, "q_ref", last_dim=7)
    if arr.ndim == 1:
        arr = arr[None]
    if arr.ndim != 2 or arr.shape[0] not in (1, n):
        raise InputError(f"q_ref: expected shape (7,) or ({n}, 7), got {arr.shape}")
    return np.broadcast_to(arr, (n, 7)).astype(float)


def solve(robot, poses, free, q_ref=None) -> Solutions:
    """Every closed-form solution of poses (8,) / (n, 8) or (4, 4) / (n, 4, 4) of the end frame
    with the free parameter at ``free`` (q7 for the Panda class, psi for the SRS class; a number
    or one per pose, rad): :func:`derive.ik.panda.ik_q7` or :func:`derive.ik.srs.ik_psi`, each
    solution checked by the reference FK. ``q_ref`` (7,) or (n, 7): the joints a singular set
    leaves free are taken from it (else 0). Joint values wrapped to (-pi, pi] (q7: as given);
    limits not applied."""
    robot = load_robot(robot)
    kind = _kind(robot)
    P, _ = as_pose_batch(poses)
    n = len(P)
    f = free_values(free, n)
    qr = _q_ref(q_ref, n)
    if kind == "panda":
        return panda.ik_q7(robot, P, f, q_ref=qr)
    return srs.ik_psi(robot, P, f, q_ref=qr)


def ik_batch(robot, poses, free, q_ref=None, details: bool = False):
    """(solutions (n, 8, 7) NaN-padded, counts (n,)) at the free parameter ``free`` (:func:`solve`);
    ``details``: also (branch (n, 8), singular (n, 8)), as the kernels' ``ik(..., details=True)``."""
    r = solve(robot, poses, free, q_ref)
    return (r.q, r.counts, r.branch, r.singular) if details else (r.q, r.counts)


def ik(robot, pose, free, q_ref=None, within_limits: bool = False, sort_by=None) -> RedundantIKSolutions:
    """Every closed-form solution (k, 7) of one pose at the free parameter ``free`` (a number):
    ``.singular``, ``.reason``, ``.branch`` and ``.free`` as attributes; ``within_limits`` and
    ``sort_by`` as in :func:`derive.ik.closed_form.ik`."""
    robot = load_robot(robot)
    P, single = as_pose_batch(pose)
    if not single:
        raise InputError("pose: ik() takes one pose; use ik_batch() for several")
    f = free_values(free, 1)
    r = solve(robot, P, f, q_ref)
    k = int(r.counts[0])
    sols, sing, br, reason = finish.select_one(robot, r.q[0, :k], r.singular[0, :k], r.branch[0, :k],
                                               r.reason[0], within_limits, sort_by)
    return RedundantIKSolutions(sols.reshape(-1, 7), sing, reason, br, f[0])


# --------------------------------------------------------------------------- #
# Sweep
# --------------------------------------------------------------------------- #
#: The most (pose, value) pairs one sweep solves: 10^6, a result of 448 MB (8 solutions of 7
#: joints per pair, 448 bytes, plus the within-limits windings); a larger sweep raises InputError.
MAX_SWEEP = 10 ** 6
#: (pose, value) pairs solved at a time in :func:`ik_sweep`.
SWEEP_CHUNK = 16384


def check_sweep_size(poses: int, n: int) -> None:
    """InputError when ``poses`` x ``n`` exceeds :data:`MAX_SWEEP`."""
    if poses * n > MAX_SWEEP:
        raise InputError(f"sweep: {poses} pose(s) x {n} values = {poses * n} is more than the limit of "
                         f"{MAX_SWEEP} (pose, value) pairs per call (448 bytes of solutions each); "
                         "use fewer values, or call it on fewer poses at a time")


def sweep_values(robot, poses, n: int, feasible=None) -> np.ndarray:
    """(P, n) values of the free parameter: the midpoints of n equal parts of the feasible range
    (q7: joint 7's limits, the same for every pose; psi: the union of the pose's feasible
    intervals, :func:`derive.ik.srs.sweep_psi`; NaN for a pose without one). ``feasible(poses
    (r, 8), psi (r,))`` -> bool (r,) decides the SRS arcs between the closed-form breakpoints
    (default: the numpy closed form and the limits)."""
    robot = load_robot(robot)
    kind = _kind(robot)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise InputError(f"n: the number of values of the free parameter, a positive integer; got {n!r}")
    P, _ = as_pose_batch(poses)
    check_sweep_size(len(P), int(n))
    if kind == "srs":
        return srs.sweep_psi(robot, P, int(n), feasible)
    lo, hi = panda.q7_interval(robot)
    if not (math.isfinite(lo) and math.isfinite(hi)):
        lo, hi = -math.pi, math.pi
    return np.broadcast_to(lo + (hi - lo) * (np.arange(n) + 0.5) / n, (len(P), n)).copy()


def ik_sweep(robot, poses, n: int, q_ref=None, within_limits: bool = True, solver=None,
             limiter=None) -> Sweep:
    """The solutions of P poses at n values of the free parameter over its feasible range
    (:func:`sweep_values`). ``within_limits`` (default): only the solutions inside the joint
    limits, each at its in-limit winding (:func:`derive.ik.select.within_limits`); else every
    solution (:func:`solve`). One pose (8,) / (4, 4) gives the arrays without the leading axis.
    ``solver(poses (m, 8), free (m,))`` -> (q, counts, branch, singular) replaces :func:`solve`
    (the generated kernels' batch IK: ``derive.kernels(robot, "c").ik_sweep``), and
    ``limiter(q, counts, branch, singular)`` -> the same four, every in-limit winding, replaces
    :func:`derive.ik.select.within_limits` (the kernels' extension does it in C)."""
    robot = load_robot(robot)
    if limiter is None:
        def limiter(sq, sc, sb, sg):
            return select.within_limits(sq, sc, robot.limits, [True] * 7, branch=sb, singular=sg)
    feasible = None
    if solver is not None:
        def feasible(p, f):
            return srs.within_limits(robot, solver(p, f)[0]).any(-1)
    values = sweep_values(robot, poses, n, feasible)
    P, single = as_pose_batch(poses)
    m = len(P)
    qr = _q_ref(q_ref, m)
    q = np.full((m, n, BRANCHES, 7), np.nan)
    counts = np.zeros((m, n), dtype=np.int64)
    branch = np.full((m, n, BRANCHES), -1, dtype=np.int64)
    singular = np.zeros((m, n, BRANCHES), dtype=bool)
    have = np.isfinite(values)
    at = np.argwhere(have)                       # (r, 2): (pose, value) of each row
    # in chunks of SWEEP_CHUNK rows, written into the result: the peak is the result plus one
    # chunk's temporaries (the within-limits result is bounded by select.MAX_RESULT_BYTES)
    for s in range(0, len(at), SWEEP_CHUNK):
        e = min(len(at), s + SWEEP_CHUNK)
        ii, jj = at[s:e, 0], at[s:e, 1]
        fv = values[ii, jj]
        if solver is None:
            r = solve(robot, P[ii], fv, None if qr is None else qr[ii])
            sq, sc, sb, sg = r.q, r.counts, r.branch, r.singular
        else:
            sq, sc, sb, sg = solver(P[ii], fv)
        if within_limits:
            sq, sc, sb, sg = limiter(sq, sc, sb, sg)
            sg = np.asarray(sg, dtype=bool)
        k = sq.shape[1]
        if k > q.shape[2]:
            grow = k - q.shape[2]
            q = np.concatenate([q, np.full((m, n, grow, 7), np.nan)], axis=2)
            branch = np.concatenate([branch, np.full((m, n, grow), -1, dtype=np.int64)], axis=2)
            singular = np.concatenate([singular, np.zeros((m, n, grow), dtype=bool)], axis=2)
        q[ii, jj, :k], counts[ii, jj], branch[ii, jj, :k], singular[ii, jj, :k] = sq, sc, sb, sg
    out = Sweep(values, q, counts, branch, singular)
    return Sweep(*(x[0] for x in out)) if single else out


# --------------------------------------------------------------------------- #
# Nearest along a path
# --------------------------------------------------------------------------- #
class _Problem:
    """The unchecked closed form of one call, evaluated at free values per pose."""

    def __init__(self, robot, kind, poses, seeds, solver=None):
        self.robot, self.kind, self.poses, self.seeds = robot, kind, poses, seeds
        self.solver = solver
        self.lo, self.hi = robot.limits[:, 0], robot.limits[:, 1]
        if kind == "panda":
            self.geo = panda.panda_geometry(robot)
            c = self.geo.into_canonical(poses)
            self.r7, self.p = quat._to_matrix(c[:, :4]), dq._translation(c)
        else:
            self.geo = srs.srs_geometry(robot)
            self.rc, self.w = srs._into_canonical(self.geo, poses)

    def candidates(self, rows, f):
        """Candidates (len(rows), 8, 7), indexed by branch id, and their singular flags (len(rows),
        8) at free values f for the poses ``rows``; not checked by FK, NaN where a root is missing."""
        if self.solver is not None:
            return _by_branch(*self.solver(self.poses[rows], f))
        if self.kind == "panda":
            cand, sing, _ = panda.canonical_candidates(self.geo, self.r7[rows], self.p[rows], f,
                                                       self.seeds[rows])
            return cand, sing
        cand, sing, _ = srs._solve_psi(self.geo, self.rc[rows], self.w[rows], f, self.seeds[rows])
        return cand, sing

    def moves(self, rows, cand):
        """Per candidate: the winding nearest to the seed inside the limits (NaN if none), and
        the largest, summed and summed squared joint moves (inf if none); the first two are the
        rule of select.nearest."""
        s = self.seeds[rows][:, None, :]
        best = select.nearest_windings(cand, s, self.lo, self.hi)
        ok = np.isfinite(best)
        move = np.where(ok, np.abs(best - s), np.inf)
        return best, move.max(axis=-1), move.sum(axis=-1), (move * move).sum(axis=-1)

    def branch_key(self, rows, f, b):
        """(largest move, summed move, summed squared move) of branch b (per row) at free values f."""
        cand, _ = self.candidates(rows, f)
        pick = cand[np.arange(len(rows)), b][:, None]
        _, mx, tot, sq = self.moves(rows, pick)
        return mx[:, 0], tot[:, 0], sq[:, 0]


def _by_branch(q, counts, branch, singular):
    """Solutions packed in branch order with their branch ids (a solver's output) as candidates
    indexed by branch id: (q (n, 8, 7), singular (n, 8)), NaN and False for a missing branch."""
    n = len(q)
    cand = np.full((n, BRANCHES, 7), np.nan)
    sing = np.zeros((n, BRANCHES), dtype=bool)
    i, k = np.nonzero(branch[:, :BRANCHES] >= 0)
    cand[i, branch[i, k]] = q[i, k]
    sing[i, branch[i, k]] = singular[i, k]
    return cand, sing


def _better(k1, t1, k2, t2):
    """(k1, t1) strictly before (k2, t2) in the lexicographic order, first keys closer than TIE
    equal."""
    return (k1 < k2 - TIE) | ((np.abs(k1 - k2) <= TIE) & (t1 < t2))


def _free_of(kind, robot, seeds) -> np.ndarray:
    if kind == "panda":
        return seeds[:, 6].copy()
    return np.atleast_1d(srs.arm_angle(robot, seeds))


def _clip(kind, f, lo, hi):
    return np.clip(f, lo, hi) if kind == "panda" else f


def _refine(prob, kind, rows, a, b, br, f_best, k_best, t_best, flo, fhi, key):
    """Successive grid refinement (a parallel form of golden-section search, Kiefer 1953) of the
    branch's lexicographic key on [a, b]: REFINE values inside the bracket, the bracket narrowed
    to the neighbours of the best value seen, until narrower than FREE_TOL. ``key(largest move,
    summed move, summed squared move)`` -> (first key, second key), each (len(rows), REFINE).
    Returns the best (f, first key, second key); (f_best, k_best, t_best) is the best so far."""
    f_best, k_best, t_best = f_best.copy(), k_best.copy(), t_best.copy()
    frac = np.arange(1, REFINE + 1) / (REFINE + 1)
    for _ in range(40):
        if np.max(b - a) <= FREE_TOL:
            break
        width = b - a
        fg = _clip(kind, a[:, None] + width[:, None] * frac, flo, fhi)
        rr = np.repeat(rows, REFINE)
        mx, tot, sq = prob.branch_key(rr, fg.reshape(-1), np.repeat(br, REFINE))
        k1, k2 = key(mx.reshape(-1, REFINE), tot.reshape(-1, REFINE), sq.reshape(-1, REFINE))
        j = np.lexsort((k2, k1), axis=-1)[:, 0]
        k = np.arange(len(rows))
        imp = _better(k1[k, j], k2[k, j], k_best, t_best)
        f_best = np.where(imp, fg[k, j], f_best)
        k_best, t_best = np.where(imp, k1[k, j], k_best), np.where(imp, k2[k, j], t_best)
        step = width / (REFINE + 1)
        a, b = f_best - step, f_best + step
    return f_best, k_best, t_best


#: Poses per chunk of :func:`nearest` (the search holds about 270 KB per pose: 49 values x 8
#: branches of 7 joints and their moves, several times over).
NEAREST_CHUNK = 512



def nearest_inputs(poses, q_seed, tol):
    """The checked inputs of a seven-joint nearest search (this module's and
    :func:`derive.ik.free_joint.nearest`): poses (n, 8), seeds (n, 7) and whether one pose and
    one seed were given; InputError naming a bad ``tol`` or ``q_seed``."""
    if tol is not None and not (isinstance(tol, (int, float, np.floating, np.integer))
                                and not isinstance(tol, bool) and math.isfinite(tol) and tol >= 0):
        raise InputError(f"tol: expected a finite number >= 0 (rad), got {tol!r}")
    P, single = as_pose_batch(poses)
    seeds_in = as_finite_array(q_seed, "q_seed", last_dim=7)
    if seeds_in.ndim > 2 or (seeds_in.ndim == 2 and seeds_in.shape[0] not in (1, len(P))):
        raise InputError(f"q_seed: expected shape (7,) or ({len(P)}, 7), got {seeds_in.shape}")
    seeds = np.broadcast_to(seeds_in.reshape(-1, 7), (len(P), 7)).astype(float)
    return P, seeds, single and seeds_in.ndim == 1


def nearest_record(q, mx, tot, br, sg, tol, single: bool, slack: float = 0.0):
    """The :class:`derive.ik.select.Nearest` record of a seven-joint nearest search (this
    module's and :func:`derive.ik.free_joint.nearest`): ``found`` where a largest move ``mx`` is
    finite and within ``tol`` + ``slack`` (no bound for tol None), NaN and branch -1 elsewhere;
    scalars for one pose and one seed."""
    found = np.isfinite(mx)
    if tol is not None:
        found &= mx <= tol + slack
    res = select.Nearest(q=np.where(found[:, None], q, np.nan), found=found,
                         max_move=np.where(found, mx, np.nan), total_move=np.where(found, tot, np.nan),
                         branch=np.where(found, br, -1), singular=found & sg)
    if single:
        return select.Nearest(*(getattr(res, f)[0] for f in ("q", "found", "max_move", "total_move",
                                                           "branch", "singular")))
    return res

def nearest(robot, poses, q_seed, tol=None, solver=None) -> select.Nearest:
    """Per pose the solution nearest to the seed along a path, with the free parameter and the
    branch chosen by the 1D search of the module docstring: on the branch of the least largest
    single-joint move M, the free value with the least summed squared joint move among those
    whose largest move is at most (1 + SLACK) M (SLACK = 0.5); ``q_seed`` (7,) or (n, 7). The
    record of :func:`derive.ik.select.nearest`: ``q`` at the winding nearest to the seed inside
    the limits, ``found`` (False where no solution inside the limits was found, or its largest
    move exceeds ``tol``), ``max_move``, ``total_move``, ``branch``, ``singular``. The joints a
    singular set leaves free are the seed's. One pose and one seed give scalars.

    ``solver(poses (m, 8), free (m,))`` -> (q, counts, branch, singular), solutions packed with
    their branch ids, replaces the numpy closed form in the search (the generated kernels' batch
    IK: ``derive.kernels(robot, "c").nearest``); a chosen solution on a singular set is then
    solved again by :func:`solve` with the seed as reference."""
    robot = load_robot(robot)
    kind = _kind(robot)
    P, seeds, single = nearest_inputs(poses, q_seed, tol)
    n = len(P)
    if n > NEAREST_CHUNK:
        # each pose's search is its own: in chunks, so the scan's temporaries (about 270 KB per
        # pose) stay bounded
        parts = [nearest(robot, P[s:s + NEAREST_CHUNK], seeds[s:s + NEAREST_CHUNK], tol, solver)
                 for s in range(0, n, NEAREST_CHUNK)]
        return select.Nearest(*(np.concatenate([getattr(part, f) for part in parts])
                                for f in ("q", "found", "max_move", "total_move", "branch", "singular")))
    prob = _Problem(robot, kind, P, seeds, solver)
    _, (flo, fhi) = free_parameter(robot)
    if kind == "panda" and not (math.isfinite(flo) and math.isfinite(fhi)):
        flo, fhi = -math.pi, math.pi
    rows = np.arange(n)

    # 1. the seed's own free value and values around it at several scales, and a scan of
    # the range: every branch at each; the best (value, branch) starts the search
    f0 = _clip(kind, _free_of(kind, robot, seeds), flo, fhi)
    grid = flo + (fhi - flo) * (np.arange(SCAN) + 0.5) / SCAN
    vals = np.concatenate([_clip(kind, f0[:, None] + _ALL, flo, fhi),
                           np.broadcast_to(grid, (n, SCAN))], axis=1)           # (n, 17 + SCAN)
    m = vals.shape[1]
    rr = np.repeat(rows, m)
    _, mx, tot, _ = prob.moves(rr, prob.candidates(rr, vals.reshape(-1))[0])
    mx, tot = mx.reshape(n, m * BRANCHES), tot.reshape(n, m * BRANCHES)
    j = np.lexsort((tot, mx), axis=-1)[:, 0]
    start, branch = vals[rows, j // BRANCHES], j % BRANCHES
    best_mx, best_tot = mx[rows, j], tot[rows, j]
    # the bracket: the neighbours of the best value in its set (the offsets around f0 are sorted)
    col = j // BRANCHES
    local = col < len(_ALL)
    lo_off = np.where(local, _LOWER[np.minimum(col, len(_ALL) - 1)], -(fhi - flo) / SCAN)
    hi_off = np.where(local, _UPPER[np.minimum(col, len(_ALL) - 1)], (fhi - flo) / SCAN)
    live = np.isfinite(best_mx)
    best_f = start.copy()
    at = rows[live]
    if len(at):
        with np.errstate(invalid="ignore"):
            # 2. the least largest move on that branch (then the least summed move)
            f, m_, _ = _refine(prob, kind, at, start[at] + lo_off[at], start[at] + hi_off[at],
                               branch[at], start[at], best_mx[at], best_tot[at], flo, fhi,
                               lambda mx_, tot_, sq_: (mx_, tot_))
            # 3. on that branch the least summed squared move among the values whose largest
            # move is at most (1 + SLACK) x the least: the excess over that bound, then the
            # summed squared move; the bracket WIDE x the bound either side
            # (SLACK = 0: the least largest move itself, the earlier rule)
            if SLACK > 0:
                bound = (1.0 + SLACK) * m_
                reach = np.minimum(WIDE * bound, math.pi)
                _, _, sq0 = prob.branch_key(at, f, branch[at])
                f, _, _ = _refine(prob, kind, at, f - reach, f + reach, branch[at], f,
                                  np.zeros(len(at)), sq0, flo, fhi,
                                  lambda mx_, tot_, sq_: (np.maximum(mx_ - bound[:, None], 0.0), sq_))
        best_f[at] = f

    # 4. the answer: the chosen branch at the chosen value, checked by the class's FK; where the
    # check fails, the nearest of the checked solutions there (:func:`solve`)
    q = np.full((n, 7), np.nan)
    mx_out, tot_out = np.full(n, np.inf), np.full(n, np.inf)
    br_out, sg_out = np.full(n, -1, dtype=np.int64), np.zeros(n, dtype=bool)
    at = rows[live]
    if len(at):
        k = np.arange(len(at))
        cand, sing = prob.candidates(at, best_f[at])
        best, mx, tot, _ = prob.moves(at, cand[k, branch[at]][:, None])
        good, _ = finish.check(robot, P[at], np.nan_to_num(best[:, :1]))
        ok = np.isfinite(mx[:, 0]) & good[:, 0]
        if solver is not None:          # the kernels set a free joint to 0, not the seed's
            ok &= ~sing[k, branch[at]]
        q[at[ok]] = best[ok, 0]
        mx_out[at[ok]], tot_out[at[ok]] = mx[ok, 0], tot[ok, 0]
        br_out[at[ok]], sg_out[at[ok]] = branch[at[ok]], sing[k[ok], branch[at[ok]]]
        redo = at[~ok]
        if len(redo):
            r = solve(robot, P[redo], best_f[redo], seeds[redo])
            kk = np.arange(len(redo))
            best, mx, tot, _ = prob.moves(redo, r.q)
            choose = np.lexsort((tot, mx), axis=-1)[:, 0]
            q[redo] = best[kk, choose]
            mx_out[redo], tot_out[redo] = mx[kk, choose], tot[kk, choose]
            br_out[redo], sg_out[redo] = r.branch[kk, choose], r.singular[kk, choose]
    return nearest_record(q, mx_out, tot_out, br_out, sg_out, tol, single)
