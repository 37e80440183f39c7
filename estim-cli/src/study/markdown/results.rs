//! The tables of the default configuration's runs: `velocity`, `filters`, `paper-std`
//! and `rho` on A-KIT trajectories 4 and 13 and the simulated mission
//! ([`results_tables`]), and the `montecarlo` table ([`monte_carlo_table`]).

use std::path::Path;

use super::{one_decimal, significant, thousands, Table, AKIT_TRAJECTORIES};
use super::{MONTE_CARLO_FIRST_SEED, MONTE_CARLO_RUNS};
use crate::study::report::{
    BEAMSNET, BEAMSNET_NEGLECTED, BEAMSNET_SCALED, BEAMSNET_SENSITIVITY, LS,
};
use crate::study::{
    analyse, apply_faults, monte_carlo, Config, FilterRun, FilterSummary, Improvement,
    LearnedInputs, LearnedSource, PaperMBasis, PipelineError, Result, Scenario, TrajectoryReport,
    ORACLE_NEGLECTED, ORACLE_SCALED, ORACLE_TRUE_M,
};

/// The committed BeamsNet models as the pipeline's learned sensor, with M from the
/// network's sensitivity, per IMU source ([`crate::study::committed_beamsnet`]: what
/// `estim reproduce` and `estim montecarlo` use).
pub fn default_beamsnet(config: &Config) -> Result<Box<LearnedSource>> {
    crate::study::committed_beamsnet(config)
}

/// One data set of the results tables: the report on the configured basis and the
/// report with the paper's M on the other basis.
pub(super) struct DataSet {
    pub(super) label: String,
    pub(super) accumulated: TrajectoryReport,
    pub(super) per_step: TrajectoryReport,
}

fn with_basis(config: &Config, basis: PaperMBasis) -> Config {
    let mut c = config.clone();
    c.filter.paper_m_basis = basis;
    c
}

pub(super) fn data_set(
    label: String,
    scenario: &mut Scenario,
    config: &Config,
    learned: &LearnedSource,
) -> Result<DataSet> {
    apply_faults(scenario, &config.faults, config.seed)?;
    let inputs: LearnedInputs = learned(scenario)?;
    let accumulated = analyse(
        scenario,
        &with_basis(config, PaperMBasis::Accumulated),
        Some(&inputs),
        config.seed,
    )?;
    let per_step = analyse(
        scenario,
        &with_basis(config, PaperMBasis::PerStep),
        Some(&inputs),
        config.seed,
    )?;
    Ok(DataSet {
        label,
        accumulated,
        per_step,
    })
}

pub(super) fn filter<'a>(report: &'a TrajectoryReport, name: &str) -> Result<&'a FilterSummary> {
    report
        .filters
        .iter()
        .find(|f| f.id == name)
        .ok_or_else(|| PipelineError::Missing {
            within: report.name.clone(),
            what: format!("filter {name:?}"),
        })
}

/// The `velocity`, `filters`, `paper-std` and `rho` tables: `config` on A-KIT
/// trajectories 4 and 13 under `data` and on the simulated mission, with `learned`.
///
/// # Errors
/// Missing or bad data files; the pipeline's errors.
pub fn results_tables(config: &Config, data: &Path, learned: &LearnedSource) -> Result<Vec<Table>> {
    let mut sets = Vec::new();
    for n in AKIT_TRAJECTORIES {
        let mut scenario = Scenario::akit(data, n, config, config.seed)?;
        sets.push(data_set(
            format!("A-KIT {n}"),
            &mut scenario,
            config,
            learned,
        )?);
    }
    let mut simulated = Scenario::simulated(config, config.seed)?;
    sets.push(data_set(
        "simulated".into(),
        &mut simulated,
        config,
        learned,
    )?);
    Ok(vec![
        velocity_table(&sets)?,
        filters_table(&sets, config.filter.rho)?,
        paper_std_table(&sets, config.filter.rho)?,
        rho_table(&sets, config.filter.rho)?,
    ])
}

