//! `estim_core::dynamic` against the static runners on the same problems: every
//! predict, update (plain and correlated), report, series filter and smoother of
//! [`DynKalmanFilter`] equals [`KalmanFilter`]'s (and its `filter_batch` /
//! `smooth_batch`) to 1e-12 relative, at (4, 2) and (6, 3), with M = 0 and a valid
//! correlated M, with missing measurements; the typed errors (shapes, invalid joint
//! covariance, partly missing rows); and n = 500 on a 2 MiB thread stack.
//!
//! Problems are seeded (ChaCha8); the static filter is the independent reference (its
//! own code, const-generic sizes, the square-root posterior by default).

use estim_core::dynamic::{DynKalmanFilter, FilteredSeries, MeasurementSeries};
use estim_core::nalgebra::{DMatrix, DVector, SMatrix, SVector};
use estim_core::{Error, Fixed, JointCheck, KalmanFilter, StateAndCovariance, Zero};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A linear-Gaussian problem of n states and m measurements: stable F, joint noise
/// [[Q, M], [M', R]] = L L' (so M is a valid cross-covariance), H, x0, P0, and a
/// simulated series with every `gap`-th measurement missing.
struct Problem {
    f: DMatrix<f64>,
    q: DMatrix<f64>,
    h: DMatrix<f64>,
    r: DMatrix<f64>,
    m: DMatrix<f64>,
    x0: DVector<f64>,
    p0: DMatrix<f64>,
    /// Measurements, `None` where missing.
    ys: Vec<Option<DVector<f64>>>,
}

fn problem(n: usize, m: usize, steps: usize, gap: usize, seed: u64) -> Problem {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut u = |scale: f64| rng.random_range(-scale..scale);
    let f = DMatrix::from_fn(n, n, |i, j| {
        if i == j {
            0.95
        } else if j == i + 1 {
            0.1
        } else {
            0.0
        }
    }) + DMatrix::from_fn(n, n, |_, _| u(0.02));
    let l = DMatrix::from_fn(n + m, n + m, |i, j| if j <= i { u(0.5) } else { 0.0 })
        + DMatrix::identity(n + m, n + m) * 0.3;
    let joint = &l * l.transpose();
    let q = joint.view((0, 0), (n, n)).into_owned();
    let cross = joint.view((0, n), (n, m)).into_owned();
    let r = joint.view((n, n), (m, m)).into_owned();
    let h = DMatrix::from_fn(m, n, |_, _| u(1.0));
    let x0 = DVector::from_fn(n, |_, _| u(1.0));
    let g = DMatrix::from_fn(n, n, |_, _| u(1.0));
    let p0 = &g * g.transpose() + DMatrix::identity(n, n);
    // Simulate with the joint noise: [w; v] = L e.
    let mut x = x0.clone();
    let mut ys = Vec::with_capacity(steps);
    for k in 0..steps {
        let e = DVector::from_fn(n + m, |_, _| u(1.7));
        let noise = &l * e;
        x = &f * &x + noise.rows(0, n);
        let y = &h * &x + noise.rows(n, m);
        ys.push(if gap > 0 && k % gap == gap - 1 {
            None
        } else {
            Some(y)
        });
    }
    Problem {
        f,
        q,
        h,
        r,
        m: cross,
        x0,
        p0,
        ys,
    }
}

fn s<const R: usize, const C: usize>(a: &DMatrix<f64>) -> SMatrix<f64, R, C> {
    SMatrix::from_column_slice(a.as_slice())
}

fn dynamic(p: &Problem) -> DynKalmanFilter {
    DynKalmanFilter::new(
        p.f.clone(),
        p.q.clone(),
        p.h.clone(),
        p.r.clone(),
        p.x0.clone(),
        p.p0.clone(),
    )
    .expect("valid problem")
}

fn static_filter<const N: usize, const M: usize>(p: &Problem) -> KalmanFilter<f64, N, M> {
    let initial = StateAndCovariance::new(SVector::from_column_slice(p.x0.as_slice()), s(&p.p0))
        .expect("valid initial");
    KalmanFilter::new(s(&p.f), s(&p.q), s(&p.h), s(&p.r), initial).expect("valid problem")
}

