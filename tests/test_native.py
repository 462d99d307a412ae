"""Tests of the Rust core through its Python binding (licrom._core)."""

from __future__ import annotations

import numpy as np
import pytest
from licrom import _core, meshes
from licrom.errors import ConfigError, ShapeError, SolverError
from licrom.subspace.basis import MeshBasis, strain_jacobians, vertex_strain_form

MU, LAM = 5.0e4, 9.0e4
SIZE, DENSITY, DT = 0.1, 1000.0, 0.01


def random_f(rng, p, scale=0.3, inverted=0):
    f = np.eye(3) + scale * rng.uniform(-1, 1, (p, 3, 3))
    f[:inverted, 2] *= -1
    return f


def fd_gradient(fun, x, h):
    g = np.empty_like(x)
    for i in range(x.size):
        e = np.zeros_like(x)
        e.flat[i] = h
        g.flat[i] = (fun(x + e) - fun(x - e)) / (2 * h)
    return g


# --- material ------------------------------------------------------------------------


def test_snh_stress_and_hessian_match_finite_differences(rng):
    fs = random_f(rng, 12, inverted=3)
    p = _core.snh_pk1(fs, MU, LAM)
    h = _core.snh_hessian(fs, MU, LAM, project=False)
    for f, pk, hk in zip(fs, p, h):
        fd = fd_gradient(lambda x: _core.snh_energy(x[None], MU, LAM)[0], f, 1e-6)
        np.testing.assert_allclose(pk, fd, rtol=0, atol=1e-6 * np.abs(pk).max())
        cols = [
            ((_core.snh_pk1((f + d)[None], MU, LAM) - _core.snh_pk1((f - d)[None], MU, LAM))[0] / 2e-6).reshape(9)
            for d in np.eye(9).reshape(9, 3, 3) * 1e-6
        ]
        np.testing.assert_allclose(hk, np.array(cols).T, rtol=0, atol=1e-6 * np.abs(hk).max())


def test_projected_hessian_is_psd_and_exact_when_psd(rng):
    fs = random_f(rng, 40, scale=0.5, inverted=10)
    proj = _core.snh_hessian(fs, MU, LAM)
    exact = _core.snh_hessian(fs, MU, LAM, project=False)
    for hp, he in zip(proj, exact):
        scale = np.abs(he).max()
        assert np.linalg.eigvalsh(hp).min() >= -1e-9 * scale
        if np.linalg.eigvalsh(he).min() >= 0:
            np.testing.assert_allclose(hp, he, atol=1e-9 * scale)


def test_rest_and_rotations_have_zero_energy_and_stress():
    theta = 0.7
    r = np.array([[np.cos(theta), -np.sin(theta), 0], [np.sin(theta), np.cos(theta), 0], [0, 0, 1]])
    fs = np.stack([np.eye(3), r])
    np.testing.assert_allclose(_core.snh_energy(fs, MU, LAM), 0, atol=1e-9 * MU)
    np.testing.assert_allclose(_core.snh_pk1(fs, MU, LAM), 0, atol=1e-9 * MU)


def test_non_contiguous_input_is_copied_in_logical_order(rng):
    fs = random_f(rng, 5)
    expected = _core.snh_energy(fs, MU, LAM)
    np.testing.assert_array_equal(_core.snh_energy(np.asfortranarray(fs), MU, LAM), expected)
    np.testing.assert_array_equal(_core.snh_energy(np.repeat(fs, 2, axis=0)[::2], MU, LAM), expected)


@pytest.mark.parametrize(
    "bad, match",
    [
        (np.zeros((4, 3)), r"F must have shape \(p, 3, 3\), got \(4, 3\)"),
        (np.zeros((4, 3, 3), dtype=np.float32), "float64"),
        (np.full((1, 3, 3), np.nan), "NaN"),
        ([[1.0, 0, 0], [0, 1, 0], [0, 0, 1]], "numpy"),
    ],
)
def test_material_rejects_bad_arrays(bad, match):
    with pytest.raises(ShapeError, match=match):
        _core.snh_energy(bad, MU, LAM)


@pytest.mark.parametrize("mu, lam", [(-1.0, LAM), (MU, 0.0), (np.nan, LAM)])
def test_material_rejects_bad_parameters(mu, lam):
    with pytest.raises(ConfigError):
        _core.snh_pk1(np.eye(3)[None], mu, lam)


# --- a small reduced model: a block with affine + smooth modes ------------------------


