//! The markdown tables of a paired study (`estim compare`): the paired differences,
//! the paper's std reductions, and the per-trajectory seed means of each variant.

use std::fmt::Write as _;

use super::{
    median, paper_variant, variant_label, CellRun, PairedInterval, PairedStudy, BEAMSNET_PER_STEP,
    BEAMSNET_SCALED, PAIRED_VARIANTS,
};
use crate::study::markdown::significant;
use crate::study::{AKIT_TEST_TRAJECTORIES, BEAMSNET_NEGLECTED};

/// An interval as `mean [lo, hi]` with `digits` decimals and signs, or `mean (n = N)`
/// when it has no bounds (fewer than two values).
pub(crate) fn interval_text(i: &PairedInterval, digits: usize) -> String {
    if i.lo.is_finite() {
        format!(
            "{:+.*} [{:+.*}, {:+.*}]",
            digits, i.mean, digits, i.lo, digits, i.hi
        )
    } else {
        format!("{:+.*} (n = {})", digits, i.mean, i.n)
    }
}

/// The markdown tables of a study: the paired differences, then the per-trajectory
/// seed means of each variant.
pub fn markdown(study: &PairedStudy) -> String {
    let mut s = String::new();
    differences_table(&mut s, study);
    let _ = writeln!(s);
    std_reduction_table(&mut s, study);
    let _ = writeln!(s);
    std_reduction_per_trajectory(&mut s, study);
    let _ = writeln!(s);
    variant_means_per_trajectory(&mut s, study);
    let _ = writeln!(s);
    cross_term_table(&mut s, study);
    s
}

/// " (test)" after a held-out trajectory's number.
fn test_mark(trajectory: u32) -> &'static str {
    if AKIT_TEST_TRAJECTORIES.contains(&trajectory) {
        " (test)"
    } else {
        ""
    }
}

/// "NEES (k)" over the runs' common k states, or "NEES per state" when they differ.
fn nees_heading(study: &PairedStudy) -> String {
    match study.runs.first() {
        Some(r) if !study.nees_per_state => format!("NEES ({})", r.nees_states),
        _ => "NEES per state".to_string(),
    }
}

/// The paired differences of NEES, NIS and position RMSE, over trajectories and over
/// cells.
fn differences_table(s: &mut String, study: &PairedStudy) {
    let digits = if study.nees_per_state { 3 } else { 2 };
    let cell = interval_text;
    let n_t = study.trajectories.len();
    let n_s = study.seeds.len();
    let nees = nees_heading(study);
    let _ = writeln!(
        s,
        "| pair (difference) | {nees}, over {n_t} trajectories | NIS (3), over trajectories | position RMSE [m], over trajectories | NEES, over {} cells | NIS, over cells | position RMSE [m], over cells |",
        n_t * n_s
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|");
    for c in &study.comparisons {
        let m = |k: usize| &c.metrics[k];
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} |",
            c.label,
            cell(&m(0).over_trajectories, digits),
            cell(&m(1).over_trajectories, 3),
            cell(&m(2).over_trajectories, 2),
            cell(&m(0).over_cells, digits),
            cell(&m(1).over_cells, 3),
            cell(&m(2).over_cells, 2),
        );
    }
}

/// The paper's metric: how much lower the first variant's std is, per pair.
fn std_reduction_table(s: &mut String, study: &PairedStudy) {
    let cell = interval_text;
    let n_t = study.trajectories.len();
    let _ = writeln!(
        s,
        "| pair | velocity std lower by [%], over {n_t} trajectories | misalignment std lower by [%], over trajectories | trajectories where both are lower by more than 10 % |"
    );
    let _ = writeln!(s, "|---|---|---|---|");
    for c in &study.comparisons {
        let (v, a) = (&c.metrics[3], &c.metrics[4]);
        let both = v
            .per_trajectory
            .iter()
            .zip(&a.per_trajectory)
            .filter(|((_, dv), (_, da))| *dv > 10.0 && *da > 10.0)
            .count();
        let _ = writeln!(
            s,
            "| {} | {} | {} | {both} of {} |",
            c.label,
            cell(&v.over_trajectories, 2),
            cell(&a.over_trajectories, 2),
            v.per_trajectory.len()
        );
    }
}

