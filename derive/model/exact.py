"""The exact values (sympy) of the numbers of a robot description, built on demand.

:mod:`derive.model.robot` reads a description with floats: every number read from a file is a
:class:`~derive.model.robot.Num` that carries the recipe of its exact value, and this module
builds that value when the symbolic derivation (:mod:`derive.symbolic.chain`) asks for it. So
loading a robot, and the kernels of a shipped or cached robot, does not import sympy
(docs/architecture.md, "Light import").

The exact value of a field is the field as written, in SI units, over the file's named
parameters: length parameters stay symbols (``d1``, ``a2``), angle parameters are replaced by
their exact values, numbers become rationals, and ``pi`` is pi. An angle within ``SNAP_TOL`` of
a multiple of pi/12 is that multiple (1.5707963267948966 is pi/2); other angles that are not
such multiples stay floats, and the robot is then not exact (:func:`derive.model.robot.is_exact`
decides the same from the numbers alone).
"""

from __future__ import annotations

import sympy as sp

from derive.model.robot import Joint, Num, Op, snap_multiple

_FACTOR = {"m": sp.Integer(1), "cm": sp.Rational(1, 100), "mm": sp.Rational(1, 1000),
           "rad": sp.Integer(1), "deg": sp.pi / 180}


def value(x) -> sp.Expr:
    """The exact value of a number of a description: a :class:`Num` from its recipe (built
    once, then kept on the number), a plain float as the rational of its binary value."""
    if not isinstance(x, Num):
        return sp.nsimplify(float(x), rational=True)
    built = x.__dict__.get("_exact")
    if built is None:
        built = _build(x.recipe)
        x._exact = built
    return built


def op_form(op: Op) -> tuple:
    """The exact form of an elementary motion: (axis, angle) for a rotation, the vector for a
    translation, each a sympy number or expression."""
    if op.kind == "R":
        axis, angle = op.numbers
        return tuple(value(a) for a in axis), value(angle)
    return tuple(value(v) for v in op.numbers)


def joint_axis(joint: Joint) -> tuple:
    """The exact motion axis of a joint (in its frame after ``pre``)."""
    return tuple(value(a) for a in joint.axis_numbers)


def multiple_of_pi_12(angle) -> bool:
    """Whether the exact ``angle`` is k pi / 12 (15 degrees) for an integer k."""
    return angle == 0 or (sp.sympify(angle) * 12 / sp.pi).is_integer is True


def _snap(angle: float):
    k = snap_multiple(angle)
    return None if k is None else sp.Rational(k, 12) * sp.pi


def _build(recipe: tuple) -> sp.Expr:
    kind = recipe[0]
    if kind == "field":
        return _field(*recipe[1:])
    if kind == "unit":                       # component k of an axis normalised exactly
        components, k = recipe[1:]
        norm = sp.sqrt(sum(value(c) ** 2 for c in components))
        return sp.nsimplify(value(components[k]) / norm)
    if kind == "turn":                       # the angle of a rotation given as a quaternion
        angle = recipe[1]
        snapped = _snap(angle)
        return snapped if snapped is not None else sp.nsimplify(angle, [sp.pi], tolerance=1e-12)
    raise ValueError(f"unknown recipe {kind!r}")


def _field(raw, kind: str, ctx) -> sp.Expr:
    """A field as an exact SI expression (``ctx``: the reading context of
    :mod:`derive.model.robot`, with the units and the kind of every parameter)."""
    symbols = {p: sp.Symbol(p, real=True) for p in ctx.params}
    exact = {"length": _FACTOR[ctx.length_unit], "angle": _FACTOR[ctx.angle_unit], "unitless": sp.Integer(1)}

    def sym(text):
        if isinstance(text, (int, float)):
            return sp.nsimplify(text, rational=True)
        return sp.sympify(text, locals={**symbols, "pi": sp.pi})

    e = sym(raw)
    f = exact[kind]
    subs = {s: s / exact[ctx.kind_of.get(p, kind)] for p, s in symbols.items()}
    e = sp.nsimplify(f * e.subs(subs)) if f != 1 else e
    if kind == "angle":
        e = e.subs({s: sym(ctx.params_raw[p]) * exact["angle"]
                    for p, s in symbols.items() if ctx.kind_of.get(p) == "angle"})
        if not e.free_symbols and not multiple_of_pi_12(e):
            snapped = _snap(float(e))
            e = snapped if snapped is not None else sp.Float(float(e), 17)
    return e
