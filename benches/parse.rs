//! Parsing a ground-truth CSV file: 10^5 and 10^6 rows of the A-KIT layout (10
//! columns, a vehicle going north at 1.5 m/s, 100 Hz), from bytes in memory through
//! `estim::datasets::parse_gt` (encoding check, header, every value checked, line
//! numbers, the time-plausibility rule). Linear time: 10 x the rows, about 10 x the
//! time. Target (issue 28): 10^6 rows in under 2 s.
//!
//! Run: `cargo bench --bench parse`. Times are the benchmark thread's CPU time (see
//! `benches/common`).

use std::fmt::Write as _;
use std::hint::black_box;
use std::path::Path;
use std::time::Duration;

mod common;
use common::ThreadCpuTime;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use estim::datasets::{parse_gt, GT_HEADER};

/// A valid GT file of `rows` rows at 100 Hz.
fn gt_file(rows: usize) -> Vec<u8> {
    let mut s = GT_HEADER.join(",");
    s.push('\n');
    let earth_radius_m = 6_356_000.0;
    for k in 0..rows {
        let t = k as f64 * 0.01;
        let _ = writeln!(
            s,
            "{t:.2},0.609,{:.12},-20.0,1.5,0.0,0.0,0.0,0.0,0.0",
            0.5733 + 1.5 * t / earth_radius_m
        );
    }
    s.into_bytes()
}

fn parse(c: &mut Criterion<ThreadCpuTime>) {
    let mut group = c.benchmark_group("parse_gt");
    for rows in [100_000usize, 1_000_000] {
        let bytes = gt_file(rows);
        let parsed = parse_gt(bytes.as_slice(), Path::new("gt.csv")).expect("a valid file");
        assert_eq!(parsed.len(), rows);
        assert_eq!(parsed[rows - 1].line, rows as u64 + 1);
        group.bench_with_input(BenchmarkId::from_parameter(rows), &bytes, |b, bytes| {
            b.iter(|| black_box(parse_gt(black_box(bytes.as_slice()), Path::new("gt.csv"))))
        });
    }
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .with_measurement(ThreadCpuTime)
        .measurement_time(Duration::from_secs(10))
        .warm_up_time(Duration::from_secs(1))
        .sample_size(10);
    targets = parse
}
criterion_main!(benches);
