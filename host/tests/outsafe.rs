//! Never lose a user's data (issue 10): sieve replaces only directories it wrote, never the
//! current directory or its parents; two runs into one DIR exclude each other; SIGINT/SIGTERM
//! and a numerical failure keep the partial run (summary status "interrupted"/"failed", exit
//! 130/143/3); what a SIGKILL leaves is removed by the next run into the same DIR.
//! docs/outputs.md, "Where sieve writes and what it never touches".

use crate::common::{names, run_full};

use assert_cmd::cargo::CommandCargoExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

fn sieve_in(dir: &Path) -> Command {
    let mut c = Command::cargo_bin("sieve").expect("binary sieve");
    c.current_dir(dir);
    c
}

fn summary(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("summary.json")).expect("summary.json");
    serde_json::from_str(&text).expect("valid JSON")
}

/// No staging, set-aside or lock file left in `dir`.
fn assert_no_debris(dir: &Path) {
    let left: Vec<String> = names(dir)
        .into_iter()
        .filter(|n| n.contains(".tmp-") || n.contains(".old-") || n.ends_with(".lock"))
        .collect();
    assert!(
        left.is_empty(),
        "debris left in {}: {left:?}",
        dir.display()
    );
}

fn one_error_line(err: &str, needles: &[&str]) {
    assert_eq!(err.lines().count(), 1, "one line expected: {err}");
    for n in needles {
        assert!(err.contains(n), "`{n}` missing in {err}");
    }
}

#[test]
fn a_directory_sieve_did_not_write_is_never_replaced() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path();
    std::fs::create_dir(p.join("mydata")).unwrap();
    std::fs::write(p.join("mydata/notes.txt"), "mine").unwrap();
    for args in [
        &["run", "column-a", "--out", "mydata", "-q"][..],
        &[
            "converge", "column-a", "--levels", "10,20", "--t-end", "0.2", "--out", "mydata", "-q",
        ],
    ] {
        let (code, _, err) = run_full(p, args);
        assert_eq!(code, 2, "{args:?}: {err}");
        one_error_line(
            &err,
            &["mydata: exists and was not written by sieve", "--out"],
        );
        assert_eq!(
            std::fs::read_to_string(p.join("mydata/notes.txt")).unwrap(),
            "mine"
        );
        assert_eq!(names(p), ["mydata"], "{args:?} created something");
    }
    // An empty existing directory is fine; the run marks it.
    std::fs::create_dir(p.join("empty")).unwrap();
    let (code, _, err) = run_full(p, &["run", "column-a", "--out", "empty", "-q"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(summary(&p.join("empty"))["status"], "complete");
    let marker: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(p.join("empty/.sieve-run")).unwrap())
            .unwrap();
    assert_eq!(marker["written_by"], "sieve");
    let files = marker["files"].as_array().unwrap();
    assert!(files.iter().any(|f| f == "summary.json"), "{marker}");
    assert!(
        files.iter().any(|f| f == "fields/state_0015.vti"),
        "{marker}"
    );
    // A file the user put into a run directory, however deep, stops the next run...
    std::fs::write(p.join("empty/fields/mine.txt"), "x").unwrap();
    let (code, _, err) = run_full(p, &["run", "column-a", "--out", "empty", "-q"]);
    assert_eq!(code, 2, "{err}");
    one_error_line(&err, &["fields/mine.txt, which sieve did not write"]);
    assert!(p.join("empty/fields/mine.txt").exists());
    // ... and without it the run directory is replaced; `sieve plot` replaces plots/ of a run
    // directory (its own marker then) and the run after it still recognises everything.
    std::fs::remove_file(p.join("empty/fields/mine.txt")).unwrap();
    for args in [
        &["run", "column-a", "--out", "empty", "-q"][..],
        &["plot", "empty"],
        &["plot", "empty"],
        &["run", "column-a", "--out", "empty", "-q"],
    ] {
        let (code, _, err) = run_full(p, args);
        assert_eq!(code, 0, "{args:?}: {err}");
    }
    // `sieve plot` never deletes a user's file in plots/.
    std::fs::write(p.join("empty/plots/figure-for-paper.png"), "x").unwrap();
    let (code, _, err) = run_full(p, &["plot", "empty"]);
    assert_eq!(code, 2, "{err}");
    assert!(p.join("empty/plots/figure-for-paper.png").exists());
    assert_no_debris(p);
    assert_no_debris(&p.join("empty"));
}

