//! README and docs numbers that no other test holds (issue 10): each is read from the document
//! and asserted against what the code computes, so editing one without the other fails.
//!
//! * README "Raising the capacity": bytes per cell of capacity of `Segregation` and `Flow`
//!   (the `size_of` table) and the solver memory derived from it (the peak RSS values need a
//!   release run of `sieve` and are not asserted here).
//! * docs/soft-sensor.md "`sieve record` scene (defaults), then `sieve replay`" table and the
//!   README's soft-sensor sentence: the two prescribed rows (`shear-cell-mixed`,
//!   `gray-thornton-shear`). The frozen-flow shear-cell rows (16,327 frames) are minutes of
//!   work each and stay "measured once". These compare the estimator with the scene's own run
//!   (the recorder's truth); the estimator against an independent exact solution is
//!   `sensor_accuracy.rs`.
//! * README "Verification": column-a shock positions at t = 0.5 on 200 cells, the L1 errors on
//!   100..800 cells and their observed order, against the exact solution of model.md 7.1a
//!   written here (shocks at S m t and 1 - S (1 - m) t; `sieve_core::exact` is not used).

use crate::readme;

use crate::common::{centres, column, crossing, observed_order, phihat, Column};
use sieve_core::{Phase, Scheme};

use sieve::soft_sensor::{record_scene, replay_bytes, ReplayOptions, SceneRecordOptions};
use sieve_core::flow::Flow;
use sieve_core::Segregation;

/// Bytes per cell of capacity: `size_of` of the solver at capacity 65,536, divided by it
/// (the fixed part, grid and configuration, is far below a byte per cell).
fn per_cell<T>() -> f64 {
    std::mem::size_of::<T>() as f64 / 65536.0
}

#[test]
fn capacity_table_bytes_per_cell() {
    const N: usize = 65536;
    let doc = readme::readme();
    let seg = readme::numbers(readme::after(
        readme::table_row(doc, "`Segregation`, f64 / f32"),
        "f32 |",
    ));
    let flow = readme::numbers(readme::after(
        readme::table_row(doc, "`Flow` (flow scenes, in addition), f64 / f32"),
        "f32 |",
    ));
    assert_eq!((seg.len(), flow.len()), (6, 6), "{seg:?} {flow:?}");
    let computed_seg = [
        per_cell::<Segregation<f64, 1, N>>(),
        per_cell::<Segregation<f32, 1, N>>(),
        per_cell::<Segregation<f64, 2, N>>(),
        per_cell::<Segregation<f32, 2, N>>(),
        per_cell::<Segregation<f64, 3, N>>(),
        per_cell::<Segregation<f32, 3, N>>(),
    ];
    let computed_flow = [
        per_cell::<Flow<f64, 1, N>>(),
        per_cell::<Flow<f32, 1, N>>(),
        per_cell::<Flow<f64, 2, N>>(),
        per_cell::<Flow<f32, 2, N>>(),
        per_cell::<Flow<f64, 3, N>>(),
        per_cell::<Flow<f32, 3, N>>(),
    ];
    println!("Segregation {computed_seg:?}\nFlow {computed_flow:?}");
    for (k, (c, s)) in computed_seg.iter().zip(&seg).enumerate() {
        readme::check(&format!("Segregation bytes per cell, column {k}"), *c, s);
    }
    for (k, (c, s)) in computed_flow.iter().zip(&flow).enumerate() {
        readme::check(&format!("Flow bytes per cell, column {k}"), *c, s);
    }
    // the memory the README derives from them (f64, 2D capacity 262,144; MB = 1e6 bytes)
    let prose = readme::prose(doc);
    let seg2 = std::mem::size_of::<Segregation<f64, 2, N>>() as f64 / N as f64;
    let flow2 = std::mem::size_of::<Flow<f64, 2, N>>() as f64 / N as f64;
    let mb = |per_cell: f64, cells: f64| per_cell * cells / 1e6;
    let today = readme::stated(&prose, "So today a prescribed 2D run holds", "MB", 1);
    readme::check("prescribed 2D solver [MB]", mb(seg2, 262144.0), &today[0]);
    let flow_today = readme::stated(&prose, "and a 2D flow scene", "MB", 1);
    readme::check(
        "2D flow scene solvers [MB]",
        mb(seg2 + flow2, 262144.0),
        &flow_today[0],
    );
    let big = readme::stated(&prose, "At 1024 x 1024 that becomes", "(flow)", 2);
    readme::check("prescribed 1024^2 [MB]", mb(seg2, 1048576.0), &big[0]);
    readme::check("flow 1024^2 [MB]", mb(seg2 + flow2, 1048576.0), &big[1]);
}

/// Records a built-in scene with the defaults of `sieve record` and replays it.
fn record_replay(name: &str) -> (u32, f64, [usize; 2], f64, f64) {
    let (scene, fields) = sieve::scene::load(name, &[]).expect("scene");
    let (bytes, report) =
        record_scene(&scene, &fields, &SceneRecordOptions::default()).expect("record");
    let r = replay_bytes(&bytes, &ReplayOptions::default()).expect("replay");
    (
        report.record.frames,
        report.period,
        report.truth_cells,
        r.max_psi_error,
        r.mean_l1,
    )
}

