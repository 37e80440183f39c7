//! The two sides of the fit: the IMU's prefix integrals on its own clock, the search
//! box of the clock, and the reference increments over the reference's intervals.

use nalgebra::Vector3;

use super::{ImuCalibrator, MAX_GRID_POINTS, MAX_SCALE_GRID};
use crate::error::{Error, Result};
use crate::mechanization::ImuSample;
use crate::simulator::{Trajectory, TrajectorySample};

/// (∫ f, ∫ ω) over some span.
type Integrals = (Vector3<f64>, Vector3<f64>);

/// Prefix integrals of the IMU's piecewise-constant rates on the IMU clock.
pub(super) struct ImuPrefix<'a> {
    samples: &'a [ImuSample],
    /// Sample boundaries u_0 < ... < u_N (the last sample lasts the typical step).
    knots: Vec<f64>,
    /// ∫ f du and ∫ ω du from u_0 to each knot.
    force: Vec<Vector3<f64>>,
    rate: Vec<Vector3<f64>>,
    pub(super) typical_step: f64,
}

impl<'a> ImuPrefix<'a> {
    pub(super) fn new(samples: &'a [ImuSample]) -> Result<Self> {
        if samples.len() < 2 {
            return Err(Error::InvalidParameter {
                name: "imu",
                reason: format!("{} samples, at least 2 needed", samples.len()),
            });
        }
        for (i, s) in samples.iter().enumerate() {
            let finite = s.time.is_finite()
                && s.specific_force.iter().all(|x| x.is_finite())
                && s.angular_rate.iter().all(|x| x.is_finite());
            if !finite {
                return Err(Error::NonFinite {
                    what: format!("IMU sample {i}"),
                });
            }
            if i > 0 && s.time <= samples[i - 1].time {
                return Err(Error::ImuTime {
                    index: i,
                    reason: format!(
                        "time {} does not increase (previous {})",
                        s.time,
                        samples[i - 1].time
                    ),
                });
            }
        }
        let mut steps: Vec<f64> = samples.windows(2).map(|w| w[1].time - w[0].time).collect();
        steps.sort_by(f64::total_cmp);
        let typical_step = steps[steps.len() / 2];
        let mut knots: Vec<f64> = samples.iter().map(|s| s.time).collect();
        knots.push(samples[samples.len() - 1].time + typical_step);
        let mut force = vec![Vector3::zeros()];
        let mut rate = vec![Vector3::zeros()];
        for (i, s) in samples.iter().enumerate() {
            let du = knots[i + 1] - knots[i];
            // A gap would stretch one sample over it: refuse (ten typical steps).
            if du > 10.0 * typical_step {
                return Err(Error::ImuTime {
                    index: i + 1,
                    reason: format!("gap of {du} s after a typical step of {typical_step} s"),
                });
            }
            force.push(force[i] + s.specific_force * du);
            rate.push(rate[i] + s.angular_rate * du);
        }
        Ok(Self {
            samples,
            knots,
            force,
            rate,
            typical_step,
        })
    }

    pub(super) fn first(&self) -> f64 {
        self.knots[0]
    }

    pub(super) fn end(&self) -> f64 {
        self.knots[self.knots.len() - 1]
    }

    /// (∫ f du, ∫ ω du) from u_0 to `u` (clamped to the log).
    pub(super) fn at(&self, u: f64) -> Integrals {
        let u = u.clamp(self.first(), self.end());
        let k = self
            .knots
            .partition_point(|&x| x <= u)
            .saturating_sub(1)
            .min(self.samples.len() - 1);
        let du = u - self.knots[k];
        let s = &self.samples[k];
        (
            self.force[k] + s.specific_force * du,
            self.rate[k] + s.angular_rate * du,
        )
    }
}

/// The search box of (s, τ) and the conditioning centre t_c of the IMU clock.
pub(super) struct ClockBox {
    pub(super) scale: (f64, f64),
    pub(super) offset: (f64, f64),
    /// Middle of the IMU log: the refinement fits τ_c = τ - (s - 1) t_c, the offset there.
    pub(super) center: f64,
    /// Largest |t - t_c| over the log.
    pub(super) half_span: f64,
    /// Central-difference step of τ \[s\].
    pub(super) offset_step: f64,
}

impl ClockBox {
    pub(super) fn new(settings: &ImuCalibrator, prefix: &ImuPrefix<'_>) -> Result<Self> {
        let center = 0.5 * (prefix.first() + prefix.end());
        let half_span = 0.5 * (prefix.end() - prefix.first());
        let farthest = prefix.first().abs().max(prefix.end().abs());
        let scale_values =
            2.0 * settings.max_clock_scale_error * farthest / settings.time_offset_grid_step;
        if scale_values > MAX_SCALE_GRID as f64 {
            return Err(Error::InvalidParameter {
                name: "imu times",
                reason: format!(
                    "times up to {farthest} s from 0 need {scale_values:.0} clock-scale grid \
                     values (at most {MAX_SCALE_GRID}): give times relative to a nearby epoch"
                ),
            });
        }
        let e = settings.max_clock_scale_error;
        let m = settings.max_time_offset;
        let points = (scale_values + 2.0) * (2.0 * m / settings.time_offset_grid_step + 2.0);
        if points > MAX_GRID_POINTS as f64 {
            return Err(Error::InvalidParameter {
                name: "max_time_offset",
                reason: format!(
                    "the (clock scale, time offset) grid would hold {points:.0} points (at most \
                     {MAX_GRID_POINTS}): narrow max_time_offset or max_clock_scale_error, or \
                     coarsen time_offset_grid_step"
                ),
            });
        }
        Ok(Self {
            scale: (1.0 - e, 1.0 + e),
            offset: (-m, m),
            center,
            half_span,
            offset_step: (2.5 * prefix.typical_step).max(1e-4),
        })
    }

