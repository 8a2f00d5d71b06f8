//! `sieve sweep` (issue 12): the product of `--set` values as independent runs, the table of
//! their summaries, and the Slurm array path (one task per combination, then `--collect`).

use assert_cmd::Command;
use std::path::Path;

fn sieve(dir: &Path) -> Command {
    let mut c = Command::cargo_bin("sieve").expect("binary sieve");
    c.current_dir(dir).env_remove("SLURM_ARRAY_TASK_ID");
    c
}

fn run(c: &mut Command) -> (i32, String, String) {
    let out = c.output().expect("run sieve");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// A 2 x 2 sweep of the exact column (short, so each run takes milliseconds).
const SETS: [&str; 6] = [
    "--set",
    "grid.cells=[40],[80]",
    "--set",
    "material.s0=0.5,2",
    "--set",
    "run.t_end=0.4",
];

fn table(dir: &Path) -> Vec<serde_json::Value> {
    let text = std::fs::read_to_string(dir.join("sweep.json")).expect("sweep.json");
    let v: serde_json::Value = serde_json::from_str(&text).expect("JSON");
    v["runs"].as_array().expect("runs").clone()
}

fn hash(row: &serde_json::Value) -> String {
    row["summary"]["state_hash"]
        .as_str()
        .expect("state_hash")
        .to_string()
}

#[test]
fn sweep_runs_every_combination_and_tabulates_them() {
    let d = tempfile::tempdir().unwrap();
    let (code, out, err) = run(sieve(d.path())
        .args(["sweep", "column-a", "--jobs", "2", "--out", "sw"])
        .args(SETS));
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("4 runs"), "{out}");
    assert_eq!(err.lines().filter(|l| l.contains("done in")).count(), 4);
    let rows = table(&d.path().join("sw"));
    assert_eq!(rows.len(), 4);
    // First key slowest: (40, 0.5), (40, 2), (80, 0.5), (80, 2).
    let expect = [
        ("[40]", "0.5"),
        ("[40]", "2"),
        ("[80]", "0.5"),
        ("[80]", "2"),
    ];
    for (i, (row, (cells, s0))) in rows.iter().zip(expect).enumerate() {
        assert_eq!(row["index"], i);
        assert_eq!(row["set"]["grid.cells"], cells);
        assert_eq!(row["set"]["material.s0"], s0);
        assert_eq!(row["summary"]["cell_count"], if i < 2 { 40 } else { 80 });
        assert_eq!(row["summary"]["t_end"], 0.4);
    }
    // The swept value acts: column-a's exact Psi(t) = 1 - |S| t with |S| = S0 (model.md 7.1a).
    for (row, s0) in rows.iter().zip([0.5, 2.0, 0.5, 2.0]) {
        let psi_exact = row["summary"]["exact.psi_exact"].as_f64().unwrap();
        assert!(
            (psi_exact - (1.0 - s0 * 0.4f64).max(0.0)).abs() < 1e-12,
            "{row}"
        );
    }
    // A sweep run is the plain run, bit for bit.
    let (code, _, err) = run(sieve(d.path()).args([
        "run",
        "column-a",
        "--set",
        "grid.cells=[80]",
        "--set",
        "material.s0=2",
        "--set",
        "run.t_end=0.4",
        "--out",
        "plain",
        "--quiet",
    ]));
    assert_eq!(code, 0, "{err}");
    let plain: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(d.path().join("plain/summary.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(hash(&rows[3]), plain["state_hash"].as_str().unwrap());
    // The CSV holds the same rows; the picture is drawn.
    let csv = std::fs::read_to_string(d.path().join("sw/sweep.csv")).unwrap();
    assert_eq!(csv.lines().count(), 5);
    assert!(
        csv.starts_with("index,run,status,grid.cells,material.s0,"),
        "{csv}"
    );
    assert!(csv.lines().nth(4).unwrap().contains(&hash(&rows[3])));
    for png in ["sw/sweep.png", "sw/sweep_psi.png"] {
        assert!(
            std::fs::metadata(d.path().join(png)).unwrap().len() > 1000,
            "{png}"
        );
    }
}

#[test]
fn slurm_array_tasks_then_collect_give_the_same_table() {
    let d = tempfile::tempdir().unwrap();
    let (code, out, _) = run(sieve(d.path())
        .args(["sweep", "column-a", "--list"])
        .args(SETS));
    assert_eq!(code, 0);
    assert_eq!(
        out,
        "0\tgrid.cells=[40] material.s0=0.5\n1\tgrid.cells=[40] material.s0=2\n\
         2\tgrid.cells=[80] material.s0=0.5\n3\tgrid.cells=[80] material.s0=2\n"
    );
    // Each task as Slurm starts it: the index from the environment, tasks in any order.
    for task in ["2", "0", "3"] {
        let (code, _, err) = run(sieve(d.path())
            .env("SLURM_ARRAY_TASK_ID", task)
            .args(["sweep", "column-a", "--out", "sw", "--quiet"])
            .args(SETS));
        assert_eq!(code, 0, "task {task}: {err}");
        assert!(d
            .path()
            .join(format!("sw/run-000{task}/summary.json"))
            .is_file());
    }
    assert!(!d.path().join("sw/run-0001").exists());
    assert!(
        !d.path().join("sw/sweep.csv").exists(),
        "a task writes no table"
    );
    let (code, out, _) = run(sieve(d.path())
        .args(["sweep", "column-a", "--out", "sw", "--collect"])
        .args(SETS));
    assert_eq!(code, 0);
    assert!(out.contains("1 combinations have no run yet"), "{out}");
    assert_eq!(table(&d.path().join("sw"))[1]["status"], "missing");
    let (code, _, _) = run(sieve(d.path())
        .args(["sweep", "column-a", "--out", "sw", "--task", "1", "--quiet"])
        .args(SETS));
    assert_eq!(code, 0);
    run(sieve(d.path())
        .args(["sweep", "column-a", "--out", "sw", "--collect"])
        .args(SETS));
    let tasks = table(&d.path().join("sw"));
    // The same sweep on the local cores gives the same states.
    let (code, _, err) = run(sieve(d.path())
        .args(["sweep", "column-a", "--out", "local", "--quiet", "-j", "2"])
        .args(SETS));
    assert_eq!(code, 0, "{err}");
    let local = table(&d.path().join("local"));
    assert_eq!(tasks.len(), 4);
    for (a, b) in tasks.iter().zip(&local) {
        assert_eq!(a["status"], "done");
        assert_eq!(hash(a), hash(b));
    }
}

#[test]
fn a_sweep_that_cannot_succeed_says_so_before_it_starts() {
    let d = tempfile::tempdir().unwrap();
    // One bad value among good ones: one line naming the key and range, nothing written.
    let (code, _, err) = run(sieve(d.path()).args([
        "sweep",
        "column-a",
        "--set",
        "numerics.courant=0.5,1.5",
        "--out",
        "sw",
    ]));
    assert_eq!(code, 2, "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("numerics.courant"), "{err}");
    assert!(!d.path().join("sw").exists());
    // A task index beyond the list.
    let (code, _, err) = run(sieve(d.path())
        .args(["sweep", "column-a", "--task", "9", "--out", "sw"])
        .args(SETS));
    assert_eq!(code, 2);
    assert!(err.contains("allowed 0..=3"), "{err}");
    // A directory sieve did not write is never written into.
    std::fs::create_dir(d.path().join("mine")).unwrap();
    std::fs::write(d.path().join("mine/notes.txt"), "keep me").unwrap();
    let (code, _, err) = run(sieve(d.path())
        .args(["sweep", "column-a", "--out", "mine"])
        .args(SETS));
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("not written by sieve"), "{err}");
    assert_eq!(
        std::fs::read_dir(d.path().join("mine")).unwrap().count(),
        1,
        "only notes.txt"
    );
    // Never the current directory or a parent of it, even an empty one.
    let empty = d.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    for out in [".", ".."] {
        let (code, _, err) = run(sieve(&empty)
            .args(["sweep", "column-a", "--out", out])
            .args(SETS));
        assert_eq!(code, 2, "--out {out}: {err}");
        assert_eq!(err.lines().count(), 1, "{err}");
        assert_eq!(
            std::fs::read_dir(&empty).unwrap().count(),
            0,
            "--out {out} wrote"
        );
    }
}

/// A run that printed warnings (here a silo orifice too narrow for its grid and its grains,
/// docs/silo.md "Narrow orifices") is done, and the sweep says how many warnings and where
/// they are; the table carries them in the `warnings` column of its summary.
#[test]
fn a_sweep_says_which_runs_were_warned() {
    let d = tempfile::tempdir().unwrap();
    let (code, _, err) = run(sieve(d.path()).args([
        "sweep",
        "silo",
        "--set",
        "boundary.flow.z_low.outlet.width=0.012,0.04",
        "--set",
        "grid.cells=[15,50]",
        "--set",
        "run.t_end=0.005",
        "--jobs",
        "1",
        "--out",
        "sw",
    ]));
    assert_eq!(code, 0, "{err}");
    let line = |i: usize| {
        err.lines()
            .find(|l| l.contains(&format!("run-000{i} (")))
            .unwrap_or_else(|| panic!("no line for run {i}: {err}"))
    };
    assert!(
        line(0).contains("done in")
            && line(0).contains("with 2 warnings (run-0000.log, summary.json)"),
        "{err}"
    );
    assert!(
        line(1).contains("done in") && !line(1).contains("warning"),
        "{err}"
    );
    let rows = table(&d.path().join("sw"));
    let warned = rows[0]["summary"]["warnings"].as_str().unwrap_or("");
    assert!(
        warned.contains("cells wide") && warned.contains("grain diameters"),
        "{rows:?}"
    );
    assert!(rows[1]["summary"].get("warnings").is_none(), "{rows:?}");
    assert!(d.path().join("sw/run-0000.log").is_file());
    assert!(!d.path().join("sw/run-0001.log").exists());
}

/// A 2-run sweep of the exact column, built once for the property below.
fn fuzz_sweep() -> &'static Path {
    static DIR: std::sync::OnceLock<tempfile::TempDir> = std::sync::OnceLock::new();
    DIR.get_or_init(|| {
        let d = tempfile::tempdir().unwrap();
        let (code, _, err) = run(sieve(d.path()).args([
            "sweep",
            "column-a",
            "--quiet",
            "--out",
            "sw",
            "--set",
            "grid.cells=[40]",
            "--set",
            "material.s0=0.5,2",
            "--set",
            "run.t_end=0.2",
        ]));
        assert_eq!(code, 0, "{err}");
        d
    })
    .path()
}

proptest::proptest! {
    #![proptest_config(proptest::test_runner::Config {
        cases: std::env::var("SIEVE_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(1000),
        ..proptest::test_runner::Config::default()
    })]

    /// `sieve sweep --collect` reads every run's summary.json and series.csv, which a user or
    /// a crashed disk may have damaged: bytes flipped, cut, inserted, or a number rewritten to
    /// a hostile value. Never a panic; an error is one line naming the damaged file; the
    /// run directories are left as they were.
    #[test]
    fn collect_never_panics_on_damaged_run_files(which in 0usize..3, at in proptest::num::usize::ANY,
                                                 how in 0u8..4, byte in proptest::num::u8::ANY,
                                                 number in proptest::sample::select(vec!["nan", "1e308", "-1e308", "-1", "0", "1e-320", "18446744073709551616", "\"x\"", "[]", "{}", "null", "true"])) {
        let root = fuzz_sweep();
        let out = root.join("sw");
        let files = [
            out.join("run-0000/summary.json"),
            out.join("run-0001/summary.json"),
            out.join("run-0000/series.csv"),
        ];
        let f = &files[which];
        let orig = std::fs::read(f).expect("read");
        let mut b = orig.clone();
        // the whole number around a position rewritten, or a byte flipped, a cut, an insert
        let is_num = |c: u8| c.is_ascii_digit() || c == b'.' || c == b'e' || c == b'-';
        crate::common::damage(&mut b, (how, at, byte), number, is_num);
        std::fs::write(f, &b).expect("write");
        let before: Vec<Vec<u8>> = files.iter().map(|p| std::fs::read(p).expect("read")).collect();
        let opts = sieve::sweep::SweepOptions {
            scene: "column-a".into(),
            axes: vec![sieve::sweep::Axis { key: "material.s0".into(), values: vec!["0.5".into(), "2".into()] }],
            fixed: vec!["grid.cells=[40]".into(), "run.t_end=0.2".into()],
            out: out.clone(),
            jobs: 1,
            task: None,
            plot: "psi_final".into(),
            fit: None,
            quiet: true,
        };
        let r = std::panic::catch_unwind(|| sieve::sweep::collect(&opts));
        let after: Vec<Vec<u8>> = files.iter().map(|p| std::fs::read(p).expect("read")).collect();
        std::fs::write(f, &orig).expect("restore");
        proptest::prop_assert!(before == after, "collect changed a run's files");
        match r {
            Err(_) => proptest::prop_assert!(false, "panic on {} ({how}, {at}, {byte}, {number})", f.display()),
            Ok(Err(e)) => {
                let e = e.to_string();
                proptest::prop_assert_eq!(e.lines().count(), 1, "{}", e);
                let name = f.file_name().unwrap().to_string_lossy().into_owned();
                proptest::prop_assert!(e.contains(&name), "{} does not name {}", e, name);
            }
            Ok(Ok(_)) => {}
        }
    }
}

