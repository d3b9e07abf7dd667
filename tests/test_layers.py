"""The package's layers: imports inside ``derive`` point one way and form no cycle, counting
the imports inside functions too (the whole syntax tree of every module is read)."""

import ast
from pathlib import Path

import derive

ROOT = Path(derive.__file__).resolve().parent

#: Layer of every subpackage / top-level module, lowest first (docs/architecture.md).
LAYERS = {
    "derive._version": 0, "derive.errors": 0, "derive.cache": 0,
    "derive.algebra": 1, "derive.model": 2, "derive.kinematics": 3, "derive.symbolic": 4,
    "derive.ik": 5, "derive.reference": 5, "derive.codegen": 6, "derive.refinement": 7,
    "derive.reports": 8, "derive.apps": 8, "derive.bench": 9, "derive.cli": 10, "derive.__main__": 11,
    "derive": 11,
}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict:
    return {_module_name(p): p for p in sorted(ROOT.rglob("*.py"))}


def _layer(module: str) -> int:
    best = None
    for prefix, layer in LAYERS.items():
        if module == prefix or module.startswith(prefix + "."):
            if best is None or len(prefix) > len(best[0]):
                best = (prefix, layer)
    assert best is not None, f"{module} has no layer in LAYERS"
    return best[1]


def _imports(name: str, path: Path, modules: dict) -> set:
    """Modules of ``derive`` that ``name`` imports, anywhere in its syntax tree."""
    out = set()
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(up + ([base] if base else []))
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
        else:
            continue
        out |= {t for t in targets if t == "derive" or t.startswith("derive.")}
    return {t for t in out if t != name}


def test_every_module_has_a_layer_and_imports_point_down():
    modules = _modules()
    wrong = []
    for name, path in modules.items():
        for target in _imports(name, path, modules):
            if _layer(target) > _layer(name):
                wrong.append(f"{name} (layer {_layer(name)}) imports {target} (layer {_layer(target)})")
    assert not wrong, "imports against the layers:\n" + "\n".join(wrong)


def test_no_import_cycles():
    modules = _modules()
    graph = {n: {t for t in _imports(n, p, modules) if t in modules} for n, p in modules.items()}
    # the package __init__ re-exports the API; submodules never import it back
    back = [n for n, ts in graph.items() if "derive" in ts and n != "derive.__main__"]
    assert not back, f"modules that import the package's __init__: {back}"
    state: dict = {}
    cycles = []

    def visit(n, stack):
        state[n] = 1
        for t in sorted(graph[n]):
            if state.get(t) == 1:
                cycles.append(" -> ".join(stack[stack.index(t):] + [t]))
            elif t not in state:
                visit(t, stack + [t])
        state[n] = 2

    for n in sorted(graph):
        if n not in state:
            visit(n, [n])
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


def test_the_layer_check_sees_imports_inside_functions(tmp_path):
    """The checker itself: an import inside a function body is found."""
    src = tmp_path / "mod.py"
    src.write_text("def f():\n    from derive.cli import main\n    return main\n")
    assert _imports("derive.algebra.fake", src, _modules()) == {"derive.cli"}
