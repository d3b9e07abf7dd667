"""Closed-form inverse kinematics of the Franka Emika Panda class with q7 as the free parameter.

The class: the Panda / FR3 chain, Franka's modified-DH table (Craig, T_i = Rx(alpha_(i-1))
Tx(a_(i-1)) Rz(theta_i) Tz(d_i)) with seven lengths, the **canonical chain**
(:func:`canonical_description`):

=====  ============  ===========  ===========
joint  alpha_(i-1)   a_(i-1)      d_i
=====  ============  ===========  ===========
1      0             0            d1
2      -pi/2         0            0
3      pi/2          0            d3
4      pi/2          a3           0
5      -pi/2         a4           d5
6      pi/2          0            0
7      pi/2          a6           0
end    0             0            d7 (flange)
=====  ============  ===========  ===========

Axes 1, 2, 3 meet in the shoulder S = (0, 0, d1) (a spherical shoulder); the elbow offsets a3,
a4 and the wrist offset a6 make the arm non-spherical at the wrist, so a pose leaves a
one-parameter self-motion. With q7 given the rest is in closed form, with up to 8 solutions.
A robot of the class is related to the canonical chain by constant transforms,

    FK_robot(q) = B  FK_canonical(q)  T,

found by :func:`panda_geometry` from the robot's axes at the zero pose (same joint values,
same zero pose; another base frame or end frame, such as a hand's TCP, goes into B and T).

The construction (our own; it follows the geometry of He & Liu, "Analytical inverse
kinematics for Franka Emika Panda - a geometric solver for 7-DOF manipulators with
unconventional design", ICCCR 2021: fix q7, locate the point O6, the elbow angle from the
shoulder-O6 distance, then q6, q5 and the shoulder), as named steps on the canonical flange
pose (R7, p):

1. ``frame6``: O7 = p - d7 z7; R6 = R7 Rz(-q7) Rx(-pi/2) (eq. F7: T7 = T6 Rx(pi/2) Tx(a6)
   Rz(q7)); O6 = O7 - a6 x6. O6 is also the origin of frame 5 (a5 = d6 = 0).
2. ``shoulder_in_6``: v = R6^T (S - O6), the shoulder in frame 6.
3. ``elbow`` (q4), **subproblem 3**: the shoulder in frame 5 seen from the arm side is
   (X c5, -X s5, Z) with X = -(a3 c4 + d3 s4 + a4), Z = a3 s4 - d3 c4 - d5 (eq. E1), and
   (-X, Z) = Rz(q4) p1 - p2 with p1 = (a3, -d3, 0), p2 = (-a4, d5, 0), so |v|^2 = X^2 + Z^2 is
   ||Rz(q4) p1 - p2|| = |v| (sp3), i.e. A c4 + B s4 = K, A = a3 a4 + d3 d5, B = a4 d3 - a3 d5,
   K = (|v|^2 - a3^2 - d3^2 - a4^2 - d5^2) / 2 (eq. E2): q4 = atan2(B, A) +- acos(K / hypot(A, B)).
   |K| > hypot(A, B): O6 is outside the elbow's range (unreachable).
4. ``wrist`` (q5, q6), **subproblem 2**: the same point from the wrist side is Rx(pi/2) Rz(q6) v =
   (vx c6 - vy s6, -vz, vx s6 + vy c6) (eq. W1) = R(-e_y, q6) (vx, -vz, vy), so
   Rz(-q5) (X, 0, Z) = R(-e_y, q6) (vx, -vz, vy) (sp2): its height along axis 6 gives q5 from
   X s5 = vz, with X c5 = +-sqrt(X^2 - vz^2) (eq. W4, accurate where |X| is small), then q6
   by subproblem 1; the pair with X c5 <= 0 is q6 = atan2(vx, vy) + a, cos a = Z / hypot(vx, vy),
   the root of the third row vx s6 + vy c6 = Z(q4) (eq. W2) with the + sign, and
   X c5 = vx c6 - vy s6, X s5 = vz (eq. W3) hold.
5. ``shoulder`` (q1, q2, q3): R3 = R6 Rz(-q6) Rx(-pi/2) Rz(-q5) Rx(pi/2) Rz(-q4) Rx(-pi/2)
   = R6 Rz(-q6) Ry(-q5) Rz(-q4) Rx(-pi/2) (eq. S1), and R3 = Rz(q1) Ry(q2) Rz(q3) (eq. S2; both
   by Rx(-pi/2) Rz(t) Rx(pi/2) = Ry(t)), a ZYZ
   Euler decomposition: q2 = atan2(+-hypot(M13, M23), M33), q1 = atan2(+-M23, +-M13),
   q3 = atan2(+-M32, -+M31).

Branch id b = 4 i4 + 2 i6 + i2, with i = 0 for the + root and 1 for the - root of steps 3,
4 and 5. Steps 3 and 4 are subproblems of :mod:`derive.ik.subproblems` (sp3, sp2), step 5 the
one ZYZ of :mod:`derive.ik.euler`; the class adds its rules for double roots, free joints and
reach on its own quantities (the cosine K / hypot(A, B), X, hypot(vx, vy)). Singular sets (the
construction's, each a real singularity of the arm with q7 fixed):

* ``elbow stretched / folded``: |K| = hypot(A, B), the two q4 roots coincide (q4 = atan2(B, A)
  or + pi); the pairs merge, 4 solutions;
* ``S on axis 5`` (X = 0: q4 = 0 or q4 = 2 atan2(d3, a3) on the Panda): axes 3 and 5 are one
  line through S, q5 is free and q3 absorbs it; q5 is taken from ``q_ref`` (else 0), the
  solution is marked singular;
* ``S on axis 6`` (vx = vy = 0, needs Z(q4) = 0; impossible on the Panda, |Z| >= d5 - hypot(a3, d3)
  > 0): q6 free, taken from ``q_ref`` (else 0), marked singular;
* ``q6 double root``: |Z| = hypot(vx, vy), i.e. c5 = 0 (q5 = +-pi/2): the two q6 roots merge
  (below (X c5)^2 = DOUBLE_ROOT X^2 + W4_NOISE |X| they are made equal);
* ``axes 1 and 3 aligned`` (sin q2 = 0): only q1 + q3 (q2 = 0) or q1 - q3 (q2 = pi) is
  determined; q1 is taken from ``q_ref`` (else 0), marked singular.

The wrist centre on axis 1 (O6 on the z axis) is not singular here: q1 comes from the
orientation of frame 3 (step 5), not from the position of O6 as in He & Liu's q1 step.

Every candidate is checked by the reference FK (:func:`derive.kinematics.fk.fk`) and dropped
beyond :data:`~derive.ik.tolerances.ACCEPT_POSITION` (m) / :data:`~derive.ik.tolerances.ACCEPT_ANGLE` (rad); near-duplicates (:data:`MERGE_TOL` in every joint)
are merged. Returned angles q1..q6 are wrapped to (-pi, pi]; q7 is the given value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from derive.algebra import dualquat as dq
from derive.algebra import quaternion as quat
from derive.algebra.angles import wrap_angle
from derive.algebra.rotations import rot_y, rot_z
from derive.cache import memo
from derive.errors import DeriveError, InputError, as_finite_array
from derive.ik import select
from derive.ik.finish import Solutions, empty, finish
from derive.ik.euler import zyz
from derive.ik.subproblems import sp2, sp3
from derive.ik.subproblems._common import double_root
from derive.ik.tolerances import (CLASS_DIRECTION, CLASS_DISTANCE, DOUBLE_ROOT,
                                  FREE_JOINT_DISTANCE, MAP_ANGLE, MAP_POSITION, REACH_TOL,
                                  W4_NOISE)
from derive.kinematics.fk import _pose_error, fk
from derive.kinematics.pose import as_pose_batch
from derive.model.geometry import numeric_chain
from derive.model.robot import load_robot, robot_from_dict

PARAMETERS = ("d1", "d3", "a3", "a4", "d5", "a6", "d7")

TWO_PI = 2.0 * math.pi

#: The most (pose, q7) pairs :func:`ik_sweep` solves in one call (as derive.ik.redundant.MAX_SWEEP).
MAX_SWEEP = 10 ** 6

#: Number of candidate branches (2 elbow x 2 wrist x 2 shoulder).
BRANCHES = 8

REASON_OK = ""
REASON_ELBOW = ("unreachable: the distance from the shoulder to the point O6 (fixed by the pose "
                "and q7) is outside the range the elbow can span")
REASON_WRIST = ("unreachable for this q7: no q6 turns the wrist so that the shoulder lies at the "
                "height Z(q4) along axis 5 that the elbow needs")
REASON_NO_CANDIDATE = "unreachable: no candidate reproduces the pose"


# reason codes per candidate
_OK, _CODE_ELBOW, _CODE_WRIST = 0, 1, 2


@dataclass(frozen=True)
class PandaGeometry:
    """The canonical lengths (m) of a Panda-class arm and FK_robot(q) = base FK_canonical(q) tool."""

    robot: str
    d1: float
    d3: float
    a3: float
    a4: float
    d5: float
    a6: float
    d7: float
    base: np.ndarray        # (8,) unit dual quaternion B
    tool: np.ndarray        # (8,) unit dual quaternion T
    q7_limits: tuple        # (lower, upper) of joint 7, +-inf without limits
    error: float            # largest mismatch of the relation on the check configurations

    @property
    def values(self) -> dict:
        return {k: getattr(self, k) for k in PARAMETERS}

    def into_canonical(self, poses: np.ndarray) -> np.ndarray:
        """Poses (n, 8) of the robot's end frame as flange poses of the canonical chain: B^-1 P T^-1."""
        return dq._mul(dq._mul(dq.conj_quaternion(self.base)[None], poses),
                       dq.conj_quaternion(self.tool)[None])


