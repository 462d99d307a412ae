"""The body-frame reduced model tied to the full simulation."""

import numpy as np
import pytest
from licrom import ConfigError, ContactParams, FullSim, InitialState, Material, MeshBasis, Plane, Scene, ShapeError, SolverParams, Trajectory, _core, meshes, validity
from licrom._blas import blas_threads, numpy_blas_threads
from licrom.errors import PhysicsWarning
from licrom.reduced.body import BodyFrameSim, _RecordedFrames
from licrom.rigid import center_of_mass
from licrom.subspace.basis import AffineBasis
from licrom.subspace.body_basis import BodyFrameBasis, rigid_momenta
from licrom.subspace.cubature import Cubature
from scipy.spatial.transform import Rotation

TIGHT = SolverParams(tolerance=1e-11, reduced_tolerance=1e-11, max_iterations=100)


def _complement_of_affine(mesh, density):
    """Every vertex displacement mass-orthogonal to the 12 affine modes (3n - 12 modes):
    with the 6 symmetric affine modes of BodyFrameBasis it spans everything but the
    rigid modes, so the body-frame model is the full space."""
    m3 = np.repeat(mesh.vertex_masses(density), 3)
    affine = AffineBasis().values(mesh.vertices).reshape(-1, 12)
    identity = MeshBasis.identity(mesh).modes.reshape(-1, 3 * mesh.n_vertices)
    coefficients = np.linalg.solve(affine.T @ (m3[:, None] * affine), affine.T @ (m3[:, None] * identity))
    rest = identity - affine @ coefficients
    # Mass-orthonormal columns spanning what is left.
    left, sigma, _ = np.linalg.svd(np.sqrt(m3)[:, None] * rest, full_matrices=False)
    keep = left[:, : 3 * mesh.n_vertices - 12] / np.sqrt(m3)[:, None]
    assert sigma[3 * mesh.n_vertices - 13] > 1e-8 * sigma[0] and sigma[3 * mesh.n_vertices - 12] < 1e-10 * sigma[0]
    return MeshBasis(mesh, keep.reshape(mesh.n_vertices, 3, -1))


def _full_space_pair(scene, steps):
    """FullSim and the body-frame model with a full-space basis on the 43-vertex cheese.

    Both read the initial velocities as backward Euler does (previous positions ``x - h v``),
    so a spinning body starts from the same previous positions in both.
    """
    mesh = meshes.cheese(resolution=4)
    assert mesh.n_vertices == 43
    basis = BodyFrameBasis(mesh, _complement_of_affine(mesh, scene.material.density), density=scene.material.density)
    assert basis.n_modes == 3 * mesh.n_vertices - 6
    full = FullSim(mesh, scene).run(steps)
    sim = BodyFrameSim(basis, mesh, scene, cubature=Cubature.full(mesh))
    reduced = sim.run(steps)
    assert full.converged.all() and reduced.converged.all()
    return full, reduced


@pytest.mark.parametrize("viscosity", [0.0, 400.0])
@pytest.mark.parametrize("integrator", ["backward_euler", "bdf2"])
def test_full_space_body_frame_basis_reproduces_full_simulation_on_an_incline(integrator, viscosity):
    # Both solvers stop at 1e-11 m/s: per step their positions differ by about
    # h * 1e-11 m, far below the 1e-8 relative tolerance (as in the world-frame test).
    # BDF2's prediction goes through the moments of four poses, its friction anchor through two; the material
    # damping's anchor strain through q_n and q_{n-1} alone.
    scene = Scene(
        material=Material(youngs_modulus=2e4, poisson_ratio=0.35, viscosity=viscosity),
        planes=(Plane.incline(25.0, 0.3, offset=0.06),),
        contact=ContactParams(normal_stiffness=1e6, normal_damping=50.0, friction_stiffness=1e6),
        solver=TIGHT,
        initial=InitialState(rotation=(0.2, 0.1, 0.0), velocity=(0.3, 0.0, -0.2)),
        integrator=integrator,
    )
    # It starts 3 cm (11.5 % of its size) inside the incline, which both simulators say.
    with pytest.warns(PhysicsWarning, match="starts 0.02957 m inside a plane"):
        full, reduced = _full_space_pair(scene, 40)
    scale = np.abs(full.displacements).max()
    assert scale > 0.01  # it moved and touched (contact + friction active)
    err = np.abs(reduced.displacements - full.displacements).max() / scale
    print(f"body-frame full-space basis vs full ({integrator}, viscosity {viscosity:g} Pa s): max relative position difference {err:.2e}")
    assert err < 1e-8


