//! The PD0 reader against ensembles encoded here from the documented format (Teledyne
//! RD Instruments, *WorkHorse Commands and Output Data Format*, P/N 957-6156-00, "PD0
//! Output Format"; byte numbers in the comments are the manual's, 1-based), against
//! corrupt input (truncated, checksum error, garbage between ensembles, arbitrary bytes),
//! and on a real recording compared with another reader's decode.
//!
//! Real-file data rule: `pd0/vmdas02_os.ENR` is looked up in `ESTIM_DATA_DIR`, then
//! `../shared/data` beside the workspace; if absent the test prints why and returns,
//! unless `ESTIM_REQUIRE_DATA=1`. The expected values in
//! `tests/data/pd0_vmdas02_os_dolfyn.csv` were written by dolfyn 1.3.0 through
//! `training/pd0_expected_dolfyn.py` (never run by the tests).

use std::path::PathBuf;

use estim_dvl::{
    read_pd0, read_pd0_file, write_pd0_csv, CoordinateSystem, CoordinateTransform, Error, Pd0Issue,
    Pd0Read, PD0_CSV_HEADER,
};
use proptest::prelude::*;
use proptest::test_runner::{FileFailurePersistence, RngSeed};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

// ---------------------------------------------------------------------------------------
// An encoder written from the manual, independent of the reader.
// ---------------------------------------------------------------------------------------

#[derive(Debug, Clone)]
struct Spec {
    number: u32,
    year: u16,
    month: u8,
    day: u8,
    hour: u8,
    minute: u8,
    second: u8,
    hundredths: u8,
    /// Write the 65-byte variable leader with the Y2K clock (bytes 58-65); else a
    /// 60-byte one with the two-digit year only (as Ocean Surveyor firmware does).
    y2k: bool,
    /// Fixed leader byte 26 (EX).
    transform: u8,
    /// Fixed leader bytes 5-6.
    system_configuration: u16,
    /// Fixed leader byte 59.
    beam_angle_byte: u8,
    /// Bottom track: velocities in mm/s and ranges in cm (24-bit: LSB word + MSB byte).
    bottom: Option<([i16; 4], [u32; 4])>,
    /// Bytes of the bottom-track data type (85 WorkHorse; below 81 it has no range MSB).
    bottom_len: usize,
    /// Depth cells of a velocity profile data type (0x0100) placed before bottom track.
    cells: u8,
    /// Leave out the variable leader.
    no_variable_leader: bool,
}

impl Spec {
    fn typical(number: u32) -> Self {
        Self {
            number,
            year: 2022,
            month: 3,
            day: 14,
            hour: 19,
            minute: 29,
            second: 10,
            hundredths: 8,
            y2k: true,
            transform: 0b0000_0111, // beam, tilts, 3-beam, bin mapping flags
            system_configuration: 0x4A_C1, // 150 kHz, convex, down, 30 deg, 4-beam janus
            beam_angle_byte: 0,
            bottom: Some(([-49, 52, 37, -31], [34_783, 33_445, 33_111, 34_114])),
            bottom_len: 85,
            cells: 3,
            no_variable_leader: false,
        }
    }

    fn time_unix_s(&self) -> f64 {
        unix_time_by_counting(
            self.year,
            self.month,
            self.day,
            self.hour,
            self.minute,
            self.second,
        ) + f64::from(self.hundredths) / 100.0
    }
}

fn put_u16(buf: &mut [u8], at: usize, v: u16) {
    buf[at..at + 2].copy_from_slice(&v.to_le_bytes());
}

/// Fixed leader, 59 bytes ("Fixed Leader Data Format").
fn fixed_leader(spec: &Spec) -> Vec<u8> {
    let mut b = vec![0u8; 59];
    put_u16(&mut b, 0, 0x0000); // bytes 1-2: ID
    b[2] = 16; // byte 3: CPU firmware version
    b[3] = 21; // byte 4: revision
    put_u16(&mut b, 4, spec.system_configuration); // bytes 5-6
    b[8] = 4; // byte 9: number of beams
    b[9] = spec.cells; // byte 10: WN
    put_u16(&mut b, 10, 1); // bytes 11-12: WP
    put_u16(&mut b, 12, 400); // bytes 13-14: WS, cm
    b[25] = spec.transform; // byte 26: EX
    b[58] = spec.beam_angle_byte; // byte 59
    b
}

/// Variable leader, 65 bytes with the Y2K clock or 60 without ("Variable Leader Data
/// Format").
fn variable_leader(spec: &Spec) -> Vec<u8> {
    let mut b = vec![0u8; if spec.y2k { 65 } else { 60 }];
    put_u16(&mut b, 0, 0x0080); // bytes 1-2: ID
    put_u16(&mut b, 2, (spec.number & 0xFFFF) as u16); // bytes 3-4: ensemble number
    b[4] = (spec.year % 100) as u8; // bytes 5-11: RTC
    b[5] = spec.month;
    b[6] = spec.day;
    b[7] = spec.hour;
    b[8] = spec.minute;
    b[9] = spec.second;
    b[10] = spec.hundredths;
    b[11] = (spec.number >> 16) as u8; // byte 12: ensemble number MSB
    put_u16(&mut b, 14, 1500); // bytes 15-16: speed of sound
    if spec.y2k {
        b[57] = (spec.year / 100) as u8; // bytes 58-65: Y2K RTC
        b[58] = (spec.year % 100) as u8;
        b[59] = spec.month;
        b[60] = spec.day;
        b[61] = spec.hour;
        b[62] = spec.minute;
        b[63] = spec.second;
        b[64] = spec.hundredths;
    }
    b
}

