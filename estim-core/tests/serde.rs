//! The `serde` feature: JSON round trips of the public value types, the serialized
//! shape against hand-written JSON, and checked types refusing invalid input.
//!
//! serde_json needs its `float_roundtrip` feature for bit-exact f64 (without it a
//! last-digit difference in parsing breaks equality). `cargo test --workspace` runs
//! this file: the workspace's facade enables estim-core's `serde` feature from its
//! dev-dependencies.
#![cfg(feature = "serde")]

use estim_core::consistency::chi_square_band;
use estim_core::nalgebra::{Matrix2, Matrix2x1, SMatrix, SVector, Vector1, Vector2};
use estim_core::sigma_point::UnscentedTransform;
use estim_core::update::correlated_update;
use estim_core::update::UpdateOutcome;
use estim_core::{
    CovarianceUpdate, FilterConfig, Fixed, Gate, InputSpec, JointCheck, KalmanFilter,
    ScaledCorrelation, StateAndCovariance, UpdateReport, UpdateStatus, Zero,
};
use serde::de::DeserializeOwned;
use serde::Serialize;

fn round_trip<V: Serialize + DeserializeOwned + PartialEq + std::fmt::Debug>(value: &V) -> V {
    let json = serde_json::to_string(value).expect("serializes");
    let back: V = serde_json::from_str(&json).expect("deserializes");
    assert_eq!(&back, value, "round trip through {json}");
    back
}

fn estimate() -> StateAndCovariance<f64, 2> {
    StateAndCovariance::new(Vector2::new(1.0, 2.0), Matrix2::new(2.0, 0.5, 0.5, 1.0)).unwrap()
}

