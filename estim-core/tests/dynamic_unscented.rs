//! `DynUnscentedKalmanFilter` (sizes known at run time) against the static
//! `UnscentedKalmanFilter` on the same problems: every predict and update (plain and
//! correlated, M from a valid joint covariance), its report (innovation, P_yy, gain,
//! NIS, log-likelihood), the series filter and the filtered-and-smoothed pass equal the
//! static runner's (`step`, `smooth_batch`) to 1e-12 relative, with Van der Merwe's
//! weights (alpha = 1 and alpha = 0.3, whose centre covariance weight is negative) and
//! Julier's kappa = 3 - n (the centre-point-modified form), on a turning vehicle whose
//! heading wraps through +/- pi, seen in range and bearing, with residual and mean hooks
//! for both angles; Saerkkae's URTS over the filtered estimates (`rts_smooth`) equals
//! the recorded backward pass; errors leave the filter unchanged.
//!
//! Problems are seeded (ChaCha8); the static runner is the independent reference (its
//! own code, const-generic sizes, the shared runner core and recorder smoother).

use std::f64::consts::{PI, TAU};

use estim_core::dynamic::{
    DynSigmaPointMeasurement, DynSigmaPointProcess, DynSigmaPoints, DynUnscentedKalmanFilter,
    MeasurementSeries,
};
use estim_core::nalgebra::{DMatrix, DVector, SMatrix, SVector};
use estim_core::sigma_point::{SigmaPoints, UnscentedTransform};
use estim_core::{
    Error, Fixed, Result, SigmaPointMeasurement, SigmaPointProcess, StateAndCovariance,
    UnscentedKalmanFilter, Zero,
};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

const N: usize = 4;
const M: usize = 2;
const DT: f64 = 0.5;
const TURN_RATE: f64 = 0.3;
const LANDMARK: [f64; 2] = [10.0, -5.0];
const TOL: f64 = 1e-12;

fn wrap(a: f64) -> f64 {
    (a + PI).rem_euclid(TAU) - PI
}

/// Constant turn: x, y, heading (wrapped), speed.
fn turn(x: &[f64], out: &mut [f64]) {
    out[0] = x[0] + DT * x[3] * x[2].cos();
    out[1] = x[1] + DT * x[3] * x[2].sin();
    out[2] = wrap(x[2] + DT * TURN_RATE);
    out[3] = x[3];
}

/// Range and bearing to the landmark.
fn range_bearing(x: &[f64], out: &mut [f64]) {
    let (dx, dy) = (x[0] - LANDMARK[0], x[1] - LANDMARK[1]);
    out[0] = dx.hypot(dy);
    out[1] = dy.atan2(dx);
}

/// a - b with entry `angle` wrapped.
fn residual(a: &[f64], b: &[f64], angle: usize, out: &mut [f64]) {
    for i in 0..a.len() {
        out[i] = a[i] - b[i];
    }
    out[angle] = wrap(out[angle]);
}

/// The weighted mean with entry `angle` as centre + sum w wrap(y - centre), wrapped.
fn tangent_mean<'a>(
    centre: &[f64],
    points: impl Iterator<Item = (f64, &'a [f64])>,
    angle: usize,
    out: &mut [f64],
) {
    let mut d = vec![0.0; centre.len()];
    for (w, y) in points {
        for i in 0..y.len() {
            let e = y[i] - centre[i];
            d[i] += w * if i == angle { wrap(e) } else { e };
        }
    }
    for i in 0..centre.len() {
        out[i] = centre[i] + d[i];
    }
    out[angle] = wrap(out[angle]);
}

// The static models.
#[derive(Clone)]
struct Turn {
    q: SMatrix<f64, N, N>,
}

