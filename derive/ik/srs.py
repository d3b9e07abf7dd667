"""Closed-form inverse kinematics of SRS arms (spherical shoulder, revolute elbow, spherical
wrist) with the arm angle psi as the free parameter: the KUKA LBR iiwa class.

References: M. Shimizu, H. Kakuya, W.-K. Yoon, K. Kitagaki, K. Kosuge, "Analytical inverse
kinematic computation for 7-DOF redundant manipulators with joint limits and its application
to redundancy resolution", IEEE T-RO 24(5), 2008 ("Shimizu" below; sec. III, the closed form
parameterised by the arm angle and the joints as tangent- or cosine-type functions of it, and
the feasible arm angles under the joint limits); C. Faria, F. Ferreira, W. Erlhagen,
S. Monteiro, E. Bicho, "Position-based kinematics for 7-DoF serial manipulators with global
configuration control, joint limit and singularity avoidance", Mechanism and Machine Theory
121, 2018 ("Faria" below; the same construction for the iiwa, with the configuration flags
GC2, GC4, GC6). The steps below cite the construction, not equation numbers.

The class
---------
Seven revolute joints. At the zero pose the arm is stretched along one line (direction u):
axes 1, 3, 5, 7 lie on it; axes 2, 4, 6 are perpendicular to it and parallel to each other and
cross it at the shoulder S (axes 1, 2, 3 meet), the elbow E and the wrist centre W (axes 5,
6, 7 meet), with d_se = |SE| > 0 and d_ew = |EW| > 0. :func:`srs_geometry` checks this on the
robot's axes at the zero pose and finds the **canonical frame**: origin S, z = u, y = axis 2,
x = y cross z. Every axis is +-z or +-y there, so with theta_i = s_i q_i (s_i = +-1, the axis
direction)

    rotation      R(theta) = Rz(t1) Ry(t2) Rz(t3) Ry(t4) Rz(t5) Ry(t6) Rz(t7)
    wrist centre  W(theta) = Rz(t1) Ry(t2) Rz(t3) v(t4),   v(t4) = d_se e_z + d_ew Ry(t4) e_z

and the robot's end frame is B (R, W) T with constant B (the canonical frame in the base) and
T (the end frame in the wrist frame at zero; the flange offset d_wf and any tool are in T).

The arm angle psi
-----------------
For a wrist centre W (x = W - S, not zero) and an elbow angle t4, the **reference
configuration** is the shoulder rotation with t3 = 0 that carries v(t4) onto x:
R0 = Rz(a) Ry(b - phi), a = atan2(x_y, x_x), b = atan2(hypot(x_x, x_y), x_z),
phi = atan2(v_x, v_z) (its other decomposition, a + pi and -b - phi, is the same rotation). With
t3 = 0 the whole arm lies in the plane spanned by axis 1 and x: the **reference plane**. Every
shoulder rotation that carries v(t4) onto x is R_s = R_psi R0, R_psi the rotation by psi about
x/|x| (right hand); psi is the arm angle (Shimizu sec. III). Geometrically psi turns the arm
plane (S, E, W) out of the reference plane about the shoulder-wrist line; psi = 0 is the arm in
the reference plane with its elbow on the side that t4's sign gives (so the elbow of the other
elbow branch at psi sits where this branch's elbow sits at psi + pi).

When x lies along axis 1 (the wrist centre on axis 1: x_x = x_y = 0) the reference plane is
undefined; this module then takes a = 0, the plane of axis 1 and the canonical x axis (for the
iiwa the base x-z plane), in the solver and in :func:`arm_angle` alike, so psi keeps a meaning
(there psi and q1 move the arm the same way). x = 0 (the wrist centre at the shoulder, possible
only when d_se = d_ew with the elbow folded) has no solution here: an empty set with its reason.

The branches
------------
Per psi, as a composition of the subproblems of :mod:`derive.ik.subproblems`: the elbow t4 by
subproblem 3 (the cosine law, two roots GC4 = sign of t4), the reference configuration by two
subproblems 1 (about axes 1 and 2), the shoulder rotation R_s = R_psi R0 (Rodrigues), then R_s
and the wrist rotation R_w = (R_s Ry(t4))^T R each split into two ZYZ Euler decompositions
(:func:`derive.ik.euler.zyz`; GC2 = sign of sin t2, GC6 = sign of sin t6). With a joint given
instead of psi (:func:`ik_joint`) the shoulder is a subproblem 4 and a subproblem 1. Branch id k = 4 i2 + 2 i4 + i6
with i = 0 for the + sign, 1 for -. Singular sets: the elbow stretched (t4 = 0: the two elbow
branches coincide), the shoulder aligned (sin t2 = 0: only t1 + t3 or t1 - t3 is fixed; t1 is
taken from ``q_ref``, else q1 = 0) and the wrist aligned (sin t6 = 0: q5 from ``q_ref``, else
0). Such solutions are exact; coinciding branches are returned once.

Feasible intervals
------------------
R_s(psi) = A_s sin psi + B_s cos psi + C_s and R_w(psi) = A_w sin psi + B_w cos psi + C_w
(Shimizu sec. III), so each joint is of tangent type, t = atan2(n(psi), d(psi)) with n, d of
the form a sin psi + b cos psi + c (joints 1, 3, 5, 7), or of cosine type, t = +-acos(a sin psi +
b cos psi + c) (joints 2, 6); t4 does not depend on psi (Shimizu sec. III). A joint reaches a
limit L where n cos L - d sin L = 0 (tangent type) or the cosine equals cos L (cosine type):
equations a sin psi + b cos psi + c = 0 with closed-form roots. :func:`psi_intervals` takes
those roots (and the roots of n and d, where a tangent-type joint may jump) as the only places
where feasibility can change and classifies each arc between them by the closed form at its
midpoint.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from derive.algebra import dualquat as dq
from derive.algebra import quaternion as quat
from derive.algebra.angles import wrap_angle
from derive.algebra.rotations import rot_y, rot_z
from derive.cache import memo
from derive.errors import DeriveError, InputError, as_finite_array
from derive.ik.euler import zyz, zyz_matrix
from derive.ik import select
from derive.ik.finish import Solutions, finish, rotation_angle
from derive.ik.subproblems import sp1, sp3, sp4
from derive.ik.subproblems._common import double_root
from derive.ik.tolerances import (ARC_MERGE, AXIS_TOL, CLASS_DIRECTION, CLASS_DISTANCE,
                                  MAP_ANGLE, MAP_POSITION, REACH_TOL, STRETCH_TOL,
                                  TRIG_DEGENERATE, WRIST_SINGULAR)
from derive.kinematics.fk import _pose_error, fk
from derive.model.geometry import numeric_chain
from derive.model.robot import load_robot

REASON_REACH = ("unreachable: the shoulder-wrist distance is outside [|d_se - d_ew|, d_se + d_ew]")
REASON_FOLDED = ("the wrist centre is at the shoulder point (d_se = d_ew, elbow folded): the "
                 "shoulder rotation is free in three dimensions; no arm angle")
REASON_JOINT = ("unreachable with the given joint value: the shoulder cannot carry the forearm "
                "onto the shoulder-wrist line")
REASON_ACCEPT = "no candidate reproduces the pose within ACCEPT_POSITION / ACCEPT_ANGLE"

_E = np.eye(3)                      # e_x, e_y, e_z of the canonical frame

#: Shoulder, elbow and wrist signs (GC2, GC4, GC6) of branch k = 4 i2 + 2 i4 + i6.
BRANCH_SIGNS = np.array([[1 - 2 * ((k >> 2) & 1), 1 - 2 * ((k >> 1) & 1), 1 - 2 * (k & 1)]
                         for k in range(8)], dtype=float)


@dataclass(frozen=True)
class SRSGeometry:
    """An SRS arm in its canonical frame (module docstring): FK(q) = B (R(s q), W(s q)) T."""

    robot: str
    d_bs: float             # base origin -> shoulder S (m), for the record
    d_se: float             # shoulder -> elbow
    d_ew: float             # elbow -> wrist centre
    d_wf: float             # wrist centre -> end-frame origin along the arm line at zero
    frame: np.ndarray       # (3, 3) canonical axes (columns) in base coordinates
    shoulder: np.ndarray    # (3,) S in base coordinates
    tool_rotation: np.ndarray     # (3, 3) end frame in the canonical wrist frame at zero
    tool_translation: np.ndarray  # (3,)
    signs: np.ndarray       # (7,) +-1: theta = signs * q
    limits: np.ndarray      # (7, 2) joint limits of q (rad)
    error: float            # largest mismatch of the relation on the check configurations


#: The former result type of :func:`ik_psi` and :func:`ik_joint`, now the one result type of all
#: classes (``count`` still reads as ``counts``).
SRSSolutions = Solutions


class SRSSweep(NamedTuple):
    """:func:`ik_sweep`: ``psi`` (n, m) the arm angles evaluated (NaN where a pose has no
    feasible arm angle), ``q`` (n, m, 8, 7) the solutions within limits, NaN-padded, ``count``
    (n, m), ``branch`` (n, m, 8)."""

    psi: np.ndarray
    q: np.ndarray
    count: np.ndarray
    branch: np.ndarray


# --------------------------------------------------------------------------- #
# Class test and canonical frame
# --------------------------------------------------------------------------- #
def srs_geometry(robot) -> SRSGeometry:
    """The canonical form of an SRS arm (module docstring), cached per robot identity and joint
    limits (it holds them); raises
    InputError naming the property a robot lacks."""
    robot = load_robot(robot)
    return memo("srs-geometry", (robot.id, robot.limits_id), lambda: _srs_geometry(robot))


def is_srs(robot) -> bool:
    try:
        srs_geometry(robot)
        return True
    except DeriveError:
        return False


def _unit(v):
    return v / np.linalg.norm(v)


def _nearest_on(p1, h1, p2, h2):
    """The point of line (p1, h1) nearest to line (p2, h2), h1 and h2 unit and not parallel."""
    c = h1 @ h2
    d = p2 - p1
    t = (d @ h1 - (d @ h2) * c) / (1.0 - c * c)
    return p1 + t * h1


def _off_line(p, s, u) -> float:
    """Distance of point p from the line through s along unit u."""
    d = p - s
    return float(np.linalg.norm(d - (d @ u) * u))


def _srs_geometry(robot) -> SRSGeometry:
    def fail(why):
        raise InputError(f"{robot.name}: not an SRS arm (spherical shoulder, revolute elbow, "
                         f"spherical wrist, stretched at the zero pose): {why}")

    if robot.dof != 7:
        fail(f"{robot.dof} joints, the class has 7")
    try:
        chain = numeric_chain(robot)
    except DeriveError as exc:
        fail(str(exc))
    if chain.n != 7 or any(t != "revolute" for t in chain.types):
        fail("the path to the end has a prismatic joint or not 7 joints")
    h = np.array([_unit(a) for a in chain.axes])
    pts = chain.start + np.vstack([np.zeros(3), np.cumsum(chain.links, axis=0)])[:7]
    tol, dtol = CLASS_DISTANCE, CLASS_DIRECTION
    for i, j in ((0, 1), (4, 5)):
        if abs(h[i] @ h[j]) > dtol:
            fail(f"axis {j + 1} is not perpendicular to axis {i + 1}")
    for i in (3, 5):
        if np.linalg.norm(np.cross(h[1], h[i])) > dtol:
            fail(f"axis {i + 1} is not parallel to axis 2 at the zero pose")
    s = _nearest_on(pts[1], h[1], pts[0], h[0])          # shoulder: axis 2 meets axis 1
    w = _nearest_on(pts[5], h[5], pts[4], h[4])          # wrist centre: axis 6 meets axis 5
    if np.linalg.norm(w - s) < tol:
        fail("shoulder and wrist centre coincide")
    u = _unit(w - s)
    for i, p in ((0, s), (2, s), (4, w), (6, w)):
        if np.linalg.norm(np.cross(h[i], u)) > dtol or _off_line(pts[i], p, u) > tol:
            fail(f"axis {i + 1} does not lie on the shoulder-wrist line at the zero pose")
    if abs(h[1] @ u) > dtol or abs(h[3] @ u) > dtol or abs(h[5] @ u) > dtol:
        fail("axes 2, 4, 6 are not perpendicular to the shoulder-wrist line at the zero pose")
    if _off_line(s, pts[1], h[1]) > tol or _off_line(w, pts[5], h[5]) > tol:
        fail("axes 2 and 6 do not cross the shoulder-wrist line")
    e = _nearest_on(pts[3], h[3], s, u)
    if _off_line(e, pts[3], h[3]) > tol:
        fail("axis 4 does not cross the shoulder-wrist line (elbow offset)")
    d_se, d_ew = float((e - s) @ u), float((w - e) @ u)
    if d_se <= tol or d_ew <= tol:
        fail("the elbow axis does not cross the shoulder-wrist line between shoulder and wrist")
    y = h[1]
    frame = np.column_stack([np.cross(y, u), y, u])
    signs = np.array([float(np.sign(h[i] @ (u if i % 2 == 0 else y))) for i in range(7)])
    # end frame at zero, in the canonical wrist frame (orientation `frame`, origin w)
    pose0 = fk(robot, np.zeros(7))
    r0 = quat._to_matrix(pose0[None, :4])[0]
    p0 = dq._translation(pose0[None])[0]
    t_rot = frame.T @ r0
    t_tr = frame.T @ (p0 - w)
    lim = robot.limits
    geo = SRSGeometry(robot.name, float(np.linalg.norm(s)), d_se, d_ew, float(t_tr[2]), frame,
                      s, t_rot, t_tr, signs, lim, 0.0)
    rng = np.random.default_rng(17)
    q = rng.uniform(-math.pi, math.pi, size=(24, 7))
    r, p = _canonical_fk(geo, q * signs)
    via = dq.from_rt(quat.from_matrix(frame @ r @ t_rot),
                     s + (frame @ (p + r @ t_tr)[..., None])[..., 0])
    dp, dr = _pose_error(fk(robot, q), via)
    err = float(max(dp.max(), dr.max()))
    if not (dp.max() <= MAP_POSITION and dr.max() <= MAP_ANGLE):
        fail(f"the canonical chain reproduces its FK only to {err:.3g} (m, rad)")
    return SRSGeometry(robot.name, geo.d_bs, d_se, d_ew, geo.d_wf, frame, s, t_rot, t_tr,
                       signs, lim, err)


# --------------------------------------------------------------------------- #
# Rotations (batches)
# --------------------------------------------------------------------------- #
def _skew(x):
    z = np.zeros_like(x[..., 0])
    return np.stack([np.stack([z, -x[..., 2], x[..., 1]], -1),
                     np.stack([x[..., 2], z, -x[..., 0]], -1),
                     np.stack([-x[..., 1], x[..., 0], z], -1)], -2)


def _t(m):
    return np.swapaxes(m, -1, -2)


def _forearm(geo: SRSGeometry, t4):
    """v(t4) = d_se e_z + d_ew Ry(t4) e_z: shoulder -> wrist centre with the shoulder at zero."""
    z = np.zeros_like(t4)
    return np.stack([geo.d_ew * np.sin(t4), z, geo.d_se + geo.d_ew * np.cos(t4)], -1)


def _canonical_fk(geo: SRSGeometry, theta):
    """(R, W) of the canonical chain for angles theta (..., 7): the module docstring's product."""
    t = [theta[..., i] for i in range(7)]
    rs = zyz_matrix(t[0], t[1], t[2])
    w = (rs @ _forearm(geo, t[3])[..., None])[..., 0]
    r = rs @ rot_y(t[3]) @ zyz_matrix(t[4], t[5], t[6])
    return r, w


