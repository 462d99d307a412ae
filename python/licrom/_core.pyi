"""Rust core of licrom (compiled extension ``licrom._core``).

Conventions: SI units; arrays are float64 (C-contiguous inputs are used as
they are, other layouts are copied); ``vec(F)`` is row-major, index ``3*i + j``
holds ``F[i, j]``. Bad inputs raise :class:`licrom.errors.ShapeError` (shape,
dtype, NaN/inf, or finite values so large that a result would overflow to
inf/NaN), :class:`licrom.errors.ConfigError` (parameters out of range,
mass matrix not symmetric positive definite); solver failures raise
:class:`licrom.errors.SolverError`. No function returns NaN or inf. Heavy calls
release the GIL.

Material: stable Neo-Hookean (Smith et al. 2018) with the SNH parameters
``mu, lam`` (Pa, both > 0):
``Psi(F) = mu/2 (I_C - 3) + lam/2 (J - alpha)^2 - mu/2 log(I_C + 1) - Psi_0``,
``alpha = 1 + 3 mu / (4 lam)``, where the constant ``Psi_0`` makes the rest
state (and every rotation) have zero energy. Valid for inverted F (J <= 0).
``mu / lam`` so large that ``alpha`` or ``Psi_0`` overflow is a ConfigError.
"""

from collections.abc import Callable, Sequence
from typing import TypeAlias, final

import numpy as np
import numpy.typing as npt
from typing_extensions import Self

__all__ = [
    "LINE_SEARCH",
    "AccuracyWarning",
    "BodyFrameCore",
    "ConcurrencyError",
    "ConfigError",
    "FileFormatError",
    "InternalError",
    "LicromError",
    "LicromWarning",
    "MeshError",
    "MissingDependencyError",
    "OutputError",
    "PhysicsWarning",
    "Reconstruction",
    "ReducedCore",
    "ResidualEstimate",
    "ShapeError",
    "SolverError",
    "VertexForces",
    "line_search",
    "set_second_thread",
    "snh_energy",
    "snh_hessian",
    "snh_pk1",
    "step_many",
]

_Float64Array: TypeAlias = npt.NDArray[np.float64]
_Int64Array: TypeAlias = npt.NDArray[np.int64]

def snh_energy(F: _Float64Array, mu: float, lam: float) -> _Float64Array:
    """Energy densities Psi(F), shape (p,), in J/m^3, of deformation gradients ``F`` (p, 3, 3); zero at rest and for every rotation."""

def snh_pk1(F: _Float64Array, mu: float, lam: float) -> _Float64Array:
    """First Piola-Kirchhoff stresses dPsi/dF, shape (p, 3, 3), in Pa."""

def snh_hessian(F: _Float64Array, mu: float, lam: float, project: bool = True) -> _Float64Array:
    """Hessians d^2 Psi / d vec(F)^2, shape (p, 9, 9), in Pa (row-major vec).

    With ``project`` the negative eigenvalues of the analytic eigensystem
    (Smith, de Goes, Kim 2019) are clamped to zero, so each Hessian is PSD;
    otherwise the exact, possibly indefinite, Hessian is returned.
    """

