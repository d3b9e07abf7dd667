"""Extraction of closed-form IK from the derived equations M_i = N_i.

The pipeline knows nothing about the UR: it takes the equation sets of
:mod:`derive.symbolic.equations` and repeatedly looks for an equation (or a pair) that
can be solved for one unknown, given the angles already found. Patterns:

* ``S1`` one equation with one unknown angle u (or one compound such as
  (t2+t3+t4+t6)/2), of the form A cos u + B sin u + C = 0; two branches:
  u = atan2(B, A) +- atan2(sqrt(A^2 + B^2 - C^2), -C), or +-acos(-C/A) when B = 0;
* ``S2`` a pair of equations linear in (cos u, sin u) with an invertible 2x2
  system: u = atan2(sin u, cos u), one branch;
* ``S3`` a pair with two unknowns whose unknown parts, squared and added, lose one
  of them (sum of squares): the result is solved by S1;
* ``span`` an angle that is a linear combination of compound angles already found.

Intermediate poses: the frame-5 point (x5, y5, z5) of set W and the
shoulder-to-wrist-1 pose (w4 ... z4) of set C are expressed through the pose and
the joint transforms (N1_W = N1 Q6^-1 (1, -l5), N2_C = Q1^-1 N1 Q6^-1 Q5^-1 (1, -l4));
an equation becomes usable once the angles in its pose's definition are known.

Among the possible steps the pipeline takes the one with the fewest branches, then
the simplest closed form (sympy's operation count). Every closed form is checked
numerically: for random configurations the true angle is among its candidates.
"""

from __future__ import annotations

import itertools
import math
import sys
from dataclasses import dataclass, field

import numpy as np
import sympy as sp

from derive.algebra import dualquat as dq
from derive.algebra.quaternion import hamilton
from derive.cache import memo
from derive.cache import step as report_step
from derive.errors import DeriveError
from derive.kinematics import fk as reference
from derive.model.robot import load_robot
from derive.symbolic.chain import (
    SymChain,
    chain_from_robot,
    numeric_robot,
    runs_matrix,
    runs_quaternion,
)
from derive.symbolic.equations import POSES, derive_equations
from derive.symbolic.trig import _fold as fold


@dataclass
class Step:
    unknown: str                 # "theta1", or a compound like "(theta2 + theta3 + theta4 + theta6)/2"
    pattern: str                 # S1, S2, S3, span
    equations: list              # ids used
    forms: list                  # closed forms (sympy) of the candidates
    branches: int
    note: str = ""
    check: float | None = None   # fraction of random configurations whose true value is a candidate
    symbol: sp.Symbol | None = None   # the unknown itself (theta_i) or sigma_k for a compound


@dataclass
class Extraction:
    robot: str
    chain: SymChain
    definitions: dict            # intermediate symbol -> sympy expression
    steps: list = field(default_factory=list)

    @property
    def order(self) -> list:
        return [s.unknown for s in self.steps]


