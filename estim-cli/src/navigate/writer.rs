//! The run's observer: [`Writer`] writes `solution.csv` as the run goes, keeps the
//! track and the plot rows, scores the truth, and at the end writes `errors.csv`,
//! `track.geojson` and `summary.json`.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::PathBuf;

use anyhow::Context;
use estim::ins::{ErrorMatrix, InsState};
use estim::navigator::{format_heading, NavSolution, NavigationObserver, SolutionKind};
use estim::truth::Truth;
use serde_json::{json, Value};

use crate::output::StagedDir;

/// Writes the solution CSV as the run goes, keeps the track and evaluates truth.
pub struct Writer {
    epoch_s: f64,
    /// The solutions scored against the truth: the reference's own epochs
    /// ([`SolutionKind::Epoch`]) or the DVL epochs.
    scored: SolutionKind,
    last: Option<NavSolution>,
    rows: usize,
    csv: Option<std::io::BufWriter<std::fs::File>>,
    /// Where `solution.csv` goes once committed (named in write errors).
    csv_target: PathBuf,
    line: String,
    track: Vec<[f64; 2]>,
    truth: Option<Truth>,
    /// With scoring at the reference's epochs, the same truth scored at the DVL
    /// epochs (interpolated), as `estim reproduce` scores.
    dvl_truth: Option<Truth>,
    plot_rows: Option<Vec<crate::navigate_plots::PlotRow>>,
}

/// The header of `solution.csv` (also the first line of `navigate --stream`).
pub const CSV_HEADER: &str = "time_s,kind,latitude_deg,longitude_deg,depth_m,v_north_mps,v_east_mps,v_down_mps,roll_deg,pitch_deg,heading_deg,acc_bias_x_mps2,acc_bias_y_mps2,acc_bias_z_mps2,gyro_bias_x_radps,gyro_bias_y_radps,gyro_bias_z_radps,sigma_north_m,sigma_east_m,sigma_down_m,sigma_v_north_mps,sigma_v_east_mps,sigma_v_down_mps,sigma_roll_deg,sigma_pitch_deg,sigma_heading_deg,sigma_acc_bias_x_mps2,sigma_acc_bias_y_mps2,sigma_acc_bias_z_mps2,sigma_gyro_bias_x_radps,sigma_gyro_bias_y_radps,sigma_gyro_bias_z_radps\n";

impl NavigationObserver for Writer {
    fn on_solution(
        &mut self,
        kind: SolutionKind,
        s: &NavSolution,
        state: &InsState,
        covariance: &ErrorMatrix,
    ) -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
        if let Some(rows) = &mut self.plot_rows {
            rows.push(crate::navigate_plots::PlotRow::new(kind, s, covariance));
        }
        if matches!(kind, SolutionKind::Dvl | SolutionKind::End) {
            self.track.push([s.longitude_deg, s.latitude_deg]);
        }
        if kind == self.scored {
            if let Some(truth) = &mut self.truth {
                truth
                    .score(s.time, state, covariance)
                    .map_err(|e| e.to_string())?;
            }
        }
        if kind == SolutionKind::Dvl {
            if let Some(truth) = &mut self.dvl_truth {
                truth
                    .score(s.time, state, covariance)
                    .map_err(|e| e.to_string())?;
            }
        }
        if kind == SolutionKind::Epoch {
            // A reference epoch: scored, not a row of the solution.
            return Ok(());
        }
        self.write_row(kind, s)
    }
}

impl Writer {
    fn write_row(
        &mut self,
        kind: SolutionKind,
        s: &NavSolution,
    ) -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
        self.last = Some(*s);
        self.rows += 1;
        if let Some(csv) = &mut self.csv {
            let l = &mut self.line;
            solution_row(l, self.epoch_s, kind.as_str(), s);
            csv.write_all(l.as_bytes())
                .map_err(|e| format!("{}: cannot write: {e}", self.csv_target.display()))?;
        }
        Ok(())
    }
}

/// One line of `solution.csv` (with its newline) into `l`: `s` at `epoch_s + s.time`,
/// `kind` in the `kind` column.
pub fn solution_row(l: &mut String, epoch_s: f64, kind: &str, s: &NavSolution) {
    l.clear();
    let _ = write!(
        l,
        "{},{kind},{:.9},{:.9},{:.4},{:.5},{:.5},{:.5},{:.5},{:.5},{}",
        epoch_s + s.time,
        s.latitude_deg,
        s.longitude_deg,
        s.depth_m,
        s.velocity_ned_mps[0],
        s.velocity_ned_mps[1],
        s.velocity_ned_mps[2],
        s.roll_deg,
        s.pitch_deg,
        format_heading(s.heading_deg, 5)
    );
    for v in s.acc_bias_mps2.iter().chain(&s.gyro_bias_radps) {
        let _ = write!(l, ",{v:.4e}");
    }
    for v in s.position_sigma_m.iter().chain(&s.velocity_sigma_mps) {
        let _ = write!(l, ",{v:.5}");
    }
    for v in &s.attitude_sigma_deg {
        let _ = write!(l, ",{v:.6}");
    }
    for v in s.acc_bias_sigma_mps2.iter().chain(&s.gyro_bias_sigma_radps) {
        let _ = write!(l, ",{v:.4e}");
    }
    l.push('\n');
}

