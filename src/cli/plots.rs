//! Plots (PNG and SVG) made with plotters. Only the binary depends on plotters.
//!
//! Conventions, the same in every figure:
//! - one fixed style per filter id ([`style`]): colour, dash pattern, marker, width;
//! - draw order by layer: thick solid lines first, thin dashed ones on top, so two
//!   variants that coincide (e.g. "M neglected" and "M from network") both stay
//!   visible;
//! - units on every axis label;
//! - a non-finite value (e.g. NEES where P was not positive definite) breaks the line
//!   ([`segments`]) instead of being bridged;
//! - the north-east track has equal metres per pixel on both axes.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

/// Marker drawn on a line at regular intervals (tells lines apart without colour).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Marker {
    /// No marker.
    None,
    /// Filled circle.
    Circle,
    /// Triangle.
    Triangle,
    /// Cross.
    Cross,
}

/// The fixed style of a filter (or of the truth) in every figure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Style {
    /// Colour.
    pub color: RGBColor,
    /// Stroke width \[px\].
    pub width: u32,
    /// Dash length and gap \[px\]; `None` for a solid line.
    pub dash: Option<(u32, u32)>,
    /// Marker.
    pub marker: Marker,
    /// Draw order: lower layers first (underneath).
    pub layer: u8,
}

const GREY_PALETTE: [RGBColor; 4] = [
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
    RGBColor(140, 86, 75),
];

/// The style of a filter id (`ls`, `beamsnet_m_rho`, ..., or `truth`). A function of
/// the id alone, so a filter looks the same in every figure; an unknown id gets a
/// thin dashed style chosen by a hash of the id.
pub fn style(id: &str) -> Style {
    let s = |color, width, dash, marker, layer| Style {
        color,
        width,
        dash,
        marker,
        layer,
    };
    match id {
        "truth" => s(BLACK, 2, None, Marker::None, 0),
        "ls" => s(RGBColor(31, 119, 180), 3, None, Marker::None, 1),
        // Thick and solid underneath; "M from network" often coincides with it and is
        // drawn thin and dashed on top.
        "beamsnet_m_neglected" => s(RGBColor(255, 127, 14), 5, None, Marker::None, 1),
        "beamsnet_m_rho" => s(RGBColor(214, 39, 40), 2, Some((3, 3)), Marker::Triangle, 2),
        "beamsnet_m_network" => s(RGBColor(44, 160, 44), 2, Some((10, 6)), Marker::Circle, 3),
        "oracle_m_neglected" => s(RGBColor(148, 103, 189), 5, None, Marker::None, 1),
        "oracle_m_true" => s(RGBColor(23, 190, 207), 2, Some((10, 6)), Marker::Circle, 3),
        "oracle_m_rho" => s(RGBColor(227, 119, 194), 2, Some((3, 3)), Marker::Cross, 2),
        // `estim smooth`: filtered in blue, smoothed in orange; 3-sigma dashed.
        "smooth_filtered" => s(RGBColor(31, 119, 180), 3, None, Marker::None, 1),
        "smooth_filtered_3sigma" => s(RGBColor(31, 119, 180), 1, Some((6, 3)), Marker::None, 2),
        "smooth_smoothed" => s(RGBColor(255, 127, 14), 2, None, Marker::None, 3),
        "smooth_smoothed_3sigma" => s(RGBColor(255, 127, 14), 1, Some((6, 3)), Marker::None, 4),
        other => {
            // FNV-1a: stable across runs and platforms.
            let h = other.bytes().fold(0xcbf2_9ce4_8422_2325_u64, |h, b| {
                (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
            });
            s(
                GREY_PALETTE[(h % GREY_PALETTE.len() as u64) as usize],
                1,
                Some((6, 3)),
                Marker::None,
                4,
            )
        }
    }
}

/// One line of a line chart, styled by its filter id.
pub struct Series<'a> {
    /// Filter id (selects the style).
    pub id: &'a str,
    /// Legend text.
    pub label: &'a str,
    /// Abscissae.
    pub x: &'a [f64],
    /// Ordinates (non-finite = undefined: the line breaks there).
    pub y: &'a [f64],
}

