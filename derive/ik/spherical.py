"""Closed-form inverse kinematics of 6R arms with an ortho-parallel base and a spherical wrist.

The class (Brandstoetter, Angerer, Hofbaur, "An analytical solution of the inverse kinematics
problem of industrial serial manipulators with an ortho-parallel basis and a spherical wrist",
2014; "OPW" below): axis 1 perpendicular to axis 2, axes 2 and 3 parallel, axes 4, 5, 6 meeting
in one point (the wrist centre) with axis 4 perpendicular to axes 3 and 5 and axis 5
perpendicular to axis 6. ABB, KUKA, FANUC, Staubli, Yaskawa and Kawasaki arms and the PUMA 560
are of this class.

Every such arm is one **canonical chain** with seven numbers, written as a robot description in
thesis axis-angle form (:func:`canonical_description`; the OPW paper's parameters):

=====  ==========  ===========================================================
joint  axis (q=0)  link to the next axis point
=====  ==========  ===========================================================
1      z           (a1, b, c1): shoulder offset a1, lateral offset b, height c1
2      y           (0, 0, c2): upper arm, pointing up at zero
3      y           (a2, 0, c3): elbow offset a2 and forearm c3 to the wrist centre
4      z           0
5      y           0
6      z           0; the end frame (flange) is the tool (0, 0, c4) from the wrist centre
=====  ==========  ===========================================================

so that the wrist centre is at (a1 + a2, b, c1 + c2 + c3) at zero and the orientation is
R = Rz(t1) Ry(t2 + t3) Rz(t4) Ry(t5) Rz(t6). A robot of the class is related to its canonical
chain by constant transforms, joint directions and joint offsets:

    FK_robot(q) = B  FK_canonical(s * q + o)  T          (s_i = +-1)

which :func:`sw_geometry` finds from the robot's axes at the zero pose (no symbolic work) and
checks on random configurations. The equations M_i = N_i of the canonical chain are derived
once for the class (:mod:`derive.symbolic.equations`, sets P and O), the IK program is built
from them (:func:`derive.ik.program.ik_program`), and each robot's numbers are substituted at
emission.

This module also holds the numeric reference of the class, after the OPW paper's section 3
written as a composition of the subproblems of :mod:`derive.ik.subproblems` (sp4, sp3, sp1,
sp2, sp1; independent of the derived program, which works on the dual-quaternion equations):
:func:`solve_batch`.
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
from derive.errors import DeriveError
from derive.ik.subproblems import rot
from derive.ik.subproblems.sp1 import _sp1
from derive.ik.subproblems.sp2 import _sp2
from derive.ik.subproblems.sp3 import _sp3
from derive.ik.subproblems.sp4 import _sp4
from derive.ik.tolerances import (CLASS_DIRECTION, CLASS_DISTANCE, MAP_ANGLE, MAP_POSITION,
                                  OFFSET_SNAP, REACH_TOL, WRIST_SINGULAR)
from derive.kinematics.fk import _pose_error, fk
from derive.model.geometry import numeric_chain
from derive.model.robot import load_robot, robot_from_dict

#: Parameter names of the canonical chain, in the OPW paper's order.
PARAMETERS = ("a1", "a2", "b", "c1", "c2", "c3", "c4")

REASON_LATERAL = ("unreachable: the wrist centre is closer to axis 1 than the lateral offset b "
                  "allows")
REASON_REACH = ("unreachable: the distance from axis 2 to the wrist centre is outside the range "
                "the upper arm c2 and the forearm sqrt(a2^2 + c3^2) can span")


@dataclass(frozen=True)
class SWGeometry:
    """The canonical parameters of a spherical-wrist arm and its relation to them:
    FK_robot(q) = base * FK_canonical(signs * q + offsets) * tool."""

    robot: str
    a1: float
    a2: float
    b: float
    c1: float
    c2: float
    c3: float
    c4: float
    base: np.ndarray        # (8,) unit dual quaternion B
    tool: np.ndarray        # (8,) unit dual quaternion T
    signs: np.ndarray       # (6,) of +-1
    offsets: np.ndarray     # (6,) rad
    error: float            # largest mismatch of the relation on the check configurations

    @property
    def values(self) -> dict:
        return {k: getattr(self, k) for k in PARAMETERS}

    def to_canonical(self, q) -> np.ndarray:
        """Joint values of the robot -> angles of the canonical chain (s q + o)."""
        return np.asarray(q, dtype=float) * self.signs + self.offsets

    def from_canonical(self, theta) -> np.ndarray:
        """Angles of the canonical chain -> joint values of the robot, wrapped to (-pi, pi]."""
        return wrap_angle((np.asarray(theta, dtype=float) - self.offsets) * self.signs)

    def into_canonical(self, poses: np.ndarray) -> np.ndarray:
        """Poses (n, 8) of the robot's end frame as poses of the canonical chain: B^-1 P T^-1."""
        return dq._mul(dq._mul(dq.conj_quaternion(self.base)[None], poses),
                       dq.conj_quaternion(self.tool)[None])