/// Velocity profile (0x0100): 2 + 8 bytes per cell, every value bad.
fn velocity_profile(spec: &Spec) -> Vec<u8> {
    let mut b = vec![0u8; 2 + 8 * usize::from(spec.cells)];
    put_u16(&mut b, 0, 0x0100);
    for i in 0..4 * usize::from(spec.cells) {
        put_u16(&mut b, 2 + 2 * i, 0x8000);
    }
    b
}

/// Bottom track ("Bottom-Track Data Format"): ranges bytes 17-24, velocities 25-32,
/// range MSBs 78-81.
fn bottom_track(spec: &Spec, velocity: [i16; 4], range_cm: [u32; 4]) -> Vec<u8> {
    let mut b = vec![0u8; spec.bottom_len];
    put_u16(&mut b, 0, 0x0600);
    put_u16(&mut b, 2, 1); // bytes 3-4: BP
    for beam in 0..4 {
        put_u16(&mut b, 16 + 2 * beam, (range_cm[beam] & 0xFFFF) as u16);
        put_u16(&mut b, 24 + 2 * beam, velocity[beam] as u16);
        if spec.bottom_len >= 81 {
            b[77 + beam] = (range_cm[beam] >> 16) as u8;
        }
    }
    b
}

/// A whole ensemble: header ("Header Data Format"), data types, checksum ("Checksum Data
/// Format": sum of every byte before it, modulo 65536).
fn encode(spec: &Spec) -> Vec<u8> {
    let mut types = vec![fixed_leader(spec)];
    if !spec.no_variable_leader {
        types.push(variable_leader(spec));
    }
    if spec.cells > 0 {
        types.push(velocity_profile(spec));
    }
    if let Some((velocity, range)) = spec.bottom {
        types.push(bottom_track(spec, velocity, range));
    }
    let header_len = 6 + 2 * types.len();
    let total: usize = header_len + types.iter().map(Vec::len).sum::<usize>();
    // Bytes 1-2 header ID, 3-4 bytes before the checksum, 5 spare, 6 number of types.
    let mut out = vec![0x7F, 0x7F, 0, 0, 0, types.len() as u8];
    put_u16(&mut out, 2, total as u16);
    let mut offset = header_len;
    for t in &types {
        out.extend_from_slice(&(offset as u16).to_le_bytes());
        offset += t.len();
    }
    for t in &types {
        out.extend_from_slice(t);
    }
    assert_eq!(out.len(), total);
    let sum = out.iter().fold(0u16, |s, &b| s.wrapping_add(u16::from(b)));
    out.extend_from_slice(&sum.to_le_bytes());
    out
}

/// Rewrites the checksum of a single encoded ensemble after its bytes were edited.
fn refresh_checksum(ensemble: &mut [u8]) {
    let end = ensemble.len() - 2;
    let sum = ensemble[..end]
        .iter()
        .fold(0u16, |s, &b| s.wrapping_add(u16::from(b)));
    ensemble[end..].copy_from_slice(&sum.to_le_bytes());
}

fn is_leap(y: u16) -> bool {
    (y.is_multiple_of(4) && !y.is_multiple_of(100)) || y.is_multiple_of(400)
}

/// Unix time by counting days year by year (independent of the reader's algorithm).
fn unix_time_by_counting(year: u16, month: u8, day: u8, hour: u8, minute: u8, second: u8) -> f64 {
    let mut days: i64 = 0;
    if year >= 1970 {
        for y in 1970..year {
            days += if is_leap(y) { 366 } else { 365 };
        }
    } else {
        for y in year..1970 {
            days -= if is_leap(y) { 366 } else { 365 };
        }
    }
    let month_days = [
        31,
        if is_leap(year) { 29 } else { 28 },
        31,
        30,
        31,
        30,
        31,
        31,
        30,
        31,
        30,
        31,
    ];
    days += month_days[..usize::from(month - 1)].iter().sum::<i64>();
    days += i64::from(day) - 1;
    (days * 86_400 + i64::from(hour) * 3600 + i64::from(minute) * 60 + i64::from(second)) as f64
}

