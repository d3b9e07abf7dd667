"""IK programs of the two 7-joint classes, the free parameter an input: the KUKA iiwa class (SRS,
arm angle psi, :mod:`derive.ik.srs`) and the Franka Panda class (q7, :mod:`derive.ik.panda`).

The programs are written in the language of :mod:`derive.ik.ir`, so the emitters print them as
pure Python, numpy and C exactly as the 6R programs, with one more input: ``fv``, the free
parameter's value (one per pose in the batch functions). Each program is the closed form of its
numpy module step by step (the docstrings there cite Shimizu et al. 2008 and He & Liu 2021), with
the robot's numbers substituted, written so that it is total and needs few transcendentals:

* **no trigonometry of known angles**: where a joint angle is the atan2 of two numbers (a ZYZ
  decomposition, the elbow root), its cosine and sine are those numbers divided by their norm,
  not dq_sincos of the angle;
* **ZYZ without division by zero**: Rz(a) Ry(b) Rz(c) = m gives |sin b| = hypot(m02, m12); below
  :data:`~derive.ik.tolerances.WRIST_SINGULAR` the first angle is free and set to 0 (flag
  ``singular_*``; the batch kernels redo such poses with the whole program), and the last angle
  is computed from the rounded first two, c = atan2(row_y . m e_x, row_x . m e_x) of
  Ry(b)^T Rz(a)^T m (:func:`derive.ik.euler.zyz`), so the product stays exact;
* **double roots snapped**: an acos argument within STRETCH_TOL (SRS elbow) or DOUBLE_ROOT
  (Panda elbow) of +-1 is +-1, so the two roots coincide exactly and merge; the Panda's q6 roots
  merge where (X c5)^2 < DOUBLE_ROOT X^2 + W4_NOISE |X| (eq. W4 of :func:`derive.ik.panda.wrist`);
* reach: an acos argument beyond +-1 by more than :data:`~derive.ik.tolerances.REACH_TOL` drops
  the branch (the pose is out of reach for this value of the free parameter).

Branch numbering equals the numpy modules': SRS k = 4 GC2 + 2 GC4 + GC6 (shoulder, elbow,
wrist), Panda b = 4 i4 + 2 i6 + i2 (elbow, wrist q6, shoulder), bit 1 for the - root.
"""

from __future__ import annotations

import sympy as sp

from derive.algebra import dualquat as dq
from derive.algebra.quaternion import dual_hamilton, hamilton
from derive.ik import panda, srs
from derive.ik.euler import zyz_plus, zyz_signed
from derive.ik.extract import _rot
from derive.errors import DeriveError
from derive.ik.ir import Builder, IKProgram, Op, pos, sgn
from derive.ik.tolerances import (AXIS_TOL, CLASS_DISTANCE, DOUBLE_ROOT, FREE_JOINT_DISTANCE,
                                  PROGRAM_SNAP, REACH_TOL, STRETCH_TOL, W4_NOISE, WRIST_SINGULAR)

#: The free parameter's input symbol in every program (a C / Python identifier).
FV = sp.Symbol("fv", real=True)


def _number(x: float):
    x = float(x)
    r = round(x)
    return sp.Integer(r) if abs(x - r) < PROGRAM_SNAP else sp.Float(x, 17)


def _inputs(bld: Builder) -> tuple:
    p = sp.symbols("p0:8", real=True)
    bld.known.update(p)
    bld.known.add(FV)
    return p


def _rotation_and_translation(bld: Builder, q, stem: str):
    """Lets for the rotation matrix (3x3 list) and translation (3 list) of the unit dual
    quaternion q (8 symbols): t = 2 vec(dual real^*)."""
    r = _rot(q[:4])
    rows = [[bld.let(f"{stem}r{i}{j}", sp.expand(r[i, j])) for j in range(3)] for i in range(3)]
    t = [2 * e for e in hamilton(q[4:], (q[0], -q[1], -q[2], -q[3]))[1:]]
    return rows, [bld.let(f"{stem}t{i}", sp.expand(t[i])) for i in range(3)]


def _let_matrix(bld: Builder, name: str, m) -> list:
    return [[bld.let(f"{name}{i}{j}", sp.expand(m[i][j])) for j in range(3)] for i in range(3)]


def _snap_select(bld: Builder, name: str, c, tol: float):
    """c within tol of +-1 taken as +-1 (a double root of the acos)."""
    inner = bld.select(f"{name}_lo", c <= -1 + tol, -1, c)
    return bld.select(name, c >= 1 - tol, 1, inner)


def _rz_rows(m, c, s):
    """Rz(-t) m (t with cos c, sin s): rows 0 and 1 turned."""
    return [[c * m[0][k] + s * m[1][k] for k in range(3)], [-s * m[0][k] + c * m[1][k] for k in range(3)], m[2]]


def _ry_rows(m, c, s):
    """Ry(-t) m: rows 0 and 2 turned."""
    return [[c * m[0][k] - s * m[2][k] for k in range(3)], m[1], [s * m[0][k] + c * m[2][k] for k in range(3)]]


def _cols(m):
    return [[m[i][k] for i in range(3)] for k in range(3)]


def _from_cols(cols):
    return [[cols[k][i] for k in range(3)] for i in range(3)]


def _rz_cols(m, c, s):
    """m Rz(-t): columns 0 and 1 turned."""
    k = _cols(m)
    return _from_cols([[c * x - s * y for x, y in zip(k[0], k[1])], [s * x + c * y for x, y in zip(k[0], k[1])], k[2]])


