"""The one finish step of the closed-form IK solvers, and their one result type.

Every class (UR family, spherical wrist, SRS, Panda) produces *candidates*: per pose a fixed
number of branches (n, m, dof), NaN where a branch's root does not exist, with a singular flag
per branch. :func:`finish` turns them into solutions, the same way for every class:

1. **check** (:func:`check`): the forward kinematics of the robot's own model
   (:func:`derive.kinematics.fk.fk`, or a class's own evaluation of the same model: SRS's
   canonical chain) must reproduce the pose within
   :data:`~derive.ik.tolerances.ACCEPT_POSITION` (m, the distance of the origins) and
   :data:`~derive.ik.tolerances.ACCEPT_ANGLE` (rad, the angle of the relative rotation); the
   residual of a candidate is the larger of the two numbers;
2. **merge** (:func:`duplicates`): a checked candidate closer than
   :data:`~derive.ik.tolerances.MERGE_TOL` in every joint (differences modulo 2 pi) to an
   earlier checked candidate is the same solution and dropped (the branches that coincide on
   a singular set, where a double root splits by rounding);
3. **compact**: the kept rows first, in branch order, with their branch ids; NaN / -1 / False in
   the padding. The solvers wrap their angles to (-pi, pi] before (:func:`wrap`).

The selection passes for one pose (:func:`select_one`: within the joint limits with every 2 pi
winding, sorted by the distance to a configuration) are :mod:`derive.ik.select`'s, called from
here for the 6R and the 7R ``ik`` alike.

:class:`Solutions` is the one result type of the solvers' batch functions
(:func:`derive.ik.srs.ik_psi`, :func:`derive.ik.srs.ik_joint`, :func:`derive.ik.panda.ik_q7`,
:func:`derive.ik.redundant.solve`); the user-facing per-pose type is
:class:`derive.ik.closed_form.IKSolutions`, an ndarray built from one row of it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from derive.algebra.angles import wrap_angle
from derive.errors import as_finite_array
from derive.ik import select
from derive.ik.tolerances import ACCEPT_ANGLE, ACCEPT_POSITION, MERGE_TOL
from derive.kinematics.fk import _pose_error, fk

TWO_PI = 2.0 * np.pi


@dataclass
class Solutions:
    """All solutions of n poses: ``q`` (n, m, dof) NaN-padded (valid rows first, in branch order),
    ``counts`` (n,), ``branch`` (n, m) the class's branch ids (-1 in the padding), ``singular``
    (n, m) (the row lies on a singular set: a joint that it leaves free was taken from ``q_ref``,
    else 0), ``residual`` (n, m) the larger of the FK's position error (m) and rotation angle (rad)
    against the pose (NaN in the padding, and where the candidates were not checked), ``reason``
    (n,) object array of str: why a pose has no solution ("" where it has one), and ``free`` (n,)
    the value of the free parameter of a 7R class (None for a 6R class).

    The names ``count``, ``branches`` and ``reasons`` are kept as read-only aliases of
    ``counts``, ``branch`` and ``reason`` (the former SRSSolutions / PandaSolutions fields)."""

    q: np.ndarray
    counts: np.ndarray
    branch: np.ndarray
    singular: np.ndarray
    residual: np.ndarray
    reason: np.ndarray
    free: np.ndarray | None = None

    @property
    def count(self):
        return self.counts

    @property
    def branches(self):
        return self.branch

    @property
    def reasons(self):
        return self.reason

    def rows(self, index) -> Solutions:
        """The poses ``index`` (a slice, an index array or one integer: then without the pose
        axis) of every field."""
        return Solutions(**{f.name: (None if getattr(self, f.name) is None else getattr(self, f.name)[index])
                            for f in dataclasses.fields(self)})

    def reshape(self, *lead) -> Solutions:
        """Every field with its pose axis reshaped to ``lead`` (n poses x k values of a sweep)."""
        out = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            out[f.name] = None if v is None else v.reshape(*lead, *v.shape[1:])
        return Solutions(**out)


def empty(n: int, m: int, dof: int) -> Solutions:
    """No solution for n poses of m branches."""
    return Solutions(np.full((n, m, dof), np.nan), np.zeros(n, dtype=np.int64),
                     np.full((n, m), -1, dtype=np.int64), np.zeros((n, m), dtype=bool),
                     np.full((n, m), np.nan), np.full(n, "", dtype=object))


def wrap(q):
    """Angles wrapped to (-pi, pi] (:func:`derive.algebra.angles.wrap_angle`)."""
    return wrap_angle(q)


def check(robot, poses: np.ndarray, cand: np.ndarray, errors=None):
    """Step 1: (ok (n, m), residual (n, m)) of candidates (n, m, dof) against poses (n, 8) by the
    FK of ``robot`` (module docstring); rows with a NaN are not ok, their residual NaN.

    ``errors(cand)`` -> (position error (n, m) in m, rotation angle (n, m) in rad) replaces the
    reference FK by a class's own evaluation of the same model (:func:`rotation_angle` for the
    angle); SRS uses its canonical chain, which reproduces the robot's FK to MAP_POSITION /
    MAP_ANGLE (1e-10) and costs about 0.4 times the reference FK."""
    n, m, dof = cand.shape
    valid = np.all(np.isfinite(cand), axis=-1)
    ok = np.zeros((n, m), dtype=bool)
    residual = np.full((n, m), np.nan)
    if errors is not None:
        dp, dr = errors(np.where(valid[..., None], cand, 0.0))
        ok = valid & (dp <= ACCEPT_POSITION) & (dr <= ACCEPT_ANGLE)
        residual[valid] = np.maximum(dp, dr)[valid]
        return ok, residual
    if np.any(valid):
        flat = cand.reshape(-1, dof)[valid.reshape(-1)]
        dp, dr = _pose_error(fk(robot, flat), np.repeat(poses, m, axis=0)[valid.reshape(-1)])
        ok[valid] = (dp <= ACCEPT_POSITION) & (dr <= ACCEPT_ANGLE)
        residual[valid] = np.maximum(dp, dr)
    return ok, residual


def rotation_angle(a, b):
    """The angle (rad) of the rotation a^T b between rotation matrices (..., 3, 3):
    atan2(|vee(M - M^T)| / 2, (tr M - 1) / 2), M = a^T b (the metric of ACCEPT_ANGLE, accurate at
    small angles)."""
    m = np.swapaxes(a, -1, -2) @ b
    vee = np.stack([m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1)
    return np.arctan2(0.5 * np.linalg.norm(vee, axis=-1), 0.5 * (np.trace(m, axis1=-2, axis2=-1) - 1.0))


def duplicates(cand: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Step 2: (n, m) the ``ok`` candidates closer than MERGE_TOL in every joint (differences
    taken modulo 2 pi) to an earlier ``ok`` candidate. Joint by joint over the pairs still close
    (few after the first joint), so the cost is about one pass over the pairs."""
    n, m, dof = cand.shape
    first, later = np.triu_indices(m, 1)
    close = ok[:, first] & ok[:, later]                                    # (n, pairs)
    for k in range(dof):
        rows, pairs = np.nonzero(close)
        if not len(rows):
            break
        d = np.mod(np.abs(cand[rows, first[pairs], k] - cand[rows, later[pairs], k]), TWO_PI)
        close[rows, pairs] = (d < MERGE_TOL) | (d > TWO_PI - MERGE_TOL)
    dup = np.zeros((n, m), dtype=bool)
    rows, pairs = np.nonzero(close)
    dup[rows, later[pairs]] = True
    return dup


