"""The full-space simulator: derivatives against finite differences, and motion against analytic values."""

import math

import numpy as np
import pytest
from licrom import (
    ConfigError,
    ContactParams,
    InitialState,
    Material,
    Mesh,
    Plane,
    Scene,
    ShapeError,
    SolverError,
    SolverParams,
    _core,
    meshes,
)
from licrom.full import FullSim

G = 9.81
L = 0.1  # box edge, m
STIFF = Material(youngs_modulus=1e7, poisson_ratio=0.3, density=1000.0)  # the box moves like a rigid body
CONTACT = ContactParams(normal_stiffness=1e7, normal_damping=0.0, friction_stiffness=1e7)


def _bottom_area(mesh):
    """Contact area carried by the boundary vertices of the face z = -L/2."""
    b = mesh.boundary_vertices
    on_bottom = np.isclose(mesh.vertices[b, 2], mesh.vertices[:, 2].min())
    return float(mesh.boundary_vertex_areas[on_bottom].sum())


def _box_on_incline(theta_deg, mu, *, speed=0.0, dt=0.01, res=2, contact=CONTACT, material=STIFF):
    """A cube lying on a plane tilted by theta (about y), sunk to its static penetration, moving downhill at ``speed``."""
    mesh = meshes.box(L, resolution=res)
    t = math.radians(theta_deg)
    normal = np.array([math.sin(t), 0.0, math.cos(t)])
    downhill = np.array([math.cos(t), 0.0, -math.sin(t)])
    mass = material.density * L**3
    sink = mass * G * math.cos(t) / (contact.normal_stiffness * _bottom_area(mesh))
    scene = Scene(
        material=material,
        planes=(Plane.incline(theta_deg, mu),),
        contact=contact,
        dt=dt,
        initial=InitialState(translation=tuple(normal * (L / 2 - sink)), rotation=(0.0, t, 0.0), velocity=tuple(speed * downhill)),
    )
    return mesh, scene, downhill


def _com(sim):
    m = sim.masses
    return m @ sim.positions / m.sum(), m @ sim.velocities / m.sum()


# --- derivatives --------------------------------------------------------------------------


def _fd_check(sim, x, terms, eps, rtol_g, rtol_h):
    """Central differences of energy -> gradient and of gradient -> Hessian (unprojected)."""
    g = sim.gradient(x, terms).ravel()
    H = sim.hessian(x, terms, project=False).toarray()
    flat = x.ravel()
    fd_g = np.empty_like(g)
    fd_h = np.empty_like(H)
    for i in range(len(flat)):
        xp, xm = flat.copy(), flat.copy()
        xp[i] += eps
        xm[i] -= eps
        xp, xm = xp.reshape(-1, 3), xm.reshape(-1, 3)
        fd_g[i] = (sim.energy(xp, terms) - sim.energy(xm, terms)) / (2 * eps)
        fd_h[:, i] = (sim.gradient(xp, terms).ravel() - sim.gradient(xm, terms).ravel()) / (2 * eps)
    err_g = np.abs(g - fd_g).max() / np.abs(g).max()
    err_h = np.abs(H - fd_h).max() / np.abs(H).max()
    print(f"{terms}: |grad| {np.abs(g).max():.3e}, gradient error {err_g:.2e}; |H| {np.abs(H).max():.3e}, Hessian error {err_h:.2e}")
    assert err_g < rtol_g
    assert err_h < rtol_h
    np.testing.assert_allclose(H, H.T, atol=1e-12 * np.abs(H).max())
    return g, H


def test_elastic_gradient_and_hessian_match_finite_differences(rng):
    mesh = meshes.box(L, resolution=2)
    sim = FullSim(mesh, Scene(material=Material(1e5, 0.3), planes=()))
    x = mesh.vertices + 0.01 * rng.standard_normal(mesh.vertices.shape)
    _, H = _fd_check(sim, x, "elastic", 1e-7, 1e-6, 1e-6)
    # The projected Hessian is PSD and differs from the exact one only where that is indefinite.
    Hp = sim.hessian(x, "elastic").toarray()
    ev, evp = np.linalg.eigvalsh(H), np.linalg.eigvalsh(Hp)
    print(f"elastic Hessian eigenvalues: exact min {ev.min():.3e}, projected min {evp.min():.3e} (max {evp.max():.3e})")
    assert ev.min() < 0 and evp.min() > -1e-9 * evp.max()
    # Rigid motions: the energy is invariant, its gradient zero.
    R = InitialState(rotation=(0.3, -0.5, 0.9)).rotation_matrix()
    xr = mesh.vertices @ R.T + np.array([0.1, 0.2, 0.3])
    assert abs(sim.energy(xr, "elastic")) < 1e-12 * sim.energy(x, "elastic")
    assert np.abs(sim.gradient(xr, "elastic")).max() < 1e-9 * np.abs(sim.gradient(x, "elastic")).max()


