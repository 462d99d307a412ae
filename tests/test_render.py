import dataclasses

import numpy as np
import pytest
from licrom import FullSim, Plane, meshes
from licrom.analysis.compare import compare
from licrom.data.presets import report_dataset_spec
from licrom.errors import ConfigError, MissingDependencyError, ShapeError
from licrom.learn.training_data import make_synthetic_trajectories
from licrom.scene.placement import drop_state, initial_state_on_plane
from licrom.viz.render import COLORBAR_PX, HEADER_PX, PANEL_GAP, RenderStyle, animation, filmstrip, pictures, plot_errors, pyvista_unavailable

RENDERERS = ["pyvista", "matplotlib"]
SLOPE = 20.0  # tan = 0.36: mu 0.1 slides (a = 2.4 m/s^2, 0.1 m in 0.3 s), mu 0.9 sticks
STYLE = RenderStyle(panel_size=(240, 160))


@pytest.fixture(scope="module")
def incline_runs():
    """``{mu: trajectory}`` of an 84-tet cheese set down on a 20 deg incline, 0.4 s in 11 frames."""
    mesh = meshes.cheese(resolution=4)
    base = report_dataset_spec("cheese", resolution=4).base_scene
    rest = drop_state(mesh, base.material.density, 0.0)
    runs = {}
    for mu in (0.1, 0.9):
        plane = Plane.incline(SLOPE, mu)
        scene = base.replace(planes=(plane,), initial=initial_state_on_plane(rest, plane, mesh, base.material.density))
        runs[mu] = FullSim(mesh, scene).run(40, record_every=4)
    return runs


@pytest.fixture(scope="module")
def trajs():
    return make_synthetic_trajectories(meshes.box(0.1, 2), count=2, frames=5, seed=1)


def _image(path):
    """The pixels of a PNG (h, w, 3), or of every frame of a GIF (f, h, w, 3)."""
    from PIL import Image, ImageSequence

    with Image.open(path) as im:
        frames = [np.asarray(f.convert("RGB")) for f in ImageSequence.Iterator(im)]
    return np.stack(frames) if path.suffix == ".gif" else frames[0]


def _object_centroid(panel):
    """(column, row) centroid of the coloured (object) pixels of a panel; plane, ghost, text and background are grey."""
    rgb = panel[..., :3].astype(float)
    hi = rgb.max(axis=-1)
    coloured = (hi - rgb.min(axis=-1)) > 0.12 * np.maximum(hi, 1.0)
    assert coloured.sum() > 200, "no object in the view"
    rows, cols = np.nonzero(coloured)
    return np.array([cols.mean(), rows.mean()])


def _gif_panels(path, title=True):
    """The views (the run's panel) of every frame of a one-run animation."""
    frames = _image(path)
    w, h = STYLE.panel_size
    top = HEADER_PX if title else 0
    assert frames.shape[1:3] == (top + h + COLORBAR_PX, w)
    return frames[:, top:top + h, :w]


@pytest.mark.parametrize("renderer", RENDERERS)
def test_animation_slider_moves_down_the_slope_and_sticker_stays(incline_runs, tmp_path, renderer):
    centroids = {}
    for mu, traj in incline_runs.items():
        path = animation([traj], [f"mu {mu}"], tmp_path / f"mu{mu}.gif", title=f"mu {mu}", style=STYLE, renderer=renderer)
        panels = _gif_panels(path)
        assert len(panels) == traj.n_frames == 11
        centroids[mu] = np.array([_object_centroid(p) for p in panels])
    slide = centroids[0.1][-1] - centroids[0.1][0]
    # Downhill is +x, seen from the side: the slider crosses the view to the right and down (rows grow).
    assert slide[0] > 40 and slide[1] > 5
    assert np.all(np.diff(centroids[0.1][3:, 0]) > 0)  # keeps going once it has landed
    assert np.abs(centroids[0.9] - centroids[0.9][0]).max() < 2.0  # pixels


@pytest.mark.parametrize("renderer", RENDERERS)
def test_animation_keeps_at_most_max_frames(incline_runs, tmp_path, renderer):
    path = animation(list(incline_runs.values()), ["slides", "sticks"], tmp_path / "both.gif", max_frames=4, style=STYLE, renderer=renderer)
    frames = _image(path)
    w, h = STYLE.panel_size
    assert frames.shape == (4, h + COLORBAR_PX, 2 * w + PANEL_GAP, 3)


@pytest.mark.parametrize("renderer", RENDERERS)
def test_filmstrip_rows_are_runs_and_columns_are_times(incline_runs, tmp_path, renderer):
    runs = [incline_runs[0.1], incline_runs[0.9]]
    path = filmstrip(runs, ["slides", "sticks"], tmp_path / "strip.png", frames=3, title="20 deg", style=STYLE, renderer=renderer)
    image = _image(path)
    w, h = STYLE.panel_size
    assert image.shape[:2] == (HEADER_PX + 2 * h + PANEL_GAP + COLORBAR_PX, 3 * w + 2 * PANEL_GAP)

    def panel(row, col):
        top, left = HEADER_PX + row * (h + PANEL_GAP), col * (w + PANEL_GAP)
        return image[top:top + h, left:left + w]

    # One camera for every view: both runs start in the same place, then only the slider moves.
    assert np.abs(_object_centroid(panel(0, 0)) - _object_centroid(panel(1, 0))).max() < 1.0
    assert _object_centroid(panel(0, 2))[0] - _object_centroid(panel(0, 0))[0] > 40
    assert np.abs(_object_centroid(panel(1, 2)) - _object_centroid(panel(1, 0))).max() < 2.0


