//! Silo discharge (model.md 7.6, issue 9) with the coupled flow and segregation: a flat
//! bottomed 2D silo, 0.145 m wide, with a central orifice in the floor (an opening in the
//! bottom wall, `sieve_core::boundary::Openings`), filled to 0.4 m with a mixed bed
//! (phihat = 1/2), the material of model.md 7.6, wall friction angle 30 deg, back-coupled
//! packing (R = 1/2 fit). Also the coupled column collapse, for the small-grain mass.
//!
//! What must hold: grains and fines in the silo plus what left equal the initial amounts to
//! round-off; `0 <= phi <= c` exactly (the carried transport, `sieve_core::flow::coupled`);
//! no NaN at the free surface or the orifice; a granular, not fluid, discharge: the rate is
//! constant while the bed is high (a liquid would drain like sqrt(h)).

use crate::silo_common::silo_material;
use sieve::silo::{DischargeRow, DischargeSeries};
use sieve_core::boundary::{Opening, Openings};
use sieve_core::closure::{Material, Packing};
use sieve_core::flow::coupled::{Coupled, CouplingConfig, Mode};
use sieve_core::flow::{Flow, FlowConfig, FlowSide, OutletPressure, Slip};
use sieve_core::segregation::{DirectionMode, Segregation, SegregationConfig};
use sieve_core::{diagnose, Boundary, Grid, Phase};
use sieve_tests::run_big;

const N: usize = 8192;

/// One discharge.
#[derive(Clone, Copy, Debug)]
pub struct Setup {
    /// Cells (x, z) over 0.145 m x `height`.
    pub cells: [usize; 2],
    /// Box height, m.
    pub height: f64,
    /// Orifice width W, m.
    pub orifice: f64,
    /// Shift of the orifice centre from the silo axis, m (grid placement study).
    pub shift: f64,
    /// Fill height, m, and volume fraction of the bed.
    pub fill: f64,
    /// Initial volume fraction.
    pub c0: f64,
    /// Ghost pressure of the outlet.
    pub outlet: OutletPressure,
    /// Simulated time, s, and sampling interval.
    pub t_end: f64,
    /// Sampling interval, s.
    pub every: f64,
    /// T floor of the flow's transport coefficients (`FlowConfig::t_min`).
    pub t_min: f64,
    /// Initial granular temperature.
    pub t0: f64,
}

impl Setup {
    /// 0.145 m x 0.5 m, W = 0.02 m, filled to 0.4 m at c = 0.6, p = 0 outlet.
    pub fn new(cells: [usize; 2], t_end: f64) -> Self {
        Self {
            cells,
            height: 0.5,
            orifice: 0.02,
            shift: 0.0,
            fill: 0.4,
            c0: 0.6,
            outlet: OutletPressure::Zero,
            t_end,
            every: 0.05,
            t_min: 1e-10,
            t0: 0.0,
        }
    }
}

/// What a discharge measured.
#[derive(Debug, Default)]
#[allow(missing_docs)]
pub struct Outcome {
    /// Discharge series (rates per sampling interval, surface height, mass in + out).
    pub series: DischargeSeries,
    /// max over samples of |carried c in the box + carried out - initial| / initial.
    pub carried_error: f64,
    pub overshoot: f64,
    pub undershoot: f64,
    pub guarded: f64,
    pub c_mismatch: f64,
    pub nonfinite: bool,
    pub steps: u64,
    pub seconds: f64,
}

impl Outcome {
    /// The sample at time `t`.
    pub fn at(&self, t: f64) -> DischargeRow {
        *self
            .series
            .rows
            .iter()
            .find(|r| (r.t - t).abs() < 1e-9)
            .unwrap()
    }
    /// Mean discharge rate over `[t0, t1]` (grain volume per unit depth, m^2/s).
    pub fn rate_in(&self, t0: f64, t1: f64) -> f64 {
        let (a, b) = (self.at(t0), self.at(t1));
        (b.out - a.out) / (b.t - a.t)
    }
}

