//! The one JSON schema of every `--json` output, and the exit statuses.
//!
//! Every document is an object with
//! - `schema_version` (integer, [`SCHEMA_VERSION`]), `estim_version` (the crate
//!   version), `command` (e.g. `"reproduce"`),
//! - `inputs`: the paths, seeds and configuration the result depends on,
//! - `status`: `"ok"`, or `"filters_failed"` when at least one filter variant stopped
//!   (its failure is listed; the other variants' results are complete),
//! - the command's own fields. Filter variants are arrays of objects, each with a
//!   stable `id` (`ls`, `beamsnet_m_neglected`, `beamsnet_m_rho`, `beamsnet_m_network`,
//!   `oracle_m_neglected`, `oracle_m_true`, `oracle_m_rho`) and a human `label` that
//!   states the rho actually used. Numeric fields carry their unit in the name
//!   (`position_rmse_m`, `rmse_mps`, `time_s`, `vaf_percent`); a value that is not
//!   defined is `null`. Each quantity has one field.
//!
//! `montecarlo` (without `--learned two-beams|outage`), per entry of `variants`:
//! - `runs_completed`, `failures`; the statistics below are over the completed runs;
//! - `nees_average` \[-\]: the 15-state NEES averaged over the runs at each DVL epoch,
//!   then over the epochs where that run-average is defined (none where some run's P
//!   was not positive definite);
//! - `nees_band` \[-\]: the 95 % band of a run-average of chi-square(15) at one epoch
//!   (it narrows with the number of runs);
//! - `nees_epochs_in_band_percent` \[%\]: share of the DVL epochs whose run-averaged
//!   NEES lies in `nees_band` (95 expected); an epoch with no run-average counts as out;
//! - `nis_average`, `nis_band`, `nis_epochs_in_band_percent`: the same for the 3-dof
//!   NIS over the updates;
//! - `covariance_not_positive_definite_epochs`, `updates_rejected`: counts summed over
//!   the runs;
//! - `position_rmse_m` \[m\], `velocity_rmse_mps` \[m/s\]: per run the RMSE over its
//!   DVL epochs of the error norm; `mean` over the runs, `lo` / `hi` the 2.5 / 97.5
//!   percentiles over the runs (a spread of the runs, not a confidence interval);
//! - `output_imu_correlation` \[-\]: BeamsNet variants with the network's sensitivity:
//!   the mean over runs and epochs of the largest output / IMU-error correlation
//!   coefficient; `null` otherwise.
//!
//! Exit statuses: 0 everything completed; 2 bad input or usage (nothing computed,
//! nothing written); 3 some filter variant failed while the others completed (results
//! written and printed, failures listed); 141 stdout was closed by the reader (quiet,
//! as a process killed by SIGPIPE would appear in a shell).

use serde_json::{json, Map, Value};

/// Version of the JSON schema; bumped on any incompatible change.
pub const SCHEMA_VERSION: u32 = 2;

/// Exit status: everything completed.
pub const EXIT_OK: u8 = 0;
/// Exit status: bad input or usage.
pub const EXIT_BAD_INPUT: u8 = 2;
/// Exit status: at least one filter variant failed, the others completed.
pub const EXIT_FILTERS_FAILED: u8 = 3;
/// Exit status: stdout closed by the reader (128 + SIGPIPE).
pub const EXIT_BROKEN_PIPE: u8 = 141;

/// Returned by a command whose results are complete except for failed filter
/// variants (already reported in its output): `main` exits with
/// [`EXIT_FILTERS_FAILED`].
#[derive(Debug, thiserror::Error)]
#[error("{count} filter run(s) failed (listed above); the other results are complete")]
pub struct FiltersFailed {
    /// Number of failed filter runs.
    pub count: usize,
}

/// `Ok(())`, or [`FiltersFailed`] when `count > 0`.
/// A navigation run stopped before its end (diverged, or a numerical failure of the
/// filter): exit 3, with what was solved before the stop written and marked partial.
#[derive(Debug, thiserror::Error)]
#[error("{message}")]
pub struct RunStopped {
    /// What stopped it, and what was kept.
    pub message: String,
}

pub fn status_result(count: usize) -> anyhow::Result<()> {
    if count == 0 {
        Ok(())
    } else {
        Err(FiltersFailed { count }.into())
    }
}

/// The JSON document of `command`: the common header, then the fields of `body`
/// (an object).
pub fn document(command: &str, inputs: Value, failures: usize, body: Value) -> Value {
    let mut out = Map::new();
    out.insert("schema_version".into(), json!(SCHEMA_VERSION));
    out.insert("estim_version".into(), json!(env!("CARGO_PKG_VERSION")));
    out.insert("command".into(), json!(command));
    out.insert("inputs".into(), inputs);
    out.insert(
        "status".into(),
        json!(if failures == 0 {
            "ok"
        } else {
            "filters_failed"
        }),
    );
    if let Value::Object(fields) = body {
        for (k, v) in fields {
            out.insert(k, v);
        }
    }
    Value::Object(out)
}

/// A path as JSON (lossy UTF-8), or `null`.
pub fn path_json(path: Option<&std::path::Path>) -> Value {
    path.map_or(Value::Null, |p| json!(p.to_string_lossy()))
}

/// Most missions of `montecarlo --runs` (about 1.5 h on two cores at the default
/// 400 s mission; larger studies run in shards joined by `estim montecarlo merge`).
pub const MAX_RUNS: usize = 10_000;

/// Most draws of `montecarlo --empirical-realizations` and realizations of
/// `dataset beamsnet --realizations`.
pub const MAX_REALIZATIONS: usize = 10_000;

/// `value` of `flag` within `[min, max]`, or an error naming the flag and the bounds.
pub fn check_count(flag: &str, value: usize, min: usize, max: usize) -> anyhow::Result<()> {
    if (min..=max).contains(&value) {
        Ok(())
    } else {
        anyhow::bail!("{flag} {value} is outside [{min}, {max}]")
    }
}

/// The seeds `first ..= first + span` all at most [`crate::experiment::MAX_SEED`] (2^53):
/// a seed never wraps around to 0, and JSON readers keep every seed exactly.
pub fn check_seeds(flag: &str, first: u64, span: u64) -> anyhow::Result<()> {
    let max = crate::experiment::MAX_SEED;
    match first.checked_add(span) {
        Some(last) if last <= max => Ok(()),
        _ => anyhow::bail!(
            "{flag} {first}: the seeds used run up to {first} + {span}, above {max} (2^53, \
             the largest seed; seeds never wrap around)"
        ),
    }
}
