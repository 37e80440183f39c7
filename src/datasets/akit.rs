//! A-KIT CSV files: `GT_trajectoryN.csv` and `DVL_trajectoryN.csv`.

use std::io::Read;
use std::path::{Path, PathBuf};

use super::{DatasetError, Result};

fn open(path: &Path) -> Result<std::fs::File> {
    std::fs::File::open(path).map_err(|source| DatasetError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Header of `GT_trajectoryN.csv`.
pub const GT_HEADER: [&str; 10] = [
    "Time [s]",
    "Longitude [rad]",
    "Latitude [rad]",
    "Altitude [m]",
    "V North [m/s]",
    "V East [m/s]",
    "V Down [m/s]",
    "Roll [rad]",
    "Pitch [rad]",
    "Yaw [rad]",
];

/// Header of `DVL_trajectoryN.csv`.
pub const DVL_HEADER: [&str; 4] = ["Time [s]", "DVL X [m/s]", "DVL Y [m/s]", "DVL Z [m/s]"];

/// One ground-truth sample (post-processed Phins solution).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GtSample {
    /// Time \[s\].
    pub time: f64,
    /// Geodetic longitude \[rad\].
    pub longitude: f64,
    /// Geodetic latitude \[rad\].
    pub latitude: f64,
    /// Height above the WGS-84 ellipsoid \[m\] (negative under water).
    pub altitude: f64,
    /// Velocity north, east, down \[m/s\].
    pub velocity_ned: [f64; 3],
    /// Roll, pitch, yaw \[rad\] (body x forward, y right, z down).
    pub roll_pitch_yaw: [f64; 3],
}

impl GtSample {
    /// The sample as an estim-ins trajectory knot (attitude from roll, pitch, yaw,
    /// body -> NED, z-y-x order).
    pub fn trajectory_sample(&self) -> estim_ins::TrajectorySample {
        let [roll, pitch, yaw] = self.roll_pitch_yaw;
        estim_ins::TrajectorySample {
            time: self.time,
            latitude: self.latitude,
            longitude: self.longitude,
            height: self.altitude,
            velocity_ned: self.velocity_ned.into(),
            attitude: nalgebra::UnitQuaternion::from_euler_angles(roll, pitch, yaw),
        }
    }
}

/// One DVL sample: body-frame velocity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DvlSample {
    /// Time \[s\].
    pub time: f64,
    /// Body-frame velocity x, y, z \[m/s\].
    pub velocity_body: [f64; 3],
}

/// Load and validate a ground-truth file.
pub fn load_gt(path: &Path) -> Result<Vec<GtSample>> {
    parse_gt(open(path)?, path)
}

/// Parse ground truth from any reader; `path` names the source in errors.
pub fn parse_gt(reader: impl Read, path: &Path) -> Result<Vec<GtSample>> {
    let rows = read_numeric_csv(reader, path, &GT_HEADER, 2)?;
    Ok(rows
        .into_iter()
        .map(|r| GtSample {
            time: r[0],
            longitude: r[1],
            latitude: r[2],
            altitude: r[3],
            velocity_ned: [r[4], r[5], r[6]],
            roll_pitch_yaw: [r[7], r[8], r[9]],
        })
        .collect())
}

/// Load and validate a DVL file.
pub fn load_dvl(path: &Path) -> Result<Vec<DvlSample>> {
    parse_dvl(open(path)?, path)
}

/// Parse a DVL log from any reader; `path` names the source in errors.
pub fn parse_dvl(reader: impl Read, path: &Path) -> Result<Vec<DvlSample>> {
    let rows = read_numeric_csv(reader, path, &DVL_HEADER, 2)?;
    Ok(rows
        .into_iter()
        .map(|r| DvlSample {
            time: r[0],
            velocity_body: [r[1], r[2], r[3]],
        })
        .collect())
}

