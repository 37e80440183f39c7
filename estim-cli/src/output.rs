//! Output folders that appear complete or not at all, and stdout that may be closed
//! or full.
//!
//! `--out DIR` ([`StagedDir`]):
//! - **Checked first.** [`StagedDir::new`] runs before any computation: it creates the
//!   folder (and missing parents), takes its lock and checks that a file can be
//!   written, or fails naming the folder.
//! - **Locked.** The run holds an exclusive lock on the folder (`flock` on the folder
//!   itself, so no lock file is left behind) until it ends: a second run on the same
//!   folder is refused instead of mixing its files with the first's.
//! - **Staged.** Files are written into a hidden staging folder inside the target
//!   (`.estim-partial-PID`; only the target needs to be writable) and moved into place
//!   by [`StagedDir::commit`], once, when every output (smoothing included) is there.
//! - **Replaced.** The commit removes the files of the previous run on that folder
//!   (listed in its `estim-files.txt`) that this run did not write, so no earlier plot
//!   lies beside the new report; files estim did not write are never touched.
//! - **Cleaned up.** On failure the staging folder is removed, and the target and the
//!   parents this run created if they are empty. SIGINT, SIGTERM and SIGHUP do the
//!   same before exiting with 128 + the signal ([`install_signal_cleanup`]); a commit
//!   in progress finishes first. A staging folder left by a process killed with
//!   SIGKILL is removed by the next run on the folder (it holds the lock, so no
//!   other live run owns one).
//!
//! stdout ([`emit`]): a closed pipe ends the program quietly with 141, a full disk
//! (or any other write error) is an error naming stdout.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use anyhow::Context;

/// Prefix of the staging folders inside an `--out` folder.
const STAGING_PREFIX: &str = ".estim-partial-";

/// The list of the files a committed run wrote, inside its `--out` folder.
pub const MANIFEST: &str = "estim-files.txt";

/// What to remove when the process is stopped by a signal: the staging folders of
/// the runs in progress and the folders they created (innermost first).
struct Pending {
    staging: PathBuf,
    created: Vec<PathBuf>,
}

static PENDING: Mutex<Vec<Pending>> = Mutex::new(Vec::new());

fn pending() -> std::sync::MutexGuard<'static, Vec<Pending>> {
    PENDING
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn remove_created(staging: &Path, created: &[PathBuf]) {
    if !staging.as_os_str().is_empty() {
        let _ = std::fs::remove_dir_all(staging);
    }
    for dir in created {
        // Only removes empty folders: never deletes anything that was there.
        let _ = std::fs::remove_dir(dir);
    }
}

/// Handle SIGINT, SIGTERM and SIGHUP on a thread of their own: remove the staging
/// folders (and folders created for `--out`) of the runs in progress, then exit with
/// 128 + the signal number. Call it first in `main`, before other threads start
/// (they inherit the blocked signal mask).
#[cfg(unix)]
pub fn install_signal_cleanup() {
    // SAFETY: sigset_t is plain data initialized by sigemptyset before use; the
    // calls only read and write the set they are given.
    unsafe {
        let mut set: libc::sigset_t = std::mem::zeroed();
        libc::sigemptyset(&mut set);
        for signal in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
            libc::sigaddset(&mut set, signal);
        }
        if libc::pthread_sigmask(libc::SIG_BLOCK, &set, std::ptr::null_mut()) != 0 {
            return;
        }
        let spawned = std::thread::Builder::new()
            .name("estim-signals".into())
            .spawn(move || loop {
                let mut signal: libc::c_int = 0;
                if libc::sigwait(&set, &mut signal) != 0 {
                    continue;
                }
                let mut list = pending();
                for p in list.drain(..) {
                    remove_created(&p.staging, &p.created);
                }
                std::process::exit(128 + signal);
            });
        if spawned.is_err() {
            // No handler thread: let the signals act as before.
            libc::pthread_sigmask(libc::SIG_UNBLOCK, &set, std::ptr::null_mut());
        }
    }
}

