"""The IK program of the three-parallel class (:mod:`derive.ik.parallel3`, the Unitree Z1), in the
language of :mod:`derive.ik.ir`, so that the emitters print it as pure Python, numpy and C.

It is the numpy reference's composition step by step, each subproblem written out with the
robot's axes and vectors substituted (numbers within 1e-12 of an integer are that integer, so a
Z1's axes along x, y, z make most terms vanish), and written to be total:

* subproblems 4 and 3 as the line a . x = b cut with the unit circle (IK-Geo, Elias & Wen 2022,
  arXiv:2211.05737): x = (a b +- sqrt(|a|^2 - b^2) J a) / |a|^2, J a = (a_2, -a_1); the angle is
  atan2 of the numerators (no division), and where |a| is a constant of the arm (q5, q3) the
  sine and cosine are those numerators over |a|, not a sin/cos of the angle;
* subproblem 1 as theta = atan2((k x p1) . p2, (p1 - (k . p1) k) . p2);
* reach: |b| / |a| beyond 1 + REACH_TOL drops the branch (q5 and q3; q1 where
  |a|^2 - b^2 < -REACH_TOL max(1, b^2)), within it the root is clipped;
* singular sets (flag ``singular``): the wrist point on axis 1 (|a| of the q1 step below
  SP_FREE_ANGLE: q1 free, set to 0; flag ``singular_sh``) and axis 6 parallel to the parallel axes
  (|h_6 x R_5^T h_2| below WRIST_SINGULAR: q6 free, set to 0; flag ``singular_wr``); in the sp6
  layout also q1 a near-double root of subproblem 6's quartic (flag ``singular_dr``).

Branch numbering as :func:`derive.ik.parallel3.solve_batch`: k = 4 i1 + 2 i5 + i3.

The layout with axes 5 and 6 not meeting (:func:`parallel3_sp6_program`) solves q1 and q5 by
subproblem 6: q5's 2x2 block eliminated, a "roots4" line for the quartic in q1
(:meth:`derive.ik.ir.Builder.roots4`), steps 3-6 as above; branch k = 2 i6 + i3 as
:func:`derive.ik.parallel3.solve_batch_sp6`.
"""

from __future__ import annotations

import math

import numpy as np
import sympy as sp

from derive.algebra.quaternion import hamilton
from derive.errors import DeriveError
from derive.ik.extract import _rot
from derive.ik.ir import Builder, IKProgram, Op, pos
from derive.ik.parallel3 import P3Geometry
from derive.ik.tolerances import REACH_TOL, SP6_DOUBLE_ROOT, SP_EXACT_TOL, SP_FREE_ANGLE, SP_RANK_TOL, WRIST_SINGULAR
from derive.ik.tolerances import SP6_BLOCK_MIN

#: Numbers of the geometry within this of an integer are that integer.
SNAP = 1e-12


def _number(x: float):
    x = float(x)
    r = round(x)
    return sp.Integer(r) if abs(x - r) < SNAP else sp.Float(x, 17)


def _vec(v) -> list:
    return [_number(x) for x in v]


def _dot(a, b):
    return sum(x * y for x, y in zip(a, b))


def _cross(a, b) -> list:
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _rot_vec(k, c, s, v) -> list:
    """R(k, t) v by Rodrigues (k a numeric unit axis, c, s the cosine and sine of t)."""
    kxv, kv = _cross(k, v), _dot(k, v)
    return [sp.expand(c * v[i] + s * kxv[i] + (1 - c) * kv * k[i]) for i in range(3)]


def _lets(bld: Builder, stem: str, exprs) -> list:
    """A let per entry; an entry that is a number (a zero of the arm's axes) stays that number."""
    out = []
    for i, e in enumerate(exprs):
        e = sp.expand(e)
        out.append(e if e.is_number else bld.let(f"{stem}{i}", e))
    return out


def _sp4_line(h, k, p, d) -> tuple:
    """(a_0, a_1, b) of subproblem 4, h^T R(k, t) p = d: a = A(k, p)^T h, b = d - (h . k)(k . p)."""
    kp = _dot(k, p)
    return (_dot(_cross(k, p), h), _dot(p, h) - kp * _dot(k, h), d - _dot(h, k) * kp)


