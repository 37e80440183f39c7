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
