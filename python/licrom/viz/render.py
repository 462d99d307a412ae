"""Pictures of runs: filmstrips and animations from a fixed world camera, and the error plot.

Two renderers draw the same pictures: one camera frames the whole run of every trajectory
shown, the planes are drawn as grids, the start pose as a grey ghost, and the surface is
coloured by its non-rigid deformation (each frame's best rigid fit removed, :mod:`licrom.rigid`)
or by its distance from a reference run, with a colour bar in mm. Full and reduced runs are
shown side by side with the same camera and colour scale (and one scale for every scene of a
comparison when :attr:`RenderStyle.clim` is given).

- ``"pyvista"`` (VTK, off-screen; ``pip install 'licrom[render]'``): smooth-shaded surfaces. On a
  Linux machine without a display VTK's wheels render through EGL (Mesa's or a GPU driver's).
- ``"matplotlib"`` (always installed): the camera's parallel projection painted triangle by
  triangle, back to front, flat-shaded. :func:`pick_renderer` chooses and says why.

Animations are GIFs written by Pillow with either renderer.
"""

from __future__ import annotations

import functools
import io
import math
import os
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._io import atomic_path
from ..analysis.compare import Comparison
from ..errors import ConfigError, MissingDependencyError, ShapeError, require_optional
from ..records.export import downhill_direction, plane_patch
from ..records.trajectory import Trajectory
from ..rigid import nonrigid_displacements
from ._plot import pyplot, save_png

__all__ = [
    "COLOR_BY",
    "RENDERERS",
    "RenderStyle",
    "animation",
    "deformation_mm",
    "filmstrip",
    "pick_renderer",
    "pictures",
    "plot_errors",
    "pyvista_unavailable",
]

COLOR_BY = ("deformation", "error")
"""What colours the surface: its non-rigid deformation, or its distance from the first run shown."""

RENDERERS = ("pyvista", "matplotlib")
"""Renderers of :func:`filmstrip` and :func:`animation`."""

HEADER_PX = 32
"""Height of the title strip above the panels (when there is a title), pixels."""
COLORBAR_PX = 58
"""Height of the colour-bar strip below the panels, pixels."""
PANEL_GAP = 2
"""Width of the grey lines between panels, pixels."""
PLANE_RGB = (0.86, 0.86, 0.84)
GRID_RGB = (0.6, 0.6, 0.58)
GHOST_RGB = (0.55, 0.55, 0.55)
GHOST_ALPHA = 0.25


@dataclass(frozen=True)
class RenderStyle:
    """How runs are drawn (both renderers).

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
        clim: the colour scale (low, high), mm; None: from 0 to the largest value of the runs
            drawn. Give one scale to the pictures of several scenes to compare them.
    """

    color_by: str = "deformation"
    panel_size: tuple[int, int] = (480, 300)
    elevation: float = 22.0
    azimuth: float = 20.0
    colormap: str = "YlOrRd"
    ghost: bool = True
    edges: bool = False
    clim: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.clim is not None:
            lim = tuple(self.clim)
            if len(lim) != 2 or not all(isinstance(v, (int, float, np.floating)) and math.isfinite(v) for v in lim) or not lim[0] < lim[1]:
                raise ConfigError(f"RenderStyle.clim must be two finite numbers low < high (mm) or None, got {self.clim!r}")
            object.__setattr__(self, "clim", (float(lim[0]), float(lim[1])))
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


# VTK itself, as PyVista's off-screen plotter uses it (the same render window, chosen by the same environment):
# importing PyVista and making a plotter took the check 1.5 s of CPU, this 0.5 s.
_PROBE = """\
import vtkmodules.vtkRenderingOpenGL2
from vtkmodules.vtkFiltersSources import vtkSphereSource
from vtkmodules.vtkRenderingCore import vtkActor, vtkPolyDataMapper, vtkRenderer, vtkRenderWindow, vtkWindowToImageFilter
sphere, mapper, actor, renderer, window = vtkSphereSource(), vtkPolyDataMapper(), vtkActor(), vtkRenderer(), vtkRenderWindow()
mapper.SetInputConnection(sphere.GetOutputPort())
actor.SetMapper(mapper)
renderer.AddActor(actor)
window.SetOffScreenRendering(1)
window.AddRenderer(renderer)
window.SetSize(16, 16)
window.Render()
grab = vtkWindowToImageFilter()
grab.SetInput(window)
grab.Update()
print('licrom-probe', grab.GetOutput().GetDimensions())
window.Finalize()
"""


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


