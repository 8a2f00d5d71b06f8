//! The objective stress `sigma = eta (grad u + grad u^T)` (model.md 2.6, `Stress::Objective`):
//! the spec's stress and heating in simple shear, none in a rigid rotation.
//!
//! - A sine shear wave `u_x(z)` in a doubly periodic box: one step of both stresses against
//!   the discrete closed forms (decay of the mode, heating `eta_f (du)^2 / h^2` per face).
//! - A full circular drum (cut cells, glass beads of model.md 7.4 at c = 0.6, gravity, the
//!   model's own `T_min`) turning for one revolution: in the lab frame with the wall moving at
//!   `omega R` the bed turns rigidly; in the rotating frame it stays at rest; mass to
//!   round-off, `T >= 0`, and no heating with the objective stress where the spec heats.

use sieve_core::closure::{self, Material};
use sieve_core::flow::{CutWall, Flow, FlowConfig, FlowSide, Slip, Stress};
use sieve_core::frame::{Frame, Rotation};
use sieve_core::geometry::{CutCells, Region, DEFAULT_SMALL};
use sieve_core::Grid;
use sieve_tests::run_big;

const PI: f64 = std::f64::consts::PI;

/// One step of a sine shear wave `u_x = A sin(2 pi z / L)` (c = 0.6, T = 0, no gravity, 4 x 32
/// cells, periodic both ways). With uniform `eta` the mode is an eigenvector of the discrete
/// viscous operator, `lambda = 4 eta sin^2(pi h / L) / h^2`, so backward Euler gives
/// `u^1 = u^0 / (1 + dt lambda / c)`; the objective stress adds nothing (`d_x u_z = 0`,
/// `d_x u_x = 0`). The heating of the new field is `H_i = eta / (2 h^2) ((u_{i+1} - u_i)^2 +
/// (u_i - u_{i-1})^2)`; its total is read back from the temperature step
/// `(c / dt + c eps) T^1 - a div(lambda grad T^1) = a H` (T^0 = 0, `eps` at the old T; the
/// conduction sums to zero over the periodic box).
#[test]
fn sine_shear_objective_equals_spec() {
    const NZ: usize = 32;
    const NX: usize = 4;
    const N: usize = NX * NZ;
    let l = 0.032;
    let amp = 1e-3;
    let h = l / NZ as f64;
    let run = |stress: Stress| {
        let mut cfg = FlowConfig::new(Material::glass_beads());
        cfg.gravity = [0.0; 2];
        cfg.stress = stress;
        let grid = Grid::new([NX, NZ], [0.0; 2], [h * NX as f64, l], N).unwrap();
        let p = FlowSide::periodic();
        let mut flow: Box<Flow<f64, 2, N>> = Box::new(Flow::zeroed());
        flow.setup(grid, [[p, p], [p, p]], cfg).unwrap();
        for i in 0..grid.len() {
            let z = grid.center(i)[1];
            flow.set_cell(i, 0.6, [amp * (2.0 * PI * z / l).sin(), 0.0], 0.0);
        }
        flow.prepare().unwrap();
        let dt = 1e-8;
        flow.step(dt);
        flow
    };
    let spec = run(Stress::Spec);
    let obj = run(Stress::Objective);
    let m = Material::glass_beads();
    let (c, dt) = (0.6, 1e-8);
    let cr = m.phi_rcp;
    let tr = closure::transport(&m, c, 0.0, cr, m.phi_rlp, 1e-14);
    let lambda = 4.0 * tr.eta * (PI * h / l).sin().powi(2) / (h * h);
    let decay = 1.0 / (1.0 + dt * lambda / c);
    let (mut e_u, mut e_h, mut e_so) = (0.0f64, 0.0f64, 0.0f64);
    for flow in [&spec, &obj] {
        // conduction only moves heat between cells (periodic box): compare the totals
        let (mut read, mut heat) = (0.0, 0.0);
        for k in 0..NZ {
            for j in 0..NX {
                let i = j + NX * k;
                assert_eq!(flow.viscosity(i), tr.eta);
                let z = flow.grid().center(i)[1];
                let want = amp * (2.0 * PI * z / l).sin() * decay;
                let u = flow.velocity(i);
                assert_eq!(u[1], 0.0);
                e_u = e_u.max((u[0] - want).abs() / amp);
                let ux = |kk: usize| flow.velocity(j + NX * (kk % NZ))[0];
                let (lo, hi) = (ux(k + NZ - 1), ux(k + 1));
                heat += tr.eta / (2.0 * h * h) * ((hi - u[0]).powi(2) + (u[0] - lo).powi(2));
                read += flow.temperature(i) * c * (1.0 / dt + tr.eps) / m.heating;
            }
        }
        e_h = e_h.max((read - heat).abs() / heat);
    }
    for i in 0..N {
        let (a, b) = (spec.velocity(i)[0], obj.velocity(i)[0]);
        e_so = e_so.max((a - b).abs() / amp);
        let (ta, tb) = (spec.temperature(i), obj.temperature(i));
        e_so = e_so.max((ta - tb).abs() / ta.abs().max(1e-300));
    }
    println!("sine shear: decay {decay:.6}, |u - closed form| {e_u:.1e}, heating {e_h:.1e}, objective vs spec {e_so:.1e}");
    assert!(decay < 0.999, "the step must shear the bed: decay {decay}");
    assert!(e_u < 1e-9, "{e_u}");
    assert!(e_h < 1e-6, "{e_h}");
    assert!(e_so < 1e-9, "{e_so}");
}

