//! `estim evaluate`: the INS/DVL filter with DVL error states on the A-KIT
//! trajectories, its parameters fitted on training trajectories only.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context;
use estim::datasets::data_root;
use estim::navigator::DvlStatesConfig;

use crate::output::emit;
use crate::schema::{document, path_json, status_result};
use crate::study::{
    evaluate, evaluation_markdown, fit_training, Config, Evaluation, ImuSelection, ImuSource,
    MAX_SEED,
};

/// Arguments of `estim evaluate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Folder holding A-KIT `TrajectoryN/` (or a data root holding `a-kit/`); else
    /// `ESTIM_DATA_DIR`, then `../shared/data`.
    #[arg(long, value_name = "DIR")]
    data: Option<PathBuf>,
    /// Trajectories evaluated (repeatable); default all 13.
    #[arg(long = "trajectory", value_name = "N")]
    trajectories: Vec<u32>,
    /// Trajectories the DVL model and states are fitted on (comma-separated); 4 and 13
    /// are refused.
    #[arg(
        long = "fit-trajectories",
        value_name = "N,N,..",
        value_delimiter = ',',
        default_value = "1,2,3,5,6,7,8,9,10,11,12"
    )]
    fit_trajectories: Vec<u32>,
    /// First seed; the seeds are S, S+1, ..., S+seeds-1.
    #[arg(long = "first-seed", value_name = "S", default_value_t = 2000)]
    first_seed: u64,
    /// Number of seeds per trajectory (1-1000).
    #[arg(long, value_name = "N", default_value_t = 5)]
    seeds: u64,
    /// TOML configuration of the study (see `estim reproduce --print-config`).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// TOML of the DVL states (`[scale_factor]` with `estimate`, `prior_std`;
    /// `[misalignment]` with `estimate`, `prior_std_rad`; `[lever_arm]` with
    /// `estimate`, `prior_std_m`; `[time_offset]` with `estimate`, `prior_std_s`;
    /// `[bias]` with `estimate`, `std_mps`, `time_constant_s`), replacing the fitted
    /// priors. The misalignment and lever-arm sigmas are a number or three per axis
    /// (0 holds that axis).
    #[arg(long, value_name = "FILE")]
    states: Option<PathBuf>,
    /// Add DVL noise growing with the angular rate, R + κ² |ω|² I, κ fitted on the
    /// training residuals (the Gauss-Markov bias then from the calm epochs only).
    #[arg(long)]
    rate_noise: bool,
    /// Adapt the DVL noise level online in each run: one scale on R and the bias
    /// variance, estimated from the run's past innovations with a memory of N DVL
    /// updates (1-100000).
    #[arg(long = "adaptive-noise", value_name = "N")]
    adaptive_noise: Option<usize>,
    /// Which IMU a trajectory uses: `auto` (the recorded `IMU_trajectoryN.csv` where
    /// the folder holds one, else synthesized from the reference), `recorded` (an
    /// error where there is none) or `synthesized`. A recorded IMU runs the vehicle
    /// file's navigator (its `[dvl_states]`, time offset and R) in place of the fit;
    /// `--states`, `--rate-noise` and `--adaptive-noise` are then refused.
    #[arg(long = "imu", value_enum, default_value = "auto")]
    imu: crate::study::ImuChoice,
    /// Vehicle file a recorded IMU is read with; default: the A-KIT vehicle,
    /// `vehicles/akit.toml`, embedded in the binary.
    #[arg(long, value_name = "FILE")]
    vehicle: Option<PathBuf>,
    /// JSON on stdout.
    #[arg(long)]
    json: bool,
}

