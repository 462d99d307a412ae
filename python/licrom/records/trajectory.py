"""Trajectories: the recorded motion of one simulation, full-space or reduced, as one file."""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from .._io import check_version, load_npz, save_npz
from ..errors import ConfigError, FileFormatError, LicromError, ShapeError, SolverError
from ..geometry.mesh import Mesh
from ..rigid import center_of_mass
from ..scene.scene import Scene
from ..validity import PENETRATION_LIMIT

__all__ = ["READABLE_VERSIONS", "TRAJECTORY_FORMAT_VERSION", "DeferredFrames", "Trajectory"]

TRAJECTORY_FORMAT_VERSION = 2
"""Written when a run holds impact frames; otherwise version 1 (the same file without them), which older licrom reads."""
READABLE_VERSIONS = (1, 2)

_FRAMES = ("displacements", "velocities")
"""The frame arrays a :class:`DeferredFrames` builds."""


class DeferredFrames:
    """A run's (f, n, 3) displacements and velocities, built when a :class:`Trajectory` first reads either, once.

    Pass the same object as a trajectory's ``displacements`` and ``velocities``. A body-frame run records its
    poses, and building every frame's n x 3 displacements and velocities from them is most of what a run does
    besides its steps, while most readers of a run read no frame (its summaries, ``min_det_f``, ``penetration``
    and ``error_estimate`` are measured by the run itself): 2000 steps on 104k tets took 18.8 s with the frames
    built and 10.5 s without, and the first read then builds them in 7.9 s.

    Args:
        shape: ``(f, n, 3)``, the shape of either array.
        build: returns ``(displacements, velocities)``; the trajectory checks them as it checks arrays given
            at once, when it calls it.
    """

    def __init__(self, shape: tuple[int, int, int], build: Callable[[], tuple[np.ndarray, np.ndarray]]) -> None:
        self.shape = shape
        self.build = build


