//! `estim smooth` without `--imu`: the 15-state INS/DVL filter on the simulated
//! mission and A-KIT trajectories (also `estim reproduce --smooth`), recorded and
//! smoothed (exact with correlated noise), smoothed against filtered errors versus
//! ground truth, plus NEES. The flags are parsed by `crate::smooth`.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::smooth::ScenarioMode;
use crate::study::{
    apply_faults, smooth_scenario, Config, CrossSource, ImuSource, Scenario, SmoothReport,
};
use anyhow::Context;
use estim::datasets::data_root;
use rayon::prelude::*;

/// Run it on the scenarios that `args` names.
pub fn run(args: ScenarioMode) -> anyhow::Result<()> {
    let config = match &args.config {
        Some(path) => Config::from_file(path)?,
        None => Config::default(),
    };
    let cross = match args.rho {
        None => CrossSource::Zero,
        Some(rho) if rho.is_finite() && (-1.0..=1.0).contains(&rho) => CrossSource::Scaled(rho),
        Some(rho) => anyhow::bail!("--rho {rho}: a correlation must be finite and in [-1, 1]"),
    };
    // Checked before any work: an unwritable --out fails now, naming the folder.
    let mut staged = match &args.out {
        Some(dir) => Some(crate::output::StagedDir::new(dir)?),
        None => None,
    };
    if let Some(dir) = &mut staged {
        dir.keep_inputs(
            [&args.config, &args.data]
                .into_iter()
                .flatten()
                .map(PathBuf::as_path),
        );
    }
    let mut scenarios = vec![Scenario::simulated(&config, config.seed)?];
    if args.data.is_some() || !args.trajectories.is_empty() {
        let dir = data_root(args.data.as_deref()).context(
            "--trajectory needs the A-KIT data: pass --data DIR, set ESTIM_DATA_DIR, \
             or place it at ../shared/data",
        )?;
        let list = if args.trajectories.is_empty() {
            vec![4, 13]
        } else {
            args.trajectories.clone()
        };
        for n in list {
            scenarios.push(Scenario::akit_choosing(
                &dir,
                n,
                &config,
                config.seed,
                false,
                args.imu_source,
                None,
            )?);
        }
    }
    for s in &mut scenarios {
        apply_faults(s, &config.faults, config.seed)?;
    }
    let reports = smooth_all(&scenarios, &config, &cross)?;
    if let Some(staged) = staged {
        write_files(&staged.path(""), &reports)?;
        staged.commit()?;
    }
    let mut text = String::new();
    if args.json {
        use crate::schema::{document, path_json};
        let inputs = serde_json::json!({
            "data": path_json(args.data.as_deref()),
            "trajectories": args.trajectories,
            "config_file": path_json(args.config.as_deref()),
            "rho": args.rho,
            "out": path_json(args.out.as_deref()),
            "seed": config.seed,
            // Which IMU each trajectory used is `imu_source` in its report.
            "imu": args.imu_source,
            "config": config,
        });
        let doc = document(
            "smooth",
            inputs,
            0,
            serde_json::json!({ "reports": reports }),
        );
        writeln!(text, "{}", serde_json::to_string_pretty(&doc)?)?;
    } else {
        print_reports(&mut text, &reports)?;
    }
    crate::output::emit(&text)
}

/// Smooth every scenario (in parallel), M = 0 or the given cross-covariance.
pub fn smooth_all(
    scenarios: &[Scenario],
    config: &Config,
    cross: &CrossSource,
) -> anyhow::Result<Vec<SmoothReport>> {
    scenarios
        .par_iter()
        .map(|s| {
            smooth_scenario(s, config, cross, config.seed)
                .with_context(|| format!("smoothing {}", s.name))
        })
        .collect()
}

