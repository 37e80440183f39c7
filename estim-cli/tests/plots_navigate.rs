//! `--plots` of `estim navigate` and `estim smooth` on A-KIT trajectory 2's recorded
//! IMU (its first 60 s, or 200 s) with `vehicles/akit.toml`: structural checks of the
//! SVG files. With `--truth` the track draws the reference (a thick black line and
//! its legend), without it does not; every panel of every plot has at least two
//! distinct tick labels on each axis; a diverged run (the raw IMU, its y axis not
//! flipped) keeps the track's axes in the metres of its valid part, whether it
//! stopped (exit 3, the plots of the rows before the stop) or ran on with the health
//! checks relaxed. Skipped without the data, failed with `ESTIM_REQUIRE_DATA=1`.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::Value;

fn estim(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_estim"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("run estim")
}

/// The inputs in `dir`: trajectory 2's IMU cut to `seconds` (rows of 0.01 s), its DVL
/// and GT, and vehicle files: `akit.toml`, `start.toml` (that with an initial
/// position, for a run without `--truth`), `raw.toml` (IMU axes as recorded),
/// `raw_relaxed.toml` (IMU axes wrong, z reversed too, and the health checks relaxed) and `smooth.toml`
/// (without `[dvl_states]`, which `smooth` refuses).
fn inputs(dir: &Path, seconds: usize) -> Option<()> {
    let root = common::data_root()?;
    let t = root.join("a-kit/Trajectory2");
    let imu = std::fs::read_to_string(t.join("IMU_trajectory2.csv")).expect("IMU");
    let cut: String = imu
        .lines()
        .take(1 + seconds * 100)
        .flat_map(|l| [l, "\n"])
        .collect();
    std::fs::write(dir.join("imu.csv"), cut).expect("write imu");
    std::fs::copy(t.join("DVL_trajectory2.csv"), dir.join("dvl.csv")).expect("dvl");
    std::fs::copy(t.join("GT_trajectory2.csv"), dir.join("gt.csv")).expect("gt");
    let akit = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../vehicles/akit.toml"),
    )
    .expect("vehicles/akit.toml");
    std::fs::write(dir.join("akit.toml"), &akit).expect("write");
    let start = "\n[initial]\nlatitude_deg = 32.8\nlongitude_deg = 34.9\ndepth_m = 20.0\n";
    std::fs::write(dir.join("start.toml"), format!("{akit}{start}")).expect("write");
    assert!(akit.contains("axes = [\"x\", \"-y\", \"z\"]"));
    let raw = akit.replace(
        "axes = [\"x\", \"-y\", \"z\"]",
        "axes = [\"x\", \"y\", \"z\"]",
    );
    std::fs::write(dir.join("raw.toml"), &raw).expect("write");
    // Relaxed: the health checks off, and the IMU's z axis reversed too, so that the
    // run diverges by hundreds of km whatever the vehicle's noise settings.
    let flipped = akit.replace(
        "axes = [\"x\", \"-y\", \"z\"]",
        "axes = [\"x\", \"y\", \"-z\"]",
    );
    let relaxed = format!(
        "{flipped}\n[health]\nnis_window = 0\nfix_nis_window = 0\nmax_speed_mps = 1e9\n\
         max_position_sigma_m = 1e12\nmax_velocity_sigma_mps = 1e9\nmin_depth_m = -1e9\n\
         max_depth_m = 1e9\n"
    );
    std::fs::write(dir.join("raw_relaxed.toml"), relaxed).expect("write");
    let (a, b) = (
        akit.find("[dvl_states]").expect("[dvl_states]"),
        akit.find("[truth]").expect("[truth]"),
    );
    std::fs::write(
        dir.join("smooth.toml"),
        format!("{}{}", &akit[..a], &akit[b..]),
    )
    .expect("write");
    Some(())
}

/// One `<text>` element of an SVG: its attributes and its content.
struct Text {
    attributes: String,
    content: String,
}