# --------------------------------------------------------------------------- #
# Input
# --------------------------------------------------------------------------- #
def _poses(poses) -> tuple[np.ndarray, bool]:
    arr = as_finite_array(poses, "poses", last_dim=8)
    if arr.ndim > 2:
        raise InputError(f"poses: expected shape (8,) or (n, 8), got {arr.shape}")
    single = arr.ndim == 1
    return dq.check_unit(arr.reshape(-1, 8), "poses"), single


def _per_pose(value, name: str, n: int) -> np.ndarray:
    arr = as_finite_array(value, name, ndim_min=0)
    if arr.ndim == 0 or arr.shape == (1,):
        return np.full(n, float(arr.reshape(-1)[0]))
    if arr.shape != (n,):
        raise InputError(f"{name}: expected a number or shape ({n},) (one per pose), got {arr.shape}")
    return arr


def _q_ref(q_ref, n: int) -> np.ndarray | None:
    if q_ref is None:
        return None
    arr = as_finite_array(q_ref, "q_ref", last_dim=7)
    if arr.ndim == 1:
        return np.broadcast_to(arr, (n, 7))
    if arr.shape != (n, 7):
        raise InputError(f"q_ref: expected shape (7,) or ({n}, 7), got {arr.shape}")
    return arr


def _into_canonical(geo: SRSGeometry, poses: np.ndarray):
    """Step 0, the wrist centre (Shimizu sec. III): the pose's rotation and wrist centre in
    the canonical frame, R_c = C^T R T_R^T and W = C^T (p - S) - R_c t_T."""
    r = quat._to_matrix(poses[:, :4])
    p = dq._translation(poses)
    rc = geo.frame.T @ r @ geo.tool_rotation.T
    w = (geo.frame.T @ (p - geo.shoulder)[..., None])[..., 0] - rc @ geo.tool_translation
    return rc, w