fn random_spec(rng: &mut ChaCha8Rng, number: u32) -> Spec {
    let y2k = rng.random_range(0..2) == 1;
    let year = rng.random_range(1980..2080);
    let month = rng.random_range(1..=12);
    let month_days = [
        31,
        if is_leap(year) { 29 } else { 28 },
        31,
        30,
        31,
        30,
        31,
        31,
        30,
        31,
        30,
        31,
    ];
    let day = rng.random_range(1..=month_days[usize::from(month - 1)]);
    let mut velocity = [0i16; 4];
    let mut range = [0u32; 4];
    for beam in 0..4 {
        velocity[beam] = match rng.random_range(0..10) {
            0 => i16::MIN,
            1 => i16::MIN + 1,
            _ => rng.random_range(-5000..5000),
        };
        range[beam] = match rng.random_range(0..10) {
            0 => 0,
            1 => rng.random_range(65_536..(1 << 24)),
            _ => rng.random_range(1..65_536),
        };
    }
    let bottom_len = [85, 81, 77, 34][rng.random_range(0..4)];
    Spec {
        number,
        year,
        month,
        day,
        hour: rng.random_range(0..24),
        minute: rng.random_range(0..60),
        second: rng.random_range(0..60),
        hundredths: rng.random_range(0..100),
        y2k,
        transform: rng.random_range(0..32),
        system_configuration: rng.random_range(0..=u16::MAX),
        beam_angle_byte: rng.random_range(0..=255),
        bottom: (rng.random_range(0..8) != 0).then_some((velocity, range)),
        bottom_len,
        cells: rng.random_range(0..20),
        no_variable_leader: false,
    }
}

fn concat(specs: &[Spec]) -> (Vec<u8>, Vec<usize>) {
    let mut bytes = Vec::new();
    let mut offsets = Vec::new();
    for s in specs {
        offsets.push(bytes.len());
        bytes.extend(encode(s));
    }
    (bytes, offsets)
}

/// The good ensembles and the skipped spans cover the input in order, without gaps or
/// overlaps, and the counts agree.
fn assert_tiles(read: &Pd0Read, len: usize) {
    let mut spans: Vec<(usize, usize)> = read
        .ensembles
        .iter()
        .map(|e| (e.offset, e.length))
        .chain(read.report.skipped.iter().map(|s| (s.offset, s.length)))
        .collect();
    spans.sort_unstable();
    let mut at = 0;
    for (offset, length) in spans {
        assert_eq!(offset, at, "spans {:?}", read.report);
        assert!(length > 0);
        at += length;
    }
    assert_eq!(at, len);
    assert_eq!(read.report.input_bytes, len);
    assert_eq!(read.report.decoded, read.ensembles.len());
}

// ---------------------------------------------------------------------------------------
// Round trips
// ---------------------------------------------------------------------------------------

#[test]
fn encoded_ensembles_round_trip() {
    let mut rng = ChaCha8Rng::seed_from_u64(27);
    let specs: Vec<Spec> = (0..200)
        .map(|k| random_spec(&mut rng, 1 + k * 977))
        .collect();
    let (bytes, offsets) = concat(&specs);
    let read = read_pd0(&bytes);
    assert!(read.report.is_clean(), "{}", read.report);
    assert_eq!(read.ensembles.len(), specs.len());
    assert_tiles(&read, bytes.len());
    for ((spec, e), offset) in specs.iter().zip(&read.ensembles).zip(&offsets) {
        assert_eq!(e.offset, *offset);
        assert_eq!(e.ensemble_number, spec.number);
        assert_eq!(e.clock.year, spec.year);
        assert_eq!(e.clock.y2k_century, spec.y2k);
        assert!(
            (e.time_unix_s - spec.time_unix_s()).abs() < 1e-6,
            "{spec:?}"
        );
        assert_eq!(
            e.fixed_leader.coordinate_transform.to_byte(),
            spec.transform
        );
        assert_eq!(
            e.fixed_leader.system_configuration,
            spec.system_configuration
        );
        assert_eq!(e.fixed_leader.number_of_cells, spec.cells);
        assert_eq!(e.fixed_leader.depth_cell_length_m, 4.0);
        let expected_angle = match (spec.system_configuration >> 8) & 3 {
            0 => Some(15.0),
            1 => Some(20.0),
            2 => Some(30.0),
            _ => (spec.beam_angle_byte != 0).then_some(f64::from(spec.beam_angle_byte)),
        };
        assert_eq!(e.fixed_leader.beam_angle_deg, expected_angle);
        match (spec.bottom, e.bottom_track) {
            (None, None) => {}
            (Some((velocity, range)), Some(bt)) => {
                for beam in 0..4 {
                    let v = (velocity[beam] != -32768).then_some(f64::from(velocity[beam]) * 1e-3);
                    let kept = if spec.bottom_len >= 81 {
                        range[beam]
                    } else {
                        range[beam] & 0xFFFF
                    };
                    let r = (kept != 0).then_some(f64::from(kept) * 1e-2);
                    assert_eq!(bt.velocity_mps[beam].is_some(), v.is_some());
                    assert!(
                        (bt.velocity_mps[beam].unwrap_or(0.0) - v.unwrap_or(0.0)).abs() < 1e-12
                    );
                    assert_eq!(bt.range_m[beam].is_some(), r.is_some());
                    assert!((bt.range_m[beam].unwrap_or(0.0) - r.unwrap_or(0.0)).abs() < 1e-9);
                }
            }
            other => panic!("bottom track {other:?} for {spec:?}"),
        }
    }
}

