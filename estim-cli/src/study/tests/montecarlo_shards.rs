//! Monte Carlo in shards (issue 31): the sufficient statistics of shards over disjoint
//! seeds, merged, give the report of one run over the union of the seeds, bit for bit;
//! overlapping seeds and different variant sets are refused.

use crate::study::{monte_carlo, Config, MergeError, MonteCarloReport, MonteCarloSums};

/// Through JSON, as a shard file is read back.
fn round_trip(sums: &MonteCarloSums) -> MonteCarloSums {
    serde_json::from_str(&serde_json::to_string(sums).unwrap()).unwrap()
}

#[test]
fn shards_merge_to_one_run_over_the_union() {
    let mut config = Config::default();
    // Shorter missions: the merge is what is tested, not the mission.
    config.mission.duration_s = 120.0;
    let (first, runs, k) = (7100, 3, 1);
    let whole = monte_carlo(&config, runs, first, None, &|| {}).unwrap();
    let a = monte_carlo(&config, k, first, None, &|| {}).unwrap();
    let b = monte_carlo(&config, runs - k, first + k as u64, None, &|| {}).unwrap();

    // In either order.
    for (x, y) in [(&a, &b), (&b, &a)] {
        let mut sums = round_trip(&x.sufficient_statistics);
        sums.merge(&round_trip(&y.sufficient_statistics)).unwrap();
        sums.check().unwrap();
        assert_eq!(sums, whole.sufficient_statistics);
        let merged = MonteCarloReport::from_sums(sums).unwrap();
        assert_eq!(
            serde_json::to_value(&merged).unwrap(),
            serde_json::to_value(&whole).unwrap()
        );
        assert_eq!(merged.seed_ranges, vec![[first, first + runs as u64]]);
        assert_eq!((merged.runs, merged.first_seed), (runs, first));
    }
    // The sums are those of the shards' runs; the means those of the whole run.
    let ls = &whole.variants["ls"];
    let (la, lb) = (&a.variants["ls"], &b.variants["ls"]);
    assert_eq!(ls.runs_completed, la.runs_completed + lb.runs_completed);
    assert_eq!(
        ls.updates_rejected,
        la.updates_rejected + lb.updates_rejected
    );
    assert_eq!(
        ls.covariance_not_positive_definite,
        la.covariance_not_positive_definite + lb.covariance_not_positive_definite
    );
    // Independent of the sums: the mean of the per-run RMSEs, from the shards' means.
    let mean = (la.position_rmse.mean * k as f64 + lb.position_rmse.mean * (runs - k) as f64)
        / runs as f64;
    assert!((ls.position_rmse.mean - mean).abs() <= 1e-12 * mean);
    // A per-epoch NEES run-average from the shards' own run-averages.
    let sa = &a.sufficient_statistics.variants[0];
    let sb = &b.sufficient_statistics.variants[0];
    let sw = &whole.sufficient_statistics.variants[0];
    assert_eq!(sw.id, "ls");
    let epoch = sw.nees.sums.len() / 2;
    let from_shards = sa.nees.sums[epoch].value() + sb.nees.sums[epoch].value();
    assert!((sw.nees.sums[epoch].value() - from_shards).abs() <= 1e-12 * from_shards);
    println!(
        "ls over seeds {first}..{}: NEES average {}, {} % of epochs in band, position RMSE \
         {} m [{}, {}], epoch {epoch} NEES sum {} (shards {} + {})",
        first + runs as u64 - 1,
        ls.nees_average,
        ls.nees_epochs_in_band_percent,
        ls.position_rmse.mean,
        ls.position_rmse.lo,
        ls.position_rmse.hi,
        sw.nees.sums[epoch].value(),
        sa.nees.sums[epoch].value(),
        sb.nees.sums[epoch].value()
    );

    // Overlap: the whole run and the second shard share seeds first+1 ..
    let mut sums = whole.sufficient_statistics.clone();
    assert_eq!(
        sums.merge(&b.sufficient_statistics),
        Err(MergeError::Overlap(
            [first, first + runs as u64],
            [first + k as u64, first + runs as u64]
        ))
    );
    // A shard claiming a run outside its seeds is inconsistent.
    let mut bad = a.sufficient_statistics.clone();
    bad.variants[0].runs[0].seed = first + 50;
    assert!(matches!(bad.check(), Err(MergeError::Inconsistent(_))));
    // Different variants (another set of filters) are refused.
    let mut other = b.sufficient_statistics.clone();
    other.variants.pop();
    let mut sums = a.sufficient_statistics.clone();
    assert!(matches!(sums.merge(&other), Err(MergeError::Variants(..))));
}
