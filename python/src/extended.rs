//! `estim.ExtendedKalmanFilter`: the extended filter with run-time sizes
//! (`estim_core::dynamic::DynExtendedKalmanFilter`) whose f, F(x), h and H(x) are
//! Python callables.
//!
//! An exception raised by a callable is kept and raised again as it is (its type and
//! message), after the filter has refused the step and stayed unchanged.

// The mathematical names of the API (F, H, Q, R, P0, M) are kept as they are.
#![allow(non_snake_case)]

use std::cell::RefCell;

use estim_core::dynamic::{
    DynExtendedKalmanFilter, DynMeasurementModel, DynProcessModel, MeasurementSeries,
};
use estim_core::nalgebra::{DMatrix, DVector};
use numpy::{PyArray1, PyArray2, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;

use crate::convert::{
    f64_array, matrix, matrix_sized, matrix_to_py, series, vector, vector_sized, vector_to_py,
};
use crate::native::{
    filter_result, joint_policy, smoother_result, update_report, FilterResult, SmootherResult,
    UpdateReport,
};
use crate::{estim_err, EstimError};

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<ExtendedKalmanFilter>()
}

/// A function and its Jacobian as Python callables, and the first exception either
/// raised.
struct Callables<'py> {
    py: Python<'py>,
    function: Bound<'py, PyAny>,
    jacobian: Bound<'py, PyAny>,
    /// The callables' names in messages ("f", "F" or "h", "H").
    names: (&'static str, &'static str),
    raised: RefCell<Option<PyErr>>,
}

impl<'py> Callables<'py> {
    fn new(
        function: &Bound<'py, PyAny>,
        jacobian: &Bound<'py, PyAny>,
        names: (&'static str, &'static str),
    ) -> PyResult<Self> {
        for (obj, name) in [(function, names.0), (jacobian, names.1)] {
            if !obj.is_callable() {
                return Err(EstimError::new_err(format!("{name}: expected a callable")));
            }
        }
        Ok(Self {
            py: function.py(),
            function: function.clone(),
            jacobian: jacobian.clone(),
            names,
            raised: RefCell::new(None),
        })
    }

    /// Keep the first exception; the filter sees a model error naming the callable.
    fn fail(&self, name: &str, e: PyErr) -> estim_core::Error {
        let message = format!("{name} raised {e}");
        self.raised.borrow_mut().get_or_insert(e);
        estim_core::Error::Model(message)
    }

    fn call(
        &self,
        f: &Bound<'py, PyAny>,
        x: &DVector<f64>,
        dt: Option<f64>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let arr = PyArray1::from_slice(self.py, x.as_slice());
        match dt {
            Some(dt) => f.call1((arr, dt)),
            None => f.call1((arr,)),
        }
    }

    /// The function's value (any shape with `out.len()` entries) into `out`.
    fn value(
        &self,
        x: &DVector<f64>,
        dt: Option<f64>,
        out: &mut DVector<f64>,
    ) -> estim_core::Result<()> {
        let name = self.names.0;
        let result = self
            .call(&self.function, x, dt)
            .map_err(|e| self.fail(name, e))?;
        let a = f64_array(&result, name).map_err(|e| self.fail(name, e))?;
        if a.len() != out.len() {
            let shape = a.shape().to_vec();
            return Err(self.fail(
                name,
                EstimError::new_err(format!(
                    "{name} returned shape {shape:?}, expected {} values",
                    out.len()
                )),
            ));
        }
        let ro = a.readonly();
        for (o, v) in out.iter_mut().zip(ro.as_array().iter()) {
            *o = *v;
        }
        Ok(())
    }

    /// The Jacobian (rows x cols, a scalar for 1 x 1) into `out`.
    fn jacobian(
        &self,
        x: &DVector<f64>,
        dt: Option<f64>,
        out: &mut DMatrix<f64>,
    ) -> estim_core::Result<()> {
        let name = self.names.1;
        let result = self
            .call(&self.jacobian, x, dt)
            .map_err(|e| self.fail(name, e))?;
        let j = matrix_sized(&result, name, out.nrows(), out.ncols())
            .map_err(|e| self.fail(name, e))?;
        out.copy_from(&j);
        Ok(())
    }

