//! Columns found by name in a CSV header, in any order, with the unit the header
//! states (`Latitude [deg]`, `depth (m)`, `time_s`), or through a column map
//! (`[columns.gt]` / `[columns.dvl]` of the configuration).
//!
//! Names are compared after lower-casing and dropping spaces, `_`, `-` and `.`, so
//! `V North`, `v_north` and `VNorth` are one name. A unit is read from a trailing
//! `[unit]` or `(unit)`, or from a trailing `_unit` / ` unit` when that word is a unit
//! of the quantity. A column without a unit is read in the A-KIT unit (s, rad, m, m/s).

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::{DatasetError, Result};

/// What a column measures, which fixes the units it may be stated in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Kind {
    Time,
    Angle,
    Length,
    Speed,
    /// Specific force (m/s^2 or g).
    Acceleration,
    /// Angular rate (rad/s or deg/s).
    AngularRate,
    /// A dimensionless value (a validity flag).
    Flag,
}

impl Kind {
    /// Accepted unit spellings (normalized) and the factor to the SI unit.
    fn units(self) -> &'static [(&'static str, f64)] {
        const DEG: f64 = std::f64::consts::PI / 180.0;
        match self {
            Kind::Time => &[
                ("s", 1.0),
                ("sec", 1.0),
                ("second", 1.0),
                ("seconds", 1.0),
                ("ms", 1e-3),
            ],
            Kind::Angle => &[
                ("rad", 1.0),
                ("radian", 1.0),
                ("radians", 1.0),
                ("deg", DEG),
                ("degree", DEG),
                ("degrees", DEG),
                ("°", DEG),
            ],
            Kind::Length => &[
                ("m", 1.0),
                ("meter", 1.0),
                ("meters", 1.0),
                ("metre", 1.0),
                ("metres", 1.0),
            ],
            Kind::Speed => &[
                ("m/s", 1.0),
                ("mps", 1.0),
                ("ms-1", 1.0),
                ("ms^-1", 1.0),
                ("cm/s", 1e-2),
                ("mm/s", 1e-3),
            ],
            Kind::Acceleration => &[
                ("m/s^2", 1.0),
                ("m/s2", 1.0),
                ("m/s/s", 1.0),
                ("mps2", 1.0),
                ("ms-2", 1.0),
                ("ms^-2", 1.0),
                ("g", 9.80665),
            ],
            Kind::AngularRate => &[
                ("rad/s", 1.0),
                ("radps", 1.0),
                ("rads-1", 1.0),
                ("deg/s", DEG),
                ("dps", DEG),
                ("degps", DEG),
                ("°/s", DEG),
            ],
            Kind::Flag => &[("", 1.0), ("-", 1.0)],
        }
    }

    /// The SI unit values are converted to.
    pub(crate) fn si_unit(self) -> &'static str {
        self.default_unit()
    }

    /// The unit a column without one is read in (A-KIT's).
    fn default_unit(self) -> &'static str {
        match self {
            Kind::Time => "s",
            Kind::Angle => "rad",
            Kind::Length => "m",
            Kind::Speed => "m/s",
            Kind::Acceleration => "m/s^2",
            Kind::AngularRate => "rad/s",
            Kind::Flag => "",
        }
    }

    /// The unit suffix of column-map keys (`latitude_deg`, `v_north_mps`).
    fn map_suffixes(self) -> &'static [(&'static str, &'static str)] {
        match self {
            Kind::Time => &[("s", "s"), ("ms", "ms")],
            Kind::Angle => &[("rad", "rad"), ("deg", "deg")],
            Kind::Length => &[("m", "m")],
            Kind::Speed => &[("mps", "m/s"), ("mmps", "mm/s"), ("cmps", "cm/s")],
            Kind::Acceleration => &[("mps2", "m/s^2"), ("g", "g")],
            Kind::AngularRate => &[("radps", "rad/s"), ("degps", "deg/s")],
            Kind::Flag => &[("flag", "")],
        }
    }

    fn factor(self, unit: &str) -> Option<f64> {
        let key = normalize_unit(unit);
        self.units()
            .iter()
            .find(|(u, _)| *u == key)
            .map(|&(_, f)| f)
    }

    fn accepted(self) -> String {
        self.units()
            .iter()
            .map(|(u, _)| *u)
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// One name a quantity may go by; `negate` flips the sign (depth = -altitude,
/// V Up = -V Down).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Alias {
    pub name: &'static str,
    pub negate: bool,
}

