//! Process-noise helpers (`estim_core::noise::process`): Van Loan's discretization
//! against the closed forms of the integrator chains and against a separately coded
//! Simpson quadrature of e^{F s} G Qc G' e^{F' s} on random F; every closed form,
//! block layout and Van Loan problem against filterpy's own functions (committed
//! expected values, `tests/data/filterpy_process_noise.csv`, written by
//! `training/peers/filterpy_process_noise.py`; no Python needed here); typed errors on
//! bad input.

mod common;

use common::*;
use estim_core::nalgebra::{DMatrix, Matrix2, Matrix3, SMatrix};
use estim_core::noise::process::{
    continuous_white_noise, discrete_white_noise, discrete_white_noise_gain, independent_axes,
    integrator_chain_transition, van_loan, van_loan_with_input, AxisLayout,
};
use estim_core::Error;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Largest entrywise relative difference max |a - b| / |b| over the entries with
/// b != 0; entries with b = 0 must be exactly 0 in a (infinity otherwise).
fn entrywise_rel(a: &DMatrix<f64>, b: &DMatrix<f64>) -> f64 {
    assert_eq!(a.shape(), b.shape());
    a.iter().zip(b.iter()).fold(0.0, |worst, (x, y)| {
        let e = if *y == 0.0 {
            if *x == 0.0 {
                0.0
            } else {
                f64::INFINITY
            }
        } else {
            ((x - y) / y).abs()
        };
        worst.max(e)
    })
}

/// The chain's continuous F: ones on the superdiagonal.
fn chain_dynamics<const N: usize>() -> SMatrix<f64, N, N> {
    SMatrix::from_fn(|i, j| if j == i + 1 { 1.0 } else { 0.0 })
}

/// k!, as f64 (test-side, a product of integers).
fn factorial(k: usize) -> f64 {
    (1..=k).map(|m| m as f64).product()
}

// ---------------------------------------------------------------- closed forms

/// Van Loan on the chain of order N (F superdiagonal ones, G Qc G' = q e_N e_N'),
/// against `continuous_white_noise` and a test-side transcription of the same closed
/// form (q dt^(a+b+1) / ((a+b+1) a! b!) with powf and factorials); Phi against
/// `integrator_chain_transition` and dt^(j-i)/(j-i)!. Returns the differences
/// [Q_d entrywise, Q_d max-norm, Phi entrywise, Phi max-norm]; entrywise over the
/// nonzero entries of the reference, the zeros of Phi measured against its largest
/// entry.
fn chain_case<const N: usize>(dt: f64, q: f64) -> [f64; 4] {
    let mut density = SMatrix::<f64, N, N>::zeros();
    density[(N - 1, N - 1)] = q;
    let model = van_loan(&chain_dynamics::<N>(), &density, dt).unwrap();
    let closed = continuous_white_noise::<f64, N>(dt, q).unwrap();
    let formula = DMatrix::from_fn(N, N, |i, j| {
        let (a, b) = (N - 1 - i, N - 1 - j);
        q * dt.powf((a + b + 1) as f64) / ((a + b + 1) as f64 * factorial(a) * factorial(b))
    });
    let phi_formula = DMatrix::from_fn(N, N, |i, j| {
        if j >= i {
            dt.powf((j - i) as f64) / factorial(j - i)
        } else {
            0.0
        }
    });
    let phi_closed = integrator_chain_transition::<f64, N>(dt).unwrap();
    // The two closed forms are the same numbers to a few ulps.
    assert!(entrywise_rel(&dm(&closed), &formula) < 1e-14);
    assert!(entrywise_rel(&dm(&phi_closed), &phi_formula) < 1e-14);
    let phi = dm(&model.transition);
    let below = (0..N)
        .flat_map(|j| ((j + 1)..N).map(move |i| (i, j)))
        .fold(0.0f64, |m, ij| m.max(phi[ij].abs()))
        / phi_formula.amax();
    let upper = DMatrix::from_fn(N, N, |i, j| if j >= i { phi[(i, j)] } else { 0.0 });
    [
        entrywise_rel(&dm(&model.process_noise), &formula),
        rel_err(&dm(&model.process_noise), &formula),
        entrywise_rel(&upper, &phi_formula).max(below),
        rel_err(&phi, &phi_formula),
    ]
}