/// max |a - b| / max(max |b|, 1e-300): relative to the reference's largest entry.
fn relative(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(0.0f64, |s, v| s.max(v.abs())).max(1e-300);
    a.iter()
        .zip(b)
        .fold(0.0f64, |e, (x, y)| e.max((x - y).abs()))
        / scale
}

const TOL: f64 = 1e-12;

/// Step by step: predicts, plain or correlated updates, reports (NIS,
/// log-likelihood, joint margin) and the cumulative log-likelihood.
fn step_by_step<const N: usize, const M: usize>(seed: u64, correlated: bool) -> f64 {
    let p = problem(N, M, 60, 4, seed);
    let mut dynamic = dynamic(&p);
    let mut reference = static_filter::<N, M>(&p);
    let cross = Fixed(s::<N, M>(&p.m));
    let mut worst = 0.0f64;
    for y in &p.ys {
        dynamic.predict().unwrap();
        reference.predict().unwrap();
        if let Some(y) = y {
            let ys = SVector::<f64, M>::from_column_slice(y.as_slice());
            let (ours, theirs) = if correlated {
                (
                    dynamic.update_correlated(y, &p.m).unwrap(),
                    reference.update(&ys, &cross).unwrap(),
                )
            } else {
                (
                    dynamic.update(y).unwrap(),
                    reference.update(&ys, &Zero).unwrap(),
                )
            };
            assert!(ours.accepted);
            worst = worst
                .max(relative(&[ours.nis], &[theirs.nis]))
                .max(relative(&[ours.log_likelihood], &[theirs.log_likelihood]))
                .max(relative(
                    dynamic.innovation().as_slice(),
                    theirs.innovation.as_slice(),
                ))
                .max(relative(
                    dynamic.innovation_covariance().as_slice(),
                    theirs.innovation_covariance.as_slice(),
                ))
                .max(relative(
                    dynamic.gain().as_slice(),
                    theirs.gain.unwrap().as_slice(),
                ));
            let (a, b) = (
                ours.joint_min_eigenvalue.unwrap(),
                theirs.joint_min_eigenvalue.unwrap(),
            );
            assert!((a - b).abs() <= 1e-9, "joint margin {a} vs {b}");
            assert!(a >= 0.0);
        }
        worst = worst
            .max(relative(
                dynamic.state().as_slice(),
                reference.estimate().state().as_slice(),
            ))
            .max(relative(
                dynamic.covariance().as_slice(),
                reference.estimate().covariance().as_slice(),
            ));
    }
    worst = worst.max(relative(
        &[dynamic.log_likelihood()],
        &[reference.log_likelihood()],
    ));
    assert!(
        worst <= TOL,
        "({N}, {M}) correlated {correlated}: {worst:e}"
    );
    eprintln!("steps ({N}, {M}) correlated {correlated} seed {seed}: worst relative {worst:.1e}");
    worst
}

#[test]
fn steps_equal_the_static_filter_4_2_and_6_3() {
    for seed in 1..=3 {
        step_by_step::<4, 2>(seed, false);
        step_by_step::<6, 3>(seed, false);
        step_by_step::<4, 2>(seed, true);
        step_by_step::<6, 3>(seed, true);
    }
}

