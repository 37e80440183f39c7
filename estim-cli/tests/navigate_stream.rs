//! `estim navigate --stream` (issue 48):
//! - A-KIT training trajectory 2 (recorded IMU, `vehicles/akit.toml`: the 26-state
//!   filter, the IMU's axes and clock scale, the DVL's -1.04 s offset), its first 120 s
//!   written as JSON lines from the library's CSV readers with every DVL record arriving
//!   up to 2 s after its stamp (seeded), piped through `--stream`: the same solution as
//!   the batch run with the DVL on time, to 1e-9 relative at every DVL epoch;
//! - a paced writer (1-s chunks through a pipe, output read concurrently): every
//!   solution line final after a chunk is on stdout before the next chunk is written;
//! - Water Linked DVL velocity reports from a mock TCP server the test starts and
//!   stops give the run with the same velocities as `dvl` records;
//! - bad lines (not JSON, a number out of range, an IMU going back, a huge line, a
//!   binary stream) end with exit status 2 and the line named, memory bounded.

mod common;

use std::io::{BufRead, BufReader, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use estim::datasets::{DvlLog, ImuLog};
use estim::navigator::DvlInput;

fn estim() -> Command {
    Command::new(env!("CARGO_BIN_EXE_estim"))
}

/// A seeded uniform in [0, 1) (SplitMix64).
struct Uniform(u64);

impl Uniform {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        (z ^ (z >> 31)) as f64 / (u64::MAX as f64 + 1.0)
    }
}

/// The rows of a solution CSV (header dropped): time, kind, and the numbers.
fn rows(text: &str) -> Vec<(String, Vec<f64>)> {
    let mut lines = text.lines();
    assert!(lines.next().is_some_and(|h| h.starts_with("time_s,kind,")));
    lines
        .map(|l| {
            let cells: Vec<&str> = l.split(',').collect();
            let numbers = cells
                .iter()
                .enumerate()
                .filter(|(i, _)| *i != 1)
                .map(|(_, c)| c.parse::<f64>().expect("a number"))
                .collect();
            (cells[1].to_string(), numbers)
        })
        .collect()
}

/// The largest relative difference between two solution tables of the same rows.
fn largest_difference(a: &[(String, Vec<f64>)], b: &[(String, Vec<f64>)]) -> f64 {
    assert_eq!(a.len(), b.len(), "row counts");
    let mut worst: f64 = 0.0;
    for ((ka, x), (kb, y)) in a.iter().zip(b) {
        assert_eq!(ka, kb);
        for (u, v) in x.iter().zip(y) {
            worst = worst.max((u - v).abs() / u.abs().max(v.abs()).max(1e-300));
        }
    }
    worst
}

