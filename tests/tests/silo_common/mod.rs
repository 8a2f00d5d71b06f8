//! The discharge runner shared by `flow_silo_3d.rs` and `flow_hopper.rs` (issue 9, model.md
//! 7.6): the silo of `flow_silo.rs` in 2D or 3D (a depth between friction walls along y),
//! optionally with a wedge hopper of cut cells at the bottom, coupled flow and segregation,
//! sampled with the host's own discharge readouts (`sieve::silo::DischargeSeries`), with the
//! bounds and finiteness checked in every cell after every step.

#![allow(dead_code)]

use sieve::silo::{DischargeRow, DischargeSeries};
use sieve_core::boundary::{Opening, Openings};
use sieve_core::closure::{Material, Packing};
use sieve_core::flow::coupled::{Coupled, CouplingConfig, Mode};
use sieve_core::flow::{CutWall, Flow, FlowConfig, FlowSide, OutletPressure, Slip};
use sieve_core::fork::{Fork, Serial};
use sieve_core::geometry::{CutCells, Region, DEFAULT_SMALL};
use sieve_core::segregation::{DirectionMode, Segregation, SegregationConfig};
use sieve_core::{Boundary, Grid};

/// Cell capacity (the 3D coarse silo has 15 x 4 x 30 = 1,800 cells).
pub const N: usize = 4096;
/// Silo width (x), m.
pub const WIDTH: f64 = 0.145;

/// The silo material of model.md 7.6.
pub fn silo_material() -> Material<f64> {
    Material {
        eta0: 0.00175,
        lambda0: 3.4e-4,
        eps0: 126.984,
        t0: 1.5,
        phi_rcp: 0.64,
        phi_rlp: 0.4,
        heating: 1.5,
        s0: 0.2,
    }
}

/// One discharge: a box `WIDTH x [depth x] height`, the orifice centred in the floor.
#[derive(Clone, Copy, Debug)]
pub struct Spec<const D: usize> {
    /// Cells per axis.
    pub cells: [usize; D],
    /// Box height, m.
    pub height: f64,
    /// Depth between the y walls (3D), m.
    pub depth: f64,
    /// Fill height, m (c = 0.6, phihat = 1/2 below it).
    pub fill: f64,
    /// Orifice width, m (a slot across the whole depth in 3D).
    pub orifice: f64,
    /// A wedge hopper: walls at this angle from the vertical [deg] meeting the orifice at
    /// `hopper_z` above the floor (a vertical channel of the orifice's width below).
    pub hopper: Option<f64>,
    /// Height of the hopper's orifice, m.
    pub hopper_z: f64,
    /// Simulated time and sampling interval, s.
    pub t_end: f64,
    /// Sampling interval, s.
    pub every: f64,
}

/// The coarse 2D silo (15 x 50, ~10 mm cells), 0.145 m x 0.5 m filled to 0.4 m, W = 0.04 m,
/// with a 30 deg hopper or a flat floor, sampled every `every` seconds.
pub fn coarse_2d(hopper: Option<f64>, t_end: f64, every: f64) -> Spec<2> {
    Spec {
        cells: [15, 50],
        height: 0.5,
        depth: 0.0,
        fill: 0.4,
        orifice: 0.04,
        hopper,
        hopper_z: 0.01,
        t_end,
        every,
    }
}

/// The coarse 3D silo (15 x 4 x 30, ~10 mm cells, 4 across the 0.04 m depth): a shortened
/// silo (0.3 m tall, filled to 0.25 m, still more than one silo width), a 6-cell slot
/// W = 0.06 m across the depth, sampled every 0.1 s.
pub fn coarse_3d(t_end: f64) -> Spec<3> {
    Spec {
        cells: [15, 4, 30],
        height: 0.3,
        depth: 0.04,
        fill: 0.25,
        orifice: 0.06,
        hopper: None,
        hopper_z: 0.0,
        t_end,
        every: 0.1,
    }
}

/// What a discharge measured.
#[derive(Debug, Default)]
pub struct Outcome {
    /// The host's discharge series (rates per sampling interval, zones, mass in + out).
    pub series: DischargeSeries,
    /// max over samples of |carried c in the box (open volume) + carried out - initial| / initial.
    pub carried_error: f64,
    /// max over cells and steps of phi - c and of -phi (0 when the bounds hold exactly).
    pub over: f64,
    /// See [`Self::over`].
    pub under: f64,
    /// A NaN or infinity in c, T, p, u or phi after some step.
    pub nonfinite: bool,
    /// Flow steps.
    pub steps: u64,
    /// Wall time, s.
    pub seconds: f64,
    /// Open cross-section of the orifice (m in 2D, m^2 in 3D).
    pub orifice_area: f64,
}

