//! Numeric helpers shared by estim-core and the crates built on it: scalar
//! conversions, the structural tolerance, and the checks every constructor runs.
//!
//! ```
//! use estim_core::nalgebra::Matrix2;
//! use estim_core::numeric::{check_finite, check_symmetric, lit, relative_tolerance};
//!
//! let p = Matrix2::new(1.0, 0.5, 0.5, 2.0);
//! check_finite(p.as_slice(), "covariance")?;
//! check_symmetric(&p, "covariance")?;
//! assert!(relative_tolerance::<f64>() < 1e-9);
//! assert_eq!(lit::<f32>(0.5), 0.5f32);
//! # Ok::<(), estim_core::Error>(())
//! ```

pub use crate::gaussian::{
    check_covariance, check_finite, check_positive_semidefinite, check_symmetric, symmetrize,
};
pub use crate::scalar::{lit, relative_tolerance, to_f64};
