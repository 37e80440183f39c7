//! Output folders that appear complete or not at all.
//!
//! Files are written into a hidden staging folder beside the target and renamed into
//! it only when everything succeeded; on failure the staging folder is removed, so
//! `--out` never holds partial output.

use std::path::{Path, PathBuf};

use anyhow::Context;

/// A staging folder for the files of one `--out DIR`.
pub struct StagedDir {
    target: PathBuf,
    staging: PathBuf,
    committed: bool,
}

impl StagedDir {
    /// Create the staging folder beside `target` (the target itself is not touched yet).
    pub fn new(target: &Path) -> anyhow::Result<Self> {
        let parent = match target.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        if !parent.is_dir() {
            anyhow::bail!("{}: parent folder does not exist", target.display());
        }
        let name = target
            .file_name()
            .map_or_else(|| "out".into(), |n| n.to_string_lossy().into_owned());
        let staging = parent.join(format!(".{name}.partial-{}", std::process::id()));
        std::fs::create_dir_all(&staging)
            .with_context(|| format!("{}: cannot create staging folder", staging.display()))?;
        Ok(Self {
            target: target.to_path_buf(),
            staging,
            committed: false,
        })
    }

    /// Path of a file inside the staging folder.
    pub fn path(&self, file: &str) -> PathBuf {
        self.staging.join(file)
    }

    /// Move every staged file into the target folder (created if needed).
    pub fn commit(mut self) -> anyhow::Result<()> {
        std::fs::create_dir_all(&self.target)
            .with_context(|| format!("{}: cannot create output folder", self.target.display()))?;
        let entries = std::fs::read_dir(&self.staging)
            .with_context(|| format!("{}: cannot list staging folder", self.staging.display()))?;
        for entry in entries {
            let entry =
                entry.with_context(|| format!("{}: cannot list", self.staging.display()))?;
            let dest = self.target.join(entry.file_name());
            std::fs::rename(entry.path(), &dest)
                .with_context(|| format!("{}: cannot move output into place", dest.display()))?;
        }
        self.committed = true;
        let _ = std::fs::remove_dir_all(&self.staging);
        Ok(())
    }
}

impl Drop for StagedDir {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_dir_all(&self.staging);
        }
    }
}
