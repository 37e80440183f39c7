//! The span rule: the ground truth and the DVL of a trajectory must cover the same
//! time span.
//!
//! Their first and their last time stamps may each differ by at most
//! `tolerance = DVL period + allowance`, where the DVL period is the median interval
//! of the DVL file (capped at [`MAX_PERIOD_IN_TOLERANCE_S`], so that a file of two
//! far-apart rows cannot widen the tolerance to anything), and the allowance covers
//! the DVL time offset: [`SPAN_TIME_OFFSET_ALLOWANCE_S`] for A-KIT's documented ~1 s
//! offset (the configured 1.48 s), or the configured offset's magnitude if larger.
//! A-KIT: both files span 0-400 s, the tolerance is 1.0025 + 1.5 = 2.5025 s.

use std::path::Path;

use super::{DatasetError, DvlSample, GtSample, Result};

/// Allowance for the DVL time offset in the span rule \[s\] (A-KIT's DVL lags the GT by
/// about one sample; the configured offset is 1.48 s).
pub const SPAN_TIME_OFFSET_ALLOWANCE_S: f64 = 1.5;

/// Largest DVL period counted in the tolerance \[s\].
pub const MAX_PERIOD_IN_TOLERANCE_S: f64 = 5.0;

/// The spans of a GT and a DVL file and the tolerance they are compared with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpanCheck {
    /// First and last GT time \[s\].
    pub gt_s: [f64; 2],
    /// Lines of the first and last GT rows.
    pub gt_lines: [u64; 2],
    /// First and last DVL time stamp \[s\].
    pub dvl_s: [f64; 2],
    /// Lines of the first and last DVL rows.
    pub dvl_lines: [u64; 2],
    /// Median DVL interval \[s\].
    pub dvl_period_s: f64,
    /// Allowance for the DVL time offset \[s\].
    pub allowance_s: f64,
}

/// The span tolerance \[s\] for a DVL period and a time-offset allowance.
pub fn span_tolerance(dvl_period_s: f64, allowance_s: f64) -> f64 {
    dvl_period_s.min(MAX_PERIOD_IN_TOLERANCE_S) + allowance_s
}

impl SpanCheck {
    /// The spans of two non-empty sample lists (`None` if one is empty).
    pub fn new(gt: &[GtSample], dvl: &[DvlSample], allowance_s: f64) -> Option<Self> {
        let (g0, g1) = (gt.first()?, gt.last()?);
        let (d0, d1) = (dvl.first()?, dvl.last()?);
        let mut intervals: Vec<f64> = dvl.windows(2).map(|w| w[1].time - w[0].time).collect();
        intervals.sort_by(f64::total_cmp);
        let dvl_period_s = intervals.get(intervals.len() / 2).copied().unwrap_or(0.0);
        Some(Self {
            gt_s: [g0.time, g1.time],
            gt_lines: [g0.line, g1.line],
            dvl_s: [d0.time, d1.time],
            dvl_lines: [d0.line, d1.line],
            dvl_period_s,
            allowance_s,
        })
    }

    /// The tolerance on each end \[s\].
    pub fn tolerance_s(&self) -> f64 {
        span_tolerance(self.dvl_period_s, self.allowance_s)
    }

    /// Largest difference of the starts or of the ends \[s\].
    pub fn largest_gap_s(&self) -> f64 {
        (self.gt_s[0] - self.dvl_s[0])
            .abs()
            .max((self.gt_s[1] - self.dvl_s[1]).abs())
    }

    /// Both ends within the tolerance.
    pub fn agrees(&self) -> bool {
        self.largest_gap_s() <= self.tolerance_s()
    }

    /// The common time interval, if it is longer than zero.
    pub fn overlap_s(&self) -> Option<[f64; 2]> {
        let start = self.gt_s[0].max(self.dvl_s[0]);
        let end = self.gt_s[1].min(self.dvl_s[1]);
        (end > start).then_some([start, end])
    }

