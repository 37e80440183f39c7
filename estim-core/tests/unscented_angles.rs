//! The angle hooks of the sigma-point filter (issue 47): a bearing measured near
//! +-pi, where the sigma points' bearings straddle the cut. With the model's
//! `residual` wrapping and its `mean` circular, the filter must give what it gives
//! on the same problem with the angle shifted away from the cut (a quarter turn
//! added to every bearing, computed by rotating the position before atan2), where no
//! wrap occurs and the plain hooks are right. Without the hooks it must be wrong.
//! The same for a heading in the state (the process model's hooks) turning through
//! +-pi, against the turn shifted a quarter turn back.
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

/// A heading (rad) and its rate, heading wrapped into (-pi, pi]; with `hooks` the
/// heading's residual is wrapped and its mean is Y_0 + sum W wrap(Y_i - Y_0).
struct Turning {
    hooks: bool,
}

impl SigmaPointProcess<f64, 2> for Turning {
    type Input = ();
    fn propagate(&self, x: &Vector2<f64>, _: &(), dt: f64) -> Result<Vector2<f64>> {
        Ok(Vector2::new(wrap(x[0] + dt * x[1]), x[1]))
    }
    fn process_noise(&self, _: &Vector2<f64>, _: &(), dt: f64) -> Result<Matrix2<f64>> {
        Ok(Matrix2::new(dt.powi(3) / 3.0, dt * dt / 2.0, dt * dt / 2.0, dt) * 1e-3)
    }
    fn residual(&self, a: &Vector2<f64>, b: &Vector2<f64>) -> Vector2<f64> {
        let d = a - b;
        if self.hooks {
            Vector2::new(wrap(d[0]), d[1])
        } else {
            d
        }
    }
    fn mean(&self, points: &SigmaPoints<'_, f64, 2>) -> Result<Vector2<f64>> {
        let plain = points.weighted_mean();
        if !self.hooks {
            return Ok(plain);
        }
        let centre = points.centre()[0];
        let heading: f64 = points.iter().map(|(w, y)| w * wrap(y[0] - centre)).sum();
        Ok(Vector2::new(wrap(centre + heading), plain[1]))
    }
}

/// The heading measured directly, sigma 0.05 rad.
struct Compass {
    hooks: bool,
}

impl SigmaPointMeasurement<f64, 2, 1> for Compass {
    fn predict(&self, x: &Vector2<f64>) -> Result<Vector1<f64>> {
        Ok(Vector1::new(x[0]))
    }
    fn noise_covariance(&self, _: &Vector2<f64>) -> Result<Matrix1<f64>> {
        Ok(Matrix1::new(0.05 * 0.05))
    }
    fn residual(&self, a: &Vector1<f64>, b: &Vector1<f64>) -> Vector1<f64> {
        let d = a[0] - b[0];
        Vector1::new(if self.hooks { wrap(d) } else { d })
    }
    fn mean(&self, points: &SigmaPoints<'_, f64, 1>) -> Result<Vector1<f64>> {
        if !self.hooks {
            return Ok(points.weighted_mean());
        }
        let centre = points.centre()[0];
        let d: f64 = points.iter().map(|(w, y)| w * wrap(y[0] - centre)).sum();
        Ok(Vector1::new(wrap(centre + d)))
    }
}

/// A turn through +-pi from heading pi - 0.3 at 0.1 rad/s, all headings plus
/// `shift`; the estimates after each of 12 steps.
fn turn(hooks: bool, shift: f64) -> Vec<StateAndCovariance<f64, 2>> {
    let mut rng = ChaCha8Rng::seed_from_u64(4747);
    let initial = StateAndCovariance::new(
        Vector2::new(wrap(PI - 0.25 + shift), 0.08),
        Matrix2::new(0.04, 0.0, 0.0, 0.01),
    )
    .unwrap();
    let mut ukf =
        UnscentedKalmanFilter::new(Turning { hooks }, UnscentedTransform::default(), initial);
    (1..=12)
        .map(|k| {
            let noise: f64 = rng.sample(StandardNormal);
            let y = Vector1::new(wrap(PI - 0.3 + 0.1 * k as f64 + 0.05 * noise + shift));
            ukf.step_uncorrelated(&(), 1.0, &Compass { hooks }, Some(&y))
                .unwrap();
            ukf.estimate().clone()
        })
        .collect()
}

/// max over the steps of |wrap(heading_a - heading_b - shift)|, |rate_a - rate_b| and
/// the covariances' differences.
fn turn_gap(a: &[StateAndCovariance<f64, 2>], b: &[StateAndCovariance<f64, 2>], shift: f64) -> f64 {
    a.iter()
        .zip(b)
        .map(|(a, b)| {
            let heading = wrap(a.state()[0] + shift - b.state()[0]).abs();
            let rate = (a.state()[1] - b.state()[1]).abs();
            let p = (a.covariance() - b.covariance()).abs().max();
            heading.max(rate).max(p)
        })
        .fold(0.0, f64::max)
}

#[test]
fn wrapped_heading_through_the_cut_equals_the_shifted_problem() {
    let wrapped = turn(true, 0.0);
    // The estimate does cross the cut.
    assert!(wrapped[0].state()[0] > 2.8 && wrapped[11].state()[0] < -1.5);
    let shifted = turn(false, -FRAC_PI_2);
    let g = turn_gap(&wrapped, &shifted, -FRAC_PI_2);
    println!("heading with hooks: gap to the shifted problem {g:.1e}");
    assert!(g < 1e-12, "gap {g:e}");
    let unwrapped = turn(false, 0.0);
    let g = turn_gap(&unwrapped, &shifted, -FRAC_PI_2);
    // Smaller than for the bearing (the measurement pulls the estimate back each
    // step), but far beyond round-off.
    println!("heading without hooks: gap to the shifted problem {g:.3}");
    assert!(g > 1e-2, "gap {g}");
}