class Block:
    """Affine modes plus 3 waves ``d sin(k.X + phase)`` on a 10 cm block on z = 0."""

    def __init__(self, rng, cubature=10, contacts=True, planes=True):
        self.waves = [(rng.normal(size=3), rng.normal(size=3) * 30, rng.uniform(0, 6)) for _ in range(3)]
        self.n = 15
        g = np.linspace(0.0, SIZE, 4)
        verts = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
        self.total_mass = DENSITY * SIZE**3
        m = self.total_mass / len(verts)
        w = self.values(verts)
        self.mass = m * np.einsum("vin,vim->nm", w, w)
        self.gravity = m * np.einsum("vin,i->n", w, np.array([0, 0, -9.81]))
        pts = rng.uniform(0, SIZE, (cubature, 3))
        self.jacobians = self.jac(pts).reshape(cubature, 9, self.n)
        self.weights = np.full(cubature, SIZE**3 / max(cubature, 1))
        bottom = verts[verts[:, 2] == 0] if contacts else np.zeros((0, 3))
        self.contact_rest = bottom
        self.contact_basis = self.values(bottom)
        self.areas = np.full(len(bottom), SIZE**2 / max(len(bottom), 1))
        self.planes = np.array([[0.0, 0, 1, 0, 0.5]]) if planes else np.zeros((0, 5))

    def values(self, x):
        out = np.zeros((len(x), 3, self.n))
        for j in range(3):
            for i in range(3):
                out[:, i, 3 * j + i] = x[:, j]
        out[:, :, 9:12] = np.eye(3)
        for r, (d, k, ph) in enumerate(self.waves):
            out[:, :, 12 + r] = np.sin(x @ k + ph)[:, None] * d
        return out

    def jac(self, x):
        out = np.zeros((len(x), 3, 3, self.n))
        for i in range(3):
            for j in range(3):
                out[:, i, j, 3 * j + i] = 1.0
        for r, (d, k, ph) in enumerate(self.waves):
            out[:, :, :, 12 + r] = np.cos(x @ k + ph)[:, None, None] * np.outer(d, k)
        return out

    def kwargs(self, **changes):
        kw = dict(
            mass=self.mass,
            gravity_force=self.gravity,
            cubature_jacobians=self.jacobians,
            cubature_weights=self.weights,
            mu=MU,
            lam=LAM,
            contact_basis=self.contact_basis,
            contact_rest=self.contact_rest,
            contact_areas=self.areas,
            planes=self.planes,
            normal_stiffness=2.0e6,
            normal_damping=1.0e3,
            friction_stiffness=1.0e6,
            dt=DT,
            total_mass=self.total_mass,
            tolerance=1e-8,
            max_iterations=50,
        )
        kw.update(changes)
        return kw

    def core(self, **changes):
        return _core.ReducedCore(**self.kwargs(**changes))

    def sliding_state(self):
        q = np.zeros(self.n)
        q[11] = -self.total_mass * 9.81 / SIZE**2 / 2.0e6  # sunk to the resting depth
        q[12:] = 1e-3
        qdot = np.zeros(self.n)
        qdot[9] = 0.2
        return q, qdot


@pytest.fixture
def block(rng):
    return Block(rng)


def test_reduced_gradient_and_hessian_match_finite_differences(block, rng):
    core = block.core()
    q0, qdot = block.sliding_state()
    core.set_state(q0, qdot)
    q = q0 + DT * qdot + 1e-5 * rng.uniform(-1, 1, block.n)
    q[11] -= 1e-5  # approaching: damping active, away from its kink
    grad = core.gradient(q)
    fd = fd_gradient(core.energy, q, 1e-8)
    np.testing.assert_allclose(grad, fd, rtol=0, atol=1e-5 * np.abs(grad).max())
    hess = core.hessian(q, project=False)
    fd_h = np.array([(core.gradient(q + e) - core.gradient(q - e)) / 2e-9 for e in np.eye(block.n) * 1e-9])
    np.testing.assert_allclose(hess, fd_h, rtol=0, atol=1e-5 * np.abs(hess).max())
    proj = core.hessian(q)
    np.testing.assert_allclose(proj, proj.T)
    assert np.linalg.eigvalsh(proj).min() > 0


