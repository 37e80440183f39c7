//! IMU CSV files at any rate: specific force and angular rate, or velocity and angle
//! increments, with the units the header states.
//!
//! Columns by name (case, spaces, `_`, `-`, `.` ignored; unit in `[..]`, `(..)` or a
//! trailing `_unit`): time (`time`, `t`, `timestamp`; s or ms); specific force
//! (`acc x`, `accx`, `ax`, `fx`, `specific force x`, ...; m/s^2 or g) or velocity
//! increments (`dv x`, `delta v x`, `dvel x`; m/s, cm/s, mm/s); angular rate (`gyro
//! x`, `gx`, `wx`, `omega x`, `angular rate x`; rad/s or deg/s) or angle increments
//! (`dtheta x`, `delta theta x`, `dang x`; rad or deg). Without a unit: m/s^2, rad/s,
//! m/s, rad.
//!
//! A rate row k is the mean over [t_k, t_k+1]; an increment row k covers
//! (t_k-1, t_k], so the first increment row only starts the clock. A simulated file
//! may carry its true biases (`true acc bias x` [m/s^2], `true gyro bias x` [rad/s]),
//! which the evaluation (`--truth`) reads and the navigator never uses.

use std::path::Path;

use estim_ins::ImuSample;
use nalgebra::Vector3;

use super::columns::{same, Alias, Kind, Quantity, Resolved};
use super::input::open_text;
use super::table::{for_each_row, MapSection, TIME};
use super::{DatasetError, Result};

/// Largest |specific force| accepted \[m/s^2\] (about 100 g).
pub const MAX_ABS_SPECIFIC_FORCE_MPS2: f64 = 1000.0;
/// Largest |angular rate| accepted \[rad/s\].
pub const MAX_ABS_ANGULAR_RATE_RADPS: f64 = 100.0;
/// Largest |angular rate| \[rad/s\] (about 170 deg/s) a vehicle the navigator models
/// sustains for [`IMPLAUSIBLE_RATE_DURATION_S`]: above it, in a file whose rate columns
/// state no unit, the unit cannot be read (deg/s read as rad/s) and the file is
/// refused ([`DatasetError::UnitUnreadable`]).
pub const PLAUSIBLE_ANGULAR_RATE_RADPS: f64 = 3.0;
/// How long \[s\] the rate must stay above [`PLAUSIBLE_ANGULAR_RATE_RADPS`] to refuse.
pub const IMPLAUSIBLE_RATE_DURATION_S: f64 = 1.0;

const fn q(key: &'static str, kind: Kind, aliases: &'static [Alias], max_abs: f64) -> Quantity {
    Quantity {
        key,
        kind,
        aliases,
        max_abs,
    }
}

const A: f64 = MAX_ABS_SPECIFIC_FORCE_MPS2;
const W: f64 = MAX_ABS_ANGULAR_RATE_RADPS;

