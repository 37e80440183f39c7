//! Python bindings of estim (`estim._estim`, re-exported by the `estim` package):
//! the native API over `estim_core::dynamic` and the Rust half of the
//! filterpy-compatible layer (`estim.filterpy`). Every error becomes
//! `estim.EstimError` (a `ValueError`) naming what was wrong; shapes are checked
//! before any work, and nothing panics across the boundary.

#![deny(missing_docs)]

mod convert;
mod em;
mod extended;
mod filterpy;
mod native;
mod navigate;
mod noise;
mod unscented;

use pyo3::prelude::*;

pyo3::create_exception!(
    estim,
    EstimError,
    pyo3::exceptions::PyValueError,
    "An input estim refused (shape, value, covariance) or a numerical failure, with the \
     quantity named in the message."
);

/// An estim_core error as an `EstimError`.
pub(crate) fn estim_err(e: estim_core::Error) -> PyErr {
    EstimError::new_err(e.to_string())
}

/// The extension module.
#[pymodule]
fn _estim(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("EstimError", m.py().get_type::<EstimError>())?;
    native::register(m)?;
    em::register(m)?;
    extended::register(m)?;
    noise::register(m)?;
    filterpy::register(m)?;
    unscented::register(m)?;
    navigate::register(m)?;
    Ok(())
}
