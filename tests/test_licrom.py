"""The package's public names: each resolves to what it is documented to be, whatever was imported before."""

import importlib
import inspect
import pkgutil
import subprocess
import sys
import types

import licrom
import pytest

MODULES = {"meshes", "render"}
FUNCTIONS = {"compare", "generate_dataset", "report_dataset_spec", "load_scene", "tetrahedralize", "train"}
ERRORS = {"LicromError", "MeshError", "ShapeError", "ConfigError", "SolverError", "FileFormatError"}


def _check_kind(name, obj):
    if name in MODULES:
        assert isinstance(obj, types.ModuleType) and obj.__name__ == f"licrom.{name}", name
    elif name in FUNCTIONS:
        assert inspect.isfunction(obj), f"licrom.{name} is {obj!r}, not a function"
    elif name in ERRORS:
        assert inspect.isclass(obj) and issubclass(obj, licrom.LicromError), name
    else:
        assert inspect.isclass(obj), f"licrom.{name} is {obj!r}, not a class"


def test_every_public_name_resolves_to_its_documented_kind_after_every_submodule_is_imported():
    for info in pkgutil.walk_packages(licrom.__path__, "licrom."):
        importlib.import_module(info.name)  # binds each submodule as a package attribute, as `import licrom.x` does
    assert sorted(dir(licrom)) == sorted(licrom.__all__)
    for name in licrom.__all__:
        _check_kind(name, getattr(licrom, name))
    assert callable(licrom.compare) and licrom.render.filmstrip


def test_compare_is_the_function_when_its_module_is_imported_first():
    code = "import licrom.compare, licrom, inspect; print(inspect.isfunction(licrom.compare), inspect.ismodule(licrom.render))"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["True", "True"]


def test_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="has no attribute 'teapot'"):
        licrom.teapot  # noqa: B018
