"""Closed-form inverse kinematics of 6R arms with three consecutive parallel axes (2, 3, 4) and
axes 5 and 6 intersecting, outside the UR layout: the three-parallel class (the Unitree Z1).

IK-Geo (Elias & Wen, "IK-Geo: Unified robot inverse kinematics using subproblem decomposition",
arXiv:2211.05737, 2022; Mechanism and Machine Theory 2024) solves this layout as "three parallel,
two intersecting" (``IK_3_parallel_2_intersecting``): 8 solutions from subproblems 4, 4, 1, 1, 3
and 1. This module is that composition, written with the subproblems of
:mod:`derive.ik.subproblems` in numpy, batched over poses.

The arm in the product-of-exponentials form of IK-Geo (every number from the robot's numeric
axis-angle chain, :func:`derive.model.geometry.numeric_chain`, base frame, zero configuration):
unit axes h_1 ... h_6, the vectors p_0 (base origin to a point of axis 1), p_i (point of axis i
to point of axis i+1), p_6 (point of axis 6 to the end frame's origin), and the end frame's
rotation R_6T at zero, with FK

    R = R_1 ... R_6 R_6T,    t = p_0 + R_1 p_1 + R_12 p_2 + R_123 p_3 + R_1234 p_4 + R_06 p_6,

R_i = R(h_i, q_i), the points of axes 5 and 6 both at the point where those axes meet (so the
vector from axis 5 to axis 6 is 0). With h_2 = h_3 = h_4 and R_06 = R R_6T^T (IK-Geo's equations,
solved in this order):

1. q1, subproblem 4: p_16 = t - p_0 - R_06 p_6 = R_1 (p_1 + R_2 p_2 + R_23 p_3 + R_234 p_4), and
   the rotations about h_2 keep the component along h_2, so
   h_2^T R(-h_1, q1) p_16 = h_2^T (p_1 + p_2 + p_3 + p_4); two roots (branch bit 4);
2. q5, subproblem 4: with R_t = R_1^T R_06 = R(h_2, q2 + q3 + q4) R_5 R_6,
   h_2^T R(h_5, q5) h_6 = h_2^T R_t h_6; two roots (branch bit 2);
3. q6, subproblem 1: R(-h_6, q6) (R_5^T h_2) = R_t^T h_2. Where R_5^T h_2 is parallel to h_6
   (``|h_6 x R_5^T h_2|`` below WRIST_SINGULAR: axis 6 parallel to the parallel axes) q6 and
   q2 + q3 + q4 are one rotation about h_2 and q6 is free: it is taken from the reference
   configuration when one is given, else 0, and the solution is marked singular;
4. theta = q2 + q3 + q4, subproblem 1: R(h_2, theta) = R_t R_6^T R_5^T, on a unit vector
   perpendicular to h_2 (exact also where q6 was chosen freely);
5. q3, subproblem 3: v = R_1^T p_16 - p_1 - R(h_2, theta) p_4 = R_2 (p_2 + R_3 p_3), so
   ||R(h_2, q3) p_3 + p_2|| = ||v||; two roots (branch bit 1);
6. q2, subproblem 1: R(h_2, q2) (p_2 + R_3 p_3) = v; q4 = theta - q2 - q3.

Singular sets: besides the wrist (step 3), the shoulder: where the wrist point (the end of
p_16) lies on axis 1 (subproblem 4 of step 1 degenerate: q1 does not enter, which for the Z1,
whose arm has no lateral offset, means every q1 solves step 1), q1 is free: from the reference
configuration, else 0, marked singular. Candidates are checked by FK in
:func:`derive.ik.closed_form.solve`, which this module's :func:`solve_batch` feeds (branch
k = 4 i1 + 2 i5 + i3, bit 1 for the second root of each subproblem).

The UR layout (axes 4 and 5 meeting too, thesis section 4.3) is of this class as well, but keeps
its own closed form (:mod:`derive.ik.closed_form`): :func:`p3_geometry` refuses it.

**Axes 5 and 6 not meeting** (``layout="sp6"``, :func:`p3_sp6_geometry`): IK-Geo's "three
parallel" solver (``IK_3_parallel``), with p_5 the vector from a point of axis 5 to a point of
axis 6 (not 0). Steps 1 and 2 become one subproblem 6 for (q1, q5): projected on h_2,

    h_2^T R(-h_1, q1) p_16 + h_2^T R(h_5, q5) (-p_5) = h_2^T (p_1 + p_2 + p_3 + p_4),
    h_2^T R(-h_1, q1) R_06 h_6 + h_2^T R(h_5, q5) (-h_6) = 0

(p_16 = t - p_0 - R_06 p_6 now a point of axis 6; R_1^T p_16 = p_1 + R_2 p_2 + R_23 p_3 + R_234 p_4
+ R_2345 p_5 and R_1^T R_06 h_6 = R_234 R_5 h_6, and rotations about h_2 keep h_2^T), up to 4
solutions (the two high bits of the branch). Steps 3 and 4 are as above; step 5 takes
v = R_1^T p_16 - p_1 - R(h_2, theta) (p_4 + R_5 p_5); steps 5 and 6 are as above (the low bit).
Where subproblem 6 leaves an angle free (``degenerate``) the candidate is marked singular.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from derive.algebra import dualquat as dq
from derive.algebra import quaternion as quat
from derive.algebra.angles import wrap_angle
from derive.cache import memo
from derive.errors import DeriveError
from derive.ik.subproblems import rot, sp1, sp3, sp4, sp6
from derive.ik.tolerances import SP_EXACT_TOL, WRIST_SINGULAR
from derive.kinematics.fk import _pose_error, fk
from derive.model.classify import classify as geometric_classify
from derive.model.geometry import numeric_chain
from derive.model.robot import load_robot

#: Geometric properties of the class must hold within this (rad for angles, m for distances).
CLASS_TOL = 1e-10
#: The product-of-exponentials model must reproduce the robot's FK within this (m, rad).
MAP_TOL = 1e-10

REASON_SHOULDER = ("unreachable: no turn of joint 1 brings the wrist point (where axes 5 and 6 "
                   "meet) to the offset along the parallel axes that the arm has")
REASON_SP6 = ("unreachable: no turn of joints 1 and 5 brings the point of axis 6 to the offset "
              "along the parallel axes that the arm has with axis 6 across them as the pose needs "
              "(subproblem 6 has no solution)")
REASON_REACH = ("unreachable: the distance from axis 2 to the wrist point is outside the range "
                "the upper arm and the forearm can span")


@dataclass(frozen=True)
class P3Geometry:
    """The three-parallel form of an arm (module docstring): axes ``h`` (6, 3), vectors ``p``
    (7, 3) with p[5] = 0, the end rotation at zero ``r6t`` (3, 3), and ``order`` (6,): the index
    in q of each joint along the chain."""

    robot: str
    h: np.ndarray
    p: np.ndarray
    r6t: np.ndarray
    order: tuple
    error: float
    ortho_wrist: bool = False
    #: "intersecting" (axes 5 and 6 meet: p[5] = 0) or "sp6" (they do not: IK-Geo's three
    #: parallel with subproblem 6, module docstring)
    layout: str = "intersecting"

    # ortho_wrist: axis 5 perpendicular to axes 4 and 6 (the Z1): the root of step 2 is taken as
    # |h_2 x R_t h_6| (accurate at the wrist singularity) instead of sqrt(1 - d^2)

    @property
    def d1(self) -> float:
        """h_2^T (p_1 + p_2 + p_3 + p_4) (m): the arm's offset along the parallel axes."""
        return float(self.h[1] @ self.p[1:5].sum(axis=0))


