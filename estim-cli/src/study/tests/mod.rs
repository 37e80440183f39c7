//! Tests of the study (run by `cargo test` as unit tests of the binary; the study
//! is private to it).

mod beamsnet_eval;
mod claims;
// The data lookup shared with the integration tests (one copy).
#[path = "../../../tests/common/mod.rs"]
mod common;
mod data_span;
mod dataset_overlaps;
mod faults;
mod filter_failures;
mod fuzz_parsers;
mod gate_recovery;
mod long_mission;
mod montecarlo_fields;
mod montecarlo_shards;
mod oracle_monte_carlo;
mod paired;
mod recorded_imu;
mod reference_mismatch;
mod results_tables;
mod smooth_ins;
mod square_root_ins;
