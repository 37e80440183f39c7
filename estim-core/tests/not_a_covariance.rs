//! Issue 46, class 9: what is not a covariance is refused, and every number the
//! library returns is finite or a typed error. Each property is checked against an
//! independent reference: eigenvalues from nalgebra's `SymmetricEigen`, quantiles
//! from statrs, values recomputed at unit scale.

use estim_core::consistency::{chi_square_band, nees, nis, WILSON_HILFERTY_DOF};
use estim_core::nalgebra::{
    DMatrix, Matrix1, Matrix1x2, Matrix2, Matrix2x1, Matrix3, SymmetricEigen, Vector1, Vector2,
    Vector3,
};
use estim_core::noise::process::{
    continuous_white_noise, discrete_white_noise, discrete_white_noise_gain,
    integrator_chain_transition,
};
use estim_core::smoother::{FixedLagSmoother, ForwardRecorder, RecordAt};
use estim_core::{
    Error, FilterConfig, Fixed, JointCheck, KalmanFilter, StateAndCovariance, UpdateStatus, Zero,
};
use proptest::prelude::*;
use proptest::test_runner::{FileFailurePersistence, RngSeed};
use statrs::distribution::{ChiSquared, ContinuousCDF};

/// 9.3e-10: the crate's relative tolerance in f64.
const TOL: f64 = 9.313225746154785e-10;

fn config() -> ProptestConfig {
    ProptestConfig {
        cases: 128,
        rng_seed: RngSeed::Fixed(20_261_206),
        failure_persistence: Some(Box::new(FileFailurePersistence::WithSource(
            "proptest-regressions",
        ))),
        ..ProptestConfig::default()
    }
}

/// Smallest eigenvalue of the correlation matrix of a symmetric `a` (zero variances
/// unscaled), by nalgebra's `SymmetricEigen` (the reference).
fn correlation_min_eigenvalue(a: &DMatrix<f64>) -> f64 {
    let n = a.nrows();
    let s: Vec<f64> = (0..n)
        .map(|i| {
            let d = a[(i, i)].abs();
            if d > 0.0 {
                1.0 / d.sqrt()
            } else {
                1.0
            }
        })
        .collect();
    let c = DMatrix::from_fn(n, n, |i, j| a[(i, j)] * s[i] * s[j]);
    SymmetricEigen::new(c).eigenvalues.min()
}

fn constant_velocity(config: FilterConfig, q: Matrix2<f64>) -> KalmanFilter<f64, 2, 1> {
    let initial = StateAndCovariance::new(Vector2::zeros(), Matrix2::identity()).unwrap();
    KalmanFilter::new(
        Matrix2::new(1.0, 1.0, 0.0, 1.0),
        q,
        Matrix1x2::new(1.0, 0.0),
        Matrix1::new(0.01),
        initial,
    )
    .unwrap()
    .with_config(config)
}

/// The attacker's case: under the former default (report only) an invalid M was used
/// and the posterior held a negative variance. Now refused by default, state
/// untouched; `Report` is the explicit opt-in that still uses it.
#[test]
fn invalid_joint_covariance_is_refused_by_default() {
    let q = Matrix2::new(0.25, 0.5, 0.5, 1.0) * 0.01;
    let m = Fixed(Matrix2x1::new(0.05, 0.05));
    let mut kf = constant_velocity(FilterConfig::default(), q);
    kf.predict().unwrap();
    let before = kf.estimate().clone();
    match kf.update(&Vector1::new(0.3), &m) {
        Err(Error::InvalidJointCovariance { min_eigenvalue }) => assert!(min_eigenvalue < -TOL),
        other => panic!("not refused: {other:?}"),
    }
    assert_eq!(kf.estimate(), &before);

    let report = FilterConfig::builder()
        .joint_check(JointCheck::Report)
        .build()
        .unwrap();
    let mut used = constant_velocity(report, q);
    used.predict().unwrap();
    let before = used.estimate().clone();
    let outcome = used.update(&Vector1::new(0.3), &m).unwrap();
    assert_eq!(outcome.status, UpdateStatus::Accepted);
    assert!(outcome.joint_min_eigenvalue.unwrap() < -TOL);
    assert_ne!(used.estimate(), &before, "the opt-in uses the invalid M");
}

