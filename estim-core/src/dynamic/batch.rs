//! A whole series in one call: [`DynKalmanFilter::filter_series`] and
//! [`DynKalmanFilter::filter_and_smooth`] (filtered and RTS-smoothed estimates from one
//! forward pass).

use nalgebra::{Cholesky, DMatrix, DMatrixView, DVector, DVectorView};

use super::filter::{check_shape, DynKalmanFilter};
use super::linalg::{check_size, lower_inverse_into, mirror_upper};
use super::product::{gemm, gemm_triangular, gemm_upper, Operand, Triangle};
use crate::{Error, Result};

/// A series of measurements, one row of m values per step, in one slice (step-major:
/// a NumPy `(T, m)` array in C order, or the columns of an m x T `DMatrix`). A step
/// is missing when its row is all NaN, or when a mask says so; a row that is only
/// partly NaN is an error (missing values are whole rows).
#[derive(Debug, Clone, Copy)]
pub struct MeasurementSeries<'a> {
    values: &'a [f64],
    size: usize,
    present: Option<&'a [bool]>,
}

impl<'a> MeasurementSeries<'a> {
    /// The series of `values.len() / size` steps of `size` values each.
    ///
    /// # Errors
    /// [`Error::Dimension`] when `size` is 0 or does not divide the length.
    pub fn new(values: &'a [f64], size: usize) -> Result<Self> {
        if size == 0 || !values.len().is_multiple_of(size) {
            return Err(Error::Dimension {
                what: "measurement series (values per step must divide its length)",
                expected: size,
                got: values.len(),
            });
        }
        Ok(Self {
            values,
            size,
            present: None,
        })
    }

    /// Each column of `columns` (m x T) is one step.
    pub fn from_columns(columns: &'a DMatrix<f64>) -> Self {
        Self {
            values: columns.as_slice(),
            size: columns.nrows().max(1),
            present: None,
        }
    }

    /// With a mask: step k is measured iff `present[k]` (its row must then be finite).
    ///
    /// # Errors
    /// [`Error::Dimension`] unless the mask has one entry per step.
    pub fn with_mask(mut self, present: &'a [bool]) -> Result<Self> {
        check_size(
            "measurement mask (one entry per step)",
            self.len(),
            present.len(),
        )?;
        self.present = Some(present);
        Ok(self)
    }

    /// Number of steps.
    pub fn len(&self) -> usize {
        self.values.len() / self.size
    }

    /// True without steps.
    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }

    /// Values per step (m).
    pub fn size(&self) -> usize {
        self.size
    }

    /// Step k's measurement, `None` when missing.
    ///
    /// # Errors
    /// [`Error::NonFinite`] for a row that is partly NaN, holds an infinity, or is
    /// masked present but not finite.
    pub fn get(&self, k: usize) -> Result<Option<&'a [f64]>> {
        let row = &self.values[k * self.size..(k + 1) * self.size];
        if let Some(present) = self.present {
            if !present[k] {
                return Ok(None);
            }
        } else if row.iter().all(|v| v.is_nan()) {
            return Ok(None);
        }
        if row.iter().all(|v| v.is_finite()) {
            Ok(Some(row))
        } else {
            Err(Error::NonFinite {
                what: "measurement series (a row partly NaN or infinite; a missing step is a whole NaN row)",
            })
        }
    }
}

/// Estimates over a series: a state (n) and a covariance (n x n) per step, in two
/// contiguous buffers (step-major, the layout of NumPy `(T, n)` and `(T, n, n)`
/// arrays; covariances are symmetric, so row and column order agree).
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    size: usize,
    states: Vec<f64>,
    covariances: Vec<f64>,
}

impl Trajectory {
    pub(super) fn zeros(size: usize, steps: usize) -> Self {
        Self {
            size,
            states: vec![0.0; size * steps],
            covariances: vec![0.0; size * size * steps],
        }
    }

    pub(super) fn set(&mut self, k: usize, state: &DVector<f64>, covariance: &DMatrix<f64>) {
        let n = self.size;
        self.states[k * n..(k + 1) * n].copy_from_slice(state.as_slice());
        self.covariances[k * n * n..(k + 1) * n * n].copy_from_slice(covariance.as_slice());
    }

    /// Number of steps.
    pub fn len(&self) -> usize {
        self.states.len() / self.size.max(1)
    }

