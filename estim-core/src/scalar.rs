//! The one scalar bound used throughout estim.

use nalgebra::RealField;

/// Scalar type of states and covariances: any `nalgebra::RealField` that is `Copy`
/// (`f64` by default, `f32` works too).
///
/// A blanket implementation covers every such type, so bounds read `T: Scalar`.
pub trait Scalar: RealField + Copy {}

impl<T: RealField + Copy> Scalar for T {}

/// Convert an `f64` constant into `T`.
#[inline]
pub fn lit<T: Scalar>(x: f64) -> T {
    nalgebra::convert(x)
}

/// `T` to `f64` (for reports and error messages).
#[inline]
pub fn to_f64<T: Scalar>(x: T) -> f64 {
    nalgebra::try_convert(x).unwrap_or(f64::NAN)
}

/// Relative tolerance of estim-core's structural checks (symmetry of a covariance,
/// positive semidefiniteness of the joint correlation matrix): 2^-4 sqrt(eps) of the
/// scalar, 9.3e-10 for `f64` (the former fixed 1e-9) and 2.2e-5 for `f32`.
///
/// Why the square root of eps rather than a fixed multiple: a covariance produced by
/// products of depth N (F P F', accumulated noise over many steps) carries relative
/// round-off of order N eps, up to 1e-5 in f32 after a few hundred steps, which a
/// fixed 1e-9 rejected; while a genuinely wrong input (an asymmetric covariance, an M
/// beyond its bound) is off by far more than sqrt(eps) (1.5e-8 in f64, 3.5e-4 in f32).
#[inline]
pub fn relative_tolerance<T: Scalar>() -> T {
    T::default_epsilon().sqrt() * lit::<T>(0.0625)
}
