//! The native API: `estim.KalmanFilter`, `estim.kalman_filter`, `estim.kalman_smoother`,
//! `estim.joint_check`, `estim.nees` / `estim.nis`.

// The mathematical names of the API (P, P0, Q, M) are kept as they are.
#![allow(non_snake_case)]

use estim_core::dynamic::{
    joint_validity_margin, normalised_squared_error, DynKalmanFilter, DynUpdateReport,
    FilteredAndSmoothed, FilteredSeries, MeasurementSeries,
};
use estim_core::nalgebra::{DMatrix, DVector};
use estim_core::JointCheck;
use numpy::{PyArray1, PyArray2, PyArray3, PyArrayMethods};
use pyo3::prelude::*;

use crate::convert::{
    covariances_to_py, f64_array, floats_to_py, matrix, matrix_sized, matrix_to_py, series,
    shape_of, states_to_py, vector, vector_sized, vector_to_py,
};
use crate::{estim_err, EstimError};

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<KalmanFilter>()?;
    m.add_class::<UpdateReport>()?;
    m.add_class::<FilterResult>()?;
    m.add_class::<SmootherResult>()?;
    m.add_function(wrap_pyfunction!(kalman_filter, m)?)?;
    m.add_function(wrap_pyfunction!(kalman_smoother, m)?)?;
    m.add_function(wrap_pyfunction!(joint_check, m)?)?;
    m.add_function(wrap_pyfunction!(nees, m)?)?;
    m.add_function(wrap_pyfunction!(nis, m)?)?;
    Ok(())
}

/// Parse the joint-check policy name.
pub(crate) fn joint_policy(name: &str) -> PyResult<JointCheck> {
    match name {
        "reject" => Ok(JointCheck::Reject),
        "report" => Ok(JointCheck::Report),
        "skip" => Ok(JointCheck::Skip),
        other => Err(EstimError::new_err(format!(
            "joint_check: expected 'reject', 'report' or 'skip', got {other:?}"
        ))),
    }
}

/// Build a filter from Python arguments (sizes from x0 and R).
#[allow(clippy::too_many_arguments)]
fn build(
    f: &Bound<'_, PyAny>,
    q: &Bound<'_, PyAny>,
    h: &Bound<'_, PyAny>,
    r: &Bound<'_, PyAny>,
    x0: &Bound<'_, PyAny>,
    p0: &Bound<'_, PyAny>,
    b: Option<&Bound<'_, PyAny>>,
    policy: &str,
    nis_gate: Option<f64>,
) -> PyResult<DynKalmanFilter> {
    let mut kf = DynKalmanFilter::new(
        matrix(f, "F")?,
        matrix(q, "Q")?,
        matrix(h, "H")?,
        matrix(r, "R")?,
        vector(x0, "x0")?,
        matrix(p0, "P0")?,
    )
    .map_err(estim_err)?
    .with_joint_check(joint_policy(policy)?);
    if let Some(b) = b {
        kf = kf.with_control(matrix(b, "B")?).map_err(estim_err)?;
    }
    if let Some(gate) = nis_gate {
        kf = kf.with_nis_gate(gate).map_err(estim_err)?;
    }
    Ok(kf)
}

/// The optional cross-covariance M (n x m).
fn cross(kf: &DynKalmanFilter, m: Option<&Bound<'_, PyAny>>) -> PyResult<Option<DMatrix<f64>>> {
    m.map(|m| matrix_sized(m, "M", kf.state_size(), kf.measurement_size()))
        .transpose()
}

/// A measurement series with an optional mask (True = measured).
fn measurements(
    kf: &DynKalmanFilter,
    zs: &Bound<'_, PyAny>,
    mask: Option<&Bound<'_, PyAny>>,
) -> PyResult<(Vec<f64>, Option<Vec<bool>>)> {
    let (values, steps) = series(zs, "zs", kf.measurement_size())?;
    let mask = match mask {
        None => None,
        Some(mask) => {
            let flags: Vec<bool> = mask
                .try_iter()?
                .map(|v| v.and_then(|v| v.is_truthy()))
                .collect::<PyResult<_>>()?;
            if flags.len() != steps {
                return Err(EstimError::new_err(format!(
                    "mask: expected {steps} entries (one per step), got {}",
                    flags.len()
                )));
            }
            Some(flags)
        }
    };
    Ok((values, mask))
}

