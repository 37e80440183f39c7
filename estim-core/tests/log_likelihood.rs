//! The measurements' log-likelihood (`UpdateReport::log_likelihood` and the runners'
//! cumulative `log_likelihood()`) against independent references:
//!
//! - the log density of the stacked measurement vector [y_1; ...; y_K] from its joint
//!   Gaussian, built here with dynamic matrices from x_0 ~ N(m0, P0), the process
//!   noises w_j and the measurement noises v_k with their cross-covariances, and
//!   evaluated through nalgebra's Cholesky (never the runners' code): one-step
//!   correlation Cov(w_k, v_k) with unmeasured steps, and exact windowed correlation
//!   with another sensor updated inside the window (Var(v | ...), E[v | ...]);
//! - every runner's per-update value against the KalmanFilter's on one linear model;
//! - the closed form of a scalar M = 0 update.
//!
//! Indexing: x_j = F x_{j-1} + G w_j (step j = 1..K), y_k = H x_k + v_k; the one-step
//! correlation Cov(w_k, v_k) is the brief's Cov(w_{k-1}, v_k) of the noise driving the
//! last step into the measured epoch. Seeded (ChaCha8), deterministic.

mod common;

use common::dm;
use estim_core::nalgebra::{DMatrix, DVector, Matrix1, SMatrix, SVector, Vector1};
use estim_core::sigma_point::{SigmaPointUpdate, UnscentedTransform};
use estim_core::window::StepWindow;
use estim_core::{
    ErrorStateKalmanFilter, ErrorStateModel, ExtendedKalmanFilter, FilterConfig, Fixed, Gate,
    KalmanFilter, MeasurementModel, ProcessModel, Result, SquareRootKalmanFilter,
    StateAndCovariance, UnscentedKalmanFilter, UpdateStatus, WindowedCrossCovariance, Zero,
};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

const N: usize = 4;
const P: usize = 3;
const M: usize = 2;

fn random(rng: &mut ChaCha8Rng, r: usize, c: usize) -> DMatrix<f64> {
    DMatrix::from_fn(r, c, |_, _| rng.random_range(-1.0..1.0))
}

fn spd(rng: &mut ChaCha8Rng, n: usize, floor: f64) -> DMatrix<f64> {
    let b = random(rng, n, n);
    &b * b.transpose() / n as f64 + DMatrix::identity(n, n) * floor
}

fn s<const R: usize, const C: usize>(m: &DMatrix<f64>) -> SMatrix<f64, R, C> {
    SMatrix::from_fn(|r, c| m[(r, c)])
}

fn sv<const R: usize>(v: &DVector<f64>) -> SVector<f64, R> {
    SVector::from_fn(|r, _| v[r])
}

/// ln N(y; mu, Sigma) through nalgebra's Cholesky: -(d ln 2 pi + ln det Sigma + r' Sigma^-1 r) / 2.
fn gaussian_log_density(y: &DVector<f64>, mu: &DVector<f64>, sigma: &DMatrix<f64>) -> f64 {
    let chol = sigma.clone().cholesky().expect("stacked covariance is SPD");
    let log_det = 2.0 * chol.l().diagonal().iter().map(|v| v.ln()).sum::<f64>();
    let r = y - mu;
    let quad = r.dot(&chol.solve(&r));
    -0.5 * (y.len() as f64 * (2.0 * std::f64::consts::PI).ln() + log_det + quad)
}

/// One measured epoch of the stacked problem: y = H x_epoch + v, Var(v) = R.
struct Measurement {
    epoch: usize,
    h: DMatrix<f64>,
    r: DMatrix<f64>,
    y: DVector<f64>,
}

/// A time-invariant linear model with noise input G (n x p) and the cross-covariances
/// Cov(w_j, v_k) listed explicitly (p x m each), over K steps.
struct Stacked {
    m0: DVector<f64>,
    p0: DMatrix<f64>,
    f: DMatrix<f64>,
    g: DMatrix<f64>,
    qw: DMatrix<f64>,
    /// The measured epochs, in the order of the updates.
    measured: Vec<Measurement>,
    /// (j, index into `measured`, Cov(w_j, v)).
    cross: Vec<(usize, usize, DMatrix<f64>)>,
    steps: usize,
}

