"""Pictures of runs: filmstrips and animations from a fixed world camera, and the error plot.

The renderer is PyVista (VTK), off-screen: on a Linux machine without a display VTK's wheels
render through EGL (Mesa's or a GPU driver's), so ``pip install 'licrom[render]'`` is all it
takes. One camera frames the whole run of every trajectory shown, the planes are drawn as
grids, the start pose as a grey ghost, and the surface is coloured by its non-rigid deformation
(each frame's best rigid fit removed, :mod:`licrom.rigid`) or by its distance from a reference
run. Full and reduced runs are shown side by side with the same camera and colour scale.

Without PyVista, :func:`filmstrip` can draw with matplotlib (``renderer="matplotlib"``: the same
fixed camera and planes, flat shading, no colours); :func:`pick_renderer` chooses and says why.
"""

from __future__ import annotations

import functools
import math
import os
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ._io import atomic_path
from .compare import Comparison
from .errors import ConfigError, MissingDependencyError, ShapeError, require_optional
from .export import downhill_direction, plane_patch
from .rigid import nonrigid_displacements
from .trajectory import Trajectory

__all__ = [
    "COLOR_BY",
    "RENDERERS",
    "RenderStyle",
    "animation",
    "filmstrip",
    "pick_renderer",
    "pictures",
    "plot_errors",
    "pyvista_unavailable",
]

COLOR_BY = ("deformation", "error")
"""What colours the surface: its non-rigid deformation, or its distance from the first run shown."""

RENDERERS = ("pyvista", "matplotlib")
"""Renderers of :func:`filmstrip`; animations need PyVista."""

HEADER_PX = 32
"""Height of the title strip above the panels (when there is a title), pixels."""
COLORBAR_PX = 58
"""Height of the colour-bar strip below the panels (PyVista pictures), pixels."""
PANEL_GAP = 2
"""Width of the grey lines between panels, pixels."""


@dataclass(frozen=True)
class RenderStyle:
    """How the PyVista renderer draws runs.

    Attributes:
        color_by: ``"deformation"``: length of each vertex's non-rigid deformation (the frame's
            best rigid fit removed), mm; ``"error"``: distance of each vertex from the same vertex
            of the first run shown (the reference: give runs of one mesh), mm.
        panel_size: (width, height) of one view, pixels.
        elevation: height of the camera above the horizon, degrees.
        azimuth: turn of the camera from the side view (perpendicular to the motion) toward
            the start of the motion, degrees.
        colormap: matplotlib colormap name of the surface colours.
        ghost: draw the start pose as a translucent grey ghost in every view.
        edges: draw the surface triangles' edges.
    """

    color_by: str = "deformation"
    panel_size: tuple[int, int] = (480, 300)
    elevation: float = 22.0
    azimuth: float = 20.0
    colormap: str = "YlOrRd"
    ghost: bool = True
    edges: bool = False

    def __post_init__(self) -> None:
        if self.color_by not in COLOR_BY:
            raise ConfigError(f"RenderStyle.color_by must be one of {', '.join(map(repr, COLOR_BY))}, got {self.color_by!r}")
        size = tuple(self.panel_size)
        if len(size) != 2 or not all(isinstance(v, (int, np.integer)) and 64 <= v <= 4096 for v in size):
            raise ConfigError(f"RenderStyle.panel_size must be two integers in [64, 4096] (pixels), got {self.panel_size!r}")
        object.__setattr__(self, "panel_size", (int(size[0]), int(size[1])))
        if not (-89.0 <= float(self.elevation) <= 89.0) or not math.isfinite(float(self.azimuth)):
            raise ConfigError(f"RenderStyle.elevation must be in [-89, 89] degrees and azimuth finite, got {self.elevation!r}, {self.azimuth!r}")
        from matplotlib import colormaps

        if self.colormap not in colormaps:
            raise ConfigError(f"RenderStyle.colormap must be a matplotlib colormap name (e.g. 'viridis', 'plasma'), got {self.colormap!r}")


# --- matplotlib helpers ------------------------------------------------------------------


