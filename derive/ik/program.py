"""Straight-line IK programs for the generated kernels, from the extracted closed forms.

:mod:`derive.ik.extract` finds, for a 6R chain, a solving order and the equations of each
step (patterns S1, S2, S3, span). This module turns those steps into a program of
assignments, branch points and reachability checks that the emitters print as pure
Python, numpy and C. The expressions are the derived ones (coefficients A, B, C of the
S1 equation, the 2x2 systems of the S2 pairs, the sum of squares of the S3 pair, the
span combinations), with the robot's numbers substituted. Three rewrites make the
program total and accurate (the extraction's forms divide by quantities that vanish at
the singular sets):

* **S2 without division.** A pair a1 cos u + b1 sin u + c1 = 0, a2 cos u + b2 sin u + c2 = 0
  gives cos u = n_c / d, sin u = n_s / d after cancelling common factors; the program
  computes u = atan2(sgn(d) n_s, sgn(d) n_c), so d may be anywhere near zero, and
  hypot(n_c, n_s) = |d|.
* **Half angles from the S2 magnitudes.** An S1 step solved by acos (cos u = v, e.g. theta5
  from B.13) loses accuracy near u = 0 and pi. When later S2 steps have the divisors
  k sin(u/2) and k' cos(u/2) (B.30/B.32 and B.29/B.31 for theta5), the program takes
  |sin(u/2)| and |cos(u/2)| from their magnitudes and u = +-2 atan2(|sin|, |cos|): exact
  to rounding at u = 0 and u = pi.
* **Singular steps.** Where sin u = 0 (the wrist singularity) one of those S2 steps is
  undetermined; the span step that relates the two compounds (theta6 = sigma2 - sigma1)
  then takes its joint (free there) at the value that puts the later S3 step mid-reach
  (:func:`_free_for_reach`), and the undetermined compound follows.

Reachability: an S1 step with A^2 + B^2 < C^2, or an acos argument beyond +-1, by more than
:data:`derive.ik.closed_form.REACH_TOL` (relative), drops the branch; within it the root is clipped.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sympy as sp

from derive.algebra import dualquat as dq
from derive.algebra.quaternion import dual_hamilton, hamilton
from derive.cache import memo
from derive.errors import DeriveError, InputError
from derive.ik import class_programs
from derive.ik.closed_form import URGeometry, closed_form_relation, parallel3_class, spherical_class, ur_geometry
from derive.ik.ir import Builder, IKProgram, Op, pos, sgn
from derive.ik.program7 import SRS_JOINTS_GIVEN, seven_joint_program
from derive.ik.program_parallel3 import parallel3_program
from derive.ik.redundant import free_choice, redundant_kind
from derive.ik.extract import R_SYMS, _as_linear_in, _linear_form, _rot, extract
from derive.ik.spherical import SWGeometry, canonical_robot
from derive.ik.tolerances import REACH_TOL, WRIST_SINGULAR
from derive.model.robot import load_robot, robot_from_dict
from derive.symbolic.chain import runs_quaternion
from derive.symbolic.equations import POSES, derive_equations

#: The free parameters of the SRS programs with a joint given besides the class's own choices
SRS_JOINT_FREE = tuple(f"q{j}" for j in SRS_JOINTS_GIVEN)


def _chain_pose(builder: Builder, g):
    """Lines for the chain pose (pose * G^-1) from the input p0..p7: w a b c, r_ij, x y z."""
    p = sp.symbols("p0:8", real=True)
    builder.known.update(p)
    gq, gt = g
    gconj = (gq[0], -gq[1], -gq[2], -gq[3])
    quat = hamilton(p[:4], gconj)
    w, a, b, c, x, y, z = POSES["B"]
    for sym, e in zip((w, a, b, c), quat):
        builder.let(sym, sp.expand(e))
    # robot translation t = 2 dual real^* (vector part); chain translation t - R_chain g_t
    preal_conj = (p[0], -p[1], -p[2], -p[3])
    t = [2 * e for e in hamilton(p[4:], preal_conj)[1:]]
    r = _rot((w, a, b, c))
    for i in range(3):
        for j in range(3):
            builder.let(R_SYMS[i, j], r[i, j])
    for i, sym in enumerate((x, y, z)):
        builder.let(sym, sp.expand(t[i] - sum(R_SYMS[i, k] * gt[k] for k in range(3))))


def _s2_pair(eqs, ids, form, thetas, u):
    """(n_s, n_c, d) of a pair of equations linear in (cos v, sin v) of the compound ``form``:
    cos v = n_c / d, sin v = n_s / d (common factors cancelled), as :func:`_s2_data`."""
    (a1, b1, c1), (a2, b2, c2) = (_as_linear_in(eqs[i], form, thetas, u) for i in ids)
    det = sp.expand(a1 * b2 - a2 * b1)
    nc = sp.expand(-c1 * b2 + c2 * b1)
    ns = sp.expand(-a1 * c2 + a2 * c1)
    g = sp.gcd(sp.gcd(nc, ns), det)
    return sp.cancel(ns / g), sp.cancel(nc / g), sp.cancel(det / g)


def _s2_data(step, eqs, form, thetas):
    """(n_s, n_c, d) of an S2 step: cos u = n_c / d, sin u = n_s / d, common factors cancelled."""
    return _s2_pair({i: eqs[i].lhs - eqs[i].rhs for i in step.equations}, step.equations, form, thetas,
                    sp.Symbol("u", real=True))


def _half_factor(d, u):
    """k if d = k sin(u/2) or k cos(u/2) (k a constant), with "sin"/"cos"; else None."""
    for f in (sp.sin, sp.cos):
        k = sp.simplify(d / f(u / 2))
        if not k.free_symbols:
            return f.__name__, k
    return None


def ik_program(robot, free: str | None = None) -> IKProgram:
    """The IK program of a robot (raises DeriveError for chains whose extraction it cannot use);
    cached per robot identity. ``free``: a 7-joint arm's free parameter where its class offers a
    choice (:func:`derive.ik.redundant.free_choice`: "q3" instead of psi for the SRS class), or
    for the SRS class one of q1, q2, q5, q6, q7 (:func:`derive.ik.program7.srs_joint_program`: the
    programs of the class routes of :mod:`derive.ik.free_joint`, whose C the free-joint kernels
    run, :mod:`derive.codegen.free_joint`)."""
    robot = load_robot(robot)
    if not (free in SRS_JOINT_FREE and redundant_kind(robot) == "srs"):
        free = free_choice(robot, free)
    return memo("ik-program", (robot.id, free), lambda: _ik_program(robot, free))


def _ik_program(robot, free) -> IKProgram:
    kind = redundant_kind(robot)
    if kind is not None:
        return seven_joint_program(robot, kind, free)
    geo = spherical_class(robot)
    if geo is not None:
        return _spherical_program(robot, geo)
    p3 = parallel3_class(robot)
    if p3 is not None:
        return parallel3_program(robot, p3)
    try:
        ur = ur_geometry(robot)
    except DeriveError:
        rel = closed_form_relation(robot)
        if rel is not None:
            return _related_program(robot, rel)
    else:
        return _ur_program(robot, ur)
    if not robot.exact:
        raise DeriveError(f"{robot.name}: no closed-form IK kernel: the description's fixed angles "
                          "are not all multiples of pi/12, so there are no exact equations to "
                          "solve; use derive.refine for the IK")
    return _extracted_program(robot)


def _extracted_program(robot, keep_symbols: bool = False) -> IKProgram:
    """The program from the extraction on the robot's own derived equations, the robot's numbers
    substituted (``keep_symbols``: its length parameters kept as symbols, for a class's shipped
    program, :mod:`derive.ik.class_programs`)."""
    ext = extract(robot)
    chain = ext.chain
    _, sets = derive_equations(robot, symbolic=False)
    eqs = {e.id: e for s in sets for e in s.equations}
    thetas = [j.theta for j in chain.joints]
    loc = {str(t): t for t in thetas}
    values = {k: (sp.Integer(int(v)) if float(v).is_integer() else sp.Float(v, 17))
              for k, v in chain.parameters.items()}
    bld = Builder({} if keep_symbols else values)
    _chain_pose(bld, chain.end_transform)
    defs = {k: v for k, v in ext.definitions.items()}
    emitted_defs: set = set()

    def with_defs(expr):
        """Emit the intermediate coordinates an expression needs (once their angles are known)."""
        expr = sp.sympify(expr)
        for s in sorted(expr.free_symbols & set(defs), key=str):
            if s not in emitted_defs:
                bld.let(s, defs[s])
                emitted_defs.add(s)
        return expr

    forms = {st.symbol: _linear_form(sp.sympify(st.unknown, locals=loc), thetas) for st in ext.steps}
    s2 = {st.symbol: _s2_data(st, eqs, forms[st.symbol], thetas) for st in ext.steps if st.pattern == "S2"}
    prog = IKProgram(robot.name, robot.dof, parameters=dict(chain.parameters))
    value: dict = {}                      # unknown symbol -> program symbol holding its value
    handled: set = set()
    sing = None
    n_branch = 0
    for st in ext.steps:
        prog.steps.append((st.unknown, st.pattern, list(st.equations)))
        if st.symbol in handled:
            continue
        u = st.symbol
        if st.pattern == "S1" and not _is_acos(st):
            a, b, c = _as_linear_in(eqs[st.equations[0]].lhs - eqs[st.equations[0]].rhs,
                                    forms[u], thetas, sp.Symbol("u", real=True))
            a, b, c = (with_defs(e) for e in (a, b, c))
            ka, kb, kc = bld.tmp(a), bld.tmp(b), bld.tmp(c)
            disc = bld.tmp(ka * ka + kb * kb - kc * kc)
            phi = bld.tmp(sp.atan2(kb, ka))
            psi = bld.tmp(sp.atan2(sp.sqrt(pos(disc)), -kc))
            bld.require(disc >= -REACH_TOL * sp.Max(1, kc * kc))
            n_branch += 1
            sg = bld.branch(f"sg{n_branch}", str(u))
            value[u] = bld.let(str(u), phi + sg * psi)
        elif st.pattern == "S1":
            # acos step: cos u = v. Look for later S2 steps divided by k sin(u/2), k' cos(u/2).
            halves = {}
            for sym, (ns, nc, d) in s2.items():
                hf = _half_factor(d, u)
                if hf:
                    halves[hf[0]] = (sym, ns, nc, hf[1])
            if set(halves) != {"sin", "cos"}:
                raise DeriveError(f"{robot.name}: the acos step for {u} has no accurate half-angle "
                                  "form (no S2 pair divided by sin and cos of its half)")
            mags = {}
            for kind, (sym, ns, nc, k) in halves.items():
                ns, nc = with_defs(ns), with_defs(nc)
                mags[kind] = bld.tmp(sp.sqrt(ns * ns + nc * nc) / abs(k), "h")
            hs, hc = mags["sin"], mags["cos"]
            half = bld.tmp(sp.atan2(hs, hc), "h")
            sing_val = bld.tmp(2 * hs * hc / (hs * hs + hc * hc), "h")
            span = next((s for s in ext.steps if s.pattern == "span"
                         and {halves["sin"][0], halves["cos"][0]} <= s.forms[0].free_symbols), None)
            if span is None:
                raise DeriveError(f"{robot.name}: no span step relates the compounds of {u}")
            # the two S2 compounds: with u = +-2 half (|u| <= pi), cos(u/2) >= 0 and sin(u/2) has
            # the branch's sign, so sgn(d) is known and both atan2 are taken before the branch
            base = {}
            for kind in ("cos", "sin"):
                sym, ns, nc, k = halves[kind]
                sk = 1 if k > 0 else -1
                base[kind] = bld.tmp(sp.atan2(sk * ns, sk * nc), "h")
            free = span.symbol
            prog.free_joint = thetas.index(free)
            free_val = _free_for_reach(bld, ext, free, defs, with_defs)
            if free_val != 0:
                prog.free_rule = "chosen for reach (the cosine of the next acos step nearest to 0)"
            sing = bld.flag("singular", sing_val < WRIST_SINGULAR)
            cos_small = bld.flag("cos_small", hc < hs)
            n_branch += 1
            sg = bld.branch(f"sg{n_branch}", f"{u} sign")
            # at the singular set u is exactly 0 (sin small) or pi (cos small)
            at_sing = bld.select(f"{u}_singular", cos_small, sp.pi, 0)
            value[u] = bld.select(str(u), sing, at_sing, 2 * sg * half)
            raw = {"cos": base["cos"], "sin": bld.tmp(base["sin"] + sp.pi * (1 - sg) / 2, "h")}
            lhs = span.forms[0]
            s_sin, s_cos = halves["sin"][0], halves["cos"][0]
            # sin(u/2) = 0: the "sin" compound follows from the other and the free joint
            sol_sin = sp.solve(sp.Eq(free, lhs), s_sin)[0].xreplace({s_cos: raw["cos"], free: free_val})
            sol_cos = sp.solve(sp.Eq(free, lhs), s_cos)[0].xreplace({s_sin: raw["sin"], free: free_val})
            value[s_sin] = bld.select(str(s_sin), sp.And(sing, sp.Not(cos_small)), sol_sin, raw["sin"])
            value[s_cos] = bld.select(str(s_cos), sp.And(sing, cos_small), sol_cos, raw["cos"])
            handled.update({s_sin, s_cos})
        elif st.pattern == "S2":
            ns, nc, d = s2[u]
            ns, nc, d = (with_defs(e) for e in (ns, nc, d))
            sd = bld.tmp(sgn(d))
            value[u] = bld.let(str(u), sp.atan2(sd * ns, sd * nc))
        elif st.pattern == "S3":
            f = st.forms[0]
            if not isinstance(f, sp.acos):
                raise DeriveError(f"{robot.name}: S3 step for {u} is not an acos form")
            v = bld.tmp(with_defs(f.args[0]))
            bld.require(sp.Abs(v) <= 1 + REACH_TOL)
            sq = bld.tmp(sp.sqrt(pos(1 - v * v)))
            ang = bld.tmp(sp.atan2(sq, v))
            n_branch += 1
            sg = bld.branch(f"sg{n_branch}", str(u))
            value[u] = bld.let(str(u), sg * ang)
            bld.set_trig(u, sg * sq, v)                  # sin u, cos u known exactly
        elif st.pattern == "span":
            value[u] = bld.let(str(u), st.forms[0])
        else:
            raise DeriveError(f"{robot.name}: IK step pattern {st.pattern} has no kernel form")
    missing = [t for t in thetas if t not in value]
    if missing:
        raise DeriveError(f"{robot.name}: IK program has no value for {missing}")
    # joint variables of the robot in its order
    var_index = {j.name: j.variable for j in robot.joints}
    order = [None] * robot.dof
    for t, j in zip(thetas, chain.joints):
        order[var_index[j.name]] = value[t]
    bld.ops.append(Op("solution", args=tuple(order), depth=bld.depth))
    prog.ops = bld.ops
    prog.branches = 2 ** n_branch
    prog.branch_labels = list(bld.labels)
    return prog


def _number(x: float):
    x = float(x)
    return sp.Integer(int(x)) if x.is_integer() else sp.Float(x, 17)


def _related_program(robot, rel) -> IKProgram:
    """The IK program of a robot related to a library robot with a closed form
    (:func:`derive.ik.closed_form.closed_form_relation`: FK_robot(q) = B FK_lib(s q) T): the
    library robot's program after lines that move the pose into its frames (B^-1 P T^-1), its
    solutions' joint directions multiplied by s."""
    lib = ik_program(load_robot(rel.other))
    p = sp.symbols("p0:8", real=True)
    moved_syms = sp.symbols("pb0:8", real=True)
    conj_b = [_number(x) for x in dq.conj_quaternion(rel.base)]
    conj_t = [_number(x) for x in dq.conj_quaternion(rel.tool)]
    moved = dual_hamilton(dual_hamilton(conj_b, p), conj_t)
    rep = dict(zip(p, moved_syms))

    def subs(e):
        return e.xreplace(rep) if isinstance(e, sp.Basic) else e

    ops = [Op("let", str(s), sp.expand(e), depth=0) for s, e in zip(moved_syms, moved)]
    for op in lib.ops:
        args = op.args
        if op.kind == "solution":
            args = tuple(subs(sp.sympify(a)) * int(s) for a, s in zip(op.args, rel.signs))
        ops.append(Op(op.kind, op.name, subs(op.expr), op.name2, subs(op.cond), subs(op.other), args, op.depth))
    flips = [str(i + 1) for i, s in enumerate(rel.signs) if s < 0]
    steps = [(f"pose in the frames of {rel.other}", "B^-1 P T^-1",
              [f"base/tool transforms found by derive.kinematics.relate (mismatch {rel.error:.1g})"]
              + ([f"joints {', '.join(flips)} reversed"] if flips else []))] + list(lib.steps)
    return IKProgram(robot.name, robot.dof, ops=ops, branches=lib.branches, free_joint=lib.free_joint,
                     free_rule=lib.free_rule, steps=steps, parameters=dict(lib.parameters),
                     branch_labels=list(lib.branch_labels))