    /// IMU time of reference time `t` for (s, τ_c).
    pub(super) fn imu_time(&self, t: f64, scale: f64, centred_offset: f64) -> f64 {
        self.center + (t - self.center + centred_offset) / scale
    }

    /// τ_c of (s, τ).
    pub(super) fn centred(&self, scale: f64, offset: f64) -> f64 {
        offset - (scale - 1.0) * self.center
    }
}

/// Reference integrals of f^b and ω_ib^b over consecutive intervals.
pub(super) struct ReferenceIncrements {
    start: Vec<f64>,
    end: Vec<f64>,
    pub(super) force: Vec<Vector3<f64>>,
    pub(super) rate: Vec<Vector3<f64>>,
}

impl ReferenceIncrements {
    pub(super) fn new(reference: &[TrajectorySample], min_interval: f64) -> Result<Self> {
        let trajectory = Trajectory::velocity_driven(reference.to_vec())?;
        let mut epochs = vec![reference[0].time];
        for s in &reference[1..] {
            if s.time - epochs[epochs.len() - 1] >= min_interval {
                epochs.push(s.time);
            }
        }
        let mut out = Self {
            start: Vec::new(),
            end: Vec::new(),
            force: Vec::new(),
            rate: Vec::new(),
        };
        for w in epochs.windows(2) {
            let dt = w[1] - w[0];
            let mean = trajectory.mean_outputs(w[0], dt);
            out.start.push(w[0]);
            out.end.push(w[1]);
            out.force.push(mean.specific_force * dt);
            out.rate.push(mean.angular_rate * dt);
        }
        Ok(out)
    }

    /// The intervals inside the IMU log for every clock in the box (with the
    /// central-difference margin).
    pub(super) fn inside(self, prefix: &ImuPrefix<'_>, clock: &ClockBox) -> Self {
        let margin = 2.0 * clock.offset_step;
        let corners = |t: f64| {
            [clock.scale.0, clock.scale.1]
                .into_iter()
                .flat_map(move |s| {
                    [clock.offset.0 - margin, clock.offset.1 + margin]
                        .into_iter()
                        .map(move |tau| (t + tau) / s)
                })
        };
        let keep: Vec<bool> = (0..self.start.len())
            .map(|j| {
                corners(self.start[j]).all(|u| u >= prefix.first())
                    && corners(self.end[j]).all(|u| u <= prefix.end())
            })
            .collect();
        let pick = |v: Vec<f64>| {
            v.into_iter()
                .zip(&keep)
                .filter(|(_, k)| **k)
                .map(|(x, _)| x)
                .collect()
        };
        let pick3 = |v: Vec<Vector3<f64>>| {
            v.into_iter()
                .zip(&keep)
                .filter(|(_, k)| **k)
                .map(|(x, _)| x)
                .collect()
        };
        Self {
            start: pick(self.start),
            end: pick(self.end),
            force: pick3(self.force),
            rate: pick3(self.rate),
        }
    }

    pub(super) fn len(&self) -> usize {
        self.start.len()
    }

    pub(super) fn duration(&self, j: usize) -> f64 {
        self.end[j] - self.start[j]
    }

    /// The IMU integrals (∫ f dT, ∫ ω dT) on the reference clock over every interval,
    /// for (s, τ_c), in IMU axes.
    pub(super) fn imu_integrals(
        &self,
        prefix: &ImuPrefix<'_>,
        clock: &ClockBox,
        scale: f64,
        centred_offset: f64,
    ) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
        let mut force = Vec::with_capacity(self.len());
        let mut rate = Vec::with_capacity(self.len());
        let mut previous: Option<(f64, Integrals)> = None;
        for j in 0..self.len() {
            let u0 = clock.imu_time(self.start[j], scale, centred_offset);
            let u1 = clock.imu_time(self.end[j], scale, centred_offset);
            // Consecutive intervals share their boundary: reuse its prefix.
            let a = match previous {
                Some((t, p)) if t == self.start[j] => p,
                _ => prefix.at(u0),
            };
            let b = prefix.at(u1);
            // ∫ over [T0, T1] of the rate at u(T): s ∫ over [u0, u1] du.
            force.push((b.0 - a.0) * scale);
            rate.push((b.1 - a.1) * scale);
            previous = Some((self.end[j], b));
        }
        (force, rate)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn prefix_integral_matches_a_direct_sum() {
        // Reference: the sum of sample * overlap written out for one window.
        let samples: Vec<ImuSample> = (0..50)
            .map(|k| {
                let x = f64::from(k);
                ImuSample::new(
                    0.1 * x,
                    Vector3::new(x, -x, 1.0),
                    Vector3::new(0.5, x * x, 0.0),
                )
            })
            .collect();
        let prefix = ImuPrefix::new(&samples).unwrap();
        let (u0, u1) = (0.234, 3.71);
        let (a, b) = (prefix.at(u0), prefix.at(u1));
        let mut f = Vector3::zeros();
        let mut w = Vector3::zeros();
        for s in &samples {
            let overlap = (s.time + 0.1).min(u1) - s.time.max(u0);
            if overlap > 0.0 {
                f += s.specific_force * overlap;
                w += s.angular_rate * overlap;
            }
        }
        assert!((b.0 - a.0 - f).norm() < 1e-10);
        assert!((b.1 - a.1 - w).norm() < 1e-10);
    }
}
