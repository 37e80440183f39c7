//! The Rust half of `estim.filterpy.KalmanFilter`: filterpy's attributes as Python
//! objects the user may replace or edit in place at any time, and its per-step
//! methods run by `DynKalmanFilter`. Before each step the attributes are read and
//! compared with what the filter holds; only what changed is handed to the filter
//! (and checked there), so a steady filter costs two array reads per matrix and no
//! validation per step.

// filterpy's attribute names (x, P, F, Q, H, R, M, B) are its API: kept as they are.
#![allow(non_snake_case)]

use estim_core::dynamic::DynKalmanFilter;
use estim_core::nalgebra::{DMatrix, DVector};
use numpy::ndarray::{Array2, Array3, ArrayViewD};
use numpy::{IntoPyArray, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyTuple;

use crate::convert::{f64_array, matrix_to_py, series, vector_to_py};
use crate::{estim_err, EstimError};

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<FilterpyKalmanFilter>()
}

/// Run `read` on a view of `obj` as a float64 array, without rust-numpy's dynamic
/// borrow tracking (a few hundred nanoseconds per borrow, a tenth of a 6-state step).
fn with_view<R>(
    obj: &Bound<'_, PyAny>,
    name: &str,
    read: impl FnOnce(ArrayViewD<'_, f64>) -> PyResult<R>,
) -> PyResult<R> {
    let a = f64_array(obj, name)?;
    // SAFETY: the view lives only inside `read`, which copies or compares values and
    // runs no Python code; the GIL is held throughout, so nothing can resize or write
    // the array while it is read (the guarantee rust-numpy's readonly borrow adds is
    // against other Rust borrows of this process, and this crate takes no mutable one).
    let view = unsafe { a.as_array() };
    read(view)
}

/// The rows x cols matrix filterpy's attribute stands for: a rows x cols array; a
/// scalar s is s I for a square matrix (filterpy broadcasts it over every entry; for
/// 1 x 1 the same); a 1-D array of rows x cols entries when one of them is 1. Returns
/// None when it equals `current` entry for entry (nothing to hand over, nothing
/// allocated).
fn changed_matrix(
    obj: &Bound<'_, PyAny>,
    name: &str,
    rows: usize,
    cols: usize,
    current: Option<&DMatrix<f64>>,
) -> PyResult<Option<DMatrix<f64>>> {
    // The common case first: a C-contiguous array of the right shape, read as a
    // row-major slice (an ndarray view with dynamic dimensions costs more than the
    // whole comparison of a 6 x 6 matrix).
    let a = f64_array(obj, name)?;
    let shape = a.shape();
    let exact = shape == [rows, cols]
        || (shape.len() == 1 && (rows == 1 || cols == 1) && shape[0] == rows * cols);
    if exact && a.is_c_contiguous() {
        // SAFETY: as in `with_view`: read under the GIL, no Python code runs meanwhile.
        if let Ok(data) = unsafe { a.as_slice() } {
            if let Some(current) = current {
                if (0..rows).all(|i| (0..cols).all(|j| data[i * cols + j] == current[(i, j)])) {
                    return Ok(None);
                }
            }
            return Ok(Some(DMatrix::from_row_slice(rows, cols, data)));
        }
    }
    with_view(obj, name, |v| {
        let shape = v.shape();
        let entry: Box<dyn Fn(usize, usize) -> f64 + '_> = match shape.len() {
            0 if rows == cols => {
                let s = v[[]];
                Box::new(move |i, j| if i == j { s } else { 0.0 })
            }
            1 if (rows == 1 || cols == 1) && shape[0] == rows * cols => {
                Box::new(move |i, j| v[[i.max(j)]])
            }
            2 if shape[0] == rows && shape[1] == cols => Box::new(move |i, j| v[[i, j]]),
            _ => {
                return Err(EstimError::new_err(format!(
                    "{name}: expected shape ({rows}, {cols}), got {shape:?}"
                )))
            }
        };
        if let Some(current) = current {
            if (0..cols).all(|j| (0..rows).all(|i| entry(i, j) == current[(i, j)])) {
                return Ok(None);
            }
        }
        Ok(Some(DMatrix::from_fn(rows, cols, entry)))
    })
}

