"""Inverse kinematics by numerical refinement with CasADi, from closed-form seeds.

``refine(robot, pose, q0=None, ...)`` minimises the pose error of
:mod:`derive.refinement.functions` (e = [t - t*; 2 s v], position in metres, rotation as 2 sin of half
the error angle) on the robot's actual model, from one or several starting configurations:

* seeds: the given ``q0`` (one (dof,) or several (k, dof)); by default every closed-form
  solution of the nominal geometry (the robot's own closed form, or that of the library
  robot named by its ``nominal`` key, e.g. ur5 for ur5-calibrated); for arms without one,
  ``starts`` configurations drawn uniformly within the joint limits (fixed ``seed``);
* each seed: Levenberg-Marquardt (damped Gauss-Newton) on the residual
  [W e(q); sqrt(lambda) (q - q_ref)], W = diag(w_pos I3, w_rot I3), with e and its Jacobian
  evaluated by one CasADi function (``residual``, algorithmic differentiation of the derived
  FK). In the exactly determined 6-DOF case this is Newton's method on e(q) = 0 with a
  safeguard: steps that do not lower |e| are damped, so a seed near a singular set converges
  to the nearest solution instead of jumping to another basin. Revolute joints are then
  moved by multiples of 2 pi into their limits where possible (the same pose);
* a closed-form seed that fails, or lands on another seed's solution, is followed from the
  nominal to the actual geometry (:func:`track`, pseudo-arclength continuation of the
  geometry homotopy of :func:`derive.refinement.functions.homotopy_function`): a path that reaches the
  actual arm gives its solution, one that turns at a fold back to another nominal solution
  proves the pair lost (``note``); only an undecided path is retried from a few perturbed
  copies (fixed seed), the first new exact solution replacing it;
* when a joint ends outside its limits: ``nlpsol`` with IPOPT, minimising the same objective
  within the joint limits (the result is clipped to the limits, so a returned solution never
  violates them).

Every result reports q, the position and rotation errors (metres, radians), the iterations,
``success`` (both errors below ``tol``) and the seed it came from. An unreachable pose is not
an error: the results have success False and the best residual found, in bounded time
(``max_iter`` iterations per seed).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from derive.cache import memo
from derive.errors import DeriveError, InputError, as_finite_array, finite_number, whole_number
from derive.ik.closed_form import (
    closed_form_relation,
    ik_batch,
    nominal_relation,
    solve_batch,
    ur_geometry,
)
from derive.kinematics.pose import as_pose_batch
from derive.model.robot import load_robot
from derive.refinement.functions import functions, homotopy_function

#: Default success tolerance on the position (m) and rotation (rad) errors.
TOL = 1e-10
#: Two converged solutions closer than this in every joint (mod 2 pi) are the same.
SAME_TOL = 1e-6


@dataclass
class Refined:
    """One refinement: joint values ``q`` (dof,), ``position_error`` (m), ``rotation_error``
    (rad), ``iterations``, ``success``, ``seed`` (index into the seeds), ``q0`` (the seed),
    ``solver`` ("lm"; "+ipopt" when the bounded NLP gave the result, "path+" when the seed was
    first followed from the nominal geometry, "+retry" for a perturbed restart), ``time_s``
    and ``note`` (why a closed-form seed has no solution, when that is known)."""

    q: np.ndarray
    position_error: float
    rotation_error: float
    iterations: int
    success: bool
    seed: int
    q0: np.ndarray
    solver: str
    time_s: float
    note: str = ""


class RefineResult(list):
    """The list of :class:`Refined`, one per seed, in seed order, with helpers."""

    @property
    def solutions(self) -> np.ndarray:
        """Distinct successful solutions (k, dof), in seed order."""
        out: list = []
        for r in self:
            if r.success and not any(_same(r.q, s) for s in out):
                out.append(r.q)
        dof = len(self[0].q) if self else 0
        return np.array(out).reshape(-1, dof)

    @property
    def success(self) -> bool:
        return any(r.success for r in self)

    @property
    def best(self) -> Refined:
        """The result with the smallest position + rotation error."""
        return min(self, key=lambda r: r.position_error + r.rotation_error)


def _same(a, b) -> bool:
    d = np.abs(np.mod(a - b + math.pi, 2 * math.pi) - math.pi)
    return bool(np.all(d < SAME_TOL))


# --------------------------------------------------------------------------- #
# Solvers (built once per robot and options)
# --------------------------------------------------------------------------- #
class _Numeric:
    """A CasADi Function called on float arrays through its evaluation buffer
    (``casadi.Function.buffer``): the same numeric evaluation as ``f(*args)``, without the
    conversion of every argument and result to and from DM, which dominates a call of a small
    function (about 45 us against 6 us for the 6R ``residual``). Returns the outputs as dense
    float arrays of their shapes (a 1 x 1 output as a float). Holds the buffer's memory: one per
    :func:`refine` call, not shared between threads."""

    def __init__(self, f):
        self.buf, self.eval = f.buffer()
        self.args = [np.zeros(f.nnz_in(i)) for i in range(f.n_in())]
        self.dense_in = [f.sparsity_in(i).is_dense() for i in range(f.n_in())]
        if not all(self.dense_in):
            raise DeriveError(f"{f.name()}: sparse inputs are not supported here")
        self.res = [np.zeros(f.nnz_out(i)) for i in range(f.n_out())]
        self.out = []
        for i in range(f.n_out()):
            sp = f.sparsity_out(i)
            rows, cols = sp.get_triplet()
            self.out.append((sp.size1(), sp.size2(), sp.is_dense(), np.array(rows, dtype=np.intp),
                             np.array(cols, dtype=np.intp)))
        for i, a in enumerate(self.args):
            self.buf.set_arg(i, memoryview(a))
        for i, r in enumerate(self.res):
            self.buf.set_res(i, memoryview(r))

    def __call__(self, *args):
        for a, x in zip(self.args, args, strict=True):
            a[:] = np.ravel(np.asarray(x, dtype=float), order="F")
        self.eval()
        out = []
        for r, (n1, n2, dense, rows, cols) in zip(self.res, self.out):
            if n1 == 1 and n2 == 1:
                out.append(float(r[0]) if dense else 0.0)
            elif dense:
                out.append(r.reshape((n1, n2), order="F").copy())
            else:
                m = np.zeros((n1, n2))
                m[rows, cols] = r
                out.append(m)
        return out


def _lm(resid, q, target, w, lam, q_ref, max_iter: int, tol: float):
    """Levenberg-Marquardt on the weighted residual [W e(q); sqrt(lambda) (q - q_ref)], e and
    its Jacobian from CasADi (algorithmic differentiation). Returns (q, iterations)."""
    wv = np.repeat(w, 3)
    sl = math.sqrt(lam)

    def evaluate(x):
        e, jac, dp, dr = resid(x, target)
        r, J = wv * np.array(e).ravel(), wv[:, None] * np.array(jac)
        if lam > 0:
            r = np.concatenate([r, sl * (x - q_ref)])
            J = np.vstack([J, sl * np.eye(len(x))])
        return r, J, float(dp), float(dr)

    r, J, dp, dr = evaluate(q)
    cost = r @ r
    mu = 1e-6
    it = 0
    while it < max_iter:
        if lam == 0 and dp < tol * 1e-3 and dr < tol * 1e-3:
            break
        it += 1
        g, H = J.T @ r, J.T @ J
        step = np.linalg.solve(H + mu * (np.diag(np.diag(H)) + 1e-12 * np.eye(len(q))), -g)
        x = q + step
        r1, J1, dp1, dr1 = evaluate(x)
        c1 = r1 @ r1
        if np.isfinite(c1) and c1 <= cost:
            small = np.max(np.abs(step)) < 1e-15 * (1 + np.max(np.abs(q)))
            q, r, J, dp, dr, cost = x, r1, J1, dp1, dr1, c1
            mu = max(mu / 10, 1e-12)
            if small or c1 == 0:
                break
        else:
            mu *= 10
            if mu > 1e12:
                break
    return q, it


def _nlp(robot, max_iter: int):
    return memo("casadi-nlp", (robot.id, robot.limits_id, max_iter), lambda: _build_nlp(robot, max_iter))


def _build_nlp(robot, max_iter: int):
    """IPOPT on 1/2 |W e|^2 + 1/2 lambda |q - q_ref|^2; parameters [target, w_pos, w_rot,
    lambda, q_ref]."""
    f = functions(robot)
    n = robot.dof
    q = ca.SX.sym("q", n)
    p = ca.SX.sym("p", 8 + 3 + n)
    e = f["pose_error"](q, p[:8])[0]
    we = ca.vertcat(p[8] * e[:3], p[9] * e[3:])
    obj = 0.5 * ca.dot(we, we) + 0.5 * p[10] * ca.dot(q - p[11:], q - p[11:])
    opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
            "ipopt.max_iter": max_iter, "ipopt.tol": 1e-20, "ipopt.acceptable_iter": 0,
            "ipopt.bound_relax_factor": 0.0, "ipopt.honor_original_bounds": "yes"}
    return ca.nlpsol("refine_nlp", "ipopt", {"x": q, "p": p, "f": obj}, opts)


@dataclass
class HomotopyPath:
    """The end of one continuation: ``status`` "end" (reached s = 1: ``q`` solves the robot),
    "back" (turned at a fold and came back to s = 0 at the nominal solution ``q``: the pair
    of solutions vanished between the geometries) or "lost" (step size or step budget
    exhausted: undecided); ``s`` where it stopped, ``steps`` accepted steps, ``turn`` the
    largest s reached (where a "back" path met its fold)."""

    status: str
    q: np.ndarray
    s: float
    steps: int
    turn: float


def track(hom, q0, target, *, h0: float = 0.05, h_max: float = 0.1, h_min: float = 1e-9,
          max_steps: int = 400, tol: float = 1e-12) -> HomotopyPath:
    """Follow the solution curve e(q, s) = 0 of the geometry homotopy (``hom`` from
    :func:`derive.refinement.functions.homotopy_function`) from the nominal solution ``q0`` at s = 0.

    Pseudo-arclength continuation in x = (q, s): the tangent is the null vector of
    J = [de/dq, de/ds] (SVD, oriented along the previous one, first towards s > 0); each
    predictor step x + h t is corrected by Gauss-Newton with the minimal-norm step
    (lstsq of the 6 x 7 system) to |e| < tol. A step is refused (and h halved) when the
    corrector does not contract, moves more than h / 4 from the prediction or turns the
    tangent by more than 0.2 rad, so the path does not jump to a neighbouring branch; h
    doubles after easy steps. The last step lands on s = 1 exactly (Newton in q). A fold
    (de/dq singular) is passed like any other point: the path then runs back to s = 0."""
    def ev(x):
        e, jac = hom(x[:-1], x[-1], target)
        return np.array(e).ravel(), np.array(jac)

    def tangent(jac, prev):
        t = np.linalg.svd(jac)[2][-1]
        return t if (t[-1] if prev is None else t @ prev) > 0 else -t

    def correct(x, fixed_s):
        last = math.inf
        for _ in range(10):
            e, jac = ev(x)
            if np.linalg.norm(e) < tol:
                return x, jac
            if fixed_s:
                dx = np.append(np.linalg.lstsq(jac[:, :-1], -e, rcond=None)[0], 0.0)
            else:
                dx = np.linalg.lstsq(jac, -e, rcond=None)[0]
            step = np.linalg.norm(dx)
            if step > 0.5 * last:
                return None, None
            last, x = step, x + dx
        e, jac = ev(x)
        return (x, jac) if np.linalg.norm(e) < tol else (None, None)

    x = np.append(np.asarray(q0, dtype=float), 0.0)
    t = tangent(ev(x)[1], None)
    h, steps, turn = h0, 0, 0.0
    while steps < max_steps and h >= h_min:
        if x[-1] + h * t[-1] >= 1.0 and t[-1] > 0:
            xp = x + t * (1.0 - x[-1]) / t[-1]
            xp[-1] = 1.0
            xc, _ = correct(xp, True)
            if xc is not None and np.linalg.norm(xc - xp) <= 0.25 * max(h, 1e-3):
                return HomotopyPath("end", xc[:-1], 1.0, steps + 1, 1.0)
            h /= 2
            continue
        xp = x + h * t
        xc, jac = correct(xp, False)
        if xc is None or np.linalg.norm(xc - xp) > 0.25 * h:
            h /= 2
            continue
        tn = tangent(jac, t)
        if tn @ t < math.cos(0.2):
            h /= 2
            continue
        x, t, steps = xc, tn, steps + 1
        if x[-1] < 0:
            # back at the nominal geometry: land on s = 0
            xp = x - t * x[-1] / t[-1]
            xp[-1] = 0.0
            xc, _ = correct(xp, True)
            if xc is None:
                return HomotopyPath("lost", x[:-1], float(x[-1]), steps, turn)
            return HomotopyPath("back", xc[:-1], 0.0, steps, turn)
        turn = max(turn, float(x[-1]))
        h = min(2 * h, h_max)
    return HomotopyPath("lost", x[:-1], float(x[-1]), steps, turn)


# --------------------------------------------------------------------------- #
# Seeds
# --------------------------------------------------------------------------- #
def closed_form_seeds(robot, pose, with_reach: bool = False):
    """Seeds from the closed form of the nominal geometry (k, dof): its solutions for the
    pose, then its branch candidates that the nominal arm just cannot reach, with their
    square roots clipped (the nearest the nominal arm comes: a calibrated arm may reach a
    little farther). (0, dof) when the robot has no closed form. With ``with_reach`` also
    the number of leading seeds that are nominal solutions."""
    robot = load_robot(robot)
    nominal, rel = _nominal_closed_form(robot)
    if nominal is None:
        empty = np.zeros((0, robot.dof))
        return (empty, 0) if with_reach else empty
    geo = ur_geometry(nominal)
    pose = np.asarray(pose, dtype=float)[None]
    if rel is not None:                 # the pose in the nominal robot's frames: B^-1 P T^-1
        pose = rel.into_other(pose)
    q, counts = ik_batch(nominal, pose)
    out = list(q[0, :counts[0]])
    cand, _, code = solve_batch(geo, pose, keep_unreachable=True)
    # a clipped root is a double root of the nominal arm; the calibrated one may have two
    # roots on either side of it: seeds there too (theta1 for code 1, theta3 for code 2)
    for c, cd in zip(cand[0], code[0]):
        if cd == 0 or not np.all(np.isfinite(c)):
            continue
        for delta in (0.0, -0.1, 0.1, -0.25, 0.25):
            v = c.copy()
            v[0 if cd == 1 else 2] += delta
            if not any(_same(v, o) for o in out):
                out.append(v)
    seeds = np.array(out).reshape(-1, robot.dof)
    if rel is not None:
        seeds = seeds * rel.signs
    return (seeds, int(counts[0])) if with_reach else seeds


def _nominal_closed_form(robot):
    """(robot with the UR closed form, relation or None) whose solutions seed the refinement:
    the ``nominal`` robot of the description, the robot itself, a library robot it is related to
    within 1e-9 (other base and tool frames) or, for a calibrated arm without a ``nominal`` key,
    the closest within 0.03 (NEAR_RELATE_TOL); (None, None) when there is none."""
    candidates = [load_robot(robot.nominal)] if robot.nominal else []
    for c in candidates + [robot]:
        try:
            ur_geometry(c)
            return c, None
        except DeriveError:
            continue
    rel = closed_form_relation(robot) or nominal_relation(robot)
    return (None, None) if rel is None else (load_robot(rel.other), rel)


def _random_starts(robot, starts: int, seed: int) -> np.ndarray:
    lim = robot.limits
    lo = np.where(np.isfinite(lim[:, 0]), lim[:, 0], -math.pi)
    hi = np.where(np.isfinite(lim[:, 1]), lim[:, 1], math.pi)
    lo, hi = np.maximum(lo, -math.pi), np.minimum(hi, math.pi)   # one turn suffices
    return np.random.default_rng(seed).uniform(lo, hi, size=(starts, robot.dof))


def _into_limits(robot, q):
    """Revolute joints moved by multiples of 2 pi into their limits where possible."""
    q = q.copy()
    lim = robot.limits
    for j in robot.joints:
        if j.is_mimic or j.type != "revolute":
            continue
        k = j.variable
        lo, hi = lim[k]
        if q[k] < lo:
            q[k] += 2 * math.pi * math.ceil((lo - q[k]) / (2 * math.pi))
        elif q[k] > hi:
            q[k] -= 2 * math.pi * math.ceil((q[k] - hi) / (2 * math.pi))
    return q


def _within(robot, q) -> bool:
    lim = robot.limits
    return bool(np.all(q >= lim[:, 0]) and np.all(q <= lim[:, 1]))


# --------------------------------------------------------------------------- #
# refine
# --------------------------------------------------------------------------- #
def refine(robot, pose, q0=None, *, weights=(1.0, 1.0), q_ref=None, regularization: float = 0.0,
           tol: float = TOL, max_iter: int = 50, starts: int = 16, seed: int = 0,
           retry_sigmas=(0.02, 0.05, 0.1, 0.2, 0.3, 0.5)) -> RefineResult:
    """Refine IK solutions of ``pose`` on the robot's actual model (see the module docstring).

    pose: unit dual quaternion (8,) or matrix (4, 4) of the end frame. q0: seed(s) (dof,) or
    (k, dof); default the nominal closed-form solutions, or ``starts`` random starts.
    weights: (position, rotation) weights of the error; regularization: lambda >= 0 towards
    q_ref (default the seed); tol: success tolerance > 0 (m and rad); max_iter: iterations per
    seed, an integer >= 1; starts (>= 1) random starts with the generator seed ``seed`` (>= 0)
    for arms without a closed form; retry_sigmas: perturbation sizes (rad) > 0 of the retries.
    Every option is checked (InputError naming it). Returns a :class:`RefineResult`, one :class:`Refined` per seed.
    """
    robot = load_robot(robot)
    n = robot.dof
    pose_b, single = as_pose_batch(pose)
    if not single:
        raise InputError("pose: refine() takes one pose")
    target = pose_b[0]
    w = as_finite_array(weights, "weights", last_dim=2)
    if w.shape != (2,) or np.any(w < 0) or not np.any(w > 0):
        raise InputError("weights: (position, rotation), two finite numbers >= 0, not both 0; got "
                         + (f"({', '.join(f'{float(x):g}' for x in w)})" if w.shape == (2,) else f"shape {w.shape}"))
    regularization = finite_number(regularization, "regularization", minimum=0.0)
    tol = finite_number(tol, "tol", minimum=0.0, strict=True)
    max_iter = whole_number(max_iter, "max_iter", minimum=1)
    starts = whole_number(starts, "starts", minimum=1)
    seed = whole_number(seed, "seed", minimum=0)
    sig = as_finite_array(retry_sigmas, "retry_sigmas", ndim_min=0).ravel()
    if np.any(sig <= 0):
        raise InputError(f"retry_sigmas: must be > 0, got ({', '.join(f'{float(x):g}' for x in sig)})")
    retry_sigmas = tuple(float(x) for x in sig)
    n_nominal = 0                # leading seeds that are nominal solutions (repaired when they fail)
    if q0 is None:
        seeds, n_nominal = closed_form_seeds(robot, target, with_reach=True)
        if len(seeds) == 0:
            seeds = _random_starts(robot, starts, seed)
    else:
        seeds = as_finite_array(q0, "q0", ndim_min=1)
        seeds = seeds[None] if seeds.ndim == 1 else seeds
        if seeds.ndim != 2 or seeds.shape[1] != n:
            raise InputError(f"q0: expected ({n},) or (k, {n}), got {seeds.shape}")
    qr = None if q_ref is None else as_finite_array(q_ref, "q_ref", last_dim=n)
    fns = functions(robot)
    err, resid = _Numeric(fns["pose_error"]), _Numeric(fns["residual"])
    lim = robot.limits
    lbx = np.where(np.isfinite(lim[:, 0]), lim[:, 0], -np.inf)
    ubx = np.where(np.isfinite(lim[:, 1]), lim[:, 1], np.inf)
    def solve_one(k, s):
        t0 = time.perf_counter()
        ref = s if qr is None else qr
        q, iters = _lm(resid, np.array(s, dtype=float), target, w, regularization, ref, max_iter, tol)
        q = _into_limits(robot, q)
        solver = "lm"
        if not _within(robot, q):
            # a joint outside its limits even after moving it by 2 pi: IPOPT within the limits,
            # from the seed moved into them (the result replaces the out-of-limits one)
            nlp = _nlp(robot, max_iter)
            start = np.clip(_into_limits(robot, np.array(s, dtype=float)), lbx, ubx)
            sol = nlp(x0=start, p=np.concatenate([target, w, [regularization], ref]), lbx=lbx, ubx=ubx)
            q = np.clip(np.array(sol["x"]).ravel(), lbx, ubx)
            iters += int(nlp.stats().get("iter_count", 0))
            solver = "lm+ipopt"
        _, dp, dr = err(q, target)
        dp, dr = float(dp), float(dr)
        return Refined(q=q, position_error=dp, rotation_error=dr, iterations=iters,
                       success=dp < tol and dr < tol, seed=k, q0=np.array(s), solver=solver,
                       time_s=time.perf_counter() - t0)

    out = RefineResult(solve_one(k, s) for k, s in enumerate(seeds))
    _repair(robot, out, seeds[:n_nominal], target, solve_one, retry_sigmas, seed)
    return out


def _homotopy(robot):
    """The geometry homotopy from the robot's nominal description, or None."""
    if not robot.nominal or robot.nominal == robot.name:
        return None
    try:
        return homotopy_function(robot, robot.nominal)
    except DeriveError:
        return None


