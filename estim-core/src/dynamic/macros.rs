//! `dmatrix!` and `dvector!` through `$crate::nalgebra`, so a crate that depends on
//! estim-core alone can write matrix literals.

/// A `DMatrix<f64>` from rows separated by `;` and entries by `,`, as nalgebra's
/// `dmatrix!`, expanded through `estim_core::nalgebra` (no direct nalgebra
/// dependency needed). Every row must have the same length (checked when it runs:
/// a ragged literal panics, as an array literal of the wrong length fails to
/// compile).
///
/// ```
/// let f = estim_core::dmatrix![1.0, 1.0;
///                              0.0, 1.0];
/// assert_eq!(f.shape(), (2, 2));
/// assert_eq!(f[(0, 1)], 1.0);
/// let h = estim_core::dmatrix![1.0, 0.0];
/// assert_eq!(h.shape(), (1, 2));
/// ```
#[macro_export]
macro_rules! dmatrix {
    () => { $crate::nalgebra::DMatrix::<f64>::zeros(0, 0) };
    ($($($x:expr),+ $(,)?);+ $(;)?) => {{
        let rows: &[&[f64]] = &[$(&[$(($x) as f64),+]),+];
        let ncols = rows[0].len();
        assert!(rows.iter().all(|r| r.len() == ncols), "dmatrix!: rows of different lengths");
        $crate::nalgebra::DMatrix::<f64>::from_fn(rows.len(), ncols, |i, j| rows[i][j])
    }};
}

/// A `DVector<f64>` from its entries, as nalgebra's `dvector!`, expanded through
/// `estim_core::nalgebra`.
///
/// ```
/// let x = estim_core::dvector![0.0, 1.5];
/// assert_eq!(x.len(), 2);
/// ```
#[macro_export]
macro_rules! dvector {
    () => { $crate::nalgebra::DVector::<f64>::zeros(0) };
    ($($x:expr),+ $(,)?) => {
        $crate::nalgebra::DVector::<f64>::from_column_slice(&[$(($x) as f64),+])
    };
}
