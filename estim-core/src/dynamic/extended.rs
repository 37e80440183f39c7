//! [`DynExtendedKalmanFilter`]: the extended Kalman filter with the correlated update,
//! sizes known at run time, on [`DynKalmanFilter`]'s core.

use nalgebra::{DMatrix, DVector};

use super::batch::{
    smooth_backward, FilteredAndSmoothed, FilteredSeries, Trajectory, UpdateRecord,
};
use super::filter::check_shape;
use super::linalg::{check_finite, check_size};
use super::product::Operand;
use super::{DynKalmanFilter, DynUpdateReport, MeasurementSeries};
use crate::{Error, JointCheck, Result};

/// A process x_k = f(x_{k-1}) + w for [`DynExtendedKalmanFilter::predict`]: f over `dt`
/// and its Jacobian F(x) = df/dx, each written into a buffer the filter owns (n, and
/// n x n), so a predict allocates nothing. The run-time-sized counterpart of
/// [`crate::ProcessModel`] (Q is the filter's). A pair of closures
/// `(Fn(&DVector<f64>, f64, &mut DVector<f64>) -> Result<()>,
/// Fn(&DVector<f64>, f64, &mut DMatrix<f64>) -> Result<()>)` is one.
///
/// ```
/// use estim_core::dynamic::DynProcessModel;
/// use estim_core::nalgebra::{DMatrix, DVector};
/// use estim_core::Result;
///
/// /// A pendulum: angle and rate, x' = [rate, -sin(angle)] (explicit Euler over dt).
/// struct Pendulum;
/// impl DynProcessModel for Pendulum {
///     fn propagate(&self, x: &DVector<f64>, dt: f64, out: &mut DVector<f64>) -> Result<()> {
///         out[0] = x[0] + dt * x[1];
///         out[1] = x[1] - dt * x[0].sin();
///         Ok(())
///     }
///     fn jacobian(&self, x: &DVector<f64>, dt: f64, out: &mut DMatrix<f64>) -> Result<()> {
///         out.copy_from_slice(&[1.0, -dt * x[0].cos(), dt, 1.0]); // column-major
///         Ok(())
///     }
/// }
/// let mut f = DMatrix::zeros(2, 2);
/// Pendulum.jacobian(&DVector::from_vec(vec![0.0, 1.0]), 0.1, &mut f)?;
/// assert_eq!(f[(0, 1)], 0.1);
/// # Ok::<(), estim_core::Error>(())
/// ```
pub trait DynProcessModel {
    /// f(x) over `dt`, written into `out` (n entries, as x).
    ///
    /// # Errors
    /// Any: the filter passes it on and stays unchanged.
    fn propagate(&self, state: &DVector<f64>, dt: f64, out: &mut DVector<f64>) -> Result<()>;

    /// F(x) = df/dx at `state` over `dt`, written into `out` (n x n).
    ///
    /// # Errors
    /// Any: the filter passes it on and stays unchanged.
    fn jacobian(&self, state: &DVector<f64>, dt: f64, out: &mut DMatrix<f64>) -> Result<()>;
}

impl<F, J> DynProcessModel for (F, J)
where
    F: Fn(&DVector<f64>, f64, &mut DVector<f64>) -> Result<()>,
    J: Fn(&DVector<f64>, f64, &mut DMatrix<f64>) -> Result<()>,
{
    fn propagate(&self, state: &DVector<f64>, dt: f64, out: &mut DVector<f64>) -> Result<()> {
        (self.0)(state, dt, out)
    }
    fn jacobian(&self, state: &DVector<f64>, dt: f64, out: &mut DMatrix<f64>) -> Result<()> {
        (self.1)(state, dt, out)
    }
}

