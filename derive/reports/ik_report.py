"""Typesetting of the extracted IK (generated/<robot>/ik.md and ik.tex) beside the thesis's
formulas 4.9-4.44."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import sympy as sp
import yaml

from derive._version import __version__
from derive.algebra import dualquat as dq
from derive.algebra import quaternion as quat
from derive.algebra.angles import wrap_angle
from derive.cache import claim_folder, write_manifest
from derive.codegen.templates import template_environment
from derive.ik.closed_form import spherical_class
from derive.ik.extract import R_SYMS, check_numerically, extract
from derive.ik.program import spherical_forms
from derive.ik.spherical import canonical_robot
from derive.ik.tolerances import WRIST_SINGULAR
from derive.kinematics.fk import fk
from derive.model.robot import load_robot
from derive.reports.appendix import class_context
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
    geo = spherical_class(robot)
    if geo is None:
        ctx, stem = build_ik_context(robot, command), "ik"
    else:
        ctx, stem = build_sw_ik_context(robot, geo, command), "ik_spherical"
    env = template_environment()
    out = Path(out_dir) / robot_name
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name in ("ik.md", "ik.tex"):
        path = out / name
        path.write_text(env.get_template(name.replace("ik", stem) + ".j2").render(ctx), encoding="utf-8")
        written.append(path)
    written.append(write_manifest(out, {"id": robot.id, "robot": robot_name,
                                        "files": {"ik/md": "ik.md", "ik/tex": "ik.tex"}}))
    if progress:
        print(f"[{robot_name}] IK extracted and typeset ({time.perf_counter() - t0:.2f} s)", file=sys.stderr)
    return written


# --------------------------------------------------------------------------- #
# Spherical-wrist class
# --------------------------------------------------------------------------- #
def _sw_check(geo, chain, sf, samples: int = 200, seed: int = 5) -> dict:
    """Per step, the fraction of random configurations (within +-pi) whose true angle is among
    the candidates of the typeset closed form, evaluated with numpy at the robot's numbers."""
    rng = np.random.default_rng(seed)
    canon = canonical_robot(geo)
    th = rng.uniform(-np.pi, np.pi, size=(samples, 6))
    pose = fk(canon, th)
    r = dq.to_matrix(pose)
    values = {k: float(v) for k, v in chain.parameters.items()}
    t = r[:, :3, 3] - r[:, :3, 2] * values[sp.Symbol("c4", real=True)]
    x_w, y_w, z_w = POSES["P"][4:]
    w_r, a_r, b_r, c_r = POSES["O"][:4]
    thetas = [j.theta for j in chain.joints]
    env = {x_w: t[:, 0], y_w: t[:, 1], z_w: t[:, 2]}
    env.update({s: th[:, i] for i, s in enumerate(thetas)})
    # the O pose from the true angles: conj(q1 q23) q
    half1, half23 = th[:, 0] / 2, (th[:, 1] + th[:, 2]) / 2
    q123 = np.stack([np.cos(half1) * np.cos(half23), -np.sin(half1) * np.sin(half23),
                     np.cos(half1) * np.sin(half23), np.sin(half1) * np.cos(half23)], -1)
    o = quat._mul(quat._conj(q123), pose[:, :4])
    env.update({w_r: o[:, 0], a_r: o[:, 1], b_r: o[:, 2], c_r: o[:, 3]})

    def ev(e):
        e = sp.sympify(e).xreplace({k: sp.Float(v) for k, v in values.items()})
        syms = sorted(e.free_symbols, key=str)
        f = sp.lambdify(syms, e, "numpy")
        return np.broadcast_to(f(*[env[s] for s in syms]), (samples,)).astype(float)

    def hit(cands, true):
        d = np.min(np.stack([np.abs(wrap_angle(c - true)) for c in cands]), axis=0)
        return f"{100 * np.mean(d < 1e-7):.0f} %"

    t1, t2, t3, t4, t5, t6 = thetas
    a, b, c = (ev(e) for e in sf.theta1)
    root = np.sqrt(np.clip(a * a + b * b - c * c, 0, None))
    out = {"theta1": hit([np.arctan2(a, -b) - np.arctan2(-c, s * root) for s in (1, -1)], th[:, 0])}
    env[sf.X], env[sf.Z] = ev(sf.x_def), ev(sf.z_def)
    a, b, c = (ev(e) for e in sf.theta3)
    root = np.sqrt(np.clip(a * a + b * b - c * c, 0, None))
    out["theta3"] = hit([np.arctan2(b, a) + s * np.arctan2(root, -c) for s in (1, -1)], th[:, 2])
    ns, nc, d = (ev(e) for e in sf.theta2)
    out["theta2"] = hit([np.arctan2(np.sign(d) * ns, np.sign(d) * nc)], th[:, 1])
    comp = {}
    for kind, (ns, nc, k, _) in sf.halves.items():
        comp[kind] = (ev(ns), ev(nc), float(k))
    hs = np.hypot(comp["sin"][0], comp["sin"][1]) / abs(comp["sin"][2])
    hc = np.hypot(comp["cos"][0], comp["cos"][1]) / abs(comp["cos"][2])
    out["theta5"] = hit([2 * s * np.arctan2(hs, hc) for s in (1, -1)], th[:, 4])
    s_sum = np.arctan2(np.sign(comp["cos"][2]) * comp["cos"][0], np.sign(comp["cos"][2]) * comp["cos"][1])
    s_dif = np.arctan2(np.sign(comp["sin"][2]) * comp["sin"][0], np.sign(comp["sin"][2]) * comp["sin"][1])
    out["theta4"] = hit([s_sum + s_dif, s_sum + s_dif + np.pi], th[:, 3])
    out["theta6"] = hit([s_sum - s_dif, s_sum - s_dif - np.pi], th[:, 5])
    return out


