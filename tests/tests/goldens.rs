//! Golden state hashes of the flow, the coupled driver, and 2D and 3D runs (issue 11).
//!
//! Each case runs a short, fixed problem and hashes its final state bit for bit (FNV-1a 64 of
//! the little-endian bytes, `-0.0` canonicalised, see `sieve_core::hash`). A changed hash means
//! the numbers changed: on purpose (a new scheme, a fixed bug: re-mint and say why in the
//! commit) or not (an accidental change of operation order, a std transcendental slipping in,
//! a feature unification switching libm: find it). What each golden guards:
//!
//! | name | guards |
//! |---|---|
//! | `flow-1d-f64` | the flow step in 1D, f64: transport, pressure, gravity, implicit viscosity/conduction (CG), limiters, walls |
//! | `flow-1d-f32` | the same in f32 (the generic `Real` path, f32 rounding) |
//! | `flow-3d-friction` | the 3D flow step with Coulomb friction walls (model.md 2 wall law), 3D CG, 3D face loops |
//! | `coupled-collapse-2d` | `sieve run column-collapse` on 40 x 8: coupled flow + segregation (model.md 2-5), free-surface rules, hand-over; through the host (scene, expressions, run loop) |
//! | `frozen-shear-cell-2d` | `sieve run shear-cell` on 16 x 16: flow spin-up on 4 columns, freeze, replication, segregation in the frozen flow |
//! | `prescribed-2d-gray-thornton` | `sieve run gray-thornton-plug` on 40 x 20: 2D modified flux with inflow/outflow (model.md 5, 7.2) |
//! | `prescribed-3d-shear` | a 3D prescribed box, f64, periodic in x, T and phi from expressions: 3D segregation step and direction from gravity |
//! | `hopper-cut-cells-2d` | `sieve run hopper` on 15 x 50: cut-cell walls, merge groups and their wall terms on the masters (model.md 5.4), the orifice outlet, fines carried by the mass fluxes |
//! | `tumbler-rotating-2d` | `sieve run tumbler` on 18 x 18: a cut-cell drum in its rotating frame (model.md 2.5), implicit pressure, limited transport |
//!
//! The constants live in ONE file, `tests/goldens.txt` (`name = 0x<16 hex digits>`). To
//! re-mint every one of them after an intended change of the numerics:
//!
//! ```sh
//! SIEVE_REMINT=1 cargo test -p sieve-tests --test suite goldens::
//! ```
//!
//! which rewrites `tests/goldens.txt` with the hashes of this build (and passes); commit it
//! with the reason. Without `SIEVE_REMINT` the test compares every case and lists every
//! mismatch (not only the first). The 1D column-a and soft-sensor goldens keep their own
//! files (`column_a.rs`, `sensor_golden.rs`: the firmware checks the latter).

use sieve_core::closure::Material;
use sieve_core::flow::{Flow, FlowConfig, FlowSide, Slip};
use sieve_core::hash::Fnv64;
use sieve_core::{Grid, Real};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

fn golden_file() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("goldens.txt")
}

/// FNV-1a of a flow state: extents, time, then c, T, p and each velocity component.
fn flow_hash<R: Real, const D: usize, const N: usize>(f: &Flow<R, D, N>) -> u64 {
    let mut h = Fnv64::new();
    for n in f.grid().cells() {
        h.write_u32(n as u32);
    }
    f.time().hash_into(&mut h);
    let n = f.len();
    for i in 0..n {
        f.c(i).hash_into(&mut h);
    }
    for i in 0..n {
        f.temperature(i).hash_into(&mut h);
    }
    for i in 0..n {
        f.pressure(i).hash_into(&mut h);
    }
    for a in 0..D {
        for i in 0..n {
            f.velocity(i)[a].hash_into(&mut h);
        }
    }
    h.finish()
}

/// A dilute 1D column (c = 0.3 below z = 0.03 m, empty above) settling under gravity between
/// no-slip walls, 300 steps of the stable step.
fn flow_1d<R: Real>() -> u64 {
    const N: usize = 64;
    let grid = Grid::<R, 1>::new([N], [R::ZERO], [R::from_f64(0.04)], N).unwrap();
    let mut f: Box<Flow<R, 1, N>> = Box::new(Flow::zeroed());
    let wall = FlowSide::wall(Slip::NoSlip);
    f.setup(
        grid,
        [[wall, wall]],
        FlowConfig::new(Material::glass_beads()),
    )
    .unwrap();
    for i in 0..N {
        let c = if i < 48 { 0.3 } else { 1e-9 };
        f.set_cell(i, R::from_f64(c), [R::ZERO], R::from_f64(1e-3));
    }
    f.prepare().unwrap();
    for _ in 0..300 {
        f.step(f.stable_dt());
    }
    flow_hash(&*f)
}

/// The 3D dilute column of `flow_boundaries.rs` (4 x 4 x 16, friction walls), 150 steps.
fn flow_3d() -> u64 {
    const N: usize = 4 * 4 * 16;
    let grid = Grid::new([4, 4, 16], [0.0; 3], [0.01, 0.01, 0.04], N).unwrap();
    let mut cfg = FlowConfig::new(Material::glass_beads());
    cfg.t_min = 1e-10;
    let wall = FlowSide::wall(Slip::Friction(0.2));
    let mut f: Box<Flow<f64, 3, N>> = Box::new(Flow::zeroed());
    f.setup(grid, [[wall, wall]; 3], cfg).unwrap();
    for i in 0..N {
        let x = grid.center(i);
        // a little asymmetry so that x and y are not mirror images of each other
        let c = 0.3 + 0.02 * (x[0] / 0.01) + 0.01 * (x[1] / 0.01);
        f.set_cell(i, c, [0.0; 3], 0.0);
    }
    f.prepare().unwrap();
    for _ in 0..150 {
        f.step(f.stable_dt());
    }
    flow_hash(&*f)
}

