//! A settled fill (model.md 5.8, scene key `initial.fill = "settled"`): a cold bed packed so
//! that the flow step's discrete balance holds on every face, so it stays at rest. The
//! uniform fill of the silo (c = 0.6 to 0.4 m) holds `p_y(0.6)` at every depth and expands
//! upwards when released (`flow_surface_release.rs`); the settled bed of the same material
//! and height does not move.
//!
//! Asserted: the column of `flow_surface_release.rs` settled by the core's `settle_run`
//! stays at rest for 10 ms on 0.625 / 0.3125 / 0.156 mm cells (f64 and f32); the scene path
//! (`sieve::scene::load`) packs every silo column from top to floor, keeps phihat, leaves
//! the air alone and holds the grain volume the continuous lithostatic profile gives; bad
//! uses are refused with one line naming the key.

use crate::silo_common::silo_material;
use sieve_core::closure::{yield_pressure, Material};
use sieve_core::flow::rest::settle_run;
use sieve_core::flow::{Flow, FlowConfig, FlowSide, Slip};
use sieve_core::{Grid, Real};
use sieve_tests::run_big;

const N: usize = 1024;
const HEIGHT: f64 = 0.1;
const FILL: f64 = 0.08;
const T_END: f64 = 0.01;

/// Largest speed over 10 ms and largest change of c of the settled column on `cells` cells.
fn settled_column<R: Real>(cells: usize) -> (f64, f64) {
    let m = silo_material();
    let mat = Material {
        eta0: R::from_f64(m.eta0),
        lambda0: R::from_f64(m.lambda0),
        eps0: R::from_f64(m.eps0),
        t0: R::from_f64(m.t0),
        phi_rcp: R::from_f64(m.phi_rcp),
        phi_rlp: R::from_f64(m.phi_rlp),
        heating: R::from_f64(m.heating),
        s0: R::from_f64(m.s0),
    };
    let mut flow: Box<Flow<R, 2, N>> = Box::new(Flow::zeroed());
    let h = HEIGHT / cells as f64;
    let r = R::from_f64;
    let grid = Grid::new([1, cells], [R::ZERO; 2], [r(h), r(HEIGHT)], N).unwrap();
    let mut cfg = FlowConfig::new(mat);
    cfg.gravity = [R::ZERO, r(-9.81)];
    cfg.t_min = r(1e-8);
    cfg.cg_tolerance = r(1e-5);
    cfg.free_surface_push = true;
    let wall = FlowSide::wall(Slip::Friction(r(30f64.to_radians().tan())));
    flow.setup(grid, [[FlowSide::periodic(); 2], [wall, wall]], cfg)
        .unwrap();
    let bed = (0..cells)
        .filter(|&i| grid.center(i)[1].to_f64() < FILL)
        .count();
    // top first
    let mut c = vec![R::ZERO; bed];
    settle_run(
        r(9.81 * h),
        mat.t0,
        &vec![mat.phi_rcp; bed],
        &vec![mat.phi_rlp; bed],
        &mut c,
    );
    for i in 0..cells {
        let ci = if i < bed { c[bed - 1 - i] } else { r(1e-9) };
        flow.set_cell(i, ci, [R::ZERO; 2], R::ZERO);
    }
    flow.prepare().unwrap();
    let c0: Vec<f64> = (0..cells).map(|i| flow.c(i).to_f64()).collect();
    let (mut speed, mut dc) = (0.0f64, 0.0f64);
    while flow.time() < r(T_END) {
        let dt = flow.stable_dt().min(r(T_END) - flow.time());
        flow.step(dt);
        for i in 0..bed {
            speed = speed.max(flow.velocity(i)[1].to_f64().abs());
            dc = dc.max((flow.c(i).to_f64() - c0[i]).abs());
        }
    }
    (speed, dc)
}

#[test]
fn a_settled_column_stays_at_rest() {
    run_big(|| {
        for n in [160, 320, 640] {
            let (s64, dc64) = settled_column::<f64>(n);
            let (s32, dc32) = settled_column::<f32>(n);
            println!("{n} cells: max |u| {s64:.3e} / {s32:.3e} m/s, max |dc| {dc64:.3e} / {dc32:.3e} (f64 / f32)");
            // the uniform fill's surface rises at ~0.8 m/s after 10 ms (flow_surface_release.rs)
            assert!(s64 < 1e-9 && dc64 < 1e-12, "{n}: {s64} {dc64}");
            assert!(s32 < 1e-3 && dc32 < 1e-5, "{n}: {s32} {dc32}");
        }
    });
}

