//! Maximum likelihood with run-time sizes (`noise::ml::maximize_dyn`,
//! `LinearNoiseModel`) against independent references:
//!
//! - the static `maximize` on the same problem, its likelihood coded with the static
//!   `KalmanFilter` (a different filter than `LinearNoiseModel`'s `DMatrix` one):
//!   estimates and standard errors equal to 1e-9 relative;
//! - `LinearNoiseModel`'s log-likelihood against `DynKalmanFilter::filter_series`'s;
//! - its dual-number gradient and information against central finite differences;
//! - the numbers `python/tests/test_fit_noise.py` compares `estim.fit_noise` with,
//!   committed in `python/tests/data/noise_fit_rust.json` (recomputed here, to 1e-12;
//!   `ESTIM_WRITE_EXPECTED=1` rewrites the file);
//! - typed errors.
//!
//! Seeded (ChaCha8), deterministic.

use estim_core::dynamic::{DynKalmanFilter, MeasurementSeries};
use estim_core::nalgebra::{DMatrix, DVector, SMatrix, SVector};
use estim_core::noise::ml::{
    gradient_dyn, maximize, maximize_dyn, observed_information_dyn, Bounds, DynBounds,
    DynLogLikelihood, FitOptions, FitStop, LinearNoiseModel, LogLikelihood, NoiseParameters,
};
use estim_core::numeric::lit;
use estim_core::{Error, KalmanFilter, Result, Scalar, StateAndCovariance, Zero};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde_json::{json, Value};

/// A model (F, Q_0, H, R_0, x0, P0) and its measurements, simulated with Q = q Q_0 and
/// R = r R_0 (`true_scales`), every `missing`-th step unmeasured.
struct Problem {
    f: DMatrix<f64>,
    q: DMatrix<f64>,
    h: DMatrix<f64>,
    r: DMatrix<f64>,
    x0: DVector<f64>,
    p0: DMatrix<f64>,
    ys: Vec<Option<DVector<f64>>>,
}

fn simulate(
    seed: u64,
    model: (DMatrix<f64>, DMatrix<f64>, DMatrix<f64>, DMatrix<f64>),
    true_noise: (&DMatrix<f64>, &DMatrix<f64>),
    steps: usize,
    missing: usize,
) -> Problem {
    let (f, q, h, r) = model;
    let (n, m) = (f.nrows(), h.nrows());
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut normals = |k: usize| -> DVector<f64> {
        DVector::from_fn(k, |_, _| {
            let z: f64 = StandardNormal.sample(&mut rng);
            z
        })
    };
    let lq = true_noise
        .0
        .clone()
        .cholesky()
        .expect("Q positive definite")
        .l();
    let lr = true_noise
        .1
        .clone()
        .cholesky()
        .expect("R positive definite")
        .l();
    let x0 = DVector::zeros(n);
    let p0 = DMatrix::identity(n, n) * 10.0;
    let mut x = &p0.clone().cholesky().expect("P0").l() * normals(n);
    let ys = (1..=steps)
        .map(|k| {
            x = &f * &x + &lq * normals(n);
            let y = &h * &x + &lr * normals(m);
            (k % missing != 0).then_some(y)
        })
        .collect();
    Problem {
        f,
        q,
        h,
        r,
        x0,
        p0,
        ys,
    }
}

/// A constant-velocity track (dt = 0.5) seen in position: Q_0 the white-acceleration
/// block, R_0 = 1; simulated with q = 0.5, r = 0.3; 300 steps, every 10th missing.
fn tracking() -> Problem {
    let dt: f64 = 0.5;
    let f = DMatrix::from_row_slice(2, 2, &[1.0, dt, 0.0, 1.0]);
    let q0 = DMatrix::from_row_slice(2, 2, &[dt.powi(3) / 3.0, dt * dt / 2.0, dt * dt / 2.0, dt]);
    let h = DMatrix::from_row_slice(1, 2, &[1.0, 0.0]);
    let r0 = DMatrix::identity(1, 1);
    let (q, r) = (&q0 * 0.5, &r0 * 0.3);
    simulate(7, (f, q0, h, r0), (&q, &r), 300, 10)
}

