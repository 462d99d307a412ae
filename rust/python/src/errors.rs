//! licrom's exception and warning classes, defined here and re-exported by `licrom.errors`
//! (their public home: `__module__` says `licrom.errors`, as tracebacks and pickles name
//! them), and the conversion of core errors to them.
//!
//! The classes derive from built-in exceptions as well (`ConfigError` is a `ValueError`), a
//! multiple inheritance a `#[pyclass]` cannot express: they are built at module init by
//! calling `type(name, bases, namespace)`, the keyword constructors of `SolverError` and
//! `OutputError` being Rust functions bound as methods through `functools.partialmethod`
//! (a built-in function is no descriptor).

use licrom_core::LicromError;
use pyo3::exceptions::{PyException, PyImportError, PyOSError, PyRuntimeError, PyUserWarning, PyValueError};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyDict, PySuper, PyTuple, PyType};
use std::sync::{Mutex, MutexGuard, TryLockError};

/// Where the classes are documented and imported from.
const PUBLIC_MODULE: &str = "licrom.errors";

/// Exception families raised from Rust.
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
    /// `InternalError`: a bug, a panic in the core caught at the boundary.
    Internal,
}

/// A base of a class of the family: a built-in class, or a class defined before it.
enum Base {
    Builtin(fn(Python<'_>) -> Bound<'_, PyType>),
    Family(&'static str),
}

/// A constructor bound as `__init__` (it receives the instance first).
type Init = for<'py> fn(Python<'py>) -> PyResult<Bound<'py, PyAny>>;

/// One class: name, bases, docstring and constructor (None: the bases' one).
struct Spec {
    name: &'static str,
    bases: &'static [Base],
    doc: &'static str,
    init: Option<Init>,
}

const LICROM: Base = Base::Family("LicromError");

/// The family, bases first. The warnings are not raised from Rust; they are here so that the
/// whole family is defined in one place. The docstrings are the stubs' (`_core.pyi`;
/// `tests/test_stubs.py` keeps the two equal).
const FAMILY: [Spec; 13] = [
    Spec {
        name: "LicromError",
        bases: &[Base::Builtin(|py| py.get_type::<PyException>())],
        doc: "Base class of every error licrom raises.",
        init: None,
    },
    Spec {
        name: "MeshError",
        bases: &[LICROM, Base::Builtin(|py| py.get_type::<PyValueError>())],
        doc: "A mesh is unusable: degenerate or inverted tets, bad indices, NaN coordinates.",
        init: None,
    },
    Spec {
        name: "ShapeError",
        bases: &[LICROM, Base::Builtin(|py| py.get_type::<PyValueError>())],
        doc: "An array has the wrong shape, dtype or non-finite values.",
        init: None,
    },
    Spec {
        name: "ConfigError",
        bases: &[LICROM, Base::Builtin(|py| py.get_type::<PyValueError>())],
        doc: "A parameter is outside its accepted range (material, plane, solver, scene).",
        init: None,
    },
    Spec {
        name: "SolverError",
        bases: &[LICROM, Base::Builtin(|py| py.get_type::<PyRuntimeError>())],
        doc: "A solve did not converge or produced non-finite values.

Attributes:
    iterations: iterations taken before giving up (None when not known).
    residual: the last convergence measure in m/s (None when not known).
    step_index: the time step that failed (None when not known).",
        init: Some(|py| wrap_pyfunction!(solver_error_init, py).map(Bound::into_any)),
    },
    Spec {
        name: "FileFormatError",
        bases: &[LICROM, Base::Builtin(|py| py.get_type::<PyOSError>())],
        doc: "A file is missing, truncated, corrupt, foreign, or of an unknown format version.",
        init: None,
    },
    Spec {
        name: "OutputError",
        bases: &[LICROM, Base::Builtin(|py| py.get_type::<PyOSError>())],
        doc: "An output cannot be written: the disk is full, the folder is read-only, or the path is a directory.

Nothing half-written is left behind: the destination keeps its previous contents (or stays absent).

Attributes:
    errno: the operating system's error number (``errno.ENOSPC``, ``errno.EACCES``, ...; None when not known).",
        init: Some(|py| wrap_pyfunction!(output_error_init, py).map(Bound::into_any)),
    },
    Spec {
        name: "ConcurrencyError",
        bases: &[LICROM, Base::Builtin(|py| py.get_type::<PyRuntimeError>())],
        doc: "One simulation was used from two threads at once (a step or evaluation was running in another thread).

A simulation serves one thread at a time; give each thread its own simulation (they run in
parallel), or guard a shared one with a ``threading.Lock``.",
        init: None,
    },
    Spec {
        name: "InternalError",
        bases: &[LICROM, Base::Builtin(|py| py.get_type::<PyRuntimeError>())],
        doc: "A bug in licrom: an internal invariant of the Rust core failed (a panic, caught where the call entered the core).

The message holds the panic's; please report it with the call that raised it. The object that raised it
(a simulation, an estimate) may be left half updated: make a new one.",
        init: None,
    },
    Spec {
        name: "MissingDependencyError",
        bases: &[LICROM, Base::Builtin(|py| py.get_type::<PyImportError>())],
        doc: "An optional package that the asked-for output needs is not installed (the message names the pip extra).",
        init: None,
    },
    Spec {
        name: "LicromWarning",
        bases: &[Base::Builtin(|py| py.get_type::<PyUserWarning>())],
        doc: "Base class of every warning licrom issues.",
        init: None,
    },
    Spec {
        name: "PhysicsWarning",
        bases: &[Base::Family("LicromWarning")],
        doc: "A simulation left the range where its physics holds: inverted elements, contact
penetration deeper than ``licrom.validity.PENETRATION_LIMIT`` of the object's size,
or a start inside a plane (see :mod:`licrom.validity`).",
        init: None,
    },
    Spec {
        name: "AccuracyWarning",
        bases: &[Base::Family("LicromWarning")],
        doc: "A reduced run's online error estimate (``Trajectory.error_estimate``) passed
``licrom.reduced.error_estimate.ERROR_THRESHOLD``: its subspace likely misses the motion
(see :mod:`licrom.reduced.error_estimate`).",
        init: None,
    },
];
/// The classes of [`FAMILY`] in its order, built once.
static CLASSES: PyOnceLock<Vec<Py<PyType>>> = PyOnceLock::new();

fn classes(py: Python<'_>) -> PyResult<&Vec<Py<PyType>>> {
    CLASSES.get_or_try_init(py, || {
        let mut built: Vec<Py<PyType>> = Vec::with_capacity(FAMILY.len());
        let partialmethod = py.import("functools")?.getattr("partialmethod")?;
        for spec in &FAMILY {
            let bases = spec.bases.iter().map(|base| match base {
                Base::Builtin(class) => Ok(class(py)),
                Base::Family(name) => Ok(built[index(name)?].bind(py).clone()),
            });
            let bases = PyTuple::new(py, bases.collect::<PyResult<Vec<_>>>()?)?;
            let namespace = PyDict::new(py);
            namespace.set_item("__module__", PUBLIC_MODULE)?;
            namespace.set_item("__doc__", spec.doc)?;
            if let Some(init) = spec.init {
                namespace.set_item("__init__", partialmethod.call1((init(py)?,))?)?;
            }
            let class = py.get_type::<PyType>().call1((spec.name, bases, namespace))?.cast_into::<PyType>()?;
            built.push(class.unbind());
        }
        Ok(built)
    })
}

/// Position of the class `name` in [`FAMILY`].
fn index(name: &str) -> PyResult<usize> {
    FAMILY.iter().position(|spec| spec.name == name).ok_or_else(|| PyRuntimeError::new_err(format!("no licrom error class {name}")))
}

/// The class `name` of the family.
fn class<'py>(py: Python<'py>, name: &str) -> PyResult<Bound<'py, PyType>> {
    Ok(classes(py)?[index(name)?].bind(py).clone())
}