/// A correlated update right after another (no predict: Q_acc = 0) is refused for any
/// size of M, including sizes far below the tolerance of the correlation matrix.
#[test]
fn correlated_update_without_predict_is_refused_at_every_scale() {
    let q = Matrix2::new(0.25, 0.5, 0.5, 1.0) * 0.01;
    for exponent in (-300..=0).step_by(20) {
        let size = 10f64.powi(exponent);
        let mut kf = constant_velocity(FilterConfig::default(), q);
        kf.predict().unwrap();
        kf.update(&Vector1::new(0.1), &Zero).unwrap();
        let before = kf.estimate().clone();
        let m = Fixed(Matrix2x1::new(size, 0.0));
        assert_eq!(
            kf.update(&Vector1::new(0.1), &m).unwrap_err(),
            Error::InvalidJointCovariance {
                min_eigenvalue: -1.0
            },
            "M = {size:e}"
        );
        assert_eq!(kf.estimate(), &before);
        // M = 0 stays valid without a predict.
        assert!(kf.update(&Vector1::new(0.1), &Zero).is_ok());
    }
}

proptest! {
    #![proptest_config(config())]

    /// Default runner behaviour against the eigenvalues of the joint correlation
    /// matrix: refused (state untouched) when clearly indefinite, accepted when
    /// clearly PSD (the band within 100 tolerances of 0 is not asserted).
    #[test]
    fn default_update_refuses_iff_joint_is_indefinite(
        g in proptest::collection::vec(-1.0f64..1.0, 4),
        m in proptest::collection::vec(-1.0f64..1.0, 2),
        log_r in -3.0f64..1.0,
        scale in 0.0f64..3.0,
    ) {
        let g = Matrix2::from_column_slice(&g);
        let q = g * g.transpose() + Matrix2::identity() * 1e-3;
        let r = 10f64.powf(log_r);
        // M scaled so that its correlation with v ranges over valid and invalid.
        let direction = Matrix2x1::new(m[0] * q[(0, 0)].sqrt(), m[1] * q[(1, 1)].sqrt()) * r.sqrt();
        let cross = direction * scale;
        let joint = DMatrix::from_fn(3, 3, |i, j| match (i, j) {
            (2, 2) => r,
            (2, k) | (k, 2) => cross[k],
            (i, j) => q[(i, j)],
        });
        let reference = correlation_min_eigenvalue(&joint);
        let initial = StateAndCovariance::new(Vector2::zeros(), Matrix2::identity()).unwrap();
        let mut kf = KalmanFilter::new(
            Matrix2::identity(), q, Matrix1x2::new(1.0, 0.0), Matrix1::new(r), initial,
        ).unwrap();
        kf.predict().unwrap();
        let before = kf.estimate().clone();
        let outcome = kf.update(&Vector1::new(0.2), &Fixed(cross));
        if reference < -100.0 * TOL {
            let refused = matches!(outcome, Err(Error::InvalidJointCovariance { .. }));
            prop_assert!(refused, "{reference:e}: {outcome:?}");
            prop_assert_eq!(kf.estimate(), &before);
        } else if reference > 100.0 * TOL {
            prop_assert!(outcome.is_ok(), "{reference:e}: {outcome:?}");
        }
    }

    /// `StateAndCovariance::new` against the eigenvalues of the correlation matrix, at
    /// scales from 1e-150 to 1e150.
    #[test]
    fn state_covariance_is_checked_for_semidefiniteness(
        values in proptest::collection::vec(-1.0f64..1.0, 6),
        shift in -0.5f64..0.5,
        exponent in -150i32..150,
    ) {
        let g = Matrix3::from_fn(|i, j| if j < 2 { values[3 * j + i] } else { 0.0 });
        let p = (g * g.transpose() + Matrix3::identity() * shift) * 10f64.powi(exponent);
        let p = (p + p.transpose()) * 0.5;
        let reference = correlation_min_eigenvalue(&DMatrix::from_column_slice(3, 3, p.as_slice()));
        let result = StateAndCovariance::new(Vector3::zeros(), p);
        if reference < -100.0 * TOL {
            let refused = matches!(
                result,
                Err(Error::InvalidCovariance { what: "state covariance", .. })
            );
            prop_assert!(refused, "{reference:e}");
        } else if reference > 100.0 * TOL {
            prop_assert!(result.is_ok(), "{reference:e}: {result:?}");
        }
    }

    /// NEES and NIS are scale-free: the same error and covariance in units 10^k apart
    /// give the unit-scale value (explicit inverse); a NEES itself out of range is
    /// `Error::Overflow`, never NaN or infinity.
    #[test]
    fn nees_is_finite_or_a_typed_error(
        a in 0.1f64..3.0, b in 0.1f64..3.0, rho in -0.9f64..0.9,
        e in proptest::collection::vec(-3.0f64..3.0, 2),
        exponent in -300i32..300,
        extra in -300i32..300,
    ) {
        let c = rho * (a * b).sqrt();
        let p = Matrix2::new(a, c, c, b);
        let e = Vector2::new(e[0], e[1]);
        let reference = (e.transpose() * p.try_inverse().unwrap() * e)[0];
        let k = 10f64.powi(exponent / 2);
        let scaled = nees(&(e * k), &(p * k * k));
        prop_assert!(scaled.is_ok(), "{scaled:?}");
        let value = scaled.unwrap();
        prop_assert!((value - reference).abs() <= 1e-12 * reference.max(1.0), "{value} {reference}");
        // Error scaled alone: NEES times 10^(2 extra), or Overflow beyond f64.
        let factor = 10f64.powi(extra / 2);
        let expected = reference * factor * factor;
        match nis(&(e * factor), &p) {
            Ok(v) => {
                prop_assert!(v.is_finite());
                prop_assert!((v - expected).abs() <= 1e-12 * expected.max(f64::MIN_POSITIVE));
            }
            Err(Error::Overflow { .. }) => prop_assert!(!expected.is_finite() || expected > 1e307),
            Err(other) => prop_assert!(false, "{other:?}"),
        }
    }

    /// Noise discretization over dt in 1e-300..1e300 and variances 1e-300..1e300:
    /// every entry finite, or `Error::Overflow`, and when finite equal to the closed
    /// form.
    #[test]
    fn noise_discretization_is_finite_or_a_typed_error(
        dt_exp in -300i32..300, var_exp in -300i32..300,
    ) {
        let dt = 10f64.powi(dt_exp);
        let var = 10f64.powi(var_exp);
        match discrete_white_noise::<f64, 2>(dt, var) {
            Ok(q) => {
                prop_assert!(q.iter().all(|x| x.is_finite()));
                let expected = dt * dt * var;
                prop_assert!((q[(1, 1)] - expected).abs() <= 1e-12 * expected);
            }
            Err(Error::Overflow { .. }) => {
                prop_assert!(!(dt.powi(4) / 4.0 * var).is_finite() || (dt * dt).is_infinite());
            }
            Err(other) => prop_assert!(false, "{other:?}"),
        }
        for result in [
            continuous_white_noise::<f64, 3>(dt, var).map(|q| q.iter().all(|x| x.is_finite())),
            integrator_chain_transition::<f64, 4>(dt).map(|q| q.iter().all(|x| x.is_finite())),
            discrete_white_noise_gain::<f64, 4>(dt).map(|q| q.iter().all(|x| x.is_finite())),
            discrete_white_noise::<f64, 3>(dt, var).map(|q| q.iter().all(|x| x.is_finite())),
        ] {
            prop_assert!(matches!(result, Ok(true) | Err(Error::Overflow { .. })), "{result:?}");
        }
    }

    /// chi_square_band against statrs at moderate degrees of freedom (exact path) and
    /// at the Wilson-Hilferty threshold and above it.
    #[test]
    fn chi_square_band_matches_statrs(
        dof in 1usize..20, runs in 1usize..100, p in 0.5f64..0.9999,
    ) {
        let band = chi_square_band(dof, runs, p).unwrap();
        let chi2 = ChiSquared::new((dof * runs) as f64).unwrap();
        let tail = (1.0 - p) / 2.0;
        let (lower, upper) = (
            chi2.inverse_cdf(tail) / runs as f64,
            chi2.inverse_cdf(1.0 - tail) / runs as f64,
        );
        prop_assert!((band.lower - lower).abs() <= 1e-9 * lower.max(1e-300));
        prop_assert!((band.upper - upper).abs() <= 1e-9 * upper);
    }
}

