//! The reduced simulation state and its solvers.

use std::collections::HashMap;

use licrom_core::integrator::Integrator;
use licrom_core::reduced::{ReducedInputs, ReducedSystem};
use licrom_core::solver::{ElasticHessian, ReducedSolver, SolverKind, SolverSettings, SolverStats};
use numpy::PyArrayDyn;
use pyo3::prelude::*;
use std::sync::Mutex;

use crate::arrays::{count, read, write, Dim};
use crate::errors::{error, exclusive, CoreResultExt, Kind};
use crate::inputs::{ContactArrays, ElasticArrays, VertexArgs};

/// Reduced model, state `(q, qdot)` and solver of one simulation.
///
/// One thread at a time: a call while another thread's call runs (a step releases the
/// GIL) raises `ConcurrencyError` instead of waiting.
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
        cubature_tet_vertices = None, cubature_shape_gradients = None, integrator = "backward_euler"
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
        let elastic = ElasticArrays::read(py, cubature_jacobians, cubature_weights, vertex, (mu, lam), n)?;
        let stiffness = (normal_stiffness, normal_damping, friction_stiffness);
        let contact = ContactArrays::read(py, [contact_basis, contact_rest, contact_areas, planes], stiffness, n)?;
        let inputs =
            ReducedInputs { mass: &mass.data, gravity_force: &gravity.data, elastic: elastic.inputs(), contact: contact.inputs(), dt, integrator };
        let settings = SolverSettings { elastic_hessian, ..SolverSettings::new(total_mass, tolerance, max_iterations, kind) };
        let inner = py.detach(|| ReducedSystem::new(&inputs).and_then(|system| ReducedSolver::new(system, settings))).py_err(py)?;
        Ok(Self { n: inner.system().n_dofs(), inner: Mutex::new(inner) })
    }

    /// Number of reduced coordinates n.
    #[getter]
    fn n_dofs(&self) -> usize {
        self.n
    }

    /// Reduced coordinates (n,), a copy.
    #[getter]
    fn q<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let q = exclusive(py, &self.inner)?.q().to_vec();
        write(py, q, &[self.n])
    }

    /// Reduced velocities (n,) per second, a copy.
    #[getter]
    fn qdot<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let qdot = exclusive(py, &self.inner)?.qdot().to_vec();
        write(py, qdot, &[self.n])
    }

    /// Replaces the state; contact forces read zero until the next step.
    fn set_state(&self, py: Python<'_>, q: &Bound<'_, PyAny>, qdot: &Bound<'_, PyAny>) -> PyResult<()> {
        let q = read(q, "q", &[Dim::Is(self.n)])?;
        let qdot = read(qdot, "qdot", &[Dim::Is(self.n)])?;
        exclusive(py, &self.inner)?.set_state(&q.data, &qdot.data).py_err(py)
    }

    /// Advances one step; returns (iterations, residual in m/s).
    fn step(&self, py: Python<'_>) -> PyResult<(usize, f64)> {
        let mut guard = exclusive(py, &self.inner)?;
        let solver = &mut *guard;
        let report = py.detach(|| solver.step()).py_err(py)?;
        Ok((report.iterations, report.residual))
    }

    /// Work counters since construction (or the last `reset_stats`): steps,
    /// iterations, evaluations, model_iterations, model_evaluations,
    /// elastic_hessians, factorizations, fallbacks, stick_solves, stick_steps.
    fn stats(&self, py: Python<'_>) -> PyResult<HashMap<&'static str, usize>> {
        Ok(stats_dict(exclusive(py, &self.inner)?.stats()))
    }

    /// `(min det F, depth)` of the last step: the smallest `det F` at the
    /// cubature points (inf without any) and the deepest penetration of a
    /// contact point into a plane (m, >= 0), at its accepted iterate.
    fn validity(&self, py: Python<'_>) -> PyResult<(f64, f64)> {
        let v = exclusive(py, &self.inner)?.validity();
        Ok((v.min_det, v.depth))
    }

    /// Zeroes the work counters.
    fn reset_stats(&self, py: Python<'_>) -> PyResult<()> {
        exclusive(py, &self.inner)?.reset_stats();
        Ok(())
    }

    /// Takes the last iterate of a step that just failed to converge as the state.
    fn accept_last_iterate(&self, py: Python<'_>) -> PyResult<()> {
        exclusive(py, &self.inner)?.accept_last_iterate().py_err(py)
    }

    /// Incremental potential E(q) in J of a step from the current state.
    fn energy(&self, py: Python<'_>, q: &Bound<'_, PyAny>) -> PyResult<f64> {
        let q = read(q, "q", &[Dim::Is(self.n)])?;
        let mut guard = exclusive(py, &self.inner)?;
        let solver = &mut *guard;
        py.detach(|| solver.energy(&q.data)).py_err(py)
    }

    /// Gradient (n,) of E at q for a step from the current state.
    fn gradient<'py>(&self, py: Python<'py>, q: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let n = self.n;
        let q = read(q, "q", &[Dim::Is(n)])?;
        let mut guard = exclusive(py, &self.inner)?;
        let solver = &mut *guard;
        let grad = py.detach(|| solver.gradient(&q.data).map(<[f64]>::to_vec)).py_err(py)?;
        write(py, grad, &[n])
    }

    /// Hessian (n, n) of E at q for a step from the current state; elastic parts
    /// PSD-projected when `project`.
    #[pyo3(signature = (q, project = true))]
    fn hessian<'py>(&self, py: Python<'py>, q: &Bound<'py, PyAny>, project: bool) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let n = self.n;
        let q = read(q, "q", &[Dim::Is(n)])?;
        let mut guard = exclusive(py, &self.inner)?;
        let solver = &mut *guard;
        let hess = py.detach(|| solver.hessian(&q.data, project).map(<[f64]>::to_vec)).py_err(py)?;
        write(py, hess, &[n, n])
    }

    /// Contact forces (C, 3) in N at the current state over the last step.
    fn contact_forces<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let guard = exclusive(py, &self.inner)?;
        let solver = &*guard;
        let c = solver.system().n_contacts();
        let mut out = vec![0.0; 3 * c];
        py.detach(|| solver.contact_forces(&mut out)).py_err(py)?;
        write(py, out, &[c, 3])
    }
}

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