const DN: usize = 32 * 32;
const RADIUS: f64 = 0.05;
/// Cells per axis (h = R/15), as tests/tests/flow_drum.rs.
const CELLS: usize = 32;

struct DrumRun {
    /// max |u - u_rigid| / (omega R) over the bulk (full cells whose neighbours are full)
    bulk: f64,
    /// the same over every open cell
    all: f64,
    mass_error: f64,
    min_t: f64,
    max_t: f64,
    max_c_ratio: f64,
    steps: u64,
    cg: u64,
    /// mean T over the bulk cells at the end [m^2/s^2]
    bulk_t: f64,
}

/// The full drum of glass beads (c = 0.6, T = 0, 32 x 32 cut cells, no-slip wall) ready to
/// step. Lab: wall at `omega R`; rotating: wall at rest, frame turning at `omega`. Started
/// from rest, or (`rigid`) in the lab's exact rigid rotation `u = omega x r` at every cell.
fn drum(
    stress: Stress,
    rotating: bool,
    gravity: bool,
    omega: f64,
    rigid: bool,
) -> Box<Flow<f64, 2, DN>> {
    drum_solved_to(stress, rotating, gravity, omega, rigid, None)
}

/// [`drum`] with the velocity solves' relative tolerance `cg_tolerance` (the core's default
/// if `None`).
fn drum_solved_to(
    stress: Stress,
    rotating: bool,
    gravity: bool,
    omega: f64,
    rigid: bool,
    cg_tolerance: Option<f64>,
) -> Box<Flow<f64, 2, DN>> {
    let n = CELLS;
    let h = 2.0 * RADIUS / (n as f64 - 2.0);
    let l = n as f64 * h;
    let grid = Grid::new([n, n], [-0.5 * l; 2], [l; 2], DN).unwrap();
    let mut cut: Box<CutCells<f64, 2, DN>> = Box::new(CutCells::zeroed());
    cut.build(
        &grid,
        &Region::drum([0.0; 2], RADIUS),
        [false; 2],
        DEFAULT_SMALL,
    )
    .unwrap();
    let mut cfg = FlowConfig::new(Material::glass_beads());
    cfg.stress = stress;
    if let Some(tol) = cg_tolerance {
        cfg.cg_tolerance = tol;
    }
    if !gravity {
        cfg.gravity = [0.0; 2];
    }
    let wall = if rotating {
        cfg.frame = Frame::Rotating(Rotation::new(omega, [0.0; 2], 0).unwrap());
        CutWall::resting(Slip::NoSlip)
    } else {
        CutWall::rotating(Slip::NoSlip, omega, [0.0; 2])
    };
    let mut flow: Box<Flow<f64, 2, DN>> = Box::new(Flow::zeroed());
    let side = FlowSide::wall(Slip::NoSlip);
    flow.setup(grid, [[side; 2]; 2], cfg).unwrap();
    flow.set_geometry(&cut, wall).unwrap();
    for i in 0..grid.len() {
        let c = if flow.open_volume(i) > 0.0 { 0.6 } else { 0.0 };
        let x = grid.center(i);
        let u = if rigid {
            [-omega * x[1], omega * x[0]]
        } else {
            [0.0; 2]
        };
        flow.set_cell(i, c, u, 0.0);
    }
    flow.prepare().unwrap();
    flow
}

