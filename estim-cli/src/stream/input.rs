//! The input of `estim navigate --stream`: lines read with a cap on their length (from
//! stdin, a file still being written, a TCP socket), each on a thread of its own, and
//! parsed into records (estim's JSON records and Water Linked velocity reports).

use std::io::{BufRead, BufReader, Read};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use estim::core::nalgebra::Vector3;
use estim::navigator::{DvlInput, StreamError};
use serde_json::{Map, Value};

use crate::waterlinked;

/// The longest line read \[bytes\]: a record is well under 1 KiB, a Water Linked
/// report about 2 KiB.
pub const MAX_LINE_BYTES: usize = 64 * 1024;

/// RDI's bad-velocity marker (-32768 mm/s), a row without lock as in a CSV.
const RDI_BAD_VELOCITY: f64 = -32.768;

/// What was wrong with one line (the line's source and number are added by
/// [`LineError`]).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RecordError {
    /// Not JSON.
    #[error("not a JSON record: {0}")]
    Json(#[source] serde_json::Error),
    /// JSON, but not an object.
    #[error("a record is a JSON object")]
    NotAnObject,
    /// A key the record needs is missing.
    #[error("key `{key}` is missing")]
    MissingKey {
        /// The key.
        key: &'static str,
    },
    /// A key the sensor does not have.
    #[error("key `{key}` is not one of a `{sensor}` record's")]
    UnknownKey {
        /// The key.
        key: String,
        /// The record's sensor.
        sensor: &'static str,
    },
    /// A value that is not a finite number (or an array of them).
    #[error("key `{key}`: not a finite number (or array of the documented length)")]
    NotANumber {
        /// The key.
        key: &'static str,
    },
    /// A value that is not true or false.
    #[error("key `{key}`: not true or false")]
    NotABool {
        /// The key.
        key: &'static str,
    },
    /// An unknown `sensor`.
    #[error("sensor `{0}` is not imu, dvl, beams, depth or fix")]
    UnknownSensor(String),
    /// A line longer than [`MAX_LINE_BYTES`].
    #[error("longer than {MAX_LINE_BYTES} bytes")]
    TooLong,
    /// The stream ended inside a line.
    #[error("the stream ended inside this line (no newline): truncated")]
    Truncated,
    /// What the navigator refused (an IMU going back in time, a non-finite value).
    #[error(transparent)]
    Stream(StreamError),
}

/// A bad line: where it is and what was wrong.
#[derive(Debug, thiserror::Error)]
#[error("{source_name}:{line}: {error}")]
pub struct LineError {
    /// `stdin`, the followed file or the TCP address.
    pub source_name: String,
    /// The line's number (from 1).
    pub line: usize,
    /// What was wrong (in the message: not also a source, so printed once).
    pub error: RecordError,
}

/// One record read.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Record {
    Imu {
        time: f64,
        acc: [f64; 3],
        gyro: [f64; 3],
    },
    Dvl {
        time: f64,
        input: DvlInput,
    },
    /// A Water Linked velocity report (time of validity in Unix µs).
    WaterLinked {
        time_us: i64,
        input: DvlInput,
    },
    Depth {
        time: f64,
        depth: f64,
    },
    Fix {
        time: f64,
        lat_deg: f64,
        lon_deg: f64,
        sigma_m: f64,
    },
    /// A record of no use to the navigator (another Water Linked report type).
    Ignored,
}