/// A line chart: several series, optional horizontal reference lines (e.g. a NEES
/// band), optional +-bound envelopes.
pub struct LineChart<'a> {
    /// Title.
    pub title: &'a str,
    /// X axis label, with its unit.
    pub x_label: &'a str,
    /// Y axis label, with its unit.
    pub y_label: &'a str,
    /// Lines.
    pub series: Vec<Series<'a>>,
    /// Horizontal reference lines (label, value), drawn thin, dashed, grey.
    pub hlines: Vec<(&'a str, f64)>,
    /// Logarithmic y axis.
    pub log_y: bool,
    /// Equal scales on both axes (maps).
    pub equal_axes: bool,
}

/// The axes as drawn: ranges and the plotting area in pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Geometry {
    /// X range.
    pub x: (f64, f64),
    /// Y range.
    pub y: (f64, f64),
    /// Plotting area (width, height) \[px\].
    pub pixels: (u32, u32),
}

type DrawResult<T = ()> = Result<T, Box<dyn std::error::Error>>;

const SIZE: (u32, u32) = (960, 640);
const MARGIN: u32 = 12;
const TITLE_HEIGHT: u32 = 40;
const X_LABEL_AREA: u32 = 45;
const Y_LABEL_AREA: u32 = 90;

/// The maximal runs of consecutive points where both coordinates are finite (and y
/// positive on a log axis): a value that is undefined breaks the line there.
pub fn segments(x: &[f64], y: &[f64], log_y: bool) -> Vec<Vec<(f64, f64)>> {
    let mut out = Vec::new();
    let mut current = Vec::new();
    for (&a, &b) in x.iter().zip(y) {
        if a.is_finite() && b.is_finite() && (!log_y || b > 0.0) {
            current.push((a, b));
        } else if !current.is_empty() {
            out.push(std::mem::take(&mut current));
        }
    }
    if !current.is_empty() {
        out.push(current);
    }
    out
}

/// Write `stem.png` and `stem.svg` for a line chart; returns the geometry drawn.
pub fn line_chart(stem: &Path, chart: &LineChart<'_>) -> DrawResult<Geometry> {
    let png = stem.with_extension("png");
    let svg = stem.with_extension("svg");
    draw_line(BitMapBackend::new(&png, SIZE).into_drawing_area(), chart)?;
    draw_line(SVGBackend::new(&svg, SIZE).into_drawing_area(), chart)
}

fn finite_range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    if hi - lo < 1e-12 * hi.abs().max(1e-12) {
        let pad = hi.abs().max(1e-9) * 0.1;
        return (lo - pad, hi + pad);
    }
    (lo, hi)
}

/// Ranges centred on the data with the same units per pixel on both axes, for a
/// plotting area of `pixels`, covering the data with a 5 % margin.
pub fn equal_scale_ranges(
    x: (f64, f64),
    y: (f64, f64),
    pixels: (u32, u32),
) -> ((f64, f64), (f64, f64)) {
    let (w, h) = (f64::from(pixels.0.max(1)), f64::from(pixels.1.max(1)));
    let per_pixel = ((x.1 - x.0) / w).max((y.1 - y.0) / h) * 1.05;
    let (cx, cy) = (0.5 * (x.0 + x.1), 0.5 * (y.0 + y.1));
    (
        (cx - 0.5 * per_pixel * w, cx + 0.5 * per_pixel * w),
        (cy - 0.5 * per_pixel * h, cy + 0.5 * per_pixel * h),
    )
}

fn shape(style: &Style) -> ShapeStyle {
    style.color.stroke_width(style.width)
}

