//! Exact windowed cross-covariance against joint-Gaussian conditioning of the whole
//! stacked problem [x_0; w_1..w_K; v_B; v_A], coded here with dynamic matrices
//! (never through the runners' bookkeeping).
//!
//! Scenario: K predicts with time-varying F_j, Q_j (K = 1..60); measurement B at the
//! end whose noise is v_B = sum_{j in W} A_j w_j + e_B over a window W of the last
//! L = 1..K steps (so D_j = Cov(w_j, v_B) = Q_j A_j', R_B = sum A_j Q_j A_j' + R_e, a
//! valid joint covariance); optionally an independent sensor A (noise v_A, M_A = 2)
//! updated after predict a = 1..K: inside the window, before it, or at the same epoch
//! as B (a = K, updated first). The filter's posterior after B must equal the
//! conditional mean and covariance of x_K given y_A and y_B to 1e-9 relative.

mod common;

use common::{dm, dv, inv, rel_err};
use estim_core::nalgebra::{DMatrix, DVector, SMatrix, SVector};
use estim_core::window::StepWindow;
use estim_core::{
    Error, ErrorStateKalmanFilter, ErrorStateModel, ExtendedKalmanFilter, FilterConfig,
    KalmanFilter, MeasurementModel, ProcessModel, Result, StateAndCovariance,
    WindowedCrossCovariance, Zero,
};
use proptest::prelude::*;
use proptest::test_runner::{FileFailurePersistence, RngSeed};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

const MA: usize = 2;

/// A random problem instance (dynamic matrices, so the reference stays independent
/// of the const-generic code under test).
#[derive(Debug, Clone)]
struct Problem {
    n: usize,
    m: usize,
    k: usize,
    window: usize,
    /// Step after which sensor A is updated (None: no sensor A).
    a_at: Option<usize>,
    m0: DVector<f64>,
    p0: DMatrix<f64>,
    /// F_j, Q_j for j = 1..=k (index j-1).
    f: Vec<DMatrix<f64>>,
    q: Vec<DMatrix<f64>>,
    /// D_j = Cov(w_j, v_B) for j = 1..=k (zero outside the window).
    d: Vec<DMatrix<f64>>,
    r_b: DMatrix<f64>,
    r_a: DMatrix<f64>,
    h_b: DMatrix<f64>,
    h_a: DMatrix<f64>,
    y_b: DVector<f64>,
    y_a: DVector<f64>,
}

fn random(rng: &mut ChaCha8Rng, r: usize, c: usize) -> DMatrix<f64> {
    DMatrix::from_fn(r, c, |_, _| rng.random_range(-1.0..1.0))
}

fn spd(rng: &mut ChaCha8Rng, n: usize, floor: f64) -> DMatrix<f64> {
    let b = random(rng, n, n);
    &b * b.transpose() / n as f64 + DMatrix::identity(n, n) * floor
}

