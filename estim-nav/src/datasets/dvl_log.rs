//! DVL logs for the navigator: body-frame velocity with an optional validity column,
//! or four beam velocities, each row at its time stamp.
//!
//! Velocity: time and `x`, `y`, `z` (the names of the A-KIT DVL loader: `DVL X`,
//! `vx`, `vel x`, ...; m/s, cm/s or mm/s). A row has no bottom lock, and is kept as
//! [`DvlInput::NoLock`] (skipped and counted by the navigator, never used), when a
//! velocity cell is empty, `nan` or RDI's bad-velocity marker -32.768 m/s (-32768
//! mm/s), when a validity column (`valid`, `validity`, `bottom lock`, `bt valid`,
//! `lock`) holds 0 / false / no / invalid / an empty cell, or when a figure-of-merit
//! column (`fom`, `figure of merit`) is empty, `nan` or the marker.
//!
//! Beams: time and `beam1`..`beam4` (`b1`, `beam_1`, `Beam 1 [m/s]`, `beam velocity
//! 1`); an empty, `nan` or marker cell is a missing beam.

use std::path::Path;

use nalgebra::Vector3;

use super::akit::{DVL_QUANTITIES, MAX_ABS_SPEED_MPS};
use super::columns::{same, Kind, Quantity, Resolved};
use super::input::open_text;
use super::table::{for_each_row, MapSection, Row, TIME};
use super::{DatasetError, Result};
use crate::navigator::{DvlInput, DvlRecord};

/// RDI's bad-velocity marker, -32768 mm/s, in m/s.
pub const RDI_BAD_VELOCITY_MPS: f64 = -32.768;

const VALIDITY: Quantity = Quantity {
    key: "validity",
    kind: Kind::Flag,
    aliases: &[
        same("valid"),
        same("validity"),
        same("bottomlock"),
        same("btvalid"),
        same("lock"),
        same("btlock"),
    ],
    max_abs: f64::INFINITY,
};

const FOM: Quantity = Quantity {
    key: "fom",
    kind: Kind::Speed,
    aliases: &[same("fom"), same("figureofmerit")],
    max_abs: MAX_ABS_SPEED_MPS,
};

/// The validity and figure-of-merit columns of a DVL velocity log (keys of
/// `[columns.dvl]` beside time, x, y, z).
pub(crate) const FLAG_QUANTITIES: &[Quantity] = &[VALIDITY, FOM];

/// Every quantity of a DVL beams log (the keys of `[columns.beams]`).
pub(crate) fn beam_quantities() -> Vec<Quantity> {
    std::iter::once(TIME).chain(BEAMS).collect()
}

const fn beam(key: &'static str, aliases: &'static [super::columns::Alias]) -> Quantity {
    Quantity {
        key,
        kind: Kind::Speed,
        aliases,
        max_abs: MAX_ABS_SPEED_MPS,
    }
}

const BEAMS: [Quantity; 4] = [
    beam(
        "beam1",
        &[
            same("beam1"),
            same("b1"),
            same("beamvelocity1"),
            same("beamvel1"),
            same("btvelocity1"),
        ],
    ),
    beam(
        "beam2",
        &[
            same("beam2"),
            same("b2"),
            same("beamvelocity2"),
            same("beamvel2"),
            same("btvelocity2"),
        ],
    ),
    beam(
        "beam3",
        &[
            same("beam3"),
            same("b3"),
            same("beamvelocity3"),
            same("beamvel3"),
            same("btvelocity3"),
        ],
    ),
    beam(
        "beam4",
        &[
            same("beam4"),
            same("b4"),
            same("beamvelocity4"),
            same("beamvel4"),
            same("btvelocity4"),
        ],
    ),
];

/// A DVL log read: rows with times relative to `epoch_s`.
#[derive(Debug, Clone, PartialEq)]
pub struct DvlLog {
    /// The epoch \[s\] the times are relative to.
    pub epoch_s: f64,
    /// Every row, lost-lock rows included (as [`DvlInput::NoLock`]).
    pub records: Vec<DvlRecord>,
    /// The 1-based line of each record.
    pub lines: Vec<u64>,
}

impl DvlLog {
    /// Rows without bottom lock.
    pub fn no_lock(&self) -> usize {
        self.records
            .iter()
            .filter(|r| r.input == DvlInput::NoLock)
            .count()
    }

    /// Read a DVL velocity log (see the module docs).
    ///
    /// # Errors
    /// [`DatasetError::Io`], then those of [`DvlLog::parse_velocity`].
    pub fn load_velocity(path: &Path, epoch_s: Option<f64>) -> Result<Self> {
        Self::parse_velocity_with(
            open_text(path)?,
            path,
            epoch_s,
            &super::ColumnMap::default(),
        )
    }

