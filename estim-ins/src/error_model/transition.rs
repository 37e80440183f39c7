//! Phi = I + A + A²/2, A = F dt, from the nonzero 3x3 blocks of F, and the zero patterns
//! of those blocks: the math of the transition, generic over how a multiply-add rounds
//! (the builds are in [`super::builds`]).

use nalgebra::Matrix3;

use super::covariance::NAV;
use super::{ErrorMatrix, SystemBlocks};
use crate::kernel::MultiplyAdd;
use crate::state::ERROR_STATES;

type M3 = Matrix3<f64>;

/// The nonzero blocks of A = F dt (F from `InsErrorModel::system_blocks`), by name.
/// A_pv = α I and the bias blocks k_a I, k_g I are scalar multiples of the identity.
pub(super) struct ScaledBlocks {
    pub(super) alpha: f64,
    pub(super) pp: M3,
    pub(super) vp: M3,
    pub(super) vv: M3,
    pub(super) vpsi: M3,
    pub(super) va: M3,
    pub(super) psip: M3,
    pub(super) psiv: M3,
    pub(super) psipsi: M3,
    pub(super) psig: M3,
    pub(super) ka: f64,
    pub(super) kg: f64,
}

impl ScaledBlocks {
    #[inline]
    pub(super) fn new(f: &SystemBlocks, dt: f64) -> Self {
        let rotation = -f.c_bn * dt;
        Self {
            alpha: dt,
            pp: f.pp * dt,
            vp: f.vp * dt,
            vv: f.vv * dt,
            vpsi: f.vpsi * dt,
            va: rotation,
            psip: f.psip * dt,
            psiv: f.psiv * dt,
            psipsi: f.psipsi * dt,
            psig: rotation,
            ka: f.acc_decay * dt,
            kg: f.gyro_decay * dt,
        }
    }

    /// Phi = I + A + A²/2 (see [`ScaledBlocks::write_transition`]) as a matrix.
    #[inline(always)]
    pub(super) fn transition<M: MultiplyAdd>(&self) -> ErrorMatrix {
        let mut phi = ErrorMatrix::zeros();
        self.write_transition::<M>(&mut phi.data.0);
        phi
    }

    /// A's nine navigation rows, column by column (see [`NavigationColumns`]).
    #[inline(always)]
    fn navigation_columns(&self) -> NavigationColumns {
        let mut a = NavigationColumns {
            top: [[0.0; 8]; ERROR_STATES],
            bottom: [0.0; ERROR_STATES],
        };
        let mut put = |i: usize, j: usize, b: &M3| {
            for c in 0..3 {
                for r in 0..3 {
                    let row = 3 * i + r;
                    if row < 8 {
                        a.top[3 * j + c][row] = b[(r, c)];
                    } else {
                        a.bottom[3 * j + c] = b[(r, c)];
                    }
                }
            }
        };
        put(0, 0, &self.pp);
        put(0, 1, &(M3::identity() * self.alpha));
        put(1, 0, &self.vp);
        put(1, 1, &self.vv);
        put(1, 2, &self.vpsi);
        put(1, 3, &self.va);
        put(2, 0, &self.psip);
        put(2, 1, &self.psiv);
        put(2, 2, &self.psipsi);
        put(2, 4, &self.psig);
        debug_assert!((0..ERROR_STATES)
            .all(|m| (0..NAV)
                .all(|k| A_COLUMNS[m] & (1 << k) != 0 || a.entry(k, m, [0.0; 6]) == 0.0)));
        a
    }

