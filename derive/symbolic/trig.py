"""Targeted trigonometric rewriting of the chain products.

The products of :mod:`derive.symbolic.chain` are expanded polynomials in sines and
cosines. The thesis prints them compactly: each pose variable or geometric
parameter multiplies a product of sines and cosines of angle sums, e.g.
``w cos((t2+t3+t4)/2) cos((t1-t5)/2)``. Generic ``simplify`` is slow and
unpredictable on such sums; here each coefficient is handled on its own:

1. collect the expression by the pose variables and parameters (linear in each);
2. factor the coefficient, then fold sums of products into sines and cosines
   of sums with sympy's ``TR10i`` (c_a c_b -+ s_a s_b = cos(a +- b), ...),
   repeating until nothing changes.

:func:`half_angle_normal_form` gives a canonical polynomial of an expression in
the half-angle sines and cosines of the joint angles; two expressions are
identical exactly when their normal forms are, which is how the rewriting is
checked symbolically.
"""

from __future__ import annotations

import sympy as sp
from sympy.simplify.fu import TR10i


def _fold(c: sp.Expr) -> sp.Expr:
    for _ in range(4):
        new = TR10i(sp.factor(c))
        if new == c:
            break
        c = new
    return c


def compact(expr: sp.Expr, gens) -> list:
    """``expr`` as a list of (generator, folded coefficient) pairs, in the order of ``gens``.

    Every generator in ``gens`` must enter linearly; what multiplies no
    generator comes last with generator 1. Terms with zero coefficient are dropped.
    """
    expr = sp.expand(expr)
    if expr == 0:
        return []
    parts = sp.collect(expr, list(gens), evaluate=False)
    order = {g: k for k, g in enumerate(gens)}
    unknown = [k for k in parts if k != 1 and k not in order]
    if unknown:
        raise ValueError(f"not linear in the generators: {unknown}")
    keys = sorted(parts, key=lambda k: order.get(k, len(order)))
    out = []
    for k in keys:
        c = _fold(parts[k])
        if c != 0:
            out.append((k, c))
    return out


def as_expr(terms) -> sp.Expr:
    """Rebuild the sum of a :func:`compact` term list."""
    return sp.Add(*[g * c for g, c in terms])


def half_angle_normal_form(expr: sp.Expr, thetas) -> sp.Expr:
    """Canonical polynomial of ``expr`` in C_i = cos(theta_i/2), S_i = sin(theta_i/2).

    Angles are written as theta_i = 2 phi_i, every sine and cosine of a sum is
    expanded, and S_i^2 is replaced by 1 - C_i^2 until no square of an S_i is
    left. The result is unique, so a difference of two expressions is zero
    exactly when its normal form is 0.
    """
    phis = [sp.Dummy(f"phi{k}") for k in range(len(thetas))]
    e = expr.subs({t: 2 * p for t, p in zip(thetas, phis)}, simultaneous=True)
    e = sp.expand_trig(e)
    cs = [sp.Dummy(f"C{k}") for k in range(len(thetas))]
    ss = [sp.Dummy(f"S{k}") for k in range(len(thetas))]
    rep = {}
    for p, c, s in zip(phis, cs, ss):
        rep[sp.cos(p)] = c
        rep[sp.sin(p)] = s
    e = sp.expand(e.xreplace(rep))
    if e.has(*phis):
        raise ValueError("expression has angles that are not sums of joint angles")
    poly = sp.Poly(e, *ss, *cs)
    # reduce modulo S^2 + C^2 - 1 (a Groebner basis: the leading terms S_i^2 are coprime)
    basis = [s**2 + c**2 - 1 for s, c in zip(ss, cs)]
    _, rem = sp.reduced(poly.as_expr(), basis, *ss, *cs)
    return sp.expand(rem)
