//! The result tables of docs/results.md, regenerated from seeded runs (`estim report --markdown`).
//!
//! Each table is a named region of docs/results.md between two HTML comments,
//! `<!-- estim-report:NAME begin -->` and `<!-- estim-report:NAME end -->`;
//! [`splice`] replaces exactly those regions and [`region`] reads one back, so a test
//! can compare docs/results.md with a fresh run byte for byte.
//!
//! Sources:
//! - [`results_tables`]: `velocity`, `filters`, `paper-std`, `rho`: the default
//!   configuration on A-KIT trajectories 4 and 13 and the embedded simulated mission
//!   (what `estim reproduce` runs), the paper's heuristic M on both bases
//!   ([`PaperMBasis`]). Needs the A-KIT data.
//! - [`seed_interval_tables`]: `filters-seeds`, `velocity-seeds`, `paper-std-seeds`,
//!   `rho-seeds`: the rows of `filters`, `velocity`, `paper-std` and `rho` over
//!   [`SEED_INTERVAL_SEEDS`] seeds from [`SEED_INTERVAL_FIRST_SEED`] (IMU synthesis,
//!   initial error and beam noise redrawn per seed): mean and 95 % interval (2.5 / 97.5
//!   percentiles, linear interpolation). Needs the A-KIT data.
//! - [`learned_seed_tables`]: `two-beams-seeds`, `outage-seeds`: the A-KIT rows of
//!   `estim reproduce --scenario two-beams|outage` over the same seeds. Needs the A-KIT
//!   data.
//! - [`monte_carlo_table`]: `montecarlo`, [`MONTE_CARLO_RUNS`] simulated missions from
//!   seed [`MONTE_CARLO_FIRST_SEED`] (what `estim montecarlo --runs 20` runs).
//! - [`long_run_tables`]: `fuzz` and `long-mission`, rendered from the committed logs
//!   of the long runs in `results/` (those runs take minutes; their logs carry the
//!   commit they ran on).
//!
//! Rounding (stated once, used everywhere): velocity metrics with 6 decimals (VAF 4;
//! in the seed table RMSE and MAE in mm/s with 3 decimals, the same digits);
//! position errors 2 decimals \[m\], velocity errors 3 decimals \[m/s\]; NEES and NIS
//! averages of filters with 3 significant digits, of the Monte Carlo with 2 decimals;
//! percentages with 1 decimal; rho with 3 decimals; counts exact (their mean over seeds
//! with 1 decimal); learned-scenario tables: NEES and NIS 2 decimals, position error 3,
//! velocity error 4. Log figures are
//! quoted as the log prints them.

mod long_runs;
mod recorded;
mod results;
mod seeds;

pub use long_runs::long_run_tables;
pub use recorded::recorded_tables;
pub use results::{default_beamsnet, median_min_max, monte_carlo_table, results_tables};
pub use seeds::{learned_seed_tables, seed_interval_tables};

use super::{PipelineError, Result};

/// Missions of the Monte Carlo table.
pub const MONTE_CARLO_RUNS: usize = 20;
/// Seed of its first mission (missions use seeds 1000..1019).
pub const MONTE_CARLO_FIRST_SEED: u64 = 1000;
/// Seeds of the `filters-seeds` table.
pub const SEED_INTERVAL_SEEDS: usize = 20;
/// Its first seed (seeds 2000..2019).
pub const SEED_INTERVAL_FIRST_SEED: u64 = 2000;
/// A-KIT trajectories of the results (the paper's "Trajectory #1" and "#2").
pub const AKIT_TRAJECTORIES: [u32; 2] = [4, 13];

/// One generated region of docs/results.md.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Table {
    /// Region name (`<!-- estim-report:NAME begin -->`).
    pub name: &'static str,
    /// The markdown between the markers, ending with a newline.
    pub markdown: String,
}

/// The begin marker of region `name`.
pub fn begin_marker(name: &str) -> String {
    format!("<!-- estim-report:{name} begin -->")
}

/// The end marker of region `name`.
pub fn end_marker(name: &str) -> String {
    format!("<!-- estim-report:{name} end -->")
}

impl Table {
    /// The region with its markers, as `estim report --markdown` prints it.
    pub fn with_markers(&self) -> String {
        format!(
            "{}\n{}{}\n",
            begin_marker(self.name),
            self.markdown,
            end_marker(self.name)
        )
    }
}