/// A measurement y = h(x) + v for [`DynExtendedKalmanFilter::update`]: h and its
/// Jacobian H(x) = dh/dx, written into buffers the filter owns (m, and m x n). The
/// run-time-sized counterpart of [`crate::MeasurementModel`] (R is the filter's). A
/// pair of closures `(Fn(&DVector<f64>, &mut DVector<f64>) -> Result<()>,
/// Fn(&DVector<f64>, &mut DMatrix<f64>) -> Result<()>)` is one.
///
/// ```
/// use estim_core::dynamic::DynMeasurementModel;
/// use estim_core::nalgebra::{DMatrix, DVector};
/// use estim_core::Result;
///
/// /// The range from the origin of a planar position.
/// struct Range;
/// impl DynMeasurementModel for Range {
///     fn predict(&self, x: &DVector<f64>, out: &mut DVector<f64>) -> Result<()> {
///         out[0] = x[0].hypot(x[1]);
///         Ok(())
///     }
///     fn jacobian(&self, x: &DVector<f64>, out: &mut DMatrix<f64>) -> Result<()> {
///         let r = x[0].hypot(x[1]);
///         out[(0, 0)] = x[0] / r;
///         out[(0, 1)] = x[1] / r;
///         Ok(())
///     }
/// }
/// let mut y = DVector::zeros(1);
/// Range.predict(&DVector::from_vec(vec![3.0, 4.0]), &mut y)?;
/// assert_eq!(y[0], 5.0);
/// # Ok::<(), estim_core::Error>(())
/// ```
pub trait DynMeasurementModel {
    /// h(x), written into `out` (m entries, as R's size).
    ///
    /// # Errors
    /// Any: the filter passes it on and stays unchanged.
    fn predict(&self, state: &DVector<f64>, out: &mut DVector<f64>) -> Result<()>;

    /// H(x) = dh/dx at `state`, written into `out` (m x n).
    ///
    /// # Errors
    /// Any: the filter passes it on and stays unchanged.
    fn jacobian(&self, state: &DVector<f64>, out: &mut DMatrix<f64>) -> Result<()>;
}

impl<F, J> DynMeasurementModel for (F, J)
where
    F: Fn(&DVector<f64>, &mut DVector<f64>) -> Result<()>,
    J: Fn(&DVector<f64>, &mut DMatrix<f64>) -> Result<()>,
{
    fn predict(&self, state: &DVector<f64>, out: &mut DVector<f64>) -> Result<()> {
        (self.0)(state, out)
    }
    fn jacobian(&self, state: &DVector<f64>, out: &mut DMatrix<f64>) -> Result<()> {
        (self.1)(state, out)
    }
}

/// Buffers the models write into, allocated at construction.
#[derive(Debug, Clone)]
struct Workspace {
    /// f(x), n.
    propagated: DVector<f64>,
    /// F(x), n x n.
    transition: DMatrix<f64>,
    /// h(x), m.
    predicted: DVector<f64>,
    /// H(x), m x n.
    observation: DMatrix<f64>,
}

