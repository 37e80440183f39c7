//! Unit tests of the runners (accumulation, gate and recovery, joint check, commit
//! rule, error-state reset).

use nalgebra::{SMatrix, SVector};

use super::*;
use crate::config::{GateRecovery, JointCheck};
use crate::observer::{Observer, PredictEvent, UpdateEvent};
use crate::{
    Error, ErrorStateModel, FilterConfig, MeasurementModel, ProcessModel, Result,
    StateAndCovariance,
};
use crate::{Fixed, Gate, Zero};
use nalgebra::{Matrix2, Matrix2x1, Vector1, Vector2};

/// F and Q of the constant-velocity model of [`cv_filter`].
fn cv_model() -> (Matrix2<f64>, Matrix2<f64>) {
    let g = Matrix2x1::new(0.5, 1.0);
    (Matrix2::new(1.0, 1.0, 0.0, 1.0), g * g.transpose() * 0.04)
}

fn cv_filter() -> KalmanFilter<f64, 2, 1> {
    let (f, q) = cv_model();
    KalmanFilter::new(
        f,
        q,
        nalgebra::Matrix1x2::new(1.0, 0.0),
        nalgebra::Matrix1::new(0.1),
        StateAndCovariance::new(Vector2::zeros(), Matrix2::identity()).unwrap(),
    )
    .unwrap()
}

#[test]
fn accumulation_matches_explicit_sum_and_resets() {
    let mut kf = cv_filter();
    let (f, q) = cv_model();
    for _ in 0..3 {
        kf.predict().unwrap();
    }
    // Independent: sum_{j=0}^{2} F^j Q F'^j and F^3.
    let expected = q + f * q * f.transpose() + f * f * q * (f * f).transpose();
    assert!((kf.accumulated_process_noise() - expected).amax() < 1e-15);
    assert!((kf.accumulated_transition() - f * f * f).amax() < 1e-15);
    assert_eq!(kf.propagations_since_update(), 3);
    kf.update(&Vector1::new(0.3), &Zero).unwrap();
    assert_eq!(kf.propagations_since_update(), 0);
    assert_eq!(*kf.accumulated_process_noise(), Matrix2::zeros());
}

/// The linear filter's first push of an interval reuses F and Q left in place by
/// the last one-step interval: Q_acc and Phi_acc still equal the explicit sums
/// after every predict, whatever mix of one-step and longer intervals came before.
#[test]
fn accumulation_is_exact_across_intervals_of_any_length() {
    let mut kf = cv_filter();
    let (f, q) = cv_model();
    for steps in [1, 1, 3, 1, 2, 1, 1, 4] {
        let (mut expected_q, mut expected_f) = (Matrix2::zeros(), Matrix2::identity());
        for step in 1..=steps {
            kf.predict().unwrap();
            // Independent: Q_acc <- F Q_acc F' + Q and Phi_acc <- F Phi_acc by
            // nalgebra's products.
            expected_q = f * expected_q * f.transpose() + q;
            expected_f = f * expected_f;
            assert!((kf.accumulated_process_noise() - expected_q).amax() < 1e-15);
            assert_eq!(*kf.accumulated_transition(), expected_f);
            assert_eq!(kf.propagations_since_update(), step);
        }
        kf.update(&Vector1::new(0.3), &Zero).unwrap();
        assert_eq!(*kf.accumulated_process_noise(), Matrix2::zeros());
        assert_eq!(*kf.accumulated_transition(), Matrix2::identity());
    }
}

