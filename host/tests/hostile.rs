//! Hostile files (issue 10): recordings whose CRC is valid but whose header, configuration or
//! truth is not what `sieve record` writes, corrupt and truncated files, and expressions built
//! to exhaust the stack or the clock. Each case once panicked, aborted, hung or reported a
//! NaN as 0; each must now end with exit code 2 and one line that names the file and the field.

use assert_cmd::Command;
use sieve::soft_sensor::{record_to_bytes, RecordOptions, Scene};
use sieve_core::sensor::recording::{write_recording, Recording, RecordingHeader, TruthRecord};
use std::path::Path;

/// Runs `sieve args...`; returns (exit code, stdout, stderr).
fn sieve(args: &[&str]) -> (i32, String, String) {
    let out = Command::cargo_bin("sieve")
        .expect("binary sieve")
        .args(args)
        .timeout(std::time::Duration::from_secs(60))
        .output()
        .expect("run sieve");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// A short valid recording of the idealised shear cell (30 frames).
fn valid() -> Vec<u8> {
    let mut o = RecordOptions::new(Scene::ShearCell);
    o.frames = 30;
    record_to_bytes(&o).expect("record").0
}

/// Rewrites a recording with `edit` applied to its header and truth records, with a fresh
/// (valid) CRC: what a careless or hostile writer produces.
fn rewrite(
    bytes: &[u8],
    edit: impl FnOnce(&mut RecordingHeader, &mut Vec<TruthRecord>),
) -> Vec<u8> {
    let rec = Recording::parse(bytes).expect("valid recording");
    let mut header = rec.header.clone();
    let mut truth: Vec<TruthRecord> = rec.truth().collect();
    edit(&mut header, &mut truth);
    let mut tb = Vec::new();
    for t in &truth {
        assert!(t.encode_into(|b| tb.extend_from_slice(b)));
    }
    let mut out = Vec::new();
    let mut scratch = vec![0u8; 4096];
    write_recording(
        &header,
        rec.stream,
        &tb,
        &mut scratch,
        |b| {
            out.extend_from_slice(b);
            Ok::<(), ()>(())
        },
        (),
    )
    .expect("write");
    out
}

/// Writes `bytes` to `name` in `dir`, replays it and asserts exit 2 with one line that names
/// the file and contains each of `needles`.
fn refused(dir: &Path, name: &str, bytes: &[u8], needles: &[&str]) -> String {
    let path = dir.join(name);
    std::fs::write(&path, bytes).expect("write");
    let (code, out, err) = sieve(&["replay", path.to_str().expect("utf-8")]);
    assert_eq!(code, 2, "{name}: stdout {out} stderr {err}");
    assert_eq!(err.lines().count(), 1, "{name}: one line expected: {err}");
    assert!(err.starts_with("error: "), "{err}");
    assert!(err.contains(name), "{name}: the file is not named: {err}");
    for n in needles {
        assert!(err.contains(n), "{name}: `{n}` missing in {err}");
    }
    assert!(!err.contains("Crc") && !err.contains("Truncated"), "{err}");
    err
}

#[test]
fn header_sizes_are_bounded_before_anything_is_allocated() {
    let dir = tempfile::tempdir().expect("temp dir");
    let good = valid();
    // Once: index out of bounds in coarsen (panic, exit 101).
    let zero = rewrite(&good, |h, _| h.truth_coarse = [0, 0]);
    refused(dir.path(), "zero.rec", &zero, &["truth_coarse", "1 to 16"]);
    // Once: a 34 GB allocation (abort).
    let huge = rewrite(&good, |h, _| h.truth_coarse = [65535, 65535]);
    refused(dir.path(), "huge.rec", &huge, &["truth_coarse", "65535"]);
    // The stored truth must match the coarse grid it claims.
    let other = rewrite(&good, |h, _| h.truth_coarse = [4, 4]);
    refused(dir.path(), "other.rec", &other, &["truth record 1", "16"]);
    let cells = rewrite(&good, |h, _| h.config.cells = [64, 64]);
    refused(dir.path(), "cells.rec", &cells, &["config.cells", "1024"]);
    // A budget of u32::MAX cycles at zero cost would ask for 65,535 substeps a tick.
    let budget = rewrite(&good, |h, _| {
        h.config.budget.cycles = u32::MAX;
        h.config.budget.per_substep = 0;
        h.config.budget.per_cell_substep = 0;
        h.config.budget.per_face_substep = 0;
    });
    refused(
        dir.path(),
        "budget.rec",
        &budget,
        &["config.budget", "65535 substeps"],
    );
    // A budget that does not cover the fixed part of a tick.
    let starved = rewrite(&good, |h, _| h.config.budget.cycles = 1);
    refused(
        dir.path(),
        "starved.rec",
        &starved,
        &["config.budget", "0 substeps"],
    );
}

#[test]
fn nan_truth_is_an_error_not_a_zero_error() {
    let dir = tempfile::tempdir().expect("temp dir");
    let good = valid();
    let psi = rewrite(&good, |_, t| t[4].psi = f32::NAN);
    refused(
        dir.path(),
        "psi.rec",
        &psi,
        &["truth record 5", "psi = NaN"],
    );
    // the truth's Psi on the estimator's grid (format 6), NaN or outside [0, 1]
    let coarse = rewrite(&good, |_, t| t[2].psi_estimator_grid = f32::NAN);
    refused(
        dir.path(),
        "coarse.rec",
        &coarse,
        &["truth record 3", "psi_estimator_grid = NaN", "0 to 1"],
    );
    let over = rewrite(&good, |_, t| t[0].psi_estimator_grid = 1.5);
    refused(
        dir.path(),
        "over.rec",
        &over,
        &["truth record 1", "psi_estimator_grid = 1.5"],
    );
    let phihat = rewrite(&good, |_, t| t[7].phihat[3] = f32::NAN);
    refused(
        dir.path(),
        "ph.rec",
        &phihat,
        &["truth record 8", "phihat[3]"],
    );
    let big = rewrite(&good, |_, t| t[0].phihat[0] = 7.0);
    refused(dir.path(), "big.rec", &big, &["phihat[0] = 7", "0 to 1"]);
    // Trailing garbage in the truth section was once skipped silently.
    let rec = Recording::parse(&good).expect("valid");
    let mut tail = rec.truth_bytes.to_vec();
    tail.extend_from_slice(&[0xff; 3]);
    let mut out = Vec::new();
    write_recording(
        &rec.header,
        rec.stream,
        &tail,
        &mut vec![0u8; 4096],
        |b| {
            out.extend_from_slice(b);
            Ok::<(), ()>(())
        },
        (),
    )
    .expect("write");
    refused(dir.path(), "tail.rec", &out, &["truth record 31"]);
}

#[test]
fn absurd_recorded_configurations_are_refused_by_field() {
    let dir = tempfile::tempdir().expect("temp dir");
    let good = valid();
    type Edit = fn(&mut RecordingHeader);
    let cases: [(&str, Edit, &str); 8] = [
        (
            "g.rec",
            |h| h.config.gravity = [0.0, -1e30],
            "config.gravity[1]",
        ),
        ("s0.rec", |h| h.config.s0 = 1e30, "config.s0"),
        (
            "ext.rec",
            |h| h.config.extent = [1e-30, 0.025],
            "config.extent[0]",
        ),
        ("c.rec", |h| h.config.c = 0.0, "config.c"),
        ("nan.rec", |h| h.config.eps0 = f32::NAN, "config.eps0"),
        ("d.rec", |h| h.config.diffusion = 1e30, "config.diffusion"),
        (
            "rs.rec",
            |h| h.config.reject_speed = f32::INFINITY,
            "config.reject_speed",
        ),
        (
            "per.rec",
            |h| h.config.tick_period = 0.0,
            "config.tick_period",
        ),
    ];
    for (name, edit, needle) in cases {
        let bytes = rewrite(&good, |h, _| edit(h));
        refused(dir.path(), name, &bytes, &[needle, "allowed"]);
    }
    // A box without small grains is legal: its drift is finite (once 0/0 = NaN).
    let empty = rewrite(&good, |h, _| h.config.initial_phihat = 0.0);
    let path = dir.path().join("empty.rec");
    std::fs::write(&path, empty).expect("write");
    let (code, out, err) = sieve(&["replay", path.to_str().unwrap(), "--every", "1000"]);
    assert_eq!(code, 0, "{err}");
    let drift = out
        .lines()
        .find_map(|l| l.split("mass_drift=").nth(1))
        .expect("mass_drift line");
    let drift: f64 = drift.trim().parse().expect("number");
    assert!(drift.is_finite() && drift.abs() < 1e-5, "{out}");
}

#[test]
fn damaged_files_say_what_is_damaged_in_words() {
    let dir = tempfile::tempdir().expect("temp dir");
    let good = valid();
    // One flipped bit in the middle of the frame stream.
    let mut flip = good.clone();
    let mid = flip.len() / 2;
    flip[mid] ^= 0x10;
    refused(
        dir.path(),
        "flip.rec",
        &flip,
        &["CRC-32 does not match", "the recording is damaged"],
    );
    // Cut in the stream: the stream length names itself.
    let hl = u32::from_le_bytes(good[12..16].try_into().unwrap()) as usize;
    let cut = &good[..16 + hl + 4 + 10];
    refused(
        dir.path(),
        "cut.rec",
        cut,
        &["stream length", "only 10 bytes"],
    );
    // Trailing bytes after the CRC.
    let mut long = good.clone();
    long.extend_from_slice(b"xyz");
    refused(
        dir.path(),
        "long.rec",
        &long,
        &["3 bytes follow the CRC-32"],
    );
    // Another version.
    let mut v = good.clone();
    v[8] = 9;
    let allowed = format!(
        "allowed {}",
        sieve_core::sensor::recording::RECORDING_VERSION
    );
    refused(dir.path(), "v.rec", &v, &["version 9", &allowed]);
    refused(dir.path(), "empty.rec", b"", &["not a sieve recording"]);
}

/// A finished run directory of `scene` for the test `tag` (written once per test binary;
/// each test damages its own copy).
fn run_dir(scene: &str, tag: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "sieve-hostile-{}-{tag}-{scene}",
        std::process::id()
    ));
    if !dir.join("summary.json").is_file() {
        let out = dir.to_str().expect("utf-8").to_owned();
        let (code, _, err) = sieve(&["run", scene, "--out", &out, "--quiet"]);
        assert_eq!(code, 0, "{err}");
    }
    dir
}

