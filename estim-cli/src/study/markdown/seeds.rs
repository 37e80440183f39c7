//! The `*-seeds` tables: rows of the single-seed tables over
//! [`SEED_INTERVAL_SEEDS`] seeds from [`SEED_INTERVAL_FIRST_SEED`] (IMU synthesis,
//! initial error, beam noise and the empirical M's draws redrawn per seed), each number
//! as mean [2.5 %, 97.5 %] over the seeds ([`MeanInterval`]: percentiles by linear
//! interpolation between order statistics).
//!
//! One machinery for all of them: [`at_each_seed`] runs a seed's work in parallel
//! (rayon) and [`over_seeds_table`] renders per-seed values, so a new seed table only
//! says which numbers a seed gives.

use std::path::Path;

use rayon::prelude::*;

use super::results::{
    data_set, filter, filter_rows, group_improvement, meets_paper_claim, paper_rows, rho_run,
    velocity_rows, DataSet,
};
use super::{
    one_decimal, significant, Table, AKIT_TRAJECTORIES, SEED_INTERVAL_FIRST_SEED,
    SEED_INTERVAL_SEEDS,
};
use crate::study::{
    apply_faults, learned_study, BeamLoss, Config, DvlOutage, LearnedEvent, LearnedSource,
    LearnedStudy, MeanInterval, PipelineError, Result, Scenario, STUDY_EMPIRICAL_REALIZATIONS,
};

/// The seeds of every `*-seeds` table.
pub fn interval_seeds() -> std::ops::Range<u64> {
    SEED_INTERVAL_FIRST_SEED..SEED_INTERVAL_FIRST_SEED + SEED_INTERVAL_SEEDS as u64
}

/// `at_seed` on a copy of `config` with each seed of [`interval_seeds`], in parallel;
/// the results in seed order.
fn at_each_seed<T: Send>(
    config: &Config,
    at_seed: impl Fn(&Config) -> Result<T> + Sync,
) -> Result<Vec<T>> {
    interval_seeds()
        .collect::<Vec<_>>()
        .into_par_iter()
        .map(|seed| {
            let mut c = config.clone();
            c.seed = seed;
            at_seed(&c)
        })
        .collect()
}

