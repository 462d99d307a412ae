//! The reduced simulation state and its solvers.

use std::collections::HashMap;

use licrom_core::integrator::Integrator;
use licrom_core::reduced::{ReducedInputs, ReducedSystem};
use licrom_core::solver::{ElasticHessian, ReducedSolver, SolverKind, SolverSettings, SolverStats};
use numpy::PyArrayDyn;
use pyo3::prelude::*;
use std::sync::Mutex;

use crate::arrays::{count, read, write, Dim};
use crate::errors::{call_core, detached, error, exclusive, CoreResultExt, Kind};
use crate::inputs::{ContactArrays, ElasticArrays, VertexArgs};

/// Reduced model, state ``(q, qdot)`` and time stepper of one simulation.
///
/// Each step minimises the incremental potential (backward Euler)
/// ``E(q) = 1/(2h^2) (q - qt)^T M (q - qt) - f.q + sum_k w_k Psi(I + G_k q) +
/// sum_j,p [penalty + damping + friction](X_j + W_j q)``, ``qt = q + h qdot``,
/// with penalty contact against each plane, normal damping while approaching
/// and implicit Coulomb friction with the normal force lagged from the start
/// of the step. The first iterate extrapolates the previous step's acceleration
/// (free fall after construction or ``set_state``). Convergence measure:
/// ``r = sqrt(D^T M D / total_mass) / h`` in m/s for the Newton direction D; a
/// step converges when r < tolerance.
///
/// Args:
///     mass: (n, n) reduced mass matrix ``W^T M W`` in kg, symmetric positive definite.
///     gravity_force: (n,) reduced gravity force ``W^T M g`` in N.
///     cubature_jacobians: (K, 9, n) ``G_k = d vec(F) / dq`` at the cubature points.
///     cubature_weights: (K,) weights w_k >= 0 in m^3.
///     mu: SNH shear parameter in Pa, > 0.
///     lam: SNH volume parameter in Pa, > 0.
///     contact_basis: (C, 3, n) basis rows W_j at the contact points.
///     contact_rest: (C, 3) rest positions X_j of the contact points in m.
///     contact_areas: (C,) boundary area a_j >= 0 carried by each contact point in m^2.
///     planes: (P, 5) rows ``[nx, ny, nz, d, friction]`` of half-spaces
///         ``n.x + d >= 0`` (the normal is normalised and d scaled with it).
///     normal_stiffness: k_n in N/m^3, >= 0.
///     normal_damping: k_d in N s/m^3, >= 0.
///     friction_stiffness: k_f in N s/m^3, >= 0.
///     dt: time step h in s, > 0.
///     total_mass: mass of the solid in kg, > 0 (normalises the convergence measure).
///     tolerance: convergence threshold on r in m/s, > 0.
///     max_iterations: search directions allowed per step, >= 1.
///     solver: ``"newton"`` (Newton-type iteration on ``M/h^2 + K_elastic + K_contact``,
///         faer Cholesky, the contact model solved inside each iteration, stick
///         correction, Armijo + secant line search) or ``"prefactored"``
///         (the elastic stiffness kept at rest: ``M/h^2 + K(rest) + K_contact``, factored
///         once and again only when the contact terms change; same contact model, line
///         search and stopping rule; a step that needs more than 25 directions, or
///         whose line search stalls, finishes with Newton directions).
///     elastic_hessian: ``"lagged"`` (default: the elastic Hessian is kept across
///         iterations and steps, corrected by BFGS along each step, and assembled
///         again when it drifts or after ``set_state``; a quasi-Newton method with
///         the same minimiser) or ``"every_iteration"`` (plain Newton). Newton only.
///     integrator: ``"backward_euler"`` (default) or ``"bdf2"`` (second order: the same
///         minimisation with the anchor ``(4 q_n - q_{n-1})/3``, anchor velocity
///         ``(4 qdot_n - qdot_{n-1})/3`` and effective step ``2h/3``; a new state gets the
///         history of a free fall). See ``rust/core/src/integrator.rs``.
///     cubature_vertex_basis: (V, 3, n) basis rows ``W_v`` at the mesh vertices, with
///         ``cubature_tet_vertices`` (K, 4) int64, the vertices of each cubature point's
///         tet, and ``cubature_shape_gradients`` (K, 4, 3), its shape functions' gradients
///         in 1/m: the Jacobians in vertex form, ``G_k = sum_a W_{v_a} (x) grad N_a``
///         (the ``"mesh"`` strain). All three or none; they must reproduce
///         ``cubature_jacobians``. The energy and gradient then go through the vertices
///         where that is cheaper (``3 V_used < 9 K``), the Hessian through ``G_k``.
///     viscosity: Kelvin-Voigt viscosity eta in Pa s, >= 0 (default 0: no material damping):
///         ``w_k eta/(2h') |E(F_k) - E(F_k at the step's anchor)|^2`` added at each cubature
///         point, E the Green strain (``rust/core/src/reduced/elastic.rs``).
///
/// K, C and P may be zero.
///
/// One thread at a time: a call while another thread's call runs (a step releases the
/// GIL) raises :class:`ConcurrencyError` instead of waiting.
#[pyclass(module = "licrom._core", frozen)]
pub struct ReducedCore {
    pub(crate) inner: Mutex<ReducedSolver>,
    n: usize,
}

