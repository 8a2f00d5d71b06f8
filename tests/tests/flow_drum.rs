//! The flow solver on cut-cell walls (issue 8): a drum of diameter 0.1 m (model.md 7.5) on
//! the static Cartesian grid, lab frame, glass beads of model.md 7.4. The box is the drum
//! plus one cell on each side; the cut cells come from `geometry::CutCells` (merging below
//! volume 1/2), the staircase is the same geometry rounded to whole cells
//! (`Flow::set_staircase_geometry`). The error of a solid-body rotation is
//! `max |u - omega x r| / (omega R)`, over the bulk (full cells whose four neighbours are
//! full and have no wall) or over the ring 1 to 3 cells inside the wall.

use sieve_core::closure::Material;
use sieve_core::flow::{CutWall, Flow, FlowConfig, FlowSide, Slip};
use sieve_core::geometry::{CutCells, Region, DEFAULT_SMALL};
use sieve_core::Grid;
use sieve_tests::run_big;

const N: usize = 48 * 48;
const RADIUS: f64 = 0.05;
/// Cells per axis (h = R/15).
const CELLS: usize = 32;
/// Initial volume fraction of the bed.
const C0: f64 = 0.6;

type F = Flow<f64, 2, N>;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Walls {
    Cut,
    Staircase,
}

struct Drum {
    flow: Box<F>,
    grid: Grid<f64, 2>,
    omega: f64,
}

/// A drum on `CELLS x CELLS` cells (the box is the drum plus one cell on each side), filled
/// below height `fill_top` (relative to the centre; `f64::INFINITY` = full) with `C0`.
fn drum(
    walls: Walls,
    slip: Slip<f64>,
    omega: f64,
    gravity: bool,
    fill_top: f64,
    t_min: f64,
) -> Drum {
    let (n, c0) = (CELLS, C0);
    let h = 2.0 * RADIUS / (n as f64 - 2.0);
    let l = n as f64 * h;
    let grid = Grid::new([n, n], [-0.5 * l; 2], [l; 2], N).unwrap();
    let mut cut: Box<CutCells<f64, 2, N>> = Box::new(CutCells::zeroed());
    cut.build(
        &grid,
        &Region::drum([0.0; 2], RADIUS),
        [false; 2],
        DEFAULT_SMALL,
    )
    .unwrap();
    let mut cfg = FlowConfig::new(Material::glass_beads());
    cfg.t_min = t_min;
    if !gravity {
        cfg.gravity = [0.0; 2];
    }
    let mut flow: Box<F> = Box::new(Flow::zeroed());
    let side = FlowSide::wall(Slip::NoSlip);
    flow.setup(grid, [[side; 2]; 2], cfg).unwrap();
    let wall = CutWall::rotating(slip, omega, [0.0; 2]);
    match walls {
        Walls::Cut => flow.set_geometry(&cut, wall).unwrap(),
        Walls::Staircase => flow.set_staircase_geometry(&cut, wall).unwrap(),
    }
    for i in 0..grid.len() {
        let x = grid.center(i);
        let c = if flow.open_volume(i) > 0.0 && x[1] < fill_top {
            c0
        } else {
            0.0
        };
        flow.set_cell(i, c, [0.0; 2], 0.0);
    }
    flow.prepare().unwrap();
    Drum { flow, grid, omega }
}

#[derive(Debug, Default)]
struct Run {
    mass_error: f64,
    min_t: f64,
    nonfinite: bool,
    max_packing: f64,
    steps: u64,
}

fn run(d: &mut Drum, t_end: f64) -> Run {
    let m0 = d.flow.diagnostics().mass;
    let mut r = Run {
        min_t: f64::MAX,
        ..Default::default()
    };
    while d.flow.time() < t_end {
        let dt = d.flow.stable_dt().min(t_end - d.flow.time());
        d.flow.step(dt);
        let g = d.flow.diagnostics();
        r.mass_error = r.mass_error.max((g.mass - m0).abs() / m0);
        r.min_t = r.min_t.min(g.t_min);
        r.max_packing = r.max_packing.max(g.max_packing);
        r.nonfinite |= !(g.mass.is_finite() && g.kinetic_energy.is_finite());
    }
    r.steps = d.flow.steps();
    r
}

