"""The public API is what type checkers and the documentation say it is.

Every name in ``licrom.__all__`` is imported statically in ``licrom/__init__.py`` (at the top, or
under ``TYPE_CHECKING`` for the lazily loaded ones), so type checkers and the API reference see
it; at run time it must be that very object, of the kind its definition says (a function is a
callable, not the module of the same name; a class a class), on first access and after the
modules that define them are imported. The stubs of the native module name what it has, and the package carries its
``py.typed`` marker and the stubs: these tests read the files beside the imported package, which
in CI is the installed wheel.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import json
import subprocess
import sys
import types
from pathlib import Path

import licrom

PACKAGE_DIR = Path(licrom.__file__).parent


def _source(module: str) -> Path:
    """File of a licrom module (``""`` is the package itself), found without importing it; the
    stubs of the native module (``_core.pyi``) stand for it."""
    rel = Path(*module.split(".")) if module else Path()
    package = PACKAGE_DIR / rel / "__init__.py"
    if package.is_file():
        return package
    source, stub = (PACKAGE_DIR / rel).with_suffix(".py"), (PACKAGE_DIR / rel).with_suffix(".pyi")
    return stub if stub.is_file() and not source.is_file() else source


def _relative(module: str, level: int, target: str | None) -> str:
    """The licrom module an import ``from .<target>`` (``level`` dots) in ``module`` names."""
    is_package = _source(module).name == "__init__.py"
    parts = module.split(".") if module else []
    base = parts if is_package else parts[:-1]
    base = base[: len(base) - (level - 1)]
    return ".".join([*base, *([target] if target else [])])


def _static_imports(module: str) -> dict[str, tuple[str, str]]:
    """``name -> (module, attribute)`` of the relative imports of a licrom module, ``TYPE_CHECKING`` ones included."""
    tree = ast.parse(_source(module).read_text())
    found: dict[str, tuple[str, str]] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level >= 1:
            source = _relative(module, node.level, node.module)
            for alias in node.names:
                found[alias.asname or alias.name] = (source, alias.name)
    return found


def _static_kind(module: str, name: str) -> str:
    """``"class"``, ``"function"``, ``"module"`` or ``"other"``: what the source defines ``module.name`` as."""
    submodule = f"{module}.{name}" if module else name
    if _source(submodule).is_file() and name not in _top_level_definitions(module):
        return "module"
    definitions = _top_level_definitions(module)
    if name in definitions:
        return definitions[name]
    imported = _static_imports(module).get(name)
    assert imported is not None, f"licrom.{module}: {name} is neither defined nor imported there" if module else f"licrom: {name} is not imported"
    return _static_kind(*imported)


def _top_level_definitions(module: str) -> dict[str, str]:
    tree = ast.parse(_source(module).read_text())
    kinds: dict[str, str] = {}
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            kinds[node.name] = "class"
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            kinds[node.name] = "function"
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            for target in node.targets if isinstance(node, ast.Assign) else [node.target]:
                if isinstance(target, ast.Name):
                    kinds[target.id] = "other"
    return kinds


def _expected() -> dict[str, tuple[str, str, str]]:
    """``name -> (defining module, attribute, kind)`` for every name of ``licrom.__all__``."""
    imports = _static_imports("")
    assert len(set(licrom.__all__)) == len(licrom.__all__), "licrom.__all__ lists a name twice"
    out = {}
    for name in licrom.__all__:
        assert name in imports, f"licrom.{name} is in __all__ but not imported in licrom/__init__.py, so type checkers and the docs do not see it"
        module, attribute = imports[name]
        out[name] = (module, attribute, _static_kind(module, attribute))
    return out


def _check(name: str, value: object, module: str, attribute: str, kind: str) -> None:
    if kind == "module":
        full = ".".join(["licrom", *filter(None, [module, attribute])])
        assert isinstance(value, types.ModuleType) and value.__name__ == full, f"licrom.{name} should be the module {full}, got {value!r}"
        return
    defined = getattr(importlib.import_module(f"licrom.{module}" if module else "licrom"), attribute)
    assert value is defined, f"licrom.{name} is {value!r}, not the {kind} licrom.{module}.{attribute} that type checkers see"
    assert not isinstance(value, types.ModuleType), f"licrom.{name} is a module, its definition is a {kind}"
    if kind == "class":
        assert inspect.isclass(value), f"licrom.{name} should be a class, got {value!r}"
    elif kind == "function":
        assert inspect.isfunction(value), f"licrom.{name} should be a function, got {value!r}"


def test_public_names_resolve_to_their_definitions_after_their_modules_are_imported():
    # Importing a submodule sets the package attribute of its name: a function named like its
    # module (licrom.compare) must survive that. Only the modules that define public names and
    # those named like one are imported (others may need optional extras).
    expected = _expected()
    for module in {m for m, _, _ in expected.values()} | {n for n in licrom.__all__ if _source(n).is_file()}:
        if module:
            importlib.import_module(f"licrom.{module}")
    assert {kind for _, _, kind in expected.values()} >= {"class", "function"}
    for name, (module, attribute, kind) in expected.items():
        _check(name, getattr(licrom, name), module, attribute, kind)


def test_public_names_resolve_lazily_in_a_fresh_interpreter():
    code = (
        "import inspect, json, types, licrom\n"
        "def kind(v):\n"
        "    return 'module' if isinstance(v, types.ModuleType) else 'class' if inspect.isclass(v) "
        "else 'function' if inspect.isfunction(v) else 'other'\n"
        "print(json.dumps({n: [kind(getattr(licrom, n)), getattr(getattr(licrom, n), '__name__', '')] for n in licrom.__all__}))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    seen = json.loads(result.stdout.strip().splitlines()[-1])
    for name, (module, attribute, kind) in _expected().items():
        got_kind, got_name = seen[name]
        assert got_kind == kind, f"licrom.{name} resolves to a {got_kind} on first access, its definition is a {kind} (licrom.{module}.{attribute})"
        if kind in ("class", "function"):
            assert got_name == attribute, f"licrom.{name} resolves to {got_name!r}, not {attribute!r}"


def test_errors_are_the_licrom_error_family():
    for name in licrom.__all__:
        value = getattr(licrom, name)
        if inspect.isclass(value) and issubclass(value, Warning):
            assert issubclass(value, licrom.LicromWarning), f"licrom.{name} is a warning outside the LicromWarning family"
        elif inspect.isclass(value) and issubclass(value, BaseException):
            assert issubclass(value, licrom.LicromError), f"licrom.{name} is an exception outside the LicromError family"


def _stub_names() -> tuple[dict[str, ast.stmt], list[str]]:
    tree = ast.parse((PACKAGE_DIR / "_core.pyi").read_text())
    names: dict[str, ast.stmt] = {}
    declared: list[str] = []
    for node in tree.body:
        if isinstance(node, (ast.ClassDef, ast.FunctionDef)):
            names[node.name] = node
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names[node.target.id] = node
        elif isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets):
            declared = list(ast.literal_eval(node.value))
    return {n: v for n, v in names.items() if not n.startswith("_")}, declared


def test_native_stubs_name_what_the_native_module_has():
    from licrom import _core

    stubs, declared = _stub_names()
    runtime = {n for n in dir(_core) if not n.startswith("_")}
    assert set(stubs) == runtime, f"only in the stubs: {sorted(set(stubs) - runtime)}; only in licrom._core: {sorted(runtime - set(stubs))}"
    assert sorted(declared) == sorted(_core.__all__) == sorted(runtime)
    for name, node in stubs.items():
        value = getattr(_core, name)
        if isinstance(node, ast.ClassDef):
            assert inspect.isclass(value), f"licrom._core.{name} is a class in the stubs, got {value!r}"
            stub_members = {m.name for m in node.body if isinstance(m, ast.FunctionDef) and not m.name.startswith("_")}
            runtime_members = {m for m in vars(value) if not m.startswith("_")}
            assert stub_members == runtime_members, (
                f"licrom._core.{name}: only in the stubs {sorted(stub_members - runtime_members)}, "
                f"only at run time {sorted(runtime_members - stub_members)}"
            )
        elif isinstance(node, ast.FunctionDef):
            assert callable(value) and not inspect.isclass(value), f"licrom._core.{name} is a function in the stubs, got {value!r}"
        else:
            assert not callable(value), f"licrom._core.{name} is data in the stubs, got {value!r}"


def test_package_ships_its_typing_marker_and_native_stubs():
    assert (PACKAGE_DIR / "py.typed").is_file()
    assert (PACKAGE_DIR / "_core.pyi").is_file()
