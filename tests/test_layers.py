"""The package's architecture as a table of layers, one folder each, checked over its import graph.

Every module of ``python/licrom`` sits in a layer: the foundation modules at the top of the
package, below everything, then one subpackage (folder) per layer. A module imports only from
its own layer or below, and the layers' imports form no loop. Imports under ``if
TYPE_CHECKING:`` (type hints alone) are not imports at run time and are left out; the
package's ``__init__`` is the facade over all layers and is left out too.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "python" / "licrom"

FOUNDATION: tuple[str, ...] = ("errors", "_io", "_limits", "_repr", "_blas", "validity", "rigid", "executors", "stepping")
"""The modules at the top of the package: errors, files, limits and checks every layer uses."""

LAYERS: tuple[tuple[str, str], ...] = (
    ("geometry", "meshes, procedural meshes, surfaces to tets"),
    ("scene", "scenes, placement and sweeps"),
    ("records", "trajectories and their exports"),
    ("full", "the full simulation (warp)"),
    ("data", "scene files, presets and data sets of full runs"),
    ("subspace", "affine modes, bases, body-frame modes, cubature"),
    ("reduced", "the reduced simulation, world and body frame, its factory and error estimate"),
    ("analysis", "full against reduced, a scene's sensitivity"),
    ("viz", "pictures and reports"),
    ("learn", "training data, models and their training"),
    ("cli", "the licrom command and its demo"),
)
"""The layer folders (subpackages of ``licrom``), lowest first, above the foundation."""

LAYER_OF = {module: 0 for module in FOUNDATION} | {folder: i + 1 for i, (folder, _) in enumerate(LAYERS)}
NAMES = ["foundation", *(folder for folder, _ in LAYERS)]


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
    """Layer folder or foundation module -> those it imports (the package facade left out)."""
    graph: dict[str, set[str]] = {}
    for name, path in _modules().items():
        if name == "":
            continue
        graph.setdefault(_top(name), set()).update(_top(t) for t in _imports(name, path) if _top(t) != _top(name))
    return graph


def test_every_module_lives_in_a_layer_folder_or_the_foundation():
    misplaced = sorted(name for name in _modules() if name and not (
        (name in FOUNDATION) or (name.split(".")[0] in dict(LAYERS) and (PACKAGE / name.split(".")[0]).is_dir())))
    assert not misplaced, f"modules outside every layer folder and the foundation: {misplaced}"
    for folder, _ in LAYERS:
        assert (PACKAGE / folder / "__init__.py").is_file(), f"layer folder {folder}/ is missing (or has no __init__.py)"
        assert ast.get_docstring(ast.parse((PACKAGE / folder / "__init__.py").read_text())), f"{folder}/__init__.py should say what the layer is"
    gone = sorted(m for m in FOUNDATION if not (PACKAGE / f"{m}.py").is_file())
    assert not gone, f"FOUNDATION names modules that do not exist: {gone}"


def test_every_module_has_a_layer():
    missing = sorted(set(_graph()) - set(LAYER_OF))
    assert not missing, f"modules without a layer: {missing}"


def test_no_module_imports_from_a_layer_above_its_own():
    upward = [f"{m} ({NAMES[LAYER_OF[m]]}) imports {t} ({NAMES[LAYER_OF[t]]})"
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


@pytest.mark.parametrize("name, source, expected", [
    ("probe", "from .geometry.mesh import Mesh\n", {"geometry"}),
    ("probe", "from . import _core, errors\n", {"errors"}),
    ("probe", "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .learn.model import Model\n", set()),
    ("probe", "def f():\n    from .viz.render import pyplot\n", {"viz"}),
    ("probe", "import licrom.scene.scene\n", {"scene"}),
    ("reduced.probe", "from ..geometry.mesh import Mesh\nfrom .base import ReducedSim\n", {"geometry", "reduced"}),
])
def test_the_graph_reads_every_kind_of_import(tmp_path, name, source, expected):
    path = tmp_path / "probe.py"
    path.write_text(source)
    assert {_top(t) for t in _imports(name, path)} == expected
