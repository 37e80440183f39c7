//! Plots (PNG and SVG) made with plotters. Only the binary depends on plotters.
//!
//! Conventions, the same in every figure:
//! - one fixed style per filter id ([`style`]): colour, dash pattern, marker, width;
//! - draw order by layer: thick solid lines first, thin dashed ones on top, so two
//!   variants that coincide (e.g. "M neglected" and "M from network") both stay
//!   visible;
//! - units on every axis label, in a unit that keeps the tick labels readable
//!   ([`plot_unit`]: gyroscope biases in deg/h, accelerometer biases in mg or µg,
//!   misalignment in deg) and tick labels with as many decimals as their spacing needs
//!   ([`tick_label`]);
//! - a bar computed from a covariance that was not positive definite is hatched and
//!   labelled "not PD", never drawn as an ordinary bar;
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

/// Standard gravity \[m/s^2\] (1 mg = 1e-3 of it), the unit accelerometer biases are
/// quoted in.
pub const STANDARD_GRAVITY: f64 = 9.80665;

/// The unit a state group's standard deviation is plotted in and the factor from the
/// SI value to it: position m, velocity m/s, misalignment deg, gyroscope bias
/// deg/h, accelerometer bias mg, or µg when every value is below 1 mg (`values`: the
/// SI values to be plotted). An unknown group stays in its SI value with unit "?".
pub fn plot_unit(group: &str, values: impl IntoIterator<Item = f64>) -> (&'static str, f64) {
    match group {
        "position" => ("m", 1.0),
        "velocity" => ("m/s", 1.0),
        "misalignment" => ("deg", 180.0 / std::f64::consts::PI),
        "gyro_bias" => ("deg/h", 180.0 / std::f64::consts::PI * 3600.0),
        "acc_bias" => {
            let mg = 1.0 / (1e-3 * STANDARD_GRAVITY);
            let largest = values
                .into_iter()
                .filter(|v| v.is_finite())
                .fold(0.0_f64, |m, v| m.max(v.abs()));
            if largest * mg >= 1.0 {
                ("mg", mg)
            } else {
                ("µg", 1e3 * mg)
            }
        }
        _ => ("?", 1.0),
    }
}

/// A tick label of `value` on an axis spanning `span`: enough decimals that ticks a
/// tenth of the span apart differ (plotters' default prints every tick of a 1e-5-wide
/// axis as the same number).
pub fn tick_label(value: f64, span: f64) -> String {
    let step = (span.abs() / 10.0).max(f64::MIN_POSITIVE);
    let decimals = (1.0 - step.log10().floor()).clamp(0.0, 15.0) as usize;
    let text = format!("{value:.decimals$}");
    // "-0.00" reads as a different tick from "0.00".
    if text.starts_with('-') && text[1..].chars().all(|c| c == '0' || c == '.') {
        text[1..].to_string()
    } else {
        text
    }
}

/// A log axis's range covering `[lo, hi]` (both > 0) from a power of ten to a power of
/// ten, at least one decade, widened by 1 % so that rounding in plotters' logarithms
/// keeps both ends: plotters labels a log axis at the powers of ten inside it (and
/// between them), so a range inside one decade got no tick label at all.
pub fn log_axis_range(lo: f64, hi: f64) -> (f64, f64) {
    let lo = lo.max(1e-300);
    let hi = hi.max(lo);
    let bottom = 10f64.powf(lo.log10().floor());
    let mut top = 10f64.powf(hi.log10().ceil());
    if top <= bottom * 1.5 {
        top = bottom * 10.0;
    }
    (bottom * 0.99, top * 1.01)
}

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
    line_chart_captioned(stem, chart, "")
}

/// [`line_chart`] with a caption under the title (one line per `\n`) saying how to
/// read the figure, e.g. what a reference band refers to.
pub fn line_chart_captioned(
    stem: &Path,
    chart: &LineChart<'_>,
    caption: &str,
) -> DrawResult<Geometry> {
    let png = stem.with_extension("png");
    let svg = stem.with_extension("svg");
    draw_line(
        BitMapBackend::new(&png, SIZE).into_drawing_area(),
        chart,
        caption,
    )?;
    draw_line(
        SVGBackend::new(&svg, SIZE).into_drawing_area(),
        chart,
        caption,
    )
}

