"""Training data for the learned subspace: trajectories in, affine-free residual frames out.

All trajectories must share one rest mesh. They are split into training and
validation sets by whole trajectory (a held-out scene is never seen in any
frame). In the body frame (the default) each frame's best rigid fit (centre of
mass, polar rotation; :mod:`licrom.rigid`) is removed first and the rest is
expressed in the body frame, so only non-rigid deformation remains. Then, in
either frame, the affine part of the displacement is removed by a mass-weighted
least-squares fit; the networks learn the residual. The
normalisation statistics come from the training frames only and are stored in
the model (never in a cache file).

Also holds :func:`make_synthetic_trajectories`, smooth analytic deformations
plus rigid motions of any mesh, used by the tests and as a stand-in data set.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._repr import concise_repr
from ..analysis.compare import first_contact_frame
from ..errors import ConfigError, FileFormatError
from ..geometry.mesh import Mesh
from ..records.trajectory import Trajectory
from ..rigid import body_frame_displacements, check_frame
from ..scene.scene import InitialState, Plane, Scene
from ..subspace.affine import apply_affine, fit_affine

__all__ = [
    "ROUNDOFF_RESIDUAL",
    "SKIPPED_STEPS",
    "FrameSet",
    "TrainingData",
    "TrajectorySource",
    "load_trajectories",
    "make_synthetic_trajectories",
    "runs_without_impact_frames",
    "split_by_trajectory",
]

TrajectorySource = str | os.PathLike | Trajectory | Iterable[str | os.PathLike | Trajectory]

ROUNDOFF_RESIDUAL = 1e-9
"""A run whose mass-weighted RMS residual (what the networks learn: the body-frame deformation, or the
world-frame displacement, less its affine part when that is removed) is below this fraction of the
object's size holds nothing but round-off: a still object, or one moved rigidly only."""


def load_trajectories(source: TrajectorySource) -> list[tuple[str, Trajectory]]:
    """Named trajectories from a directory (every ``*.npz`` in it, sorted), a file, or a list.

    Raises:
        FileFormatError: a path that does not exist, an empty directory, an unreadable file.
    """
    items: list[Any]
    if isinstance(source, (str, os.PathLike, Trajectory)):
        items = [source]
    else:
        items = list(source)
    out: list[tuple[str, Trajectory]] = []
    for k, item in enumerate(items):
        if isinstance(item, Trajectory):
            out.append((str(item.info.get("name", f"trajectory_{k:03d}")), item))
            continue
        p = Path(item)
        if p.is_dir():
            files = sorted(f for f in p.glob("*.npz") if not f.name.startswith("."))
            if not files:
                raise FileFormatError(f"no trajectory files (*.npz) in directory '{p}'")
            out.extend((f.stem, Trajectory.load(f)) for f in files)
        elif p.is_file():
            out.append((p.stem, Trajectory.load(p)))
        else:
            raise FileFormatError(f"trajectory file or directory not found: '{p}'")
    if not out:
        raise ConfigError("no trajectories given")
    names = [n for n, _ in out]
    if len(set(names)) != len(names):  # keep names unique for reports and splits
        out = [(f"{k:03d}_{n}", t) for k, (n, t) in enumerate(out)]
    return out


def check_same_mesh(named: Sequence[tuple[str, Trajectory]]) -> Mesh:
    """The common rest mesh of the trajectories; raise ConfigError if they differ."""
    name0, t0 = named[0]
    for name, t in named[1:]:
        if t.rest_positions.shape != t0.rest_positions.shape or t.tets.shape != t0.tets.shape:
            raise ConfigError(
                f"all training trajectories must share one rest mesh: '{name}' has {len(t.rest_positions)} vertices "
                f"and {len(t.tets)} tets, '{name0}' has {len(t0.rest_positions)} and {len(t0.tets)}"
            )
        if not np.array_equal(t.tets, t0.tets) or not np.allclose(t.rest_positions, t0.rest_positions, rtol=0, atol=1e-9 * max(1.0, float(np.abs(t0.rest_positions).max()))):
            raise ConfigError(f"all training trajectories must share one rest mesh: '{name}' differs from '{name0}' (vertex positions or tets)")
    return t0.mesh