/// The square-root filter with F, Q, H and R replaced between steps (intervals of one
/// and several predicts): its accumulated Q and Phi equal the explicit products, and
/// its posterior equals a textbook Kalman filter coded here with nalgebra's inverse.
#[test]
fn square_root_filter_takes_a_time_varying_model() {
    let (f0, q0) = cv_model();
    let initial = StateAndCovariance::new(Vector2::new(0.2, -0.1), Matrix2::identity()).unwrap();
    let mut sr = SquareRootKalmanFilter::new(
        f0,
        q0,
        nalgebra::Matrix1x2::new(1.0, 0.0),
        nalgebra::Matrix1::new(0.1),
        initial,
    )
    .unwrap();
    let (mut x, mut p) = (Vector2::new(0.2, -0.1), Matrix2::<f64>::identity());
    let mut k = 0.0f64;
    for steps in [1usize, 3, 1, 1, 2, 1, 4] {
        let (mut expected_q, mut expected_f) = (Matrix2::zeros(), Matrix2::identity());
        for _ in 0..steps {
            k += 1.0;
            let dt = 0.5 + 0.1 * k;
            let f = Matrix2::new(1.0, dt, 0.0, 1.0);
            let g = Matrix2x1::new(0.5 * dt * dt, dt);
            let q = g * g.transpose() * (0.02 + 0.01 * k) + Matrix2::identity() * 1e-4;
            sr.set_transition(f).unwrap();
            sr.set_process_noise(q).unwrap();
            sr.predict().unwrap();
            x = f * x;
            p = f * p * f.transpose() + q;
            expected_q = f * expected_q * f.transpose() + q;
            expected_f = f * expected_f;
            assert!((sr.accumulated_process_noise() - expected_q).amax() < 1e-13);
            assert!((sr.accumulated_transition() - expected_f).amax() < 1e-13);
        }
        let h = nalgebra::Matrix1x2::new(1.0, 0.3 * k.sin());
        let r = nalgebra::Matrix1::new(0.05 + 0.01 * k);
        sr.set_observation(h).unwrap();
        sr.set_measurement_noise(r).unwrap();
        let y = Vector1::new(0.1 * k.cos());
        sr.update(&y, &Zero).unwrap();
        let s = h * p * h.transpose() + r;
        let gain = p * h.transpose() * s.try_inverse().unwrap();
        x += gain * (y - h * x);
        p -= gain * h * p;
        assert!((sr.state() - x).amax() < 1e-12, "step {k}");
        assert!((sr.estimate().covariance() - p).amax() < 1e-12, "step {k}");
    }
    assert!(sr
        .set_process_noise(Matrix2::new(1.0, 2.0, 2.0, 1.0))
        .is_err());
    assert!(sr
        .set_measurement_noise(nalgebra::Matrix1::new(0.0))
        .is_err());
    assert!(sr
        .set_transition(Matrix2::new(f64::NAN, 0.0, 0.0, 1.0))
        .is_err());
    assert_eq!(
        *sr.measurement_noise(),
        nalgebra::Matrix1::new(0.05 + 0.01 * k)
    );
}

#[test]
fn gate_rejects_outlier_and_leaves_state_untouched() {
    let config = FilterConfig::builder()
        .gate(Gate::Nis { probability: 0.99 })
        .build()
        .unwrap();
    let mut kf = cv_filter()
        .with_config(config)
        .with_observer(crate::NisRecorder::default());
    kf.predict().unwrap();
    let before = kf.estimate().clone();
    let report = kf.update(&Vector1::new(100.0), &Zero).unwrap();
    assert_eq!(report.status, UpdateStatus::RejectedByGate);
    assert!(report.nis > 6.63, "nis {}", report.nis);
    assert_eq!(*kf.estimate(), before);
    assert_eq!(kf.propagations_since_update(), 0);
    kf.predict().unwrap();
    let ok = kf.update(&Vector1::new(0.1), &Zero).unwrap();
    assert!(ok.is_accepted());
    let rec = kf.into_observer();
    assert_eq!((rec.accepted(), rec.rejected()), (1, 1));
}

/// A filter that a far measurement locks out: x = 0, P = I, gate at NIS 9.
fn locked_out(after: Option<usize>) -> KalmanFilter<f64, 2, 1> {
    let mut builder = FilterConfig::builder().gate(Gate::NisThreshold(9.0));
    if let Some(after) = after {
        builder = builder.gate_recovery(GateRecovery::Inflate { after });
    }
    cv_filter().with_config(builder.build().unwrap())
}