def deformation_mm(traj: Trajectory) -> np.ndarray:
    """(f, n) length of each vertex's non-rigid deformation in each frame (the frame's best rigid fit removed), mm:
    the colours of ``color_by="deformation"``."""
    x = traj.rest_positions[None] + traj.displacements
    return 1e3 * np.linalg.norm(nonrigid_displacements(x, traj.rest_positions, traj.mesh.vertex_masses(traj.scene.material.density)), axis=-1)


def _check_runs(trajectories: Sequence[Trajectory], labels: Sequence[str], what: str) -> list[Trajectory]:
    runs = list(trajectories)
    if not runs or len(labels) != len(runs):
        raise ShapeError(f"{what} needs one label per trajectory, got {len(runs)} trajectories and {len(labels)} labels")
    if len({t.n_frames for t in runs}) != 1:
        raise ShapeError(f"{what} needs trajectories of one frame count, got {[t.n_frames for t in runs]}")
    return runs


class _Views:
    """The runs, their colours, one world camera and one painter (a view drawn by the renderer) per run."""

    def __init__(self, runs: list[Trajectory], labels: Sequence[str], style: RenderStyle, title: str | None, renderer: str) -> None:
        self.runs, self.labels, self.style, self.title, self.renderer = runs, list(labels), style, title, renderer
        self.positions = [t.rest_positions[None] + t.displacements for t in runs]
        if style.color_by == "error":
            ref = runs[0]
            for t in runs[1:]:
                if t.rest_positions.shape != ref.rest_positions.shape or not np.allclose(t.rest_positions, ref.rest_positions):
                    raise ShapeError("RenderStyle.color_by='error' needs every run on the first run's mesh (rest positions differ)")
            self.scalars = [1e3 * np.linalg.norm(x - self.positions[0], axis=-1) for x in self.positions]
            self.scalar_label = f"distance from {self.labels[0]} (mm)"
        else:
            self.scalars = [deformation_mm(t) for t in runs]
            self.scalar_label = "non-rigid deformation (mm)"
        top = max(float(s.max()) for s in self.scalars)
        # a rigid run: a scale of 0 to 10 micrometres, not of 0 to 0
        self.clim = style.clim if style.clim is not None else (0.0, max(top, 0.01))
        if style.ghost:
            self.scalar_label += "; grey ghost: the start pose"
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
        self.painters: list[Any] = []
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

    def panel(self, i: int, frame: int) -> np.ndarray:
        """(h, w, 3) picture of run ``i`` at ``frame``."""
        if not self.painters:
            kind = _VtkPanel if self.renderer == "pyvista" else _FlatPanel
            self.painters = [kind(self, k) for k in range(len(self.runs))]
        text = f"{self.labels[i]}   t = {self.runs[i].times[frame]:.{self.decimals}f} s"
        return self.painters[i].draw(self.positions[i][frame], self.scalars[i][frame], text)

    def grid_cells(self, i: int, patch: np.ndarray) -> tuple[int, int]:
        """Cells of a plane's grid along its two sides: squares of about half the object's size."""
        cell = 0.5 * self.runs[i].mesh.size
        ns, nt = (max(2, min(60, round(float(np.linalg.norm(patch[k] - patch[0])) / cell))) for k in (1, 3))
        return ns, nt

    def close(self) -> None:
        for painter in self.painters:
            painter.close()
        self.painters = []

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


