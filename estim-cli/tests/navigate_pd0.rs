//! `estim navigate --pd0`: PD0 ensembles encoded here from the documented format
//! (Teledyne RD Instruments, *WorkHorse Commands and Output Data Format*, "PD0 Output
//! Format"), in beam, instrument, ship and earth coordinates, against a DVL velocity
//! CSV carrying the velocities that RDI's beam-to-instrument transform (as dolfyn codes
//! it: X = a (b1 - b2), Y = a (b4 - b3), Z = b (b1 + b2 + b3 + b4), convex head) gives
//! for the same beams; corrupt and truncated ensembles are skipped, reported with their
//! byte offsets and counted in summary.json; and the real VmDas recording of the data
//! folder (skipped with a printed reason when absent, unless `ESTIM_REQUIRE_DATA=1`).

mod common;

use std::fmt::Write as _;
use std::path::Path;
use std::process::{Command, Output};

use serde_json::Value;

fn estim(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_estim"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("run estim")
}

fn ok_json(out: Output, what: &str) -> Value {
    assert_eq!(
        out.status.code(),
        Some(0),
        "{what}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("JSON on stdout")
}

// ---------------------------------------------------------------------------------------
// A PD0 encoder written from the manual (as in estim-dvl/tests/pd0.rs, shortened).
// ---------------------------------------------------------------------------------------

fn put_u16(buf: &mut [u8], at: usize, v: u16) {
    buf[at..at + 2].copy_from_slice(&v.to_le_bytes());
}

/// Coordinate-transform byte (EX, bits 4-3).
const BEAM: u8 = 0b00_000;
const INSTRUMENT: u8 = 0b01_000;
const SHIP: u8 = 0b10_000;
const EARTH: u8 = 0b11_000;

/// System configuration: 150 kHz (bits 2-0 = 001), convex (bit 3), transducer
/// attached (bit 6), down-looking (bit 7 = 0), 30 deg (MSB bits 1-0 = 10), 4-beam Janus.
const SYSTEM_CONFIGURATION: u16 = 0x4A_49;

/// One ensemble: fixed leader (59 bytes), variable leader (65 bytes, Y2K clock),
/// bottom track (85 bytes), checksum. `time` in hundredths of a second since
/// 2022-03-14 00:00:00.
fn encode(number: u32, hundredths_of_day: u32, transform: u8, velocity_mm_s: [i16; 4]) -> Vec<u8> {
    let mut fixed = vec![0u8; 59];
    b_fixed(&mut fixed, transform);
    let mut variable = vec![0u8; 65];
    put_u16(&mut variable, 0, 0x0080);
    put_u16(&mut variable, 2, (number & 0xFFFF) as u16);
    let (h, rem) = (hundredths_of_day / 360_000, hundredths_of_day % 360_000);
    let (m, rem) = (rem / 6000, rem % 6000);
    let (s, c) = (rem / 100, rem % 100);
    let clock = [22u8, 3, 14, h as u8, m as u8, s as u8, c as u8];
    variable[4..11].copy_from_slice(&clock);
    variable[57] = 20;
    variable[58..65].copy_from_slice(&clock);
    let mut bottom = vec![0u8; 85];
    put_u16(&mut bottom, 0, 0x0600);
    for (beam, &velocity) in velocity_mm_s.iter().enumerate() {
        put_u16(&mut bottom, 16 + 2 * beam, 2000); // 20 m range
        put_u16(&mut bottom, 24 + 2 * beam, velocity as u16);
    }
    let types = [fixed, variable, bottom];
    let header_len = 6 + 2 * types.len();
    let total = header_len + types.iter().map(Vec::len).sum::<usize>();
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
    let sum = out.iter().fold(0u16, |s, &b| s.wrapping_add(u16::from(b)));
    out.extend_from_slice(&sum.to_le_bytes());
    out
}

fn b_fixed(b: &mut [u8], transform: u8) {
    b[2] = 16;
    b[3] = 21;
    put_u16(b, 4, SYSTEM_CONFIGURATION);
    b[8] = 4;
    b[9] = 0;
    put_u16(b, 10, 1);
    put_u16(b, 12, 400);
    b[25] = transform;
}

// ---------------------------------------------------------------------------------------
// The survey: level, heading north, constant NED velocity.
// ---------------------------------------------------------------------------------------

/// 2022-03-14 00:00:00 UTC in Unix seconds (19065 days).
const DAY: f64 = 19_065.0 * 86_400.0;
/// Survey start: 10:00:00 of that day.
const START_S: u32 = 36_000;
const SECONDS: u32 = 60;
const VELOCITY_NED: [f64; 3] = [1.2, 0.3, 0.05];
const LATITUDE_DEG: f64 = 32.85;

fn write_imu_and_vehicle(dir: &Path) {
    let latitude = LATITUDE_DEG.to_radians();
    let g = estim::ins::earth::normal_gravity(latitude, -20.0);
    // Level, heading north: the gyros read the Earth's rate (7.292115e-5 rad/s) in
    // NED, so that the attitude holds (the transport rate, ~5e-8 rad/s here, is left
    // out).
    let earth_rate = 7.292_115e-5;
    let (gx, gz) = (earth_rate * latitude.cos(), -earth_rate * latitude.sin());
    let mut imu = String::from("time_s,acc_x,acc_y,acc_z,gyro_x,gyro_y,gyro_z\n");
    for k in 0..=SECONDS * 100 {
        let t = DAY + f64::from(START_S) + f64::from(k) / 100.0;
        writeln!(imu, "{t:.2},0,0,{:.6},{gx:.9e},0,{gz:.9e}", -g).unwrap();
    }
    std::fs::write(dir.join("imu.csv"), imu).unwrap();
    std::fs::write(
        dir.join("vehicle.toml"),
        format!(
            "[imu]\nrate_hz = 100.0\n[gate]\nprobability = 0.0\n[initial]\nlatitude_deg = {LATITUDE_DEG}\n\
             longitude_deg = 34.89\ndepth_m = 20.0\nvelocity_ned_mps = [{}, {}, {}]\n\
             attitude_deg = [0.0, 0.0, 0.0]\n",
            VELOCITY_NED[0], VELOCITY_NED[1], VELOCITY_NED[2]
        ),
    )
    .unwrap();
}

/// Radial bottom-track values \[mm/s\] of a convex down-looking head with beam 3
/// forward for the vehicle velocity `v` (DVL frame x forward, y starboard, z down),
/// inverting the transform above: with X, Y, Z the bottom's velocity relative to the
/// instrument (X starboard, Y forward, Z up) = (-v_y, -v_x, v_z), b1 - b2 = 2 X sin,
/// b4 - b3 = 2 Y sin, sum = 4 Z cos.
fn beams_mm_s(v: [f64; 3]) -> [i16; 4] {
    let (s, c) = 30f64.to_radians().sin_cos();
    let (x, y, z) = (-v[1], -v[0], v[2]);
    let b = [x * s + z * c, -x * s + z * c, -y * s + z * c, y * s + z * c];
    b.map(|v| (v * 1000.0).round() as i16)
}

/// dolfyn's transform of radial values [m/s] to instrument X, Y, Z, error.
fn instrument_of(beams: [f64; 4]) -> [f64; 4] {
    let theta = 30f64.to_radians();
    let a = 1.0 / (2.0 * theta.sin());
    let b = 1.0 / (4.0 * theta.cos());
    let d = a / 2f64.sqrt();
    [
        a * (beams[0] - beams[1]),
        a * (beams[3] - beams[2]),
        b * (beams[0] + beams[1] + beams[2] + beams[3]),
        d * (beams[0] + beams[1] - beams[2] - beams[3]),
    ]
}

struct Epoch {
    hundredths: u32,
    beams: [i16; 4],
}

fn epochs() -> Vec<Epoch> {
    (1..SECONDS)
        .map(|k| {
            // A small deterministic wobble so that every epoch differs.
            let w = 0.01 * f64::from(k % 7) - 0.03;
            let v = [VELOCITY_NED[0] + w, VELOCITY_NED[1] - w, VELOCITY_NED[2]];
            Epoch {
                hundredths: (START_S + k) * 100,
                beams: beams_mm_s(v),
            }
        })
        .collect()
}

fn mm(v: i16) -> f64 {
    f64::from(v) / 1000.0
}

fn navigate_json(dir: &Path, input: &[&str]) -> Value {
    let mut args = vec!["navigate", "--imu", "imu.csv", "--vehicle", "vehicle.toml"];
    args.extend_from_slice(input);
    args.push("--json");
    ok_json(estim(&args, dir), &format!("navigate {input:?}"))
}

fn final_of(v: &Value) -> [f64; 4] {
    let f = &v["final"];
    [
        f["latitude_deg"].as_f64().unwrap(),
        f["longitude_deg"].as_f64().unwrap(),
        f["depth_m"].as_f64().unwrap(),
        f["position_sigma_m"][0].as_f64().unwrap(),
    ]
}

/// Largest difference of the final positions in metres (and of the N sigma).
fn final_difference_m(a: &Value, b: &Value) -> f64 {
    let (x, y) = (final_of(a), final_of(b));
    let metres = 111_000.0;
    [
        (x[0] - y[0]).abs() * metres,
        (x[1] - y[1]).abs() * metres,
        (x[2] - y[2]).abs(),
        (x[3] - y[3]).abs(),
    ]
    .into_iter()
    .fold(0.0, f64::max)
}

#[test]
fn every_coordinate_system_navigates_like_the_velocity_it_encodes() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_imu_and_vehicle(d);
    let epochs = epochs();
    let mut files: Vec<(&str, u8, Vec<u8>)> = Vec::new();
    let mut csv_from_beams = String::from("time_s,vx,vy,vz\n");
    let mut csv_from_instrument = String::from("time_s,vx,vy,vz\n");
    for (name, transform) in [
        ("beam.pd0", BEAM),
        ("instrument.pd0", INSTRUMENT),
        ("ship.pd0", SHIP),
        ("earth.pd0", EARTH),
    ] {
        let mut bytes = Vec::new();
        for (k, e) in epochs.iter().enumerate() {
            let radial = e.beams.map(mm);
            let values = match transform {
                BEAM => e.beams,
                // Instrument, ship and (heading north, level) earth: X, Y, Z, error of
                // the same beams, rounded to mm/s as an instrument writes them.
                _ => instrument_of(radial).map(|v| (v * 1000.0).round() as i16),
            };
            if transform == BEAM {
                let x = instrument_of(radial);
                writeln!(
                    csv_from_beams,
                    "{:.2},{},{},{}",
                    DAY + f64::from(e.hundredths) / 100.0,
                    -x[1],
                    -x[0],
                    x[2]
                )
                .unwrap();
            }
            if transform == INSTRUMENT {
                writeln!(
                    csv_from_instrument,
                    "{:.2},{},{},{}",
                    DAY + f64::from(e.hundredths) / 100.0,
                    -mm(values[1]),
                    -mm(values[0]),
                    mm(values[2])
                )
                .unwrap();
            }
            bytes.extend(encode(k as u32 + 1, e.hundredths, transform, values));
        }
        std::fs::write(d.join(name), &bytes).unwrap();
        files.push((name, transform, bytes));
    }
    std::fs::write(d.join("from_beams.csv"), csv_from_beams).unwrap();
    std::fs::write(d.join("from_instrument.csv"), csv_from_instrument).unwrap();

    let beam = navigate_json(d, &["--pd0", "beam.pd0"]);
    let reference = navigate_json(d, &["--dvl", "from_beams.csv"]);
    let n = epochs.len() as u64;
    assert_eq!(beam["pd0"]["ensembles"], n);
    assert_eq!(beam["pd0"]["warnings"], 0);
    assert_eq!(beam["pd0"]["coordinate_systems"]["beam"], n);
    assert_eq!(beam["pd0"]["beam_angle_deg"], 30.0);
    assert_eq!(beam["pd0"]["head"], "convex");
    assert_eq!(beam["dvl_source"], "pd0");
    assert_eq!(beam["updates"]["dvl"]["accepted"], n);
    // Least squares on the four beams of the RDI layout equals dolfyn's closed-form
    // transform: the same run to rounding.
    let d_ref = final_difference_m(&beam, &reference);
    eprintln!("beam PD0 vs velocity CSV of dolfyn's transform: {d_ref:e} m");
    assert!(d_ref <= 1e-6, "{d_ref}");

    let instrument = navigate_json(d, &["--pd0", "instrument.pd0"]);
    let instrument_reference = navigate_json(d, &["--dvl", "from_instrument.csv"]);
    let d_inst = final_difference_m(&instrument, &instrument_reference);
    assert!(d_inst <= 1e-6, "instrument vs its CSV: {d_inst}");
    let ship = navigate_json(d, &["--pd0", "ship.pd0"]);
    assert_eq!(
        final_of(&ship),
        final_of(&instrument),
        "ship = instrument here"
    );
    let earth = navigate_json(d, &["--pd0", "earth.pd0"]);
    // Instrument and earth values are the beams' X, Y, Z rounded to 1 mm/s: the runs
    // differ from the beam run by that rounding only, at most 0.5 mm/s x 60 s = 0.03 m
    // (a wrong sign or axis would move the 60-s track by tens of metres). Measured:
    // 0.021 m for both.
    for (name, run) in [("instrument", &instrument), ("earth", &earth)] {
        let diff = final_difference_m(run, &beam);
        eprintln!("{name} vs beam coordinates: {diff:.2e} m");
        assert!(diff <= 0.03, "{name}: {diff} m from the beam run");
        assert_eq!(run["pd0"]["warnings"], 0);
    }
    assert_eq!(earth["pd0"]["coordinate_systems"]["earth"], n);
    // The track goes where the encoded velocity says: north ~1.2 m/s over 59 s.
    let north_m = (final_of(&beam)[0] - LATITUDE_DEG) * 110_900.0;
    assert!((north_m - 1.2 * 60.0).abs() < 2.0, "north {north_m} m");

    // Headings in [0, 360) as written (the zero-rate IMU drifts about north).
    let out = estim(
        &[
            "navigate",
            "--imu",
            "imu.csv",
            "--vehicle",
            "vehicle.toml",
            "--pd0",
            "beam.pd0",
            "--rate",
            "10",
            "--out",
            "o",
        ],
        d,
    );
    assert_eq!(out.status.code(), Some(0));
    let csv = std::fs::read_to_string(d.join("o/solution.csv")).unwrap();
    let column = csv
        .lines()
        .next()
        .unwrap()
        .split(',')
        .position(|c| c == "heading_deg")
        .unwrap();
    let mut rows = 0;
    for line in csv.lines().skip(1) {
        let cell = line.split(',').nth(column).unwrap();
        let h: f64 = cell.parse().unwrap();
        assert!(
            (0.0..360.0).contains(&h) && !cell.starts_with('-'),
            "{cell}"
        );
        assert!(!cell.starts_with("360"), "{cell}");
        rows += 1;
    }
    assert!(rows > 600, "{rows} rows");
}