# --------------------------------------------------------------------------- #
# The named closed-form steps
# --------------------------------------------------------------------------- #
def elbow_cosine(geo: SRSGeometry, w):
    """The elbow's reach test (Shimizu sec. III; Faria, the elbow angle): the triangle S, E, W
    gives cos t4 = (|W|^2 - d_se^2 - d_ew^2) / (2 d_se d_ew), independent of psi; beyond
    1 + REACH_TOL in size W is out of reach, within STRETCH_TOL of +-1 the arm is stretched or
    folded (:func:`elbow`)."""
    return (np.sum(w * w, -1) - geo.d_se ** 2 - geo.d_ew ** 2) / (2.0 * geo.d_se * geo.d_ew)


def elbow(geo: SRSGeometry, w, c4):
    """Step 1, the elbow: subproblem 3, ||Ry(t4) d_ew e_z + d_se e_z|| = |W| (the cosine law of
    the triangle S, E, W), its two roots (..., 2) with t4 >= 0 first. Within STRETCH_TOL of a
    stretched or folded arm (the cosine ``c4`` of :func:`elbow_cosine` near +-1; beyond 1 sp3
    returns its least-squares root) both are t4 = 0 or pi, so the two elbow branches coincide
    exactly there (a rounding of 1e-16 would otherwise split them by 1e-8 rad; the pose moves
    by ~1e-15 m)."""
    roots = sp3(_E[1], geo.d_ew * _E[2], -geo.d_se * _E[2], np.linalg.norm(w, axis=-1)).theta[..., ::-1, 0]
    return np.where((c4 >= 1.0 - STRETCH_TOL)[..., None], 0.0,
                    np.where((c4 <= -1.0 + STRETCH_TOL)[..., None], np.pi, roots))