pub(crate) const fn same(name: &'static str) -> Alias {
    Alias {
        name,
        negate: false,
    }
}

pub(crate) const fn flipped(name: &'static str) -> Alias {
    Alias { name, negate: true }
}

/// A quantity a loader needs: its canonical name, kind and the names it goes by.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Quantity {
    /// Canonical name, also the column-map key's stem (`latitude`, `v_north`).
    pub key: &'static str,
    pub kind: Kind,
    /// Normalized names (see the module doc).
    pub aliases: &'static [Alias],
    /// Values must satisfy |x| < max_abs (SI unit), the range the navigator models.
    pub max_abs: f64,
}

/// A column of the header resolved to a quantity: its index, header text and the
/// factor (unit and sign) taking a cell to the canonical SI value.
#[derive(Debug, Clone)]
pub(crate) struct Resolved {
    pub index: usize,
    pub header: String,
    pub factor: f64,
    /// Whether the header (or the column map) states the unit; else the default is
    /// assumed.
    pub unit_stated: bool,
}

/// A column map: canonical name with unit suffix -> header text, per file kind.
///
/// Keys are `<quantity>_<unit>`: for GT `time_s`, `longitude_rad`/`_deg`,
/// `latitude_rad`/`_deg`, `altitude_m`, `height_m`, `depth_m`, `v_north_mps`,
/// `v_east_mps`, `v_down_mps`, `v_up_mps`, `roll_rad`/`_deg`, `pitch_rad`/`_deg`,
/// `yaw_rad`/`_deg`, `heading_rad`/`_deg`; for DVL `time_s`, `x_mps`, `y_mps`, `z_mps`
/// (speeds also `_mmps`, `_cmps`; times also `_ms`), and for the survey readers
/// `validity_flag` and `fom_mps`; for the IMU `time_s`, `acc_x_mps2`/`_g` (x, y, z),
/// `gyro_x_radps`/`_degps`, or increments `dv_x_mps`, `dtheta_x_rad`/`_deg`, and
/// `true_acc_bias_x_mps2`, `true_gyro_bias_x_radps`; for DVL beams `time_s`,
/// `beam1_mps` .. `beam4_mps`; for depth `time_s`, `depth_m`; for fixes `time_s`,
/// `latitude_rad`/`_deg`, `longitude_rad`/`_deg`, `sigma_m`. The value is the header
/// cell's text (trimmed). A mapped quantity is found only through the map; the others
/// by name as usual. `[columns]` of the study's configuration (`gt`, `dvl`) and of the
/// navigator's vehicle file (every section; `gt` for `--truth`) are this map.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ColumnMap {
    /// Ground-truth file: key -> header text.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub gt: BTreeMap<String, String>,
    /// DVL velocity file: key -> header text.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub dvl: BTreeMap<String, String>,
    /// IMU file (survey readers): key -> header text.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub imu: BTreeMap<String, String>,
    /// DVL beams file (survey readers): key -> header text.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub beams: BTreeMap<String, String>,
    /// Depth file: key -> header text.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub depth: BTreeMap<String, String>,
    /// Position-fix file: key -> header text.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub fixes: BTreeMap<String, String>,
}

