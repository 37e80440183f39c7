//! The study's parts of the command line: the modes of user commands that run the
//! paper's scenarios (their flags are parsed where the command is, `main.rs` brings
//! them here).

pub mod smooth;
pub mod tune;
