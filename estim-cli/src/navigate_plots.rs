//! Plots of `estim navigate --plots` and `estim smooth --plots` (PNG and SVG, into the
//! staged `--out` folder): the north-east track with 3-sigma position ellipses, the
//! 1-sigma of every state group over time, and the DVL NIS of every update with its
//! chi-square band.
//!
//! Lines join consecutive solutions only: where two solutions are more than twice the
//! median solution interval apart the line breaks. With `navigate --rate` the
//! solutions inside a DVL gap are the filter coasting at that rate (with its growing
//! sigma) and are drawn as such; without solutions inside a gap (no `--rate`, or the
//! smoother, whose estimates exist at the update epochs) the gap stays empty, never a
//! straight line between its ends.
//!
//! The track's view covers the solution and, with `--truth`, the reference over the
//! solution's span. A solution farther from the first one than a vehicle could have
//! gone at [`MAX_PLOTTED_SPEED_MPS`] (plus [`PLAUSIBLE_MARGIN_M`]) is a diverged one:
//! it does not widen the view and is clipped at the frame, and the caption counts it.
//! The 3-sigma ellipses widen the view by at most its larger side beyond the track
//! (at least [`MIN_VIEW_M`]); an ellipse larger than that is clipped at the frame and
//! counted. So a diverged run (a partial one that stopped with exit 3, or a solution
//! of 1e8 m) keeps axes in the metres of the track that was valid.
//!
//! Every log axis runs from a power of ten to a power of ten, at least one decade
//! ([`crate::plots::log_axis_range`]): plotters labels a log axis at powers of ten and
//! between them, so an axis inside one decade had no tick label.

use std::path::Path;

use estim::ins::{earth, ErrorMatrix, POS};
use estim::navigator::{NavSolution, SolutionKind};
use plotters::coord::Shift;
use plotters::prelude::*;

const SIZE: (u32, u32) = (960, 720);
const SIGMA_SIZE: (u32, u32) = (960, 1200);
/// Ellipses drawn on the track at most (evenly spaced DVL epochs, and the last).
const MAX_ELLIPSES: usize = 40;
/// A solution farther from the first than this speed times the elapsed time (plus
/// [`PLAUSIBLE_MARGIN_M`]) is outside the track's view: faster than any vehicle that
/// carries a DVL \[m/s\].
pub const MAX_PLOTTED_SPEED_MPS: f64 = 100.0;
/// The distance from the first solution always inside the plausible part \[m\].
pub const PLAUSIBLE_MARGIN_M: f64 = 1000.0;
/// The smallest side of the track's view \[m\].
pub const MIN_VIEW_M: f64 = 10.0;
/// The NIS band's probability.
const NIS_BAND_PROBABILITY: f64 = 0.95;
const AXIS_COLORS: [RGBColor; 3] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
];

/// One solution as the plots need it.
#[derive(Debug, Clone, Copy)]
pub struct PlotRow {
    /// Time since the first solution \[s\].
    pub time: f64,
    /// Why it was emitted.
    pub kind: SolutionKind,
    /// Latitude, longitude \[deg\].
    pub position_deg: [f64; 2],
    /// 1-sigma per group: position m, velocity m/s, attitude deg, acc bias m/s^2,
    /// gyro bias rad/s (three axes each).
    pub sigma: [[f64; 3]; 5],
    /// The north-east block of the position covariance \[m^2\].
    pub north_east: [[f64; 2]; 2],
}

impl PlotRow {
    /// The row of a solution and its covariance.
    pub fn new(kind: SolutionKind, s: &NavSolution, covariance: &ErrorMatrix) -> Self {
        Self {
            time: s.time,
            kind,
            position_deg: [s.latitude_deg, s.longitude_deg],
            sigma: [
                s.position_sigma_m,
                s.velocity_sigma_mps,
                s.attitude_sigma_deg,
                s.acc_bias_sigma_mps2,
                s.gyro_bias_sigma_radps,
            ],
            north_east: [
                [covariance[(POS, POS)], covariance[(POS, POS + 1)]],
                [covariance[(POS + 1, POS)], covariance[(POS + 1, POS + 1)]],
            ],
        }
    }
}

