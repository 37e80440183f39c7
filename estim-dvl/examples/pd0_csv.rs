//! Decode a Teledyne RDI PD0 file: the bottom-track CSV on stdout, the reader's report
//! (ensembles decoded, spans skipped with their byte offsets) on stderr.
//!
//! ```text
//! cargo run --release -p estim-dvl --example pd0_csv -- FILE.pd0 > bottom_track.csv
//! ```

use std::process::ExitCode;

use estim_dvl::{read_pd0_file, write_pd0_csv};

fn main() -> ExitCode {
    let Some(path) = std::env::args_os().nth(1) else {
        eprintln!("usage: pd0_csv FILE");
        return ExitCode::from(2);
    };
    let read = match read_pd0_file(&path) {
        Ok(read) => read,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::from(2);
        }
    };
    eprintln!("{}", read.report);
    match write_pd0_csv(&read.ensembles, std::io::stdout().lock()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => ExitCode::from(141),
        Err(e) => {
            eprintln!("{e}");
            ExitCode::FAILURE
        }
    }
}
