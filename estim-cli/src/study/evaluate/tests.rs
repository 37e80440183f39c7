use super::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// A simulated Gauss-Markov process (exact discretisation) plus white noise: the
/// fit recovers sigma and tau within their sampling error, for several seeds; white
/// noise alone gives no Gauss-Markov part.
#[test]
fn gauss_markov_fit_recovers_a_simulated_process() {
    let (sigma, tau, white, dt) = (0.03, 8.0, 0.01, 1.0);
    let phi = f64::exp(-dt / tau);
    let n = 200_000;
    for seed in [1u64, 2, 3] {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut normal = || -> f64 { StandardNormal.sample(&mut rng) };
        let mut b = sigma * normal();
        let mut series = Vec::with_capacity(n);
        for _ in 0..n {
            series.push(b + white * normal());
            b = phi * b + sigma * (1.0 - phi * phi).sqrt() * normal();
        }
        let lag = |k: usize| -> f64 {
            (0..n - k).map(|i| series[i] * series[i + k]).sum::<f64>() / (n - k) as f64
        };
        let c = [lag(0), lag(1), lag(2)];
        let (s, t) = gauss_markov_from_autocovariance(c, dt).expect("a Gauss-Markov part");
        assert!((s - sigma).abs() < 0.1 * sigma, "seed {seed}: sigma {s}");
        assert!((t - tau).abs() < 0.2 * tau, "seed {seed}: tau {t}");
        let w = (c[0] - s * s).sqrt();
        assert!((w - white).abs() < 0.3 * white, "seed {seed}: white {w}");
        // No decaying correlation (white: c_1 = 0; growing or sign-changing): none.
        assert!(gauss_markov_from_autocovariance([1.0, 0.0, 0.0], dt).is_none());
        assert!(gauss_markov_from_autocovariance([1.0, 0.1, 0.2], dt).is_none());
        assert!(gauss_markov_from_autocovariance([1.0, 0.1, -0.01], dt).is_none());
    }
}

#[test]
fn test_trajectories_and_repeats_are_refused_for_fitting() {
    for bad in [&[1, 4][..], &[13], &[2, 3, 2], &[]] {
        let e = check_fit_trajectories(bad).unwrap_err().to_string();
        assert!(e.contains("--fit-trajectories"), "{e}");
    }
    assert!(check_fit_trajectories(&AKIT_TRAINING_TRAJECTORIES).is_ok());
    assert!(AKIT_TRAINING_TRAJECTORIES
        .iter()
        .all(|t| !AKIT_TEST_TRAJECTORIES.contains(t)));
}