fn with_series<T>(
    kf: &DynKalmanFilter,
    values: &[f64],
    mask: Option<&[bool]>,
    run: impl FnOnce(&MeasurementSeries<'_>) -> estim_core::Result<T>,
) -> PyResult<T> {
    let mut s = MeasurementSeries::new(values, kf.measurement_size()).map_err(estim_err)?;
    if let Some(mask) = mask {
        s = s.with_mask(mask).map_err(estim_err)?;
    }
    run(&s).map_err(estim_err)
}

/// Everything one update attempt produced.
#[pyclass(module = "estim", frozen)]
pub(crate) struct UpdateReport {
    /// False when the NIS gate rejected the measurement (state untouched).
    #[pyo3(get)]
    accepted: bool,
    /// Innovation y - H x, shape (m,).
    #[pyo3(get)]
    innovation: Py<PyAny>,
    /// Innovation covariance S = H P H' + H M + M' H' + R, shape (m, m).
    #[pyo3(get, name = "S")]
    s: Py<PyAny>,
    /// The gain K, shape (n, m); None when rejected.
    #[pyo3(get, name = "K")]
    k: Option<Py<PyAny>>,
    /// Normalised innovation squared.
    #[pyo3(get)]
    nis: f64,
    /// ln N(innovation; 0, S).
    #[pyo3(get)]
    log_likelihood: f64,
    /// Validity margin of [[Q_acc, M], [M', R]] (>= 0 valid); None with joint_check='skip'.
    #[pyo3(get)]
    joint_min_eigenvalue: Option<f64>,
}

#[pymethods]
impl UpdateReport {
    fn __repr__(&self) -> String {
        format!(
            "UpdateReport(accepted={}, nis={:.6}, log_likelihood={:.6}, joint_min_eigenvalue={})",
            if self.accepted { "True" } else { "False" },
            self.nis,
            self.log_likelihood,
            self.joint_min_eigenvalue
                .map_or_else(|| "None".to_string(), |v| format!("{v:.6}"))
        )
    }
}

fn report(py: Python<'_>, kf: &DynKalmanFilter, r: DynUpdateReport) -> UpdateReport {
    update_report(
        py,
        r,
        kf.innovation(),
        kf.innovation_covariance(),
        kf.gain(),
    )
}

/// The report of an update attempt from its innovation, S and gain (the gain shown
/// only when accepted).
pub(crate) fn update_report(
    py: Python<'_>,
    r: DynUpdateReport,
    innovation: &DVector<f64>,
    s: &DMatrix<f64>,
    gain: &DMatrix<f64>,
) -> UpdateReport {
    UpdateReport {
        accepted: r.accepted,
        innovation: vector_to_py(py, innovation, false).unbind(),
        s: matrix_to_py(py, s).into_any().unbind(),
        k: r.accepted
            .then(|| matrix_to_py(py, gain).into_any().unbind()),
        nis: r.nis,
        log_likelihood: r.log_likelihood,
        joint_min_eigenvalue: r.joint_min_eigenvalue,
    }
}

/// Linear Kalman filter with sizes from the arrays: x_k = F x_{k-1} + B u + w,
/// y_k = H x_k + v, Cov(w) = Q, Cov(v) = R, optional M = Cov(w, v) per update.
///
/// KalmanFilter(F, Q, H, R, x0, P0, B=None, joint_check='reject', nis_gate=None)
#[pyclass(module = "estim")]
pub(crate) struct KalmanFilter {
    inner: DynKalmanFilter,
}

#[pymethods]
impl KalmanFilter {
    #[new]
    #[pyo3(signature = (F, Q, H, R, x0, P0, B=None, joint_check="reject", nis_gate=None))]
    #[allow(non_snake_case, clippy::too_many_arguments)]
    fn new(
        F: &Bound<'_, PyAny>,
        Q: &Bound<'_, PyAny>,
        H: &Bound<'_, PyAny>,
        R: &Bound<'_, PyAny>,
        x0: &Bound<'_, PyAny>,
        P0: &Bound<'_, PyAny>,
        B: Option<&Bound<'_, PyAny>>,
        joint_check: &str,
        nis_gate: Option<f64>,
    ) -> PyResult<Self> {
        Ok(Self {
            inner: build(F, Q, H, R, x0, P0, B, joint_check, nis_gate)?,
        })
    }

    /// Predict: x <- F x (+ B u), P <- F P F' + Q.
    #[pyo3(signature = (u=None))]
    fn predict(&mut self, u: Option<&Bound<'_, PyAny>>) -> PyResult<()> {
        match u {
            None => self.inner.predict(),
            Some(u) => {
                let cols = self.inner.control().map_or(0, |b| b.ncols());
                let u = vector_sized(u, "u", cols)?;
                self.inner.predict_with_input(&u)
            }
        }
        .map_err(estim_err)
    }

    /// Update with z (m values); with M (n x m) the correlated update, after the
    /// joint-covariance check. Returns an UpdateReport.
    #[pyo3(signature = (z, M=None))]
    #[allow(non_snake_case)]
    fn update(
        &mut self,
        py: Python<'_>,
        z: &Bound<'_, PyAny>,
        M: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<UpdateReport> {
        let z = vector_sized(z, "z", self.inner.measurement_size())?;
        let m = cross(&self.inner, M)?;
        let r = self
            .inner
            .update_slice(z.as_slice(), m.as_ref())
            .map_err(estim_err)?;
        Ok(report(py, &self.inner, r))
    }

    /// Filter a series zs (T, m) (NaN rows or mask=False: no measurement); the filter
    /// advances. Returns a FilterResult.
    #[pyo3(signature = (zs, M=None, mask=None))]
    #[allow(non_snake_case)]
    fn filter(
        &mut self,
        py: Python<'_>,
        zs: &Bound<'_, PyAny>,
        M: Option<&Bound<'_, PyAny>>,
        mask: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<FilterResult> {
        let m = cross(&self.inner, M)?;
        let (values, mask) = measurements(&self.inner, zs, mask)?;
        let inner = &mut self.inner;
        let out = {
            let mut s =
                MeasurementSeries::new(&values, inner.measurement_size()).map_err(estim_err)?;
            if let Some(mask) = mask.as_deref() {
                s = s.with_mask(mask).map_err(estim_err)?;
            }
            inner.filter_series(&s, m.as_ref()).map_err(estim_err)?
        };
        filter_result(py, out)
    }

    /// Filter and smooth a series in one call (this filter is left untouched).
    /// Returns a SmootherResult.
    #[pyo3(signature = (zs, M=None, mask=None))]
    #[allow(non_snake_case)]
    fn smooth(
        &self,
        py: Python<'_>,
        zs: &Bound<'_, PyAny>,
        M: Option<&Bound<'_, PyAny>>,
        mask: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<SmootherResult> {
        smooth_with(py, &self.inner, zs, M, mask)
    }

    /// The state estimate, shape (n,).
    #[getter]
    fn x<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        vector_to_py(py, self.inner.state(), false)
    }

    /// Its covariance, shape (n, n).
    #[getter(P)]
    fn p<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        matrix_to_py(py, self.inner.covariance())
    }

    /// Sum of the accepted updates' log-likelihood terms.
    #[getter]
    fn log_likelihood(&self) -> f64 {
        self.inner.log_likelihood()
    }

    fn __repr__(&self) -> String {
        format!(
            "estim.KalmanFilter(n={}, m={})",
            self.inner.state_size(),
            self.inner.measurement_size()
        )
    }
}

/// A filtered series.
#[pyclass(module = "estim", frozen)]
pub(crate) struct FilterResult {
    /// Filtered states, (T, n).
    #[pyo3(get)]
    x: Py<PyArray2<f64>>,
    /// Filtered covariances, (T, n, n).
    #[pyo3(get, name = "P")]
    p: Py<PyArray3<f64>>,
    /// NIS per step (NaN without a measurement), (T,).
    #[pyo3(get)]
    nis: Py<PyArray1<f64>>,
    /// Whether each step's update was accepted, list of T bools.
    #[pyo3(get)]
    accepted: Vec<bool>,
    /// Sum of the accepted updates' log-likelihood terms.
    #[pyo3(get)]
    log_likelihood: f64,
}

#[pymethods]
impl FilterResult {
    fn __repr__(&self) -> String {
        format!(
            "FilterResult(steps={}, log_likelihood={:.6})",
            self.accepted.len(),
            self.log_likelihood
        )
    }
}

pub(crate) fn filter_result(py: Python<'_>, out: FilteredSeries) -> PyResult<FilterResult> {
    let n = out.estimates.state_size();
    let (states, covariances) = out.estimates.into_parts();
    Ok(FilterResult {
        x: states_to_py(py, states, n)?.unbind(),
        p: covariances_to_py(py, covariances, n)?.unbind(),
        nis: floats_to_py(py, out.nis).unbind(),
        accepted: out.accepted,
        log_likelihood: out.log_likelihood,
    })
}

/// Filtered and smoothed estimates of one forward pass.
#[pyclass(module = "estim", frozen)]
pub(crate) struct SmootherResult {
    /// Smoothed states, (T, n).
    #[pyo3(get)]
    x: Py<PyArray2<f64>>,
    /// Smoothed covariances, (T, n, n).
    #[pyo3(get, name = "P")]
    p: Py<PyArray3<f64>>,
    /// Filtered states, (T, n).
    #[pyo3(get)]
    x_filtered: Py<PyArray2<f64>>,
    /// Filtered covariances, (T, n, n).
    #[pyo3(get)]
    P_filtered: Py<PyArray3<f64>>,
    /// Smoothed initial state x0 given every measurement, (n,).
    #[pyo3(get)]
    x0: Py<PyAny>,
    /// Its covariance, (n, n).
    #[pyo3(get)]
    P0: Py<PyArray2<f64>>,
    /// NIS per step (NaN without a measurement), (T,).
    #[pyo3(get)]
    nis: Py<PyArray1<f64>>,
    /// Sum of the accepted updates' log-likelihood terms.
    #[pyo3(get)]
    log_likelihood: f64,
}

#[pymethods]
impl SmootherResult {
    fn __repr__(&self) -> String {
        format!("SmootherResult(log_likelihood={:.6})", self.log_likelihood)
    }
}

fn smooth_with(
    py: Python<'_>,
    kf: &DynKalmanFilter,
    zs: &Bound<'_, PyAny>,
    m: Option<&Bound<'_, PyAny>>,
    mask: Option<&Bound<'_, PyAny>>,
) -> PyResult<SmootherResult> {
    let m = cross(kf, m)?;
    let (values, mask) = measurements(kf, zs, mask)?;
    let out = with_series(kf, &values, mask.as_deref(), |s| {
        kf.filter_and_smooth(s, m.as_ref())
    })?;
    smoother_result(py, kf.state_size(), out)
}

/// A SmootherResult from one call's filtered and smoothed estimates (n states).
pub(crate) fn smoother_result(
    py: Python<'_>,
    n: usize,
    out: FilteredAndSmoothed,
) -> PyResult<SmootherResult> {
    let log_likelihood = out.filtered.log_likelihood;
    let filtered = filter_result(py, out.filtered)?;
    let (states, covariances) = out.smoothed.into_parts();
    Ok(SmootherResult {
        x: states_to_py(py, states, n)?.unbind(),
        p: covariances_to_py(py, covariances, n)?.unbind(),
        x_filtered: filtered.x,
        P_filtered: filtered.p,
        x0: vector_to_py(py, &out.smoothed_initial_state, false).unbind(),
        P0: matrix_to_py(py, &out.smoothed_initial_covariance).unbind(),
        nis: filtered.nis,
        log_likelihood,
    })
}

/// Filter a whole series: x_k = F x_{k-1} + w, z_k = H x_k + v (predict, then update
/// when row k of zs is not NaN / mask[k] is True). Returns a FilterResult.
#[pyfunction]
#[pyo3(signature = (F, Q, H, R, x0, P0, zs, M=None, mask=None, joint_check="reject"))]
#[allow(non_snake_case, clippy::too_many_arguments)]
fn kalman_filter(
    py: Python<'_>,
    F: &Bound<'_, PyAny>,
    Q: &Bound<'_, PyAny>,
    H: &Bound<'_, PyAny>,
    R: &Bound<'_, PyAny>,
    x0: &Bound<'_, PyAny>,
    P0: &Bound<'_, PyAny>,
    zs: &Bound<'_, PyAny>,
    M: Option<&Bound<'_, PyAny>>,
    mask: Option<&Bound<'_, PyAny>>,
    joint_check: &str,
) -> PyResult<FilterResult> {
    let mut kf = build(F, Q, H, R, x0, P0, None, joint_check, None)?;
    let m = cross(&kf, M)?;
    let (values, mask) = measurements(&kf, zs, mask)?;
    let m_size = kf.measurement_size();
    let out = py.detach(|| {
        let mut s = MeasurementSeries::new(&values, m_size)?;
        if let Some(mask) = mask.as_deref() {
            s = s.with_mask(mask)?;
        }
        kf.filter_series(&s, m.as_ref())
    });
    filter_result(py, out.map_err(estim_err)?)
}

/// Filter and smooth a whole series in one call (RTS, consistent with M). Returns a
/// SmootherResult with the smoothed and the filtered estimates.
#[pyfunction]
#[pyo3(signature = (F, Q, H, R, x0, P0, zs, M=None, mask=None, joint_check="reject"))]
#[allow(non_snake_case, clippy::too_many_arguments)]
fn kalman_smoother(
    py: Python<'_>,
    F: &Bound<'_, PyAny>,
    Q: &Bound<'_, PyAny>,
    H: &Bound<'_, PyAny>,
    R: &Bound<'_, PyAny>,
    x0: &Bound<'_, PyAny>,
    P0: &Bound<'_, PyAny>,
    zs: &Bound<'_, PyAny>,
    M: Option<&Bound<'_, PyAny>>,
    mask: Option<&Bound<'_, PyAny>>,
    joint_check: &str,
) -> PyResult<SmootherResult> {
    let kf = build(F, Q, H, R, x0, P0, None, joint_check, None)?;
    smooth_with(py, &kf, zs, M, mask)
}

/// Validity margin of the joint covariance [[Q, M], [M', R]]: >= 0 (to ~1e-9) iff it
/// is a covariance (positive semidefinite); negative: M is not a possible
/// Cov(w, v) for these Q and R.
#[pyfunction]
#[allow(non_snake_case)]
fn joint_check(Q: &Bound<'_, PyAny>, M: &Bound<'_, PyAny>, R: &Bound<'_, PyAny>) -> PyResult<f64> {
    joint_validity_margin(&matrix(Q, "Q")?, &matrix(M, "M")?, &matrix(R, "R")?).map_err(estim_err)
}

/// e' C^-1 e for one error (n,) and covariance (n, n) -> float, or for a series (T, n)
/// and (T, n, n) -> array (T,).
fn normalised(
    py: Python<'_>,
    error: &Bound<'_, PyAny>,
    covariance: &Bound<'_, PyAny>,
    names: (&str, &str),
) -> PyResult<Py<PyAny>> {
    let e = f64_array(error, names.0)?;
    let c = f64_array(covariance, names.1)?;
    let (es, cs) = (shape_of(&e), shape_of(&c));
    let (e_ro, c_ro) = (e.readonly(), c.readonly());
    let (ev, cv) = (e_ro.as_array(), c_ro.as_array());
    let one = |k: Option<usize>, n: usize| -> PyResult<f64> {
        let err = DVector::from_fn(n, |i, _| match k {
            None => ev[[i]],
            Some(k) => ev[[k, i]],
        });
        let cov = DMatrix::from_fn(n, n, |i, j| match k {
            None => cv[[i, j]],
            Some(k) => cv[[k, i, j]],
        });
        normalised_squared_error(&err, &cov).map_err(estim_err)
    };
    match (es.as_slice(), cs.as_slice()) {
        ([n], [a, b]) if a == n && b == n => Ok(one(None, *n)?.into_pyobject(py)?.into_any().unbind()),
        ([t, n], [t2, a, b]) if t == t2 && a == n && b == n => {
            let values = (0..*t).map(|k| one(Some(k), *n)).collect::<PyResult<Vec<_>>>()?;
            Ok(floats_to_py(py, values).into_any().unbind())
        }
        _ => Err(EstimError::new_err(format!(
            "{}, {}: expected shapes (n,) and (n, n), or (T, n) and (T, n, n); got {es:?} and {cs:?}",
            names.0, names.1
        ))),
    }
}

/// Normalised estimation error squared (x_true - x_est)' P^-1 (x_true - x_est); for one
/// step ((n,), (n,), (n, n)) a float, for a series ((T, n), (T, n), (T, n, n)) an array
/// (T,).
#[pyfunction]
#[pyo3(name = "nees")]
#[allow(non_snake_case)]
fn nees(
    py: Python<'_>,
    x_true: &Bound<'_, PyAny>,
    x_est: &Bound<'_, PyAny>,
    P: &Bound<'_, PyAny>,
) -> PyResult<Py<PyAny>> {
    let (a, b) = (f64_array(x_true, "x_true")?, f64_array(x_est, "x_est")?);
    if shape_of(&a) != shape_of(&b) {
        return Err(EstimError::new_err(format!(
            "x_true, x_est: shapes differ ({:?} and {:?})",
            shape_of(&a),
            shape_of(&b)
        )));
    }
    let error = a.readonly().as_array().to_owned() - b.readonly().as_array();
    let error = numpy::IntoPyArray::into_pyarray(error, py);
    normalised(py, error.as_any(), P, ("x_true - x_est", "P"))
}

/// Normalised innovation squared nu' S^-1 nu; for one innovation ((m,), (m, m)) a
/// float, for a series ((T, m), (T, m, m)) an array (T,).
#[pyfunction]
#[allow(non_snake_case)]
fn nis(py: Python<'_>, innovation: &Bound<'_, PyAny>, S: &Bound<'_, PyAny>) -> PyResult<Py<PyAny>> {
    normalised(py, innovation, S, ("innovation", "S"))
}