def _root_of_unit_line(bld: Builder, stem: str, a, b, label: str, root2=None):
    """The two roots of a . x = b on the unit circle when |a| is a constant of the arm: the sine
    and cosine (x = (a c +- sqrt(1 - c^2) J a) / |a| with c = b / |a|), reach required, the
    branch, and the angle. ``root2``: an accurate expression of 1 - c^2 where one is known.
    Returns (angle, sin, cos)."""
    af = [float(x) for x in a]
    na = math.hypot(*af)
    a0, a1 = (_number(x / na) for x in af)
    c = bld.let(f"{stem}_c", sp.expand(b * _number(1.0 / na)))
    bld.require(sp.Abs(c) <= 1 + REACH_TOL)
    r = bld.let(f"{stem}_r", sp.sqrt(pos(1 - c * c)) if root2 is None else sp.sqrt(root2))
    sg = bld.branch(f"sg_{stem}", label)
    s_ = bld.let(f"{stem}_s", a0 * c + sg * r * a1)
    c_ = bld.let(f"{stem}_cs", a1 * c - sg * r * a0)
    t = bld.let(stem, sp.atan2(s_, c_))
    bld.set_trig(t, s_, c_)
    return t, s_, c_


def _pose_lets(geo: P3Geometry):
    """Step 0 of both layouts: a Builder with the pose's rotation R and translation t, R_06 =
    R R_6T^T and p_16 = t - p_0 - R_06 p_6 (the wrist point, or the point of axis 6 in the sp6
    layout). Returns (builder, h, p, R_06 rows, p_16)."""
    h = [_vec(v) for v in geo.h]
    p = [_vec(v) for v in geo.p]
    r6t = [_vec(row) for row in geo.r6t]
    bld = Builder({})
    pin = sp.symbols("p0:8", real=True)
    bld.known.update(pin)
    # 0. rotation, translation, R_06, p_16
    rm = _rot(pin[:4])
    rows = [[bld.let(f"r{i}{j}", sp.expand(rm[i, j])) for j in range(3)] for i in range(3)]
    tt = _lets(bld, "t", [2 * e for e in hamilton(pin[4:], (pin[0], -pin[1], -pin[2], -pin[3]))[1:]])
    if r6t == [[1, 0, 0], [0, 1, 0], [0, 0, 1]]:
        r06 = rows
    else:
        r06 = [[bld.let(f"m{i}{j}", sp.expand(_dot(rows[i], r6t[j]))) for j in range(3)] for i in range(3)]
    p16 = _lets(bld, "w", [tt[i] - p[0][i] - _dot(r06[i], p[6]) for i in range(3)])
    return bld, h, p, r06, p16


def _shoulder_lets(bld: Builder, h, q1, r06, p16):
    """R_t = R_1^T R_06 (rows of lets) and R_1^T p_16, once q1 is known (both layouts)."""
    c1, s1 = sp.cos(q1), sp.sin(q1)
    cols = [[r06[i][j] for i in range(3)] for j in range(3)]
    mh0 = [-x for x in h[0]]
    rt_cols = [_rot_vec(mh0, c1, s1, col) for col in cols]               # R(-h_1, q1) = R_1^T
    rt = [[bld.let(f"rt{i}{j}", rt_cols[j][i]) for j in range(3)] for i in range(3)]
    u16 = _lets(bld, "u", _rot_vec(mh0, c1, s1, p16))
    return rt, u16