@final
class ReducedCore:
    """Reduced model, state ``(q, qdot)`` and time stepper of one simulation.

    Each step minimises the incremental potential (backward Euler)
    ``E(q) = 1/(2h^2) (q - qt)^T M (q - qt) - f.q + sum_k w_k Psi(I + G_k q) +
    sum_j,p [penalty + damping + friction](X_j + W_j q)``, ``qt = q + h qdot``,
    with penalty contact against each plane, normal damping while approaching
    and implicit Coulomb friction with the normal force lagged from the start
    of the step. The first iterate extrapolates the previous step's acceleration
    (free fall after construction or ``set_state``). Convergence measure:
    ``r = sqrt(D^T M D / total_mass) / h`` in m/s for the Newton direction D; a
    step converges when r < tolerance.

    Args:
        mass: (n, n) reduced mass matrix ``W^T M W`` in kg, symmetric positive definite.
        gravity_force: (n,) reduced gravity force ``W^T M g`` in N.
        cubature_jacobians: (K, 9, n) ``G_k = d vec(F) / dq`` at the cubature points.
        cubature_weights: (K,) weights w_k >= 0 in m^3.
        mu: SNH shear parameter in Pa, > 0.
        lam: SNH volume parameter in Pa, > 0.
        contact_basis: (C, 3, n) basis rows W_j at the contact points.
        contact_rest: (C, 3) rest positions X_j of the contact points in m.
        contact_areas: (C,) boundary area a_j >= 0 carried by each contact point in m^2.
        planes: (P, 5) rows ``[nx, ny, nz, d, friction]`` of half-spaces
            ``n.x + d >= 0`` (the normal is normalised and d scaled with it).
        normal_stiffness: k_n in N/m^3, >= 0.
        normal_damping: k_d in N s/m^3, >= 0.
        friction_stiffness: k_f in N s/m^3, >= 0.
        dt: time step h in s, > 0.
        total_mass: mass of the solid in kg, > 0 (normalises the convergence measure).
        tolerance: convergence threshold on r in m/s, > 0.
        max_iterations: search directions allowed per step, >= 1.
        solver: ``"newton"`` (Newton-type iteration on ``M/h^2 + K_elastic + K_contact``,
            faer Cholesky, the contact model solved inside each iteration, stick
            correction, Armijo + secant line search) or ``"prefactored"``
            (the elastic stiffness kept at rest: ``M/h^2 + K(rest) + K_contact``, factored
            once and again only when the contact terms change; same contact model, line
            search and stopping rule; a step that needs more than 25 directions, or
            whose line search stalls, finishes with Newton directions).
        elastic_hessian: ``"lagged"`` (default: the elastic Hessian is kept across
            iterations and steps, corrected by BFGS along each step, and assembled
            again when it drifts or after ``set_state``; a quasi-Newton method with
            the same minimiser) or ``"every_iteration"`` (plain Newton). Newton only.
        integrator: ``"backward_euler"`` (default) or ``"bdf2"`` (second order: the same
            minimisation with the anchor ``(4 q_n - q_{n-1})/3``, anchor velocity
            ``(4 qdot_n - qdot_{n-1})/3`` and effective step ``2h/3``; a new state gets the
            history of a free fall). See ``rust/core/src/integrator.rs``.
        cubature_vertex_basis: (V, 3, n) basis rows ``W_v`` at the mesh vertices, with
            ``cubature_tet_vertices`` (K, 4) int64, the vertices of each cubature point's
            tet, and ``cubature_shape_gradients`` (K, 4, 3), its shape functions' gradients
            in 1/m: the Jacobians in vertex form, ``G_k = sum_a W_{v_a} (x) grad N_a``
            (the ``"mesh"`` strain). All three or none; they must reproduce
            ``cubature_jacobians``. The energy and gradient then go through the vertices
            where that is cheaper (``3 V_used < 9 K``), the Hessian through ``G_k``.
        viscosity: Kelvin-Voigt viscosity eta in Pa s, >= 0 (default 0: no material damping):
            ``w_k eta/(2h') |E(F_k) - E(F_k at the step's anchor)|^2`` added at each cubature
            point, E the Green strain (``rust/core/src/reduced/elastic.rs``).

    K, C and P may be zero.

    One thread at a time: a call while another thread's call runs (a step releases the
    GIL) raises :class:`ConcurrencyError` instead of waiting.
    """

    def __new__(
        cls,
        mass: _Float64Array,
        gravity_force: _Float64Array,
        cubature_jacobians: _Float64Array,
        cubature_weights: _Float64Array,
        mu: float,
        lam: float,
        contact_basis: _Float64Array,
        contact_rest: _Float64Array,
        contact_areas: _Float64Array,
        planes: _Float64Array,
        normal_stiffness: float,
        normal_damping: float,
        friction_stiffness: float,
        dt: float,
        total_mass: float,
        tolerance: float,
        max_iterations: int,
        solver: str = "newton",
        elastic_hessian: str = "lagged",
        cubature_vertex_basis: _Float64Array | None = None,
        cubature_tet_vertices: _Int64Array | None = None,
        cubature_shape_gradients: _Float64Array | None = None,
        integrator: str = "backward_euler",
        viscosity: float = 0.0,
    ) -> Self: ...
    @property
    def n_dofs(self) -> int:
        """Number of reduced coordinates n."""
    @property
    def q(self) -> _Float64Array:
        """(n,) reduced coordinates (a copy)."""
    @property
    def qdot(self) -> _Float64Array:
        """(n,) reduced velocities per second (a copy)."""
    def set_state(self, q: _Float64Array, qdot: _Float64Array) -> None:
        """Replace the state with ``q`` (n,) and ``qdot`` (n,); contact forces read zero until the next step."""
    def step(self) -> tuple[int, float]:
        """Advance one time step; return (iterations, residual in m/s).

        Raises:
            SolverError: no convergence within ``max_iterations`` (attributes
                ``iterations`` and ``residual``) or non-finite values; the state is
                left unchanged.
        """
    def validity(self) -> tuple[float, float]:
        """``(min det F, depth)`` of the last step at its accepted iterate: the smallest
        ``det F`` at the cubature points (inf without any) and the deepest penetration of a
        contact point into a plane in m (>= 0); ``(inf, 0)`` before any step."""
    def stats(self) -> dict[str, int]:
        """Work counters since construction or :meth:`reset_stats`: ``steps``,
        ``iterations`` (Newton directions, as ``step`` reports them),
        ``evaluations`` (energy and gradient over all cubature points),
        ``model_iterations`` and ``model_evaluations`` (on the contact model, no
        pass over the cubature points), ``elastic_hessians`` (assemblies of the
        elastic Hessian), ``factorizations`` (of the direction's matrix),
        ``fallbacks`` (prefactored steps finished with Newton directions),
        ``stick_solves`` and ``stick_steps`` (stick-corrected directions solved
        and taken)."""
    def reset_stats(self) -> None:
        """Zero the work counters."""
    def accept_last_iterate(self) -> None:
        """After a step that did not converge, take its last iterate as the new
        state (``qdot`` from the difference) as if it had converged.

        Raises:
            ConfigError: the previous call was not a step that failed to converge.
        """
    def energy(self, q: _Float64Array) -> float:
        """Incremental potential E(q) in J of a step starting from the current state."""
    def gradient(self, q: _Float64Array) -> _Float64Array:
        """(n,) gradient of E at ``q`` for a step starting from the current state."""
    def hessian(self, q: _Float64Array, project: bool = True) -> _Float64Array:
        """(n, n) Hessian of E at ``q`` for a step starting from the current state.

        With ``project`` the elastic Hessians are PSD-projected (the matrix Newton
        uses); otherwise it is the exact Hessian. Contact terms are always exact
        (they are PSD).
        """
    def contact_forces(self) -> _Float64Array:
        """(C, 3) contact + friction force on each contact point in N (world frame),
        minus the gradient of the contact potentials at the current state relative
        to the start of the last step; zeros before any step."""

