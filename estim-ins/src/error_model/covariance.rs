//! P' = Phi P Phi' + Q and Phi_later Phi_earlier from the block structure of the model's
//! Phi: the math of the covariance kernels, generic over how a multiply-add rounds (the
//! builds are in [`super::builds`]).

use super::ErrorMatrix;
use crate::kernel::MultiplyAdd;
#[cfg(doc)]
use crate::kernel::Separate;
use crate::state::{ACC_BIAS, ERROR_STATES, GYRO_BIAS, POS, VEL};

/// Structure check used by the structured covariance propagation: Phi's bias rows are
/// diagonal and its position x gyro-bias block is zero (both hold for
/// [`InsErrorModel::transition_and_noise`](super::InsErrorModel::transition_and_noise);
/// anything else takes the dense path).
#[inline]
pub(super) fn has_model_structure(phi: &ErrorMatrix) -> bool {
    for r in ACC_BIAS..ERROR_STATES {
        for c in 0..ERROR_STATES {
            if r != c && phi[(r, c)] != 0.0 {
                return false;
            }
        }
    }
    for r in POS..VEL {
        for c in GYRO_BIAS..ERROR_STATES {
            if phi[(r, c)] != 0.0 {
                return false;
            }
        }
    }
    true
}

/// Phi_later Phi_earlier for a `later` of the model's structure (checked by
/// [`has_model_structure`]): its bias rows are diagonal, so the bias rows of the product
/// are those of `earlier` scaled (6 x 15 multiplies), and its position x gyro-bias block
/// is zero. The navigation rows are the dense sums, term by term in the order of the
/// dense product (so the same values): 1,980 multiply-adds instead of 3,375. Its builds
/// ([`super::builds`]) use [`Separate`] only, for those values.
#[inline(always)]
pub(super) fn compose_structured<M: MultiplyAdd>(
    later: &[[f64; ERROR_STATES]; ERROR_STATES],
    earlier: &[[f64; ERROR_STATES]; ERROR_STATES],
) -> ErrorMatrix {
    let mut out = ErrorMatrix::zeros();
    for (column, earlier_column) in out.data.0.iter_mut().zip(earlier) {
        let navigation = navigation_column::<M, NAV>(later, |k| earlier_column[k]);
        column[..NAV].copy_from_slice(&navigation);
        for r in NAV..ERROR_STATES {
            column[r] = later[r][r] * earlier_column[r];
        }
    }
    out
}

/// Navigation rows (position, velocity, misalignment) of the error state.
pub(super) const NAV: usize = 9;

/// P' = Phi P Phi' + Q for a Phi of the model's structure (checked by
/// [`has_model_structure`]):
///
/// ```text
/// Phi = [ N_nav (9x9)   N_bias (9x6) ]     N_bias's position/gyro-bias block is zero,
///       [ 0             D (6x6 diag) ]     D = diag(d) (first-order Gauss-Markov decay)
/// ```
///
/// With Y = P N' (15 x 9, N = the nine navigation rows of Phi):
///
/// - navigation block  (Phi P Phi')[i, j]       = N[i, :] Y[:, j]   (upper half only),
/// - bias x navigation (Phi P Phi')[9 + b, j]   = d_b Y[9 + b, j],
/// - bias block        (Phi P Phi')[9 + a, 9 + b] = d_a P[9 + a, 9 + b] d_b,
///
/// each of which is the dense product with the zero blocks left out; the lower triangle is
/// mirrored, so the result is exactly symmetric (Q's two triangles are averaged, as in
/// estim-core's runners). Cost as computed: Y 2,025 multiply-adds (225 eight-lane ones
/// down Phi's columns for the first eight navigation rows, 225 for the ninth; 135 of them
/// multiply a structural zero of Phi's position x gyro-bias block, kept so that every
/// vector has the same shape), the navigation block 1,095 (rows 0..8 of each of its nine
/// columns as one vector, where only the upper half is kept, and the corner (8, 8)), the
/// bias rows 75: about 3,200 instead of the dense 6,750 (2 x 15^3). That is more than the
/// 2,560 of a term-by-term count, but whole 8-lane vectors with no lane shuffles, which
/// measured faster (estim-ins/README.md). Loops run down contiguous columns (column-major
/// storage) so they vectorise.
///
/// In place: once Y is formed, P is read only in its bias block, each entry just before
/// it is overwritten, so the result needs no second 15 x 15 array (whose copy back cost
/// more than a tenth of the step).
#[inline(always)]
pub(super) fn propagate_structured<M: MultiplyAdd>(
    covariance: &mut [[f64; ERROR_STATES]; ERROR_STATES],
    phi: &[[f64; ERROR_STATES]; ERROR_STATES],
    q: &[[f64; ERROR_STATES]; ERROR_STATES],
) {
    propagate_upper::<M>(covariance, phi);
    // The upper triangle (out[j][i], i <= j) plus Q's mean triangle, mirrored.
    for j in 0..ERROR_STATES {
        for i in 0..=j {
            let v = covariance[j][i] + (q[j][i] + q[i][j]) * 0.5;
            covariance[j][i] = v;
            covariance[i][j] = v;
        }
    }
}