#[test]
fn gate_recovery_inflates_p_onto_the_gate_boundary_after_a_run_of_rejections() {
    let mut kf = locked_out(Some(3));
    let y = Vector1::new(100.0);
    for _ in 0..3 {
        kf.predict().unwrap();
        let before = kf.estimate().clone();
        let report = kf.update(&y, &Zero).unwrap();
        assert_eq!(report.status, UpdateStatus::RejectedByGate);
        assert_eq!(report.covariance_inflation, None);
        assert_eq!(*kf.estimate(), before);
    }
    kf.predict().unwrap();
    let prior = kf.estimate().clone();
    let report = kf.update(&y, &Zero).unwrap();
    assert!(report.is_accepted());
    let lambda = report.covariance_inflation.unwrap();
    // Independent reference, scalar measurement of the first state (H = [1 0],
    // R = 0.1): nu^2 / (lambda P00 + R) = 9 gives lambda = (nu^2 / 9 - R) / P00.
    let p = prior.covariance();
    let nu = 100.0 - prior.state()[0];
    let expected = (nu * nu / 9.0 - 0.1) / p[(0, 0)];
    assert!(expected > 1.0);
    assert!(
        (lambda - expected).abs() <= 1e-12 * expected,
        "{lambda} vs {expected}"
    );
    // The NIS the gate saw is the uninflated one.
    assert!((report.nis - nu * nu / (p[(0, 0)] + 0.1)).abs() < 1e-9 * report.nis);
    // The posterior is the textbook update of the prior with P -> lambda P.
    let pl = p * lambda;
    let s = pl[(0, 0)] + 0.1;
    let k = Vector2::new(pl[(0, 0)] / s, pl[(1, 0)] / s);
    let x = prior.state() + k * nu;
    let h = nalgebra::Matrix1x2::new(1.0, 0.0);
    let posterior = (Matrix2::identity() - k * h) * pl;
    assert!((kf.estimate().state() - x).norm() < 1e-12 * x.norm());
    assert!((kf.estimate().covariance() - posterior).norm() < 1e-12 * posterior.norm());
    // The run is over: the next gated measurement is rejected again.
    kf.predict().unwrap();
    let far = Vector1::new(kf.estimate().state()[0] + 50.0);
    assert_eq!(
        kf.update(&far, &Zero).unwrap().status,
        UpdateStatus::RejectedByGate
    );
}

#[test]
fn without_recovery_a_locked_out_filter_stays_locked_out() {
    let mut kf = locked_out(None);
    for _ in 0..50 {
        kf.predict().unwrap();
        let report = kf.update(&Vector1::new(1e4), &Zero).unwrap();
        assert_eq!(report.status, UpdateStatus::RejectedByGate);
    }
    // With the rule, the same sequence is accepted at the 4th attempt.
    let mut kf = locked_out(Some(3));
    let statuses: Vec<_> = (0..5)
        .map(|_| {
            kf.predict().unwrap();
            kf.update(&Vector1::new(1e4), &Zero).unwrap().status
        })
        .collect();
    assert_eq!(statuses[..3], [UpdateStatus::RejectedByGate; 3]);
    assert_eq!(statuses[3], UpdateStatus::Accepted);
}

#[test]
fn gate_recovery_leaves_rejected_what_no_inflation_can_explain() {
    // State 2 is known exactly (zero variance, no process noise) and measured
    // directly: an innovation there is not explained by any lambda P.
    let config = FilterConfig::builder()
        .gate(Gate::NisThreshold(9.0))
        .gate_recovery(GateRecovery::Inflate { after: 1 })
        .build()
        .unwrap();
    let mut kf = KalmanFilter::<f64, 2, 2>::new(
        Matrix2::identity(),
        Matrix2::new(0.01, 0.0, 0.0, 0.0),
        Matrix2::identity(),
        Matrix2::identity() * 0.01,
        StateAndCovariance::new(Vector2::zeros(), Matrix2::new(1.0, 0.0, 0.0, 0.0)).unwrap(),
    )
    .unwrap()
    .with_config(config);
    for _ in 0..4 {
        kf.predict().unwrap();
        let report = kf.update(&Vector2::new(0.0, 5.0), &Zero).unwrap();
        assert_eq!(report.status, UpdateStatus::RejectedByGate);
        assert_eq!(report.covariance_inflation, None);
    }
}

