//! DVL rows from Teledyne RDI PD0 ensembles (bottom track), for [`super::navigate`].
//!
//! Each good ensemble (see [`estim_dvl::read_pd0`]) becomes one [`DvlRecord`] at its
//! real-time clock, in the coordinate system its fixed leader declares (EX command):
//!
//! - **beam**: the four radial velocities are [`DvlInput::Beams`], solved by least
//!   squares on the beams present (4, or 3) with the RDI beam layout of
//!   [`rdi_beam_geometry`] (not the vehicle file's `beam1_azimuth_deg`, which is the
//!   layout of a beams CSV); a beam marked bad (-32768 mm/s) is a missing beam;
//! - **instrument** (X, Y, Z, error) and **ship** (starboard, forward, mast, error):
//!   the velocity in the DVL frame (x forward, y starboard, z down) is
//!   `-(Y, X, -Z)`, a [`DvlInput::Velocity`] used with the vehicle's DVL model (lever
//!   arm, mounting misalignment, scale factor) as a CSV velocity is; the instrument
//!   frame is taken with Y towards beam 3 (forward), X to starboard, Z up, so that
//!   instrument and ship coordinates differ only by the instrument's heading
//!   alignment (EA), which the vehicle's `dvl.mounting_misalignment_rad` then
//!   represents;
//! - **earth** (east, north, up, error): the vehicle's NED velocity is
//!   `-(N, E, -U)`, a [`DvlInput::EarthVelocity`]; the navigator rotates it into the
//!   body frame with the filter's own attitude at the update time (the nominal state
//!   after propagation to that time) and uses it as a DVL-frame velocity. The
//!   attitude error this brings into the measurement is not modelled (its correlation
//!   with the state is neglected); prefer beam coordinates where the instrument can
//!   output them.
//!
//! Signs and layout: the beam-to-instrument transform is RDI's as dolfyn (`lkilcher/
//! dolfyn`, `calc_beam_orientmat`) codes it, X = c a (b1 - b2), Y = c a (b4 - b3),
//! Z = b (b1 + b2 + b3 + b4), a = 1 / (2 sin theta), b = 1 / (4 cos theta), c = +1
//! convex, -1 concave, Z up for a down-looking head. RDI reports bottom track as the velocity of the bottom relative to the
//! instrument, and radial (beam) velocities as positive towards the transducer. The
//! two conventions give the same sign for a beam value as the project's
//! `beams = A v` (the vehicle's velocity projected on each beam's outward direction),
//! and the opposite sign for the three components, hence the minus signs above.
//!
//! An ensemble without bottom track, or a component system with one of its three
//! components marked bad, is [`DvlInput::NoLock`] (skipped and counted, as a lost lock
//! in a CSV). The error velocity (fourth value) is not used.

use estim_dvl::{BeamGeometry, CoordinateSystem, Pd0Ensemble};
use nalgebra::Vector3;
use serde::Serialize;

use super::{DvlInput, DvlRecord, NavigatorError, Result};

/// What the PD0 conversion found, for the run's summary.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Pd0Conversion {
    /// Ensembles per coordinate system (`beam`, `instrument`, `ship`, `earth`).
    pub beam: usize,
    /// See `beam`.
    pub instrument: usize,
    /// See `beam`.
    pub ship: usize,
    /// See `beam`.
    pub earth: usize,
    /// Ensembles without a bottom-track data type (no lock).
    pub without_bottom_track: usize,
    /// Beam values the instrument marked bad (-32768 mm/s), over all ensembles.
    pub bad_velocity_values: usize,
    /// The beam angle of the fixed leaders \[deg\] when they declare one (the first
    /// ensemble's; every ensemble must agree).
    pub beam_angle_deg: Option<f64>,
    /// Convex transducer head (system configuration bit 3; every ensemble must agree).
    pub convex: bool,
}