/// Adds every class of the family to the module.
pub fn add_classes(m: &Bound<'_, PyModule>) -> PyResult<()> {
    for spec in &FAMILY {
        m.add(spec.name, class(m.py(), spec.name)?)?;
    }
    Ok(())
}

/// `SolverError.__init__`: `super().__init__(message)`, then the keyword attributes.
#[pyfunction]
#[pyo3(
    name = "__init__",
    signature = (this, /, message, *, iterations = None, residual = None, step_index = None),
    text_signature = "(self, /, message, *, iterations=None, residual=None, step_index=None)"
)]
fn solver_error_init(
    this: &Bound<'_, PyAny>,
    message: &Bound<'_, PyAny>,
    iterations: Option<&Bound<'_, PyAny>>,
    residual: Option<&Bound<'_, PyAny>>,
    step_index: Option<&Bound<'_, PyAny>>,
) -> PyResult<()> {
    PySuper::new(&class(this.py(), "SolverError")?, this)?.call_method1("__init__", (message,))?;
    this.setattr("iterations", iterations)?;
    this.setattr("residual", residual)?;
    this.setattr("step_index", step_index)
}

/// `OutputError.__init__`: `super().__init__(message)`, then the `errno` attribute.
#[pyfunction]
#[pyo3(name = "__init__", signature = (this, /, message, *, errno = None), text_signature = "(self, /, message, *, errno=None)")]
fn output_error_init(this: &Bound<'_, PyAny>, message: &Bound<'_, PyAny>, errno: Option<&Bound<'_, PyAny>>) -> PyResult<()> {
    PySuper::new(&class(this.py(), "OutputError")?, this)?.call_method1("__init__", (message,))?;
    this.setattr("errno", errno)
}

