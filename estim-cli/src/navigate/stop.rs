//! A run stopped by divergence or a numerical failure: the `stop` block and what is
//! kept of the run.

use estim::navigator::NavigatorError;
use serde_json::{json, Value};

use super::{evaluation_json, inputs_json, Survey, Writer};
use crate::output::StagedDir;
use crate::schema;

/// The `stop` block of a run that ended early: its status, time and reason.
pub fn stop_json(epoch: f64, error: &NavigatorError) -> (&'static str, Value) {
    match error {
        NavigatorError::Diverged { time, reason } => (
            "diverged",
            json!({
                "time_s": epoch + time,
                "time_since_epoch_s": time,
                "reason": reason.to_string(),
                "check": reason,
            }),
        ),
        NavigatorError::Filter { time, source } => (
            "failed",
            json!({
                "time_s": epoch + time,
                "time_since_epoch_s": time,
                "reason": source.to_string(),
            }),
        ),
        other => ("failed", json!({ "reason": other.to_string() })),
    }
}

/// A run stopped by divergence or a numerical failure: the solution rows before the
/// stop, the track and a summary marked `partial` are committed to `--out` (exit 3);
/// nothing of the stopped run is reported as a solution.
pub fn stopped(
    command: &str,
    survey: &Survey,
    writer: &mut Writer,
    staged: Option<StagedDir>,
    error: &NavigatorError,
    rate: Option<f64>,
    json_out: bool,
) -> anyhow::Result<()> {
    let (status, stop) = stop_json(survey.epoch, error);
    let mut summary = schema::document(
        command,
        inputs_json(survey, rate),
        0,
        json!({
            "epoch_s": survey.epoch,
            "partial": true,
            "stop": stop,
            "solution_rows_before_stop": writer.solution_rows(),
            "last_solution_before_stop": writer.last_solution().map(|f| json!({
                "time_s": survey.epoch + f.time,
                "latitude_deg": f.latitude_deg,
                "longitude_deg": f.longitude_deg,
                "depth_m": f.depth_m,
                "position_sigma_m": f.position_sigma_m,
            })),
            "evaluation_before_stop": evaluation_json(writer.truth()),
            "warnings": survey.warnings,
        }),
    );
    summary["status"] = json!(status);
    let kept = match staged {
        Some(dir) => {
            // The plots of the solutions before the stop (their axes bounded by the
            // valid part, see navigate_plots); the NIS were not kept.
            let note = format!(
                "{status} at t = {:.1} s",
                stop["time_since_epoch_s"].as_f64().unwrap_or(f64::NAN)
            );
            if let Some(plots) =
                writer.write_plots(&dir, command, "filter", (&[], &[]), Some(&note))
            {
                summary["plots"] = plots;
            }
            writer.finish(
                &dir,
                &format!("estim {command} track before the stop (partial)"),
                &summary,
            )?;
            let path = dir.target().to_path_buf();
            dir.commit()?;
            format!(
                "the {} solution rows before the stop are in {} (summary.json: \"partial\": true)",
                writer.solution_rows(),
                path.display()
            )
        }
        None => "nothing was written (no --out)".to_string(),
    };
    if json_out {
        crate::output::emit(&format!("{}\n", serde_json::to_string_pretty(&summary)?))?;
    }
    Err(schema::RunStopped {
        message: format!(
            "{command} {status} at t = {} s: {}; {kept}",
            stop["time_s"],
            stop["reason"].as_str().unwrap_or("")
        ),
    }
    .into())
}
