//! The five properties of the correlated update (issue 2), over random
//! well-conditioned systems for every (states, measurements) in 1..=9 x 1..=4.
//!
//! Each reference is coded here with dynamic matrices and LU inverses, independently
//! of the crate's static-size Cholesky code:
//! 1. M = 0: a textbook EKF (nonlinear process and measurement), against the EKF and
//!    the error-state runners.
//! 2. Stacked augmentation: the joint Gaussian of [x_{k-1}; w_{k-1}; v_k] pushed through
//!    the model and conditioned on y_k.
//! 3. Decorrelation (Simon 2006, sec. 7.1): the measurement seen as a measurement of
//!    x_{k-1} with noise nu = H G w + v, the process noise split into the part
//!    correlated with nu and the rest; an uncorrelated update then prediction.
//! 4. Short form = Joseph-like form at the optimal gain; symmetric PSD posterior over
//!    10,000 random steps.
//! 5. Invalid joint covariance and singular S give typed errors.

mod common;

use common::*;
use estim_core::nalgebra::{DMatrix, DVector, SMatrix, SVector};
use estim_core::update::correlated_update;
use estim_core::{
    CovarianceUpdate, Error, ErrorStateKalmanFilter, ErrorStateModel, ExtendedKalmanFilter,
    FilterConfig, Fixed, JointCheck, JointCovariance, KalmanFilter, MeasurementModel, ProcessModel,
    Result, StateAndCovariance, Zero,
};
use proptest::prelude::*;
use proptest::test_runner::{FileFailurePersistence, RngSeed, TestCaseError};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Tolerance of the comparisons with the references: the systems are well
/// conditioned (cond(S), cond(P) below ~1e3), so 1e-10 relative leaves room for the
/// round-off of two different factorisations.
const TOL: f64 = 1e-10;

/// Nonlinear process f(x) = F x + 0.1 sin(x) (elementwise), discrete noise Qd.
struct Wobble<const N: usize> {
    f: SMatrix<f64, N, N>,
    qd: SMatrix<f64, N, N>,
}

impl<const N: usize> ProcessModel<f64, N> for Wobble<N> {
    type State = SVector<f64, N>;
    type Input = ();
    fn propagate(&self, x: &Self::State, _: &(), _: f64) -> Result<Self::State> {
        Ok(self.f * x + x.map(|v| 0.1 * v.sin()))
    }
    fn transition(&self, x: &Self::State, _: &(), _: f64) -> Result<SMatrix<f64, N, N>> {
        Ok(self.f + SMatrix::from_diagonal(&x.map(|v| 0.1 * v.cos())))
    }
    fn process_noise(&self, _: &Self::State, _: &(), _: f64) -> Result<SMatrix<f64, N, N>> {
        Ok(self.qd)
    }
}

/// Additive error state: true = nominal + error.
impl<const N: usize> ErrorStateModel<f64, N> for Wobble<N> {
    fn inject(&self, nominal: &Self::State, error: &SVector<f64, N>) -> Result<Self::State> {
        Ok(nominal + error)
    }
}

/// Nonlinear measurement h(x) = H x + 0.1 sin(H x).
struct Bent<const N: usize, const M: usize> {
    h: SMatrix<f64, M, N>,
    r: SMatrix<f64, M, M>,
}

impl<const N: usize, const M: usize> MeasurementModel<f64, N, M> for Bent<N, M> {
    type State = SVector<f64, N>;
    fn predict(&self, x: &Self::State) -> Result<SVector<f64, M>> {
        let hx = self.h * x;
        Ok(hx + hx.map(|v| 0.1 * v.sin()))
    }
    fn jacobian(&self, x: &Self::State) -> Result<SMatrix<f64, M, N>> {
        let hx = self.h * x;
        Ok(SMatrix::from_diagonal(&hx.map(|v| 1.0 + 0.1 * v.cos())) * self.h)
    }
    fn noise_covariance(&self, _: &Self::State) -> Result<SMatrix<f64, M, M>> {
        Ok(self.r)
    }
}