/// A full drum turning at `omega`, run for `t_end` (started from rest; [`drum`]).
/// `u_rigid` is `omega x r` in the lab and 0 in the rotating frame.
fn full_drum(stress: Stress, rotating: bool, gravity: bool, omega: f64, t_end: f64) -> DrumRun {
    let n = CELLS;
    let mut flow = drum(stress, rotating, gravity, omega, false);
    let grid = *flow.grid();
    let m0 = flow.diagnostics().mass;
    let mut r = DrumRun {
        bulk: 0.0,
        all: 0.0,
        mass_error: 0.0,
        min_t: f64::MAX,
        max_t: 0.0,
        max_c_ratio: 0.0,
        steps: 0,
        cg: 0,
        bulk_t: 0.0,
    };
    while flow.time() < t_end {
        let dt = flow.stable_dt().min(t_end - flow.time());
        flow.step(dt);
        let g = flow.diagnostics();
        assert!(g.mass.is_finite() && g.kinetic_energy.is_finite());
        r.mass_error = r.mass_error.max((g.mass - m0).abs() / m0);
        r.min_t = r.min_t.min(g.t_min);
        r.max_t = r.max_t.max(g.t_max);
        r.max_c_ratio = r.max_c_ratio.max(g.max_packing);
    }
    r.steps = flow.steps();
    r.cg = flow.cg_iterations();
    let s = n;
    let mut bulk_cells = 0;
    for i in 0..grid.len() {
        if flow.open_volume(i) <= 0.0 {
            continue;
        }
        let x = grid.center(i);
        let u = flow.velocity(i);
        let want = if rotating {
            [0.0, 0.0]
        } else {
            [-omega * x[1], omega * x[0]]
        };
        let e = ((u[0] - want[0]).powi(2) + (u[1] - want[1]).powi(2)).sqrt() / (omega * RADIUS);
        r.all = r.all.max(e);
        let [ix, iy] = grid.coords(i);
        let interior = ix > 0 && iy > 0 && ix + 1 < n && iy + 1 < n;
        if interior
            && [i, i - 1, i + 1, i - s, i + s]
                .iter()
                .all(|&j| flow.open_volume(j) >= 1.0 && flow.wall_coefficient(j) == 0.0)
        {
            r.bulk = r.bulk.max(e);
            r.bulk_t += flow.temperature(i);
            bulk_cells += 1;
        }
    }
    r.bulk_t /= bulk_cells as f64;
    r
}

