//! Seeded Monte Carlo consistency: a linear system whose process and measurement
//! noises are truly correlated. The M-aware filter's average NEES must lie in the
//! 95 % chi-square band; the M-neglecting filter's must not.

use estim_core::nalgebra::{Matrix1, Matrix1x2, Matrix2, Matrix2x1, Vector1, Vector2};
use estim_core::{
    average_over_runs, chi_square_band, monte_carlo, nees, CrossCovariance, FilterConfig, Fixed,
    JointCheck, KalmanFilter, StateAndCovariance, Zero,
};
use rand_distr::{Distribution, StandardNormal};

const RUNS: usize = 300;
const STEPS: usize = 60;

/// Constant-velocity target, dt = 1, acceleration noise w_{k-1} ~ N(0, q).
/// The position sensor's noise contains the same acceleration noise:
/// v_k = c w_{k-1} + e_k, e_k ~ N(0, r_ind), so R = c^2 q + r_ind and
/// M = Cov(G w_{k-1}, v_k) = G c q. With c = -0.5 = -H G the sensor's error nearly
/// cancels the position part of the process noise (correlation of H G w and v about
/// -0.995): a standard filter badly mis-weights it.
struct Truth {
    f: Matrix2<f64>,
    g: Matrix2x1<f64>,
    h: Matrix1x2<f64>,
    q: f64,
    c: f64,
    r_ind: f64,
}

impl Truth {
    fn new() -> Self {
        Self {
            f: Matrix2::new(1.0, 1.0, 0.0, 1.0),
            g: Matrix2x1::new(0.5, 1.0),
            h: Matrix1x2::new(1.0, 0.0),
            q: 0.04,
            c: -0.5,
            r_ind: 0.0001,
        }
    }
    fn qd(&self) -> Matrix2<f64> {
        self.g * self.g.transpose() * self.q
    }
    fn r(&self) -> Matrix1<f64> {
        Matrix1::new(self.c * self.c * self.q + self.r_ind)
    }
    fn m(&self) -> Matrix2x1<f64> {
        self.g * (self.c * self.q)
    }
}

/// NEES per step of one run, for the filter using `cross`.
fn run<C: CrossCovariance<f64, Vector2<f64>, 2, 1>>(
    truth: &Truth,
    rng: &mut rand_chacha::ChaCha8Rng,
    cross: &C,
) -> Vec<f64> {
    let p0 = Matrix2::identity();
    let mut x = Vector2::new(0.0, 1.0);
    // Initial estimate drawn from the prior so the first NEES is chi-square too.
    let e0: Vector2<f64> = Vector2::from_fn(|_, _| StandardNormal.sample(rng));
    let initial = StateAndCovariance::new(x + e0, p0).unwrap();
    let config = FilterConfig::builder()
        .joint_check(JointCheck::Reject)
        .build()
        .unwrap();
    let mut kf = KalmanFilter::new(truth.f, truth.qd(), truth.h, truth.r(), initial)
        .unwrap()
        .with_config(config);
    let mut out = Vec::with_capacity(STEPS);
    for _ in 0..STEPS {
        let w: f64 = StandardNormal.sample(rng);
        let w = w * truth.q.sqrt();
        let e: f64 = StandardNormal.sample(rng);
        x = truth.f * x + truth.g * w;
        let y = truth.h * x + Vector1::new(truth.c * w + truth.r_ind.sqrt() * e);
        kf.step(Some(&y), cross).unwrap();
        let err = x - kf.estimate().state();
        out.push(nees(&err, kf.estimate().covariance()).unwrap());
    }
    out
}

#[test]
fn m_aware_filter_is_consistent_and_m_neglecting_is_not() {
    let truth = Truth::new();
    // Both filters see the same noise in each run (same seed per run index).
    let aware = monte_carlo(RUNS, |_, rng| run(&truth, rng, &Fixed(truth.m())));
    let neglect = monte_carlo(RUNS, |_, rng| run(&truth, rng, &Zero));
    let aware = average_over_runs(&aware).unwrap();
    let neglect = average_over_runs(&neglect).unwrap();
    let band = chi_square_band(2, RUNS, 0.95).unwrap();
    let inside = |s: &[f64]| s.iter().filter(|v| band.contains(**v)).count();
    let mean = |s: &[f64]| s[10..].iter().sum::<f64>() / (s.len() - 10) as f64;
    println!(
        "{RUNS} runs x {STEPS} steps, 95 % band of the average NEES (2 states): [{:.3}, {:.3}]",
        band.lower, band.upper
    );
    println!(
        "M-aware:     final average NEES {:.3}, time mean (steps 10..) {:.3}, steps inside band {}/{STEPS}",
        aware[STEPS - 1],
        mean(&aware),
        inside(&aware)
    );
    println!(
        "M-neglected: final average NEES {:.3}, time mean (steps 10..) {:.3}, steps inside band {}/{STEPS}",
        neglect[STEPS - 1],
        mean(&neglect),
        inside(&neglect)
    );
    assert!(
        band.contains(aware[STEPS - 1]),
        "M-aware final NEES {}",
        aware[STEPS - 1]
    );
    // 95 % of steps expected inside; the per-step averages are correlated in time,
    // so allow down to 80 %.
    assert!(
        inside(&aware) * 10 >= STEPS * 8,
        "M-aware: {}",
        inside(&aware)
    );
    assert!(
        !band.contains(neglect[STEPS - 1]),
        "M-neglected final NEES {} inside the band",
        neglect[STEPS - 1]
    );
    assert!(
        inside(&neglect) * 10 <= STEPS,
        "M-neglected: {}",
        inside(&neglect)
    );
}