    /// Read a DVL beams log.
    ///
    /// # Errors
    /// [`DatasetError::Io`], then those of [`DvlLog::parse_beams`].
    pub fn load_beams(path: &Path, epoch_s: Option<f64>) -> Result<Self> {
        Self::parse_beams_with(
            open_text(path)?,
            path,
            epoch_s,
            &super::ColumnMap::default(),
        )
    }

    /// [`DvlLog::load_velocity`] with a column map (its `dvl` section).
    ///
    /// # Errors
    /// As [`DvlLog::parse_velocity_with`].
    pub fn load_velocity_with(
        path: &Path,
        epoch_s: Option<f64>,
        map: &super::ColumnMap,
    ) -> Result<Self> {
        Self::parse_velocity_with(open_text(path)?, path, epoch_s, map)
    }

    /// [`DvlLog::load_beams`] with a column map (its `beams` section).
    ///
    /// # Errors
    /// As [`DvlLog::parse_beams_with`].
    pub fn load_beams_with(
        path: &Path,
        epoch_s: Option<f64>,
        map: &super::ColumnMap,
    ) -> Result<Self> {
        Self::parse_beams_with(open_text(path)?, path, epoch_s, map)
    }

    /// Parse a DVL velocity log; errors name the file and line. A lost lock is a
    /// row kept as [`DvlInput::NoLock`], not an error.
    ///
    /// # Errors
    /// Missing or ambiguous columns, units, text that is not a number (or a validity
    /// word), infinite or out-of-range values, times that do not increase, no rows.
    pub fn parse_velocity(bytes: &[u8], path: &Path, epoch_s: Option<f64>) -> Result<Self> {
        Self::parse_velocity_with(bytes, path, epoch_s, &super::ColumnMap::default())
    }

    /// [`DvlLog::parse_velocity`] with a column map (its `dvl` section).
    ///
    /// # Errors
    /// As [`DvlLog::parse_velocity`], and [`DatasetError::ColumnMap`] naming a bad key.
    pub fn parse_velocity_with(
        input: impl std::io::Read,
        path: &Path,
        epoch_s: Option<f64>,
        map: &super::ColumnMap,
    ) -> Result<Self> {
        let quantities: Vec<Quantity> = DVL_QUANTITIES
            .iter()
            .chain(FLAG_QUANTITIES)
            .copied()
            .collect();
        let section = MapSection {
            map: &map.dvl,
            section: "columns.dvl",
            quantities: &quantities,
        };
        let mut log = Self::empty(epoch_s);
        for_each_row(
            input,
            path,
            section,
            |h| {
                let mut cols = h.require(DVL_QUANTITIES)?;
                let validity = h.optional(VALIDITY)?;
                let fom = h.optional(FOM)?;
                let time = cols.remove(0);
                Ok((time, cols, validity, fom))
            },
            |(time, cols, validity, fom), row| {
                let t = log.time(row, time)?;
                let mut lock = true;
                if let Some(v) = validity {
                    lock &= flag(row, v)?;
                }
                if let Some(f) = fom {
                    lock &= velocity_cell(row, f, &FOM)?.is_some();
                }
                let mut v = [0.0; 3];
                for (k, (c, q)) in cols.iter().zip(&DVL_QUANTITIES[1..]).enumerate() {
                    match velocity_cell(row, c, q)? {
                        Some(x) => v[k] = x,
                        None => lock = false,
                    }
                }
                let input = if lock {
                    DvlInput::Velocity(Vector3::from(v))
                } else {
                    DvlInput::NoLock
                };
                log.push(row, t, input)
            },
        )?;
        log.finish(path)
    }

    /// Parse a DVL beams log (4 beams; a missing beam is empty, `nan` or the marker).
    ///
    /// # Errors
    /// As [`DvlLog::parse_velocity`].
    pub fn parse_beams(bytes: &[u8], path: &Path, epoch_s: Option<f64>) -> Result<Self> {
        Self::parse_beams_with(bytes, path, epoch_s, &super::ColumnMap::default())
    }

    /// [`DvlLog::parse_beams`] with a column map (its `beams` section).
    ///
    /// # Errors
    /// As [`DvlLog::parse_beams`], and [`DatasetError::ColumnMap`] naming a bad key.
    pub fn parse_beams_with(
        input: impl std::io::Read,
        path: &Path,
        epoch_s: Option<f64>,
        map: &super::ColumnMap,
    ) -> Result<Self> {
        let quantities = beam_quantities();
        let section = MapSection {
            map: &map.beams,
            section: "columns.beams",
            quantities: &quantities,
        };
        let mut log = Self::empty(epoch_s);
        for_each_row(
            input,
            path,
            section,
            |h| Ok((h.require(&[TIME])?.remove(0), h.require(&BEAMS)?)),
            |(time, cols), row| {
                let t = log.time(row, time)?;
                let mut beams = [None; 4];
                for (k, c) in cols.iter().enumerate() {
                    beams[k] = velocity_cell(row, c, &BEAMS[k])?;
                }
                let input = if beams.iter().all(Option::is_none) {
                    DvlInput::NoLock
                } else {
                    DvlInput::Beams(beams)
                };
                log.push(row, t, input)
            },
        )?;
        log.finish(path)
    }