/// Max |u - omega x r| / (omega R) over cells whose centre radius lies in `[r0, r1)` and that
/// are full cells (volume 1) in the cut-cell geometry.
fn rotation_error(d: &Drum, r0: f64, r1: f64, bulk_only: bool) -> f64 {
    let mut e = 0.0f64;
    let n = d.grid.cells();
    for i in 0..d.grid.len() {
        let x = d.grid.center(i);
        let r = (x[0] * x[0] + x[1] * x[1]).sqrt();
        if r < r0 || r >= r1 {
            continue;
        }
        if bulk_only {
            // not touching the wall: the cell and its four neighbours are full
            let [ix, iy] = d.grid.coords(i);
            if ix == 0 || iy == 0 || ix + 1 == n[0] || iy + 1 == n[1] {
                continue;
            }
            let s = n[0];
            if [i, i - 1, i + 1, i - s, i + s]
                .iter()
                .any(|&j| d.flow.open_volume(j) < 1.0 || d.flow.wall_coefficient(j) > 0.0)
            {
                continue;
            }
        }
        let u = d.flow.velocity(i);
        let ex = u[0] + d.omega * x[1];
        let ey = u[1] - d.omega * x[0];
        e = e.max((ex * ex + ey * ey).sqrt() / (d.omega * RADIUS));
    }
    e
}

/// Least-squares slope (degrees) of the free surface over the columns with `|x| < R/2`: per
/// column the bed height above `y = -6 h` from `sum c h / c_ref`, `c_ref` the column's `c` at
/// `y = -6.5 h` (full cells only there).
fn surface_angle(d: &Drum) -> f64 {
    let n = d.grid.cells();
    let h = d.grid.spacing();
    let (mut sx, mut sy, mut sxx, mut sxy, mut k) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for ix in 0..n[0] {
        let x = d.grid.center(d.grid.index([ix, 0]))[0];
        if x.abs() >= 0.5 * RADIUS {
            continue;
        }
        let mut height = 0.0;
        let mut c_ref = 0.0;
        for iy in 0..n[1] {
            let i = d.grid.index([ix, iy]);
            let y = d.grid.center(i)[1];
            if (y + 6.5 * h[1]).abs() < 0.25 * h[1] {
                c_ref = d.flow.c(i);
            }
            if y > -6.0 * h[1] {
                height += d.flow.c(i) * h[1];
            }
        }
        let z = height / c_ref;
        sx += x;
        sy += z;
        sxx += x * x;
        sxy += x * z;
        k += 1.0;
    }
    let slope = (k * sxy - sx * sy) / (k * sxx - sx * sx);
    slope.atan().to_degrees()
}

/// Spread `max - min` (m) of the bed height over the columns with `|x| < R/2` (as in
/// [`surface_angle`]).
fn surface_spread(d: &Drum) -> f64 {
    let n = d.grid.cells();
    let h = d.grid.spacing();
    let (mut lo, mut hi) = (f64::MAX, f64::MIN);
    for ix in 0..n[0] {
        let x = d.grid.center(d.grid.index([ix, 0]))[0];
        if x.abs() >= 0.5 * RADIUS {
            continue;
        }
        let (mut height, mut c_ref) = (0.0, 0.0);
        for iy in 0..n[1] {
            let i = d.grid.index([ix, iy]);
            let y = d.grid.center(i)[1];
            if (y + 6.5 * h[1]).abs() < 0.25 * h[1] {
                c_ref = d.flow.c(i);
            }
            if y > -6.0 * h[1] {
                height += d.flow.c(i) * h[1];
            }
        }
        lo = lo.min(height / c_ref);
        hi = hi.max(height / c_ref);
    }
    hi - lo
}

