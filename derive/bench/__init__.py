"""Speed measurements (``dq-derive bench``, docs/benchmarks.md).

``BENCHES`` lives here, not in derive.bench.runner, so that the command line's parser offers the
choices without importing the benches (sympy, CasADi, matplotlib)."""

#: What ``dq-derive bench`` measures (derive.bench.runner runs them).
BENCHES = ("derivation", "ik", "fk", "kernels", "chain", "refine", "load")
