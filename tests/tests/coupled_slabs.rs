//! The coupled step (percolation, flow, carried transport, back-coupled packing) on slabs of
//! rows (core/src/flow/coupled_slab.rs), each slab on its own thread as a rank of an MPI run
//! would step it: after every step the owned rows of every slab hold the serial run's bits in
//! every state array of the flow and of the segregation, and the step, the flush counter, the
//! guard's total, the bound maxima and the discharge books are the serial ones. A failure
//! names the first step, array and cell where the slabs left the serial run (issue 12).
//!
//! The scenes are the coupled hard cases: a mixed column collapsing onto a floor with the
//! packing limits back-coupled (free surfaces, empty cells, a bed near maximal packing), a
//! silo draining its fines through an orifice in the floor with a coarse flush floor (the
//! flush of the percolation's sub-steps at the cuts), the compensated update, random states,
//! a box in its rotating frame and a 3D collapse.

use crate::common::thread_links::{assert_serial_rows, on_threads};
use sieve_core::boundary::{Boundary, Opening, Openings};
use sieve_core::closure::{Material, Packing};
use sieve_core::flow::coupled::{Coupled, CouplingConfig, CouplingError, Mode};
use sieve_core::flow::coupled_slab::{load_coupled_slab, store_slab_records, SlabRecord};
use sieve_core::flow::slab::{Slab, SlabError};
use sieve_core::flow::{Flow, FlowConfig, FlowSide, PressureMode, Slip};
use sieve_core::fork::Serial;
use sieve_core::frame::{Frame, Rotation};
use sieve_core::geometry::CutCells;
use sieve_core::segregation::{DirectionMode, Segregation, SegregationConfig, Transport};
use sieve_core::sum::InOrder;
use sieve_core::{
    add_psi_sums, diagnose_fields, psi_floor, psi_of_sums, psi_sums_start, Grid, PsiOf, Real,
};
use std::ops::Range;

const N: usize = 1024;

/// A coupled run's two solvers and its coupling, before the driver is built.
struct Scene<R: Real, const D: usize> {
    flow: Box<Flow<R, D, N>>,
    seg: Box<Segregation<R, D, N>>,
    coupling: CouplingConfig<R>,
    /// The container's cut cells (the flow has them already), if any.
    cut: Option<Box<CutCells<R, D, N>>>,
}

impl<R: Real, const D: usize> Scene<R, D> {
    /// The driver of the whole run.
    fn driver(&mut self) -> Coupled<'_, R, D, N> {
        match &self.cut {
            Some(cut) => Coupled::new_embedded(&mut self.flow, &mut self.seg, self.coupling, cut),
            None => Coupled::new(&mut self.flow, &mut self.seg, self.coupling),
        }
        .unwrap()
    }
}

/// What one step left: the step, the running counters and books, and every state array of
/// both solvers over some cells (`flow.` and `seg.` before the names of
/// [`Flow::for_each_state_array`] and [`Segregation::for_each_state_array`]), as f64 (an
/// f32 value widens exactly, so equal bits stay equal bits).
struct After {
    dt: f64,
    cg: [u32; 4],
    flushed: f64,
    guarded: f64,
    excess: [f64; 2],
    /// small grains and all grains out through `[axis][side]`
    out: Vec<[[f64; 2]; 2]>,
    /// The segregation timer's Psi and the floor under it (`psi_of`).
    psi: [f64; 2],
    arrays: Vec<(String, Vec<f64>)>,
}

/// Psi and the floor under it of the cells `own` of `cpl` (their open volume fractions in
/// `volume`) as the segregation timer of a run on slabs takes them: sums continued across
/// the slabs in cell order (`sums`), over a grid of `cells` cells.
fn psi_of<R: Real, const D: usize>(
    cpl: &Coupled<'_, R, D, N>,
    own: Range<usize>,
    volume: Option<&[R]>,
    cells: usize,
    sums: &mut impl InOrder<R>,
) -> [f64; 2] {
    let phi: Vec<R> = own.clone().map(|i| cpl.seg.phi(i)).collect();
    let c: Vec<R> = own.map(|i| cpl.seg.c(i)).collect();
    let vacuum = cpl.seg.config().vacuum;
    [PsiOf::Value, PsiOf::Floor].map(|of| {
        let total = sums.sums_in_order(psi_sums_start(), |s| {
            add_psi_sums(s, of, &phi, &c, volume, vacuum)
        });
        psi_of_sums(total, of, cells, cpl.seg.grid().cell_volume()).to_f64()
    })
}