    /// The exception a callable raised, else `e` as an `EstimError`.
    fn error(&self, e: estim_core::Error) -> PyErr {
        self.raised
            .borrow_mut()
            .take()
            .unwrap_or_else(|| estim_err(e))
    }
}

struct PyProcess<'a, 'py>(&'a Callables<'py>);

impl DynProcessModel for PyProcess<'_, '_> {
    fn propagate(
        &self,
        state: &DVector<f64>,
        dt: f64,
        out: &mut DVector<f64>,
    ) -> estim_core::Result<()> {
        self.0.value(state, Some(dt), out)
    }
    fn jacobian(
        &self,
        state: &DVector<f64>,
        dt: f64,
        out: &mut DMatrix<f64>,
    ) -> estim_core::Result<()> {
        self.0.jacobian(state, Some(dt), out)
    }
}

struct PyMeasurement<'a, 'py>(&'a Callables<'py>);

impl DynMeasurementModel for PyMeasurement<'_, '_> {
    fn predict(&self, state: &DVector<f64>, out: &mut DVector<f64>) -> estim_core::Result<()> {
        self.0.value(state, None, out)
    }
    fn jacobian(&self, state: &DVector<f64>, out: &mut DMatrix<f64>) -> estim_core::Result<()> {
        self.0.jacobian(state, None, out)
    }
}

/// Extended Kalman filter with sizes from the arrays: x_k = f(x_{k-1}, dt) + w,
/// z_k = h(x_k) + v, Cov(w) = Q, Cov(v) = R, optional M = Cov(w, v) per update; f,
/// F(x, dt) = df/dx, h and H(x) = dh/dx are Python callables given to each call.
///
/// ExtendedKalmanFilter(Q, R, x0, P0, joint_check='reject', nis_gate=None)
#[pyclass(module = "estim")]
pub(crate) struct ExtendedKalmanFilter {
    inner: DynExtendedKalmanFilter,
}

/// dt as one value or one per step.
fn time_steps(dt: &Bound<'_, PyAny>) -> PyResult<Vec<f64>> {
    if let Ok(v) = dt.extract::<f64>() {
        return Ok(vec![v]);
    }
    Ok(vector(dt, "dt")?.iter().copied().collect())
}

impl ExtendedKalmanFilter {
    fn cross(&self, m: Option<&Bound<'_, PyAny>>) -> PyResult<Option<DMatrix<f64>>> {
        m.map(|m| {
            matrix_sized(
                m,
                "M",
                self.inner.state_size(),
                self.inner.measurement_size(),
            )
        })
        .transpose()
    }
}

#[pymethods]
impl ExtendedKalmanFilter {
    #[new]
    #[pyo3(signature = (Q, R, x0, P0, joint_check="reject", nis_gate=None))]
    fn new(
        Q: &Bound<'_, PyAny>,
        R: &Bound<'_, PyAny>,
        x0: &Bound<'_, PyAny>,
        P0: &Bound<'_, PyAny>,
        joint_check: &str,
        nis_gate: Option<f64>,
    ) -> PyResult<Self> {
        let mut inner = DynExtendedKalmanFilter::new(
            matrix(Q, "Q")?,
            matrix(R, "R")?,
            vector(x0, "x0")?,
            matrix(P0, "P0")?,
        )
        .map_err(estim_err)?
        .with_joint_check(joint_policy(joint_check)?);
        if let Some(gate) = nis_gate {
            inner = inner.with_nis_gate(gate).map_err(estim_err)?;
        }
        Ok(Self { inner })
    }

    /// Predict over dt: F = F(x, dt), x <- f(x, dt), P <- F P F' + Q.
    #[pyo3(signature = (f, F, dt=1.0))]
    fn predict(&mut self, f: &Bound<'_, PyAny>, F: &Bound<'_, PyAny>, dt: f64) -> PyResult<()> {
        let calls = Callables::new(f, F, ("f", "F"))?;
        self.inner
            .predict(&PyProcess(&calls), dt)
            .map_err(|e| calls.error(e))
    }