impl SigmaPointProcess<f64, N> for Turn {
    type Input = ();
    fn propagate(&self, x: &SVector<f64, N>, _: &(), _: f64) -> Result<SVector<f64, N>> {
        let mut out = SVector::<f64, N>::zeros();
        turn(x.as_slice(), out.as_mut_slice());
        Ok(out)
    }
    fn process_noise(&self, _: &SVector<f64, N>, _: &(), _: f64) -> Result<SMatrix<f64, N, N>> {
        Ok(self.q)
    }
    fn residual(&self, a: &SVector<f64, N>, b: &SVector<f64, N>) -> SVector<f64, N> {
        let mut out = SVector::<f64, N>::zeros();
        residual(a.as_slice(), b.as_slice(), 2, out.as_mut_slice());
        out
    }
    fn mean(&self, points: &SigmaPoints<'_, f64, N>) -> Result<SVector<f64, N>> {
        let mut out = SVector::<f64, N>::zeros();
        let iter = points.iter().map(|(w, y)| (w, y.as_slice()));
        tangent_mean(points.centre().as_slice(), iter, 2, out.as_mut_slice());
        Ok(out)
    }
}

struct RangeBearing {
    r: SMatrix<f64, M, M>,
}

impl SigmaPointMeasurement<f64, N, M> for RangeBearing {
    fn predict(&self, x: &SVector<f64, N>) -> Result<SVector<f64, M>> {
        let mut out = SVector::<f64, M>::zeros();
        range_bearing(x.as_slice(), out.as_mut_slice());
        Ok(out)
    }
    fn noise_covariance(&self, _: &SVector<f64, N>) -> Result<SMatrix<f64, M, M>> {
        Ok(self.r)
    }
    fn residual(&self, a: &SVector<f64, M>, b: &SVector<f64, M>) -> SVector<f64, M> {
        let mut out = SVector::<f64, M>::zeros();
        residual(a.as_slice(), b.as_slice(), 1, out.as_mut_slice());
        out
    }
    fn mean(&self, points: &SigmaPoints<'_, f64, M>) -> Result<SVector<f64, M>> {
        let mut out = SVector::<f64, M>::zeros();
        let iter = points.iter().map(|(w, y)| (w, y.as_slice()));
        tangent_mean(points.centre().as_slice(), iter, 1, out.as_mut_slice());
        Ok(out)
    }
}

// The run-time-sized models.
struct DynTurn;

impl DynSigmaPointProcess for DynTurn {
    fn propagate(&self, x: &DVector<f64>, _: f64, out: &mut DVector<f64>) -> Result<()> {
        turn(x.as_slice(), out.as_mut_slice());
        Ok(())
    }
    fn residual(&self, a: &DVector<f64>, b: &DVector<f64>, out: &mut DVector<f64>) -> Result<()> {
        residual(a.as_slice(), b.as_slice(), 2, out.as_mut_slice());
        Ok(())
    }
    fn mean(&self, points: &DynSigmaPoints<'_>, out: &mut DVector<f64>) -> Result<()> {
        dyn_mean(points, 2, out);
        Ok(())
    }
}

struct DynRangeBearing;

impl DynSigmaPointMeasurement for DynRangeBearing {
    fn predict(&self, x: &DVector<f64>, out: &mut DVector<f64>) -> Result<()> {
        range_bearing(x.as_slice(), out.as_mut_slice());
        Ok(())
    }
    fn residual(&self, a: &DVector<f64>, b: &DVector<f64>, out: &mut DVector<f64>) -> Result<()> {
        residual(a.as_slice(), b.as_slice(), 1, out.as_mut_slice());
        Ok(())
    }
    fn mean(&self, points: &DynSigmaPoints<'_>, out: &mut DVector<f64>) -> Result<()> {
        dyn_mean(points, 1, out);
        Ok(())
    }
}

fn dyn_mean(points: &DynSigmaPoints<'_>, angle: usize, out: &mut DVector<f64>) {
    let images = points.points();
    let dim = images.nrows();
    let centre = images.column(0);
    let iter = (0..points.len()).map(|i| {
        let start = i * dim;
        (
            points.mean_weight(i),
            &images.as_slice()[start..start + dim],
        )
    });
    tangent_mean(centre.as_slice(), iter, angle, out.as_mut_slice());
}

/// A seeded problem: joint noise [[Q, M], [M', R]] = L L' (M a valid
/// cross-covariance), x0, P0 and a simulated series with every `gap`-th measurement
/// missing (0: none missing).
struct Problem {
    q: DMatrix<f64>,
    r: DMatrix<f64>,
    m: DMatrix<f64>,
    x0: DVector<f64>,
    p0: DMatrix<f64>,
    ys: Vec<Option<DVector<f64>>>,
}

