//! The CLI contract of issue 2: exit codes and one-line messages for bad input, the files a run
//! writes and their headers, atomic output directories, `--set` overrides, reproducibility.

use crate::common::run_full;

use std::path::{Path, PathBuf};

fn tmp() -> tempfile::TempDir {
    tempfile::tempdir().expect("temp dir")
}

fn summary(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("summary.json")).expect("summary.json");
    serde_json::from_str(&text).expect("valid JSON")
}

fn scenes_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes")
}

/// Asserts exit code 2 and one line `error: FILE: KEY ...` containing every `needles`.
fn assert_bad_input(args: &[&str], needles: &[&str]) {
    let d = tmp();
    let mut full = args.to_vec();
    full.extend(["--out", "out", "--quiet"]);
    let (code, _, err) = run_full(d.path(), &full);
    assert_eq!(code, 2, "{args:?}: stderr {err}");
    assert_eq!(
        err.lines().count(),
        1,
        "{args:?}: one line expected, got {err}"
    );
    assert!(err.starts_with("error: "), "{err}");
    for n in needles {
        assert!(err.contains(n), "{args:?}: `{n}` missing in {err}");
    }
    // Bad input never leaves an output directory or a staging directory behind.
    let left: Vec<_> = std::fs::read_dir(d.path()).unwrap().collect();
    assert!(left.is_empty(), "{args:?} left {left:?}");
}

#[test]
fn scenes_lists_every_builtin_and_every_file() {
    let d = tmp();
    let (code, out, _) = run_full(d.path(), &["scenes"]);
    assert_eq!(code, 0);
    let listed: Vec<&str> = out.lines().map(|l| l.split('\t').next().unwrap()).collect();
    let mut files: Vec<String> = std::fs::read_dir(scenes_dir())
        .unwrap()
        .filter_map(|e| {
            let p = e.unwrap().path();
            (p.extension()? == "toml").then(|| p.file_stem().unwrap().to_string_lossy().into())
        })
        .collect();
    files.sort();
    let mut sorted: Vec<String> = listed.iter().map(|s| s.to_string()).collect();
    sorted.sort();
    assert_eq!(sorted, files);
    for name in [
        "column-a",
        "column-b",
        "column-c",
        "column-d",
        "gray-thornton-plug",
        "gray-thornton-shear",
        "gray-thornton-plug-inverse",
        "gray-thornton-shear-inverse",
        "shear-cell-mixed",
        "shear-cell-inverse",
    ] {
        assert!(listed.contains(&name), "{name} not listed");
    }
    for line in out.lines() {
        let cols: Vec<&str> = line.split('\t').collect();
        assert_eq!(cols.len(), 3, "{line}");
        assert!(["1D", "2D", "3D"].contains(&cols[1]), "{line}");
        assert!(!cols[2].is_empty());
    }
}

