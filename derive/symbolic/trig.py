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

from functools import lru_cache

import sympy as sp
from sympy.core.mul import _keep_coeff
from sympy.polys.polyerrors import BasePolynomialError
from sympy.polys.rings import ring
from sympy.simplify.fu import TR10i


def _factor_list(p):
    """(content, [(factor, multiplicity)]) of ``p``, a sparse polynomial over the integers.

    The factors are irreducible, primitive, with a positive leading coefficient (lex order of
    the ring's generators), as ``factor_list`` gives them; a factorisation so normalised is
    unique, so this is exactly sympy's answer. It is found cheaply when ``p`` has degree 1 in
    some generator x (the chain products are linear in each sine and cosine): with
    ``p = x A + B`` and ``h = gcd(A, B)``, ``p = h (x A/h + B/h)`` and the cofactor is
    irreducible (degree 1 in x, its coefficients A/h, B/h coprime), so only ``h``, which lacks
    x, is left to factor. Without such a generator sympy's ``factor_list`` does the work.
    """
    cont, p = p.primitive()
    if p.LC < 0:
        cont, p = -cont, -p
    if p.is_ground:
        return cont * p.LC, []
    k = next((k for k, d in enumerate(p.degrees()) if d == 1), None)
    if k is None:
        c, factors = p.factor_list()
        return cont * c, factors
    ring_ = p.ring
    a = ring_({m[:k] + (0,) + m[k + 1:]: c for m, c in p.terms() if m[k]})
    b = ring_({m: c for m, c in p.terms() if not m[k]})
    h, a, b = a.cofactors(b)
    if h.is_ground:
        return cont, [(p, 1)]
    q = ring_.gens[k] * a + b
    c, factors = _factor_list(h)
    if q.LC < 0:
        q, c = -q, -c
    return cont * c, factors + [(q, 1)]


def _factor(c: sp.Expr) -> sp.Expr:
    """``sp.factor(c)``, the same expression, faster for polynomials in sines, cosines and symbols.

    ``sp.factor`` factors each factor of ``c`` as a polynomial and multiplies the normalised
    irreducible factors back with ``_keep_coeff``; by unique factorisation the result does not
    depend on how ``c`` is split, so each factor of ``c`` is factored by :func:`_factor_list`
    and the product built the same way. Anything else (rational or algebraic coefficients,
    other functions) is left to ``sp.factor``.
    """
    if not isinstance(c, sp.Expr) or c.is_Number:
        return sp.factor(c)
    coeff, factors = sp.S.One, {}
    for arg in sp.Mul.make_args(c):
        if arg.is_Number:
            coeff *= arg
            continue
        base, e = arg.as_base_exp() if arg.is_Pow else (arg, sp.S.One)
        if not (e.is_Integer and e > 0):
            return sp.factor(c)
        try:
            poly = sp.Poly(base)
        except BasePolynomialError:
            return sp.factor(c)
        if poly.domain != sp.ZZ or not all(g.is_Symbol or isinstance(g, (sp.sin, sp.cos)) for g in poly.gens):
            return sp.factor(c)
        ring_ = ring(poly.gens, sp.ZZ)[0]
        cont, fs = _factor_list(ring_.from_dict(dict(poly.terms())))
        coeff *= sp.Integer(cont) ** e
        for f, k in fs:
            f = f.as_expr()
            factors[f] = factors.get(f, 0) + k * e
    return _keep_coeff(coeff, sp.Mul(*[f**k for f, k in factors.items()]))


@lru_cache(maxsize=2048)
def _fold(c: sp.Expr) -> sp.Expr:
    """Factor ``c`` and fold it with ``TR10i``, repeated until nothing changes (at most 4 times).

    Cached: the same coefficient comes back in many equations, sets and robots, and the result
    depends on ``c`` only (sympy expressions are immutable and compare structurally).
    """
    for _ in range(4):
        new = TR10i(_factor(c))
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
    return _normal_form(expr, tuple(thetas))


@lru_cache(maxsize=1024)
def _normal_form(expr: sp.Expr, thetas: tuple) -> sp.Expr:
    """:func:`half_angle_normal_form`, cached: the robots of a family verify the same differences.

    theta_i -> 2 phi_i is a plain replacement of symbols (``xreplace``, the same expression
    as ``subs`` gives, without its pattern matching).
    """
    phis = [sp.Dummy(f"phi{k}") for k in range(len(thetas))]
    e = expr.xreplace({t: 2 * p for t, p in zip(thetas, phis)})
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