/// Property 1 reference: textbook EKF (Simon 2006, sec. 13.2), dynamic matrices.
fn textbook_ekf<const N: usize, const M: usize>(
    sys: &System<N, M>,
    steps: usize,
) -> (DVector<f64>, DMatrix<f64>) {
    let f = dm(&sys.f);
    let h = dm(&sys.h);
    let q = dm(&sys.qd());
    let r = dm(&sys.r);
    let mut x = dv(&sys.x0);
    let mut p = dm(&sys.p0);
    for y in sys.ys.iter().take(steps) {
        let fj = &f + DMatrix::from_diagonal(&x.map(|v| 0.1 * v.cos()));
        x = &f * &x + x.map(|v| 0.1 * v.sin());
        p = &fj * &p * fj.transpose() + &q;
        let hx = &h * &x;
        let hj = DMatrix::from_diagonal(&hx.map(|v| 1.0 + 0.1 * v.cos())) * &h;
        let predicted = &hx + hx.map(|v| 0.1 * v.sin());
        let s = &hj * &p * hj.transpose() + &r;
        let k = &p * hj.transpose() * inv(&s);
        x += &k * (dv(y) - predicted);
        p = (DMatrix::identity(N, N) - &k * &hj) * &p;
    }
    (x, p)
}

/// Property 2 reference: Gaussian conditioning of the stacked [x_{k-1}; w; v].
fn stacked_reference<const N: usize, const M: usize>(
    sys: &System<N, M>,
) -> (DVector<f64>, DMatrix<f64>) {
    let (n, m) = (N, M);
    let dim = 2 * n + m;
    let mut sigma = DMatrix::zeros(dim, dim);
    sigma.view_mut((0, 0), (n, n)).copy_from(&dm(&sys.p0));
    sigma.view_mut((n, n), (n, n)).copy_from(&dm(&sys.qw));
    sigma.view_mut((n, 2 * n), (n, m)).copy_from(&dm(&sys.c));
    sigma
        .view_mut((2 * n, n), (m, n))
        .copy_from(&dm(&sys.c).transpose());
    sigma
        .view_mut((2 * n, 2 * n), (m, m))
        .copy_from(&dm(&sys.r));
    let mut mean = DVector::zeros(dim);
    mean.rows_mut(0, n).copy_from(&dv(&sys.x0));
    // [x_k; y_k] = T z with x_k = F x + G w, y_k = H F x + H G w + v.
    let (f, g, h) = (dm(&sys.f), dm(&sys.g), dm(&sys.h));
    let mut t = DMatrix::zeros(n + m, dim);
    t.view_mut((0, 0), (n, n)).copy_from(&f);
    t.view_mut((0, n), (n, n)).copy_from(&g);
    t.view_mut((n, 0), (m, n)).copy_from(&(&h * &f));
    t.view_mut((n, n), (m, n)).copy_from(&(&h * &g));
    t.view_mut((n, 2 * n), (m, m))
        .copy_from(&DMatrix::identity(m, m));
    let mu = &t * mean;
    let c = &t * sigma * t.transpose();
    let cxx = c.view((0, 0), (n, n)).clone_owned();
    let cxy = c.view((0, n), (n, m)).clone_owned();
    let cyy = c.view((n, n), (m, m)).clone_owned();
    let k = &cxy * inv(&cyy);
    let x = mu.rows(0, n) + &k * (dv(&sys.ys[0]) - mu.rows(n, m));
    let p = cxx - &k * cxy.transpose();
    (x, p)
}

/// Property 3 reference: decorrelation (Simon 2006, sec. 7.1, applied to the
/// one-step form). y_k = (H F) x_{k-1} + nu with nu = H G w + v, independent of
/// x_{k-1}. Write G w = D nu + w~ with D = Cov(G w, nu) Cov(nu)^-1, so w~ is
/// uncorrelated with nu and Cov(w~) = Qd - D Cov(nu) D'. Then
/// x_k = (F - D H F) x_{k-1} + D y_k + w~: update x_{k-1} with y_k by a standard
/// uncorrelated filter, then predict with the decorrelated process.
fn decorrelated_reference<const N: usize, const M: usize>(
    sys: &System<N, M>,
) -> (DVector<f64>, DMatrix<f64>) {
    let (f, h, r) = (dm(&sys.f), dm(&sys.h), dm(&sys.r));
    let qd = dm(&sys.qd());
    let mx = dm(&sys.m());
    let y = dv(&sys.ys[0]);
    let r_nu = &h * &qd * h.transpose() + &h * &mx + mx.transpose() * h.transpose() + &r;
    let c_wnu = &qd * h.transpose() + &mx;
    let d = &c_wnu * inv(&r_nu);
    let q_tilde = &qd - &d * &r_nu * d.transpose();
    // Standard (uncorrelated) update of x_{k-1}.
    let hs = &h * &f;
    let p0 = dm(&sys.p0);
    let x0 = dv(&sys.x0);
    let s = &hs * &p0 * hs.transpose() + &r_nu;
    let k = &p0 * hs.transpose() * inv(&s);
    let xs = &x0 + &k * (&y - &hs * &x0);
    let ps = (DMatrix::identity(N, N) - &k * &hs) * &p0;
    // Decorrelated prediction.
    let a = &f - &d * &hs;
    let x = &a * xs + &d * &y;
    let p = &a * ps * a.transpose() + q_tilde;
    (x, p)
}