impl Stacked {
    /// ln p(y_1, ..., y_K): z = [x_0; w_1..w_K; v_1..v_L] ~ N(mean, cov), y = T z.
    fn log_density(&self) -> f64 {
        let (n, p, k) = (self.f.nrows(), self.g.ncols(), self.steps);
        let offsets: Vec<usize> = self
            .measured
            .iter()
            .scan(n + p * k, |at, measurement| {
                let here = *at;
                *at += measurement.h.nrows();
                Some(here)
            })
            .collect();
        let dim = n + p * k + self.measured.iter().map(|m| m.h.nrows()).sum::<usize>();
        let mut cov = DMatrix::zeros(dim, dim);
        cov.view_mut((0, 0), (n, n)).copy_from(&self.p0);
        for j in 1..=k {
            let w = n + p * (j - 1);
            cov.view_mut((w, w), (p, p)).copy_from(&self.qw);
        }
        for (measurement, &at) in self.measured.iter().zip(&offsets) {
            let r = &measurement.r;
            cov.view_mut((at, at), r.shape()).copy_from(r);
        }
        for (j, i, c) in &self.cross {
            let (w, v) = (n + p * (j - 1), offsets[*i]);
            cov.view_mut((w, v), c.shape()).copy_from(c);
            cov.view_mut((v, w), (c.ncols(), c.nrows()))
                .copy_from(&c.transpose());
        }
        let mut mean = DVector::zeros(dim);
        mean.rows_mut(0, n).copy_from(&self.m0);
        // x_j = L_j z.
        let mut l = DMatrix::zeros(n, dim);
        l.view_mut((0, 0), (n, n)).fill_with_identity();
        let rows: usize = self.measured.iter().map(|m| m.h.nrows()).sum();
        let mut t = DMatrix::zeros(rows, dim);
        let mut y = DVector::zeros(rows);
        let mut row = 0;
        for j in 1..=k {
            l = &self.f * &l;
            l.view_mut((0, n + p * (j - 1)), (n, p)).copy_from(&self.g);
            for (measurement, &at) in self.measured.iter().zip(&offsets) {
                if measurement.epoch == j {
                    let m = measurement.h.nrows();
                    let mut block = &measurement.h * &l;
                    block.view_mut((0, at), (m, m)).fill_with_identity();
                    t.view_mut((row, 0), (m, dim)).copy_from(&block);
                    y.rows_mut(row, m).copy_from(&measurement.y);
                    row += m;
                }
            }
        }
        assert_eq!(row, rows);
        let mu = &t * &mean;
        let sigma = &t * &cov * t.transpose();
        gaussian_log_density(&y, &mu, &sigma)
    }
}

/// |a - b| / max(|b|, 1): relative for log-likelihoods of order one or more, absolute
/// near zero (where a relative error is meaningless).
fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs().max(1.0)
}

// ------------------------------------------------------------ the one-step problem

/// A 4-state, 2-measurement problem with Cov(w_k, v_k) = C != 0 at every measured
/// epoch; `measured[k - 1]` says whether epoch k has a measurement.
struct OneStep {
    m0: DVector<f64>,
    p0: DMatrix<f64>,
    f: DMatrix<f64>,
    g: DMatrix<f64>,
    qw: DMatrix<f64>,
    c: DMatrix<f64>,
    h: DMatrix<f64>,
    r: DMatrix<f64>,
    ys: Vec<Option<DVector<f64>>>,
}

impl OneStep {
    fn new(seed: u64, measured: &[bool]) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let m0 = DVector::from_fn(N, |_, _| rng.random_range(-1.0..1.0));
        let p0 = spd(&mut rng, N, 0.5);
        let a = random(&mut rng, N, N);
        let f =
            DMatrix::identity(N, N) + (&a - a.transpose()) * 0.1 + random(&mut rng, N, N) * 0.05;
        let g = random(&mut rng, N, P);
        let qw = spd(&mut rng, P, 0.2) * 0.3;
        let h = random(&mut rng, M, N);
        // C = Qw B' with R = B Qw B' + R_e: [[Qw, C], [C', R]] is a valid joint
        // covariance (v = B w + e).
        let b = random(&mut rng, M, P) * 0.6;
        let c = &qw * b.transpose();
        let r = &b * &qw * b.transpose() + spd(&mut rng, M, 0.05) * 0.2;
        let ys = measured
            .iter()
            .map(|&on| {
                let y = DVector::from_fn(M, |_, _| rng.random_range(-2.0..2.0));
                on.then_some(y)
            })
            .collect();
        Self {
            m0,
            p0,
            f,
            g,
            qw,
            c,
            h,
            r,
            ys,
        }
    }

    fn stacked(&self) -> Stacked {
        let mut measured = Vec::new();
        let mut cross = Vec::new();
        for (k, y) in self.ys.iter().enumerate() {
            if let Some(y) = y {
                cross.push((k + 1, measured.len(), self.c.clone()));
                measured.push(Measurement {
                    epoch: k + 1,
                    h: self.h.clone(),
                    r: self.r.clone(),
                    y: y.clone(),
                });
            }
        }
        Stacked {
            m0: self.m0.clone(),
            p0: self.p0.clone(),
            f: self.f.clone(),
            g: self.g.clone(),
            qw: self.qw.clone(),
            measured,
            cross,
            steps: self.ys.len(),
        }
    }

    /// The runners' M = Cov(G w_k, v_k) = G C, and Q = G Qw G'.
    fn state_cross(&self) -> SMatrix<f64, N, M> {
        s(&(&self.g * &self.c))
    }

    fn process_noise(&self) -> SMatrix<f64, N, N> {
        s(&(&self.g * &self.qw * self.g.transpose()))
    }

    fn initial(&self) -> StateAndCovariance<f64, N> {
        StateAndCovariance::new(sv(&self.m0), s(&self.p0)).expect("initial")
    }

    fn config() -> FilterConfig {
        FilterConfig::builder()
            .track_accumulated_noise(true)
            .build()
            .expect("config")
    }
}

