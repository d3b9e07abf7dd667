"""The equations M_i = N_i term by term, their readable forms and their verification.

Three sets are derived for a 6R chain (thesis section 4.3.3-4.3.4):

* ``B``: base to wrist 3, i = 1..6, N_1 = ([w, <a, b, c>], <x, y, z>) (appendix B, B.1-B.42);
* ``W``: base to wrist 2 with the frame-5 coordinates, i = 1..5, the last joint's
  translation set to zero, N_1 = ([w5, <a5, b5, c5>], <x5, y5, z5>) (section 4.3.3, used
  for theta1; the thesis does not print this set, its ids are W.1-W.35);
* ``C``: shoulder to wrist 1, i = 2..4, the last translation set to zero,
  N_2 = ([w4, <a4, b4, c4>], <x4, y4, z4>) (appendix C, C.1-C.21).

The canonical chain of the spherical-wrist class (:mod:`derive.ik.spherical`: axes z, y, y, z,
y, z, the links of joints 4 and 5 zero, so axes 4, 5, 6 meet at the wrist centre) gets two sets
instead, the decomposition of Pieper's criterion into position and orientation:

* ``P``: base to wrist centre, i = 1..3, N_1 = ([w_w, <a_w, b_w, c_w>], <x_w, y_w, z_w>) the
  frame at the wrist centre: its translation is the pose's position less the last link
  (W = p - R l6, fixed by joints 4 to 6), its rotation depends on joints 4 to 6, so the
  translation terms alone solve theta1 to theta3 (P.1-P.21);
* ``O``: the wrist, i = 4..6, the last translation set to zero, N_4 = ([w_r, <a_r, b_r, c_r>],
  <x_r, y_r, z_r>) = (Q1 Q2 Q3)^-1 N_1 (1, -l6), whose quaternion terms solve theta4 to
  theta6 in half angles (O.1-O.21).

Equation ids follow the thesis: for products i = first..last the seven terms of
M_i = N_i are numbered 7 (last - i) + j, j = 1..4 the quaternion terms (w, i, j, k)
and 5..7 the translation terms (x, y, z). Other chains get the ``B`` set only.

Every equation is verified twice:

* symbolically: each printed side, brought to the half-angle normal form
  (:func:`derive.symbolic.trig.half_angle_normal_form`), is identical to the product it
  comes from;
* numerically: at random joint angles and random parameters, and at the robot's
  own parameters, the pose N_first is taken from the independent numeric
  reference (:func:`derive.kinematics.fk.fk` on the same chain written as an
  ``axis_angle`` description) and |lhs - rhs| must stay below 1e-12.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field

import numpy as np
import sympy as sp

from derive.cache import check as check_budget
from derive.cache import memo, peek, step
from derive.errors import DeriveError
from derive.kinematics import fk as reference
from derive.model.robot import load_robot
from derive.symbolic.chain import SymChain, chain_from_robot, numeric_robot, products
from derive.symbolic.trig import as_expr, compact, half_angle_normal_form

NUMERIC_TOL = 1e-12

POSES = {
    "B": sp.symbols("w a b c x y z", real=True),
    "W": sp.symbols("w5 a5 b5 c5 x5 y5 z5", real=True),
    "C": sp.symbols("w4 a4 b4 c4 x4 y4 z4", real=True),
    "P": sp.symbols("w_w a_w b_w c_w x_w y_w z_w", real=True),
    "O": sp.symbols("w_r a_r b_r c_r x_r y_r z_r", real=True),
}

SET_INFO = {
    "B": ("Base to wrist 3", "appendix B"),
    "W": ("Base to wrist 2, frame-5 coordinates", "section 4.3.3"),
    "C": ("Shoulder to wrist 1", "appendix C"),
    "P": ("Base to wrist centre (position)", "spherical-wrist class, Pieper's decomposition"),
    "O": ("Wrist (orientation)", "spherical-wrist class, Pieper's decomposition"),
}

#: Axes of the spherical-wrist class's canonical chain (derive.ik.spherical).
SW_AXES = ((0, 0, 1), (0, 1, 0), (0, 1, 0), (0, 0, 1), (0, 1, 0), (0, 0, 1))


def is_spherical_chain(chain: SymChain) -> bool:
    """Whether ``chain`` is the spherical-wrist canonical chain (axes :data:`SW_AXES`, the
    links of joints 4 and 5 zero)."""
    return (chain.n == 6 and all(j.type == "revolute" for j in chain.joints)
            and all(tuple(j.axis) == a for j, a in zip(chain.joints, SW_AXES))
            and all(e == 0 for j in chain.joints[3:5] for e in j.link))


@dataclass
class Equation:
    id: str
    set: str
    i: int                 # product index: M_i = N_i
    term: int              # 1..4 quaternion w, i, j, k; 5..7 translation x, y, z
    lhs_terms: list        # [(generator, coefficient)] of M_i term
    rhs_terms: list
    symbolic: bool | None = None
    numeric_error: float | None = None

    @property
    def product(self) -> str:
        return f"M{self.i} = N{self.i}"

    @property
    def lhs(self) -> sp.Expr:
        return as_expr(self.lhs_terms)

    @property
    def rhs(self) -> sp.Expr:
        return as_expr(self.rhs_terms)


@dataclass
class EquationSet:
    key: str
    first: int
    last: int
    zero_last_link: bool
    pose: tuple
    equations: list = field(default_factory=list)
    raw: dict = field(default_factory=dict)      # id -> (M term, N term), expanded products

    @property
    def title(self) -> str:
        return SET_INFO[self.key][0]

    @property
    def source(self) -> str:
        return SET_INFO[self.key][1]


def _say(progress, msg):
    """A progress line: printed when ``progress``, else reported to the running task (if any:
    :func:`derive.cache.step` prints it with the elapsed time and checks the time budget)."""
    if progress:
        print(msg, file=sys.stderr, flush=True)
    else:
        step(msg.split("] ", 1)[-1])


def set_specs(chain: SymChain) -> list:
    """(key, first, last, zero_last_link) of the sets that apply to ``chain``."""
    n = chain.n
    if is_spherical_chain(chain):
        return [("P", 1, 3, False), ("O", 4, 6, True)]
    specs = [("B", 1, n, False)]
    if n == 6 and all(j.type == "revolute" for j in chain.joints):
        specs += [("W", 1, 5, True), ("C", 2, 4, True)]
    return specs


def _generators(chain: SymChain, pose) -> list:
    prismatic = [j.theta for j in chain.joints if j.type == "prismatic"]
    return list(pose) + list(chain.parameters) + prismatic


def _derive_cached(joints, params, key, first, last, zero_last_link):
    """The symbolic work of one set; cached per chain structure, so a family is derived once."""
    return memo("equation-set", (joints, params, key, first, last, zero_last_link),
                lambda: _derive_set(joints, params, key, first, last, zero_last_link))


def _derive_set(joints, params, key, first, last, zero_last_link):
    chain = SymChain(robot="", family="", joints=joints,
                     parameters={p: 0.0 for p in params}, end_transform=((1, 0, 0, 0), (0, 0, 0)))
    pose = POSES[key]
    m_side, n_side = products(chain, first, last, pose, zero_last_link)
    gens = _generators(chain, pose)
    eqs, raw = [], {}
    for i in range(last, first - 1, -1):
        for j in range(1, 8):
            eid = f"{key}.{7 * (last - i) + j}"
            m, n = m_side[i].terms[j - 1], n_side[i].terms[j - 1]
            raw[eid] = (m, n)
            check_budget()
            eqs.append(Equation(eid, key, i, j, compact(m, gens), compact(n, gens)))
    return eqs, raw


def derive_set(chain: SymChain, key: str, first: int, last: int, zero_last_link: bool) -> EquationSet:
    eqs, raw = _derive_cached(chain.joints, tuple(chain.parameters), key, first, last, zero_last_link)
    # fresh Equation objects: verification results belong to the robot, not the family
    eqs = [Equation(e.id, e.set, e.i, e.term, e.lhs_terms, e.rhs_terms) for e in eqs]
    return EquationSet(key, first, last, zero_last_link, POSES[key], eqs, raw)


# --------------------------------------------------------------------------- #
# Verification
# --------------------------------------------------------------------------- #
def verify_symbolic(chain: SymChain, eset: EquationSet) -> None:
    """Each printed side is identical to its product (half-angle normal form)."""
    thetas = [j.theta for j in chain.joints]
    for e in eset.equations:
        m, n = eset.raw[e.id]
        ok = (half_angle_normal_form(e.lhs - m, thetas) == 0
              and half_angle_normal_form(e.rhs - n, thetas) == 0)
        e.symbolic = bool(ok)


def _samples(chain: SymChain, rng, count: int) -> list:
    """Parameter sets: the robot's own numbers, then random ones (0.05-0.8 m, either sign)."""
    out = [dict(chain.parameters)]
    for _ in range(count):
        out.append({p: float(rng.uniform(0.05, 0.8) * rng.choice([-1, 1])) for p in chain.parameters})
    return out


