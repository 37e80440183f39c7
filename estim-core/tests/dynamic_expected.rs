//! The static runner's numbers, committed for the Python bindings: `KalmanFilter`'s
//! `filter_batch` and `smooth_batch` on two fixed problems (a 4-state / 2-measurement
//! model with missing measurements and M = 0, and the same model with a correlated M
//! and every step measured), written to `python/tests/data/static_runner.json`, which
//! `python/tests/test_native.py` compares `estim.kalman_smoother` with.
//!
//! This test recomputes them and requires the committed file to hold the same numbers
//! (to 1e-12 relative), so the file cannot drift from the Rust static runner.
//! `ESTIM_WRITE_EXPECTED=1` rewrites it instead.

use estim_core::nalgebra::{DMatrix, SMatrix, SVector};
use estim_core::{Fixed, KalmanFilter, StateAndCovariance, Zero};
use serde_json::{json, Value};

const N: usize = 4;
const M: usize = 2;

fn path() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../python/tests/data/static_runner.json")
}

/// F, Q, H, R and M of the fixed problem.
struct Model {
    f: DMatrix<f64>,
    q: DMatrix<f64>,
    h: DMatrix<f64>,
    r: DMatrix<f64>,
    cross: DMatrix<f64>,
}

/// A fixed, well-conditioned problem (no random generator: the numbers are the spec).
fn problem() -> Model {
    let f = DMatrix::from_fn(N, N, |i, j| match j as isize - i as isize {
        0 => 0.97,
        1 => 0.1,
        -1 => -0.02,
        _ => 0.0,
    });
    let l = DMatrix::from_fn(N + M, N + M, |i, j| {
        if j <= i {
            0.3 + 0.05 * ((i * 7 + j * 3) % 5) as f64 - if i == j { 0.0 } else { 0.25 }
        } else {
            0.0
        }
    });
    let joint = &l * l.transpose();
    let q = joint.view((0, 0), (N, N)).into_owned();
    let cross = joint.view((0, N), (N, M)).into_owned();
    let r = joint.view((N, N), (M, M)).into_owned();
    let h = DMatrix::from_fn(M, N, |i, j| ((i * N + j) as f64 * 0.7).sin());
    Model { f, q, h, r, cross }
}

fn s<const R: usize, const C: usize>(a: &DMatrix<f64>) -> SMatrix<f64, R, C> {
    SMatrix::from_column_slice(a.as_slice())
}

fn rows(m: &DMatrix<f64>) -> Value {
    json!((0..m.nrows())
        .map(|i| m.row(i).iter().copied().collect::<Vec<_>>())
        .collect::<Vec<_>>())
}

fn case(correlated: bool) -> Value {
    let Model { f, q, h, r, cross } = problem();
    let x0 = SVector::<f64, N>::from_fn(|i, _| 0.5 - 0.25 * i as f64);
    let p0 = SMatrix::<f64, N, N>::identity() * 2.0;
    let ys: Vec<Option<SVector<f64, M>>> = (0..25)
        .map(|k| {
            (correlated || k % 6 != 4)
                .then(|| SVector::from_fn(|i, _| ((k * M + i) as f64 * 0.37).sin() * 2.0))
        })
        .collect();
    let initial = StateAndCovariance::new(x0, p0).expect("valid initial");
    let mut kf =
        KalmanFilter::<f64, N, M>::new(s(&f), s(&q), s(&h), s(&r), initial).expect("valid model");
    let (smoothed, filtered) = if correlated {
        let m = Fixed(s::<N, M>(&cross));
        (
            kf.smooth_batch(&ys, &m).expect("smooths"),
            kf.filter_batch(&ys, &m).expect("filters"),
        )
    } else {
        (
            kf.smooth_batch(&ys, &Zero).expect("smooths"),
            kf.filter_batch(&ys, &Zero).expect("filters"),
        )
    };
    let state = |e: &StateAndCovariance<f64, N>| e.state().iter().copied().collect::<Vec<_>>();
    let cov = |e: &StateAndCovariance<f64, N>| {
        rows(&DMatrix::from_column_slice(N, N, e.covariance().as_slice()))
    };
    json!({
        "F": rows(&f), "Q": rows(&q), "H": rows(&h), "R": rows(&r),
        "M": if correlated { rows(&cross) } else { Value::Null },
        "x0": x0.iter().copied().collect::<Vec<_>>(),
        "P0": rows(&DMatrix::from_column_slice(N, N, p0.as_slice())),
        "zs": ys.iter().map(|y| match y {
            Some(y) => json!(y.iter().copied().collect::<Vec<_>>()),
            None => Value::Null,
        }).collect::<Vec<_>>(),
        "filtered_x": filtered.estimates.iter().map(state).collect::<Vec<_>>(),
        "filtered_P": filtered.estimates.iter().map(cov).collect::<Vec<_>>(),
        "smoothed_x": smoothed.estimates.iter().map(state).collect::<Vec<_>>(),
        "smoothed_P": smoothed.estimates.iter().map(cov).collect::<Vec<_>>(),
        "smoothed_x0": state(&smoothed.initial),
        "log_likelihood": filtered.log_likelihood,
    })
}

/// Every number of `a` within 1e-12 relative (of the largest in its array) of `b`'s.
fn same(a: &Value, b: &Value, at: &str) {
    fn numbers(v: &Value, out: &mut Vec<f64>) {
        match v {
            Value::Number(x) => out.push(x.as_f64().unwrap_or(f64::NAN)),
            Value::Array(xs) => xs.iter().for_each(|x| numbers(x, out)),
            _ => {}
        }
    }
    let (mut x, mut y) = (Vec::new(), Vec::new());
    numbers(a, &mut x);
    numbers(b, &mut y);
    assert_eq!(x.len(), y.len(), "{at}: sizes");
    let scale = y.iter().fold(0.0f64, |s, v| s.max(v.abs())).max(1e-300);
    for (u, v) in x.iter().zip(&y) {
        assert!((u - v).abs() <= 1e-12 * scale, "{at}: {u} vs {v}");
    }
}

#[test]
fn committed_values_are_the_static_runners() {
    let now = json!({ "uncorrelated": case(false), "correlated": case(true) });
    if std::env::var_os("ESTIM_WRITE_EXPECTED").is_some_and(|v| v == "1") {
        let text = serde_json::to_string_pretty(&now).expect("serializable");
        std::fs::write(path(), text + "\n").expect("writable python/tests/data");
        return;
    }
    let text = std::fs::read_to_string(path()).expect("python/tests/data/static_runner.json");
    let committed: Value = serde_json::from_str(&text).expect("valid JSON");
    for name in ["uncorrelated", "correlated"] {
        let (a, b) = (&committed[name], &now[name]);
        assert!(a.is_object(), "{name} missing");
        for (key, value) in b.as_object().expect("object") {
            same(&a[key], value, &format!("{name}.{key}"));
        }
    }
}