@final
class BodyFrameCore:
    """Body-frame reduced model, pose history and time stepper of one simulation.

    Positions ``x_v = c + R (Xbar_v + W_v q)``, every column of W mass-orthogonal to
    the rigid modes. Each step minimises the backward-Euler energy over
    ``(c, R, q)``: inertia exact from the mass moments, elastic energy
    ``sum_k w_k Psi(I + G_k q)``, contact and friction at the contact points as in
    :class:`ReducedCore`, with the lagged normal force and the slip measured from
    the positions at the start of the step. Newton on ``(dc, omega, dq)`` with
    ``R <- exp([omega]x) R``; convergence measure ``r`` (m/s) as in ReducedCore.

    Args:
        total_mass: M in kg, > 0.
        inertia_moments: (3, 3) ``J = sum m Xbar Xbar^T`` in kg m^2, symmetric positive definite.
        mode_moments: (n, 3, 3) ``P_k = sum m W^k Xbar^T``.
        mode_products: (n, n, 3, 3) ``Q_kl = sum m W^k W^l^T`` (``Q_kl = Q_lk^T``).
        gravity: (3,) gravity acceleration in m/s^2.
        cubature_jacobians: (K, 9, n) ``G_k = d vec(F) / dq`` at the cubature points.
        cubature_weights: (K,) weights w_k >= 0 in m^3.
        mu: SNH shear parameter in Pa, > 0.
        lam: SNH volume parameter in Pa, > 0.
        contact_basis: (C, 3, n) basis rows W_j at the contact points.
        contact_rest: (C, 3) ``Xbar_j`` of the contact points in m.
        contact_areas: (C,) boundary area a_j >= 0 carried by each contact point in m^2.
        planes: (P, 5) rows ``[nx, ny, nz, d, friction]``.
        normal_stiffness: k_n in N/m^3, >= 0.
        normal_damping: k_d in N s/m^3, >= 0.
        friction_stiffness: k_f in N s/m^3, >= 0.
        dt: time step h in s, > 0.
        tolerance: convergence threshold on r in m/s, > 0.
        max_iterations: Newton directions allowed per step, >= 1.
        integrator: ``"backward_euler"`` (default) or ``"bdf2"`` (second order: the same
            minimisation with the anchor ``(4 x_n - x_{n-1})/3``, anchor velocity
            ``(4 v_n - v_{n-1})/3`` and effective step ``2h/3``; a new state gets the
            history of a free fall). See ``rust/core/src/integrator.rs``.
        cubature_vertex_basis: (V, 3, n) basis rows ``W_v`` at the mesh vertices, with
            ``cubature_tet_vertices`` (K, 4) int64, the vertices of each cubature point's
            tet, and ``cubature_shape_gradients`` (K, 4, 3), its shape functions' gradients
            in 1/m: the Jacobians in vertex form, ``G_k = sum_a W_{v_a} (x) grad N_a``
            (the ``"mesh"`` strain). All three or none; they must reproduce
            ``cubature_jacobians``. The energy and gradient then go through the vertices
            where that is cheaper (``3 V_used < 9 K``), the Hessian through ``G_k``.
        viscosity: Kelvin-Voigt viscosity eta in Pa s, >= 0 (default 0: no material damping):
            ``w_k eta/(2h') |E(F_k) - E(F_k at the step's anchor)|^2`` added at each cubature
            point, E the Green strain (``rust/core/src/reduced/elastic.rs``).

    n, K, C and P may be zero (n = 0: a rigid body).

    One thread at a time: a call while another thread's call runs (a step releases the
    GIL) raises :class:`ConcurrencyError` instead of waiting.
    """

    def __new__(
        cls,
        total_mass: float,
        inertia_moments: _Float64Array,
        mode_moments: _Float64Array,
        mode_products: _Float64Array,
        gravity: _Float64Array,
        cubature_jacobians: _Float64Array,
        cubature_weights: _Float64Array,
        mu: float,
        lam: float,
        contact_basis: _Float64Array,
        contact_rest: _Float64Array,
        contact_areas: _Float64Array,
        planes: _Float64Array,
        normal_stiffness: float,
        normal_damping: float,
        friction_stiffness: float,
        dt: float,
        tolerance: float,
        max_iterations: int,
        cubature_vertex_basis: _Float64Array | None = None,
        cubature_tet_vertices: _Int64Array | None = None,
        cubature_shape_gradients: _Float64Array | None = None,
        integrator: str = "backward_euler",
        viscosity: float = 0.0,
    ) -> Self: ...
    @property
    def n_dofs(self) -> int:
        """Number of modes n."""
    def set_state(
        self,
        center: _Float64Array,
        rotation: _Float64Array,
        q: _Float64Array,
        velocity: _Float64Array,
        angular_velocity: _Float64Array,
        qdot: _Float64Array,
    ) -> None:
        """Replace the state: pose, velocity of the centre of mass (m/s), angular velocity in the world frame
        (rad/s) and modal velocities (per second). The pose k steps back becomes
        ``(c - k h v, exp(-k h [w]x) R, q - k h qdot)`` (k = 1, 2, 3; BDF2: ``c - k h v + (k h)^2 g / 2``,
        the history of a free fall, its start).

        Raises:
            ShapeError: wrong shapes, NaN/inf, or ``rotation`` not orthonormal with
                determinant +1 (to 1e-8).
        """
    def set_history(self, centers: _Float64Array, rotations: _Float64Array, q: _Float64Array) -> None:
        """Replace the poses one, two and three steps back (nearest first; centres (3, 3), rotations
        (3, 3, 3), q (3, n)) after :meth:`set_state`: the history BDF2 reads; velocities then read from it.

        Raises:
            ShapeError: wrong shapes, NaN/inf, or a rotation that is not orthonormal with
                determinant +1 (to 1e-8).
        """
    def step(self) -> tuple[int, float]:
        """Advance one time step; return (iterations, residual in m/s).

        Raises:
            SolverError: no convergence within ``max_iterations`` (attributes
                ``iterations`` and ``residual``) or non-finite values; the state is
                left unchanged.
        """
    def validity(self) -> tuple[float, float]:
        """``(min det F, depth)`` of the last step at its accepted iterate: the smallest
        ``det F`` at the cubature points (inf without any) and the deepest penetration of a
        contact point into a plane in m (>= 0); ``(inf, 0)`` before any step."""
    def stats(self) -> dict[str, int]:
        """Work counters since construction or :meth:`reset_stats`, as
        :meth:`ReducedCore.stats` (the same solver machinery: contact model, stick
        correction, lagged elastic Hessian)."""
    def reset_stats(self) -> None:
        """Zero the work counters."""
    def accept_last_iterate(self) -> None:
        """After a step that did not converge, take its last iterate as the new pose."""
    @property
    def center(self) -> _Float64Array:
        """(3,) centre of mass in m."""
    @property
    def rotation(self) -> _Float64Array:
        """(3, 3) rotation from the body frame to the world."""
    @property
    def q(self) -> _Float64Array:
        """(n,) modal coordinates."""
    def previous_pose(self, steps_back: int) -> tuple[_Float64Array, _Float64Array, _Float64Array]:
        """``(c, R, q)`` (shapes (3,), (3, 3), (n,)) of the pose ``steps_back`` (1, 2 or 3) steps before
        the current one: the history the integrator reads.

        Raises:
            ConfigError: ``steps_back`` is not 1, 2 or 3.
        """
    @property
    def velocity(self) -> _Float64Array:
        """(3,) ``(c - c_prev) / h`` in m/s (BDF2: ``(3 c - 4 c_prev + c_prev2) / (2h)``)."""
    @property
    def angular_velocity(self) -> _Float64Array:
        """(3,) ``log(R R_prev^T) / h`` in rad/s (world frame; BDF2: ``(3 w_1 - w_2) / (2h)``
        with ``w_k`` the turns ``log(R R_prev^T)`` of the last two steps)."""
    @property
    def qdot(self) -> _Float64Array:
        """(n,) ``(q - q_prev) / h`` per second (BDF2: ``(3 q - 4 q_prev + q_prev2) / (2h)``)."""
    def contact_forces(self) -> _Float64Array:
        """(C, 3) contact + friction force on each contact point over the last step in N; zeros before any step."""
    def energy(self, center: _Float64Array, rotation: _Float64Array, q: _Float64Array) -> float:
        """Energy in J at the pose of a step from the current state, up to a constant of the step."""
    def gradient(self, center: _Float64Array, rotation: _Float64Array, q: _Float64Array) -> _Float64Array:
        """(6 + n,) gradient in ``(c, omega, q)`` at the pose (omega: left rotation increment)."""
    def hessian(self, center: _Float64Array, rotation: _Float64Array, q: _Float64Array, exact: bool = True) -> _Float64Array:
        """(6 + n, 6 + n) Hessian at the pose: exact, or the solver's positive definite one."""