#: The former result type of :func:`ik_q7`, now the one result type of all classes.
PandaSolutions = Solutions


def canonical_description(values: dict, name: str = "panda-class") -> dict:
    """The canonical chain (module docstring) as a robot description with the given lengths (m)."""
    rows = [(0, 0, "d1"), ("-pi/2", 0, 0), ("pi/2", 0, "d3"), ("pi/2", "a3", 0),
            ("-pi/2", "a4", "d5"), ("pi/2", 0, 0), ("pi/2", "a6", 0)]
    return {
        "name": name,
        "title": "Franka Panda class, canonical chain",
        "source": "Franka's modified DH table with lengths d1, d3, a3, a4, d5, a6, d7",
        "convention": "modified_dh",
        "parameters": {k: float(values[k]) for k in PARAMETERS},
        "joints": [{"name": f"j{i + 1}", "alpha": al, "a": a, "theta": 0, "d": d}
                   for i, (al, a, d) in enumerate(rows)],
        "ends": {"flange": {"parent": "j7", "translation": [0, 0, "d7"]}},
    }


def panda_geometry(robot) -> PandaGeometry:
    """The canonical form of a Panda-class arm (module docstring), or InputError naming what
    differs; cached per robot identity and joint limits (it holds the q7 limits)."""
    robot = load_robot(robot)
    return memo("panda-geometry", (robot.id, robot.limits_id), lambda: _panda_geometry(robot))