fn kalman<const N: usize, const M: usize>(sys: &System<N, M>) -> KalmanFilter<f64, N, M> {
    KalmanFilter::new(
        sys.f,
        sys.qd(),
        sys.h,
        sys.r,
        StateAndCovariance::new(sys.x0, sys.p0).unwrap(),
    )
    .unwrap()
}

fn check<const N: usize>(
    name: &str,
    x: &SVector<f64, N>,
    p: &SMatrix<f64, N, N>,
    reference: &(DVector<f64>, DMatrix<f64>),
    tol: f64,
) -> std::result::Result<(), TestCaseError> {
    let ex = rel_err(&DMatrix::from_column_slice(N, 1, x.as_slice()), &{
        let r = &reference.0;
        DMatrix::from_column_slice(N, 1, r.as_slice())
    });
    let ep = rel_err(&dm(p), &reference.1);
    prop_assert!(
        ex <= tol && ep <= tol,
        "{name}: mean rel err {ex:e}, covariance rel err {ep:e}"
    );
    Ok(())
}

/// Properties 1-5 on one random system.
fn properties<const N: usize, const M: usize>(
    values: &[f64],
) -> std::result::Result<(), TestCaseError> {
    let sys = System::<N, M>::from_entries(values);

    // (1) M = 0 against the textbook EKF, 3 steps, EKF and error-state runners.
    let process = Wobble {
        f: sys.f,
        qd: sys.qd(),
    };
    let meas = Bent { h: sys.h, r: sys.r };
    let initial = StateAndCovariance::new(sys.x0, sys.p0).unwrap();
    let mut ekf = ExtendedKalmanFilter::new(
        Wobble {
            f: sys.f,
            qd: sys.qd(),
        },
        initial,
    );
    let mut eskf = ErrorStateKalmanFilter::new(process, sys.x0, sys.p0).unwrap();
    for y in sys.ys.iter().take(3) {
        ekf.step(&(), 1.0, &meas, Some(y), &Zero).unwrap();
        eskf.step(&(), 1.0, &meas, Some(y), &Zero).unwrap();
    }
    let reference = textbook_ekf(&sys, 3);
    check(
        "EKF vs textbook",
        ekf.estimate().state(),
        ekf.estimate().covariance(),
        &reference,
        TOL,
    )?;
    check(
        "ESKF vs textbook",
        eskf.nominal(),
        eskf.covariance(),
        &reference,
        TOL,
    )?;

    // (2) stacked augmentation, through the linear runner with Fixed(M).
    let mut kf = kalman(&sys);
    kf.predict().unwrap();
    let report = kf.update(&sys.ys[0], &Fixed(sys.m())).unwrap();
    // M derived from a valid joint covariance of (w, v): the runner must see it valid.
    prop_assert!(report.joint_min_eigenvalue.unwrap() >= -1e-12);
    let stacked = stacked_reference(&sys);
    check(
        "KF vs stacked",
        kf.estimate().state(),
        kf.estimate().covariance(),
        &stacked,
        TOL,
    )?;

    // (3) decorrelation reformulation.
    let decorrelated = decorrelated_reference(&sys);
    check(
        "KF vs decorrelated",
        kf.estimate().state(),
        kf.estimate().covariance(),
        &decorrelated,
        TOL,
    )?;

    // (4) short form = Joseph-like form at the optimal gain.
    let prior = StateAndCovariance::new(
        sys.f * sys.x0,
        sys.f * sys.p0 * sys.f.transpose() + sys.qd(),
    )
    .unwrap();
    let innovation = sys.ys[0] - sys.h * prior.state();
    let short = correlated_update(
        &prior,
        &innovation,
        &sys.h,
        &sys.r,
        &sys.m(),
        CovarianceUpdate::Short,
    )
    .unwrap();
    let joseph = correlated_update(
        &prior,
        &innovation,
        &sys.h,
        &sys.r,
        &sys.m(),
        CovarianceUpdate::JosephLike,
    )
    .unwrap();
    let ep = rel_err(
        &dm(short.posterior.covariance()),
        &dm(joseph.posterior.covariance()),
    );
    prop_assert!(ep <= TOL, "short vs Joseph-like: {ep:e}");

    // (5a) invalid joint covariance: scale the valid M beyond the largest valid scale.
    // The boundary is cross-checked against eigenvalues computed here.
    let qd = sys.qd();
    let u = sys.m();
    let c_max = JointCovariance::new(qd, u, sys.r)
        .largest_valid_scale()
        .unwrap();
    prop_assert!(c_max >= 1.0 - 1e-9, "valid M must be within: {c_max}");
    let joint = |c: f64| {
        let mut j = DMatrix::zeros(N + M, N + M);
        j.view_mut((0, 0), (N, N)).copy_from(&dm(&qd));
        j.view_mut((0, N), (N, M)).copy_from(&(dm(&u) * c));
        j.view_mut((N, 0), (M, N))
            .copy_from(&(dm(&u).transpose() * c));
        j.view_mut((N, N), (M, M)).copy_from(&dm(&sys.r));
        j
    };
    let eig_scale = qd.amax().max(sys.r.amax());
    prop_assert!(min_eig(&joint(c_max * 0.999)) >= -1e-12 * eig_scale);
    prop_assert!(min_eig(&joint(c_max * 1.01)) < 0.0);
    let bad = u * (c_max * 1.01);
    let err = JointCovariance::new(qd, bad, sys.r).check().unwrap_err();
    let rejected =
        matches!(err, Error::InvalidJointCovariance { min_eigenvalue } if min_eigenvalue < 0.0);
    prop_assert!(rejected, "{:?}", err);
    let mut strict = kalman(&sys).with_config(
        FilterConfig::builder()
            .joint_check(JointCheck::Reject)
            .build()
            .unwrap(),
    );
    strict.predict().unwrap();
    let before = strict.estimate().clone();
    let err = strict.update(&sys.ys[0], &Fixed(bad)).unwrap_err();
    let rejected = matches!(err, Error::InvalidJointCovariance { .. });
    prop_assert!(rejected, "{:?}", err);
    prop_assert_eq!(strict.estimate(), &before);

    // (5b) singular S, exactly in floating point: the last measurement repeats the
    // first (same row of H, same noise, same cross-covariance column), so S has two
    // bitwise identical rows; for M = 1, H = 0 and R = 0 give S = 0.
    let (mut h, mut r, mut mx) = (sys.h, sys.r, sys.m());
    if M == 1 {
        h.fill(0.0);
        r.fill(0.0);
        mx.fill(0.0);
    } else {
        let last = M - 1;
        h.set_row(last, &sys.h.row(0));
        mx.set_column(last, &sys.m().column(0));
        let r0 = sys.r;
        for i in 0..M {
            let src = if i == last { 0 } else { i };
            r[(i, last)] = r0[(src, 0)];
            r[(last, i)] = r0[(0, src)];
        }
    }
    let prior = StateAndCovariance::new(sys.x0, sys.p0).unwrap();
    let err = correlated_update(
        &prior,
        &sys.ys[0],
        &h,
        &r,
        &mx,
        CovarianceUpdate::JosephLike,
    )
    .unwrap_err();
    let typed = matches!(
        err,
        Error::InnovationNotPositiveDefinite | Error::InnovationIllConditioned { .. }
    );
    prop_assert!(typed, "{:?}", err);
    Ok(())
}

