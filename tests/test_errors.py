"""The exception family: defined in the native module, re-exported by ``licrom.errors``.

The classes are built by ``licrom._core`` (which raises them from Rust without importing the
package above it); ``licrom.errors`` is their public home, as their ``__module__`` says.
"""

from __future__ import annotations

import errno
import pickle
import warnings
from pathlib import Path

import licrom
import licrom._core as core
import licrom.errors as errors
import numpy as np
import pytest

HIERARCHY = {
    "LicromError": (Exception,),
    "MeshError": (errors.LicromError, ValueError),
    "ShapeError": (errors.LicromError, ValueError),
    "ConfigError": (errors.LicromError, ValueError),
    "SolverError": (errors.LicromError, RuntimeError),
    "FileFormatError": (errors.LicromError, OSError),
    "OutputError": (errors.LicromError, OSError),
    "ConcurrencyError": (errors.LicromError, RuntimeError),
    "InternalError": (errors.LicromError, RuntimeError),
    "MissingDependencyError": (errors.LicromError, ImportError),
    "LicromWarning": (UserWarning,),
    "PhysicsWarning": (errors.LicromWarning,),
    "AccuracyWarning": (errors.LicromWarning,),
}


def test_every_class_is_the_native_modules():
    assert set(HIERARCHY) | {"require_optional"} == set(errors.__all__)
    for name in HIERARCHY:
        cls = getattr(errors, name)
        assert cls is getattr(core, name), name
        assert (cls.__module__, cls.__qualname__) == ("licrom.errors", name)
        assert getattr(licrom, name, cls) is cls
        assert cls.__doc__


@pytest.mark.parametrize("name", sorted(HIERARCHY))
def test_hierarchy(name):
    cls = getattr(errors, name)
    assert cls.__bases__ == HIERARCHY[name]


def test_builtin_bases_catch_licrom_errors():
    with pytest.raises(ValueError):
        raise errors.ConfigError("x")
    with pytest.raises(OSError):
        raise errors.FileFormatError("x")
    with pytest.raises(ImportError):
        raise errors.MissingDependencyError("x")
    with pytest.raises(RuntimeError):
        raise errors.ConcurrencyError("x")
    with pytest.warns(UserWarning):
        warnings.warn("x", errors.PhysicsWarning, stacklevel=1)


def test_solver_error_attributes():
    e = errors.SolverError("no convergence", iterations=30, residual=1e-3, step_index=7)
    assert (str(e), e.args, e.iterations, e.residual, e.step_index) == ("no convergence", ("no convergence",), 30, 1e-3, 7)
    bare = errors.SolverError("x")
    assert (bare.iterations, bare.residual, bare.step_index) == (None, None, None)
    with pytest.raises(TypeError):
        errors.SolverError("x", 3)  # the attributes are keywords only
    with pytest.raises(TypeError):
        errors.SolverError("x", iteration=3)
    back = pickle.loads(pickle.dumps(e))
    assert type(back) is errors.SolverError and (back.args, back.iterations, back.residual, back.step_index) == (e.args, 30, 1e-3, 7)


def test_output_error_errno():
    e = errors.OutputError("cannot write 'x': No space left on device", errno=errno.ENOSPC)
    assert (str(e), e.errno, e.args) == ("cannot write 'x': No space left on device", errno.ENOSPC, ("cannot write 'x': No space left on device",))
    assert errors.OutputError("x").errno is None
    with pytest.raises(TypeError):
        errors.OutputError("x", errno.ENOSPC)


def test_subclasses_keep_the_constructor():
    class Mine(errors.SolverError):
        pass

    e = Mine("x", step_index=3)
    assert (e.args, e.step_index, e.iterations) == (("x",), 3, None)


def test_raised_from_rust():
    with pytest.raises(errors.ConfigError, match="e0 must be a finite energy"):
        core.line_search(float("nan"), -1.0, lambda alpha: (0.0, 0.0))
    with pytest.raises(errors.ShapeError):
        core.snh_energy(np.zeros((2, 3)), 1.0, 1.0)


def test_require_optional():
    assert errors.require_optional("json", "x", "y").__name__ == "json"
    with pytest.raises(errors.MissingDependencyError, match=r"pip install 'licrom\[extra\]'"):
        errors.require_optional("licrom_no_such_module", "extra", "this output")


BINDINGS = Path(__file__).resolve().parents[1] / "rust" / "python" / "src"


def test_every_call_into_the_core_turns_a_panic_into_internal_error():
    """The bindings call the core only through ``errors.rs``'s ``call_core`` / ``detached``, which catch a panic
    (``licrom_core::error::guarded``, tested in the core) and raise InternalError: no other GIL release, and no
    core result mapped on its own (a ``str.parse`` of a name cannot panic)."""
    sources = sorted(BINDINGS.glob("*.rs"))
    assert len(sources) > 5
    for path in sources:
        if path.name == "errors.rs":
            continue
        for number, line in enumerate(path.read_text().splitlines(), 1):
            assert "py.detach(" not in line, f"{path.name}:{number} releases the GIL without `detached`"
            if ".py_err(py)" in line:
                assert ".parse().py_err(py)" in line, f"{path.name}:{number} maps a core result without `call_core`"
