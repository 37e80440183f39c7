//! Hostile input to every `estim` subcommand that reads a file: a missing path, an
//! empty file, a truncated file, binary garbage. Each must print ONE line on stderr
//! naming the file (and the line where there is one), exit with code 2, print
//! nothing on stdout and leave nothing in `--out`.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use estim::datasets::{DVL_HEADER, GT_HEADER};

fn estim(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_estim"))
        .args(args)
        .env_remove("ESTIM_DATA_DIR")
        .output()
        .expect("run estim")
}

/// A valid GT file: a vehicle going north at 1.5 m/s, `rows` seconds.
fn valid_gt(rows: usize) -> String {
    let mut s = GT_HEADER.join(",");
    s.push('\n');
    let rn = 6_356_000.0;
    for k in 0..rows {
        let t = k as f64;
        s.push_str(&format!(
            "{t},0.609,{},-20.0,1.5,0.0,0.0,0.0,0.0,0.0\n",
            0.5733 + 1.5 * t / rn
        ));
    }
    s
}

fn valid_dvl(rows: usize) -> String {
    let mut s = DVL_HEADER.join(",");
    s.push('\n');
    for k in 0..rows {
        s.push_str(&format!("{},1.5,0.0,0.0\n", k as f64 * 1.0025));
    }
    s
}

fn valid_beams() -> String {
    "beam1,beam2,beam3,beam4\n0.1,0.2,0.3,0.4\n0.2,0.1,0.4,0.3\n0.3,0.3,0.3,0.3\n".into()
}

/// Cut a valid file in the middle of its last data row.
fn truncated(text: &str) -> Vec<u8> {
    let body = text.trim_end_matches('\n');
    let last_line_start = body.rfind('\n').map_or(0, |i| i + 1);
    let cut = last_line_start + (body.len() - last_line_start) / 2;
    // Cut at a comma so the last row keeps fewer fields (a classic partial write).
    let cut = body[..cut].rfind(',').unwrap_or(cut);
    body.as_bytes()[..cut].to_vec()
}

const GARBAGE: &[u8] =
    b"\x7fELF\x02\x01\x01\x00\xff\xfe\xfd\x00\x00,\x80\x81\n\x00\x01\x02\xc3\x28\xa0\xa1\n";

/// The line number (1-based) of the last line of a truncated file.
fn last_line(bytes: &[u8]) -> usize {
    1 + bytes.iter().filter(|&&c| c == b'\n').count()
}

#[track_caller]
fn assert_one_line_error(out: &Output, file: &Path, line: Option<usize>) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "stderr: {stderr}");
    assert!(out.stdout.is_empty(), "stdout not empty: {:?}", out.stdout);
    let lines: Vec<&str> = stderr.lines().collect();
    assert_eq!(lines.len(), 1, "not one line: {stderr:?}");
    let name = file.to_string_lossy();
    assert!(
        lines[0].contains(name.as_ref()),
        "{stderr:?} does not name {name}"
    );
    if let Some(l) = line {
        assert!(
            lines[0].contains(&format!(":{l}:")) || lines[0].contains(&format!("line {l}")),
            "{stderr:?} does not name line {l}"
        );
    }
}

fn assert_nothing_in(out_dir: &Path) {
    let entries = std::fs::read_dir(out_dir).map_or(0, |d| d.count());
    assert_eq!(entries, 0, "{} is not empty", out_dir.display());
}

struct Files {
    _dir: tempfile::TempDir,
    root: PathBuf,
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

/// An A-KIT-like data folder with trajectory 4 (GT and DVL contents given).
fn akit(gt: &[u8], dvl: &[u8]) -> (Files, PathBuf, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let traj = dir.path().join("Trajectory4");
    std::fs::create_dir(&traj).unwrap();
    let g = write(&traj, "GT_trajectory4.csv", gt);
    let d = write(&traj, "DVL_trajectory4.csv", dvl);
    let root = dir.path().to_path_buf();
    (Files { _dir: dir, root }, g, d)
}

/// The hostile variants of a valid text file: (label, bytes, line expected in the error).
fn hostile(valid: &str) -> Vec<(&'static str, Vec<u8>, Option<usize>)> {
    let t = truncated(valid);
    let line = last_line(&t);
    vec![
        ("empty", Vec::new(), None),
        ("truncated", t, Some(line)),
        ("garbage", GARBAGE.to_vec(), None),
    ]
}

#[test]
fn dvl_solve_hostile_inputs() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.csv");
    let out = estim(&[
        "dvl",
        "solve",
        "--beam-angle",
        "20",
        missing.to_str().unwrap(),
    ]);
    assert_one_line_error(&out, &missing, None);
    for (label, bytes, line) in hostile(&valid_beams()) {
        let f = write(dir.path(), &format!("{label}.csv"), &bytes);
        let out = estim(&["dvl", "solve", "--beam-angle", "20", f.to_str().unwrap()]);
        assert_one_line_error(&out, &f, line);
    }
}

