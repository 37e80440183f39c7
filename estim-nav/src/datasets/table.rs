//! The CSV layer shared by the survey readers (IMU, DVL log, depth, fixes): a header
//! resolved by name and unit, rows streamed with their 1-based line numbers, numbers
//! checked where they stand, and times read relative to an epoch without losing the
//! digits of a Unix time.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::akit::MAX_ABS_TIME_S;
use super::columns::{check_section, maps, resolve_some, same, Kind, Quantity, Resolved};
use super::input::{open_text, TextStream, MAX_INPUT_BYTES};
use super::{DatasetError, Result};

/// The time column of every survey file.
pub(crate) const TIME: Quantity = Quantity {
    key: "time",
    kind: Kind::Time,
    aliases: &[
        same("time"),
        same("t"),
        same("timestamp"),
        same("timeunix"),
        same("unixtime"),
    ],
    max_abs: MAX_ABS_TIME_S,
};

/// One section of a column map as a reader applies it (`[columns.imu]` of a vehicle
/// file), with every quantity its file may have (to check the section's keys); an
/// empty map finds every column by name.
#[derive(Clone, Copy)]
pub(crate) struct MapSection<'a> {
    pub map: &'a BTreeMap<String, String>,
    pub section: &'a str,
    pub quantities: &'a [Quantity],
}

/// The header of a table and the resolution of its columns.
pub(crate) struct Header<'a> {
    pub path: &'a Path,
    pub cells: Vec<String>,
    pub map: MapSection<'a>,
}

impl Header<'_> {
    /// Resolve quantities that must all be present.
    pub fn require(&self, quantities: &[Quantity]) -> Result<Vec<Resolved>> {
        resolve_some(
            self.path,
            &self.cells,
            quantities,
            self.map.map,
            self.map.section,
        )
    }

    /// Resolve a quantity that may be absent.
    pub fn optional(&self, quantity: Quantity) -> Result<Option<Resolved>> {
        match resolve_some(
            self.path,
            &self.cells,
            &[quantity],
            self.map.map,
            self.map.section,
        ) {
            Ok(mut r) => Ok(r.pop()),
            Err(DatasetError::MissingColumn { .. }) if !maps(self.map.map, &quantity) => Ok(None),
            Err(e) => Err(e),
        }
    }

    /// Resolve all of `quantities`, or none of them (`Ok(None)`); some only is an
    /// error naming the first missing one.
    pub fn all_or_none(&self, quantities: &[Quantity]) -> Result<Option<Vec<Resolved>>> {
        let mut found = Vec::new();
        for q in quantities {
            found.push(self.optional(*q)?);
        }
        if found.iter().all(Option::is_none) {
            return Ok(None);
        }
        if found.iter().all(Option::is_some) {
            return Ok(Some(found.into_iter().flatten().collect()));
        }
        // Name the missing one.
        self.require(quantities).map(Some)
    }
}

/// One data row: its line and cells.
pub(crate) struct Row<'a> {
    pub path: &'a Path,
    pub line: u64,
    pub record: &'a csv::StringRecord,
}

