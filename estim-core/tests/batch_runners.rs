//! `filter_batch` and `smooth_batch` of the runners other than the linear
//! `KalmanFilter` (EKF, error-state EKF, square-root KF, unscented KF):
//!
//! - each runner's `filter_batch` equals its `step()` in a loop bit for bit (the estimate
//!   after every step, every report, the batch log-likelihood as the sum of the accepted
//!   reports' terms, the runner's end state, its cumulative `log_likelihood()` and the
//!   events its observer saw), on a mildly nonlinear model (for the model runners) with
//!   varying inputs and dt, some steps unmeasured, in three cases: M = 0, a `Fixed`
//!   M != 0, and a `Fixed` M with an innovation gate that rejects some (outlier)
//!   measurements (M = 0 through `Zero`);
//! - on a linear model, each runner's `smooth_batch` equals the `KalmanFilter`'s
//!   `smooth_batch` to 1e-12 (entries relative to the largest entry of the reference),
//!   for M = 0 with unmeasured steps and for a `Fixed` M != 0 at every step (the UKF
//!   with both update forms, sigma points over x and over [x; v]). The
//!   reference is itself checked against joint-Gaussian conditioning of the stacked
//!   problem in `tests/batch.rs`;
//! - `smooth_batch` leaves the runner untouched and refuses what the smoother cannot
//!   smooth with a typed error.

use estim_core::nalgebra::{SMatrix, SVector};
use estim_core::sigma_point::{SigmaPointUpdate, UnscentedTransform};
use estim_core::smoother::SmoothedBatch;
use estim_core::{
    CrossCovariance, Error, ErrorStateKalmanFilter, ErrorStateModel, ExtendedKalmanFilter,
    FilterConfig, FilteredBatch, Fixed, Gate, KalmanFilter, MeasurementModel, NisRecorder,
    ProcessModel, Result, SquareRootKalmanFilter, StateAndCovariance, UnscentedKalmanFilter,
    UpdateReport, UpdateStatus, Zero,
};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

const N: usize = 3;
const M: usize = 2;

type Step = (SVector<f64, N>, f64, Option<SVector<f64, M>>);

/// x_k = F x_{k-1} + c sin(x_{k-1}) (entrywise) + u, Q_d = Q dt; additive error
/// injection (true = nominal + error). Linear for c = 0.
#[derive(Debug, Clone)]
struct Wobble {
    f: SMatrix<f64, N, N>,
    q: SMatrix<f64, N, N>,
    c: f64,
}

impl ProcessModel<f64, N> for Wobble {
    type State = SVector<f64, N>;
    type Input = SVector<f64, N>;
    fn propagate(&self, x: &Self::State, u: &Self::Input, _: f64) -> Result<Self::State> {
        Ok(self.f * x + x.map(f64::sin) * self.c + u)
    }
    fn transition(&self, x: &Self::State, _: &Self::Input, _: f64) -> Result<SMatrix<f64, N, N>> {
        Ok(self.f + SMatrix::from_diagonal(&x.map(f64::cos)) * self.c)
    }
    fn process_noise(
        &self,
        _: &Self::State,
        _: &Self::Input,
        dt: f64,
    ) -> Result<SMatrix<f64, N, N>> {
        Ok(self.q * dt)
    }
}

impl ErrorStateModel<f64, N> for Wobble {
    fn inject(&self, nominal: &Self::State, error: &SVector<f64, N>) -> Result<Self::State> {
        Ok(nominal + error)
    }
}

/// y = H x + c sin(H x) (entrywise) + v. Linear for c = 0.
#[derive(Debug, Clone)]
struct Sensor {
    h: SMatrix<f64, M, N>,
    r: SMatrix<f64, M, M>,
    c: f64,
}

impl MeasurementModel<f64, N, M> for Sensor {
    type State = SVector<f64, N>;
    fn predict(&self, x: &Self::State) -> Result<SVector<f64, M>> {
        let hx = self.h * x;
        Ok(hx + hx.map(f64::sin) * self.c)
    }
    fn jacobian(&self, x: &Self::State) -> Result<SMatrix<f64, M, N>> {
        let hx = self.h * x;
        Ok((SMatrix::identity() + SMatrix::from_diagonal(&hx.map(f64::cos)) * self.c) * self.h)
    }
    fn noise_covariance(&self, _: &Self::State) -> Result<SMatrix<f64, M, M>> {
        Ok(self.r)
    }
}

