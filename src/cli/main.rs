//! The `estim` command-line tool.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod beamsnet;
mod dataset;
mod dvl;
mod learned;
mod montecarlo;
mod output;
mod plots;
mod reproduce;
mod smooth;

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
    /// Monte Carlo consistency (NEES / NIS) over seeded simulated missions.
    Montecarlo(montecarlo::Args),
    /// DVL beams: least squares, calibration.
    Dvl(dvl::Args),
    /// BeamsNet: evaluate LS vs BeamsNet.
    Beamsnet(beamsnet::Args),
    /// Write training datasets.
    Dataset(dataset::Args),
    /// Smooth the INS/DVL survey (RTS): smoothed vs filtered errors against truth.
    Smooth(smooth::Args),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Reproduce(args) => reproduce::run(args),
        Command::Montecarlo(args) => montecarlo::run(args),
        Command::Dvl(args) => dvl::run(args),
        Command::Beamsnet(args) => beamsnet::run(args),
        Command::Dataset(args) => dataset::run(args),
        Command::Smooth(args) => smooth::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // One line, naming what was wrong; exit code 2 for bad input.
            eprintln!("error: {e:#}");
            ExitCode::from(2)
        }
    }
}
