//! Checkpoints and `sieve run --resume DIR` (issue 10, docs/resume.md).
//!
//! The main test of each kind of scene spawns the binary with checkpoints every 40 ms of wall
//! time, kills it with SIGKILL once a checkpoint exists (so the kill lands wherever the run
//! happens to be: mid-interval, between outputs, in any chunk), resumes it, and compares the
//! outputs byte for byte with an uninterrupted run: final.csv, series.csv, every VTK snapshot
//! and the collection, discharge.csv and profiles.csv where the scene writes them, and every
//! value of summary.json except the wall-clock timings (state hash included). Then the
//! refusals: another scene, another build's or a damaged checkpoint, none at all, a fresh run
//! over a checkpoint, a bad interval (exit 2, one line each). Last, the reader is fuzzed.

use crate::common::run_full;

use proptest::prelude::*;
use sieve::checkpoint::{decode, encode, Entries, Value};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// summary.json without the wall-clock timings (the only values that may differ).
fn summary_without_timings(dir: &Path) -> serde_json::Value {
    let mut v = json(&dir.join("summary.json"));
    let o = v.as_object_mut().unwrap();
    for k in [
        "wall_seconds",
        "stepping_seconds",
        "cell_updates_per_second",
    ] {
        assert!(o.remove(k).is_some(), "summary.json has no {k}");
    }
    if let Some(f) = o.get_mut("flow").and_then(|f| f.as_object_mut()) {
        f.remove("flow_seconds");
    }
    v
}

/// Asserts that the resumed run `b` (checkpointed every `interval`) wrote the summary of the
/// uninterrupted run `a` but for the timings and its overrides, which are `a`'s plus the
/// checkpoint interval (`--checkpoint-interval` sets a scene key).
fn same_summary(a: &Path, b: &Path, interval: &str, what: &str) -> serde_json::Value {
    let (mut sa, mut sb) = (summary_without_timings(a), summary_without_timings(b));
    let mut want = sa["overrides"].as_array().expect("overrides").clone();
    want.push(format!("run.checkpoint_interval={interval}").into());
    assert_eq!(sb["overrides"], serde_json::Value::Array(want), "{what}");
    sa["overrides"].take();
    sb["overrides"].take();
    assert_eq!(sa, sb, "{what}: summary.json differs after resume");
    sa
}

/// Every file of a run directory but the pictures and summary.json, by relative path.
fn data_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for top in ["", "fields"] {
        for e in std::fs::read_dir(dir.join(top)).unwrap() {
            let p = e.unwrap().path();
            // summary.json holds timings; .sieve-run the command and pid (outsafe's marker)
            let name = p.file_name().unwrap();
            if p.is_file() && name != "summary.json" && name != ".sieve-run" {
                out.push(p.strip_prefix(dir).unwrap().to_path_buf());
            }
        }
    }
    out.sort();
    out
}

/// Whether `args` run a coupled flow scene (one of this file's).
fn args_flow(args: &[&str]) -> bool {
    ["column-collapse", "tumbler", "silo"].contains(&args[0])
}

