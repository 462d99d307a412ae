import re
import sys
import warnings

import meshio
import numpy as np
import pytest
from licrom import ConfigError, FileFormatError, Mesh, MeshError, OutputError, ShapeError, meshes


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


@pytest.mark.parametrize("suffix", [".stl", ".ply", ".obj", ".off", ".wkt", ".svg"])
def test_save_refuses_formats_that_cannot_hold_tets(tmp_path, suffix):
    with pytest.raises(FileFormatError, match=rf"cannot write a mesh to '.*m{suffix}': a {suffix} file cannot hold tets \(meshio would "
                                              r"drop them\)\. Accepted: \.mesh, \.meshb, \.msh, \.vtu, \.vtk, "):
        meshes.box(0.1, resolution=1).save(tmp_path / f"m{suffix}")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("suffix, package", [(".xdmf", "h5py"), (".med", "h5py"), (".exo", "netCDF4")])
def test_formats_whose_package_is_missing_name_it(tmp_path, monkeypatch, capsys, suffix, package):
    from licrom.cli.commands import main
    from licrom.errors import MissingDependencyError

    monkeypatch.setitem(sys.modules, package, None)  # not installed
    message = rf"meshio needs the optional package '{package}' for 'm{suffix}' \({suffix} files\), and it is not installed; " \
              rf"install it with: pip install {package}"
    with pytest.raises(MissingDependencyError, match=message):
        meshes.box(0.1, resolution=1).save(tmp_path / f"m{suffix}")
    (tmp_path / f"m{suffix}").write_bytes(b"anything")
    with pytest.raises(MissingDependencyError, match=message):
        Mesh.load(tmp_path / f"m{suffix}")
    assert main(["mesh", "box", "-r", "1", "-o", str(tmp_path / f"out{suffix}")]) == 2
    assert f"pip install {package}" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"m{suffix}"]  # nothing half-written


def test_a_mesh_file_of_too_few_points_or_no_tets_is_a_named_error(tmp_path):
    three = tmp_path / "three.mesh"
    three.write_text("MeshVersionFormatted 1\nDimension 3\nVertices\n3\n0 0 0 0\n1 0 0 0\n0 1 0 0\n"
                     "Tetrahedra\n1\n1 2 3 3 0\nEnd\n")
    with pytest.raises(MeshError, match=r"mesh '.*three\.mesh': mesh vertices must have shape \(n, 3\) with n >= 4, got \(3, 3\)"):
        Mesh.load(three)
    empty = tmp_path / "empty.mesh"
    empty.write_text("MeshVersionFormatted 1\nDimension 3\nVertices\n4\n0 0 0 0\n1 0 0 0\n0 1 0 0\n0 0 1 0\nTetrahedra\n0\nEnd\n")
    with pytest.raises(FileFormatError, match=r"mesh '.*empty\.mesh' holds no tetrahedra \(cell types: none\)"):
        Mesh.load(empty)


@pytest.mark.parametrize("candidates", [0, -1, True, 2.5, "12", None])
def test_locate_refuses_a_candidate_count_out_of_range(candidates):
    m = meshes.box(0.1, resolution=2)
    with pytest.raises(ConfigError, match=rf"Mesh.locate candidates must be an integer >= 1 \(nearest tets examined per point\), "
                                          rf"got {re.escape(repr(candidates))}"):
        m.locate(np.zeros((1, 3)), candidates=candidates)
    tets, _ = m.locate(m.centroids[:3], candidates=np.int64(1))
    np.testing.assert_array_equal(tets, [0, 1, 2])


@pytest.mark.parametrize("suffix", [".dat", ".tec", ".mdpa"])
def test_truncated_files_of_looping_readers_are_named_errors_not_hangs(tmp_path, suffix):
    import threading

    good = tmp_path / f"good{suffix}"
    meshes.box(0.1, resolution=2).save(good)
    assert Mesh.load(good).same_as(meshes.box(0.1, resolution=2))
    cut = tmp_path / f"cut{suffix}"
    cut.write_bytes(good.read_bytes()[:len(good.read_bytes()) // 2])  # meshio's reader would call readline() at the end for ever
    outcome = []

    def load():
        try:
            Mesh.load(cut)
        except Exception as exc:  # the type is what is checked
            outcome.append(exc)

    reader = threading.Thread(target=load, daemon=True)
    reader.start()
    reader.join(timeout=60)
    assert not reader.is_alive(), "Mesh.load did not return"
    assert isinstance(outcome[0], FileFormatError)
    assert re.search(r"cannot read mesh '.*cut\..*' \(truncated or corrupt\?\): .*the end of the file", str(outcome[0]))


def test_nearest_surface_points_match_a_dense_sampling_of_the_surface(rng):
    from licrom.geometry.closest import closest_points_on_triangles

    # every Voronoi region of a triangle: points around it in and out of its plane
    a, b, c = np.array([0.0, 0, 0]), np.array([1.0, 0, 0]), np.array([0.2, 0.8, 0])
    p = rng.uniform(-1.0, 2.0, size=(400, 3))
    near = closest_points_on_triangles(p, a, b, c)
    s, t = np.meshgrid(np.linspace(0, 1, 201), np.linspace(0, 1, 201))
    keep = s + t <= 1
    samples = a + np.outer(s[keep], b - a) + np.outer(t[keep], c - a)
    brute = np.sqrt(((p[:, None] - samples[None]) ** 2).sum(axis=2)).min(axis=1)
    ours = np.linalg.norm(near - p, axis=1)
    assert np.all(ours <= brute + 1e-12) and np.all(ours >= brute - 0.01)  # the grid's spacing bounds the gap
    # the answers lie on the triangle: non-negative barycentric coordinates summing to one, in its plane
    m = np.column_stack([b - a, c - a])
    coef, *_ = np.linalg.lstsq(m, (near - a).T, rcond=None)
    assert np.all(coef >= -1e-12) and np.all(coef.sum(axis=0) <= 1 + 1e-12)
    np.testing.assert_allclose(near[:, 2], 0.0, atol=1e-15)


def test_nearest_surface_points_of_a_box_are_on_its_faces():
    from licrom import meshes

    box = meshes.box((0.2, 0.1, 0.1), resolution=3)
    lo, hi = box.bounds
    outside = np.array([[hi[0] + 0.01, 0.01, 0.02], [0.03, lo[1] - 0.02, -0.01], [hi[0] + 0.01, hi[1] + 0.01, 0.0]])
    expected = np.array([[hi[0], 0.01, 0.02], [0.03, lo[1], -0.01], [hi[0], hi[1], 0.0]])
    np.testing.assert_allclose(box.nearest_surface_points(outside), expected, atol=1e-12)
    inside = np.array([[hi[0] - 0.004, 0.0, 0.0]])
    np.testing.assert_allclose(box.nearest_surface_points(inside), [[hi[0], 0.0, 0.0]], atol=1e-12)
    with pytest.raises(ConfigError, match="candidates"):
        box.nearest_surface_points(outside, candidates=0)
