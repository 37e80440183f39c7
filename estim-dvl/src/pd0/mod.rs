//! Teledyne RDI PD0 binary ensembles: reader, report of what was skipped, CSV writer.

use std::fmt;
use std::io::{Read, Write};
use std::path::Path;

use crate::error::{Error, Result};

mod decode;
use decode::{decode, find_header, frame, skip_span, Candidate, Rejection};

/// Both bytes of the header ID (WH "Header Data Format": HEADER ID 7Fh, DATA SOURCE ID 7Fh).
const HEADER_ID: u8 = 0x7F;
/// Bytes of the header before the data-type offset table (WH "Header Data Format").
const HEADER_BYTES: usize = 6;
/// The checksum that follows the `number of bytes in ensemble` counted bytes.
const CHECKSUM_BYTES: usize = 2;

const FIXED_LEADER_ID: u16 = 0x0000;
const VARIABLE_LEADER_ID: u16 = 0x0080;
const BOTTOM_TRACK_ID: u16 = 0x0600;

/// Fixed leader bytes read: up to the coordinate transform (byte 26, 1-based).
const FIXED_LEADER_MIN: usize = 26;
/// Fixed leader byte 59 (1-based): the beam angle, on firmware that writes it.
const FIXED_LEADER_BEAM_ANGLE: usize = 58;
/// Variable leader bytes read: up to the RTC hundredths and ensemble-number MSB (byte 12).
const VARIABLE_LEADER_MIN: usize = 12;
/// Variable leader bytes 58-65 (1-based): the Y2K real-time clock (century first).
const VARIABLE_LEADER_Y2K: usize = 57;
/// Bottom-track bytes read: ranges (bytes 17-24) and velocities (bytes 25-32).
const BOTTOM_TRACK_MIN: usize = 32;
/// Bottom-track bytes 78-81 (1-based): the most significant byte of each beam's range.
const BOTTOM_TRACK_RANGE_MSB: usize = 77;

/// The velocity value the instrument writes for a bad or missing velocity
/// (WH "Bottom-Track Data Format", BT velocity: -32768 marks a bad velocity).
const BAD_VELOCITY: i16 = i16::MIN;

/// Header of the CSV written by [`write_pd0_csv`].
pub const PD0_CSV_HEADER: &str = "time_unix_s,bt_velocity_1_mps,bt_velocity_2_mps,\
bt_velocity_3_mps,bt_velocity_4_mps,bt_range_1_m,bt_range_2_m,bt_range_3_m,bt_range_4_m,\
coordinate_system";

/// The coordinate system of the velocities, as the fixed leader's coordinate-transform
/// byte declares it (EX command; bits 4-3: 00 beam, 01 instrument, 10 ship, 11 earth).
///
/// The four bottom-track values of an ensemble are in this system:
/// - `Beam`: beams 1-4 along their own axes;
/// - `Instrument`: X, Y, Z and error velocity in the instrument frame;
/// - `Ship`: starboard, forward, mast and error velocity;
/// - `Earth`: east, north, up and error velocity.
///
/// Values are passed on as the instrument wrote them, with RDI's sign convention (see
/// the manual's bottom-track section); the reader changes no sign and no frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum CoordinateSystem {
    /// Radial beam velocities.
    Beam,
    /// Instrument frame (X, Y, Z, error).
    Instrument,
    /// Ship frame (starboard, forward, mast, error).
    Ship,
    /// Earth frame (east, north, up, error).
    Earth,
}

impl CoordinateSystem {
    /// The lower-case name written in the CSV (`beam`, `instrument`, `ship`, `earth`).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Beam => "beam",
            Self::Instrument => "instrument",
            Self::Ship => "ship",
            Self::Earth => "earth",
        }
    }
}

impl fmt::Display for CoordinateSystem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The fixed leader's coordinate-transform byte (WH "Fixed Leader Data Format",
/// COORD XFRM, the EX command): `xxxCCTPB` with CC the coordinate system, T tilts used,
/// P 3-beam solutions used, B bin mapping used.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct CoordinateTransform {
    /// Bits 4-3.
    pub system: CoordinateSystem,
    /// Bit 2: tilts (pitch and roll) used in the transformation.
    pub tilts_used: bool,
    /// Bit 1: 3-beam solutions used when one beam was bad.
    pub three_beam_used: bool,
    /// Bit 0: bin mapping used.
    pub bin_mapping_used: bool,
}

