//! Every generated table of docs/results.md equals a fresh run of its generator, byte
//! for byte (`estim report --markdown`; runs are seeded, rounding is stated in
//! `crate::study::markdown`). When a table differs, regenerate it with
//! `cargo run --release -- report --write docs/results.md` and commit the page with the
//! change that moved it.
//!
//! The A-KIT tables need the data: they run when it is found and in CI
//! (`ESTIM_REQUIRE_DATA=1`), and are skipped elsewhere with a printed reason. The
//! Monte Carlo table runs everywhere (simulated missions; about 25 s in release on
//! 2 cores). The 20-seed twins of the A-KIT tables (`*-seeds`) run with the A-KIT
//! tables; the learned-scenario ones cost 110-145 s of CPU (about 55-75 s wall on 2
//! cores). The long-run tables are rendered from the logs in `results/`.

use std::path::PathBuf;

use crate::study::markdown::{
    default_beamsnet, learned_seed_tables, long_run_tables, monte_carlo_table, recorded_tables,
    region, results_tables, seed_interval_tables, splice, Table,
};
use crate::study::Config;

use super::common;

/// The repository root (estim-cli's parent).
fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn readme() -> String {
    std::fs::read_to_string(root().join("docs/results.md")).expect("docs/results.md")
}

/// The region of `table` equals the fresh markdown.
fn assert_matches(readme: &str, table: &Table) {
    let committed = region(readme, table.name)
        .unwrap_or_else(|e| panic!("docs/results.md: region {}: {e}", table.name));
    assert!(
        committed == table.markdown,
        "docs/results.md region {:?} differs from a fresh run \
         (regenerate: cargo run --release -- report --write docs/results.md)\n\
         --- docs/results.md ---\n{committed}--- fresh ---\n{}",
        table.name,
        table.markdown
    );
}

#[test]
fn every_region_is_marked_once() {
    let text = readme();
    let names = [
        "velocity",
        "filters",
        "filters-seeds",
        "velocity-seeds",
        "paper-std",
        "paper-std-seeds",
        "rho",
        "rho-seeds",
        "two-beams-seeds",
        "outage-seeds",
        "montecarlo",
        "fuzz",
        "long-mission",
        "recorded-imu",
        "recorded-imu-paired",
        "recorded-imu-correlation",
    ];
    let tables: Vec<Table> = names
        .iter()
        .map(|n| Table {
            name: n,
            markdown: region(&text, n)
                .unwrap_or_else(|e| panic!("docs/results.md: {e}"))
                .to_string(),
        })
        .collect();
    // Splicing the page's own regions back in is the identity.
    assert_eq!(splice(&text, &tables).expect("markers"), text);
}

#[test]
fn akit_and_simulated_tables_match_a_fresh_run() {
    let Some(data) = common::data_root() else {
        return;
    };
    let config = Config::default();
    let learned = default_beamsnet(&config).expect("committed BeamsNet model");
    let tables = results_tables(&config, &data, learned.as_ref()).expect("tables");
    let text = readme();
    for t in &tables {
        assert_matches(&text, t);
    }
}

/// The recorded-IMU tables of the training trajectories (about 20 s in release).
#[test]
fn recorded_imu_tables_match_a_fresh_run() {
    let Some(data) = common::data_root() else {
        return;
    };
    let config = Config::default();
    let learned = default_beamsnet(&config).expect("committed BeamsNet model");
    let tables = recorded_tables(&config, &data, learned.as_ref()).expect("tables");
    let text = readme();
    for t in &tables {
        assert_matches(&text, t);
    }
}

/// The 20-seed intervals of the filters, velocity, paper-std and rho tables (about 40 s
/// in release on 2 cores).
#[test]
fn seed_interval_tables_match_a_fresh_run() {
    let Some(data) = common::data_root() else {
        return;
    };
    let config = Config::default();
    let learned = default_beamsnet(&config).expect("committed BeamsNet model");
    let tables = seed_interval_tables(&config, &data, learned.as_ref()).expect("tables");
    let text = readme();
    for t in &tables {
        assert_matches(&text, t);
    }
}

/// The 20-seed intervals of the two-beams and outage scenarios on A-KIT (about 60 s in
/// release on 2 cores; the empirical M's 400 draws per update are most of it).
#[test]
fn learned_seed_tables_match_a_fresh_run() {
    let Some(data) = common::data_root() else {
        return;
    };
    let tables = learned_seed_tables(&Config::default(), &data).expect("tables");
    let text = readme();
    for t in &tables {
        assert_matches(&text, t);
    }
}

#[test]
fn monte_carlo_table_matches_a_fresh_run() {
    let config = Config::default();
    let learned = default_beamsnet(&config).expect("committed BeamsNet model");
    let table = monte_carlo_table(&config, learned.as_ref()).expect("Monte Carlo");
    assert_matches(&readme(), &table);
}

#[test]
fn long_run_tables_match_their_logs() {
    let tables = long_run_tables(&root().join("results")).expect("logs in results/");
    let text = readme();
    for t in &tables {
        assert_matches(&text, t);
    }
}