#[test]
fn bad_input_exits_2_with_one_line_naming_file_key_and_range() {
    // |g|^2 overflowed the direction's normalisation: the run "completed" without segregating.
    assert_bad_input(
        &["run", "column-a", "--set", "physics.gravity=[-1e155]"],
        &["physics.gravity[0]", "-1e155", "-1e6..=1e6"],
    );
    assert_bad_input(
        &["run", "no-such-scene"],
        &["no-such-scene", "unknown scene", "column-a"],
    );
    assert_bad_input(
        &["run", "column-a", "--set", "grid.bogus=1"],
        &[
            "scenes/column-a.toml",
            "grid.bogus",
            "unknown field",
            "cells",
        ],
    );
    // A --set into a table the scene lacks (the flat silo has no [geometry]; its outlet width
    // is boundary.flow.z_low.outlet.width) names the new table and what it still needs.
    assert_bad_input(
        &["run", "silo", "--set", "geometry.outlet_width=0.03"],
        &[
            "scenes/silo.toml",
            "--set geometry.outlet_width",
            "no [geometry] table",
            "`shape`",
        ],
    );
    assert_bad_input(
        &["run", "column-a", "--set", "initial.c=nan"],
        &[
            "scenes/column-a.toml",
            "initial.c",
            "NaN",
            "allowed 0 < c <= material.phi_rcp",
        ],
    );
    assert_bad_input(
        &["run", "column-a", "--set", "initial.c=0.7"],
        &[
            "initial.c = 0.7",
            "allowed 0 < c <= material.phi_rcp = 0.64",
        ],
    );
    assert_bad_input(
        &["run", "column-a", "--set", "initial.c=0"],
        &["initial.c = 0", "allowed 0 < c"],
    );
    assert_bad_input(
        &["run", "column-a", "--set", "initial.phi=c*1.5"],
        &["initial.phi", "allowed 0 <= phi <= c"],
    );
    assert_bad_input(
        &["run", "column-a", "--set", "initial.phi=-0.1"],
        &["initial.phi = -0.1", "allowed 0 <= phi <= c"],
    );
    assert_bad_input(
        &["run", "column-a", "--set", "initial.T=-1"],
        &["initial.T = -1", "allowed a finite T >= 0"],
    );
    assert_bad_input(
        &["run", "column-a", "--cells", "70000"],
        &["grid.cells[0] = 70000", "allowed integer 1..=65536"],
    );
    assert_bad_input(
        &["run", "shear-cell-mixed", "--grid", "1000x1000"],
        &["grid.cells", "at most 262144 cells in 2D"],
    );
    assert_bad_input(
        &["run", "column-a", "--cfl", "1"],
        &["numerics.courant = 1", "allowed 0 < courant < 1"],
    );
    assert_bad_input(
        &["run", "column-a", "--cfl", "0"],
        &["numerics.courant = 0", "allowed 0 < courant < 1"],
    );
    assert_bad_input(
        &["run", "column-a", "--set", "numerics.courant=inf"],
        &["numerics.courant", "allowed a finite number"],
    );
    assert_bad_input(
        &["run", "column-a", "--set", "model.equations=\"full\""],
        &["model.equations", "prescribed", "frozen-flow", "coupled"],
    );
    assert_bad_input(
        &["run", "column-a", "--set", "numerics.scheme=\"fast\""],
        &["numerics.scheme", "modified", "godunov", "upwind"],
    );
    assert_bad_input(
        &["run", "column-a", "--set", "grid.cells=[0]"],
        &["grid.cells[0] = 0 is out of range: allowed integer 1..=65536"],
    );
    assert_bad_input(
        &["run", "column-a", "--set", "name=\"../escape\""],
        &["name = \"../escape\"", "allowed letters, digits"],
    );
    assert_bad_input(
        &["run", "column-a", "--set", "initial.c=0.5*q"],
        &["initial.c", "unknown variable `q`"],
    );
}

#[test]
fn malformed_toml_and_unknown_top_level_key() {
    let d = tmp();
    std::fs::write(d.path().join("broken.toml"), "name = \"x\"\n[grid\n").unwrap();
    let (code, _, err) = run_full(d.path(), &["run", "broken.toml", "--quiet"]);
    assert_eq!(code, 2);
    assert_eq!(err.lines().count(), 1);
    assert!(err.contains("broken.toml: malformed TOML: line 2"), "{err}");

    let text = std::fs::read_to_string(scenes_dir().join("column-a.toml")).unwrap();
    std::fs::write(d.path().join("extra.toml"), format!("colour = 3\n{text}")).unwrap();
    let (code, _, err) = run_full(d.path(), &["run", "extra.toml", "--quiet"]);
    assert_eq!(code, 2);
    assert!(
        err.contains("extra.toml: colour: unknown field `colour`"),
        "{err}"
    );
    assert!(!d.path().join("runs").exists());
}