impl CoordinateTransform {
    /// Decodes the byte (bits 7-5 are unused and ignored).
    pub fn from_byte(byte: u8) -> Self {
        let system = match (byte >> 3) & 0b11 {
            0b00 => CoordinateSystem::Beam,
            0b01 => CoordinateSystem::Instrument,
            0b10 => CoordinateSystem::Ship,
            _ => CoordinateSystem::Earth,
        };
        Self {
            system,
            tilts_used: byte & 0b100 != 0,
            three_beam_used: byte & 0b10 != 0,
            bin_mapping_used: byte & 0b1 != 0,
        }
    }

    /// The byte that encodes this transform (unused bits zero).
    pub fn to_byte(self) -> u8 {
        let system = match self.system {
            CoordinateSystem::Beam => 0b00,
            CoordinateSystem::Instrument => 0b01,
            CoordinateSystem::Ship => 0b10,
            CoordinateSystem::Earth => 0b11,
        };
        (system << 3)
            | (u8::from(self.tilts_used) << 2)
            | (u8::from(self.three_beam_used) << 1)
            | u8::from(self.bin_mapping_used)
    }
}

/// What an ensemble's fixed leader says about the instrument's set-up
/// (WH "Fixed Leader Data Format"; byte numbers below are 1-based as in the manual).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FixedLeader {
    /// CPU firmware version (byte 3; e.g. 16 WorkHorse, 23 Ocean Surveyor).
    pub firmware_version: u8,
    /// CPU firmware revision (byte 4).
    pub firmware_revision: u8,
    /// System configuration word (bytes 5-6, LSB first): frequency, beam pattern,
    /// orientation, beam angle and beam configuration bits.
    pub system_configuration: u16,
    /// Number of beams (byte 9).
    pub number_of_beams: u8,
    /// Number of depth cells (byte 10, WN).
    pub number_of_cells: u8,
    /// Pings per ensemble (bytes 11-12, WP).
    pub pings_per_ensemble: u16,
    /// Depth-cell length in metres (bytes 13-14, WS, in cm).
    pub depth_cell_length_m: f64,
    /// Coordinate transform (byte 26, EX).
    pub coordinate_transform: CoordinateTransform,
    /// Beam angle from the vertical in degrees: from the system configuration (15, 20 or
    /// 30 deg), or, when it says "other", from byte 59 where the firmware writes it.
    /// `None` when neither tells.
    pub beam_angle_deg: Option<f64>,
}

impl FixedLeader {
    /// Transmit frequency in kHz from system-configuration bits 2-0 (75, 150, 300, 600,
    /// 1200, 2400); `None` for a code the manual does not list.
    pub fn frequency_khz(&self) -> Option<u32> {
        match self.system_configuration & 0b111 {
            0 => Some(75),
            1 => Some(150),
            2 => Some(300),
            3 => Some(600),
            4 => Some(1200),
            5 => Some(2400),
            _ => None,
        }
    }

    /// System-configuration bit 7: the transducer head looks up.
    pub fn upward_looking(&self) -> bool {
        self.system_configuration & 0x80 != 0
    }

    /// System-configuration bit 3: convex beam pattern (else concave).
    pub fn convex(&self) -> bool {
        self.system_configuration & 0x08 != 0
    }
}

/// The instrument's real-time clock at the ensemble (WH "Variable Leader Data Format":
/// RTC bytes 5-11, two-digit year; Y2K RTC bytes 58-65, with century).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct RealTimeClock {
    /// Full year. From the Y2K clock when the variable leader has one (century * 100 +
    /// year), else from the two-digit year: 80-99 are 1980-1999, 00-79 are 2000-2079.
    pub year: u16,
    /// Month, 1-12.
    pub month: u8,
    /// Day of the month, 1-31.
    pub day: u8,
    /// Hour, 0-23.
    pub hour: u8,
    /// Minute, 0-59.
    pub minute: u8,
    /// Second, 0-59.
    pub second: u8,
    /// Hundredths of a second, 0-99.
    pub hundredths: u8,
    /// The year came from the Y2K clock's century field.
    pub y2k_century: bool,
}