# --------------------------------------------------------------------------- #
# Symbolic pair algebra for the intermediate poses
# --------------------------------------------------------------------------- #
def _rot(q):
    w, x, y, z = q
    return sp.Matrix([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                      [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                      [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _joint_triple(j, inverse=False):
    """(quaternion, rotation matrix, translation) of Q_j or Q_j^-1."""
    q = runs_quaternion([(j.axis, (-1 if inverse else 1) * j.theta)])
    r = runs_matrix([(j.axis, j.theta)])
    if inverse:
        return q, r.T, -sp.Matrix(j.link)          # -R^T (R l) = -l exactly
    return q, r, r * sp.Matrix(j.link)


def _tmul(a, b):
    """Pair product on triples: (q1 q2, R1 R2, R1 p2 + p1)."""
    qa, ra, pa = a
    qb, rb, pb = b
    return (tuple(sp.expand(e) for e in hamilton(qa, qb)), (ra * rb).applyfunc(sp.expand),
            (ra * pb + pa).applyfunc(sp.expand))


def _translation_only(v):
    return ((sp.Integer(1), 0, 0, 0), sp.eye(3), sp.Matrix(v))


#: Entries r_ij of the rotation matrix of the pose quaternion (w, a, b, c).
R_SYMS = sp.Matrix(3, 3, lambda i, j: sp.Symbol(f"r{i + 1}{j + 1}", real=True))


def _definitions(chain: SymChain) -> dict:
    """Intermediate pose symbols of sets W and C as functions of the pose and the angles
    (translations written with the entries r_ij of the pose's rotation matrix)."""
    w, a, b, c, x, y, z = POSES["B"]
    pose = ((w, a, b, c), R_SYMS, sp.Matrix([x, y, z]))
    j = chain.joints
    defs = {}
    # W: N1_W = N1 Q6^-1 (1, -l5)
    nw = _tmul(_tmul(pose, _joint_triple(j[5], inverse=True)), _translation_only(-sp.Matrix(j[4].link)))
    for sym, e in zip(POSES["W"], list(nw[0]) + list(nw[2])):
        defs[sym] = e
    # C: N2_C = Q1^-1 N1 Q6^-1 Q5^-1 (1, -l4)
    nc = _tmul(_joint_triple(j[0], inverse=True), pose)
    nc = _tmul(nc, _joint_triple(j[5], inverse=True))
    nc = _tmul(nc, _joint_triple(j[4], inverse=True))
    nc = _tmul(nc, _translation_only(-sp.Matrix(j[3].link)))
    for sym, e in zip(POSES["C"], list(nc[0]) + list(nc[2])):
        defs[sym] = e
    return defs


# --------------------------------------------------------------------------- #
# Linear forms of angle arguments
# --------------------------------------------------------------------------- #
def _linear_form(arg, thetas):
    """Coefficients of arg as a linear combination of the thetas (None if not linear/pure)."""
    arg = sp.expand(arg)
    coeffs = [arg.coeff(t) for t in thetas]
    rest = sp.expand(arg - sum(c * t for c, t in zip(coeffs, thetas)))
    if rest != 0 or any(c.free_symbols for c in coeffs):
        return None
    return tuple(sp.nsimplify(c) for c in coeffs)


def _trig_args(expr):
    return {f.args[0] for f in expr.atoms(sp.sin, sp.cos)}


class _State:
    def __init__(self, thetas, definitions):
        self.thetas = thetas
        self.known_forms: list = []           # linear forms known (as tuples)
        self.definitions = definitions
        self.known_angles: set = set()

    def in_span(self, form) -> bool:
        if not self.known_forms:
            return all(c == 0 for c in form)
        m = sp.Matrix(self.known_forms)
        return m.rank() == m.col_join(sp.Matrix([form])).rank()

    def add(self, form):
        if not self.in_span(form):
            self.known_forms.append(form)
        for k, t in enumerate(self.thetas):
            unit = tuple(1 if i == k else 0 for i in range(len(self.thetas)))
            if self.in_span(unit):
                self.known_angles.add(t)

    def symbol_known(self, s) -> bool:
        if s in self.definitions:
            return self.definitions[s].free_symbols.isdisjoint(set(self.thetas) - self.known_angles)
        return True

    def unknown_args(self, expr):
        """Distinct unknown linear forms among the trig arguments of expr (None: not usable)."""
        forms = set()
        for arg in _trig_args(expr):
            f = _linear_form(arg, self.thetas)
            if f is None:
                return None
            if not self.in_span(f):
                neg = tuple(-c for c in f)
                forms.add(max(f, neg, key=str))
        # a theta appearing outside trig functions (prismatic) is not handled
        bare = expr.free_symbols & (set(self.thetas) - self.known_angles)
        if any(not self._only_in_trig(expr, t) for t in bare):
            return None
        return forms

    @staticmethod
    def _only_in_trig(expr, t):
        return not expr.subs({f: 0 for f in expr.atoms(sp.sin, sp.cos)}).has(t)


def _as_linear_in(expr, form, thetas, u):
    """expr with the compound angle `form` replaced by symbol u: (A, B, C) of A cos u + B sin u + C,
    or None. Arguments k*form + known are expanded (k = +-1, +-2 not supported beyond sign)."""
    lin = sum(c * t for c, t in zip(form, thetas))
    pivot = next(t for c, t in zip(form, thetas) if c != 0)
    cp = dict(zip(thetas, form))[pivot]
    e = expr.subs(pivot, (u - (lin - cp * pivot)) / cp)
    e = sp.expand(sp.expand_trig(e))
    e = e.subs({sp.cos(u): sp.Symbol("_C"), sp.sin(u): sp.Symbol("_S")})
    cs, ss = sp.Symbol("_C"), sp.Symbol("_S")
    if e.has(u):
        return None
    poly = sp.Poly(e, cs, ss)
    if poly.total_degree() > 1:
        return None
    a = poly.coeff_monomial(cs)
    b = poly.coeff_monomial(ss)
    c0 = poly.coeff_monomial(1)
    return sp.factor_terms(a), sp.factor_terms(b), sp.factor_terms(c0)


def _fold(e):
    return fold(sp.expand(e))


def _fold_form(f):
    """Fold the arguments of the functions in a closed form (acos(...), atan2(..., ...))."""
    if isinstance(f, (sp.acos, sp.asin, sp.atan2)):
        return f.func(*[_fold_ratio(a) for a in f.args])
    if f.args:
        return f.func(*[_fold_form(a) for a in f.args])
    return f


def _fold_ratio(e):
    num, den = sp.fraction(sp.together(e))
    return _fold(num) / _fold(den)


# --------------------------------------------------------------------------- #
# Numeric environments: consistent values of every symbol at random configurations
# --------------------------------------------------------------------------- #
def _numeric_envs(chain: SymChain, defs: dict, count: int, seed: int, generic: bool = True) -> list:
    """[{symbol: value}] for random configurations: angles, parameters, the pose from the
    independent reference FK (quaternion sign = the product), and the intermediate poses."""

    thetas = [j.theta for j in chain.joints]
    params = dict(chain.parameters)
    robot = numeric_robot(chain, params)
    rsyms = list(R_SYMS)
    def_fns = {s: sp.lambdify(thetas + list(params) + list(POSES["B"]) + rsyms, e, "math")
               for s, e in defs.items()}
    rng = np.random.default_rng(seed)
    envs = []
    while len(envs) < count:
        q = rng.uniform(-math.pi, math.pi, chain.n)
        if generic and min(abs(math.sin(q[4])), abs(math.sin(q[2])), abs(math.cos(q[4] / 2)),
                           abs(math.sin(q[4] / 2)), abs(math.cos((q[1] + q[2] + q[3]) / 2))) < 0.1:
            continue
        frame = reference._frames_dq(robot, q[None, :])[-1][0]      # exact product, its own sign
        pose = list(frame[:4]) + list(dq._translation(frame))
        env = {**params, **dict(zip(POSES["B"], pose)), **dict(zip(thetas, q))}
        rvals = [float(v) for v in _rot(frame[:4]).reshape(9, 1)]
        env.update(zip(rsyms, rvals))
        args = list(q) + [params[p] for p in params] + pose + rvals
        for s, f in def_fns.items():
            env[s] = float(f(*args))
        envs.append(env)
    return envs


def _evaluate(expr, envs) -> list:
    syms = sorted(expr.free_symbols, key=str)
    f = sp.lambdify(syms, expr, "math")
    out = []
    for env in envs:
        try:
            out.append(complex(f(*[env[s] for s in syms])))
        except (ValueError, ZeroDivisionError, KeyError):
            out.append(complex("nan"))
    return out


def _generic_nonzero(expr, envs) -> bool:
    return all(abs(v) > 1e-9 for v in _evaluate(expr, envs))


# --------------------------------------------------------------------------- #
# The search
# --------------------------------------------------------------------------- #
def _candidates(state, eqs, thetas, envs):
    """All possible next steps: (branches, ops, Step, new forms)."""
    u = sp.Symbol("u", real=True)
    usable = [e for e in eqs if all(state.symbol_known(s) for s in (e.lhs - e.rhs).free_symbols
                                    if s not in thetas)]
    single: dict = {}
    pairs: dict = {}
    for e in usable:
        expr = e.lhs - e.rhs
        forms = state.unknown_args(expr)
        if not forms:
            continue
        if len(forms) == 1:
            single.setdefault(next(iter(forms)), []).append(e)
        elif len(forms) == 2:
            pairs.setdefault(frozenset(forms), []).append(e)
    out = []
    for form, group in single.items():
        lins = []
        for e in group:
            abc = _as_linear_in(e.lhs - e.rhs, form, thetas, u)
            if abc is None or (abc[0] == 0 and abc[1] == 0):
                continue
            if not _generic_nonzero(abc[0] * abc[0] + abc[1] * abc[1], envs):
                continue          # coefficients vanish for every consistent pose (e.g. C.4)
            lins.append((e, abc))
        # S2: a pair forming an invertible linear system in (cos u, sin u)
        for (e1, (a1, b1, c1)), (e2, (a2, b2, c2)) in itertools.combinations(lins, 2):
            if c1 == 0 and c2 == 0:      # homogeneous: only tan u is determined (S1)
                continue
            det = sp.expand(a1 * b2 - a2 * b1)
            if det == 0 or not _generic_nonzero(det, envs):
                continue
            cu = sp.expand(-c1 * b2 + c2 * b1) / det
            su = sp.expand(-a1 * c2 + a2 * c1) / det
            st = Step(_form_name(form, thetas), "S2", [e1.id, e2.id], [sp.atan2(su, cu)], 1)
            out.append((1, sp.count_ops(st.forms[0]), st, [form]))
        # S1
        for e, (a, b, c) in lins:
            if b == 0:
                val = -c / a
                forms = [sp.acos(val), -sp.acos(val)]
            elif a == 0:
                val = -c / b
                forms = [sp.asin(val), sp.pi - sp.asin(val)]
            else:
                r = sp.sqrt(sp.expand(a * a + b * b - c * c))
                forms = [sp.atan2(b, a) + sp.atan2(r, -c), sp.atan2(b, a) - sp.atan2(r, -c)]
            st = Step(_form_name(form, thetas), "S1", [e.id], forms, 2)
            out.append((2, sp.count_ops(forms[0]), st, [form]))
    if out:
        return out
    # S3 (only when nothing simpler exists): sum of squares of the unknown parts of two
    # equations of one product with the same two unknowns
    for key, group in pairs.items():
        for e1, e2 in itertools.combinations(group, 2):
            if (e1.i, e1.set) != (e2.i, e2.set):
                continue
            p1, k1 = _split(e1.lhs - e1.rhs, state, thetas)
            p2, k2 = _split(e2.lhs - e2.rhs, state, thetas)
            if len(sp.Add.make_args(p1)) > 3 or len(sp.Add.make_args(p2)) > 3:
                continue
            s = sp.trigsimp(sp.expand(p1 * p1 + p2 * p2))
            new = sp.expand(s - k1 * k1 - k2 * k2)
            forms = state.unknown_args(new)
            if not forms or len(forms) != 1:
                continue
            form = next(iter(forms))
            abc = _as_linear_in(new, form, thetas, u)
            if abc is None:
                continue
            a, b, c = abc
            if b == 0 and a != 0 and _generic_nonzero(a, envs):
                val = -c / a
                cands = [sp.acos(val), -sp.acos(val)]
            else:
                continue
            st = Step(_form_name(form, thetas), "S3", [e1.id, e2.id], cands, 2,
                      note=f"sum of squares: {sp.sstr(sp.Eq(s, k1 * k1 + k2 * k2))}")
            out.append((2, sp.count_ops(cands[0]), st, [form]))
    return out


def _id_key(eid: str):
    key, num = eid.split(".")
    return ("BWC".index(key), int(num))


def _split(expr, state, thetas):
    """expr = P - K with P the terms that contain unknown angles."""
    unknown = set(thetas) - state.known_angles
    terms = sp.Add.make_args(sp.expand(expr))
    p = sp.Add(*[t for t in terms if t.free_symbols & unknown])
    k = -sp.Add(*[t for t in terms if not (t.free_symbols & unknown)])
    return p, k


def _form_name(form, thetas) -> str:
    lin = sp.Add(*[c * t for c, t in zip(form, thetas)])
    return sp.sstr(lin)


def extract(robot, progress: bool = False) -> Extraction:
    """Find a solving order and the closed forms for every joint angle of a 6R chain
    (cached per robot identity, and per chain structure: a family is extracted once)."""
    robot = load_robot(robot)
    return memo("ik-extraction", robot.id, lambda: _extract_robot(robot, progress))


def _extract_robot(robot, progress: bool) -> Extraction:
    chain = chain_from_robot(robot)
    key = (chain.joints, tuple(chain.parameters))
    family = memo("ik-extraction-family", key, lambda: _extract(robot, progress))
    return Extraction(chain.robot, chain, family.definitions, family.steps)


def _extract(robot, progress: bool) -> Extraction:
    chain, sets = derive_equations(robot, progress=progress, symbolic=False)
    if chain.n != 6 or len(sets) < 3:
        raise DeriveError(f"{chain.robot}: IK extraction needs a 6R chain with the B, W and C sets")
    thetas = [jt.theta for jt in chain.joints]
    defs = _definitions(chain)
    state = _State(thetas, defs)
    eqs = [e for s in sets for e in s.equations]
    ext = Extraction(chain.robot, chain, defs)
    envs = _numeric_envs(chain, defs, 3, seed=11)
    for _ in range(16):
        if len(state.known_angles) == len(thetas):
            break
        cands = _candidates(state, eqs, thetas, envs)
        if not cands:
            raise DeriveError(f"{chain.robot}: no solvable equation left; found {ext.order}")
        cands = [c for c in cands if not any(f.has(sp.nan, sp.zoo) for f in c[2].forms)]
        cands.sort(key=lambda c: (c[0], c[1], [_id_key(i) for i in c[2].equations]))
        _, _, step, forms = cands[0]
        step.forms = [_fold_form(f) for f in step.forms]
        line = (f"IK step {len(ext.steps) + 1}: {step.unknown} by {step.pattern} from "
                f"{', '.join(step.equations)}")
        if progress:
            print(f"[{chain.robot}] {line}", file=sys.stderr, flush=True)
        else:
            report_step(line)
        unknown = sp.sympify(step.unknown, locals={str(t): t for t in thetas})
        n_sigma = sum(1 for st in ext.steps if st.symbol is not None and st.symbol not in thetas)
        step.symbol = unknown if unknown in thetas else sp.Symbol(f"sigma{n_sigma + 1}", real=True)
        ext.steps.append(step)
        before = set(state.known_angles)
        for f in forms:
            state.add(f)
        solved = sp.sympify(step.unknown, locals={str(t): t for t in thetas})
        for t in thetas:                     # angles that the compounds found so far determine
            if t in state.known_angles and t not in before and t != solved:
                ext.steps.append(Step(str(t), "span", [], [_span_expression(state, thetas, t, ext)], 1,
                                      note="a combination of the angles found before", symbol=t))
    return ext


def _span_expression(state, thetas, t, ext):
    """t as a combination of the unknowns of the earlier steps, e.g. theta6 = sigma_+ - sigma_-
    (written with those steps' expressions as symbols)."""
    steps = [st for st in ext.steps if st.pattern != "span" or st.symbol in thetas]
    forms = [_linear_form(sp.sympify(st.unknown, locals={str(x): x for x in thetas}), thetas)
             for st in steps]
    m = sp.Matrix(forms).T
    target = sp.Matrix([1 if tt == t else 0 for tt in thetas])
    coeffs = sp.symbols(f"k0:{len(steps)}")
    sol = sp.solve(list(m * sp.Matrix(coeffs) - target), coeffs, dict=True)[0]
    free = [k for k in coeffs if k not in sol]
    sol = {k: v.subs({f: 0 for f in free}) for k, v in sol.items()}
    return sp.Add(*[sol.get(k, 0) * st.symbol for k, st in zip(coeffs, steps)])


# --------------------------------------------------------------------------- #
# Numeric check of the closed forms
# --------------------------------------------------------------------------- #
def check_numerically(ext: Extraction, samples: int = 200, seed: int = 3) -> None:
    """For random generic configurations, the true value of each step's unknown is among its
    candidates (mod 2 pi); the pose and the earlier unknowns are taken from the configuration."""
    thetas = [j.theta for j in ext.chain.joints]
    envs = _numeric_envs(ext.chain, ext.definitions, samples, seed)
    loc = {str(t): t for t in thetas}
    for st in ext.steps:
        true_vals = _evaluate(sp.sympify(st.unknown, locals=loc), envs)
        for earlier in ext.steps:
            if earlier is st:
                break
            vals = _evaluate(sp.sympify(earlier.unknown, locals=loc), envs)
            for env, v in zip(envs, vals):
                env[earlier.symbol] = v.real
        cand_vals = [_evaluate(f, envs) for f in st.forms]
        hits = 0
        for k, true in enumerate(true_vals):
            ok = any(abs(c[k].imag) < 1e-9 and abs(math.remainder(c[k].real - true.real, 2 * math.pi)) < 1e-8
                     for c in cand_vals)
            hits += ok
        st.check = hits / len(envs)
