//! `[columns]` in the vehicle file (and `--columns FILE` over it): a survey whose IMU,
//! DVL, depth, fixes and truth files have renamed and reordered columns gives the
//! same solution as the standard files, byte for byte (same cells, so the same
//! numbers), and a gyroscope logged in deg/s, declared by its map key, gives the same
//! solution to rounding. Unknown keys and sections are refused naming them, and a
//! survey section in the study's configuration (which reads GT and DVL only). On A-KIT
//! trajectory 2's recorded IMU (first 60 s) with `vehicles/akit.toml`; skipped without
//! the data, failed with `ESTIM_REQUIRE_DATA=1`.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn estim(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_estim"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("run estim")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A CSV table: header cells and rows of cell texts.
struct Table {
    header: Vec<String>,
    rows: Vec<Vec<String>>,
}

impl Table {
    fn read(path: &Path, rows: usize) -> Table {
        let text = std::fs::read_to_string(path).expect("read");
        let mut lines = text.lines();
        let header = lines
            .next()
            .expect("header")
            .split(',')
            .map(str::to_string)
            .collect();
        let rows = lines
            .take(rows)
            .map(|l| l.split(',').map(str::to_string).collect())
            .collect();
        Table { header, rows }
    }

    /// The columns in `order` (indices into this table), renamed to `names`.
    fn rearranged(&self, order: &[usize], names: &[&str]) -> String {
        let mut out = names.join(",") + "\n";
        for r in &self.rows {
            let cells: Vec<&str> = order.iter().map(|&i| r[i].as_str()).collect();
            out += &(cells.join(",") + "\n");
        }
        out
    }

    fn write(&self) -> String {
        let mut out = self.header.join(",") + "\n";
        for r in &self.rows {
            out += &(r.join(",") + "\n");
        }
        out
    }
}

const MAPPED: &str = r#"
[columns.imu]
time_s = "SEC"
acc_x_mps2 = "F1"
acc_y_mps2 = "F2"
acc_z_mps2 = "F3"
gyro_x_radps = "W1"
gyro_y_radps = "W2"
gyro_z_radps = "W3"
[columns.dvl]
time_s = "SEC"
x_mps = "U"
y_mps = "V"
z_mps = "W"
[columns.depth]
time_s = "SEC"
depth_m = "PRESSURE_DEPTH"
[columns.fixes]
time_s = "SEC"
latitude_deg = "N"
longitude_deg = "E"
sigma_m = "ACC"
[columns.gt]
time_s = "SEC"
longitude_rad = "X1"
latitude_rad = "X2"
altitude_m = "X3"
v_north_mps = "X4"
v_east_mps = "X5"
v_down_mps = "X6"
roll_rad = "X7"
pitch_rad = "X8"
heading_rad = "X9"
"#;