/// [`changed_matrix`] without a current value: always the matrix.
fn model_matrix(
    obj: &Bound<'_, PyAny>,
    name: &str,
    rows: usize,
    cols: usize,
) -> PyResult<DMatrix<f64>> {
    changed_matrix(obj, name, rows, cols, None)?
        .ok_or_else(|| EstimError::new_err(format!("{name}: unreadable")))
}

/// The state: (n, 1) or (n,) (a scalar when n = 1); whether it is a column, and the
/// vector when it differs from `current`.
fn changed_state(
    obj: &Bound<'_, PyAny>,
    n: usize,
    current: &DVector<f64>,
) -> PyResult<(Option<DVector<f64>>, bool)> {
    let a = f64_array(obj, "x")?;
    let shape = a.shape();
    let column = shape == [n, 1];
    if (column || shape == [n]) && a.is_c_contiguous() {
        // SAFETY: as in `with_view`.
        if let Ok(data) = unsafe { a.as_slice() } {
            if data == current.as_slice() {
                return Ok((None, column));
            }
            return Ok((Some(DVector::from_column_slice(data)), column));
        }
    }
    with_view(obj, "x", |v| {
        let shape = v.shape();
        let column = match shape {
            [] if n == 1 => false,
            [k] if *k == n => false,
            [k, 1] if *k == n => true,
            _ => {
                return Err(EstimError::new_err(format!(
                    "x: expected shape ({n}, 1) or ({n},), got {shape:?}"
                )))
            }
        };
        if v.iter().zip(current.iter()).all(|(a, b)| a == b) {
            return Ok((None, column));
        }
        Ok((Some(DVector::from_iterator(n, v.iter().copied())), column))
    })
}

/// filterpy's `reshape_z`: z as m values from a scalar (m = 1), (m,), (m, 1) or (1, m).
fn measurement(obj: &Bound<'_, PyAny>, m: usize) -> PyResult<DVector<f64>> {
    if m == 1 {
        if let Ok(value) = obj.extract::<f64>() {
            return Ok(DVector::from_element(1, value));
        }
    }
    with_view(obj, "z", |v| {
        let shape = v.shape();
        let ok = match shape {
            [] => m == 1,
            [k] => *k == m,
            [r, c] => (*r == m && *c == 1) || (*r == 1 && *c == m),
            _ => false,
        };
        if !ok {
            return Err(EstimError::new_err(format!(
                "z (shape {shape:?}) must be convertible to shape ({m}, 1)"
            )));
        }
        Ok(DVector::from_iterator(m, v.iter().copied()))
    })
}

/// The Rust base of `estim.filterpy.KalmanFilter` (see its docstring).
#[pyclass(
    subclass,
    dict,
    module = "estim.filterpy",
    name = "FilterpyKalmanFilter"
)]
pub(crate) struct FilterpyKalmanFilter {
    /// Number of states.
    #[pyo3(get)]
    dim_x: usize,
    /// Number of measurements.
    #[pyo3(get)]
    dim_z: usize,
    /// Number of control inputs.
    #[pyo3(get)]
    dim_u: usize,
    /// State estimate, (dim_x, 1) (or (dim_x,) if you assign a 1-D array).
    #[pyo3(get, set)]
    x: Py<PyAny>,
    /// State covariance.
    #[pyo3(get, set)]
    P: Py<PyAny>,
    /// State transition matrix.
    #[pyo3(get, set)]
    F: Py<PyAny>,
    /// Process noise covariance.
    #[pyo3(get, set)]
    Q: Py<PyAny>,
    /// Measurement matrix.
    #[pyo3(get, set)]
    H: Py<PyAny>,
    /// Measurement noise covariance.
    #[pyo3(get, set)]
    R: Py<PyAny>,
    /// Process-measurement cross-covariance (update_correlated).
    #[pyo3(get, set)]
    M: Py<PyAny>,
    /// Control transition matrix, or None.
    #[pyo3(get, set)]
    B: Py<PyAny>,
    /// The last measurement (None entries after update(None)).
    #[pyo3(get, set)]
    z: Py<PyAny>,
    inner: DynKalmanFilter,
    alpha_sq: f64,
    column: bool,
    /// y's shape: a column after update(None) whatever x's (filterpy).
    y_column: bool,
    y: DVector<f64>,
    s: DMatrix<f64>,
    si: DMatrix<f64>,
    k: DMatrix<f64>,
    x_prior: DVector<f64>,
    p_prior: DMatrix<f64>,
    x_post: DVector<f64>,
    p_post: DMatrix<f64>,
    log_likelihood: f64,
    nis: f64,
}

