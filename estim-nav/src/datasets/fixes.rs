//! Depth (pressure) and position-fix CSV files for the navigator.
//!
//! Depth: time and `depth` (m, positive down). Fixes: time, `latitude` / `lat`,
//! `longitude` / `lon` (rad or deg as the header states; without a unit, rad as in
//! the GT files) and the horizontal 1-sigma `sigma` (`std`, `accuracy`, `hacc`,
//! `sigma h`; m). Every error names the file and the line.

use std::path::Path;

use super::akit::{MAX_ABS_ALTITUDE_M, MAX_ABS_LATITUDE_RAD, MAX_ABS_LONGITUDE_RAD};
use super::columns::{same, Kind, Quantity};
use super::input::open_text;
use super::table::{for_each_row, MapSection, TIME};
use super::ColumnMap;
use super::{DatasetError, Result};
use crate::navigator::{DepthSample, PositionFix};

const DEPTH: Quantity = Quantity {
    key: "depth",
    kind: Kind::Length,
    aliases: &[same("depth"), same("pressuredepth"), same("z")],
    max_abs: MAX_ABS_ALTITUDE_M,
};

const FIX: [Quantity; 3] = [
    Quantity {
        key: "latitude",
        kind: Kind::Angle,
        aliases: &[same("latitude"), same("lat")],
        max_abs: MAX_ABS_LATITUDE_RAD,
    },
    Quantity {
        key: "longitude",
        kind: Kind::Angle,
        aliases: &[same("longitude"), same("lon"), same("long"), same("lng")],
        max_abs: MAX_ABS_LONGITUDE_RAD,
    },
    Quantity {
        key: "sigma",
        kind: Kind::Length,
        aliases: &[
            same("sigma"),
            same("std"),
            same("accuracy"),
            same("hacc"),
            same("sigmah"),
            same("horizontalaccuracy"),
        ],
        max_abs: 1e6,
    },
];

/// Every quantity of a depth file (the keys of `[columns.depth]`).
pub(crate) fn depth_quantities() -> Vec<Quantity> {
    vec![TIME, DEPTH]
}

/// Every quantity of a position-fix file (the keys of `[columns.fixes]`).
pub(crate) fn fix_quantities() -> Vec<Quantity> {
    std::iter::once(TIME).chain(FIX).collect()
}

fn epoch_of(
    epoch: &mut Option<f64>,
    row: &super::table::Row<'_>,
    c: &super::columns::Resolved,
) -> Result<f64> {
    match *epoch {
        Some(e) => Ok(e),
        None => Ok(*epoch.insert(row.whole_seconds(c)?)),
    }
}

/// Read a depth file: samples with times relative to the epoch (the one given, else
/// the whole seconds of the first time), and that epoch.
///
/// # Errors
/// [`DatasetError::Io`]; missing columns, bad cells, times that do not increase, no
/// rows (file and line).
pub fn load_depth(path: &Path, epoch_s: Option<f64>) -> Result<(Vec<DepthSample>, f64)> {
    parse_depth_with(open_text(path)?, path, epoch_s, &ColumnMap::default())
}

/// [`load_depth`] with a column map (its `depth` section).
///
/// # Errors
/// As [`load_depth`], and [`DatasetError::ColumnMap`] naming a bad key.
pub fn load_depth_with(
    path: &Path,
    epoch_s: Option<f64>,
    map: &ColumnMap,
) -> Result<(Vec<DepthSample>, f64)> {
    parse_depth_with(open_text(path)?, path, epoch_s, map)
}

/// Parse a depth file (see [`load_depth`]).
///
/// # Errors
/// As [`load_depth`].
pub fn parse_depth(
    bytes: &[u8],
    path: &Path,
    epoch_s: Option<f64>,
) -> Result<(Vec<DepthSample>, f64)> {
    parse_depth_with(bytes, path, epoch_s, &ColumnMap::default())
}

/// [`parse_depth`] with a column map (its `depth` section).
///
/// # Errors
/// As [`load_depth_with`].
pub fn parse_depth_with(
    input: impl std::io::Read,
    path: &Path,
    epoch_s: Option<f64>,
    map: &ColumnMap,
) -> Result<(Vec<DepthSample>, f64)> {
    let quantities = depth_quantities();
    let section = MapSection {
        map: &map.depth,
        section: "columns.depth",
        quantities: &quantities,
    };
    let mut epoch = epoch_s;
    let mut out: Vec<DepthSample> = Vec::new();
    for_each_row(
        input,
        path,
        section,
        |h| {
            Ok((
                h.require(&[TIME])?.remove(0),
                h.require(&[DEPTH])?.remove(0),
            ))
        },
        |(time, depth), row| {
            let t = row.time(time, epoch_of(&mut epoch, row, time)?)?;
            if let Some(last) = out.last() {
                if t <= last.time {
                    return Err(row.not_increasing(t, last.time));
                }
            }
            out.push(DepthSample {
                time: t,
                depth_m: row.number(depth, &DEPTH)?,
            });
            Ok(())
        },
    )?;
    finish(path, out, epoch)
}

