//! The files of `estim reproduce --out DIR`: `report.json`, and per trajectory the
//! time series CSV and the plots (the paper's Figs. 2-5, NEES, per-axis errors).

use std::io::Write;
use std::path::Path;

use anyhow::Context;

use crate::output::StagedDir;
use crate::plots::{
    bar_chart, error_chart, line_chart, line_chart_captioned, plot_unit, BarChart, ErrorPanel,
    LineChart, Series,
};
use crate::study::stats::{group_std_positive_definite, GROUPS};
use crate::study::TrajectoryReport;

use super::slug;

/// CSV time series and plots of every report into the staged folder, then commit.
pub(super) fn write_outputs(
    staged: StagedDir,
    reports: &[TrajectoryReport],
    json: &str,
) -> anyhow::Result<()> {
    let target = staged.target().to_path_buf();
    std::fs::write(staged.path("report.json"), json)
        .with_context(|| format!("{}: cannot write", target.join("report.json").display()))?;
    for r in reports {
        let stem = slug(r);
        write_time_series(&staged, &target, &stem, r)?;
        plot_std(&staged, &stem, r)?;
        if !r.improvements.is_empty() {
            plot_improvements(&staged, &stem, r)?;
        }
        plot_track(&staged, &stem, r)?;
        plot_nees(&staged, &stem, r)?;
        plot_errors(&staged, &stem, r)?;
    }
    staged.commit()
}

fn plot_err(e: Box<dyn std::error::Error>) -> anyhow::Error {
    anyhow::anyhow!("plot: {e}")
}

/// `{stem}_timeseries.csv`, long format: one row per filter and epoch.
fn write_time_series(
    staged: &StagedDir,
    target: &Path,
    stem: &str,
    r: &TrajectoryReport,
) -> anyhow::Result<()> {
    let name = format!("{stem}_timeseries.csv");
    let path = staged.path(&name);
    // A write error (a full disk) names the file as it will be in --out.
    let named =
        |e: std::io::Error| anyhow::anyhow!("{}: cannot write: {e}", target.join(&name).display());
    let mut w = std::io::BufWriter::new(
        std::fs::File::create(&path)
            .with_context(|| format!("{}: cannot create", target.join(&name).display()))?,
    );
    let mut header = vec!["filter_id".to_string(), "time_s".to_string()];
    header.extend(
        GROUPS
            .iter()
            .map(|(g, _)| format!("{}_std_sum", crate::study::stats::group_key_with_unit(g))),
    );
    header.extend(
        [
            "position_error_m",
            "velocity_error_mps",
            "attitude_error_deg",
            "nees",
            "north_m",
            "east_m",
        ]
        .map(String::from),
    );
    writeln!(w, "{}", header.join(",")).map_err(named)?;
    for run in &r.runs {
        for k in 0..run.time.len() {
            let d = &run.covariance_diagonal[k];
            let stds: Vec<String> = GROUPS
                .iter()
                .map(|(_, i)| {
                    format!(
                        "{:e}",
                        (*i..*i + 3).map(|j| d[j].max(0.0).sqrt()).sum::<f64>()
                    )
                })
                .collect();
            writeln!(
                w,
                "{},{},{},{},{},{},{},{},{}",
                run.id,
                run.time[k],
                stds.join(","),
                run.position_error[k],
                run.velocity_error[k],
                run.attitude_error_deg[k],
                run.nees[k],
                run.north_east[k][0],
                run.north_east[k][1]
            )
            .map_err(named)?;
        }
    }
    w.flush().map_err(named)?;
    Ok(())
}

/// Standard deviation over time per group (paper Figs. 3/4), in a unit whose ticks
/// read (biases in deg/h and mg or µg).
fn plot_std(staged: &StagedDir, stem: &str, r: &TrajectoryReport) -> anyhow::Result<()> {
    for (g, i) in GROUPS {
        let ys: Vec<Vec<f64>> = r
            .runs
            .iter()
            .map(|run| {
                run.covariance_diagonal
                    .iter()
                    .map(|d| (i..i + 3).map(|j| d[j].max(0.0).sqrt()).sum::<f64>())
                    .collect()
            })
            .collect();
        let (unit, scale) = plot_unit(g, ys.iter().flatten().copied());
        let ys: Vec<Vec<f64>> = ys
            .into_iter()
            .map(|y| y.into_iter().map(|v| v * scale).collect())
            .collect();
        let chart = LineChart {
            title: &format!("{}: {g} std (sum over axes)", r.name),
            x_label: "time [s]",
            y_label: &format!("{g} std, sum over axes [{unit}]"),
            series: r
                .runs
                .iter()
                .zip(&ys)
                .map(|(run, y)| Series {
                    id: &run.id,
                    label: &run.name,
                    x: &run.time,
                    y,
                })
                .collect(),
            hlines: vec![],
            log_y: false,
            equal_axes: false,
        };
        line_chart(&staged.path(&format!("{stem}_std_{g}")), &chart).map_err(plot_err)?;
    }
    Ok(())
}