fn rev(r: f64) -> f64 {
    2.0 * std::f64::consts::PI * r
}

/// Solid-body rotation of the full drum (100 % fill, c = 0.6, no-slip wall turning at
/// omega), started from rest, lab frame, on 32 x 32 cells (h = R/15). Gravity off and
/// `T_min = 1e-4` (above the heating equilibrium `T ~ 1e-7`, so `eta` is uniform up to the
/// centrifugal pressure): this isolates the walls from the model's own non-objectivity (see
/// `full_drum_with_the_model_coefficients`). Measured (t = 0.08 s, spun up by 0.04 s):
/// bulk error 4.4e-3 (0.1 rev/s), band error 4.4e-3; the staircase wall 1.3e-1 / 3.1e-1.
/// On 48 x 48 the cut-cell bulk error is 3.1e-3 (order ~0.8): the 1e-3 of issue 8 is not
/// reached on these grids (the remaining error is the upwind face velocity of partial faces,
/// taken at the face centre, not at the open part's centroid).
#[test]
fn full_drum_solid_body_rotation_cut_cells_vs_staircase() {
    run_big(|| {
        let h = 2.0 * RADIUS / 30.0;
        for r in [0.1, 0.5] {
            let mut e = [[0.0; 2]; 2];
            for (k, walls) in [Walls::Cut, Walls::Staircase].into_iter().enumerate() {
                let mut d = drum(walls, Slip::NoSlip, rev(r), false, f64::INFINITY, 1e-4);
                let run = run(&mut d, 0.08);
                let bulk = rotation_error(&d, 0.0, RADIUS, true);
                // the ring of cells 1 to 3 cells inside the wall (open in both geometries)
                let band = rotation_error(&d, RADIUS - 3.0 * h, RADIUS - h, false);
                println!(
                    "{r} rev/s {walls:?}: bulk {bulk:.2e}, near wall {band:.2e}, mass {:.1e}, \
                     min T {:.1e}, max c/c_rcp {:.4}, {} steps",
                    run.mass_error, run.min_t, run.max_packing, run.steps
                );
                assert!(!run.nonfinite);
                assert!(run.mass_error < 1e-13, "{}", run.mass_error);
                assert!(run.min_t >= 0.0);
                assert!(run.max_packing < 0.999);
                e[k] = [bulk, band];
            }
            let [cut, stair] = e;
            // 1.26e-3 / 2.41e-3 at 0.1 rev/s, 1.33e-3 in the bulk at 0.5 (4.4e-3 and 4.2e-3
            // before the merge groups carried the wall's rigid motion, docs/flow-walls.md)
            assert!(cut[0] < 2e-3, "cut-cell bulk error {}", cut[0]);
            assert!(cut[1] < 3.5e-3, "cut-cell near-wall error {}", cut[1]);
            // the staircase drags and slips: an order of magnitude worse, most near the wall
            assert!(stair[0] > 10.0 * cut[0], "{stair:?} vs {cut:?}");
            assert!(stair[1] > 30.0 * cut[1], "{stair:?} vs {cut:?}");
        }
    });
}

/// The same drum with the model's own coefficients (`T_min = 1e-14`) and gravity: the
/// asymmetric stress `eta grad u` of model.md 2 does not vanish in a rigid rotation (its
/// heating `eta kappa:kappa = 2 eta omega^2` makes `T ~ 1e-7` and `eta ~ 1/sqrt(kappa:kappa)`),
/// so where `eta` varies (with the pressure under gravity, with T next to the wall) it acts as
/// the body force `omega rot90(grad eta)`, and the lab-frame bed lags the wall. Measured at
/// 0.1 rev/s: bulk error 1.1e-2 without gravity, 1.3e-2 with it (32 x 32). The rotating frame
/// (u = 0, kappa = 0) has no such stress: the frames are not equivalent for this model.
#[test]
fn full_drum_with_the_model_coefficients() {
    run_big(|| {
        let mut d = drum(
            Walls::Cut,
            Slip::NoSlip,
            rev(0.1),
            true,
            f64::INFINITY,
            1e-14,
        );
        let run = run(&mut d, 0.08);
        let bulk = rotation_error(&d, 0.0, RADIUS, true);
        println!(
            "model coefficients, gravity: bulk {bulk:.2e}, mass {:.1e}, min T {:.1e}, T max {:.2e}",
            run.mass_error,
            run.min_t,
            d.flow.diagnostics().t_max
        );
        assert!(!run.nonfinite);
        assert!(run.mass_error < 1e-13);
        assert!(run.min_t >= 0.0);
        assert!(bulk < 2e-2, "{bulk}");
    });
}