    /// Both spans, the overlap and the rule, in words.
    pub fn describe(&self) -> String {
        let overlap = match self.overlap_s() {
            Some([a, b]) => format!("overlap {a:.3}-{b:.3} s"),
            None => "no overlap".to_string(),
        };
        format!(
            "GT {:.3}-{:.3} s (lines {}-{}), DVL {:.3}-{:.3} s (lines {}-{}), {overlap}; \
             starts or ends differ by {:.3} s, more than the tolerance {:.3} s \
             (one DVL period {:.4} s + {:.2} s for the DVL time offset)",
            self.gt_s[0],
            self.gt_s[1],
            self.gt_lines[0],
            self.gt_lines[1],
            self.dvl_s[0],
            self.dvl_s[1],
            self.dvl_lines[0],
            self.dvl_lines[1],
            self.largest_gap_s(),
            self.tolerance_s(),
            self.dvl_period_s.min(MAX_PERIOD_IN_TOLERANCE_S),
            self.allowance_s,
        )
    }
}

/// Apply the span rule to two loaded files.
///
/// # Errors
/// [`DatasetError::SpanMismatch`] naming both files and their spans; with
/// `allow_partial`, only when they do not overlap at all.
pub fn check_spans(
    gt_path: &Path,
    gt: &[GtSample],
    dvl_path: &Path,
    dvl: &[DvlSample],
    allowance_s: f64,
    allow_partial: bool,
) -> Result<SpanCheck> {
    let mismatch = |span: SpanCheck| DatasetError::SpanMismatch {
        gt: gt_path.to_path_buf(),
        dvl: dvl_path.to_path_buf(),
        span: Box::new(span),
    };
    let Some(span) = SpanCheck::new(gt, dvl, allowance_s) else {
        let (path, found) = if gt.is_empty() {
            (gt_path, gt.len())
        } else {
            (dvl_path, dvl.len())
        };
        return Err(DatasetError::TooFewRows {
            path: path.to_path_buf(),
            found,
            min: 2,
        });
    };
    if span.agrees() || (allow_partial && span.overlap_s().is_some()) {
        Ok(span)
    } else {
        Err(mismatch(span))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gt(times: &[f64]) -> Vec<GtSample> {
        times
            .iter()
            .enumerate()
            .map(|(i, &time)| GtSample {
                line: i as u64 + 2,
                time,
                longitude: 0.6,
                latitude: 0.57,
                altitude: -10.0,
                velocity_ned: [0.0; 3],
                roll_pitch_yaw: [0.0; 3],
            })
            .collect()
    }

    fn dvl(times: impl Iterator<Item = f64>) -> Vec<DvlSample> {
        times
            .enumerate()
            .map(|(i, time)| DvlSample {
                line: i as u64 + 2,
                time,
                velocity_body: [0.0; 3],
            })
            .collect()
    }

    #[test]
    fn tolerance_is_one_period_plus_the_allowance() {
        let g = gt(&[0.0, 100.0]);
        let p = Path::new;
        // Ends 2.5 s apart: inside 1 + 1.5 = 2.5 s; 2.6 s: outside.
        let ok = dvl((0..=97).map(|k| k as f64 * 1.0).chain([97.5]));
        let ok = check_spans(p("g"), &g, p("d"), &ok, 1.5, false).unwrap();
        assert_eq!(ok.tolerance_s(), 2.5);
        let late = dvl((0..=102).map(|k| k as f64).chain([102.6]));
        let e = check_spans(p("g"), &g, p("d"), &late, 1.5, false).unwrap_err();
        let s = e.to_string();
        assert!(
            s.contains("g and d") && s.contains("0.000-100.000") && s.contains("2.6"),
            "{s}"
        );
        // --allow-partial accepts an overlap, never a disjoint pair.
        assert!(check_spans(p("g"), &g, p("d"), &late, 1.5, true).is_ok());
        let after = dvl((200..300).map(f64::from));
        assert!(check_spans(p("g"), &g, p("d"), &after, 1.5, true).is_err());
        // Two far-apart rows do not widen the tolerance beyond 5 s + allowance.
        let sparse = dvl([0.0, 400.0].into_iter());
        let e = check_spans(p("g"), &g, p("d"), &sparse, 1.5, false).unwrap_err();
        assert!(e.to_string().contains("6.500"), "{e}");
    }
}
