//! Hostile command lines (the input sweep of 2026-12): each case below once ran the whole
//! simulation and failed after it, answered with the wrong words, or printed two lines. Each
//! must now end with exit code 2 and one line that names the option or key and what is
//! allowed, before anything is run or written.

use crate::common::run_full;
use std::path::Path;

/// Runs `sieve args` in `dir` and asserts exit 2 with one `error:` line holding each of
/// `needles`; returns the line.
fn refused(dir: &Path, args: &[&str], needles: &[&str]) -> String {
    let (code, out, err) = run_full(dir, args);
    assert_eq!(code, 2, "{args:?}: stdout {out} stderr {err}");
    assert_eq!(err.lines().count(), 1, "{args:?}: one line expected: {err}");
    assert!(err.starts_with("error: "), "{err}");
    for n in needles {
        assert!(err.contains(n), "{args:?}: `{n}` missing in {err}");
    }
    err
}

/// The names in `dir`, sorted.
fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn resume_of_a_path_without_a_name_is_refused() {
    let d = tempfile::tempdir().unwrap();
    // a checkpoint of a run into `./run` must not be taken for `/`'s
    std::fs::create_dir_all(d.path().join(".run.checkpoint")).unwrap();
    for dir in ["/", "..", "a/.."] {
        let err = refused(
            d.path(),
            &["run", "--resume", dir, "-q"],
            &["--resume", "runs/NAME"],
        );
        assert!(!err.contains(".run.checkpoint"), "{err}");
    }
}

#[test]
fn an_out_path_ending_in_dotdot_is_not_called_a_parent_of_the_current_directory() {
    let d = tempfile::tempdir().unwrap();
    let (work, other) = (d.path().join("work"), d.path().join("other"));
    std::fs::create_dir_all(other.join("sub")).unwrap();
    std::fs::create_dir_all(&work).unwrap();
    let out = other.join("sub").join("..");
    let err = refused(
        &work,
        &["run", "column-a", "-q", "--out", out.to_str().unwrap()],
        &["ends in `..`", "other"],
    );
    assert!(!err.contains("current directory"), "{err}");
    // the current directory's parent is still called one
    refused(
        &work,
        &["run", "column-a", "-q", "--out", ".."],
        &["current directory or one of its parents"],
    );
    assert_eq!(names(&other), ["sub"]);
}

#[test]
fn an_out_path_below_a_file_is_refused_in_words() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("file.txt"), "the user's").unwrap();
    // Once: "File exists (os error 17)", exit 1.
    for args in [
        &["run", "column-a", "-q", "--out", "file.txt/sub"][..],
        &["run", "column-a", "-q", "--out", "file.txt/a/b"],
        &[
            "sweep",
            "column-a",
            "--set",
            "run.t_end=0.1,0.2",
            "-q",
            "--out",
            "file.txt/sub",
        ],
        &[
            "record",
            "shear-cell-mixed",
            "--frames",
            "3",
            "--out",
            "file.txt/x.rec",
        ],
    ] {
        refused(d.path(), args, &["file.txt is a file, not a directory"]);
    }
    assert_eq!(
        std::fs::read_to_string(d.path().join("file.txt")).unwrap(),
        "the user's"
    );
    assert_eq!(names(d.path()), ["file.txt"]);
}
