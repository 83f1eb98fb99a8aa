"""No import circles among the project's modules, and ``atr_node.io`` never imports ``hw``.

The import graph is read from the source with :mod:`ast` (nothing is imported): every
``import`` and ``from ... import`` of a project module, at module level or inside a function
(a function-level import still runs, and only hides a circle until then). Imports under
``if TYPE_CHECKING:`` are left out: they never run, so they cannot make one module see another
half-initialised; they are how a module names a type of the module that imports it.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("atr_node", "hw")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(tree: ast.AST, module: str, is_package: bool, modules: frozenset[str] = frozenset()) -> set[str]:
    """Every module name ``module`` imports at run time (absolute, possibly not ours)."""
    found: set[str] = set()
    package = module if is_package else module.rpartition(".")[0]

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            for child in node.orelse:  # the else branch does run
                visit(child)
            return
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            subs = {f"{target}.{alias.name}" for alias in node.names}
            found.update(subs)  # "from pkg import mod" imports the submodule pkg.mod
            # ... and pkg itself, unless every name is a submodule and pkg is this module's own
            # package (already initialised before any of its modules: "from . import sibling")
            if not (subs <= modules and module.startswith(target + ".")):
                found.add(target)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    return found


def import_graph() -> dict[str, set[str]]:
    """Module -> the project modules it imports (a package import counts as its ``__init__``)."""
    files = {(_module_name(p)): p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        raw = _imports(ast.parse(path.read_text(), str(path)), name, path.name == "__init__.py", frozenset(files))
        graph[name] = {m for m in raw if m in files and m != name}
    return graph


def find_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def strong(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            strong(v)
    return out


def test_no_import_cycles_among_modules():
    graph = import_graph()
    assert len(graph) > 100, "the walk found too few modules: the test would pass vacuously"
    cycles = find_cycles(graph)
    assert not cycles, "import circles: " + "; ".join(" <-> ".join(c) for c in cycles)


def test_the_finder_sees_a_circle():
    """The checker itself: a planted circle and a type-only back-reference."""
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert find_cycles(graph) == [["a", "b", "c"]]
    tree = ast.parse("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .grid import G\n"
                     "def f():\n    from .merge import m\n")
    assert _imports(tree, "atr_node.fusion.x", False) >= {"atr_node.fusion.merge"}
    assert "atr_node.fusion.grid" not in _imports(tree, "atr_node.fusion.x", False)


def test_known_circles_are_gone():
    graph = import_graph()
    assert "hw.nmea_decoder" not in graph["hw.nmea"]
    assert "atr_node.fusion.grid" not in graph["atr_node.fusion.merge"]


def test_file_formats_never_import_the_link_drivers():
    """``hw`` (the live links) builds on ``atr_node.io`` (the file formats), never the reverse."""
    graph = import_graph()
    io_modules = [m for m in graph if m == "atr_node.io" or m.startswith("atr_node.io.")]
    assert io_modules, "no atr_node.io module found"
    wrong = {m: sorted(d for d in graph[m] if d == "hw" or d.startswith("hw.")) for m in io_modules}
    wrong = {m: d for m, d in wrong.items() if d}
    assert not wrong, f"atr_node.io imports hw: {wrong}"
    assert any(d.startswith("atr_node.io") for d in graph["hw.base"]), "hw.base no longer builds on atr_node.io?"
