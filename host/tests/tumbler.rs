//! Containers with cut-cell walls through the CLI (issue 8): the `[geometry]` and `[frame]`
//! keys (good values run, every bad one exits 2 with one line naming the file, the key and
//! the allowed range), the `drum-settling` scene (mass to round-off, bounds exact, fines
//! below the bed's centre, solid cells masked), and the rotating frame of a coupled flow.

use crate::common::run_full;

use std::path::Path;

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// Columns of final.csv by name, one Vec per column.
fn columns(path: &Path) -> std::collections::HashMap<String, Vec<f64>> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let names: Vec<String> = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    let mut cols: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
    for line in lines {
        for (k, v) in line.split(',').enumerate() {
            cols[k].push(v.parse().unwrap());
        }
    }
    names.into_iter().zip(cols).collect()
}

/// A bad value: exit 2, exactly one stderr line, naming the file and `key`, with `allowed`.
fn refused(args: &[&str], key: &str, allowed: &str) {
    let d = tempfile::tempdir().unwrap();
    let (code, _, err) = run_full(d.path(), args);
    assert_eq!(code, 2, "{args:?}: {err}");
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 1, "{args:?}: one line expected:\n{err}");
    let line = lines[0];
    assert!(line.starts_with("error: scenes/"), "{line}");
    assert!(line.contains(key), "{args:?}: no key {key}: {line}");
    assert!(line.contains(allowed), "{args:?}: no '{allowed}': {line}");
    assert!(
        !d.path().join("runs").exists(),
        "a refused run wrote output"
    );
}

