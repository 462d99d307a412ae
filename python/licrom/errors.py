"""The licrom exception family.

Every error licrom raises on purpose is a :class:`LicromError`. The subclasses
also derive from the matching built-in exception, so ``except ValueError``
keeps working for code that does not know licrom.
"""

from __future__ import annotations

__all__ = [
    "LicromError",
    "MeshError",
    "ShapeError",
    "ConfigError",
    "SolverError",
    "FileFormatError",
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
    """A solve did not converge or produced non-finite values."""


class FileFormatError(LicromError, OSError):
    """A file is missing, truncated, corrupt, foreign, or of an unknown format version."""