def is_panda_class(robot) -> bool:
    try:
        panda_geometry(robot)
        return True
    except DeriveError:
        return False


#: Directions of the axes at the zero pose in the canonical base frame (x, y, z).
_AXES = np.array([[0, 0, 1], [0, 1, 0], [0, 0, 1], [0, -1, 0], [0, 0, 1], [0, -1, 0], [0, 0, -1]], float)


def _panda_geometry(robot) -> PandaGeometry:
    name = robot.name

    def fail(why):
        raise InputError(f"{name}: not of the Franka Panda class (derive.ik.panda): {why}")

    if robot.dof != 7:
        fail(f"{robot.dof} joints, the class has 7")
    try:
        chain = numeric_chain(robot)
    except DeriveError as exc:
        fail(str(exc))
    if chain.n != 7 or any(t != "revolute" for t in chain.types) or chain.variables != tuple(range(7)):
        fail("the path to the end is not 7 revolute joints driven by q1 .. q7 in order")
    h = chain.axes / np.linalg.norm(chain.axes, axis=1, keepdims=True)
    pts = chain.start + np.vstack([np.zeros(3), np.cumsum(chain.links, axis=0)])[:7]
    tol = CLASS_DISTANCE
    if abs(h[0] @ h[1]) > CLASS_DIRECTION:
        fail("axis 2 is not perpendicular to axis 1")
    # canonical base frame: z = axis 1, y = axis 2 (as the joints turn), origin on axis 1 at the
    # foot of the robot's base origin
    zc, yc = h[0], h[1]
    xc = np.cross(yc, zc)
    frame = np.column_stack([xc, yc, zc])
    origin = pts[0] - (pts[0] @ zc) * zc
    loc_h = h @ frame
    loc_p = (pts - origin) @ frame
    for i in range(2, 7):
        if np.abs(loc_h[i] - _AXES[i]).max() > CLASS_DIRECTION:
            fail(f"at the zero pose axis {i + 1} is {np.round(loc_h[i], 6).tolist()} in the frame "
                 f"of axes 1 and 2 (x = y2 x z1, y = y2, z = z1); the class has {_AXES[i].tolist()}"
                 " (Franka's zero pose, no joint offsets or reversed joints)")

    def across(i, k):
        """coordinate k of axis i (constant along the axis, which is along another coordinate)"""
        return float(loc_p[i][k])

    # axis 2 (along y) meets axis 1: x = 0; axis 3 (along z) passes through S: x = y = 0
    if abs(across(1, 0)) > tol:
        fail("axis 2 does not meet axis 1")
    d1 = across(1, 2)
    if abs(across(2, 0)) > tol or abs(across(2, 1)) > tol:
        fail("axis 3 does not pass through the point where axes 1 and 2 meet (no spherical shoulder)")
    a3, z4 = across(3, 0), across(3, 2)
    d3 = z4 - d1
    if abs(across(4, 1)) > tol:
        fail("axis 5 is not in the plane of axes 1 and 4 at the zero pose")
    x5 = across(4, 0)
    a4 = x5 - a3
    if abs(across(5, 0) - x5) > tol:
        fail("axes 5 and 6 do not meet")
    d5 = across(5, 2) - z4
    if abs(across(6, 1)) > tol:
        fail("axis 7 is not in the plane of axes 1 and 4 at the zero pose")
    a6 = across(6, 0) - x5
    # the canonical flange: on axis 7 at the height of the robot's end frame at zero
    pose0 = fk(robot, np.zeros(7))
    end0 = (dq._translation(pose0[None])[0] - origin) @ frame
    d7 = across(5, 2) - float(end0[2])
    vals = {k: round(v, 12) + 0.0 for k, v in zip(PARAMETERS, (d1, d3, a3, a4, d5, a6, d7))}
    if math.hypot(vals["a3"] * vals["a4"] + vals["d3"] * vals["d5"],
                  vals["a4"] * vals["d3"] - vals["a3"] * vals["d5"]) < 1e-9:
        fail("the elbow cannot change the shoulder-wrist distance (a3 = d3 = 0 or a4 = d5 = 0)")
    canon = robot_from_dict(canonical_description(vals, f"{name}-canonical"))
    base = dq.tidy(dq.from_rt(quat.from_matrix(frame), origin))
    tool = dq.tidy(dq._mul(dq.conj_quaternion(fk(canon, np.zeros(7)))[None],
                         dq._mul(dq.conj_quaternion(base)[None], pose0[None]))[0])
    rng = np.random.default_rng(17)
    q = rng.uniform(-math.pi, math.pi, size=(32, 7))
    via = dq._mul(dq._mul(np.broadcast_to(base, (32, 8)), fk(canon, q)), np.broadcast_to(tool, (32, 8)))
    dp, dr = _pose_error(fk(robot, q), via)
    err = float(max(dp.max(), dr.max()))
    if not (dp.max() <= MAP_POSITION and dr.max() <= MAP_ANGLE):
        fail(f"the canonical chain reproduces its FK only to {err:.3g} (m, rad)")
    lim = robot.limits[6]
    return PandaGeometry(name, **vals, base=base, tool=tool, q7_limits=(float(lim[0]), float(lim[1])),
                         error=err)