/// Extended Kalman filter x_k = f(x_{k-1}) + G w_{k-1}, y_k = h(x_k) + v_k with
/// Cov(G w) = Q, Cov(v) = R and the cross-covariance M = Cov(G w_{k-1}, v_k), whose
/// sizes are known only at run time: f, F(x), h, H(x) from a [`DynProcessModel`] and a
/// [`DynMeasurementModel`] (types or pairs of closures).
///
/// [`DynKalmanFilter`]'s core with the model's linearisation at each step: the same
/// time index, accumulation of Q_acc with F(x) between updates, joint check of
/// [[Q_acc, M], [M', R]] ([`JointCheck::Reject`] by default), NIS gate and
/// Joseph-like posterior valid for any gain; the same equations as the static
/// [`crate::ExtendedKalmanFilter`] (F evaluated at the state before propagation, H at
/// the prior), to 1e-12 on the same problem (`tests/dynamic_extended.rs`):
///
/// ```text
/// predict:  F = F(x)      x <- f(x)       P <- F P F' + Q
/// update:   H = H(x)      S = H P H' + H M + M' H' + R   (Simon 2006, sec. 7.1)
///           K = (P H' + M) S^-1           x <- x + K (y - h(x))
/// ```
///
/// Every buffer is allocated by the constructor: `predict`, `update` and
/// `update_correlated` allocate nothing (`tests/dynamic_alloc.rs`), except the joint
/// check's eigen decomposition when an M is invalid or too close to call. On an error
/// the estimate is unchanged; [`Self::transition`] and [`Self::observation`] hold the
/// last linearisation attempted.
///
/// ```
/// use estim_core::dynamic::DynExtendedKalmanFilter;
/// use estim_core::nalgebra::{DMatrix, DVector};
/// use estim_core::Result;
///
/// // A constant-velocity track seen in range from a station at (0, -10).
/// let f = |x: &DVector<f64>, dt: f64, out: &mut DVector<f64>| -> Result<()> {
///     out.copy_from_slice(&[x[0] + dt * x[1], x[1]]);
///     Ok(())
/// };
/// let jf = |_: &DVector<f64>, dt: f64, out: &mut DMatrix<f64>| -> Result<()> {
///     out.copy_from_slice(&[1.0, 0.0, dt, 1.0]);
///     Ok(())
/// };
/// let h = |x: &DVector<f64>, out: &mut DVector<f64>| -> Result<()> {
///     out[0] = x[0].hypot(10.0);
///     Ok(())
/// };
/// let jh = |x: &DVector<f64>, out: &mut DMatrix<f64>| -> Result<()> {
///     out.copy_from_slice(&[x[0] / x[0].hypot(10.0), 0.0]);
///     Ok(())
/// };
/// let mut ekf = DynExtendedKalmanFilter::new(
///     DMatrix::identity(2, 2) * 0.01,
///     DMatrix::from_element(1, 1, 0.1),
///     DVector::from_vec(vec![5.0, 1.0]),
///     DMatrix::identity(2, 2),
/// )?;
/// ekf.predict(&(f, jf), 1.0)?;
/// assert_eq!(ekf.state()[0], 6.0);
/// let report = ekf.update(&(h, jh), &DVector::from_element(1, 11.7))?;
/// assert!(report.accepted && ekf.state()[0] > 6.0);
/// # Ok::<(), estim_core::Error>(())
/// ```
#[derive(Debug, Clone)]
pub struct DynExtendedKalmanFilter {
    core: DynKalmanFilter,
    ws: Workspace,
}

impl DynExtendedKalmanFilter {
    /// A filter with process noise Q (n x n), measurement noise R (m x m) and the
    /// initial estimate (x0, P0); no gate, [`JointCheck::Reject`].
    ///
    /// # Errors
    /// Those of [`DynKalmanFilter::new`]: [`Error::Dimension`] for an empty x0 or R or
    /// a shape that disagrees with n (from x0) and m (from R); [`Error::NonFinite`];
    /// [`Error::InvalidCovariance`] when Q, R or P0 is not symmetric positive
    /// semidefinite to round-off.
    pub fn new(
        process_noise: DMatrix<f64>,
        measurement_noise: DMatrix<f64>,
        state: DVector<f64>,
        covariance: DMatrix<f64>,
    ) -> Result<Self> {
        let (n, m) = (state.len(), measurement_noise.nrows());
        // F and H until the first linearisation: the identity and zero.
        let core = DynKalmanFilter::new(
            DMatrix::identity(n, n),
            process_noise,
            DMatrix::zeros(m, n),
            measurement_noise,
            state,
            covariance,
        )?;
        Ok(Self {
            core,
            ws: Workspace {
                propagated: DVector::zeros(n),
                transition: DMatrix::zeros(n, n),
                predicted: DVector::zeros(m),
                observation: DMatrix::zeros(m, n),
            },
        })
    }

    /// With this joint-covariance policy ([`JointCheck::Reject`] by default).
    #[must_use]
    pub fn with_joint_check(mut self, joint_check: JointCheck) -> Self {
        self.core = self.core.with_joint_check(joint_check);
        self
    }

    /// With an innovation gate: an update whose NIS exceeds `threshold` is rejected.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] unless the threshold is positive.
    pub fn with_nis_gate(mut self, threshold: f64) -> Result<Self> {
        self.core = self.core.with_nis_gate(threshold)?;
        Ok(self)
    }