/// The files of a run directory that `sieve plot` reads.
fn plot_inputs(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut v = vec![
        dir.join("summary.json"),
        dir.join("series.csv"),
        dir.join("fields/series.pvd"),
    ];
    v.extend(snapshots(dir).into_iter().take(2));
    v
}

/// The `.vti` snapshots of a run directory, in name (= output) order.
fn snapshots(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut vti: Vec<_> = std::fs::read_dir(dir.join("fields"))
        .expect("fields")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "vti"))
        .collect();
    vti.sort();
    vti
}

/// `sieve plot` on a series.csv whose time runs backwards: a row's t rewritten to
/// 18446744073709551615 once made the plotting library overflow (found by
/// `plot_reader_never_panics`); the reader now refuses it in one line, as for NaN.
#[test]
fn plot_refuses_a_series_out_of_time_order() {
    let dir = run_dir("column-a", "series-order");
    let csv = dir.join("series.csv");
    let good = std::fs::read_to_string(&csv).expect("read");
    let out = dir.to_str().expect("utf-8").to_owned();
    for bad_t in ["18446744073709551615", "nan", "-1"] {
        let mut lines: Vec<String> = good.lines().map(String::from).collect();
        let row = &mut lines[5];
        let rest = row.split_once(',').expect("a row").1.to_string();
        *row = format!("{bad_t},{rest}");
        std::fs::write(&csv, lines.join("\n") + "\n").expect("write");
        let (code, _, err) = sieve(&["plot", &out]);
        assert_eq!(code, 1, "t = {bad_t}: {err}");
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(
            err.contains("series.csv") && err.contains("in order"),
            "{err}"
        );
    }
    std::fs::write(&csv, &good).expect("restore");
    let (code, _, err) = sieve(&["plot", &out]);
    assert_eq!(code, 0, "restored: {err}");
}