#[pymethods]
impl ReducedCore {
    #[new]
    #[pyo3(signature = (
        mass, gravity_force, cubature_jacobians, cubature_weights, mu, lam, contact_basis, contact_rest,
        contact_areas, planes, normal_stiffness, normal_damping, friction_stiffness, dt, total_mass,
        tolerance, max_iterations, solver = "newton", elastic_hessian = "lagged", cubature_vertex_basis = None,
        cubature_tet_vertices = None, cubature_shape_gradients = None, integrator = "backward_euler", viscosity = 0.0
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        mass: &Bound<'_, PyAny>,
        gravity_force: &Bound<'_, PyAny>,
        cubature_jacobians: &Bound<'_, PyAny>,
        cubature_weights: &Bound<'_, PyAny>,
        mu: f64,
        lam: f64,
        contact_basis: &Bound<'_, PyAny>,
        contact_rest: &Bound<'_, PyAny>,
        contact_areas: &Bound<'_, PyAny>,
        planes: &Bound<'_, PyAny>,
        normal_stiffness: f64,
        normal_damping: f64,
        friction_stiffness: f64,
        dt: f64,
        total_mass: f64,
        tolerance: f64,
        max_iterations: &Bound<'_, PyAny>,
        solver: &str,
        elastic_hessian: &str,
        cubature_vertex_basis: Option<&Bound<'_, PyAny>>,
        cubature_tet_vertices: Option<&Bound<'_, PyAny>>,
        cubature_shape_gradients: Option<&Bound<'_, PyAny>>,
        integrator: &str,
        viscosity: f64,
    ) -> PyResult<Self> {
        let integrator: Integrator = integrator.parse().py_err(py)?;
        let kind: SolverKind = solver.parse().py_err(py)?;
        let elastic_hessian: ElasticHessian = elastic_hessian.parse().py_err(py)?;
        let max_iterations = count(max_iterations, "max_iterations")?;
        let mass = read(mass, "mass", &[Dim::Any("n"), Dim::Any("n")])?;
        let n = mass.shape[0];
        if mass.shape[1] != n || n == 0 {
            return Err(error(py, Kind::Shape, format!("mass must have shape (n, n) with n >= 1, got {}", crate::arrays::shape_text(&mass.shape))));
        }
        let gravity = read(gravity_force, "gravity_force", &[Dim::Is(n)])?;
        let vertex = VertexArgs { basis: cubature_vertex_basis, tets: cubature_tet_vertices, grads: cubature_shape_gradients };
        let elastic = ElasticArrays::read(py, cubature_jacobians, cubature_weights, vertex, (mu, lam, viscosity), n)?;
        let stiffness = (normal_stiffness, normal_damping, friction_stiffness);
        let contact = ContactArrays::read(py, [contact_basis, contact_rest, contact_areas, planes], stiffness, n)?;
        let inputs =
            ReducedInputs { mass: &mass.data, gravity_force: &gravity.data, elastic: elastic.inputs(), contact: contact.inputs(), dt, integrator };
        let settings = SolverSettings { elastic_hessian, ..SolverSettings::new(total_mass, tolerance, max_iterations, kind) };
        let inner = detached(py, || ReducedSystem::new(&inputs).and_then(|system| ReducedSolver::new(system, settings)))?;
        Ok(Self { n: inner.system().n_dofs(), inner: Mutex::new(inner) })
    }

    /// Number of reduced coordinates n.
    #[getter]
    fn n_dofs(&self) -> usize {
        self.n
    }

    /// (n,) reduced coordinates (a copy).
    #[getter]
    fn q<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let q = exclusive(py, &self.inner)?.q().to_vec();
        write(py, q, &[self.n])
    }

    /// (n,) reduced velocities per second (a copy).
    #[getter]
    fn qdot<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let qdot = exclusive(py, &self.inner)?.qdot().to_vec();
        write(py, qdot, &[self.n])
    }

    /// Replace the state with ``q`` (n,) and ``qdot`` (n,); contact forces read zero until the next step.
    fn set_state(&self, py: Python<'_>, q: &Bound<'_, PyAny>, qdot: &Bound<'_, PyAny>) -> PyResult<()> {
        let q = read(q, "q", &[Dim::Is(self.n)])?;
        let qdot = read(qdot, "qdot", &[Dim::Is(self.n)])?;
        let mut solver = exclusive(py, &self.inner)?;
        call_core(py, || solver.set_state(&q.data, &qdot.data))
    }

    /// Work counters since construction or :meth:`reset_stats`: ``steps``,
    /// ``iterations`` (Newton directions, as ``step`` reports them),
    /// ``evaluations`` (energy and gradient over all cubature points),
    /// ``model_iterations`` and ``model_evaluations`` (on the contact model, no
    /// pass over the cubature points), ``elastic_hessians`` (assemblies of the
    /// elastic Hessian), ``factorizations`` (of the direction's matrix),
    /// ``fallbacks`` (prefactored steps finished with Newton directions),
    /// ``stick_solves`` and ``stick_steps`` (stick-corrected directions solved
    /// and taken).
    fn stats(&self, py: Python<'_>) -> PyResult<HashMap<&'static str, usize>> {
        Ok(stats_dict(exclusive(py, &self.inner)?.stats()))
    }

    /// After a step that did not converge, take its last iterate as the new
    /// state (``qdot`` from the difference) as if it had converged.
    ///
    /// Raises:
    ///     ConfigError: the previous call was not a step that failed to converge.
    fn accept_last_iterate(&self, py: Python<'_>) -> PyResult<()> {
        let mut solver = exclusive(py, &self.inner)?;
        call_core(py, || solver.accept_last_iterate())
    }

    /// Incremental potential E(q) in J of a step starting from the current state.
    fn energy(&self, py: Python<'_>, q: &Bound<'_, PyAny>) -> PyResult<f64> {
        let q = read(q, "q", &[Dim::Is(self.n)])?;
        let mut guard = exclusive(py, &self.inner)?;
        let solver = &mut *guard;
        detached(py, || solver.energy(&q.data))
    }

    /// (n,) gradient of E at ``q`` for a step starting from the current state.
    fn gradient<'py>(&self, py: Python<'py>, q: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let n = self.n;
        let q = read(q, "q", &[Dim::Is(n)])?;
        let mut guard = exclusive(py, &self.inner)?;
        let solver = &mut *guard;
        let grad = detached(py, || solver.gradient(&q.data).map(<[f64]>::to_vec))?;
        write(py, grad, &[n])
    }

    /// (n, n) Hessian of E at ``q`` for a step starting from the current state.
    ///
    /// With ``project`` the elastic Hessians are PSD-projected (the matrix Newton
    /// uses); otherwise it is the exact Hessian. Contact terms are always exact
    /// (they are PSD).
    #[pyo3(signature = (q, project = true))]
    fn hessian<'py>(&self, py: Python<'py>, q: &Bound<'py, PyAny>, project: bool) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let n = self.n;
        let q = read(q, "q", &[Dim::Is(n)])?;
        let mut guard = exclusive(py, &self.inner)?;
        let solver = &mut *guard;
        let hess = detached(py, || solver.hessian(&q.data, project).map(<[f64]>::to_vec))?;
        write(py, hess, &[n, n])
    }

    /// (C, 3) contact + friction force on each contact point in N (world frame),
    /// minus the gradient of the contact potentials at the current state relative
    /// to the start of the last step; zeros before any step.
    fn contact_forces<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let guard = exclusive(py, &self.inner)?;
        let solver = &*guard;
        let c = solver.system().n_contacts();
        let mut out = vec![0.0; 3 * c];
        detached(py, || solver.contact_forces(&mut out))?;
        write(py, out, &[c, 3])
    }
}

solver_methods!(ReducedCore);

/// The solvers' work counters by name (as `stats()` returns them).
pub(crate) fn stats_dict(s: SolverStats) -> HashMap<&'static str, usize> {
    [
        ("steps", s.steps),
        ("iterations", s.iterations),
        ("evaluations", s.evaluations),
        ("model_iterations", s.model_iterations),
        ("model_evaluations", s.model_evaluations),
        ("elastic_hessians", s.elastic_hessians),
        ("factorizations", s.factorizations),
        ("fallbacks", s.fallbacks),
        ("stick_solves", s.stick_solves),
        ("stick_steps", s.stick_steps),
    ]
    .into_iter()
    .collect()
}
