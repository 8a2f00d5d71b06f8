//! Frame equivalence of the circular 50 % drum with the objective stress (issue 8; model.md
//! 2.6, docs/frames.md): the built-in `tumbler` (34 x 34, D = 0.1 m, glass beads, mixed
//! start, 0.1 rev/s, coupled flow and segregation on cut cells, implicit pressure) with
//! `flow.stress = "objective"` and a no-slip drum wall, run for 5 s (half a revolution) once in
//! the lab frame (the cut wall turns at omega R) and once in the drum's rotating frame. The
//! readouts (host/src/drum.rs, over the second half of the run, mapped into the lab) and the
//! fines core (the phi-weighted centroid of the cells with phihat > 0.75, rotated back into
//! the lab by omega t) must agree.
//!
//! Why no-slip in the main test: until stop 17 the cut wall's friction passed next to none of
//! the Coulomb stress to a stiff bed (docs/model.md 2.4, `Flow::wall_law`), so from rest in the
//! lab the wall slid under a flat bed. With that mended, the second test runs the scene's own
//! 11 deg friction wall in both frames and checks the bed's geometry.
//!
//! Measured (lab / rotating, h = 3.1 mm, limited transport as the scene declares, with the
//! implicit pressure's viscous share since 2026-12-06): dynamic angle 22.33 / 22.25 deg,
//! flowing layer 10.9 / 14.8 mm, circulation centre (4.7, -7.8) / (7.8, -10.9) mm from the axis,
//! fines core (3.0, -14.5) / (4.9, -14.5) mm, phihat at the centre 0.994 / 0.997, Psi(5 s)
//! 0.569 / 0.341. Before the share the angles were 20.58 / 21.52 deg (the bed's creep at the
//! long step lowered the lab's more), so the angle is now asserted within 0.5 deg, a third of
//! half a cell over the fitted width (atan(h / 2 / 60 mm) = 1.5 deg). The layer readout walks
//! down the surface normal in quarter cells through the lab grid's cells and jumps by up to
//! 1.5 cells (10.2 or 10.9 <-> 14.8 mm): at `flow.courant` 0.1 both frames give 10.9 mm, the
//! rotating frame's 14.8 at 0.4 is one such jump (before the share it was 10.9 at 0.4 and 14.8
//! at 0.1); asserted within 2 cells.
//!
//! Psi differs most, at D = 0, where nothing in the model remixes: there
//! Psi measures the width of the core's numerical edge, and the lab frame carries the whole bed
//! across the grid where the rotating frame keeps its solid-body part at rest on it. The lab
//! behaves like the rotating frame with an extra diffusivity of 1.8e-5 / 0.9e-5 / 0.55e-5
//! m^2/s on 34 / 48 / 68 cells, and the gap closes, 0.207 -> 0.189 -> 0.138 (docs/frames.md,
//! "Where the Psi gap comes from", with what was ruled out: the time step, the lab bulk's
//! warmth, the cut cells, the moving wall's heat). With a remixing diffusivity of 1e-4 m^2/s
//! the frames agree on Psi(t) within 0.04, asserted.

use assert_cmd::Command;
use std::f64::consts::TAU;
use std::path::Path;

const T_END: f64 = 5.0;
const REV_PER_S: f64 = 0.1;
/// Cell size of the 34 x 34 tumbler [m].
const H: f64 = 0.10625 / 34.0;
const AXIS: [f64; 2] = [0.05, 0.05];
/// How far the two frames' dynamic angles may differ [deg] (module docs).
const ANGLE_DEG: f64 = 0.5;
/// How far their flowing-layer readouts may differ [m]: 2 cells (module docs).
const LAYER: f64 = 2.0 * H;

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn run_with(dir: &Path, out: &str, frame: &str, extra: &[&str]) {
    let o = Command::cargo_bin("sieve")
        .unwrap()
        .current_dir(dir)
        .args(["run", "tumbler", "--quiet", "--out", out])
        .args(["--t-end", &T_END.to_string()])
        .args(["--set", "flow.stress=\"objective\""])
        .args(["--set", &format!("frame.kind=\"{frame}\"")])
        .args(extra)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// Columns `names` of every row of a CSV file.
fn csv(path: &Path, names: &[&str]) -> Vec<Vec<f64>> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    let cols: Vec<usize> = names
        .iter()
        .map(|n| head.iter().position(|h| h == n).unwrap())
        .collect();
    lines
        .map(|l| {
            let f: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            cols.iter().map(|&c| f[c]).collect()
        })
        .collect()
}