/// What the plots show: the solutions in time order, the DVL NIS with their times.
pub struct PlotData<'a> {
    /// `navigate` or `smooth` (titles).
    pub command: &'a str,
    /// What the solutions are ("filter" or "smoothed").
    pub solution_label: &'a str,
    /// The solutions.
    pub rows: &'a [PlotRow],
    /// Times of the DVL update attempts \[s\] (the navigator's clock).
    pub nis_times: &'a [f64],
    /// Their NIS.
    pub nis: &'a [f64],
    /// With `--truth`: the reference's track (latitude, longitude \[deg\], carried to
    /// the IMU's point) at its own epochs inside the solutions' span; empty without.
    pub truth: &'a [[f64; 2]],
    /// For a run that stopped (exit 3): the stop, said in every caption.
    pub stopped: Option<&'a str>,
}

/// The plot files written by [`write_plots`] (stems; each as `.png` and `.svg`).
pub const PLOT_STEMS: [&str; 3] = ["plot_track", "plot_sigma", "plot_nis"];

type Plot<T = ()> = anyhow::Result<T>;

fn err<E: std::fmt::Display>(e: E) -> anyhow::Error {
    anyhow::anyhow!("plot: {e}")
}

/// Write every plot into `dir`.
///
/// # Errors
/// A drawing or file error (the caller's staged folder is then discarded).
pub fn write_plots(dir: &Path, data: &PlotData<'_>) -> Plot {
    anyhow::ensure!(!data.rows.is_empty(), "plot: no solution to draw");
    let t0 = data.rows[0].time;
    let segments = time_segments(data.rows);
    for (stem, size) in [
        (PLOT_STEMS[0], SIZE),
        (PLOT_STEMS[1], SIGMA_SIZE),
        (PLOT_STEMS[2], SIZE),
    ] {
        let png = dir.join(format!("{stem}.png"));
        let svg = dir.join(format!("{stem}.svg"));
        let named = |path: &Path| {
            let name = path
                .file_name()
                .unwrap_or_default()
                .to_string_lossy()
                .into_owned();
            move |e: anyhow::Error| anyhow::anyhow!("{name}: {e:#}")
        };
        draw(
            stem,
            BitMapBackend::new(&png, size).into_drawing_area(),
            data,
            &segments,
            t0,
        )
        .map_err(named(&png))?;
        draw(
            stem,
            SVGBackend::new(&svg, size).into_drawing_area(),
            data,
            &segments,
            t0,
        )
        .map_err(named(&svg))?;
    }
    Ok(())
}

/// [`write_plots`] for an optional output: a failure (nothing to draw, a drawing
/// error) removes the plot files written so far, is warned about on stderr and
/// returned as the summary's `plots` block, and the run's other outputs are kept.
pub fn write_plots_or_warn(dir: &Path, data: &PlotData<'_>) -> serde_json::Value {
    match write_plots(dir, data) {
        Ok(()) => serde_json::json!({ "written": true, "files": PLOT_STEMS }),
        Err(e) => {
            for stem in PLOT_STEMS {
                for ext in ["png", "svg"] {
                    let _ = std::fs::remove_file(dir.join(format!("{stem}.{ext}")));
                }
            }
            eprintln!("warning: --plots: {e:#}; no plot written, the other outputs are complete");
            serde_json::json!({ "written": false, "reason": format!("{e:#}") })
        }
    }
}

fn draw<DB: DrawingBackend>(
    stem: &str,
    root: DrawingArea<DB, Shift>,
    data: &PlotData<'_>,
    segments: &[std::ops::Range<usize>],
    t0: f64,
) -> Plot
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(err)?;
    match stem {
        "plot_track" => track(&root, data, segments),
        "plot_sigma" => sigmas(&root, data, segments, t0),
        _ => nis(&root, data, t0),
    }?;
    root.present().map_err(err)
}