def test_the_reduced_solve_stops_at_the_reduced_tolerance():
    # The same reduced run solved to the full solver's 1e-6 m/s and to the reduced default:
    # each step stops below its own threshold, the looser with fewer iterations, and the
    # motions differ by no more than that threshold's velocity over the time run.
    mesh = meshes.cheese(resolution=4)
    basis = BodyFrameBasis(mesh, _complement_of_affine(mesh, 1000.0), density=1000.0)
    scene = Scene(material=Material(youngs_modulus=2e4, poisson_ratio=0.35), planes=(Plane.incline(25.0, 0.3),),
                  initial=InitialState(translation=(0.0, 0.0, 0.1), rotation=(0.2, 0.1, 0.0)))
    steps, loose = 40, SolverParams().reduced_tolerance
    assert loose > SolverParams().tolerance
    runs = {tol: BodyFrameSim(basis, mesh, scene.replace(solver=SolverParams(reduced_tolerance=tol)), cubature=Cubature.full(mesh)).run(steps)
            for tol in (1e-6, loose)}
    for tol, run in runs.items():
        assert run.converged.all() and (run.residuals < tol).all()
    assert runs[loose].iterations.sum() < runs[1e-6].iterations.sum()
    assert np.abs(runs[loose].displacements[-1]).max() > 0.01  # it landed and slid
    gap = np.abs(runs[loose].displacements - runs[1e-6].displacements).max()
    assert 0.0 < gap < loose * steps * scene.dt


def test_a_hard_impact_converges_at_the_default_reduced_tolerance():
    # A box hitting the ground at 50 m/s, at the default 1e-4 m/s: in its third step friction sits at the
    # stick/slip boundary, where the Newton direction's r fell 1.5 % a full step and met the 100-iteration
    # cap at 1.29e-4 m/s; the step now ends on the contact model's step once that is below the tolerance.
    mesh = meshes.box(0.1, 2)
    scene = Scene(initial=InitialState(translation=(0, 0, 0.06), velocity=(0, 0, -50.0)), solver=SolverParams(on_failure="record"))
    traj = BodyFrameSim(BodyFrameBasis(mesh), mesh, scene).run(4)
    assert traj.converged.all() and (traj.residuals < scene.solver.reduced_tolerance).all()
    assert traj.iterations[2] < scene.solver.max_iterations // 2


def test_affine_modes_alone_step_on_one_cubature_tet_as_on_every_tet():
    # Affine modes deform every tet alike, so one tet weighted by the whole volume holds the same energy; with the
    # material's damping that is a cubature whose every column is constant over its points (it once panicked).
    mesh = meshes.box(size=(0.04, 0.04, 0.12), resolution=3)
    scene = Scene(material=Material(youngs_modulus=2e4, poisson_ratio=0.3, viscosity=400.0), dt=0.001, integrator="bdf2",
                  initial=InitialState(translation=(0, 0, 0.07), rotation=(0.3, 0.2, 0.0), velocity=(0.2, 0.0, -0.5)))
    basis = BodyFrameBasis(mesh, density=scene.material.density)
    one = Cubature(np.array([0]), np.array([mesh.volume]), mesh.centroids[[0]], "naive")
    runs = [BodyFrameSim(basis, mesh, scene, cubature=c).run(60) for c in (one, Cubature.full(mesh))]
    assert min(runs[1].positions(f)[:, 2].min() for f in range(runs[1].n_frames)) < 1e-3  # it landed on the ground
    assert np.abs(runs[0].displacements - runs[1].displacements).max() < 1e-8 * mesh.size


@pytest.mark.parametrize("integrator", ["backward_euler", "bdf2"])
def test_tumbling_free_flight_matches_full_simulation(integrator):
    # BDF2 reads three poses back: fitted to the full simulation's start history, not extrapolated by rotation.
    w = np.array([3.0, -5.0, 8.0])
    scene = Scene(
        material=Material(youngs_modulus=5e4, poisson_ratio=0.3),
        planes=(),
        solver=TIGHT,
        initial=InitialState(rotation=(0.4, -0.3, 0.2), velocity=(0.5, 0.0, 1.0), angular_velocity=tuple(w)),
        integrator=integrator,
    )
    full, reduced = _full_space_pair(scene, 30)
    # It tumbled (the orientation turned by almost 3 rad) and spun itself out of shape.
    assert np.linalg.norm(w) * scene.dt * 30 > 2.5
    scale = np.abs(full.displacements).max()
    err = np.abs(reduced.displacements - full.displacements).max() / scale
    print(f"tumbling: max relative position difference {err:.2e}")
    assert err < 1e-8