def reference_shoulder(geo: SRSGeometry, w, t4):
    """Step 2, the reference configuration (Shimizu sec. III, t3 = 0), R0 = Rz(a) Ry(b) with
    R0 v(t4) = W, by two subproblems 1: a = sp1(e_z, e_x -> W), the plane of axis 1 and W
    (sp1's degenerate case, W on axis 1, gives a = 0), then b = sp1(e_y, v(t4) -> Rz(a)^T W),
    the forearm turned onto W in that plane."""
    w = np.broadcast_to(w, np.broadcast_shapes(w.shape, np.shape(t4) + (3,)))
    a = sp1(_E[2], _E[0], w).theta[..., 0, 0]
    b = sp1(_E[1], _forearm(geo, t4), np.einsum("...ji,...j->...i", rot_z(a), w)).theta[..., 0, 0]
    return rot_z(a) @ rot_y(b)


def arm_angle_matrices(w, r0):
    """Step 3, the shoulder as a function of psi (Shimizu sec. III): with x = W/|W| and
    R_psi = I + sin psi [x]x + (1 - cos psi) [x]x^2 (Rodrigues),
    R_s = R_psi R0 = A_s sin psi + B_s cos psi + C_s,
    A_s = [x]x R0, B_s = -[x]x^2 R0, C_s = x x^T R0."""
    x = w / np.linalg.norm(w, axis=-1, keepdims=True)
    k = _skew(x)
    a = k @ r0
    b = -(k @ (k @ r0))
    c = x[..., :, None] * x[..., None, :] @ r0
    return a, b, c


def _free_angles(geo: SRSGeometry, q_ref, n):
    """Canonical t1 and t5 used where the shoulder / wrist is aligned: s q_ref, else 0."""
    if q_ref is None:
        return np.zeros(n), np.zeros(n)
    return geo.signs[0] * q_ref[:, 0], geo.signs[4] * q_ref[:, 4]


def _solve_psi(geo: SRSGeometry, rc, w, psi, q_ref):
    """The 8 branches (n, 8, 7) in robot joint values (wrapped), singular (n, 8), reason (n,)
    (empty where the pose has solutions); unreachable poses give NaN rows here (the public
    functions drop them)."""
    n = len(w)
    out = np.full((n, 8, 7), np.nan)
    singular = np.zeros((n, 8), dtype=bool)
    reason = np.full(n, "", dtype=object)
    c4 = elbow_cosine(geo, w)
    folded = np.linalg.norm(w, axis=-1) < CLASS_DISTANCE
    bad = np.abs(c4) > 1.0 + REACH_TOL
    reason[bad] = REASON_REACH
    reason[folded] = REASON_FOLDED
    ok = ~(bad | folded)
    if not np.any(ok):
        return out, singular, reason
    rc, w, psi = rc[ok], w[ok], psi[ok]
    free1, free5 = _free_angles(geo, None if q_ref is None else q_ref[ok], int(ok.sum()))
    sign = np.array([1.0, -1.0])
    # axes after the pose: elbow i4, shoulder i2, wrist i6 (signs +, -)
    t4 = elbow(geo, w, c4[ok])                                   # (m, 2): step 1
    r0 = reference_shoulder(geo, w[:, None], t4)                 # step 2
    a_s, b_s, c_s = arm_angle_matrices(w[:, None], r0)
    rs = (a_s * np.sin(psi)[:, None, None, None] + b_s * np.cos(psi)[:, None, None, None]
          + c_s)                                                 # step 3: R_s(psi), (m, 2, 3, 3)
    t1, t2, t3, sing_s = zyz(rs[:, :, None], sign, free1[:, None, None])     # step 4, (m, 2, 2)
    # step 5: the wrist rotation R_w = (Rz(t1) Ry(t2) Rz(t3) Ry(t4))^T R (from the rounded
    # shoulder angles, so that the wrist absorbs their rounding)
    rw = _t(zyz_matrix(t1, t2, t3) @ rot_y(t4)[:, :, None]) @ rc[:, None, None]
    t5, t6, t7, sing_w = zyz(rw[:, :, :, None], sign, free5[:, None, None, None])  # step 6
    shape = t5.shape                                             # (m, 2, 2, 2): i4, i2, i6
    theta = np.stack([np.broadcast_to(t[..., None], shape) for t in (t1, t2, t3)]
                     + [np.broadcast_to(t4[:, :, None, None], shape), t5, t6, t7], -1)
    sing = (sing_s[..., None] | sing_w
            | (np.abs(np.sin(t4)) < WRIST_SINGULAR)[:, :, None, None])
    # branch k = 4 i2 + 2 i4 + i6
    sub = wrap_angle(theta * geo.signs).transpose(0, 2, 1, 3, 4).reshape(-1, 8, 7)
    sub_sing = sing.transpose(0, 2, 1, 3).reshape(-1, 8)
    out[ok] = sub
    singular[ok] = sub_sing
    return out, singular, reason