/// The rows of the `velocity` table of one data set: LS, then BeamsNet if present, each
/// with [RMSE, MAE, R^2, VAF, RMSE change against LS in %] (NaN for LS itself).
pub(super) fn velocity_rows(set: &DataSet) -> Result<Vec<(&'static str, [f64; 5])>> {
    let v = &set.accumulated.velocity;
    let ls = v.get(LS).ok_or_else(|| PipelineError::Missing {
        within: set.label.clone(),
        what: "least-squares velocity".into(),
    })?;
    let mut rows = Vec::new();
    for (method, m) in [("LS", Some(ls)), ("BeamsNet", v.get(BEAMSNET))] {
        let Some(m) = m else { continue };
        let versus = if method == "LS" {
            f64::NAN
        } else {
            100.0 * (m.rmse - ls.rmse) / ls.rmse
        };
        rows.push((method, [m.rmse, m.mae, m.r2, m.vaf, versus]));
    }
    Ok(rows)
}

fn velocity_table(sets: &[DataSet]) -> Result<Table> {
    let mut s = String::from(
        "| data | method | RMSE [m/s] | MAE [m/s] | R^2 | VAF [%] | RMSE vs LS |\n\
         |---|---|---|---|---|---|---|\n",
    );
    for set in sets {
        for (method, [rmse, mae, r2, vaf, versus]) in velocity_rows(set)? {
            let versus = if versus.is_finite() {
                format!("{} %", one_decimal(versus))
            } else {
                String::new()
            };
            s.push_str(&format!(
                "| {} | {method} | {rmse:.6} | {mae:.6} | {r2:.6} | {vaf:.4} | {versus} |\n",
                set.label
            ));
        }
    }
    Ok(Table {
        name: "velocity",
        markdown: s,
    })
}

