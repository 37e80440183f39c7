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

use std::path::Path;

use estim::ins::{earth, ErrorMatrix, POS};
use estim::navigator::{NavSolution, SolutionKind};
use plotters::coord::Shift;
use plotters::prelude::*;

const SIZE: (u32, u32) = (960, 720);
const SIGMA_SIZE: (u32, u32) = (960, 1200);
/// Ellipses drawn on the track at most (evenly spaced DVL epochs, and the last).
const MAX_ELLIPSES: usize = 40;
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

/// North, east \[m\] of a row from the first row's position (local tangent plane).
fn north_east(rows: &[PlotRow], row: &PlotRow) -> (f64, f64) {
    let [lat0, lon0] = rows[0].position_deg;
    let (rn, re) = earth::radii_of_curvature(lat0.to_radians());
    (
        (row.position_deg[0] - lat0).to_radians() * rn,
        (row.position_deg[1] - lon0).to_radians() * re * lat0.to_radians().cos(),
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
            let (n, e) = north_east(rows, r);
            (e, n)
        })
        .collect();
    let dvl: Vec<usize> = (0..rows.len())
        .filter(|&k| rows[k].kind == SolutionKind::Dvl)
        .collect();
    let step = dvl.len().div_ceil(MAX_ELLIPSES).max(1);
    let mut chosen: Vec<usize> = dvl.iter().copied().step_by(step).collect();
    chosen.push(rows.len() - 1);
    let ellipses: Vec<Vec<(f64, f64)>> = chosen
        .iter()
        .map(|&k| ellipse((points[k].1, points[k].0), rows[k].north_east))
        .collect();
    let all = points.iter().chain(ellipses.iter().flatten());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in all.filter(|p| p.0.is_finite() && p.1.is_finite()) {
        (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
    }
    if x0 > x1 {
        (x0, x1, y0, y1) = (-1.0, 1.0, -1.0, 1.0);
    }
    let pad = 1e-3_f64.max(0.0);
    let (w, h) = root.dim_in_pixel();
    let ((x0, x1), (y0, y1)) = crate::plots::equal_scale_ranges(
        (x0 - pad, x1 + pad),
        (y0 - pad, y1 + pad),
        (w.saturating_sub(110), h.saturating_sub(110)),
    );
    let mut chart = ChartBuilder::on(root)
        .caption(
            format!(
                "estim {}: track ({} solution), 3-sigma position ellipses (98.9 %)",
                data.command, data.solution_label
            ),
            ("sans-serif", 20),
        )
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
    let line = AXIS_COLORS[0].stroke_width(2);
    for (i, range) in segments.iter().enumerate() {
        let series = chart
            .draw_series(LineSeries::new(points[range.clone()].iter().copied(), line))
            .map_err(err)?;
        if i == 0 {
            series
                .label("solution (a break = no solution in between)")
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], line));
        }
    }
    let ring = RGBColor(214, 39, 40).stroke_width(1);
    for (i, e) in ellipses.into_iter().enumerate() {
        let series = chart
            .draw_series(std::iter::once(PathElement::new(e, ring)))
            .map_err(err)?;
        if i == 0 {
            series
                .label("3-sigma position ellipse (DVL epochs)")
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], ring));
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
                "estim {}: 1-sigma per state group ({} solution; sqrt of the diagonal of P)",
                data.command, data.solution_label
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
            (lo / 1.5, hi * 1.5)
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
            .y_label_formatter(&|v| format!("{v:.1e}"))
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
                "estim {}: DVL NIS per epoch (not averaged; forward filter), {} of {} inside the {:.0} % chi-square(3) band",
                data.command,
                inside,
                points.len(),
                100.0 * NIS_BAND_PROBABILITY
            ),
            ("sans-serif", 17),
        )
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..x1, ((lo / 2.0)..(hi * 2.0)).log_scale())
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("time since the first solution [s]")
        .y_desc("NIS of the DVL update (3 dof)")
        .y_label_formatter(&|v| format!("{v:.1e}"))
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

    #[test]
    fn nothing_to_draw_is_a_warning_with_no_plot_file() {
        let dir = tempfile::tempdir().expect("tempdir");
        let data = PlotData {
            command: "navigate",
            solution_label: "filter",
            rows: &[],
            nis_times: &[],
            nis: &[],
        };
        let block = write_plots_or_warn(dir.path(), &data);
        assert_eq!(block["written"], false);
        assert!(block["reason"]
            .as_str()
            .is_some_and(|r| r.contains("no solution")));
        assert_eq!(std::fs::read_dir(dir.path()).expect("list").count(), 0);
    }
}
