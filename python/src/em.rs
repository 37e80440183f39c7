//! `estim.em`: expectation-maximisation of a linear-Gaussian model over
//! `estim_core::noise::em` (pykalman's `em`, with its arguments' meanings).

// The mathematical names of the API (F, H, Q, R, P0) are kept as they are.
#![allow(non_snake_case)]

use estim_core::nalgebra::{DMatrix, DVector};
use estim_core::noise::em::{
    em as run_em, EmStop, EmVariables, LinearGaussianModel, TransitionOffsets,
};
use numpy::{PyArray1, PyArray2, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;

use crate::convert::{f64_array, floats_to_py, matrix, matrix_to_py, vector, vector_to_py};
use crate::{estim_err, EstimError};

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<EmResult>()?;
    m.add_function(wrap_pyfunction!(em, m)?)?;
    Ok(())
}

/// The fitted model of `estim.em` and its log-likelihood per iteration.
#[pyclass(module = "estim", frozen)]
pub(crate) struct EmResult {
    /// Transition matrix F, (n, n).
    #[pyo3(get)]
    F: Py<PyArray2<f64>>,
    /// Observation matrix H, (m, n).
    #[pyo3(get)]
    H: Py<PyArray2<f64>>,
    /// Transition covariance Q, (n, n).
    #[pyo3(get)]
    Q: Py<PyArray2<f64>>,
    /// Observation covariance R, (m, m).
    #[pyo3(get)]
    R: Py<PyArray2<f64>>,
    /// Initial state mean x0 (pykalman's initial_state_mean), (n,).
    #[pyo3(get)]
    x0: Py<PyAny>,
    /// Initial state covariance P0, (n, n).
    #[pyo3(get)]
    P0: Py<PyArray2<f64>>,
    /// Transition offsets b: (n,) constant, or (T - 1, n) per step as given.
    #[pyo3(get)]
    b: Py<PyAny>,
    /// Observation offset d, (m,).
    #[pyo3(get)]
    d: Py<PyAny>,
    /// Log-likelihood (nats) after k iterations, k = 0 .. iterations: element 0 is the
    /// given model's.
    #[pyo3(get)]
    log_likelihoods: Py<PyArray1<f64>>,
    /// Iterations that ran (n_iter unless an iteration was refused).
    #[pyo3(get)]
    iterations: usize,
    /// None when every iteration ran; else why the fit stopped early (the iteration
    /// and the check that refused it; the result is the model before it).
    #[pyo3(get)]
    stopped: Option<String>,
}

#[pymethods]
impl EmResult {
    fn __repr__(&self, py: Python<'_>) -> String {
        let last = self
            .log_likelihoods
            .bind(py)
            .readonly()
            .as_slice()
            .ok()
            .and_then(|s| s.last().copied())
            .unwrap_or(f64::NAN);
        format!(
            "EmResult(iterations={}, log_likelihood={last:.6}, stopped={})",
            self.iterations,
            self.stopped
                .as_deref()
                .map_or_else(|| "None".to_string(), |s| format!("{s:?}"))
        )
    }
}

/// One em_vars name (pykalman's, or the native API's short one) as a variable.
fn variable(name: &str) -> PyResult<EmVariables> {
    Ok(match name {
        "transition_covariance" | "Q" => EmVariables::TRANSITION_COVARIANCE,
        "observation_covariance" | "R" => EmVariables::OBSERVATION_COVARIANCE,
        "initial_state_mean" | "x0" => EmVariables::INITIAL_STATE_MEAN,
        "initial_state_covariance" | "P0" => EmVariables::INITIAL_STATE_COVARIANCE,
        "transition_matrices" | "transition_matrix" | "F" => EmVariables::TRANSITION_MATRIX,
        "observation_matrices" | "observation_matrix" | "H" => EmVariables::OBSERVATION_MATRIX,
        "transition_offsets" | "transition_offset" | "b" => EmVariables::TRANSITION_OFFSETS,
        "observation_offsets" | "observation_offset" | "d" => EmVariables::OBSERVATION_OFFSET,
        "all" => EmVariables::ALL,
        other => {
            return Err(EstimError::new_err(format!(
                "em_vars: unknown variable {other:?} (expected 'all' or names among Q, R, x0, \
                 P0, F, H, b, d or pykalman's transition_covariance, observation_covariance, \
                 initial_state_mean, initial_state_covariance, transition_matrices, \
                 observation_matrices, transition_offsets, observation_offsets)"
            )))
        }
    })
}