/// The full drum at 2 rev/s for one revolution (0.5 s, started from rest, 32 x 32 cells,
/// h = R/15). Measured when written (lab frame unless said; re-measured 2026-12-06 with the
/// lab solves relative to the turning wall, model.md 5.3: spec 2.74e-2 / 4.30e-5, objective
/// 5.0e-5 / 1.2e-9 (5.7e-5 without the shift), objective with gravity 1.40e-3 / 1.8e-8 (1.41e-3
/// without it), rotating 3.64e-6 / 6.6e-16):
///
/// | case | bulk max \|u - u_rigid\| / (omega R) | bulk mean T at the end |
/// |---|---|---|
/// | spec, no gravity | 2.2e-2 | 4.22e-5 (`2 a omega^2 eta0 / eps0` = 4.17e-5) |
/// | objective, no gravity | 5.1e-5 | 1.3e-9 |
/// | objective, rotating frame, gravity | 3.6e-6 (u = 0) | 6.6e-16 |
/// | objective, gravity | 1.22e-3 | 1.3e-8 |
///
/// Before the merge groups carried the moving wall's rigid motion (`lab_drum_wall_ring_is_not_
/// warmer_than_the_bed`, docs/frames.md) the lab rows were 1.8e-2 / 4.14e-5, 2.6e-4 / 1.9e-9
/// and 1.4e-3 / 1.1e-8. With gravity the lab bulk misses the 1e-3 of issue 8 by 1.2x (the
/// numbers below were measured before that fix). It is not the time
/// splitting (Courant 0.2 instead of 0.4: 1.64e-3 against 1.61e-3 at 1 rev/s), nor the cut
/// wall (48 x 48: 1.52e-3), nor the spin-up (a start in exact rigid rotation: 1.55e-3), nor
/// the stress (without gravity 1.1e-4 at 1 rev/s): the bed is compressible, packed by its
/// weight to c/c_rcp = 0.957 at the bottom against 0.953 without gravity, and a rigid
/// rotation would carry that denser layer up the rising side; the flow that keeps the
/// compaction under the lab's gravity is what remains. Checked (stop 17, measured once): a
/// stiffer bed, T0 x 3 and x 10 (the yield pressure, so the compaction, 3x and 10x smaller),
/// brings the lab error under gravity to 3.6e-4 and 8.1e-5, about 1/T0^1.25: the incompressible
/// limit is the rigid rotation. Why the rotating frame shows no such flow is not understood.
/// All cases: mass to 4e-15, T >= 0.
#[test]
fn full_drum_turns_rigidly_with_the_objective_stress() {
    run_big(|| {
        let omega = 2.0 * PI * 2.0;
        let m: Material<f64> = Material::glass_beads();
        let t_eq: f64 = 2.0 * m.heating * omega * omega * m.eta0 / m.eps0;
        let runs = [
            ("spec, lab", Stress::Spec, false, false),
            ("objective, lab", Stress::Objective, false, false),
            (
                "objective, rotating frame, gravity",
                Stress::Objective,
                true,
                true,
            ),
            ("objective, lab, gravity", Stress::Objective, false, true),
        ];
        let mut out: Vec<DrumRun> = Vec::new();
        for (name, stress, rotating, gravity) in runs {
            let r = full_drum(stress, rotating, gravity, omega, 0.5);
            println!(
                "{name}: bulk {:.2e}, all open cells {:.2e}, bulk T {:.2e} (spec equilibrium \
                 {t_eq:.2e}), mass {:.1e}, T in [{:.1e}, {:.1e}], max c/c_rcp {:.4}, {} steps, \
                 {} CG iterations",
                r.bulk,
                r.all,
                r.bulk_t,
                r.mass_error,
                r.min_t,
                r.max_t,
                r.max_c_ratio,
                r.steps,
                r.cg
            );
            assert!(r.mass_error < 1e-13, "{name}: mass {}", r.mass_error);
            assert!(r.min_t >= 0.0, "{name}");
            assert!(r.max_c_ratio < 0.999, "{name}");
            out.push(r);
        }
        // the spec's stress heats a rigid rotation to its heating-dissipation balance and
        // lets the bed lag
        assert!(
            (out[0].bulk_t / t_eq - 1.0).abs() < 0.05,
            "{} vs {t_eq}",
            out[0].bulk_t
        );
        assert!(out[0].bulk > 5e-3, "{}", out[0].bulk);
        // the objective stress: rigid rotation within 2e-4 (2.6e-4 before the moving wall's
        // merge groups carried the rigid motion), no heating
        assert!(out[1].bulk < 2e-4, "{}", out[1].bulk);
        assert!(out[1].bulk_t < 1e-3 * t_eq, "{}", out[1].bulk_t);
        // rotating frame: at rest
        assert!(out[2].bulk < 1e-3, "{}", out[2].bulk);
        assert!(out[2].bulk_t < 1e-6 * t_eq, "{}", out[2].bulk_t);
        // with gravity in the lab: the compaction flow (doc above), an order of magnitude
        // below the spec's lag
        assert!(out[3].bulk < 1.5e-3, "{}", out[3].bulk);
        assert!(out[3].bulk_t < 1e-3 * t_eq, "{}", out[3].bulk_t);
        // the lagged cross part needs no smaller step (same Courant limit)
        let ratio = out[1].steps as f64 / out[0].steps as f64;
        assert!(ratio < 1.02, "{ratio}");
    });
}

