//! The `recorded-imu` and `recorded-imu-paired` tables: the study on the A-KIT
//! training trajectories with their recorded IMU (`estim reproduce --data DIR
//! --trajectory N`, vehicles/akit.toml), never 4 or 13.

use std::path::Path;

use super::{significant, Table};
use crate::study::{
    analyse, Config, FilterSummary, ImuChoice, ImuSource, LearnedSource, PairedInterval,
    PipelineError, Result, Scenario, TrajectoryReport, AKIT_TEST_TRAJECTORIES, BEAMSNET,
    BEAMSNET_NEGLECTED, BEAMSNET_SCALED, BEAMSNET_SENSITIVITY, LS,
};

/// The A-KIT trajectories the tables cover: 1-13 without the test trajectories.
fn training() -> impl Iterator<Item = u32> {
    (1..=13).filter(|n| !AKIT_TEST_TRAJECTORIES.contains(n))
}

/// The reports of the training trajectories whose folder holds a recorded IMU.
fn reports(
    config: &Config,
    data: &Path,
    learned: &LearnedSource,
) -> Result<Vec<(u32, TrajectoryReport)>> {
    let mut out = Vec::new();
    for n in training() {
        let scenario =
            Scenario::akit_choosing(data, n, config, config.seed, false, ImuChoice::Auto, None)?;
        if scenario.imu_source != ImuSource::Recorded {
            continue;
        }
        let inputs = learned(&scenario)?;
        out.push((n, analyse(&scenario, config, Some(&inputs), config.seed)?));
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
/// all the same: the navigator's `JointCheck::Report`), the velocity RMSE of the method's source against the DVL; then the
/// paired comparisons over the trajectories.
///
/// # Errors
/// Missing or bad data files; the pipeline's errors.
pub fn recorded_tables(
    config: &Config,
    data: &Path,
    learned: &LearnedSource,
) -> Result<Vec<Table>> {
    let reports = reports(config, data, learned)?;
    let mut s = String::from(
        "| trajectory | method | position RMSE [m] | horizontal RMSE [m] | NEES / 9 | \
         NIS / 3 | gated | M invalid | velocity RMSE [mm/s] |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    for (n, r) in &reports {
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
    Ok(vec![rows, paired_table(&reports)?])
}

/// The value of filter `id` in report `r` by `pick`.
fn value(r: &TrajectoryReport, id: &str, pick: impl Fn(&FilterSummary) -> f64) -> Option<f64> {
    r.filters.iter().find(|f| f.id == id).map(pick)
}

/// Paired differences over the trajectories (95 % t intervals): horizontal RMSE of
/// BeamsNet (M = 0) against LS, and the paper's metric (percent lower time-averaged
/// std of velocity and misalignment) of each M against M = 0.
fn paired_table(reports: &[(u32, TrajectoryReport)]) -> Result<Table> {
    let mut s = String::from("| comparison | n | mean | 95 % interval |\n|---|---|---|---|\n");
    let row = |s: &mut String, label: &str, d: Vec<f64>| {
        let i = PairedInterval::of(&d, 0.95);
        s.push_str(&format!(
            "| {label} | {} | {} | [{}, {}] |\n",
            i.n,
            significant(i.mean, 2),
            significant(i.lo, 2),
            significant(i.hi, 2)
        ));
    };
    let horizontal = |f: &FilterSummary| f.horizontal_position_error_m.rmse;
    let d: Vec<f64> = reports
        .iter()
        .filter_map(|(_, r)| {
            Some(value(r, BEAMSNET_NEGLECTED, horizontal)? - value(r, LS, horizontal)?)
        })
        .collect();
    row(&mut s, "horizontal RMSE [m]: BeamsNet (M = 0) minus LS", d);
    for (id, label) in [
        (BEAMSNET_SCALED, "M rho"),
        (BEAMSNET_SENSITIVITY, "M network"),
    ] {
        for group in ["velocity", "misalignment"] {
            let d: Vec<f64> = reports
                .iter()
                .filter_map(|(_, r)| {
                    r.improvements
                        .iter()
                        .find(|i| i.id == id)
                        .and_then(|i| i.groups.get(group))
                        .map(|v| v.time_average_percent)
                })
                .collect();
            row(
                &mut s,
                &format!("{group} std, % lower with {label} than with M = 0 (time average)"),
                d,
            );
        }
    }
    if reports.is_empty() {
        return Err(PipelineError::Invalid(
            "no A-KIT training trajectory with a recorded IMU (IMU_trajectoryN.csv)".into(),
        ));
    }
    Ok(Table {
        name: "recorded-imu-paired",
        markdown: s,
    })
}
