//! Issue 10, "Never hang, never compute garbage silently", "Messages" and "Accuracy details":
//! each case below was seen to hang, stay silent or mislead before; each test reproduces it.

use crate::common::{run_env, run_full};

use std::path::Path;
use std::time::{Duration, Instant};

fn tmp() -> tempfile::TempDir {
    tempfile::tempdir().expect("temp dir")
}

fn summary(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("summary.json")).expect("summary.json");
    serde_json::from_str(&text).expect("valid JSON")
}

/// Exit 2, a single `error:` line holding every needle, in well under `secs` seconds, and no
/// output left behind.
fn refused(args: &[&str], needles: &[&str], secs: u64) -> String {
    let d = tmp();
    let start = Instant::now();
    let (code, _, err) = run_full(d.path(), args);
    let took = start.elapsed();
    assert_eq!(code, 2, "{args:?}: {err}");
    assert_eq!(err.lines().count(), 1, "{args:?}: one line expected: {err}");
    assert!(err.starts_with("error: "), "{err}");
    for n in needles {
        assert!(err.contains(n), "{args:?}: `{n}` missing in {err}");
    }
    assert!(
        took < Duration::from_secs(secs),
        "{args:?} took {took:?} to be refused"
    );
    let left: Vec<_> = std::fs::read_dir(d.path()).unwrap().collect();
    assert!(left.is_empty(), "{args:?} left {left:?}");
    err
}

/// The runs that never ended (issue 10): refused at once with the estimate and the flag.
#[test]
fn absurd_runs_are_refused_with_the_estimate() {
    for set in [
        "material.s0=1e12",
        "material.s0=1e100",
        "grid.upper=[1e-12]",
        "initial.T=1e300",
        "material.diffusion=1e300",
        "initial.u=[1e10]",
    ] {
        let err = refused(
            &["run", "column-b", "--set", set, "--out", "o"],
            &[
                "run.t_end",
                "steps",
                "raise --max-steps or shorten run.t_end",
            ],
            20,
        );
        assert!(err.len() < 400, "{err}");
    }
    // s0 = 1e308 overflows the segregation rate: dt = C / inf = 0, zero-length steps for ever
    refused(
        &[
            "run",
            "column-b",
            "--set",
            "material.s0=1e308",
            "--out",
            "o",
        ],
        &["stable time step is 0", "material.s0"],
        20,
    );
    // t_end = 1e30 (with an output interval that validation accepts)
    let err = refused(
        &[
            "run",
            "column-b",
            "--set",
            "run.t_end=1e30",
            "--set",
            "run.output_interval=1e26",
            "--out",
            "o",
        ],
        &["t_end = 1e30", "4.0e32 steps", "--max-steps = 1e8"],
        20,
    );
    assert!(err.contains(" h at the measured "), "{err}");
}