/// The filtered-against-smoothed tables.
pub fn print_reports(out: &mut String, reports: &[SmoothReport]) -> std::fmt::Result {
    for r in reports {
        let imu = match r.imu_source {
            ImuSource::Recorded => {
                "recorded IMU read through vehicles/akit.toml, the navigator's own pass"
            }
            ImuSource::Synthesized => "IMU synthesized from the ground truth",
        };
        writeln!(
            out,
            "== {} ({imu}, LS DVL, {}, {} epochs): filtered vs smoothed against ground truth",
            r.name,
            r.cross,
            r.time.len()
        )?;
        writeln!(
            out,
            "{:<10} {:>12} {:>12} {:>14} {:>14} {:>10}",
            "", "pos RMSE m", "pos final m", "vel RMSE m/s", "att RMSE deg", "mean NEES"
        )?;
        for (name, s) in [
            ("filtered", &r.filtered_summary),
            ("smoothed", &r.smoothed_summary),
        ] {
            writeln!(
                out,
                "{:<10} {:>12.3} {:>12.3} {:>14.4} {:>14.4} {:>10.2}",
                name,
                s.position_m.rmse,
                s.position_m.final_value,
                s.velocity_mps.rmse,
                s.attitude_deg.rmse,
                s.mean_nees
            )?;
        }
        writeln!(
            out,
            "(NEES of the {n}-state error; {n} for a consistent estimate)\n",
            n = r.nees_states
        )?;
    }
    Ok(())
}

/// File-name stem of a report.
fn slug(r: &SmoothReport) -> String {
    match r.trajectory {
        Some(n) => format!("trajectory{n}"),
        None => "simulated".to_string(),
    }
}

/// CSV time series and the position-error plot of every report, into `dir` (a
/// folder inside a staging folder: the caller commits it with its other outputs).
pub fn write_files(dir: &Path, reports: &[SmoothReport]) -> anyhow::Result<()> {
    use crate::plots::{line_chart, LineChart, Series};
    use std::io::Write;

    let file = |name: &str| dir.join(name);
    std::fs::write(
        file("smoothing.json"),
        serde_json::to_string_pretty(reports)?,
    )
    .with_context(|| format!("{}: cannot write", file("smoothing.json").display()))?;
    for r in reports {
        let stem = slug(r);
        let path = file(&format!("{stem}_smoothing.csv"));
        // A write error (a full disk) names the file.
        let named = |e: std::io::Error| anyhow::anyhow!("{}: cannot write: {e}", path.display());
        let mut w = std::io::BufWriter::new(
            std::fs::File::create(&path)
                .with_context(|| format!("{}: cannot create", path.display()))?,
        );
        writeln!(
            w,
            "time_s,filtered_position_error_m,filtered_position_3sigma_m,smoothed_position_error_m,smoothed_position_3sigma_m,filtered_velocity_error_mps,smoothed_velocity_error_mps,filtered_attitude_error_deg,smoothed_attitude_error_deg,filtered_nees,smoothed_nees"
        )
        .map_err(named)?;
        let (f, s) = (&r.filtered, &r.smoothed);
        for k in 0..r.time.len() {
            writeln!(
                w,
                "{},{},{},{},{},{},{},{},{},{},{}",
                r.time[k],
                f.position_error[k],
                f.position_3sigma[k],
                s.position_error[k],
                s.position_3sigma[k],
                f.velocity_error[k],
                s.velocity_error[k],
                f.attitude_error_deg[k],
                s.attitude_error_deg[k],
                f.nees[k],
                s.nees[k]
            )
            .map_err(named)?;
        }
        w.flush().map_err(named)?;
        drop(w);
        let chart = LineChart {
            title: &format!("{}: position error, filtered and smoothed", r.name),
            x_label: "time [s]",
            y_label: "|position error| and 3 sqrt(trace P_pos) [m]",
            series: vec![
                Series {
                    id: "smooth_filtered",
                    label: "filtered error",
                    x: &r.time,
                    y: &f.position_error,
                },
                Series {
                    id: "smooth_filtered_3sigma",
                    label: "filtered 3-sigma",
                    x: &r.time,
                    y: &f.position_3sigma,
                },
                Series {
                    id: "smooth_smoothed",
                    label: "smoothed error",
                    x: &r.time,
                    y: &s.position_error,
                },
                Series {
                    id: "smooth_smoothed_3sigma",
                    label: "smoothed 3-sigma",
                    x: &r.time,
                    y: &s.position_3sigma,
                },
            ],
            hlines: vec![],
            log_y: false,
            equal_axes: false,
        };
        line_chart(&file(&format!("{stem}_smoothed_position")), &chart)
            .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
    }
    Ok(())
}