/// Caption of a NEES-over-time figure: the band drawn is per epoch (`per_epoch`, that
/// of one chi-square(15) draw), while the band printed next to the average NEES is that
/// of its time average over `epochs` epochs (`time_average`), much narrower.
pub fn nees_band_caption(per_epoch: [f64; 2], epochs: usize, time_average: [f64; 2]) -> String {
    format!(
        "Dashed: 95% band of chi-square(15) at one epoch ({:.2}-{:.2}), for the NEES drawn per epoch.\n\
         The band printed with the average NEES (text, JSON) is that of its time average over \
         {epochs} epochs ({:.2}-{:.2}).",
        per_epoch[0], per_epoch[1], time_average[0], time_average[1]
    )
}

/// Height of one caption line \[px\].
const CAPTION_LINE: u32 = 18;

/// Title, then the caption lines under it, in `area`; returns the area left below.
fn title_and_caption<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    title: &str,
    caption: &str,
) -> DrawResult<DrawingArea<DB, Shift>>
where
    DB::ErrorType: 'static,
{
    let lines: Vec<&str> = caption.lines().filter(|l| !l.is_empty()).collect();
    let (title_area, body) =
        root.split_vertically(TITLE_HEIGHT + CAPTION_LINE * lines.len() as u32);
    let (top, captions) = title_area.split_vertically(TITLE_HEIGHT);
    top.titled(title, ("sans-serif", 22))?;
    for (i, line) in lines.iter().enumerate() {
        captions.draw(&Text::new(
            line.to_string(),
            (MARGIN as i32, (i as u32 * CAPTION_LINE) as i32),
            ("sans-serif", 15),
        ))?;
    }
    Ok(body)
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

/// The axes' ranges of a line chart over `pixels` of plotting area: every finite
/// value (positive ones on a log axis) and the horizontal lines; equal metres per
/// pixel when asked, else 5 % padding on a linear y axis.
fn line_ranges(c: &LineChart<'_>, pixels: (u32, u32)) -> ((f64, f64), (f64, f64)) {
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
    ((x0, x1), (y0, y1))
}

fn draw_line<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    c: &LineChart<'_>,
    caption: &str,
) -> DrawResult<Geometry>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let body = title_and_caption(&root, c.title, caption)?;
    let (bw, bh) = body.dim_in_pixel();
    // The plotting area left by the margins and the label areas (checked against the
    // chart actually built, see the tests).
    let pixels = (
        bw.saturating_sub(2 * MARGIN + Y_LABEL_AREA),
        bh.saturating_sub(2 * MARGIN + X_LABEL_AREA),
    );
    let ((x0, x1), (y0, y1)) = line_ranges(c, pixels);
    let mut builder = ChartBuilder::on(&body);
    builder
        .margin(MARGIN)
        .x_label_area_size(X_LABEL_AREA)
        .y_label_area_size(Y_LABEL_AREA);
    // Lower layers first; a stable sort keeps the caller's order within a layer.
    let mut order: Vec<&Series<'_>> = c.series.iter().collect();
    order.sort_by_key(|s| style(s.id).layer);
    let (x_span, y_span) = (x1 - x0, y1 - y0);
    macro_rules! body {
        ($chart:expr, $y_ticks:expr) => {{
            let mut chart = $chart;
            chart
                .configure_mesh()
                .x_desc(c.x_label)
                .y_desc(c.y_label)
                .x_label_formatter(&|x| tick_label(*x, x_span))
                .y_label_formatter($y_ticks)
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
        // A log axis: each tick its own magnitude.
        body!(
            builder.build_cartesian_2d(x0..x1, {
                let (lo, hi) = log_axis_range(y0, y1);
                (lo..hi).log_scale()
            })?,
            &|y: &f64| tick_label(*y, *y)
        )
    } else {
        body!(builder.build_cartesian_2d(x0..x1, y0..y1)?, &|y: &f64| {
            tick_label(*y, y_span)
        })
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
        let span = (hi - lo) * 1.1;
        chart
            .configure_mesh()
            .x_desc("time [s]")
            .y_desc(p.y_label)
            .x_label_formatter(&|x| tick_label(*x, x1 - x0))
            .y_label_formatter(&|y| tick_label(*y, span))
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
    /// `positive_definite[variant][group]`: whether the value was computed from
    /// covariances that were positive definite throughout (the caller's statistics);
    /// a missing entry counts as `true`.
    /// A `false` bar is drawn hatched and labelled "not PD".
    pub positive_definite: &'a [Vec<bool>],
}

/// Legend text of the hatched bars.
pub const NOT_PD_LEGEND: &str = "hatched (not PD): from a covariance not positive definite";

impl BarChart<'_> {
    /// Whether bar (`variant`, `group`) comes from positive definite covariances.
    pub fn is_positive_definite(&self, variant: usize, group: usize) -> bool {
        self.positive_definite
            .get(variant)
            .and_then(|v| v.get(group))
            .copied()
            .unwrap_or(true)
    }
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
        .y_label_formatter(&|y| tick_label(*y, hi - lo + 2.0 * pad))
        .draw()?;
    let width = 0.8 / c.variants.len().max(1) as f64;
    let span = hi - lo + 2.0 * pad;
    let mut any_not_pd = false;
    for (v, (id, label)) in c.variants.iter().enumerate() {
        let color = style(id).color;
        let bars: Vec<(f64, f64, bool)> = c
            .values
            .get(v)
            .into_iter()
            .flatten()
            .enumerate()
            .filter(|(_, y)| y.is_finite())
            .map(|(g, y)| {
                (
                    g as f64 + 0.1 + v as f64 * width,
                    *y,
                    c.is_positive_definite(v, g),
                )
            })
            .collect();
        chart
            .draw_series(
                bars.iter()
                    .filter(|b| b.2)
                    .map(|&(x, y, _)| Rectangle::new([(x, 0.0), (x + width, y)], color.filled())),
            )?
            .label(*label)
            .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 15, y + 5)], color.filled()));
        // Not PD: outline, slanted hatching and a label, never a filled bar.
        for &(x, y, _) in bars.iter().filter(|b| !b.2) {
            any_not_pd = true;
            chart.draw_series(std::iter::once(Rectangle::new(
                [(x, 0.0), (x + width, y)],
                color.stroke_width(2),
            )))?;
            const HATCHES: usize = 6;
            let step = width / HATCHES as f64;
            chart.draw_series((0..HATCHES).map(|i| {
                let left = x + i as f64 * step;
                PathElement::new(vec![(left, 0.0), (left + step, y)], color.stroke_width(1))
            }))?;
            let above = if y >= 0.0 {
                y + 0.02 * span
            } else {
                y - 0.06 * span
            };
            chart.draw_series(std::iter::once(Text::new(
                "not PD",
                (x, above),
                ("sans-serif", 13),
            )))?;
        }
    }
    if any_not_pd {
        chart
            .draw_series(std::iter::empty::<Rectangle<(f64, f64)>>())?
            .label(NOT_PD_LEGEND)
            .legend(|(x, y)| Rectangle::new([(x, y - 5), (x + 15, y + 5)], BLACK.stroke_width(1)));
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
    fn bias_units_read_and_ticks_differ() {
        // 1 deg/h is pi / 180 / 3600 rad/s (independent of the factor in plot_unit).
        let (unit, scale) = plot_unit("gyro_bias", [1e-5]);
        assert_eq!(unit, "deg/h");
        let one_deg_per_hour = 1.0_f64.to_radians() / 3600.0;
        assert!((one_deg_per_hour * scale - 1.0).abs() < 1e-15);
        // A typical std sum of 1e-5 rad/s is 2.06 deg/h.
        assert!((1e-5 * scale - 2.062_648_062_470_963_5).abs() < 1e-12);
        // Accelerometer: mg when some value reaches 1 mg, else µg.
        let (unit, scale) = plot_unit("acc_bias", [2e-2, f64::NAN, 5e-4]);
        assert_eq!(unit, "mg");
        assert!((9.80665e-3 * scale - 1.0).abs() < 1e-15);
        let (unit, scale) = plot_unit("acc_bias", [5e-3, 1e-4]);
        assert_eq!(unit, "µg");
        assert!((9.80665e-6 * scale - 1.0).abs() < 1e-15);
        assert_eq!(
            plot_unit("misalignment", []),
            ("deg", 180.0 / std::f64::consts::PI)
        );
        // Ticks a tenth of the span apart print differently, at every magnitude.
        for (lo, span) in [(1.0e-5, 1e-6), (0.0, 3e-9), (2.0, 0.5), (100.0, 2000.0)] {
            let labels: Vec<String> = (0..=10)
                .map(|k| tick_label(lo + span * f64::from(k) / 10.0, span))
                .collect();
            for w in labels.windows(2) {
                assert_ne!(w[0], w[1], "span {span}: {labels:?}");
            }
        }
        assert_eq!(tick_label(1.25e-5, 1e-5), "0.0000125");
        assert_eq!(tick_label(-1e-20, 1.0), "0.00");
        assert_eq!(tick_label(1500.0, 2000.0), "1500");
    }

    /// Count of `needle` in `hay`.
    fn count(hay: &str, needle: &str) -> usize {
        hay.matches(needle).count()
    }

    #[test]
    fn bars_from_a_covariance_not_pd_are_hatched_not_filled() {
        let dir = tempfile::tempdir().expect("tempdir");
        let groups = ["velocity", "misalignment"];
        let variants = [
            ("beamsnet_m_rho", "M = rho"),
            ("beamsnet_m_network", "network"),
        ];
        let values = vec![vec![10.0, -5.0], vec![2.0, 3.0]];
        let draw = |name: &str, positive_definite: &[Vec<bool>]| {
            let stem = dir.path().join(name);
            bar_chart(
                &stem,
                &BarChart {
                    title: "improvement",
                    y_label: "improvement [%]",
                    groups: &groups,
                    variants: &variants,
                    values: &values,
                    positive_definite,
                },
            )
            .expect("drawn");
            std::fs::read_to_string(stem.with_extension("svg")).expect("svg")
        };
        let all = draw("all", &[]);
        let one = draw("one", &[vec![true, false], vec![true, true]]);
        // The filled rectangles of M = rho's colour (214, 39, 40): two bars plus the
        // legend swatch; with one bar not PD, that bar is no longer filled.
        let fill = "fill=\"#D62728\"";
        assert_eq!(count(&all, fill), 3, "{all}");
        assert_eq!(count(&one, fill), 2);
        // ... it is an outline with 6 hatching lines, labelled, and the legend says so.
        assert_eq!(count(&all, "not PD"), 0);
        assert_eq!(
            count(&one, ">not PD<") + count(&one, ">\nnot PD\n<"),
            1,
            "{one}"
        );
        assert!(one.contains(NOT_PD_LEGEND));
        assert!(!all.contains(NOT_PD_LEGEND));
        assert_eq!(
            count(&one, "stroke=\"#D62728\"") - count(&all, "stroke=\"#D62728\""),
            7
        );
    }

    #[test]
    fn nees_plot_says_its_band_is_per_epoch() {
        let dir = tempfile::tempdir().expect("tempdir");
        let caption = nees_band_caption([7.26, 27.49], 400, [14.73, 15.28]);
        assert!(caption.contains("at one epoch (7.26-27.49)"), "{caption}");
        assert!(caption.contains("time average over 400 epochs (14.73-15.28)"));
        let (t, nees) = ([0.0, 1.0, 2.0], [10.0, 20.0, 15.0]);
        let chart = LineChart {
            title: "NEES",
            x_label: "time [s]",
            y_label: "NEES [-]",
            series: vec![Series {
                id: "ls",
                label: "LS",
                x: &t,
                y: &nees,
            }],
            hlines: vec![("95% per-epoch band, lower", 7.26)],
            log_y: true,
            equal_axes: false,
        };
        let stem = dir.path().join("nees");
        line_chart_captioned(&stem, &chart, &caption).expect("drawn");
        let svg = std::fs::read_to_string(stem.with_extension("svg")).expect("svg");
        for line in caption.lines() {
            assert!(svg.contains(line), "caption line missing: {line}");
        }
        assert!(svg.contains("95% per-epoch band, lower"));
        assert!(stem.with_extension("png").is_file());
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
