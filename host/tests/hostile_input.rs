//! Hostile command lines (the input sweep of 2026-12): each case below once ran the whole
//! simulation and failed after it, answered with the wrong words, or printed two lines. Each
//! must now end with exit code 2 and one line that names the option or key and what is
//! allowed, before anything is run or written.

use crate::common::{names, run_full};
use sieve::soft_sensor::{record_to_bytes, RecordOptions, Scene};
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

#[test]
fn a_box_past_the_plots_range_is_refused_before_the_run() {
    let d = tempfile::tempdir().unwrap();
    fn run(set: &str) -> [&str; 7] {
        ["run", "shear-cell-mixed", "-q", "--set", set, "--out", "r"]
    }
    // Once: the whole run, then exit 1 at the first plot ("values out of the plottable
    // range (0e0 .. 1e151)").
    refused(
        d.path(),
        &run("grid.upper=[1e151,0.025]"),
        &["grid.upper[0] = 1e151", "1e150"],
    );
    refused(
        d.path(),
        &run("grid.lower=[-1e200,0]"),
        &["grid.lower[0] = -1e200", "1e150"],
    );
    // a span lost against its coordinates: no plot can tell it from a point
    refused(
        d.path(),
        &[
            "run",
            "shear-cell-mixed",
            "-q",
            "--set",
            "grid.lower=[1e6,0]",
            "--set",
            "grid.upper=[1000000.0000000001,0.025]",
            "--out",
            "r",
        ],
        &["grid.upper[0]", "1e-15"],
    );
    assert!(names(d.path()).is_empty(), "{:?}", names(d.path()));
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

#[test]
fn grid_and_fields_options_are_named_with_their_range() {
    let d = tempfile::tempdir().unwrap();
    // Once: `grid.cells: expected a list, got "[1e20,1]"`.
    for grid in ["99999999999999999999x1", "65537x2", "0x4"] {
        refused(
            d.path(),
            &[
                "run",
                "shear-cell-mixed",
                "-q",
                "--grid",
                grid,
                "--out",
                "r",
            ],
            &["--grid = ", "1..=65536 cells per axis"],
        );
    }
    // Once: the same line twice, blaming output.fields of the scene file.
    for fields in [",", "phihat,,c", "bogus,bogus"] {
        let err = refused(
            d.path(),
            &["run", "column-a", "-q", "--fields", fields, "--out", "r"],
            &["--fields", "phihat, phi, c, T, u, p, volume"],
        );
        assert!(!err.contains("column-a.toml"), "{err}");
    }
    assert!(names(d.path()).is_empty());
}

#[test]
fn a_hopper_centre_outside_the_box_is_one_line() {
    let d = tempfile::tempdir().unwrap();
    // Once: a second line, outlet_width "< -2e300 [m]", measured from the refused centre.
    for center in ["[1e300,0.25]", "[-1,-1]", "[100,100]"] {
        let set = format!("geometry.center={center}");
        let err = refused(
            d.path(),
            &["run", "hopper", "-q", "--set", &set, "--out", "r"],
            &["geometry.center[0]", "the outlet's centre inside the box"],
        );
        assert!(!err.contains("outlet_width"), "{err}");
    }
}

#[test]
fn sweep_counts_conflicts_and_plot_keys_are_refused_before_running() {
    let d = tempfile::tempdir().unwrap();
    let hundred = (1..=100)
        .map(|i| i.to_string())
        .collect::<Vec<_>>()
        .join(",");
    // `axes` swept keys of 100 values each
    let sweep = |axes: usize| -> Vec<String> {
        let mut a: Vec<String> = ["sweep", "column-a", "--out", "s"].map(String::from).into();
        for i in 0..axes {
            a.extend(["--set".to_string(), format!("k{i}={hundred}")]);
        }
        a
    };
    // Once: 18446744073709551615 (the saturated count) for both.
    for (axes, count) in [(11, "1e22"), (20, "more than 1e38")] {
        let args = sweep(axes);
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        refused(
            d.path(),
            &args,
            &[&format!("{count} combinations"), "at most 10000"],
        );
    }
    // Once: the fixed value silently replaced by the swept ones.
    for order in [
        ["run.t_end=0.1", "run.t_end=0.2,0.3"],
        ["run.t_end=0.2,0.3", "run.t_end=0.1"],
    ] {
        refused(
            d.path(),
            &[
                "sweep", "column-a", "--set", order[0], "--set", order[1], "-q", "--out", "s",
            ],
            &["--set run.t_end", "fixed value and swept values"],
        );
    }
    // Once: two runs, then no sweep.png and exit 0.
    refused(
        d.path(),
        &[
            "sweep",
            "column-a",
            "--set",
            "run.t_end=0.1,0.2",
            "--plot",
            "bogus",
            "-q",
            "--out",
            "s",
        ],
        &["--plot = bogus", "psi_final", "mass_rel_drift", "flow.*"],
    );
    refused(
        d.path(),
        &[
            "sweep",
            "column-a",
            "--set",
            "run.t_end=0.1,0.2",
            "--plot",
            "flow.bogus",
            "--collect",
            "--out",
            "s",
        ],
        &[
            "--plot = flow.bogus",
            "flow.max_packing",
            "flow.outlet.steady_rate",
        ],
    );
    assert!(names(d.path()).is_empty(), "{:?}", names(d.path()));
}

#[test]
fn replay_and_record_name_smoothing_and_rate() {
    let d = tempfile::tempdir().unwrap();
    let mut o = RecordOptions::new(Scene::ShearCell);
    o.frames = 30;
    std::fs::write(d.path().join("a.rec"), record_to_bytes(&o).unwrap().0).unwrap();
    // Once: "a.rec: config: the smoothing factor must be in (0, 1]" (1e-300 as f32 is 0).
    for w in ["1e-300", "0", "1.5"] {
        let err = refused(
            d.path(),
            &["replay", "a.rec", "--smoothing", w],
            &["--smoothing", "1e-38 <= W <= 1"],
        );
        assert!(!err.contains("a.rec"), "{err}");
    }
    // Once: 1e-300 Hz stepped the truth, then exit 1 ("the truth did not reach t =
    // 9.999999999999999e299 s"); 1e9 Hz blamed the scene file without naming --rate.
    let record = |scene: &'static str, hz: &'static str| {
        [
            "record", scene, "--frames", "3", "--rate", hz, "--out", "r.rec",
        ]
    };
    for scene in ["shear-cell-mixed", "idealised-shear-cell"] {
        for hz in ["1e-300", "1e9", "0", "-1"] {
            refused(
                d.path(),
                &record(scene, hz),
                &["--rate", "1e-30 <= HZ <=", "--cpu-mhz"],
            );
        }
    }
    // Within those bounds but too slow for the scene's truth (2^24 steps per frame): refused
    // before the truth steps (it once stepped for minutes).
    let start = std::time::Instant::now();
    refused(
        d.path(),
        &record("shear-cell-mixed", "1e-6"),
        &["--rate", "for this scene", "at most 16777216 a frame"],
    );
    refused(
        d.path(),
        &record("idealised-shear-cell", "1e-20"),
        &[
            "--rate = 1e-20",
            "for this scene",
            "at most 1048576 a frame",
        ],
    );
    assert!(start.elapsed().as_secs() < 30, "{:?}", start.elapsed());
    assert_eq!(names(d.path()), ["a.rec"]);
}
