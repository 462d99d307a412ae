import warnings

import meshio
import numpy as np
import pytest
from licrom import FileFormatError, Mesh, MeshError, OutputError, ShapeError, meshes


def test_unit_tet_geometry(unit_tet):
    assert unit_tet.rest_volumes[0] == pytest.approx(1 / 6)
    np.testing.assert_allclose(unit_tet.vertex_masses(600.0), np.full(4, 600 / 6 / 4))
    assert len(unit_tet.boundary_faces) == 4
    assert unit_tet.surface_area == pytest.approx(1.5 + np.sqrt(3) / 2)
    q = unit_tet.quality()
    assert q.min_dihedral_deg == pytest.approx(np.degrees(np.arccos(1 / np.sqrt(3))))
    assert q.max_dihedral_deg == pytest.approx(90.0)


def test_boundary_faces_point_outward():
    m = meshes.box(0.2, resolution=3)
    f = m.boundary_faces
    x = m.vertices
    n = np.cross(x[f[:, 1]] - x[f[:, 0]], x[f[:, 2]] - x[f[:, 0]])
    centre_to_face = x[f].mean(axis=1) - x.mean(axis=0)
    assert np.all((n * centre_to_face).sum(axis=1) > 0)
    # divergence theorem: closed outward surface encloses the volume
    vol = np.einsum("ij,ij->", x[f[:, 0]], n) / 6.0
    assert vol == pytest.approx(m.volume)
    assert m.surface_area == pytest.approx(6 * 0.04)


def test_deformation_gradient_of_affine_map(rng):
    m = meshes.box(0.1, resolution=2)
    a = np.eye(3) + 0.1 * rng.standard_normal((3, 3))
    f = m.deformation_gradients(m.vertices @ a.T + 1.0)
    np.testing.assert_allclose(f, np.broadcast_to(a, f.shape), atol=1e-12)


def test_shape_gradients_sum_to_zero_and_reproduce_linear_fields(rng):
    m = meshes.sphere(0.05, resolution=5)
    g = m.shape_gradients
    np.testing.assert_allclose(g.sum(axis=1), 0.0, atol=1e-9)
    c = rng.standard_normal(3)
    vals = m.vertices @ c
    grad = np.einsum("ta,taj->tj", vals[m.tets], g)
    np.testing.assert_allclose(grad, np.broadcast_to(c, grad.shape), atol=1e-9)


def test_locate_finds_containing_tet(rng):
    m = meshes.box(0.1, resolution=3)
    tets, bary = m.locate(m.centroids)
    np.testing.assert_array_equal(tets, np.arange(m.n_tets))
    np.testing.assert_allclose(bary, 0.25, atol=1e-12)
    p = rng.uniform(-0.049, 0.049, size=(50, 3))
    tets, bary = m.locate(p)
    np.testing.assert_allclose(np.einsum("pa,pai->pi", bary, m.vertices[m.tets[tets]]), p, atol=1e-12)


@pytest.mark.parametrize("suffix", [".vtu", ".msh", ".mesh"])
def test_save_load_round_trip(tmp_path, suffix):
    m = meshes.cheese(resolution=5)
    path = tmp_path / f"cheese{suffix}"
    m.save(path)
    back = Mesh.load(path)
    np.testing.assert_allclose(back.vertices, m.vertices, rtol=1e-12)
    np.testing.assert_array_equal(back.tets, m.tets)
    assert not list(tmp_path.glob(".*"))  # no temporary file left behind


def test_load_drops_unreferenced_vertices(tmp_path):
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [5, 5, 5]])
    path = tmp_path / "extra.vtu"
    meshio.write(path, meshio.Mesh(v, [("tetra", np.array([[0, 1, 2, 3]]))]))
    with pytest.warns(UserWarning, match="dropped 1 vertices"):
        m = Mesh.load(path)
    assert m.n_vertices == 4


def test_inverted_tet_is_reoriented_with_warning():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    with pytest.warns(UserWarning, match="re-oriented 1 inverted tets"):
        m = Mesh(v, np.array([[0, 2, 1, 3]]))
    assert m.rest_volumes[0] > 0
    with pytest.raises(MeshError, match="inverted"):
        Mesh(v, np.array([[0, 2, 1, 3]]), fix_orientation=False)