/// Trajectory 2's first `seconds` s of IMU and DVL rows as CSV files in `dir`, the
/// JSON lines of the same records with each DVL row `delay(i)` s late, and a vehicle
/// file: `vehicles/akit.toml` with an `[initial]` state from the reference's first row.
fn trajectory_2(root: &Path, dir: &Path, seconds: f64) -> (PathBuf, PathBuf, PathBuf, String) {
    let folder = root.join("a-kit/Trajectory2");
    let imu_path = folder.join("IMU_trajectory2.csv");
    let dvl_path = folder.join("DVL_trajectory2.csv");
    let imu = ImuLog::load(&imu_path, None).expect("IMU");
    let dvl = DvlLog::load_velocity(&dvl_path, Some(imu.epoch_s)).expect("DVL");
    // The CSVs cut at `seconds` (header and rows kept as written).
    let cut = |from: &Path, to: &Path| {
        let text = std::fs::read_to_string(from).unwrap();
        let mut out = String::new();
        for (i, line) in text.lines().enumerate() {
            let keep = i == 0
                || line
                    .split(',')
                    .next()
                    .and_then(|t| t.trim().parse::<f64>().ok())
                    .is_some_and(|t| t < seconds);
            if keep {
                out.push_str(line);
                out.push('\n');
            }
        }
        std::fs::write(to, out).unwrap();
    };
    let (imu_csv, dvl_csv) = (dir.join("imu.csv"), dir.join("dvl.csv"));
    cut(&imu_path, &imu_csv);
    cut(&dvl_path, &dvl_csv);
    // The initial state: the reference's first row (rad, m, m/s).
    let gt = std::fs::read_to_string(folder.join("GT_trajectory2.csv")).unwrap();
    let first: Vec<f64> = gt
        .lines()
        .nth(1)
        .unwrap()
        .split(',')
        .map(|c| c.trim().parse().unwrap())
        .collect();
    let vehicle = dir.join("vehicle.toml");
    let akit = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../vehicles/akit.toml"),
    )
    .unwrap();
    let initial = format!(
        "\n[initial]\nlatitude_deg = {}\nlongitude_deg = {}\ndepth_m = {}\nvelocity_ned_mps = [{}, {}, {}]\nattitude_deg = [{}, {}, {}]\n",
        first[2].to_degrees(),
        first[1].to_degrees(),
        -first[3],
        first[4],
        first[5],
        first[6],
        first[7].to_degrees(),
        first[8].to_degrees(),
        first[9].to_degrees(),
    );
    std::fs::write(&vehicle, akit + &initial).unwrap();
    // Arrival order: IMU samples at their stamps, DVL rows up to 2 s late.
    let mut uniform = Uniform(48);
    let epoch = imu.epoch_s;
    let mut arrivals: Vec<(f64, String)> = Vec::new();
    for s in imu.samples.iter().filter(|s| s.time < seconds) {
        let line = serde_json::json!({
            "sensor": "imu",
            "time": epoch + s.time,
            "acc": [s.specific_force.x, s.specific_force.y, s.specific_force.z],
            "gyro": [s.angular_rate.x, s.angular_rate.y, s.angular_rate.z],
        });
        arrivals.push((s.time, line.to_string()));
    }
    for d in dvl.records.iter().filter(|d| d.time < seconds) {
        let velocity = match d.input {
            DvlInput::Velocity(v) => serde_json::json!([v.x, v.y, v.z]),
            _ => serde_json::Value::Null,
        };
        let line =
            serde_json::json!({ "sensor": "dvl", "time": epoch + d.time, "velocity": velocity });
        arrivals.push((d.time + 2.0 * uniform.next(), line.to_string()));
    }
    arrivals.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut jsonl = String::new();
    for (_, line) in arrivals {
        jsonl.push_str(&line);
        jsonl.push('\n');
    }
    (imu_csv, dvl_csv, vehicle, jsonl)
}

/// Run `estim` with `stdin` written from a thread; its output.
fn run_with_stdin(args: &[&str], stdin: String) -> Output {
    let mut child = estim()
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run estim");
    let mut input = child.stdin.take().unwrap();
    let writer = std::thread::spawn(move || {
        let _ = input.write_all(stdin.as_bytes());
    });
    let out = child.wait_with_output().unwrap();
    writer.join().unwrap();
    out
}

#[test]
fn a_kit_stream_with_late_dvl_equals_the_batch_run() {
    let Some(root) = common::data_root() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (imu, dvl, vehicle, jsonl) = trajectory_2(&root, dir.path(), 120.0);
    let out = dir.path().join("batch");
    let batch = estim()
        .args(["navigate", "--imu"])
        .arg(&imu)
        .arg("--dvl")
        .arg(&dvl)
        .arg("--vehicle")
        .arg(&vehicle)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        batch.status.success(),
        "{}",
        String::from_utf8_lossy(&batch.stderr)
    );
    let batch_rows = rows(&std::fs::read_to_string(out.join("solution.csv")).unwrap());
    let vehicle_arg = vehicle.display().to_string();
    let stream = run_with_stdin(
        &["navigate", "--stream", "--vehicle", &vehicle_arg, "--json"],
        jsonl,
    );
    let stderr = String::from_utf8_lossy(&stream.stderr);
    assert!(stream.status.success(), "{stderr}");
    let stream_rows = rows(&String::from_utf8_lossy(&stream.stdout));
    assert!(batch_rows.len() >= 110, "{} DVL epochs", batch_rows.len());
    assert!(batch_rows.iter().all(|(k, _)| k == "dvl"));
    let worst = largest_difference(&stream_rows, &batch_rows);
    println!(
        "trajectory 2, first 120 s, DVL up to 2 s late: {} DVL epochs, largest relative \
         difference {worst:e}",
        stream_rows.len()
    );
    assert!(worst <= 1e-9, "{worst}");
    // The summary (on stderr without --out): every late row was a rewind, none refused.
    let summary: serde_json::Value = serde_json::from_str(&stderr).expect("summary JSON");
    assert_eq!(summary["stream"]["refused_too_old"], 0);
    assert!(summary["stream"]["rewinds"].as_u64().unwrap() > 50);
    assert!(summary["dvl_states"].is_object());
}

