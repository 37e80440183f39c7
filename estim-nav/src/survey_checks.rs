//! Checks of a loaded survey as a whole, shared by every front end (the `estim`
//! commands and the Python package), after [`SurveyFiles::read`]:
//! - an aiding file (DVL, depth, fixes) none of whose records falls in the IMU's span
//!   is refused: the navigator would count every row "outside the IMU span" and run
//!   unaided (a DVL file in Unix seconds beside an IMU file in relative seconds, a
//!   mistyped `time_offset_s`). One record inside is enough;
//! - a DVL file none of whose rows has bottom lock is refused when nothing else aids
//!   the INS (the run would be free inertial, not the run asked for), and is a
//!   warning otherwise;
//! - an `imu.rate_hz` more than 1 % from the IMU file's median sample rate is a
//!   warning: the run then integrates each sample's own interval, as without the key;
//! - spikes of the IMU log ([`crate::imu_spikes`]) are a warning naming their data
//!   rows: the run integrates them as logged.

use std::path::{Path, PathBuf};

use crate::navigator::{DvlInput, NavigatorConfig, SurveyInputs};
use crate::survey::{SurveyError, SurveyFiles};

/// Something about a survey's inputs that does not stop the run but that its user
/// should know; the front ends print it and list it in their summary.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SurveyWarning {
    /// A stable identifier: `dvl_no_lock`, `imu_rate_mismatch` or `imu_spike`.
    pub code: &'static str,
    /// The file concerned.
    pub file: PathBuf,
    /// What was found, naming the file and the key.
    pub message: String,
}

/// One aiding file's record times (on the navigator's clock, before its offset).
pub struct AidingTimes<'a> {
    /// The file.
    pub path: &'a Path,
    /// The vehicle file's key of its time offset (`dvl.time_offset_s`, ...).
    pub offset_key: &'static str,
    /// That offset \[s\], subtracted from each record's time.
    pub offset_s: f64,
    /// The record times \[s\], relative to the IMU file's epoch.
    pub times: Vec<f64>,
}

/// Refuse `aiding` when it has records and none falls in `[imu_first, imu_last]`
/// (after its offset), naming the file, both spans in the files' own time (`epoch`
/// added back), the offset and the IMU file.
///
/// # Errors
/// [`SurveyError::OutsideImuSpan`].
pub fn check_in_imu_span(
    aiding: &AidingTimes<'_>,
    imu: &Path,
    imu_span: [f64; 2],
    epoch: f64,
) -> Result<(), SurveyError> {
    let shifted = aiding.times.iter().map(|t| t - aiding.offset_s);
    let (mut first, mut last, mut inside) = (f64::INFINITY, f64::NEG_INFINITY, false);
    for t in shifted {
        first = first.min(t);
        last = last.max(t);
        inside |= t >= imu_span[0] && t <= imu_span[1];
    }
    if aiding.times.is_empty() || inside {
        return Ok(());
    }
    Err(SurveyError::OutsideImuSpan {
        path: aiding.path.to_path_buf(),
        message: format!(
            "{}: none of its {} records falls in the IMU's span: its times run {}..{} s \
             (after {} = {:?} s), {} runs {}..{} s; are both on one clock (Unix seconds \
             against relative seconds?) and is the offset right?",
            aiding.path.display(),
            aiding.times.len(),
            seconds(epoch + first),
            seconds(epoch + last),
            aiding.offset_key,
            aiding.offset_s,
            imu.display(),
            seconds(epoch + imu_span[0]),
            seconds(epoch + imu_span[1])
        ),
    })
}

/// A time for a message: to the millisecond, or in exponent form beyond any clock.
pub(crate) fn seconds(t: f64) -> String {
    if t.abs() < 1e12 {
        format!("{t:.3}")
    } else {
        format!("{t:e}")
    }
}