/// A seeded problem: models, initial estimate, a valid joint [[Q, M], [M', R]] (the
/// blocks of A A' + I/10 for a random A, so [[Q_acc, M], [M', R]] and
/// [[P-, M], [M', R]] are valid too, Q_acc >= Q and P- >= Q), and the steps.
struct Problem {
    process: Wobble,
    sensor: Sensor,
    initial: StateAndCovariance<f64, N>,
    cross: SMatrix<f64, N, M>,
    steps: Vec<Step>,
}

fn normal(rng: &mut ChaCha8Rng) -> f64 {
    rng.sample(StandardNormal)
}

/// `nonlinear`: c of the models (0 for a linear problem, then inputs 0 and dt 1, the
/// `KalmanFilter`'s model); `measured`: the probability of a measurement at a step;
/// `outliers`: the probability that a measurement is displaced by 20 sigma.
fn problem(seed: u64, nonlinear: bool, measured: f64, outliers: f64, steps: usize) -> Problem {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let a = SMatrix::<f64, { N + M }, { N + M }>::from_fn(|_, _| normal(&mut rng));
    let joint = a * a.transpose() * 0.1 + SMatrix::identity() * 0.1;
    let q = joint.fixed_view::<N, N>(0, 0).into_owned();
    let cross = joint.fixed_view::<N, M>(0, N).into_owned();
    let r = joint.fixed_view::<M, M>(N, N).into_owned();
    // F = (an orthogonal matrix) diag(0.95, 0.9, 0.8): spectral norm 0.95, a stable
    // model whose states stay of the noise's size.
    let random = SMatrix::<f64, N, N>::from_fn(|_, _| normal(&mut rng));
    let f = random.qr().q() * SMatrix::from_diagonal(&SVector::from([0.95, 0.9, 0.8]));
    let h = SMatrix::<f64, M, N>::from_fn(|_, _| normal(&mut rng));
    let c = if nonlinear { 0.2 } else { 0.0 };
    let (process, sensor) = (Wobble { f, q, c }, Sensor { h, r, c });
    let p0 = SMatrix::<f64, N, N>::from_fn(|_, _| 0.5 * normal(&mut rng));
    let p0 = p0 * p0.transpose() + SMatrix::identity();
    let x0 = SVector::<f64, N>::from_fn(|_, _| normal(&mut rng));
    let initial = StateAndCovariance::new(x0, p0).expect("initial");
    // The measurements: the model's prediction plus noise of R's size (their exact law
    // does not matter here; the smoothing reference is the KalmanFilter's).
    let r_factor = r.cholesky().expect("R").l();
    let mut x = x0;
    let mut out = Vec::with_capacity(steps);
    for _ in 0..steps {
        let (u, dt) = if nonlinear {
            (
                SVector::<f64, N>::from_fn(|_, _| 0.1 * normal(&mut rng)),
                1.0 + rng.random::<f64>(),
            )
        } else {
            (SVector::zeros(), 1.0)
        };
        let w = (q * dt).cholesky().expect("Q").l()
            * SVector::<f64, N>::from_fn(|_, _| normal(&mut rng));
        x = process.propagate(&x, &u, dt).expect("propagate") + w;
        let y = (rng.random::<f64>() < measured).then(|| {
            let v = r_factor * SVector::<f64, M>::from_fn(|_, _| normal(&mut rng));
            let outlier = if rng.random::<f64>() < outliers {
                20.0
            } else {
                0.0
            };
            sensor.predict(&x).expect("predict") + v * (1.0 + outlier)
        });
        out.push((u, dt, y));
    }
    Problem {
        process,
        sensor,
        initial,
        cross,
        steps: out,
    }
}

/// The three filtering cases: (name, M, configuration, outlier probability).
fn cases() -> Vec<(&'static str, bool, FilterConfig, f64)> {
    let gate = FilterConfig::builder()
        .gate(Gate::Nis { probability: 0.99 })
        .build()
        .expect("config");
    vec![
        ("M = 0", false, FilterConfig::default(), 0.0),
        ("Fixed M", true, FilterConfig::default(), 0.0),
        ("Fixed M, gate", true, gate, 0.15),
    ]
}

