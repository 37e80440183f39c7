//! The `--columns` file of the survey commands (`navigate`, `smooth`, `tune --imu`).
//! The checks of a loaded survey as a whole (aiding files outside the IMU's span, a DVL
//! file with no lock, an IMU rate that does not describe its file) are the library's
//! ([`estim::check_survey`]), shared with the Python package.

use std::path::Path;

use estim::datasets::ColumnMap;

/// A `--columns` file: a `[columns]` table and nothing else.
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct ColumnsFile {
    columns: ColumnMap,
}

/// Read a `--columns` file; errors name the file, the line or the key.
pub fn columns_file(path: &Path) -> anyhow::Result<ColumnMap> {
    let text = estim::datasets::read_text_file(path)?;
    let file = toml::from_str::<ColumnsFile>(&text).map_err(|e| {
        let line = e
            .span()
            .map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1);
        match line {
            Some(l) => anyhow::anyhow!("{}:{l}: {}", path.display(), e.message()),
            None => anyhow::anyhow!("{}: {}", path.display(), e.message()),
        }
    })?;
    file.columns
        .check()
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    Ok(file.columns)
}
