//! What several CLI test files share: running the built `sieve` binary.

#![allow(dead_code)]

use assert_cmd::Command;
use std::path::Path;

/// Runs `sieve args...` in `dir`; returns the exit code (-1 if killed by a signal) and stderr.
pub fn run_in(dir: &Path, args: &[&str]) -> (i32, String) {
    let out = Command::cargo_bin("sieve")
        .unwrap()
        .current_dir(dir)
        .args(args)
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}
