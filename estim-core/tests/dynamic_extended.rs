//! `DynExtendedKalmanFilter` against the static `ExtendedKalmanFilter` on the same
//! nonlinear problem (a planar target with quadratic drag, seen in range and bearing
//! from a station; n = 4, m = 2): every step's estimate, NIS and log-likelihood
//! (`step`), and the filtered and smoothed estimates of one call (`smooth_batch`), with
//! M = 0 and missing measurements and with a correlated M at every step, equal to
//! 1e-12 relative; the models' errors are typed and leave the estimate unchanged.
//!
//! Seeded (ChaCha8), deterministic.

use estim_core::dynamic::{
    DynExtendedKalmanFilter, DynMeasurementModel, DynProcessModel, MeasurementSeries,
};
use estim_core::nalgebra::{DMatrix, DVector, SMatrix, SVector};
use estim_core::{
    Error, ExtendedKalmanFilter, Fixed, MeasurementModel, ProcessModel, Result, StateAndCovariance,
    Zero,
};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

const N: usize = 4;
const M: usize = 2;
const DRAG: f64 = 0.05;
const STATION: [f64; 2] = [-20.0, -5.0];

/// x = [px, py, vx, vy]: p <- p + dt v, v <- v - dt c |v| v.
fn propagate(x: &[f64], dt: f64) -> [f64; N] {
    let speed = x[2].hypot(x[3]);
    [
        x[0] + dt * x[2],
        x[1] + dt * x[3],
        x[2] - dt * DRAG * speed * x[2],
        x[3] - dt * DRAG * speed * x[3],
    ]
}

/// df/dx, row-major.
fn transition(x: &[f64], dt: f64) -> [[f64; N]; N] {
    let speed = x[2].hypot(x[3]);
    // d(|v| v_i)/d v_j = |v| delta_ij + v_i v_j / |v|.
    let d = |i: usize, j: usize| f64::from(u8::from(i == j)) * speed + x[2 + i] * x[2 + j] / speed;
    [
        [1.0, 0.0, dt, 0.0],
        [0.0, 1.0, 0.0, dt],
        [0.0, 0.0, 1.0 - dt * DRAG * d(0, 0), -dt * DRAG * d(0, 1)],
        [0.0, 0.0, -dt * DRAG * d(1, 0), 1.0 - dt * DRAG * d(1, 1)],
    ]
}

/// Range and bearing from the station.
fn observe(x: &[f64]) -> [f64; M] {
    let (dx, dy) = (x[0] - STATION[0], x[1] - STATION[1]);
    [dx.hypot(dy), dy.atan2(dx)]
}

fn observation(x: &[f64]) -> [[f64; N]; M] {
    let (dx, dy) = (x[0] - STATION[0], x[1] - STATION[1]);
    let r2 = dx * dx + dy * dy;
    let r = r2.sqrt();
    [[dx / r, dy / r, 0.0, 0.0], [-dy / r2, dx / r2, 0.0, 0.0]]
}

// The dynamic models: types writing into the filter's buffers.
struct Drag;
impl DynProcessModel for Drag {
    fn propagate(&self, x: &DVector<f64>, dt: f64, out: &mut DVector<f64>) -> Result<()> {
        out.copy_from_slice(&propagate(x.as_slice(), dt));
        Ok(())
    }
    fn jacobian(&self, x: &DVector<f64>, dt: f64, out: &mut DMatrix<f64>) -> Result<()> {
        let f = transition(x.as_slice(), dt);
        for (i, row) in f.iter().enumerate() {
            for (j, v) in row.iter().enumerate() {
                out[(i, j)] = *v;
            }
        }
        Ok(())
    }
}

struct RangeBearing;
impl DynMeasurementModel for RangeBearing {
    fn predict(&self, x: &DVector<f64>, out: &mut DVector<f64>) -> Result<()> {
        out.copy_from_slice(&observe(x.as_slice()));
        Ok(())
    }
    fn jacobian(&self, x: &DVector<f64>, out: &mut DMatrix<f64>) -> Result<()> {
        let h = observation(x.as_slice());
        for (i, row) in h.iter().enumerate() {
            for (j, v) in row.iter().enumerate() {
                out[(i, j)] = *v;
            }
        }
        Ok(())
    }
}