impl FilterpyKalmanFilter {
    /// Hand the filter F and Q (or the given overrides) where they changed.
    fn sync_process(
        &mut self,
        py: Python<'_>,
        f: Option<&Bound<'_, PyAny>>,
        q: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        let n = self.dim_x;
        let f = f.unwrap_or(self.F.bind(py));
        if let Some(f) = changed_matrix(f, "F", n, n, Some(self.inner.transition()))? {
            self.inner.set_transition(&f).map_err(estim_err)?;
        }
        let q = q.unwrap_or(self.Q.bind(py));
        if let Some(q) = changed_matrix(q, "Q", n, n, Some(self.inner.process_noise()))? {
            self.inner.set_process_noise(&q).map_err(estim_err)?;
        }
        Ok(())
    }

    /// Hand the filter H and R (or the overrides) where they changed.
    fn sync_measurement(
        &mut self,
        py: Python<'_>,
        r: Option<&Bound<'_, PyAny>>,
        h: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        let (n, m) = (self.dim_x, self.dim_z);
        let h = h.unwrap_or(self.H.bind(py));
        if let Some(h) = changed_matrix(h, "H", m, n, Some(self.inner.observation()))? {
            self.inner.set_observation(&h).map_err(estim_err)?;
        }
        let r = r.unwrap_or(self.R.bind(py));
        if let Some(r) = changed_matrix(r, "R", m, m, Some(self.inner.measurement_noise()))? {
            self.inner.set_measurement_noise(&r).map_err(estim_err)?;
        }
        Ok(())
    }

    /// Hand the filter x and P where they changed (checked: finite, P symmetric
    /// positive semidefinite).
    fn sync_estimate(&mut self, py: Python<'_>) -> PyResult<()> {
        let n = self.dim_x;
        let (x, column) = changed_state(self.x.bind(py), n, self.inner.state())?;
        self.column = column;
        let p = changed_matrix(self.P.bind(py), "P", n, n, Some(self.inner.covariance()))?;
        if x.is_some() || p.is_some() {
            let x = x.unwrap_or_else(|| self.inner.state().clone());
            let p = p.unwrap_or_else(|| self.inner.covariance().clone());
            self.inner.set_estimate(&x, &p).map_err(estim_err)?;
        }
        Ok(())
    }

    /// Write the filter's estimate back as new arrays (filterpy replaces x and P at
    /// every step: arrays the caller kept are not changed).
    fn publish_estimate(&mut self, py: Python<'_>) {
        self.x = vector_to_py(py, self.inner.state(), self.column).unbind();
        self.P = matrix_to_py(py, self.inner.covariance())
            .into_any()
            .unbind();
    }