fn after<R: Real, const D: usize>(cpl: &Coupled<'_, R, D, N>, dt: R, cells: Range<usize>) -> After {
    let wide = |a: &[R]| a[cells.clone()].iter().map(|v| v.to_f64()).collect();
    let mut arrays = vec![];
    cpl.flow
        .for_each_state_array(|name, a| arrays.push((format!("flow.{name}"), wide(a))));
    cpl.seg
        .for_each_state_array(|name, a| arrays.push((format!("seg.{name}"), wide(a))));
    let (small, total) = (cpl.discharged_small(), cpl.discharged_total());
    let sides = |s: [R; 2]| s.map(|v| v.to_f64());
    After {
        dt: dt.to_f64(),
        cg: cpl.flow.last_cg_iterations(),
        flushed: cpl.seg.flushed_tracked().to_f64(),
        guarded: cpl.guarded_mass().to_f64(),
        excess: sides(cpl.seg.tracked_excess()),
        out: (0..D).map(|a| [sides(small[a]), sides(total[a])]).collect(),
        psi: [f64::NAN; 2],
        arrays,
    }
}

/// `steps` serial coupled steps of `scene`, each at its stable step.
fn serial<R: Real, const D: usize>(mut scene: Scene<R, D>, steps: usize) -> Vec<After> {
    let mut cpl = scene.driver();
    let n = cpl.flow.len();
    (0..steps)
        .map(|_| {
            let dt = cpl.stable_dt();
            cpl.step_with(dt).unwrap();
            let mut a = after(&cpl, dt, 0..n);
            // the serial timer's: the whole fields at once
            let (phi, c): (Vec<R>, Vec<R>) = (0..n).map(|i| (cpl.seg.phi(i), cpl.seg.c(i))).unzip();
            let vol = cpl.geometry().map(|g| g.volumes());
            let (vac, cv) = (cpl.seg.config().vacuum, cpl.seg.grid().cell_volume());
            a.psi = [
                diagnose_fields(&phi, &c, vol, vac, cv).psi.to_f64(),
                psi_floor(&phi, &c, vol, vac, cv).to_f64(),
            ];
            a
        })
        .collect()
}

/// The same steps on slabs cut at the rows `starts`, each slab on a thread: per slab, the
/// global cells it owns and what each step left in them.
fn on_slabs<R: Real, const D: usize>(
    start: &Coupled<'_, R, D, N>,
    starts: &[usize],
    steps: usize,
) -> Vec<(Range<usize>, Vec<After>)> {
    on_threads(starts.len(), |k, mut links| {
        let mut flow: Box<Flow<R, D, N>> = Box::new(Flow::zeroed());
        let mut seg: Box<Segregation<R, D, N>> = Box::new(Segregation::zeroed());
        let mut cut: Box<CutCells<R, D, N>> = Box::new(CutCells::zeroed());
        let geo = start.geometry().map(|_| &mut *cut);
        let plan = load_coupled_slab(start, starts, k, &mut flow, &mut seg, geo).unwrap();
        let geo = start.geometry().map(|_| &*cut);
        let mut memory = vec![R::ZERO; plan.memory_len()];
        let mut slab = Slab::new(&plan, &mut links, &mut memory);
        let mut cpl =
            Coupled::on_slab(&mut flow, &mut seg, start.slab_start(), geo, &mut slab).unwrap();
        let own = plan.owned_cells();
        let history = (0..steps)
            .map(|_| {
                let dt = cpl.stable_dt_reaching(&mut slab);
                cpl.step_with_reaching(dt, &Serial, &mut slab).unwrap();
                let mut a = after(&cpl, dt, own.clone());
                let vol = geo.map(|g| &g.volumes()[own.clone()]);
                a.psi = psi_of(&cpl, own.clone(), vol, start.flow.len(), &mut slab);
                a
            })
            .collect();
        (plan.global_cells(), history)
    })
}

/// Steps the scene `make` builds serially and on slabs cut at each of `cuts`, and asserts
/// the serial bits after every step, naming the first step, array and cell that differ.
/// Returns the serial run's steps.
fn check<R: Real, const D: usize>(
    make: impl Fn() -> Scene<R, D>,
    cuts: &[&[usize]],
    steps: usize,
    what: &str,
) -> Vec<After> {
    let mut start = make();
    let start = start.driver();
    let whole = serial(make(), steps);
    let plane = start.flow.len() / start.flow.grid().cells()[D - 1];
    for starts in cuts {
        let slabs = on_slabs(&start, starts, steps);
        for (step, expected) in whole.iter().enumerate() {
            let at = format!("{what}, cut at rows {starts:?}, step {}", step + 1);
            // the bound maxima of the whole grid: the largest of the slabs' (exact, but for
            // the sign of a zero: a maximum of +0 and -0 may be either)
            let most = slabs.iter().fold([f64::MIN; 2], |m, (_, h)| {
                [m[0].max(h[step].excess[0]), m[1].max(h[step].excess[1])]
            });
            assert_eq!(most, expected.excess, "{at}: bounds");
            for (k, (cells, history)) in slabs.iter().enumerate() {
                let got = &history[step];
                let at = format!("{at}, slab {k}");
                assert_eq!(got.dt.to_bits(), expected.dt.to_bits(), "{at}: dt");
                for ((name, mine), (_, all)) in got.arrays.iter().zip(&expected.arrays) {
                    assert_serial_rows(&at, name, mine, all, cells.start, plane);
                }
                assert_eq!(got.cg, expected.cg, "{at}: CG iterations");
                for (k, what) in ["Psi", "floor under Psi"].iter().enumerate() {
                    assert_eq!(
                        got.psi[k].to_bits(),
                        expected.psi[k].to_bits(),
                        "{at}: the timer's {what}"
                    );
                }
                assert_eq!(
                    got.flushed.to_bits(),
                    expected.flushed.to_bits(),
                    "{at}: flushed"
                );
                assert_eq!(
                    got.guarded.to_bits(),
                    expected.guarded.to_bits(),
                    "{at}: guarded"
                );
                // every slab holds the books of the sides along the cut (summed across the
                // slabs); the floor's books are the first slab's, the lid's the last one's
                for a in 0..D {
                    for side in 0..2 {
                        let owner = match (a + 1 == D, side) {
                            (false, _) => k,
                            (true, 0) => 0,
                            (true, _) => slabs.len() - 1,
                        };
                        if k == owner {
                            for (p, phase) in ["small", "all"].iter().enumerate() {
                                assert_eq!(
                                    got.out[a][p][side].to_bits(),
                                    expected.out[a][p][side].to_bits(),
                                    "{at}: {phase} grains out through side {side} of axis {a}"
                                );
                            }
                        }
                    }
                }
            }
        }
    }
    whole
}