#: The UR family's chain in thesis form (:data:`derive.ik.closed_form.UR_AXES`) as a description
#: with its lengths as parameters (the UR5's values; the class program keeps them as symbols) and
#: the end frame of the UR arms' standard-DH descriptions (Rx(pi/2) after the thesis chain), so
#: that a standard-DH UR needs no pose transform before the shipped program.
UR_CANONICAL = {
    "name": "ur-canonical",
    "title": "UR family, chain in thesis form (axes z, -y, -y, -y, -z, -y)",
    "source": "thesis section 4.3.5; derive.ik.closed_form.ur_geometry",
    "convention": "axis_angle",
    "parameters": {"d1": 0.089159, "a2": -0.425, "a3": -0.39225, "d4": 0.10915, "d5": 0.09465,
                   "d6": 0.0823},
    "joints": [
        {"name": "j1", "axis": [0, 0, 1], "link": [0, 0, "d1"]},
        {"name": "j2", "axis": [0, -1, 0], "link": ["a2", 0, 0]},
        {"name": "j3", "axis": [0, -1, 0], "link": ["a3", "-d4", 0]},
        {"name": "j4", "axis": [0, -1, 0], "link": [0, 0, "-d5"]},
        {"name": "j5", "axis": [0, 0, -1], "link": [0, "-d6", 0]},
        {"name": "j6", "axis": [0, -1, 0], "link": [0, 0, 0]},
    ],
    "tool": {"rotation": {"axis": [1, 0, 0], "angle": "pi/2"}},
}