/// The step estimate is t_end / dt plus one landing step per output; the limit is the user's.
#[test]
fn max_steps_is_a_limit_the_user_can_raise() {
    // column-a: dt = 0.0025 to t_end = 1.5 with 15 outputs: 600 + 15 estimated
    refused(
        &["run", "column-a", "--max-steps", "600", "--out", "o"],
        &["615 steps", "--max-steps = 600"],
        20,
    );
    refused(
        &["run", "column-a", "--max-cell-steps", "1e5", "--out", "o"],
        &["1.2e5 cell updates", "--max-cell-steps = 100000"],
        20,
    );
    let d = tmp();
    let (code, _, err) = run_full(
        d.path(),
        &[
            "run",
            "column-a",
            "--max-steps",
            "615",
            "--out",
            "o",
            "--quiet",
        ],
    );
    assert_eq!(code, 0, "{err}");
    assert_eq!(summary(&d.path().join("o"))["steps"], 600);
    let (code, _, err) = run_full(d.path(), &["run", "column-a", "--max-steps", "0"]);
    assert_eq!(code, 2, "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
}

/// The 8 GB run of issue 10 (512 x 512, output every 3e-5) is refused before it writes, and the
/// estimate of the VTK bytes matches what a run writes.
#[test]
fn output_size_is_estimated_and_limited() {
    refused(
        &[
            "run",
            "shear-cell-inverse",
            "--grid",
            "512x512",
            "--set",
            "run.output_interval=3e-5",
            "--out",
            "o",
        ],
        &[
            "run.output_interval",
            "outputs of 262144 cells",
            "--max-output",
        ],
        20,
    );
    refused(
        &["run", "column-a", "--max-output", "100k", "--out", "o"],
        &["would write about", "--max-output = 100.0 kB"],
        20,
    );
    let d = tmp();
    let (code, _, err) = run_full(d.path(), &["run", "column-b", "--out", "o", "--quiet"]);
    assert_eq!(code, 0, "{err}");
    let written: u64 = std::fs::read_dir(d.path().join("o/fields"))
        .unwrap()
        .map(|e| e.unwrap())
        .filter(|e| e.path().extension().is_some_and(|x| x == "vti"))
        .map(|e| e.metadata().unwrap().len())
        .sum();
    let (scene, _) = sieve::scene::load("column-b", &[]).unwrap();
    let est = sieve::estimate::fields_bytes(&scene);
    let rel = (est - written as f64).abs() / written as f64;
    assert!(rel < 0.02, "estimate {est} against {written} written");
    let total: u64 = walk(&d.path().join("o"));
    assert!(sieve::estimate::output_bytes(&scene) >= total as f64);
    assert!(sieve::estimate::output_bytes(&scene) < 20.0 * total as f64);
}

fn walk(p: &Path) -> u64 {
    std::fs::read_dir(p)
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            if e.path().is_dir() {
                walk(&e.path())
            } else {
                e.metadata().unwrap().len()
            }
        })
        .sum()
}

/// stderr not a terminal: progress lines (here one at every 10 %, SIEVE_PROGRESS_SECONDS=0);
/// a short run with the default interval (10 s) stays silent; --quiet prints nothing.
#[test]
fn progress_lines_when_stderr_is_not_a_terminal() {
    let d = tmp();
    let (code, _, err) = run_env(
        d.path(),
        &["run", "column-a", "--out", "o"],
        &[("SIEVE_PROGRESS_SECONDS", "0")],
    );
    assert_eq!(code, 0, "{err}");
    let lines: Vec<&str> = err
        .lines()
        .filter(|l| l.starts_with("progress: "))
        .collect();
    assert!(lines.len() >= 9, "{err}");
    let pct: Vec<u32> = lines
        .iter()
        .map(|l| {
            let open = l.find(" (").unwrap() + 2;
            let close = l[open..].find(" %").unwrap() + open;
            l[open..close].parse().unwrap()
        })
        .collect();
    assert!(pct.windows(2).all(|w| w[0] < w[1]), "{pct:?}");
    assert_eq!(*pct.last().unwrap(), 100, "{pct:?}");
    for l in &lines {
        assert!(
            l.contains("column-a: t = ") && l.contains(", step ") && l.contains(" eta "),
            "{l}"
        );
    }
    let (code, _, err) = run_full(d.path(), &["run", "column-a", "--out", "p"]);
    assert_eq!(code, 0, "{err}");
    assert!(!err.contains("progress: "), "{err}");
    let (code, _, err) = run_env(
        d.path(),
        &["run", "column-a", "--out", "q", "--quiet"],
        &[("SIEVE_PROGRESS_SECONDS", "0")],
    );
    assert_eq!(code, 0, "{err}");
    assert!(err.is_empty(), "{err}");
}

