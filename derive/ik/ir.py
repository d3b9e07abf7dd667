"""The language of the IK programs the kernels are printed from: lines (:class:`Op`), a
program (:class:`IKProgram`) and the :class:`Builder` the program constructions write with.

:mod:`derive.ik.program` builds the programs of the 6R classes from their derived equations,
:mod:`derive.ik.program7` those of the 7R classes with a free parameter; :mod:`derive.codegen.emit`
prints them as pure Python, numpy and C, :mod:`derive.refinement.functions` as CasADi.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import sympy as sp

from derive.errors import DeriveError

#: Functions the printers map to each language.
sgn = sp.Function("sgn")        # copysign(1, x)
pos = sp.Function("pos")        # max(x, 0)


@dataclass
class Op:
    """One line of an IK program.

    kind: "let" (name = expr), "sincos" (name, name2 = sin, cos of expr), "double"
    (name, name2 = sin, cos of twice the angle whose sin, cos are args), "branch" (name = +1,
    then -1, for everything after), "require" (drop the branch unless expr, a relational,
    holds), "select" (name = expr if cond else other), "solution" (exprs, one per joint),
    "roots4" (the up to 4 real roots of a trigonometric polynomial of degree 2, a quartic in the
    tangent half-angle: :meth:`Builder.roots4`; args its five coefficients, names
    :func:`roots4_names`).
    """

    kind: str
    name: str = ""
    expr: object = None
    name2: str = ""
    cond: object = None
    other: object = None
    args: tuple = ()
    depth: int = 0


@dataclass
class IKProgram:
    robot: str
    dof: int
    ops: list = field(default_factory=list)
    branches: int = 1
    free_joint: int | None = None           # joint that is free at the singular set
    free_rule: str = "set to 0"             # how the program chooses it there
    steps: list = field(default_factory=list)   # (unknown, pattern, equations) for the header
    parameters: dict = field(default_factory=dict)
    branch_labels: list = field(default_factory=list)   # the unknown each branch bit chooses the root of
    free: str | None = None                 # 7R: the free parameter (input ``fv``), "psi" or "q7"
    # the weight of each nesting level's bit in the branch (leaf) index, outermost first; None:
    # 2^(levels - 1) ... 1 (the nesting order); branch_labels are in the order of the weights
    bit_weights: tuple | None = None
    free_doc: str = ""                      # what it is, for the generated files' headers
    singular_doc: str = ""                  # where the free joint is free, for the headers ("" : sin theta5 = 0)
    steps_source: str = ""                  # where the steps come from, for the headers ("": the derived equations)


def roots4_names(stem: str) -> tuple:
    """The names a "roots4" line defines: the four angles ``stem0`` .. ``stem3`` and their
    validity flags ``stem_ok0`` .. ``stem_ok3`` (1.0 for a real root, 0.0 for an empty slot)."""
    return tuple(f"{stem}{i}" for i in range(4)) + tuple(f"{stem}_ok{i}" for i in range(4))


def leaf_weights(prog: IKProgram) -> tuple:
    """The weight of each nesting level's branch bit in the leaf (branch) index, outermost first."""
    levels = sorted({op.depth for op in prog.ops if op.kind == "branch"})
    return tuple(prog.bit_weights) if prog.bit_weights else tuple(2 ** (len(levels) - 1 - i)
                                                                   for i in range(len(levels)))


def leaf_of(prog: IKProgram, bits) -> int:
    """The leaf (branch) index of a path of branch bits (0 for the first root), outermost first."""
    return sum(w * int(b) for w, b in zip(leaf_weights(prog), bits))