/// Orders 1..6 (2, 3, 4 are filterpy's), dt from 1e-3 to 10 s, two spectral
/// densities: Van Loan's Q_d and Phi equal the closed forms to 1e-12 relative to their
/// largest entry everywhere, and to 1e-12 in every entry for orders up to 3 at every
/// dt and for orders 4..6 at dt >= 0.5.
///
/// Not entrywise below that: for a small ||C||_1 nalgebra's exponential takes a
/// low-degree Padé approximant (degree 3 when its norm estimate is below 0.015),
/// backward stable in norm but with the wrong coefficient of C^7 and beyond, and the
/// position variance dt^(2N-1) / ((2N-1) ((N-1)!)^2) of a chain of order N >= 4 is
/// exactly such a term: off by a fixed 2.5e-3 (N = 4), 3.3e-3 (5), 8.3e-3 (6)
/// relative at dt <= 0.01, 1.6e-5 for N = 6 at dt = 0.1, an absolute error far below
/// the round-off of the largest entry. Measured figures are printed; the module docs say to use the closed forms
/// for chains.
#[test]
fn van_loan_equals_the_integrator_chain_closed_forms() {
    let (mut entry_q, mut norm_q, mut entry_phi, mut norm_phi) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    let mut graded = 0.0f64; // entrywise Q_d where it is not asserted
    for dt in [1e-3, 0.01, 0.1, 0.5, 1.0, 2.5, 10.0] {
        for q in [1.0, 0.37] {
            let cases = [
                (1, chain_case::<1>(dt, q)),
                (2, chain_case::<2>(dt, q)),
                (3, chain_case::<3>(dt, q)),
                (4, chain_case::<4>(dt, q)),
                (5, chain_case::<5>(dt, q)),
                (6, chain_case::<6>(dt, q)),
            ];
            for (order, [eq, nq, ephi, nphi]) in cases {
                if order <= 3 || dt >= 0.5 {
                    entry_q = entry_q.max(eq);
                } else {
                    graded = graded.max(eq);
                }
                norm_q = norm_q.max(nq);
                entry_phi = entry_phi.max(ephi);
                norm_phi = norm_phi.max(nphi);
            }
        }
    }
    println!(
        "chains: Q_d max-norm rel {norm_q:e}, entrywise {entry_q:e} (orders 4..6 at dt < 0.5: \
         {graded:e}); Phi max-norm rel {norm_phi:e}, entrywise {entry_phi:e}"
    );
    assert!(norm_q < 1e-12, "Q_d {norm_q:e}");
    assert!(entry_q < 1e-12, "Q_d entrywise {entry_q:e}");
    assert!(norm_phi < 1e-12, "Phi {norm_phi:e}");
    assert!(entry_phi < 1e-12, "Phi entrywise {entry_phi:e}");
}

/// The discrete white-noise model is Gamma var Gamma' with filterpy's Gamma (test-side
/// transcription: [dt^2/2, dt] for order 2, [dt^(N-1)/(N-1)!, ..., dt, 1] above).
#[test]
fn discrete_white_noise_is_gamma_var_gamma() {
    fn case<const N: usize>(dt: f64, var: f64) -> f64 {
        let gamma = DMatrix::from_fn(N, 1, |i, _| {
            let k = if N == 2 { 2 - i } else { N - 1 - i };
            dt.powf(k as f64) / factorial(k)
        });
        let q = discrete_white_noise::<f64, N>(dt, var).unwrap();
        let g = discrete_white_noise_gain::<f64, N>(dt).unwrap();
        assert!(entrywise_rel(&dm(&g), &gamma) < 1e-15);
        entrywise_rel(&dm(&q), &(&gamma * gamma.transpose() * var))
    }
    let mut worst = 0.0f64;
    for dt in [1e-3, 0.1, 1.0, 3.0] {
        for var in [1.0, 0.25] {
            worst = worst
                .max(case::<2>(dt, var))
                .max(case::<3>(dt, var))
                .max(case::<4>(dt, var));
        }
    }
    println!("discrete white noise: max entrywise rel diff {worst:e}");
    assert!(worst < 1e-14);
}