const FORCE: [Quantity; 3] = [
    q(
        "acc_x",
        Kind::Acceleration,
        &[
            same("accx"),
            same("ax"),
            same("fx"),
            same("accelerometerx"),
            same("specificforcex"),
            same("accelx"),
            same("accelerationx"),
        ],
        A,
    ),
    q(
        "acc_y",
        Kind::Acceleration,
        &[
            same("accy"),
            same("ay"),
            same("fy"),
            same("accelerometery"),
            same("specificforcey"),
            same("accely"),
            same("accelerationy"),
        ],
        A,
    ),
    q(
        "acc_z",
        Kind::Acceleration,
        &[
            same("accz"),
            same("az"),
            same("fz"),
            same("accelerometerz"),
            same("specificforcez"),
            same("accelz"),
            same("accelerationz"),
        ],
        A,
    ),
];
const RATE: [Quantity; 3] = [
    q(
        "gyro_x",
        Kind::AngularRate,
        &[
            same("gyrox"),
            same("gx"),
            same("wx"),
            same("omegax"),
            same("gyroscopex"),
            same("angularratex"),
            same("ratex"),
        ],
        W,
    ),
    q(
        "gyro_y",
        Kind::AngularRate,
        &[
            same("gyroy"),
            same("gy"),
            same("wy"),
            same("omegay"),
            same("gyroscopey"),
            same("angularratey"),
            same("ratey"),
        ],
        W,
    ),
    q(
        "gyro_z",
        Kind::AngularRate,
        &[
            same("gyroz"),
            same("gz"),
            same("wz"),
            same("omegaz"),
            same("gyroscopez"),
            same("angularratez"),
            same("ratez"),
        ],
        W,
    ),
];
const DELTA_V: [Quantity; 3] = [
    q(
        "dv_x",
        Kind::Speed,
        &[
            same("dvx"),
            same("deltavx"),
            same("dvelx"),
            same("deltavelocityx"),
        ],
        A,
    ),
    q(
        "dv_y",
        Kind::Speed,
        &[
            same("dvy"),
            same("deltavy"),
            same("dvely"),
            same("deltavelocityy"),
        ],
        A,
    ),
    q(
        "dv_z",
        Kind::Speed,
        &[
            same("dvz"),
            same("deltavz"),
            same("dvelz"),
            same("deltavelocityz"),
        ],
        A,
    ),
];
const DELTA_THETA: [Quantity; 3] = [
    q(
        "dtheta_x",
        Kind::Angle,
        &[
            same("dthetax"),
            same("deltathetax"),
            same("dangx"),
            same("deltaanglex"),
        ],
        W,
    ),
    q(
        "dtheta_y",
        Kind::Angle,
        &[
            same("dthetay"),
            same("deltathetay"),
            same("dangy"),
            same("deltaangley"),
        ],
        W,
    ),
    q(
        "dtheta_z",
        Kind::Angle,
        &[
            same("dthetaz"),
            same("deltathetaz"),
            same("dangz"),
            same("deltaanglez"),
        ],
        W,
    ),
];
const TRUE_ACC_BIAS: [Quantity; 3] = [
    q(
        "true_acc_bias_x",
        Kind::Acceleration,
        &[same("trueaccbiasx")],
        A,
    ),
    q(
        "true_acc_bias_y",
        Kind::Acceleration,
        &[same("trueaccbiasy")],
        A,
    ),
    q(
        "true_acc_bias_z",
        Kind::Acceleration,
        &[same("trueaccbiasz")],
        A,
    ),
];
const TRUE_GYRO_BIAS: [Quantity; 3] = [
    q(
        "true_gyro_bias_x",
        Kind::AngularRate,
        &[same("truegyrobiasx")],
        W,
    ),
    q(
        "true_gyro_bias_y",
        Kind::AngularRate,
        &[same("truegyrobiasy")],
        W,
    ),
    q(
        "true_gyro_bias_z",
        Kind::AngularRate,
        &[same("truegyrobiasz")],
        W,
    ),
];

/// An IMU file read: samples with times relative to `epoch_s`.
#[derive(Debug, Clone, PartialEq)]
pub struct ImuLog {
    /// The epoch \[s\] the times are relative to (an integer number of seconds: the
    /// one asked for, else the whole seconds of the first time).
    pub epoch_s: f64,
    /// Samples (raw: biases included), time = start of the interval each covers.
    pub samples: Vec<ImuSample>,
    /// The 1-based line of each sample (of its last row for increments).
    pub lines: Vec<u64>,
    /// True accelerometer and gyroscope biases per sample, when the file carries them
    /// (a simulated IMU).
    pub true_biases: Option<Vec<(Vector3<f64>, Vector3<f64>)>>,
}

struct Columns {
    time: Resolved,
    force: Vec<Resolved>,
    rate: Vec<Resolved>,
    increments: (bool, bool),
    truth: Option<(Vec<Resolved>, Vec<Resolved>)>,
}

/// Every quantity an IMU file may have (the keys of `[columns.imu]`).
pub(crate) fn quantities() -> Vec<Quantity> {
    std::iter::once(TIME)
        .chain(FORCE)
        .chain(RATE)
        .chain(DELTA_V)
        .chain(DELTA_THETA)
        .chain(TRUE_ACC_BIAS)
        .chain(TRUE_GYRO_BIAS)
        .collect()
}

fn pick(
    header: &super::table::Header<'_>,
    rate: &[Quantity; 3],
    increment: &[Quantity; 3],
) -> Result<(Vec<Resolved>, bool)> {
    if let Some(r) = header.all_or_none(rate)? {
        return Ok((r, false));
    }
    if let Some(r) = header.all_or_none(increment)? {
        return Ok((r, true));
    }
    header.require(rate).map(|r| (r, false))
}

impl ImuLog {
    /// Read an IMU file (see [`ImuLog::parse`]).
    ///
    /// # Errors
    /// [`DatasetError::Io`], then those of [`ImuLog::parse`].
    pub fn load(path: &Path, epoch_s: Option<f64>) -> Result<Self> {
        Self::parse_with(
            open_text(path)?,
            path,
            epoch_s,
            &super::ColumnMap::default(),
        )
    }

