//! The Rust half of `estim.filterpy.UnscentedKalmanFilter`: filterpy's Python
//! callables (fx, hx and the residual / mean hooks) as the models of
//! `estim_core::dynamic::DynUnscentedKalmanFilter`, which draws the sigma points, sums
//! them and updates; the Python class keeps filterpy's attributes and hands them over
//! at each call.
//!
//! An exception raised by a callable is kept and raised again as it is (its type and
//! message), after the filter has refused the step and stayed unchanged.

// filterpy's argument names (x, P, Q, R, Wm, Xs, Ps, Qs) are its API.
#![allow(non_snake_case)]

use std::cell::RefCell;

use estim_core::dynamic::{
    DynSigmaPointMeasurement, DynSigmaPointProcess, DynSigmaPoints, DynUnscentedKalmanFilter,
};
use estim_core::nalgebra::{DMatrix, DVector};
use estim_core::sigma_point::UnscentedTransform;
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::convert::{
    covariances_to_py, f64_array, matrix_sized, matrix_to_py, states_to_py, vector_to_py,
};
use crate::{estim_err, EstimError};

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<UnscentedCore>()
}

/// The Python callables of one call and the first exception one of them raised.
struct Callables<'py> {
    py: Python<'py>,
    /// fx(x, dt, **kwargs) or hx(x, **kwargs).
    map: Bound<'py, PyAny>,
    kwargs: Option<Bound<'py, PyDict>>,
    residual: Option<Bound<'py, PyAny>>,
    mean: Option<Bound<'py, PyAny>>,
    /// filterpy's `Wm`, handed to the mean hook.
    mean_weights: Bound<'py, PyAny>,
    name: &'static str,
    raised: RefCell<Option<PyErr>>,
}

impl<'py> Callables<'py> {
    /// Keep the first exception; the filter sees a model error naming the callable.
    fn fail(&self, e: PyErr) -> estim_core::Error {
        let message = format!("{} raised {e}", self.name);
        self.raised.borrow_mut().get_or_insert(e);
        estim_core::Error::Model(message)
    }

    /// `value` (any shape with `out.len()` entries) into `out`.
    fn read_into(
        &self,
        value: &Bound<'py, PyAny>,
        what: &str,
        out: &mut DVector<f64>,
    ) -> estim_core::Result<()> {
        let a = f64_array(value, what).map_err(|e| self.fail(e))?;
        if a.len() != out.len() {
            let shape = a.shape().to_vec();
            return Err(self.fail(EstimError::new_err(format!(
                "{what} returned shape {shape:?}, expected {} values",
                out.len()
            ))));
        }
        let ro = a.readonly();
        for (o, v) in out.iter_mut().zip(ro.as_array().iter()) {
            *o = *v;
        }
        Ok(())
    }

    fn call_map(
        &self,
        x: &DVector<f64>,
        dt: Option<f64>,
        out: &mut DVector<f64>,
    ) -> estim_core::Result<()> {
        let arr = PyArray1::from_slice(self.py, x.as_slice());
        let result = match dt {
            Some(dt) => self.map.call((arr, dt), self.kwargs.as_ref()),
            None => self.map.call((arr,), self.kwargs.as_ref()),
        }
        .map_err(|e| self.fail(e))?;
        self.read_into(&result, self.name, out)
    }

    fn call_residual(
        &self,
        a: &DVector<f64>,
        b: &DVector<f64>,
        out: &mut DVector<f64>,
    ) -> estim_core::Result<()> {
        match &self.residual {
            None => {
                out.copy_from(a);
                *out -= b;
                Ok(())
            }
            Some(f) => {
                let result = f
                    .call1((
                        PyArray1::from_slice(self.py, a.as_slice()),
                        PyArray1::from_slice(self.py, b.as_slice()),
                    ))
                    .map_err(|e| self.fail(e))?;
                self.read_into(&result, "residual", out)
            }
        }
    }

