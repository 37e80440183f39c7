//! `estim navigate --learned` (the embedded BeamsNet on a survey's own beams and IMU
//! windows, M from the network), `--plots` for `navigate` and `smooth`, and
//! `estim smooth` on survey inputs: on a synthetic survey written here (level, heading
//! north, constant velocity, beams in BeamsNet's geometry), and on A-KIT trajectory 4
//! against the study's own smoother when the data is present.

mod common;

use std::fmt::Write as _;
use std::path::Path;
use std::process::{Command, Output};

use estim::core::nalgebra::{Vector3, Vector4};
use serde_json::Value;

fn estim(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_estim"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("run estim")
}

fn ok_json(out: Output, what: &str) -> Value {
    assert_eq!(
        out.status.code(),
        Some(0),
        "{what}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("JSON on stdout")
}

const SECONDS: usize = 40;
const VELOCITY: [f64; 3] = [1.2, 0.3, 0.05];
const LATITUDE_DEG: f64 = 32.85;

/// Specific force and angular rate of IMU sample k (level, heading north, the Earth's
/// rate in NED; a small deterministic wobble on x so that each window differs).
fn imu_sample(k: usize) -> (Vector3<f64>, Vector3<f64>) {
    let latitude = LATITUDE_DEG.to_radians();
    let g = estim::ins::earth::normal_gravity(latitude, -20.0);
    let earth_rate = 7.292_115e-5;
    let wobble = 0.01 * (k as f64 * 0.37).sin();
    (
        Vector3::new(wobble, 0.0, -g),
        Vector3::new(
            earth_rate * latitude.cos(),
            0.0,
            -earth_rate * latitude.sin(),
        ),
    )
}

/// IMU row k as written in the CSV.
fn imu_row(k: usize) -> String {
    let (f, w) = imu_sample(k);
    format!(
        "{:.2},{:.9},{},{:.9},{:.9e},0,{:.9e}",
        k as f64 / 100.0,
        f.x,
        f.y,
        f.z,
        w.x,
        w.z
    )
}

/// IMU sample k as the CLI reads it back from the CSV.
fn imu_read(k: usize) -> (Vector3<f64>, Vector3<f64>) {
    let c: Vec<f64> = imu_row(k).split(',').map(|v| v.parse().unwrap()).collect();
    (
        Vector3::new(c[1], c[2], c[3]),
        Vector3::new(c[4], c[5], c[6]),
    )
}

/// The beams of BeamsNet's geometry (20 deg, azimuths 45 + 90 k) for velocity `v`.
fn beams_of(v: [f64; 3]) -> Vector4<f64> {
    let theta = 20f64.to_radians();
    Vector4::from_fn(|i, _| {
        let psi = (45.0 + 90.0 * i as f64).to_radians();
        v[0] * psi.cos() * theta.sin() + v[1] * psi.sin() * theta.sin() + v[2] * theta.cos()
    })
}

/// IMU (100 Hz), beams (1 Hz from t = 0.5 s; rows 12-18 missing, a DVL gap; row 5
/// with 3 beams, row 8 with 2), vehicle. Returns the beams written per row.
fn write_survey(dir: &Path) -> Vec<(f64, Vector4<f64>)> {
    let mut imu = String::from("time_s,acc_x,acc_y,acc_z,gyro_x,gyro_y,gyro_z\n");
    for k in 0..=SECONDS * 100 {
        writeln!(imu, "{}", imu_row(k)).unwrap();
    }
    std::fs::write(dir.join("imu.csv"), imu).unwrap();
    let mut rows = Vec::new();
    let mut csv = String::from("time_s,beam1,beam2,beam3,beam4\n");
    for r in 0..SECONDS - 1 {
        if (12..=18).contains(&r) {
            continue;
        }
        let t = if r == 0 { 0.5 } else { r as f64 };
        let w = 0.01 * (r % 5) as f64;
        let b = beams_of([VELOCITY[0] + w, VELOCITY[1] - w, VELOCITY[2]]);
        let cells: Vec<String> = (0..4)
            .map(|i| match (r, i) {
                (5, 2) | (8, 0) | (8, 3) => String::new(),
                _ => format!("{:.6}", b[i]),
            })
            .collect();
        writeln!(csv, "{t},{}", cells.join(",")).unwrap();
        rows.push((t, b));
    }
    std::fs::write(dir.join("beams.csv"), csv).unwrap();
    std::fs::write(
        dir.join("vehicle.toml"),
        format!(
            "[imu]\nrate_hz = 100.0\n[dvl]\nbeam_angle_deg = 20.0\nbeam1_azimuth_deg = 45.0\n\
             [gate]\nprobability = 0.0\n[initial]\nlatitude_deg = {LATITUDE_DEG}\n\
             longitude_deg = 34.89\ndepth_m = 20.0\nvelocity_ned_mps = [{}, {}, {}]\n\
             attitude_deg = [0.0, 0.0, 0.0]\n",
            VELOCITY[0], VELOCITY[1], VELOCITY[2]
        ),
    )
    .unwrap();
    rows
}

#[test]
fn beamsnet_runs_on_the_given_beams_and_the_json_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let rows = write_survey(d);
    let base = [
        "navigate",
        "--imu",
        "imu.csv",
        "--beams",
        "beams.csv",
        "--vehicle",
        "vehicle.toml",
    ];
    let mut args = base.to_vec();
    args.extend(["--learned", "--json"]);
    let v = ok_json(estim(&args, d), "navigate --learned");
    assert_eq!(v["dvl_sensor"], "beamsnet");
    assert_eq!(v["dvl_source"], "beams_csv");
    let l = &v["learned"];
    assert_eq!(l["model"], "embedded:models/beamsnet.onnx");
    // Rows: 32 written; row 0 (t = 0.5 s) has no full window, row 5 three beams, row 8
    // two beams (skipped, counted); the other 29 are BeamsNet updates.
    assert_eq!(rows.len(), 32);
    assert_eq!(l["least_squares_window_not_full"], 1);
    assert_eq!(l["least_squares_three_beams"], 1);
    assert_eq!(v["dvl_insufficient_beam_rows"], 1);
    assert_eq!(l["beamsnet_updates"], 29);
    assert_eq!(v["updates"]["dvl"]["accepted"], 31);
    // The first BeamsNet update (t = 1 s) used the network on the 100 IMU samples the
    // filter integrated before it (samples 0..99) and that row's beams: the same call
    // made here on the library's embedded model.
    let first = &l["first_update"];
    assert_eq!(first["time_since_epoch_s"], 1.0);
    let (force, rate): (Vec<Vector3<f64>>, Vec<Vector3<f64>>) = (0..100).map(imu_read).unzip();
    // The CSV holds the beams to 6 decimals: the network sees those values.
    let beams = rows[1].1.map(|b| format!("{b:.6}").parse::<f64>().unwrap());
    let net = estim::models::beamsnet().unwrap();
    let expected = net
        .velocity(&estim::learned::BeamsNetInput::from_samples(
            &force, &rate, beams,
        ))
        .unwrap();
    for i in 0..3 {
        let got = first["velocity_mps"][i].as_f64().unwrap();
        assert!(
            (got - expected[i]).abs() <= 1e-9 * (1.0 + expected[i].abs()),
            "axis {i}: {got} vs the library's {}",
            expected[i]
        );
    }
    // Least squares on the same file says so.
    let mut ls_args = base.to_vec();
    ls_args.push("--json");
    let ls = ok_json(estim(&ls_args, d), "navigate (LS)");
    assert_eq!(ls["dvl_sensor"], "least_squares");
    assert!(ls["learned"].is_null());
    // Refused: BeamsNet on velocities, on another geometry, on a 50 Hz IMU.
    std::fs::write(d.join("dvl.csv"), "time_s,vx,vy,vz\n1,1,0,0\n").unwrap();
    let out = estim(
        &[
            "navigate",
            "--imu",
            "imu.csv",
            "--dvl",
            "dvl.csv",
            "--learned",
        ],
        d,
    );
    assert_eq!(out.status.code(), Some(2));
    let out = estim(
        &[
            "navigate",
            "--imu",
            "imu.csv",
            "--beams",
            "beams.csv",
            "--learned",
        ],
        d,
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("trained on beams 20 deg"), "{stderr}");
}