impl Problem {
    fn new(n: usize, m: usize, seed: u64, k: usize, window: usize, a_at: Option<usize>) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let m0 = DVector::from_fn(n, |_, _| rng.random_range(-1.0..1.0));
        let p0 = spd(&mut rng, n, 0.5);
        let mut f = Vec::new();
        let mut q = Vec::new();
        let mut d = Vec::new();
        let mut r_b = spd(&mut rng, m, 0.05) * 0.2;
        for j in 1..=k {
            // Near-orthogonal transitions keep 60 steps well conditioned.
            let a = random(&mut rng, n, n);
            let skew = (&a - a.transpose()) * (0.3 / n as f64);
            f.push(DMatrix::identity(n, n) + skew + random(&mut rng, n, n) * (0.05 / n as f64));
            let qj = spd(&mut rng, n, 0.02) * 0.05;
            if j + window > k {
                let aj = random(&mut rng, m, n) * 0.5;
                r_b += &aj * &qj * aj.transpose();
                d.push(&qj * aj.transpose());
            } else {
                d.push(DMatrix::zeros(n, m));
            }
            q.push(qj);
        }
        let r_a = spd(&mut rng, MA, 0.1) * 0.3;
        let h_b = random(&mut rng, m, n);
        let h_a = random(&mut rng, MA, n);
        let y_b = DVector::from_fn(m, |_, _| rng.random_range(-2.0..2.0));
        let y_a = DVector::from_fn(MA, |_, _| rng.random_range(-2.0..2.0));
        Self {
            n,
            m,
            k,
            window,
            a_at,
            m0,
            p0,
            f,
            q,
            d,
            r_b,
            r_a,
            h_b,
            h_a,
            y_b,
            y_a,
        }
    }

    /// Posterior mean and covariance of x_K given the measurements, by plain
    /// Gaussian conditioning of z = [x_0; w_1..w_K; v_B; v_A].
    fn reference(&self) -> (DVector<f64>, DMatrix<f64>) {
        let (n, m, k) = (self.n, self.m, self.k);
        let dim = n * (k + 1) + m + MA;
        let vb = n * (k + 1);
        let va = vb + m;
        let mut cov = DMatrix::zeros(dim, dim);
        cov.view_mut((0, 0), (n, n)).copy_from(&self.p0);
        for j in 1..=k {
            let w = n * j;
            cov.view_mut((w, w), (n, n)).copy_from(&self.q[j - 1]);
            cov.view_mut((w, vb), (n, m)).copy_from(&self.d[j - 1]);
            cov.view_mut((vb, w), (m, n))
                .copy_from(&self.d[j - 1].transpose());
        }
        cov.view_mut((vb, vb), (m, m)).copy_from(&self.r_b);
        cov.view_mut((va, va), (MA, MA)).copy_from(&self.r_a);
        let mut mean = DVector::zeros(dim);
        mean.rows_mut(0, n).copy_from(&self.m0);
        // x_j = L_j z.
        let mut l = DMatrix::zeros(n, dim);
        l.view_mut((0, 0), (n, n)).fill_with_identity();
        let mut rows: Vec<DMatrix<f64>> = Vec::new();
        let mut ys: Vec<DVector<f64>> = Vec::new();
        for j in 1..=k {
            l = &self.f[j - 1] * &l;
            let mut w = DMatrix::zeros(n, dim);
            w.view_mut((0, n * j), (n, n)).fill_with_identity();
            l += w;
            if self.a_at == Some(j) {
                let mut t = &self.h_a * &l;
                let mut e = DMatrix::zeros(MA, dim);
                e.view_mut((0, va), (MA, MA)).fill_with_identity();
                t += e;
                rows.push(t);
                ys.push(self.y_a.clone());
            }
        }
        let mut t = &self.h_b * &l;
        let mut e = DMatrix::zeros(m, dim);
        e.view_mut((0, vb), (m, m)).fill_with_identity();
        t += e;
        rows.push(t);
        ys.push(self.y_b.clone());
        let total: usize = rows.iter().map(|r| r.nrows()).sum();
        let mut tm = DMatrix::zeros(total, dim);
        let mut y = DVector::zeros(total);
        let mut at = 0;
        for (r, v) in rows.iter().zip(&ys) {
            tm.view_mut((at, 0), (r.nrows(), dim)).copy_from(r);
            y.rows_mut(at, v.len()).copy_from(v);
            at += r.nrows();
        }
        let sxy = &l * &cov * tm.transpose();
        let syy = &tm * &cov * tm.transpose();
        let gain = &sxy * inv(&syy);
        let post_mean = &l * &mean + &gain * (y - &tm * &mean);
        let post_cov = &l * &cov * l.transpose() - &gain * sxy.transpose();
        (post_mean, post_cov)
    }
}

/// The linear time-varying process: input = step index j (1-based).
struct Ltv<const N: usize> {
    f: Vec<SMatrix<f64, N, N>>,
    q: Vec<SMatrix<f64, N, N>>,
}