/// em_vars: None (pykalman's default Q, R, x0, P0), a string, or an iterable of names.
fn variables(em_vars: Option<&Bound<'_, PyAny>>) -> PyResult<EmVariables> {
    let Some(em_vars) = em_vars else {
        return Ok(EmVariables::NOISE_AND_INITIAL_STATE);
    };
    if let Ok(name) = em_vars.extract::<String>() {
        return variable(&name);
    }
    let mut vars = EmVariables::NONE;
    for name in em_vars
        .try_iter()
        .map_err(|_| EstimError::new_err("em_vars: expected a string or a sequence of names"))?
    {
        let name: String = name?
            .extract()
            .map_err(|_| EstimError::new_err("em_vars: every name must be a string"))?;
        vars = vars | variable(&name)?;
    }
    Ok(vars)
}

/// zs as T epochs of m values: (T, m), or (T,) for m = 1; a NaN row is a missing
/// epoch, a row only partly NaN an error.
fn observations(zs: &Bound<'_, PyAny>) -> PyResult<(Vec<Option<DVector<f64>>>, usize)> {
    let a = f64_array(zs, "zs")?;
    let ro = a.readonly();
    let view = ro.as_array();
    let shape = view.shape().to_vec();
    let (steps, m) = match shape.as_slice() {
        [t] => (*t, 1),
        [t, m] => (*t, *m),
        _ => {
            return Err(EstimError::new_err(format!(
                "zs: expected shape (T, m) or (T,), one row per epoch (NaN rows for missing \
                 ones), got {shape:?}"
            )))
        }
    };
    if m == 0 {
        return Err(EstimError::new_err("zs: rows of 0 measurements"));
    }
    let values: Vec<f64> = view.iter().copied().collect();
    debug_assert_eq!(values.len(), steps * m);
    let epochs = values
        .chunks(m)
        .enumerate()
        .map(|(t, row)| match row.iter().filter(|v| v.is_nan()).count() {
            0 => Ok(Some(DVector::from_column_slice(row))),
            nan if nan == m => Ok(None),
            _ => Err(EstimError::new_err(format!(
                "zs: row {t} is partly NaN; a missing epoch is a whole NaN row (EM uses all \
                 of an epoch's measurements or none)"
            ))),
        })
        .collect::<PyResult<_>>()?;
    Ok((epochs, m))
}

/// The state size: dim_x, else the first given array that fixes it, else m
/// (pykalman's default).
fn state_size(
    dim_x: Option<usize>,
    given: &[(Option<&Bound<'_, PyAny>>, &str, usize)],
    m: usize,
) -> PyResult<usize> {
    if let Some(n) = dim_x {
        return Ok(n);
    }
    for &(obj, name, axis) in given {
        if let Some(obj) = obj {
            let a = f64_array(obj, name)?;
            let shape = a.shape().to_vec();
            // A scalar is a 1 x 1 matrix or a 1-vector.
            return Ok(if shape.is_empty() {
                1
            } else {
                *shape.get(axis).unwrap_or(&shape[0])
            });
        }
    }
    Ok(m)
}

/// The transition offsets: None (zero), (n,) constant or (T - 1, n) per step.
fn offsets(b: Option<&Bound<'_, PyAny>>, n: usize) -> PyResult<TransitionOffsets> {
    let Some(b) = b else {
        return Ok(TransitionOffsets::Constant(DVector::zeros(n)));
    };
    let a = f64_array(b, "b")?;
    if a.ndim() == 2 {
        let per_step = matrix(b, "b")?;
        if per_step.ncols() != n {
            return Err(EstimError::new_err(format!(
                "b: per-step offsets must have shape (T - 1, {n}), got ({}, {})",
                per_step.nrows(),
                per_step.ncols()
            )));
        }
        Ok(TransitionOffsets::PerStep(
            per_step
                .row_iter()
                .map(|r| r.transpose().into_owned())
                .collect(),
        ))
    } else {
        Ok(TransitionOffsets::Constant(vector(b, "b")?))
    }
}

/// Fit a linear-Gaussian state-space model to measurements by EM (pykalman's `em`):
///
///     x_0 ~ N(x0, P0),  x_{t+1} = F x_t + b_t + w_t,  z_t = H x_t + d + v_t,
///     Cov(w) = Q, Cov(v) = R,  t = 0 .. T-1.
///
/// Epoch 0 is measured at x_0 itself (no predict before it), as in pykalman; a NaN
/// row of zs is a missing epoch (a row only partly NaN is an error). Arguments not given take pykalman's
/// defaults (F, H, Q, R, P0 identity, x0, b, d zero; n = dim_x, else from the given
/// arrays, else m). em_vars names the parameters learned (pykalman's names or Q, R,
/// x0, P0, F, H, b, d; 'all'); default Q, R, x0, P0. Returns an EmResult.
#[pyfunction]
#[pyo3(signature = (zs, F=None, H=None, Q=None, R=None, x0=None, P0=None, b=None, d=None,
                    em_vars=None, n_iter=10, dim_x=None))]
