"""One interface over the closed-form IK classes, and their registry.

A class (:class:`IKClass`) is what the solvers of the classes have in common, written once:

* ``detect(robot)``: the class's geometry of a robot, or None. The geometry carries the
  transform into the class's canonical frames (:class:`derive.ik.spherical.SWGeometry`: base,
  tool, joint signs and offsets; :class:`derive.ik.srs.SRSGeometry`: frame, shoulder, tool,
  signs; :class:`derive.ik.panda.PandaGeometry`: base, tool; the UR family is detected in its
  thesis form, its end transform in :class:`derive.ik.closed_form.URGeometry`);
* ``candidates(geo, poses, free)``: every branch for n poses of the robot's end frame,
  (q (n, 8, dof), singular (n, 8), reason codes (n, 8)), not yet checked; ``free`` is the
  reference value of the joint a singular set leaves free (6R: theta6 of the UR, q4 of the
  spherical wrist; None: the class's default) or, for a 7R class, the free parameter;
  the candidates then go through the one finish step (:mod:`derive.ik.finish`);
* ``steps``: the candidates as a sequence of named steps, each with the subproblem it is
  (Paden-Kahan / IK-Geo naming, :mod:`derive.ik.subproblems`; "zyz" the decomposition of
  :mod:`derive.ik.euler`);
* ``branch_labels``: what the three bits of a branch id choose, most significant first;
* ``singular_sets``: where a joint is free or two branches meet, and what the solver does there;
* ``reasons``: the reason of an empty result per code (1, 2).

:func:`classes` is the registry in the order of detection (:data:`ORDER`: the UR family before
the spherical wrist, as :func:`derive.ik.closed_form.spherical_class` has it; the Panda class
before SRS, as :func:`derive.ik.redundant.redundant_kind`). The UR member is registered by
:mod:`derive.ik.closed_form` (:func:`register`), which holds the UR solver. :func:`detect` returns the first class that
accepts a robot, :func:`find` a class by name. The solvers' own modules keep their numbers and
their step functions; this module only names them in one shape.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from derive.cache import memo
from derive.errors import DeriveError, InputError
from derive.model.robot import load_robot


@dataclass(frozen=True)
class IKClass:
    """One closed-form class (module docstring)."""

    name: str
    title: str
    dof: int
    detect: Callable
    candidates: Callable
    steps: tuple
    branch_labels: tuple
    singular_sets: tuple
    reasons: tuple
    free: str | None = None           # the free parameter of a 7R class ("q7", "psi")
    # 6R: the joint (0-based) a wrist singularity leaves free, or slice(None) where the class takes
    # the whole reference configuration (three parallel: q1 at the shoulder, q6 at the wrist)
    free_joint: int | slice | None = None


def quiet_detect(fn):
    """detect from a geometry function that raises DeriveError: the geometry or None."""
    def detect(robot):
        try:
            return fn(robot)
        except DeriveError:
            return None
    return detect


def _spherical():
    from derive.ik import spherical as sw

    def candidates(geo, poses, free=None):
        return sw.solve_batch(geo, poses, free)

    return IKClass(
        name="spherical", title="spherical wrist with an ortho-parallel base (OPW, Brandstoetter et al. 2014)",
        dof=6, detect=quiet_detect(sw.sw_geometry), candidates=candidates,
        steps=(("wrist centre", "W = p - c4 R e_z in the canonical frames (B^-1 P T^-1)"),
               ("theta1", "sp4: e_y^T R(-z, t1) W = b, W in the arm plane, two roots"),
               ("theta3", "sp3: ||R(y, t3) (a2, 0, c3) + c2 e_z|| = |v|, the cosine law, two roots"),
               ("theta2", "sp1: R(y, t2) (c2 e_z + R(y, t3) (a2, 0, c3)) = v in the arm plane"),
               ("theta4, theta5", "sp2: R(-z, t4) M e_z = R(y, t5) e_z, M = (Rz(t1) Ry(t2 + t3))^T R, two signs"),
               ("theta6", "sp1: R(z, t6) e_x = Ry(t5)^T Rz(t4)^T M e_x")),
        branch_labels=("theta1 root (+ / -)", "theta3 root (+ / -)", "theta5 sign (+ / -)"),
        singular_sets=("wrist, sin t5 = 0: q4 free (from q_ref, else 0), marked singular",
                       "shoulder: the wrist centre on axis 1 at b = 0 (sp4 degenerate): theta1 free, 0 and pi taken",
                       "elbow stretched or folded: the theta3 roots meet (merged)"),
        reasons=(sw.REASON_LATERAL, sw.REASON_REACH), free_joint=3)


def _parallel3():
    from derive.ik import parallel3 as p3

    def candidates(geo, poses, free=None):
        return p3.solve_batch(geo, poses, free)

    return IKClass(
        name="parallel3", title="three parallel axes, two intersecting (IK-Geo; the Unitree Z1)",
        dof=6, detect=quiet_detect(p3.p3_geometry), candidates=candidates,
        steps=(("q1", "sp4: the component of the wrist point along the parallel axes, two roots"),
               ("q5", "sp4: h2^T R(h5, q5) h6 = h2^T R_t h6, two roots"),
               ("q6", "sp1: R(-h6, q6) R5^T h2 = R_t^T h2; free where axis 6 is parallel to axes 2-4"),
               ("q2 + q3 + q4", "sp1: the rotation about the parallel axes"),
               ("q3", "sp3: the cosine law in the plane of the parallel axes, two roots"),
               ("q2, q4", "sp1 in that plane, then the sum")),
        branch_labels=("q1 root (+ / -)", "q5 root (+ / -)", "q3 root (+ / -)"),
        singular_sets=("wrist: axis 6 parallel to axes 2-4, q6 free (from q_ref, else 0), marked singular",
                       "shoulder: the wrist point on axis 1, q1 free (from q_ref, else 0), marked singular",
                       "elbow stretched or folded: the q3 roots meet (merged)"),
        reasons=(p3.REASON_SHOULDER, p3.REASON_REACH), free_joint=slice(None))


def _parallel3_sp6():
    from derive.ik import parallel3 as p3

    def candidates(geo, poses, free=None):
        return p3.solve_batch_sp6(geo, poses, free)

    return IKClass(
        name="parallel3-sp6", title="three parallel axes, axes 5 and 6 not meeting (IK-Geo's three parallel)",
        dof=6, detect=quiet_detect(p3.p3_sp6_geometry), candidates=candidates,
        steps=(("q1, q5", "sp6: the point of axis 6 and axis 6 itself, both projected on the parallel "
                          "axes, up to 4 solutions"),
               ("q6", "sp1: R(-h6, q6) R5^T h2 = R_t^T h2; free where axis 6 is parallel to axes 2-4"),
               ("q2 + q3 + q4", "sp1: the rotation about the parallel axes"),
               ("q3", "sp3: the cosine law in the plane of the parallel axes, two roots"),
               ("q2, q4", "sp1 in that plane, then the sum")),
        branch_labels=("sp6 solution (bit 2 of 2)", "sp6 solution (bit 1 of 2)", "q3 root (+ / -)"),
        singular_sets=("wrist: axis 6 parallel to axes 2-4, q6 free (from q_ref, else 0), marked singular",
                       "sp6 degenerate: an angle in neither equation, returned as 0, marked singular",
                       "elbow stretched or folded: the q3 roots meet (merged)"),
        reasons=(p3.REASON_SP6, p3.REASON_REACH), free_joint=slice(None))


def _panda():
    from derive.ik import panda as pd

    def candidates(geo, poses, free, q_free=None):
        import numpy as np
        n = len(poses)
        q_free = np.zeros((n, 7)) if q_free is None else q_free
        return pd.candidates(geo, poses, np.broadcast_to(np.asarray(free, dtype=float), (n,)), q_free)

    return IKClass(
        name="panda", title="Franka Panda class, q7 given (after He & Liu 2021)", dof=7,
        detect=quiet_detect(pd.panda_geometry), candidates=candidates,
        steps=(("frame 6", "eq. F7: R6, O6 from the flange pose and q7"),
               ("theta4", "sp3: ||Rz(q4) (a3, -d3, 0) - (-a4, d5, 0)|| = |v| (eq. E2), two roots"),
               ("theta5, theta6", "sp2: Rz(-q5) (X, 0, Z) = R(-e_y, q6) (vx, -vz, vy) (eq. W1-W3), two roots"),
               ("theta1, theta2, theta3", "zyz of R3 (eq. S1, S2), two signs")),
        branch_labels=("elbow q4 root (eq. E2, + / -)", "wrist q6 root (eq. W2, + / -)",
                       "shoulder sign of sin q2 (+ / -)"),
        singular_sets=("elbow stretched / folded: the q4 roots meet (merged)",
                       "S on axis 5 (X = 0): q5 free (from q_ref, else 0), marked singular",
                       "S on axis 6: q6 free (from q_ref, else 0), marked singular",
                       "q5 = +-pi/2: the q6 roots meet (merged)",
                       "sin q2 = 0: q1 free (from q_ref, else 0), marked singular"),
        reasons=(pd.REASON_ELBOW, pd.REASON_WRIST), free="q7")


def _srs():
    from derive.ik import srs

    def candidates(geo, poses, free, q_ref=None):
        import numpy as np
        rc, w = srs._into_canonical(geo, poses)
        psi = np.broadcast_to(np.asarray(free, dtype=float), (len(poses),))
        cand, singular, reason = srs._solve_psi(geo, rc, w, psi, q_ref)
        code = np.where(reason == "", 0, 1)[:, None] * np.ones((1, 8), dtype=np.int8)
        return cand, singular, code

    return IKClass(
        name="srs", title="SRS class, arm angle psi given (Shimizu et al. 2008)", dof=7,
        detect=quiet_detect(srs.srs_geometry), candidates=candidates,
        steps=(("wrist centre", "R_c, W in the canonical frame"),
               ("theta4", "sp3: ||Ry(t4) d_ew e_z + d_se e_z|| = |W| (the cosine law), two roots"),
               ("reference plane", "sp1 about axis 1 (e_x to W), sp1 about axis 2 (v(t4) to W): R0 = Rz(a) Ry(b)"),
               ("arm angle", "R_s = R_psi R0 (Rodrigues about W/|W|)"),
               ("theta1, theta2, theta3", "zyz of R_s, two signs"),
               ("theta5, theta6, theta7", "zyz of (R_s Ry(t4))^T R_c, two signs")),
        branch_labels=("shoulder GC2 = sign of sin q2 (+ / -)", "elbow GC4 = sign of theta4 = s4 q4 (+ / -)",
                       "wrist GC6 = sign of sin q6 (+ / -)"),
        singular_sets=("elbow stretched, t4 = 0: the elbow branches meet (merged), marked singular",
                       "shoulder aligned, sin t2 = 0: q1 free (from q_ref, else 0), marked singular",
                       "wrist aligned, sin t6 = 0: q5 free (from q_ref, else 0), marked singular",
                       "wrist centre at the shoulder: no arm angle (empty, with its reason)"),
        reasons=(srs.REASON_REACH, srs.REASON_FOLDED), free="psi")


_BUILT: dict = {}
#: Names of the classes in the order of detection.
ORDER = ("ur", "spherical", "parallel3", "parallel3-sp6", "panda", "srs")
_MAKERS = {"spherical": _spherical, "parallel3": _parallel3, "parallel3-sp6": _parallel3_sp6,
           "panda": _panda, "srs": _srs}


def register(cls: IKClass) -> None:
    """Add a class built elsewhere: the UR family is registered by :mod:`derive.ik.closed_form`,
    which holds its solver (and imports this module, so this one cannot import it)."""
    _BUILT[cls.name] = cls


def find(name: str) -> IKClass:
    """The registered class ``name`` (one of :data:`ORDER`); InputError for another name (and
    for "ur" before :mod:`derive.ik.closed_form` is imported)."""
    if name not in _BUILT and name in _MAKERS:
        _BUILT[name] = _MAKERS[name]()
    if name not in _BUILT:
        raise InputError(f"IK class: {name!r} is not one of {', '.join(ORDER)}")
    return _BUILT[name]


def classes() -> tuple:
    """Every registered class, in the order of detection."""
    return tuple(find(n) for n in ORDER if n in _BUILT or n in _MAKERS)


def detect(robot, dof: int | None = None):
    """(class, geometry) of the first registered class that accepts ``robot`` (only classes with
    ``dof`` joints when given), or None. Cached per robot identity."""
    robot = load_robot(robot)
    hit = memo("ik-class", robot.id, lambda: _detect(robot))
    if hit is None or (dof is not None and find(hit).dof != dof):
        return None
    cls = find(hit)
    return cls, cls.detect(robot)


def _detect(robot):
    for cls in classes():
        if cls.dof == robot.dof and cls.detect(robot) is not None:
            return cls.name
    return None
