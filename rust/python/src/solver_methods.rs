//! The methods both native simulations (`ReducedCore`, `BodyFrameCore`) have
//! alike, written once: a macro puts them on each class as a second
//! `#[pymethods]` block (pyo3's `multiple-pymethods`), since a Python class
//! cannot inherit methods from a Rust trait.

/// Adds `step`, `validity` and `reset_stats` to `$class`, a pyclass whose
/// `inner: Mutex<Solver>` has the solvers' `step`, `validity` and
/// `reset_stats`.
macro_rules! solver_methods {
    ($class:ty) => {
        #[pyo3::pymethods]
        impl $class {
            /// Advance one time step; return (iterations, residual in m/s).
            ///
            /// Raises:
            ///     SolverError: no convergence within ``max_iterations`` (attributes
            ///         ``iterations`` and ``residual``) or non-finite values; the state is
            ///         left unchanged.
            fn step(&self, py: pyo3::Python<'_>) -> pyo3::PyResult<(usize, f64)> {
                let mut guard = $crate::errors::exclusive(py, &self.inner)?;
                let solver = &mut *guard;
                let report = $crate::errors::detached(py, || solver.step())?;
                Ok((report.iterations, report.residual))
            }

            /// ``(min det F, depth)`` of the last step at its accepted iterate: the smallest
            /// ``det F`` at the cubature points (inf without any) and the deepest penetration of a
            /// contact point into a plane in m (>= 0); ``(inf, 0)`` before any step.
            fn validity(&self, py: pyo3::Python<'_>) -> pyo3::PyResult<(f64, f64)> {
                let v = $crate::errors::exclusive(py, &self.inner)?.validity();
                Ok((v.min_det, v.depth))
            }

            /// Zero the work counters.
            fn reset_stats(&self, py: pyo3::Python<'_>) -> pyo3::PyResult<()> {
                $crate::errors::exclusive(py, &self.inner)?.reset_stats();
                Ok(())
            }
        }
    };
}