impl RealTimeClock {
    /// Seconds since 1970-01-01T00:00:00 UTC, reading the clock as UTC (the ensemble does
    /// not record a time zone; set the instrument clock to UTC). `None` when a field is
    /// out of range (month 13, 31 April, hour 24, ...).
    pub fn unix_seconds(&self) -> Option<f64> {
        let month_ok = (1..=12).contains(&self.month);
        if !month_ok
            || self.day == 0
            || self.day > days_in_month(self.year, self.month)
            || self.hour > 23
            || self.minute > 59
            || self.second > 59
            || self.hundredths > 99
        {
            return None;
        }
        let days = days_from_civil(
            i64::from(self.year),
            i64::from(self.month),
            i64::from(self.day),
        );
        let seconds = days * 86_400
            + i64::from(self.hour) * 3600
            + i64::from(self.minute) * 60
            + i64::from(self.second);
        // Whole hundredths first, one division: the closest double to the decimal time.
        Some((seconds * 100 + i64::from(self.hundredths)) as f64 / 100.0)
    }
}

fn is_leap(year: u16) -> bool {
    (year.is_multiple_of(4) && !year.is_multiple_of(100)) || year.is_multiple_of(400)
}

fn days_in_month(year: u16, month: u8) -> u8 {
    match month {
        1 | 3 | 5 | 7 | 8 | 10 | 12 => 31,
        4 | 6 | 9 | 11 => 30,
        2 if is_leap(year) => 29,
        2 => 28,
        _ => 0,
    }
}

/// Days from 1970-01-01 to a proleptic Gregorian date (H. Hinnant, "chrono-Compatible
/// Low-Level Date Algorithms", `days_from_civil`).
fn days_from_civil(year: i64, month: i64, day: i64) -> i64 {
    let y = if month <= 2 { year - 1 } else { year };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let mp = (month + 9) % 12;
    let doy = (153 * mp + 2) / 5 + day - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

/// Bottom-track velocities and ranges of one ensemble (WH "Bottom-Track Data Format":
/// BT range bytes 17-24 in cm, with the range MSB bytes 78-81 where present; BT velocity
/// bytes 25-32 in mm/s). `None` is a value the instrument marked bad: velocity -32768,
/// range 0 (no bottom detection on that beam).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BottomTrack {
    /// Four velocities in m/s, in the ensemble's [`CoordinateSystem`] (beams 1-4, or the
    /// three components and the error velocity).
    pub velocity_mps: [Option<f64>; 4],
    /// Vertical range to the bottom along each beam, in m (slant range times the cosine
    /// of the beam angle, as the instrument reports it).
    pub range_m: [Option<f64>; 4],
}

/// One good PD0 ensemble: its header length and checksum verified, its fixed and
/// variable leaders decoded, its clock valid.
#[derive(Debug, Clone, PartialEq)]
pub struct Pd0Ensemble {
    /// Byte offset of the ensemble's header in the input.
    pub offset: usize,
    /// Bytes the ensemble occupies in the input, checksum included.
    pub length: usize,
    /// Ensemble number (variable leader bytes 3-4, and byte 12 as the most significant
    /// byte: number = LSB word + 65536 * MSB).
    pub ensemble_number: u32,
    /// The real-time clock at the ensemble.
    pub clock: RealTimeClock,
    /// [`RealTimeClock::unix_seconds`] of `clock`, always valid here.
    pub time_unix_s: f64,
    /// The instrument's set-up, coordinate transform included.
    pub fixed_leader: FixedLeader,
    /// The bottom-track data type, when the ensemble has one.
    pub bottom_track: Option<BottomTrack>,
}

impl Pd0Ensemble {
    /// The coordinate system of the velocities (`fixed_leader.coordinate_transform.system`).
    pub fn coordinate_system(&self) -> CoordinateSystem {
        self.fixed_leader.coordinate_transform.system
    }
}

