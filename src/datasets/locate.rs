//! Finding the data: a CLI flag, then `ESTIM_DATA_DIR`, then `../shared/data`.

use std::path::{Path, PathBuf};

use super::{DatasetError, Result};

/// Environment variable naming the data root (the folder holding `a-kit/` and `beamsnet/`).
pub const DATA_DIR_ENV: &str = "ESTIM_DATA_DIR";

/// The data root: `flag` if given, else `$ESTIM_DATA_DIR`, else `../shared/data` if it
/// exists (relative to the current directory). `None` if none applies.
pub fn data_root(flag: Option<&Path>) -> Option<PathBuf> {
    if let Some(p) = flag {
        return Some(p.to_path_buf());
    }
    if let Some(p) = std::env::var_os(DATA_DIR_ENV) {
        return Some(PathBuf::from(p));
    }
    let shared = Path::new("../shared/data");
    shared.is_dir().then(|| shared.to_path_buf())
}

/// The folder holding `TrajectoryN/`: `dir` itself if it holds trajectories, else `dir/a-kit`.
pub fn akit_dir(dir: &Path) -> Result<PathBuf> {
    if !dir.is_dir() {
        return Err(DatasetError::Missing {
            path: dir.to_path_buf(),
            what: "data folder not found".into(),
        });
    }
    let holds = |d: &Path| {
        std::fs::read_dir(d).is_ok_and(|mut it| {
            it.any(|e| e.is_ok_and(|e| e.file_name().to_string_lossy().starts_with("Trajectory")))
        })
    };
    if holds(dir) {
        return Ok(dir.to_path_buf());
    }
    let sub = dir.join("a-kit");
    if holds(&sub) {
        return Ok(sub);
    }
    Err(DatasetError::Missing {
        path: dir.to_path_buf(),
        what: "holds no TrajectoryN/ folder (nor a-kit/TrajectoryN/)".into(),
    })
}

/// Paths of one A-KIT trajectory's files.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TrajectoryFiles {
    /// `GT_trajectoryN.csv`.
    pub gt: PathBuf,
    /// `DVL_trajectoryN.csv`.
    pub dvl: PathBuf,
}

/// The files of trajectory `n` under `dir` (see [`akit_dir`]); both must exist.
pub fn trajectory_files(dir: &Path, n: u32) -> Result<TrajectoryFiles> {
    let base = akit_dir(dir)?.join(format!("Trajectory{n}"));
    let files = TrajectoryFiles {
        gt: base.join(format!("GT_trajectory{n}.csv")),
        dvl: base.join(format!("DVL_trajectory{n}.csv")),
    };
    for p in [&files.gt, &files.dvl] {
        if !p.is_file() {
            return Err(DatasetError::Missing {
                path: p.clone(),
                what: "file not found".into(),
            });
        }
    }
    Ok(files)
}