/// The silo's fields with `initial.fill = "settled"` (5 mm cells, back-coupling "half",
/// phihat 1/2): every column packs from just above `c_rlp(1/2)` under the surface to its
/// floor, the air keeps its c, phihat is kept, and a column's grain volume is `p_floor / g`
/// with the floor pressure of the continuous profile
/// `g H = p_f / c_rcp + T0 (1 - c_rlp / c_rcp) ln(1 + p_f / (T0 c_rlp))`, H = 0.4 m.
#[test]
fn the_settled_silo_packs_every_column_under_its_weight() {
    let sets = ["initial.fill=settled".to_string()];
    let (scene, f) = sieve::scene::load("silo", &sets).expect("scene");
    let (nx, nz) = (scene.cells[0], scene.cells[1]);
    let h = scene.spacing()[1];
    let m = silo_material();
    let (rcp, rlp) = sieve_core::closure::Packing::FitHalf.limits(&m, 0.5);
    // the continuous floor pressure, by bisection
    let depth = |p: f64| p / rcp + m.t0 * (1.0 - rlp / rcp) * (1.0 + p / (m.t0 * rlp)).ln();
    let (mut lo, mut hi) = (0.0, 100.0);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if depth(mid) < 9.81 * 0.4 {
            lo = mid
        } else {
            hi = mid
        }
    }
    let volume_exact = lo / 9.81;
    for x in 0..nx {
        let col: Vec<f64> = (0..nz).map(|z| f.c[x + nx * z]).collect();
        let bed = col.iter().filter(|&&c| c >= 0.05).count();
        assert_eq!(bed, 80, "column {x}");
        assert!(col[bed..].iter().all(|&c| c == 1e-9), "air, column {x}");
        assert!(
            col[bed - 1] > rlp && col[bed - 1] < rlp + 0.01,
            "{}",
            col[bed - 1]
        );
        assert!(col[..bed].windows(2).all(|w| w[0] > w[1]), "column {x}");
        for z in 0..bed {
            let i = x + nx * z;
            assert!((f.phi[i] / f.c[i] - 0.5).abs() < 1e-15);
            // the compact balance with the top cell's surface condition
            let p = |z: usize| yield_pressure(col[z], rcp, rlp, m.t0);
            let face = if z + 1 < bed {
                (p(z) - p(z + 1)) / h - 9.81 * (col[z] + col[z + 1]) / 2.0
            } else {
                p(z) / h - 9.81 * col[z] / 2.0
            };
            assert!(
                face.abs() < 1e-10 * p(0) / h,
                "column {x}, cell {z}: {face}"
            );
        }
        let volume: f64 = col[..bed].iter().sum::<f64>() * h;
        if x == 0 {
            println!(
                "settled silo column: c {:.5} (floor) .. {:.5} (top), grain volume {volume:.6e} m \
                 (continuous {volume_exact:.6e}, {:+.2e} rel.)",
                col[0],
                col[bed - 1],
                volume / volume_exact - 1.0
            );
        }
        assert!(
            (volume / volume_exact - 1.0).abs() < 1e-3,
            "{volume} {volume_exact}"
        );
    }
}

/// Each misuse is refused with one line naming the key and what is allowed; the tumbler in
/// the lab frame (gravity fixed, the drum wall turning) may start settled.
#[test]
fn settled_fill_misuse_names_the_key() {
    let lab = ["initial.fill=settled", "frame.kind=\"lab\""].map(String::from);
    let (_, settled) = sieve::scene::load("tumbler", &lab).expect("a lab-frame drum settles");
    let (_, given) = sieve::scene::load("tumbler", &lab[1..]).expect("the lab-frame drum");
    // every bed cell repacked (the drum's given c = 0.6 is below the beads' c_rlp: loose)
    let bed = given.c.iter().filter(|&&c| c >= 0.05).count();
    let moved = (0..given.c.len())
        .filter(|&i| given.c[i] >= 0.05 && settled.c[i] != given.c[i])
        .count();
    println!("lab-frame drum: {moved} of {bed} bed cells repacked");
    assert!(bed > 100 && moved == bed, "{moved} of {bed}");
    let cases: [(&str, &[&str], &str); 5] = [
        (
            "column-a",
            &[],
            "initial.fill = \"settled\" is out of range: allowed \"given\" unless the flow is solved",
        ),
        (
            "tumbler",
            &[],
            "initial.fill = \"settled\" is out of range: allowed \"given\" in a rotating frame",
        ),
        (
            "silo",
            &["physics.gravity=[1.0,-9.81]"],
            "allowed \"given\" unless physics.gravity points along one axis",
        ),
        (
            "silo",
            &["initial.T=0.1"],
            "is out of range: allowed 0 in the bed with initial.fill = \"settled\"",
        ),
        (
            "silo",
            &["physics.gravity=[0.0,-2e5]"],
            "is out of range: allowed a bed shallow enough to stay below the flow's c_max",
        ),
    ];
    for (scene, extra, want) in cases {
        let mut sets = vec!["initial.fill=settled".to_string()];
        sets.extend(extra.iter().map(|s| s.to_string()));
        let err = sieve::scene::load(scene, &sets)
            .err()
            .unwrap_or_else(|| panic!("{scene} {extra:?}: accepted"));
        assert_eq!(err.exit_code(), 2, "{err}");
        let e = err.to_string();
        println!("{e}");
        let line = e
            .lines()
            .find(|l| l.contains(want))
            .unwrap_or_else(|| panic!("{scene} {extra:?}: {e}"));
        assert!(line.starts_with("scenes/"), "{line}");
        assert!(line.contains(": initial."), "{line}");
    }
}