/// Runs `args` into `ref` uninterrupted, and into `run` with checkpoints, killed (SIGKILL)
/// after the first checkpoint (a coupled flow scene: the second), then resumed; asserts the same outputs. Returns the number of
/// kept snapshots the killed run's checkpoint held and the reference summary.
fn kill_and_resume(args: &[&str]) -> serde_json::Value {
    let d = tempfile::tempdir().unwrap();
    let mut reference = vec!["run"];
    reference.extend_from_slice(args);
    reference.extend_from_slice(&["--out", "ref", "-q"]);
    let start = Instant::now();
    let (code, _, err) = run_full(d.path(), &reference);
    assert_eq!(code, 0, "{err}");
    let ref_seconds = start.elapsed().as_secs_f64();

    let mut killed = vec!["run"];
    killed.extend_from_slice(args);
    killed.extend_from_slice(&["--out", "run", "-q", "--checkpoint-interval", "0.04"]);
    let mut child = std::process::Command::new(assert_cmd::cargo::cargo_bin("sieve"))
        .current_dir(d.path())
        .args(&killed)
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let state = d.path().join(".run.checkpoint").join("checkpoint.bin");
    let t0 = Instant::now();
    while !state.exists() {
        assert!(
            child.try_wait().unwrap().is_none(),
            "{args:?}: the run ended ({ref_seconds:.2} s uninterrupted) before its first checkpoint: lengthen it"
        );
        assert!(t0.elapsed() < Duration::from_secs(60), "no checkpoint");
        std::thread::sleep(Duration::from_millis(5));
    }
    // The first checkpoint follows the first step, when a state that only a step writes
    // (the flow's start-of-step velocity) still equals its set-up value. A flow scene checks
    // for a due checkpoint after every step: wait for its next one, so that the resumed run
    // needs everything a checkpoint must keep. (A prescribed or frozen-flow run checks after
    // chunks of thousands of steps: its second checkpoint would need a much longer test run.)
    let first = std::fs::read(&state).unwrap_or_default();
    while args_flow(args) && std::fs::read(&state).is_ok_and(|b| b == first) {
        assert!(
            child.try_wait().unwrap().is_none(),
            "{args:?}: the run ended ({ref_seconds:.2} s uninterrupted) before its second checkpoint: lengthen it"
        );
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "no second checkpoint"
        );
        std::thread::sleep(Duration::from_millis(2));
    }
    // A little later, somewhere in the run.
    std::thread::sleep(Duration::from_millis(10));
    child.kill().unwrap(); // SIGKILL
    let status = child.wait().unwrap();
    assert!(
        !status.success(),
        "{args:?}: the run finished before the kill ({ref_seconds:.2} s): lengthen it"
    );
    assert!(!d.path().join("run").exists(), "a killed run committed DIR");
    let (code, _, err) = run_full(d.path(), &["run", "--resume", "run", "-q"]);
    assert_eq!(code, 0, "{args:?}: resume failed: {err}");
    assert!(
        !d.path().join(".run.checkpoint").exists(),
        "a finished run keeps its checkpoint"
    );

    let (a, b) = (d.path().join("ref"), d.path().join("run"));
    let files = data_files(&a);
    assert_eq!(files, data_files(&b), "{args:?}: different files");
    assert!(files.iter().any(|f| f.ends_with("final.csv")));
    assert!(files.iter().any(|f| f.ends_with("state_0001.vti")));
    for f in &files {
        assert!(
            std::fs::read(a.join(f)).unwrap() == std::fs::read(b.join(f)).unwrap(),
            "{args:?}: {} differs after resume",
            f.display()
        );
    }
    same_summary(&a, &b, "0.04", &format!("{args:?}"))
}

#[test]
fn prescribed_scene_killed_and_resumed_ends_with_the_same_bits() {
    // 2D modified flux, T from shear: 48 x 48 for 3 s.
    let s = kill_and_resume(&["shear-cell-inverse", "--grid", "48x48", "--t-end", "3"]);
    assert!(s["steps"].as_u64().unwrap() > 100, "{s}");
}

#[test]
fn prescribed_large_phase_f32_godunov_killed_and_resumed() {
    // The tracked large phase in f32 with a naive flux (bounds broken by design: the resume
    // must not re-validate phi), 1D, many steps.
    kill_and_resume(&[
        "column-d",
        "--cells",
        "4000",
        "--scheme",
        "godunov",
        "--set",
        "numerics.phase=\"large\"",
        "--set",
        "model.precision=\"f32\"",
        "--t-end",
        "1",
    ]);
}