#[test]
fn state_and_covariance_round_trips_and_has_the_documented_shape() {
    let e = estimate();
    round_trip(&e);
    // nalgebra writes matrices as flat column-major arrays.
    let json: serde_json::Value = serde_json::to_value(&e).unwrap();
    let expected: serde_json::Value =
        serde_json::from_str(r#"{"state":[1.0,2.0],"covariance":[2.0,0.5,0.5,1.0]}"#).unwrap();
    assert_eq!(json, expected);
    // f32 as well.
    let e32 = StateAndCovariance::<f32, 1>::new(
        SVector::<f32, 1>::new(0.5),
        SMatrix::<f32, 1, 1>::new(0.25),
    )
    .unwrap();
    round_trip(&e32);
}

#[test]
fn state_and_covariance_is_checked_on_deserialization() {
    for bad in [
        // asymmetric covariance
        r#"{"state":[1.0,2.0],"covariance":[2.0,0.5,0.4,1.0]}"#,
        // wrong size
        r#"{"state":[1.0],"covariance":[2.0,0.5,0.5,1.0]}"#,
        // unknown key
        r#"{"state":[1.0,2.0],"covariance":[2.0,0.5,0.5,1.0],"mean":[0.0,0.0]}"#,
        // missing key
        r#"{"state":[1.0,2.0]}"#,
    ] {
        let r: Result<StateAndCovariance<f64, 2>, _> = serde_json::from_str(bad);
        assert!(r.is_err(), "{bad} accepted");
    }
    let err = serde_json::from_str::<StateAndCovariance<f64, 2>>(
        r#"{"state":[1.0,2.0],"covariance":[2.0,0.5,0.4,1.0]}"#,
    )
    .unwrap_err();
    assert!(err.to_string().contains("not symmetric"), "{err}");
}

#[test]
fn filter_config_round_trips_through_its_settings_and_is_rebuilt() {
    let config = FilterConfig::builder()
        .covariance_update(CovarianceUpdate::JosephLike)
        .gate(Gate::Nis { probability: 0.999 })
        .joint_check(JointCheck::Reject)
        .track_accumulated_noise(false)
        .window_capacity(100)
        .build()
        .unwrap();
    let back = round_trip(&config);
    // The cached gate thresholds were recomputed, not read: chi-square(3) at 0.999 is
    // 16.266 (published tables, e.g. NIST/SEMATECH 1.3.6.7.4).
    let t = back.gate_threshold(3).unwrap().unwrap();
    assert!((t - 16.266).abs() < 1e-3, "{t}");
    round_trip(&FilterConfig::default());
    round_trip(
        &FilterConfig::builder()
            .gate(Gate::NisThreshold(9.0))
            .build()
            .unwrap(),
    );

    // Missing keys take the defaults; unknown keys and invalid gates are refused.
    let partial: FilterConfig = serde_json::from_str(r#"{"window_capacity":7}"#).unwrap();
    assert_eq!(
        partial,
        FilterConfig::builder().window_capacity(7).build().unwrap()
    );
    assert!(serde_json::from_str::<FilterConfig>(r#"{"windows":7}"#).is_err());
    let err = serde_json::from_str::<FilterConfig>(r#"{"gate":{"Nis":{"probability":1.5}}}"#)
        .unwrap_err();
    assert!(err.to_string().contains("gate probability"), "{err}");
}

#[test]
fn update_reports_and_outcomes_round_trip() {
    // A real correlated update, M = Cov(G w, v) = G c q with c = -0.5.
    let (q, c) = (0.04, -0.5);
    let g = Matrix2x1::new(0.5, 1.0);
    let f = Matrix2::new(1.0, 1.0, 0.0, 1.0);
    let h = estim_core::nalgebra::Matrix1x2::new(1.0, 0.0);
    let r = estim_core::nalgebra::Matrix1::new(c * c * q + 1e-3);
    let m = Fixed(g * (c * q));
    let mut kf = KalmanFilter::new(f, g * g.transpose() * q, h, r, estimate()).unwrap();
    kf.predict().unwrap();
    let report: UpdateReport<f64, 2, 1> = kf.update(&Vector1::new(3.1), &m).unwrap();
    assert_eq!(report.status, UpdateStatus::Accepted);
    let back = round_trip(&report);
    assert!(back.is_accepted());

    let gated = FilterConfig::builder()
        .gate(Gate::NisThreshold(1e-6))
        .build()
        .unwrap();
    let mut kf = KalmanFilter::new(f, g * g.transpose() * q, h, r, estimate())
        .unwrap()
        .with_config(gated);
    kf.predict().unwrap();
    let rejected = kf.update(&Vector1::new(30.0), &Zero).unwrap();
    assert_eq!(round_trip(&rejected).status, UpdateStatus::RejectedByGate);

    let outcome: UpdateOutcome<f64, 2, 1> = correlated_update(
        &estimate(),
        &Vector1::new(0.3),
        &h,
        &r,
        &m.0,
        CovarianceUpdate::SquareRoot,
    )
    .unwrap();
    round_trip(&outcome);
}

#[test]
fn models_specs_and_bands_round_trip() {
    round_trip(&Zero);
    round_trip(&Fixed(Matrix2x1::new(-0.01, 0.02)));
    round_trip(&ScaledCorrelation { rho: 0.42 });
    round_trip(&InputSpec {
        name: "acc".into(),
        channels: 3,
        window: 100,
        sample_rate_hz: 100.0,
    });
    round_trip(&chi_square_band(2, 50, 0.95).unwrap());
    round_trip(&UnscentedTransform::new(0.5, 2.0, 1.0).unwrap());
    let err =
        serde_json::from_str::<UnscentedTransform>(r#"{"alpha":-1.0,"beta":2.0,"kappa":0.0}"#)
            .unwrap_err();
    assert!(err.to_string().contains("alpha"), "{err}");
    for form in [
        CovarianceUpdate::JosephLike,
        CovarianceUpdate::Short,
        CovarianceUpdate::Product,
        CovarianceUpdate::SquareRoot,
    ] {
        round_trip(&form);
    }
    for check in [JointCheck::Skip, JointCheck::Report, JointCheck::Reject] {
        round_trip(&check);
    }
}