/// Writes the standard files (`std/`) and the renamed, reordered ones (`renamed/`), and
/// the vehicle files. `None` without the data.
fn inputs(d: &Path) -> Option<()> {
    let root = common::data_root()?;
    let t = root.join("a-kit/Trajectory2");
    let imu = Table::read(&t.join("IMU_trajectory2.csv"), 6000);
    let dvl = Table::read(&t.join("DVL_trajectory2.csv"), 400);
    let gt = Table::read(&t.join("GT_trajectory2.csv"), 400);
    for sub in ["std", "renamed"] {
        std::fs::create_dir_all(d.join(sub)).expect("mkdir");
    }
    let w = |name: &str, text: String| std::fs::write(d.join(name), text).expect("write");
    w("std/imu.csv", imu.write());
    w("std/dvl.csv", dvl.write());
    w("std/gt.csv", gt.write());
    // Depth from the GT's altitude, fixes from its position (degrees) every 20 s.
    let mut depth = String::from("time,depth\n");
    let mut depth_renamed = String::from("NOTE,PRESSURE_DEPTH,SEC\n");
    let mut fixes = String::from("time,lat [deg],lon [deg],sigma\n");
    let mut fixes_renamed = String::from("ACC,E,SEC,N\n");
    for (k, r) in gt.rows.iter().enumerate().take(60) {
        let alt: f64 = r[3].parse().expect("altitude");
        let d = format!("{}", -alt);
        depth += &format!("{},{d}\n", r[0]);
        depth_renamed += &format!("x,{d},{}\n", r[0]);
        if k % 20 == 5 {
            let lat = format!("{:.9}", r[2].parse::<f64>().expect("lat").to_degrees());
            let lon = format!("{:.9}", r[1].parse::<f64>().expect("lon").to_degrees());
            fixes += &format!("{},{lat},{lon},3.0\n", r[0]);
            fixes_renamed += &format!("3.0,{lon},{},{lat}\n", r[0]);
        }
    }
    w("std/depth.csv", depth);
    w("std/fixes.csv", fixes);
    w("renamed/depth.csv", depth_renamed);
    w("renamed/fixes.csv", fixes_renamed);
    // IMU: time, acc x y z, gyro x y z -> gyro z y x, time, acc z x y.
    w(
        "renamed/imu.csv",
        imu.rearranged(
            &[6, 5, 4, 0, 3, 1, 2],
            &["W3", "W2", "W1", "SEC", "F3", "F1", "F2"],
        ),
    );
    w(
        "renamed/dvl.csv",
        dvl.rearranged(&[2, 0, 3, 1], &["V", "SEC", "W", "U"]),
    );
    w(
        "renamed/gt.csv",
        gt.rearranged(
            &[9, 8, 7, 6, 5, 4, 3, 2, 1, 0],
            &["X9", "X8", "X7", "X6", "X5", "X4", "X3", "X2", "X1", "SEC"],
        ),
    );
    // The gyroscope in deg/s, declared by the map key.
    let mut deg = imu.rearranged(
        &[6, 5, 4, 0, 3, 1, 2],
        &["W3", "W2", "W1", "SEC", "F3", "F1", "F2"],
    );
    deg = deg
        .lines()
        .enumerate()
        .map(|(i, l)| {
            if i == 0 {
                return l.to_string() + "\n";
            }
            let mut c: Vec<String> = l.split(',').map(str::to_string).collect();
            for cell in c.iter_mut().take(3) {
                let v: f64 = cell.parse().expect("rate");
                *cell = format!("{:e}", v.to_degrees());
            }
            c.join(",") + "\n"
        })
        .collect();
    w("renamed/imu_deg.csv", deg);
    let akit = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../vehicles/akit.toml"),
    )
    .expect("vehicles/akit.toml");
    w("std.toml", akit.clone());
    w("mapped.toml", format!("{akit}{MAPPED}"));
    w(
        "mapped_deg.toml",
        format!(
            "{akit}{}",
            MAPPED
                .replace("gyro_x_radps", "gyro_x_degps")
                .replace("gyro_y_radps", "gyro_y_degps")
                .replace("gyro_z_radps", "gyro_z_degps")
        ),
    );
    // A vehicle file mapping the gyroscope wrongly, put right by --columns.
    w(
        "wrong.toml",
        format!("{akit}{}", MAPPED.replace("\"W1\"", "\"NOPE\"")),
    );
    w(
        "fix.toml",
        "[columns.imu]\ngyro_x_radps = \"W1\"\n".to_string(),
    );
    Some(())
}

fn run(d: &Path, dir: &str, imu: &str, vehicle: &str, extra: &[&str], out: &str) -> String {
    let files = |f: &str| format!("{dir}/{f}");
    let (imu, dvl, depth, fixes, gt) = (
        files(imu),
        files("dvl.csv"),
        files("depth.csv"),
        files("fixes.csv"),
        files("gt.csv"),
    );
    let mut args = vec![
        "navigate",
        "--imu",
        &imu,
        "--dvl",
        &dvl,
        "--depth",
        &depth,
        "--fixes",
        &fixes,
        "--truth",
        &gt,
        "--vehicle",
        vehicle,
        "--out",
        out,
    ];
    args.extend(extra);
    let o = estim(&args, d);
    assert_eq!(o.status.code(), Some(0), "{args:?}: {}", stderr(&o));
    std::fs::read_to_string(d.join(out).join("solution.csv")).expect("solution.csv")
}

fn summary(d: &Path, out: &str) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(d.join(out).join("summary.json")).expect("read"))
        .expect("JSON")
}

