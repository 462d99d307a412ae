"""The reduced runtime tied to the full simulation and to analytic motion."""

import math

import numpy as np
import pytest
from licrom import (
    AffineBasis,
    BodyFrameBasis,
    BodyFrameSim,
    ConfigError,
    ContactParams,
    FullSim,
    InitialState,
    Material,
    MeshBasis,
    Plane,
    ReducedSim,
    Scene,
    ShapeError,
    SolverError,
    SolverParams,
    StackedBasis,
    meshes,
)
from licrom.analysis.compare import compare
from licrom.subspace.cubature import ContactPoints, Cubature

G = 9.81
STIFF = Material(youngs_modulus=1e7, poisson_ratio=0.3, density=1000.0)
TIGHT = SolverParams(tolerance=1e-11, reduced_tolerance=1e-11, max_iterations=100)


def _incline_scene(theta_deg, mu, dt=0.01, **kw):
    t = math.radians(theta_deg)
    # The 0.1 m box starts resting at its equilibrium penetration, so the lagged normal
    # force (hence friction) is right from the first step.
    depth = STIFF.density * 0.1 * G * math.cos(t) / kw.get("contact", ContactParams()).normal_stiffness
    # Gravity tilted instead of the plane, so "along the slope" is the x axis.
    return Scene(
        material=STIFF,
        planes=(Plane((0, 0, 1), 0.05 - depth, mu),),
        gravity=(G * math.sin(t), 0.0, -G * math.cos(t)),
        dt=dt,
        **kw,
    )


@pytest.mark.parametrize("viscosity", [0.0, 400.0])
@pytest.mark.parametrize("integrator", ["backward_euler", "bdf2"])
def test_identity_basis_reproduces_full_simulation(integrator, viscosity):
    # With a viscosity both add the same Kelvin-Voigt term (the full one per tet, the reduced one per cubature tet).
    mesh = meshes.box((0.1, 0.08, 0.06), resolution=2)
    scene = Scene(
        material=Material(youngs_modulus=2e4, poisson_ratio=0.35, viscosity=viscosity),
        planes=(Plane.incline(25.0, 0.3, offset=0.045), Plane((-1, 0, 0.2), 0.2, 0.6)),
        contact=ContactParams(normal_stiffness=1e6, normal_damping=50.0, friction_stiffness=1e6),
        solver=TIGHT,
        initial=InitialState(rotation=(0.2, 0.1, 0.0), velocity=(0.3, 0.0, -0.2)),
        integrator=integrator,
    )
    full = FullSim(mesh, scene).run(40)
    reduced = ReducedSim(MeshBasis.identity(mesh), mesh, scene, cubature=Cubature.full(mesh)).run(40)
    assert full.converged.all() and reduced.converged.all()
    scale = np.abs(full.displacements).max()
    assert scale > 0.01  # it moved and touched (contact + friction active)
    err = np.abs(reduced.displacements - full.displacements).max() / scale
    print(f"identity basis vs full ({integrator}, viscosity {viscosity:g} Pa s): max relative position difference {err:.2e}")
    # The reduced system holds its Jacobians in single precision (relative rounding 6e-8): that alone moves the
    # result by about 1.5e-8 here, where any error of a term would show at 1e-4 or more.
    assert err < 1e-7


def test_affine_free_fall_is_discrete_backward_euler():
    mesh = meshes.box(0.1, 2)
    scene = Scene(material=STIFF, planes=(), solver=TIGHT, initial=InitialState(velocity=(0.5, 0, 1.0)))
    traj = ReducedSim(AffineBasis(), mesh, scene).run(50)
    h, g = scene.dt, np.array(scene.gravity)
    x, v = np.zeros(3), np.array([0.5, 0, 1.0])
    for _ in range(50):
        x, v = x + h * v + h * h * g, v + h * g
    np.testing.assert_allclose(traj.displacements[-1], np.broadcast_to(x, (mesh.n_vertices, 3)), atol=1e-10)


