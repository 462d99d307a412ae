"""The package's architecture as a table of layers, checked over its import graph.

Every module of ``python/licrom`` sits in one layer; a module imports only from its own
layer or below, and the imports form no loop. Imports under ``if TYPE_CHECKING:`` (type
hints alone) are not imports at run time and are left out; the package's ``__init__`` is
the facade over all layers and is left out too.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "python" / "licrom"

LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("foundation", ("errors", "_io", "_limits", "_repr", "_plot", "validity", "rigid", "executors", "stepping")),
    ("geometry", ("mesh", "meshes", "surface")),
    ("scene", ("scene", "placement")),
    ("records", ("trajectory", "export")),
    ("full simulation", ("full_sim",)),
    ("subspace", ("affine", "basis", "body_basis", "cubature", "training_data")),
    ("reduced simulation", ("error_estimate", "reduced_base", "body_frame", "reduced_sim")),
    ("comparison and data", ("compare", "dataset", "scene_file", "presets")),
    ("learning", ("model", "training")),
    ("pictures", ("render", "report")),
    ("application", ("cli", "demo")),
)
"""Layers, lowest first, and the top-level modules (or subpackages) in each."""

LAYER_OF = {module: i for i, (_, modules) in enumerate(LAYERS) for module in modules}


def _modules() -> dict[str, Path]:
    """Dotted name (relative to the package) of every module, and its file."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if parts:
            out[".".join(parts)] = path
    return out


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(name: str, path: Path) -> set[str]:
    """Modules of the package that module ``name`` imports at run time (anywhere in it)."""
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    found: set[str] = set()

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node):
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                target = [*base, *(node.module.split(".") if node.module else [])]
                found.update(".".join([*target, alias.name]) if not node.module else ".".join(target) for alias in node.names)
            elif node.module and node.module.startswith("licrom."):
                found.add(node.module.removeprefix("licrom."))
        elif isinstance(node, ast.Import):
            found.update(a.name.removeprefix("licrom.") for a in node.names if a.name.startswith("licrom."))
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(ast.parse(path.read_text()))
    return {f for f in found if f and f != "_core"}


def _top(name: str) -> str:
    return name.split(".")[0]


def _graph() -> dict[str, set[str]]:
    """Top-level module -> the top-level modules it imports (the package facade left out)."""
    graph: dict[str, set[str]] = {}
    for name, path in _modules().items():
        if name == "":
            continue
        graph.setdefault(_top(name), set()).update(_top(t) for t in _imports(name, path) if _top(t) != _top(name))
    return graph


def test_every_module_has_a_layer():
    missing = sorted(set(_graph()) - set(LAYER_OF))
    assert not missing, f"modules without a layer in LAYERS: {missing}"
    gone = sorted(set(LAYER_OF) - set(_graph()))
    assert not gone, f"LAYERS names modules that do not exist: {gone}"


def test_no_module_imports_from_a_layer_above_its_own():
    upward = [f"{m} ({LAYERS[LAYER_OF[m]][0]}) imports {t} ({LAYERS[LAYER_OF[t]][0]})"
              for m, targets in sorted(_graph().items()) for t in sorted(targets)
              if m in LAYER_OF and t in LAYER_OF and LAYER_OF[t] > LAYER_OF[m]]
    assert not upward, "imports from a higher layer:\n" + "\n".join(upward)


def test_imports_form_no_loop():
    graph = _graph()
    state: dict[str, int] = {}
    loops: list[list[str]] = []

    def walk(node: str, path: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                loops.append([*path[path.index(nxt):], nxt])
            elif nxt not in state:
                walk(nxt, [*path, nxt])
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            walk(node, [node])
    assert not loops, "import loops: " + "; ".join(" -> ".join(loop) for loop in loops)


@pytest.mark.parametrize("source, expected", [
    ("from .mesh import Mesh\n", {"mesh"}),
    ("from . import _core, meshes\n", {"meshes"}),
    ("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .model import Model\n", set()),
    ("def f():\n    from .render import pyplot\n", {"render"}),
    ("import licrom.scene\n", {"scene"}),
])
def test_the_graph_reads_every_kind_of_import(tmp_path, source, expected):
    path = tmp_path / "probe.py"
    path.write_text(source)
    assert {_top(t) for t in _imports("probe", path)} == expected