@pytest.mark.parametrize("solver", ["newton", "prefactored"])
def test_step_converges_to_a_stationary_point(block, solver):
    core = block.core(solver=solver, tolerance=1e-7, max_iterations=500)
    q0, qdot0 = block.sliding_state()
    core.set_state(q0, qdot0)
    np.testing.assert_array_equal(core.contact_forces(), 0.0)
    iterations, residual = core.step()
    assert 1 <= iterations <= (10 if solver == "newton" else 500) and residual < 1e-7
    q1 = core.q
    np.testing.assert_allclose(core.qdot, (q1 - q0) / DT)
    forces = core.contact_forces()
    assert forces.shape == (len(block.areas), 3) and forces[:, 2].sum() > 0
    assert forces[:, 0].sum() < 0, "friction opposes the +x slide"
    # The result minimises the step's incremental potential.
    core.set_state(q0, qdot0)
    grad = core.gradient(q1)
    assert np.linalg.norm(grad) < 1e-4 * np.linalg.norm(block.gravity)


def test_lagged_elastic_hessian_reaches_the_newton_solution(block):
    q0, qdot0 = block.sliding_state()
    cores = {mode: block.core(tolerance=1e-10, max_iterations=100, elastic_hessian=mode) for mode in ("lagged", "every_iteration")}
    for core in cores.values():
        core.set_state(q0, qdot0)
        for _ in range(5):
            core.step()
    lagged, plain = cores["lagged"], cores["every_iteration"]
    d = lagged.q - plain.q
    assert np.sqrt(d @ block.mass @ d / block.total_mass) / DT < 1e-8
    s, p = lagged.stats(), plain.stats()
    assert s["steps"] == p["steps"] == 5 and s["iterations"] >= 5
    assert s["elastic_hessians"] < p["elastic_hessians"]
    assert set(s) >= {"evaluations", "model_iterations", "model_evaluations", "stick_solves", "stick_steps"}
    lagged.reset_stats()
    assert all(v == 0 for v in lagged.stats().values())
    with pytest.raises(ConfigError, match="elastic_hessian"):
        block.core(elastic_hessian="sometimes")


def test_empty_cubature_contacts_and_planes(rng):
    block = Block(rng, cubature=0, contacts=False, planes=False)
    core = block.core()
    iterations, _ = core.step()
    assert iterations == 1
    np.testing.assert_allclose(core.qdot[9:12], [0, 0, -9.81 * DT], atol=1e-12)
    assert core.contact_forces().shape == (0, 3)


def test_non_convergence_raises_and_keeps_the_state(block):
    core = block.core(tolerance=1e-15, max_iterations=1)
    q0, qdot0 = block.sliding_state()
    core.set_state(q0, qdot0)
    with pytest.raises(SolverError, match="did not converge") as info:
        core.step()
    assert info.value.iterations == 1 and info.value.residual > 1e-15
    np.testing.assert_array_equal(core.q, q0)
    core.accept_last_iterate()
    assert not np.array_equal(core.q, q0)
    with pytest.raises(ConfigError):
        core.accept_last_iterate()


def test_reconstruction_matches_numpy(block, rng):
    x = rng.uniform(0, SIZE, (50, 3))
    w = block.values(x)
    q = rng.normal(size=block.n)
    rec = _core.Reconstruction(w, x)
    assert (rec.n_points, rec.n_dofs) == (50, block.n)
    np.testing.assert_allclose(rec.positions(q), x + w @ q, atol=1e-12)
    with pytest.raises(ShapeError, match=r"q must have shape \(15,\), got \(3,\)"):
        rec.positions(q[:3])
    with pytest.raises(ShapeError, match="basis"):
        _core.Reconstruction(w[:10], x)


def test_vertex_forces_sum_the_ring_stresses_and_reject_bad_input(rng):
    mesh = meshes.cheese(resolution=4)
    tet = 7
    x = mesh.vertices + 0.01 * mesh.size * rng.normal(size=mesh.vertices.shape)
    grads, volume = mesh.shape_gradients[tet], mesh.rest_volumes[tet]
    forces = _core.VertexForces(mesh.n_vertices, 1, mesh.tets[tet:tet + 1], grads[None], volume[None], np.array([0]), np.array([2]), MU, LAM)
    deformation = x[mesh.tets[tet]].T @ grads
    expected = -volume * _core.snh_pk1(deformation[None], MU, LAM)[0] @ grads[2]
    np.testing.assert_allclose(forces.forces(x)[0], expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())
    with pytest.raises(ShapeError, match="positions"):
        forces.forces(x[:-1])
    with pytest.raises(ShapeError, match="positions holds NaN"):
        forces.forces(np.where(np.arange(x.size).reshape(x.shape) == 0, np.nan, x))
    with pytest.raises(ConfigError, match="own_corners must be below 4"):
        _core.VertexForces(mesh.n_vertices, 1, mesh.tets[tet:tet + 1], grads[None], volume[None], np.array([0]), np.array([4]), MU, LAM)
    with pytest.raises(ConfigError, match="volumes"):
        _core.VertexForces(mesh.n_vertices, 1, mesh.tets[tet:tet + 1], grads[None], -volume[None], np.array([0]), np.array([2]), MU, LAM)
    with pytest.raises(ShapeError, match="gradients"):
        _core.VertexForces(mesh.n_vertices, 1, mesh.tets[tet:tet + 1], grads[None, :3], volume[None], np.array([0]), np.array([2]), MU, LAM)


