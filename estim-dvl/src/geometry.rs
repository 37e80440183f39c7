//! Beam geometry (the beam matrix A) and the velocity solutions from 4 or 3 beams.

use nalgebra::{Matrix3, Matrix3x4, Matrix4x3, RowVector3, Vector3, Vector4};

use crate::error::{finite, Error, Result};

/// Smallest singular value every 3-beam sub-matrix of A must have.
const MIN_SINGULAR_VALUE: f64 = 1e-6;
/// Tolerance on the norm of a beam direction given as a unit vector.
const UNIT_TOLERANCE: f64 = 1e-9;

/// Directions of the four beams of a DVL in its own frame (x forward, y right, z down),
/// as the rows of the beam matrix A (4 x 3): beam velocities = A v.
///
/// Built once by [`BeamGeometry::janus`] or [`BeamGeometry::from_unit_vectors`] (both
/// return a [`BeamGeometryBuilder`] whose `build()` validates), after which the
/// least-squares pseudo-inverse, every 3-beam inverse and the error-velocity vector are
/// precomputed, so solving never allocates nor fails.
///
/// ```
/// use estim_dvl::{BeamGeometry, BeamSolution};
/// use estim_dvl::nalgebra::Vector3;
///
/// let geometry = BeamGeometry::janus(20.0).azimuth_offset(45.0).build()?;
/// let v = Vector3::new(2.0, 0.3, -0.05);
/// let beams = geometry.beams(&v);
/// // beam 2 lost: the 3-beam solution is still exact on noise-free data
/// let solution = geometry.solve(&[Some(beams[0]), None, Some(beams[2]), Some(beams[3])]);
/// assert!(matches!(solution, BeamSolution::ThreeBeam { missing_beam: 2, .. }));
/// assert!((solution.velocity().unwrap() - v).norm() < 1e-12);
/// # Ok::<(), estim_dvl::Error>(())
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct BeamGeometry {
    matrix: Matrix4x3<f64>,
    beam_angle_deg: Option<f64>,
    pseudo_inverse: Matrix3x4<f64>,
    /// `three_beam_inverse[i]`: inverse of A without row i, columns in beam order.
    three_beam_inverse: [Matrix3<f64>; 4],
    /// Error-velocity row: e = error_row . beams (see [`BeamGeometry::error_velocity`]).
    error_row: Vector4<f64>,
}

enum Layout {
    Janus {
        beam_angle_deg: f64,
        azimuth_offset_deg: f64,
    },
    Vectors([Vector3<f64>; 4]),
}

/// Builder of a [`BeamGeometry`]; `build()` validates.
#[must_use]
pub struct BeamGeometryBuilder {
    layout: Layout,
}

impl BeamGeometryBuilder {
    /// Azimuth of beam 1 in degrees from the x axis toward y (Janus layouts only;
    /// default 45, the BeamsNet layout: psi_i = offset + (i-1) * 90 deg).
    pub fn azimuth_offset(mut self, degrees: f64) -> Self {
        if let Layout::Janus {
            azimuth_offset_deg, ..
        } = &mut self.layout
        {
            *azimuth_offset_deg = degrees;
        }
        self
    }

    /// Validate and precompute.
    ///
    /// Errors: a beam angle outside (0, 90) degrees, a non-finite value, a direction
    /// that is not a unit vector (tolerance 1e-9), or a set of 3 beams whose matrix has
    /// a singular value below 1e-6 (no 3-beam solution possible).
    pub fn build(self) -> Result<BeamGeometry> {
        let (rows, beam_angle_deg) = match self.layout {
            Layout::Janus {
                beam_angle_deg,
                azimuth_offset_deg,
            } => {
                finite("beam_angle", beam_angle_deg)?;
                finite("azimuth_offset", azimuth_offset_deg)?;
                if !(beam_angle_deg > 0.0 && beam_angle_deg < 90.0) {
                    return Err(Error::InvalidParameter {
                        name: "beam_angle",
                        reason: format!("{beam_angle_deg} deg is outside (0, 90) deg"),
                    });
                }
                (
                    janus_directions(beam_angle_deg, azimuth_offset_deg),
                    Some(beam_angle_deg),
                )
            }
            Layout::Vectors(v) => {
                for (i, b) in v.iter().enumerate() {
                    if !b.iter().all(|x| x.is_finite()) {
                        return Err(Error::InvalidParameter {
                            name: "beam_direction",
                            reason: format!("beam {} holds a non-finite value", i + 1),
                        });
                    }
                    if (b.norm() - 1.0).abs() > UNIT_TOLERANCE {
                        return Err(Error::InvalidParameter {
                            name: "beam_direction",
                            reason: format!(
                                "beam {} has norm {} (a unit vector is required)",
                                i + 1,
                                b.norm()
                            ),
                        });
                    }
                }
                (v, None)
            }
        };
        let matrix = Matrix4x3::from_rows(&rows.map(|b| b.transpose()));
        BeamGeometry::from_matrix(matrix, beam_angle_deg)
    }
}