impl Kind {
    fn class_name(self) -> &'static str {
        match self {
            Kind::Shape => "ShapeError",
            Kind::Config => "ConfigError",
            Kind::Solver => "SolverError",
            Kind::Concurrency => "ConcurrencyError",
            Kind::Internal => "InternalError",
        }
    }
}

/// An instance of the `kind` class with `message`.
pub fn error(py: Python<'_>, kind: Kind, message: impl Into<String>) -> PyErr {
    error_with(py, kind, message.into(), None)
}

/// [`error`] with keyword arguments of the exception's constructor (e.g.
/// `SolverError(message, iterations=..., residual=...)`).
fn error_with(py: Python<'_>, kind: Kind, message: String, kwargs: Option<&Bound<'_, PyDict>>) -> PyErr {
    match class(py, kind.class_name()).and_then(|c| c.call((message,), kwargs)) {
        Ok(instance) => PyErr::from_value(instance),
        // Only when the interpreter itself fails (out of memory): that error, not a lesser one.
        Err(e) => e,
    }
}

/// The licrom exception for a core error. Non-convergence carries the
/// `iterations` and `residual` (m/s) attributes.
pub fn from_core(py: Python<'_>, e: LicromError) -> PyErr {
    let kind = match e {
        LicromError::ShapeMismatch { .. } | LicromError::NonFinite { .. } | LicromError::Overflow { .. } => Kind::Shape,
        LicromError::InvalidParameter { .. } | LicromError::SingularMass { .. } => Kind::Config,
        LicromError::NotConverged { .. } | LicromError::Diverged { .. } => Kind::Solver,
        LicromError::Internal { .. } => Kind::Internal,
    };
    if let LicromError::NotConverged { iterations, residual } = e {
        let kwargs = PyDict::new(py);
        if kwargs.set_item("iterations", iterations).and_then(|_| kwargs.set_item("residual", residual)).is_ok() {
            return error_with(py, kind, e.to_string(), Some(&kwargs));
        }
    }
    error(py, kind, e.to_string())
}

/// A call into the core, a panic there turned into `InternalError` ([`licrom_core::error::guarded`]): every
/// call into the core goes through this or [`detached`], so that a bug reaches the user as a `LicromError`.
pub fn call_core<T>(py: Python<'_>, f: impl FnOnce() -> licrom_core::Result<T>) -> PyResult<T> {
    licrom_core::error::guarded(f).py_err(py)
}

/// [`call_core`] with the GIL released, for calls that compute.
pub fn detached<T: Send>(py: Python<'_>, f: impl FnOnce() -> licrom_core::Result<T> + Send) -> PyResult<T> {
    py.detach(|| licrom_core::error::guarded(f)).py_err(py)
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
