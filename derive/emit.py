"""Emission of the numeric kernels (pure Python, numpy, C99) from :mod:`derive.codegen`.

Every file is standalone (copy it into another project and it works) and starts with a
header naming the robot, its parameters, the dq-derive version and the command that made it.
"""

from __future__ import annotations

from pathlib import Path

import sympy as sp
from sympy.printing.c import C99CodePrinter
from sympy.printing.pycode import PythonCodePrinter

from . import __version__
from .appendix import template_environment
from .codegen import fk_kernel
from .robot import load_robot


def identifier(robot_name: str) -> str:
    return robot_name.replace("-", "_").replace(".", "_")


class _Py(PythonCodePrinter):
    def _print_Pow(self, expr, rational=False):
        if expr.exp == 2:
            b = self._print(expr.base)
            return f"{b}*{b}" if expr.base.is_Symbol else f"({b})*({b})"
        return super()._print_Pow(expr, rational)

    def _print_Float(self, expr):
        return repr(float(expr))


class _C(C99CodePrinter):
    def _print_Pow(self, expr):
        if expr.exp == 2:
            b = self._print(expr.base)
            return f"{b}*{b}" if expr.base.is_Symbol else f"({b})*({b})"
        return super()._print_Pow(expr)

    def _print_Float(self, expr):
        return repr(float(expr))


def _arg(printer, a, column):
    """Angle argument as code: q[k] replaced by column(k)."""
    qs = sorted(a.free_symbols, key=lambda s: int(s.name[1:]))
    return printer.doprint(a.xreplace({s: sp.Symbol(column(int(s.name[1:]))) for s in qs}))


def _context(robot_name: str, command: str) -> dict:
    robot = load_robot(robot_name)
    k = fk_kernel(robot_name)
    py, c = _Py(), _C()
    trig = []
    for s, co, a in k.trig:
        if isinstance(a, tuple):
            trig.append({"s": s, "c": co, "double": True, "hs": a[1], "hc": a[2]})
        else:
            trig.append({"s": s, "c": co, "double": False,
                         "py": _arg(py, a, lambda i: f"q[{i}]"),
                         "np": _arg(py, a, lambda i: f"Q[:, {i}]"),
                         "cc": _arg(c, a, lambda i: f"q[{i}]")})
    temps = [{"name": str(n), "py": py.doprint(e), "cc": c.doprint(e)} for n, e in k.temps]
    outs = [{"py": py.doprint(e), "cc": c.doprint(e)} for e in k.outputs]
    return {
        "version": __version__, "command": command, "robot": robot, "id": identifier(robot.name),
        "dof": robot.dof, "parameters": [(str(p), v) for p, v in k.parameters.items()],
        "trig": trig, "temps": temps, "outputs": outs, "n_sincos": k.n_sincos,
    }


FILES = {
    "python": ("kinematics.py.j2", "{id}_kinematics.py"),
    "numpy": ("kinematics_numpy.py.j2", "{id}_kinematics_numpy.py"),
    "c_header": ("kinematics.h.j2", "{id}_kinematics.h"),
    "c_source": ("kinematics.c.j2", "{id}_kinematics.c"),
}


def render_kernels(robot_name: str, command: str | None = None) -> dict:
    """{file name: text} of every kernel file of one robot."""
    command = command or f"dq-derive kernels {robot_name}"
    ctx = _context(robot_name, command)
    env = template_environment()
    return {name.format(id=ctx["id"]): env.get_template(tpl).render(ctx) for tpl, name in FILES.values()}


def write_kernels(robot_name: str, out_dir, command: str | None = None) -> list:
    out = Path(out_dir) / robot_name
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in render_kernels(robot_name, command).items():
        (out / name).write_text(text, encoding="utf-8")
        written.append(out / name)
    return written
