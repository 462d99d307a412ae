"""Full vs reduced: run both on one scene and measure how far apart they are.

Errors are mass-weighted, so they do not depend on how the mesh is refined:
``e(t) = |u_r(t) - u_f(t)|_M / |u_f(t)|_M`` per frame, the centre-of-mass distance
as a fraction of the object's size, whether the object slid or stuck in each,
the deepest penetration, and the per-step wall time of both.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from .errors import ConfigError, ShapeError
from .scene import Scene
from .trajectory import Trajectory

__all__ = ["Comparison", "compare", "run_comparison", "time_steps", "slip_distance", "penetration_depths"]

# An object "slides" when its contact points slip further than this fraction of its size
# over the second half of the run (after a drop's landing transient has passed).
SLIDE_THRESHOLD = 0.01


def penetration_depths(traj: Trajectory, scene: Scene | None = None) -> np.ndarray:
    """(f,) deepest penetration of any vertex below any plane per frame, m (0 if none)."""
    scene = scene or traj.scene
    if not scene.planes:
        return np.zeros(traj.n_frames)
    planes = scene.plane_array()
    x = traj.rest_positions[None] + traj.displacements  # (f, n, 3)
    gaps = np.einsum("fnk,pk->fnp", x, planes[:, :3]) + planes[:, 3]
    return np.maximum(-gaps.min(axis=(1, 2)), 0.0)


def slip_distance(traj: Trajectory, contact_tolerance: float | None = None, start: int = 1) -> float:
    """Distance the contact points slid along the planes from frame ``start`` on, m.

    Integrates, over the recorded frames, the mean tangential speed of the vertices in
    contact (gap below ``contact_tolerance``, default 0.5% of the object's size).
    Rolling without slipping gives ~0; sticking gives ~0; sliding gives the slide length.
    """
    scene = traj.scene
    if not scene.planes or traj.n_frames < 2:
        return 0.0
    size = float(np.linalg.norm(np.ptp(traj.rest_positions, axis=0)))
    tol = 0.005 * size if contact_tolerance is None else contact_tolerance
    planes = scene.plane_array()
    total = 0.0
    for f in range(max(start, 1), traj.n_frames):
        x = traj.positions(f)
        v = traj.velocities[f]
        speeds = []
        for p in planes:
            n = p[:3]
            touching = x @ n + p[3] < tol
            if touching.any():
                vt = v[touching] - np.outer(v[touching] @ n, n)
                speeds.append(np.linalg.norm(vt, axis=1).mean())
        if speeds:
            total += max(speeds) * (traj.times[f] - traj.times[f - 1])
    return float(total)


@dataclass(frozen=True)
class Comparison:
    """How a reduced trajectory differs from the full one on the same mesh and scene.

    Attributes:
        times: (f,) frame times, s.
        frame_errors: (f,) relative mass-weighted displacement error per frame.
        com_errors: (f,) centre-of-mass distance per frame as a fraction of the object size.
        mean_error: mean of ``frame_errors`` over frames after the first.
        final_com_error: ``com_errors`` at the last frame.
        slip_full, slip_reduced: slide distance of the contact points over the run, m.
        slid_full, slid_reduced: whether each slides: slip over the second half of the
            run above 1% of the object size (so a landing transient does not count).
        penetration_full, penetration_reduced: deepest penetration, m.
        full_step_ms, reduced_step_ms: median wall time per step, ms.
        full_iterations, reduced_iterations: mean Newton iterations per step.
        object_size: bounding-box diagonal of the rest shape, m.
    """

    times: np.ndarray
    frame_errors: np.ndarray
    com_errors: np.ndarray
    mean_error: float
    final_com_error: float
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


def compare(full: Trajectory, reduced: Trajectory) -> Comparison:
    """Compare two trajectories of the same mesh, scene and frame times."""
    if full.rest_positions.shape != reduced.rest_positions.shape or not np.allclose(full.rest_positions, reduced.rest_positions):
        raise ShapeError("compare needs both trajectories on the same mesh (rest positions differ)")
    if full.n_frames != reduced.n_frames or not np.allclose(full.times, reduced.times):
        raise ShapeError(f"compare needs the same frame times (got {full.n_frames} and {reduced.n_frames} frames)")
    mesh = full.mesh
    masses = mesh.vertex_masses(full.scene.material.density)
    size = mesh.size
    diff = reduced.displacements - full.displacements
    num = np.sqrt(np.einsum("fnk,n->f", diff**2, masses))
    den = np.sqrt(np.einsum("fnk,n->f", full.displacements**2, masses))
    # Frames where the object has hardly moved would divide by ~0: floor at 0.1% of the size.
    errors = num / np.maximum(den, 1e-3 * size * math.sqrt(masses.sum()))
    com_err = np.linalg.norm(reduced.centers_of_mass() - full.centers_of_mass(), axis=1) / size
    slip_f, slip_r = slip_distance(full), slip_distance(reduced)
    half = full.n_frames // 2
    return Comparison(
        times=full.times.copy(),
        frame_errors=errors,
        com_errors=com_err,
        mean_error=float(errors[1:].mean()) if len(errors) > 1 else 0.0,
        final_com_error=float(com_err[-1]),
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
    )


def run_comparison(
    basis: Any,
    scene: Scene,
    mesh=None,
    steps: int = 100,
    record_every: int = 1,
    device: str = "cpu",
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
        device: warp device of the full simulation.
        progress: show progress bars.
        **reduced_options: passed to :class:`~licrom.ReducedSim` (cubature, solver, ...).

    Returns:
        ``(comparison, full_trajectory, reduced_trajectory)``.
    """
    from .full_sim import FullSim
    from .reduced_sim import ReducedSim

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
