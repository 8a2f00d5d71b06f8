//! The soft-sensor CLI contract (issue 4, item 8): `sieve record idealised-shear-cell` writes
//! the recording that firmware-sim embeds, `sieve replay` prints the firmware's
//! `final_state_hash` line (the golden value in firmware-sim/recordings/shear-cell.golden),
//! catalogue scenes (the flow shear cell, prescribed scenes) record and replay within stated
//! bounds, and bad options exit with code 2 and one line.

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
fn shear_gain_scales_the_segregation_and_one_changes_nothing() {
    // `--shear-gain G` multiplies S0, i.e. sqrt(T) from the measured shear (model.md 3.1):
    // G = 1 is the recorded estimate bit for bit; a larger gain segregates the idealised
    // shear cell faster, so its psi falls further (the estimate changes, and its hash).
    // Compared at the same estimate time: with G = 3 the recording's M4F budget (1 substep a
    // tick) limits every tick, so the estimate lags the frames. Measured at t = 0.24 s: psi
    // 0.80 with G = 1 and 0.32 with G = 3.
    let (clean, _) = golden();
    let rec = recordings().join("shear-cell.rec");
    let rec = rec.to_str().expect("utf-8 path");
    let (code, out, err) = sieve(&["replay", rec, "--shear-gain", "1", "--every", "1"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(hash_line(&out), clean);
    let psi_near = |out: &str, t: f64| -> (f64, f64) {
        // The row whose estimate time is nearest t: tick, seq, time, psi, ...
        let rows = out.lines().filter_map(|l| {
            let w: Vec<&str> = l.split_whitespace().collect();
            let time = w.get(2)?.parse::<f64>().ok()?;
            let psi = w.get(3)?.parse::<f64>().ok()?;
            w.first()?.parse::<u32>().ok()?;
            Some((time, psi))
        });
        rows.min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs()))
            .expect("a tick row")
    };
    let (code, out3, err) = sieve(&["replay", rec, "--shear-gain", "3", "--every", "1"]);
    assert_eq!(code, 0, "{err}");
    assert_ne!(hash_line(&out3), clean);
    let ((t1, p1), (t3, p3)) = (psi_near(&out, 0.24), psi_near(&out3, 0.24));
    assert!(
        (t1 - 0.24).abs() < 0.006 && (t3 - 0.24).abs() < 0.006,
        "{t1} {t3}"
    );
    assert!(
        p1 > 0.7 && p3 < p1 - 0.3,
        "psi with gain 1: {p1}, with gain 3: {p3}"
    );
}

#[test]
fn recorded_estimator_settings_give_the_recorded_estimate_and_others_change_it() {
    // Per-installation settings of `sieve replay` (docs/soft-sensor.md): the committed noisy
    // recording's own value reproduces its estimate bit for bit, another value changes it,
    // and `--kinematic` (frames from the rate alone) refuses each.
    // - `--noise-term L` subtracts L times the noise's own kappa:kappa before T ("Noise in
    //   the measured shear"), recorded 0;
    // - `--smoothing W`, the weight of a new frame in the moving average, recorded 0.02;
    // - `--spatial-passes P`, the 1-2-1 passes over each frame, recorded 2 ("Sensor grid,
    //   filter and gain on the silo").
    let (clean, _) = golden();
    let rec = recordings().join("shear-cell.rec");
    let rec = rec.to_str().expect("utf-8 path");
    for (flag, recorded, other) in [
        ("--noise-term", "0", "1"),
        ("--smoothing", "0.02", "1"),
        ("--spatial-passes", "2", "0"),
    ] {
        let hash = |value: &str| {
            let (code, out, err) = sieve(&["replay", rec, flag, value]);
            assert_eq!(code, 0, "{flag} {value}: {err}");
            hash_line(&out).to_string()
        };
        assert_eq!(hash(recorded), clean, "{flag} {recorded}");
        assert_ne!(hash(other), clean, "{flag} {other}");
        let (code, _, err) = sieve(&["replay", rec, "--kinematic", "0.05", flag, other]);
        assert_eq!(code, 2, "{err}");
        assert!(err.contains(flag), "{err}");
    }
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
        "idealised-shear-cell",
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
        "idealised-shear-cell",
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

/// The summary numbers of `sieve replay` output.
struct Replay {
    max_psi_error: f64,
    mean_l1: f64,
    mass_drift: f64,
    budget_limited: u64,
    ticks: u64,
    hash: String,
}

fn value<'a>(out: &'a str, key: &str) -> &'a str {
    out.split_whitespace()
        .find_map(|w| w.strip_prefix(key).and_then(|r| r.strip_prefix('=')))
        .unwrap_or_else(|| panic!("{key} missing in {out}"))
}

