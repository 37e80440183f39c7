//! The streaming navigator (`estim::navigator::StreamNavigator`, 10 s history, a
//! checkpoint every 10 events) on a synthetic survey (100 Hz IMU, a DVL row every
//! second), in steady state (finalization and checkpoints included): the cost per IMU
//! sample, and of one second of the stream (100 samples and a DVL row) with the DVL
//! row on time or arriving 0.1, 0.5, 1 or 2 s late (applied by rewind and replay); for
//! the 15-state filter and the 26-state one with DVL error states.
//!
//! Run: `cargo bench --bench stream`. Times are the benchmark thread's CPU time
//! (benches/common).
//!
//! `ESTIM_STREAM_SURVEY=1 cargo bench --bench stream` instead streams a synthetic
//! 10-hour survey (DVL rows up to 2 s late) through the library and prints the time
//! of its first hour against real time and the resident memory (`VmRSS`, `VmHWM` of
//! /proc/self/status) at 1 h and 10 h. `ESTIM_STREAM_JSONL=HOURS cargo bench --bench
//! stream` writes that survey as JSON lines on stdout, in arrival order, for
//! `estim navigate --stream` (docs/cli.md, "Streaming").

use std::hint::black_box;
use std::time::{Duration, Instant};

mod common;
use common::ThreadCpuTime;

use criterion::{criterion_group, Criterion};
use estim::core::nalgebra::Vector3;
use estim::ins::ImuSample;
use estim::navigator::{
    DvlInput, DvlRecord, DvlStatesConfig, NavigatorConfig, StreamConfig, StreamNavigator,
};

const PERIOD: f64 = 0.01;

/// A vehicle at rest with a slow wobble (deterministic), at 100 Hz.
fn sample(k: u64) -> ImuSample {
    let t = k as f64 * PERIOD;
    let g = 9.7944;
    let w = (0.3 * t).sin();
    ImuSample::new(
        t,
        Vector3::new(0.01 * w, -0.02 * w, -g + 0.005 * w),
        Vector3::new(1e-4 * w, -2e-4 * w, 3e-4 * w),
    )
}

fn dvl(time: f64) -> DvlRecord {
    let w = (0.7 * time).cos();
    DvlRecord {
        time,
        input: DvlInput::Velocity(Vector3::new(0.01 * w, -0.005 * w, 0.002)),
    }
}

fn navigator(augmented: bool) -> StreamNavigator {
    let mut config = NavigatorConfig::default();
    config.imu.rate_hz = Some(100.0);
    config.initial.latitude_deg = Some(32.5);
    config.initial.longitude_deg = Some(34.9);
    config.initial.depth_m = Some(20.0);
    config.initial.attitude_deg = Some([0.0, 0.0, 30.0]);
    config.gate.probability = 0.0;
    config.health.nis_window = 0;
    if augmented {
        config.dvl_states = Some(DvlStatesConfig::default());
    }
    let settings = config.check().expect("settings");
    let stream = StreamConfig::builder()
        .history_s(10.0)
        .build()
        .expect("stream");
    StreamNavigator::new(settings, stream)
}

/// A navigator fed `seconds` of the survey (DVL on time); the next sample's index.
fn warmed(augmented: bool, seconds: u64) -> (StreamNavigator, u64) {
    let mut nav = navigator(augmented);
    let n = seconds * 100;
    for k in 0..n {
        nav.push_imu(sample(k)).expect("imu");
        if k % 100 == 50 {
            nav.push_dvl(dvl(k as f64 * PERIOD)).expect("dvl");
        }
        nav.take_final();
    }
    (nav, n)
}

fn benches(c: &mut Criterion<ThreadCpuTime>) {
    let mut g = c.benchmark_group("stream");
    for (label, augmented) in [("15 states", false), ("26 states", true)] {
        let (mut nav, mut k) = warmed(augmented, 20);
        g.bench_function(format!("IMU sample, {label}"), |b| {
            b.iter(|| {
                nav.push_imu(sample(k)).expect("imu");
                k += 1;
                black_box(nav.take_final().len())
            });
        });
        // One second of the stream: 100 IMU samples and, after the 51st, a DVL row
        // stamped `delay` before it; the DVL update's cost is this minus 100 IMU
        // samples.
        for delay in [0.0, 0.1, 0.5, 1.0, 2.0] {
            let (mut nav, mut k) = warmed(augmented, 20);
            let name = if delay == 0.0 {
                format!("1 s: 100 IMU samples + DVL on time, {label}")
            } else {
                format!("1 s: 100 IMU samples + DVL {delay} s late, {label}")
            };
            g.bench_function(name, |b| {
                b.iter(|| {
                    for j in 0..100 {
                        nav.push_imu(sample(k)).expect("imu");
                        if j == 50 {
                            // Arrives now, stamped `delay` ago.
                            let stamp = k as f64 * PERIOD - delay;
                            nav.push_dvl(dvl(stamp)).expect("dvl");
                        }
                        k += 1;
                    }
                    black_box(nav.take_final().len())
                });
            });
        }
    }
    g.finish();
}

