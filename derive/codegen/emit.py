"""Emission of the numeric kernels (pure Python, numpy, C99) from :mod:`derive.codegen.fk`.

Every file is standalone (copy it into another project and it works) and starts with a
header naming the robot, its parameters, the dq-derive version and the command that made it.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import sympy as sp
from sympy.printing.c import C99CodePrinter
from sympy.printing.numpy import NumPyPrinter
from sympy.printing.pycode import PythonCodePrinter

from derive._version import __version__
from derive.cache import claim_folder, step, task, write_manifest
from derive.codegen.fk import fk_kernel
from derive.codegen.general6r import general_context as general6r_context
from derive.codegen.formats import FILES, KERNEL_FORMAT, nominal_key  # defined there for the loader
from derive.codegen.polish import held_joint, nominal_program, polish_context, polish_width
from derive.codegen.templates import template_environment
from derive.errors import DeriveError
from derive.ik.closed_form import MERGE_TOL
from derive.ik.select import LIMIT_SLACK
from derive.ik.tolerances import SP_ROOT_MODULUS
from derive.ik.tolerances import (ROOTS4_BIQUADRATIC, ROOTS4_DK_STOP, ROOTS4_LEAD, ROOTS4_NEWTON_DF,
                                  ROOTS4_NEWTON_STEP)
from derive.ik.ir import leaf_of, leaf_weights, roots4_names
from derive.ik.program import ik_program
from derive.ik.redundant import FREE_CHOICES, redundant_kind
from derive.model.robot import load_robot


def identifier(robot_name: str) -> str:
    """The C / Python identifier stem of a robot name (``ur10e``, ``seed_arm``, ``r_3dof``)."""
    stem = robot_name.replace("-", "_").replace(".", "_")
    return stem if stem[:1].isalpha() else "r_" + stem


def _prefix(robot, free: str | None = None) -> str:
    """The stem of the kernels' C identifiers and file names: the robot's identifier, and for the
    kernels of an alternative free parameter that too (``iiwa14_q3_ik``), so that both sets can
    be linked into one program."""
    return identifier(robot.name) + (f"_{free}" if free else "")


def _is_half(e) -> bool:
    return e == sp.S.Half or (e.is_Float and float(e) == 0.5)


class _Shared:
    """Rules all three printers share: floats and pi as plain literals, x**2 as x*x, x**0.5 as
    a square root, and the program's functions sgn(x) and pos(x) = max(x, 0). Each printer names
    its spellings in SQRT, SGN and POS (format strings of the argument)."""

    SQRT = SGN = POS = ""

    def _print_Pow(self, expr, *args, **kwargs):
        if expr.exp == 2:
            b = self._print(expr.base)
            return f"{b}*{b}" if expr.base.is_Symbol else f"({b})*({b})"
        if _is_half(expr.exp):
            return self.SQRT.format(self._print(expr.base))
        return super()._print_Pow(expr, *args, **kwargs)

    def _print_Float(self, expr):
        return repr(float(expr))

    def _print_Pi(self, expr):
        return repr(float(sp.pi))

    def _print_Function(self, expr):
        spelling = {"sgn": self.SGN, "pos": self.POS}.get(expr.func.__name__)
        if spelling:
            return spelling.format(self._print(expr.args[0]))
        return super()._print_Function(expr)


class _Py(_Shared, PythonCodePrinter):
    """Pure Python with ``math`` imported as names (sqrt, atan2, copysign)."""

    SQRT, SGN, POS = "sqrt({})", "copysign(1.0, {})", "max({}, 0.0)"

    def _print_atan2(self, expr):
        return f"atan2({self._print(expr.args[0])}, {self._print(expr.args[1])})"

    def _print_Abs(self, expr):
        return f"abs({self._print(expr.args[0])})"

    def _print_Max(self, expr):
        return f"max({', '.join(self._print(a) for a in expr.args)})"


class _Np(_Shared, NumPyPrinter):
    """numpy with ``import numpy as np``; elementwise over a batch."""

    SQRT, SGN, POS = "np.sqrt({})", "np.copysign(1.0, {})", "np.maximum({}, 0.0)"

    def __init__(self):
        super().__init__({"fully_qualified_modules": False})

    def _module_format(self, fqn, register=True):
        return "np." + fqn.split(".")[-1] if fqn.startswith("numpy.") else fqn

    def _print_Max(self, expr):
        a, b = expr.args
        return f"np.maximum({self._print(a)}, {self._print(b)})"


class _C(_Shared, C99CodePrinter):
    # compares, not fmax (a library call without -ffast-math), and the choice a branch-free
    # blend dq_sel(c, a, b) = c ? a : b of the template, so that the batch loops vectorise
    SQRT, SGN, POS = "sqrt({})", "copysign(1.0, {})", "dq_sel(({0}) > 0.0, {0}, 0.0)"
    # constants as numbers, never the macros M_PI_4, M_SQRT2 ... (not C99: absent under -std=c99)
    math_macros: dict = {}

    def _print_Max(self, expr):
        a, b = (self._print(e) for e in expr.args)
        return f"dq_sel(({a}) > ({b}), {a}, {b})"

    def _print_And(self, expr):         # flags are 0/1 ints: no short circuit, so loops vectorise
        return " & ".join(f"({self._print(a)})" for a in expr.args)

    def _print_Or(self, expr):
        return " | ".join(f"({self._print(a)})" for a in expr.args)

    def _print_Not(self, expr):
        return f"!({self._print(expr.args[0])})"

    def _print_atan2(self, expr):
        return f"dq_atan2({self._print(expr.args[0])}, {self._print(expr.args[1])})"


def _arg(printer, a, column):
    """An expression as code, the joint variables q0, q1, ... replaced by column(k)."""
    qs = [s for s in a.free_symbols if re.fullmatch(r"q\d+", s.name)]
    return printer.doprint(a.xreplace({s: sp.Symbol(column(int(s.name[1:]))) for s in qs}))


def _context(robot, command: str, free: str | None = None, nominal=None) -> dict:
    """The templates' context; ``nominal`` (a :class:`derive.ik.nearclass.Nominal`): the IK is the
    nominal robot's program polished on the robot's own FK (:mod:`derive.codegen.polish`)."""
    k = fk_kernel(robot)
    py, c = _Py(), _C()
    trig = []
    for s, co, a in k.trig:
        if isinstance(a, tuple) and a[0] == "double":
            trig.append({"s": s, "c": co, "derived": True, "se": f"2.0*{a[1]}*{a[2]}",
                         "ce": f"1.0 - 2.0*{a[1]}*{a[1]}"})
        elif isinstance(a, tuple):             # ("sum", s_x, c_x, s_y, c_y, sign): x + sign y
            _, sx, cx, sy, cy, sign = a
            pm, mp = ("+", "-") if sign > 0 else ("-", "+")
            trig.append({"s": s, "c": co, "derived": True, "se": f"{sx}*{cy} {pm} {cx}*{sy}",
                         "ce": f"{cx}*{cy} {mp} {sx}*{sy}"})
        else:
            trig.append({"s": s, "c": co, "derived": False, "k": sum(not t["derived"] for t in trig),
                         "py": _arg(py, a, lambda i: f"q[{i}]"),
                         "np": _arg(py, a, lambda i: f"Q[:, {i}]"),
                         "cc": _arg(c, a, lambda i: f"q[{i}]")})
    columns = {"py": lambda i: f"q[{i}]", "np": lambda i: f"Q[:, {i}]", "cc": lambda i: f"q[{i}]"}
    printer = {"py": py, "np": py, "cc": c}

    def code(e):
        """An expression in each language, joint variables (prismatic joints enter linearly)
        written as the input's elements."""
        return {lang: _arg(printer[lang], e, col) for lang, col in columns.items()}

    temps = [{"name": str(n), **code(e)} for n, e in k.temps]
    outs = [code(e) for e in k.outputs]
    _mark_used_c(trig, temps, outs)
    limits = _limit_context(robot)
    return {
        "version": __version__, "command": command, "robot": robot, "id": _prefix(robot, free),
        "dof": robot.dof, "parameters": [(str(p), f"{float(v):.12g}") for p, v in k.parameters.items()],
        "trig": trig, "temps": temps, "outputs": outs, "n_sincos": k.n_sincos,
        "n_sincos_padded": -(-k.n_sincos // 4) * 4,
        "limits": limits,
        "always_winding": all(lim["revolute"] and lim["full_turn"] for lim in limits),
        **_ik_context(robot, free, nominal),
        "polish": None if nominal is None else _polish_context(robot, nominal, free),
    }


def _polish_context(robot, nominal, free=None) -> dict:
    """:func:`derive.codegen.polish.polish_context` with this module's printers, each let line
    marked ``used`` when the C code reads it (no unused variable under -Wall -Werror)."""
    prog = nominal_program(robot, nominal, free)
    hold = held_joint(prog)
    ctx = polish_context(robot, nominal, {"py": _Py(), "cc": _C()}, hold)
    # the output width: the nominal's branches, then the extra slots of the seeds' solutions
    ctx["branches"] = prog.branches
    ctx["width"] = polish_width(prog.branches, robot.dof - (hold is not None))
    used: set = set()
    for e in [*ctx["R"], *ctx["t"]]:
        used.update(_IDENT.findall(e["cc"]))
    for col in ctx["cols"]:
        for e in col["z"] + ([] if col["prismatic"] else col["c"]):
            used.update(_IDENT.findall(e["cc"]))
    for d in reversed(ctx["lines"]):
        if d["kind"] == "let":
            d["used"] = d["name"] in used
            if d["used"]:
                used.update(_IDENT.findall(d["cc"]))
        else:
            d["use_s"], d["use_c"] = d["s"] in used, d["c"] in used
    return ctx


def _mark_used_c(trig, temps, outs) -> None:
    """Mark in place which FK names the C code reads (``used`` on temps, ``use_s`` / ``use_c``
    on sines and cosines), so that the C kernels declare no unused variable (-Wall -Werror as C
    and C++: a sine whose cosine the products never need, a temp of a dropped output)."""
    used: set = set()
    for o in outs:
        used.update(_IDENT.findall(o["cc"]))
    for t in reversed(temps):
        t["used"] = t["name"] in used
        if t["used"]:
            used.update(_IDENT.findall(t["cc"]))
    for t in reversed(trig):
        t["use_s"], t["use_c"] = t["s"] in used, t["c"] in used
        if t["derived"]:
            if t["use_s"]:
                used.update(_IDENT.findall(t["se"]))
            if t["use_c"]:
                used.update(_IDENT.findall(t["ce"]))


def _limit_context(robot) -> list:
    """Per joint its limits as C literals with the slack of :mod:`derive.ik.select` (``lo``,
    ``hi``; +-INFINITY where the description gives none), as written (``lo_text``,
    ``hi_text``), whether it is revolute (the nearest winding is chosen for those) and whether
    its range spans a full turn (``full_turn``: hi - lo >= 2 pi + 1e-9, so every angle has a
    winding inside the limits and the nearest pass skips that test)."""
    def lit(x):
        return repr(float(x)) if math.isfinite(x) else ("INFINITY" if x > 0 else "-INFINITY")

    return [{"lo": lit(lo - LIMIT_SLACK), "hi": lit(hi + LIMIT_SLACK), "lo_text": f"{lo:.6g}",
             "hi_text": f"{hi:.6g}", "revolute": rev, "full_turn": bool(hi - lo >= 2.0 * math.pi + 1e-9)}
            for (lo, hi), rev in zip(robot.limits.tolist(), robot.revolute.tolist())]


def _ik_context(robot, free: str | None = None, nominal=None) -> dict:
    """The IK program's lines printed for each language ("ik" is None when the robot has none);
    ``free`` as :func:`derive.ik.program.ik_program`; ``nominal``: the program of
    :func:`derive.codegen.polish.nominal_program` (a DeriveError when it has none)."""

    if nominal is not None:
        prog = nominal_program(robot, nominal, free)
    else:
        try:
            prog = ik_program(robot, free)
        except DeriveError as exc:
            general = _general_ik_context(robot, free)
            return general or {"ik": None, "ik_missing": str(exc)}
    # the branching program is printed for the Python kernels; the C kernels run the flat one
    printers = {"py": _Py(), "np": _Np()}

    def numeric(e):
        e = sp.sympify(e)
        if isinstance(e, (sp.Rel, sp.And, sp.Or, sp.Not)):
            return e.func(*[numeric(a) for a in e.args])
        return e if e.is_Symbol else sp.N(e, 17)

    def pr(e):
        e = numeric(e)
        return {lang: p.doprint(e) for lang, p in printers.items()}

    ops = []
    branch_index = []
    for op in prog.ops:
        d = {"kind": op.kind, "name": op.name, "name2": op.name2, "depth": op.depth}
        if op.kind in ("let", "sincos", "require", "flag"):
            d["e"] = pr(op.expr)
        if op.kind == "select":
            d["e"], d["cond"], d["other"] = pr(op.expr), pr(op.cond), pr(op.other)
        if op.kind == "double":
            d["hs"], d["hc"] = op.args
        if op.kind == "solution":
            d["q"] = [pr(e) for e in op.args]
        if op.kind == "branch":
            d["index"] = "b" + op.name[2:]
            branch_index.append(d["index"])
        if op.kind == "roots4":
            d["coef"], d["names"] = [pr(e) for e in op.args], list(roots4_names(op.name))
        ops.append(d)
    k = len(branch_index)
    leaf = " + ".join(f"{w}*{b}" if w != 1 else b for w, b in zip(leaf_weights(prog), branch_index))
    flat_raw = _flat_ops(prog, _C(), numeric)
    flat_full = _live(flat_raw, full=True)
    roots4 = _roots4_context(prog, flat_raw)
    if roots4 and roots4["prefix"]:           # the vectorised loop reads the roots from the block
        flat = _live([{**d, "loaded": True} if d["kind"] == "roots4" else d for d in flat_raw])
    else:
        flat = _live(flat_raw)
    # per leaf and joint, the first leaf whose value of that joint is the same expression (theta1
    # is common to four leaves of the UR, ...): the nearest pass computes each value's winding once
    first: dict = {}
    same_as = [[0] * robot.dof for _ in range(prog.branches)]
    for d in flat:
        if nominal is not None and d["kind"] == "solution":   # polished: no two leaves share a value
            same_as[d["leaf"]] = [d["leaf"]] * robot.dof
        elif d["kind"] == "solution":
            for j, e in enumerate(d["q"]):
                same_as[d["leaf"]][j] = first.setdefault((j, e), d["leaf"])
    near, dups = _duplicate_tests(same_as, prog.branches, robot.dof)
    gates = _duplicate_gates(near, dups)
    step_lines = [f"{u}: {pat}" + (f" ({', '.join(e)})" if e else "") for u, pat, e in prog.steps]
    labels = list(prog.branch_labels) or [f"step {i + 1}" for i in range(k)]
    # labels are in the order of significance: weights 2^(k-1) ... 1
    bits = [f"{2 ** (k - 1 - i)} x ({lab}: 1 for the second root)" for i, lab in enumerate(labels)]
    branch_doc = "index = " + " + ".join(bits) if bits else "always 0"
    return {"ik": {"ops": ops, "branches": prog.branches,
                   "branch_doc": branch_doc, "branch_labels": labels,
                   "free_joint": prog.free_joint, "free_rule": prog.free_rule,
                   "leaf": leaf or "0", "flat": flat, "flat_full": flat_full, "merge_tol": repr(MERGE_TOL), "steps": step_lines,
                   "singular_flag": any(op.kind == "flag" and op.name == "singular" for op in prog.ops),
                   "same_as": same_as, "near": near, "dups": dups, "gates": gates,
                   "free": prog.free, "free_doc": prog.free_doc,
                   "singular_doc": prog.singular_doc or "sin theta5 = 0",
                   "steps_source": prog.steps_source or "from the derived equations",
                   # the root finder of the "roots4" lines, printed only where a program has them
                   "roots4": roots4},
            "ik_missing": ""}


def _roots4_context(prog, flat_raw):
    """What the printers need for the program's "roots4" lines (None without one): the root
    test's threshold and, for the C batch loop, ``prefix``: where the program has one such line,
    outside every branch, the flat lines its coefficients need and the line itself
    (``roots4_store``), which the C template runs in a scalar loop of their own before the
    vectorised loop (which then reads the roots from the block: a call inside it would keep the
    whole loop from vectorising); None otherwise (the loop calls the root finder)."""
    at = [i for i, d in enumerate(flat_raw) if d["kind"] == "roots4"]
    if not at:
        return None
    prefix = None
    if len(at) == 1 and sum(op.kind == "roots4" and op.depth == 0 for op in prog.ops) == 1:
        pre = [d for d in flat_raw[:at[0]] if not d["kind"].startswith("ok_")]
        prefix = _live(pre + [{**flat_raw[at[0]], "kind": "roots4_store"}])
    return {"root_modulus": repr(SP_ROOT_MODULUS), "prefix": prefix, "lead": _power_literal(ROOTS4_LEAD),
            "dk_stop": _power_literal(ROOTS4_DK_STOP), "biquadratic": _power_literal(ROOTS4_BIQUADRATIC),
            "newton_df": _power_literal(ROOTS4_NEWTON_DF), "newton_step": _power_literal(ROOTS4_NEWTON_STEP)}


def _power_literal(x: float) -> str:
    """A tolerance of one significant digit (a power of ten) as a C and Python literal without
    padding (1e-8, not 1e-08): the form the roots4 templates had written in; ValueError for
    another value."""
    text = f"{x:.0e}".replace("e-0", "e-").replace("e+0", "e+")
    if float(text) != x:
        raise ValueError(f"{x!r} has more than one significant digit")
    return text


def _general_ik_context(robot, free=None):
    """The IK context of a six-revolute arm without a closed-form class: the general 6R solver
    (:mod:`derive.codegen.general6r`), or None when it does not apply (not a 6R, a 7-joint arm's
    free parameter, or no elimination for this geometry)."""
    if free is not None or robot.dof != 6 or not all(robot.revolute.tolist()):
        return None
    try:
        g = general6r_context(robot)
    except DeriveError:
        return None
    return {"ik": {"general": g, "branches": g["max_solutions"], "free": None, "free_joint": 0,
                   "free_rule": "one of its values (a continuum of solutions is not enumerated)",
                   "singular_doc": "the Jacobian's smallest singular value below "
                                   f"{g['singular']} of its largest",
                   "branch_doc": "no branches: the index of the solution in the order of joint 1",
                   "branch_labels": [], "merge_tol": repr(MERGE_TOL), "singular_flag": True,
                   "steps": [f"general 6R: {g['how']}"], "steps_source": "derive.ik.general6r"},
            "ik_missing": ""}


def _duplicate_tests(same_as, branches: int, dof: int):
    """The batch loop's duplicate test (candidate i is dropped when an earlier valid candidate a
    is within the merge tolerance in every joint, as the Python kernels' merge) with each
    distinct pair of values compared once. Leaves whose value of joint k is the same expression (``same_as``) are
    equal there and need no test; theta1 is one of two values for all 8 leaves of the UR, so its
    28 leaf pairs need 1 comparison. Returns the comparisons [(flag name, joint, leaf x, leaf y)]
    and per leaf i > 0 the list [(a, [flag names])] of its earlier leaves and the flags that must
    all hold for a to be its duplicate."""
    near, names, dups = [], {}, []
    for i in range(1, branches):
        row = []
        for a in range(i):
            flags = []
            for k in range(dof):
                x, y = sorted((same_as[i][k], same_as[a][k]), reverse=True)
                if x == y:
                    continue
                if (k, x, y) not in names:
                    names[(k, x, y)] = f"near{k}_{x}_{y}"
                    near.append((names[(k, x, y)], k, x, y))
                flags.append(names[(k, x, y)])
            row.append((a, flags))
        dups.append((i, row))
    return near, dups


def _duplicate_gates(near, dups) -> list:
    """A few near flags of :func:`_duplicate_tests` such that every pair of candidates has one of
    them among the flags that must all hold for a duplicate (chosen greedily, the flag in most
    pairs first), each as its comparison (flag name, joint, leaf x, leaf y) of ``near`` with the
    pairs it stands for: [((flag, k, x, y), [(i, a), ...])]. Where no flag holds
    together with both candidates of one of its pairs being valid, for any pose of a block, no
    candidate is a duplicate and the batch loop skips the full test. For the UR, 7 of the 97
    comparisons: theta1's pair (all 16 pairs across its two roots), theta5's per theta1 root and
    one of the three joints the last step chooses. Empty when some pair has no flag at all (the
    test then always runs)."""
    pairs = [((i, a), set(flags)) for i, row in dups for a, flags in row]
    if not pairs or any(not f for _, f in pairs):
        return []
    comparison = {c[0]: c for c in near}
    gates = []
    while pairs:
        count: dict = {}
        for _, flags in pairs:
            for f in flags:
                count[f] = count.get(f, 0) + 1
        best = max(sorted(count), key=lambda f: count[f])    # sorted: the same choice every run
        gates.append((comparison[best], [ia for ia, flags in pairs if best in flags]))
        pairs = [(ia, flags) for ia, flags in pairs if best not in flags]
    return gates


def _singular_only(cond) -> bool:
    """Whether a select's condition can hold only where the program's ``singular`` flag is set
    (the flag itself or one of the flags ``singular_*`` it is the union of, alone or in a
    conjunction): the batch loop then takes the other arm and
    leaves the singular poses to a scalar pass (``dq_singular_block`` in the C template)."""
    cond = sp.sympify(cond)
    terms = cond.args if isinstance(cond, sp.And) else (cond,)
    return any(t.is_Symbol and (t.name == "singular" or t.name.startswith("singular_")) for t in terms)


def _magnitude_bounds(prog) -> dict:
    """Per name of the IK program an upper bound of its magnitude (inf where none is known): an
    atan2 is at most pi (pi/2 when both its arguments are square roots or absolute values),
    sines, cosines and branch signs at most 1, sums and products bounded by their terms'. A
    joint value bounded by pi already lies in [-pi, pi] and needs no wrap (dq_wrap would change
    only -pi into pi and -0 into 0)."""
    inf = math.inf
    bound: dict = {}
    nonnegative: set = set()          # names defined as a square root or an absolute value

    def nonneg(e):
        return (isinstance(e, sp.Abs) or (e.is_Pow and e.exp == sp.Rational(1, 2))
                or (e.is_Symbol and e.name in nonnegative))

    def mag(e):
        if e.is_number:
            return abs(float(e))
        if e.is_Symbol:
            return bound.get(e.name, inf)
        if isinstance(e, sp.atan2):
            return math.pi / 2 if all(nonneg(a) for a in e.args) else math.pi
        if isinstance(e, (sp.sin, sp.cos)):
            return 1.0
        if e.is_Add:
            return sum(mag(a) for a in e.args)
        if e.is_Mul:
            terms = [mag(a) for a in e.args]
            return 0.0 if 0.0 in terms else math.prod(terms)
        return inf

    for op in prog.ops:
        if op.kind == "branch":
            bound[op.name] = 1.0
        elif op.kind == "let":
            e = sp.sympify(op.expr)
            bound[op.name] = mag(e)
            if nonneg(e):
                nonnegative.add(op.name)
        elif op.kind == "select":
            bound[op.name] = max(mag(sp.sympify(op.expr)), mag(sp.sympify(op.other)))
        elif op.kind in ("sincos", "double"):
            bound[op.name] = bound[op.name2] = 1.0
        elif op.kind == "roots4":           # angles in (-pi, pi], flags 0 or 1
            names = roots4_names(op.name)
            bound.update({n: math.pi for n in names[:4]} | {n: 1.0 for n in names[4:]})
    return bound


def _flat_ops(prog, printer, numeric) -> list:
    """The IK program with every branch unrolled (C, for the vectorised batch loop).

    A name defined at depth d gets the suffix of the first d branch bits of the path it
    belongs to (theta1_0, theta1_1, ...); branch signs become constants; "require" lines
    become validity flags ok_<path>; each leaf writes its candidate and its flag. The paths are
    unrolled depth first (see ``walk``)."""

    depth_of: dict = {}
    for op in prog.ops:
        if op.kind in ("let", "flag", "select", "branch"):
            depth_of[op.name] = op.depth
        if op.kind in ("sincos", "double"):
            depth_of[op.name] = depth_of[op.name2] = op.depth
        if op.kind == "roots4":
            depth_of.update({n: op.depth for n in (op.name, *roots4_names(op.name))})

    def name(n, path):
        d = depth_of[n]
        return n if d == 0 else f"{n}_{''.join(map(str, path[:d]))}"

    def rename(e, path):
        e = sp.sympify(e)
        return e.xreplace({s_: sp.Symbol(name(s_.name, path), real=True)
                           for s_ in e.free_symbols if s_.name in depth_of})

    def pr(e, path):
        return printer.doprint(numeric(rename(e, path)))

    def ok(path):
        return "ok_" + "".join(map(str, path)) if path else "ok"

    bounds = _magnitude_bounds(prog)

    def line(op, path):
        """One op of the program on one branch path, as a flat line."""
        d = {"kind": op.kind, "name": name(op.name, path) if op.name else ""}
        if op.kind == "branch":
            return [{"kind": "ok_copy", "name": ok(path), "e": ok(path[:-1])},
                    {"kind": "let", "name": name(op.name, path), "e": "-1.0" if path[-1] else "1.0"}]
        if op.kind in ("let", "flag"):
            d["e"] = pr(op.expr, path)
        elif op.kind == "select":
            d["e"], d["cond"], d["other"] = pr(op.expr, path), pr(op.cond, path), pr(op.other, path)
            d["regular"] = _singular_only(op.cond)
        elif op.kind == "sincos":
            d["e"], d["name2"] = pr(op.expr, path), name(op.name2, path)
        elif op.kind == "double":
            d["name2"] = name(op.name2, path)
            d["hs"], d["hc"] = (name(a, path) for a in op.args)
        elif op.kind == "require":
            d = {"kind": "ok_and", "name": ok(path), "e": pr(op.expr, path)}
        elif op.kind == "roots4":
            d["names"] = [name(n, path) for n in roots4_names(op.name)]
            d["coef"] = [pr(e, path) for e in op.args]
        elif op.kind == "solution":
            leaf = leaf_of(prog, path)
            d = {"kind": "solution", "leaf": leaf, "ok": ok(path), "q": [pr(e, path) for e in op.args],
                 "wrap": [bounds.get(str(e), math.inf) > math.pi for e in op.args],
                 "sing": name("singular", path) if "singular" in depth_of else "0"}
        return [d]

    ops = prog.ops
    out = [{"kind": "ok_init", "name": "ok"}]

    def walk(i, path):
        """Depth first, as the nested loops run: the ops from i on at the depth of path, each
        branch's body first for the root 0, then for the root 1. Every path's values are then
        dead before the next path starts, which keeps the vectorised loop's live values (and
        register spills) down. Returns the index of the first op outside the body."""
        while i < len(ops) and ops[i].depth >= len(path):
            if ops[i].kind == "branch" and ops[i].depth == len(path) + 1:
                for root in (0, 1):
                    out.extend(line(ops[i], path + (root,)))
                    end = walk(i + 1, path + (root,))
                i = end
            else:
                out.extend(line(ops[i], path))
                i += 1
        return i

    walk(0, ())
    return out


_IDENT = re.compile(r"[A-Za-z_]\w*")


def _live(flat: list, full: bool = False) -> list:
    """The flat lines without the values nothing reads: where a select's condition can hold only
    on a singular set (``regular``), its first arm is left to the scalar pass, and the lines that
    only it read go (no unused variables in the emitted C). ``full``: for the whole program of
    the scalar pass (every select with both arms), only the values nothing reads go."""
    live: set = set()
    kept = []
    for d in reversed(flat):
        if d["kind"] in ("let", "flag", "select", "sincos", "double"):
            names = {d["name"], d.get("name2")}
            if not names & live:
                continue
        if d["kind"] == "roots4":
            if not set(d["names"]) & live:
                continue
            d = {**d, "used": [n in live for n in d["names"]]}     # one call, the names read
        if d["kind"] == "select":
            reads = [d["other"]] if d["regular"] and not full else [d["e"], d["cond"], d["other"]]
        elif d["kind"] == "double":
            reads = [d["hs"], d["hc"]]
        elif d["kind"] in ("roots4", "roots4_store"):
            reads = [] if d.get("loaded") else d["coef"]
        elif d["kind"] == "solution":
            reads = [*d["q"], d["ok"], d["sing"]]
        else:
            reads = [d.get("e", "")]
        if d["kind"] in ("ok_copy", "ok_and"):
            reads.append(d["name"])
        for text in reads:
            live.update(_IDENT.findall(str(text)))
        kept.append(d)
    return kept[::-1]


#: The CMake package written beside the C kernels by :func:`write_kernels` (not a kernel: the
#: loader neither needs nor checks them).
CMAKE_FILES = {
    "cmake_lists": ("CMakeLists.txt.j2", "CMakeLists.txt"),
    "cmake_config": ("kinematicsConfig.cmake.j2", "{id}_kinematicsConfig.cmake"),
}


def render_cmake(robot, command: str | None = None) -> dict:
    """{role: (file name, text)} of the CMake package of a robot's C kernels (:data:`CMAKE_FILES`):
    a library target, install rules and ``<id>_kinematicsConfig.cmake``, so that
    ``find_package(<id>_kinematics)`` finds the installed kernels."""
    robot = load_robot(robot)
    ctx = {"version": __version__, "version_numeric": re.match(r"\d+(\.\d+)*", __version__).group(0),
           "command": command or f"dq-derive kernels {robot.name}", "robot": robot, "id": _prefix(robot)}
    env = template_environment()
    return {role: (name.format(id=ctx["id"]), env.get_template(tpl).render(ctx))
            for role, (tpl, name) in CMAKE_FILES.items()}


def render_ikfast(robot, command: str | None = None) -> tuple:
    """(file name, text) of the IKFast 61 drop-in of a robot with a closed-form IK
    (``<id>_ikfast_solver.cpp``, templates/ikfast_solver.cpp.j2): the IKFast C++ API on the C
    kernels, which it embeds (renamed ``<id>_ikfast_*`` and compiled as C++ in the including
    file's namespace, so they clash neither with the robot's C library nor with another robot's
    solver). A seven-joint arm's free parameter is a joint, as IKFast's is: q7 for the Panda
    class, q3 (the joint-3 kernels) for the SRS class."""
    robot = load_robot(robot)
    command = command or f"dq-derive kernels {robot.name} --ikfast"
    free = "q3" if "q3" in FREE_CHOICES.get(redundant_kind(robot) or "", ()) else None
    ctx = _context(robot, command, free)
    if ctx["ik"] is None:
        raise DeriveError(f"{robot.name}: no closed-form IK kernel ({ctx['ik_missing']}); an IKFast drop-in "
                          "needs one")
    prefix = ctx["id"]
    ctx["id"] = f"{prefix}_ikfast"
    env = template_environment()
    header = env.get_template("kinematics.h.j2").render(ctx)
    source = env.get_template("kinematics.c.j2").render(ctx).replace(
        f'#include "{ctx["id"]}_kinematics.h"\n', "")
    prog_free = ctx["ik"]["free"]
    free_index = int(prog_free[1:]) - 1 if prog_free else None
    if prog_free and not re.fullmatch(r"q\d+", prog_free):
        raise DeriveError(f"{robot.name}: the IK's free parameter {prog_free} is not a joint; IKFast needs one")
    text = env.get_template("ikfast_solver.cpp.j2").render(
        version=__version__, command=command, robot=robot, id=ctx["id"], dof=robot.dof,
        branches=ctx["ik"]["branches"], free_index=free_index, revolute=robot.revolute.tolist(),
        header=header, source=source)
    return f"{identifier(robot.name)}_ikfast_solver.cpp", text


def write_ikfast(robot, out_dir, command: str | None = None) -> list:
    """Write the IKFast drop-in (:func:`render_ikfast`) into out_dir/<robot name>/."""
    robot = load_robot(robot)
    out = Path(out_dir) / robot.name
    with task(robot.name):
        step("rendering the IKFast drop-in")
        name, text = render_ikfast(robot, command)
    out.mkdir(parents=True, exist_ok=True)
    (out / name).write_text(text, encoding="utf-8")
    return [out / name]


def render_kernels(robot, command: str | None = None, free: str | None = None, nominal=None) -> dict:
    """{role: (file name, text)} of every kernel file of one robot (roles as in :data:`FILES`);
    ``free``: a 7-joint arm's free parameter where its class offers a choice (the IK functions
    then take that one, :func:`derive.ik.program.ik_program`); ``nominal``: a near-class arm's
    :class:`derive.ik.nearclass.Nominal`, whose closed form the IK runs and polishes on the
    robot's own FK (:mod:`derive.codegen.polish`)."""
    robot = load_robot(robot)
    command = command or (f"dq-derive kernels {robot.name}" if free is None else
                          f"derive.kernels({robot.name!r}, free={free!r})")
    ctx = _context(robot, command, free, nominal)
    env = template_environment()
    return {role: (name.format(id=ctx["id"]), env.get_template(tpl).render(ctx))
            for role, (tpl, name) in FILES.items()}


def kernel_manifest(robot, free: str | None = None, nominal=None) -> dict:
    """What a kernel folder's manifest records besides its files: the robot's identity and
    name, the identifier stem of its functions, the IK's branch labels and, for a 7-joint arm,
    the name of the free parameter its IK functions take (``free``: "psi", "q3" or "q7"); for
    near-class kernels (``nominal``) the nominal robot, its identity and the relation's key
    (:func:`derive.codegen.polish.nominal_key`)."""
    robot = load_robot(robot)
    try:
        prog = ik_program(robot, free) if nominal is None else nominal_program(robot, nominal, free)
    except DeriveError:
        prog = None
    out = {"id": robot.id, "limits": robot.limits_id, "robot": robot.name, "prefix": _prefix(robot, free),
           "dof": robot.dof, "dq_derive": __version__, "format": KERNEL_FORMAT,
           "branch_labels": list(prog.branch_labels) if prog else []}
    if prog is None and nominal is None and _general_ik_context(robot, free) is not None:
        out["max_solutions"] = general6r_context(robot)["max_solutions"]
        out["ik"] = "general6r"
    if prog is not None and prog.free:
        out["free"] = prog.free            # the IK functions take the free parameter fv
    if nominal is not None and prog is not None:
        # near-class kernels: the nominal's branches, then extra slots (derive.codegen.polish.polish_width)
        out["max_solutions"] = polish_width(prog.branches, robot.dof - (held_joint(prog) is not None))
    if nominal is not None:
        out["nominal"] = {"robot": nominal.robot.name, "id": nominal.robot.id, "key": nominal_key(nominal),
                          "deviation": float(nominal.deviation), "how": nominal.how}
    return out


def write_kernels(robot, out_dir, command: str | None = None, force: bool = False, nominal=None) -> list:
    """Write the kernel files and the CMake package of the C kernels (:func:`render_cmake`) into
    out_dir/<robot name>/ and record them in its manifest (a folder of another robot is refused
    unless ``force``: :func:`derive.cache.claim_folder`); ``nominal``: near-class kernels
    (:func:`render_kernels`)."""
    robot = load_robot(robot)
    out = Path(out_dir) / robot.name
    claim_folder(out, robot.id, robot.name, force)
    with task(robot.name):
        step("rendering the FK/IK kernels")
        files = render_kernels(robot, command, nominal=nominal)
        files.update(render_cmake(robot, command))
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in files.values():
        (out / name).write_text(text, encoding="utf-8")
        written.append(out / name)
    written.append(write_manifest(out, {**kernel_manifest(robot, nominal=nominal),
                                        "files": {role: name for role, (name, _) in files.items()}}))
    return written
