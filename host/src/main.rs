//! The `sieve` binary: parse the command line, run it, map errors to exit codes.
use std::process::ExitCode;

fn main() -> ExitCode {
    let cli = sieve::cli::parse_args();
    // The step's instruction set (SIEVE_ISA, docs/simd.md): a bad value exits 2 before any work.
    if let Err(e) = sieve::isa::init() {
        for line in e.lines() {
            eprintln!("error: {line}");
        }
        return ExitCode::from(e.exit_code() as u8);
    }
    // SIGINT/SIGTERM stop the step loops, which keep what was written (host/src/interrupt.rs).
    if let Err(e) = sieve::interrupt::install() {
        eprintln!("warning: cannot handle SIGINT/SIGTERM ({e}); a signal ends sieve at once");
    }
    match sieve::cli::execute(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // An interruption is the user's choice, not an error.
            let prefix = match e {
                sieve::error::Error::Interrupted { .. } => "sieve",
                _ => "error",
            };
            // under mpirun rank 0 prints an error every rank shares; the others stay silent
            #[cfg(feature = "mpi")]
            if sieve::parallel_mpi::silent() {
                return ExitCode::from(e.exit_code() as u8);
            }
            for line in e.lines() {
                eprintln!("{prefix}: {line}");
            }
            ExitCode::from(e.exit_code() as u8)
        }
    }
}
