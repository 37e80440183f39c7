//! Checks of a survey's inputs beside their readers (`navigate`, `smooth`, `tune
//! --imu`): the `--columns` file, a DVL file with no lock at all, and an IMU rate that
//! does not describe the IMU file.

use std::path::Path;

use estim::datasets::ColumnMap;
use estim::navigator::SurveyInputs;
use serde_json::{json, Value};

use crate::navigate::SurveyFiles;

/// A `--columns` file: a `[columns]` table and nothing else.
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct ColumnsFile {
    columns: ColumnMap,
}

/// Read a `--columns` file; errors name the file, the line or the key.
pub fn columns_file(path: &Path) -> anyhow::Result<ColumnMap> {
    let text = estim::datasets::read_text_file(path)?;
    let file = toml::from_str::<ColumnsFile>(&text).map_err(|e| {
        let line = e
            .span()
            .map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1);
        match line {
            Some(l) => anyhow::anyhow!("{}:{l}: {}", path.display(), e.message()),
            None => anyhow::anyhow!("{}: {}", path.display(), e.message()),
        }
    })?;
    file.columns
        .check()
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    Ok(file.columns)
}

/// A DVL file none of whose rows has bottom lock (every velocity empty, NaN, the
/// -32.768 marker or flagged invalid; beams: fewer than 3) is refused when nothing
/// else aids the INS (no depth, no fix: the run would be free inertial, not the run
/// asked for), and is otherwise a warning, printed on stderr and returned for the
/// summary's `warnings`.
pub fn check_dvl_lock(files: &SurveyFiles, inputs: &SurveyInputs) -> anyhow::Result<Vec<Value>> {
    use estim::navigator::DvlInput;
    let usable = |input: &DvlInput| match input {
        DvlInput::Velocity(_) | DvlInput::EarthVelocity(_) => true,
        DvlInput::Beams(b) => b.iter().flatten().count() >= 3,
        DvlInput::NoLock => false,
    };
    if inputs.dvl.iter().any(|r| usable(&r.input)) {
        return Ok(Vec::new());
    }
    let path = [&files.sensors.dvl, &files.sensors.beams, &files.sensors.pd0]
        .into_iter()
        .flatten()
        .next()
        .map_or_else(|| "the DVL input".to_string(), |p| p.display().to_string());
    let what = format!(
        "{path}: none of its {} rows has bottom lock (an empty, NaN or -32.768 velocity, a \
         validity flag saying no, or fewer than 3 beams)",
        inputs.dvl.len()
    );
    let aided_by: Vec<&str> = [
        (!inputs.depth.is_empty()).then_some("depth"),
        (!inputs.fixes.is_empty()).then_some("fixes"),
    ]
    .into_iter()
    .flatten()
    .collect();
    anyhow::ensure!(
        !aided_by.is_empty(),
        "{what}: nothing would aid the INS (no --depth, no --fixes); refused"
    );
    let message = format!(
        "{what}; the run is aided by {} only",
        aided_by.join(" and ")
    );
    eprintln!("warning: {message}");
    Ok(vec![json!({
        "code": "dvl_no_lock",
        "file": path,
        "message": message,
    })])
}

/// An `imu.rate_hz` more than 1 % from the IMU file's median sample rate (on the
/// navigator's clock, after `imu.clock_scale`) is a warning, printed on stderr and
/// returned for the summary's `warnings`: the run then integrates each sample's own
/// interval, as without the key, but the key was meant to describe this file.
pub fn check_imu_rate(
    files: &SurveyFiles,
    config: &estim::navigator::NavigatorConfig,
    inputs: &SurveyInputs,
) -> Option<Value> {
    let declared = config.imu.rate_hz?;
    let mut steps: Vec<f64> = inputs
        .imu
        .windows(2)
        .map(|w| w[1].time - w[0].time)
        .filter(|dt| dt.is_finite() && *dt > 0.0)
        .collect();
    steps.sort_by(f64::total_cmp);
    let median = *steps.get(steps.len() / 2)?;
    let measured = 1.0 / median;
    if (declared / measured - 1.0).abs() <= 0.01 {
        return None;
    }
    let path = files.sensors.imu.display().to_string();
    let message = format!(
        "{}: imu.rate_hz = {declared:?} Hz, but {path}'s median sample interval is \
         {median:.6} s ({measured:.4} Hz on the navigator's clock); each sample's own \
         interval is integrated",
        files.sensors.vehicle.as_ref().map_or_else(
            || "the vehicle file".to_string(),
            |p| p.display().to_string()
        ),
    );
    eprintln!("warning: {message}");
    Some(json!({
        "code": "imu_rate_mismatch",
        "file": path,
        "message": message,
    }))
}