def describe(geo: P3Geometry) -> str:
    """One line: the axes and the vectors (m) of the product-of-exponentials form."""
    def vec(v):
        return "(" + ", ".join(f"{x:.12g}" for x in np.asarray(v) + 0.0) + ")"
    head = ("axes 2, 3, 4 parallel, axes 5 and 6 meeting at the wrist point; IK-Geo's three "
            "parallel, two intersecting: subproblems 4 (q1), 4 (q5), 1 (q6), 1 (q2 + q3 + q4), "
            "3 (q3), 1 (q2)" if geo.layout == "intersecting" else
            "axes 2, 3, 4 parallel, axes 5 and 6 not meeting; IK-Geo's three parallel: "
            "subproblems 6 (q1, q5), 1 (q6), 1 (q2 + q3 + q4), 3 (q3), 1 (q2)")
    return (head + "; axes " + ", ".join(vec(h) for h in geo.h) + "; vectors p0 ... p6 "
            + ", ".join(vec(p) for p in geo.p) + " m")


def p3_geometry(robot) -> P3Geometry:
    """The three-parallel form of a robot, or DeriveError naming the property it lacks; cached
    per robot identity."""
    robot = load_robot(robot)
    return memo("p3-geometry", robot.id, lambda: _p3_geometry(robot))


