//! Beams -> least squares -> velocity on noise-free data, for random geometries.

use estim_dvl::nalgebra::{Matrix4x3, Vector3, Vector4};
use estim_dvl::{BeamGeometry, BeamSolution};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn random_unit(rng: &mut ChaCha8Rng) -> Vector3<f64> {
    loop {
        let v = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        let n = v.norm();
        if n > 0.2 && n <= 1.0 {
            return v / n;
        }
    }
}

/// Random geometries: Janus with random angle / offset, and arbitrary unit vectors
/// (kept only if every 3-beam subset is reasonably conditioned, so that 1e-12 is a
/// fair absolute tolerance).
fn random_geometries(rng: &mut ChaCha8Rng, count: usize) -> Vec<BeamGeometry> {
    let mut out = Vec::new();
    while out.len() < count {
        if out.len() % 2 == 0 {
            let angle = rng.random_range(10.0..60.0);
            let offset = rng.random_range(-180.0..180.0);
            out.push(
                BeamGeometry::janus(angle)
                    .azimuth_offset(offset)
                    .build()
                    .unwrap(),
            );
        } else {
            let dirs = std::array::from_fn(|_| random_unit(rng));
            let a = Matrix4x3::from_rows(&dirs.map(|d: Vector3<f64>| d.transpose()));
            let well_conditioned = (0..4).all(|skip| {
                let rows: Vec<_> = (0..4)
                    .filter(|&r| r != skip)
                    .map(|r| a.row(r).into_owned())
                    .collect();
                let sub = estim_dvl::nalgebra::Matrix3::from_rows(&rows);
                sub.singular_values().min() > 0.2
            });
            if well_conditioned {
                out.push(BeamGeometry::from_unit_vectors(dirs).build().unwrap());
            }
        }
    }
    out
}

fn random_velocity(rng: &mut ChaCha8Rng) -> Vector3<f64> {
    Vector3::new(
        rng.random_range(-3.0..3.0),
        rng.random_range(-3.0..3.0),
        rng.random_range(-1.0..1.0),
    )
}

#[test]
fn four_beam_round_trip_is_exact() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    for g in random_geometries(&mut rng, 200) {
        let v = random_velocity(&mut rng);
        // beams computed independently of the geometry's own A v
        let beams = Vector4::from_fn(|i, _| g.matrix().row(i).transpose().dot(&v));
        let s = g.solve(&[
            Some(beams[0]),
            Some(beams[1]),
            Some(beams[2]),
            Some(beams[3]),
        ]);
        let BeamSolution::FourBeam {
            velocity,
            error_velocity,
        } = s
        else {
            panic!("expected a 4-beam solution, got {s:?}");
        };
        assert!((velocity - v).amax() < 1e-12, "{velocity} vs {v}");
        assert!(
            error_velocity.abs() < 1e-12,
            "error velocity {error_velocity}"
        );
        assert!((g.least_squares(&beams) - v).amax() < 1e-12);
    }
}

#[test]
fn three_beam_solution_is_exact_for_each_missing_beam() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    for g in random_geometries(&mut rng, 200) {
        let v = random_velocity(&mut rng);
        let beams = Vector4::from_fn(|i, _| g.matrix().row(i).transpose().dot(&v));
        for missing in 0..4 {
            let mut with_nan = beams;
            with_nan[missing] = f64::NAN;
            let s = g.solve_nan(&with_nan);
            match s {
                BeamSolution::ThreeBeam {
                    velocity,
                    missing_beam,
                } => {
                    assert_eq!(missing_beam, missing + 1);
                    assert!(
                        (velocity - v).amax() < 1e-12,
                        "missing {missing}: {velocity} vs {v}"
                    );
                }
                other => panic!("expected a 3-beam solution, got {other:?}"),
            }
            let absent: [Option<f64>; 4] =
                std::array::from_fn(|i| (i != missing).then_some(beams[i]));
            assert_eq!(g.solve(&absent), s);
        }
    }
}

#[test]
fn error_velocity_is_rdi_formula_for_janus() {
    // RDI: e = d (b1 + b2 - b3 - b4) with d = 1 / (2 sqrt 2 sin theta) and RDI's opposite
    // pairs (1,2), (3,4); in the BeamsNet numbering the opposite pairs are (1,3), (2,4).
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for _ in 0..100 {
        let angle: f64 = rng.random_range(5.0..80.0);
        let offset: f64 = rng.random_range(-180.0..180.0);
        let g = BeamGeometry::janus(angle)
            .azimuth_offset(offset)
            .build()
            .unwrap();
        let b = Vector4::from_fn(|_, _| rng.random_range(-2.0..2.0));
        let d = 1.0 / (2.0 * 2f64.sqrt() * angle.to_radians().sin());
        let rdi = d * (b[0] + b[2] - b[1] - b[3]);
        let e = g.error_velocity(&b);
        assert!((e - rdi).abs() < 1e-12 * (1.0 + rdi.abs()), "{e} vs {rdi}");
    }
}

#[test]
fn error_velocity_measures_the_residual() {
    // |e| / scale equals the norm of the least-squares residual, for any geometry.
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    for g in random_geometries(&mut rng, 50) {
        let b = Vector4::from_fn(|_, _| rng.random_range(-2.0..2.0));
        let residual = b - g.matrix() * g.least_squares(&b);
        let ata_inv = (g.matrix().transpose() * g.matrix()).try_inverse().unwrap();
        let scale = (0.5 * (ata_inv[(0, 0)] + ata_inv[(1, 1)])).sqrt();
        let e = g.error_velocity(&b);
        assert!((e.abs() / scale - residual.norm()).abs() < 1e-10);
    }
}