def test_residual_estimate_is_the_numpy_residual_and_rejects_bad_input(rng):
    mesh = meshes.cheese(resolution=4)
    tet = 7
    grads, volume = mesh.shape_gradients[tet], mesh.rest_volumes[tet]
    corners = mesh.tets[tet]
    forces = _core.VertexForces(4, 1, np.arange(4)[None], grads[None], volume[None], np.array([0]), np.array([2]), MU, LAM)
    basis = rng.normal(size=(4, 3, 5)) * 0.01 * mesh.size
    rest = mesh.vertices[corners]
    mass, jacobi, gravity = 0.3, np.linalg.inv(np.diag([2.0e3, 3.0e3, 4.0e3])), np.array([0.0, 0.0, -9.81])
    plane = np.array([[0.0, 0.0, 1.0, 1.0]])  # z >= -1: every sample free
    est = _core.ResidualEstimate(forces, basis, rest, np.array([2]), np.array([mass]), jacobi[None], gravity, plane, np.array([2.0, -1.0]),
                                 0.01, 2.0)
    history = [rest[2] + 1e-3 * rng.normal(size=3) for _ in range(2)]
    est.start(np.stack(history)[:, None, :])
    q, c = 0.1 * rng.normal(size=5), rng.normal(size=3)
    rot = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    rot *= np.linalg.det(rot)
    value = est.evaluate(q, c, rot)
    y = rest + basis @ q
    f = -volume * _core.snh_pk1((y.T @ grads)[None], MU, LAM)[0] @ grads[2]
    x = c + rot @ y[2]
    residual = mass * (x - (2.0 * history[1] - history[0])) / 1e-4 - mass * gravity - rot @ f
    du = jacobi @ residual
    assert value == pytest.approx(2.0 * du @ du, rel=1e-12)
    with pytest.raises(ConfigError, match="center and rotation"):
        est.evaluate(q, c)
    with pytest.raises(ShapeError, match="q"):
        est.evaluate(q[:3])
    with pytest.raises(ShapeError, match="q holds NaN"):
        est.record(np.full(5, np.nan))
    with pytest.raises(ShapeError, match="planes"):
        _core.ResidualEstimate(forces, basis, rest, np.array([2]), np.array([mass]), jacobi[None], gravity, plane[:, :3], np.array([2.0, -1.0]), 0.01, 2.0)
    with pytest.raises(ConfigError, match="own"):
        _core.ResidualEstimate(forces, basis, rest, np.array([4]), np.array([mass]), jacobi[None], gravity, plane, np.array([2.0, -1.0]), 0.01, 2.0)
    with pytest.raises(ConfigError, match="target"):
        _core.ResidualEstimate(forces, basis, rest, np.array([2]), np.array([mass]), jacobi[None], gravity, plane, np.array([1.0, 2.0, 3.0]), 0.01, 2.0)


@pytest.mark.parametrize(
    "changes, error, match",
    [
        ({"solver": "gauss-seidel"}, ConfigError, "solver"),
        ({"mu": -1.0}, ConfigError, "mu"),
        ({"max_iterations": 0}, ConfigError, "max_iterations"),
        ({"dt": 0.0}, ConfigError, "dt"),
        ({"tolerance": -1.0}, ConfigError, "tolerance"),
        ({"gravity_force": np.zeros(14)}, ShapeError, r"gravity_force must have shape \(15,\), got \(14,\)"),
        ({"cubature_jacobians": np.zeros((10, 9, 14))}, ShapeError, "cubature_jacobians"),
        ({"contact_basis": np.zeros((15, 3, 15))}, ShapeError, "contact_basis"),
        ({"planes": np.zeros((1, 4))}, ShapeError, "planes"),
        ({"planes": np.array([[0.0, 0, 0, 0, 0.5]])}, ConfigError, "plane"),
        ({"cubature_weights": -np.ones(10)}, ConfigError, "cubature_weights"),
        ({"mass": np.zeros((15, 15))}, ConfigError, "mass"),
        ({"mass": -np.eye(15)}, ConfigError, "positive definite"),
        ({"mass": np.triu(np.ones((15, 15)))}, ConfigError, "symmetric"),
        ({"mass": np.eye(15, dtype=np.float32)}, ShapeError, "float64"),
        ({"contact_rest": np.full((16, 3), np.nan)}, ShapeError, "NaN"),
    ],
)
def test_reduced_core_rejects_bad_inputs(block, changes, error, match):
    with pytest.raises(error, match=match):
        block.core(**changes)