#[test]
fn run_writes_every_output_with_the_contract_headers() {
    let d = tmp();
    let (code, out, err) = run_full(
        d.path(),
        &[
            "run", "column-a", "--cells", "50", "--t-end", "0.3", "--quiet",
        ],
    );
    assert_eq!(code, 0, "{err}");
    assert!(
        out.is_empty() && err.is_empty(),
        "--quiet prints nothing: {out} {err}"
    );
    let dir = d.path().join("runs/column-a");
    let series = std::fs::read_to_string(dir.join("series.csv")).unwrap();
    let mut lines = series.lines();
    assert_eq!(
        lines.next(),
        Some("t,psi,mass,overshoot_max,undershoot_max")
    );
    let times: Vec<f64> = lines
        .map(|l| l.split(',').next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(times, vec![0.0, 0.1, 0.2, 0.3]);
    let fin = std::fs::read_to_string(dir.join("final.csv")).unwrap();
    assert_eq!(fin.lines().next(), Some("x,y,z,c,phi,phihat,T,ux,uy,uz"));
    assert_eq!(fin.lines().count(), 51);
    let s = summary(&dir);
    for key in [
        "scene",
        "scheme",
        "dims",
        "cells",
        "steps",
        "t_end",
        "wall_seconds",
        "cell_updates_per_second",
        "mass_initial",
        "mass_final",
        "mass_out",
        "mass_rel_drift",
        "overshoot_max",
        "undershoot_max",
        "psi_final",
        "segregation_time",
        "psi_threshold",
        "state_hash",
        "precision",
        "phase",
    ] {
        assert!(s.get(key).is_some(), "summary lacks {key}");
    }
    assert_eq!(s["scene"], "column-a");
    assert_eq!(s["dims"], 1);
    assert_eq!(s["cells"], serde_json::json!([50]));
    assert_eq!(s["mass_out"], 0.0, "no outlet, nothing booked out");
    assert!(s["segregation_time"].is_null(), "not segregated by t = 0.3");
    assert_eq!(s["psi_threshold"], 0.05);
    assert_eq!(s["state_hash"].as_str().unwrap().len(), 16);
    assert!(s["cell_updates_per_second"].as_f64().unwrap() > 0.0);
    // Exact Psi(0.3) = 0.7; the first-order scheme smears the shocks over a few cells.
    assert!((s["psi_final"].as_f64().unwrap() - 0.7).abs() < 0.05, "{s}");
    let pvd = std::fs::read_to_string(dir.join("fields/series.pvd")).unwrap();
    assert_eq!(pvd.matches("<DataSet").count(), 4);
    for k in 0..4 {
        let vti = std::fs::read(dir.join(format!("fields/state_{k:04}.vti"))).unwrap();
        let head = String::from_utf8_lossy(&vti[..600.min(vti.len())]).into_owned();
        assert!(head.contains("<VTKFile type=\"ImageData\""), "{head}");
        assert!(head.contains("WholeExtent=\"0 0 0 0 0 50\""), "{head}");
    }
    for png in ["plots/psi.png", "plots/phihat_profiles.png"] {
        let bytes = std::fs::read(dir.join(png)).unwrap();
        assert_eq!(&bytes[1..4], b"PNG", "{png}");
    }
    // Nothing but the run directory is left in runs/ (no staging directories).
    let entries: Vec<_> = std::fs::read_dir(d.path().join("runs")).unwrap().collect();
    assert_eq!(entries.len(), 1);
}

#[test]
fn set_overrides_and_flags_reach_the_run() {
    let d = tmp();
    let (code, _, err) = run_full(
        d.path(),
        &[
            "run",
            "column-b",
            "--set",
            "grid.cells=[40]",
            "--set",
            "numerics.scheme=\"upwind\"",
            "--set",
            "run.output_interval=0.25",
            "--t-end",
            "0.5",
            "--cfl",
            "0.4",
            "--out",
            "custom",
            "--quiet",
        ],
    );
    assert_eq!(code, 0, "{err}");
    let s = summary(&d.path().join("custom"));
    assert_eq!(s["cells"], serde_json::json!([40]));
    assert_eq!(s["scheme"], "upwind");
    assert_eq!(s["t_end"], 0.5);
    assert_eq!(s["courant"], 0.4);
    assert_eq!(s["output_interval"], 0.25);
    // summary.json says what changed the scene file, in the order applied (flags after --set)
    assert_eq!(
        s["overrides"],
        serde_json::json!([
            "grid.cells=[40]",
            "numerics.scheme=\"upwind\"",
            "run.output_interval=0.25",
            "run.t_end=0.5",
            "numerics.courant=0.4"
        ])
    );
    // --scheme beats --set (flags apply after --set), --grid sets every axis.
    let (code, _, err) = run_full(
        d.path(),
        &[
            "run",
            "shear-cell-mixed",
            "--set",
            "numerics.scheme=\"upwind\"",
            "--scheme",
            "godunov",
            "--grid",
            "8x12",
            "--t-end",
            "0.2",
            "--out",
            "sc",
            "--quiet",
        ],
    );
    assert_eq!(code, 0, "{err}");
    let s = summary(&d.path().join("sc"));
    assert_eq!(s["scheme"], "godunov");
    assert_eq!(s["cells"], serde_json::json!([8, 12]));
}

#[test]
fn column_a_is_reproducible_and_conserves_mass() {
    let d = tmp();
    let mut hashes = Vec::new();
    for out in ["a", "b"] {
        let (code, _, err) = run_full(d.path(), &["run", "column-a", "--out", out, "--quiet"]);
        assert_eq!(code, 0, "{err}");
        let s = summary(&d.path().join(out));
        assert!(s["mass_rel_drift"].as_f64().unwrap() < 1e-12, "{s}");
        assert_eq!(s["overshoot_max"], 0.0);
        assert_eq!(s["undershoot_max"], 0.0);
        // Exact segregation time 0.95 (Psi = 1 - t); within an output interval.
        let ts = s["segregation_time"].as_f64().unwrap();
        assert!((ts - 0.95).abs() < 0.02, "{ts}");
        hashes.push(s["state_hash"].as_str().unwrap().to_string());
    }
    assert_eq!(hashes[0], hashes[1]);
    // A file sieve did not write stops the replacement (host/tests/outsafe.rs has more) ...
    std::fs::write(d.path().join("a/stale.txt"), "old").unwrap();
    let (code, _, _) = run_full(d.path(), &["run", "column-a", "--out", "a", "--quiet"]);
    assert_eq!(code, 2);
    assert!(d.path().join("a/stale.txt").exists());
    // ... and without it, running into an existing run directory replaces it whole.
    std::fs::remove_file(d.path().join("a/stale.txt")).unwrap();
    let (code, _, _) = run_full(d.path(), &["run", "column-a", "--out", "a", "--quiet"]);
    assert_eq!(code, 0);
    assert_eq!(
        summary(&d.path().join("a"))["state_hash"],
        hashes[0].as_str()
    );
    let names: Vec<String> = std::fs::read_dir(d.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(
        names.len(),
        2,
        "no staging or set-aside directories left: {names:?}"
    );
}

#[test]
fn failed_validation_keeps_an_existing_dir_untouched() {
    let d = tmp();
    std::fs::create_dir(d.path().join("keep")).unwrap();
    std::fs::write(d.path().join("keep/marker"), "x").unwrap();
    let (code, _, _) = run_full(
        d.path(),
        &["run", "column-a", "--cfl", "2", "--out", "keep", "--quiet"],
    );
    assert_eq!(code, 2);
    assert!(d.path().join("keep/marker").exists());
    assert_eq!(std::fs::read_dir(d.path()).unwrap().count(), 1);
}

#[test]
fn default_scene_runs_in_2d_and_re_segregates() {
    let d = tmp();
    let (code, _, err) = run_full(d.path(), &["run", "--cells", "16", "--quiet"]);
    assert_eq!(code, 0, "{err}");
    let dir = d.path().join("runs/shear-cell-inverse");
    let s = summary(&dir);
    assert_eq!(s["dims"], 2);
    assert_eq!(s["psi_initial"], 0.0);
    // It starts segregated the wrong way round, so the segregation time is that of the
    // re-segregation, not t = 0.
    let ts = s["segregation_time"].as_f64().unwrap();
    assert!(ts > 1.0 && ts < 3.0, "{ts}");
    assert!(dir.join("plots/phihat_0000.png").exists());
    let vti = std::fs::read(dir.join("fields/state_0000.vti")).unwrap();
    let head = String::from_utf8_lossy(&vti[..400]).into_owned();
    assert!(head.contains("WholeExtent=\"0 16 0 0 0 16\""), "{head}");
}

#[test]
fn three_dimensional_f32_scene_from_a_file() {
    let d = tmp();
    let text = r#"
name = "box3"
description = "3D box"
dim = 3
[model]
precision = "f32"
[grid]
cells = [6, 4, 8]
lower = [0, 0, 0]
upper = [1, 1, 1]
[material]
s0 = 1
[physics]
gravity = [0, 0, -1]
[initial]
c = 0.6
T = "0.5 + 0.5 * z"
u = ["z", 0, 0]
phi = "c * if(x < 0.5, 0.25, 0.75)"
[boundary]
x = ["periodic", "periodic"]
[run]
t_end = 0.2
output_interval = 0.1
"#;
    std::fs::write(d.path().join("box3.toml"), text).unwrap();
    let (code, _, err) = run_full(d.path(), &["run", "box3.toml", "--quiet"]);
    assert_eq!(code, 0, "{err}");
    let dir = d.path().join("runs/box3");
    let s = summary(&dir);
    assert_eq!(s["precision"], "f32");
    assert_eq!(s["dims"], 3);
    assert!(s["mass_rel_drift"].as_f64().unwrap() < 1e-5, "{s}");
    assert!(dir.join("plots/phihat_midplane_0000.png").exists());
    let fin = std::fs::read_to_string(dir.join("final.csv")).unwrap();
    assert_eq!(fin.lines().count(), 6 * 4 * 8 + 1);
}

#[test]
fn converge_column_a_is_first_order() {
    let d = tmp();
    let (code, out, err) = run_full(
        d.path(),
        &[
            "converge",
            "column-a",
            "--levels",
            "50,100,200,400",
            "--t-end",
            "0.5",
            "--quiet",
        ],
    );
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("L1"), "{out}");
    let dir = d.path().join("runs/column-a-converge");
    let csv = std::fs::read_to_string(dir.join("converge.csv")).unwrap();
    assert_eq!(
        csv.lines().next(),
        Some("level,cells,l1,l2,linf,order_l1,order_l2,order_linf,steps,wall_seconds")
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("converge.json")).unwrap()).unwrap();
    let levels = json["levels"].as_array().unwrap();
    assert_eq!(levels.len(), 4);
    let last = &levels[3];
    let order = last["order_l1"].as_f64().unwrap();
    assert!((order - 1.0).abs() < 0.1, "observed L1 order {order}");
    assert!(last["l1"].as_f64().unwrap() < levels[1]["l1"].as_f64().unwrap());
}

