//! The `sieve` binary: parse the command line, run it, map errors to exit codes.
use clap::Parser;
use std::process::ExitCode;

fn main() -> ExitCode {
    let cli = sieve::cli::Cli::parse();
    match sieve::cli::execute(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(e.exit_code() as u8)
        }
    }
}