fn draw_line<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    c: &LineChart<'_>,
) -> DrawResult<Geometry>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let (title_area, body) = root.split_vertically(TITLE_HEIGHT);
    title_area.titled(c.title, ("sans-serif", 22))?;
    let (bw, bh) = body.dim_in_pixel();
    // The plotting area left by the margins and the label areas (checked against the
    // chart actually built, see the tests).
    let pixels = (
        bw.saturating_sub(2 * MARGIN + Y_LABEL_AREA),
        bh.saturating_sub(2 * MARGIN + X_LABEL_AREA),
    );
    let (mut x0, mut x1) = finite_range(c.series.iter().flat_map(|s| s.x.iter().copied()));
    let (mut y0, mut y1) = finite_range(
        c.series
            .iter()
            .flat_map(|s| s.y.iter().copied())
            .chain(c.hlines.iter().map(|h| h.1))
            .filter(|v| !c.log_y || *v > 0.0),
    );
    if c.equal_axes {
        ((x0, x1), (y0, y1)) = equal_scale_ranges((x0, x1), (y0, y1), pixels);
    } else if !c.log_y {
        let pad = 0.05 * (y1 - y0);
        (y0, y1) = (y0 - pad, y1 + pad);
    }
    let mut builder = ChartBuilder::on(&body);
    builder
        .margin(MARGIN)
        .x_label_area_size(X_LABEL_AREA)
        .y_label_area_size(Y_LABEL_AREA);
    // Lower layers first; a stable sort keeps the caller's order within a layer.
    let mut order: Vec<&Series<'_>> = c.series.iter().collect();
    order.sort_by_key(|s| style(s.id).layer);
    macro_rules! body {
        ($chart:expr) => {{
            let mut chart = $chart;
            chart
                .configure_mesh()
                .x_desc(c.x_label)
                .y_desc(c.y_label)
                .draw()?;
            for (name, value) in &c.hlines {
                let v = *value;
                let st = ShapeStyle {
                    color: BLACK.mix(0.6),
                    filled: false,
                    stroke_width: 1,
                };
                chart
                    .draw_series(DashedLineSeries::new([(x0, v), (x1, v)], 4, 4, st))?
                    .label(*name)
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], st));
            }
            for s in &order {
                let st = style(s.id);
                let segs = segments(s.x, s.y, c.log_y);
                for (i, seg) in segs.iter().enumerate() {
                    let drawn = match st.dash {
                        Some((dash, gap)) => chart.draw_series(DashedLineSeries::new(
                            seg.iter().copied(),
                            dash,
                            gap,
                            shape(&st),
                        ))?,
                        None => {
                            chart.draw_series(LineSeries::new(seg.iter().copied(), shape(&st)))?
                        }
                    };
                    if i == 0 {
                        drawn.label(s.label).legend(move |(x, y)| {
                            PathElement::new(vec![(x, y), (x + 24, y)], shape(&st))
                        });
                    }
                    let step = (seg.len() / 12).max(1);
                    let marks = seg.iter().copied().step_by(step);
                    let color = st.color;
                    match st.marker {
                        Marker::None => {}
                        Marker::Circle => {
                            chart.draw_series(marks.map(|p| Circle::new(p, 4, color.filled())))?;
                        }
                        Marker::Triangle => {
                            chart.draw_series(
                                marks.map(|p| TriangleMarker::new(p, 5, color.filled())),
                            )?;
                        }
                        Marker::Cross => {
                            chart.draw_series(
                                marks.map(|p| Cross::new(p, 4, color.stroke_width(2))),
                            )?;
                        }
                    }
                }
            }
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .draw()?;
            let (xr, yr) = (chart.x_range(), chart.y_range());
            Geometry {
                x: (xr.start, xr.end),
                y: (yr.start, yr.end),
                pixels: chart.plotting_area().dim_in_pixel(),
            }
        }};
    }
    let geometry = if c.log_y {
        body!(builder.build_cartesian_2d(x0..x1, (y0.max(1e-300) * 0.9..y1 * 1.1).log_scale())?)
    } else {
        body!(builder.build_cartesian_2d(x0..x1, y0..y1)?)
    };
    root.present()?;
    Ok(geometry)
}

/// One panel of an error plot: the error of one axis against truth and its
/// +-3 sigma bound from the filter's covariance.
pub struct ErrorPanel<'a> {
    /// Axis label with unit (e.g. "north error \[m\]").
    pub y_label: &'a str,
    /// Error per epoch.
    pub error: Vec<f64>,
    /// 3 sigma per epoch.
    pub three_sigma: Vec<f64>,
}