#[test]
fn corrupt_and_truncated_ensembles_are_reported_and_the_good_ones_kept() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_imu_and_vehicle(d);
    let epochs = epochs();
    let mut bytes = Vec::new();
    let mut offsets = Vec::new();
    for (k, e) in epochs.iter().enumerate() {
        let mut beams = e.beams;
        if k == 20 {
            beams[1] = i16::MIN; // one bad beam: 3-beam solution
        }
        if k == 30 {
            beams[0] = i16::MIN; // two bad beams: skipped, counted
            beams[1] = i16::MIN;
        }
        let mut ensemble = encode(k as u32 + 1, e.hundredths, BEAM, beams);
        if k == 10 {
            let middle = ensemble.len() / 2;
            ensemble[middle] ^= 0x55; // checksum no longer verifies
        }
        offsets.push(bytes.len());
        bytes.extend(ensemble);
    }
    // The last ensemble cut in half (a recording that stopped mid-write).
    let last = *offsets.last().unwrap();
    let cut = last + (bytes.len() - last) / 2;
    bytes.truncate(cut);
    std::fs::write(d.join("bad.pd0"), &bytes).unwrap();
    let out = estim(
        &[
            "navigate",
            "--imu",
            "imu.csv",
            "--vehicle",
            "vehicle.toml",
            "--pd0",
            "bad.pd0",
            "--json",
        ],
        d,
    );
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    let v = ok_json(out, "navigate --pd0 bad.pd0");
    let n = epochs.len() as u64;
    let pd0 = &v["pd0"];
    assert_eq!(pd0["ensembles"], n - 2);
    assert_eq!(pd0["warnings"], 2);
    assert_eq!(pd0["skipped"][0]["offset"], offsets[10] as u64);
    assert!(
        pd0["skipped"][0]["reason"]
            .as_str()
            .unwrap()
            .starts_with("checksum error"),
        "{pd0}"
    );
    assert_eq!(pd0["skipped"][1]["offset"], last as u64);
    assert!(pd0["skipped"][1]["reason"]
        .as_str()
        .unwrap()
        .starts_with("truncated ensemble"));
    assert_eq!(pd0["bad_velocity_values"], 3);
    assert!(
        stderr.contains(&format!("bad.pd0: byte {}", offsets[10])),
        "{stderr}"
    );
    assert!(
        stderr.contains(&format!("bad.pd0: byte {last}")),
        "{stderr}"
    );
    assert_eq!(v["dvl_insufficient_beam_rows"], 1);
    assert_eq!(v["updates"]["dvl"]["accepted"], n - 3);
    assert_eq!(v["status"], "ok");

    // Nothing decodable: exit 2 naming the file, nothing on stdout.
    std::fs::write(d.join("junk.pd0"), vec![0x7Fu8; 300]).unwrap();
    let out = estim(
        &[
            "navigate", "--imu", "imu.csv", "--pd0", "junk.pd0", "--out", "o",
        ],
        d,
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("junk.pd0: no good PD0 ensemble"),
        "{stderr}"
    );
    assert!(out.stdout.is_empty());
    assert!(!d.join("o").exists());
}

