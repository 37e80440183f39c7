//! Framing and decoding of one PD0 ensemble: the header and checksum of a 0x7F7F
//! candidate, its data-type offsets, and the fixed leader, variable leader (clock) and
//! bottom-track records the reader keeps (Teledyne RDI "WorkHorse Commands and Output
//! Data Format", the sections cited at each item).

use super::*;

pub(super) fn find_header(bytes: &[u8], from: usize) -> Option<usize> {
    let rest = bytes.get(from..)?;
    rest.windows(2)
        .position(|w| w[0] == HEADER_ID && w[1] == HEADER_ID)
        .map(|i| from + i)
}

fn u16_at(bytes: &[u8], at: usize) -> Option<u16> {
    let b = bytes.get(at..at.checked_add(2)?)?;
    Some(u16::from_le_bytes([b[0], b[1]]))
}

fn i16_at(bytes: &[u8], at: usize) -> Option<i16> {
    u16_at(bytes, at).map(|v| v as i16)
}

/// A rejected candidate: the issue and the bytes it declared (0 when unknown).
pub(super) type Rejection = (Pd0Issue, usize);

/// What a 0x7F7F candidate turned out to be.
pub(super) enum Candidate {
    /// Framed and decoded.
    Good(Pd0Ensemble),
    /// Length and checksum verified (the length, checksum included), but not decodable.
    Undecodable(Pd0Issue, usize),
    /// Length or checksum did not verify.
    Rejected(Rejection),
}

/// Checks the header length and checksum of the candidate at `start`; returns the
/// ensemble's length in the input, checksum included.
pub(super) fn frame(
    bytes: &[u8],
    sums: &[u16],
    start: usize,
) -> std::result::Result<usize, Rejection> {
    let available = bytes.len() - start;
    // WH "Header Data Format": bytes 3-4 are the number of bytes in the ensemble,
    // counted from the header ID up to, not including, the checksum.
    let Some(declared) = u16_at(bytes, start + 2) else {
        let needed = HEADER_BYTES + CHECKSUM_BYTES;
        return Err((Pd0Issue::Truncated { needed, available }, needed));
    };
    let declared = usize::from(declared);
    if declared < HEADER_BYTES {
        return Err((
            Pd0Issue::BadHeader {
                reason: "declared length shorter than the header",
            },
            0,
        ));
    }
    let needed = declared + CHECKSUM_BYTES;
    if needed > available {
        return Err((Pd0Issue::Truncated { needed, available }, needed));
    }
    let end = start + declared;
    // WH "Checksum Data Format": the sum of all ensemble bytes, excluding the checksum,
    // kept to 16 bits (the manual calls it modulo 65535; the sum wraps at 65536, which
    // every ensemble of the real file in the tests confirms).
    let computed = sums[end].wrapping_sub(sums[start]);
    let stored = u16::from_le_bytes([bytes[end], bytes[end + 1]]);
    if computed != stored {
        return Err((Pd0Issue::Checksum { stored, computed }, needed));
    }
    Ok(needed)
}

/// The skipped span `[from, to)`; a checksum failure whose declared length overlaps the
/// next good ensemble was a truncated ensemble.
pub(super) fn skip_span(from: usize, to: usize, first_issue: Option<Rejection>) -> Pd0Skip {
    let length = to - from;
    let issue = match first_issue {
        None => Pd0Issue::Garbage,
        Some((Pd0Issue::Checksum { .. }, needed)) if needed > length => Pd0Issue::Truncated {
            needed,
            available: length,
        },
        Some((Pd0Issue::Truncated { needed, .. }, _)) => Pd0Issue::Truncated {
            needed,
            available: length,
        },
        Some((issue, _)) => issue,
    };
    Pd0Skip {
        offset: from,
        length,
        issue,
    }
}

/// Decodes the framed ensemble at `start` (`length` bytes with the checksum).
pub(super) fn decode(
    bytes: &[u8],
    start: usize,
    length: usize,
) -> std::result::Result<Pd0Ensemble, Pd0Issue> {
    let ensemble = &bytes[start..start + length - CHECKSUM_BYTES];
    let data_types = DataTypes::parse(ensemble)?;
    let fixed = data_types
        .get(ensemble, FIXED_LEADER_ID, "fixed leader", FIXED_LEADER_MIN)?
        .ok_or(Pd0Issue::MissingDataType {
            id: FIXED_LEADER_ID,
            name: "fixed leader",
        })?;
    let variable = data_types
        .get(
            ensemble,
            VARIABLE_LEADER_ID,
            "variable leader",
            VARIABLE_LEADER_MIN,
        )?
        .ok_or(Pd0Issue::MissingDataType {
            id: VARIABLE_LEADER_ID,
            name: "variable leader",
        })?;
    let bottom = data_types.get(
        ensemble,
        BOTTOM_TRACK_ID,
        "bottom-track data",
        BOTTOM_TRACK_MIN,
    )?;

    let fixed_leader = decode_fixed_leader(fixed);
    let clock = decode_clock(variable);
    let time_unix_s = clock
        .unix_seconds()
        .ok_or(Pd0Issue::InvalidClock { clock })?;
    // Variable leader bytes 3-4 (LSB word) and 12 (MSB): the ensemble number.
    let ensemble_number =
        u32::from(u16::from_le_bytes([variable[2], variable[3]])) + (u32::from(variable[11]) << 16);
    Ok(Pd0Ensemble {
        offset: start,
        length,
        ensemble_number,
        clock,
        time_unix_s,
        fixed_leader,
        bottom_track: bottom.map(decode_bottom_track),
    })
}

