//! Output folders that appear complete or not at all, and stdout that may be closed.
//!
//! Files are written into a hidden staging folder inside the target and moved into
//! the target only when everything succeeded; on failure the staging folder is
//! removed (and the target too, if this run created it and it is empty), so `--out`
//! never holds partial output. Staging inside the target means only the target needs
//! to be writable, and [`StagedDir::new`] checks that before any work is done.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::Context;

/// A staging folder for the files of one `--out DIR`.
pub struct StagedDir {
    target: PathBuf,
    staging: PathBuf,
    created_target: bool,
    committed: bool,
}

impl StagedDir {
    /// Create `target` if needed and a staging folder inside it; fails (naming the
    /// target) when the target is not a writable folder. Call it before computing.
    pub fn new(target: &Path) -> anyhow::Result<Self> {
        if target.exists() && !target.is_dir() {
            anyhow::bail!("{}: --out exists and is not a folder", target.display());
        }
        let created_target = !target.exists();
        std::fs::create_dir_all(target)
            .with_context(|| format!("{}: cannot create the output folder", target.display()))?;
        let staging = target.join(format!(".estim-partial-{}", std::process::id()));
        let mut this = Self {
            target: target.to_path_buf(),
            staging: staging.clone(),
            created_target,
            committed: false,
        };
        if let Err(e) = std::fs::create_dir(&staging) {
            // Nothing of ours is left behind (Drop removes a target we created).
            this.staging = PathBuf::new();
            return Err(anyhow::anyhow!(
                "{}: output folder is not writable ({e})",
                target.display()
            ));
        }
        // A probe file: a folder may allow mkdir but not file creation (e.g. quotas).
        let probe = staging.join(".probe");
        std::fs::write(&probe, b"")
            .with_context(|| format!("{}: output folder is not writable", target.display()))?;
        let _ = std::fs::remove_file(&probe);
        Ok(this)
    }

    /// Path of a file inside the staging folder.
    pub fn path(&self, file: &str) -> PathBuf {
        self.staging.join(file)
    }

    /// Move every staged file into the target folder.
    pub fn commit(mut self) -> anyhow::Result<()> {
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
            if !self.staging.as_os_str().is_empty() {
                let _ = std::fs::remove_dir_all(&self.staging);
            }
            if self.created_target {
                // Only removes it when empty: never deletes anything that was there.
                let _ = std::fs::remove_dir(&self.target);
            }
        }
    }
}

/// Write `text` to stdout. A closed stdout (the reader went away, e.g. `| head`)
/// surfaces as an `io::Error` of kind `BrokenPipe`, which `main` turns into a quiet
/// exit with status 141 (the shell's status for SIGPIPE) instead of a panic.
pub fn emit(text: &str) -> anyhow::Result<()> {
    let mut out = std::io::stdout().lock();
    out.write_all(text.as_bytes())?;
    out.flush()?;
    Ok(())
}

/// Whether `e` (or any error in its chain) is a broken pipe on stdout.
pub fn is_broken_pipe(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn files_are_staged_inside_the_target_and_appear_on_commit() {
        let dir = tempfile::tempdir().expect("tempdir");
        let target = dir.path().join("out");
        let staged = StagedDir::new(&target).expect("writable");
        let file = staged.path("a.csv");
        // Inside the target: only the target needs to be writable.
        assert_eq!(file.parent().and_then(Path::parent), Some(target.as_path()));
        std::fs::write(&file, "x").expect("write");
        assert!(!target.join("a.csv").exists(), "visible before commit");
        staged.commit().expect("commit");
        assert!(target.join("a.csv").is_file());
        let names: Vec<_> = std::fs::read_dir(&target)
            .expect("list")
            .filter_map(|e| e.ok().map(|e| e.file_name()))
            .collect();
        assert_eq!(names.len(), 1, "{names:?}");
        // Dropped without commit: nothing left, and a target it created is removed.
        let other = dir.path().join("other");
        let staged = StagedDir::new(&other).expect("writable");
        std::fs::write(staged.path("b.csv"), "x").expect("write");
        drop(staged);
        assert!(!other.exists());
        // An existing target keeps its files when a run fails.
        let staged = StagedDir::new(&target).expect("writable");
        drop(staged);
        assert!(target.join("a.csv").is_file());
    }
}
