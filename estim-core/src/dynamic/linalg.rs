//! Dense helpers of the run-time-sized filter, on `DMatrix<f64>` workspaces that the
//! caller allocated once: Cholesky of S with its inverse and log-determinant, the
//! conditioning test of S, the LDL' certificate of a correlation matrix and the
//! covariance checks. Each mirrors its static counterpart in `crate::linalg` /
//! `crate::update` / `crate::cross` (same rule, same tolerance), written for sizes
//! known only at run time.

use nalgebra::{DMatrix, DVector};

use crate::linalg::cholesky::Square;
use crate::update::RCOND_FLOOR;
use crate::{Error, Result};

impl Square<f64> for DMatrix<f64> {
    #[inline(always)]
    fn value(&self, i: usize, k: usize) -> f64 {
        self[(i, k)]
    }
    #[inline(always)]
    fn set(&mut self, i: usize, k: usize, v: f64) {
        self[(i, k)] = v;
    }
}

/// The tolerance of the joint check and of the covariance checks (the static core's
/// `relative_tolerance`, 9.3e-10 in f64).
pub(crate) fn relative_tolerance() -> f64 {
    crate::scalar::relative_tolerance::<f64>()
}

/// Fail with [`Error::NonFinite`] naming `what` if a value is NaN or infinite.
pub(crate) fn check_finite(values: &[f64], what: &'static str) -> Result<()> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(Error::NonFinite { what })
    }
}

/// Fail with [`Error::Dimension`] unless `got == expected`.
pub(crate) fn check_size(what: &'static str, expected: usize, got: usize) -> Result<()> {
    if expected == got {
        Ok(())
    } else {
        Err(Error::Dimension {
            what,
            expected,
            got,
        })
    }
}

/// Replace `a` by (a + a') / 2 (exactly symmetric).
pub(crate) fn symmetrize_in_place(a: &mut DMatrix<f64>) {
    let n = a.nrows();
    for j in 0..n {
        for i in 0..j {
            let v = (a[(i, j)] + a[(j, i)]) * 0.5;
            a[(i, j)] = v;
            a[(j, i)] = v;
        }
    }
}

/// Copy the upper triangle of `a` onto its lower one (the result of products that
/// computed only the upper triangle of a symmetric matrix).
pub(crate) fn mirror_upper(a: &mut DMatrix<f64>) {
    let n = a.nrows();
    for j in 0..n {
        for i in 0..j {
            a[(j, i)] = a[(i, j)];
        }
    }
}

/// S^-1 and ln det S of a symmetric positive definite `s` through its Cholesky factor
/// (Golub & Van Loan, 4th ed., alg. 4.2.1), written into `inverse`, with `factor` as
/// scratch (both m x m, preallocated). `None` when a pivot is not positive (S not
/// positive definite).
pub(crate) fn spd_inverse_log_det_into(
    s: &DMatrix<f64>,
    factor: &mut DMatrix<f64>,
    inverse: &mut DMatrix<f64>,
) -> Option<f64> {
    let m = s.nrows();
    factor.fill(0.0);
    let mut log_det = 0.0;
    for j in 0..m {
        let mut d = s[(j, j)];
        for k in 0..j {
            d -= factor[(j, k)] * factor[(j, k)];
        }
        if d <= 0.0 || !d.is_finite() {
            return None;
        }
        let ljj = d.sqrt();
        log_det += d.ln();
        factor[(j, j)] = ljj;
        let r = 1.0 / ljj;
        for i in (j + 1)..m {
            let mut v = s[(i, j)];
            for k in 0..j {
                v -= factor[(i, k)] * factor[(j, k)];
            }
            factor[(i, j)] = v * r;
        }
    }
    // W = L^-1 in the upper triangle of `inverse` (transposed), then S^-1 = W' W.
    // Forward substitution column by column: W is lower triangular; stored in
    // `inverse` as its transpose so the final product reads contiguous columns.
    inverse.fill(0.0);
    for j in 0..m {
        inverse[(j, j)] = 1.0 / factor[(j, j)];
        for i in (j + 1)..m {
            let mut v = 0.0;
            for k in j..i {
                v -= factor[(i, k)] * inverse[(j, k)];
            }
            inverse[(j, i)] = v / factor[(i, i)];
        }
    }
    // inverse holds W' (upper triangular): W'[j, i] = W[i, j]. S^-1 = W' W:
    // (S^-1)[a, b] = sum_k W[k, a] W[k, b] = sum_k W'[a, k] W'[b, k], k >= max(a, b).
    // Into `factor` (no longer needed), then copied back.
    for b in 0..m {
        for a in 0..=b {
            let mut v = 0.0;
            for k in b..m {
                v += inverse[(a, k)] * inverse[(b, k)];
            }
            factor[(a, b)] = v;
            factor[(b, a)] = v;
        }
    }
    inverse.copy_from(factor);
    Some(log_det)
}