def set_second_thread(on: bool) -> None:
    """Whether one simulation's step may hand half of its large products (the basis
    rows times the coordinates, and back) to a second thread; on by default where
    the machine has two cores or more. Steps are the same, bit for bit, either way."""

def step_many(
    sims: Sequence[ReducedCore | BodyFrameCore], steps: int, threads: int | None, record_failures: Sequence[bool]
) -> list[tuple[list[int], list[float], list[bool], BaseException | None]]:
    """Step each simulation ``steps`` times, spread over ``threads`` threads (None: every core), the GIL released.

    The simulations are independent (each owns its model and buffers); each takes its
    steps exactly as a loop of ``step`` calls would, so the states do not depend on
    ``threads``. A simulation whose ``record_failures`` flag is set takes the last iterate
    of a step that fails (``accept_last_iterate``) and goes on; otherwise it stops at the
    start of that step. Returns, per simulation, ``(iterations, residuals, converged,
    error)``: one entry per step taken (a failed step: its iterations, its residual or NaN,
    False) and the licrom exception that stopped it, or None.

    Raises ConfigError for a simulation given twice, an object of another type,
    ``steps < 0`` or ``threads < 1``; ConcurrencyError for a simulation busy in another
    thread; ShapeError for ``record_failures`` of another length than ``sims``.
    """

