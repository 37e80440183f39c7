//! `estim navigate` from CSV files to the written solution: a 1-hour survey at 100 Hz
//! IMU (360,000 rows, 3,600 DVL epochs) and the same at 400 Hz (1,440,000 rows), Unix
//! times. The files are written once (deterministic pseudo-noise); each iteration runs
//! the `estim` binary (read, navigate, write solution.csv, track and summary).
//! Targets (issue 27): under 3 s and under 10 s on one core.

use std::fmt::Write as _;
use std::path::Path;
use std::process::Command;

use criterion::{criterion_group, criterion_main, Criterion};

/// Deterministic noise in [-1, 1) (a 64-bit LCG; no RNG dependency in the bench).
struct Noise(u64);

impl Noise {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (self.0 >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
}

fn write_survey(dir: &Path, rate_hz: u32) {
    let mut noise = Noise(rate_hz as u64);
    let n = 3600 * rate_hz as usize;
    let dt = 1.0 / f64::from(rate_hz);
    let mut imu = String::with_capacity(n * 80);
    imu.push_str(
        "time_s,acc_x_mps2,acc_y_mps2,acc_z_mps2,gyro_x_radps,gyro_y_radps,gyro_z_radps\n",
    );
    for k in 0..n {
        let _ = writeln!(
            imu,
            "{:.4},{:.6},{:.6},{:.6},{:.7},{:.7},{:.7}",
            1.7e9 + k as f64 * dt,
            0.03 * noise.next(),
            0.03 * noise.next(),
            -9.8 + 0.03 * noise.next(),
            5e-4 * noise.next(),
            5e-4 * noise.next(),
            5e-4 * noise.next()
        );
    }
    std::fs::write(dir.join("imu.csv"), imu).expect("write imu.csv");
    let mut dvl = String::from("time_s,vx,vy,vz\n");
    for k in 1..=3600 {
        let _ = writeln!(
            dvl,
            "{:.2},{:.4},{:.4},{:.4}",
            1.7e9 + f64::from(k),
            0.02 * noise.next(),
            0.02 * noise.next(),
            0.02 * noise.next()
        );
    }
    std::fs::write(dir.join("dvl.csv"), dvl).expect("write dvl.csv");
    std::fs::write(
        dir.join("vehicle.toml"),
        format!("[imu]\nrate_hz = {rate_hz}.0\n[initial]\nlatitude_deg = 32.85\nlongitude_deg = 34.89\ndepth_m = 20.0\n"),
    )
    .expect("write vehicle.toml");
}

fn navigate(dir: &Path) {
    let out = dir.join("out");
    let _ = std::fs::remove_dir_all(&out);
    let status = Command::new(env!("CARGO_BIN_EXE_estim"))
        .args([
            "navigate",
            "--imu",
            "imu.csv",
            "--dvl",
            "dvl.csv",
            "--vehicle",
            "vehicle.toml",
            "--out",
            "out",
        ])
        .current_dir(dir)
        .stdout(std::process::Stdio::null())
        .status()
        .expect("run estim");
    assert!(status.success());
    assert!(out.join("solution.csv").is_file());
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("navigate_1h_survey");
    group.sample_size(10);
    for rate in [100, 400] {
        let dir = tempfile::tempdir().expect("tempdir");
        write_survey(dir.path(), rate);
        group.bench_function(format!("{rate}hz_imu_csv_to_solution"), |b| {
            b.iter(|| navigate(dir.path()))
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