/// 1.5 / 0.0025 = 600 steps: no extra steps where the summed clock falls a few ulps short of
/// an output time (610 before: one per output interval).
#[test]
fn no_zero_length_steps_at_output_times() {
    let d = tmp();
    for (scene, steps) in [("column-a", 600), ("column-b", 800)] {
        let (code, _, err) = run_full(d.path(), &["run", scene, "--out", scene, "--quiet"]);
        assert_eq!(code, 0, "{err}");
        let s = summary(&d.path().join(scene));
        assert_eq!(s["steps"], steps, "{scene}");
        assert_eq!(s["dt"], 0.0025);
        assert_eq!(s["t_end"].as_f64().unwrap() / 0.0025, steps as f64);
    }
}

/// The segregation time is resolved to the step: the default output interval (0.1) and an
/// output after every step (0.005 = dt on 100 cells) give the same time, where interpolating
/// between output samples was off by 0.0127 on column b.
#[test]
fn segregation_time_is_resolved_to_the_step() {
    let d = tmp();
    let run = |out: &str, sets: &[&str]| {
        let mut args = vec!["run", "column-b", "--cells", "100", "--out", out, "--quiet"];
        for s in sets {
            args.extend(["--set", s]);
        }
        let (code, _, err) = run_full(d.path(), &args);
        assert_eq!(code, 0, "{err}");
        summary(&d.path().join(out))
    };
    let coarse = run("coarse", &[]);
    let fine = run("fine", &["run.output_interval=0.005"]);
    assert_eq!(fine["dt"], 0.005);
    assert_eq!(coarse["steps"], fine["steps"]);
    let tc = coarse["segregation_time"].as_f64().unwrap();
    let tf = fine["segregation_time"].as_f64().unwrap();
    assert!((tc - tf).abs() < 1e-9, "default {tc} vs every step {tf}");
    // Interpolating the default run's own output samples (the old way) is visibly off.
    let series = std::fs::read_to_string(d.path().join("coarse/series.csv")).unwrap();
    let rows: Vec<(f64, f64)> = series
        .lines()
        .skip(1)
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            (v[0], v[1])
        })
        .collect();
    let thr = coarse["psi_threshold"].as_f64().unwrap();
    let k = rows.iter().position(|r| r.1 < thr).unwrap();
    let (t0, p0, t1, p1) = (rows[k - 1].0, rows[k - 1].1, rows[k].0, rows[k].1);
    let sampled = t0 + (t1 - t0) * (p0 - thr) / (p0 - p1);
    assert!(
        (sampled - tf).abs() > 0.01,
        "sampled {sampled} vs step-resolved {tf}"
    );
    // The README's figures (issue 10 section): 0.92330 step-resolved, 0.93598 sampled.
    assert!((tf - 0.92330).abs() < 5e-6, "step-resolved {tf}");
    assert!((sampled - 0.93598).abs() < 5e-6, "sampled {sampled}");
}

/// column-collapse reported dt = 1.8e308 (the segregation limit of a bed at rest): the steps
/// actually taken are reported instead.
#[test]
fn coupled_runs_report_the_steps_they_took() {
    let d = tmp();
    let (code, _, err) = run_full(
        d.path(),
        &[
            "run",
            "column-collapse",
            "--grid",
            "40x8",
            "--t-end",
            "0.02",
            "--set",
            "run.output_interval=0.01",
            "--out",
            "o",
            "--quiet",
        ],
    );
    assert_eq!(code, 0, "{err}");
    let s = summary(&d.path().join("o"));
    let f = |k: &str| s[k].as_f64().unwrap_or_else(|| panic!("{k}: {s}"));
    let (dt, lo, hi, last) = (f("dt"), f("dt_min"), f("dt_max"), f("dt_last"));
    assert!(dt > 0.0 && dt < 0.02, "dt {dt}");
    assert!(
        lo > 0.0 && lo <= last && last <= hi && hi < 0.02,
        "{lo} {last} {hi}"
    );
    // at least t_end / dt_max steps, at most t_end / dt_min plus the landing steps
    let steps = f("steps");
    assert!(steps >= 0.02 / hi && steps <= 0.02 / lo + 3.0, "{steps}");
}