def test_elastic_energy_survives_inverted_tets(rng):
    mesh = meshes.box(L, resolution=1)
    sim = FullSim(mesh, Scene(material=Material(1e5, 0.3), planes=()))
    x = mesh.vertices.copy()
    x[:, 2] *= -0.5  # mirror and squash: every tet inverted
    x += 1e-3 * rng.standard_normal(x.shape)
    assert (np.linalg.det(mesh.deformation_gradients(x)) < 0).all()
    assert np.isfinite(sim.energy(x, "elastic"))
    _fd_check(sim, x, "elastic", 1e-7, 1e-6, 1e-6)
    Hp = sim.hessian(x, "elastic").toarray()
    assert np.linalg.eigvalsh(Hp).min() > -1e-9 * np.abs(Hp).max()


def test_material_damping_matches_finite_differences_and_the_homogeneous_stretch(rng):
    """Kelvin-Voigt viscosity: eta V/(2h) |E(F) - E(F_a)|^2 per tet, anchored at the step's start (the rest shape here)."""
    eta, dt = 400.0, 0.01
    mesh = meshes.box(L, resolution=2)
    sim = FullSim(mesh, Scene(material=Material(1e5, 0.3, viscosity=eta), planes=(), dt=dt))
    x = mesh.vertices + 0.01 * rng.standard_normal(mesh.vertices.shape)
    g, H = _fd_check(sim, x, "viscosity", 1e-7, 1e-6, 1e-6)
    # Newton's Hessian is the Gauss-Newton part: positive semi-definite.
    Hp = sim.hessian(x, "viscosity").toarray()
    assert np.linalg.eigvalsh(Hp).min() > -1e-9 * np.abs(Hp).max()
    assert np.abs(Hp - H).max() > 1e-6 * np.abs(H).max()  # away from the anchor the exact one differs
    # Internal forces: no net force or torque, at any positions.
    f = g.reshape(-1, 3)
    assert np.abs(f.sum(axis=0)).max() < 1e-10 * np.abs(f).max()
    assert np.abs(np.cross(x, f).sum(axis=0)).max() < 1e-10 * np.abs(np.cross(x, f)).max()
    # A rigid motion of the anchor is not damped.
    R = InitialState(rotation=(0.3, -0.5, 0.9)).rotation_matrix()
    xr = mesh.vertices @ R.T + np.array([0.1, 0.2, 0.3])
    assert abs(sim.energy(xr, "viscosity")) < 1e-20
    assert np.abs(sim.gradient(xr, "viscosity")).max() < 1e-12 * np.abs(g).max()
    # A homogeneous stretch F = diag(1 + s, 1, 1): E_11 = ((1 + s)^2 - 1)/2, energy eta V/(2h) E_11^2.
    s = 0.05
    stretched = mesh.vertices * np.array([1.0 + s, 1.0, 1.0])
    e11 = ((1.0 + s) ** 2 - 1.0) / 2.0
    assert sim.energy(stretched, "viscosity") == pytest.approx(eta * L**3 / (2.0 * dt) * e11**2, rel=1e-12)
    # Without viscosity the term is absent.
    plain = FullSim(mesh, Scene(material=Material(1e5, 0.3), planes=(), dt=dt))
    assert plain.energy(x, "viscosity") == 0.0 and plain.energy(x) == pytest.approx(sim.energy(x) - sim.energy(x, "viscosity"), rel=1e-12)


def _contact_state(rng, mu=0.5, kd=3e4):
    """A box sunk 2 mm into the ground (normal force on its bottom), evaluated at a moved position."""
    mesh = meshes.box(L, resolution=2)
    contact = ContactParams(normal_stiffness=1e7, normal_damping=kd, friction_stiffness=1e7)
    scene = Scene(material=Material(1e5, 0.3), planes=(Plane((0, 0, 1), L / 2 - 2e-3, mu),), contact=contact)
    sim = FullSim(mesh, scene)
    return mesh, scene, sim


def test_penalty_and_damping_match_finite_differences(rng):
    mesh, scene, sim = _contact_state(rng)
    # Pushed further in at most points (approaching: damping on), lifted out at some.
    x = mesh.vertices + np.array([0, 0, -1e-3]) + 1.5e-3 * rng.standard_normal(mesh.vertices.shape)
    bottom = sim.contact_indices[np.isclose(mesh.vertices[sim.contact_indices, 2], -L / 2)]
    assert (x[bottom, 2] < mesh.vertices[bottom, 2]).any() and (x[bottom, 2] > mesh.vertices[bottom, 2]).any()
    g, _ = _fd_check(sim, x, "penalty", 1e-8, 1e-6, 1e-6)
    # Analytic penalty gradient: a k_n min(gap, 0) n at each contact point.
    area = dict(zip(sim.contact_indices.tolist(), sim.contact_areas))
    gap = x[:, 2] + L / 2 - 2e-3
    for j in bottom:
        assert g.reshape(-1, 3)[j, 2] == pytest.approx(area[j] * 1e7 * min(gap[j], 0.0), rel=1e-12, abs=1e-15)
    gd, _ = _fd_check(sim, x, "damping", 1e-8, 1e-6, 1e-6)
    # Analytic damping force: a k_d v_n (approaching only), v_n = dz / h, where the start state is in contact.
    dz = x[:, 2] - mesh.vertices[:, 2]
    for j in bottom:
        assert gd.reshape(-1, 3)[j, 2] == pytest.approx(area[j] * 3e4 * min(dz[j], 0.0) / scene.dt, rel=1e-12, abs=1e-15)


