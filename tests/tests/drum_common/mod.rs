//! The coupled half drum shared by `flow_drum_coupled.rs`, `flow_implicit.rs`,
//! `coupled_step_limit.rs` and `limited_bounds.rs`: a drum of diameter 0.1 m on 24 x 24 cells
//! (the box is the drum plus one cell on each side), cut-cell wall, glass beads of model.md
//! 7.4, turning at 1 rev/s in its own rotating frame, walls with 11 deg of Coulomb friction,
//! the segregation with the flow's direction under gravity. The fill and the run stay in each
//! test (they differ).

#![allow(dead_code)]

use sieve_core::flow::{CutWall, Flow, FlowConfig, FlowSide, Slip};
use sieve_core::frame::{Frame, Rotation};
use sieve_core::geometry::{CutCells, Region, DEFAULT_SMALL};
use sieve_core::segregation::{DirectionMode, Segregation, SegregationConfig};
use sieve_core::{Boundary, Grid};
use std::f64::consts::PI;

/// The drum's solvers and geometry, not yet filled.
pub struct HalfDrum<const M: usize> {
    /// The 24 x 24 grid.
    pub grid: Grid<f64, 2>,
    /// The flow, set up on the cut cells.
    pub flow: Box<Flow<f64, 2, M>>,
    /// The segregation solver, set up.
    pub seg: Box<Segregation<f64, 2, M>>,
    /// The drum's cut cells.
    pub cut: Box<CutCells<f64, 2, M>>,
}

/// A drum of `diameter` on `n x n` cells, one cell of the box around it (its centre at
/// `diameter / 2` on both axes): the grid and its cut cells.
pub fn drum_cells<const M: usize>(
    n: usize,
    diameter: f64,
) -> (Grid<f64, 2>, Box<CutCells<f64, 2, M>>) {
    let r = 0.5 * diameter;
    let h = diameter / (n as f64 - 2.0);
    let grid = Grid::new([n, n], [-h; 2], [diameter + 2.0 * h; 2], M).unwrap();
    let mut cut: Box<CutCells<f64, 2, M>> = Box::new(CutCells::zeroed());
    cut.build(&grid, &Region::drum([r, r], r), [false; 2], DEFAULT_SMALL)
        .unwrap();
    (grid, cut)
}

/// The drum of [`drum_cells`] at 0.15 m on 32 x 32 cells as a flow of `cfg`, walls with
/// 11 deg of friction, turning at 1 rev/s in its own frame, or (`lab`) in the lab frame with
/// its cut-cell wall turning; the cells not yet set. The slab tests' drum.
pub fn turning_drum<const M: usize>(
    lab: bool,
    mut cfg: FlowConfig<f64, 2>,
) -> (Box<Flow<f64, 2, M>>, Box<CutCells<f64, 2, M>>) {
    let (grid, cut) = drum_cells::<M>(32, 0.15);
    let omega = 2.0 * PI;
    let tan = 11f64.to_radians().tan();
    let mut wall = CutWall::resting(Slip::Friction(tan));
    if lab {
        wall = CutWall::rotating(Slip::Friction(tan), omega, [0.075, 0.075]);
    } else {
        cfg.frame = Frame::Rotating(Rotation::new(omega, [0.075, 0.075], 0).unwrap());
    }
    let side = FlowSide::wall(Slip::Friction(tan));
    let mut flow: Box<Flow<f64, 2, M>> = Box::new(Flow::zeroed());
    flow.setup(grid, [[side, side], [side, side]], cfg).unwrap();
    flow.set_geometry(&cut, wall).unwrap();
    (flow, cut)
}

/// Builds the drum with the flow configuration `cfg` (its frame is set here). Call on a
/// big-stack thread (`sieve_tests::run_big`).
pub fn half_drum<const M: usize>(mut cfg: FlowConfig<f64, 2>) -> HalfDrum<M> {
    let (grid, cut) = drum_cells::<M>(24, 0.1);
    cfg.frame = Frame::Rotating(Rotation::new(2.0 * PI, [0.05, 0.05], 0).unwrap());
    let tan = 11f64.to_radians().tan();
    let wall = FlowSide::wall(Slip::Friction(tan));
    let mut flow: Box<Flow<f64, 2, M>> = Box::new(Flow::zeroed());
    flow.setup(grid, [[wall, wall], [wall, wall]], cfg).unwrap();
    flow.set_geometry(&cut, CutWall::resting(Slip::Friction(tan)))
        .unwrap();
    let mut seg: Box<Segregation<f64, 2, M>> = Box::new(Segregation::zeroed());
    let mut scfg = SegregationConfig::new();
    scfg.gravity = [0.0, -9.81];
    scfg.direction = DirectionMode::Flow;
    seg.setup(grid, [[Boundary::Wall; 2]; 2], scfg).unwrap();
    HalfDrum {
        grid,
        flow,
        seg,
        cut,
    }
}
