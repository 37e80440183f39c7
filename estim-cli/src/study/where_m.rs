//! "Where M matters": a simulation study of when the exact cross-covariance M between
//! the INS process noise and a learned velocity sensor's error changes the filter.
//!
//! The sweep: IMU grade (the presets of [`GRADES`], sources in their doc comments in
//! `estim_ins::ImuSpec`) x DVL noise ([`DvlNoise`]) x sensor type ([`SensorKind`]).
//! Per cell, seeded simulated missions are filtered twice, with the exact M (from the
//! sensor's own Jacobian-vector products through estim-learned's generic
//! [`LearnedCrossCovariance`]) and with M neglected, and the run-averaged NEES and the
//! filter's velocity and attitude standard deviations are compared.
//!
//! The sensors are analytic stand-ins for networks with the named behaviour
//! ([`StandInNetwork`]), not trained networks: their error is known in closed form, so
//! the exact M and R are known and the filter with them should be consistent.

mod gyro_stand_in;
mod measurements;
mod stand_in;

use estim_core::consistency::chi_square_band;
use estim_core::nalgebra::Matrix3;
use estim_ins::{ATT, ERROR_STATES, VEL};
use rayon::prelude::*;
use serde::Serialize;

use super::{
    run_filter_per_epoch_noise, Config, CrossSource, FilterRun, MeasurementSet, PipelineError,
    Result, Scenario,
};
use measurements::stand_in_measurements;

/// The IMU grades swept (preset names of `imu.preset`; numbers and sources in the doc
/// comments of `estim_ins::ImuSpec::navigation_grade_fog`, `tactical_mems`,
/// `consumer_mems` and `akit_observed`).
pub const GRADES: [&str; 4] = [
    "navigation_grade_fog",
    "tactical_mems",
    "consumer_mems",
    "akit_observed",
];

/// Per-beam noise std of the beam-level DVL noise \[m/s\]: the BeamsNet protocol's
/// `0.042**2 * randn` (shared DESIGN.md, "Pitfalls").
pub const BEAM_NOISE_STD: f64 = 0.042 * 0.042;

/// Velocity noise std per axis of the mismatch-level DVL noise \[m/s\]: the A-KIT
/// DVL-vs-reference mismatch fitted on the training trajectories (`estim dvl
/// mismatch`, `dvl.akit_reference_mismatch_std_mps`).
pub const MISMATCH_STD: f64 = 0.017;

/// Duration of each simulated mission of the study \[s\].
pub const MISSION_DURATION_S: f64 = 120.0;

/// Relative change of NEES or a std above which a cell is flagged.
pub const FLAG_THRESHOLD: f64 = 0.10;

/// The DVL noise of a cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DvlNoise {
    /// Independent noise of [`BEAM_NOISE_STD`] on each of the four beams, solved by least
    /// squares: R = σ_b² (A'A)⁻¹.
    Beam,
    /// The beam noise plus a velocity noise of [`MISMATCH_STD`] per axis:
    /// R = σ_m² I + σ_b² (A'A)⁻¹.
    Mismatch,
}

impl DvlNoise {
    /// Both levels.
    pub const ALL: [Self; 2] = [Self::Beam, Self::Mismatch];

    /// Velocity noise std per axis added before the beams are formed \[m/s\].
    fn velocity_std(self) -> f64 {
        match self {
            Self::Beam => 0.0,
            Self::Mismatch => MISMATCH_STD,
        }
    }

    /// Short label.
    pub fn label(self) -> &'static str {
        match self {
            Self::Beam => "beam 0.00176 m/s",
            Self::Mismatch => "mismatch 0.017 m/s",
        }
    }
}

/// The sensor type of a cell: what the stand-in network does with the IMU window.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SensorKind {
    /// The velocity from this epoch's beams; reads the IMU window but its output does
    /// not depend on it (BeamsNet under its protocol): M = 0 by construction.
    BeamsOnly,
    /// The velocity solved from the beams one DVL period (L IMU steps) ago, carried
    /// forward to now by integrating the accelerometer samples of the window it was
    /// fed: its error holds +dt Σ n of the same samples whose noise enters the INS
    /// velocity error as -dt Σ n.
    DeadReckoning,
    /// As `DeadReckoning`, but half of the carried increment comes from the
    /// accelerometer and half from a noise-free motion model: error +dt Σ n / 2.
    HalfDeadReckoning,
    /// As `DeadReckoning`, with the attitude also dead-reckoned from the window's
    /// gyroscope samples (from the attitude at the beams' epoch): it shares the
    /// accelerometer and the gyroscope white noise ([`GyroStandIn`]).
    GyroDeadReckoning,
}