/// Naive fluxes break 0 <= phi <= c (column d, large phase: 0.225): the run goes on, exit 0,
/// and one warning line says by how much and where. The modified flux stays silent.
#[test]
fn broken_bounds_are_reported_in_one_line() {
    let d = tmp();
    let (code, _, err) = run_full(
        d.path(),
        &[
            "run",
            "column-d",
            "--scheme",
            "godunov",
            "--set",
            "numerics.phase=\"large\"",
            "--out",
            "g",
            "--quiet",
        ],
    );
    assert_eq!(code, 0, "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.starts_with("warning: scenes/column-d.toml: 0 <= phi <= c broken"));
    let s = summary(&d.path().join("g"));
    let worst = s["undershoot_max"]
        .as_f64()
        .unwrap()
        .max(s["overshoot_max"].as_f64().unwrap());
    assert!((worst - 0.225).abs() < 0.01, "{worst}");
    assert!(
        err.contains(&format!("by up to {}", sieve::text::approx(worst))),
        "{err}"
    );
    assert!(err.contains("in the cell at z = "), "{err}");
    assert!(err.contains("--scheme modified"), "{err}");
    // summary.json keeps the line, as printed
    assert_eq!(s["warnings"], serde_json::json!([err.trim_end()]));
    let (code, _, err) = run_full(
        d.path(),
        &[
            "run",
            "column-d",
            "--set",
            "numerics.phase=\"large\"",
            "--out",
            "m",
            "--quiet",
        ],
    );
    assert_eq!(code, 0, "{err}");
    assert!(err.is_empty(), "{err}");
}

/// `sieve converge column-a` at the default t_end (1.5) measured the fully segregated state
/// (errors 1e-14, negative orders): it now measures at t = 0.5 with a note, first order.
#[test]
fn converge_column_a_default_t_end_is_before_completion() {
    let d = tmp();
    let (code, _, err) = run_full(
        d.path(),
        &[
            "converge",
            "column-a",
            "--levels",
            "100,200,400",
            "--out",
            "c",
        ],
    );
    assert_eq!(code, 0, "{err}");
    assert!(
        err.lines()
            .next()
            .unwrap()
            .starts_with("note: scenes/column-a.toml: run.t_end = 1.5"),
        "{err}"
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.path().join("c/converge.json")).unwrap())
            .unwrap();
    assert_eq!(json["t_end"], 0.5);
    for row in &json["levels"].as_array().unwrap()[1..] {
        let p = row["order_l1"].as_f64().unwrap();
        assert!((p - 1.0).abs() < 0.05, "order {p}");
    }
    // given explicitly, it is kept, with a one-line warning
    let (code, _, err) = run_full(
        d.path(),
        &[
            "converge", "column-a", "--levels", "50,100", "--t-end", "1.2", "--out", "w",
        ],
    );
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains(
            "warning: scenes/column-a.toml: run.t_end = 1.2 is after segregation completes"
        ),
        "{err}"
    );
}