#[test]
fn open_side_books_survive_a_kill_and_resume() {
    // Gray-Thornton's shear layer with its inflow and outflow sides, the large phase tracked:
    // the sides' books (summary.json's mass_out_sides, docs/model.md 5.6) come back from the
    // checkpoint. The inflow lets in u c phihat = 0.36 of fines per unit time (u = 2z over a
    // unit height), so 4.32 by t = 12, and the books close the mass.
    let s = kill_and_resume(&[
        "gray-thornton-shear",
        "--t-end",
        "12",
        "--set",
        "numerics.phase=\"large\"",
    ]);
    let x_low = s["mass_out_sides"]["x_low"].as_f64().unwrap();
    assert!((x_low + 0.36 * 12.0).abs() < 1e-12, "{s}");
    assert!(s["mass_rel_drift"].as_f64().unwrap() < 1e-12, "{s}");
}

#[test]
fn frozen_flow_scene_killed_and_resumed_ends_with_the_same_bits() {
    let s = kill_and_resume(&["shear-cell", "--grid", "20x20", "--t-end", "40"]);
    assert_eq!(s["flow"]["equations"], "frozen-flow");
}

#[test]
fn coupled_collapse_killed_and_resumed_ends_with_the_same_bits() {
    let s = kill_and_resume(&["column-collapse", "--grid", "40x8", "--t-end", "0.25"]);
    assert_eq!(s["flow"]["equations"], "coupled");
}

#[test]
fn cut_cell_tumbler_in_its_rotating_frame_killed_and_resumed() {
    let s = kill_and_resume(&["tumbler", "--grid", "20x20", "--t-end", "1.5"]);
    assert_eq!(s["frame"]["kind"], "rotating");
}

#[test]
fn silo_with_outlet_killed_and_resumed_keeps_discharge_csv() {
    kill_and_resume(&[
        "silo",
        "--grid",
        "15x50",
        "--t-end",
        "0.12",
        "--set",
        "run.output_interval=0.03",
    ]);
}

/// The arguments of the run [`killed_run`] kills.
const COLUMN_B: [&str; 9] = [
    "run", "column-b", "--cells", "3000", "--t-end", "2", "--out", "run", "-q",
];

/// Starts a checkpointed run of column-b into `dir/run`, kills it after its first
/// checkpoint, and returns the path of the checkpoint file.
fn killed_run(dir: &Path) -> PathBuf {
    let mut args = COLUMN_B.to_vec();
    args.extend(["--checkpoint-interval", "0.02"]);
    kill_after_checkpoint(dir, &args, None)
}

/// Runs `sieve args` in `dir` (a run into `dir/run` with checkpoints), and kills it (SIGKILL)
/// 10 ms after a checkpoint other than `old` (the bytes of the checkpoint it resumes) exists;
/// returns the path of the checkpoint file.
fn kill_after_checkpoint(dir: &Path, args: &[&str], old: Option<&[u8]>) -> PathBuf {
    let mut child = std::process::Command::new(assert_cmd::cargo::cargo_bin("sieve"))
        .current_dir(dir)
        .args(args)
        .spawn()
        .unwrap();
    let state = dir.join(".run.checkpoint").join("checkpoint.bin");
    let t0 = Instant::now();
    // (the state file is replaced by a rename: a read sees the old or the new bytes)
    while std::fs::read(&state).map_or(true, |b| Some(&b[..]) == old) {
        assert!(
            child.try_wait().unwrap().is_none(),
            "{args:?}: ended before a checkpoint"
        );
        assert!(t0.elapsed() < Duration::from_secs(60));
        std::thread::sleep(Duration::from_millis(5));
    }
    std::thread::sleep(Duration::from_millis(10));
    child.kill().unwrap();
    let status = child.wait().unwrap();
    assert!(!status.success(), "{args:?}: finished before the kill");
    state
}

