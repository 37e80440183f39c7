//! `estim dvl solve` and `estim dvl calibrate`, run as the built binary.

use std::io::Write;
use std::process::{Command, Output};

fn estim(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_estim"))
        .args(args)
        .output()
        .expect("run estim")
}

fn write(content: &str) -> tempfile::NamedTempFile {
    let mut f = tempfile::NamedTempFile::new().unwrap();
    f.write_all(content.as_bytes()).unwrap();
    f
}

/// Janus beams written out from the README formula (independent of estim-dvl).
fn beams(theta_deg: f64, offset_deg: f64, v: [f64; 3]) -> [f64; 4] {
    let t = theta_deg.to_radians();
    std::array::from_fn(|i| {
        let psi = (offset_deg + 90.0 * i as f64).to_radians();
        psi.cos() * t.sin() * v[0] + psi.sin() * t.sin() * v[1] + t.cos() * v[2]
    })
}

fn assert_bad_input(out: &Output, needle: &str) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "stderr: {stderr}");
    assert!(
        out.stdout.is_empty(),
        "stdout not empty: {:?}",
        String::from_utf8_lossy(&out.stdout)
    );
    assert!(
        stderr.contains(needle),
        "stderr {stderr:?} does not name {needle:?}"
    );
}

#[test]
fn solve_writes_one_row_per_input_row() {
    let v = [1.9, -0.3, 0.05];
    let b = beams(30.0, 45.0, v);
    let input = format!(
        "time,Beam 1, beam2 ,BEAM 3,beam 4,extra\n\
         0,{},{},{},{},x\n\
         1,{},,{},{},y\n\
         2,{},{},NaN,{},z\n\
         3,,{},nan,{},w\n",
        b[0], b[1], b[2], b[3], b[0], b[2], b[3], b[0], b[1], b[3], b[1], b[3]
    );
    let f = write(&input);
    let out = estim(&[
        "dvl",
        "solve",
        "--beam-angle",
        "30",
        f.path().to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    // The time column is kept (in seconds), first.
    assert_eq!(lines[0], "time_s,vx,vy,vz,error_velocity,n_beams");
    assert_eq!(lines.len(), 5);
    for (i, (line, n)) in lines[1..4].iter().zip([4, 3, 3]).enumerate() {
        let cells: Vec<&str> = line.split(',').collect();
        assert_eq!(cells.len(), 6, "{line}");
        assert_eq!(cells[0], i.to_string());
        for k in 0..3 {
            let x: f64 = cells[k + 1].parse().unwrap();
            assert!((x - v[k]).abs() < 1e-12, "{line}");
        }
        assert_eq!(cells[5], n.to_string());
        if n == 4 {
            assert!(cells[4].parse::<f64>().unwrap().abs() < 1e-12);
        } else {
            assert_eq!(cells[4], "");
        }
    }
    assert_eq!(lines[4], "3,,,,,2");
}

#[test]
fn solve_honours_the_azimuth_offset() {
    let v = [0.7, 1.1, -0.2];
    let b = beams(20.0, 0.0, v);
    let f = write(&format!(
        "beam1,beam2,beam3,beam4\n{},{},{},{}\n",
        b[0], b[1], b[2], b[3]
    ));
    let out = estim(&[
        "dvl",
        "solve",
        "--beam-angle",
        "20",
        "--azimuth-offset",
        "0",
        f.path().to_str().unwrap(),
    ]);
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    let cells: Vec<f64> = text
        .lines()
        .nth(1)
        .unwrap()
        .split(',')
        .take(3)
        .map(|c| c.parse().unwrap())
        .collect();
    for k in 0..3 {
        assert!((cells[k] - v[k]).abs() < 1e-12);
    }
}

#[test]
fn solve_missing_beam_column_names_line_1() {
    let f = write("beam1,beam2,beam4\n1,2,3\n");
    let out = estim(&[
        "dvl",
        "solve",
        "--beam-angle",
        "20",
        f.path().to_str().unwrap(),
    ]);
    assert_bad_input(&out, ":1:");
    assert_bad_input(&out, "beam3");
}

#[test]
fn solve_non_numeric_cell_names_the_line() {
    // valid rows before the bad one must not leak to stdout
    let f = write("beam1,beam2,beam3,beam4\n0.1,0.2,0.3,0.4\n\n0.1,abc,0.3,0.4\n");
    let out = estim(&[
        "dvl",
        "solve",
        "--beam-angle",
        "20",
        f.path().to_str().unwrap(),
    ]);
    assert_bad_input(&out, ":4:");
    assert_bad_input(&out, "abc");
    let inf = write("beam1,beam2,beam3,beam4\n0.1,inf,0.3,0.4\n");
    let out = estim(&[
        "dvl",
        "solve",
        "--beam-angle",
        "20",
        inf.path().to_str().unwrap(),
    ]);
    assert_bad_input(&out, ":2:");
}

#[test]
fn solve_short_row_names_the_line() {
    let f = write("t,beam1,beam2,beam3,beam4\n0,1,2,3,4\n1,1,2\n");
    let out = estim(&[
        "dvl",
        "solve",
        "--beam-angle",
        "20",
        f.path().to_str().unwrap(),
    ]);
    assert_bad_input(&out, ":3:");
}

#[test]
fn solve_rejects_bad_geometry_empty_file_and_missing_file() {
    let f = write("beam1,beam2,beam3,beam4\n1,2,3,4\n");
    let out = estim(&[
        "dvl",
        "solve",
        "--beam-angle",
        "95",
        f.path().to_str().unwrap(),
    ]);
    assert_bad_input(&out, "beam_angle");
    let empty = write("");
    let out = estim(&[
        "dvl",
        "solve",
        "--beam-angle",
        "20",
        empty.path().to_str().unwrap(),
    ]);
    // An empty file is read as every survey table is: no data row.
    assert_bad_input(&out, "0 data rows");
    let out = estim(&[
        "dvl",
        "solve",
        "--beam-angle",
        "20",
        "/nonexistent/beams.csv",
    ]);
    assert_bad_input(&out, "/nonexistent/beams.csv");
}

#[test]
fn solve_binary_garbage_is_an_error_not_a_panic() {
    let mut f = tempfile::NamedTempFile::new().unwrap();
    f.write_all(b"beam1,beam2,beam3,beam4\n1,2,3,4\n\xff\xfe,\x80,1,2\n")
        .unwrap();
    let out = estim(&[
        "dvl",
        "solve",
        "--beam-angle",
        "20",
        f.path().to_str().unwrap(),
    ]);
    assert_bad_input(&out, ":3:");
}

#[test]
fn calibrate_bad_file_names_file_and_line() {
    let gt = write("t,x\n0,1\n");
    let dvl = write("Time [s],DVL X [m/s],DVL Y [m/s],DVL Z [m/s]\n0,1,0,0\n1,1,0,0\n");
    let out = estim(&[
        "dvl",
        "calibrate",
        "--gt",
        gt.path().to_str().unwrap(),
        "--dvl",
        dvl.path().to_str().unwrap(),
    ]);
    assert_bad_input(&out, &format!("{}:1:", gt.path().display()));
    let good_gt = write(
        "Time [s],Longitude [rad],Latitude [rad],Altitude [m],V North [m/s],V East [m/s],V Down [m/s],Roll [rad],Pitch [rad],Yaw [rad]\n\
         0,0.6,0.57,-20,1,0,0,0,0,0\n1,0.6,0.57,-20,1,0,0,0,0,0\n",
    );
    let bad_dvl = write("Time [s],DVL X [m/s],DVL Y [m/s],DVL Z [m/s]\n0,1,0,0\n1,x,0,0\n");
    let out = estim(&[
        "dvl",
        "calibrate",
        "--gt",
        good_gt.path().to_str().unwrap(),
        "--dvl",
        bad_dvl.path().to_str().unwrap(),
    ]);
    assert_bad_input(&out, ":3:");
    // valid files but far too short for a calibration: a typed error, exit code 2
    let out = estim(&[
        "dvl",
        "calibrate",
        "--gt",
        good_gt.path().to_str().unwrap(),
        "--dvl",
        dvl.path().to_str().unwrap(),
    ]);
    assert_bad_input(&out, "trajectory");
}

#[test]
fn calibrate_prints_estimates_on_akit_13() {
    let required = std::env::var("ESTIM_REQUIRE_DATA").is_ok_and(|v| v == "1");
    let root = std::env::var_os("ESTIM_DATA_DIR")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| {
            std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data")
        });
    let Ok(files) = estim::datasets::trajectory_files(&root, 13) else {
        assert!(
            !required,
            "ESTIM_REQUIRE_DATA=1 but A-KIT trajectory 13 not found"
        );
        eprintln!("skipped: A-KIT data not found");
        return;
    };
    let out = estim(&[
        "dvl",
        "calibrate",
        "--gt",
        files.gt.to_str().unwrap(),
        "--dvl",
        files.dvl.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.starts_with("parameter,estimate,standard_error,unit\n"));
    for name in [
        "lever_arm_x",
        "scale_factor_error",
        "misalignment_z",
        "time_offset",
    ] {
        let line = text.lines().find(|l| l.starts_with(name)).unwrap();
        let cells: Vec<&str> = line.split(',').collect();
        assert!(cells[1].parse::<f64>().unwrap().is_finite());
        assert!(cells[2].parse::<f64>().unwrap() > 0.0);
    }
}

#[test]
fn solve_reads_stdin_with_dash_other_beam_names_and_units() {
    use std::process::Stdio;
    let v = [1.2, 0.4, -0.1];
    let b = beams(30.0, 45.0, v);
    // Beams in mm/s under other common names, time in ms, columns in another order.
    let input = format!(
        "Beam 4 [mm/s],b2 [mm/s],Time [ms],beam_1 [mm/s],beam velocity 3 [mm/s]\r\n{},{},1500,{},{}\r\n",
        b[3] * 1e3,
        b[1] * 1e3,
        b[0] * 1e3,
        b[2] * 1e3
    );
    let mut child = Command::new(env!("CARGO_BIN_EXE_estim"))
        .args(["dvl", "solve", "--beam-angle", "30", "-"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(input.as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines[0], "time_s,vx,vy,vz,error_velocity,n_beams");
    let cells: Vec<&str> = lines[1].split(',').collect();
    assert_eq!(cells[0], "1.5");
    for k in 0..3 {
        let x: f64 = cells[k + 1].parse().unwrap();
        assert!((x - v[k]).abs() < 1e-9, "{}", lines[1]);
    }
    // A bad stdin names `<stdin>` and the line.
    let mut child = Command::new(env!("CARGO_BIN_EXE_estim"))
        .args(["dvl", "solve", "--beam-angle", "30", "-"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(b"b1,b2,b3,b4\n1,2,x,4\n")
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert_bad_input(&out, "<stdin>:2:");
}

#[test]
fn missing_file_names_the_os_error_once() {
    let out = estim(&[
        "dvl",
        "solve",
        "--beam-angle",
        "20",
        "/nonexistent/beams.csv",
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2));
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert_eq!(stderr.matches("No such file").count(), 1, "{stderr}");
}