def _wrist_and_arm(bld: Builder, geo: P3Geometry, h, p, rt, u16, q1_q5, sing_sh, p45) -> None:
    """Steps 3 to 6 of both layouts (:func:`parallel3_program`), given R_t = R_1^T R_06 (``rt``),
    R_1^T p_16 (``u16``), q1, q5 with its sine and cosine, the shoulder's singular flag, and
    ``p45``: p_4 (axes 5 and 6 meeting) or p_4 + R(h_5, q5) p_5 (the sp6 layout), the vector from
    axis 4 to the point of axis 6 that p_16 ends at, before the rotation about h_2."""
    q1, q5, s5, c5 = q1_q5
    # 3. q6 (subproblem 1 about -h_6)
    u5 = _lets(bld, "g", _rot_vec(h[4], c5, -s5, h[1]))                  # R_5^T h_2
    v6 = _lets(bld, "e", [_dot([rt[k][i] for k in range(3)], h[1]) for i in range(3)])   # R_t^T h_2
    mh5 = [-x for x in h[5]]
    off = _cross(h[5], u5)
    sing_wr = bld.flag("singular_wr", sp.expand(_dot(off, off)) < WRIST_SINGULAR ** 2)
    bld.flag("singular", sp.Or(sing_sh, sing_wr))
    ku = _dot(mh5, u5)
    q6 = bld.select("q6", sing_wr, 0, sp.atan2(sp.expand(_dot(_cross(mh5, u5), v6)),
                                                sp.expand(_dot(u5, v6) - ku * _dot(mh5, v6))))
    c6, s6 = sp.cos(q6), sp.sin(q6)
    # 4. theta = q2 + q3 + q4 (subproblem 1 about h_2 on x across h_2)
    xv = np.cross(geo.h[1], geo.h[0])
    x = _vec(xv / np.linalg.norm(xv))
    y1 = _lets(bld, "y", _rot_vec(h[4], c5, -s5, x))
    y2 = _lets(bld, "z", _rot_vec(h[5], c6, -s6, y1))
    tg = _lets(bld, "f", [_dot(rt[i], y2) for i in range(3)])
    th = bld.let("th", sp.atan2(sp.expand(_dot(_cross(h[1], x), tg)), sp.expand(_dot(x, tg))))
    # 5. q3 (subproblem 3 about h_2): ||R(h_2, q3) p_3 + p_2|| = ||v||
    rp4 = _rot_vec(h[1], sp.cos(th), sp.sin(th), p45)
    v = _lets(bld, "v", [u16[i] - p[1][i] - rp4[i] for i in range(3)])
    vv = bld.let("vv", v[0] ** 2 + v[1] ** 2 + v[2] ** 2)
    mp2 = [-x for x in p[2]]
    k3 = _dot(h[1], p[3]) * _dot(h[1], mp2)
    a3 = (_dot(_cross(h[1], p[3]), mp2), _dot(p[3], mp2) - k3)
    beta = (_dot(p[3], p[3]) + _dot(p[2], p[2]) - vv) / 2 - k3
    q3, s3, c3 = _root_of_unit_line(bld, "q3", a3, sp.expand(beta), "q3, elbow (subproblem 3)")
    # 6. q2 (subproblem 1 about h_2), q4
    w = _lets(bld, "k", [p[2][i] + e for i, e in enumerate(_rot_vec(h[1], c3, s3, p[3]))])
    hw = _dot(h[1], w)
    q2 = bld.let("q2", sp.atan2(sp.expand(_dot(_cross(h[1], w), v)),
                                sp.expand(_dot(w, v) - hw * _dot(h[1], v))))
    q4 = bld.let("q4", th - q2 - q3)
    sol = [None] * 6
    for i, qi in enumerate((q1, q2, q3, q4, q5, q6)):
        sol[geo.order[i]] = qi
    bld.ops.append(Op("solution", args=tuple(sol), depth=bld.depth))