/// Runs the tumbler (objective stress, `extra` settings) in the lab frame into `dir/lab` and in
/// the rotating frame into `dir/rot`, side by side; returns their summaries after checking what
/// every run keeps: the stress and end time asked, mass to round-off, 0 <= phi <= c exactly.
fn both_frames(dir: &Path, extra: &[&str]) -> (serde_json::Value, serde_json::Value) {
    std::thread::scope(|s| {
        s.spawn(|| run_with(dir, "lab", "lab", extra));
        s.spawn(|| run_with(dir, "rot", "rotating", extra));
    });
    let lab = json(&dir.join("lab/summary.json"));
    let rot = json(&dir.join("rot/summary.json"));
    for s in [&lab, &rot] {
        assert_eq!(s["flow"]["stress"], "objective");
        assert_eq!(s["t_end"].as_f64().unwrap(), T_END);
        assert!(s["mass_rel_drift"].as_f64().unwrap().abs() < 1e-12);
        // 0 <= phi <= c exactly
        assert_eq!(s["overshoot_max"].as_f64().unwrap(), 0.0);
        assert_eq!(s["undershoot_max"].as_f64().unwrap(), 0.0);
    }
    (lab, rot)
}

/// A number of the summary's drum readouts.
fn drum(s: &serde_json::Value, k: &str) -> f64 {
    s["drum"][k].as_f64().unwrap()
}

/// Centroid of the fines core in the lab, relative to the axis: the phi-weighted centroid of
/// the dense cells (c > 0.3) with phihat > 0.75, rotated by `angle` about the axis.
fn fines_core(path: &Path, angle: f64) -> [f64; 2] {
    let (s, co) = angle.sin_cos();
    let (mut w, mut x, mut z) = (0.0, 0.0, 0.0);
    for r in csv(path, &["x", "z", "c", "phi", "phihat", "volume"]) {
        if r[2] > 0.3 && r[4] > 0.75 {
            let m = r[3] * r[5];
            let (dx, dz) = (r[0] - AXIS[0], r[1] - AXIS[1]);
            w += m;
            x += m * (co * dx - s * dz);
            z += m * (s * dx + co * dz);
        }
    }
    assert!(w > 0.0, "no fines core");
    [x / w, z / w]
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
}

#[test]
fn lab_and_rotating_frames_tell_the_same_story_with_the_objective_stress() {
    let d = tempfile::tempdir().unwrap();
    let (lab, rot) = both_frames(
        d.path(),
        &["--set", "boundary.flow.z_low={wall=\"no-slip\"}"],
    );
    let f = drum;
    let v = |s: &serde_json::Value, k: &str| -> [f64; 2] {
        let a = s["drum"][k].as_array().unwrap();
        [a[0].as_f64().unwrap(), a[1].as_f64().unwrap()]
    };
    let (al, ar) = (
        f(&lab, "angle_of_repose_deg"),
        f(&rot, "angle_of_repose_deg"),
    );
    let (ll, lr) = (
        f(&lab, "flowing_layer_thickness"),
        f(&rot, "flowing_layer_thickness"),
    );
    let (cl, cr) = (v(&lab, "circulation_centre"), v(&rot, "circulation_centre"));
    let kl = fines_core(&d.path().join("lab/final.csv"), 0.0);
    let kr = fines_core(&d.path().join("rot/final.csv"), TAU * REV_PER_S * T_END);
    let pl = csv(&d.path().join("lab/series.csv"), &["t", "psi"]);
    let pr = csv(&d.path().join("rot/series.csv"), &["t", "psi"]);
    println!(
        "angle {al:.2} / {ar:.2} deg, layer {:.1} / {:.1} mm, centre {:.1?} / {:.1?} mm, fines \
         core {:.1?} / {:.1?} mm, centre phihat {:.3} / {:.3}, Psi(5 s) {:.3} / {:.3}",
        ll * 1e3,
        lr * 1e3,
        cl.map(|x| x * 1e3),
        cr.map(|x| x * 1e3),
        kl.map(|x| x * 1e3),
        kr.map(|x| x * 1e3),
        f(&lab, "centre_phihat"),
        f(&rot, "centre_phihat"),
        pl.last().unwrap()[1],
        pr.last().unwrap()[1],
    );
    // The bed turns with the drum in both frames: a sloped surface, a flowing layer.
    assert!(ar > 15.0 && ar < 30.0, "{ar}");
    assert!((al - ar).abs() < ANGLE_DEG, "angle {al} vs {ar}");
    assert!((ll - lr).abs() < LAYER, "layer {ll} vs {lr}");
    assert!(dist(cl, cr) < 2.0 * H, "centre {cl:?} vs {cr:?}");
    // The fines gather in the same place of the lab, below the surface near the centre.
    assert!(dist(kl, kr) < 2.0 * H, "fines core {kl:?} vs {kr:?}");
    assert!(f(&lab, "centre_phihat") > 0.8 && f(&rot, "centre_phihat") > 0.8);
    // Psi(t): both fall from 1 at the same outputs; the lab frame's transport smears phi
    // more (module docs), so it stays above the rotating frame's, by at most 0.3 over 5 s.
    assert_eq!(pl.len(), pr.len());
    for (a, b) in pl.iter().zip(&pr) {
        assert_eq!(a[0], b[0]);
        assert!(a[1] <= 1.0 && b[1] <= 1.0);
        assert!(
            a[1] - b[1] > -0.01 && a[1] - b[1] < 0.3,
            "Psi({}) {} vs {}",
            a[0],
            a[1],
            b[1]
        );
    }
    assert!(pl.last().unwrap()[1] < 0.9 && pr.last().unwrap()[1] < 0.9);
}

