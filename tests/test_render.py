import xml.etree.ElementTree as ET

import meshio
import numpy as np
import pytest
from licrom import meshes
from licrom.compare import compare
from licrom.errors import ShapeError
from licrom.render import filmstrip, plot_errors, write_vtu_series
from licrom.training_data import make_synthetic_trajectories


@pytest.fixture(scope="module")
def trajs():
    return make_synthetic_trajectories(meshes.box(0.1, 2), count=2, frames=5, seed=1)


def _png(path):
    import matplotlib.image

    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    return matplotlib.image.imread(path)


def test_vtu_series_reads_back_every_frame(trajs, tmp_path):
    traj = trajs[0]
    pvd = write_vtu_series(traj, tmp_path / "series", name="run")
    entries = ET.parse(pvd).getroot().find("Collection")
    assert len(entries) == traj.n_frames
    for f, entry in enumerate(entries):
        assert float(entry.get("timestep")) == pytest.approx(traj.times[f])
        m = meshio.read(pvd.parent / entry.get("file"))
        np.testing.assert_allclose(m.points, traj.positions(f))
        np.testing.assert_allclose(m.point_data["displacement"], traj.displacements[f])
        np.testing.assert_array_equal(m.cells_dict["tetra"], traj.tets)
    assert sorted(p.name for p in pvd.parent.iterdir()) == ["run.pvd"] + [f"run_{f:04d}.vtu" for f in range(traj.n_frames)]


def test_filmstrip_has_a_row_per_trajectory(trajs, tmp_path):
    one = _png(filmstrip(trajs[:1], ["a"], tmp_path / "one.png", frames=4))
    two = _png(filmstrip(trajs, ["a", "b"], tmp_path / "two.png", frames=4, title="t"))
    assert two.shape[1] == one.shape[1] and two.shape[0] > 1.5 * one.shape[0]
    assert two[..., :3].std() > 0.05  # something is drawn


def test_filmstrip_refuses_mismatched_input(trajs, tmp_path):
    with pytest.raises(ShapeError, match="one label per trajectory"):
        filmstrip(trajs, ["only one"], tmp_path / "x.png")
    short = make_synthetic_trajectories(meshes.box(0.1, 2), count=1, frames=3, seed=2)[0]
    with pytest.raises(ShapeError, match="one frame count"):
        filmstrip([trajs[0], short], ["a", "b"], tmp_path / "x.png")
    assert not (tmp_path / "x.png").exists()


def test_error_plot(trajs, tmp_path):
    c = compare(trajs[0], trajs[0])
    image = _png(plot_errors({"same": c}, tmp_path / "errors.png"))
    assert image.shape[1] > image.shape[0] > 100
