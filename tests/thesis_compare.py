"""Compare the thesis's printed equations (tests/data/thesis_printed.yaml) with the derived ones.

Used by tests/test_thesis_errata.py; run as a script it prints the comparison, from which the
appendix part of docs/errata.md is written:  python tests/thesis_compare.py
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import sympy as sp
import yaml

from derive import dualquat as DQ
from derive import load_robot
from derive.kinematics import fk as kin
from derive.symbolic.equations import derive_equations
from derive.symbolic.trig import half_angle_normal_form

DATA = Path(__file__).resolve().parent.parent / "derive" / "data" / "thesis_printed.yaml"
THETAS = [sp.Symbol(f"theta{k}", real=True) for k in range(1, 7)]
NAMES = {f"t{k}": THETAS[k - 1] for k in range(1, 7)}
for n in ("d1 a2 a3 d4 d5 d6 w a b c x y z w4 a4 b4 c4 x4 y4 z4 x5 y5 z5 "
          "alpha beta gamma delta").split():
    NAMES[n] = sp.Symbol(n, real=True)


def parse(text):
    return None if text is None else sp.sympify(text, locals=NAMES)


def load():
    return yaml.safe_load(DATA.read_text())


def _same(expr_a, expr_b) -> bool:
    return half_angle_normal_form(expr_a - expr_b, THETAS) == 0


def compare_equations():
    """[(entry, derived Equation, verdict)] with verdict 'correct', 'wrong' or 'not legible'."""
    _, sets = derive_equations("ur3-thesis", symbolic=False)
    derived = {e.id: e for s in sets for e in s.equations}
    data = load()
    out = []
    for entry in data["appendix"] + data["section_4_3"]:
        e = derived[entry.get("same_as", entry["id"])]
        lhs, rhs = parse(entry["lhs"]), parse(entry["rhs"])
        if lhs is None and rhs is None:
            verdict = "not legible"
        elif lhs is None:
            verdict = "correct" if _same(rhs, e.rhs) or _same(rhs, -e.rhs) else "wrong"
        else:
            d_printed, d_derived = lhs - rhs, e.lhs - e.rhs
            verdict = "correct" if _same(d_printed, d_derived) or _same(d_printed, -d_derived) else "wrong"
        out.append((entry, e, verdict))
    return out


def _configurations(rng, n):
    """Generic UR3 configurations (away from the singular sets of the closed forms)."""
    out = []
    while len(out) < n:
        q = rng.uniform(-math.pi, math.pi, 6)
        if abs(math.sin(q[4])) < 0.2 or abs(math.sin(q[2])) < 0.2:
            continue
        if abs(math.cos((q[1] + q[2] + q[3]) / 2)) < 0.2:
            continue
        out.append(q)
    return out


def _pose_values(q):
    """Pose variables of appendix B (product sign), frame-5 and shoulder-to-wrist-1 coordinates."""
    robot = load_robot("ur3-thesis")
    frames = [f[0] for f in kin._frames_dq(robot, q[None, :])]   # exact products, no sign change
    full = frames[5]
    vals = dict(zip("w a b c".split(), full[:4]))
    vals.update(zip("x y z".split(), DQ._translation(full)))
    vals.update(zip("x5 y5 z5".split(), DQ._translation(frames[3])))
    rel = DQ._mul(DQ.inv(frames[0]), frames[2])                       # Q2 Q3
    q4 = kin._joint_dq(robot.joints[3], np.array([q[3]]))[0]
    n2 = DQ._mul(rel, np.r_[q4[:4], 0, 0, 0, 0])                     # Q2 Q3 (rotation of Q4)
    vals.update(zip("w4 a4 b4 c4".split(), n2[:4]))
    vals.update(zip("x4 y4 z4".split(), DQ._translation(n2)))
    vals.update({k: v for k, v in robot.parameters.items()})
    vals.update({f"t{k + 1}": q[k] for k in range(6)})
    return vals


def check_formulas(samples=200, seed=7):
    """[(entry, fraction of samples whose true angle is among the printed candidates)]"""
    rng = np.random.default_rng(seed)
    data = load()
    configs = _configurations(rng, samples)
    out = []
    for entry in data["formulas"]:
        target = entry["angle"]
        defs = {NAMES[k]: parse(v) for k, v in (entry.get("definitions") or {}).items()}
        cands = [parse(c).subs(defs) for c in entry["candidates"]]
        free = sorted({s for c in cands for s in c.free_symbols}, key=str)
        fns = [sp.lambdify(free, c, "math") for c in cands]
        hits = 0
        for q in configs:
            vals = _pose_values(q)
            args = [vals[str(s) if not str(s).startswith("theta") else "t" + str(s)[5:]] for s in free]
            true = vals[target]
            ok = False
            for f in fns:
                try:
                    v = f(*args)
                except ValueError:
                    continue
                if abs(math.remainder(v - true, 2 * math.pi)) < 1e-9:
                    ok = True
            hits += ok
        out.append((entry, hits / len(configs)))
    return out


if __name__ == "__main__":
    for entry, e, verdict in compare_equations():
        if verdict != "correct":
            print(f"{entry['id']}: {verdict}")
            print(f"   printed: {entry['lhs']} = {entry['rhs']}")
            print(f"   derived: {sp.sstr(e.lhs)} = {sp.sstr(e.rhs)}")
    for entry, frac in check_formulas():
        print(f"formula {entry['id']} ({entry['angle']}): true angle among candidates in {frac:.0%} of samples")