/// (4b) The posterior stays symmetric positive semidefinite over 10,000 random steps
/// (random F with spectral norm <= 1, random valid joint covariances, both forms
/// chained independently).
fn psd_over_many_steps<const N: usize, const M: usize>(seed: u64) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut draw = |len: usize| -> Vec<f64> {
        (0..len)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect::<Vec<f64>>()
    };
    let mut joseph =
        StateAndCovariance::new(SVector::<f64, N>::zeros(), SMatrix::identity()).unwrap();
    let mut short = joseph.clone();
    let mut worst = f64::INFINITY;
    for step in 0..10_000 {
        let sys = System::<N, M>::from_entries(&draw(entries_len(N, M)));
        // Orthogonal part of a random matrix (QR) times a contraction.
        let q = dm(&sys.f).qr().q() * 0.99;
        let f = SMatrix::<f64, N, N>::from_column_slice(q.as_slice());
        let qd = sys.qd() * 0.1;
        let m = sys.m() * 0.1_f64.sqrt();
        let r = sys.r;
        for (estimate, form) in [
            (&mut joseph, CovarianceUpdate::JosephLike),
            (&mut short, CovarianceUpdate::Short),
        ] {
            let prior = StateAndCovariance::new(
                f * estimate.state(),
                f * estimate.covariance() * f.transpose() + qd,
            )
            .unwrap();
            let innovation = sys.ys[0] - sys.h * prior.state();
            let out = correlated_update(&prior, &innovation, &sys.h, &r, &m, form).unwrap();
            let p = out.posterior.covariance();
            assert_eq!(*p, p.transpose(), "not symmetric at step {step} ({form:?})");
            let lmin = min_eig(&dm(p));
            assert!(
                lmin >= -1e-12 * p.amax(),
                "negative eigenvalue {lmin:e} at step {step} ({form:?})"
            );
            worst = worst.min(lmin / p.amax());
            *estimate = out.posterior;
        }
    }
    assert!(worst.is_finite());
}

