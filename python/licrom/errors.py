"""The licrom exception family.

Every error licrom raises on purpose is a :class:`LicromError`. The subclasses
also derive from the matching built-in exception, so ``except ValueError``
keeps working for code that does not know licrom. Every warning it issues is a
:class:`LicromWarning`.

The classes are defined in the native module (``licrom._core``, which raises them from
Rust) and re-exported here, their public home: ``licrom.errors.ShapeError is
licrom._core.ShapeError``, and their ``__module__`` is ``licrom.errors``.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from ._core import (
    AccuracyWarning,
    ConcurrencyError,
    ConfigError,
    FileFormatError,
    InternalError,
    LicromError,
    LicromWarning,
    MeshError,
    MissingDependencyError,
    OutputError,
    PhysicsWarning,
    ShapeError,
    SolverError,
)

__all__ = [
    "AccuracyWarning",
    "ConcurrencyError",
    "ConfigError",
    "FileFormatError",
    "InternalError",
    "LicromError",
    "LicromWarning",
    "MeshError",
    "MissingDependencyError",
    "OutputError",
    "PhysicsWarning",
    "ShapeError",
    "SolverError",
    "require_optional",
]


def require_optional(module: str, extra: str, what: str) -> ModuleType:
    """Import ``module``, or raise MissingDependencyError naming the ``licrom[extra]`` that installs it."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingDependencyError(f"{what} needs the optional package '{module.split('.')[0]}' ({exc}); "
                                     f"install it with: pip install 'licrom[{extra}]'") from exc