/// Every check of the module docs on a survey read from `files` with `config`
/// (`inputs` on the navigator's clock, `epoch` the IMU file's): the warnings, in the
/// order found.
///
/// ```no_run
/// use estim_nav::navigator::{NavigatorConfig, SurveyInputs};
/// use estim_nav::{check_survey, SurveyFiles};
///
/// let files = SurveyFiles {
///     imu: "imu.csv".into(),
///     dvl: Some("dvl.csv".into()),
///     ..SurveyFiles::default()
/// };
/// let config = NavigatorConfig::default();
/// let survey = SurveyInputs::load(&files, &config)?;
/// for warning in check_survey(&files, &config, &survey.inputs, survey.epoch)? {
///     eprintln!("warning ({}): {}", warning.code, warning.message);
/// }
/// # Ok::<(), estim_nav::SurveyError>(())
/// ```
///
/// # Errors
/// [`SurveyError::OutsideImuSpan`] for an aiding file outside the IMU's span,
/// [`SurveyError::NoLock`] for a DVL file without lock and nothing else aiding.
pub fn check_survey(
    files: &SurveyFiles,
    config: &NavigatorConfig,
    inputs: &SurveyInputs,
    epoch: f64,
) -> Result<Vec<SurveyWarning>, SurveyError> {
    check_spans(files, config, inputs, epoch)?;
    let mut warnings: Vec<SurveyWarning> = check_dvl_lock(files, inputs)?.into_iter().collect();
    warnings.extend(check_imu_rate(files, config, inputs));
    warnings.extend(check_imu_spikes(files, inputs));
    Ok(warnings)
}

/// [`check_in_imu_span`] for each aiding file of a survey: the DVL (velocity, beams or
/// PD0), depth and fixes files, each with its vehicle-file offset.
fn check_spans(
    files: &SurveyFiles,
    config: &NavigatorConfig,
    inputs: &SurveyInputs,
    epoch: f64,
) -> Result<(), SurveyError> {
    let imu_span = [
        inputs.imu.first().map_or(0.0, |s| s.time),
        inputs.imu.last().map_or(0.0, |s| s.time),
    ];
    let dvl = files
        .dvl
        .as_ref()
        .or(files.beams.as_ref())
        .or(files.pd0.as_ref());
    let checks = [
        dvl.map(|path| AidingTimes {
            path,
            offset_key: "dvl.time_offset_s",
            offset_s: config.dvl.time_offset_s,
            times: inputs.dvl.iter().map(|r| r.time).collect(),
        }),
        files.depth.as_ref().map(|path| AidingTimes {
            path,
            offset_key: "depth.time_offset_s",
            offset_s: config.depth.time_offset_s,
            times: inputs.depth.iter().map(|r| r.time).collect(),
        }),
        files.fixes.as_ref().map(|path| AidingTimes {
            path,
            offset_key: "fixes.time_offset_s",
            offset_s: config.fixes.time_offset_s,
            times: inputs.fixes.iter().map(|r| r.time).collect(),
        }),
    ];
    for aiding in checks.iter().flatten() {
        check_in_imu_span(aiding, &files.imu, imu_span, epoch)?;
    }
    Ok(())
}

/// A DVL file none of whose rows has bottom lock (every velocity empty, NaN, the
/// -32.768 marker or flagged invalid; beams: fewer than 3): refused when nothing else
/// aids the INS (no depth, no fix), a warning otherwise.
fn check_dvl_lock(
    files: &SurveyFiles,
    inputs: &SurveyInputs,
) -> Result<Option<SurveyWarning>, SurveyError> {
    let usable = |input: &DvlInput| match input {
        DvlInput::Velocity(_) | DvlInput::EarthVelocity(_) => true,
        DvlInput::Beams(b) => b.iter().flatten().count() >= 3,
        DvlInput::NoLock => false,
    };
    if inputs.dvl.iter().any(|r| usable(&r.input)) {
        return Ok(None);
    }
    let path = [&files.dvl, &files.beams, &files.pd0]
        .into_iter()
        .flatten()
        .next()
        .cloned()
        .unwrap_or_else(|| PathBuf::from("the DVL input"));
    let what = format!(
        "{}: none of its {} rows has bottom lock (an empty, NaN or -32.768 velocity, a \
         validity flag saying no, or fewer than 3 beams)",
        path.display(),
        inputs.dvl.len()
    );
    let aided_by: Vec<&str> = [
        (!inputs.depth.is_empty()).then_some("depth"),
        (!inputs.fixes.is_empty()).then_some("fixes"),
    ]
    .into_iter()
    .flatten()
    .collect();
    if aided_by.is_empty() {
        return Err(SurveyError::NoLock {
            path,
            message: format!("{what}: nothing would aid the INS (no depth, no fixes); refused"),
        });
    }
    Ok(Some(SurveyWarning {
        code: "dvl_no_lock",
        message: format!(
            "{what}; the run is aided by {} only",
            aided_by.join(" and ")
        ),
        file: path,
    }))
}