    /// Phi = I + A + A²/2 into a column array that is zero outside its 16 nonzero blocks
    /// (the structure [`propagate_structured`](super::covariance::propagate_structured) relies on). Column m of the navigation
    /// rows is e_m + A\[:, m\] + ½ Σ_k A\[:, k\] A\[k, m\], summed over the k where A\[k, m\]
    /// can be nonzero (`A_COLUMNS`, from the zero patterns of F's blocks; a left-out term
    /// is an exact zero), in increasing k, as 8-lane multiply-adds down A's columns plus
    /// the ninth row: 83 vector and 83 scalar multiply-adds (68 terms and one ½ per
    /// column) instead of 19 3x3 block products (estim-ins/README.md: 1,200 to about 750
    /// instructions). The bias rows are diagonal: 1 + k + k²/2. Every product of a zero
    /// block is left out, so the position x gyro-bias block and the bias rows'
    /// off-diagonal blocks stay exactly zero.
    #[inline(always)]
    pub(super) fn write_transition<M: MultiplyAdd>(
        &self,
        phi: &mut [[f64; ERROR_STATES]; ERROR_STATES],
    ) {
        let a = self.navigation_columns();
        let (ka, kg) = (self.ka, self.kg);
        let bias = [ka, ka, ka, kg, kg, kg];
        transition_columns::<M>(&a, bias, phi);
        for (b, k) in bias.iter().enumerate() {
            let row = NAV + b;
            phi[row][row] = 1.0 + k + 0.5 * k * k;
        }
    }
}

/// The nine navigation rows of A = F dt by column: rows 0..8 of column m in `top[m]`
/// (one 8-lane vector) and row 8 (ψ_D) in `bottom[m]`. A's bias rows are k_a, k_g on
/// the diagonal and zero elsewhere.
pub(super) struct NavigationColumns {
    top: [[f64; 8]; ERROR_STATES],
    bottom: [f64; ERROR_STATES],
}

impl NavigationColumns {
    /// A\[k, m\] (`bias` = the diagonal of A's bias rows).
    #[inline(always)]
    fn entry(&self, k: usize, m: usize, bias: [f64; 6]) -> f64 {
        if k < 8 {
            self.top[m][k]
        } else if k == 8 {
            self.bottom[m]
        } else if k == m {
            bias[k - NAV]
        } else {
            0.0
        }
    }
}

/// The nonzero blocks of A = F dt: (row block, column block, zero pattern).
pub(super) const A_BLOCKS: [(usize, usize, u16); 12] = [
    (0, 0, PP),
    (0, 1, IDENTITY),
    (1, 0, NO_EAST),
    (1, 1, FULL),
    (1, 2, SKEW),
    (1, 3, FULL),
    (2, 0, NO_EAST),
    (2, 1, PSI_V),
    (2, 2, SKEW),
    (2, 4, FULL),
    (3, 3, IDENTITY),
    (4, 4, IDENTITY),
];

/// For each column m of A, bit k set where A\[k, m\] can be nonzero (from `A_BLOCKS`).
pub(super) const A_COLUMNS: [u16; ERROR_STATES] = {
    let mut out = [0u16; ERROR_STATES];
    let mut b = 0;
    while b < A_BLOCKS.len() {
        let (i, j, pattern) = A_BLOCKS[b];
        let mut r = 0;
        while r < 3 {
            let mut c = 0;
            while c < 3 {
                if pattern & (1 << (3 * r + c)) != 0 {
                    out[3 * j + c] |= 1 << (3 * i + r);
                }
                c += 1;
            }
            r += 1;
        }
        b += 1;
    }
    out
};

/// The navigation rows of Phi's columns (see [`ScaledBlocks::write_transition`]).
#[inline(always)]
pub(super) fn transition_columns<M: MultiplyAdd>(
    a: &NavigationColumns,
    bias: [f64; 6],
    phi: &mut [[f64; ERROR_STATES]; ERROR_STATES],
) {
    transition_column::<M, 0>(a, bias, phi);
    transition_column::<M, 1>(a, bias, phi);
    transition_column::<M, 2>(a, bias, phi);
    transition_column::<M, 3>(a, bias, phi);
    transition_column::<M, 4>(a, bias, phi);
    transition_column::<M, 5>(a, bias, phi);
    transition_column::<M, 6>(a, bias, phi);
    transition_column::<M, 7>(a, bias, phi);
    transition_column::<M, 8>(a, bias, phi);
    transition_column::<M, 9>(a, bias, phi);
    transition_column::<M, 10>(a, bias, phi);
    transition_column::<M, 11>(a, bias, phi);
    transition_column::<M, 12>(a, bias, phi);
    transition_column::<M, 13>(a, bias, phi);
    transition_column::<M, 14>(a, bias, phi);
}