#[test]
fn reject_policy_returns_typed_error_without_touching_state() {
    let config = FilterConfig::builder()
        .joint_check(JointCheck::Reject)
        .build()
        .unwrap();
    let mut kf = cv_filter().with_config(config);
    kf.predict().unwrap();
    let before = kf.estimate().clone();
    // |M| far beyond sqrt(Q_acc R): not a covariance.
    let err = kf
        .update(&Vector1::new(0.1), &Fixed(Matrix2x1::new(5.0, 5.0)))
        .unwrap_err();
    assert!(matches!(err, Error::InvalidJointCovariance { .. }));
    assert_eq!(*kf.estimate(), before);
    assert_eq!(kf.propagations_since_update(), 1);
}

/// The commit rule: an observer's error is returned after the predict or update
/// was committed (module docs).
#[test]
fn observer_error_leaves_the_committed_result() {
    struct Fails;
    impl<S, const N: usize> Observer<f64, S, N> for Fails {
        fn on_predict(&mut self, _: &PredictEvent<'_, f64, S, N>) -> Result<()> {
            Err(Error::Observer("disk full".into()))
        }
        fn on_update(&mut self, _: &UpdateEvent<'_, f64, S, N>) -> Result<()> {
            Err(Error::Observer("disk full".into()))
        }
    }
    let mut reference = cv_filter();
    let mut kf = cv_filter().with_observer(Fails);
    reference.predict().unwrap();
    assert!(matches!(kf.predict(), Err(Error::Observer(_))));
    assert_eq!(kf.estimate(), reference.estimate());
    assert_eq!(kf.propagations_since_update(), 1);
    reference.update(&Vector1::new(0.4), &Zero).unwrap();
    assert!(matches!(
        kf.update(&Vector1::new(0.4), &Zero),
        Err(Error::Observer(_))
    ));
    assert_eq!(kf.estimate(), reference.estimate());
    assert_eq!(kf.propagations_since_update(), 0);
}

/// With accumulation off, a model that needs Q_acc fails with a typed error and
/// Zero / Fixed still work.
#[test]
fn untracked_accumulation_is_refused_where_needed() {
    // Report (an opt-in): an unchecked Fixed M is used; the default refuses it below.
    let config = FilterConfig::builder()
        .track_accumulated_noise(false)
        .joint_check(JointCheck::Report)
        .build()
        .unwrap();
    let mut kf = cv_filter().with_config(config);
    kf.predict().unwrap();
    kf.predict().unwrap();
    assert_eq!(*kf.accumulated_process_noise(), Matrix2::zeros());
    assert_eq!(kf.propagations_since_update(), 2);
    let err = kf
        .update(&Vector1::new(0.1), &crate::ScaledCorrelation { rho: 0.1 })
        .unwrap_err();
    assert!(matches!(err, Error::NotTracked { .. }), "{err}");
    let report = kf
        .update(&Vector1::new(0.1), &Fixed(Matrix2x1::new(0.001, 0.002)))
        .unwrap();
    assert_eq!(report.joint_min_eigenvalue, None);
    let reject = FilterConfig::builder()
        .track_accumulated_noise(false)
        .joint_check(JointCheck::Reject)
        .build()
        .unwrap();
    let mut kf = cv_filter().with_config(reject);
    kf.predict().unwrap();
    assert!(kf.update(&Vector1::new(0.1), &Zero).is_ok());
    assert!(matches!(
        kf.update(&Vector1::new(0.1), &Fixed(Matrix2x1::new(0.001, 0.002))),
        Err(Error::NotTracked { .. })
    ));
}

