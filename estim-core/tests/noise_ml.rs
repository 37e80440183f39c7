//! Maximum-likelihood noise parameters (`noise::ml`) against independent references:
//!
//! - the model's log-likelihood (a runner's cumulative value, windowed M) against the
//!   log density of the stacked measurement vector from its joint Gaussian, built here
//!   from x_0, every acceleration sample and every independent noise;
//! - the dual-number gradient and hyper-dual information against central finite
//!   differences of the `f64` log-likelihood (and of the gradient);
//! - recovery: over seeded datasets of a 4-state model whose measurement noise shares
//!   the accelerations of a 3-step window, the estimates cover the truth within 2
//!   standard errors and the standard errors match the spread of the estimates;
//! - the likelihood-ratio test of M = 0: its size over 1,000 seeded datasets simulated
//!   with M = 0 is in [3 %, 7 %] (nominal 5 %; binomial standard error 0.7 %).
//!
//! Seeded (ChaCha8), deterministic.

#[path = "common/shared_noise.rs"]
mod shared_noise;

use estim_core::nalgebra::{DMatrix, DVector, SVector};
use estim_core::noise::ml::{
    gradient, likelihood_ratio_test, maximize, observed_information, Bounds, FitOptions,
    LogLikelihood, MaximumLikelihood,
};
use rayon::prelude::*;
use shared_noise::{Dataset, Setup};

const TRUTH: [f64; 4] = [0.5, 0.2, 0.0025, 0.6];

fn bounds() -> Bounds<4> {
    Bounds::new(
        SVector::from([0.0, 0.0, 0.0, -10.0]),
        SVector::from([f64::INFINITY, f64::INFINITY, f64::INFINITY, 10.0]),
    )
    .expect("valid bounds")
}

/// ln N(y; 0, Sigma) of the stacked measurements, from the linear map of
/// [x_0; a_1..a_T; e_1..e_K] (independent standard parts) to y.
fn stacked_log_density(data: &Dataset, theta: [f64; 4]) -> f64 {
    let s = data.setup;
    let [qx, qy, r, c] = theta;
    let steps = s.updates * s.interval;
    let (n0, na, ne) = (4, 2 * steps, 2 * s.updates);
    let cols = n0 + na + ne;
    // State as a linear function of the standard normals: x = X z.
    let mut x = DMatrix::<f64>::zeros(4, cols);
    for i in 0..4 {
        x[(i, i)] = s.initial_std[i];
    }
    let f = DMatrix::from_row_slice(
        4,
        4,
        &[
            1.0, s.dt, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, s.dt, 0.0, 0.0, 0.0, 1.0,
        ],
    );
    let g = [s.dt * s.dt / 2.0, s.dt];
    let mut y = DMatrix::<f64>::zeros(2 * s.updates, cols);
    let mut k = 0;
    for step in 1..=steps {
        x = &f * &x;
        let (ax, ay) = (n0 + 2 * (step - 1), n0 + 2 * (step - 1) + 1);
        x[(0, ax)] += g[0] * qx.sqrt();
        x[(1, ax)] += g[1] * qx.sqrt();
        x[(2, ay)] += g[0] * qy.sqrt();
        x[(3, ay)] += g[1] * qy.sqrt();
        if step % s.interval == 0 {
            for axis in 0..2 {
                let row = 2 * k + axis;
                for col in 0..cols {
                    y[(row, col)] = x[(2 * axis, col)];
                }
                for back in 0..s.window.min(step) {
                    let a = n0 + 2 * (step - 1 - back) + axis;
                    let std = if axis == 0 { qx.sqrt() } else { qy.sqrt() };
                    y[(row, a)] += c * s.dt * std;
                }
                y[(row, n0 + na + row)] += r.sqrt();
            }
            k += 1;
        }
    }
    let sigma = &y * y.transpose();
    let obs = DVector::from_iterator(2 * s.updates, data.measurements.iter().flatten().copied());
    let chol = sigma.cholesky().expect("stacked covariance is SPD");
    let log_det = 2.0 * chol.l().diagonal().iter().map(|v| v.ln()).sum::<f64>();
    let quad = obs.dot(&chol.solve(&obs));
    -0.5 * (obs.len() as f64 * (2.0 * std::f64::consts::PI).ln() + log_det + quad)
}