def describe(geo: SWGeometry) -> str:
    """One line: the parameters (m) and the relation's joint signs and offsets (deg)."""
    par = ", ".join(f"{k} = {v:.12g}" for k, v in geo.values.items())
    flips = [str(i + 1) for i, s in enumerate(geo.signs) if s < 0]
    offs = [f"o{i + 1} = {math.degrees(o):.12g} deg" for i, o in enumerate(geo.offsets) if o != 0]
    return (f"{par} m; canonical angles = s q + o with "
            f"{'joints ' + ', '.join(flips) + ' reversed' if flips else 'no joint reversed'}"
            f"{', ' + ', '.join(offs) if offs else ', no offsets'}")


def canonical_description(values: dict, name: str = "spherical-wrist") -> dict:
    """The canonical chain (module docstring) as a robot description, lengths named a1 ... c4
    with the given values (metres)."""
    return {
        "name": name,
        "title": "Spherical-wrist arm with an ortho-parallel base, canonical chain",
        "source": "Brandstoetter, Angerer, Hofbaur 2014, parameters a1, a2, b, c1, c2, c3, c4",
        "convention": "axis_angle",
        "parameters": {k: float(values[k]) for k in PARAMETERS},
        "joints": [
            {"name": "j1", "axis": [0, 0, 1], "link": ["a1", "b", "c1"]},
            {"name": "j2", "axis": [0, 1, 0], "link": [0, 0, "c2"]},
            {"name": "j3", "axis": [0, 1, 0], "link": ["a2", 0, "c3"]},
            {"name": "j4", "axis": [0, 0, 1], "link": [0, 0, 0]},
            {"name": "j5", "axis": [0, 1, 0], "link": [0, 0, 0]},
            {"name": "j6", "axis": [0, 0, 1], "link": [0, 0, 0]},
        ],
        "tool": {"translation": [0, 0, "c4"]},
    }


def canonical_robot(geo: SWGeometry):
    """The canonical chain with the numbers of ``geo`` (a Robot)."""
    return robot_from_dict(canonical_description(geo.values, f"{geo.robot}-canonical"))


def sw_geometry(robot) -> SWGeometry:
    """The canonical form of a spherical-wrist arm (module docstring), or DeriveError naming the
    property the robot lacks; cached per robot identity."""
    robot = load_robot(robot)
    return memo("sw-geometry", robot.id, lambda: _sw_geometry(robot))


def is_spherical(robot) -> bool:
    try:
        sw_geometry(robot)
        return True
    except DeriveError:
        return False


def _unit(v):
    return v / np.linalg.norm(v)


def _line_distance(p1, h1, p2, h2) -> float:
    n = np.cross(h1, h2)
    if np.linalg.norm(n) < 1e-12:
        return float(np.linalg.norm(np.cross(p2 - p1, h1)))
    return float(abs(np.dot(p2 - p1, _unit(n))))


def _ry(t):
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rz(t):
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _snap(x: float, step: float, tol: float = OFFSET_SNAP) -> float:
    k = round(x / step)
    return k * step if abs(x - k * step) <= tol else x


