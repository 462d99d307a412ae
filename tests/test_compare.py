import numpy as np
import pytest
from licrom import Plane, Scene, Trajectory, meshes
from licrom.analysis.compare import (
    compare,
    first_contact_frame,
    nonrigid_error,
    peak_nonrigid_deformation,
    penetration_depths,
    slip_distance,
    time_steps,
    total_rotation,
)
from licrom.errors import ConfigError, ShapeError
from licrom.rigid import center_of_mass


def _sliding_box(speed, frames=21, dt=0.01, sink=0.0):
    m = meshes.box(0.1, 2)
    lift = 0.05 - sink  # box centred at origin: bottom at z = -0.05 + lift
    t = np.arange(frames) * dt
    u = np.zeros((frames, m.n_vertices, 3))
    u[:, :, 0] = speed * t[:, None]
    u[:, :, 2] = lift
    v = np.zeros_like(u)
    v[:, :, 0] = speed
    scene = Scene(planes=(Plane((0, 0, 1), 0.0, 0.5),), dt=dt)
    return Trajectory(m.vertices, m.tets, u, v, t, scene, step_seconds=np.full(frames - 1, 0.01))


def test_slip_and_penetration_of_known_motion():
    traj = _sliding_box(0.5, sink=0.002)
    assert slip_distance(traj) == pytest.approx(0.5 * 0.2)
    np.testing.assert_allclose(penetration_depths(traj), 0.002, atol=1e-12)
    assert slip_distance(_sliding_box(0.0)) == 0.0


def test_compare_identical_and_shifted():
    a = _sliding_box(0.5)
    c = compare(a, a)
    assert c.mean_error == 0.0 and c.final_com_error == 0.0 and c.stick_slip_agree
    b = _sliding_box(0.0)
    c = compare(a, b)
    assert c.slid_full and not c.slid_reduced and not c.stick_slip_agree
    assert c.final_com_error == pytest.approx(0.1 / a.mesh.size)
    assert "DISAGREE" in c.table()


class _RecordedSim:
    """Stands in for a simulation whose step times and iterations are known."""

    def __init__(self, seconds, iterations):
        self.seconds, self.iterations = np.asarray(seconds, float), np.asarray(iterations)

    def run(self, steps, record_every=1):
        assert steps == len(self.seconds) and record_every == steps
        traj = _sliding_box(0.0, frames=2)
        traj.step_seconds, traj.iterations = self.seconds, self.iterations
        return traj


def test_time_steps_skips_the_warmup():
    # The first (warm-up) steps are slow and take many iterations; only the rest count.
    sim = _RecordedSim([5.0, 4.0, 0.001, 0.003, 0.002], [9, 9, 1, 2, 3])
    ms, its = time_steps(sim, 3, warmup=2)
    assert ms == pytest.approx(2.0) and its == pytest.approx(2.0)
    with pytest.raises(ConfigError, match="steps >= 1"):
        time_steps(sim, 0)


def test_licrom_compare_is_the_function_after_the_module_is_imported():
    import importlib

    import licrom

    module = importlib.import_module("licrom.analysis.compare")  # the module of the same name, in its layer folder
    assert licrom.compare is module.compare
    a = _sliding_box(0.5)
    assert licrom.compare(a, a).mean_error == 0.0


def test_frame_errors_are_relative_with_a_floor_for_frames_that_hardly_moved():
    a = _sliding_box(0.0, frames=3)
    a.displacements[:] = 0.0
    a.displacements[2, :, 0] = 0.01
    b = Trajectory(a.rest_positions, a.tets, a.displacements + [0.0, 0.0, 1e-5], a.velocities, a.times, a.scene)
    errors = compare(a, b).frame_errors
    size = a.mesh.size
    # Frames 0 and 1: the full run has not moved, so the error is against 0.1% of the size.
    np.testing.assert_allclose(errors, [1e-5 / (1e-3 * size), 1e-5 / (1e-3 * size), 1e-5 / 0.01], rtol=1e-12)


# ------------------------------------------------------------------------------------------
# non-rigid metrics on synthetic motions x = c + R (Xbar + S(t) Xbar)
# ------------------------------------------------------------------------------------------
_DT = 0.05