def _spinning_cheese(integrator: str, offset: float):
    """The tiny cheese thrown spinning at an incline ``offset`` m below it, and a maker of its body-frame simulation on 5
    random modes with every tet."""
    mesh = meshes.cheese(resolution=4)
    scene = Scene(planes=(Plane.incline(25.0, 0.3, offset=offset),), initial=InitialState(rotation=(0.2, 0.1, 0.0), velocity=(0.3, 0.0, -0.4)),
                  integrator=integrator)
    learned = MeshBasis(mesh, 0.01 * np.random.default_rng(3).normal(size=(mesh.n_vertices, 3, 5)))
    basis = BodyFrameBasis(mesh, learned, density=scene.material.density)
    return mesh, lambda: BodyFrameSim(basis, mesh, scene, cubature=Cubature.full(mesh))


@pytest.mark.parametrize("integrator", ["backward_euler", "bdf2"])
def test_recorded_frames_are_the_states_read_between_steps(integrator, monkeypatch):
    # run() rebuilds its frames' shapes at the end, a block of frames at once (blocks of 2 here): the same
    # positions and velocities (the integrator's difference of the poses before) as reading them after each step.
    monkeypatch.setattr("licrom.reduced.body._FRAME_BLOCK", 2)
    mesh, sim = _spinning_cheese(integrator, offset=0.1)
    recorded = sim().run(8, record_every=3)
    stepped = sim()
    frames = [(stepped.positions, stepped.velocities)]
    for s in range(1, 9):
        stepped.step()
        if s % 3 == 0:
            frames.append((stepped.positions, stepped.velocities))
    assert recorded.n_frames == len(frames) == 3
    scale = np.abs(recorded.velocities).max()
    assert scale > 0.1
    for f, (x, v) in enumerate(frames):
        np.testing.assert_allclose(recorded.displacements[f] + mesh.vertices, x, rtol=0, atol=1e-12)
        np.testing.assert_allclose(recorded.velocities[f], v, rtol=0, atol=1e-10 * scale)


@pytest.mark.filterwarnings("ignore::licrom.AccuracyWarning")  # random modes miss the motion
@pytest.mark.parametrize("integrator", ["backward_euler", "bdf2"])
def test_frames_built_on_their_first_read_are_those_read_at_once_and_those_the_run_measured(integrator, monkeypatch, tmp_path):
    # run() measures each frame's positions by blocks (of 2 here, the last one short) and leaves the trajectory's
    # displacements and velocities to be built when first read: once, the same bits whatever the simulation did since.
    monkeypatch.setattr("licrom.reduced.body._FRAME_BLOCK", 2)
    builds = []
    build = _RecordedFrames.build
    monkeypatch.setattr(_RecordedFrames, "build", lambda self: builds.append(1) or build(self))
    measured = []
    depth = validity.penetration
    monkeypatch.setattr("licrom.reduced.base.penetration", lambda x, planes: measured.append(np.array(x)) or depth(x, planes))
    mesh, sim = _spinning_cheese(integrator, offset=0.12)
    at_once = sim().run(60, record_every=5)
    frames = (at_once.displacements, at_once.velocities)
    assert len(builds) == 1 and at_once.n_frames == 13
    first = len(measured)
    stepped = sim()
    later = stepped.run(60, record_every=5)
    assert len(builds) == 1  # the run built nothing
    stepped.run(7)
    stepped.set_state(velocities=np.zeros((mesh.n_vertices, 3)))
    for a, b in zip((later.displacements, later.velocities), frames):
        assert a.dtype == b.dtype == np.float64 and a.shape == b.shape == (13, mesh.n_vertices, 3) and np.array_equal(a, b)
    for name in ("penetration", "min_det_f", "error_estimate", "times"):
        assert np.array_equal(getattr(later, name), getattr(at_once, name))
    # The run measured the positions of the frames built, bit for bit.
    assert np.array_equal(np.array(measured[first:first + 13]) - mesh.vertices, later.displacements)
    assert later.penetration[0] == 0 < later.penetration.max() and np.abs(later.velocities).max() > 0.1
    back = Trajectory.load(later.save(tmp_path / "t.npz", precision="float64"))
    assert np.array_equal(back.displacements, frames[0]) and np.array_equal(back.velocities, frames[1])
    later.positions(3)
    assert len(builds) == 2
    # The first touch (frame 2, in the second block) is where one block over every frame finds it: the estimate runs from there.
    monkeypatch.setattr("licrom.reduced.body._FRAME_BLOCK", 1000)
    assert np.array_equal(sim().run(60, record_every=5).error_estimate, later.error_estimate) and not later.error_estimate[:2].any()


