//! The 15-state error model against independent references: finite differences of the
//! navigation equations, the Van Loan exponential, the dense covariance product and a
//! Monte Carlo of IMU noise pushed through the mechanization.

use estim_core::{ErrorStateModel, ProcessModel};
use estim_ins::earth::radii_of_curvature;
use estim_ins::{
    navigation_rates, ImuSample, ImuSpec, InsErrorModel, InsState, Mechanization, ATT,
};
use nalgebra::{SMatrix, SVector, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

type V15 = SVector<f64, 15>;

fn normal(rng: &mut ChaCha8Rng) -> f64 {
    rng.sample(StandardNormal)
}

fn random_state(rng: &mut ChaCha8Rng) -> (InsState, ImuSample) {
    let mut s = InsState::new(
        0.0,
        rng.random_range(-1.2..1.2),
        rng.random_range(-3.0..3.0),
        rng.random_range(-100.0..100.0),
        Vector3::new(normal(rng) * 2.0, normal(rng) * 2.0, normal(rng) * 0.3),
        UnitQuaternion::from_euler_angles(
            rng.random_range(-0.3..0.3),
            rng.random_range(-0.3..0.3),
            rng.random_range(-3.1..3.1),
        ),
    );
    s.acc_bias = Vector3::new(normal(rng), normal(rng), normal(rng)) * 1e-2;
    s.gyro_bias = Vector3::new(normal(rng), normal(rng), normal(rng)) * 1e-4;
    let imu = ImuSample::new(
        0.0,
        Vector3::new(
            normal(rng) * 0.3,
            normal(rng) * 0.3,
            -9.8 + normal(rng) * 0.3,
        ),
        Vector3::new(normal(rng), normal(rng), normal(rng)) * 0.1,
    );
    (s, imu)
}

/// true = nominal + error, coded here from the documented convention (not the crate's).
fn plus(n: &InsState, e: &V15) -> InsState {
    let (rn, re) = radii_of_curvature(n.latitude);
    let mut t = *n;
    t.latitude += e[0] / (rn + n.height);
    t.longitude += e[1] / ((re + n.height) * n.latitude.cos());
    t.height -= e[2];
    t.velocity_ned += Vector3::new(e[3], e[4], e[5]);
    t.attitude = UnitQuaternion::from_scaled_axis(Vector3::new(e[6], e[7], e[8])) * n.attitude;
    t.acc_bias += Vector3::new(e[9], e[10], e[11]);
    t.gyro_bias += Vector3::new(e[12], e[13], e[14]);
    t
}

/// error = true - nominal (inverse of `plus`).
fn minus(t: &InsState, n: &InsState) -> V15 {
    let (rn, re) = radii_of_curvature(n.latitude);
    let psi = (t.attitude * n.attitude.inverse()).scaled_axis();
    let dv = t.velocity_ned - n.velocity_ned;
    let da = t.acc_bias - n.acc_bias;
    let dg = t.gyro_bias - n.gyro_bias;
    V15::from_column_slice(&[
        (t.latitude - n.latitude) * (rn + n.height),
        (t.longitude - n.longitude) * (re + n.height) * n.latitude.cos(),
        -(t.height - n.height),
        dv.x,
        dv.y,
        dv.z,
        psi.x,
        psi.y,
        psi.z,
        da.x,
        da.y,
        da.z,
        dg.x,
        dg.y,
        dg.z,
    ])
}

/// An Euler move of the state along its continuous navigation rates by `tau`.
fn advance(s: &InsState, imu: &ImuSample, tau: f64) -> InsState {
    let r = navigation_rates(s, imu);
    let mut o = *s;
    o.latitude += tau * r.latitude_rate;
    o.longitude += tau * r.longitude_rate;
    o.height += tau * r.height_rate;
    o.velocity_ned += tau * r.velocity_rate;
    o.attitude = UnitQuaternion::from_scaled_axis(-tau * r.navigation_frame_rate)
        * s.attitude
        * UnitQuaternion::from_scaled_axis(tau * r.body_rate);
    o
}

/// d/dt (true - nominal) by a central difference in time. Position and velocity rows
/// are quadratic in tau up to the radii's change over L̇ tau (relative 1e-10 at 100 s),
/// so a long tau keeps the rounding of the longitude (2e-9 m) below 1e-7 of the entries;
/// the attitude rows need a short tau (their error is (ω tau)² ≈ 1e-8 relative).
fn error_rate(n: &InsState, e: &V15, imu: &ImuSample) -> V15 {
    let t = plus(n, e);
    let rate = |tau: f64| {
        (minus(&advance(&t, imu, tau), &advance(n, imu, tau))
            - minus(&advance(&t, imu, -tau), &advance(n, imu, -tau)))
            / (2.0 * tau)
    };
    let long = rate(100.0);
    let short = rate(1e-3);
    let mut out = long;
    out.fixed_rows_mut::<3>(ATT)
        .copy_from(&short.fixed_rows::<3>(ATT));
    out
}

#[test]
fn system_matrix_matches_finite_differences_of_the_navigation_equations() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let model = InsErrorModel::new(ImuSpec::tactical_mems());
    let steps = [
        1000.0, 1000.0, 1000.0, 1e-2, 1e-2, 1e-2, 1e-5, 1e-5, 1e-5, 1e-3, 1e-3, 1e-3, 1e-6, 1e-6,
        1e-6,
    ];
    let mut worst: f64 = 0.0;
    for _ in 0..20 {
        let (s, imu) = random_state(&mut rng);
        let f = model.system_matrix(&s, &imu);
        for (j, &eps) in steps.iter().enumerate() {
            let mut e = V15::zeros();
            e[j] = eps;
            let fd = (error_rate(&s, &e, &imu) - error_rate(&s, &(-e), &imu)) / (2.0 * eps);
            // Navigation rows (0..9); the bias rows are the Gauss-Markov model, not the
            // mechanization, and are checked below.
            let analytic = f.fixed_view::<9, 1>(0, j);
            let numeric = fd.fixed_rows::<9>(0);
            let scale = analytic.amax();
            let err = (analytic - numeric).amax();
            let rel = err / scale;
            worst = worst.max(rel);
            assert!(
                rel < 1e-6,
                "column {j}: relative error {rel:e}\nanalytic {}\nnumeric {}",
                analytic.transpose(),
                numeric.transpose()
            );
        }
        let tau_a = ImuSpec::tactical_mems().accelerometer().bias_time_constant;
        for i in 9..12 {
            assert!((f[(i, i)] + 1.0 / tau_a).abs() < 1e-15);
        }
    }
    println!("worst column-relative error of F: {worst:e}");
}