/// Runs one discharge.
pub fn silo(s: Setup) -> Outcome {
    let width = 0.145;
    let mat = silo_material();
    let grid = Grid::new(s.cells, [0.0; 2], [width, s.height], N).unwrap();
    let mut flow: Box<Flow<f64, 2, N>> = Box::new(Flow::zeroed());
    let mut cfg = FlowConfig::new(mat);
    cfg.free_surface_push = true;
    cfg.t_min = s.t_min;
    let wall = FlowSide::wall(Slip::Friction(30f64.to_radians().tan()));
    let mut floor = wall;
    let centre = 0.5 * width + s.shift;
    floor.openings = Openings::one(Opening {
        lower: [centre - 0.5 * s.orifice, 0.0],
        upper: [centre + 0.5 * s.orifice, 0.0],
    });
    floor.outlet = s.outlet;
    flow.setup(grid, [[wall, wall], [floor, wall]], cfg)
        .unwrap();
    let mut seg: Box<Segregation<f64, 2, N>> = Box::new(Segregation::zeroed());
    let mut scfg = SegregationConfig::new();
    scfg.s0 = mat.s0;
    scfg.gravity = [0.0, -9.81];
    scfg.direction = DirectionMode::Flow;
    seg.setup(grid, [[Boundary::Wall; 2]; 2], scfg).unwrap();
    for i in 0..grid.len() {
        let z = grid.center(i)[1];
        let c = if z < s.fill { s.c0 } else { 0.0 };
        flow.set_cell(i, c, [0.0; 2], if c > 0.0 { s.t0 } else { 0.0 });
        seg.set_cell(i, c, 0.0, [0.0; 2], 0.5 * c);
    }
    let mut cc = CouplingConfig::new(Mode::Coupled);
    cc.packing = Packing::FitHalf;
    let mut cpl = Coupled::new(&mut flow, &mut seg, cc).unwrap();
    let vol = grid.cell_volume();
    let m0 = cpl.flow.diagnostics().mass;
    let mut o = Outcome::default();
    let start = std::time::Instant::now();
    let mut k = 0u32;
    loop {
        let t = cpl.seg.time();
        let next = f64::from(k) * s.every;
        if t >= next - 1e-12 {
            o.series.sample(next, &cpl);
            let carried: f64 = (0..grid.len()).map(|i| cpl.seg.c(i)).sum::<f64>() * vol;
            let e = (carried + cpl.discharged_total()[1][0] - m0).abs() / m0;
            o.carried_error = o.carried_error.max(e);
            o.c_mismatch = o.c_mismatch.max(cpl.c_mismatch());
            k += 1;
            if next >= s.t_end - 1e-12 {
                break;
            }
            continue;
        }
        let dt = cpl.flow.stable_dt().min(cpl.seg.stable_dt()).min(next - t);
        cpl.step_with(dt).unwrap();
        o.nonfinite |= (0..grid.len()).any(|i| {
            let u = cpl.flow.velocity(i);
            let v = [
                cpl.flow.c(i),
                cpl.flow.temperature(i),
                cpl.flow.pressure(i),
                u[0],
                u[1],
                cpl.seg.phi(i),
            ];
            v.iter().any(|x| !x.is_finite())
        });
    }
    o.seconds = start.elapsed().as_secs_f64();
    o.steps = cpl.flow.steps();
    let (over, under) = cpl.seg.bound_violations();
    o.overshoot = over;
    o.undershoot = under;
    o.guarded = cpl.guarded_mass();
    let sm = o.series.summary();
    println!(
        "silo {:?} W = {} shift {} {:?}: {} steps, {:.1} s wall; mass errors (flow, carried, fines) {:.1e} {:.1e} {:.1e}; over/under {:.1e} {:.1e}; guarded {:.1e}; c mismatch {:.1e}",
        s.cells, s.orifice, s.shift, s.outlet, o.steps, o.seconds, sm.mass_error, o.carried_error, sm.mass_small_error, o.overshoot, o.undershoot, o.guarded, o.c_mismatch
    );
    for r in &o.series.rows {
        println!(
            "  t {:.2}: out {:.1} %, rate {:.3e} m^2/s, fines fraction {:.3}, surface {:.3} m",
            r.t,
            100.0 * r.out / sm.mass_initial,
            r.rate,
            r.fines_fraction,
            r.surface
        );
    }
    o
}