fn texts(svg: &str) -> Vec<Text> {
    let mut out = Vec::new();
    let mut rest = svg;
    while let Some(start) = rest.find("<text") {
        rest = &rest[start + 5..];
        let Some(close) = rest.find('>') else { break };
        let attributes = rest[..close].to_string();
        rest = &rest[close + 1..];
        let Some(end) = rest.find("</text>") else {
            break;
        };
        out.push(Text {
            attributes,
            content: rest[..end].trim().to_string(),
        });
        rest = &rest[end..];
    }
    out
}

/// The tick labels of each panel, (x, y), in document order: a panel starts at its
/// rotated y-axis description; y ticks are right-aligned numbers, x ticks centred
/// numbers below the axis (plotters' layout of a mesh).
fn panel_ticks(svg: &str) -> Vec<(Vec<f64>, Vec<f64>)> {
    let mut panels: Vec<(Vec<f64>, Vec<f64>)> = Vec::new();
    for t in texts(svg) {
        if t.attributes.contains("rotate(270") {
            panels.push((Vec::new(), Vec::new()));
            continue;
        }
        let (Some(panel), Ok(v)) = (panels.last_mut(), t.content.parse::<f64>()) else {
            continue;
        };
        if t.attributes.contains("text-anchor=\"end\"") {
            panel.1.push(v);
        } else if t.attributes.contains("text-anchor=\"middle\"")
            && t.attributes.contains("dy=\"0.76em\"")
        {
            panel.0.push(v);
        }
    }
    panels
}

fn distinct(values: &[f64]) -> usize {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    v.dedup();
    v.len()
}

fn svg(dir: &Path, stem: &str) -> String {
    std::fs::read_to_string(dir.join(format!("{stem}.svg"))).expect("svg")
}

/// Every panel of the three plots has >= 2 distinct tick labels on each axis; the
/// sigma plot has its 5 panels.
fn assert_ticks_on_every_panel(out: &Path) {
    for (stem, panels) in [("plot_track", 1), ("plot_sigma", 5), ("plot_nis", 1)] {
        let ticks = panel_ticks(&svg(out, stem));
        assert_eq!(ticks.len(), panels, "{stem}: panels");
        for (i, (x, y)) in ticks.iter().enumerate() {
            assert!(distinct(x) >= 2, "{stem} panel {i}: x ticks {x:?}");
            assert!(distinct(y) >= 2, "{stem} panel {i}: y ticks {y:?}");
        }
    }
}

/// The reference's line: a thick black polyline of many points (the truth's epochs).
fn has_truth_line(track_svg: &str) -> bool {
    track_svg
        .split("<polyline")
        .skip(1)
        .filter(|p| p.contains("stroke=\"#000000\" stroke-width=\"2\""))
        .any(|p| {
            p.split("points=\"")
                .nth(1)
                .is_some_and(|pts| pts.split(' ').count() > 20)
        })
}

fn summary(out: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).expect("summary"))
        .expect("JSON")
}

#[test]
fn truth_is_drawn_and_every_panel_has_tick_labels() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    if inputs(d, 60).is_none() {
        return;
    }
    let base = [
        "--imu",
        "imu.csv",
        "--dvl",
        "dvl.csv",
        "--plots",
        "--vehicle",
    ];
    // Without --truth the vehicle file needs an initial position (start.toml).
    for (command, vehicle, truth, out) in [
        ("navigate", "akit.toml", true, "nav_truth"),
        ("smooth", "smooth.toml", true, "smooth_truth"),
        ("navigate", "start.toml", false, "nav"),
    ] {
        let mut args = vec![command];
        args.extend(base);
        args.extend([vehicle, "--out", out]);
        if truth {
            args.extend(["--truth", "gt.csv"]);
        }
        let o = estim(&args, d);
        assert_eq!(
            o.status.code(),
            Some(0),
            "{args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let out = d.join(out);
        assert_eq!(summary(&out)["plots"]["written"], true, "{args:?}");
        let track = svg(&out, "plot_track");
        assert_eq!(has_truth_line(&track), truth, "{args:?}: truth line");
        assert_eq!(
            track.contains("truth (reference track)"),
            truth,
            "{args:?}: truth legend"
        );
        assert!(
            track.contains("estimate (a break"),
            "{args:?}: estimate legend"
        );
        assert_ticks_on_every_panel(&out);
    }
}