def _finish(robot, geo, rc, w, poses, cand, singular, reason, free) -> Solutions:
    """The finish step of all classes (:func:`derive.ik.finish.finish`: the FK check with its one
    metric, here by the canonical chain against (R_c, W); the merge of branches that coincide on
    a singular set; compaction), with the reasons."""
    def errors(q):
        r, p = _canonical_fk(geo, q * geo.signs)
        return np.linalg.norm(p - w[:, None], axis=-1), rotation_angle(rc[:, None], r)

    out = Solutions(*finish(robot, poses, cand, singular, errors=errors), reason.copy(), free)
    out.reason[(out.counts == 0) & (out.reason == "")] = REASON_ACCEPT
    return out


def _single(res: Solutions, single: bool) -> Solutions:
    return res.rows(0) if single else res


# --------------------------------------------------------------------------- #
# Public API
# --------------------------------------------------------------------------- #
def ik_psi(robot, poses, psi, *, q_ref=None) -> SRSSolutions:
    """All solutions (up to 8: GC2, GC4, GC6) of poses (8,) or (n, 8) of the robot's end frame
    at arm angle ``psi`` (a number or one per pose, rad; module docstring for its definition).

    The steps: wrist centre (:func:`_into_canonical`), elbow (:func:`elbow`, sp3), reference
    configuration (:func:`reference_shoulder`, sp1 and sp1), shoulder as a function of psi
    (:func:`arm_angle_matrices`), shoulder and wrist joints by ZYZ decomposition
    (:func:`derive.ik.euler.zyz`). ``q_ref`` (7,) or (n, 7) supplies q1 (shoulder aligned) and q5 (wrist
    aligned) on the singular sets, else they are 0. Joint values are wrapped to (-pi, pi];
    limits are not applied (see :func:`psi_intervals`, :func:`within_limits`). Returns
    :class:`derive.ik.finish.Solutions` (one pose: its rows without the leading axis)."""
    robot = load_robot(robot)
    geo = srs_geometry(robot)
    P, single = _poses(poses)
    n = len(P)
    psi = _per_pose(psi, "psi", n)
    qr = _q_ref(q_ref, n)
    rc, w = _into_canonical(geo, P)
    cand, singular, reason = _solve_psi(geo, rc, w, psi, qr)
    return _single(_finish(robot, geo, rc, w, P, cand, singular, reason, psi), single)


def arm_angle(robot, q) -> np.ndarray:
    """The arm angle psi (rad, in (-pi, pi]) of configurations q (7,) or (n, 7): with R_s the
    configuration's shoulder rotation and R0 the reference configuration for its W and t4,
    R_s R0^T is the rotation by psi about x = W/|W|; psi = atan2(x . (n x m), n . m) with
    n = R0 e_y, m = R_s e_y (both perpendicular to x, since v(t4) lies in the x-z plane).
    A configuration with its wrist centre at the shoulder has no arm angle (InputError)."""
    geo = srs_geometry(robot)
    arr = as_finite_array(q, "q", last_dim=7)
    if arr.ndim > 2:
        raise InputError(f"q: expected shape (7,) or (n, 7), got {arr.shape}")
    theta = arr.reshape(-1, 7) * geo.signs
    rs = zyz_matrix(theta[:, 0], theta[:, 1], theta[:, 2])
    w = (rs @ _forearm(geo, theta[:, 3])[..., None])[..., 0]
    norm = np.linalg.norm(w, axis=-1)
    if np.any(norm < CLASS_DISTANCE):
        raise InputError(f"q: row {int(np.argmax(norm < CLASS_DISTANCE))} has its wrist centre at the "
                         "shoulder point; the arm angle is undefined there")
    x = w / norm[:, None]
    r0 = reference_shoulder(geo, w, theta[:, 3])
    nn, mm = r0[:, :, 1], rs[:, :, 1]
    psi = np.arctan2(np.sum(x * np.cross(nn, mm), -1), np.sum(nn * mm, -1))
    out = wrap_angle(psi)
    return out[0] if arr.ndim == 1 else out


def within_limits(robot, q) -> np.ndarray:
    """(...,) bool: every joint of q (..., 7) has a winding q + 2 pi k within its limits
    (LIMIT_SLACK); NaN rows are False."""
    geo = srs_geometry(robot)
    return _within(geo.limits, np.asarray(q, dtype=float))


def _within(limits, q):
    return select.inside_limits(q, limits)


# --------------------------------------------------------------------------- #
# One joint given instead of psi
# --------------------------------------------------------------------------- #
JOINTS_GIVEN = (1, 3, 5, 7)
#: Ry(pi): turns the reversed chain (wrist to shoulder) into canonical form (see _reverse).
_RY_PI = np.diag([-1.0, 1.0, -1.0])


