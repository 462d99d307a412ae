import re
import warnings

import meshio
import numpy as np
import pytest
from licrom import ConfigError, FileFormatError, LicromWarning, Mesh, MeshError
from licrom.cli.commands import main
from licrom.geometry.surface import Surface, TetrahedralizeParams, tetrahedralize

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


def box_surface(size=(0.1, 0.1, 0.1)) -> tuple[np.ndarray, np.ndarray]:
    """A closed box surface (8 corners, 12 outward triangles)."""
    v = np.array([[x, y, z] for x in (0, size[0]) for y in (0, size[1]) for z in (0, size[2])], dtype=float)
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4],
                  [1, 5, 7], [1, 7, 3]])
    return v, f


def _tilted_sheet():
    v, f = icosphere()
    v[:, 2] *= 1e-12
    rotation = np.linalg.qr(np.random.default_rng(0).standard_normal((3, 3)))[0]
    return Surface(v @ rotation.T, f), TetrahedralizeParams()


def _cancelling_pair():
    # Two copies of a box, one turned inside out: closed, 3D, enclosing +V - V = 0.
    v, f = box_surface()
    return Surface(np.concatenate([v, v]), np.concatenate([f, f[:, ::-1] + 8])), TetrahedralizeParams()


@pytest.mark.parametrize("case, message", [
    pytest.param(lambda: (Surface(*box_surface((0.1, 0.1, 0.0))), TetrahedralizeParams()), r"flat: its extent along \[0, 0, -?1\] is 0 m",
                 id="zero-thickness"),
    pytest.param(lambda: (Surface(*box_surface((0.1, 0.1, 1e-12))), TetrahedralizeParams()),
                 r"flat: its extent along .* is 1e-12 m, under 1e-06", id="1e-12-thick"),
    pytest.param(lambda: (Surface(icosphere()[0] * [1, 0, 0], icosphere()[1]), TetrahedralizeParams()), "flat", id="collinear"),
    pytest.param(_tilted_sheet, "flat", id="tilted-sheet"),
    pytest.param(lambda: (Surface(icosphere()[0] * 1e300, icosphere()[1]), TetrahedralizeParams()),
                 r"diagonal is 1\.\d+e\+299 m; fTetWild meshes surfaces of 0\.0001 m to 1e\+06 m", id="1e300-coordinates"),
    pytest.param(lambda: (Surface(*icosphere()), TetrahedralizeParams(scale=1e-300)), r"diagonal \(after scale 1e-300\) is 1\.\d+e-301 m",
                 id="scale-1e-300"),
    pytest.param(lambda: (Surface(icosphere()[0] * 1e300, icosphere()[1]), TetrahedralizeParams(scale=1e300)), "diagonal .* overflows",
                 id="overflow-after-scale"),
    pytest.param(_cancelling_pair, "encloses no volume", id="cancelling-volume"),
])
def test_degenerate_surfaces_are_refused_before_ftetwild(case, message):
    surface, params = case()
    with pytest.raises(MeshError, match=message):
        tetrahedralize(surface, params)


def test_surface_size_of_huge_coordinates_does_not_overflow():
    v, f = icosphere()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        huge = Surface(v * 1e300, f)
        assert huge.size == pytest.approx(Surface(v, f).size * 1e300, rel=1e-12)
        assert huge.enclosed_volume == float("inf")  # the true value, past the largest float


def test_edge_lengths_beyond_the_memory_limit_are_refused_before_meshing(monkeypatch):
    surface = Surface(*icosphere())
    with pytest.raises(ConfigError, match=r"TetrahedralizeParams.edge_length=1e-06 \(--edge-length; a 1.73e-07 m edge\) needs about "
                                          r".* tets, .* over the memory limit of .*; an edge length of about .* or more fits"):
        tetrahedralize(surface, TetrahedralizeParams(edge_length=1e-6))
    monkeypatch.setenv("LICROM_MEMORY_LIMIT", "1M")
    with pytest.raises(ConfigError, match=r"edge_length=0\.05 .* over the memory limit of 1 MiB \(LICROM_MEMORY_LIMIT=1M\)"):
        tetrahedralize(surface)


# Stand-ins for pytetwild, put first on the child process's path: a deterministic mesher (the
# corners of the input's box, 6 tets, shifted by every argument), one that segfaults, one out of memory.
FAKE_PYTETWILD = {
    "exact": '''
import numpy as np

def tetrahedralize(vertices, faces, *, edge_length_fac, epsilon, stop_energy, num_opt_iter, optimize, coarsen, quiet):
    assert vertices.dtype == np.float64 and faces.dtype == np.int32 and quiet
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    shift = edge_length_fac * 1e-3 + epsilon * 1e-5 + stop_energy * 1e-7 + num_opt_iter * 1e-9 + optimize * 1e-11 + coarsen * 1e-13
    tets = np.array([[0, 1, 3, 7], [0, 3, 2, 7], [0, 2, 6, 7], [0, 6, 4, 7], [0, 4, 5, 7], [0, 5, 1, 7]], dtype=np.int32)
    return corners * (1 + faces.sum() * 1e-9) + shift, tets
''',
    "segfault": "import ctypes\n\ndef tetrahedralize(*args, **kwargs):\n    ctypes.string_at(0)\n",
    "bad_alloc": "def tetrahedralize(*args, **kwargs):\n    raise MemoryError('std::bad_alloc')\n",
}