def p3_sp6_geometry(robot) -> P3Geometry:
    """The three-parallel form of a robot whose axes 5 and 6 do not meet (``layout="sp6"``,
    module docstring), or DeriveError naming the property it lacks; cached per robot identity."""
    robot = load_robot(robot)
    return memo("p3-sp6-geometry", robot.id, lambda: _p3_geometry(robot, layout="sp6"))


def is_parallel3(robot) -> bool:
    """Whether the robot is of the three-parallel class in either layout."""
    for geometry in (p3_geometry, p3_sp6_geometry):
        try:
            geometry(robot)
            return True
        except DeriveError:
            pass
    return False


def _fk_poe(geo: P3Geometry, q: np.ndarray):
    """(R (n, 3, 3), t (n, 3)) of the product-of-exponentials form at q (n, 6) (robot order)."""
    n = q.shape[0]
    r = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    t = np.broadcast_to(geo.p[0], (n, 3)).copy()
    for i in range(6):
        qi = q[:, geo.order[i]]
        cols = [rot(np.broadcast_to(geo.h[i], (n, 3)), qi, np.broadcast_to(e, (n, 3))) for e in np.eye(3)]
        r = r @ np.stack(cols, axis=-1)
        t = t + np.einsum("nij,j->ni", r, geo.p[i + 1])
    return r @ geo.r6t, t


def _line_distance(p1, h1, p2, h2) -> float:
    n = np.cross(h1, h2)
    if np.linalg.norm(n) < 1e-12:
        return float(np.linalg.norm(np.cross(p2 - p1, h1)))
    return float(abs(np.dot(p2 - p1, n / np.linalg.norm(n))))