/// Assert that `batch` equals a step loop bit for bit: `step(k)` runs step k of the
/// loop and returns its report and the estimate after it. Returns the number of
/// updates rejected by the gate and of unmeasured steps.
fn assert_equals_loop<E: PartialEq + std::fmt::Debug>(
    batch: &FilteredBatch<f64, N, M, E>,
    steps: usize,
    mut step: impl FnMut(usize) -> (Option<UpdateReport<f64, N, M>>, E),
) -> (usize, usize) {
    assert_eq!(batch.estimates.len(), steps);
    assert_eq!(batch.reports.len(), steps);
    let (mut log_likelihood, mut rejected, mut unmeasured) = (0.0, 0, 0);
    for k in 0..steps {
        let (report, estimate) = step(k);
        match report.as_ref() {
            Some(r) if r.status == UpdateStatus::Accepted => log_likelihood += r.log_likelihood,
            Some(_) => rejected += 1,
            None => unmeasured += 1,
        }
        assert_eq!(
            batch.estimates[k],
            estimate,
            "estimate after step {}",
            k + 1
        );
        assert_eq!(batch.reports[k], report, "report of step {}", k + 1);
    }
    assert_eq!(batch.log_likelihood.to_bits(), log_likelihood.to_bits());
    (rejected, unmeasured)
}

/// What every case must contain: unmeasured steps, and rejections in the gate case.
fn assert_case(name: &str, runner: &str, (rejected, unmeasured): (usize, usize)) {
    eprintln!("{runner}, {name}: {rejected} rejected, {unmeasured} unmeasured");
    assert!(unmeasured > 0);
    if name.contains("gate") {
        assert!(
            rejected > 0,
            "{runner}: the gate case must reject some updates"
        );
    } else {
        assert_eq!(rejected, 0);
    }
}

/// The case's cross-covariance model: `Fixed` with the problem's M, or `Zero`.
fn cross_model(
    correlated: bool,
    problem: &Problem,
) -> Box<dyn CrossCovariance<f64, SVector<f64, N>, N, M>> {
    if correlated {
        Box::new(Fixed(problem.cross))
    } else {
        Box::new(Zero)
    }
}

#[test]
fn extended_filter_batch_equals_step_in_a_loop_bit_for_bit() {
    for (seed, (name, correlated, config, outliers)) in cases().into_iter().enumerate() {
        let p = problem(10 + seed as u64, true, 0.7, outliers, 60);
        let cross = cross_model(correlated, &p);
        let ekf = ExtendedKalmanFilter::new(p.process.clone(), p.initial.clone())
            .with_config(config)
            .with_observer(NisRecorder::default());
        let (mut batch, mut looped) = (ekf.clone(), ekf);
        let out = batch
            .filter_batch(&p.steps, &p.sensor, &*cross)
            .expect("batch");
        let counts = assert_equals_loop(&out, p.steps.len(), |k| {
            let (u, dt, y) = &p.steps[k];
            let report = looped
                .step(u, *dt, &p.sensor, y.as_ref(), &*cross)
                .expect("step");
            (report, looped.estimate().clone())
        });
        assert_case(name, "EKF", counts);
        assert_eq!(batch.estimate(), looped.estimate());
        assert_eq!(
            batch.log_likelihood().to_bits(),
            looped.log_likelihood().to_bits()
        );
        assert_eq!(batch.observer(), looped.observer());
        assert_eq!(
            batch.accumulated_process_noise(),
            looped.accumulated_process_noise()
        );
    }
}