#[test]
fn a_run_directory_of_an_older_sieve_is_still_recognised() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path();
    let (code, _, err) = run_full(p, &["run", "column-a", "--out", "old", "-q"]);
    assert_eq!(code, 0, "{err}");
    // What sieve wrote before directories were marked: the same files, no marker.
    std::fs::remove_file(p.join("old/.sieve-run")).unwrap();
    let (code, _, err) = run_full(p, &["run", "column-a", "--out", "old", "-q"]);
    assert_eq!(code, 0, "{err}");
    std::fs::remove_file(p.join("old/.sieve-run")).unwrap();
    std::fs::write(p.join("old/notes.txt"), "mine").unwrap();
    let (code, _, err) = run_full(p, &["run", "column-a", "--out", "old", "-q"]);
    assert_eq!(code, 2, "{err}");
    assert!(p.join("old/notes.txt").exists());
}

#[test]
fn the_current_directory_and_its_parents_are_refused_before_anything_is_created() {
    let d = tempfile::tempdir().unwrap();
    let work = d.path().join("a/b");
    std::fs::create_dir_all(&work).unwrap();
    std::fs::write(work.join("keep.txt"), "x").unwrap();
    let top = d.path().to_str().unwrap().to_string();
    for out in [".", "..", "../..", "/", "./", "../b", top.as_str()] {
        let (code, _, err) = run_full(&work, &["run", "column-a", "--out", out, "-q"]);
        assert_eq!(code, 2, "--out {out}: {err}");
        one_error_line(&err, &["current directory or one of its parents", "--out"]);
        assert_eq!(names(&work), ["keep.txt"], "--out {out}");
        assert_eq!(names(&d.path().join("a")), ["b"], "--out {out}");
        assert_eq!(names(d.path()), ["a"], "--out {out}");
    }
}

#[test]
fn a_second_run_into_a_locked_directory_exits_2_at_once() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path();
    // The lock a running sieve holds (this process plays that run).
    let lock = sieve::output::target::Lock::take(&p.join("busy")).expect("lock");
    let start = Instant::now();
    let (code, _, err) = run_full(p, &["run", "column-a", "--out", "busy", "-q"]);
    assert_eq!(code, 2, "{err}");
    one_error_line(
        &err,
        &[
            "busy: is being written by another sieve run",
            &format!("(pid {})", std::process::id()),
            "choose another --out",
        ],
    );
    assert!(start.elapsed() < Duration::from_secs(10));
    assert!(!p.join("busy").exists());
    drop(lock);
    assert_eq!(
        names(p),
        Vec::<String>::new(),
        "the lock file goes with the lock"
    );
    let (code, _, err) = run_full(p, &["run", "column-a", "--out", "busy", "-q"]);
    assert_eq!(code, 0, "{err}");
    assert_no_debris(p);
}