/// The glass beads under gravity along the last axis.
fn beads<R: Real, const D: usize>() -> FlowConfig<R, D> {
    let mut cfg = FlowConfig::new(Material::glass_beads());
    cfg.gravity[D - 1] = R::from_f64(-9.81);
    cfg.free_surface_push = true;
    cfg
}

/// A segregation solver for the flow's grid: the direction from the flow, walls where the
/// flow has walls (open where it has outlets), fines at `phi = fines(x) c`, and the coupled
/// mode with back-coupled packing limits.
fn scene<R: Real, const D: usize>(
    flow: Box<Flow<R, D, N>>,
    fines: impl Fn(usize, [R; D]) -> R,
    tune: impl Fn(&mut SegregationConfig<R, D>),
) -> Scene<R, D> {
    let grid = *flow.grid();
    let mut cfg = SegregationConfig::new();
    cfg.s0 = R::from_f64(0.2);
    cfg.gravity[D - 1] = R::from_f64(-9.81);
    cfg.direction = DirectionMode::Flow;
    tune(&mut cfg);
    let mut bc = [[Boundary::Wall; 2]; D];
    for (a, sides) in flow.boundaries().iter().enumerate() {
        for (s, side) in sides.iter().enumerate() {
            if side.kind != Boundary::Wall {
                bc[a][s] = side.kind;
            }
        }
    }
    let mut seg: Box<Segregation<R, D, N>> = Box::new(Segregation::zeroed());
    seg.setup(grid, bc, cfg).unwrap();
    for i in 0..grid.len() {
        let c = flow.c(i);
        seg.set_cell(
            i,
            c,
            flow.temperature(i),
            flow.velocity(i),
            fines(i, grid.center(i)) * c,
        );
    }
    let mut coupling = CouplingConfig::new(Mode::Coupled);
    coupling.packing = Packing::FitHalf;
    Scene {
        flow,
        seg,
        coupling,
        cut: None,
    }
}

/// A flow in a box of friction walls, `c(x)` at rest, prepared.
fn boxed_flow<R: Real, const D: usize>(
    cells: [usize; D],
    size: [R; D],
    cfg: FlowConfig<R, D>,
    floor: FlowSide<R, D>,
    c: impl Fn([R; D]) -> R,
) -> Box<Flow<R, D, N>> {
    let mut flow: Box<Flow<R, D, N>> = Box::new(Flow::zeroed());
    let grid = Grid::new(cells, [R::ZERO; D], size, N).unwrap();
    let mut bc = [[friction_wall(); 2]; D];
    bc[D - 1][0] = floor;
    flow.setup(grid, bc, cfg).unwrap();
    for i in 0..grid.len() {
        let ci = c(grid.center(i));
        let t = if ci > R::ZERO { 1e-4 } else { 0.0 };
        flow.set_cell(i, ci, [R::ZERO; D], R::from_f64(t));
    }
    flow.prepare().unwrap();
    flow
}

/// A wall with 30 degrees of friction.
fn friction_wall<R: Real, const D: usize>() -> FlowSide<R, D> {
    FlowSide::wall(Slip::Friction(R::from_f64(30f64.to_radians().tan())))
}

/// A mixed block in the corner below `block` (fines in its upper half) that collapses.
fn collapse<R: Real, const D: usize>(
    cells: [usize; D],
    size: [R; D],
    block: [R; D],
    pressure: PressureMode,
) -> Scene<R, D> {
    let mut cfg = beads::<R, D>();
    cfg.pressure = pressure;
    let inside = move |x: [R; D]| (0..D).all(|a| x[a] < block[a]);
    let c = move |x| R::from_f64(if inside(x) { 0.6 } else { 0.0 });
    let flow = boxed_flow(cells, size, cfg, friction_wall(), c);
    let upper = move |x: [R; D]| x[D - 1] > R::from_f64(0.5) * block[D - 1];
    let fines = move |_, x| R::from_f64(if upper(x) { 0.7 } else { 0.2 });
    scene(flow, fines, |_| {})
}