@final
class Reconstruction:
    """Positions ``x = X + W q`` of N points.

    Args:
        basis: (N, 3, n) basis rows W at the points.
        rest: (N, 3) rest positions X in m.
    """

    def __new__(cls, basis: _Float64Array, rest: _Float64Array) -> Self: ...
    @property
    def n_dofs(self) -> int:
        """Number of reduced coordinates n."""
    @property
    def n_points(self) -> int:
        """Number of points N."""
    def positions(self, q: _Float64Array) -> _Float64Array:
        """(N, 3) positions in m for reduced coordinates ``q`` (n,)."""

@final
class ResidualEstimate:
    """The full model's residual at S sample vertices of a reduced state, with the sample
    positions of the steps the integrator reads kept from call to call
    (``rust/core/src/residual_estimate.rs`` has the formulas).

    Args:
        forces: the ring forces of the samples, over the U near vertices.
        near_basis: (U, 3, n) basis rows of the near vertices.
        near_rest: (U, 3) rest term of their positions in m.
        own: (S,) int64 each sample's index among the near vertices.
        masses: (S,) lumped masses in kg, > 0.
        normaliser: (S, 3, 3) inverse normalising blocks in m/N (residual force to displacement).
        gravity: (3,) gravity in m/s^2.
        planes: (P, 4) contact planes ``(n, d)``, outside where ``n . x + d >= 0``.
        target: (L,) the integrator's target weights, newest first (L = 2 or 4).
        step: the integrator's effective step in s, > 0.
        total_mass: the body's mass in kg, > 0.
        viscosity: the material's Kelvin-Voigt viscosity in Pa s, >= 0 (default 0): the force of its
            damping joins the elastic one, its anchor from the recorded states before the step.
    """

    def __new__(
        cls,
        forces: VertexForces,
        near_basis: _Float64Array,
        near_rest: _Float64Array,
        own: _Int64Array,
        masses: _Float64Array,
        normaliser: _Float64Array,
        gravity: _Float64Array,
        planes: _Float64Array,
        target: _Float64Array,
        step: float,
        total_mass: float,
        viscosity: float = 0.0,
    ) -> Self: ...
    @property
    def n_samples(self) -> int:
        """Number of sample vertices S."""
    @property
    def history_length(self) -> int:
        """States the residual reads before the step (2 or 4)."""
    def start(self, history: _Float64Array) -> None:
        """Begins a run from the (L, S, 3) sample positions (m) of the states before it, oldest first."""
    def record(
        self, q: _Float64Array, center: _Float64Array | None = None, rotation: _Float64Array | None = None, before: int | None = None
    ) -> None:
        """Keeps the sample positions at ``q`` (placed by ``center``, ``rotation`` for body-frame models) as the newest state.
        ``before``: steps from this one to the next evaluation, where known; the states the material damping will read
        (1 and, for BDF2, 2 steps before) then keep their near vertices' positions, formed here rather than there."""
    def prepare(self, q: _Float64Array, center: _Float64Array | None = None, rotation: _Float64Array | None = None) -> None:
        """Begins the evaluation of ``q`` (placed by ``center``, ``rotation`` for body-frame models): its near vertices'
        positions; :meth:`finish` ends it (a run does so on the next step, so that the halves' costs fall on two steps)."""
    def finish(self) -> float:
        """The residual value (see :meth:`evaluate`) of the state :meth:`prepare` began, which becomes the newest state."""
    def evaluate(self, q: _Float64Array, center: _Float64Array | None = None, rotation: _Float64Array | None = None) -> float:
        """The step's residual value ``M sum m |du|^2 / sum m`` (kg m^2) over the samples no plane touches, at
        ``q`` (placed by ``center``, ``rotation`` for body-frame models), which becomes the newest state."""