/// Just above the threshold the approximation agrees with statrs's exact inversion.
#[test]
fn chi_square_band_is_accurate_and_fast_beyond_the_threshold() {
    for total in [WILSON_HILFERTY_DOF + 1, 4 * WILSON_HILFERTY_DOF] {
        let chi2 = ChiSquared::new(total as f64).unwrap();
        for p in [0.5, 0.9, 0.99, 0.999_999] {
            let band = chi_square_band(total, 1, p).unwrap();
            let tail = (1.0 - p) / 2.0;
            let (lower, upper) = (chi2.inverse_cdf(tail), chi2.inverse_cdf(1.0 - tail));
            let worst = ((band.lower - lower) / lower)
                .abs()
                .max(((band.upper - upper) / upper).abs());
            eprintln!("{total} dof, p = {p}: relative difference {worst:e}");
            assert!(worst <= 1e-8, "{total} {p}: {band:?} vs [{lower}, {upper}]");
        }
    }
    let started = std::time::Instant::now();
    let band = chi_square_band(1, 1 << 52, 0.95).unwrap();
    assert!(started.elapsed().as_secs_f64() < 0.5);
    // sd of the average is sqrt(2 / 2^52): a 95 % band of +-1.96 of it.
    let half = 1.959_963_984_540_054 * (2.0f64 / (1u64 << 52) as f64).sqrt();
    assert!((band.upper - 1.0 - half).abs() < 1e-3 * half, "{band:?}");
    assert!((1.0 - band.lower - half).abs() < 1e-3 * half, "{band:?}");
}