def _fake_pytetwild(tmp_path, monkeypatch, kind):
    folder = tmp_path / kind
    folder.mkdir()
    (folder / "pytetwild.py").write_text(FAKE_PYTETWILD[kind])
    monkeypatch.setenv("PYTHONPATH", str(folder))
    return folder


def test_ftetwild_runs_in_a_child_process_with_the_in_process_result(tmp_path, monkeypatch):
    import importlib.util

    folder = _fake_pytetwild(tmp_path, monkeypatch, "exact")
    spec = importlib.util.spec_from_file_location("fake_pytetwild", folder / "pytetwild.py")
    fake = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(fake)
    v, f = icosphere()
    params = TetrahedralizeParams(edge_length=0.3, epsilon=0.02, stop_energy=7.5, max_iterations=3, coarsen=True)
    mesh = tetrahedralize(Surface(v, f), params)
    vertices, tets = fake.tetrahedralize(v, f.astype(np.int32), edge_length_fac=0.3, epsilon=0.02, stop_energy=7.5, num_opt_iter=3,
                                         optimize=True, coarsen=True, quiet=True)
    expected = Mesh(vertices, tets.astype(np.int64)[:, [0, 2, 1, 3]], fix_orientation=False)  # licrom's orientation
    assert mesh.same_as(expected)  # bit for bit: the vertices went through files and back unchanged


@pytest.mark.parametrize("kind, message", [
    ("segfault", r"fTetWild crashed on this surface: killed by SIGSEGV \(Segmentation fault\)"),
    ("bad_alloc", r"fTetWild ran out of memory \(std::bad_alloc\): use a larger edge length"),
])
def test_a_crash_of_ftetwild_is_a_mesh_error(tmp_path, monkeypatch, kind, message):
    _fake_pytetwild(tmp_path, monkeypatch, kind)
    with pytest.raises(MeshError, match=message):
        tetrahedralize(Surface(*icosphere()), TetrahedralizeParams(**COARSE))


def test_the_real_ftetwild_crashing_on_a_flat_box_ends_the_child_not_this_process():
    from licrom.geometry.surface import _ftetwild

    v, f = box_surface((0.1, 0.1, 0.0))  # what the checks refuse: here handed to fTetWild directly
    with pytest.raises(MeshError, match="fTetWild crashed on this surface: killed by SIGSEGV"):
        _ftetwild(v, f, {"edge_length_fac": 0.05, "epsilon": 1e-3, "quiet": True})


@pytest.fixture(scope="module")
def open_surface(tmp_path_factory):
    """The sphere with its top cap cut off (a hole of 24 edges), as a file."""
    v, f = icosphere()
    path = tmp_path_factory.mktemp("open") / "cut.obj"
    meshio.write(path, meshio.Mesh(v, [("triangle", f[v[f].mean(axis=1)[:, 2] <= 0.03])]))
    return path


def test_an_open_surface_is_refused_unless_allowed(open_surface, capsys):
    surface = Surface.load(open_surface)
    with pytest.raises(MeshError, match=r"not closed \(24 edges belong to one triangle only, 0 to three or more\): fTetWild would fill "
                                        r"it into a solid of another shape .* pass allow_open=True \(--allow-open\)"):
        tetrahedralize(surface, TetrahedralizeParams(**COARSE))
    with pytest.raises(ConfigError, match="allow_open must be True or False, got 'yes'"):
        tetrahedralize(surface, TetrahedralizeParams(**COARSE), allow_open="yes")
    with pytest.warns(LicromWarning, match=r"the open surface was meshed into a solid of another shape: the tets hold .* m\^3 against "
                                           r".* m\^3 inside the surface with its holes capped flat \(.* %\); their bounds .* against "
                                           r"the surface's .* \(up to .* m beyond them, .* m short of them\)"):
        mesh = tetrahedralize(surface, TetrahedralizeParams(**COARSE), allow_open=True)
    assert mesh.n_tets > 50
    assert main(["mesh", str(open_surface), "--edge-length", "0.2", "--epsilon", "0.01"]) == 2
    assert "not closed" in capsys.readouterr().err
    assert main(["mesh", str(open_surface), "--edge-length", "0.2", "--epsilon", "0.01", "--allow-open"]) == 0
    captured = capsys.readouterr()
    assert "NOT the surface's shape: the tets hold" in captured.out and "capped flat" in captured.out
    assert "LicromWarning" not in captured.err  # said once, in the summary
    assert main(["mesh", "box", "--allow-open"]) == 2
    assert "--allow-open: only for surface files" in capsys.readouterr().err


@pytest.mark.parametrize("argv, message", [
    pytest.param(["--scale", "1e-300"], r"diagonal \(after scale 1e-300\) is 1.73e-301 m", id="scale"),
    pytest.param(["--edge-length", "1e-6"], r"--edge-length; .* over the memory limit", id="edge-length"),
])
def test_mesh_command_refuses_what_would_crash_ftetwild(sphere_files, capsys, argv, message):
    assert main(["mesh", str(sphere_files / "ball.obj"), *argv]) == 2
    assert re.search(message, capsys.readouterr().err)


def test_mesh_command_scales_tiny_coordinates_up_without_overflow(tmp_path, capsys):
    v, f = icosphere()
    path = tmp_path / "tiny.obj"
    meshio.write(path, meshio.Mesh(v * 1e-299, [("triangle", f)]))  # a 0.1 m ball in units of 1e299 m
    assert main(["mesh", str(path), "--scale", "1e299", "--edge-length", "0.2", "--epsilon", "0.01"]) == 0
    assert re.search(r"surface volume    0.000505\d* m\^3 \(tets [+-]\d", capsys.readouterr().out)