// ---------------------------------------------------------------- quadrature

/// Composite Simpson over [0, dt] with `intervals` (even) sub-intervals of
/// e^{F s} D e^{F' s}, e^{F s} by nalgebra's exponential at every node.
fn simpson(f: &DMatrix<f64>, d: &DMatrix<f64>, dt: f64, intervals: usize) -> DMatrix<f64> {
    let n = f.nrows();
    let h = dt / intervals as f64;
    let mut sum = DMatrix::<f64>::zeros(n, n);
    for k in 0..=intervals {
        let weight = if k == 0 || k == intervals {
            1.0
        } else if k % 2 == 1 {
            4.0
        } else {
            2.0
        };
        let e = (f * (k as f64 * h)).exp();
        sum += (&e * d * e.transpose()) * weight;
    }
    sum * (h / 3.0)
}

/// One random problem of size N: F = A + shift I with A uniform in [-1, 1) scaled to
/// Frobenius norm 1 / dt (so ||F dt||_2 <= 1 + |shift|; shift -0.8 stable, 0 mixed,
/// +0.8 unstable), G uniform N x P with P = 1 + seed % N (rank-deficient when P < N),
/// Qc = B B' (P x P). Returns [Q_d vs Simpson 2000, the Richardson estimate
/// |S_2000 - S_1000| / 15 of that quadrature's own error, Phi vs (F dt).exp(),
/// with_input vs van_loan], max-norm relative.
fn quadrature_case<const N: usize>(seed: u64, shift: f64, dt: f64) -> [f64; 4] {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let a = SMatrix::<f64, N, N>::from_fn(|_, _| rng.random_range(-1.0..1.0));
    let scale = 1.0 / (dt * a.norm().max(1e-3));
    let f = a * scale + SMatrix::<f64, N, N>::identity() * (shift / dt);
    let p = 1 + (seed as usize) % N;
    let g = DMatrix::from_fn(N, p, |_, _| rng.random_range(-1.0..1.0));
    let b = DMatrix::from_fn(p, p, |_, _| rng.random_range(-1.0..1.0));
    let qc = &b * b.transpose();
    let density_dyn = &g * &qc * g.transpose();
    let density = SMatrix::<f64, N, N>::from_column_slice(density_dyn.as_slice());
    let model = van_loan(&f, &density, dt).unwrap();
    let fine = simpson(&dm(&f), &density_dyn, dt, 2000);
    let coarse = simpson(&dm(&f), &density_dyn, dt, 1000);
    let phi = dm(&(f * dt)).exp();
    // The same problem with G and Qc given apart (static P chosen as N, G padded).
    let g_pad = SMatrix::<f64, N, N>::from_fn(|i, j| if j < p { g[(i, j)] } else { 0.0 });
    let qc_pad =
        SMatrix::<f64, N, N>::from_fn(|i, j| if i < p && j < p { qc[(i, j)] } else { 0.0 });
    let apart = van_loan_with_input(&f, &g_pad, &qc_pad, dt).unwrap();
    // F and Qc do not commute: the quadrature is not a scalar integral in disguise.
    let commutator = (dm(&f) * &density_dyn - &density_dyn * dm(&f)).amax();
    assert!(commutator > 1e-3 * density_dyn.amax() * dm(&f).amax());
    [
        rel_err(&dm(&model.process_noise), &fine),
        rel_err(&fine, &coarse) / 15.0,
        rel_err(&dm(&model.transition), &phi),
        rel_err(&dm(&apart.process_noise), &dm(&model.process_noise)),
    ]
}

