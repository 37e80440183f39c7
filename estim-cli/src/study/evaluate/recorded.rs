//! A cell on a recorded IMU (module docs of `evaluate`, "On a recorded IMU").

use super::*;

/// The two variants on a recorded IMU's cell (module docs, "On a recorded IMU"): the
/// vehicle file's navigator, and the same without DVL error states for the comparison.
pub(super) fn recorded_cell(
    n: u32,
    seed: u64,
    scenario: &Scenario,
    recorded: &RecordedSurvey,
    config: &Config,
    learned: &LearnedSource,
) -> Result<Vec<std::result::Result<EvaluationRun, String>>> {
    let [ls, net] = recorded_sets(scenario, config, learned)?;
    let fifteen = recorded.without_dvl_states()?;
    let applied = recorded.settings.config().dvl.time_offset_s;
    let mut out = Vec::with_capacity(2);
    for (id, set) in [(LS, ls), (BEAMSNET_NEGLECTED, net)] {
        let finding = |e: PipelineError| -> Result<String> {
            match e {
                e @ (PipelineError::FilterStopped { .. } | PipelineError::NavigatorAt { .. }) => {
                    Ok(format!("trajectory {n}, seed {seed}, {id}: {e}"))
                }
                e => Err(e),
            }
        };
        let comparison =
            match crate::study::run_recorded(id, scenario, &fifteen, &set, &CrossSource::Zero) {
                Ok(run) => summarise(&run)?.position_error_m.rmse,
                Err(e) => {
                    finding(e)?;
                    f64::NAN
                }
            };
        let run = match crate::study::run_recorded(id, scenario, recorded, &set, &CrossSource::Zero)
        {
            Ok(run) => run,
            Err(e) => {
                out.push(Err(finding(e)?));
                continue;
            }
        };
        let states = run.final_dvl_states;
        out.push(Ok(EvaluationRun {
            trajectory: n,
            seed,
            id: id.to_string(),
            imu_source: ImuSource::Recorded,
            nees_states: run.nees_states,
            nees: finite_mean(&run.nees),
            nis: finite_mean(&run.nis),
            position_rmse_m: summarise(&run)?.position_error_m.rmse,
            accepted: run.accepted,
            rejected: run.rejected,
            applied_time_offset_s: applied,
            time_offset_s: states.map_or([0.0, 0.0], |s| [s.time_offset_s, s.time_offset_sigma_s]),
            scale_factor_error: states.map_or([f64::NAN, f64::NAN], |s| {
                [s.scale_factor_error, s.scale_factor_sigma]
            }),
            noise_scale: run.final_noise_scale.unwrap_or(1.0),
            fifteen_state_position_rmse_m: comparison,
        }));
    }
    Ok(out)
}