#[test]
fn known_clock_gives_known_unix_time() {
    // 2022-03-14 19:29:10.08 UTC (the first ensemble of the real file below).
    let read = read_pd0(&encode(&Spec::typical(1)));
    assert_eq!(read.ensembles[0].time_unix_s, 1_647_286_150.08);
    // Without the Y2K clock the two-digit year pivots at 80: 99 -> 1999, 05 -> 2005.
    for (year, expected) in [(1999, 915_148_800.0), (2005, 1_104_537_600.0)] {
        let spec = Spec {
            y2k: false,
            year,
            month: 1,
            day: 1,
            hour: 0,
            minute: 0,
            second: 0,
            hundredths: 0,
            ..Spec::typical(1)
        };
        let e = &read_pd0(&encode(&spec)).ensembles[0];
        assert!(!e.clock.y2k_century);
        assert_eq!(e.time_unix_s, expected);
    }
    // A Y2K clock with century 0 (not set) falls back to the two-digit year.
    let mut bytes = encode(&Spec::typical(1));
    let variable_leader_at = 6 + 2 * 4 + 59;
    assert_eq!(bytes[variable_leader_at], 0x80);
    bytes[variable_leader_at + 57] = 0;
    refresh_checksum(&mut bytes);
    let e = &read_pd0(&bytes).ensembles[0];
    assert!(!e.clock.y2k_century);
    assert_eq!(e.time_unix_s, 1_647_286_150.08);
    // The Y2K century decides when present: 2099 is not 1999.
    let spec = Spec {
        year: 2099,
        month: 12,
        day: 31,
        ..Spec::typical(1)
    };
    let e = &read_pd0(&encode(&spec)).ensembles[0];
    assert_eq!(e.clock.year, 2099);
    assert!(e.clock.y2k_century);
}

#[test]
fn every_coordinate_transform() {
    let systems = [
        (0b00, CoordinateSystem::Beam, "beam"),
        (0b01, CoordinateSystem::Instrument, "instrument"),
        (0b10, CoordinateSystem::Ship, "ship"),
        (0b11, CoordinateSystem::Earth, "earth"),
    ];
    for (bits, system, name) in systems {
        for flags in 0u8..8 {
            let byte = (bits << 3) | flags;
            let spec = Spec {
                transform: byte,
                ..Spec::typical(7)
            };
            let read = read_pd0(&encode(&spec));
            let e = &read.ensembles[0];
            assert_eq!(e.coordinate_system(), system);
            let t = e.fixed_leader.coordinate_transform;
            assert_eq!(
                t,
                CoordinateTransform {
                    system,
                    tilts_used: flags & 4 != 0,
                    three_beam_used: flags & 2 != 0,
                    bin_mapping_used: flags & 1 != 0,
                }
            );
            let mut csv = Vec::new();
            write_pd0_csv(&read.ensembles, &mut csv).unwrap();
            let csv = String::from_utf8(csv).unwrap();
            let row = csv.lines().nth(1).unwrap();
            assert!(row.ends_with(&format!(",{name}")), "{row}");
        }
    }
}

#[test]
fn bad_velocity_marker_and_no_detection_are_empty() {
    let spec = Spec {
        bottom: Some((
            [-32768, -32767, 1234, -32768],
            [0, 70_000 + (3 << 16), 1, 0],
        )),
        ..Spec::typical(3)
    };
    let read = read_pd0(&encode(&spec));
    let bt = read.ensembles[0].bottom_track.unwrap();
    assert_eq!(bt.velocity_mps, [None, Some(-32.767), Some(1.234), None]);
    // 70_000 cm overflows the LSB word; the MSB byte carries it.
    assert_eq!(
        bt.range_m,
        [
            None,
            Some(f64::from(70_000 + (3 << 16)) / 100.0),
            Some(0.01),
            None
        ]
    );
    let mut csv = Vec::new();
    write_pd0_csv(&read.ensembles, &mut csv).unwrap();
    let csv = String::from_utf8(csv).unwrap();
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some(PD0_CSV_HEADER));
    assert_eq!(
        lines.next(),
        Some("1647286150.08,,-32.767,1.234,,,2666.08,0.01,,beam")
    );
    assert_eq!(lines.next(), None);
}

#[test]
fn csv_header_is_the_documented_one_and_no_bottom_track_gives_empty_cells() {
    assert_eq!(
        PD0_CSV_HEADER,
        "time_unix_s,bt_velocity_1_mps,bt_velocity_2_mps,bt_velocity_3_mps,bt_velocity_4_mps,\
         bt_range_1_m,bt_range_2_m,bt_range_3_m,bt_range_4_m,coordinate_system"
    );
    let spec = Spec {
        bottom: None,
        transform: 0b11 << 3,
        ..Spec::typical(9)
    };
    let read = read_pd0(&encode(&spec));
    assert_eq!(read.report.with_bottom_track, 0);
    let mut csv = Vec::new();
    write_pd0_csv(&read.ensembles, &mut csv).unwrap();
    assert_eq!(
        String::from_utf8(csv).unwrap().lines().nth(1),
        Some("1647286150.08,,,,,,,,,earth")
    );
}

// ---------------------------------------------------------------------------------------
// Corrupt input: every good ensemble kept, the bad span named by its offset
// ---------------------------------------------------------------------------------------