impl<const N: usize> ProcessModel<f64, N> for Ltv<N> {
    type State = SVector<f64, N>;
    type Input = usize;
    fn propagate(&self, x: &Self::State, j: &usize, _: f64) -> Result<Self::State> {
        Ok(self.f[*j - 1] * x)
    }
    fn transition(&self, _: &Self::State, j: &usize, _: f64) -> Result<SMatrix<f64, N, N>> {
        Ok(self.f[*j - 1])
    }
    fn process_noise(&self, _: &Self::State, j: &usize, _: f64) -> Result<SMatrix<f64, N, N>> {
        Ok(self.q[*j - 1])
    }
}

impl<const N: usize> ErrorStateModel<f64, N> for Ltv<N> {
    fn inject(&self, nominal: &Self::State, error: &SVector<f64, N>) -> Result<Self::State> {
        Ok(nominal + error)
    }
}

struct Linear<const N: usize, const M: usize> {
    h: SMatrix<f64, M, N>,
    r: SMatrix<f64, M, M>,
}

impl<const N: usize, const M: usize> MeasurementModel<f64, N, M> for Linear<N, M> {
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

/// D_j looked up by the step index the runner recorded as the step's input.
struct KnownD<const N: usize, const M: usize> {
    window: usize,
    d: Vec<SMatrix<f64, N, M>>,
}

impl<const N: usize, const M: usize> WindowedCrossCovariance<f64, SVector<f64, N>, usize, N, M>
    for KnownD<N, M>
{
    fn window_steps(&self) -> usize {
        self.window
    }
    fn step_cross_covariances(
        &self,
        window: &StepWindow<'_, f64, SVector<f64, N>, usize, N>,
        sink: &mut dyn FnMut(&SMatrix<f64, N, M>) -> Result<()>,
    ) -> Result<()> {
        for step in window.iter() {
            sink(&self.d[*step.input - 1])?;
        }
        Ok(())
    }
}

/// The same for the linear KF (input `()`): by position in the window.
struct KnownDByPosition<const N: usize, const M: usize> {
    d: Vec<SMatrix<f64, N, M>>,
}

impl<const N: usize, const M: usize> WindowedCrossCovariance<f64, SVector<f64, N>, (), N, M>
    for KnownDByPosition<N, M>
{
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

fn s<const R: usize, const C: usize>(m: &DMatrix<f64>) -> SMatrix<f64, R, C> {
    SMatrix::from_fn(|r, c| m[(r, c)])
}

fn config(p: &Problem) -> FilterConfig {
    // Capacity larger than the window: only the window's steps may count.
    FilterConfig::builder()
        .window_capacity(p.k + 3)
        .build()
        .expect("config")
}

fn check_close(
    what: &str,
    mean: &DVector<f64>,
    cov: &DMatrix<f64>,
    reference: &(DVector<f64>, DMatrix<f64>),
) -> std::result::Result<(), TestCaseError> {
    let em = rel_err(
        &DMatrix::from_column_slice(mean.len(), 1, mean.as_slice()),
        &DMatrix::from_column_slice(reference.0.len(), 1, reference.0.as_slice()),
    );
    let ec = rel_err(cov, &reference.1);
    prop_assert!(em < 1e-9, "{what}: mean relative error {em:e}");
    prop_assert!(ec < 1e-9, "{what}: covariance relative error {ec:e}");
    Ok(())
}

/// EKF and ESKF on the LTV problem.
fn nonlinear_runners<const N: usize, const M: usize>(
    p: &Problem,
) -> std::result::Result<(), TestCaseError> {
    let reference = p.reference();
    let process = || Ltv::<N> {
        f: p.f.iter().map(s::<N, N>).collect(),
        q: p.q.iter().map(s::<N, N>).collect(),
    };
    let sensor_b = Linear::<N, M> {
        h: s(&p.h_b),
        r: s(&p.r_b),
    };
    let sensor_a = Linear::<N, MA> {
        h: s(&p.h_a),
        r: s(&p.r_a),
    };
    let cross = KnownD::<N, M> {
        window: p.window,
        d: p.d.iter().map(s::<N, M>).collect(),
    };
    let y_b: SVector<f64, M> = s(&DMatrix::from_column_slice(M, 1, p.y_b.as_slice()));
    let y_a: SVector<f64, MA> = s(&DMatrix::from_column_slice(MA, 1, p.y_a.as_slice()));
    let initial = StateAndCovariance::new(
        s(&DMatrix::from_column_slice(N, 1, p.m0.as_slice())),
        s(&p.p0),
    )
    .expect("initial");

    let mut ekf = ExtendedKalmanFilter::new(process(), initial.clone()).with_config(config(p));
    let mut eskf = ErrorStateKalmanFilter::new(process(), *initial.state(), *initial.covariance())
        .expect("eskf")
        .with_config(config(p));
    for j in 1..=p.k {
        ekf.predict(&j, 1.0).expect("predict");
        eskf.predict(&j, 1.0).expect("predict");
        if p.a_at == Some(j) {
            ekf.update(&sensor_a, &y_a, &Zero).expect("update A");
            eskf.update(&sensor_a, &y_a, &Zero).expect("update A");
        }
    }
    let report = ekf
        .update_windowed(&sensor_b, &y_b, &cross)
        .expect("windowed update");
    prop_assert!(report.is_accepted());
    check_close(
        "EKF",
        &dv(ekf.estimate().state()),
        &dm(ekf.estimate().covariance()),
        &reference,
    )?;
    eskf.update_windowed(&sensor_b, &y_b, &cross)
        .expect("windowed update");
    check_close(
        "ESKF",
        &dv(eskf.nominal()),
        &dm(eskf.covariance()),
        &reference,
    )?;
    Ok(())
}

/// The linear KF needs a time-invariant F, Q and one H, R: sensor A is then a second
/// sensor of the same kind with independent noise of covariance R_B.
fn linear_runner<const N: usize, const M: usize>(
    mut p: Problem,
) -> std::result::Result<(), TestCaseError> {
    for j in 1..p.k {
        p.f[j] = p.f[0].clone();
        p.q[j] = p.q[0].clone();
    }
    // Rebuild D and R_B for the time-invariant Q (same A_j draws are not needed: any
    // valid kernel does).
    let mut rng = ChaCha8Rng::seed_from_u64(p.k as u64 * 7919 + p.window as u64);
    let mut r_b = spd(&mut rng, p.m, 0.05) * 0.2;
    for j in 1..=p.k {
        if j + p.window > p.k {
            let aj = random(&mut rng, p.m, p.n) * 0.5;
            r_b += &aj * &p.q[0] * aj.transpose();
            p.d[j - 1] = &p.q[0] * aj.transpose();
        }
    }
    p.r_b = r_b;
    p.h_a = p.h_b.clone();
    p.r_a = p.r_b.clone();
    let mut y_a = p.y_b.clone() * -0.5;
    y_a[0] += 0.3;
    p.y_a = y_a;
    // Sensor A has size M here: the reference is generic in MA only through r_a/h_a
    // sizes, so stack it by hand.
    let reference = reference_same_size(&p);
    let initial = StateAndCovariance::new(
        s(&DMatrix::from_column_slice(N, 1, p.m0.as_slice())),
        s(&p.p0),
    )
    .expect("initial");
    let mut kf =
        KalmanFilter::<f64, N, M>::new(s(&p.f[0]), s(&p.q[0]), s(&p.h_b), s(&p.r_b), initial)
            .expect("kf")
            .with_config(config(&p));
    let y_a: SVector<f64, M> = s(&DMatrix::from_column_slice(M, 1, p.y_a.as_slice()));
    let y_b: SVector<f64, M> = s(&DMatrix::from_column_slice(M, 1, p.y_b.as_slice()));
    for j in 1..=p.k {
        kf.predict().expect("predict");
        if p.a_at == Some(j) {
            kf.update(&y_a, &Zero).expect("update A");
        }
    }
    let cross = KnownDByPosition::<N, M> {
        d: p.d[p.k - p.window..].iter().map(s::<N, M>).collect(),
    };
    kf.update_windowed(&y_b, &cross).expect("windowed update");
    check_close(
        "KF",
        &dv(kf.estimate().state()),
        &dm(kf.estimate().covariance()),
        &reference,
    )
}

/// Reference for the KF case, where sensor A has the size and covariance of B.
fn reference_same_size(p: &Problem) -> (DVector<f64>, DMatrix<f64>) {
    let (n, m, k) = (p.n, p.m, p.k);
    let dim = n * (k + 1) + 2 * m;
    let vb = n * (k + 1);
    let va = vb + m;
    let mut cov = DMatrix::zeros(dim, dim);
    cov.view_mut((0, 0), (n, n)).copy_from(&p.p0);
    for j in 1..=k {
        let w = n * j;
        cov.view_mut((w, w), (n, n)).copy_from(&p.q[j - 1]);
        cov.view_mut((w, vb), (n, m)).copy_from(&p.d[j - 1]);
        cov.view_mut((vb, w), (m, n))
            .copy_from(&p.d[j - 1].transpose());
    }
    cov.view_mut((vb, vb), (m, m)).copy_from(&p.r_b);
    cov.view_mut((va, va), (m, m)).copy_from(&p.r_a);
    let mut mean = DVector::zeros(dim);
    mean.rows_mut(0, n).copy_from(&p.m0);
    let mut l = DMatrix::zeros(n, dim);
    l.view_mut((0, 0), (n, n)).fill_with_identity();
    let mut tm = DMatrix::zeros(0, dim);
    let mut y = DVector::zeros(0);
    for j in 1..=k {
        l = &p.f[j - 1] * &l;
        l.view_mut((0, n * j), (n, n)).fill_with_identity();
        if p.a_at == Some(j) {
            let mut t = &p.h_a * &l;
            for i in 0..m {
                t[(i, va + i)] = 1.0;
            }
            tm = stack(&tm, &t);
            y = DVector::from_iterator(y.len() + m, y.iter().copied().chain(p.y_a.iter().copied()));
        }
    }
    let mut t = &p.h_b * &l;
    for i in 0..m {
        t[(i, vb + i)] = 1.0;
    }
    tm = stack(&tm, &t);
    y = DVector::from_iterator(y.len() + m, y.iter().copied().chain(p.y_b.iter().copied()));
    let sxy = &l * &cov * tm.transpose();
    let syy = &tm * &cov * tm.transpose();
    let gain = &sxy * inv(&syy);
    (
        &l * &mean + &gain * (y - &tm * &mean),
        &l * &cov * l.transpose() - &gain * sxy.transpose(),
    )
}

fn stack(a: &DMatrix<f64>, b: &DMatrix<f64>) -> DMatrix<f64> {
    let mut out = DMatrix::zeros(a.nrows() + b.nrows(), b.ncols());
    if a.nrows() > 0 {
        out.view_mut((0, 0), (a.nrows(), a.ncols())).copy_from(a);
    }
    out.view_mut((a.nrows(), 0), (b.nrows(), b.ncols()))
        .copy_from(b);
    out
}

/// (K, window, where sensor A updates): windows of 1..K steps, A inside the window,
/// before it, at the same epoch as B, or absent.
fn scenario() -> impl Strategy<Value = (u64, usize, usize, Option<usize>)> {
    (any::<u64>(), 1usize..=60).prop_flat_map(|(seed, k)| {
        (
            Just(seed),
            Just(k),
            1usize..=k,
            prop_oneof![Just(None), (1usize..=k).prop_map(Some), Just(Some(k))],
        )
    })
}

macro_rules! for_every_size {
    ($($name:ident: $n:literal, $m:literal;)*) => {
        proptest! {
            #![proptest_config(ProptestConfig {
                cases: 12,
                rng_seed: RngSeed::Fixed(20_261_130),
                failure_persistence: Some(Box::new(FileFailurePersistence::WithSource(
                    "proptest-regressions",
                ))),
                ..ProptestConfig::default()
            })]
            $(
                #[test]
                fn $name((seed, k, window, a_at) in scenario()) {
                    let p = Problem::new($n, $m, seed, k, window, a_at);
                    nonlinear_runners::<$n, $m>(&p)?;
                    linear_runner::<$n, $m>(p)?;
                }
            )*
        }
    };
}