/// Why a span of the input did not give an ensemble.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum Pd0Issue {
    /// Bytes that do not start a PD0 ensemble (no 0x7F7F header whose length and
    /// checksum verify).
    #[error(
        "bytes that are not a PD0 ensemble (no 0x7F7F header whose length and checksum verify)"
    )]
    Garbage,
    /// The ensemble's declared length runs past the end of the input or into the next
    /// good ensemble.
    #[error("truncated ensemble: it declares {needed} bytes (checksum included), only {available} follow before the next good ensemble or the end")]
    Truncated {
        /// Bytes the header declares, checksum included (or the header size when even the
        /// length field is cut).
        needed: usize,
        /// Bytes present from the header to the next good ensemble or the end.
        available: usize,
    },
    /// The stored checksum differs from the sum of the ensemble's bytes.
    #[error("checksum error: stored {stored:#06x}, bytes sum to {computed:#06x}")]
    Checksum {
        /// The checksum in the file.
        stored: u16,
        /// The 16-bit sum of the ensemble's bytes.
        computed: u16,
    },
    /// The header is inconsistent (length shorter than the header, an offset outside the
    /// ensemble).
    #[error("malformed header: {reason}")]
    BadHeader {
        /// What is inconsistent.
        reason: &'static str,
    },
    /// A data type the reader needs is absent.
    #[error("no {name} (data type {id:#06x})")]
    MissingDataType {
        /// Its ID.
        id: u16,
        /// Its name in the manual.
        name: &'static str,
    },
    /// A data type is shorter than its fields the reader needs.
    #[error("{name} (data type {id:#06x}) has {length} bytes, at least {needed} are needed")]
    ShortDataType {
        /// Its ID.
        id: u16,
        /// Its name in the manual.
        name: &'static str,
        /// Its bytes in the ensemble.
        length: usize,
        /// The bytes the reader needs.
        needed: usize,
    },
    /// The real-time clock has a field out of range.
    #[error("invalid real-time clock {year:04}-{month:02}-{day:02} {hour:02}:{minute:02}:{second:02}.{hundredths:02}", year = clock.year, month = clock.month, day = clock.day, hour = clock.hour, minute = clock.minute, second = clock.second, hundredths = clock.hundredths)]
    InvalidClock {
        /// The clock as read.
        clock: RealTimeClock,
    },
}

/// A span of the input skipped by the reader.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Pd0Skip {
    /// Byte offset where the span starts.
    pub offset: usize,
    /// Bytes skipped (up to the next good ensemble or the end of the input).
    pub length: usize,
    /// Why: the problem of the ensemble starting at `offset`, or
    /// [`Pd0Issue::Garbage`] when no header starts there.
    pub issue: Pd0Issue,
}

impl From<Pd0Skip> for Error {
    fn from(skip: Pd0Skip) -> Self {
        Error::Pd0 {
            offset: skip.offset,
            length: skip.length,
            issue: skip.issue,
        }
    }
}

impl fmt::Display for Pd0Skip {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "byte {} ({} bytes skipped): {}",
            self.offset, self.length, self.issue
        )
    }
}

/// What the reader did with its input.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Pd0Report {
    /// Bytes of input.
    pub input_bytes: usize,
    /// Good ensembles decoded.
    pub decoded: usize,
    /// Good ensembles that have a bottom-track data type.
    pub with_bottom_track: usize,
    /// Spans skipped, in input order; with the good ensembles they tile the input.
    pub skipped: Vec<Pd0Skip>,
}

impl Pd0Report {
    /// No span was skipped.
    pub fn is_clean(&self) -> bool {
        self.skipped.is_empty()
    }

    /// Total bytes skipped.
    pub fn skipped_bytes(&self) -> usize {
        self.skipped.iter().map(|s| s.length).sum()
    }
}

impl fmt::Display for Pd0Report {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} ensembles decoded ({} with bottom track) from {} bytes; {} spans skipped ({} bytes)",
            self.decoded,
            self.with_bottom_track,
            self.input_bytes,
            self.skipped.len(),
            self.skipped_bytes()
        )?;
        for skip in &self.skipped {
            write!(f, "\n  {skip}")?;
        }
        Ok(())
    }
}

/// The good ensembles of a PD0 input and the report of what was skipped.
#[derive(Debug, Clone, PartialEq)]
pub struct Pd0Read {
    /// Good ensembles, in input order.
    pub ensembles: Vec<Pd0Ensemble>,
    /// Counts and skipped spans.
    pub report: Pd0Report,
}