SKIPPED_STEPS = 1.5
"""Frames further apart than this many of the scene's time steps (median spacing) are a run recorded every n-th step."""


def runs_without_impact_frames(named: Sequence[tuple[str, Trajectory]]) -> list[str]:
    """Names of the runs that touch a plane, keep a frame only every n-th step (n > 1) and hold no impact frames.

    A landing's transient falls between such frames, and a subspace without it lands the body off: on a 2748-tet cheese
    POD(100) of a run's own 10 ms frames ended it 7.7 % of its size away, the same number of modes from its every step
    0.04 % (docs/results.md sections 26 and 67). `licrom generate` keeps every step for
    :data:`licrom.data.dataset.IMPACT_WINDOW` after each impact; ``FullSim.run(..., impact_window=...)`` does on request.
    """
    return [name for name, t in named
            if not len(t.impact_times) and t.n_frames >= 2 and float(np.median(np.diff(t.times))) >= SKIPPED_STEPS * t.scene.dt
            and first_contact_frame(t) is not None]


def split_by_trajectory(
    count: int, val_fraction: float = 0.2, seed: int = 0, val_indices: Sequence[int] | None = None
) -> tuple[list[int], list[int]]:
    """Indices ``(train, validation)`` of whole trajectories.

    With ``val_indices`` those are held out; otherwise ``round(val_fraction * count)``
    trajectories (at least one when ``val_fraction > 0`` and ``count >= 2``) chosen by a
    seeded permutation. Validation may be empty (``val_fraction = 0``).
    """
    if count < 1:
        raise ConfigError("need at least one trajectory")
    if val_indices is not None:
        val = sorted({int(i) for i in val_indices})
        if any(i < 0 or i >= count for i in val):
            raise ConfigError(f"validation indices {val} out of range for {count} trajectories")
    else:
        if not 0.0 <= val_fraction < 1.0:
            raise ConfigError(f"val_fraction must be in [0, 1), got {val_fraction}")
        k = round(val_fraction * count)
        if val_fraction > 0 and count >= 2:
            k = max(k, 1)
        k = min(k, count - 1)
        perm = np.random.default_rng(seed).permutation(count)
        val = sorted(int(i) for i in perm[:k])
    train = [i for i in range(count) if i not in val]
    if not train:
        raise ConfigError("every trajectory is held out for validation; keep at least one for training")
    return train, val


@dataclass
class FrameSet:
    """Frames of some trajectories, affine part removed.

    In the body frame, "full" means the body-frame displacement ``R^T (x - c) - Xbar``
    (the non-rigid deformation), not the world-frame displacement.

    Attributes:
        residuals: (F, n, 3) float32 residual displacements in m.
        affine: (F, 12) float64 affine coefficients of the mass-weighted fit (zeros
            when the affine modes are off).
        trajectory: (F,) index (into ``names``) of the trajectory of each frame.
        frame: (F,) frame number within its trajectory; -1 for an impact frame
            (:attr:`licrom.Trajectory.impact_displacements`).
        norm2_full: (F,) mass-weighted squared norm ``sum_v m_v |u_v|^2`` of each full displacement.
        norm2_residual: (F,) the same for the residual.
        names: trajectory names.
    """

    residuals: np.ndarray
    affine: np.ndarray
    trajectory: np.ndarray
    frame: np.ndarray
    norm2_full: np.ndarray
    norm2_residual: np.ndarray
    names: list[str]

    __repr__ = concise_repr

    def __len__(self) -> int:
        return len(self.residuals)

    def full_displacements(self, rest: np.ndarray, index: int | slice | np.ndarray) -> np.ndarray:
        """Full displacements (affine + residual) of the selected frames, float64."""
        return apply_affine(rest, self.affine[index]) + self.residuals[index].astype(np.float64)