#[test]
fn a_mixed_column_collapsing_on_slabs_has_the_serial_bits() {
    // 20 x 24 cells of 5 mm; the block falls and spreads across every cut, its packing limits
    // following its composition
    let cuts: [&[usize]; 3] = [&[0, 12], &[0, 6, 12, 18], &[0, 4, 8, 12, 16, 20]];
    let make = || collapse([20, 24], [0.1, 0.12], [0.05, 0.09], PressureMode::Explicit);
    check(make, &cuts, 60, "2D mixed collapse");
    let make = || collapse([20, 24], [0.1, 0.12], [0.05, 0.09], PressureMode::Implicit);
    check(make, &cuts[..2], 40, "2D mixed collapse, implicit pressure");
}

/// A silo of 16 x 32 cells draining through a central orifice in its floor, fines in a band
/// at mid-height, with the segregation tuned by `tune`.
fn silo(pressure: PressureMode, tune: impl Fn(&mut SegregationConfig<f64, 2>)) -> Scene<f64, 2> {
    let mut cfg = beads::<f64, 2>();
    cfg.pressure = pressure;
    cfg.viscous_share = pressure == PressureMode::Implicit;
    let mut floor = friction_wall::<f64, 2>();
    floor.openings = Openings::one(Opening {
        lower: [0.03, 0.0],
        upper: [0.05, 0.0],
    });
    let bed = |x: [f64; 2]| if x[1] < 0.12 { 0.6 } else { 0.0 };
    let flow = boxed_flow([16, 32], [0.08, 0.16], cfg, floor, bed);
    let band = |_, x: [f64; 2]| {
        if (0.05..0.08).contains(&x[1]) {
            0.9
        } else {
            0.0
        }
    };
    scene(flow, band, tune)
}

#[test]
fn a_silo_draining_its_fines_on_slabs_has_the_serial_bits() {
    // The orifice is the first slab's. A flush floor of 1e-9 (the default is far below any
    // fraction a short run makes) flushes the fines' thin front as it spreads from the band:
    // the flush of the percolation's sub-steps runs on the owned cells, its counter continued
    // from slab to slab.
    for pressure in [PressureMode::Explicit, PressureMode::Implicit] {
        let make = || silo(pressure, |s| s.flush_below = 1e-9);
        let what = format!("2D silo, {pressure:?} pressure");
        let whole = check(make, &[&[0, 8], &[0, 4, 12, 20, 26]], 240, &what);
        let last = whole.last().unwrap();
        // grains left through the floor, and something was flushed
        assert!(
            last.out[1][1][0] > 1e-5,
            "{what}: discharged {:?}",
            last.out
        );
        assert!(last.flushed != 0.0, "{what}: nothing flushed");
    }
}

/// A silo of 16 x 32 cells draining through an opening in its right wall that spans the cuts
/// (its edges inside rows 3 and 13) and, with the explicit pressure, through an outflow left
/// side: sides along the cut that move mass (issue 12), fines in a band at mid-height.
fn side_silo(
    pressure: PressureMode,
    tune: impl Fn(&mut SegregationConfig<f64, 2>),
) -> Scene<f64, 2> {
    let mut cfg = beads::<f64, 2>();
    cfg.pressure = pressure;
    cfg.viscous_share = pressure == PressureMode::Implicit;
    let wall = friction_wall::<f64, 2>();
    let mut right = wall;
    right.openings = Openings::one(Opening {
        lower: [0.0, 0.0173],
        upper: [0.0, 0.0671],
    });
    let left = match pressure {
        PressureMode::Explicit => FlowSide::outflow(),
        PressureMode::Implicit => wall,
    };
    let mut flow: Box<Flow<f64, 2, N>> = Box::new(Flow::zeroed());
    let grid = Grid::new([16, 32], [0.0; 2], [0.08, 0.16], N).unwrap();
    flow.setup(grid, [[left, right], [wall, wall]], cfg)
        .unwrap();
    for i in 0..grid.len() {
        let [x, z] = grid.center(i);
        let c = if z < 0.12 && x > 0.01 { 0.6 } else { 0.0 };
        flow.set_cell(i, c, [0.0; 2], if c > 0.0 { 1e-4 } else { 0.0 });
    }
    flow.prepare().unwrap();
    let band = |_, x: [f64; 2]| {
        if (0.02..0.06).contains(&x[1]) {
            0.9
        } else {
            0.1
        }
    };
    scene(flow, band, tune)
}