def test_friction_matches_finite_differences_in_stick_and_slip(rng):
    mu, kf, h = 0.5, 1e7, 0.01
    mesh, _scene, sim = _contact_state(rng, mu=mu)
    idx = sim.contact_indices
    area = sim.contact_areas
    bottom = np.isclose(mesh.vertices[idx, 2], -L / 2)
    fn = area * 1e7 * 2e-3  # lagged normal force at the start of the step
    threshold = mu * fn * h / (area * kf)  # slip length where stick turns into slip
    # Tangential moves from 0.3x to 3x the threshold: some points stick, others slip.
    x = mesh.vertices.copy()
    scale = np.zeros(mesh.n_vertices)
    scale[idx[bottom]] = threshold[bottom] * rng.uniform(0.3, 3.0, bottom.sum())
    direction = rng.standard_normal((mesh.n_vertices, 2))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    x[:, :2] += scale[:, None] * direction
    slip = np.linalg.norm(x[idx, :2] - mesh.vertices[idx, :2], axis=1)
    sticking = bottom & (slip < threshold)
    slipping = bottom & (slip > threshold)
    print(f"friction check: {sticking.sum()} points stick, {slipping.sum()} slip")
    assert sticking.sum() >= 2 and slipping.sum() >= 2
    assert np.min(np.abs(slip[bottom] / threshold[bottom] - 1)) > 1e-3  # no point on the switch
    g, H = _fd_check(sim, x, "friction", 1e-10, 1e-6, 1e-5)
    # Analytic force magnitude: min(a k_f |v_t|, mu f_n), opposite to the slip.
    force = np.linalg.norm(g.reshape(-1, 3)[idx], axis=1)
    np.testing.assert_allclose(force[sticking], area[sticking] * kf * slip[sticking] / h, rtol=1e-10)
    np.testing.assert_allclose(force[slipping], mu * fn[slipping], rtol=1e-10)
    assert np.linalg.eigvalsh(sim.hessian(x, "friction").toarray()).min() > -1e-9 * np.abs(H).max()


# --- against the native core ---------------------------------------------------------------


def test_elastic_energy_stress_and_hessian_match_the_native_material_point_for_point(rng):
    """Per tet: energy V Psi(F), gradient V P(F) n_a and Hessian V B^T d2Psi B (exact and PSD-projected) of a one-tet mesh
    at given deformation gradients, against licrom._core's snh_energy, snh_pk1 and snh_hessian (the reduced model's material)."""
    rest = np.array([[0.0, 0.0, 0.0], [0.12, 0.01, -0.02], [0.03, 0.09, 0.01], [0.02, -0.01, 0.11]])
    mesh = Mesh(rest, np.array([[0, 1, 2, 3]]))
    scene = Scene(material=Material(1e5, 0.3), planes=())
    sim = FullSim(mesh, scene, device="cpu")
    mu, lam = scene.material.snh_parameters
    volume, dm_inv = mesh.rest_volumes[0], mesh.shape_matrix_inverses[0]
    shape_gradients = np.vstack([-dm_inv.sum(axis=0), dm_inv])  # n_a, a = 0..3
    dvecf = np.einsum("ik,aj->ijak", np.eye(3), shape_gradients).reshape(9, 12)  # d vec(F) / dx, row-major vec(F)
    stretched = [np.eye(3) + 0.4 * rng.standard_normal((3, 3)) for _ in range(40)]
    reflect = np.diag([1.0, 1.0, -1.0])
    stretched = [f @ reflect if k % 2 and np.linalg.det(f) > 0 else f for k, f in enumerate(stretched)]  # half of them inverted
    extreme = [np.diag([2.5, 0.6, 0.3]), -np.eye(3), np.diag([1.0, 1.0, -0.5]), np.diag([1.0, 1.0, 1e-4]), np.array([[1.2, 0.36, 0.0], [0.0, 1.2, 0.0], [0.0, 0.0, -1.2]])]
    Fs = np.array(stretched + extreme)
    assert (np.linalg.det(Fs) < 0).sum() >= 20
    psi, pk1 = _core.snh_energy(Fs, mu, lam), _core.snh_pk1(Fs, mu, lam)
    exact, projected = _core.snh_hessian(Fs, mu, lam, project=False), _core.snh_hessian(Fs, mu, lam, project=True)
    worst = np.zeros(4)
    for F, e_ref, p_ref, h_ref, hp_ref in zip(Fs, psi, pk1, exact, projected):
        x = rest @ F.T + np.array([0.3, -0.2, 0.1])
        np.testing.assert_allclose(mesh.deformation_gradients(x)[0], F, rtol=0, atol=1e-13)
        g_ref = volume * shape_gradients @ p_ref.T  # row a: V P n_a
        H_ref, Hp_ref = (volume * dvecf.T @ h @ dvecf for h in (h_ref, hp_ref))
        errors = (abs(sim.energy(x, "elastic") - volume * e_ref) / abs(volume * e_ref),
                  np.abs(sim.gradient(x, "elastic") - g_ref).max() / np.abs(g_ref).max(),
                  np.abs(sim.hessian(x, "elastic", project=False).toarray() - H_ref).max() / np.abs(H_ref).max(),
                  np.abs(sim.hessian(x, "elastic").toarray() - Hp_ref).max() / np.abs(Hp_ref).max())
        worst = np.maximum(worst, errors)
    print(f"warp against licrom._core over {len(Fs)} F ({(np.linalg.det(Fs) < 0).sum()} inverted): largest relative differences "
          f"energy {worst[0]:.1e}, stress {worst[1]:.1e}, Hessian {worst[2]:.1e}, projected Hessian {worst[3]:.1e}")
    assert (worst < 1e-12).all()