/// The std reductions of each pair, per trajectory.
fn std_reduction_per_trajectory(s: &mut String, study: &PairedStudy) {
    let _ = writeln!(
        s,
        "| trajectory | {} |",
        study
            .comparisons
            .iter()
            .map(|c| format!("{}: velocity / misalignment std lower by [%]", c.label))
            .collect::<Vec<_>>()
            .join(" | ")
    );
    let _ = writeln!(s, "|---|{}", "---|".repeat(study.comparisons.len()));
    for t in &study.trajectories {
        let cells: Vec<String> = study
            .comparisons
            .iter()
            .map(|c| {
                let at = |k: usize| {
                    c.metrics[k]
                        .per_trajectory
                        .iter()
                        .find(|(tt, _)| tt == t)
                        .map_or("-".to_string(), |(_, d)| format!("{d:+.2}"))
                };
                format!("{} / {}", at(3), at(4))
            })
            .collect();
        let _ = writeln!(s, "| {t}{} | {} |", test_mark(*t), cells.join(" | "));
    }
}

/// Each variant's NEES, NIS and position RMSE, the mean over seeds per trajectory.
fn variant_means_per_trajectory(s: &mut String, study: &PairedStudy) {
    let n_s = study.seeds.len();
    // The variants some cell ran (or tried to).
    let variants: Vec<&str> = PAIRED_VARIANTS
        .into_iter()
        .filter(|id| {
            study.runs.iter().any(|r| r.id == *id) || study.failures.iter().any(|f| f.id == *id)
        })
        .collect();
    let _ = writeln!(
        s,
        "| trajectory | {} |",
        variants
            .iter()
            .map(|id| format!("{}: NEES / NIS / position RMSE [m]", variant_label(id)))
            .collect::<Vec<_>>()
            .join(" | ")
    );
    let _ = writeln!(s, "|---|{}", "---|".repeat(variants.len()));
    for t in &study.trajectories {
        let cells: Vec<String> = variants
            .iter()
            .map(|id| {
                let rs: Vec<&CellRun> = study
                    .runs
                    .iter()
                    .filter(|r| r.trajectory == *t && r.id == *id)
                    .collect();
                let source = study.imu_sources.get(t).copied();
                let paper = [BEAMSNET_PER_STEP, BEAMSNET_SCALED].contains(id);
                match source {
                    Some(source) if paper && paper_variant(source) != *id => {
                        return format!("not run ({} IMU)", source.as_str())
                    }
                    _ if rs.is_empty() => return "failed".into(),
                    _ => {}
                }
                let mean = |k: &str| rs.iter().map(|r| r.metric(k)).sum::<f64>() / rs.len() as f64;
                let failed = n_s - rs.len();
                let note = if failed > 0 {
                    format!(" ({failed} of {n_s} seeds failed)")
                } else {
                    String::new()
                };
                format!(
                    "{} / {:.2} / {:.2}{note}",
                    significant(mean("nees"), 3),
                    mean("nis"),
                    mean("position_rmse_m")
                )
            })
            .collect();
        let _ = writeln!(s, "| {t}{} | {} |", test_mark(*t), cells.join(" | "));
    }
}

/// Per trajectory: the headings visited, the largest valid rho and the range of the
/// paper's cross term relative to R on both bases.
fn cross_term_table(s: &mut String, study: &PairedStudy) {
    let _ = writeln!(
        s,
        "| trajectory | heading sectors of 30 deg visited | largest valid rho, per-step M against per-step Q_k: median | forward entry of the cross term of S over R_xx at rho {}, Q accumulated: min / max | per-step Q_k: min / max |",
        study.rho
    );
    let _ = writeln!(s, "|---|---|---|---|---|");
    for t in &study.trajectories {
        let rs: Vec<&CellRun> = study
            .runs
            .iter()
            .filter(|r| r.trajectory == *t && r.id == BEAMSNET_NEGLECTED)
            .collect();
        if rs.is_empty() {
            continue;
        }
        let rho = median(
            &rs.iter()
                .map(|r| r.largest_valid_rho_per_step_own)
                .collect::<Vec<_>>(),
        );
        let range = |basis: usize| {
            let lo = rs
                .iter()
                .map(|r| r.paper_cross_term_over_r[basis][0])
                .fold(f64::INFINITY, f64::min);
            let hi = rs
                .iter()
                .map(|r| r.paper_cross_term_over_r[basis][1])
                .fold(f64::NEG_INFINITY, f64::max);
            // A recorded IMU's runs (the navigator's loop) do not compute it.
            if lo <= hi {
                format!("{lo:+.3} / {hi:+.3}")
            } else {
                "-".to_string()
            }
        };
        let rho = if rho.is_finite() {
            format!("{rho:.3}")
        } else {
            "-".to_string()
        };
        let _ = writeln!(
            s,
            "| {t} | {} | {rho} | {} | {} |",
            rs[0].heading_sectors_visited,
            range(0),
            range(1)
        );
    }
}