@dataclass
class Trajectory:
    """Recorded frames of a simulation of one mesh in one scene.

    Attributes:
        rest_positions: (n, 3) rest positions in m.
        tets: (m, 4) tets.
        displacements: (f, n, 3) displacement from rest at each frame, m. Given as a :class:`DeferredFrames`
            (with ``velocities``), both are built when first read, once: a NaN or inf in them raises then.
        velocities: (f, n, 3) velocity at each frame, m/s.
        times: (f,) time of each frame, s.
        scene: the scene simulated (material, planes, stiffnesses, dt, gravity, initial state).
        iterations: (s,) Newton iterations of each step taken.
        residuals: (s,) final convergence measure of each step (m/s).
        converged: (s,) whether each step met the tolerance.
        step_seconds: (s,) wall time of each step, s.
        min_det_f: (f,) smallest ``det F`` over the elements at each frame and the steps since
            the previous frame (the tets, or the cubature points of a reduced model), or empty
            when not measured; <= 0 means inverted elements (see :mod:`licrom.validity`).
        penetration: (f,) deepest penetration of a vertex into a plane at each frame and the
            steps since the previous frame (every vertex at the frames; the contact points of a
            reduced model between them), m, or empty when not measured.
        error_estimate: (f,) a reduced run's online estimate of its non-rigid error, running
            from the first contact (dimensionless; see :mod:`licrom.reduced.error_estimate`), or empty
            (full runs, and files written before it existed).
        impact_displacements: (k, n, 3) displacement at extra frames kept for learning, m: the steps
            between frames just after each impact (:func:`licrom.stepping.record_run`, ``impact_window``),
            whose fast transient the regular frames alias; empty (0, n, 3) when none were kept.
        impact_times: (k,) time of each impact frame, s, strictly increasing.
        info: free-form JSON-ready metadata (source, mesh name, sweep parameters, ...).
    """

    rest_positions: np.ndarray
    tets: np.ndarray
    displacements: np.ndarray
    velocities: np.ndarray
    times: np.ndarray
    scene: Scene
    iterations: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int32))
    residuals: np.ndarray = field(default_factory=lambda: np.zeros(0))
    converged: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    step_seconds: np.ndarray = field(default_factory=lambda: np.zeros(0))
    min_det_f: np.ndarray = field(default_factory=lambda: np.zeros(0))
    penetration: np.ndarray = field(default_factory=lambda: np.zeros(0))
    error_estimate: np.ndarray = field(default_factory=lambda: np.zeros(0))
    impact_displacements: np.ndarray | None = None
    impact_times: np.ndarray = field(default_factory=lambda: np.zeros(0))
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.rest_positions = np.asarray(self.rest_positions, dtype=np.float64)
        tets = np.asarray(self.tets)
        if tets.size and not np.issubdtype(tets.dtype, np.integer):
            raise ShapeError(f"Trajectory.tets must be integer vertex indices, got dtype {tets.dtype}")
        self.tets = tets.astype(np.int64)
        self.times = np.asarray(self.times, dtype=np.float64)
        n = len(self.rest_positions)
        f = len(self.times)
        deferred = self.displacements
        if isinstance(deferred, DeferredFrames):
            if self.velocities is not deferred or deferred.shape != (f, n, 3):
                raise ShapeError(f"Trajectory's DeferredFrames must be given as both displacements and velocities, with shape "
                                 f"(frames, vertices, 3) = {(f, n, 3)}")
            # Missing attributes until __getattr__ builds them.
            del self.displacements, self.velocities
            self._deferred = deferred
        else:
            self.displacements, self.velocities = self._checked_frames(self.displacements, self.velocities)
        if not np.all(np.isfinite(self.times)):
            raise SolverError("Trajectory.times holds NaN or inf; refusing to keep a diverged simulation")
        if self.times.ndim != 1 or np.any(np.diff(self.times) <= 0):
            raise ShapeError("Trajectory.times must be a 1-D array of strictly increasing times in s")
        self.impact_times = np.asarray(self.impact_times, dtype=np.float64)
        k = len(self.impact_times)
        impact = np.zeros((0, n, 3)) if self.impact_displacements is None else self.impact_displacements
        self.impact_displacements = np.asarray(impact, dtype=np.float64)
        if self.impact_displacements.shape != (k, n, 3) or self.impact_times.ndim != 1:
            raise ShapeError(f"Trajectory.impact_displacements must have shape (impact frames, vertices, 3) = {(k, n, 3)} "
                             f"(one per impact time), got {self.impact_displacements.shape}")
        if not (np.all(np.isfinite(self.impact_displacements)) and np.all(np.isfinite(self.impact_times))):
            raise SolverError("Trajectory impact frames hold NaN or inf; refusing to keep a diverged simulation")
        if np.any(np.diff(self.impact_times) <= 0):
            raise ShapeError("Trajectory.impact_times must be strictly increasing times in s")
        self.iterations = np.asarray(self.iterations, dtype=np.int32)
        self.residuals = np.asarray(self.residuals, dtype=np.float64)
        self.converged = np.asarray(self.converged, dtype=bool)
        self.step_seconds = np.asarray(self.step_seconds, dtype=np.float64)
        for name in ("min_det_f", "penetration", "error_estimate"):
            a = np.asarray(getattr(self, name), dtype=np.float64)
            if a.shape not in ((0,), (f,)):
                raise ShapeError(f"Trajectory.{name} must have shape (frames,) = ({f},) or be empty, got {a.shape}")
            setattr(self, name, a)

    def _checked_frames(self, displacements: np.ndarray, velocities: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(displacements, velocities)`` as float64 arrays of shape (frames, vertices, 3), all finite.

        Raises:
            ShapeError: another shape.
            SolverError: a NaN or inf.
        """
        frames = {"displacements": np.asarray(displacements, dtype=np.float64), "velocities": np.asarray(velocities, dtype=np.float64)}
        shape = (len(self.times), len(self.rest_positions), 3)
        for name, a in frames.items():
            if a.shape != shape:
                raise ShapeError(f"Trajectory.{name} must have shape (frames, vertices, 3) = {shape}, got {a.shape}")
        for name, a in frames.items():
            if not np.all(np.isfinite(a)):
                raise SolverError(f"Trajectory.{name} holds NaN or inf; refusing to keep a diverged simulation")
        return frames["displacements"], frames["velocities"]

    def __getattr__(self, name: str) -> Any:
        """Deferred frames (:class:`DeferredFrames`), built on their first read; Python asks here only for missing attributes."""
        deferred = self.__dict__.get("_deferred") if name in _FRAMES else None
        if deferred is None:
            raise AttributeError(f"'{type(self).__name__}' object has no attribute '{name}'")
        for key, value in zip(_FRAMES, self._checked_frames(*deferred.build())):
            self.__dict__.setdefault(key, value)  # one assigned since construction stays
        self.__dict__.pop("_deferred", None)
        return self.__dict__[name]

    def __getstate__(self) -> dict[str, Any]:
        """The attributes to pickle or copy, frames built: a deferred build holds its simulation's arrays in a closure."""
        for name in _FRAMES:
            getattr(self, name)
        return self.__dict__

    @property
    def n_frames(self) -> int:
        return len(self.times)

    def __repr__(self) -> str:
        span = f"t = {self.times[0]:.4g}..{self.times[-1]:.4g} s" if self.n_frames else "no frames"
        planes = "; ".join(f"slope {p.slope_deg:.3g} deg, mu {p.friction:g}" for p in self.scene.planes) or "none"
        source = self.info.get("source", "unknown source")
        if source == "reduced":
            source += "".join(f", {k.replace('_', ' ')} {self.info[k]}" for k in ("frame", "n_modes", "cubature_points") if k in self.info)
        impacts = f" (+{len(self.impact_times)} impact frames)" if len(self.impact_times) else ""
        return (f"Trajectory({source}: {self.n_frames} frames{impacts}, {span}, {len(self.rest_positions)} vertices, {len(self.tets)} tets, "
                f"{len(self.iterations)} steps ({int((~self.converged).sum())} unconverged), planes: {planes})")

    @cached_property
    def mesh(self) -> Mesh:
        """The rest mesh (built once from the stored arrays)."""
        return Mesh(self.rest_positions, self.tets, fix_orientation=False)

    @property
    def valid(self) -> np.ndarray:
        """(f,) whether each frame is inside the valid range of the physics: no inverted
        elements and no penetration deeper than ``PENETRATION_LIMIT`` of the object's size
        (all True where not measured; see :mod:`licrom.validity`)."""
        ok = np.ones(self.n_frames, dtype=bool)
        if len(self.min_det_f):
            ok &= self.min_det_f > 0.0
        if len(self.penetration):
            ok &= self.penetration <= PENETRATION_LIMIT * self.mesh.size
        return ok

    def positions(self, frame: int) -> np.ndarray:
        """(n, 3) positions at ``frame``, m."""
        return self.rest_positions + self.displacements[frame]

    def centers_of_mass(self) -> np.ndarray:
        """(f, 3) mass-weighted centre of each frame, m."""
        return center_of_mass(self.rest_positions + self.displacements, self.mesh.vertex_masses(self.scene.material.density))

    def save(self, path: str | os.PathLike, precision: str = "float32") -> Path:
        """Write the trajectory to one ``.npz`` file atomically; return the path.

        Args:
            path: destination, ``.npz`` is appended if missing.
            precision: ``"float32"`` (default, half the size) or ``"float64"`` for the frames;
                rest positions are always float64.

        Raises:
            ShapeError: unknown precision, or frames beyond its range (they would be
                stored as inf, which :meth:`load` refuses).
            ConfigError: :attr:`info` is not a dict of JSON-serialisable values (the message names the
                first entry that is not).
        """
        if precision not in ("float32", "float64"):
            raise ShapeError(f"precision must be 'float32' or 'float64', got {precision!r}")
        _check_info(self.info)
        limit = float(np.finfo(precision).max)
        for name in ("displacements", "velocities", "impact_displacements"):
            # Values beyond float32 would be stored as inf, which load refuses.
            if np.abs(getattr(self, name)).max(initial=0.0) > limit:
                raise ShapeError(f"Trajectory.{name} exceed the {precision} range (|value| <= {limit:.3g}); save with precision='float64'")
        p = Path(path)
        if p.suffix != ".npz":
            p = p.with_name(p.name + ".npz")
        header = {
            "kind": "trajectory",
            "version": TRAJECTORY_FORMAT_VERSION if len(self.impact_times) else 1,
            "scene": self.scene.to_dict(),
            "info": self.info,
        }
        arrays = {
            "rest_positions": self.rest_positions,
            "tets": self.tets,
            "displacements": self.displacements.astype(precision),
            "velocities": self.velocities.astype(precision),
            "times": self.times,
            "iterations": self.iterations,
            "residuals": self.residuals,
            "converged": self.converged,
            "step_seconds": self.step_seconds,
            "min_det_f": self.min_det_f,
            "penetration": self.penetration,
            "error_estimate": self.error_estimate,
        }
        if len(self.impact_times):
            arrays |= {"impact_displacements": self.impact_displacements.astype(precision), "impact_times": self.impact_times}
        save_npz(p, arrays, header)
        return p

    @classmethod
    def load(cls, path: str | os.PathLike) -> Trajectory:
        """Read a file written by :meth:`save`.

        Raises:
            FileFormatError: missing, truncated or foreign file, unknown format version, or
                contents a trajectory cannot hold (wrong shapes, NaN, an invalid scene).
        """
        header, arrays = load_npz(path, "trajectory")
        check_version(header.get("version"), READABLE_VERSIONS, f"trajectory '{path}'")
        if not isinstance(header.get("info", {}), dict):
            raise FileFormatError(f"trajectory '{path}' has a corrupt header: 'info' must be a JSON object")
        _check_members(path, arrays)
        try:
            return cls(scene=Scene.from_dict(header["scene"]), info=header.get("info", {}), **arrays)
        except FileFormatError:
            raise
        except (KeyError, TypeError) as exc:
            raise FileFormatError(f"trajectory '{path}' is missing data: {exc}") from exc
        except (LicromError, ValueError) as exc:
            raise FileFormatError(f"trajectory '{path}' holds invalid data: {exc}") from exc


_JSON_INFO = ("Trajectory.info must be a dict of JSON-serialisable values (dicts, lists, tuples, str, int, float, "
              "bool, None; arrays as .tolist())")


def _check_info(info: Any) -> None:
    """Refuse an ``info`` the file's JSON header cannot hold, naming the entry, before anything is written.

    Raises:
        ConfigError: not a dict, or an entry that is not JSON (an array, a NumPy integer, a set, an object, a key
            that is no str, int, float, bool or None, a cycle, or nesting too deep).
    """
    if not isinstance(info, dict):
        raise ConfigError(f"{_JSON_INFO}; got {type(info).__name__}")

    def bad(value: Any, where: str, open_: tuple[int, ...]) -> str | None:
        """What is wrong first at or under ``value`` (reached as ``where``), None when it is JSON."""
        if value is None or isinstance(value, (str, bool, int, float)):
            return None
        if not isinstance(value, (dict, list, tuple)):
            return f"{where} is a {type(value).__name__}"
        if id(value) in open_:
            return f"{where} refers back to an entry that holds it (a cycle)"
        items = value.items() if isinstance(value, dict) else enumerate(value)
        for key, item in items:
            if isinstance(value, dict) and key is not None and not isinstance(key, (str, int, float)):  # json writes these as strings
                return f"{where} has a key {key!r} of type {type(key).__name__}"
            found = bad(item, f"{where}[{key!r}]", (*open_, id(value)))
            if found is not None:
                return found
        return None

    try:
        found = bad(info, "info", ())
    except RecursionError:
        found = "info is nested too deeply"
    if found is not None:
        raise ConfigError(f"{_JSON_INFO}; {found}")


def _check_members(path: Any, arrays: dict[str, np.ndarray]) -> None:
    """Refuse a file whose arrays are not real numbers or whose mesh part is no mesh, naming the member."""
    for key in sorted(arrays):
        if arrays[key].dtype.kind not in "biuf":
            raise FileFormatError(f"trajectory '{path}' member {key} must hold real numbers, it holds dtype {arrays[key].dtype}")
    rest = arrays.get("rest_positions")
    if rest is None:
        return  # the constructor names the missing member
    if rest.ndim != 2 or rest.shape[1] != 3:
        raise FileFormatError(f"trajectory '{path}' member rest_positions must have shape (n, 3), got {rest.shape}")
    if not np.all(np.isfinite(rest)):
        raise FileFormatError(f"trajectory '{path}' member rest_positions holds NaN or inf; every position must be finite")
    tets = arrays.get("tets")
    if tets is None:
        return
    if tets.ndim != 2 or tets.shape[1] != 4:
        raise FileFormatError(f"trajectory '{path}' member tets must have shape (m, 4), got {tets.shape}")
    if tets.size and tets.dtype.kind not in "iu":
        raise FileFormatError(f"trajectory '{path}' member tets must hold integer vertex indices, it holds dtype {tets.dtype}")
    if tets.size and (int(tets.min()) < 0 or int(tets.max()) >= len(rest)):
        raise FileFormatError(f"trajectory '{path}' member tets holds vertex indices from {int(tets.min())} to {int(tets.max())}; "
                              f"accepted 0 to {len(rest) - 1} (its {len(rest)} rest positions)")
