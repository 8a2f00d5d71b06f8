//! Granular column collapse (issue 3 hard case): a 2D block of glass beads (model.md 7.4)
//! released against the left wall of a box spreads along the floor and stops with a finite
//! slope, which is compared with the internal friction angle of model.md 2.
//!
//! Set-up: block width `a = 0.02 m`, height `H = 0.02 m` (aspect ratio 1), `c = 0.6` at rest
//! and cold, the rest of the box empty (`c = 0`); box 0.16 m x 0.032 m, walls with friction
//! angle 30 deg, gravity (0, -9.81) m/s^2, the full flow model (no segregation).
//!
//! The final slope is fitted by least squares to the free surface: per column the height
//! where `c` crosses half the bed value (the mean `c` of the deposit's dense cells), over the
//! sloping part (heights between 20 % and 80 % of the deposit height at the wall). The
//! internal friction angle is `atan(sqrt(eps0 eta0 / a))` ([`Material::friction_coefficient`],
//! 19.7 deg for the glass beads): the stress ratio of steady uniform shear, which is also the
//! yield criterion of the model (a resting region heats up and flows where `tau > mu p`).
//!
//! Band: `0.5 theta_f <= theta <= 1.05 theta_f`. The upper end is the static stability limit
//! (a heap cannot stand steeper than its friction angle; 5 % for the staircase surface of a
//! 2 mm grid). The lower end allows the inertial overshoot of a dynamic collapse: the flowing
//! layer stops only after its kinetic energy is spent, so deposits of low aspect ratio columns
//! end below the angle of repose (Lajeunesse et al. 2005, Lube et al. 2005: truncated deposits
//! for a < ~1 whose flank lies below the repose angle; continuum mu(I) simulations of the same
//! experiments, Lagree et al. 2011, end a few degrees below the static friction angle).
//!
//! Within that physical band the README's collapse row states what this run measures (runout,
//! height, kinetic energy, rest time, mass, packing, steps, flank): the row is read back and
//! every number asserted to its last written digit (issue 10), so a change of the numerics
//! that moves the deposit fails here until the README says so.

use crate::readme;

use sieve_core::closure::Material;
use sieve_core::flow::{Flow, FlowConfig, FlowSide, Slip};
use sieve_core::Grid;
use sieve_tests::run_big;

const N: usize = 4096;

/// Geometry and duration of one collapse.
#[derive(Clone, Copy, Debug)]
pub struct Setup {
    /// Cells (x, z).
    pub cells: [usize; 2],
    /// Box (x, z) in m.
    pub size: [f64; 2],
    /// Block width a and height H in m.
    pub block: [f64; 2],
    /// Volume fraction of the block.
    pub c0: f64,
    /// Simulated time in s.
    pub t_end: f64,
    /// Start of the window in which the deposit must be at rest, in s.
    pub t_rest: f64,
}

/// What a collapse measured.
#[derive(Debug, Default)]
#[allow(missing_docs)]
pub struct Outcome {
    pub mass_error: f64,
    pub max_packing: f64,
    pub min_t: f64,
    pub nonfinite: bool,
    pub ke_peak: f64,
    pub ke_end: f64,
    /// Largest kinetic energy in the rest window.
    pub ke_rest: f64,
    /// Spread of the front position over the rest window, m.
    pub front_drift: f64,
    /// Front position (runout from the left wall) at the end, m.
    pub runout: f64,
    /// Deposit height at the left wall, m.
    pub height: f64,
    /// Fitted slope angle, degrees, and the number of columns in the fit.
    pub slope_deg: f64,
    pub fit_columns: usize,
    /// Time when the kinetic energy fell below 1e-5 of its peak for good, s.
    pub t_stop: f64,
    pub steps: u64,
    pub seconds: f64,
}

