//! Conversion of core errors to licrom's own exception classes.

use licrom_core::LicromError;
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::sync::{Mutex, MutexGuard, TryLockError};

/// Exception families of `licrom.errors`.
#[derive(Debug, Clone, Copy)]
pub enum Kind {
    /// `ShapeError`: wrong shape, dtype or non-finite values.
    Shape,
    /// `ConfigError`: parameter out of range.
    Config,
    /// `SolverError`: no convergence or non-finite values during a solve.
    Solver,
    /// `ConcurrencyError`: one simulation used from two threads at once.
    Concurrency,
}

impl Kind {
    fn class_name(self) -> &'static str {
        match self {
            Kind::Shape => "ShapeError",
            Kind::Config => "ConfigError",
            Kind::Solver => "SolverError",
            Kind::Concurrency => "ConcurrencyError",
        }
    }
}

/// An instance of `licrom.errors.<kind>` with `message`; falls back to the
/// built-in base class if the Python package cannot be imported.
pub fn error(py: Python<'_>, kind: Kind, message: impl Into<String>) -> PyErr {
    error_with(py, kind, message.into(), None)
}

/// [`error`] with keyword arguments of the exception's constructor (e.g.
/// `SolverError(message, iterations=..., residual=...)`).
fn error_with(py: Python<'_>, kind: Kind, message: String, kwargs: Option<&Bound<'_, PyDict>>) -> PyErr {
    let class = py.import("licrom.errors").and_then(|m| m.getattr(kind.class_name()));
    match class.and_then(|c| c.call((message.clone(),), kwargs)) {
        Ok(instance) => PyErr::from_value(instance),
        Err(_) => match kind {
            Kind::Solver | Kind::Concurrency => PyRuntimeError::new_err(message),
            _ => PyValueError::new_err(message),
        },
    }
}

/// The licrom exception for a core error. Non-convergence carries the
/// `iterations` and `residual` (m/s) attributes.
pub fn from_core(py: Python<'_>, e: LicromError) -> PyErr {
    let kind = match e {
        LicromError::ShapeMismatch { .. } | LicromError::NonFinite { .. } | LicromError::Overflow { .. } => Kind::Shape,
        LicromError::InvalidParameter { .. } | LicromError::SingularMass { .. } => Kind::Config,
        LicromError::NotConverged { .. } | LicromError::Diverged { .. } => Kind::Solver,
    };
    if let LicromError::NotConverged { iterations, residual } = e {
        let kwargs = PyDict::new(py);
        if kwargs.set_item("iterations", iterations).and_then(|_| kwargs.set_item("residual", residual)).is_ok() {
            return error_with(py, kind, e.to_string(), Some(&kwargs));
        }
    }
    error(py, kind, e.to_string())
}

/// `Result` of the core mapped to a Python result.
pub trait CoreResultExt<T> {
    /// Maps the error with [`from_core`].
    fn py_err(self, py: Python<'_>) -> PyResult<T>;
}

impl<T> CoreResultExt<T> for licrom_core::Result<T> {
    fn py_err(self, py: Python<'_>) -> PyResult<T> {
        self.map_err(|e| from_core(py, e))
    }
}

/// Exclusive use of a simulation's solver, or a `ConcurrencyError` when another thread
/// holds it: a step runs without the GIL, so a second thread can call in meanwhile.
pub fn exclusive<'a, T>(py: Python<'_>, lock: &'a Mutex<T>) -> PyResult<MutexGuard<'a, T>> {
    match lock.try_lock() {
        Ok(guard) => Ok(guard),
        // A panic in an earlier call already reached its caller as an exception.
        Err(TryLockError::Poisoned(poisoned)) => Ok(poisoned.into_inner()),
        Err(TryLockError::WouldBlock) => Err(error(
            py,
            Kind::Concurrency,
            "this simulation is busy in another thread (a step or evaluation is running there); a simulation serves one \
             thread at a time: give each thread its own simulation, or guard a shared one with a threading.Lock",
        )),
    }
}