/// The sections of a [`ColumnMap`] with the quantities each may map.
fn sections(map: &ColumnMap) -> [(&BTreeMap<String, String>, Vec<Quantity>, &'static str); 6] {
    let dvl: Vec<Quantity> = super::akit::DVL_QUANTITIES
        .iter()
        .chain(super::dvl_log::FLAG_QUANTITIES)
        .copied()
        .collect();
    [
        (&map.gt, super::akit::GT_QUANTITIES.to_vec(), "columns.gt"),
        (&map.dvl, dvl, "columns.dvl"),
        (&map.imu, super::imu::quantities(), "columns.imu"),
        (
            &map.beams,
            super::dvl_log::beam_quantities(),
            "columns.beams",
        ),
        (
            &map.depth,
            super::fixes::depth_quantities(),
            "columns.depth",
        ),
        (&map.fixes, super::fixes::fix_quantities(), "columns.fixes"),
    ]
}

impl ColumnMap {
    /// Validate every key against the quantities of its file; the message names the key.
    ///
    /// # Errors
    /// The first invalid key: unknown (with the keys its section accepts), an empty
    /// header text, or a quantity mapped twice.
    pub fn check(&self) -> std::result::Result<(), String> {
        for (map, quantities, section) in sections(self) {
            check_map(map, &quantities, section)?;
        }
        Ok(())
    }

    /// [`ColumnMap::check`], and refuse a mapped section that is not among `used`
    /// (e.g. `[columns.imu]` in the study's configuration, whose IMU is synthesized):
    /// a map that would be ignored is an error naming it.
    ///
    /// # Errors
    /// As [`ColumnMap::check`]; `columns.<section>: not used here` for the others.
    pub fn check_used(&self, used: &[&str]) -> std::result::Result<(), String> {
        self.check()?;
        for (map, _, section) in sections(self) {
            let name = section.trim_start_matches("columns.");
            if !map.is_empty() && !used.contains(&name) {
                return Err(format!(
                    "{section}: not used here (this file reads only [columns.{}])",
                    used.join("], [columns.")
                ));
            }
        }
        Ok(())
    }

    /// True when no column is mapped.
    pub fn is_empty(&self) -> bool {
        self.gt.is_empty()
            && self.dvl.is_empty()
            && self.imu.is_empty()
            && self.beams.is_empty()
            && self.depth.is_empty()
            && self.fixes.is_empty()
    }

    /// This map with `over`'s entries taking precedence: an entry of `over` replaces
    /// the entry of the same section that maps the same quantity (whatever its unit),
    /// the others are kept (a command-line map over a vehicle file's).
    ///
    /// # Errors
    /// As [`ColumnMap::check`], for either map.
    pub fn overridden_by(&self, over: &ColumnMap) -> std::result::Result<ColumnMap, String> {
        self.check()?;
        over.check()?;
        let mut out = self.clone();
        let targets = [
            (&mut out.gt, &over.gt),
            (&mut out.dvl, &over.dvl),
            (&mut out.imu, &over.imu),
            (&mut out.beams, &over.beams),
            (&mut out.depth, &over.depth),
            (&mut out.fixes, &over.fixes),
        ];
        for ((base, top), (_, quantities, _)) in targets.into_iter().zip(sections(self)) {
            let quantity = |key: &str| parse_map_key(key, &quantities).map(|(q, _)| q);
            for (key, header) in top {
                let q = quantity(key);
                base.retain(|k, _| quantity(k) != q);
                base.insert(key.clone(), header.clone());
            }
        }
        Ok(out)
    }
}

/// A map entry resolved: the quantity it names, its unit factor and sign.
struct MapEntry<'a> {
    quantity: &'static str,
    header: &'a str,
    factor: f64,
}

fn parse_map_key(key: &str, quantities: &[Quantity]) -> Option<(&'static str, f64)> {
    let (stem, suffix) = key.rsplit_once('_')?;
    for q in quantities {
        for alias in q.aliases {
            if normalize_name(stem) != alias.name {
                continue;
            }
            // Only the key spellings listed in the ColumnMap doc: the canonical stem or
            // one of the documented alternatives (height, depth, v_up, heading).
            if !map_stems(q.key).contains(&stem) {
                continue;
            }
            let &(_, unit) = q.kind.map_suffixes().iter().find(|(s, _)| *s == suffix)?;
            let factor = q.kind.factor(unit)?;
            let sign = if alias.negate { -1.0 } else { 1.0 };
            return Some((q.key, sign * factor));
        }
    }
    None
}

