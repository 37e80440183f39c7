//! Water Linked DVL (A50, A125) velocity reports: the JSON protocol over TCP
//! (`json_v3` and later; the DVL serves it on port 16171), one report per line.
//!
//! Fields used from a report whose `type` is `"velocity"` (Water Linked, "DVL
//! protocol", "Velocity and transducer report"): `vx`, `vy`, `vz` (m/s, in the
//! DVL's mounted frame as marked on it: the vehicle file's `[dvl]` mounting applies),
//! `velocity_valid` (false: no bottom lock, the row is skipped and counted) and
//! `time_of_validity` (the centre of the ping, Unix time in microseconds: the
//! record's stamp, before `dvl.time_offset_s`). `time`, `fom`, `covariance`,
//! `altitude`, `transducers`, `status`, `format` and `time_of_transmission` are not
//! used (R is the vehicle file's). Reports of other types (`position_local`,
//! command responses) are ignored and counted.

use serde_json::{Map, Value};

use crate::stream::RecordError;

/// A Water Linked report.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Report {
    /// A velocity report: its time of validity \[µs, Unix\] and velocity (`None`:
    /// no bottom lock).
    Velocity {
        /// `time_of_validity` \[µs\].
        time_of_validity_us: i64,
        /// `vx`, `vy`, `vz` \[m/s\] when `velocity_valid`.
        velocity: Option<[f64; 3]>,
    },
    /// Another type of report (ignored).
    Other,
}

/// Read a report from a JSON object that has a `type` key.
///
/// # Errors
/// [`RecordError`] naming the key missing or of the wrong kind.
pub fn report(object: &Map<String, Value>) -> Result<Report, RecordError> {
    if object.get("type").and_then(Value::as_str) != Some("velocity") {
        return Ok(Report::Other);
    }
    let number = |key: &'static str| -> Result<f64, RecordError> {
        match object.get(key) {
            None => Err(RecordError::MissingKey { key }),
            Some(v) => v
                .as_f64()
                .filter(|x| x.is_finite())
                .ok_or(RecordError::NotANumber { key }),
        }
    };
    let time_of_validity_us = match object.get("time_of_validity") {
        None => {
            return Err(RecordError::MissingKey {
                key: "time_of_validity (a json_v3 report or later)",
            })
        }
        Some(v) => v.as_i64().ok_or(RecordError::NotANumber {
            key: "time_of_validity (integer microseconds)",
        })?,
    };
    let valid = match object.get("velocity_valid") {
        None => {
            return Err(RecordError::MissingKey {
                key: "velocity_valid",
            })
        }
        Some(v) => v.as_bool().ok_or(RecordError::NotABool {
            key: "velocity_valid",
        })?,
    };
    let velocity = [number("vx")?, number("vy")?, number("vz")?];
    Ok(Report::Velocity {
        time_of_validity_us,
        velocity: valid.then_some(velocity),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Report, RecordError> {
        let value: Value = serde_json::from_str(text).unwrap();
        report(value.as_object().unwrap())
    }

    /// The documented example report (json_v3), shortened.
    #[test]
    fn reads_the_documented_velocity_report() {
        let text = r#"{"time": 106.39, "vx": -3.71e-05, "vy": 5.70e-05, "vz": 2.50e-05,
            "fom": 0.00016, "altitude": 0.49, "transducers": [], "velocity_valid": true,
            "status": 0, "format": "json_v3", "type": "velocity",
            "time_of_validity": 1638191471563017, "time_of_transmission": 1638191471752336}"#;
        assert_eq!(
            parse(text).unwrap(),
            Report::Velocity {
                time_of_validity_us: 1_638_191_471_563_017,
                velocity: Some([-3.71e-05, 5.70e-05, 2.50e-05]),
            }
        );
        let invalid = text.replace("\"velocity_valid\": true", "\"velocity_valid\": false");
        assert!(matches!(
            parse(&invalid).unwrap(),
            Report::Velocity { velocity: None, .. }
        ));
        assert_eq!(
            parse(r#"{"type": "position_local", "x": 1}"#).unwrap(),
            Report::Other
        );
        assert!(matches!(
            parse(r#"{"type": "velocity", "vx": 0, "vy": 0, "vz": 0, "velocity_valid": true}"#),
            Err(RecordError::MissingKey { .. })
        ));
    }
}
