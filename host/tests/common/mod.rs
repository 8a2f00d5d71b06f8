//! What several CLI test files share: running the built `sieve` binary.

#![allow(dead_code)]

use std::path::Path;
use std::time::{Duration, Instant};

/// Longest any CLI test's run of sieve may take before it is killed and the test fails: far
/// above the slowest (about a minute), far below CI's limit, so a regression that hangs fails
/// one test instead of the whole CI run.
pub const RUN_LIMIT: Duration = Duration::from_secs(900);

/// Runs `sieve args...` in `dir` with the extra environment `env` (and without a progress
/// interval inherited from the caller's shell, which would add lines to stderr), within
/// [`RUN_LIMIT`]; returns the exit code (-1 if killed by a signal), stdout and stderr.
pub fn run_env(dir: &Path, args: &[&str], env: &[(&str, &str)]) -> (i32, String, String) {
    use assert_cmd::cargo::CommandCargoExt;
    let mut cmd = std::process::Command::cargo_bin("sieve").expect("binary sieve");
    cmd.current_dir(dir)
        .args(args)
        .env_remove("SIEVE_PROGRESS_SECONDS");
    for (k, v) in env {
        cmd.env(k, v);
    }
    let out = output_within(cmd, RUN_LIMIT);
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Runs `cmd` with stdout and stderr captured; kills it and fails the test if it has not
/// ended within `limit`, so that a regression that blocks (on a FIFO, say) fails the test
/// instead of hanging CI for its whole time limit.
pub fn output_within(mut cmd: std::process::Command, limit: Duration) -> std::process::Output {
    use std::process::Stdio;
    fn drain(mut r: impl std::io::Read + Send + 'static) -> std::thread::JoinHandle<Vec<u8>> {
        std::thread::spawn(move || {
            let mut b = Vec::new();
            let _ = r.read_to_end(&mut b);
            b
        })
    }
    let mut child = cmd
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn");
    let out = drain(child.stdout.take().expect("stdout"));
    let err = drain(child.stderr.take().expect("stderr"));
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait") {
            break status;
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{cmd:?}: still running after {limit:?}: killed");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    std::process::Output {
        status,
        stdout: out.join().expect("stdout"),
        stderr: err.join().expect("stderr"),
    }
}

/// [`run_full`] with a deadline ([`output_within`]): for a case that once blocked sieve.
pub fn run_within(dir: &Path, args: &[&str], limit: Duration) -> (i32, String, String) {
    use assert_cmd::cargo::CommandCargoExt;
    let mut cmd = std::process::Command::cargo_bin("sieve").expect("binary sieve");
    cmd.current_dir(dir)
        .args(args)
        .env_remove("SIEVE_PROGRESS_SECONDS");
    let out = output_within(cmd, limit);
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// The deadline itself: a child that outlives it is killed and the test fails, at once.
#[cfg(unix)]
#[test]
#[should_panic(expected = "still running after 1s: killed")]
fn a_child_past_its_deadline_is_killed_and_fails_the_test() {
    let mut sleep = std::process::Command::new("sleep");
    sleep.arg("30");
    output_within(sleep, Duration::from_secs(1));
}

/// The names in `dir`, sorted.
pub fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
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

/// One damage of a file's bytes, as the fuzz tests of the run-directory readers apply it:
/// `how` 0 flips bits of the byte at `at` (by `byte | 1`), 1 cuts the file at `at`, 2 inserts
/// `number` at `at`, 3 rewrites the run of `is_num` bytes around `at` to `number` (positions
/// taken modulo the length).
pub fn damage(
    b: &mut Vec<u8>,
    (how, at, byte): (u8, usize, u8),
    number: &str,
    is_num: impl Fn(u8) -> bool,
) {
    let n = b.len().max(1);
    match how {
        0 => {
            if !b.is_empty() {
                b[at % n] ^= byte | 1;
            }
        }
        1 => b.truncate(at % n),
        2 => {
            let i = at % (b.len() + 1);
            b.splice(i..i, number.bytes());
        }
        _ => {
            let i = at % n;
            let s = (0..=i.min(b.len().saturating_sub(1)))
                .rev()
                .take_while(|&j| b.get(j).is_some_and(|&c| is_num(c)))
                .last();
            if let Some(s) = s {
                let e = (s..b.len()).find(|&j| !is_num(b[j])).unwrap_or(b.len());
                b.splice(s..e, number.bytes());
            }
        }
    }
}