for_every_size! {
    stacked_n1_m1: 1, 1; stacked_n1_m2: 1, 2; stacked_n1_m3: 1, 3; stacked_n1_m4: 1, 4;
    stacked_n2_m1: 2, 1; stacked_n2_m2: 2, 2; stacked_n2_m3: 2, 3; stacked_n2_m4: 2, 4;
    stacked_n3_m1: 3, 1; stacked_n3_m2: 3, 2; stacked_n3_m3: 3, 3; stacked_n3_m4: 3, 4;
    stacked_n4_m1: 4, 1; stacked_n4_m2: 4, 2; stacked_n4_m3: 4, 3; stacked_n4_m4: 4, 4;
    stacked_n5_m1: 5, 1; stacked_n5_m2: 5, 2; stacked_n5_m3: 5, 3; stacked_n5_m4: 5, 4;
    stacked_n6_m1: 6, 1; stacked_n6_m2: 6, 2; stacked_n6_m3: 6, 3; stacked_n6_m4: 6, 4;
    stacked_n7_m1: 7, 1; stacked_n7_m2: 7, 2; stacked_n7_m3: 7, 3; stacked_n7_m4: 7, 4;
    stacked_n8_m1: 8, 1; stacked_n8_m2: 8, 2; stacked_n8_m3: 8, 3; stacked_n8_m4: 8, 4;
    stacked_n9_m1: 9, 1; stacked_n9_m2: 9, 2; stacked_n9_m3: 9, 3; stacked_n9_m4: 9, 4;
}