/// `VmRSS` and `VmHWM` of this process \[kB\].
fn memory_kb() -> (u64, u64) {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let field = |name: &str| {
        status
            .lines()
            .find(|l| l.starts_with(name))
            .and_then(|l| l.split_whitespace().nth(1))
            .and_then(|v| v.parse().ok())
            .unwrap_or(0)
    };
    (field("VmRSS:"), field("VmHWM:"))
}

/// When the DVL row of IMU sample `k` arrives (up to 2 s late, spread
/// deterministically): the index of the sample after which it comes.
fn arrival(k: u64) -> u64 {
    k + (k / 100 * 7919) % 200
}

/// The synthetic survey of `hours` as JSON lines on stdout, in arrival order (module
/// docs).
fn write_jsonl(hours: u64) -> std::io::Result<()> {
    use std::io::Write;
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    let mut late: Vec<(u64, DvlRecord)> = Vec::new();
    for k in 0..hours * 360_000 {
        let s = sample(k);
        let (f, w) = (s.specific_force, s.angular_rate);
        writeln!(
            out,
            r#"{{"sensor":"imu","time":{},"acc":[{},{},{}],"gyro":[{},{},{}]}}"#,
            s.time, f.x, f.y, f.z, w.x, w.y, w.z
        )?;
        if k % 100 == 50 {
            late.push((arrival(k), dvl(k as f64 * PERIOD)));
        }
        while let Some(i) = late.iter().position(|(due, _)| *due <= k) {
            let (_, record) = late.swap_remove(i);
            if let DvlInput::Velocity(v) = record.input {
                writeln!(
                    out,
                    r#"{{"sensor":"dvl","time":{},"velocity":[{},{},{}]}}"#,
                    record.time, v.x, v.y, v.z
                )?;
            }
        }
    }
    out.flush()
}

/// The 10-hour synthetic survey (module docs).
fn survey() {
    let hours = 10;
    let mut nav = navigator(true);
    let mut late: Vec<(u64, DvlRecord)> = Vec::new();
    let mut solutions = 0;
    let started = Instant::now();
    for k in 0..hours * 360_000 {
        nav.push_imu(sample(k)).expect("imu");
        if k % 100 == 50 {
            late.push((arrival(k), dvl(k as f64 * PERIOD)));
        }
        while let Some(i) = late.iter().position(|(due, _)| *due <= k) {
            let (_, record) = late.swap_remove(i);
            nav.push_dvl(record).expect("dvl");
        }
        solutions += nav.take_final().len();
        if (k + 1) % 360_000 == 0 {
            let hour = (k + 1) / 360_000;
            let wall = started.elapsed().as_secs_f64();
            let (rss, hwm) = memory_kb();
            println!(
                "{hour} h: {solutions} solutions, wall {wall:.1} s ({:.0}x real time), \
                 VmRSS {rss} kB, VmHWM {hwm} kB, history {} events, {} checkpoints",
                hour as f64 * 3600.0 / wall,
                nav.history_events(),
                nav.history_checkpoints()
            );
        }
    }
    nav.finish().expect("finish");
    println!("{:?}", nav.counts());
}

criterion_group! {
    name = stream;
    config = Criterion::default()
        .with_measurement(ThreadCpuTime)
        .warm_up_time(Duration::from_millis(300))
        .measurement_time(Duration::from_secs(2))
        .sample_size(20);
    targets = benches
}

fn main() {
    if let Some(hours) = std::env::var("ESTIM_STREAM_JSONL")
        .ok()
        .and_then(|h| h.parse().ok())
    {
        if let Err(e) = write_jsonl(hours) {
            eprintln!("error: stdout: {e}");
        }
        return;
    }
    if std::env::var_os("ESTIM_STREAM_SURVEY").is_some() {
        survey();
        return;
    }
    stream();
    Criterion::default().configure_from_args().final_summary();
}
