//! The coarse search over the axis conventions and the clock, and the
//! Levenberg-Marquardt refinement with its covariance (steps 1-3 of the method in the
//! parent module's docs).

use nalgebra::{DVector, Matrix3, Vector3};

use super::increments::{ClockBox, ImuPrefix, ReferenceIncrements};
use super::{
    AxisMap, Estimate, ImuCalibration, ImuCalibrator, ParameterMatrix, ParameterVector,
    IMU_CALIBRATION_PARAMETERS,
};
use crate::error::{Error, Result};

/// Sums over the intervals that the profiled cost of every permutation needs.
struct SensorSums {
    /// C\[a\]\[k\] = Σ_j R_{j,a} I_{j,k}.
    cross: Matrix3<f64>,
    /// Σ_j ΔT_j I_j.
    weighted: Vector3<f64>,
    /// Σ_j |I_j|².
    square: f64,
}

impl SensorSums {
    fn new(reference: &[Vector3<f64>], imu: &[Vector3<f64>], durations: &[f64]) -> Self {
        let mut sums = Self {
            cross: Matrix3::zeros(),
            weighted: Vector3::zeros(),
            square: 0.0,
        };
        for ((r, i), &dt) in reference.iter().zip(imu).zip(durations) {
            sums.cross += r * i.transpose();
            sums.weighted += i * dt;
            sums.square += i.norm_squared();
        }
        sums
    }
}

/// The reference's own sums for one sensor.
struct ReferenceSums {
    /// S_R = Σ_j ΔT_j R_j.
    weighted: Vector3<f64>,
    /// Σ_j |R_j|².
    square: f64,
    /// D = Σ_j ΔT_j².
    duration_square: f64,
    /// SS: Σ_j |R_j - ΔT_j S_R / D|², the variability a constant rate leaves.
    spread: f64,
}

impl ReferenceSums {
    fn new(reference: &[Vector3<f64>], durations: &[f64]) -> Self {
        let weighted: Vector3<f64> = reference.iter().zip(durations).map(|(r, &dt)| r * dt).sum();
        let square: f64 = reference.iter().map(|r| r.norm_squared()).sum();
        let duration_square: f64 = durations.iter().map(|dt| dt * dt).sum();
        Self {
            weighted,
            square,
            duration_square,
            spread: square - weighted.norm_squared() / duration_square,
        }
    }

    /// (RSS, bias) for `axes` with the bias eliminated in closed form:
    /// b = (P S_I - S_R) / D, RSS = Σ |P I_j - R_j|² - |P S_I - S_R|² / D.
    fn profiled(&self, axes: &AxisMap, sums: &SensorSums) -> (f64, Vector3<f64>) {
        let cross: f64 = (0..3)
            .map(|a| {
                let c = sums.cross[(a, axes.source(a))];
                if axes.is_negated(a) {
                    -c
                } else {
                    c
                }
            })
            .sum();
        let mismatch = axes.apply(&sums.weighted) - self.weighted;
        let rss = sums.square + self.square
            - 2.0 * cross
            - mismatch.norm_squared() / self.duration_square;
        (rss.max(0.0), mismatch / self.duration_square)
    }
}

/// The coarse search's outcome.
pub(super) struct Search {
    axes: AxisMap,
    scale: f64,
    offset: f64,
    cost: f64,
    runner_up: Option<(AxisMap, f64)>,
}

