"""Flat expressions for the generated kernels, from the derived chain products.

The forward kinematics of a robot is M_1 G (:mod:`derive.symbolic.chain`): the product of the
joint dual quaternions in thesis form times the constant end transform. Its 8
components are built symbolically, the robot's numbers substituted, and written as a
sequence of assignments:

1. the sines and cosines the expressions need: one sin/cos pair per distinct angle
   argument (a half angle such as (q2+q3+q4)/2, or a full angle); a full angle whose
   half is also needed comes from the half by the double-angle formulas, which costs
   two multiplications instead of a sin/cos call, and an angle that is the sum or difference
   of two others from theirs by the addition theorem (four multiplications, two additions);
2. common subexpressions (sympy's ``cse``) over the 8 outputs.

The joint variables are ``q[0] .. q[n-1]``; the outputs are the unit dual quaternion
[real w x y z, dual w x y z] (dual = 1/2 t real) in the sign the product gives.

A robot that is not exact (a fixed angle that is not a multiple of pi/12: decimal DH
twists, calibrated arms, see :func:`derive.model.robot.is_exact`) has no exact equations
to fold. Its kernel is the product of the joint dual quaternions of the description's
neutral form (Kunze eq. 1.8, 5.28: each rotation cos(t/2) + sin(t/2) n, each translation
1 + eps v/2), with the fixed motions as numeric constants; the same steps 1 and 2 follow.
It takes no simplification, so it is made in about a second whatever the numbers.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import sympy as sp

from derive.algebra import dualquat as dq
from derive.algebra.quaternion import dual_hamilton, hamilton
from derive.cache import memo, step
from derive.errors import BudgetError, DeriveError
from derive.ik.closed_form import spherical_class, ur_geometry
from derive.ik.extract import _rot
from derive.model.geometry import path_to_end
from derive.ik.redundant import redundant_kind
from derive.model.robot import LIBRARY_DIR, load_robot
from derive.symbolic.equations import derive_equations


@dataclass
class Kernel:
    """Straight-line code: inputs q[0..n-1], temporaries, outputs."""

    robot: str
    dof: int
    # (name_s, name_c, how): how is the argument (an expression in q: a sin/cos call), or
    # ("double", half_s, half_c), or ("sum", s_x, c_x, s_y, c_y, sign) for the angle x + sign y
    trig: list = field(default_factory=list)
    temps: list = field(default_factory=list)     # (name, expr)
    outputs: list = field(default_factory=list)   # expr per output
    parameters: dict = field(default_factory=dict)
    n_sincos: int = 0


def _fk_symbolic(robot):
    """The 8 components of M_1 G from the folded left sides of M_1 = N_1 (set B)."""

    chain, sets = derive_equations(robot, symbolic=False)
    bset = sets[0]
    m1 = [e.lhs for e in bset.equations if e.i == 1]           # terms 1..7 of M_1
    q, p = m1[:4], m1[4:]
    gq, gt = (tuple(sp.sympify(v) for v in part) for part in chain.end_transform)
    if any(v != 0 for v in gt):
        rq = _rot(q)
        p = [p[i] + sum(rq[i, k] * gt[k] for k in range(3)) for i in range(3)]
    real = hamilton(q, gq)
    dual = tuple(e / 2 for e in hamilton((0, *p), real))
    return chain, tuple(real) + dual


def fk_kernel(robot) -> Kernel:
    """The FK kernel's straight-line code (cached per robot identity)."""
    robot = load_robot(robot)
    return memo("fk-kernel", robot.id, lambda: _fk_kernel(robot))


def _number(x) -> sp.Expr:
    x = float(x)
    return sp.Integer(int(x)) if x.is_integer() else sp.Float(x, 17)


def _constant(ops) -> np.ndarray:
    """The unit dual quaternion of a run of fixed motions, multiplied out numerically."""
    out = dq.IDENTITY.copy()
    for op in ops:
        m = dq._rotation(op.axis, op.angle) if op.kind == "R" else dq._translation_dq(op.vector)
        out = dq._mul(out, m)
    return np.asarray(out, dtype=float).reshape(8)


def _fk_numeric(robot, qs) -> Kernel:
    """The kernel of a robot that is not exact: the product of the joint dual quaternions along
    the path to the default end (module docstring), one joint per group of temporaries, each
    joint's fixed motions before and after its motion multiplied out to one constant."""
    k = Kernel(robot=robot.name, dof=robot.dof,
               parameters={sp.Symbol(n, real=True): v for n, v in robot.parameters.items()})
    path = path_to_end(robot)
    cur = None
    n_tmp = 0

    def fold(v):
        nonlocal n_tmp
        out = []
        for e in v:
            e = sp.sympify(e)
            if e.is_Number or e.is_Symbol:
                out.append(e)
                continue
            sym = sp.Symbol(f"t{n_tmp}")
            n_tmp += 1
            k.temps.append((sym, e))
            out.append(sym)
        return tuple(out)

    def const(c):
        return tuple(_number(x) if abs(x) > 0 else sp.Integer(0) for x in c)

    for idx in path:
        j = robot.joints[idx]
        value = _number(j.multiplier) * qs[j.variable] + _number(j.mimic_offset + j.offset)
        if j.type == "revolute":
            s, c = sp.Symbol(f"s{len(k.trig)}"), sp.Symbol(f"c{len(k.trig)}")
            k.trig.append((str(s), str(c), value / 2))
            m = (c, *(s * _number(a) for a in j.axis), 0, 0, 0, 0)
        else:
            m = (1, 0, 0, 0, 0, *(value * _number(a / 2) for a in j.axis))
        pre = const(_constant(j.pre))
        m = dual_hamilton(pre, m) if j.pre else m
        m = dual_hamilton(m, const(_constant(j.post))) if j.post else m
        cur = fold(m) if cur is None else fold(dual_hamilton(cur, fold(m)))
    end = robot.ends[robot.default_end].ops
    if cur is None:
        cur = const(_constant(end))
    elif end:
        cur = fold(dual_hamilton(cur, const(_constant(end))))
    k.n_sincos = len(k.trig)
    k.outputs = list(cur)
    return k