fn one_line_refusal(dir: &Path, args: &[&str], needles: &[&str]) {
    let (code, _, err) = run_full(dir, args);
    assert_eq!(code, 2, "{args:?}: {err}");
    // The first refusal may follow the note that the killed run's staging debris was
    // removed (docs/outputs.md); the error itself is one line.
    let err: String = err
        .lines()
        .filter(|l| !l.starts_with("note: removed"))
        .map(|l| format!("{l}\n"))
        .collect();
    assert_eq!(
        err.lines().count(),
        1,
        "{args:?}: one line expected:\n{err}"
    );
    for n in needles {
        assert!(err.contains(n), "{args:?}: no '{n}' in: {err}");
    }
}

#[test]
fn refusals_name_the_checkpoint_and_what_to_do() {
    let d = tempfile::tempdir().unwrap();
    let state = killed_run(d.path());
    // a fresh run over an unfinished one
    one_line_refusal(
        d.path(),
        &["run", "column-b", "--out", "run", "-q"],
        &[".run.checkpoint", "--resume run"],
    );
    // another scene (also: the same scene with another S0)
    one_line_refusal(
        d.path(),
        &["run", "column-a", "--resume", "run", "-q"],
        &["checkpoint.bin", "differs", "--resume alone"],
    );
    one_line_refusal(
        d.path(),
        &[
            "run",
            "column-b",
            "--cells",
            "3000",
            "--t-end",
            "2",
            "--set",
            "material.s0=2",
            "--resume",
            "run",
            "-q",
        ],
        &["differs"],
    );
    // no checkpoint at all
    one_line_refusal(
        d.path(),
        &["run", "--resume", "elsewhere", "-q"],
        &["no checkpoint", "--checkpoint-interval"],
    );
    // a bad interval
    one_line_refusal(
        d.path(),
        &[
            "run",
            "column-a",
            "--out",
            "x",
            "--checkpoint-interval",
            "0",
            "-q",
        ],
        &["run.checkpoint_interval", "0 < checkpoint_interval"],
    );
    // another build: rewrite the build entry (with a valid checksum)
    let good = std::fs::read(&state).unwrap();
    let mut e = decode(&good).unwrap();
    e.put("build", Value::Text("sieve 0.0.0 build 0".into()));
    std::fs::write(&state, encode(&e)).unwrap();
    one_line_refusal(
        d.path(),
        &["run", "--resume", "run", "-q"],
        &["written by sieve 0.0.0", "start afresh"],
    );
    // a damaged file: one flipped bit
    let mut bad = good.clone();
    let mid = bad.len() / 2;
    bad[mid] ^= 0x10;
    std::fs::write(&state, &bad).unwrap();
    one_line_refusal(d.path(), &["run", "--resume", "run", "-q"], &["checksum"]);
    // a damaged kept snapshot
    std::fs::write(&state, &good).unwrap();
    let snap = d
        .path()
        .join(".run.checkpoint")
        .join("fields")
        .join("state_0000.vti");
    let mut v = std::fs::read(&snap).unwrap();
    v.push(b' ');
    // break the hard link first: the staging copy is not ours to change
    std::fs::remove_file(&snap).unwrap();
    std::fs::write(&snap, &v).unwrap();
    one_line_refusal(
        d.path(),
        &["run", "--resume", "run", "-q"],
        &["state_0000.vti", "damaged"],
    );
    v.pop();
    std::fs::remove_file(&snap).unwrap();
    std::fs::write(&snap, &v).unwrap();
    // intact again: it resumes and cleans up
    let (code, _, err) = run_full(d.path(), &["run", "--resume", "run", "-q"]);
    assert_eq!(code, 0, "{err}");
    assert!(d.path().join("run").join("summary.json").exists());
    assert!(!d.path().join(".run.checkpoint").exists());
}

/// A name of the pattern sieve's temporary checkpoint files have (checkpoint.rs,
/// `write_durably`): `.checkpoint.`, six ASCII letters or digits, `.part`. Sieve removes only
/// the one name a checkpoint recorded (`part.next`), so a user's file of this name stays.
const PATTERN_PART: &str = ".checkpoint.Ab12Cd.part";