#: The UR class's length names (fields of :class:`derive.ik.closed_form.URGeometry`).
UR_PARAMETERS = ("d1", "a2", "a3", "d4", "d5", "d6")


def _clean(x: float) -> float:
    """A length read off the numeric chain (a sum of the description's numbers) to 15
    significant digits: -0.39225000000000004 is -0.39225 (a change below 1e-15 relative)."""
    return float(f"{float(x):.15g}")


def _dq_numbers(part_q, part_t, values: dict) -> np.ndarray:
    q = [float(sp.sympify(e).xreplace(values)) for e in part_q]
    t = [float(sp.sympify(e).xreplace(values)) for e in part_t]
    return dq.from_rt(np.array(q), np.array(t))


def _ur_program(robot, geo: URGeometry) -> IKProgram:
    """The IK program of a robot with the UR structure in its own frames
    (:func:`derive.ik.closed_form.ur_geometry`): the UR class's shipped program
    (:mod:`derive.ik.class_programs`, derived once on :data:`UR_CANONICAL`) with the robot's
    lengths substituted, after lines that move the pose into the canonical chain's end frame
    (P G^-1 G_c, G the robot's end transform after its chain, G_c the canonical one's) when the
    two end transforms differ. No symbolic derivation on the robot's own chain."""
    tpl, params, (gq, gt) = class_programs.ur_template()
    values = {params[k]: _number(_clean(getattr(geo, k))) for k in UR_PARAMETERS}
    g_c = _dq_numbers(gq, gt, values)
    move = dq._mul(dq.conj_quaternion(geo.g)[None], g_c[None])[0]
    p = sp.symbols("p0:8", real=True)
    ops = []
    rep = dict(values)
    if np.max(np.abs(move - dq.IDENTITY.reshape(8))) > 1e-15:
        moved_syms = sp.symbols("pb0:8", real=True)
        moved = dual_hamilton(p, [_number(x) if abs(x) > 1e-15 else sp.Integer(0) for x in move])
        ops = [Op("let", str(s), sp.expand(e), depth=0) for s, e in zip(moved_syms, moved)]
        rep.update(zip(p, moved_syms))

    def subs(e):
        return e.xreplace(rep) if isinstance(e, sp.Basic) else e

    for op in tpl.ops:
        args = tuple(subs(a) for a in op.args) if op.kind == "solution" else op.args
        ops.append(Op(op.kind, op.name, subs(op.expr), op.name2, subs(op.cond), subs(op.other), args, op.depth))
    steps = ([("pose in the canonical chain's end frame", "P G^-1 G_c", ["the robot's end transform G "
                                                                         "differs from the canonical chain's"])]
             if len(ops) > len(tpl.ops) else []) + list(tpl.steps)
    return IKProgram(robot.name, robot.dof, ops=ops, branches=tpl.branches, free_joint=tpl.free_joint,
                     free_rule=tpl.free_rule, steps=steps,
                     parameters={params[k]: _clean(getattr(geo, k)) for k in UR_PARAMETERS},
                     branch_labels=list(tpl.branch_labels))