/// W = L^-1 of a lower-triangular L (read: its lower triangle and diagonal; the
/// upper triangle may hold anything), written into `w` (lower triangular, upper
/// triangle zero), by forward substitution column by column in axpy form (contiguous
/// columns, vectorizable). False, with `w` partly written, when a diagonal entry is
/// not positive and finite.
pub(crate) fn lower_inverse_into(l: &DMatrix<f64>, w: &mut DMatrix<f64>) -> bool {
    let n = l.nrows();
    let ld = l.as_slice();
    w.fill(0.0);
    for j in 0..n {
        let column = &mut w.as_mut_slice()[j * n..(j + 1) * n];
        column[j] = 1.0;
        for k in j..n {
            let diagonal = ld[k * n + k];
            if !(diagonal > 0.0 && diagonal.is_finite()) {
                return false;
            }
            let xk = column[k] / diagonal;
            column[k] = xk;
            let below = &ld[k * n + k + 1..(k + 1) * n];
            for (x, li) in column[k + 1..].iter_mut().zip(below) {
                *x -= li * xk;
            }
        }
    }
    true
}

/// The static core's conditioning test of S (`crate::update`), for any size: the
/// reciprocal 1-norm condition number of the correlation matrix of S must be above
/// 1000 eps, else [`Error::InnovationIllConditioned`]. One measurement passes.
pub(crate) fn check_innovation_conditioning(
    s: &DMatrix<f64>,
    inverse: &DMatrix<f64>,
) -> Result<()> {
    let m = s.nrows();
    if m == 1 {
        return Ok(());
    }
    let floor = f64::EPSILON * RCOND_FLOOR;
    let (mut norm_c, mut norm_c_inv) = (0.0f64, 0.0f64);
    for j in 0..m {
        let (mut col_c, mut col_c_inv) = (0.0, 0.0);
        for i in 0..m {
            let sd = s[(i, i)].sqrt();
            col_c += s[(i, j)].abs() / sd;
            col_c_inv += inverse[(i, j)].abs() * sd;
        }
        let sdj = s[(j, j)].sqrt();
        norm_c = norm_c.max(col_c / sdj);
        norm_c_inv = norm_c_inv.max(col_c_inv * sdj);
    }
    let product = norm_c * norm_c_inv;
    if !(product.is_finite() && product > 0.0 && product * floor < 1.0) {
        return Err(Error::InnovationIllConditioned {
            reciprocal_condition: 1.0 / product,
        });
    }
    Ok(())
}

/// 1/sqrt(d), or 1 where d <= 0 (a zero variance: left unscaled).
fn inverse_sqrt_or_one(d: f64) -> f64 {
    if d > 0.0 {
        1.0 / d.sqrt()
    } else {
        1.0
    }
}

