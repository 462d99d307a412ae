"""The full-space solver: Newton on the incremental potential of backward Euler or BDF2 (see :mod:`licrom.full`)."""

from __future__ import annotations

import logging
import math
import sys
import time
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from .. import _core
from ..errors import ConfigError, ShapeError, SolverError
from ..geometry.mesh import Mesh
from ..records.trajectory import Trajectory
from ..scene.scene import Scene
from ..stepping import ThreadGuard, check_field, check_impact_window, exclusive, record_run
from ..validity import check_start, penetration, tet_determinants, warn_frames, with_steps
from . import contact, damping, elastic, inertia, pcg, validity
from .device import (
    MODE_ENERGY,
    MODE_FORCES,
    MODE_GRADIENT,
    MODE_HESSIAN,
    MODE_RAW_HESSIAN,
    assembly,
    load_kernels,
    resolve_device,
    warp_ready,
)

__all__ = ["ENERGY_TERMS", "FullSim", "StepStats"]

_log = logging.getLogger("licrom.full")

ENERGY_TERMS = ("inertia", "elastic", "penalty", "damping", "friction", "viscosity")
"""Terms of the incremental potential, for :meth:`FullSim.energy` and friends: ``damping`` is the contact's
normal damping, ``viscosity`` the material's Kelvin-Voigt damping (:mod:`licrom.full.damping`)."""
_ALL_TERMS = (1 << len(ENERGY_TERMS)) - 1

# Energies and dot products are reduced through this many partial sums: one on the CPU
# (sequential, deterministic), many on a GPU (spreads the atomic additions).
_PARTIALS = {"cpu": 1, "cuda": 256}
_MAX_FORCING = 0.25  # loosest relative tolerance of the linear solves
_MIN_FORCING = 1.0e-10  # tightest relative tolerance of the linear solves


def _sufficient_decrease(e0: float, d0: float, e: float) -> bool:
    """Armijo's test of the core's line search for the whole step (``rust/core/src/solver/line_search.rs``,
    its constants ``licrom._core.LINE_SEARCH``), with its allowance for round-off."""
    constants = _core.LINE_SEARCH
    scale = max(abs(e0), abs(e))
    return math.isfinite(e) and e <= e0 + constants["armijo"] * d0 + constants["roundoff_ulps"] * sys.float_info.epsilon * scale


@dataclass(frozen=True)
class StepStats:
    """What the last :meth:`FullSim.step` did.

    Attributes:
        iterations: Newton directions computed.
        residual: final convergence measure ``sqrt(dx^T M dx / m_total) / h_eff`` in m/s (``h_eff`` the step's
            effective time step: ``h`` for backward Euler, ``2 h / 3`` for BDF2, whose velocity is ``(x - x_a) / h_eff``).
        converged: whether the residual met ``scene.solver.tolerance``.
        linear_iterations: conjugate-gradient iterations summed over the Newton iterations.
        energy_evaluations: incremental-potential evaluations of the line searches.
        seconds: wall time of the step, s.
    """

    iterations: int
    residual: float
    converged: bool
    linear_iterations: int
    energy_evaluations: int
    seconds: float