fn three() -> (Vec<u8>, Vec<usize>) {
    concat(&[Spec::typical(1), Spec::typical(2), Spec::typical(3)])
}

#[test]
fn truncated_file_keeps_the_complete_ensembles() {
    let (bytes, offsets) = three();
    let cut = offsets[2] + 40;
    let read = read_pd0(&bytes[..cut]);
    assert_tiles(&read, cut);
    assert_eq!(
        read.ensembles
            .iter()
            .map(|e| e.ensemble_number)
            .collect::<Vec<_>>(),
        [1, 2]
    );
    assert_eq!(read.report.skipped.len(), 1);
    let skip = &read.report.skipped[0];
    assert_eq!(skip.offset, offsets[2]);
    assert_eq!(skip.length, 40);
    assert_eq!(
        skip.issue,
        Pd0Issue::Truncated {
            needed: bytes.len() - offsets[2],
            available: 40
        }
    );
    // Cut inside the length field too.
    for keep in 1..4 {
        let read = read_pd0(&bytes[..offsets[2] + keep]);
        assert_eq!(read.ensembles.len(), 2);
        assert_eq!(read.report.skipped[0].offset, offsets[2]);
        assert_eq!(read.report.skipped[0].length, keep);
    }
    let message = read_pd0(&bytes[..cut])
        .require_clean()
        .unwrap_err()
        .to_string();
    assert!(
        message.contains(&format!("byte {}", offsets[2])),
        "{message}"
    );
}

#[test]
fn truncated_ensemble_inside_the_file_is_named_and_the_next_one_kept() {
    let (bytes, offsets) = three();
    // Ensemble 2 loses its last 100 bytes (a recorder restart): 1 and 3 stay.
    let mut cut = bytes[..offsets[2] - 100].to_vec();
    cut.extend_from_slice(&bytes[offsets[2]..]);
    let read = read_pd0(&cut);
    assert_tiles(&read, cut.len());
    assert_eq!(
        read.ensembles
            .iter()
            .map(|e| e.ensemble_number)
            .collect::<Vec<_>>(),
        [1, 3]
    );
    let skip = &read.report.skipped[0];
    assert_eq!(skip.offset, offsets[1]);
    assert_eq!(
        skip.issue,
        Pd0Issue::Truncated {
            needed: offsets[2] - offsets[1],
            available: offsets[2] - offsets[1] - 100
        }
    );
}

#[test]
fn checksum_error_skips_only_that_ensemble() {
    let (mut bytes, offsets) = three();
    // One velocity byte of ensemble 2's bottom track changes.
    let at = offsets[2] - 2 - 85 + 24;
    bytes[at] ^= 0x10;
    let read = read_pd0(&bytes);
    assert_tiles(&read, bytes.len());
    assert_eq!(
        read.ensembles
            .iter()
            .map(|e| e.ensemble_number)
            .collect::<Vec<_>>(),
        [1, 3]
    );
    let skip = &read.report.skipped[0];
    assert_eq!(
        (skip.offset, skip.length),
        (offsets[1], offsets[2] - offsets[1])
    );
    assert!(matches!(skip.issue, Pd0Issue::Checksum { stored, computed } if stored != computed));
    let err = read.require_clean().unwrap_err();
    assert!(matches!(err, Error::Pd0 { offset, .. } if offset == offsets[1]));
    assert!(err.to_string().contains("checksum"), "{err}");
}

#[test]
fn garbage_before_between_and_after_ensembles() {
    let (clean, _) = three();
    let one = encode(&Spec::typical(1));
    let n = one.len();
    // Garbage with false headers: 0x7F7F with an impossible length, with a length that
    // fits but a wrong checksum, and a lone 0x7F at the very end.
    let lead = vec![0x00, 0x7F, 0x7F, 0x02, 0x00, 0x55];
    let mid = {
        let mut g = vec![0x7F, 0x7F, 0x20, 0x00, 0x00, 0x01, 0x08, 0x00];
        g.extend((0..40u8).map(|i| i.wrapping_mul(37)));
        g
    };
    let tail = vec![0x13, 0x7F];
    let mut bytes = lead.clone();
    bytes.extend_from_slice(&clean[..n]);
    bytes.extend_from_slice(&mid);
    bytes.extend_from_slice(&clean[n..2 * n]);
    bytes.extend_from_slice(&clean[2 * n..]);
    bytes.extend_from_slice(&tail);
    let read = read_pd0(&bytes);
    assert_tiles(&read, bytes.len());
    assert_eq!(
        read.ensembles
            .iter()
            .map(|e| e.ensemble_number)
            .collect::<Vec<_>>(),
        [1, 2, 3]
    );
    let spans: Vec<(usize, usize)> = read
        .report
        .skipped
        .iter()
        .map(|s| (s.offset, s.length))
        .collect();
    let mid_at = lead.len() + n;
    let tail_at = bytes.len() - tail.len();
    assert_eq!(
        spans,
        [(0, lead.len()), (mid_at, mid.len()), (tail_at, tail.len())]
    );
    assert_eq!(read.report.skipped[0].issue, Pd0Issue::Garbage);
    // The middle span starts with a 0x7F7F header that does not verify: its reason.
    assert!(matches!(
        read.report.skipped[1].issue,
        Pd0Issue::Checksum { .. }
    ));
    assert_eq!(read.report.skipped[2].issue, Pd0Issue::Garbage);
    assert_eq!(
        read.report.skipped_bytes(),
        lead.len() + mid.len() + tail.len()
    );
    let text = read.report.to_string();
    assert!(text.contains(&format!("byte {mid_at}")), "{text}");
}