/// A column-a run of minutes: 2000 cells to t = 2000 s, an output every second of simulated
/// time (a tenth of a second of wall time each).
fn long_run(dir: &Path, out: &str) -> Child {
    sieve_in(dir)
        .args([
            "run",
            "column-a",
            "--cells",
            "2000",
            "--t-end",
            "2000",
            "--set",
            "run.output_interval=1",
            "--out",
            out,
            "-q",
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn sieve")
}

/// Waits until the staging directory of `out` in `dir` holds its third VTK file.
fn wait_for_outputs(dir: &Path, out: &str, child: &mut Child) -> PathBuf {
    let start = Instant::now();
    loop {
        assert!(child.try_wait().unwrap().is_none(), "the run ended early");
        let staged = names(dir)
            .into_iter()
            .find(|n| n.starts_with(&format!(".{out}.tmp-")))
            .map(|n| dir.join(n));
        if let Some(s) = staged {
            if s.join("fields/state_0002.vti").exists() {
                return s;
            }
        }
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "no outputs after 60 s"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn kill(child: &Child, signal: &str) {
    let ok = Command::new("kill")
        .args([signal, &child.id().to_string()])
        .status()
        .expect("kill")
        .success();
    assert!(ok, "kill {signal}");
}

fn finish(child: Child) -> (i32, String) {
    let out = child.wait_with_output().expect("wait");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn sigint_and_sigterm_keep_the_partial_run() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path();
    for (signal, code_expected, name) in [("-INT", 130, "SIGINT"), ("-TERM", 143, "SIGTERM")] {
        let out = format!("r{code_expected}");
        let mut child = long_run(p, &out);
        wait_for_outputs(p, &out, &mut child);
        // Meanwhile a second run into the same DIR is refused at once with the first's pid.
        let (code, _, err) = run_full(p, &["run", "column-a", "--out", &out, "-q"]);
        assert_eq!(code, 2, "{err}");
        one_error_line(
            &err,
            &[
                "is being written by another sieve run",
                &format!("(pid {})", child.id()),
            ],
        );
        let sent = Instant::now();
        kill(&child, signal);
        let (code, err) = finish(child);
        assert!(sent.elapsed() < Duration::from_secs(20), "slow to stop");
        assert_eq!(code, code_expected, "{err}");
        one_error_line(
            &err,
            &[
                &format!("interrupted by {name} at t = "),
                "step ",
                &format!("partial output kept in {out}"),
            ],
        );
        let dir = p.join(&out);
        let s = summary(&dir);
        assert_eq!(s["status"], "interrupted", "{s}");
        assert_eq!(s["stopped"]["signal"], name);
        let t = s["stopped"]["t"].as_f64().unwrap();
        assert!(t > 2.0 && t < 2000.0, "{t}");
        assert_eq!(s["steps"], s["stopped"]["step"]);
        // What was written stays, consistent: one series row and one VTK file per output
        // time reached, final.csv at the stop, and the mass conserved to round-off.
        let rows = std::fs::read_to_string(dir.join("series.csv"))
            .unwrap()
            .lines()
            .count()
            - 1;
        assert!(rows >= 3, "{rows}");
        assert!(dir
            .join(format!("fields/state_{:04}.vti", rows - 1))
            .exists());
        assert!(!dir.join(format!("fields/state_{rows:04}.vti")).exists());
        assert_eq!(
            std::fs::read_to_string(dir.join("final.csv"))
                .unwrap()
                .lines()
                .count(),
            2001
        );
        // Round-off: each step changes the total by at most about one ulp of it (the update
        // of every cell rounds by half an ulp of its own content), so the bound grows with the
        // steps taken before the signal (18,003 steps: 1.2e-12 seen, bound 4.0e-12).
        let steps = s["steps"].as_f64().unwrap();
        let drift = s["mass_rel_drift"].as_f64().unwrap();
        assert!(
            drift < f64::EPSILON * steps.max(1000.0),
            "{drift} after {steps} steps: {s}"
        );
        assert_no_debris(p);
    }
}

#[test]
fn what_a_sigkill_leaves_is_removed_by_the_next_run() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path();
    let mut child = long_run(p, "k");
    let staged = wait_for_outputs(p, "k", &mut child);
    kill(&child, "-KILL");
    let (code, _) = finish(child);
    assert_eq!(code, -1, "killed by a signal");
    assert!(staged.exists(), "SIGKILL cannot clean up");
    // Debris of the kinds sieve leaves, and one directory that only looks like it.
    let marker = std::fs::read_to_string(staged.join(".sieve-run")).unwrap();
    std::fs::create_dir_all(p.join(".k.old-AbCdEf/old")).unwrap();
    std::fs::write(p.join(".k.old-AbCdEf/old/.sieve-run"), &marker).unwrap();
    std::fs::write(p.join(".k.old-AbCdEf/old/summary.json"), "{}").unwrap();
    std::fs::create_dir(p.join(".k.tmp-users")).unwrap();
    std::fs::write(p.join(".k.tmp-users/data.txt"), "mine").unwrap();
    let (code, _, err) = run_full(p, &["run", "column-a", "--out", "k", "-q"]);
    assert_eq!(code, 0, "{err}");
    one_error_line(
        &err,
        &[
            "removed 2 directories left in",
            "by an interrupted sieve run",
        ],
    );
    assert!(!staged.exists());
    assert!(!p.join(".k.old-AbCdEf").exists());
    assert!(p.join(".k.tmp-users/data.txt").exists(), "not sieve's");
    assert_eq!(summary(&p.join("k"))["status"], "complete");
    let (code, _, err) = run_full(p, &["run", "column-a", "--out", "k", "-q"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(err, "", "nothing left to remove");
}

#[test]
fn a_non_finite_state_stops_the_run_with_exit_3_and_keeps_it() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path();
    // Issue 10: grid.upper = [1e-160] gave dt = 1.8e308, phi NaN and exit 0.
    let (code, _, err) = run_full(
        p,
        &[
            "run",
            "column-a",
            "--set",
            "grid.upper=[1e-160]",
            "--out",
            "tiny",
            "-q",
        ],
    );
    if code == 2 {
        // Refused before the run (a pre-run guard): better still; nothing created.
        assert_eq!(names(p), Vec::<String>::new());
        return;
    }
    assert_eq!(code, 3, "{err}");
    let line = err
        .lines()
        .find(|l| l.starts_with("error: "))
        .expect("an error line");
    for n in [
        "the run failed numerically at step ",
        "phi = ",
        "in cell 0 [0]",
        "partial output kept in tiny",
    ] {
        assert!(line.contains(n), "`{n}` missing in {line}");
    }
    let s = summary(&p.join("tiny"));
    assert_eq!(s["status"], "failed", "{s}");
    assert_eq!(s["stopped"]["field"], "phi");
    assert_eq!(s["stopped"]["cell"], 0);
    assert!(s["stopped"]["step"].as_u64().unwrap() >= 1);
    assert!(p.join("tiny/final.csv").exists());
    assert!(p.join("tiny/series.csv").exists());
    assert_no_debris(p);
}

/// Waits until `dir` holds the staging directory of `out`.
fn wait_for_staging(dir: &Path, out: &str, child: &mut Child) -> PathBuf {
    let start = Instant::now();
    loop {
        assert!(
            child.try_wait().unwrap().is_none(),
            "the command ended early"
        );
        if let Some(n) = names(dir)
            .into_iter()
            .find(|n| n.starts_with(&format!(".{out}.tmp-")))
        {
            return dir.join(n);
        }
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "no staging directory"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn a_coupled_flow_run_stops_on_sigterm_and_keeps_its_flow_block() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path();
    let mut child = sieve_in(p)
        .args(["run", "column-collapse", "--out", "cc", "-q"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let staged = wait_for_staging(p, "cc", &mut child);
    // The t = 0 output, then some coupled steps.
    let start = Instant::now();
    while !staged.join("fields/state_0000.vti").exists() {
        assert!(start.elapsed() < Duration::from_secs(60));
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(300));
    kill(&child, "-TERM");
    let (code, err) = finish(child);
    assert_eq!(code, 143, "{err}");
    one_error_line(
        &err,
        &["interrupted by SIGTERM", "partial output kept in cc"],
    );
    let s = summary(&p.join("cc"));
    assert_eq!(s["status"], "interrupted", "{s}");
    assert!(s["stopped"]["step"].as_u64().unwrap() > 0, "{s}");
    assert_eq!(s["flow"]["equations"], "coupled");
    assert_eq!(s["flow"]["flow_steps"], s["steps"]);
    assert!(s["stopped"]["t"].as_f64().unwrap() < 1.0);
    assert!(p.join("cc/final.csv").exists() && p.join("cc/profiles.csv").exists());
    assert_no_debris(p);
}

#[test]
fn an_interrupted_convergence_study_writes_nothing_and_leaves_nothing() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path();
    let mut child = sieve_in(p)
        .args([
            "converge",
            "column-a",
            "--levels",
            "2000,4000",
            "--t-end",
            "2000",
            "--out",
            "conv",
            "-q",
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_for_staging(p, "conv", &mut child);
    std::thread::sleep(Duration::from_millis(300));
    kill(&child, "-INT");
    let (code, err) = finish(child);
    assert_eq!(code, 130, "{err}");
    one_error_line(&err, &["interrupted by SIGINT at t = ", "nothing written"]);
    assert_eq!(names(p), Vec::<String>::new());
}

#[test]
fn record_never_writes_over_a_file_it_did_not_write() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path();
    std::fs::write(p.join("notes.txt"), "mine").unwrap();
    let args = |out: &str| {
        [
            "record",
            "idealised-shear-cell",
            "--frames",
            "3",
            "--out",
            out,
        ]
        .map(String::from)
    };
    let out = sieve_in(p).args(args("notes.txt")).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    one_error_line(&err, &["notes.txt: exists and was not written by sieve"]);
    assert_eq!(
        std::fs::read_to_string(p.join("notes.txt")).unwrap(),
        "mine"
    );
    let out = sieve_in(p).args(args(".")).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    // A recording sieve wrote is replaced.
    for _ in 0..2 {
        let out = sieve_in(p).args(args("a.rec")).output().unwrap();
        assert!(out.status.success(), "{out:?}");
    }
    assert_eq!(names(p), ["a.rec", "notes.txt"]);
}