impl Pd0Read {
    /// The ensembles if nothing was skipped, else the first skipped span as an
    /// [`Error::Pd0`] naming its byte offset.
    pub fn require_clean(self) -> Result<Vec<Pd0Ensemble>> {
        match self.report.skipped.into_iter().next() {
            Some(skip) => Err(skip.into()),
            None => Ok(self.ensembles),
        }
    }
}

/// Reads every good PD0 ensemble in `bytes`.
///
/// An ensemble is good when it starts with 0x7F7F, its declared length fits in the
/// input, its checksum (the 16-bit sum of its bytes, WH "Checksum Data Format")
/// verifies, its fixed and variable leaders are present and long enough, and its clock
/// is valid. Anything else (a truncated or corrupt ensemble, bytes between ensembles) is
/// skipped up to the next good ensemble and recorded in the report with its byte offset
/// and reason. Never panics. `bytes` is read as [`read_pd0_from`] reads a stream.
///
/// Format reference (cited as WH below, with the section name): Teledyne RD
/// Instruments, *WorkHorse Commands and Output Data Format*, P/N 957-6156-00 (March
/// 2005), chapter "Output Data Format", section "PD0 Output Format" and its subsections
/// "Header Data Format", "Fixed Leader Data Format", "Variable Leader Data Format",
/// "Bottom-Track Data Format" and "Checksum Data Format". Ocean Surveyor, Ocean Observer
/// and DVL (Navigator) firmware write the same header, leaders and bottom-track layout,
/// but their leaders may be shorter or longer (the Ocean Surveyor variable leader has no
/// Y2K clock), so every field beyond the minimum this reader needs is read only when
/// present. Public readers consulted for these differences: dolfyn's `io/rdi.py`.
pub fn read_pd0(bytes: &[u8]) -> Pd0Read {
    match read_pd0_from(bytes) {
        Ok(read) => read,
        // `Read` for a byte slice never fails.
        Err(e) => unreachable!("reading a byte slice failed: {e}"),
    }
}

/// Bytes read from the stream at a time by [`read_pd0_from`].
const READ_CHUNK: usize = 1 << 20;
/// The most bytes a candidate ensemble can span from its header: the 16-bit declared
/// length plus the checksum.
const MAX_ENSEMBLE_BYTES: usize = u16::MAX as usize + CHECKSUM_BYTES;

/// Reads every good PD0 ensemble from a stream, as [`read_pd0`] does on the whole
/// input, in bounded memory: the reader holds a window of the input (a chunk of 1 MiB
/// plus the longest ensemble a header can declare, 65,537 bytes) with one 16-bit
/// prefix sum per byte of the window, so that every resynchronisation candidate is
/// checked in constant time; what it keeps is the decoded ensembles and the report.
///
/// # Errors
/// The reader's error (an `Interrupted` read is retried).
pub fn read_pd0_from<R: Read>(reader: R) -> std::io::Result<Pd0Read> {
    read_pd0_window(reader).map(|(read, _)| read)
}