/// The joint check reuses Q_acc's block certificate only while Q_acc is the same:
/// with 1, 2, 1, 3, 1 predicts per update (Q_acc = Q, F Q F' + Q, ...), every
/// reported margin equals a fresh `joint_validity_margin` of Q_acc (formed here by
/// the recursion, dense), for a valid Q and for an indefinite one (whose margins,
/// negative, come from the eigenvalue fallback and differ between the intervals).
/// 1e-12: the runner's Q_acc (symmetric propagation) and the dense one here differ
/// by rounding; a stale certificate is off by more than 1e-3.
#[test]
fn joint_check_reuses_the_noise_certificate_only_while_q_acc_is_unchanged() {
    use crate::cross::joint_validity_margin;
    /// F x and a fixed Q, any Q: the indefinite one, which `KalmanFilter::new`
    /// refuses, reaches the shared joint check through the EKF (whose Q_d comes from
    /// the model at each step).
    struct Linear(Matrix2<f64>, Matrix2<f64>);
    impl ProcessModel<f64, 2> for Linear {
        type State = SVector<f64, 2>;
        type Input = ();
        fn propagate(&self, x: &Self::State, _: &(), _: f64) -> Result<Self::State> {
            Ok(self.0 * x)
        }
        fn transition(&self, _: &Self::State, _: &(), _: f64) -> Result<Matrix2<f64>> {
            Ok(self.0)
        }
        fn process_noise(&self, _: &Self::State, _: &(), _: f64) -> Result<Matrix2<f64>> {
            Ok(self.1)
        }
    }
    struct First;
    impl MeasurementModel<f64, 2, 1> for First {
        type State = SVector<f64, 2>;
        fn predict(&self, x: &Self::State) -> Result<Vector1<f64>> {
            Ok(Vector1::new(x[0]))
        }
        fn jacobian(&self, _: &Self::State) -> Result<nalgebra::Matrix1x2<f64>> {
            Ok(nalgebra::Matrix1x2::new(1.0, 0.0))
        }
        fn noise_covariance(&self, _: &Self::State) -> Result<nalgebra::Matrix1<f64>> {
            Ok(nalgebra::Matrix1::new(0.1))
        }
    }
    for (case, q) in [
        Matrix2::<f64>::new(0.01, 0.02, 0.02, 0.04),
        Matrix2::new(0.04, 0.01, 0.01, -0.01),
    ]
    .into_iter()
    .enumerate()
    {
        let f = Matrix2::new(1.0, 1.0, 0.0, 1.0);
        let r = nalgebra::Matrix1::new(0.1);
        let initial = StateAndCovariance::new(Vector2::zeros(), Matrix2::identity()).unwrap();
        // Report (an opt-in): case 1's Q is indefinite, which the default refuses.
        let report = FilterConfig::builder()
            .joint_check(JointCheck::Report)
            .build()
            .unwrap();
        let mut kf = (case == 0).then(|| {
            KalmanFilter::new(f, q, nalgebra::Matrix1x2::new(1.0, 0.0), r, initial.clone())
                .unwrap()
                .with_config(report.clone())
        });
        let mut ekf = ExtendedKalmanFilter::new(Linear(f, q), initial).with_config(report);
        let mut margins: Vec<f64> = Vec::new();
        for predicts in [1, 2, 1, 3, 1] {
            let mut q_acc = Matrix2::zeros();
            for _ in 0..predicts {
                match kf.as_mut() {
                    Some(kf) => kf.predict().unwrap(),
                    None => ekf.predict(&(), 1.0).unwrap(),
                }
                q_acc = f * q_acc * f.transpose() + q;
            }
            let report = match kf.as_mut() {
                Some(kf) => kf.update(&Vector1::new(0.1), &Zero).unwrap(),
                None => ekf.update(&First, &Vector1::new(0.1), &Zero).unwrap(),
            };
            let margin: f64 = report.joint_min_eigenvalue.unwrap();
            let fresh = joint_validity_margin(&q_acc, &Matrix2x1::zeros(), &r).unwrap();
            assert!(
                (margin - fresh).abs() <= 1e-12,
                "{predicts}: {margin} vs {fresh}"
            );
            margins.push(margin);
        }
        // The intervals' Q_acc differ enough that a stale certificate would show.
        assert!((margins[0] - margins[1]).abs() > 1e-3, "{margins:?}");
    }
}