#[test]
fn likelihood_equals_the_stacked_gaussian() {
    let setup = Setup {
        updates: 15,
        ..Setup::default()
    };
    let mut worst: f64 = 0.0;
    for seed in 0..4 {
        let data = Dataset::simulate(setup, TRUTH, seed);
        for theta in [TRUTH, [0.3, 0.9, 0.05, -0.4], [1.0, 1.0, 0.02, 0.0]] {
            let filter = data
                .log_likelihood(&SVector::from(theta))
                .expect("likelihood");
            let stacked = stacked_log_density(&data, theta);
            worst = worst.max((filter - stacked).abs() / stacked.abs());
        }
    }
    println!(
        "windowed model: filter vs stacked log-likelihood, max relative difference {worst:.1e}"
    );
    assert!(worst < 1e-11, "{worst:e}");
}

#[test]
fn gradient_and_information_equal_finite_differences() {
    let data = Dataset::simulate(
        Setup {
            updates: 60,
            ..Setup::default()
        },
        TRUTH,
        11,
    );
    let theta = SVector::from([0.4, 0.3, 0.015, 0.5]);
    let free = [false; 4];
    let (value, grad) = gradient(&data, &theta, &free).expect("gradient");
    let info = observed_information(&data, &theta, &free).expect("information");
    assert_eq!(
        value,
        data.log_likelihood(&theta).expect("value"),
        "same value as f64 pass"
    );
    let (mut worst_g, mut worst_h): (f64, f64) = (0.0, 0.0);
    for i in 0..4 {
        let h = 1e-5 * theta[i].abs();
        let mut plus = theta;
        let mut minus = theta;
        plus[i] += h;
        minus[i] -= h;
        let fd = (data.log_likelihood(&plus).unwrap() - data.log_likelihood(&minus).unwrap())
            / (2.0 * h);
        worst_g = worst_g.max((grad[i] - fd).abs() / grad.amax());
        let gp = gradient(&data, &plus, &free).unwrap().1;
        let gm = gradient(&data, &minus, &free).unwrap().1;
        for j in 0..4 {
            let fd_h = -(gp[j] - gm[j]) / (2.0 * h);
            worst_h = worst_h.max((info[(i, j)] - fd_h).abs() / info.amax());
        }
    }
    println!("gradient vs central differences {worst_g:.1e}, information {worst_h:.1e}");
    // Central differences with h = 1e-5 theta: truncation ~ h^2 |f'''| ~ 1e-10 relative,
    // round-off ~ eps |f| / h ~ 1e-8 relative to the gradient's scale.
    assert!(worst_g < 1e-6, "{worst_g:e}");
    assert!(worst_h < 1e-6, "{worst_h:e}");
}

#[test]
fn derivatives_at_m_zero_equal_finite_differences() {
    // At c = 0 the cross-covariance's value is 0 but its derivative is not: the
    // update must not take the M = 0 shortcut for dual numbers (d ln p / d c would be 0).
    let data = Dataset::simulate(
        Setup {
            updates: 60,
            ..Setup::default()
        },
        TRUTH,
        13,
    );
    let theta = SVector::from([0.4, 0.3, 0.015, 0.0]);
    let free = [false; 4];
    let (_, grad) = gradient(&data, &theta, &free).expect("gradient");
    let info = observed_information(&data, &theta, &free).expect("information");
    let h = 1e-5;
    let at = |c: f64| {
        let mut t = theta;
        t[3] = c;
        data.log_likelihood(&t).unwrap()
    };
    let fd = (at(h) - at(-h)) / (2.0 * h);
    let fd2 = -(at(h) - 2.0 * at(0.0) + at(-h)) / (h * h);
    println!(
        "d ln p / d c at c = 0: dual {} vs central difference {fd}",
        grad[3]
    );
    assert!(fd.abs() > 1.0, "the data must make the slope visible: {fd}");
    assert!(
        (grad[3] - fd).abs() < 1e-6 * fd.abs(),
        "{} vs {fd}",
        grad[3]
    );
    // Second difference: rounding ~ eps |ln p| / h^2 ~ 1e-6 relative at h = 1e-5.
    assert!(
        (info[(3, 3)] - fd2).abs() < 1e-4 * fd2.abs(),
        "{} vs {fd2}",
        info[(3, 3)]
    );
}

fn fit(data: &Dataset, bounds: &Bounds<4>, start: [f64; 4]) -> MaximumLikelihood<4> {
    maximize(data, &SVector::from(start), bounds, &FitOptions::default()).expect("fit")
}

