"""The numeric reference of dq-derive: forward kinematics two independent ways and the
closed-form IK, the check every generated kernel is tested against.

* :func:`fk`, :func:`fk_matrix`, :func:`frame_poses`, :func:`joint_positions`, :func:`fk_pair`,
  :func:`pose_error`: :mod:`derive.kinematics.fk` (dual-quaternion products, Kunze eq. 1.8 and
  5.28, and plain 4x4 matrices, Kunze eq. 5.1-5.4, sharing no code);
* :func:`ik`, :func:`ik_batch`: for 6R arms :mod:`derive.ik.closed_form` (the UR family's closed
  form in numpy, written by hand after the thesis's section 4.3.5 and kept independent of the
  IK program that the kernels and the CasADi ``ik`` are generated from, and the
  spherical-wrist class); for the seven-joint arms with a free parameter
  :mod:`derive.ik.redundant` (the Franka Panda class with q7 given, after He & Liu 2021, and
  the SRS class with the arm angle psi given, after Shimizu et al. 2008);
* :func:`free_parameter`, :func:`ik_sweep`, :func:`nearest`: the free parameter of a 7R arm,
  its sweep, and the solution nearest to a seed (7R: by a 1D search along the path).
"""

import math

import numpy as np

from derive.errors import InputError, as_finite_array
from derive.ik import closed_form, free_joint, nearclass, redundant, select, srs
from derive.ik.closed_form import IKSolutions
from derive.ik.redundant import RedundantIKSolutions, Sweep, free_parameter
from derive.kinematics.fk import (
           fk,
           fk_matrix,
           fk_pair,
           frame_poses,
           joint_positions,
           pose_error,
)
from derive.kinematics.pose import as_pose_batch
from derive.model.robot import load_robot

__all__ = ["fk", "fk_matrix", "fk_pair", "frame_poses", "joint_positions", "pose_error",
           "ik", "ik_batch", "ik_sweep", "nearest", "free_parameter", "IKSolutions",
           "RedundantIKSolutions", "Sweep"]


def _near(robot) -> bool:
    """No exact class with a closed form, but a nominal robot of one
    (:func:`derive.ik.nearclass.nominal`)."""
    return nearclass.exact_class(robot) is None and nearclass.nominal(robot) is not None


def _srs_q3(robot, pose, free, q_ref, within_limits, sort_by) -> IKSolutions:
    """One pose of an SRS arm with joint 3 given (:func:`derive.ik.srs.ik_joint`)."""
    P, single = as_pose_batch(pose)
    if not single:
        raise InputError("pose: ik() takes one pose; use ik_batch() for several")
    qr = None if q_ref is None else as_finite_array(q_ref, "q_ref", last_dim=7).reshape(1, 7)
    r = srs.ik_joint(robot, P, 3, redundant.free_values(free, 1), q_ref=qr)
    k = int(r.count[0])
    sols, sing = r.q[0, :k], r.singular[0, :k]
    reason = str(r.reason[0])
    if within_limits:
        q, cnt, _, sg = select.within_limits(sols[None], np.array([k]), robot.limits, robot.revolute,
                                             singular=sing[None])
        sols, sing = q[0, :cnt[0]], sg[0, :cnt[0]]
        if len(sols) == 0 and not reason:
            reason = f"no solution inside the joint limits ({k} outside)"
    if sort_by is not None and len(sols):
        order = select.sort_order(sols, as_finite_array(sort_by, "sort_by", last_dim=7), robot.revolute,
                                  windings=within_limits)
        sols, sing = sols[order], sing[order]
    return IKSolutions(sols.reshape(-1, 7), sing, reason)


def _any_joint(robot, free_name):
    """K when ``free_name`` is "qK" for a seven-joint arm and the any-joint solver answers it
    (:mod:`derive.ik.free_joint`; a near-class arm's "q3" stays with its polish), else None."""
    k = free_joint.parse_joint(free_name)
    if k is None or robot.dof != 7 or (free_name == "q3" and _near(robot)):
        return None
    return k


def _no_free(robot) -> InputError:
    return InputError(f"free: {robot.name} has {robot.dof} joint variables and no free parameter; "
                      "free= is for the seven-joint arms of the Franka Panda class (q7) and the "
                      "SRS class (the arm angle psi)")