/// Run it. Exit status 2 for bad input (a test trajectory in the fit set), 3 when a
/// run stopped on a numerical failure (the others are reported).
pub fn run(args: Args) -> anyhow::Result<()> {
    let config = match &args.config {
        Some(path) => Config::from_file(path)?,
        None => Config::default(),
    };
    crate::study::check_fit_trajectories(&args.fit_trajectories)?;
    if !(1..=1000).contains(&args.seeds) {
        anyhow::bail!("--seeds {} is outside 1-1000", args.seeds);
    }
    if let Some(n) = args.adaptive_noise {
        if !(1..=100_000).contains(&n) {
            anyhow::bail!("--adaptive-noise {n} is outside 1-100000");
        }
    }
    let last = args
        .first_seed
        .checked_add(args.seeds - 1)
        .filter(|s| *s <= MAX_SEED)
        .with_context(|| format!("--first-seed plus --seeds exceeds {MAX_SEED}"))?;
    let states = match &args.states {
        Some(path) => {
            let text = estim::datasets::read_text_file(path)?;
            // One line: the line number and the message, not toml's multi-line report.
            let states: DvlStatesConfig = toml::from_str(&text).map_err(|e| {
                let line = e
                    .span()
                    .map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1);
                match line {
                    Some(l) => anyhow::anyhow!("{}: line {l}: {}", path.display(), e.message()),
                    None => anyhow::anyhow!("{}: {}", path.display(), e.message()),
                }
            })?;
            states
                .check()
                .with_context(|| format!("{}", path.display()))?;
            Some(states)
        }
        None => None,
    };
    let dir = data_root(args.data.as_deref()).context(
        "evaluate needs the A-KIT data: pass --data DIR, set ESTIM_DATA_DIR, \
         or place it at ../shared/data",
    )?;
    let trajectories = if args.trajectories.is_empty() {
        (1..=13).collect()
    } else {
        args.trajectories.clone()
    };
    let seeds: Vec<u64> = (args.first_seed..=last).collect();
    let fit = fit_training(&dir, &config, &args.fit_trajectories, args.rate_noise)?;
    let evaluation = evaluate(
        &dir,
        &config,
        fit,
        states,
        args.adaptive_noise,
        &trajectories,
        &seeds,
        &ImuSelection {
            choice: args.imu,
            vehicle: args.vehicle.clone(),
        },
    )?;
    let failures = evaluation.failures.len();
    if args.json {
        let inputs = serde_json::json!({
            "data": path_json(args.data.as_deref()),
            "trajectories": trajectories,
            "fit_trajectories": args.fit_trajectories,
            "seeds": seeds,
            "config_file": path_json(args.config.as_deref()),
            "states_file": path_json(args.states.as_deref()),
            "rate_noise": args.rate_noise,
            "adaptive_noise": args.adaptive_noise,
            "imu": args.imu,
            "vehicle": path_json(args.vehicle.as_deref()),
            "config": config,
        });
        let body = serde_json::json!({ "evaluation": evaluation, "failures": evaluation.failures });
        let doc = document("evaluate", inputs, failures, body);
        emit(&format!("{}\n", serde_json::to_string_pretty(&doc)?))?;
    } else {
        let mut text = header(
            &args,
            &config,
            &evaluation,
            [trajectories.len(), seeds.len()],
            last,
        )?;
        text.push_str(&evaluation_markdown(&evaluation));
        for f in &evaluation.failures {
            writeln!(text, "FAILED: {f}")?;
        }
        emit(&text)?;
    }
    status_result(failures)
}

/// The text's opening lines: which trajectories ran on a recorded IMU, the filter,
/// seeds and the synthesized IMU's model.
fn header(
    args: &Args,
    config: &Config,
    evaluation: &Evaluation,
    [trajectories, seeds]: [usize; 2],
    last: u64,
) -> anyhow::Result<String> {
    let mut text = String::new();
    let recorded: Vec<u32> = evaluation
        .rows
        .iter()
        .filter(|r| r.imu_source == Some(ImuSource::Recorded))
        .map(|r| r.trajectory)
        .fold(Vec::new(), |mut v, t| {
            if !v.contains(&t) {
                v.push(t);
            }
            v
        });
    if !recorded.is_empty() {
        writeln!(
            text,
            "Recorded IMU on trajectories {recorded:?} (marked \"recorded\" below): read \
             with {}, the vehicle file's navigator (its DVL error states, time offset and \
             R) in place of the fit; NEES over the 9 states with truth at the reference's \
             epochs; the seeds redraw only the protocol's beam noise. The rest below is \
             the synthesized IMU's.",
            args.vehicle
                .as_deref()
                .map_or("the embedded vehicles/akit.toml".into(), |p| p
                    .display()
                    .to_string()),
        )?;
    }
    writeln!(
        text,
        "INS/DVL filter with DVL error states (scale factor, misalignment, Gauss-Markov \
         bias, lever arm, time offset); {} trajectories x {} seeds ({}-{}), gate \
         probability {}.\n\
         Synthesized IMU: from the ground truth (error model `{}`), DVL real (LS: beams by \
         the BeamsNet protocol from the real DVL); the seeds redraw only the synthetic \
         noise. NEES over the 15 INS states against truth. {}\n",
        trajectories,
        seeds,
        args.first_seed,
        last,
        config.filter.gate_probability,
        config.imu.preset,
        match args.adaptive_noise {
            Some(n) => format!(
                "DVL noise level adapted online (memory {n} updates): the NIS is near 3 \
                 by construction, the NEES is the check."
            ),
            None => "DVL noise level fixed by the fit.".into(),
        },
    )?;
    Ok(text)
}
