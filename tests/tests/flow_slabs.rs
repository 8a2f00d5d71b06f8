//! The coupled flow's step on slabs of rows (core/src/flow/slab.rs), each slab on its own
//! thread as a rank of an MPI run would step it: after every step the owned rows of every
//! slab hold the serial run's bits in every state array, the step, the residual and the CG
//! iterations are the serial ones, and a failure names the first step, array and cell where
//! the slabs left the serial run (issue 12: "name the first step where two decompositions
//! diverge").
//!
//! The scenes are the hard cases of the flow: a column collapsing onto a floor (free
//! surfaces, empty cells, a bed near maximal packing, friction walls) cut across its fall,
//! a sheared periodic layer with the objective stress (its cross terms read across the cut),
//! and a 3D collapse.

use crate::common::thread_links::{assert_serial_rows, on_threads};
use sieve_core::boundary::{Opening, Openings};
use sieve_core::closure::Material;
use sieve_core::flow::slab::{halo_rows, load_slab, Slab, SlabError};
use sieve_core::flow::{Flow, FlowConfig, FlowSide, PressureMode, Slip, Stress};
use sieve_core::fork::Serial;
use sieve_core::frame::{Frame, Rotation};
use sieve_core::Grid;
use std::ops::Range;

const N: usize = 1024;

