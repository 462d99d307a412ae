"""How far a scene's own full run moves when its inputs move a little: the accuracy a model can be held to.

A noise floor (the same scene dropped 0.1 mm higher) says whether a run repeats. It does not say whether the run is
stable against the errors a reduced model makes, which change the body's path and stiffness by more than that. A
cheese tumbling down a 30 deg, mu 0.8 slope repeats to 1.3 % non-rigid from a drop 0.1 mm higher, and moves 15-49 %
when it is dropped 1 mm higher, its slope turned by 1 deg or its Young's modulus raised by 2 % (docs/results.md
section 68): no model of it can be held to 1.3 %.

:func:`sensitivity` runs the scene in full space once as it is and once per moved input (:class:`Perturbations`),
and compares each moved run with the scene's run as :func:`licrom.analysis.compare.compare` compares a reduced run
(non-rigid error from the first contact, final centre of mass over the size, stick/slip). The largest of those is the
scene's **spread**: a reduced run within a small multiple of it is as good as the scene's inputs are known. The run at
half the time step is kept apart: it measures the truth's own error in time, not the scene's conditioning.

Chaos is judged on the non-rigid spread alone (:data:`CHAOTIC_SPREAD`). The centre of mass of a slide is sensitive to
its inputs without being chaotic: a slope turned by half a degree or mu raised by 0.01 changes a slide's acceleration
by several percent, and its end point by a third of its size over a metre (section 68), while its shape moves 1-3 %.
A reduced model keeps gravity and friction exact, so its slides land far closer than that spread; the spread of the
centre of mass bounds only runs whose shape spread is large too.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._repr import concise_repr
from ..errors import ConfigError
from ..geometry.mesh import Mesh
from ..records.trajectory import Trajectory
from ..scene.scene import Scene
from .compare import compare

__all__ = ["CHAOTIC_SPREAD", "HALF_STEP", "Perturbations", "Sensitivity", "perturbed_scenes", "sensitivity"]

HALF_STEP = "h / 2"
"""Label of the run at half the time step (the truth's convergence in time, not an input moved)."""

CHAOTIC_SPREAD = 0.10
"""Non-rigid spread above which a scene is chaotic at the scale of a model's error: a run moved by a millimetre, half
a degree, 0.01 in mu or 2 % in stiffness ends 10 % or more away (the held-out cheese slides of docs/results.md section
68 stay under it; its tumbles do not)."""


@dataclass(frozen=True)
class Perturbations:
    """How far each input of a scene is moved, one at a time.

    Attributes:
        drop: m the start is moved against gravity, > 0 (1 mm: more than the 0.1 mm noise floor, less than the shape
            error of a model at a few percent).
        tilt_deg: degrees gravity is turned about each of two horizontal axes, in (0, 10]: a slope or its downhill
            direction known to half a degree.
        friction: added to every plane's Coulomb coefficient, > 0.
        stiffness: relative change of Young's modulus, in (0, 0.5].
        half_step: also run at half the time step (twice the steps), the truth's own error in time.
    """

    drop: float = 1.0e-3
    tilt_deg: float = 0.5
    friction: float = 0.01
    stiffness: float = 0.02
    half_step: bool = True

    __repr__ = concise_repr

    def __post_init__(self) -> None:
        for name, value, low, high in (("drop (m)", self.drop, 0.0, math.inf), ("tilt_deg", self.tilt_deg, 0.0, 10.0),
                                       ("friction", self.friction, 0.0, math.inf), ("stiffness", self.stiffness, 0.0, 0.5)):
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not (low < value <= high and math.isfinite(value)):
                raise ConfigError(f"Perturbations.{name} must be a number in ({low:g}, {high:g}], got {value!r}")


def _horizontal_axes(gravity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to gravity and to each other (x and y when gravity is along z)."""
    down = gravity / np.linalg.norm(gravity)
    seed = np.array([1.0, 0.0, 0.0]) if abs(down[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    first = seed - down * (seed @ down)
    first /= np.linalg.norm(first)
    return first, np.cross(down, first)


def _turned(vector: np.ndarray, axis: np.ndarray, angle: float) -> tuple[float, float, float]:
    """``vector`` rotated by ``angle`` rad about the unit ``axis``."""
    from scipy.spatial.transform import Rotation

    return tuple(float(v) for v in Rotation.from_rotvec(angle * axis).apply(vector))


def perturbed_scenes(scene: Scene, perturbations: Perturbations = Perturbations()) -> dict[str, Scene]:
    """Label -> the scene with one input moved (:class:`Perturbations`), the half step last (:data:`HALF_STEP`).

    Raises:
        ConfigError: a scene without gravity (nothing to tilt or drop against).
    """
    gravity = np.asarray(scene.gravity, dtype=float)
    if not np.linalg.norm(gravity) > 0.0:
        raise ConfigError("sensitivity needs a scene with gravity: the drop and the tilt are taken against it")
    p = perturbations
    up = -gravity / np.linalg.norm(gravity)
    init = scene.initial
    first, second = _horizontal_axes(gravity)
    tilt = math.radians(p.tilt_deg)
    scenes = {
        f"{1e3 * p.drop:g} mm higher": scene.replace(initial=dataclasses.replace(
            init, translation=tuple(float(v) for v in np.add(init.translation, p.drop * up)))),
        f"gravity turned {p.tilt_deg:g} deg (1)": scene.replace(gravity=_turned(gravity, first, tilt)),
        f"gravity turned {p.tilt_deg:g} deg (2)": scene.replace(gravity=_turned(gravity, second, tilt)),
        f"mu +{p.friction:g}": scene.replace(planes=tuple(dataclasses.replace(pl, friction=pl.friction + p.friction) for pl in scene.planes)),
        f"E +{100 * p.stiffness:g} %": scene.replace(material=dataclasses.replace(
            scene.material, youngs_modulus=scene.material.youngs_modulus * (1.0 + p.stiffness))),
    }
    if not scene.planes:
        del scenes[f"mu +{p.friction:g}"]
    if p.half_step:
        scenes[HALF_STEP] = scene.replace(dt=scene.dt / 2)
    return scenes


@dataclass(frozen=True)
class Sensitivity:
    """A scene's full runs with one input moved each, against the scene's own run.

    Attributes:
        rows: label -> ``{"nonrigid_error", "com_error", "stick_slip_agree"}`` of each moved run against the scene's
            (fractions; the centre of mass over the object's size, at the last frame).
        reference: the scene's own full run.
    """

    rows: dict[str, dict[str, Any]]
    reference: Trajectory

    __repr__ = concise_repr

    def _inputs(self) -> list[dict[str, Any]]:
        return [row for label, row in self.rows.items() if label != HALF_STEP]

    @property
    def nonrigid_spread(self) -> float:
        """Largest non-rigid error of a run with one input moved (the half step not counted)."""
        return max((r["nonrigid_error"] for r in self._inputs()), default=0.0)

    @property
    def com_spread(self) -> float:
        """Largest final centre-of-mass distance over the size of a run with one input moved."""
        return max((r["com_error"] for r in self._inputs()), default=0.0)

    @property
    def chaotic(self) -> bool:
        """Whether the non-rigid spread is at or above :data:`CHAOTIC_SPREAD`."""
        return self.nonrigid_spread >= CHAOTIC_SPREAD

    @property
    def time_step_error(self) -> dict[str, Any] | None:
        """The row of the run at half the time step (the truth's own error in time), None where not run."""
        return self.rows.get(HALF_STEP)

    def summary(self) -> dict[str, Any]:
        """Plain numbers: the spreads, whether chaotic, the half-step row and every row."""
        return {"nonrigid_spread": self.nonrigid_spread, "com_spread": self.com_spread, "chaotic": self.chaotic,
                "time_step_error": self.time_step_error, "rows": self.rows}


def sensitivity(mesh: Mesh, scene: Scene, steps: int, record_every: int = 1, perturbations: Perturbations = Perturbations(),
                reference: Trajectory | None = None, device: str | None = None,
                on_run: Callable[[str, dict[str, Any]], None] | None = None) -> Sensitivity:
    """Run ``scene`` in full space with each input moved (:func:`perturbed_scenes`) and measure how far each run ends.

    Args:
        mesh: the object.
        scene: the scene as given.
        steps: time steps of each run (twice as many at half the step).
        record_every: steps between recorded frames (doubled at half the step, so the frames fall at the same times).
        perturbations: how far each input moves.
        reference: the scene's own full run with these steps and frames, where one exists (else it is run here).
        device: warp device of the full simulations (default: CUDA when visible, else the CPU).
        on_run: called with each label and its row as it finishes (progress of a long study).

    Returns:
        The rows and the spreads.

    Raises:
        ConfigError: a scene without gravity, ``steps`` or ``record_every`` below 1, or a ``reference`` of other
            frame times.
    """
    from ..full import FullSim

    for name, value in (("steps", steps), ("record_every", record_every)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ConfigError(f"sensitivity {name} must be an integer >= 1, got {value!r}")
    scenes = perturbed_scenes(scene, perturbations)
    if reference is None:
        reference = FullSim(mesh, scene, device=device).run(steps, record_every=record_every)
    elif reference.n_frames != steps // record_every + 1:
        raise ConfigError(f"the reference run has {reference.n_frames} frames; {steps} steps recorded every {record_every} "
                          f"make {steps // record_every + 1}")
    rows = {}
    for label, moved in scenes.items():
        scale = 2 if label == HALF_STEP else 1
        run = FullSim(mesh, moved, device=device).run(scale * steps, record_every=scale * record_every)
        c = compare(reference, run)
        rows[label] = {"nonrigid_error": c.nonrigid_error, "com_error": c.final_com_error,
                       "stick_slip_agree": bool(c.stick_slip_agree)}
        if on_run is not None:
            on_run(label, rows[label])
    return Sensitivity(rows, reference)