/// `base` followed by `--set s` for every `s` of `sets`.
fn with_sets<'a>(base: &[&'a str], sets: &[&'a str]) -> Vec<&'a str> {
    let mut a = base.to_vec();
    for s in sets {
        a.push("--set");
        a.push(s);
    }
    a
}

#[test]
fn drum_settling_conserves_mass_keeps_bounds_and_sinks_the_fines() {
    let d = tempfile::tempdir().unwrap();
    let (code, _, err) = run_full(
        d.path(),
        &["run", "drum-settling", "--t-end", "1", "--quiet"],
    );
    assert_eq!(code, 0, "{err}");
    let dir = d.path().join("runs/drum-settling");
    let s = json(&dir.join("summary.json"));
    let drift = s["mass_rel_drift"].as_f64().unwrap();
    assert!(drift < 1e-12, "mass drift {drift}");
    assert_eq!(s["overshoot_max"].as_f64(), Some(0.0));
    assert_eq!(s["undershoot_max"].as_f64(), Some(0.0));
    // the half-filled drum: mass = c/2 * pi R^2 / 2 with the cut cells' area (second order)
    let r: f64 = 0.05;
    let half_disc = std::f64::consts::PI * r * r / 2.0;
    let m0 = s["mass_initial"].as_f64().unwrap();
    assert!((m0 / (0.3 * half_disc) - 1.0).abs() < 2e-3, "mass {m0}");
    let g = &s["geometry"];
    assert_eq!(g["shape"], "drum");
    let open = g["open_volume"].as_f64().unwrap();
    assert!(
        (open / (2.0 * half_disc) - 1.0).abs() < 1e-3,
        "open volume {open}"
    );
    assert!(g["min_group_volume"].as_f64().unwrap() >= 0.5);
    assert!(g["cut_cells"].as_u64().unwrap() > 0);
    // the bed segregates (Psi from 1 to below 0.1 in 1 s), without a frame block
    assert!(s["psi_initial"].as_f64().unwrap() > 0.999);
    let psi = s["psi_final"].as_f64().unwrap();
    assert!(psi < 0.1, "psi {psi}");
    assert!(s.get("frame").is_none());

    let f = columns(&dir.join("final.csv"));
    let (z, c, phi, ph, vol) = (&f["z"], &f["c"], &f["phi"], &f["phihat"], &f["volume"]);
    let (mut bed, mut fines, mut mb, mut mf) = (0.0, 0.0, 0.0, 0.0);
    for i in 0..z.len() {
        assert!((0.0..=1.0).contains(&ph[i]), "phihat {} at cell {i}", ph[i]);
        assert!(
            phi[i] >= 0.0 && phi[i] <= c[i],
            "phi {} > c {}",
            phi[i],
            c[i]
        );
        if vol[i] == 0.0 {
            // solid cells never hold grains
            assert_eq!((c[i], phi[i]), (0.0, 0.0), "solid cell {i} holds grains");
        }
        bed += vol[i] * c[i] * z[i];
        mb += vol[i] * c[i];
        fines += vol[i] * phi[i] * z[i];
        mf += vol[i] * phi[i];
    }
    let (zb, zf) = (bed / mb, fines / mf);
    // mixed at the start: both at the same height; at the end the fines sit clearly lower
    assert!(zf < zb - 0.005, "fines centre {zf} vs bed centre {zb}");
    assert!(vol.contains(&0.0) && vol.iter().any(|&v| v > 0.0 && v < 1.0));

    let vti = std::fs::read(dir.join("fields/state_0000.vti")).unwrap();
    let head = String::from_utf8_lossy(&vti[..2000.min(vti.len())]).into_owned();
    assert!(
        head.contains("Name=\"volume\""),
        "no volume array in the VTK file"
    );
    assert!(dir.join("plots/phihat_0000.png").is_file());
}

#[test]
fn drum_settling_reruns_bit_identically() {
    let hash = || {
        let d = tempfile::tempdir().unwrap();
        let args = [
            "run",
            "drum-settling",
            "--grid",
            "24x24",
            "--t-end",
            "0.3",
            "--quiet",
        ];
        let (code, _, err) = run_full(d.path(), &args);
        assert_eq!(code, 0, "{err}");
        json(&d.path().join("runs/drum-settling/summary.json"))["state_hash"].clone()
    };
    assert_eq!(hash(), hash());
}

#[test]
fn every_shape_runs_with_mass_to_round_off() {
    for sets in [
        vec![
            "geometry.shape=\"square-drum\"",
            "geometry.half_width=0.03",
            "geometry.angle=20",
        ],
        vec![
            "geometry.shape=\"drum-baffle\"",
            "geometry.radius=0.045",
            "geometry.angle=-60",
            "geometry.baffle_length=0.02",
            "geometry.baffle_thickness=0.005",
        ],
        vec![
            "geometry.shape=\"hopper\"",
            "geometry.outlet_z=0.03",
            "geometry.outlet_width=0.01",
            "geometry.hopper_angle=30",
        ],
    ] {
        let d = tempfile::tempdir().unwrap();
        let mut args = vec![
            "run",
            "drum-settling",
            "--grid",
            "32x32",
            "--t-end",
            "0.3",
            "--quiet",
        ];
        // the drum's radius is not a key of the other shapes: remove it first
        args.push("--set");
        args.push("geometry={}");
        for s in &sets {
            args.push("--set");
            args.push(s);
        }
        let (code, _, err) = run_full(d.path(), &args);
        assert_eq!(code, 0, "{sets:?}: {err}");
        let s = json(&d.path().join("runs/drum-settling/summary.json"));
        let drift = s["mass_rel_drift"].as_f64().unwrap();
        assert!(drift < 1e-12, "{sets:?}: drift {drift}");
        assert_eq!(s["overshoot_max"].as_f64(), Some(0.0), "{sets:?}");
        assert_eq!(s["undershoot_max"].as_f64(), Some(0.0), "{sets:?}");
        let shape = sets[0].split('"').nth(1).unwrap();
        assert_eq!(s["geometry"]["shape"], shape);
    }
}

#[test]
fn bad_geometry_values_exit_2_with_one_line() {
    let base = ["run", "drum-settling", "--quiet", "--set"];
    let case = |set: &str, key: &str, allowed: &str| {
        let mut a: Vec<&str> = base.to_vec();
        a.push(set);
        refused(&a, key, allowed);
    };
    case(
        "geometry.radius=0.06",
        "geometry.radius = 0.06",
        "the drum must fit in the box",
    );
    case(
        "geometry.radius=-1",
        "geometry.radius = -1",
        "a finite length > 0 [m]",
    );
    case(
        "geometry.radius=0.001",
        "geometry.radius = 0.001",
        "radius >= 2 cells",
    );
    case("geometry.small=1", "geometry.small = 1", "0.5 <= small < 1");
    // no merging would let cells of 1e-23 of a cell into the flow (a run that never ends)
    case("geometry.small=0", "geometry.small = 0", "0.5 <= small < 1");
    case(
        "geometry.center=[0.2, 0.05]",
        "geometry.center",
        "a point inside the box",
    );
    case(
        "geometry.center=[0.05]",
        "geometry.center",
        "2 numbers, one per axis (x, z)",
    );
    case(
        "geometry.half_width=0.01",
        "geometry.half_width",
        "not a key of geometry.shape = \"drum\"",
    );
    case("geometry.shape=\"barrel\"", "geometry.shape", "drum");
    case("geometry.colour=1", "geometry", "unknown field");
    refused(
        &with_sets(
            &["run", "drum-settling", "--quiet"],
            &[
                "geometry.shape=\"drum-baffle\"",
                "geometry.baffle_thickness=0.005",
            ],
        ),
        "geometry.baffle_length",
        "required with geometry.shape = \"drum-baffle\"",
    );
}

#[test]
fn bad_shape_parameters_name_their_key() {
    let run = |sets: &[&'static str]| {
        with_sets(
            &["run", "drum-settling", "--quiet", "--set", "geometry={}"],
            sets,
        )
    };
    refused(
        &run(&[
            "geometry.shape=\"drum-baffle\"",
            "geometry.radius=0.045",
            "geometry.baffle_length=0.05",
            "geometry.baffle_thickness=0.005",
        ]),
        "geometry.baffle_length = 0.05",
        "0 < baffle_length < geometry.radius = 0.045",
    );
    refused(
        &run(&[
            "geometry.shape=\"drum-baffle\"",
            "geometry.radius=0.045",
            "geometry.baffle_length=0.02",
            "geometry.baffle_thickness=0.0005",
        ]),
        "geometry.baffle_thickness = 0.0005",
        "baffle_thickness >= one cell",
    );
    refused(
        &run(&[
            "geometry.shape=\"square-drum\"",
            "geometry.half_width=0.045",
            "geometry.angle=45",
        ]),
        "geometry.half_width = 0.045",
        "the turned square must fit in the box",
    );
    refused(
        &run(&[
            "geometry.shape=\"square-drum\"",
            "geometry.half_width=0.03",
            "geometry.angle=400",
        ]),
        "geometry.angle = 400",
        "-360 <= geometry.angle <= 360 [deg]",
    );
    refused(
        &run(&[
            "geometry.shape=\"hopper\"",
            "geometry.outlet_z=0.03",
            "geometry.outlet_width=0.01",
            "geometry.hopper_angle=90",
        ]),
        "geometry.hopper_angle = 90",
        "0 < hopper_angle < 90 [deg]",
    );
    refused(
        &run(&[
            "geometry.shape=\"hopper\"",
            "geometry.outlet_z=0.2",
            "geometry.outlet_width=0.01",
            "geometry.hopper_angle=30",
        ]),
        "geometry.outlet_z = 0.2",
        "0 < outlet_z < 0.1 [m]",
    );
}

#[test]
fn a_geometry_is_refused_where_cut_cells_do_not_run() {
    // a frozen flow does not run on cut cells: no silent fallback to the box
    refused(
        &[
            "run",
            "shear-cell",
            "--quiet",
            "--set",
            "geometry.shape=\"drum\"",
            "--set",
            "geometry.radius=0.01",
        ],
        "geometry",
        "allowed with \"prescribed\"",
    );
    // a 1D scene has no x-z plane
    refused(
        &[
            "run",
            "column-a",
            "--quiet",
            "--set",
            "geometry.shape=\"drum\"",
        ],
        "geometry = a 1D scene",
        "2D and 3D scenes only",
    );
}

#[test]
fn bad_frame_values_exit_2_with_one_line() {
    let settle = |set: &'static str| with_sets(&["run", "drum-settling", "--quiet"], &[set]);
    refused(
        &settle("frame.kind=\"rotating\""),
        "frame.kind",
        "\"rotating\" only with a solved flow",
    );
    refused(
        &settle("frame.rev_per_s=0.4"),
        "frame.rev_per_s = 0.4",
        "0 in the lab frame",
    );
    refused(&settle("frame.kind=\"spinning\""), "frame.kind", "lab");
    refused(&settle("frame.axis=\"y\""), "frame.axis", "nothing in 2D");
    let collapse = |sets: &[&'static str]| with_sets(&["run", "column-collapse", "--quiet"], sets);
    refused(
        &collapse(&["frame.kind=\"rotating\"", "frame.rev_per_s=11"]),
        "frame.rev_per_s = 11",
        "-10 <= rev_per_s <= 10 [rev/s]",
    );
    refused(
        &collapse(&["frame.kind=\"rotating\"", "frame.center=[0.1]"]),
        "frame.center",
        "2 numbers, one per axis (x, z)",
    );
    refused(
        &collapse(&[
            "frame.kind=\"rotating\"",
            "boundary.x=[\"periodic\", \"periodic\"]",
            "boundary.flow={}",
        ]),
        "frame.kind",
        "periodic axis x in the rotation plane",
    );
    refused(
        &collapse(&["frame.kind=\"rotating\"", "model.equations=\"frozen-flow\""]),
        "frame.kind",
        "no steady flow to freeze",
    );
}

#[test]
fn rotating_frame_of_a_coupled_flow_runs_and_is_the_lab_at_rest() {
    let summary = |sets: &[&str]| {
        let d = tempfile::tempdir().unwrap();
        let mut a = vec!["run", "column-collapse", "--t-end", "0.02", "--quiet"];
        for s in sets {
            a.push("--set");
            a.push(s);
        }
        let (code, _, err) = run_full(d.path(), &a);
        assert_eq!(code, 0, "{sets:?}: {err}");
        json(&d.path().join("runs/column-collapse/summary.json"))
    };
    let lab = summary(&[]);
    // a frame at rest is the lab frame up to its time step (the rotating frame's free-fall
    // limit takes |g| on both axes of the plane, docs/frames.md): same mass, same Psi to
    // first order in dt
    let rest = summary(&["frame.kind=\"rotating\"", "frame.rev_per_s=0"]);
    let psi = |s: &serde_json::Value| s["psi_final"].as_f64().unwrap();
    assert!(
        (psi(&lab) - psi(&rest)).abs() < 1e-3,
        "{} vs {}",
        psi(&lab),
        psi(&rest)
    );
    assert_eq!(lab["mass_initial"], rest["mass_initial"]);
    assert_eq!(rest["frame"]["kind"], "rotating");
    assert!(rest["frame"]["period"].is_null());
    // turning: other bits, mass still to round-off, the speed in the summary
    let turning = summary(&["frame.kind=\"rotating\"", "frame.rev_per_s=0.5"]);
    assert_ne!(lab["state_hash"], turning["state_hash"]);
    assert!(turning["mass_rel_drift"].as_f64().unwrap() < 1e-12);
    let f = &turning["frame"];
    assert_eq!(f["rev_per_s"].as_f64(), Some(0.5));
    assert!((f["omega"].as_f64().unwrap() - std::f64::consts::PI).abs() < 1e-15);
    assert_eq!(f["period"].as_f64(), Some(2.0));
    // default centre: the box centre (no geometry)
    assert_eq!(f["center"], serde_json::json!([0.08, 0.016]));
}

#[test]
fn a_3d_drum_slice_runs_on_cut_cells() {
    // the drum as a cylinder along y, periodic axial slice of 3 cells
    let d = tempfile::tempdir().unwrap();
    let args = with_sets(
        &["run", "drum-settling", "--t-end", "0.5", "--quiet"],
        &[
            "dim=3",
            "grid.cells=[24, 3, 24]",
            "grid.lower=[0.0, 0.0, 0.0]",
            "grid.upper=[0.1, 0.0125, 0.1]",
            "geometry.center=[0.05, 0.0, 0.05]",
            "physics.gravity=[0.0, 0.0, -9.81]",
            "initial.u=[0.0, 0.0, 0.0]",
            "boundary.y=[\"periodic\", \"periodic\"]",
        ],
    );
    let (code, _, err) = run_full(d.path(), &args);
    assert_eq!(code, 0, "{err}");
    let s = json(&d.path().join("runs/drum-settling/summary.json"));
    assert!(s["mass_rel_drift"].as_f64().unwrap() < 1e-12);
    assert_eq!(s["overshoot_max"].as_f64(), Some(0.0));
    assert_eq!(s["undershoot_max"].as_f64(), Some(0.0));
    // the cylinder's volume pi R^2 L, second order in h (24 cells: 1.2e-3)
    let exact = std::f64::consts::PI * 0.05 * 0.05 * 0.0125;
    let open = s["geometry"]["open_volume"].as_f64().unwrap();
    assert!(
        (open / exact - 1.0).abs() < 3e-3,
        "open volume {open} vs {exact}"
    );
    assert!(s["psi_final"].as_f64().unwrap() < 0.5);
}

/// A short coupled drum run (18 x 18, 1.5 rev/s, 0.2 s) into `dir/out`: exit 0, both phases
/// to round-off, bounds exact, nothing clipped; returns its summary.
fn short_drum_run(dir: &Path, scene: &str, out: &str) -> serde_json::Value {
    let args = [
        "run",
        scene,
        "--quiet",
        "--grid",
        "18x18",
        "--t-end",
        "0.2",
        "--set",
        "frame.rev_per_s=1.5",
        "--out",
        out,
    ];
    let (code, _, err) = run_full(dir, &args);
    assert_eq!(code, 0, "{scene}: {err}");
    let s = json(&dir.join(out).join("summary.json"));
    let drift = s["mass_rel_drift"].as_f64().unwrap();
    assert!(drift.abs() < 1e-12, "{scene}: small-grain drift {drift}");
    assert_eq!(s["overshoot_max"].as_f64().unwrap(), 0.0);
    assert_eq!(s["undershoot_max"].as_f64().unwrap(), 0.0);
    assert_eq!(s["frame"]["kind"], "rotating");
    assert_eq!(s["flow"]["clipped_mass"].as_f64().unwrap(), 0.0);
    s
}

#[test]
fn tumbler_runs_coupled_on_cut_cells_with_both_phases_to_round_off() {
    // The built-in tumbler (model.md 7.5: half-filled drum, rotating frame, back-coupling),
    // a short stretch on a coarse grid: flow and segregation on cut cells, the small grains
    // carried on the flow's face mass fluxes.
    let d = tempfile::tempdir().unwrap();
    let s = short_drum_run(d.path(), "tumbler", "t");
    assert_eq!(s["geometry"]["shape"], "drum");
    // rerun: the same bits
    let s2 = short_drum_run(d.path(), "tumbler", "t2");
    assert_eq!(s["state_hash"], s2["state_hash"]);
}

#[test]
fn tumbler_75_fills_three_quarters_of_the_drum_and_conserves_both_phases() {
    // The 75 % fill of model.md 7.5: the level z = 0.0702 m (0.404 R above the axis) holds
    // 3/4 of the drum's open area; phi = c/2 = 0.3 there, so the small-grain mass is
    // 0.3 * 0.75 * open area. The row the level crosses is filled in proportion, so on the
    // default 34 x 34 grid the fill is 0.7499 (a staircase level gave 0.733).
    let d = tempfile::tempdir().unwrap();
    let args = [
        "run",
        "tumbler-75",
        "--quiet",
        "--t-end",
        "0.05",
        "--set",
        "frame.rev_per_s=1.5",
        "--out",
        "t",
    ];
    let (code, _, err) = run_full(d.path(), &args);
    assert_eq!(code, 0, "{err}");
    let s = json(&d.path().join("t/summary.json"));
    let open = s["geometry"]["open_volume"].as_f64().unwrap();
    let fill = s["mass_initial"].as_f64().unwrap() / (0.3 * open);
    assert!((fill - 0.75).abs() < 1e-3, "fill {fill}");
    let drift = s["mass_rel_drift"].as_f64().unwrap();
    assert!(drift.abs() < 1e-12, "small-grain drift {drift}");
    assert_eq!(s["overshoot_max"].as_f64().unwrap(), 0.0);
    assert_eq!(s["undershoot_max"].as_f64().unwrap(), 0.0);
    assert_eq!(s["flow"]["clipped_mass"].as_f64().unwrap(), 0.0);
}

#[test]
fn psi_is_sampled_once_per_revolution() {
    // 1.5 rev/s: a period of 2/3 s, four outputs per revolution (interval 1/6 s), 1.4 s run:
    // revolutions 0, 1, 2 fall on output samples, so the summary's values are series.csv's.
    let d = tempfile::tempdir().unwrap();
    let args = [
        "run",
        "tumbler",
        "--quiet",
        "--grid",
        "18x18",
        "--t-end",
        "1.4",
        "--set",
        "frame.rev_per_s=1.5",
        "--set",
        "run.output_interval=0.16666666666666666",
        "--out",
        "t",
    ];
    let (code, _, err) = run_full(d.path(), &args);
    assert_eq!(code, 0, "{err}");
    let s = json(&d.path().join("t/summary.json"));
    let per_rev: Vec<f64> = s["frame"]["psi_per_revolution"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let series = columns(&d.path().join("t/series.csv"));
    let (t, psi) = (&series["t"], &series["psi"]);
    assert_eq!(per_rev.len(), 3, "{per_rev:?}");
    for (k, &p) in per_rev.iter().enumerate() {
        let at = k as f64 * 2.0 / 3.0;
        let j = t
            .iter()
            .position(|&x| (x - at).abs() < 1e-9)
            .expect("a sample");
        assert!(
            (p - psi[j]).abs() < 1e-12,
            "revolution {k}: {p} vs {}",
            psi[j]
        );
    }
    // mixed start: Psi = 1 (to the 1e-9 of the empty cells' c)
    assert!((per_rev[0] - 1.0).abs() < 1e-8, "{}", per_rev[0]);
    // Drum readouts over the last revolution (host/src/drum.rs; exact answers on a
    // constructed drum in drum_readouts.rs). Here: counter-clockwise at 1.5 rev/s the bed is
    // carried up on the right, so its surface rises to the right; the centre lies in the bed,
    // below the axis, and barely moves; the radial rings cover the bed.
    let drum = &s["drum"];
    assert_eq!(drum["window"][1].as_f64().unwrap(), 1.4);
    let angle = drum["angle_of_repose_deg"].as_f64().unwrap();
    assert!(angle > 0.0 && angle < 60.0, "angle of repose {angle}");
    let centre = [
        drum["circulation_centre"][0].as_f64().unwrap(),
        drum["circulation_centre"][1].as_f64().unwrap(),
    ];
    assert!(
        centre[1] < 0.0 && centre[0].hypot(centre[1]) < 0.05,
        "{centre:?}"
    );
    let omega_r = std::f64::consts::TAU * 1.5 * 0.05;
    let speed = drum["centre_speed"].as_f64().unwrap();
    assert!(
        speed < 0.2 * omega_r,
        "centre speed {speed} vs omega R {omega_r}"
    );
    let rings = drum["radial_about_centre"].as_array().unwrap();
    assert!(rings.iter().any(|r| r["cells"].as_u64().unwrap() > 0));
    assert!(d.path().join("t/radial.csv").exists());
    assert!(d.path().join("t/plots/radial.png").exists());
}

#[test]
fn square_tumbler_runs_in_its_rotating_frame_with_both_phases_to_round_off() {
    // A square drum is not rotation-invariant: only the rotating frame can solve it (issue 8).
    let d = tempfile::tempdir().unwrap();
    let s = short_drum_run(d.path(), "tumbler-square", "t");
    assert_eq!(s["geometry"]["shape"], "square-drum");
    // the square's open area (2 * 0.045)^2: flat walls are cut exactly, only the four corner
    // cells (two walls in one cell) are approximated, each by less than a cell
    let open = s["geometry"]["open_volume"].as_f64().unwrap();
    let cell = (0.10625f64 / 18.0).powi(2);
    let err = (open - 0.09f64.powi(2)).abs();
    assert!(
        err < 4.0 * cell,
        "open area {open}: {} cells off",
        err / cell
    );
    // not a circular drum: no drum readouts
    assert!(s.get("drum").is_none());
}

#[test]
fn three_d_tumblers_run_coupled_on_cut_cells_with_both_phases_to_round_off() {
    // The periodic axial slice and the drum closed by friction end walls (issue 8), on a
    // coarse grid for a few steps: the cylinder as a prism of cut cells along y, the frame
    // turning about y.
    for (scene, grid) in [("tumbler-3d", "16x4x16"), ("tumbler-3d-walls", "16x6x16")] {
        let d = tempfile::tempdir().unwrap();
        let args = [
            "run",
            scene,
            "--quiet",
            "--grid",
            grid,
            "--t-end",
            "0.1",
            "--set",
            "frame.rev_per_s=1.5",
            "--out",
            "t",
        ];
        let (code, _, err) = run_full(d.path(), &args);
        assert_eq!(code, 0, "{scene}: {err}");
        let s = json(&d.path().join("t/summary.json"));
        assert_eq!(s["dims"], 3);
        assert_eq!(s["geometry"]["shape"], "drum");
        assert_eq!(s["frame"]["kind"], "rotating");
        let drift = s["mass_rel_drift"].as_f64().unwrap();
        assert!(drift.abs() < 1e-12, "{scene}: small-grain drift {drift}");
        assert_eq!(s["overshoot_max"].as_f64().unwrap(), 0.0);
        assert_eq!(s["undershoot_max"].as_f64().unwrap(), 0.0);
        assert_eq!(s["flow"]["clipped_mass"].as_f64().unwrap(), 0.0);
        assert!(s["steps"].as_u64().unwrap() >= 5, "{scene}: it ran");
    }
}

/// The explicit pressure on the shipped tumbler past t = 1.9 - 2.0 s, where it used to run
/// away (model.md 5.3, "The solves' floor does not scale with the field's speed"): the
/// velocity solves' floor scaled with the field's largest speed, and the extrapolated guess
/// repeated the error it let through, so one cell gained 0.1 m/s per step until T ran away
/// and the step collapsed (2,046,098 steps to t = 1.92 s). Measured since (2026-12-04, 5 s):
/// 47,318 steps, T max 5.8e-3, largest speed 0.47 m/s. A relapse would take minutes to fail
/// on its own, so the run is killed after 10 minutes.
#[test]
fn explicit_tumbler_runs_past_the_old_runaway() {
    let d = tempfile::tempdir().unwrap();
    let o = assert_cmd::Command::cargo_bin("sieve")
        .unwrap()
        .current_dir(d.path())
        .args([
            "run",
            "tumbler",
            "--quiet",
            "--threads",
            "1",
            "--t-end",
            "2.2",
        ])
        .args(["--set", "flow.pressure=explicit", "--out", "x"])
        .timeout(std::time::Duration::from_secs(600))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = json(&d.path().join("x").join("summary.json"));
    assert_eq!(s["status"], "complete");
    let steps = s["steps"].as_u64().unwrap();
    let (t_max, speed) = (
        s["flow"]["t_max"].as_f64().unwrap(),
        s["flow"]["max_speed"].as_f64().unwrap(),
    );
    println!("explicit tumbler to 2.2 s: {steps} steps, T max {t_max:e}, speed {speed}");
    // ~1.1e-4 s steps (the acoustic limit of the packed bed): about 21,000
    assert!(steps < 30_000, "{steps} steps: the step collapsed");
    assert!(t_max < 0.05, "T max {t_max}");
    assert!(speed < 2.0, "largest speed {speed} m/s");
    let drift = s["mass_rel_drift"].as_f64().unwrap();
    assert!(drift.abs() < 1e-12, "small-grain drift {drift}");
    assert_eq!(s["overshoot_max"].as_f64().unwrap(), 0.0);
    assert_eq!(s["undershoot_max"].as_f64().unwrap(), 0.0);
}