/// What one step left: the step taken, the residual, the CG iterations and every state array
/// over some cells (by name, in [`Flow::for_each_state_array`] order).
struct After {
    dt: f64,
    residual: f64,
    cg: [u32; 4],
    /// What has left through the floor and the lid (the split axis's sides).
    books: [f64; 2],
    /// What has left through the sides along the cut, in all and in the step, per axis.
    along: Vec<[[f64; 2]; 2]>,
    arrays: Vec<(&'static str, Vec<f64>)>,
}

fn after<const D: usize>(flow: &Flow<f64, D, N>, dt: f64, cells: Range<usize>) -> After {
    let mut arrays = vec![];
    flow.for_each_state_array(|name, a| arrays.push((name, a[cells.clone()].to_vec())));
    After {
        dt,
        residual: flow.residual(),
        cg: flow.last_cg_iterations(),
        books: flow.discharged()[D - 1],
        along: (0..D - 1)
            .map(|a| [flow.discharged()[a], flow.last_discharge()[a]])
            .collect(),
        arrays,
    }
}

fn boxed<const D: usize>() -> Box<Flow<f64, D, N>> {
    Box::new(Flow::zeroed())
}

/// `steps` steps of the serial flow `flow`, each at its stable step.
fn serial<const D: usize>(mut flow: Box<Flow<f64, D, N>>, steps: usize) -> Vec<After> {
    let n = flow.len();
    (0..steps)
        .map(|_| {
            let dt = flow.stable_dt();
            flow.step(dt);
            after(&flow, dt, 0..n)
        })
        .collect()
}

/// The same steps on slabs cut at the rows `starts`, each slab on a thread: per slab, the
/// global cells it owns and what each step left in them.
fn on_slabs<const D: usize>(
    start: &Flow<f64, D, N>,
    starts: &[usize],
    steps: usize,
) -> Vec<(Range<usize>, Vec<After>)> {
    on_threads(starts.len(), |k, mut links| {
        let mut flow = boxed::<D>();
        let plan = load_slab(start, starts, k, &mut *flow).unwrap();
        let mut memory = vec![0.0; plan.memory_len()];
        let mut slab = Slab::new(&plan, &mut links, &mut memory);
        let own = plan.owned_cells();
        let history = (0..steps)
            .map(|_| {
                let dt = flow.stable_dt_reaching(&mut slab);
                flow.step_reaching(dt, &Serial, &mut slab);
                after(&flow, dt, own.clone())
            })
            .collect();
        (plan.global_cells(), history)
    })
}

/// Steps the flow `make` builds serially and on slabs cut at each of `cuts`, and asserts the
/// serial bits after every step, naming the first step, array and cell that differ. Returns
/// the serial run's steps.
fn check<const D: usize>(
    make: impl Fn() -> Box<Flow<f64, D, N>>,
    cuts: &[&[usize]],
    steps: usize,
    what: &str,
) -> Vec<After> {
    let start = make();
    let start = &*start;
    let whole = serial(make(), steps);
    let plane = start.len() / start.grid().cells()[D - 1];
    for starts in cuts {
        let slabs = on_slabs(start, starts, steps);
        for (step, expected) in whole.iter().enumerate() {
            for (k, (cells, history)) in slabs.iter().enumerate() {
                let got = &history[step];
                let at = format!(
                    "{what}, cut at rows {starts:?}: slab {k}, step {}",
                    step + 1
                );
                assert_eq!(got.dt.to_bits(), expected.dt.to_bits(), "{at}: dt");
                for ((name, mine), (_, all)) in got.arrays.iter().zip(&expected.arrays) {
                    assert_serial_rows(&at, name, mine, all, cells.start, plane);
                }
                assert_eq!(got.cg, expected.cg, "{at}: CG iterations");
                // the floor's book is the first slab's, the lid's the last one's
                for (side, owner) in [(0, 0), (1, slabs.len() - 1)] {
                    if k == owner {
                        assert_eq!(
                            got.books[side].to_bits(),
                            expected.books[side].to_bits(),
                            "{at}: discharge book of side {side}"
                        );
                    }
                }
                // the sides along the cut: every slab holds the whole side's books
                let bits = |b: &[[[f64; 2]; 2]]| {
                    b.iter()
                        .flatten()
                        .flatten()
                        .map(|x| x.to_bits())
                        .collect::<Vec<_>>()
                };
                assert_eq!(bits(&got.along), bits(&expected.along), "{at}: side books");
                assert_eq!(
                    got.residual.to_bits(),
                    expected.residual.to_bits(),
                    "{at}: residual"
                );
            }
        }
    }
    whole
}

/// The glass beads under gravity along the last axis.
fn beads<const D: usize>() -> FlowConfig<f64, D> {
    let mut cfg = FlowConfig::new(Material::glass_beads());
    cfg.gravity[D - 1] = -9.81;
    cfg
}

/// A prepared flow in a box of friction walls: a block at `c = 0.6` in the corner below
/// `block`, at rest (a column that collapses).
fn collapse<const D: usize>(
    cells: [usize; D],
    size: [f64; D],
    block: [f64; D],
    pressure: PressureMode,
) -> Box<Flow<f64, D, N>> {
    thrown(cells, size, block, 0.0, pressure)
}

/// [`collapse`] with the block's bottom `lift` above the floor, thrown down at 1 m/s when
/// lifted (a clump that falls through the cuts and hits the floor).
fn thrown<const D: usize>(
    cells: [usize; D],
    size: [f64; D],
    block: [f64; D],
    lift: f64,
    pressure: PressureMode,
) -> Box<Flow<f64, D, N>> {
    let mut flow = boxed::<D>();
    let grid = Grid::new(cells, [0.0; D], size, N).unwrap();
    let mut cfg = beads::<D>();
    cfg.free_surface_push = true;
    cfg.pressure = pressure;
    let wall = FlowSide::wall(Slip::Friction(30f64.to_radians().tan()));
    flow.setup(grid, [[wall, wall]; D], cfg).unwrap();
    for i in 0..grid.len() {
        let x = grid.center(i);
        let inside = (0..D).all(|a| x[a] < block[a]) && x[D - 1] >= lift;
        let mut u = [0.0; D];
        if lift > 0.0 {
            u[D - 1] = -2.0;
        }
        let bed = x[D - 1] < lift * 0.75;
        let c = if inside {
            0.6
        } else if bed {
            0.999 * (1.0 - cfg.margin) * cfg.material.phi_rcp
        } else {
            0.0
        };
        flow.set_cell(i, c, if inside { u } else { [0.0; D] }, 0.0);
    }
    flow.prepare().unwrap();
    flow
}

#[test]
fn a_collapsing_column_on_slabs_has_the_serial_bits() {
    // 20 x 24 cells of 5 mm; the block falls and spreads across every cut
    let make = || collapse([20, 24], [0.1, 0.12], [0.05, 0.09], PressureMode::Explicit);
    let cuts: [&[usize]; 4] = [
        &[0, 12],
        &[0, 8, 16],
        &[0, 6, 12, 18],
        &[0, 4, 8, 12, 16, 20],
    ];
    check(make, &cuts, 60, "2D collapse");
    // the implicit pressure: its solve, its sums and its face velocities across the cuts
    let make = || collapse([20, 24], [0.1, 0.12], [0.05, 0.09], PressureMode::Implicit);
    check(make, &cuts[..2], 40, "2D collapse, implicit pressure");
}

#[test]
fn a_clump_falling_through_the_cuts_has_the_serial_bits() {
    // dense grains thrown down through three cuts onto the floor: cells fill and empty at
    // the cuts, so the transport's limiters bind beside them (the halo's depth, slab.rs
    // `HALO`)
    let make = || {
        thrown(
            [16, 24],
            [0.08, 0.12],
            [0.05, 0.11],
            0.06,
            PressureMode::Explicit,
        )
    };
    check(make, &[&[0, 6, 12, 18]], 240, "2D falling clump");
}

#[test]
fn a_sheared_periodic_layer_with_the_objective_stress_on_slabs_has_the_serial_bits() {
    // periodic along x, a lid moving at 0.5 m/s over a dense bed with a loose top: the
    // objective stress's cross terms and the lid's wall law reach across the cuts
    let make = || {
        let mut flow = boxed::<2>();
        let grid = Grid::new([8, 24], [0.0; 2], [0.04, 0.12], N).unwrap();
        let mut cfg = beads::<2>();
        cfg.stress = Stress::Objective;
        let floor = FlowSide::wall(Slip::NoSlip);
        let lid = FlowSide::moving_wall([0.5, 0.0]);
        let x = FlowSide::periodic();
        flow.setup(grid, [[x, x], [floor, lid]], cfg).unwrap();
        for i in 0..grid.len() {
            let [xc, z] = grid.center(i);
            let c = 0.58 - 0.3 * z / 0.12;
            flow.set_cell(i, c, [0.2 * z / 0.12 + 0.01 * (40.0 * xc).sin(), 0.0], 1e-4);
        }
        flow.prepare().unwrap();
        flow
    };
    check(make, &[&[0, 12], &[0, 4, 10, 18]], 40, "2D sheared layer");
}

#[test]
fn a_silo_discharging_through_its_floor_on_slabs_has_the_serial_bits() {
    // a bed draining through a central orifice in the floor (the first slab's side): the
    // outlet's faces, its wall contact and its discharge book; with the implicit pressure
    // and the viscous share too (the outlet's step, the held accelerations)
    for pressure in [PressureMode::Explicit, PressureMode::Implicit] {
        let make = || {
            let mut flow = boxed::<2>();
            let grid = Grid::new([16, 32], [0.0; 2], [0.08, 0.16], N).unwrap();
            let mut cfg = beads::<2>();
            cfg.free_surface_push = true;
            cfg.pressure = pressure;
            cfg.viscous_share = true;
            let wall = FlowSide::wall(Slip::Friction(30f64.to_radians().tan()));
            let mut floor = wall;
            floor.openings = Openings::one(Opening {
                lower: [0.03, 0.0],
                upper: [0.05, 0.0],
            });
            flow.setup(grid, [[wall, wall], [floor, wall]], cfg)
                .unwrap();
            for i in 0..grid.len() {
                let c = if grid.center(i)[1] < 0.12 { 0.6 } else { 0.0 };
                flow.set_cell(i, c, [0.0; 2], if c > 0.0 { 1e-4 } else { 0.0 });
            }
            flow.prepare().unwrap();
            flow
        };
        let what = format!("2D silo, {pressure:?} pressure");
        let whole = check(make, &[&[0, 8], &[0, 4, 12, 20, 26]], 300, &what);
        // grains did leave (m^2 per unit depth; the bed holds 0.6 x 0.08 x 0.12 = 5.8e-3)
        let out = whole.last().unwrap().books[0];
        assert!(out > 1e-5, "{what}: discharged {out}");
    }
}

#[test]
fn a_silo_discharging_through_its_side_walls_on_slabs_has_the_serial_bits() {
    // Sides along the cut that move mass (issue 12): an opening in the right wall that spans
    // the cuts, and an outflow left side; their faces, the outlet's step, and their books,
    // which every slab continues from the slabs below (`Flow::discharge_along`). The
    // opening's edges lie inside rows 3 and 13, so its open fractions are placed on the whole
    // grid, not a slab's (`origin + k h` rounds differently from `(origin + k0 h) + k h`).
    for pressure in [PressureMode::Explicit, PressureMode::Implicit] {
        let make = || {
            let mut flow = boxed::<2>();
            let grid = Grid::new([16, 32], [0.0, 0.013], [0.08, 0.16], N).unwrap();
            let mut cfg = beads::<2>();
            cfg.free_surface_push = true;
            cfg.pressure = pressure;
            cfg.viscous_share = true;
            let wall = FlowSide::wall(Slip::Friction(30f64.to_radians().tan()));
            let mut right = wall;
            right.openings = Openings::one(Opening {
                lower: [0.0, 0.013 + 0.0173],
                upper: [0.0, 0.013 + 0.0671],
            });
            let left = if pressure == PressureMode::Explicit {
                FlowSide::outflow()
            } else {
                wall
            };
            flow.setup(grid, [[left, right], [wall, wall]], cfg)
                .unwrap();
            for i in 0..grid.len() {
                let [x, z] = grid.center(i);
                let c = if z < 0.013 + 0.12 && x > 0.01 {
                    0.6
                } else {
                    0.0
                };
                flow.set_cell(i, c, [0.0; 2], if c > 0.0 { 1e-4 } else { 0.0 });
            }
            flow.prepare().unwrap();
            flow
        };
        let what = format!("2D silo with side outlets, {pressure:?} pressure");
        let whole = check(make, &[&[0, 8], &[0, 4, 12, 20, 26]], 200, &what);
        // grains did leave through the right wall's opening (and the left side, if open)
        let [right, _] = whole.last().unwrap().along[0];
        assert!(
            right[1] > 1e-5,
            "{what}: right side discharged {}",
            right[1]
        );
        if pressure == PressureMode::Explicit {
            assert!(right[0] > 1e-6, "{what}: left side discharged {}", right[0]);
        }
    }
}

#[test]
fn random_states_on_slabs_have_the_serial_bits() {
    // Random content (empty to packed), velocities and temperatures: the limiters bind and
    // the Rhie-Chow corrections stay below their caps next to the cuts, where a smooth scene
    // rarely puts them.
    for seed in 1..=24u64 {
        let make = || {
            let mut next = crate::common::uniform(seed);
            let mut flow = boxed::<2>();
            let grid = Grid::new([12, 16], [0.0; 2], [0.06, 0.08], N).unwrap();
            let mut cfg = beads::<2>();
            cfg.free_surface_push = seed % 2 == 0;
            if seed % 3 == 0 {
                cfg.pressure = PressureMode::Implicit;
                cfg.viscous_share = seed % 6 == 0;
            }
            let wall = FlowSide::wall(Slip::Friction(0.5));
            // every other seed opens the sides along the cut: an opening, an outflow
            let (mut left, mut right) = (wall, wall);
            if seed % 4 == 1 {
                right.openings = Openings::one(Opening {
                    lower: [0.0, 0.012],
                    upper: [0.0, 0.061],
                });
            } else if seed % 4 == 3 {
                left = FlowSide::outflow();
            }
            flow.setup(grid, [[left, right], [wall, wall]], cfg)
                .unwrap();
            let c_max = (1.0 - cfg.margin) * cfg.material.phi_rcp;
            for i in 0..grid.len() {
                let c = match (next() * 4.0) as u32 {
                    0 => 0.0,
                    1 => c_max * (1.0 - 1e-3 * next()),
                    _ => c_max * next(),
                };
                let u = [next() - 0.5, 2.0 * next() - 1.0];
                flow.set_cell(i, c, u, 1e-3 * next());
            }
            flow.prepare().unwrap();
            flow
        };
        check(make, &[&[0, 4, 8, 12]], 4, &format!("random state {seed}"));
    }
}

#[test]
fn a_box_in_its_rotating_frame_on_slabs_has_the_serial_bits() {
    // a half-filled box turning at 3 rad/s about a point off its centre, in its own frame:
    // gravity turns, and the centrifugal bounds are the box's, not a slab's
    let make = || {
        let mut flow = boxed::<2>();
        let grid = Grid::new([16, 32], [0.0; 2], [0.08, 0.16], N).unwrap();
        let mut cfg = beads::<2>();
        cfg.free_surface_push = true;
        cfg.frame = Frame::Rotating(Rotation::new(3.0, [0.04, 0.02], 0).unwrap());
        let wall = FlowSide::wall(Slip::Friction(0.5));
        flow.setup(grid, [[wall, wall], [wall, wall]], cfg).unwrap();
        for i in 0..grid.len() {
            let c = if grid.center(i)[1] < 0.08 { 0.6 } else { 0.0 };
            flow.set_cell(i, c, [0.0; 2], 0.0);
        }
        flow.prepare().unwrap();
        flow
    };
    check(make, &[&[0, 16], &[0, 8, 16, 24]], 120, "rotating box");
}

#[test]
fn a_3d_collapse_on_slabs_has_the_serial_bits() {
    let make = || {
        collapse(
            [6, 5, 16],
            [0.03, 0.025, 0.08],
            [0.015, 0.02, 0.06],
            PressureMode::Explicit,
        )
    };
    check(make, &[&[0, 8], &[0, 4, 8, 12]], 30, "3D collapse");
}

#[test]
fn what_does_not_run_on_slabs_is_refused_before_it_starts() {
    let flow = collapse([20, 24], [0.1, 0.12], [0.05, 0.09], PressureMode::Explicit);
    let mut local = boxed::<2>();
    // a slab thinner than its halo would take halo rows from two neighbours
    assert_eq!(
        load_slab(&*flow, &[0, 2, 12], 0, &mut *local).err(),
        Some(SlabError::Rows {
            index: 0,
            rows: 2,
            depth: 4
        })
    );
    // an odd cut cannot carry the V-cycle's coarse levels
    assert!(matches!(
        load_slab(&*flow, &[0, 11], 0, &mut *local),
        Err(SlabError::Plan(_))
    ));
    // each refusal reads as one line in words
    let short = load_slab(&*flow, &[0, 2, 12], 0, &mut *local)
        .err()
        .unwrap();
    assert_eq!(
        short.to_string(),
        "slab 0 owns 2 rows; every slab needs at least 4 (its halo's depth)"
    );
    let odd = load_slab(&*flow, &[0, 11], 0, &mut *local).err().unwrap();
    assert!(odd.to_string().contains("odd row"), "{odd}");
    // a flow that was never prepared has no pressures or coefficients to hand on
    let mut unprepared = boxed::<2>();
    unprepared
        .setup(*flow.grid(), *flow.boundaries(), *flow.config())
        .unwrap();
    assert_eq!(
        load_slab(&*unprepared, &[0, 12], 0, &mut *local).err(),
        Some(SlabError::Unprepared)
    );
}

/// A drum of diameter 0.15 m on 32 x 32 cells (one cell around it), cut-cell wall with 11 deg
/// of friction, half filled at rest with a tilted surface; in its rotating frame at 1 rev/s
/// (`lab = false`) or in the lab frame with its wall turning (`lab = true`).
fn drum(lab: bool) -> Box<Flow<f64, 2, N>> {
    drum_filled(lab, |[x, z]| {
        let surface = 0.075 + 0.4 * (x - 0.075);
        let c = if z < surface { 0.6 } else { 0.0 };
        (c, [0.0; 2], 0.0)
    })
}

/// [`drum`] with the state `fill` gives each open cell from its centre.
fn drum_filled(
    lab: bool,
    mut fill: impl FnMut([f64; 2]) -> (f64, [f64; 2], f64),
) -> Box<Flow<f64, 2, N>> {
    let mut cfg = beads::<2>();
    cfg.free_surface_push = true;
    let (mut flow, cut) = crate::drum_common::turning_drum::<N>(lab, cfg);
    let grid = *flow.grid();
    for i in 0..grid.len() {
        let (c, u, t) = if cut.is_solid(i) {
            (0.0, [0.0; 2], 0.0)
        } else {
            fill(grid.center(i))
        };
        flow.set_cell(i, c, u, t);
    }
    flow.prepare().unwrap();
    flow
}

/// A random state in the open cells of the drum: empty to packed, velocities up to 1 m/s,
/// temperatures up to 1e-3 (the `random_states` test's, on cut cells).
fn random_drum(seed: u64) -> Box<Flow<f64, 2, N>> {
    let mut next = crate::common::uniform(seed);
    let cfg = beads::<2>();
    let c_max = (1.0 - cfg.margin) * cfg.material.phi_rcp;
    drum_filled(seed % 2 == 0, |_| {
        let c = match (next() * 4.0) as u32 {
            0 => 0.0,
            1 => c_max * (1.0 - 1e-3 * next()),
            _ => c_max * next(),
        };
        (c, [next() - 0.5, 2.0 * next() - 1.0], 1e-3 * next())
    })
}

#[test]
fn a_drum_with_its_cut_cell_wall_on_slabs_has_the_serial_bits() {
    // a bed slumping in a drum turning in its own frame, and in the lab frame with its wall
    // turning (the wall's rigid motion carried across merge groups); the cuts cross the
    // groups where the wall runs along the rows
    let start = drum(false);
    assert_eq!(
        halo_rows(&*start),
        7,
        "merge groups span one row: 4 + 3 halo rows"
    );
    let cuts: [&[usize]; 3] = [&[0, 16], &[0, 8, 24], &[0, 10, 18]];
    check(|| drum(false), &cuts, 80, "drum in its frame");
    check(|| drum(true), &cuts, 80, "drum in the lab frame");
}

#[test]
fn random_drum_states_on_slabs_have_the_serial_bits_at_every_cut() {
    // The halo's depth (slab.rs `halo_rows`): random states make every wrong halo value
    // show; each even cut the depth allows, rotating frame and lab frame. With the box's 4
    // rows the cut at row 4 failed (seeds 5 and 6).
    for seed in 1..=8u64 {
        let depth = halo_rows(&*random_drum(seed));
        for k in (depth..=32 - depth).filter(|k| k % 2 == 0) {
            check(
                || random_drum(seed),
                &[&[0, k]],
                4,
                &format!("random drum {seed}"),
            );
        }
    }
}