#[test]
fn dvl_calibrate_hostile_inputs() {
    let dir = tempfile::tempdir().unwrap();
    let gt = write(dir.path(), "gt.csv", valid_gt(60).as_bytes());
    let dvl = write(dir.path(), "dvl.csv", valid_dvl(60).as_bytes());
    let missing = dir.path().join("missing.csv");
    let run = |g: &Path, d: &Path| {
        estim(&[
            "dvl",
            "calibrate",
            "--gt",
            g.to_str().unwrap(),
            "--dvl",
            d.to_str().unwrap(),
        ])
    };
    assert_one_line_error(&run(&missing, &dvl), &missing, None);
    assert_one_line_error(&run(&gt, &missing), &missing, None);
    for (label, bytes, line) in hostile(&valid_gt(60)) {
        let f = write(dir.path(), &format!("gt_{label}.csv"), &bytes);
        assert_one_line_error(&run(&f, &dvl), &f, line);
    }
    for (label, bytes, line) in hostile(&valid_dvl(60)) {
        let f = write(dir.path(), &format!("dvl_{label}.csv"), &bytes);
        assert_one_line_error(&run(&gt, &f), &f, line);
    }
}

#[test]
fn reproduce_hostile_data_leaves_out_empty() {
    let out_parent = tempfile::tempdir().unwrap();
    let out_dir = out_parent.path().join("out");
    let reproduce = |data: &Path| {
        estim(&[
            "reproduce",
            "--data",
            data.to_str().unwrap(),
            "--trajectory",
            "4",
            "--out",
            out_dir.to_str().unwrap(),
        ])
    };
    // Missing data folder.
    let missing = out_parent.path().join("no-such-data");
    assert_one_line_error(&reproduce(&missing), &missing, None);
    assert_nothing_in(&out_dir);
    // A folder without trajectories.
    let empty = tempfile::tempdir().unwrap();
    assert_one_line_error(&reproduce(empty.path()), empty.path(), None);
    assert_nothing_in(&out_dir);
    // Broken GT (valid DVL), then broken DVL (valid GT).
    for (label, bytes, line) in hostile(&valid_gt(60)) {
        let (files, gt, _) = akit(&bytes, valid_dvl(60).as_bytes());
        let out = reproduce(&files.root);
        assert_one_line_error(&out, &gt, line);
        assert_nothing_in(&out_dir);
        let _ = label;
    }
    for (_, bytes, line) in hostile(&valid_dvl(60)) {
        let (files, _, dvl) = akit(valid_gt(60).as_bytes(), &bytes);
        let out = reproduce(&files.root);
        assert_one_line_error(&out, &dvl, line);
        assert_nothing_in(&out_dir);
    }
}

#[test]
fn reproduce_hostile_config_leaves_out_empty() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("out");
    let reproduce = |config: &Path| {
        estim(&[
            "reproduce",
            "--config",
            config.to_str().unwrap(),
            "--out",
            out_dir.to_str().unwrap(),
        ])
    };
    let missing = dir.path().join("missing.toml");
    assert_one_line_error(&reproduce(&missing), &missing, None);
    assert_nothing_in(&out_dir);
    // A truncated configuration: the last `key = value` cut after the `=`.
    let valid = "seed = 3\n[filter]\nrho = 0.1\ngate_probability = 0.999\n";
    let cut = write(
        dir.path(),
        "truncated.toml",
        b"seed = 3\n[filter]\nrho = 0.1\ngate_probability =",
    );
    assert_one_line_error(&reproduce(&cut), &cut, Some(4));
    assert_nothing_in(&out_dir);
    let garbage = write(dir.path(), "garbage.toml", GARBAGE);
    assert_one_line_error(&reproduce(&garbage), &garbage, None);
    assert_nothing_in(&out_dir);
    let bad_value = write(dir.path(), "bad.toml", b"[filter]\nrho = 7.0\n");
    assert_one_line_error(&reproduce(&bad_value), &bad_value, None);
    assert_nothing_in(&out_dir);
    // An empty file is a valid configuration (every key has a default): accepted.
    let empty = write(dir.path(), "empty.toml", b"");
    let out = estim(&[
        "reproduce",
        "--config",
        empty.to_str().unwrap(),
        "--print-config",
    ]);
    assert_eq!(out.status.code(), Some(0));
    let _ = valid;
}

