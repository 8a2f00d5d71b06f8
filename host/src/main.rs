//! The `sieve` binary: parse the command line, run it, map errors to exit codes.
use std::process::ExitCode;

fn main() -> ExitCode {
    let cli = sieve::cli::parse_args();
    match sieve::cli::execute(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            for line in e.lines() {
                eprintln!("error: {line}");
            }
            ExitCode::from(e.exit_code() as u8)
        }
    }
}