    /// n.
    pub fn state_size(&self) -> usize {
        self.core.state_size()
    }

    /// m.
    pub fn measurement_size(&self) -> usize {
        self.core.measurement_size()
    }

    /// x.
    pub fn state(&self) -> &DVector<f64> {
        self.core.state()
    }

    /// P.
    pub fn covariance(&self) -> &DMatrix<f64> {
        self.core.covariance()
    }

    /// Q.
    pub fn process_noise(&self) -> &DMatrix<f64> {
        self.core.process_noise()
    }

    /// R.
    pub fn measurement_noise(&self) -> &DMatrix<f64> {
        self.core.measurement_noise()
    }

    /// F(x) of the last predict (the identity before the first).
    pub fn transition(&self) -> &DMatrix<f64> {
        self.core.transition()
    }

    /// H(x) of the last update attempt (zero before the first).
    pub fn observation(&self) -> &DMatrix<f64> {
        self.core.observation()
    }

    /// h(x) of the last update attempt.
    pub fn predicted_measurement(&self) -> &DVector<f64> {
        &self.ws.predicted
    }

    /// The sum of the accepted updates' log-likelihood terms.
    pub fn log_likelihood(&self) -> f64 {
        self.core.log_likelihood()
    }

    /// Q_acc since the last update attempt.
    pub fn accumulated_process_noise(&self) -> &DMatrix<f64> {
        self.core.accumulated_process_noise()
    }

    /// The innovation y - h(x) of the last update attempt.
    pub fn innovation(&self) -> &DVector<f64> {
        self.core.innovation()
    }

    /// S of the last update attempt.
    pub fn innovation_covariance(&self) -> &DMatrix<f64> {
        self.core.innovation_covariance()
    }

    /// K of the last accepted update.
    pub fn gain(&self) -> &DMatrix<f64> {
        self.core.gain()
    }

    /// Replace the estimate (x, P), checked as in [`Self::new`].
    ///
    /// # Errors
    /// As [`DynKalmanFilter::set_estimate`].
    pub fn set_estimate(&mut self, state: &DVector<f64>, covariance: &DMatrix<f64>) -> Result<()> {
        self.core.set_estimate(state, covariance)
    }

    /// Replace Q for the following predicts.
    ///
    /// # Errors
    /// As [`DynKalmanFilter::set_process_noise`].
    pub fn set_process_noise(&mut self, process_noise: &DMatrix<f64>) -> Result<()> {
        self.core.set_process_noise(process_noise)
    }

    /// Replace R for the following updates.
    ///
    /// # Errors
    /// As [`DynKalmanFilter::set_measurement_noise`].
    pub fn set_measurement_noise(&mut self, measurement_noise: &DMatrix<f64>) -> Result<()> {
        self.core.set_measurement_noise(measurement_noise)
    }

    /// Prior over `dt`: F = F(x), x <- f(x), P <- F P F' + Q.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] for dt not finite and positive; the model's errors;
    /// [`Error::Dimension`] if the model resized its output; [`Error::NonFinite`] for a
    /// non-finite f(x) or F(x) or an overflow. The estimate is then unchanged.
    pub fn predict<P: DynProcessModel + ?Sized>(&mut self, process: &P, dt: f64) -> Result<()> {
        if !(dt.is_finite() && dt > 0.0) {
            return Err(Error::InvalidParameter {
                name: "dt",
                reason: format!("{dt} is not a positive finite time step"),
            });
        }
        let n = self.state_size();
        let ws = &mut self.ws;
        process.jacobian(self.core.state(), dt, &mut ws.transition)?;
        check_shape!("process Jacobian F(x)", &ws.transition, n, n)?;
        check_finite(ws.transition.as_slice(), "process Jacobian F(x)")?;
        process.propagate(self.core.state(), dt, &mut ws.propagated)?;
        check_size("propagated state f(x)", n, ws.propagated.len())?;
        check_finite(ws.propagated.as_slice(), "propagated state f(x)")?;
        self.core.set_transition(&ws.transition)?;
        self.core.predict_propagated(&ws.propagated)
    }