#[test]
fn transition_and_noise_match_the_van_loan_exponential_at_imu_rate() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let model = InsErrorModel::new(ImuSpec::consumer_mems());
    for _ in 0..10 {
        let (s, imu) = random_state(&mut rng);
        let dt = 0.01;
        let (phi, q) = model.transition_and_noise(&s, &imu, dt);
        let (phi_exact, q_exact) = model.van_loan(&s, &imu, dt);
        let f_dt = (model.system_matrix(&s, &imu) * dt).abs().row_sum().max();
        // Truncation after (F dt)²/2: remainder bounded by ||F dt||³/6 · e^||F dt||.
        let bound = f_dt.powi(3) / 6.0 * f_dt.exp();
        let phi_err = (phi - phi_exact).abs().row_sum().max();
        assert!(phi_err <= bound, "{phi_err:e} > {bound:e}");
        // Q: each entry within 1 % of the exact one, relative to the geometric mean of
        // its two diagonal entries (the neglected terms are O(||F dt||) smaller).
        for i in 0..15 {
            for j in 0..15 {
                let scale = (q_exact[(i, i)] * q_exact[(j, j)]).sqrt();
                if scale == 0.0 {
                    continue;
                }
                let rel = (q[(i, j)] - q_exact[(i, j)]).abs() / scale;
                assert!(rel < 1e-2, "Q[{i},{j}] relative {rel:e}");
            }
        }
        assert!(q.symmetric_eigenvalues().min() > -1e-20);
        // The trait methods return the same matrices.
        assert_eq!(model.transition(&s, &imu, dt).unwrap(), phi);
        assert_eq!(model.process_noise(&s, &imu, dt).unwrap(), q);
        // The trait's one-pass override (used by the runners) equals both.
        let (phi_trait, q_trait) =
            ProcessModel::transition_and_noise(&model, &s, &imu, dt).unwrap();
        assert_eq!((phi_trait, q_trait), (phi, q));
        assert!(matches!(
            ProcessModel::transition_and_noise(&model, &s, &imu, -dt),
            Err(estim_core::Error::InvalidParameter { name: "dt", .. })
        ));
    }
}