class _VtkPanel:
    """One run's view drawn by an off-screen PyVista plotter."""

    def __init__(self, views: _Views, i: int) -> None:
        pv = _pyvista()
        style = views.style
        pl = pv.Plotter(off_screen=True, window_size=list(style.panel_size))
        pl.set_background("white")
        for patch in views.patches:
            ns, nt = views.grid_cells(i, patch)
            s, t = np.meshgrid(np.linspace(0, 1, ns + 1), np.linspace(0, 1, nt + 1), indexing="ij")
            pts = patch[0] + s[..., None] * (patch[1] - patch[0]) + t[..., None] * (patch[3] - patch[0])
            grid = pv.StructuredGrid(pts[..., 0], pts[..., 1], pts[..., 2])
            pl.add_mesh(grid, color=PLANE_RGB, show_edges=True, edge_color=GRID_RGB, line_width=1)
        faces = np.asarray(views.runs[i].mesh.boundary_faces)
        vtk_faces = np.hstack([np.full((len(faces), 1), 3), faces]).ravel()
        if style.ghost:
            pl.add_mesh(pv.PolyData(views.positions[i][0], vtk_faces), color=GHOST_RGB, opacity=GHOST_ALPHA)
        self.surface = pv.PolyData(views.positions[i][0].copy(), vtk_faces)
        self.surface.point_data["value"] = views.scalars[i][0].copy()
        pl.add_mesh(self.surface, scalars="value", cmap=style.colormap, clim=views.clim, show_scalar_bar=False,
                    show_edges=style.edges, edge_color=(0.2, 0.2, 0.2), line_width=0.5)
        self.text = pl.add_text("", position=(8, style.panel_size[1] - 22), font_size=10, color="black")
        cam = pl.camera
        cam.focal_point, cam.position, cam.up = views.camera["focal"], views.camera["position"], views.camera["up"]
        cam.parallel_projection = True
        cam.parallel_scale = views.camera["scale"]
        pl.reset_camera_clipping_range()
        self.plotter = pl

    def draw(self, x: np.ndarray, values: np.ndarray, text: str) -> np.ndarray:
        self.surface.points = x
        self.surface.point_data["value"] = values
        self.text.SetInput(text)
        self.plotter.reset_camera_clipping_range()
        self.plotter.render()
        return np.asarray(self.plotter.screenshot(None, return_img=True))[..., :3]

    def close(self) -> None:
        self.plotter.close()