/// Random F of sizes 2..6 (stable, mixed, unstable; 4 seeds each, dt 0.05 and 1.3),
/// G Qc G' of every rank: Van Loan's Q_d equals the Simpson quadrature to within
/// 4 times the quadrature's own error plus 1e-13 (max-norm relative), and Phi equals
/// nalgebra's e^{F dt} to 1e-13.
///
/// Tolerance of the quadrature: Simpson's error is O(h^4), so the Richardson estimate
/// |S_2000 - S_1000| / 15 measures the error of S_2000 (4 times it leaves room for the
/// estimate's own inaccuracy); 1e-13 is a floor for the round-off of summing 2001
/// products of exponentials (about 450 eps; the measured Richardson estimates, at
/// most 3.6e-14, are themselves round-off of that order, printed with the figures).
/// Phi: both are nalgebra's Padé exponential, of F dt and of the 2N block (whose
/// norm is larger), so they differ by the round-off of the scaling and squaring.
/// van_loan_with_input equals van_loan of G Qc G' formed apart to 1e-14 (the same
/// computation after one product).
#[test]
fn van_loan_equals_quadrature_on_random_models() {
    let (mut wq, mut west, mut wphi, mut wapart) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    let mut cases = 0;
    for (k, shift) in [-0.8, 0.0, 0.8].into_iter().enumerate() {
        for dt in [0.05, 1.3] {
            for seed in 0..4u64 {
                let s = seed + 100 * k as u64;
                for [eq, est, ephi, eapart] in [
                    quadrature_case::<2>(s, shift, dt),
                    quadrature_case::<3>(s, shift, dt),
                    quadrature_case::<4>(s, shift, dt),
                    quadrature_case::<5>(s, shift, dt),
                    quadrature_case::<6>(s, shift, dt),
                ] {
                    assert!(
                        eq <= 4.0 * est + 1e-13,
                        "Q_d {eq:e}, quadrature error {est:e}"
                    );
                    wq = wq.max(eq);
                    west = west.max(est);
                    wphi = wphi.max(ephi);
                    wapart = wapart.max(eapart);
                    cases += 1;
                }
            }
        }
    }
    println!(
        "random F ({cases} cases): max rel diff Q_d vs Simpson {wq:e} (Richardson estimate \
         up to {west:e}), Phi vs exp {wphi:e}, with_input {wapart:e}"
    );
    assert!(wphi < 1e-13, "Phi {wphi:e}");
    assert!(wapart < 1e-14, "with_input {wapart:e}");
}

/// f32 works through the same code: Van Loan of a Singer model in f32 equals the f64
/// result to 1e-5 relative (f32 eps 1.2e-7 times the exponential's growth).
#[test]
fn single_precision_van_loan_tracks_double() {
    let f = Matrix3::new(0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, -0.5);
    let mut d = Matrix3::zeros();
    d[(2, 2)] = 0.09;
    let ours = van_loan(&f, &d, 0.2).unwrap();
    let single = van_loan(&f.cast::<f32>(), &d.cast::<f32>(), 0.2f32).unwrap();
    let e = rel_err(
        &dm(&single.process_noise.cast::<f64>()),
        &dm(&ours.process_noise),
    );
    println!("f32 Van Loan: rel diff {e:e}");
    assert!(e < 1e-5);
}

// ---------------------------------------------------------------- filterpy

struct Row {
    kind: String,
    dim: usize,
    block: usize,
    by_dim: bool,
    dt: f64,
    scale: f64,
    entries: Vec<f64>,
}

fn filterpy_rows() -> Vec<Row> {
    let text = include_str!("data/filterpy_process_noise.csv");
    text.lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with("kind"))
        .map(|line| {
            let cells: Vec<&str> = line.split(',').collect();
            let num = |i: usize| cells[i].parse::<f64>().unwrap();
            Row {
                kind: cells[0].to_string(),
                dim: cells[2].parse().unwrap(),
                block: cells[3].parse().unwrap(),
                by_dim: cells[4] == "1",
                dt: num(5),
                scale: num(6),
                entries: cells[7..].iter().map(|c| c.parse().unwrap()).collect(),
            }
        })
        .collect()
}

/// Row-major entries to a dynamic matrix.
fn row_major(entries: &[f64], n: usize) -> DMatrix<f64> {
    DMatrix::from_row_slice(n, n, entries)
}

