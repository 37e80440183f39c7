//! Helpers shared by the integration tests: random well-conditioned systems and
//! independently coded references (dynamic matrices, plain formulas, LU inverses),
//! never the update under test.
#![allow(dead_code)]

use estim_core::nalgebra::{DMatrix, DVector, SMatrix, SVector};

/// Static to dynamic matrix.
pub fn dm<const R: usize, const C: usize>(m: &SMatrix<f64, R, C>) -> DMatrix<f64> {
    DMatrix::from_column_slice(R, C, m.as_slice())
}

/// Static to dynamic vector.
pub fn dv<const R: usize>(v: &SVector<f64, R>) -> DVector<f64> {
    DVector::from_column_slice(v.as_slice())
}

/// ||a - b||_max / max(||b||_max, floor).
pub fn rel_err(a: &DMatrix<f64>, b: &DMatrix<f64>) -> f64 {
    assert_eq!(a.shape(), b.shape());
    let scale = b.amax().max(f64::MIN_POSITIVE);
    (a - b).amax() / scale
}

/// Inverse by LU (a different factorisation from the Cholesky used in the crate).
pub fn inv(m: &DMatrix<f64>) -> DMatrix<f64> {
    m.clone().lu().try_inverse().expect("reference inverse")
}

/// Smallest eigenvalue of the symmetric part.
pub fn min_eig(m: &DMatrix<f64>) -> f64 {
    let s = (m + m.transpose()) * 0.5;
    s.symmetric_eigenvalues().min()
}

/// Consumes a slice of numbers in [-1, 1] to build matrices.
pub struct Entries<'a> {
    values: &'a [f64],
    at: usize,
}

impl<'a> Entries<'a> {
    pub fn new(values: &'a [f64]) -> Self {
        Self { values, at: 0 }
    }

    pub fn take(&mut self, n: usize) -> &'a [f64] {
        let s = &self.values[self.at..self.at + n];
        self.at += n;
        s
    }

    pub fn mat<const R: usize, const C: usize>(&mut self) -> SMatrix<f64, R, C> {
        SMatrix::from_column_slice(self.take(R * C))
    }

    pub fn dmat(&mut self, r: usize, c: usize) -> DMatrix<f64> {
        DMatrix::from_column_slice(r, c, self.take(r * c))
    }
}

/// Numbers a random system of `n` states and `m` measurements consumes.
pub const fn entries_len(n: usize, m: usize) -> usize {
    3 * n * n + (n + m) * (n + m) + m * n + 2 * n + 4 * m
}

/// A random linear system with correlated noise:
/// x_k = F x_{k-1} + G w, y_k = H x_k + v, [w; v] ~ N(0, J), J well conditioned.
#[derive(Debug, Clone)]
pub struct System<const N: usize, const M: usize> {
    pub f: SMatrix<f64, N, N>,
    pub g: SMatrix<f64, N, N>,
    /// Cov(w).
    pub qw: SMatrix<f64, N, N>,
    /// Cov(v).
    pub r: SMatrix<f64, M, M>,
    /// Cov(w, v).
    pub c: SMatrix<f64, N, M>,
    pub h: SMatrix<f64, M, N>,
    pub x0: SVector<f64, N>,
    pub p0: SMatrix<f64, N, N>,
    /// Measurements for up to 4 steps.
    pub ys: [SVector<f64, M>; 4],
}

impl<const N: usize, const M: usize> System<N, M> {
    pub fn from_entries(values: &[f64]) -> Self {
        let mut e = Entries::new(values);
        let a: SMatrix<f64, N, N> = e.mat();
        let f = SMatrix::<f64, N, N>::identity() * 0.9 + a * 0.3;
        let b: SMatrix<f64, N, N> = e.mat();
        let p0 = b * b.transpose() / N as f64 + SMatrix::<f64, N, N>::identity() * 0.5;
        let gr: SMatrix<f64, N, N> = e.mat();
        let g = SMatrix::<f64, N, N>::identity() + gr * 0.3;
        let k = N + M;
        let bj = e.dmat(k, k);
        let j = &bj * bj.transpose() / k as f64 + DMatrix::<f64>::identity(k, k) * 0.2;
        let qw = SMatrix::<f64, N, N>::from_fn(|r, c| j[(r, c)]);
        let r = SMatrix::<f64, M, M>::from_fn(|r, c| j[(N + r, N + c)]);
        let c = SMatrix::<f64, N, M>::from_fn(|r, c| j[(r, N + c)]);
        let h: SMatrix<f64, M, N> = e.mat();
        let x0: SVector<f64, N> = e.mat();
        let _spare: SVector<f64, N> = e.mat();
        let ys = [e.mat(), e.mat(), e.mat(), e.mat()];
        let ys = ys.map(|y: SVector<f64, M>| y * 3.0);
        Self {
            f,
            g,
            qw,
            r,
            c,
            h,
            x0,
            p0,
            ys,
        }
    }

    /// Cov(G w), state space.
    pub fn qd(&self) -> SMatrix<f64, N, N> {
        self.g * self.qw * self.g.transpose()
    }

    /// M = Cov(G w, v).
    pub fn m(&self) -> SMatrix<f64, N, M> {
        self.g * self.c
    }
}

/// Reference: `steps` x (predict, update with ys[k]) with constant M, covariance
/// form, LU inverse of S.
pub fn reference<const N: usize, const M: usize>(
    sys: &System<N, M>,
    steps: usize,
) -> (DMatrix<f64>, DMatrix<f64>) {
    let (f, h, r, m, qd) = (
        dm(&sys.f),
        dm(&sys.h),
        dm(&sys.r),
        dm(&sys.m()),
        dm(&sys.qd()),
    );
    let mut x = DMatrix::from_column_slice(N, 1, sys.x0.as_slice());
    let mut p = dm(&sys.p0);
    for y in sys.ys.iter().take(steps) {
        x = &f * &x;
        p = &f * &p * f.transpose() + &qd;
        let s = &h * &p * h.transpose() + &h * &m + m.transpose() * h.transpose() + &r;
        let k = (&p * h.transpose() + &m) * inv(&s);
        let y = DMatrix::from_column_slice(M, 1, y.as_slice());
        x = &x + &k * (y - &h * &x);
        p = &p - &k * (&h * &p + m.transpose());
    }
    (x, p)
}