/// The beam layout of a down-looking RDI head in the DVL frame (x forward = towards
/// beam 3, y starboard, z down), each row the beam's outward look direction:
/// for a convex head (c = 1) beam 1 looks to port, 2 to starboard, 3 forward, 4 aft,
/// each `beam_angle_deg` from the z axis; a concave head (c = -1) looks the other way
/// (see the module docs for the transform it inverts).
///
/// # Errors
/// [`NavigatorError::InvalidValue`] for a beam angle outside (0, 90) deg.
pub fn rdi_beam_geometry(beam_angle_deg: f64, convex: bool) -> Result<BeamGeometry> {
    if !(beam_angle_deg > 0.0 && beam_angle_deg < 90.0) {
        return Err(NavigatorError::invalid(
            "PD0 beam angle",
            format!("{beam_angle_deg} deg is not in (0, 90)"),
        ));
    }
    let (s, k) = beam_angle_deg.to_radians().sin_cos();
    let c = if convex { 1.0 } else { -1.0 };
    Ok(BeamGeometry::from_unit_vectors([
        Vector3::new(0.0, -c * s, k),
        Vector3::new(0.0, c * s, k),
        Vector3::new(c * s, 0.0, k),
        Vector3::new(-c * s, 0.0, k),
    ])
    .build()?)
}

/// DVL rows of PD0 ensembles (see the module docs), times relative to `epoch_s`.
///
/// # Errors
/// [`NavigatorError::Pd0`] naming the ensemble's byte offset for an ensemble time not
/// after the previous one, an up-looking head (bottom track needs a down-looking
/// one), or a beam angle or head shape that differs from the first ensemble's.
pub fn pd0_records(
    ensembles: &[Pd0Ensemble],
    epoch_s: f64,
) -> Result<(Vec<DvlRecord>, Pd0Conversion)> {
    let mut records = Vec::with_capacity(ensembles.len());
    let mut c = Pd0Conversion {
        beam_angle_deg: ensembles
            .first()
            .and_then(|e| e.fixed_leader.beam_angle_deg),
        convex: ensembles.first().is_some_and(|e| e.fixed_leader.convex()),
        ..Pd0Conversion::default()
    };
    let mut previous: Option<f64> = None;
    for e in ensembles {
        if e.fixed_leader.upward_looking() {
            return Err(NavigatorError::Pd0 {
                offset: e.offset,
                reason: "the head looks up (system configuration bit 7); bottom track \
                         needs a down-looking DVL"
                    .into(),
            });
        }
        if e.fixed_leader.convex() != c.convex {
            return Err(NavigatorError::Pd0 {
                offset: e.offset,
                reason: "the head shape (convex / concave) differs from the first ensemble's"
                    .into(),
            });
        }
        if e.fixed_leader.beam_angle_deg != c.beam_angle_deg {
            return Err(NavigatorError::Pd0 {
                offset: e.offset,
                reason: format!(
                    "beam angle {:?} deg differs from the first ensemble's {:?} deg",
                    e.fixed_leader.beam_angle_deg, c.beam_angle_deg
                ),
            });
        }
        if let Some(p) = previous {
            if e.time_unix_s <= p {
                return Err(NavigatorError::Pd0 {
                    offset: e.offset,
                    reason: format!(
                        "ensemble {} at {} s (Unix) is not after the previous ensemble's {} s",
                        e.ensemble_number, e.time_unix_s, p
                    ),
                });
            }
        }
        previous = Some(e.time_unix_s);
        let system = e.coordinate_system();
        match system {
            CoordinateSystem::Beam => c.beam += 1,
            CoordinateSystem::Instrument => c.instrument += 1,
            CoordinateSystem::Ship => c.ship += 1,
            CoordinateSystem::Earth => c.earth += 1,
        }
        let input = match &e.bottom_track {
            None => {
                c.without_bottom_track += 1;
                DvlInput::NoLock
            }
            Some(bt) => {
                let v = bt.velocity_mps;
                c.bad_velocity_values += v.iter().filter(|b| b.is_none()).count();
                match (system, v[0], v[1], v[2]) {
                    (CoordinateSystem::Beam, ..) if v.iter().all(Option::is_none) => {
                        DvlInput::NoLock
                    }
                    (CoordinateSystem::Beam, ..) => DvlInput::Beams(v),
                    (
                        CoordinateSystem::Instrument | CoordinateSystem::Ship,
                        Some(x),
                        Some(y),
                        Some(z),
                    ) => DvlInput::Velocity(-Vector3::new(y, x, -z)),
                    (CoordinateSystem::Earth, Some(east), Some(north), Some(up)) => {
                        DvlInput::EarthVelocity(-Vector3::new(north, east, -up))
                    }
                    _ => DvlInput::NoLock,
                }
            }
        };
        records.push(DvlRecord {
            time: e.time_unix_s - epoch_s,
            input,
        });
    }
    Ok((records, c))
}