/// Our Q for a chain row: order N, S = N block_size states.
fn chain_q<const N: usize, const S: usize>(row: &Row) -> DMatrix<f64> {
    let axis = if row.kind == "discrete" {
        discrete_white_noise::<f64, N>(row.dt, row.scale).unwrap()
    } else {
        continuous_white_noise::<f64, N>(row.dt, row.scale).unwrap()
    };
    let layout = if row.by_dim {
        AxisLayout::ByAxis
    } else {
        AxisLayout::ByDerivative
    };
    dm(&independent_axes::<f64, N, S>(&axis, layout).unwrap())
}

fn van_loan_row<const N: usize>(row: &Row) -> (f64, f64) {
    let m = N * N;
    let f = SMatrix::<f64, N, N>::from_row_slice(&row.entries[..m]);
    let d = SMatrix::<f64, N, N>::from_row_slice(&row.entries[m..2 * m]);
    let model = van_loan(&f, &d, row.dt).unwrap();
    (
        rel_err(
            &dm(&model.transition),
            &row_major(&row.entries[2 * m..3 * m], N),
        ),
        rel_err(
            &dm(&model.process_noise),
            &row_major(&row.entries[3 * m..], N),
        ),
    )
}

/// Every filterpy row: Q_discrete_white_noise and Q_continuous_white_noise (dims 2..4,
/// dt 0.01..2.5, block_size 1, 2, 3, both state orders) equal ours to 1e-12 relative
/// in every entry (zeros exactly); van_loan_discretization's Phi and Q (scipy's expm)
/// equal ours (nalgebra's exp) to 1e-12 max-norm relative.
#[test]
fn equals_filterpy() {
    let rows = filterpy_rows();
    let (mut chain, mut phi, mut q) = (0.0f64, 0.0f64, 0.0f64);
    let (mut n_chain, mut n_van_loan, mut n_blocks) = (0, 0, 0);
    for row in &rows {
        if row.kind == "van_loan" {
            let (ep, eq) = match row.dim {
                2 => van_loan_row::<2>(row),
                3 => van_loan_row::<3>(row),
                4 => van_loan_row::<4>(row),
                d => panic!("no van_loan case of size {d}"),
            };
            phi = phi.max(ep);
            q = q.max(eq);
            n_van_loan += 1;
            continue;
        }
        let ours = match (row.dim, row.block) {
            (2, 1) => chain_q::<2, 2>(row),
            (2, 2) => chain_q::<2, 4>(row),
            (2, 3) => chain_q::<2, 6>(row),
            (3, 1) => chain_q::<3, 3>(row),
            (3, 2) => chain_q::<3, 6>(row),
            (3, 3) => chain_q::<3, 9>(row),
            (4, 1) => chain_q::<4, 4>(row),
            (4, 2) => chain_q::<4, 8>(row),
            (4, 3) => chain_q::<4, 12>(row),
            other => panic!("no chain case {other:?}"),
        };
        let n = row.dim * row.block;
        chain = chain.max(entrywise_rel(&ours, &row_major(&row.entries, n)));
        n_chain += 1;
        n_blocks += usize::from(row.block > 1);
    }
    println!(
        "filterpy: {n_chain} chain rows ({n_blocks} blocked) max entrywise rel diff {chain:e}; \
         {n_van_loan} Van Loan rows: Phi {phi:e}, Q {q:e}"
    );
    assert_eq!((n_chain, n_blocks, n_van_loan), (96, 48, 4));
    assert!(chain < 1e-12, "chain {chain:e}");
    assert!(phi < 1e-12, "Phi {phi:e}");
    assert!(q < 1e-12, "Q {q:e}");
}

// ---------------------------------------------------------------- errors

fn is_param(r: Result<impl std::fmt::Debug, Error>, want: &str) -> bool {
    matches!(r, Err(Error::InvalidParameter { name, .. }) if name == want)
}

fn is_covariance(r: Result<impl std::fmt::Debug, Error>) -> bool {
    matches!(r, Err(Error::InvalidCovariance { .. }))
}