#[test]
fn error_state_filter_batch_equals_step_in_a_loop_bit_for_bit() {
    for (seed, (name, correlated, config, outliers)) in cases().into_iter().enumerate() {
        let p = problem(20 + seed as u64, true, 0.7, outliers, 60);
        let cross = cross_model(correlated, &p);
        let eskf = ErrorStateKalmanFilter::new(
            p.process.clone(),
            *p.initial.state(),
            *p.initial.covariance(),
        )
        .expect("eskf")
        .with_config(config)
        .with_observer(NisRecorder::default());
        let (mut batch, mut looped) = (eskf.clone(), eskf);
        let out = batch
            .filter_batch(&p.steps, &p.sensor, &*cross)
            .expect("batch");
        let counts = assert_equals_loop(&out, p.steps.len(), |k| {
            let (u, dt, y) = &p.steps[k];
            let report = looped
                .step(u, *dt, &p.sensor, y.as_ref(), &*cross)
                .expect("step");
            (report, (*looped.nominal(), *looped.covariance()))
        });
        assert_case(name, "ESKF", counts);
        assert_eq!(batch.nominal(), looped.nominal());
        assert_eq!(batch.covariance(), looped.covariance());
        assert_eq!(
            batch.log_likelihood().to_bits(),
            looped.log_likelihood().to_bits()
        );
        assert_eq!(batch.observer(), looped.observer());
    }
}

#[test]
fn unscented_filter_batch_equals_step_in_a_loop_bit_for_bit() {
    for (seed, (name, correlated, config, outliers)) in cases().into_iter().enumerate() {
        let p = problem(30 + seed as u64, true, 0.7, outliers, 60);
        let cross = cross_model(correlated, &p);
        let ukf = UnscentedKalmanFilter::new(
            p.process.clone(),
            UnscentedTransform::default(),
            p.initial.clone(),
        )
        .with_config(config)
        .with_observer(NisRecorder::default());
        let (mut batch, mut looped) = (ukf.clone(), ukf);
        let out = batch
            .filter_batch(&p.steps, &p.sensor, &*cross)
            .expect("batch");
        let counts = assert_equals_loop(&out, p.steps.len(), |k| {
            let (u, dt, y) = &p.steps[k];
            let report = looped
                .step(u, *dt, &p.sensor, y.as_ref(), &*cross)
                .expect("step");
            (report, looped.estimate().clone())
        });
        assert_case(name, "UKF", counts);
        assert_eq!(batch.estimate(), looped.estimate());
        assert_eq!(
            batch.log_likelihood().to_bits(),
            looped.log_likelihood().to_bits()
        );
        assert_eq!(batch.observer(), looped.observer());
    }
}

/// The square-root filter of the problem's linear model (F, Q, H, R).
fn square_root(p: &Problem) -> SquareRootKalmanFilter<f64, N, M> {
    SquareRootKalmanFilter::new(
        p.process.f,
        p.process.q,
        p.sensor.h,
        p.sensor.r,
        p.initial.clone(),
    )
    .expect("square-root filter")
}

fn measurements(p: &Problem) -> Vec<Option<SVector<f64, M>>> {
    p.steps.iter().map(|(_, _, y)| *y).collect()
}

#[test]
fn square_root_filter_batch_equals_step_in_a_loop_bit_for_bit() {
    for (seed, (name, correlated, config, outliers)) in cases().into_iter().enumerate() {
        let p = problem(40 + seed as u64, false, 0.7, outliers, 60);
        let cross = cross_model(correlated, &p);
        let ys = measurements(&p);
        let srkf = square_root(&p)
            .with_config(config)
            .with_observer(NisRecorder::default());
        let (mut batch, mut looped) = (srkf.clone(), srkf);
        let out = batch.filter_batch(&ys, &*cross).expect("batch");
        let counts = assert_equals_loop(&out, ys.len(), |k| {
            let report = looped.step(ys[k].as_ref(), &*cross).expect("step");
            (report, looped.estimate().clone())
        });
        assert_case(name, "SRKF", counts);
        assert_eq!(batch.estimate(), looped.estimate());
        assert_eq!(batch.factor(), looped.factor());
        assert_eq!(
            batch.log_likelihood().to_bits(),
            looped.log_likelihood().to_bits()
        );
        assert_eq!(batch.observer(), looped.observer());
    }
}

/// An estimate as (state, covariance).
type Pair = (SVector<f64, N>, SMatrix<f64, N, N>);

/// x_0 and the estimates of a smoothed batch of a runner whose estimate is a
/// `StateAndCovariance`, as pairs.
fn pairs(batch: &SmoothedBatch<f64, N>) -> Vec<Pair> {
    std::iter::once(&batch.initial)
        .chain(&batch.estimates)
        .map(|e| (*e.state(), *e.covariance()))
        .collect()
}