/// Grid over (s, τ), every permutation's profiled cost at each point (step 1 of the
/// method).
pub(super) fn coarse_search(
    settings: &ImuCalibrator,
    prefix: &ImuPrefix<'_>,
    reference: &ReferenceIncrements,
    clock: &ClockBox,
) -> Result<Search> {
    let durations: Vec<f64> = (0..reference.len())
        .map(|j| reference.duration(j))
        .collect();
    let reference_force = ReferenceSums::new(&reference.force, &durations);
    let reference_rate = ReferenceSums::new(&reference.rate, &durations);
    // Numerically no variability: nothing to fit the axes against (relative to the
    // constant part, or absolutely for a reference at rest with no rotation).
    let tiny = |r: &ReferenceSums| r.spread <= 1e-12 * (r.square + reference.len() as f64 * 1e-12);
    if tiny(&reference_force) && tiny(&reference_rate) {
        return Err(Error::CalibrationNoMotion);
    }
    let floor = |r: &ReferenceSums| r.spread.max(1e-12 * r.square).max(1e-300);
    let (force_norm, rate_norm) = (floor(&reference_force), floor(&reference_rate));
    let farthest = prefix.first().abs().max(prefix.end().abs()).max(1e-9);
    let tau_count = grid_count(clock.offset, settings.time_offset_grid_step);
    let scale_count = grid_count(clock.scale, settings.time_offset_grid_step / farthest);
    let mut best: Vec<(f64, f64, f64)> = vec![(f64::INFINITY, 1.0, 0.0); 48];
    for si in 0..scale_count {
        let scale = grid_value(clock.scale, scale_count, si);
        for ti in 0..tau_count {
            let offset = grid_value(clock.offset, tau_count, ti);
            let (force, rate) =
                reference.imu_integrals(prefix, clock, scale, clock.centred(scale, offset));
            let force_sums = SensorSums::new(&reference.force, &force, &durations);
            let rate_sums = SensorSums::new(&reference.rate, &rate, &durations);
            for (k, axes) in AxisMap::all().enumerate() {
                let (rss_f, bias_f) = reference_force.profiled(&axes, &force_sums);
                let (rss_w, bias_w) = reference_rate.profiled(&axes, &rate_sums);
                if bias_f.amax() > settings.max_accelerometer_bias
                    || bias_w.amax() > settings.max_gyroscope_bias
                {
                    continue;
                }
                let cost = rss_f / force_norm + rss_w / rate_norm;
                if cost < best[k].0 {
                    best[k] = (cost, scale, offset);
                }
            }
        }
    }
    let mut ranked: Vec<(AxisMap, (f64, f64, f64))> = AxisMap::all()
        .zip(best)
        .filter(|(_, b)| b.0.is_finite())
        .collect();
    ranked.sort_by(|a, b| a.1 .0.total_cmp(&b.1 .0));
    let Some(&(axes, (cost, scale, offset))) = ranked.first() else {
        return Err(Error::CalibrationNoAxes {
            max_accelerometer_bias: settings.max_accelerometer_bias,
            max_gyroscope_bias: settings.max_gyroscope_bias,
        });
    };
    let runner_up = ranked.get(1).map(|&(a, (c, _, _))| (a, c));
    if let Some((second, second_cost)) = runner_up {
        let ratio = second_cost / cost.max(1e-300);
        if ratio < settings.min_cost_ratio {
            return Err(Error::CalibrationAmbiguousAxes {
                best: axes,
                runner_up: second,
                cost_ratio: ratio,
                min_cost_ratio: settings.min_cost_ratio,
            });
        }
    }
    Ok(Search {
        axes,
        scale,
        offset,
        cost,
        runner_up,
    })
}

/// Number of grid values over `range` with spacing at most `step` (at least 2).
fn grid_count(range: (f64, f64), step: f64) -> usize {
    ((range.1 - range.0) / step).ceil().max(1.0) as usize + 1
}

fn grid_value(range: (f64, f64), count: usize, i: usize) -> f64 {
    range.0 + (range.1 - range.0) * i as f64 / (count - 1) as f64
}

/// The refined fit (steps 2 and 3 of the method), in (s, τ_c, b_a, b_g).
pub(super) struct Refined {
    axes: AxisMap,
    parameters: ParameterVector,
    covariance: ParameterMatrix,
    free_scale: [bool; 3],
    residual_rms: [Vector3<f64>; 2],
    autocorrelation: f64,
    variance_ratio: f64,
    iterations: usize,
}

/// Residuals (6 per interval: accelerometer x y z, gyroscope x y z) at `p`.
fn residuals(
    axes: &AxisMap,
    prefix: &ImuPrefix<'_>,
    reference: &ReferenceIncrements,
    clock: &ClockBox,
    p: &ParameterVector,
) -> DVector<f64> {
    let (force, rate) = reference.imu_integrals(prefix, clock, p[0], p[1]);
    let acc_bias = Vector3::new(p[2], p[3], p[4]);
    let gyro_bias = Vector3::new(p[5], p[6], p[7]);
    let gyro_scale = Vector3::new(1.0 + p[8], 1.0 + p[9], 1.0 + p[10]);
    let mut r = DVector::zeros(6 * reference.len());
    for j in 0..reference.len() {
        let dt = reference.duration(j);
        let f = axes.apply(&force[j]) - acc_bias * dt - reference.force[j];
        let w =
            axes.apply(&rate[j]) - gyro_bias * dt - reference.rate[j].component_mul(&gyro_scale);
        r.fixed_rows_mut::<3>(6 * j).copy_from(&f);
        r.fixed_rows_mut::<3>(6 * j + 3).copy_from(&w);
    }
    r
}

