//! Signed permutations of axes (IMU -> body).

use std::fmt;

use nalgebra::{Matrix3, Vector3};

use crate::error::{Error, Result};

/// Axis labels, indexed by axis.
const AXIS_NAMES: [&str; 3] = ["x", "y", "z"];
const NEGATED_NAMES: [&str; 3] = ["-x", "-y", "-z"];

/// A signed permutation of axes, IMU -> body: body axis i = ± IMU axis `source(i)`.
///
/// Written as three labels, one per body axis: `["x", "-y", "z"]` means body x = +IMU x,
/// body y = -IMU y, body z = +IMU z. The same map applies to the accelerometer and the
/// gyroscope (a mirror image, [`AxisMap::is_proper`] false, flips the sense of rotation
/// as it flips the axis, which is what a mislabelled axis does to both triads).
///
/// ```
/// use estim_ins::AxisMap;
/// use nalgebra::Vector3;
///
/// let axes = AxisMap::from_labels(&["x", "-y", "z"])?;
/// assert_eq!(axes.apply(&Vector3::new(1.0, 2.0, 3.0)), Vector3::new(1.0, -2.0, 3.0));
/// assert_eq!(axes.to_string(), r#"["x", "-y", "z"]"#);
/// assert!(!axes.is_proper());
/// assert_eq!(AxisMap::all().count(), 48);
/// # Ok::<(), estim_ins::Error>(())
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct AxisMap {
    source: [usize; 3],
    negated: [bool; 3],
}

impl AxisMap {
    /// Body axes = IMU axes.
    pub const IDENTITY: Self = Self {
        source: [0, 1, 2],
        negated: [false; 3],
    };

    /// Body axis i = (-1 if `negated[i]`) IMU axis `source[i]`.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] (`axes`) unless `source` is a permutation of 0, 1, 2.
    pub fn new(source: [usize; 3], negated: [bool; 3]) -> Result<Self> {
        let mut seen = [false; 3];
        for &s in &source {
            if s > 2 || seen[s] {
                return Err(Error::InvalidParameter {
                    name: "axes",
                    reason: format!("{source:?} is not a permutation of the axes 0, 1, 2"),
                });
            }
            seen[s] = true;
        }
        Ok(Self { source, negated })
    }

    /// From three labels `x`, `y`, `z`, each optionally signed (`-y`, `+z`), one per body
    /// axis; case and surrounding spaces ignored.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] (`axes`) naming the label that is not an axis, or an
    /// axis used twice, or a count other than three.
    pub fn from_labels<S: AsRef<str>>(labels: &[S]) -> Result<Self> {
        let invalid = |reason: String| Error::InvalidParameter {
            name: "axes",
            reason,
        };
        if labels.len() != 3 {
            return Err(invalid(format!("{} labels, 3 needed", labels.len())));
        }
        let mut source = [0; 3];
        let mut negated = [false; 3];
        for (i, label) in labels.iter().enumerate() {
            let text = label.as_ref().trim().to_ascii_lowercase();
            let (sign, axis) = match text.strip_prefix('-') {
                Some(rest) => (true, rest),
                None => (false, text.strip_prefix('+').unwrap_or(&text)),
            };
            source[i] = AXIS_NAMES
                .iter()
                .position(|&n| n == axis.trim())
                .ok_or_else(|| {
                    invalid(format!(
                        "label {:?} is not x, y or z (optionally signed)",
                        label.as_ref()
                    ))
                })?;
            negated[i] = sign;
        }
        Self::new(source, negated)
    }

    /// The 48 signed permutations (6 permutations x 8 sign patterns), identity first.
    pub fn all() -> impl Iterator<Item = Self> {
        const PERMUTATIONS: [[usize; 3]; 6] = [
            [0, 1, 2],
            [0, 2, 1],
            [1, 0, 2],
            [1, 2, 0],
            [2, 0, 1],
            [2, 1, 0],
        ];
        PERMUTATIONS.into_iter().flat_map(|source| {
            (0..8u8).map(move |bits| Self {
                source,
                negated: [bits & 1 != 0, bits & 2 != 0, bits & 4 != 0],
            })
        })
    }

    /// The IMU axis (0 = x, 1 = y, 2 = z) that body axis `body_axis` reads.
    #[must_use]
    pub fn source(&self, body_axis: usize) -> usize {
        self.source[body_axis.min(2)]
    }

    /// Whether body axis `body_axis` reads its IMU axis negated.
    #[must_use]
    pub fn is_negated(&self, body_axis: usize) -> bool {
        self.negated[body_axis.min(2)]
    }

    /// The labels, one per body axis (`"x"`, `"-y"`, ...).
    #[must_use]
    pub fn labels(&self) -> [&'static str; 3] {
        std::array::from_fn(|i| {
            if self.negated[i] {
                NEGATED_NAMES[self.source[i]]
            } else {
                AXIS_NAMES[self.source[i]]
            }
        })
    }

    /// A vector in IMU axes expressed in body axes.
    #[must_use]
    pub fn apply(&self, imu: &Vector3<f64>) -> Vector3<f64> {
        Vector3::from_fn(|i, _| {
            let v = imu[self.source[i]];
            if self.negated[i] {
                -v
            } else {
                v
            }
        })
    }

    /// The matrix P with body = P imu.
    #[must_use]
    pub fn matrix(&self) -> Matrix3<f64> {
        Matrix3::from_fn(|i, k| match (k == self.source[i], self.negated[i]) {
            (false, _) => 0.0,
            (true, false) => 1.0,
            (true, true) => -1.0,
        })
    }

    /// Whether the map is a rotation (determinant +1) rather than a mirror image (-1).
    #[must_use]
    pub fn is_proper(&self) -> bool {
        self.matrix().determinant() > 0.0
    }
}

impl fmt::Display for AxisMap {
    /// The TOML array, e.g. `["x", "-y", "z"]`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let [a, b, c] = self.labels();
        write!(f, "[\"{a}\", \"{b}\", \"{c}\"]")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn forty_eight_distinct_maps_half_proper() {
        let all: Vec<AxisMap> = AxisMap::all().collect();
        assert_eq!(all.len(), 48);
        let distinct: std::collections::HashSet<_> = all.iter().collect();
        assert_eq!(distinct.len(), 48);
        assert_eq!(all.iter().filter(|a| a.is_proper()).count(), 24);
        assert_eq!(all[0], AxisMap::IDENTITY);
        // apply agrees with the matrix, labels round-trip.
        let v = Vector3::new(1.0, -2.0, 5.0);
        for a in &all {
            assert_eq!(a.apply(&v), a.matrix() * v);
            assert_eq!(AxisMap::from_labels(&a.labels()).ok(), Some(*a));
        }
    }

    #[test]
    fn labels_refused_name_the_problem() {
        for bad in [&["x", "x", "z"][..], &["x", "w", "z"], &["x", "y"]] {
            let e = AxisMap::from_labels(bad).unwrap_err();
            assert!(
                matches!(e, Error::InvalidParameter { name: "axes", .. }),
                "{e}"
            );
        }
        let a = AxisMap::from_labels(&[" +Y", "-x ", "Z"]).unwrap();
        assert_eq!(a.labels(), ["y", "-x", "z"]);
    }
}