def parallel3_program(robot, geo: P3Geometry) -> IKProgram:
    """The IK program of an arm of the three-parallel class (module docstring; the steps of
    :mod:`derive.ik.parallel3`):

    0. the pose's rotation R and translation t; R_06 = R R_6T^T, the wrist point's
       p_16 = t - p_0 - R_06 p_6;
    1. q1, subproblem 4: h_2^T R(-h_1, q1) p_16 = h_2^T (p_1 + ... + p_4), two roots (free, 0,
       where p_16 lies on axis 1); R_t = R_1^T R_06 and R_1^T p_16;
    2. q5, subproblem 4: h_2^T R(h_5, q5) h_6 = h_2^T R_t h_6, two roots;
    3. q6, subproblem 1: R(-h_6, q6) R_5^T h_2 = R_t^T h_2 (free, 0, where R_5^T h_2 is along h_6);
    4. theta = q2 + q3 + q4, subproblem 1: R(h_2, theta) x = R_t R_6^T R_5^T x, x across h_2;
    5. q3, subproblem 3: ||R(h_2, q3) p_3 + p_2|| = ||v||, v = R_1^T p_16 - p_1 - R(h_2, theta) p_4,
       two roots;
    6. q2, subproblem 1: R(h_2, q2)(p_2 + R(h_2, q3) p_3) = v; q4 = theta - q2 - q3.
    """
    if geo.layout == "sp6":
        return parallel3_sp6_program(robot, geo)
    bld, h, p, r06, p16 = _pose_lets(geo)
    # 1. q1 (subproblem 4 about -h_1)
    d1 = _dot(h[1], [sum(p[k][i] for k in range(1, 5)) for i in range(3)])
    a0, a1, b1 = (bld.tmp(sp.expand(e), "a") for e in _sp4_line(h[1], [-x for x in h[0]], p16, d1))
    na1 = bld.let("na1", a0 * a0 + a1 * a1)
    sing_sh = bld.flag("singular_sh", na1 < SP_FREE_ANGLE ** 2)
    disc1 = bld.let("disc1", na1 - b1 * b1)
    bld.require(disc1 >= -REACH_TOL * sp.Max(1, b1 * b1))
    root1 = bld.let("root1", sp.sqrt(pos(disc1)))
    sg1 = bld.branch("sg1", "q1, shoulder (subproblem 4)")
    q1 = bld.select("q1", sing_sh, 0, sp.atan2(a0 * b1 + sg1 * root1 * a1, a1 * b1 - sg1 * root1 * a0))
    rt, u16 = _shoulder_lets(bld, h, q1, r06, p16)
    # 2. q5 (subproblem 4 about h_5)
    rt6 = [sp.expand(_dot(rt[i], h[5])) for i in range(3)]             # R_t h_6
    a5 = _sp4_line(h[1], h[4], h[5], 0)
    # an ortho wrist (h_5 across h_2 and h_6): |a| = 1 and 1 - c^2 = |h_2 x R_t h_6|^2, exact at
    # the wrist singularity (derive.ik.parallel3._wrist_roots)
    across = _cross(h[1], rt6)
    q5, s5, c5 = _root_of_unit_line(bld, "q5", a5[:2], sp.expand(_dot(h[1], rt6) - _dot(h[1], h[4]) * _dot(h[4], h[5])),
                                    "q5, wrist (subproblem 4)",
                                    sp.expand(_dot(across, across)) if geo.ortho_wrist else None)
    _wrist_and_arm(bld, geo, h, p, rt, u16, (q1, q5, s5, c5), sing_sh, p[4])
    steps = [
        ("pose, wrist point", "R_06 = R R_6T^T, p_16 = t - p_0 - R_06 p_6",
         [f"three-parallel class, product-of-exponentials mismatch {geo.error:.1g}"]),
        ("q1", "subproblem 4", ["h2^T R(-h1, q1) p16 = h2^T (p1 + p2 + p3 + p4)"]),
        ("q5", "subproblem 4", ["h2^T R(h5, q5) h6 = h2^T R1^T R06 h6"]),
        ("q6", "subproblem 1", ["R(-h6, q6) R5^T h2 = (R1^T R06)^T h2"]),
        ("q2 + q3 + q4", "subproblem 1", ["R(h2, theta) = R1^T R06 R6^T R5^T"]),
        ("q3", "subproblem 3", ["||R(h2, q3) p3 + p2|| = ||R1^T p16 - p1 - R(h2, theta) p4||"]),
        ("q2", "subproblem 1", ["R(h2, q2) (p2 + R(h2, q3) p3) = R1^T p16 - p1 - R(h2, theta) p4"]),
        ("q4", "span", ["q4 = theta - q2 - q3"]),
    ]
    return IKProgram(robot.name, 6, ops=bld.ops, branches=8, free_joint=5,
                     free_rule=("set to 0 (and q1 is set to 0 where the wrist point, where axes 5 and "
                                "6 meet, lies on axis 1)"),
                     singular_doc="axis 6 parallel to axes 2, 3, 4",
                     steps_source="IK-Geo's subproblems, the robot's numbers substituted",
                     steps=steps, parameters={}, branch_labels=list(bld.labels))