/// A window longer than the update interval spans the sensor's own previous
/// (correlated) update: coloured noise, refused with a typed error.
#[test]
fn window_longer_than_update_interval_is_coloured_noise() {
    let p = Problem::new(2, 1, 5, 10, 10, None);
    let process = Ltv::<2> {
        f: p.f.iter().map(s::<2, 2>).collect(),
        q: p.q.iter().map(s::<2, 2>).collect(),
    };
    let sensor = Linear::<2, 1> {
        h: s(&p.h_b),
        r: s(&p.r_b),
    };
    let cross = KnownD::<2, 1> {
        window: 6,
        d: vec![SMatrix::<f64, 2, 1>::new(0.001, 0.002); 10],
    };
    let initial = StateAndCovariance::new(SVector::zeros(), SMatrix::identity()).expect("initial");
    let mut ekf = ExtendedKalmanFilter::new(process, initial).with_config(
        FilterConfig::builder()
            .window_capacity(8)
            .build()
            .expect("config"),
    );
    let y = SVector::<f64, 1>::new(0.1);
    for j in 1..=6 {
        ekf.predict(&j, 1.0).expect("predict");
    }
    ekf.update_windowed(&sensor, &y, &cross)
        .expect("first update");
    for j in 7..=9 {
        ekf.predict(&j, 1.0).expect("predict");
    }
    // Window 6 > interval 3: the previous correlated update lies inside.
    let before = ekf.estimate().clone();
    let err = ekf.update_windowed(&sensor, &y, &cross).unwrap_err();
    assert!(
        matches!(
            err,
            Error::ColouredMeasurementNoise {
                window: 6,
                steps_before_end: 3
            }
        ),
        "{err}"
    );
    assert_eq!(*ekf.estimate(), before, "state untouched on error");
}