#[test]
fn verified_ensemble_without_a_leader_or_with_a_bad_clock_is_reported() {
    let no_leader = Spec {
        no_variable_leader: true,
        ..Spec::typical(2)
    };
    let bad_clock = Spec {
        month: 2,
        day: 30,
        ..Spec::typical(3)
    };
    let (bytes, offsets) = concat(&[Spec::typical(1), no_leader, bad_clock, Spec::typical(4)]);
    let read = read_pd0(&bytes);
    assert_tiles(&read, bytes.len());
    assert_eq!(
        read.ensembles
            .iter()
            .map(|e| e.ensemble_number)
            .collect::<Vec<_>>(),
        [1, 4]
    );
    let skips = &read.report.skipped;
    assert_eq!(skips.len(), 2);
    assert_eq!(skips[0].offset, offsets[1]);
    assert_eq!(
        skips[0].issue,
        Pd0Issue::MissingDataType {
            id: 0x0080,
            name: "variable leader"
        }
    );
    assert_eq!(skips[1].offset, offsets[2]);
    assert!(matches!(skips[1].issue, Pd0Issue::InvalidClock { clock } if clock.day == 30));
}

#[test]
fn missing_file_is_an_io_error() {
    let err = read_pd0_file("/nonexistent/estim/pd0.ENR").unwrap_err();
    assert!(
        matches!(
            err,
            Error::Io {
                kind: std::io::ErrorKind::NotFound,
                ..
            }
        ),
        "{err}"
    );
}

// ---------------------------------------------------------------------------------------
// Arbitrary input never panics; the report always accounts for every byte
// ---------------------------------------------------------------------------------------

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 512,
        rng_seed: RngSeed::Fixed(20_261_201),
        failure_persistence: Some(Box::new(FileFailurePersistence::WithSource(
            "proptest-regressions",
        ))),
        ..ProptestConfig::default()
    })]

    #[test]
    fn arbitrary_bytes_never_panic(
        bytes in proptest::collection::vec(
            prop_oneof![any::<u8>(), Just(0x7Fu8), Just(0x00u8)], 0..3000),
    ) {
        let read = read_pd0(&bytes);
        assert_tiles(&read, bytes.len());
        let mut csv = Vec::new();
        write_pd0_csv(&read.ensembles, &mut csv).unwrap();
    }

    /// Ensembles whose checksum verifies but whose offset table and data types are
    /// random (IDs often those the reader looks for): decoding never panics, and what
    /// decodes spans exactly the declared bytes.
    #[test]
    fn checksummed_random_ensembles_never_panic(
        count in 0u8..8,
        offsets in proptest::collection::vec(any::<u16>(), 8),
        ids in proptest::collection::vec(0usize..5, 8),
        body in proptest::collection::vec(any::<u8>(), 0..300),
    ) {
        let table_end = 6 + 2 * usize::from(count);
        let mut e = vec![0x7F, 0x7F, 0, 0, 0, count];
        e.resize(table_end, 0);
        e.extend_from_slice(&body);
        let total = e.len();
        put_u16(&mut e, 2, total as u16);
        for i in 0..usize::from(count) {
            let offset = usize::from(offsets[i]) % (total + 4);
            put_u16(&mut e, 6 + 2 * i, offset as u16);
            if offset >= table_end && offset + 2 <= total {
                let id = [0x0000, 0x0080, 0x0600, 0x0100, offsets[i]][ids[i]];
                put_u16(&mut e, offset, id);
            }
        }
        e.extend_from_slice(&[0, 0]);
        refresh_checksum(&mut e);
        let read = read_pd0(&e);
        assert_tiles(&read, e.len());
        for ensemble in &read.ensembles {
            prop_assert_eq!(ensemble.offset, 0);
            prop_assert_eq!(ensemble.length, total + 2);
        }
    }

    #[test]
    fn corrupted_streams_keep_every_untouched_ensemble(
        seed in any::<u64>(),
        edits in proptest::collection::vec((any::<u16>(), any::<u8>(), 0u8..3), 0..6),
        cut in any::<u16>(),
    ) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let specs: Vec<Spec> = (0..5).map(|k| random_spec(&mut rng, k + 1)).collect();
        let (mut bytes, mut offsets) = concat(&specs);
        let mut ends: Vec<usize> = offsets.iter().skip(1).copied().chain([bytes.len()]).collect();
        let mut touched = vec![false; specs.len()];
        let owner = |offsets: &[usize], at: usize| offsets.iter().rposition(|&o| o <= at);
        for &(at, value, kind) in &edits {
            let at = usize::from(at) % (bytes.len() + 1);
            match kind {
                // overwrite a byte
                0 if at < bytes.len() && bytes[at] != value => {
                    bytes[at] = value;
                    if let Some(k) = owner(&offsets, at) { touched[k] = true; }
                }
                // insert a byte (garbage between or inside ensembles)
                1 => {
                    bytes.insert(at, value);
                    if let Some(k) = owner(&offsets, at) {
                        if at > offsets[k] && at < ends[k] { touched[k] = true; }
                    }
                    for (o, e) in offsets.iter_mut().zip(ends.iter_mut()) {
                        if *o >= at { *o += 1; }
                        if *e > at { *e += 1; }
                    }
                }
                _ => {}
            }
        }
        let cut = bytes.len() - usize::from(cut) % 64usize.min(bytes.len() + 1);
        bytes.truncate(cut);
        let read = read_pd0(&bytes);
        assert_tiles(&read, bytes.len());
        for (k, spec) in specs.iter().enumerate() {
            if !touched[k] && ends[k] <= cut {
                prop_assert!(
                    read.ensembles.iter().any(|e| e.offset == offsets[k] && e.ensemble_number == spec.number),
                    "ensemble {} at {} lost: {}", spec.number, offsets[k], read.report
                );
            }
        }
    }
}