/// Per ring of `r / R` (0-0.5, 0.5-0.625, 0.625-0.75, 0.75-0.875, 0.875-1: the last holds
/// the cut and wall cells) over the cells with open volume >= 1/2 (the slivers hold too little
/// volume to count): the open-volume-weighted mean T and the max `|u - omega x r| / (omega R)`.
fn lab_rings(flow: &Flow<f64, 2, DN>, omega: f64) -> [(f64, f64); 5] {
    let grid = flow.grid();
    let mut out = [(0.0f64, 0.0f64); 5];
    let mut vol = [0.0f64; 5];
    for i in 0..grid.len() {
        let v = flow.open_volume(i);
        if v < 0.5 {
            continue;
        }
        let x = grid.center(i);
        let r = (x[0] * x[0] + x[1] * x[1]).sqrt() / RADIUS;
        let k = if r < 0.5 {
            0
        } else {
            (1 + ((r - 0.5) / 0.125) as usize).min(4)
        };
        let u = flow.velocity(i);
        let e = ((u[0] + omega * x[1]).powi(2) + (u[1] - omega * x[0]).powi(2)).sqrt()
            / (omega * RADIUS);
        vol[k] += v;
        out[k].0 += v * flow.temperature(i);
        out[k].1 = out[k].1.max(e);
    }
    for (o, v) in out.iter_mut().zip(vol) {
        o.0 /= v;
    }
    out
}

/// The discrete rigid rotation in the lab frame (full drum, no gravity, 2 rev/s, every cell
/// started at `omega x r`) over one step of 1e-12 s: the objective stress must not heat it,
/// at the moving cut wall as in the bulk. With the frozen-in field the step is the viscous
/// operator's and the heating's answer to a rigid field (the transport's centripetal
/// deviation is `omega dt` = 1.3e-11 of omega R). The spec's stress heats it by
/// `2 eta omega^2` everywhere, the yardstick.
///
/// Measured (mean T per ring, objective / spec): before the merge groups carried the wall's
/// rigid motion (`Flow::carry_rigid_offsets`) and the transposed traction's differences
/// avoided merge members, the wall ring (0.875-1) had 9.0e-8 / 8.9e-7 (a tenth of the spec's
/// heating) and the velocity there moved by 1.7e-2 of omega R in the one tiny step: each
/// member started at its group's mean velocity, a cell's width off the rotation. Now: wall
/// ring 4.0e-16 (4.5e-10 of the spec's; 6.6e-5 / 3.6e5 in the heating, flat in dt from 1e-14
/// to 1e-12: the linear solves' tolerance), inner rings 9e-24 - 2e-23 (1e-17), the 0.75-0.875
/// ring 3.7e-19; velocity error 1.7e-11 (the centripetal `omega dt`).
#[test]
fn rigid_rotation_does_not_heat_the_moving_cut_wall() {
    run_big(|| {
        let omega = 2.0 * PI * 2.0;
        let dt = 1e-12;
        let mut obj = drum(Stress::Objective, false, false, omega, true);
        let mut spec = drum(Stress::Spec, false, false, omega, true);
        obj.step(dt);
        spec.step(dt);
        let (ro, rs) = (lab_rings(&obj, omega), lab_rings(&spec, omega));
        for k in 0..5 {
            println!(
                "ring {k}: mean T objective {:.2e}, spec {:.2e}; max error {:.2e} / {:.2e}",
                ro[k].0, rs[k].0, ro[k].1, rs[k].1
            );
            assert!(rs[k].0 > 5e-7, "the spec must heat: {}", rs[k].0);
            assert!(ro[k].0 >= 0.0);
            // the wall ring at the linear solves' tolerance, the rest at round-off
            let bound = if k == 4 { 1e-8 } else { 1e-12 };
            assert!(
                ro[k].0 < bound * rs[k].0,
                "ring {k}: {} vs {}",
                ro[k].0,
                rs[k].0
            );
            assert!(ro[k].1 < 1e-9, "ring {k}: {}", ro[k].1);
        }
        for i in 0..obj.grid().len() {
            assert!(obj.temperature(i) >= 0.0 && obj.temperature(i).is_finite());
        }
    });
}