#[test]
fn renamed_and_reordered_columns_give_the_same_solution() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    if inputs(d).is_none() {
        return;
    }
    let standard = run(d, "std", "imu.csv", "std.toml", &[], "a");
    let s = summary(d, "a");
    // The run used every input: DVL, depth and fix updates, and a scored truth.
    for sensor in ["dvl", "depth", "fixes"] {
        assert!(
            s["updates"][sensor]["accepted"].as_u64().unwrap_or(0) > 0,
            "{sensor}: {}",
            s["updates"]
        );
    }
    assert!(
        s["evaluation"]["position_rmse_m"].as_f64().is_some(),
        "{}",
        s["evaluation"]
    );
    let renamed = run(d, "renamed", "imu.csv", "mapped.toml", &[], "b");
    assert_eq!(
        renamed, standard,
        "renamed columns, same cells: the same solution"
    );
    assert_eq!(summary(d, "b")["evaluation"], s["evaluation"]);
    // The map is in the summary's configuration.
    assert_eq!(
        summary(d, "b")["inputs"]["configuration"]["columns"]["imu"]["gyro_x_radps"],
        "W1"
    );

    // --columns overrides the vehicle file's entry for the same quantity.
    let fixed = run(
        d,
        "renamed",
        "imu.csv",
        "wrong.toml",
        &["--columns", "fix.toml"],
        "c",
    );
    assert_eq!(fixed, standard, "--columns over the vehicle file");
    // Without it the vehicle file's wrong entry is an error naming the mapped header.
    let o = estim(
        &[
            "navigate",
            "--imu",
            "renamed/imu.csv",
            "--dvl",
            "renamed/dvl.csv",
            "--vehicle",
            "wrong.toml",
        ],
        d,
    );
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("NOPE") && stderr(&o).contains("imu.csv"),
        "{}",
        stderr(&o)
    );

    // The gyroscope in deg/s: the same solution to rounding (the cells differ).
    let deg = run(d, "renamed", "imu_deg.csv", "mapped_deg.toml", &[], "e");
    let last = |text: &str| -> Vec<f64> {
        let line = text.lines().last().expect("row");
        line.split(',')
            .enumerate()
            .filter(|(i, _)| [0, 2, 3, 4].contains(i))
            .map(|(_, c)| c.parse().expect("number"))
            .collect()
    };
    assert_eq!(deg.lines().count(), standard.lines().count());
    let (a, b) = (last(&standard), last(&deg));
    assert_eq!(a[0], b[0], "time");
    assert!(
        (a[1] - b[1]).abs() < 1e-8 && (a[2] - b[2]).abs() < 1e-8,
        "{a:?} {b:?}"
    );
    assert!((a[3] - b[3]).abs() < 1e-3, "depth {a:?} {b:?}");
}

#[test]
fn unknown_column_keys_and_sections_are_refused_naming_them() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    std::fs::write(
        d.join("imu.csv"),
        "time,ax,ay,az,gx,gy,gz\n0,0,0,-9.8,0,0,0\n",
    )
    .expect("w");
    std::fs::write(d.join("dvl.csv"), "time,vx,vy,vz\n0,1,0,0\n").expect("w");
    for (toml, needles) in [
        (
            "[columns.imu]\nacc_q_mps2 = \"A\"\n",
            &["columns.imu.acc_q_mps2", "acc_x_mps2"][..],
        ),
        (
            "[columns.imu]\ngyro_x_furlong = \"A\"\n",
            &["columns.imu.gyro_x_furlong"][..],
        ),
        (
            "[columns.dvl]\nx_mps = \"\"\n",
            &["columns.dvl.x_mps", "empty"][..],
        ),
        (
            "[columns.imu]\ntime_s = \"A\"\ntime_ms = \"B\"\n",
            &["columns.imu", "time", "second time"][..],
        ),
        (
            "\n[columns.gps]\ntime_s = \"A\"\n",
            &["v.toml:2", "gps"][..],
        ),
    ] {
        std::fs::write(d.join("v.toml"), toml).expect("write");
        let o = estim(
            &[
                "navigate",
                "--imu",
                "imu.csv",
                "--dvl",
                "dvl.csv",
                "--vehicle",
                "v.toml",
            ],
            d,
        );
        assert_eq!(o.status.code(), Some(2), "{toml}: {}", stderr(&o));
        let e = stderr(&o);
        for n in needles {
            assert!(e.contains(n), "{toml}: `{n}` not in: {e}");
        }
        assert!(o.stdout.is_empty());
        // The same table in a --columns file is refused naming that file.
        let table = toml.trim_start().to_string();
        std::fs::write(d.join("c.toml"), &table).expect("write");
        let o = estim(
            &[
                "navigate",
                "--imu",
                "imu.csv",
                "--dvl",
                "dvl.csv",
                "--columns",
                "c.toml",
            ],
            d,
        );
        assert_eq!(
            o.status.code(),
            Some(2),
            "--columns {table}: {}",
            stderr(&o)
        );
        assert!(stderr(&o).contains("c.toml"), "{}", stderr(&o));
    }
    // The study's configuration reads GT and DVL files only: a survey section there
    // would be ignored, so it is refused naming it.
    std::fs::write(d.join("study.toml"), "[columns.imu]\ntime_s = \"SEC\"\n").expect("write");
    let o = estim(&["reproduce", "--config", "study.toml", "--json"], d);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("study.toml") && stderr(&o).contains("columns.imu: not used here"),
        "{}",
        stderr(&o)
    );
    // A --columns file holds only [columns].
    std::fs::write(d.join("c.toml"), "[dvl]\ntime_offset_s = 1.0\n").expect("write");
    let o = estim(
        &[
            "navigate",
            "--imu",
            "imu.csv",
            "--dvl",
            "dvl.csv",
            "--columns",
            "c.toml",
        ],
        d,
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("c.toml:1") && stderr(&o).contains("dvl"),
        "{}",
        stderr(&o)
    );
}