def test_affine_rigid_rotation_has_no_elastic_force():
    mesh = meshes.cheese(resolution=6)
    scene = Scene(material=STIFF, planes=(), gravity=(0, 0, 0), solver=TIGHT, initial=InitialState(rotation=(0.4, -1.1, 0.7)))
    sim = ReducedSim(AffineBasis(), mesh, scene)
    start = sim.positions
    d0 = np.linalg.norm(mesh.vertices[:, None] - mesh.vertices[None], axis=2)
    np.testing.assert_allclose(np.linalg.norm(start[:, None] - start[None], axis=2), d0, atol=1e-12)
    for _ in range(5):
        sim.step()
    np.testing.assert_allclose(sim.positions, start, atol=1e-10)
    with pytest.raises(ConfigError, match="strain must be one of 'mesh', 'field'"):
        ReducedSim(AffineBasis(), mesh, scene, strain="continuous")


@pytest.mark.parametrize("theta, mu", [(20.0, 0.2), (30.0, 0.3), (35.0, 0.5)])
def test_affine_box_slides_with_coulomb_acceleration(theta, mu):
    t = math.radians(theta)
    assert math.tan(t) > mu
    mesh = meshes.box(0.1, 2)
    scene = _incline_scene(theta, mu)
    traj = ReducedSim(AffineBasis(), mesh, scene).run(100)
    com_v = traj.velocities.mean(axis=1)[:, 0]
    a = np.polyfit(traj.times[40:], com_v[40:], 1)[0]
    expected = G * (math.sin(t) - mu * math.cos(t))
    print(f"theta={theta} mu={mu}: a={a:.4f} expected {expected:.4f}")
    assert a == pytest.approx(expected, rel=0.02)


@pytest.mark.parametrize("theta, mu", [(10.0, 0.3), (20.0, 0.5)])
def test_affine_box_sticks_below_friction_angle(theta, mu):
    mesh = meshes.box(0.1, 2)
    scene = _incline_scene(theta, mu)
    traj = ReducedSim(AffineBasis(), mesh, scene).run(100)
    slide = traj.displacements[-1, :, 0].mean()
    print(f"theta={theta} mu={mu}: slid {1e3 * slide:.4f} mm in 1 s")
    assert abs(slide) < 1e-4


def test_affine_box_slides_to_rest_at_analytic_distance():
    # Backward Euler stops early by about mu g h / v0 (0.7 % here).
    mu, v0 = 0.3, 2.0
    mesh = meshes.box(0.1, 2)
    scene = _incline_scene(0.0, mu, dt=0.005, initial=InitialState(velocity=(v0, 0, 0)))
    traj = ReducedSim(AffineBasis(), mesh, scene).run(200)
    distance = traj.displacements[-1, :, 0].mean()
    expected = v0**2 / (2 * mu * G)
    print(f"slide to rest: {distance:.4f} m, expected {expected:.4f} m")
    assert np.abs(traj.velocities[-1]).max() < 1e-3
    assert distance == pytest.approx(expected, rel=0.03)


def _tumble_onto_incline(resolution, steps):
    """A soft cheese dropped, tilted, onto a 20 deg incline (mu 0.3): ``(mesh, scene, full run)``, a deforming run to take POD modes from."""
    mesh = meshes.cheese(resolution=resolution)
    scene = Scene(
        material=Material(youngs_modulus=5e4),
        planes=(Plane.incline(20.0, 0.3),),
        initial=InitialState(translation=(0, 0, 0.07), rotation=(0.3, 0.2, 0.0)),
    )
    return mesh, scene, FullSim(mesh, scene).run(steps)


def test_pod_error_falls_as_modes_are_added():
    mesh, scene, full = _tumble_onto_incline(resolution=5, steps=60)
    errors = []
    for k in (2, 4, 8, 16):
        pod, _ = MeshBasis.pod(mesh, full.displacements, k)
        basis = StackedBasis(AffineBasis(), pod)
        reduced = ReducedSim(basis, mesh, scene, cubature=Cubature.full(mesh)).run(60)
        errors.append(compare(full, reduced).mean_error)
    print("POD modes (+12 affine) 2, 4, 8, 16 -> mean relative error", ", ".join(f"{e:.2e}" for e in errors))
    assert errors[-1] < errors[0]
    assert errors[-1] < 0.05