def _p3_geometry(robot, layout: str = "intersecting") -> P3Geometry:
    name = robot.name
    sp6_layout = layout == "sp6"

    def fail(why):
        raise DeriveError(f"{name}: not of the three-parallel class (axes 2, 3, 4 parallel, axes "
                          f"5 and 6 {'not intersecting' if sp6_layout else 'intersecting'}): {why}")

    if robot.dof != 6:
        fail(f"{robot.dof} joints, the class has 6")
    chain = numeric_chain(robot)
    if chain.n != 6 or any(t != "revolute" for t in chain.types):
        fail("the path to the end has a prismatic joint or not 6 joints")
    h = np.array([a / np.linalg.norm(a) for a in chain.axes])
    pts = chain.start + np.vstack([np.zeros(3), np.cumsum(chain.links, axis=0)])
    tol = CLASS_TOL
    if np.linalg.norm(np.cross(h[1], h[2])) > tol or np.linalg.norm(np.cross(h[2], h[3])) > tol:
        fail("axes 2, 3 and 4 are not parallel")
    h[2] = h[1] * np.sign(h[1] @ h[2])          # exactly parallel (sign kept)
    h[3] = h[1] * np.sign(h[1] @ h[3])
    if np.linalg.norm(np.cross(h[4], h[5])) <= tol:
        fail("axes 5 and 6 are parallel")
    meet56 = _line_distance(pts[4], h[4], pts[5], h[5]) <= tol
    if meet56 and sp6_layout:
        fail("axes 5 and 6 intersect (the two-intersecting layout, p3_geometry)")
    if not meet56 and not sp6_layout:
        fail("axes 5 and 6 do not intersect")
    for i, j, what in ((0, 1, "axes 1 and 2 are parallel (joint 1 would not move the arm plane)"),
                       (1, 4, "axis 5 is parallel to the parallel axes")):
        if np.linalg.norm(np.cross(h[i], h[j])) <= tol:
            fail(what)
    if not sp6_layout and geometric_classify(robot).cls == "UR":
        fail("it is of the UR layout (axes 4 and 5 meet as well), which has its own closed form "
             "(derive.ik.closed_form, thesis section 4.3)")
    end0 = pts[6] + chain.end_translation
    if sp6_layout:      # points of axes 5 and 6 as the chain gives them, p5 between them
        p = np.array([pts[0], pts[1] - pts[0], pts[2] - pts[1], pts[3] - pts[2], pts[4] - pts[3],
                      pts[5] - pts[4], end0 - pts[5]])
    else:
        # the point where axes 5 and 6 meet
        d56 = pts[5] - pts[4]
        c56 = h[4] @ h[5]
        wrist = pts[4] + h[4] * (d56 @ h[4] - (d56 @ h[5]) * c56) / (1.0 - c56 * c56)
        p = np.array([pts[0], pts[1] - pts[0], pts[2] - pts[1], pts[3] - pts[2], wrist - pts[3],
                      np.zeros(3), end0 - wrist])
    for k, what in ((2, "upper arm"), (3, "forearm")):
        if np.linalg.norm(np.cross(h[1], p[k])) <= 1e-9:
            fail(f"no {what}: axes {k} and {k + 1} coincide")
    order = tuple(int(v) for v in chain.variables)
    geo = P3Geometry(name, h=h, p=p, r6t=np.asarray(chain.end_rotation, dtype=float), order=order,
                     error=0.0, layout=layout)
    rng = np.random.default_rng(13)
    q = rng.uniform(-math.pi, math.pi, size=(24, 6))
    r, t = _fk_poe(geo, q)
    ref = fk(robot, q)
    via = dq.from_rt(quat.from_matrix(r), t)
    dp, dr = _pose_error(ref, via)
    err = float(max(dp.max(), dr.max()))
    if not err <= MAP_TOL:
        fail(f"its product-of-exponentials form reproduces the FK only to {err:.3g} (m, rad)")
    ortho = bool(abs(h[1] @ h[4]) <= tol and abs(h[4] @ h[5]) <= tol) and not sp6_layout
    return P3Geometry(name, h=h, p=p, r6t=geo.r6t, order=order, error=err, ortho_wrist=ortho,
                      layout=layout)


# --------------------------------------------------------------------------- #
# Numeric reference solver (IK-Geo's three parallel, two intersecting)
# --------------------------------------------------------------------------- #
def _ok(sol) -> np.ndarray:
    """(..., m) slots of a subproblem that hold an exact solution."""
    return sol.valid & (sol.residual <= SP_EXACT_TOL)


def _first_if_missing(sol) -> np.ndarray:
    """The (..., 2) angles of a two-slot subproblem; a missing second slot (one least-squares or
    degenerate solution) repeats the first."""
    th = sol.theta[..., 0]
    return np.where(sol.valid, th, th[..., :1])