class FullSim:
    """Full-space simulation of one mesh in one scene (the ground truth).

    Args:
        mesh: the tet mesh (rest shape).
        scene: material, planes, contact stiffnesses, time step and integrator (backward Euler or
            BDF2), gravity, solver settings and initial state (applied on construction).
        device: ``None`` or ``"auto"`` (default: CUDA when warp sees a GPU, else the CPU),
            ``"cpu"``, ``"cuda"`` or ``"cuda:N"``. :attr:`device` holds the one chosen.
        contact_points: where contact acts: ``None`` for every boundary vertex with its share
            of the boundary area, or ``(indices, areas)`` (or an object with ``indices`` and
            ``areas`` attributes, such as ``licrom.subspace.cubature.ContactPoints``).

    Threads: one simulation serves one thread at a time, as the reduced simulations do: a call
    (step, run, state, evaluation) while another thread's call on it runs raises
    :class:`~licrom.errors.ConcurrencyError` at once rather than interleaving the two on one state
    (give each thread its own simulation, or guard a shared one with a ``threading.Lock``).

    Raises:
        ConfigError: unknown device, or bad contact points.
        ShapeError: contact-point arrays of the wrong shape.
        ConcurrencyError: (from any method) the simulation is in use by another thread.
    """

    def __init__(self, mesh: Mesh, scene: Scene, device: str | None = None, contact_points: Any = None) -> None:
        if not isinstance(mesh, Mesh):
            raise ConfigError(f"mesh must be a licrom.Mesh, got {type(mesh).__name__}")
        if not isinstance(scene, Scene):
            raise ConfigError(f"scene must be a licrom.Scene, got {type(scene).__name__}")
        self._guard = ThreadGuard()
        self.device = resolve_device(device)
        """The warp device the simulation runs on: ``"cpu"``, ``"cuda"`` or ``"cuda:N"``."""
        _log.info("full simulation of %d vertices, %d tets on %s", mesh.n_vertices, mesh.n_tets, self.device)
        self.mesh = mesh
        self.scene = scene
        idx, areas = self._check_contact_points(contact_points)
        wp = warp_ready()
        dev = self.device
        n = mesh.n_vertices
        self._n = n
        self._masses = mesh.vertex_masses(scene.material.density)
        self._total_mass = float(self._masses.sum())
        self._contact_idx = idx
        self._contact_areas = areas
        mu, lam = scene.material.snh_parameters
        self._mu, self._lam = float(mu), float(lam)
        self._alpha = 1.0 + 0.75 * self._mu / self._lam
        h = scene.dt
        self._h = h
        self._bdf2 = scene.integrator == "bdf2"
        self._h_step = h  # effective step of a step: h, or 2h/3 for BDF2
        self._eval_graphs: dict[tuple, Any] = {}  # _evaluate's recorded graphs on the CPU
        planes = scene.plane_array()

        f64 = wp.float64
        # Static data.
        self._tets = elastic.Tets()
        self._tets.ids = wp.array(mesh.tets.astype(np.int32), dtype=wp.vec4i, device=dev)
        self._tets.dminv = wp.array(mesh.shape_matrix_inverses, dtype=wp.mat33d, device=dev)
        self._tets.vol = wp.array(mesh.rest_volumes, dtype=f64, device=dev)
        self._mass = wp.array(self._masses, dtype=f64, device=dev)
        self._n_planes = len(planes)
        self._contacts = contact.Contacts()
        self._contacts.points = wp.array(idx.astype(np.int32), dtype=wp.int32, device=dev)
        self._contacts.areas = wp.array(areas, dtype=f64, device=dev)
        self._contacts.normals = wp.array(planes[:, :3].reshape(-1, 3), dtype=wp.vec3d, device=dev)
        self._contacts.offsets = wp.array(planes[:, 3].copy(), dtype=f64, device=dev)
        self._contacts.frictions = wp.array(planes[:, 4].copy(), dtype=f64, device=dev)
        self._contacts.fn_lag = wp.zeros((max(len(idx), 1), max(self._n_planes, 1)), dtype=f64, device=dev)
        c = scene.contact
        self._contacts.kn, self._contacts.kd, self._contacts.kf = c.normal_stiffness, c.normal_damping, c.friction_stiffness
        self._forces = wp.zeros(max(len(idx), 1), dtype=wp.vec3d, device=dev)

        # State and work arrays.

        def vec() -> Any:
            return wp.zeros(n, dtype=wp.vec3d, device=dev)

        self._x = vec()
        self._v = vec()
        self._v_prev = vec()
        self._have_prev = False
        self._x_start = vec()  # the step's anchor x_a: x_n for backward Euler, (4 x_n - x_{n-1}) / 3 for BDF2
        self._x_now = vec()  # x_n during a step
        self._x_prev = vec()  # x_{n-1} (BDF2's history; after set_state that of a free fall)
        # C_a = 2 E_a + I per tet: the material damping's anchor strain (licrom.full.damping), set each step.
        self._strain_anchor = wp.zeros(mesh.n_tets if scene.material.viscosity > 0.0 else 0, dtype=wp.mat33d, device=dev)
        self._x_tilde = vec()
        self._x_trial = vec()
        self._grad = vec()
        self._y = vec()
        parts = _PARTIALS["cpu" if dev == "cpu" else "cuda"]
        self._energy = wp.zeros(parts, dtype=f64, device=dev)
        self._gnorm = wp.zeros(parts, dtype=f64, device=dev)
        self._stats = wp.zeros((2, parts), dtype=f64, device=dev)
        self._validity = wp.zeros((2, parts), dtype=f64, device=dev)
        self._y_alt = vec()
        self._rhs = vec()
        self._count = wp.zeros(1, dtype=wp.int32, device=dev)
        self._stick_correction = True
        # Hessian pattern (a 3x3 block per vertex pair sharing a tet), values and the PCG solve.
        self._hess = pcg.BlockHessian(mesh.tets, n, dev, parts)
        self._out = assembly(self._energy, self._grad, self._hess)  # where the evaluations add up

        self.time = 0.0
        self._step_index = 0
        self._has_forces = False
        self.last_stats: StepStats | None = None
        positions, velocities = scene.initial.apply(mesh.vertices, self._masses)
        self.set_state(positions, velocities)

    # --- setup -------------------------------------------------------------------------
    def _check_contact_points(self, contact_points: Any) -> tuple[np.ndarray, np.ndarray]:
        mesh = self.mesh
        if contact_points is None:
            return np.asarray(mesh.boundary_vertices, dtype=np.int64), np.asarray(mesh.boundary_vertex_areas, dtype=np.float64)
        if hasattr(contact_points, "indices") and hasattr(contact_points, "areas"):
            raw_idx, raw_areas = contact_points.indices, contact_points.areas
        else:
            try:
                raw_idx, raw_areas = contact_points
            except (TypeError, ValueError):
                raise ConfigError("contact_points must be None or a pair (indices, areas)") from None
        idx = np.asarray(raw_idx)
        areas = np.asarray(raw_areas)
        if idx.ndim != 1 or areas.ndim != 1 or len(idx) != len(areas):
            raise ShapeError(f"contact_points indices and areas must be 1-d arrays of equal length, got shapes {idx.shape} and {areas.shape}")
        if len(idx) and not np.issubdtype(idx.dtype, np.integer):
            raise ShapeError(f"contact_points indices must be integers, got dtype {idx.dtype}")
        idx = idx.astype(np.int64)
        if len(idx) and (idx.min() < 0 or idx.max() >= mesh.n_vertices):
            raise ConfigError(f"contact_points indices must be vertex indices in [0, {mesh.n_vertices - 1}], found {idx.min()}..{idx.max()}")
        if len(np.unique(idx)) != len(idx):
            raise ConfigError("contact_points indices must not repeat a vertex")
        try:
            areas = areas.astype(np.float64)
        except (TypeError, ValueError):
            raise ShapeError(f"contact_points areas must be real numbers, got dtype {areas.dtype}") from None
        if not np.all(np.isfinite(areas)) or np.any(areas < 0):
            raise ConfigError("contact_points areas must be finite and >= 0 (m^2)")
        return idx, areas

    # --- state -------------------------------------------------------------------------
    @property
    def n_vertices(self) -> int:
        return self._n

    @property
    @exclusive
    def positions(self) -> np.ndarray:
        """(n, 3) float64 vertex positions in m (a copy)."""
        return self._x.numpy().astype(np.float64, copy=True)

    @property
    @exclusive
    def velocities(self) -> np.ndarray:
        """(n, 3) float64 vertex velocities in m/s (a copy)."""
        return self._v.numpy().astype(np.float64, copy=True)

    @exclusive
    def validity(self) -> tuple[float, float]:
        """``(min det F, depth)`` at the current state, computed on the device: the smallest
        tet ``det F`` and the deepest penetration of a vertex into a plane (m, >= 0)."""
        dev = self.device
        self._validity.fill_(np.inf)
        wp.launch(validity.tet_det_kernel, dim=self.mesh.n_tets, device=dev, inputs=[self._x, self._tets, self._validity])
        if self._n_planes:
            wp.launch(validity.depth_kernel, dim=self._n, device=dev, inputs=[self._x, self._contacts, self._validity])
        out = self._validity.numpy()
        return float(out[0].min()), max(-float(out[1].min()), 0.0)

    @property
    def masses(self) -> np.ndarray:
        """(n,) lumped vertex masses in kg."""
        return self._masses.copy()

    @property
    def contact_indices(self) -> np.ndarray:
        """(C,) vertex index of each contact point."""
        return self._contact_idx.copy()

    @property
    def contact_areas(self) -> np.ndarray:
        """(C,) boundary area carried by each contact point, m^2."""
        return self._contact_areas.copy()

    @exclusive
    def set_state(self, positions: np.ndarray | None = None, velocities: np.ndarray | None = None) -> None:
        """Set positions and/or velocities ((n, 3), m and m/s); an omitted one keeps its value.

        The step history starts afresh, as after construction: with ``scene.integrator == "bdf2"``
        the state one step back becomes that of a free fall, ``x - h v + h^2 g / 2`` and ``v - h g``
        (BDF2's start, the same in the reduced simulations), so every step is a BDF2 step and a
        free fall is exact from the first.

        Warns (:class:`~licrom.errors.PhysicsWarning`) when the positions put a
        vertex deeper inside a plane than ``licrom.validity.PENETRATION_LIMIT`` of the object's size.

        Raises:
            ShapeError: wrong shape, or NaN/inf values.
        """
        wp = warp_ready()
        if positions is not None:
            checked = self._check_field("positions", positions)
            check_start(checked, self.scene.plane_array(), self.mesh.size, "the full simulation")
            self._x.assign(wp.array(checked, dtype=wp.vec3d, device=self.device))
        if velocities is not None:
            self._v.assign(wp.array(self._check_field("velocities", velocities), dtype=wp.vec3d, device=self.device))
        self._has_forces = False
        self._have_prev = False
        if self._bdf2:  # BDF2's start: the history of a free fall, x - h v + h^2 g / 2 and v - h g
            x, v, g, h = self._x.numpy(), self._v.numpy(), np.asarray(self.scene.gravity), self._h
            self._x_prev.assign(wp.array(x - h * v + 0.5 * h * h * g, dtype=wp.vec3d, device=self.device))
            self._v_prev.assign(wp.array(v - h * g, dtype=wp.vec3d, device=self.device))

    def _check_field(self, name: str, a: Any) -> np.ndarray:
        return check_field(name, a, self._n)

    # --- evaluation --------------------------------------------------------------------
    def _begin_step(self) -> None:
        """Anchor x_a, x~ = x_a + h' v_a + h'^2 g, lagged normal forces at x_n; the iterate starts near x~.

        Backward Euler: x_a = x_n, v_a = v_n, h' = h. BDF2 (with a previous step to use; else this step is
        backward Euler): x_a = (4 x_n - x_{n-1}) / 3, v_a = (4 v_n - v_{n-1}) / 3, h' = 2h/3, so that the
        minimiser and ``v = (x - x_a) / h'`` satisfy ``3 x_{n+1} - 4 x_n + x_{n-1} = 2 h v_{n+1}`` and
        ``3 v_{n+1} - 4 v_n + v_{n-1} = 2 h M^-1 f(x_{n+1})``.
        """
        wp = warp_ready()
        dev = self.device
        history = self._bdf2
        h = self._h_step = 2.0 * self._h / 3.0 if history else self._h
        wp.launch(
            inertia.predict_kernel, dim=self._n, device=dev,
            inputs=[self._x, self._v, self._x_prev, self._v_prev, wp.float64(1.0 / 3.0 if history else 0.0), wp.float64(h),
                    wp.vec3d(*self.scene.gravity), wp.float64(1.0 if self._have_prev else 0.0),
                    wp.float64(h * h / self._h if history else h), self._x_now, self._x_start, self._x_tilde, self._x],
        )
        if self.scene.material.viscosity > 0.0:
            wp.launch(damping.anchor_kernel, dim=self.mesh.n_tets, device=dev,
                      inputs=[self._x_now, self._x_prev, self._tets, wp.float64(1.0 / 3.0 if history else 0.0), self._strain_anchor])
        if len(self._contact_idx) and self._n_planes:
            wp.launch(
                contact.lagged_normal_kernel, dim=(len(self._contact_idx), self._n_planes), device=dev,
                inputs=[self._x_now, self._contacts],
            )

    def _evaluate(self, x: Any, mode: int, terms: int = _ALL_TERMS) -> None:
        """Accumulate the energy partials (and gradient / Hessian for mode >= 1 / 2) at ``x``.

        ``terms`` bits: 1 inertia, 2 elastic, 4 penalty, 8 damping, 16 friction, 32 viscosity.

        On the CPU the evaluation (three memsets, up to four launches) is recorded once per
        (point array, mode, terms, effective step) as a warp graph and replayed, which skips the
        launches' Python argument packing (warp >= 1.13; :data:`pcg._CPU_CAPTURE`). Everything
        else it reads is fixed for the simulation's life; the results are the same bit for bit.
        """
        if self.device == "cpu" and pcg._CPU_CAPTURE:
            key = (x.ptr, mode, terms, self._h_step)
            graph = self._eval_graphs.get(key)
            if graph is None:
                with wp.ScopedCapture(device=self.device, force_module_load=False) as capture:  # recording launches nothing
                    self._launch_evaluate(x, mode, terms)
                graph = self._eval_graphs[key] = capture.graph
            wp.capture_launch(graph)
            return
        self._launch_evaluate(x, mode, terms)

    def _launch_evaluate(self, x: Any, mode: int, terms: int) -> None:
        wp = warp_ready()
        dev = self.device
        self._energy.zero_()
        if mode >= MODE_GRADIENT:
            self._grad.zero_()
        if mode >= MODE_HESSIAN:
            self._hess.values.zero_()
        if terms & 1:
            wp.launch(
                inertia.inertia_kernel, dim=self._n, device=dev,
                inputs=[x, self._x_tilde, self._mass, wp.float64(1.0 / self._h_step**2), mode, self._out],
            )
        if terms & 2:
            wp.launch(
                elastic.tet_kernel, dim=self.mesh.n_tets, device=dev,
                inputs=[x, self._tets, wp.float64(self._mu), wp.float64(self._lam), wp.float64(self._alpha), mode, self._out],
            )
        if terms & 32 and self.scene.material.viscosity > 0.0:
            wp.launch(
                damping.damping_kernel, dim=self.mesh.n_tets, device=dev,
                inputs=[x, self._strain_anchor, self._tets, wp.float64(self.scene.material.viscosity / self._h_step), mode, self._out],
            )
        contact_terms = (terms >> 2) & 0b111
        if contact_terms and len(self._contact_idx) and self._n_planes:
            self._launch_contact(x, mode, contact_terms)

    def _launch_contact(self, x: Any, mode: int, contact_terms: int = 0b111) -> None:
        wp = warp_ready()
        wp.launch(
            contact.contact_kernel, dim=len(self._contact_idx), device=self.device,
            inputs=[x, self._x_start, self._contacts, wp.float64(self._h_step), contact_terms, mode, self._out, self._forces],
        )

    def _energy_value(self) -> float:
        return float(self._energy.numpy().sum())

    # --- stepping ----------------------------------------------------------------------
    @exclusive
    def step(self) -> tuple[int, float]:
        """Advance one time step by minimising the incremental potential.

        Returns:
            ``(iterations, residual)``: Newton directions computed and the final convergence
            measure in m/s. :attr:`last_stats` holds more (linear iterations, timing).

        Raises:
            SolverError: no convergence within ``scene.solver.max_iterations`` with
                ``scene.solver.on_failure == "raise"``, or a NaN/inf either way; the state is
                then left unchanged. Without convergence and with ``"record"`` the last
                iterate is kept and ``last_stats.converged`` is False.
        """
        dev = self.device
        n = self._n
        start = time.perf_counter()
        solver = self.scene.solver
        self._begin_step()
        h = self._h_step
        iterations = 0
        linear_iterations = 0
        evaluations = 0
        residual = math.inf
        converged = False
        failure = nonfinite = ""
        gnorm0 = None
        energy = None
        maxiter_cg = max(3 * n, 50)
        while iterations < solver.max_iterations:
            self._evaluate(self._x, MODE_HESSIAN)
            self._gnorm.zero_()
            wp.launch(pcg.diag_kernel, dim=n, device=dev, inputs=[self._out, self._hess.inv_diag, self._gnorm])
            e0 = self._energy_value() if energy is None else energy
            gnorm = math.sqrt(float(self._gnorm.numpy().sum()))
            if not (math.isfinite(e0) and math.isfinite(gnorm)):
                failure = nonfinite = "the energy or its gradient is NaN or inf"
                break
            if gnorm0 is None:
                gnorm0 = gnorm
            forcing = _MAX_FORCING if gnorm0 == 0.0 else min(_MAX_FORCING, max(_MIN_FORCING, math.sqrt(gnorm / gnorm0)))
            linear_iterations += self._hess.solve(self._grad, self._y, forcing, maxiter_cg)
            iterations += 1
            self._stats.zero_()
            wp.launch(pcg.stats_kernel, dim=n, device=dev, inputs=[self._grad, self._y, self._mass, self._stats])
            st = self._stats.numpy().sum(axis=1)
            slope, ymy = float(st[0]), float(st[1])  # the direction is -y: slope of E along it is -g.y
            if not (math.isfinite(slope) and math.isfinite(ymy)):
                failure = nonfinite = "the Newton direction is NaN or inf"
                break
            residual = math.sqrt(max(ymy, 0.0) / self._total_mass) / h
            if residual < solver.tolerance:
                wp.launch(inertia.axpy_kernel, dim=n, device=dev, inputs=[self._x, self._y, wp.float64(-1.0), self._x])
                converged = True
                break
            accepted, evals = None, 0
            if self._stick_correction and len(self._contact_idx) and self._n_planes:
                its, stick_slope = self._stick_direction(forcing, maxiter_cg)
                linear_iterations += its
                if stick_slope is not None:
                    # Take the stick-corrected step only if it decreases E in full.
                    self._y, self._y_alt = self._y_alt, self._y
                    e1, _ = self._trial(1.0, False)
                    evals += 1
                    if _sufficient_decrease(e0, -stick_slope, e1):
                        accepted = e1
                    else:
                        self._y, self._y_alt = self._y_alt, self._y
            if accepted is None:
                accepted, ls_evals = self._line_search(e0, slope)
                evals += ls_evals
            evaluations += evals
            if accepted is None:
                failure = "the line search found no decrease of the incremental potential"
                break
            self._x, self._x_trial = self._x_trial, self._x
            energy = accepted
        seconds = time.perf_counter() - start
        if not converged and not failure:
            failure = f"no convergence in {iterations} Newton iterations"
        # NaN or inf leaves no finite iterate to record, so it raises either way.
        if not converged and (solver.on_failure == "raise" or nonfinite):
            wp.copy(self._x, self._x_now)
            self._has_forces = False
            self.last_stats = StepStats(iterations, residual, False, linear_iterations, evaluations, seconds)
            raise SolverError(
                f"full-space step {self._step_index} (t = {self.time:.6g} s) failed: {failure}; "
                f"residual {residual:.3e} m/s, tolerance {solver.tolerance:.3e} m/s, "
                f"{iterations} iterations (max_iterations {solver.max_iterations})",
                iterations=iterations,
                residual=residual,
                step_index=self._step_index,
            )
        wp.launch(inertia.velocity_kernel, dim=n, device=dev, inputs=[self._x, self._x_start, wp.float64(1.0 / h), self._v, self._v_prev])
        self._x_prev, self._x_now = self._x_now, self._x_prev
        self._have_prev = True
        if len(self._contact_idx) and self._n_planes:
            self._launch_contact(self._x, MODE_FORCES)
        self._has_forces = True
        self.time += self._h
        self._step_index += 1
        self.last_stats = StepStats(iterations, residual, converged, linear_iterations, evaluations, time.perf_counter() - start)
        return iterations, residual

    def _stick_direction(self, tol: float, maxiter: int) -> tuple[int, float | None]:
        """Newton direction with the contact points that the current step would carry through stick modelled as sticking.

        Slipping points whose slip the step ``-y`` would reverse or bring into the stick
        region get the stick Hessian and the stick gradient (pulling their slip to zero),
        and the system is solved again into ``_y_alt``. Friction makes the energy nearly
        non-smooth where stiff sticking meets slip; this anticipates the switch that the
        plain Newton step would overshoot.

        Returns (CG iterations, slope ``g . y_alt``), the slope None when no point switches
        or the new direction is not a descent direction of the true energy.
        """
        dev = self.device
        n = self._n
        wp.copy(self._rhs, self._grad)
        self._count.zero_()
        wp.launch(
            contact.stick_kernel, dim=len(self._contact_idx), device=dev,
            inputs=[self._x, self._x_start, self._y, self._contacts, wp.float64(self._h_step), self._out, self._rhs, self._count],
        )
        switched = int(self._count.numpy()[0])
        if switched == 0:
            return 0, None
        self._gnorm.zero_()
        wp.launch(pcg.diag_kernel, dim=n, device=dev, inputs=[self._out, self._hess.inv_diag, self._gnorm])
        its = self._hess.solve(self._rhs, self._y_alt, tol, maxiter)
        self._stats.zero_()
        wp.launch(pcg.stats_kernel, dim=n, device=dev, inputs=[self._grad, self._y_alt, self._mass, self._stats])
        slope = float(self._stats.numpy()[0].sum())
        return its, (slope if math.isfinite(slope) and slope > 0.0 else None)

    def _trial(self, alpha: float, with_slope: bool) -> tuple[float, float]:
        """E and dE/dalpha at x - alpha y (the point is left in ``_x_trial``)."""
        dev = self.device
        n = self._n
        wp.launch(inertia.axpy_kernel, dim=n, device=dev, inputs=[self._x, self._y, wp.float64(-alpha), self._x_trial])
        self._evaluate(self._x_trial, MODE_GRADIENT if with_slope else MODE_ENERGY)
        e = self._energy_value()
        if not with_slope:
            return e, math.nan
        self._stats.zero_()
        wp.launch(pcg.stats_kernel, dim=n, device=dev, inputs=[self._grad, self._y, self._mass, self._stats])
        return e, -float(self._stats.numpy()[0].sum())

    def _line_search(self, e0: float, slope: float) -> tuple[float | None, int]:
        """The reduced solvers' line search (``licrom._core.line_search``) along ``-y`` from ``x``:
        the energy of the step taken (None when no step decreases it) and the evaluations made.

        The accepted point is left in ``_x_trial``.
        """
        evaluations = 0

        def phi(alpha: float) -> tuple[float, float]:
            nonlocal evaluations
            evaluations += 1
            return self._trial(alpha, True)

        if not (math.isfinite(e0) and math.isfinite(slope) and slope > 0.0):  # not a descent direction
            return None, evaluations
        step = _core.line_search(e0, -slope, phi)
        return (None if step is None else step[1]), evaluations

    @exclusive
    def contact_forces(self) -> np.ndarray:
        """(C, 3) contact + damping + friction force on each contact point at the end of the last step, N.

        Zero before the first step (and after :meth:`set_state`).
        """
        c = len(self._contact_idx)
        if not self._has_forces or not c or not self._n_planes:
            return np.zeros((c, 3))
        return self._forces.numpy()[:c].astype(np.float64, copy=True)

    @exclusive
    def run(self, steps: int, record_every: int = 1, progress: bool = False, impact_window: float = 0.0) -> Trajectory:
        """Step ``steps`` times; record frame 0 (the current state) and every ``record_every``-th step.

        With ``impact_window`` (s), the displacement after every step between frames is kept too for that long from
        each impact (a step that ends with a vertex inside a plane after one that ended with none), as
        ``Trajectory.impact_displacements``: training data for the subspace, which must hold an impact's fast
        transient (:data:`licrom.data.dataset.IMPACT_WINDOW`).

        With ``scene.solver.on_failure == "record"``, unconverged steps are flagged in
        ``Trajectory.converged`` and the run goes on from the last iterate. Each frame's
        smallest tet ``det F`` and deepest penetration of a vertex into a plane are recorded
        (``Trajectory.min_det_f``, ``Trajectory.penetration``), with a
        :class:`~licrom.errors.PhysicsWarning` where they leave the valid range
        (:mod:`licrom.validity`).

        Raises:
            ConfigError: bad ``steps``, ``record_every`` or ``impact_window``.
            SolverError: a step failed and ``on_failure == "raise"``, or met NaN/inf.
        """
        impact_window = check_impact_window(impact_window)
        rest = self.mesh.vertices
        linear = 0
        if progress:
            load_kernels(self.device, lambda line: print(line, file=sys.stderr, flush=True))

        def step() -> tuple[int, float, bool]:
            nonlocal linear
            its, res = self.step()
            linear += self.last_stats.linear_iterations
            return its, res, self.last_stats.converged

        rec = record_run(step, lambda: (self.positions - rest, self.velocities), lambda: self.time, steps, record_every, progress,
                         f"full ({self.device})", self.validity, math.ceil(impact_window / self.scene.dt - 1e-9))
        converged = rec.converged
        displacements = np.array([d for d, _ in rec.frames])
        dm_inv, tets = self.mesh.shape_matrix_inverses, self.mesh.tets
        planes = self.scene.plane_array()
        min_det_f = np.array([tet_determinants(dm_inv, tets, rest + d).min() for d in displacements])
        depth = np.array([penetration(rest + d, planes) for d in displacements])
        min_det_f, depth = with_steps(min_det_f, depth, rec.between)
        arrays = rec.arrays()
        warn_frames(arrays["times"], min_det_f, depth, self.mesh.size, "the full simulation", rec.trailing)
        return Trajectory(
            rest_positions=rest,
            tets=tets,
            displacements=displacements,
            velocities=np.array([v for _, v in rec.frames]),
            scene=self.scene,
            min_det_f=min_det_f,
            penetration=depth,
            impact_displacements=np.array([d for d, _ in rec.impact_frames]).reshape(-1, len(rest), 3),
            impact_times=np.array(rec.impact_times),
            **arrays,
            info={
                "source": "full",
                "device": self.device,
                "n_vertices": int(self._n),
                "n_tets": int(self.mesh.n_tets),
                "contact_points": len(self._contact_idx),
                "record_every": int(record_every),
                "impact_window": float(impact_window),
                "linear_iterations": int(linear),
                "unconverged_steps": int(len(converged) - int(np.sum(converged))),
            },
        )

    # --- inspection (tests, debugging) -------------------------------------------------
    def _terms_mask(self, terms: str | Iterable[str]) -> int:
        names = ENERGY_TERMS if terms == "all" else ((terms,) if isinstance(terms, str) else tuple(terms))
        mask = 0
        for t in names:
            if t not in ENERGY_TERMS:
                raise ConfigError(f"unknown energy term {t!r}; accepted: 'all' or any of {', '.join(ENERGY_TERMS)}")
            mask |= 1 << ENERGY_TERMS.index(t)
        return mask

    def _at(self, positions: np.ndarray | None) -> Any:
        """Prepare the step from the current state and return the warp array to evaluate at."""
        wp = warp_ready()
        x_now = self._x.numpy().copy()
        self._begin_step()  # overwrites self._x with x~; restore it
        self._x.assign(wp.array(x_now, dtype=wp.vec3d, device=self.device))
        pos = x_now if positions is None else self._check_field("positions", positions)
        self._x_trial.assign(wp.array(pos, dtype=wp.vec3d, device=self.device))
        return self._x_trial

    @exclusive
    def energy(self, positions: np.ndarray | None = None, terms: str | Iterable[str] = "all") -> float:
        """Incremental potential of a step from the current state, at ``positions`` (default: now), J.

        Elastic energy is measured from the rest state (``Psi(F) - Psi(I)``), which changes
        nothing but the constant.
        """
        x = self._at(positions)
        self._evaluate(x, MODE_ENERGY, self._terms_mask(terms))
        return self._energy_value()

    @exclusive
    def gradient(self, positions: np.ndarray | None = None, terms: str | Iterable[str] = "all") -> np.ndarray:
        """(n, 3) gradient of :meth:`energy`, N."""
        x = self._at(positions)
        self._evaluate(x, MODE_GRADIENT, self._terms_mask(terms))
        return self._grad.numpy().astype(np.float64, copy=True)

    @exclusive
    def hessian(self, positions: np.ndarray | None = None, terms: str | Iterable[str] = "all", project: bool = True) -> Any:
        """(3n, 3n) ``scipy.sparse.csr_matrix`` Hessian of :meth:`energy` as assembled by Newton.

        With ``project=False`` the elastic part is the exact (unprojected) Hessian.
        """
        import scipy.sparse as sp

        x = self._at(positions)
        self._evaluate(x, MODE_HESSIAN if project else MODE_RAW_HESSIAN, self._terms_mask(terms))
        offsets, cols = self._hess.pattern
        vals = self._hess.values.numpy()
        return sp.bsr_matrix((vals, cols, offsets), shape=(3 * self._n, 3 * self._n)).tocsr()