    fn predict_inner(
        &mut self,
        py: Python<'_>,
        u: Option<&Bound<'_, PyAny>>,
        b: Option<&Bound<'_, PyAny>>,
        f: Option<&Bound<'_, PyAny>>,
        q: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        self.sync_process(py, f, q)?;
        self.sync_estimate(py)?;
        let b = match b {
            Some(b) => Some(b.clone()),
            None => Some(self.B.bind(py).clone()).filter(|b| !b.is_none()),
        };
        match (b, u.filter(|u| !u.is_none())) {
            (Some(b), Some(u)) => {
                let u = crate::convert::vector(u, "u")?;
                let b = model_matrix(&b, "B", self.dim_x, u.len())?;
                if self.inner.control() != Some(&b) {
                    self.inner.set_control(Some(b)).map_err(estim_err)?;
                }
                self.inner.predict_with_input(&u).map_err(estim_err)?;
            }
            _ => self.inner.predict().map_err(estim_err)?,
        }
        if self.alpha_sq != 1.0 {
            // Fading memory: P = alpha^2 F P F' + Q = alpha^2 (P- - Q) + Q.
            let q = self.inner.process_noise().clone();
            let faded = (self.inner.covariance() - &q) * self.alpha_sq + q;
            let x = self.inner.state().clone();
            self.inner.set_estimate(&x, &faded).map_err(estim_err)?;
        }
        self.x_prior.copy_from(self.inner.state());
        self.p_prior.copy_from(self.inner.covariance());
        self.publish_estimate(py);
        Ok(())
    }

    /// update / update_correlated.
    fn update_inner(
        &mut self,
        py: Python<'_>,
        z: &Bound<'_, PyAny>,
        r: Option<&Bound<'_, PyAny>>,
        h: Option<&Bound<'_, PyAny>>,
        correlated: bool,
    ) -> PyResult<()> {
        if z.is_none() {
            let np = PyModule::import(py, "numpy")?;
            let nones: Vec<Py<PyAny>> = (0..self.dim_z).map(|_| py.None()).collect();
            self.z = np
                .call_method1("array", (vec![nones],))?
                .getattr("T")?
                .unbind();
            self.sync_estimate(py)?;
            self.x_post.copy_from(self.inner.state());
            self.p_post.copy_from(self.inner.covariance());
            self.y.fill(0.0);
            self.y_column = true;
            self.nis = 0.0;
            // filterpy's log-likelihood of a zero residual under the last S.
            self.log_likelihood = log_density_at_zero(&self.s).unwrap_or(f64::MIN_POSITIVE.ln());
            return Ok(());
        }
        self.sync_measurement(py, r, h)?;
        self.sync_estimate(py)?;
        let zv = measurement(z, self.dim_z)?;
        let cross = if correlated {
            Some(model_matrix(self.M.bind(py), "M", self.dim_x, self.dim_z)?)
        } else {
            None
        };
        let report = self
            .inner
            .update_slice(zv.as_slice(), cross.as_ref())
            .map_err(estim_err)?;
        self.record_update(report.log_likelihood, report.nis);
        self.z = vector_to_py(py, &zv, self.column).unbind();
        self.publish_estimate(py);
        Ok(())
    }

    fn record_update(&mut self, log_likelihood: f64, nis: f64) {
        self.y_column = self.column;
        self.y.copy_from(self.inner.innovation());
        self.s.copy_from(self.inner.innovation_covariance());
        self.si
            .copy_from(self.inner.innovation_covariance_inverse());
        self.k.copy_from(self.inner.gain());
        self.x_post.copy_from(self.inner.state());
        self.p_post.copy_from(self.inner.covariance());
        self.log_likelihood = log_likelihood;
        self.nis = nis;
    }
}

/// ln N(0; 0, S), or None when S is not positive definite (before any update).
fn log_density_at_zero(s: &DMatrix<f64>) -> Option<f64> {
    let chol = s.clone().cholesky()?;
    let log_det: f64 = chol.l().diagonal().iter().map(|d| 2.0 * d.ln()).sum();
    let m = s.nrows() as f64;
    Some(-0.5 * (m * (2.0 * std::f64::consts::PI).ln() + log_det))
}