/// What the user typed as SCENE is said for what it is, echoed short.
#[test]
fn scene_paths_are_named_for_what_they_are() {
    let d = tmp();
    std::fs::create_dir(d.path().join("adir")).unwrap();
    let adir = d.path().join("adir");
    refused(
        &["run", adir.to_str().unwrap(), "--out", "o"],
        &["adir: SCENE: is a directory"],
        20,
    );
    refused(
        &["run", "missing/scene.toml", "--out", "o"],
        &["missing/scene.toml: SCENE: no such file"],
        20,
    );
    refused(
        &["run", "/dev/urandom", "--out", "o"],
        &["/dev/urandom: SCENE: is not a regular file"],
        20,
    );
    std::fs::write(d.path().join("bin.toml"), [0xffu8, 0xfe, 0, 1]).unwrap();
    let (code, _, err) = run_full(d.path(), &["run", "bin.toml", "--out", "o"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("not a text file"), "{err}");
    refused(
        &["run", "no-such-scene", "--out", "o"],
        &["unknown scene", "column-a"],
        20,
    );
    // 120 kB: one argument may not exceed 128 KiB on Linux (MAX_ARG_STRLEN)
    let long = "s".repeat(120_000);
    let err = refused(
        &["run", &long, "--out", "o"],
        &["chars)", "unknown scene"],
        20,
    );
    // the name is clipped to 60 characters; the rest is the list of built-in names
    assert!(err.len() < 600, "{} bytes echoed", err.len());
    assert!(!err.contains(&"s".repeat(61)), "{err}");
}

/// clap's errors are one line, exit 2; negative numbers reach the range check.
#[test]
fn command_line_errors_are_one_line() {
    let err = refused(
        &["run", "column-a", "--t-end", "-1"],
        &["run.t_end = -1 is out of range"],
        20,
    );
    assert!(!err.contains("-- -1"), "{err}");
    refused(
        &["run", "column-a", "--cfl", "-0.5"],
        &["numerics.courant"],
        20,
    );
    refused(&["run", "--bogus"], &["unexpected argument '--bogus'"], 20);
    refused(
        &["run", "column-a", "--scheme", "foo"],
        &["possible values: modified, godunov, upwind"],
        20,
    );
    refused(&["bogus-command"], &["unrecognized subcommand"], 20);
    refused(&[], &["no command given"], 20);
    let long = format!("--{}", "x".repeat(120_000));
    let err = refused(&["run", &long], &["unexpected argument"], 20);
    assert!(err.len() < 300, "{} bytes echoed", err.len());
    // --help still prints the help, exit 0
    let d = tmp();
    let (code, out, _) = run_full(d.path(), &["run", "--help"]);
    assert_eq!(code, 0);
    assert!(out.contains("--max-steps"), "{out}");
}

/// A 1e300 value is echoed as 1e300, not as 301 digits.
#[test]
fn huge_numbers_are_echoed_short() {
    let err = refused(
        &["run", "column-a", "--set", "run.t_end=1e300", "--out", "o"],
        &["run.output_interval", "1e295"],
        20,
    );
    assert!(err.len() < 250, "{err}");
    let err = refused(
        &[
            "run",
            "column-a",
            "--set",
            "numerics.courant=1e300",
            "--out",
            "o",
        ],
        &["numerics.courant = 1e300"],
        20,
    );
    assert!(err.len() < 250, "{err}");
}

/// `--compress` writes vtkZLibDataCompressor blocks: decompressed here with flate2 directly
/// (header `[1, n, n, c]` per array, UInt64), they are the raw run's arrays to the bit; the
/// host's reader (`sieve plot`) reads them too. `--fields` and `--vtk-every` thin the output.
#[test]
fn compressed_and_thinned_vtk_holds_the_raw_arrays() {
    use std::io::Read;
    let d = tmp();
    let args = |out: &'static str, extra: &[&'static str]| {
        let mut v = vec!["run", "column-c", "--out", out, "--quiet"];
        v.extend_from_slice(extra);
        v
    };
    let (code, _, err) = run_full(d.path(), &args("raw", &[]));
    assert_eq!(code, 0, "{err}");
    let (code, _, err) = run_full(d.path(), &args("zip", &["--compress"]));
    assert_eq!(code, 0, "{err}");
    let raw_file = d.path().join("raw/fields/state_0010.vti");
    let zip_file = d.path().join("zip/fields/state_0010.vti");
    let raw = sieve::output::vtk::read_vti(&raw_file).unwrap();
    let bytes = std::fs::read(&zip_file).unwrap();
    let text_end = bytes
        .windows(4)
        .position(|w| w == b"   _")
        .map(|p| p + 4)
        .unwrap();
    let header = String::from_utf8_lossy(&bytes[..text_end]).into_owned();
    assert!(header.contains("compressor=\"vtkZLibDataCompressor\""));
    assert!(header.contains("header_type=\"UInt64\""));
    let data = &bytes[text_end..];
    let mut seen = 0;
    for tag in header.split("<DataArray ").skip(2) {
        // skip(2): the text before the first tag and the TimeValue array
        let name = tag
            .split("Name=\"")
            .nth(1)
            .unwrap()
            .split('"')
            .next()
            .unwrap();
        let offset: usize = tag
            .split("offset=\"")
            .nth(1)
            .unwrap()
            .split('"')
            .next()
            .unwrap()
            .parse()
            .unwrap();
        let word = |i: usize| {
            u64::from_le_bytes(data[offset + 8 * i..offset + 8 * i + 8].try_into().unwrap())
        };
        assert_eq!(word(0), 1, "{name}: one block");
        let (n, c) = (word(1) as usize, word(3) as usize);
        assert_eq!(word(2) as usize, n);
        let z = &data[offset + 32..offset + 32 + c];
        let mut plain = Vec::new();
        flate2::read::ZlibDecoder::new(z)
            .read_to_end(&mut plain)
            .unwrap();
        assert_eq!(plain.len(), n);
        let values: Vec<f64> = plain
            .chunks_exact(8)
            .map(|b| f64::from_le_bytes(b.try_into().unwrap()))
            .collect();
        let expect = raw.array(name).unwrap();
        assert_eq!(values.len(), expect.len());
        assert!(
            values
                .iter()
                .zip(expect)
                .all(|(a, b)| a.to_bits() == b.to_bits()),
            "{name}"
        );
        assert!(c < n, "{name}: {c} compressed bytes of {n}");
        seen += 1;
    }
    assert_eq!(seen, 5, "phihat, phi, c, T, u");
    // the host's own reader agrees
    let back = sieve::output::vtk::read_vti(&zip_file).unwrap();
    assert_eq!(back.arrays.len(), raw.arrays.len());
    for ((n1, c1, v1), (n2, c2, v2)) in back.arrays.iter().zip(&raw.arrays) {
        assert_eq!((n1, c1), (n2, c2));
        assert!(
            v1.iter().zip(v2).all(|(a, b)| a.to_bits() == b.to_bits()),
            "{n1}"
        );
    }
    // thinning: every 4th of 31 output times (0, 4, ..., 28) plus the last (30); phihat and c
    // always, T asked for
    let (code, _, err) = run_full(
        d.path(),
        &args("thin", &["--vtk-every", "4", "--fields", "T"]),
    );
    assert_eq!(code, 0, "{err}");
    let mut names: Vec<String> = std::fs::read_dir(d.path().join("thin/fields"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".vti"))
        .collect();
    names.sort();
    let expect: Vec<String> = (0..=28)
        .step_by(4)
        .chain([30])
        .map(|k| format!("state_{k:04}.vti"))
        .collect();
    assert_eq!(names, expect);
    let thin = sieve::output::vtk::read_vti(&d.path().join("thin/fields/state_0030.vti")).unwrap();
    let got: Vec<&str> = thin.arrays.iter().map(|a| a.0.as_str()).collect();
    assert_eq!(got, ["phihat", "c", "T"]);
    let pvd = std::fs::read_to_string(d.path().join("thin/fields/series.pvd")).unwrap();
    assert_eq!(pvd.matches("<DataSet").count(), expect.len());
    // the estimate counts what thinning leaves
    let (scene, _) = sieve::scene::load(
        "column-c",
        &["output.vtk_every=4".into(), "output.fields=[\"T\"]".into()],
    )
    .unwrap();
    let written: u64 = names
        .iter()
        .map(|n| {
            std::fs::metadata(d.path().join("thin/fields").join(n))
                .unwrap()
                .len()
        })
        .sum();
    let est = sieve::estimate::fields_bytes(&scene);
    assert!(
        (est - written as f64).abs() / (written as f64) < 0.05,
        "{est} vs {written}"
    );
}