/// F, Q as a ProcessModel (input ignored), with the additive error injection.
struct Lti {
    f: SMatrix<f64, N, N>,
    q: SMatrix<f64, N, N>,
}

impl ProcessModel<f64, N> for Lti {
    type State = SVector<f64, N>;
    type Input = ();
    fn propagate(&self, x: &Self::State, _: &(), _: f64) -> Result<Self::State> {
        Ok(self.f * x)
    }
    fn transition(&self, _: &Self::State, _: &(), _: f64) -> Result<SMatrix<f64, N, N>> {
        Ok(self.f)
    }
    fn process_noise(&self, _: &Self::State, _: &(), _: f64) -> Result<SMatrix<f64, N, N>> {
        Ok(self.q)
    }
}

impl ErrorStateModel<f64, N> for Lti {
    fn inject(&self, nominal: &Self::State, error: &SVector<f64, N>) -> Result<Self::State> {
        Ok(nominal + error)
    }
}

/// H, R as a MeasurementModel.
struct Linear {
    h: SMatrix<f64, M, N>,
    r: SMatrix<f64, M, M>,
}

impl MeasurementModel<f64, N, M> for Linear {
    type State = SVector<f64, N>;
    fn predict(&self, x: &Self::State) -> Result<SVector<f64, M>> {
        Ok(self.h * x)
    }
    fn jacobian(&self, _: &Self::State) -> Result<SMatrix<f64, M, N>> {
        Ok(self.h)
    }
    fn noise_covariance(&self, _: &Self::State) -> Result<SMatrix<f64, M, M>> {
        Ok(self.r)
    }
}

/// The KalmanFilter over the problem: per-update log-likelihoods and the cumulative one.
fn kalman(problem: &OneStep) -> (Vec<f64>, f64) {
    let mut kf = KalmanFilter::<f64, N, M>::new(
        s(&problem.f),
        problem.process_noise(),
        s(&problem.h),
        s(&problem.r),
        problem.initial(),
    )
    .expect("kf")
    .with_config(OneStep::config());
    let cross = Fixed(problem.state_cross());
    let mut terms = Vec::new();
    for y in &problem.ys {
        let y = y.as_ref().map(sv::<M>);
        if let Some(report) = kf.step(y.as_ref(), &cross).expect("step") {
            assert!(report.is_accepted());
            terms.push(report.log_likelihood);
        }
    }
    (terms, kf.log_likelihood())
}

const SCHEDULE: [bool; 10] = [
    true, false, true, true, false, false, true, true, false, true,
];

/// The KalmanFilter's cumulative log-likelihood with M != 0 and unmeasured epochs
/// equals ln N([y_k]; mu, Sigma) of the stacked problem, for several seeds.
#[test]
fn cumulative_log_likelihood_equals_the_stacked_joint_gaussian() {
    let mut worst: f64 = 0.0;
    for seed in 0..8 {
        let problem = OneStep::new(seed, &SCHEDULE);
        let (terms, total) = kalman(&problem);
        let reference = problem.stacked().log_density();
        assert_eq!(terms.len(), SCHEDULE.iter().filter(|&&on| on).count());
        let sum: f64 = terms.iter().sum();
        assert!(rel(sum, total) < 1e-14, "seed {seed}: sum {sum} vs {total}");
        let err = rel(total, reference);
        assert!(err < 1e-10, "seed {seed}: {total} vs {reference} ({err:e})");
        // M matters: the M = 0 likelihood of the same data is a different number.
        let mut uncorrelated = problem.stacked();
        uncorrelated.cross.clear();
        assert!(rel(uncorrelated.log_density(), reference) > 1e-6);
        worst = worst.max(err);
    }
    println!("one-step stacked: worst relative error {worst:e}");
}

