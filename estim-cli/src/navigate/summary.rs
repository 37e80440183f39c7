//! The summary of a survey run: `summary.json`'s document (inputs, counts, NIS, the
//! final solution, the evaluation against truth) and its text form.

use std::fmt::Write as _;

use estim::navigator::{format_heading, NavSolution, NavigationRun, NavigatorConfig};
use estim::truth::{Truth, TruthTimeOffset};
use serde_json::{json, Value};

use super::{Survey, SurveyFiles};
use crate::schema;

/// The reference's clock offset in effect, as the summary gives it (`source`,
/// `offset_s`, and for an estimate its `sigma_s`, `residual_rad`, `intervals`).
pub fn time_offset_json(offset: &TruthTimeOffset) -> Value {
    match offset {
        TruthTimeOffset::Vehicle(tau) => json!({ "source": "vehicle", "offset_s": tau }),
        TruthTimeOffset::Estimated(est) => json!({
            "source": "estimated",
            "offset_s": est.offset_s,
            "sigma_s": est.sigma_s,
            "residual_rad": est.residual_rad,
            "intervals": est.intervals,
        }),
    }
}

fn stats(values: &[f64]) -> Value {
    let finite: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    if finite.is_empty() {
        return json!({ "count": values.len(), "mean": null, "max": null });
    }
    let mean = finite.iter().sum::<f64>() / finite.len() as f64;
    let max = finite.iter().copied().fold(f64::MIN, f64::max);
    json!({ "count": values.len(), "mean": mean, "max": max })
}

/// The evaluation of a run scored at the reference's own epochs ([`Writer`]'s
/// `scored_at_reference_epochs`), with the same scored at the DVL epochs (the truth
/// interpolated there) as `at_dvl_epochs`.
pub fn reference_epochs_evaluation_json(writer: &super::Writer) -> Value {
    let mut evaluation = evaluation_json(writer.truth());
    if let (Some(e), Some(dvl)) = (evaluation.as_object_mut(), writer.dvl_epoch_truth()) {
        e.insert("scored_at".into(), json!("reference_epochs"));
        e.insert("at_dvl_epochs".into(), evaluation_json(Some(dvl)));
    }
    evaluation
}

/// The evaluation block of the summary (position RMSE, final error, NEES at the DVL
/// epochs).
pub fn evaluation_json(truth: Option<&Truth>) -> Value {
    let Some(t) = truth else { return Value::Null };
    let e = t.evaluation();
    // No epoch scored: every figure is null, with the reason (never an RMSE of 0).
    let not_scored = (e.epochs == 0).then(|| {
        format!(
            "no solution epoch was scored against the truth ({} outside its span); scored at \
             the DVL epochs, a run without a DVL update has none",
            e.epochs_outside_truth
        )
    });
    json!({
        "horizontal_position_rmse_m": e.horizontal_position_rmse_m,
        "nees_per_group": {
            "position": e.nees_per_group[0],
            "velocity": e.nees_per_group[1],
            "attitude": e.nees_per_group[2],
        },
        "epochs": e.epochs,
        "epochs_outside_truth": e.epochs_outside_truth,
        "truth_time_offset_s": t.time_offset().offset_s(),
        "truth_time_offset": time_offset_json(t.time_offset()),
        "truth_velocity_bias": t.velocity_bias().map(|b| json!({
            "bias_mps": b.bias_mps,
            "sigma_mps": b.sigma_mps,
            "residual_rms_m": b.residual_rms_m,
            "intervals": b.intervals,
            "removed": b.removed,
        })),
        "position_rmse_m": e.position_rmse_m,
        "final_position_error_m": e.final_position_error_m,
        "nees_average": e.nees_average,
        "nees_states": e.nees_states,
        "covariance_not_positive_definite_epochs": e.covariance_not_positive_definite_epochs,
        "not_scored_reason": not_scored,
    })
}

