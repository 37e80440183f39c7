//! The INS kernels under the portable path and under the builds this CPU has, in one
//! process (estim-core's dispatch override, `estim_core::dispatch::with_features`): the
//! CPU's builds must agree with the portable path, the reference, to 1e-12.

use estim_core::dispatch::{cpu, with_features, Features};
use estim_core::ProcessModel;
use estim_ins::{
    ImuSample, ImuSpec, InsErrorModel, InsState, Mechanization, Mission, MissionConfig,
};
use nalgebra::{SMatrix, SVector};

type M15 = SMatrix<f64, 15, 15>;

/// Largest |a - b| / sqrt(b_ii b_jj) (relative to each entry's scale: P mixes variances
/// from 1 m^2 to 1e-10 (rad/s)^2).
fn correlation_scaled_error(a: &M15, b: &M15) -> f64 {
    let mut worst = 0.0f64;
    for i in 0..15 {
        for j in 0..15 {
            let scale = (b[(i, i)] * b[(j, j)]).sqrt();
            worst = worst.max((a[(i, j)] - b[(i, j)]).abs() / scale);
        }
    }
    worst
}

/// Largest |a - b| / max(|b|, 1) over the state's components (latitude, longitude,
/// height, velocity, attitude quaternion; the biases are passed through unchanged).
fn state_error(a: &InsState, b: &InsState) -> f64 {
    let parts = |s: &InsState| {
        let q = s.attitude.quaternion().coords;
        [
            s.latitude,
            s.longitude,
            s.height,
            s.velocity_ned.x,
            s.velocity_ned.y,
            s.velocity_ned.z,
            q.x,
            q.y,
            q.z,
            q.w,
        ]
    };
    parts(a)
        .iter()
        .zip(parts(b))
        .map(|(x, y)| (x - y).abs() / y.abs().max(1.0))
        .fold(0.0, f64::max)
}

/// What one path computes at one step of the mission: Phi and Q_d, the trait path's
/// propagation of `p`, the composition of Phi after `accumulated`, `p` after the
/// in-place covariance step, and one mechanization step.
struct Step {
    transition: (M15, M15),
    propagated: M15,
    composed: M15,
    covariance: M15,
    state: InsState,
}

fn step(
    features: Features,
    (state, imu, dt): (&InsState, &ImuSample, f64),
    (p, accumulated): (&M15, &M15),
) -> Step {
    let model = InsErrorModel::new(ImuSpec::akit_observed());
    with_features(features, || {
        let (phi, q) = model.transition_and_noise(state, imu, dt);
        let mut covariance = *p;
        model.predict_covariance(state, imu, dt, &mut covariance);
        Step {
            transition: (phi, q),
            propagated: model.propagate_covariance(p, &phi, &q),
            composed: model.compose_transitions(&phi, accumulated),
            covariance,
            state: Mechanization::new().step_unchecked(state, imu, dt),
        }
    })
}

/// The INS kernels (Phi and Q_d, the covariance step in place and through the trait,
/// the composition of transitions, the mechanization step) on the CPU's builds against
/// the portable path, the reference, in the same process, at each of the 40,000 steps
/// of the 400 s default mission along the true trajectory, each path carrying its own
/// covariance chain (and product of transitions, reset every 100 steps): the
/// covariances within 1e-12 (correlation-scaled), Phi, Q_d and the products of
/// transitions within 1e-12 relative to the largest entry of their column, the
/// composition of the same factors identical (its AVX2 build rounds as the portable
/// one), and the mechanization step within 1e-12 relative (absolute below magnitude 1). On a CPU without the hand-tuned builds both paths are the
/// portable one and agree exactly.
#[test]
fn the_cpu_builds_agree_with_the_portable_path() {
    let mission = Mission::generate(&MissionConfig::default(), 7).expect("mission");
    let dt = mission.imu_dt;
    let p0 = M15::from_diagonal(&SVector::<f64, 15>::from_fn(|i, _| {
        [1.0, 1e-2, 1e-6, 1e-6, 1e-10][i / 3]
    }));
    let column_scaled = |a: &M15, b: &M15| {
        (0..15)
            .map(|j| {
                let scale = b.column(j).amax().max(f64::MIN_POSITIVE);
                (a.column(j) - b.column(j)).amax() / scale
            })
            .fold(0.0, f64::max)
    };
    let model = InsErrorModel::new(ImuSpec::akit_observed());
    let mut portable = (p0, M15::identity());
    let mut native = portable;
    let (mut covariance, mut transition, mut mechanization) = (0.0f64, 0.0f64, 0.0f64);
    for (k, (state, imu)) in mission.truth.iter().zip(&mission.imu).enumerate() {
        let reference = step(
            Features::PORTABLE,
            (state, imu, dt),
            (&portable.0, &portable.1),
        );
        let cpu_step = step(cpu(), (state, imu, dt), (&native.0, &native.1));
        covariance = covariance
            .max(correlation_scaled_error(
                &cpu_step.covariance,
                &reference.covariance,
            ))
            .max(correlation_scaled_error(
                &cpu_step.propagated,
                &reference.propagated,
            ));
        let ((phi, q), (phi_ref, q_ref)) = (&cpu_step.transition, &reference.transition);
        transition = transition
            .max(column_scaled(phi, phi_ref))
            .max(column_scaled(q, q_ref));
        transition = transition.max(column_scaled(&cpu_step.composed, &reference.composed));
        // On the same factors, the CPU's composition is the portable one's to the last bit.
        let same_factors = with_features(cpu(), || {
            model.compose_transitions(&reference.transition.0, &portable.1)
        });
        assert_eq!(same_factors, reference.composed, "step {k}");
        mechanization = mechanization.max(state_error(&cpu_step.state, &reference.state));
        let reset = (k + 1) % 100 == 0;
        let next = |s: &Step| {
            let accumulated = if reset { M15::identity() } else { s.composed };
            (s.covariance, accumulated)
        };
        portable = next(&reference);
        native = next(&cpu_step);
    }
    println!(
        "CPU builds ({:?}) against the portable path over {} steps: covariance \
         {covariance:e}, Phi, Q_d and their products {transition:e}, mechanization step {mechanization:e}",
        cpu(),
        mission.imu.len()
    );
    assert!(covariance < 1e-12, "{covariance:e}");
    assert!(transition < 1e-12, "{transition:e}");
    assert!(mechanization < 1e-12, "{mechanization:e}");
}
