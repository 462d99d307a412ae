//! The reduced simulation state and its solvers.

use licrom_core::contact::Plane;
use licrom_core::reduced::{ReducedInputs, ReducedSystem};
use licrom_core::solver::{ElasticHessian, ReducedSolver, SolverKind, SolverSettings};
use licrom_core::StableNeoHookean;
use nalgebra::Vector3;
use numpy::PyArrayDyn;
use pyo3::prelude::*;

use crate::arrays::{read, write, Dim};
use crate::errors::{error, CoreResultExt, Kind};

/// Reduced model, state `(q, qdot)` and solver of one simulation.
#[pyclass(module = "licrom._core")]
pub struct ReducedCore {
    pub(crate) inner: ReducedSolver,
}

#[pymethods]
impl ReducedCore {
    #[new]
    #[pyo3(signature = (
        mass, gravity_force, cubature_jacobians, cubature_weights, mu, lam, contact_basis, contact_rest,
        contact_areas, planes, normal_stiffness, normal_damping, friction_stiffness, dt, total_mass,
        tolerance, max_iterations, solver = "newton", elastic_hessian = "lagged"
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
        max_iterations: i64,
        solver: &str,
        elastic_hessian: &str,
    ) -> PyResult<Self> {
        let kind: SolverKind = solver.parse().py_err(py)?;
        let elastic_hessian: ElasticHessian = elastic_hessian.parse().py_err(py)?;
        if max_iterations < 1 {
            return Err(error(py, Kind::Config, format!("max_iterations must be an integer >= 1, got {max_iterations}")));
        }
        let material = StableNeoHookean::new(mu, lam).py_err(py)?;
        let mass = read(mass, "mass", &[Dim::Any("n"), Dim::Any("n")])?;
        let n = mass.shape[0];
        if mass.shape[1] != n || n == 0 {
            return Err(error(py, Kind::Shape, format!("mass must have shape (n, n) with n >= 1, got {}", crate::arrays::shape_text(&mass.shape))));
        }
        let gravity = read(gravity_force, "gravity_force", &[Dim::Is(n)])?;
        let weights = read(cubature_weights, "cubature_weights", &[Dim::Any("K")])?;
        let k = weights.shape[0];
        let jacobians = read(cubature_jacobians, "cubature_jacobians", &[Dim::Is(k), Dim::Is(9), Dim::Is(n)])?;
        let areas = read(contact_areas, "contact_areas", &[Dim::Any("C")])?;
        let c = areas.shape[0];
        let basis = read(contact_basis, "contact_basis", &[Dim::Is(c), Dim::Is(3), Dim::Is(n)])?;
        let rest = read(contact_rest, "contact_rest", &[Dim::Is(c), Dim::Is(3)])?;
        let planes = read(planes, "planes", &[Dim::Any("P"), Dim::Is(5)])?;
        let planes =
            planes.data.chunks_exact(5).map(|p| Plane::new(Vector3::new(p[0], p[1], p[2]), p[3], p[4])).collect::<Result<Vec<_>, _>>().py_err(py)?;
        let inputs = ReducedInputs {
            mass: &mass.data,
            gravity_force: &gravity.data,
            cubature_jacobians: &jacobians.data,
            cubature_weights: &weights.data,
            material,
            contact_basis: &basis.data,
            contact_rest: &rest.data,
            contact_areas: &areas.data,
            planes: &planes,
            normal_stiffness,
            normal_damping,
            friction_stiffness,
            dt,
        };
        let settings = SolverSettings { elastic_hessian, ..SolverSettings::new(total_mass, tolerance, max_iterations as usize, kind) };
        let inner = py.detach(|| ReducedSystem::new(&inputs).and_then(|system| ReducedSolver::new(system, settings))).py_err(py)?;
        Ok(Self { inner })
    }

    /// Number of reduced coordinates n.
    #[getter]
    fn n_dofs(&self) -> usize {
        self.inner.system().n_dofs()
    }

    /// Reduced coordinates (n,), a copy.
    #[getter]
    fn q<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        write(py, self.inner.q().to_vec(), &[self.n_dofs()])
    }

    /// Reduced velocities (n,) per second, a copy.
    #[getter]
    fn qdot<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        write(py, self.inner.qdot().to_vec(), &[self.n_dofs()])
    }

    /// Replaces the state; contact forces read zero until the next step.
    fn set_state(&mut self, py: Python<'_>, q: &Bound<'_, PyAny>, qdot: &Bound<'_, PyAny>) -> PyResult<()> {
        let n = self.n_dofs();
        let q = read(q, "q", &[Dim::Is(n)])?;
        let qdot = read(qdot, "qdot", &[Dim::Is(n)])?;
        self.inner.set_state(&q.data, &qdot.data).py_err(py)
    }

    /// Advances one step; returns (iterations, residual in m/s).
    fn step(&mut self, py: Python<'_>) -> PyResult<(usize, f64)> {
        let solver = &mut self.inner;
        let report = py.detach(|| solver.step()).py_err(py)?;
        Ok((report.iterations, report.residual))
    }

    /// Work counters since construction (or the last `reset_stats`): steps,
    /// iterations, evaluations, model_iterations, model_evaluations,
    /// elastic_hessians, stick_solves, stick_steps.
    fn stats(&self) -> std::collections::HashMap<&'static str, usize> {
        let s = self.inner.stats();
        [
            ("steps", s.steps),
            ("iterations", s.iterations),
            ("evaluations", s.evaluations),
            ("model_iterations", s.model_iterations),
            ("model_evaluations", s.model_evaluations),
            ("elastic_hessians", s.elastic_hessians),
            ("stick_solves", s.stick_solves),
            ("stick_steps", s.stick_steps),
        ]
        .into_iter()
        .collect()
    }

    /// Zeroes the work counters.
    fn reset_stats(&mut self) {
        self.inner.reset_stats();
    }

    /// Takes the last iterate of a step that just failed to converge as the state.
    fn accept_last_iterate(&mut self, py: Python<'_>) -> PyResult<()> {
        self.inner.accept_last_iterate().py_err(py)
    }

    /// Incremental potential E(q) in J of a step from the current state.
    fn energy(&mut self, py: Python<'_>, q: &Bound<'_, PyAny>) -> PyResult<f64> {
        let q = read(q, "q", &[Dim::Is(self.n_dofs())])?;
        let solver = &mut self.inner;
        py.detach(|| solver.energy(&q.data)).py_err(py)
    }

    /// Gradient (n,) of E at q for a step from the current state.
    fn gradient<'py>(&mut self, py: Python<'py>, q: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let n = self.n_dofs();
        let q = read(q, "q", &[Dim::Is(n)])?;
        let solver = &mut self.inner;
        let grad = py.detach(|| solver.gradient(&q.data).map(<[f64]>::to_vec)).py_err(py)?;
        write(py, grad, &[n])
    }

    /// Hessian (n, n) of E at q for a step from the current state; elastic parts
    /// PSD-projected when `project`.
    #[pyo3(signature = (q, project = true))]
    fn hessian<'py>(&mut self, py: Python<'py>, q: &Bound<'py, PyAny>, project: bool) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let n = self.n_dofs();
        let q = read(q, "q", &[Dim::Is(n)])?;
        let solver = &mut self.inner;
        let hess = py.detach(|| solver.hessian(&q.data, project).map(<[f64]>::to_vec)).py_err(py)?;
        write(py, hess, &[n, n])
    }

    /// Contact forces (C, 3) in N at the current state over the last step.
    fn contact_forces<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let c = self.inner.system().n_contacts();
        let mut out = vec![0.0; 3 * c];
        let solver = &self.inner;
        py.detach(|| solver.contact_forces(&mut out)).py_err(py)?;
        write(py, out, &[c, 3])
    }
}