#[test]
fn montecarlo_hostile_config() {
    let dir = tempfile::tempdir().unwrap();
    let run = |config: &Path| {
        estim(&[
            "montecarlo",
            "--runs",
            "1",
            "--config",
            config.to_str().unwrap(),
        ])
    };
    let missing = dir.path().join("missing.toml");
    assert_one_line_error(&run(&missing), &missing, None);
    let cut = write(
        dir.path(),
        "truncated.toml",
        b"[faults]\nbeam_dropout_probability =",
    );
    assert_one_line_error(&run(&cut), &cut, Some(2));
    let garbage = write(dir.path(), "garbage.toml", GARBAGE);
    assert_one_line_error(&run(&garbage), &garbage, None);
    let bad = write(
        dir.path(),
        "bad_faults.toml",
        b"[faults]\nbeam_outlier_probability = 1.5\n",
    );
    assert_one_line_error(&run(&bad), &bad, None);
}

#[test]
fn wrong_model_file_is_one_line_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let meta = std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/beamsnet.json"))
        .unwrap();
    let cases: [(&str, &[u8]); 3] = [
        ("empty", b""),
        ("garbage", &[0xde, 0xad, 0xbe, 0xef, 0, 1, 2, 3]),
        ("text", b"not an onnx model\n"),
    ];
    for (name, bytes) in cases {
        let sub = dir.path().join(name);
        std::fs::create_dir_all(&sub).unwrap();
        write(&sub, "beamsnet.json", &meta);
        let model = write(&sub, "beamsnet.onnx", bytes);
        let out_dir = sub.join("out");
        let m = model.to_str().unwrap();
        let o = out_dir.to_str().unwrap();
        assert_one_line_error(
            &estim(&["reproduce", "--model", m, "--out", o]),
            &model,
            None,
        );
        assert_nothing_in(&out_dir);
        assert_one_line_error(&estim(&["beamsnet", "eval", "--model", m]), &model, None);
    }
    // A missing model file.
    let missing = dir.path().join("nowhere/beamsnet.onnx");
    assert_one_line_error(
        &estim(&["reproduce", "--model", missing.to_str().unwrap()]),
        &missing,
        None,
    );
}

