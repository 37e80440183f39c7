//! `estim.navigate`: the INS/DVL navigator (estim-nav) on a survey's files, its
//! solution returned as NumPy arrays. The same loader and navigator as `estim
//! navigate`: the vehicle file's axes, clocks, offsets and noise, and with a truth
//! file the evaluation at the reference's own epochs.

use std::path::PathBuf;

use estim_nav::navigator::{
    navigate as run_navigator, NavSolution, NavigationObserver, NavigationRun, NavigatorConfig,
    NavigatorError, SolutionKind, UpdateCounts,
};
use estim_nav::truth::{read_vehicle, Truth, TruthTimeOffset};
use estim_nav::{check_survey, SurveyError, SurveyFiles, SurveyWarning};
use numpy::ndarray::Array2;
use numpy::IntoPyArray;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::EstimError;

/// A survey error as an `EstimError` (it names the file and line, or the key).
fn survey_err(e: SurveyError) -> PyErr {
    EstimError::new_err(e.to_string())
}

/// Keeps every solution and scores the truth at its epochs.
struct Collector {
    rows: Vec<(SolutionKind, NavSolution)>,
    truth: Option<Truth>,
}

impl NavigationObserver for Collector {
    fn on_solution(
        &mut self,
        kind: SolutionKind,
        solution: &NavSolution,
        state: &estim_ins::InsState,
        covariance: &estim_ins::ErrorMatrix,
    ) -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
        if kind == SolutionKind::Epoch {
            // A reference epoch: scored, not a row of the solution.
            if let Some(truth) = &mut self.truth {
                truth.score(solution.time, state, covariance)?;
            }
            return Ok(());
        }
        self.rows.push((kind, *solution));
        Ok(())
    }
}

/// (n, 3) from one triple per row.
fn triples<'py>(
    py: Python<'py>,
    rows: &[(SolutionKind, NavSolution)],
    f: impl Fn(&NavSolution) -> [f64; 3],
) -> Bound<'py, numpy::PyArray2<f64>> {
    Array2::from_shape_fn((rows.len(), 3), |(i, j)| f(&rows[i].1)[j]).into_pyarray(py)
}

/// One column per row.
fn column<'py>(
    py: Python<'py>,
    rows: &[(SolutionKind, NavSolution)],
    f: impl Fn(&NavSolution) -> f64,
) -> Bound<'py, numpy::PyArray1<f64>> {
    numpy::PyArray1::from_iter(py, rows.iter().map(|(_, s)| f(s)))
}

fn counts<'py>(py: Python<'py>, c: &UpdateCounts) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("accepted", c.accepted)?;
    d.set_item("gated", c.gated)?;
    d.set_item("recovered", c.recovered)?;
    Ok(d)
}

/// The INS/DVL navigator on a survey's files.
///
/// The same loader and navigator as ``estim navigate``: ``imu`` (CSV), one DVL source
/// (``dvl`` velocity CSV, ``beams`` CSV or ``pd0`` file), optional ``depth`` and
/// ``fixes`` CSVs, and the ``vehicle`` TOML (axes, clocks, offsets, lever arms, noise,
/// initial state). With ``truth`` (a reference CSV) the run is scored at the
/// reference's own epochs (clock aligned per the vehicle's ``[truth]`` table, else
/// estimated); ``init_from_truth`` starts from the truth's state. ``rate_hz`` adds
/// solutions at that rate besides every DVL epoch.
///
/// Returns a dict of NumPy arrays, one row per solution: ``time_s`` (the files' own
/// time), ``kind`` (``'dvl'`` or ``'rate'``), ``latitude_deg``, ``longitude_deg``,
/// ``depth_m``, ``velocity_ned_mps`` (n, 3), ``attitude_deg`` (n, 3: roll, pitch,
/// heading), ``acc_bias_mps2``, ``gyro_bias_radps``, their 1-sigmas
/// ``position_sigma_m`` (N, E, D), ``velocity_sigma_mps``, ``attitude_sigma_deg``,
/// ``acc_bias_sigma_mps2``, ``gyro_bias_sigma_radps``; ``epoch_s``; ``dvl``,
/// ``depth``, ``fixes`` update counts; ``dvl_nis`` and ``dvl_nis_time_s``;
/// ``warnings`` (dicts of ``code``, ``file``, ``message``: a DVL file without lock
/// beside depth or fixes, an ``imu.rate_hz`` that does not fit the IMU file; each is
/// also issued as a ``UserWarning``); and with a
/// truth ``evaluation`` (RMSE, NEES) and ``errors`` (``time_s``, ``error`` and
/// ``sigma`` (m, 9): position N, E, D [m], velocity [m/s], misalignment [deg]).
///
/// Raises ``EstimError`` naming the file and line or the key for bad input (an aiding
/// file none of whose records falls in the IMU's span, a DVL file without lock and
/// nothing else aiding the INS, among others), and for a
/// run that diverged or failed (its epoch and reason): a diverged solution is never
/// returned.
#[pyfunction]
#[pyo3(signature = (imu, dvl=None, beams=None, pd0=None, depth=None, fixes=None, vehicle=None, truth=None, init_from_truth=false, rate_hz=None))]
#[allow(clippy::too_many_arguments)]
fn navigate<'py>(
    py: Python<'py>,
    imu: PathBuf,
    dvl: Option<PathBuf>,
    beams: Option<PathBuf>,
    pd0: Option<PathBuf>,
    depth: Option<PathBuf>,
    fixes: Option<PathBuf>,
    vehicle: Option<PathBuf>,
    truth: Option<PathBuf>,
    init_from_truth: bool,
    rate_hz: Option<f64>,
) -> PyResult<Bound<'py, PyDict>> {
    if let Some(rate) = rate_hz {
        if !(rate.is_finite() && rate > 0.0) {
            return Err(EstimError::new_err(format!(
                "rate_hz {rate}: not a positive rate"
            )));
        }
    }
    if init_from_truth && truth.is_none() {
        return Err(EstimError::new_err("init_from_truth needs a truth file"));
    }
    let files = SurveyFiles {
        imu,
        dvl,
        beams,
        pd0,
        depth,
        fixes,
        vehicle,
    };
    let (collector, run, epoch, found) =
        py.detach(move || run_survey(&files, truth.as_deref(), init_from_truth, rate_hz))?;
    let out = solution(py, &collector.rows, &run, epoch)?;
    out.set_item("warnings", warnings(py, &found)?)?;
    match &collector.truth {
        None => {
            out.set_item("evaluation", py.None())?;
            out.set_item("errors", py.None())?;
        }
        Some(t) => {
            out.set_item("evaluation", evaluation(py, t)?)?;
            out.set_item("errors", errors(py, t, epoch)?)?;
        }
    }
    Ok(out)
}