def _identity_core(sim, scene, mass, **changes):
    """licrom._core.ReducedCore of the same scene with q the displacement of every vertex (an identity basis), FullSim's contact
    points, no elastic term (no cubature) and the mass matrix ``mass * I``: its energy is the same incremental potential."""
    n = 3 * sim.n_vertices
    idx = sim.contact_indices
    basis = np.zeros((len(idx), 3, n))
    for j, v in enumerate(idx):
        basis[j, :, 3 * v : 3 * v + 3] = np.eye(3)
    c = scene.contact
    mu, lam = scene.material.snh_parameters
    kwargs = dict(mass=mass * np.eye(n), gravity_force=np.zeros(n), cubature_jacobians=np.zeros((0, 9, n)), cubature_weights=np.zeros(0),
                  mu=mu, lam=lam, contact_basis=basis, contact_rest=sim.mesh.vertices[idx], contact_areas=sim.contact_areas,
                  planes=scene.plane_array(), normal_stiffness=c.normal_stiffness, normal_damping=c.normal_damping,
                  friction_stiffness=c.friction_stiffness, dt=scene.dt, total_mass=1.0, tolerance=1e-6, max_iterations=50,
                  integrator=scene.integrator)
    return _core.ReducedCore(**{**kwargs, **changes})


@pytest.mark.parametrize("integrator", ["backward_euler", "bdf2"])
def test_contact_and_friction_match_the_native_core_point_for_point(rng, integrator):
    """Penalty, damping and friction of every contact point against the Rust contact model (``rust/core/src/contact.rs``): a
    ReducedCore whose coordinates are the vertex displacements gives the same incremental potential, its gradient (the force at
    each point) and Hessian, from the same start state and lagged normal forces, in and out of contact, approaching and receding,
    sticking and slipping, on two planes."""
    mesh = meshes.box(L, resolution=1)
    contact = ContactParams(normal_stiffness=1e7, normal_damping=3e4, friction_stiffness=1e7)
    planes = (Plane((0, 0, 1), L / 2 - 2e-3, 0.5), Plane((-1, 0, 0.2), L / 2 - 1e-3, 0.3))  # the floor 2 mm and a wall ~1 mm deep
    scene = Scene(material=Material(1e5, 0.3), planes=planes, contact=contact, gravity=(0.0, 0.0, 0.0), integrator=integrator)
    sim = FullSim(mesh, scene, device="cpu")
    # Without gravity both start BDF2 from x_prev = x - h v, v_prev = v: anchor x_a = x + h v / 3, effective step h' = 2h/3,
    # and x~ = x_a + h' v = x + h v either way. The core's inertia, of a negligible mass, is taken off exactly.
    mass, h = 1e-12, scene.dt
    h_eff = h if integrator == "backward_euler" else 2 * h / 3
    terms_and_cores = {
        ("penalty",): _identity_core(sim, scene, mass, normal_damping=0.0, planes=scene.plane_array() * [1, 1, 1, 1, 0]),
        ("penalty", "damping"): _identity_core(sim, scene, mass, planes=scene.plane_array() * [1, 1, 1, 1, 0]),
        ("penalty", "damping", "friction"): _identity_core(sim, scene, mass),
    }
    x0 = mesh.vertices + 1e-4 * rng.standard_normal(mesh.vertices.shape)
    v0 = 0.05 * rng.standard_normal(mesh.vertices.shape)
    sim.set_state(x0, v0)
    for core in terms_and_cores.values():
        core.set_state((x0 - mesh.vertices).ravel(), v0.ravel())
    x_a = x0 if integrator == "backward_euler" else x0 + h * v0 / 3
    x_tilde = x0 + h * v0
    plane_rows = scene.plane_array()
    areas = sim.contact_areas
    fn = areas[:, None] * contact.normal_stiffness * np.maximum(-(x0[sim.contact_indices] @ plane_rows[:, :3].T + plane_rows[:, 3]), 0.0)
    threshold = 0.5 * contact.normal_stiffness * 2e-3 * h_eff / contact.friction_stiffness  # the floor's slip where stick turns into slip
    regimes = set()
    worst = 0.0
    for _ in range(6):
        # Along the floor 0.3 to 3 times its stick threshold from the anchor; pushed in (approaching) or lifted out, up to 2.5 mm.
        direction = rng.standard_normal((mesh.n_vertices, 2))
        x = x_a.copy()
        x[:, :2] += threshold * rng.uniform(0.3, 3.0, (mesh.n_vertices, 1)) * direction / np.linalg.norm(direction, axis=1, keepdims=True)
        x[:, 2] += rng.uniform(-1.5e-3, 2.5e-3, mesh.n_vertices)
        for j, v in enumerate(sim.contact_indices):
            for p, (normal, offset) in enumerate(zip(plane_rows[:, :3], plane_rows[:, 3])):
                regimes.add("in" if normal @ x[v] + offset < 0 else "out")
                if fn[j, p] > 0:
                    dx = x[v] - x_a[v]
                    regimes.add("approaching" if normal @ dx < 0 else "receding")
                    slip = np.linalg.norm(dx - (normal @ dx) * normal)
                    regimes.add("sticking" if areas[j] * contact.friction_stiffness / h_eff * slip <= plane_rows[p, 4] * fn[j, p] else "slipping")
        q = (x - mesh.vertices).ravel()
        d = (x - x_tilde).ravel()
        inertia = (0.5 * mass / h_eff**2 * d @ d, mass / h_eff**2 * d, mass / h_eff**2 * np.eye(q.size))
        for terms, core in terms_and_cores.items():
            e, g, H = sim.energy(x, terms), sim.gradient(x, terms).ravel(), sim.hessian(x, terms).toarray()
            e_ref, g_ref, H_ref = core.energy(q) - inertia[0], core.gradient(q) - inertia[1], core.hessian(q) - inertia[2]
            errors = abs(e - e_ref) / abs(e_ref), np.abs(g - g_ref).max() / np.abs(g_ref).max(), np.abs(H - H_ref).max() / np.abs(H_ref).max()
            assert max(errors) < 1e-12, f"{terms}: relative differences (energy, gradient, Hessian) {errors}"
            worst = max(worst, *errors)
    print(f"{integrator}: warp against the Rust contact model, largest relative difference {worst:.1e}; regimes {sorted(regimes)}")
    assert regimes == {"in", "out", "approaching", "receding", "sticking", "slipping"}


