"""The online error estimate of reduced runs (licrom.reduced.error_estimate)."""

from __future__ import annotations

import warnings

import licrom
import numpy as np
import pytest
from licrom import AccuracyWarning, Material, MeshBasis, Plane, ReducedSim, Scene, SolverParams, Trajectory, _core, meshes
from licrom.analysis.compare import compare, nonrigid_error
from licrom.reduced.body import BodyFrameSim
from licrom.reduced.error_estimate import (
    ERROR_STRIDE,
    ERROR_THRESHOLD,
    INERTIA_EXPONENT,
    MIN_EVALUATIONS,
    RESOLUTION_REACH,
    ErrorMonitor,
    normalising_inverse,
    residual_stride,
)
from licrom.scene.placement import drop_state, initial_state_on_plane
from licrom.subspace.body_basis import BodyFrameBasis
from licrom.subspace.cubature import Cubature
from scipy.linalg import fractional_matrix_power

STEPS = 30


def _scene(mesh: licrom.Mesh, slope: float = 30.0) -> Scene:
    """The mesh dropped 2 cm onto an incline: it lands, deforms and slides."""
    base = Scene(material=Material(youngs_modulus=2.0e4, poisson_ratio=0.3, density=1000.0), dt=0.01,
                 solver=SolverParams(tolerance=1e-10, reduced_tolerance=1e-10, max_iterations=100))
    plane = Plane.incline(slope, friction=0.3)
    flat = drop_state(mesh, 1000.0, 0.02, rotation=(0.15, 0.1, 0.0))
    return base.replace(planes=(plane,), initial=initial_state_on_plane(flat, plane, mesh, 1000.0))


@pytest.fixture(scope="module")
def mesh() -> licrom.Mesh:
    return meshes.cheese(resolution=4)


@pytest.mark.parametrize("integrator", ["backward_euler", "bdf2"])
def test_full_space_basis_has_no_residual(mesh, integrator):
    # The residual is that of the run's own integrator (BDF2's reads four states back).
    scene = _scene(mesh).replace(integrator=integrator)
    sim = ReducedSim(MeshBasis.identity(mesh), mesh, scene, cubature=Cubature.full(mesh))
    traj = sim.run(STEPS)
    assert traj.error_estimate.shape == (traj.n_frames,)
    assert np.all(np.isfinite(traj.error_estimate))
    # The full space solves the full equations: only the Newton tolerance is left.
    assert traj.error_estimate[-1] < 1e-4


def _bend_sim(mesh, scene) -> BodyFrameSim:
    """A body-frame simulation with the affine modes and one bending mode, every tet as cubature."""
    x = mesh.vertices - mesh.vertices.mean(axis=0)
    bend = np.zeros((mesh.n_vertices, 3, 1))
    bend[:, 2, 0] = x[:, 0] ** 2
    return BodyFrameSim(BodyFrameBasis(mesh, MeshBasis(mesh, bend)), mesh, scene, cubature=Cubature.full(mesh))


@pytest.fixture(scope="module")
def one_mode_run(mesh):
    """A body-frame run with the affine modes and one bending mode, and the full run of the scene."""
    scene = _scene(mesh)
    full = licrom.FullSim(mesh, scene).run(STEPS)
    sim = _bend_sim(mesh, scene)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        reduced = sim.run(STEPS)
    return full, reduced, [w for w in caught if issubclass(w.category, AccuracyWarning)]


def test_a_run_recorded_only_after_its_evaluations_has_a_zero_estimate(mesh):
    # recorded at its end only: first contact is counted from the last frame, after every evaluation
    sim = ReducedSim(MeshBasis.identity(mesh), mesh, _scene(mesh), cubature=Cubature.full(mesh))
    traj = sim.run(12, record_every=12)
    assert traj.n_frames == 2 and traj.info["error_estimate_terms"]["residual"] == 0.0
    # the cubature's term is evaluated once more at the run's end, which counts: every tet leaves round-off there
    assert traj.error_estimate[0] == 0.0 and traj.error_estimate[-1] < 1e-12


def test_one_mode_basis_has_a_large_estimate(one_mode_run):
    full, reduced, _ = one_mode_run
    assert nonrigid_error(full, reduced) > 0.3
    assert reduced.error_estimate[-1] > ERROR_THRESHOLD


def test_accuracy_warning_is_raised_once(one_mode_run):
    _, _, caught = one_mode_run
    assert len(caught) == 1
    assert "more modes" in str(caught[0].message)
    assert issubclass(AccuracyWarning, licrom.LicromWarning)