def _sw_geometry(robot) -> SWGeometry:
    name = robot.name

    def fail(why):
        raise DeriveError(f"{name}: not a spherical-wrist arm with an ortho-parallel base (OPW "
                          f"class): {why}")

    if robot.dof != 6:
        fail(f"{robot.dof} joints, the class has 6")
    chain = numeric_chain(robot)
    if chain.n != 6 or any(t != "revolute" for t in chain.types):
        fail("the path to the end has a prismatic joint or not 6 joints")
    h = np.array([_unit(a) for a in chain.axes])
    pts = chain.start + np.vstack([np.zeros(3), np.cumsum(chain.links, axis=0)])[:6]
    tol = CLASS_DISTANCE
    if abs(h[0] @ h[1]) > CLASS_DIRECTION:
        fail("axis 1 is not perpendicular to axis 2")
    if np.linalg.norm(np.cross(h[1], h[2])) > CLASS_DIRECTION:
        fail("axes 2 and 3 are not parallel")
    for i, j in ((2, 3), (3, 4), (4, 5)):
        if abs(h[i] @ h[j]) > CLASS_DIRECTION:
            fail(f"axis {j + 1} is not perpendicular to axis {i + 1}")
    # wrist centre: the point of axis 5 nearest to axis 4 (they must meet), on axis 6 too
    if _line_distance(pts[3], h[3], pts[4], h[4]) > tol or _line_distance(pts[4], h[4], pts[5], h[5]) > tol \
            or _line_distance(pts[3], h[3], pts[5], h[5]) > tol:
        fail("axes 4, 5 and 6 do not meet in one point")
    # intersection of lines 4 and 5 (perpendicular): point on 4 nearest to 5
    d45 = pts[4] - pts[3]
    w = pts[3] + h[3] * (d45 @ h[3] - (d45 @ h[4]) * (h[3] @ h[4])) / (1.0 - (h[3] @ h[4]) ** 2)

    # canonical base frame: z along axis 1, origin at the foot of the base origin on axis 1
    s1 = 1.0 if h[0][2] >= 0 else -1.0
    zc = s1 * h[0]
    oc = pts[0] + (-pts[0] @ h[0]) * h[0]
    d = pts[1] - oc
    foot2 = pts[1] - (d @ h[1]) * h[1]                   # point of axis 2 nearest to axis 1
    c1 = float(d @ zc)
    radial = foot2 - (oc + c1 * zc)
    s2 = 1.0
    if np.cross(h[1], zc) @ radial < 0:
        s2 = -1.0
    yc = s2 * h[1]
    xc = np.cross(yc, zc)
    a1 = float(radial @ xc)
    frame = np.column_stack([xc, yc, zc])                 # canonical axes in robot base coordinates

    def local(v):
        return frame.T @ v

    wl, p3l = local(w - oc), local(pts[2] - oc)
    b = float(wl[1])
    s3 = s2 * (1.0 if h[2] @ h[1] > 0 else -1.0)
    # joint 2 offset: the upper arm (axis 2 -> axis 3, in the x-z plane) points up at theta2 = 0
    v23 = np.array([p3l[0] - a1, p3l[2] - c1])
    c2 = float(np.hypot(*v23))
    if c2 < 1e-9:
        fail("axes 2 and 3 coincide (no upper arm)")
    o2 = math.atan2(v23[0], v23[1])
    # theta2 + theta3 offset: axis 4 along +-z at theta2 = theta3 = 0, forearm c3 >= 0
    h4l = local(h[3])
    v3w = np.array([wl[0] - p3l[0], 0.0, wl[2] - p3l[2]])
    best = None
    for s4 in (1.0, -1.0):
        alpha = math.atan2(s4 * h4l[0], s4 * h4l[2])
        fore = _ry(-alpha) @ v3w
        if best is None or fore[2] > best[2][2] + 1e-12:
            best = (s4, alpha, fore)
    s4, alpha, fore = best
    a2, c3 = float(fore[0]), float(fore[2])
    o3 = alpha - o2
    # joint 4 offset: axis 5 along +y; joint 5 offset: axis 6 along +z
    v5 = _ry(-alpha) @ local(h[4])
    o4 = math.atan2(-v5[0], v5[1])
    u6 = _rz(-o4) @ _ry(-alpha) @ local(h[5])
    o5 = math.atan2(u6[0], u6[2])
    # the end frame's origin at zero (tool included) along axis 6; what is off the axis stays in T
    c4 = float((dq._translation(fk(robot, np.zeros(6))[None])[0] - w) @ h[5])
    s6 = 1.0
    if c4 < -1e-12:          # the flange lies along -axis 6: reverse joint 6, turn joint 5 by pi
        s6, o5, c4 = -1.0, o5 + math.pi, -c4

    signs = np.array([s1, s2, s3, s4, 1.0, s6])
    offsets = np.array([0.0, o2, o3, o4, o5, 0.0])
    offsets = np.array([_snap(float(wrap_angle(x)), math.pi / 12) for x in offsets]) + 0.0
    vals = {k: round(v, 12) + 0.0 for k, v in zip(PARAMETERS, (a1, a2, b, c1, c2, c3, c4))}
    base = dq.from_rt(quat.from_matrix(frame), oc)
    canon = robot_from_dict(canonical_description(vals, f"{name}-canonical"))
    # T = FK_c(o)^-1 B^-1 FK_robot(0)
    pose0 = fk(robot, np.zeros(6))
    c0 = fk(canon, offsets)
    tool = dq._mul(dq.conj_quaternion(c0)[None],
                   dq._mul(dq.conj_quaternion(base)[None], pose0[None]))[0]
    tool = dq.tidy(tool)
    base = dq.tidy(base)
    geo = SWGeometry(name, **vals, base=base, tool=tool, signs=signs, offsets=offsets, error=0.0)
    rng = np.random.default_rng(11)
    q = rng.uniform(-math.pi, math.pi, size=(24, 6))
    ref = fk(robot, q)
    via = dq._mul(dq._mul(np.broadcast_to(base, (24, 8)), fk(canon, geo.to_canonical(q))),
                  np.broadcast_to(tool, (24, 8)))
    dp, dr = _pose_error(ref, via)
    err = float(max(dp.max(), dr.max()))
    if not (dp.max() <= MAP_POSITION and dr.max() <= MAP_ANGLE):
        fail(f"the canonical chain reproduces its FK only to {err:.3g} (m, rad)")
    return SWGeometry(name, **vals, base=base, tool=tool, signs=signs, offsets=offsets, error=err)