    fn call_mean(
        &self,
        points: &DynSigmaPoints<'_>,
        out: &mut DVector<f64>,
    ) -> estim_core::Result<()> {
        match &self.mean {
            None => {
                points.weighted_mean_into(out);
                Ok(())
            }
            Some(f) => {
                // filterpy's sigmas: one point per row.
                let sigmas = points.points().transpose();
                let (rows, cols) = (sigmas.nrows(), sigmas.ncols());
                let array = Array2::from_shape_fn((rows, cols), |(i, j)| sigmas[(i, j)]);
                let result = f
                    .call1((array.into_pyarray(self.py), &self.mean_weights))
                    .map_err(|e| self.fail(e))?;
                self.read_into(&result, "mean function", out)
            }
        }
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

impl DynSigmaPointProcess for PyProcess<'_, '_> {
    fn propagate(
        &self,
        state: &DVector<f64>,
        dt: f64,
        out: &mut DVector<f64>,
    ) -> estim_core::Result<()> {
        self.0.call_map(state, Some(dt), out)
    }
    fn residual(
        &self,
        a: &DVector<f64>,
        b: &DVector<f64>,
        out: &mut DVector<f64>,
    ) -> estim_core::Result<()> {
        self.0.call_residual(a, b, out)
    }
    fn mean(&self, points: &DynSigmaPoints<'_>, out: &mut DVector<f64>) -> estim_core::Result<()> {
        self.0.call_mean(points, out)
    }
}

struct PyMeasurement<'a, 'py>(&'a Callables<'py>);

impl DynSigmaPointMeasurement for PyMeasurement<'_, '_> {
    fn predict(&self, state: &DVector<f64>, out: &mut DVector<f64>) -> estim_core::Result<()> {
        self.0.call_map(state, None, out)
    }
    fn residual(
        &self,
        a: &DVector<f64>,
        b: &DVector<f64>,
        out: &mut DVector<f64>,
    ) -> estim_core::Result<()> {
        self.0.call_residual(a, b, out)
    }
    fn mean(&self, points: &DynSigmaPoints<'_>, out: &mut DVector<f64>) -> estim_core::Result<()> {
        self.0.call_mean(points, out)
    }
}

/// `None` for a missing hook or NumPy's `subtract` (the plain difference).
fn hook<'py>(obj: Option<Bound<'py, PyAny>>) -> PyResult<Option<Bound<'py, PyAny>>> {
    let Some(obj) = obj else { return Ok(None) };
    if obj.is_none() {
        return Ok(None);
    }
    let subtract = PyModule::import(obj.py(), "numpy")?.getattr("subtract")?;
    Ok(if obj.is(&subtract) { None } else { Some(obj) })
}

/// A state of n values: (n,) or (n, 1), or a scalar for n = 1.
fn state(obj: &Bound<'_, PyAny>, n: usize) -> PyResult<DVector<f64>> {
    let a = f64_array(obj, "x")?;
    let shape = a.shape().to_vec();
    let ok = matches!(shape.as_slice(), [k] if *k == n)
        || matches!(shape.as_slice(), [k, 1] if *k == n)
        || (shape.is_empty() && n == 1);
    if !ok {
        return Err(EstimError::new_err(format!(
            "x: expected shape ({n},), got {shape:?}"
        )));
    }
    let ro = a.readonly();
    Ok(DVector::from_iterator(n, ro.as_array().iter().copied()))
}

/// A square covariance: n x n, or a scalar s as s I.
fn covariance(obj: &Bound<'_, PyAny>, name: &str, n: usize) -> PyResult<DMatrix<f64>> {
    if let Ok(s) = obj.extract::<f64>() {
        return Ok(DMatrix::identity(n, n) * s);
    }
    matrix_sized(obj, name, n, n)
}

/// The sigma-point machinery of `estim.filterpy.UnscentedKalmanFilter` (estim-core's
/// `DynUnscentedKalmanFilter`): predict, update and the URTS smoother, each handed
/// the filter's current attributes.
#[pyclass(module = "estim.filterpy", name = "_UnscentedCore")]
pub(crate) struct UnscentedCore {
    filter: DynUnscentedKalmanFilter,
    n: usize,
    m: usize,
}

impl UnscentedCore {
    /// Hand over x, P and one noise matrix (Q or R) when they differ.
    fn load(&mut self, x: &Bound<'_, PyAny>, P: &Bound<'_, PyAny>) -> PyResult<()> {
        let x = state(x, self.n)?;
        let p = covariance(P, "P", self.n)?;
        if &x != self.filter.state() || &p != self.filter.covariance() {
            self.filter.set_estimate(&x, &p).map_err(estim_err)?;
        }
        Ok(())
    }
}