/// The textbook asymmetric and indefinite cases.
#[test]
fn asymmetric_or_indefinite_covariances_are_refused() {
    assert!(matches!(
        StateAndCovariance::new(Vector2::zeros(), Matrix2::new(1.0, 2.0, 2.0, 1.0)),
        Err(Error::InvalidCovariance { .. })
    ));
    assert!(matches!(
        StateAndCovariance::new(Vector2::zeros(), Matrix2::new(-1e-300, 0.0, 0.0, 1.0)),
        Err(Error::InvalidCovariance { .. })
    ));
    // Singular (rank one) is a covariance.
    assert!(StateAndCovariance::new(Vector2::zeros(), Matrix2::new(4.0, 2.0, 2.0, 1.0)).is_ok());
    assert!(matches!(
        nees(&Vector2::new(1.0, 0.0), &Matrix2::new(2.0, 0.5, -0.5, 1.0)),
        Err(Error::InvalidCovariance { .. })
    ));
    assert!(matches!(
        nees(
            &Vector2::new(1e200, 0.0),
            &Matrix2::new(1e-200, 0.0, 0.0, 1.0)
        ),
        Err(Error::Overflow { .. })
    ));
    assert!(matches!(
        discrete_white_noise::<f64, 2>(1e300, 1.0),
        Err(Error::Overflow { .. })
    ));
}