/// Parse one line.
pub(super) fn parse(bytes: &[u8]) -> Result<Record, RecordError> {
    let value: Value = serde_json::from_slice(bytes).map_err(RecordError::Json)?;
    let Value::Object(object) = value else {
        return Err(RecordError::NotAnObject);
    };
    if !object.contains_key("sensor") && object.contains_key("type") {
        return Ok(match waterlinked::report(&object)? {
            waterlinked::Report::Velocity {
                time_of_validity_us,
                velocity,
            } => Record::WaterLinked {
                time_us: time_of_validity_us,
                input: velocity.map_or(DvlInput::NoLock, dvl_velocity),
            },
            waterlinked::Report::Other => Record::Ignored,
        });
    }
    let sensor = match object.get("sensor") {
        None => return Err(RecordError::MissingKey { key: "sensor" }),
        Some(Value::String(s)) => s.as_str(),
        Some(_) => return Err(RecordError::NotANumber { key: "sensor" }),
    };
    let (name, keys): (&'static str, &[&str]) = match sensor {
        "imu" => ("imu", &["sensor", "time", "acc", "gyro"]),
        "dvl" => ("dvl", &["sensor", "time", "velocity"]),
        "beams" => ("beams", &["sensor", "time", "beams"]),
        "depth" => ("depth", &["sensor", "time", "depth"]),
        "fix" => ("fix", &["sensor", "time", "lat_deg", "lon_deg", "sigma_m"]),
        other => return Err(RecordError::UnknownSensor(other.chars().take(40).collect())),
    };
    if let Some(key) = object.keys().find(|k| !keys.contains(&k.as_str())) {
        return Err(RecordError::UnknownKey {
            key: key.chars().take(40).collect(),
            sensor: name,
        });
    }
    let time = number(&object, "time")?;
    Ok(match name {
        "imu" => Record::Imu {
            time,
            acc: triple(&object, "acc")?,
            gyro: triple(&object, "gyro")?,
        },
        "dvl" => match object.get("velocity") {
            None => return Err(RecordError::MissingKey { key: "velocity" }),
            Some(Value::Null) => Record::Dvl {
                time,
                input: DvlInput::NoLock,
            },
            Some(_) => Record::Dvl {
                time,
                input: dvl_velocity(triple(&object, "velocity")?),
            },
        },
        "beams" => Record::Dvl {
            time,
            input: DvlInput::Beams(beams(&object)?),
        },
        "depth" => Record::Depth {
            time,
            depth: number(&object, "depth")?,
        },
        _ => Record::Fix {
            time,
            lat_deg: number(&object, "lat_deg")?,
            lon_deg: number(&object, "lon_deg")?,
            sigma_m: number(&object, "sigma_m")?,
        },
    })
}

/// A DVL velocity, or no lock for RDI's bad-value marker.
fn dvl_velocity(v: [f64; 3]) -> DvlInput {
    if v.contains(&RDI_BAD_VELOCITY) {
        DvlInput::NoLock
    } else {
        DvlInput::Velocity(Vector3::from(v))
    }
}

fn number(object: &Map<String, Value>, key: &'static str) -> Result<f64, RecordError> {
    match object.get(key) {
        None => Err(RecordError::MissingKey { key }),
        Some(v) => v
            .as_f64()
            .filter(|x| x.is_finite())
            .ok_or(RecordError::NotANumber { key }),
    }
}

fn triple(object: &Map<String, Value>, key: &'static str) -> Result<[f64; 3], RecordError> {
    let Some(value) = object.get(key) else {
        return Err(RecordError::MissingKey { key });
    };
    let values: Option<Vec<f64>> = value.as_array().filter(|a| a.len() == 3).and_then(|a| {
        a.iter()
            .map(|x| x.as_f64().filter(|x| x.is_finite()))
            .collect()
    });
    match values.as_deref() {
        Some(&[x, y, z]) => Ok([x, y, z]),
        _ => Err(RecordError::NotANumber { key }),
    }
}

/// Four beams; null, or RDI's marker, is a missing beam.
fn beams(object: &Map<String, Value>) -> Result<[Option<f64>; 4], RecordError> {
    let key = "beams";
    let Some(value) = object.get(key) else {
        return Err(RecordError::MissingKey { key });
    };
    let array = value
        .as_array()
        .filter(|a| a.len() == 4)
        .ok_or(RecordError::NotANumber { key })?;
    let mut out = [None; 4];
    for (slot, v) in out.iter_mut().zip(array) {
        *slot = match v {
            Value::Null => None,
            v => {
                let x = v
                    .as_f64()
                    .filter(|x| x.is_finite())
                    .ok_or(RecordError::NotANumber { key })?;
                (x != RDI_BAD_VELOCITY).then_some(x)
            }
        };
    }
    Ok(out)
}

/// What a reader thread sends.
pub(super) enum Message {
    Line {
        source: usize,
        number: usize,
        bytes: Vec<u8>,
    },
    Failed {
        source: usize,
        number: usize,
        error: RecordError,
    },
    Io {
        source: usize,
        error: std::io::Error,
    },
    Ended {
        source: usize,
    },
}

/// How one line read ended.
pub(super) enum LineRead {
    Line,
    End,
}

