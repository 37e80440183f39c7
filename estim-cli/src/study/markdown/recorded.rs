//! The `recorded-imu`, `recorded-imu-paired` and `recorded-imu-correlation` tables:
//! the study on the A-KIT training trajectories with their recorded IMU (`estim
//! reproduce --data DIR --trajectory N`, vehicles/akit.toml), never 4 or 13.

use std::path::Path;
use std::sync::Arc;

use estim_core::nalgebra::Vector3;
use estim_learned::BEAMSNET_WINDOW;

use super::{significant, Table};
use crate::study::{
    analyse, least_squares_velocities, Config, FilterSummary, ImuChoice, ImuSource, LearnedSource,
    PairedInterval, PipelineError, Result, Scenario, TrajectoryReport, AKIT_TEST_TRAJECTORIES,
    BEAMSNET, BEAMSNET_NEGLECTED, BEAMSNET_SCALED, BEAMSNET_SENSITIVITY, LS,
};

/// The A-KIT trajectories the tables cover: 1-13 without the test trajectories.
fn training() -> impl Iterator<Item = u32> {
    (1..=13).filter(|n| !AKIT_TEST_TRAJECTORIES.contains(n))
}

/// One training trajectory on its recorded IMU: the report with the vehicle's gate,
/// the report with the gate off, and the output-error correlations.
struct Recorded {
    n: u32,
    gated: TrajectoryReport,
    ungated: TrajectoryReport,
    /// BeamsNet's and least squares': (largest |r|, epochs).
    correlation: [(f64, usize); 2],
}

/// The training trajectories whose folder holds a recorded IMU.
fn reports(config: &Config, data: &Path, learned: &LearnedSource) -> Result<Vec<Recorded>> {
    let mut out = Vec::new();
    for n in training() {
        let scenario =
            Scenario::akit_choosing(data, n, config, config.seed, false, ImuChoice::Auto, None)?;
        let survey = match &scenario.recorded {
            Some(s) if scenario.imu_source == ImuSource::Recorded => s.clone(),
            _ => continue,
        };
        let inputs = learned(&scenario)?;
        let gated = analyse(&scenario, config, Some(&inputs), config.seed)?;
        let mut open = scenario.clone();
        open.recorded = Some(Arc::new(survey.without_gate()?));
        let ungated = analyse(&open, config, Some(&inputs), config.seed)?;
        let ls = least_squares_velocities(&scenario, config);
        out.push(Recorded {
            n,
            gated,
            ungated,
            correlation: [
                output_noise_correlation(&scenario, &inputs.velocities),
                output_noise_correlation(&scenario, &ls),
            ],
        });
    }
    if out.is_empty() {
        return Err(PipelineError::NoData {
            what: "A-KIT training trajectory with a recorded IMU (IMU_trajectoryN.csv)".into(),
        });
    }
    Ok(out)
}

const METHODS: [(&str, &str); 4] = [
    (LS, "LS"),
    (BEAMSNET_NEGLECTED, "BeamsNet, M = 0"),
    (BEAMSNET_SCALED, "BeamsNet, M rho"),
    (BEAMSNET_SENSITIVITY, "BeamsNet, M network"),
];

