//! The transport's donor limiter keeps `c >= 0` exactly whatever the face velocities are
//! (model.md 5.3; docs/implicit-pressure.md, "The scheme" 4): the limited outflows of a cell
//! that empties, and the update that applies them, round, and handing out the whole content
//! let a few half-ulps leave the cell below 0. The implicit column collapse at a loose CG
//! tolerance (1e-6) is where it was seen: one cell of c = 3.55e-12 drained to -2.0e-28 at step
//! 166 of 336. The limiter keeps `SPARE_ULPS` (64) machine epsilons of the content back
//! (core/src/flow/step.rs, `spendable`), so every cell stays at `c >= 0` exactly; the mass is
//! still conserved to round-off (every flux leaves one cell and enters the other).

use crate::drum_common::{half_drum, HalfDrum};
use sieve_core::closure::Material;
use sieve_core::flow::{Flow, FlowConfig, FlowSide, PressureMode, Slip};
use sieve_core::real::Real;
use sieve_core::Grid;
use sieve_tests::run_big;

const N: usize = 4096;

/// Smallest `c` over every cell after every step, worst relative mass error, steps.
struct Watch {
    min_c: f64,
    mass_error: f64,
    steps: u64,
}

/// The implicit column collapse of tests/tests/flow_implicit.rs (model.md 7.8: a = H = 0.02 m,
/// 80 x 16 cells, friction walls 30 deg, 1 s) at the CG tolerance `tol`, in precision `R`.
fn collapse<R: Real>(tol: f64) -> Watch {
    let cells = [80, 16];
    let grid = Grid::new(
        cells,
        [R::ZERO; 2],
        [R::from_f64(0.16), R::from_f64(0.032)],
        N,
    )
    .unwrap();
    let wall = FlowSide::wall(Slip::Friction(R::from_f64(30f64.to_radians().tan())));
    let mut cfg = FlowConfig::new(Material::<R>::glass_beads());
    cfg.free_surface_push = true;
    cfg.pressure = PressureMode::Implicit;
    cfg.cg_tolerance = R::from_f64(tol);
    let mut flow: Box<Flow<R, 2, N>> = Box::new(Flow::zeroed());
    flow.setup(grid, [[wall; 2]; 2], cfg).unwrap();
    for i in 0..grid.len() {
        let [x, z] = grid.center(i);
        let inside = x.to_f64() < 0.02 && z.to_f64() < 0.02;
        let c = if inside { 0.6 } else { 0.0 };
        flow.set_cell(i, R::from_f64(c), [R::ZERO; 2], R::ZERO);
    }
    flow.prepare().unwrap();
    let m0 = flow.diagnostics().mass.to_f64();
    let mut w = Watch {
        min_c: f64::MAX,
        mass_error: 0.0,
        steps: 0,
    };
    while flow.time().to_f64() < 1.0 {
        flow.step(flow.stable_dt());
        for i in 0..grid.len() {
            w.min_c = w.min_c.min(flow.c(i).to_f64());
        }
        let m = flow.diagnostics().mass.to_f64();
        w.mass_error = w.mass_error.max((m - m0).abs() / m0);
    }
    w.steps = flow.steps();
    w
}

#[test]
fn implicit_collapse_at_a_loose_tolerance_keeps_c_nonnegative_exactly() {
    run_big(|| {
        let w = collapse::<f64>(1e-6);
        println!(
            "f64, tolerance 1e-6: {} steps, min c {:e}, mass {:.1e}",
            w.steps, w.min_c, w.mass_error
        );
        assert!(w.min_c >= 0.0, "min c {:e}", w.min_c);
        assert!(w.mass_error < 1e-13, "mass {:e}", w.mass_error);
        // f32 at its loosest default-like tolerance (64 eps = 7.6e-6)
        let w = collapse::<f32>(7.6e-6);
        println!(
            "f32, tolerance 7.6e-6: {} steps, min c {:e}, mass {:.1e}",
            w.steps, w.min_c, w.mass_error
        );
        assert!(w.min_c >= 0.0, "min c {:e}", w.min_c);
        assert!(w.mass_error < 1e-5, "mass {:e}", w.mass_error);
    });
}

/// The cut-cell path (content units, merge groups summed, then divided by the group volume):
/// the half drum of drum_common, flow alone, implicit, tolerance 1e-6, 400 steps at 1 rev/s.
/// (No cell went below 0 here before the reserve either: this guards the second limiter.)
#[test]
fn cut_cell_drum_at_a_loose_tolerance_keeps_c_nonnegative_exactly() {
    run_big(|| {
        let mut cfg = FlowConfig::new(Material::glass_beads());
        cfg.free_surface_push = true;
        cfg.pressure = PressureMode::Implicit;
        cfg.cg_tolerance = 1e-6;
        let HalfDrum { grid, mut flow, .. } = half_drum::<N>(cfg);
        for i in 0..grid.len() {
            let c = if grid.center(i)[1] < 0.05 { 0.6 } else { 0.0 };
            flow.set_cell(i, c, [0.0; 2], 0.0);
        }
        flow.prepare().unwrap();
        let m0 = flow.diagnostics().mass;
        let (mut min_c, mut drift) = (f64::MAX, 0f64);
        for _ in 0..400 {
            flow.step(flow.stable_dt());
            for i in 0..grid.len() {
                min_c = min_c.min(flow.c(i));
            }
            drift = drift.max((flow.diagnostics().mass - m0).abs() / m0);
        }
        println!(
            "drum: t = {:.3} s, min c {min_c:e}, mass {drift:.1e}",
            flow.time()
        );
        assert!(min_c >= 0.0, "min c {min_c:e}");
        assert!(drift < 1e-13, "mass {drift:e}");
    });
}