// ---- message and estimate helpers (host/src/text.rs, host/src/estimate.rs) ----
mod helpers {
    use sieve::estimate::{bytes_text, free_space, parse_bytes, parse_count};
    use sieve::text::{approx, num, shorten};

    #[test]
    fn long_numbers_become_exponents() {
        let big = format!("{}", 1e300);
        assert_eq!(big.len(), 301);
        assert_eq!(shorten(&format!("t = {big} is out")), "t = 1e300 is out");
        assert_eq!(
            shorten("output_interval >= 10000000000000000000000000"),
            "output_interval >= 1e25"
        );
        assert_eq!(shorten(&format!("[{big}, 2]")), "[1e300, 2]");
        // short numbers and words stay as they are
        assert_eq!(
            shorten("grid.cells[0] = 0.125 ok"),
            "grid.cells[0] = 0.125 ok"
        );
        assert_eq!(shorten("column-a 1..=65536"), "column-a 1..=65536");
        // Display writes 1e-15 with fifteen zeros; the exponent form only where it is shorter
        assert_eq!(
            shorten(&format!("tol = {} is out", 1e-15)),
            "tol = 1e-15 is out"
        );
        assert_eq!(shorten("x = 0.0123456789 y"), "x = 0.0123456789 y");
        assert_eq!(shorten("steps 123456789"), "steps 123456789");
    }