/// Surface height of every column: where `c` first reaches `level` from above (linear
/// interpolation between cell centres; 0 if the bottom cell is below `level`).
fn surface(flow: &Flow<f64, 2, N>, cells: [usize; 2], hz: f64, level: f64) -> Vec<f64> {
    let [nx, nz] = cells;
    (0..nx)
        .map(|ix| {
            let c = |iz: usize| flow.c(ix + nx * iz);
            match (0..nz).rev().find(|&iz| c(iz) >= level) {
                None => 0.0,
                Some(iz) if iz + 1 == nz => nz as f64 * hz,
                Some(iz) => {
                    let (lo, hi) = (c(iz), c(iz + 1));
                    (iz as f64 + 0.5 + (lo - level) / (lo - hi)) * hz
                }
            }
        })
        .collect()
}

/// Front position: where the bottom row's `c` falls below `level` (interpolated), m.
fn front(flow: &Flow<f64, 2, N>, cells: [usize; 2], hx: f64, level: f64) -> f64 {
    let nx = cells[0];
    match (0..nx).rev().find(|&ix| flow.c(ix) >= level) {
        None => 0.0,
        Some(ix) if ix + 1 == nx => nx as f64 * hx,
        Some(ix) => {
            let (lo, hi) = (flow.c(ix), flow.c(ix + 1));
            (ix as f64 + 0.5 + (lo - level) / (lo - hi)) * hx
        }
    }
}