fn scales_model(p: &Problem) -> LinearNoiseModel {
    LinearNoiseModel::new(
        p.f.clone(),
        p.q.clone(),
        p.h.clone(),
        p.r.clone(),
        p.x0.clone(),
        p.p0.clone(),
        p.ys.clone(),
        NoiseParameters::Scales,
    )
    .expect("a valid model")
}

/// The same likelihood through the static `KalmanFilter` (2 states, 1 measurement).
struct StaticTracking<'a>(&'a Problem);

impl LogLikelihood<2> for StaticTracking<'_> {
    fn log_likelihood<T: Scalar>(&self, theta: &SVector<T, 2>) -> Result<T> {
        let p = self.0;
        let s2 = |m: &DMatrix<f64>| SMatrix::<T, 2, 2>::from_fn(|i, j| lit(m[(i, j)]));
        let initial =
            StateAndCovariance::new(SVector::<T, 2>::from_fn(|i, _| lit(p.x0[i])), s2(&p.p0))?;
        let h = SMatrix::<T, 1, 2>::from_fn(|i, j| lit(p.h[(i, j)]));
        let r = SMatrix::<T, 1, 1>::new(lit::<T>(p.r[(0, 0)]) * theta[1]);
        let mut kf = KalmanFilter::new(s2(&p.f), s2(&p.q) * theta[0], h, r, initial)?;
        for y in &p.ys {
            let y = y.as_ref().map(|y| SVector::<T, 1>::new(lit(y[0])));
            kf.step(y.as_ref(), &Zero)?;
        }
        Ok(kf.log_likelihood())
    }
}

fn relative(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs()
}

#[test]
fn maximize_dyn_equals_the_static_maximize() {
    let problem = tracking();
    // The default decrement tolerance (1e-10) stops a fit within sqrt(2e-10) = 1.4e-5
    // standard errors of the optimum: two fits of likelihoods that differ by round-off
    // stop at points up to that far apart (measured 1.6e-7 relative in theta). Newton's
    // quadratic convergence takes both to the optimum to round-off in one or two more
    // steps, which a tolerance of 1e-20 asks for.
    let options = FitOptions {
        decrement_tolerance: 1e-20,
        ..FitOptions::default()
    };
    let positive =
        Bounds::new(SVector::from([0.0, 0.0]), SVector::from([f64::INFINITY; 2])).expect("bounds");
    let fixed = maximize(
        &StaticTracking(&problem),
        &SVector::from([1.0, 1.0]),
        &positive,
        &options,
    )
    .expect("the static fit runs");
    let model = scales_model(&problem);
    let dyn_bounds =
        DynBounds::new(DVector::zeros(2), DVector::from_element(2, f64::INFINITY)).expect("bounds");
    let dynamic = maximize_dyn(&model, &model.initial_parameters(), &dyn_bounds, &options)
        .expect("the dynamic fit runs");
    assert_eq!(fixed.stop, FitStop::Converged);
    assert_eq!(dynamic.stop, FitStop::Converged);
    let (se_static, se_dyn) = (
        fixed.standard_errors.expect("static standard errors"),
        dynamic.standard_errors.expect("dynamic standard errors"),
    );
    let mut worst: f64 = 0.0;
    for i in 0..2 {
        worst = worst
            .max(relative(dynamic.theta[i], fixed.theta[i]))
            .max(relative(se_dyn[i], se_static[i]));
    }
    // Two filter codes (static runner, LinearNoiseModel's DMatrix filter) and one
    // optimiser: they differ by round-off in the likelihood only.
    eprintln!(
        "theta {:?} (se {:?}) vs static {:?} (se {:?}): {worst:.1e} relative; log-likelihood {:.1e}",
        dynamic.theta.as_slice(),
        se_dyn.as_slice(),
        fixed.theta.as_slice(),
        se_static.as_slice(),
        relative(dynamic.log_likelihood, fixed.log_likelihood)
    );
    assert!(worst < 1e-9, "{worst:.1e}");
    assert!(relative(dynamic.log_likelihood, fixed.log_likelihood) < 1e-12);
    // The truth (0.5, 0.3) within 3 standard errors.
    assert!((dynamic.theta[0] - 0.5).abs() < 3.0 * se_dyn[0]);
    assert!((dynamic.theta[1] - 0.3).abs() < 3.0 * se_dyn[1]);
}