/// A collect job inside the array's allocation inherits SLURM_ARRAY_TASK_ID: it is no task
/// (it was refused as "--collect cannot be used with --task", a flag the user never passed),
/// and a variable that is not an index is refused naming the variable.
#[test]
fn the_slurm_variable_names_itself_and_leaves_collect_alone() {
    let d = tempfile::tempdir().unwrap();
    let (code, _, err) = run(sieve(d.path())
        .env("SLURM_ARRAY_TASK_ID", "0")
        .args(["sweep", "column-a", "--out", "sw", "--quiet"])
        .args(SETS));
    assert_eq!(code, 0, "{err}");
    let (code, out, err) = run(sieve(d.path())
        .env("SLURM_ARRAY_TASK_ID", "1")
        .args(["sweep", "column-a", "--out", "sw", "--collect"])
        .args(SETS));
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("3 combinations have no run yet"), "{out}");
    for bad in ["-1", "abc"] {
        let (code, _, err) = run(sieve(d.path())
            .env("SLURM_ARRAY_TASK_ID", bad)
            .args(["sweep", "column-a", "--out", "sw2", "--quiet"])
            .args(SETS));
        assert_eq!(code, 2, "{bad}: {err}");
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(err.contains("SLURM_ARRAY_TASK_ID"), "{err}");
        assert!(!d.path().join("sw2").exists());
    }
}