/// Least-squares slope of `(x, y)`.
fn slope(x: &[f64], y: &[f64]) -> f64 {
    let n = x.len() as f64;
    let (mx, my) = (x.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = x.iter().map(|a| (a - mx) * (a - mx)).sum();
    sxy / sxx
}

/// Runs one collapse and measures it.
pub fn collapse(s: Setup) -> Outcome {
    let mut flow: Box<Flow<f64, 2, N>> = Box::new(Flow::zeroed());
    let grid = Grid::new(s.cells, [0.0; 2], s.size, N).unwrap();
    let mat = Material::glass_beads();
    let mut cfg = FlowConfig::new(mat);
    cfg.free_surface_push = true;
    let wall = FlowSide::wall(Slip::Friction(30f64.to_radians().tan()));
    flow.setup(grid, [[wall, wall], [wall, wall]], cfg).unwrap();
    for i in 0..grid.len() {
        let [x, z] = grid.center(i);
        let c = if x < s.block[0] && z < s.block[1] {
            s.c0
        } else {
            0.0
        };
        flow.set_cell(i, c, [0.0; 2], 0.0);
    }
    flow.prepare().unwrap();
    let [hx, hz] = grid.spacing();
    let m0 = flow.diagnostics().mass;
    let mut o = Outcome {
        min_t: f64::MAX,
        ..Default::default()
    };
    let (mut front_min, mut front_max) = (f64::MAX, 0.0f64);
    let start = std::time::Instant::now();
    while flow.time() < s.t_end {
        flow.step(flow.stable_dt());
        let d = flow.diagnostics();
        o.mass_error = o.mass_error.max((d.mass - m0).abs() / m0);
        o.max_packing = o.max_packing.max(d.max_packing);
        o.min_t = o.min_t.min(d.t_min);
        o.nonfinite |= (0..grid.len()).any(|i| {
            let u = flow.velocity(i);
            let v = [flow.c(i), flow.temperature(i), flow.pressure(i), u[0], u[1]];
            v.iter().any(|x| !x.is_finite())
        });
        o.ke_peak = o.ke_peak.max(d.kinetic_energy);
        if d.kinetic_energy > 1e-5 * o.ke_peak {
            o.t_stop = flow.time();
        }
        if flow.time() >= s.t_rest {
            o.ke_rest = o.ke_rest.max(d.kinetic_energy);
            let f = front(&flow, s.cells, hx, 0.5 * mat.phi_rlp);
            front_min = front_min.min(f);
            front_max = front_max.max(f);
        }
    }
    o.seconds = start.elapsed().as_secs_f64();
    o.steps = flow.steps();
    o.ke_end = flow.diagnostics().kinetic_energy;
    o.front_drift = front_max - front_min;
    // bed value: mean c of the dense cells of the deposit
    let dense: Vec<f64> = (0..grid.len())
        .map(|i| flow.c(i))
        .filter(|&c| c >= 0.95 * mat.phi_rlp)
        .collect();
    let bed = dense.iter().sum::<f64>() / dense.len() as f64;
    let level = 0.5 * bed;
    o.runout = front(&flow, s.cells, hx, level);
    let h = surface(&flow, s.cells, hz, level);
    o.height = h[0];
    let (mut xs, mut ys) = (Vec::new(), Vec::new());
    for (ix, &y) in h.iter().enumerate() {
        if y >= 0.2 * o.height && y <= 0.8 * o.height {
            xs.push((ix as f64 + 0.5) * hx);
            ys.push(y);
        }
    }
    o.fit_columns = xs.len();
    o.slope_deg = (-slope(&xs, &ys)).atan().to_degrees();
    println!(
        "surface (mm): {:?}",
        h.iter()
            .map(|v| (v * 1e4).round() / 10.0)
            .collect::<Vec<_>>()
    );
    println!(
        "{} x {} cells, a = {} m, H = {} m, c0 = {}: bed c {bed:.4}, slope {:.2} deg over {} columns \
         (friction angle {:.2} deg), runout {:.4} m, height {:.4} m, KE peak {:.3e} end {:.3e} \
         rest-window max {:.3e}, stop {:.3} s, front drift {:.1e} m, mass {:.1e}, max c/c_rcp {:.5}, \
         min T {:.1e}, {} steps, {:.1} s",
        s.cells[0],
        s.cells[1],
        s.block[0],
        s.block[1],
        s.c0,
        o.slope_deg,
        o.fit_columns,
        mat.friction_coefficient().atan().to_degrees(),
        o.runout,
        o.height,
        o.ke_peak,
        o.ke_end,
        o.ke_rest,
        o.t_stop,
        o.front_drift,
        o.mass_error,
        o.max_packing,
        o.min_t,
        o.steps,
        o.seconds
    );
    o
}

/// Internal friction angle of model.md 2, `atan(sqrt(eps0 eta0 / a))`, in degrees, from the
/// constants of model.md 7.4 (eps0 = 1477.15 1/m, eta0 = 1.3e-4 m) and a = 3/2, written here
/// rather than read from the code's `Material`.
fn friction_angle_deg() -> f64 {
    (1477.15f64 * 1.3e-4 / 1.5).sqrt().atan().to_degrees()
}

/// Aspect ratio 1 on a 2 mm grid (80 x 16 cells), 1 s, ~14 s (opt-level 3). The numbers are
/// the README's collapse row (read from it): runout, height, kinetic energy, rest time, front
/// drift, mass, max c/c_rcp, steps, the flank and the friction angle.
#[test]
fn block_collapses_spreads_and_stops_near_the_friction_angle() {
    run_big(|| {
        let (a, h) = (0.02, 0.02);
        let o = collapse(Setup {
            cells: [80, 16],
            size: [0.16, 0.032],
            block: [a, h],
            c0: 0.6,
            t_end: 1.0,
            t_rest: 0.6,
        });
        let theta_f = friction_angle_deg();
        assert!(!o.nonfinite);
        // every face flux leaves one cell and enters the other: mass to round-off
        assert!(o.mass_error < 1e-13, "mass {}", o.mass_error);
        // the limiter keeps c <= (1 - 1e-3) c_rcp
        assert!(o.max_packing <= 0.999 + 1e-12, "{}", o.max_packing);
        assert!(o.min_t >= 0.0, "{}", o.min_t);
        // it spreads: runout well beyond the block, lower than the block
        assert!(o.runout > 2.0 * a, "runout {}", o.runout);
        assert!(
            o.height < 0.8 * h && o.height > 0.3 * h,
            "height {}",
            o.height
        );
        // it stops: kinetic energy down by > 5 orders, front still over the last 0.4 s
        assert!(o.ke_peak > 1e-6, "{}", o.ke_peak);
        assert!(
            o.ke_rest < 1e-5 * o.ke_peak,
            "{} vs {}",
            o.ke_rest,
            o.ke_peak
        );
        assert!(
            o.front_drift < 0.05 * 0.002,
            "front drift {}",
            o.front_drift
        );
        // final slope against the friction angle (band: see the module docs)
        assert!(o.fit_columns >= 8, "{}", o.fit_columns);
        assert!(
            o.slope_deg > 0.45 * theta_f && o.slope_deg < 1.05 * theta_f,
            "slope {} deg vs friction angle {} deg",
            o.slope_deg,
            theta_f
        );
        // the README's row, number by number
        let row = readme::table_row(readme::readme(), "column collapse, a = H = 0.02 m");
        let runout = readme::stated(row, "runout of", "m (", 1);
        readme::check("runout [m]", o.runout, &runout[0]);
        let runout_a = readme::stated(row, "m (", " a)", 1);
        readme::check("runout / a", o.runout / a, &runout_a[0]);
        let height = readme::stated(row, "height", " H;", 1);
        readme::check("height at the wall / H", o.height / h, &height[0]);
        let ke = readme::stated(row, "kinetic energy", ", at rest", 2);
        readme::check("kinetic energy, peak", o.ke_peak, &ke[0]);
        readme::check("kinetic energy, end", o.ke_end, &ke[1]);
        let rest = readme::stated(row, "at rest from", " s (", 1);
        readme::check("at rest from [s]", o.t_stop, &rest[0]);
        let drift = readme::stated(row, "front moves <", " um in", 1);
        readme::check_at_most("front drift [um]", o.front_drift * 1e6, &drift[0]);
        let window = readme::stated(row, "um in", " s)", 1);
        assert_eq!(
            window[0].value,
            1.0 - 0.6,
            "rest window of this test: 0.6 .. 1 s"
        );
        let mass = readme::stated(row, "mass", ", max", 1);
        readme::check("mass drift", o.mass_error, &mass[0]);
        let packing = readme::stated(row, "max c/c_rcp", ";", 1);
        readme::check("max c/c_rcp", o.max_packing, &packing[0]);
        let steps = readme::stated(row, "max c/c_rcp", "steps", 2);
        assert_eq!(o.steps as f64, steps[1].value, "steps");
        let flank = readme::stated(row, "Final flank", " deg (", 1);
        readme::check("final flank [deg]", o.slope_deg, &flank[0]);
        let theta = readme::stated(row, "eta0/a)) =", "deg of model.md", 1);
        readme::check("friction angle [deg]", theta_f, &theta[0]);
        let frac = readme::stated(row, "about", "of it", 1);
        // "about 0.59" covers this grid (0.586) and the 1 mm grid (0.594)
        assert!(
            (o.slope_deg / theta_f - frac[0].value).abs() < 0.05,
            "flank / friction angle {}",
            o.slope_deg / theta_f
        );
        // the prose below the table: (r_inf - a)/a ~ 1.2 in experiments, "against 2.4 here"
        let prose = readme::stated(readme::readme(), "1.2`, against", "here)", 1);
        readme::check("(r_inf - a)/a", (o.runout - a) / a, &prose[0]);
    });
}

/// The same collapse on a 1 mm grid (100 x 32 cells over 0.1 m x 0.032 m): the README's
/// "11.7 deg on 1 mm cells" (read from it); it asserts the flank, the invariants and that the
/// deposit is at rest, like the 2 mm test. Ignored until 2026-12-04 as "~2 min"; measured then
/// at 21 s (24,440 steps, opt-level 3), so it runs in the default suite.
#[test]
fn fine_grid_collapse() {
    run_big(|| {
        let o = collapse(Setup {
            cells: [100, 32],
            size: [0.1, 0.032],
            block: [0.02, 0.02],
            c0: 0.6,
            t_end: 1.0,
            t_rest: 0.6,
        });
        assert!(!o.nonfinite);
        assert!(o.mass_error < 1e-13, "mass {}", o.mass_error);
        assert!(o.max_packing <= 0.999 + 1e-12, "{}", o.max_packing);
        assert!(o.min_t >= 0.0, "{}", o.min_t);
        assert!(o.ke_rest < 1e-5 * o.ke_peak, "{} {}", o.ke_rest, o.ke_peak);
        assert!(o.fit_columns >= 8, "{}", o.fit_columns);
        let row = readme::table_row(readme::readme(), "column collapse, a = H = 0.02 m");
        let flank = readme::stated(row, " deg (", "deg on 1 mm cells", 1);
        readme::check("final flank on 1 mm cells [deg]", o.slope_deg, &flank[0]);
    });
}