def _q6_theta(h, hb, rt, q5, x, free6):
    """Steps 3 and 4 of both layouts, given q5 and ``rt`` = R_1^T R_06: q6 by subproblem 1
    (R(-h6, q6) R_5^T h_2 = rt^T h_2; ``free6`` where R_5^T h_2 is along h_6, the wrist
    singularity), then theta = q2 + q3 + q4 by subproblem 1 on ``x`` (a vector normal to the
    parallel axes). Returns q6, theta and the wrist-singular flags."""
    u = rot(hb[4], -q5, hb[1])                                           # R_5^T h_2
    sing6 = np.linalg.norm(np.cross(h[5], u), axis=-1) < WRIST_SINGULAR
    q6 = np.where(sing6, free6, sp1(-hb[5], u, np.einsum("nji,j->ni", rt, h[1])).theta[:, 0, 0])
    y = np.einsum("nij,nj->ni", rt, rot(hb[5], -q6, rot(hb[4], -q5, x)))
    return q6, sp1(hb[1], x, y).theta[:, 0, 0], sing6


def _q3_q2_q4(hb, p, v, theta):
    """Steps 5 and 6 of both layouts: q3 by subproblem 3 (||R(h_2, q3) p_3 + p_2|| = ||v||, two
    roots, the first repeated where one is missing), then per root q2 by subproblem 1
    (R(h_2, q2)(p_2 + R(h_2, q3) p_3) = v) and q4 = theta - q2 - q3. Returns whether q3 exists
    (n,) and the two (q2, q3, q4)."""
    n = len(v)
    s3 = sp3(hb[1], np.broadcast_to(p[3], (n, 3)), np.broadcast_to(-p[2], (n, 3)),
             np.linalg.norm(v, axis=-1))
    q3s = _first_if_missing(s3)
    arms = []
    for i3 in range(2):
        q3 = q3s[:, i3]
        w = p[2] + rot(hb[1], q3, np.broadcast_to(p[3], (n, 3)))
        q2 = sp1(hb[1], w, v).theta[:, 0, 0]
        arms.append((q2, q3, theta - q2 - q3))
    return _ok(s3), arms

def _pose_terms(geo: P3Geometry, poses: np.ndarray):
    """Step 0 of both layouts: the axes broadcast over the n poses, R_06 = R R_6T^T and the point
    p_16 = t - p_0 - R_06 p_6 of axis 6 (the wrist point where axes 5 and 6 meet)."""
    n = poses.shape[0]
    r06 = quat._to_matrix(poses[:, :4]) @ geo.r6t.T
    p16 = dq._translation(poses) - geo.p[0] - np.einsum("nij,j->ni", r06, geo.p[6])
    return [np.broadcast_to(v, (n, 3)) for v in geo.h], r06, p16


