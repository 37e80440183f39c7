//! Ground-truth and DVL velocity CSV files (`GT_trajectoryN.csv`, `DVL_trajectoryN.csv`
//! of A-KIT, or a user's own files with the same quantities).
//!
//! Columns are found by name in any order, with the units their headers state (see
//! [`super::columns`]). The file must end with a newline: a last line without one is
//! reported as truncated (a partial write), even if it parses. CRLF line ends, a
//! UTF-8 BOM and trailing blank lines are accepted. Every value is checked where it
//! stands (file and line): a number, finite, within the physical range the navigator
//! models, and a strictly increasing time. Time must also be plausible as a whole: two
//! rows closer than [`MIN_INTERVAL_FRACTION`] (1/10) of the file's typical interval
//! (the upper quartile of its intervals) are refused, naming both lines, never merged.
//! Files are read through [`super::read_input`] (size limit, encoding) and parsed in
//! one pass: line numbers are counted once, forward.

use std::io::Read;
use std::path::{Path, PathBuf};

use super::columns::{flipped, same, Alias, Kind, Quantity};
use super::input::open_text;
use super::table::{for_each_row, MapSection};
use super::{ColumnMap, DatasetError, Result, MIN_INTERVAL_FRACTION};

/// Header of A-KIT's `GT_trajectoryN.csv` (one accepted layout among many).
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

/// Header of A-KIT's `DVL_trajectoryN.csv` (one accepted layout among many).
pub const DVL_HEADER: [&str; 4] = ["Time [s]", "DVL X [m/s]", "DVL Y [m/s]", "DVL Z [m/s]"];

/// Largest |time| accepted \[s\] (Unix time is about 1.7e9 s).
pub const MAX_ABS_TIME_S: f64 = 1e10;
/// Largest |speed| component accepted \[m/s\], GT and DVL.
pub const MAX_ABS_SPEED_MPS: f64 = 1000.0;
/// |latitude| must stay below this \[rad\] (85.9 deg; the INS model's pole limit).
pub const MAX_ABS_LATITUDE_RAD: f64 = 1.5;
/// |longitude| must stay below this \[rad\] (a little more than 360 deg).
pub const MAX_ABS_LONGITUDE_RAD: f64 = 7.0;
/// |altitude| must stay below this \[m\].
pub const MAX_ABS_ALTITUDE_M: f64 = 1e5;
/// |roll|, |pitch|, |yaw| must stay below this \[rad\] (unwrapped yaw may exceed 2 pi).
pub const MAX_ABS_ANGLE_RAD: f64 = 1e4;

const TIME: Quantity = Quantity {
    key: "time",
    kind: Kind::Time,
    aliases: &[same("time"), same("t"), same("timestamp")],
    max_abs: MAX_ABS_TIME_S,
};

const fn speed(key: &'static str, aliases: &'static [Alias]) -> Quantity {
    Quantity {
        key,
        kind: Kind::Speed,
        aliases,
        max_abs: MAX_ABS_SPEED_MPS,
    }
}

const fn angle(key: &'static str, aliases: &'static [Alias]) -> Quantity {
    Quantity {
        key,
        kind: Kind::Angle,
        aliases,
        max_abs: MAX_ABS_ANGLE_RAD,
    }
}

/// The quantities of a ground-truth file, in [`GtSample`] order.
pub(crate) const GT_QUANTITIES: &[Quantity; 10] = &[
    TIME,
    Quantity {
        key: "longitude",
        kind: Kind::Angle,
        aliases: &[same("longitude"), same("lon"), same("long"), same("lng")],
        max_abs: MAX_ABS_LONGITUDE_RAD,
    },
    Quantity {
        key: "latitude",
        kind: Kind::Angle,
        aliases: &[same("latitude"), same("lat")],
        max_abs: MAX_ABS_LATITUDE_RAD,
    },
    Quantity {
        key: "altitude",
        kind: Kind::Length,
        aliases: &[
            same("altitude"),
            same("alt"),
            same("height"),
            flipped("depth"),
        ],
        max_abs: MAX_ABS_ALTITUDE_M,
    },
    speed(
        "v_north",
        &[
            same("vnorth"),
            same("vn"),
            same("velnorth"),
            same("velocitynorth"),
            same("northvelocity"),
        ],
    ),
    speed(
        "v_east",
        &[
            same("veast"),
            same("ve"),
            same("veleast"),
            same("velocityeast"),
            same("eastvelocity"),
        ],
    ),
    speed(
        "v_down",
        &[
            same("vdown"),
            same("vd"),
            same("veldown"),
            same("velocitydown"),
            same("downvelocity"),
            flipped("vup"),
            flipped("vu"),
            flipped("velup"),
            flipped("velocityup"),
            flipped("upvelocity"),
        ],
    ),
    angle("roll", &[same("roll")]),
    angle("pitch", &[same("pitch")]),
    angle("yaw", &[same("yaw"), same("heading")]),
];