// The static models.
#[derive(Clone)]
struct StaticDrag {
    q: SMatrix<f64, N, N>,
}
impl ProcessModel<f64, N> for StaticDrag {
    type State = SVector<f64, N>;
    type Input = ();
    fn propagate(&self, x: &SVector<f64, N>, _: &(), dt: f64) -> Result<SVector<f64, N>> {
        Ok(SVector::from(propagate(x.as_slice(), dt)))
    }
    fn transition(&self, x: &SVector<f64, N>, _: &(), dt: f64) -> Result<SMatrix<f64, N, N>> {
        let f = transition(x.as_slice(), dt);
        Ok(SMatrix::from_fn(|i, j| f[i][j]))
    }
    fn process_noise(&self, _: &SVector<f64, N>, _: &(), _: f64) -> Result<SMatrix<f64, N, N>> {
        Ok(self.q)
    }
}

struct StaticRangeBearing {
    r: SMatrix<f64, M, M>,
}
impl MeasurementModel<f64, N, M> for StaticRangeBearing {
    type State = SVector<f64, N>;
    fn predict(&self, x: &SVector<f64, N>) -> Result<SVector<f64, M>> {
        Ok(SVector::from(observe(x.as_slice())))
    }
    fn jacobian(&self, x: &SVector<f64, N>) -> Result<SMatrix<f64, M, N>> {
        let h = observation(x.as_slice());
        Ok(SMatrix::from_fn(|i, j| h[i][j]))
    }
    fn noise_covariance(&self, _: &SVector<f64, N>) -> Result<SMatrix<f64, M, M>> {
        Ok(self.r)
    }
}

struct Problem {
    q: DMatrix<f64>,
    r: DMatrix<f64>,
    m: DMatrix<f64>,
    x0: DVector<f64>,
    p0: DMatrix<f64>,
    dts: Vec<f64>,
    ys: Vec<Option<DVector<f64>>>,
}

/// `steps` steps of varying dt, every `missing`-th unmeasured (0: none), simulated with
/// the joint noise [[Q, M], [M', R]] = L L' (valid by construction).
fn problem(seed: u64, steps: usize, missing: usize) -> Problem {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut normal = || -> f64 { StandardNormal.sample(&mut rng) };
    let l = DMatrix::from_fn(N + M, N + M, |i, j| {
        if j > i {
            0.0
        } else if i == j {
            [0.05, 0.05, 0.1, 0.1, 0.3, 0.01][i]
        } else {
            0.02 * ((i * 3 + j) % 5) as f64 - 0.04
        }
    });
    let joint = &l * l.transpose();
    let q = joint.view((0, 0), (N, N)).into_owned();
    let m = joint.view((0, N), (N, M)).into_owned();
    let r = joint.view((N, N), (M, M)).into_owned();
    let x0 = DVector::from_column_slice(&[0.0, 0.0, 3.0, 1.5]);
    let p0 = DMatrix::from_diagonal(&DVector::from_column_slice(&[1.0, 1.0, 0.25, 0.25]));
    let mut x = x0.clone();
    let dts: Vec<f64> = (0..steps).map(|k| 0.5 + 0.1 * (k % 3) as f64).collect();
    let ys = (0..steps)
        .map(|k| {
            let e = &l * DVector::from_fn(N + M, |_, _| normal());
            x = DVector::from_column_slice(&propagate(x.as_slice(), dts[k])) + e.rows(0, N);
            let y = DVector::from_column_slice(&observe(x.as_slice())) + e.rows(N, M);
            (missing == 0 || (k + 1) % missing != 0).then_some(y)
        })
        .collect();
    Problem {
        q,
        r,
        m,
        x0,
        p0,
        dts,
        ys,
    }
}

fn s<const R: usize, const C: usize>(a: &DMatrix<f64>) -> SMatrix<f64, R, C> {
    SMatrix::from_column_slice(a.as_slice())
}

fn filters(
    p: &Problem,
) -> (
    DynExtendedKalmanFilter,
    ExtendedKalmanFilter<f64, StaticDrag, N>,
) {
    let dynamic =
        DynExtendedKalmanFilter::new(p.q.clone(), p.r.clone(), p.x0.clone(), p.p0.clone())
            .expect("valid");
    let initial = StateAndCovariance::new(SVector::from_column_slice(p.x0.as_slice()), s(&p.p0))
        .expect("valid");
    let reference = ExtendedKalmanFilter::new(StaticDrag { q: s(&p.q) }, initial);
    (dynamic, reference)
}