#[pymethods]
impl FilterpyKalmanFilter {
    #[new]
    #[pyo3(signature = (dim_x, dim_z, dim_u=0))]
    fn new(py: Python<'_>, dim_x: isize, dim_z: isize, dim_u: isize) -> PyResult<Self> {
        if dim_x < 1 {
            return Err(pyo3::exceptions::PyValueError::new_err(
                "dim_x must be 1 or greater",
            ));
        }
        if dim_z < 1 {
            return Err(pyo3::exceptions::PyValueError::new_err(
                "dim_z must be 1 or greater",
            ));
        }
        if dim_u < 0 {
            return Err(pyo3::exceptions::PyValueError::new_err(
                "dim_u must be 0 or greater",
            ));
        }
        let (n, m) = (dim_x as usize, dim_z as usize);
        let inner = DynKalmanFilter::new(
            DMatrix::identity(n, n),
            DMatrix::identity(n, n),
            DMatrix::zeros(m, n),
            DMatrix::identity(m, m),
            DVector::zeros(n),
            DMatrix::identity(n, n),
        )
        .map_err(estim_err)?;
        let np = PyModule::import(py, "numpy")?;
        let nones: Vec<Py<PyAny>> = (0..m).map(|_| py.None()).collect();
        let z = np
            .call_method1("array", (vec![nones],))?
            .getattr("T")?
            .unbind();
        let mat = |a: DMatrix<f64>| matrix_to_py(py, &a).into_any().unbind();
        Ok(Self {
            dim_x: n,
            dim_z: m,
            dim_u: dim_u as usize,
            x: vector_to_py(py, &DVector::zeros(n), true).unbind(),
            P: mat(DMatrix::identity(n, n)),
            F: mat(DMatrix::identity(n, n)),
            Q: mat(DMatrix::identity(n, n)),
            H: mat(DMatrix::zeros(m, n)),
            R: mat(DMatrix::identity(m, m)),
            M: mat(DMatrix::zeros(n, m)),
            B: py.None(),
            z,
            inner,
            alpha_sq: 1.0,
            column: true,
            y_column: true,
            y: DVector::zeros(m),
            s: DMatrix::zeros(m, m),
            si: DMatrix::zeros(m, m),
            k: DMatrix::zeros(n, m),
            x_prior: DVector::zeros(n),
            p_prior: DMatrix::identity(n, n),
            x_post: DVector::zeros(n),
            p_post: DMatrix::identity(n, n),
            log_likelihood: f64::MIN_POSITIVE.ln(),
            nis: 0.0,
        })
    }

    /// Predict the next state (prior): x = F x + B u, P = alpha^2 F P F' + Q.
    #[pyo3(signature = (u=None, B=None, F=None, Q=None))]
    #[allow(non_snake_case)]
    fn predict(
        &mut self,
        py: Python<'_>,
        u: Option<&Bound<'_, PyAny>>,
        B: Option<&Bound<'_, PyAny>>,
        F: Option<&Bound<'_, PyAny>>,
        Q: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        self.predict_inner(py, u, B, F, Q)
    }

    /// Add a measurement z (None: no update; x_post and P_post take the prior).
    #[pyo3(signature = (z, R=None, H=None))]
    #[allow(non_snake_case)]
    fn update(
        &mut self,
        py: Python<'_>,
        z: &Bound<'_, PyAny>,
        R: Option<&Bound<'_, PyAny>>,
        H: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        self.update_inner(py, z, R, H, false)
    }

    /// Add a measurement z whose noise is correlated with the process noise by self.M
    /// (after the joint-covariance check: an M that is not a covariance raises).
    #[pyo3(signature = (z, R=None, H=None))]
    #[allow(non_snake_case)]
    fn update_correlated(
        &mut self,
        py: Python<'_>,
        z: &Bound<'_, PyAny>,
        R: Option<&Bound<'_, PyAny>>,
        H: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        self.update_inner(py, z, R, H, true)
    }

