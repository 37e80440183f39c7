//! The readers of estim-nav ([`estim_nav::datasets`]: A-KIT's and users' files, the
//! rules for finding the data on disk), and the rows shared between A-KIT trajectories.

mod overlaps;

pub use estim_nav::datasets::*;
pub use overlaps::{akit_overlaps, akit_row_keys, touches_held_out, WINDOW_MARGIN_ROWS};