#[test]
fn a_silo_draining_through_its_side_walls_on_slabs_has_the_serial_bits() {
    // The books of the sides along the cut are sums over every slab's boundary cells,
    // continued from slab to slab: the flow's discharge and the carried transport's small
    // and total amounts (donor and limited rule), and the segregation's own books of its
    // outflow side (exact, merged by the driver).
    for pressure in [PressureMode::Explicit, PressureMode::Implicit] {
        let make = || side_silo(pressure, |s| s.flush_below = 1e-9);
        let what = format!("2D silo with side outlets, {pressure:?} pressure");
        let whole = check(make, &[&[0, 8], &[0, 4, 12, 20, 26]], 160, &what);
        // grains and fines left through the right wall's opening (and the left side)
        let out = whole.last().unwrap().out[0];
        assert!(
            out[1][1] > 1e-5 && out[0][1] > 1e-7,
            "{what}: right side {out:?}"
        );
        if pressure == PressureMode::Explicit {
            assert!(
                out[1][0] > 1e-6 && out[0][0] > 1e-8,
                "{what}: left side {out:?}"
            );
        }
    }
    let make = || {
        let mut s = side_silo(PressureMode::Explicit, |s| s.flush_below = 1e-9);
        s.seg.set_transport(Transport::Limited);
        s
    };
    check(
        make,
        &[&[0, 4, 12, 20, 26]],
        120,
        "2D silo with side outlets, limited",
    );
}

#[test]
fn the_compensated_update_on_slabs_has_the_serial_bits() {
    // the two-sum update carries each cell's rounding error (the `carry` array, refreshed at
    // the cuts) and flushes after every sub-step
    let make = || {
        silo(PressureMode::Explicit, |s| {
            s.compensated = true;
            s.flush_below = 1e-9;
        })
    };
    check(make, &[&[0, 4, 12, 20, 26]], 120, "2D silo, compensated");
}

#[test]
fn the_limited_transport_on_slabs_has_the_serial_bits() {
    // model.md 5.7: the face value at a cut reads the first halo row's slopes, bounds and
    // limiter, which read the second halo row
    let make = || {
        let mut s = silo(PressureMode::Explicit, |s| s.flush_below = 1e-9);
        s.seg.set_transport(Transport::Limited);
        s
    };
    check(
        make,
        &[&[0, 8], &[0, 4, 12, 20, 26]],
        240,
        "2D silo, limited transport",
    );
    let make = || {
        let mut s = collapse([20, 24], [0.1, 0.12], [0.05, 0.09], PressureMode::Implicit);
        s.seg.set_transport(Transport::Limited);
        s
    };
    check(
        make,
        &[&[0, 6, 12, 18]],
        40,
        "2D mixed collapse, limited transport",
    );
}

#[test]
fn random_coupled_states_on_slabs_have_the_serial_bits() {
    // random content (empty to packed) and composition, velocities and temperatures: the
    // limiters bind and the fines' fronts are steep next to the cuts; every other state with
    // the limited transport
    for seed in 1..=12u64 {
        let make = || {
            let mut next = crate::common::uniform(seed);
            let mut cfg = beads::<f64, 2>();
            if seed % 3 == 0 {
                cfg.pressure = PressureMode::Implicit;
            }
            let mut flow: Box<Flow<f64, 2, N>> = Box::new(Flow::zeroed());
            let grid = Grid::new([12, 16], [0.0; 2], [0.06, 0.08], N).unwrap();
            let wall = FlowSide::wall(Slip::Friction(0.5));
            flow.setup(grid, [[wall, wall], [wall, wall]], cfg).unwrap();
            let c_max = (1.0 - cfg.margin) * cfg.material.phi_rcp;
            let mut fines = vec![0.0; grid.len()];
            for (i, f) in fines.iter_mut().enumerate() {
                let c = match (next() * 4.0) as u32 {
                    0 => 0.0,
                    1 => c_max * (1.0 - 1e-3 * next()),
                    _ => c_max * next(),
                };
                let u = [next() - 0.5, 2.0 * next() - 1.0];
                flow.set_cell(i, c, u, 1e-3 * next());
                *f = if next() < 0.3 { 0.0 } else { next() };
            }
            flow.prepare().unwrap();
            let mut s = scene(flow, |i, _| fines[i], |_| {});
            if seed % 2 == 0 {
                s.seg.set_transport(Transport::Limited);
            }
            s
        };
        check(make, &[&[0, 4, 8, 12]], 4, &format!("random state {seed}"));
    }
}

#[test]
fn a_mixed_box_in_its_rotating_frame_on_slabs_has_the_serial_bits() {
    // a half-filled box turning at 3 rad/s about a point off its centre, in its own frame:
    // the segregation's gravity turns with the frame on every slab alike
    let make = || {
        let mut cfg = beads::<f64, 2>();
        cfg.frame = Frame::Rotating(Rotation::new(3.0, [0.04, 0.02], 0).unwrap());
        let wall = FlowSide::wall(Slip::Friction(0.5));
        let bed = |x: [f64; 2]| if x[1] < 0.08 { 0.6 } else { 0.0 };
        let flow = boxed_flow([16, 32], [0.08, 0.16], cfg, wall, bed);
        scene(flow, |_, x| if x[0] < 0.04 { 0.8 } else { 0.1 }, |_| {})
    };
    check(make, &[&[0, 8, 16, 24]], 120, "rotating mixed box");
}

