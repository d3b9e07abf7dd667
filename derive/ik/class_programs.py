"""The shipped symbolic IK of the 6R classes: derived once with the class's canonical lengths as
sympy symbols, stored in ``derive/data/ik_classes.json``, read back here.

A new robot of a known class then gets its IK program by substitution (its lengths for the
symbols, its frames by a pose transform before the program), never by a symbolic derivation on
its own chain (:func:`derive.ik.program.ik_program`):

* ``ur``: the IK program of the UR family's chain in thesis form (:mod:`derive.ik.closed_form`,
  axes z, -y, -y, -y, -z, -y; lengths d1, a2, a3, d4, d5, d6), extracted from its derived
  equations (:mod:`derive.ik.extract`, the sets B, W, C of thesis section 4.3.5) for a canonical
  description written like ``ur5.yaml`` with its lengths as parameters, and the end transform
  ``g`` of that description's chain;
* ``spherical``: the symbolic pieces of the spherical-wrist (OPW) closed form taken from the
  equations (sets P and O) of the class's canonical chain with the parameters a1 ... c4
  (:func:`derive.ik.program.spherical_forms`), the chain's end transform and first three axes.

The 7-joint classes (:mod:`derive.ik.program7`) need no shipped derivation: their programs are
written from the numeric closed forms with the robot's numbers.

The file is written by ``dq-derive generate`` (``make generate``,
:func:`derive.ik.program.write_class_data`); ``tests/test_first_use.py`` derives it again and
compares it byte for byte. Every expression is stored as sympy's ``srepr`` text, which is read
back by evaluating it in sympy's namespace (the file is package data, never user input).
"""

from __future__ import annotations

import json
from pathlib import Path

import sympy as sp

from derive.cache import memo
from derive.errors import DeriveError
from derive.ik.ir import IKProgram, Op

#: The shipped file.
DATA = Path(__file__).resolve().parent.parent / "data" / "ik_classes.json"
#: Version of the file's layout; a file of another layout is refused.
FORMAT = 1

_NS: dict = {}


def dump_expr(e):
    """An expression, a number or a string as its ``srepr`` text (None stays None)."""
    if e is None:
        return None
    return sp.srepr(e if isinstance(e, (str, sp.Basic)) else sp.sympify(e))


def load_expr(v):
    """The value of :func:`dump_expr`'s text."""
    if v is None:
        return None
    if not _NS:
        _NS.update({k: getattr(sp, k) for k in dir(sp) if not k.startswith("_")})
    return eval(v, _NS)      # noqa: S307 -- package data written by dump_expr


def dump_op(op: Op) -> dict:
    return {"kind": op.kind, "name": op.name, "name2": op.name2, "depth": op.depth,
            "expr": dump_expr(op.expr), "cond": dump_expr(op.cond), "other": dump_expr(op.other),
            "args": [dump_expr(a) for a in op.args]}


def load_op(d: dict) -> Op:
    return Op(d["kind"], d["name"], load_expr(d["expr"]), d["name2"], load_expr(d["cond"]),
              load_expr(d["other"]), tuple(load_expr(a) for a in d["args"]), d["depth"])


def dump_program(prog: IKProgram) -> dict:
    return {"dof": prog.dof, "ops": [dump_op(op) for op in prog.ops], "branches": prog.branches,
            "free_joint": prog.free_joint, "free_rule": prog.free_rule,
            "steps": [[dump_expr(u), p, [str(e) for e in eqs]] for u, p, eqs in prog.steps],
            "parameters": [dump_expr(s) for s in prog.parameters],
            "branch_labels": list(prog.branch_labels)}


def load_program(d: dict, name: str) -> IKProgram:
    return IKProgram(name, d["dof"], ops=[load_op(o) for o in d["ops"]], branches=d["branches"],
                     free_joint=d["free_joint"], free_rule=d["free_rule"],
                     steps=[(load_expr(u), p, list(eqs)) for u, p, eqs in d["steps"]],
                     parameters={load_expr(s): None for s in d["parameters"]},
                     branch_labels=list(d["branch_labels"]))


def render(data: dict) -> str:
    """The file's text: sorted keys, one value a line, so that it is stable and diffs read."""
    return json.dumps({"format": FORMAT, **data}, sort_keys=True, indent=0) + "\n"


def class_data() -> dict:
    """The shipped file, parsed (once per process); DeriveError when it is missing or of
    another layout (``make generate`` writes it)."""
    return memo("ik-class-data", None, _read)


def _read() -> dict:
    try:
        data = json.loads(DATA.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise DeriveError(f"the shipped class programs {DATA} do not load ({exc}); run make "
                          "generate") from None
    if data.get("format") != FORMAT:
        raise DeriveError(f"{DATA} has layout {data.get('format')}, this dq-derive reads {FORMAT}: "
                          "run make generate")
    return data


def ur_template() -> tuple:
    """(program with the symbols d1 ... d6, {name: symbol}, end transform g of its chain as
    (quaternion, translation) of sympy numbers) of the UR class; once per process."""
    return memo("ik-class-ur", None, _ur_template)


def _ur_template() -> tuple:
    d = class_data()["ur"]
    prog = load_program(d["program"], "ur-canonical")
    params = {str(s): s for s in prog.parameters}
    gq, gt = ([load_expr(e) for e in part] for part in d["g"])
    return prog, params, (tuple(gq), tuple(gt))


def spherical_template() -> dict:
    """The spherical-wrist class's symbolic pieces (see the module docstring): ``thetas``,
    ``parameters`` ({name: symbol}), ``axes`` (of joints 1-3), ``g`` (quaternion, translation)
    and ``forms`` (the fields of :class:`derive.ik.program.SphericalForms`); once per process."""
    return memo("ik-class-spherical", None, _spherical_template)


def _spherical_template() -> dict:
    d = class_data()["spherical"]
    f = d["forms"]
    forms = {k: tuple(load_expr(e) for e in f[k]) for k in ("theta1", "theta3", "theta2")}
    forms.update({k: load_expr(f[k]) for k in ("x_def", "z_def", "X", "Z")})
    forms["halves"] = {k: (load_expr(ns), load_expr(nc), load_expr(kk), tuple(ids))
                       for k, (ns, nc, kk, ids) in f["halves"].items()}
    params = [load_expr(s) for s in d["parameters"]]
    return {"thetas": [load_expr(t) for t in d["thetas"]],
            "parameters": {str(s): s for s in params},
            "axes": [tuple(load_expr(a) for a in ax) for ax in d["axes"]],
            "g": tuple(tuple(load_expr(e) for e in part) for part in d["g"]),
            "forms": forms}