/// Per trajectory and method: position RMSE (3-D and horizontal), NEES / 9, NIS / 3,
/// gated updates, updates whose joint covariance [[Q, M], [M', R]] was not PSD (used
/// all the same: the navigator's `JointCheck::Report`), the velocity RMSE of the
/// method's source against the DVL; then the paired comparisons over the trajectories
/// (gate off) and the output-error correlations.
///
/// # Errors
/// Missing or bad data files; no training trajectory with a recorded IMU; the
/// pipeline's errors.
pub fn recorded_tables(
    config: &Config,
    data: &Path,
    learned: &LearnedSource,
) -> Result<Vec<Table>> {
    let reports = reports(config, data, learned)?;
    let mut s = String::from(
        "| trajectory | method | position RMSE [m] | horizontal RMSE [m] | NEES / 9 | \
         NIS / 3 | gated | M invalid | velocity RMSE [mm/s] |\n\
         |---|---|---|---|---|---|---|---|---|\n",
    );
    for Recorded { n, gated: r, .. } in &reports {
        for (id, label) in METHODS {
            let Some(f) = r.filters.iter().find(|f| f.id == id) else {
                if r.failures.iter().any(|x| x.id == id) {
                    s.push_str(&format!("| {n} | {label} | stopped | | | | | | |\n"));
                }
                continue;
            };
            let source = if id == LS { LS } else { BEAMSNET };
            let velocity = r.velocity.get(source).map_or(f64::NAN, |m| 1000.0 * m.rmse);
            s.push_str(&format!(
                "| {n} | {label} | {} | {} | {} | {} | {} of {} | {} | {} |\n",
                significant(f.position_error_m.rmse, 3),
                significant(f.horizontal_position_error_m.rmse, 3),
                significant(f.nees_average / f.nees_states as f64, 3),
                significant(f.nis_average / 3.0, 3),
                f.updates_rejected,
                f.updates_rejected + f.updates_accepted,
                f.joint_invalid_updates,
                significant(velocity, 2),
            ));
        }
    }
    let rows = Table {
        name: "recorded-imu",
        markdown: s,
    };
    Ok(vec![
        rows,
        paired_table(&reports),
        correlation_table(&reports),
    ])
}

/// A figure of a filter's summary.
type Pick = dyn Fn(&FilterSummary) -> f64;

/// The value of filter `id` in report `r` by `pick`.
fn value(r: &TrajectoryReport, id: &str, pick: &Pick) -> Option<f64> {
    r.filters.iter().find(|f| f.id == id).map(pick)
}

/// One paired row: the t interval of `d`'s mean.
fn paired_row(s: &mut String, label: &str, d: &[f64]) {
    let i = PairedInterval::of(d, 0.95);
    s.push_str(&format!(
        "| {label} | {} | {} | [{}, {}] |\n",
        i.n,
        significant(i.mean, 2),
        significant(i.lo, 2),
        significant(i.hi, 2)
    ));
}

/// Paired differences over the trajectories with the gate off (95 % t intervals):
/// horizontal RMSE and NEES / 9 of BeamsNet (M = 0) against LS and of each M against
/// M = 0, then the paper's metric (percent lower time-averaged std of velocity and
/// misalignment) of each M against M = 0.
fn paired_table(reports: &[Recorded]) -> Table {
    let mut s = String::from("| comparison | n | mean | 95 % interval |\n|---|---|---|---|\n");
    let horizontal = |f: &FilterSummary| f.horizontal_position_error_m.rmse;
    let nees = |f: &FilterSummary| f.nees_average / f.nees_states as f64;
    let pairs = [
        (BEAMSNET_NEGLECTED, LS, "BeamsNet (M = 0) minus LS"),
        (BEAMSNET_SCALED, BEAMSNET_NEGLECTED, "M rho minus M = 0"),
        (
            BEAMSNET_SENSITIVITY,
            BEAMSNET_NEGLECTED,
            "M network minus M = 0",
        ),
    ];
    let metrics: [(&str, &Pick); 2] = [("horizontal RMSE [m]", &horizontal), ("NEES / 9", &nees)];
    for (what, pick) in metrics {
        for (a, b, label) in pairs {
            let d: Vec<f64> = reports
                .iter()
                .filter_map(|x| Some(value(&x.ungated, a, pick)? - value(&x.ungated, b, pick)?))
                .collect();
            paired_row(&mut s, &format!("{what}: {label}"), &d);
        }
    }
    for (id, label) in [
        (BEAMSNET_SCALED, "M rho"),
        (BEAMSNET_SENSITIVITY, "M network"),
    ] {
        for group in ["velocity", "misalignment"] {
            let d: Vec<f64> = reports
                .iter()
                .filter_map(|x| {
                    x.ungated
                        .improvements
                        .iter()
                        .find(|i| i.id == id)
                        .and_then(|i| i.groups.get(group))
                        .map(|v| v.time_average_percent)
                })
                .collect();
            paired_row(
                &mut s,
                &format!("{group} std, % lower with {label} than with M = 0 (time average)"),
                &d,
            );
        }
    }
    Table {
        name: "recorded-imu-paired",
        markdown: s,
    }
}