impl SensorKind {
    /// The three types.
    pub const ALL: [Self; 4] = [
        Self::BeamsOnly,
        Self::DeadReckoning,
        Self::HalfDeadReckoning,
        Self::GyroDeadReckoning,
    ];

    /// Gain α on the integrated accelerometer samples.
    pub fn imu_gain(self) -> f64 {
        match self {
            Self::BeamsOnly => 0.0,
            Self::DeadReckoning | Self::GyroDeadReckoning => 1.0,
            Self::HalfDeadReckoning => 0.5,
        }
    }

    /// Whether the beams are those of the previous DVL epoch (carried forward).
    fn carries(self) -> bool {
        !matches!(self, Self::BeamsOnly)
    }

    /// Short label.
    pub fn label(self) -> &'static str {
        match self {
            Self::BeamsOnly => "beams only",
            Self::DeadReckoning => "dead-reckons IMU",
            Self::HalfDeadReckoning => "half IMU",
            Self::GyroDeadReckoning => "dead-reckons IMU + gyro",
        }
    }
}

/// The configuration of the study's missions for `grade`: `base` with that IMU preset
/// (`base`'s per-sensor overrides, if any, still apply), the mission cut to
/// `duration_s` and the innovation gate off (the two filters of a pair then fuse the
/// same updates).
pub fn cell_config(base: &Config, grade: &str, duration_s: f64) -> Config {
    let mut config = base.clone();
    config.imu.preset = grade.into();
    config.mission.duration_s = duration_s;
    config.filter.gate_probability = 0.0;
    config
}

/// The two filter runs of one mission and one sensor, and the sensor's mean
/// output / IMU-error correlation.
#[derive(Debug, Clone)]
pub struct PairedRuns {
    /// Exact M.
    pub exact: FilterRun,
    /// M neglected.
    pub neglected: FilterRun,
    /// Mean over the measured epochs of the output / IMU-error correlation.
    pub correlation: f64,
}

/// Filter one scenario with `kind`'s measurements, exact M and M neglected.
pub fn paired_runs(
    kind: SensorKind,
    noise: DvlNoise,
    scenario: &Scenario,
    config: &Config,
    seed: u64,
) -> Result<PairedRuns> {
    let sensor = stand_in_measurements(kind, noise, scenario, config, seed)?;
    // The set's R only configures the navigator: every measured epoch has its own R.
    let set = MeasurementSet {
        velocities: sensor.velocities,
        noise_covariance: Matrix3::identity() * MISMATCH_STD.powi(2),
    };
    let neglected = run_filter_per_epoch_noise(
        "m_neglected",
        scenario,
        config,
        &set,
        &sensor.noise_covariances,
        &CrossSource::Zero,
        seed,
    )?;
    // M = 0 exactly (beams only): the exact-M filter is the same filter.
    let exact = if sensor
        .cross_covariances
        .iter()
        .all(|m| m.iter().all(|v| *v == 0.0))
    {
        let mut run = neglected.clone();
        run.id = "m_exact".into();
        run
    } else {
        run_filter_per_epoch_noise(
            "m_exact",
            scenario,
            config,
            &set,
            &sensor.noise_covariances,
            &CrossSource::PerEpoch(sensor.cross_covariances),
            seed,
        )?
    };
    let correlation = if sensor.output_imu_correlation.is_empty() {
        0.0
    } else {
        sensor.output_imu_correlation.iter().sum::<f64>()
            / sensor.output_imu_correlation.len() as f64
    };
    Ok(PairedRuns {
        exact,
        neglected,
        correlation,
    })
}

/// One filter's statistics over the runs of a cell.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct FilterStats {
    /// NEES (15 states) averaged over the runs at each DVL epoch, then over the epochs.
    pub nees_average: f64,
    /// Share of the DVL epochs whose run-averaged NEES lies in the cell's `nees_band`
    /// \[%\].
    pub nees_epochs_in_band_percent: f64,
    /// sqrt(P_vN + P_vE + P_vD) averaged over runs and epochs \[m/s\].
    pub velocity_std_mps: f64,
    /// sqrt(P_ψN + P_ψE + P_ψD) averaged over runs and epochs \[deg\].
    pub attitude_std_deg: f64,
    /// Per run the RMSE over its epochs of |velocity error|, averaged over the runs
    /// \[m/s\].
    pub velocity_rmse_mps: f64,
    /// Mean over runs, epochs and the three axes of e_v,i² / P_v,ii, the velocity
    /// error normalised by its own variance (1 for a consistent filter whatever the
    /// correlations; the velocity part of the NEES, which M acts on first) \[-\].
    pub velocity_normalised_error: f64,
}