/// `filter_and_smooth` (one call) against the static `filter_batch` and
/// `smooth_batch` (two): filtered, smoothed (and smoothed x_0), log-likelihood, with
/// missing measurements (M = 0) and with a correlated M on a fully measured series.
fn series<const N: usize, const M: usize>(seed: u64, correlated: bool) {
    let gap = if correlated { 0 } else { 3 };
    let p = problem(N, M, 80, gap, seed);
    let values: Vec<f64> =
        p.ys.iter()
            .flat_map(|y| match y {
                Some(y) => y.iter().copied().collect::<Vec<_>>(),
                None => vec![f64::NAN; M],
            })
            .collect();
    let measurements = MeasurementSeries::new(&values, M).unwrap();
    let ys: Vec<Option<SVector<f64, M>>> =
        p.ys.iter()
            .map(|y| y.as_ref().map(|y| SVector::from_column_slice(y.as_slice())))
            .collect();
    let kf = dynamic(&p);
    let cross = correlated.then_some(&p.m);
    let out = kf.filter_and_smooth(&measurements, cross).unwrap();
    let mut reference = static_filter::<N, M>(&p);
    let (smoothed, filtered) = if correlated {
        let m = Fixed(s::<N, M>(&p.m));
        (
            reference.smooth_batch(&ys, &m).unwrap(),
            reference.filter_batch(&ys, &m).unwrap(),
        )
    } else {
        (
            reference.smooth_batch(&ys, &Zero).unwrap(),
            reference.filter_batch(&ys, &Zero).unwrap(),
        )
    };
    let mut worst = relative(&[out.filtered.log_likelihood], &[filtered.log_likelihood]);
    for (k, y) in ys.iter().enumerate() {
        worst = worst
            .max(relative(
                out.filtered.estimates.state(k).as_slice(),
                filtered.estimates[k].state().as_slice(),
            ))
            .max(relative(
                out.filtered
                    .estimates
                    .covariance(k)
                    .clone_owned()
                    .as_slice(),
                filtered.estimates[k].covariance().as_slice(),
            ))
            .max(relative(
                out.smoothed.state(k).as_slice(),
                smoothed.estimates[k].state().as_slice(),
            ))
            .max(relative(
                out.smoothed.covariance(k).clone_owned().as_slice(),
                smoothed.estimates[k].covariance().as_slice(),
            ));
        assert_eq!(out.filtered.accepted[k], y.is_some());
        assert_eq!(out.filtered.nis[k].is_nan(), y.is_none());
    }
    worst = worst
        .max(relative(
            out.smoothed_initial_state.as_slice(),
            smoothed.initial.state().as_slice(),
        ))
        .max(relative(
            out.smoothed_initial_covariance.as_slice(),
            smoothed.initial.covariance().as_slice(),
        ));
    assert!(
        worst <= TOL,
        "({N}, {M}) correlated {correlated}: {worst:e}"
    );
    eprintln!("series ({N}, {M}) correlated {correlated} seed {seed}: worst relative {worst:.1e}");
    // The smoother changed something (a test that cannot pass by copying the filter).
    assert!(relative(out.smoothed.states(), out.filtered.estimates.states()) > 1e-3);
    // The filter itself was left untouched.
    assert_eq!(kf.state(), &p.x0);
}

#[test]
fn filter_and_smooth_equal_the_static_batches() {
    for seed in 1..=3 {
        series::<4, 2>(seed, false);
        series::<6, 3>(seed, false);
        series::<4, 2>(seed, true);
        series::<6, 3>(seed, true);
    }
}

/// A mask gives the same result as NaN rows; `filter_series` advances the filter as
/// the step loop does, bit for bit.
#[test]
fn mask_and_nan_rows_agree_and_series_equals_the_step_loop() {
    let p = problem(5, 2, 40, 4, 9);
    let mut values = Vec::new();
    let mut mask = Vec::new();
    let mut with_nan = Vec::new();
    for y in &p.ys {
        match y {
            Some(y) => {
                values.extend(y.iter());
                with_nan.extend(y.iter());
                mask.push(true);
            }
            None => {
                values.extend([123.0, -4.0]); // ignored: masked out
                with_nan.extend([f64::NAN; 2]);
                mask.push(false);
            }
        }
    }
    let masked = MeasurementSeries::new(&values, 2)
        .unwrap()
        .with_mask(&mask)
        .unwrap();
    let nan_rows = MeasurementSeries::new(&with_nan, 2).unwrap();
    let kf = dynamic(&p);
    let a = kf.filter_and_smooth(&masked, None).unwrap();
    let b = kf.filter_and_smooth(&nan_rows, None).unwrap();
    assert_same(&a.filtered, &b.filtered);
    assert_eq!(a.smoothed, b.smoothed);
    assert_eq!(a.smoothed_initial_covariance, b.smoothed_initial_covariance);
    let mut series = dynamic(&p);
    let batch = series.filter_series(&nan_rows, None).unwrap();
    let mut stepped = dynamic(&p);
    for (k, y) in p.ys.iter().enumerate() {
        stepped.predict().unwrap();
        if let Some(y) = y {
            stepped.update(y).unwrap();
        }
        assert_eq!(&batch.estimates.state(k).clone_owned(), stepped.state());
        assert_eq!(
            &batch.estimates.covariance(k).clone_owned(),
            stepped.covariance()
        );
    }
    assert_eq!(series.state(), stepped.state());
    assert_eq!(batch.log_likelihood, stepped.log_likelihood());
    assert_same(&batch, &a.filtered);
}