/// Index ranges of the rows between two breaks (an interval longer than twice the
/// median interval).
pub fn time_segments(rows: &[PlotRow]) -> Vec<std::ops::Range<usize>> {
    let mut intervals: Vec<f64> = rows.windows(2).map(|w| w[1].time - w[0].time).collect();
    intervals.sort_by(f64::total_cmp);
    let median = intervals.get(intervals.len() / 2).copied().unwrap_or(0.0);
    let limit = 2.0 * median;
    let mut out = Vec::new();
    let mut start = 0;
    for k in 1..rows.len() {
        if rows[k].time - rows[k - 1].time > limit {
            out.push(start..k);
            start = k;
        }
    }
    out.push(start..rows.len());
    out
}

/// North, east \[m\] of a latitude, longitude \[deg\] from the first row's position
/// (local tangent plane).
fn north_east(rows: &[PlotRow], position_deg: &[f64; 2]) -> (f64, f64) {
    let [lat0, lon0] = rows[0].position_deg;
    let (rn, re) = earth::radii_of_curvature(lat0.to_radians());
    (
        (position_deg[0] - lat0).to_radians() * rn,
        (position_deg[1] - lon0).to_radians() * re * lat0.to_radians().cos(),
    )
}

/// Points of the 3-sigma ellipse of a 2x2 covariance (north, east) around a centre,
/// as (east, north) for the plot: centre + 3 (sqrt(l1) cos t u1 + sqrt(l2) sin t u2),
/// with l, u the eigenpairs (a 2-D Gaussian lies inside with probability
/// 1 - exp(-9/2) = 98.9 %).
pub fn ellipse(centre: (f64, f64), p: [[f64; 2]; 2]) -> Vec<(f64, f64)> {
    let (a, b, c) = (p[0][0], 0.5 * (p[0][1] + p[1][0]), p[1][1]);
    let mean = 0.5 * (a + c);
    let radius = (0.25 * (a - c) * (a - c) + b * b).sqrt();
    let (l1, l2) = ((mean + radius).max(0.0), (mean - radius).max(0.0));
    let angle = 0.5 * (2.0 * b).atan2(a - c);
    let (s, co) = angle.sin_cos();
    (0..=64)
        .map(|k| {
            let t = f64::from(k) / 64.0 * std::f64::consts::TAU;
            let (x, y) = (3.0 * l1.sqrt() * t.cos(), 3.0 * l2.sqrt() * t.sin());
            let north = centre.0 + co * x - s * y;
            let east = centre.1 + s * x + co * y;
            (east, north)
        })
        .collect()
}

/// The track's view (east and north ranges \[m\]) and what lies outside it.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackView {
    /// East range \[m\].
    pub east: (f64, f64),
    /// North range \[m\].
    pub north: (f64, f64),
    /// Solutions outside the plausible part (diverged or not finite).
    pub diverged_solutions: usize,
    /// Ellipses not wholly inside the view.
    pub clipped_ellipses: usize,
}

/// The track's view: the box of the plausible solutions (see the module docs) and
/// the truth, widened by the ellipses by at most its larger side (at least
/// [`MIN_VIEW_M`]). Points are (east, north) \[m\]; `elapsed` the solutions' times
/// since the first \[s\].
pub fn track_view(
    solution: &[(f64, f64)],
    elapsed: &[f64],
    truth: &[(f64, f64)],
    ellipses: &[Vec<(f64, f64)>],
) -> TrackView {
    let finite = |p: &&(f64, f64)| p.0.is_finite() && p.1.is_finite();
    let plausible = |(p, t): (&(f64, f64), &f64)| {
        finite(&p) && p.0.hypot(p.1) <= MAX_PLOTTED_SPEED_MPS * t.abs() + PLAUSIBLE_MARGIN_M
    };
    let kept: Vec<(f64, f64)> = solution
        .iter()
        .zip(elapsed)
        .filter(|&pair| plausible(pair))
        .map(|(p, _)| *p)
        .collect();
    let diverged_solutions = solution.len() - kept.len();
    let mut b = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in kept.iter().chain(truth.iter().filter(finite)) {
        b = (b.0.min(x), b.1.max(x), b.2.min(y), b.3.max(y));
    }
    if b.0 > b.1 {
        b = (-1.0, 1.0, -1.0, 1.0);
    }
    let side = (b.1 - b.0).max(b.3 - b.2).max(MIN_VIEW_M);
    let (cx, cy) = (0.5 * (b.0 + b.1), 0.5 * (b.2 + b.3));
    // At least MIN_VIEW_M wide, centred on the track.
    let mut v = (
        b.0.min(cx - 0.5 * MIN_VIEW_M),
        b.1.max(cx + 0.5 * MIN_VIEW_M),
        b.2.min(cy - 0.5 * MIN_VIEW_M),
        b.3.max(cy + 0.5 * MIN_VIEW_M),
    );
    let limit = (v.0 - side, v.1 + side, v.2 - side, v.3 + side);
    for &(x, y) in ellipses.iter().flatten().filter(finite) {
        v = (
            v.0.min(x).max(limit.0),
            v.1.max(x).min(limit.1),
            v.2.min(y).max(limit.2),
            v.3.max(y).min(limit.3),
        );
    }
    let clipped_ellipses = ellipses
        .iter()
        .filter(|e| {
            e.iter()
                .any(|&(x, y)| !(x >= v.0 && x <= v.1 && y >= v.2 && y <= v.3))
        })
        .count();
    TrackView {
        east: (v.0, v.1),
        north: (v.2, v.3),
        diverged_solutions,
        clipped_ellipses,
    }
}

