//! Batch stable Neo-Hookean functions.

use licrom_core::StableNeoHookean;
use numpy::PyArrayDyn;
use pyo3::prelude::*;

use crate::arrays::{read, write, Dim};
use crate::errors::{call_core, detached};

const F_DIMS: [Dim; 3] = [Dim::Any("p"), Dim::Is(3), Dim::Is(3)];

/// Material and validated deformation gradients `(p, 3, 3)`.
fn inputs(py: Python<'_>, f: &Bound<'_, PyAny>, mu: f64, lam: f64) -> PyResult<(StableNeoHookean, Vec<f64>, usize)> {
    let material = call_core(py, || StableNeoHookean::new(mu, lam))?;
    let f = read(f, "F", &F_DIMS)?;
    Ok((material, f.data, f.shape[0]))
}

/// Energy densities Psi(F), shape (p,), in J/m^3, of deformation gradients ``F`` (p, 3, 3); zero at rest and for every rotation.
#[pyfunction]
#[pyo3(signature = (F, mu, lam))]
#[allow(non_snake_case)]
pub fn snh_energy<'py>(py: Python<'py>, F: &Bound<'py, PyAny>, mu: f64, lam: f64) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    let (material, fs, p) = inputs(py, F, mu, lam)?;
    let mut out = vec![0.0; p];
    detached(py, || material.energy_batch(&fs, &mut out))?;
    write(py, out, &[p])
}

/// First Piola-Kirchhoff stresses dPsi/dF, shape (p, 3, 3), in Pa.
#[pyfunction]
#[pyo3(signature = (F, mu, lam))]
#[allow(non_snake_case)]
pub fn snh_pk1<'py>(py: Python<'py>, F: &Bound<'py, PyAny>, mu: f64, lam: f64) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    let (material, fs, p) = inputs(py, F, mu, lam)?;
    let mut out = vec![0.0; 9 * p];
    detached(py, || material.pk1_batch(&fs, &mut out))?;
    write(py, out, &[p, 3, 3])
}

/// Hessians d^2 Psi / d vec(F)^2, shape (p, 9, 9), in Pa (row-major vec).
///
/// With ``project`` the negative eigenvalues of the analytic eigensystem
/// (Smith, de Goes, Kim 2019) are clamped to zero, so each Hessian is PSD;
/// otherwise the exact, possibly indefinite, Hessian is returned.
#[pyfunction]
#[pyo3(signature = (F, mu, lam, project = true))]
#[allow(non_snake_case)]
pub fn snh_hessian<'py>(py: Python<'py>, F: &Bound<'py, PyAny>, mu: f64, lam: f64, project: bool) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    let (material, fs, p) = inputs(py, F, mu, lam)?;
    let mut out = vec![0.0; 81 * p];
    detached(py, || material.hessian_batch(&fs, project, &mut out))?;
    write(py, out, &[p, 9, 9])
}