class Builder:
    def __init__(self, values: dict):
        self.ops: list = []
        self.depth = 0
        self.values = values
        self.known: set = set()           # symbols with a value in the program
        self.trig: dict = {}              # angle argument -> (sin symbol, cos symbol)
        self.n_trig = 0
        self.n_tmp = 0
        self.labels: list = []

    def _num(self, e):
        """The robot's numbers substituted for the parameters."""
        return sp.sympify(e).xreplace(self.values)

    def let(self, name, expr) -> sp.Symbol:
        expr = self._trig(self._num(expr))
        sym = name if isinstance(name, sp.Symbol) else sp.Symbol(name, real=True)
        self.ops.append(Op("let", str(sym), expr, depth=self.depth))
        self.known.add(sym)
        return sym

    def tmp(self, expr, stem="k") -> sp.Symbol:
        self.n_tmp += 1
        return self.let(f"{stem}{self.n_tmp}", expr)

    def branch(self, name, label: str = "") -> sp.Symbol:
        self.labels.append(label or name)
        self.depth += 1
        sym = sp.Symbol(name, real=True)
        self.ops.append(Op("branch", name, depth=self.depth))
        self.known.add(sym)
        return sym

    def require(self, cond):
        self.ops.append(Op("require", expr=self._trig(self._num(cond)), depth=self.depth))

    def known_symbol(self, name: str) -> sp.Symbol:
        """The symbol of a flag (or value) defined earlier, by name."""
        sym = next((s for s in self.known if s.name == name), None)
        if sym is None:
            raise DeriveError(f"IK program: {name} is used before it is defined")
        return sym

    def flag(self, name, cond) -> sp.Symbol:
        sym = sp.Symbol(name)
        self.ops.append(Op("flag", name, self._trig(self._num(cond)), depth=self.depth))
        self.known.add(sym)
        return sym

    def select(self, name, cond, a, b) -> sp.Symbol:
        sym = sp.Symbol(name, real=True)
        self.ops.append(Op("select", name, self._trig(self._num(a)), cond=self._trig(self._num(cond)),
                           other=self._trig(self._num(b)), depth=self.depth))
        self.known.add(sym)
        return sym

    def roots4(self, stem: str, coef) -> tuple:
        """A "roots4" line: the real roots t in (-pi, pi] of
        F(t) = A0 + A1 cos t + B1 sin t + A2 cos 2t + B2 sin 2t, coef = (A0, A1, B1, A2, B2): up to
        4, the real roots of the quartic (1 + u^2)^2 F in u = tan((t - t0) / 2) (the shift t0 and
        the root test of :func:`derive.ik.subproblems._common._trig_roots`, two Newton steps on F).
        The slots hold the real roots first, in ascending order of the angle, then the empty slots
        (angle 0, flag 0.0): every printer computes the same slots, so that branches that select a
        slot agree across the languages. Total: no root (all flags 0.0) where F vanishes or
        is tiny at every sample. Returns the symbols (angles (4,), flags (4,))."""
        args = tuple(self._trig(self._num(e)) for e in coef)
        if len(args) != 5:
            raise DeriveError("IK program: roots4 takes five coefficients (A0, A1, B1, A2, B2)")
        self.ops.append(Op("roots4", stem, args=args, depth=self.depth))
        syms = [sp.Symbol(n, real=True) for n in roots4_names(stem)]
        self.known.update(syms)
        return tuple(syms[:4]), tuple(syms[4:])

    def set_trig(self, arg, s, c):
        self.trig[sp.expand(arg)] = (s, c)

    def _trig(self, expr):
        """Replace sin/cos of known angles by symbols, emitting sincos (or double-angle) lines."""
        expr = sp.sympify(expr)
        atoms = expr.atoms(sp.sin, sp.cos)
        if not atoms:
            return expr
        args = sorted({sp.expand(a.args[0]) for a in atoms}, key=lambda a: (sp.count_ops(a), sp.default_sort_key(a)))
        for arg in args:
            if arg in self.trig:
                continue
            if not arg.free_symbols <= self.known:
                raise DeriveError(f"IK program: sin/cos of {arg} needed before its angle is known")
            half = sp.expand(arg / 2)
            if half in self.trig:
                hs, hc = self.trig[half]
                s, c = self._trig_names()
                self.ops.append(Op("double", str(s), name2=str(c), args=(str(hs), str(hc)), depth=self.depth))
            else:
                s, c = self._trig_names()
                self.ops.append(Op("sincos", str(s), arg, name2=str(c), depth=self.depth))
            self.trig[arg] = (s, c)
        rep = {}
        for a in atoms:
            s, c = self.trig[sp.expand(a.args[0])]
            rep[a] = s if isinstance(a, sp.sin) else c
        return expr.xreplace(rep)

    def _trig_names(self):
        self.n_trig += 1
        return sp.Symbol(f"s{self.n_trig}", real=True), sp.Symbol(f"c{self.n_trig}", real=True)