def test_frames_are_built_with_the_blas_threads_of_their_run(monkeypatch):
    # OpenBLAS rounds a product differently with another thread count: frames read later multiply as their run did.
    if numpy_blas_threads() is None:
        pytest.skip("numpy's BLAS is not its wheel's OpenBLAS")
    seen = []
    shapes = _RecordedFrames._shapes
    monkeypatch.setattr(_RecordedFrames, "_shapes", lambda self, block: seen.append(numpy_blas_threads()) or shapes(self, block))
    mesh = meshes.box((0.2, 0.1, 0.1), resolution=2)
    basis = BodyFrameBasis(mesh, density=Scene().material.density)
    with blas_threads(1):
        traj = BodyFrameSim(basis, mesh, Scene(planes=()), cubature=Cubature.full(mesh)).run(3)
    assert seen == [1]
    with blas_threads(2):
        assert traj.velocities.shape == (4, mesh.n_vertices, 3) and seen == [1, 1] and numpy_blas_threads() == 2


def test_basis_carries_no_momentum_on_an_anisotropic_body():
    mesh = meshes.box((0.2, 0.06, 0.03), resolution=3)
    learned = MeshBasis(mesh, np.random.default_rng(0).normal(size=(mesh.n_vertices, 3, 4)))
    basis = BodyFrameBasis(mesh, learned, density=800.0)
    m = mesh.vertex_masses(800.0)
    w = basis.values(mesh.vertices)
    xbar = mesh.vertices - center_of_mass(mesh.vertices, m)
    scale = np.abs(w).max() * m.sum()
    assert np.abs(np.einsum("v,vik->ik", m, w)).max() < 1e-12 * scale
    assert np.abs(np.einsum("v,vik->ik", m, np.cross(xbar[:, :, None], w, axis=1))).max() < 1e-12 * scale * 0.2
    # The Jacobians are the derivatives of the values (finite differences inside a tet).
    p = mesh.centroids[:5]
    d = 1e-6
    fd = np.stack([(basis.values(p + d * e) - basis.values(p - d * e)) / (2 * d) for e in np.eye(3)], axis=2)
    np.testing.assert_allclose(basis.jacobians(p), fd, atol=1e-6 * np.abs(fd).max())


def test_rigid_momenta_recover_a_rigid_field():
    rng = np.random.default_rng(1)
    xbar = rng.normal(size=(40, 3))
    m = rng.uniform(0.5, 2.0, 40)
    xbar -= (m @ xbar) / m.sum()  # about the centre of mass, as rigid_momenta assumes
    t, w = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    field = t.T[None] + np.cross(w[None], xbar[:, None], axis=2).transpose(0, 2, 1)  # (n, 3, k): t_k + w_k x Xbar
    got_t, got_w = rigid_momenta(field, xbar, m)
    np.testing.assert_allclose(got_t, t, atol=1e-12)
    np.testing.assert_allclose(got_w, w, atol=1e-12)


def test_transfer_to_a_finer_mesh_keeps_the_pose():
    coarse, fine = meshes.cheese(resolution=4), meshes.cheese(resolution=6)
    scene = Scene(planes=(Plane((0, 0, 1), 0.06, 0.5),), initial=InitialState(velocity=(0.2, 0, 0), angular_velocity=(0, 0, 2.0)))
    sim = BodyFrameSim(BodyFrameBasis(coarse), coarse, scene)
    for _ in range(5):
        sim.step()
    # The solver's work counters, as the world-frame solver's.
    stats = sim._core.stats()
    assert stats["steps"] == 5 and stats["evaluations"] >= stats["iterations"] >= 5
    sim._core.reset_stats()
    assert all(v == 0 for v in sim._core.stats().values())
    other = sim.transfer(fine)
    np.testing.assert_allclose(other.center, sim.center, atol=1e-15)
    np.testing.assert_allclose(other.rotation, sim.rotation, atol=1e-15)
    np.testing.assert_allclose(other.q, sim.q, atol=1e-15)
    # The new mesh's modes carry no momentum there, so c is its centre of mass.
    m_fine = fine.vertex_masses(scene.material.density)
    np.testing.assert_allclose(center_of_mass(other.positions, m_fine), sim.center, atol=1e-12)
    other.step()