/// Every runner gives the KalmanFilter's per-update log-likelihood (and cumulative)
/// on the linear one-step problem: EKF, ESKF, square-root, UKF additive and augmented.
#[test]
fn every_runner_gives_the_kalman_filter_log_likelihood() {
    let mut worst: [f64; 5] = [0.0; 5];
    for seed in 0..4 {
        let problem = OneStep::new(100 + seed, &SCHEDULE);
        let (expected, expected_total) = kalman(&problem);
        let process = || Lti {
            f: s(&problem.f),
            q: problem.process_noise(),
        };
        let sensor = Linear {
            h: s(&problem.h),
            r: s(&problem.r),
        };
        let cross = Fixed(problem.state_cross());
        let config = OneStep::config();
        let ys: Vec<Option<SVector<f64, M>>> =
            problem.ys.iter().map(|y| y.as_ref().map(sv::<M>)).collect();
        let mut runs: Vec<(&str, Vec<f64>, f64)> = Vec::new();

        let mut ekf =
            ExtendedKalmanFilter::new(process(), problem.initial()).with_config(config.clone());
        let terms = ys
            .iter()
            .filter_map(|y| {
                ekf.step(&(), 1.0, &sensor, y.as_ref(), &cross)
                    .expect("ekf")
            })
            .map(|r| r.log_likelihood)
            .collect();
        runs.push(("EKF", terms, ekf.log_likelihood()));

        let mut eskf = ErrorStateKalmanFilter::new(process(), sv(&problem.m0), s(&problem.p0))
            .expect("eskf")
            .with_config(config.clone());
        let terms = ys
            .iter()
            .filter_map(|y| {
                eskf.step(&(), 1.0, &sensor, y.as_ref(), &cross)
                    .expect("eskf")
            })
            .map(|r| r.log_likelihood)
            .collect();
        runs.push(("ESKF", terms, eskf.log_likelihood()));

        let mut srkf = SquareRootKalmanFilter::<f64, N, M>::new(
            s(&problem.f),
            problem.process_noise(),
            s(&problem.h),
            s(&problem.r),
            problem.initial(),
        )
        .expect("srkf")
        .with_config(config.clone());
        let terms = ys
            .iter()
            .filter_map(|y| srkf.step(y.as_ref(), &cross).expect("srkf"))
            .map(|r| r.log_likelihood)
            .collect();
        runs.push(("square-root", terms, srkf.log_likelihood()));

        for (name, form) in [
            ("UKF additive", SigmaPointUpdate::Additive),
            ("UKF augmented", SigmaPointUpdate::Augmented),
        ] {
            let transform = UnscentedTransform::new(0.5, 2.0, 0.0)
                .expect("transform")
                .with_update(form);
            let mut ukf = UnscentedKalmanFilter::new(process(), transform, problem.initial())
                .with_config(config.clone());
            let terms = ys
                .iter()
                .filter_map(|y| {
                    ukf.step(&(), 1.0, &sensor, y.as_ref(), &cross)
                        .expect("ukf")
                })
                .map(|r| r.log_likelihood)
                .collect();
            runs.push((name, terms, ukf.log_likelihood()));
        }

        for (i, (name, terms, total)) in runs.iter().enumerate() {
            assert_eq!(terms.len(), expected.len(), "{name}");
            for (k, (a, b)) in terms.iter().zip(&expected).enumerate() {
                let err = rel(*a, *b);
                assert!(
                    err < 1e-10,
                    "{name} seed {seed} update {k}: {a} vs {b} ({err:e})"
                );
                worst[i] = worst[i].max(err);
            }
            let err = rel(*total, expected_total);
            assert!(
                err < 1e-10,
                "{name} seed {seed}: total {total} vs {expected_total}"
            );
            worst[i] = worst[i].max(err);
        }
    }
    println!(
        "against the KF: EKF, ESKF, square-root, UKF additive, augmented: {:?}",
        worst.map(|v| format!("{v:.1e}"))
    );
}