/// A reader that hands out at most 1-7 bytes per call, and says `Interrupted` now and
/// then, as a pipe or a socket may.
struct Trickle<'a> {
    bytes: &'a [u8],
    at: usize,
    calls: u64,
}

impl std::io::Read for Trickle<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        self.calls += 1;
        if self.calls.is_multiple_of(97) {
            return Err(std::io::ErrorKind::Interrupted.into());
        }
        let n = (1 + (self.calls % 7) as usize)
            .min(buf.len())
            .min(self.bytes.len() - self.at);
        buf[..n].copy_from_slice(&self.bytes[self.at..self.at + n]);
        self.at += n;
        Ok(n)
    }
}

/// A 3.3 MB stream (more than three of the streaming reader's 1 MiB windows): 12,000
/// ensembles with garbage runs between some (0x7F bytes, a lone header, a false header
/// with a long declared length) and every 50th ensemble corrupted. Read from a trickling
/// stream, every untouched ensemble is found at its own offset and the report tiles
/// the input, across every window boundary; and the stream gives what the whole input
/// gives.
#[test]
fn a_long_stream_read_in_trickles_finds_every_ensemble_at_its_offset() {
    let mut rng = ChaCha8Rng::seed_from_u64(31);
    let mut bytes = Vec::new();
    let mut expected = Vec::new();
    for k in 0..12_000u32 {
        match k % 37 {
            0 => bytes.extend([0x7F; 13]),
            1 => bytes.extend([0x7F, 0x7F]),
            // A false header declaring 60,000 bytes: the reader must look that far
            // ahead (into the next window) before rejecting it.
            2 => bytes.extend([0x7F, 0x7F, 0x60, 0xEA, 0x00, 0x01]),
            _ => {}
        }
        let spec = random_spec(&mut rng, k + 1);
        let mut ensemble = encode(&spec);
        if k % 50 == 7 {
            let at = 8 + (k as usize % (ensemble.len() - 10));
            ensemble[at] ^= 0x5A;
        } else {
            expected.push((bytes.len(), k + 1));
        }
        bytes.extend(ensemble);
    }
    assert!(bytes.len() > 3 * (1 << 20), "{} bytes", bytes.len());
    let streamed = estim_dvl::read_pd0_from(Trickle {
        bytes: &bytes,
        at: 0,
        calls: 0,
    })
    .expect("a trickle never fails");
    assert_tiles(&streamed, bytes.len());
    let found: std::collections::HashMap<usize, u32> = streamed
        .ensembles
        .iter()
        .map(|e| (e.offset, e.ensemble_number))
        .collect();
    for &(offset, number) in &expected {
        assert_eq!(
            found.get(&offset),
            Some(&number),
            "ensemble {number} at {offset}"
        );
    }
    assert_eq!(streamed, read_pd0(&bytes));
}

// ---------------------------------------------------------------------------------------
// A real recording, compared with dolfyn's decode
// ---------------------------------------------------------------------------------------

fn real_file() -> Option<PathBuf> {
    let required = std::env::var("ESTIM_REQUIRE_DATA").is_ok_and(|v| v == "1");
    let found = std::env::var_os("ESTIM_DATA_DIR")
        .map(PathBuf::from)
        .into_iter()
        .chain([
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data"),
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data"),
        ])
        .map(|root| root.join("pd0/vmdas02_os.ENR"))
        .find(|p| p.is_file());
    if found.is_none() {
        assert!(
            !required,
            "ESTIM_REQUIRE_DATA=1 but pd0/vmdas02_os.ENR not found"
        );
        eprintln!("skipped: pd0/vmdas02_os.ENR not found (set ESTIM_DATA_DIR)");
    }
    found
}

struct Expected {
    number: u32,
    time_unix_s: f64,
    velocity: [f64; 4],
    range: [f64; 4],
}

