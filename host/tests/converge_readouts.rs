//! `sieve converge` on the devices: the scene's readouts (Psi at `t_end`, a silo's discharge
//! rate and fines fractions, the flow's largest speed and temperature) on every level, each
//! the value `sieve run` of that grid reports, with the grid error of the three finest
//! (`sieve::grid_error`); cut-cell scenes (drums) compare readouts only, the drum's own
//! (angle of repose, flowing layer, fines core) among them.

use crate::common::run_in;
use sieve::grid_error::{estimate, Behaviour};
use std::path::Path;

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// The readout `name` of a study: its values per level.
fn values(study: &serde_json::Value, name: &str) -> Vec<Option<f64>> {
    let row = study["readouts"]
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["name"] == name)
        .unwrap_or_else(|| panic!("no readout {name}: {study}"));
    row["values"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64())
        .collect()
}

/// The value under a dotted key of a summary.json.
fn at(summary: &serde_json::Value, key: &str) -> f64 {
    key.split('.')
        .fold(summary, |v, k| &v[k])
        .as_f64()
        .unwrap_or_else(|| panic!("no {key}"))
}

#[test]
fn a_silo_study_reports_the_runs_readouts_and_their_grid_error() {
    let d = tempfile::tempdir().unwrap();
    let width = "boundary.flow.z_low.outlet.width=0.04";
    let (code, err) = run_in(
        d.path(),
        &[
            "converge",
            "silo",
            "--set",
            width,
            "--set",
            "grid.cells=[10,30]",
            "--levels",
            "30,60,120",
            "--t-end",
            "0.3",
            "--quiet",
            "--out",
            "c",
        ],
    );
    assert_eq!(code, 0, "{err}");
    let study = json(&d.path().join("c/converge.json"));
    let levels = [30usize, 60, 120];
    // every level's readouts are what `sieve run` of its grid reports, to the bit
    let (code, err) = run_in(
        d.path(),
        &[
            "run", "silo", "--set", width, "--grid", "20x60", "--t-end", "0.3", "--quiet", "--out",
            "r",
        ],
    );
    assert_eq!(code, 0, "{err}");
    let run = json(&d.path().join("r/summary.json"));
    let names = [
        "psi_final",
        "flow.max_speed",
        "flow.t_max",
        "flow.outlet.out",
        "flow.outlet.steady_rate",
        "flow.outlet.steady_fines_fraction",
        "flow.outlet.final_fines_fraction",
    ];
    for name in names {
        let v = values(&study, name);
        assert_eq!(v.len(), 3, "{name}");
        assert_eq!(v[1], Some(at(&run, name)), "{name}");
    }
    // the estimate in the file is the three values' (Celik et al.), and it says something:
    // the discharged volume converges from below on these grids
    for row in study["readouts"].as_array().unwrap() {
        let v = values(&study, row["name"].as_str().unwrap());
        let pairs: Vec<(usize, f64)> = levels
            .iter()
            .zip(&v)
            .filter_map(|(&l, v)| Some((l, (*v)?)))
            .collect();
        // (serde_json reads floats to within an ulp, not always to the bit)
        let e = serde_json::to_value(estimate(&pairs)).unwrap();
        let file = &row["estimate"];
        assert_eq!(file["behaviour"], e["behaviour"], "{row}");
        for k in ["order", "extrapolated", "error_finest", "gci_finest"] {
            match (file[k].as_f64(), e[k].as_f64()) {
                (Some(a), Some(b)) => assert!((a - b).abs() <= 1e-12 * b.abs(), "{k}: {row}"),
                (a, b) => assert_eq!(a, b, "{k}: {row}"),
            }
        }
    }
    let out = values(&study, "flow.outlet.out");
    let out: Vec<f64> = out.into_iter().map(Option::unwrap).collect();
    assert!(out[0] < out[1] && out[1] < out[2], "{out:?}");
    let e = estimate(&[(30, out[0]), (60, out[1]), (120, out[2])]);
    assert_eq!(e.behaviour, Behaviour::Converging);
    let p = e.order.unwrap();
    let ext = e.extrapolated.unwrap();
    assert!(p > 0.5 && ext > out[2], "order {p}, extrapolated {ext}");
    // readouts.csv: one row per readout, a column per level, then the estimate
    let csv = std::fs::read_to_string(d.path().join("c/readouts.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(
        lines.next().unwrap(),
        "readout,level_30,level_60,level_120,behaviour,order,extrapolated,error_finest,gci_finest,\
         coarser_behaviour,coarser_order,asymptotic"
    );
    let rate = csv
        .lines()
        .find(|l| l.starts_with("flow.outlet.steady_rate,"))
        .unwrap();
    let cols: Vec<&str> = rate.split(',').collect();
    // three levels: no check by a coarser three (the last three columns empty)
    assert_eq!(cols.len(), 12, "{rate}");
    assert_eq!(&cols[9..], ["", "", ""], "{rate}");
    assert_eq!(
        cols[2].parse::<f64>().unwrap(),
        at(&run, "flow.outlet.steady_rate")
    );
    assert_eq!(
        csv.lines().count(),
        1 + study["readouts"].as_array().unwrap().len()
    );
    // and their picture beside the work-precision one
    for png in ["converge.png", "readouts.png"] {
        let bytes = std::fs::read(d.path().join("c").join(png)).unwrap();
        assert_eq!(&bytes[1..4], b"PNG", "{png}");
    }
}

/// A drum on cut cells: no field comparison (the cells' open volumes differ between grids),
/// so any levels are allowed, no work-precision picture is drawn, and the readouts are the
/// runs'. The prescribed drum and the coupled tumbler take the two solver paths.
#[test]
fn drums_on_cut_cells_compare_readouts_only() {
    let d = tempfile::tempdir().unwrap();
    // the tumbler thinned (`vtk_every`): a run measures the snapshots it writes, so the
    // study must keep those and no others (window [1.25, 2.5] s: outputs 6, 9 and 10 of 11)
    let thinned: &[&str] = &[
        "--set",
        "run.output_interval=0.25",
        "--set",
        "output.vtk_every=3",
    ];
    for (scene, levels, t_end, grid, mid, sets) in [
        (
            "drum-settling",
            "8,12,20,32",
            "0.5",
            "20x20",
            2usize,
            &[][..],
        ),
        ("tumbler", "12,17", "2.5", "17x17", 1, thinned),
    ] {
        let out = format!("c-{scene}");
        let mut args = vec![
            "converge", scene, "--levels", levels, "--t-end", t_end, "--quiet", "--out", &out,
        ];
        args.extend(sets);
        let (code, err) = run_in(d.path(), &args);
        assert_eq!(code, 0, "{scene}: {err}");
        let dir = d.path().join(&out);
        let study = json(&dir.join("converge.json"));
        assert!(
            study["reference"].as_str().unwrap().contains("cut cells"),
            "{study}"
        );
        assert!(study["levels"]
            .as_array()
            .unwrap()
            .iter()
            .all(|r| r["l1"].is_null()));
        assert!(!dir.join("converge.png").exists());
        assert!(dir.join("readouts.csv").exists());
        let png = std::fs::read(dir.join("readouts.png")).unwrap();
        assert_eq!(&png[1..4], b"PNG");
        let run_dir = format!("r-{scene}");
        let mut args = vec![
            "run", scene, "--grid", grid, "--t-end", t_end, "--quiet", "--out", &run_dir,
        ];
        args.extend(sets);
        let (code, err) = run_in(d.path(), &args);
        assert_eq!(code, 0, "{scene}: {err}");
        let run = json(&d.path().join(&run_dir).join("summary.json"));
        let psi = values(&study, "psi_final");
        assert_eq!(psi[mid], Some(at(&run, "psi_final")), "{scene}");
        // the drum's readouts, measured from snapshots kept in memory, are the run's
        // (measured from its files)
        let drum = [
            "drum.angle_of_repose_deg",
            "drum.flowing_layer_thickness",
            "drum.centre_phihat",
            "drum.centre_speed",
            "drum.relative_kinetic_energy",
            "drum.loose_share",
        ];
        for name in drum {
            let in_run = name
                .split('.')
                .fold(&run, |v, k| &v[k])
                .as_f64()
                .filter(|v| v.is_finite());
            if scene == "tumbler" {
                assert!(in_run.is_some(), "{name}: {run}");
            }
            if let Some(v) = in_run {
                assert_eq!(values(&study, name)[mid], Some(v), "{scene} {name}");
            }
        }
        assert!(psi.iter().all(|p| p.is_some_and(|p| p > 0.0 && p <= 1.0)));
        let est = &study["readouts"][0]["estimate"]["behaviour"];
        if psi.len() < 3 {
            assert_eq!(est, "too_few_grids", "{scene}");
        } else {
            // the settling drum's fines sink into a sharper layer on finer cells (D = 0):
            // Psi falls with h, at a shrinking rate on the three finest (0.235 / 0.127 /
            // 0.079, order 1.5), but not from the coarsest (0.306 / 0.235 / 0.127: the
            // differences grow, order -0.42), so the study does not show it asymptotic
            let p: Vec<f64> = psi.iter().map(|p| p.unwrap()).collect();
            assert!(p.windows(2).all(|w| w[0] > w[1]), "{scene}: {p:?}");
            let e = &study["readouts"][0]["estimate"];
            assert_eq!(est, "converging", "{scene}: {study}");
            assert_eq!(e["coarser_behaviour"], "not_shrinking", "{e}");
            assert!(e["coarser_order"].as_f64().unwrap() < 0.0, "{e}");
            assert_eq!(e["asymptotic"], false, "{e}");
            let csv = std::fs::read_to_string(dir.join("readouts.csv")).unwrap();
            let row = csv.lines().find(|l| l.starts_with("psi_final,")).unwrap();
            assert!(
                row.contains(",converging,") && row.contains(",not_shrinking,"),
                "{row}"
            );
            assert!(row.ends_with(",no"), "{row}");
        }
    }
}

/// A level too coarse for the scene is bad input: exit 2 before anything runs, one line that
/// names the key, the allowed range and the level, and no directory.
#[test]
fn a_level_too_coarse_for_the_drum_is_named() {
    let d = tempfile::tempdir().unwrap();
    let (code, err) = run_in(
        d.path(),
        &[
            "converge", "tumbler", "--levels", "2,34", "--quiet", "--out", "c",
        ],
    );
    assert_eq!(code, 2, "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains("scenes/tumbler.toml: geometry.radius = 0.05 is out of range: allowed radius >= 2 cells")
            && err.trim_end().ends_with("(on level 2, 2x2 cells)"),
        "{err}"
    );
    assert!(!d.path().join("c").exists());
}

/// A readout a level does not have yet (the hopper's steady window when the run ends at the
/// output where a tenth has left, 14 - 15 % at 0.3 s on both levels: its rate and fines
/// fraction are NaN in summary.json) is left out, never written as NaN, and the hopper (cut
/// cells with an outlet) reports the outlet's readouts.
#[test]
fn a_readout_a_level_lacks_is_left_out() {
    let d = tempfile::tempdir().unwrap();
    let (code, err) = run_in(
        d.path(),
        &[
            "converge",
            "hopper",
            "--levels",
            "60,120",
            "--t-end",
            "0.3",
            "--set",
            "run.output_interval=0.3",
            "--quiet",
            "--out",
            "c",
        ],
    );
    assert_eq!(code, 0, "{err}");
    let csv = std::fs::read_to_string(d.path().join("c/readouts.csv")).unwrap();
    assert!(
        csv.split([',', '\n'])
            .all(|c| !c.eq_ignore_ascii_case("nan")),
        "{csv}"
    );
    let study = json(&d.path().join("c/converge.json"));
    assert!(values(&study, "flow.outlet.out")
        .iter()
        .all(|v| v.is_some_and(|v| v > 0.0)));
    // no level has them: no row at all
    assert!(!csv.contains("flow.outlet.steady_fines_fraction"), "{csv}");
    assert!(!csv.contains("flow.outlet.steady_rate"), "{csv}");
}

/// Hostile levels: one too large for any grid (u64::MAX once overflowed `level * cells`, a
/// panic with overflow checks and a wrong aspect without) and a single level of a cut-cell
/// scene are refused before anything runs, one line each.
#[test]
fn hostile_levels_are_refused_in_one_line() {
    let d = tempfile::tempdir().unwrap();
    for (levels, says) in [
        (
            "18446744073709551615,17",
            "scenes/tumbler.toml: --levels = 18446744073709551615 is out of range: allowed integer 1..=65536",
        ),
        (
            "65537,17",
            "scenes/tumbler.toml: --levels = 65537 is out of range: allowed integer 1..=65536",
        ),
        (
            "17",
            "scenes/tumbler.toml: --levels: a study compares levels: give at least 2 levels",
        ),
    ] {
        let (code, err) = run_in(
            d.path(),
            &["converge", "tumbler", "--levels", levels, "--quiet", "--out", "c"],
        );
        assert_eq!(code, 2, "{levels}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(err.contains(says), "{levels}: {err}");
        assert!(!d.path().join("c").exists());
    }
}