    /// True without steps.
    pub fn is_empty(&self) -> bool {
        self.states.is_empty()
    }

    /// State size n.
    pub fn state_size(&self) -> usize {
        self.size
    }

    /// The state after step k (index k: step k + 1 of the filter's time index).
    pub fn state(&self, k: usize) -> DVectorView<'_, f64> {
        DVectorView::from_slice(&self.states[k * self.size..(k + 1) * self.size], self.size)
    }

    /// The covariance after step k.
    pub fn covariance(&self, k: usize) -> DMatrixView<'_, f64> {
        let nn = self.size * self.size;
        DMatrixView::from_slice(
            &self.covariances[k * nn..(k + 1) * nn],
            self.size,
            self.size,
        )
    }

    /// Every state, step-major (T x n).
    pub fn states(&self) -> &[f64] {
        &self.states
    }

    /// Every covariance, step-major (T x n x n).
    pub fn covariances(&self) -> &[f64] {
        &self.covariances
    }

    /// (states, covariances) as owned buffers.
    pub fn into_parts(self) -> (Vec<f64>, Vec<f64>) {
        (self.states, self.covariances)
    }
}

/// What [`DynKalmanFilter::filter_series`] produced.
#[derive(Debug, Clone, PartialEq)]
pub struct FilteredSeries {
    /// The estimate after each step: the posterior where a measurement was accepted,
    /// else the prediction.
    pub estimates: Trajectory,
    /// Each step's NIS (NaN where the step had no measurement).
    pub nis: Vec<f64>,
    /// Whether each step's update was accepted (false without a measurement or when
    /// the gate rejected it).
    pub accepted: Vec<bool>,
    /// Sum of the accepted updates' log-likelihood terms of the series.
    pub log_likelihood: f64,
}

/// What [`DynKalmanFilter::filter_and_smooth`] produced: both passes of one call.
#[derive(Debug, Clone, PartialEq)]
pub struct FilteredAndSmoothed {
    /// The filter's pass, as [`DynKalmanFilter::filter_series`] returns it.
    pub filtered: FilteredSeries,
    /// The estimate of x_k given every measurement of the series, after each step.
    pub smoothed: Trajectory,
    /// The smoothed estimate of x_0 (the filter's estimate before the series).
    pub smoothed_initial_state: DVector<f64>,
    /// Its covariance.
    pub smoothed_initial_covariance: DMatrix<f64>,
}

/// Per-step quantities of the forward pass the backward pass needs: nu, S^-1, K'.
pub(super) struct UpdateRecord {
    pub(super) m: usize,
    pub(super) n: usize,
    pub(super) innovation: Vec<f64>,
    pub(super) inverse: Vec<f64>,
    pub(super) gain_t: Vec<f64>,
}

impl UpdateRecord {
    /// Room for `steps` updates of m measurements and n states.
    pub(super) fn new(n: usize, m: usize, steps: usize) -> Self {
        Self {
            m,
            n,
            innovation: vec![0.0; steps * m],
            inverse: vec![0.0; steps * m * m],
            gain_t: vec![0.0; steps * m * n],
        }
    }

    /// Keep step k's innovation, S^-1 and K'.
    pub(super) fn set(
        &mut self,
        k: usize,
        innovation: &DVector<f64>,
        inverse: &DMatrix<f64>,
        gain_t: &DMatrix<f64>,
    ) {
        let (m, n) = (self.m, self.n);
        self.innovation[k * m..(k + 1) * m].copy_from_slice(innovation.as_slice());
        self.inverse[k * m * m..(k + 1) * m * m].copy_from_slice(inverse.as_slice());
        self.gain_t[k * m * n..(k + 1) * m * n].copy_from_slice(gain_t.as_slice());
    }
}

/// The buffers of the smoother gain G (allocated once per backward pass).
struct GainBuffers {
    factor: DMatrix<f64>,
    inverse_factor: DMatrix<f64>,
    inverse_factor_t: DMatrix<f64>,
    scratch: DMatrix<f64>,
}

impl GainBuffers {
    fn new(n: usize) -> Self {
        Self {
            factor: DMatrix::zeros(n, n),
            inverse_factor: DMatrix::zeros(n, n),
            inverse_factor_t: DMatrix::zeros(n, n),
            scratch: DMatrix::zeros(n, n),
        }
    }