def test_elastic_force_matches_finite_differences(mesh):
    monitor = ErrorMonitor(mesh, np.zeros((mesh.n_vertices, 3, 0)), mesh.vertices, _scene(mesh), count=4)
    x = mesh.vertices + 0.02 * mesh.size * np.random.default_rng(0).standard_normal(mesh.vertices.shape)
    mu, lam = _scene(mesh).material.snh_parameters

    def energy(pos: np.ndarray) -> float:
        return float(mesh.rest_volumes @ _core.snh_energy(np.ascontiguousarray(mesh.deformation_gradients(pos)), mu, lam))

    forces = monitor.elastic_forces(x[monitor.near])
    eps = 1e-7 * mesh.size
    for s, v in enumerate(monitor.vertices):
        for i in range(3):
            plus, minus = x.copy(), x.copy()
            plus[v, i] += eps
            minus[v, i] -= eps
            fd = -(energy(plus) - energy(minus)) / (2 * eps)
            assert forces[s, i] == pytest.approx(fd, rel=1e-5, abs=1e-6 * np.abs(forces).max())


def test_residual_stride_follows_the_cost_of_a_step():
    # Cheap steps (few modes, few cubature tets) space the evaluations out; dear ones keep the least stride.
    assert residual_stride(73, 18) >= 3 * ERROR_STRIDE
    assert residual_stride(100_000, 256) == ERROR_STRIDE
    strides = [residual_stride(count, 60) for count in (10, 100, 1000, 10_000)]
    assert strides == sorted(strides, reverse=True) and strides[0] > strides[-1]


@pytest.mark.parametrize("stride", [3, ERROR_STRIDE, 50])
def test_residual_is_evaluated_from_the_least_stride_on(mesh, stride):
    # The first evaluation at min(stride, ERROR_STRIDE), then every stride-th step: a run of ERROR_STRIDE steps has one.
    monitor = ErrorMonitor(mesh, np.zeros((mesh.n_vertices, 3, 0)), mesh.vertices, _scene(mesh), count=4, stride=stride)
    x = mesh.vertices[monitor.vertices]
    monitor.start([x] * monitor.history_length)
    for _ in range(120):
        monitor.after_step(lambda: (np.zeros(0), None, None), lambda q: 1.0)
    first = min(stride, ERROR_STRIDE)
    # An evaluation is finished on the step after it; one on the last step, by the run's end.
    assert (monitor._pending is not None) == ((120 - first) % stride == 0)
    monitor.finish(np.zeros(0), lambda q: 1.0)
    assert [step for step, _, _ in monitor._evaluations] == list(range(first, 121, stride))