/// `--fit power:1.5` on four orifice widths of the 5 mm silo gives Beverloo's constants of
/// docs/silo.md section 4 (C = 1.20, W0 = 4.5 mm, residuals below 0.3 %), and a `--collect`
/// with `--fit power` fits the exponent from the same runs (measured 1.527 at W0 = 3.8 mm).
/// The fit is of the runs' own summaries: each run's rate is within the reported residual.
#[test]
fn a_width_sweep_fits_beverloos_law() {
    let d = tempfile::tempdir().unwrap();
    let widths = ["0.03", "0.04", "0.05", "0.06"];
    let args = |fit: &str| {
        [
            "sweep".to_string(),
            "silo".into(),
            "--set".into(),
            "run.t_end=1.5".into(),
            "--set".into(),
            format!("boundary.flow.z_low.outlet.width={}", widths.join(",")),
            "--plot".into(),
            "flow.outlet.steady_rate".into(),
            "--fit".into(),
            fit.into(),
            "--out".into(),
            "sw".into(),
            "-q".into(),
        ]
    };
    let (code, out, err) = run(sieve(d.path()).args(args("power:1.5")).args(["-j", "2"]));
    assert_eq!(code, 0, "{err}");
    assert_eq!(
        out.lines().filter(|l| l.starts_with("fit: ")).count(),
        1,
        "{out}"
    );
    let sw = d.path().join("sw");
    assert!(sw.join("sweep.png").is_file());
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(sw.join("sweep.json")).unwrap()).unwrap();
    let f = &doc["fit"]["curves"][0];
    let (a, x0, n, res) = (
        f["a"].as_f64().unwrap(),
        f["x0"].as_f64().unwrap(),
        f["n"].as_f64().unwrap(),
        f["max_residual"].as_f64().unwrap(),
    );
    assert_eq!(n, 1.5);
    assert_eq!(doc["fit"]["x"], "boundary.flow.z_low.outlet.width");
    let c = a / (0.6 * 9.81f64.sqrt());
    assert!((c - 1.20).abs() < 0.02, "Beverloo C = {c}");
    assert!((x0 - 0.0045).abs() < 0.001, "W0 = {x0}");
    assert!(res < 0.005, "largest residual {res}");
    // Standard errors from the scatter about the law (power_law's unit test checks them
    // against repeated fits): present, positive, and small beside the constants.
    let (a_se, x0_se) = (f["a_se"].as_f64().unwrap(), f["x0_se"].as_f64().unwrap());
    println!("{out}");
    assert!(a_se > 0.0 && a_se < 0.02 * a, "A = {a} +- {a_se}");
    assert!(x0_se > 0.0 && x0_se < 0.001, "W0 = {x0} +- {x0_se}");
    assert_eq!(f["n_se"].as_f64(), Some(0.0));
    assert!(out.contains(&format!("A = {a:.6e} ± {a_se:.2e}")), "{out}");
    // The fit's residual is the runs' own: the largest of |fit / rate - 1|.
    let rows = table(&sw);
    let worst = rows
        .iter()
        .zip(widths)
        .map(|(r, w)| {
            let q = r["summary"]["flow.outlet.steady_rate"].as_f64().unwrap();
            let w: f64 = w.parse().unwrap();
            (a * (w - x0).powf(n) / q - 1.0).abs()
        })
        .fold(0.0, f64::max);
    assert!((worst - res).abs() < 1e-12, "{worst} against {res}");
    // The exponent fitted from the same runs, without running them again.
    let (code, out, err) = run(sieve(d.path()).args(args("power")).arg("--collect"));
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("(fitted)"), "{out}");
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(sw.join("sweep.json")).unwrap()).unwrap();
    let f = &doc["fit"]["curves"][0];
    let n = f["n"].as_f64().unwrap();
    assert!((1.45..1.6).contains(&n), "fitted exponent {n}");
    let n_se = f["n_se"].as_f64().unwrap();
    println!("{out}");
    assert!(n_se > 0.0 && n_se < 0.2, "n = {n} +- {n_se}");
    assert!(f["max_residual"].as_f64().unwrap() < 0.005, "{f}");
}