/// FNV-1a of the bits of c, phi and u of both solvers after a run (rerun check).
fn bits<const M: usize>(flow: &Flow<f64, 2, M>, seg: &Segregation<f64, 2, M>) -> u64 {
    let mut h: u64 = 0xcbf29ce484222325;
    for i in 0..flow.len() {
        let u = flow.velocity(i);
        for v in [flow.c(i), seg.c(i), seg.phi(i), u[0], u[1]] {
            for b in v.to_bits().to_le_bytes() {
                h = (h ^ u64::from(b)).wrapping_mul(0x100000001b3);
            }
        }
    }
    h
}

/// The column collapse of `flow_collapse.rs` coupled to segregation of a mixed bed: the
/// flow's limiter cuts face fluxes all along the spreading front, where the old scheme
/// clipped phi (column-collapse lost 0.265 % of its small grains). Returns (largest relative
/// mass error of the small and of the large grains, overshoot, undershoot, state bits).
fn coupled_collapse(t_end: f64, phase: Phase) -> (f64, f64, f64, u64) {
    const M: usize = 2048;
    let grid = Grid::new([80, 16], [0.0; 2], [0.16, 0.032], M).unwrap();
    let mat = Material::glass_beads();
    let mut flow: Box<Flow<f64, 2, M>> = Box::new(Flow::zeroed());
    let mut cfg = FlowConfig::new(mat);
    cfg.free_surface_push = true;
    let wall = FlowSide::wall(Slip::Friction(30f64.to_radians().tan()));
    flow.setup(grid, [[wall, wall], [wall, wall]], cfg).unwrap();
    let mut seg: Box<Segregation<f64, 2, M>> = Box::new(Segregation::zeroed());
    let mut scfg = SegregationConfig::new();
    scfg.gravity = [0.0, -9.81];
    scfg.direction = DirectionMode::Flow;
    scfg.phase = phase;
    seg.setup(grid, [[Boundary::Wall; 2]; 2], scfg).unwrap();
    for i in 0..grid.len() {
        let [x, z] = grid.center(i);
        let c = if x < 0.02 && z < 0.02 { 0.6 } else { 0.0 };
        flow.set_cell(i, c, [0.0; 2], 0.0);
        seg.set_cell(i, c, 0.0, [0.0; 2], 0.5 * c);
    }
    let mut cpl = Coupled::new(&mut flow, &mut seg, CouplingConfig::new(Mode::Coupled)).unwrap();
    let large = |seg: &Segregation<f64, 2, M>| -> f64 {
        (0..grid.len()).map(|i| seg.c(i) - seg.phi(i)).sum::<f64>() * grid.cell_volume()
    };
    let s0 = diagnose(cpl.seg).mass_small;
    let l0 = large(cpl.seg);
    cpl.advance_to(t_end, u64::MAX).unwrap();
    let d = diagnose(cpl.seg);
    let el = (large(cpl.seg) - l0) / l0;
    let (over, under) = cpl.seg.bound_violations();
    assert_eq!(cpl.guarded_mass(), 0.0);
    let e = (d.mass_small - s0) / s0;
    println!(
        "coupled collapse ({phase:?} phase tracked) to t = {t_end}: {} steps, small mass {e:.1e}, large mass {el:.1e}, over/under {over:.1e} {under:.1e}, c mismatch {:.1e}, runout cells {}",
        cpl.flow.steps(),
        cpl.c_mismatch(),
        (0..80).filter(|&ix| cpl.flow.c(ix) > 0.1).count()
    );
    let h = bits(cpl.flow, cpl.seg);
    (e.abs().max(el.abs()), over, under, h)
}

/// Small- and large-grain mass to round-off in the coupled collapse (small grains were
/// -0.265 % with clipping), bounds exact, the same bits on a rerun, for either tracked phase.
/// Measured: small mass -6.1e-15, over/under exactly 0, ~3,000 steps.
#[test]
fn coupled_collapse_keeps_both_phases_to_round_off() {
    run_big(|| {
        for phase in [Phase::Small, Phase::Large] {
            let (e, over, under, h1) = coupled_collapse(0.25, phase);
            assert!(e < 1e-13, "{phase:?} {e}");
            assert!(over <= 0.0 && under <= 0.0, "{phase:?} {over} {under}");
            if phase == Phase::Small {
                let (_, _, _, h2) = coupled_collapse(0.25, phase);
                assert_eq!(h1, h2, "coupled rerun not bit-identical");
            }
        }
    });
}