def class_data() -> dict:
    """The class programs, derived now (the UR program from the extraction on
    :data:`UR_CANONICAL` with its lengths as symbols, the spherical-wrist forms from the
    canonical chain's equations), as the JSON data of :mod:`derive.ik.class_programs`."""
    canon = robot_from_dict(UR_CANONICAL)
    prog = _extracted_program(canon, keep_symbols=True)
    prog.parameters = {sp.Symbol(k, real=True): None for k in UR_PARAMETERS}
    chain = extract(canon).chain
    ur = {"program": class_programs.dump_program(prog),
          "g": [[class_programs.dump_expr(e) for e in part] for part in chain.end_transform]}
    sw = canonical_robot(SWGeometry("canonical", *(1.0,) * 7, base=dq.IDENTITY.reshape(8),
                                    tool=dq.IDENTITY.reshape(8), signs=np.ones(6),
                                    offsets=np.zeros(6), error=0.0))
    chain, sets = derive_equations(sw, symbolic=False)
    eqs = {e.id: sp.expand(e.lhs - e.rhs) for s in sets for e in s.equations}
    sf = spherical_forms(chain, eqs)
    dump = class_programs.dump_expr
    forms = {k: [dump(e) for e in getattr(sf, k)] for k in ("theta1", "theta3", "theta2")}
    forms.update({k: dump(getattr(sf, k)) for k in ("x_def", "z_def", "X", "Z")})
    forms["halves"] = {k: [dump(ns), dump(nc), dump(kk), list(ids)] for k, (ns, nc, kk, ids) in sf.halves.items()}
    spherical = {"thetas": [dump(j.theta) for j in chain.joints],
                 "parameters": [dump(k) for k in chain.parameters],
                 "axes": [[dump(a) for a in j.axis] for j in chain.joints[:3]],
                 "g": [[dump(e) for e in part] for part in chain.end_transform],
                 "forms": forms}
    return {"ur": ur, "spherical": spherical}


