"""The error estimate's cubature term (licrom.reduced.cubature_error): every tet's reduced force against the cubature's."""

from __future__ import annotations

import warnings

import licrom
import numpy as np
import pytest
from licrom import AccuracyWarning, Material, MeshBasis, Scene, _core, meshes
from licrom.analysis.compare import nonrigid_error
from licrom.reduced.body import BodyFrameSim
from licrom.reduced.cubature_error import CubatureError, evaluation_stride
from licrom.reduced.error_estimate import warn_estimate
from licrom.rigid import body_frame_displacements
from licrom.subspace.basis import strain_jacobians
from licrom.subspace.body_basis import BodyFrameBasis
from licrom.subspace.cubature import Cubature
from test_error_estimate import _scene

MATERIAL = Material(youngs_modulus=2.0e4, poisson_ratio=0.3, density=1000.0)


@pytest.fixture(scope="module")
def mesh() -> licrom.Mesh:
    return meshes.cheese(resolution=4)


@pytest.fixture(scope="module")
def basis(mesh) -> BodyFrameBasis:
    """The 6 symmetric affine modes and two bending modes, orthogonal to the rigid ones."""
    x = mesh.vertices - mesh.vertices.mean(axis=0)
    bend = np.zeros((mesh.n_vertices, 3, 2))
    bend[:, 2, 0] = x[:, 0] ** 2
    bend[:, 0, 1] = x[:, 1] * x[:, 2]
    return BodyFrameBasis(mesh, MeshBasis(mesh, bend))


def _term(mesh, basis, cubature, field: bool = False) -> tuple[CubatureError, np.ndarray, np.ndarray]:
    """The cubature term of ``basis`` on ``mesh`` with ``cubature``, with the mode values and the modal mass (``field``:
    the cubature's Jacobians given, as the reduced models pass them for ``strain="field"``; here the mesh strain's)."""
    values = basis.values(mesh.vertices)
    k = values.shape[2]
    masses = mesh.vertex_masses(MATERIAL.density)
    xbar = mesh.vertices - masses @ mesh.vertices / masses.sum()
    jac = strain_jacobians(basis, mesh, cubature.tets, "mesh", values).reshape(-1, 9, k)
    modal_mass = np.einsum("v,vic,vid->cd", masses, values, values)
    return CubatureError(mesh, values, xbar, Scene(material=MATERIAL), cubature, jac if field else None, modal_mass), values, modal_mass


def _energy(mesh, values, q, tets, weights) -> float:
    """``sum_t w_t Psi(F_t)`` over ``tets`` of the body ``Xbar + W q`` (the rest's gradient is I, so Xbar is X here)."""
    y = mesh.vertices + (values @ q)
    f = np.einsum("tai,taj->tij", y[mesh.tets[tets]], mesh.shape_gradients[tets])
    return float(weights @ _core.snh_energy(f, *MATERIAL.snh_parameters))


@pytest.mark.parametrize("field", [False, True])
def test_both_forces_are_the_gradients_of_their_energies(mesh, basis, field):
    # every tet's force from the vertices, the cubature's from the vertices too or from its Jacobians: each against
    # finite differences of its energy
    cubature = Cubature.naive(mesh, 40, seed=1)
    term, values, _ = _term(mesh, basis, cubature, field)
    q = np.random.default_rng(0).normal(scale=0.05, size=values.shape[2])
    everything, cub = term.forces(q)
    eps = 1e-6
    every = np.arange(mesh.n_tets)
    for i in range(len(q)):
        e = np.zeros_like(q)
        e[i] = eps
        fd_all = (_energy(mesh, values, q + e, every, mesh.rest_volumes) - _energy(mesh, values, q - e, every, mesh.rest_volumes)) / (2 * eps)
        fd_cub = (_energy(mesh, values, q + e, cubature.tets, cubature.weights) - _energy(mesh, values, q - e, cubature.tets, cubature.weights)) / (2 * eps)
        assert everything[i] == pytest.approx(fd_all, rel=1e-5, abs=1e-9 * np.abs(everything).max())
        assert cub[i] == pytest.approx(fd_cub, rel=1e-5, abs=1e-9 * np.abs(cub).max())


def test_every_tet_as_cubature_has_no_term(mesh, basis):
    term, values, modal_mass = _term(mesh, basis, Cubature.full(mesh))
    q = np.random.default_rng(1).normal(scale=0.05, size=values.shape[2])
    assert term.displacement(q) <= 1e-20 * float(q @ modal_mass @ q)