/// An `imu.rate_hz` more than 1 % from the IMU file's median sample rate (on the
/// navigator's clock, after `imu.clock_scale`).
fn check_imu_rate(
    files: &SurveyFiles,
    config: &NavigatorConfig,
    inputs: &SurveyInputs,
) -> Option<SurveyWarning> {
    let declared = config.imu.rate_hz?;
    let median = crate::navigator::median_interval(&inputs.imu)?;
    let measured = 1.0 / median;
    if (declared / measured - 1.0).abs() <= 0.01 {
        return None;
    }
    let vehicle = files.vehicle.as_ref().map_or_else(
        || "the vehicle file".to_string(),
        |p| p.display().to_string(),
    );
    Some(SurveyWarning {
        code: "imu_rate_mismatch",
        file: files.imu.clone(),
        message: format!(
            "{vehicle}: imu.rate_hz = {declared:?} Hz, but {}'s median sample interval is \
             {median:.6} s ({measured:.4} Hz on the navigator's clock); each sample's own \
             interval is integrated",
            files.imu.display()
        ),
    })
}

/// Spikes named in a warning, at most.
const SPIKES_NAMED: usize = 5;

/// The IMU log's spikes ([`crate::imu_spikes::imu_spikes`], on the body axes), the
/// first [`SPIKES_NAMED`] named by sample (1 = the first; data row k of a file of
/// rates, k + 1 of a file of increments), channel, departure and threshold.
fn check_imu_spikes(files: &SurveyFiles, inputs: &SurveyInputs) -> Option<SurveyWarning> {
    let mut spikes = crate::imu_spikes::imu_spikes(&inputs.imu);
    if spikes.is_empty() {
        return None;
    }
    spikes.sort_by_key(|s| (s.index, s.channel));
    let named: Vec<String> = spikes
        .iter()
        .take(SPIKES_NAMED)
        .map(|s| {
            let rows = if s.samples == 1 {
                format!("sample {}", s.index + 1)
            } else {
                format!("samples {}-{}", s.index + 1, s.index + s.samples)
            };
            let unit = if s.channel < 3 { "m/s^2" } else { "rad/s" };
            format!(
                "{rows} {} {:+.4} {unit} (threshold {:.4})",
                crate::imu_spikes::CHANNELS[s.channel],
                s.departure,
                s.threshold
            )
        })
        .collect();
    let more = spikes.len().saturating_sub(SPIKES_NAMED);
    let rest = if more > 0 {
        format!(" and {more} more")
    } else {
        String::new()
    };
    Some(SurveyWarning {
        code: "imu_spike",
        file: files.imu.clone(),
        message: format!(
            "{}: {} spike(s), samples that leave both neighbours far beyond the log's \
             sample-to-sample change (body axes): {}{rest} (sample k is data row k of a file \
             of rates, k + 1 of a file of increments); they are integrated as logged, each a velocity or attitude step the covariance does not hold",
            files.imu.display(),
            spikes.len(),
            named.join("; ")
        ),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn times(times: Vec<f64>, offset_s: f64) -> AidingTimes<'static> {
        AidingTimes {
            path: Path::new("dvl.csv"),
            offset_key: "dvl.time_offset_s",
            offset_s,
            times,
        }
    }

    #[test]
    fn one_record_inside_is_enough() {
        let imu = Path::new("imu.csv");
        assert!(check_in_imu_span(&times(vec![-5.0, 3.0], 0.0), imu, [0.0, 10.0], 0.0).is_ok());
        assert!(check_in_imu_span(&times(Vec::new(), 0.0), imu, [0.0, 10.0], 0.0).is_ok());
    }

    #[test]
    fn every_record_outside_names_file_spans_and_offset() {
        let imu = Path::new("imu.csv");
        let e = check_in_imu_span(&times(vec![1.7e9, 1.7e9 + 1.0], 0.0), imu, [0.0, 10.0], 0.0)
            .unwrap_err()
            .to_string();
        for part in ["dvl.csv", "imu.csv", "dvl.time_offset_s", "0.000..10.000"] {
            assert!(e.contains(part), "{part}: {e}");
        }
        // A mistyped offset pushes every record out.
        assert!(check_in_imu_span(&times(vec![1.0, 2.0], 100.0), imu, [0.0, 10.0], 0.0).is_err());
        // A time beyond any clock is quoted in exponent form.
        let e = check_in_imu_span(&times(vec![1e300], 0.0), imu, [0.0, 10.0], 0.0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("1e300..1e300 s"), "{e}");
    }
}
