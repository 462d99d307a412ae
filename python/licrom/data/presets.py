"""The built-in scenes as the report's data sets: :func:`report_dataset_spec` of a preset name."""

from __future__ import annotations

from ..errors import ConfigError
from .dataset import DatasetSpec
from .scene_file import builtin_scenes, load_scene

__all__ = ["PRESETS", "report_dataset_spec"]

PRESETS = builtin_scenes()
"""The built-in scene files, by name: the presets of :func:`report_dataset_spec`."""


def report_dataset_spec(preset: str = "cheese", resolution: int | None = None, steps: int | None = None,
                        record_every: int | None = None) -> DatasetSpec:
    """A built-in scene file (``licrom/scenes/NAME.toml``) as a dataset spec.

    - ``"cheese"``: the report's training set: the cheese block (default resolution 12,
      ~2.5k tets; E = 100 kPa, nu = 0.3, 1000 kg/m^3) dropped from 2 cm, slightly tilted,
      onto an incline: 5 friction coefficients (0.1, 0.3, 0.5, 0.7, 0.9) x 3 slopes (10, 20,
      30 deg) = 15 runs of 2 s (h = 10 ms). tan(10, 20, 30 deg) = 0.18, 0.36, 0.58, so the
      set holds sliding (mu < tan) and sticking (mu > tan) runs on every slope but the
      steepest-with-0.9.
    - ``"sphere"``: a ball (radius 5 cm, default resolution 8, E = 100 kPa) thrown down a
      20 deg slope with mu 0.5 from 20 cm, moving downhill at 0.5 m/s and into the plane
      at 1 m/s; h = 2 ms so that backward Euler keeps the bounces (at h = 10 ms its
      numerical damping absorbs them), 1.5 s (750 steps, every 5th recorded).
    - ``"demo"``: the training set of ``licrom demo`` (a small cheese, 2 slopes x 3 mu).

    Args:
        preset: the name of a built-in scene (:data:`PRESETS`).
        resolution: mesh resolution (cells along the longest side) [the scene's].
        steps: time steps per run [the scene's].
        record_every: record every n-th step [the scene's].
    """
    if preset not in PRESETS:
        raise ConfigError(f"unknown dataset preset {preset!r}; accepted: {', '.join(PRESETS)}")
    return load_scene(preset).overridden(resolution=resolution, steps=steps, record_every=record_every).dataset_spec()