    /// [`ImuLog::load`] with a column map (its `imu` section).
    ///
    /// # Errors
    /// As [`ImuLog::load`], and [`DatasetError::ColumnMap`] naming a bad key.
    pub fn load_with(path: &Path, epoch_s: Option<f64>, map: &super::ColumnMap) -> Result<Self> {
        Self::parse_with(open_text(path)?, path, epoch_s, map)
    }

    /// Parse an IMU file; `path` names it in errors (with the 1-based line).
    ///
    /// # Errors
    /// Missing, ambiguous or badly united columns, non-numeric, non-finite or
    /// out-of-range cells, times that do not increase, fewer than 2 samples.
    pub fn parse(bytes: &[u8], path: &Path, epoch_s: Option<f64>) -> Result<Self> {
        Self::parse_with(bytes, path, epoch_s, &super::ColumnMap::default())
    }

    /// [`ImuLog::parse`] with a column map (its `imu` section).
    ///
    /// # Errors
    /// As [`ImuLog::parse`], and [`DatasetError::ColumnMap`] naming a bad key.
    pub fn parse_with(
        input: impl std::io::Read,
        path: &Path,
        epoch_s: Option<f64>,
        map: &super::ColumnMap,
    ) -> Result<Self> {
        let quantities = quantities();
        let section = MapSection {
            map: &map.imu,
            section: "columns.imu",
            quantities: &quantities,
        };
        let mut epoch = epoch_s;
        let mut samples = Vec::new();
        let mut lines = Vec::new();
        let mut truth: Vec<(Vector3<f64>, Vector3<f64>)> = Vec::new();
        let mut previous: Option<(f64, Vector3<f64>, Vector3<f64>)> = None;
        // The rate (or angle increment) columns, when none states its unit.
        let mut unitless_rates: Option<Vec<String>> = None;
        let mut first_row = true;
        for_each_row(
            input,
            path,
            section,
            |h| {
                let time = h.require(&[TIME])?.remove(0);
                let (force, dv) = pick(h, &FORCE, &DELTA_V)?;
                let (rate, dtheta) = pick(h, &RATE, &DELTA_THETA)?;
                let truth = match (
                    h.all_or_none(&TRUE_ACC_BIAS)?,
                    h.all_or_none(&TRUE_GYRO_BIAS)?,
                ) {
                    (Some(a), Some(g)) => Some((a, g)),
                    _ => None,
                };
                Ok(Columns {
                    time,
                    force,
                    rate,
                    increments: (dv, dtheta),
                    truth,
                })
            },
            |c, row| {
                if std::mem::take(&mut first_row) && c.rate.iter().all(|r| !r.unit_stated) {
                    unitless_rates = Some(c.rate.iter().map(|r| r.header.clone()).collect());
                }
                let epoch = match epoch {
                    Some(e) => e,
                    None => *epoch.insert(row.whole_seconds(&c.time)?),
                };
                let t = row.time(&c.time, epoch)?;
                let vector = |cols: &[Resolved], qs: &[Quantity; 3]| -> Result<Vector3<f64>> {
                    Ok(Vector3::new(
                        row.number(&cols[0], &qs[0])?,
                        row.number(&cols[1], &qs[1])?,
                        row.number(&cols[2], &qs[2])?,
                    ))
                };
                let (dv, dtheta) = c.increments;
                let force = vector(&c.force, if dv { &DELTA_V } else { &FORCE })?;
                let rate = vector(&c.rate, if dtheta { &DELTA_THETA } else { &RATE })?;
                let biases = match &c.truth {
                    Some((a, g)) => Some((vector(a, &TRUE_ACC_BIAS)?, vector(g, &TRUE_GYRO_BIAS)?)),
                    None => None,
                };
                if let Some((p, _, _)) = previous {
                    if t <= p {
                        return Err(row.not_increasing(t, p));
                    }
                }
                match previous {
                    Some((p, _, _)) if dv || dtheta => {
                        let dt = t - p;
                        let f = if dv { force / dt } else { force };
                        let w = if dtheta { rate / dt } else { rate };
                        samples.push(ImuSample::new(p, f, w));
                        lines.push(row.line);
                        if let Some(b) = biases {
                            truth.push(b);
                        }
                    }
                    _ if !(dv || dtheta) => {
                        samples.push(ImuSample::new(t, force, rate));
                        lines.push(row.line);
                        if let Some(b) = biases {
                            truth.push(b);
                        }
                    }
                    _ => {}
                }
                previous = Some((t, force, rate));
                Ok(())
            },
        )?;
        if samples.len() < 2 {
            return Err(DatasetError::TooFewRows {
                path: path.to_path_buf(),
                found: samples.len(),
                min: 2,
            });
        }
        if let Some(columns) = unitless_rates {
            check_rate_unit(path, &samples, &lines, &columns)?;
        }
        let true_biases = (truth.len() == samples.len()).then_some(truth);
        Ok(Self {
            epoch_s: epoch.unwrap_or(0.0),
            samples,
            lines,
            true_biases,
        })
    }
}