# --- motion -------------------------------------------------------------------------------


def test_free_fall_is_discrete_backward_euler():
    mesh = meshes.box(L, resolution=2)
    v0 = np.array([0.5, -0.2, 1.0])
    scene = Scene(material=STIFF, planes=(), initial=InitialState(translation=(0, 0, 1), velocity=tuple(v0)))
    sim = FullSim(mesh, scene)
    traj = sim.run(50)
    h, g = scene.dt, np.array(scene.gravity)
    x, v = np.array([0, 0, 1.0]), v0.copy()
    worst = 0.0
    for k in range(1, 51):
        x, v = x + h * v + h * h * g, v + h * g
        worst = max(worst, np.abs(traj.displacements[k] - x).max(), np.abs(traj.velocities[k] - v).max())
    print(f"free fall: max deviation from the point-mass recursion {worst:.2e} (m, m/s); iterations {set(traj.iterations)}")
    assert worst < 1e-10
    assert traj.converged.all()


def test_free_fall_centre_of_mass_of_a_spinning_body():
    mesh = meshes.box((0.1, 0.06, 0.04), resolution=3)
    scene = Scene(
        material=Material(1e5, 0.3),
        planes=(),
        solver=SolverParams(tolerance=1e-10),
        initial=InitialState(velocity=(0.3, 0, 0.5), angular_velocity=(2.0, 5.0, -3.0)),
    )
    sim = FullSim(mesh, scene)
    c0, v0 = _com(sim)
    h, g = scene.dt, np.array(scene.gravity)
    for _ in range(30):
        sim.step()
        c0, v0 = c0 + h * v0 + h * h * g, v0 + h * g
    c, v = _com(sim)
    print(f"spinning body: centre of mass off the point-mass recursion by {np.abs(c - c0).max():.2e} m")
    assert np.abs(c - c0).max() < 1e-10 and np.abs(v - v0).max() < 1e-8


