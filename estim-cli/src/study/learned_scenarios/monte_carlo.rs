//! The Monte Carlo of a learned scenario: seeded simulated missions with the event,
//! every variant's NEES, NIS and errors over the loss, as means with 95 % intervals.

use estim_core::consistency::chi_square_band;
use estim_learned::BeamsNet;
use rayon::prelude::*;
use serde::Serialize;

use super::{learned_filter_label, learned_study, LearnedEvent, LearnedStudy, LossWindowSummary};
use crate::study::stats::finite_mean;
use crate::study::{Config, PipelineError, Result, Scenario};

/// Mean and 95 % interval (2.5th and 97.5th percentiles over the runs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MeanInterval {
    /// Mean over the runs.
    pub mean: f64,
    /// 2.5th percentile.
    pub lo: f64,
    /// 97.5th percentile.
    pub hi: f64,
}

impl MeanInterval {
    /// Of the finite values of `xs` (NaN fields if none).
    pub fn of(xs: &[f64]) -> Self {
        let mut v: Vec<f64> = xs.iter().copied().filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            return Self {
                mean: f64::NAN,
                lo: f64::NAN,
                hi: f64::NAN,
            };
        }
        v.sort_by(f64::total_cmp);
        let q = |p: f64| {
            // Linear interpolation between order statistics.
            let x = p * (v.len() - 1) as f64;
            let (i, f) = (x.floor() as usize, x - x.floor());
            v[i] + f * (v[(i + 1).min(v.len() - 1)] - v[i])
        };
        Self {
            mean: v.iter().sum::<f64>() / v.len() as f64,
            lo: q(0.025),
            hi: q(0.975),
        }
    }
}

/// One variant over the Monte Carlo runs (`estim montecarlo --learned ... --json`).
#[derive(Debug, Clone, Serialize)]
pub struct LearnedVariant {
    /// Stable filter id (e.g. `two_beams_m_network`).
    pub id: String,
    /// Human label (the scaled variant's states the median rho over the runs).
    pub label: String,
    /// Mean over the loss epochs of the run-averaged NEES (15 states).
    pub nees_average: f64,
    /// 95 % band of the run-averaged NEES at one epoch.
    pub nees_band: [f64; 2],
    /// Percentage of loss epochs whose run-averaged NEES lies in `nees_band` [%].
    pub nees_epochs_in_band_percent: f64,
    /// Mean over runs and loss updates of the NIS (3 dof; NaN without updates).
    pub nis_average: f64,
    /// Per-run position RMSE over the loss epochs \[m\].
    pub position_rmse_m: MeanInterval,
    /// Per-run velocity RMSE over the loss epochs [m/s].
    pub velocity_rmse_mps: MeanInterval,
    /// Mean over runs of the network's output / IMU-driven error correlation.
    pub output_imu_correlation: f64,
}

/// The Monte Carlo of a learned scenario.
#[derive(Debug, Clone, Serialize)]
pub struct LearnedMonteCarlo {
    /// Scenario (`two-beams`, `outage`).
    pub scenario: String,
    /// Runs.
    pub runs: usize,
    /// Seeds `first_seed..first_seed + runs`.
    pub first_seed: u64,
    /// Monte Carlo draws of the empirical M per update (0: variant left out).
    pub empirical_realizations: usize,
    /// What the statistics cover.
    pub note: String,
    /// Per variant, in a fixed order.
    pub variants: Vec<LearnedVariant>,
}

/// `runs` simulated missions with the event (seeds `first_seed..`); the empirical M
/// with `empirical_realizations` draws per update (0: left out).
pub fn learned_monte_carlo(
    config: &Config,
    beamsnet: &BeamsNet,
    event: &LearnedEvent<'_>,
    runs: usize,
    first_seed: u64,
    empirical_realizations: usize,
    tick: &(dyn Fn() + Sync),
) -> Result<LearnedMonteCarlo> {
    let studies: Vec<(LearnedStudy, Vec<usize>)> = (0..runs)
        .into_par_iter()
        .map(|i| {
            let seed = first_seed + i as u64;
            let scenario = Scenario::simulated(config, seed)?;
            let mut probe = scenario.clone();
            let epochs = event.apply(&mut probe)?;
            let study = learned_study(
                &scenario,
                config,
                beamsnet,
                event,
                empirical_realizations,
                seed,
            )?;
            tick();
            Ok((study, epochs))
        })
        .collect::<Result<_>>()?;
    let band = chi_square_band(15, runs.max(1), 0.95)?;
    let mut rhos: Vec<f64> = studies.iter().map(|(s, _)| s.paper_rho).collect();
    rhos.sort_by(f64::total_cmp);
    let median_rho = rhos.get(rhos.len() / 2).copied().unwrap_or(f64::NAN);
    let mut variants = Vec::new();
    let Some((first, epochs)) = studies.first() else {
        return Err(PipelineError::Argument {
            flag: "--runs".into(),
            reason: "must be at least 1".into(),
        });
    };
    for (v, run0) in first.runs.iter().enumerate() {
        let per_epoch: Vec<f64> = epochs
            .iter()
            .map(|&k| {
                studies
                    .iter()
                    .map(|(s, _)| s.runs[v].nees.get(k).copied().unwrap_or(f64::NAN))
                    .sum::<f64>()
                    / runs as f64
            })
            .collect();
        let in_band = per_epoch
            .iter()
            .filter(|x| **x >= band.lower && **x <= band.upper)
            .count() as f64
            / per_epoch.len().max(1) as f64;
        let loss: Vec<&LossWindowSummary> =
            studies.iter().map(|(s, _)| &s.loss_window[v]).collect();
        let uses_network = run0.id != event.ids()[4];
        variants.push(LearnedVariant {
            id: run0.id.clone(),
            label: learned_filter_label(&run0.id, median_rho),
            nees_average: finite_mean(&per_epoch),
            nees_band: [band.lower, band.upper],
            nees_epochs_in_band_percent: 100.0 * in_band,
            nis_average: finite_mean(&loss.iter().map(|l| l.nis_mean).collect::<Vec<_>>()),
            position_rmse_m: MeanInterval::of(
                &loss.iter().map(|l| l.position_rmse_m).collect::<Vec<_>>(),
            ),
            velocity_rmse_mps: MeanInterval::of(
                &loss.iter().map(|l| l.velocity_rmse_mps).collect::<Vec<_>>(),
            ),
            output_imu_correlation: if uses_network {
                finite_mean(
                    &studies
                        .iter()
                        .map(|(s, _)| s.output_imu_correlation)
                        .collect::<Vec<_>>(),
                )
            } else {
                f64::NAN
            },
        });
    }
    Ok(LearnedMonteCarlo {
        scenario: event.name().into(),
        runs,
        first_seed,
        empirical_realizations,
        note: format!(
            "simulated missions; {}; NEES, NIS and RMSE over the DVL epochs of the event; \
             intervals are the 2.5/97.5 percentiles of the per-run values; output_imu_correlation: \
             mean over runs of the per-run mean over the event of max |M_ij| / sqrt(Q_w,ii R_jj)",
            event.describe()
        ),
        variants,
    })
}