/// b_i = [cos psi_i sin theta, sin psi_i sin theta, cos theta], psi_i = offset + (i-1) 90 deg
/// (BeamsNet test scripts; data README).
fn janus_directions(beam_angle_deg: f64, azimuth_offset_deg: f64) -> [Vector3<f64>; 4] {
    let theta = beam_angle_deg.to_radians();
    std::array::from_fn(|i| {
        let psi = (azimuth_offset_deg + 90.0 * i as f64).to_radians();
        Vector3::new(
            psi.cos() * theta.sin(),
            psi.sin() * theta.sin(),
            theta.cos(),
        )
    })
}

fn without_row(matrix: &Matrix4x3<f64>, skip: usize) -> Matrix3<f64> {
    let rows: Vec<RowVector3<f64>> = (0..4)
        .filter(|&r| r != skip)
        .map(|r| matrix.row(r).into_owned())
        .collect();
    Matrix3::from_rows(&rows)
}

impl BeamGeometry {
    /// A Janus 4-beam layout with beams `beam_angle_deg` from the z axis (BeamsNet: 20;
    /// Teledyne RDI Workhorse Navigator: 30) and azimuths `offset + (i-1) 90` deg.
    pub fn janus(beam_angle_deg: f64) -> BeamGeometryBuilder {
        BeamGeometryBuilder {
            layout: Layout::Janus {
                beam_angle_deg,
                azimuth_offset_deg: 45.0,
            },
        }
    }

    /// Four arbitrary beam unit vectors (rows of A, in beam order).
    pub fn from_unit_vectors(directions: [Vector3<f64>; 4]) -> BeamGeometryBuilder {
        BeamGeometryBuilder {
            layout: Layout::Vectors(directions),
        }
    }

    /// The BeamsNet simulation layout: Janus, 20 deg, azimuth offset 45 deg.
    pub fn beamsnet() -> Self {
        // Constant, valid parameters: the fallible path cannot fail; fall back to the
        // (equally valid) direct construction rather than panicking.
        Self::janus_unchecked(20.0, 45.0)
    }

    /// A Teledyne RDI Workhorse Navigator layout: Janus, 30 deg (its datasheet), azimuth
    /// offset 45 deg.
    pub fn rdi_workhorse_navigator() -> Self {
        Self::janus_unchecked(30.0, 45.0)
    }

    fn janus_unchecked(beam_angle_deg: f64, azimuth_offset_deg: f64) -> Self {
        let rows = janus_directions(beam_angle_deg, azimuth_offset_deg);
        let matrix = Matrix4x3::from_rows(&rows.map(|b| b.transpose()));
        let three_beam_inverse = std::array::from_fn(|i| {
            without_row(&matrix, i)
                .try_inverse()
                .unwrap_or_else(Matrix3::zeros)
        });
        Self::assemble(matrix, Some(beam_angle_deg), three_beam_inverse)
    }

    fn from_matrix(matrix: Matrix4x3<f64>, beam_angle_deg: Option<f64>) -> Result<Self> {
        let mut three_beam_inverse = [Matrix3::zeros(); 4];
        for (i, inv) in three_beam_inverse.iter_mut().enumerate() {
            let sub = without_row(&matrix, i);
            let smallest = sub.singular_values().min();
            let inverse = sub.try_inverse();
            match inverse {
                Some(m) if smallest >= MIN_SINGULAR_VALUE => *inv = m,
                _ => {
                    let used: Vec<String> = (1..=4)
                        .filter(|&b| b != i + 1)
                        .map(|b| b.to_string())
                        .collect();
                    return Err(Error::DegenerateGeometry {
                        reason: format!(
                            "beams {} have smallest singular value {smallest:e} (< {MIN_SINGULAR_VALUE:e})",
                            used.join(",")
                        ),
                    });
                }
            }
        }
        Ok(Self::assemble(matrix, beam_angle_deg, three_beam_inverse))
    }

