//! The solvers' line search and its constants, so that the full-space solver
//! (Python, warp) takes steps by the same rule as the reduced solvers.

use licrom_core::solver::line_search as ls;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::errors::{call_core, error, Kind};

/// The reduced solvers' line search from ``phi(0) = e0`` with slope ``d0 < 0``.
///
/// ``phi(alpha)`` returns ``(energy, slope)``; the result is ``(alpha, energy)`` of the
/// step taken (the last call of ``phi`` was there), or None when no step decreases the
/// energy beyond round-off. An exception raised by ``phi`` propagates.
///
/// Raises:
///     ConfigError: ``e0`` not finite, or ``d0`` not a finite negative slope.
#[pyfunction]
pub fn line_search(e0: f64, d0: f64, phi: &Bound<'_, PyAny>) -> PyResult<Option<(f64, f64)>> {
    let py = phi.py();
    if !e0.is_finite() {
        return Err(error(py, Kind::Config, format!("e0 must be a finite energy, got {e0}")));
    }
    if !(d0.is_finite() && d0 < 0.0) {
        return Err(error(py, Kind::Config, format!("d0 must be a finite slope < 0 (a descent direction), got {d0}")));
    }
    let mut failure: Option<PyErr> = None;
    let step = call_core(py, || {
        Ok(ls::line_search(e0, d0, |alpha| {
            if failure.is_some() {
                return (f64::NAN, f64::NAN);
            }
            match phi.call1((alpha,)).and_then(|r| r.extract::<(f64, f64)>()) {
                Ok(value) => value,
                Err(e) => {
                    failure = Some(e);
                    (f64::NAN, f64::NAN)
                }
            }
        }))
    })?;
    match failure {
        Some(e) => Err(e),
        None => Ok(step.map(|s| (s.alpha, s.energy))),
    }
}

/// The line search's constants by name (see `licrom_core::solver::line_search`).
pub fn constants(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("armijo", ls::ARMIJO)?;
    d.set_item("curvature", ls::CURVATURE)?;
    d.set_item("max_secant", ls::MAX_SECANT)?;
    d.set_item("max_halvings", ls::MAX_HALVINGS)?;
    d.set_item("roundoff_ulps", ls::ROUNDOFF_ULPS)?;
    d.set_item("noise", ls::NOISE)?;
    Ok(d)
}