fn root_sum(diagonal: &[f64; 15], first: usize) -> f64 {
    (diagonal[first] + diagonal[first + 1] + diagonal[first + 2]).sqrt()
}

impl FilterStats {
    fn of(runs: &[&FilterRun], band: &estim_core::consistency::ChiSquareBand) -> Self {
        let epochs = runs.iter().map(|r| r.nees.len()).min().unwrap_or(0);
        let n = runs.len() as f64;
        let averages: Vec<f64> = (0..epochs)
            .map(|e| runs.iter().map(|r| r.nees[e]).sum::<f64>() / n)
            .collect();
        let finite: Vec<f64> = averages.iter().copied().filter(|a| a.is_finite()).collect();
        let in_band = averages.iter().filter(|a| band.contains(**a)).count();
        let mean_over = |f: &dyn Fn(&FilterRun) -> f64| runs.iter().map(|r| f(r)).sum::<f64>() / n;
        let per_epoch_mean = |run: &FilterRun, g: &dyn Fn(&[f64; 15]) -> f64| {
            run.covariance_diagonal.iter().map(g).sum::<f64>()
                / run.covariance_diagonal.len().max(1) as f64
        };
        Self {
            nees_average: finite.iter().sum::<f64>() / finite.len().max(1) as f64,
            nees_epochs_in_band_percent: 100.0 * in_band as f64 / epochs.max(1) as f64,
            velocity_std_mps: mean_over(&|r| per_epoch_mean(r, &|d| root_sum(d, VEL))),
            attitude_std_deg: mean_over(&|r| per_epoch_mean(r, &|d| root_sum(d, ATT).to_degrees())),
            velocity_rmse_mps: mean_over(&|r| {
                let s: f64 = r.velocity_error.iter().map(|e| e * e).sum();
                (s / r.velocity_error.len().max(1) as f64).sqrt()
            }),
            velocity_normalised_error: mean_over(&|r| {
                let s: f64 = r
                    .axis_error
                    .iter()
                    .zip(&r.covariance_diagonal)
                    .map(|(e, p)| (0..3).map(|i| e[3 + i].powi(2) / p[VEL + i]).sum::<f64>())
                    .sum();
                s / (3 * r.axis_error.len().max(1)) as f64
            }),
        }
    }
}

/// One cell of the sweep.
#[derive(Debug, Clone, Serialize)]
pub struct Cell {
    /// IMU preset.
    pub imu: String,
    /// DVL noise level.
    pub dvl_noise: DvlNoise,
    /// Sensor type.
    pub sensor: SensorKind,
    /// Gain α of the sensor on the integrated accelerometer noise.
    pub imu_gain: f64,
    /// Mean over runs and measured epochs of the largest output / IMU-error
    /// correlation coefficient.
    pub output_imu_correlation: f64,
    /// 95 % band of a run-average of chi-square(15) at one epoch.
    pub nees_band: [f64; 2],
    /// The filter with the exact M.
    pub exact: FilterStats,
    /// The filter with M neglected.
    pub neglected: FilterStats,
    /// (exact - neglected) / neglected of the NEES average.
    pub nees_change: f64,
    /// The same of the velocity std.
    pub velocity_std_change: f64,
    /// The same of the attitude std.
    pub attitude_std_change: f64,
    /// Some |change| > [`FLAG_THRESHOLD`].
    pub m_matters: bool,
}

/// The study's report.
#[derive(Debug, Clone, Serialize)]
pub struct WhereM {
    /// Missions per cell.
    pub runs: usize,
    /// Seed of the first mission (missions use seeds S..S+runs; every cell of a grade
    /// sees the same missions).
    pub first_seed: u64,
    /// Mission duration \[s\].
    pub mission_duration_s: f64,
    /// DVL epochs per mission.
    pub epochs: usize,
    /// The cells, grade-major.
    pub cells: Vec<Cell>,
}

fn relative(exact: f64, neglected: f64) -> f64 {
    (exact - neglected) / neglected
}

