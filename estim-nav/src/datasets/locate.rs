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

/// The numbers of the complete trajectories (`TrajectoryN/` holding both files)
/// under an A-KIT folder, in increasing order.
pub fn trajectories_in(akit: &Path) -> Vec<u32> {
    let mut found: Vec<u32> = std::fs::read_dir(akit)
        .map(|entries| {
            entries
                .filter_map(|e| e.ok())
                .filter_map(|e| {
                    e.file_name()
                        .to_str()?
                        .strip_prefix("Trajectory")?
                        .parse::<u32>()
                        .ok()
                })
                .filter(|&n| files_in(akit, n).iter().all(|p| p.is_file()))
                .collect()
        })
        .unwrap_or_default();
    found.sort_unstable();
    found
}

fn files_in(akit: &Path, n: u32) -> [PathBuf; 2] {
    let base = akit.join(format!("Trajectory{n}"));
    [
        base.join(format!("GT_trajectory{n}.csv")),
        base.join(format!("DVL_trajectory{n}.csv")),
    ]
}

/// The files of trajectory `n` under `dir` (see [`akit_dir`]); both must exist.
///
/// # Errors
/// [`DatasetError::Missing`] naming the file looked for and listing the trajectories
/// that the folder does hold.
pub fn trajectory_files(dir: &Path, n: u32) -> Result<TrajectoryFiles> {
    let akit = akit_dir(dir)?;
    let [gt, dvl] = files_in(&akit, n);
    for p in [&gt, &dvl] {
        if !p.is_file() {
            let found = trajectories_in(&akit);
            let list = if found.is_empty() {
                "none complete".to_string()
            } else {
                found
                    .iter()
                    .map(u32::to_string)
                    .collect::<Vec<_>>()
                    .join(", ")
            };
            return Err(DatasetError::Missing {
                path: p.clone(),
                what: format!("file not found; trajectories found: {list}"),
            });
        }
    }
    Ok(TrajectoryFiles { gt, dvl })
}