/// The lab drum of [`rigid_rotation_does_not_heat_the_moving_cut_wall`] run for a
/// revolution (0.5 s, no gravity, objective stress): what heat there is must not come from
/// the moving wall. Measured (mean T per ring 0-0.5 ... 0.875-1; max error / (omega R)):
///
/// | | 0-0.5 | 0.5-0.625 | 0.625-0.75 | 0.75-0.875 | 0.875-1 (cut, wall) |
/// |---|---|---|---|---|---|
/// | before (stop 18) | 2.0e-10, 7.8e-5 | 5.4e-10, 1.0e-4 | 1.5e-9, 1.4e-4 | 4.2e-9, 1.9e-4 | 4.1e-8, 3.3e-4 |
/// | now | 5.9e-11, 2.0e-5 | 1.4e-10, 2.5e-5 | 7.6e-10, 3.2e-5 | 3.5e-9, 5.5e-5 | 3.3e-9, 6.4e-5 |
///
/// The wall ring was 10x warmer than the next ring inwards; now it is not warmer at all.
/// Mass to 3.5e-15.
#[test]
fn lab_drum_wall_ring_is_not_warmer_than_the_bed() {
    run_big(|| {
        let omega = 2.0 * PI * 2.0;
        let mut flow = drum(Stress::Objective, false, false, omega, true);
        let m0 = flow.diagnostics().mass;
        let mut mass = 0.0f64;
        while flow.time() < 0.5 {
            let dt = flow.stable_dt().min(0.5 - flow.time());
            flow.step(dt);
            mass = mass.max((flow.diagnostics().mass - m0).abs() / m0);
        }
        let r = lab_rings(&flow, omega);
        for (k, (t, e)) in r.iter().enumerate() {
            println!("ring {k}: mean T {t:.2e}, max error {e:.2e}");
        }
        println!("mass {mass:.1e}");
        assert!(mass < 1e-13, "{mass}");
        assert!(r[4].0 < 1e-8, "wall ring T {}", r[4].0);
        assert!(r[4].0 < 1.5 * r[3].0, "wall ring {} vs {}", r[4].0, r[3].0);
        for (k, &(t, e)) in r.iter().enumerate() {
            assert!((0.0..1e-8).contains(&t), "ring {k}: T {t}");
            assert!(e < 1e-4, "ring {k}: error {e}");
        }
    });
}

