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

use sieve_core::boundary::{Opening, Openings};
use sieve_core::closure::{Material, Packing};
use sieve_core::flow::coupled::{Coupled, CouplingConfig, Mode};
use sieve_core::flow::{Flow, FlowConfig, FlowSide, OutletPressure, Slip};
use sieve_core::segregation::{DirectionMode, Segregation, SegregationConfig};
use sieve_core::{diagnose, Boundary, Grid};
use sieve_tests::run_big;

const N: usize = 8192;

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

/// A sample: time, cumulative grain and fines volume out, grains and fines in the silo.
#[derive(Clone, Copy, Debug, Default)]
#[allow(missing_docs)]
pub struct Row {
    pub t: f64,
    pub out: f64,
    pub out_small: f64,
    pub in_box: f64,
    pub small_in_box: f64,
}

/// What a discharge measured.
#[derive(Debug, Default)]
#[allow(missing_docs)]
pub struct Outcome {
    pub rows: Vec<Row>,
    /// max over samples of |in + out - initial| / initial: flow grains, carried grains, fines.
    pub mass_error: [f64; 3],
    pub overshoot: f64,
    pub undershoot: f64,
    pub guarded: f64,
    pub c_mismatch: f64,
    pub nonfinite: bool,
    pub steps: u64,
    pub seconds: f64,
    pub initial: [f64; 2],
}

impl Outcome {
    /// Mean discharge rate (grain volume per unit depth and time, m^2/s) between the samples
    /// where the discharged fraction first reaches `from` and `to` of the initial grains.
    pub fn rate_between(&self, from: f64, to: f64) -> Option<f64> {
        let m0 = self.initial[0];
        let a = self.rows.iter().find(|r| r.out >= from * m0)?;
        let b = self.rows.iter().find(|r| r.out >= to * m0)?;
        (b.t > a.t).then(|| (b.out - a.out) / (b.t - a.t))
    }
    /// Mean rate over the samples in `[t0, t1]`.
    pub fn rate_in(&self, t0: f64, t1: f64) -> f64 {
        let a = self.rows.iter().find(|r| r.t >= t0 - 1e-9).unwrap();
        let b = self.rows.iter().rev().find(|r| r.t <= t1 + 1e-9).unwrap();
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
    let s0 = diagnose(cpl.seg).mass_small;
    let mut o = Outcome {
        initial: [m0, s0],
        ..Default::default()
    };
    let start = std::time::Instant::now();
    let mut next = 0.0;
    loop {
        let t = cpl.seg.time();
        if t >= next - 1e-12 {
            let d = diagnose(cpl.seg);
            let out = cpl.flow.discharged()[1][0];
            let row = Row {
                t,
                out,
                out_small: cpl.discharged_small()[1][0],
                in_box: cpl.flow.diagnostics().mass,
                small_in_box: d.mass_small,
            };
            let carried: f64 = (0..grid.len()).map(|i| cpl.seg.c(i)).sum::<f64>() * vol;
            let e = [
                (row.in_box + row.out - m0).abs() / m0,
                (carried + cpl.discharged_total()[1][0] - m0).abs() / m0,
                (row.small_in_box + row.out_small - s0).abs() / s0,
            ];
            for k in 0..3 {
                o.mass_error[k] = o.mass_error[k].max(e[k]);
            }
            o.c_mismatch = o.c_mismatch.max(cpl.c_mismatch());
            o.rows.push(row);
            next += s.every;
            if t >= s.t_end - 1e-12 {
                break;
            }
        }
        let dt = cpl
            .flow
            .stable_dt()
            .min(cpl.seg.stable_dt())
            .min(next - cpl.seg.time());
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
    println!(
        "silo {:?} W = {} shift {} {:?}: {} steps, {:.1} s wall; mass errors (flow, carried, fines) {:.1e} {:.1e} {:.1e}; over/under {:.1e} {:.1e}; guarded {:.1e}; c mismatch {:.1e}",
        s.cells, s.orifice, s.shift, s.outlet, o.steps, o.seconds, o.mass_error[0], o.mass_error[1], o.mass_error[2], o.overshoot, o.undershoot, o.guarded, o.c_mismatch
    );
    for w in o.rows.windows(2).step_by(2) {
        let (a, b) = (w[0], w[1]);
        let dq = b.out - a.out;
        println!(
            "  t {:.2}: out {:.3e} m^2 ({:.1} %), rate {:.3e} m^2/s, fines fraction of discharge {:.3}",
            b.t,
            b.out,
            100.0 * b.out / m0,
            dq / (b.t - a.t),
            if dq > 0.0 { (b.out_small - a.out_small) / dq } else { f64::NAN }
        );
    }
    o
}

#[test]
#[ignore]
fn explore() {
    run_big(|| {
        let args: Vec<f64> = std::env::var("SILO")
            .unwrap_or_default()
            .split(',')
            .filter_map(|x| x.parse().ok())
            .collect();
        let mut s = Setup::new([args[0] as usize, args[1] as usize], args[2]);
        s.t_min = args[3];
        s.t0 = args[4];
        s.orifice = args[5];
        let o = silo(s);
        assert!(!o.nonfinite);
    });
}