def solve_batch(geo: P3Geometry, poses: np.ndarray, q_ref: np.ndarray | None = None,
                keep_unreachable: bool = False):
    """All 8 candidate branches for n poses of the robot's end frame: (q (n, 8, 6) in the
    robot's joint order, singular (n, 8), reason codes (n, 8): 0 ok, 1 q1 or q5 unreachable
    (``REASON_SHOULDER``), 2 q3 unreachable (``REASON_REACH``)). Not yet checked by FK
    (:func:`derive.ik.closed_form.solve` does that). ``q_ref`` (n, 6) or None: the reference
    configurations whose q1 (shoulder singularity) and q6 (wrist singularity) are used where
    those joints are free (else 0). Unreachable branches are NaN unless ``keep_unreachable``
    (then the least-squares roots of the subproblems: the nearest the arm comes).
    Steps as in the module docstring; the layout with axes 5 and 6 not meeting goes to
    :func:`solve_batch_sp6`."""
    if geo.layout == "sp6":
        return solve_batch_sp6(geo, poses, q_ref, keep_unreachable)
    n = poses.shape[0]
    h, p = geo.h, geo.p
    hb, r06, p16 = _pose_terms(geo, poses)
    free1 = np.zeros(n) if q_ref is None else q_ref[:, geo.order[0]]
    free6 = np.zeros(n) if q_ref is None else q_ref[:, geo.order[5]]
    x = np.cross(h[1], h[0])
    x = np.broadcast_to(x / np.linalg.norm(x), (n, 3))          # a unit vector across h_2
    out = np.full((n, 8, 6), np.nan)
    singular = np.zeros((n, 8), dtype=bool)
    code = np.zeros((n, 8), dtype=np.int8)
    # 1. q1 (subproblem 4)
    s1 = sp4(hb[1], -hb[0], p16, np.full(n, geo.d1))
    sing1 = s1.degenerate
    ok1 = _ok(s1) | sing1[:, None]
    q1s = np.where(sing1[:, None], free1[:, None], _first_if_missing(s1))
    for i1 in range(2):
        q1 = q1s[:, i1]
        rt = np.einsum("nji,njk->nik", _rotm(hb[0], q1), r06)          # R_1^T R_06
        # 2. q5 (subproblem 4)
        rt6 = np.einsum("nij,j->ni", rt, h[5])                          # R_t h_6
        s5 = sp4(hb[1], hb[4], hb[5], rt6 @ h[1])
        ok5 = _ok(s5)
        q5s = _first_if_missing(s5) if not geo.ortho_wrist else _wrist_roots(geo, rt6)
        ok5 = ok5 | geo.ortho_wrist
        for i5 in range(2):
            q5 = q5s[:, i5]
            # 3. q6 and 4. theta = q2 + q3 + q4 (subproblems 1)
            q6, theta, sing6 = _q6_theta(h, hb, rt, q5, x, free6)
            # 5. q3 (subproblem 3)
            v = (np.einsum("nji,nj->ni", _rotm(hb[0], q1), p16) - p[1]
                 - rot(hb[1], theta, np.broadcast_to(p[4], (n, 3))))
            # 6. q2 (subproblem 1), q4 by subtraction, per root of q3
            ok3, arms = _q3_q2_q4(hb, p, v, theta)
            for i3, (q2, q3, q4) in enumerate(arms):
                k = 4 * i1 + 2 * i5 + i3
                theta_k = np.stack([q1, q2, q3, q4, q5, q6], axis=-1)
                out[:, k, list(geo.order)] = wrap_angle(theta_k)
                singular[:, k] = sing1 | sing6
                code[:, k] = np.where(~(ok1[:, i1] & ok5[:, i5]), 1, np.where(~ok3[:, i3], 2, 0))
    if not keep_unreachable:
        out[code > 0] = np.nan
    return out, singular, code


def _wrist_roots(geo: P3Geometry, rt6) -> np.ndarray:
    """The two roots (n, 2) of step 2 for an ortho wrist (h_5 perpendicular to h_2 and h_6):
    subproblem 4's line a . x = b with |a| = 1 and b = h_2^T R_t h_6, whose root
    sqrt(|a|^2 - b^2) is the length of the part of the unit vector R_t h_6 across h_2,
    |h_2 x R_t h_6|: exact at the wrist singularity, where sqrt(1 - b^2) carries the square root
    of the rounding (about 1e-8 rad in q5)."""
    h2, h5, h6 = geo.h[1], geo.h[4], geo.h[5]
    a = np.array([np.cross(h5, h6) @ h2, h6 @ h2])                      # A(h5, h6)^T h2, |a| = 1
    b = rt6 @ h2
    r = np.linalg.norm(np.cross(h2, rt6), axis=-1)
    roots = [np.arctan2(a[0] * b + sg * r * a[1], a[1] * b - sg * r * a[0]) for sg in (1.0, -1.0)]
    return np.stack(roots, axis=-1)


def _rotm(k, theta) -> np.ndarray:
    """R(k, theta) (n, 3, 3) for axes k (n, 3) and angles theta (n,)."""
    n = k.shape[0]
    return np.stack([rot(k, theta, np.broadcast_to(e, (n, 3))) for e in np.eye(3)], axis=-1)


