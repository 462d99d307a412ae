"""Full vs reduced: run both on one scene and measure how far apart they are.

Errors are mass-weighted, so they do not depend on how the mesh is refined:
``e(t) = |u_r(t) - u_f(t)|_M / |u_f(t)|_M`` per frame, the centre-of-mass distance
as a fraction of the object's size, whether the object slid or stuck in each,
the deepest penetration, and the per-step wall time of both.

The displacement error is dominated by rigid motion (a slide of a few sizes hides a
shape that is far off), so the shape is measured on its own: each frame's best rigid
fit removed (:mod:`licrom.rigid`), the error of the body-frame displacements from the
first contact on, the peak deformation and the total rotation of each run.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from .._repr import concise_repr
from ..errors import ConfigError, ShapeError
from ..geometry.mesh import Mesh
from ..records.trajectory import Trajectory
from ..reduced.error_estimate import ERROR_THRESHOLD
from ..rigid import body_frame_displacements, relative_error, rigid_fit, rotation_angle
from ..scene.scene import Scene
from ..validity import CONTACT_TOLERANCE, first_touch

__all__ = [
    "COM_TARGET",
    "METRICS",
    "NONRIGID_TARGET",
    "Comparison",
    "Metric",
    "compare",
    "first_contact_frame",
    "judge",
    "nonrigid_error",
    "peak_nonrigid_deformation",
    "penetration_depths",
    "plane_gaps",
    "run_comparison",
    "slip_distance",
    "time_steps",
    "total_rotation",
    "verdict",
]

# An object "slides" when its contact points slip further than this fraction of its size
# over the second half of the run (after a drop's landing transient has passed).
SLIDE_THRESHOLD = 0.01


def _positions(traj: Trajectory) -> np.ndarray:
    """(f, n, 3) positions of every frame, m."""
    return traj.rest_positions[None] + traj.displacements


def _masses(traj: Trajectory) -> np.ndarray:
    return traj.mesh.vertex_masses(traj.scene.material.density)


def plane_gaps(traj: Trajectory, scene: Scene | None = None) -> np.ndarray:
    """(f, n, p) signed distance of every vertex from every plane of ``scene`` per frame, m.

    Negative inside a plane's half-space; ``p = 0`` when the scene has no planes.
    """
    planes = (scene or traj.scene).plane_array()
    return np.einsum("fnk,pk->fnp", _positions(traj), planes[:, :3]) + planes[:, 3]


def penetration_depths(traj: Trajectory, scene: Scene | None = None) -> np.ndarray:
    """(f,) deepest penetration of any vertex below any plane per frame, m (0 if none)."""
    gaps = plane_gaps(traj, scene)
    if gaps.shape[2] == 0:
        return np.zeros(traj.n_frames)
    return np.maximum(-gaps.min(axis=(1, 2)), 0.0)


def first_contact_frame(traj: Trajectory, contact_tolerance: float | None = None) -> int | None:
    """Index of the first frame where any vertex touches a plane; None if none ever does.

    A vertex touches when its gap is below ``contact_tolerance`` (m, default 0.5% of the
    object's size). None also when the scene has no planes.
    """
    tol = CONTACT_TOLERANCE * traj.mesh.size if contact_tolerance is None else contact_tolerance
    return first_touch(_positions(traj), traj.scene.plane_array(), tol)


def slip_distance(traj: Trajectory, contact_tolerance: float | None = None, start: int = 1) -> float:
    """Distance the contact points slid along the planes from frame ``start`` on, m.

    Integrates, over the recorded frames, the mean tangential speed of the vertices in
    contact (gap below ``contact_tolerance``, default 0.5% of the object's size).
    Rolling without slipping gives ~0; sticking gives ~0; sliding gives the slide length.
    """
    scene = traj.scene
    if not scene.planes or traj.n_frames < 2:
        return 0.0
    tol = CONTACT_TOLERANCE * traj.mesh.size if contact_tolerance is None else contact_tolerance
    normals = scene.plane_array()[:, :3]
    touching = plane_gaps(traj) < tol  # (f, n, p)
    total = 0.0
    for f in range(max(start, 1), traj.n_frames):
        v = traj.velocities[f]
        speeds = []
        for p, n in enumerate(normals):
            on = touching[f, :, p]
            if on.any():
                vt = v[on] - np.outer(v[on] @ n, n)
                speeds.append(np.linalg.norm(vt, axis=1).mean())
        if speeds:
            total += max(speeds) * (traj.times[f] - traj.times[f - 1])
    return float(total)


def _check_same_run(a: Trajectory, b: Trajectory, what: str) -> None:
    if a.n_frames == 0:
        raise ShapeError(f"{what} needs trajectories with at least one frame")
    if a.rest_positions.shape != b.rest_positions.shape or not np.allclose(a.rest_positions, b.rest_positions):
        raise ShapeError(f"{what} needs both trajectories on the same mesh (rest positions differ)")
    if a.n_frames != b.n_frames or not np.allclose(a.times, b.times):
        raise ShapeError(f"{what} needs the same frame times (got {a.n_frames} and {b.n_frames} frames)")


def nonrigid_error(
    reference: Trajectory, other: Trajectory, start: int | None = None, contact_tolerance: float | None = None
) -> float:
    """Relative error of the non-rigid deformation of ``other`` against ``reference``.

    Each run's own best rigid fit is removed from every frame (mass-weighted centre and
    Kabsch rotation, :func:`licrom.rigid.body_frame_displacements`); the result is
    ``sqrt(sum_t |d_t|_M^2 / sum_t |u_t|_M^2)`` over frames ``t >= start``, with ``u_t``
    the reference's body-frame displacements and ``d_t`` the difference of the two. Works
    on any two runs of one mesh and frame times: full against reduced, or full against
    full with a perturbed start (the noise floor of a scene).

    Args:
        reference: the run taken as the truth.
        other: the run measured.
        start: first frame counted (default: the reference's first contact, see
            :func:`first_contact_frame`; every frame when it never touches a plane).
        contact_tolerance: gap below which a vertex touches, m (default 0.5% of the size).

    Returns:
        The relative error (0 for identical shapes; unbounded when the reference
        hardly deforms over the frames counted).

    Raises:
        ShapeError: different meshes or frame times.
        ConfigError: ``start`` not a frame index.
    """
    _check_same_run(reference, other, "nonrigid_error")
    if start is None:
        start = first_contact_frame(reference, contact_tolerance) or 0
    if isinstance(start, bool) or not isinstance(start, (int, np.integer)) or not 0 <= start < reference.n_frames:
        raise ConfigError(f"nonrigid_error start must be a frame index in [0, {reference.n_frames}), got {start!r}")
    masses = _masses(reference)
    rest = reference.rest_positions
    ref = body_frame_displacements(_positions(reference)[start:], rest, masses)
    oth = body_frame_displacements(_positions(other)[start:], rest, masses)
    return relative_error(ref, oth, masses)


def peak_nonrigid_deformation(traj: Trajectory) -> float:
    """Largest body-frame displacement of any vertex in any frame, as a fraction of the object's size.

    The body-frame displacement is what is left of a vertex's motion once the frame's best
    rigid fit is removed (:func:`licrom.rigid.body_frame_displacements`).
    """
    d = body_frame_displacements(_positions(traj), traj.rest_positions, _masses(traj))
    return float(np.linalg.norm(d, axis=-1).max()) / traj.mesh.size


def total_rotation(traj: Trajectory) -> float:
    """Accumulated rotation of the best-fit frame over the run, degrees.

    Sum over consecutive frames of the angle of ``R_{t+1} R_t^T``, so a body turning back
    and forth adds both ways. Frames must be close enough that the body turns less than
    half a turn between them (a faster spin is aliased to a smaller angle).
    """
    if traj.n_frames < 2:
        return 0.0
    _, r = rigid_fit(_positions(traj), traj.rest_positions, _masses(traj))
    steps = r[1:] @ np.swapaxes(r[:-1], -1, -2)
    return math.degrees(float(rotation_angle(steps).sum()))


@dataclass(frozen=True)
class Comparison:
    """How a reduced trajectory differs from the full one on the same mesh and scene.

    Attributes:
        times: (f,) frame times, s.
        frame_errors: (f,) relative mass-weighted displacement error per frame.
        com_errors: (f,) centre-of-mass distance per frame as a fraction of the object size.
        mean_error: mean of ``frame_errors`` over frames after the first.
        final_com_error: ``com_errors`` at the last frame (mass-weighted centroids).
        nonrigid_error: relative error of the body-frame (non-rigid) displacements from
            the full run's first contact on, see :func:`nonrigid_error`.
        nonrigid_start_time: time of the first frame counted in ``nonrigid_error``, s.
        peak_deformation_full, peak_deformation_reduced: largest body-frame displacement of
            any vertex over the run, as a fraction of the object size.
        rotation_full, rotation_reduced: total rotation of the best-fit frame, degrees.
        slip_full, slip_reduced: slide distance of the contact points over the run, m.
        slid_full, slid_reduced: whether each slides: slip over the second half of the
            run above 1% of the object size (so a landing transient does not count).
        penetration_full, penetration_reduced: deepest penetration, m.
        full_step_ms, reduced_step_ms: median wall time per step, ms.
        full_iterations, reduced_iterations: mean Newton iterations per step.
        object_size: bounding-box diagonal of the rest shape, m.
        error_estimate: the reduced run's own estimate of its non-rigid error, computed
            online without the full run (last frame of ``Trajectory.error_estimate``, see
            :mod:`licrom.reduced.error_estimate`); NaN when the run has none.
    """

    times: np.ndarray
    frame_errors: np.ndarray
    com_errors: np.ndarray
    mean_error: float
    final_com_error: float
    nonrigid_error: float
    nonrigid_start_time: float
    peak_deformation_full: float
    peak_deformation_reduced: float
    rotation_full: float
    rotation_reduced: float
    slip_full: float
    slip_reduced: float
    slid_full: bool
    slid_reduced: bool
    penetration_full: float
    penetration_reduced: float
    full_step_ms: float
    reduced_step_ms: float
    full_iterations: float
    reduced_iterations: float
    object_size: float
    error_estimate: float = math.nan

    __repr__ = concise_repr

    @property
    def stick_slip_agree(self) -> bool:
        return self.slid_full == self.slid_reduced

    @property
    def speedup(self) -> float:
        return self.full_step_ms / self.reduced_step_ms if self.reduced_step_ms > 0 else math.nan

    def summary(self) -> dict[str, Any]:
        """Scalars only, JSON-ready."""
        d = {k: v for k, v in asdict(self).items() if not isinstance(v, np.ndarray)}
        d = {k: (bool(v) if isinstance(v, (bool, np.bool_)) else float(v)) for k, v in d.items()}
        d["stick_slip_agree"] = self.stick_slip_agree
        d["speedup"] = self.speedup
        return d

    def table(self) -> str:
        """A human-readable summary table."""
        rows = [
            ("mean relative displacement error", f"{100 * self.mean_error:.2f} %"),
            ("final centre-of-mass error / size", f"{100 * self.final_com_error:.2f} %"),
            (f"non-rigid deformation error (from {self.nonrigid_start_time:.3g} s)", f"{100 * self.nonrigid_error:.2f} %"),
            ("estimated non-rigid error (online, no full run)", f"{100 * self.error_estimate:.2f} %"),
            ("peak non-rigid deformation / size full / reduced",
             f"{100 * self.peak_deformation_full:.2f} % / {100 * self.peak_deformation_reduced:.2f} %"),
            ("total rotation full / reduced", f"{self.rotation_full:.1f} deg / {self.rotation_reduced:.1f} deg"),
            ("slide distance full / reduced", f"{1e3 * self.slip_full:.2f} mm / {1e3 * self.slip_reduced:.2f} mm"),
            ("stick/slip full / reduced", f"{'slides' if self.slid_full else 'sticks'} / {'slides' if self.slid_reduced else 'sticks'}"
             f" ({'agree' if self.stick_slip_agree else 'DISAGREE'})"),
            ("max penetration full / reduced", f"{1e3 * self.penetration_full:.3f} mm / {1e3 * self.penetration_reduced:.3f} mm"),
            ("Newton iterations per step full / reduced", f"{self.full_iterations:.1f} / {self.reduced_iterations:.1f}"),
            ("time per step full / reduced", f"{self.full_step_ms:.3f} ms / {self.reduced_step_ms:.4f} ms"),
            ("speedup per step", f"{self.speedup:.0f}x"),
        ]
        width = max(len(r[0]) for r in rows)
        return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


@dataclass(frozen=True)
class Metric:
    """One number of a comparison: how it is shown, what it means and its target.

    Attributes:
        key: the key in :meth:`licrom.analysis.compare.Comparison.summary`.
        name: the column's name.
        definition: what the number is, in a sentence.
        target: the target in words ("" where there is none: the number informs).
        meets: whether a value meets the target (None where there is none).
        show: the value as text.
    """

    key: str
    name: str
    definition: str
    target: str
    meets: Callable[[Any], bool] | None
    show: Callable[[Any], str]


def _pct(v: float) -> str:
    return f"{100 * v:.2f} %"


NONRIGID_TARGET = 0.10
"""Target of the non-rigid deformation error (relative)."""
COM_TARGET = 0.02
"""Target of the final centre-of-mass error, over the object's size."""

METRICS = (
    Metric("nonrigid_error", "non-rigid error",
           "How far the reduced run's deformation is from the full run's: each frame's best rigid fit removed from both, "
           "the mass-weighted distance between them over the full run's deformation, in the body frame, from first contact.",
           "< 10 %", lambda v: v < NONRIGID_TARGET, _pct),
    Metric("final_com_error", "final centre-of-mass error",
           "Distance between the two runs' centres of mass at the last frame, over the object's size (bounding-box diagonal).",
           "< 2 % of the size", lambda v: v < COM_TARGET, _pct),
    Metric("stick_slip_agree", "stick/slip",
           "Whether both runs slide, or both stick (a run slides when its contact points slip more than 1 % of the size "
           "over the second half of the run).",
           "the same in both", bool, lambda v: "agree" if v else "DISAGREE"),
    Metric("error_estimate", "estimated non-rigid error",
           "The reduced run's own estimate of its non-rigid error, made without the full run (the relative residual of the "
           "full equations at the reconstructed state, licrom.reduced.error_estimate); an AccuracyWarning is raised above the threshold, "
           "set below the 10 % target because the estimate reads a chaotic run 2-4x low.",
           f"< {100 * ERROR_THRESHOLD:.0f} %", lambda v: v < ERROR_THRESHOLD, _pct),
    Metric("mean_error", "mean displacement error",
           "Mean over frames of the mass-weighted distance between the runs' displacements over the full run's: mostly "
           "measures the slide, so it stays small while the deformation is wrong; the non-rigid error measures that.",
           "", None, _pct),
    Metric("speedup", "speed-up per step",
           "The full step's median wall time over the reduced step's, both in this process.", "", None, lambda v: f"{v:.0f}x"),
)


def judge(m: Metric, summary: dict[str, Any]) -> bool | None:
    """Whether the summary's value meets the metric's target; None without a target or a value (NaN: not measured)."""
    v = summary.get(m.key)
    if m.meets is None or v is None or (isinstance(v, float) and not math.isfinite(v)):
        return None
    return bool(m.meets(v))


def verdict(summary: dict[str, Any]) -> tuple[bool, list[str]]:
    """Whether a comparison's summary meets every target of :data:`METRICS` it has a value for, and the names of those it misses."""
    missed = [m.name for m in METRICS if judge(m, summary) is False]
    return not missed, missed


def compare(full: Trajectory, reduced: Trajectory) -> Comparison:
    """Compare two trajectories of the same mesh, scene and frame times.

    Raises:
        ShapeError: different meshes or frame times.
    """

    _check_same_run(full, reduced, "compare")
    masses = _masses(full)
    size = full.mesh.size
    # Frames where the object has hardly moved would divide by ~0: each frame is measured against
    # at least a shift s by 0.1% of the size, |d|/max(|u|, |s|) = min(|d|/|u|, |d|/|s|).
    shift = np.zeros_like(full.rest_positions)
    shift[:, 0] = 1e-3 * size
    errors = np.array([
        min(relative_error(uf, ur, masses), relative_error(shift, shift + ur - uf, masses))
        for uf, ur in zip(full.displacements, reduced.displacements)
    ])
    start = first_contact_frame(full) or 0
    com_err = np.linalg.norm(reduced.centers_of_mass() - full.centers_of_mass(), axis=1) / size
    slip_f, slip_r = slip_distance(full), slip_distance(reduced)
    half = full.n_frames // 2
    return Comparison(
        times=full.times.copy(),
        frame_errors=errors,
        com_errors=com_err,
        mean_error=float(errors[1:].mean()) if len(errors) > 1 else 0.0,
        final_com_error=float(com_err[-1]),
        nonrigid_error=nonrigid_error(full, reduced, start=start),
        nonrigid_start_time=float(full.times[start]),
        peak_deformation_full=peak_nonrigid_deformation(full),
        peak_deformation_reduced=peak_nonrigid_deformation(reduced),
        rotation_full=total_rotation(full),
        rotation_reduced=total_rotation(reduced),
        slip_full=slip_f,
        slip_reduced=slip_r,
        slid_full=slip_distance(full, start=half) > SLIDE_THRESHOLD * size,
        slid_reduced=slip_distance(reduced, start=half) > SLIDE_THRESHOLD * size,
        penetration_full=float(penetration_depths(full).max()),
        penetration_reduced=float(penetration_depths(reduced).max()),
        full_step_ms=1e3 * float(np.median(full.step_seconds)) if len(full.step_seconds) else math.nan,
        reduced_step_ms=1e3 * float(np.median(reduced.step_seconds)) if len(reduced.step_seconds) else math.nan,
        full_iterations=float(full.iterations.mean()) if len(full.iterations) else math.nan,
        reduced_iterations=float(reduced.iterations.mean()) if len(reduced.iterations) else math.nan,
        object_size=size,
        error_estimate=float(reduced.error_estimate[-1]) if len(reduced.error_estimate) else math.nan,
    )


def run_comparison(
    basis: Any,
    scene: Scene,
    mesh: Mesh | None = None,
    steps: int = 100,
    record_every: int = 1,
    device: str | None = None,
    progress: bool = False,
    **reduced_options: Any,
) -> tuple[Comparison, Trajectory, Trajectory]:
    """Run the full and the reduced simulation of ``scene`` and compare them.

    Args:
        basis: a trained model or any basis.
        scene: the scene to run (both simulations start from ``scene.initial``).
        mesh: the mesh (default: the model's mesh).
        steps: time steps to run.
        record_every: record every n-th step.
        device: warp device of the full simulation (default: CUDA when visible, else the CPU).
        progress: show progress bars.
        **reduced_options: passed to :class:`~licrom.ReducedSim` (cubature, solver, ...).

    Returns:
        ``(comparison, full_trajectory, reduced_trajectory)``.
    """
    from ..full import FullSim
    from ..reduced.base import ReducedSim

    reduced_sim = ReducedSim(basis, mesh, scene, **reduced_options)
    full = FullSim(reduced_sim.mesh, scene, device=device).run(steps, record_every=record_every, progress=progress)
    reduced = reduced_sim.run(steps, record_every=record_every, progress=progress)
    return compare(full, reduced), full, reduced


def time_steps(sim: Any, steps: int, warmup: int = 0) -> tuple[float, float]:
    """Median wall time and mean Newton iterations of ``steps`` steps of a simulation.

    Args:
        sim: a :class:`~licrom.FullSim` or :class:`~licrom.ReducedSim` (anything with ``run``).
        steps: steps timed.
        warmup: steps run first and not timed (kernel compilation, a drop's fall: time
            both simulations over the same steps of the same scene).

    Returns:
        ``(milliseconds per step, iterations per step)``.
    """
    if steps < 1 or warmup < 0:
        raise ConfigError(f"time_steps needs steps >= 1 and warmup >= 0, got steps={steps}, warmup={warmup}")
    traj = sim.run(warmup + steps, record_every=warmup + steps)
    return 1e3 * float(np.median(traj.step_seconds[warmup:])), float(np.mean(traj.iterations[warmup:]))
