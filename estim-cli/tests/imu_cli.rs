//! `estim imu calibrate`, run as the built binary: refusals that name the file or flag,
//! and A-KIT trajectory 2 (when the data is present) against the data README's
//! measured axes and clock.

use std::io::Write;
use std::process::{Command, Output};

mod common;

fn estim(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_estim"))
        .args(args)
        .output()
        .expect("run estim")
}

fn write(content: &str) -> tempfile::NamedTempFile {
    let mut f = tempfile::NamedTempFile::new().unwrap();
    f.write_all(content.as_bytes()).unwrap();
    f
}

fn assert_bad_input(out: &Output, needle: &str) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "stderr: {stderr}");
    assert!(out.stdout.is_empty(), "stdout not empty");
    assert!(
        stderr.contains(needle),
        "stderr {stderr:?} does not name {needle:?}"
    );
}

#[test]
fn refusals_name_the_file_or_flag() {
    // Ten seconds of a still IMU and reference: far too short.
    let mut imu = String::from("Time [s],ACC X,ACC Y,ACC Z,GYRO X,GYRO Y,GYRO Z\n");
    for k in 0..1000 {
        imu.push_str(&format!("{},0,0,-9.8,0,0,0\n", f64::from(k) * 0.01));
    }
    let mut gt = String::from(
        "Time [s],Longitude [rad],Latitude [rad],Altitude [m],V North [m/s],V East [m/s],\
         V Down [m/s],Roll [rad],Pitch [rad],Yaw [rad]\n",
    );
    for k in 0..10 {
        gt.push_str(&format!("{k},0.6,0.57,-15,0,0,0,0,0,0\n"));
    }
    let (imu, gt) = (write(&imu), write(&gt));
    let (imu_path, gt_path) = (imu.path().to_str().unwrap(), gt.path().to_str().unwrap());
    let out = estim(&["imu", "calibrate", "--imu", imu_path, "--truth", gt_path]);
    assert_bad_input(&out, imu_path);
    assert_bad_input(&out, "reference intervals");
    let out = estim(&[
        "imu",
        "calibrate",
        "--imu",
        imu_path,
        "--truth",
        "no-such-gt.csv",
    ]);
    assert_bad_input(&out, "no-such-gt.csv");
    let out = estim(&[
        "imu",
        "calibrate",
        "--imu",
        imu_path,
        "--truth",
        gt_path,
        "--max-time-offset=-1",
    ]);
    assert_bad_input(&out, "--max-time-offset");
}

#[test]
fn akit_trajectory_2_has_its_y_axes_reversed_and_a_stretched_clock() {
    let Some(root) = common::data_root() else {
        return;
    };
    let akit = estim::datasets::akit_dir(&root).expect("A-KIT folder");
    let dir = akit.join("Trajectory2");
    let (imu, gt) = (
        dir.join("IMU_trajectory2.csv"),
        dir.join("GT_trajectory2.csv"),
    );
    let args = [
        "imu",
        "calibrate",
        "--imu",
        imu.to_str().unwrap(),
        "--truth",
        gt.to_str().unwrap(),
    ];
    let out = estim(&[&args[..], &["--json"]].concat());
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    println!("{doc:#}");
    // The data README: y reversed on both triads; GT time = 1.0025 t + c, c about
    // +0.45 s on trajectory 2 (so tau = -c).
    // The schema every --json speaks (tests/cli_manners.rs).
    assert_eq!(doc["schema_version"], 2);
    assert_eq!(doc["command"], "imu calibrate");
    assert_eq!(doc["status"], "ok");
    assert_eq!(doc["inputs"]["imu"].as_str(), imu.to_str());
    assert_eq!(doc["axes"], serde_json::json!(["x", "-y", "z"]));
    let scale = doc["clock_scale"]["estimate"].as_f64().unwrap();
    assert!((scale - 1.0025).abs() < 0.001, "{scale}");
    let offset = doc["time_offset_s"]["estimate"].as_f64().unwrap();
    assert!((offset + 0.45).abs() < 0.1, "{offset}");
    // The table is TOML with the vehicle file's keys under [imu].
    let out = estim(&args);
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    let table: toml::Table = text.parse().expect("TOML");
    let imu = table["imu"].as_table().expect("[imu]");
    let mut keys: Vec<&str> = imu.keys().map(String::as_str).collect();
    keys.sort_unstable();
    assert_eq!(
        keys,
        [
            "accelerometer_bias",
            "axes",
            "clock_origin_s",
            "clock_scale",
            "gyroscope_bias",
            "gyroscope_scale",
            "time_offset_s"
        ]
    );
    assert!((imu["clock_scale"].as_float().unwrap() - scale).abs() < 1e-5);
    // The scale acts about the IMU file's epoch, its first whole second (0 here).
    assert_eq!(imu["clock_origin_s"].as_float(), doc["epoch_s"].as_f64());
    assert_eq!(doc["epoch_s"].as_f64(), Some(0.0));
    // Trajectory 2 turns about z (327 deg net): the gyroscope's scale there is fitted,
    // and reads the clock's 1.0025 (the rates are per second of the IMU's clock).
    let z = &doc["gyroscope_scale"];
    let (k, sigma) = (
        z["estimate"][2].as_f64().unwrap(),
        z["standard_error"][2].as_f64().unwrap(),
    );
    assert!((k - 1.0025).abs() < 5.0 * sigma, "{k} +- {sigma}");
    assert!(sigma < 1e-4, "{sigma}");
    let written = imu["gyroscope_scale"].as_array().expect("three numbers");
    assert!((written[2].as_float().unwrap() - k).abs() < 1e-5);
}