/// Lags near usize::MAX are a typed error; a lag beyond the recording is the whole
/// recording, not a wrapped index.
#[test]
fn fixed_lag_is_bounded() {
    type Lag = FixedLagSmoother<f64, Vector2<f64>, 2>;
    for lag in [usize::MAX, usize::MAX - 1, Lag::MAX_LAG + 1] {
        assert!(matches!(
            Lag::new(RecordAt::EveryStep, lag),
            Err(Error::InvalidParameter { name: "lag", .. })
        ));
    }
    assert!(Lag::new(RecordAt::EveryStep, Lag::MAX_LAG).is_ok());

    let initial = StateAndCovariance::new(Vector2::zeros(), Matrix2::identity()).unwrap();
    let mut kf = KalmanFilter::new(
        Matrix2::new(1.0, 1.0, 0.0, 1.0),
        Matrix2::identity() * 0.01,
        Matrix1x2::new(1.0, 0.0),
        Matrix1::new(0.1),
        initial.clone(),
    )
    .unwrap()
    .with_observer(ForwardRecorder::from_initial(RecordAt::EveryStep, &initial));
    for k in 0..6 {
        kf.step(Some(&Vector1::new(k as f64)), &Zero).unwrap();
    }
    let recorder = kf.into_observer();
    assert_eq!(
        recorder.fixed_lag(usize::MAX).unwrap(),
        recorder.smooth().unwrap()
    );
}

/// An EM iteration whose M-step sums overflow stops the fit with a typed reason; the
/// result holds the given model (the last valid one) and its log-likelihood.
#[test]
fn em_stop_is_typed() {
    use estim_core::nalgebra::{dmatrix, dvector, DVector};
    use estim_core::noise::em::{em, log_likelihood, EmStop, EmVariables, LinearGaussianModel};
    let model = LinearGaussianModel::new(
        dmatrix![1.0],
        dmatrix![1.0],
        dmatrix![1.0],
        dmatrix![1e10],
        dvector![0.0],
        dmatrix![1e10],
    )
    .unwrap();
    let ys: Vec<Option<DVector<f64>>> = [1e154, -1e154, 1e154, -1e154]
        .iter()
        .map(|y| Some(dvector![*y]))
        .collect();
    let start = log_likelihood(&model, &ys).unwrap();
    let fit = em(&model, &ys, EmVariables::NOISE_COVARIANCES, 5).unwrap();
    match &fit.stop {
        EmStop::Refused {
            iteration: 1,
            error,
        } => {
            assert!(matches!(error, Error::NonFinite { .. }), "{error:?}")
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(fit.log_likelihoods, vec![start]);
    assert_eq!(fit.model, model);
}

/// A maximum-likelihood fit whose every Newton trial point is refused by the model
/// (here: a likelihood that rises toward theta = 2 but is only defined for
/// theta <= 1, as a filter's joint check refuses parameters where M is no longer a
/// covariance) stops with the typed `FitStop::Refused` naming the model's error, at the
/// last point the model accepted, not converged; not with an error, not as converged.
#[test]
fn ml_stop_on_refused_steps_is_typed() {
    use estim_core::nalgebra::SVector;
    use estim_core::noise::ml::{maximize, Bounds, FitOptions, FitStop, LogLikelihood};
    use estim_core::Scalar;

    struct Edge;
    impl LogLikelihood<1> for Edge {
        fn log_likelihood<T: Scalar>(&self, theta: &SVector<T, 1>) -> estim_core::Result<T> {
            let t = theta[0];
            if t > estim_core::nalgebra::convert(1.0) {
                return Err(Error::InnovationNotPositiveDefinite);
            }
            let d = t - estim_core::nalgebra::convert(2.0);
            Ok(-(d * d))
        }
    }
    let unbounded = Bounds::new(
        SVector::from([f64::NEG_INFINITY]),
        SVector::from([f64::INFINITY]),
    )
    .unwrap();
    // At the edge theta = 1 the gradient is 2: a gradient tolerance above it ends the
    // L-BFGS phase where it starts, so the Newton phase makes the first move.
    let options = FitOptions {
        gradient_tolerance: 10.0,
        ..FitOptions::default()
    };
    let fit = maximize(&Edge, &SVector::from([1.0]), &unbounded, &options).unwrap();
    match &fit.stop {
        FitStop::Refused { error } => {
            assert!(
                matches!(error, Error::InnovationNotPositiveDefinite),
                "{error:?}"
            )
        }
        other => panic!("{other:?}"),
    }
    assert!(!fit.converged);
    assert_eq!(fit.theta[0], 1.0);
    assert_eq!(fit.log_likelihood, -1.0);
}