/// [`read_pd0_from`], and the most input bytes its window held at once.
fn read_pd0_window<R: Read>(reader: R) -> std::io::Result<(Pd0Read, usize)> {
    let mut window = Window::new(reader, READ_CHUNK);
    let mut ensembles = Vec::new();
    let mut skipped = Vec::new();
    // End of the last framed ensemble (length and checksum verified): where the reader
    // is in sync, and where the next skipped span would start.
    let mut sync_end = 0;
    // The problem of the candidate at `sync_end`, if it was rejected.
    let mut first_issue: Option<Rejection> = None;
    let mut search = 0;
    loop {
        // Every candidate is examined with its longest possible ensemble in the window
        // (or the whole rest of the input), as if the input were whole.
        window.cover(search, MAX_ENSEMBLE_BYTES)?;
        let Some(relative) = find_header(&window.bytes, search - window.base) else {
            if window.eof {
                break;
            }
            // The window's last byte may begin a header; the loop's `cover` moves the
            // window there.
            search = window.end().saturating_sub(1).max(search);
            continue;
        };
        let start = window.base + relative;
        if !window.eof && start + MAX_ENSEMBLE_BYTES > window.end() {
            search = start;
            continue;
        }
        let candidate = match frame(&window.bytes, &window.sums, relative) {
            Ok(length) => match decode(&window.bytes, relative, length) {
                Ok(mut ensemble) => {
                    ensemble.offset = start;
                    Candidate::Good(ensemble)
                }
                Err(issue) => Candidate::Undecodable(issue, length),
            },
            Err(rejection) => Candidate::Rejected(rejection),
        };
        match candidate {
            Candidate::Good(ensemble) => {
                if start > sync_end {
                    skipped.push(skip_span(sync_end, start, first_issue.take()));
                }
                first_issue = None;
                sync_end = start + ensemble.length;
                search = sync_end;
                ensembles.push(ensemble);
            }
            // In sync, a verified ensemble that does not decode is skipped whole. Out of
            // sync (inside garbage) only a decodable one resynchronises, so that a false
            // header whose checksum happens to match cannot swallow a good ensemble.
            Candidate::Undecodable(issue, length) if start == sync_end => {
                skipped.push(Pd0Skip {
                    offset: start,
                    length,
                    issue,
                });
                first_issue = None;
                sync_end = start + length;
                search = sync_end;
            }
            Candidate::Undecodable(..) => search = start + 1,
            Candidate::Rejected(rejection) => {
                if start == sync_end {
                    first_issue = Some(rejection);
                }
                search = start + 1;
            }
        }
    }
    let input_bytes = window.end();
    if input_bytes > sync_end {
        skipped.push(skip_span(sync_end, input_bytes, first_issue));
    }
    let with_bottom_track = ensembles
        .iter()
        .filter(|e| e.bottom_track.is_some())
        .count();
    let read = Pd0Read {
        report: Pd0Report {
            input_bytes,
            decoded: ensembles.len(),
            with_bottom_track,
            skipped,
        },
        ensembles,
    };
    Ok((read, window.peak))
}

/// The part of a PD0 stream the reader looks at: `bytes` from input offset `base`,
/// their wrapping 16-bit prefix sums (`sums[i]` = sum of `bytes[..i]`), and whether
/// the stream has ended.
struct Window<R> {
    reader: R,
    chunk: usize,
    /// What one read fills before it is appended to `bytes`.
    scratch: Vec<u8>,
    bytes: Vec<u8>,
    sums: Vec<u16>,
    base: usize,
    eof: bool,
    /// The most bytes `bytes` held at once.
    peak: usize,
}

impl<R: Read> Window<R> {
    fn new(reader: R, chunk: usize) -> Self {
        Self {
            reader,
            chunk,
            scratch: vec![0; chunk.min(1 << 16)],
            bytes: Vec::new(),
            sums: vec![0],
            base: 0,
            eof: false,
            peak: 0,
        }
    }

    /// Input offset one past the window's last byte (the input's length once `eof`).
    fn end(&self) -> usize {
        self.base + self.bytes.len()
    }