/// The upper triangle (column j, rows i <= j) of Phi P Phi' over P's, for a Phi of the
/// model's structure (see [`propagate_structured`]); the lower triangle holds scratch
/// values afterwards (both callers overwrite it with the mirror of the upper one).
#[inline(always)]
pub(super) fn propagate_upper<M: MultiplyAdd>(
    covariance: &mut [[f64; ERROR_STATES]; ERROR_STATES],
    phi: &[[f64; ERROR_STATES]; ERROR_STATES],
) {
    const N: usize = ERROR_STATES;
    // Column arrays (nalgebra stores column-major: `data.0[column][row]`), so every loop
    // below has a length known at compile time and runs down contiguous memory.
    let p = &*covariance;
    // Y = P N' (15 x 9), Y[k, j] = sum_m P[k, m] Phi[j, m] = sum_m Phi[j, m] P[m, k] (P is
    // symmetric), kept as `y[k][j]` for the first eight navigation rows j and `y_down[k]`
    // for the ninth (ψ_D). Each y[k] is a sum over m of Phi's column m (rows 0..8, one
    // 8-lane vector) times the scalar P[m, k]: the vector runs down Phi's contiguous
    // columns, with no shuffles (a sum down P's 15-row columns needs an 8-, 4-, 2- and
    // 1-lane operation, and three such sums at a time were compiled into lane
    // permutations). Every entry is summed over m in increasing order from zero.
    let mut y = [[0.0f64; 8]; N];
    for (yk, pk) in y.iter_mut().zip(p) {
        for (m, phim) in phi.iter().enumerate() {
            let w = pk[m];
            // Rows 0..3 of the gyro-bias columns of Phi are zero: adding their zero
            // products changes no value (w is finite), so the loop stays uniform.
            for (acc, f) in yk.iter_mut().zip(&phim[..8]) {
                *acc = M::multiply_add(*f, w, *acc);
            }
        }
    }
    // Y[:, 8] = sum_m Phi[8, m] P[:, m], down P's columns.
    let mut y_down = [0.0f64; N];
    for (pm, phim) in p.iter().zip(phi) {
        let w = phim[NAV - 1];
        for (acc, v) in y_down.iter_mut().zip(pm) {
            *acc = M::multiply_add(w, *v, *acc);
        }
    }
    let out = covariance;
    // Navigation block, upper half: out[i, j] = sum_k Phi[i, k] Y[k, j], i <= j, summed
    // over k in increasing order. Rows 0..8 of every column j as one 8-lane vector
    // (Phi's column k times the scalar Y[k, j]); the rows below the diagonal are
    // lower-triangle entries, which the callers overwrite with the mirror of the upper
    // triangle and nothing reads before that. Only the corner (8, 8) needs row 8.
    for j in 0..NAV {
        let mut acc = [0.0f64; 8];
        for (k, phik) in phi.iter().enumerate() {
            let w = if j < NAV - 1 { y[k][j] } else { y_down[k] };
            for (a, f) in acc.iter_mut().zip(&phik[..8]) {
                *a = M::multiply_add(*f, w, *a);
            }
        }
        out[j][..8].copy_from_slice(&acc);
    }
    out[NAV - 1][NAV - 1] = phi.iter().zip(&y_down).fold(0.0, |acc, (phik, w)| {
        M::multiply_add(phik[NAV - 1], *w, acc)
    });
    // Bias rows: d_b Y[9 + b, j] against the navigation columns, d_a P d_b among
    // themselves (column 9 + b, rows <= 9 + b of the upper triangle).
    for b in 0..(N - NAV) {
        let row = NAV + b;
        let d = phi[row][row];
        for (o, v) in out[row].iter_mut().zip(&y[row]) {
            *o = d * v;
        }
        out[row][NAV - 1] = d * y_down[row];
        for a in 0..=b {
            let col = NAV + a;
            out[row][col] = phi[col][col] * out[row][col] * d;
        }
    }
}

/// Rows 0..R of sum_k Phi[:, k] Y[k, j] (3 < R <= 9; `y_column(k)` = Y[k, j]). Rows 0..3
/// of the gyro-bias columns of Phi are zero and skipped.
#[inline(always)]
pub(super) fn navigation_column<M: MultiplyAdd, const R: usize>(
    phi: &[[f64; ERROR_STATES]; ERROR_STATES],
    y_column: impl Fn(usize) -> f64,
) -> [f64; R] {
    let mut acc = [0.0f64; R];
    for (k, phik) in phi.iter().enumerate().take(GYRO_BIAS) {
        let w = y_column(k);
        for (a, f) in acc.iter_mut().zip(&phik[..R]) {
            *a = M::multiply_add(*f, w, *a);
        }
    }
    for (k, phik) in phi.iter().enumerate().skip(GYRO_BIAS) {
        let w = y_column(k);
        for (a, f) in acc[VEL..].iter_mut().zip(&phik[VEL..R]) {
            *a = M::multiply_add(*f, w, *a);
        }
    }
    acc
}

/// Copy the upper triangle (out[j][i], i <= j) onto the lower one.
#[inline(always)]
#[allow(clippy::needless_range_loop)] // a transpose: both indices address `out`
pub(super) fn mirror_upper(out: &mut [[f64; ERROR_STATES]; ERROR_STATES]) {
    for j in 0..ERROR_STATES {
        for i in 0..j {
            out[i][j] = out[j][i];
        }
    }
}
