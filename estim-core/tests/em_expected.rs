//! EM's numbers on a problem of its own, committed for the Python bindings: a seeded
//! 3-state / 2-measurement linear-Gaussian model with a constant transition offset, an
//! observation offset and missing epochs, fitted by `noise::em::em` over R, Q, F and d
//! for 8 iterations from a wrong start. Written to `python/tests/data/em_rust.json`,
//! which `python/tests/test_em.py` compares `estim.em` with (the bindings' argument
//! mapping, variable names, offsets and missing rows, against the Rust call).
//!
//! This test recomputes them and requires the committed file to hold the same numbers
//! (to 1e-12 relative), so the file cannot drift from the Rust EM.
//! `ESTIM_WRITE_EXPECTED=1` rewrites it instead.

use estim_core::nalgebra::{DMatrix, DVector};
use estim_core::noise::em::{em, EmStop, EmVariables, LinearGaussianModel, TransitionOffsets};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde_json::{json, Value};

const N: usize = 3;
const M: usize = 2;
const STEPS: usize = 80;
const ITERATIONS: usize = 8;

fn path() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../python/tests/data/em_rust.json")
}

fn rows(m: &DMatrix<f64>) -> Value {
    json!((0..m.nrows())
        .map(|i| m.row(i).iter().copied().collect::<Vec<_>>())
        .collect::<Vec<_>>())
}

fn column(v: &DVector<f64>) -> Value {
    json!(v.iter().copied().collect::<Vec<_>>())
}

/// The true model, measurements simulated from it (seeded), and the fit from a
/// start with the wrong F, Q, R and d.
fn case() -> Value {
    let mut rng = ChaCha8Rng::seed_from_u64(47);
    let mut normal = |scale: f64| -> f64 {
        let z: f64 = StandardNormal.sample(&mut rng);
        scale * z
    };
    let f = DMatrix::from_row_slice(N, N, &[0.95, 0.1, 0.0, -0.05, 0.9, 0.1, 0.0, 0.0, 0.8]);
    let h = DMatrix::from_row_slice(M, N, &[1.0, 0.0, 0.5, 0.0, 1.0, -0.3]);
    let b = DVector::from_column_slice(&[0.1, -0.05, 0.02]);
    let d = DVector::from_column_slice(&[0.3, -0.2]);
    let (q_std, r_std) = ([0.2, 0.1, 0.15], [0.3, 0.25]);
    let mut x = DVector::from_column_slice(&[1.0, -0.5, 0.2]);
    let mut zs = Vec::with_capacity(STEPS);
    for t in 0..STEPS {
        if t > 0 {
            x = &f * &x + &b + DVector::from_fn(N, |i, _| normal(q_std[i]));
        }
        let y = &h * &x + &d + DVector::from_fn(M, |i, _| normal(r_std[i]));
        // Every seventh epoch missing, the first one included.
        zs.push((t % 7 != 0).then_some(y));
    }
    let start = LinearGaussianModel::new(
        DMatrix::identity(N, N) * 0.5,
        h.clone(),
        DMatrix::identity(N, N) * 0.5,
        DMatrix::identity(M, M) * 2.0,
        DVector::zeros(N),
        DMatrix::identity(N, N) * 3.0,
    )
    .and_then(|m| m.with_transition_offsets(TransitionOffsets::Constant(b.clone())))
    .and_then(|m| m.with_observation_offset(DVector::zeros(M)))
    .expect("a valid start");
    let vars = EmVariables::OBSERVATION_COVARIANCE
        | EmVariables::TRANSITION_COVARIANCE
        | EmVariables::TRANSITION_MATRIX
        | EmVariables::OBSERVATION_OFFSET;
    let fit = em(&start, &zs, vars, ITERATIONS).expect("EM runs");
    assert_eq!(fit.stop, EmStop::Completed);
    assert_eq!(fit.log_likelihoods.len(), ITERATIONS + 1);
    let model = &fit.model;
    let TransitionOffsets::Constant(fitted_b) = model.transition_offsets() else {
        panic!("a constant offset stays constant");
    };
    json!({
        "zs": zs.iter().map(|y| match y {
            Some(y) => column(y),
            None => Value::Null,
        }).collect::<Vec<_>>(),
        "start": {
            "F": rows(start.transition_matrix()), "H": rows(start.observation_matrix()),
            "Q": rows(start.transition_covariance()), "R": rows(start.observation_covariance()),
            "x0": column(start.initial_state_mean()), "P0": rows(start.initial_state_covariance()),
            "b": column(&b), "d": column(start.observation_offset()),
        },
        "em_vars": ["R", "Q", "F", "d"],
        "n_iter": ITERATIONS,
        "fitted": {
            "F": rows(model.transition_matrix()), "H": rows(model.observation_matrix()),
            "Q": rows(model.transition_covariance()), "R": rows(model.observation_covariance()),
            "x0": column(model.initial_state_mean()), "P0": rows(model.initial_state_covariance()),
            "b": column(fitted_b), "d": column(model.observation_offset()),
        },
        "log_likelihoods": fit.log_likelihoods,
    })
}

/// Every number of `a` within 1e-12 relative (of the largest in its array) of `b`'s.
fn same(a: &Value, b: &Value, at: &str) {
    fn numbers(v: &Value, out: &mut Vec<f64>) {
        match v {
            Value::Number(x) => out.push(x.as_f64().unwrap_or(f64::NAN)),
            Value::Array(xs) => xs.iter().for_each(|x| numbers(x, out)),
            Value::Object(o) => o.values().for_each(|x| numbers(x, out)),
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
fn committed_values_are_the_rust_em() {
    let now = case();
    if std::env::var_os("ESTIM_WRITE_EXPECTED").is_some_and(|v| v == "1") {
        let text = serde_json::to_string_pretty(&now).expect("serializable");
        std::fs::write(path(), text + "\n").expect("writable python/tests/data");
        return;
    }
    let text = std::fs::read_to_string(path()).expect("python/tests/data/em_rust.json");
    let committed: Value = serde_json::from_str(&text).expect("valid JSON");
    for (key, value) in now.as_object().expect("object") {
        assert!(!committed[key].is_null(), "{key} missing");
        same(&committed[key], value, key);
    }
    // The fit moved the likelihood up from the wrong start.
    let trace: Vec<f64> = serde_json::from_value(now["log_likelihoods"].clone()).expect("floats");
    assert!(trace.windows(2).all(|w| w[1] > w[0]), "{trace:?}");
}
