import meshio
import numpy as np
import pytest
from licrom import ConfigError, FileFormatError, Mesh, MeshError
from licrom.cli import main
from licrom.surface import Surface, TetrahedralizeParams, tetrahedralize

# Coarse settings so that a test meshes in about a second.
COARSE = {"edge_length": 0.2, "epsilon": 0.01}


def icosphere(radius: float = 0.05, subdivisions: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """A closed triangulated sphere with outward-facing triangles."""
    t = (1 + 5**0.5) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
         (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6),
             (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    points = [np.array(p, dtype=float) / np.linalg.norm(p) for p in v]
    for _ in range(subdivisions):
        def mid(a: int, b: int, middle: dict[tuple[int, int], int]) -> int:
            key = (min(a, b), max(a, b))
            if key not in middle:
                m = points[a] + points[b]
                points.append(m / np.linalg.norm(m))
                middle[key] = len(points) - 1
            return middle[key]

        refined, middle = [], {}
        for a, b, c in faces:
            ab, bc, ca = mid(a, b, middle), mid(b, c, middle), mid(c, a, middle)
            refined += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = refined
    return radius * np.array(points), np.array(faces)


@pytest.fixture(scope="module")
def sphere_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("surfaces")
    v, f = icosphere()
    for suffix in (".obj", ".stl"):
        meshio.write(d / f"ball{suffix}", meshio.Mesh(v, [("triangle", f)]))
    return d


def test_surface_reads_a_closed_sphere(sphere_files):
    for name in ("ball.obj", "ball.stl"):
        s = Surface.load(sphere_files / name)
        assert s.is_closed and len(s.faces) == 320
        # An inscribed polyhedron: a little less than the ball's volume.
        assert 0.95 * 4 / 3 * np.pi * 0.05**3 < s.enclosed_volume < 4 / 3 * np.pi * 0.05**3
    assert "closed=True" in repr(s)
    assert not Surface(s.vertices, s.faces[1:]).is_closed


def test_tetrahedralize_fills_the_surface(sphere_files, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    surface = Surface.load(sphere_files / "ball.obj")
    mesh = tetrahedralize(surface, TetrahedralizeParams(**COARSE))
    assert mesh.n_tets > 50
    assert mesh.rest_volumes.min() > 0  # every tet positively oriented, none flat
    assert mesh.volume == pytest.approx(surface.enclosed_volume, rel=0.02)
    lo, hi = mesh.bounds
    np.testing.assert_allclose(hi - lo, 0.1, rtol=0.03)
    # Scaled input: a ball modelled in mm comes out in m.
    scaled = tetrahedralize(Surface(surface.vertices * 1000, surface.faces), TetrahedralizeParams(**COARSE, scale=1e-3))
    assert scaled.volume == pytest.approx(surface.enclosed_volume, rel=0.02)
    assert list(tmp_path.iterdir()) == []  # the mesher's scratch files stay out of the working directory


def test_mesh_command_tetrahedralises_a_surface(sphere_files, tmp_path, capsys):
    out = tmp_path / "ball.msh"
    assert main(["mesh", str(sphere_files / "ball.stl"), "--edge-length", "0.2", "--epsilon", "0.01", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "320 triangles, closed" in text and "surface volume" in text and "dihedral" in text
    mesh = Mesh.load(out)
    assert mesh.rest_volumes.min() > 0
    assert mesh.volume == pytest.approx(Surface.load(sphere_files / "ball.stl").enclosed_volume, rel=0.02)


@pytest.mark.parametrize("key, value", [("edge_length", 0.0), ("edge_length", 1.5), ("epsilon", 0.5), ("stop_energy", 2.0),
                                        ("max_iterations", -1), ("scale", 0.0), ("edge_length", float("nan"))])
def test_params_refuse_out_of_range(key, value):
    with pytest.raises(ConfigError, match=f"TetrahedralizeParams.{key}"):
        TetrahedralizeParams(**{key: value})


def test_bad_surfaces_are_named_errors(tmp_path, capsys):
    with pytest.raises(FileFormatError, match="not found"):
        Surface.load(tmp_path / "missing.obj")
    junk = tmp_path / "junk.stl"
    junk.write_bytes(b"\x00\x01 definitely not an stl")
    with pytest.raises(FileFormatError, match=r"junk\.stl"):
        Surface.load(junk)
    with pytest.raises(MeshError, match="out of range"):
        Surface(np.zeros((3, 3)), np.array([[0, 1, 5]]))
    assert main(["mesh", "box", "--edge-length", "0.1"]) == 2
    assert "--edge-length: only for surface files" in capsys.readouterr().err
    assert main(["mesh", str(tmp_path / "missing.obj")]) == 2
    assert "surface file not found" in capsys.readouterr().err