/// The quantities of a DVL velocity file, in [`DvlSample`] order.
pub(crate) const DVL_QUANTITIES: &[Quantity; 4] = &[
    TIME,
    speed(
        "x",
        &[
            same("dvlx"),
            same("dvlvx"),
            same("vx"),
            same("velx"),
            same("velocityx"),
            same("x"),
        ],
    ),
    speed(
        "y",
        &[
            same("dvly"),
            same("dvlvy"),
            same("vy"),
            same("vely"),
            same("velocityy"),
            same("y"),
        ],
    ),
    speed(
        "z",
        &[
            same("dvlz"),
            same("dvlvz"),
            same("vz"),
            same("velz"),
            same("velocityz"),
            same("z"),
        ],
    ),
];

/// One ground-truth sample (post-processed Phins solution on A-KIT).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GtSample {
    /// 1-based line of the file this sample was read from.
    pub line: u64,
    /// Time \[s\].
    pub time: f64,
    /// Geodetic longitude \[rad\].
    pub longitude: f64,
    /// Geodetic latitude \[rad\].
    pub latitude: f64,
    /// Height above the WGS-84 ellipsoid \[m\], negative under water (a depth column
    /// is read as altitude = -depth; the sign is never dropped).
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
    /// 1-based line of the file this sample was read from.
    pub line: u64,
    /// Time \[s\].
    pub time: f64,
    /// Body-frame velocity x, y, z \[m/s\].
    pub velocity_body: [f64; 3],
}

/// Load and validate a ground-truth file, columns found by name.
///
/// # Errors
/// Every [`DatasetError`] variant that names a file or a line.
pub fn load_gt(path: &Path) -> Result<Vec<GtSample>> {
    load_gt_with(path, &ColumnMap::default())
}

/// [`load_gt`] with a column map (`[columns.gt]`).
///
/// # Errors
/// As [`load_gt`], and [`DatasetError::ColumnMap`].
pub fn load_gt_with(path: &Path, map: &ColumnMap) -> Result<Vec<GtSample>> {
    gt_from(open_text(path)?, path, map)
}

/// Parse ground truth from any reader; `path` names the source in errors.
///
/// # Errors
/// As [`load_gt`].
pub fn parse_gt(reader: impl Read, path: &Path) -> Result<Vec<GtSample>> {
    gt_from(reader, path, &ColumnMap::default())
}

fn gt_from(input: impl Read, path: &Path, map: &ColumnMap) -> Result<Vec<GtSample>> {
    let rows = read_table(input, path, GT_QUANTITIES, &map.gt, "columns.gt", 2)?;
    Ok(rows
        .into_iter()
        .map(|(line, r)| GtSample {
            line,
            time: r[0],
            longitude: r[1],
            latitude: r[2],
            altitude: r[3],
            velocity_ned: [r[4], r[5], r[6]],
            roll_pitch_yaw: [r[7], r[8], r[9]],
        })
        .collect())
}

/// Load and validate a DVL velocity file, columns found by name.
///
/// # Errors
/// As [`load_gt`].
pub fn load_dvl(path: &Path) -> Result<Vec<DvlSample>> {
    load_dvl_with(path, &ColumnMap::default())
}

/// [`load_dvl`] with a column map (`[columns.dvl]`).
///
/// # Errors
/// As [`load_gt_with`].
pub fn load_dvl_with(path: &Path, map: &ColumnMap) -> Result<Vec<DvlSample>> {
    dvl_from(open_text(path)?, path, map)
}