def _ry_cols(m, c, s):
    """m Ry(-t): columns 0 and 2 turned."""
    k = _cols(m)
    return _from_cols([[c * x + s * z for x, z in zip(k[0], k[2])], k[1], [-s * x + c * z for x, z in zip(k[0], k[2])]])


def _rx_minus_half_pi(m):
    """m Rx(-pi/2): columns (c0, -c2, c1)."""
    k = _cols(m)
    return _from_cols([k[0], [-x for x in k[2]], k[1]])


# --------------------------------------------------------------------------- #
# SRS (iiwa): arm angle psi
# --------------------------------------------------------------------------- #
def _srs_elbow(bld: Builder, geo) -> tuple:
    """Steps 0 and 1 of the SRS programs: the pose's rotation R_c and wrist centre W in the
    canonical frame (R_c = F^T R T_R^T, W = F^T (t - S) - R_c t_T), |W|^2, and the elbow: cos t4
    (snapped at the stretch), |sin t4|, |t4|; unreachable beyond +-1 and where W is at the
    shoulder. Returns (rc, w, ww, c4, s4a, t4a)."""
    p = _inputs(bld)
    rot, tr = _rotation_and_translation(bld, p, "p")
    frame = [[_number(x) for x in row] for row in geo.frame.tolist()]
    tool_r = [[_number(x) for x in row] for row in geo.tool_rotation.tolist()]
    shoulder = [_number(x) for x in geo.shoulder]
    tool_t = [_number(x) for x in geo.tool_translation]
    fr = [[sum(frame[k][i] * rot[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
    rc = _let_matrix(bld, "rc", [[sum(fr[i][k] * tool_r[j][k] for k in range(3)) for j in range(3)]
                                 for i in range(3)])
    w = [bld.let(f"w{i}", sum(frame[k][i] * (tr[k] - shoulder[k]) for k in range(3))
                 - sum(rc[i][k] * tool_t[k] for k in range(3))) for i in range(3)]
    dse, dew = _number(geo.d_se), _number(geo.d_ew)
    ww = bld.let("ww", w[0] ** 2 + w[1] ** 2 + w[2] ** 2)
    bld.require(ww > CLASS_DISTANCE ** 2)                      # wrist centre not at the shoulder
    ce = bld.let("ce", (ww - dse ** 2 - dew ** 2) / (2 * dse * dew))
    bld.require(sp.Abs(ce) <= 1 + REACH_TOL)
    c4 = _snap_select(bld, "ct4", ce, STRETCH_TOL)
    s4a = bld.let("st4a", sp.sqrt(pos(1 - c4 * c4)))
    t4a = bld.let("t4a", sp.atan2(s4a, c4))
    return rc, w, ww, c4, s4a, t4a


def _srs_wrist(bld: Builder, rc, angles):
    """The wrist rotation R_w = Ry(-t4) Rz(-t3) Ry(-t2) Rz(-t1) R_c from the cosines and sines
    ((c1, s1), ..., (c4, s4)) of the rounded shoulder and elbow angles, and its ZYZ decomposition
    before the sign branch (:func:`derive.ik.euler.zyz_plus`, flag ``singular_wr``)."""
    (c1, s1), (c2, s2), (c3, s3), (c4, s4) = angles
    m = _let_matrix(bld, "ma", _rz_rows(rc, c1, s1))
    m = _let_matrix(bld, "mb", _ry_rows(m, c2, s2))
    m = _let_matrix(bld, "mc", _rz_rows(m, c3, s3))
    rw = _let_matrix(bld, "rw", _ry_rows(m, c4, s4))
    return zyz_plus(bld, rw, "wr", "singular_wr", False)


def srs_program(robot) -> IKProgram:
    """The IK program of an SRS arm with the arm angle psi as input ``fv``
    (:mod:`derive.ik.srs`, Shimizu sec. III). Steps:

    0. the pose's rotation R and translation t; R_c = F^T R T_R^T and the wrist centre
       W = F^T (t - S) - R_c t_T in the canonical frame (F, S the canonical frame and shoulder,
       (T_R, t_T) the end frame in the wrist frame: :func:`derive.ik.srs.srs_geometry`);
    1. the elbow: cos t4 = (|W|^2 - d_se^2 - d_ew^2) / (2 d_se d_ew), unreachable beyond +-1;
    2. the shoulder rotation about x = W/|W| by psi, R_psi (Rodrigues), before the branches;
    3. branch GC2 (the shoulder's sign), branch GC4 (t4 = +-acos): the reference configuration
       R0 = Rz(a) Ry(b - phi) from the directions of W and of v(t4), all cosines and sines
       algebraic; R_s = R_psi R0; t1, t2, t3 from R_s (ZYZ, sign GC2);
    4. the wrist rotation R_w = Ry(t4)^T Rz(t3)^T Ry(t2)^T Rz(t1)^T R_c from the rounded shoulder
       angles; branch GC6: t5, t6, t7 from R_w (ZYZ);
    5. q = s theta (s the axis signs).
    """
    geo = srs.srs_geometry(robot)
    bld = Builder({})
    rc, w, ww, c4, s4a, t4a = _srs_elbow(bld, geo)
    dse, dew = _number(geo.d_se), _number(geo.d_ew)
    # 2. R_psi = cos psi I + sin psi [x]x + (1 - cos psi) x x^T, x = W/|W|
    nw = bld.let("nw", sp.sqrt(ww))
    x = [bld.let(f"x{i}", w[i] / nw) for i in range(3)]
    cp, sp_ = sp.cos(FV), sp.sin(FV)
    skew = [[0, -x[2], x[1]], [x[2], 0, -x[0]], [-x[1], x[0], 0]]
    rpsi = _let_matrix(bld, "rq", [[(cp if i == j else 0) + sp_ * skew[i][j] + (1 - cp) * x[i] * x[j]
                                    for j in range(3)] for i in range(3)])
    rho = bld.let("rho", sp.sqrt(w[0] ** 2 + w[1] ** 2))
    axis = rho > AXIS_TOL
    rho_d = bld.select("rho_d", axis, rho, 1)
    ca0 = bld.select("ca0", axis, w[0] / rho_d, 1)
    sa0 = bld.select("sa0", axis, w[1] / rho_d, 0)
    cb0, sb0 = bld.let("cb0", w[2] / nw), bld.let("sb0", rho / nw)
    # 3. the elbow root, then everything that does not depend on the shoulder's and the wrist's
    # sign (the rotations R_s and R_w are the same for both signs of each)
    g4 = bld.branch("sg1", "elbow GC4 = sign of theta4 = s4 q4 (+ / -)")
    s4 = bld.let("st4", g4 * s4a)
    t4 = bld.let("t4", g4 * t4a)
    vx, vz = bld.let("vx", dew * s4), bld.let("vz", dse + dew * c4)
    nv = bld.let("nv", sp.sqrt(vx * vx + vz * vz))
    cphi, sphi = bld.let("cphi", vz / nv), bld.let("sphi", vx / nv)
    cbe = bld.let("cbe", cb0 * cphi + sb0 * sphi)             # cos(b - phi)
    sbe = bld.let("sbe", sb0 * cphi - cb0 * sphi)
    r0 = [[ca0 * cbe, -sa0, ca0 * sbe], [sa0 * cbe, ca0, sa0 * sbe], [-sbe, 0, cbe]]
    rs = _let_matrix(bld, "rs", [[sum(rpsi[i][k] * r0[k][j] for k in range(3)) for j in range(3)]
                                 for i in range(3)])
    sh = zyz_plus(bld, rs, "sh", "singular_sh", True)
    c1, s1, c2, s2, c3, s3 = sh[4]
    # 4. R_w = Ry(-t4) Rz(-t3) Ry(-t2) Rz(-t1) R_c, from the rounded shoulder angles
    wr = _srs_wrist(bld, rc, ((c1, s1), (c2, s2), (c3, s3), (c4, s4)))
    bld.flag("singular", sp.Or(bld.known_symbol("singular_sh"), bld.known_symbol("singular_wr"),
                               s4a < WRIST_SINGULAR))
    # 5. the shoulder's and the wrist's signs
    g2 = bld.branch("sg2", "shoulder GC2 = sign of sin q2 (+ / -)")
    t1, t2, t3 = zyz_signed(bld, sh, g2, ("t1", "t2", "t3"))
    return _srs_end(bld, geo, wr, (t1, t2, t3, t4), [
        ("R_psi", "Rodrigues", ["rotation by psi about W/|W|"]),
        ("theta1, theta2, theta3", "ZYZ of R_psi R0", ["R0 = Rz(a) Ry(b - phi), the reference plane"])],
        free_rule=("set to 0 (q1 at the shoulder's alignment, sin q2 = 0; q5 at the "
                   "wrist's, sin q6 = 0), the next joint taking the rest"),
        free="psi",
        free_doc="psi, the arm angle (rad): the rotation of the arm plane (shoulder, elbow, "
                 "wrist centre) about the shoulder-wrist line, 0 in the reference plane")


def _srs_end(bld: Builder, geo, wr, shoulder: tuple, shoulder_steps: list, reverse: bool = False,
             **doc) -> IKProgram:
    """The last steps of the SRS programs and the program itself: branch GC6 and t5, t6, t7 from
    the wrist decomposition ``wr``, the solution q = s theta from the shoulder and elbow angles
    ``shoulder`` (t1, t2, t3, t4), and the step list with the programs' own shoulder steps.
    ``reverse``: the angles are those of the reversed chain (:func:`_reverse_frame`), mapped back."""
    g6 = bld.branch("sg3", "wrist GC6 = sign of sin q6 (+ / -)")
    t5, t6, t7 = zyz_signed(bld, wr, g6, ("t5", "t6", "t7"))
    thetas = (*shoulder, t5, t6, t7)
    if reverse:
        # the reversed chain's angles phi (derive.ik.srs._reverse): theta = (phi7, -phi6, phi5,
        # -phi4, phi3, -phi2, phi1)
        thetas = tuple(s * t for s, t in zip(_REVERSE_SIGNS, thetas[::-1]))
    bld.ops.append(Op("solution", args=tuple(int(s) * t for s, t in zip(geo.signs, thetas)), depth=bld.depth))
    steps = [
        ("pose in the canonical frame, wrist centre W", "R_c = F^T R T_R^T, W = F^T (t - S) - R_c t_T",
         [f"SRS class, relation mismatch {geo.error:.1g}"]),
        ("theta4", "cosine law", ["|W|^2 = d_se^2 + d_ew^2 + 2 d_se d_ew cos t4"]),
        *shoulder_steps,
        ("theta5, theta6, theta7", "ZYZ of R_w", ["R_w = (Rz(t1) Ry(t2) Rz(t3) Ry(t4))^T R_c"]),
    ]
    return IKProgram(geo.robot, 7, ops=bld.ops, branches=8, free_joint=0, steps=steps,
                     parameters={"d_se": geo.d_se, "d_ew": geo.d_ew, "d_wf": geo.d_wf},
                     branch_labels=[bld.labels[1], bld.labels[0], bld.labels[2]], bit_weights=(2, 4, 1),
                     **doc)


#: The joints of an SRS arm that a program takes as its input ``fv`` besides the arm angle and q3
#: (the class routes of :func:`derive.ik.free_joint.route`; q4 fixes the shoulder-wrist distance).
SRS_JOINTS_GIVEN = (1, 2, 5, 6, 7)
#: theta = _REVERSE_SIGNS * phi reversed: the angles of the reversed chain (derive.ik.srs._reverse)
_REVERSE_SIGNS = (1, -1, 1, -1, 1, -1, 1)


def _reverse_frame(bld: Builder, rc, w):
    """The pose of the chain read from the wrist to the shoulder (:func:`derive.ik.srs._reverse`):
    R' = Ry(pi) R_c^T Ry(pi), W' = -Ry(pi) R_c^T W (Ry(pi) = diag(-1, 1, -1)); its angles are
    phi = (t7, -t6, t5, -t4, t3, -t2, t1), with d_se and d_ew swapped."""
    d = (-1, 1, -1)
    rr = _let_matrix(bld, "rr", [[d[i] * d[j] * rc[j][i] for j in range(3)] for i in range(3)])
    rv = [bld.let(f"rv{i}", -d[i] * sum(rc[k][i] * w[k] for k in range(3))) for i in range(3)]
    return rr, rv


def srs_joint3_program(robot) -> IKProgram:
    """The IK program of an SRS arm with joint 3 given as input ``fv`` instead of the arm angle
    (:func:`derive.ik.srs.ik_joint` with joint 3, :func:`derive.ik.srs.joint_given_steps`; the
    joint that EAIK and IK-Geo lock). Steps:

    0, 1. as :func:`srs_program`: R_c, W, the elbow t4 = +-acos (branch GC4);
    2. the shoulder carries the forearm u = Rz(t3) v(t4) onto W (Paden-Kahan subproblem 2 about
       axes z and y): Rz(t1) Ry(t2) u = W gives cos(t2 + phi) = W_z / r with r = hypot(u_x, u_z),
       phi = atan2(u_x, u_z): t2 = +-acos(W_z / r) - phi (branch: the root), unreachable with
       this t3 beyond +-1; t1 = atan2(W_y, W_x) - atan2(u'_y, u'_x), u' = Ry(t2) u (t1 free, set
       to 0, where W lies on axis 1: flag ``singular_sh``);
    3. the wrist rotation R_w = (Rz(t1) Ry(t2) Rz(t3) Ry(t4))^T R_c; branch GC6: t5, t6, t7 (ZYZ);
    4. q = s theta (s the axis signs; the given q3 is returned as given, wrapped).

    Branch k = 4 i + 2 i4 + i6 as :func:`derive.ik.srs.ik_joint` (i the root of step 2)."""
    return srs_joint_program(robot, 3)


def srs_joint_program(robot, joint: int) -> IKProgram:
    """The IK program of an SRS arm with joint ``joint`` (1, 2, 3, 5, 6 or 7) given as input
    ``fv``: the closed forms of :func:`derive.ik.srs.ik_joint` (joints 1, 3, 5, 7) and
    :func:`derive.ik.free_joint._srs_joint2` (joints 2, 6) step by step, with their branch ids
    and singular flags. Joints 5, 6, 7 are joints 3, 2, 1 of the reversed chain
    (:func:`_reverse_frame`); each program is then a composition of named subproblems:

    0, 1. as :func:`srs_program`: R_c, W (reversed: R', W'), the elbow t4 = +-acos (branch
       GC4: the sign of t4 of the arm, so of -phi4 on the reversed chain);
    2. the shoulder carries the forearm v(t4) onto W with one of its joints given:
       - t1 given (:func:`_shoulder_t1`): subproblem 4 for t3 (e_y^T Rz(t3) v = (Rz(t1)^T W)_y,
         the roots asin and pi - asin; t3 free, set to 0, where the elbow is stretched: flag
         ``singular_st``), subproblem 1 about axis 2 for t2;
       - t2 given (:func:`_shoulder_t2`): subproblem 4 for t3 (the z row, cos t3 = (cos t2 v_z -
         W_z) / (sin t2 v_x), the roots +-acos; t3 free where sin t2 v_x = 0: flag ``singular_fl``),
         subproblem 1 about axis 1 for t1 (free where W is on axis 1: flag ``singular_ax``);
       - t3 given (:func:`_shoulder_t3`): subproblem 4 for t2 about axis 2, subproblem 1 about
         axis 1 for t1 (IK-Geo's subproblem 2 about axes z and y; flag ``singular_sh``);
    3. the wrist rotation R_w = (Rz(t1) Ry(t2) Rz(t3) Ry(t4))^T R_c; branch GC6: t5, t6, t7 (ZYZ,
       flag ``singular_wr``);
    4. q = s theta (reversed: theta = (phi7, -phi6, phi5, -phi4, phi3, -phi2, phi1)); the given
       joint is returned as given, wrapped.

    Branch k = 4 i + 2 i4 + i6 as the numpy closed forms number them (i the root of step 2, i4
    the sign of t4, i6 the sign of the Euler decomposition solved last)."""
    if joint not in (3, *SRS_JOINTS_GIVEN):
        raise DeriveError(f"SRS joint-given program: joint {joint} cannot be given (1, 2, 3, 5, 6 or 7)")
    geo = srs.srs_geometry(robot)
    bld = Builder({})
    rc, w, ww, c4, s4a, t4a = _srs_elbow(bld, geo)
    dse, dew = _number(geo.d_se), _number(geo.d_ew)
    reverse = joint > 4
    j = 8 - joint if reverse else joint
    if reverse:
        rc, w = _reverse_frame(bld, rc, w)
        dse, dew = dew, dse
    # the given canonical angle (of the reversed chain: phi_j = +-t_joint)
    sign = int(geo.signs[joint - 1]) * (_REVERSE_SIGNS[j - 1] if reverse else 1)
    tg = bld.let(f"t{j}", sign * FV)
    elbow = (-1 if reverse else 1, c4, s4a, t4a, dse, dew)
    steps = {1: _shoulder_t1, 2: _shoulder_t2, 3: _shoulder_t3}[j](bld, w, tg, elbow)
    angles, flags, step_doc, free_rule = steps
    (t1, c1, s1), (t2, c2, s2), (t3, c3, s3), (t4, c4_, s4) = angles
    wr = _srs_wrist(bld, rc, ((c1, s1), (c2, s2), (c3, s3), (c4_, s4)))
    bld.flag("singular", sp.Or(*flags, bld.known_symbol("singular_wr")))
    if joint == 3:
        return _srs_end(bld, geo, wr, (t1, t2, t3, t4), step_doc, free_rule=free_rule,
                        free="q3", free_doc="q3, the value of joint 3 (rad), returned as given in (-pi, pi]")
    prog = _srs_end(bld, geo, wr, (t1, t2, t3, t4), step_doc, reverse=reverse, free_rule=free_rule,
                    free=f"q{joint}",
                    free_doc=f"q{joint}, the value of joint {joint} (rad), returned as given in (-pi, pi]",
                    steps_source=("the numpy closed form " + ("derive.ik.srs.ik_joint" if joint in (1, 7)
                                                              else "derive.ik.free_joint._srs_joint2")
                                  + (" on the reversed chain (wrist to shoulder)" if reverse else "")))
    return prog


def _elbow_root(bld: Builder, elbow):
    """Branch GC4 (the sign of the arm's t4) and the forearm v(t4) = (v_x, 0, v_z) of the chain
    solved (reversed: phi4 = -t4). Returns (t4, cos t4, sin t4, v_x, v_z)."""
    rs, c4, s4a, t4a, dse, dew = elbow
    g4 = bld.branch("sg1", "elbow GC4 = sign of theta4 = s4 q4 (+ / -)")
    s4 = bld.let("st4", rs * g4 * s4a)
    t4 = bld.let("t4", rs * g4 * t4a)
    vx, vz = bld.let("vx", dew * s4), bld.let("vz", dse + dew * c4)
    return t4, c4, s4, vx, vz


def _shoulder_t3(bld: Builder, w, t3, elbow):
    """t3 given: subproblem 4 for t2, subproblem 1 for t1 (:func:`srs_joint3_program`)."""
    c3, s3 = sp.cos(t3), sp.sin(t3)
    rho = bld.let("rho", sp.sqrt(w[0] ** 2 + w[1] ** 2))
    on_axis = bld.flag("singular_sh", rho < AXIS_TOL)
    aw = bld.select("aw", on_axis, 0, sp.atan2(w[1], w[0]))
    # 1. the elbow root
    t4, c4, s4, vx, vz = _elbow_root(bld, elbow)
    ux, uy = bld.let("ux", c3 * vx), bld.let("uy", s3 * vx)
    r = bld.let("ru", sp.sqrt(ux * ux + vz * vz))
    bld.require(r > 0)
    cz = bld.let("cz", w[2] / bld.select("ru_d", r > 0, r, 1))
    bld.require(sp.Abs(cz) <= 1 + REACH_TOL)
    czs = _snap_select(bld, "czs", cz, STRETCH_TOL)
    acz = bld.let("acz", sp.atan2(sp.sqrt(pos(1 - czs * czs)), czs))
    phi = bld.let("phi", sp.atan2(ux, vz))
    # 2. the root of the shoulder subproblem
    g2 = bld.branch("sg2", "shoulder root = sign of t2 + phi (+ / -)")
    t2 = bld.let("t2", g2 * acz - phi)
    c2, s2 = sp.cos(t2), sp.sin(t2)
    upx = bld.let("upx", c2 * ux + s2 * vz)
    t1 = bld.select("t1", on_axis, 0, aw - sp.atan2(uy, upx))
    c1, s1 = sp.cos(t1), sp.sin(t1)
    return (((t1, c1, s1), (t2, c2, s2), (t3, c3, s3), (t4, c4, s4)), (on_axis,),
            [("theta1, theta2", "subproblem 2 (axes z, y)", ["Rz(t1) Ry(t2) Rz(t3) v(t4) = W, t3 given"])],
            ("set to 0 (q1 where the wrist centre is on axis 1; q5 at the "
             "wrist's alignment, sin q6 = 0), the next joint taking the rest"))


def _shoulder_t1(bld: Builder, w, t1, elbow):
    """t1 given (:func:`derive.ik.srs.joint_given_steps`, joint 1): y = Rz(t1)^T W; subproblem 4,
    e_y^T Rz(t3) v = y_y, so sin t3 = y_y / v_x: the roots atan2(s, +c) first, atan2(s, -c)
    (c = sqrt(1 - s^2); within STRETCH_TOL of |s| = 1 the double root t3 = +-pi/2; unreachable
    beyond 1 + REACH_TOL; t3 free, set to 0, where the elbow is stretched, |v_x| below
    WRIST_SINGULAR max(d_ew, 1), reachable there when |y_y| <= REACH_TOL); subproblem 1 about axis
    2, Ry(t2) Rz(t3) v = y: t2 = atan2(a_z y_x - a_x y_z, a_x y_x + a_z y_z), a = Rz(t3) v."""
    c1, s1 = sp.cos(t1), sp.sin(t1)
    y0 = bld.let("y0", c1 * w[0] + s1 * w[1])
    y1 = bld.let("y1", c1 * w[1] - s1 * w[0])
    t4, c4, s4, vx, vz = _elbow_root(bld, elbow)
    rs, _, _, _, _, dew = elbow
    st = bld.flag("singular_st", sp.Abs(vx) < WRIST_SINGULAR * max(float(dew), 1.0))
    s3r = bld.let("s3r", y1 / bld.select("vx_d", st, 1, vx))
    bld.require(sp.Or(sp.And(st, sp.Abs(y1) <= REACH_TOL), sp.And(sp.Not(st), sp.Abs(s3r) <= 1 + REACH_TOL)))
    s3s = _snap_select(bld, "s3s", s3r, STRETCH_TOL)
    c3a = bld.let("c3a", sp.sqrt(pos((1 - s3s) * (1 + s3s))))
    g2 = bld.branch("sg2", "shoulder root: t3 = asin(s) (+) or pi - asin(s) (-), s = (Rz(t1)^T W)_y / v_x")
    t3 = bld.select("t3", st, 0, sp.atan2(s3s, g2 * c3a))
    c3, s3 = sp.cos(t3), sp.sin(t3)
    ax = bld.let("ax3", c3 * vx)
    t2 = bld.let("t2", sp.atan2(vz * y0 - ax * w[2], ax * y0 + vz * w[2]))
    c2, s2 = sp.cos(t2), sp.sin(t2)
    return (((t1, c1, s1), (t2, c2, s2), (t3, c3, s3), (t4, c4, s4)), (st,),
            [("theta3", "subproblem 4 (axis z)", ["e_y^T Rz(t3) v(t4) = (Rz(t1)^T W)_y, t1 given"]),
             ("theta2", "subproblem 1 (axis y)", ["Ry(t2) Rz(t3) v(t4) = Rz(t1)^T W"])],
            ("set to 0 (t3 where the elbow is stretched; the wrist's first joint at its alignment), "
             "the next joint taking the rest"))


def _shoulder_t2(bld: Builder, w, t2, elbow):
    """t2 given (:func:`derive.ik.free_joint._joint2_steps`): subproblem 4, the z row of
    Rz(t1) Ry(t2) Rz(t3) v = W, cos t3 = (cos t2 v_z - W_z) / (sin t2 v_x), clipped to [-1, 1]:
    the roots +acos first, -acos (unreachable beyond 1 + REACH_TOL; t3 free, set to 0, where
    |sin t2 v_x| is below WRIST_SINGULAR max(d_ew, 1), reachable there when |cos t2 v_z - W_z| <=
    REACH_TOL); subproblem 1 about axis 1: t1 = atan2(W_y, W_x) - atan2(u_y, u_x), u = Ry(t2)
    Rz(t3) v (t1 free, set to 0, where W lies on axis 1)."""
    c2, s2 = sp.cos(t2), sp.sin(t2)
    rho = bld.let("rho", sp.sqrt(w[0] ** 2 + w[1] ** 2))
    on_axis = bld.flag("singular_ax", rho < AXIS_TOL)
    aw = bld.select("aw", on_axis, 0, sp.atan2(w[1], w[0]))
    t4, c4, s4, vx, vz = _elbow_root(bld, elbow)
    _, _, _, _, _, dew = elbow
    den = bld.let("den3", s2 * vx)
    num = bld.let("num3", c2 * vz - w[2])
    flat = bld.flag("singular_fl", sp.Abs(den) < WRIST_SINGULAR * max(float(dew), 1.0))
    c3r = bld.let("c3r", num / bld.select("den3_d", flat, 1, den))
    bld.require(sp.Or(sp.And(flat, sp.Abs(num) <= REACH_TOL), sp.And(sp.Not(flat), sp.Abs(c3r) <= 1 + REACH_TOL)))
    c3c = bld.select("c3c", c3r >= 1, 1, bld.select("c3c_lo", c3r <= -1, -1, c3r))
    a3 = bld.let("a3", sp.atan2(sp.sqrt(pos((1 - c3c) * (1 + c3c))), c3c))
    g2 = bld.branch("sg2", "shoulder root: t3 = +acos (+) or -acos (-) of the z row")
    t3 = bld.select("t3", flat, 0, g2 * a3)
    c3, s3 = sp.cos(t3), sp.sin(t3)
    ux = bld.let("ux2", c2 * c3 * vx + s2 * vz)
    t1 = bld.select("t1", on_axis, 0, aw - sp.atan2(s3 * vx, ux))
    c1, s1 = sp.cos(t1), sp.sin(t1)
    return (((t1, c1, s1), (t2, c2, s2), (t3, c3, s3), (t4, c4, s4)), (flat, on_axis),
            [("theta3", "subproblem 4 (axis z)", ["e_z^T Rz(t1) Ry(t2) Rz(t3) v(t4) = W_z, t2 given"]),
             ("theta1", "subproblem 1 (axis z)", ["Rz(t1) Ry(t2) Rz(t3) v(t4) = W"])],
            ("set to 0 (t3 where sin t2 v_x = 0, t1 where the wrist centre is on the first axis; the "
             "wrist's first joint at its alignment), the next joint taking the rest"))


# --------------------------------------------------------------------------- #
# Panda / FR3: q7
# --------------------------------------------------------------------------- #
def panda_program(robot) -> IKProgram:
    """The IK program of a Panda-class arm with q7 as input ``fv`` (:mod:`derive.ik.panda`, He &
    Liu's construction). Steps (the numpy module's eq. labels):

    0. the canonical flange pose B^-1 P T^-1, its rotation R7 and position p;
    1. frame 6 (eq. F7): R6 = R7 Rz(-q7) Rx(-pi/2), O6 = p - d7 z7 - a6 x6;
    2. v = R6^T (S - O6), the shoulder S = (0, 0, d1) in frame 6;
    3. branch on the elbow root (eq. E2): q4 = atan2(B, A) +- acos(K / hypot(A, B)); X, Z (eq. E1);
    4. branch on the q6 root (eq. W2): q6 = atan2(vx, vy) +- atan2(sqrt(X^2 - vz^2), Z) (eq. W4,
       the sine of acos(Z / hypot(vx, vy)) without cancellation); q5 (eq. W3);
    5. R3 = R6 Rz(-q6) Ry(-q5) Rz(-q4) Rx(-pi/2) (eq. S1); branch on the sign of sin q2: q1, q2,
       q3 by ZYZ (eq. S2).

    Free joints on singular sets (S on axis 6: q6; S on axis 5, X = 0: q5; sin q2 = 0: q1) are
    set to 0 and flagged.
    """
    geo = panda.panda_geometry(robot)
    bld = Builder({})
    p = _inputs(bld)
    conj_b = [_number(x) for x in dq.conj_quaternion(geo.base)]
    conj_t = [_number(x) for x in dq.conj_quaternion(geo.tool)]
    moved = [sp.expand(e) for e in dual_hamilton(dual_hamilton(conj_b, p), conj_t)]
    pc = list(p) if moved == list(p) else [bld.let(f"pc{i}", e) for i, e in enumerate(moved)]
    r7, pos7 = _rotation_and_translation(bld, pc, "f")
    v = {k: _number(getattr(geo, k)) for k in panda.PARAMETERS}
    # 1. frame 6
    c7, s7 = sp.cos(FV), sp.sin(FV)
    col0 = [bld.let(f"x6_{i}", c7 * r7[i][0] - s7 * r7[i][1]) for i in range(3)]
    col2 = [bld.let(f"z6_{i}", s7 * r7[i][0] + c7 * r7[i][1]) for i in range(3)]
    r6 = [[col0[i], -r7[i][2], col2[i]] for i in range(3)]
    o6 = [bld.let(f"o6_{i}", pos7[i] - v["d7"] * r7[i][2] - v["a6"] * col0[i]) for i in range(3)]
    # 2. the shoulder in frame 6
    d = [-o6[0], -o6[1], v["d1"] - o6[2]]
    vv = [bld.let(f"v{k}", sum(r6[i][k] * d[i] for i in range(3))) for k in range(3)]
    # 3. the elbow (eq. E2)
    a = v["a3"] * v["a4"] + v["d3"] * v["d5"]
    b = v["a4"] * v["d3"] - v["a3"] * v["d5"]
    rab = sp.sqrt(a * a + b * b)
    k = (vv[0] ** 2 + vv[1] ** 2 + vv[2] ** 2 - v["a3"] ** 2 - v["d3"] ** 2 - v["a4"] ** 2 - v["d5"] ** 2) / 2
    ce = bld.let("ce", k / rab)
    bld.require(sp.Abs(ce) <= 1 + REACH_TOL)
    cang = _snap_select(bld, "ca4", ce, DOUBLE_ROOT)
    sang = bld.let("sa4", sp.sqrt(pos(1 - cang * cang)))
    cphi, sphi = _number(float(a / rab)), _number(float(b / rab))
    phi = _number(float(sp.atan2(b, a)))
    ang = bld.let("an4", sp.atan2(sang, cang))
    # q6 data that does not depend on the elbow: S on axis 6 when hypot(vx, vy) = 0
    rho6 = bld.let("rho6", sp.sqrt(vv[0] ** 2 + vv[1] ** 2))
    free6 = bld.flag("singular_q6", rho6 < FREE_JOINT_DISTANCE)
    rho6d = bld.select("rho6_d", free6, 1, rho6)
    cps, sps = bld.let("cps6", vv[1] / rho6d), bld.let("sps6", vv[0] / rho6d)
    psi6 = bld.let("ps6", sp.atan2(vv[0], vv[1]))
    g4 = bld.branch("sg1", "elbow q4 root (eq. E2, + / -)")
    q4 = bld.let("q4", phi + g4 * ang)
    c4 = bld.let("cq4", cphi * cang - g4 * sphi * sang)
    s4 = bld.let("sq4", sphi * cang + g4 * cphi * sang)
    xx = bld.let("xe", -(v["a3"] * c4 + v["d3"] * s4 + v["a4"]))
    zz = bld.let("ze", v["a3"] * s4 - v["d3"] * c4 - v["d5"])
    # 4. q6 (eq. W2): vx s6 + vy c6 = Z
    c6a = bld.let("ce6", zz / rho6d)
    bld.require(sp.And(sp.Abs(c6a) <= 1 + REACH_TOL,
                       sp.Or(sp.Not(free6), sp.Abs(zz) <= FREE_JOINT_DISTANCE)))
    # the root's sine from eq. W4, (X c5)^2 = X^2 - vz^2 (derive.ik.panda.wrist): accurate where
    # X is small; the roots merge where (X c5)^2 < DOUBLE_ROOT X^2 + W4_NOISE |X|
    x2 = bld.let("x2e", xx * xx)
    e6 = bld.let("e6", x2 - vv[2] * vv[2])
    e6s = bld.select("e6s", e6 <= DOUBLE_ROOT * x2 + W4_NOISE * sp.Abs(xx), 0, e6)
    r6s = bld.let("r6s", sp.sqrt(e6s))
    n6 = bld.let("n6", sp.sqrt(e6s + zz * zz))
    n6d = bld.select("n6d", n6 <= 0, 1, n6)
    cang6 = bld.let("ca6", zz / n6d)
    sang6 = bld.let("sa6", r6s / n6d)
    ang6 = bld.let("an6", sp.atan2(r6s, zz))
    g6 = bld.branch("sg2", "wrist q6 root (eq. W2, + / -)")
    q6 = bld.select("q6", free6, 0, psi6 + g6 * ang6)
    c6 = bld.select("cq6", free6, 1, cps * cang6 - g6 * sps * sang6)
    s6 = bld.select("sq6", free6, 0, sps * cang6 + g6 * cps * sang6)
    # q5 (eq. W3): X c5 = vx c6 - vy s6, X s5 = vz
    free5 = bld.flag("singular_q5", sp.Abs(xx) < FREE_JOINT_DISTANCE)
    sx = bld.let("sgx", sgn(xx))
    u5 = bld.let("u5", sx * (vv[0] * c6 - vv[1] * s6))
    w5 = bld.let("w5", sx * vv[2])
    n5 = bld.select("n5", free5, 1, sp.sqrt(u5 * u5 + w5 * w5))
    q5 = bld.select("q5", free5, 0, sp.atan2(w5, u5))
    c5 = bld.select("cq5", free5, 1, u5 / n5)
    s5 = bld.select("sq5", free5, 0, w5 / n5)
    # 5. R3 (eq. S1), the shoulder (eq. S2)
    m = _let_matrix(bld, "ra", _rz_cols(r6, c6, s6))
    m = _let_matrix(bld, "rb", _ry_cols(m, c5, s5))
    m = _rx_minus_half_pi(_rz_cols(m, c4, s4))
    r3 = _let_matrix(bld, "r3", m)
    sh = zyz_plus(bld, r3, "sh", "singular_q1", False)
    bld.flag("singular", sp.Or(bld.known_symbol("singular_q1"), free5, free6))
    g2 = bld.branch("sg3", "shoulder sign of sin q2 (+ / -)")
    q1, q2, q3 = zyz_signed(bld, sh, g2, ("q1", "q2", "q3"))
    bld.ops.append(Op("solution", args=(q1, q2, q3, q4, q5, q6, FV), depth=bld.depth))
    steps = [
        ("pose in the canonical chain's frames", "B^-1 P T^-1", [f"Panda class, relation mismatch {geo.error:.1g}"]),
        ("frame 6", "F7", ["R6 = R7 Rz(-q7) Rx(-pi/2), O6 = p - d7 z7 - a6 x6"]),
        ("theta4", "S1", ["E2: A c4 + B s4 = K"]),
        ("theta6", "S1", ["W2: vx s6 + vy c6 = Z(q4)"]),
        ("theta5", "S2", ["W3: X c5 = vx c6 - vy s6, X s5 = vz"]),
        ("theta1, theta2, theta3", "ZYZ", ["S1, S2: R3 = Rz(q1) Ry(q2) Rz(q3)"]),
    ]
    return IKProgram(geo.robot, 7, ops=bld.ops, branches=8, free_joint=0,
                     free_rule=("set to 0 (q1 where sin q2 = 0, q5 where the shoulder is on axis 5, q6 "
                                "where it is on axis 6), the joint after it taking the rest"),
                     steps=steps, parameters=dict(geo.values), branch_labels=list(bld.labels),
                     free="q7", free_doc="q7, the value of joint 7 (rad), returned as given in (-pi, pi]")


def seven_joint_program(robot, kind: str, free: str | None = None) -> IKProgram:
    """The program of a 7R arm of class ``kind`` ("srs" or "panda",
    :func:`derive.ik.redundant.redundant_kind`) with the free parameter ``free`` (one of
    the class's :data:`derive.ik.redundant.FREE_CHOICES`; default the class's first: psi, q7)."""
    if kind == "panda":
        return panda_program(robot)
    if free is not None and free != "psi":
        return srs_joint_program(robot, int(free[1:]))
    return srs_program(robot)

