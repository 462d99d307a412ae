//! Python bindings of licrom-core (module `licrom._core`): argument checks,
//! conversions and GIL release; every numerical decision lives in the core.

#[macro_use]
mod solver_methods;

mod arrays;
mod batch;
mod body_frame;
mod errors;
mod inputs;
mod line_search;
mod material;
mod reconstruction;
mod reduced;
mod residual_estimate;
mod vertex_forces;

use pyo3::prelude::*;

/// Rust core of licrom (compiled extension ``licrom._core``).
///
/// Conventions: SI units; arrays are float64 (C-contiguous inputs are used as
/// they are, other layouts are copied); ``vec(F)`` is row-major, index ``3*i + j``
/// holds ``F[i, j]``. Bad inputs raise :class:`licrom.errors.ShapeError` (shape,
/// dtype, NaN/inf, or finite values so large that a result would overflow to
/// inf/NaN), :class:`licrom.errors.ConfigError` (parameters out of range,
/// mass matrix not symmetric positive definite); solver failures raise
/// :class:`licrom.errors.SolverError`. No function returns NaN or inf. Heavy calls
/// release the GIL.
///
/// Material: stable Neo-Hookean (Smith et al. 2018) with the SNH parameters
/// ``mu, lam`` (Pa, both > 0):
/// ``Psi(F) = mu/2 (I_C - 3) + lam/2 (J - alpha)^2 - mu/2 log(I_C + 1) - Psi_0``,
/// ``alpha = 1 + 3 mu / (4 lam)``, where the constant ``Psi_0`` makes the rest
/// state (and every rotation) have zero energy. Valid for inverted F (J <= 0).
/// ``mu / lam`` so large that ``alpha`` or ``Psi_0`` overflow is a ConfigError.
#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    errors::add_classes(m)?;
    m.add_function(wrap_pyfunction!(material::snh_energy, m)?)?;
    m.add_function(wrap_pyfunction!(material::snh_pk1, m)?)?;
    m.add_function(wrap_pyfunction!(material::snh_hessian, m)?)?;
    m.add_class::<reduced::ReducedCore>()?;
    m.add_class::<body_frame::BodyFrameCore>()?;
    m.add_class::<reconstruction::Reconstruction>()?;
    m.add_class::<residual_estimate::ResidualEstimate>()?;
    m.add_class::<vertex_forces::VertexForces>()?;
    m.add_function(wrap_pyfunction!(batch::step_many, m)?)?;
    m.add_function(wrap_pyfunction!(batch::set_second_thread, m)?)?;
    m.add_function(wrap_pyfunction!(line_search::line_search, m)?)?;
    m.add("LINE_SEARCH", line_search::constants(m.py())?)?;
    Ok(())
}
