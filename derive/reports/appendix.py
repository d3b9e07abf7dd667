"""Emission of the derived equations: appendix.md, appendix.tex and equations.json.

The Markdown and LaTeX files are rendered from the jinja2 templates in
``templates/``; equations.json is written with the json module. Nothing in the
outputs depends on the machine or the time (numeric errors are reported as
"below the tolerance", not as the exact value, which may differ in the last bit
between numpy builds), so a second run writes byte-identical files.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
import sympy as sp

from derive._version import __version__
from derive.algebra import dualquat as dq
from derive.cache import claim_folder, write_manifest
from derive.codegen.templates import template_environment
from derive.ik.closed_form import spherical_class
from derive.ik.spherical import SWGeometry, canonical_robot
from derive.ik.tolerances import MAP_POSITION
from derive.model.robot import load_robot
from derive.reports.latex import latex, side
from derive.symbolic.chain import SymChain
from derive.symbolic.equations import NUMERIC_TOL, EquationSet, derive_equations

TERM_NAMES = {1: "w (scalar)", 2: "i", 3: "j", 4: "k", 5: "x", 6: "y", 7: "z"}


def _vec_latex(v) -> str:
    return r"\langle " + ", ".join(latex(sp.sympify(e)) for e in v) + r" \rangle"


def _quat_latex(q) -> str:
    w, x, y, z = (sp.sympify(e) for e in q)
    return "[" + latex(w) + r", \langle " + ", ".join(latex(e) for e in (x, y, z)) + r" \rangle]"


def _equation_context(e, eset: EquationSet) -> dict:
    return {
        "id": e.id,
        "product": e.product,
        "term": e.term,
        "term_name": TERM_NAMES[e.term],
        "lhs": " ".join(side(e.lhs_terms)),
        "rhs_terms": side(e.rhs_terms),
        "lhs_str": sp.sstr(e.lhs),
        "rhs_str": sp.sstr(e.rhs),
        "symbolic": e.symbolic,
        "numeric": e.numeric_error is not None and e.numeric_error < NUMERIC_TOL,
    }


def _set_context(eset: EquationSet, chain: SymChain) -> dict:
    pose = eset.pose
    return {
        "key": eset.key,
        "title": eset.title,
        "source": eset.source,
        "first": eset.first,
        "last": eset.last,
        "zero_last_link": eset.zero_last_link,
        "pose_latex": "(" + _quat_latex(pose[:4]) + ", " + _vec_latex(pose[4:]) + ")",
        "pose_names": [str(p) for p in pose],
        "equations": [_equation_context(e, eset) for e in eset.equations],
    }


def _num(x: float) -> str:
    return f"{x + 0.0:.12g}"


def class_context(geo: SWGeometry, robot) -> dict:
    """The relation of a spherical-wrist robot to its class's canonical chain, for the reports."""
    def pose(d):
        r, t = dq.to_rt(d)
        return {"rotation": [_num(v) for v in r], "translation": [_num(v) for v in t],
                "identity": bool(np.allclose(d, dq.IDENTITY, atol=0))}
    joints = [j.name for j in robot.joints if not j.is_mimic]
    return {
        "values": [(k, _num(v)) for k, v in geo.values.items()],
        "joints": [{"index": i + 1, "name": n, "sign": "+1" if s > 0 else "-1",
                    "offset_deg": _num(float(np.degrees(o))), "offset_rad": _num(float(o))}
                   for i, (n, s, o) in enumerate(zip(joints, geo.signs, geo.offsets))],
        "base": pose(geo.base), "tool": pose(geo.tool), "error": f"below {MAP_POSITION:g}",
    }


def equations_of(robot) -> tuple:
    """(chain, sets, class context or None) of a robot's appendix: its own chain's equations,
    or for a spherical-wrist arm (not of the UR family) those of its class's canonical chain."""
    robot = load_robot(robot)
    geo = spherical_class(robot)
    if geo is None:
        chain, sets = derive_equations(robot)
        return chain, sets, None
    chain, sets = derive_equations(canonical_robot(geo))
    return chain, sets, class_context(geo, robot)