def test_bad_meshes_raise_named_errors():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    with pytest.raises(MeshError, match="zero volume"):
        Mesh(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]), np.array([[0, 1, 2, 3]]))
    with pytest.raises(MeshError, match="NaN or inf"):
        Mesh(np.where(np.eye(4, 3) == 1, np.nan, v), np.array([[0, 1, 2, 3]]))
    with pytest.raises(MeshError, match="out of range"):
        Mesh(v, np.array([[0, 1, 2, 4]]))
    with pytest.raises(ShapeError, match=r"shape \(m, 4\)"):
        Mesh(v, np.array([[0, 1, 2]]))
    with pytest.raises(ShapeError, match="integers"):
        Mesh(v, np.array([[0.0, 1, 2, 3]]))
    with pytest.raises(MeshError, match="repeat a vertex"):
        Mesh(v, np.array([[0, 1, 1, 3]]))


def test_missing_and_truncated_files(tmp_path):
    with pytest.raises(FileFormatError, match="not found"):
        Mesh.load(tmp_path / "nope.vtu")
    good = tmp_path / "c.vtu"
    meshes.box(0.1, 2).save(good)
    bad = tmp_path / "truncated.vtu"
    bad.write_bytes(good.read_bytes()[:300])
    with pytest.raises(FileFormatError, match="cannot read mesh"):
        Mesh.load(bad)
    tri = tmp_path / "tri.vtu"
    meshio.write(tri, meshio.Mesh(np.eye(3), [("triangle", np.array([[0, 1, 2]]))]))
    with pytest.raises(FileFormatError, match="no tetrahedra"):
        Mesh.load(tri)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(FileFormatError):
            meshes.box(0.1, 2).save(tmp_path / "x.unknownext")


def test_write_errors_name_the_users_path_not_a_temporary_one(tmp_path):
    from licrom.errors import OutputError

    m = meshes.box(0.1, resolution=1)
    for name in ("mesh.xyz", "mesh"):
        with pytest.raises(FileFormatError, match="unknown file extension") as info:
            m.save(tmp_path / name)
        assert f"'{tmp_path / name}'" in str(info.value) and f".{name}." not in str(info.value)
    (tmp_path / "afile").write_text("")
    with pytest.raises(OutputError, match=r"cannot write '.*afile': a part of the path is a file"):
        m.save(tmp_path / "afile" / "m.vtu")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]  # nothing left behind


def test_msh_is_written_in_gmsh_format(tmp_path):
    m = meshes.box(0.1, resolution=2)
    m.save(tmp_path / "m.msh")
    assert (tmp_path / "m.msh").read_bytes().startswith(b"$MeshFormat")  # Gmsh, not ANSYS (meshio's first .msh match)
    assert Mesh.load(tmp_path / "m.msh").same_as(m)


def test_names_over_the_file_system_limit_are_named(tmp_path):
    long = tmp_path / ("m" * 300 + ".msh")
    with pytest.raises(FileFormatError, match="its name is 304 bytes long, over the file system's limit of 255 bytes"):
        Mesh.load(long)
    with pytest.raises(OutputError, match="its name is 304 bytes long, over the file system's limit of 255 bytes"):
        meshes.box(0.1, 2).save(long)
    legal = tmp_path / ("m" * 251 + ".msh")
    meshes.box(0.1, 2).save(legal)
    assert Mesh.load(legal).n_vertices == meshes.box(0.1, 2).n_vertices


@pytest.mark.parametrize("density", [-1, 0, float("nan"), float("inf"), True, "1000", 1j])
def test_vertex_masses_refuse_a_density_out_of_range(density):
    from licrom import ConfigError

    with pytest.raises(ConfigError, match=r"density must be a finite number > 0 \(kg/m\^3\), got"):
        meshes.box(0.1, 1).vertex_masses(density)
    assert meshes.box(0.1, 1).vertex_masses(np.float32(2.0)).sum() == pytest.approx(2.0 * 1e-3)