# --------------------------------------------------------------------------- #
# The named steps (module docstring), vectorised over poses
# --------------------------------------------------------------------------- #
_E = np.eye(3)                      # e_x, e_y, e_z
#: Rx(-pi/2)
_RX_M = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])


def frame6(geo: PandaGeometry, r7, p, q7):
    """Step 1 (eq. F7): rotation R6 (n, 3, 3) and origin O6 (n, 3) from the canonical flange
    pose (R7, p) and q7."""
    o7 = p - geo.d7 * r7[:, :, 2]
    r6 = r7 @ rot_z(-q7) @ _RX_M
    return r6, o7 - geo.a6 * r6[:, :, 0]


def shoulder_in_6(geo: PandaGeometry, r6, o6):
    """Step 2: v = R6^T (S - O6) (n, 3), S = (0, 0, d1)."""
    s = np.array([0.0, 0.0, geo.d1])
    return np.einsum("nji,nj->ni", r6, s - o6)


def elbow(geo: PandaGeometry, v):
    """Step 3 (eq. E2) as subproblem 3: |v|^2 = X^2 + Z^2 with (-X, Z) = Rz(q4) p1 - p2,
    p1 = (a3, -d3, 0), p2 = (-a4, d5, 0) (eq. E1), so ||Rz(q4) p1 - p2|| = |v|: the two roots
    q4 (n, 2) (atan2(B, A) + acos(c) first) and the unreachable flag (n,). The cosine
    c = K / hypot(A, B) = (|v|^2 - |p1|^2 - |p2|^2) / (2 |p1| |p2|) decides the reach (beyond
    1 + REACH_TOL) and the double root (within DOUBLE_ROOT of +-1: both roots its middle)."""
    p1, p2 = np.array([geo.a3, -geo.d3, 0.0]), np.array([-geo.a4, geo.d5, 0.0])
    c = 0.5 * (np.einsum("ni,ni->n", v, v) - p1 @ p1 - p2 @ p2) / (np.linalg.norm(p1) * np.linalg.norm(p2))
    roots = double_root(sp3(_E[2], p1, p2, np.linalg.norm(v, axis=-1)).theta[..., 0],
                        np.abs(c) > 1.0 - DOUBLE_ROOT)
    return roots[:, ::-1], np.abs(c) > 1.0 + REACH_TOL