    fn assemble(
        matrix: Matrix4x3<f64>,
        beam_angle_deg: Option<f64>,
        three_beam_inverse: [Matrix3<f64>; 4],
    ) -> Self {
        // Every 3x3 sub-matrix is invertible, hence A'A is positive definite.
        let normal = matrix.transpose() * matrix;
        let normal_inv = normal.try_inverse().unwrap_or_else(Matrix3::zeros);
        let pseudo_inverse = normal_inv * matrix.transpose();
        // Null vector of A' by cofactors (generalised cross product): n_i = (-1)^i det(A without row i).
        let mut null = Vector4::from_fn(|i, _| {
            let sign = if i % 2 == 0 { 1.0 } else { -1.0 };
            sign * without_row(&matrix, i).determinant()
        });
        null /= null.norm();
        if null[0] < 0.0 {
            null = -null;
        }
        // Scale so that with white beam noise the error velocity has the mean standard
        // deviation of the two horizontal velocity components (RDI's convention).
        let scale = (0.5 * (normal_inv[(0, 0)] + normal_inv[(1, 1)])).sqrt();
        Self {
            matrix,
            beam_angle_deg,
            pseudo_inverse,
            three_beam_inverse,
            error_row: null * scale,
        }
    }

    /// The beam matrix A (rows = beam unit vectors).
    pub fn matrix(&self) -> &Matrix4x3<f64> {
        &self.matrix
    }

    /// Beam angle from the z axis in degrees, for Janus layouts.
    pub fn beam_angle_deg(&self) -> Option<f64> {
        self.beam_angle_deg
    }

    /// Noise-free beam velocities of a DVL moving at `velocity` (DVL frame): A v.
    pub fn beams(&self, velocity: &Vector3<f64>) -> Vector4<f64> {
        self.matrix * velocity
    }

    /// The least-squares pseudo-inverse (A'A)^-1 A' (3 x 4).
    pub fn pseudo_inverse(&self) -> &Matrix3x4<f64> {
        &self.pseudo_inverse
    }

    /// Four-beam least squares v = (A'A)^-1 A' beams (BeamsNet, eq. for v_LS).
    pub fn least_squares(&self, beams: &Vector4<f64>) -> Vector3<f64> {
        self.pseudo_inverse * beams
    }

    /// The DVL error velocity of four beams.
    ///
    /// With n the unit vector spanning the null space of A' (sign: n_1 > 0), the
    /// least-squares residual is (n . beams) n, and
    ///
    /// ```text
    /// e = (n . beams) * sqrt( ((A'A)^-1_xx + (A'A)^-1_yy) / 2 )
    /// ```
    ///
    /// scaled so that under white beam noise e has the standard deviation of a
    /// horizontal velocity component. For a Janus layout (beam 1 opposite beam 3, beam 2
    /// opposite beam 4) this is exactly Teledyne RDI's error velocity
    /// e = (b1 + b3 - b2 - b4) / (2 sqrt(2) sin theta) (RDI "ADCP Coordinate
    /// Transformation" manual, d = a / sqrt 2 with a = 1 / (2 sin theta); RDI numbers the
    /// opposite pairs (1,2), (3,4)). It is zero on noise-free data of any velocity.
    pub fn error_velocity(&self, beams: &Vector4<f64>) -> f64 {
        self.error_row.dot(beams)
    }

    /// Velocity from the beams present: 4 beams -> least squares and error velocity;
    /// 3 beams -> the exact 3-beam solution; fewer -> [`BeamSolution::Insufficient`].
    /// A `Some` holding NaN or infinity counts as missing.
    pub fn solve(&self, beams: &[Option<f64>; 4]) -> BeamSolution {
        let present: [Option<f64>; 4] = beams.map(|b| b.filter(|x| x.is_finite()));
        let available = present.iter().filter(|b| b.is_some()).count();
        match available {
            4 => {
                let b = Vector4::from_fn(|i, _| present[i].unwrap_or(0.0));
                BeamSolution::FourBeam {
                    velocity: self.least_squares(&b),
                    error_velocity: self.error_velocity(&b),
                }
            }
            3 => {
                let missing = present.iter().position(|b| b.is_none()).unwrap_or(0);
                let sub = Vector3::from_iterator(
                    present
                        .iter()
                        .enumerate()
                        .filter(|(i, _)| *i != missing)
                        .map(|(_, b)| b.unwrap_or(0.0)),
                );
                BeamSolution::ThreeBeam {
                    velocity: self.three_beam_inverse[missing] * sub,
                    missing_beam: missing + 1,
                }
            }
            n => BeamSolution::Insufficient { beams_available: n },
        }
    }