def _frames(named: Sequence[tuple[str, Trajectory]], rest: np.ndarray, masses: np.ndarray, affine: bool, stride: int, frame: str) -> FrameSet:
    res_list, aff_list, traj_list, frame_list, nf_list, nr_list = [], [], [], [], [], []
    n = len(rest)
    for k, (_, t) in enumerate(named):
        # the impact frames too: the fast transient of each impact, which the regular frames alias
        impacts = t.impact_displacements[::stride]
        idx = np.concatenate([np.arange(0, t.n_frames, stride), np.full(len(impacts), -1)])
        u = np.concatenate([t.displacements[idx[idx >= 0]], impacts])
        if frame == "body":
            u = body_frame_displacements(rest + u, rest, masses)
        if affine:
            a = fit_affine(rest, u, masses)
            res = u - apply_affine(rest, a)
        else:
            a = np.zeros((len(idx), 12))
            res = u
        res_list.append(res.astype(np.float32))
        aff_list.append(a)
        traj_list.append(np.full(len(idx), k))
        frame_list.append(idx)
        nf_list.append(np.einsum("fni,n->f", u * u, masses))
        nr_list.append(np.einsum("fni,n->f", res * res, masses))
    cat = lambda xs, shape: np.concatenate(xs) if xs else np.zeros(shape)  # noqa: E731
    return FrameSet(
        residuals=cat(res_list, (0, n, 3)).astype(np.float32),
        affine=cat(aff_list, (0, 12)),
        trajectory=cat(traj_list, (0,)).astype(np.int64),
        frame=cat(frame_list, (0,)).astype(np.int64),
        norm2_full=cat(nf_list, (0,)),
        norm2_residual=cat(nr_list, (0,)),
        names=[name for name, _ in named],
    )


