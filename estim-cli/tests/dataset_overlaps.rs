//! Data hygiene on the real A-KIT files: `estim dataset beamsnet` keeps every example
//! touching a held-out trajectory (4, 13) out of the training set and records the overlap
//! groups for the split (the shared rows themselves: the study's
//! `estim-cli/src/study/tests/dataset_overlaps.rs`).
//!
//! Data rule: if the data is absent the tests print why and return, unless
//! `ESTIM_REQUIRE_DATA=1`.

use std::process::Command;

use estim::datasets::{load_gt, trajectory_files};

mod common;
use common::data_root;

/// Rows and metadata of an `.npy` written by `estim dataset beamsnet`.
fn read_npy(path: &std::path::Path) -> (usize, usize, Vec<f64>) {
    let bytes = std::fs::read(path).unwrap();
    let hlen = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    let header = std::str::from_utf8(&bytes[10..10 + hlen]).unwrap();
    let shape = header.split("'shape': (").nth(1).unwrap();
    let dims: Vec<usize> = shape
        .split(')')
        .next()
        .unwrap()
        .split(',')
        .filter_map(|s| s.trim().parse().ok())
        .collect();
    let data: Vec<f64> = bytes[10 + hlen..]
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
        .collect();
    (dims[0], dims[1], data)
}

#[test]
fn dataset_command_leaves_out_windows_touching_held_out_rows() {
    let Some(root) = data_root() else { return };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("d.npy");
    let status = Command::new(env!("CARGO_BIN_EXE_estim"))
        .args(["dataset", "beamsnet", "--realizations", "1", "--data"])
        .arg(&root)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(status.status.success(), "{status:?}");
    let (rows, cols, data) = read_npy(&out);
    assert_eq!(cols, 610);
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.with_extension("json")).unwrap())
            .unwrap();
    assert_eq!(
        meta["overlap_groups"],
        serde_json::json!([[1, 8], [10, 13]])
    );
    // Independent of the builder: the DVL time of 10's first row shared with 13 (it is
    // 13's row 0), found by comparing the GT files value by value.
    let gt10 = load_gt(&trajectory_files(&root, 10).unwrap().gt).unwrap();
    let gt13 = load_gt(&trajectory_files(&root, 13).unwrap().gt).unwrap();
    let same = |a: &estim::datasets::GtSample, b: &estim::datasets::GtSample| {
        (
            a.longitude,
            a.latitude,
            a.altitude,
            a.velocity_ned,
            a.roll_pitch_yaw,
        ) == (
            b.longitude,
            b.latitude,
            b.altitude,
            b.velocity_ned,
            b.roll_pitch_yaw,
        )
    };
    let first_shared = gt10.iter().position(|g| same(g, &gt13[0])).unwrap();
    let shared_time = gt10[first_shared].time;
    let mut last10 = f64::NEG_INFINITY;
    let mut per_trajectory = [0usize; 14];
    for r in 0..rows {
        let row = &data[r * cols..(r + 1) * cols];
        let n = row[607] as usize;
        assert!(n != 4 && n != 13, "row {r} is from held-out trajectory {n}");
        per_trajectory[n] += 1;
        if n == 10 {
            last10 = last10.max(row[608]);
        }
    }
    // An example of the DVL row stamped t depends on that row and on the IMU window
    // ending at the motion instant t - offset (the filter's alignment recorded in the
    // JSON; A-KIT's offset is negative, so the window lies after the stamp).
    assert_eq!(meta["window_alignment"]["rule"], "filter");
    let offset = meta["window_alignment"]["time_offset_s"].as_f64().unwrap();
    assert!(offset < 0.0, "{offset}");
    let last_end = last10 - offset;
    // Every kept example of 10 ends more than 2 rows (margin) before the shared part.
    assert!(
        last_end < gt10[first_shared - 2].time,
        "trajectory 10 keeps an example ending at {last_end} s; shared rows start at {shared_time} s"
    );
    // and the rule costs only the shared part, the margin and the rows the offset
    // spans: 10's DVL rows 0 ..= first_shared - 3 - ceil(|offset| / 1 s) keep their
    // examples (1 Hz rows).
    let offset_rows = (-offset).ceil() as usize;
    assert!(
        per_trajectory[10] >= first_shared - 2 - offset_rows,
        "{} examples of 10 kept, shared rows start at row {first_shared}",
        per_trajectory[10]
    );
    assert!(per_trajectory[1] > 0 && per_trajectory[8] > 0);
}