/// Without Unix signals, nothing to install.
#[cfg(not(unix))]
pub fn install_signal_cleanup() {}

/// A staging folder for the files of one `--out DIR`.
pub struct StagedDir {
    target: PathBuf,
    staging: PathBuf,
    /// Folders this run created (the target and missing parents), innermost first.
    created: Vec<PathBuf>,
    /// The exclusive lock on the target, held until the run ends.
    _lock: Option<std::fs::File>,
    /// A folder of this run's outputs (replaced as a whole, listed in [`MANIFEST`]),
    /// or a folder the outputs are put into beside other files ([`StagedDir::for_files`]).
    owned: bool,
    committed: bool,
    /// The run's input files and folders (canonical): the commit never replaces or
    /// removes one.
    inputs: Vec<PathBuf>,
}

impl StagedDir {
    /// Create `target` (and missing parents), lock it, remove stale staging folders
    /// and create this run's; fails (naming the target) when the target is not a
    /// writable folder or another run holds it. Call it before computing.
    pub fn new(target: &Path) -> anyhow::Result<Self> {
        if target.exists() && !target.is_dir() {
            anyhow::bail!("{}: --out exists and is not a folder", target.display());
        }
        let created: Vec<PathBuf> = target
            .ancestors()
            .filter(|a| !a.as_os_str().is_empty() && !a.exists())
            .map(Path::to_path_buf)
            .collect();
        let mut this = Self {
            target: target.to_path_buf(),
            staging: PathBuf::new(),
            created,
            _lock: None,
            owned: true,
            committed: false,
            inputs: Vec::new(),
        };
        // Registered first: a signal from here on removes what this run created.
        pending().push(Pending {
            staging: PathBuf::new(),
            created: this.created.clone(),
        });
        std::fs::create_dir_all(target)
            .with_context(|| format!("{}: cannot create the output folder", target.display()))?;
        this._lock = Some(lock(target)?);
        remove_stale_staging(target);
        let staging = target.join(format!("{STAGING_PREFIX}{}", std::process::id()));
        if let Err(e) = std::fs::create_dir(&staging) {
            anyhow::bail!("{}: output folder is not writable ({e})", target.display());
        }
        this.staging = staging.clone();
        if let Some(p) = pending()
            .iter_mut()
            .find(|p| p.staging.as_os_str().is_empty() && p.created == this.created)
        {
            p.staging = staging.clone();
        }
        // A probe file: a folder may allow mkdir but not file creation (e.g. quotas).
        let probe = staging.join(".probe");
        std::fs::write(&probe, b"")
            .with_context(|| format!("{}: output folder is not writable", target.display()))?;
        let _ = std::fs::remove_file(&probe);
        Ok(this)
    }

    /// Staging for single files put into `folder` beside files of others (e.g.
    /// `dataset beamsnet --out DIR/x.npy`): as [`StagedDir::new`] (checked first,
    /// locked, staged, cleaned up), but the commit only adds or replaces its own
    /// files and writes no [`MANIFEST`].
    pub fn for_files(folder: &Path) -> anyhow::Result<Self> {
        let mut this = Self::new(folder)?;
        this.owned = false;
        Ok(this)
    }