/// Largest |a - b| over states and covariances of two estimate sequences, relative
/// to the largest entry of `b` (the reference).
fn relative_difference(a: &[Pair], b: &[Pair]) -> f64 {
    assert_eq!(a.len(), b.len());
    let (mut diff, mut scale) = (0.0_f64, 0.0_f64);
    for (a, b) in a.iter().zip(b) {
        diff = diff.max((a.0 - b.0).amax()).max((a.1 - b.1).amax());
        scale = scale.max(b.0.amax()).max(b.1.amax());
    }
    diff / scale
}

/// The smoothing cases on the linear problem: (name, cross-covariance, problem). With
/// M != 0 every step is measured (a correlated update after an unmeasured step is not
/// smoothable at every step, see `smoother`).
fn smoothing_cases() -> Vec<(&'static str, Fixed<f64, N, M>, Problem)> {
    let mut out = Vec::new();
    for seed in [50, 51] {
        let p = problem(seed, false, 0.6, 0.0, 40);
        assert!(p.steps.iter().any(|s| s.2.is_none()));
        out.push(("M = 0", Fixed(SMatrix::zeros()), p));
        let p = problem(seed + 10, false, 1.0, 0.0, 40);
        out.push(("Fixed M", Fixed(p.cross), p));
    }
    out
}

/// Every runner's smoothed batch equals the KalmanFilter's on the linear problem.
#[test]
fn smooth_batch_of_every_runner_equals_the_kalman_filters_on_a_linear_model() {
    for (name, cross, p) in smoothing_cases() {
        let ys = measurements(&p);
        let kf = KalmanFilter::new(
            p.process.f,
            p.process.q,
            p.sensor.h,
            p.sensor.r,
            p.initial.clone(),
        )
        .expect("kf");
        let reference = kf.smooth_batch(&ys, &cross).expect("kf smooth");
        let expected = pairs(&reference);
        let ll_scale = reference.log_likelihood.abs();

        let ekf = ExtendedKalmanFilter::new(p.process.clone(), p.initial.clone());
        let out = ekf.smooth_batch(&p.steps, &p.sensor, &cross).expect("ekf");
        let ekf_err = relative_difference(&pairs(&out), &expected);
        let ekf_ll = (out.log_likelihood - reference.log_likelihood).abs() / ll_scale;

        let eskf = ErrorStateKalmanFilter::new(
            p.process.clone(),
            *p.initial.state(),
            *p.initial.covariance(),
        )
        .expect("eskf");
        let out = eskf
            .smooth_batch(&p.steps, &p.sensor, &cross)
            .expect("eskf");
        let eskf_pairs: Vec<Pair> = std::iter::once(out.initial).chain(out.estimates).collect();
        let eskf_err = relative_difference(&eskf_pairs, &expected);
        let eskf_ll = (out.log_likelihood - reference.log_likelihood).abs() / ll_scale;

        let ukf = UnscentedKalmanFilter::new(
            p.process.clone(),
            UnscentedTransform::default(),
            p.initial.clone(),
        );
        let out = ukf.smooth_batch(&p.steps, &p.sensor, &cross).expect("ukf");
        let ukf_err = relative_difference(&pairs(&out), &expected);
        let ukf_ll = (out.log_likelihood - reference.log_likelihood).abs() / ll_scale;

        // The sigma points over the joint [x; v] (the other update form).
        let augmented = UnscentedTransform::default().with_update(SigmaPointUpdate::Augmented);
        let ukf = UnscentedKalmanFilter::new(p.process.clone(), augmented, p.initial.clone());
        let out = ukf.smooth_batch(&p.steps, &p.sensor, &cross).expect("ukf");
        let joint_err = relative_difference(&pairs(&out), &expected);
        let joint_ll = (out.log_likelihood - reference.log_likelihood).abs() / ll_scale;

        let srkf = square_root(&p);
        let out = srkf.smooth_batch(&ys, &cross).expect("srkf");
        let srkf_err = relative_difference(&pairs(&out), &expected);
        let srkf_ll = (out.log_likelihood - reference.log_likelihood).abs() / ll_scale;

        eprintln!(
            "{name}: estimates EKF {ekf_err:.1e} ESKF {eskf_err:.1e} UKF {ukf_err:.1e} \
             UKF [x; v] {joint_err:.1e} SRKF {srkf_err:.1e}; log-likelihood EKF {ekf_ll:.1e} \
             ESKF {eskf_ll:.1e} UKF {ukf_ll:.1e} UKF [x; v] {joint_ll:.1e} SRKF {srkf_ll:.1e}"
        );
        for err in [ekf_err, eskf_err, ukf_err, joint_err, srkf_err] {
            assert!(err < 1e-12, "{name}: {err:e}");
        }
        for err in [ekf_ll, eskf_ll, ukf_ll, joint_ll, srkf_ll] {
            assert!(err < 1e-12, "{name}: log-likelihood {err:e}");
        }
    }
}

