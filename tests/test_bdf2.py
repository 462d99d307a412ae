"""BDF2 in the full and the reduced simulations: the recurrence, its order and (lack of) damping, friction."""

import json
import math

import numpy as np
import pytest
from licrom import ConfigError, InitialState, Material, Scene, SolverError, SolverParams, meshes
from licrom.data.scene_file import load_scene
from licrom.full import FullSim
from licrom.reduced.base import ReducedSim
from licrom.reduced.body import BodyFrameSim
from licrom.subspace.basis import AffineBasis
from licrom.subspace.body_basis import BodyFrameBasis
from licrom.subspace.cubature import Cubature
from test_full_sim import _box_on_incline

SOFT = Material(youngs_modulus=2e4, poisson_ratio=0.3, density=1000.0)


# --- the scene option -----------------------------------------------------------------------


def test_integrator_is_checked_and_round_trips():
    with pytest.raises(ConfigError, match=r"Scene.integrator must be one of 'backward_euler', 'bdf2', got 'rk4'"):
        Scene(integrator="rk4")
    scene = Scene(integrator="bdf2")
    assert Scene.from_json(scene.to_json()) == scene
    old = json.loads(Scene().to_json())
    del old["integrator"]  # written before the option existed
    assert Scene.from_dict(old).integrator == "backward_euler"