class TrainingData:
    """Trajectories of one mesh, split by trajectory, affine part removed, with statistics.

    Args:
        source: trajectories (see :func:`load_trajectories`).
        val_fraction: fraction of the trajectories held out for validation.
        seed: seed of the split.
        val_indices: explicit held-out trajectory indices (into the sorted list); overrides
            ``val_fraction``.
        affine: remove the affine part (the model stacks affine modes in front).
        frame_stride: keep every ``frame_stride``-th frame of each trajectory.
        frame: ``"body"`` (remove each frame's rigid part first, see the module
            docstring) or ``"world"``.

    Attributes:
        mesh: the common rest mesh.
        masses: (n,) lumped vertex masses in kg (density of the first scene).
        names, scenes: of all trajectories, in order.
        train_indices, val_indices: the split.
        frame: ``"body"`` or ``"world"``.
        train, val: :class:`FrameSet` of each side.
        held_out: ``(name, Trajectory)`` of each validation run, whole.
        training_runs: ``(name, Trajectory)`` of each training run, whole.
        x_center: (3,) mass-weighted centre of the rest shape, m.
        x_scale: largest distance of a vertex from ``x_center`` along an axis, m.
        u_scale: mass-weighted RMS of the training residuals, m (floored at 1e-6 of the
            object's size so a rigid-only data set still normalises).
    """

    def __init__(
        self,
        source: TrajectorySource,
        *,
        val_fraction: float = 0.2,
        seed: int = 0,
        val_indices: Sequence[int] | None = None,
        affine: bool = True,
        frame_stride: int = 1,
        frame: str = "body",
    ) -> None:
        if not isinstance(frame_stride, (int, np.integer)) or frame_stride < 1:
            raise ConfigError(f"frame_stride must be an integer >= 1, got {frame_stride!r}")
        self.frame = check_frame(frame)
        named = load_trajectories(source)
        self.mesh = check_same_mesh(named)
        self.names = [n for n, _ in named]
        self.scenes = [t.scene for _, t in named]
        self.infos = [t.info for _, t in named]
        self.masses = self.mesh.vertex_masses(self.scenes[0].material.density)
        self.affine = bool(affine)
        self.train_indices, self.val_indices = split_by_trajectory(len(named), val_fraction, seed, val_indices)
        rest = np.asarray(self.mesh.vertices)
        self.train = _frames([named[i] for i in self.train_indices], rest, self.masses, self.affine, int(frame_stride), self.frame)
        self.val = _frames([named[i] for i in self.val_indices], rest, self.masses, self.affine, int(frame_stride), self.frame)
        # The runs themselves: the held-out ones for the end-of-training check of the reduced model against them,
        # the training ones for the dynamics check of r (licrom.learn.training.dynamics).
        self.held_out = [named[i] for i in self.val_indices]
        self.training_runs = [named[i] for i in self.train_indices]
        self.without_impact_frames = runs_without_impact_frames(named)
        if len(self.train) == 0:
            raise ConfigError("the training trajectories hold no frames")
        w = self.masses / self.masses.sum()
        self.x_center = w @ rest
        self.x_scale = float(np.abs(rest - self.x_center).max())
        mean_sq = float(self.train.norm2_residual.sum() / (len(self.train) * self.masses.sum()))
        self.u_scale = max(float(np.sqrt(mean_sq / 3.0)), 1e-6 * self.mesh.size)

    @property
    def rest(self) -> np.ndarray:
        return np.asarray(self.mesh.vertices)

    def residual_rms(self) -> dict[str, float]:
        """Mass-weighted RMS residual (m) of each training run: ``sqrt(sum_f sum_v m_v |r_v|^2 / (F M))``."""
        frames, total = self.train, float(self.masses.sum())
        return {frames.names[k]: float(np.sqrt(frames.norm2_residual[frames.trajectory == k].mean() / total))
                for k in np.unique(frames.trajectory)}

    def check_deformation(self) -> None:
        """Refuse training data whose every training run holds round-off only (see :data:`ROUNDOFF_RESIDUAL`).

        Raises:
            ConfigError: naming the runs, their residual and the threshold.
        """
        rms = self.residual_rms()
        limit = ROUNDOFF_RESIDUAL * self.mesh.size
        if rms and max(rms.values()) < limit:
            what = "deformation in the body frame" if self.frame == "body" else "displacement" + (" beyond its affine part" if self.affine else "")
            shown = ", ".join(f"{name} ({value:.3g} m)" for name, value in list(rms.items())[:8]) + (", ..." if len(rms) > 8 else "")
            raise ConfigError(
                f"no training run holds any {what}: the mass-weighted RMS residual of every run is below "
                f"{ROUNDOFF_RESIDUAL:g} of the object's size ({limit:.3g} m), round-off only: {shown}. A model trained on them "
                "would be modes of round-off; train on runs that deform (a drop or a push onto a plane, a softer material)")

    def summary(self) -> dict[str, Any]:
        """JSON-ready description (names, split, frame counts, statistics)."""
        return {
            "trajectories": self.names,
            "train": [self.names[i] for i in self.train_indices],
            "validation": [self.names[i] for i in self.val_indices],
            "train_frames": len(self.train),
            "validation_frames": len(self.val),
            "train_impact_frames": int(np.sum(self.train.frame < 0)),
            "validation_impact_frames": int(np.sum(self.val.frame < 0)),
            "runs_without_impact_frames": self.without_impact_frames,
            "n_vertices": self.mesh.n_vertices,
            "n_tets": self.mesh.n_tets,
            "x_center": self.x_center.tolist(),
            "x_scale": self.x_scale,
            "u_scale": self.u_scale,
            "affine_removed": self.affine,
            "frame": self.frame,
        }


