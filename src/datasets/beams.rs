//! DVL beam files read by `estim dvl solve`: a CSV with a header row naming the beam
//! columns (`beam1`..`beam4` or `beam 1`..`beam 4`, any case, a leading BOM
//! allowed); other columns are ignored; an empty or `nan` cell is a missing beam.

use std::path::Path;

use super::{DatasetError, Result};

/// Beam velocities of one row \[m/s\]; `None` = missing beam.
pub type BeamRow = [Option<f64>; 4];

/// Read and parse a beam file (see [`parse_beams`]).
///
/// # Errors
/// [`DatasetError::Io`] when the file cannot be read, then those of [`parse_beams`].
pub fn load_beams(path: &Path) -> Result<Vec<BeamRow>> {
    let bytes = std::fs::read(path).map_err(|source| DatasetError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_beams(&bytes, path)
}

/// Column indices of beams 1..4 from a header row.
fn beam_columns(path: &Path, header: &csv::StringRecord) -> Result<[usize; 4]> {
    let mut found: [Option<usize>; 4] = [None; 4];
    let header_error = |problem: String| DatasetError::Header {
        path: path.to_path_buf(),
        expected: format!("columns beam1..beam4 or \"beam 1\"..\"beam 4\" ({problem})"),
        found: header
            .iter()
            .collect::<Vec<_>>()
            .join(",")
            .chars()
            .take(80)
            .collect(),
    };
    for (index, name) in header.iter().enumerate() {
        let key: String = name
            .trim_start_matches('\u{feff}')
            .chars()
            .filter(|c| !c.is_whitespace())
            .collect::<String>()
            .to_ascii_lowercase();
        let beam = match key.as_str() {
            "beam1" => 0,
            "beam2" => 1,
            "beam3" => 2,
            "beam4" => 3,
            _ => continue,
        };
        if found[beam].is_some() {
            return Err(header_error(format!("beam{} appears twice", beam + 1)));
        }
        found[beam] = Some(index);
    }
    let missing: Vec<String> = (0..4)
        .filter(|&b| found[b].is_none())
        .map(|b| format!("beam{}", b + 1))
        .collect();
    if !missing.is_empty() {
        return Err(header_error(format!("missing {}", missing.join(", "))));
    }
    Ok(found.map(|c| c.unwrap_or(0)))
}

/// Parse the beams of every data row of a beam file; `path` names it in errors.
/// Blank lines are skipped; every error names the file and the 1-based line.
///
/// # Errors
/// [`DatasetError::Header`] (empty file, missing or repeated beam column),
/// [`DatasetError::Csv`], [`DatasetError::FieldCount`] (a row too short to hold a beam
/// column), [`DatasetError::Parse`], [`DatasetError::NonFinite`].
pub fn parse_beams(bytes: &[u8], path: &Path) -> Result<Vec<BeamRow>> {
    // Line numbers from byte offsets (the csv crate's own line counter skips blank
    // lines, and a record's offset may point at the blank lines before it).
    let line_at = |byte: u64| -> u64 {
        let mut start = usize::try_from(byte).unwrap_or(usize::MAX).min(bytes.len());
        while start < bytes.len() && matches!(bytes[start], b'\n' | b'\r') {
            start += 1;
        }
        1 + bytes[..start].iter().filter(|&&c| c == b'\n').count() as u64
    };
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .from_reader(bytes);
    let csv_error = |e: csv::Error| DatasetError::Csv {
        path: path.to_path_buf(),
        line: e.position().map_or(1, |p| line_at(p.byte())),
        message: e.to_string(),
    };
    let mut records = reader.records();
    let header = match records.next() {
        Some(r) => r.map_err(csv_error)?,
        None => {
            return Err(DatasetError::Header {
                path: path.to_path_buf(),
                expected: "a header row naming beam1..beam4 (the file is empty)".into(),
                found: String::new(),
            })
        }
    };
    let columns = beam_columns(path, &header)?;
    let mut rows = Vec::new();
    for record in records {
        let record = record.map_err(csv_error)?;
        let line = record.position().map_or(0, |p| line_at(p.byte()));
        if record.iter().all(|c| c.trim().is_empty()) && record.len() <= 1 {
            continue; // blank line
        }
        let mut beams = [None; 4];
        for (b, &col) in columns.iter().enumerate() {
            let Some(cell) = record.get(col) else {
                return Err(DatasetError::FieldCount {
                    path: path.to_path_buf(),
                    line,
                    expected: col + 1,
                    found: record.len(),
                });
            };
            let cell = cell.trim();
            if cell.is_empty() || cell.eq_ignore_ascii_case("nan") {
                continue;
            }
            match cell.parse::<f64>() {
                Ok(x) if x.is_finite() => beams[b] = Some(x),
                Ok(_) => {
                    return Err(DatasetError::NonFinite {
                        path: path.to_path_buf(),
                        line,
                        column: format!("beam{}", b + 1),
                    })
                }
                Err(_) => {
                    return Err(DatasetError::Parse {
                        path: path.to_path_buf(),
                        line,
                        column: format!("beam{}", b + 1),
                        value: cell.chars().take(40).collect(),
                    })
                }
            }
        }
        rows.push(beams);
    }
    Ok(rows)
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
    }
}