    /// G' = P_{k+1}^-1 C' = W' (W C') into `gain_t`, with `covariance` = P_{k+1} = L L'
    /// (the filtered covariance after `step` = k + 1), W = L^-1: two blocked products
    /// instead of two triangular solves with n right-hand sides.
    fn gain_t(
        &mut self,
        covariance: DMatrixView<'_, f64>,
        cross_cov: &DMatrix<f64>,
        gain_t: &mut DMatrix<f64>,
        step: usize,
    ) -> Result<()> {
        self.factor.copy_from(&covariance);
        let not_positive_definite = || Error::InvalidCovariance {
            what: "filtered covariance (smoother gain)",
            reason: format!("not positive definite after step {step}"),
        };
        let chol = Cholesky::new(std::mem::replace(&mut self.factor, DMatrix::zeros(0, 0)))
            .ok_or_else(not_positive_definite)?;
        self.factor = chol.unpack_dirty();
        if !lower_inverse_into(&self.factor, &mut self.inverse_factor) {
            return Err(not_positive_definite());
        }
        self.inverse_factor.transpose_to(&mut self.inverse_factor_t);
        cross_cov.transpose_to(gain_t);
        gemm_triangular(
            &mut self.scratch,
            1.0,
            &self.inverse_factor,
            Triangle::Lower,
            &*gain_t,
            0.0,
        );
        gemm_triangular(
            gain_t,
            1.0,
            &self.inverse_factor_t,
            Triangle::Upper,
            &self.scratch,
            0.0,
        );
        Ok(())
    }
}

/// The fixed-interval smoother's backward pass over a recorded forward pass (the
/// formulas of [`DynKalmanFilter::filter_and_smooth`]), with the transition and the
/// observation of each step given transposed: `transition_t(k)` is F' of the predict
/// into series step k (index k), `observation_t(k)` H' of its update. A linear filter
/// gives its constant F' and H'; the unscented filter its statistical linearisations.
pub(super) fn smooth_backward<'a>(
    x0: &DVector<f64>,
    p0: &DMatrix<f64>,
    filtered: FilteredSeries,
    record: &UpdateRecord,
    transition_t: impl Fn(usize) -> Operand<'a>,
    observation_t: impl Fn(usize) -> Operand<'a>,
) -> Result<FilteredAndSmoothed> {
    let (n, m, steps) = (record.n, record.m, filtered.accepted.len());
    // Backward buffers, allocated once.
    let mut correction = DVector::<f64>::zeros(n);
    let mut next_correction = DVector::<f64>::zeros(n);
    let mut smoothed_cov = DMatrix::<f64>::zeros(n, n);
    let mut previous_cov = DMatrix::<f64>::zeros(n, n);
    let mut cross_cov = DMatrix::<f64>::zeros(n, n);
    let mut gain_t = DMatrix::<f64>::zeros(n, n);
    let mut gain = DMatrix::<f64>::zeros(n, n);
    let mut ch_t = DMatrix::<f64>::zeros(m, n);
    let mut gain_buffers = GainBuffers::new(n);
    let mut difference = DMatrix::<f64>::zeros(n, n);
    let mut product = DMatrix::<f64>::zeros(n, n);
    let mut ch = DMatrix::<f64>::zeros(n, m);
    let mut a = DMatrix::<f64>::zeros(n, m);
    let mut shift = DVector::<f64>::zeros(n);
    let mut filtered_k = DMatrix::<f64>::zeros(n, n);
    let mut smoothed = Trajectory::zeros(n, steps);
    if steps > 0 {
        let last = steps - 1;
        smoothed.states[last * n..].copy_from_slice(&filtered.estimates.states[last * n..]);
        smoothed.covariances[last * n * n..]
            .copy_from_slice(&filtered.estimates.covariances[last * n * n..]);
        smoothed_cov.copy_from(&filtered.estimates.covariance(last));
    } else {
        smoothed_cov.copy_from(p0);
    }
    // Epoch k = 0 is x_0, epoch k >= 1 the estimate after step k (index k - 1).
    for k in (0..steps).rev() {
        let (state_k, cov_k): (DVectorView<'_, f64>, DMatrixView<'_, f64>) = if k == 0 {
            (x0.as_view(), p0.as_view())
        } else {
            (
                filtered.estimates.state(k - 1),
                filtered.estimates.covariance(k - 1),
            )
        };
        filtered_k.copy_from(&cov_k);
        // C = P_k F'.
        gemm(&mut cross_cov, 1.0, &filtered_k, transition_t(k), 0.0);
        previous_cov.copy_from(&filtered_k);
        shift.fill(0.0);
        if filtered.accepted[k] {
            let innovation = DVectorView::from_slice(&record.innovation[k * m..(k + 1) * m], m);
            let inverse = Operand::new(&record.inverse[k * m * m..(k + 1) * m * m], m, m);
            let kt = Operand::new(&record.gain_t[k * m * n..(k + 1) * m * n], m, n);
            gemm(&mut ch, 1.0, &cross_cov, observation_t(k), 0.0);
            ch.transpose_to(&mut ch_t);
            gemm(&mut a, 1.0, &ch, inverse, 0.0);
            shift.gemv(1.0, &a, &innovation, 0.0);
            gemm_upper(&mut previous_cov, -1.0, &a, &ch_t, 1.0);
            gemm(&mut cross_cov, -1.0, &ch, kt, 1.0);
        }
        gain_buffers.gain_t(
            filtered.estimates.covariance(k),
            &cross_cov,
            &mut gain_t,
            k + 1,
        )?;
        // e^s_k = shift + G e^s_{k+1}.
        next_correction.copy_from(&shift);
        next_correction.gemv_tr(1.0, &gain_t, &correction, 1.0);
        std::mem::swap(&mut correction, &mut next_correction);
        // P^s_k = P_k|k+1 + G (P^s_{k+1} - P_{k+1}) G'.
        difference.copy_from(&smoothed_cov);
        difference -= &filtered.estimates.covariance(k);
        gain_t.transpose_to(&mut gain);
        gemm(&mut product, 1.0, &gain, &difference, 0.0);
        smoothed_cov.copy_from(&previous_cov);
        // Symmetric: the upper triangle of each term, mirrored.
        gemm_upper(&mut smoothed_cov, 1.0, &product, &gain_t, 1.0);
        mirror_upper(&mut smoothed_cov);
        if !(correction.iter().all(|v| v.is_finite()) && smoothed_cov.iter().all(|v| v.is_finite()))
        {
            return Err(Error::NonFinite {
                what: "smoothed estimate (overflow)",
            });
        }
        shift.copy_from(&state_k);
        shift += &correction;
        if k > 0 {
            smoothed.set(k - 1, &shift, &smoothed_cov);
        } else {
            return Ok(FilteredAndSmoothed {
                filtered,
                smoothed,
                smoothed_initial_state: shift,
                smoothed_initial_covariance: smoothed_cov,
            });
        }
    }
    // No steps: x_0 is its own smoothed estimate.
    Ok(FilteredAndSmoothed {
        filtered,
        smoothed,
        smoothed_initial_state: x0.clone(),
        smoothed_initial_covariance: p0.clone(),
    })
}