/// Parse a DVL log from any reader; `path` names the source in errors.
///
/// # Errors
/// As [`load_gt`].
pub fn parse_dvl(reader: impl Read, path: &Path) -> Result<Vec<DvlSample>> {
    dvl_from(reader, path, &ColumnMap::default())
}

fn dvl_from(input: impl Read, path: &Path, map: &ColumnMap) -> Result<Vec<DvlSample>> {
    let rows = read_table(input, path, DVL_QUANTITIES, &map.dvl, "columns.dvl", 2)?;
    Ok(rows
        .into_iter()
        .map(|(line, r)| DvlSample {
            line,
            time: r[0],
            velocity_body: [r[1], r[2], r[3]],
        })
        .collect())
}

/// Read a table, streamed record by record (see [`super::table`]): the header names
/// the quantities' columns (see [`super::columns`]); every row holds as many fields as
/// the header; every cell of a quantity's column is a finite number within the
/// quantity's range (in SI after the header's unit); the first quantity is a strictly
/// increasing time; at least `min_rows` rows. Returns (line, values in quantity
/// order) per row.
fn read_table<const C: usize>(
    input: impl Read,
    path: &Path,
    quantities: &[Quantity; C],
    map: &std::collections::BTreeMap<String, String>,
    section: &str,
    min_rows: usize,
) -> Result<Vec<(u64, [f64; C])>> {
    let pb = || PathBuf::from(path);
    let mut rows: Vec<(u64, [f64; C])> = Vec::new();
    let read = for_each_row(
        input,
        path,
        MapSection {
            map,
            section,
            quantities,
        },
        |h| h.require(quantities),
        |columns, record| {
            let mut row = [0.0; C];
            for (k, (column, quantity)) in columns.iter().zip(quantities).enumerate() {
                row[k] = record.number(column, quantity)?;
            }
            if let Some(&(_, previous)) = rows.last() {
                if row[0] <= previous[0] {
                    return Err(DatasetError::TimeNotIncreasing {
                        path: pb(),
                        line: record.line,
                        time: row[0],
                        previous: previous[0],
                    });
                }
            }
            rows.push((record.line, row));
            Ok(())
        },
    );
    match read {
        // A blank file: the count this table needs.
        Err(DatasetError::TooFewRows { found: 0, .. }) => {
            return Err(DatasetError::TooFewRows {
                path: pb(),
                found: 0,
                min: min_rows,
            })
        }
        other => other?,
    }
    if rows.len() < min_rows {
        return Err(DatasetError::TooFewRows {
            path: pb(),
            found: rows.len(),
            min: min_rows,
        });
    }
    check_intervals(path, rows.iter().map(|(line, r)| (*line, r[0])))?;
    Ok(rows)
}

/// The interval every other one is compared with: the upper quartile of the
/// intervals. Not the median: in a file whose every row is doubled, half the
/// intervals are the duplicates' and the median may be one of them.
fn reference_interval(times: &[f64]) -> Option<f64> {
    let mut intervals: Vec<f64> = times.windows(2).map(|w| w[1] - w[0]).collect();
    if intervals.is_empty() {
        return None;
    }
    let k = (intervals.len() * 3) / 4;
    let (_, q, _) = intervals.select_nth_unstable_by(k, f64::total_cmp);
    Some(*q)
}