/// Byte range of the content of region `name` in `text` (between the line of the
/// begin marker and the line of the end marker). Errors when a marker is missing,
/// repeated, or out of order.
fn region_range(text: &str, name: &str) -> Result<std::ops::Range<usize>> {
    let region_error = |reason: String| PipelineError::Region {
        region: name.into(),
        reason,
    };
    let find_line = |marker: &str| -> Result<usize> {
        // A marker is a whole line: text that merely quotes it does not count.
        let line = format!("{marker}\n");
        let mut hits = text
            .match_indices(&line)
            .map(|(i, _)| i)
            .filter(|i| *i == 0 || text.as_bytes()[i - 1] == b'\n');
        let first = hits
            .next()
            .ok_or_else(|| region_error(format!("marker line {marker:?} not found")))?;
        if hits.next().is_some() {
            return Err(region_error(format!(
                "marker line {marker:?} appears more than once"
            )));
        }
        Ok(first)
    };
    let begin = find_line(&begin_marker(name))?;
    let end = find_line(&end_marker(name))?;
    let start = begin + begin_marker(name).len() + 1;
    if end < start {
        return Err(region_error("end marker before begin marker".into()));
    }
    Ok(start..end)
}

/// The content of region `name` in `text` (the study's tests compare regions).
///
/// # Errors
/// A missing, repeated or misordered marker.
#[cfg(test)]
pub fn region<'a>(text: &'a str, name: &str) -> Result<&'a str> {
    Ok(&text[region_range(text, name)?])
}

/// `text` with each table's region replaced by its markdown; nothing else changes.
///
/// # Errors
/// A missing, repeated or misordered marker of any table (then nothing is replaced).
pub fn splice(text: &str, tables: &[Table]) -> Result<String> {
    let mut ranges = tables
        .iter()
        .map(|t| Ok((region_range(text, t.name)?, t)))
        .collect::<Result<Vec<_>>>()?;
    ranges.sort_by_key(|(r, _)| r.start);
    let mut out = String::with_capacity(text.len());
    let mut at = 0;
    for (range, table) in ranges {
        if range.start < at {
            return Err(PipelineError::Region {
                region: table.name.into(),
                reason: "overlaps another region".into(),
            });
        }
        out.push_str(&text[at..range.start]);
        out.push_str(&table.markdown);
        at = range.end;
    }
    out.push_str(&text[at..]);
    Ok(out)
}

/// `x` with `digits` significant digits, in positional notation ("n/a" if not finite).
pub fn significant(x: f64, digits: usize) -> String {
    if !x.is_finite() {
        return "n/a".into();
    }
    if x == 0.0 {
        return format!("{:.*}", digits.saturating_sub(1), 0.0);
    }
    let magnitude = x.abs().log10().floor() as i64;
    let decimals = (digits as i64 - 1 - magnitude).max(0) as usize;
    // Rounding can carry into the next decade (9.995 -> 10.0): format again.
    let text = format!("{x:.decimals$}");
    let rounded: f64 = text.parse().unwrap_or(x);
    let magnitude_after = rounded.abs().log10().floor() as i64;
    if magnitude_after > magnitude {
        let decimals = (digits as i64 - 1 - magnitude_after).max(0) as usize;
        format!("{rounded:.decimals$}")
    } else {
        text
    }
}

/// `x` with one decimal, without the sign of a value that rounds to zero ("-0.0").
pub fn one_decimal(x: f64) -> String {
    let text = format!("{x:.1}");
    if text == "-0.0" {
        "0.0".into()
    } else {
        text
    }
}