/// A half-filled drum at rest (c = 0.6 below the centre, cold, gravity, wall friction 11 deg
/// of model.md 7.5): it compacts and stays at rest. Measured on 32 x 32: max speed 2.6e-6 m/s
/// over [0.2, 0.4] s (the creep of the regularised yield viscosity, as in the box pile test),
/// surface angle 3e-11 deg (the friction angle is 19.7 deg), spread of the bed height over the
/// central half 1.3e-6 m (4e-4 h), mass 5.0e-15.
#[test]
fn half_drum_at_rest_stays_at_rest() {
    run_big(|| {
        let tan11 = 11f64.to_radians().tan();
        let mut d = drum(Walls::Cut, Slip::Friction(tan11), 0.0, true, 0.0, 1e-14);
        let early = run(&mut d, 0.2);
        let mut late_speed = 0.0f64;
        let mut mass = early.mass_error;
        let mut min_t = early.min_t;
        let mut nonfinite = early.nonfinite;
        while d.flow.time() < 0.4 {
            let t = d.flow.time() + 0.02;
            let r = run(&mut d, t);
            late_speed = late_speed.max(d.flow.diagnostics().max_speed);
            mass = mass.max(r.mass_error);
            min_t = min_t.min(r.min_t);
            nonfinite |= r.nonfinite;
        }
        let angle = surface_angle(&d);
        let spread = surface_spread(&d);
        let friction = Material::<f64>::glass_beads()
            .friction_coefficient()
            .atan()
            .to_degrees();
        println!(
            "half drum at rest: late speed {late_speed:.2e} m/s, angle {angle:.2e} deg \
             (friction {friction:.1} deg), height spread {spread:.2e} m, mass {mass:.1e}, \
             {} steps",
            d.flow.steps()
        );
        assert!(!nonfinite);
        assert!(mass < 1e-13, "{mass}");
        assert!(min_t >= 0.0);
        assert!(late_speed < 5e-6, "{late_speed}");
        assert!(angle.abs() < 0.1 * friction, "{angle}");
        assert!(spread < 1e-3 * RADIUS, "{spread}");
    });
}

fn fields_hash(d: &Drum) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for i in 0..d.grid.len() {
        let u = d.flow.velocity(i);
        for x in [d.flow.c(i), d.flow.temperature(i), u[0], u[1]] {
            for b in (x + 0.0).to_bits().to_le_bytes() {
                h ^= u64::from(b);
                h = h.wrapping_mul(0x0000_0100_0000_01b3);
            }
        }
    }
    h
}

/// Same input, same bits: two runs of a rotating, half-filled drum with wall friction and
/// gravity (every embedded code path) give the same fields.
#[test]
fn rerun_is_bit_identical() {
    run_big(|| {
        let tan11 = 11f64.to_radians().tan();
        let hash = || {
            let mut d = drum(
                Walls::Cut,
                Slip::Friction(tan11),
                rev(0.5),
                true,
                0.01,
                1e-14,
            );
            for _ in 0..300 {
                let dt = d.flow.stable_dt();
                d.flow.step(dt);
            }
            (fields_hash(&d), d.flow.time())
        };
        let (a, b) = (hash(), hash());
        println!("rerun: {:#018x} at t = {}", a.0, a.1);
        assert_eq!(a.0, b.0);
        assert_eq!(a.1.to_bits(), b.1.to_bits());
    });
}