def xz(geo: PandaGeometry, q4):
    """X(q4), Z(q4) of eq. E1: the shoulder in frame 5 is (X c5, -X s5, Z)."""
    c4, s4 = np.cos(q4), np.sin(q4)
    return -(geo.a3 * c4 + geo.d3 * s4 + geo.a4), geo.a3 * s4 - geo.d3 * c4 - geo.d5


def wrist(v, x, z, q5_free, q6_free):
    """Steps 4 and 5 (eq. W1-W3) as subproblem 2: the shoulder in frame 5 from the arm side,
    Rz(-q5) (X, 0, Z) (eq. E1), equals the shoulder in frame 6 turned into frame 5,
    Rx(pi/2) Rz(q6) v = R(-e_y, q6) (vx, -vz, vy) (eq. W1). sp2 takes q5 from the height along
    axis 6, X s5 = vz, then q6 by subproblem 1; its two roots (q5, q6) (n, 2) each, X c5 <= 0
    first (q6 = atan2(vx, vy) + a of eq. W2). The root X c5 = +-sqrt(X^2 - vz^2) (eq. W4) keeps
    its relative accuracy where |X| is small (the shoulder near axis 5, q4 near 0 on the Panda;
    the height along axis 5, vx s6 + vy c6 = Z of eq. W2, would lose it: hypot(vx, vy) and |Z|
    nearly equal). The class's rules: the roots merge (both at their middle) where
    X^2 - vz^2 = (X c5)^2 < DOUBLE_ROOT X^2 + W4_NOISE |X| (q5 = +-pi/2, the second term the
    rounding of vz; the pose changes only to second order there); q5 is free (``q5_free``)
    where |X| < FREE_JOINT_DISTANCE (S on axis 5), q6 (``q6_free``) where
    hypot(vx, vy) < FREE_JOINT_DISTANCE (S on axis 6); unreachable where |Z| > hypot(vx, vy)
    (1 + REACH_TOL). Returns q5, q6, unreachable (n,), free5 (n,), free6 (n,)."""
    rho = np.hypot(v[:, 0], v[:, 1])
    free6, free5 = rho < FREE_JOINT_DISTANCE, np.abs(x) < FREE_JOINT_DISTANCE
    bad = np.where(free6, np.abs(z) > FREE_JOINT_DISTANCE,
                   np.abs(np.where(free6, 0.0, z / np.where(free6, 1.0, rho))) > 1.0 + REACH_TOL)
    double = x * x - v[:, 2] * v[:, 2] <= DOUBLE_ROOT * x * x + W4_NOISE * np.abs(x)
    sol = sp2(-_E[2], -_E[1], np.stack([x, 0.0 * x, z], -1), v[:, [0, 2, 1]] * [1.0, -1.0, 1.0])
    q5, q6 = (double_root(sol.theta[..., j], double) for j in (0, 1))
    return (np.where(free5[:, None], q5_free[:, None], q5),
            np.where(free6[:, None], q6_free[:, None], q6), bad, free5, free6)


