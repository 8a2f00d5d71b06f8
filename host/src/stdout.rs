//! Results on standard output without a panic when the reader has gone.
//!
//! `println!` panics if stdout is a pipe whose reader closed (`sieve scenes | head -1`,
//! `sieve sweep --list | head`): Rust ignores SIGPIPE, so the write fails with EPIPE and the
//! macro turns that into a panic and exit code 101. A C tool would die of SIGPIPE at that
//! point, silently, with status 128 + 13. sieve does the same, without a signal: when a write to
//! stdout fails because the reader has gone, it exits at once with [`BROKEN_PIPE_EXIT`] and
//! prints nothing. Every command writes its files before it prints its last lines, so nothing
//! is lost; any other write error is reported as a failure.

use std::fmt;
use std::io::{self, Write};

use crate::error::{Error, Result};

/// The exit status when stdout's reader has gone: 128 + SIGPIPE, what a shell reports for a
/// C tool killed by that signal, so `set -o pipefail` scripts see the same.
pub const BROKEN_PIPE_EXIT: i32 = 141;

/// Writes `args` to stdout and flushes; see the module docs for a reader that has gone.
pub fn write(args: fmt::Arguments<'_>) -> Result<()> {
    let mut out = io::stdout().lock();
    checked(out.write_fmt(args).and_then(|()| out.flush()))
}

/// The outcome of a write to stdout done elsewhere (a report written through `&mut impl
/// Write`): a reader that has gone exits as in the module docs, any other error is a failure.
pub fn checked(r: io::Result<()>) -> Result<()> {
    match r {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == io::ErrorKind::BrokenPipe => std::process::exit(BROKEN_PIPE_EXIT),
        Err(e) => Err(Error::Failure(format!(
            "cannot write to standard output: {e}"
        ))),
    }
}

/// `println!` through [`fn@write`]: evaluates to the crate's `Result<()>`.
#[macro_export]
macro_rules! outln {
    ($($arg:tt)*) => {
        $crate::stdout::write(format_args!("{}\n", format_args!($($arg)*)))
    };
}

/// `print!` through [`fn@write`]: evaluates to the crate's `Result<()>`.
#[macro_export]
macro_rules! out {
    ($($arg:tt)*) => {
        $crate::stdout::write(format_args!($($arg)*))
    };
}