#[test]
fn report_policy_exposes_negative_eigenvalue() {
    let report = FilterConfig::builder()
        .joint_check(JointCheck::Report)
        .build()
        .unwrap();
    let mut kf = cv_filter().with_config(report);
    kf.predict().unwrap();
    let report = kf
        .update(&Vector1::new(0.1), &Fixed(Matrix2x1::new(0.3, 0.3)))
        .unwrap();
    assert!(report.joint_min_eigenvalue.unwrap() < 0.0);
}

#[test]
fn bad_dt_is_a_typed_error() {
    struct Walk;
    impl ProcessModel<f64, 1> for Walk {
        type State = SVector<f64, 1>;
        type Input = ();
        fn propagate(&self, s: &Self::State, _: &(), _: f64) -> Result<Self::State> {
            Ok(*s)
        }
        fn transition(&self, _: &Self::State, _: &(), _: f64) -> Result<SMatrix<f64, 1, 1>> {
            Ok(SMatrix::identity())
        }
        fn process_noise(&self, _: &Self::State, _: &(), dt: f64) -> Result<SMatrix<f64, 1, 1>> {
            Ok(SMatrix::identity() * dt)
        }
    }
    let mut ekf = ExtendedKalmanFilter::new(
        Walk,
        StateAndCovariance::new(Vector1::zeros(), nalgebra::Matrix1::identity()).unwrap(),
    );
    for dt in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        assert!(matches!(
            ekf.predict(&(), dt),
            Err(Error::InvalidParameter { name: "dt", .. })
        ));
    }
    ekf.predict(&(), 0.5).unwrap();
    assert_eq!(ekf.estimate().covariance()[(0, 0)], 1.5);
}

/// A model whose Phi and Q_d come only from `transition_and_noise` (the separate
/// methods fail): the runners must ask for both at once.
struct OnlyJoint;
impl ProcessModel<f64, 1> for OnlyJoint {
    type State = SVector<f64, 1>;
    type Input = ();
    fn propagate(&self, s: &Self::State, _: &(), _: f64) -> Result<Self::State> {
        Ok(*s)
    }
    fn transition(&self, _: &Self::State, _: &(), _: f64) -> Result<SMatrix<f64, 1, 1>> {
        Err(Error::InvalidParameter {
            name: "transition",
            reason: "not to be called".into(),
        })
    }
    fn process_noise(&self, _: &Self::State, _: &(), _: f64) -> Result<SMatrix<f64, 1, 1>> {
        Err(Error::InvalidParameter {
            name: "process_noise",
            reason: "not to be called".into(),
        })
    }
    fn transition_and_noise(
        &self,
        _: &Self::State,
        _: &(),
        dt: f64,
    ) -> Result<(SMatrix<f64, 1, 1>, SMatrix<f64, 1, 1>)> {
        Ok((SMatrix::identity() * 2.0, SMatrix::identity() * dt))
    }
}
impl ErrorStateModel<f64, 1> for OnlyJoint {
    fn inject(&self, nominal: &Self::State, error: &SVector<f64, 1>) -> Result<Self::State> {
        Ok(nominal + error)
    }
}

#[test]
fn runners_take_transition_and_noise_together() {
    let initial = StateAndCovariance::new(Vector1::zeros(), nalgebra::Matrix1::new(0.5));
    let mut ekf = ExtendedKalmanFilter::new(OnlyJoint, initial.unwrap());
    ekf.predict(&(), 0.25).unwrap();
    // 2 * 0.5 * 2 + 0.25
    assert_eq!(ekf.estimate().covariance()[(0, 0)], 2.25);
    let mut eskf =
        ErrorStateKalmanFilter::new(OnlyJoint, Vector1::zeros(), nalgebra::Matrix1::new(0.5))
            .unwrap();
    eskf.predict(&(), 0.25).unwrap();
    assert_eq!(eskf.covariance()[(0, 0)], 2.25);
    // The default pairs the two separate methods.
    assert!(matches!(
        ScalarNominal.transition_and_noise(&1.0, &0.0, 0.5),
        Ok((phi, qd)) if phi[(0, 0)] == 1.0 && qd[(0, 0)] == 0.05
    ));
}