#[test]
fn converge_without_exact_solution_needs_nested_levels() {
    let d = tmp();
    let (code, _, err) = run_full(
        d.path(),
        &["converge", "column-b", "--levels", "30,100", "--quiet"],
    );
    assert_eq!(code, 2);
    assert!(err.contains("--levels") && err.contains("nested"), "{err}");
    let (code, out, err) = run_full(
        d.path(),
        &[
            "converge",
            "column-b",
            "--levels",
            "25,50,100",
            "--t-end",
            "0.3",
            "--quiet",
        ],
    );
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("finest level 100"), "{out}");
}

#[test]
fn naive_fluxes_leave_the_bounds_on_column_d_and_the_modified_one_does_not() {
    let d = tmp();
    let mut undershoot = Vec::new();
    for scheme in ["modified", "godunov", "upwind"] {
        // Tracking the large phase: psi = c - phi overshooting c shows up as phi < 0.
        let (code, _, err) = run_full(
            d.path(),
            &[
                "run",
                "column-d",
                "--scheme",
                scheme,
                "--set",
                "numerics.phase=\"large\"",
                "--t-end",
                "1",
                "--out",
                scheme,
                "--quiet",
            ],
        );
        assert_eq!(code, 0, "{err}");
        let s = summary(&d.path().join(scheme));
        assert_eq!(s["phase"], "large");
        assert!(s["mass_rel_drift"].as_f64().unwrap() < 1e-12);
        let every_step = s["undershoot_max"].as_f64().unwrap();
        // The summary's bound covers every step; series.csv samples the output times only.
        let series = std::fs::read_to_string(d.path().join(scheme).join("series.csv")).unwrap();
        let sampled = series
            .lines()
            .skip(1)
            .map(|l| l.split(',').nth(4).unwrap().parse::<f64>().unwrap())
            .fold(0.0, f64::max);
        assert!(every_step >= sampled, "{every_step} < {sampled}");
        undershoot.push(every_step);
    }
    assert_eq!(undershoot[0], 0.0);
    assert!(undershoot[1] > 0.1 && undershoot[2] > 0.1, "{undershoot:?}");
}