def _repair(robot, out, nominal, target, solve_one, retry_sigmas, seed):
    """Closed-form seeds that fail or share their solution with another seed: near the
    nominal singular sets the actual arm's solutions move farther than a seed's basin, or a
    pair of them vanishes. Each such seed is followed from the nominal to the actual geometry
    (:func:`track`) and refined from the path's end; a path that turns back to s = 0 at another
    nominal solution proves the pair lost (note set, no retries); an undecided path falls back
    to a few perturbed restarts (fixed seed). out[k] is replaced by the first new exact
    solution."""
    hom = _homotopy(robot)
    rng = np.random.default_rng(seed)
    n = len(nominal)

    def clash(k, q):
        return [i for i, o in enumerate(out) if i != k and o.success and _same(q, o.q)]

    pending = [k for k in range(n) if not out[k].success or clash(k, out[k].q)]
    done: set = set()
    while pending:
        k = pending.pop(0)
        done.add(k)
        r = out[k]
        path = track(hom, nominal[k], target) if hom is not None else None
        if path is not None and path.status == "end":
            r2 = solve_one(k, path.q)
            if r2.success:
                r2.solver, r2.time_s, r2.q0 = "path+" + r2.solver, r2.time_s + r.time_s, nominal[k]
                out[k] = r2
                # a seed whose solution this is jumped there: follow it too
                pending += [i for i in clash(k, r2.q) if i < n and i not in done and i not in pending]
                continue
        if path is not None and path.status == "back":
            partner = next((i for i in range(n) if i != k and _same(path.q, nominal[i])), None)
            if partner is not None:
                out[k].note = (f"no solution on this branch: followed from the nominal geometry, "
                               f"it meets a fold at s = {path.turn:.3f} and returns to the nominal "
                               f"solution of seed {partner} (the pair vanishes on this arm)")
                continue
        others = [o.q for i, o in enumerate(out) if i != k and o.success]
        for sigma in np.repeat(retry_sigmas, 2):
            r2 = solve_one(k, nominal[k] + rng.normal(0.0, sigma, len(nominal[k])))
            if r2.success and not any(_same(r2.q, o) for o in others):
                r2.solver += "+retry"
                r2.time_s += r.time_s
                out[k] = r2
                break
