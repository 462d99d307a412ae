import numpy as np
import pytest
from licrom import AffineBasis, ConfigError, MeshBasis, ShapeError, StackedBasis, meshes
from licrom.basis import SubspaceProjector, strain_jacobians


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
