//! `estim.fit_noise`: maximum-likelihood scales or diagonals of Q and R for a
//! linear-Gaussian model, over `estim_core::noise::ml::maximize_dyn` and
//! `LinearNoiseModel`.

// The mathematical names of the API (F, Q, H, R, P0) are kept as they are.
#![allow(non_snake_case)]

use estim_core::nalgebra::{DMatrix, DVector};
use estim_core::noise::ml::{
    maximize_dyn, DynBounds, FitOptions, FitStop, LinearNoiseModel, NoiseParameters,
};
use numpy::{PyArray1, PyArray2};
use pyo3::prelude::*;

use crate::convert::{floats_to_py, matrix, matrix_to_py, series, vector};
use crate::{estim_err, EstimError};

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<NoiseFit>()?;
    m.add_function(wrap_pyfunction!(fit_noise, m)?)?;
    Ok(())
}

/// The maximum-likelihood noise of `estim.fit_noise`.
#[pyclass(module = "estim", frozen)]
pub(crate) struct NoiseFit {
    /// The fitted process noise Q(theta^), (n, n).
    #[pyo3(get)]
    Q: Py<PyArray2<f64>>,
    /// The fitted measurement noise R(theta^), (m, m).
    #[pyo3(get)]
    R: Py<PyArray2<f64>>,
    /// The estimate theta^: [q, r] (scales) or [diag Q; diag R] (diagonals).
    #[pyo3(get)]
    theta: Py<PyArray1<f64>>,
    /// Standard errors of theta^ from the observed information; None when the
    /// information is not positive definite.
    #[pyo3(get)]
    standard_errors: Option<Py<PyArray1<f64>>>,
    /// Asymptotic covariance of theta^ (the information's inverse), or None.
    #[pyo3(get)]
    covariance: Option<Py<PyArray2<f64>>>,
    /// Observed information -d^2 ln p / d theta^2 at theta^ (exact, dual numbers).
    #[pyo3(get)]
    information: Py<PyArray2<f64>>,
    /// d ln p / d theta at theta^ (exact).
    #[pyo3(get)]
    gradient: Py<PyArray1<f64>>,
    /// ln p(z_1..z_T | theta^), as kalman_filter's log_likelihood with Q, R.
    #[pyo3(get)]
    log_likelihood: f64,
    /// Whether the information is positive definite and the Newton decrement is below
    /// its tolerance.
    #[pyo3(get)]
    converged: bool,
    /// Why the optimiser stopped: "converged" or the reason it did not.
    #[pyo3(get)]
    stop: String,
    /// "scales" or "diagonals".
    #[pyo3(get)]
    parameters: &'static str,
}

#[pymethods]
impl NoiseFit {
    fn __repr__(&self) -> String {
        format!(
            "NoiseFit(parameters={:?}, log_likelihood={:.6}, converged={})",
            self.parameters,
            self.log_likelihood,
            if self.converged { "True" } else { "False" }
        )
    }
}

fn stop_name(stop: &FitStop) -> String {
    match stop {
        FitStop::Converged => "converged".into(),
        FitStop::NoFreeParameter => "no free parameter".into(),
        FitStop::NewtonStepLimit => "Newton step limit".into(),
        FitStop::HessianNotPositiveDefinite => "Hessian not positive definite".into(),
        FitStop::NoDecrease => "no decrease".into(),
        FitStop::Refused { error } => format!("refused: {error}"),
        FitStop::InformationNotPositiveDefinite => "information not positive definite".into(),
        other => format!("{other:?}"),
    }
}

/// Maximum-likelihood noise of x_k = F x_{k-1} + w_k, z_k = H x_k + v_k (predict, then
/// update at each step, as kalman_filter): with diagonal=False, positive scales
/// theta = [q, r] of the given shapes, Q = q Q0, R = r R0 (start q = r = 1); with
/// diagonal=True, theta = [diag Q; diag R], off-diagonal terms zero (start: the
/// diagonals of Q0, R0). zs is (T, m), NaN rows missing. Exact derivatives (dual
/// numbers), L-BFGS then Newton, standard errors from the observed information.
/// Returns a NoiseFit.
#[pyfunction]
#[pyo3(signature = (F, Q, H, R, x0, P0, zs, diagonal=false))]
#[allow(clippy::too_many_arguments)]
fn fit_noise(
    py: Python<'_>,
    F: &Bound<'_, PyAny>,
    Q: &Bound<'_, PyAny>,
    H: &Bound<'_, PyAny>,
    R: &Bound<'_, PyAny>,
    x0: &Bound<'_, PyAny>,
    P0: &Bound<'_, PyAny>,
    zs: &Bound<'_, PyAny>,
    diagonal: bool,
) -> PyResult<NoiseFit> {
    let r = matrix(R, "R")?;
    let m = r.nrows();
    if m == 0 {
        return Err(EstimError::new_err("R: at least one measurement (m >= 1)"));
    }
    let (values, _) = series(zs, "zs", m)?;
    let measurements = values
        .chunks(m)
        .enumerate()
        .map(|(t, row)| match row.iter().filter(|v| v.is_nan()).count() {
            0 => Ok(Some(DVector::from_column_slice(row))),
            nan if nan == m => Ok(None),
            _ => Err(EstimError::new_err(format!(
                "zs: row {t} is partly NaN; a missing step is a whole NaN row"
            ))),
        })
        .collect::<PyResult<Vec<_>>>()?;
    let parameters = if diagonal {
        NoiseParameters::Diagonals
    } else {
        NoiseParameters::Scales
    };
    let model = LinearNoiseModel::new(
        matrix(F, "F")?,
        matrix(Q, "Q")?,
        matrix(H, "H")?,
        r,
        vector(x0, "x0")?,
        matrix(P0, "P0")?,
        measurements,
        parameters,
    )
    .map_err(estim_err)?;
    let start = model.initial_parameters();
    if let Some(i) = start.iter().position(|&v| v <= 0.0) {
        return Err(EstimError::new_err(format!(
            "Q, R: the start must be positive; diagonal entry {i} of [diag Q; diag R] is {}",
            start[i]
        )));
    }
    let count = model.parameter_count();
    let bounds = DynBounds::new(
        DVector::zeros(count),
        DVector::from_element(count, f64::INFINITY),
    )
    .map_err(estim_err)?;
    let fit = py
        .detach(|| maximize_dyn(&model, &start, &bounds, &FitOptions::default()))
        .map_err(estim_err)?;
    let (q, r) = model.noise_at(&fit.theta).map_err(estim_err)?;
    let vector_py = |v: &DVector<f64>| floats_to_py(py, v.iter().copied().collect()).unbind();
    let matrix_py = |m: &DMatrix<f64>| matrix_to_py(py, m).unbind();
    Ok(NoiseFit {
        Q: matrix_py(&q),
        R: matrix_py(&r),
        theta: vector_py(&fit.theta),
        standard_errors: fit.standard_errors.as_ref().map(vector_py),
        covariance: fit.covariance.as_ref().map(matrix_py),
        information: matrix_py(&fit.information),
        gradient: vector_py(&fit.gradient),
        log_likelihood: fit.log_likelihood,
        converged: fit.converged,
        stop: stop_name(&fit.stop),
        parameters: if diagonal { "diagonals" } else { "scales" },
    })
}