    /// Name the run's inputs: [`StagedDir::commit`] refuses (naming both, before
    /// moving anything) to replace or remove one of them, or a folder holding one
    /// (e.g. `--out DIR` where `DIR/solution.csv` is the `--imu` file, or an input
    /// written by an earlier run and listed in its manifest).
    pub fn keep_inputs<'a>(&mut self, inputs: impl IntoIterator<Item = &'a Path>) {
        self.inputs
            .extend(inputs.into_iter().filter_map(|p| p.canonicalize().ok()));
    }

    /// Refuse to replace or remove `dest` when it is, or holds, an input.
    fn check_not_input(&self, dest: &Path) -> anyhow::Result<()> {
        let Ok(dest) = dest.canonicalize() else {
            return Ok(());
        };
        if let Some(input) = self.inputs.iter().find(|i| i.starts_with(&dest)) {
            anyhow::bail!(
                "{}: this run's output would replace its input {}; nothing was written \
                 (choose another --out folder, or move the input out of it)",
                dest.display(),
                input.display()
            );
        }
        Ok(())
    }

    /// The folder the outputs are committed to.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Path of a file inside the staging folder.
    pub fn path(&self, file: &str) -> PathBuf {
        self.staging.join(file)
    }

    /// Move every staged file into the target folder, remove the files of the
    /// previous run there that this one did not write, and list the new ones in
    /// [`MANIFEST`]. Signals wait for it to finish.
    pub fn commit(mut self) -> anyhow::Result<()> {
        let mut list = pending();
        let mut names: Vec<std::ffi::OsString> = Vec::new();
        let entries = std::fs::read_dir(&self.staging)
            .with_context(|| format!("{}: cannot list staging folder", self.staging.display()))?;
        for entry in entries {
            let entry =
                entry.with_context(|| format!("{}: cannot list", self.staging.display()))?;
            names.push(entry.file_name());
        }
        names.sort();
        let previous = if self.owned {
            read_manifest(&self.target)
        } else {
            Vec::new()
        };
        for name in names
            .iter()
            .map(|n| n.as_os_str())
            .chain(previous.iter().map(|p| p.as_os_str()))
        {
            self.check_not_input(&self.target.join(name))?;
        }
        // What the commit replaces or removes is first moved aside into the staging
        // folder, so that a failure at any step puts everything back: the outputs of
        // a run are committed all together or not at all.
        let mut moving: Vec<PathBuf> = names.iter().map(PathBuf::from).collect();
        let mut aside: Vec<PathBuf> = previous
            .iter()
            .filter(|old| !names.iter().any(|n| n == old.as_os_str()))
            .cloned()
            .collect();
        aside.extend(moving.iter().cloned());
        if self.owned {
            let mut manifest = String::from("# written by estim: the files of the last run\n");
            for name in &names {
                manifest.push_str(&name.to_string_lossy());
                manifest.push('\n');
            }
            let staged_manifest = self.staging.join(MANIFEST);
            std::fs::write(&staged_manifest, manifest).with_context(|| {
                format!("{}: cannot write", self.target.join(MANIFEST).display())
            })?;
            moving.push(PathBuf::from(MANIFEST));
            aside.push(PathBuf::from(MANIFEST));
        }
        // An existing entry of another kind (a file where this run writes a folder)
        // is not estim's to replace.
        for name in &moving {
            let dest = self.target.join(name);
            let (Ok(old), Ok(new)) = (
                std::fs::symlink_metadata(&dest),
                std::fs::symlink_metadata(self.staging.join(name)),
            ) else {
                continue;
            };
            if old.is_dir() != new.is_dir() {
                anyhow::bail!(
                    "{}: exists and is not a {}; nothing was written",
                    dest.display(),
                    if new.is_dir() { "folder" } else { "file" }
                );
            }
        }
        let backup = self.staging.join(".replaced");
        std::fs::create_dir(&backup)
            .with_context(|| format!("{}: output folder is not writable", self.target.display()))?;
        let mut moved_aside: Vec<&PathBuf> = Vec::new();
        let mut placed: Vec<&PathBuf> = Vec::new();
        let mut result = Ok(());
        for name in &aside {
            let dest = self.target.join(name);
            if std::fs::symlink_metadata(&dest).is_err() {
                continue;
            }
            if let Err(e) = std::fs::rename(&dest, backup.join(name)) {
                result = Err(anyhow::anyhow!("{}: cannot replace: {e}", dest.display()));
                break;
            }
            moved_aside.push(name);
        }
        if result.is_ok() {
            for name in &moving {
                let dest = self.target.join(name);
                if let Err(e) = std::fs::rename(self.staging.join(name), &dest) {
                    result = Err(anyhow::anyhow!(
                        "{}: cannot move output into place: {e}",
                        dest.display()
                    ));
                    break;
                }
                placed.push(name);
            }
        }
        if let Err(e) = result {
            for name in placed.iter().rev() {
                let _ = std::fs::rename(self.target.join(name), self.staging.join(name));
            }
            for name in moved_aside.iter().rev() {
                let _ = std::fs::rename(backup.join(name), self.target.join(name));
            }
            return Err(e.context(format!(
                "{}: nothing of this run was committed; the folder is as it was",
                self.target.display()
            )));
        }
        self.committed = true;
        let _ = std::fs::remove_dir_all(&self.staging);
        list.retain(|p| p.staging != self.staging);
        drop(list);
        Ok(())
    }
}