/// Per-axis error plot of one filter: one panel per axis, the error (filter style)
/// and the +-3 sigma envelope (same colour, thin, dashed). Writes PNG and SVG.
pub fn error_chart(
    stem: &Path,
    title: &str,
    id: &str,
    time: &[f64],
    panels: &[ErrorPanel<'_>],
) -> DrawResult {
    let png = stem.with_extension("png");
    let svg = stem.with_extension("svg");
    let size = (960, 260 * panels.len().max(1) as u32 + TITLE_HEIGHT);
    draw_errors(
        BitMapBackend::new(&png, size).into_drawing_area(),
        title,
        id,
        time,
        panels,
    )?;
    draw_errors(
        SVGBackend::new(&svg, size).into_drawing_area(),
        title,
        id,
        time,
        panels,
    )
}

fn draw_errors<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    title: &str,
    id: &str,
    time: &[f64],
    panels: &[ErrorPanel<'_>],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let (title_area, body) = root.split_vertically(TITLE_HEIGHT);
    title_area.titled(title, ("sans-serif", 22))?;
    let st = style(id);
    let (x0, x1) = finite_range(time.iter().copied());
    for (area, p) in body
        .split_evenly((panels.len().max(1), 1))
        .iter()
        .zip(panels)
    {
        let (lo, hi) = finite_range(
            p.error
                .iter()
                .copied()
                .chain(p.three_sigma.iter().flat_map(|s| [*s, -*s])),
        );
        let pad = 0.05 * (hi - lo);
        let mut chart = ChartBuilder::on(area)
            .margin(MARGIN)
            .x_label_area_size(X_LABEL_AREA)
            .y_label_area_size(Y_LABEL_AREA)
            .build_cartesian_2d(x0..x1, (lo - pad)..(hi + pad))?;
        chart
            .configure_mesh()
            .x_desc("time [s]")
            .y_desc(p.y_label)
            .draw()?;
        let bound_style = ShapeStyle {
            color: st.color.mix(0.8),
            filled: false,
            stroke_width: 1,
        };
        for sign in [1.0, -1.0] {
            let bound: Vec<f64> = p.three_sigma.iter().map(|s| sign * s).collect();
            for (i, seg) in segments(time, &bound, false).into_iter().enumerate() {
                let drawn = chart.draw_series(DashedLineSeries::new(seg, 6, 4, bound_style))?;
                if i == 0 && sign > 0.0 {
                    drawn.label("+-3 sigma").legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 24, y)], bound_style)
                    });
                }
            }
        }
        for (i, seg) in segments(time, &p.error, false).into_iter().enumerate() {
            let drawn = chart.draw_series(LineSeries::new(seg, st.color.stroke_width(2)))?;
            if i == 0 {
                drawn.label("error vs truth").legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 24, y)], st.color.stroke_width(2))
                });
            }
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()?;
    }
    root.present()?;
    Ok(())
}

/// Grouped bar chart: for each group (x), one bar per variant (styled by filter id);
/// values in percent.
pub struct BarChart<'a> {
    /// Title.
    pub title: &'a str,
    /// Y axis label with unit.
    pub y_label: &'a str,
    /// Groups along x.
    pub groups: &'a [&'a str],
    /// (filter id, legend label) per variant.
    pub variants: &'a [(&'a str, &'a str)],
    /// `values[variant][group]`.
    pub values: &'a [Vec<f64>],
}

/// Write `stem.png` and `stem.svg` for a grouped bar chart.
pub fn bar_chart(stem: &Path, c: &BarChart<'_>) -> DrawResult {
    let png = stem.with_extension("png");
    let svg = stem.with_extension("svg");
    draw_bars(BitMapBackend::new(&png, SIZE).into_drawing_area(), c)?;
    draw_bars(SVGBackend::new(&svg, SIZE).into_drawing_area(), c)?;
    Ok(())
}