/// The part of segment a-b inside the rectangle `x` by `y` (Liang-Barsky), `None` when
/// none is or a coordinate is not finite.
fn clip_segment(
    a: (f64, f64),
    b: (f64, f64),
    x: (f64, f64),
    y: (f64, f64),
) -> Option<((f64, f64), (f64, f64))> {
    if ![a.0, a.1, b.0, b.1].iter().all(|v| v.is_finite()) {
        return None;
    }
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let (mut t0, mut t1) = (0.0_f64, 1.0_f64);
    for (p, q) in [
        (-dx, a.0 - x.0),
        (dx, x.1 - a.0),
        (-dy, a.1 - y.0),
        (dy, y.1 - a.1),
    ] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let r = q / p;
            if p < 0.0 {
                t0 = t0.max(r);
            } else {
                t1 = t1.min(r);
            }
        }
    }
    (t0 <= t1).then_some((
        (a.0 + t0 * dx, a.1 + t0 * dy),
        (a.0 + t1 * dx, a.1 + t1 * dy),
    ))
}

/// The pieces of a polyline inside the rectangle `x` by `y`: a line leaving the frame
/// ends at its edge and starts again where it comes back.
pub fn clip_polyline(points: &[(f64, f64)], x: (f64, f64), y: (f64, f64)) -> Vec<Vec<(f64, f64)>> {
    let mut out = Vec::new();
    let mut current: Vec<(f64, f64)> = Vec::new();
    for w in points.windows(2) {
        match clip_segment(w[0], w[1], x, y) {
            Some((a, b)) => {
                if current.last() != Some(&a) {
                    if current.len() >= 2 {
                        out.push(std::mem::take(&mut current));
                    }
                    current = vec![a];
                }
                current.push(b);
            }
            None => {
                if current.len() >= 2 {
                    out.push(std::mem::take(&mut current));
                }
                current.clear();
            }
        }
    }
    if current.len() >= 2 {
        out.push(current);
    }
    out
}

/// A log axis's tick label: 1, 2 and 5 times a power of ten are labelled (`2e-5`),
/// the other ticks plotters places between the powers of ten only draw their grid
/// line, so the labels of one decade do not crowd.
pub fn log_tick_label(value: &f64) -> String {
    let text = format!("{value:.0e}");
    if ["1e", "2e", "5e"].iter().any(|m| text.starts_with(m)) {
        text
    } else {
        String::new()
    }
}

/// A polyline split at every vertex where it turns by more than 90 degrees: plotters
/// draws a thick line in a bitmap as one polygon with mitred joins, and the mitre of
/// such a turn is a spike far out of the frame.
fn split_sharp_turns(piece: Vec<(f64, f64)>) -> Vec<Vec<(f64, f64)>> {
    let mut out = Vec::new();
    let mut current: Vec<(f64, f64)> = Vec::new();
    for p in piece {
        if let [.., a, b] = current[..] {
            let (u, v) = ((b.0 - a.0, b.1 - a.1), (p.0 - b.0, p.1 - b.1));
            if u.0 * v.0 + u.1 * v.1 < 0.0 {
                out.push(std::mem::replace(&mut current, vec![b]));
            }
        }
        current.push(p);
    }
    if current.len() >= 2 {
        out.push(current);
    }
    out
}