    /// Update with z (m values) through h and H: H = H(x), nu = z - h(x); with M (n x m)
    /// the correlated update, after the joint-covariance check. Returns an UpdateReport.
    #[pyo3(signature = (z, h, H, M=None))]
    fn update(
        &mut self,
        py: Python<'_>,
        z: &Bound<'_, PyAny>,
        h: &Bound<'_, PyAny>,
        H: &Bound<'_, PyAny>,
        M: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<UpdateReport> {
        let z = vector_sized(z, "z", self.inner.measurement_size())?;
        let m = self.cross(M)?;
        let calls = Callables::new(h, H, ("h", "H"))?;
        let r = self
            .inner
            .update_slice(&PyMeasurement(&calls), z.as_slice(), m.as_ref())
            .map_err(|e| calls.error(e))?;
        let kf = &self.inner;
        Ok(update_report(
            py,
            r,
            kf.innovation(),
            kf.innovation_covariance(),
            kf.gain(),
        ))
    }

    /// Filter a series zs (T, m) (NaN rows: no measurement): step k predicts over dt
    /// (one value or T) through f, F, then updates through h, H. The filter advances.
    /// Returns a FilterResult.
    #[pyo3(signature = (zs, f, F, h, H, dt=None, M=None))]
    #[allow(clippy::too_many_arguments)]
    fn filter(
        &mut self,
        py: Python<'_>,
        zs: &Bound<'_, PyAny>,
        f: &Bound<'_, PyAny>,
        F: &Bound<'_, PyAny>,
        h: &Bound<'_, PyAny>,
        H: &Bound<'_, PyAny>,
        dt: Option<&Bound<'_, PyAny>>,
        M: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<FilterResult> {
        let dts = dt.map_or(Ok(vec![1.0]), time_steps)?;
        let m = self.cross(M)?;
        let (values, _) = series(zs, "zs", self.inner.measurement_size())?;
        let s =
            MeasurementSeries::new(&values, self.inner.measurement_size()).map_err(estim_err)?;
        let (process, model) = (
            Callables::new(f, F, ("f", "F"))?,
            Callables::new(h, H, ("h", "H"))?,
        );
        let out = self
            .inner
            .filter_series(
                &PyProcess(&process),
                &PyMeasurement(&model),
                &dts,
                &s,
                m.as_ref(),
            )
            .map_err(|e| match process.raised.borrow_mut().take() {
                Some(raised) => raised,
                None => model.error(e),
            })?;
        filter_result(py, out)
    }

    /// Filter and smooth a series in one call (arguments as filter; this filter is left
    /// untouched): the extended RTS smoother over each step's F(x) and H(x), consistent
    /// with M. Returns a SmootherResult.
    #[pyo3(signature = (zs, f, F, h, H, dt=None, M=None))]
    #[allow(clippy::too_many_arguments)]
    fn smooth(
        &self,
        py: Python<'_>,
        zs: &Bound<'_, PyAny>,
        f: &Bound<'_, PyAny>,
        F: &Bound<'_, PyAny>,
        h: &Bound<'_, PyAny>,
        H: &Bound<'_, PyAny>,
        dt: Option<&Bound<'_, PyAny>>,
        M: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<SmootherResult> {
        let dts = dt.map_or(Ok(vec![1.0]), time_steps)?;
        let m = self.cross(M)?;
        let (values, _) = series(zs, "zs", self.inner.measurement_size())?;
        let s =
            MeasurementSeries::new(&values, self.inner.measurement_size()).map_err(estim_err)?;
        let (process, model) = (
            Callables::new(f, F, ("f", "F"))?,
            Callables::new(h, H, ("h", "H"))?,
        );
        let out = self
            .inner
            .filter_and_smooth(
                &PyProcess(&process),
                &PyMeasurement(&model),
                &dts,
                &s,
                m.as_ref(),
            )
            .map_err(|e| match process.raised.borrow_mut().take() {
                Some(raised) => raised,
                None => model.error(e),
            })?;
        smoother_result(py, self.inner.state_size(), out)
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
            "estim.ExtendedKalmanFilter(n={}, m={})",
            self.inner.state_size(),
            self.inner.measurement_size()
        )
    }
}
