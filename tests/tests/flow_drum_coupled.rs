//! The coupled flow and segregation in a drum with cut-cell walls (issue 8): a half-filled
//! drum of glass beads (model.md 7.4, S0 = 1, wall friction 11 deg, back-coupling R = 1/2),
//! mixed start, turning at 1 rev/s in its own frame (model.md 7.5). The small grains ride on
//! the flow's aperture-weighted face mass fluxes group by group
//! (`Segregation::carry_mass_fluxes_embedded`): both phases to round-off, 0 <= phi <= c
//! exactly in every cell after every step (cut cells and merged cells included), the
//! segregation's c equal to the flow's, bit-identical reruns.

use sieve_core::closure::{Material, Packing};
use sieve_core::diagnostics::diagnose_embedded;
use sieve_core::flow::coupled::{Coupled, CouplingConfig, Mode};
use sieve_core::flow::{CutWall, Flow, FlowConfig, FlowSide, Slip};
use sieve_core::frame::{Frame, Rotation};
use sieve_core::geometry::{CutCells, Region, DEFAULT_SMALL};
use sieve_core::segregation::{DirectionMode, Segregation, SegregationConfig};
use sieve_core::{Boundary, Grid};
use sieve_tests::run_big;
use std::f64::consts::PI;

const N: usize = 1024;

struct Outcome {
    small_drift: f64,
    total_drift: f64,
    worst_over: f64,
    worst_under: f64,
    c_mismatch: f64,
    max_speed: f64,
    hash: u64,
}

fn drum(steps: usize) -> Outcome {
    let n = 24;
    let (r, h) = (0.05, 0.1 / (n as f64 - 2.0));
    let lo = 0.05 - r - h;
    let grid = Grid::new([n, n], [lo; 2], [0.1 + 2.0 * h; 2], N).unwrap();
    let mut cut: Box<CutCells<f64, 2, N>> = Box::new(CutCells::zeroed());
    cut.build(
        &grid,
        &Region::drum([0.05, 0.05], r),
        [false; 2],
        DEFAULT_SMALL,
    )
    .unwrap();
    let omega = 2.0 * PI;
    let mut cfg = FlowConfig::new(Material::glass_beads());
    cfg.frame = Frame::Rotating(Rotation::new(omega, [0.05, 0.05], 0).unwrap());
    cfg.free_surface_push = true;
    let tan = 11f64.to_radians().tan();
    let wall = FlowSide::wall(Slip::Friction(tan));
    let mut flow: Box<Flow<f64, 2, N>> = Box::new(Flow::zeroed());
    flow.setup(grid, [[wall, wall], [wall, wall]], cfg).unwrap();
    flow.set_geometry(&cut, CutWall::resting(Slip::Friction(tan)))
        .unwrap();
    let mut seg: Box<Segregation<f64, 2, N>> = Box::new(Segregation::zeroed());
    let mut scfg = SegregationConfig::new();
    scfg.gravity = [0.0, -9.81];
    scfg.direction = DirectionMode::Flow;
    seg.setup(grid, [[Boundary::Wall; 2]; 2], scfg).unwrap();
    for i in 0..grid.len() {
        let z = grid.center(i)[1];
        let c = if z < 0.05 && !cut.is_solid(i) {
            0.6
        } else {
            0.0
        };
        flow.set_cell(i, c, [0.0; 2], 0.0);
        seg.set_cell(i, c, 0.0, [0.0; 2], 0.5 * c);
    }
    let mut cc = CouplingConfig::new(Mode::Coupled);
    cc.packing = Packing::FitHalf;
    let mut cpl = Coupled::new_embedded(&mut flow, &mut seg, cc, &cut).unwrap();
    let d0 = diagnose_embedded(cpl.seg, &cut);
    let total0: f64 = (0..grid.len()).map(|i| cpl.seg.c(i) * cut.volume(i)).sum();
    let mut o = Outcome {
        small_drift: 0.0,
        total_drift: 0.0,
        worst_over: 0.0,
        worst_under: 0.0,
        c_mismatch: 0.0,
        max_speed: 0.0,
        hash: 0,
    };
    for _ in 0..steps {
        cpl.step().unwrap();
        for i in 0..grid.len() {
            let (phi, c) = (cpl.seg.phi(i), cpl.seg.c(i));
            assert!(phi.is_finite() && c.is_finite());
            o.worst_over = o.worst_over.max(phi - c);
            o.worst_under = o.worst_under.max(-phi);
            o.c_mismatch = o.c_mismatch.max((c - cpl.flow.c(i)).abs());
        }
        o.max_speed = o.max_speed.max(cpl.flow.diagnostics().max_speed);
    }
    let d = diagnose_embedded(cpl.seg, &cut);
    o.small_drift = (d.mass_small - d0.mass_small).abs() / d0.mass_small;
    let total: f64 = (0..grid.len()).map(|i| cpl.seg.c(i) * cut.volume(i)).sum();
    o.total_drift = (total - total0).abs() / total0;
    o.hash = sieve_core::state_hash(cpl.seg);
    o
}

#[test]
fn coupled_half_drum_on_cut_cells_keeps_both_phases_and_the_bounds() {
    run_big(|| {
        let o = drum(400);
        println!(
            "coupled half drum, 24 x 24, 1 rev/s, 400 steps: small-grain drift {:.1e}, grains {:.1e}, max(phi - c) {:.1e}, max(-phi) {:.1e}, |c_seg - c_flow| {:.1e}, max speed {:.2e} m/s",
            o.small_drift, o.total_drift, o.worst_over, o.worst_under, o.c_mismatch, o.max_speed
        );
        assert!(o.small_drift < 1e-12, "{}", o.small_drift);
        assert!(o.total_drift < 1e-12, "{}", o.total_drift);
        assert!(o.worst_over <= 0.0 && o.worst_under <= 0.0);
        assert!(o.c_mismatch < 1e-12, "{}", o.c_mismatch);
        assert!(o.max_speed > 0.0);
        let again = drum(400);
        assert_eq!(o.hash, again.hash);
    });
}
