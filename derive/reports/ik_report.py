"""Typesetting of the extracted IK (generated/<robot>/ik.md and ik.tex) beside the thesis's
formulas 4.9-4.44."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import sympy as sp
import yaml

from derive._version import __version__
from derive.cache import claim_folder, write_manifest
from derive.codegen.templates import template_environment
from derive.ik.extract import R_SYMS, check_numerically, extract
from derive.model.robot import load_robot
from derive.reports.latex import latex, side
from derive.symbolic.equations import POSES, derive_equations
from derive.symbolic.trig import as_expr, compact

THESIS_DATA = Path(__file__).resolve().parent.parent / "data" / "thesis_printed.yaml"
PATTERNS = {
    "S1": "one equation A cos u + B sin u + C = 0 (two roots)",
    "S2": "two equations linear in cos u and sin u (atan2, one root)",
    "S3": "two equations squared and added, the other unknown eliminated (two roots)",
    "span": "a combination of the angles found before",
}


def _thesis():
    data = yaml.safe_load(THESIS_DATA.read_text())
    names = {f"t{k}": sp.Symbol(f"theta{k}", real=True) for k in range(1, 7)}
    for n in ("d1 a2 a3 d4 d5 d6 w a b c x y z w4 a4 b4 c4 x4 y4 z4 x5 y5 z5 "
              "alpha beta gamma delta").split():
        names[n] = sp.Symbol(n, real=True)
    return data["formulas"], names


def _thetas_of(unknown: str) -> set:
    return {s.name for s in sp.sympify(unknown).free_symbols}


def build_ik_context(robot, command: str) -> dict:
    robot = load_robot(robot)
    ext = extract(robot)
    check_numerically(ext, samples=200)
    chain = ext.chain
    _, sets = derive_equations(robot, symbolic=False)
    eq_by_id = {e.id: e for s in sets for e in s.equations}
    thetas = [j.theta for j in chain.joints]

    steps, used_eqs, used_syms, known_order, deps = [], set(), set(), [], {}
    for k, st in enumerate(ext.steps):
        used_eqs |= set(st.equations)
        for f in st.forms:
            used_syms |= f.free_symbols
        for eid in st.equations:
            used_syms |= (eq_by_id[eid].lhs - eq_by_id[eid].rhs).free_symbols
        # the equations an angle rests on: its own and those of the steps it combines
        own = set(st.equations)
        for f in st.forms:
            for s2 in f.free_symbols:
                own |= deps.get(s2, set())
        deps[st.symbol] = own
        if st.symbol in thetas:
            known_order.append(st.symbol)
        steps.append({
            "k": k + 1,
            "symbol": latex(st.symbol),
            "unknown": latex(sp.sympify(st.unknown, locals={str(t): t for t in thetas})),
            "is_compound": st.symbol not in thetas,
            "pattern": st.pattern,
            "pattern_text": PATTERNS[st.pattern],
            "equations": [{"id": eid, "lhs": " ".join(side(eq_by_id[eid].lhs_terms)),
                           "rhs": " ".join(side(eq_by_id[eid].rhs_terms))} for eid in st.equations],
            "forms": [latex(f) for f in st.forms],
            "branches": st.branches,
            "check": f"{100 * st.check:.0f} %",
            "note": st.note,
        })

    gens = list(POSES["B"]) + list(chain.parameters) + list(R_SYMS)
    definitions = []
    for sym in list(POSES["W"]) + list(POSES["C"]):
        if sym in used_syms:
            expr = as_expr(compact(ext.definitions[sym], gens))
            definitions.append({"symbol": latex(sym), "expr": latex(expr)})

    formulas, names = _thesis()
    thesis_rows = []
    for f in formulas:
        angle = names[f["angle"]]
        defs = {names[k]: sp.sympify(v, locals=names) for k, v in (f.get("definitions") or {}).items()}
        ours = sorted(deps.get(angle, set()), key=lambda i: ("BWC".index(i[0]), int(i[2:])))
        theirs = list(f["equations"])
        thesis_rows.append({
            "id": f["id"], "angle": latex(angle),
            "forms": [latex(sp.sympify(c, locals=names)) for c in f["candidates"]],
            "definitions": [f"{latex(k)} = {latex(v)}" for k, v in defs.items()],
            "thesis_equations": ", ".join(theirs), "pipeline_equations": ", ".join(ours),
            "same": set(theirs) == set(ours) or (theirs and set(theirs) <= set(ours)),
        })
    thesis_order = [names[f["angle"]] for f in formulas]      # the data lists 4.11 ... 4.44 in order
    return {
        "version": __version__, "command": command, "robot": chain.robot,
        "title": robot.title,
        "parameters": [(latex(p), v) for p, v in chain.parameters.items()],
        "steps": steps, "definitions": definitions,
        "order": ", ".join(latex(t) for t in known_order),
        "thesis_order": ", ".join(latex(t) for t in thesis_order),
        "same_order": [str(t) for t in known_order] == [str(t) for t in thesis_order],
        "thesis": thesis_rows,
        "g_identity": tuple(sp.sympify(v) for v in chain.end_transform[0]) == (1, 0, 0, 0),
    }


def write_ik(robot, out_dir, progress: bool = False, command: str | None = None,
             force: bool = False) -> list:
    """Extract and typeset the closed-form IK into out_dir/<robot name>/ik.{md,tex}, recorded in
    its manifest (a folder of another robot is refused unless ``force``)."""
    t0 = time.perf_counter()
    robot = load_robot(robot)
    robot_name = robot.name
    claim_folder(Path(out_dir) / robot_name, robot.id, robot_name, force)
    command = command or f"dq-derive ik {robot_name}"
    ctx = build_ik_context(robot, command)
    env = template_environment()
    out = Path(out_dir) / robot_name
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name in ("ik.md", "ik.tex"):
        path = out / name
        path.write_text(env.get_template(name + ".j2").render(ctx), encoding="utf-8")
        written.append(path)
    written.append(write_manifest(out, {"id": robot.id, "robot": robot_name,
                                        "files": {"ik/md": "ik.md", "ik/tex": "ik.tex"}}))
    if progress:
        print(f"[{robot_name}] IK extracted and typeset ({time.perf_counter() - t0:.2f} s)", file=sys.stderr)
    return written