def verify_numeric(chain: SymChain, eset: EquationSet, seed: int = 0, n_angles: int = 4,
                   n_params: int = 3) -> None:
    """|lhs - rhs| at random angles and parameters, with the pose from the numeric reference."""
    rng = np.random.default_rng(seed)
    thetas = [j.theta for j in chain.joints]
    params = list(chain.parameters)
    args = thetas + params + list(eset.pose)
    fl = {e.id: (sp.lambdify(args, e.lhs, "numpy"), sp.lambdify(args, e.rhs, "numpy"))
          for e in eset.equations}
    m_first_terms = [eset.raw[f"{eset.key}.{7 * (eset.last - eset.first) + j}"][0] for j in range(1, 8)]
    m_first = sp.lambdify(thetas + params, list(m_first_terms), "numpy")
    worst = {e.id: 0.0 for e in eset.equations}
    fk_gap = 0.0
    for values in _samples(chain, rng, n_params):
        sub = numeric_robot(chain, values, eset.first, eset.last, eset.zero_last_link)
        th = rng.uniform(-np.pi, np.pi, size=(n_angles, chain.n))
        q_sub = th[:, eset.first - 1:eset.last]
        pose = reference.fk(sub, q_sub)
        pvals = [values[p] for p in params]
        cols = [th[:, k] for k in range(chain.n)]
        m = np.array([np.broadcast_to(v, (n_angles,)) for v in m_first(*cols, *pvals)], dtype=float).T
        quat, trans = pose[:, :4], reference.dq._translation(pose)
        sign = np.where(np.sum(quat * m[:, :4], axis=1) < 0, -1.0, 1.0)[:, None]
        n_first = np.hstack((sign * quat, trans))
        fk_gap = max(fk_gap, float(np.max(np.abs(n_first - m))))
        for e in eset.equations:
            fl_l, fl_r = fl[e.id]
            pv = [n_first[:, k] for k in range(7)]
            lv = np.broadcast_to(fl_l(*cols, *pvals, *pv), (n_angles,))
            rv = np.broadcast_to(fl_r(*cols, *pvals, *pv), (n_angles,))
            worst[e.id] = max(worst[e.id], float(np.max(np.abs(lv - rv))))
    if fk_gap > NUMERIC_TOL:
        raise DeriveError(f"{chain.robot} set {eset.key}: the symbolic product M_{eset.first} differs from "
                          f"the numeric reference FK by {fk_gap:.3g}")
    for e in eset.equations:
        e.numeric_error = worst[e.id]