/// max |a - b| / max |b|.
fn relative(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-300);
    a.iter()
        .zip(b)
        .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
        / scale
}

#[test]
fn steps_equal_the_static_filter() {
    for correlated in [false, true] {
        let p = problem(11, 60, if correlated { 0 } else { 5 });
        let (mut dynamic, mut reference) = filters(&p);
        let static_model = StaticRangeBearing { r: s(&p.r) };
        let cross = Fixed(s::<N, M>(&p.m));
        let mut worst: f64 = 0.0;
        for (k, y) in p.ys.iter().enumerate() {
            dynamic.predict(&Drag, p.dts[k]).expect("predicts");
            let ys = y
                .as_ref()
                .map(|y| SVector::<f64, M>::from_column_slice(y.as_slice()));
            let theirs = if correlated {
                reference.step(&(), p.dts[k], &static_model, ys.as_ref(), &cross)
            } else {
                reference.step(&(), p.dts[k], &static_model, ys.as_ref(), &Zero)
            }
            .expect("steps");
            if let Some(y) = y {
                let ours = if correlated {
                    dynamic.update_correlated(&RangeBearing, y, &p.m)
                } else {
                    dynamic.update(&RangeBearing, y)
                }
                .expect("updates");
                let theirs = theirs.expect("a report");
                assert!(ours.accepted);
                worst = worst
                    .max((ours.nis - theirs.nis).abs() / theirs.nis.abs())
                    .max(
                        (ours.log_likelihood - theirs.log_likelihood).abs()
                            / theirs.log_likelihood.abs(),
                    );
            }
            let estimate = reference.estimate();
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
        let ll = (dynamic.log_likelihood() - reference.log_likelihood()).abs()
            / reference.log_likelihood().abs();
        eprintln!("correlated {correlated}: steps {worst:.1e}, log-likelihood {ll:.1e} relative");
        assert!(worst < 1e-12, "{worst:.1e}");
        assert!(ll < 1e-12, "{ll:.1e}");
    }
}

#[test]
fn filter_and_smooth_equals_smooth_batch() {
    for correlated in [false, true] {
        let p = problem(12, 60, if correlated { 0 } else { 4 });
        let (dynamic, reference) = filters(&p);
        let values: Vec<f64> =
            p.ys.iter()
                .flat_map(|y| match y {
                    Some(y) => y.iter().copied().collect::<Vec<_>>(),
                    None => vec![f64::NAN; M],
                })
                .collect();
        let series = MeasurementSeries::new(&values, M).expect("series");
        let cross = correlated.then_some(&p.m);
        let ours = dynamic
            .filter_and_smooth(&Drag, &RangeBearing, &p.dts, &series, cross)
            .expect("smooths");
        let steps: Vec<((), f64, Option<SVector<f64, M>>)> =
            p.ys.iter()
                .zip(&p.dts)
                .map(|(y, &dt)| {
                    (
                        (),
                        dt,
                        y.as_ref()
                            .map(|y| SVector::<f64, M>::from_column_slice(y.as_slice())),
                    )
                })
                .collect();
        let model = StaticRangeBearing { r: s(&p.r) };
        let theirs = if correlated {
            reference.smooth_batch(&steps, &model, &Fixed(s::<N, M>(&p.m)))
        } else {
            reference.smooth_batch(&steps, &model, &Zero)
        }
        .expect("smooths");
        let mut worst = relative(
            ours.smoothed_initial_state.as_slice(),
            theirs.initial.state().as_slice(),
        )
        .max(relative(
            ours.smoothed_initial_covariance.as_slice(),
            theirs.initial.covariance().as_slice(),
        ));
        for k in 0..p.ys.len() {
            for (ours, theirs) in [
                (&ours.smoothed, &theirs.estimates[k]),
                (&ours.filtered.estimates, &theirs.filtered[k]),
            ] {
                worst = worst
                    .max(relative(
                        ours.state(k).as_slice(),
                        theirs.state().as_slice(),
                    ))
                    .max(relative(
                        ours.covariance(k).into_owned().as_slice(),
                        theirs.covariance().as_slice(),
                    ));
            }
        }
        let ll = (ours.filtered.log_likelihood - theirs.log_likelihood).abs()
            / theirs.log_likelihood.abs();
        eprintln!(
            "correlated {correlated}: smoothed and filtered {worst:.1e}, log-likelihood {ll:.1e}"
        );
        assert!(worst < 1e-12, "{worst:.1e}");
        assert!(ll < 1e-12, "{ll:.1e}");
        // The smoother moved the early estimates.
        assert!(
            relative(
                ours.smoothed.state(0).as_slice(),
                ours.filtered.estimates.state(0).as_slice()
            ) > 1e-3
        );
    }
}

#[test]
fn closures_are_models() {
    let p = problem(13, 10, 0);
    let (mut by_type, _) = filters(&p);
    let mut by_closure = by_type.clone();
    let f = |x: &DVector<f64>, dt: f64, out: &mut DVector<f64>| Drag.propagate(x, dt, out);
    let jf = |x: &DVector<f64>, dt: f64, out: &mut DMatrix<f64>| Drag.jacobian(x, dt, out);
    let h = |x: &DVector<f64>, out: &mut DVector<f64>| RangeBearing.predict(x, out);
    let jh = |x: &DVector<f64>, out: &mut DMatrix<f64>| RangeBearing.jacobian(x, out);
    for (k, y) in p.ys.iter().enumerate() {
        by_type.predict(&Drag, p.dts[k]).unwrap();
        by_closure.predict(&(f, jf), p.dts[k]).unwrap();
        let y = y.as_ref().unwrap();
        by_type.update(&RangeBearing, y).unwrap();
        by_closure.update(&(h, jh), y).unwrap();
    }
    assert_eq!(by_type.state(), by_closure.state());
    assert_eq!(by_type.covariance(), by_closure.covariance());
}

#[test]
fn model_errors_are_typed_and_leave_the_estimate() {
    let p = problem(14, 3, 0);
    let (mut ekf, _) = filters(&p);
    let (x, cov) = (ekf.state().clone(), ekf.covariance().clone());
    let resizing = (
        |_: &DVector<f64>, _: f64, out: &mut DVector<f64>| -> Result<()> {
            *out = DVector::zeros(3);
            Ok(())
        },
        |_: &DVector<f64>, _: f64, out: &mut DMatrix<f64>| -> Result<()> {
            out.fill_with_identity();
            Ok(())
        },
    );
    assert!(matches!(
        ekf.predict(&resizing, 0.5),
        Err(Error::Dimension {
            what: "propagated state f(x)",
            expected: 4,
            got: 3
        })
    ));
    let nan_jacobian = (
        |x: &DVector<f64>, dt: f64, out: &mut DVector<f64>| Drag.propagate(x, dt, out),
        |_: &DVector<f64>, _: f64, out: &mut DMatrix<f64>| -> Result<()> {
            out.fill(f64::NAN);
            Ok(())
        },
    );
    assert!(matches!(
        ekf.predict(&nan_jacobian, 0.5),
        Err(Error::NonFinite {
            what: "process Jacobian F(x)"
        })
    ));
    assert!(matches!(
        ekf.predict(&Drag, 0.0),
        Err(Error::InvalidParameter { name: "dt", .. })
    ));
    let refusing = (
        |_: &DVector<f64>, _: &mut DVector<f64>| -> Result<()> {
            Err(Error::InvalidParameter {
                name: "h",
                reason: "outside its domain".into(),
            })
        },
        |x: &DVector<f64>, out: &mut DMatrix<f64>| RangeBearing.jacobian(x, out),
    );
    assert!(matches!(
        ekf.update(&refusing, &DVector::zeros(2)),
        Err(Error::InvalidParameter { name: "h", .. })
    ));
    assert!(matches!(
        ekf.update(&RangeBearing, &DVector::zeros(3)),
        Err(Error::Dimension { .. })
    ));
    assert_eq!(ekf.state(), &x);
    assert_eq!(ekf.covariance(), &cov);
    assert!(matches!(
        DynExtendedKalmanFilter::new(
            DMatrix::identity(3, 3),
            p.r.clone(),
            p.x0.clone(),
            p.p0.clone()
        ),
        Err(Error::Dimension { .. })
    ));
}