/// A mixed drum of diameter 0.15 m on 32 x 32 cells (a cut-cell wall with 11 deg of
/// friction), half filled with a tilted surface, fines on the left; turning at 1 rev/s in its
/// own frame, or in the lab frame with its wall turning (`lab`).
fn mixed_drum(lab: bool, tune: impl Fn(&mut SegregationConfig<f64, 2>)) -> Scene<f64, 2> {
    let (mut flow, cut) = crate::drum_common::turning_drum::<N>(lab, beads::<f64, 2>());
    let grid = *flow.grid();
    for i in 0..grid.len() {
        let [x, z] = grid.center(i);
        let bed = z < 0.075 + 0.4 * (x - 0.075) && !cut.is_solid(i);
        flow.set_cell(i, if bed { 0.6 } else { 0.0 }, [0.0; 2], 0.0);
    }
    let mut s = scene(flow, |_, x| if x[0] < 0.075 { 0.8 } else { 0.2 }, tune);
    s.cut = Some(cut);
    s
}

#[test]
fn a_mixed_drum_with_its_cut_cell_wall_on_slabs_has_the_serial_bits() {
    // both solvers on cut cells: the flow's groups and deeper halo (slab.rs `halo_rows`),
    // the segregation's percolation, flush and carried transport group by group, the
    // guard's sum continued across the slabs; the cuts cross the groups where the wall
    // runs along the rows
    let cuts: [&[usize]; 2] = [&[0, 16], &[0, 8, 24]];
    let floor = |c: &mut SegregationConfig<f64, 2>| c.flush_below = 1e-9;
    check(
        || mixed_drum(false, floor),
        &cuts,
        80,
        "mixed drum in its frame",
    );
    check(
        || mixed_drum(true, |_| {}),
        &cuts,
        80,
        "mixed drum in the lab frame",
    );
    let limited = || {
        let mut s = mixed_drum(false, |_| {});
        s.seg.set_transport(Transport::Limited);
        s
    };
    check(limited, &cuts[1..], 40, "mixed drum, limited transport");
}

#[test]
fn a_mixed_3d_collapse_on_slabs_has_the_serial_bits() {
    let make = || {
        collapse(
            [6, 5, 16],
            [0.03, 0.025, 0.08],
            [0.015, 0.02, 0.06],
            PressureMode::Explicit,
        )
    };
    check(make, &[&[0, 8], &[0, 4, 8, 12]], 30, "3D mixed collapse");
}

#[test]
fn an_f32_mixed_collapse_on_slabs_has_the_serial_bits() {
    // the core is generic over the precision: the same construction in f32 (the slabs'
    // messages carry f32 here; over MPI they widen to f64 and narrow back exactly)
    let make = || collapse::<f32, 2>([20, 24], [0.1, 0.12], [0.05, 0.09], PressureMode::Explicit);
    check(
        make,
        &[&[0, 12], &[0, 6, 12, 18]],
        60,
        "2D mixed collapse in f32",
    );
}

/// A slab's owned cells (global numbering), its owned rows of every array (named as in
/// [`After`]) and its record.
type SlabReport = (Range<usize>, Vec<(String, Vec<f64>)>, SlabRecord<f64, 2>);

/// Every state array of both solvers, named as in [`After`], as f64.
fn arrays_of<R: Real, const D: usize>(cpl: &Coupled<'_, R, D, N>) -> Vec<(String, Vec<f64>)> {
    after(cpl, R::ZERO, 0..cpl.flow.len()).arrays
}

/// Copies `values` (named as in [`After`]) into `global`'s cells `cells`.
fn put_rows<R: Real, const D: usize>(
    global: &mut Coupled<'_, R, D, N>,
    cells: Range<usize>,
    values: &[(String, Vec<f64>)],
) {
    let find = |name: String| &values.iter().find(|(n, _)| *n == name).unwrap().1;
    global.flow.for_each_state_array_mut(|name, a| {
        for (x, &v) in a[cells.clone()]
            .iter_mut()
            .zip(find(format!("flow.{name}")))
        {
            *x = R::from_f64(v);
        }
    });
    global.seg.for_each_state_array_mut(|name, a| {
        for (x, &v) in a[cells.clone()].iter_mut().zip(find(format!("seg.{name}"))) {
            *x = R::from_f64(v);
        }
    });
}

