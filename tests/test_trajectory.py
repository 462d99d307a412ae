import dataclasses
import pickle

import numpy as np
import pytest
from licrom import FileFormatError, Plane, Scene, ShapeError, SolverError, Trajectory, meshes
from licrom.records.trajectory import DeferredFrames


def _traj(frames=3):
    m = meshes.box(0.1, 2)
    rng = np.random.default_rng(0)
    u = 1e-3 * rng.standard_normal((frames, m.n_vertices, 3))
    return Trajectory(m.vertices, m.tets, u, u * 10, np.arange(frames) * 0.01, Scene(), info={"source": "test"})


def test_round_trip(tmp_path):
    t = _traj()
    p = t.save(tmp_path / "t", precision="float64")
    assert p.suffix == ".npz"
    back = Trajectory.load(p)
    np.testing.assert_array_equal(back.displacements, t.displacements)
    assert back.scene == t.scene
    assert back.info == {"source": "test"}
    assert not [f for f in tmp_path.iterdir() if f.name.startswith(".")]


def test_float32_storage_is_close(tmp_path):
    t = _traj()
    back = Trajectory.load(t.save(tmp_path / "t.npz"))
    np.testing.assert_allclose(back.displacements, t.displacements, rtol=1e-6, atol=1e-12)


def test_refuses_nan():
    t = _traj()
    u = t.displacements.copy()
    u[1, 2, 0] = np.nan
    with pytest.raises(SolverError, match="NaN"):
        Trajectory(t.rest_positions, t.tets, u, t.velocities, t.times, t.scene)


def test_bad_files(tmp_path):
    with pytest.raises(FileFormatError, match="not found"):
        Trajectory.load(tmp_path / "missing.npz")
    p = _traj().save(tmp_path / "t.npz")
    cut = tmp_path / "cut.npz"
    cut.write_bytes(p.read_bytes()[:200])
    with pytest.raises(FileFormatError, match="truncated or corrupt"):
        Trajectory.load(cut)
    other = tmp_path / "other.npz"
    np.savez(other, a=np.zeros(3))
    with pytest.raises(FileFormatError, match="not a licrom trajectory"):
        Trajectory.load(other)


def test_save_writes_only_what_load_reads(tmp_path):
    # A plane given with a huge normal and offset is stored normalised and loads back.
    t = _traj()
    t.scene = Scene(planes=(Plane(normal=(0, 0, 1e200), offset=-2e199),))
    back = Trajectory.load(t.save(tmp_path / "plane.npz"))
    assert back.scene.planes[0].normal == (0.0, 0.0, 1.0) and back.scene.planes[0].offset == pytest.approx(-0.2)
    # Frames beyond float32 would become inf in the file: refused, and kept in float64 on request.
    t.displacements[1, 0, 0] = 1e39
    with pytest.raises(ShapeError, match="precision='float64'"):
        t.save(tmp_path / "big.npz")
    assert not (tmp_path / "big.npz").exists()
    assert Trajectory.load(t.save(tmp_path / "big.npz", precision="float64")).displacements[1, 0, 0] == 1e39
def test_loose_arrays_are_refused_not_truncated_or_reordered():
    from licrom import ShapeError

    t = _traj()
    with pytest.raises(ShapeError, match="tets must be integer vertex indices, got dtype float64"):
        Trajectory(t.rest_positions, t.tets + 0.5, t.displacements, t.velocities, t.times, t.scene)
    for times in (t.times[::-1], np.array([0.0, 0.01, 0.01])):
        with pytest.raises(ShapeError, match="times must be a 1-D array of strictly increasing times"):
            Trajectory(t.rest_positions, t.tets, t.displacements, t.velocities, times, t.scene)


def test_a_file_with_invalid_contents_is_a_file_format_error(tmp_path):
    from licrom._io import load_npz, save_npz

    header, arrays = load_npz(_traj().save(tmp_path / "t.npz"), "trajectory")
    save_npz(tmp_path / "r.npz", {**arrays, "times": arrays["times"][::-1].copy()}, header)
    with pytest.raises(FileFormatError, match=r"holds invalid data: Trajectory\.times must be"):
        Trajectory.load(tmp_path / "r.npz")


