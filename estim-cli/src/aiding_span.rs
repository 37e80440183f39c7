//! An aiding file none of whose records falls in the IMU's span is refused: the
//! navigator would count every row "outside the IMU span" and run unaided (a DVL
//! file in Unix seconds beside an IMU file in relative seconds, a mistyped
//! `time_offset_s`). A file with some records inside runs; the others are counted in
//! `outside_imu_span` as before.

use std::path::Path;

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
pub fn check_in_imu_span(
    aiding: &AidingTimes<'_>,
    imu: &Path,
    imu_span: [f64; 2],
    epoch: f64,
) -> anyhow::Result<()> {
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
    anyhow::bail!(
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
    )
}

/// A time for a message: to the millisecond, or in exponent form beyond any clock.
fn seconds(t: f64) -> String {
    if t.abs() < 1e12 {
        format!("{t:.3}")
    } else {
        format!("{t:e}")
    }
}

/// [`check_in_imu_span`] for each aiding file of a survey: the DVL (velocity,
/// beams or PD0), depth and fixes files, each with its vehicle-file offset.
pub fn check_survey(
    files: &crate::navigate::SurveyFiles,
    config: &estim::navigator::NavigatorConfig,
    inputs: &estim::navigator::SurveyInputs,
    epoch: f64,
) -> anyhow::Result<()> {
    let imu_span = [
        inputs.imu.first().map_or(0.0, |s| s.time),
        inputs.imu.last().map_or(0.0, |s| s.time),
    ];
    let dvl = files
        .sensors
        .dvl
        .as_ref()
        .or(files.sensors.beams.as_ref())
        .or(files.sensors.pd0.as_ref());
    let checks = [
        dvl.map(|path| AidingTimes {
            path,
            offset_key: "dvl.time_offset_s",
            offset_s: config.dvl.time_offset_s,
            times: inputs.dvl.iter().map(|r| r.time).collect(),
        }),
        files.sensors.depth.as_ref().map(|path| AidingTimes {
            path,
            offset_key: "depth.time_offset_s",
            offset_s: config.depth.time_offset_s,
            times: inputs.depth.iter().map(|r| r.time).collect(),
        }),
        files.sensors.fixes.as_ref().map(|path| AidingTimes {
            path,
            offset_key: "fixes.time_offset_s",
            offset_s: config.fixes.time_offset_s,
            times: inputs.fixes.iter().map(|r| r.time).collect(),
        }),
    ];
    for aiding in checks.iter().flatten() {
        check_in_imu_span(aiding, &files.sensors.imu, imu_span, epoch)?;
    }
    Ok(())
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
    }
}