def frame3(r6, q4, q5, q6):
    """Step 5, eq. S1: R3 = R6 Rz(-q6) Rx(-pi/2) Rz(-q5) Rx(pi/2) Rz(-q4) Rx(-pi/2)
    = R6 Rz(-q6) Ry(-q5) Rz(-q4) Rx(-pi/2) (Rx(-pi/2) Rz(t) Rx(pi/2) = Ry(t))."""
    return r6 @ (rot_z(-q6) @ rot_y(-q5) @ rot_z(-q4)) @ _RX_M


def shoulder(m, sign2, q1_free):
    """Step 5, eq. S2: R3 = Rz(q1) Ry(q2) Rz(q3), the ZYZ decomposition with sin q2 of sign
    ``sign2`` (:func:`derive.ik.euler.zyz`); where |sin q2| < WRIST_SINGULAR q1 is ``q1_free`` and
    q3 takes the rest. Returns q1, q2, q3, singular."""
    return zyz(m, sign2, q1_free)


def candidates(geo: PandaGeometry, poses: np.ndarray, q7: np.ndarray, q_free: np.ndarray):
    """All 8 branches for n poses of the robot's end frame: (q (n, 8, 7), singular (n, 8),
    codes (n, 8): 0 ok, 1 elbow unreachable, 2 wrist unreachable). Not yet checked by FK;
    unreachable branches are NaN. ``q_free`` (n, 7): values of the free joints at singular sets."""
    c = geo.into_canonical(poses)
    return canonical_candidates(geo, quat._to_matrix(c[:, :4]), dq._translation(c), q7, q_free)