/// Windows that do not fit what was recorded, and a filter that records nothing.
#[test]
fn window_longer_than_recorded_or_not_kept_is_a_typed_error() {
    let p = Problem::new(2, 1, 6, 10, 4, None);
    let make = |capacity: usize| {
        let process = Ltv::<2> {
            f: p.f.iter().map(s::<2, 2>).collect(),
            q: p.q.iter().map(s::<2, 2>).collect(),
        };
        let initial =
            StateAndCovariance::new(SVector::zeros(), SMatrix::identity()).expect("initial");
        ExtendedKalmanFilter::new(process, initial).with_config(
            FilterConfig::builder()
                .window_capacity(capacity)
                .build()
                .expect("config"),
        )
    };
    let sensor = Linear::<2, 1> {
        h: s(&p.h_b),
        r: s(&p.r_b),
    };
    let cross = KnownD::<2, 1> {
        window: 4,
        d: vec![SMatrix::<f64, 2, 1>::zeros(); 10],
    };
    let y = SVector::<f64, 1>::new(0.1);
    // Nothing kept (default capacity 0): nothing recorded, typed error.
    let mut none = make(0);
    for j in 1..=5 {
        none.predict(&j, 1.0).expect("predict");
    }
    assert_eq!(none.recorded_steps(), 0);
    assert!(matches!(
        none.update_windowed(&sensor, &y, &cross),
        Err(Error::NotTracked { .. })
    ));
    // Capacity 3 < window 4.
    let mut small = make(3);
    for j in 1..=5 {
        small.predict(&j, 1.0).expect("predict");
    }
    assert_eq!(small.recorded_steps(), 3, "memory bounded by the capacity");
    assert!(matches!(
        small.update_windowed(&sensor, &y, &cross),
        Err(Error::WindowUnavailable {
            needed: 4,
            available: 3,
            capacity: 3
        })
    ));
    // Enough capacity but only 2 predicts so far.
    let mut early = make(8);
    for j in 1..=2 {
        early.predict(&j, 1.0).expect("predict");
    }
    assert!(matches!(
        early.update_windowed(&sensor, &y, &cross),
        Err(Error::WindowUnavailable {
            needed: 4,
            available: 2,
            ..
        })
    ));
}