/// Improvement bars (paper Fig. 5).
fn plot_improvements(staged: &StagedDir, stem: &str, r: &TrajectoryReport) -> anyhow::Result<()> {
    let groups: Vec<&str> = GROUPS.iter().skip(1).map(|(g, _)| *g).collect();
    let variants: Vec<(&str, &str)> = r
        .improvements
        .iter()
        .map(|i| (i.id.as_str(), i.variant.as_str()))
        .collect();
    let values: Vec<Vec<f64>> = r
        .improvements
        .iter()
        .map(|imp| {
            groups
                .iter()
                .map(|g| {
                    imp.groups
                        .get(*g)
                        .map_or(f64::NAN, |v| v.time_average_percent)
                })
                .collect()
        })
        .collect();
    // A bar is PD when both the aware run and the M-neglected run kept P
    // positive definite throughout in that group.
    let pd = |id: &str, g: &str| {
        let first = GROUPS.iter().find(|(name, _)| *name == g).map(|(_, i)| *i);
        r.runs.iter().find(|run| run.id == id).is_some_and(|run| {
            first.is_some_and(|i| {
                group_std_positive_definite(
                    run.covariance_not_positive_definite,
                    &run.covariance_diagonal,
                    i,
                )
            })
        })
    };
    let positive_definite: Vec<Vec<bool>> = r
        .improvements
        .iter()
        .map(|imp| {
            groups
                .iter()
                .map(|g| pd(&imp.id, g) && pd(crate::study::BEAMSNET_NEGLECTED, g))
                .collect()
        })
        .collect();
    bar_chart(
        &staged.path(&format!("{stem}_improvement")),
        &BarChart {
            title: &format!("{}: time-averaged std improvement over M neglected", r.name),
            y_label: "improvement of the time-averaged std [%]",
            groups: &groups,
            variants: &variants,
            values: &values,
            positive_definite: &positive_definite,
        },
    )
    .map_err(plot_err)?;
    Ok(())
}

/// North-east track (paper Fig. 2), equal metres per pixel.
fn plot_track(staged: &StagedDir, stem: &str, r: &TrajectoryReport) -> anyhow::Result<()> {
    let tracks: Vec<(&str, &str, &Vec<[f64; 2]>)> =
        std::iter::once(("truth", "truth", &r.truth_north_east))
            .chain(
                r.runs
                    .iter()
                    .map(|run| (run.id.as_str(), run.name.as_str(), &run.north_east)),
            )
            .collect();
    let east: Vec<Vec<f64>> = tracks
        .iter()
        .map(|t| t.2.iter().map(|p| p[1]).collect())
        .collect();
    let north: Vec<Vec<f64>> = tracks
        .iter()
        .map(|t| t.2.iter().map(|p| p[0]).collect())
        .collect();
    let chart = LineChart {
        title: &format!("{}: north-east track", r.name),
        x_label: "east [m]",
        y_label: "north [m]",
        series: tracks
            .iter()
            .zip(east.iter().zip(&north))
            .map(|(t, (x, y))| Series {
                id: t.0,
                label: t.1,
                x,
                y,
            })
            .collect(),
        hlines: vec![],
        log_y: false,
        equal_axes: true,
    };
    line_chart(&staged.path(&format!("{stem}_track")), &chart).map_err(plot_err)?;
    Ok(())
}

/// NEES over time with the per-epoch 95 % band of chi-square(15); the line breaks
/// where P was not positive definite (NEES undefined). The band printed with the
/// average NEES is that of a time average: the caption says so.
fn plot_nees(staged: &StagedDir, stem: &str, r: &TrajectoryReport) -> anyhow::Result<()> {
    let band = estim::core::consistency::chi_square_band(15, 1, 0.95)?;
    let epochs = r.runs.iter().map(|run| run.nees.len()).max().unwrap_or(0);
    let averaged = estim::core::consistency::chi_square_band(15, epochs.max(1), 0.95)?;
    let caption = crate::plots::nees_band_caption(
        [band.lower, band.upper],
        epochs,
        [averaged.lower, averaged.upper],
    );
    let chart = LineChart {
        title: &format!("{}: NEES (15 states) against truth", r.name),
        x_label: "time [s]",
        y_label: "NEES [-] (log scale)",
        series: r
            .runs
            .iter()
            .map(|run| Series {
                id: &run.id,
                label: &run.name,
                x: &run.time,
                y: &run.nees,
            })
            .collect(),
        hlines: vec![
            ("95% per-epoch band, lower", band.lower),
            ("95% per-epoch band, upper", band.upper),
        ],
        log_y: true,
        equal_axes: false,
    };
    line_chart_captioned(&staged.path(&format!("{stem}_nees")), &chart, &caption)
        .map_err(plot_err)?;
    Ok(())
}

/// Per-axis error against truth with the filter's +-3 sigma, per filter.
fn plot_errors(staged: &StagedDir, stem: &str, r: &TrajectoryReport) -> anyhow::Result<()> {
    const AXES: [&str; 3] = ["north", "east", "down"];
    for run in &r.runs {
        for (group, first, unit, scale) in [
            ("position", 0, "m", 1.0),
            ("velocity", 3, "m/s", 1.0),
            ("misalignment", 6, "deg", 180.0 / std::f64::consts::PI),
        ] {
            let labels: Vec<String> = AXES
                .iter()
                .map(|a| format!("{a} {group} error [{unit}]"))
                .collect();
            let panels: Vec<ErrorPanel<'_>> = (0..3)
                .map(|a| ErrorPanel {
                    y_label: &labels[a],
                    error: run
                        .axis_error
                        .iter()
                        .map(|e| e[first + a] * scale)
                        .collect(),
                    three_sigma: run
                        .covariance_diagonal
                        .iter()
                        .map(|d| {
                            let v = d[first + a];
                            // Undefined where the variance is not positive.
                            if v > 0.0 {
                                3.0 * v.sqrt() * scale
                            } else {
                                f64::NAN
                            }
                        })
                        .collect(),
                })
                .collect();
            error_chart(
                &staged.path(&format!("{stem}_error_{group}_{}", run.id)),
                &format!("{}: {} {group} error vs truth, +-3 sigma", r.name, run.name),
                &run.id,
                &run.time,
                &panels,
            )
            .map_err(plot_err)?;
        }
    }
    Ok(())
}