def pyplot():
    """matplotlib.pyplot on the headless Agg backend (imported on first use: it is slow to import)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_png(fig: Any, path: str | os.PathLike, dpi: float = 110) -> Path:
    """Write a matplotlib figure as a PNG, atomically, and close it."""
    out = Path(path)
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    pyplot().close(fig)
    return out


def _figure_pixels(fig: Any) -> np.ndarray:
    """(h, w, 3) uint8 pixels of a drawn matplotlib figure; closes it."""
    fig.canvas.draw()
    rgb = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    pyplot().close(fig)
    return rgb


def _text_strip(width: int, height: int, text: str) -> np.ndarray:
    plt = pyplot()
    fig = plt.figure(figsize=(width / 100, height / 100), dpi=100)
    fig.text(0.5, 0.5, text, ha="center", va="center", fontsize=11)
    return _figure_pixels(fig)


def _colorbar_strip(width: int, colormap: str, clim: tuple[float, float], label: str) -> np.ndarray:
    import matplotlib as mpl

    plt = pyplot()
    fig = plt.figure(figsize=(width / 100, COLORBAR_PX / 100), dpi=100)
    bar_width = min(0.6, 360 / width)
    ax = fig.add_axes((0.5 - bar_width / 2, 0.62, bar_width, 0.22))
    fig.colorbar(mpl.cm.ScalarMappable(norm=mpl.colors.Normalize(*clim), cmap=colormap), cax=ax, orientation="horizontal")
    ax.tick_params(labelsize=8, length=2, pad=1)
    ax.set_title(label, fontsize=8, pad=2, y=-2.9)
    return _figure_pixels(fig)


# --- PyVista ---------------------------------------------------------------------------------


def _headless_vtk() -> None:
    # Without a display VTK's Linux wheels try X first (and log a warning) before EGL; ask for EGL.
    if sys.platform.startswith("linux") and not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


_PROBE = ("import pyvista as pv\np = pv.Plotter(off_screen=True, window_size=(16, 16))\np.add_mesh(pv.Sphere())\n"
          "print('licrom-probe', p.screenshot(None, return_img=True).shape)\np.close()\n")


@functools.cache
def pyvista_unavailable() -> str | None:
    """None when PyVista can render off-screen here; otherwise one line saying why not.

    The check renders a sphere in a subprocess once per process (VTK ends a process that
    finds no OpenGL at all instead of raising an error).
    """
    import importlib.util

    if importlib.util.find_spec("pyvista") is None:
        return "PyVista is not installed (pip install 'licrom[render]')"
    _headless_vtk()
    try:
        done = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=180, env=os.environ.copy())
    except subprocess.TimeoutExpired:
        return "PyVista did not render a test picture within 180 s"
    if done.returncode != 0 or "licrom-probe" not in done.stdout:
        last = (done.stderr.strip().splitlines() or ["no message"])[-1][:200]
        return f"PyVista is installed but cannot render off-screen here (it needs an X display, EGL or OSMesa): {last}"
    return None


def pick_renderer() -> tuple[str, str | None]:
    """``("pyvista", None)`` when PyVista renders here, else ``("matplotlib", why)``."""
    why = pyvista_unavailable()
    return ("pyvista", None) if why is None else ("matplotlib", why)


def _pyvista():
    why = pyvista_unavailable()
    if why is not None:
        raise MissingDependencyError(f"pictures with PyVista: {why}")
    pv = require_optional("pyvista", "render", "pictures with PyVista")
    pv.OFF_SCREEN = True
    return pv


def _check_runs(trajectories: Sequence[Trajectory], labels: Sequence[str], what: str) -> list[Trajectory]:
    runs = list(trajectories)
    if not runs or len(labels) != len(runs):
        raise ShapeError(f"{what} needs one label per trajectory, got {len(runs)} trajectories and {len(labels)} labels")
    if len({t.n_frames for t in runs}) != 1:
        raise ShapeError(f"{what} needs trajectories of one frame count, got {[t.n_frames for t in runs]}")
    return runs


class _Views:
    """The runs, their colours, one world camera and one off-screen plotter per run."""

    def __init__(self, runs: list[Trajectory], labels: Sequence[str], style: RenderStyle, title: str | None) -> None:
        self.runs, self.labels, self.style, self.title = runs, list(labels), style, title
        self.positions = [t.rest_positions[None] + t.displacements for t in runs]
        if style.color_by == "error":
            ref = runs[0]
            for t in runs[1:]:
                if t.rest_positions.shape != ref.rest_positions.shape or not np.allclose(t.rest_positions, ref.rest_positions):
                    raise ShapeError("RenderStyle.color_by='error' needs every run on the first run's mesh (rest positions differ)")
            self.scalars = [1e3 * np.linalg.norm(x - self.positions[0], axis=-1) for x in self.positions]
            self.scalar_label = f"distance from {self.labels[0]} (mm)"
        else:
            self.scalars = [
                1e3 * np.linalg.norm(nonrigid_displacements(x, t.rest_positions, t.mesh.vertex_masses(t.scene.material.density)), axis=-1)
                for x, t in zip(self.positions, runs)
            ]
            self.scalar_label = "non-rigid deformation (mm)"
        top = max(float(s.max()) for s in self.scalars)
        self.clim = (0.0, max(top, 0.01))  # a rigid run: a scale of 0 to 10 micrometres, not of 0 to 0
        every = np.concatenate([x.reshape(-1, 3) for x in self.positions])
        size = max(t.mesh.size for t in runs)
        scene = runs[0].scene
        self.patches = [plane_patch(p, every, 0.6 * float(np.ptp(every, axis=0).max()) + 0.5 * size, scene.gravity)
                        for p in scene.planes]
        # The camera frames the run and the ground under it: the feet of the positions on every
        # plane that the run comes within one object size of (a far wall does not widen the view).
        framed = [every]
        for p in scene.planes:
            n = np.asarray(p.normal)
            gaps = every @ n + p.offset
            if gaps.min() < size:
                framed.append(every - np.outer(gaps, n))
        self.camera = self._camera(np.concatenate(framed), size)
        spacing = np.diff(runs[0].times)
        self.decimals = max(2, math.ceil(-math.log10(spacing[spacing > 0].min()) - 1e-6)) if np.any(spacing > 0) else 2
        self.plotters: list[Any] = []
        self._strips: dict[int, tuple[list[np.ndarray], np.ndarray]] = {}

    def _camera(self, every: np.ndarray, size: float) -> dict[str, Any]:
        """A fixed camera (parallel projection) that frames every position of every run."""
        scene = self.runs[0].scene
        g = np.asarray(scene.gravity)
        up = -g / np.linalg.norm(g) if np.linalg.norm(g) > 0 else np.array([0.0, 0.0, 1.0])
        com = self.runs[0].centers_of_mass()
        motion = com[-1] - com[0]
        motion -= (motion @ up) * up
        if np.linalg.norm(motion) < 0.05 * size:
            motion = downhill_direction(scene.planes[0], g) if scene.planes else np.zeros(3)
            motion -= (motion @ up) * up
        if np.linalg.norm(motion) < 1e-9:
            motion = np.cross(up, [0.0, 1.0, 0.0] if abs(up[1]) < 0.9 else [1.0, 0.0, 0.0])
        m = motion / np.linalg.norm(motion)
        side = np.cross(up, m)
        el, az = math.radians(self.style.elevation), math.radians(self.style.azimuth)
        back = -side * math.cos(el) * math.cos(az) - m * math.cos(el) * math.sin(az) + up * math.sin(el)
        forward = -back
        right = np.cross(forward, up)
        right /= np.linalg.norm(right)
        cam_up = np.cross(right, forward)
        lo, hi = every.min(axis=0), every.max(axis=0)
        corners = np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
        r, u = corners @ right, corners @ cam_up
        centre = 0.5 * (lo + hi)
        focal = 0.5 * (r.min() + r.max()) * right + 0.5 * (u.min() + u.max()) * cam_up + (centre @ forward) * forward
        width, height = self.style.panel_size
        half = 0.5 * max(float(np.ptp(u)), float(np.ptp(r)) * height / width, 0.5 * size)
        return {"focal": focal, "position": focal + back * 20.0 * (float(np.ptp(every, axis=0).max()) + size),
                "up": cam_up, "scale": 1.22 * half}

    def _plotter(self, i: int):
        pv = _pyvista()
        style = self.style
        pl = pv.Plotter(off_screen=True, window_size=list(style.panel_size))
        pl.set_background("white")
        for patch in self.patches:
            # Square grid cells of about half the object's size: they show the slide and the scale.
            cell = 0.5 * self.runs[i].mesh.size
            ns, nt = (max(2, min(60, round(float(np.linalg.norm(patch[k] - patch[0])) / cell))) for k in (1, 3))
            s, t = np.meshgrid(np.linspace(0, 1, ns + 1), np.linspace(0, 1, nt + 1), indexing="ij")
            pts = patch[0] + s[..., None] * (patch[1] - patch[0]) + t[..., None] * (patch[3] - patch[0])
            grid = pv.StructuredGrid(pts[..., 0], pts[..., 1], pts[..., 2])
            pl.add_mesh(grid, color=(0.86, 0.86, 0.84), show_edges=True, edge_color=(0.6, 0.6, 0.58), line_width=1)
        faces = np.asarray(self.runs[i].mesh.boundary_faces)
        vtk_faces = np.hstack([np.full((len(faces), 1), 3), faces]).ravel()
        if style.ghost:
            pl.add_mesh(pv.PolyData(self.positions[i][0], vtk_faces), color=(0.55, 0.55, 0.55), opacity=0.25)
        surface = pv.PolyData(self.positions[i][0].copy(), vtk_faces)
        surface.point_data["value"] = self.scalars[i][0].copy()
        pl.add_mesh(surface, scalars="value", cmap=style.colormap, clim=self.clim, show_scalar_bar=False,
                    show_edges=style.edges, edge_color=(0.2, 0.2, 0.2), line_width=0.5)
        text = pl.add_text("", position=(8, style.panel_size[1] - 22), font_size=10, color="black")
        cam = pl.camera
        cam.focal_point, cam.position, cam.up = self.camera["focal"], self.camera["position"], self.camera["up"]
        cam.parallel_projection = True
        cam.parallel_scale = self.camera["scale"]
        pl.reset_camera_clipping_range()
        return pl, surface, text

    def panel(self, i: int, frame: int) -> np.ndarray:
        """(h, w, 3) picture of run ``i`` at ``frame``."""
        if not self.plotters:
            self.plotters = [self._plotter(k) for k in range(len(self.runs))]
        pl, surface, text = self.plotters[i]
        surface.points = self.positions[i][frame]
        surface.point_data["value"] = self.scalars[i][frame]
        text.SetInput(f"{self.labels[i]}   t = {self.runs[i].times[frame]:.{self.decimals}f} s")
        pl.reset_camera_clipping_range()
        pl.render()
        return np.asarray(pl.screenshot(None, return_img=True))[..., :3]

    def close(self) -> None:
        for pl, _, _ in self.plotters:
            pl.close()
        self.plotters = []

    def compose(self, grid: list[list[np.ndarray]]) -> np.ndarray:
        """Panels in rows and columns, grey lines between them, the title above, the colour bar below."""
        line = np.full((1, 1, 3), 150, np.uint8)
        rows = []
        for row in grid:
            cells = []
            for j, p in enumerate(row):
                if j:
                    cells.append(np.broadcast_to(line, (p.shape[0], PANEL_GAP, 3)))
                cells.append(p)
            rows.append(np.hstack(cells))
        width = rows[0].shape[1]
        if width not in self._strips:  # drawn once per layout: an animation has many frames
            header = [_text_strip(width, HEADER_PX, self.title)] if self.title else []
            self._strips[width] = (header, _colorbar_strip(width, self.style.colormap, self.clim, self.scalar_label))
        header, colorbar = self._strips[width]
        stack = list(header)
        for k, r in enumerate(rows):
            if k:
                stack.append(np.broadcast_to(line, (PANEL_GAP, width, 3)))
            stack.append(r)
        stack.append(colorbar)
        return np.ascontiguousarray(np.vstack(stack))


def filmstrip(
    trajectories: Sequence[Trajectory],
    labels: Sequence[str],
    path: str | os.PathLike,
    frames: int = 6,
    title: str | None = None,
    style: RenderStyle | None = None,
    renderer: str = "pyvista",
) -> Path:
    """One row per trajectory, ``frames`` evenly spaced snapshots per row, saved as PNG.

    Every view uses one fixed world camera that frames the whole run of every trajectory, so a
    slide shows as the object crossing the views and a stick as the object staying put. The
    trajectories must share their frame count (e.g. full and reduced runs of one scene).

    Args:
        trajectories: the runs, one row each.
        labels: a name per run, shown in its views.
        path: the PNG to write.
        frames: snapshots per row, >= 1.
        title: text above the views.
        style: colours, camera angles and view size of the PyVista renderer.
        renderer: ``"pyvista"`` (coloured, needs ``licrom[render]``) or ``"matplotlib"`` (grey,
            flat shading; for installs without PyVista, see :func:`pick_renderer`).

    Raises:
        ShapeError: labels or frame counts that do not match.
        ConfigError: ``frames`` < 1 or an unknown renderer.
        MissingDependencyError: ``renderer="pyvista"`` where PyVista cannot render.
    """
    runs = _check_runs(trajectories, labels, "filmstrip")
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 1:
        raise ConfigError(f"filmstrip frames must be an integer >= 1, got {frames!r}")
    if renderer not in RENDERERS:
        raise ConfigError(f"filmstrip renderer must be one of {', '.join(map(repr, RENDERERS))}, got {renderer!r}")
    picks = np.linspace(0, runs[0].n_frames - 1, frames).round().astype(int)
    if renderer == "matplotlib":
        return _filmstrip_matplotlib(runs, labels, path, picks, title)
    views = _Views(runs, labels, style or RenderStyle(), title)
    try:
        image = views.compose([[views.panel(i, f) for f in picks] for i in range(len(runs))])
    finally:
        views.close()
    return _save_image(image, path)


def animation(
    trajectories: Sequence[Trajectory],
    labels: Sequence[str],
    path: str | os.PathLike,
    fps: float = 20.0,
    max_frames: int = 60,
    title: str | None = None,
    style: RenderStyle | None = None,
) -> Path:
    """An animated GIF of the runs side by side, from the fixed world camera of :func:`filmstrip`.

    Args:
        trajectories: the runs, one view each, left to right.
        labels: a name per run, shown in its view.
        path: the ``.gif`` to write.
        fps: frames per second of the GIF (the recorded time is shown in each view).
        max_frames: at most this many frames, evenly spaced over the run (all when fewer).
        title: text above the views.
        style: colours, camera angles and view size.

    Raises:
        ShapeError: labels or frame counts that do not match.
        ConfigError: a path not ending in ``.gif``, ``fps`` <= 0 or ``max_frames`` < 1.
        MissingDependencyError: PyVista or imageio missing, or PyVista unable to render here.
    """
    runs = _check_runs(trajectories, labels, "animation")
    out = Path(path)
    if out.suffix.lower() != ".gif":
        raise ConfigError(f"animation path must end in .gif, got '{out.name}'")
    if not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
        raise ConfigError(f"animation fps must be > 0, got {fps!r}")
    if isinstance(max_frames, bool) or not isinstance(max_frames, (int, np.integer)) or max_frames < 1:
        raise ConfigError(f"animation max_frames must be an integer >= 1, got {max_frames!r}")
    iio = require_optional("imageio.v3", "render", "GIF animations")
    n = runs[0].n_frames
    picks = np.arange(n) if n <= max_frames else np.linspace(0, n - 1, max_frames).round().astype(int)
    views = _Views(runs, labels, style or RenderStyle(), title)
    try:
        images = np.stack([views.compose([[views.panel(i, f) for i in range(len(runs))]]) for f in picks])
    finally:
        views.close()
    # Encoded in memory, then written: imageio writing the file itself retries its failed flush
    # of a full disk when it is garbage-collected, printing an "Exception ignored" traceback.
    data = iio.imwrite("<bytes>", images, extension=".gif", duration=1000.0 / fps, loop=0)
    with atomic_path(out) as tmp:
        tmp.write_bytes(data)
    return out


def pictures(
    trajectories: Sequence[Trajectory],
    labels: Sequence[str],
    folder: str | os.PathLike,
    tag: str,
    title: str | None = None,
    renderer: str = "pyvista",
    style: RenderStyle | None = None,
) -> list[Path]:
    """The pictures of runs of one scene: ``filmstrip_TAG.png`` and, with PyVista, ``animation_TAG.gif``.

    Args:
        trajectories: the runs (as for :func:`filmstrip`).
        labels: a name per run.
        folder: where the pictures go.
        tag: the file names' suffix (e.g. the scene's name).
        title: text above the views.
        renderer: ``"pyvista"``, or ``"matplotlib"`` for the filmstrip alone (see :func:`pick_renderer`).
        style: colours, camera angles and view size of the PyVista renderer.

    Returns:
        The paths written.
    """
    out = Path(folder)
    paths = [filmstrip(trajectories, labels, out / f"filmstrip_{tag}.png", title=title, style=style, renderer=renderer)]
    if renderer == "pyvista":
        paths.append(animation(trajectories, labels, out / f"animation_{tag}.gif", title=title, style=style))
    return paths


def _save_image(image: np.ndarray, path: str | os.PathLike) -> Path:
    from PIL import Image

    out = Path(path)
    with atomic_path(out) as tmp:
        Image.fromarray(image).save(tmp, format="PNG", optimize=True)
    return out


def _filmstrip_matplotlib(runs: list[Trajectory], labels: Sequence[str], path: str | os.PathLike, picks: np.ndarray, title: str | None) -> Path:
    """The filmstrip drawn with matplotlib's 3-D axes: grey flat-shaded surfaces, the same fixed camera."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    plt = pyplot()
    every = np.concatenate([(t.rest_positions[None] + t.displacements).reshape(-1, 3) for t in runs])
    lo, hi = every.min(axis=0), every.max(axis=0)
    centre = 0.5 * (lo + hi)
    half = 0.55 * float((hi - lo).max()) + 0.3 * max(t.mesh.size for t in runs)
    scene = runs[0].scene
    patches = [plane_patch(p, every, 0.5 * float((hi - lo).max()), scene.gravity) for p in scene.planes]
    light = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    fig = plt.figure(figsize=(2.6 * len(picks), 2.6 * len(runs) + 0.4))
    for row, (traj, label) in enumerate(zip(runs, labels)):
        faces = traj.mesh.boundary_faces
        for col, f in enumerate(picks):
            ax = fig.add_subplot(len(runs), len(picks), row * len(picks) + col + 1, projection="3d")
            tri = traj.positions(f)[faces]
            nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
            shade = 0.35 + 0.65 * np.clip(nrm @ light, 0, 1)
            for patch in patches:
                ax.add_collection3d(Poly3DCollection([patch], facecolors=(0.6, 0.6, 0.6, 0.35), edgecolors="none"))
            ax.add_collection3d(Poly3DCollection(tri, facecolors=np.outer(shade, [0.98, 0.82, 0.35]), edgecolors="none"))
            ax.set_xlim(centre[0] - half, centre[0] + half)
            ax.set_ylim(centre[1] - half, centre[1] + half)
            ax.set_zlim(centre[2] - half, centre[2] + half)
            ax.view_init(elev=18, azim=-70)
            ax.set_axis_off()
            ax.set_title(f"{label}  t={traj.times[f]:.2f}s", fontsize=7)
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