/// Read the survey `files` (with the truth `truth`, scored at its own epochs) and run
/// the navigator: the solutions, the run's counts and the epoch every time is
/// relative to.
fn run_survey(
    files: &SurveyFiles,
    truth: Option<&std::path::Path>,
    init_from_truth: bool,
    rate_hz: Option<f64>,
) -> PyResult<(Collector, NavigationRun, f64, Vec<SurveyWarning>)> {
    let mut config = match &files.vehicle {
        Some(p) => read_vehicle(p).map_err(survey_err)?,
        None => NavigatorConfig::default(),
    };
    let mut loaded = files.read(&config, &mut |_, _| {}).map_err(|e| match e {
        SurveyError::NoDvl => EstimError::new_err("no DVL file: give dvl=, beams= or pd0="),
        e => survey_err(e),
    })?;
    let truth = match truth {
        Some(p) => Some(Truth::load(p, &loaded, &config).map_err(survey_err)?),
        None => None,
    };
    if let Some(t) = &truth {
        if init_from_truth || config.truth.initial_state {
            t.set_initial(&loaded, &mut config).map_err(survey_err)?;
        }
        loaded.inputs.output_epochs = t.epochs().to_vec();
    }
    loaded.settle_initial(&config).map_err(survey_err)?;
    let found = check_survey(files, &config, &loaded.inputs, loaded.epoch).map_err(survey_err)?;
    let mut collector = Collector {
        rows: Vec::new(),
        truth,
    };
    let epoch = loaded.epoch;
    let run =
        run_navigator(&loaded.inputs, &loaded.settings, rate_hz, &mut collector).map_err(|e| {
            match e {
                NavigatorError::Diverged { time, reason } => EstimError::new_err(format!(
                    "navigate diverged at t = {} s ({time} s after the IMU's first sample): \
                 {reason}; no solution is returned",
                    epoch + time
                )),
                NavigatorError::Filter { time, source } => EstimError::new_err(format!(
                    "navigate stopped at t = {} s ({time} s after the IMU's first sample): \
                 {source}; no solution is returned",
                    epoch + time
                )),
                e => EstimError::new_err(e.to_string()),
            }
        })?;
    Ok((collector, run, epoch, found))
}

/// Each warning of the survey's checks issued as a Python `UserWarning` and listed as
/// a dict (`code`, `file`, `message`).
fn warnings<'py>(
    py: Python<'py>,
    found: &[SurveyWarning],
) -> PyResult<Bound<'py, pyo3::types::PyList>> {
    let list = pyo3::types::PyList::empty(py);
    for w in found {
        let message = std::ffi::CString::new(w.message.replace('\0', " "))
            .map_err(|e| EstimError::new_err(e.to_string()))?;
        let category = py.get_type::<pyo3::exceptions::PyUserWarning>();
        PyErr::warn(py, category.as_any(), &message, 1)?;
        let d = PyDict::new(py);
        d.set_item("code", w.code)?;
        d.set_item("file", w.file.display().to_string())?;
        d.set_item("message", &w.message)?;
        list.append(d)?;
    }
    Ok(list)
}