impl Row<'_> {
    /// The trimmed text of a column.
    pub fn text(&self, column: &Resolved) -> &str {
        self.record.get(column.index).unwrap_or("").trim()
    }

    fn pb(&self) -> PathBuf {
        self.path.to_path_buf()
    }

    /// A finite number within +-`max_abs` (SI, after the column's unit factor).
    pub fn number(&self, column: &Resolved, quantity: &Quantity) -> Result<f64> {
        let read = self.parse(column)?;
        if !read.is_finite() {
            return Err(DatasetError::NonFinite {
                path: self.pb(),
                line: self.line,
                column: column.header.clone(),
            });
        }
        self.in_range(column, quantity, read * column.factor)
    }

    /// A number or "no value" (`Ok(None)` for an empty cell or NaN).
    pub fn maybe_number(&self, column: &Resolved, quantity: &Quantity) -> Result<Option<f64>> {
        let text = self.text(column);
        if text.is_empty() || text.eq_ignore_ascii_case("nan") {
            return Ok(None);
        }
        self.number(column, quantity).map(Some)
    }

    fn parse(&self, column: &Resolved) -> Result<f64> {
        let text = self.text(column);
        text.parse().map_err(|_| DatasetError::Parse {
            path: self.pb(),
            line: self.line,
            column: column.header.clone(),
            value: text.chars().take(40).collect(),
        })
    }

    fn in_range(&self, column: &Resolved, quantity: &Quantity, value: f64) -> Result<f64> {
        if value.abs() >= quantity.max_abs {
            return Err(DatasetError::OutOfRange {
                path: self.pb(),
                line: self.line,
                column: column.header.clone(),
                value,
                limit: quantity.max_abs,
                unit: quantity.kind.si_unit(),
            });
        }
        Ok(value)
    }

    /// The time of this row in seconds relative to `epoch_s` (an integer number of
    /// seconds). A plain decimal in seconds (`1700000003.485`) has its integer part
    /// subtracted before it becomes an f64, so a Unix time keeps every digit it was
    /// written with: the result is the f64 of the text `3.485`, the same as for a
    /// file written relative to the epoch.
    pub fn time(&self, column: &Resolved, epoch_s: f64) -> Result<f64> {
        let text = self.text(column);
        if let Some(t) = relative_decimal(text, column.factor, epoch_s) {
            return Ok(t);
        }
        let absolute = self.number(column, &TIME)?;
        Ok(absolute - epoch_s)
    }

    /// The integer seconds of this row's time (the epoch of a file that has none).
    pub fn whole_seconds(&self, column: &Resolved) -> Result<f64> {
        Ok((self.number(column, &TIME)?).floor())
    }

    /// A time-ordering error at this row.
    pub fn not_increasing(&self, time: f64, previous: f64) -> DatasetError {
        DatasetError::TimeNotIncreasing {
            path: self.pb(),
            line: self.line,
            time,
            previous,
        }
    }
}

/// `text - epoch` for a plain non-negative decimal in seconds whose integer part is
/// at least the epoch, computed on the digits; `None` otherwise.
fn relative_decimal(text: &str, factor: f64, epoch_s: f64) -> Option<f64> {
    if factor != 1.0 || epoch_s.fract() != 0.0 || epoch_s.abs() > 1e15 {
        return None;
    }
    let (whole, fraction) = text.split_once('.').unwrap_or((text, ""));
    let digits = |s: &str| s.bytes().all(|b| b.is_ascii_digit());
    if whole.is_empty() || whole.len() > 15 || !digits(whole) || !digits(fraction) {
        return None;
    }
    let whole: i64 = whole.parse().ok()?;
    let relative = whole.checked_sub(epoch_s as i64)?;
    if relative < 0 {
        return None;
    }
    let value: f64 = format!("{relative}.{fraction}0").parse().ok()?;
    (value.abs() < MAX_ABS_TIME_S).then_some(value)
}

/// What the CSV reader said, at the line where it stopped.
fn csv_error(path: &Path, e: &csv::Error) -> DatasetError {
    DatasetError::Csv {
        path: path.to_path_buf(),
        line: e.position().map_or(1, csv::Position::line),
        message: e.to_string(),
    }
}

