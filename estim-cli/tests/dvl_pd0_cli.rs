//! `estim dvl pd0 FILE`: the bottom-track CSV of a PD0 file, every good ensemble kept
//! and every skipped span named with its byte offset.
//!
//! The real file is the VmDas recording of the data folder (`pd0/vmdas02_os.ENR`, 690
//! ensembles of 1,921 bytes; see estim-dvl/tests/pd0.rs for the decoded values against
//! another reader). Found through `ESTIM_DATA_DIR` or `../shared/data`; a failure when
//! absent with `ESTIM_REQUIRE_DATA=1` (CI), skipped with a printed reason elsewhere.

use std::path::PathBuf;
use std::process::{Command, Output};

mod common;

const HEADER: &str = "time_unix_s,bt_velocity_1_mps,bt_velocity_2_mps,bt_velocity_3_mps,\
bt_velocity_4_mps,bt_range_1_m,bt_range_2_m,bt_range_3_m,bt_range_4_m,coordinate_system";

fn estim(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_estim"))
        .args(args)
        .output()
        .expect("run estim")
}

fn real_file() -> Option<PathBuf> {
    let file = common::data_root()?.join("pd0/vmdas02_os.ENR");
    assert!(
        file.is_file(),
        "{}: missing from the data folder",
        file.display()
    );
    Some(file)
}

#[test]
fn real_file_gives_one_row_per_ensemble_in_beam_coordinates() {
    let Some(file) = real_file() else { return };
    let out = estim(&["dvl", "pd0", file.to_str().expect("utf-8 path")]);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).expect("utf-8");
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some(HEADER));
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 690);
    let mut previous = f64::NEG_INFINITY;
    for row in &rows {
        assert_eq!(row.len(), 10);
        assert_eq!(row[9], "beam");
        let t: f64 = row[0].parse().expect("time");
        // 2022-03-14 (VmDas file date), strictly increasing.
        assert!(
            t > 1_647_216_000.0 && t < 1_647_302_400.0 && t > previous,
            "{t}"
        );
        previous = t;
        // Bottom ranges where present: positive and within the reach of a 75 kHz
        // profiler's bottom track (under 1,000 m; this file's are mostly 330-350 m).
        for cell in &row[5..9] {
            if !cell.is_empty() {
                let r: f64 = cell.parse().expect("range");
                assert!(r > 0.0 && r < 1000.0, "{r}");
            }
        }
    }
    // The instrument's bad-velocity marker is an empty cell, never -32.768.
    assert!(!text.contains("-32.768"));
    assert!(rows.iter().any(|r| r[1..5].iter().any(|c| c.is_empty())));
}

#[test]
fn corrupt_ensemble_is_named_by_offset_and_the_others_kept() {
    let Some(file) = real_file() else { return };
    let mut bytes = std::fs::read(&file).expect("read");
    // One byte inside ensemble 11 (offset 10 * 1921 + 100): its checksum fails.
    let offset = 10 * 1921;
    bytes[offset + 100] ^= 0x55;
    // Garbage after the last ensemble, and a cut ensemble: the first 500 bytes again.
    bytes.extend_from_slice(b"garbage between ensembles");
    let head = bytes[..500].to_vec();
    bytes.extend_from_slice(&head);
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("damaged.pd0");
    std::fs::write(&path, &bytes).expect("write");
    let path = path.to_str().expect("utf-8 path");

    let out = estim(&["dvl", "pd0", path]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    assert!(stderr.contains(&format!("byte {offset} ")), "{stderr}");
    assert!(stderr.contains("checksum"), "{stderr}");
    assert!(
        stderr.contains(&format!("byte {} ", 690 * 1921)),
        "{stderr}"
    );
    let rows = String::from_utf8(out.stdout)
        .expect("utf-8")
        .lines()
        .count()
        - 1;
    assert_eq!(rows, 689);

    let strict = estim(&["dvl", "pd0", "--strict", path]);
    assert_eq!(strict.status.code(), Some(2));
    assert!(strict.stdout.is_empty());
    assert!(String::from_utf8_lossy(&strict.stderr).contains(&format!("byte {offset} ")));
}

#[test]
fn a_file_with_no_ensemble_or_no_file_is_bad_input() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("not_pd0.bin");
    std::fs::write(&path, b"\x7f\x7f\x00\x01this is not an ensemble").expect("write");
    let out = estim(&["dvl", "pd0", path.to_str().expect("utf-8 path")]);
    assert_eq!(out.status.code(), Some(2));
    assert!(out.stdout.is_empty());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("not_pd0.bin") && stderr.contains("no good PD0 ensemble"),
        "{stderr}"
    );

    let missing = dir.path().join("missing.pd0");
    let out = estim(&["dvl", "pd0", missing.to_str().expect("utf-8 path")]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("missing.pd0"));
    assert!(!String::from_utf8_lossy(&out.stderr).contains("panicked"));
}
