//! `estim reproduce --scenario two-beams` and `estim montecarlo --learned two-beams`:
//! learned sensors that must use the IMU.

use crate::study::{
    learned_monte_carlo, learned_study, BeamLoss, Config, DvlOutage, ImuSource, LearnedEvent,
    LearnedMonteCarlo, LearnedStudy, Scenario,
};
use estim::learned::{BeamsNet, OutageNet, TwoBeamsNet};

use std::fmt::Write as _;

use anyhow::Context;

/// The `--scenario` of `estim reproduce`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ScenarioKind {
    /// The paper: BeamsNet with four beams throughout.
    Paper,
    /// Beams 1 and 2 only for 120 s: the two-beams network (IMU window + 2 beams).
    TwoBeams,
    /// No DVL for 60 s: the outage network (IMU window + last valid velocity + time
    /// since it).
    Outage,
}

/// The `--learned` of `estim montecarlo`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LearnedKind {
    /// BeamsNet, four beams (the standard Monte Carlo table).
    Beamsnet,
    /// The two-beams scenario.
    TwoBeams,
    /// The outage scenario.
    Outage,
}

/// Realizations of the empirical M per update in `estim reproduce --scenario two-beams`.
pub const EMPIRICAL_REALIZATIONS: usize = crate::study::STUDY_EMPIRICAL_REALIZATIONS;

/// The scripted outage: no DVL from 200 s for 60 s (inside the 400 s A-KIT segments and
/// the default simulated mission).
pub fn outage() -> DvlOutage {
    DvlOutage::scripted()
}

/// The committed networks a learned scenario needs.
pub struct Networks {
    beamsnet: BeamsNet,
    two_beams: Option<TwoBeamsNet>,
    outage: Option<OutageNet>,
}

impl Networks {
    /// BeamsNet and the network of `outage` (true) or the two-beams scenario, trained
    /// on windows of the IMU `source`: on the recorded IMU windows of the A-KIT training
    /// trajectories (`models/*_recorded.onnx`) for a recorded IMU, else on synthesized
    /// ones.
    pub fn load(outage: bool, source: ImuSource) -> anyhow::Result<Self> {
        use estim::models;
        let recorded = source == ImuSource::Recorded;
        let beamsnet = if recorded {
            models::beamsnet_recorded()
        } else {
            models::beamsnet()
        }
        .context("the committed BeamsNet model")?;
        let (two_beams, outage) = if outage {
            let net = if recorded {
                models::outage_recorded()
            } else {
                models::outage()
            };
            (None, Some(net.context("the committed outage model")?))
        } else {
            let net = if recorded {
                models::two_beams_recorded()
            } else {
                models::two_beams()
            };
            (Some(net.context("the committed two-beams model")?), None)
        };
        Ok(Self {
            beamsnet,
            two_beams,
            outage,
        })
    }

    fn event(&self) -> anyhow::Result<LearnedEvent<'_>> {
        match (&self.two_beams, &self.outage) {
            (Some(net), _) => Ok(LearnedEvent::TwoBeams {
                net,
                loss: BeamLoss::two_beams(),
            }),
            (None, Some(net)) => Ok(LearnedEvent::Outage {
                net,
                outage: outage(),
            }),
            (None, None) => anyhow::bail!("no learned network loaded"),
        }
    }
}

/// The learned study (`outage` or two-beams) on each scenario, with the networks
/// trained on windows of its IMU ([`Networks::load`]).
pub fn reproduce_learned(
    scenarios: &[Scenario],
    config: &Config,
    outage: bool,
) -> anyhow::Result<Vec<LearnedStudy>> {
    scenarios
        .iter()
        .map(|s| {
            let nets = Networks::load(outage, s.imu_source)?;
            let event = nets.event()?;
            Ok(learned_study(
                s,
                config,
                &nets.beamsnet,
                &event,
                EMPIRICAL_REALIZATIONS,
                config.seed,
            )?)
        })
        .collect()
}

