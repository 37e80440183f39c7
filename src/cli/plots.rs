//! Plots (PNG and SVG) made with plotters. Only the binary depends on plotters.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

/// One named line of a line chart.
pub struct Series<'a> {
    pub name: &'a str,
    pub x: &'a [f64],
    pub y: &'a [f64],
}

/// A line chart: several series, optional horizontal reference lines (e.g. a NEES band).
pub struct LineChart<'a> {
    pub title: &'a str,
    pub x_label: &'a str,
    pub y_label: &'a str,
    pub series: Vec<Series<'a>>,
    pub hlines: Vec<(&'a str, f64)>,
    pub log_y: bool,
    /// Equal scales on both axes (maps).
    pub equal_axes: bool,
}

const PALETTE: [RGBColor; 6] = [
    RGBColor(0, 0, 0),
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
];

type DrawResult = Result<(), Box<dyn std::error::Error>>;

/// Write `stem.png` and `stem.svg` for a line chart.
pub fn line_chart(stem: &Path, chart: &LineChart<'_>) -> DrawResult {
    let png = stem.with_extension("png");
    let svg = stem.with_extension("svg");
    draw_line(
        BitMapBackend::new(&png, (960, 600)).into_drawing_area(),
        chart,
    )?;
    draw_line(SVGBackend::new(&svg, (960, 600)).into_drawing_area(), chart)?;
    Ok(())
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

fn draw_line<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, c: &LineChart<'_>) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let (mut x0, mut x1) = finite_range(c.series.iter().flat_map(|s| s.x.iter().copied()));
    let (mut y0, mut y1) = finite_range(
        c.series
            .iter()
            .flat_map(|s| s.y.iter().copied())
            .chain(c.hlines.iter().map(|h| h.1))
            .filter(|v| !c.log_y || *v > 0.0),
    );
    if c.equal_axes {
        let half = 0.5 * (x1 - x0).max(y1 - y0) * 1.05;
        let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
        (x0, x1, y0, y1) = (cx - half, cx + half, cy - half, cy + half);
    }
    let mut builder = ChartBuilder::on(&root);
    builder
        .caption(c.title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(80);
    macro_rules! body {
        ($chart:expr) => {{
            let mut chart = $chart;
            chart
                .configure_mesh()
                .x_desc(c.x_label)
                .y_desc(c.y_label)
                .draw()?;
            for (i, s) in c.series.iter().enumerate() {
                let color = PALETTE[i % PALETTE.len()];
                let points =
                    s.x.iter()
                        .zip(s.y.iter())
                        .filter(|(x, y)| x.is_finite() && y.is_finite() && (!c.log_y || **y > 0.0))
                        .map(|(x, y)| (*x, *y));
                chart
                    .draw_series(LineSeries::new(points, color.stroke_width(2)))?
                    .label(s.name)
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                    });
            }
            for (name, value) in &c.hlines {
                let v = *value;
                chart
                    .draw_series(LineSeries::new(
                        [(x0, v), (x1, v)],
                        BLACK.mix(0.5).stroke_width(1),
                    ))?
                    .label(*name)
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], BLACK.mix(0.5))
                    });
            }
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()?;
        }};
    }
    if c.log_y {
        body!(builder.build_cartesian_2d(x0..x1, (y0.max(1e-300)..y1 * 1.1).log_scale())?);
    } else {
        let pad = 0.05 * (y1 - y0);
        body!(builder.build_cartesian_2d(x0..x1, (y0 - pad)..(y1 + pad))?);
    }
    root.present()?;
    Ok(())
}

/// Grouped bar chart: for each group (x), one bar per variant; values in percent.
pub fn bar_chart(
    stem: &Path,
    title: &str,
    y_label: &str,
    groups: &[&str],
    variants: &[&str],
    values: &[Vec<f64>],
) -> DrawResult {
    let png = stem.with_extension("png");
    let svg = stem.with_extension("svg");
    draw_bars(
        BitMapBackend::new(&png, (960, 600)).into_drawing_area(),
        title,
        y_label,
        groups,
        variants,
        values,
    )?;
    draw_bars(
        SVGBackend::new(&svg, (960, 600)).into_drawing_area(),
        title,
        y_label,
        groups,
        variants,
        values,
    )?;
    Ok(())
}

fn draw_bars<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    title: &str,
    y_label: &str,
    groups: &[&str],
    variants: &[&str],
    values: &[Vec<f64>],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let (lo, hi) = finite_range(values.iter().flatten().copied().chain([0.0]));
    let pad = 0.1 * (hi - lo).max(1.0);
    let n = groups.len() as f64;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..n, (lo - pad)..(hi + pad))?;
    let labels: Vec<String> = groups.iter().map(|g| g.to_string()).collect();
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(groups.len() * 2 + 1)
        .x_label_formatter(&|x| {
            let i = x.floor() as usize;
            if (x - x.floor() - 0.5).abs() < 1e-6 && i < labels.len() {
                labels[i].clone()
            } else {
                String::new()
            }
        })
        .y_desc(y_label)
        .draw()?;
    let width = 0.8 / variants.len().max(1) as f64;
    for (v, name) in variants.iter().enumerate() {
        let color = PALETTE[(v + 1) % PALETTE.len()];
        let bars = values
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
            .label(*name)
            .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 15, y + 5)], color.filled()));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()?;
    root.present()?;
    Ok(())
}