/// Whether `map` names a column for `quantity` (a mapped column that is missing is an
/// error even where the quantity is optional).
pub(crate) fn maps(map: &BTreeMap<String, String>, quantity: &Quantity) -> bool {
    map.keys()
        .any(|k| parse_map_key(k, std::slice::from_ref(quantity)).is_some())
}

/// Column-map key stems per quantity (the canonical one first): the quantity's key,
/// and for some the documented alternatives.
fn map_stems(key: &'static str) -> Vec<&'static str> {
    match key {
        "altitude" => vec!["altitude", "height", "depth"],
        "v_down" => vec!["v_down", "v_up"],
        "yaw" => vec!["yaw", "heading"],
        other => vec![other],
    }
}

fn map_entries<'a>(
    map: &'a BTreeMap<String, String>,
    quantities: &[Quantity],
    section: &str,
    strict: bool,
) -> std::result::Result<Vec<MapEntry<'a>>, String> {
    let mut entries: Vec<MapEntry<'a>> = Vec::new();
    for (key, header) in map {
        let Some((quantity, factor)) = parse_map_key(key, quantities) else {
            if !strict {
                // A key of another quantity of the file (checked by ColumnMap::check).
                continue;
            }
            let keys: Vec<String> = quantities
                .iter()
                .flat_map(|q| {
                    map_stems(q.key).into_iter().map(move |s| {
                        let units: Vec<&str> =
                            q.kind.map_suffixes().iter().map(|(u, _)| *u).collect();
                        format!("{s}_{}", units.join("|"))
                    })
                })
                .collect();
            return Err(format!(
                "{section}.{key}: unknown key (expected one of {})",
                keys.join(", ")
            ));
        };
        if header.trim().is_empty() {
            return Err(format!("{section}.{key}: empty header text"));
        }
        if let Some(other) = entries.iter().find(|e| e.quantity == quantity) {
            return Err(format!(
                "{section}.{key}: maps {quantity} a second time (also `{}`)",
                other.header
            ));
        }
        entries.push(MapEntry {
            quantity,
            header: header.as_str(),
            factor,
        });
    }
    Ok(entries)
}

fn check_map(
    map: &BTreeMap<String, String>,
    quantities: &[Quantity],
    section: &str,
) -> std::result::Result<(), String> {
    map_entries(map, quantities, section, true).map(|_| ())
}

/// Lower-case, without spaces, `_`, `-`, `.` and a BOM.
pub(crate) fn normalize_name(s: &str) -> String {
    s.chars()
        .filter(|c| !c.is_whitespace() && !matches!(c, '_' | '-' | '.' | '\u{feff}'))
        .flat_map(char::to_lowercase)
        .collect()
}

fn normalize_unit(s: &str) -> String {
    s.chars()
        .filter(|c| !c.is_whitespace())
        .flat_map(char::to_lowercase)
        .collect()
}

/// Split a header cell into a name and an optional unit in brackets or parentheses.
fn split_unit(cell: &str) -> (&str, Option<&str>) {
    let cell = cell.trim().trim_start_matches('\u{feff}').trim();
    for (open, close) in [('[', ']'), ('(', ')')] {
        if let Some(body) = cell.strip_suffix(close) {
            if let Some(start) = body.rfind(open) {
                return (body[..start].trim(), Some(body[start + 1..].trim()));
            }
        }
    }
    (cell, None)
}