    /// The fast path of batch_filter: zs (T, dim_z) float with NaN rows for None.
    fn _batch_filter<'py>(
        &mut self,
        py: Python<'py>,
        zs: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyTuple>> {
        self.sync_process(py, None, None)?;
        self.sync_measurement(py, None, None)?;
        self.sync_estimate(py)?;
        let (n, m) = (self.dim_x, self.dim_z);
        let (values, steps) = series(zs, "zs", m)?;
        let (mut means, mut covs) = (vec![0.0; steps * n], vec![0.0; steps * n * n]);
        let (mut means_p, mut covs_p) = (vec![0.0; steps * n], vec![0.0; steps * n * n]);
        let inner = &mut self.inner;
        let last = py.detach(|| -> estim_core::Result<Option<(f64, f64)>> {
            let mut last = None;
            for k in 0..steps {
                inner.predict()?;
                means_p[k * n..(k + 1) * n].copy_from_slice(inner.state().as_slice());
                covs_p[k * n * n..(k + 1) * n * n].copy_from_slice(inner.covariance().as_slice());
                let row = &values[k * m..(k + 1) * m];
                if !row.iter().all(|v| v.is_nan()) {
                    let r = inner.update_slice(row, None)?;
                    last = Some((r.log_likelihood, r.nis));
                }
                means[k * n..(k + 1) * n].copy_from_slice(inner.state().as_slice());
                covs[k * n * n..(k + 1) * n * n].copy_from_slice(inner.covariance().as_slice());
            }
            Ok(last)
        });
        if let Some((ll, nis)) = last.map_err(estim_err)? {
            self.record_update(ll, nis);
        }
        if steps > 0 {
            self.x_prior.copy_from_slice(&means_p[(steps - 1) * n..]);
            self.p_prior.copy_from_slice(&covs_p[(steps - 1) * n * n..]);
        }
        self.publish_estimate(py);
        // P is symmetric: row-major and column-major buffers agree.
        let shape_means = |v: Vec<f64>| -> PyResult<Bound<'py, PyAny>> {
            let a = numpy::ndarray::ArrayD::from_shape_vec(
                if self.column {
                    vec![steps, n, 1]
                } else {
                    vec![steps, n]
                },
                v,
            )
            .map_err(|e| EstimError::new_err(format!("internal shape error: {e}")))?;
            Ok(a.into_pyarray(py).into_any())
        };
        let shape_covs = |v: Vec<f64>| -> PyResult<Bound<'py, PyAny>> {
            let a = Array3::from_shape_vec((steps, n, n), v)
                .map_err(|e| EstimError::new_err(format!("internal shape error: {e}")))?;
            Ok(a.into_pyarray(py).into_any())
        };
        PyTuple::new(
            py,
            [
                shape_means(means)?,
                shape_covs(covs)?,
                shape_means(means_p)?,
                shape_covs(covs_p)?,
            ],
        )
    }

    /// The fast path of rts_smoother with self.F and self.Q: Xs (T, n[, 1]), Ps (T, n, n)
    /// -> (x, P, K, Pp) as filterpy's.
    #[allow(non_snake_case)]
    fn _rts_smoother<'py>(
        &mut self,
        py: Python<'py>,
        Xs: &Bound<'py, PyAny>,
        Ps: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyTuple>> {
        let n = self.dim_x;
        let f = model_matrix(self.F.bind(py), "F", n, n)?;
        let q = model_matrix(self.Q.bind(py), "Q", n, n)?;
        let xs = f64_array(Xs, "Xs")?;
        let ps = f64_array(Ps, "Ps")?;
        let x_shape = xs.shape().to_vec();
        let (xr, pr) = (xs.readonly(), ps.readonly());
        let (xv, pv) = (xr.as_array(), pr.as_array());
        let steps = x_shape.first().copied().unwrap_or(0);
        let x_ok = matches!(x_shape.as_slice(), [_, k] if *k == n)
            || matches!(x_shape.as_slice(), [_, k, 1] if *k == n);
        if !x_ok || pv.shape() != [steps, n, n] {
            return Err(EstimError::new_err(format!(
                "Xs, Ps: expected shapes (T, {n}[, 1]) and (T, {n}, {n}), got {:?} and {:?}",
                x_shape,
                pv.shape()
            )));
        }
        let mut x: Vec<DVector<f64>> = (0..steps)
            .map(|k| {
                DVector::from_iterator(n, xv.index_axis(numpy::ndarray::Axis(0), k).iter().copied())
            })
            .collect();
        let mut p: Vec<DMatrix<f64>> = (0..steps)
            .map(|k| DMatrix::from_fn(n, n, |i, j| pv[[k, i, j]]))
            .collect();
        let mut gains = vec![DMatrix::<f64>::zeros(n, n); steps];
        let mut predicted = p.clone();
        let outcome = py.detach(|| -> Result<(), String> {
            let ft = f.transpose();
            for k in (0..steps.saturating_sub(1)).rev() {
                let pp = &f * &p[k] * &ft + &q;
                // K = P_k F' Pp^-1: Pp K' = F P_k (P_k symmetric).
                let rhs = &f * &p[k];
                let kt = match pp.clone().cholesky() {
                    Some(c) => c.solve(&rhs),
                    None => pp
                        .clone()
                        .lu()
                        .solve(&rhs)
                        .ok_or_else(|| format!("predicted covariance singular at step {k}"))?,
                };
                let gain = kt.transpose();
                let dx = &x[k + 1] - &f * &x[k];
                x[k] += &gain * dx;
                let dp = &p[k + 1] - &pp;
                p[k] += &gain * dp * &kt;
                gains[k] = gain;
                predicted[k] = pp;
            }
            Ok(())
        });
        outcome.map_err(EstimError::new_err)?;
        let flat = |ms: &[DMatrix<f64>]| -> PyResult<Bound<'py, PyAny>> {
            let a = Array3::from_shape_fn((ms.len(), n, n), |(k, i, j)| ms[k][(i, j)]);
            Ok(a.into_pyarray(py).into_any())
        };
        let states = Array2::from_shape_fn((steps, n), |(k, i)| x[k][i]).into_pyarray(py);
        let states = states.reshape(x_shape)?.into_any();
        PyTuple::new(py, [states, flat(&p)?, flat(&gains)?, flat(&predicted)?])
    }

    /// Residual y = z - H x of the last update.
    #[getter]
    fn y<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        vector_to_py(py, &self.y, self.y_column)
    }

    /// System uncertainty S of the last update.
    #[getter(S)]
    fn s<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        matrix_to_py(py, &self.s).into_any()
    }

    /// Inverse of S of the last update.
    #[getter(SI)]
    fn si<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        matrix_to_py(py, &self.si).into_any()
    }

    /// Kalman gain of the last update.
    #[getter(K)]
    fn k<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        matrix_to_py(py, &self.k).into_any()
    }

    /// Copy of x after the last predict.
    #[getter]
    fn x_prior<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        vector_to_py(py, &self.x_prior, self.column)
    }

    /// Copy of P after the last predict.
    #[getter]
    fn P_prior<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        matrix_to_py(py, &self.p_prior).into_any()
    }

    /// Copy of x after the last update.
    #[getter]
    fn x_post<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        vector_to_py(py, &self.x_post, self.column)
    }

    /// Copy of P after the last update.
    #[getter]
    fn P_post<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        matrix_to_py(py, &self.p_post).into_any()
    }

    /// Log-likelihood of the last measurement, ln N(y; 0, S).
    #[getter]
    fn log_likelihood(&self) -> f64 {
        self.log_likelihood
    }

    /// exp(log_likelihood), at least the smallest positive float.
    #[getter]
    fn likelihood(&self) -> f64 {
        self.log_likelihood.exp().max(f64::MIN_POSITIVE)
    }

    /// Mahalanobis distance of the last measurement, sqrt(y' S^-1 y).
    #[getter]
    fn mahalanobis(&self) -> f64 {
        self.nis.sqrt()
    }

    /// Fading memory setting (1: the ordinary Kalman filter).
    #[getter]
    fn alpha(&self) -> f64 {
        self.alpha_sq.sqrt()
    }

    #[setter]
    fn set_alpha(&mut self, value: f64) -> PyResult<()> {
        if value.is_nan() || value < 1.0 {
            return Err(pyo3::exceptions::PyValueError::new_err(
                "alpha must be a float greater than 1",
            ));
        }
        self.alpha_sq = value * value;
        Ok(())
    }
}
