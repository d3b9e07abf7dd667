"""LaTeX of the derived equations in the thesis's notation.

Half-angle sums print as ``\\cos\\frac{\\theta_2+\\theta_3+\\theta_4}{2}``, full-angle
sums as ``\\cos(\\theta_3+\\theta_4)``, single angles without parentheses. The
terms of a side keep the order of :func:`derive.symbolic.trig.compact` (pose variables,
then parameters, then constants), so the output is stable and reads like the
thesis's appendices.
"""

from __future__ import annotations

import sympy as sp
from sympy.printing.latex import LatexPrinter


class ThesisLatexPrinter(LatexPrinter):
    def _angle(self, arg) -> str:
        if isinstance(arg, sp.Symbol):
            return self._print(arg)
        doubled = sp.expand(2 * arg)
        coeffs = doubled.as_coefficients_dict()
        if all(isinstance(k, sp.Symbol) for k in coeffs) and all(v in (1, -1) for v in coeffs.values()):
            return r"\frac{%s}{2}" % self._sum(doubled)
        return r"\left(%s\right)" % self._sum(arg)

    def _sum(self, expr) -> str:
        terms = sp.Add.make_args(sp.expand(expr))
        terms = sorted(terms, key=lambda t: (t.could_extract_minus_sign(), sp.default_sort_key(t)))
        out = ""
        for k, t in enumerate(terms):
            s = self._print(t)
            if k and not s.startswith("-"):
                out += " + "
            elif k:
                out += " - "
                s = s[1:].lstrip()
            out += s
        return out

    def _print_atan2(self, expr, exp=None):
        y, x = expr.args
        return r"\operatorname{atan2}\left(%s,\ %s\right)" % (self._print(y), self._print(x))

    def _print_cos(self, expr, exp=None):
        return self._trig("cos", expr.args[0], exp)

    def _print_sin(self, expr, exp=None):
        return self._trig("sin", expr.args[0], exp)

    def _trig(self, name, arg, exp):
        head = rf"\{name}" + (f"^{{{exp}}}" if exp else "")
        inner = self._angle(arg)
        if inner.startswith(r"\frac") or inner.startswith(r"\left"):
            return head + inner
        return head + " " + inner


_PRINTER = ThesisLatexPrinter({"order": "none"})


def latex(expr) -> str:
    return _PRINTER.doprint(expr)


def side(terms) -> list:
    """LaTeX of each term of a compact side, signs attached: ['a \\cos ...', '- b ...']."""
    out = []
    for g, c in terms:
        s = latex(sp.Mul(g, c))
        if out:
            s = ("- " + s[1:].lstrip()) if s.startswith("-") else "+ " + s
        out.append(s)
    return out or ["0"]