@final
class VertexForces:
    """Elastic force ``f_v = -sum_t V_t P(F_t) g_{t,v}`` (N) on each of S sample vertices
    from the positions of the corners of their T one-ring tets, with
    ``F_t = sum_a y_a g_{t,a}^T`` and the stable Neo-Hookean stress P (``snh_pk1``).

    Args:
        n_points: number of points whose positions ``forces`` takes.
        n_samples: number of sample vertices S.
        corners: (T, 4) int64 point indices of each ring tet's corners, below ``n_points``.
        gradients: (T, 4, 3) shape gradients of the corners in 1/m.
        volumes: (T,) rest volumes in m^3, > 0.
        owners: (T,) int64 the sample (below ``n_samples``) whose ring each tet is in.
        own_corners: (T,) int64 which corner (0-3) of its tet that sample is.
        mu: stable Neo-Hookean parameter mu in Pa.
        lam: stable Neo-Hookean parameter lambda in Pa.
    """

    def __new__(
        cls,
        n_points: int,
        n_samples: int,
        corners: _Int64Array,
        gradients: _Float64Array,
        volumes: _Float64Array,
        owners: _Int64Array,
        own_corners: _Int64Array,
        mu: float,
        lam: float,
    ) -> Self: ...
    def forces(self, positions: _Float64Array) -> _Float64Array:
        """(S, 3) forces in N from (n_points, 3) ``positions`` in m."""