def test_projection_transfer_and_bad_input():
    coarse = meshes.cheese(resolution=6)
    fine = meshes.cheese(resolution=9)
    scene = Scene(planes=(Plane((0, 0, 1), 0.06, 0.5),), initial=InitialState(velocity=(0.2, 0, 0)))
    sim = ReducedSim(AffineBasis(), coarse, scene)
    for _ in range(3):
        sim.step()
    other = sim.transfer(fine)
    np.testing.assert_allclose(other.q, sim.q)
    # the same affine motion evaluated on the other mesh's vertices
    a = sim.q[:9].reshape(3, 3)
    np.testing.assert_allclose(other.positions, fine.vertices + fine.vertices @ a.T + sim.q[9:], atol=1e-12)
    u = sim.positions - coarse.vertices
    np.testing.assert_allclose(sim.project(u), sim.q, atol=1e-10)
    with pytest.raises(ShapeError, match="positions must have shape"):
        sim.set_state(positions=np.zeros((3, 3)))
    with pytest.raises(ShapeError, match="NaN"):
        sim.set_state(velocities=np.full((coarse.n_vertices, 3), np.nan))
    with pytest.raises(ConfigError, match="solver must be one of"):
        ReducedSim(AffineBasis(), coarse, scene, solver="gradient")
    with pytest.raises(ConfigError, match="singular"):
        ReducedSim(StackedBasis(AffineBasis(), AffineBasis()), coarse, scene)
    with pytest.raises(ConfigError, match="needs a mesh"):
        ReducedSim(AffineBasis())


def test_non_convergence_is_reported():
    mesh = meshes.box(0.1, 2)
    scene = _incline_scene(30.0, 0.3, solver=SolverParams(tolerance=1e-14, reduced_tolerance=1e-14, max_iterations=1),
                           initial=InitialState(velocity=(0, 0, -1.0)))
    sim = ReducedSim(AffineBasis(), mesh, scene)
    before = sim.q
    with pytest.raises(SolverError, match="converge"):
        sim.step()
    np.testing.assert_array_equal(sim.q, before)
    recorded = ReducedSim(AffineBasis(), mesh, scene.replace(solver=SolverParams(1e-14, 1, "record", 1e-14))).run(3)
    assert not recorded.converged.any()


def test_contact_subset_matches_weight_on_flat_ground():
    mesh = meshes.box(0.1, 4)
    scene = _incline_scene(0.0, 0.5)
    sim = ReducedSim(AffineBasis(), mesh, scene, contact_points=ContactPoints.subset(mesh, 30))
    for _ in range(150):
        sim.step()
    weight = mesh.vertex_masses(STIFF.density).sum() * G
    assert sim.contact_forces()[:, 2].sum() == pytest.approx(weight, rel=1e-3)


def test_a_non_basis_is_refused_naming_what_it_lacks():
    mesh = meshes.box(0.1, resolution=2)
    with pytest.raises(ConfigError, match=r"not a basis: it lacks 'n_modes', 'values', 'jacobians'"):
        ReducedSim(object(), mesh, Scene())


def test_prefactored_converges_through_a_landing():
    # A box dropped 2 cm onto flat ground: before the contact terms entered its matrix,
    # the prefactored scheme failed at the first contact step.
    mesh = meshes.box(0.1, 3)
    scene = Scene(planes=(Plane(friction=0.5),), initial=InitialState(translation=(0, 0, 0.07)))
    runs = {solver: ReducedSim(AffineBasis(), mesh, scene, solver=solver).run(30) for solver in ("newton", "prefactored")}
    newton, pre = runs["newton"], runs["prefactored"]
    assert newton.converged.all() and pre.converged.all()
    assert pre.positions(-1)[:, 2].min() < 0.0 < pre.positions(3)[:, 2].min()  # it landed (at step 7)
    np.testing.assert_allclose(pre.displacements, newton.displacements, atol=1e-6)
    stats = pre.info["solver_stats"]
    assert stats["steps"] == 30 and stats["fallbacks"] == 0
    assert stats["elastic_hessians"] == 0  # K(rest), assembled at construction, serves every step
    assert stats["factorizations"] < newton.info["solver_stats"]["factorizations"]