/// The quantity alias a header cell names, with the unit it states (if any).
fn identify<'q>(cell: &str, q: &'q Quantity) -> Option<(&'q Alias, Option<String>)> {
    let (name, unit) = split_unit(cell);
    let key = normalize_name(name);
    if let Some(a) = q.aliases.iter().find(|a| a.name == key) {
        return Some((a, unit.map(str::to_string)));
    }
    if unit.is_some() {
        return None;
    }
    // `time_s`, `lat deg`, `vx_mm/s`: a trailing word that is a unit of the quantity.
    let (stem, word) = name.rsplit_once(['_', ' '])?;
    let stem_key = normalize_name(stem);
    let a = q.aliases.iter().find(|a| a.name == stem_key)?;
    q.kind.factor(word)?;
    Some((a, Some(word.to_string())))
}

/// Resolve every quantity to one header column.
///
/// # Errors
/// [`DatasetError::MissingColumn`], [`DatasetError::AmbiguousColumn`],
/// [`DatasetError::Unit`], and [`DatasetError::ColumnMap`] for an invalid map.
#[cfg(test)]
pub(crate) fn resolve(
    path: &Path,
    header: &[String],
    quantities: &[Quantity],
    map: &BTreeMap<String, String>,
    section: &str,
) -> Result<Vec<Resolved>> {
    resolve_with(path, header, quantities, map, section, true)
}

/// Resolve every quantity to one header column, for a subset of a file's quantities: map keys of the file's other
/// quantities are passed over (the whole map is checked once, before the header is
/// read: [`check_section`]).
pub(crate) fn resolve_some(
    path: &Path,
    header: &[String],
    quantities: &[Quantity],
    map: &BTreeMap<String, String>,
    section: &str,
) -> Result<Vec<Resolved>> {
    resolve_with(path, header, quantities, map, section, false)
}

/// Check one section of a map against all the quantities its file may have, as an
/// error naming the file.
///
/// # Errors
/// [`DatasetError::ColumnMap`] naming the key.
pub(crate) fn check_section(
    path: &Path,
    map: &BTreeMap<String, String>,
    quantities: &[Quantity],
    section: &str,
) -> Result<()> {
    check_map(map, quantities, section).map_err(|message| DatasetError::ColumnMap {
        path: path.to_path_buf(),
        message,
    })
}