#[test]
fn a_stale_temporary_file_is_removed_on_resume_and_never_read() {
    let d = tempfile::tempdir().unwrap();
    // about 0.8 s uninterrupted: long enough to be killed twice
    let long = [
        "run",
        "column-b",
        "--cells",
        "3000",
        "--t-end",
        "20",
        "--set",
        "run.output_interval=1",
        "-q",
        "--out",
    ];
    let (code, _, err) = run_full(d.path(), &[&long[..], &["ref"]].concat());
    assert_eq!(code, 0, "{err}");
    let args = [&long[..], &["run", "--checkpoint-interval", "0.02"]].concat();
    let state = kill_after_checkpoint(d.path(), &args, None);
    let ck = state.parent().unwrap().to_path_buf();
    let good = std::fs::read(&state).unwrap();
    // what a SIGKILL during the next checkpoint write leaves: the start of a checkpoint,
    // under the name this one recorded for it
    let recorded = decode(&good)
        .unwrap()
        .text("part.next")
        .unwrap()
        .to_string();
    assert_ne!(recorded, PATTERN_PART);
    let stale = ck.join(&recorded);
    std::fs::write(&stale, &good[..good.len() / 2]).unwrap();
    // not sieve's: a user's file, one of the pattern and names close to it
    let users = [
        "notes.txt",
        PATTERN_PART,
        ".checkpoint.mine.part",
        ".checkpoint.Ab12Cd.part.bak",
        ".checkpoint.Ab12Cde.part",
    ];
    for name in users {
        std::fs::write(ck.join(name), "the user's").unwrap();
    }
    // never taken for the checkpoint, even a whole one: without checkpoint.bin there is none
    std::fs::remove_file(&state).unwrap();
    std::fs::write(ck.join(".checkpoint.Whole1.part"), &good).unwrap();
    let resume = ["run", "--resume", "run", "-q"];
    one_line_refusal(d.path(), &resume, &["no checkpoint", "checkpoint.bin"]);
    assert!(stale.exists(), "a refused resume changed it");
    std::fs::write(&state, &good).unwrap();

    // resumed, and killed after its next checkpoint: sieve's stale file is gone, the
    // user's are untouched (a whole checkpoint under a name no checkpoint recorded, too)
    kill_after_checkpoint(d.path(), &resume, Some(&good));
    assert!(!stale.exists(), "the stale .part is left");
    assert!(ck.join(".checkpoint.Whole1.part").exists());
    for name in users {
        assert_eq!(
            std::fs::read_to_string(ck.join(name)).unwrap(),
            "the user's",
            "{name}"
        );
    }
    // a user's file put under the name the checkpoint now on disk recorded for the next
    // write, before that write: it holds no checkpoint, so it is not sieve's and stays
    let taken = decode(&std::fs::read(&state).unwrap())
        .unwrap()
        .text("part.next")
        .unwrap()
        .to_string();
    std::fs::write(ck.join(&taken), "the user's").unwrap();
    // resumed to the end: the uninterrupted run's bits; the checkpoint's own files go, the
    // user's stay, with their directory, and a note says so
    let (code, _, err) = run_full(d.path(), &resume);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("holds files sieve did not write"), "{err}");
    assert!(!state.exists() && !ck.join("fields").exists());
    assert_eq!(
        std::fs::read_to_string(ck.join(&taken)).unwrap(),
        "the user's",
        "the user's file under the recorded name {taken}"
    );
    for name in users {
        assert_eq!(
            std::fs::read_to_string(ck.join(name)).unwrap(),
            "the user's"
        );
    }
    let (a, b) = (d.path().join("ref"), d.path().join("run"));
    let hash = |dir: &Path| json(&dir.join("summary.json"))["state_hash"].clone();
    assert_eq!(hash(&a).as_str().map(str::len), Some(16));
    assert_eq!(hash(&a), hash(&b));
    same_summary(&a, &b, "0.02", "column-b");
    let files = data_files(&a);
    assert_eq!(files, data_files(&b));
    for f in &files {
        assert!(
            std::fs::read(a.join(f)).unwrap() == std::fs::read(b.join(f)).unwrap(),
            "{} differs after resume",
            f.display()
        );
    }
}

