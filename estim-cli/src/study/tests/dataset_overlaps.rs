//! Rows shared between A-KIT trajectories, found in the real files, and the rule that
//! keeps a window touching a held-out trajectory out (`estim dataset beamsnet`'s data
//! hygiene; the command itself: `estim-cli/tests/dataset_overlaps.rs`).
//!
//! Data rule: if the data is absent the test prints why and returns, unless
//! `ESTIM_REQUIRE_DATA=1`.

use estim::datasets::{load_gt, trajectory_files};

use super::common::data_root;
use crate::study::{akit_overlaps, touches_held_out};

const ALL: [u32; 13] = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13];

#[test]
fn shared_rows_are_found_in_the_files() {
    let Some(root) = data_root() else { return };
    let o = akit_overlaps(&root, &ALL).unwrap();
    // The published facts (shared/data/README.md): 13's first 101 rows are 10's last
    // 101 rows; 1 and 8 share 102 rows.
    let gt10 = load_gt(&trajectory_files(&root, 10).unwrap().gt).unwrap();
    let n10 = gt10.len();
    assert_eq!(
        o.rows_shared_with(10, 13),
        (n10 - 101..n10).collect::<Vec<_>>()
    );
    assert_eq!(o.rows_shared_with(13, 10), (0..101).collect::<Vec<_>>());
    assert_eq!(o.rows_shared_with(1, 8).len(), 102);
    assert_eq!(o.rows_shared_with(8, 1).len(), 102);
    // Nothing shared with trajectory 4, and no pair beyond those two.
    for n in ALL {
        assert!(
            o.rows_shared_with(4, n).is_empty(),
            "4 shares rows with {n}"
        );
    }
    let pairs: Vec<(u32, u32)> = o.pairs().iter().map(|p| (p.0, p.1)).collect();
    assert_eq!(pairs, vec![(1, 8), (10, 13)]);
    assert_eq!(o.groups(), vec![vec![1, 8], vec![10, 13]]);
    // The split rule: 1 and 8 on one side; 10 may be validated without 13 (13 is not
    // in the dataset, its shared rows are removed from 10).
    let dataset = [1, 2, 3, 5, 6, 7, 8, 9, 10, 11, 12];
    assert!(o.check_split(&dataset, &[3, 10]).is_ok());
    assert!(o.check_split(&dataset, &[1, 8]).is_ok());
    assert!(o.check_split(&dataset, &[8]).is_err());
    // A window ending at 10's first shared row touches 13; one 5 rows earlier does not
    // (margin 2 rows each side); every window of 4 and 13 touches.
    let t: Vec<f64> = gt10.iter().map(|g| g.time).collect();
    let first_shared = n10 - 101;
    let end = t[first_shared];
    assert!(touches_held_out(&o, 10, &t, end - 1.0, end, &[4, 13]));
    let end = t[first_shared - 4];
    assert!(!touches_held_out(&o, 10, &t, end - 1.0, end, &[4, 13]));
    assert!(touches_held_out(&o, 4, &t, t[5], t[6], &[4, 13]));
}
