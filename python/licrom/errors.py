"""The licrom exception family.

Every error licrom raises on purpose is a :class:`LicromError`. The subclasses
also derive from the matching built-in exception, so ``except ValueError``
keeps working for code that does not know licrom. Every warning it issues is a
:class:`LicromWarning`.
"""

from __future__ import annotations

__all__ = [
    "ConfigError",
    "FileFormatError",
    "LicromError",
    "LicromWarning",
    "MeshError",
    "PhysicsWarning",
    "ShapeError",
    "SolverError",
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