def ik(robot, pose, q_ref=None, within_limits: bool = False, sort_by=None, *, free=None,
       free_name=None) -> IKSolutions:
    """Every closed-form IK solution of one pose (a unit dual quaternion (8,) or a 4x4 matrix
    of the robot's end frame), as :class:`IKSolutions` (k, dof) with ``.singular`` and
    ``.reason`` (why there is none).

    6R arms (UR family, spherical wrist): :func:`derive.ik.closed_form.ik`; ``free`` must not be
    given. Seven-joint arms: ``free`` is required, the value (rad) of the free parameter:
    **q7** (joint 7) for the Franka Panda class (panda, fr3), the **arm angle psi** for the SRS
    class (iiwa7, iiwa14); :func:`free_parameter` names it and its range. Up to 8 solutions,
    a :class:`RedundantIKSolutions` with ``.branch`` and ``.free`` too
    (:func:`derive.ik.redundant.ik`). ``q_ref``: the joints a singular set leaves free are
    taken from it; ``within_limits``: only solutions inside the joint limits, every 2 pi
    winding; ``sort_by``: sorted by distance to this configuration. ``free_name="q3"``: for the
    SRS class, ``free`` is the value of joint 3 instead of the arm angle
    (:func:`derive.ik.srs.ik_joint`). ``free_name="qK"`` (K = 1..7) for any seven-joint arm:
    ``free`` is the value of joint K, the other six solved as a 6R by its class or by the
    general 6R, up to 16 solutions (:func:`derive.ik.free_joint.ik`).

    Near-class arms (no exact class, a nominal robot of one within the tolerances of
    :func:`derive.ik.nearclass.nominal`): the nominal's closed form and a Newton polish on the
    arm's own FK (:func:`derive.ik.nearclass.ik`); the result also has ``.residual`` and
    ``.iterations`` per solution and ``.polish``. Seven-joint near-class arms are solved with a
    joint given: joint 3 (``free_name="q3"``) for the SRS class, joint 7 for the Panda class."""
    robot = load_robot(robot)
    k = _any_joint(robot, free_name)
    if k is not None:
        if free is None:
            raise InputError(f"free: free_name={free_name!r} needs free=, the value of joint {k} (rad)")
        return free_joint.ik(robot, pose, k, free, q_ref=q_ref, within_limits=within_limits, sort_by=sort_by)
    if _near(robot):
        return nearclass.ik(robot, pose, q_ref, within_limits, sort_by, free=free, free_name=free_name)
    if free_name == "q3" and redundant.redundant_kind(robot) == "srs":
        return _srs_q3(robot, pose, free, q_ref, within_limits, sort_by)
    if redundant.redundant_kind(robot) is not None:
        if free is None:
            raise InputError("free: " + redundant.missing_free_message(robot))
        return redundant.ik(robot, pose, free, q_ref=q_ref, within_limits=within_limits, sort_by=sort_by)
    if free is not None:
        raise _no_free(robot)
    return closed_form.ik(robot, pose, q_ref=q_ref, within_limits=within_limits, sort_by=sort_by)


def ik_batch(robot, poses, q_ref=None, *, free=None, details: bool = False, free_name=None):
    """Closed-form IK of n poses (n, 8) or (n, 4, 4): (solutions (n, 8, dof) NaN-padded, valid
    rows first, counts (n,)).

    6R arms: :func:`derive.ik.closed_form.ik_batch` (``free`` must not be given; the 6R branch
    ids come from the C kernels, ``derive.kernels(robot, "c").ik(P, details=True)``).
    Seven-joint arms: ``free`` is required, q7 (Panda class) or the arm angle psi (SRS class),
    a number or one per pose (rad); ``details``: (solutions, counts, branch (n, 8), singular
    (n, 8)) as the kernels' ``details=True`` (:func:`derive.ik.redundant.branch_labels` says
    what the branch bits choose). ``free_name="q3"``: SRS class with joint 3 given.
    Near-class arms: :func:`derive.ik.nearclass.ik_batch` (nominal closed form + Newton polish;
    its result also has residual and iterations per solution)."""
    robot = load_robot(robot)
    k = _any_joint(robot, free_name)
    if k is not None:
        if free is None:
            raise InputError(f"free: free_name={free_name!r} needs free=, the value of joint {k} (rad)")
        return free_joint.ik_batch(robot, poses, k, free, q_ref=q_ref, details=details)
    if _near(robot):
        if details:
            raise InputError("details: a near-class arm has no branch ids; "
                             "derive.ik.nearclass.ik_batch gives residual and iterations per solution")
        r = nearclass.ik_batch(robot, poses, q_ref, free=free, free_name=free_name)
        return r.q, r.counts
    if free_name == "q3" and redundant.redundant_kind(robot) == "srs":
        P, _ = as_pose_batch(poses)
        r = srs.ik_joint(robot, P, 3, redundant.free_values(free, len(P)),
                         q_ref=None if q_ref is None else np.broadcast_to(
                             as_finite_array(q_ref, "q_ref", last_dim=7).reshape(-1, 7), (len(P), 7)))
        return (r.q, r.count, r.branch, r.singular) if details else (r.q, r.count)
    if redundant.redundant_kind(robot) is not None:
        if free is None:
            raise InputError("free: " + redundant.missing_free_message(robot))
        return redundant.ik_batch(robot, poses, free, q_ref=q_ref, details=details)
    if free is not None:
        raise _no_free(robot)
    if details:
        raise InputError("details: the reference IK of a 6R arm gives no branch ids; "
                         "derive.kernels(robot, 'c').ik(P, details=True) does")
    return closed_form.ik_batch(robot, poses, q_ref=q_ref)