#[allow(clippy::too_many_arguments)]
fn em(
    py: Python<'_>,
    zs: &Bound<'_, PyAny>,
    F: Option<&Bound<'_, PyAny>>,
    H: Option<&Bound<'_, PyAny>>,
    Q: Option<&Bound<'_, PyAny>>,
    R: Option<&Bound<'_, PyAny>>,
    x0: Option<&Bound<'_, PyAny>>,
    P0: Option<&Bound<'_, PyAny>>,
    b: Option<&Bound<'_, PyAny>>,
    d: Option<&Bound<'_, PyAny>>,
    em_vars: Option<&Bound<'_, PyAny>>,
    n_iter: i64,
    dim_x: Option<i64>,
) -> PyResult<EmResult> {
    let iterations = usize::try_from(n_iter)
        .map_err(|_| EstimError::new_err(format!("n_iter: expected >= 0, got {n_iter}")))?;
    let dim_x = dim_x
        .map(|n| {
            usize::try_from(n)
                .ok()
                .filter(|&n| n > 0)
                .ok_or_else(|| EstimError::new_err(format!("dim_x: expected >= 1, got {n}")))
        })
        .transpose()?;
    let vars = variables(em_vars)?;
    let (measurements, m) = observations(zs)?;
    let b_axis = b
        .map(|b| f64_array(b, "b").map(|a| if a.ndim() == 2 { 1 } else { 0 }))
        .transpose()?
        .unwrap_or(0);
    let n = state_size(
        dim_x,
        &[
            (F, "F", 0),
            (H, "H", 1),
            (Q, "Q", 0),
            (P0, "P0", 0),
            (x0, "x0", 0),
            (b, "b", b_axis),
        ],
        m,
    )?;
    let transition_offsets = offsets(b, n)?;
    let or = |obj: Option<&Bound<'_, PyAny>>, name: &str, default: DMatrix<f64>| {
        obj.map_or(Ok(default), |o| matrix(o, name))
    };
    let model = LinearGaussianModel::new(
        or(F, "F", DMatrix::identity(n, n))?,
        or(H, "H", DMatrix::identity(m, n))?,
        or(Q, "Q", DMatrix::identity(n, n))?,
        or(R, "R", DMatrix::identity(m, m))?,
        x0.map_or(Ok(DVector::zeros(n)), |v| vector(v, "x0"))?,
        or(P0, "P0", DMatrix::identity(n, n))?,
    )
    .and_then(|model| model.with_transition_offsets(transition_offsets))
    .map_err(estim_err)?;
    let model = match d {
        Some(d) => model
            .with_observation_offset(vector(d, "d")?)
            .map_err(estim_err)?,
        None => model,
    };
    let fit = py
        .detach(|| run_em(&model, &measurements, vars, iterations))
        .map_err(estim_err)?;
    let stopped = match &fit.stop {
        EmStop::Refused { iteration, error } => {
            Some(format!("iteration {iteration} refused: {error}"))
        }
        _ => None,
    };
    let fitted = &fit.model;
    let b = match fitted.transition_offsets() {
        TransitionOffsets::Constant(b) => vector_to_py(py, b, false).unbind(),
        TransitionOffsets::PerStep(bs) => {
            let rows = DMatrix::from_fn(bs.len(), n, |t, i| bs[t][i]);
            matrix_to_py(py, &rows).into_any().unbind()
        }
    };
    Ok(EmResult {
        F: matrix_to_py(py, fitted.transition_matrix()).unbind(),
        H: matrix_to_py(py, fitted.observation_matrix()).unbind(),
        Q: matrix_to_py(py, fitted.transition_covariance()).unbind(),
        R: matrix_to_py(py, fitted.observation_covariance()).unbind(),
        x0: vector_to_py(py, fitted.initial_state_mean(), false).unbind(),
        P0: matrix_to_py(py, fitted.initial_state_covariance()).unbind(),
        b,
        d: vector_to_py(py, fitted.observation_offset(), false).unbind(),
        iterations: fit.log_likelihoods.len().saturating_sub(1),
        log_likelihoods: floats_to_py(py, fit.log_likelihoods).unbind(),
        stopped,
    })
}
