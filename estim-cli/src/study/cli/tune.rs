//! `estim tune --trajectories`: the maximum-likelihood fit ([`tune_akit`]) on A-KIT
//! training trajectories, printed as `crate::tune` prints a survey's fit. The flags are
//! parsed by `crate::tune`.

use anyhow::Context;

use crate::study::{tune_akit, Config, ImuSelection};
use crate::tune::{finish, json, table, TrajectoryMode};

/// Run it on the trajectories that `args` names.
pub fn run(args: TrajectoryMode) -> anyhow::Result<()> {
    let options = &args.options;
    let config = match &args.config {
        Some(path) => Config::from_file(path)?,
        None => Config::default(),
    };
    let seed = match args.seed {
        Some(seed) => {
            crate::schema::check_seeds("--seed", seed, 0)?;
            seed
        }
        None => config.seed,
    };
    let dir = estim::datasets::data_root(args.data.as_deref()).context(
        "no data folder: pass --data DIR, set ESTIM_DATA_DIR, or place the data at ../shared/data",
    )?;
    let selection = ImuSelection {
        choice: args.imu_source,
        vehicle: args.vehicle.clone(),
    };
    let report = tune_akit(&dir, &args.trajectories, &config, seed, &selection, options)?;
    let recorded = report.imu_source == Some("recorded");
    let text = if args.json {
        use crate::schema::path_json;
        let inputs = serde_json::json!({
            "data": path_json(Some(&dir)),
            "config": path_json(args.config.as_deref()),
            "trajectories": report.trajectories,
            "seed": seed,
            "linearizations": args.linearizations,
            "imu": if recorded {
                "recorded, read through the vehicle file"
            } else {
                "synthesized from the ground truth with the configured error model"
            },
            // Every trajectory's IMU (one fit, one source), as `reproduce` says it.
            "imu_source": report.imu_source,
            "vehicle": if recorded {
                args.vehicle.as_ref().map_or_else(
                    || serde_json::Value::from("vehicles/akit.toml (embedded)"),
                    |p| path_json(Some(p)),
                )
            } else {
                serde_json::Value::Null
            },
        });
        json(inputs, &report)?
    } else {
        let list: Vec<String> = report.trajectories.iter().map(u32::to_string).collect();
        let imu = if recorded {
            "The IMU is the recorded one, read through the vehicle file (15-state fit)."
        } else {
            "The IMU is synthesized from the ground truth with the configured error model \
             (column `synthesized`)."
        };
        let head = format!(
            "Maximum likelihood on A-KIT trajectories {} ({} DVL epochs; {} left out as \
             shared with a test trajectory). {imu}",
            list.join(", "),
            report.epochs.iter().sum::<usize>(),
            report.overlapping.iter().sum::<usize>(),
        );
        table(&head, &report)
    };
    finish(&text, &report)
}