    /// Update with y through `model`, M = 0: the textbook EKF update.
    ///
    /// # Errors
    /// As [`Self::update_correlated`].
    pub fn update<H: DynMeasurementModel + ?Sized>(
        &mut self,
        model: &H,
        measurement: &DVector<f64>,
    ) -> Result<DynUpdateReport> {
        self.update_slice(model, measurement.as_slice(), None)
    }

    /// Update with y through `model` and the cross-covariance M = Cov(G w, v) (n x m),
    /// checked by the joint policy ([`JointCheck::Reject`] by default).
    ///
    /// # Errors
    /// The model's errors; [`Error::Dimension`] for a y or M of the wrong shape or a
    /// model that resized its output; [`Error::NonFinite`] (h(x), H(x), y, M);
    /// [`Error::InvalidJointCovariance`]; [`Error::InnovationNotPositiveDefinite`];
    /// [`Error::InnovationIllConditioned`]. The estimate is then unchanged.
    pub fn update_correlated<H: DynMeasurementModel + ?Sized>(
        &mut self,
        model: &H,
        measurement: &DVector<f64>,
        cross_covariance: &DMatrix<f64>,
    ) -> Result<DynUpdateReport> {
        self.update_slice(model, measurement.as_slice(), Some(cross_covariance))
    }

    /// [`Self::update_correlated`] from a slice, M optional.
    ///
    /// # Errors
    /// As [`Self::update_correlated`].
    pub fn update_slice<H: DynMeasurementModel + ?Sized>(
        &mut self,
        model: &H,
        measurement: &[f64],
        cross_covariance: Option<&DMatrix<f64>>,
    ) -> Result<DynUpdateReport> {
        let (n, m) = (self.state_size(), self.measurement_size());
        let ws = &mut self.ws;
        model.predict(self.core.state(), &mut ws.predicted)?;
        check_size("predicted measurement h(x)", m, ws.predicted.len())?;
        check_finite(ws.predicted.as_slice(), "predicted measurement h(x)")?;
        model.jacobian(self.core.state(), &mut ws.observation)?;
        check_shape!("measurement Jacobian H(x)", &ws.observation, m, n)?;
        check_finite(ws.observation.as_slice(), "measurement Jacobian H(x)")?;
        self.core.set_observation(&ws.observation)?;
        self.core
            .update_predicted(measurement, &ws.predicted, cross_covariance)
    }

    /// Filter a series: entry k is a predict over `dts[k]` (or `dts[0]` for every step
    /// when `dts` has one entry) through `process`, then an update through `model` when
    /// measured (NaN rows or a mask: [`MeasurementSeries`]), with the cross-covariance
    /// `cross` at every update, or none. The filter advances, as predict and update in
    /// a loop (the static [`crate::ExtendedKalmanFilter::filter_batch`]).
    ///
    /// # Errors
    /// [`Error::Dimension`] when the series' size is not m, `dts` has neither 1 nor T
    /// entries, or M's shape is not n x m; those of the steps (the steps before a
    /// failing one stay committed).
    pub fn filter_series<P, H>(
        &mut self,
        process: &P,
        model: &H,
        dts: &[f64],
        measurements: &MeasurementSeries<'_>,
        cross: Option<&DMatrix<f64>>,
    ) -> Result<FilteredSeries>
    where
        P: DynProcessModel + ?Sized,
        H: DynMeasurementModel + ?Sized,
    {
        self.run_series(process, model, dts, measurements, cross, None)
    }