fn draw_bars<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, c: &BarChart<'_>) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let (lo, hi) = finite_range(c.values.iter().flatten().copied().chain([0.0]));
    let pad = 0.1 * (hi - lo).max(1.0);
    let n = c.groups.len() as f64;
    let mut chart = ChartBuilder::on(&root)
        .caption(c.title, ("sans-serif", 22))
        .margin(MARGIN)
        .x_label_area_size(X_LABEL_AREA)
        .y_label_area_size(Y_LABEL_AREA)
        .build_cartesian_2d(0.0..n, (lo - pad)..(hi + pad))?;
    let labels: Vec<String> = c.groups.iter().map(|g| g.to_string()).collect();
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(c.groups.len() * 2 + 1)
        .x_label_formatter(&|x| {
            let i = x.floor() as usize;
            if (x - x.floor() - 0.5).abs() < 1e-6 && i < labels.len() {
                labels[i].clone()
            } else {
                String::new()
            }
        })
        .x_desc("state group")
        .y_desc(c.y_label)
        .draw()?;
    let width = 0.8 / c.variants.len().max(1) as f64;
    for (v, (id, label)) in c.variants.iter().enumerate() {
        let color = style(id).color;
        let bars = c
            .values
            .get(v)
            .into_iter()
            .flatten()
            .enumerate()
            .filter(|(_, y)| y.is_finite())
            .map(|(g, y)| {
                let x = g as f64 + 0.1 + v as f64 * width;
                Rectangle::new([(x, 0.0), (x + width, *y)], color.filled())
            });
        chart
            .draw_series(bars)?
            .label(*label)
            .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 15, y + 5)], color.filled()));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    root.present()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn style_is_a_function_of_the_id_only() {
        let ids = [
            "truth",
            "ls",
            "beamsnet_m_neglected",
            "beamsnet_m_rho",
            "beamsnet_m_network",
            "oracle_m_neglected",
            "oracle_m_true",
            "oracle_m_rho",
        ];
        // Same id, same style, whatever was asked before (no state, no palette index).
        let first: Vec<Style> = ids.iter().map(|id| style(id)).collect();
        let reversed: Vec<Style> = ids.iter().rev().map(|id| style(id)).collect();
        for (a, b) in first.iter().zip(reversed.iter().rev()) {
            assert_eq!(a, b);
        }
        assert_eq!(style("my_sensor"), style(&String::from("my_sensor")));
        // Known filters are pairwise distinguishable by colour, dash or marker.
        for (i, a) in first.iter().enumerate() {
            for b in &first[i + 1..] {
                assert!(
                    a.color != b.color || a.dash != b.dash || a.marker != b.marker,
                    "{a:?} vs {b:?}"
                );
            }
        }
        // The variant that often coincides with "M neglected" is drawn on top of it,
        // thinner and dashed, so both stay visible.
        let (under, over) = (style("beamsnet_m_neglected"), style("beamsnet_m_network"));
        assert!(over.layer > under.layer && over.width < under.width && over.dash.is_some());
    }

    #[test]
    fn nan_splits_a_series_into_segments() {
        let x = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0];
        let y = [1.0, f64::NAN, 2.0, 3.0, f64::INFINITY, f64::NAN, 4.0];
        let s = segments(&x, &y, false);
        assert_eq!(
            s,
            vec![
                vec![(0.0, 1.0)],
                vec![(2.0, 2.0), (3.0, 3.0)],
                vec![(6.0, 4.0)]
            ]
        );
        // Log axis: a non-positive value is undefined as well.
        let s = segments(&x[..3], &[1.0, 0.0, 2.0], true);
        assert_eq!(s, vec![vec![(0.0, 1.0)], vec![(2.0, 2.0)]]);
        assert!(segments(&x[..2], &[f64::NAN, f64::NAN], false).is_empty());
    }

    #[test]
    fn track_plot_has_equal_metres_per_pixel() {
        let dir = tempfile::tempdir().expect("tempdir");
        // A track much longer east than north, and one much longer north.
        for (east, north) in [
            (vec![0.0, 500.0, 1000.0], vec![0.0, 20.0, 10.0]),
            (vec![0.0, 3.0, -2.0], vec![0.0, 400.0, 800.0]),
        ] {
            let chart = LineChart {
                title: "track",
                x_label: "east [m]",
                y_label: "north [m]",
                series: vec![Series {
                    id: "truth",
                    label: "truth",
                    x: &east,
                    y: &north,
                }],
                hlines: vec![],
                log_y: false,
                equal_axes: true,
            };
            let g = line_chart(&dir.path().join("track"), &chart).expect("drawn");
            let mx = (g.x.1 - g.x.0) / f64::from(g.pixels.0);
            let my = (g.y.1 - g.y.0) / f64::from(g.pixels.1);
            assert!(
                (mx / my - 1.0).abs() < 1e-9,
                "metres per pixel: x {mx}, y {my} ({g:?})"
            );
            // The data is inside the ranges.
            assert!(east.iter().all(|e| *e >= g.x.0 && *e <= g.x.1));
            assert!(north.iter().all(|n| *n >= g.y.0 && *n <= g.y.1));
        }
    }
}