/// Writes a copy of `scenes/column-a.toml` with `(from, to)` replacements into `dir`.
fn column_a_with(dir: &Path, name: &str, edits: &[(&str, &str)]) -> PathBuf {
    let mut text = std::fs::read_to_string(scenes_dir().join("column-a.toml")).unwrap();
    for (from, to) in edits {
        assert!(text.contains(from), "column-a.toml has no `{from}`");
        text = text.replacen(from, to, 1);
    }
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

/// Issue 11: validation reports every problem of a scene file in one go, one line each, in the
/// order of the file's sections, with exit code 2 and no output directory.
#[test]
fn a_file_with_three_mistakes_gets_three_lines() {
    let d = tmp();
    let scene = column_a_with(
        d.path(),
        "three.toml",
        &[
            ("courant = 0.5", "courant = 1.5"),
            ("s0 = 1.0", "s0 = -1.0"),
            ("t_end = 1.5", "t_end = 0.0"),
        ],
    );
    let (code, _, err) = run_full(
        d.path(),
        &["run", scene.to_str().unwrap(), "--out", "out", "--quiet"],
    );
    assert_eq!(code, 2, "{err}");
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 3, "{err}");
    assert!(lines.iter().all(|l| l.starts_with("error: ")), "{err}");
    for (line, key) in lines.iter().zip([
        "numerics.courant = 1.5",
        "material.s0 = -1",
        "run.t_end = 0",
    ]) {
        assert!(line.contains("three.toml") && line.contains(key), "{line}");
    }
    assert!(!d.path().join("out").exists());
}