impl Drop for StagedDir {
    fn drop(&mut self) {
        let mut list = pending();
        list.retain(|p| p.staging != self.staging || p.created != self.created);
        if !self.committed {
            remove_created(&self.staging, &self.created);
        }
    }
}

/// Refuse a single output file that is one of the inputs (compared as files: the
/// same path, a link or another spelling), naming both.
pub fn refuse_input_as_output<'a>(
    output: &Path,
    inputs: impl IntoIterator<Item = &'a PathBuf>,
) -> anyhow::Result<()> {
    let Ok(out) = output.canonicalize() else {
        // Not there yet: it cannot be an input.
        return Ok(());
    };
    for input in inputs {
        if input.canonicalize().is_ok_and(|i| i == out) {
            anyhow::bail!(
                "{}: the output would overwrite the input {}; nothing was written",
                output.display(),
                input.display()
            );
        }
    }
    Ok(())
}

/// An exclusive lock on the folder itself (no lock file to leave behind).
fn lock(target: &Path) -> anyhow::Result<std::fs::File> {
    let dir = std::fs::File::open(target)
        .with_context(|| format!("{}: cannot open the output folder", target.display()))?;
    match dir.try_lock() {
        Ok(()) => Ok(dir),
        Err(std::fs::TryLockError::WouldBlock) => anyhow::bail!(
            "{}: another estim run is writing to this --out folder; wait for it to end or \
             choose another folder",
            target.display()
        ),
        // A file system without locks: run unlocked rather than not at all.
        Err(std::fs::TryLockError::Error(_)) => Ok(dir),
    }
}

/// Staging folders in `target` are stale once this run holds the lock: every live
/// run holds the lock of the folder it stages in.
fn remove_stale_staging(target: &Path) {
    let Ok(entries) = std::fs::read_dir(target) else {
        return;
    };
    for entry in entries.flatten() {
        if entry
            .file_name()
            .to_string_lossy()
            .starts_with(STAGING_PREFIX)
        {
            let _ = std::fs::remove_dir_all(entry.path());
        }
    }
}

/// The names listed in `target`'s [`MANIFEST`] (plain names only: nothing outside
/// the folder can be named).
fn read_manifest(target: &Path) -> Vec<PathBuf> {
    let Ok(text) = std::fs::read_to_string(target.join(MANIFEST)) else {
        return Vec::new();
    };
    text.lines()
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .map(PathBuf::from)
        .filter(|p| {
            let mut parts = p.components();
            matches!(
                (parts.next(), parts.next()),
                (Some(std::path::Component::Normal(_)), None)
            )
        })
        .collect()
}