INTEGRATORS = ["backward_euler", "bdf2"]


@pytest.mark.parametrize("integrator", INTEGRATORS)
@pytest.mark.parametrize("theta, mu", [(10.0, 0.3), (20.0, 0.5), (30.0, 0.7)])
def test_box_sticks_on_incline_below_friction_angle(theta, mu, integrator):
    assert math.tan(math.radians(theta)) < mu
    mesh, scene, downhill = _box_on_incline(theta, mu)
    sim = FullSim(mesh, scene.replace(integrator=integrator))
    c0, _ = _com(sim)
    sim.run(100)
    c, v = _com(sim)
    slide = (c - c0) @ downhill
    print(f"stick ({integrator}) theta={theta} mu={mu}: moved {1e6 * slide:.2f} um down the slope in 1 s, speed {1e6 * abs(v @ downhill):.2f} um/s")
    assert abs(slide) < 1e-4  # 0.1 mm (creep of the friction regularisation k_f: ~ rho L g sin(theta) / k_f)


@pytest.mark.parametrize("integrator", INTEGRATORS)
@pytest.mark.parametrize("theta, mu", [(30.0, 0.3), (25.0, 0.2), (35.0, 0.5), (40.0, 0.8)])
def test_box_slides_on_incline_with_coulomb_acceleration(theta, mu, integrator):
    t = math.radians(theta)
    assert math.tan(t) > mu
    mesh, scene, downhill = _box_on_incline(theta, mu)
    sim = FullSim(mesh, scene.replace(integrator=integrator))
    traj = sim.run(100)
    w = sim.masses / sim.masses.sum()
    v = np.einsum("fnk,n,k->f", traj.velocities, w, downhill)
    window = traj.times >= 0.3  # after the landing transient
    a = np.polyfit(traj.times[window], v[window], 1)[0]
    expected = G * (math.sin(t) - mu * math.cos(t))
    print(f"slide ({integrator}) theta={theta} mu={mu}: a = {a:.5f} m/s^2, analytic {expected:.5f} m/s^2 (error {100 * (a / expected - 1):+.3f}%)")
    assert a == pytest.approx(expected, rel=0.02)


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_box_pushed_on_flat_ground_stops_at_analytic_distance(integrator):
    mu, v0 = 0.3, 2.0
    mesh, scene, direction = _box_on_incline(0.0, mu, speed=v0, dt=0.005)
    sim = FullSim(mesh, scene.replace(integrator=integrator))
    c0, _ = _com(sim)
    sim.run(200)  # 1 s; it stops after v0 / (mu g) = 0.68 s
    c, v = _com(sim)
    distance = (c - c0) @ direction
    expected = v0**2 / (2 * mu * G)
    print(f"push ({integrator}) v0={v0} mu={mu}: stopped after {distance:.5f} m, analytic {expected:.5f} m (error {100 * (distance / expected - 1):+.3f}%)")
    assert np.linalg.norm(v) < 1e-3
    assert distance == pytest.approx(expected, rel=0.03)


def test_contact_forces_carry_the_weight_at_rest():
    mesh, scene, _ = _box_on_incline(0.0, 0.5)
    sim = FullSim(mesh, scene)
    assert np.all(sim.contact_forces() == 0)
    sim.run(30)
    f = sim.contact_forces()
    assert f.shape == (len(sim.contact_indices), 3)
    total = f.sum(axis=0)
    weight = sim.masses.sum() * G
    print(f"resting box: contact force {total} N, weight {weight:.5f} N")
    assert total[2] == pytest.approx(weight, rel=1e-3)
    assert np.abs(total[:2]).max() < 1e-3 * weight


def test_cheese_dropped_on_incline_stays_sound():
    mesh = meshes.cheese(resolution=6)
    theta, mu = 20.0, 0.5
    t = math.radians(theta)
    normal = np.array([math.sin(t), 0.0, math.cos(t)])
    scene = Scene(
        planes=(Plane.incline(theta, mu),),
        contact=CONTACT,
        initial=InitialState(translation=tuple(0.1 * normal), rotation=(0.3, 0.2, 0.1)),
    )
    sim = FullSim(mesh, scene)
    depth, min_j, iterations = 0.0, np.inf, []
    for _k in range(1000):
        its, _ = sim.step()
        iterations.append(its)
        x = sim.positions
        assert np.isfinite(x).all()
        depth = max(depth, -float((x @ normal).min()))
        min_j = min(min_j, float(np.linalg.det(mesh.deformation_gradients(x)).min()))
    print(
        f"cheese drop ({mesh.n_tets} tets, 1000 steps): max penetration {1e3 * depth:.3f} mm, min J {min_j:.3f}, "
        f"Newton iterations mean {np.mean(iterations):.2f} max {max(iterations)}"
    )
    assert min_j > 0.0
    assert depth < 2e-3  # 1% of the cheese's 0.2 m length
    _, v = _com(sim)
    assert np.linalg.norm(v) < 0.05  # it came to rest on the 20 deg slope (tan 20 < 0.5)