#[test]
fn the_slabs_records_make_the_whole_run_whole_again_and_it_steps_on_with_the_serial_bits() {
    // What an MPI run's rank 0 does before an output or a checkpoint: every slab's owned rows
    // and record into a whole run built as at the start. The silo drains through the first
    // slab's floor and flushes; the stored run must equal the serial one after 150 steps
    // (arrays, clocks, counters, totals, state hash) and then step on with its bits.
    let make = || silo(PressureMode::Explicit, |s| s.flush_below = 1e-9);
    let starts = [0, 4, 12, 20, 26];
    let (steps, more) = (150, 30);
    let mut start = make();
    let start = start.driver();
    let slabs: Vec<SlabReport> = on_threads(starts.len(), |k, mut links| {
        let mut flow: Box<Flow<f64, 2, N>> = Box::new(Flow::zeroed());
        let mut seg: Box<Segregation<f64, 2, N>> = Box::new(Segregation::zeroed());
        let plan = load_coupled_slab(&start, &starts, k, &mut flow, &mut seg, None).unwrap();
        let mut memory = vec![0.0; plan.memory_len()];
        let mut slab = Slab::new(&plan, &mut links, &mut memory);
        let mut cpl =
            Coupled::on_slab(&mut flow, &mut seg, start.slab_start(), None, &mut slab).unwrap();
        for _ in 0..steps {
            let dt = cpl.stable_dt_reaching(&mut slab);
            cpl.step_with_reaching(dt, &Serial, &mut slab).unwrap();
        }
        let own = plan.owned_cells();
        let rows = after(&cpl, 0.0, own).arrays;
        (plan.global_cells(), rows, cpl.slab_record())
    });
    let mut s = make();
    let mut stored = s.driver();
    for (cells, rows, _) in &slabs {
        put_rows(&mut stored, cells.clone(), rows);
    }
    let records: Vec<_> = slabs.iter().map(|s| s.2).collect();
    store_slab_records(&mut stored, &records).unwrap();
    let mut w = make();
    let mut whole = w.driver();
    for _ in 0..steps {
        let dt = whole.stable_dt();
        whole.step_with(dt).unwrap();
    }
    let plane = 16;
    for step in 0..=more {
        let at = format!("stored at step {steps}, then {step} more");
        for ((name, got), (_, expected)) in arrays_of(&stored).iter().zip(&arrays_of(&whole)) {
            assert_serial_rows(&at, name, got, expected, 0, plane);
        }
        assert_eq!(
            stored.flow.counters(),
            whole.flow.counters(),
            "{at}: flow counters"
        );
        assert_eq!(stored.totals(), whole.totals(), "{at}: totals");
        assert_eq!(
            (stored.seg.time(), stored.seg.steps()),
            (whole.seg.time(), whole.seg.steps()),
            "{at}: clock"
        );
        assert_eq!(
            stored.seg.flushed_tracked().to_bits(),
            whole.seg.flushed_tracked().to_bits(),
            "{at}: flushed"
        );
        assert_eq!(
            stored.seg.tracked_excess(),
            whole.seg.tracked_excess(),
            "{at}: bounds"
        );
        assert_eq!(
            stored.seg.side_books(),
            whole.seg.side_books(),
            "{at}: books"
        );
        assert_eq!(
            sieve_core::state_hash(stored.seg),
            sieve_core::state_hash(whole.seg),
            "{at}: state hash"
        );
        let dt = whole.stable_dt();
        assert_eq!(
            stored.stable_dt().to_bits(),
            dt.to_bits(),
            "{at}: stable step"
        );
        whole.step_with(dt).unwrap();
        stored.step_with(dt).unwrap();
    }
    // the run drained and flushed across the cuts: the books and the counter are not zeros
    let out = whole.discharged_total()[1][0];
    assert!(out > 1e-5, "discharged {out}");
    assert!(whole.seg.flushed_tracked() != 0.0, "nothing flushed");
}

/// One coupled step of the 20 x 24 mixed collapse on 4 slabs (rows cut at 0, 6, 12, 18; on
/// threads), with a non-finite phi in the cell `cell` of the whole grid: each slab's error,
/// its cell counted in the whole grid (`CouplingError::offset_cell`), as a rank reports it.
fn one_step_with_a_nan(cell: usize) -> Vec<Option<CouplingError>> {
    let mut start = collapse([20, 24], [0.1, 0.12], [0.05, 0.09], PressureMode::Explicit);
    let start = start.driver();
    on_threads(4, |k, mut links| {
        let mut flow: Box<Flow<f64, 2, N>> = Box::new(Flow::zeroed());
        let mut seg: Box<Segregation<f64, 2, N>> = Box::new(Segregation::zeroed());
        let plan =
            load_coupled_slab(&start, &[0, 6, 12, 18], k, &mut flow, &mut seg, None).unwrap();
        let first = plan.global_cells().start - plan.owned_cells().start;
        let mut memory = vec![0.0; plan.memory_len()];
        let mut slab = Slab::new(&plan, &mut links, &mut memory);
        let mut cpl =
            Coupled::on_slab(&mut flow, &mut seg, start.slab_start(), None, &mut slab).unwrap();
        if plan.global_cells().contains(&cell) {
            cpl.seg.set_phi(cell - first, f64::NAN);
        }
        let dt = cpl.stable_dt_reaching(&mut slab);
        cpl.step_with_reaching(dt, &Serial, &mut slab)
            .err()
            .map(|e| e.offset_cell(first))
    })
}

#[test]
fn a_slab_that_fails_stops_every_slab_without_a_hang() {
    // a non-finite fraction in the first slab's floor row: after the step that slab's
    // segregation refuses its fields (its neighbour's too if the NaN reached its halo), and
    // the last slab says that another slab stopped, at the same point of the step
    let outcomes = one_step_with_a_nan(2);
    assert!(
        matches!(outcomes[0], Some(CouplingError::Segregation(_))),
        "{outcomes:?}"
    );
    assert_eq!(outcomes[3], Some(CouplingError::OtherSlab), "{outcomes:?}");
    assert_eq!(
        CouplingError::OtherSlab.to_string(),
        "another slab of the run stopped"
    );
}

