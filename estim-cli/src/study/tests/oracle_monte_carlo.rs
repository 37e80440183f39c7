//! The oracle Monte Carlo: the filter fed the true M is consistent.

use crate::study::{monte_carlo, Config, ORACLE_NEGLECTED, ORACLE_TRUE_M};

#[test]
fn monte_carlo_filter_fed_the_true_m_is_consistent() {
    let mut config = Config::default();
    config.mission.duration_s = 200.0;
    let report = monte_carlo(&config, 8, 1, None, &|| {}).expect("monte carlo");
    for (name, v) in &report.variants {
        eprintln!(
            "{name}: NEES {:.2} (band {:.2}-{:.2}, {:.1}% of epochs in band), NIS {:.2} (band {:.2}-{:.2}), P not PD {}",
            v.nees_average, v.nees_band[0], v.nees_band[1], v.nees_epochs_in_band_percent,
            v.nis_average, v.nis_band[0], v.nis_band[1], v.covariance_not_positive_definite
        );
    }
    let aware = &report.variants[ORACLE_TRUE_M];
    assert!(aware.nees_average >= aware.nees_band[0] && aware.nees_average <= aware.nees_band[1]);
    assert!(aware.nis_average >= aware.nis_band[0] && aware.nis_average <= aware.nis_band[1]);
    // Epoch by epoch, about 95 % should fall in the band; 85 % leaves room for 8 runs.
    assert!(
        aware.nees_epochs_in_band_percent >= 85.0,
        "{}",
        aware.nees_epochs_in_band_percent
    );
    assert_eq!(aware.covariance_not_positive_definite, 0);
    // Neglecting M overstates S: its NIS sits below the true-M filter's.
    assert!(report.variants[ORACLE_NEGLECTED].nis_average < aware.nis_average);
}