def _sums(called: list) -> dict:
    """The angles among ``called`` (arguments of sin/cos calls, linear in q) that are the sum or
    difference of two others, {angle: (x, y, sign)} with angle = x + sign y, x and y kept as
    calls: the sine and cosine of such an angle come from theirs by the addition theorem (four
    multiplications and two additions instead of a call): on the UR arms (q2 + q3 + q4 - q6) / 2
    is q2 + q3 + q4 minus (q2 + q3 + q4 + q6) / 2. Greedy and deterministic: the angles with the
    most terms are tried first (a long sum is more likely made of shorter ones, which then stay
    calls), the ordered pairs in the order of ``called``."""
    out, bases = {}, set()
    for a in sorted(called, key=lambda e: -len(sp.Add.make_args(sp.expand(e)))):   # stable
        if a in bases:
            continue
        kept = [x for x in called if x != a and x not in out]
        pair = next(((x, y, sign) for x in kept for y in kept if y is not x for sign in (1, -1)
                     if sp.expand(x + sign * y - a) == 0), None)
        if pair is not None:
            out[a] = pair
            bases.update(pair[:2])
    return out


def _library_file(robot) -> bool:
    """Whether the robot was read from the library's folder (derive/robots)."""
    return robot.path != "<dict>" and Path(robot.path).parent == LIBRARY_DIR


def _known_class(robot) -> bool:
    """Whether the robot's IK program comes from a class (UR family in its own frames or
    related to a library robot, or a 7-joint class), not from an extraction on its chain."""
    if redundant_kind(robot) is not None:
        return True
    try:
        ur_geometry(robot)
        return True
    except DeriveError:
        return False


def _fk_kernel(robot) -> Kernel:
    qs = sp.symbols(f"q0:{robot.dof}", real=True)
    symbolic = None
    if spherical_class(robot) is not None:
        # a spherical-wrist arm: the product of its joints' dual quaternions, constants multiplied
        # out (a second; folding the expanded product of the canonical chain gave 20x more code)
        return _fk_numeric(robot, qs)
    if robot.exact and not _library_file(robot) and _known_class(robot):
        # a new robot of a class with a shipped IK program: no symbolic derivation on its chain
        # on first use (issue 30: substitution and a compile); the library's robots, whose
        # kernels make generate ships, keep the folded products
        step("FK from the numeric product of the joint dual quaternions (a new robot of a known class)")
        return _fk_numeric(robot, qs)
    if robot.exact:
        try:
            symbolic = _fk_symbolic(robot)
        except BudgetError:
            raise
        except DeriveError as exc:      # e.g. a chain whose axis 1 misses the base origin
            step(f"FK from the numeric product of the joint dual quaternions ({exc})")
    if symbolic is not None:
        chain, outs = symbolic
        values = {k: sp.Float(v, 17) if not float(v).is_integer() else sp.Integer(int(v))
                  for k, v in chain.parameters.items()}
        outs = [e.subs(values) for e in outs]
        # map joints of the chain to variables of the robot (chain path joints are the variables)
        var_index = {j.name: j.variable for j in robot.joints}
        subs_q = {j.theta: qs[var_index[j.name]] for j in chain.joints}
        outs = [e.xreplace(subs_q) for e in outs]
        parameters = dict(chain.parameters)
    else:
        if not robot.exact:
            step("FK from the numeric product of the joint dual quaternions (not exact: no folding)")
        return _fk_numeric(robot, qs)

    # trig atoms -> symbols
    atoms = set()
    for e in outs:
        atoms |= e.atoms(sp.sin, sp.cos)
    args = sorted({a.args[0] for a in atoms}, key=sp.default_sort_key)
    k = Kernel(robot=robot.name, dof=robot.dof, parameters=parameters)
    rep = {}
    half_of = {sp.expand(2 * a): a for a in args}
    # plain sin/cos calls for the arguments without a half among them and that are not the sum
    # or difference of two other calls
    calls = [a for a in args if not (a in half_of and half_of[a] in args)]
    sums = _sums(calls)
    calls = [a for a in calls if a not in sums]
    sym_of = {}

    def name(a, how):
        n = len(k.trig)
        sym_of[a] = (sp.Symbol(f"s{n}"), sp.Symbol(f"c{n}"))
        k.trig.append((f"s{n}", f"c{n}", how))

    for a in calls:
        name(a, a)
    k.n_sincos = len(calls)
    for a, (x, y, sign) in sums.items():   # by the addition theorem from two calls
        (sx, cx), (sy, cy) = sym_of[x], sym_of[y]
        name(a, ("sum", str(sx), str(cx), str(sy), str(cy), sign))
    for a in args:                          # double angles from their halves
        if a not in sym_of:
            hs, hc = sym_of[half_of[a]]
            name(a, ("double", str(hs), str(hc)))
    for a, (s, c) in sym_of.items():
        rep[sp.sin(a)] = s
        rep[sp.cos(a)] = c
    outs = [sp.N(e.xreplace(rep), 17) for e in outs]   # exact constants (sqrt(2)/2) as floats
    temps, reduced = sp.cse(outs, symbols=sp.numbered_symbols("t"), optimizations="basic")
    k.temps = temps
    k.outputs = reduced
    return k
