import dataclasses

import numpy as np
import pytest
from licrom import ConfigError, ShapeError, meshes
from licrom.cubature import ContactPoints, Cubature


def test_full_and_naive_weights_sum_to_volume():
    m = meshes.cheese(resolution=8)
    full = Cubature.full(m)
    assert full.weights.sum() == pytest.approx(m.volume)
    naive = Cubature.naive(m, 100, seed=1)
    assert naive.count == 100
    assert naive.weights.sum() == pytest.approx(m.volume)
    assert len(np.unique(naive.tets)) == 100
    np.testing.assert_allclose(naive.points, m.centroids[naive.tets])
    assert Cubature.naive(m, 100, seed=1).tets.tolist() == naive.tets.tolist()
    assert Cubature.naive(m, 10 * m.n_tets).scheme == "full"


def test_contact_subset_keeps_area():
    m = meshes.sphere(0.05, 10)
    everyone = ContactPoints.all(m)
    assert everyone.areas.sum() == pytest.approx(m.surface_area)
    sub = ContactPoints.subset(m, 60)
    assert sub.count == 60
    assert sub.areas.sum() == pytest.approx(m.surface_area)
    # well spread: each hemisphere carries about half the area
    up = m.vertices[sub.indices][:, 2] > 0
    assert 0.35 < sub.areas[up].sum() / m.surface_area < 0.65


def test_bad_counts():
    m = meshes.box(0.1, 2)
    with pytest.raises(ConfigError, match="count must be an integer >= 1"):
        Cubature.naive(m, 0)
    with pytest.raises(ConfigError, match="count must be an integer >= 1"):
        ContactPoints.subset(m, -1)


def test_repr_shows_shapes_not_values():
    m = meshes.box(0.1, 3)
    text = repr(Cubature.naive(m, 20))
    assert "weights=array(float64, shape=(20,))" in text and "scheme='naive'" in text and "\n" not in text
    assert repr(ContactPoints.all(m)).startswith("ContactPoints(indices=array(int64")


def test_cubature_for_a_trained_model_fits_its_training_forces(tiny_demo):
    from licrom import Model, ReducedSim, Trajectory
    from licrom.compare import nonrigid_error
    from licrom.training_data import load_trajectories

    out, summary = tiny_demo
    model = Model.load(out / "model.lcm")
    runs = [traj for _, traj in load_trajectories(out / "data")]
    cubature = Cubature.for_model(model, runs, count=40)
    assert cubature.scheme == "optimized" and 1 <= cubature.count <= 40
    assert cubature.fit_error < 1e-3 or cubature.count == 40
    assert summary["model"]["cubature_points"] == cubature.count  # what the demo simulates with
    # A held-out run with the fitted tets stays with the run that takes every tet (the exact elastic energy):
    # 1 % apart in their deformation with 26 fitted tets, where 40 random ones (naive) leave 10 %.
    full = Trajectory.load(sorted((out / "runs").glob("full_*.npz"))[0])
    fitted = ReducedSim(model, full.mesh, full.scene, cubature=cubature).run(40)
    every = ReducedSim(model, full.mesh, full.scene, cubature=Cubature.full(full.mesh)).run(40)
    assert nonrigid_error(every, fitted, start=0) < 0.04
    with pytest.raises(ConfigError, match="at least one run"):
        Cubature.for_model(model, [])
    with pytest.raises(ShapeError, match="rest mesh"):
        Cubature.for_model(model, [dataclasses.replace(runs[0], rest_positions=runs[0].rest_positions + 0.01)])