fn check_record_row(name: &str, first_cell: &str) -> (f64, f64) {
    let row = readme::table_row(readme::soft_sensor_doc(), first_cell);
    let truth = readme::stated(row, "` (", " truth", 2);
    // "| 120 x 0.025 s | 0.033 | 0.0067 |"
    let rest = readme::numbers(readme::after(row, ") |"));
    assert_eq!(rest.len(), 4, "{row}");
    let (n, dt, cells, psi_err, l1) = record_replay(name);
    println!("{name}: {n} frames of {dt} s, truth {cells:?}, psi err {psi_err}, L1 {l1}");
    assert_eq!(
        [cells[0] as f64, cells[1] as f64],
        [truth[0].value, truth[1].value]
    );
    assert_eq!(n as f64, rest[0].value, "{name}: frames");
    readme::check(&format!("{name}: frame period [s]"), dt, &rest[1]);
    let errors = &rest[2..];
    readme::check(&format!("{name}: max |psi error|"), psi_err, &errors[0]);
    readme::check(&format!("{name}: mean L1"), l1, &errors[1]);
    (psi_err, l1)
}

#[test]
fn sieve_record_table_shear_cell_mixed_and_readme_sentence() {
    let (psi_err, l1) = check_record_row("shear-cell-mixed", "`shear-cell-mixed` (64 x 64");
    // README, soft sensor: "(`shear-cell-mixed`: 120 frames of 0.025 s, max |psi error| 0.033
    // against the truth, mean L1 of phihat 0.0067)"
    let s = readme::between(readme::readme(), "(`shear-cell-mixed`:", ")");
    let n = readme::numbers(s);
    assert_eq!(n.len(), 4, "{s}");
    assert_eq!((n[0].value, n[1].value), (120.0, 0.025), "{s}");
    readme::check("README: max |psi error|", psi_err, &n[2]);
    readme::check("README: mean L1", l1, &n[3]);
}

#[test]
fn sieve_record_table_gray_thornton_shear() {
    check_record_row("gray-thornton-shear", "`gray-thornton-shear` (200 x 100");
}

/// Column 7.1a (S = 1, m = 1/2, height 1): phihat 1 below t/2, 1/2 up to 1 - t/2, 0 above.
fn column_a_cell_average(z0: f64, z1: f64, t: f64) -> f64 {
    let (lo, hi) = (0.5 * t, 1.0 - 0.5 * t);
    let overlap = |a: f64, b: f64| (b.min(z1) - a.max(z0)).max(0.0);
    (overlap(0.0, lo) + 0.5 * overlap(lo, hi)) / (z1 - z0)
}

#[test]
fn column_a_shocks_l1_errors_and_order() {
    let prose = readme::prose(readme::readme());
    let shocks = readme::stated(
        &prose,
        "shocks at t = 0.5 within a cell (measured",
        "on 200",
        2,
    );
    let errors = readme::stated(&prose, "L1 error of phihat", "on 100-800", 4);
    let order = readme::stated(&prose, "100-800 cells: **observed order", "**.", 1);
    // shock positions on 200 cells: crossings of the mid-values 0.75 and 0.25
    let mut s = column::<f64>(Column::A, 200, Scheme::Modified, Phase::Small);
    s.advance_to(0.5, u64::MAX);
    let neg: Vec<f64> = phihat(&*s).iter().map(|p| -p).collect();
    let z = centres(200, 1.0);
    let lower = crossing(&z, &neg, -0.75).expect("lower shock");
    let upper = crossing(&z, &neg, -0.25).expect("upper shock");
    readme::check("column-a lower shock, 200 cells", lower, &shocks[0]);
    readme::check("column-a upper shock, 200 cells", upper, &shocks[1]);
    // exact: 0.25 and 0.75, within a cell
    assert!((lower - 0.25).abs() < 1.0 / 200.0 && (upper - 0.75).abs() < 1.0 / 200.0);
    let levels = [100usize, 200, 400, 800];
    let h: Vec<f64> = levels.iter().map(|&n| 1.0 / n as f64).collect();
    let e: Vec<f64> = levels
        .iter()
        .map(|&n| {
            let mut s = column::<f64>(Column::A, n, Scheme::Modified, Phase::Small);
            s.advance_to(0.5, u64::MAX);
            let h = 1.0 / n as f64;
            phihat(&*s)
                .iter()
                .enumerate()
                .map(|(i, p)| {
                    (p - column_a_cell_average(i as f64 * h, (i + 1) as f64 * h, 0.5)).abs() * h
                })
                .sum()
        })
        .collect();
    for (k, (ek, sk)) in e.iter().zip(&errors).enumerate() {
        readme::check(&format!("column-a L1 error, {} cells", levels[k]), *ek, sk);
    }
    readme::check(
        "column-a observed L1 order",
        observed_order(&h, &e),
        &order[0],
    );
}