/// Which DVL sensor a run used, for the summary.
pub fn dvl_source(files: &SurveyFiles) -> &'static str {
    match (&files.sensors.dvl, &files.sensors.beams, &files.sensors.pd0) {
        (Some(_), _, _) => "velocity_csv",
        (None, Some(_), _) => "beams_csv",
        _ => "pd0",
    }
}

/// The summary document of a survey run (`command` = `navigate` or `smooth`):
/// `inputs`, the run's counts and NIS, the final solution of `last` (the filter's, or
/// the smoother's), the evaluation, and the `extra` fields merged at the top level.
pub fn summary_json(
    command: &str,
    survey: &Survey,
    run: &NavigationRun,
    last: &NavSolution,
    rate: Option<f64>,
    evaluation: Value,
    extra: Value,
) -> Value {
    let files = &survey.files;
    let epoch = survey.epoch;
    let counts = |c: &estim::navigator::UpdateCounts| json!({ "accepted": c.accepted, "gated": c.gated, "recovered": c.recovered });
    let f = last;
    let mut body = json!({
        "epoch_s": epoch,
        "time_span_s": [epoch + run.span_s[0], epoch + run.span_s[1]],
        "imu_samples": run.imu_samples,
        "imu_period_s": run.imu_period_s,
        "initial": run.alignment,
        "dvl_source": dvl_source(files),
        "updates": {
            "dvl": counts(&run.dvl),
            "depth": counts(&run.depth),
            "fixes": counts(&run.fixes),
        },
        "dvl_no_lock_rows": run.dvl_no_lock,
        "dvl_insufficient_beam_rows": run.dvl_insufficient_beams,
        "outside_imu_span": run.outside_imu_span,
        "dvl_gaps_coasted": run.dvl_gaps_coasted,
        "longest_dvl_gap_s": run.longest_dvl_gap_s,
        "dvl_noise_scale": run.dvl_noise_scale,
        "dvl_states": dvl_states_json(run, &survey.config),
        "nis": {
            "dvl": stats(&run.dvl_nis),
            "depth": stats(&run.depth_nis),
            "fixes": stats(&run.fix_nis),
        },
        "pd0": survey.pd0,
        "warnings": survey.warnings,
        "solutions": run.solutions,
        "final": {
            "time_s": epoch + f.time,
            "latitude_deg": f.latitude_deg,
            "longitude_deg": f.longitude_deg,
            "depth_m": f.depth_m,
            "position_sigma_m": f.position_sigma_m,
            "heading_deg": f.heading_deg,
            "heading_sigma_deg": f.attitude_sigma_deg[2],
        },
        "evaluation": evaluation,
    });
    if let (Some(b), Value::Object(e)) = (body.as_object_mut(), extra) {
        b.extend(e);
    }
    schema::document(command, inputs_json(survey, rate), 0, body)
}

/// The summary's `inputs` block of a survey run (`navigate`, `smooth`; a completed or
/// a stopped run): every input path, the rate and the configuration in effect.
pub fn inputs_json(survey: &Survey, rate: Option<f64>) -> Value {
    let files = &survey.files;
    json!({
        "imu": schema::path_json(Some(&files.sensors.imu)),
        "dvl": schema::path_json(files.sensors.dvl.as_deref()),
        "beams": schema::path_json(files.sensors.beams.as_deref()),
        "pd0": schema::path_json(files.sensors.pd0.as_deref()),
        "depth": schema::path_json(files.sensors.depth.as_deref()),
        "fixes": schema::path_json(files.sensors.fixes.as_deref()),
        "vehicle": schema::path_json(files.sensors.vehicle.as_deref()),
        "truth": schema::path_json(files.truth.as_deref()),
        "rate_hz": rate,
        "configuration": survey.config,
    })
}