/// The same scalar problem through a trait object-free wrapper: a `DynLogLikelihood`
/// that calls the static one, so both fits run the same likelihood bit for bit and
/// must end at the same point exactly (the shared optimiser).
struct Wrapped<'a>(StaticTracking<'a>);

impl DynLogLikelihood for Wrapped<'_> {
    fn log_likelihood<T: Scalar>(&self, theta: &DVector<T>) -> Result<T> {
        self.0
            .log_likelihood(&SVector::<T, 2>::from_column_slice(theta.as_slice()))
    }
}

#[test]
fn one_optimiser_bit_for_bit() {
    let problem = tracking();
    let options = FitOptions::default();
    let positive =
        Bounds::new(SVector::from([0.0, 0.0]), SVector::from([f64::INFINITY; 2])).expect("bounds");
    let fixed = maximize(
        &StaticTracking(&problem),
        &SVector::from([2.0, 0.5]),
        &positive,
        &options,
    )
    .expect("static");
    let dynamic = maximize_dyn(
        &Wrapped(StaticTracking(&problem)),
        &DVector::from_column_slice(&[2.0, 0.5]),
        &DynBounds::new(DVector::zeros(2), DVector::from_element(2, f64::INFINITY))
            .expect("bounds"),
        &options,
    )
    .expect("dynamic");
    assert_eq!(dynamic.theta.as_slice(), fixed.theta.as_slice());
    assert_eq!(dynamic.information.as_slice(), fixed.information.as_slice());
    assert_eq!(dynamic.iterations, fixed.iterations);
    assert_eq!(dynamic.log_likelihood, fixed.log_likelihood);
}

/// A 2-state, 2-measurement problem with diagonal noise to fit (also the Python
/// expected values).
fn diagonal_problem() -> Problem {
    let f = DMatrix::from_row_slice(2, 2, &[0.9, 0.2, -0.1, 0.8]);
    let h = DMatrix::from_row_slice(2, 2, &[1.0, 0.0, 0.5, 1.0]);
    let q_true = DMatrix::from_diagonal(&DVector::from_column_slice(&[0.4, 0.1]));
    let r_true = DMatrix::from_diagonal(&DVector::from_column_slice(&[0.2, 0.5]));
    let q0 = DMatrix::from_row_slice(2, 2, &[1.0, 0.1, 0.1, 1.0]);
    let r0 = DMatrix::identity(2, 2);
    simulate(48, (f, q0, h, r0), (&q_true, &r_true), 200, 9)
}

fn diagonal_model(p: &Problem) -> LinearNoiseModel {
    LinearNoiseModel::new(
        p.f.clone(),
        p.q.clone(),
        p.h.clone(),
        p.r.clone(),
        p.x0.clone(),
        p.p0.clone(),
        p.ys.clone(),
        NoiseParameters::Diagonals,
    )
    .expect("a valid model")
}