/// dt = 0, negative, NaN, infinite; negative or NaN variance and spectral density;
/// orders outside the model's range; a state size that is not a multiple of the
/// axis size: each a typed error naming the parameter.
#[test]
fn bad_parameters_are_typed_errors() {
    let f = Matrix2::new(0.0, 1.0, 0.0, 0.0);
    let d = Matrix2::new(0.0, 0.0, 0.0, 1.0);
    for dt in [0.0, -0.1, f64::NAN, f64::INFINITY, -0.0] {
        assert!(is_param(discrete_white_noise::<f64, 2>(dt, 1.0), "dt"));
        assert!(is_param(continuous_white_noise::<f64, 3>(dt, 1.0), "dt"));
        assert!(is_param(integrator_chain_transition::<f64, 2>(dt), "dt"));
        assert!(is_param(van_loan(&f, &d, dt), "dt"));
    }
    for bad in [-1e-3, f64::NAN, f64::NEG_INFINITY] {
        assert!(is_param(
            discrete_white_noise::<f64, 3>(0.1, bad),
            "variance"
        ));
        assert!(is_param(
            continuous_white_noise::<f64, 2>(0.1, bad),
            "spectral_density"
        ));
    }
    // Zero variance is a valid (noise-free) model.
    assert_eq!(
        discrete_white_noise::<f64, 2>(0.1, 0.0).unwrap(),
        Matrix2::zeros()
    );
    assert!(is_param(discrete_white_noise::<f64, 1>(0.1, 1.0), "N"));
    assert!(is_param(discrete_white_noise::<f64, 5>(0.1, 1.0), "N"));
    assert!(is_param(continuous_white_noise::<f64, 0>(0.1, 1.0), "N"));
    let q = discrete_white_noise::<f64, 2>(0.1, 1.0).unwrap();
    assert!(matches!(
        independent_axes::<f64, 2, 5>(&q, AxisLayout::ByAxis),
        Err(Error::Dimension {
            expected: 6,
            got: 5,
            ..
        })
    ));
}

/// G Qc G' asymmetric, indefinite, a covariance beside a zero variance, NaN; NaN in F;
/// Qc indefinite given apart; a stiff F whose e^{-F dt} block overflows; an F dt so
/// large the exponential's norm estimates would overflow: each a typed error. Round-off
/// asymmetry and a round-off negative eigenvalue are accepted.
#[test]
fn bad_models_are_typed_errors() {
    let f = Matrix2::new(0.0, 1.0, -2.0, -0.3);
    let asymmetric = Matrix2::new(1.0, 0.5, 0.4, 1.0);
    let indefinite = Matrix2::new(1.0, 2.0, 2.0, 1.0);
    let beside_zero = Matrix2::new(0.0, 1e-3, 1e-3, 1.0);
    for bad in [asymmetric, indefinite, beside_zero] {
        assert!(is_covariance(van_loan(&f, &bad, 0.1)));
        assert!(is_covariance(van_loan_with_input(
            &f,
            &Matrix2::identity(),
            &bad,
            0.1
        )));
    }
    let mut nan = Matrix2::identity();
    nan[(0, 1)] = f64::NAN;
    assert!(matches!(
        van_loan(&f, &nan, 0.1),
        Err(Error::NonFinite { .. })
    ));
    assert!(matches!(
        van_loan(&nan, &Matrix2::identity(), 0.1),
        Err(Error::NonFinite { .. })
    ));
    assert!(matches!(
        van_loan_with_input(&f, &nan, &Matrix2::identity(), 0.1),
        Err(Error::NonFinite { .. })
    ));
    // Stiff and stable: e^{-F dt} = e^{1000} overflows.
    let stiff = Matrix2::identity() * -1000.0;
    assert!(matches!(
        van_loan(&stiff, &Matrix2::identity(), 1.0),
        Err(Error::NonFinite {
            what: "Van Loan exponential"
        })
    ));
    assert!(is_param(
        van_loan(&(Matrix2::identity() * 1e300), &Matrix2::identity(), 1.0),
        "F dt"
    ));
    // Round-off: asymmetry of 1e-15 relative and a rank-1 density with an eigenvalue
    // of -1e-17 pass.
    let mut near = Matrix2::new(1.0, 1.0, 1.0, 1.0);
    near[(0, 1)] += 1e-15;
    near[(1, 1)] -= 1e-16;
    let model = van_loan(&f, &near, 0.1).unwrap();
    assert_eq!(model.process_noise, model.process_noise.transpose());
}