/// Refuse rates above [`PLAUSIBLE_ANGULAR_RATE_RADPS`] for
/// [`IMPLAUSIBLE_RATE_DURATION_S`] or longer (rate columns without a unit).
fn check_rate_unit(
    path: &Path,
    samples: &[ImuSample],
    lines: &[u64],
    columns: &[String],
) -> Result<()> {
    let mut start: Option<usize> = None;
    for (k, s) in samples.iter().enumerate() {
        if s.angular_rate.amax() <= PLAUSIBLE_ANGULAR_RATE_RADPS {
            start = None;
            continue;
        }
        let first = *start.get_or_insert(k);
        let seconds = s.time - samples[first].time;
        if seconds >= IMPLAUSIBLE_RATE_DURATION_S {
            // The column with the largest value over the stretch.
            let (axis, value) = samples[first..=k]
                .iter()
                .flat_map(|s| s.angular_rate.iter().copied().enumerate())
                .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
                .unwrap_or((0, s.angular_rate.x));
            return Err(DatasetError::UnitUnreadable {
                path: path.to_path_buf(),
                line: lines.get(first).copied().unwrap_or(0),
                column: columns.get(axis).cloned().unwrap_or_default(),
                value,
                limit: PLAUSIBLE_ANGULAR_RATE_RADPS,
                unit: "rad/s",
                seconds,
            });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn units_names_and_increments() {
        let p = Path::new("imu.csv");
        let log = ImuLog::parse(
            b"Time [ms],GYRO X [deg/s],gyro y [deg/s],gyro z [deg/s],ax [g],ay [g],az [g]\n0,0,0,180,0,0,-1\n10,0,0,180,0,0,-1\n",
            p,
            None,
        )
        .unwrap();
        assert_eq!(log.samples.len(), 2);
        assert_eq!(log.samples[1].time, 0.01);
        assert!((log.samples[0].angular_rate.z - std::f64::consts::PI).abs() < 1e-12);
        assert!((log.samples[0].specific_force.z + 9.80665).abs() < 1e-12);
        let inc = ImuLog::parse(
            b"t,dv_x,dv_y,dv_z,dtheta x [deg],dtheta y [deg],dtheta z [deg]\n10.0,0,0,0,0,0,0\n10.5,0,0,-4.9,0,0,1\n11.0,0,0,-4.9,0,0,1\n",
            p,
            None,
        )
        .unwrap();
        assert_eq!(inc.epoch_s, 10.0);
        assert_eq!(inc.samples.len(), 2);
        assert_eq!(inc.samples[0].time, 0.0);
        assert!((inc.samples[0].specific_force.z + 9.8).abs() < 1e-12);
        assert!((inc.samples[1].angular_rate.z - 2f64.to_radians()).abs() < 1e-12);
    }

    #[test]
    fn errors_name_file_and_line() {
        let p = Path::new("imu.csv");
        let e = ImuLog::parse(
            b"t,ax,ay,az,gx,gy,gz\n0,0,0,-9.8,0,0,0\n0.01,0,0,x,0,0,0\n",
            p,
            None,
        )
        .unwrap_err();
        assert!(e.to_string().starts_with("imu.csv:3:"), "{e}");
        let e = ImuLog::parse(
            b"t,ax,ay,az,gx,gy,gz\n0,0,0,-9.8,0,0,0\n0,0,0,-9.8,0,0,0\n",
            p,
            None,
        )
        .unwrap_err();
        assert!(e.to_string().starts_with("imu.csv:3:"), "{e}");
        let e = ImuLog::parse(b"t,ax,ay,gx,gy,gz\n0,0,0,0,0,0\n", p, None).unwrap_err();
        assert!(e.to_string().contains("imu.csv:1:"), "{e}");
        let e = ImuLog::parse(b"t,ax,ay,az,gx,gy,gz\n0,0,0,nan,0,0,0\n", p, None).unwrap_err();
        assert!(e.to_string().starts_with("imu.csv:2:"), "{e}");
    }
}