def test_prefactored_follows_newton_with_pod_modes_on_an_incline():
    mesh, scene, full = _tumble_onto_incline(resolution=4, steps=30)
    pod, _ = MeshBasis.pod(mesh, full.displacements, 4)
    basis = StackedBasis(AffineBasis(), pod)
    scene = scene.replace(solver=SolverParams(reduced_tolerance=1e-6))  # both stop within h * 1e-6 m of the solution a step
    runs = {s: ReducedSim(basis, mesh, scene, cubature=Cubature.full(mesh), solver=s).run(30) for s in ("newton", "prefactored")}
    assert runs["prefactored"].converged.all()
    scale = np.abs(runs["newton"].displacements).max()
    assert np.abs(runs["prefactored"].displacements - runs["newton"].displacements).max() < 1e-4 * scale
def _contend(sim, steps=5000):
    """Step ``sim`` in a second thread while this one reads and steps it; return the exceptions raised here."""
    import threading

    raised, failed = [], []

    def stepper():
        try:
            for _ in range(steps):
                if raised:
                    return
                sim.step()
        except Exception as exc:  # collected: any error of the stepping thread fails the test
            failed.append(exc)

    thread = threading.Thread(target=stepper)
    thread.start()
    while thread.is_alive() and not raised:
        try:
            _ = sim.q
            sim.step()
        except Exception as exc:
            raised.append(exc)
    thread.join()
    assert not failed, failed
    return raised


def _serial_and_threaded(make, steps=8):
    """Final q of two simulations run one after the other, and of two run at once in two threads."""
    import threading

    serial = [make(), make()]
    for sim in serial:
        for _ in range(steps):
            sim.step()
    sims = [make(), make()]
    threads = [threading.Thread(target=lambda s=s: [s.step() for _ in range(steps)]) for s in sims]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return [s.q for s in serial], [s.q for s in sims]



def _world_frame_sim():
    mesh = meshes.box(0.1, 2)
    scene = Scene(material=STIFF, planes=(Plane((0, 0, 1), 0.05, 0.5),), solver=TIGHT, initial=InitialState(velocity=(0.2, 0, -0.5)))
    return ReducedSim(MeshBasis.identity(mesh), mesh, scene, cubature=Cubature.full(mesh))


def _body_frame_sim():
    from licrom.reduced.body import BodyFrameSim
    from licrom.subspace.body_basis import BodyFrameBasis

    mesh = meshes.box(0.1, 4)
    scene = Scene(planes=(Plane((0, 0, 1), 0.05, 0.5),), solver=TIGHT, initial=InitialState(angular_velocity=(1.0, 2.0, 0.0)))
    return BodyFrameSim(BodyFrameBasis(mesh), mesh, scene, cubature=Cubature.full(mesh))


@pytest.mark.parametrize("make", [_world_frame_sim, _body_frame_sim], ids=["world", "body"])
def test_one_simulation_in_two_threads_is_a_named_error_and_two_run_in_parallel(make):
    from licrom import ConcurrencyError

    raised = _contend(make())
    # a read or step while the other thread's step runs (without the GIL) is refused by name
    assert raised and all(isinstance(e, ConcurrencyError) for e in raised), raised
    assert "another thread" in str(raised[0]) and isinstance(raised[0], RuntimeError)
    serial, threaded = _serial_and_threaded(make)
    for a, b in zip(serial, threaded):
        np.testing.assert_array_equal(a, b)


def _many_scenes():
    """World-frame (affine) and body-frame sims of an 84-tet cheese: drops and slides on several slopes."""
    from licrom.reduced.body import BodyFrameSim
    from licrom.subspace.body_basis import BodyFrameBasis

    mesh = meshes.cheese(resolution=4)
    soft = Material(youngs_modulus=1e5, poisson_ratio=0.3)
    sims = []
    for k, (slope, mu) in enumerate([(10.0, 0.2), (25.0, 0.3), (30.0, 0.9), (0.0, 0.5)]):
        # Touching or up to 2.4 cm deep at the start (the limit of licrom.validity is 2.6 cm here).
        scene = Scene(material=soft, planes=(Plane.incline(slope, mu, offset=0.075),),
                      initial=InitialState(rotation=(0.1 * k, 0.05, 0.0), velocity=(0.2 * k, 0.0, -0.3)))
        sims.append(ReducedSim(AffineBasis(), mesh, scene))
        if k < 2:
            sims.append(BodyFrameSim(BodyFrameBasis(mesh, density=soft.density), mesh, scene))
    return sims