#[test]
fn linear_noise_model_equals_the_dynamic_filter() {
    let p = diagonal_problem();
    let model = diagonal_model(&p);
    let theta = DVector::from_column_slice(&[0.3, 0.2, 0.25, 0.4]);
    let ours = model.log_likelihood(&theta).expect("evaluates");
    let (q, r) = model.noise_at(&theta).expect("sizes");
    let mut kf = DynKalmanFilter::new(p.f.clone(), q, p.h.clone(), r, p.x0.clone(), p.p0.clone())
        .expect("valid");
    let values: Vec<f64> =
        p.ys.iter()
            .flat_map(|y| match y {
                Some(y) => y.iter().copied().collect::<Vec<_>>(),
                None => vec![f64::NAN; 2],
            })
            .collect();
    let series = MeasurementSeries::new(&values, 2).expect("series");
    let theirs = kf
        .filter_series(&series, None)
        .expect("filters")
        .log_likelihood;
    // Measured 1.2e-16 (round-off of two update codes).
    eprintln!(
        "log-likelihood {ours} vs DynKalmanFilter {theirs}: {:.1e}",
        relative(ours, theirs)
    );
    assert!(relative(ours, theirs) < 1e-12);
}

#[test]
fn derivatives_equal_finite_differences() {
    let p = diagonal_problem();
    let model = diagonal_model(&p);
    let theta = DVector::from_column_slice(&[0.3, 0.2, 0.25, 0.4]);
    let fixed = [false; 4];
    let (value, grad) = gradient_dyn(&model, &theta, &fixed).expect("gradient");
    let info = observed_information_dyn(&model, &theta, &fixed).expect("information");
    let at = |t: &DVector<f64>| model.log_likelihood(t).expect("evaluates");
    // The dual pass's real part and the f64 pass: the same operations, but ln and sqrt
    // of dual numbers may round differently in the last bit.
    assert!(relative(value, at(&theta)) < 1e-14);
    let (mut worst_g, mut worst_h): (f64, f64) = (0.0, 0.0);
    for i in 0..4 {
        let step = 1e-5 * theta[i];
        let shifted = |d: f64| {
            let mut t = theta.clone();
            t[i] += d;
            t
        };
        let fd = (at(&shifted(step)) - at(&shifted(-step))) / (2.0 * step);
        worst_g = worst_g.max((grad[i] - fd).abs() / grad.amax());
        let (_, up) = gradient_dyn(&model, &shifted(step), &fixed).expect("gradient");
        let (_, down) = gradient_dyn(&model, &shifted(-step), &fixed).expect("gradient");
        for j in 0..4 {
            let fd = -(up[j] - down[j]) / (2.0 * step);
            worst_h = worst_h.max((info[(i, j)] - fd).abs() / info.amax());
        }
    }
    // Central differences of step 1e-5 theta: truncation ~1e-10, round-off ~1e-11
    // relative to the largest entry.
    eprintln!("finite differences: gradient {worst_g:.1e}, information {worst_h:.1e}");
    assert!(
        worst_g < 1e-6 && worst_h < 1e-6,
        "{worst_g:.1e} {worst_h:.1e}"
    );
}

fn rows(m: &DMatrix<f64>) -> Value {
    json!((0..m.nrows())
        .map(|i| m.row(i).iter().copied().collect::<Vec<_>>())
        .collect::<Vec<_>>())
}

fn fit_case(p: &Problem, parameters: NoiseParameters) -> Value {
    let model = LinearNoiseModel::new(
        p.f.clone(),
        p.q.clone(),
        p.h.clone(),
        p.r.clone(),
        p.x0.clone(),
        p.p0.clone(),
        p.ys.clone(),
        parameters,
    )
    .expect("valid");
    let count = model.parameter_count();
    let bounds = DynBounds::new(
        DVector::zeros(count),
        DVector::from_element(count, f64::INFINITY),
    )
    .expect("bounds");
    let fit = maximize_dyn(
        &model,
        &model.initial_parameters(),
        &bounds,
        &FitOptions::default(),
    )
    .expect("fits");
    assert_eq!(fit.stop, FitStop::Converged);
    let se = fit.standard_errors.expect("standard errors");
    json!({
        "theta": fit.theta.as_slice(),
        "standard_errors": se.as_slice(),
        "log_likelihood": fit.log_likelihood,
    })
}