/// A stationary vehicle at 100 Hz with a DVL row every second at x.5 s; the vehicle
/// file that starts it.
fn synthetic(seconds: usize, epoch: f64) -> (Vec<Vec<String>>, String) {
    let g = 9.7944;
    let mut chunks = Vec::new();
    for second in 0..seconds {
        let mut lines = Vec::new();
        for k in 0..100 {
            let t = epoch + second as f64 + k as f64 * 0.01;
            lines.push(format!(
                r#"{{"sensor": "imu", "time": {t}, "acc": [0.001, -0.002, {}], "gyro": [1e-5, 0, 2e-5]}}"#,
                -g
            ));
            if k == 50 {
                lines.push(format!(
                    r#"{{"sensor": "dvl", "time": {t}, "velocity": [0.01, 0.0, -0.005]}}"#
                ));
            }
        }
        chunks.push(lines);
    }
    let vehicle = "[imu]\nrate_hz = 100.0\n[initial]\nlatitude_deg = 32.5\nlongitude_deg = 34.9\n\
                   depth_m = 20.0\nattitude_deg = [0.0, 0.0, 30.0]\n"
        .to_string();
    (chunks, vehicle)
}

#[test]
fn each_solution_line_is_out_before_the_next_second_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let seconds = 12;
    let history = 0.5;
    let (chunks, vehicle) = synthetic(seconds, 0.0);
    let vehicle_path = dir.path().join("vehicle.toml");
    std::fs::write(&vehicle_path, vehicle).unwrap();
    let mut child: Child = estim()
        .args([
            "navigate",
            "--stream",
            "--history",
            &history.to_string(),
            "--vehicle",
        ])
        .arg(&vehicle_path)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    let (tx, rx) = mpsc::channel::<(String, Instant)>();
    let reader = std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines() {
            let Ok(line) = line else { return };
            if tx.send((line, Instant::now())).is_err() {
                return;
            }
        }
    });
    let mut stdin = child.stdin.take().unwrap();
    let mut received: Vec<(f64, Instant)> = Vec::new();
    let mut latencies = Vec::new();
    for (second, chunk) in chunks.iter().enumerate() {
        let text: String = chunk.iter().map(|l| format!("{l}\n")).collect();
        stdin.write_all(text.as_bytes()).unwrap();
        stdin.flush().unwrap();
        let written = Instant::now();
        // Final after this chunk: the DVL rows at s + 0.5 with s + 0.5 < (second +
        // 0.99) - history, i.e. up to this second's own row.
        let expected = (0..=second)
            .filter(|s| (*s as f64 + 0.5) < second as f64 + 0.99 - history)
            .count();
        let deadline = Instant::now() + Duration::from_secs(60);
        while received.len() < expected {
            let left = deadline.saturating_duration_since(Instant::now());
            let (line, at) = rx.recv_timeout(left).unwrap_or_else(|_| {
                panic!("second {second}: {} of {expected} lines", received.len())
            });
            if line.starts_with("time_s") {
                continue;
            }
            let time: f64 = line.split(',').next().unwrap().parse().unwrap();
            received.push((time, at));
            latencies.push(at.saturating_duration_since(written));
        }
        // Nothing of a later second before it is written.
        assert!(received.iter().all(|(t, _)| *t < second as f64 + 1.0));
    }
    drop(stdin);
    assert!(child.wait().unwrap().success());
    reader.join().unwrap();
    let rest: Vec<_> = rx.try_iter().collect();
    assert_eq!(received.len() + rest.len(), seconds);
    let worst = latencies.iter().max().copied().unwrap_or_default();
    println!(
        "{} lines each before the next chunk; largest delay from writing a chunk to its \
         line: {:.2} ms",
        received.len(),
        worst.as_secs_f64() * 1e3
    );
}

