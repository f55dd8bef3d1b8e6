"""The package's layering is one-way: a module imports only from its own layer or the layers below.

Every ``import`` and ``from ... import`` in ``mitsnerf/`` counts, also those inside functions
(a lazy import is still a dependency). Layers, lowest first: infrastructure; ``math`` (the
floor: box, rays, sampling, compositing, metrics); ``volumes`` and ``data``; ``scene``;
``fields``; ``render``; ``scoring`` and the oracle; ``methods``; training and generation; ``runs`` (a run and
what is made of one); ``verify`` and ``bench``; the CLI (and ``python -m mitsnerf``): the layers README.md draws.
No two modules import each other, in a layer or across layers (:func:`import_cycles`).
"""

from __future__ import annotations

import ast
from pathlib import Path

import mitsnerf

LAYERS = (
    ("mitsnerf", "mitsnerf._llvm", "mitsnerf.env", "mitsnerf.errors", "mitsnerf.config", "mitsnerf.outputs",
     "mitsnerf.plugins"),
    ("mitsnerf.math",),
    ("mitsnerf.volumes", "mitsnerf.data"),
    ("mitsnerf.scene",),
    ("mitsnerf.fields",),
    ("mitsnerf.render",),
    ("mitsnerf.scoring", "mitsnerf.oracle"),
    ("mitsnerf.methods",),
    ("mitsnerf.train", "mitsnerf.generate"),
    ("mitsnerf.runs",),
    ("mitsnerf.verify", "mitsnerf.bench"),
    ("mitsnerf.cli", "mitsnerf.__main__", "mitsnerf.api"),
)
ROOT = Path(mitsnerf.__file__).parent


def layer_of(module: str) -> int:
    """The layer of the longest listed prefix of ``module``."""
    best, level = -1, None
    for i, names in enumerate(LAYERS):
        for name in names:
            if (module == name or module.startswith(name + ".")) and len(name) > best:
                best, level = len(name), i
    if level is None:
        raise AssertionError(f"{module}: not in any layer; add it to LAYERS")
    return level


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(path: Path) -> list[tuple[str, int]]:
    """``(imported module, line)`` of every mitsnerf import in ``path``, relative ones resolved."""
    tree = ast.parse(path.read_text(), str(path))
    package = module_name(path) if path.name == "__init__.py" else module_name(path).rpartition(".")[0]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names if a.name.split(".")[0] == "mitsnerf"]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else []))
            if base.split(".")[0] == "mitsnerf":
                out += [(f"{base}.{a.name}" if _is_module(f"{base}.{a.name}") else base, node.lineno) for a in node.names]
    return out


def _is_module(name: str) -> bool:
    path = ROOT.parent.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def upward_imports(root: Path = ROOT) -> list[str]:
    found = []
    for path in sorted(root.rglob("*.py")):
        me = module_name(path)
        for target, line in imports_of(path):
            if layer_of(target) > layer_of(me):
                found.append(f"{path.relative_to(root.parent)}:{line}: {me} (layer {layer_of(me)}) imports "
                             f"{target} (layer {layer_of(target)})")
    return found


def import_graph(root: Path = ROOT) -> dict[str, set[str]]:
    """``{module: the mitsnerf modules it imports}`` over every module under ``root`` (lazy imports too)."""
    return {module_name(path): {target for target, _ in imports_of(path)} - {module_name(path)}
            for path in sorted(root.rglob("*.py"))}


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan): each is a cycle of imports,
    whether its modules sit in one layer or not.

    >>> import_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}})
    [['a', 'b', 'c']]
    """
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return cycles


def test_no_import_cycles():
    assert import_cycles(import_graph()) == []


def test_the_check_finds_a_planted_cycle_inside_one_layer():
    graph = import_graph()
    graph["mitsnerf.verify.cases"] = graph["mitsnerf.verify.cases"] | {"mitsnerf.verify.scenarios"}
    assert import_cycles(import_graph()) == []
    (cycle,) = import_cycles(graph)
    assert {"mitsnerf.verify.cases", "mitsnerf.verify.scenarios"} <= set(cycle)
    assert layer_of("mitsnerf.verify.cases") == layer_of("mitsnerf.verify.scenarios")  # the layer check cannot


def test_no_module_imports_from_a_higher_layer():
    assert upward_imports() == []


def test_the_check_finds_a_planted_upward_import(tmp_path):
    pkg = tmp_path / "mitsnerf"
    (pkg / "math").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "math" / "__init__.py").write_text("")
    (pkg / "math" / "bad.py").write_text("def f():\n    from mitsnerf.runs.fit import fit\n")
    (pkg / "run.py").write_text("")
    global ROOT
    saved, ROOT = ROOT, pkg
    try:
        found = upward_imports(pkg)
    finally:
        ROOT = saved
    assert len(found) == 1 and "mitsnerf.math.bad (layer 1) imports mitsnerf.runs.fit (layer 9)" in found[0]
