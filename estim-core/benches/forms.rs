//! Cost of the covariance forms of the correlated update, and of the square-root
//! and sigma-point updates beside it, at (N, M) = (4, 2), (15, 3), (30, 6).
//!
//! `cargo bench -p estim-core --bench forms` (criterion; numbers in
//! estim-core/README.md). Every case has a nonzero, valid M; random well-conditioned
//! P, H, R from a fixed seed.

use criterion::{criterion_group, criterion_main, Criterion};
use estim_core::nalgebra::{SMatrix, SVector};
use estim_core::sigma_point::{unscented_predict, unscented_update, UnscentedTransform};
use estim_core::square_root::{covariance_factor, square_root_predict, square_root_update};
use estim_core::update::correlated_update;
use estim_core::{CovarianceUpdate, StateAndCovariance};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use std::hint::black_box;

struct Case<const N: usize, const M: usize> {
    prior: StateAndCovariance<f64, N>,
    factor: SMatrix<f64, N, N>,
    f: SMatrix<f64, N, N>,
    q: SMatrix<f64, N, N>,
    q_factor: SMatrix<f64, N, N>,
    h: SMatrix<f64, M, N>,
    r: SMatrix<f64, M, M>,
    m: SMatrix<f64, N, M>,
    innovation: SVector<f64, M>,
}

fn case<const N: usize, const M: usize>() -> Case<N, M> {
    let mut rng = ChaCha8Rng::seed_from_u64(N as u64 * 100 + M as u64);
    let mut g = || -> f64 { StandardNormal.sample(&mut rng) };
    let a = SMatrix::<f64, N, N>::from_fn(|_, _| g());
    let p = a * a.transpose() / N as f64 + SMatrix::<f64, N, N>::identity();
    let p = (p + p.transpose()) * 0.5;
    let f = SMatrix::<f64, N, N>::identity() + SMatrix::<f64, N, N>::from_fn(|_, _| 0.01 * g());
    let q = SMatrix::<f64, N, N>::identity() * 1e-3;
    let h = SMatrix::<f64, M, N>::from_fn(|_, _| g());
    let r = SMatrix::<f64, M, M>::identity() * 0.5;
    let factor = covariance_factor(&p, "P").unwrap();
    // Valid M: 0.3 x (first M columns of chol(P)) chol(R)'.
    let m = SMatrix::<f64, N, M>::from_fn(|i, k| 0.3 * factor[(i, k)] * 0.5f64.sqrt());
    Case {
        prior: StateAndCovariance::new(SVector::zeros(), p).unwrap(),
        factor,
        f,
        q,
        q_factor: covariance_factor(&q, "Q").unwrap(),
        h,
        r,
        m,
        innovation: SVector::from_fn(|i, _| 0.1 * i as f64),
    }
}

fn bench_size<const N: usize, const M: usize>(c: &mut Criterion) {
    let k = case::<N, M>();
    let mut group = c.benchmark_group(format!("({N},{M})"));
    for (name, form) in [
        ("update JosephLike", CovarianceUpdate::JosephLike),
        ("update Short", CovarianceUpdate::Short),
        ("update Product", CovarianceUpdate::Product),
        ("update SquareRoot (default)", CovarianceUpdate::SquareRoot),
    ] {
        group.bench_function(name, |b| {
            b.iter(|| {
                correlated_update(
                    black_box(&k.prior),
                    black_box(&k.innovation),
                    &k.h,
                    &k.r,
                    &k.m,
                    form,
                )
                .unwrap()
            })
        });
    }
    group.bench_function("square_root_update", |b| {
        b.iter(|| {
            square_root_update(
                black_box(k.prior.state()),
                black_box(&k.factor),
                &k.innovation,
                &k.h,
                &k.r,
                &k.m,
            )
            .unwrap()
        })
    });
    group.bench_function("square_root_predict", |b| {
        b.iter(|| square_root_predict(black_box(&k.factor), &k.f, &k.q_factor).unwrap())
    });
    group.bench_function("covariance predict F P F' + Q", |b| {
        b.iter(|| {
            let p = black_box(k.prior.covariance());
            k.f * p * k.f.transpose() + k.q
        })
    });
    let ut = UnscentedTransform::default();
    group.bench_function("unscented_update (linear h)", |b| {
        b.iter(|| {
            unscented_update(
                &ut,
                black_box(&k.prior),
                &k.innovation,
                |x| Ok(k.h * x),
                &k.r,
                &k.m,
            )
            .unwrap()
        })
    });
    group.bench_function("unscented_predict (linear f)", |b| {
        b.iter(|| unscented_predict(&ut, black_box(&k.prior), |x| Ok(k.f * x), &k.q).unwrap())
    });
    group.finish();
}

fn forms(c: &mut Criterion) {
    bench_size::<4, 2>(c);
    bench_size::<15, 3>(c);
    bench_size::<30, 6>(c);
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(30)
        .warm_up_time(std::time::Duration::from_millis(500))
        .measurement_time(std::time::Duration::from_secs(2));
    targets = forms
}
criterion_main!(benches);