/// The LDL' certificate of `crate::linalg::ldl` on the upper triangle of the
/// unit-diagonal `c` (n x n, overwritten): true when it certifies C positive
/// semidefinite to `tol`, with every pivot folded into `smallest`. Rows `0..coupled`
/// are eliminated only up to `coupled` when `decoupled` (block-diagonal C).
pub(crate) fn certify(
    c: &mut DMatrix<f64>,
    coupled: usize,
    decoupled: bool,
    tol: f64,
    smallest: &mut f64,
) -> bool {
    let n = c.nrows();
    for k in 0..n {
        let d = c[(k, k)];
        *smallest = smallest.min(d);
        if d > tol {
            let inv = 1.0 / d;
            let end = if decoupled && k < coupled { coupled } else { n };
            for j in (k + 1)..end {
                let f = c[(k, j)] * inv;
                for i in (k + 1)..=j {
                    let v = c[(k, i)] * f;
                    c[(i, j)] -= v;
                }
            }
        } else if d < -tol || ((k + 1)..n).any(|j| c[(k, j)].abs() > tol) {
            return false;
        }
    }
    true
}

/// Write the correlation matrix of `a` (triangles averaged, zero variances unscaled)
/// into `out` at offset (`at`, `at`); returns nothing, scales in `scale[at..]`.
fn correlation_block(
    a: &DMatrix<f64>,
    out: &mut DMatrix<f64>,
    at: usize,
    scale: &mut DVector<f64>,
) {
    let n = a.nrows();
    for i in 0..n {
        scale[at + i] = inverse_sqrt_or_one(a[(i, i)]);
    }
    for j in 0..n {
        for i in 0..=j {
            let v = (a[(i, j)] + a[(j, i)]) * 0.5 * scale[at + i] * scale[at + j];
            out[(at + i, at + j)] = v;
            out[(at + j, at + i)] = v;
        }
    }
}

/// The LDL' certificate of one symmetric block's correlation matrix (its smallest
/// pivot, unclamped), or `None` when it does not certify. Allocates (construction
/// and model changes only).
pub(crate) fn block_certificate(a: &DMatrix<f64>) -> Option<f64> {
    let n = a.nrows();
    let mut c = DMatrix::zeros(n, n);
    let mut scale = DVector::zeros(n);
    correlation_block(a, &mut c, 0, &mut scale);
    let mut smallest = 1.0;
    certify(&mut c, n, false, relative_tolerance(), &mut smallest).then_some(smallest)
}

/// Preallocated scratch of the joint check: the (n+m)-square correlation matrix and
/// its scaling.
#[derive(Debug, Clone)]
pub(crate) struct JointScratch {
    correlation: DMatrix<f64>,
    scale: DVector<f64>,
    /// n x n: Q_acc's block certificate with M = 0.
    block: DMatrix<f64>,
}

impl JointScratch {
    pub(crate) fn new(n: usize, m: usize) -> Self {
        Self {
            correlation: DMatrix::zeros(n + m, n + m),
            scale: DVector::zeros(n + m),
            block: DMatrix::zeros(n, n),
        }
    }
}

