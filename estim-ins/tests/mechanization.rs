//! Classic INS checks of the strapdown mechanization.

use estim_ins::earth::{earth_rate_ned, normal_gravity, radii_of_curvature};
use estim_ins::{ImuSample, InsState, Mechanization};
use nalgebra::{UnitQuaternion, Vector3};

/// Haifa, about where the A-KIT data were recorded.
const LATITUDE: f64 = 0.5733;
const HEIGHT: f64 = -20.0;

/// The IMU reading of a body at rest on the Earth at `state` (independent of the
/// mechanization: f^n = -g^n, ω_ib^n = ω_ie^n, resolved in the body frame).
fn stationary_imu(state: &InsState) -> ImuSample {
    let c_nb = state.attitude.inverse();
    ImuSample::new(
        0.0,
        c_nb * Vector3::new(0.0, 0.0, -normal_gravity(state.latitude, state.height)),
        c_nb * earth_rate_ned(state.latitude),
    )
}

fn start() -> InsState {
    InsState::new(
        0.0,
        LATITUDE,
        0.6,
        HEIGHT,
        Vector3::zeros(),
        UnitQuaternion::from_euler_angles(0.02, -0.03, 2.1),
    )
}

#[test]
fn stationary_imu_stays_put_for_one_hour_at_100_hz() {
    let mech = Mechanization::new();
    let s0 = start();
    let imu = stationary_imu(&s0);
    let dt = 0.01;
    let mut s = s0;
    for _ in 0..360_000 {
        s = mech.step(&s, &imu, dt).unwrap();
    }
    let (rn, re) = radii_of_curvature(LATITUDE);
    let north = (s.latitude - s0.latitude) * (rn + HEIGHT);
    let east = (s.longitude - s0.longitude) * (re + HEIGHT) * LATITUDE.cos();
    let up = s.height - s0.height;
    let attitude = (s.attitude * s0.attitude.inverse()).angle();
    println!(
        "1 h stationary: north {north:e} m, east {east:e} m, up {up:e} m, |v| {:e} m/s, attitude {attitude:e} rad",
        s.velocity_ned.norm()
    );
    assert!((s.time - 3600.0).abs() < 1e-6);
    // Numerical noise only. The free vertical channel is unstable with time constant
    // τ = sqrt(R / 2g) ≈ 570 s: a rounding-level acceleration a (1e-13 m/s^2, a few ulp
    // of g) grows to a τ² cosh(t/τ) ≈ 9e7 s² · a ≈ 1e-5 m after 1 h, so the vertical
    // bound is 1e-4 m and 1e-7 m/s; horizontally the Schuler loop keeps it bounded.
    assert!(north.abs() < 1e-6 && east.abs() < 1e-6 && up.abs() < 1e-4);
    assert!(s.velocity_ned.norm() < 1e-7);
    assert!(attitude < 1e-10);
}

#[test]
fn north_velocity_error_oscillates_with_the_schuler_period() {
    let mech = Mechanization::new();
    let truth = start();
    let imu = stationary_imu(&truth);
    let mut s = truth;
    s.velocity_ned.x = 0.1;
    let dt = 0.1; // any rate works; 10 Hz keeps the test short
    let mut previous = s.velocity_ned.x;
    let mut crossings = Vec::new();
    for _ in 0..72_000 {
        s = mech.step(&s, &imu, dt).unwrap();
        // Perfect depth aiding: the free vertical channel is unstable (time constant
        // sqrt(R / 2g) ≈ 570 s) and is not what this test is about.
        s.height = HEIGHT;
        s.velocity_ned.z = 0.0;
        let v = s.velocity_ned.x;
        if previous.signum() != v.signum() {
            // Linear interpolation of the zero crossing.
            crossings.push(s.time - dt * v / (v - previous));
        }
        previous = v;
    }
    assert!(crossings.len() >= 3, "{crossings:?}");
    // Zero crossings at T/4, 3T/4, 5T/4: one period between the first and the third.
    let period_min = (crossings[2] - crossings[0]) / 60.0;
    let (rn, re) = radii_of_curvature(LATITUDE);
    let radius = (rn * re).sqrt() + HEIGHT;
    let theory_min =
        2.0 * std::f64::consts::PI * (radius / normal_gravity(LATITUDE, HEIGHT)).sqrt() / 60.0;
    println!("Schuler period: measured {period_min:.3} min, 2π sqrt(R/g) = {theory_min:.3} min");
    assert!((period_min - 84.4).abs() < 0.01 * 84.4, "{period_min}");
    // The rotating Earth shortens the period slightly: measured 0.23 % below
    // 2π sqrt(R/g), close to adding Ω² to ω_s² (0.34 %); 0.5 % bounds that effect.
    assert!((period_min - theory_min).abs() < 0.005 * theory_min);
}