def test_repr_is_one_short_line_not_every_array():
    t = _traj(frames=50)
    text = repr(t)
    assert text == str(t) and "\n" not in text and len(text) < 200
    assert text.startswith("Trajectory(test: 50 frames, t = 0..0.49 s, 27 vertices, 48 tets") and "slope 0 deg, mu 0.5" in text
    # A full and a reduced run of one scene print differently.
    full = dataclasses.replace(t, info={"source": "full"})
    reduced = dataclasses.replace(t, info={"source": "reduced", "frame": "body", "n_modes": 14, "cubature_points": 20})
    assert repr(full).startswith("Trajectory(full: 50 frames")
    assert repr(reduced).startswith("Trajectory(reduced, frame body, n modes 14, cubature points 20: 50 frames")
    impacts = dataclasses.replace(full, impact_displacements=t.displacements[:3], impact_times=np.array([0.001, 0.002, 0.003]))
    assert repr(impacts).startswith("Trajectory(full: 50 frames (+3 impact frames), t = 0..0.49 s")


@pytest.mark.parametrize(("member", "edit", "message"), [
    ("rest_positions", lambda a: np.where(np.arange(len(a))[:, None] == 0, np.nan, a), "member rest_positions holds NaN or inf"),
    ("rest_positions", lambda a: a[:, :2].copy(), r"member rest_positions must have shape \(n, 3\), got \(\d+, 2\)"),
    ("tets", lambda a: np.where(a == 0, 10**6, a), r"member tets holds vertex indices from 1 to 1000000; accepted 0 to \d+"),
    ("tets", lambda a: np.where(a == 0, -1, a), r"member tets holds vertex indices from -1 to \d+; accepted 0 to"),
    ("tets", lambda a: a[:, :3].copy(), r"member tets must have shape \(m, 4\), got \(\d+, 3\)"),
    ("tets", lambda a: a + 0.5, "member tets must hold integer vertex indices"),
    ("times", lambda a: a + 1j, "member times must hold real numbers, it holds dtype complex128"),
])
def test_load_validates_the_mesh_part_naming_the_member(tmp_path, member, edit, message):
    from licrom._io import load_npz, save_npz

    header, arrays = load_npz(_traj().save(tmp_path / "t.npz"), "trajectory")
    save_npz(tmp_path / "bad.npz", {**arrays, member: edit(arrays[member])}, header)
    with pytest.raises(FileFormatError, match=message):
        Trajectory.load(tmp_path / "bad.npz")


def test_a_boolean_format_version_is_refused(tmp_path):
    from licrom._io import load_npz, save_npz

    header, arrays = load_npz(_traj().save(tmp_path / "t.npz"), "trajectory")
    save_npz(tmp_path / "v.npz", arrays, {**header, "version": True})
    with pytest.raises(FileFormatError, match="format version True; this licrom reads version 1 or 2 only"):
        Trajectory.load(tmp_path / "v.npz")


def test_info_that_json_cannot_hold_is_a_config_error_naming_the_entry(tmp_path):
    from licrom import ConfigError

    cycle = {"run": 1}
    cycle["again"] = cycle
    nested = [1]
    nested.append(nested)
    for info, says in (({"weights": np.ones(3)}, r"info\['weights'\] is a ndarray"),  # was numpy's TypeError
                       (cycle, r"info\['again'\] refers back to an entry that holds it \(a cycle\)"),  # was json's ValueError
                       ({"runs": nested}, r"info\['runs'\]\[1\] refers back"),
                       ({"count": np.int64(3)}, r"info\['count'\] is a int64"),
                       ({"tags": {"a", "b"}}, r"info\['tags'\] is a set"),
                       ({("a", 1): 2}, r"info has a key \('a', 1\) of type tuple"),
                       ([("source", "full")], "got list")):
        t = _traj()
        t.info = info
        with pytest.raises(ConfigError, match=r"^Trajectory.info must be a dict of JSON-serialisable values \(dicts, lists, .*; " + says):
            t.save(tmp_path / "t.npz")
        assert not list(tmp_path.iterdir())  # nothing written
    t = _traj()
    t.info = {"source": "full", "sweep": {"mu": [0.1, 0.5], "slope": (10.0, 20.0)}, "n": 3, "ok": True, "none": None, "x": np.float64(2.5)}
    assert Trajectory.load(t.save(tmp_path / "t.npz")).info == {**t.info, "sweep": {"mu": [0.1, 0.5], "slope": [10.0, 20.0]}}


