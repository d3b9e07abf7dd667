"""Flat expressions for the generated kernels, from the derived chain products.

The forward kinematics of a robot is M_1 G (:mod:`derive.chain`): the product of the
joint dual quaternions in thesis form times the constant end transform. Its 8
components are built symbolically, the robot's numbers substituted, and written as a
sequence of assignments:

1. the sines and cosines the expressions need: one sin/cos pair per distinct angle
   argument (a half angle such as (q2+q3+q4)/2, or a full angle); a full angle whose
   half is also needed comes from the half by the double-angle formulas, which costs
   two multiplications instead of a sin/cos call;
2. common subexpressions (sympy's ``cse``) over the 8 outputs.

The joint variables are ``q[0] .. q[n-1]``; the outputs are the unit dual quaternion
[real w x y z, dual w x y z] (dual = 1/2 t real) in the sign the product gives.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import sympy as sp

from .quaternion import hamilton
from .robot import load_robot


@dataclass
class Kernel:
    """Straight-line code: inputs q[0..n-1], temporaries, outputs."""

    robot: str
    dof: int
    trig: list = field(default_factory=list)      # (name_s, name_c, arg expr in q, or ("double", half_s, half_c))
    temps: list = field(default_factory=list)     # (name, expr)
    outputs: list = field(default_factory=list)   # expr per output
    parameters: dict = field(default_factory=dict)
    n_sincos: int = 0


def _fk_symbolic(robot):
    """The 8 components of M_1 G from the folded left sides of M_1 = N_1 (set B)."""
    from .equations import derive_equations
    from .ik_extract import _rot

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


@lru_cache(maxsize=16)
def fk_kernel(robot_name: str) -> Kernel:
    robot = load_robot(robot_name)
    chain, outs = _fk_symbolic(robot)
    values = {k: sp.Float(v, 17) if not float(v).is_integer() else sp.Integer(int(v))
              for k, v in chain.parameters.items()}
    outs = [e.subs(values) for e in outs]
    thetas = [j.theta for j in chain.joints]
    qs = sp.symbols(f"q0:{chain.n}", real=True)
    # map joints of the chain to variables of the robot (chain path joints are the variables)
    names = [j.name for j in chain.joints]
    var_index = {j.name: j.variable for j in robot.joints}
    subs_q = {t: qs[var_index[n]] for t, n in zip(thetas, names)}
    outs = [e.xreplace(subs_q) for e in outs]

    # trig atoms -> symbols
    atoms = set()
    for e in outs:
        atoms |= e.atoms(sp.sin, sp.cos)
    args = sorted({a.args[0] for a in atoms}, key=sp.default_sort_key)
    k = Kernel(robot=robot.name, dof=robot.dof, parameters=dict(chain.parameters))
    rep = {}
    half_of = {sp.expand(2 * a): a for a in args}
    sym_of = {}
    n = 0
    for a in args:                       # plain sin/cos calls for arguments without a half
        if a in half_of and half_of[a] in args:
            continue
        s, c = sp.Symbol(f"s{n}"), sp.Symbol(f"c{n}")
        n += 1
        sym_of[a] = (s, c)
        k.trig.append((str(s), str(c), a))
    k.n_sincos = n
    for a in args:                       # double angles from their halves
        if a in sym_of:
            continue
        hs, hc = sym_of[half_of[a]]
        s, c = sp.Symbol(f"s{n}"), sp.Symbol(f"c{n}")
        n += 1
        sym_of[a] = (s, c)
        k.trig.append((str(s), str(c), ("double", str(hs), str(hc))))
    for a, (s, c) in sym_of.items():
        rep[sp.sin(a)] = s
        rep[sp.cos(a)] = c
    outs = [sp.N(e.xreplace(rep), 17) for e in outs]   # exact constants (sqrt(2)/2) as floats
    temps, reduced = sp.cse(outs, symbols=sp.numbered_symbols("t"), optimizations="basic")
    k.temps = temps
    k.outputs = reduced
    return k