/// Phi and Q_d from the 3x3 blocks (written out block by block, with the products that
/// skip F's structurally zero entries) against the documented formulas evaluated densely
/// from F = `system_matrix` and G = `noise_input` with nalgebra's 15 x 15 products:
/// Phi = I + A + A²/2 and Q_d = dt [Q₁ + (A Q₁ + Q₁ A')/2 + A Q₁ A'/3], A = F dt,
/// Q₁ = G Σ G'. Each entry within 16 ε of the sum of the absolute values of its terms
/// (a rounding bound for sums this short), at random states (several IMU grades and
/// step lengths) and along the default mission.
#[test]
fn transition_and_noise_equal_the_dense_second_order_formulas() {
    let eps = f64::EPSILON;
    let check = |model: &InsErrorModel, s: &InsState, imu: &ImuSample, dt: f64| {
        let (phi, q) = model.transition_and_noise(s, imu, dt);
        let a = model.system_matrix(s, imu) * dt;
        let id = SMatrix::<f64, 15, 15>::identity();
        let phi_ref = id + a + a * a * 0.5;
        let phi_scale = id + a.abs() + a.abs() * a.abs() * 0.5;
        let g = model.noise_input(s);
        let sigma = SMatrix::<f64, 12, 12>::from_diagonal(&model.noise_psd());
        let q1 = g * sigma * g.transpose();
        let q_ref = (q1 + (a * q1 + q1 * a.transpose()) * 0.5 + a * q1 * a.transpose() / 3.0) * dt;
        let q1_abs = g.abs() * sigma * g.abs().transpose();
        let q_scale = (q1_abs
            + (a.abs() * q1_abs + q1_abs * a.abs().transpose()) * 0.5
            + a.abs() * q1_abs * a.abs().transpose() / 3.0)
            * dt;
        for i in 0..15 {
            for j in 0..15 {
                let e = (phi[(i, j)] - phi_ref[(i, j)]).abs();
                assert!(e <= 16.0 * eps * phi_scale[(i, j)], "Phi[{i},{j}]: {e:e}");
                let e = (q[(i, j)] - q_ref[(i, j)]).abs();
                assert!(e <= 16.0 * eps * q_scale[(i, j)], "Q[{i},{j}]: {e:e}");
            }
        }
    };
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    for spec in [
        ImuSpec::consumer_mems(),
        ImuSpec::tactical_mems(),
        ImuSpec::navigation_grade_fog(),
    ] {
        let model = InsErrorModel::new(spec);
        for dt in [0.001, 0.01, 0.1, 1.0] {
            for _ in 0..10 {
                let (s, imu) = random_state(&mut rng);
                check(&model, &s, &imu, dt);
            }
        }
    }
    let mission = estim_ins::Mission::generate(&estim_ins::MissionConfig::default(), 7).unwrap();
    let model = InsErrorModel::new(ImuSpec::akit_observed());
    for (s, imu) in mission.truth.iter().zip(&mission.imu).step_by(97) {
        check(&model, s, imu, mission.imu_dt);
    }
}