/// A study as a table.
pub fn print_study(out: &mut String, s: &LearnedStudy) -> std::fmt::Result {
    writeln!(
        out,
        "== {} ({}, IMU {}): {} ({} network updates); paper rho used {:.3}",
        s.scenario,
        s.event,
        s.imu_source.as_str(),
        s.description,
        s.loss_epochs,
        s.paper_rho
    )?;
    if s.imu_source == ImuSource::Recorded {
        writeln!(
            out,
            "   recorded IMU read with the vehicle file, networks trained on recorded windows; \
             errors and NEES (over {} states with truth) at the reference's epochs",
            s.nees_states
        )?;
    }
    writeln!(
        out,
        "   correlation network output error / IMU-driven INS error (mean over the loss of the largest |rho_ij|): {:.3e}",
        s.output_imu_correlation
    )?;
    if let Some(d) = s.network_vs_empirical_relative {
        writeln!(
            out,
            "   max |M_network - M_empirical| / max |M_empirical|: {d:.3}"
        )?;
    }
    writeln!(
        out,
        "   {:<56} {:>10} {:>10} {:>10} {:>10} | {:>9} {:>9} {:>9}",
        "variant (event window | whole run)",
        "NEES",
        "NIS",
        "pos RMSE",
        "vel RMSE",
        "NEES",
        "pos RMSE",
        "vel RMSE"
    )?;
    for (f, l) in s.filters.iter().zip(&s.loss_window) {
        writeln!(
            out,
            "   {:<56} {:>10.2} {:>10.2} {:>9.3}m {:>8.4}m/s | {:>9.2} {:>8.3}m {:>7.4}m/s",
            f.name,
            l.nees_mean,
            l.nis_mean,
            l.position_rmse_m,
            l.velocity_rmse_mps,
            f.nees_average,
            f.position_error_m.rmse,
            f.velocity_error_mps.rmse
        )?;
    }
    Ok(())
}

/// `estim montecarlo --learned two-beams|outage`.
pub fn monte_carlo_learned(
    config: &Config,
    outage: bool,
    runs: usize,
    seed: u64,
    empirical_realizations: usize,
    tick: &(dyn Fn() + Sync),
) -> anyhow::Result<LearnedMonteCarlo> {
    let nets = Networks::load(outage, ImuSource::Synthesized)?;
    let event = nets.event()?;
    Ok(learned_monte_carlo(
        config,
        &nets.beamsnet,
        &event,
        runs,
        seed,
        empirical_realizations,
        tick,
    )?)
}

/// A learned Monte Carlo as a table.
pub fn print_monte_carlo(out: &mut String, r: &LearnedMonteCarlo) -> std::fmt::Result {
    writeln!(
        out,
        "Monte Carlo ({}): {} runs from seed {}",
        r.scenario, r.runs, r.first_seed
    )?;
    writeln!(out, "({})", r.note)?;
    writeln!(
        out,
        "{:<56} {:>8} {:>15} {:>8} {:>8} {:>26} {:>28} {:>10}",
        "variant",
        "NEES",
        "band",
        "in band",
        "NIS",
        "pos RMSE mean [lo, hi] m",
        "vel RMSE mean [lo, hi] m/s",
        "corr"
    )?;
    for v in &r.variants {
        writeln!(
        out,
            "{:<56} {:>8.2} {:>7.2}-{:<7.2} {:>7.1}% {:>8.2} {:>8.3} [{:.3}, {:.3}] {:>9.4} [{:.4}, {:.4}] {:>10.2e}",
            v.label,
            v.nees_average,
            v.nees_band[0],
            v.nees_band[1],
            v.nees_epochs_in_band_percent,
            v.nis_average,
            v.position_rmse_m.mean,
            v.position_rmse_m.lo,
            v.position_rmse_m.hi,
            v.velocity_rmse_mps.mean,
            v.velocity_rmse_mps.lo,
            v.velocity_rmse_mps.hi,
            v.output_imu_correlation
        )?;
    }
    Ok(())
}