/// Scalar error-state model with a non-identity reset (like the attitude reset of
/// Sola 2017, eq. 287: J = 1 - e/2), checked against scalar formulas.
struct ScalarNominal;
impl ProcessModel<f64, 1> for ScalarNominal {
    type State = f64;
    type Input = f64;
    fn propagate(&self, x: &f64, u: &f64, dt: f64) -> Result<f64> {
        Ok(x + u * dt)
    }
    fn transition(&self, _: &f64, _: &f64, _: f64) -> Result<SMatrix<f64, 1, 1>> {
        Ok(SMatrix::identity())
    }
    fn process_noise(&self, _: &f64, _: &f64, dt: f64) -> Result<SMatrix<f64, 1, 1>> {
        Ok(SMatrix::identity() * 0.1 * dt)
    }
}
impl ErrorStateModel<f64, 1> for ScalarNominal {
    fn inject(&self, nominal: &f64, error: &SVector<f64, 1>) -> Result<f64> {
        Ok(nominal + error[0])
    }
    fn reset_jacobian(&self, _: &f64, error: &SVector<f64, 1>) -> SMatrix<f64, 1, 1> {
        SMatrix::identity() * (1.0 - 0.5 * error[0])
    }
}
struct Direct;
impl MeasurementModel<f64, 1, 1> for Direct {
    type State = f64;
    fn predict(&self, x: &f64) -> Result<SVector<f64, 1>> {
        Ok(Vector1::new(*x))
    }
    fn jacobian(&self, _: &f64) -> Result<SMatrix<f64, 1, 1>> {
        Ok(SMatrix::identity())
    }
    fn noise_covariance(&self, _: &f64) -> Result<SMatrix<f64, 1, 1>> {
        Ok(SMatrix::identity() * 0.2)
    }
}

#[test]
fn error_state_injects_and_resets() {
    let mut eskf =
        ErrorStateKalmanFilter::new(ScalarNominal, 1.0, nalgebra::Matrix1::new(0.3)).unwrap();
    eskf.predict(&2.0, 0.5).unwrap(); // nominal 2.0, P = 0.3 + 0.05
    let (p, r, y) = (0.35, 0.2, 2.4);
    let report = eskf.update(&Direct, &Vector1::new(y), &Zero).unwrap();
    let k = p / (p + r);
    let e = k * (y - 2.0);
    let j = 1.0 - 0.5 * e;
    assert!((report.correction.unwrap()[0] - e).abs() < 1e-15);
    assert!((eskf.nominal() - (2.0 + e)).abs() < 1e-15);
    assert!((eskf.covariance()[(0, 0)] - j * (1.0 - k) * p * j).abs() < 1e-15);
}

