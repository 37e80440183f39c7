//! The INS/DVL + BeamsNet pipeline behind `estim reproduce` and `estim montecarlo`.

pub mod stats;
