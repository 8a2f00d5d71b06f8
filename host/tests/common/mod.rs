//! What several CLI test files share: running the built `sieve` binary.

#![allow(dead_code)]

use assert_cmd::Command;
use std::path::Path;

/// Runs `sieve args...` in `dir` with the extra environment `env` (and without a progress
/// interval inherited from the caller's shell, which would add lines to stderr); returns the
/// exit code (-1 if killed by a signal), stdout and stderr.
pub fn run_env(dir: &Path, args: &[&str], env: &[(&str, &str)]) -> (i32, String, String) {
    let mut cmd = Command::cargo_bin("sieve").expect("binary sieve");
    cmd.current_dir(dir)
        .args(args)
        .env_remove("SIEVE_PROGRESS_SECONDS");
    for (k, v) in env {
        cmd.env(k, v);
    }
    let out = cmd.output().expect("run sieve");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Runs `sieve args...` in `dir`; returns the exit code, stdout and stderr.
pub fn run_full(dir: &Path, args: &[&str]) -> (i32, String, String) {
    run_env(dir, args, &[])
}

/// Runs `sieve args...` in `dir`; returns the exit code (-1 if killed by a signal) and stderr.
pub fn run_in(dir: &Path, args: &[&str]) -> (i32, String) {
    let (code, _, err) = run_full(dir, args);
    (code, err)
}