def ik_joint(robot, poses, joint: int, value, *, q_ref=None) -> SRSSolutions:
    """All solutions (up to 8) of poses (8,) or (n, 8) with joint ``joint`` (1-based: 1, 3, 5
    or 7) held at ``value`` (rad, a number or one per pose): the remaining 6R problem in closed
    form (:func:`joint_given_steps`). Joints 5 and 7 are joints 3 and 1 of the reversed chain
    (:func:`_reverse`). ``q_ref`` supplies the joint that a singular set leaves free (else 0).
    Branch id k = 4 i + 2 i4 + ie: i the root of the shoulder (wrist) subproblem, i4 the elbow
    sign, ie the sign of the Euler decomposition solved last (+ first)."""
    geo = srs_geometry(robot)
    if isinstance(joint, bool) or not isinstance(joint, (int, np.integer)) or joint not in JOINTS_GIVEN:
        raise InputError(f"joint: ik_joint solves with joint 1, 3, 5 or 7 given (1-based), got {joint!r}")
    P, single = _poses(poses)
    n = len(P)
    val = _per_pose(value, "value", n)
    qr = _q_ref(q_ref, n)
    rc, w = _into_canonical(geo, P)
    reason = np.full(n, "", dtype=object)
    c4 = elbow_cosine(geo, w)
    bad = np.abs(c4) > 1.0 + REACH_TOL
    reason[bad] = REASON_REACH
    tg = geo.signs[joint - 1] * val
    fr = np.zeros((n, 7)) if qr is None else qr * geo.signs      # canonical free values
    if joint in (1, 3):
        theta, singular, reach = joint_given_steps(geo, rc, w, joint, tg, fr[:, 0], fr[:, 2], fr[:, 4])
    else:
        rgeo, rrc, rw = _reverse(geo, rc, w)
        phi, singular, reach = joint_given_steps(rgeo, rrc, rw, 8 - joint, tg,
                                                 fr[:, 6], fr[:, 4], fr[:, 2])
        theta = phi[..., ::-1] * np.array([1.0, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0])
        flip = np.array([k ^ 2 for k in range(8)])          # the elbow sign turns: t4 = -phi4
        theta, singular = theta[:, flip], singular[:, flip]
    cand = np.where(bad[:, None, None], np.nan, wrap_angle(theta * geo.signs))
    singular = singular & ~bad[:, None]
    reason[~np.any(reach, 1) & (reason == "")] = REASON_JOINT
    return _single(_finish(robot, geo, rc, w, P, cand, singular, reason, val), single)


def _reverse(geo: SRSGeometry, rc, w):
    """The chain read from the wrist to the shoulder, in canonical form: with phi = (t7, -t6,
    t5, -t4, t3, -t2, t1) and d_se, d_ew swapped, Ry(pi) R^T Ry(pi) = Rz(phi1) Ry(phi2) ...
    Rz(phi7) and Ry(pi) (-R^T W) = Rz(phi1) Ry(phi2) Rz(phi3) v'(phi4) (conjugation by Ry(pi)
    negates z-rotations and keeps y-rotations)."""
    from_end = _t(rc)
    rgeo = replace(geo, d_se=geo.d_ew, d_ew=geo.d_se)       # only the lengths are used
    rrc = _RY_PI @ from_end @ _RY_PI
    rw = -(_RY_PI @ (from_end @ w[..., None]))[..., 0]
    return rgeo, rrc, rw


def joint_given_steps(geo: SRSGeometry, rc, w, joint: int, tg, free1, free3, free5):
    """The closed form with canonical joint t1 (``joint`` 1) or t3 (``joint`` 3) given: canonical
    angles (n, 8, 7) (NaN where a root does not exist), singular (n, 8), root exists (n, 8).

    Steps: the elbow as in :func:`ik_psi` (sp3, two signs); then the shoulder carries v(t4)
    onto W with the given joint (Paden-Kahan subproblem 2 about two of the axes z, y, z, solved
    as IK-Geo does, a subproblem 4 for the height along the first axis and a subproblem 1):
    - t3 given: Rz(t1) Ry(t2) u = W with u = Rz(t3) v(t4): t2 by sp4, e_z^T Ry(t2) u = W_z
      (t2 = +-acos(W_z / r) - atan2(u_x, u_z), r = hypot(u_x, u_z); the double root within
      STRETCH_TOL of |W_z / r| = 1), t1 by sp1 about axis 1, Ry(t2) u to W (t1 free where W
      lies on axis 1);
    - t1 given: Ry(t2) Rz(t3) v = y with y = Rz(t1)^T W: t3 by sp4, e_y^T Rz(t3) v = y_y
      (sin t3 = y_y / v_x, two roots, asin first; the double root within STRETCH_TOL of
      |sin t3| = 1), t2 by sp1 about axis 2, Rz(t3) v to y (t3 free where the elbow is
      stretched, v_x = 0);
    and the wrist joints by the ZYZ decomposition of (R_s Ry(t4))^T R."""
    n = len(w)
    theta = np.full((n, 8, 7), np.nan)
    singular = np.zeros((n, 8), dtype=bool)
    reach_all = np.zeros((n, 8), dtype=bool)
    c4 = elbow_cosine(geo, w)
    ok = np.abs(c4) <= 1.0 + REACH_TOL
    t4s = elbow(geo, w, c4)
    for i4 in range(2):
        t4 = t4s[:, i4]
        v = _forearm(geo, t4)
        if joint == 3:
            t3 = tg
            wv = (rot_z(t3) @ v[..., None])[..., 0]
            r = np.hypot(wv[:, 0], wv[:, 2])
            cz = w[:, 2] / np.where(r > 0, r, 1.0)
            reach = (np.abs(cz) <= 1.0 + REACH_TOL) & (r > 0)
            # sp4: e_z^T Ry(t2) wv = W_z; within STRETCH_TOL of |cz| = 1 the double root
            roots = double_root(sp4(_E[2], _E[1], wv, w[:, 2]).theta[..., 0],
                                 np.abs(cz) >= 1.0 - STRETCH_TOL)
            on_axis = np.hypot(w[:, 0], w[:, 1]) < AXIS_TOL
        else:
            t1 = tg
            yv = (_t(rot_z(t1)) @ w[..., None])[..., 0]
            stretched = np.abs(v[:, 0]) < WRIST_SINGULAR * max(geo.d_ew, 1.0)
            s3 = yv[:, 1] / np.where(stretched, 1.0, v[:, 0])
            reach = np.where(stretched, np.abs(yv[:, 1]) <= REACH_TOL, np.abs(s3) <= 1.0 + REACH_TOL)
            # sp4: e_y^T Rz(t3) v = (R_z(t1)^T W)_y, root i = 0 first: asin(W_y / v_x) (sp4's slot 1
            # for v_x > 0, slot 0 else); within STRETCH_TOL of |sin t3| = 1 the double root; t3
            # free where the elbow is stretched
            roots = double_root(sp4(_E[1], _E[2], v, yv[:, 1]).theta[..., 0],
                                np.abs(s3) >= 1.0 - STRETCH_TOL)
            roots = np.where((v[:, :1] > 0), roots[:, ::-1], roots)
            roots = np.where(stretched[:, None], free3[:, None], roots)
        reach = reach & ok
        for i, root in enumerate(roots.T):
            if joint == 3:
                t2 = root
                u = (rot_y(t2) @ wv[..., None])[..., 0]
                t1 = np.where(on_axis, free1, sp1(_E[2], u, w).theta[:, 0, 0])     # sp1 about axis 1
                sing_s = on_axis
            else:
                t3 = root
                t2 = sp1(_E[1], (rot_z(t3) @ v[..., None])[..., 0], yv).theta[:, 0, 0]   # about axis 2
                sing_s = stretched
            t1b, t3b = np.broadcast_to(t1, (n,)), np.broadcast_to(t3, (n,))
            rw = _t(zyz_matrix(t1b, t2, t3b) @ rot_y(t4)) @ rc
            for i6, g6 in enumerate((1.0, -1.0)):
                t5, t6, t7, sing_w = zyz(rw, g6, free5)
                k = 4 * i + 2 * i4 + i6
                th = np.stack([t1b, t2, t3b, t4, t5, t6, t7], -1)
                theta[reach, k] = th[reach]
                singular[:, k] = reach & (sing_s | sing_w)
                reach_all[:, k] = reach
    return theta, singular, reach_all