#[test]
fn kept_pvti_and_piece_are_checked_and_resumed_without_mpi() {
    let d = tempfile::tempdir().unwrap();
    let mut reference = COLUMN_B.to_vec();
    reference[7] = "ref";
    let (code, _, err) = run_full(d.path(), &reference);
    assert_eq!(code, 0, "{err}");
    let state = killed_run(d.path());
    let fields = state.parent().unwrap().join("fields");
    let mut e = decode(&std::fs::read(&state).unwrap()).unwrap();
    let n = e.u64("progress.next").unwrap() as usize;
    assert!(n >= 1, "no kept output");
    assert!(
        !e.0.contains_key("kept.pieces"),
        "a serial run keeps .vti files"
    );

    // Output 0 as a run under mpirun on one rank keeps it: a .pvti and its piece
    // state_0000_0.vti (the serial .vti, which covers the whole grid).
    let vti = std::fs::read(fields.join("state_0000.vti")).unwrap();
    let head = String::from_utf8_lossy(&vti[..vti.len().min(2000)]).into_owned();
    let image = head
        .split('<')
        .find(|t| t.starts_with("ImageData "))
        .unwrap();
    let attrs = image["ImageData ".len()..].trim_end().trim_end_matches('>');
    let whole = attrs.split("WholeExtent=\"").nth(1).unwrap();
    let whole = &whole[..whole.find('"').unwrap()];
    let pvti = format!(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"PImageData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n  <PImageData {attrs} GhostLevel=\"0\">\n    <Piece Extent=\"{whole}\" Source=\"state_0000_0.vti\"/>\n  </PImageData>\n</VTKFile>\n"
    );
    std::fs::remove_file(fields.join("state_0000.vti")).unwrap();
    std::fs::write(fields.join("state_0000.pvti"), &pvti).unwrap();
    let piece = fields.join("state_0000_0.vti");
    std::fs::write(&piece, &vti).unwrap();
    let crc = |b: &[u8]| crc::Crc::<u64>::new(&crc::CRC_64_XZ).checksum(b);
    let mut lens = e.u64s("kept.len", n).unwrap().to_vec();
    let mut sums = e.u64s("kept.crc", n).unwrap().to_vec();
    (lens[0], sums[0]) = (pvti.len() as u64, crc(pvti.as_bytes()));
    let mut pieces = vec![0; n];
    pieces[0] = 1;
    e.put("kept.len", Value::U64s(lens));
    e.put("kept.crc", Value::U64s(sums));
    e.put("kept.pieces", Value::U64s(pieces));
    e.put("kept.piece.len", Value::U64s(vec![vti.len() as u64]));
    e.put("kept.piece.crc", Value::U64s(vec![crc(&vti)]));
    std::fs::write(&state, encode(&e)).unwrap();

    // the piece one byte longer, then one bit flipped: exit 2, one line naming it
    let mut v = vti.clone();
    v.push(b' ');
    std::fs::write(&piece, &v).unwrap();
    let resume = ["run", "--resume", "run", "-q"];
    one_line_refusal(
        d.path(),
        &resume,
        &["checkpoint.bin", "state_0000_0.vti", "damaged"],
    );
    v.pop();
    let last = v.len() - 1;
    v[last] ^= 1;
    std::fs::write(&piece, &v).unwrap();
    one_line_refusal(d.path(), &resume, &["state_0000_0.vti", "damaged"]);
    std::fs::remove_file(&piece).unwrap();
    one_line_refusal(d.path(), &resume, &["state_0000_0.vti", "missing"]);

    // intact: it resumes, keeps the .pvti and its piece, ends with the uninterrupted bits
    std::fs::write(&piece, &vti).unwrap();
    let (code, _, err) = run_full(d.path(), &resume);
    assert_eq!(code, 0, "{err}");
    let (a, b) = (d.path().join("ref"), d.path().join("run"));
    let got = b.join("fields");
    assert_eq!(
        std::fs::read_to_string(got.join("state_0000.pvti")).unwrap(),
        pvti
    );
    assert!(std::fs::read(got.join("state_0000_0.vti")).unwrap() == vti);
    assert!(!got.join("state_0000.vti").exists());
    let pvd = std::fs::read_to_string(got.join("series.pvd")).unwrap();
    assert!(pvd.contains("file=\"state_0000.pvti\""), "{pvd}");
    assert_eq!(
        pvd.replace("state_0000.pvti", "state_0000.vti"),
        std::fs::read_to_string(a.join("fields/series.pvd")).unwrap()
    );
    let hash = |dir: &Path| json(&dir.join("summary.json"))["state_hash"].clone();
    assert_eq!(hash(&a), hash(&b));
    for f in data_files(&a) {
        if f.ends_with("state_0000.vti") || f.ends_with("series.pvd") {
            continue;
        }
        assert!(
            std::fs::read(a.join(&f)).unwrap() == std::fs::read(b.join(&f)).unwrap(),
            "{} differs after resume",
            f.display()
        );
    }
}