/// `sieve run SCENE --set ...` through the host library; the summary's state hash.
fn host_run(spec: &str, sets: &[&str]) -> u64 {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let (scene, fields) = sieve::scene::load(spec, &sets).unwrap();
    let out = tempfile::tempdir().unwrap();
    let opts = sieve::run::RunOptions {
        out: out.path().join("run"),
        quiet: true,
    };
    let summary = sieve::run::run_scene(&scene, &fields, &opts).unwrap();
    u64::from_str_radix(&summary.state_hash, 16).unwrap()
}

const BOX_3D: &str = r#"
name = "golden-box3"
dim = 3
[grid]
cells = [8, 4, 16]
lower = [0, 0, 0]
upper = [1, 0.5, 1]
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
t_end = 0.3
output_interval = 0.1
"#;

fn cases() -> Vec<(&'static str, u64)> {
    let box3 = tempfile::tempdir().unwrap();
    let box3_file = box3.path().join("golden-box3.toml");
    std::fs::write(&box3_file, BOX_3D).unwrap();
    let box3_path = box3_file.to_str().unwrap().to_string();
    let mut v = Vec::new();
    let (tx, rx) = std::sync::mpsc::channel();
    // The flow solvers are large values: build them on a big stack.
    sieve_tests::run_big(move || {
        let r = vec![
            ("flow-1d-f64", flow_1d::<f64>()),
            ("flow-1d-f32", flow_1d::<f32>()),
            ("flow-3d-friction", flow_3d()),
        ];
        tx.send(r).unwrap();
    });
    v.extend(rx.recv().unwrap());
    v.push((
        "coupled-collapse-2d",
        host_run(
            "column-collapse",
            &[
                "grid.cells=[40, 8]",
                "run.t_end=0.02",
                "run.output_interval=0.01",
            ],
        ),
    ));
    v.push((
        "frozen-shear-cell-2d",
        host_run(
            "shear-cell",
            &[
                "grid.cells=[16, 16]",
                "run.t_end=20",
                "run.output_interval=10",
            ],
        ),
    ));
    v.push((
        "prescribed-2d-gray-thornton",
        host_run(
            "gray-thornton-plug",
            &[
                "grid.cells=[40, 20]",
                "run.t_end=1",
                "run.output_interval=0.5",
            ],
        ),
    ));
    v.push(("prescribed-3d-shear", host_run(&box3_path, &[])));
    v.push((
        "hopper-cut-cells-2d",
        host_run(
            "hopper",
            &[
                "grid.cells=[15, 50]",
                "run.t_end=0.15",
                "run.output_interval=0.05",
            ],
        ),
    ));
    v.push((
        "tumbler-rotating-2d",
        host_run(
            "tumbler",
            &[
                "grid.cells=[18, 18]",
                "run.t_end=0.2",
                "run.output_interval=0.1",
            ],
        ),
    ));
    v
}

fn read_goldens(text: &str) -> BTreeMap<String, u64> {
    text.lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .filter_map(|l| {
            let (k, v) = l.split_once('=')?;
            let v = v.trim().trim_start_matches("0x");
            Some((k.trim().to_string(), u64::from_str_radix(v, 16).ok()?))
        })
        .collect()
}

const HEADER: &str = "\
# Golden state hashes of tests/tests/goldens.rs (what each guards: see that file's header).
# Re-mint all of them after an intended change of the numerics, and commit with the reason:
#   SIEVE_REMINT=1 cargo test -p sieve-tests --test suite goldens::
";

#[test]
fn golden_state_hashes() {
    let got = cases();
    for (name, h) in &got {
        println!("{name} = 0x{h:016x}");
    }
    if std::env::var_os("SIEVE_REMINT").is_some() {
        let mut text = HEADER.to_string();
        for (name, h) in &got {
            text.push_str(&format!("{name} = 0x{h:016x}\n"));
        }
        std::fs::write(golden_file(), text).unwrap();
        println!("re-minted {}", golden_file().display());
        return;
    }
    let text = std::fs::read_to_string(golden_file()).unwrap_or_default();
    let want = read_goldens(&text);
    let mut bad = Vec::new();
    for (name, h) in &got {
        match want.get(*name) {
            Some(w) if w == h => {}
            Some(w) => bad.push(format!("{name}: got 0x{h:016x}, golden 0x{w:016x}")),
            None => bad.push(format!("{name}: no golden in tests/goldens.txt")),
        }
    }
    assert!(
        bad.is_empty(),
        "golden mismatches (if intended: SIEVE_REMINT=1 cargo test -p sieve-tests --test suite goldens::):\n{}",
        bad.join("\n")
    );
}

/// Two runs in one process give the same bits (no state leaks between runs, no order
/// dependence), on the cheapest cases.
#[test]
fn golden_cases_rerun_bit_identically() {
    let (tx, rx) = std::sync::mpsc::channel();
    sieve_tests::run_big(move || {
        tx.send((flow_1d::<f32>(), flow_1d::<f32>())).unwrap();
    });
    let (a, b) = rx.recv().unwrap();
    assert_eq!(a, b);
}