def write_class_data(path=None) -> str:
    """Derive the class programs (:func:`class_data`) and write them to ``path`` (default: the
    shipped file, :data:`derive.ik.class_programs.DATA`); returns the path."""
    path = class_programs.DATA if path is None else path
    text = class_programs.render(class_data())
    with open(path, "w", encoding="utf-8", newline="\n") as f:
        f.write(text)
    return str(path)


def _free_for_reach(bld: Builder, ext, free, defs: dict, with_defs):
    """Lines for the free joint's value at the singular set, chosen for reach.

    The later S3 step (theta3 from C.19, C.21) has cos u = v, where v depends on the free
    joint f through coordinates (x4, z4) linear in sin f, cos f. Written out, v = alpha +
    beta cos f + gamma sin f plus terms of second order whose sum is constant on the
    singular set (the wrist-1 point moves on a circle). The value solves v = 0 (the middle
    of the reach) when possible and otherwise takes f nearest to it:
    f = atan2(gamma, beta) + atan2(sqrt(max(R^2 - alpha^2, 0)), -alpha), R^2 = beta^2 + gamma^2.
    Without such an S3 step the free joint is 0.
    """
    s3 = next((st for st in ext.steps if st.pattern == "S3" and isinstance(st.forms[0], sp.acos)), None)
    if s3 is None:
        return sp.Integer(0)
    v = sp.sympify(s3.forms[0].args[0])
    dep = sorted((d for d in v.free_symbols & set(defs) if free in defs[d].free_symbols), key=str)
    if not dep:
        return sp.Integer(0)
    S, C = sp.symbols("S_free C_free", real=True)
    rep = {}
    for d in dep:
        e = sp.expand(sp.expand_trig(defs[d]).xreplace({sp.sin(free): S, sp.cos(free): C}))
        if free in e.free_symbols:
            return sp.Integer(0)
        poly = sp.Poly(e, S, C)
        if poly.total_degree() > 1:
            return sp.Integer(0)
        k0, ks, kc = (poly.coeff_monomial(m) for m in (1, S, C))
        k0, ks, kc = (bld.tmp(with_defs(k), "f") for k in (k0, ks, kc))
        rep[d] = k0 + ks * S + kc * C
    poly = sp.Poly(sp.expand(with_defs(v.xreplace(rep))), S, C)
    if poly.total_degree() > 2:
        return sp.Integer(0)
    co = {m: poly.coeff_monomial(m) for m in (1, S, C, S * S, C * C)}
    alpha = bld.tmp(co[1] + (co[S * S] + co[C * C]) / 2, "f")
    beta, gamma = bld.tmp(co[C], "f"), bld.tmp(co[S], "f")
    disc = bld.tmp(beta * beta + gamma * gamma - alpha * alpha, "f")
    return bld.tmp(sp.atan2(gamma, beta) + sp.atan2(sp.sqrt(pos(disc)), -alpha), "f")