def _coef_row(h, k, v) -> tuple:
    """(h . (k x v), h . (v - (k . v) k)) and the axial part (h . k)(k . v): h^T R(k, t) v =
    axial + row . (sin t, cos t) (module docstring)."""
    kv = _dot(k, v)
    return (_dot(_cross(k, v), h), _dot(v, h) - kv * _dot(k, h)), _dot(h, k) * kv


def parallel3_sp6_program(robot, geo: P3Geometry) -> IKProgram:
    """The IK program of the three-parallel layout with axes 5 and 6 not meeting (IK-Geo's
    ``IK_3_parallel``; the steps of :func:`derive.ik.parallel3.solve_batch_sp6`):

    0. as :func:`parallel3_program`, p_16 now a point of axis 6;
    1-2. (q1, q5), subproblem 6: projected on h_2,
         h_2^T R(-h_1, q1) p_16 + h_2^T R(h_5, q5)(-p_5) = h_2^T (p_1 + p_2 + p_3 + p_4),
         h_2^T R(-h_1, q1) R_06 h_6 + h_2^T R(h_5, q5)(-h_6) = 0,
         that is M_a x_1 + M_b x_5 = b with x = (sin, cos). M_b is a constant of the arm
         (|det M_b| / |M_b|^2 at least SP6_BLOCK_MIN, else DeriveError): x_5 = adj(M_b)(b - M_a x_1)
         / det, and |x_5|^2 = 1 is a trigonometric polynomial of degree 2 in q1 (numpy's
         ``two_circles``, with its b-block fixed to q5's), whose up to 4 real roots (a "roots4"
         line, :meth:`derive.ik.ir.Builder.roots4`: real roots first, ascending) the two high
         branch bits select. A slot is kept when its root is real and the two equations' residual
         at (q1, q5) is within SP_EXACT_TOL (the numpy subproblem's test). q1 is free where M_a
         vanishes (a column norm of the row-scaled M below SP_RANK_TOL: p_16 and R_06 h_6 both on
         axis 1): 0 in slot 0, flag ``singular_sh``. Where q1 is a (near-)double root of the
         quartic (|F'(q1)| below SP6_DOUBLE_ROOT times the sum of |coefficients|; at the wrist
         singularity q5 = 0 among others) it is good to about the square root of the rounding
         only, and the solution may miss the pose by up to about 2e-7: flag ``singular_dr``, ORed
         into ``singular`` (solve_batch_sp6 drops such a candidate at its FK check instead;
         docs/ik.md says why the kernels keep it flagged);
    3-6. as :func:`parallel3_program`, with p_4 + R(h_5, q5) p_5 for p_4 in step 5.

    Branch k = 2 i6 + i3 = 4 ia + 2 ib + i3 (slot i6 = 2 ia + ib), as
    :func:`derive.ik.parallel3.solve_batch_sp6`, whose slots are in the same order (real
    solutions of subproblem 6 first, ascending in q1).
    """
    hf = [np.asarray(v, dtype=float) for v in geo.h]
    mbf = np.array([_coef_row(hf[1], hf[4], -geo.p[5])[0], _coef_row(hf[1], hf[4], -hf[5])[0]], dtype=float)
    detf = float(np.linalg.det(mbf))
    if not abs(detf) >= SP6_BLOCK_MIN * float(np.sum(mbf ** 2)):
        raise DeriveError(f"{robot.name}: no IK program for this three-parallel arm with axes 5 and 6 not "
                          f"meeting: the q5 block of its subproblem 6 is singular (|det| {abs(detf):.3g}); "
                          "derive.reference.ik solves it (derive.ik.parallel3.solve_batch_sp6), and the "
                          "kernels run the general 6R elimination")
    bld, h, p, r06, p16 = _pose_lets(geo)
    mh0, mp5, mh6 = [-x for x in h[0]], [-x for x in p[5]], [-x for x in h[5]]
    # 1-2. subproblem 6: rows (q1 block, pose dependent | q5 block, constant) and right side
    r06h6 = _lets(bld, "hb", [_dot(r06[i], h[5]) for i in range(3)])          # R_06 h_6
    (ma0, ax0), (ma1, ax1) = _coef_row(h[1], mh0, p16), _coef_row(h[1], mh0, r06h6)
    (mb0, bx0), (mb1, bx1) = _coef_row(h[1], h[4], mp5), _coef_row(h[1], h[4], mh6)
    mb = [[_number(x) for x in mb0], [_number(x) for x in mb1]]
    det = _number(detf)
    d1 = _dot(h[1], [sum(p[k][i] for k in range(1, 5)) for i in range(3)])
    ma = [_lets(bld, "ma0", ma0), _lets(bld, "ma1", ma1)]
    bb = _lets(bld, "bq", [d1 - ax0 - bx0, -ax1 - bx1])
    adj = [[mb[1][1], -mb[0][1]], [-mb[1][0], mb[0][0]]]
    g = _lets(bld, "gq", [adj[i][0] * bb[0] + adj[i][1] * bb[1] for i in range(2)])     # adj b
    gm = [_lets(bld, f"gm{i}", [adj[i][0] * ma[0][j] + adj[i][1] * ma[1][j] for j in range(2)])
          for i in range(2)]                                                          # adj M_a
    p00 = gm[0][0] ** 2 + gm[1][0] ** 2
    p11 = gm[0][1] ** 2 + gm[1][1] ** 2
    p01 = gm[0][0] * gm[0][1] + gm[1][0] * gm[1][1]
    lin = [gm[0][j] * g[0] + gm[1][j] * g[1] for j in range(2)]
    coef = [sp.expand(e) for e in (g[0] ** 2 + g[1] ** 2 - det ** 2 + (p00 + p11) / 2, -2 * lin[1],
                                    -2 * lin[0], (p11 - p00) / 2, p01)]
    cf = [e if e.is_number else bld.let(f"cq{i}", e) for i, e in enumerate(coef)]
    roots, oks = bld.roots4("rq", cf)
    # q1 free where the q1 block of the row-scaled M vanishes (numpy's two_circles: free_a)
    na = _lets(bld, "naq", [sum(x * x for x in row) for row in ma])
    rn2 = [na[i] + _number(sum(float(x) ** 2 for x in mb[i])) for i in range(2)]
    sing_sh = bld.flag("singular_sh", na[0] * rn2[1] + na[1] * rn2[0] < SP_RANK_TOL ** 2 * rn2[0] * rn2[1])
    sga = bld.branch("sg6a", "sp6 solution (bit 2 of 2)")
    ra = [bld.select(f"rqa{j}", sga > 0, roots[j], roots[2 + j]) for j in range(2)]
    va = [bld.select(f"vqa{j}", sga > 0, oks[j], oks[2 + j]) for j in range(2)]
    sgb = bld.branch("sg6b", "sp6 solution (bit 1 of 2)")
    t1 = bld.select("t1q", sgb > 0, ra[0], ra[1])
    v1 = bld.select("v1q", sgb > 0, va[0], va[1])
    # slot 0 alone where q1 is free
    valid = bld.select("vq", sing_sh, pos(sga) * pos(sgb), v1)
    bld.require(valid > 0.5)
    q1 = bld.select("q1", sing_sh, 0, t1)
    c1, s1 = sp.cos(q1), sp.sin(q1)
    # a (near-)double root of the quartic is only good to about the square root of the rounding
    # (FK errors up to 1e-7 at the wrist singularity q5 = 0): flag singular_dr where
    # |F'(q1)| < SP6_DOUBLE_ROOT (|A0| + |A1| + |B1| + |A2| + |B2|)
    dfq = bld.let("dfq", -cf[1] * s1 + cf[2] * c1 - 2 * cf[3] * sp.sin(2 * q1) + 2 * cf[4] * sp.cos(2 * q1))
    sing_dr = bld.flag("singular_dr", sp.Abs(dfq) < SP6_DOUBLE_ROOT * sum(sp.Abs(e) for e in cf))
    # x_5 det = adj (b - M_a x_1) = g - adj(M_a) x_1; q5 from it, its residual in both equations
    nq = _lets(bld, "nq", [g[i] - gm[i][0] * s1 - gm[i][1] * c1 for i in range(2)])
    nn = bld.let("nnq", nq[0] ** 2 + nq[1] ** 2)
    rn = bld.let("rnq", sp.Max(sp.sqrt(nn), sp.Float(1e-150)))     # rnq^2 stays normal
    mbn = [sp.expand(mb[i][0] * nq[0] + mb[i][1] * nq[1]) for i in range(2)]
    res2 = bld.let("resq", (mbn[0] ** 2 + mbn[1] ** 2) * (abs(det) - rn) ** 2 / (rn ** 2 * det ** 2))
    bld.require(res2 <= SP_EXACT_TOL ** 2)
    sgn = 1 if detf > 0 else -1
    s5 = bld.let("q5_s", sgn * nq[0] / rn)
    c5 = bld.let("q5_cs", sgn * nq[1] / rn)
    q5 = bld.let("q5", sp.atan2(sgn * nq[0], sgn * nq[1]))
    bld.set_trig(q5, s5, c5)
    rt, u16 = _shoulder_lets(bld, h, q1, r06, p16)
    p45 = [p[4][i] + e for i, e in enumerate(_rot_vec(h[4], c5, s5, p[5]))]    # p_4 + R_5 p_5
    _wrist_and_arm(bld, geo, h, p, rt, u16, (q1, q5, s5, c5), sp.Or(sing_sh, sing_dr), p45)
    steps = [
        ("pose, point of axis 6", "R_06 = R R_6T^T, p_16 = t - p_0 - R_06 p_6",
         [f"three-parallel class (axes 5 and 6 not meeting), product-of-exponentials mismatch {geo.error:.1g}"]),
        ("q1, q5", "subproblem 6", ["h2^T R(-h1, q1) p16 + h2^T R(h5, q5) (-p5) = h2^T (p1 + p2 + p3 + p4)",
                                    "h2^T R(-h1, q1) R06 h6 + h2^T R(h5, q5) (-h6) = 0",
                                    "x5 = adj(Mb) (b - Ma x1) / det Mb, |x5| = 1: a quartic in tan(q1 / 2)"]),
        ("q6", "subproblem 1", ["R(-h6, q6) R5^T h2 = (R1^T R06)^T h2"]),
        ("q2 + q3 + q4", "subproblem 1", ["R(h2, theta) = R1^T R06 R6^T R5^T"]),
        ("q3", "subproblem 3", ["||R(h2, q3) p3 + p2|| = ||R1^T p16 - p1 - R(h2, theta) (p4 + R5 p5)||"]),
        ("q2", "subproblem 1", ["R(h2, q2) (p2 + R(h2, q3) p3) = R1^T p16 - p1 - R(h2, theta) (p4 + R5 p5)"]),
        ("q4", "span", ["q4 = theta - q2 - q3"]),
    ]
    return IKProgram(robot.name, 6, ops=bld.ops, branches=8, free_joint=5,
                     free_rule=("set to 0 (and q1 is set to 0 where both p16 and R06 h6 lie on "
                                "axis 1, the q1 block of subproblem 6 vanishing)"),
                     singular_doc="axis 6 parallel to axes 2, 3, 4",
                     steps_source="IK-Geo's subproblems, the robot's numbers substituted",
                     steps=steps, parameters={}, branch_labels=list(bld.labels))