@pytest.mark.parametrize("renderer", RENDERERS)
def test_error_colouring_leaves_the_reference_at_zero(incline_runs, tmp_path, renderer):
    traj = incline_runs[0.9]
    shifted = dataclasses.replace(traj, displacements=traj.displacements + [0.0, 0.0, 0.005])
    path = animation([traj, shifted], ["ref", "shifted"], tmp_path / "err.gif", max_frames=2,
                     style=RenderStyle(panel_size=(240, 160), color_by="error", ghost=False), renderer=renderer)
    last = _image(path)[-1].astype(float)
    w, h = STYLE.panel_size
    ref, other = last[:h, :w], last[:h, w + PANEL_GAP:]
    # The colour map's zero is pale yellow; 5 mm everywhere is its darkest red: less green, much less blue.
    assert ref[..., 2].mean() > other[..., 2].mean() + 10
    with pytest.raises(ShapeError, match="first run's mesh"):
        other_mesh = make_synthetic_trajectories(meshes.box(0.1, 2), count=1, frames=traj.n_frames, seed=3)[0]
        animation([traj, other_mesh], ["a", "b"], tmp_path / "x.gif", style=RenderStyle(color_by="error"))


def test_pictures_writes_a_filmstrip_and_an_animation(trajs, tmp_path):
    paths = pictures(trajs, ["a", "b"], tmp_path, "case", title="t", style=STYLE)
    assert [p.name for p in paths] == ["filmstrip_case.png", "animation_case.gif"]
    flat = pictures(trajs, ["a", "b"], tmp_path / "mpl", "case", renderer="matplotlib", style=STYLE)
    assert [p.name for p in flat] == ["filmstrip_case.png", "animation_case.gif"]


def test_one_colour_scale_for_several_scenes(incline_runs, tmp_path):
    """A scale given in the style is the one drawn: the same run is paler on a wider scale."""
    traj = incline_runs[0.1]
    reds = []
    for top in (1.0, 100.0):
        style = RenderStyle(panel_size=(240, 160), color_by="error", ghost=False, clim=(0.0, top))
        shifted = dataclasses.replace(traj, displacements=traj.displacements + [0.0, 0.0, 0.001])
        frames = _image(animation([traj, shifted], ["ref", "shifted"], tmp_path / f"s{top}.gif", max_frames=1, style=style,
                                  renderer="matplotlib"))
        w, h = STYLE.panel_size
        reds.append(frames[0][:h, w + PANEL_GAP:][..., 2].astype(float).mean())  # blue: low where the map is red
    assert reds[0] < reds[1] - 5
    with pytest.raises(ConfigError, match=r"RenderStyle\.clim"):
        RenderStyle(clim=(1.0, 0.0))


def test_matplotlib_filmstrip_has_a_row_per_trajectory(trajs, tmp_path):
    one = _image(filmstrip(trajs[:1], ["a"], tmp_path / "one.png", frames=4, renderer="matplotlib"))
    two = _image(filmstrip(trajs, ["a", "b"], tmp_path / "two.png", frames=4, title="t", renderer="matplotlib"))
    assert two.shape[1] == one.shape[1] and two.shape[0] > 1.5 * one.shape[0]
    assert two[..., :3].std() > 10  # something is drawn


def test_filmstrip_refuses_mismatched_input(trajs, tmp_path):
    with pytest.raises(ShapeError, match="one label per trajectory"):
        filmstrip(trajs, ["only one"], tmp_path / "x.png")
    short = make_synthetic_trajectories(meshes.box(0.1, 2), count=1, frames=3, seed=2)[0]
    with pytest.raises(ShapeError, match="one frame count"):
        filmstrip([trajs[0], short], ["a", "b"], tmp_path / "x.png")
    with pytest.raises(ConfigError, match="frames"):
        filmstrip(trajs, ["a", "b"], tmp_path / "x.png", frames=0)
    with pytest.raises(ConfigError, match="renderer"):
        filmstrip(trajs, ["a", "b"], tmp_path / "x.png", renderer="povray")
    with pytest.raises(ConfigError, match=r"\.gif"):
        animation(trajs, ["a", "b"], tmp_path / "x.mp4")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("field, value", [("color_by", "speed"), ("panel_size", (10, 10)), ("elevation", 95.0), ("colormap", "nope"),
                                          ("clim", (0.0, float("nan")))])
def test_render_style_refuses_bad_values(field, value):
    with pytest.raises(ConfigError, match=f"RenderStyle.{field}"):
        RenderStyle(**{field: value})


def test_without_pyvista_the_error_names_the_extra(trajs, tmp_path, monkeypatch):
    import importlib.util

    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "pyvista" else find_spec(name, *a))
    pyvista_unavailable.cache_clear()
    try:
        assert "licrom[render]" in pyvista_unavailable()
        with pytest.raises(MissingDependencyError, match=r"pip install 'licrom\[render\]'"):
            filmstrip(trajs, ["a", "b"], tmp_path / "x.png")
    finally:
        pyvista_unavailable.cache_clear()


def test_a_pyvista_that_cannot_render_is_reported_not_fatal(monkeypatch):
    import subprocess

    from licrom import render

    failed = subprocess.CompletedProcess([], 0, stdout="", stderr="vtkOSOpenGLRenderWindow: libOSMesa not found\n")
    monkeypatch.setattr(render.subprocess, "run", lambda *a, **k: failed)  # VTK exits 0 without a picture
    pyvista_unavailable.cache_clear()
    try:
        renderer, why = render.pick_renderer()
        assert renderer == "matplotlib" and "cannot render off-screen" in why and "libOSMesa not found" in why
    finally:
        pyvista_unavailable.cache_clear()


def test_error_plot(trajs, tmp_path):
    c = compare(trajs[0], trajs[0])
    image = _image(plot_errors({"same": c}, tmp_path / "errors.png"))
    assert image.shape[1] > image.shape[0] > 100