/// Rows 0..9 of Phi's column `COL`: e + A\[:, COL\] + ½ Σ_k A\[:, k\] A\[k, COL\] over the k
/// of `A_COLUMNS[COL]` (a constant, so the loop unrolls into the nonzero terms only).
#[inline(always)]
pub(super) fn transition_column<M: MultiplyAdd, const COL: usize>(
    a: &NavigationColumns,
    bias: [f64; 6],
    phi: &mut [[f64; ERROR_STATES]; ERROR_STATES],
) {
    let mut top = [0.0f64; 8];
    let mut bottom = 0.0f64;
    for k in 0..ERROR_STATES {
        if A_COLUMNS[COL] & (1 << k) != 0 {
            let w = a.entry(k, COL, bias);
            for (acc, x) in top.iter_mut().zip(&a.top[k]) {
                *acc = M::multiply_add(*x, w, *acc);
            }
            bottom = M::multiply_add(a.bottom[k], w, bottom);
        }
    }
    let column = &mut phi[COL];
    for (r, (out, (acc, x))) in column
        .iter_mut()
        .zip(top.iter().zip(&a.top[COL]))
        .enumerate()
    {
        let identity = if r == COL { 1.0 } else { 0.0 };
        *out = M::multiply_add(0.5, *acc, identity + x);
    }
    column[8] = M::multiply_add(
        0.5,
        bottom,
        if COL == 8 { 1.0 } else { 0.0 } + a.bottom[COL],
    );
}

/// Zero patterns of F's 3x3 blocks: bit 3 i + j is set where entry (i, j) can be nonzero.
/// All nine entries.
pub(super) const FULL: u16 = 0b111_111_111;
/// A multiple of the identity.
pub(super) const IDENTITY: u16 = 0b100_010_001;
/// A skew-symmetric block (\[ω×\] dt, \[f×\] dt): zero diagonal.
pub(super) const SKEW: u16 = 0b011_101_110;
/// F_pp dt: its down row is zero (ḣ = -v_D has no position term) and so is its (N, E)
/// entry (L̇ does not depend on the longitude).
pub(super) const PP: u16 = 0b000_111_101;
/// F_vp dt and F_ψp dt: the east column is zero (nothing depends on the longitude).
pub(super) const NO_EAST: u16 = 0b101_101_101;
/// F_ψv dt = -∂ω_en/∂v dt: entries (N, E), (E, N) and (D, E) only.
pub(super) const PSI_V: u16 = 0b010_001_010;
/// The transpose of `PSI_V`: entries (E, N), (N, E) and (E, D).
pub(super) const PSI_V_T: u16 = 0b000_101_010;

/// a b for 3x3 blocks whose entries outside the patterns `A` and `B` are exactly zero:
/// each entry is the sum over k of a_ik b_kj in increasing k, the terms that are zero by
/// pattern left out (adding an exact zero changes nothing, so the value is the dense
/// product's). The patterns are constants, so the loops unroll into the nonzero terms
/// only. Debug builds check the patterns.
#[inline(always)]
pub(super) fn block_product<const A: u16, const B: u16>(a: &M3, b: &M3) -> M3 {
    debug_assert!(has_pattern(a, A) && has_pattern(b, B));
    let mut out = M3::zeros();
    for j in 0..3 {
        for i in 0..3 {
            let mut sum: Option<f64> = None;
            for k in 0..3 {
                if A & (1 << (3 * i + k)) != 0 && B & (1 << (3 * k + j)) != 0 {
                    let term = a[(i, k)] * b[(k, j)];
                    sum = Some(sum.map_or(term, |s| s + term));
                }
            }
            out[(i, j)] = sum.unwrap_or(0.0);
        }
    }
    out
}

/// Whether every entry of `m` outside `pattern` is zero.
pub(super) fn has_pattern(m: &M3, pattern: u16) -> bool {
    (0..9).all(|e| pattern & (1 << e) != 0 || m[(e / 3, e % 3)] == 0.0)
}

/// Write block `b` at block position (r, c) of a column-array matrix and, when r != c,
/// its transpose at (c, r).
#[inline]
pub(super) fn put_symmetric_block(
    out: &mut [[f64; ERROR_STATES]; ERROR_STATES],
    r: usize,
    c: usize,
    b: &M3,
) {
    for j in 0..3 {
        for i in 0..3 {
            out[3 * c + j][3 * r + i] = b[(i, j)];
            out[3 * r + i][3 * c + j] = b[(i, j)];
        }
    }
}