/// Read a CSV whose header must equal `header` (cells trimmed), every cell a finite
/// number, the first column a strictly increasing time, at least `min_rows` rows.
fn read_numeric_csv<const C: usize>(
    input: impl Read,
    path: &Path,
    header: &[&str; C],
    min_rows: usize,
) -> Result<Vec<[f64; C]>> {
    let pb = || PathBuf::from(path);
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .from_reader(std::io::BufReader::new(input));
    let mut records = reader.records();
    let csv_err = |e: csv::Error| match e.kind() {
        csv::ErrorKind::Io(_) => DatasetError::Io {
            path: pb(),
            source: std::io::Error::other(e.to_string()),
        },
        _ => DatasetError::Csv {
            path: pb(),
            line: e.position().map_or(0, |p| p.line()),
            message: e.to_string(),
        },
    };
    let first = match records.next() {
        None => {
            return Err(DatasetError::TooFewRows {
                path: pb(),
                found: 0,
                min: min_rows,
            });
        }
        Some(r) => r.map_err(csv_err)?,
    };
    let found: Vec<&str> = first
        .iter()
        .map(|c| c.trim().trim_start_matches('\u{feff}'))
        .collect();
    if found != header.as_slice() {
        return Err(DatasetError::Header {
            path: pb(),
            expected: header.join(","),
            found: found.join(","),
        });
    }
    let mut rows: Vec<[f64; C]> = Vec::new();
    let mut previous: Option<f64> = None;
    for record in records {
        let record = record.map_err(csv_err)?;
        let line = record.position().map_or(0, |p| p.line());
        if record.len() == 1 && record.get(0).is_some_and(|c| c.trim().is_empty()) {
            continue; // blank line
        }
        if record.len() != C {
            return Err(DatasetError::FieldCount {
                path: pb(),
                line,
                expected: C,
                found: record.len(),
            });
        }
        let mut row = [0.0; C];
        for (i, cell) in record.iter().enumerate() {
            let v: f64 = cell.trim().parse().map_err(|_| DatasetError::Parse {
                path: pb(),
                line,
                column: header[i].to_string(),
                value: cell.chars().take(40).collect(),
            })?;
            if !v.is_finite() {
                return Err(DatasetError::NonFinite {
                    path: pb(),
                    line,
                    column: header[i].to_string(),
                });
            }
            row[i] = v;
        }
        if let Some(prev) = previous {
            if row[0] <= prev {
                return Err(DatasetError::TimeNotIncreasing {
                    path: pb(),
                    line,
                    time: row[0],
                    previous: prev,
                });
            }
        }
        previous = Some(row[0]);
        rows.push(row);
    }
    if rows.len() < min_rows {
        return Err(DatasetError::TooFewRows {
            path: pb(),
            found: rows.len(),
            min: min_rows,
        });
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn write(content: &str) -> tempfile::NamedTempFile {
        let mut f = tempfile::NamedTempFile::new().expect("temp file");
        f.write_all(content.as_bytes()).expect("write");
        f
    }

    const DVL_OK: &str = "Time [s],DVL X [m/s],DVL Y [m/s],DVL Z [m/s]\n0.0,1,2,3\n1.0,1.5,2,3\n";

    #[test]
    fn dvl_parses() {
        let f = write(DVL_OK);
        let rows = load_dvl(f.path()).expect("valid file");
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[1].velocity_body, [1.5, 2.0, 3.0]);
    }

    #[test]
    fn bad_header_is_named() {
        let f = write("t,x,y,z\n0,1,2,3\n1,1,2,3\n");
        let e = load_dvl(f.path()).unwrap_err();
        assert!(matches!(e, DatasetError::Header { .. }), "{e}");
    }

    #[test]
    fn non_numeric_cell_names_line_and_column() {
        let f = write("Time [s],DVL X [m/s],DVL Y [m/s],DVL Z [m/s]\n0.0,1,2,3\n1.0,abc,2,3\n");
        let e = load_dvl(f.path()).unwrap_err();
        match &e {
            DatasetError::Parse { line, column, .. } => {
                assert_eq!(*line, 3);
                assert_eq!(column, "DVL X [m/s]");
            }
            other => panic!("unexpected {other}"),
        }
        assert!(e.to_string().contains(":3:"), "{e}");
    }

    #[test]
    fn nan_time_backwards_short_and_ragged_rejected() {
        let h = "Time [s],DVL X [m/s],DVL Y [m/s],DVL Z [m/s]\n";
        let nan = write(&format!("{h}0,1,2,3\n1,NaN,2,3\n"));
        assert!(matches!(
            load_dvl(nan.path()),
            Err(DatasetError::NonFinite { line: 3, .. })
        ));
        let back = write(&format!("{h}0,1,2,3\n1,1,2,3\n1,1,2,3\n"));
        assert!(matches!(
            load_dvl(back.path()),
            Err(DatasetError::TimeNotIncreasing { line: 4, .. })
        ));
        let short = write(&format!("{h}0,1,2,3\n"));
        assert!(matches!(
            load_dvl(short.path()),
            Err(DatasetError::TooFewRows { found: 1, .. })
        ));
        let ragged = write(&format!("{h}0,1,2,3\n1,1,2\n"));
        assert!(matches!(
            load_dvl(ragged.path()),
            Err(DatasetError::FieldCount {
                line: 3,
                found: 3,
                ..
            })
        ));
        let empty = write("");
        assert!(matches!(
            load_dvl(empty.path()),
            Err(DatasetError::TooFewRows { found: 0, .. })
        ));
        let missing = load_dvl(Path::new("/nonexistent/DVL.csv")).unwrap_err();
        assert!(missing.to_string().contains("/nonexistent/DVL.csv"));
    }

    #[test]
    fn gt_parses_negative_altitude() {
        let f = write(
            "Time [s],Longitude [rad],Latitude [rad],Altitude [m],V North [m/s],V East [m/s],V Down [m/s],Roll [rad],Pitch [rad],Yaw [rad]\n\
             0,0.6,0.57,-20.5,1,0,0,0,0,0\n1,0.6,0.57,-20.6,1,0,0,0,0,0.1\n",
        );
        let rows = load_gt(f.path()).expect("valid");
        assert_eq!(rows[0].altitude, -20.5);
        assert_eq!(rows[1].roll_pitch_yaw[2], 0.1);
    }

    #[test]
    fn binary_garbage_is_an_error_not_a_panic() {
        let mut f = tempfile::NamedTempFile::new().expect("temp");
        f.write_all(&[0xff, 0xfe, 0x00, 0x01, b'\n', 0x80, 0x81])
            .expect("write");
        assert!(load_gt(f.path()).is_err());
    }
}
