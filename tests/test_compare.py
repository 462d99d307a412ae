import numpy as np
import pytest

from licrom import Plane, Scene, Trajectory, meshes
from licrom.compare import compare, penetration_depths, slip_distance, time_steps
from licrom.errors import ConfigError


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
