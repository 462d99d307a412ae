"""Reduced-space simulation in the world frame: ``x = X + W(X) q`` stepped by the Rust core.

Python prepares, once, everything the subspace needs on the mesh — the exact
reduced mass matrix and gravity force over all vertices, the basis Jacobians at the
cubature points, the basis values at the contact points — and hands it to
``licrom._core.ReducedCore``, which runs the Newton solve of the reduced
incremental potential without the GIL.

:class:`WorldFrameSim` is what ``ReducedSim(basis, ...)`` gives for any basis but a
body-frame model (:func:`licrom.reduced.factory.reduced_sim`); it shares
:class:`licrom.reduced.base.ReducedSim` with the body-frame simulation.
"""

from __future__ import annotations

import numpy as np

from .. import _core
from ..errors import ConfigError
from ..geometry.mesh import Mesh
from ..records.trajectory import Trajectory
from ..rigid import body_frame_displacements
from ..scene.scene import Scene
from ..stepping import record_run
from ..subspace.basis import Basis, SubspaceProjector, check_basis, check_basis_output, strain_jacobians
from ..subspace.cubature import ContactPoints, Cubature
from ..validity import check_start
from .base import ReducedSim, _fitted_cubature, mesh_and_scene, native_inputs, sampling, warn_off_resolution
from .cubature_error import CubatureError
from .error_estimate import ErrorMonitor, residual_stride

__all__ = ["SOLVERS", "WorldFrameSim"]

SOLVERS = ("newton", "prefactored")