def _vertex_form_case(block, rng):
    """Cubature on every tet of a small box mesh, the block's 15 modes given random values at its vertices."""
    mesh = meshes.box(SIZE, resolution=2)
    values = 0.05 * rng.normal(size=(mesh.n_vertices, 3, block.n))
    tets = np.arange(mesh.n_tets)
    jac = strain_jacobians(MeshBasis(mesh, values), mesh, tets).reshape(mesh.n_tets, 9, block.n)
    cubature = {"cubature_jacobians": np.ascontiguousarray(jac), "cubature_weights": mesh.rest_volumes.copy()}
    return cubature, vertex_strain_form(mesh, tets, "mesh", values)


def test_vertex_form_of_the_cubature_gives_the_energy_and_forces_of_its_jacobians(block, rng):
    cubature, form = _vertex_form_case(block, rng)
    by_points, by_vertices = block.core(**cubature), block.core(**cubature, **form)
    q0, qdot = block.sliding_state()
    for core in (by_points, by_vertices):
        core.set_state(q0, qdot)
    q = q0 + 0.2 * rng.uniform(-1, 1, block.n)
    e = by_vertices.energy(q)
    grad = by_vertices.gradient(q)
    # The Jacobians are held in f32 (relative 6e-8), the vertex rows in f64.
    assert e == pytest.approx(by_points.energy(q), rel=1e-6, abs=1e-9)
    np.testing.assert_allclose(grad, by_points.gradient(q), rtol=0, atol=1e-6 * np.abs(grad).max())
    np.testing.assert_allclose(grad, fd_gradient(by_vertices.energy, q, 1e-8), rtol=0, atol=1e-5 * np.abs(grad).max())
    for core in (by_points, by_vertices):
        core.step()
    np.testing.assert_allclose(by_vertices.q, by_points.q, rtol=0, atol=1e-6 * np.abs(by_points.q).max())


@pytest.mark.parametrize(
    "change, error, match",
    [
        (lambda f: {"cubature_vertex_basis": f["cubature_vertex_basis"]}, ConfigError, "all three or none"),
        (lambda f: {**f, "cubature_tet_vertices": f["cubature_tet_vertices"].astype(np.float64)}, ShapeError, "int64"),
        (lambda f: {**f, "cubature_tet_vertices": -f["cubature_tet_vertices"]}, ShapeError, "indices >= 0"),
        (lambda f: {**f, "cubature_tet_vertices": f["cubature_tet_vertices"] + len(f["cubature_vertex_basis"])}, ConfigError, "below the"),
        (lambda f: {**f, "cubature_vertex_basis": 2.0 * f["cubature_vertex_basis"]}, ConfigError, "reproduce cubature_jacobians"),
        (lambda f: {**f, "cubature_shape_gradients": f["cubature_shape_gradients"][:, :3]}, ShapeError, "cubature_shape_gradients"),
    ],
)
def test_vertex_form_is_checked_against_the_jacobians(block, rng, change, error, match):
    cubature, form = _vertex_form_case(block, rng)
    with pytest.raises(error, match=match):
        block.core(**cubature, **change(form))


def test_state_and_probes_check_their_arguments(block):
    core = block.core()
    with pytest.raises(ShapeError, match=r"q must have shape \(15,\)"):
        core.set_state(np.zeros(3), np.zeros(15))
    with pytest.raises(ShapeError, match="NaN"):
        core.energy(np.full(15, np.inf))
    with pytest.raises(ShapeError):
        core.hessian(np.zeros((15, 1)))
    q = core.q
    q[0] = 1.0  # a copy: the state is untouched
    assert core.q[0] == 0.0


def test_a_bool_is_not_an_iteration_count(block):
    with pytest.raises(ConfigError, match="max_iterations must be an integer >= 1, got True"):
        block.core(max_iterations=True)