def canonical_candidates(geo: PandaGeometry, r7: np.ndarray, p: np.ndarray, q7: np.ndarray,
                         q_free: np.ndarray):
    """:func:`candidates` from the canonical flange poses: rotations r7 (n, 3, 3), positions p
    (n, 3) (for callers that evaluate one pose at many q7)."""
    n = r7.shape[0]
    r6, o6 = frame6(geo, r7, p, q7)
    v = shoulder_in_6(geo, r6, o6)
    q4s, bad4 = elbow(geo, v)
    out = np.full((n, BRANCHES, 7), np.nan)
    singular = np.zeros((n, BRANCHES), dtype=bool)
    code = np.zeros((n, BRANCHES), dtype=np.int8)
    for i4 in range(2):
        q4 = q4s[:, i4]
        x, z = xz(geo, q4)
        q5s, q6s, bad6, free5, free6 = wrist(v, x, z, q_free[:, 4], q_free[:, 5])
        for i6 in range(2):
            q5, q6 = q5s[:, i6], q6s[:, i6]
            m = frame3(r6, q4, q5, q6)
            for i2, sign2 in enumerate((1.0, -1.0)):
                q1, q2, q3, free1 = shoulder(m, sign2, q_free[:, 0])
                b = 4 * i4 + 2 * i6 + i2
                out[:, b] = np.stack([q1, q2, q3, q4, q5, q6, q7], -1)
                singular[:, b] = free1 | free5 | free6
                code[:, b] = np.where(bad4, _CODE_ELBOW, np.where(bad6, _CODE_WRIST, _OK))
    out[..., :6] = wrap_angle(out[..., :6])
    out[code > 0] = np.nan
    return out, singular, code


def canonical_fk(geo: PandaGeometry, q: np.ndarray):
    """Flange rotation (n, 3, 3) and position (n, 3) of the canonical chain (module docstring's
    table: T_i = Rx(alpha_(i-1)) Tx(a_(i-1)) Rz(q_i) Tz(d_i), then Tz(d7)) for q (n, 7): a cheap
    check of candidates against :meth:`PandaGeometry.into_canonical` poses."""
    rows = ((0.0, 0.0, geo.d1), (-1.0, 0.0, 0.0), (1.0, 0.0, geo.d3), (1.0, geo.a3, 0.0),
            (-1.0, geo.a4, geo.d5), (1.0, 0.0, 0.0), (1.0, geo.a6, 0.0))
    n = q.shape[0]
    r = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    p = np.zeros((n, 3))
    for i, (sx, a, d) in enumerate(rows):
        # Rx(sx pi/2) (sx = +-1) or identity, then Tx(a), Rz(q_i), Tz(d)
        p = p + a * r[:, :, 0]
        if sx:
            r = np.stack([r[:, :, 0], sx * r[:, :, 2], -sx * r[:, :, 1]], -1)
        r = r @ rot_z(q[:, i])
        p = p + d * r[:, :, 2]
    return r, p + geo.d7 * r[:, :, 2]


# --------------------------------------------------------------------------- #
# Public API
# --------------------------------------------------------------------------- #
def q7_interval(robot) -> tuple[float, float]:
    """(lower, upper) limits of joint 7 (rad), the range of the free parameter."""
    return panda_geometry(load_robot(robot)).q7_limits


def _check_q7(q7, n: int) -> np.ndarray:
    arr = as_finite_array(q7, "q7", ndim_min=0)
    if arr.ndim == 0:
        return np.full(n, float(arr))
    if arr.ndim != 1 or arr.shape[0] != n:
        raise InputError(f"q7: expected a number or an array of shape ({n},) (one per pose), got "
                         f"shape {arr.shape}")
    return arr.copy()


