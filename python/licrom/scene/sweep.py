"""Sweeps: the runs of a data set and the scenes of a comparison, as products of their axes.

A sweep is the cartesian product of its axes (friction coefficients, slopes or plane
configurations, initial states), the first axis outermost: its value changes slowest, the
last axis's fastest. An axis that is None or empty is not swept: it is one value, its
default (None unless given). The callers name their axes in their own order:

- a data set's runs, in file order, are frictions x planes x initial states
  (:func:`licrom.data.dataset.sweep_runs`, :attr:`licrom.data.dataset.DatasetSpec.n_trajectories`);
- a scene file's runs are frictions x slopes x initial states
  (:attr:`licrom.data.scene_file.SceneFile.n_runs`), and the comparison over every run of its
  sweep frictions x slopes;
- the scenes a comparison is given are slopes x frictions (:func:`slope_friction_pairs`:
  ``SceneFile.cases`` with slopes or frictions, ``licrom compare`` without a scene file).

Here too: a plane's default friction (:data:`DEFAULT_FRICTION`, :class:`~licrom.scene.scene.Plane`'s),
the one check of a friction coefficient (:func:`check_friction`), the held-out (slope,
friction) pairs with the first plane's values for those left out (:func:`held_out_pairs`),
whether such a pair is a run of the training sweep (:func:`in_sweep`), and the planes of a run
(:func:`tilted`, :func:`with_friction`).
"""

from __future__ import annotations

import itertools
import math
import numbers
from collections.abc import Iterable, Sequence
from dataclasses import replace
from typing import Any

from ..errors import ConfigError
from .scene import Plane

__all__ = [
    "DEFAULT_FRICTION",
    "check_friction",
    "held_out_pairs",
    "in_sweep",
    "slope_friction_pairs",
    "sweep",
    "sweep_axis",
    "sweep_count",
    "tilted",
    "with_friction",
]

DEFAULT_FRICTION: float = Plane().friction
"""The Coulomb coefficient of a plane that names none: the default of :attr:`Plane.friction <licrom.scene.scene.Plane>` (0.5)."""


def check_friction(value: Any, name: str = "friction") -> float:
    """``value`` as a float if it is a Coulomb friction coefficient: a real number (not a bool), finite and >= 0.

    Raises:
        ConfigError: it is not; the message names ``name`` (``"{name} must be a number >= 0, got ..."``).
    """
    try:
        v = float(value) if isinstance(value, numbers.Real) and not isinstance(value, bool) else math.nan
    except OverflowError:  # an integer beyond float range
        v = math.inf
    if not (math.isfinite(v) and v >= 0.0):
        raise ConfigError(f"{name} must be a number >= 0, got {value!r}")
    return v


def sweep_axis(values: Iterable[Any] | None, default: Any = None) -> tuple[Any, ...]:
    """The values of one axis: ``values`` as a tuple, or ``(default,)`` when they are None or empty (the axis is not swept)."""
    given = () if values is None else tuple(values)
    return given or (default,)


def sweep(*axes: Iterable[Any] | None) -> list[tuple[Any, ...]]:
    """Every combination of one value of each axis, the first axis outermost (its value changes slowest).

    An axis that is None or empty is one value, None (see :func:`sweep_axis` to give it a default).
    """
    return list(itertools.product(*(sweep_axis(a) for a in axes)))


def sweep_count(*axes: Iterable[Any] | None) -> int:
    """How many combinations :func:`sweep` gives for the same axes."""
    return math.prod(len(sweep_axis(a)) for a in axes)


def _slope_and_friction(plane: Plane | None) -> tuple[float, float]:
    """``plane``'s slope in degrees and friction; of a horizontal plane of :data:`DEFAULT_FRICTION` when None."""
    return (0.0, DEFAULT_FRICTION) if plane is None else (plane.slope_deg, plane.friction)


def slope_friction_pairs(slopes: Iterable[float] | None, frictions: Iterable[float] | None,
                         plane: Plane | None) -> list[tuple[float, float]]:
    """The (slope, friction) scenes of slopes x frictions, slopes outermost.

    An axis not given (None or empty) is ``plane``'s own slope or friction; with no plane, a
    horizontal one of :data:`DEFAULT_FRICTION`.
    """
    slope, friction = _slope_and_friction(plane)
    return sweep(sweep_axis(slopes, slope), sweep_axis(frictions, friction))


def held_out_pairs(held_out: Iterable[tuple[float | None, float | None]], plane: Plane | None) -> list[tuple[float, float]]:
    """Each held-out ``(slope, friction)``, a None replaced by ``plane``'s slope or friction (no plane: horizontal, :data:`DEFAULT_FRICTION`)."""
    slope, friction = _slope_and_friction(plane)
    return [(slope if s is None else s, friction if m is None else m) for s, m in held_out]


def in_sweep(point: Sequence[float], *axes: Iterable[float]) -> bool:
    """True when ``point`` is, within rounding (:func:`math.isclose`), a combination of the axes: each of its values close to one of its axis."""
    axes_ = [tuple(a) for a in axes]
    return len(point) == len(axes_) and all(any(math.isclose(v, a) for a in axis) for v, axis in zip(point, axes_))


def tilted(planes: Sequence[Plane], slope: float, friction: float | None = None) -> tuple[Plane, ...]:
    """``planes`` with the first one inclined by ``slope`` degrees (its azimuth and offset kept, its friction
    unless ``friction`` is given: :meth:`Plane.incline <licrom.scene.scene.Plane.incline>`); the others as they are."""
    first = planes[0]
    plane = Plane.incline(slope, first.friction if friction is None else friction, offset=first.offset, azimuth_deg=first.azimuth_deg)
    return (plane, *planes[1:])


def with_friction(planes: Iterable[Plane], friction: float | None) -> tuple[Plane, ...]:
    """``planes`` with every friction coefficient replaced by ``friction`` (None: as they are): one run of a friction sweep."""
    return tuple(planes) if friction is None else tuple(replace(p, friction=friction) for p in planes)
