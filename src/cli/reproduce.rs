//! `estim reproduce`.

use estim_core::nalgebra::{Matrix1, Matrix1x2, Matrix2, Matrix2x1, Vector1, Vector2};
use estim_core::{correlated_update, CovarianceUpdate, StateAndCovariance};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};

/// Arguments of `estim reproduce`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Seed of the simulated mission.
    #[arg(long, default_value_t = 7)]
    seed: u64,
}

/// Placeholder main job until the INS/DVL pipeline lands: a seeded constant-velocity
/// tracker whose position measurement shares noise with the process, filtered with
/// M neglected and with the true M; prints the average NEES of each (expected 2).
pub fn run(args: Args) -> anyhow::Result<()> {
    let dt = 1.0;
    let f = Matrix2::new(1.0, dt, 0.0, 1.0);
    let h = Matrix1x2::new(1.0, 0.0);
    // w ~ N(0, q) on velocity; v = c * w_prev + independent part.
    let q: f64 = 0.04;
    let c = 2.0;
    let r_ind: f64 = 0.01;
    let g = Matrix2x1::new(0.5 * dt, 1.0);
    let qd = g * g.transpose() * q;
    let r = Matrix1::new(c * c * q + r_ind);
    let m = g * (c * q); // Cov(G w_{k-1}, v_k)
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(args.seed);
    let steps = 2000;
    let mut truth = Vector2::new(0.0, 1.0);
    let p0 = Matrix2::identity();
    let mut aware = StateAndCovariance::new(truth, p0)?;
    let mut neglect = aware.clone();
    let (mut nees_aware, mut nees_neglect) = (0.0, 0.0);
    for _ in 0..steps {
        let w: f64 = StandardNormal.sample(&mut rng);
        let w = w * q.sqrt();
        let e: f64 = StandardNormal.sample(&mut rng);
        truth = f * truth + g * w;
        let y = h * truth + Vector1::new(c * w + r_ind.sqrt() * e);
        for (est, mk, nees) in [
            (&mut aware, m, &mut nees_aware),
            (&mut neglect, Matrix2x1::zeros(), &mut nees_neglect),
        ] {
            let prior = StateAndCovariance::new(
                f * est.state(),
                f * est.covariance() * f.transpose() + qd,
            )?;
            let innovation = y - h * prior.state();
            let out = correlated_update(
                &prior,
                &innovation,
                &h,
                &r,
                &mk,
                CovarianceUpdate::JosephLike,
            )?;
            let err = truth - out.posterior.state();
            let inv = out
                .posterior
                .covariance()
                .try_inverse()
                .ok_or_else(|| anyhow::anyhow!("singular P"))?;
            *nees += (err.transpose() * inv * err)[0] / steps as f64;
            *est = out.posterior;
        }
    }
    println!(
        "linear tracker with correlated noise, {steps} steps, seed {}",
        args.seed
    );
    println!("average NEES (expected 2): M-aware {nees_aware:.3}, M-neglected {nees_neglect:.3}");
    println!("INS/DVL + BeamsNet pipeline: not yet available in this build");
    Ok(())
}
