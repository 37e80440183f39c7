//! The angle hooks of the sigma-point filter (issue 47): a bearing measured near
//! +-pi, where the sigma points' bearings straddle the cut. With the model's
//! `residual` wrapping and its `mean` circular, the filter must give what it gives
//! on the same problem with the angle shifted away from the cut (a quarter turn
//! added to every bearing, computed by rotating the position before atan2), where no
//! wrap occurs and the plain hooks are right. Without the hooks it must be wrong.
//!
//! Only the measured angle is shifted, not the state: rotating the state would
//! change the sigma points themselves (the Cholesky factor of R P R' is not R times
//! that of P), and so the estimate of a nonlinear model beyond round-off.

use std::f64::consts::{FRAC_PI_2, PI};

use estim_core::nalgebra::{Matrix1, Matrix2, Vector1, Vector2};
use estim_core::sigma_point::{SigmaPoints, UnscentedTransform};
use estim_core::{
    Result, SigmaPointMeasurement, SigmaPointProcess, StateAndCovariance, UnscentedKalmanFilter,
};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

fn wrap(a: f64) -> f64 {
    let w = (a + PI).rem_euclid(2.0 * PI) - PI;
    if w == -PI {
        PI
    } else {
        w
    }
}

/// A target that drifts: x_k = x_{k-1} + w, Cov(w) = 0.05 I.
struct Drift;

impl SigmaPointProcess<f64, 2> for Drift {
    type Input = ();
    fn propagate(&self, x: &Vector2<f64>, _: &(), _: f64) -> Result<Vector2<f64>> {
        Ok(*x)
    }
    fn process_noise(&self, _: &Vector2<f64>, _: &(), _: f64) -> Result<Matrix2<f64>> {
        Ok(Matrix2::identity() * 0.05)
    }
}

#[derive(Clone, Copy, PartialEq)]
enum Mean {
    /// The default weighted mean of the bearings.
    Plain,
    /// Y_0 + sum_{i>0} W wrap(Y_i - Y_0), wrapped.
    Tangent,
    /// atan2(sum w sin Y_i, sum w cos Y_i).
    Circular,
}

/// The bearing of the target from the origin, plus `offset` (atan2 of the position
/// rotated by `offset`, so never wrapped by an addition), sigma 0.02 rad.
struct Bearing {
    offset: f64,
    wrap: bool,
    mean: Mean,
}

impl SigmaPointMeasurement<f64, 2, 1> for Bearing {
    fn predict(&self, x: &Vector2<f64>) -> Result<Vector1<f64>> {
        let (s, c) = self.offset.sin_cos();
        Ok(Vector1::new(
            (s * x[0] + c * x[1]).atan2(c * x[0] - s * x[1]),
        ))
    }
    fn noise_covariance(&self, _: &Vector2<f64>) -> Result<Matrix1<f64>> {
        Ok(Matrix1::new(0.02 * 0.02))
    }
    fn residual(&self, a: &Vector1<f64>, b: &Vector1<f64>) -> Vector1<f64> {
        let d = a[0] - b[0];
        Vector1::new(if self.wrap { wrap(d) } else { d })
    }
    fn mean(&self, points: &SigmaPoints<'_, f64, 1>) -> Result<Vector1<f64>> {
        let centre = points.centre()[0];
        Ok(Vector1::new(match self.mean {
            Mean::Plain => points.weighted_mean()[0],
            Mean::Tangent => wrap(
                centre
                    + points
                        .iter()
                        .map(|(w, y)| w * wrap(y[0] - centre))
                        .sum::<f64>(),
            ),
            Mean::Circular => {
                let (s, c) = points.iter().fold((0.0, 0.0), |(s, c), (w, y)| {
                    (s + w * y[0].sin(), c + w * y[0].cos())
                });
                s.atan2(c)
            }
        }))
    }
}

/// Seeded bearings of a target at (-10, 0.1) drifting across the negative x axis,
/// each near +-pi.
fn bearings() -> Vec<f64> {
    let mut rng = ChaCha8Rng::seed_from_u64(47);
    let mut x = Vector2::<f64>::new(-10.0, 0.1);
    (0..12)
        .map(|k| {
            x[1] += if k % 2 == 0 { -0.15 } else { 0.1 };
            let noise: f64 = rng.sample(StandardNormal);
            wrap(x[1].atan2(x[0]) + 0.02 * noise)
        })
        .collect()
}

/// Predict and update with every bearing (shifted by the model's offset); the
/// estimates and NIS after each step.
fn run(model: &Bearing) -> Vec<(StateAndCovariance<f64, 2>, f64)> {
    let initial =
        StateAndCovariance::new(Vector2::new(-9.0, 0.0), Matrix2::new(1.0, 0.0, 0.0, 4.0)).unwrap();
    let mut ukf = UnscentedKalmanFilter::new(Drift, UnscentedTransform::default(), initial);
    bearings()
        .into_iter()
        .map(|y| {
            let y = Vector1::new(wrap(y + model.offset));
            let report = ukf
                .step_uncorrelated(&(), 1.0, model, Some(&y))
                .unwrap()
                .unwrap();
            (ukf.estimate().clone(), report.nis)
        })
        .collect()
}

/// max |a - b| over states, covariances and NIS.
fn gap(a: &[(StateAndCovariance<f64, 2>, f64)], b: &[(StateAndCovariance<f64, 2>, f64)]) -> f64 {
    a.iter()
        .zip(b)
        .flat_map(|((ea, na), (eb, nb))| {
            let states = ea.state().iter().zip(eb.state().iter());
            let covariances = ea.covariance().iter().zip(eb.covariance().iter());
            states
                .chain(covariances)
                .chain(std::iter::once((na, nb)))
                .map(|(x, y)| (x - y).abs())
        })
        .fold(0.0, f64::max)
}

#[test]
fn wrapped_bearing_across_the_cut_equals_the_shifted_problem() {
    // The sigma points' bearings do straddle the cut: some near +pi, some near -pi.
    let plain_here = Bearing {
        offset: 0.0,
        wrap: false,
        mean: Mean::Plain,
    };
    let bearings_of_points = [-1.0, 1.0].map(|sign| {
        plain_here
            .predict(&Vector2::new(-9.0, sign * 2.0f64.sqrt() * 2.0))
            .unwrap()[0]
    });
    assert!(bearings_of_points[0] < -2.5 && bearings_of_points[1] > 2.5);

    for mean in [Mean::Tangent, Mean::Circular] {
        let wrapped = run(&Bearing {
            offset: 0.0,
            wrap: true,
            mean,
        });
        // A quarter turn away from the cut no wrap occurs: the plain residual is right,
        // and the mean is the same function of the points.
        let reference_mean = if mean == Mean::Tangent {
            Mean::Plain
        } else {
            mean
        };
        let shifted = run(&Bearing {
            offset: FRAC_PI_2,
            wrap: false,
            mean: reference_mean,
        });
        let g = gap(&wrapped, &shifted);
        println!(
            "wrapped, mean {}: gap to the shifted problem {g:.1e}",
            mean as u8
        );
        assert!(g < 1e-12, "gap {g:e}");
    }

    // Without the hooks the same bearings ruin the estimate.
    let unwrapped = run(&plain_here);
    let reference = run(&Bearing {
        offset: FRAC_PI_2,
        wrap: false,
        mean: Mean::Plain,
    });
    let g = gap(&unwrapped, &reference);
    println!("unwrapped: gap to the shifted problem {g:.1}");
    assert!(g > 1.0, "gap {g}");
}
