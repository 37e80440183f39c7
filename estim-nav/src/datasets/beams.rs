//! DVL beam files read by `estim dvl solve`: a CSV with a header row naming the beam
//! columns by any common name (`beam1`, `b1`, `beam_1`, `Beam 1 [m/s]`,
//! `beam velocity 1`; any case, any order, unit m/s, cm/s or mm/s in the header), and
//! optionally a time column (`time`, `t`, `timestamp`, unit s or ms), which is kept.
//! Other columns are ignored; an empty or `nan` cell is a missing beam. As for the GT
//! and DVL files, the file must end with a newline (else it is reported truncated).

use std::collections::BTreeMap;
use std::path::Path;

use super::akit::MAX_ABS_SPEED_MPS;
use super::columns::{same, Kind, Quantity};
use super::input::open_text;
use super::table::{for_each_row, MapSection};
use super::Result;

/// Beam velocities of one row \[m/s\]; `None` = missing beam.
pub type BeamRow = [Option<f64>; 4];

/// A beam file: the beams of every row and, if the file has a time column, the times.
#[derive(Debug, Clone, PartialEq)]
pub struct BeamFile {
    /// Time of every row \[s\], when the file has a time column.
    pub times: Option<Vec<f64>>,
    /// Beams of every row \[m/s\].
    pub rows: Vec<BeamRow>,
}

const fn beam(key: &'static str, aliases: &'static [super::columns::Alias]) -> Quantity {
    Quantity {
        key,
        kind: Kind::Speed,
        aliases,
        max_abs: MAX_ABS_SPEED_MPS,
    }
}

const BEAMS: &[Quantity; 4] = &[
    beam(
        "beam1",
        &[
            same("beam1"),
            same("b1"),
            same("beamvelocity1"),
            same("beamvel1"),
        ],
    ),
    beam(
        "beam2",
        &[
            same("beam2"),
            same("b2"),
            same("beamvelocity2"),
            same("beamvel2"),
        ],
    ),
    beam(
        "beam3",
        &[
            same("beam3"),
            same("b3"),
            same("beamvelocity3"),
            same("beamvel3"),
        ],
    ),
    beam(
        "beam4",
        &[
            same("beam4"),
            same("b4"),
            same("beamvelocity4"),
            same("beamvel4"),
        ],
    ),
];

const TIME: &[Quantity; 1] = &[Quantity {
    key: "time",
    kind: Kind::Time,
    aliases: &[same("time"), same("t"), same("timestamp")],
    max_abs: super::akit::MAX_ABS_TIME_S,
}];

/// Read and parse a beam file (see [`parse_beams`]).
///
/// # Errors
/// [`DatasetError::Io`](super::DatasetError::Io) when the file cannot be read, then those of [`parse_beams`].
pub fn load_beams(path: &Path) -> Result<Vec<BeamRow>> {
    BeamFile::load(path).map(|f| f.rows)
}

/// Parse the beams of every data row of a beam file; `path` names it in errors.
///
/// # Errors
/// As [`BeamFile::parse`].
pub fn parse_beams(bytes: &[u8], path: &Path) -> Result<Vec<BeamRow>> {
    BeamFile::parse(bytes, path).map(|f| f.rows)
}

impl BeamFile {
    /// Read and parse a beam file, streamed record by record (memory holds the rows,
    /// not the file).
    ///
    /// # Errors
    /// [`DatasetError::Io`](super::DatasetError::Io), then those of [`BeamFile::read`].
    pub fn load(path: &Path) -> Result<Self> {
        Self::read(open_text(path)?, path)
    }

    /// Parse a beam file held in memory (see [`BeamFile::read`]).
    ///
    /// # Errors
    /// As [`BeamFile::read`].
    pub fn parse(bytes: &[u8], path: &Path) -> Result<Self> {
        Self::read(bytes, path)
    }

