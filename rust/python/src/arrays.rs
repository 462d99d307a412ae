//! Validation of numpy inputs and construction of numpy outputs.

use numpy::{PyArrayDyn, PyArrayMethods, PyUntypedArray, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyBool;

use crate::errors::{error, Kind};

/// Python-style tuple text of a shape: `(5,)`, `(2, 3)`.
pub fn shape_text(shape: &[usize]) -> String {
    match shape {
        [d] => format!("({d},)"),
        _ => format!("({})", shape.iter().map(|d| d.to_string()).collect::<Vec<_>>().join(", ")),
    }
}

/// One expected dimension: a fixed size, or a free one with its symbol.
#[derive(Debug, Clone, Copy)]
pub enum Dim {
    /// Exactly this size.
    Is(usize),
    /// Any size (e.g. "p" points).
    Any(&'static str),
}

fn expected_text(dims: &[Dim]) -> String {
    let parts: Vec<String> = dims
        .iter()
        .map(|d| match d {
            Dim::Is(n) => n.to_string(),
            Dim::Any(s) => s.to_string(),
        })
        .collect();
    if parts.len() == 1 {
        format!("({},)", parts[0])
    } else {
        format!("({})", parts.join(", "))
    }
}

/// A validated float64 array copied into C order.
pub struct Array {
    /// Values in C (row-major) order.
    pub data: Vec<f64>,
    /// Its shape.
    pub shape: Vec<usize>,
}

/// Checks that `obj` is a numpy array of element type `T` (`type_name`, with its
/// article, in the messages) and shape `dims`, and copies it in C order (non-contiguous inputs
/// are accepted).
fn read_typed<T: numpy::Element + Copy>(obj: &Bound<'_, PyAny>, name: &str, dims: &[Dim], type_name: &str) -> PyResult<(Vec<T>, Vec<usize>)> {
    let py = obj.py();
    let expected = expected_text(dims);
    let Ok(untyped) = obj.cast::<PyUntypedArray>() else {
        let given = obj.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "?".into());
        return Err(error(py, Kind::Shape, format!("{name} must be {type_name} numpy array of shape {expected}, got a {given}")));
    };
    let dtype = untyped.dtype();
    let Ok(array) = obj.cast::<PyArrayDyn<T>>() else {
        return Err(error(py, Kind::Shape, format!("{name} must be {type_name} array of shape {expected}, got dtype {dtype}")));
    };
    let shape = untyped.shape().to_vec();
    let matches = shape.len() == dims.len()
        && shape.iter().zip(dims).all(|(s, d)| match d {
            Dim::Is(n) => s == n,
            Dim::Any(_) => true,
        });
    if !matches {
        return Err(error(py, Kind::Shape, format!("{name} must have shape {expected}, got {}", shape_text(&shape))));
    }
    let readonly = array.try_readonly().map_err(|e| error(py, Kind::Shape, format!("{name} cannot be read: {e}")))?;
    // `as_slice` also accepts Fortran order, so test for C order explicitly; other
    // layouts are copied in logical (C) order.
    let data: Vec<T> = match readonly.as_slice() {
        Ok(slice) if untyped.is_c_contiguous() => slice.to_vec(),
        _ => readonly.as_array().iter().copied().collect(),
    };
    Ok((data, shape))
}

/// Checks that `obj` is a finite float64 numpy array of shape `dims` and copies
/// it in C order (non-contiguous inputs are accepted).
pub fn read(obj: &Bound<'_, PyAny>, name: &str, dims: &[Dim]) -> PyResult<Array> {
    let (data, shape) = read_typed::<f64>(obj, name, dims, "a float64")?;
    if !data.iter().all(|v| v.is_finite()) {
        return Err(error(obj.py(), Kind::Shape, format!("{name} holds NaN or inf values")));
    }
    Ok(Array { data, shape })
}

/// Checks that `obj` is an int64 numpy array of shape `dims` with values >= 0
/// and copies it in C order (as indices: their upper bound is the caller's to check).
pub fn read_indices(obj: &Bound<'_, PyAny>, name: &str, dims: &[Dim]) -> PyResult<Vec<usize>> {
    let (values, _) = read_typed::<i64>(obj, name, dims, "an int64")?;
    if let Some(v) = values.iter().find(|v| **v < 0) {
        return Err(error(obj.py(), Kind::Shape, format!("{name} must hold indices >= 0, found {v}")));
    }
    Ok(values.into_iter().map(|v| v as usize).collect())
}

/// A new numpy array of `shape` owning `data` (C order).
pub fn write<'py>(py: Python<'py>, data: Vec<f64>, shape: &[usize]) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    numpy::PyArray1::from_vec(py, data).reshape(shape.to_vec())
}

/// A count given from Python: an integer >= 1 (`True` is refused, not taken as 1).
pub fn count(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<usize> {
    let value = if obj.is_instance_of::<PyBool>() { None } else { obj.extract::<i64>().ok().filter(|v| *v >= 1) };
    match value {
        Some(v) => Ok(v as usize),
        None => {
            let text = obj.repr().map(|r| r.to_string()).unwrap_or_else(|_| "?".into());
            Err(error(obj.py(), Kind::Config, format!("{name} must be an integer >= 1, got {text}")))
        }
    }
}