    /// Make the window hold input `[from, from + need)`, or everything from `from` to
    /// the end of the input; bytes before `from` are dropped. Reads a chunk beyond
    /// what is needed, so that the window moves (and its sums are recomputed) once per
    /// chunk of progress.
    fn cover(&mut self, from: usize, need: usize) -> std::io::Result<()> {
        if self.eof || self.end() >= from + need {
            return Ok(());
        }
        let drop = from.saturating_sub(self.base).min(self.bytes.len());
        self.bytes.drain(..drop);
        self.base += drop;
        let target = need + self.chunk;
        while !self.eof && self.bytes.len() < target {
            let want = (target - self.bytes.len()).min(self.scratch.len());
            match self.reader.read(&mut self.scratch[..want]) {
                Ok(0) => self.eof = true,
                Ok(n) => self.bytes.extend_from_slice(&self.scratch[..n]),
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        self.peak = self.peak.max(self.bytes.len());
        self.sums.clear();
        self.sums.push(0);
        let mut sum = 0u16;
        for &b in &self.bytes {
            sum = sum.wrapping_add(u16::from(b));
            self.sums.push(sum);
        }
        Ok(())
    }
}

/// Reads a PD0 file with [`read_pd0_from`] (in bounded memory). Fails only when the
/// file cannot be read.
pub fn read_pd0_file(path: impl AsRef<Path>) -> Result<Pd0Read> {
    let path = path.as_ref();
    let io = |e: std::io::Error| Error::Io {
        path: path.to_path_buf(),
        kind: e.kind(),
        message: e.to_string(),
    };
    let file = std::fs::File::open(path).map_err(io)?;
    read_pd0_from(file).map_err(io)
}

/// Writes the ensembles as CSV: the [`PD0_CSV_HEADER`] line, then one row per ensemble
/// with its time (Unix seconds, UTC), the four bottom-track velocities (m/s) and ranges
/// (m) in the file's own coordinate system, and that system's name. A value the
/// instrument marked bad is an empty cell, and so are all eight of an ensemble without
/// bottom track.
pub fn write_pd0_csv<W: Write>(ensembles: &[Pd0Ensemble], mut out: W) -> std::io::Result<()> {
    writeln!(out, "{PD0_CSV_HEADER}")?;
    for e in ensembles {
        write!(out, "{}", e.time_unix_s)?;
        let (velocity, range) = match &e.bottom_track {
            Some(bt) => (bt.velocity_mps, bt.range_m),
            None => ([None; 4], [None; 4]),
        };
        for value in velocity.iter().chain(range.iter()) {
            match value {
                Some(v) => write!(out, ",{v}")?,
                None => write!(out, ",")?,
            }
        }
        writeln!(out, ",{}", e.coordinate_system())?;
    }
    out.flush()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The window stays within one chunk plus the longest ensemble, whatever the
    /// input's length: 40 MiB of zeros (no header), of 0x7F bytes (a header candidate
    /// at every byte, each declaring 32,639 bytes) and of a repeated false header.
    #[test]
    fn the_window_is_bounded_on_long_inputs() {
        let bound = READ_CHUNK + MAX_ENSEMBLE_BYTES;
        let len = 40 << 20;
        for (name, byte) in [("zeros", 0u8), ("0x7F", 0x7F)] {
            let (read, peak) =
                read_pd0_window(std::io::repeat(byte).take(len as u64)).expect("read");
            assert_eq!(read.report.input_bytes, len, "{name}");
            assert!(read.ensembles.is_empty(), "{name}");
            assert!(peak <= bound, "{name}: window of {peak} bytes");
        }
        let header: Vec<u8> = [0x7F, 0x7F, 0x60, 0xEA, 0x00, 0x01]
            .iter()
            .copied()
            .cycle()
            .take(len / 8)
            .collect();
        let (read, peak) = read_pd0_window(header.as_slice()).expect("read");
        assert_eq!(read.report.input_bytes, len / 8);
        assert!(peak <= bound, "false headers: window of {peak} bytes");
    }

    #[test]
    fn days_from_civil_matches_known_dates() {
        assert_eq!(days_from_civil(1970, 1, 1), 0);
        assert_eq!(days_from_civil(2000, 3, 1), 11_017);
        assert_eq!(days_from_civil(2022, 3, 14), 19_065);
        assert_eq!(days_from_civil(1969, 12, 31), -1);
    }

    #[test]
    fn coordinate_transform_byte_round_trips() {
        for byte in 0u8..32 {
            assert_eq!(CoordinateTransform::from_byte(byte).to_byte(), byte);
        }
        assert_eq!(
            CoordinateTransform::from_byte(0b1110_0000).system,
            CoordinateSystem::Beam
        );
    }

    #[test]
    fn clock_rejects_out_of_range_fields() {
        let ok = RealTimeClock {
            year: 2024,
            month: 2,
            day: 29,
            hour: 23,
            minute: 59,
            second: 59,
            hundredths: 99,
            y2k_century: true,
        };
        assert!(ok.unix_seconds().is_some());
        assert!(RealTimeClock { year: 2023, ..ok }.unix_seconds().is_none());
        assert!(RealTimeClock { month: 13, ..ok }.unix_seconds().is_none());
        assert!(RealTimeClock { hour: 24, ..ok }.unix_seconds().is_none());
        assert!(RealTimeClock {
            hundredths: 100,
            ..ok
        }
        .unix_seconds()
        .is_none());
    }
}