    /// [`BeamGeometry::solve`] with a missing beam given as NaN.
    pub fn solve_nan(&self, beams: &Vector4<f64>) -> BeamSolution {
        self.solve(&std::array::from_fn(|i| Some(beams[i])))
    }
}

/// Outcome of a velocity solution from the beams present.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BeamSolution {
    /// All four beams: least squares and the error velocity.
    FourBeam {
        /// Velocity in the DVL frame \[m/s\].
        velocity: Vector3<f64>,
        /// Error velocity \[m/s\] (see [`BeamGeometry::error_velocity`]).
        error_velocity: f64,
    },
    /// Three beams: the unique solution; no redundancy, so no error velocity.
    ThreeBeam {
        /// Velocity in the DVL frame \[m/s\].
        velocity: Vector3<f64>,
        /// Number (1..=4) of the missing beam.
        missing_beam: usize,
    },
    /// Fewer than three beams: no velocity.
    Insufficient {
        /// Number of usable beams (0..=2).
        beams_available: usize,
    },
}

impl BeamSolution {
    /// The velocity, if there is one.
    pub fn velocity(&self) -> Option<Vector3<f64>> {
        match self {
            Self::FourBeam { velocity, .. } | Self::ThreeBeam { velocity, .. } => Some(*velocity),
            Self::Insufficient { .. } => None,
        }
    }

    /// The error velocity (four beams only).
    pub fn error_velocity(&self) -> Option<f64> {
        match self {
            Self::FourBeam { error_velocity, .. } => Some(*error_velocity),
            _ => None,
        }
    }

    /// Number of beams used (or available, when insufficient).
    pub fn beams_used(&self) -> usize {
        match self {
            Self::FourBeam { .. } => 4,
            Self::ThreeBeam { .. } => 3,
            Self::Insufficient { beams_available } => *beams_available,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn janus_rows_follow_the_readme_formula() {
        let g = BeamGeometry::beamsnet();
        let t = 20f64.to_radians();
        let s = std::f64::consts::FRAC_1_SQRT_2;
        // psi_1 = 45 deg: [cos45 sin20, sin45 sin20, cos20]
        let expected = [
            [s * t.sin(), s * t.sin(), t.cos()],
            [-s * t.sin(), s * t.sin(), t.cos()],
            [-s * t.sin(), -s * t.sin(), t.cos()],
            [s * t.sin(), -s * t.sin(), t.cos()],
        ];
        for (i, row) in expected.iter().enumerate() {
            for (j, x) in row.iter().enumerate() {
                assert!((g.matrix()[(i, j)] - x).abs() < 1e-15, "A[{i},{j}]");
            }
        }
        let built = BeamGeometry::janus(20.0).build().unwrap();
        assert_eq!(built, g);
        assert_eq!(
            BeamGeometry::janus(30.0).build().unwrap(),
            BeamGeometry::rdi_workhorse_navigator()
        );
    }

    #[test]
    fn builder_rejects_bad_geometry() {
        for angle in [0.0, 90.0, -5.0, f64::NAN, 120.0] {
            assert!(matches!(
                BeamGeometry::janus(angle).build(),
                Err(Error::InvalidParameter {
                    name: "beam_angle",
                    ..
                })
            ));
        }
        let z = Vector3::z();
        let x = Vector3::x();
        let y = Vector3::y();
        assert!(matches!(
            BeamGeometry::from_unit_vectors([x, y, z, 2.0 * z]).build(),
            Err(Error::InvalidParameter { .. })
        ));
        // beams 1,2,4 coplanar (all in the x-y plane): no 3-beam solution without beam 3
        let d = (x + y).normalize();
        let e = BeamGeometry::from_unit_vectors([x, y, z, d])
            .build()
            .unwrap_err();
        assert!(e.to_string().contains("beams 1,2,4"), "{e}");
    }

    #[test]
    fn insufficient_beams_is_an_outcome() {
        let g = BeamGeometry::beamsnet();
        let s = g.solve(&[Some(1.0), None, Some(f64::NAN), None]);
        assert_eq!(s, BeamSolution::Insufficient { beams_available: 1 });
        assert_eq!(s.velocity(), None);
        assert_eq!(s.beams_used(), 1);
    }
}
