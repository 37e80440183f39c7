//! A whole series through [`DynUnscentedKalmanFilter`]: the filter's pass, the
//! filtered and smoothed estimates of one call, and Saerkkae's URTS over given filtered
//! estimates.

use nalgebra::{DMatrix, DVector};

use super::DynUnscentedKalmanFilter;
use crate::dynamic::batch::{
    smooth_backward, FilteredAndSmoothed, FilteredSeries, Trajectory, UpdateRecord,
};
use crate::dynamic::filter::check_shape;
use crate::dynamic::linalg::{check_finite, check_size, spd_inverse_log_det_into};
use crate::dynamic::product::{gemm, Operand};
use crate::dynamic::sigma::{
    factor_into, sigma_pass, DynSigmaPointMeasurement, DynSigmaPointProcess,
};
use crate::dynamic::MeasurementSeries;
use crate::{Error, Result};

impl DynUnscentedKalmanFilter {
    /// Filter a series: entry k is a predict over `dts[k]` (or `dts[0]` for every step
    /// when `dts` has one entry) through `process`, then an update through `model` when
    /// measured (NaN rows or a mask: [`MeasurementSeries`]), with the cross-covariance
    /// `cross` at every update, or none. The filter advances, as predict and update in
    /// a loop (filterpy's `batch_filter`).
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
        P: DynSigmaPointProcess + ?Sized,
        H: DynSigmaPointMeasurement + ?Sized,
    {
        self.run_series(process, model, dts, measurements, cross, None)
    }

