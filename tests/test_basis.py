import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from licrom import AffineBasis, ConfigError, MeshBasis, ShapeError, StackedBasis, meshes
from licrom.subspace.basis import RUN_BALANCE, ModalNorm, SubspaceProjector, run_balanced_weights, strain_jacobians, weighted_gram


def _fd_jacobian(basis, points, eps=1e-6):
    out = np.zeros((len(points), 3, 3, basis.n_modes))
    for j in range(3):
        d = np.zeros(3)
        d[j] = eps
        out[:, :, j, :] = (basis.values(points + d) - basis.values(points - d)) / (2 * eps)
    return out


def test_affine_modes_represent_any_affine_map(rng):
    pts = rng.standard_normal((30, 3))
    a = rng.standard_normal((3, 3))
    t = rng.standard_normal(3)
    q = np.concatenate([a.ravel(), t])
    np.testing.assert_allclose(AffineBasis().values(pts) @ q, pts @ a.T + t, atol=1e-12)
    jac = AffineBasis().jacobians(pts) @ q
    np.testing.assert_allclose(jac, np.broadcast_to(a, jac.shape), atol=1e-12)
    np.testing.assert_allclose(AffineBasis().jacobians(pts), _fd_jacobian(AffineBasis(), pts), atol=1e-8)


def test_mesh_basis_interpolates_and_differentiates(rng):
    mesh = meshes.box(0.1, resolution=3)
    modes = rng.standard_normal((mesh.n_vertices, 3, 4))
    b = MeshBasis(mesh, modes)
    np.testing.assert_allclose(b.values(mesh.vertices), modes)
    # a linear field is reproduced exactly everywhere inside
    a = rng.standard_normal((3, 3))
    lin = MeshBasis(mesh, (mesh.vertices @ a.T)[:, :, None])
    pts = rng.uniform(-0.045, 0.045, (40, 3))
    np.testing.assert_allclose(lin.values(pts)[:, :, 0], pts @ a.T, atol=1e-12)
    np.testing.assert_allclose(lin.jacobians(pts)[..., 0], np.broadcast_to(a, (40, 3, 3)), atol=1e-10)
    # inside a tet the gradient of a general field matches finite differences
    c = mesh.centroids[:10]
    np.testing.assert_allclose(b.jacobians(c), _fd_jacobian(b, c, eps=1e-7), rtol=1e-5, atol=1e-5)


def test_identity_basis_maps_q_to_displacements(rng):
    mesh = meshes.box(0.1, resolution=1)
    b = MeshBasis.identity(mesh)
    q = rng.standard_normal(b.n_modes)
    np.testing.assert_allclose(b.values(mesh.vertices) @ q, q.reshape(-1, 3))
    f = mesh.deformation_gradients(mesh.vertices + q.reshape(-1, 3))
    np.testing.assert_allclose(np.eye(3) + b.jacobians(mesh.centroids) @ q, f, atol=1e-12)


def test_stacked_and_projection(rng):
    mesh = meshes.box(0.1, resolution=2)
    extra = MeshBasis(mesh, rng.standard_normal((mesh.n_vertices, 3, 5)))
    b = StackedBasis(AffineBasis(), extra)
    assert b.n_modes == 17
    vals = b.values(mesh.vertices)
    proj = SubspaceProjector(vals, mesh.vertex_masses(1000.0))
    q = rng.standard_normal(17)
    np.testing.assert_allclose(proj.project(vals @ q), q, rtol=1e-8, atol=1e-8)
    # the projection is mass-orthogonal: residual has no component in the subspace
    u = rng.standard_normal((mesh.n_vertices, 3))
    r = u - vals @ proj.project(u)
    np.testing.assert_allclose(proj.reduce(mesh.vertex_masses(1000.0)[:, None] * r), 0, atol=1e-9)
    # a reduced mass the caller formed gives the same projector; one of the wrong size is refused
    given = SubspaceProjector(vals, mesh.vertex_masses(1000.0), reduced_mass=proj.reduced_mass.copy())
    np.testing.assert_array_equal(given.project(u), proj.project(u))
    with pytest.raises(ShapeError, match=r"reduced_mass must have shape \(17, 17\), got \(16, 16\)"):
        SubspaceProjector(vals, mesh.vertex_masses(1000.0), reduced_mass=np.eye(16))