/// A Water Linked velocity report at Unix time `t` \[s\].
fn water_linked(t_us: i64, v: [f64; 3], valid: bool) -> String {
    serde_json::json!({
        "time": 1000.0, "vx": v[0], "vy": v[1], "vz": v[2], "fom": 0.002,
        "covariance": [[1e-6, 0, 0], [0, 1e-6, 0], [0, 0, 1e-6]], "altitude": 3.2,
        "transducers": [], "velocity_valid": valid, "status": 0, "format": "json_v3.1",
        "type": "velocity", "time_of_validity": t_us, "time_of_transmission": t_us + 150_000,
    })
    .to_string()
}

#[test]
fn water_linked_reports_over_tcp_equal_dvl_records() {
    let dir = tempfile::tempdir().unwrap();
    let epoch = 1_700_000_000.0;
    let seconds = 20;
    let (chunks, vehicle) = synthetic(seconds, epoch);
    let vehicle_path = dir.path().join("vehicle.toml");
    std::fs::write(&vehicle_path, vehicle).unwrap();
    let all: Vec<String> = chunks.into_iter().flatten().collect();
    // Reference: the DVL rows as `dvl` records on stdin.
    let vehicle_arg = vehicle_path.display().to_string();
    let args = ["navigate", "--stream", "--vehicle", &vehicle_arg, "--json"];
    let reference = run_with_stdin(&args, all.iter().map(|l| format!("{l}\n")).collect());
    assert!(reference.status.success());
    // The same velocities from a mock DVL on localhost; stdin carries the IMU only.
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let address = listener.local_addr().unwrap().to_string();
    let server = std::thread::spawn(move || {
        let (mut socket, _) = listener.accept().unwrap();
        let mut text = String::new();
        for s in 0..seconds as i64 {
            let t_us = 1_700_000_000_000_000 + s * 1_000_000 + 500_000;
            text.push_str(&water_linked(t_us, [0.01, 0.0, -0.005], true));
            text.push('\n');
            text.push_str(r#"{"ts": 49056.8, "x": 1.0, "y": 2.0, "z": 3.0, "std": 0.1, "roll": 0, "pitch": 0, "yaw": 0, "type": "position_local", "status": 0, "format": "json_v3.1"}"#);
            text.push('\n');
        }
        text.push_str(&water_linked(
            1_700_000_000_000_000 + 3_250_000,
            [0.0; 3],
            false,
        ));
        text.push('\n');
        socket.write_all(text.as_bytes()).unwrap();
        // The server stops: the connection closes.
    });
    let imu_only: String = all
        .iter()
        .filter(|l| l.contains("\"imu\""))
        .map(|l| format!("{l}\n"))
        .collect();
    // Start the IMU once the reports are in (they wait for the IMU to reach them).
    let mut args = args.to_vec();
    args.extend(["--dvl-tcp", &address]);
    let mut child = estim()
        .args(&args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    server.join().unwrap();
    std::thread::sleep(Duration::from_millis(300));
    let mut stdin = child.stdin.take().unwrap();
    stdin.write_all(imu_only.as_bytes()).unwrap();
    drop(stdin);
    let tcp = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&tcp.stderr);
    assert!(tcp.status.success(), "{stderr}");
    let (a, b) = (
        rows(&String::from_utf8_lossy(&tcp.stdout)),
        rows(&String::from_utf8_lossy(&reference.stdout)),
    );
    assert_eq!(a.len(), seconds);
    assert_eq!(largest_difference(&a, &b), 0.0);
    let summary: serde_json::Value = serde_json::from_str(&stderr).unwrap();
    assert_eq!(summary["water_linked_velocity_reports"]["valid"], seconds);
    assert_eq!(summary["water_linked_velocity_reports"]["no_lock"], 1);
    assert_eq!(summary["ignored_records"], seconds);
    assert_eq!(summary["stream"]["dvl_no_lock"], 1);
}

#[test]
fn bad_lines_are_named_and_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (chunks, vehicle) = synthetic(2, 0.0);
    let vehicle_path = dir.path().join("vehicle.toml");
    std::fs::write(&vehicle_path, vehicle).unwrap();
    let vehicle_arg = vehicle_path.display().to_string();
    let args = ["navigate", "--stream", "--vehicle", &vehicle_arg];
    let good: Vec<String> = chunks.concat();
    let with = |line: usize, bad: &str| {
        let mut lines = good.clone();
        lines.insert(line - 1, bad.to_string());
        lines.iter().map(|l| format!("{l}\n")).collect::<String>()
    };
    let cases = [
        (
            with(5, "{\"sensor\": \"imu\", \"time\": "),
            "stdin:5: not a JSON record",
        ),
        (
            with(7, r#"{"sensor": "depth", "time": 0.05, "depth": NaN}"#),
            "stdin:7: not a JSON record",
        ),
        (
            with(9, r#"{"sensor": "depth", "time": 0.05, "depth": 1e400}"#),
            "stdin:9: not a JSON record",
        ),
        (
            with(
                11,
                r#"{"sensor": "imu", "time": 0.001, "acc": [0, 0, -9.8], "gyro": [0, 0, 0]}"#,
            ),
            "stdin:11: IMU sample at t = 0.001 s is not after",
        ),
        (
            with(3, r#"{"sensor": "fix", "time": 0.05, "lat_deg": 1}"#),
            "stdin:3: key `lon_deg` is missing",
        ),
        (
            with(4, &"x".repeat(100_000)),
            "stdin:4: longer than 65536 bytes",
        ),
        ("\0".repeat(1 << 20), "stdin:1: longer than 65536 bytes"),
        (
            good[..3].join("\n"),
            "stdin:3: the stream ended inside this line",
        ),
    ];
    for (input, expected) in cases {
        let out = run_with_stdin(&args, input);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{expected}: {stderr}");
        assert!(stderr.contains(expected), "{expected} not in {stderr}");
        assert!(!stderr.contains("panicked"));
    }
    // A binary stream without end is refused after its first line's worth.
    let mut child = estim()
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = child.stdin.take().unwrap();
    let writer = std::thread::spawn(move || {
        let zeros = vec![0u8; 1 << 16];
        for _ in 0..1024 {
            if stdin.write_all(&zeros).is_err() {
                return;
            }
        }
    });
    let status = child.wait().unwrap();
    let mut stderr = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut stderr)
        .unwrap();
    writer.join().unwrap();
    assert_eq!(status.code(), Some(2), "{stderr}");
}

#[test]
fn follow_reads_a_file_still_being_written() {
    let dir = tempfile::tempdir().unwrap();
    let (chunks, vehicle) = synthetic(6, 0.0);
    let vehicle_path = dir.path().join("vehicle.toml");
    std::fs::write(&vehicle_path, vehicle).unwrap();
    let vehicle_arg = vehicle_path.display().to_string();
    let all: String = chunks.concat().iter().map(|l| format!("{l}\n")).collect();
    let reference = run_with_stdin(&["navigate", "--stream", "--vehicle", &vehicle_arg], all);
    assert!(reference.status.success());
    // The file grows by one second of records every 100 ms, a line cut in two once.
    let log = dir.path().join("live.jsonl");
    std::fs::write(&log, "").unwrap();
    let child = estim()
        .args([
            "navigate",
            "--stream",
            "--vehicle",
            &vehicle_arg,
            "--idle-timeout",
            "1",
            "--follow",
        ])
        .arg(&log)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut file = std::fs::OpenOptions::new().append(true).open(&log).unwrap();
    for chunk in &chunks {
        let text: String = chunk.iter().map(|l| format!("{l}\n")).collect();
        let (a, b) = text.split_at(text.len() / 2 + 7);
        file.write_all(a.as_bytes()).unwrap();
        file.flush().unwrap();
        std::thread::sleep(Duration::from_millis(50));
        file.write_all(b.as_bytes()).unwrap();
        file.flush().unwrap();
        std::thread::sleep(Duration::from_millis(50));
    }
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(out.stdout, reference.stdout);
    assert_eq!(rows(&String::from_utf8_lossy(&out.stdout)).len(), 6);
}

#[test]
fn out_folder_holds_the_streamed_solution() {
    let dir = tempfile::tempdir().unwrap();
    let (chunks, vehicle) = synthetic(5, 0.0);
    let vehicle_path = dir.path().join("vehicle.toml");
    std::fs::write(&vehicle_path, vehicle).unwrap();
    let vehicle_arg = vehicle_path.display().to_string();
    let input: String = chunks.concat().iter().map(|l| format!("{l}\n")).collect();
    let live = run_with_stdin(
        &["navigate", "--stream", "--vehicle", &vehicle_arg],
        input.clone(),
    );
    assert!(live.status.success());
    let out = dir.path().join("nav");
    let out_arg = out.display().to_string();
    let staged = run_with_stdin(
        &[
            "navigate",
            "--stream",
            "--vehicle",
            &vehicle_arg,
            "--out",
            &out_arg,
            "--json",
        ],
        input,
    );
    assert!(
        staged.status.success(),
        "{}",
        String::from_utf8_lossy(&staged.stderr)
    );
    assert_eq!(
        std::fs::read(out.join("solution.csv")).unwrap(),
        live.stdout
    );
    let summary: serde_json::Value = serde_json::from_slice(&staged.stdout).unwrap();
    assert_eq!(summary["command"], "navigate");
    assert_eq!(summary["inputs"]["mode"], "stream");
    assert_eq!(summary["solutions"], 5);
    assert!(out.join("track.geojson").exists() && out.join("summary.json").exists());
}

#[test]
fn lag_adds_smoothed_rows_next_to_the_filter_rows() {
    let dir = tempfile::tempdir().unwrap();
    let (chunks, vehicle) = synthetic(8, 0.0);
    let vehicle_path = dir.path().join("vehicle.toml");
    std::fs::write(&vehicle_path, &vehicle).unwrap();
    let vehicle_arg = vehicle_path.display().to_string();
    let input: String = chunks.concat().iter().map(|l| format!("{l}\n")).collect();
    let out = run_with_stdin(
        &[
            "navigate",
            "--stream",
            "--lag",
            "2",
            "--vehicle",
            &vehicle_arg,
        ],
        input.clone(),
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let all = rows(&String::from_utf8_lossy(&out.stdout));
    let filter: Vec<_> = all.iter().filter(|(k, _)| k == "dvl").collect();
    let lagged: Vec<_> = all.iter().filter(|(k, _)| k == "lag").collect();
    // One per accepted DVL update, and the end of the stream.
    assert_eq!(filter.len(), 8);
    assert_eq!(lagged.len(), 9);
    for (f, l) in filter.iter().zip(&lagged) {
        assert!((f.1[0] - l.1[0]).abs() < 1e-6, "same epochs");
        // sigma_north_m (index 16 without `kind`): smoothed at or below filtered.
        assert!(l.1[16] <= f.1[16] + 1e-12);
    }
    // The lag needs the 15-state filter, as `estim smooth`.
    std::fs::write(&vehicle_path, vehicle + "[dvl_states]\n").unwrap();
    let refused = run_with_stdin(
        &[
            "navigate",
            "--stream",
            "--lag",
            "2",
            "--vehicle",
            &vehicle_arg,
        ],
        input,
    );
    assert_eq!(refused.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&refused.stderr).contains("[dvl_states]"));
}