def ik_q7(robot, poses, q7, *, q_ref=None, check: bool = True, chunk: int = 20000) -> PandaSolutions:
    """Every closed-form IK solution of a Panda-class arm with joint 7 at ``q7`` (module docstring).

    ``poses``: unit dual quaternions (8,) / (n, 8) or matrices (4, 4) / (n, 4, 4) of the robot's
    end frame; ``q7``: a number or (n,) array (rad), kept as given in the solutions; ``q_ref``
    (7,) or (n, 7): its q1, q5, q6 are used where that joint is free (singular sets; default 0).
    Up to 8 solutions per pose, not filtered by joint limits (:func:`within_limits`), q1..q6
    wrapped to (-pi, pi]. ``check``: keep only candidates whose reference FK reproduces the
    pose within ACCEPT_POSITION / ACCEPT_ANGLE (most of the run time; without it every branch that the steps
    reach is returned, for callers that check themselves). The candidates go through the finish
    step of all classes (:func:`derive.ik.finish.finish`). Returns
    :class:`derive.ik.finish.Solutions` (q (n, 8, 7), counts, branch, singular, residual,
    reason, free = q7; the former names ``branches`` and ``reasons`` still read); one pose (8,)
    gives n = 1.
    """
    robot = load_robot(robot)
    geo = panda_geometry(robot)
    poses, _ = as_pose_batch(poses)
    n = poses.shape[0]
    q7 = _check_q7(q7, n)
    q_free = np.zeros((n, 7))
    if q_ref is not None:
        qr = as_finite_array(q_ref, "q_ref", last_dim=7)
        if qr.ndim > 2 or (qr.ndim == 2 and qr.shape[0] not in (1, n)):
            raise InputError(f"q_ref: expected shape (7,) or ({n}, 7), got {qr.shape}")
        q_free = np.broadcast_to(qr.reshape(-1, 7), (n, 7)).astype(float)
    out = empty(n, BRANCHES, 7)
    for s in range(0, n, chunk):
        e = min(n, s + chunk)
        cand, sing, code = candidates(geo, poses[s:e], q7[s:e], q_free[s:e])
        (out.q[s:e], out.counts[s:e], out.branch[s:e], out.singular[s:e],
         out.residual[s:e]) = finish(robot, poses[s:e], cand, sing, check_fk=check)
        for k in np.nonzero(out.counts[s:e] == 0)[0]:
            codes = code[k]
            out.reason[s + k] = (REASON_ELBOW if np.all(codes == _CODE_ELBOW) else
                                 REASON_WRIST if np.all(codes > 0) else REASON_NO_CANDIDATE)
    out.free = q7
    return out


def within_limits(robot, sols: PandaSolutions):
    """The solutions inside the robot's joint limits, every 2 pi winding included
    (:func:`derive.ik.select.within_limits`): (q (n, M, 7), counts (n,), branches (n, M),
    singular (n, M))."""
    robot = load_robot(robot)
    return select.within_limits(sols.q, sols.counts, robot.limits, [True] * 7,
                                branch=sols.branch, singular=sols.singular)


def ik_sweep(robot, poses, n: int, *, q_ref=None):
    """:func:`ik_q7` at ``n`` values of q7 evenly spaced over joint 7's limits (both ends
    included; [-pi, pi) without limits). Returns (q7 values (n,), :class:`derive.ik.finish.Solutions`
    with q (P, n, 8, 7), counts (P, n), branch (P, n, 8), singular (P, n, 8), residual (P, n, 8),
    reason (P, n), free (P, n))."""
    robot = load_robot(robot)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise InputError(f"n: a positive number of q7 values, got {n!r}")
    lo, hi = q7_interval(robot)
    if not (math.isfinite(lo) and math.isfinite(hi)):
        lo, hi = -math.pi, math.pi
        values = lo + (hi - lo) * np.arange(n) / n
    else:
        values = np.linspace(lo, hi, n) if n > 1 else np.array([0.5 * (lo + hi)])
    poses, _ = as_pose_batch(poses)
    p = poses.shape[0]
    if p * n > MAX_SWEEP:
        raise InputError(f"sweep: {p} pose(s) x {n} values = {p * n} is more than the limit of "
                         f"{MAX_SWEEP} (pose, value) pairs per call; use fewer values or poses")
    if q_ref is not None:
        qr = as_finite_array(q_ref, "q_ref", last_dim=7)
        q_ref = np.repeat(np.broadcast_to(qr.reshape(-1, 7), (p, 7)), n, axis=0)
    res = ik_q7(robot, np.repeat(poses, n, axis=0), np.tile(values, p), q_ref=q_ref)
    return values, res.reshape(p, n)