/// `(time, sigma_north)` of the rows of a solution.csv.
fn sigma_north(csv: &str) -> Vec<(f64, String, f64)> {
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|c| *c == name).unwrap();
    let (t, k, s) = (col("time_s"), col("kind"), col("sigma_north_m"));
    csv.lines()
        .skip(1)
        .map(|l| {
            let c: Vec<&str> = l.split(',').collect();
            (
                c[t].parse().unwrap(),
                c[k].to_string(),
                c[s].parse().unwrap(),
            )
        })
        .collect()
}

fn assert_plots(dir: &Path) {
    for stem in ["plot_track", "plot_sigma", "plot_nis"] {
        for ext in ["png", "svg"] {
            let p = dir.join(format!("{stem}.{ext}"));
            let len = std::fs::metadata(&p).map(|m| m.len()).unwrap_or(0);
            assert!(len > 1000, "{}: {len} bytes", p.display());
        }
    }
    let svg = std::fs::read_to_string(dir.join("plot_nis.svg")).unwrap();
    assert!(
        svg.contains("per epoch (not averaged"),
        "NIS plot states per-epoch"
    );
    assert!(svg.contains("chi-square(3) band"));
}

#[test]
fn plots_are_written_gaps_coast_and_out_is_complete_or_absent() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_survey(d);
    let out = estim(
        &[
            "navigate",
            "--imu",
            "imu.csv",
            "--beams",
            "beams.csv",
            "--vehicle",
            "vehicle.toml",
            "--rate",
            "10",
            "--out",
            "nav",
            "--plots",
        ],
        d,
    );
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_plots(&d.join("nav"));
    // The DVL gap (no rows from 11 s to 19 s): the solution at 10 Hz coasts through it
    // with a growing sigma, and the plots draw those rows (they join consecutive
    // solutions only, 0.1 s apart here).
    let rows = sigma_north(&std::fs::read_to_string(d.join("nav/solution.csv")).unwrap());
    let inside: Vec<&(f64, String, f64)> = rows
        .iter()
        .filter(|r| r.0 > 11.05 && r.0 < 18.95 && r.1 == "rate")
        .collect();
    assert!(
        inside.len() >= 75,
        "{} rate rows inside the gap",
        inside.len()
    );
    for w in inside.windows(2) {
        assert!(
            w[1].2 >= w[0].2,
            "sigma shrinks while coasting: {:?} {:?}",
            w[0],
            w[1]
        );
    }
    let (start, end) = (inside[0].2, inside[inside.len() - 1].2);
    eprintln!("coasting 1-sigma north: {start} m -> {end} m over the gap");
    assert!(end > start, "{start} -> {end}");

    // Smooth with plots: complete files, smoothed sigma never above the filter's at the
    // same DVL epoch, the last epoch the filter's own.
    let out = estim(
        &[
            "smooth",
            "--imu",
            "imu.csv",
            "--beams",
            "beams.csv",
            "--vehicle",
            "vehicle.toml",
            "--out",
            "sm",
            "--plots",
            "--json",
        ],
        d,
    );
    let v = ok_json(out, "smooth --imu");
    assert_plots(&d.join("sm"));
    assert_eq!(v["command"], "smooth");
    let smoothed = sigma_north(&std::fs::read_to_string(d.join("sm/solution.csv")).unwrap());
    let filtered: Vec<(f64, String, f64)> = rows.iter().filter(|r| r.1 == "dvl").cloned().collect();
    let mut compared = 0;
    for s in smoothed.iter().filter(|s| s.1 == "dvl") {
        let f = filtered.iter().find(|f| (f.0 - s.0).abs() < 1e-6).unwrap();
        // 1e-5 m: solution.csv rounds the sigmas to 5 decimals.
        assert!(
            s.2 <= f.2 + 1e-5,
            "t = {}: smoothed {} above filtered {}",
            s.0,
            s.2,
            f.2
        );
        compared += 1;
    }
    assert_eq!(compared, 31);
    assert_eq!(
        v["smoother"]["epochs"], 32,
        "31 update epochs and the last propagation"
    );

    // An input error after --out was claimed: exit 2, nothing left behind.
    std::fs::write(
        d.join("broken.csv"),
        "time_s,beam1,beam2,beam3,beam4\n1,0.1,0.1,x,0.1\n",
    )
    .unwrap();
    for command in ["navigate", "smooth"] {
        let out = estim(
            &[
                command,
                "--imu",
                "imu.csv",
                "--beams",
                "broken.csv",
                "--out",
                "gone",
                "--plots",
            ],
            d,
        );
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{command}: {stderr}");
        assert!(stderr.contains("broken.csv:2:"), "{stderr}");
        assert!(!d.join("gone").exists(), "{command}: --out left behind");
    }
    // --plots needs --out.
    let out = estim(
        &[
            "navigate",
            "--imu",
            "imu.csv",
            "--beams",
            "beams.csv",
            "--plots",
        ],
        d,
    );
    assert_eq!(out.status.code(), Some(2));
}