LINE_SEARCH: dict[str, float]
"""The solvers' line-search constants by name: ``armijo``, ``curvature``, ``max_secant``,
``max_halvings``, ``roundoff_ulps``, ``noise`` (see ``rust/core/src/solver/line_search.rs``)."""

def line_search(e0: float, d0: float, phi: Callable[[float], tuple[float, float]]) -> tuple[float, float] | None:
    """The reduced solvers' line search from ``phi(0) = e0`` with slope ``d0 < 0``.

    ``phi(alpha)`` returns ``(energy, slope)``; the result is ``(alpha, energy)`` of the
    step taken (the last call of ``phi`` was there), or None when no step decreases the
    energy beyond round-off. An exception raised by ``phi`` propagates.

    Raises:
        ConfigError: ``e0`` not finite, or ``d0`` not a finite negative slope.
    """

# The exception and warning family, re-exported by licrom.errors (their public home, which
# their __module__ names).

class LicromError(Exception):
    """Base class of every error licrom raises."""

class MeshError(LicromError, ValueError):
    """A mesh is unusable: degenerate or inverted tets, bad indices, NaN coordinates."""

class ShapeError(LicromError, ValueError):
    """An array has the wrong shape, dtype or non-finite values."""

class ConfigError(LicromError, ValueError):
    """A parameter is outside its accepted range (material, plane, solver, scene)."""

class SolverError(LicromError, RuntimeError):
    """A solve did not converge or produced non-finite values.

    Attributes:
        iterations: iterations taken before giving up (None when not known).
        residual: the last convergence measure in m/s (None when not known).
        step_index: the time step that failed (None when not known).
    """

    iterations: int | None
    residual: float | None
    step_index: int | None
    def __init__(self, /, message: str, *, iterations: int | None = None, residual: float | None = None, step_index: int | None = None) -> None: ...

class FileFormatError(LicromError, OSError):
    """A file is missing, truncated, corrupt, foreign, or of an unknown format version."""

class OutputError(LicromError, OSError):
    """An output cannot be written: the disk is full, the folder is read-only, or the path is a directory.

    Nothing half-written is left behind: the destination keeps its previous contents (or stays absent).

    Attributes:
        errno: the operating system's error number (``errno.ENOSPC``, ``errno.EACCES``, ...; None when not known).
    """

    errno: int | None
    def __init__(self, /, message: str, *, errno: int | None = None) -> None: ...

class ConcurrencyError(LicromError, RuntimeError):
    """One simulation was used from two threads at once (a step or evaluation was running in another thread).

    A simulation serves one thread at a time; give each thread its own simulation (they run in
    parallel), or guard a shared one with a ``threading.Lock``.
    """

class InternalError(LicromError, RuntimeError):
    """A bug in licrom: an internal invariant of the Rust core failed (a panic, caught where the call entered the core).

    The message holds the panic's; please report it with the call that raised it. The object that raised it
    (a simulation, an estimate) may be left half updated: make a new one.
    """

class MissingDependencyError(LicromError, ImportError):
    """An optional package that the asked-for output needs is not installed (the message names the pip extra)."""

class LicromWarning(UserWarning):
    """Base class of every warning licrom issues."""

class PhysicsWarning(LicromWarning):
    """A simulation left the range where its physics holds: inverted elements, contact
    penetration deeper than ``licrom.validity.PENETRATION_LIMIT`` of the object's size,
    or a start inside a plane (see :mod:`licrom.validity`)."""

class AccuracyWarning(LicromWarning):
    """A reduced run's online error estimate (``Trajectory.error_estimate``) passed
    ``licrom.reduced.error_estimate.ERROR_THRESHOLD``: its subspace likely misses the motion
    (see :mod:`licrom.reduced.error_estimate`)."""