def _state(sim):
    names = ("q", "qdot", "center", "rotation", "velocity", "angular_velocity")
    return [getattr(sim, n).tobytes() for n in names if hasattr(sim, n)] + [sim.time]


def test_step_many_equals_stepping_each_alone_bit_for_bit():
    from licrom.reduced.body import BodyFrameSim

    steps = 8
    alone = _many_scenes()
    expected = np.array([[s.step_or_record()[0] for _ in range(steps)] for s in alone])
    assert sum(isinstance(s, BodyFrameSim) for s in alone) == 2 and len(alone) == 6
    assert expected.max() > 1  # landing: real Newton solves, not free flight
    for threads in (1, 2, None):
        sims = _many_scenes()
        its, res, ok = ReducedSim.step_many(sims, steps=steps, threads=threads)
        assert its.shape == res.shape == ok.shape == (len(sims), steps) and ok.all()
        np.testing.assert_array_equal(its, expected)
        for a, b in zip(sims, alone):
            assert _state(a) == _state(b)
    # Steps in several calls are the same steps; BodyFrameSim has the same function.
    sims = _many_scenes()
    BodyFrameSim.step_many(sims, steps=3, threads=2)
    ReducedSim.step_many(sims, steps=steps - 3)
    assert [_state(s) for s in sims] == [_state(s) for s in alone]


def test_step_many_failures_and_bad_arguments():
    mesh = meshes.box(0.1, 2)
    hopeless = SolverParams(tolerance=1e-14, reduced_tolerance=1e-14, max_iterations=1)
    scene = _incline_scene(30.0, 0.3, initial=InitialState(velocity=(0, 0, -1.0)))
    ok, failing = ReducedSim(AffineBasis(), mesh, scene), ReducedSim(AffineBasis(), mesh, scene.replace(solver=hopeless))
    reference = ReducedSim(AffineBasis(), mesh, scene)
    for _ in range(3):
        reference.step()
    before = failing.q
    with pytest.raises(SolverError, match=r"sims\[1\], at its step 1 of 3: .*converge") as info:
        ReducedSim.step_many([ok, failing], steps=3, threads=2)
    assert info.value.step_index == 0 and info.value.iterations == 1
    # The failing sim stopped at the start of its failed step; the other took all its steps.
    np.testing.assert_array_equal(failing.q, before)
    assert failing.time == 0.0 and _state(ok) == _state(reference)
    # on_failure="record": the failed steps are recorded, as run() records them.
    record = scene.replace(solver=SolverParams(1e-14, 1, "record", 1e-14))
    batched, looped = ReducedSim(AffineBasis(), mesh, record), ReducedSim(AffineBasis(), mesh, record)
    its, res, conv = ReducedSim.step_many([batched], steps=3)
    traj = looped.run(3)
    assert not conv.any() and (its == 1).all()
    np.testing.assert_array_equal(res[0], traj.residuals)
    assert _state(batched) == _state(looped)

    with pytest.raises(ConfigError, match=r"sims\[0\] and sims\[2\] are the same simulation"):
        ReducedSim.step_many([ok, reference, ok])
    with pytest.raises(ConfigError, match=r"sims\[1\] must be a ReducedSim or BodyFrameSim"):
        ReducedSim.step_many([ok, "sim"])
    with pytest.raises(ConfigError, match="threads must be None"):
        ReducedSim.step_many([ok], threads=0)
    with pytest.raises(ConfigError, match="steps must be an integer >= 0"):
        ReducedSim.step_many([ok], steps=-1)
    assert [a.shape for a in ReducedSim.step_many([], steps=2)] == [(0, 2)] * 3


def test_step_many_of_a_simulation_busy_in_another_thread_is_a_named_error():
    import threading

    from licrom import ConcurrencyError

    sim, other = _world_frame_sim(), _world_frame_sim()
    raised, stop = [], threading.Event()

    def stepper():
        while not stop.is_set():
            try:
                sim.step()
            except ConcurrencyError:  # step_many holds it just now
                pass

    thread = threading.Thread(target=stepper)
    thread.start()
    try:
        for _ in range(5000):
            try:
                ReducedSim.step_many([other, sim])
            except ConcurrencyError as exc:
                raised.append(exc)
                break
    finally:
        stop.set()
        thread.join()
    assert raised and "sims[1] is busy in another thread" in str(raised[0])