/// How a column of a seed table summarises the per-seed values of its cell.
#[derive(Clone, Copy)]
enum Column {
    /// mean [2.5 %, 97.5 %] (header, number format); see [`interval_cell`].
    Interval(&'static str, fn(f64) -> String),
    /// In how many seeds the value is nonzero, "n of N" (header); "-" when no seed has
    /// a value.
    Count(&'static str),
}

/// "mean [lo, hi]" of the finite values of `xs`, each formatted by `format`; when some
/// values are not finite (a variant that produced no number at that seed) the cell says
/// over how many seeds it is; "-" when none is finite.
pub fn interval_cell(xs: &[f64], format: fn(f64) -> String) -> String {
    let finite = xs.iter().filter(|x| x.is_finite()).count();
    if finite == 0 {
        return "-".into();
    }
    let m = MeanInterval::of(xs);
    let cell = format!("{} [{}, {}]", format(m.mean), format(m.lo), format(m.hi));
    if finite < xs.len() {
        format!("{cell} ({finite} of {} seeds)", xs.len())
    } else {
        cell
    }
}

/// A markdown table over seeds: `labels[r]` are the leading cells of row r (one per
/// entry of `label_headers`), `per_seed[s][r][c]` the value of column c of row r at
/// seed s.
fn over_seeds_table(
    name: &'static str,
    label_headers: &[&str],
    columns: &[Column],
    labels: &[Vec<String>],
    per_seed: &[Vec<Vec<f64>>],
) -> Result<Table> {
    for (s, rows) in per_seed.iter().enumerate() {
        if rows.len() != labels.len() || rows.iter().any(|r| r.len() != columns.len()) {
            return Err(PipelineError::Table {
                table: name.into(),
                reason: format!(
                    "seed {s} gave {} rows, expected {} rows of {} values",
                    rows.len(),
                    labels.len(),
                    columns.len()
                ),
            });
        }
    }
    if let Some(bad) = labels.iter().find(|l| l.len() != label_headers.len()) {
        return Err(PipelineError::Table {
            table: name.into(),
            reason: format!(
                "row {bad:?} has {} labels, expected {}",
                bad.len(),
                label_headers.len()
            ),
        });
    }
    let headers: Vec<&str> = label_headers
        .iter()
        .copied()
        .chain(columns.iter().map(|c| match c {
            Column::Interval(h, _) | Column::Count(h) => *h,
        }))
        .collect();
    let mut s = format!(
        "| {} |\n|{}\n",
        headers.join(" | "),
        "---|".repeat(headers.len())
    );
    for (r, label) in labels.iter().enumerate() {
        let cells: Vec<String> = columns
            .iter()
            .enumerate()
            .map(|(c, column)| {
                let xs: Vec<f64> = per_seed.iter().map(|seed| seed[r][c]).collect();
                match column {
                    Column::Interval(_, format) => interval_cell(&xs, *format),
                    Column::Count(_) if xs.iter().all(|x| !x.is_finite()) => "-".into(),
                    Column::Count(_) => format!(
                        "{} of {}",
                        xs.iter().filter(|x| x.is_finite() && **x != 0.0).count(),
                        xs.len()
                    ),
                }
            })
            .collect();
        s.push_str(&format!(
            "| {} | {} |\n",
            label.join(" | "),
            cells.join(" | ")
        ));
    }
    Ok(Table { name, markdown: s })
}

fn two_decimals(x: f64) -> String {
    format!("{x:.2}")
}

fn three_decimals(x: f64) -> String {
    format!("{x:.3}")
}

fn four_decimals(x: f64) -> String {
    format!("{x:.4}")
}

fn six_decimals(x: f64) -> String {
    format!("{x:.6}")
}

fn three_significant(x: f64) -> String {
    significant(x, 3)
}

/// m/s as mm/s with 3 decimals (the 6 decimals in m/s of the `velocity` table).
fn millimetres_per_second(x: f64) -> String {
    format!("{:.3}", 1e3 * x)
}

/// The labels of the data sets of the results tables.
fn data_labels() -> Vec<String> {
    AKIT_TRAJECTORIES
        .iter()
        .map(|n| format!("A-KIT {n}"))
        .chain(std::iter::once("simulated".to_string()))
        .collect()
}

/// One table's values at one seed: rows x columns.
type SeedValues = Vec<Vec<f64>>;

/// The tables of one seed's data sets: `filters-seeds`, `velocity-seeds`,
/// `paper-std-seeds`, `rho-seeds`, in that order.
fn data_set_values(sets: &[DataSet], rho: f64) -> Result<[SeedValues; 4]> {
    let mut out: [SeedValues; 4] = Default::default();
    for set in sets {
        for (_, id, per_step) in filter_rows(rho) {
            let report = if per_step {
                &set.per_step
            } else {
                &set.accumulated
            };
            let f = filter(report, id)?;
            out[0].push(vec![
                f.position_error_m.rmse,
                f.velocity_error_mps.rmse,
                f.nees_average,
            ]);
        }
        let velocity = velocity_rows(set)?;
        if velocity.len() != 2 {
            return Err(PipelineError::Table {
                table: set.label.clone(),
                reason: "velocity-seeds needs the LS and the BeamsNet velocity".into(),
            });
        }
        for (_, values) in velocity {
            out[1].push(values.to_vec());
        }
        for (_, imp) in paper_rows(set, rho)? {
            let [velocity_average, velocity_final] = group_improvement(set, &imp, "velocity")?;
            let [misalignment_average, misalignment_final] =
                group_improvement(set, &imp, "misalignment")?;
            out[2].push(vec![
                velocity_average,
                velocity_final,
                misalignment_average,
                misalignment_final,
                f64::from(u8::from(meets_paper_claim(&imp))),
            ]);
        }
        let run = rho_run(set)?;
        let median = |v: &[f64]| super::median_min_max(v)[0];
        let valid = |v: &[f64]| v.iter().filter(|x| **x >= rho.abs()).count() as f64;
        out[3].push(vec![
            median(&run.largest_valid_rho),
            valid(&run.largest_valid_rho),
            median(&run.largest_valid_rho_per_step),
            valid(&run.largest_valid_rho_per_step),
        ]);
    }
    Ok(out)
}

/// The seed tables of the results tables: `filters-seeds` (position and velocity RMSE
/// and time-averaged NEES of every row of `filters`), `velocity-seeds` (every metric of
/// `velocity`, RMSE and MAE in mm/s), `paper-std-seeds` (velocity and misalignment
/// improvements of `paper-std`, time average and final, and in how many seeds the
/// paper's claim holds) and `rho-seeds` (the median over the updates of the largest
/// valid rho, and the updates where rho is valid), all on A-KIT 4 and 13 under `data`
/// and the simulated mission, over [`interval_seeds`]. The seeds are run once for all
/// four.
///
/// # Errors
/// Missing or bad data files; the pipeline's errors.
pub fn seed_interval_tables(
    config: &Config,
    data: &Path,
    learned: &LearnedSource,
) -> Result<Vec<Table>> {
    let rho = config.filter.rho;
    let labels = data_labels();
    let per_seed = at_each_seed(config, |c| {
        let mut scenarios = Vec::new();
        for n in AKIT_TRAJECTORIES {
            scenarios.push(Scenario::akit(data, n, c, c.seed)?);
        }
        scenarios.push(Scenario::simulated(c, c.seed)?);
        let sets = scenarios
            .iter_mut()
            .zip(&labels)
            .map(|(scenario, label)| data_set(label.clone(), scenario, c, learned))
            .collect::<Result<Vec<_>>>()?;
        data_set_values(&sets, rho)
    })?;
    let table = |t: usize| -> Vec<SeedValues> { per_seed.iter().map(|s| s[t].clone()).collect() };
    let rows = |names: &[String]| -> Vec<Vec<String>> {
        labels
            .iter()
            .flat_map(|d| names.iter().map(move |n| vec![d.clone(), n.clone()]))
            .collect()
    };
    let filters = over_seeds_table(
        "filters-seeds",
        &["data", "filter"],
        &[
            Column::Interval("position RMSE [m]", two_decimals),
            Column::Interval("velocity RMSE [m/s]", three_decimals),
            Column::Interval("NEES (15)", three_significant),
        ],
        &rows(&filter_rows(rho).map(|(name, _, _)| name)),
        &table(0),
    )?;
    let velocity = over_seeds_table(
        "velocity-seeds",
        &["data", "method"],
        &[
            Column::Interval("RMSE [mm/s]", millimetres_per_second),
            Column::Interval("MAE [mm/s]", millimetres_per_second),
            Column::Interval("R^2", six_decimals),
            Column::Interval("VAF [%]", four_decimals),
            Column::Interval("RMSE vs LS [%]", one_decimal),
        ],
        &rows(&["LS".to_string(), "BeamsNet".to_string()]),
        &table(1),
    )?;
    let paper_names: Vec<String> = [
        format!("rho {rho}, Q accumulated over the interval"),
        format!("rho {rho}, per-step Q_k"),
        "from the network's sensitivity".to_string(),
    ]
    .to_vec();
    let paper = over_seeds_table(
        "paper-std-seeds",
        &["data", "M"],
        &[
            Column::Interval("velocity, time average [%]", one_decimal),
            Column::Interval("velocity, final [%]", one_decimal),
            Column::Interval("misalignment, time average [%]", one_decimal),
            Column::Interval("misalignment, final [%]", one_decimal),
            Column::Count("> 10 % on velocity and misalignment [seeds]"),
        ],
        &rows(&paper_names),
        &table(2),
    )?;
    let rho_rows: Vec<Vec<String>> = labels.iter().map(|d| vec![d.clone()]).collect();
    let rho_seeds = over_seeds_table(
        "rho-seeds",
        &["data"],
        &[
            Column::Interval("largest valid rho, Q accumulated: median", three_decimals),
            Column::Interval("rho valid at [updates], accumulated", |x: f64| {
                format!("{x:.1}")
            }),
            Column::Interval("per-step Q_k: median", three_decimals),
            Column::Interval("rho valid at [updates], per-step", |x: f64| {
                format!("{x:.1}")
            }),
        ],
        &rho_rows,
        &table(3),
    )?;
    Ok(vec![filters, velocity, paper, rho_seeds])
}

/// The learned-scenario seed tables, `two-beams-seeds` and `outage-seeds`: the A-KIT 4
/// and 13 rows of `estim reproduce --scenario two-beams|outage --data DIR` (every
/// variant; the empirical M with [`STUDY_EMPIRICAL_REALIZATIONS`] draws per update)
/// over [`interval_seeds`]: NEES, NIS, position and velocity RMSE over the event's
/// epochs and NEES over the whole run, and in how many seeds the variant's position
/// RMSE over the event is below that of INS only in the same seed.
///
/// # Errors
/// Missing or bad data files or model files; the pipeline's errors.
pub fn learned_seed_tables(config: &Config, data: &Path) -> Result<Vec<Table>> {
    let beamsnet = estim::models::beamsnet()?;
    let two_beams = estim::models::two_beams()?;
    let outage = estim::models::outage()?;
    let events = [
        (
            "two-beams-seeds",
            LearnedEvent::TwoBeams {
                net: &two_beams,
                loss: BeamLoss::two_beams(),
            },
        ),
        (
            "outage-seeds",
            LearnedEvent::Outage {
                net: &outage,
                outage: DvlOutage::scripted(),
            },
        ),
    ];
    events
        .iter()
        .map(|(name, event)| learned_seed_table(name, config, data, &beamsnet, event))
        .collect()
}

/// Per variant of `ids` (INS only last, as [`LearnedEvent::ids`]): NEES, NIS, position
/// and velocity RMSE over the event, NEES over the run, and whether its position RMSE
/// over the event is below INS only's in the same study (1 or 0; NaN for INS only).
fn study_values(study: &LearnedStudy, ids: &[&str; 5]) -> Result<SeedValues> {
    let mut rows = ids
        .iter()
        .map(|id| {
            let v = study
                .filters
                .iter()
                .position(|f| f.id == *id)
                .ok_or_else(|| PipelineError::Missing {
                    within: "learned study".into(),
                    what: format!("variant {id:?}"),
                })?;
            let (f, l) = (&study.filters[v], &study.loss_window[v]);
            Ok(vec![
                l.nees_mean,
                l.nis_mean,
                l.position_rmse_m,
                l.velocity_rmse_mps,
                f.nees_average,
            ])
        })
        .collect::<Result<SeedValues>>()?;
    let ins_only = rows.len() - 1;
    let ins_only_position = rows[ins_only][2];
    for (v, row) in rows.iter_mut().enumerate() {
        let below = f64::from(u8::from(row[2] < ins_only_position));
        row.push(if v == ins_only { f64::NAN } else { below });
    }
    Ok(rows)
}

fn learned_seed_table(
    name: &'static str,
    config: &Config,
    data: &Path,
    beamsnet: &estim_learned::BeamsNet,
    event: &LearnedEvent<'_>,
) -> Result<Table> {
    let ids = event.ids();
    // Per seed: per trajectory: (the paper variant's rho, per variant the values).
    let per_seed: Vec<Vec<(f64, SeedValues)>> = at_each_seed(config, |c| {
        AKIT_TRAJECTORIES
            .iter()
            .map(|&n| {
                let mut scenario = Scenario::akit(data, n, c, c.seed)?;
                apply_faults(&mut scenario, &c.faults, c.seed)?;
                let study = learned_study(
                    &scenario,
                    c,
                    beamsnet,
                    event,
                    STUDY_EMPIRICAL_REALIZATIONS,
                    c.seed,
                )?;
                let rows = study_values(&study, &ids).map_err(|e| PipelineError::Run {
                    run: format!("{name}: A-KIT {n}, seed {}", c.seed),
                    error: Box::new(e),
                })?;
                Ok((study.paper_rho, rows))
            })
            .collect::<Result<Vec<_>>>()
    })?;
    let ins_only = match event {
        LearnedEvent::TwoBeams { .. } => "INS only during the loss",
        LearnedEvent::Outage { .. } => "INS only during the outage",
    };
    let mut labels = Vec::new();
    for (t, n) in AKIT_TRAJECTORIES.iter().enumerate() {
        let rhos: Vec<f64> = per_seed.iter().map(|s| s[t].0).collect();
        let [_, lo, hi] = super::median_min_max(&rhos);
        let (lo, hi) = (format!("{lo:.3}"), format!("{hi:.3}"));
        let paper = if lo == hi {
            format!("M = rho {lo} (paper, largest valid, every seed)")
        } else {
            format!("M = rho {lo}-{hi} (paper, largest valid per seed)")
        };
        let names = [
            "M from network".to_string(),
            "M empirical".to_string(),
            "M neglected".to_string(),
            paper,
            ins_only.to_string(),
        ];
        labels.extend(names.into_iter().map(|v| vec![format!("A-KIT {n}"), v]));
    }
    let values: Vec<SeedValues> = per_seed
        .into_iter()
        .map(|s| s.into_iter().flat_map(|(_, rows)| rows).collect())
        .collect();
    // Column headers are static strings; the two events have their own.
    let columns: [Column; 6] = match event {
        LearnedEvent::TwoBeams { .. } => [
            Column::Interval("NEES (loss)", two_decimals),
            Column::Interval("NIS (loss)", two_decimals),
            Column::Interval("position RMSE (loss) [m]", three_decimals),
            Column::Interval("velocity RMSE (loss) [m/s]", four_decimals),
            Column::Interval("NEES (run)", two_decimals),
            Column::Count("position RMSE below INS only [seeds]"),
        ],
        LearnedEvent::Outage { .. } => [
            Column::Interval("NEES (outage)", two_decimals),
            Column::Interval("NIS (outage)", two_decimals),
            Column::Interval("position RMSE (outage) [m]", three_decimals),
            Column::Interval("velocity RMSE (outage) [m/s]", four_decimals),
            Column::Interval("NEES (run)", two_decimals),
            Column::Count("position RMSE below INS only [seeds]"),
        ],
    };
    over_seeds_table(name, &["data", "variant"], &columns, &labels, &values)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The p-quantile of `xs` as the piecewise-linear curve through the points
    /// (k / (n - 1), x_(k)) (Hyndman & Fan 1996, type 7; NumPy's default), found by
    /// searching the segment that holds p: coded apart from [`MeanInterval::of`].
    fn reference_quantile(xs: &[f64], p: f64) -> f64 {
        let mut v = xs.to_vec();
        v.sort_by(f64::total_cmp);
        let n = v.len();
        if n == 1 {
            return v[0];
        }
        for k in 0..n - 1 {
            let (a, b) = (k as f64 / (n - 1) as f64, (k + 1) as f64 / (n - 1) as f64);
            if p >= a && p <= b {
                return v[k] + (p - a) / (b - a) * (v[k + 1] - v[k]);
            }
        }
        v[n - 1]
    }

    #[test]
    fn interval_matches_numpy_and_a_separately_coded_percentile() {
        // numpy.percentile(range(1, 11), [2.5, 97.5]) = [1.225, 9.775].
        let xs: Vec<f64> = (1..=10).map(f64::from).rev().collect();
        let m = MeanInterval::of(&xs);
        assert!((m.lo - 1.225).abs() < 1e-12 && (m.hi - 9.775).abs() < 1e-12);
        assert_eq!(m.mean, 5.5);
        // Seeded draws of several sizes, 20 (the seeds of docs/results.md) among them.
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut uniform = || {
            // xorshift64*: deterministic, no dependency.
            state ^= state >> 12;
            state ^= state << 25;
            state ^= state >> 27;
            (state.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
        };
        for n in [1usize, 2, 3, 7, 20, 41, 200] {
            let xs: Vec<f64> = (0..n).map(|_| 10.0 * uniform() - 3.0).collect();
            let m = MeanInterval::of(&xs);
            let mean = xs.iter().sum::<f64>() / n as f64;
            assert!((m.mean - mean).abs() < 1e-12, "n = {n}");
            assert!(
                (m.lo - reference_quantile(&xs, 0.025)).abs() < 1e-12,
                "n = {n}"
            );
            assert!(
                (m.hi - reference_quantile(&xs, 0.975)).abs() < 1e-12,
                "n = {n}"
            );
        }
    }

    #[test]
    fn cells_say_how_many_seeds_they_cover() {
        assert_eq!(
            interval_cell(&[1.0, 3.0], two_decimals),
            "2.00 [1.05, 2.95]"
        );
        assert_eq!(
            interval_cell(&[1.0, f64::NAN, 3.0], two_decimals),
            "2.00 [1.05, 2.95] (2 of 3 seeds)"
        );
        assert_eq!(interval_cell(&[f64::NAN, f64::NAN], two_decimals), "-");
        assert_eq!(millimetres_per_second(0.0038124), "3.812");
    }

    #[test]
    fn over_seeds_table_renders_rows_and_refuses_ragged_values() {
        let labels = vec![
            vec!["A".to_string(), "x".to_string()],
            vec!["A".to_string(), "y".to_string()],
        ];
        let columns = [
            Column::Interval("v", two_decimals),
            Column::Count("claim [seeds]"),
        ];
        let per_seed = vec![
            vec![vec![1.0, 1.0], vec![2.0, 0.0]],
            vec![vec![3.0, 0.0], vec![2.0, 0.0]],
        ];
        let t = over_seeds_table("t", &["data", "row"], &columns, &labels, &per_seed)
            .expect("consistent shapes");
        assert_eq!(
            t.markdown,
            "| data | row | v | claim [seeds] |\n|---|---|---|---|\n\
             | A | x | 2.00 [1.05, 2.95] | 1 of 2 |\n\
             | A | y | 2.00 [2.00, 2.00] | 0 of 2 |\n"
        );
        let none = vec![vec![vec![1.0, f64::NAN], vec![2.0, 0.0]]];
        let t = over_seeds_table("t", &["data", "row"], &columns, &labels, &none)
            .expect("consistent shapes");
        assert!(
            t.markdown.contains("| A | x | 1.00 [1.00, 1.00] | - |\n"),
            "{}",
            t.markdown
        );
        let ragged = vec![vec![vec![1.0, 1.0]], vec![vec![3.0, 0.0], vec![2.0, 0.0]]];
        assert!(over_seeds_table("t", &["data", "row"], &columns, &labels, &ragged).is_err());
        assert!(over_seeds_table("t", &["data"], &columns, &labels, &per_seed).is_err());
    }

    #[test]
    fn the_seeds_are_2000_to_2019() {
        let seeds: Vec<u64> = interval_seeds().collect();
        assert_eq!(seeds.len(), 20);
        assert_eq!((seeds[0], seeds[19]), (2000, 2019));
    }
}