# --- failure and API -------------------------------------------------------------------------


def test_failed_step_raises_and_leaves_state_unchanged():
    mesh, scene, _ = _box_on_incline(30.0, 0.3, speed=0.5)
    scene = scene.replace(solver=SolverParams(tolerance=1e-14, max_iterations=1))
    sim = FullSim(mesh, scene)
    x0, v0 = sim.positions, sim.velocities
    with pytest.raises(SolverError, match=r"step 0 .*residual .* 1 iterations") as info:
        sim.step()
    assert info.value.iterations == 1 and info.value.residual > 1e-14
    np.testing.assert_array_equal(sim.positions, x0)
    np.testing.assert_array_equal(sim.velocities, v0)
    assert sim.time == 0.0


def test_failed_steps_are_recorded_on_request():
    mesh, scene, _ = _box_on_incline(30.0, 0.3, speed=0.5)
    scene = scene.replace(solver=SolverParams(tolerance=1e-14, max_iterations=1, on_failure="record"))
    traj = FullSim(mesh, scene).run(3)
    assert traj.converged.tolist() == [False, False, False]
    assert traj.iterations.tolist() == [1, 1, 1]
    assert np.isfinite(traj.displacements).all() and traj.n_frames == 4
    assert traj.info["unconverged_steps"] == 3


def test_run_records_frames_and_metadata():
    mesh, scene, _ = _box_on_incline(30.0, 0.3)
    sim = FullSim(mesh, scene)
    traj = sim.run(6, record_every=3)
    np.testing.assert_allclose(traj.times, [0.0, 0.03, 0.06])
    assert len(traj.iterations) == len(traj.residuals) == len(traj.step_seconds) == 6
    assert traj.converged.all() and (traj.residuals < scene.solver.tolerance).all()
    assert traj.info["source"] == "full" and traj.info["n_tets"] == mesh.n_tets
    np.testing.assert_allclose(traj.positions(2), sim.positions, atol=1e-15)
    assert sim.time == pytest.approx(0.06)


def test_device_auto_picks_cuda_when_warp_sees_a_gpu_and_says_which(monkeypatch, caplog):
    import logging

    from licrom.full import device as device_module
    from licrom.full import resolve_device

    mesh, scene, _ = _box_on_incline(0.0, 0.5, res=1)
    gpus = device_module.warp_ready().get_cuda_device_count()
    expected = "cuda" if gpus else "cpu"
    assert resolve_device(None) == resolve_device("auto") == expected
    with caplog.at_level(logging.INFO, logger="licrom.full"):
        sim = FullSim(mesh, scene)
    assert sim.device == expected
    assert f"on {expected}" in caplog.text and f"{mesh.n_tets} tets" in caplog.text
    assert sim.run(1).info["device"] == expected
    # The choice itself, with and without a GPU in sight (nothing is launched).
    monkeypatch.setattr(device_module.warp_ready(), "get_cuda_device_count", lambda: 1)
    assert resolve_device(None) == "cuda" and resolve_device("cuda:0") == "cuda:0"
    with pytest.raises(ConfigError, match=r"cuda:1.*1 CUDA device"):
        resolve_device("cuda:1")
    monkeypatch.setattr(device_module.warp_ready(), "get_cuda_device_count", lambda: 0)
    assert resolve_device(None) == "cpu" and resolve_device("cpu") == "cpu"
    for name in ("cuda", "cuda:0"):
        with pytest.raises(ConfigError, match=r"no CUDA device.*accepted here: auto, cpu"):
            FullSim(mesh, scene, device=name)


def test_custom_contact_points_and_validation():
    mesh, scene, _ = _box_on_incline(0.0, 0.5)
    sub = mesh.boundary_vertices[:5]
    sim = FullSim(mesh, scene, contact_points=(sub, np.full(5, 1e-3)))
    np.testing.assert_array_equal(sim.contact_indices, sub)
    with pytest.raises(ConfigError, match="auto, cpu, cuda, cuda:N"):
        FullSim(mesh, scene, device="gpu")
    with pytest.raises(ConfigError, match="vertex indices"):
        FullSim(mesh, scene, contact_points=([0, mesh.n_vertices], [1.0, 1.0]))
    with pytest.raises(ShapeError):
        FullSim(mesh, scene, contact_points=([0, 1], [1.0]))
    with pytest.raises(ShapeError, match="shape"):
        sim.set_state(positions=np.zeros((3, 3)))
    bad = sim.positions
    bad[0, 0] = np.nan
    with pytest.raises(ShapeError, match="NaN"):
        sim.set_state(positions=bad)
    with pytest.raises(ConfigError):
        sim.run(-1)
    with pytest.raises(ConfigError):
        sim.run(2, record_every=0)
    v = np.ones((mesh.n_vertices, 3))
    sim.set_state(velocities=v)
    np.testing.assert_array_equal(sim.velocities, v)