def _is_acos(step) -> bool:
    return all(isinstance(f, sp.acos) or (isinstance(f, sp.Mul) and f.args[0] == -1
                                           and isinstance(f.args[1], sp.acos)) for f in step.forms)


# --------------------------------------------------------------------------- #
# Spherical-wrist class (derive.ik.spherical)
# --------------------------------------------------------------------------- #
@dataclass
class SphericalForms:
    """The symbolic pieces of the spherical-wrist closed form, taken from the class's equations
    (parameters a1 ... c4 as symbols): the S1 coefficients (A, B, C) of theta1 (P.13, C = -b)
    and of theta3 (sum of squares of P.12, P.14, in the arm-plane coordinates X, Z, whose
    definitions are ``x_def``, ``z_def``), the S2 numerators and divisor of theta2 and of the
    wrist compounds (t4 + t6)/2 ("cos": divided by k cos(t5/2)) and (t4 - t6)/2 ("sin")."""

    theta1: tuple
    theta3: tuple
    theta2: tuple
    x_def: object
    z_def: object
    halves: dict
    X: sp.Symbol
    Z: sp.Symbol


def spherical_forms(chain, eqs: dict) -> SphericalForms:
    """:class:`SphericalForms` from the equations (id -> lhs - rhs) of the sets P and O."""
    thetas = [j.theta for j in chain.joints]
    t1, t2, t3, t4, t5, t6 = thetas
    u = sp.Symbol("u", real=True)
    par = {str(k): k for k in chain.parameters}
    a, b, c = _as_linear_in(eqs["P.13"], _linear_form(t1, thetas), thetas, u)
    if sp.expand(c - par["b"]) == 0:
        a, b, c = -a, -b, -c
    if sp.expand(c + par["b"]) != 0:
        raise DeriveError(f"{chain.robot}: P.13 is not the theta1 equation of the class")
    X, Z = sp.Symbol("X", real=True), sp.Symbol("Z", real=True)
    sides = {}
    for eid, sym in (("P.12", X), ("P.14", Z)):
        e = eqs[eid]
        known = sum(t for t in e.as_ordered_terms() if not (t.free_symbols & {t2, t3}))
        sides[sym] = (sp.expand(e - known), sp.expand(-known))      # theta2,3 part = known part
    lhs2 = sp.expand(sp.trigsimp(sp.expand(sp.expand_trig(sides[X][0] ** 2 + sides[Z][0] ** 2))))
    if t2 in lhs2.free_symbols:
        raise DeriveError(f"{chain.robot}: the sum of squares of P.12, P.14 keeps theta2")
    th3 = _as_linear_in(sp.expand(lhs2 - X * X - Z * Z), _linear_form(t3, thetas), thetas, u)
    pair = {"P.12": sides[X][0] - X, "P.14": sides[Z][0] - Z}
    th2 = tuple(sp.factor_terms(sp.trigsimp(e))
                for e in _s2_pair(pair, ("P.12", "P.14"), _linear_form(t2, thetas), thetas, u))
    halves = {}
    for ids, form in ((("O.15", "O.18"), (0, 0, 0, sp.S.Half, 0, sp.S.Half)),
                      (("O.16", "O.17"), (0, 0, 0, sp.S.Half, 0, -sp.S.Half))):
        ns, nc, d = _s2_pair(eqs, ids, form, thetas, u)
        hf = _half_factor(d, t5)
        if hf is None:
            raise DeriveError(f"{chain.robot}: {ids} are not divided by a half angle of theta5")
        halves[hf[0]] = (ns, nc, hf[1], ids)
    if set(halves) != {"sin", "cos"}:
        raise DeriveError(f"{chain.robot}: the wrist pairs do not give sin and cos of theta5/2")
    return SphericalForms((a, b, c), th3, th2, sides[X][1], sides[Z][1], halves, X, Z)


