//! NumPy <-> nalgebra conversions with shape checks that name the argument.

use estim_core::nalgebra::{DMatrix, DVector};
use numpy::ndarray::{Array1, Array2, Array3};
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyArray3, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods,
};
use pyo3::prelude::*;

use crate::EstimError;

/// `obj` as a float64 ndarray: the object itself when it already is one, else
/// `numpy.asarray(obj, dtype=float64)`.
pub(crate) fn f64_array<'py>(
    obj: &Bound<'py, PyAny>,
    name: &str,
) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    if let Ok(a) = obj.cast::<PyArrayDyn<f64>>() {
        return Ok(a.clone());
    }
    let np = PyModule::import(obj.py(), "numpy")?;
    let converted = np
        .call_method1("asarray", (obj, "float64"))
        .map_err(|e| EstimError::new_err(format!("{name}: not an array of numbers ({e})")))?;
    converted
        .cast_into::<PyArrayDyn<f64>>()
        .map_err(|_| EstimError::new_err(format!("{name}: not an array of numbers")))
}

/// A float64 array's shape, for messages.
pub(crate) fn shape_of(a: &Bound<'_, PyArrayDyn<f64>>) -> Vec<usize> {
    a.shape().to_vec()
}

/// Read a matrix of any shape: a 2-D array, or a scalar as 1 x 1.
pub(crate) fn matrix(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<DMatrix<f64>> {
    let a = f64_array(obj, name)?;
    let ro = a.readonly();
    let view = ro.as_array();
    match view.ndim() {
        // estim-core's macro: this crate has no nalgebra dependency of its own.
        0 => Ok(estim_core::nalgebra::dmatrix![view[[]]]),
        2 => {
            let (r, c) = (view.shape()[0], view.shape()[1]);
            Ok(DMatrix::from_fn(r, c, |i, j| view[[i, j]]))
        }
        _ => Err(EstimError::new_err(format!(
            "{name}: expected a 2-D array, got shape {:?}",
            view.shape()
        ))),
    }
}

/// Read a matrix that must be rows x cols (a scalar is accepted for 1 x 1).
pub(crate) fn matrix_sized(
    obj: &Bound<'_, PyAny>,
    name: &str,
    rows: usize,
    cols: usize,
) -> PyResult<DMatrix<f64>> {
    let m = matrix(obj, name)?;
    if m.shape() != (rows, cols) {
        return Err(EstimError::new_err(format!(
            "{name}: expected shape ({rows}, {cols}), got ({}, {})",
            m.nrows(),
            m.ncols()
        )));
    }
    Ok(m)
}

/// Read a vector: 1-D, a column (n, 1), a row (1, n) or a scalar (n = 1).
pub(crate) fn vector(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<DVector<f64>> {
    let a = f64_array(obj, name)?;
    let ro = a.readonly();
    let view = ro.as_array();
    let shape = view.shape();
    let ok = match shape.len() {
        0 | 1 => true,
        2 => shape[0] == 1 || shape[1] == 1,
        _ => false,
    };
    if !ok {
        return Err(EstimError::new_err(format!(
            "{name}: expected a vector (n,), (n, 1) or (1, n), got shape {shape:?}"
        )));
    }
    Ok(DVector::from_iterator(view.len(), view.iter().copied()))
}

/// Read a vector that must have n entries.
pub(crate) fn vector_sized(obj: &Bound<'_, PyAny>, name: &str, n: usize) -> PyResult<DVector<f64>> {
    let v = vector(obj, name)?;
    if v.len() != n {
        return Err(EstimError::new_err(format!(
            "{name}: expected {n} entries, got {}",
            v.len()
        )));
    }
    Ok(v)
}

/// A series of T measurements of m values, step-major and contiguous: (T, m), (T,)
/// when m = 1, or (T, m, 1); missing steps are NaN rows.
pub(crate) fn series(obj: &Bound<'_, PyAny>, name: &str, m: usize) -> PyResult<(Vec<f64>, usize)> {
    let a = f64_array(obj, name)?;
    let ro = a.readonly();
    let view = ro.as_array();
    let shape = view.shape().to_vec();
    let steps = shape.first().copied().unwrap_or(0);
    let per_step: usize = shape.iter().skip(1).product();
    if shape.is_empty() || per_step != m {
        return Err(EstimError::new_err(format!(
            "{name}: expected shape (T, {m}) (one row of {m} measurements per step, NaN rows \
             for missing ones), got {shape:?}"
        )));
    }
    // Logical (C) order whatever the memory layout.
    Ok((view.iter().copied().collect(), steps))
}

/// A matrix as a new (rows, cols) array.
pub(crate) fn matrix_to_py<'py>(py: Python<'py>, m: &DMatrix<f64>) -> Bound<'py, PyArray2<f64>> {
    Array2::from_shape_fn(m.shape(), |(i, j)| m[(i, j)]).into_pyarray(py)
}

/// A vector as a new (n,) array, or (n, 1) when `column`.
pub(crate) fn vector_to_py<'py>(
    py: Python<'py>,
    v: &DVector<f64>,
    column: bool,
) -> Bound<'py, PyAny> {
    if column {
        Array2::from_shape_fn((v.len(), 1), |(i, _)| v[i])
            .into_pyarray(py)
            .into_any()
    } else {
        Array1::from_iter(v.iter().copied())
            .into_pyarray(py)
            .into_any()
    }
}

/// A step-major buffer of T states as (T, n).
pub(crate) fn states_to_py(
    py: Python<'_>,
    data: Vec<f64>,
    n: usize,
) -> PyResult<Bound<'_, PyArray2<f64>>> {
    let steps = data.len().checked_div(n).unwrap_or(0);
    Array2::from_shape_vec((steps, n), data)
        .map(|a| a.into_pyarray(py))
        .map_err(|e| EstimError::new_err(format!("internal shape error: {e}")))
}

/// A step-major buffer of T symmetric n x n covariances as (T, n, n).
pub(crate) fn covariances_to_py(
    py: Python<'_>,
    data: Vec<f64>,
    n: usize,
) -> PyResult<Bound<'_, PyArray3<f64>>> {
    let steps = data.len().checked_div(n * n).unwrap_or(0);
    Array3::from_shape_vec((steps, n, n), data)
        .map(|a| a.into_pyarray(py))
        .map_err(|e| EstimError::new_err(format!("internal shape error: {e}")))
}

/// A vector of f64 as a 1-D array.
pub(crate) fn floats_to_py(py: Python<'_>, data: Vec<f64>) -> Bound<'_, PyArray1<f64>> {
    PyArray1::from_vec(py, data)
}
