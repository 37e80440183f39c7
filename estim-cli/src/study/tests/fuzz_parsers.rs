//! Fuzzing on stable Rust: proptest-driven arbitrary bytes and structure-aware
//! mutations of valid inputs for every parser a user feeds.
//!
//! Property: no panic; either a typed error or a parse whose rows satisfy the
//! parser's own validation rules (finite values, strictly increasing time).
//!
//! CI runs `ESTIM_FUZZ_CASES` (default 2,000) cases per property. The long run:
//!
//! ```sh
//! ESTIM_FUZZ_CASES=1000000 cargo test --release --test fuzz_parsers
//! ```
//!
//! or one parser at a time by test-name filter (`gt_`, `dvl_`, `beams_`, `config_`,
//! `faults_`), e.g. `ESTIM_FUZZ_CASES=1000000 cargo test --release --test fuzz_parsers beams_`.
//!
//! Parsers covered: the A-KIT GT and DVL loaders, the `estim dvl solve` beam file
//! (`estim::datasets::parse_beams`), the TOML configuration
//! (`crate::study::Config::from_toml`) and the fault configuration
//! (`crate::study::FaultConfig::from_toml`).

use std::path::Path;

use crate::study::{Config as PipelineConfig, FaultConfig};
use estim::datasets::{parse_beams, parse_dvl, parse_gt, DVL_HEADER, GT_HEADER};
use proptest::prelude::*;
use proptest::test_runner::Config;