def build_sw_ik_context(robot, geo, command: str) -> dict:
    """The closed form of a spherical-wrist arm as its class's derived equations give it."""
    canon = canonical_robot(geo)
    chain, sets = derive_equations(canon, symbolic=False)
    eq_by_id = {e.id: e for s in sets for e in s.equations}
    sf = spherical_forms(chain, {k: sp.expand(e.lhs - e.rhs) for k, e in eq_by_id.items()})
    check = _sw_check(geo, chain, sf)
    thetas = [j.theta for j in chain.joints]
    t1, t2, t3, t4, t5, t6 = thetas

    def eqs(ids):
        return [{"id": i, "lhs": " ".join(side(eq_by_id[i].lhs_terms)),
                 "rhs": " ".join(side(eq_by_id[i].rhs_terms))} for i in ids]

    a1, b1, c1 = sf.theta1
    a3, b3, c3 = sf.theta3
    ns2, nc2, d2 = sf.theta2
    hcos, hsin = sf.halves["cos"], sf.halves["sin"]
    sig1, sig2 = sp.Symbol(r"\sigma_1", real=True), sp.Symbol(r"\sigma_2", real=True)
    steps = [
        {"k": 1, "symbol": latex(t1), "pattern": "S1", "text": PATTERNS["S1"], "check": check["theta1"],
         "equations": eqs(["P.13"]),
         "coefficients": [f"A = {latex(a1)},\\; B = {latex(b1)},\\; C = {latex(c1)}"],
         "forms": [r"\operatorname{atan2}(A, -B) - \operatorname{atan2}\left(-C, \pm\sqrt{A^2 + B^2 - C^2}\right)"]},
        {"k": 2, "symbol": latex(t3), "pattern": "S3", "text": PATTERNS["S3"], "check": check["theta3"],
         "equations": eqs(["P.12", "P.14"]),
         "coefficients": [f"X = {latex(sf.x_def)},\\; Z = {latex(sf.z_def)}",
                          f"A = {latex(a3)},\\; B = {latex(b3)},\\; C = {latex(c3)}"],
         "forms": [r"\operatorname{atan2}(B, A) \pm \operatorname{atan2}\left(\sqrt{A^2 + B^2 - C^2}, -C\right)"]},
        {"k": 3, "symbol": latex(t2), "pattern": "S2", "text": PATTERNS["S2"], "check": check["theta2"],
         "equations": eqs(["P.12", "P.14"]),
         "coefficients": [f"d = {latex(d2)}"],
         "forms": [r"\operatorname{atan2}\left(\operatorname{sgn}(d)\,(" + latex(ns2) + r"),\ "
                   r"\operatorname{sgn}(d)\,(" + latex(nc2) + r")\right)"]},
        {"k": 4, "symbol": latex(t5), "pattern": "half angles", "check": check["theta5"],
         "text": "cos and sin of theta5/2 from the magnitudes of the two wrist pairs (exact at 0 and pi)",
         "equations": eqs(["O.15", "O.16", "O.17", "O.18"]),
         "coefficients": [],
         "forms": [r"\pm 2 \operatorname{atan2}\left(\sqrt{" + latex(hsin[0] ** 2 + hsin[1] ** 2) + r"},\ \sqrt{"
                   + latex(hcos[0] ** 2 + hcos[1] ** 2) + r"}\right)"]},
        {"k": 5, "symbol": latex(sig1) + " = " + latex((t4 + t6) / 2), "pattern": "S2",
         "text": PATTERNS["S2"] + ", divided by " + ("" if hcos[2] == 1 else f"{hcos[2]} ") + "cos(theta5/2)", "check": check["theta4"],
         "equations": eqs(list(hcos[3])), "coefficients": [],
         "forms": [latex(sp.atan2(hcos[0], hcos[1]))]},
        {"k": 6, "symbol": latex(sig2) + " = " + latex((t4 - t6) / 2), "pattern": "S2",
         "text": PATTERNS["S2"] + ", divided by " + ("" if hsin[2] == 1 else f"{hsin[2]} ")
         + "sin(theta5/2) (plus pi on the branch sin(theta5/2) < 0)",
         "check": check["theta6"], "equations": eqs(list(hsin[3])), "coefficients": [],
         "forms": [latex(sp.atan2(hsin[0], hsin[1]))]},
    ]
    return {
        "version": __version__, "command": command, "robot": robot.name, "title": robot.title,
        "sw": class_context(geo, robot), "steps": steps,
        "spans": [f"{latex(t4)} = {latex(sig1 + sig2)}", f"{latex(t6)} = {latex(sig1 - sig2)}"],
        "wrist_singular": WRIST_SINGULAR,
    }