/// A `--fit` the sweep cannot feed is refused before anything runs, in one line.
#[test]
fn a_fit_that_cannot_be_made_is_refused_before_the_runs() {
    let d = tempfile::tempdir().unwrap();
    let cases: [(&[&str], &str); 5] = [
        (
            &["--fit", "beverloo"],
            "`beverloo` is not a model sieve fits: allowed `power`",
        ),
        (&["--fit", "power:0"], "0 < N <= 100"),
        (&["--fit", "power:1e9"], "0 < N <= 100"),
        // two values of the only numeric key: a fixed exponent needs 3
        (
            &["--set", "material.s0=0.5,2", "--fit", "power:1.5"],
            "at least 3",
        ),
        (
            &["--set", "material.s0=0.5,1,2", "--fit", "power"],
            "at least 4",
        ),
    ];
    for (extra, says) in cases {
        let (code, _, err) = run(sieve(d.path())
            .args(["sweep", "column-a", "--out", "sw", "--set", "run.t_end=0.1"])
            .args(["--set", "grid.cells=[40],[80]"])
            .args(extra));
        assert_eq!(code, 2, "{extra:?}: {err}");
        assert_eq!(err.lines().count(), 1, "{extra:?}: {err}");
        assert!(err.contains(says), "{extra:?}: {err}");
        assert!(!d.path().join("sw").exists(), "{extra:?} ran");
    }
    // No swept key with numeric values at all.
    let (code, _, err) = run(sieve(d.path()).args([
        "sweep",
        "column-a",
        "--out",
        "sw",
        "--set",
        "numerics.scheme=modified,classical",
        "--fit",
        "power",
    ]));
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("numeric values"), "{err}");
    // A value the scene's summaries do not hold (a column has no outlet): the runs are
    // made, and the fit says it was not.
    let (code, out, err) = run(sieve(d.path()).args([
        "sweep",
        "column-a",
        "--out",
        "sw",
        "-q",
        "--set",
        "run.t_end=0.1",
        "--set",
        "material.s0=0.5,1,2",
        "--plot",
        "flow.outlet.steady_rate",
        "--fit",
        "power:1.5",
    ]));
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains(
            "fit: not made: no run's summary.json has a number at flow.outlet.steady_rate"
        ),
        "{out}"
    );
}