# --------------------------------------------------------------------------- #
# Numeric reference solver: a composition of subproblems (derive.ik.subproblems)
# --------------------------------------------------------------------------- #
_X, _Y, _Z = np.eye(3)


def solve_batch(geo: SWGeometry, poses: np.ndarray, q4_ref: np.ndarray | None = None,
                keep_unreachable: bool = False):
    """All 8 candidate branches for n poses of the robot's end frame: (q (n, 8, 6) in the
    robot's joint values, singular (n, 8), reason codes (n, 8): 0 ok, 1 theta1 unreachable
    (lateral offset), 2 theta3 unreachable (arm reach)). Not yet checked by FK.

    In the canonical chain (pose B^-1 P T^-1, rotation R, flange position p), after the OPW
    paper's section 3, each step a subproblem of :mod:`derive.ik.subproblems`:

    1. wrist centre W = p - c4 R e_z; t1, sp4: e_y^T R(-z, t1) W = b (W in the arm plane, at
       the lateral offset b), two roots, t1 = atan2(Wy, Wx) - atan2(b, +-sqrt(Wx^2 + Wy^2 - b^2));
       W on axis 1 (b = 0; sp4 degenerate): t1 is free, 0 and pi are taken;
    2. t3, sp3: ||R(y, t3) (a2, 0, c3) + c2 e_z|| = ||v||, v = R(-z, t1) W - (a1, b, c1) the
       wrist centre from axis 2 in the arm plane (the cosine law of the paper,
       cos(t3 + psi3) = (|v|^2 - c2^2 - k^2) / (2 c2 k), k^2 = a2^2 + c3^2), two roots;
    3. t2, sp1: R(y, t2) (c2 e_z + R(y, t3) (a2, 0, c3)) = v;
    4. the wrist, M = (Rz(t1) Ry(t2 + t3))^T R = Rz(t4) Ry(t5) Rz(t6) (IK-Geo's spherical
       wrist): (t4, t5) by sp2, R(-z, t4) M e_z = R(y, t5) e_z, two solutions (the sign of
       sin t5); t6 by sp1, R(z, t6) e_x = Ry(t5)^T Rz(t4)^T M e_x. Where |sin t5| =
       hypot(M13, M23) < WRIST_SINGULAR only t4 + t6 (t5 = 0) or t4 - t6 (t5 = pi) is
       determined: t4 is taken from ``q4_ref`` (robot joint values) or as the robot's q4 = 0,
       and t6 from the rest of the rotation; such solutions are marked singular.

    Branch k = 4 i1 + 2 i3 + i5 (bit 1 the second root). Unreachable branches are NaN unless
    ``keep_unreachable`` (then the subproblems' least-squares roots: the nearest the arm comes).
    """
    n = poses.shape[0]
    chain = geo.into_canonical(poses)
    r = quat._to_matrix(chain[:, :4])
    w = dq._translation(chain) - geo.c4 * r[:, :, 2]
    out = np.full((n, 8, 6), np.nan)
    singular = np.zeros((n, 8), dtype=bool)
    code = np.zeros((n, 8), dtype=np.int8)
    # constant vectors stay (3,): the subproblems' private steps (no input checks, no residuals)
    # broadcast them, and a constant axis enters their products as three numbers
    x, y, z = _X, _Y, _Z
    fore, upper = np.array([geo.a2, 0.0, geo.c3]), geo.c2 * z
    k2 = geo.a2 ** 2 + geo.c3 ** 2
    bad1 = w[:, 0] ** 2 + w[:, 1] ** 2 - geo.b ** 2 < -REACH_TOL * max(1.0, geo.b ** 2)
    if q4_ref is None:
        t4_free = np.full(n, geo.offsets[3])
    else:
        t4_free = np.broadcast_to(geo.signs[3] * np.asarray(q4_ref, dtype=float) + geo.offsets[3], (n,))
    s1, s1_free = _sp4(y, -z, w, np.full(n, geo.b))
    for i1 in range(2):
        # W on axis 1 (b = 0, sp4 degenerate): t1 is free; 0 and pi, the arm and its mirror
        t1 = np.where(s1_free, i1 * np.pi, s1[:, i1])
        v = rot(-z, t1, w) - [geo.a1, geo.b, geo.c1]
        vv = v[:, 0] ** 2 + v[:, 2] ** 2
        bad3 = np.abs((vv - geo.c2 ** 2 - k2) / (2.0 * geo.c2 * math.sqrt(k2))) > 1.0 + REACH_TOL
        s3 = _sp3(y, fore, -upper, np.sqrt(vv))
        for i3 in range(2):
            t3 = s3[:, 1 - i3]                        # slot 1 has sin(t3 + psi3) >= 0
            t2 = _sp1(y, upper + rot(y, t3, fore), v)
            m = np.swapaxes(rot_z(t1) @ rot_y(t2 + t3), -1, -2) @ r
            s45 = _sp2(-z, y, m[:, :, 2], z)
            sing = np.hypot(m[:, 0, 2], m[:, 1, 2]) < WRIST_SINGULAR
            for i5 in range(2):
                t4, t5 = s45[:, i5].T
                t4 = np.where(sing, t4_free, t4)
                t5 = np.where(sing, np.where(m[:, 2, 2] >= 0, 0.0, np.pi), t5)
                t6 = _sp1(z, x, rot(y, -t5, rot(z, -t4, m[:, :, 0])))
                kk = 4 * i1 + 2 * i3 + i5
                out[:, kk] = geo.from_canonical(np.stack([t1, t2, t3, t4, t5, t6], -1))
                singular[:, kk] = sing
                code[:, kk] = np.where(bad1, 1, np.where(bad3, 2, 0))
    if not keep_unreachable:
        out[code > 0] = np.nan
    return out, singular, code