    /// Filter and smooth a series in one call (arguments as [`Self::filter_series`]):
    /// the filter's pass on a copy of this filter (which stays untouched) and the
    /// fixed-interval smoother over it, the correlated update's consistent backward
    /// pass of [`DynKalmanFilter::filter_and_smooth`] over each step's F(x) and H(x).
    /// With M = 0 it is the extended RTS smoother (Saerkkae 2013, ch. 9:
    /// G_k = P_k F_k' (P-_{k+1})^-1, x^s_k = x_k + G_k (x^s_{k+1} - f(x_k))), and it
    /// equals the static [`crate::ExtendedKalmanFilter::smooth_batch`] with and without
    /// M. Memory as [`DynKalmanFilter::filter_and_smooth`], plus each step's F' and
    /// H' (T (n^2 + n m) values), allocated before the first step.
    ///
    /// # Errors
    /// Those of [`Self::filter_series`]; [`Error::SmootherUnsupported`] for a
    /// correlated update after an unmeasured step; [`Error::InvalidCovariance`] when a
    /// filtered covariance is not positive definite (the smoother gain needs its
    /// inverse).
    pub fn filter_and_smooth<P, H>(
        &self,
        process: &P,
        model: &H,
        dts: &[f64],
        measurements: &MeasurementSeries<'_>,
        cross: Option<&DMatrix<f64>>,
    ) -> Result<FilteredAndSmoothed>
    where
        P: DynProcessModel + ?Sized,
        H: DynMeasurementModel + ?Sized,
    {
        let (n, m, steps) = (
            self.state_size(),
            self.measurement_size(),
            measurements.len(),
        );
        let mut forward = self.clone();
        let mut linearisations = Linearisations {
            transitions_t: vec![0.0; steps * n * n],
            observations_t: vec![0.0; steps * n * m],
            record: UpdateRecord::new(n, m, steps),
        };
        let filtered = forward.run_series(
            process,
            model,
            dts,
            measurements,
            cross,
            Some(&mut linearisations),
        )?;
        let Linearisations {
            transitions_t,
            observations_t,
            record,
        } = &linearisations;
        smooth_backward(
            self.state(),
            self.covariance(),
            filtered,
            record,
            |k| Operand::new(&transitions_t[k * n * n..(k + 1) * n * n], n, n),
            |k| Operand::new(&observations_t[k * n * m..(k + 1) * n * m], n, m),
        )
    }

    fn run_series<P, H>(
        &mut self,
        process: &P,
        model: &H,
        dts: &[f64],
        measurements: &MeasurementSeries<'_>,
        cross: Option<&DMatrix<f64>>,
        mut record: Option<&mut Linearisations>,
    ) -> Result<FilteredSeries>
    where
        P: DynProcessModel + ?Sized,
        H: DynMeasurementModel + ?Sized,
    {
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
        if dts.len() != 1 && dts.len() != steps {
            return Err(Error::Dimension {
                what: "time steps dts (one, or one per step)",
                expected: steps,
                got: dts.len(),
            });
        }
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
            self.predict(process, dts[k.min(dts.len() - 1)])?;
            if let Some(record) = record.as_deref_mut() {
                record.transitions_t[k * n * n..(k + 1) * n * n]
                    .copy_from_slice(self.core.transition_transposed().as_slice());
            }
            if let Some(y) = measurements.get(k)? {
                if correlated && record.is_some() && self.core.predicts_since_update() > 1 {
                    return Err(Error::SmootherUnsupported {
                        epoch: k + 1,
                        reason: "correlated update after an unmeasured step (or a series \
                                 started after predicts without an update)",
                    });
                }
                let report = self.update_slice(model, y, cross)?;
                out.nis[k] = report.nis;
                out.accepted[k] = report.accepted;
                if report.accepted {
                    out.log_likelihood += report.log_likelihood;
                    if let Some(record) = record.as_deref_mut() {
                        record.observations_t[k * n * m..(k + 1) * n * m]
                            .copy_from_slice(self.core.observation_transposed().as_slice());
                        record.record.set(
                            k,
                            self.core.innovation(),
                            self.core.innovation_covariance_inverse(),
                            self.core.gain_transposed(),
                        );
                    }
                }
            }
            out.estimates.set(k, self.state(), self.covariance());
        }
        Ok(out)
    }
}

/// What [`DynExtendedKalmanFilter::filter_and_smooth`] keeps of each step.
struct Linearisations {
    /// F(x)' per step, n x n each.
    transitions_t: Vec<f64>,
    /// H(x)' per step, n x m each.
    observations_t: Vec<f64>,
    record: UpdateRecord,
}