/// A model that hands the runner the wrong number of D_j is a typed error.
#[test]
fn wrong_number_of_steps_from_the_model_is_a_typed_error() {
    struct TooFew;
    impl WindowedCrossCovariance<f64, SVector<f64, 1>, usize, 1, 1> for TooFew {
        fn window_steps(&self) -> usize {
            3
        }
        fn step_cross_covariances(
            &self,
            _: &StepWindow<'_, f64, SVector<f64, 1>, usize, 1>,
            sink: &mut dyn FnMut(&SMatrix<f64, 1, 1>) -> Result<()>,
        ) -> Result<()> {
            sink(&SMatrix::zeros())
        }
    }
    let process = Ltv::<1> {
        f: vec![SMatrix::identity(); 4],
        q: vec![SMatrix::identity() * 0.1; 4],
    };
    let initial = StateAndCovariance::new(SVector::zeros(), SMatrix::identity()).expect("initial");
    let mut ekf = ExtendedKalmanFilter::new(process, initial).with_config(
        FilterConfig::builder()
            .window_capacity(4)
            .build()
            .expect("config"),
    );
    for j in 1..=4 {
        ekf.predict(&j, 1.0).expect("predict");
    }
    let sensor = Linear::<1, 1> {
        h: SMatrix::identity(),
        r: SMatrix::identity(),
    };
    assert!(matches!(
        ekf.update_windowed(&sensor, &SVector::<f64, 1>::new(0.0), &TooFew),
        Err(Error::Dimension {
            expected: 3,
            got: 1,
            ..
        })
    ));
}