/// Write `text` to stdout. A closed stdout (the reader went away, e.g. `| head`)
/// surfaces as an `io::Error` of kind `BrokenPipe`, which `main` turns into a quiet
/// exit with status 141 (the shell's status for SIGPIPE) instead of a panic; any
/// other error (a full disk) is reported naming stdout.
pub fn emit(text: &str) -> anyhow::Result<()> {
    let mut out = std::io::stdout().lock();
    out.write_all(text.as_bytes())
        .and_then(|()| out.flush())
        .context("cannot write to stdout")?;
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

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .expect("list")
            .filter_map(|e| e.ok().map(|e| e.file_name().to_string_lossy().into_owned()))
            .collect();
        v.sort();
        v
    }

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
        assert_eq!(names(&target), ["a.csv", MANIFEST]);
        // Dropped without commit: nothing left, and a target it created is removed,
        // with the parents it created.
        let other = dir.path().join("p/q/other");
        let staged = StagedDir::new(&other).expect("writable");
        std::fs::write(staged.path("b.csv"), "x").expect("write");
        drop(staged);
        assert!(!dir.path().join("p").exists());
        // An existing target keeps its files when a run fails.
        let staged = StagedDir::new(&target).expect("writable");
        drop(staged);
        assert!(target.join("a.csv").is_file());
    }

    #[test]
    fn a_second_commit_replaces_the_first_and_keeps_foreign_files() {
        let dir = tempfile::tempdir().expect("tempdir");
        let target = dir.path().join("out");
        let staged = StagedDir::new(&target).expect("writable");
        std::fs::write(staged.path("old.csv"), "1").expect("write");
        std::fs::create_dir(staged.path("smoothing")).expect("mkdir");
        std::fs::write(staged.path("smoothing/s.csv"), "1").expect("write");
        std::fs::write(staged.path("report.json"), "1").expect("write");
        staged.commit().expect("commit");
        std::fs::write(target.join("notes.txt"), "mine").expect("write");
        std::fs::create_dir(target.join(".estim-partial-4000000")).expect("stale");
        let staged = StagedDir::new(&target).expect("writable");
        assert!(
            !target.join(".estim-partial-4000000").exists(),
            "stale staging"
        );
        std::fs::write(staged.path("report.json"), "2").expect("write");
        staged.commit().expect("commit");
        assert_eq!(names(&target), [MANIFEST, "notes.txt", "report.json"]);
        assert_eq!(
            std::fs::read_to_string(target.join("report.json"))
                .ok()
                .as_deref(),
            Some("2")
        );
    }

    #[test]
    fn a_commit_that_cannot_complete_leaves_the_folder_as_it_was() {
        let dir = tempfile::tempdir().expect("tempdir");
        let target = dir.path().join("out");
        let staged = StagedDir::new(&target).expect("writable");
        std::fs::write(staged.path("report.json"), "1").expect("write");
        staged.commit().expect("commit");
        // A file where this run puts a folder: refused before anything moves.
        std::fs::write(target.join("smoothing"), "mine").expect("write");
        let staged = StagedDir::new(&target).expect("writable");
        std::fs::write(staged.path("report.json"), "2").expect("write");
        std::fs::create_dir(staged.path("smoothing")).expect("mkdir");
        let e = staged.commit().expect_err("refused").to_string();
        assert!(e.contains("smoothing"), "{e}");
        assert_eq!(names(&target), [MANIFEST, "report.json", "smoothing"]);
        assert_eq!(
            std::fs::read_to_string(target.join("report.json"))
                .ok()
                .as_deref(),
            Some("1")
        );
    }

    #[test]
    fn a_commit_never_replaces_or_removes_an_input() {
        let dir = tempfile::tempdir().expect("tempdir");
        let target = dir.path().join("out");
        let staged = StagedDir::new(&target).expect("writable");
        std::fs::write(staged.path("a.csv"), "1").expect("write");
        std::fs::write(staged.path("b.csv"), "1").expect("write");
        staged.commit().expect("commit");
        for (input, writes) in [("a.csv", "a.csv"), ("b.csv", "c.csv")] {
            let mut staged = StagedDir::new(&target).expect("writable");
            staged.keep_inputs([target.join(input).as_path()]);
            std::fs::write(staged.path(writes), "2").expect("write");
            let e = staged.commit().expect_err("refused").to_string();
            assert!(e.contains(input) && e.contains("input"), "{e}");
            assert_eq!(names(&target), ["a.csv", "b.csv", MANIFEST]);
        }
    }

    #[test]
    fn a_locked_folder_is_refused() {
        let dir = tempfile::tempdir().expect("tempdir");
        let first = StagedDir::new(dir.path()).expect("writable");
        // flock locks belong to the open file: a second open in this process conflicts.
        let e = StagedDir::new(dir.path())
            .err()
            .expect("locked")
            .to_string();
        assert!(e.contains("another estim run"), "{e}");
        drop(first);
        assert!(StagedDir::new(dir.path()).is_ok());
    }
}