def test_scene_file_reads_the_integrator(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('version = 1\n[object]\nmesh = "box"\nresolution = 1\n[time]\ndt = 0.005\nintegrator = "bdf2"\n')
    assert load_scene(path).scene.integrator == "bdf2"
    path.write_text('version = 1\n[object]\nmesh = "box"\n[time]\nintegrator = "bdf3"\n')
    with pytest.raises(ConfigError, match=r"time.integrator must be one of 'backward_euler', 'bdf2', got 'bdf3'"):
        load_scene(path)


# --- the recurrence -------------------------------------------------------------------------


def _free_fall(integrator="bdf2"):
    v0 = np.array([0.5, -0.2, 1.0])
    scene = Scene(material=Material(1e7, 0.3), planes=(), integrator=integrator, initial=InitialState(translation=(0, 0, 1), velocity=tuple(v0)),
                  solver=SolverParams(tolerance=1e-11, reduced_tolerance=1e-11))
    return meshes.box(0.1, resolution=2), scene, v0


@pytest.mark.parametrize("simulation", ["full", "world", "body"])
def test_free_fall_is_exact(simulation):
    """BDF2 is exact for a motion quadratic in time, and starts from the history of a free fall."""
    mesh, scene, v0 = _free_fall()
    if simulation == "full":
        sim = FullSim(mesh, scene)
    elif simulation == "world":
        sim = ReducedSim(AffineBasis(), mesh, scene, cubature=Cubature.full(mesh))
    else:
        sim = BodyFrameSim(BodyFrameBasis(mesh), mesh, scene, cubature=Cubature.full(mesh))
    traj = sim.run(50)
    t, g = traj.times, np.array(scene.gravity)
    w = mesh.vertex_masses(scene.material.density)
    w = w / w.sum()
    centre = np.einsum("fnk,n->fk", traj.rest_positions + traj.displacements, w)
    velocity = np.einsum("fnk,n->fk", traj.velocities, w)
    exact = w @ traj.rest_positions + np.array([0, 0, 1.0]) + np.outer(t, v0) + 0.5 * np.outer(t * t, g)
    worst = max(np.abs(centre - exact).max(), np.abs(velocity - (v0 + np.outer(t, g))).max())
    print(f"free fall, BDF2 ({simulation}): max deviation from the exact fall {worst:.2e} (m, m/s); "
          f"backward Euler's is h^2 g k / 2 = {0.5 * scene.dt**2 * 9.81 * 50:.2e} m after 50 steps")
    assert worst < 1e-9
    assert traj.converged.all()


def test_set_state_restarts_the_history():
    mesh, scene, _ = _free_fall()
    moved = FullSim(mesh, scene)
    moved.run(5)
    x, v = moved.positions, moved.velocities
    moved.set_state(x, v)
    moved.run(3)
    fresh = FullSim(mesh, scene)
    fresh.set_state(x, v)
    fresh.run(3)
    np.testing.assert_array_equal(moved.positions, fresh.positions)
    np.testing.assert_array_equal(moved.velocities, fresh.velocities)


def test_failed_bdf2_step_keeps_the_history():
    mesh, scene, _ = _box_on_incline(30.0, 0.3, speed=0.5, material=SOFT)
    scene = scene.replace(integrator="bdf2")
    ref = FullSim(mesh, scene)
    ref.run(3)
    sim = FullSim(mesh, scene)
    sim.run(2)
    x, v = sim.positions, sim.velocities
    sim.scene = scene.replace(solver=SolverParams(tolerance=1e-14, reduced_tolerance=1e-14, max_iterations=1))
    with pytest.raises(SolverError):
        sim.step()
    np.testing.assert_array_equal(sim.positions, x)
    np.testing.assert_array_equal(sim.velocities, v)
    sim.scene = scene
    sim.step()
    np.testing.assert_array_equal(sim.positions, ref.positions)


# --- accuracy on a smooth problem: an elastic cube oscillating and spinning in free space ----------


def _oscillating_cube(integrator, h):
    mesh = meshes.box(0.1, resolution=2)
    scene = Scene(material=SOFT, planes=(), gravity=(0.0, 0.0, 0.0), dt=h, integrator=integrator, solver=SolverParams(tolerance=1e-11, reduced_tolerance=1e-11))
    sim = FullSim(mesh, scene, device="cpu")
    arm = mesh.vertices - mesh.vertices.mean(axis=0)
    v = 3.0 * arm * np.array([1.0, -0.3, -0.3]) + np.cross([0.0, 0.0, 2.0], arm)  # stretch along x, spin about z
    sim.set_state(mesh.vertices, v - sim.masses @ v / sim.masses.sum())
    return sim


def _total_energy(sim):
    return 0.5 * float(np.sum(sim.masses[:, None] * sim.velocities**2)) + sim.energy(terms="elastic")


def test_bdf2_dissipates_far_less_than_backward_euler():
    kept = {}
    for integrator in ("backward_euler", "bdf2"):
        sim = _oscillating_cube(integrator, 1e-3)
        e0 = _total_energy(sim)
        sim.run(100)  # about 4 periods of the stretch mode, some 25 steps a period
        kept[integrator] = _total_energy(sim) / e0
    print(f"energy kept after 100 steps of 1 ms: backward Euler {kept['backward_euler']:.3f}, BDF2 {kept['bdf2']:.4f}")
    assert kept["bdf2"] > 0.95
    assert kept["backward_euler"] < 0.7
    assert 1.0 - kept["bdf2"] < 0.1 * (1.0 - kept["backward_euler"])


def test_bdf2_converges_at_second_order_and_backward_euler_at_first():
    duration = 0.04
    reference = _oscillating_cube("bdf2", duration / 2560)
    reference.run(2560)
    errors = {}
    for integrator in ("backward_euler", "bdf2"):
        errors[integrator] = []
        for steps in (40, 80, 160):
            sim = _oscillating_cube(integrator, duration / steps)
            sim.run(steps)
            errors[integrator].append(np.abs(sim.positions - reference.positions).max())
    orders = {k: [math.log2(e[i] / e[i + 1]) for i in range(2)] for k, e in errors.items()}
    print(f"errors at h = 1, 0.5, 0.25 ms: {errors}; observed orders {orders}")
    assert 0.8 < orders["backward_euler"][-1] < 1.2
    assert 1.8 < orders["bdf2"][-1] < 2.2
    assert errors["bdf2"][-1] < 0.05 * errors["backward_euler"][-1]