def test_cpu_run_prints_no_missing_driver_warning_but_other_native_output_passes(capfd):
    import os
    import subprocess
    import sys

    from licrom.full.device import _NO_DRIVER_WARNING, _native_stderr_without

    code = ("import licrom; licrom.FullSim(licrom.meshes.box(resolution=1), licrom.Scene()).run(1); "
            "import warp; print(warp.get_cuda_device_count())")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert _NO_DRIVER_WARNING not in r.stderr and "Warp CUDA warning" not in r.stderr
    with _native_stderr_without(_NO_DRIVER_WARNING):
        os.write(2, f"Warp CUDA warning: {_NO_DRIVER_WARNING}. GPU execution will not be available.\n".encode())
        os.write(2, b"Warp CUDA error: a real error\n")
    err = capfd.readouterr().err
    assert err == "Warp CUDA error: a real error\n"


def test_one_simulation_in_two_threads_is_a_named_error_and_its_state_stays_a_serial_run():
    import threading

    from licrom import ConcurrencyError

    mesh = meshes.box(L, resolution=2)
    scene = Scene(material=STIFF, contact=CONTACT, planes=(Plane((0, 0, 1), 0.05, 0.5),), initial=InitialState(velocity=(0.2, 0, -0.5)))
    sim = FullSim(mesh, scene, device="cpu")
    raised, taken = [], [0, 0]

    def contend(k):
        # Both threads read and step the one simulation until one of them is refused.
        while not raised and taken[k] < 1000:
            try:
                _ = sim.positions
                sim.step()
                taken[k] += 1
            except Exception as exc:  # collected: anything but ConcurrencyError fails the test
                raised.append(exc)

    thread = threading.Thread(target=contend, args=(1,))
    thread.start()
    contend(0)
    thread.join()
    assert raised and all(isinstance(e, ConcurrencyError) for e in raised), raised
    assert "busy in another thread" in str(raised[0]) and isinstance(raised[0], RuntimeError)
    # The steps that ran went one after the other: the state is that of a serial run of as many steps.
    serial = FullSim(mesh, scene, device="cpu")
    for _ in range(sum(taken)):
        serial.step()
    np.testing.assert_array_equal(sim.positions, serial.positions)
    np.testing.assert_array_equal(sim.velocities, serial.velocities)
    assert sim.time == serial.time and sim.run(2).n_frames == 3  # the refused call left it usable


def test_a_first_run_says_that_warp_compiles_its_kernels(tmp_path, monkeypatch):
    """The line comes where the kernel cache lacks a module (a fresh install), and not once it holds them all."""
    import warp as wp
    from licrom.full import device

    loaded = []
    device.warp_ready()  # its initialisation sets the cache folder
    monkeypatch.setattr(wp.config, "kernel_cache_dir", str(tmp_path))
    monkeypatch.setattr(wp, "load_module", lambda m, device: loaded.append((m.name, device)))
    said = []
    device.load_kernels("cpu", said.append)
    assert len(said) == 1 and "compiling" in said[0] and "first run only" in said[0]
    assert sorted(name for name, _ in loaded) == sorted(f"licrom.full.{n}" for n in device.KERNEL_MODULES)
    for name in device.KERNEL_MODULES:
        folder = tmp_path / wp.get_module(f"licrom.full.{name}").get_module_identifier()
        folder.mkdir()
        (folder / "module.o").write_bytes(b"")
    said.clear()
    device.load_kernels("cpu", said.append)
    assert said == []
    device.load_kernels("cuda", said.append)  # built for the CPU only
    assert len(said) == 1


def test_impact_frames_are_the_every_step_run_between_frames_after_the_landing():
    mesh = meshes.box(L, resolution=1)
    scene = Scene(material=STIFF, planes=(Plane(),), contact=CONTACT, dt=0.005,
                  initial=InitialState(translation=(0.0, 0.0, L / 2 + 0.004)))  # lands after about 29 ms
    every = FullSim(mesh, scene).run(16)
    traj = FullSim(mesh, scene).run(16, record_every=4, impact_window=0.02)
    landing = int(np.argmax(every.penetration > 0))  # the first step that ends inside the plane
    expected = [s for s in range(landing, landing + 4) if s % 4]
    assert 0 < landing < 12 and len(expected) >= 2
    np.testing.assert_allclose(traj.impact_times, every.times[expected], atol=1e-12)
    np.testing.assert_allclose(traj.impact_displacements, every.displacements[expected], atol=1e-12)
    np.testing.assert_allclose(traj.displacements, every.displacements[::4], atol=1e-12)
    assert FullSim(mesh, scene).run(16, record_every=4).impact_displacements.shape == (0, mesh.n_vertices, 3)
    with pytest.raises(ConfigError, match="impact_window"):
        FullSim(mesh, scene).run(4, impact_window=-0.1)