/// A coarse discharge (~10 mm cells, 4-cell orifice W = 0.04 m, 2 s): grains and fines in +
/// out = initial to round-off, bounds exact, no NaN at the surface or the orifice, and a
/// granular rate: the same within 10 % over [0.25, 0.75] s and [1.25, 1.75] s while the free
/// surface falls so far that a liquid's sqrt(h) rate would have dropped by more than 15 %.
/// Measured (since `p = 0` sits on the orifice face, 2026-12-04): 1.31e-2 and 1.22e-2 m^2/s
/// (-7 %), surface 0.434 -> 0.183 m (sqrt ratio 0.65), 72 % out at 2 s, mass errors ~1e-15.
/// (With the ghost's `p = 0` half a cell below the face this grid took 1.5 s to open and
/// drained at 3.4e-3 m^2/s.)
#[test]
fn coarse_discharge_is_exact_bounded_and_granular() {
    run_big(|| {
        let mut s = Setup::new([15, 50], 2.0);
        s.orifice = 0.04;
        s.t_min = 1e-8;
        s.every = 0.25;
        let o = silo(s);
        let sm = o.series.summary();
        assert!(!o.nonfinite);
        assert!(sm.mass_error < 1e-13, "{sm:?}");
        assert!(sm.mass_small_error < 1e-13, "{sm:?}");
        assert!(o.carried_error < 1e-13, "{}", o.carried_error);
        assert!(o.overshoot <= 0.0 && o.undershoot <= 0.0);
        assert_eq!(o.guarded, 0.0);
        let (r1, r2) = (o.rate_in(0.25, 0.75), o.rate_in(1.25, 1.75));
        let (h1, h2) = (o.at(0.25).surface, o.at(1.75).surface);
        println!(
            "rates {r1:.4e} {r2:.4e} ({:+.1} %), surface {h1:.3} -> {h2:.3} m, sqrt ratio {:.3}",
            100.0 * (r2 / r1 - 1.0),
            (h2 / h1).sqrt()
        );
        assert!(r1 > 5e-3, "{r1}");
        assert!((r2 / r1 - 1.0).abs() < 0.1, "{r1} {r2}");
        assert!((h2 / h1).sqrt() < 0.85, "{h1} {h2}");
        // the bed is still higher than the silo is wide (0.145 m) at the end of the window
        assert!(h2 > 0.145, "{h2}");
        let out = o.at(2.0).out / sm.mass_initial;
        assert!(out > 0.5 && out < 0.9, "{out}");
        // model.md 7.6: stagnant corners (below 1 % of the outlet speed) that grow as the bed
        // sinks, and a layer of fines growing in the shear band around them (the V from the
        // orifice corners) while the flowing core stays mixed. Measured on this 15 x 50 grid
        // (`sieve run silo --grid 15x50`, the same setup): stagnant 0.014 -> 0.030 of the
        // bed, band phihat 0.541 -> 0.637, core 0.495 -> 0.492 over 0.5 -> 1.75 s.
        let (early, late) = (o.at(0.5), o.at(1.75));
        println!(
            "zones: stagnant {:.3} -> {:.3}, band phihat {:.3} -> {:.3}, core {:.3} -> {:.3}",
            early.stagnant,
            late.stagnant,
            early.band_phihat,
            late.band_phihat,
            early.core_phihat,
            late.core_phihat
        );
        assert!(
            early.stagnant > 0.005 && late.stagnant > early.stagnant,
            "{early:?} {late:?}"
        );
        assert!(
            late.band_phihat > early.band_phihat + 0.03,
            "{early:?} {late:?}"
        );
        assert!(late.band_phihat > late.core_phihat + 0.06, "{late:?}");
        assert!((late.core_phihat - 0.5).abs() < 0.02, "{late:?}");
    });
}