/// One (n, 3) column of the solution from its row.
type Triple = fn(&NavSolution) -> [f64; 3];

/// The solution's columns, update counts and DVL NIS (times on the files' clock).
fn solution<'py>(
    py: Python<'py>,
    rows: &[(SolutionKind, NavSolution)],
    run: &NavigationRun,
    epoch: f64,
) -> PyResult<Bound<'py, PyDict>> {
    let out = PyDict::new(py);
    out.set_item("status", "ok")?;
    out.set_item("epoch_s", epoch)?;
    out.set_item("time_s", column(py, rows, |s| epoch + s.time))?;
    let kinds: Vec<&str> = rows.iter().map(|(k, _)| k.as_str()).collect();
    out.set_item("kind", kinds)?;
    out.set_item("latitude_deg", column(py, rows, |s| s.latitude_deg))?;
    out.set_item("longitude_deg", column(py, rows, |s| s.longitude_deg))?;
    out.set_item("depth_m", column(py, rows, |s| s.depth_m))?;
    let triple_columns: [(&str, Triple); 9] = [
        ("velocity_ned_mps", |s| s.velocity_ned_mps),
        ("attitude_deg", |s| [s.roll_deg, s.pitch_deg, s.heading_deg]),
        ("acc_bias_mps2", |s| s.acc_bias_mps2),
        ("gyro_bias_radps", |s| s.gyro_bias_radps),
        ("position_sigma_m", |s| s.position_sigma_m),
        ("velocity_sigma_mps", |s| s.velocity_sigma_mps),
        ("attitude_sigma_deg", |s| s.attitude_sigma_deg),
        ("acc_bias_sigma_mps2", |s| s.acc_bias_sigma_mps2),
        ("gyro_bias_sigma_radps", |s| s.gyro_bias_sigma_radps),
    ];
    for (name, f) in triple_columns {
        out.set_item(name, triples(py, rows, f))?;
    }
    out.set_item("dvl", counts(py, &run.dvl)?)?;
    out.set_item("depth", counts(py, &run.depth)?)?;
    out.set_item("fixes", counts(py, &run.fixes)?)?;
    out.set_item("dvl_nis", numpy::PyArray1::from_slice(py, &run.dvl_nis))?;
    out.set_item(
        "dvl_nis_time_s",
        numpy::PyArray1::from_iter(py, run.dvl_nis_times.iter().map(|t| epoch + t)),
    )?;
    Ok(out)
}

/// The evaluation against the truth `t`: RMSE, NEES and the reference's clock offset
/// and velocity bias.
fn evaluation<'py>(py: Python<'py>, t: &Truth) -> PyResult<Bound<'py, PyDict>> {
    let e = t.evaluation();
    let ev = PyDict::new(py);
    ev.set_item("epochs", e.epochs)?;
    ev.set_item("epochs_outside_truth", e.epochs_outside_truth)?;
    ev.set_item("position_rmse_m", e.position_rmse_m)?;
    ev.set_item("horizontal_position_rmse_m", e.horizontal_position_rmse_m)?;
    ev.set_item("final_position_error_m", e.final_position_error_m)?;
    ev.set_item("nees_average", e.nees_average)?;
    ev.set_item("nees_states", e.nees_states)?;
    ev.set_item("nees_per_group", e.nees_per_group.to_vec())?;
    ev.set_item(
        "covariance_not_positive_definite_epochs",
        e.covariance_not_positive_definite_epochs,
    )?;
    ev.set_item("truth_time_offset_s", t.time_offset().offset_s())?;
    let source = match t.time_offset() {
        TruthTimeOffset::Vehicle(_) => "vehicle",
        TruthTimeOffset::Estimated(_) => "estimated",
    };
    ev.set_item("truth_time_offset_source", source)?;
    if let Some(b) = t.velocity_bias() {
        ev.set_item("truth_velocity_bias_mps", b.bias_mps.to_vec())?;
        ev.set_item("truth_velocity_bias_removed", b.removed)?;
    }
    Ok(ev)
}

/// The errors and 1-sigmas at the truth's scored epochs (times on the files' clock).
fn errors<'py>(py: Python<'py>, t: &Truth, epoch: f64) -> PyResult<Bound<'py, PyDict>> {
    let scored = t.rows();
    let errors = PyDict::new(py);
    errors.set_item(
        "time_s",
        numpy::PyArray1::from_iter(py, scored.iter().map(|r| epoch + r[0])),
    )?;
    errors.set_item(
        "error",
        Array2::from_shape_fn((scored.len(), 9), |(i, j)| scored[i][1 + j]).into_pyarray(py),
    )?;
    errors.set_item(
        "sigma",
        Array2::from_shape_fn((scored.len(), 9), |(i, j)| scored[i][10 + j]).into_pyarray(py),
    )?;
    errors.set_item("nees", numpy::PyArray1::from_slice(py, t.nees()))?;
    Ok(errors)
}

/// Register `navigate`.
pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(navigate, m)?)
}