#[pymethods]
impl UnscentedCore {
    /// Sigma points of `dim_x` states with Van der Merwe's (alpha, beta, kappa) (Julier's
    /// kappa: alpha = 1, beta = 0), for `dim_z` measurements.
    #[new]
    fn new(dim_x: usize, dim_z: usize, alpha: f64, beta: f64, kappa: f64) -> PyResult<Self> {
        let transform = UnscentedTransform::new(alpha, beta, kappa).map_err(estim_err)?;
        let filter = DynUnscentedKalmanFilter::new(
            transform,
            DMatrix::identity(dim_x, dim_x),
            DMatrix::identity(dim_z, dim_z),
            DVector::zeros(dim_x),
            DMatrix::identity(dim_x, dim_x),
        )
        .map_err(estim_err)?;
        Ok(Self {
            filter,
            n: dim_x,
            m: dim_z,
        })
    }

    /// The prior of (x, P) over dt through fx (filterpy's `predict`): returns (x, P).
    #[pyo3(signature = (x, P, Q, dt, fx, kwargs, residual_x, x_mean_fn, Wm))]
    #[allow(clippy::too_many_arguments)] // filterpy's attributes, handed over at each call
    fn predict<'py>(
        &mut self,
        py: Python<'py>,
        x: &Bound<'py, PyAny>,
        P: &Bound<'py, PyAny>,
        Q: &Bound<'py, PyAny>,
        dt: f64,
        fx: Bound<'py, PyAny>,
        kwargs: Option<Bound<'py, PyDict>>,
        residual_x: Option<Bound<'py, PyAny>>,
        x_mean_fn: Option<Bound<'py, PyAny>>,
        Wm: Bound<'py, PyAny>,
    ) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
        self.load(x, P)?;
        let q = covariance(Q, "Q", self.n)?;
        if &q != self.filter.process_noise() {
            self.filter.set_process_noise(&q).map_err(estim_err)?;
        }
        let callables = Callables {
            py,
            map: fx,
            kwargs,
            residual: hook(residual_x)?,
            mean: hook(x_mean_fn)?,
            mean_weights: Wm,
            name: "fx",
            raised: RefCell::new(None),
        };
        self.filter
            .predict(&PyProcess(&callables), dt)
            .map_err(|e| callables.error(e))?;
        Ok((
            vector_to_py(py, self.filter.state(), false),
            matrix_to_py(py, self.filter.covariance()).into_any(),
        ))
    }

    /// The posterior of (x, P) given z through hx (filterpy's `update`): returns a dict
    /// with x, P, K, y, S, SI, zp, sigmas_h and log_likelihood.
    #[pyo3(signature = (x, P, z, R, hx, kwargs, residual_z, z_mean_fn, Wm))]
    #[allow(clippy::too_many_arguments)] // filterpy's attributes, handed over at each call
    fn update<'py>(
        &mut self,
        py: Python<'py>,
        x: &Bound<'py, PyAny>,
        P: &Bound<'py, PyAny>,
        z: &Bound<'py, PyAny>,
        R: &Bound<'py, PyAny>,
        hx: Bound<'py, PyAny>,
        kwargs: Option<Bound<'py, PyDict>>,
        residual_z: Option<Bound<'py, PyAny>>,
        z_mean_fn: Option<Bound<'py, PyAny>>,
        Wm: Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyDict>> {
        self.load(x, P)?;
        let r = covariance(R, "R", self.m)?;
        if &r != self.filter.measurement_noise() {
            self.filter.set_measurement_noise(&r).map_err(estim_err)?;
        }
        let z = {
            let a = f64_array(z, "z")?;
            if a.len() != self.m {
                return Err(EstimError::new_err(format!(
                    "z (shape {:?}) must have {} values",
                    a.shape(),
                    self.m
                )));
            }
            let ro = a.readonly();
            DVector::from_iterator(self.m, ro.as_array().iter().copied())
        };
        let callables = Callables {
            py,
            map: hx,
            kwargs,
            residual: hook(residual_z)?,
            mean: hook(z_mean_fn)?,
            mean_weights: Wm,
            name: "hx",
            raised: RefCell::new(None),
        };
        let report = self
            .filter
            .update(&PyMeasurement(&callables), &z)
            .map_err(|e| callables.error(e))?;
        let f = &self.filter;
        let out = PyDict::new(py);
        out.set_item("x", vector_to_py(py, f.state(), false))?;
        out.set_item("P", matrix_to_py(py, f.covariance()))?;
        out.set_item("K", matrix_to_py(py, f.gain()))?;
        out.set_item("y", vector_to_py(py, f.innovation(), false))?;
        out.set_item("S", matrix_to_py(py, f.innovation_covariance()))?;
        out.set_item("SI", matrix_to_py(py, f.innovation_covariance_inverse()))?;
        out.set_item("zp", vector_to_py(py, f.predicted_measurement(), false))?;
        out.set_item(
            "sigmas_h",
            matrix_to_py(py, &f.measurement_sigma_points().transpose()),
        )?;
        out.set_item("log_likelihood", report.log_likelihood)?;
        Ok(out)
    }

    /// Saerkkae's URTS over filtered (Xs, Ps) (filterpy's `rts_smoother`): returns
    /// (xs, Ps, Ks).
    #[pyo3(signature = (Xs, Ps, Q, Qs, dts, fx, residual_x, x_mean_fn, Wm))]
    #[allow(clippy::too_many_arguments)] // filterpy's arguments and attributes
    fn rts_smoother<'py>(
        &mut self,
        py: Python<'py>,
        Xs: &Bound<'py, PyAny>,
        Ps: &Bound<'py, PyAny>,
        Q: &Bound<'py, PyAny>,
        Qs: Option<&Bound<'py, PyAny>>,
        dts: Vec<f64>,
        fx: Bound<'py, PyAny>,
        residual_x: Option<Bound<'py, PyAny>>,
        x_mean_fn: Option<Bound<'py, PyAny>>,
        Wm: Bound<'py, PyAny>,
    ) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>, Bound<'py, PyAny>)> {
        let n = self.n;
        let xs = f64_array(Xs, "Xs")?;
        let steps = xs.shape().first().copied().unwrap_or(0);
        if xs.len() != steps * n {
            return Err(EstimError::new_err(format!(
                "Xs: expected shape (T, {n}) or (T, {n}, 1), got {:?}",
                xs.shape()
            )));
        }
        let ps = f64_array(Ps, "Ps")?;
        if ps.shape() != [steps, n, n] {
            return Err(EstimError::new_err(format!(
                "Ps: expected shape ({steps}, {n}, {n}), got {:?}",
                ps.shape()
            )));
        }
        // Step-major, each state then each covariance (symmetric: either order).
        let mut states: Vec<f64> = xs.readonly().as_array().iter().copied().collect();
        let mut covariances: Vec<f64> = ps.readonly().as_array().iter().copied().collect();
        let noises = match Qs {
            Some(qs) => {
                let qs = f64_array(qs, "Qs")?;
                if qs.shape() != [steps, n, n] {
                    return Err(EstimError::new_err(format!(
                        "Qs: expected shape ({steps}, {n}, {n}), got {:?}",
                        qs.shape()
                    )));
                }
                // Column-major per matrix, as the smoother reads them.
                let ro = qs.readonly();
                let v = ro.as_array();
                let mut out = vec![0.0; steps * n * n];
                for k in 0..steps {
                    for j in 0..n {
                        for i in 0..n {
                            out[k * n * n + i + j * n] = v[[k, i, j]];
                        }
                    }
                }
                Some(out)
            }
            None => None,
        };
        let q = covariance(Q, "Q", n)?;
        if &q != self.filter.process_noise() {
            self.filter.set_process_noise(&q).map_err(estim_err)?;
        }
        // The covariances are read column-major: transpose each (row-major from NumPy).
        transpose_each(&mut covariances, steps, n);
        let callables = Callables {
            py,
            map: fx,
            kwargs: None,
            residual: hook(residual_x)?,
            mean: hook(x_mean_fn)?,
            mean_weights: Wm,
            name: "fx",
            raised: RefCell::new(None),
        };
        let mut gains = self
            .filter
            .rts_smooth(
                &PyProcess(&callables),
                &mut states,
                &mut covariances,
                &dts,
                noises.as_deref(),
            )
            .map_err(|e| callables.error(e))?;
        transpose_each(&mut covariances, steps, n);
        transpose_each(&mut gains, steps, n);
        Ok((
            states_to_py(py, states, n)?.into_any(),
            covariances_to_py(py, covariances, n)?.into_any(),
            covariances_to_py(py, gains, n)?.into_any(),
        ))
    }
}

/// Transpose each n x n matrix of a step-major buffer in place.
fn transpose_each(data: &mut [f64], steps: usize, n: usize) {
    for k in 0..steps {
        let block = &mut data[k * n * n..(k + 1) * n * n];
        for i in 0..n {
            for j in i + 1..n {
                block.swap(i * n + j, j * n + i);
            }
        }
    }
}