#[test]
fn survey_smoothing_equals_the_study_smoother_on_akit_trajectory4() {
    let Some(root) = common::data_root() else {
        return;
    };
    let files = estim::datasets::trajectory_files(&root, 4).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let gt = files.gt.to_str().unwrap();
    let imu = estim(
        &[
            "simulate",
            "imu",
            "--gt",
            gt,
            "--vehicle-out",
            "vehicle.toml",
        ],
        d,
    );
    assert_eq!(imu.status.code(), Some(0));
    std::fs::write(d.join("imu.csv"), imu.stdout).unwrap();
    let beams = estim(
        &[
            "simulate",
            "beams",
            "--gt",
            gt,
            "--dvl",
            files.dvl.to_str().unwrap(),
        ],
        d,
    );
    assert_eq!(beams.status.code(), Some(0));
    std::fs::write(d.join("beams.csv"), beams.stdout).unwrap();
    // The IMU was synthesized from this truth on its clock: declare the offset (else it
    // is estimated from the data, within a millisecond of zero) so that the figures
    // are the study's to 1e-9.
    let mut vehicle = std::fs::read_to_string(d.join("vehicle.toml")).unwrap();
    vehicle.push_str("\n[truth]\ntime_offset_s = 0.0\n");
    std::fs::write(d.join("vehicle.toml"), vehicle).unwrap();
    let survey = ok_json(
        estim(
            &[
                "smooth",
                "--imu",
                "imu.csv",
                "--beams",
                "beams.csv",
                "--vehicle",
                "vehicle.toml",
                "--truth",
                gt,
                "--epochs",
                "accepted",
                "--json",
            ],
            d,
        ),
        "smooth --imu",
    );
    let study = ok_json(
        estim(
            &[
                "smooth",
                "--data",
                root.to_str().unwrap(),
                "--trajectory",
                "4",
                "--json",
            ],
            d,
        ),
        "smooth --data",
    );
    let report = study["reports"]
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["trajectory"] == 4)
        .unwrap();
    // The study scores at the DVL epochs; the survey mode at the reference's own
    // epochs, and at the DVL epochs as `at_dvl_epochs`.
    let e = &survey["evaluation"]["at_dvl_epochs"];
    let pairs = [
        (
            e["position_rmse_m"].as_f64().unwrap(),
            report["smoothed_summary"]["position_m"]["rmse"]
                .as_f64()
                .unwrap(),
        ),
        (
            e["nees_average"].as_f64().unwrap(),
            report["smoothed_summary"]["mean_nees"].as_f64().unwrap(),
        ),
        (
            e["final_position_error_m"].as_f64().unwrap(),
            report["smoothed_summary"]["position_m"]["final_value"]
                .as_f64()
                .unwrap(),
        ),
    ];
    eprintln!("survey smoother vs study smoother: {pairs:?}");
    for (a, b) in pairs {
        assert!((a - b).abs() <= 1e-9 * b.abs(), "survey {a} vs study {b}");
    }
    assert_eq!(e["epochs"], report["time"].as_array().unwrap().len());
    // The forward pass is navigate's (reproduce's LS filter).
    let forward = &survey["smoother"]["forward_evaluation"];
    assert!(forward["position_rmse_m"].as_f64().unwrap() > 0.0);
}