#[test]
fn a_failing_slab_names_the_cell_the_serial_run_names() {
    // A non-finite fraction in the top owned row of the third slab (rows 12..18 of 24; row
    // 17, column 2): the slab's refusal, its cell counted from the whole grid's first
    // (`CouplingError::offset_cell`, what a rank of an MPI run reports), is the serial run's.
    let make = || collapse([20, 24], [0.1, 0.12], [0.05, 0.09], PressureMode::Explicit);
    let cell = 17 * 20 + 2;
    let mut serial = make();
    let mut whole = serial.driver();
    whole.seg.set_phi(cell, f64::NAN);
    let dt = whole.stable_dt();
    let expected = whole.step_with(dt).err();
    assert!(
        matches!(expected, Some(CouplingError::Segregation(_))),
        "{expected:?}"
    );
    let outcomes = one_step_with_a_nan(cell);
    // the first slab that failed for a reason of its own, as rank 0 reports it
    let named = outcomes
        .iter()
        .flatten()
        .find(|e| **e != CouplingError::OtherSlab);
    assert_eq!(named, expected.as_ref(), "{outcomes:?}");
    // and the offset reaches the cell only
    let e = CouplingError::Flow(sieve_core::flow::FlowError::Field {
        field: "c",
        cell: 3,
    });
    assert_eq!(
        e.offset_cell(40),
        CouplingError::Flow(sieve_core::flow::FlowError::Field {
            field: "c",
            cell: 43
        })
    );
    assert_eq!(
        CouplingError::OtherSlab.offset_cell(40),
        CouplingError::OtherSlab
    );
}

#[test]
fn what_does_not_run_on_slabs_is_refused_before_it_starts() {
    let mut flow: Box<Flow<f64, 2, N>> = Box::new(Flow::zeroed());
    let mut seg: Box<Segregation<f64, 2, N>> = Box::new(Segregation::zeroed());
    // the prescribed and frozen modes step the segregation alone (the subdomains of
    // `decomp` run them): not a coupled step on slabs
    let mut alone = collapse([20, 24], [0.1, 0.12], [0.05, 0.09], PressureMode::Explicit);
    alone.coupling.mode = Mode::Prescribed;
    let cpl = alone.driver();
    let refused = load_coupled_slab(&cpl, &[0, 12], 0, &mut flow, &mut seg, None).err();
    assert_eq!(
        refused,
        Some(SlabError::NotYet("the prescribed and frozen modes"))
    );
    assert_eq!(
        refused.unwrap().to_string(),
        "the prescribed and frozen modes do not run on slabs of rows yet"
    );
    // the flow slab's own refusals come through
    let mut plain = collapse([20, 24], [0.1, 0.12], [0.05, 0.09], PressureMode::Explicit);
    let cpl = plain.driver();
    assert_eq!(
        load_coupled_slab(&cpl, &[0, 2, 12], 0, &mut flow, &mut seg, None).err(),
        Some(SlabError::Rows {
            index: 0,
            rows: 2,
            depth: 4
        })
    );
    // a run on cut cells needs the slab's cut cells, and its driver the same geometry as
    // its flow; its slabs own the deeper halo's rows
    let mut drum = mixed_drum(false, |_| {});
    let cpl = drum.driver();
    let missing = load_coupled_slab(&cpl, &[0, 16], 0, &mut flow, &mut seg, None).err();
    assert_eq!(missing, Some(SlabError::GeometryMissing));
    assert_eq!(
        missing.unwrap().to_string(),
        "the run has cut-cell walls and its slabs were given no geometry"
    );
    let mut cut: Box<CutCells<f64, 2, N>> = Box::new(CutCells::zeroed());
    let thin = load_coupled_slab(&cpl, &[0, 6], 0, &mut flow, &mut seg, Some(&mut *cut)).err();
    assert_eq!(
        thin.unwrap().to_string(),
        "slab 0 owns 6 rows; every slab needs at least 7 (its halo's depth)"
    );
    let plan = load_coupled_slab(&cpl, &[0, 16], 0, &mut flow, &mut seg, Some(&mut *cut)).unwrap();
    let mut links = crate::common::thread_links::ThreadLinks::chain(2).swap_remove(0);
    let mut memory = vec![0.0; plan.memory_len()];
    let mut slab = Slab::new(&plan, &mut links, &mut memory);
    let start = cpl.slab_start();
    let mismatch = Coupled::on_slab(&mut flow, &mut seg, start, None, &mut slab).err();
    assert_eq!(mismatch, Some(CouplingError::GeometryMismatch));
    assert_eq!(
        mismatch.unwrap().to_string(),
        "the flow's cut-cell walls and the segregation's geometry differ (one has them, the other not)"
    );
}