/// The outlet's `p = 0` sits on the orifice face, so the rate is resolved on coarse grids:
/// 10 mm cells (a 4-cell orifice, W = 0.04 m) drain within 25 % of the 5 mm rate over
/// [0.5, 1.0] s. With the ghost's `p = 0` half a cell below the face (until 2026-12-04) the
/// 10 mm silo crept through a nearly jammed orifice for a second and drained at a fifth of the
/// 5 mm rate (2.1e-3 against 9.3e-3 m^2/s over [0.6, 1.0] s: docs/silo.md section 4, where
/// the grids down to 1.25 mm are). Measured: 1.276e-2 against 1.497e-2 m^2/s (0.852), 7 s.
#[test]
fn the_orifice_is_resolved_on_coarse_grids() {
    run_big(|| {
        let rate = |cells: [usize; 2]| {
            let mut s = Setup::new(cells, 1.0);
            s.orifice = 0.04;
            s.t_min = 1e-8;
            s.every = 0.25;
            let o = silo(s);
            assert!(!o.nonfinite);
            o.rate_in(0.5, 1.0)
        };
        let (coarse, fine) = (rate([15, 50]), rate([29, 100]));
        println!(
            "rate over [0.5, 1.0] s: 10 mm {coarse:.4e}, 5 mm {fine:.4e} m^2/s (ratio {:.3})",
            coarse / fine
        );
        assert!(fine > 1.2e-2 && fine < 1.8e-2, "{fine}");
        assert!(
            coarse > 0.75 * fine && coarse < 1.1 * fine,
            "{coarse} {fine}"
        );
    });
}

/// Beverloo study on the default 5 mm grid (run with `--ignored`; ~1 CPU minute): steady
/// rates (10 - 50 % discharged, or to 1.5 s) for W = 0.03 .. 0.06 m, the Beverloo fit
/// `Q = C c sqrt(g) (W - W0)^(3/2)` and the free exponent of `W - W0`. Measured (since `p = 0`
/// sits on the orifice face, 2026-12-04; 244 s with the CI build beside it): 9.236e-3,
/// 1.509e-2, 2.203e-2, 2.970e-2 m^2/s; C = 1.21, W0 = 0.0046 m (0.9 cells), exponent of
/// W - W0 1.498 with that W0 (the CLI's runs: C = 1.20, W0 = 0.0045 m, residuals < 0.21 %;
/// the free fit of `sieve sweep --fit power`, which this study uses since 2026-12-07, gives
/// these four rates 1.568 at its own W0, run 2026-12-07 with C = 1.211, W0 = 4.6 mm). Before: 4.73e-3 .. 2.574e-2,
/// W0 = 0.0154 m (3.1 cells), residuals < 3 %. docs/silo.md section 4.
#[test]
#[ignore]
fn beverloo_study() {
    run_big(|| {
        let widths = [0.03, 0.04, 0.05, 0.06];
        let rates: Vec<f64> = widths
            .iter()
            .map(|&w| {
                let mut s = Setup::new([29, 100], 1.5);
                s.orifice = w;
                s.t_min = 1e-8;
                s.every = 0.1;
                silo(s).series.summary().steady_rate
            })
            .collect();
        // The fits of `sieve sweep --fit` (host/src/power_law.rs): 3/2 given, then free.
        use sieve::power_law::{fit, Exponent};
        let pts: Vec<(f64, f64)> = widths.iter().copied().zip(rates.iter().copied()).collect();
        let law = fit(&pts, Exponent::Fixed(1.5)).expect("Beverloo fit");
        let (c, w0) = (law.a / (9.81f64.sqrt() * 0.6), law.x0);
        let e = fit(&pts, Exponent::Free).expect("free fit").n;
        println!("widths {widths:?}, rates {rates:?}: Beverloo C = {c:.3}, W0 = {w0:.4} m; exponent of W - W0: {e:.3}");
        // the Beverloo form holds within 1 %, with W0 below two cells (it was 3.1 cells
        // while the outlet's p = 0 sat half a cell below the face)
        assert!(law.max_residual < 0.01, "{law:?}");
        assert!(w0 > 0.0 && w0 < 0.01, "{w0}");
    });
}