/// The static core's `JointCovariance::validity_margin` of [[Q, M], [M', R]] for
/// run-time sizes: the smallest LDL' pivot of the joint correlation matrix, clamped
/// at 0, when its certificate holds (no allocation); else the smallest eigenvalue of
/// that matrix (allocates: invalid or too close to call), or -1 when a zero variance
/// of Q or R has a nonzero entry of M. `known_noise` / `known_measurement`: the
/// block certificates of Q and R when already known (used with M absent).
pub(crate) fn joint_validity_margin(
    q: &DMatrix<f64>,
    cross: Option<&DMatrix<f64>>,
    r: &DMatrix<f64>,
    known_noise: Option<Option<f64>>,
    known_measurement: Option<Option<f64>>,
    scratch: &mut JointScratch,
) -> Result<f64> {
    let (n, m) = (q.nrows(), r.nrows());
    let tol = relative_tolerance();
    let cross = cross.filter(|c| c.iter().any(|v| *v != 0.0));
    let Some(cross) = cross else {
        let noise = match known_noise {
            Some(known) => known,
            None => {
                check_finite(q.as_slice(), "accumulated process noise")?;
                let JointScratch { block, scale, .. } = scratch;
                correlation_block(q, block, 0, scale);
                let mut smallest = 1.0;
                certify(block, n, false, tol, &mut smallest).then_some(smallest)
            }
        };
        let measurement = match known_measurement {
            Some(known) => known,
            None => {
                check_finite(r.as_slice(), "measurement noise")?;
                block_certificate(r)
            }
        };
        return match (noise, measurement) {
            (Some(a), Some(c)) => Ok(a.min(c).max(0.0)),
            _ => joint_min_correlation_eigenvalue(q, None, r),
        };
    };
    check_finite(q.as_slice(), "accumulated process noise")?;
    check_finite(cross.as_slice(), "cross-covariance")?;
    check_finite(r.as_slice(), "measurement noise")?;
    let zero_variance_correlated = (0..n)
        .any(|i| q[(i, i)] <= 0.0 && (0..m).any(|j| cross[(i, j)] != 0.0))
        || (0..m).any(|j| r[(j, j)] <= 0.0 && (0..n).any(|i| cross[(i, j)] != 0.0));
    if zero_variance_correlated {
        return Ok(-1.0);
    }
    let JointScratch {
        correlation, scale, ..
    } = scratch;
    correlation_block(q, correlation, 0, scale);
    // R's block at (n, n): through a view-free copy of the same rule.
    for i in 0..m {
        scale[n + i] = inverse_sqrt_or_one(r[(i, i)]);
    }
    for j in 0..m {
        for i in 0..=j {
            let v = (r[(i, j)] + r[(j, i)]) * 0.5 * scale[n + i] * scale[n + j];
            correlation[(n + i, n + j)] = v;
            correlation[(n + j, n + i)] = v;
        }
    }
    for j in 0..m {
        for i in 0..n {
            let v = cross[(i, j)] * scale[i] * scale[n + j];
            correlation[(i, n + j)] = v;
            correlation[(n + j, i)] = v;
        }
    }
    let mut smallest = 1.0;
    if certify(correlation, n, false, tol, &mut smallest) {
        Ok(smallest.max(0.0))
    } else {
        joint_min_correlation_eigenvalue(q, Some(cross), r)
    }
}

/// Smallest eigenvalue of the joint correlation matrix (allocates; the cold path).
fn joint_min_correlation_eigenvalue(
    q: &DMatrix<f64>,
    cross: Option<&DMatrix<f64>>,
    r: &DMatrix<f64>,
) -> Result<f64> {
    let (n, m) = (q.nrows(), r.nrows());
    let mut j = DMatrix::zeros(n + m, n + m);
    j.view_mut((0, 0), (n, n)).copy_from(q);
    j.view_mut((n, n), (m, m)).copy_from(r);
    if let Some(c) = cross {
        j.view_mut((0, n), (n, m)).copy_from(c);
        j.view_mut((n, 0), (m, n)).copy_from(&c.transpose());
    }
    let scale: Vec<f64> = (0..n + m).map(|i| inverse_sqrt_or_one(j[(i, i)])).collect();
    let c = DMatrix::from_fn(n + m, n + m, |a, b| {
        (j[(a, b)] + j[(b, a)]) * 0.5 * scale[a] * scale[b]
    });
    let smallest = c.symmetric_eigenvalues().min();
    if smallest.is_finite() {
        Ok(smallest)
    } else {
        Err(Error::Overflow {
            what: "smallest eigenvalue of the joint covariance",
        })
    }
}