/// `sieve plot` on run directories whose .vti once could not be trusted: a reversed extent
/// (an underflow panic), an offset near `usize::MAX` (an overflow panic), a grid larger than
/// its arrays (an index out of bounds).
#[test]
fn plot_refuses_lying_vti_files() {
    let dir = run_dir("column-a", "vti");
    let vti = plot_inputs(&dir)[3].clone();
    let bytes = std::fs::read(&vti).expect("read");
    let marker = b"<AppendedData";
    let head_end = bytes
        .windows(marker.len())
        .position(|w| w == marker)
        .expect("appended data");
    let good = String::from_utf8(bytes[..head_end].to_vec()).expect("the header is text");
    let ext = good
        .split("WholeExtent=\"")
        .nth(1)
        .and_then(|r| r.split('"').next())
        .expect("WholeExtent")
        .to_string();
    let swap = |from: &str, to: &str| -> Vec<u8> {
        let head = String::from_utf8_lossy(&bytes[..head_end]).replacen(from, to, 1);
        let mut b = head.into_bytes();
        b.extend_from_slice(&bytes[head_end..]);
        b
    };
    let cases = [
        swap(
            &format!("WholeExtent=\"{ext}\""),
            "WholeExtent=\"0 0 0 0 5 2\"",
        ),
        swap(
            &format!("WholeExtent=\"{ext}\""),
            "WholeExtent=\"0 0 0 0 0 100000\"",
        ),
        swap("offset=\"0\"", "offset=\"18446744073709551615\""),
    ];
    for (k, b) in cases.iter().enumerate() {
        std::fs::write(&vti, b).expect("write");
        let (code, out, err) = sieve(&["plot", dir.to_str().unwrap()]);
        std::fs::write(&vti, &bytes).expect("restore");
        assert_eq!(code, 1, "case {k}: {out} {err}");
        assert_eq!(err.lines().count(), 1, "case {k}: {err}");
        assert!(err.contains(".vti"), "case {k}: {err}");
    }
    let (code, _, err) = sieve(&["plot", dir.to_str().unwrap()]);
    assert_eq!(code, 0, "restored: {err}");
}