def solve_batch_sp6(geo: P3Geometry, poses: np.ndarray, q_ref: np.ndarray | None = None,
                    keep_unreachable: bool = False):
    """:func:`solve_batch` for the layout with axes 5 and 6 not meeting (IK-Geo's
    ``IK_3_parallel``, module docstring): (q (n, 8, 6), singular (n, 8), reason codes (n, 8): 0
    ok, 1 subproblem 6 without a solution in that slot (``REASON_SP6``), 2 q3 unreachable
    (``REASON_REACH``)); branch k = 2 i6 + i3 with i6 the slot of subproblem 6 (0-3) and i3 the
    root of q3; the solutions of subproblem 6 fill the first slots, ascending in q1 (the order
    of the IK program, :func:`derive.ik.program_parallel3.parallel3_sp6_program`, so that the
    kernels' branches are these). ``q_ref``: its q6 is used where q6 is free (R_5^T h_2 along h_6), else 0.
    Subproblem 6 returns no least-squares solution, so ``keep_unreachable`` keeps only the q3
    roots of the slots it solved."""
    n = poses.shape[0]
    h, p = geo.h, geo.p
    hb, r06, p16 = _pose_terms(geo, poses)
    free6 = np.zeros(n) if q_ref is None else q_ref[:, geo.order[5]]
    x = np.cross(h[1], h[0])
    x = np.broadcast_to(x / np.linalg.norm(x), (n, 3))
    out = np.full((n, 8, 6), np.nan)
    singular = np.zeros((n, 8), dtype=bool)
    code = np.ones((n, 8), dtype=np.int8)
    # 1-2. (q1, q5), subproblem 6: rows (h2, -h1, p16), (h2, h5, -p5); (h2, -h1, R06 h6), (h2, h5, -h6)
    r06h6 = np.einsum("nij,j->ni", r06, h[5])
    hh = np.broadcast_to(h[1], (n, 4, 3))
    kk = np.stack([-hb[0], hb[4], -hb[0], hb[4]], axis=1)
    pp = np.stack([p16, np.broadcast_to(-p[5], (n, 3)), r06h6, -hb[5]], axis=1)
    d = np.stack([np.full(n, geo.d1), np.zeros(n)], axis=-1)
    s6 = sp6(hh, kk, pp, d)
    # the slots in a canonical order, as the IK program's (derive.ik.program_parallel3): the
    # solutions first, ascending in q1, then the empty slots
    ok_all = _ok(s6)
    order = np.argsort(np.where(ok_all, s6.theta[:, :, 0], np.inf), axis=-1, kind="stable")
    ok_all = np.take_along_axis(ok_all, order, axis=-1)
    theta6 = np.take_along_axis(s6.theta, order[..., None], axis=1)
    for i6 in range(4):
        ok6 = ok_all[:, i6]
        q1 = np.where(ok6, theta6[:, i6, 0], 0.0)
        q5 = np.where(ok6, theta6[:, i6, 1], 0.0)
        r1 = _rotm(hb[0], q1)
        rt = np.einsum("nji,njk->nik", r1, r06)                          # R_1^T R_06
        # 3. q6 and 4. theta = q2 + q3 + q4 (subproblems 1)
        q6, theta, sing6 = _q6_theta(h, hb, rt, q5, x, free6)
        # 5. q3 (subproblem 3): v = R_2 (p_2 + R_3 p_3)
        v = (np.einsum("nji,nj->ni", r1, p16) - p[1]
             - rot(hb[1], theta, np.broadcast_to(p[4], (n, 3)) + rot(hb[4], q5, np.broadcast_to(p[5], (n, 3)))))
        # 6. q2 (subproblem 1), q4 by subtraction, per root of q3
        ok3, arms = _q3_q2_q4(hb, p, v, theta)
        for i3, (q2, q3, q4) in enumerate(arms):
            k = 2 * i6 + i3
            theta_k = np.stack([q1, q2, q3, q4, q5, q6], axis=-1)
            out[:, k, list(geo.order)] = np.where(ok6[:, None], wrap_angle(theta_k), np.nan)
            singular[:, k] = s6.degenerate | sing6
            code[:, k] = np.where(~ok6, 1, np.where(~ok3[:, i3], 2, 0))
    if not keep_unreachable:
        out[code > 0] = np.nan
    return out, singular, code