/// The caption's note for a stopped run ("" otherwise).
fn stop_note(data: &PlotData<'_>) -> String {
    data.stopped
        .map(|s| format!(" [run stopped: {s}]"))
        .unwrap_or_default()
}

/// What the track plot leaves out of its view, for its caption.
fn outside_notes(view: &TrackView, stopped: Option<&str>) -> Vec<String> {
    let mut outside = Vec::new();
    if view.diverged_solutions > 0 {
        outside.push(format!(
            "{} diverged solutions (beyond {MAX_PLOTTED_SPEED_MPS} m/s from the start) outside the view",
            view.diverged_solutions
        ));
    }
    if view.clipped_ellipses > 0 {
        outside.push(format!(
            "{} ellipses clipped at the frame",
            view.clipped_ellipses
        ));
    }
    if let Some(stop) = stopped {
        outside.insert(
            0,
            format!("run stopped ({stop}): the solutions before the stop"),
        );
    }
    outside
}

/// The 3-sigma position ellipses drawn: at most [`MAX_ELLIPSES`] of the DVL epochs,
/// evenly spaced, and the last solution.
fn position_ellipses(rows: &[PlotRow], points: &[(f64, f64)]) -> Vec<Vec<(f64, f64)>> {
    let dvl: Vec<usize> = (0..rows.len())
        .filter(|&k| rows[k].kind == SolutionKind::Dvl)
        .collect();
    let step = dvl.len().div_ceil(MAX_ELLIPSES).max(1);
    let mut chosen: Vec<usize> = dvl.iter().copied().step_by(step).collect();
    chosen.extend(rows.len().checked_sub(1));
    chosen
        .iter()
        .map(|&k| ellipse((points[k].1, points[k].0), rows[k].north_east))
        .collect()
}

fn track<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    data: &PlotData<'_>,
    segments: &[std::ops::Range<usize>],
) -> Plot
where
    DB::ErrorType: 'static,
{
    let rows = data.rows;
    let points: Vec<(f64, f64)> = rows
        .iter()
        .map(|r| {
            let (n, e) = north_east(rows, &r.position_deg);
            (e, n)
        })
        .collect();
    let truth: Vec<(f64, f64)> = data
        .truth
        .iter()
        .map(|p| {
            let (n, e) = north_east(rows, p);
            (e, n)
        })
        .collect();
    let ellipses = position_ellipses(rows, &points);
    let elapsed: Vec<f64> = rows.iter().map(|r| r.time - rows[0].time).collect();
    let view = track_view(&points, &elapsed, &truth, &ellipses);
    let (title, body) = root.split_vertically(50);
    let (w, h) = body.dim_in_pixel();
    let ((x0, x1), (y0, y1)) = crate::plots::equal_scale_ranges(
        view.east,
        view.north,
        (w.saturating_sub(110), h.saturating_sub(110)),
    );
    let outside = outside_notes(&view, data.stopped);
    title
        .draw(&Text::new(
            format!(
                "estim {}: track ({} solution), 3-sigma position ellipses (98.9 %)",
                data.command, data.solution_label,
            ),
            (12, 6),
            ("sans-serif", 18),
        ))
        .map_err(err)?;
    title
        .draw(&Text::new(outside.join("; "), (12, 30), ("sans-serif", 13)))
        .map_err(err)?;
    let mut chart = ChartBuilder::on(&body)
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("east of the first solution [m]")
        .y_desc("north of the first solution [m]")
        .draw()
        .map_err(err)?;
    let (xr, yr) = ((x0, x1), (y0, y1));
    if !truth.is_empty() {
        let style = BLACK.stroke_width(2);
        let pieces = clip_polyline(&truth, xr, yr);
        for (i, piece) in pieces.into_iter().flat_map(split_sharp_turns).enumerate() {
            let series = chart
                .draw_series(LineSeries::new(piece, style))
                .map_err(err)?;
            if i == 0 {
                series
                    .label("truth (reference track)")
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
            }
        }
    }
    let line = AXIS_COLORS[0].stroke_width(2);
    let mut labelled = false;
    for range in segments {
        let pieces = clip_polyline(&points[range.clone()], xr, yr);
        for piece in pieces.into_iter().flat_map(split_sharp_turns) {
            let series = chart
                .draw_series(LineSeries::new(piece, line))
                .map_err(err)?;
            if !labelled {
                labelled = true;
                series
                    .label("estimate (a break = no solution in between)")
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], line));
            }
        }
    }
    let ring = RGBColor(214, 39, 40).stroke_width(1);
    let mut labelled = false;
    for e in &ellipses {
        for piece in clip_polyline(e, xr, yr) {
            let series = chart
                .draw_series(std::iter::once(PathElement::new(piece, ring)))
                .map_err(err)?;
            if !labelled {
                labelled = true;
                series
                    .label("3-sigma position ellipse (DVL epochs)")
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], ring));
            }
        }
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(err)?;
    Ok(())
}