/// Turning a 1D scene into 3D by changing `dim` alone: one run names every per-axis key that
/// still has one entry (the issue's "five runs"), and the boundary key of an axis 3D has.
#[test]
fn a_1d_scene_made_3d_reports_every_per_axis_key_at_once() {
    let d = tmp();
    let scene = column_a_with(d.path(), "to3d.toml", &[("dim = 1", "dim = 3")]);
    let (code, _, err) = run_full(
        d.path(),
        &["run", scene.to_str().unwrap(), "--out", "out", "--quiet"],
    );
    assert_eq!(code, 2, "{err}");
    for key in [
        "grid.cells",
        "grid.lower",
        "grid.upper",
        "physics.gravity",
        "initial.u",
    ] {
        assert!(
            err.lines()
                .any(|l| l.contains(&format!("to3d.toml: {key}"))),
            "{key} missing in\n{err}"
        );
    }
    assert_eq!(err.lines().count(), 5, "{err}");
    // Per-cell field checks report a key once, at its first bad cell, and every bad key.
    let fields = column_a_with(
        d.path(),
        "fields.toml",
        &[
            ("T = 1.0", "T = \"z - 0.5\""),
            ("phi = \"c / 2\"", "phi = \"c * 2\""),
            ("exact = \"column-a\"", ""),
        ],
    );
    let (code, _, err) = run_full(
        d.path(),
        &["run", fields.to_str().unwrap(), "--out", "out", "--quiet"],
    );
    assert_eq!(code, 2, "{err}");
    assert_eq!(err.lines().count(), 2, "{err}");
    assert!(
        err.contains("initial.T = -0.4975") && err.contains("initial.phi"),
        "{err}"
    );
}

/// Number of frames of a GIF (graphic control extensions, one per frame as plotters writes).
fn gif_frames(path: &Path) -> usize {
    let b = std::fs::read(path).unwrap();
    assert_eq!(&b[..6], b"GIF89a", "{}", path.display());
    b.windows(3).filter(|w| w == &[0x21, 0xf9, 0x04]).count()
}