/// Stream a table record by record from `input` (at most [`MAX_INPUT_BYTES`], text
/// checked as it is read: [`TextStream`]): header (resolved by `columns`), then every
/// non-blank row with as many fields as the header, handed to `row`. Memory is bounded
/// by what `row` keeps, not by the file. A file that fits in the first block is
/// checked whole before any row (blank, cut last line); a longer one is refused for a
/// cut last line as soon as its end has been read, before the rows read with it.
pub(crate) fn for_each_row<C>(
    input: impl std::io::Read,
    path: &Path,
    map: MapSection<'_>,
    columns: impl FnOnce(&Header<'_>) -> Result<C>,
    mut row: impl FnMut(&C, &Row<'_>) -> Result<()>,
) -> Result<()> {
    check_section(path, map.map, map.quantities, map.section)?;
    let stream = TextStream::new(input, path, MAX_INPUT_BYTES)?;
    let too_few = || DatasetError::TooFewRows {
        path: path.to_path_buf(),
        found: 0,
        min: 1,
    };
    let cut = |stream: &TextStream<_>| {
        stream.truncated_line().map(|line| DatasetError::Truncated {
            path: path.to_path_buf(),
            line,
        })
    };
    if stream.blank() {
        return Err(too_few());
    }
    if let Some(e) = cut(&stream) {
        return Err(e);
    }
    // Records end at LF only (a CR before it stays in the last cell, which is read
    // trimmed), so that the reader's line count after a record is the line of its end.
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .terminator(csv::Terminator::Any(b'\n'))
        .from_reader(stream);
    let mut record = csv::StringRecord::new();
    // A record and where it ends; its line is the line before its terminator, less
    // the line ends inside quoted cells (blank lines before it are not its own).
    let next = |reader: &mut csv::Reader<TextStream<_>>,
                record: &mut csv::StringRecord|
     -> Result<Option<u64>> {
        let got = match reader.read_record(record) {
            Ok(got) => got,
            Err(e) => {
                return Err(reader
                    .get_mut()
                    .take_failure()
                    .unwrap_or_else(|| csv_error(path, &e)))
            }
        };
        if reader.get_ref().blank() {
            return Err(too_few());
        }
        if let Some(e) = cut(reader.get_ref()) {
            return Err(e);
        }
        if !got {
            return Ok(None);
        }
        let inside = record
            .iter()
            .map(|c| c.bytes().filter(|&b| b == b'\n').count() as u64)
            .sum::<u64>();
        // Every record reaching here ends with a line end (a cut last line was refused).
        let end = reader.position().line();
        Ok(Some(end.saturating_sub(1 + inside).max(1)))
    };
    if next(&mut reader, &mut record)?.is_none() {
        return Err(too_few());
    }
    let header = Header {
        path,
        cells: record
            .iter()
            .map(|c| c.trim_end_matches('\r').to_string())
            .collect(),
        map,
    };
    let resolved = columns(&header)?;
    let width = header.cells.len();
    while let Some(line) = next(&mut reader, &mut record)? {
        if record.len() <= 1 && record.iter().all(|c| c.trim().is_empty()) {
            continue; // blank line
        }
        if record.len() != width {
            return Err(DatasetError::FieldCount {
                path: path.to_path_buf(),
                line,
                expected: width,
                found: record.len(),
            });
        }
        row(
            &resolved,
            &Row {
                path,
                line,
                record: &record,
            },
        )?;
    }
    Ok(())
}

/// The time column of any CSV file with a header (`time`, `t`, `timestamp`; s or
/// ms), every row relative to `epoch_s` and read on its digits (see the IMU and DVL
/// readers), e.g. to put a ground-truth file on the navigator's clock.
///
/// # Errors
/// [`DatasetError::Io`]; a missing time column; a bad cell (file and line).
pub fn load_times(path: &Path, epoch_s: f64) -> Result<Vec<f64>> {
    load_times_with(path, epoch_s, &super::ColumnMap::default())
}

/// [`load_times`] of a ground-truth file with a column map (its `gt` section's
/// `time_s` / `time_ms`).
///
/// # Errors
/// As [`load_times`], and [`DatasetError::ColumnMap`].
pub fn load_times_with(path: &Path, epoch_s: f64, map: &super::ColumnMap) -> Result<Vec<f64>> {
    let mut out = Vec::new();
    let quantities = super::akit::GT_QUANTITIES;
    let section = MapSection {
        map: &map.gt,
        section: "columns.gt",
        quantities,
    };
    for_each_row(
        open_text(path)?,
        path,
        section,
        |h| Ok(h.require(&[TIME])?.remove(0)),
        |time, row| {
            out.push(row.time(time, epoch_s)?);
            Ok(())
        },
    )?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::cell::Cell;
    use std::rc::Rc;

    /// A reader of `text` that counts the bytes handed out.
    struct Counted {
        text: Vec<u8>,
        at: usize,
        handed: Rc<Cell<usize>>,
    }

    impl std::io::Read for Counted {
        fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
            let n = buf.len().min(self.text.len() - self.at).min(4096);
            buf[..n].copy_from_slice(&self.text[self.at..self.at + n]);
            self.at += n;
            self.handed.set(self.at);
            Ok(n)
        }
    }

    fn table(rows: usize) -> String {
        (0..rows).fold(String::from("time,x\n"), |t, k| t + &format!("{k},{k}\n"))
    }

    /// Rows with their lines, read from `text` (or the error).
    fn rows_of(text: &[u8]) -> Result<Vec<(u64, f64)>> {
        const X: Quantity = Quantity {
            key: "x",
            kind: Kind::Length,
            aliases: &[same("x")],
            max_abs: 1e9,
        };
        let (mut out, x) = (Vec::new(), X);
        for_each_row(
            text,
            Path::new("f.csv"),
            MapSection {
                map: &BTreeMap::new(),
                section: "columns",
                quantities: &[],
            },
            |h| h.require(&[TIME, x]),
            |c, row| {
                out.push((row.line, row.number(&c[1], &x)?));
                Ok(())
            },
        )?;
        Ok(out)
    }

    /// The first row is handed over long before a 2 MB input is read: records are
    /// streamed, not the file read whole first.
    #[test]
    fn rows_are_streamed_before_the_input_is_read() {
        let text = table(200_000).into_bytes();
        assert!(text.len() > 2_000_000);
        let handed = Rc::new(Cell::new(0));
        let input = Counted {
            text,
            at: 0,
            handed: handed.clone(),
        };
        let mut at_first_row = None;
        for_each_row(
            input,
            Path::new("f.csv"),
            MapSection {
                map: &BTreeMap::new(),
                section: "columns",
                quantities: &[],
            },
            |h| h.require(&[TIME]),
            |_, _| {
                at_first_row.get_or_insert(handed.get());
                Ok(())
            },
        )
        .expect("rows");
        let first = at_first_row.expect("a row");
        assert!(
            first <= 128 * 1024,
            "{first} bytes read before the first row"
        );
    }

    /// Lines are those of the file with LF or CRLF ends, blank lines and a quoted
    /// cell holding a line end; past the first block too.
    #[test]
    fn lines_are_counted_as_in_the_file() {
        let text = "time,x\r\n\r\n0,\"5\"\r\n1,6\r\n\n\n2,7\n";
        let rows = rows_of(text.as_bytes()).expect("rows");
        assert_eq!(rows, vec![(3, 5.0), (4, 6.0), (7, 7.0)]);
        let big = table(20_000) + "20000,\"a\nb\"\n";
        match rows_of(big.as_bytes()) {
            Err(DatasetError::Parse { line, .. }) => assert_eq!(line, 20_002),
            other => panic!("{other:?}"),
        }
    }

    /// Past the first block: a cut last line, a NUL byte and invalid UTF-8 are named
    /// with their lines, as when the file was read whole.
    #[test]
    fn a_long_file_is_checked_as_it_streams() {
        let mut cut = table(20_000);
        cut.pop();
        match rows_of(cut.as_bytes()) {
            Err(DatasetError::Truncated { line, .. }) => assert_eq!(line, 20_001),
            other => panic!("{other:?}"),
        }
        let text = table(20_000).into_bytes();
        let at = text.len() - 100;
        let line = 1 + text[..at].iter().filter(|&&b| b == b'\n').count() as u64;
        for (byte, what) in [(0u8, "NUL byte"), (0xe9, "not UTF-8")] {
            let mut bad = text.clone();
            bad[at] = byte;
            match rows_of(&bad) {
                Err(DatasetError::NotText {
                    line: l, what: w, ..
                }) => {
                    assert_eq!(l, Some(line));
                    assert!(
                        w.contains(what) && w.contains(&format!("offset {at}")),
                        "{w}"
                    );
                }
                other => panic!("{other:?}"),
            }
        }
    }

    #[test]
    fn unix_times_keep_their_digits() {
        let unshifted: f64 = "3.0025062656641603".parse().unwrap();
        assert_eq!(
            relative_decimal("1700000003.0025062656641603", 1.0, 1.7e9),
            Some(unshifted)
        );
        assert_eq!(
            relative_decimal("3.0025062656641603", 1.0, 0.0),
            Some(unshifted)
        );
        assert_eq!(relative_decimal("12", 1.0, 0.0), Some(12.0));
        assert_eq!(relative_decimal("-1.5", 1.0, 0.0), None);
        assert_eq!(relative_decimal("1e3", 1.0, 0.0), None);
        assert_eq!(relative_decimal("5.5", 1.0, 10.0), None);
        assert_eq!(relative_decimal("5.5", 1e-3, 0.0), None);
    }
}