def compact(cand, keep, singular, residual) -> tuple:
    """Step 3: the rows ``keep`` first (stable, in branch order): (q, counts, branch, singular,
    residual) with NaN / -1 / False / NaN in the padding."""
    order = np.argsort(~keep, axis=1, kind="stable")
    kept = np.take_along_axis(keep, order, axis=1)
    q = np.take_along_axis(cand, order[..., None], axis=1)
    q[~kept] = np.nan
    branch = np.where(kept, order, -1).astype(np.int64)
    sing = np.take_along_axis(np.asarray(singular, dtype=bool), order, axis=1) & kept
    res = np.where(kept, np.take_along_axis(residual, order, axis=1), np.nan)
    return q, kept.sum(axis=1).astype(np.int64), branch, sing, res


def finish(robot, poses: np.ndarray, cand: np.ndarray, singular: np.ndarray,
           check_fk: bool = True, errors=None) -> tuple:
    """Steps 1-3 on candidates (n, m, dof) of poses (n, 8) of ``robot``'s end frame:
    (q, counts, branch, singular, residual). ``check_fk`` False keeps every finite candidate
    (the residual is then NaN) and still merges; ``errors`` as in :func:`check`."""
    if check_fk:
        ok, residual = check(robot, poses, cand, errors)
    else:
        ok = np.all(np.isfinite(cand), axis=-1)
        residual = np.full(ok.shape, np.nan)
    keep = ok & ~duplicates(cand, ok)
    return compact(cand, keep, singular, residual)


def select_one(robot, sols, singular, branch, reason: str, within_limits: bool, sort_by):
    """The selection passes of one pose's solutions (k, dof): ``within_limits`` (every in-limit
    2 pi winding, :func:`derive.ik.select.within_limits`; an empty result says how many were
    outside) and ``sort_by`` (a configuration; :func:`derive.ik.select.sort_order`, plain joint
    moves when the windings were expanded, wrapped differences otherwise). Returns (sols,
    singular, branch, reason)."""
    k = len(sols)
    if within_limits:
        q, cnt, b, sg = select.within_limits(sols[None], np.array([k]), robot.limits, robot.revolute,
                                             branch=branch[None], singular=singular[None])
        sols, branch, singular = q[0, :cnt[0]], b[0, :cnt[0]], sg[0, :cnt[0]]
        if len(sols) == 0 and not reason:
            reason = f"no solution inside the joint limits ({k} outside)"
    if sort_by is not None and len(sols):
        ref = as_finite_array(sort_by, "sort_by", last_dim=robot.dof)
        order = select.sort_order(sols, ref, robot.revolute, windings=within_limits)
        sols, singular, branch = sols[order], singular[order], branch[order]
    return sols, singular, branch, reason