impl DynKalmanFilter {
    /// Filter a series (convention of [`crate::KalmanFilter::filter_batch`], filterpy's
    /// `batch_filter`: entry k is a predict then an update when measured), with the
    /// cross-covariance `cross` (n x m) at every update, or none (M = 0). The filter
    /// advances, as [`Self::predict`] and [`Self::update_correlated`] in a loop; its
    /// output buffers are allocated once, before the first step.
    ///
    /// # Errors
    /// [`Error::Dimension`] when the series' size is not m or M's shape is not n x m;
    /// those of the steps (the steps before a failing one stay committed).
    pub fn filter_series(
        &mut self,
        measurements: &MeasurementSeries<'_>,
        cross: Option<&DMatrix<f64>>,
    ) -> Result<FilteredSeries> {
        self.run_series(measurements, cross, None)
    }

    /// Filter and smooth a series in one call: the filter's pass (as
    /// [`Self::filter_series`], on a copy of this filter, which stays untouched) and
    /// the fixed-interval smoother over it, consistent with the correlated update
    /// (the static core's smoother, [`crate::smoother`]: with M = 0 it is Rauch, Tung
    /// & Striebel's, Saerkkae 2013 th. 8.2):
    ///
    /// ```text
    /// C = P_k F'                    (before the update of step k+1)
    /// on an accepted update (nu, S, K):
    ///   A = C H' S^-1,  shift_k = A nu,  P_k|k+1 = P_k - A H C',  C <- C (I - K H)'
    /// G_k = C P_{k+1}^-1,  e^s_k = shift_k + G_k e^s_{k+1},
    /// P^s_k = P_k|k+1 + G_k (P^s_{k+1} - P_{k+1}) G_k'
    /// ```
    ///
    /// (e^s: smoothed minus filtered mean). Memory: two trajectories (T (n + n^2)
    /// values each) and T (m n + m^2 + m) for the updates, allocated before the first
    /// step; the backward pass allocates nothing per step.
    ///
    /// ```
    /// use estim_core::dynamic::{DynKalmanFilter, MeasurementSeries};
    /// use estim_core::nalgebra::{DMatrix, DVector};
    ///
    /// let kf = DynKalmanFilter::new(
    ///     DMatrix::from_row_slice(2, 2, &[1.0, 1.0, 0.0, 1.0]),
    ///     DMatrix::identity(2, 2) * 0.01,
    ///     DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
    ///     DMatrix::from_element(1, 1, 0.1),
    ///     DVector::zeros(2),
    ///     DMatrix::identity(2, 2),
    /// )?;
    /// let ys = [1.0, f64::NAN, 3.1, 3.9]; // NaN: no measurement at step 2
    /// let out = kf.filter_and_smooth(&MeasurementSeries::new(&ys, 1)?, None)?;
    /// assert_eq!(out.smoothed.len(), 4);
    /// // The last smoothed estimate is the filtered one.
    /// assert_eq!(out.smoothed.state(3), out.filtered.estimates.state(3));
    /// # Ok::<(), estim_core::Error>(())
    /// ```
    ///
    /// # Errors
    /// Those of [`Self::filter_series`]; [`Error::SmootherUnsupported`] for a
    /// correlated update after an unmeasured step (M = Cov(accumulated noise, v)
    /// does not say how v shares the steps) or a correlated first update when this
    /// filter had predicted since its last update; [`Error::InvalidCovariance`] when a
    /// filtered covariance is not positive definite (the smoother gain needs its
    /// inverse).
    pub fn filter_and_smooth(
        &self,
        measurements: &MeasurementSeries<'_>,
        cross: Option<&DMatrix<f64>>,
    ) -> Result<FilteredAndSmoothed> {
        let (n, m, steps) = (
            self.state_size(),
            self.measurement_size(),
            measurements.len(),
        );
        let mut forward = self.clone();
        let mut record = UpdateRecord::new(n, m, steps);
        let filtered = forward.run_series(measurements, cross, Some(&mut record))?;
        let f_t = Operand::from(self.transition_transposed());
        let h_t = Operand::from(self.observation_transposed());
        smooth_backward(
            self.state(),
            self.covariance(),
            filtered,
            &record,
            |_| f_t,
            |_| h_t,
        )
    }