impl Outcome {
    /// The sample at time `t`.
    pub fn at(&self, t: f64) -> DischargeRow {
        *self
            .series
            .rows
            .iter()
            .find(|r| (r.t - t).abs() < 1e-9)
            .unwrap_or_else(|| panic!("no sample at {t}"))
    }
    /// Mean discharge rate over `[t0, t1]`.
    pub fn rate_in(&self, t0: f64, t1: f64) -> f64 {
        let (a, b) = (self.at(t0), self.at(t1));
        (b.out - a.out) / (b.t - a.t)
    }
    /// Small-grain fraction of what left over `[t0, t1]`.
    pub fn fines_in(&self, t0: f64, t1: f64) -> f64 {
        let (a, b) = (self.at(t0), self.at(t1));
        (b.out_small - a.out_small) / (b.out - a.out)
    }
}

/// Runs one discharge (call on a big-stack thread: `sieve_tests::run_big`).
pub fn discharge<const D: usize>(s: Spec<D>) -> Outcome {
    discharge_with(s, |_| {})
}

/// [`discharge`], handing the coupled state at `t_end` to `at_end` (a probe of the fields).
pub fn discharge_with<const D: usize>(
    s: Spec<D>,
    at_end: impl FnOnce(&Coupled<'_, f64, D, N>),
) -> Outcome {
    discharge_on(s, &Serial, at_end, |_| {})
}

/// [`discharge_with`] with the flow's solves on the threads of `fork`, handing the coupled
/// state to `after_step` after every step.
pub fn discharge_on<const D: usize, F: Fork>(
    s: Spec<D>,
    fork: &F,
    at_end: impl FnOnce(&Coupled<'_, f64, D, N>),
    after_step: impl FnMut(&Coupled<'_, f64, D, N>),
) -> Outcome {
    discharge_configured(s, fork, |_| {}, at_end, after_step)
}

/// [`discharge_on`] with the flow configuration changed by `configure` after the runner set
/// it up (e.g. the solves' initial guess).
pub fn discharge_configured<const D: usize, F: Fork>(
    s: Spec<D>,
    fork: &F,
    configure: impl FnOnce(&mut FlowConfig<f64, D>),
    at_end: impl FnOnce(&Coupled<'_, f64, D, N>),
    mut after_step: impl FnMut(&Coupled<'_, f64, D, N>),
) -> Outcome {
    let z = D - 1;
    let mut upper = [0.0; D];
    upper[0] = WIDTH;
    if D == 3 {
        upper[1] = s.depth;
    }
    upper[z] = s.height;
    let grid = Grid::new(s.cells, [0.0; D], upper, N).unwrap();
    let mat = silo_material();
    let tan = 30f64.to_radians().tan();
    let wall = FlowSide::wall(Slip::Friction(tan));
    let mut floor = wall;
    let centre = 0.5 * WIDTH;
    // With a hopper the whole floor is open: the solid wedges close all of it but the
    // channel under the orifice, so the geometry alone sets the orifice (scenes/hopper.toml).
    let half = if s.hopper.is_some() {
        0.5 * WIDTH
    } else {
        0.5 * s.orifice
    };
    let (mut lo, mut hi) = ([0.0; D], [0.0; D]);
    lo[0] = centre - half;
    hi[0] = centre + half;
    if D == 3 {
        hi[1] = s.depth;
    }
    floor.openings = Openings::one(Opening {
        lower: lo,
        upper: hi,
    });
    floor.outlet = OutletPressure::Zero;
    let mut sides = [[wall, wall]; D];
    sides[z][0] = floor;
    let mut cfg = FlowConfig::new(mat);
    cfg.free_surface_push = true;
    cfg.t_min = 1e-8;
    configure(&mut cfg);
    let mut flow: Box<Flow<f64, D, N>> = Box::new(Flow::zeroed());
    flow.setup(grid, sides, cfg).unwrap();
    let cut: Option<Box<CutCells<f64, D, N>>> = s.hopper.map(|angle| {
        let mut cut: Box<CutCells<f64, D, N>> = Box::new(CutCells::zeroed());
        let region = Region::hopper(
            0.0,
            WIDTH,
            centre,
            s.hopper_z,
            0.5 * s.orifice,
            angle.to_radians(),
        );
        cut.build(&grid, &region, [false; D], DEFAULT_SMALL)
            .unwrap();
        cut
    });
    if let Some(g) = cut.as_deref() {
        flow.set_geometry(g, CutWall::resting(Slip::Friction(tan)))
            .unwrap();
    }
    let mut seg: Box<Segregation<f64, D, N>> = Box::new(Segregation::zeroed());
    let mut scfg = SegregationConfig::new();
    scfg.s0 = mat.s0;
    let mut g = [0.0; D];
    g[z] = -9.81;
    scfg.gravity = g;
    scfg.direction = DirectionMode::Flow;
    seg.setup(grid, [[Boundary::Wall; 2]; D], scfg).unwrap();
    let open = |i: usize| cut.as_deref().map_or(1.0, |g| g.volume(i));
    for i in 0..grid.len() {
        let solid = cut.as_deref().is_some_and(|g| g.is_solid(i));
        let c = if grid.center(i)[z] < s.fill && !solid {
            0.6
        } else {
            0.0
        };
        flow.set_cell(i, c, [0.0; D], 0.0);
        seg.set_cell(i, c, 0.0, [0.0; D], 0.5 * c);
    }
    let mut cc = CouplingConfig::new(Mode::Coupled);
    cc.packing = Packing::FitHalf;
    let mut cpl = match cut.as_deref() {
        Some(g) => Coupled::new_embedded(&mut flow, &mut seg, cc, g).unwrap(),
        None => Coupled::new(&mut flow, &mut seg, cc).unwrap(),
    };
    let vol = grid.cell_volume();
    let carried = |cpl: &Coupled<'_, f64, D, N>| -> f64 {
        (0..grid.len()).map(|i| cpl.seg.c(i) * open(i)).sum::<f64>() * vol
    };
    let m0 = carried(&cpl);
    let mut o = Outcome {
        orifice_area: s.orifice * if D == 3 { s.depth } else { 1.0 },
        ..Default::default()
    };
    let start = std::time::Instant::now();
    let mut k = 0u32;
    loop {
        let t = cpl.seg.time();
        let next = f64::from(k) * s.every;
        if t >= next - 1e-12 {
            o.series.sample_in(next, &cpl, cut.as_deref());
            let out: f64 = cpl.discharged_total().iter().flatten().sum();
            o.carried_error = o.carried_error.max((carried(&cpl) + out - m0).abs() / m0);
            k += 1;
            if next >= s.t_end - 1e-12 {
                break;
            }
            continue;
        }
        let seg_dt = match cut.as_deref() {
            Some(g) => cpl.seg.stable_dt_embedded(g),
            None => cpl.seg.stable_dt(),
        };
        let dt = cpl.flow.stable_dt().min(seg_dt).min(next - t);
        cpl.step_with_on(dt, fork).unwrap();
        after_step(&cpl);
        for i in 0..grid.len() {
            let (phi, c) = (cpl.seg.phi(i), cpl.seg.c(i));
            o.over = o.over.max(phi - c);
            o.under = o.under.max(-phi);
            let u = cpl.flow.velocity(i);
            let finite = [
                phi,
                c,
                cpl.flow.c(i),
                cpl.flow.temperature(i),
                cpl.flow.pressure(i),
            ]
            .iter()
            .chain(u.iter())
            .all(|v| v.is_finite());
            o.nonfinite |= !finite;
        }
    }
    o.seconds = start.elapsed().as_secs_f64();
    o.steps = cpl.flow.steps();
    at_end(&cpl);
    let sm = o.series.summary();
    println!(
        "{}D {:?} W = {} hopper {:?}: {} steps, {:.1} s wall; mass errors (flow, carried, fines) {:.1e} {:.1e} {:.1e}; max(phi - c) {:.1e}, max(-phi) {:.1e}",
        D, s.cells, s.orifice, s.hopper, o.steps, o.seconds, sm.mass_error, o.carried_error, sm.mass_small_error, o.over, o.under
    );
    for r in &o.series.rows {
        println!(
            "  t {:.2}: out {:5.1} %, rate {:.3e}, fines fraction {:.3}, surface {:.3} m, stagnant {:.3}, band {:.3}, core {:.3}",
            r.t,
            100.0 * r.out / sm.mass_initial,
            r.rate,
            r.fines_fraction,
            r.surface,
            r.stagnant,
            r.band_phihat,
            r.core_phihat
        );
    }
    o
}