/// M = 0, one state and one measurement: ln N(y; H x-, H P- H' + R) in closed form,
/// -(ln(2 pi s) + nu^2 / s) / 2, per update and summed.
#[test]
fn scalar_uncorrelated_update_is_the_closed_form() {
    let (f, q, h, r) = (0.9, 0.3, 2.0, 0.5);
    let (mut x, mut p) = (0.4, 1.5);
    let initial = StateAndCovariance::new(Vector1::new(x), Matrix1::new(p)).expect("x0");
    let mut kf = KalmanFilter::<f64, 1, 1>::new(
        Matrix1::new(f),
        Matrix1::new(q),
        Matrix1::new(h),
        Matrix1::new(r),
        initial,
    )
    .expect("kf");
    let mut total = 0.0;
    let mut worst: f64 = 0.0;
    for y in [1.1, -0.3, 0.7, 2.5, 0.0] {
        x *= f;
        p = f * p * f + q;
        let (nu, s) = (y - h * x, h * p * h + r);
        let expected = -0.5 * ((2.0 * std::f64::consts::PI * s).ln() + nu * nu / s);
        let report = kf
            .step(Some(&Vector1::new(y)), &Zero)
            .expect("step")
            .expect("measured");
        let err = rel(report.log_likelihood, expected);
        assert!(err < 1e-14, "{} vs {expected}", report.log_likelihood);
        worst = worst.max(err);
        let k = p * h / s;
        x += k * nu;
        p *= 1.0 - k * h;
        total += expected;
    }
    let err = rel(kf.log_likelihood(), total);
    assert!(err < 1e-14, "{} vs {total}", kf.log_likelihood());
    println!(
        "scalar closed form: worst relative error {:e}",
        worst.max(err)
    );
}

/// A gate-rejected update reports its log-likelihood (the density of the rejected
/// innovation) but adds nothing to the cumulative one; `with_config` resets nothing.
#[test]
fn rejected_updates_report_but_do_not_accumulate() {
    let problem = OneStep::new(7, &[true, true, true]);
    let config = FilterConfig::builder()
        .track_accumulated_noise(true)
        .gate(Gate::NisThreshold(20.0))
        .build()
        .expect("config");
    let mut kf = KalmanFilter::<f64, N, M>::new(
        s(&problem.f),
        problem.process_noise(),
        s(&problem.h),
        s(&problem.r),
        problem.initial(),
    )
    .expect("kf")
    .with_config(config.clone());
    let cross = Fixed(problem.state_cross());
    let good = sv::<M>(problem.ys[0].as_ref().expect("y"));
    let first = kf.step(Some(&good), &cross).expect("step").expect("report");
    assert!(first.is_accepted());
    let outlier = good + SVector::<f64, M>::repeat(1e3);
    let before = kf.log_likelihood();
    let rejected = kf
        .step(Some(&outlier), &cross)
        .expect("step")
        .expect("report");
    assert_eq!(rejected.status, UpdateStatus::RejectedByGate);
    // The reported term is that of the innovation and S the gate saw.
    let innovation = DVector::from_column_slice(rejected.innovation.as_slice());
    let reference = gaussian_log_density(
        &innovation,
        &DVector::zeros(M),
        &dm(&rejected.innovation_covariance),
    );
    assert!(rel(rejected.log_likelihood, reference) < 1e-12);
    assert!(rejected.log_likelihood < -1e4);
    assert_eq!(kf.log_likelihood(), before);
    let kf = kf.with_config(config);
    assert_eq!(kf.log_likelihood(), before);
    assert_eq!(kf.log_likelihood(), first.log_likelihood);
}

// ------------------------------------------------------------ the windowed problem

/// Cov(G w_j, v_B) by position in the window (oldest first), for the linear KF.
struct KnownD {
    d: Vec<SMatrix<f64, N, M>>,
}

impl WindowedCrossCovariance<f64, SVector<f64, N>, (), N, M> for KnownD {
    fn window_steps(&self) -> usize {
        self.d.len()
    }
    fn step_cross_covariances(
        &self,
        window: &StepWindow<'_, f64, SVector<f64, N>, (), N>,
        sink: &mut dyn FnMut(&SMatrix<f64, N, M>) -> Result<()>,
    ) -> Result<()> {
        for step in window.iter() {
            sink(&self.d[step.position])?;
        }
        Ok(())
    }
}

