"""The licrom exception family.

Every error licrom raises on purpose is a :class:`LicromError`. The subclasses
also derive from the matching built-in exception, so ``except ValueError``
keeps working for code that does not know licrom. Every warning it issues is a
:class:`LicromWarning`.
"""

from __future__ import annotations

import importlib
from types import ModuleType

__all__ = [
    "AccuracyWarning",
    "ConcurrencyError",
    "ConfigError",
    "FileFormatError",
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


class LicromError(Exception):
    """Base class of every error licrom raises."""


class MeshError(LicromError, ValueError):
    """A mesh is unusable: degenerate or inverted tets, bad indices, NaN coordinates."""


class ShapeError(LicromError, ValueError):
    """An array has the wrong shape, dtype or non-finite values."""


class ConfigError(LicromError, ValueError):
    """A parameter is outside its accepted range (material, plane, solver, scene)."""


class SolverError(LicromError, RuntimeError):
    """A solve did not converge or produced non-finite values.

    Attributes:
        iterations: iterations taken before giving up (None when not known).
        residual: the last convergence measure in m/s (None when not known).
        step_index: the time step that failed (None when not known).
    """

    def __init__(
        self, message: str, *, iterations: int | None = None, residual: float | None = None, step_index: int | None = None
    ) -> None:
        super().__init__(message)
        self.iterations = iterations
        self.residual = residual
        self.step_index = step_index


class FileFormatError(LicromError, OSError):
    """A file is missing, truncated, corrupt, foreign, or of an unknown format version."""


class LicromWarning(UserWarning):
    """Base class of every warning licrom issues."""


class PhysicsWarning(LicromWarning):
    """A simulation left the range where its physics holds: inverted elements, contact
    penetration deeper than ``licrom.validity.PENETRATION_LIMIT`` of the object's size,
    or a start inside a plane (see :mod:`licrom.validity`)."""


class AccuracyWarning(LicromWarning):
    """A reduced run's online error estimate (``Trajectory.error_estimate``) passed
    ``licrom.error_estimate.ERROR_THRESHOLD``: its subspace likely misses the motion
    (see :mod:`licrom.error_estimate`)."""


class OutputError(LicromError, OSError):
    """An output cannot be written: the disk is full, the folder is read-only, or the path is a directory.

    Nothing half-written is left behind: the destination keeps its previous contents (or stays absent).

    Attributes:
        errno: the operating system's error number (``errno.ENOSPC``, ``errno.EACCES``, ...; None when not known).
    """

    def __init__(self, message: str, *, errno: int | None = None) -> None:
        super().__init__(message)
        self.errno = errno


class ConcurrencyError(LicromError, RuntimeError):
    """One simulation was used from two threads at once (a step or evaluation was running in another thread).

    A simulation serves one thread at a time; give each thread its own simulation (they run in
    parallel), or guard a shared one with a ``threading.Lock``.
    """


class MissingDependencyError(LicromError, ImportError):
    """An optional package that the asked-for output needs is not installed (the message names the pip extra)."""


def require_optional(module: str, extra: str, what: str) -> ModuleType:
    """Import ``module``, or raise MissingDependencyError naming the ``licrom[extra]`` that installs it."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingDependencyError(f"{what} needs the optional package '{module.split('.')[0]}' ({exc}); "
                                     f"install it with: pip install 'licrom[{extra}]'") from exc