/// Read a position-fix file (see [`load_depth`] for the epoch).
///
/// # Errors
/// As [`load_depth`]; a sigma that is not positive.
pub fn load_fixes(path: &Path, epoch_s: Option<f64>) -> Result<(Vec<PositionFix>, f64)> {
    parse_fixes_with(open_text(path)?, path, epoch_s, &ColumnMap::default())
}

/// [`load_fixes`] with a column map (its `fixes` section).
///
/// # Errors
/// As [`load_fixes`], and [`DatasetError::ColumnMap`] naming a bad key.
pub fn load_fixes_with(
    path: &Path,
    epoch_s: Option<f64>,
    map: &ColumnMap,
) -> Result<(Vec<PositionFix>, f64)> {
    parse_fixes_with(open_text(path)?, path, epoch_s, map)
}

/// Parse a position-fix file.
///
/// # Errors
/// As [`load_fixes`].
pub fn parse_fixes(
    bytes: &[u8],
    path: &Path,
    epoch_s: Option<f64>,
) -> Result<(Vec<PositionFix>, f64)> {
    parse_fixes_with(bytes, path, epoch_s, &ColumnMap::default())
}

/// [`parse_fixes`] with a column map (its `fixes` section).
///
/// # Errors
/// As [`load_fixes_with`].
pub fn parse_fixes_with(
    input: impl std::io::Read,
    path: &Path,
    epoch_s: Option<f64>,
    map: &ColumnMap,
) -> Result<(Vec<PositionFix>, f64)> {
    let quantities = fix_quantities();
    let section = MapSection {
        map: &map.fixes,
        section: "columns.fixes",
        quantities: &quantities,
    };
    let mut epoch = epoch_s;
    let mut out: Vec<PositionFix> = Vec::new();
    for_each_row(
        input,
        path,
        section,
        |h| Ok((h.require(&[TIME])?.remove(0), h.require(&FIX)?)),
        |(time, cols), row| {
            let t = row.time(time, epoch_of(&mut epoch, row, time)?)?;
            if let Some(last) = out.last() {
                if t <= last.time {
                    return Err(row.not_increasing(t, last.time));
                }
            }
            let sigma = row.number(&cols[2], &FIX[2])?;
            if sigma <= 0.0 {
                return Err(DatasetError::OutOfRange {
                    path: path.to_path_buf(),
                    line: row.line,
                    column: cols[2].header.clone(),
                    value: sigma,
                    limit: 0.0,
                    unit: "m (a sigma must be > 0)",
                });
            }
            out.push(PositionFix {
                time: t,
                latitude_deg: row.number(&cols[0], &FIX[0])?.to_degrees(),
                longitude_deg: row.number(&cols[1], &FIX[1])?.to_degrees(),
                sigma_m: sigma,
            });
            Ok(())
        },
    )?;
    finish(path, out, epoch)
}

fn finish<T>(path: &Path, out: Vec<T>, epoch: Option<f64>) -> Result<(Vec<T>, f64)> {
    if out.is_empty() {
        return Err(DatasetError::TooFewRows {
            path: path.to_path_buf(),
            found: 0,
            min: 1,
        });
    }
    Ok((out, epoch.unwrap_or(0.0)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_and_fixes_parse_with_units() {
        let p = Path::new("f.csv");
        let (d, e) = parse_depth(b"time,depth [m]\n100.5,12.5\n101.5,12.7\n", p, None).unwrap();
        assert_eq!((e, d[0].time, d[1].depth_m), (100.0, 0.5, 12.7));
        let (f, _) = parse_fixes(
            b"t,lat [deg],lon [deg],sigma [m]\n5,32.5,34.9,2.0\n",
            p,
            Some(0.0),
        )
        .unwrap();
        assert!((f[0].latitude_deg - 32.5).abs() < 1e-12 && f[0].sigma_m == 2.0);
        let e = parse_fixes(b"t,lat [deg],lon [deg],sigma\n5,32.5,34.9,0\n", p, None).unwrap_err();
        assert!(e.to_string().starts_with("f.csv:2:"), "{e}");
        let e = parse_fixes(b"t,lat,lon,sigma\n5,32.5,34.9,1\n", p, None).unwrap_err();
        assert!(e.to_string().starts_with("f.csv:2:"), "{e}");
    }
}
