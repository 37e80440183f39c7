//! The `serde` feature: JSON round trips of the IMU specifications, the mission
//! configuration, the INS state and IMU samples; checked types refuse invalid input.
//!
//! serde_json needs its `float_roundtrip` feature for bit-exact f64 (without it a
//! last-digit difference in parsing breaks equality). `cargo test --workspace` runs
//! this file: the workspace's facade enables estim-ins's `serde` feature from its
//! dev-dependencies.
#![cfg(feature = "serde")]

use estim_ins::{ImuSample, ImuSpec, InsState, MissionConfig, SensorSpec};
use nalgebra::{UnitQuaternion, Vector3};
use serde::de::DeserializeOwned;
use serde::Serialize;

fn round_trip<V: Serialize + DeserializeOwned + PartialEq + std::fmt::Debug>(value: &V) -> V {
    let json = serde_json::to_string(value).expect("serializes");
    let back: V = serde_json::from_str(&json).expect("deserializes");
    assert_eq!(&back, value, "round trip through {json}");
    back
}

#[test]
fn imu_specs_round_trip_including_an_infinite_time_constant() {
    for spec in [
        ImuSpec::akit_observed(),
        ImuSpec::tactical_mems(),
        ImuSpec::navigation_grade_fog(),
        ImuSpec::consumer_mems(),
        ImuSpec::perfect(),
    ] {
        round_trip(&spec);
    }
    // A random-constant bias (tau infinite) is written as null, which JSON can hold.
    let constant = SensorSpec {
        white_noise_density: 1e-3,
        bias_instability: 1e-4,
        bias_time_constant: f64::INFINITY,
        turn_on_bias: 0.0,
        scale_factor: 0.0,
    };
    let json = serde_json::to_value(constant).unwrap();
    assert_eq!(json["bias_time_constant"], serde_json::Value::Null);
    let back = round_trip(&constant);
    assert!(back.bias_time_constant.is_infinite());
}

#[test]
fn imu_spec_is_validated_on_deserialization() {
    let mut json = serde_json::to_value(ImuSpec::tactical_mems()).unwrap();
    json["gyroscope"]["white_noise_density"] = serde_json::json!(-1.0);
    let err = serde_json::from_value::<ImuSpec>(json).unwrap_err();
    assert!(err.to_string().contains("gyroscope"), "{err}");
}

#[test]
fn mission_config_round_trips_and_is_validated() {
    let config = MissionConfig::builder()
        .duration(60.0)
        .imu_spec(ImuSpec::tactical_mems())
        .build()
        .unwrap();
    round_trip(&config);
    round_trip(&MissionConfig::default());
    let mut json = serde_json::to_value(config).unwrap();
    json["duration"] = serde_json::json!(-5.0);
    let err = serde_json::from_value::<MissionConfig>(json).unwrap_err();
    assert!(err.to_string().contains("duration"), "{err}");
}

#[test]
fn ins_state_and_imu_samples_round_trip() {
    let state = InsState::new(
        12.5,
        0.5733,
        0.6089,
        -20.0,
        Vector3::new(1.8, -0.2, 0.05),
        UnitQuaternion::from_euler_angles(0.01, -0.02, 1.3),
    );
    round_trip(&state);
    round_trip(&ImuSample::new(
        0.01,
        Vector3::new(0.1, -0.05, -9.8),
        Vector3::new(1e-3, 2e-3, -5e-3),
    ));
}