/// The linear runner's hand-tuned builds against the portable one, in one process
/// (`crate::linalg::dispatch`): at (4, 2) and (15, 3), 40 predict + update steps with
/// a nonzero valid M. The AVX2 build alone does the same separately rounded
/// operations, so it equals the portable build bit for bit; with AVX-512F too, the
/// products of 8+ states are fused and the results differ by round-off only (within
/// 1e-10 of the largest variance over the run). Seeded.
#[test]
fn hand_tuned_builds_of_the_linear_runner_equal_the_portable_one() {
    use crate::linalg::dispatch::{cpu, with_features, Features};
    use rand::{RngExt, SeedableRng};

    type Trace<const N: usize> = Vec<(SVector<f64, N>, SMatrix<f64, N, N>, f64)>;

    fn run<const N: usize, const M: usize>(seed: u64, features: Features) -> Trace<N> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut draw = |scale: f64| rng.random_range(-1.0..1.0) * scale;
        let f = SMatrix::<f64, N, N>::identity() + SMatrix::from_fn(|_, _| draw(0.05));
        let g = SMatrix::<f64, N, N>::from_fn(|_, _| draw(0.1));
        let q = g * g.transpose() + SMatrix::identity() * 1e-3;
        let h = SMatrix::<f64, M, N>::from_fn(|_, _| draw(1.0));
        let r = SMatrix::<f64, M, M>::identity() * 0.5;
        let m = crate::Fixed(SMatrix::<f64, N, M>::from_fn(|i, k| {
            if i == k {
                0.01
            } else {
                0.0
            }
        }));
        let ys: Vec<SVector<f64, M>> = (0..40)
            .map(|_| SVector::from_fn(|_, _| draw(1.0)))
            .collect();
        let initial = StateAndCovariance::new(SVector::zeros(), SMatrix::identity()).unwrap();
        let mut kf = KalmanFilter::new(f, q, h, r, initial).unwrap();
        with_features(features, || {
            ys.iter()
                .map(|y| {
                    let report = kf.step(Some(y), &m).unwrap().unwrap();
                    let e = kf.estimate();
                    (*e.state(), *e.covariance(), report.nis)
                })
                .collect()
        })
    }

    fn compare<const N: usize, const M: usize>(seed: u64) {
        let avx2 = Features {
            avx2: true,
            avx512f: false,
            fma: false,
        };
        let all = Features {
            avx2: true,
            avx512f: true,
            fma: false,
        };
        let portable = run::<N, M>(seed, Features::PORTABLE);
        assert_eq!(run::<N, M>(seed, avx2), portable, "({N}, {M}) AVX2");
        let fused = run::<N, M>(seed, all);
        let scale = portable
            .iter()
            .map(|(_, p, _)| p.diagonal().amax())
            .fold(0.0, f64::max);
        for (step, (a, b)) in fused.iter().zip(&portable).enumerate() {
            assert!(
                (a.0 - b.0).amax() <= 1e-10 * scale,
                "({N}, {M}) step {step}"
            );
            assert!(
                (a.1 - b.1).amax() <= 1e-10 * scale,
                "({N}, {M}) step {step}"
            );
            assert!(
                (a.2 - b.2).abs() <= 1e-10 * b.2.max(1.0),
                "({N}, {M}) step {step}"
            );
        }
        if !cpu().avx512f || N < 8 {
            assert_eq!(fused, portable, "({N}, {M}) without the fused product");
        }
    }

    compare::<4, 2>(91);
    compare::<15, 3>(92);
}

/// `KalmanFilter::new` refuses a process or measurement noise that is not positive
/// semidefinite (Q = -0.01 I was accepted, and P's smallest eigenvalue then reached
/// -1 after 200 predicts), and accepts a singular PSD Q = G G' q.
#[test]
fn linear_filter_refuses_noise_that_is_not_a_covariance() {
    use nalgebra::{Matrix1, Matrix1x2};
    let initial = || StateAndCovariance::new(Vector2::zeros(), Matrix2::identity()).unwrap();
    let (f, q) = cv_model();
    let h = Matrix1x2::new(1.0, 0.0);
    for bad in [
        Matrix2::identity() * -0.01,
        Matrix2::new(0.01, 0.0, 0.0, -1e-4),
        Matrix2::new(0.01, 0.02, 0.02, 0.01),
    ] {
        let err = KalmanFilter::new(f, bad, h, Matrix1::new(0.1), initial()).unwrap_err();
        assert!(
            matches!(
                err,
                Error::InvalidCovariance {
                    what: "process noise covariance",
                    ..
                }
            ),
            "{err}"
        );
    }
    let err = KalmanFilter::new(f, q, h, Matrix1::new(-0.1), initial()).unwrap_err();
    assert!(matches!(
        err,
        Error::InvalidCovariance {
            what: "measurement noise covariance",
            ..
        }
    ));
    // Q = G G' q is singular (rank 1) and valid.
    assert!(KalmanFilter::new(f, q, h, Matrix1::new(0.1), initial()).is_ok());
}