@pytest.mark.parametrize("steps", [60, 400, 5000])
def test_a_run_of_known_length_gets_its_evaluations(mesh, steps):
    # A stride of 100 gives a run about MIN_EVALUATIONS evaluations where ERROR_STRIDE allows, and never more steps
    # between two than the model's stride.
    monitor = ErrorMonitor(mesh, np.zeros((mesh.n_vertices, 3, 0)), mesh.vertices, _scene(mesh), count=4, stride=100)
    monitor.start([mesh.vertices[monitor.vertices]] * monitor.history_length, steps)
    for _ in range(steps):
        monitor.after_step(lambda: (np.zeros(0), None, None), lambda q: 1.0)
    monitor.finish(np.zeros(0), lambda q: 1.0)
    stride = min(100, max(ERROR_STRIDE, steps // MIN_EVALUATIONS))
    assert [step for step, _, _ in monitor._evaluations] == list(range(ERROR_STRIDE, steps + 1, stride))
    assert len(monitor._evaluations) >= min(MIN_EVALUATIONS, steps // ERROR_STRIDE)


def test_error_estimate_saves_and_loads(one_mode_run, tmp_path):
    _, reduced, _ = one_mode_run
    back = Trajectory.load(reduced.save(tmp_path / "run.npz"))
    np.testing.assert_array_equal(back.error_estimate, reduced.error_estimate)


def test_file_without_error_estimate_still_loads(one_mode_run, tmp_path):
    _, reduced, _ = one_mode_run
    path = reduced.save(tmp_path / "run.npz")
    with np.load(path) as f:
        arrays = {k: f[k] for k in f.files if k != "error_estimate"}
    np.savez(path, **arrays)  # a file written before the estimate existed
    back = Trajectory.load(path)
    assert back.error_estimate.shape == (0,)
    np.testing.assert_array_equal(back.displacements, reduced.displacements.astype(np.float32))


def test_error_estimate_must_match_the_frames(one_mode_run):
    _, reduced, _ = one_mode_run
    with pytest.raises(licrom.ShapeError):
        Trajectory(reduced.rest_positions, reduced.tets, reduced.displacements, reduced.velocities, reduced.times, reduced.scene,
                   error_estimate=np.zeros(3))


def test_comparison_reports_the_estimate(one_mode_run):
    full, reduced, _ = one_mode_run
    c = compare(full, reduced)
    assert c.error_estimate == reduced.error_estimate[-1]
    assert c.summary()["error_estimate"] == pytest.approx(reduced.error_estimate[-1])
    assert "estimated non-rigid error" in c.table()
    assert np.isnan(compare(full, full).error_estimate)  # a full run has none


def test_normalising_block_is_the_weighted_geometric_mean_of_static_and_one_step_stiffness():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(6, 3, 3))
    stiffness = a @ a.transpose(0, 2, 1) + 0.5 * np.eye(3)
    inertia = rng.uniform(0.0, 50.0, size=6)
    got = normalising_inverse(stiffness, inertia)
    for k, m, j in zip(stiffness, inertia, got):
        block = fractional_matrix_power(k, 1.0 - INERTIA_EXPONENT) @ fractional_matrix_power(k + m * np.eye(3), INERTIA_EXPONENT)
        np.testing.assert_allclose(j, np.linalg.inv(block.real), rtol=1e-10, atol=1e-12)
    # no inertia: the static stiffness alone
    np.testing.assert_allclose(normalising_inverse(stiffness, np.zeros(6)), np.linalg.inv(stiffness), rtol=1e-10)


def _bend_run(mesh, scene, steps):
    """(estimate, true non-rigid error) of :func:`_bend_sim` run for ``steps``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)
        reduced = _bend_sim(mesh, scene).run(steps)
    return float(reduced.error_estimate[-1]), nonrigid_error(licrom.FullSim(mesh, scene).run(steps), reduced)


def test_estimate_keeps_its_scale_when_the_step_shrinks(mesh):
    """The same subspace over the same 0.3 s at h = 10 ms and 2.5 ms: the one-step inertia m/h'^2 grows 16x. The
    estimate over the true error moves by 0.33x here (a one-sweep normalisation, a = 1, by 0.11x; the static
    block, a = 0, by 0.58x); the validation runs set the scale, this keeps the estimate from shrinking with h."""
    scene = _scene(mesh)
    coarse = _bend_run(mesh, scene, STEPS)
    fine = _bend_run(mesh, scene.replace(dt=scene.dt / 4), 4 * STEPS)
    ratio = (fine[0] / fine[1]) / (coarse[0] / coarse[1])
    assert 0.25 < ratio < 4.0, (coarse, fine)


@pytest.mark.parametrize("frame", ["world", "body"])
def test_a_model_on_a_much_finer_or_coarser_mesh_warns_that_its_estimate_is_unchecked(frame):
    # Within RESOLUTION_REACH times the training mesh's tets no warning; beyond it, finer or coarser, one AccuracyWarning.
    import torch
    from licrom.learn.model import LicromNet, Model, ModelConfig
    from licrom.learn.model.finalize import finalize_basis

    training = meshes.box((0.2, 0.1, 0.1), resolution=6)
    torch.manual_seed(0)
    net = LicromNet(ModelConfig(latent_dim=2, frame=frame))
    c = training.vertices.mean(axis=0)
    net.set_normalization(c, float(np.abs(training.vertices - c).max()), 1e-3)
    model = Model(net, training, [Scene(planes=(Plane(friction=0.3),))], finalization=finalize_basis(net, training))
    for mesh, warns in [(training, False), (meshes.box((0.2, 0.1, 0.1), resolution=8), False),  # 324, 768 tets
                        (meshes.box((0.2, 0.1, 0.1), resolution=14), True), (meshes.box((0.2, 0.1, 0.1), resolution=2), True)]:  # 4116, 12
        ratio = mesh.n_tets / training.n_tets
        assert (max(ratio, 1 / ratio) > RESOLUTION_REACH) == warns
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            ReducedSim(model, mesh=mesh, cubature="naive")
        said = [w for w in caught if issubclass(w.category, AccuracyWarning) and "checked within" in str(w.message)]
        assert len(said) == warns, (mesh.n_tets, [str(w.message) for w in caught])