def derive_equations(robot, progress: bool = False, symbolic: bool = True) -> tuple:
    """(chain, [EquationSet]) for ``robot``, every equation verified (symbolically too unless
    ``symbolic`` is False); cached per robot identity."""
    robot = load_robot(robot)
    if not robot.exact:
        if robot.dof == 6:
            how = (f"solve a pose with its kernels (dq-derive ik {robot.name} --q ... or "
                   "derive.kernels(robot).ik: the nearby class's closed form polished, or the general "
                   "6R elimination)")
        elif robot.dof == 7:
            how = (f"solve a pose with one joint given (derive.kernels({robot.name!r}, free='qK').ik, "
                   f"or dq-derive ik {robot.name} --q ... --free-joint K)")
        else:
            how = "derive.refine solves a pose"
        raise DeriveError(
            f"{robot.name}: not every fixed angle is a multiple of pi/12 (decimal or "
            "calibrated twists), so the exact equations M_i = N_i are not derived; the FK kernels "
            f"come from the numeric product; {how}")
    if not symbolic:
        hit = peek("equations", (robot.id, True))
        if hit is not None:
            return hit
    return memo("equations", (robot.id, symbolic), lambda: _derive_equations(robot, progress, symbolic))


def _derive_equations(robot, progress: bool, symbolic: bool) -> tuple:
    t0 = time.perf_counter()
    chain = chain_from_robot(robot)
    _say(progress, f"[{chain.robot}] chain in thesis form: {chain.n} joints ({time.perf_counter() - t0:.2f} s)")
    sets = []
    for key, first, last, zero in set_specs(chain):
        clash = sorted({p.name for p in chain.parameters} & {s.name for s in POSES[key]})
        if clash:
            raise DeriveError(f"{chain.robot}: the parameter name(s) {', '.join(clash)} are also the pose "
                              f"symbols of equation set {key} ({' '.join(s.name for s in POSES[key])}); "
                              "rename them in the robot file (for example a5 -> a_5)")
        t = time.perf_counter()
        eset = derive_set(chain, key, first, last, zero)
        _say(progress, f"[{chain.robot}] set {key}: {len(eset.equations)} equations derived and "
                       f"simplified ({time.perf_counter() - t:.2f} s)")
        t = time.perf_counter()
        if symbolic:
            verify_symbolic(chain, eset)
        verify_numeric(chain, eset)
        bad = [e.id for e in eset.equations
               if e.numeric_error is None or e.numeric_error >= NUMERIC_TOL or e.symbolic is False]
        if bad:
            raise DeriveError(f"{chain.robot}: equations {bad} failed verification")
        _say(progress, f"[{chain.robot}] set {key}: verified ({time.perf_counter() - t:.2f} s)")
        sets.append(eset)
    return chain, sets
