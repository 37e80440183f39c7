//! The per-trajectory rows of an evaluation.

use super::*;

/// Per trajectory and variant, the means over the seeds' runs.
pub(super) fn evaluation_rows(
    trajectories: &[u32],
    runs: &[EvaluationRun],
    fit: &TrainingFit,
) -> Vec<EvaluationRow> {
    let mut rows = Vec::new();
    for &t in trajectories {
        for id in EVALUATED_VARIANTS {
            let mine: Vec<&EvaluationRun> = runs
                .iter()
                .filter(|r| r.trajectory == t && r.id == id)
                .collect();
            let mean = |f: &dyn Fn(&EvaluationRun) -> f64| {
                finite_mean(&mine.iter().map(|r| f(r)).collect::<Vec<_>>())
            };
            let nees = mean(&|r| r.nees);
            let nis = mean(&|r| r.nis);
            let differences: Vec<f64> = mine
                .iter()
                .map(|r| r.position_rmse_m - r.fifteen_state_position_rmse_m)
                .filter(|d| d.is_finite())
                .collect();
            let nees_states = mine.first().map_or(ERROR_STATES, |r| r.nees_states);
            let applied = mine
                .first()
                .map_or(fit.time_offset_s, |r| r.applied_time_offset_s);
            rows.push(EvaluationRow {
                imu_source: mine.first().map(|r| r.imu_source),
                nees_states,
                fifteen_state_position_rmse_m: mean(&|r| r.fifteen_state_position_rmse_m),
                position_rmse_difference_m: PairedInterval::of(&differences, LEVEL),
                trajectory: t,
                id: id.to_string(),
                runs: mine.len(),
                nees,
                nis,
                position_rmse_m: mean(&|r| r.position_rmse_m),
                nees_in_band: in_band(nees, nees_states as f64),
                nis_in_band: in_band(nis, 3.0),
                time_offset_s: applied + mean(&|r| r.time_offset_s[0]),
                noise_scale: mean(&|r| r.noise_scale),
            });
        }
    }
    rows
}
