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


@lru_cache(maxsize=None)
def _symbols(n: int) -> tuple:
    """(phi, C, S): the dummies of n joint angles, made once so that expansions can be cached."""
    return tuple(tuple(sp.Dummy(f"{x}{k}") for k in range(n)) for x in ("phi", "C", "S"))


def _in_half_angles(e: sp.Expr, thetas: tuple) -> sp.Expr:
    """``e`` with theta_i = 2 phi_i (a plain replacement, ``xreplace``), its sines and cosines
    expanded (``expand_trig``) into polynomials in C_i = cos(phi_i), S_i = sin(phi_i)."""
    phis, cs, ss = _symbols(len(thetas))
    e = sp.expand_trig(e.xreplace({t: 2 * p for t, p in zip(thetas, phis)}))
    rep = {h(p): x for p, c, s in zip(phis, cs, ss) for h, x in ((sp.cos, c), (sp.sin, s))}
    return sp.expand(e.xreplace(rep))


#: :func:`_in_half_angles` of one sine or cosine, cached.
_expanded = lru_cache(maxsize=4096)(_in_half_angles)


class _NotPolynomial(Exception):
    """Raised by :func:`_to_ring` for anything but sums, products and powers of its atoms."""


def _to_ring(e: sp.Expr, images: dict, ring_):
    """``e`` (sums, products and powers of ``images``' keys and rationals) in ``ring_``."""
    if e in images:
        return images[e]
    if e.is_Rational:
        return ring_(e)
    if e.is_Add:
        return ring_.add(*[_to_ring(a, images, ring_) for a in e.args])
    if e.is_Mul:
        out = ring_.one
        for a in e.args:
            out *= _to_ring(a, images, ring_)
        return out
    if e.is_Pow and e.exp.is_Integer and e.exp > 0:
        return _to_ring(e.base, images, ring_) ** int(e.exp)
    raise _NotPolynomial


@lru_cache(maxsize=1024)
def _normal_form(expr: sp.Expr, thetas: tuple) -> sp.Expr:
    """:func:`half_angle_normal_form`, cached: the robots of a family verify the same differences.

    Each sine and cosine is expanded once (:func:`_expanded`), the expression is multiplied out
    with sparse polynomials over the rationals, and its remainder modulo S_i^2 + C_i^2 - 1 (a
    Groebner basis: the leading terms S_i^2 are coprime) is the unique normal form. Other
    coefficients (algebraic numbers, floats) take the way of sympy expressions.
    """
    phis, cs, ss = _symbols(len(thetas))
    others = sorted(expr.free_symbols - set(thetas), key=sp.default_sort_key)
    ring_ = ring(ss + cs + tuple(others), sp.QQ)[0]
    images = {x: g for x, g in zip(ss + cs + tuple(others), ring_.gens)}
    try:
        for f in expr.atoms(sp.sin, sp.cos):
            images[f] = _to_ring(_expanded(f, thetas), images, ring_)
        poly = _to_ring(expr, images, ring_)
    except _NotPolynomial:
        return _normal_form_expanded(expr, thetas)
    rem = poly.rem([ring_(s**2 + c**2 - 1) for s, c in zip(ss, cs)])
    return sp.expand(rem.as_expr())


def _normal_form_expanded(expr: sp.Expr, thetas: tuple) -> sp.Expr:
    """:func:`half_angle_normal_form` with sympy expressions."""
    phis, cs, ss = _symbols(len(thetas))
    e = _in_half_angles(expr, thetas)
    if e.has(*phis):
        raise ValueError("expression has angles that are not sums of joint angles")
    poly = sp.Poly(e, *ss, *cs)
    basis = [s**2 + c**2 - 1 for s, c in zip(ss, cs)]
    _, rem = sp.reduced(poly.as_expr(), basis, *ss, *cs)
    return sp.expand(rem)