#[test]
fn sparse_covariance_propagation_equals_the_dense_product() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let model = InsErrorModel::new(ImuSpec::tactical_mems());
    for _ in 0..20 {
        let (s, imu) = random_state(&mut rng);
        let (phi, q) = model.transition_and_noise(&s, &imu, 0.01);
        let l = SMatrix::<f64, 15, 15>::from_fn(|_, _| normal(&mut rng));
        let p = l * l.transpose() + SMatrix::<f64, 15, 15>::identity();
        let sparse = model.propagate_covariance(&p, &phi, &q);
        let dense = phi * p * phi.transpose() + q;
        let rel = (sparse - dense).amax() / dense.amax();
        assert!(rel < 1e-13, "{rel:e}");
        // A transition without the model's structure takes the dense path.
        let other = phi + SMatrix::<f64, 15, 15>::from_fn(|_, _| 1e-3 * normal(&mut rng));
        let rel = (model.propagate_covariance(&p, &other, &q)
            - (other * p * other.transpose() + q))
            .amax();
        assert!(rel < 1e-12);
    }
}

#[test]
fn inject_then_reset_is_consistent() {
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    let model = InsErrorModel::new(ImuSpec::tactical_mems());
    let (s, _) = random_state(&mut rng);
    let e = V15::from_fn(|i, _| normal(&mut rng) * [10.0, 0.1, 1e-3, 1e-3, 1e-5][i / 3]);
    let t = model.inject(&s, &e).unwrap();
    let back = minus(&t, &s);
    assert!((back - e).amax() < 1e-9, "{}", (back - e).transpose());
    // Reset Jacobian: re-centring ψ on the corrected attitude, checked numerically.
    let psi_hat = Vector3::new(e[ATT], e[ATT + 1], e[ATT + 2]);
    let j = model.reset_jacobian(&s, &e);
    for k in 0..3 {
        let mut d = Vector3::zeros();
        d[k] = 1e-7;
        let c_true = UnitQuaternion::from_scaled_axis(psi_hat + d) * s.attitude;
        let c_new = UnitQuaternion::from_scaled_axis(psi_hat) * s.attitude;
        let new_err = (c_true * c_new.inverse()).scaled_axis() / 1e-7;
        let predicted = j.fixed_view::<3, 3>(ATT, ATT).column(k).into_owned();
        assert!((new_err - predicted).amax() < 1e-6, "{new_err} {predicted}");
    }
    assert!(model.inject(&s, &V15::from_element(f64::NAN)).is_err());
}