/// Over the DVL epochs with a value: the error of `velocities` against the DVL's
/// velocity (3 axes) and the recorded IMU minus the reference's error-free IMU
/// (`Scenario::clean_imu`, from the reference spline), averaged over the
/// [`BEAMSNET_WINDOW`] samples before the update (6 channels); the largest |Pearson
/// correlation| over the 18 pairs, and the count of epochs.
fn output_noise_correlation(
    scenario: &Scenario,
    velocities: &[Option<Vector3<f64>>],
) -> (f64, usize) {
    let n = BEAMSNET_WINDOW;
    let mut errors: Vec<[f64; 3]> = Vec::new();
    let mut noise: Vec<[f64; 6]> = Vec::new();
    for (epoch, v) in scenario.dvl.iter().zip(velocities) {
        let (Some(v), Some(start)) = (v, epoch.imu_index.checked_sub(n)) else {
            continue;
        };
        let (Some(recorded), Some(clean)) = (
            scenario.imu.get(start..epoch.imu_index),
            scenario.clean_imu.get(start..epoch.imu_index),
        ) else {
            continue;
        };
        let mut mean = [0.0; 6];
        for (r, c) in recorded.iter().zip(clean) {
            let f = r.specific_force - c.specific_force;
            let w = r.angular_rate - c.angular_rate;
            for i in 0..3 {
                mean[i] += f[i] / n as f64;
                mean[3 + i] += w[i] / n as f64;
            }
        }
        let e = v - epoch.reference_velocity;
        errors.push([e.x, e.y, e.z]);
        noise.push(mean);
    }
    let largest = (0..3)
        .flat_map(|i| (0..6).map(move |j| (i, j)))
        .map(|(i, j)| {
            let a: Vec<f64> = errors.iter().map(|e| e[i]).collect();
            let b: Vec<f64> = noise.iter().map(|x| x[j]).collect();
            pearson(&a, &b).abs()
        })
        .fold(0.0, f64::max);
    (largest, errors.len())
}

/// Pearson's correlation coefficient (NaN for fewer than 3 values or a constant one).
fn pearson(a: &[f64], b: &[f64]) -> f64 {
    if a.len() < 3 || a.len() != b.len() {
        return f64::NAN;
    }
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma).powi(2);
        sbb += (y - mb).powi(2);
    }
    sab / (saa * sbb).sqrt()
}

/// Normal quantile at 1 - 0.01 / 36: the two-sided 1 % level of the largest of 18
/// null correlations (Bonferroni), times sqrt(n) (Python:
/// `statistics.NormalDist().inv_cdf(1 - 0.01 / 36)`).
const NULL_LEVEL_Z: f64 = 3.452_432_937_387_534;

/// Per trajectory: the largest |correlation| of BeamsNet's and least squares' output
/// error with the window's IMU noise, against the 99 % level of the largest of 18
/// independent null correlations, [`NULL_LEVEL_Z`] / sqrt(n). Least squares does not
/// see the IMU: its row is the control.
fn correlation_table(reports: &[Recorded]) -> Table {
    let mut s = String::from(
        "| trajectory | epochs | BeamsNet max abs r | LS max abs r | 99 % null level |\n\
         |---|---|---|---|---|\n",
    );
    for x in reports {
        let [(b, n), (l, _)] = x.correlation;
        s.push_str(&format!(
            "| {} | {n} | {} | {} | {} |\n",
            x.n,
            significant(b, 2),
            significant(l, 2),
            significant(NULL_LEVEL_Z / (n as f64).sqrt(), 2)
        ));
    }
    Table {
        name: "recorded-imu-correlation",
        markdown: s,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pearson's r against a hand-computed case: y = 2x + 1 gives 1, y = -x gives -1,
    /// and [1, 2, 3] with [1, 3, 2] gives 0.5 (sum of products of deviations 1 over
    /// sqrt(2 * 2)).
    #[test]
    fn pearson_matches_hand_values() {
        let x = [1.0, 2.0, 3.0];
        assert!((pearson(&x, &[3.0, 5.0, 7.0]) - 1.0).abs() < 1e-15);
        assert!((pearson(&x, &[-1.0, -2.0, -3.0]) + 1.0).abs() < 1e-15);
        assert!((pearson(&x, &[1.0, 3.0, 2.0]) - 0.5).abs() < 1e-15);
        assert!(pearson(&x[..2], &[1.0, 2.0]).is_nan());
    }
}