/// Equal bit for bit (NaN NIS of missing steps included).
fn assert_same(a: &FilteredSeries, b: &FilteredSeries) {
    assert_eq!(a.estimates, b.estimates);
    assert_eq!(a.accepted, b.accepted);
    assert_eq!(a.log_likelihood.to_bits(), b.log_likelihood.to_bits());
    let bits = |s: &FilteredSeries| s.nis.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(a), bits(b));
}

/// Typed errors naming what was wrong, and nothing committed on an error.
#[test]
fn wrong_shapes_and_invalid_inputs_are_typed_errors() {
    let p = problem(4, 2, 1, 0, 3);
    let bad_h = DMatrix::zeros(2, 3);
    let err = DynKalmanFilter::new(
        p.f.clone(),
        p.q.clone(),
        bad_h,
        p.r.clone(),
        p.x0.clone(),
        p.p0.clone(),
    )
    .unwrap_err();
    assert_eq!(
        err,
        Error::Dimension {
            what: "observation matrix H (columns)",
            expected: 4,
            got: 3
        }
    );
    let not_psd = DMatrix::from_row_slice(2, 2, &[1.0, 2.0, 2.0, 1.0]);
    let err = DynKalmanFilter::new(
        p.f.clone(),
        p.q.clone(),
        p.h.clone(),
        not_psd,
        p.x0.clone(),
        p.p0.clone(),
    )
    .unwrap_err();
    assert!(
        matches!(
            err,
            Error::InvalidCovariance {
                what: "measurement noise R",
                ..
            }
        ),
        "{err}"
    );
    let mut kf = dynamic(&p);
    kf.predict().unwrap();
    let before = (kf.state().clone(), kf.covariance().clone());
    assert!(matches!(
        kf.update(&DVector::zeros(3)),
        Err(Error::Dimension {
            what: "measurement y",
            expected: 2,
            got: 3
        })
    ));
    assert!(matches!(
        kf.update(&DVector::from_vec(vec![1.0, f64::NAN])),
        Err(Error::NonFinite { .. })
    ));
    // |corr| > 1 between a state's noise and the measurement noise: not a covariance.
    let mut invalid = DMatrix::zeros(4, 2);
    invalid[(0, 0)] = 10.0 * (p.q[(0, 0)] * p.r[(0, 0)]).sqrt();
    let err = kf
        .update_correlated(&DVector::zeros(2), &invalid)
        .unwrap_err();
    let Error::InvalidJointCovariance { min_eigenvalue } = err else {
        panic!("{err}")
    };
    assert!(min_eigenvalue < -0.5, "{min_eigenvalue}");
    assert_eq!((kf.state(), kf.covariance()), (&before.0, &before.1));
    // The same M with JointCheck::Report is used, and its margin reported as the
    // static runner reports it.
    let mut report_only = dynamic(&p).with_joint_check(JointCheck::Report);
    let mut reference = static_filter::<4, 2>(&p).with_config(
        estim_core::FilterConfig::builder()
            .joint_check(JointCheck::Report)
            .build()
            .unwrap(),
    );
    report_only.predict().unwrap();
    reference.predict().unwrap();
    let ours = report_only
        .update_correlated(&DVector::zeros(2), &invalid)
        .unwrap();
    let theirs = reference
        .update(&SVector::zeros(), &Fixed(s::<4, 2>(&invalid)))
        .unwrap();
    let (a, b) = (
        ours.joint_min_eigenvalue.unwrap(),
        theirs.joint_min_eigenvalue.unwrap(),
    );
    assert!((a - b).abs() < 1e-12, "{a} vs {b}");
    // A partly NaN row is refused.
    let values = [1.0, f64::NAN];
    let series = MeasurementSeries::new(&values, 2).unwrap();
    assert!(matches!(
        dynamic(&p).filter_series(&series, None),
        Err(Error::NonFinite { .. })
    ));
    assert!(MeasurementSeries::new(&values, 3).is_err());
}

