//! The `estim` command-line tool.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod beamsnet;
mod compare;
mod dataset;
mod dvl;
mod evaluate;
mod experiment;
mod imu;
mod imu_choice;
mod learned;
mod learned_scenarios;
mod montecarlo;
mod navigate;
mod navigate_plots;
mod output;
mod plots;
mod report;
mod reproduce;
mod schema;
mod simulate;
mod smooth;
mod stream;
mod survey_checks;
mod tune;
mod waterlinked;
mod where_m;

/// The paper study (reproduce, montecarlo, report): private to the binary, not
/// library API. See docs/design.md.
mod study;

/// estim: state estimation with correlated process and measurement noise.
#[derive(Debug, Parser)]
#[command(name = "estim", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Reproduce the paper (INS/DVL + BeamsNet, M-aware vs M-neglected).
    Reproduce(reproduce::Args),
    /// Paired comparisons of filter variants on all A-KIT trajectories, innovation
    /// gate off: mean paired differences with 95 % t confidence intervals.
    Compare(compare::Args),
    /// The INS/DVL filter with DVL error states on all A-KIT trajectories, fitted on
    /// the training trajectories only: NEES, NIS, position RMSE per trajectory.
    Evaluate(evaluate::Args),
    /// Monte Carlo consistency (NEES / NIS) over seeded simulated missions.
    Montecarlo(montecarlo::Args),
    /// DVL beams: least squares, calibration.
    Dvl(dvl::Args),
    /// IMU: axis convention, clock and biases against a reference trajectory.
    Imu(imu::Args),
    /// BeamsNet: evaluate LS vs BeamsNet.
    Beamsnet(beamsnet::Args),
    /// Write training datasets.
    Dataset(dataset::Args),
    /// Regenerate the result tables of docs/results.md (between marker comments).
    Report(report::Args),
    /// Smooth the INS/DVL survey (RTS): smoothed vs filtered errors against truth.
    Smooth(smooth::Args),
    /// Navigate a survey: IMU + DVL (velocity or beams) [+ depth, fixes] in, a
    /// navigation solution with its 1-sigma out; no ground truth needed.
    Navigate(navigate::Args),
    /// Synthesize sensor files from a recorded trajectory (IMU, beams): a simulation.
    Simulate(simulate::Args),
    /// Fit the INS/DVL noise parameters (IMU densities, DVL noise and mismatch, the M
    /// scale) by maximum likelihood on A-KIT training trajectories, with standard
    /// errors and a likelihood-ratio test of M = 0.
    Tune(tune::Args),
    /// Where the exact cross-covariance M changes NEES or std by more than 10 %: IMU
    /// grade x DVL noise x sensor type over seeded simulated missions.
    WhereM(where_m::Args),
}

fn main() -> ExitCode {
    // First, before any other thread starts: SIGINT / SIGTERM remove staging folders.
    output::install_signal_cleanup();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Reproduce(args) => reproduce::run(args),
        Command::Compare(args) => compare::run(args),
        Command::Evaluate(args) => evaluate::run(args),
        Command::Montecarlo(args) => montecarlo::run(args),
        Command::Dvl(args) => match args.into_mode() {
            dvl::Mode::Tool(tool) => dvl::run(tool),
            dvl::Mode::Mismatch(args) => study::cli::dvl_mismatch::run(&args),
        },
        Command::Imu(args) => imu::run(args),
        Command::Beamsnet(args) => beamsnet::run(args),
        Command::Dataset(args) => dataset::run(args),
        Command::Report(args) => report::run(args),
        Command::Smooth(args) => match args.into_mode() {
            smooth::Mode::Survey(survey) => smooth::run(survey),
            smooth::Mode::Scenarios(scenarios) => study::cli::smooth::run(scenarios),
        },
        Command::Navigate(args) => navigate::run(args),
        Command::Simulate(args) => simulate::run(args),
        Command::Tune(args) => args.into_mode().and_then(|mode| match mode {
            tune::Mode::Survey(survey) => tune::run(survey),
            tune::Mode::Trajectories(trajectories) => study::cli::tune::run(trajectories),
        }),
        Command::WhereM(args) => where_m::run(args),
    };
    // Exit statuses: see `schema` (0 ok, 2 bad input, 3 some filter failed, 141
    // stdout closed).
    match result {
        Ok(()) => ExitCode::from(schema::EXIT_OK),
        // The reader of stdout went away (`estim reproduce | head`): end quietly.
        Err(e) if output::is_broken_pipe(&e) => ExitCode::from(schema::EXIT_BROKEN_PIPE),
        Err(e) if e.downcast_ref::<schema::RunStopped>().is_some() => {
            eprintln!("error: {e}");
            ExitCode::from(schema::EXIT_FILTERS_FAILED)
        }
        Err(e) if e.downcast_ref::<schema::FiltersFailed>().is_some() => {
            eprintln!("warning: {e}");
            ExitCode::from(schema::EXIT_FILTERS_FAILED)
        }
        Err(e) => {
            // One line, naming what was wrong.
            eprintln!("error: {e:#}");
            ExitCode::from(schema::EXIT_BAD_INPUT)
        }
    }
}