def test_state_round_trip_and_bad_inputs():
    mesh = meshes.cheese(resolution=4)
    scene = Scene(planes=(), gravity=(0, 0, 0), solver=TIGHT)
    sim = BodyFrameSim(BodyFrameBasis(mesh), mesh, scene)
    m = mesh.vertex_masses(scene.material.density)
    # A rigid motion plus an affine stretch is represented exactly.
    r = np.linalg.qr(np.random.default_rng(1).normal(size=(3, 3)))[0]
    r *= np.sign(np.linalg.det(r))
    xbar = mesh.vertices - center_of_mass(mesh.vertices, m)
    stretch = np.diag([1.01, 0.99, 1.02])
    positions = np.array([0.1, 0.2, 0.3]) + xbar @ (r @ stretch).T
    w = np.array([0.5, -1.0, 2.0])
    velocities = np.array([1.0, 0.0, -1.0]) + np.cross(w, positions - center_of_mass(positions, m))
    sim.set_state(positions, velocities)
    np.testing.assert_allclose(sim.positions, positions, atol=1e-12)
    np.testing.assert_allclose(sim.velocities, velocities, atol=1e-12)
    np.testing.assert_allclose(sim.rotation @ sim.rotation.T, np.eye(3), atol=1e-12)
    with pytest.raises(ShapeError, match="positions must have shape"):
        sim.set_state(positions=np.zeros((3, 3)))
    with pytest.raises(ShapeError, match="NaN"):
        sim.set_state(velocities=np.full((mesh.n_vertices, 3), np.nan))
    with pytest.raises(ShapeError, match="rotation"):
        sim._core.set_state(sim.center, 1.001 * np.eye(3), sim.q, np.zeros(3), np.zeros(3), sim.q)
    with pytest.raises(ShapeError, match="rotation"):
        sim._core.set_state(sim.center, np.diag([1.0, 1.0, -1.0]), sim.q, np.zeros(3), np.zeros(3), sim.q)
    with pytest.raises(ShapeError, match="q must have shape"):
        sim._core.set_state(sim.center, np.eye(3), np.zeros(2), np.zeros(3), np.zeros(3), sim.q)
    with pytest.raises(ConfigError, match="momentum"):
        BodyFrameSim(MeshBasis.identity(mesh), mesh, scene)
    with pytest.raises(ConfigError, match="not a basis"):
        BodyFrameBasis(mesh, learned=object())
    with pytest.raises(ConfigError, match="needs a scene"):
        BodyFrameSim(BodyFrameBasis(mesh))
    with pytest.raises(ConfigError, match="strain must be one of"):
        BodyFrameSim(BodyFrameBasis(mesh), mesh, scene, strain="continuous")
    n = sim.n_modes
    core_args = {
        "total_mass": 1.0, "inertia_moments": np.eye(3), "mode_moments": np.zeros((n, 3, 3)), "mode_products": np.zeros((n, n, 3, 3)),
        "gravity": np.zeros(3), "cubature_jacobians": np.zeros((0, 9, n)), "cubature_weights": np.zeros(0), "mu": 1e4, "lam": 1e4,
        "contact_basis": np.zeros((0, 3, n)), "contact_rest": np.zeros((0, 3)), "contact_areas": np.zeros(0), "planes": np.zeros((0, 5)),
        "normal_stiffness": 1e6, "normal_damping": 0.0, "friction_stiffness": 1e6, "dt": 0.01, "tolerance": 1e-6, "max_iterations": 10,
    }
    with pytest.raises(ConfigError, match="max_iterations"):
        _core.BodyFrameCore(**{**core_args, "max_iterations": 0})
    with pytest.raises(ShapeError, match="mode_products"):
        _core.BodyFrameCore(**{**core_args, "mode_products": np.zeros((n, n, 3))})
    with pytest.raises(ConfigError, match="inertia_moments"):
        _core.BodyFrameCore(**{**core_args, "inertia_moments": np.diag([1.0, 1.0, 0.0])})