/// A correlated update after an unmeasured step cannot be smoothed exactly: refused
/// by name, as the static `smooth_batch` refuses it.
#[test]
fn correlated_update_after_a_gap_is_not_smoothed() {
    let p = problem(4, 2, 9, 3, 4);
    let values: Vec<f64> =
        p.ys.iter()
            .flat_map(|y| {
                y.clone()
                    .map_or(vec![f64::NAN; 2], |y| y.as_slice().to_vec())
            })
            .collect();
    let series = MeasurementSeries::new(&values, 2).unwrap();
    let err = dynamic(&p)
        .filter_and_smooth(&series, Some(&p.m))
        .unwrap_err();
    assert!(
        matches!(err, Error::SmootherUnsupported { epoch: 4, .. }),
        "{err}"
    );
    let ys: Vec<Option<SVector<f64, 2>>> =
        p.ys.iter()
            .map(|y| y.as_ref().map(|y| SVector::from_column_slice(y.as_slice())))
            .collect();
    assert!(matches!(
        static_filter::<4, 2>(&p).smooth_batch(&ys, &Fixed(s::<4, 2>(&p.m))),
        Err(Error::SmootherUnsupported { .. })
    ));
}

/// n = 500, m = 10: construct, filter and smooth in a thread with a 2 MiB stack (the
/// default of a test thread); results finite and the smoothed variances no larger
/// than the filtered ones.
#[test]
fn five_hundred_states_run_on_a_two_mebibyte_stack() {
    let handle = std::thread::Builder::new()
        .stack_size(2 << 20)
        .spawn(|| {
            let (n, m, steps) = (500, 10, 6);
            let f = DMatrix::identity(n, n) * 0.99;
            let q = DMatrix::identity(n, n) * 0.01;
            let h = DMatrix::from_fn(m, n, |i, j| if j % m == i { 1.0 } else { 0.0 });
            let r = DMatrix::identity(m, m) * 0.1;
            let kf = DynKalmanFilter::new(f, q, h, r, DVector::zeros(n), DMatrix::identity(n, n))
                .unwrap();
            let values: Vec<f64> = (0..steps * m).map(|i| (i as f64 * 0.37).sin()).collect();
            let out = kf
                .filter_and_smooth(&MeasurementSeries::new(&values, m).unwrap(), None)
                .unwrap();
            assert_eq!(out.smoothed.len(), steps);
            assert!(out.smoothed.states().iter().all(|v| v.is_finite()));
            for k in 0..steps {
                for i in 0..n {
                    let (sv, fv) = (
                        out.smoothed.covariance(k)[(i, i)],
                        out.filtered.estimates.covariance(k)[(i, i)],
                    );
                    assert!(sv <= fv * (1.0 + 1e-12), "step {k} state {i}: {sv} > {fv}");
                }
            }
            out.filtered.log_likelihood
        })
        .unwrap();
    assert!(handle.join().unwrap().is_finite());
}