/// Read one line (without its newline, and a CR before it) into `buf`, at most
/// [`MAX_LINE_BYTES`]. With `follow`, wait at the end of the data for more, up to
/// `idle` without any.
pub(super) fn read_line(
    reader: &mut impl BufRead,
    buf: &mut Vec<u8>,
    follow: Option<Duration>,
) -> Result<LineRead, Result<RecordError, std::io::Error>> {
    buf.clear();
    let mut idle_since = Instant::now();
    loop {
        let available = match reader.fill_buf() {
            Ok(a) => a,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(Err(e)),
        };
        if available.is_empty() {
            match follow {
                Some(idle) if idle_since.elapsed() < idle => {
                    std::thread::sleep(Duration::from_millis(20));
                    continue;
                }
                _ if buf.is_empty() => return Ok(LineRead::End),
                _ => return Err(Ok(RecordError::Truncated)),
            }
        }
        idle_since = Instant::now();
        let (take, done) = match available.iter().position(|&b| b == b'\n') {
            Some(i) => (i, true),
            None => (available.len(), false),
        };
        if buf.len() + take > MAX_LINE_BYTES {
            return Err(Ok(RecordError::TooLong));
        }
        buf.extend_from_slice(&available[..take]);
        reader.consume(take + usize::from(done));
        if done {
            if buf.last() == Some(&b'\r') {
                buf.pop();
            }
            return Ok(LineRead::Line);
        }
    }
}

/// Read lines from `reader` on a thread of its own, sending them to `tx`.
pub(super) fn spawn_reader(
    source: usize,
    reader: Box<dyn Read + Send>,
    follow: Option<Duration>,
    tx: mpsc::SyncSender<Message>,
) {
    std::thread::spawn(move || {
        let mut reader = BufReader::with_capacity(64 * 1024, reader);
        let mut number = 0;
        let mut buf = Vec::new();
        loop {
            number += 1;
            let message = match read_line(&mut reader, &mut buf, follow) {
                Ok(LineRead::Line) => Message::Line {
                    source,
                    number,
                    bytes: std::mem::take(&mut buf),
                },
                Ok(LineRead::End) => Message::Ended { source },
                Err(Ok(error)) => Message::Failed {
                    source,
                    number,
                    error,
                },
                Err(Err(error)) => Message::Io { source, error },
            };
            let last = !matches!(message, Message::Line { .. });
            if tx.send(message).is_err() || last {
                return;
            }
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_parse_and_bad_ones_name_what_is_wrong() {
        let imu = br#"{"sensor": "imu", "time": 1.5, "acc": [0, 0, -9.8], "gyro": [0, 0, 0.1]}"#;
        assert_eq!(
            parse(imu).unwrap(),
            Record::Imu {
                time: 1.5,
                acc: [0.0, 0.0, -9.8],
                gyro: [0.0, 0.0, 0.1]
            }
        );
        let dvl = br#"{"sensor": "dvl", "time": 2, "velocity": null}"#;
        assert!(matches!(
            parse(dvl).unwrap(),
            Record::Dvl {
                input: DvlInput::NoLock,
                ..
            }
        ));
        let beams = br#"{"sensor": "beams", "time": 2, "beams": [0.1, null, 0.2, -32.768]}"#;
        assert!(matches!(
            parse(beams).unwrap(),
            Record::Dvl {
                input: DvlInput::Beams([Some(_), None, Some(_), None]),
                ..
            }
        ));
        let cases: [(&[u8], &str); 8] = [
            (b"{\"sensor\": \"imu\"", "not a JSON record"),
            (b"[1, 2]", "JSON object"),
            (br#"{"sensor": "gps", "time": 1}"#, "sensor `gps`"),
            (
                br#"{"sensor": "imu", "time": 1, "acc": [0, 0], "gyro": [0, 0, 0]}"#,
                "`acc`",
            ),
            (
                br#"{"sensor": "depth", "time": 1, "depth": 1e999}"#,
                "not a JSON record",
            ),
            (
                br#"{"sensor": "fix", "time": 1, "lat_deg": 1, "lon_deg": 2}"#,
                "`sigma_m` is missing",
            ),
            (
                br#"{"sensor": "depth", "time": 1, "depth": 3, "extra": 1}"#,
                "`extra`",
            ),
            (
                br#"{"sensor": "dvl", "time": "soon", "velocity": null}"#,
                "`time`",
            ),
        ];
        for (line, expected) in cases {
            let e = parse(line).unwrap_err().to_string();
            assert!(e.contains(expected), "{e} lacks {expected}");
        }
    }

    #[test]
    fn lines_are_capped_and_a_missing_newline_is_truncation() {
        let long = vec![b'x'; MAX_LINE_BYTES + 10];
        let mut reader = std::io::Cursor::new(long);
        let mut buf = Vec::new();
        assert!(matches!(
            read_line(&mut reader, &mut buf, None),
            Err(Ok(RecordError::TooLong))
        ));
        let mut reader = std::io::Cursor::new(b"a\r\nb".to_vec());
        assert!(matches!(
            read_line(&mut reader, &mut buf, None),
            Ok(LineRead::Line)
        ));
        assert_eq!(buf, b"a");
        assert!(matches!(
            read_line(&mut reader, &mut buf, None),
            Err(Ok(RecordError::Truncated))
        ));
    }
}