fn dolfyn_expected() -> (usize, Vec<Expected>) {
    let text = include_str!("data/pd0_vmdas02_os_dolfyn.csv");
    let mut lines = text.lines();
    // "# dolfyn 1.3.0: 689 ensembles, coord_sys beam"
    let comment = lines.next().unwrap();
    let count: usize = comment
        .split(": ")
        .nth(1)
        .and_then(|s| s.split(' ').next())
        .and_then(|s| s.parse().ok())
        .unwrap();
    assert!(comment.ends_with("coord_sys beam"));
    lines.next(); // header
    let rows = lines
        .map(|line| {
            let cells: Vec<f64> = line.split(',').map(|c| c.parse().unwrap()).collect();
            Expected {
                number: cells[0] as u32,
                time_unix_s: cells[1],
                velocity: [cells[2], cells[3], cells[4], cells[5]],
                range: [cells[6], cells[7], cells[8], cells[9]],
            }
        })
        .collect();
    (count, rows)
}

#[test]
fn real_vmdas_file_matches_dolfyn() {
    let Some(path) = real_file() else { return };
    let read = read_pd0_file(&path).unwrap();
    eprintln!("{}", read.report);
    assert!(read.report.is_clean(), "{}", read.report);
    assert_eq!(read.report.input_bytes, 1_325_490);
    // The file holds 690 ensembles, each with bottom track and a verified checksum
    // (690 x 1921 bytes = the file size); dolfyn 1.3.0 reads the first 689.
    assert_eq!(read.report.decoded, 690);
    assert_eq!(read.report.with_bottom_track, 690);
    let (dolfyn_count, expected) = dolfyn_expected();
    assert_eq!(dolfyn_count, 689);
    for (k, e) in read.ensembles.iter().enumerate() {
        assert_eq!(e.ensemble_number, k as u32 + 1);
        assert_eq!(e.coordinate_system(), CoordinateSystem::Beam);
        assert_eq!(e.fixed_leader.number_of_beams, 4);
        assert_eq!(e.fixed_leader.beam_angle_deg, Some(30.0));
        assert_eq!(e.fixed_leader.frequency_khz(), Some(75));
        assert_eq!(e.fixed_leader.firmware_version, 23);
        assert!(!e.clock.y2k_century);
        if k > 0 {
            assert!(e.time_unix_s > read.ensembles[k - 1].time_unix_s);
        }
    }
    let mut max_time = 0.0f64;
    let mut max_velocity = 0.0f64;
    let mut max_range = 0.0f64;
    let mut bad_seen = 0;
    for x in &expected {
        let e = &read.ensembles[x.number as usize - 1];
        assert_eq!(e.ensemble_number, x.number);
        max_time = max_time.max((e.time_unix_s - x.time_unix_s).abs());
        let bt = e.bottom_track.unwrap();
        for beam in 0..4 {
            // dolfyn keeps RDI's bad-velocity marker as -32.768 m/s.
            if x.velocity[beam] == -32.768 {
                assert_eq!(bt.velocity_mps[beam], None, "ensemble {}", x.number);
                bad_seen += 1;
            } else {
                max_velocity =
                    max_velocity.max((bt.velocity_mps[beam].unwrap() - x.velocity[beam]).abs());
            }
            max_range = max_range.max((bt.range_m[beam].unwrap() - x.range[beam]).abs());
        }
    }
    eprintln!(
        "vs dolfyn on {} ensembles: max |dt| {max_time:.2e} s, max |dv| {max_velocity:.2e} m/s, \
         max |dr| {max_range:.2e} m, {bad_seen} bad velocities",
        expected.len()
    );
    assert_eq!(bad_seen, 2, "ensemble 206 has two bad beam velocities");
    assert!(max_time <= 1e-3, "{max_time}");
    assert!(max_velocity <= 1e-9, "{max_velocity}");
    assert!(max_range <= 1e-9, "{max_range}");

    let mut csv = Vec::new();
    write_pd0_csv(&read.ensembles, &mut csv).unwrap();
    let csv = String::from_utf8(csv).unwrap();
    assert_eq!(csv.lines().count(), 691);
    assert_eq!(
        csv.lines().nth(1),
        Some("1647286150.08,-0.049,0.052,0.037,-0.031,347.83,334.45,331.11,341.14,beam")
    );
    assert_eq!(
        csv.lines().nth(206),
        Some("1647286818.02,-0.078,0.071,,,327.7,340.81,337.53,337.53,beam")
    );
}

#[test]
fn header_declaring_fewer_bytes_than_itself_is_skipped() {
    // In sync at the start of the input: a 0x7F7F header whose length (2) cannot even
    // hold the header; the good ensemble after it is kept.
    let mut bytes = vec![0x7F, 0x7F, 0x02, 0x00];
    bytes.extend(encode(&Spec::typical(5)));
    let read = read_pd0(&bytes);
    assert_tiles(&read, bytes.len());
    assert_eq!(read.ensembles.len(), 1);
    assert_eq!(read.ensembles[0].offset, 4);
    assert_eq!(read.report.skipped.len(), 1);
    assert!(matches!(
        read.report.skipped[0].issue,
        Pd0Issue::BadHeader { .. }
    ));
}
