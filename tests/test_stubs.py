"""The stubs of the native module say what its Rust docs say.

Each docstring of ``licrom._core`` is written twice: as ``///`` docs in ``rust/python/src``
(pyo3 makes them the objects' ``__doc__``) and in ``python/licrom/_core.pyi`` (read by type
checkers, editors and the API reference). Both are written by hand; this test keeps them
equal: for the module and for every class, function, method and property of the stubs, the
stub's docstring is the run-time ``__doc__`` (both normalised with ``inspect.cleandoc``).
Constructors are documented by their class's docstring and carry none of their own.
``python -m mypy.stubtest licrom._core`` checks the signatures; test_public_api the names.
"""

from __future__ import annotations

import ast
import inspect
from collections.abc import Iterator
from pathlib import Path

import licrom
import pytest
from licrom import _core

STUBS = Path(licrom.__file__).parent / "_core.pyi"
CONSTRUCTORS = ("__new__", "__init__")


def _documented() -> Iterator[tuple[str, ast.AST, object]]:
    """``(qualified name, stub node, run-time object)`` of the module and each documented object of the stubs."""
    tree = ast.parse(STUBS.read_text())
    yield "licrom._core", tree, _core
    for node in tree.body:
        if isinstance(node, ast.FunctionDef):
            yield node.name, node, getattr(_core, node.name)
        elif isinstance(node, ast.ClassDef):
            cls = getattr(_core, node.name)
            yield node.name, node, cls
            for member in node.body:
                if isinstance(member, ast.FunctionDef):
                    yield f"{node.name}.{member.name}", member, inspect.getattr_static(cls, member.name)


DOCUMENTED = list(_documented())


def _cleaned(doc: str | None) -> str | None:
    return inspect.cleandoc(doc) if doc else None


@pytest.mark.parametrize(("name", "node", "value"), DOCUMENTED, ids=[name for name, _, _ in DOCUMENTED])
def test_stub_docstring_is_the_rust_one(name, node, value):
    stub = ast.get_docstring(node, clean=True)
    if name.endswith(CONSTRUCTORS):
        assert stub is None, f"{name}: a constructor is documented by its class's docstring"
        return
    assert stub, f"{name} has no docstring in {STUBS.name}"
    assert _cleaned(value.__doc__) == stub, f"{name}: the Rust doc comment and the stub's docstring differ; make them equal"


def test_every_public_name_has_a_documented_stub():
    documented = {name for name, _, _ in DOCUMENTED}
    public = {name for name in dir(_core) if not name.startswith("_")}
    data = {name for name in public if not callable(getattr(_core, name))}  # LINE_SEARCH: a dict, documented in the stubs only
    assert public - data <= documented, f"without a stub: {sorted(public - data - documented)}"
    assert data <= set(_core.__all__) and all(f"\n{name}: " in STUBS.read_text() for name in data)