    /// Read a beam file from a stream (a file, stdin), record by record, at most
    /// [`super::MAX_INPUT_BYTES`]; `path` names it in errors. Blank lines are skipped;
    /// every row has the header's number of cells; every error names the file and the
    /// 1-based line.
    ///
    /// # Errors
    /// [`DatasetError::NotText`](super::DatasetError::NotText) (UTF-16, CR-only line ends, binary data),
    /// [`DatasetError::TooFewRows`](super::DatasetError::TooFewRows) (an empty file), [`DatasetError::Truncated`](super::DatasetError::Truncated),
    /// [`DatasetError::MissingColumn`](super::DatasetError::MissingColumn), [`DatasetError::AmbiguousColumn`](super::DatasetError::AmbiguousColumn),
    /// [`DatasetError::Unit`](super::DatasetError::Unit), [`DatasetError::Csv`](super::DatasetError::Csv), [`DatasetError::FieldCount`](super::DatasetError::FieldCount),
    /// [`DatasetError::Parse`](super::DatasetError::Parse), [`DatasetError::NonFinite`](super::DatasetError::NonFinite),
    /// [`DatasetError::OutOfRange`](super::DatasetError::OutOfRange), [`DatasetError::TimeNotIncreasing`](super::DatasetError::TimeNotIncreasing),
    /// [`DatasetError::TooLarge`](super::DatasetError::TooLarge).
    pub fn read(input: impl std::io::Read, path: &Path) -> Result<Self> {
        let none = BTreeMap::new();
        let section = MapSection {
            map: &none,
            section: "beams",
            quantities: &[],
        };
        let has_time = std::cell::Cell::new(false);
        let mut times = Vec::new();
        let mut rows = Vec::new();
        for_each_row(
            input,
            path,
            section,
            |h| {
                let beams = h.require(BEAMS)?;
                let time = h.optional(TIME[0])?;
                has_time.set(time.is_some());
                Ok((beams, time))
            },
            |(beams, time), row| {
                let mut beam_row = [None; 4];
                for ((slot, column), quantity) in beam_row.iter_mut().zip(beams).zip(BEAMS) {
                    *slot = row.maybe_number(column, quantity)?;
                }
                if let Some(column) = time {
                    let t = row.number(column, &TIME[0])?;
                    if let Some(&previous) = times.last() {
                        if t <= previous {
                            return Err(row.not_increasing(t, previous));
                        }
                    }
                    times.push(t);
                }
                rows.push(beam_row);
                Ok(())
            },
        )?;
        Ok(Self {
            times: has_time.get().then_some(times),
            rows,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::datasets::DatasetError;

    #[test]
    fn columns_by_name_missing_cells_and_line_numbers() {
        let p = Path::new("b.csv");
        let rows =
            parse_beams(b"t, Beam 2,beam1,BEAM3,beam4\n0,1,2,,4\n\n1,1,2,nan,4\n", p).unwrap();
        assert_eq!(
            rows,
            vec![
                [Some(2.0), Some(1.0), None, Some(4.0)],
                [Some(2.0), Some(1.0), None, Some(4.0)]
            ]
        );
        let e = parse_beams(b"beam1,beam2,beam3,beam4\n1,2,3,4\n\n1,x,3,4\n", p).unwrap_err();
        assert!(e.to_string().starts_with("b.csv:4:"), "{e}");
        let e = parse_beams(b"beam1,beam2,beam4\n", p).unwrap_err();
        assert!(
            e.to_string().contains(":1:") && e.to_string().contains("beam3"),
            "{e}"
        );
        let e = parse_beams(b"", p).unwrap_err();
        assert!(e.to_string().starts_with("b.csv: 0 data rows"), "{e}");
        let e = parse_beams(b"beam1,beam2,beam3,beam4\n1,2,3,4", p).unwrap_err();
        assert!(e.to_string().starts_with("b.csv:2: truncated"), "{e}");
    }

    #[test]
    fn other_beam_names_units_and_the_time_column() {
        let p = Path::new("b.csv");
        let f = BeamFile::parse(
            b"\xef\xbb\xbfTime [ms],b4,Beam 3 [mm/s],beam_2,Beam Velocity 1\r\n1000,4,3000,2,1\r\n2500,,nan,2,1\r\n\r\n",
            p,
        )
        .unwrap();
        assert_eq!(f.times, Some(vec![1.0, 2.5]));
        assert_eq!(
            f.rows,
            vec![
                [Some(1.0), Some(2.0), Some(3.0), Some(4.0)],
                [Some(1.0), Some(2.0), None, None]
            ]
        );
        let e = BeamFile::parse(b"t,b1,b2,b3,b4\n1,1,2,3,4\n1,1,2,3,4\n", p).unwrap_err();
        assert!(e.to_string().starts_with("b.csv:3:"), "{e}");
        let e = BeamFile::parse(b"b1,b2,b3,b4,beam1\n", p).unwrap_err();
        assert!(matches!(e, DatasetError::AmbiguousColumn { .. }), "{e}");
        let none = BeamFile::parse(b"b1,b2,b3,b4\n1,2,3,4\n", p).unwrap();
        assert_eq!(none.times, None);
    }
}