def test_scene_dicts_huge_counts_and_non_real_states_are_named():
    mesh = meshes.box(0.1, 2)
    with pytest.raises(ConfigError, match=r"scene must be a licrom\.Scene, got dict"):
        ReducedSim(AffineBasis(), mesh, scene={"dt": 0.01})
    sim = ReducedSim(AffineBasis(), mesh, Scene(planes=()))
    with pytest.raises(ConfigError, match=r"threads must be None \(every core\) or an integer in 1\.\.9223372036854775807"):
        ReducedSim.step_many([sim], threads=2**70)
    with pytest.raises(ConfigError, match=r"steps must be an integer in 0\.\.\d+ for 1 simulation\(s\), got 1180591620717411303424"):
        ReducedSim.step_many([sim], steps=2**70)
    with pytest.raises(ConfigError, match=r"steps must be an integer in 0\.\.\d+ for 1 simulation\(s\)"):
        ReducedSim.step_many([sim], steps=2**62)
    assert ReducedSim.step_many([sim], steps=2, threads=10**6)[0].shape == (1, 2)
    before = sim.q
    x = mesh.vertices.copy()
    zero = np.zeros_like(x)
    for positions, velocities in ((x.astype(str), zero.astype(str)), (x + 1j, zero + 1j), ("x", "v")):
        with pytest.raises(ShapeError, match=r"positions must be a real \(\d+, 3\) array of finite numbers"):
            sim.set_state(positions=positions)
        with pytest.raises(ShapeError, match=r"velocities must be a real \(\d+, 3\) array of finite numbers"):
            sim.set_state(velocities=velocities)
    np.testing.assert_array_equal(sim.q, before)
    full = FullSim(mesh, Scene(planes=()), device="cpu")
    with pytest.raises(ShapeError, match=r"positions must be a real \(\d+, 3\) array of finite numbers"):
        full.set_state(positions=x + 1j)


def test_every_reduced_simulation_is_a_reduced_sim_and_the_factory_picks_its_frame():
    from licrom.reduced.factory import reduced_sim
    from licrom.reduced.world import WorldFrameSim

    mesh = meshes.box((0.1, 0.1, 0.1), resolution=2)
    scene = Scene(planes=(Plane(),), initial=InitialState(translation=(0.0, 0.0, 0.06)))
    for sim in (ReducedSim(AffineBasis(), mesh, scene), reduced_sim(AffineBasis(), mesh, scene),
                WorldFrameSim(AffineBasis(), mesh, scene), BodyFrameSim(BodyFrameBasis(mesh), mesh, scene)):
        assert isinstance(sim, ReducedSim)
    assert type(ReducedSim(AffineBasis(), mesh, scene)) is WorldFrameSim
    assert type(ReducedSim(AffineBasis(), mesh, scene).transfer(mesh)) is WorldFrameSim
    assert ReducedSim.step_many is WorldFrameSim.step_many is BodyFrameSim.step_many


def test_a_body_frame_model_gives_a_body_frame_sim_through_the_factory():
    from licrom.reduced.factory import reduced_sim

    mesh = meshes.box((0.1, 0.1, 0.1), resolution=2)
    scene = Scene(planes=(Plane(),), initial=InitialState(translation=(0.0, 0.0, 0.06)))

    class BodyModel:  # what the factory reads of a body-frame model: no learned modes
        frame = "body"
        default_scene = scene
        n_modes = 0

        def __init__(self):
            self.mesh = mesh

        def values(self, points):
            return np.zeros((len(points), 3, 0))

        def jacobians(self, points):
            return np.zeros((len(points), 3, 3, 0))

    sim = ReducedSim(BodyModel())
    assert type(sim) is BodyFrameSim and isinstance(sim, ReducedSim) and sim.mesh is mesh
    with pytest.raises(ConfigError, match="newton"):
        reduced_sim(BodyModel(), solver="prefactored")
