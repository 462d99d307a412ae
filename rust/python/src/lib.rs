//! Python bindings of licrom-core (module `licrom._core`): argument checks,
//! conversions and GIL release; every numerical decision lives in the core.

mod arrays;
mod batch;
mod body_frame;
mod errors;
mod inputs;
mod line_search;
mod material;
mod reconstruction;
mod reduced;

use pyo3::prelude::*;

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    errors::add_classes(m)?;
    m.add_function(wrap_pyfunction!(material::snh_energy, m)?)?;
    m.add_function(wrap_pyfunction!(material::snh_pk1, m)?)?;
    m.add_function(wrap_pyfunction!(material::snh_hessian, m)?)?;
    m.add_class::<reduced::ReducedCore>()?;
    m.add_class::<body_frame::BodyFrameCore>()?;
    m.add_class::<reconstruction::Reconstruction>()?;
    m.add_function(wrap_pyfunction!(batch::step_many, m)?)?;
    m.add_function(wrap_pyfunction!(line_search::line_search, m)?)?;
    m.add("LINE_SEARCH", line_search::constants(m.py())?)?;
    Ok(())
}