    fn empty(epoch_s: Option<f64>) -> Self {
        Self {
            epoch_s: epoch_s.unwrap_or(f64::NAN),
            records: Vec::new(),
            lines: Vec::new(),
        }
    }

    fn time(&mut self, row: &Row<'_>, column: &Resolved) -> Result<f64> {
        if self.epoch_s.is_nan() {
            self.epoch_s = row.whole_seconds(column)?;
        }
        row.time(column, self.epoch_s)
    }

    fn push(&mut self, row: &Row<'_>, time: f64, input: DvlInput) -> Result<()> {
        if let Some(last) = self.records.last() {
            if time <= last.time {
                return Err(row.not_increasing(time, last.time));
            }
        }
        self.records.push(DvlRecord { time, input });
        self.lines.push(row.line);
        Ok(())
    }

    fn finish(mut self, path: &Path) -> Result<Self> {
        if self.records.is_empty() {
            return Err(DatasetError::TooFewRows {
                path: path.to_path_buf(),
                found: 0,
                min: 1,
            });
        }
        if self.epoch_s.is_nan() {
            self.epoch_s = 0.0;
        }
        // Rows doubled a few ms apart would each be used as an update: refused, as the
        // study's DVL reader refuses them.
        super::akit::check_intervals(
            path,
            self.lines
                .iter()
                .copied()
                .zip(self.records.iter().map(|r| r.time)),
        )?;
        Ok(self)
    }
}

/// A velocity cell: `None` for empty, `nan` or the RDI marker.
fn velocity_cell(row: &Row<'_>, column: &Resolved, quantity: &Quantity) -> Result<Option<f64>> {
    match row.maybe_number(column, quantity)? {
        Some(v) if (v - RDI_BAD_VELOCITY_MPS).abs() < 1e-9 => Ok(None),
        other => Ok(other),
    }
}

/// A validity cell: true for 1 / true / yes / valid / ok / locked, false for 0 /
/// false / no / invalid / bad / an empty cell.
fn flag(row: &Row<'_>, column: &Resolved) -> Result<bool> {
    let text = row.text(column).to_ascii_lowercase();
    match text.as_str() {
        "1" | "true" | "t" | "yes" | "y" | "valid" | "ok" | "locked" | "lock" => Ok(true),
        "" | "0" | "false" | "f" | "no" | "n" | "invalid" | "bad" | "nan" | "unlocked" => Ok(false),
        _ => Err(DatasetError::Parse {
            path: row.path.to_path_buf(),
            line: row.line,
            column: column.header.clone(),
            value: text.chars().take(40).collect(),
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lost_lock_rows_are_kept_as_no_lock() {
        let p = Path::new("dvl.csv");
        let log = DvlLog::parse_velocity(
            b"time,vx,vy,vz\n0,1,0,0\n1,nan,0,0\n2,,0,0\n3,-32.768,0,0\n4,1,0,0\n",
            p,
            None,
        )
        .unwrap();
        assert_eq!(log.records.len(), 5);
        assert_eq!(log.no_lock(), 3);
        let mm = DvlLog::parse_velocity(b"time,vx [mm/s],vy,vz\n0,-32768,0,0\n", p, None).unwrap();
        assert_eq!(mm.no_lock(), 1);
        let flagged = DvlLog::parse_velocity(
            b"time,vx,vy,vz,bottom_lock\n0,1,0,0,1\n1,1,0,0,0\n2,1,0,0,true\n",
            p,
            None,
        )
        .unwrap();
        assert_eq!(flagged.no_lock(), 1);
        let e =
            DvlLog::parse_velocity(b"time,vx,vy,vz,valid\n0,1,0,0,maybe\n", p, None).unwrap_err();
        assert!(e.to_string().starts_with("dvl.csv:2:"), "{e}");
        let e =
            DvlLog::parse_velocity(b"time,vx,vy,vz\n0,1,0,0\n1,abc,0,0\n", p, None).unwrap_err();
        assert!(e.to_string().starts_with("dvl.csv:3:"), "{e}");
    }

    #[test]
    fn beams_with_missing_cells_and_unix_times() {
        let p = Path::new("beams.csv");
        let log = DvlLog::parse_beams(
            b"time,beam1,beam2,beam3,beam4\n1700000000.5,1,2,,4\n1700000001.5,nan,,-32.768,\n",
            p,
            None,
        )
        .unwrap();
        assert_eq!(log.epoch_s, 1.7e9);
        assert_eq!(log.records[0].time, 0.5);
        assert_eq!(
            log.records[0].input,
            DvlInput::Beams([Some(1.0), Some(2.0), None, Some(4.0)])
        );
        assert_eq!(log.records[1].input, DvlInput::NoLock);
    }
}