/// Windowed exact M: sensor B at epochs 4, 8, 12, its noise v_B = sum_j A_j w_j + e
/// over the 4 steps since its last measurement; an independent sensor A (same H and
/// R, the linear KF has one of each) at epochs 2, 6, 7 and 11, inside B's windows, so
/// the windowed updates use Var(v | y_A) and E[v | y_A]. The KF's cumulative
/// log-likelihood equals ln p(all y) of the stacked problem.
#[test]
fn windowed_log_likelihood_equals_the_stacked_joint_gaussian() {
    const WINDOW: usize = 4;
    const STEPS: usize = 12;
    let mut worst: f64 = 0.0;
    for seed in 0..6 {
        let mut rng = ChaCha8Rng::seed_from_u64(200 + seed);
        let m0 = DVector::from_fn(N, |_, _| rng.random_range(-1.0..1.0));
        let p0 = spd(&mut rng, N, 0.5);
        let a = random(&mut rng, N, N);
        let f =
            DMatrix::identity(N, N) + (&a - a.transpose()) * 0.1 + random(&mut rng, N, N) * 0.05;
        let g = random(&mut rng, N, P);
        let qw = spd(&mut rng, P, 0.2) * 0.3;
        let h = random(&mut rng, M, N);
        // The same A_j (by position in the window) for every B measurement, so that
        // one R = sum A_j Qw A_j' + R_e serves every epoch; sensor A shares R.
        let kernels: Vec<DMatrix<f64>> =
            (0..WINDOW).map(|_| random(&mut rng, M, P) * 0.4).collect();
        let mut r = spd(&mut rng, M, 0.05) * 0.2;
        for aj in &kernels {
            r += aj * &qw * aj.transpose();
        }
        let (b_at, a_at) = ([4, 8, 12], [2, 6, 7, 11]);
        let mut measured = Vec::new();
        let mut cross = Vec::new();
        let mut events: Vec<(usize, bool, DVector<f64>)> = Vec::new();
        for k in 1..=STEPS {
            // A first at a shared epoch (none here), then B.
            for (is_b, on) in [(false, a_at.contains(&k)), (true, b_at.contains(&k))] {
                if !on {
                    continue;
                }
                let y = DVector::from_fn(M, |_, _| rng.random_range(-2.0..2.0));
                if is_b {
                    for (position, aj) in kernels.iter().enumerate() {
                        let j = k + 1 + position - WINDOW;
                        cross.push((j, measured.len(), &qw * aj.transpose()));
                    }
                }
                measured.push(Measurement {
                    epoch: k,
                    h: h.clone(),
                    r: r.clone(),
                    y: y.clone(),
                });
                events.push((k, is_b, y));
            }
        }
        let mut stacked = Stacked {
            m0: m0.clone(),
            p0: p0.clone(),
            f: f.clone(),
            g: g.clone(),
            qw: qw.clone(),
            measured,
            cross,
            steps: STEPS,
        };
        let reference = stacked.log_density();
        // The windowed correlation matters: without it the same data score differently.
        stacked.cross.clear();
        assert!(rel(stacked.log_density(), reference) > 1e-6);

        let initial = StateAndCovariance::new(sv(&m0), s(&p0)).expect("initial");
        let config = FilterConfig::builder()
            .window_capacity(2 * WINDOW)
            .build()
            .expect("config");
        let mut kf = KalmanFilter::<f64, N, M>::new(
            s(&f),
            s(&(&g * &qw * g.transpose())),
            s(&h),
            s(&r),
            initial,
        )
        .expect("kf")
        .with_config(config);
        let windowed = KnownD {
            d: kernels
                .iter()
                .map(|aj| s(&(&g * &qw * aj.transpose())))
                .collect(),
        };
        let mut saw_noise_mean = false;
        let mut next = 0;
        for k in 1..=STEPS {
            kf.predict().expect("predict");
            while next < events.len() && events[next].0 == k {
                let (_, is_b, y) = &events[next];
                let y = sv::<M>(y);
                let report = if *is_b {
                    kf.update_windowed(&y, &windowed).expect("windowed update")
                } else {
                    kf.update(&y, &Zero).expect("update A")
                };
                assert!(report.is_accepted());
                saw_noise_mean |= report.noise_mean.amax() > 1e-3;
                next += 1;
            }
        }
        assert!(saw_noise_mean, "sensor A inside the window shifts E[v]");
        let err = rel(kf.log_likelihood(), reference);
        assert!(
            err < 1e-10,
            "seed {seed}: {} vs {reference} ({err:e})",
            kf.log_likelihood()
        );
        worst = worst.max(err);
    }
    println!("windowed stacked: worst relative error {worst:e}");
}