def build_context(robot, chain: SymChain, sets, command: str, sw: dict | None = None) -> dict:
    robot = load_robot(robot)
    g_q, g_t = chain.end_transform
    return {
        "sw": sw,
        "version": __version__,
        "command": command,
        "robot": robot,
        "parameters": [(str(k), latex(k), v) for k, v in chain.parameters.items()],
        "joints": [{"index": j.index, "name": j.name, "type": j.type,
                    "axis": _vec_latex(j.axis), "link": _vec_latex(j.link),
                    "axis_str": [sp.sstr(a) for a in j.axis], "link_str": [sp.sstr(a) for a in j.link]}
                   for j in chain.joints],
        "end_rotation": _quat_latex(g_q),
        "end_translation": _vec_latex(g_t),
        "end_rotation_str": [sp.sstr(sp.sympify(e)) for e in g_q],
        "end_translation_str": [sp.sstr(sp.sympify(e)) for e in g_t],
        "end_is_identity": tuple(sp.sympify(e) for e in g_q) == (1, 0, 0, 0)
        and all(sp.sympify(e) == 0 for e in g_t),
        "sets": [_set_context(s, chain) for s in sets],
        "n_equations": sum(len(s.equations) for s in sets),
        "tolerance": NUMERIC_TOL,
    }


def _json(ctx: dict) -> str:
    data = {
        "robot": ctx["robot"].name,
        "title": ctx["robot"].title,
        "generator": f"dq-derive {ctx['version']}",
        "command": ctx["command"],
        "parameters": {name: value for name, _, value in ctx["parameters"]},
        "chain": [{"joint": j["index"], "name": j["name"], "type": j["type"],
                   "axis": j["axis_str"], "link": j["link_str"]} for j in ctx["joints"]],
        "end_transform": {"rotation": ctx["end_rotation_str"], "translation": ctx["end_translation_str"],
                          "meaning": "robot end frame = chain end frame * G; the pose symbols are "
                                     "the chain end frame, i.e. FK * G^-1"},
        "verification": {"symbolic": "each side identical to its product in half-angle normal form",
                         "numeric_tolerance": ctx["tolerance"],
                         "numeric": "random angles and parameters, pose from derive.reference.fk"},
        "sets": [],
    }
    if ctx["sw"]:
        sw = ctx["sw"]
        data["class"] = {
            "name": "spherical wrist with an ortho-parallel base (OPW)",
            "relation": "FK_robot(q) = B FK_canonical(s q + o) T",
            "parameters": {k: float(v) for k, v in sw["values"]},
            "signs": [int(j["sign"]) for j in sw["joints"]],
            "offsets_rad": [float(j["offset_rad"]) for j in sw["joints"]],
            "base": sw["base"], "tool": sw["tool"],
        }
    for s in ctx["sets"]:
        data["sets"].append({
            "key": s["key"], "title": s["title"], "source": s["source"],
            "products": f"i = {s['first']}..{s['last']}", "zero_last_translation": s["zero_last_link"],
            "pose": s["pose_names"],
            "equations": [{"id": e["id"], "product": e["product"], "term": e["term"],
                           "lhs": e["lhs_str"], "rhs": e["rhs_str"],
                           "verified": {"symbolic": e["symbolic"], "numeric": e["numeric"]}}
                          for e in s["equations"]],
        })
    return json.dumps(data, indent=1, ensure_ascii=True) + "\n"


def write_appendix(robot, out_dir, progress: bool = False, command: str | None = None,
                   force: bool = False) -> list:
    """Derive, verify and write the three files for one robot into out_dir/<robot name>/,
    recorded in its manifest (a folder of another robot is refused unless ``force``); returns
    the paths written."""
    t0 = time.perf_counter()
    robot = load_robot(robot)
    robot_name = robot.name
    claim_folder(Path(out_dir) / robot_name, robot.id, robot_name, force)
    chain, sets, sw = equations_of(robot)
    command = command or f"dq-derive appendix {robot_name}"
    ctx = build_context(robot, chain, sets, command, sw)
    env = template_environment()
    out = Path(out_dir) / robot_name
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in (("appendix.md", env.get_template("appendix.md.j2").render(ctx)),
                       ("appendix.tex", env.get_template("appendix.tex.j2").render(ctx)),
                       ("equations.json", _json(ctx))):
        path = out / name
        path.write_text(text, encoding="utf-8")
        written.append(path)
    written.append(write_manifest(out, {"id": robot.id, "robot": robot_name, "files": {
        "appendix/md": "appendix.md", "appendix/tex": "appendix.tex", "appendix/json": "equations.json"}}))
    if progress:
        print(f"[{robot_name}] wrote {len(written)} files, {ctx['n_equations']} equations "
              f"({time.perf_counter() - t0:.2f} s)", file=sys.stderr)
    return written
