//! `estim reproduce`: the paper end to end.

use std::path::PathBuf;

use std::fmt::Write as _;

use crate::study::{analyse, apply_faults, filter_label, Config, Scenario, TrajectoryReport};
use anyhow::Context;
use estim::datasets::data_root;

use crate::output::emit;

mod outputs;
use crate::schema::{document, path_json, status_result};
use outputs::write_outputs;

/// Arguments of `estim reproduce`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Folder holding A-KIT `TrajectoryN/` (or a data root holding `a-kit/`).
    /// Without it, the embedded simulated mission is used.
    #[arg(long, value_name = "DIR")]
    data: Option<PathBuf>,
    /// A-KIT trajectories to run (repeatable); default 4 and 13. Without --data the
    /// data is found through `ESTIM_DATA_DIR`, then `../shared/data`.
    #[arg(long = "trajectory", value_name = "N")]
    trajectories: Vec<u32>,
    /// A ground-truth CSV file at any path (one trajectory; with --dvl). Columns are
    /// found by name in any order, with units from the header (docs/cli.md, "Your own data").
    #[arg(long, value_name = "FILE", requires = "dvl", conflicts_with_all = ["data", "trajectories"])]
    gt: Option<PathBuf>,
    /// The DVL velocity CSV file of that trajectory (with --gt).
    #[arg(long, value_name = "FILE", requires = "gt")]
    dvl: Option<PathBuf>,
    /// Run on the common time span when GT and DVL do not cover the same span
    /// (otherwise an error); the choice is printed on stderr.
    #[arg(long)]
    allow_partial: bool,
    /// TOML configuration (see --print-config for every key and default).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Print the configuration in effect as TOML and exit.
    #[arg(long)]
    print_config: bool,
    /// Machine-readable JSON on stdout instead of tables.
    #[arg(long)]
    json: bool,
    /// BeamsNet ONNX model to use instead of the committed one (metadata JSON beside it).
    #[arg(long, value_name = "FILE")]
    model: Option<PathBuf>,
    /// Write CSV time series and plots (PNG, SVG) into this folder.
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Scenario: `paper` (default), `two-beams` (beams 1-2 only for 120 s, the
    /// two-beams network), `outage` (no DVL for 60 s, the outage network).
    #[arg(long, value_enum, default_value = "paper")]
    scenario: crate::learned_scenarios::ScenarioKind,
    /// Which IMU an A-KIT trajectory uses: `auto` (the recorded `IMU_trajectoryN.csv`
    /// where the folder holds one, else synthesized from the reference), `recorded`
    /// (an error where there is none) or `synthesized`. On a recorded IMU `--scenario
    /// two-beams` and `outage` use the networks trained on recorded windows.
    #[arg(long = "imu", value_enum, default_value = "auto")]
    imu: crate::study::ImuChoice,
    /// Vehicle file a recorded IMU is read with (axes, clocks, offsets, lever arms);
    /// default: the A-KIT vehicle, `vehicles/akit.toml`, embedded in the binary.
    #[arg(long, value_name = "FILE")]
    vehicle: Option<PathBuf>,
    /// Also smooth each trajectory (RTS, LS DVL, M = 0): smoothed vs filtered errors
    /// and NEES (files in `--out DIR/smoothing`).
    #[arg(long)]
    smooth: bool,
}