fn problem(steps: usize, gap: usize, seed: u64) -> Problem {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut u = |scale: f64| rng.random_range(-scale..scale);
    let l = DMatrix::from_fn(N + M, N + M, |i, j| if j < i { u(0.05) } else { 0.0 })
        + DMatrix::from_diagonal(&DVector::from_vec(vec![0.1, 0.1, 0.03, 0.05, 0.2, 0.02]));
    let joint = &l * l.transpose();
    let q = joint.view((0, 0), (N, N)).into_owned();
    let m = joint.view((0, N), (N, M)).into_owned();
    let r = joint.view((N, N), (M, M)).into_owned();
    let x0 = DVector::from_vec(vec![0.0, 0.0, 2.5, 2.0]);
    let p0 = DMatrix::from_diagonal(&DVector::from_vec(vec![0.5, 0.5, 0.05, 0.1]));
    let mut truth = x0.clone();
    let mut next = DVector::zeros(N);
    let mut y = DVector::zeros(M);
    let mut ys = Vec::with_capacity(steps);
    for k in 0..steps {
        let e = DVector::from_fn(N + M, |_, _| u(1.7));
        let noise = &l * e;
        turn(truth.as_slice(), next.as_mut_slice());
        truth = &next + noise.rows(0, N);
        truth[2] = wrap(truth[2]);
        range_bearing(truth.as_slice(), y.as_mut_slice());
        let mut z = &y + noise.rows(N, M);
        z[1] = wrap(z[1]);
        ys.push(if gap > 0 && k % gap == gap - 1 {
            None
        } else {
            Some(z)
        });
    }
    Problem {
        q,
        r,
        m,
        x0,
        p0,
        ys,
    }
}

fn s<const R: usize, const C: usize>(a: &DMatrix<f64>) -> SMatrix<f64, R, C> {
    SMatrix::from_column_slice(a.as_slice())
}

