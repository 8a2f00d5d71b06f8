//! The soft-sensor CLI contract (issue 4, item 8): `sieve record` writes the recording that
//! firmware-sim embeds, `sieve replay` prints the firmware's `final_state_hash` line (the
//! golden value in firmware-sim/recordings/shear-cell.golden), and bad options exit with
//! code 2 and one line.

use assert_cmd::Command;
use std::path::{Path, PathBuf};

fn recordings() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../firmware-sim/recordings")
}

/// Runs `sieve args...`; returns (exit code, stdout, stderr).
fn sieve(args: &[&str]) -> (i32, String, String) {
    let out = Command::cargo_bin("sieve")
        .expect("binary sieve")
        .args(args)
        .output()
        .expect("run sieve");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// The golden lines (`final_state_hash=0x...`, `faulted_state_hash=0x...`).
fn golden() -> (String, String) {
    let text = std::fs::read_to_string(recordings().join("shear-cell.golden")).expect("golden");
    let mut lines = text.lines().map(str::to_owned);
    let clean = lines.next().expect("clean line");
    let faulted = lines.next().expect("faulted line");
    assert!(clean.starts_with("final_state_hash=0x"), "{clean}");
    assert!(faulted.starts_with("faulted_state_hash=0x"), "{faulted}");
    (clean, faulted)
}

fn hash_line(stdout: &str) -> &str {
    let lines: Vec<&str> = stdout
        .lines()
        .filter(|l| l.starts_with("final_state_hash=0x"))
        .collect();
    assert_eq!(lines.len(), 1, "{stdout}");
    lines[0]
}

#[test]
fn replay_of_the_committed_recording_prints_the_golden_hashes() {
    let (clean, faulted) = golden();
    let rec = recordings().join("shear-cell.rec");
    let rec = rec.to_str().expect("utf-8 path");
    let (code, out, err) = sieve(&["replay", rec]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(hash_line(&out), clean);
    assert!(out.contains("scene=shear-cell"), "{out}");
    // The faulted replay prints, as its final state hash, firmware-sim's faulted value.
    let (code, out, err) = sieve(&["replay", rec, "--faults"]);
    assert_eq!(code, 0, "{err}");
    let want = faulted.replace("faulted_state_hash", "final_state_hash");
    assert_eq!(hash_line(&out), want);
}

#[test]
fn record_then_replay_reproduces_the_firmware_recording_and_hash() {
    let dir = tempfile::tempdir().expect("temp dir");
    let file = dir.path().join("shear.rec");
    let file_s = file.to_str().expect("utf-8 path");
    // firmware-sim's recording: 8x8 sensor, 5 % noise, 100 Hz, 100 frames (seed 1).
    let (code, out, err) = sieve(&[
        "record",
        "shear-cell",
        "--sensor-grid",
        "8x8",
        "--noise",
        "0.05",
        "--rate",
        "100",
        "--frames",
        "100",
        "--out",
        file_s,
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(out.starts_with("recorded 100 frames"), "{out}");
    let written = std::fs::read(&file).expect("recording written");
    let committed = std::fs::read(recordings().join("shear-cell.rec")).expect("committed");
    assert!(
        written == committed,
        "the CLI recording differs from firmware-sim/recordings/shear-cell.rec"
    );
    let (code, out, err) = sieve(&["replay", file_s, "--every", "25"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(hash_line(&out), golden().0);
    // Ticks 0, 25, 50, 75 and the last (99).
    let rows = out
        .lines()
        .filter(|l| l.trim_start().starts_with(char::is_numeric))
        .count();
    assert_eq!(rows, 5, "{out}");
    // Another seed gives another recording and another hash.
    let other = dir.path().join("other.rec");
    let other_s = other.to_str().expect("utf-8 path");
    let (code, _, err) = sieve(&[
        "record",
        "shear-cell",
        "--frames",
        "20",
        "--seed",
        "7",
        "--out",
        other_s,
    ]);
    assert_eq!(code, 0, "{err}");
    let (code, out, err) = sieve(&["replay", other_s]);
    assert_eq!(code, 0, "{err}");
    assert_ne!(hash_line(&out), golden().0);
}

/// Exit code 2, exactly one line on stderr starting with `error: `, containing `needle`, and
/// no file written.
fn assert_bad(args: &[&str], needle: &str) {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("x.rec");
    let mut full: Vec<&str> = args.to_vec();
    let out_s = out.to_str().expect("utf-8 path").to_owned();
    if args[0] == "record" {
        full.extend(["--out", &out_s]);
    }
    let (code, stdout, err) = sieve(&full);
    assert_eq!(code, 2, "{args:?}: stdout {stdout} stderr {err}");
    assert_eq!(err.lines().count(), 1, "{args:?}: one line expected: {err}");
    assert!(err.starts_with("error: "), "{err}");
    assert!(
        err.contains(needle),
        "{args:?}: `{needle}` missing in {err}"
    );
    assert!(!out.exists(), "{args:?} wrote a file");
}

#[test]
fn bad_options_exit_2_with_one_line() {
    assert_bad(&["record", "no-such-scene"], "unknown recording scene");
    assert_bad(
        &["record", "shear-cell", "--sensor-grid", "40x8"],
        "--sensor-grid",
    );
    assert_bad(&["record", "shear-cell", "--sensor-grid", "8by8"], "8by8");
    assert_bad(&["record", "shear-cell", "--noise", "2"], "--noise");
    assert_bad(&["record", "shear-cell", "--noise=-0.1"], "--noise");
    assert_bad(&["record", "shear-cell", "--rate", "0"], "--rate");
    assert_bad(&["record", "shear-cell", "--rate", "inf"], "--rate");
    assert_bad(&["record", "shear-cell", "--frames", "0"], "--frames");
    // Not a recording: a text file, a truncated recording, a missing file.
    let dir = tempfile::tempdir().expect("temp dir");
    let text = dir.path().join("notes.rec");
    std::fs::write(&text, "not a recording\n").expect("write");
    assert_bad(&["replay", text.to_str().unwrap()], "not a valid recording");
    let committed = std::fs::read(recordings().join("shear-cell.rec")).expect("committed");
    let cut = dir.path().join("cut.rec");
    std::fs::write(&cut, &committed[..committed.len() / 2]).expect("write");
    assert_bad(&["replay", cut.to_str().unwrap()], "not a valid recording");
    let missing = dir.path().join("missing.rec");
    assert_bad(
        &["replay", missing.to_str().unwrap()],
        "not a valid recording",
    );
}
