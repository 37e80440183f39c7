//! `estim where-m`: where the exact cross-covariance M changes the filter (IMU grade x
//! DVL noise x sensor type; docs/results.md "Where M matters").

use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use crate::output::emit;
use crate::schema::document;
use crate::study::where_m::{markdown, where_m, DvlNoise, SensorKind, FLAG_THRESHOLD};
use crate::study::{Config, GRADES, MISSION_DURATION_S};

/// Arguments of `estim where-m`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Simulated missions per IMU grade (every cell of a grade filters the same
    /// missions).
    #[arg(long, default_value_t = 100)]
    runs: usize,
    /// Seed of the first mission (missions use seeds S, S+1, ..., S+runs-1).
    #[arg(long = "first-seed", value_name = "S", default_value_t = 1000)]
    first_seed: u64,
    /// JSON on stdout.
    #[arg(long)]
    json: bool,
}

/// Run it.
pub fn run(args: Args) -> anyhow::Result<()> {
    crate::schema::check_count("--runs", args.runs, 1, crate::schema::MAX_RUNS)?;
    crate::schema::check_seeds("--first-seed", args.first_seed, args.runs as u64 - 1)?;
    let mut config = Config::default();
    config.mission.duration_s = MISSION_DURATION_S;
    let start = Instant::now();
    // Progress on stderr (stdout stays clean): a line per tenth of the missions.
    let total = args.runs * GRADES.len();
    let done = AtomicUsize::new(0);
    let tick = || {
        let n = done.fetch_add(1, Ordering::SeqCst) + 1;
        if n * 10 / total != (n - 1) * 10 / total {
            eprintln!(
                "where-m: {n}/{total} missions done ({:.0} s)",
                start.elapsed().as_secs_f64()
            );
        }
    };
    let report = where_m(
        &config,
        &GRADES,
        &DvlNoise::ALL,
        &SensorKind::ALL,
        args.runs,
        args.first_seed,
        &tick,
    )?;
    let wall_s = start.elapsed().as_secs_f64();
    if args.json {
        let inputs = serde_json::json!({
            "runs": args.runs,
            "first_seed": args.first_seed,
            "seeds": [args.first_seed, args.first_seed + args.runs as u64 - 1],
            "mission_duration_s": MISSION_DURATION_S,
            // Simulated missions: the IMU is synthesized from each mission's truth.
            "imu_source": "synthesized",
        });
        let doc = document("where-m", inputs, 0, serde_json::to_value(&report)?);
        emit(&format!("{}\n", serde_json::to_string_pretty(&doc)?))?;
    } else {
        let text = format!(
            "Where M matters: {} simulated missions of {} s per IMU grade (seeds {}-{}), \
             {} DVL epochs each, innovation gate off; per cell the same missions filtered \
             with the exact M and with M neglected. change = (exact - neglected) / \
             neglected; flagged when some |change| > {:.0} %. NEES band (95 %, run-average \
             of chi-square(15) at one epoch): {:.2}-{:.2}. {:.0} s wall.\n\n{}",
            report.runs,
            report.mission_duration_s,
            report.first_seed,
            report.first_seed + report.runs as u64 - 1,
            report.epochs,
            100.0 * FLAG_THRESHOLD,
            report.cells.first().map_or(f64::NAN, |c| c.nees_band[0]),
            report.cells.first().map_or(f64::NAN, |c| c.nees_band[1]),
            wall_s,
            markdown(&report)
        );
        emit(&text)?;
    }
    Ok(())
}