fn transforms() -> [(&'static str, UnscentedTransform); 3] {
    [
        (
            "merwe alpha 1",
            UnscentedTransform::new(1.0, 2.0, 0.0).unwrap(),
        ),
        (
            "merwe alpha 0.3",
            UnscentedTransform::new(0.3, 2.0, 0.0).unwrap(),
        ),
        (
            "julier 3 - n",
            UnscentedTransform::julier(3.0 - N as f64).unwrap(),
        ),
    ]
}

fn filters(
    p: &Problem,
    transform: UnscentedTransform,
) -> (
    DynUnscentedKalmanFilter,
    UnscentedKalmanFilter<f64, Turn, N>,
) {
    let dynamic = DynUnscentedKalmanFilter::new(
        transform,
        p.q.clone(),
        p.r.clone(),
        p.x0.clone(),
        p.p0.clone(),
    )
    .unwrap();
    let initial =
        StateAndCovariance::new(SVector::from_column_slice(p.x0.as_slice()), s(&p.p0)).unwrap();
    let reference = UnscentedKalmanFilter::new(Turn { q: s(&p.q) }, transform, initial);
    (dynamic, reference)
}

/// max |a - b| / max(max |b|, 1e-300).
fn relative(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(0.0f64, |s, v| s.max(v.abs())).max(1e-300);
    a.iter()
        .zip(b)
        .fold(0.0f64, |e, (x, y)| e.max((x - y).abs()))
        / scale
}

/// Step by step, every predict and update (plain or correlated) and its report.
fn step_by_step(transform: UnscentedTransform, correlated: bool, seed: u64) -> f64 {
    let p = problem(80, 5, seed);
    let (mut dynamic, mut reference) = filters(&p, transform);
    let model = RangeBearing { r: s(&p.r) };
    let cross = Fixed(s::<N, M>(&p.m));
    let mut worst = 0.0f64;
    let mut wrapped = false;
    for y in &p.ys {
        dynamic.predict(&DynTurn, DT).unwrap();
        reference.predict(&(), DT).unwrap();
        if let Some(y) = y {
            let ys = SVector::<f64, M>::from_column_slice(y.as_slice());
            let (ours, theirs) = if correlated {
                (
                    dynamic
                        .update_correlated(&DynRangeBearing, y, &p.m)
                        .unwrap(),
                    reference.update(&model, &ys, &cross).unwrap(),
                )
            } else {
                (
                    dynamic.update(&DynRangeBearing, y).unwrap(),
                    reference.update(&model, &ys, &Zero).unwrap(),
                )
            };
            assert!(ours.accepted && theirs.is_accepted());
            let gain = theirs.gain.expect("an accepted update has a gain");
            worst = worst
                // The NIS inherits the innovation's cancellation (above): its error is
                // taken against max(NIS, m), m its expected value.
                .max((ours.nis - theirs.nis).abs() / theirs.nis.max(M as f64))
                // ln N = -(m ln 2 pi + ln det S + NIS) / 2 is a sum of terms of order
                // one that can cancel to 0.01: its error is taken against max(|ln N|, 1).
                .max(
                    (ours.log_likelihood - theirs.log_likelihood).abs()
                        / theirs.log_likelihood.abs().max(1.0),
                )
                // The innovation y - y_hat is compared through y_hat = y - innovation:
                // an innovation of 1e-3 against a range of 10 keeps only the digits
                // left after that cancellation (1e-12 of it is 1e-15 of y).
                .max(relative(
                    (y - dynamic.innovation()).as_slice(),
                    (ys - theirs.innovation).as_slice(),
                ))
                .max(relative(
                    dynamic.innovation_covariance().as_slice(),
                    theirs.innovation_covariance.as_slice(),
                ))
                .max(relative(dynamic.gain().as_slice(), gain.as_slice()));
        }
        let estimate = reference.estimate();
        wrapped |= estimate.state()[2].abs() > 3.0;
        worst = worst
            .max(relative(
                dynamic.state().as_slice(),
                estimate.state().as_slice(),
            ))
            .max(relative(
                dynamic.covariance().as_slice(),
                estimate.covariance().as_slice(),
            ));
    }
    assert!(wrapped, "the heading never came near +/- pi");
    worst
}

#[test]
fn steps_equal_the_static_runner() {
    for (name, transform) in transforms() {
        for correlated in [false, true] {
            let worst = step_by_step(transform, correlated, 11);
            println!("{name}, correlated {correlated}: {worst:.2e}");
            assert!(worst < TOL, "{name}, correlated {correlated}: {worst:e}");
        }
    }
}

fn series(p: &Problem) -> Vec<f64> {
    p.ys.iter()
        .flat_map(|y| match y {
            Some(y) => y.iter().copied().collect::<Vec<_>>(),
            None => vec![f64::NAN; M],
        })
        .collect()
}

/// filter_and_smooth against the static smooth_batch (filtered and smoothed, x_0
/// included), with M = 0 and missing measurements, and with a correlated M at every
/// step.
#[test]
fn filter_and_smooth_equals_smooth_batch() {
    for (name, transform) in transforms() {
        for correlated in [false, true] {
            let p = problem(60, if correlated { 0 } else { 4 }, 12);
            let (dynamic, reference) = filters(&p, transform);
            let values = series(&p);
            let ys = MeasurementSeries::new(&values, M).unwrap();
            let cross = correlated.then_some(&p.m);
            let ours = dynamic
                .filter_and_smooth(&DynTurn, &DynRangeBearing, &[DT], &ys, cross)
                .unwrap();
            let steps: Vec<_> =
                p.ys.iter()
                    .map(|y| {
                        (
                            (),
                            DT,
                            y.as_ref()
                                .map(|y| SVector::<f64, M>::from_column_slice(y.as_slice())),
                        )
                    })
                    .collect();
            let model = RangeBearing { r: s(&p.r) };
            let theirs = if correlated {
                reference.smooth_batch(&steps, &model, &Fixed(s::<N, M>(&p.m)))
            } else {
                reference.smooth_batch(&steps, &model, &Zero)
            }
            .unwrap();
            let mut worst = relative(
                ours.smoothed_initial_state.as_slice(),
                theirs.initial.state().as_slice(),
            )
            .max(relative(
                ours.smoothed_initial_covariance.as_slice(),
                theirs.initial.covariance().as_slice(),
            ))
            .max(relative(
                &[ours.filtered.log_likelihood],
                &[theirs.log_likelihood],
            ));
            for k in 0..p.ys.len() {
                for (trajectory, estimates) in [
                    (&ours.smoothed, &theirs.estimates),
                    (&ours.filtered.estimates, &theirs.filtered),
                ] {
                    worst = worst
                        .max(relative(
                            trajectory.state(k).as_slice(),
                            estimates[k].state().as_slice(),
                        ))
                        .max(relative(
                            trajectory.covariance(k).into_owned().as_slice(),
                            estimates[k].covariance().as_slice(),
                        ));
                }
            }
            println!("{name}, correlated {correlated}: {worst:.2e}");
            assert!(worst < TOL, "{name}, correlated {correlated}: {worst:e}");
        }
    }
}

/// Saerkkae's URTS over the filtered estimates (`rts_smooth`, filterpy's
/// `rts_smoother`) equals the recorded backward pass of `filter_and_smooth` when every
/// step is measured and M = 0 (two codings of one smoother).
#[test]
fn rts_smooth_equals_the_recorded_pass() {
    let p = problem(50, 0, 13);
    let transform = UnscentedTransform::new(0.5, 2.0, 0.0).unwrap();
    let (dynamic, _) = filters(&p, transform);
    let values = series(&p);
    let ys = MeasurementSeries::new(&values, M).unwrap();
    let both = dynamic
        .filter_and_smooth(&DynTurn, &DynRangeBearing, &[DT], &ys, None)
        .unwrap();
    let (mut states, mut covariances) = both.filtered.estimates.clone().into_parts();
    let mut smoother = dynamic.clone();
    let gains = smoother
        .rts_smooth(&DynTurn, &mut states, &mut covariances, &[DT], None)
        .unwrap();
    assert_eq!(gains.len(), 50 * N * N);
    let worst = relative(&states, both.smoothed.states())
        .max(relative(&covariances, both.smoothed.covariances()));
    println!("rts_smooth vs recorded: {worst:.2e}");
    assert!(worst < TOL, "{worst:e}");
    assert_eq!(smoother.state(), dynamic.state());
}

/// Errors: a measurement of the wrong length, a P0 of the wrong shape, an invalid M,
/// and a model that fails leave the filter unchanged.
#[test]
fn errors_leave_the_filter_unchanged() {
    let p = problem(3, 0, 14);
    let (mut ukf, _) = filters(&p, UnscentedTransform::default());
    assert!(matches!(
        DynUnscentedKalmanFilter::new(
            UnscentedTransform::default(),
            p.q.clone(),
            p.r.clone(),
            p.x0.clone(),
            DMatrix::identity(3, 3),
        ),
        Err(Error::Dimension { .. })
    ));
    ukf.predict(&DynTurn, DT).unwrap();
    let before = ukf.clone();
    assert!(matches!(
        ukf.update(&DynRangeBearing, &DVector::zeros(3)),
        Err(Error::Dimension { .. })
    ));
    let failing = |_: &DVector<f64>, _: &mut DVector<f64>| -> Result<()> {
        Err(Error::Model("h failed".into()))
    };
    assert!(matches!(
        ukf.update(&failing, &DVector::zeros(M)),
        Err(Error::Model(_))
    ));
    let invalid = &p.m * 100.0;
    assert!(matches!(
        ukf.update_correlated(&DynRangeBearing, &DVector::zeros(M), &invalid),
        Err(Error::InvalidJointCovariance { .. })
    ));
    let failing_f = |_: &DVector<f64>, _: f64, _: &mut DVector<f64>| -> Result<()> {
        Err(Error::Model("f failed".into()))
    };
    assert!(matches!(ukf.predict(&failing_f, DT), Err(Error::Model(_))));
    assert!(matches!(
        ukf.predict(&DynTurn, 0.0),
        Err(Error::InvalidParameter { .. })
    ));
    assert_eq!(ukf.state(), before.state());
    assert_eq!(ukf.covariance(), before.covariance());
    assert_eq!(
        ukf.accumulated_process_noise(),
        before.accumulated_process_noise()
    );
}