/// The rows of the `filters` table (label, filter id, on the per-step basis).
pub(super) fn filter_rows(rho: f64) -> [(String, &'static str, bool); 5] {
    [
        ("LS".to_string(), LS, false),
        (
            "BeamsNet, M neglected".to_string(),
            BEAMSNET_NEGLECTED,
            false,
        ),
        (
            format!("BeamsNet, M = rho {rho} (Q accumulated over the interval)"),
            BEAMSNET_SCALED,
            false,
        ),
        (
            format!("BeamsNet, M = rho {rho} (per-step Q_k)"),
            BEAMSNET_SCALED,
            true,
        ),
        (
            "BeamsNet, M from network".to_string(),
            BEAMSNET_SENSITIVITY,
            false,
        ),
    ]
}

fn filters_table(sets: &[DataSet], rho: f64) -> Result<Table> {
    let mut s = String::from(
        "| data | filter | position [m] | velocity [m/s] | NEES (15) | NEES 95 % band | P not PD [epochs] | updates gated |\n\
         |---|---|---|---|---|---|---|---|\n",
    );
    for set in sets {
        let rows = [
            ("LS".to_string(), filter(&set.accumulated, LS)?),
            (
                "BeamsNet, M neglected".to_string(),
                filter(&set.accumulated, BEAMSNET_NEGLECTED)?,
            ),
            (
                format!("BeamsNet, M = rho {rho} (Q accumulated over the interval)"),
                filter(&set.accumulated, BEAMSNET_SCALED)?,
            ),
            (
                format!("BeamsNet, M = rho {rho} (per-step Q_k)"),
                filter(&set.per_step, BEAMSNET_SCALED)?,
            ),
            (
                "BeamsNet, M from network".to_string(),
                filter(&set.accumulated, BEAMSNET_SENSITIVITY)?,
            ),
        ];
        for (name, f) in rows {
            s.push_str(&format!(
                "| {} | {name} | {:.2} / {:.2} | {:.3} / {:.3} | {} | {:.1}-{:.1} | {} | {} / {} |\n",
                set.label,
                f.position_error_m.rmse,
                f.position_error_m.final_value,
                f.velocity_error_mps.rmse,
                f.velocity_error_mps.final_value,
                significant(f.nees_average, 3),
                f.nees_band[0],
                f.nees_band[1],
                thousands(f.covariance_not_positive_definite_epochs),
                f.updates_rejected,
                f.updates_accepted + f.updates_rejected,
            ));
        }
    }
    Ok(Table {
        name: "filters",
        markdown: s,
    })
}

/// Whether a time-averaged improvement meets the paper's "more than 10 %".
fn meets_paper(percent: f64) -> bool {
    percent > 10.0
}

/// The rows of the `paper-std` table of one data set: (M label, its improvement over
/// M neglected).
pub(super) fn paper_rows(set: &DataSet, rho: f64) -> Result<Vec<(String, Improvement)>> {
    let find = |report: &TrajectoryReport, variant: &str| {
        report
            .improvements
            .iter()
            .find(|i| i.id == variant)
            .cloned()
            .ok_or_else(|| PipelineError::Missing {
                within: set.label.clone(),
                what: format!("improvement of {variant}"),
            })
    };
    Ok(vec![
        (
            format!("rho {rho}, Q accumulated over the interval"),
            find(&set.accumulated, BEAMSNET_SCALED)?,
        ),
        (
            format!("rho {rho}, per-step Q_k"),
            find(&set.per_step, BEAMSNET_SCALED)?,
        ),
        (
            "from the network's sensitivity".to_string(),
            find(&set.accumulated, BEAMSNET_SENSITIVITY)?,
        ),
    ])
}

/// Improvement of `group` (time average, final) in %.
pub(super) fn group_improvement(set: &DataSet, imp: &Improvement, group: &str) -> Result<[f64; 2]> {
    let v = imp
        .groups
        .get(group)
        .ok_or_else(|| PipelineError::Missing {
            within: set.label.clone(),
            what: format!("group {group}"),
        })?;
    Ok([v.time_average_percent, v.final_percent])
}

/// Whether `imp` meets the paper's claim: > 10 % on the time-averaged velocity and
/// misalignment std.
pub(super) fn meets_paper_claim(imp: &Improvement) -> bool {
    ["velocity", "misalignment"].iter().all(|g| {
        imp.groups
            .get(*g)
            .is_some_and(|v| meets_paper(v.time_average_percent))
    })
}

fn paper_std_table(sets: &[DataSet], rho: f64) -> Result<Table> {
    let mut s = String::from(
        "| data | M | velocity | misalignment | acc bias | gyro bias | > 10 % on velocity and misalignment |\n\
         |---|---|---|---|---|---|---|\n",
    );
    for set in sets {
        for (name, imp) in paper_rows(set, rho)? {
            let cell = |group: &str| -> Result<String> {
                let [average, last] = group_improvement(set, &imp, group)?;
                Ok(format!(
                    "{} % / {} %",
                    one_decimal(average),
                    one_decimal(last)
                ))
            };
            s.push_str(&format!(
                "| {} | {name} | {} | {} | {} | {} | {} |\n",
                set.label,
                cell("velocity")?,
                cell("misalignment")?,
                cell("acc_bias")?,
                cell("gyro_bias")?,
                if meets_paper_claim(&imp) { "yes" } else { "no" },
            ));
        }
    }
    Ok(Table {
        name: "paper-std",
        markdown: s,
    })
}

/// Median, smallest and largest of the finite values (NaN if none).
pub fn median_min_max(values: &[f64]) -> [f64; 3] {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return [f64::NAN; 3];
    }
    v.sort_by(f64::total_cmp);
    [v[v.len() / 2], v[0], v[v.len() - 1]]
}