# ----------------------------------------------------------------------------------------
# synthetic data
# ----------------------------------------------------------------------------------------
def _synthetic_fields(xi: np.ndarray) -> np.ndarray:
    """(K, n, 3) smooth deformation fields of normalised points xi (n, 3) in [-1, 1]^3."""
    x, y, z = xi[:, 0], xi[:, 1], xi[:, 2]
    zero = np.zeros_like(x)
    fields = [
        (zero, zero, x * x),  # bending about y
        (zero, zero, y * y),  # bending about x
        (zero, -z * x, y * x),  # twist about x
        (x * z * z, y * z * z, zero),  # bulge under a vertical squash
        (zero, zero, x * x * y),  # saddle sag
        (x * y, zero, zero),  # shear in plane
        (np.sin(np.pi * y) * 0.5, zero, np.sin(np.pi * x) * 0.5),  # wavy
        (zero, x * x * z, zero),
    ]
    return np.stack([np.stack(f, axis=1) for f in fields])


def make_synthetic_trajectories(
    mesh: Mesh,
    count: int = 6,
    frames: int = 40,
    *,
    seed: int = 0,
    modes: int = 4,
    amplitude: float = 0.05,
    rotation: bool = True,
    dt: float = 0.01,
) -> list[Trajectory]:
    """Trajectories of smooth analytic deformations plus rigid motions (no physics).

    The displacement of a trajectory is
    ``u(X, t) = R(t) (X - c + s sum_k a_k(t) phi_k((X - c)/s)) + c + d(t) - X``
    with ``modes`` analytic fields ``phi_k``, random smooth amplitudes ``a_k(t)`` of
    size ``amplitude`` (a fraction of the object's half-size ``s``), a rigid rotation
    ``R(t)`` (identity when ``rotation=False``, so the residual lies exactly in a
    ``modes``-dimensional space) and a falling translation ``d(t)``. Each trajectory
    gets a scene with another friction coefficient, like a real training set.
    """
    if not 1 <= modes <= 8:
        raise ConfigError(f"modes must be in 1..8, got {modes}")
    rng = np.random.default_rng(seed)
    rest = np.asarray(mesh.vertices)
    masses = mesh.vertex_masses(1000.0)
    c = (masses / masses.sum()) @ rest
    s = float(np.abs(rest - c).max())
    phi = _synthetic_fields((rest - c) / s)[:modes]  # (K, n, 3)
    t = np.arange(frames) * dt
    out = []
    for k in range(count):
        omega = rng.uniform(2.0, 12.0, size=modes)
        phase = rng.uniform(0, 2 * np.pi, size=modes)
        amp = amplitude * rng.uniform(0.3, 1.0, size=modes)
        a = amp[None] * np.sin(omega[None] * t[:, None] + phase[None]) * (1 - np.exp(-t[:, None] / (5 * dt)))
        deform = s * np.einsum("fk,kni->fni", a, phi)
        if rotation:
            axis = rng.normal(size=3)
            axis /= np.linalg.norm(axis)
            ang = rng.uniform(-1.0, 1.0) * t + rng.uniform(-0.5, 0.5)
            kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
            rots = np.stack([np.eye(3) + np.sin(g) * kx + (1 - np.cos(g)) * kx @ kx for g in ang])
        else:
            rots = np.broadcast_to(np.eye(3), (frames, 3, 3))
        drop = np.stack([rng.uniform(-0.1, 0.1) * t, rng.uniform(-0.1, 0.1) * t, -0.5 * 9.81 * np.minimum(t, 0.2) ** 2], axis=1)
        pos = np.einsum("fij,fnj->fni", rots, (rest - c)[None] + deform) + c + drop[:, None, :]
        disp = pos - rest[None]
        vel = np.gradient(disp, dt, axis=0) if frames > 1 else np.zeros_like(disp)
        # The ground touches the rest shape from below, so the scene starts out of it.
        ground = Plane(offset=-float(rest[:, 2].min()), friction=float(0.1 + 0.1 * k))
        scene = Scene(planes=(ground,), dt=dt, initial=InitialState())
        out.append(
            Trajectory(
                rest, mesh.tets, disp, vel, t, scene,
                info={"name": f"synthetic_{k:03d}", "source": "synthetic", "seed": seed, "modes": modes, "rotation": rotation},
            )
        )
    return out