/// Issue 11: a 2D run animates every output time beside its still frames, and `sieve plot
/// DIR` redraws the same pictures from the run's files alone (after they were deleted).
#[test]
fn plot_redraws_a_finished_run_with_an_animation_of_every_output() {
    let d = tmp();
    let (code, _, err) = run_full(
        d.path(),
        &[
            "run",
            "shear-cell-mixed",
            "--grid",
            "16x16",
            "--t-end",
            "0.4",
            "--set",
            "run.output_interval=0.025",
            "--out",
            "r",
            "--quiet",
        ],
    );
    assert_eq!(code, 0, "{err}");
    let plots = d.path().join("r/plots");
    // 17 output times: all in the animation, 12 still frames (first and last included).
    assert_eq!(gif_frames(&plots.join("phihat.gif")), 17);
    let stills = |p: &Path| {
        std::fs::read_dir(p)
            .unwrap()
            .filter(|e| {
                let n = e.as_ref().unwrap().file_name();
                let n = n.to_string_lossy();
                n.starts_with("phihat_") && n.ends_with(".png")
            })
            .count()
    };
    assert_eq!(stills(&plots), 12);
    assert!(plots.join("phihat_0000.png").exists() && plots.join("phihat_0016.png").exists());
    std::fs::remove_dir_all(&plots).unwrap();
    let (code, out, err) = run_full(d.path(), &["plot", "r"]);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("phihat.gif") && out.contains("psi.png"),
        "{out}"
    );
    assert_eq!(gif_frames(&plots.join("phihat.gif")), 17);
    assert_eq!(stills(&plots), 12);
    let png = std::fs::read(plots.join("psi.png")).unwrap();
    assert_eq!(&png[1..4], b"PNG");
    // Not a run directory: bad input.
    let (code, _, err) = run_full(d.path(), &["plot", "."]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("no summary.json"), "{err}");
}

/// `sieve converge` draws its work-precision picture beside the table.
#[test]
fn converge_draws_error_against_cell_size_and_wall_time() {
    let d = tmp();
    let (code, _, err) = run_full(
        d.path(),
        &[
            "converge",
            "column-a",
            "--levels",
            "50,100,200",
            "--t-end",
            "0.5",
            "--out",
            "c",
            "--quiet",
        ],
    );
    assert_eq!(code, 0, "{err}");
    let png = std::fs::read(d.path().join("c/converge.png")).unwrap();
    assert_eq!(&png[1..4], b"PNG");
}

/// `sieve sweep --list | head -1`: the reader goes away while sieve still writes. `println!`
/// panicked there (exit 101 and a backtrace); now sieve exits at once with 141 (128 + SIGPIPE,
/// what a C tool killed by the signal reports) and prints nothing (host/src/stdout.rs).
#[test]
fn a_reader_that_goes_away_is_not_a_panic() {
    use std::io::Read;
    use std::process::{Command, Stdio};
    // 60 x 60 combinations, ~150 kB: more than a pipe buffer, so the write must meet the
    // closed pipe whatever the timing.
    let values = |n: usize| {
        (1..=n)
            .map(|k| format!("{}", k as f64 * 1e-3))
            .collect::<Vec<_>>()
            .join(",")
    };
    let mut child = Command::new(assert_cmd::cargo::cargo_bin("sieve"))
        .args([
            "sweep",
            "column-a",
            "--list",
            "--set",
            &format!("numerics.courant={}", values(60)),
            "--set",
            &format!("initial.T={}", values(60)),
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // read the first line, then hang up
    let mut stdout = child.stdout.take().unwrap();
    let mut first = [0u8; 16];
    stdout.read_exact(&mut first).unwrap();
    drop(stdout);
    let mut err = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    let status = child.wait().unwrap();
    assert!(
        first.starts_with(b"0\t"),
        "{:?}",
        String::from_utf8_lossy(&first)
    );
    assert_eq!(status.code(), Some(141), "stderr: {err}");
    assert!(err.is_empty(), "stderr: {err}");
}