def test_weighted_gram_is_the_weighted_product_and_symmetric(rng):
    a = rng.standard_normal((50, 7))
    w = rng.uniform(0.0, 3.0, 50)
    g = weighted_gram(a, w)
    np.testing.assert_allclose(g, a.T @ (w[:, None] * a), rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(g, g.T)
    assert weighted_gram(a[:, :0], w).shape == (0, 0)


def test_singular_and_bad_bases(rng):
    mesh = meshes.box(0.1, resolution=2)
    twice = StackedBasis(AffineBasis(), AffineBasis())
    with pytest.raises(ConfigError, match="singular"):
        SubspaceProjector(twice.values(mesh.vertices), mesh.vertex_masses(1.0))
    with pytest.raises(ShapeError, match="NaN"):
        MeshBasis(mesh, np.full((mesh.n_vertices, 3, 2), np.nan))
    with pytest.raises(ShapeError, match="shape"):
        MeshBasis(mesh, np.zeros((3, 3, 2)))
    with pytest.raises(ShapeError, match="not a basis"):
        StackedBasis(AffineBasis(), object())


def test_pod_modes_are_mass_orthonormal(rng):
    mesh = meshes.box(0.1, resolution=2)
    snaps = rng.standard_normal((6, mesh.n_vertices, 3))
    b, sigma = MeshBasis.pod(mesh, snaps, 4, density=1000.0)
    m = np.repeat(mesh.vertex_masses(1000.0), 3)
    w = b.modes.reshape(-1, 4)
    np.testing.assert_allclose(w.T @ (m[:, None] * w), np.eye(4), atol=1e-10)
    assert np.all(np.diff(sigma) <= 0)


def _in_span(modes: np.ndarray, field: np.ndarray, masses: np.ndarray) -> float:
    """Relative mass-weighted part of ``field`` (n, 3) outside the span of mass-orthonormal ``modes`` (n, 3, k)."""
    m = np.repeat(masses, 3)
    w, f = modes.reshape(-1, modes.shape[2]), field.reshape(-1)
    rest = f - w @ (w.T @ (m * f))
    return float(np.sqrt(rest @ (m * rest) / (f @ (m * f))))


def test_weighted_pod_minimises_the_weighted_error(rng):
    mesh = meshes.box(0.1, resolution=2)
    masses = mesh.vertex_masses(1.0)
    snaps = rng.standard_normal((5, mesh.n_vertices, 3))
    w = np.array([4.0, 1.0, 0.0, 2.0, 0.5])
    weighted, sigma = MeshBasis.pod(mesh, snaps, 3, weights=w)
    scaled, sigma_scaled = MeshBasis.pod(mesh, snaps * np.sqrt(w)[:, None, None], 3)
    np.testing.assert_allclose(sigma[:4], sigma_scaled[:4], rtol=1e-12)  # the fifth is round-off (weight 0)
    for k in range(3):  # the same modes up to sign
        assert _in_span(weighted.modes, scaled.modes[:, :, k], masses) < 1e-9
    # a snapshot of weight 0 takes no mode: 4 modes span the other four snapshots exactly
    four = MeshBasis.pod(mesh, snaps, 4, weights=w)[0]
    assert max(_in_span(four.modes, snaps[i], masses) for i in (0, 1, 3, 4)) < 1e-9
    assert _in_span(four.modes, snaps[2], masses) > 0.1
    for bad in (np.ones(4), np.array([1.0, -1.0, 1.0, 1.0, 1.0]), np.array([1.0, np.nan, 1.0, 1.0, 1.0])):
        with pytest.raises(ShapeError, match="weights"):
            MeshBasis.pod(mesh, snaps, 2, weights=bad)


def test_run_balanced_pod_keeps_the_gentle_run(rng):
    """Two large deformations of one run take plain POD(2); balanced, the smaller run of another gets its mode."""
    mesh = meshes.box(0.1, resolution=2)
    masses = mesh.vertex_masses(1.0)
    # three mass-orthonormal fields (Gram-Schmidt), so that each is one POD mode
    m3 = np.repeat(masses, 3)
    q, _ = np.linalg.qr(np.sqrt(m3)[:, None] * rng.standard_normal((3 * mesh.n_vertices, 3)))
    a, b, c = ((q[:, k] / np.sqrt(m3)).reshape(mesh.n_vertices, 3) for k in range(3))
    big = np.stack([5.0 * a, 4.5 * b] * 3)  # one run, six frames, 34x the energy of the other
    small = np.stack([1.0 * c] * 4)  # another, four frames
    snaps = np.concatenate([big, small])
    runs = np.array([0] * 6 + [1] * 4)
    norm2 = np.einsum("fni,fni,n->f", snaps, snaps, masses)
    weights = run_balanced_weights(runs, norm2, power=1.0)
    np.testing.assert_allclose(np.bincount(runs, weights=weights * norm2), [1.0, 1.0])
    plain = MeshBasis.pod(mesh, snaps, 2)[0]
    balanced = MeshBasis.pod(mesh, snaps, 2, weights=weights)[0]
    assert _in_span(plain.modes, c, masses) > 0.5
    assert _in_span(balanced.modes, c, masses) < 1e-9


def test_run_balanced_pod_ignores_the_round_off_of_a_run_that_does_not_deform(rng):
    """A free fall's residual is round-off: balanced in full it would become the modes."""
    mesh = meshes.box(0.1, resolution=2)
    masses = mesh.vertex_masses(1.0)
    a = rng.standard_normal((mesh.n_vertices, 3))
    snaps = np.concatenate([np.stack([a * s for s in (1.0, 2.0, 3.0)]), 1e-15 * rng.standard_normal((3, mesh.n_vertices, 3))])
    runs = np.array([0, 0, 0, 1, 1, 1])
    weights = run_balanced_weights(runs, np.einsum("fni,fni,n->f", snaps, snaps, masses))
    assert weights[3] == pytest.approx(weights[0] * 100.0**RUN_BALANCE)  # the noisy run is boosted by at most floor^-power
    assert _in_span(MeshBasis.pod(mesh, snaps, 1, weights=weights)[0].modes, a, masses) < 1e-9


def test_run_balanced_weights_count_each_run_by_its_energy_to_one_minus_the_power():
    runs = np.array([0, 0, 1, 2, 2, 2])
    norm2 = np.array([1.0, 3.0, 16.0, 0.5, 0.25, 0.25])  # run energies 4, 16, 1
    for power in (0.0, 0.5, RUN_BALANCE, 1.0):
        weights = run_balanced_weights(runs, norm2, power=power)
        np.testing.assert_allclose(np.bincount(runs, weights=weights * norm2), np.array([4.0, 16.0, 1.0]) ** (1.0 - power))
    np.testing.assert_array_equal(run_balanced_weights(runs, norm2), run_balanced_weights(runs, norm2, power=RUN_BALANCE))


def test_run_balanced_weights_edge_cases():
    np.testing.assert_array_equal(run_balanced_weights(np.array([3, 3, 7]), np.array([1.0, 3.0, 0.0]), power=1.0), [0.25, 0.25, 25.0])
    np.testing.assert_array_equal(run_balanced_weights(np.array([3, 3, 7]), np.array([1.0, 3.0, 0.0]), floor=0.5, power=1.0), [0.25, 0.25, 0.5])
    with pytest.raises(ConfigError, match="power"):
        run_balanced_weights(np.zeros(2), np.ones(2), power=1.5)
    np.testing.assert_array_equal(run_balanced_weights(np.array([1, 1]), np.zeros(2)), [0.0, 0.0])
    assert run_balanced_weights(np.zeros(0, dtype=int), np.zeros(0)).shape == (0,)
    with pytest.raises(ConfigError, match="floor"):
        run_balanced_weights(np.zeros(2), np.ones(2), floor=2.0)
    with pytest.raises(ShapeError, match="one length"):
        run_balanced_weights(np.zeros(3), np.ones(2))
    with pytest.raises(ShapeError, match="finite"):
        run_balanced_weights(np.zeros(2), np.array([1.0, -1.0]))


class _Wiggly:
    """A basis whose values are linear at the vertices but whose own gradient is not the mesh's (a field between vertices)."""

    n_modes = 1

    def __init__(self, mesh):
        self.mesh = mesh

    def values(self, points):
        p = np.asarray(points, dtype=np.float64)
        return (p + 0.3 * np.sin(40.0 * p))[:, :, None]

    def jacobians(self, points):
        p = np.asarray(points, dtype=np.float64)
        d = 1.0 + 0.3 * 40.0 * np.cos(40.0 * p)
        return (d[:, :, None] * np.eye(3))[..., None]


def test_strain_jacobians_mesh_is_the_fem_gradient_of_the_vertex_values(rng):
    mesh = meshes.cheese(resolution=4)
    basis = _Wiggly(mesh)
    tets = np.arange(0, mesh.n_tets, 3)
    q = np.array([0.01])
    mesh_jac = strain_jacobians(basis, mesh, tets, "mesh")
    # The deformation gradient of the linear FEM with every vertex moved by the basis' values.
    x = mesh.vertices + basis.values(mesh.vertices)[:, :, 0] * q[0]
    f = mesh.deformation_gradients(x)[tets]
    np.testing.assert_allclose(np.eye(3) + mesh_jac @ q, f, atol=1e-12)
    field_jac = strain_jacobians(basis, mesh, tets, "field")
    np.testing.assert_allclose(field_jac, basis.jacobians(mesh.centroids[tets]))
    assert np.abs(field_jac - mesh_jac).max() > 0.1  # the wiggle between vertices: the two differ here
    lin = MeshBasis(mesh, rng.normal(size=(mesh.n_vertices, 3, 2)))  # linear in each tet: both agree
    np.testing.assert_allclose(strain_jacobians(lin, mesh, tets, "field"), strain_jacobians(lin, mesh, tets, "mesh"), atol=1e-10)
    with pytest.raises(ConfigError, match="strain must be one of 'mesh', 'field'"):
        strain_jacobians(lin, mesh, tets, "exact")


@settings(max_examples=40, deadline=None)
@given(k=st.integers(1, 40), coupled=st.integers(0, 8), seed=st.integers(0, 2**32 - 1))
def test_modal_norm_is_the_dense_quadratic_form(k, coupled, seed):
    # A mass matrix with `coupled` leading modes coupled among themselves and mass-orthogonal modes after them (as the
    # body frame's affine and learned modes), the same with one late mode coupled to the first (the block grows to
    # it), and the matrix fully dense: each as q^T M q to round-off.
    rng = np.random.default_rng(seed)
    coupled = min(coupled, k)
    a = rng.normal(size=(k, k))
    dense = a @ a.T + k * np.eye(k)
    leading = np.diag(np.diag(dense))
    leading[:coupled, :coupled] = dense[:coupled, :coupled]
    late = leading.copy()
    late[0, k - 1] = late[k - 1, 0] = 0.5 * dense[0, k - 1]
    q = rng.normal(size=k)
    for m in (dense, leading, late):
        assert ModalNorm(m)(q) == pytest.approx(float(q @ m @ q), rel=1e-12)