/// Run it. Exit status: see `schema` (3 when a filter variant failed).
pub fn run(args: Args) -> anyhow::Result<()> {
    let config = match &args.config {
        Some(path) => Config::from_file(path)?,
        None => Config::default(),
    };
    if args.print_config {
        return crate::output::emit(&config.to_commented_toml());
    }
    // Checked before any work: an unwritable --out fails now, naming the folder.
    let mut staged = match &args.out {
        Some(dir) => Some(crate::output::StagedDir::new(dir)?),
        None => None,
    };
    if let Some(dir) = &mut staged {
        dir.keep_inputs(
            [&args.config, &args.data, &args.gt, &args.dvl]
                .into_iter()
                .flatten()
                .map(std::path::PathBuf::as_path),
        );
    }
    let (scenarios, trajectories) = load_scenarios(&args, &config, args.imu)?;
    if args.scenario != crate::learned_scenarios::ScenarioKind::Paper {
        return run_learned(&args, &scenarios, &config, trajectories);
    }
    let learned = crate::learned::sensor(&config, args.model.as_deref())?;
    let reports: Vec<TrajectoryReport> = scenarios
        .iter()
        .map(|s| -> anyhow::Result<TrajectoryReport> {
            let inputs = match &learned {
                Some(make) => Some(make(s)?),
                None => None,
            };
            Ok(analyse(s, &config, inputs.as_ref(), config.seed)?)
        })
        .collect::<Result<_, _>>()?;
    let failures: usize = reports.iter().map(|r| r.failures.len()).sum();
    let inputs = serde_json::json!({
        "data": path_json(args.data.as_deref()),
        "trajectories": trajectories,
        "config_file": path_json(args.config.as_deref()),
        "model": match &args.model {
            Some(path) => path_json(Some(path)),
            None => serde_json::Value::from(estim::models::BEAMSNET_NAME),
        },
        // On a recorded IMU without --model: the network trained on recorded windows.
        "model_recorded_imu": match &args.model {
            Some(path) => path_json(Some(path)),
            None => serde_json::Value::from(estim::models::BEAMSNET_RECORDED_NAME),
        },
        "out": path_json(args.out.as_deref()),
        "seed": config.seed,
        "config": config,
    });
    let smoothed = if args.smooth {
        let cross = crate::study::CrossSource::Zero;
        Some(crate::study::cli::smooth::smooth_all(
            &scenarios, &config, &cross,
        )?)
    } else {
        None
    };
    let mut payload = serde_json::json!({ "trajectories": reports });
    if let Some(s) = &smoothed {
        payload["smoothing"] = serde_json::to_value(s)?;
    }
    let json = serde_json::to_string_pretty(&document("reproduce", inputs, failures, payload))?;
    // Outputs first: on failure nothing is printed as if it had succeeded.
    // Everything, the smoothing files included, in one commit.
    if let Some(staged) = staged {
        if let Some(s) = &smoothed {
            let dir = staged.path("smoothing");
            std::fs::create_dir(&dir)
                .with_context(|| format!("{}: cannot create", dir.display()))?;
            crate::study::cli::smooth::write_files(&dir, s)?;
        }
        write_outputs(staged, &reports, &json)?;
    }
    if args.json {
        emit(&format!("{json}\n"))?;
    } else {
        let mut text = String::new();
        for r in &reports {
            print_report(&mut text, r)?;
        }
        if let Some(s) = &smoothed {
            crate::study::cli::smooth::print_reports(&mut text, s)?;
        }
        emit(&text)?;
    }
    status_result(failures)
}

/// The scenarios of a run (the embedded mission, `--gt`/`--dvl`, or A-KIT
/// trajectories), a partial span warned about on stderr, the configured faults
/// applied; the trajectory numbers for the JSON inputs.
fn load_scenarios(
    args: &Args,
    config: &Config,
    imu: crate::study::ImuChoice,
) -> anyhow::Result<(Vec<Scenario>, Option<Vec<u32>>)> {
    let (scenarios, trajectories): (Vec<Scenario>, Option<Vec<u32>>) =
        match (&args.data, &args.gt, &args.dvl) {
            (_, Some(gt), Some(dvl)) => (
                vec![Scenario::recorded(
                    gt,
                    dvl,
                    config,
                    config.seed,
                    args.allow_partial,
                )?],
                None,
            ),
            (Some(_), _, _) | (None, None, None)
                if args.data.is_some() || !args.trajectories.is_empty() =>
            {
                let dir = data_root(args.data.as_deref()).context(
                    "--trajectory needs the A-KIT data: pass --data DIR, set ESTIM_DATA_DIR, \
                     or place it at ../shared/data",
                )?;
                let list = if args.trajectories.is_empty() {
                    vec![4, 13]
                } else {
                    args.trajectories.clone()
                };
                let s = list
                    .iter()
                    .map(|n| {
                        Scenario::akit_choosing(
                            &dir,
                            *n,
                            config,
                            config.seed,
                            args.allow_partial,
                            imu,
                            args.vehicle.as_deref(),
                        )
                    })
                    .collect::<Result<_, _>>()?;
                (s, Some(list))
            }
            _ => (vec![Scenario::simulated(config, config.seed)?], None),
        };
    for s in &scenarios {
        if let Some(span) = s.span.filter(|span| !span.agrees()) {
            let [a, b] = span.overlap_s().unwrap_or(span.gt_s);
            eprintln!(
                "warning: --allow-partial: {}: {}; running on the overlap {a:.3}-{b:.3} s only",
                s.name,
                span.describe()
            );
        }
    }
    let mut scenarios = scenarios;
    for s in &mut scenarios {
        apply_faults(s, &config.faults, config.seed)?;
    }
    Ok((scenarios, trajectories))
}

/// `--scenario two-beams` or `outage`: the learned-event study on `scenarios`.
fn run_learned(
    args: &Args,
    scenarios: &[Scenario],
    config: &Config,
    trajectories: Option<Vec<u32>>,
) -> anyhow::Result<()> {
    let outage = args.scenario == crate::learned_scenarios::ScenarioKind::Outage;
    let studies = crate::learned_scenarios::reproduce_learned(scenarios, config, outage)?;
    if args.json {
        let inputs = serde_json::json!({
            "data": path_json(args.data.as_deref()),
            "trajectories": trajectories,
            "config_file": path_json(args.config.as_deref()),
            "scenario": if outage { "outage" } else { "two-beams" },
            "seed": config.seed,
            "config": config,
        });
        let payload = serde_json::json!({ "studies": studies });
        let doc = document("reproduce", inputs, 0, payload);
        emit(&format!("{}\n", serde_json::to_string_pretty(&doc)?))?;
    } else {
        let mut text = String::new();
        for s in &studies {
            crate::learned_scenarios::print_study(&mut text, s)?;
        }
        emit(&text)?;
    }
    Ok(())
}