impl Writer {
    /// A writer of `solution.csv` in `dir` (none without a folder), evaluating `truth`.
    pub fn new(
        dir: Option<&StagedDir>,
        epoch_s: f64,
        truth: Option<Truth>,
    ) -> anyhow::Result<Self> {
        let csv_target = dir.map_or_else(PathBuf::new, |d| d.target().join("solution.csv"));
        let csv = match dir {
            Some(dir) => {
                let path = dir.path("solution.csv");
                let file = std::fs::File::create(&path)
                    .with_context(|| format!("{}: cannot create", csv_target.display()))?;
                let mut w = std::io::BufWriter::new(file);
                w.write_all(CSV_HEADER.as_bytes())
                    .with_context(|| format!("{}: cannot write", csv_target.display()))?;
                Some(w)
            }
            None => None,
        };
        Ok(Self {
            epoch_s,
            scored: SolutionKind::Dvl,
            last: None,
            rows: 0,
            csv,
            csv_target,
            line: String::new(),
            track: Vec::new(),
            truth,
            dvl_truth: None,
            plot_rows: None,
        })
    }

    /// Score the truth at the reference's own epochs (the run's
    /// [`SurveyInputs::output_epochs`](estim::navigator::SurveyInputs::output_epochs)
    /// must be the truth's epochs).
    #[must_use]
    pub fn scored_at_reference_epochs(mut self) -> Self {
        self.scored = SolutionKind::Epoch;
        self.dvl_truth = self.truth.clone();
        self
    }

    /// The evaluation at the DVL epochs, when the main one is at the reference's.
    pub fn dvl_epoch_truth(&self) -> Option<&Truth> {
        self.dvl_truth.as_ref()
    }

    /// Keep every solution for the plots.
    #[must_use]
    pub fn with_plot_rows(mut self, keep: bool) -> Self {
        self.plot_rows = keep.then(Vec::new);
        self
    }

    /// Write the plots of the kept solutions (and the truth's track over their span)
    /// into `dir`: the summary's `plots` block, or `None` when no plot was asked for.
    pub fn write_plots(
        &self,
        dir: &StagedDir,
        command: &str,
        solution_label: &str,
        nis: (&[f64], &[f64]),
        stopped: Option<&str>,
    ) -> Option<Value> {
        let rows = self.plot_rows.as_deref()?;
        let truth = match (self.truth.as_ref(), rows.first(), rows.last()) {
            (Some(t), Some(a), Some(b)) => t.track_deg(a.time, b.time),
            _ => Vec::new(),
        };
        Some(crate::navigate_plots::write_plots_or_warn(
            &dir.path(""),
            &crate::navigate_plots::PlotData {
                command,
                solution_label,
                rows,
                nis_times: nis.0,
                nis: nis.1,
                truth: &truth,
                stopped,
            },
        ))
    }

    /// The evaluation against truth, if any.
    pub fn truth(&self) -> Option<&Truth> {
        self.truth.as_ref()
    }

    /// How many solution rows were written (or would have been, without a folder).
    pub fn solution_rows(&self) -> usize {
        self.rows
    }

    /// The last solution row, if any.
    pub fn last_solution(&self) -> Option<NavSolution> {
        self.last
    }

    /// Flush the CSV and write `errors.csv` (with truth), `track.geojson` and
    /// `summary.json` into `dir` (the caller commits the staged folder).
    pub fn finish(
        &mut self,
        dir: &StagedDir,
        track_name: &str,
        summary: &Value,
    ) -> anyhow::Result<()> {
        if let Some(mut csv) = self.csv.take() {
            csv.flush()
                .with_context(|| format!("{}: cannot write", self.csv_target.display()))?;
        }
        if let Some(truth) = &self.truth {
            write_output(
                dir,
                "errors.csv",
                errors_csv(truth, self.epoch_s).as_bytes(),
            )?;
        }
        let track = track_geojson(track_name, &self.track);
        write_output(
            dir,
            "track.geojson",
            serde_json::to_string(&track)?.as_bytes(),
        )?;
        write_output(
            dir,
            "summary.json",
            serde_json::to_string_pretty(summary)?.as_bytes(),
        )?;
        Ok(())
    }
}

/// Write `text` as `name` into the staged `dir`; write errors name the file as it
/// will be in --out (a full disk).
fn write_output(dir: &StagedDir, name: &str, text: &[u8]) -> anyhow::Result<()> {
    std::fs::write(dir.path(name), text)
        .with_context(|| format!("{}: cannot write", dir.target().join(name).display()))
}

/// `errors.csv`: the truth's scored rows (errors and 1-sigma per state), times at
/// `epoch_s + t`.
fn errors_csv(truth: &Truth, epoch_s: f64) -> String {
    let mut text = String::from(
        "time_s,error_north_m,error_east_m,error_down_m,error_v_north_mps,error_v_east_mps,error_v_down_mps,error_roll_axis_deg,error_pitch_axis_deg,error_heading_deg,sigma_north_m,sigma_east_m,sigma_down_m,sigma_v_north_mps,sigma_v_east_mps,sigma_v_down_mps,sigma_roll_axis_deg,sigma_pitch_axis_deg,sigma_heading_deg\n",
    );
    for row in truth.rows() {
        let _ = write!(text, "{}", epoch_s + row[0]);
        for v in &row[1..] {
            let _ = write!(text, ",{v:.6e}");
        }
        text.push('\n');
    }
    text
}

/// `track.geojson`: the track (longitude, latitude) as one named line string.
fn track_geojson(name: &str, track: &[[f64; 2]]) -> Value {
    json!({
        "type": "FeatureCollection",
        "features": [{
            "type": "Feature",
            "properties": { "name": name },
            "geometry": { "type": "LineString", "coordinates": track },
        }],
    })
}