/// The largest |tick| of the track plot \[m\].
fn track_extent(out: &Path) -> f64 {
    let ticks = panel_ticks(&svg(out, "plot_track"));
    ticks[0]
        .0
        .iter()
        .chain(&ticks[0].1)
        .fold(0.0_f64, |m, v| m.max(v.abs()))
}

/// The farthest solution of `solution.csv` from its first row, in metres (a sphere of
/// 6,371 km: an independent, approximate distance).
fn farthest_solution_m(out: &Path) -> f64 {
    let text = std::fs::read_to_string(out.join("solution.csv")).expect("solution.csv");
    let rows: Vec<(f64, f64)> = text
        .lines()
        .skip(1)
        .map(|l| {
            let c: Vec<&str> = l.split(',').collect();
            (c[2].parse().expect("lat"), c[3].parse().expect("lon"))
        })
        .collect();
    let (lat0, lon0) = rows[0];
    rows.iter()
        .map(|&(lat, lon)| {
            let n = (lat - lat0).to_radians() * 6.371e6;
            let e = (lon - lon0).to_radians() * 6.371e6 * lat0.to_radians().cos();
            n.hypot(e)
        })
        .fold(0.0, f64::max)
}

#[test]
fn a_diverged_run_keeps_readable_axes() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    if inputs(d, 200).is_none() {
        return;
    }
    // The raw IMU: stopped by the health checks (exit 3); the rows before the stop are
    // plotted, the captions say so, and the axes stay within what the vehicle could
    // have travelled at 100 m/s by the stop, plus 1 km, widened at most 3 times by
    // the ellipses (the view's rule, docs/cli.md).
    let args = [
        "navigate",
        "--imu",
        "imu.csv",
        "--dvl",
        "dvl.csv",
        "--truth",
        "gt.csv",
        "--vehicle",
        "raw.toml",
        "--out",
        "stopped",
        "--plots",
    ];
    let o = estim(&args, d);
    assert_eq!(
        o.status.code(),
        Some(3),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let out = d.join("stopped");
    let s = summary(&out);
    assert_eq!(s["partial"], true);
    assert_eq!(s["plots"]["written"], true, "{s}");
    let stop = s["stop"]["time_since_epoch_s"].as_f64().expect("stop time");
    let bound = 3.0 * (100.0 * stop + 1000.0) * 1.5;
    let extent = track_extent(&out);
    assert!(
        extent > 0.0 && extent < bound,
        "{extent} m, bound {bound} m"
    );
    for stem in ["plot_track", "plot_sigma", "plot_nis"] {
        assert!(svg(&out, stem).contains("run stopped"), "{stem}");
    }
    assert_ticks_on_every_panel(&out);

    // The health checks relaxed: the run goes on to exit 0 with a diverged solution
    // tens of km off. The view leaves out the solutions beyond 100 m/s from the start
    // (counted in the caption): the farthest solution lies outside the axes.
    let args = [
        "navigate",
        "--imu",
        "imu.csv",
        "--dvl",
        "dvl.csv",
        "--truth",
        "gt.csv",
        "--vehicle",
        "raw_relaxed.toml",
        "--out",
        "relaxed",
        "--plots",
    ];
    let o = estim(&args, d);
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let out = d.join("relaxed");
    let farthest = farthest_solution_m(&out);
    let extent = track_extent(&out);
    assert!(farthest > 5_000.0, "the raw IMU diverges: {farthest} m");
    assert!(
        extent < farthest,
        "the view ({extent} m) leaves out the farthest solution ({farthest} m)"
    );
    assert!(extent < 3.0 * (100.0 * 200.0 + 1000.0) * 1.5, "{extent}");
    assert!(svg(&out, "plot_track").contains("diverged solutions (beyond 100 m/s"));
    assert_ticks_on_every_panel(&out);
}