    fn run_series(
        &mut self,
        measurements: &MeasurementSeries<'_>,
        cross: Option<&DMatrix<f64>>,
        mut record: Option<&mut UpdateRecord>,
    ) -> Result<FilteredSeries> {
        let (n, m, steps) = (
            self.state_size(),
            self.measurement_size(),
            measurements.len(),
        );
        check_size(
            "measurement series (values per step)",
            m,
            measurements.size(),
        )?;
        if let Some(c) = cross {
            check_shape!("cross-covariance M", c, n, m)?;
        }
        let correlated = cross.is_some_and(|c| c.iter().any(|v| *v != 0.0));
        let mut out = FilteredSeries {
            estimates: Trajectory::zeros(n, steps),
            nis: vec![f64::NAN; steps],
            accepted: vec![false; steps],
            log_likelihood: 0.0,
        };
        for k in 0..steps {
            self.predict()?;
            if let Some(y) = measurements.get(k)? {
                if correlated && record.is_some() && self.predicts_since_update() > 1 {
                    return Err(Error::SmootherUnsupported {
                        epoch: k + 1,
                        reason: "correlated update after an unmeasured step (or a series \
                                 started after predicts without an update)",
                    });
                }
                let report = self.update_slice(y, cross)?;
                out.nis[k] = report.nis;
                out.accepted[k] = report.accepted;
                if report.accepted {
                    out.log_likelihood += report.log_likelihood;
                    if let Some(record) = record.as_deref_mut() {
                        record.set(
                            k,
                            self.innovation(),
                            self.innovation_covariance_inverse(),
                            self.gain_transposed(),
                        );
                    }
                }
            }
            out.estimates.set(k, self.state(), self.covariance());
        }
        Ok(out)
    }
}