def ik_sweep(robot, poses, n: int, q_ref=None, within_limits: bool = True, *, free_name=None) -> Sweep:
    """A seven-joint arm's solutions at ``n`` values of its free parameter over the feasible
    range (q7: joint 7's limits; psi: the pose's feasible intervals,
    :func:`derive.ik.srs.psi_intervals`): :func:`derive.ik.redundant.ik_sweep`.
    ``free_name="qK"``: over joint K's range (:func:`derive.ik.free_joint.ik_sweep`)."""
    k = _any_joint(load_robot(robot), free_name)
    if k is not None:
        return free_joint.ik_sweep(robot, poses, k, n, q_ref=q_ref, within_limits=within_limits)
    return redundant.ik_sweep(robot, poses, n, q_ref=q_ref, within_limits=within_limits)


def nearest(robot, poses, q_seed, tol=None, *, free_name=None) -> select.Nearest:
    """Per pose the closed-form solution nearest to the seed(s) ``q_seed`` ((dof,) or (n, dof)),
    inside the joint limits with every winding, by the largest single-joint move then the
    summed move, as a :class:`derive.ik.select.Nearest` record; ``found`` False where there is
    none (or none within ``tol``).

    Seven-joint arms: the free parameter and the branch are chosen by the 1D search of
    :func:`derive.ik.redundant.nearest` (from the seed's own q7 or arm angle), which keeps a path
    continuous. 6R arms: every solution (:func:`derive.ik.closed_form.ik_batch` with the seed as
    reference configuration) and :func:`derive.ik.select.nearest` (branch ids -1).
    ``free_name="qK"`` (seven joints): joint K is chosen for the path by the same 1D search
    (:func:`derive.ik.free_joint.nearest`)."""
    robot = load_robot(robot)
    k = _any_joint(robot, free_name)
    if k is not None:
        return free_joint.nearest(robot, poses, k, q_seed, tol=tol)
    if redundant.redundant_kind(robot) is not None:
        return redundant.nearest(robot, poses, q_seed, tol=tol)
    if tol is not None and not (isinstance(tol, (int, float, np.floating, np.integer))
                                and not isinstance(tol, bool) and math.isfinite(tol) and tol >= 0):
        raise InputError(f"tol: expected a finite number >= 0 (rad or m), got {tol!r}")
    P, single = as_pose_batch(poses)
    seeds = _seeds(robot, q_seed, len(P))
    single = single and seeds[1]
    sols, counts = closed_form.ik_batch(robot, P, q_ref=seeds[0])
    res = select.nearest(sols, counts, seeds[0], robot.limits, robot.revolute, tol=tol)
    if single:
        return select.Nearest(*(getattr(res, f)[0] for f in ("q", "found", "max_move", "total_move",
                                                           "branch", "singular")))
    return res


def _seeds(robot, q_seed, n: int):
    """(seeds (n, dof), whether one seed (dof,) was given); InputError for another shape."""
    arr = as_finite_array(q_seed, "q_seed", last_dim=robot.dof)
    if arr.ndim > 2 or (arr.ndim == 2 and arr.shape[0] not in (1, n)):
        raise InputError(f"q_seed: expected shape ({robot.dof},) or ({n}, {robot.dof}), got {arr.shape}")
    return np.broadcast_to(arr.reshape(-1, robot.dof), (n, robot.dof)).astype(float), arr.ndim == 1