/// The final DVL error states of a run with `[dvl_states]` (null without): each
/// state's value and 1-sigma, and the time offset in total (the configured stamp
/// shift plus the estimated rest), in the units of the `[dvl]` keys they refine.
fn dvl_states_json(run: &NavigationRun, config: &NavigatorConfig) -> Value {
    let (Some(s), Some(states)) = (&run.dvl_states, &config.dvl_states) else {
        return Value::Null;
    };
    json!({
        "estimated": {
            "scale_factor": states.scale_factor.estimate,
            "misalignment": states.misalignment.estimate,
            "bias": states.bias.estimate,
            "lever_arm": states.lever_arm.estimate,
            "time_offset": states.time_offset.estimate,
        },
        "scale_factor": 1.0 + s.scale_factor_error,
        "scale_factor_sigma": s.scale_factor_sigma,
        "mounting_misalignment_rad": s.misalignment_rad,
        "mounting_misalignment_sigma_rad": s.misalignment_sigma_rad,
        "bias_mps": s.bias_mps,
        "bias_sigma_mps": s.bias_sigma_mps,
        "lever_arm_m": s.lever_arm_m,
        "lever_arm_sigma_m": s.lever_arm_sigma_m,
        "time_offset_s": config.dvl.time_offset_s + s.time_offset_s,
        "time_offset_sigma_s": s.time_offset_sigma_s,
    })
}

/// The text summary of a survey run.
pub fn summary_text(
    verb: &str,
    run: &NavigationRun,
    last: &NavSolution,
    summary: &Value,
) -> String {
    let f = last;
    let mut text = String::new();
    let _ = writeln!(
        text,
        "{verb} {} IMU samples ({:.1} s); DVL updates {} accepted, {} gated, {} recovered; {} rows without lock skipped; {} gaps coasted",
        run.imu_samples,
        run.span_s[1] - run.span_s[0],
        run.dvl.accepted,
        run.dvl.gated,
        run.dvl.recovered,
        run.dvl_no_lock,
        run.dvl_gaps_coasted
    );
    let _ = writeln!(
        text,
        "final: lat {:.7} deg, lon {:.7} deg, depth {:.2} m, heading {} deg; 1-sigma N/E {:.2}/{:.2} m",
        f.latitude_deg,
        f.longitude_deg,
        f.depth_m,
        format_heading(f.heading_deg, 2),
        f.position_sigma_m[0],
        f.position_sigma_m[1]
    );
    if let Some(d) = &run.dvl_states {
        let mrad =
            |v: &[f64; 3]| format!("[{:.2}, {:.2}, {:.2}]", v[0] * 1e3, v[1] * 1e3, v[2] * 1e3);
        let _ = writeln!(
            text,
            "DVL states: scale factor {:.5} +- {:.5}, misalignment {} +- {} mrad, lever arm [{:.3}, {:.3}, {:.3}] m, time offset {:.3} +- {:.3} s",
            summary["dvl_states"]["scale_factor"].as_f64().unwrap_or(f64::NAN),
            d.scale_factor_sigma,
            mrad(&d.misalignment_rad),
            mrad(&d.misalignment_sigma_rad),
            d.lever_arm_m[0],
            d.lever_arm_m[1],
            d.lever_arm_m[2],
            summary["dvl_states"]["time_offset_s"].as_f64().unwrap_or(f64::NAN),
            d.time_offset_sigma_s
        );
    }
    let evaluation = summary.get("evaluation").filter(|v| !v.is_null());
    if let Some(reason) = evaluation.and_then(|e| e["not_scored_reason"].as_str()) {
        let _ = writeln!(text, "against truth: not scored: {reason}");
    } else if let Some(e) = evaluation {
        let number = |key: &str| e[key].as_f64().unwrap_or(f64::NAN);
        let _ = writeln!(
            text,
            "against truth: position RMSE {:.3} m (horizontal {:.3} m), average NEES {:.3} \
             over {} states at {} epochs",
            number("position_rmse_m"),
            number("horizontal_position_rmse_m"),
            number("nees_average"),
            e["nees_states"],
            e["epochs"]
        );
    }
    text
}