fn cases() -> u32 {
    std::env::var("ESTIM_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(2_000)
}

fn config() -> Config {
    Config {
        cases: cases(),
        failure_persistence: None,
        ..Config::default()
    }
}

/// A valid file with `rows` rows after `header` (time first, then pseudo-random values).
fn valid_csv(header: &[&str], rows: usize, seed: u64) -> String {
    let mut s = header.join(",");
    s.push('\n');
    let mut x = seed;
    for r in 0..rows {
        let mut cells = vec![format!("{}", r as f64 * 1.0025)];
        for _ in 1..header.len() {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            // Within +-1.4: inside every column's range (latitude < 1.5 rad).
            cells.push(format!(
                "{}",
                ((x >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 2.8
            ));
        }
        s.push_str(&cells.join(","));
        s.push('\n');
    }
    s
}

/// One structure-aware mutation of a text file.
#[derive(Debug, Clone)]
enum Mutation {
    DeleteRange(usize, usize),
    InsertBytes(usize, Vec<u8>),
    Truncate(usize),
    ReplaceCell(usize, usize, &'static str),
    DuplicateLine(usize),
    SwapLines(usize, usize),
}

const TOKENS: [&str; 14] = [
    "",
    "nan",
    "NaN",
    "inf",
    "-inf",
    "1e309",
    "-",
    "0x10",
    "\"",
    "\"a,b\"",
    ",,,",
    "1.5.2",
    "\u{feff}",
    "9999999999999999999999",
];

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        (any::<usize>(), 0usize..40).prop_map(|(a, n)| Mutation::DeleteRange(a, n)),
        (any::<usize>(), proptest::collection::vec(any::<u8>(), 1..8))
            .prop_map(|(a, b)| Mutation::InsertBytes(a, b)),
        any::<usize>().prop_map(Mutation::Truncate),
        (
            any::<usize>(),
            any::<usize>(),
            proptest::sample::select(TOKENS.to_vec())
        )
            .prop_map(|(l, c, t)| Mutation::ReplaceCell(l, c, t)),
        any::<usize>().prop_map(Mutation::DuplicateLine),
        (any::<usize>(), any::<usize>()).prop_map(|(a, b)| Mutation::SwapLines(a, b)),
    ]
}

/// Apply line-level edits on the text's lines.
fn edit_lines(bytes: &[u8], edit: impl FnOnce(&mut Vec<String>)) -> Vec<u8> {
    let text = String::from_utf8_lossy(bytes);
    let mut lines: Vec<String> = text.split('\n').map(str::to_string).collect();
    edit(&mut lines);
    lines.join("\n").into_bytes()
}

fn apply(text: &str, mutations: &[Mutation]) -> Vec<u8> {
    let mut bytes = text.as_bytes().to_vec();
    for m in mutations {
        match m {
            Mutation::DeleteRange(a, n) => {
                if !bytes.is_empty() {
                    let a = a % bytes.len();
                    let b = (a + n).min(bytes.len());
                    bytes.drain(a..b);
                }
            }
            Mutation::InsertBytes(a, ins) => {
                let a = a % (bytes.len() + 1);
                bytes.splice(a..a, ins.iter().copied());
            }
            Mutation::Truncate(a) => bytes.truncate(a % (bytes.len() + 1)),
            Mutation::ReplaceCell(l, c, t) => {
                bytes = edit_lines(&bytes, |lines| {
                    let n = lines.len();
                    let line = &mut lines[l % n];
                    let mut cells: Vec<String> = line.split(',').map(str::to_string).collect();
                    let k = c % cells.len();
                    cells[k] = (*t).to_string();
                    *line = cells.join(",");
                })
            }
            Mutation::DuplicateLine(l) => {
                bytes = edit_lines(&bytes, |lines| {
                    let i = l % lines.len();
                    let line = lines[i].clone();
                    lines.insert(i, line);
                })
            }
            Mutation::SwapLines(a, b) => {
                bytes = edit_lines(&bytes, |lines| {
                    let n = lines.len();
                    lines.swap(a % n, b % n);
                })
            }
        }
    }
    bytes
}

fn rows_valid(times: &[f64], mut values: impl Iterator<Item = f64>) -> bool {
    times.len() >= 2 && times.windows(2).all(|w| w[1] > w[0]) && values.all(f64::is_finite)
}

/// An accepted file ends with a newline, or with blanks after its last one (the rule
/// of a complete last line, coded independently of the loaders).
fn ends_complete(bytes: &[u8]) -> bool {
    let tail = match bytes.iter().rposition(|&c| c == b'\n') {
        Some(i) => &bytes[i + 1..],
        None => bytes,
    };
    tail.iter().all(|&c| c == b' ' || c == b'\t')
}

fn check_gt(bytes: &[u8]) {
    if let Ok(rows) = parse_gt(bytes, Path::new("fuzz/GT.csv")) {
        assert!(ends_complete(bytes), "accepted a truncated GT file");
        let times: Vec<f64> = rows.iter().map(|r| r.time).collect();
        let values = rows.iter().flat_map(|r| {
            [r.longitude, r.latitude, r.altitude]
                .into_iter()
                .chain(r.velocity_ned)
                .chain(r.roll_pitch_yaw)
        });
        assert!(rows_valid(&times, values), "accepted an invalid GT file");
    }
}

fn check_dvl(bytes: &[u8]) {
    if let Ok(rows) = parse_dvl(bytes, Path::new("fuzz/DVL.csv")) {
        assert!(ends_complete(bytes), "accepted a truncated DVL file");
        let times: Vec<f64> = rows.iter().map(|r| r.time).collect();
        assert!(
            rows_valid(&times, rows.iter().flat_map(|r| r.velocity_body)),
            "accepted an invalid DVL file"
        );
    }
}

fn check_beams(bytes: &[u8]) {
    if let Ok(rows) = parse_beams(bytes, Path::new("fuzz/beams.csv")) {
        assert!(ends_complete(bytes), "accepted a truncated beam file");
        // At most one row per data line; every present beam finite.
        let lines = bytes.split(|&c| c == b'\n' || c == b'\r').count();
        assert!(rows.len() < lines.max(1), "more rows than lines");
        assert!(
            rows.iter().flatten().flatten().all(|x| x.is_finite()),
            "accepted a non-finite beam"
        );
    }
}

/// A valid beam file: a time column, the four beams (some missing), a comment column.
fn valid_beams(rows: usize, seed: u64) -> String {
    let mut s = String::from("time,beam1,Beam 2,beam3,BEAM4,note\n");
    let mut x = seed;
    for r in 0..rows {
        let mut cells = vec![format!("{r}")];
        for _ in 0..4 {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            cells.push(if x >> 60 == 0 {
                String::new()
            } else {
                format!("{}", ((x >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 4.0)
            });
        }
        cells.push("ok".into());
        s.push_str(&cells.join(","));
        s.push('\n');
    }
    s
}

/// Config: an accepted file must pass the validation again and survive a TOML round
/// trip unchanged (the parse is a real configuration).
fn check_config(bytes: &[u8]) {
    let text = String::from_utf8_lossy(bytes);
    if let Ok(c) = PipelineConfig::from_toml(&text, Path::new("fuzz/config.toml")) {
        assert!(c.check().is_ok(), "accepted an invalid configuration");
        let back = PipelineConfig::from_toml(&c.to_toml(), Path::new("round-trip.toml"))
            .expect("an accepted configuration re-parses");
        assert_eq!(back, c);
    }
}

fn check_faults(bytes: &[u8]) {
    let text = String::from_utf8_lossy(bytes);
    if let Ok(c) = FaultConfig::from_toml(&text, Path::new("fuzz/faults.toml")) {
        assert!(c.check().is_ok(), "accepted an invalid fault configuration");
    }
}

/// TOML values that stress the parser and the validation.
const TOML_VALUES: [&str; 18] = [
    "nan",
    "-inf",
    "inf",
    "1e400",
    "-1",
    "0",
    "\"v3\"",
    "\"\"",
    "[",
    "]]",
    "{ a = 1 }",
    "[1.0, 2.0]",
    "true",
    "1979-05-27T07:32:00Z",
    "'''",
    "0x7fffffffffffffff",
    "18446744073709551616",
    "\"\\u0000\"",
];

/// Replace the value of a `key = value` line (structure-aware TOML mutation).
fn replace_toml_value(text: &str, line: usize, value: &str) -> String {
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    let candidates: Vec<usize> = (0..lines.len())
        .filter(|&i| lines[i].contains('='))
        .collect();
    if let Some(&i) = candidates.get(line % candidates.len().max(1)) {
        let key = lines[i].split('=').next().unwrap_or("").to_string();
        lines[i] = format!("{key}= {value}");
    }
    lines.join("\n")
}

const VALID_FAULTS: &str = "beam_dropout_probability = 0.1
beam_outlier_probability = 0.05
beam_outlier_magnitude_mps = [0.5, 2.0]
imu_gap_rate_per_s = 0.1
imu_gap_samples = 10
[[dvl_outages]]
start_s = 100.0
duration_s = 60.0
[[imu_gaps]]
start_s = 20.0
samples = 5
";

proptest! {
    #![proptest_config(config())]

    #[test]
    fn beams_parser_survives_arbitrary_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        check_beams(&bytes);
    }

    #[test]
    fn beams_parser_survives_mutations(seed in any::<u64>(), rows in 0usize..6,
                                       muts in proptest::collection::vec(mutation(), 1..5)) {
        check_beams(&apply(&valid_beams(rows, seed), &muts));
    }

    #[test]
    fn config_parser_survives_arbitrary_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        check_config(&bytes);
    }

    #[test]
    fn config_parser_survives_mutations(
        value_edits in proptest::collection::vec(
            (any::<usize>(), proptest::sample::select(TOML_VALUES.to_vec())), 0..3),
        muts in proptest::collection::vec(mutation(), 0..3)) {
        let mut text = PipelineConfig::default().to_toml();
        for (line, value) in &value_edits {
            text = replace_toml_value(&text, *line, value);
        }
        check_config(&apply(&text, &muts));
    }

    #[test]
    fn faults_parser_survives_mutations(
        value_edits in proptest::collection::vec(
            (any::<usize>(), proptest::sample::select(TOML_VALUES.to_vec())), 0..3),
        muts in proptest::collection::vec(mutation(), 0..3)) {
        let mut text = VALID_FAULTS.to_string();
        for (line, value) in &value_edits {
            text = replace_toml_value(&text, *line, value);
        }
        check_faults(&apply(&text, &muts));
    }
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn gt_loader_survives_arbitrary_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        check_gt(&bytes);
    }

    #[test]
    fn gt_loader_survives_mutations(seed in any::<u64>(), rows in 0usize..6,
                                    muts in proptest::collection::vec(mutation(), 1..5)) {
        check_gt(&apply(&valid_csv(&GT_HEADER, rows, seed), &muts));
    }

    #[test]
    fn dvl_loader_survives_arbitrary_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        check_dvl(&bytes);
    }

    #[test]
    fn dvl_loader_survives_mutations(seed in any::<u64>(), rows in 0usize..6,
                                     muts in proptest::collection::vec(mutation(), 1..5)) {
        check_dvl(&apply(&valid_csv(&DVL_HEADER, rows, seed), &muts));
    }
}

#[test]
fn unmutated_files_parse() {
    let beams = parse_beams(valid_beams(4, 3).as_bytes(), Path::new("x"));
    assert_eq!(beams.map(|r| r.len()).ok(), Some(4));
    let c = PipelineConfig::from_toml(&PipelineConfig::default().to_toml(), Path::new("x"));
    assert_eq!(c.ok(), Some(PipelineConfig::default()));
    assert!(FaultConfig::from_toml(VALID_FAULTS, Path::new("x")).is_ok());
    let gt = parse_gt(valid_csv(&GT_HEADER, 5, 1).as_bytes(), Path::new("x"));
    assert_eq!(gt.map(|r| r.len()).ok(), Some(5));
    let dvl = parse_dvl(valid_csv(&DVL_HEADER, 3, 2).as_bytes(), Path::new("x"));
    assert_eq!(dvl.map(|r| r.len()).ok(), Some(3));
}