/// Monte Carlo: IMU white noise at 1 kHz and Gauss-Markov bias drift pushed through the
/// nonlinear mechanization for 1 s; the sample covariance of (true - nominal) must match
/// the exact (Van Loan) Q_d of the linear model.
///
/// Tolerance: for N independent runs the sample covariance S_ij has standard deviation
/// sqrt((Q_ii Q_jj + Q_ij²)/N); every entry must lie within 5 of those (a false alarm
/// has probability < 225 · 6e-7 ≈ 1e-4 for a given seed), plus 2 % of
/// sqrt(Q_ii Q_jj) for the 1 kHz Euler-Maruyama discretisation and linearisation.
#[test]
fn discrete_noise_matches_monte_carlo_of_imu_noise() {
    let spec = ImuSpec::consumer_mems();
    let model = InsErrorModel::new(spec);
    let nominal = InsState::new(
        0.0,
        0.5733,
        0.609,
        -20.0,
        Vector3::new(1.5, -0.8, 0.05),
        UnitQuaternion::from_euler_angles(0.05, -0.02, 2.3),
    );
    let imu = ImuSample::new(
        0.0,
        Vector3::new(0.1, -0.05, -9.79),
        Vector3::new(0.0, 0.001, 0.03),
    );
    let (dt, inner) = (1.0, 1000usize);
    let h = dt / inner as f64;
    let mech = Mechanization::new();
    let mut clean = nominal;
    for _ in 0..inner {
        clean = mech.step(&clean, &imu, h).unwrap();
    }
    let (_, q_exact) = model.van_loan(&nominal, &imu, dt);
    let (acc, gyro) = (spec.accelerometer(), spec.gyroscope());
    let a_phi = (-h / acc.bias_time_constant).exp();
    let g_phi = (-h / gyro.bias_time_constant).exp();
    let a_drive = acc.bias_instability * (1.0 - a_phi * a_phi).sqrt();
    let g_drive = gyro.bias_instability * (1.0 - g_phi * g_phi).sqrt();
    let (a_white, g_white) = (
        acc.white_noise_density / h.sqrt(),
        gyro.white_noise_density / h.sqrt(),
    );
    let runs = 4000;
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut sum = SMatrix::<f64, 15, 15>::zeros();
    for _ in 0..runs {
        let mut s = nominal;
        let (mut ba, mut bg) = (Vector3::<f64>::zeros(), Vector3::<f64>::zeros());
        let v3 = |rng: &mut ChaCha8Rng| Vector3::new(normal(rng), normal(rng), normal(rng));
        for _ in 0..inner {
            // The IMU reading carries the bias b(t) and white noise; the nominal filter
            // state estimates zero bias, so b is also the bias error at the end.
            let noisy = ImuSample::new(
                0.0,
                imu.specific_force + ba + a_white * v3(&mut rng),
                imu.angular_rate + bg + g_white * v3(&mut rng),
            );
            s = mech.step(&s, &noisy, h).unwrap();
            ba = a_phi * ba + a_drive * v3(&mut rng);
            bg = g_phi * bg + g_drive * v3(&mut rng);
        }
        let mut truth = s;
        truth.acc_bias = ba;
        truth.gyro_bias = bg;
        // Error = truth - clean nominal. The noisy run used b = 0 in its state, the IMU
        // carried b: that is the true trajectory with true bias b.
        let e = minus(&truth, &clean);
        sum += e * e.transpose();
    }
    let sample = sum / runs as f64;
    let n = runs as f64;
    let mut worst: f64 = 0.0;
    for i in 0..15 {
        for j in 0..15 {
            let (qii, qjj, qij) = (q_exact[(i, i)], q_exact[(j, j)], q_exact[(i, j)]);
            let sd = ((qii * qjj + qij * qij) / n).sqrt();
            let tol = 5.0 * sd + 0.02 * (qii * qjj).sqrt();
            let diff = (sample[(i, j)] - qij).abs();
            if (qii * qjj).sqrt() > 0.0 {
                worst = worst.max(diff / sd.max(1e-300));
            }
            assert!(
                diff <= tol,
                "Q[{i},{j}]: MC {:e} vs Van Loan {qij:e} (tol {tol:e})",
                sample[(i, j)]
            );
        }
    }
    println!("largest |MC - Q| in sampling standard deviations: {worst:.2}");
}

/// Phi P Phi' + Q by three explicit loops (the reference; no structure, no nalgebra
/// product).
fn dense_reference(
    p: &SMatrix<f64, 15, 15>,
    phi: &SMatrix<f64, 15, 15>,
    q: &SMatrix<f64, 15, 15>,
) -> SMatrix<f64, 15, 15> {
    let mut phi_p = SMatrix::<f64, 15, 15>::zeros();
    for i in 0..15 {
        for j in 0..15 {
            phi_p[(i, j)] = (0..15).map(|k| phi[(i, k)] * p[(k, j)]).sum();
        }
    }
    SMatrix::from_fn(|i, j| (0..15).map(|k| phi_p[(i, k)] * phi[(j, k)]).sum::<f64>() + q[(i, j)])
}