# --------------------------------------------------------------------------- #
# Feasible arm angles under the joint limits (Shimizu sec. III)
# --------------------------------------------------------------------------- #
def _trig_roots(a, b, c):
    """(..., 2) roots psi in [-pi, pi] of a sin psi + b cos psi + c = 0 (arrays of one shape):
    with r = hypot(a, b), r cos(psi - atan2(a, b)) = -c; NaN where there is none."""
    r = np.hypot(a, b)
    ok = (r >= TRIG_DEGENERATE) & (np.abs(c) <= r)
    base = np.arctan2(a, b)
    d = np.arccos(np.clip(-c / np.where(ok, r, 1.0), -1.0, 1.0))
    roots = np.stack([base + d, base - d], -1)
    # x - 2 pi rint(x / 2 pi) is exact here (|x| <= 2 pi, Sterbenz), as math.remainder
    roots = roots - 2.0 * math.pi * np.rint(roots / (2.0 * math.pi))
    return np.where(ok[..., None], roots, np.nan)


def _breakpoints(geo: SRSGeometry, rc, w) -> np.ndarray:
    """(m, 82) arm angles per pose where a joint of a branch can meet a limit or jump, with -pi
    and pi; NaN where a root does not exist (and for a whole pose without arm angles).

    For each elbow sign, R_s and R_w are A sin psi + B cos psi + C (:func:`arm_angle_matrices`);
    tangent-type joints (numerator, denominator entries) give the roots of n cos L - d sin L and
    of n and d; cosine-type joints the roots of m - cos L (module docstring, "Feasible
    intervals")."""
    m = len(w)
    c4 = elbow_cosine(geo, w)
    ok = (np.abs(c4) <= 1.0 + REACH_TOL) & (np.linalg.norm(w, axis=-1) >= CLASS_DISTANCE)
    wk = np.where(ok[:, None], w, 1.0)
    t4s = elbow(geo, wk, np.where(ok, c4, 1.0))
    tangent = (((0, 1, 2), (0, 0, 2), 0), ((0, 2, 1), (0, 2, 0), 2),
               ((1, 1, 2), (1, 0, 2), 4), ((1, 2, 1), (1, 2, 0), 6))
    cosine = (((0, 2, 2), 1), ((1, 2, 2), 5))
    parts = [np.full((m, 1), -math.pi), np.full((m, 1), math.pi)]
    for t4 in t4s.T:
        r0 = reference_shoulder(geo, wk, t4)
        shoulder = arm_angle_matrices(wk, r0)                       # A_s, B_s, C_s: (m, 3, 3)
        r4 = rot_y(t4)
        wrist = [_t(x @ r4) @ rc for x in shoulder]                 # A_w, B_w, C_w
        abc = np.stack([np.stack(shoulder, -1), np.stack(wrist, -1)], 1)   # (m, 2, 3, 3, 3)
        for num, den, j in tangent:
            an, ad = abc[:, num[0], num[1], num[2]], abc[:, den[0], den[1], den[2]]   # (m, 3)
            parts += [_trig_roots(*an.T), _trig_roots(*ad.T)]
            for lim in geo.limits[j]:
                if np.isfinite(lim):
                    L = geo.signs[j] * lim
                    parts.append(_trig_roots(*(an * math.cos(L) - ad * math.sin(L)).T))
        for ent, j in cosine:
            a = abc[:, ent[0], ent[1], ent[2]]
            for lim in geo.limits[j]:
                if np.isfinite(lim):
                    parts.append(_trig_roots(a[:, 0], a[:, 1], a[:, 2] - math.cos(lim)))
    pts = np.concatenate(parts, 1)
    pts[~ok] = np.nan
    return pts