/// Run the sweep: for every grade, `runs` missions (seeds `first_seed..`, in parallel),
/// each filtered by every (DVL noise, sensor) pair with exact and neglected M.
/// `grades` and `sensors` restrict the sweep (e.g. one cell in a test); `tick` is
/// called after each mission of each grade.
pub fn where_m(
    base: &Config,
    grades: &[&str],
    noises: &[DvlNoise],
    sensors: &[SensorKind],
    runs: usize,
    first_seed: u64,
    tick: &(dyn Fn() + Sync),
) -> Result<WhereM> {
    if runs == 0 {
        return Err(PipelineError::Argument {
            flag: "--runs".into(),
            reason: "must be at least 1".into(),
        });
    }
    let band = chi_square_band(ERROR_STATES, runs, 0.95)?;
    let pairs: Vec<(DvlNoise, SensorKind)> = noises
        .iter()
        .flat_map(|n| sensors.iter().map(move |s| (*n, *s)))
        .collect();
    let mut cells = Vec::new();
    let mut epochs = 0;
    for grade in grades {
        let config = cell_config(base, grade, base.mission.duration_s);
        // runs x pairs
        let missions: Vec<Vec<PairedRuns>> = (0..runs)
            .into_par_iter()
            .map(|i| {
                let seed = first_seed + i as u64;
                let scenario = Scenario::simulated(&config, seed)?;
                let out = pairs
                    .iter()
                    .map(|(noise, kind)| {
                        paired_runs(*kind, *noise, &scenario, &config, seed).map_err(|e| {
                            PipelineError::Run {
                                run: format!("{grade}, {noise:?} DVL noise, {kind:?}, seed {seed}"),
                                error: Box::new(e),
                            }
                        })
                    })
                    .collect::<Result<Vec<_>>>();
                tick();
                out
            })
            .collect::<Result<_>>()?;
        for (p, (noise, kind)) in pairs.iter().enumerate() {
            let exact_runs: Vec<&FilterRun> = missions.iter().map(|m| &m[p].exact).collect();
            let neglected_runs: Vec<&FilterRun> =
                missions.iter().map(|m| &m[p].neglected).collect();
            epochs = exact_runs.first().map_or(0, |r| r.nees.len());
            let exact = FilterStats::of(&exact_runs, &band);
            let neglected = FilterStats::of(&neglected_runs, &band);
            let nees_change = relative(exact.nees_average, neglected.nees_average);
            let velocity_std_change = relative(exact.velocity_std_mps, neglected.velocity_std_mps);
            let attitude_std_change = relative(exact.attitude_std_deg, neglected.attitude_std_deg);
            cells.push(Cell {
                imu: (*grade).into(),
                dvl_noise: *noise,
                sensor: *kind,
                imu_gain: kind.imu_gain(),
                output_imu_correlation: missions.iter().map(|m| m[p].correlation).sum::<f64>()
                    / runs as f64,
                nees_band: [band.lower, band.upper],
                exact,
                neglected,
                nees_change,
                velocity_std_change,
                attitude_std_change,
                m_matters: [nees_change, velocity_std_change, attitude_std_change]
                    .iter()
                    .any(|c| c.abs() > FLAG_THRESHOLD),
            });
        }
    }
    Ok(WhereM {
        runs,
        first_seed,
        mission_duration_s: base.mission.duration_s,
        epochs,
        cells,
    })
}

/// The markdown table of the report.
pub fn markdown(report: &WhereM) -> String {
    let mut s = String::from(
        "| IMU | DVL noise | sensor | corr. | NEES exact M | NEES M neglected | NEES change | \
         vel. e²/P exact / neglected | vel. std exact [m/s] | vel. std change | \
         att. std exact [deg] | att. std change | \\|change\\| > 10 % |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    let pct = |c: f64| format!("{:+.1} %", 100.0 * c);
    for c in &report.cells {
        s.push_str(&format!(
            "| {} | {} | {} | {:.2} | {:.2} ({:.0} % in band) | {:.2} ({:.0} % in band) | {} | \
             {:.2} / {:.2} | {:.5} | {} | {:.4} | {} | {} |\n",
            c.imu,
            c.dvl_noise.label(),
            c.sensor.label(),
            c.output_imu_correlation,
            c.exact.nees_average,
            c.exact.nees_epochs_in_band_percent,
            c.neglected.nees_average,
            c.neglected.nees_epochs_in_band_percent,
            pct(c.nees_change),
            c.exact.velocity_normalised_error,
            c.neglected.velocity_normalised_error,
            c.exact.velocity_std_mps,
            pct(c.velocity_std_change),
            c.exact.attitude_std_deg,
            pct(c.attitude_std_change),
            if c.m_matters { "yes" } else { "no" },
        ));
    }
    s
}

#[cfg(test)]
mod tests;