fn sigmas<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    data: &PlotData<'_>,
    segments: &[std::ops::Range<usize>],
    t0: f64,
) -> Plot
where
    DB::ErrorType: 'static,
{
    let groups = [
        ("position 1-sigma [m]", ["north", "east", "down"]),
        ("velocity 1-sigma [m/s]", ["north", "east", "down"]),
        (
            "misalignment 1-sigma [deg]",
            ["about N", "about E", "about D (heading)"],
        ),
        ("accelerometer bias 1-sigma [m/s^2]", ["x", "y", "z"]),
        ("gyroscope bias 1-sigma [rad/s]", ["x", "y", "z"]),
    ];
    let (title, body) = root.split_vertically(40);
    title
        .titled(
            &format!(
                "estim {}: 1-sigma per state group ({} solution; sqrt of the diagonal of P){}",
                data.command,
                data.solution_label,
                stop_note(data)
            ),
            ("sans-serif", 20),
        )
        .map_err(err)?;
    let panels = body.split_evenly((groups.len(), 1));
    let rows = data.rows;
    let x1 = rows.last().map_or(1.0, |r| r.time - t0).max(1e-9);
    for (g, ((label, axes), panel)) in groups.iter().zip(&panels).enumerate() {
        let values = rows
            .iter()
            .flat_map(|r| r.sigma[g])
            .filter(|v| *v > 0.0 && v.is_finite());
        let (lo, hi) = values.fold((f64::MAX, f64::MIN), |(a, b), v| (a.min(v), b.max(v)));
        let (lo, hi) = if lo > hi {
            (1e-12, 1.0)
        } else {
            crate::plots::log_axis_range(lo, hi)
        };
        let mut chart = ChartBuilder::on(panel)
            .margin(8)
            .x_label_area_size(30)
            .y_label_area_size(80)
            .build_cartesian_2d(0.0..x1, (lo..hi).log_scale())
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc("time since the first solution [s]")
            .y_desc(*label)
            .y_label_formatter(&log_tick_label)
            .draw()
            .map_err(err)?;
        for (axis, name) in axes.iter().enumerate() {
            let style = AXIS_COLORS[axis].stroke_width(2);
            for (i, range) in segments.iter().enumerate() {
                let series = chart
                    .draw_series(LineSeries::new(
                        rows[range.clone()]
                            .iter()
                            .map(|r| (r.time - t0, r.sigma[g][axis]))
                            .filter(|p| p.1 > 0.0 && p.1.is_finite()),
                        style,
                    ))
                    .map_err(err)?;
                if i == 0 {
                    series
                        .label(*name)
                        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
                }
            }
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(err)?;
    }
    Ok(())
}

fn nis<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, data: &PlotData<'_>, t0: f64) -> Plot
where
    DB::ErrorType: 'static,
{
    let band =
        estim::core::consistency::chi_square_band(3, 1, NIS_BAND_PROBABILITY).map_err(err)?;
    let points: Vec<(f64, f64)> = data
        .nis_times
        .iter()
        .zip(data.nis)
        .map(|(&t, &v)| (t - t0, v))
        .filter(|p| p.1.is_finite() && p.1 > 0.0)
        .collect();
    let inside = points
        .iter()
        .filter(|p| p.1 >= band.lower && p.1 <= band.upper)
        .count();
    let (lo, hi) = points.iter().fold((band.lower, band.upper), |(a, b), p| {
        (a.min(p.1), b.max(p.1))
    });
    let x1 = data
        .rows
        .last()
        .map_or(1.0, |r| r.time - t0)
        .max(points.last().map_or(0.0, |p| p.0))
        .max(1e-9);
    let mut chart = ChartBuilder::on(root)
        .caption(
            format!(
                "estim {}: DVL NIS per epoch (not averaged; forward filter), {} of {} inside the {:.0} % chi-square(3) band{}",
                data.command,
                inside,
                points.len(),
                100.0 * NIS_BAND_PROBABILITY,
                stop_note(data)
            ),
            ("sans-serif", 17),
        )
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..x1, {
            let (lo, hi) = crate::plots::log_axis_range(lo, hi);
            (lo..hi).log_scale()
        })
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("time since the first solution [s]")
        .y_desc("NIS of the DVL update (3 dof)")
        .y_label_formatter(&log_tick_label)
        .draw()
        .map_err(err)?;
    let dot = AXIS_COLORS[0].filled();
    chart
        .draw_series(points.iter().map(|&p| Circle::new(p, 2, dot)))
        .map_err(err)?
        .label("NIS of one update")
        .legend(move |(x, y)| Circle::new((x + 10, y), 3, dot));
    let edge = BLACK.stroke_width(1);
    for (i, v) in [band.lower, band.upper].into_iter().enumerate() {
        let series = chart
            .draw_series(LineSeries::new([(0.0, v), (x1, v)], edge))
            .map_err(err)?;
        if i == 0 {
            series
                .label(format!(
                    "{:.0} % band of one chi-square(3) draw: [{:.3}, {:.2}]",
                    100.0 * NIS_BAND_PROBABILITY,
                    band.lower,
                    band.upper
                ))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], edge));
        }
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(err)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The ellipse's points satisfy d' P^-1 d = 9 (the 3-sigma contour), for a
    /// correlated covariance.
    #[test]
    fn ellipse_is_the_three_sigma_contour() {
        let p = [[4.0, 1.5], [1.5, 1.0]];
        let det = p[0][0] * p[1][1] - p[0][1] * p[1][0];
        for (east, north) in ellipse((10.0, -5.0), p) {
            let (dn, de) = (north - 10.0, east + 5.0);
            let q = (p[1][1] * dn * dn - 2.0 * p[0][1] * dn * de + p[0][0] * de * de) / det;
            assert!((q - 9.0).abs() < 1e-9, "{q}");
        }
    }

    /// A track that diverges to 1e8 m: the view covers the valid part (the first
    /// three solutions and the truth), computed here by hand, not the 1e8 m.
    #[test]
    fn a_diverged_track_keeps_the_view_of_its_valid_part() {
        let solution = [
            (0.0, 0.0),
            (30.0, 40.0),
            (60.0, 20.0),
            (1e8, -1e8),
            (f64::NAN, 0.0),
        ];
        let elapsed = [0.0, 10.0, 20.0, 30.0, 40.0];
        let truth = [(-5.0, 0.0), (50.0, 45.0)];
        let view = track_view(&solution, &elapsed, &truth, &[]);
        assert_eq!(view.east, (-5.0, 60.0));
        assert_eq!(view.north, (0.0, 45.0));
        assert_eq!(view.diverged_solutions, 2);
        // Ellipses widen it by at most its larger side (65 m) on each side.
        let huge = ellipse((0.0, 0.0), [[1e10, 0.0], [0.0, 1e10]]);
        let view = track_view(&solution, &elapsed, &truth, &[huge]);
        assert_eq!(view.east, (-70.0, 125.0));
        assert_eq!(view.north, (-65.0, 110.0));
        assert_eq!(view.clipped_ellipses, 1);
        // Nothing plausible, nothing finite: a default view, never NaN.
        let view = track_view(&[(f64::INFINITY, 1.0)], &[0.0], &[], &[]);
        assert!(view.east.0.is_finite() && view.north.1.is_finite());
    }

    /// Clipping keeps the inside parts with their exact edge crossings, and splits a
    /// line that leaves and re-enters the frame.
    #[test]
    fn a_polyline_is_clipped_at_the_frame() {
        let line = [(-1.0, 0.5), (0.5, 0.5), (3.0, 0.5), (0.5, 0.8), (0.5, 0.2)];
        let pieces = clip_polyline(&line, (0.0, 1.0), (0.0, 1.0));
        // (3, 0.5) -> (0.5, 0.8) enters at x = 1, a fraction 2 / 2.5 along: y = 0.74.
        let expected = [
            vec![(0.0, 0.5), (0.5, 0.5), (1.0, 0.5)],
            vec![(1.0, 0.74), (0.5, 0.8), (0.5, 0.2)],
        ];
        assert_eq!(pieces.len(), expected.len());
        for (piece, want) in pieces.iter().zip(&expected) {
            assert_eq!(piece.len(), want.len());
            for (p, q) in piece.iter().zip(want) {
                assert!(
                    (p.0 - q.0).abs() < 1e-12 && (p.1 - q.1).abs() < 1e-12,
                    "{p:?} {q:?}"
                );
            }
        }
        assert!(clip_polyline(&[(2.0, 2.0), (3.0, 3.0)], (0.0, 1.0), (0.0, 1.0)).is_empty());
        assert!(clip_polyline(&[(0.5, 0.5), (f64::NAN, 0.5)], (0.0, 1.0), (0.0, 1.0)).is_empty());
    }

    /// A sharp turn splits the line; a gentle one does not.
    #[test]
    fn sharp_turns_split_the_line() {
        let gentle = vec![(0.0, 0.0), (1.0, 0.0), (2.0, 0.5)];
        assert_eq!(split_sharp_turns(gentle.clone()), vec![gentle]);
        let back = vec![(0.0, 0.0), (1.0, 0.0), (0.0, 0.1)];
        assert_eq!(
            split_sharp_turns(back),
            vec![vec![(0.0, 0.0), (1.0, 0.0)], vec![(1.0, 0.0), (0.0, 0.1)]]
        );
    }

    /// Every log range holds at least two powers of ten (the ticks plotters labels),
    /// including a range inside one decade (the gyroscope-bias panel had none).
    #[test]
    fn log_ranges_hold_two_powers_of_ten() {
        for (lo, hi) in [
            (2e-6, 8e-6),
            (1.0, 1.0),
            (3e-6, 4e-5),
            (0.9, 1.1),
            (1e-3, 1e5),
        ] {
            let (a, b) = crate::plots::log_axis_range(lo, hi);
            assert!(a <= lo && b >= hi, "{lo} {hi}: {a} {b}");
            let powers = (-320..320)
                .map(|k| 10f64.powi(k))
                .filter(|p| *p >= a && *p <= b)
                .count();
            assert!(powers >= 2, "{lo} {hi}: {a} {b}");
        }
        assert_eq!(log_tick_label(&2e-5), "2e-5");
        assert_eq!(log_tick_label(&1.0), "1e0");
        assert_eq!(log_tick_label(&3e-5), "");
    }

    #[test]
    fn nothing_to_draw_is_a_warning_with_no_plot_file() {
        let dir = tempfile::tempdir().expect("tempdir");
        let data = PlotData {
            command: "navigate",
            solution_label: "filter",
            rows: &[],
            nis_times: &[],
            nis: &[],
            truth: &[],
            stopped: None,
        };
        let block = write_plots_or_warn(dir.path(), &data);
        assert_eq!(block["written"], false);
        assert!(block["reason"]
            .as_str()
            .is_some_and(|r| r.contains("no solution")));
        assert_eq!(std::fs::read_dir(dir.path()).expect("list").count(), 0);
    }
}