class WorldFrameSim(ReducedSim):
    """Simulate a solid in a subspace of displacement fields, in the world frame.

    ``ReducedSim(basis, ...)`` gives one for every basis but a body-frame model; build one
    directly to run a body-frame model's modes in the world frame. Threads are used as
    described in :class:`~licrom.reduced.base.ReducedSim`.

    Args:
        basis: a basis (``n_modes``, ``values``, ``jacobians``) or a trained ``licrom.Model``.
        mesh: the mesh to simulate (default: the model's mesh).
        scene: the scene (default: the model's default scene).
        cubature: cubature tets and weights, or a name of :data:`~licrom.reduced.base.CUBATURES` (default: the
            model's fitted cubature, refitted on another mesh; the naive scheme with 1000 tets
            for a basis without one).
        contact_points: where contact acts (default: :meth:`ContactPoints.default`, every boundary vertex up to
            :data:`~licrom.subspace.cubature.DEFAULT_CONTACT_POINTS`, a farthest-point subset of that many above).
        solver: ``"newton"`` (dense Newton, Cholesky, line search) or ``"prefactored"``
            (the report's scheme: the elastic stiffness kept at rest, ``M_r/h^2 + K_r(rest)``
            factored once and again only when contact terms change; a step that needs more
            than ``licrom_core``'s ``PREFACTORED_BUDGET`` (25) directions finishes with Newton,
            counted as ``fallbacks`` in the solver stats).
        strain: how the deformation gradient at the cubature tets follows q: ``"mesh"``
            (the linear-tet gradient of the basis' vertex values, as in the FEM) or
            ``"field"`` (the basis' own gradient, LiCROM as published); see
            :func:`licrom.subspace.basis.strain_jacobians`.

    Raises:
        ConfigError: unknown solver, missing mesh/scene, singular reduced mass matrix.
        ShapeError: the basis returns arrays of the wrong shape or with NaN/inf.
        ConcurrencyError: (from any method) the simulation is in use by another thread.
    """

    def __init__(
        self,
        basis: Basis,
        mesh: Mesh | None = None,
        scene: Scene | None = None,
        cubature: Cubature | str | None = None,
        contact_points: ContactPoints | None = None,
        solver: str = "newton",
        strain: str = "mesh",
    ) -> None:
        mesh, scene = mesh_and_scene("ReducedSim", mesh, scene, basis, "a trained model", (basis,))
        if solver not in SOLVERS:
            raise ConfigError(f"solver must be one of {SOLVERS}, got {solver!r}")
        check_basis(basis)
        self.basis = basis
        self.mesh = mesh
        self.scene = scene
        self.solver = solver
        self.cubature, self.contact_points = sampling(mesh, cubature, contact_points, basis)

        k = int(basis.n_modes)
        n = mesh.n_vertices
        self._values = check_basis_output("values", basis.values(mesh.vertices), (n, 3, k))
        self.strain = strain
        jac = check_basis_output("jacobians", strain_jacobians(basis, mesh, self.cubature.tets, strain, self._values), (self.cubature.count, 3, 3, k))
        self._masses = mesh.vertex_masses(scene.material.density)
        self._projector = SubspaceProjector(self._values, self._masses)
        gravity_force = self._projector.reduce(self._masses[:, None] * np.asarray(scene.gravity))
        self._free_fall = np.linalg.solve(self._projector.reduced_mass, gravity_force)  # gravity's acceleration of q
        self._jacobians = np.ascontiguousarray(jac.reshape(self.cubature.count, 9, k))
        self._core = _core.ReducedCore(
            mass=self._projector.reduced_mass,
            gravity_force=gravity_force,
            total_mass=float(self._masses.sum()),
            solver=solver,
            **native_inputs(self, strain, mesh.vertices),
        )
        self._reconstruction = _core.Reconstruction(self._values, mesh.vertices)
        self._monitor = ErrorMonitor(mesh, self._values, mesh.vertices, scene, stride=residual_stride(self.cubature.count, k),
                                     cubature_error=CubatureError(mesh, self._values, mesh.vertices, scene, self.cubature,
                                                                  self._jacobians if strain == "field" else None, self._projector.reduced_mass))
        warn_off_resolution(basis, mesh, "the reduced simulation")
        self.time = 0.0
        positions, velocities = scene.initial.apply(mesh.vertices, self._masses)
        self.set_state(positions, velocities)

    # --- state -------------------------------------------------------------------------
    @property
    def reduced_mass(self) -> np.ndarray:
        """(k, k) exact reduced mass matrix ``W^T M W``."""
        return self._projector.reduced_mass

    @property
    def positions(self) -> np.ndarray:
        """(n, 3) vertex positions ``X + W q`` in m."""
        return self._reconstruction.positions(self._core.q)

    @property
    def velocities(self) -> np.ndarray:
        """(n, 3) vertex velocities ``W q_dot`` in m/s."""
        return self._reconstruction.positions(self._core.qdot) - self.mesh.vertices

    def project(self, displacements: np.ndarray) -> np.ndarray:
        """Mass-weighted projection ``q = M_r^-1 W^T M u`` of (..., n, 3) displacements."""
        return self._projector.project(displacements)

    def set_state(self, positions: np.ndarray | None = None, velocities: np.ndarray | None = None) -> None:
        """Set the state from full-space positions/velocities, projected onto the subspace.

        Either may be omitted to keep its current value. Warns
        (:class:`~licrom.errors.PhysicsWarning`) when the state puts a vertex deeper inside
        a plane than ``licrom.validity.PENETRATION_LIMIT`` of the object's size.
        """
        q = self.q if positions is None else self.project(self._check_field("positions", positions) - self.mesh.vertices)
        qdot = self.qdot if velocities is None else self.project(self._check_field("velocities", velocities))
        self._core.set_state(q, qdot)
        if positions is not None:
            check_start(self.positions, self.scene.plane_array(), self.mesh.size, "the reduced simulation")

    # --- stepping ----------------------------------------------------------------------
    def run(self, steps: int, record_every: int = 1, progress: bool = False) -> Trajectory:
        """Step ``steps`` times and record every ``record_every``-th state (frame 0 is now).

        With ``scene.solver.on_failure == "record"``, a step that does not converge is
        recorded as unconverged and the run continues from the last iterate.
        ``info["solver_stats"]`` holds the solver's work counters over the run
        (``ReducedCore.stats``: iterations, factorizations, prefactored ``fallbacks``, ...).
        Each frame's smallest ``det F`` at the cubature points and deepest penetration of a
        vertex into a plane are recorded, with a :class:`~licrom.errors.PhysicsWarning`
        where they leave the valid range (:mod:`licrom.validity`).
        """
        before = self._core.stats()
        monitor = self._monitor
        # The states before: those of the integrator's history (BDF2's after set_state: a free fall,
        # rust/core/src/integrator.rs; backward Euler reads q - h qdot).
        h = self.scene.dt
        fall = self._free_fall if self.scene.integrator == "bdf2" else np.zeros_like(self._free_fall)
        back = range(monitor.history_length - 1, -1, -1)
        monitor.start([monitor.sample_positions(self.q - k * h * self.qdot + 0.5 * (k * h) ** 2 * fall) for k in back], steps)

        def deformation(q: np.ndarray) -> float:
            bent = body_frame_displacements(self._reconstruction.positions(q), self.mesh.vertices, self._masses)
            return float(np.einsum("ni,ni,n->", bent, bent, self._masses))

        def step() -> tuple[int, float, bool]:
            outcome = self.step_or_record()
            monitor.after_step(lambda: (self.q, None, None), deformation)
            return outcome

        rec = record_run(step, lambda: (self.q, self.qdot), lambda: self.time, steps, record_every, progress, "reduced", self._core.validity)
        monitor.finish(self.q, deformation)
        work = {k: v - before[k] for k, v in sorted(self._core.stats().items())}
        qs = np.array([q for q, _ in rec.frames])
        qdots = np.array([qd for _, qd in rec.frames])
        w = self._values.reshape(-1, self._values.shape[2])
        n = self.mesh.n_vertices
        displacements = (qs @ w.T).reshape(-1, n, 3)
        return self._trajectory(rec, [self.mesh.vertices + displacements], displacements, (qdots @ w.T).reshape(-1, n, 3), qs, record_every,
                                "the reduced simulation",
                                {"solver": self.solver, "solver_stats": work, "q": qs.tolist() if qs.size <= 200_000 else None})

    # --- other meshes ------------------------------------------------------------------
    def transfer(self, mesh: Mesh, cubature: Cubature | None = None, contact_points: ContactPoints | None = None) -> WorldFrameSim:
        """The same state (q, q_dot) on another mesh of the same object.

        The subspace is continuous, so the reduced state carries over unchanged; the
        new simulation samples the basis on ``mesh`` (cubature: the model's fitted one refitted
        on ``mesh``, else the naive scheme with as many points as this one, unless given).
        """
        if cubature is None:
            cubature = _fitted_cubature(self.basis, mesh) or Cubature.naive(mesh, max(self.cubature.count, 1))
        other = WorldFrameSim(self.basis, mesh, self.scene, cubature=cubature, contact_points=contact_points, solver=self.solver, strain=self.strain)
        other._core.set_state(self.q, self.qdot)
        other.time = self.time
        return other

