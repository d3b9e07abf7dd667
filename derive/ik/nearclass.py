"""Near-class arms: a description a little off a class with a closed form (a URDF's printed
constants such as 1.570796325, decimal DH such as ``alpha: 1.5708``, a calibrated arm, axes
that miss by fractions of a millimetre) keeps the closed form of its *nominal* robot, an exact
member of the class, and every candidate is polished by Newton steps on the arm's own FK.

This module holds the interface shared by the numpy reference (:mod:`derive.ik`) and the
emitted kernels (:mod:`derive.codegen`): :class:`Nominal`, the exact robot and the constant
relation between the two chains,

    FK_robot(q) ~= B FK_nominal(signs * q + offsets) T,

with B and T unit dual quaternions (scalar-first, [real | dual]) and the relation's largest
mismatch on sample configurations in ``deviation``.

The numpy side: :func:`nominal` finds the nominal robot (the routes and tolerances are in its
docstring and in :mod:`derive.ik.tolerances`), :func:`polish` is the Newton polish, and
:func:`solve` solves a near-class arm (nominal closed form, map back, polish, drop what does not
converge, merge duplicates), which :func:`derive.reference.ik` and ``ik_batch`` call for an arm
with no exact class.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from derive.algebra import dualquat as dq
from derive.algebra import quaternion as quat
from derive.algebra.angles import wrap_angle
from derive.cache import memo
from derive.errors import DeriveError, InputError, as_finite_array
from derive.ik import closed_form, panda, redundant, spherical, srs
from derive.ik.closed_form import IKSolutions
from derive.ik.finish import select_one
from derive.ik.tolerances import (
           MERGE_TOL,
           HOMOTOPY_FROM,
           HOMOTOPY_STAGES,
           HOMOTOPY_STEPS,
           NEAR_AXIS_TOL,
           NEAR_DEVIATION_MAX,
           NEAR_DEVIATION_MAX_7R,
           NEAR_POINT_TOL,
           NEAR_POINT_TOL_7R,
           POLISH_MAX_ITER,
           POLISH_MAX_STEP,
           POLISH_TOL,
           SEED_REACH,
           SEED_SINGULAR,
)
from derive.kinematics.fk import _joint_values, _op_dq, _pose_error, fk
from derive.kinematics.pose import as_pose_batch
from derive.kinematics.relate import relate
from derive.model.classify import classify as geometric_classify
from derive.model.geometry import numeric_chain, path_to_end
from derive.model.robot import Op, Robot, load_robot, robot_from_dict

__all__ = ["Nominal", "nominal", "exact_class", "classify", "nominal_class", "polish", "Polished", "fk_jacobian", "solve",
           "NearSolutions", "NearIKSolutions", "describe", "relation_fk", "into_nominal",
           "from_nominal"]


@dataclass(frozen=True)
class Nominal:
    """The nominal robot of a near-class arm and the relation to it.

    robot: an exact robot of a class with a closed form, with the arm's number of joints.
    base, tool: (8,) unit dual quaternions B and T of FK_robot(q) ~= B FK_nominal(s q + o) T.
    signs: (dof,) +1 or -1 per joint variable (s); offsets: (dof,) radians (o).
    deviation: the largest mismatch of that relation (metres or radians) on sample
    configurations; the Newton polish removes it.
    how: one line saying how the nominal robot was found (for messages).
    """

    robot: Robot
    base: np.ndarray
    tool: np.ndarray
    signs: np.ndarray
    offsets: np.ndarray
    deviation: float
    how: str


# --------------------------------------------------------------------------- #
# The nominal robot
# --------------------------------------------------------------------------- #
def nominal(robot) -> Nominal | None:
    """The nominal robot of an arm that has no exact class with a closed form, or None (an
    exact class, or no closed-form class within the tolerances). Memoised per robot identity.

    Routes, in this order:

    1. **the description's ``nominal:`` key** (a calibrated arm, ur5-calibrated.yaml): that
       library robot, with the relation B, T, s fitted by the hand-eye equation
       (:func:`derive.kinematics.relate.relate`) within NEAR_DEVIATION_MAX;
    2. **axes projected onto the class** (a URDF's printed twists 1.570796325, a DH file's
       ``alpha: 1.5708``, axes that miss by fractions of a millimetre): the numeric axis-angle
       chain (:func:`derive.model.geometry.numeric_chain`) in a canonical frame (axis 1 along z,
       the first axis not parallel to it along -y), each axis within NEAR_AXIS_TOL of a
       coordinate axis made that axis (nearly parallel axes become parallel, nearly
       perpendicular ones perpendicular: the fixed angles snapped to multiples of pi/2), the
       axis points' coordinates within NEAR_POINT_TOL of each other made equal (nearly
       intersecting axes intersect), written as an exact description (convention axis_angle,
       lengths as named parameters) whose class is then detected exactly;
    3. **the closest library robot** of the UR family within the calibration tolerance
       (:func:`derive.ik.closed_form.nominal_relation`: a calibrated URDF without the key).

    The nominal robot must have a closed form (UR family, spherical wrist, SRS, Panda class)
    and the relation FK_robot(q) ~= B FK_nominal(s q + o) T must hold within
    NEAR_DEVIATION_MAX on sample configurations; its largest mismatch is ``deviation``."""
    robot = load_robot(robot)
    return memo("nominal", (robot.id, robot.limits_id), lambda: _nominal(robot))


def exact_class(robot) -> str | None:
    """The class whose closed form solves the robot as it is described ("UR", "spherical
    wrist", "three parallel", "Panda", "SRS", "UR (through a library robot)"), or None."""
    robot = load_robot(robot)
    return memo("exact-closed-form-class", robot.id, lambda: _exact_class(robot))


def _exact_class(robot) -> str | None:
    if any(j.is_mimic for j in robot.joints):
        return None
    if robot.dof == 7:
        kind = redundant.redundant_kind(robot)
        return {"panda": "Panda", "srs": "SRS"}.get(kind)
    if robot.dof != 6:
        return None
    try:
        closed_form.ur_geometry(robot)
        return "UR"
    except DeriveError:
        pass
    if closed_form.spherical_class(robot) is not None:
        return "spherical wrist"
    if closed_form.parallel3_class(robot) is not None:
        return "three parallel"
    if closed_form.closed_form_relation(robot) is not None:
        return "UR"
    return None


def _nominal(robot) -> Nominal | None:
    if robot.dof not in (6, 7) or exact_class(robot) is not None:
        return None
    if any(j.type != "revolute" for j in robot.joints) or any(j.is_mimic for j in robot.joints):
        return None
    if robot.nominal:
        lib = load_robot(robot.nominal)
        rel = relate(robot, lib, tol=NEAR_DEVIATION_MAX)
        if rel is not None and exact_class(lib) is not None:
            return Nominal(lib, rel.base, rel.tool, rel.signs.astype(float), np.zeros(robot.dof),
                           rel.error, f"the description's nominal: {lib.name} (relation fitted by "
                           f"the hand-eye equation, largest mismatch {rel.error:.2g} m / rad)")
    nom = _projected(robot)
    if nom is None and robot.dof == 7:
        # a seven-joint arm whose shoulder or wrist axes miss by millimetres (the Kinova Gen3's
        # shoulder by 5.9 mm): the wider projection; it is polished with a joint given
        nom = _projected(robot, NEAR_POINT_TOL_7R, NEAR_DEVIATION_MAX_7R)
    if nom is not None:
        return nom
    if robot.dof == 6:
        rel = closed_form.nominal_relation(robot)
        if rel is not None:
            lib = load_robot(rel.other)
            return Nominal(lib, rel.base, rel.tool, rel.signs.astype(float), np.zeros(6), rel.error,
                           f"the closest library robot {lib.name} within {NEAR_DEVIATION_MAX:g} "
                           f"(largest mismatch {rel.error:.2g} m / rad)")
    return None


def _clusters(values: np.ndarray, tol: float) -> np.ndarray:
    """Each value replaced by the first (in the given order) of its single-linkage cluster:
    values whose sorted neighbours are at most ``tol`` apart form one cluster. 0.0 stays 0.0
    when it is a member (axis 1 passes through the origin)."""
    order = np.argsort(values, kind="stable")
    out = values.copy()
    start = 0
    for i in range(1, len(order) + 1):
        if i == len(order) or values[order[i]] - values[order[i - 1]] > tol:
            members = order[start:i]
            rep = 0.0 if np.any(values[members] == 0.0) else values[members.min()]
            out[members] = rep
            start = i
    return out


def _canonical_rotation(axes: np.ndarray) -> np.ndarray | None:
    """R0 (columns: the canonical x, y, z in the base frame): z along axis 1, -y along the part
    of the first axis far from parallel to it that is perpendicular to axis 1."""
    z = axes[0] / np.linalg.norm(axes[0])
    for a in axes[1:]:
        perp = a - (a @ z) * z
        if np.linalg.norm(perp) > 0.5:
            y = -perp / np.linalg.norm(perp)
            return np.column_stack([np.cross(y, z), y, z])
    return None


def _projected(robot, point_tol: float = NEAR_POINT_TOL,
               deviation_max: float = NEAR_DEVIATION_MAX) -> Nominal | None:
    """Route 2 of :func:`nominal`: the axes projected onto the class, axis points within
    ``point_tol`` (m) merged, the relation's mismatch at most ``deviation_max`` (m, rad)."""
    try:
        chain = numeric_chain(robot)
    except DeriveError:
        return None
    n = chain.n
    if n != robot.dof or chain.variables != tuple(range(n)):
        return None
    r0 = _canonical_rotation(chain.axes)
    if r0 is None:
        return None
    axes = chain.axes @ r0                                     # canonical frame
    snapped = np.zeros_like(axes)
    worst_axis = 0.0
    for i, a in enumerate(axes):
        a = a / np.linalg.norm(a)
        k = int(np.argmax(np.abs(a)))
        e = np.zeros(3)
        e[k] = np.sign(a[k])
        ang = float(np.arctan2(np.linalg.norm(np.cross(a, e)), a @ e))
        if ang > NEAR_AXIS_TOL:
            return None
        worst_axis = max(worst_axis, ang)
        snapped[i] = e
    pts = (chain.start + np.vstack([np.zeros(3), np.cumsum(chain.links, axis=0)])[:n] - chain.start) @ r0
    pts[0] = 0.0
    for c in range(3):
        pts[:, c] = _clusters(pts[:, c], point_tol)
    links = np.vstack([np.diff(pts, axis=0), np.zeros(3)])
    params, joints = {}, []
    for i in range(n):
        link = []
        for c, v in enumerate(links[i]):
            if v == 0.0:
                link.append(0)
            else:
                name = f"l{i + 1}{'xyz'[c]}"
                params[name] = float(v)
                link.append(name)
        jd = {"name": f"j{i + 1}", "axis": [int(v) for v in snapped[i]], "link": link}
        lim = robot.joints[path_to_end(robot)[i]].limits
        if lim is not None:
            jd["limits"] = [float(lim[0]), float(lim[1])]
        joints.append(jd)
    desc = {"name": f"{robot.name}-nominal", "title": f"{robot.title}, nominal (projected onto its class)",
            "source": f"derive.ik.nearclass: the axes of {robot.name} projected onto the class",
            "convention": "axis_angle", "units": {"length": "m", "angle": "rad"},
            "parameters": params, "joints": joints}
    try:
        nrob = robot_from_dict(desc)
    except DeriveError:
        return None
    if exact_class(nrob) is None:
        return None
    base = dq.from_rt(quat.from_matrix(r0), chain.start)
    signs, offsets = np.ones(n), np.zeros(n)
    f_n0 = fk(nrob, np.zeros(n))
    tool = dq._mul(dq._mul(dq.conj_quaternion(f_n0), dq.conj_quaternion(base)), fk(robot, np.zeros(n)))
    dev = _deviation(robot, nrob, base, tool, signs, offsets)
    if not dev <= deviation_max:
        return None
    return Nominal(nrob, base, tool, signs, offsets, dev,
                   f"axes projected onto the class (axes within {worst_axis:.2g} rad of the nominal's, "
                   f"axis points within {point_tol:g} m merged)")


def _deviation(robot, nrob, base, tool, signs, offsets, samples: int = 64, seed: int = 11) -> float:
    """The largest mismatch (m, rad) of FK_robot(q) against B FK_nominal(s q + o) T on random
    configurations."""
    q = np.random.default_rng(seed).uniform(-np.pi, np.pi, (samples, robot.dof))
    pred = relation_fk(Nominal(nrob, base, tool, signs, offsets, 0.0, ""), q)
    dp, dr = _pose_error(pred, fk(robot, q))
    return float(max(dp.max(), dr.max()))


def relation_fk(nom: Nominal, q) -> np.ndarray:
    """B FK_nominal(s q + o) T (n, 8) for the arm's joint values q (n, dof)."""
    q = np.asarray(q, dtype=float).reshape(-1, nom.robot.dof)
    f = fk(nom.robot, q * nom.signs + nom.offsets)
    return dq._mul(dq._mul(np.broadcast_to(nom.base, f.shape), f), np.broadcast_to(nom.tool, f.shape))


def into_nominal(nom: Nominal, poses: np.ndarray) -> np.ndarray:
    """Poses (n, 8) of the arm's end frame as poses of the nominal robot's: B^-1 P T^-1."""
    return dq._mul(dq._mul(dq.conj_quaternion(nom.base)[None], poses), dq.conj_quaternion(nom.tool)[None])


def from_nominal(nom: Nominal, q_n: np.ndarray) -> np.ndarray:
    """The nominal robot's joint values -> the arm's: q = (q_N - o) * s (s = +-1)."""
    return (np.asarray(q_n, dtype=float) - nom.offsets) * nom.signs


# --------------------------------------------------------------------------- #
# The Newton polish
# --------------------------------------------------------------------------- #
class Polished(NamedTuple):
    """:func:`polish`: ``q`` the polished joint values (the shape given), ``residual`` the larger
    of the position error (m) and the rotation angle (rad) of FK(q) against the pose, per
    solution, ``iterations`` the Newton steps taken, ``converged`` residual <= the tolerance
    (NaN rows: residual inf, not converged)."""

    q: np.ndarray
    residual: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray


def fk_jacobian(robot, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The end pose (m, 8) and the geometric Jacobian (m, 6, dof) of configurations q (m, dof):
    rows 0-2 the linear velocity of the end-frame origin, rows 3-5 the angular velocity, both
    in the base frame (the spatial form of Siciliano et al., "Robotics: Modelling, Planning and
    Control", 2009, eq. 3.30: column i = (w_i x (p_e - p_i), w_i) for a revolute joint, (w_i, 0)
    for a prismatic one, w_i and p_i the joint's axis and a point of it from the joint frames
    of the dual-quaternion FK, :mod:`derive.kinematics.fk`). A mimic joint adds its multiplier
    times its column to the column of the variable it follows."""
    robot = load_robot(robot)
    q2 = np.asarray(q, dtype=float).reshape(-1, robot.dof)
    m = len(q2)
    vals = _joint_values(robot, q2)
    ident = np.broadcast_to(dq.IDENTITY, (m, 8))
    frames, axes, points = [], [], []
    for i, j in enumerate(robot.joints):
        pre = ident if j.parent < 0 else frames[j.parent]
        for op in j.pre:
            pre = dq._mul(pre, _op_dq(op))
        axes.append(quat._rotate(pre[:, :4], np.broadcast_to(j.axis, (m, 3))))
        points.append(dq._translation(pre))
        motion = dq._rotation(j.axis, vals[i]) if j.type == "revolute" else dq._translation_dq(
            vals[i][:, None] * j.axis)
        f = dq._mul(pre, motion)
        for op in j.post:
            f = dq._mul(f, _op_dq(op))
        frames.append(f)
    end = robot.ends[robot.default_end]
    pose = frames[end.parent]
    for op in end.ops:
        pose = dq._mul(pose, _op_dq(op))
    pe = dq._translation(pose)
    jac = np.zeros((m, 6, robot.dof))
    for k in path_to_end(robot):
        j = robot.joints[k]
        w = axes[k]
        if j.type == "revolute":
            col = np.concatenate([np.cross(w, pe - points[k]), w], axis=1)
        else:
            col = np.concatenate([w, np.zeros_like(w)], axis=1)
        jac[:, :, j.variable] += j.multiplier * col
    return pose, jac


def _twist_error(target: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """(m, 6): the position error t_target - t and the rotation vector of R_target R^T (base
    frame), the error the geometric Jacobian maps joint steps onto."""
    dp = dq._translation(target) - dq._translation(pose)
    r = quat._mul(target[:, :4], quat._conj(pose[:, :4]))
    r = np.where(r[:, :1] < 0, -r, r)
    vn = np.linalg.norm(r[:, 1:], axis=1)
    angle = 2.0 * np.arctan2(vn, r[:, 0])
    scale = np.where(vn > 1e-300, angle / np.where(vn > 1e-300, vn, 1.0), 2.0)
    return np.concatenate([dp, r[:, 1:] * scale[:, None]], axis=1)


def polish(robot, poses, q, fixed=None, *, tol: float = POLISH_TOL,
           max_iter: int = POLISH_MAX_ITER, monotone=None) -> Polished:
    """Newton steps on the arm's own forward kinematics: every configuration of ``q`` moved onto
    an exact solution of its pose.

    ``poses``: (n, 8) unit dual quaternions or (n, 4, 4) matrices of the default end frame;
    ``q``: (n, dof) or (n, k, dof) starting configurations (k candidates per pose; NaN rows are
    left alone); ``fixed``: joint indices (0-based) or a (dof,) bool mask of joints held at
    their starting values (a seven-joint arm with one joint given).

    The method is the damped least-squares (Levenberg-Marquardt) iteration of Wampler, "Manipulator
    inverse kinematic solutions based on vector formulations and damped least-squares methods",
    IEEE SMC 16(1), 1986, and Nakamura & Hanafusa, "Inverse kinematic solutions with singularity
    robustness for robot manipulator control", J. Dyn. Sys. Meas. Control 108, 1986:
    dq = (J^T J + lambda I)^-1 J^T e, with J the geometric Jacobian of the free joints
    (:func:`fk_jacobian`) and e the twist error (:func:`_twist_error`). lambda starts at 1e-12
    (a Gauss-Newton step, quadratic convergence from the nominal closed form's candidates),
    grows tenfold when a step does not lower |e|^2 (the step is then rejected) and shrinks
    tenfold after an accepted one; a step larger than POLISH_MAX_STEP in any joint is scaled
    down. Converged: residual max(|dp| m, rotation angle rad) <= ``tol`` (POLISH_TOL), at most
    ``max_iter`` steps.

    Two passes: Newton steps always taken (:func:`_newton_free`), then, from the same starts
    where that failed, the monotone iteration above (:func:`_newton`). ``monotone``: None (every
    start), or a bool mask of q's shape without its last axis: the starts that get the second
    pass (:func:`solve` leaves the seeds near singular sets out: they approach a root in the first
    pass or not at all, and the second pass was most of the time of a calibrated UR5)."""
    robot = load_robot(robot)
    P, _ = as_pose_batch(poses)
    q = np.asarray(q, dtype=float)
    shape = q.shape
    if q.ndim not in (2, 3) or shape[-1] != robot.dof or shape[0] != len(P):
        raise InputError(f"q: expected shape ({len(P)}, {robot.dof}) or ({len(P)}, k, {robot.dof}), "
                         f"got {shape}")
    k = shape[1] if q.ndim == 3 else 1
    x = q.reshape(-1, robot.dof).copy()
    target = np.repeat(P, k, axis=0)
    free = _free_mask(robot.dof, fixed)
    m = len(x)
    residual = np.full(m, np.inf)
    iters = np.zeros(m, dtype=np.int64)
    idx = np.nonzero(np.all(np.isfinite(x), axis=1))[0]
    if len(idx):
        model = lambda z, t: _model(robot, z, t)  # noqa: E731
        x0 = x[idx].copy()
        x[idx], residual[idx], iters[idx] = _newton_free(model, target[idx], x0, free, tol, max_iter)
        again = idx[~(residual[idx] <= tol)]
        if monotone is not None:
            again = again[np.asarray(monotone, dtype=bool).reshape(-1)[again]]
        if len(again):      # the monotone iteration from the same starts where that one failed
            sub = np.searchsorted(idx, again)
            xa, ra, ia = _newton(model, target[again], x0[sub], free, tol, max_iter)
            better = ra < residual[again]
            x[again[better]], residual[again[better]] = xa[better], ra[better]
            iters[again] += ia
    return Polished(x.reshape(shape), residual.reshape(shape[:-1]), iters.reshape(shape[:-1]),
                    (residual <= tol).reshape(shape[:-1]))


def _free_mask(dof: int, fixed) -> np.ndarray:
    free = np.ones(dof, dtype=bool)
    if fixed is not None:
        fx = np.asarray(fixed)
        if fx.dtype == bool:
            free &= ~fx
        else:
            free[fx.astype(int)] = False
    return free


def _model(robot, x, target):
    """(twist error (m, 6), Jacobian (m, 6, dof), residual (m,)) of the robot at x."""
    pose, jac = fk_jacobian(robot, x)
    return _twist_error(target, pose), jac, _residual(target, pose)


def _newton_free(model, target, x, free, tol, max_iter):
    """The first pass of :func:`polish`: Newton steps that are always taken (no test that |e|
    falls), damped by mu = |e|^2 (Yamashita and Fukushima, "On the rate of convergence of the
    Levenberg-Marquardt method", Computing Suppl. 15, 2001: quadratic convergence kept) and
    clipped to POLISH_MAX_STEP in their largest joint, as the emitted kernels do
    (:mod:`derive.codegen.polish`). Near a singular set the way to a solution often climbs
    before it falls, which the monotone iteration (:func:`_newton`) refuses. (x, residual,
    iterations)."""
    xs = x.copy()
    it = np.zeros(len(xs), dtype=np.int64)
    res = np.full(len(xs), np.inf)
    active = np.ones(len(xs), dtype=bool)
    nfree = int(free.sum())
    eye = np.eye(nfree)
    for k in range(max_iter + 1):
        a = np.nonzero(active)[0]
        if len(a) == 0:
            break
        err, jac, r = model(xs[a], target[a])
        res[a] = r
        go = (r > tol) & np.isfinite(r)
        active[a[~go]] = False
        if k == max_iter or not go.any():
            break
        a, err, jac = a[go], err[go], jac[go]
        jf = jac[:, :, free]
        jt = np.swapaxes(jf, 1, 2)
        mu = np.einsum("ij,ij->i", err, err)
        step = np.linalg.solve(jt @ jf + mu[:, None, None] * eye, (jt @ err[..., None]))[..., 0]
        big = np.abs(step).max(axis=1, initial=0.0)
        step *= np.minimum(1.0, POLISH_MAX_STEP / np.where(big > 0, big, 1.0))[:, None]
        ok = np.all(np.isfinite(step), axis=1)
        active[a[~ok]] = False
        rows = a[ok]
        sub = xs[rows]
        sub[:, free] += step[ok]
        xs[rows] = sub
        it[rows] += 1
    return xs, res, it


def _newton(model, target, x, free, tol, max_iter):
    """The damped least-squares iteration of :func:`polish` on rows x (m, dof) for the error
    model ``model(x, target) -> (e, J, residual)``: (x, residual, iterations)."""
    xs = x.copy()
    lam = np.full(len(xs), 1e-12)
    err, jac, res = model(xs, target)
    cost = np.einsum("ij,ij->i", err, err)
    it = np.zeros(len(xs), dtype=np.int64)
    active = res > tol
    eye = np.eye(int(free.sum()))
    for _ in range(max_iter):
        a = np.nonzero(active)[0]
        if len(a) == 0:
            break
        jf = jac[a][:, :, free]
        jt = np.swapaxes(jf, 1, 2)
        lhs = jt @ jf + lam[a, None, None] * eye
        rhs = (jt @ err[a][..., None])[..., 0]
        try:
            step = np.linalg.solve(lhs, rhs[..., None])[..., 0]
        except np.linalg.LinAlgError:
            step = np.stack([np.linalg.lstsq(l, r, rcond=None)[0] for l, r in zip(lhs, rhs)])
        big = np.abs(step).max(axis=1, initial=0.0)
        step *= np.minimum(1.0, POLISH_MAX_STEP / np.where(big > 0, big, 1.0))[:, None]
        trial = xs[a].copy()
        trial[:, free] += step
        terr, tjac, tres = model(trial, target[a])
        tcost = np.einsum("ij,ij->i", terr, terr)
        ok = tcost < cost[a]
        acc = a[ok]
        xs[acc], jac[acc], err[acc], cost[acc], res[acc] = trial[ok], tjac[ok], terr[ok], tcost[ok], tres[ok]
        lam[acc] = np.maximum(lam[acc] * 0.1, 1e-15)
        lam[a[~ok]] *= 10.0
        it[a] += 1
        active[a] = (res[a] > tol) & (lam[a] < 1e6)
    return xs, res, it


def track(robot, nom: Nominal, poses, q, fixed=None, stages=HOMOTOPY_STAGES):
    """Carry candidates of the nominal's relation onto the arm by a convex homotopy (Allgower &
    Georg, "Introduction to Numerical Continuation Methods", 1990, ch. 1: H(q, s) = (1 - s)
    e_nominal(q) + s e_arm(q), the twist errors of B FK_N(s q + o) T and of the arm's FK
    against the pose): a few damped Newton steps (:func:`polish`'s iteration) at each s of
    ``stages``, from q (exact at s = 0). Used before :func:`polish` when the nominal deviates by
    more than HOMOTOPY_FROM, where Newton from the nominal's candidates straight onto the arm
    can fall onto another branch. Returns q (same shape, NaN rows kept)."""
    robot = load_robot(robot)
    P, _ = as_pose_batch(poses)
    q = np.asarray(q, dtype=float)
    shape = q.shape
    k = shape[1] if q.ndim == 3 else 1
    x = q.reshape(-1, robot.dof).copy()
    target = np.repeat(P, k, axis=0)
    idx = np.nonzero(np.all(np.isfinite(x), axis=1))[0]
    if len(idx) == 0:
        return x.reshape(shape)
    free = _free_mask(robot.dof, fixed)
    rel = relation_robot(nom)
    xs, tg = x[idx], target[idx]
    for s in stages:
        def model(z, t, s=s):
            e1, j1, _ = _model(rel, z, t)
            e2, j2, _ = _model(robot, z, t)
            e = (1.0 - s) * e1 + s * e2
            return e, (1.0 - s) * j1 + s * j2, np.linalg.norm(e, axis=1)
        xs, _, _ = _newton(model, tg, xs, free, POLISH_TOL, HOMOTOPY_STEPS)
    x[idx] = xs
    return x.reshape(shape)


def relation_robot(nom: Nominal) -> Robot:
    """The nominal robot with B before its first joints, T after its end frame, and the joint
    variables s q + o: a Robot whose FK is B FK_nominal(s q + o) T (for :func:`track`)."""
    return memo("nominal-relation-robot", (nom.robot.id, nom.base.tobytes(), nom.tool.tobytes(),
                                           nom.signs.tobytes(), nom.offsets.tobytes()),
                lambda: _relation_robot(nom))


def _ops(d: np.ndarray) -> tuple:
    r, t = dq.to_rt(d)
    r = r / np.linalg.norm(r)
    vn = np.linalg.norm(r[1:])
    ops = (Op.trans(t),)
    if vn > 0:
        ops += (Op.rot(r[1:] / vn, 2.0 * np.arctan2(vn, r[0])),)
    return ops


def _relation_robot(nom: Nominal) -> Robot:
    rob = nom.robot
    pre_b, post_t = _ops(nom.base), _ops(nom.tool)
    joints = []
    for j in rob.joints:
        kw = {}
        if j.parent < 0:
            kw["pre"] = pre_b + tuple(j.pre)
        if not j.is_mimic:
            kw["multiplier"] = float(nom.signs[j.variable]) * j.multiplier
            kw["offset"] = float(j.offset) + float(nom.offsets[j.variable])
        joints.append(dataclasses.replace(j, **kw))
    ends = {name: dataclasses.replace(e, ops=tuple(e.ops) + (post_t if name == rob.default_end else ()))
            for name, e in rob.ends.items()}
    return dataclasses.replace(rob, name=f"{rob.name}-related", joints=tuple(joints), ends=ends,
                               id=f"{rob.id}-related", exact=False)


def _residual(target, pose) -> np.ndarray:
    dp, dr = _pose_error(pose, target)
    return np.maximum(dp, dr)


# --------------------------------------------------------------------------- #
# Solving a near-class arm
# --------------------------------------------------------------------------- #
class NearSolutions(NamedTuple):
    """:func:`solve` for n poses: ``q`` (n, w, dof) NaN-padded (valid rows first; w = 8, or the
    largest count where a pose has more: near its singular sets an arm off its class can have
    more solutions than the class, at most 16), ``counts`` (n,), ``singular`` (n, w) (the nominal's candidate lay on its singular set), ``residual``
    (n, w) the residual after the polish (max of position error m and rotation angle rad; NaN in
    the padding), ``iterations`` (n, w) the Newton steps (-1 in the padding), ``dropped`` (n,)
    candidates the nominal closed form gave that did not converge, ``reasons`` (n,) why a pose
    has no solution ('' when it has)."""

    q: np.ndarray
    counts: np.ndarray
    singular: np.ndarray
    residual: np.ndarray
    iterations: np.ndarray
    dropped: np.ndarray
    reasons: list


#: The most solutions kept per pose: an arm a little off its class is a general 6R (or, with a
#: joint given, a general 6R sub-chain), which has at most 16; the nominal class has 8.
_MAX_SOLUTIONS = 16

REASON_NOT_CONVERGED = ("no solution found: no candidate of the nominal closed form converged under "
                        "the Newton polish on this arm's FK (near a singular set of the nominal two "
                        "solutions can share one candidate; derive.refine searches from other starts)")


def _candidates(nom: Nominal, pn: np.ndarray, qr_n, given):
    """Candidates of the nominal robot (n, 8, dof) in its joint values, whether the nominal
    reaches them (n, 8), singular flags (n, 8) and reasons (n,)."""
    nrob = nom.robot
    n = len(pn)
    if nrob.dof == 7:
        joint, value = given
        if redundant.redundant_kind(nrob) == "panda":
            if joint != 6:
                raise InputError(f"{nrob.name}: the Panda class is solved with joint 7 given")
            r = panda.ik_q7(nrob, pn, value, q_ref=qr_n)
            q, sing, reasons = r.q, r.singular, list(r.reasons)
        else:
            r = srs.ik_joint(nrob, pn, joint + 1, value, q_ref=qr_n)
            q, sing, reasons = r.q, r.singular, [str(x) for x in r.reason]
            out = r.count == 0
            if np.any(out):         # just out of the nominal's reach: seeds from the reach's edge
                r2 = srs.ik_joint(nrob, _within_reach(nrob, pn[out]), joint + 1, value[out],
                                  q_ref=None if qr_n is None else qr_n[out])
                q = q.copy()
                q[out] = r2.q
                sing = sing.copy()
                sing[out] = r2.singular
                still = np.zeros(n, dtype=bool)
                still[np.nonzero(out)[0][r2.count == 0]] = True
                if np.any(still):   # the given joint just out of the nominal's range for the pose
                    q, sing = _psi_seeds(nrob, pn, q, sing, still, joint, value)
                return q, np.all(np.isfinite(q), -1) & ~out[:, None], sing, reasons
        return q, np.all(np.isfinite(q), -1), sing, reasons
    geo = closed_form.spherical_class(nrob)
    if geo is not None:
        q, sing, code = spherical.solve_batch(geo, pn, None if qr_n is None else qr_n[:, 3],
                                              keep_unreachable=True)
        why = (spherical.REASON_LATERAL, spherical.REASON_REACH)
        q = _near_reach(nrob, pn, q, code, nom.deviation)
    else:
        try:
            ugeo = closed_form.ur_geometry(nrob)
        except DeriveError:
            q, counts, sing, reasons = closed_form._solve_related(nrob, pn, qr_n)
            return q, np.all(np.isfinite(q), -1), sing, reasons
        q, sing, code = closed_form.solve_batch(ugeo, pn, None if qr_n is None else qr_n[:, 5],
                                                keep_unreachable=True)
        out = np.all(code == 1, axis=1)
        if np.any(out):             # the wrist centre just inside the nominal's d4 cylinder
            extra = []
            for t in (1e-9 * abs(ugeo.d4),) + tuple(f * nom.deviation for f in (0.25, 0.5, 1.0)):
                q2, _, _ = closed_form.solve_batch(ugeo, _outside_d4(ugeo, pn[out], t),
                                                   None if qr_n is None else qr_n[out, 5],
                                                   keep_unreachable=True)
                extra.append(q2)
            pad = np.full((n, 8 * len(extra), 6), np.nan)
            pad[out] = np.concatenate(extra, axis=1)
            q = np.concatenate([np.where(out[:, None, None], np.nan, q), pad], axis=1)
            sing = np.concatenate([sing, np.zeros((n, pad.shape[1]), dtype=bool)], axis=1)
            code = np.concatenate([code, np.ones((n, pad.shape[1]), dtype=code.dtype)], axis=1)
        why = (closed_form.REASON_WRIST_NEAR_AXIS, closed_form.REASON_ARM_REACH)
        q = _near_reach(nrob, pn, q, code, nom.deviation)
        q, sing, code = _elbow_seeds(q, sing, code, nom.deviation)
    reasons = [why[0] if np.all(c == 1) else why[1] if np.all(c > 0) else "" for c in code]
    return q, (code == 0) & np.all(np.isfinite(q), -1), sing, reasons


def _singular_seeds(robot, start: np.ndarray, fixed, deviation: float) -> np.ndarray:
    """Extra seeds (n, m, dof) for the candidates (n, k, dof) that lie near a singular set of the
    arm: where the smallest singular value of the Jacobian of the free joints over the largest
    is below SEED_SINGULAR sqrt(deviation) (Newton from a candidate off by deviation / s_min
    stays on its root while that is small against the root's basin, about s_min / curvature:
    s_min^2 against the deviation), two of the arm's solutions can lie within one candidate's deviation
    (the two elbow roots of a nearly stretched arm, the two wrist roots where sin q5 is about
    the deviation; a nearly free joint along the whole circle), and Newton from the one
    candidate finds one of them. Seeds on both sides along the singular direction v (the right
    singular vector of the smallest singular value, unit in rad): q + t v for t in +-sqrt(dev),
    +-3 sqrt(dev) (a fold: the roots part as the square root of the offset) and +-pi/4, +-pi/2,
    +-3 pi/4, pi (a joint pair that is nearly free). NaN where no seed is needed."""
    n, k, dof = start.shape
    free = _free_mask(dof, fixed)
    flat = start.reshape(-1, dof)
    rows = np.nonzero(np.all(np.isfinite(flat), axis=1))[0]
    if len(rows) == 0:
        return np.full((n, 0, dof), np.nan)
    _, jac = fk_jacobian(robot, flat[rows])
    u, sv, vt = np.linalg.svd(jac[:, :, free])
    r = np.sqrt(max(deviation, 1e-12))
    near = sv[:, -1] < SEED_SINGULAR * r * sv[:, 0]
    if not near.any():
        return np.full((n, 0, dof), np.nan)
    ts = np.array([r, -r, 3 * r, -3 * r, np.pi / 4, -np.pi / 4, np.pi / 2, -np.pi / 2,
                   3 * np.pi / 4, -3 * np.pi / 4, np.pi])
    v = np.zeros((int(near.sum()), dof))
    v[:, free] = vt[near, -1, :]
    which = rows[near]
    seeds = flat[which][:, None, :] + ts[None, :, None] * v[:, None, :]
    pose_of, cand_of = np.divmod(which, k)
    # per pose, its near-singular candidates' seeds side by side
    slot = np.zeros(len(which), dtype=np.int64)
    order = np.argsort(pose_of, kind="stable")
    _, first, cnt = np.unique(pose_of[order], return_index=True, return_counts=True)
    slot[order] = np.arange(len(which)) - np.repeat(first, cnt)
    width = int(slot.max()) + 1
    out = np.full((n, width, len(ts), dof), np.nan)
    out[pose_of, slot] = seeds
    return out.reshape(n, width * len(ts), dof)


def _near_reach(nrob, pn, q, code, deviation):
    """The seeds of branches the nominal does not reach (code > 0, square roots clipped) kept
    only where the nominal comes within SEED_REACH * deviation of the pose (m, rad): only there
    can the arm, which deviates by at most ``deviation``, reach on that branch. Seeds whose
    wrist (joint 5, the middle angle of the nominal's wrist decomposition) is within that of its
    singular set are kept too: there the nominal's joint 6, and so its arm plane, moves by
    about deviation / |sin q5|, so its miss says nothing about the arm."""
    far = (code > 0) & np.all(np.isfinite(q), -1) & ~(np.abs(np.sin(q[..., 4])) < SEED_REACH * deviation)
    if not np.any(far):
        return q
    n, k = code.shape
    rows = np.nonzero(far.reshape(-1))[0]
    dp, dr = _pose_error(fk(nrob, q.reshape(-1, q.shape[-1])[rows]), np.repeat(pn, k, axis=0)[rows])
    drop = rows[np.maximum(dp, dr) > SEED_REACH * deviation + 1e-12]
    q = q.copy().reshape(-1, q.shape[-1])
    q[drop] = np.nan
    return q.reshape(n, k, -1)


def _elbow_seeds(q, sing, code, deviation):
    """Where the nominal's elbow (theta3) is out of reach on a branch (code 2: its cosine
    clipped, t3 at 0 or pi, a double root), the arm may still reach with two elbow roots close
    to it: extra seeds with t3 moved by +-sqrt(deviation) and +-2 sqrt(deviation) (rad; a
    clipped cosine root moves as the square root of the pose's offset) are added."""
    far = (code == 2) & np.all(np.isfinite(q), -1)
    if not np.any(far):
        return q, sing, code
    d = np.sqrt(max(deviation, 1e-12))
    extra = []
    for delta in (-2 * d, -d, d, 2 * d):
        e = np.where(far[..., None], q, np.nan).copy()
        e[..., 2] += delta
        extra.append(e)
    n, k = code.shape
    return (np.concatenate([q] + extra, axis=1),
            np.concatenate([sing] + [np.zeros((n, k), dtype=bool)] * 4, axis=1),
            np.concatenate([code] + [np.full((n, k), 2, dtype=code.dtype)] * 4, axis=1))


def _outside_d4(geo, pn: np.ndarray, margin: float) -> np.ndarray:
    """Poses of a UR nominal with the frame-5 point moved radially out of the cylinder of
    radius |d4| about axis 1 (to |d4| + margin), the rotation kept: the nearest poses whose
    theta1 the nominal solves (:mod:`derive.ik.closed_form`, step 1), as seeds for an arm whose
    own cylinder is a little narrower."""
    r, p = closed_form._chain_pose(geo, pn)
    p5 = p + geo.d6 * r[:, :, 1]
    rad = np.hypot(p5[:, 0], p5[:, 1])
    want = abs(geo.d4) + margin
    scale = np.where(rad > 0, want / np.where(rad > 0, rad, 1.0), 1.0) - 1.0
    shift = np.zeros_like(p5)
    shift[:, 0], shift[:, 1] = p5[:, 0] * scale, p5[:, 1] * scale
    shift[rad == 0, 0] = want
    return dq._from_rt(pn[:, :4], dq._translation(pn) + shift)


def _psi_seeds(nrob, pn, q, sing, rows, joint: int, value, count: int = 8):
    """Seeds for poses whose SRS nominal has no solution with the given joint at its value (the
    arm, a little off, may have some): the nominal's solutions at ``count`` arm angles spread
    over (-pi, pi] (:func:`derive.ik.srs.ik_psi`), the given joint then set to its value (the
    polish holds it and moves the others)."""
    reach = _within_reach(nrob, pn[rows])
    extra = []
    for psi in np.linspace(-np.pi, np.pi, count, endpoint=False):
        r = srs.ik_psi(nrob, reach, np.full(len(reach), psi))
        extra.append(r.q)
    e = np.concatenate(extra, axis=1)
    e[..., joint] = np.where(np.isfinite(e[..., joint]), value[rows][:, None], np.nan)
    n, k, dof = q.shape
    pad = np.full((n, e.shape[1], dof), np.nan)
    pad[rows] = e
    return (np.concatenate([q, pad], axis=1),
            np.concatenate([sing, np.zeros((n, e.shape[1]), dtype=bool)], axis=1))


def _within_reach(nrob, pn: np.ndarray) -> np.ndarray:
    """Poses of an SRS nominal with the wrist centre moved along the shoulder-wrist line into
    the reach [|d_se - d_ew|, d_se + d_ew] (shrunk by 1e-9 relative), the rotation kept: the
    nearest poses the nominal reaches, whose solutions seed the polish of an arm that reaches
    a little farther (the square roots clipped, as keep_unreachable does for the 6R classes)."""
    geo = srs.srs_geometry(nrob)
    rc, w = srs._into_canonical(geo, pn)
    d = np.linalg.norm(w, axis=1)
    lo, hi = abs(geo.d_se - geo.d_ew) * (1 + 1e-9), (geo.d_se + geo.d_ew) * (1 - 1e-9)
    dn = np.clip(d, lo, hi)
    shift = (geo.frame @ (w * (dn / np.where(d > 0, d, 1.0) - 1.0)[:, None])[..., None])[..., 0]
    r, t = pn[:, :4], dq._translation(pn) + shift
    return dq._from_rt(r, t)


def solve(robot, poses, q_ref=None, given=None, chunk: int = 8192) -> NearSolutions:
    """Every solution of a near-class arm (:func:`nominal` not None) for poses (n, 8) or
    (n, 4, 4): the nominal closed form on B^-1 P T^-1 (every branch, the unreachable ones
    included as seeds with their square roots clipped), the candidates mapped back
    (q = (q_N - o) s), polished on the arm's own FK (:func:`polish`), those that do not converge
    dropped, duplicates (every joint within MERGE_TOL modulo 2 pi) merged, revolute joints
    wrapped to (-pi, pi].

    ``q_ref`` (n, dof) or None: the joint a singular set leaves free is taken from it.
    ``given``: for a seven-joint arm, (joint index 0-based, values (n,)): joint 3 of the SRS
    class (index 2) or joint 7 of the Panda class (index 6), held through the polish."""
    robot = load_robot(robot)
    nom = nominal(robot)
    if nom is None:
        raise DeriveError(f"{robot.name}: no nominal robot of a class with a closed form")
    P, _ = as_pose_batch(poses)
    n, dof = len(P), robot.dof
    width = _MAX_SOLUTIONS
    q_all = np.full((n, width, dof), np.nan)
    sing_all = np.zeros((n, width), dtype=bool)
    res_all = np.full((n, width), np.nan)
    it_all = np.full((n, width), -1, dtype=np.int64)
    counts = np.zeros(n, dtype=np.int64)
    dropped = np.zeros(n, dtype=np.int64)
    reasons = [""] * n
    rev = robot.revolute
    for s in range(0, n, chunk):
        e = min(n, s + chunk)
        pn = into_nominal(nom, P[s:e])
        qr_n = None if q_ref is None else q_ref[s:e] * nom.signs + nom.offsets
        g = None
        fixed = None
        if given is not None:
            joint, value = given
            g = (joint, value[s:e] * nom.signs[joint] + nom.offsets[joint])
            fixed = [joint]
        cand, reached, sing, why = _candidates(nom, pn, qr_n, g)
        k = cand.shape[1]
        start = from_nominal(nom, cand)
        if given is not None:
            start[..., given[0]] = np.where(np.isfinite(start[..., given[0]]), given[1][s:e, None], np.nan)
        if nom.deviation > HOMOTOPY_FROM:
            start = track(robot, nom, P[s:e], start, fixed=fixed)
        extra = _singular_seeds(robot, start, fixed, nom.deviation)
        second = np.ones(start.shape[:2], dtype=bool)
        if extra.shape[1]:
            second = np.concatenate([second, np.zeros(extra.shape[:2], dtype=bool)], axis=1)
            start = np.concatenate([start, extra], axis=1)
            sing = np.concatenate([sing, np.zeros(extra.shape[:2], dtype=bool)], axis=1)
            reached = np.concatenate([reached, np.zeros(extra.shape[:2], dtype=bool)], axis=1)
            k = start.shape[1]
        pol = polish(robot, P[s:e], start, fixed=fixed, monotone=second)
        dropped[s:e] = (reached & ~pol.converged).sum(1)
        # the converged candidates first (in candidate order), the columns no pose fills cut
        front = np.argsort(~pol.converged, axis=1, kind="stable")
        kc = max(1, int(pol.converged.sum(1).max(initial=0)))
        front = front[:, :kc]
        ok = np.take_along_axis(pol.converged, front, 1)
        sing = np.take_along_axis(sing, front, 1)
        residual = np.take_along_axis(pol.residual, front, 1)
        iterations = np.take_along_axis(pol.iterations, front, 1)
        q = np.take_along_axis(pol.q, front[..., None], 1)
        q = np.where(rev, wrap_angle(q), q)
        k = kc
        q[~ok] = np.nan
        keep = ok.copy()
        for i in np.nonzero(ok.any(axis=0))[0]:
            if i == 0:
                continue
            rows = np.nonzero(ok[:, i])[0]
            d = q[rows, i:i + 1] - q[rows, :i]
            d = np.abs(np.where(rev, wrap_angle(d), d))
            keep[rows, i] &= ~np.any(np.all(d < MERGE_TOL, axis=-1) & keep[rows, :i], axis=1)
        order = np.argsort(~keep, axis=1, kind="stable")
        kept = np.take_along_axis(keep, order, 1)
        q = np.take_along_axis(q, order[..., None], 1)
        q[~kept] = np.nan
        m = min(k, width)
        q_all[s:e, :m] = q[:, :m]
        sing_all[s:e, :m] = (np.take_along_axis(sing, order, 1) & kept)[:, :m]
        res_all[s:e, :m] = np.where(kept, np.take_along_axis(residual, order, 1), np.nan)[:, :m]
        it_all[s:e, :m] = np.where(kept, np.take_along_axis(iterations, order, 1), -1)[:, :m]
        counts[s:e] = kept.sum(1)
        for i in range(e - s):
            if counts[s + i] == 0:
                # the nominal's reason says why the nominal misses the pose; the arm itself is only
                # known to be unreachable where no clipped candidate came near it either
                reasons[s + i] = (why[i] if why[i] and not reached[i].any() and not np.isfinite(start[i]).any()
                                  else (f"{why[i]} for the nominal robot, and no candidate converged on this arm"
                                        if why[i] and not reached[i].any() else REASON_NOT_CONVERGED))
    w = max(8, int(counts.max(initial=0)))
    return NearSolutions(q_all[:, :w], counts, sing_all[:, :w], res_all[:, :w], it_all[:, :w], dropped, reasons)


def classify(robot):
    """:func:`derive.ik.closed_form.classify` (``derive.classify``), and for an arm with no exact
    class but a nominal robot of one: ``closed_form`` True and one note naming the class, the
    nominal class and the polish ("class: general; nominal class: UR within 0.016 m / rad (...);
    closed-form IK: the nominal's closed form + Newton polish ..."), the notes that said
    derive.refine solves it or that there is no closed form dropped."""
    robot = load_robot(robot)
    c = closed_form.classify(robot)
    if c.closed_form or exact_class(robot) is not None:
        return c
    line = describe(robot)
    if not line:
        return c
    # also the geometric SRS note's "free=psi": psi is defined on the exact class only
    stale = ("derive.refine", "no closed form", "implements none", "a calibrated arm", "free=psi")
    notes = [n for n in c.notes if not any(k in n for k in stale)]
    if c.cls == "SRS" and robot.dof == 7:
        # the geometric SRS test (spherical shoulder and wrist) holds, the exact closed form does not
        try:
            srs.srs_geometry(robot)
        except DeriveError as exc:
            notes.append("the exact SRS closed form does not apply as described: "
                         + str(exc).split(": ", 1)[-1])
    return dataclasses.replace(c, closed_form=True, notes=notes + [f"class: {c.cls}; {line}"])


def nominal_class(robot) -> str:
    """The class (:func:`derive.model.classify.classify`: "UR", "OPW", "SRS", ...) of the arm's
    nominal robot ("" without one)."""
    nom = nominal(robot)
    return "" if nom is None else geometric_classify(nom.robot).cls


def describe(robot) -> str:
    """One line for messages: the nominal class, the deviation and how the arm is solved (""
    for an arm without a nominal), e.g. "nominal class: UR within 1.5e-05 m / rad (...);
    closed-form IK: the nominal's closed form + Newton polish"."""
    nom = nominal(robot)
    if nom is None:
        return ""
    return (f"nominal class: {nominal_class(robot)} within {nom.deviation:.2g} m / rad "
            f"(nominal robot {nom.robot.name}: {nom.how}); closed-form IK: the nominal's closed "
            f"form + Newton polish on this arm's FK (derive.reference.ik; converged to "
            f"{POLISH_TOL:g} m / rad, candidates that do not converge dropped)")


class NearIKSolutions(IKSolutions):
    """:class:`derive.ik.closed_form.IKSolutions` of a near-class arm, with per solution
    ``residual`` (k,) (max of position error m and rotation angle rad after the polish) and
    ``iterations`` (k,) (Newton steps), and ``polish``: one line saying how the solutions were
    found and how many candidates were dropped."""

    _ROW_ATTRS = ("singular", "residual", "iterations")

    def __new__(cls, q, singular, reason="", residual=(), iterations=(), polish=""):
        obj = super().__new__(cls, q, singular, reason)
        obj.residual = np.asarray(residual, dtype=float)
        obj.iterations = np.asarray(iterations, dtype=np.int64)
        obj.polish = polish
        return obj

    def __array_finalize__(self, obj):
        super().__array_finalize__(obj)
        if obj is not None:
            self.residual = getattr(obj, "residual", None)
            self.iterations = getattr(obj, "iterations", None)
            self.polish = getattr(obj, "polish", "")


def _given(robot, nom: Nominal, free, free_name, n: int):
    """(joint index, values (n,)) of a seven-joint near-class arm's given joint, or None (6R)."""
    kind = redundant.redundant_kind(nom.robot)
    if robot.dof != 7:
        if free is not None:
            raise InputError(f"free: {robot.name} has {robot.dof} joint variables and no free parameter")
        return None
    if free is None:
        raise InputError(f"free: {robot.name} has 7 joints (nominal class {exact_class(nom.robot)}): "
                         "give the value of the joint held, free=v with "
                         + ("free_name='q3' (joint 3; dq-derive ik: --free V --free-joint 3)"
                            if kind == "srs" else "q7 (joint 7; dq-derive ik: --free V)"))
    if kind == "srs":
        if free_name != "q3":
            raise InputError(f"free_name: {robot.name} is solved through its nominal SRS robot with joint "
                             "3 given (free_name='q3'; dq-derive ik: --free V --free-joint 3); the "
                             "arm angle psi is defined on the exact class only")
        joint = 2
    else:
        if free_name not in (None, "q7"):
            raise InputError(f"free_name: {robot.name} (nominal Panda class) takes q7 as the free parameter")
        joint = 6
    return joint, redundant.free_values(free, n)


def ik_batch(robot, poses, q_ref=None, *, free=None, free_name=None) -> NearSolutions:
    """:func:`solve` with the arguments of :func:`derive.reference.ik_batch`: ``q_ref`` (dof,) or
    (n, dof), ``free`` the given joint's value(s) of a seven-joint arm (joint 3 with
    ``free_name="q3"`` for the SRS class, joint 7 for the Panda class)."""
    robot = load_robot(robot)
    nom = nominal(robot)
    if nom is None:
        raise DeriveError(f"{robot.name}: no nominal robot of a class with a closed form"
                          + (f" (it has an exact class, {exact_class(robot)}: use derive.reference.ik)"
                             if exact_class(robot) else ""))
    P, _ = as_pose_batch(poses)
    n = len(P)
    qr = None
    if q_ref is not None:
        qr = as_finite_array(q_ref, "q_ref", last_dim=robot.dof)
        if qr.ndim > 2 or (qr.ndim == 2 and qr.shape[0] not in (1, n)):
            raise InputError(f"q_ref: expected shape ({robot.dof},) or ({n}, {robot.dof}), got {qr.shape}")
        qr = np.broadcast_to(qr.reshape(-1, robot.dof), (n, robot.dof)).astype(float)
    return solve(robot, P, q_ref=qr, given=_given(robot, nom, free, free_name, n))


def ik(robot, pose, q_ref=None, within_limits: bool = False, sort_by=None, *, free=None,
       free_name=None) -> NearIKSolutions:
    """Every solution of one pose of a near-class arm as :class:`NearIKSolutions` (``residual``,
    ``iterations``, ``polish`` besides ``singular`` and ``reason``); ``within_limits`` and
    ``sort_by`` as in :func:`derive.ik.closed_form.ik`."""
    robot = load_robot(robot)
    P, single = as_pose_batch(pose)
    if not single:
        raise InputError("pose: ik() takes one pose; use ik_batch() for several")
    r = ik_batch(robot, P, q_ref, free=free, free_name=free_name)
    k = int(r.counts[0])
    sols, sing, res, its = r.q[0, :k], r.singular[0, :k], r.residual[0, :k], r.iterations[0, :k]
    reason = r.reasons[0]
    # the selection passes of every class (finish.select_one); each row's index rides along as
    # its branch, so residuals and Newton steps follow their rows (windings repeat them)
    sols, sing, rows, reason = select_one(robot, sols, sing, np.arange(k), reason, within_limits, sort_by)
    res, its = res[rows], its[rows]
    nom = nominal(robot)
    note = (f"nominal {nom.robot.name} ({nominal_class(robot)}, deviation {nom.deviation:.2g} m / rad), "
            f"closed form + Newton polish: {k} solution(s)"
            + (f", {int(r.dropped[0])} candidate(s) dropped (did not converge)" if r.dropped[0] else ""))
    return NearIKSolutions(sols.reshape(-1, robot.dof), sing, reason, res, its, note)
