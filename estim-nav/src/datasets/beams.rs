//! DVL beam files read by `estim dvl solve`: a CSV with a header row naming the beam
//! columns by any common name (`beam1`, `b1`, `beam_1`, `Beam 1 [m/s]`,
//! `beam velocity 1`; any case, any order, unit m/s, cm/s or mm/s in the header), and
//! optionally a time column (`time`, `t`, `timestamp`, unit s or ms), which is kept.
//! Other columns are ignored; an empty or `nan` cell is a missing beam. As for the GT
//! and DVL files, the file must end with a newline (else it is reported truncated).

use std::collections::BTreeMap;
use std::path::Path;

use super::akit::{csv_error, truncated_line, MAX_ABS_SPEED_MPS};
use super::columns::{resolve, same, Kind, Quantity, Resolved};
use super::input::{check_text, read_file, Lines};
use super::{DatasetError, Result};

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
/// [`DatasetError::Io`] when the file cannot be read, then those of [`parse_beams`].
pub fn load_beams(path: &Path) -> Result<Vec<BeamRow>> {
    parse_beams(&read_file(path)?, path)
}

/// Parse the beams of every data row of a beam file; `path` names it in errors.
///
/// # Errors
/// As [`BeamFile::parse`].
pub fn parse_beams(bytes: &[u8], path: &Path) -> Result<Vec<BeamRow>> {
    BeamFile::parse(bytes, path).map(|f| f.rows)
}

impl BeamFile {
    /// Read and parse a beam file.
    ///
    /// # Errors
    /// [`DatasetError::Io`], then those of [`BeamFile::parse`].
    pub fn load(path: &Path) -> Result<Self> {
        Self::parse(&read_file(path)?, path)
    }

    /// Parse a beam file; `path` names it in errors. Blank lines are skipped; every
    /// error names the file and the 1-based line.
    ///
    /// # Errors
    /// [`DatasetError::NotText`] (UTF-16, CR-only line ends, binary data),
    /// [`DatasetError::Header`] (empty file), [`DatasetError::Truncated`],
    /// [`DatasetError::MissingColumn`], [`DatasetError::AmbiguousColumn`],
    /// [`DatasetError::Unit`], [`DatasetError::Csv`], [`DatasetError::FieldCount`]
    /// (a row too short to hold a needed column), [`DatasetError::Parse`],
    /// [`DatasetError::NonFinite`], [`DatasetError::OutOfRange`],
    /// [`DatasetError::TimeNotIncreasing`].
    pub fn parse(bytes: &[u8], path: &Path) -> Result<Self> {
        check_text(bytes, path, true)?;
        if let Some(line) = truncated_line(bytes).filter(|_| !bytes.is_empty()) {
            return Err(DatasetError::Truncated {
                path: path.to_path_buf(),
                line,
            });
        }
        let mut reader = csv::ReaderBuilder::new()
            .has_headers(false)
            .flexible(true)
            .from_reader(bytes);
        let mut records = reader.records();
        let header = match records.next() {
            Some(r) => r.map_err(|e| csv_error(bytes, path, &e))?,
            None => {
                return Err(DatasetError::Header {
                    path: path.to_path_buf(),
                    expected: "a header row naming beam1..beam4 (the file is empty)".into(),
                    found: String::new(),
                })
            }
        };
        let header: Vec<String> = header.iter().map(str::to_string).collect();
        let none = BTreeMap::new();
        let beams = resolve(path, &header, BEAMS, &none, "beams")?;
        let time: Option<Resolved> = match resolve(path, &header, TIME, &none, "beams") {
            Ok(mut t) => t.pop(),
            Err(DatasetError::MissingColumn { .. }) => None,
            Err(e) => return Err(e),
        };
        let mut times = time.as_ref().map(|_| Vec::new());
        let mut rows = Vec::new();
        let mut lines = Lines::new(bytes);
        for record in records {
            let record = record.map_err(|e| csv_error(bytes, path, &e))?;
            let line = record.position().map_or(0, |p| lines.line_at(p.byte()));
            if record.iter().all(|c| c.trim().is_empty()) && record.len() <= 1 {
                continue; // blank line
            }
            let cell = |column: &Resolved| {
                record
                    .get(column.index)
                    .map(str::trim)
                    .ok_or_else(|| DatasetError::FieldCount {
                        path: path.to_path_buf(),
                        line,
                        expected: column.index + 1,
                        found: record.len(),
                    })
            };
            let number = |column: &Resolved, text: &str, max_abs: f64| -> Result<f64> {
                let read: f64 = text.parse().map_err(|_| DatasetError::Parse {
                    path: path.to_path_buf(),
                    line,
                    column: column.header.clone(),
                    value: text.chars().take(40).collect(),
                })?;
                if !read.is_finite() {
                    return Err(DatasetError::NonFinite {
                        path: path.to_path_buf(),
                        line,
                        column: column.header.clone(),
                    });
                }
                let value = read * column.factor;
                if value.abs() >= max_abs {
                    return Err(DatasetError::OutOfRange {
                        path: path.to_path_buf(),
                        line,
                        column: column.header.clone(),
                        value,
                        limit: max_abs,
                        unit: if max_abs == MAX_ABS_SPEED_MPS {
                            "m/s"
                        } else {
                            "s"
                        },
                    });
                }
                Ok(value)
            };
            let mut row = [None; 4];
            for (b, column) in beams.iter().enumerate() {
                let text = cell(column)?;
                if text.is_empty() || text.eq_ignore_ascii_case("nan") {
                    continue;
                }
                row[b] = Some(number(column, text, MAX_ABS_SPEED_MPS)?);
            }
            if let (Some(column), Some(times)) = (&time, times.as_mut()) {
                let t = number(column, cell(column)?, TIME[0].max_abs)?;
                if let Some(&previous) = times.last() {
                    if t <= previous {
                        return Err(DatasetError::TimeNotIncreasing {
                            path: path.to_path_buf(),
                            line,
                            time: t,
                            previous,
                        });
                    }
                }
                times.push(t);
            }
            rows.push(row);
        }
        Ok(Self { times, rows })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
        assert!(e.to_string().contains("b.csv:1:"), "{e}");
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