    /// Filter and smooth a series in one call (arguments as [`Self::filter_series`]):
    /// the filter's pass on a copy of this filter (which stays untouched) and the
    /// unscented RTS smoother over it, with the correlated update's consistent
    /// backward pass (that of [`crate::dynamic::DynKalmanFilter::filter_and_smooth`]) over each
    /// step's Phi~ and H~. With M = 0 it is Saerkkae's URTS (2008), G_k = D_{k+1}
    /// (P-_{k+1})^-1, since P_k Phi~' = D_{k+1}; it equals [`Self::rts_smooth`] over
    /// the filtered estimates when every step is measured, and the static
    /// [`crate::UnscentedKalmanFilter::smooth_batch`] with and without M.
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
        P: DynSigmaPointProcess + ?Sized,
        H: DynSigmaPointMeasurement + ?Sized,
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
            &self.state,
            &self.covariance,
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
        P: DynSigmaPointProcess + ?Sized,
        H: DynSigmaPointMeasurement + ?Sized,
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
                let phi_t = &mut record.transitions_t[k * n * n..(k + 1) * n * n];
                transpose_into(&self.ws.process.linearised, phi_t);
            }
            if let Some(y) = measurements.get(k)? {
                if correlated && record.is_some() && self.predicts_since_update > 1 {
                    return Err(Error::SmootherUnsupported {
                        epoch: k + 1,
                        reason: "correlated update after an unmeasured step (or a series \
                                 started after predicts without an update)",
                    });
                }
                let report = self.update_slice(model, y, cross)?;
                out.nis[k] = report.nis;
                out.accepted[k] = report.accepted;
                out.log_likelihood += report.log_likelihood;
                if let Some(record) = record.as_deref_mut() {
                    let h_t = &mut record.observations_t[k * n * m..(k + 1) * n * m];
                    transpose_into(&self.ws.measurement.linearised, h_t);
                    record
                        .record
                        .set(k, &self.ws.innovation, &self.ws.s_inverse, &self.ws.gain_t);
                }
            }
            out.estimates.set(k, &self.state, &self.covariance);
        }
        Ok(out)
    }

    /// Saerkkae's unscented RTS smoother over given filtered estimates (filterpy's
    /// `rts_smoother(Xs, Ps)`), in place: for k = T - 2 down to 0, the sigma points of
    /// (x_k, P_k) through `process` over `dts[k + 1]`, their mean x-, covariance
    /// P- + Q_{k+1} and cross-covariance D, G_k = D (P-)^-1,
    /// x_k += G_k residual(x_{k+1}, x-), P_k += G_k (P_{k+1} - P-) G_k'. `states` is
    /// T x n and `covariances` T x n x n, step-major; `dts` one entry or T;
    /// `process_noises` none (this filter's Q), or T matrices (n x n, step-major), entry
    /// k + 1 used between k and k + 1. Returns the gains (T x n x n, the last zero).
    /// Uses this filter's weights and workspace; its estimate is untouched.
    ///
    /// # Errors
    /// [`Error::Dimension`] for buffers of the wrong size; [`Error::InvalidCovariance`]
    /// when a covariance has no square root or a predicted covariance is not positive
    /// definite; [`Error::NonFinite`]; the model's errors.
    pub fn rts_smooth<P: DynSigmaPointProcess + ?Sized>(
        &mut self,
        process: &P,
        states: &mut [f64],
        covariances: &mut [f64],
        dts: &[f64],
        process_noises: Option<&[f64]>,
    ) -> Result<Vec<f64>> {
        let n = self.state_size();
        let steps = states.len() / n;
        check_size("smoother states (T x n)", steps * n, states.len())?;
        check_size(
            "smoother covariances (T x n x n)",
            steps * n * n,
            covariances.len(),
        )?;
        if dts.len() != 1 && dts.len() != steps {
            return Err(Error::Dimension {
                what: "time steps dts (one, or one per step)",
                expected: steps,
                got: dts.len(),
            });
        }
        if let Some(q) = process_noises {
            check_size("process noises Qs (T x n x n)", steps * n * n, q.len())?;
        }
        check_finite(states, "smoother states")?;
        check_finite(covariances, "smoother covariances")?;
        let weights = self.weights()?;
        let nn = n * n;
        let mut gains = vec![0.0; steps * nn];
        let mut x = DVector::<f64>::zeros(n);
        let mut p = DMatrix::<f64>::zeros(n, n);
        let mut predicted = DMatrix::<f64>::zeros(n, n);
        let mut factor = DMatrix::<f64>::zeros(n, n);
        let mut inverse = DMatrix::<f64>::zeros(n, n);
        let mut gain = DMatrix::<f64>::zeros(n, n);
        let mut gain_t = DMatrix::<f64>::zeros(n, n);
        let mut scratch = DMatrix::<f64>::zeros(n, n);
        let mut cross = DMatrix::<f64>::zeros(n, n);
        let mut shift = DVector::<f64>::zeros(n);
        for k in (0..steps.saturating_sub(1)).rev() {
            let dt = dts[(k + 1).min(dts.len() - 1)];
            x.copy_from_slice(&states[k * n..(k + 1) * n]);
            p.copy_from_slice(&covariances[k * nn..(k + 1) * nn]);
            factor_into(&p, &mut self.ws.factor, "filtered covariance (smoother)")?;
            let ws = &mut self.ws;
            sigma_pass(
                &weights,
                &x,
                &ws.factor,
                &mut ws.point,
                &mut ws.process,
                |s, out| process.propagate(s, dt, out),
                |a, b, out| process.residual(a, b, out),
                |points, out| process.mean(points, out),
                "propagated sigma point",
            )?;
            let pass = &ws.process;
            for j in 0..n {
                for i in 0..n {
                    let q = match process_noises {
                        Some(q) => {
                            let q = &q[(k + 1) * nn..(k + 2) * nn];
                            (q[i + j * n] + q[j + i * n]) * 0.5
                        }
                        None => (self.process_noise[(i, j)] + self.process_noise[(j, i)]) * 0.5,
                    };
                    predicted[(i, j)] = (pass.second[(i, j)] + pass.second[(j, i)]) * 0.5 + q;
                }
            }
            // D = S G'; G_k = D (P-)^-1.
            pass.spread.transpose_to(&mut scratch);
            gemm(&mut cross, 1.0, &ws.factor, &scratch, 0.0);
            spd_inverse_log_det_into(&predicted, &mut factor, &mut inverse).ok_or_else(|| {
                Error::InvalidCovariance {
                    what: "predicted covariance (smoother gain)",
                    reason: format!("not positive definite after step {}", k + 1),
                }
            })?;
            gemm(&mut gain, 1.0, &cross, &inverse, 0.0);
            // x_k += G residual(x_{k+1}, x-).
            x.copy_from_slice(&states[(k + 1) * n..(k + 2) * n]);
            process.residual(&x, &pass.mean, &mut shift)?;
            for r in 0..n {
                let mut v = 0.0;
                for c in 0..n {
                    v += gain[(r, c)] * shift[c];
                }
                states[k * n + r] += v;
            }
            // P_k += G (P_{k+1} - P-) G'.
            for j in 0..n {
                for i in 0..n {
                    p[(i, j)] = covariances[(k + 1) * nn + i + j * n] - predicted[(i, j)];
                }
            }
            gemm(&mut scratch, 1.0, &gain, &p, 0.0);
            gain.transpose_to(&mut gain_t);
            gemm(&mut p, 1.0, &scratch, &gain_t, 0.0);
            for j in 0..n {
                for i in 0..n {
                    covariances[k * nn + i + j * n] += (p[(i, j)] + p[(j, i)]) * 0.5;
                }
            }
            gains[k * nn..(k + 1) * nn].copy_from_slice(gain.as_slice());
        }
        check_finite(states, "smoothed states")?;
        check_finite(covariances, "smoothed covariances")?;
        Ok(gains)
    }
}

/// What [`DynUnscentedKalmanFilter::filter_and_smooth`] keeps of each step.
struct Linearisations {
    /// Phi~' per step, n x n each.
    transitions_t: Vec<f64>,
    /// H~' per step, n x m each.
    observations_t: Vec<f64>,
    record: UpdateRecord,
}

/// `a'` into a column-major slice.
fn transpose_into(a: &DMatrix<f64>, out: &mut [f64]) {
    let (rows, cols) = (a.nrows(), a.ncols());
    for i in 0..rows {
        for j in 0..cols {
            out[j + i * cols] = a[(i, j)];
        }
    }
}