def _arcs(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The arcs between consecutive distinct breakpoints (closer than ARC_MERGE count as one):
    lower and upper ends (m, K - 1) in [-pi, pi], NaN past a pose's last arc."""
    s = np.sort(np.clip(pts, -math.pi, math.pi), 1)             # NaN sort last
    keep = np.concatenate([np.isfinite(s[:, :1]), np.diff(s, axis=1) > ARC_MERGE], 1)
    s = np.sort(np.where(keep, s, np.nan), 1)
    return s[:, :-1], s[:, 1:]


def _feasible_arcs(geo: SRSGeometry, rc, w, feasible=None):
    """Arcs (lo, hi (m, K)) of each pose and which of them are feasible: (m, K, 8) per branch
    by :func:`_solve_psi` and the limits, or (m, K) for any branch by ``feasible(rows, psi)``
    (the rows (r,) of the poses and the arm angles (r,) -> bool (r,)), decided at each arc's
    midpoint (the breakpoints are the only places where feasibility can change)."""
    lo, hi = _arcs(_breakpoints(geo, rc, w))
    have = np.isfinite(hi)
    rows = np.nonzero(have)[0]
    mids = 0.5 * (lo[have] + hi[have])
    if feasible is None:
        out = np.zeros(lo.shape + (8,), dtype=bool)
        cand, _, _ = _solve_psi(geo, rc[rows], w[rows], mids, None)
        out[have] = _within(geo.limits, cand)                     # NaN rows are False
    else:
        out = np.zeros(lo.shape, dtype=bool)
        out[have] = feasible(rows, mids)
    return lo, hi, out


def psi_intervals(robot, pose) -> list[np.ndarray]:
    """The arm angles at which each branch k (0-7, as in :func:`ik_psi`) of one pose (8,) has
    every joint within its limits: a list of 8 arrays (m, 2) of closed intervals [lo, hi] in
    [-pi, pi], sorted (an interval across pi appears as [b, pi] and [-pi, a]); empty arrays for
    a branch (or a pose) with no feasible arm angle.

    The boundaries are the closed-form roots of the module docstring ("Feasible intervals");
    each arc between consecutive roots is feasible or not as a whole, decided at its midpoint by
    :func:`ik_psi`'s closed form."""
    geo = srs_geometry(robot)
    P, single = _poses(pose)
    if not single:
        raise InputError(f"pose: psi_intervals takes one pose (8,), got shape {P.shape}")
    rc, w = _into_canonical(geo, P)
    lo, hi, feasible = _feasible_arcs(geo, rc, w)
    out = []
    for k in range(8):
        iv = []
        for i in np.flatnonzero(feasible[0, :, k]):
            a, b = float(lo[0, i]), float(hi[0, i])
            if iv and abs(iv[-1][1] - a) <= ARC_MERGE:
                iv[-1][1] = b
            else:
                iv.append([a, b])
        out.append(np.array(iv, dtype=float).reshape(-1, 2))
    return out


def sweep_psi(robot, poses, n: int, feasible=None) -> np.ndarray:
    """(m, n) arm angles for poses (8,) or (m, 8): per pose ``n`` values spread evenly over the
    union of the branches' feasible intervals (:func:`psi_intervals`), the midpoints of n equal
    parts of its total length; a NaN row for a pose without a feasible arm angle. All poses at
    once: ``feasible(poses (r, 8), psi (r,))`` -> bool (r,), whether any solution at psi is
    within the limits, replaces the numpy closed form's test at the arcs' midpoints (the
    generated kernels' batch IK: ``derive.kernels(robot, "c").ik_sweep``)."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise InputError(f"n: expected a positive integer, got {n!r}")
    geo = srs_geometry(robot)
    P, _ = _poses(poses)
    rc, w = _into_canonical(geo, P)
    test = None if feasible is None else (lambda rows, psi: feasible(P[rows], psi))
    lo, hi, ok = _feasible_arcs(geo, rc, w, test)
    if ok.ndim == 3:
        ok = ok.any(-1)
    length = np.where(ok, hi - lo, 0.0)                          # NaN arcs are not ok
    edges = np.concatenate([np.zeros((len(P), 1)), np.cumsum(length, 1)], 1)
    total = edges[:, -1:]
    s = (np.arange(n) + 0.5) / n * total                         # (m, n)
    # the arc holding s: the last one starting at or below it (zero-length arcs are skipped:
    # s < total, so that arc has positive length)
    j = np.minimum((edges[:, None, :-1] <= s[:, :, None]).sum(-1) - 1, lo.shape[1] - 1)
    rows = np.arange(len(P))[:, None]
    psi = lo[rows, j] + (s - edges[rows, j])
    psi[total[:, 0] <= 0.0] = np.nan
    return psi


def ik_sweep(robot, poses, n: int) -> SRSSweep:
    """``n`` arm angles per pose spread evenly over the union of the branches' feasible
    intervals (:func:`sweep_psi`), and at each the solutions within the joint limits. Poses
    without a feasible arm angle get psi = NaN and count 0."""
    geo = srs_geometry(robot)
    psi = sweep_psi(robot, poses, n)
    P, single = _poses(poses)
    m = len(P)
    q = np.full((m, n, 8, 7), np.nan)
    count = np.zeros((m, n), dtype=int)
    branch = np.full((m, n, 8), -1)
    have = np.isfinite(psi[:, 0])
    if np.any(have):
        rows = np.repeat(np.flatnonzero(have), n)
        res = ik_psi(robot, P[rows], psi[have].reshape(-1))
        inside = _within(geo.limits, res.q)
        order = np.argsort(~inside, axis=1, kind="stable")
        qq = np.take_along_axis(res.q, order[..., None], 1)
        kept = np.take_along_axis(inside, order, 1)
        qq[~kept] = np.nan
        q[have] = qq.reshape(-1, n, 8, 7)
        count[have] = kept.sum(1).reshape(-1, n)
        branch[have] = np.where(kept, np.take_along_axis(res.branch, order, 1), -1).reshape(-1, n, 8)
    out = SRSSweep(psi, q, count, branch)
    return type(out)(*(x[0] for x in out)) if single else out
