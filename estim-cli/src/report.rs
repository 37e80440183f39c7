//! `estim report`: regenerate the result tables (docs/results.md) from seeded runs.

use std::fmt::Write as _;
use std::path::PathBuf;

use crate::study::markdown::{
    default_beamsnet, learned_seed_tables, long_run_tables, monte_carlo_table, recorded_tables,
    results_tables, seed_interval_tables, splice, Table,
};
use crate::study::Config;
use anyhow::Context;
use estim::datasets::{akit_dir, data_root};

/// Arguments of `estim report`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Print every generated table as markdown between its markers
    /// (`<!-- estim-report:NAME begin -->` ... `end -->`); the default output.
    #[arg(long)]
    markdown: bool,
    /// Folder holding A-KIT `TrajectoryN/` (or a data root holding `a-kit/`); default:
    /// `ESTIM_DATA_DIR`, then `../shared/data`. Without data the A-KIT tables are
    /// skipped (said on stderr).
    #[arg(long, value_name = "DIR")]
    data: Option<PathBuf>,
    /// Folder of the long-run logs (fuzzing, 10-hour mission).
    #[arg(long, value_name = "DIR", default_value = "results")]
    results: PathBuf,
    /// Replace the marked regions of this file (docs/results.md) with the fresh tables;
    /// nothing else in it changes.
    #[arg(long, value_name = "FILE")]
    write: Option<PathBuf>,
}

/// Run it.
pub fn run(args: Args) -> anyhow::Result<()> {
    // The tables are the defaults' (no --config on purpose).
    let config = Config::default();
    let learned = default_beamsnet(&config)?;
    let mut tables: Vec<Table> = Vec::new();
    let akit = match &args.data {
        Some(dir) => Some(akit_dir(dir)?),
        None => data_root(None).and_then(|d| akit_dir(&d).ok()),
    };
    match akit {
        Some(dir) => {
            tables.extend(results_tables(&config, &dir, learned.as_ref())?);
            tables.extend(seed_interval_tables(&config, &dir, learned.as_ref())?);
            tables.extend(learned_seed_tables(&config, &dir)?);
            tables.extend(recorded_tables(&config, &dir, learned.as_ref())?);
        }
        None => eprintln!(
            "note: A-KIT data not found (--data, ESTIM_DATA_DIR, ../shared/data): \
             velocity, filters, paper-std, rho and their -seeds tables, \
             two-beams-seeds, outage-seeds, recorded-imu and recorded-imu-paired skipped"
        ),
    }
    tables.push(monte_carlo_table(&config, learned.as_ref())?);
    if args.results.is_dir() {
        tables.extend(long_run_tables(&args.results)?);
    } else {
        eprintln!(
            "note: {} not found: fuzz and long-mission tables skipped",
            args.results.display()
        );
    }
    if let Some(path) = &args.write {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("{}: cannot read", path.display()))?;
        let spliced = splice(&text, &tables).with_context(|| path.display().to_string())?;
        // Write beside it and rename: the file is either the old or the new one.
        let staging = path.with_extension(format!("partial-{}", std::process::id()));
        std::fs::write(&staging, &spliced)
            .with_context(|| format!("{}: cannot write", staging.display()))?;
        std::fs::rename(&staging, path).with_context(|| {
            let _ = std::fs::remove_file(&staging);
            format!("{}: cannot replace", path.display())
        })?;
        let names: Vec<&str> = tables.iter().map(|t| t.name).collect();
        eprintln!("{}: regions {} rewritten", path.display(), names.join(", "));
    }
    if args.markdown || args.write.is_none() {
        let mut out = String::new();
        for t in &tables {
            writeln!(out, "{}", t.with_markers())?;
        }
        crate::output::emit(&out)?;
    }
    Ok(())
}