/// The data-type offset table of an ensemble (WH "Header Data Format": byte 6 the
/// number of data types, then one 2-byte offset per data type from the header start).
struct DataTypes {
    /// (offset, id), sorted by offset.
    entries: Vec<(usize, u16)>,
}

impl DataTypes {
    fn parse(ensemble: &[u8]) -> std::result::Result<Self, Pd0Issue> {
        let count = usize::from(ensemble[5]);
        let table_end = HEADER_BYTES + 2 * count;
        if table_end > ensemble.len() {
            return Err(Pd0Issue::BadHeader {
                reason: "the data-type offset table runs past the ensemble",
            });
        }
        let mut entries = Vec::with_capacity(count);
        for i in 0..count {
            let offset = u16_at(ensemble, HEADER_BYTES + 2 * i).map(usize::from);
            let id = offset.and_then(|o| {
                if o >= table_end {
                    u16_at(ensemble, o)
                } else {
                    None
                }
            });
            match (offset, id) {
                (Some(o), Some(id)) => entries.push((o, id)),
                _ => {
                    return Err(Pd0Issue::BadHeader {
                        reason: "a data-type offset points outside the ensemble's data",
                    })
                }
            }
        }
        entries.sort_unstable();
        Ok(Self { entries })
    }

    /// The bytes of the first data type with this ID (up to the next data type or the
    /// checksum), checked to have at least `needed` bytes.
    fn get<'a>(
        &self,
        ensemble: &'a [u8],
        id: u16,
        name: &'static str,
        needed: usize,
    ) -> std::result::Result<Option<&'a [u8]>, Pd0Issue> {
        let Some(index) = self.entries.iter().position(|&(_, i)| i == id) else {
            return Ok(None);
        };
        let start = self.entries[index].0;
        let end = self
            .entries
            .iter()
            .map(|&(o, _)| o)
            .find(|&o| o > start)
            .unwrap_or(ensemble.len());
        let data = &ensemble[start..end];
        if data.len() < needed {
            return Err(Pd0Issue::ShortDataType {
                id,
                name,
                length: data.len(),
                needed,
            });
        }
        Ok(Some(data))
    }
}

/// WH "Fixed Leader Data Format" (0-based byte indices here; the manual counts from 1).
fn decode_fixed_leader(fixed: &[u8]) -> FixedLeader {
    let system_configuration = u16::from_le_bytes([fixed[4], fixed[5]]);
    // System configuration MSB bits 1-0: 00 15 deg, 01 20 deg, 10 30 deg, 11 other.
    let beam_angle_deg = match (system_configuration >> 8) & 0b11 {
        0b00 => Some(15.0),
        0b01 => Some(20.0),
        0b10 => Some(30.0),
        _ => fixed
            .get(FIXED_LEADER_BEAM_ANGLE)
            .filter(|&&a| a != 0)
            .map(|&a| f64::from(a)),
    };
    FixedLeader {
        firmware_version: fixed[2],
        firmware_revision: fixed[3],
        system_configuration,
        number_of_beams: fixed[8],
        number_of_cells: fixed[9],
        pings_per_ensemble: u16::from_le_bytes([fixed[10], fixed[11]]),
        depth_cell_length_m: f64::from(u16::from_le_bytes([fixed[12], fixed[13]])) / 100.0,
        coordinate_transform: CoordinateTransform::from_byte(fixed[25]),
        beam_angle_deg,
    }
}

/// WH "Variable Leader Data Format": RTC (bytes 5-11) or, when present with a nonzero
/// century, the Y2K RTC (bytes 58-65).
fn decode_clock(variable: &[u8]) -> RealTimeClock {
    if let Some(y2k) = variable.get(VARIABLE_LEADER_Y2K..VARIABLE_LEADER_Y2K + 8) {
        if y2k[0] != 0 {
            return RealTimeClock {
                year: u16::from(y2k[0]) * 100 + u16::from(y2k[1]),
                month: y2k[2],
                day: y2k[3],
                hour: y2k[4],
                minute: y2k[5],
                second: y2k[6],
                hundredths: y2k[7],
                y2k_century: true,
            };
        }
    }
    let yy = u16::from(variable[4]);
    RealTimeClock {
        year: if yy >= 80 { 1900 + yy } else { 2000 + yy },
        month: variable[5],
        day: variable[6],
        hour: variable[7],
        minute: variable[8],
        second: variable[9],
        hundredths: variable[10],
        y2k_century: false,
    }
}

/// WH "Bottom-Track Data Format": range LSB words at bytes 17-24 (cm), velocities at
/// bytes 25-32 (mm/s), range MSB bytes at 78-81 where the data type is that long.
fn decode_bottom_track(bottom: &[u8]) -> BottomTrack {
    let mut velocity_mps = [None; 4];
    let mut range_m = [None; 4];
    for beam in 0..4 {
        let velocity = i16_at(bottom, 24 + 2 * beam).unwrap_or(BAD_VELOCITY);
        velocity_mps[beam] = (velocity != BAD_VELOCITY).then(|| f64::from(velocity) / 1000.0);
        let lsb = u32::from(u16_at(bottom, 16 + 2 * beam).unwrap_or(0));
        let msb = u32::from(
            bottom
                .get(BOTTOM_TRACK_RANGE_MSB + beam)
                .copied()
                .unwrap_or(0),
        );
        let range_cm = lsb + (msb << 16);
        range_m[beam] = (range_cm != 0).then(|| f64::from(range_cm) / 100.0);
    }
    BottomTrack {
        velocity_mps,
        range_m,
    }
}