/// What a covariance given to the filter must be (the static `check_covariance`):
/// finite, symmetric to round-off and positive semidefinite to the relative tolerance
/// (certificate, then an eigen decomposition where it does not certify). Allocates.
pub(crate) fn check_covariance(a: &DMatrix<f64>, what: &'static str) -> Result<()> {
    check_finite(a.as_slice(), what)?;
    crate::gaussian::check_symmetric_entries(a.nrows(), |i, j| a[(i, j)], what)?;
    let n = a.nrows();
    // As the static check: a negative variance shows as -1 on the diagonal.
    let scale: Vec<f64> = (0..n)
        .map(|i| {
            let d = a[(i, i)].abs();
            if d > 0.0 {
                1.0 / d.sqrt()
            } else {
                1.0
            }
        })
        .collect();
    let c = DMatrix::from_fn(n, n, |i, j| {
        (a[(i, j)] + a[(j, i)]) * 0.5 * scale[i] * scale[j]
    });
    let tol = relative_tolerance();
    let mut certified = c.clone();
    let mut smallest = 1.0;
    if certify(&mut certified, n, false, tol, &mut smallest) {
        return Ok(());
    }
    let eigenvalue = c.symmetric_eigenvalues().min();
    if eigenvalue >= -tol {
        Ok(())
    } else {
        Err(Error::InvalidCovariance {
            what,
            reason: format!(
                "not positive semidefinite (smallest eigenvalue of its correlation matrix {eigenvalue:e}, tolerance -{tol:e})"
            ),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// L^-1 by forward substitution times L is the identity (to round-off), for the
    /// Cholesky factors of random SPD matrices of 1..40 rows; a zero pivot refuses.
    #[test]
    fn lower_inverse_inverts() {
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        for n in [1, 2, 5, 17, 40] {
            let g = DMatrix::from_fn(n, n, |_, _| rng.random_range(-1.0..1.0));
            let p = &g * g.transpose() + DMatrix::identity(n, n) * 0.5;
            let l = p.cholesky().unwrap().l();
            let mut w = DMatrix::from_element(n, n, f64::NAN);
            assert!(lower_inverse_into(&l, &mut w));
            assert!((&w * &l - DMatrix::identity(n, n)).amax() < 1e-12, "n {n}");
            assert!((0..n).all(|j| (0..j).all(|i| w[(i, j)] == 0.0)));
        }
        let singular = DMatrix::from_row_slice(2, 2, &[1.0, 0.0, 1.0, 0.0]);
        assert!(!lower_inverse_into(&singular, &mut DMatrix::zeros(2, 2)));
    }

    /// S^-1 and ln det S from the workspace Cholesky equal nalgebra's LU inverse and
    /// determinant (an independent factorisation) on random SPD matrices of 1..12 rows.
    #[test]
    fn spd_inverse_and_log_det_equal_lu() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for m in 1..=12 {
            let g = DMatrix::from_fn(m, m, |_, _| rng.random_range(-1.0..1.0));
            let s = &g * g.transpose() + DMatrix::identity(m, m) * 0.1;
            let (mut factor, mut inverse) = (DMatrix::zeros(m, m), DMatrix::zeros(m, m));
            let log_det = spd_inverse_log_det_into(&s, &mut factor, &mut inverse).unwrap();
            let lu = s.clone().lu();
            let reference = lu.try_inverse().unwrap();
            assert!(
                (&inverse - &reference).amax() <= 1e-10 * reference.amax(),
                "m {m}"
            );
            assert!(
                (log_det - s.clone().lu().determinant().ln()).abs() < 1e-10,
                "m {m}"
            );
            assert_eq!(inverse, inverse.transpose());
        }
        let not_pd = DMatrix::from_row_slice(2, 2, &[1.0, 2.0, 2.0, 1.0]);
        let (mut f, mut i) = (DMatrix::zeros(2, 2), DMatrix::zeros(2, 2));
        assert!(spd_inverse_log_det_into(&not_pd, &mut f, &mut i).is_none());
    }
}