fn print_report(out: &mut String, r: &TrajectoryReport) -> std::fmt::Result {
    writeln!(
        out,
        "== {} ({:.0} s, {} DVL epochs, IMU {})",
        r.name,
        r.duration_s,
        r.dvl_epochs,
        r.imu_source.as_str()
    )?;
    if let Some(recorded) = &r.recorded {
        writeln!(
            out,
            "recorded IMU read with {}; reference clock offset {} s; errors and NEES (over \
             {} states with truth) at the reference's epochs",
            recorded["vehicle"].as_str().unwrap_or("?"),
            recorded["truth_time_offset"]["offset_s"],
            recorded["nees_states"]
        )?;
    }
    writeln!(out, "velocity norm vs DVL reference (paper Tables I/II):")?;
    writeln!(
        out,
        "  {:<10} {:>10} {:>10} {:>10} {:>10}",
        "method", "RMSE [m/s]", "MAE [m/s]", "R^2", "VAF [%]"
    )?;
    // LS first, then the learned sources.
    let mut rows: Vec<_> = r.velocity.iter().collect();
    rows.sort_by_key(|(id, _)| (id.as_str() != crate::study::LS, id.as_str()));
    for (id, m) in rows {
        writeln!(
            out,
            "  {:<10} {:>10.6} {:>10.6} {:>10.6} {:>10.4}",
            filter_label(id, f64::NAN),
            m.rmse,
            m.mae,
            m.r2,
            m.vaf
        )?;
    }
    writeln!(
        out,
        "filters (std = time average / final, summed over axes; errors RMSE / final):"
    )?;
    for f in &r.filters {
        writeln!(out, "  {} [{}]", f.name, f.id)?;
        for (g, s) in &f.std {
            writeln!(
                out,
                "    std {:<17} {:>12.4e} / {:>12.4e}",
                format!("{g} [{}]", group_unit(g)),
                s.time_average,
                s.final_value
            )?;
        }
        writeln!(
            out,
            "    error position {:.3} / {:.3} m (horizontal {:.3} / {:.3} m), velocity {:.4} / {:.4} m/s, attitude {:.4} / {:.4} deg",
            f.position_error_m.rmse,
            f.position_error_m.final_value,
            f.horizontal_position_error_m.rmse,
            f.horizontal_position_error_m.final_value,
            f.velocity_error_mps.rmse,
            f.velocity_error_mps.final_value,
            f.attitude_error_deg.rmse,
            f.attitude_error_deg.final_value
        )?;
        writeln!(
            out,
            "    NEES {:.2} (95% band {:.2}-{:.2}), NIS {:.2} (band {:.2}-{:.2}), updates {} accepted / {} gated",
            f.nees_average, f.nees_band[0], f.nees_band[1], f.nis_average, f.nis_band[0], f.nis_band[1],
            f.updates_accepted, f.updates_rejected
        )?;
        writeln!(
            out,
            "    joint covariance: min eigenvalue {:.3e}, invalid updates {}, largest valid rho (median) {:.3}; P not positive definite at {} epochs",
            f.joint_min_eigenvalue, f.joint_invalid_updates, f.largest_valid_rho, f.covariance_not_positive_definite_epochs
        )?;
    }
    for failure in &r.failures {
        writeln!(out, "  FAILED: {failure}")?;
    }
    for imp in &r.improvements {
        writeln!(
            out,
            "  improvement of {} over M neglected (time average / final):",
            imp.variant
        )?;
        for (g, v) in &imp.groups {
            writeln!(
                out,
                "    {:<13} {:>7.2} % / {:>7.2} %",
                g, v.time_average_percent, v.final_percent
            )?;
        }
    }
    Ok(())
}

/// Unit of a state group's std.
fn group_unit(group: &str) -> &'static str {
    match group {
        "position" => "m",
        "velocity" => "m/s",
        "misalignment" => "rad",
        "acc_bias" => "m/s^2",
        "gyro_bias" => "rad/s",
        _ => "?",
    }
}

/// File-name stem of a report ("simulated", "trajectory4").
fn slug(r: &TrajectoryReport) -> String {
    match r.trajectory {
        Some(n) => format!("trajectory{n}"),
        None if r.name == "simulated mission" => "simulated".to_string(),
        None => "trajectory".to_string(),
    }
}
