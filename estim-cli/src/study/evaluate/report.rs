//! The evaluation as markdown.

use super::*;

/// The evaluation as markdown: the fit, then per trajectory LS and BeamsNet, then the
/// counts.
pub fn markdown(e: &Evaluation) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    fit_text(&mut s, &e.fit);
    let trajectories: Vec<u32> = {
        let mut t: Vec<u32> = e.rows.iter().map(|r| r.trajectory).collect();
        t.dedup();
        t
    };
    variants_table(&mut s, e, &trajectories);
    comparison_table(&mut s, e, &trajectories);
    for c in &e.counts {
        let _ = writeln!(
            s,
            "{}: NEES within [0.5, 2] x its states with truth on {} of {} trajectories; NIS within [0.5, 2] x 3 on {} of {}.",
            super::super::filter_label(&c.id, f64::NAN),
            c.nees_in_band,
            c.trajectories,
            c.nis_in_band,
            c.trajectories
        );
    }
    s
}

/// The fit's paragraph.
fn fit_text(s: &mut String, f: &TrainingFit) {
    use std::fmt::Write as _;
    let _ = writeln!(
        s,
        "Fit on training trajectories {:?} (4 and 13 never used): lever arm [{:.3}, {:.3}, {:.3}] m, \
         scale-factor error {:+.5}, misalignment [{:+.5}, {:+.5}, {:+.5}] rad; time offset prior \
         {:.3} s +- {:.3} s (training offsets {}); {}; \
         white residual std {:.4} m/s, rate noise {:.3} m/s per rad/s ({} residual epochs).\n",
        f.trajectories,
        f.lever_arm_m[0],
        f.lever_arm_m[1],
        f.lever_arm_m[2],
        f.scale_factor_error,
        f.misalignment_rad[0],
        f.misalignment_rad[1],
        f.misalignment_rad[2],
        f.time_offset_s,
        f.time_offset_std_s,
        f.calibrations
            .iter()
            .map(|c| format!("{}: {:.2}", c.trajectory, c.time_offset_s))
            .collect::<Vec<_>>()
            .join(", "),
        if f.bias_estimated {
            format!(
                "bias Gauss-Markov sigma {:.4} m/s, tau {:.1} s",
                f.bias_std_mps, f.bias_time_constant_s
            )
        } else {
            format!(
                "no Gauss-Markov part in the residuals (autocovariances {:.2e}, {:.2e}, \
                 {:.2e} m^2/s^2): bias not estimated",
                f.autocovariance[0], f.autocovariance[1], f.autocovariance[2]
            )
        },
        f.white_std_mps,
        f.rate_noise_mps_per_radps,
        f.residual_samples,
    );
}

/// Per trajectory, LS and BeamsNet with the augmented filter.
fn variants_table(s: &mut String, e: &Evaluation, trajectories: &[u32]) {
    use std::fmt::Write as _;
    let adaptive = e.adaptive_noise_window.is_some();
    s.push_str(
        "| trajectory | LS: NEES / NIS / position RMSE [m] | BeamsNet, M neglected: NEES / NIS / \
         position RMSE [m] | final time offset LS / BeamsNet [s] |",
    );
    s.push_str(if adaptive {
        " final DVL noise scale LS / BeamsNet |\n|---|---|---|---|---|\n"
    } else {
        "\n|---|---|---|---|\n"
    });
    for &t in trajectories {
        let cell = |id: &str| e.rows.iter().find(|r| r.trajectory == t && r.id == id);
        let text = |r: Option<&EvaluationRow>| match r {
            Some(r) if r.runs > 0 => format!(
                "{:.1}{} / {:.2}{} / {:.2}",
                r.nees,
                if r.nees_in_band { "" } else { " (out)" },
                r.nis,
                if r.nis_in_band { "" } else { " (out)" },
                r.position_rmse_m
            ),
            _ => "failed".into(),
        };
        let offset = |r: Option<&EvaluationRow>| r.map_or(f64::NAN, |r| r.time_offset_s);
        let scale = |r: Option<&EvaluationRow>| r.map_or(f64::NAN, |r| r.noise_scale);
        let _ = write!(
            s,
            "| {} | {} | {} | {:.2} / {:.2} |",
            trajectory_label(e, t),
            text(cell(LS)),
            text(cell(BEAMSNET_NEGLECTED)),
            offset(cell(LS)),
            offset(cell(BEAMSNET_NEGLECTED)),
        );
        if adaptive {
            let _ = write!(
                s,
                " {:.3} / {:.3} |",
                scale(cell(LS)),
                scale(cell(BEAMSNET_NEGLECTED))
            );
        }
        s.push('\n');
    }
}

/// Per trajectory, the paired difference to the 15-state filter.
fn comparison_table(s: &mut String, e: &Evaluation, trajectories: &[u32]) {
    use std::fmt::Write as _;
    s.push('\n');
    let _ = writeln!(
        s,
        "Position RMSE against the 15-state filter of `estim reproduce --data` (no DVL states, \
         fixed R, time offset {:.2} s; on a recorded IMU the vehicle file's navigator without \
         its DVL states) on the same seeds, so on the same IMU: this filter minus that one, \
         mean [95 % t interval over the seeds; the seeds redraw synthetic noise only].\n",
        e.fifteen_state_time_offset_s
    );
    s.push_str(
        "| trajectory | 15-state LS / BeamsNet [m] | LS: difference [m] | BeamsNet, M neglected: \
         difference [m] |\n|---|---|---|---|\n",
    );
    for t in trajectories {
        let cell = |id: &str| e.rows.iter().find(|r| r.trajectory == *t && r.id == id);
        let base =
            |r: Option<&EvaluationRow>| r.map_or(f64::NAN, |r| r.fifteen_state_position_rmse_m);
        let diff = |r: Option<&EvaluationRow>| match r {
            Some(r) => super::super::paired::interval_text(&r.position_rmse_difference_m, 2),
            None => "failed".into(),
        };
        let _ = writeln!(
            s,
            "| {} | {:.2} / {:.2} | {} | {} |",
            trajectory_label(e, *t),
            base(cell(LS)),
            base(cell(BEAMSNET_NEGLECTED)),
            diff(cell(LS)),
            diff(cell(BEAMSNET_NEGLECTED)),
        );
    }
    s.push('\n');
}

/// `t`, marked `(test)` for a held-out trajectory and `(recorded)` where its runs
/// integrated the recorded IMU.
fn trajectory_label(e: &Evaluation, t: u32) -> String {
    let mut label = t.to_string();
    if AKIT_TEST_TRAJECTORIES.contains(&t) {
        label.push_str(" (test)");
    }
    let recorded = e
        .rows
        .iter()
        .any(|r| r.trajectory == t && r.imu_source == Some(ImuSource::Recorded));
    if recorded {
        label.push_str(" (recorded)");
    }
    label
}