/// Refuse two rows closer in time than [`MIN_INTERVAL_FRACTION`] of the reference
/// interval (the upper quartile of the file's intervals): a row duplicated 1e-10 s
/// after its neighbour, or every row doubled at +1e-6 s, would otherwise be used as a
/// second sample (twice the DVL updates; a GT velocity from 1e-10 s).
pub(crate) fn check_intervals(path: &Path, rows: impl Iterator<Item = (u64, f64)>) -> Result<()> {
    let rows: Vec<(u64, f64)> = rows.collect();
    let times: Vec<f64> = rows.iter().map(|r| r.1).collect();
    let Some(reference) = reference_interval(&times) else {
        return Ok(());
    };
    let floor = MIN_INTERVAL_FRACTION * reference;
    if let Some(w) = rows.windows(2).find(|w| w[1].1 - w[0].1 < floor) {
        return Err(DatasetError::ImplausibleInterval {
            path: path.to_path_buf(),
            line: w[1].0,
            previous_line: w[0].0,
            time: w[1].1,
            interval: w[1].1 - w[0].1,
            reference,
        });
    }
    Ok(())
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
        let f = write("a,b,c,d\n0,1,2,3\n1,1,2,3\n");
        let e = load_dvl(f.path()).unwrap_err();
        assert!(matches!(e, DatasetError::MissingColumn { .. }), "{e}");
        let s = e.to_string();
        assert!(s.contains("time") && s.contains("a,b,c,d"), "{s}");
    }

    const GT_A_KIT: &str = "Time [s],Longitude [rad],Latitude [rad],Altitude [m],V North [m/s],V East [m/s],V Down [m/s],Roll [rad],Pitch [rad],Yaw [rad]\n\
         0,0.6,0.57,-20.5,1,0,0,0,0,0\n1,0.6,0.57,-20.6,1,0,0,0,0,0.1\n";

    #[test]
    fn reordered_columns_degrees_depth_and_v_up_give_the_same_samples() {
        let a = parse_gt(GT_A_KIT.as_bytes(), Path::new("a.csv")).expect("A-KIT layout");
        let d = |r: f64| r.to_degrees();
        let converted = format!(
            "\u{feff}yaw_deg,V Up [m/s],lat (deg),Depth [m],time,Roll [deg],Pitch [rad],lon [deg],v_east,VN\r\n\
             {},0,{},20.5,0,0,0,{},0,1\r\n{},0,{},20.6,1,0,0,{},0,1\r\n\r\n",
            d(0.0),
            d(0.57),
            d(0.6),
            d(0.1),
            d(0.57),
            d(0.6)
        );
        let b = parse_gt(converted.as_bytes(), Path::new("b.csv")).expect("converted layout");
        for (x, y) in a.iter().zip(&b) {
            assert_eq!(x.time, y.time);
            assert_eq!(x.altitude, y.altitude, "depth is minus altitude");
            assert!((x.latitude - y.latitude).abs() < 1e-15);
            assert!((x.longitude - y.longitude).abs() < 1e-15);
            assert!((x.roll_pitch_yaw[2] - y.roll_pitch_yaw[2]).abs() < 1e-15);
            assert_eq!(x.velocity_ned, y.velocity_ned);
        }
        assert_eq!(b[1].line, 3);
    }

    #[test]
    fn column_map_names_headers_with_units() {
        let text =
            "T,LAT,LON,Z,N,E,D,R,P,H\n0,32.7,34.9,15,1,0,0,0,0,90\n1,32.7,34.9,15,1,0,0,0,0,90\n";
        let mut map = ColumnMap::default();
        for (k, v) in [
            ("time_s", "T"),
            ("latitude_deg", "LAT"),
            ("longitude_deg", "LON"),
            ("depth_m", "Z"),
            ("v_north_mps", "N"),
            ("v_east_mps", "E"),
            ("v_down_mps", "D"),
            ("roll_deg", "R"),
            ("pitch_deg", "P"),
            ("heading_deg", "H"),
        ] {
            map.gt.insert(k.into(), v.into());
        }
        let f = write(text);
        let rows = load_gt_with(f.path(), &map).expect("mapped");
        assert_eq!(rows[0].altitude, -15.0);
        assert!((rows[0].latitude - 32.7f64.to_radians()).abs() < 1e-15);
        assert!((rows[0].roll_pitch_yaw[2] - std::f64::consts::FRAC_PI_2).abs() < 1e-15);
        // Without the map the same file fails, naming the file, the column and the headers.
        let e = load_gt(f.path()).unwrap_err().to_string();
        assert!(
            e.contains(&f.path().display().to_string()) && e.contains("T,LAT,LON"),
            "{e}"
        );
        map.gt.insert("yaw_furlong".into(), "H".into());
        let e = load_gt_with(f.path(), &map).unwrap_err().to_string();
        assert!(e.contains("yaw_furlong"), "{e}");
    }

    #[test]
    fn truncation_crlf_bom_blank_lines_and_ranges() {
        let h = "Time [s],DVL X [m/s],DVL Y [m/s],DVL Z [m/s]\n";
        let p = Path::new("d.csv");
        // A last line without newline is a truncation even when it parses.
        let e = parse_dvl(format!("{h}0,1,2,3\n1,1,2,3").as_bytes(), p).unwrap_err();
        assert!(matches!(e, DatasetError::Truncated { line: 3, .. }), "{e}");
        let e = parse_dvl(format!("{h}0,1,2,3\n1,1,2,3\r").as_bytes(), p).unwrap_err();
        assert!(matches!(e, DatasetError::Truncated { line: 3, .. }), "{e}");
        let ok = format!(
            "\u{feff}{}0,1,2,3\r\n1,1,2,3\r\n\r\n\n  ",
            h.replace('\n', "\r\n")
        );
        assert_eq!(parse_dvl(ok.as_bytes(), p).map(|r| r.len()).ok(), Some(2));
        let e = parse_dvl(format!("{h}0,1,2,3\n1,1,2000,3\n").as_bytes(), p).unwrap_err();
        assert!(
            e.to_string().starts_with("d.csv:3: column `DVL Y [m/s]`"),
            "{e}"
        );
        let deg_as_rad = GT_A_KIT.replace("0.57,", "32.7,");
        let e = parse_gt(deg_as_rad.as_bytes(), p).unwrap_err().to_string();
        assert!(
            e.starts_with("d.csv:2:") && e.contains("Latitude [rad]") && e.contains("deg"),
            "{e}"
        );
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
    fn rows_closer_than_a_tenth_of_the_typical_interval_are_refused() {
        let h = "Time [s],DVL X [m/s],DVL Y [m/s],DVL Z [m/s]\n";
        let p = Path::new("d.csv");
        let rows = |times: &[f64]| {
            let mut s = h.to_string();
            for t in times {
                s.push_str(&format!("{t},1,0,0\n"));
            }
            s
        };
        let regular: Vec<f64> = (0..50).map(|k| k as f64 * 1.0025).collect();
        assert!(parse_dvl(rows(&regular).as_bytes(), p).is_ok());
        // One row duplicated 1e-10 s after its neighbour (line 12 = row 11 + header).
        let mut dup = regular.clone();
        dup.insert(11, dup[10] + 1e-10);
        let e = parse_dvl(rows(&dup).as_bytes(), p).unwrap_err();
        assert!(
            matches!(
                e,
                DatasetError::ImplausibleInterval {
                    line: 13,
                    previous_line: 12,
                    ..
                }
            ),
            "{e}"
        );
        assert!(e.to_string().starts_with("d.csv:13:"), "{e}");
        // Every row doubled at +1e-6 s: the median interval is a duplicate's, the upper
        // quartile is not.
        let doubled: Vec<f64> = regular.iter().flat_map(|&t| [t, t + 1e-6]).collect();
        let e = parse_dvl(rows(&doubled).as_bytes(), p).unwrap_err();
        assert!(
            matches!(e, DatasetError::ImplausibleInterval { line: 3, .. }),
            "{e}"
        );
        // Gaps (an outage) and jitter of +-30 % are not refused.
        let mut gappy: Vec<f64> = (0..40)
            .map(|k| k as f64 + 0.3 * ((k % 3) as f64 - 1.0))
            .collect();
        gappy.extend((0..20).map(|k| 100.0 + k as f64));
        assert!(parse_dvl(rows(&gappy).as_bytes(), p).is_ok());
        // GT too.
        let gt = format!("{GT_A_KIT}1.00000000001,0.6,0.57,-20.6,1,0,0,0,0,0.1\n2,0.6,0.57,-20.6,1,0,0,0,0,0.1\n3,0.6,0.57,-20.6,1,0,0,0,0,0.1\n");
        let e = parse_gt(gt.as_bytes(), p).unwrap_err();
        assert!(
            matches!(e, DatasetError::ImplausibleInterval { line: 4, .. }),
            "{e}"
        );
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