#[test]
fn recovers_known_noise_within_two_standard_errors() {
    let datasets = 200;
    let start = [1.0, 1.0, 0.01, 0.1];
    // Independent seeded fits, on every core (rayon keeps their order).
    let fits: Vec<MaximumLikelihood<4>> = (0..datasets)
        .into_par_iter()
        .map(|seed| {
            fit(
                &Dataset::simulate(Setup::default(), TRUTH, 1000 + seed),
                &bounds(),
                start,
            )
        })
        .collect();
    let mut covered = [0usize; 4];
    let mut mean = [0.0; 4];
    let mut mean_se = [0.0; 4];
    for f in &fits {
        assert!(f.converged, "{}", f.termination);
        assert_eq!(f.stop, estim_core::noise::ml::FitStop::Converged);
        let se = f.standard_errors.expect("information positive definite");
        for i in 0..4 {
            covered[i] += usize::from((f.theta[i] - TRUTH[i]).abs() <= 2.0 * se[i]);
            mean[i] += f.theta[i] / datasets as f64;
            mean_se[i] += se[i] / datasets as f64;
        }
    }
    let mut checks = Vec::new();
    for i in 0..4 {
        let spread = (fits
            .iter()
            .map(|f| (f.theta[i] - mean[i]).powi(2))
            .sum::<f64>()
            / (datasets - 1) as f64)
            .sqrt();
        let coverage = covered[i] as f64 / datasets as f64;
        println!(
            "theta[{i}] truth {} mean {:.4} spread {spread:.4e} mean SE {:.4e} (ratio {:.3}) coverage {:.1} %",
            TRUTH[i], mean[i], mean_se[i], mean_se[i] / spread, 100.0 * coverage
        );
        checks.push((i, coverage, mean_se[i] / spread));
    }
    for (i, coverage, ratio) in checks {
        assert!(coverage >= 0.90, "theta[{i}] coverage {coverage}");
        assert!((ratio - 1.0).abs() <= 0.2, "theta[{i}] SE / spread {ratio}");
    }
}

/// The size of the likelihood-ratio test of M = 0 (c = 0) at 5 %, and its power under
/// the oracle's M (c = 0.6), 200 fixes per dataset. r is known (fixed at its true value in both fits): with r
/// free the independent noise can be traded for the shared one (r -> 0 at
/// |c| = sqrt(r / (dt^2 window q))), an optimum on the boundary where Wilks' theorem does
/// not hold; here the rest of the model (q_x, q_y) is fitted and regular.
#[test]
fn likelihood_ratio_test_of_m_zero_has_its_size() {
    let setup = Setup {
        updates: 200,
        ..Setup::default()
    };
    let rejection_rate = |c: f64, runs: u64, seed0: u64| -> f64 {
        let truth = [TRUTH[0], TRUTH[1], TRUTH[2], c];
        let known_r = bounds().fix(2, TRUTH[2]).expect("fix r");
        // Independent seeded datasets, on every core.
        let rejected: usize = (seed0..seed0 + runs)
            .into_par_iter()
            .map(|seed| {
                let data = Dataset::simulate(setup, truth, seed);
                let full = fit(&data, &known_r, [1.0, 1.0, TRUTH[2], 0.1]);
                let restricted = fit(
                    &data,
                    &known_r.fix(3, 0.0).expect("fix c"),
                    [1.0, 1.0, TRUTH[2], 0.0],
                );
                assert!(
                    full.converged && restricted.converged,
                    "seed {seed}: {} / {}",
                    full.termination,
                    restricted.termination
                );
                let test = likelihood_ratio_test(full.log_likelihood, restricted.log_likelihood, 1)
                    .expect("test");
                usize::from(test.p_value < 0.05)
            })
            .sum();
        rejected as f64 / runs as f64
    };
    let size = rejection_rate(0.0, 1000, 50_000);
    let power = rejection_rate(TRUTH[3], 100, 60_000);
    println!(
        "LR test of M = 0 at 5 %: size {:.1} % over 1000 runs; power {:.1} % at c = {} over 100 runs",
        100.0 * size,
        100.0 * power,
        TRUTH[3]
    );
    assert!((0.03..=0.07).contains(&size), "size {size}");
    assert!(power > 0.5, "power {power}");
}