#[test]
fn real_vmdas_recording_navigates_with_its_bad_beams_counted() {
    let Some(root) = common::data_root() else {
        return;
    };
    let file = root.join("pd0/vmdas02_os.ENR");
    assert!(
        file.is_file(),
        "{}: missing from the data folder",
        file.display()
    );
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // The recording has no IMU: a level, stationary 20 Hz IMU over its span (the ship
    // drifts at about 0.1 m/s; the DVL updates carry that motion).
    let (first, last) = (1_647_286_140.0, 1_647_288_500.0);
    let g = estim::ins::earth::normal_gravity(21.3f64.to_radians(), 0.0);
    let mut imu = String::from("time_s,acc_x,acc_y,acc_z,gyro_x,gyro_y,gyro_z\n");
    let mut k = 0u32;
    loop {
        let t = first + f64::from(k) * 0.05;
        if t > last {
            break;
        }
        writeln!(imu, "{t:.2},0,0,{:.6},0,0,0", -g).unwrap();
        k += 1;
    }
    std::fs::write(d.join("imu.csv"), imu).unwrap();
    std::fs::write(
        d.join("vehicle.toml"),
        "[imu]\nrate_hz = 20.0\n[initial]\nlatitude_deg = 21.3\nlongitude_deg = -157.9\n\
         depth_m = 0.0\nattitude_deg = [0.0, 0.0, 0.0]\n",
    )
    .unwrap();
    let v = navigate_json(d, &["--pd0", file.to_str().unwrap()]);
    let pd0 = &v["pd0"];
    eprintln!("{}", serde_json::to_string_pretty(pd0).unwrap());
    assert_eq!(pd0["input_bytes"], 1_325_490);
    assert_eq!(pd0["ensembles"], 690);
    assert_eq!(pd0["warnings"], 0);
    assert_eq!(pd0["coordinate_systems"]["beam"], 690);
    assert_eq!(pd0["beam_angle_deg"], 30.0);
    assert_eq!(pd0["beam_angle_from"], "fixed_leader");
    // Ensemble 206 has two bad beam velocities (estim-dvl/tests/pd0.rs, against
    // dolfyn): that row is skipped as insufficient, the other 689 are used.
    assert_eq!(pd0["bad_velocity_values"], 2);
    assert_eq!(v["dvl_insufficient_beam_rows"], 1);
    let used = v["updates"]["dvl"]["accepted"].as_u64().unwrap()
        + v["updates"]["dvl"]["gated"].as_u64().unwrap();
    assert_eq!(used, 689);
    let f = &v["final"];
    assert!(f["latitude_deg"].as_f64().unwrap().is_finite());
    assert!(f["position_sigma_m"][0].as_f64().unwrap().is_finite());
    let nis = v["nis"]["dvl"]["mean"].as_f64().unwrap();
    eprintln!(
        "real PD0: {} accepted, {} gated, mean DVL NIS {nis:.2}, final sigma N {} m",
        v["updates"]["dvl"]["accepted"], v["updates"]["dvl"]["gated"], f["position_sigma_m"][0]
    );
    assert!(nis.is_finite());
}