def test_binding_gradient_and_hessian_match_finite_differences():
    mesh = meshes.cheese(resolution=4)
    scene = Scene(planes=(Plane((0, 0, 1), 0.05, 0.5),), initial=InitialState(velocity=(0.3, 0, -0.5), angular_velocity=(1, 2, 0)))
    sim = BodyFrameSim(BodyFrameBasis(mesh), mesh, scene)
    for _ in range(3):
        sim.step()
    core = sim._core
    c, r, q = sim.center + 1e-4, Rotation.from_rotvec([0.01, -0.02, 0.03]).as_matrix() @ sim.rotation, sim.q + 1e-3

    def moved(x):
        return c + x[:3], Rotation.from_rotvec(x[3:6]).as_matrix() @ r, q + x[6:]

    n = 6 + sim.n_modes
    eps = 1e-7
    fd = np.array([(core.energy(*moved(eps * e)) - core.energy(*moved(-eps * e))) / (2 * eps) for e in np.eye(n)])
    grad = core.gradient(c, r, q)
    np.testing.assert_allclose(grad, fd, atol=1e-6 * np.abs(fd).max())
    # Jacobian of the (left-trivialised) gradient, symmetrised: the Hessian of the pulled-back energy.
    jac = np.array([(core.gradient(*moved(eps * e)) - core.gradient(*moved(-eps * e))) / (2 * eps) for e in np.eye(n)])
    hess = core.hessian(c, r, q, exact=True)
    np.testing.assert_allclose(hess, 0.5 * (jac + jac.T), atol=1e-5 * np.abs(hess).max())
    assert np.linalg.eigvalsh(core.hessian(c, r, q, exact=False)).min() > 0


def test_a_step_whose_contact_model_stalls_goes_on_with_newton():
    """The tipping box of docs/results.md section 10 in 80 POD modes of its training runs (saved).

    At step 38 the contact model's direction led where the energy does not decrease, every
    outer iteration again: the line search took steps of 4e-11 to 2e-8 and the step failed
    after max_iterations at a residual of 1.8e-3 m/s. After such a step the next direction
    is now the plain Newton one (``STALLED_STEP`` in the Rust solver), and the run converges.
    """
    import pathlib

    data = np.load(pathlib.Path(__file__).parent / "data" / "box_tip_pod80.npz")
    mesh = meshes.box(size=(0.04, 0.04, 0.12), resolution=8)
    scene = Scene.from_json(str(data["scene"]))
    basis = BodyFrameBasis(mesh, MeshBasis(mesh, data["modes"]), density=scene.material.density)
    sim = BodyFrameSim(basis, mesh, scene, cubature=Cubature.full(mesh))
    iterations = [sim.step()[0] for _ in range(45)]
    assert max(iterations) < 20


def test_scene_dicts_and_non_real_states_are_named():
    mesh = meshes.box(0.1, 2)
    with pytest.raises(ConfigError, match=r"scene must be a licrom\.Scene, got dict"):
        BodyFrameSim(BodyFrameBasis(mesh), mesh, scene={"dt": 0.01})
    sim = BodyFrameSim(BodyFrameBasis(mesh), mesh, Scene(planes=()))
    x = mesh.vertices.copy()
    with pytest.raises(ShapeError, match=r"positions must be a real \(\d+, 3\) array of finite numbers"):
        sim.set_state(positions=x.astype(str))
    with pytest.raises(ShapeError, match=r"velocities must be a real \(\d+, 3\) array of finite numbers"):
        sim.set_state(velocities=np.zeros((mesh.n_vertices, 3)) + 1j)


@pytest.mark.filterwarnings("ignore::licrom.AccuracyWarning")  # random modes miss the motion
def test_a_step_is_the_same_bit_for_bit_with_or_without_the_second_thread():
    # 60 learned modes on 198 vertices: the basis products are large enough to be split over two threads.
    mesh = meshes.cheese(resolution=7)
    scene = Scene(planes=(Plane.incline(25.0, 0.3, offset=0.06),), initial=InitialState(rotation=(0.2, 0.1, 0.0), velocity=(0.3, 0.0, -0.4)))
    learned = MeshBasis(mesh, 0.002 * np.random.default_rng(5).normal(size=(mesh.n_vertices, 3, 60)))
    basis = BodyFrameBasis(mesh, learned, density=scene.material.density)
    states = []
    try:
        for on in (True, False, True):
            BodyFrameSim.use_second_thread(on)
            sim = BodyFrameSim(basis, mesh, scene, cubature=Cubature.full(mesh))
            its = [sim.step_or_record()[0] for _ in range(12)]
            states.append((its, sim.q.tobytes(), sim.center.tobytes(), sim.rotation.tobytes()))
    finally:
        BodyFrameSim.use_second_thread(True)
    assert max(states[0][0]) > 1  # landing: real Newton solves
    assert states[0] == states[1] == states[2]
    with pytest.raises(ConfigError, match="True or False"):
        BodyFrameSim.use_second_thread(1)