/// Largest |a - b| / sqrt(b_ii b_jj): the error relative to the scale of each entry (P
/// mixes variances from 1 m^2 to 1e-10 (rad/s)^2, so a plain max-norm relative error
/// would not see errors in the small blocks).
fn correlation_scaled_error(a: &SMatrix<f64, 15, 15>, b: &SMatrix<f64, 15, 15>) -> f64 {
    let mut worst = 0.0f64;
    for i in 0..15 {
        for j in 0..15 {
            let scale = (b[(i, i)] * b[(j, j)]).sqrt();
            worst = worst.max((a[(i, j)] - b[(i, j)]).abs() / scale);
        }
    }
    worst
}

/// The structured propagation (the one the runners use) against the dense reference over
/// the whole 400 s default mission at 100 Hz: at every step on the same prior, and as two
/// chains run side by side for 40 000 steps. The in-place path
/// (`InsErrorModel::predict_covariance`, a third chain) must equal the structured one to
/// the last bit at every step (both run the build the CPU selects: fused multiply-adds
/// where it has AVX2 or AVX-512 and FMA, the portable kernel otherwise; the lib test
/// `every_covariance_kernel_equals_the_dense_reference` checks each build against the
/// dense reference on one machine), so the bounds hold for it too. The structured product of
/// transitions (`compose_transitions`, the runners' Phi_acc between updates, here reset
/// every 100 steps as with 1 Hz updates) must equal an explicitly looped dense product
/// of the same factors at every step.
#[test]
fn structured_propagation_equals_dense_reference_over_a_400_s_mission() {
    let mission = estim_ins::Mission::generate(&estim_ins::MissionConfig::default(), 7).unwrap();
    let model = InsErrorModel::new(ImuSpec::akit_observed());
    let mech = Mechanization::new();
    let dt = mission.imu_dt;
    let p0 = SMatrix::<f64, 15, 15>::from_diagonal(&V15::from_fn(|i, _| {
        [1.0, 1e-2, 1e-6, 1e-6, 1e-10][i / 3]
    }));
    let (mut s, mut structured, mut dense, mut in_place) = (mission.truth[0], p0, p0, p0);
    let mut accumulated = SMatrix::<f64, 15, 15>::identity();
    let (mut worst_step, mut worst_chain) = (0.0f64, 0.0f64);
    for (step, imu) in mission.imu.iter().enumerate() {
        let (phi, q) = model.transition_and_noise(&s, imu, dt);
        let next = model.propagate_covariance(&structured, &phi, &q);
        // Exactly symmetric, and equal to the dense product of the same prior.
        assert_eq!(next, next.transpose());
        worst_step = worst_step.max(correlation_scaled_error(
            &next,
            &dense_reference(&structured, &phi, &q),
        ));
        structured = next;
        model.predict_covariance(&s, imu, dt, &mut in_place);
        assert_eq!(in_place, structured);
        let composed = model.compose_transitions(&phi, &accumulated);
        let looped = SMatrix::<f64, 15, 15>::from_fn(|i, j| {
            (0..15).fold(0.0, |sum, k| sum + phi[(i, k)] * accumulated[(k, j)])
        });
        assert_eq!(composed, looped);
        accumulated = if (step + 1) % 100 == 0 {
            SMatrix::identity()
        } else {
            composed
        };
        dense = dense_reference(&dense, &phi, &q);
        worst_chain = worst_chain.max(correlation_scaled_error(&structured, &dense));
        s = mech.step(&s, imu, dt).unwrap();
    }
    println!("worst per step {worst_step:e}, worst between the chains {worst_chain:e}");
    assert!(worst_step < 1e-12, "{worst_step:e}");
    assert!(worst_chain < 1e-12, "{worst_chain:e}");
}