def _spherical_program(robot, geo: SWGeometry) -> IKProgram:
    """The IK program of a spherical-wrist arm, from the equations of its class's canonical chain
    (:mod:`derive.symbolic.equations`, sets P and O) with the robot's numbers substituted.

    Steps (equation ids of the sets P and O):

    0. the pose moved into the canonical chain's frames (B^-1 P T^-1) and the wrist centre
       (x_w, y_w, z_w) = p - R (0, 0, c4), the chain end frame without its tool;
    1. theta1 from P.13, A cos t1 + B sin t1 + C = 0 with C = -b: t1 = atan2(A, -B) -
       atan2(-C, +-sqrt(A^2 + B^2 - C^2)), two branches; unreachable when A^2 + B^2 < C^2
       (the wrist centre nearer axis 1 than b); on axis 1 (b = 0) the two branches are the two
       opposite arm planes;
    2. theta3 from P.12, P.14 by the sum of squares (theta2 drops out), an S1 equation in
       theta3, two branches, unreachable beyond the reach of the arm, clipped within
       :data:`REACH_TOL` (full stretch or fold of the elbow);
    3. theta2 from P.12, P.14 as a 2x2 system in (cos t2, sin t2), without division;
    4. the wrist from O.15-O.18, the quaternion of (Q1 Q2 Q3)^-1 N1 = Q4 Q5 Q6: cos(t5/2) and
       sin(t5/2) up to sign are the magnitudes of the pairs (O.15, O.18) and (O.16, O.17), the
       compounds (t4 + t6)/2 and (t4 - t6)/2 their S2 solutions, t5 = +-2 atan2(|sin|, |cos|)
       (exact at t5 = 0 and pi); at the wrist singularity (sin t5 below WRIST_SINGULAR) joint 4
       is free: the program takes the robot's q4 = 0 and joint 6 takes the rest.
    """
    tpl = class_programs.spherical_template()      # shipped: no derivation on the robot's chain
    thetas = tpl["thetas"]
    t1, t2, t3, t4, t5, t6 = thetas
    values = {tpl["parameters"][k]: _number(v) for k, v in geo.values.items()}

    def num(e):
        return sp.sympify(e).xreplace(values)

    bld = Builder({})          # numbers substituted here: the builder's trig names c1, c2 ...
    p = sp.symbols("p0:8", real=True)
    bld.known.update(p)
    # 0. pose in the canonical frames, chain end frame (tool removed), wrist centre
    conj_b = [_number(x) for x in dq.conj_quaternion(geo.base)]
    conj_t = [_number(x) for x in dq.conj_quaternion(geo.tool)]
    moved = [sp.expand(e) for e in dual_hamilton(dual_hamilton(conj_b, p), conj_t)]
    pb = list(p) if moved == list(p) else [bld.let(f"pb{i}", e) for i, e in enumerate(moved)]
    gq, gt = tpl["g"]
    if tuple(sp.sympify(e) for e in gq) != (1, 0, 0, 0):
        raise DeriveError(f"{robot.name}: the canonical chain's end transform has a rotation")
    qw = pb[:4]
    trans = [2 * e for e in hamilton(pb[4:], (qw[0], -qw[1], -qw[2], -qw[3]))[1:]]
    rot = _rot(qw)
    w_w, a_w, b_w, c_w, x_w, y_w, z_w = POSES["P"]
    g_t = [num(e) for e in gt]
    for i, sym in enumerate((x_w, y_w, z_w)):
        bld.let(sym, sp.expand(trans[i] - sum(rot[i, k] * g_t[k] for k in range(3))))
    sf = SphericalForms(**tpl["forms"])
    X, Z = sf.X, sf.Z
    # 1. theta1 (P.13)
    ka, kb, kc = (bld.tmp(num(e)) for e in sf.theta1)
    disc = bld.tmp(ka * ka + kb * kb - kc * kc)
    bld.require(disc >= -REACH_TOL * sp.Max(1, kc * kc))
    beta = bld.tmp(sp.atan2(ka, -kb))
    root = bld.tmp(sp.sqrt(pos(disc)))
    sg1 = bld.branch("sg1", "theta1, shoulder")
    bld.let(t1, beta - sp.atan2(-kc, sg1 * root))
    bld._trig(sp.sin(t1 / 2))       # the half angle first: the full angle then by doubling
    # 2. theta3 (P.12, P.14): the unknown sides squared and added lose theta2
    kx, kz = bld.tmp(num(sf.x_def), "w"), bld.tmp(num(sf.z_def), "w")
    ka, kb, kc = (bld.tmp(num(e).xreplace({X: kx, Z: kz})) for e in sf.theta3)
    disc = bld.tmp(ka * ka + kb * kb - kc * kc)
    bld.require(disc >= -REACH_TOL * sp.Max(1, kc * kc))
    phi = bld.tmp(sp.atan2(kb, ka))
    psi = bld.tmp(sp.atan2(sp.sqrt(pos(disc)), -kc))
    sg2 = bld.branch("sg2", "theta3, elbow")
    bld.let(t3, phi + sg2 * psi)
    # 3. theta2 (P.12, P.14 as a 2x2 system)
    ns, nc, d = (num(e).xreplace({X: kx, Z: kz}) for e in sf.theta2)
    sd = bld.tmp(sgn(d))
    bld.let(t2, sp.atan2(sd * ns, sd * nc))
    # 4. the wrist (O.15-O.18): O pose quaternion = (Q1 Q2 Q3)^-1 rotation of the chain pose
    w_r, a_r, b_r, c_r = POSES["O"][:4]
    ax = tpl["axes"]
    inv = runs_quaternion([(ax[2], -t3), (ax[1], -t2), (ax[0], -t1)])
    for sym, e in zip((w_r, a_r, b_r, c_r), hamilton(inv, qw)):
        bld.let(sym, sp.expand(e))
    halves = sf.halves
    mags, base = {}, {}
    for kind, (ns, nc, k, _) in halves.items():
        mags[kind] = bld.tmp(sp.sqrt(ns * ns + nc * nc) / abs(k), "h")
        sk = 1 if k > 0 else -1
        base[kind] = bld.tmp(sp.atan2(sk * ns, sk * nc), "h")
    hs, hc = mags["sin"], mags["cos"]
    half = bld.tmp(sp.atan2(hs, hc), "h")
    sing_val = bld.tmp(2 * hs * hc / (hs * hs + hc * hc), "h")
    free = _number(geo.offsets[3])          # the robot's q4 = 0
    sing = bld.flag("singular", sing_val < WRIST_SINGULAR)
    cos_small = bld.flag("cos_small", hc < hs)
    sg3 = bld.branch("sg3", "theta5, wrist")
    at_sing = bld.select("theta5_singular", cos_small, sp.pi, 0)
    bld.select(str(t5), sing, at_sing, 2 * sg3 * half)
    s_sum = base["cos"]                                           # (t4 + t6) / 2
    s_dif = bld.tmp(base["sin"] + sp.pi * (1 - sg3) / 2, "h")      # (t4 - t6) / 2
    bld.select(str(t4), sing, free, s_sum + s_dif)
    t6_sing = bld.select("theta6_singular", cos_small, free - 2 * s_dif, 2 * s_sum - free)
    bld.select(str(t6), sing, t6_sing, s_sum - s_dif)
    order = [int(s) * (t - _number(o)) for t, s, o in zip(thetas, geo.signs, geo.offsets)]
    bld.ops.append(Op("solution", args=tuple(order), depth=bld.depth))
    steps = [
        ("pose in the canonical chain's frames", "B^-1 P T^-1",
         [f"spherical-wrist class, relation mismatch {geo.error:.1g}"]),
        ("wrist centre", "W = p - R (0, 0, c4)", []),
        ("theta1", "S1", ["P.13"]),
        ("theta3", "S3", ["P.12", "P.14"]),
        ("theta2", "S2", ["P.12", "P.14"]),
        ("theta5", "half angles", ["O.15", "O.16", "O.17", "O.18"]),
        ("(theta4 + theta6)/2", "S2", ["O.15", "O.18"]),
        ("(theta4 - theta6)/2", "S2", ["O.16", "O.17"]),
        ("theta4, theta6", "span", []),
    ]
    return IKProgram(robot.name, robot.dof, ops=bld.ops, branches=8, free_joint=3,
                     free_rule="set to the robot's q4 = 0, joint 6 taking the rest",
                     steps=steps, parameters=dict(geo.values), branch_labels=list(bld.labels))