def test_impact_frames_round_trip_as_version_2_and_a_run_without_them_stays_version_1(tmp_path):
    from licrom._io import load_npz

    t = _traj()
    plain = t.save(tmp_path / "plain.npz")
    assert load_npz(plain, "trajectory")[0]["version"] == 1
    assert Trajectory.load(plain).impact_displacements.shape == (0, len(t.rest_positions), 3)
    t.impact_displacements, t.impact_times = t.displacements[:2] * 0.5, np.array([0.003, 0.004])
    t.__post_init__()
    p = t.save(tmp_path / "impacts.npz", precision="float64")
    assert load_npz(p, "trajectory")[0]["version"] == 2
    back = Trajectory.load(p)
    np.testing.assert_array_equal(back.impact_displacements, t.impact_displacements)
    np.testing.assert_array_equal(back.impact_times, t.impact_times)


@pytest.mark.parametrize("impacts, times, error", [
    (np.zeros((2, 5, 3)), [0.1, 0.2], ShapeError),  # another vertex count
    (np.zeros((2, 27, 3)), [0.1], ShapeError),  # one time for two frames
    (np.zeros((2, 27, 3)), [0.2, 0.1], ShapeError),  # times out of order
    (np.full((1, 27, 3), np.inf), [0.1], SolverError),
])
def test_bad_impact_frames_are_refused(impacts, times, error):
    t = _traj()
    with pytest.raises(error, match="impact"):
        dataclasses.replace(t, impact_displacements=impacts, impact_times=np.array(times))


def _deferred(t, build):
    """``t`` with its frames given as one :class:`DeferredFrames` of ``build``."""
    frames = DeferredFrames(t.displacements.shape, build)
    return Trajectory(t.rest_positions, t.tets, frames, frames, t.times, t.scene, info=t.info)


def test_deferred_frames_are_built_on_their_first_read_once_and_read_as_frames_given_at_once(tmp_path):
    t = _traj()
    builds = []

    def build():
        builds.append(len(builds))
        return t.displacements.tolist(), t.velocities.astype(np.float32)  # converted as arrays given at once are

    lazy = _deferred(t, build)
    assert repr(lazy) == repr(t) and lazy.valid.all() and not builds
    given = Trajectory(t.rest_positions, t.tets, t.displacements.tolist(), t.velocities.astype(np.float32), t.times, t.scene)
    for name in ("velocities", "displacements"):
        a = getattr(lazy, name)
        assert a.dtype == np.float64 and np.array_equal(a, getattr(given, name))
    np.testing.assert_array_equal(lazy.positions(1), given.positions(1))
    np.testing.assert_array_equal(lazy.centers_of_mass(), given.centers_of_mass())
    # Saving writes the frames built.
    back = Trajectory.load(lazy.save(tmp_path / "t.npz", precision="float64"))
    assert np.array_equal(back.displacements, given.displacements) and np.array_equal(back.velocities, given.velocities)
    assert builds == [0]
    # A frame array assigned before the first read stays; a pickle holds the frames, not the build.
    lazy = _deferred(t, build)
    lazy.velocities = np.zeros_like(t.velocities)
    assert np.array_equal(lazy.displacements, given.displacements) and not lazy.velocities.any()
    copy = pickle.loads(pickle.dumps(_deferred(t, lambda: (t.displacements, t.velocities))))
    assert np.array_equal(copy.displacements, t.displacements) and np.array_equal(copy.velocities, t.velocities)
    with pytest.raises(AttributeError, match="no attribute 'speeds'"):
        _ = lazy.speeds


def test_deferred_frames_are_refused_as_frames_given_at_once():
    t = _traj()
    frames = DeferredFrames((2, len(t.rest_positions), 3), lambda: (t.displacements, t.velocities))
    with pytest.raises(ShapeError, match=r"both displacements and velocities, with shape \(frames, vertices, 3\) = \(3, 27, 3\)"):
        Trajectory(t.rest_positions, t.tets, frames, frames, t.times, t.scene)
    frames = DeferredFrames(t.displacements.shape, lambda: (t.displacements, t.velocities))
    with pytest.raises(ShapeError, match="both displacements and velocities"):
        Trajectory(t.rest_positions, t.tets, frames, t.velocities, t.times, t.scene)
    # A build's frames are checked when it runs, on the first read.
    bad = t.velocities.copy()
    bad[1, 2, 0] = np.inf
    lazy = _deferred(t, lambda: (t.displacements, bad))
    with pytest.raises(SolverError, match="velocities holds NaN or inf"):
        _ = lazy.displacements
    with pytest.raises(ShapeError, match=r"displacements must have shape \(frames, vertices, 3\) = \(3, 27, 3\), got \(2, 27, 3\)"):
        _ = _deferred(t, lambda: (t.displacements[:2], t.velocities)).velocities