macro_rules! for_every_size {
    ($($prop:ident, $psd:ident: $n:literal, $m:literal;)*) => {
        proptest! {
            #![proptest_config(ProptestConfig {
                cases: 48,
                rng_seed: RngSeed::Fixed(20_261_123),
                failure_persistence: Some(Box::new(FileFailurePersistence::WithSource(
                    "proptest-regressions",
                ))),
                ..ProptestConfig::default()
            })]
            $(
                #[test]
                fn $prop(values in proptest::collection::vec(-1.0f64..1.0, entries_len($n, $m))) {
                    properties::<$n, $m>(&values)?;
                }
            )*
        }
        $(
            #[test]
            fn $psd() {
                psd_over_many_steps::<$n, $m>(1000 * $n + $m);
            }
        )*
    };
}

for_every_size! {
    properties_n1_m1, psd_n1_m1: 1, 1;
    properties_n1_m2, psd_n1_m2: 1, 2;
    properties_n1_m3, psd_n1_m3: 1, 3;
    properties_n1_m4, psd_n1_m4: 1, 4;
    properties_n2_m1, psd_n2_m1: 2, 1;
    properties_n2_m2, psd_n2_m2: 2, 2;
    properties_n2_m3, psd_n2_m3: 2, 3;
    properties_n2_m4, psd_n2_m4: 2, 4;
    properties_n3_m1, psd_n3_m1: 3, 1;
    properties_n3_m2, psd_n3_m2: 3, 2;
    properties_n3_m3, psd_n3_m3: 3, 3;
    properties_n3_m4, psd_n3_m4: 3, 4;
    properties_n4_m1, psd_n4_m1: 4, 1;
    properties_n4_m2, psd_n4_m2: 4, 2;
    properties_n4_m3, psd_n4_m3: 4, 3;
    properties_n4_m4, psd_n4_m4: 4, 4;
    properties_n5_m1, psd_n5_m1: 5, 1;
    properties_n5_m2, psd_n5_m2: 5, 2;
    properties_n5_m3, psd_n5_m3: 5, 3;
    properties_n5_m4, psd_n5_m4: 5, 4;
    properties_n6_m1, psd_n6_m1: 6, 1;
    properties_n6_m2, psd_n6_m2: 6, 2;
    properties_n6_m3, psd_n6_m3: 6, 3;
    properties_n6_m4, psd_n6_m4: 6, 4;
    properties_n7_m1, psd_n7_m1: 7, 1;
    properties_n7_m2, psd_n7_m2: 7, 2;
    properties_n7_m3, psd_n7_m3: 7, 3;
    properties_n7_m4, psd_n7_m4: 7, 4;
    properties_n8_m1, psd_n8_m1: 8, 1;
    properties_n8_m2, psd_n8_m2: 8, 2;
    properties_n8_m3, psd_n8_m3: 8, 3;
    properties_n8_m4, psd_n8_m4: 8, 4;
    properties_n9_m1, psd_n9_m1: 9, 1;
    properties_n9_m2, psd_n9_m2: 9, 2;
    properties_n9_m3, psd_n9_m3: 9, 3;
    properties_n9_m4, psd_n9_m4: 9, 4;
}