/// A GT file cut inside the last number of its last row (it parses as a shorter
/// number): reported as truncated, never run.
#[test]
fn reproduce_gt_cut_inside_its_last_number_is_truncated() {
    let out_parent = tempfile::tempdir().unwrap();
    let out_dir = out_parent.path().join("out");
    let text = valid_gt(60);
    let cut = &text.as_bytes()[..text.len() - 3];
    let (files, gt, _) = akit(cut, valid_dvl(60).as_bytes());
    let out = estim(&[
        "reproduce",
        "--data",
        files.root.to_str().unwrap(),
        "--trajectory",
        "4",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert_one_line_error(&out, &gt, Some(61));
    assert!(String::from_utf8_lossy(&out.stderr).contains("truncated"));
    assert_nothing_in(&out_dir);
}

fn shifted_dvl(rows: usize, shift: f64) -> String {
    let mut s = DVL_HEADER.join(",");
    s.push('\n');
    for k in 0..rows {
        s.push_str(&format!("{},1.5,0.0,0.0\n", k as f64 * 1.0025 + shift));
    }
    s
}

/// GT and DVL that do not cover the same span: an error naming both files and their
/// spans, exit 2, nothing written; --allow-partial runs on the overlap and says so.
#[test]
fn reproduce_refuses_spans_that_differ_unless_partial_is_allowed() {
    let out_parent = tempfile::tempdir().unwrap();
    let out_dir = out_parent.path().join("out");
    let run = |gt: &Path, dvl: &Path, partial: bool| {
        let mut args = vec![
            "reproduce",
            "--gt",
            gt.to_str().unwrap(),
            "--dvl",
            dvl.to_str().unwrap(),
            "--out",
            out_dir.to_str().unwrap(),
            "--json",
        ];
        if partial {
            args.push("--allow-partial");
        }
        estim(&args)
    };
    let dir = tempfile::tempdir().unwrap();
    let gt = write(dir.path(), "gt.csv", valid_gt(60).as_bytes());
    // No overlap at all: refused, even with --allow-partial.
    let far = write(dir.path(), "far.csv", shifted_dvl(60, 1000.0).as_bytes());
    for partial in [false, true] {
        let out = run(&gt, &far, partial);
        assert_one_line_error(&out, &gt, None);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(stderr.contains(far.to_str().unwrap()), "{stderr}");
        assert!(
            stderr.contains("0.000-59.000") && stderr.contains("1000.000-1059.1"),
            "{stderr}"
        );
        assert_nothing_in(&out_dir);
    }
    // The DVL covers the first half: refused; with --allow-partial, 0-29.07 s is run.
    let half = write(dir.path(), "half.csv", valid_dvl(30).as_bytes());
    let out = run(&gt, &half, false);
    assert_one_line_error(&out, &gt, None);
    assert!(String::from_utf8_lossy(&out.stderr).contains("--allow-partial"));
    assert_nothing_in(&out_dir);
    let out = run(&gt, &half, true);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    assert!(
        stderr.contains("warning: --allow-partial") && stderr.contains("overlap 0.000-29.07"),
        "{stderr}"
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let duration = json["trajectories"][0]["duration_s"].as_f64().unwrap();
    assert!(
        (duration - 29.0).abs() < 0.011,
        "ran {duration} s, GT rows 0-29 s lie inside the overlap"
    );
    assert!(out_dir.join("trajectory_timeseries.csv").is_file());
}

/// A folder holding only trajectory 7, asked for 4: the error lists what is there.
#[test]
fn missing_trajectory_lists_the_trajectories_found() {
    let dir = tempfile::tempdir().unwrap();
    let traj = dir.path().join("Trajectory7");
    std::fs::create_dir(&traj).unwrap();
    write(&traj, "GT_trajectory7.csv", valid_gt(60).as_bytes());
    write(&traj, "DVL_trajectory7.csv", valid_dvl(60).as_bytes());
    let out = estim(&["reproduce", "--data", dir.path().to_str().unwrap()]);
    let expected = dir.path().join("Trajectory4/GT_trajectory4.csv");
    assert_one_line_error(&out, &expected, None);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("Trajectory4/GT_trajectory4.csv: file not found; trajectories found: 7"),
        "{stderr}"
    );
}

/// `--gt` / `--dvl` name their files in errors like `--data` does.
#[test]
fn reproduce_gt_dvl_hostile_files() {
    let dir = tempfile::tempdir().unwrap();
    let gt = write(dir.path(), "gt.csv", valid_gt(60).as_bytes());
    let dvl = write(dir.path(), "dvl.csv", valid_dvl(60).as_bytes());
    let run = |g: &Path, d: &Path| {
        estim(&[
            "reproduce",
            "--gt",
            g.to_str().unwrap(),
            "--dvl",
            d.to_str().unwrap(),
        ])
    };
    let missing = dir.path().join("missing.csv");
    assert_one_line_error(&run(&missing, &dvl), &missing, None);
    assert_one_line_error(&run(&gt, &missing), &missing, None);
    for (label, bytes, line) in hostile(&valid_dvl(60)) {
        let f = write(dir.path(), &format!("dvl_{label}.csv"), &bytes);
        assert_one_line_error(&run(&gt, &f), &f, line);
    }
    // A value out of range names the file, the line and the column.
    let bad = valid_gt(60).replacen(",0.609,", ",34.9,", 3);
    let f = write(dir.path(), "deg.csv", bad.as_bytes());
    let out = run(&f, &dvl);
    assert_one_line_error(&out, &f, Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("Longitude [rad]"));
}

/// `dvl calibrate` applies the same span rule (allowance: the searched time offset).
#[test]
fn dvl_calibrate_refuses_disjoint_spans() {
    let dir = tempfile::tempdir().unwrap();
    let gt = write(dir.path(), "gt.csv", valid_gt(60).as_bytes());
    let far = write(dir.path(), "far.csv", shifted_dvl(60, 500.0).as_bytes());
    let out = estim(&[
        "dvl",
        "calibrate",
        "--gt",
        gt.to_str().unwrap(),
        "--dvl",
        far.to_str().unwrap(),
    ]);
    assert_one_line_error(&out, &gt, None);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains(far.to_str().unwrap()) && stderr.contains("500.000-559.1"),
        "{stderr}"
    );
}
