"""Pictures: side-by-side filmstrips of trajectories, error plots, VTU series for ParaView."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any
from xml.sax.saxutils import quoteattr

import numpy as np

from ._io import atomic_path, make_dir
from .compare import Comparison
from .errors import ShapeError
from .trajectory import Trajectory

__all__ = ["filmstrip", "plot_errors", "write_vtu_series"]


def pyplot():
    """matplotlib.pyplot on the headless Agg backend (imported on first use: it is slow to import)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_png(fig: Any, path: str | os.PathLike) -> Path:
    """Write a matplotlib figure as a PNG, atomically, and close it."""
    out = Path(path)
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    pyplot().close(fig)
    return out


def _plane_patch(normal: np.ndarray, offset: float, centre: np.ndarray, half: float) -> np.ndarray:
    """Corners of a square of the plane around the projection of ``centre``."""
    n = np.asarray(normal)
    p0 = centre - (centre @ n + offset) * n
    a = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    return np.array([p0 + half * (sa * a + sb * b) for sa, sb in ((-1, -1), (1, -1), (1, 1), (-1, 1))])


def filmstrip(
    trajectories: Sequence[Trajectory],
    labels: Sequence[str],
    path: str | os.PathLike,
    frames: int = 6,
    title: str | None = None,
) -> Path:
    """One row per trajectory, ``frames`` evenly spaced snapshots per row, saved as PNG.

    The trajectories must share their frame count (e.g. full and reduced of one scene).
    The boundary surface is drawn shaded, the first plane as a grey square.
    """
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    if not trajectories or len(labels) != len(trajectories):
        raise ShapeError(f"filmstrip needs one label per trajectory, got {len(trajectories)} trajectories and {len(labels)} labels")
    if len({t.n_frames for t in trajectories}) != 1:
        raise ShapeError(f"filmstrip needs trajectories of one frame count, got {[t.n_frames for t in trajectories]}")
    if frames < 1:
        raise ShapeError(f"filmstrip needs frames >= 1, got {frames}")
    plt = pyplot()
    first = trajectories[0]
    picks = np.linspace(0, first.n_frames - 1, frames).round().astype(int)
    # The camera follows the object: each panel is centred on the mean of the shown frames'
    # positions and spans 1.6 x the rest shape's largest extent.
    half = 0.8 * float(np.ptp(first.rest_positions, axis=0).max())
    light = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    fig = plt.figure(figsize=(2.6 * frames, 2.6 * len(trajectories) + 0.4))
    for row, (traj, label) in enumerate(zip(trajectories, labels)):
        faces = traj.mesh.boundary_faces
        for col, f in enumerate(picks):
            ax = fig.add_subplot(len(trajectories), frames, row * frames + col + 1, projection="3d")
            x = traj.positions(f)
            centre = np.mean([t.positions(f).mean(axis=0) for t in trajectories], axis=0)
            tri = x[faces]
            nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
            shade = 0.35 + 0.65 * np.clip(nrm @ light, 0, 1)
            colours = np.outer(shade, [0.98, 0.82, 0.35])
            ax.add_collection3d(Poly3DCollection(tri, facecolors=colours, edgecolors="none"))
            if traj.scene.planes:
                p = traj.scene.planes[0]
                ax.add_collection3d(Poly3DCollection([_plane_patch(np.array(p.normal), p.offset, centre, half)],
                                                     facecolors=(0.6, 0.6, 0.6, 0.35), edgecolors="none"))
            ax.set_xlim(centre[0] - half, centre[0] + half)
            ax.set_ylim(centre[1] - half, centre[1] + half)
            ax.set_zlim(centre[2] - half, centre[2] + half)
            ax.view_init(elev=18, azim=-70)
            ax.set_axis_off()
            ax.set_title(f"{label}  t={traj.times[f]:.2f}s\ncentre ({centre[0]:.2f}, {centre[1]:.2f}, {centre[2]:.2f}) m", fontsize=7)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return save_png(fig, path)


def plot_errors(comparisons: dict[str, Comparison], path: str | os.PathLike) -> Path:
    """Relative displacement error and centre-of-mass error over time, one line per comparison."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for name, c in comparisons.items():
        axes[0].plot(c.times, 100 * c.frame_errors, label=name)
        axes[1].plot(c.times, 100 * c.com_errors, label=name)
    axes[0].set_ylabel("relative displacement error (%)")
    axes[1].set_ylabel("centre-of-mass error / size (%)")
    for ax in axes:
        ax.set_xlabel("time (s)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    return save_png(fig, path)


def write_vtu_series(traj: Trajectory, folder: str | os.PathLike, name: str = "frame") -> Path:
    """Write every frame as ``name_XXXX.vtu`` (with displacement and velocity fields) and a
    ParaView collection ``name.pvd`` that plays them in time. Returns the ``.pvd`` path."""
    import meshio

    out = make_dir(folder)
    entries = []
    for f in range(traj.n_frames):
        fname = f"{name}_{f:04d}.vtu"
        mesh = meshio.Mesh(
            traj.positions(f),
            [("tetra", traj.tets)],
            point_data={"displacement": traj.displacements[f], "velocity": traj.velocities[f]},
        )
        with atomic_path(out / fname) as tmp:
            meshio.write(tmp, mesh, file_format="vtu")
        entries.append(f'    <DataSet timestep="{traj.times[f]:.9g}" part="0" file={quoteattr(fname)}/>')
    pvd = out / f"{name}.pvd"
    text = '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n  <Collection>\n'
    text += "\n".join(entries) + "\n  </Collection>\n</VTKFile>\n"
    with atomic_path(pvd) as tmp:
        tmp.write_text(text)
    return pvd