/// Σ_j r_{j,c}² / σ_c².
fn weighted_cost(r: &DVector<f64>, weights: &[f64; 6]) -> f64 {
    r.iter()
        .enumerate()
        .map(|(i, x)| x * x * weights[i % 6])
        .sum()
}

/// Per-channel inverse residual variances (floored so that a perfect channel keeps a
/// finite weight), with the degrees-of-freedom correction 6M / (6M - 8).
fn channel_weights(r: &DVector<f64>) -> [f64; 6] {
    let n = r.len() / 6;
    let dof = (r.len() as f64 / (r.len() as f64 - IMU_CALIBRATION_PARAMETERS as f64)).max(1.0);
    std::array::from_fn(|c| {
        let ms = (0..n).map(|j| r[6 * j + c].powi(2)).sum::<f64>() / n as f64 * dof;
        1.0 / ms.max(1e-30)
    })
}

/// Index of the first gyroscope scale-factor error k_g in the parameter vector.
const SCALE: usize = 8;

/// J'WJ and J'Wr at `p`: the (s, τ_c) columns by central differences, the bias columns
/// exact (-ΔT_j on their channel), the gyroscope scale columns exact (minus the
/// reference's rate integral on their axis; zero for a scale held at 1).
#[allow(clippy::too_many_arguments)]
fn normal_equations(
    axes: &AxisMap,
    prefix: &ImuPrefix<'_>,
    reference: &ReferenceIncrements,
    clock: &ClockBox,
    p: &ParameterVector,
    r: &DVector<f64>,
    weights: &[f64; 6],
    free_scale: &[bool; 3],
) -> NormalEquations {
    let steps = [
        clock.offset_step / clock.half_span.max(1.0),
        clock.offset_step,
    ];
    let columns: Vec<DVector<f64>> = (0..2)
        .map(|k| {
            let mut plus = *p;
            let mut minus = *p;
            plus[k] += steps[k];
            minus[k] -= steps[k];
            (residuals(axes, prefix, reference, clock, &plus)
                - residuals(axes, prefix, reference, clock, &minus))
                / (2.0 * steps[k])
        })
        .collect();
    let mut jtj = ParameterMatrix::zeros();
    let mut scores = Vec::with_capacity(reference.len());
    for j in 0..reference.len() {
        let dt = reference.duration(j);
        let mut score = ParameterVector::zeros();
        for c in 0..6 {
            let i = 6 * j + c;
            let mut row = ParameterVector::zeros();
            row[0] = columns[0][i];
            row[1] = columns[1][i];
            row[2 + c] = -dt;
            if c >= 3 && free_scale[c - 3] {
                row[SCALE + c - 3] = -reference.rate[j][c - 3];
            }
            jtj += row * row.transpose() * weights[c];
            score += row * (r[i] * weights[c]);
        }
        scores.push(score);
    }
    // A scale held at 1 has a zero column: a unit diagonal keeps the system solvable
    // and its step zero (its gradient is zero).
    for (a, free) in free_scale.iter().enumerate() {
        if !free {
            jtj[(SCALE + a, SCALE + a)] = 1.0;
        }
    }
    NormalEquations {
        jtj,
        jtr: scores.iter().sum(),
        scores,
    }
}

/// J'WJ, J'Wr and the per-interval scores g_j = J_j' W r_j (J'Wr = Σ_j g_j).
struct NormalEquations {
    jtj: ParameterMatrix,
    jtr: ParameterVector,
    scores: Vec<ParameterVector>,
}

