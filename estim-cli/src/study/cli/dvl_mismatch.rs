//! `estim dvl mismatch`: `dvl.akit_reference_mismatch_std_mps` fitted on the A-KIT
//! training trajectories ([`fit_reference_mismatch`]), as CSV or JSON. The flags are
//! parsed by `crate::dvl`.

use std::fmt::Write as _;

use anyhow::Context;
use estim_dvl::nalgebra::Vector3;

use crate::dvl::MismatchArgs;
use crate::study::{fit_reference_mismatch, Config, AKIT_TEST_TRAJECTORIES};

/// Run it: the whole output is written only on success.
pub fn run(args: &MismatchArgs) -> anyhow::Result<()> {
    crate::output::emit(&mismatch(args)?)
}

fn mismatch(args: &MismatchArgs) -> anyhow::Result<String> {
    let config = match &args.config {
        Some(path) => Config::from_file(path)?,
        None => Config::default(),
    };
    let dir = estim::datasets::data_root(args.data.as_deref()).context(
        "no data folder: pass --data DIR, set ESTIM_DATA_DIR, or place the data at ../shared/data",
    )?;
    let held_out = if args.held_out.is_empty() {
        AKIT_TEST_TRAJECTORIES.to_vec()
    } else {
        args.held_out.clone()
    };
    let fit = fit_reference_mismatch(&dir, &config, &held_out)?;
    let v = |v: &Vector3<f64>| [v.x, v.y, v.z];
    if args.json {
        use crate::schema::{document, path_json};
        let inputs = serde_json::json!({
            "data": path_json(Some(&dir)),
            "config": path_json(args.config.as_deref()),
            "held_out": held_out,
            "lever_arm_m": config.dvl.lever_arm_m,
            "akit_time_offset_s": config.dvl.akit_time_offset_s,
        });
        let trajectories: Vec<_> = fit
            .trajectories
            .iter()
            .map(|t| {
                serde_json::json!({
                    "trajectory": t.trajectory,
                    "samples": t.samples,
                    "overlapping_samples": t.overlapping,
                    "mean_mps": v(&t.mean),
                    "rms_mps": v(&t.rms),
                })
            })
            .collect();
        let doc = document(
            "dvl mismatch",
            inputs,
            0,
            serde_json::json!({
                "rms_all_mps": fit.rms_all,
                "robust_std_mps": fit.robust_std,
                "samples": fit.samples,
                "mean_mps": v(&fit.mean),
                "rms_mps": v(&fit.rms),
                "trajectories": trajectories,
            }),
        );
        return Ok(format!("{}\n", serde_json::to_string_pretty(&doc)?));
    }
    let mut out = String::from(
        "trajectory,samples,overlapping_samples,mean_x_mps,mean_y_mps,mean_z_mps,rms_x_mps,rms_y_mps,rms_z_mps\n",
    );
    let row =
        |out: &mut String, name: &str, n: usize, o: usize, m: &Vector3<f64>, r: &Vector3<f64>| {
            let _ = writeln!(
                out,
                "{name},{n},{o},{:.5},{:.5},{:.5},{:.5},{:.5},{:.5}",
                m.x, m.y, m.z, r.x, r.y, r.z
            );
        };
    for t in &fit.trajectories {
        row(
            &mut out,
            &t.trajectory.to_string(),
            t.samples,
            t.overlapping,
            &t.mean,
            &t.rms,
        );
    }
    let overlapping = fit.trajectories.iter().map(|t| t.overlapping).sum();
    row(
        &mut out,
        "all",
        fit.samples,
        overlapping,
        &fit.mean,
        &fit.rms,
    );
    let _ = writeln!(
        out,
        "# pooled over epochs and axes (held out: {held_out:?}): RMS {:.4} m/s, robust std {:.4} m/s",
        fit.rms_all, fit.robust_std
    );
    Ok(out)
}
