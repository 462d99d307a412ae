//! Positions of many points from reduced coordinates.

use licrom_core::reconstruction::Reconstruction as CoreReconstruction;
use numpy::PyArrayDyn;
use pyo3::prelude::*;

use crate::arrays::{read, write, Dim};
use crate::errors::{call_core, detached};

/// Positions ``x = X + W q`` of N points.
///
/// Args:
///     basis: (N, 3, n) basis rows W at the points.
///     rest: (N, 3) rest positions X in m.
#[pyclass(module = "licrom._core", frozen)]
pub struct Reconstruction {
    inner: CoreReconstruction,
}

#[pymethods]
impl Reconstruction {
    #[new]
    #[pyo3(signature = (basis, rest))]
    fn new(py: Python<'_>, basis: &Bound<'_, PyAny>, rest: &Bound<'_, PyAny>) -> PyResult<Self> {
        let rest = read(rest, "rest", &[Dim::Any("N"), Dim::Is(3)])?;
        let points = rest.shape[0];
        let basis = read(basis, "basis", &[Dim::Is(points), Dim::Is(3), Dim::Any("n")])?;
        let n = basis.shape[2];
        if n == 0 {
            return Err(crate::errors::error(py, crate::errors::Kind::Shape, "basis must have shape (N, 3, n) with n >= 1, got n = 0"));
        }
        let inner = call_core(py, || CoreReconstruction::new(basis.data, rest.data, n))?;
        Ok(Self { inner })
    }

    /// Number of reduced coordinates n.
    #[getter]
    fn n_dofs(&self) -> usize {
        self.inner.n_dofs()
    }

    /// Number of points N.
    #[getter]
    fn n_points(&self) -> usize {
        self.inner.n_points()
    }

    /// (N, 3) positions in m for reduced coordinates ``q`` (n,).
    fn positions<'py>(&self, py: Python<'py>, q: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let q = read(q, "q", &[Dim::Is(self.inner.n_dofs())])?;
        let points = self.inner.n_points();
        let mut out = vec![0.0; 3 * points];
        detached(py, || self.inner.positions(&q.data, &mut out))?;
        write(py, out, &[points, 3])
    }
}