@pytest.mark.parametrize("field", [False, True])
def test_the_term_is_the_static_displacement_of_the_missing_force(mesh, basis, field):
    # |W dq|_M^2 with K dq = d, K the reduced stiffness at rest over every tet, formed here tet by tet
    cubature = Cubature.naive(mesh, 12, seed=2)
    term, values, modal_mass = _term(mesh, basis, cubature, field)
    q = np.random.default_rng(2).normal(scale=0.05, size=values.shape[2])
    everything, cub = term.forces(q)
    c = _core.snh_hessian(np.eye(3)[None], *MATERIAL.snh_parameters, False)[0]
    g = strain_jacobians(basis, mesh, np.arange(mesh.n_tets), "mesh", values).reshape(mesh.n_tets, 9, -1)
    stiffness = np.einsum("t,tic,ij,tjd->cd", mesh.rest_volumes, g, c, g)
    dq = np.linalg.solve(stiffness, everything - cub)
    assert term.displacement(q) == pytest.approx(float(dq @ modal_mass @ dq), rel=1e-8)
    assert term.displacement(q) > 0.0


@pytest.fixture(scope="module")
def run_basis(mesh) -> tuple[licrom.Scene, BodyFrameBasis]:
    """A scene and POD(16) of its full run's body-frame displacements: a basis that holds the run (1.4 % residual with
    every tet), so that a cubature's error shows."""
    scene = _scene(mesh)
    full = licrom.FullSim(mesh, scene).run(30)
    masses = mesh.vertex_masses(scene.material.density)
    bent = body_frame_displacements(full.rest_positions + full.displacements, mesh.vertices, masses)
    return scene, BodyFrameBasis(mesh, MeshBasis.pod(mesh, bent, 16)[0])


def test_a_few_cubature_tets_raise_the_estimate_and_the_warning_names_the_cubature(mesh, run_basis):
    scene, basis = run_basis
    exact = BodyFrameSim(basis, mesh, scene, cubature=Cubature.full(mesh)).run(30)
    assert exact.info["error_estimate_terms"]["cubature"] < 1e-8
    sim = BodyFrameSim(basis, mesh, scene, cubature=Cubature.naive(mesh, 40, seed=0))
    # a run shorter than the term's stride: its one value is the evaluation at the run's end (ErrorMonitor.finish)
    assert evaluation_stride(mesh.n_tets, 40, basis.n_modes) > 30
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run = sim.run(30)
    terms = run.info["error_estimate_terms"]
    assert run.error_estimate[-1] == pytest.approx(np.hypot(terms["residual"], terms["cubature"]))
    assert run.error_estimate[-1] > exact.error_estimate[-1]
    messages = [str(w.message) for w in caught if issubclass(w.category, AccuracyWarning)]
    assert len(messages) == 1 and f"the cubature's {100 * terms['cubature']:.3g} %" in messages[0]
    # the cubature's term follows what the cubature costs: the run's distance from the same model with every tet
    share = nonrigid_error(exact, run)
    assert 0.5 * share < terms["cubature"] < 2.0 * share, (terms, share)


def test_the_warning_names_the_larger_term():
    with pytest.warns(AccuracyWarning, match="more cubature tets"):
        warn_estimate(np.array([0.2]), "a run", terms={"residual": 0.05, "cubature": 0.19})
    with pytest.warns(AccuracyWarning, match="more modes"):
        warn_estimate(np.array([0.2]), "a run", terms={"residual": 0.19, "cubature": 0.05})


def test_world_frame_rigid_modes_add_nothing(mesh, basis):
    # the world frame's affine modes hold the rigid motions: no stiffness there (no division by it), and moving the
    # body adds nothing to the term
    modes = licrom.StackedBasis(licrom.AffineBasis(), basis.learned)
    cubature = Cubature.naive(mesh, 12, seed=3)
    values = modes.values(mesh.vertices)
    masses = mesh.vertex_masses(MATERIAL.density)
    jac = strain_jacobians(modes, mesh, cubature.tets, "mesh", values).reshape(-1, 9, values.shape[2])
    term = CubatureError(mesh, values, mesh.vertices, Scene(material=MATERIAL), cubature, jac, np.einsum("v,vic,vid->cd", masses, values, values))
    q = np.zeros(values.shape[2])
    q[12:] = (0.2, -0.1)  # the bending modes
    moved = q.copy()
    moved[9:12] = (0.1, -0.2, 0.3)  # [X1 I, X2 I, X3 I, I]: the translation
    bent = term.displacement(q)
    assert np.isfinite(bent) and bent > 0.0
    assert term.displacement(moved) == pytest.approx(bent, rel=1e-9)


def test_the_stride_keeps_the_term_to_its_share_of_the_steps():
    # a larger mesh costs more a pass, a heavier step (more cubature tets, more modes) less in proportion
    assert evaluation_stride(120378, 600, 256) > evaluation_stride(1638, 908, 256)
    assert evaluation_stride(1638, 908, 256) < evaluation_stride(1638, 100, 256) < evaluation_stride(1638, 100, 20)
    assert evaluation_stride(10, 10, 1) >= 1