/// Newey-West estimate of the covariance of the scores' sum, Σ_j g_j g_j' plus the
/// lagged products up to lag L with Bartlett weights 1 - l/(L+1), L = floor(4 (M/100)^(2/9))
/// (Newey & West, Econometrica 55(3), 1987, eq. 3; the lag rule of Newey & West, Rev.
/// Econ. Stud. 61(4), 1994). Positive semidefinite by construction.
fn score_covariance(scores: &[ParameterVector]) -> ParameterMatrix {
    let m = scores.len();
    let lags = (4.0 * (m as f64 / 100.0).powf(2.0 / 9.0)).floor() as usize;
    let mut b: ParameterMatrix = scores.iter().map(|g| g * g.transpose()).sum();
    for l in 1..=lags.min(m.saturating_sub(1)) {
        let weight = 1.0 - l as f64 / (lags as f64 + 1.0);
        let mut lagged = ParameterMatrix::zeros();
        for j in l..m {
            lagged += scores[j] * scores[j - l].transpose();
        }
        b += (lagged + lagged.transpose()) * weight;
    }
    b
}

/// Levenberg-Marquardt from `p` with fixed weights; returns the point and iterations.
#[allow(clippy::too_many_arguments)]
fn levenberg_marquardt(
    settings: &ImuCalibrator,
    axes: &AxisMap,
    prefix: &ImuPrefix<'_>,
    reference: &ReferenceIncrements,
    clock: &ClockBox,
    mut p: ParameterVector,
    weights: &[f64; 6],
    free_scale: &[bool; 3],
) -> (ParameterVector, usize) {
    let mut r = residuals(axes, prefix, reference, clock, &p);
    let mut cost = weighted_cost(&r, weights);
    let mut lambda = 1e-3;
    let mut iterations = 0;
    while iterations < settings.max_iterations {
        iterations += 1;
        let NormalEquations { jtj, jtr, .. } =
            normal_equations(axes, prefix, reference, clock, &p, &r, weights, free_scale);
        let mut improved = false;
        while lambda < 1e12 {
            let mut damped = jtj;
            for k in 0..IMU_CALIBRATION_PARAMETERS {
                damped[(k, k)] += lambda * jtj[(k, k)].max(1e-300);
            }
            let Some(step) = damped.cholesky().map(|c| c.solve(&(-jtr))) else {
                lambda *= 10.0;
                continue;
            };
            let mut candidate = p + step;
            candidate[0] = candidate[0].clamp(clock.scale.0, clock.scale.1);
            let offset = (candidate[1] + (candidate[0] - 1.0) * clock.center)
                .clamp(clock.offset.0, clock.offset.1);
            candidate[1] = clock.centred(candidate[0], offset);
            let r_new = residuals(axes, prefix, reference, clock, &candidate);
            let cost_new = weighted_cost(&r_new, weights);
            if cost_new <= cost {
                let small = (cost - cost_new) <= 1e-12 * cost;
                p = candidate;
                r = r_new;
                cost = cost_new;
                lambda = (lambda * 0.1).max(1e-12);
                improved = !small;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    (p, iterations)
}

pub(super) fn refine(
    settings: &ImuCalibrator,
    prefix: &ImuPrefix<'_>,
    reference: &ReferenceIncrements,
    clock: &ClockBox,
    search: &Search,
) -> Result<Refined> {
    let axes = search.axes;
    let mut p = ParameterVector::zeros();
    p[0] = search.scale;
    p[1] = clock.centred(search.scale, search.offset);
    // Start the biases at their closed-form values for the grid clock.
    let r0 = residuals(&axes, prefix, reference, clock, &p);
    let total: f64 = (0..reference.len()).map(|j| reference.duration(j)).sum();
    for c in 0..6 {
        let sum: f64 = (0..reference.len()).map(|j| r0[6 * j + c]).sum();
        p[2 + c] = sum / total;
    }
    let free_scale = scale_excited(reference, settings.min_scale_rate);
    let mut iterations = 0;
    for _round in 0..3 {
        let r = residuals(&axes, prefix, reference, clock, &p);
        let weights = channel_weights(&r);
        let (next, n) = levenberg_marquardt(
            settings,
            &axes,
            prefix,
            reference,
            clock,
            p,
            &weights,
            &free_scale,
        );
        p = next;
        iterations += n;
    }
    let r = residuals(&axes, prefix, reference, clock, &p);
    let weights = channel_weights(&r);
    let normal = normal_equations(
        &axes,
        prefix,
        reference,
        clock,
        &p,
        &r,
        &weights,
        &free_scale,
    );
    let inverse = normal
        .jtj
        .cholesky()
        .map(|c| c.inverse())
        .filter(|c| c.iter().all(|x| x.is_finite()))
        .ok_or(Error::CalibrationDegenerate {
            reason: "the normal matrix J'WJ is not positive definite",
        })?;
    let covariance = inverse * score_covariance(&normal.scores) * inverse;
    let variance_ratio = (0..IMU_CALIBRATION_PARAMETERS)
        .filter(|&k| k < SCALE || free_scale[k - SCALE])
        .map(|k| covariance[(k, k)] / inverse[(k, k)])
        .fold(0.0, f64::max);
    let autocorrelation = lag1_autocorrelation(&r, &weights);
    let residual_rms = [0, 3].map(|offset| {
        Vector3::from_fn(|c, _| {
            let ms = (0..reference.len())
                .map(|j| (r[6 * j + offset + c] / reference.duration(j)).powi(2))
                .sum::<f64>()
                / reference.len() as f64;
            ms.sqrt()
        })
    });
    Ok(Refined {
        axes,
        parameters: p,
        covariance,
        free_scale,
        residual_rms,
        autocorrelation,
        variance_ratio,
        iterations,
    })
}

/// Which body axes' reference rate varies enough (RMS about its time-weighted mean at
/// least `min_rate`) for the gyroscope's scale factor on that axis to be fitted.
fn scale_excited(reference: &ReferenceIncrements, min_rate: f64) -> [bool; 3] {
    let total: f64 = (0..reference.len()).map(|j| reference.duration(j)).sum();
    let mean: Vector3<f64> = reference.rate.iter().sum::<Vector3<f64>>() / total.max(1e-300);
    std::array::from_fn(|a| {
        let square: f64 = (0..reference.len())
            .map(|j| {
                let dt = reference.duration(j);
                (reference.rate[j][a] / dt - mean[a]).powi(2) * dt
            })
            .sum();
        (square / total.max(1e-300)).sqrt() >= min_rate
    })
}

/// Σ_c Σ_j z_{j,c} z_{j+1,c} / Σ_c Σ_j z_{j,c}², z = r / σ_c.
fn lag1_autocorrelation(r: &DVector<f64>, weights: &[f64; 6]) -> f64 {
    let n = r.len() / 6;
    let (mut lagged, mut square) = (0.0, 0.0);
    for c in 0..6 {
        for j in 0..n {
            let z = r[6 * j + c] * weights[c].sqrt();
            square += z * z;
            if j + 1 < n {
                lagged += z * r[6 * (j + 1) + c] * weights[c].sqrt();
            }
        }
    }
    if square > 0.0 {
        lagged / square
    } else {
        0.0
    }
}

impl Refined {
    /// The result in the reported parameters: τ = τ_c + (s - 1) t_c.
    pub(super) fn into_calibration(
        self,
        search: &Search,
        intervals: usize,
        center: f64,
    ) -> ImuCalibration {
        let p = self.parameters;
        let mut transform = ParameterMatrix::identity();
        transform[(1, 0)] = center;
        let covariance = transform * self.covariance * transform.transpose();
        let estimate = |k: usize, value: f64| Estimate {
            value,
            standard_error: covariance[(k, k)].max(0.0).sqrt(),
        };
        ImuCalibration {
            axes: self.axes,
            clock_scale: estimate(0, p[0]),
            time_offset_s: estimate(1, p[1] + (p[0] - 1.0) * center),
            accelerometer_bias: std::array::from_fn(|i| estimate(2 + i, p[2 + i])),
            gyroscope_bias: std::array::from_fn(|i| estimate(5 + i, p[5 + i])),
            gyroscope_scale: std::array::from_fn(|i| {
                self.free_scale[i].then(|| estimate(SCALE + i, 1.0 + p[SCALE + i]))
            }),
            covariance,
            residual_rms_accelerometer: self.residual_rms[0],
            residual_rms_gyroscope: self.residual_rms[1],
            residual_lag1_autocorrelation: self.autocorrelation,
            max_variance_ratio: self.variance_ratio,
            cost: search.cost,
            runner_up: search.runner_up,
            cost_ratio: search
                .runner_up
                .map_or(f64::INFINITY, |(_, c)| c / search.cost.max(1e-300)),
            intervals,
            iterations: self.iterations,
        }
    }
}