    #[test]
    fn long_words_are_clipped() {
        let name = "a".repeat(1 << 20);
        let s = shorten(&format!("{name}: unknown scene"));
        assert!(s.len() < 120, "{}", s.len());
        assert!(s.contains("(1048577 chars)"), "{s}");
        assert!(s.ends_with(" unknown scene"));
    }

    #[test]
    fn numbers_for_messages() {
        assert_eq!(num(3.2e14), "3.2e14");
        assert_eq!(num(0.5), "0.5");
        assert_eq!(num(1e-12), "1e-12");
        assert_eq!(num(0.0), "0");
        assert_eq!(approx(1e300 / 1e5), "1e295");
        assert_eq!(approx(0.0123456), "1.235e-2");
        assert_eq!(approx(0.5), "0.5");
    }

    #[test]
    fn byte_sizes_parse() {
        assert_eq!(parse_bytes("500M").unwrap(), 5e8);
        assert_eq!(parse_bytes("8G").unwrap(), 8e9);
        assert_eq!(parse_bytes("1e10").unwrap(), 1e10);
        assert_eq!(parse_bytes("2k").unwrap(), 2e3);
        assert!(parse_bytes("-1G").is_err());
        assert!(parse_bytes("lots").is_err());
        assert_eq!(parse_count("1e9").unwrap(), 1e9);
        assert!(parse_count("0").is_err());
        assert_eq!(bytes_text(8.2e9), "8.2 GB");
    }

    #[test]
    fn free_space_of_a_missing_directory_is_its_parent_s() {
        let d = tempfile::tempdir().unwrap();
        let a = free_space(d.path()).unwrap();
        let b = free_space(&d.path().join("not/yet/there")).unwrap();
        assert!(a > 0 && b > 0);
    }

    #[test]
    fn command_line_definition_is_consistent() {
        use clap::CommandFactory;
        sieve::cli::Cli::command().debug_assert();
    }
}

/// `sieve converge` has no `--max-cell-steps`: its refusal says what it can change (it once
/// told the user to raise a flag the command does not take).
#[test]
fn converge_refusal_names_what_converge_can_change() {
    let err = refused(
        &[
            "converge",
            "column-b",
            "--levels",
            "32768,65536",
            "--t-end",
            "1000",
            "--out",
            "o",
        ],
        &["run.t_end", "use fewer cells", "`sieve run` takes --max-"],
        20,
    );
    assert!(!err.contains("raise --max"), "{err}");
}