/// The smoother runs on a copy: the runner (estimate, accumulators, log-likelihood,
/// observer) is untouched; what it cannot smooth is a typed refusal.
#[test]
fn smooth_batch_leaves_the_runner_untouched_and_refuses_with_a_typed_error() {
    let p = problem(70, true, 1.0, 0.0, 12);
    let cross = Fixed(p.cross);
    let ekf = ExtendedKalmanFilter::new(p.process.clone(), p.initial.clone())
        .with_observer(NisRecorder::default());
    let before = ekf.clone();
    ekf.smooth_batch(&p.steps, &p.sensor, &cross)
        .expect("smooth");
    assert_eq!(ekf.estimate(), before.estimate());
    assert_eq!(ekf.log_likelihood(), 0.0);
    assert_eq!(ekf.propagations_since_update(), 0);
    assert!(ekf.observer().records.is_empty());

    // A correlated update after an unmeasured step (two predicts, one epoch each).
    let mut steps = p.steps.clone();
    steps[3].2 = None;
    let refused = |r: Result<_>| matches!(r, Err(Error::SmootherUnsupported { .. }));
    assert!(refused(
        ekf.smooth_batch(&steps, &p.sensor, &cross).map(|_| ())
    ));
    let eskf = ErrorStateKalmanFilter::new(
        p.process.clone(),
        *p.initial.state(),
        *p.initial.covariance(),
    )
    .expect("eskf");
    assert!(refused(
        eskf.smooth_batch(&steps, &p.sensor, &cross).map(|_| ())
    ));
    let ukf = UnscentedKalmanFilter::new(
        p.process.clone(),
        UnscentedTransform::default(),
        p.initial.clone(),
    );
    assert!(refused(
        ukf.smooth_batch(&steps, &p.sensor, &cross).map(|_| ())
    ));
    let ys: Vec<_> = steps.iter().map(|s| s.2).collect();
    assert!(refused(
        square_root(&p).smooth_batch(&ys, &cross).map(|_| ())
    ));

    // A correlated first update when the runner had already predicted.
    let mut ekf = ekf;
    ekf.predict(&SVector::zeros(), 1.0).expect("predict");
    assert!(matches!(
        ekf.smooth_batch(&p.steps, &p.sensor, &cross),
        Err(Error::SmootherUnsupported { epoch: 1, .. })
    ));
    // ... which is fine without correlation.
    assert!(ekf.smooth_batch(&p.steps, &p.sensor, &Zero).is_ok());

    // A bad dt is the runner's typed error, from batch and smoother alike; the steps
    // before the failing one stay committed.
    let mut steps = p.steps.clone();
    steps[2].1 = -1.0;
    assert!(matches!(
        ekf.smooth_batch(&steps, &p.sensor, &Zero),
        Err(Error::InvalidParameter { .. })
    ));
    let mut batch = ukf.clone();
    assert!(matches!(
        batch.filter_batch(&steps, &p.sensor, &Zero),
        Err(Error::InvalidParameter { .. })
    ));
    let mut looped = ukf;
    for (u, dt, y) in &steps[..2] {
        looped
            .step(u, *dt, &p.sensor, y.as_ref(), &Zero)
            .expect("step");
    }
    assert_eq!(batch.estimate(), looped.estimate());
    assert_eq!(batch.log_likelihood(), looped.log_likelihood());
}