fn replay(file: &str) -> Replay {
    let (code, out, err) = sieve(&["replay", file, "--every", "1000"]);
    assert_eq!(code, 0, "{err}");
    Replay {
        max_psi_error: value(&out, "max_psi_error").parse().unwrap(),
        mean_l1: value(&out, "mean_l1").parse().unwrap(),
        mass_drift: value(&out, "mass_drift").parse().unwrap(),
        budget_limited: value(&out, "budget_limited").parse().unwrap(),
        ticks: value(&out, "ticks").parse().unwrap(),
        hash: hash_line(&out).to_owned(),
    }
}

/// The flow shear cell (model.md 7.4: frozen flow) on small grids, from a mixed bed (the soft
/// sensor starts from one uniform phihat): the truth is the scene's own run with the spun-up
/// flow, the frames its frozen velocity. Measured (release and debug alike): max |psi error|
/// 0.067, mean L1 0.038.
#[test]
fn record_and_replay_the_flow_shear_cell() {
    let dir = tempfile::tempdir().expect("temp dir");
    let file = dir.path().join("flow.rec");
    let file_s = file.to_str().expect("utf-8 path");
    let (code, out, err) = sieve(&[
        "record",
        "shear-cell",
        "--set",
        "initial.phi=c/2",
        "--truth-grid",
        "16x16",
        "--estimator-grid",
        "16x16",
        "--sensor-grid",
        "8x8",
        "--frames",
        "40",
        "--out",
        file_s,
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("flow (frozen-flow)"), "{out}");
    assert!(out.contains("recorded 40 frames"), "{out}");
    assert!(out.contains("of shear-cell"), "{out}");
    assert!(out.contains("truth 16x16"), "{out}");
    // The frozen flow's c is a field: the configuration carries its mean, and says so.
    assert!(err.contains("c is not uniform"), "{err}");
    let r = replay(file_s);
    assert_eq!(r.ticks, 40);
    assert!(r.max_psi_error < 0.1, "max psi error {}", r.max_psi_error);
    assert!(r.mean_l1 < 0.06, "mean L1 {}", r.mean_l1);
    // Closed box (periodic x, walls in z): f32 round-off only.
    assert!(r.mass_drift.abs() < 1e-5, "mass drift {}", r.mass_drift);
    assert_eq!(r.budget_limited, 0, "default period within the budget");
    assert_eq!(replay(file_s).hash, r.hash, "replay is deterministic");
    // The scene as it is (inversely graded bed) records too, with a note that the soft
    // sensor starts mixed.
    let inv = dir.path().join("inverse.rec");
    let (code, _, err) = sieve(&[
        "record",
        "shear-cell",
        "--truth-grid",
        "8x8",
        "--frames",
        "3",
        "--out",
        inv.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("initial phihat is not uniform"), "{err}");
}

/// A prescribed built-in with its defaults (truth 64x64, estimator 32x32, sensor 8x8, 5 %
/// noise, period = 2 Courant steps of the estimator, frames covering t_end = 3 s). Measured: 120
/// frames, max |psi error| 0.033, mean L1 0.0067.
#[test]
fn record_and_replay_a_prescribed_scene_with_defaults() {
    let dir = tempfile::tempdir().expect("temp dir");
    let file = dir.path().join("mixed.rec");
    let file_s = file.to_str().expect("utf-8 path");
    let (code, out, err) = sieve(&["record", "shear-cell-mixed", "--out", file_s]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("recorded 120 frames"), "{out}");
    assert!(out.contains("t = 3.0000e0 s"), "{out}");
    // T is given: the note says how the sensor's T-from-shear was matched.
    assert!(err.contains("T is given"), "{err}");
    let r = replay(file_s);
    assert_eq!(r.ticks, 120);
    assert!(r.max_psi_error < 0.05, "max psi error {}", r.max_psi_error);
    assert!(r.mean_l1 < 0.02, "mean L1 {}", r.mean_l1);
    assert!(r.mass_drift.abs() < 1e-5, "mass drift {}", r.mass_drift);
    assert_eq!(r.budget_limited, 0);
    assert_eq!(replay(file_s).hash, r.hash);
    // Another seed: another recording, another hash.
    let other = dir.path().join("other.rec");
    let (code, _, err) = sieve(&[
        "record",
        "shear-cell-mixed",
        "--frames",
        "10",
        "--seed",
        "3",
        "--out",
        other.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    assert_ne!(replay(other.to_str().unwrap()).hash, r.hash);
}

#[test]
fn bad_options_exit_2_with_one_line() {
    assert_bad(&["record", "no-such-scene"], "unknown recording scene");
    // The message lists what is allowed: catalogue and legacy names.
    assert_bad(&["record", "no-such-scene"], "shear-cell-mixed");
    assert_bad(&["record", "no-such-scene"], "idealised-shear-cell");
    // Not 2D: a 1D built-in, a scene turned 3D.
    assert_bad(
        &["record", "column-a"],
        "dim = 1 is out of range: allowed 2",
    );
    assert_bad(
        &["record", "shear-cell-mixed", "--set", "dim=3"],
        "dim = 3 is out of range: allowed 2",
    );
    // A container (cut cells): the estimator is a box (coupled box scenes record since
    // issue 9).
    assert_bad(&["record", "tumbler"], "tumbler");
    // Given T and no shear: the soft sensor's T would be 0.
    assert_bad(&["record", "gray-thornton-plug"], "initial.u: has no shear");
    assert_bad(
        &["record", "shear-cell-mixed", "--estimator-grid", "64x64"],
        "--estimator-grid",
    );
    assert_bad(
        &["record", "idealised-shear-cell", "--set", "run.t_end=1"],
        "--set",
    );
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
    assert_bad(&["replay", text.to_str().unwrap()], "not a sieve recording");
    let committed = std::fs::read(recordings().join("shear-cell.rec")).expect("committed");
    let cut = dir.path().join("cut.rec");
    std::fs::write(&cut, &committed[..committed.len() / 2]).expect("write");
    assert_bad(
        &["replay", cut.to_str().unwrap()],
        "the recording is damaged",
    );
    // Replay flags (issue 9): out of range, negative, not numbers: one line each.
    let rec = recordings().join("shear-cell.rec");
    let rec = rec.to_str().unwrap();
    for (flag, value) in [
        ("--fines-band", "0.6,0.4"),
        ("--fines-band", "-1,2"),
        ("--fines-band", "nan,1"),
        ("--fines-band", "0.4"),
        ("--alarm-persist", "0"),
        ("--alarm-persist", "-3"),
        ("--alarm-persist", "1e9"),
        ("--alarm-persist", "70000"),
        ("--kinematic", "0"),
        ("--kinematic", "-1"),
        ("--kinematic", "nan"),
        ("--shear-gain", "0"),
        ("--shear-gain", "-2"),
        ("--shear-gain", "nan"),
        ("--shear-gain", "1e9"),
        ("--noise-term", "-1"),
        ("--noise-term", "nan"),
        ("--noise-term", "11"),
        ("--noise-term", "inf"),
        ("--smoothing", "0"),
        ("--smoothing", "-0.5"),
        ("--smoothing", "1.5"),
        ("--smoothing", "nan"),
        ("--spatial-passes", "-1"),
        ("--spatial-passes", "9"),
        ("--spatial-passes", "1.5"),
    ] {
        assert_bad(&["replay", rec, flag, value], flag);
    }
    let missing = dir.path().join("missing.rec");
    assert_bad(
        &["replay", missing.to_str().unwrap()],
        "cannot read the recording",
    );
}

/// `sieve record` says the same pre-run lines as `sieve run` (`run::caveats`): a scene that
/// names `flow.merged_walls` without cut cells gets the one warning line, and records.
#[test]
fn record_says_the_runs_pre_run_warnings() {
    let dir = tempfile::tempdir().expect("temp dir");
    let file = dir.path().join("mw.rec");
    let (code, _, err) = sieve(&[
        "record",
        "shear-cell",
        "--frames",
        "2",
        "--set",
        "flow.merged_walls=\"member\"",
        "--out",
        file.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let lines: Vec<&str> = err
        .lines()
        .filter(|l| l.contains("flow.merged_walls"))
        .collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(
        lines[0].starts_with("warning: ") && lines[0].contains("no cut cells"),
        "{err}"
    );
    assert!(file.exists());
}