fn resolve_with(
    path: &Path,
    header: &[String],
    quantities: &[Quantity],
    map: &BTreeMap<String, String>,
    section: &str,
    strict: bool,
) -> Result<Vec<Resolved>> {
    let entries = map_entries(map, quantities, section, strict).map_err(|message| {
        DatasetError::ColumnMap {
            path: path.to_path_buf(),
            message,
        }
    })?;
    let found = || header.join(",").chars().take(200).collect::<String>();
    let mut out = Vec::with_capacity(quantities.len());
    for q in quantities {
        if let Some(entry) = entries.iter().find(|e| e.quantity == q.key) {
            let index = header
                .iter()
                .position(|h| h.trim().trim_start_matches('\u{feff}').trim() == entry.header.trim())
                .ok_or_else(|| DatasetError::MissingColumn {
                    path: path.to_path_buf(),
                    column: format!("{} (mapped to `{}`)", q.key, entry.header),
                    accepted: format!("`{}` as mapped in the configuration", entry.header),
                    found: found(),
                })?;
            out.push(Resolved {
                index,
                header: header[index].clone(),
                factor: entry.factor,
                unit_stated: true,
            });
            continue;
        }
        let hits: Vec<(usize, &Alias, Option<String>)> = header
            .iter()
            .enumerate()
            .filter_map(|(i, h)| identify(h, q).map(|(a, u)| (i, a, u)))
            .collect();
        match hits.as_slice() {
            [] => {
                return Err(DatasetError::MissingColumn {
                    path: path.to_path_buf(),
                    column: q.key.to_string(),
                    accepted: q
                        .aliases
                        .iter()
                        .map(|a| a.name)
                        .collect::<Vec<_>>()
                        .join(", "),
                    found: found(),
                })
            }
            [(index, alias, unit)] => {
                let unit_stated = unit.is_some();
                let unit = unit.as_deref().unwrap_or(q.kind.default_unit());
                let factor = q.kind.factor(unit).ok_or_else(|| DatasetError::Unit {
                    path: path.to_path_buf(),
                    column: header[*index].trim().to_string(),
                    unit: unit.to_string(),
                    accepted: q.kind.accepted(),
                })?;
                let sign = if alias.negate { -1.0 } else { 1.0 };
                out.push(Resolved {
                    index: *index,
                    header: header[*index].trim().to_string(),
                    factor: sign * factor,
                    unit_stated,
                });
            }
            many => {
                return Err(DatasetError::AmbiguousColumn {
                    path: path.to_path_buf(),
                    column: q.key.to_string(),
                    candidates: many
                        .iter()
                        .map(|(i, _, _)| format!("`{}`", header[*i].trim()))
                        .collect::<Vec<_>>()
                        .join(", "),
                })
            }
        }
    }
    // Two quantities on one column (e.g. a map entry and a name match).
    for (i, a) in out.iter().enumerate() {
        if let Some(j) = out[i + 1..].iter().position(|b| b.index == a.index) {
            return Err(DatasetError::AmbiguousColumn {
                path: path.to_path_buf(),
                column: format!("{} and {}", quantities[i].key, quantities[i + 1 + j].key),
                candidates: format!("both read from `{}`", a.header),
            });
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    const Q: &[Quantity] = &[
        Quantity {
            key: "time",
            kind: Kind::Time,
            aliases: &[same("time"), same("t")],
            max_abs: 1e10,
        },
        Quantity {
            key: "altitude",
            kind: Kind::Length,
            aliases: &[same("altitude"), same("height"), flipped("depth")],
            max_abs: 1e5,
        },
        Quantity {
            key: "yaw",
            kind: Kind::Angle,
            aliases: &[same("yaw"), same("heading")],
            max_abs: 1e4,
        },
    ];

    fn header(s: &str) -> Vec<String> {
        s.split(',').map(str::to_string).collect()
    }

    #[test]
    fn names_units_and_signs() {
        let r = resolve(
            Path::new("f.csv"),
            &header("Heading (deg), depth_m ,\u{feff}TIME [ms]"),
            Q,
            &BTreeMap::new(),
            "columns.gt",
        )
        .unwrap();
        assert_eq!(r[0].index, 2);
        assert_eq!(r[0].factor, 1e-3);
        assert_eq!(r[1].index, 1);
        assert_eq!(r[1].factor, -1.0);
        assert_eq!(r[2].factor, std::f64::consts::PI / 180.0);
    }

    #[test]
    fn missing_ambiguous_and_unknown_unit_are_named() {
        let p = Path::new("f.csv");
        let e = resolve(p, &header("t,yaw"), Q, &BTreeMap::new(), "c").unwrap_err();
        let s = e.to_string();
        assert!(
            s.contains("f.csv") && s.contains("altitude") && s.contains("t,yaw"),
            "{s}"
        );
        let e = resolve(p, &header("t,depth,height,yaw"), Q, &BTreeMap::new(), "c").unwrap_err();
        assert!(matches!(e, DatasetError::AmbiguousColumn { .. }), "{e}");
        let e = resolve(p, &header("t,depth [ft],yaw"), Q, &BTreeMap::new(), "c").unwrap_err();
        assert!(e.to_string().contains("ft"), "{e}");
    }

    #[test]
    fn column_map_overrides_names() {
        let p = Path::new("f.csv");
        let map: BTreeMap<String, String> = [
            ("depth_m".to_string(), "Z".to_string()),
            ("heading_deg".to_string(), "HDG".to_string()),
        ]
        .into();
        let r = resolve(p, &header("t,HDG,Z"), Q, &map, "c").unwrap();
        assert_eq!((r[1].index, r[1].factor), (2, -1.0));
        assert_eq!(r[2].index, 1);
        let bad: BTreeMap<String, String> = [("depth_ft".to_string(), "Z".to_string())].into();
        let e = resolve(p, &header("t,HDG,Z"), Q, &bad, "c").unwrap_err();
        assert!(e.to_string().contains("depth_ft"), "{e}");
    }
}