class _FlatPanel:
    """One run's view drawn by matplotlib: the camera's parallel projection of the surface
    triangles, painted back to front (painter's algorithm), each flat-shaded by its normal
    against a light from the camera and above."""

    def __init__(self, views: _Views, i: int) -> None:
        from matplotlib import colormaps
        from matplotlib.collections import LineCollection, PolyCollection
        from matplotlib.colors import Normalize

        plt = pyplot()
        style, cam = views.style, views.camera
        w, h = style.panel_size
        forward = np.asarray(cam["focal"], float) - np.asarray(cam["position"], float)
        forward /= np.linalg.norm(forward)
        up = np.asarray(cam["up"], float)
        right = np.cross(forward, up)
        right /= np.linalg.norm(right)
        self.axes3 = np.stack([right, up, forward])  # screen x, screen y, depth (away from the camera)
        self.origin = np.asarray(cam["focal"], float)
        light = up - 1.5 * forward
        self.light = light / np.linalg.norm(light)
        self.faces = np.asarray(views.runs[i].mesh.boundary_faces)
        self.cmap, self.norm = colormaps[style.colormap], Normalize(*views.clim)
        self.fig = plt.figure(figsize=(w / 100, h / 100), dpi=100)
        ax = self.fig.add_axes((0, 0, 1, 1))
        ax.set_axis_off()
        half = float(cam["scale"])
        ax.set_xlim(-half * w / h, half * w / h)
        ax.set_ylim(-half, half)
        for patch in views.patches:
            ns, nt = views.grid_cells(i, patch)
            corners = self._project(np.asarray(patch))[:, :2]
            ax.add_collection(PolyCollection([corners], facecolors=[PLANE_RGB], edgecolors="none"))
            p0, ps, pt = patch[0], patch[1] - patch[0], patch[3] - patch[0]
            lines = [[p0 + a * ps, p0 + a * ps + pt] for a in np.linspace(0, 1, ns + 1)]
            lines += [[p0 + b * pt, p0 + b * pt + ps] for b in np.linspace(0, 1, nt + 1)]
            ax.add_collection(LineCollection([self._project(np.asarray(seg))[:, :2] for seg in lines], colors=[GRID_RGB], linewidths=0.8))
        if style.ghost:
            tri = self._project(views.positions[i][0])[self.faces]
            ghost = tri[np.argsort(-tri[:, :, 2].mean(axis=1))][:, :, :2]
            ax.add_collection(PolyCollection(ghost, facecolors=[(*GHOST_RGB, GHOST_ALPHA)], edgecolors="none"))
        # Edges in the face colour hide the anti-aliasing seams between neighbours.
        self.surface = PolyCollection([], linewidths=0.4 if not style.edges else 0.3)
        ax.add_collection(self.surface)
        self.edges = style.edges
        self.text = ax.text(8 / w, 1 - 8 / h, "", transform=ax.transAxes, va="top", ha="left", fontsize=9)

    def _project(self, x: np.ndarray) -> np.ndarray:
        return (x - self.origin) @ self.axes3.T

    def draw(self, x: np.ndarray, values: np.ndarray, text: str) -> np.ndarray:
        tri_world = x[self.faces]
        normal = np.cross(tri_world[:, 1] - tri_world[:, 0], tri_world[:, 2] - tri_world[:, 0])
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
        shade = 0.45 + 0.55 * np.abs(normal @ self.light)
        rgb = self.cmap(self.norm(values[self.faces].mean(axis=1)))[:, :3] * shade[:, None]
        tri = self._project(x)[self.faces]
        order = np.argsort(-tri[:, :, 2].mean(axis=1))  # farthest first
        self.surface.set_verts(tri[order][:, :, :2])
        self.surface.set_facecolor(rgb[order])
        self.surface.set_edgecolor((0.2, 0.2, 0.2) if self.edges else rgb[order])
        self.text.set_text(text)
        self.fig.canvas.draw()
        return np.asarray(self.fig.canvas.buffer_rgba())[..., :3].copy()

    def close(self) -> None:
        pyplot().close(self.fig)


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
        style: colours, camera angles, view size and colour scale.
        renderer: ``"pyvista"`` (smooth shading, needs ``licrom[render]``) or ``"matplotlib"``
            (flat shading, always installed; see :func:`pick_renderer`).

    Raises:
        ShapeError: labels or frame counts that do not match.
        ConfigError: ``frames`` < 1 or an unknown renderer.
        MissingDependencyError: ``renderer="pyvista"`` where PyVista cannot render.
    """
    runs = _check_runs(trajectories, labels, "filmstrip")
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 1:
        raise ConfigError(f"filmstrip frames must be an integer >= 1, got {frames!r}")
    _check_renderer(renderer, "filmstrip")
    views = _Views(runs, labels, style or RenderStyle(), title, renderer)
    try:
        return _filmstrip(views, runs, frames, path)
    finally:
        views.close()


def _filmstrip(views: _Views, runs: list[Trajectory], frames: int, path: str | os.PathLike) -> Path:
    picks = np.linspace(0, runs[0].n_frames - 1, frames).round().astype(int)
    return _save_image(views.compose([[views.panel(i, f) for f in picks] for i in range(len(runs))]), path)


def animation(
    trajectories: Sequence[Trajectory],
    labels: Sequence[str],
    path: str | os.PathLike,
    fps: float = 20.0,
    max_frames: int = 60,
    title: str | None = None,
    style: RenderStyle | None = None,
    renderer: str = "pyvista",
) -> Path:
    """An animated GIF of the runs side by side, from the fixed world camera of :func:`filmstrip`.

    Args:
        trajectories: the runs, one view each, left to right.
        labels: a name per run, shown in its view.
        path: the ``.gif`` to write.
        fps: frames per second of the GIF (the recorded time is shown in each view).
        max_frames: at most this many frames, evenly spaced over the run (all when fewer).
        title: text above the views.
        style: colours, camera angles, view size and colour scale.
        renderer: ``"pyvista"`` or ``"matplotlib"`` (as for :func:`filmstrip`).

    Raises:
        ShapeError: labels or frame counts that do not match.
        ConfigError: a path not ending in ``.gif``, ``fps`` <= 0, ``max_frames`` < 1 or an
            unknown renderer.
        MissingDependencyError: ``renderer="pyvista"`` where PyVista cannot render.
    """
    runs = _check_runs(trajectories, labels, "animation")
    out = Path(path)
    if out.suffix.lower() != ".gif":
        raise ConfigError(f"animation path must end in .gif, got '{out.name}'")
    if not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
        raise ConfigError(f"animation fps must be > 0, got {fps!r}")
    if isinstance(max_frames, bool) or not isinstance(max_frames, (int, np.integer)) or max_frames < 1:
        raise ConfigError(f"animation max_frames must be an integer >= 1, got {max_frames!r}")
    _check_renderer(renderer, "animation")
    views = _Views(runs, labels, style or RenderStyle(), title, renderer)
    try:
        return _animation(views, runs, out, fps, max_frames)
    finally:
        views.close()


def _animation(views: _Views, runs: list[Trajectory], out: Path, fps: float, max_frames: int) -> Path:
    from PIL import Image

    n = runs[0].n_frames
    picks = np.arange(n) if n <= max_frames else np.linspace(0, n - 1, max_frames).round().astype(int)
    frames = [views.compose([[views.panel(i, f) for i in range(len(runs))]]) for f in picks]
    # One palette for every frame, made from a few of them: mapping each frame onto it is several times
    # cheaper than Pillow's own per-frame median cut, and the colours do not flicker between frames.
    sample = np.vstack([frames[k] for k in np.linspace(0, len(frames) - 1, min(len(frames), 6)).round().astype(int)])
    palette = Image.fromarray(sample).quantize(colors=255, method=Image.Quantize.MEDIANCUT)
    images = [Image.fromarray(f).quantize(palette=palette, dither=Image.Dither.NONE) for f in frames]
    buffer = io.BytesIO()
    images[0].save(buffer, format="GIF", save_all=True, append_images=images[1:], duration=round(1000.0 / fps), loop=0)
    data = buffer.getvalue()
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
    max_frames: int = 30,
    fps: float = 10.0,
) -> list[Path]:
    """The pictures of runs of one scene: ``filmstrip_TAG.png`` and ``animation_TAG.gif``.

    Args:
        trajectories: the runs (as for :func:`filmstrip`).
        labels: a name per run.
        folder: where the pictures go.
        tag: the file names' suffix (e.g. the scene's name).
        title: text above the views.
        renderer: ``"pyvista"`` or ``"matplotlib"`` (see :func:`pick_renderer`).
        style: colours, camera angles, view size and colour scale.
        max_frames: most frames of the animation, evenly spaced over the run (30: every fifth
            step of a 150-step run; each frame costs two renders, about a tenth of a second of CPU).
        fps: frames per second of the animation (10: 30 frames play in 3 s).

    Returns:
        The paths written.
    """
    runs = _check_runs(trajectories, labels, "pictures")
    _check_renderer(renderer, "pictures")
    out = Path(folder)
    views = _Views(runs, labels, style or RenderStyle(), title, renderer)  # one set of views (plotters) for both
    try:
        return [_filmstrip(views, runs, 6, out / f"filmstrip_{tag}.png"),
                _animation(views, runs, out / f"animation_{tag}.gif", fps, max_frames)]
    finally:
        views.close()


def _check_renderer(renderer: Any, what: str) -> None:
    if renderer not in RENDERERS:
        raise ConfigError(f"{what} renderer must be one of {', '.join(map(repr, RENDERERS))}, got {renderer!r}")


def _save_image(image: np.ndarray, path: str | os.PathLike) -> Path:
    from PIL import Image

    out = Path(path)
    with atomic_path(out) as tmp:
        # zlib's default level: optimize=True (level 9 and every filter) took 5x longer for a 3 % smaller file.
        Image.fromarray(image).save(tmp, format="PNG", compress_level=6)
    return out


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