fn sample_entries() -> Vec<u8> {
    let mut e = Entries::default();
    e.put("build", Value::Text("sieve x".into()));
    e.put("progress.next", Value::U64(3));
    e.put("seg.time", Value::F64(0.125));
    e.put("seg.q", Value::F64s(vec![0.1, -0.0, 1e-300, f64::MAX]));
    e.put("kept.len", Value::U64s(vec![1, 2, u64::MAX]));
    // a .pvti with two pieces (written under mpirun), then a .vti
    e.put("kept.pieces", Value::U64s(vec![2, 0, 0]));
    e.put("kept.piece.len", Value::U64s(vec![40, 41]));
    e.put("kept.piece.crc", Value::U64s(vec![7, u64::MAX]));
    encode(&e)
}

#[test]
fn encoding_round_trips_every_bit() {
    let bytes = sample_entries();
    let e = decode(&bytes).unwrap();
    match e.0.get("seg.q") {
        Some(Value::F64s(v)) => {
            assert_eq!(v[1].to_bits(), (-0.0f64).to_bits());
            assert_eq!(v[2], 1e-300);
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(encode(&e), bytes);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 3000, failure_persistence: None, ..ProptestConfig::default() })]

    /// Arbitrary bytes, with and without the magic bytes: an error, never a panic.
    #[test]
    fn arbitrary_bytes_are_rejected_without_panic(mut b in proptest::collection::vec(any::<u8>(), 0..400), magic in any::<bool>()) {
        if magic && b.len() >= 8 {
            b[..8].copy_from_slice(b"SIEVECKP");
        }
        prop_assert!(decode(&b).is_err());
    }

    /// A valid checkpoint mutated (bytes changed, inserted, cut) with its checksum fixed up,
    /// so that the structure checks behind the checksum are reached: no panic, and any file
    /// that decodes re-encodes to itself.
    #[test]
    fn mutated_checkpoints_with_valid_checksum_never_panic(
        edits in proptest::collection::vec((any::<u16>(), any::<u8>(), 0u8..3), 1..6),
    ) {
        let mut b = sample_entries();
        b.truncate(b.len() - 8);
        for (at, byte, kind) in edits {
            let at = usize::from(at) % (b.len() + 1);
            match kind {
                0 if at < b.len() => b[at] = byte,
                1 => b.insert(at, byte),
                _ => b.truncate(at.max(8)),
            }
        }
        let crc = crc::Crc::<u64>::new(&crc::CRC_64_XZ).checksum(&b);
        b.extend_from_slice(&crc.to_le_bytes());
        if let Ok(e) = decode(&b) {
            prop_assert_eq!(encode(&e), b);
        }
    }
}