/// `sieve plot` on a 2D series whose last snapshot is of another grid with the same cell
/// count (an extent 8 x 1 x 8 rewritten to 2 x 2 x 16: found by a hostile sweep, it indexed
/// the animation's grid out of bounds, a panic) and whose snapshot is a FIFO (the open
/// blocked for ever, deaf to SIGTERM) or a device (read without end): each is one line now.
#[test]
fn plot_refuses_a_snapshot_of_another_grid_or_not_a_file() {
    let dir = std::env::temp_dir().join(format!("sieve-hostile-{}-grid2d", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let out = dir.to_str().expect("utf-8").to_owned();
    let (code, _, err) = sieve(&[
        "run",
        "shear-cell-mixed",
        "--grid",
        "8x8",
        "--t-end",
        "2",
        "--out",
        &out,
        "--quiet",
    ]);
    assert_eq!(code, 0, "{err}");
    let last = snapshots(&dir).pop().expect("snapshots");
    let good = std::fs::read(&last).expect("read");
    let text = String::from_utf8_lossy(&good).into_owned();
    assert!(text.contains("Extent=\"0 8 0 0 0 8\""), "the 2D extent");
    let bad = text.replace("Extent=\"0 8 0 0 0 8\"", "Extent=\"0 2 0 2 0 16\"");
    // The appended data are raw bytes: rewrite the header only.
    let head = text.find("<AppendedData").expect("appended data");
    let mut b = bad.as_bytes()[..bad.find("<AppendedData").unwrap()].to_vec();
    b.extend_from_slice(&good[head..]);
    std::fs::write(&last, &b).expect("write");
    let (code, _, err) = sieve(&["plot", &out]);
    assert_eq!(code, 1, "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.contains(last.file_name().unwrap().to_str().unwrap())
            && err.contains("in a series of 8 x 1 x 8"),
        "{err}"
    );
    // A FIFO in its place: refused without opening it (exit 2), where mkfifo exists; under a
    // deadline, since a regression here blocks sieve for ever.
    std::fs::remove_file(&last).expect("remove");
    let fifo = std::process::Command::new("mkfifo").arg(&last).status();
    if fifo.is_ok_and(|s| s.success()) {
        let deadline = std::time::Duration::from_secs(20);
        let (code, _, err) = crate::common::run_within(&dir, &["plot", &out], deadline);
        assert_eq!(code, 2, "{err}");
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(err.contains("not a regular file"), "{err}");
        std::fs::remove_file(&last).expect("remove the fifo");
    }
    std::fs::write(&last, &good).expect("restore");
    let (code, _, err) = sieve(&["plot", &out]);
    assert_eq!(code, 0, "restored: {err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `sieve plot` on a drum run whose radial.csv (drum readouts) is damaged: a value past f64
/// once made the chart's mesh loop without end (found by hand: 10 CPU minutes and counting).
/// Each case ends at once: drawn (values that can be drawn, non-finite rings left out) or
/// refused in one line, and the run's files stay.
#[test]
fn plot_neither_hangs_nor_loses_files_on_a_damaged_radial_csv() {
    let dir = std::env::temp_dir().join(format!("sieve-hostile-{}-radial", std::process::id()));
    let out = dir.to_str().expect("utf-8").to_owned();
    let (code, _, err) = sieve(&[
        "run",
        "tumbler",
        "--grid",
        "18x18",
        "--t-end",
        "0.4",
        "--set",
        "frame.rev_per_s=1.5",
        "--quiet",
        "--out",
        &out,
    ]);
    assert_eq!(code, 0, "{err}");
    let csv = dir.join("radial.csv");
    let good = std::fs::read(&csv).expect("radial.csv of a drum run");
    let head = "about,r_lo,r_hi,cells,phihat,c\n";
    for (row, refused) in [
        ("centre,1e308,1e308,3,0.5,0.6", true),
        ("centre,-1e308,1e308,3,0.5,0.6", false), // its midpoint is 0
        ("centre,1e306,1e306,3,0.5,0.6", true),
        ("centre,0,1,3,0.5,1e308", false),
        ("centre,0,1,3,inf,0.6", false),
        ("centre,NaN,NaN,3,NaN,NaN", false),
        ("centre,x,1,2,3,4", true),
        ("", true),
    ] {
        std::fs::write(&csv, format!("{head}{row}\n")).expect("write");
        let (code, _, err) = sieve(&["plot", &out]);
        if refused {
            assert_eq!(code, 1, "[{row}]: {err}");
            assert_eq!(err.lines().count(), 1, "[{row}]: {err}");
            assert!(err.contains("radial"), "[{row}]: {err}");
        } else {
            assert_eq!(code, 0, "[{row}]: {err}");
        }
        assert!(dir.join("summary.json").is_file() && dir.join("fields/series.pvd").is_file());
    }
    std::fs::write(&csv, &good).expect("restore");
    let (code, _, err) = sieve(&["plot", &out]);
    assert_eq!(code, 0, "restored: {err}");
    let _ = std::fs::remove_dir_all(&dir);
}

proptest::proptest! {
    #![proptest_config(proptest::test_runner::Config {
        cases: std::env::var("SIEVE_FUZZ_CASES_PLOT").ok().and_then(|v| v.parse().ok()).unwrap_or(12),
        ..proptest::test_runner::Config::default()
    })]

    /// The reader behind `sieve plot` (summary.json, series.csv, series.pvd, .vti) on a run
    /// directory with one file damaged: bytes flipped, cut, replaced or a number rewritten.
    /// Never a panic; an error is one line.
    #[test]
    fn plot_reader_never_panics(two_d in proptest::bool::ANY, which in 0usize..5, at in proptest::num::usize::ANY,
                                how in 0u8..4, byte in proptest::num::u8::ANY,
                                number in proptest::sample::select(vec!["nan", "inf", "-1", "1e308", "0", "18446744073709551615", "-0", "x"])) {
        let dir = run_dir(if two_d { "shear-cell-inverse" } else { "column-a" }, "fuzz");
        let files = plot_inputs(&dir);
        let f = &files[which % files.len()];
        let orig = std::fs::read(f).expect("read");
        let mut b = orig.clone();
        // the digits around a position rewritten, or a byte flipped, a cut, an insert
        crate::common::damage(&mut b, (how, at, byte), number, |c| c.is_ascii_digit());
        std::fs::write(f, &b).expect("write");
        let plots = tempfile::tempdir().expect("temp dir");
        let r = std::panic::catch_unwind(|| sieve::output::redraw::redraw(&dir, plots.path()));
        std::fs::write(f, &orig).expect("restore");
        match r {
            Err(_) => proptest::prop_assert!(false, "panic on {} ({how}, {at}, {byte}, {number})", f.display()),
            Ok(Err(e)) => proptest::prop_assert_eq!(e.lines().count(), 1, "{}", e),
            Ok(Ok(_)) => {}
        }
    }
}