/// With a remixing diffusivity (`material.diffusion = 1e-4` m^2/s, the value of the refinement
/// study in docs/tumbler.md) the two frames agree on Psi(t): the gap of the main test is the
/// lab frame's extra numerical diffusion of a bed that crosses the grid, worth an effective
/// diffusivity of about 1e-5 m^2/s on this grid (docs/frames.md, "Where the Psi gap comes
/// from"), small against 1e-4. Measured (34 x 34, limited transport): the gap within
/// [-0.011, +0.029] over the 0.5 s outputs (the first avalanche comes at slightly different
/// times), +0.021 at 5 s (Psi 0.913 / 0.893); at D = 0 the same runs end 0.207 apart.
#[test]
fn with_a_remixing_diffusivity_the_frames_agree_on_psi() {
    let d = tempfile::tempdir().unwrap();
    let (lab, rot) = both_frames(
        d.path(),
        &[
            "--set",
            "boundary.flow.z_low={wall=\"no-slip\"}",
            "--set",
            "material.diffusion=1e-4",
        ],
    );
    let pl = csv(&d.path().join("lab/series.csv"), &["t", "psi"]);
    let pr = csv(&d.path().join("rot/series.csv"), &["t", "psi"]);
    assert_eq!(pl.len(), pr.len());
    let gaps: Vec<f64> = pl.iter().zip(&pr).map(|(a, b)| a[1] - b[1]).collect();
    println!(
        "D = 1e-4: Psi(5 s) {:.3} / {:.3}, gaps {:.3?}",
        pl.last().unwrap()[1],
        pr.last().unwrap()[1],
        gaps
    );
    for (a, g) in pl.iter().zip(&gaps) {
        assert!(g.abs() < 0.04, "Psi({}) gap {g}", a[0]);
    }
    // and the bed did segregate in both frames (the diffuse core at D = 1e-4 has too few
    // cells above phihat 0.75 for the main test's centroid to mean much)
    assert!(pl.last().unwrap()[1] < 0.95 && pr.last().unwrap()[1] < 0.95);
    assert!(drum(&lab, "centre_phihat") > 0.7 && drum(&rot, "centre_phihat") > 0.7);
}

/// The scene's own wall, 11 deg of Coulomb friction, in both frames: the lab wall drags the
/// bed up to the same dynamic angle (the wall law passes the Coulomb stress to the stiff bed,
/// `Flow::wall_law`). Measured (lab / rotating): angle 22.33 / 22.33 deg, flowing layer 10.2 /
/// 14.8 mm (before the viscous share 20.49 / 21.55 deg, 9.4 / 10.9 mm); before stop 17 the lab
/// bed slid flat (angle 0).
#[test]
fn with_the_friction_wall_the_lab_bed_turns_up_as_in_the_rotating_frame() {
    let d = tempfile::tempdir().unwrap();
    let (lab, rot) = both_frames(d.path(), &[]);
    let f = drum;
    let (al, ar) = (
        f(&lab, "angle_of_repose_deg"),
        f(&rot, "angle_of_repose_deg"),
    );
    let (ll, lr) = (
        f(&lab, "flowing_layer_thickness"),
        f(&rot, "flowing_layer_thickness"),
    );
    println!(
        "friction wall: angle {al:.2} / {ar:.2} deg, layer {:.1} / {:.1} mm",
        ll * 1e3,
        lr * 1e3
    );
    assert!(ar > 15.0 && ar < 30.0, "{ar}");
    assert!((al - ar).abs() < ANGLE_DEG, "angle {al} vs {ar}");
    assert!((ll - lr).abs() < LAYER, "layer {ll} vs {lr}");
}

#[test]
fn a_bad_stress_name_exits_2_with_one_line() {
    let o = Command::cargo_bin("sieve")
        .unwrap()
        .args(["run", "tumbler", "--quiet", "--t-end", "0.01"])
        .args(["--set", "flow.stress=\"symmetric\""])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains("flow.stress"), "{err}");
    assert!(err.contains("`spec` or `objective`"), "{err}");
}