/// `estim_core::dmatrix!` / `dvector!` build the same matrices as nalgebra's
/// constructors.
#[test]
fn macros_build_row_major_literals() {
    let a = estim_core::dmatrix![1.0, 2.0, 3.0; 4.0, 5.0, 6.0];
    assert_eq!(
        a,
        DMatrix::from_row_slice(2, 3, &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    );
    let v = estim_core::dvector![1, 2.5];
    assert_eq!(v, DVector::from_vec(vec![1.0, 2.5]));
}

/// The free functions against their static counterparts: the joint validity margin
/// (valid and invalid M, from the random problems and scaled up) and NEES.
#[test]
fn joint_margin_and_nees_equal_the_static_ones() {
    use estim_core::dynamic::{joint_validity_margin, normalised_squared_error};
    use estim_core::JointCovariance;
    let mut invalid = 0;
    for seed in 1..=5 {
        let p = problem(4, 2, 1, 0, seed);
        for scale in [0.0, 0.5, 1.0, 3.0, 10.0] {
            let m = &p.m * scale;
            let ours = joint_validity_margin(&p.q, &m, &p.r).unwrap();
            let theirs = JointCovariance::new(s::<4, 4>(&p.q), s::<4, 2>(&m), s::<2, 2>(&p.r))
                .validity_margin()
                .unwrap();
            assert!(
                (ours - theirs).abs() <= 1e-12,
                "seed {seed} scale {scale}: {ours} vs {theirs}"
            );
            invalid += usize::from(ours < 0.0);
        }
        let e = DVector::from_fn(4, |i, _| (i as f64 + seed as f64).sin());
        let ours = normalised_squared_error(&e, &p.p0).unwrap();
        let theirs = estim_core::consistency::nees(
            &SVector::<f64, 4>::from_column_slice(e.as_slice()),
            &s::<4, 4>(&p.p0),
        )
        .unwrap();
        assert!(
            (ours - theirs).abs() <= 1e-12 * theirs,
            "{ours} vs {theirs}"
        );
    }
    assert!(invalid >= 5, "{invalid}"); // both outcomes exercised
    assert!(matches!(
        joint_validity_margin(
            &DMatrix::zeros(2, 2),
            &DMatrix::zeros(3, 1),
            &DMatrix::zeros(1, 1)
        ),
        Err(Error::Dimension { .. })
    ));
}

/// pykalman's convention (epoch 0 measured at the initial state) run on the dynamic
/// filter: update at x_0, then predict + update. Its log-likelihood equals
/// `noise::em::log_likelihood` (the EM module's own filter) on the given model and
/// on the model EM fitted (Q and R learned over 5 iterations, which must raise the
/// likelihood), missing epochs included.
#[test]
fn log_likelihood_equals_the_em_modules_before_and_after_a_fit() {
    use estim_core::noise::em::{em, log_likelihood, EmVariables, LinearGaussianModel};
    let p = problem(3, 2, 60, 5, 12);
    let dynamic_log_likelihood = |model: &LinearGaussianModel| {
        let mut kf = DynKalmanFilter::new(
            model.transition_matrix().clone(),
            model.transition_covariance().clone(),
            model.observation_matrix().clone(),
            model.observation_covariance().clone(),
            model.initial_state_mean().clone(),
            model.initial_state_covariance().clone(),
        )
        .unwrap();
        for (k, y) in p.ys.iter().enumerate() {
            if k > 0 {
                kf.predict().unwrap();
            }
            if let Some(y) = y {
                kf.update(y).unwrap();
            }
        }
        kf.log_likelihood()
    };
    let model = LinearGaussianModel::new(
        p.f.clone(),
        p.h.clone(),
        DMatrix::identity(3, 3) * 0.3, // deliberately off, for EM to improve
        DMatrix::identity(2, 2) * 2.0,
        p.x0.clone(),
        p.p0.clone(),
    )
    .unwrap();
    let given = log_likelihood(&model, &p.ys).unwrap();
    let ours = dynamic_log_likelihood(&model);
    assert!(
        (ours - given).abs() <= 1e-12 * given.abs(),
        "{ours} vs {given}"
    );
    let fit = em(
        &model,
        &p.ys,
        EmVariables::TRANSITION_COVARIANCE | EmVariables::OBSERVATION_COVARIANCE,
        5,
    )
    .unwrap();
    let fitted = *fit.log_likelihoods.last().unwrap();
    assert!(fitted > given + 1.0, "{fitted} vs {given}");
    let ours = dynamic_log_likelihood(&fit.model);
    assert!(
        (ours - fitted).abs() <= 1e-12 * fitted.abs(),
        "{ours} vs {fitted}"
    );
}