/// The lab drum's velocity solves stop on the flow relative to the turning wall (model.md 5.3,
/// "The solves' stopping rule in a turning drum"). The full drum with gravity, started in
/// the exact rigid rotation (0.5 rev/s, objective stress), takes 40 steps with the solves'
/// tolerance 1e-4 (the `tumbler` scene's) and with 1e-12. What the bed does besides turning
/// rigidly, `u - omega x r`, is the compaction flow of `full_drum_turns_rigidly_with_the_
/// objective_stress` (2.6e-4 m/s against `omega R` = 0.157 m/s). When the stop counted the
/// rigid rotation's momentum in `|b|`, the guess (the rigid rotation carried on) already
/// met it and the loose solves missed that flow entirely: measured when written, max
/// |u_loose - u_tight| / max |u_tight - omega x r| = 1.00 at the tolerance 1e-4 and at 1e-6.
/// With the shift 0.32 and 0.23: a slow, stiff mode that the residual norm weighs little,
/// but the solves now work on it.
#[test]
fn lab_drum_solves_stop_on_the_flow_relative_to_the_wall() {
    run_big(|| {
        let omega = 2.0 * PI * 0.5;
        let run = |tol: f64| {
            let mut flow = drum_solved_to(Stress::Objective, false, true, omega, true, Some(tol));
            for _ in 0..40 {
                let dt = flow.stable_dt();
                flow.step(dt);
            }
            flow
        };
        let (loose, tight) = (run(1e-4), run(1e-12));
        let grid = *tight.grid();
        let (mut diff, mut flow_speed) = (0.0f64, 0.0f64);
        for i in 0..grid.len() {
            if tight.open_volume(i) <= 0.0 {
                continue;
            }
            let x = grid.center(i);
            let (a, b) = (loose.velocity(i), tight.velocity(i));
            let rigid = [-omega * x[1], omega * x[0]];
            diff = diff.max(((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt());
            flow_speed =
                flow_speed.max(((b[0] - rigid[0]).powi(2) + (b[1] - rigid[1]).powi(2)).sqrt());
        }
        println!(
            "loose against tight solves: max |du| {diff:.3e} m/s, flow relative to the wall \
             {flow_speed:.3e} m/s, ratio {:.2e}; omega R {:.3e} m/s",
            diff / flow_speed,
            omega * RADIUS
        );
        assert!(flow_speed > 0.0);
        assert!(diff < 0.5 * flow_speed, "{diff} vs {flow_speed}");
    });
}

/// The 3D, f32 path: a shear wave `u_y(x)` in a triply periodic 8 x 4 x 4 box of c = 0.6, T = 0
/// (no gravity), one step of each stress. `d_y u_x = 0` and `d_y u_y = 0`, so the objective
/// stress must reproduce the spec's velocity and temperature (to the f32 solver's tolerance:
/// measured 2.5e-7 of the amplitude in u, 5.6e-6 relative in T) and keep every value finite.
#[test]
fn shear_wave_3d_f32_objective_equals_spec() {
    const N: usize = 8 * 4 * 4;
    let l = 0.008f32;
    let run = |stress: Stress| {
        let mut cfg = FlowConfig::new(Material::glass_beads());
        cfg.gravity = [0.0; 3];
        cfg.stress = stress;
        let grid = Grid::new([8, 4, 4], [0.0; 3], [l, 0.004, 0.004], N).unwrap();
        let p = FlowSide::periodic();
        let mut flow: Box<Flow<f32, 3, N>> = Box::new(Flow::zeroed());
        flow.setup(grid, [[p, p]; 3], cfg).unwrap();
        for i in 0..grid.len() {
            let x = grid.center(i)[0];
            let u = 1e-3 * (2.0 * std::f32::consts::PI * x / l).sin();
            flow.set_cell(i, 0.6, [0.0, u, 0.0], 0.0);
        }
        flow.prepare().unwrap();
        flow.step(1e-8);
        flow
    };
    let (spec, obj) = (run(Stress::Spec), run(Stress::Objective));
    let (mut du, mut dt, mut moved) = (0.0f32, 0.0f32, 0.0f32);
    for i in 0..N {
        let (a, b) = (spec.velocity(i), obj.velocity(i));
        assert!(a.iter().chain(&b).all(|v| v.is_finite()));
        assert_eq!(b[0], 0.0);
        assert_eq!(b[2], 0.0);
        du = du.max((a[1] - b[1]).abs() / 1e-3);
        let (ta, tb) = (spec.temperature(i), obj.temperature(i));
        assert!(ta >= 0.0 && tb >= 0.0);
        dt = dt.max((ta - tb).abs() / ta.max(f32::MIN_POSITIVE));
        moved = moved.max(ta);
    }
    println!("3D f32 shear wave: |du| {du:.1e}, |dT|/T {dt:.1e}, max T {moved:.2e}");
    assert!(moved > 0.0, "the wave must heat");
    assert!(du < 1e-5, "{du}");
    assert!(dt < 1e-4, "{dt}");
}