/// `n` with thousands separators (7,703).
pub fn thousands(n: usize) -> String {
    let digits = n.to_string();
    let mut out = String::with_capacity(digits.len() + digits.len() / 3);
    for (i, c) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splice_replaces_only_the_regions() {
        let text = "a\n<!-- estim-report:x begin -->\nold\n<!-- estim-report:x end -->\nb\n\
                    <!-- estim-report:y begin -->\n<!-- estim-report:y end -->\nc";
        let tables = [
            Table {
                name: "y",
                markdown: "Y\n".into(),
            },
            Table {
                name: "x",
                markdown: "X1\nX2\n".into(),
            },
        ];
        let out = splice(text, &tables).expect("markers present");
        assert_eq!(
            out,
            "a\n<!-- estim-report:x begin -->\nX1\nX2\n<!-- estim-report:x end -->\nb\n\
             <!-- estim-report:y begin -->\nY\n<!-- estim-report:y end -->\nc"
        );
        assert_eq!(region(&out, "x").expect("present"), "X1\nX2\n");
        // Splicing the same tables again changes nothing.
        assert_eq!(splice(&out, &tables).expect("present"), out);
    }

    #[test]
    fn splice_refuses_missing_repeated_or_misordered_markers() {
        let t = [Table {
            name: "x",
            markdown: String::new(),
        }];
        assert!(splice("no markers\n", &t).is_err());
        let twice = "<!-- estim-report:x begin -->\n<!-- estim-report:x begin -->\n<!-- estim-report:x end -->\n";
        assert!(splice(twice, &t).is_err());
        let reversed = "<!-- estim-report:x end -->\n<!-- estim-report:x begin -->\n";
        assert!(splice(reversed, &t).is_err());
    }

    #[test]
    fn number_formats() {
        assert_eq!(significant(42.63, 3), "42.6");
        assert_eq!(significant(473.2, 3), "473");
        assert_eq!(significant(12.0, 3), "12.0");
        assert_eq!(significant(9.996, 3), "10.0");
        assert_eq!(significant(0.0123456, 3), "0.0123");
        assert_eq!(significant(f64::NAN, 3), "n/a");
        assert_eq!(one_decimal(-0.04), "0.0");
        assert_eq!(one_decimal(-0.05), "-0.1");
        assert_eq!(thousands(0), "0");
        assert_eq!(thousands(999), "999");
        assert_eq!(thousands(7703), "7,703");
        assert_eq!(thousands(3_636_000), "3,636,000");
        assert_eq!(median_min_max(&[3.0, f64::NAN, 1.0, 2.0]), [2.0, 1.0, 3.0]);
    }

    #[test]
    fn logs_render_and_bad_logs_name_file_and_line() {
        let dir = std::env::temp_dir().join(format!("estim-md-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let hash = "0123456789abcdef0123456789abcdef01234567";
        std::fs::write(
            dir.join("fuzz_parsers-gt_loader_survives_mutations.log"),
            format!(
                "{hash} ESTIM_FUZZ_CASES=1000000 cargo test --release --bin estim study::tests::fuzz_parsers\n\
                 running 1 test\ntest gt_loader_survives_mutations ... ok\n\n\
                 test result: ok. 1 passed; 0 failed; 0 ignored; 0 measured; 11 filtered out; finished in 58.71s\n"
            ),
        )
        .expect("write");
        std::fs::write(
            dir.join("long_mission-10h.log"),
            format!(
                "{hash} cargo test --release --bin estim study::tests::long_mission -- --ignored --nocapture\n\
                 test ten_hour ... ignored, 10-hour mission: about 75 s; run with --ignored\n\
                 10 h mission: 3600001 IMU steps, 36000 DVL epochs, generated in 70.2 s\n\
                 Zero                     run   25.1 s; 3636000 checks, Cholesky failures 0, non-finite 0, max asymmetry 1.1e-14, min eigenvalue of P 4.230e-12, of its correlation matrix 8.000e-3\n\
                 {:<24} updates 36000 accepted / 0 gated; joint covariance min eigenvalue 1.330e-1; final position error 43.5 m\n\
                 test result: ok. 1 passed; 0 failed; 0 ignored; 0 measured; 1 filtered out; finished in 120.00s\n",
                ""
            ),
        )
        .expect("write");
        let tables = long_run_tables(&dir).expect("valid logs");
        assert!(tables[0].markdown.contains(
            "| A-KIT GT CSV (`datasets::parse_gt`) | mutations of a valid file | 1,000,000 | 0 | 59 s |"
        ));
        assert!(tables[1].markdown.contains(
            "| 10 h | `Zero` (M neglected) | 3,636,000 | 0 | 0 | 1.1e-14 | 4.230e-12 | 8.000e-3 | 1.330e-1 | 25.1 s | 43.5 m |"
        ));
        std::fs::write(dir.join("long_mission-1h.log"), "not a hash\n").expect("write");
        let e = long_run_tables(&dir).unwrap_err().to_string();
        assert!(e.contains("long_mission-1h.log:1"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
