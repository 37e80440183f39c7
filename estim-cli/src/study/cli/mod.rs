//! The study's parts of the command line: `estim dvl mismatch` (a fit on A-KIT
//! training trajectories), and the modes of `estim smooth` and `estim tune` that run the
//! paper's scenarios (their flags are parsed in the command's own file, `main.rs`
//! brings them here).

pub mod dvl_mismatch;
pub mod smooth;
pub mod tune;