/// The run the `rho` table reads: BeamsNet with M neglected (R enters the largest
/// valid rho only through its correlations).
pub(super) fn rho_run(set: &DataSet) -> Result<&FilterRun> {
    set.accumulated
        .runs
        .iter()
        .find(|r| r.id == BEAMSNET_NEGLECTED)
        .ok_or_else(|| PipelineError::Missing {
            within: set.label.clone(),
            what: format!("run {BEAMSNET_NEGLECTED:?}"),
        })
}

fn rho_table(sets: &[DataSet], rho: f64) -> Result<Table> {
    let mut s = format!(
        "| data | updates | largest valid rho, M from Q accumulated: median / min / max | from per-step Q_k: median / min / max | rho = {rho} valid at (accumulated / per-step) |\n\
         |---|---|---|---|---|\n"
    );
    for set in sets {
        let run = rho_run(set)?;
        let acc = median_min_max(&run.largest_valid_rho);
        let step = median_min_max(&run.largest_valid_rho_per_step);
        let valid = |v: &[f64]| v.iter().filter(|x| **x >= rho.abs()).count();
        s.push_str(&format!(
            "| {} | {} | {:.3} / {:.3} / {:.3} | {:.3} / {:.3} / {:.3} | {} / {} |\n",
            set.label,
            run.largest_valid_rho.len(),
            acc[0],
            acc[1],
            acc[2],
            step[0],
            step[1],
            step[2],
            valid(&run.largest_valid_rho),
            valid(&run.largest_valid_rho_per_step),
        ));
    }
    Ok(Table {
        name: "rho",
        markdown: s,
    })
}

/// The `montecarlo` table: [`MONTE_CARLO_RUNS`] simulated missions from
/// [`MONTE_CARLO_FIRST_SEED`] with `config`, the oracle sensor and `learned`.
///
/// # Errors
/// The pipeline's errors.
pub fn monte_carlo_table(config: &Config, learned: &LearnedSource) -> Result<Table> {
    let report = monte_carlo(
        config,
        MONTE_CARLO_RUNS,
        MONTE_CARLO_FIRST_SEED,
        Some(learned),
        &|| {},
    )?;
    let rho = config.filter.rho;
    let any = report
        .variants
        .values()
        .next()
        .ok_or_else(|| PipelineError::Missing {
            within: "Monte Carlo".into(),
            what: "variant".into(),
        })?;
    let mut s = format!(
        "| variant | average NEES (band {:.1}-{:.1}) | epochs in band | NIS (band {:.2}-{:.2}) | P not PD [run-epochs] |\n\
         |---|---|---|---|---|\n",
        any.nees_band[0], any.nees_band[1], any.nis_band[0], any.nis_band[1]
    );
    let rows = [
        (ORACLE_TRUE_M, "oracle, true M".to_string()),
        (ORACLE_NEGLECTED, "oracle, M neglected".to_string()),
        (ORACLE_SCALED, format!("oracle, M = rho {rho}")),
        (BEAMSNET_SENSITIVITY, "BeamsNet, M from network".to_string()),
        (BEAMSNET_NEGLECTED, "BeamsNet, M neglected".to_string()),
        (BEAMSNET_SCALED, format!("BeamsNet, M = rho {rho}")),
        (LS, "LS".to_string()),
    ];
    let total = report.runs * report.epochs;
    for (key, label) in rows {
        let v = report
            .variants
            .get(key)
            .ok_or_else(|| PipelineError::Missing {
                within: "Monte Carlo".into(),
                what: format!("variant {key:?}"),
            })?;
        let nees = if v.covariance_not_positive_definite > 0 {
            format!("{:.2} (over the epochs where P stayed PD)", v.nees_average)
        } else {
            format!("{:.2}", v.nees_average)
        };
        s.push_str(&format!(
            "| {label} | {nees} | {:.1} % | {:.2} | {} of {} |\n",
            v.nees_epochs_in_band_percent,
            v.nis_average,
            thousands(v.covariance_not_positive_definite),
            thousands(total),
        ));
    }
    Ok(Table {
        name: "montecarlo",
        markdown: s,
    })
}