def _rot_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rot_x(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _principal_axes(mesh):
    """Centred rest positions and the (3, 3) principal axes (columns) of their mass moments."""
    masses = mesh.vertex_masses(1000.0)
    xbar = mesh.vertices - center_of_mass(mesh.vertices, masses)
    return xbar, np.linalg.eigh(np.einsum("n,ni,nj->ij", masses, xbar, xbar))[1]


def _moving_box(rotations, centres, stretches, planes=()):
    """A 10 x 6 x 4 cm box moved rigidly by (rotations, centres) and stretched.

    ``stretches`` (f, 3) are strains along the principal axes Q of the rest shape's mass
    moments J: ``S_t = Q diag(stretches[t]) Q^T`` commutes with J, so it holds no rotation
    and the body-frame displacement of frame t is exactly ``S_t Xbar``.
    """
    m = meshes.box((0.1, 0.06, 0.04), 2)
    xbar, q = _principal_axes(m)
    strain = np.einsum("ik,fk,jk->fij", q, np.asarray(stretches, dtype=float), q)
    body = xbar[None] + np.einsum("fij,nj->fni", strain, xbar)
    x = np.einsum("fij,fnj->fni", np.asarray(rotations), body) + np.asarray(centres)[:, None, :]
    f = len(x)
    scene = Scene(planes=tuple(planes), dt=_DT)
    return Trajectory(m.vertices, m.tets, x - m.vertices, np.zeros_like(x), np.arange(f) * _DT, scene)


def _tumble(f, rate_z, rate_x, velocity):
    t = np.arange(f) * _DT
    rotations = [_rot_z(rate_z * s) @ _rot_x(rate_x * s) for s in t]
    return rotations, np.outer(t, velocity) + [0.0, 0.0, 0.3]


def _stretch(f, amplitude):
    t = np.arange(f) * _DT
    return amplitude * np.stack([np.sin(3 * t), -0.5 * np.sin(3 * t), 0.2 * t], axis=1)


def test_rigid_motion_does_not_count_as_deformation():
    f = 30
    a = _moving_box(*_tumble(f, 2.0, 0.0, [0.5, 0.0, 0.0]), _stretch(f, 0.05))
    b = _moving_box(*_tumble(f, -1.0, 3.0, [0.0, 1.0, -0.2]), _stretch(f, 0.05))
    assert nonrigid_error(a, b, start=0) == pytest.approx(0.0, abs=1e-10)
    c = compare(a, b)
    assert c.nonrigid_error == pytest.approx(0.0, abs=1e-10)
    # The world-frame error sees only the different rigid motions.
    assert c.mean_error > 0.5


def test_known_deformation_gives_the_known_error():
    f = 30
    a = _moving_box(*_tumble(f, 2.0, 0.0, [0.5, 0.0, 0.0]), _stretch(f, 0.05))
    b = _moving_box(*_tumble(f, 0.0, 1.0, [0.0, 0.3, 0.0]), _stretch(f, 0.06))
    assert nonrigid_error(a, b, start=0) == pytest.approx(0.2, rel=1e-8)
    assert nonrigid_error(b, a, start=0) == pytest.approx(1 / 6, rel=1e-8)
    # A stretch only in the later frames: the error is over the frames counted, summed before dividing.
    late = _stretch(f, 0.05)
    late[:20] = 0.0
    d = _moving_box(*_tumble(f, 0.0, 1.0, [0.0, 0.3, 0.0]), late)
    masses = a.mesh.vertex_masses(a.scene.material.density)
    xbar, q = _principal_axes(a.mesh)
    along = xbar @ q  # coordinates along the principal axes: |S_t Xbar|_M^2 = sum m |diag(s_t) along|^2
    norms = np.array([np.einsum("n,ni,ni->", masses, along * s, along * s) for s in _stretch(f, 0.05)])
    expected = np.sqrt(norms[10:20].sum() / norms[10:].sum())
    assert nonrigid_error(a, d, start=10) == pytest.approx(expected, rel=1e-8)


def test_total_rotation_of_a_steady_spin_is_rate_times_time():
    f, rate = 41, 3.0  # 6 rad: most of a turn, far from the net angle between first and last frame
    rotations, centres = _tumble(f, rate, 0.0, [0.2, 0.0, 0.0])
    traj = _moving_box(rotations, centres, _stretch(f, 0.03))
    assert total_rotation(traj) == pytest.approx(np.degrees(rate * (f - 1) * _DT), rel=1e-9)
    # Turning back adds: a spin out and back is twice the angle, not zero.
    back = np.concatenate([rotations, rotations[-2::-1]])
    traj = _moving_box(back, np.zeros((len(back), 3)), np.zeros((len(back), 3)))
    assert total_rotation(traj) == pytest.approx(2 * np.degrees(rate * (f - 1) * _DT), rel=1e-9)


def test_peak_deformation_of_a_known_stretch():
    f = 5
    strains = np.zeros((f, 3))
    strains[3] = [0.1, 0.0, 0.0]
    traj = _moving_box(*_tumble(f, 1.0, 0.5, [0.3, 0.0, 0.0]), strains)
    # The vertex farthest along the first principal axis moves 10% of its distance along it.
    xbar, q = _principal_axes(traj.mesh)
    expected = 0.1 * np.abs(xbar @ q[:, 0]).max() / traj.mesh.size
    assert peak_nonrigid_deformation(traj) == pytest.approx(expected, rel=1e-9)
    c = compare(traj, _moving_box(*_tumble(f, 0.0, 0.0, [0.0, 0.0, 0.0]), np.zeros((f, 3))))
    assert c.peak_deformation_full == pytest.approx(expected, rel=1e-9)
    assert c.peak_deformation_reduced == pytest.approx(0.0, abs=1e-12)


def _falling_box(planes, frames=21, dt=0.01, speed=0.5, height=0.05, deform_before=0.0):
    """A box falling at ``speed`` onto z = 0 from ``height``; stretched by ``deform_before`` until frame 10."""
    m = meshes.box(0.1, 2)
    t = np.arange(frames) * dt
    u = np.zeros((frames, m.n_vertices, 3))
    u[:, :, 2] = 0.05 + height - speed * t[:, None]
    u[:10] += deform_before * m.vertices
    return Trajectory(m.vertices, m.tets, u, np.zeros_like(u), t, Scene(planes=tuple(planes), dt=dt))


def test_first_contact_frame_and_the_frames_the_error_counts():
    floor = Plane((0, 0, 1), 0.0, 0.5)
    # The bottom face is 0.05 - 0.005 f above the floor: it touches at frame 10.
    a = _falling_box([floor])
    assert first_contact_frame(a) == 10
    assert first_contact_frame(a, contact_tolerance=0.0051) == 9
    assert first_contact_frame(_falling_box([])) is None
    assert first_contact_frame(_falling_box([Plane((0, 0, 1), 1.0, 0.5)])) is None
    # Deformation before the first contact does not count by default; with no contact every frame does.
    b = _falling_box([floor], deform_before=0.1)
    assert nonrigid_error(a, b) == 0.0
    assert compare(a, b).nonrigid_error == 0.0 and compare(a, b).nonrigid_start_time == pytest.approx(0.1)
    assert nonrigid_error(a, b, start=0) > 1e6  # relative to a reference that never deforms
    assert nonrigid_error(b, a, start=0) == pytest.approx(1.0)
    assert nonrigid_error(_falling_box([], deform_before=0.1), _falling_box([])) == pytest.approx(1.0)


def test_nonrigid_error_refuses_mismatched_runs_and_bad_starts():
    a = _falling_box([])
    with pytest.raises(ShapeError, match="same frame times"):
        nonrigid_error(a, _falling_box([], frames=20))
    with pytest.raises(ShapeError, match="same mesh"):
        nonrigid_error(a, _moving_box(*_tumble(21, 0.0, 0.0, [0.0, 0.0, 0.0]), np.zeros((21, 3))))
    for start in (-1, 21, 2.0, True):
        with pytest.raises(ConfigError, match="start"):
            nonrigid_error(a, a, start=start)


def test_summary_and_table_carry_the_deformation_metrics():
    f = 30
    a = _moving_box(*_tumble(f, 2.0, 0.0, [0.5, 0.0, 0.0]), _stretch(f, 0.05))
    b = _moving_box(*_tumble(f, 0.0, 1.0, [0.0, 0.3, 0.0]), _stretch(f, 0.06))
    c = compare(a, b)
    s = c.summary()
    assert s["nonrigid_error"] == pytest.approx(0.2, rel=1e-8)
    assert s["rotation_full"] == pytest.approx(np.degrees(2.0 * (f - 1) * _DT), rel=1e-9)
    assert s["rotation_reduced"] == pytest.approx(np.degrees(1.0 * (f - 1) * _DT), rel=1e-9)
    assert s["peak_deformation_reduced"] == pytest.approx(1.2 * s["peak_deformation_full"], rel=1e-9)
    table = c.table()
    row = next(line for line in table.splitlines() if line.startswith("non-rigid deformation error (from 0 s)"))
    assert row.endswith("  20.00 %")
    assert "total rotation full / reduced" in table and f"{c.rotation_full:.1f} deg" in table


def test_comparison_repr_shows_shapes_not_values():
    a = _sliding_box(0.1)
    text = repr(compare(a, a))
    assert "frame_errors=array(float64, shape=(21,))" in text and "mean_error=0.0" in text and "\n" not in text