fn python_path() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../python/tests/data/noise_fit_rust.json")
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
fn committed_values_are_the_rust_fits() {
    let p = diagonal_problem();
    let now = json!({
        "F": rows(&p.f), "Q": rows(&p.q), "H": rows(&p.h), "R": rows(&p.r),
        "x0": p.x0.as_slice(), "P0": rows(&p.p0),
        "zs": p.ys.iter().map(|y| match y {
            Some(y) => json!(y.as_slice()),
            None => Value::Null,
        }).collect::<Vec<_>>(),
        "scales": fit_case(&p, NoiseParameters::Scales),
        "diagonals": fit_case(&p, NoiseParameters::Diagonals),
    });
    if std::env::var_os("ESTIM_WRITE_EXPECTED").is_some_and(|v| v == "1") {
        let text = serde_json::to_string_pretty(&now).expect("serializable");
        std::fs::write(python_path(), text + "\n").expect("writable python/tests/data");
        return;
    }
    let text =
        std::fs::read_to_string(python_path()).expect("python/tests/data/noise_fit_rust.json");
    let committed: Value = serde_json::from_str(&text).expect("valid JSON");
    for (key, value) in now.as_object().expect("object") {
        assert!(!committed[key].is_null(), "{key} missing");
        same(&committed[key], value, key);
    }
}

#[test]
fn sizes_are_checked() {
    let p = diagonal_problem();
    let model = diagonal_model(&p);
    assert!(matches!(
        model.log_likelihood(&DVector::from_element(3, 0.5)),
        Err(Error::Dimension {
            what: "noise parameters",
            expected: 4,
            got: 3
        })
    ));
    let bounds = DynBounds::unbounded(4);
    assert!(matches!(
        maximize_dyn(
            &model,
            &DVector::from_element(2, 0.5),
            &bounds,
            &FitOptions::default()
        ),
        Err(Error::Dimension {
            expected: 4,
            got: 2,
            ..
        })
    ));
    assert!(matches!(
        DynBounds::new(DVector::zeros(2), DVector::zeros(3)),
        Err(Error::Dimension {
            expected: 2,
            got: 3,
            ..
        })
    ));
    assert!(matches!(
        DynBounds::new(DVector::from_element(1, 1.0), DVector::zeros(1)),
        Err(Error::InvalidParameter { name: "bounds", .. })
    ));
    assert!(matches!(
        gradient_dyn(&model, &DVector::from_element(4, 0.5), &[false; 3]),
        Err(Error::Dimension { .. })
    ));
    let mut ys = p.ys.clone();
    ys[3] = Some(DVector::from_element(3, 0.0));
    assert!(matches!(
        LinearNoiseModel::new(
            p.f.clone(),
            p.q.clone(),
            p.h.clone(),
            p.r.clone(),
            p.x0.clone(),
            p.p0.clone(),
            ys,
            NoiseParameters::Scales
        ),
        Err(Error::Dimension {
            what: "measurement",
            expected: 2,
            got: 3
        })
    ));
    // A start on the bound is refused (strictly inside, as the static fit).
    let positive =
        DynBounds::new(DVector::zeros(4), DVector::from_element(4, f64::INFINITY)).expect("bounds");
    assert!(matches!(
        maximize_dyn(
            &model,
            &DVector::from_column_slice(&[0.0, 1.0, 1.0, 1.0]),
            &positive,
            &FitOptions::default()
        ),
        Err(Error::InvalidParameter {
            name: "initial",
            ..
        })
    ));
    // Fixed parameters keep their value and get standard error 0.
    let fixed = positive.fix(1, 0.1).expect("fix");
    let fit = maximize_dyn(
        &model,
        &DVector::from_column_slice(&[0.5, 0.1, 0.5, 0.5]),
        &fixed,
        &FitOptions::default(),
    )
    .expect("fits");
    assert_eq!(fit.theta[1], 0.1);
    assert_eq!(fit.standard_errors.expect("se")[1], 0.0);
}
