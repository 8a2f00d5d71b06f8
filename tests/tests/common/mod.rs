//! Shared set-up of the integration tests: the scenes of model.md 7.1/7.2 built through the
//! public API of `sieve-core`, heap-allocated solvers, and small measuring helpers.
//!
//! Every test binary includes this module but uses only part of it, hence the `dead_code`
//! allowance below.
#![allow(dead_code)]

pub mod thread_links;

use sieve_core::{
    Boundaries, Boundary, DirectionMode, Grid, Phase, Real, Scheme, Segregation, SegregationConfig,
};

/// Capacity of the 1D columns (the finest column-a level has 800 cells).
pub const N1: usize = 1024;
/// Capacity of the 2D Gray–Thornton grids (160 x 80 = 12800 cells).
pub const N2: usize = 16384;

/// Uniform numbers in `[0, 1)` from a 64-bit linear congruential generator seeded by `seed`
/// (the random states of the slab tests).
pub fn uniform(seed: u64) -> impl FnMut() -> f64 {
    let mut state = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15);
    move || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// A zeroed solver on the heap.
///
/// `Segregation<R, D, N>` holds `(6 + 2 D) N` reals (1.3 MB for the 2D f64 tests), more than is
/// wise on the 2 MiB test-thread stack, and `Box::new(value)` may build the value on the stack
/// first. So it is built on a helper thread with a 256 MiB stack and only the box comes back.
pub fn boxed<R: Real, const D: usize, const N: usize>() -> Box<Segregation<R, D, N>> {
    std::thread::Builder::new()
        .stack_size(256 << 20)
        .spawn(|| Box::new(Segregation::<R, D, N>::zeroed()))
        .expect("spawn builder thread")
        .join()
        .expect("builder thread")
}

/// Configuration shared by all tests: S0 = 1, gravity `g`, given T, Courant 0.5.
pub fn config<R: Real, const D: usize>(
    scheme: Scheme,
    phase: Phase,
    gravity: [f64; D],
    direction: DirectionMode<R, D>,
) -> SegregationConfig<R, D> {
    let mut cfg = SegregationConfig::new();
    cfg.scheme = scheme;
    cfg.phase = phase;
    cfg.gravity = gravity.map(R::from_f64);
    cfg.direction = direction;
    cfg
}

// ---------------------------------------------------------------------------------------------
// Segregation columns (model.md 7.1)
// ---------------------------------------------------------------------------------------------

/// The four segregation columns of model.md 7.1, z in [0, 1], walls at both ends.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Column {
    /// c = 0.64, T = 1.
    A,
    /// c falls linearly from 0.64 at z = 0.05 to 0.24 at z = 0.95 (constant outside), T = 1.
    B,
    /// c as in B, T = 0.1 + z^2 (non-linear, increasing with height).
    C,
    /// T = 1, c = 0.6 below z = 0.56 and 0.15 above.
    D,
}

impl Column {
    /// Volume fraction at height z.
    pub fn c(self, z: f64) -> f64 {
        match self {
            Column::A => 0.64,
            Column::B | Column::C => {
                let s = ((z - 0.05) / 0.9).clamp(0.0, 1.0);
                0.64 + (0.24 - 0.64) * s
            }
            Column::D => {
                if z < 0.56 {
                    0.6
                } else {
                    0.15
                }
            }
        }
    }
    /// Granular temperature at height z.
    pub fn t(self, z: f64) -> f64 {
        match self {
            Column::C => 0.1 + z * z,
            _ => 1.0,
        }
    }
}

/// A column on `cells` cells with the given scheme and tracked phase, initial phi = c/2,
/// gravity `[gz]` (-1: the large grains rise with |S| = 1), prepared.
pub fn column_with_gravity<R: Real>(
    col: Column,
    cells: usize,
    scheme: Scheme,
    phase: Phase,
    gz: f64,
) -> Box<Segregation<R, 1, N1>> {
    let mut s = boxed::<R, 1, N1>();
    let grid = Grid::new([cells], [R::ZERO], [R::ONE], N1).expect("grid");
    let bc: Boundaries<1> = [[Boundary::Wall; 2]];
    s.setup(
        grid,
        bc,
        config(scheme, phase, [gz], DirectionMode::Gravity),
    )
    .expect("setup");
    for i in 0..cells {
        let z = grid.center(i)[0].to_f64();
        let c = R::from_f64(col.c(z));
        s.set_cell(i, c, R::from_f64(col.t(z)), [R::ZERO], c * R::HALF);
    }
    s.prepare().expect("prepare");
    s
}

/// A column with gravity pointing down (model.md 7.1).
pub fn column<R: Real>(
    col: Column,
    cells: usize,
    scheme: Scheme,
    phase: Phase,
) -> Box<Segregation<R, 1, N1>> {
    column_with_gravity(col, cells, scheme, phase, -1.0)
}

/// Bound violations of model.md 6 (`max(0, phi - c)`, `max(0, -phi)`) of the current state, in
/// f64 (computed here rather than by `diagnose`, which also evaluates logarithms: this runs
/// after every step).
pub fn violations<R: Real, const D: usize, const N: usize>(s: &Segregation<R, D, N>) -> (f64, f64) {
    let (mut over, mut under) = (0.0f64, 0.0f64);
    for i in 0..s.len() {
        let (phi, c) = (s.phi(i).to_f64(), s.c(i).to_f64());
        over = over.max(phi - c);
        under = under.max(-phi);
    }
    (over, under)
}

/// Result of [`run_watching`]: the largest bound violations over all cells and all steps.
#[derive(Clone, Copy, Debug, Default)]
pub struct Watch {
    /// max over time of max(0, phi - c)
    pub overshoot: f64,
    /// max over time of max(0, -phi)
    pub undershoot: f64,
    /// steps taken
    pub steps: u64,
    /// true if every phi stayed finite
    pub finite: bool,
}

/// Advances to `t_end` with the stable step, checking the bounds after every step.
pub fn run_watching<R: Real, const D: usize, const N: usize>(
    s: &mut Segregation<R, D, N>,
    t_end: f64,
    max_steps: u64,
) -> Watch {
    let t_end = R::from_f64(t_end);
    let mut w = Watch {
        finite: true,
        ..Watch::default()
    };
    while s.time() < t_end && w.steps < max_steps {
        w.steps += s.advance_to(t_end, 1);
        let (o, u) = violations(s);
        w.overshoot = w.overshoot.max(o);
        w.undershoot = w.undershoot.max(u);
        w.finite &= (0..s.len()).all(|i| s.phi(i).is_finite());
    }
    w
}

/// phihat = phi / c of every cell, in f64.
pub fn phihat<R: Real, const D: usize, const N: usize>(s: &Segregation<R, D, N>) -> Vec<f64> {
    (0..s.len())
        .map(|i| s.phi(i).to_f64() / s.c(i).to_f64())
        .collect()
}

/// The first position where the piecewise-linear interpolant of `(z[j], v[j])` crosses `level`,
/// scanning upward, or None.
pub fn crossing(z: &[f64], v: &[f64], level: f64) -> Option<f64> {
    (1..v.len()).find_map(|j| {
        let (a, b) = (v[j - 1] - level, v[j] - level);
        if a == 0.0 {
            Some(z[j - 1])
        } else if a * b < 0.0 || b == 0.0 {
            Some(z[j - 1] + (z[j] - z[j - 1]) * a / (a - b))
        } else {
            None
        }
    })
}

/// Cell centres along axis `axis` of a grid with `n` cells on `[0, len]`.
pub fn centres(n: usize, len: f64) -> Vec<f64> {
    (0..n).map(|j| (j as f64 + 0.5) * len / n as f64).collect()
}

/// Least-squares slope of `log e` against `log h`: the observed order of convergence.
pub fn observed_order(h: &[f64], e: &[f64]) -> f64 {
    let x: Vec<f64> = h.iter().map(|v| v.ln()).collect();
    let y: Vec<f64> = e.iter().map(|v| v.ln()).collect();
    let n = x.len() as f64;
    let (mx, my) = (x.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let sxy: f64 = x.iter().zip(&y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = x.iter().map(|a| (a - mx) * (a - mx)).sum();
    sxy / sxx
}

// ---------------------------------------------------------------------------------------------
// Gray–Thornton steady states (model.md 7.2)
// ---------------------------------------------------------------------------------------------

/// Velocity profile of the Gray–Thornton layer (depth 1, depth-averaged speed 1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Profile {
    /// u = (1, 0), direction parallel to gravity.
    Plug,
    /// u = (2 z, 0), direction from the flow.
    Shear,
}

/// What enters at x = 0.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Inflow {
    /// phihat = m at every height.
    Mixed(f64),
    /// Inversely graded: phihat = 1 (small grains) above `z_r`, 0 below.
    Inverse(f64),
}

impl Inflow {
    /// Inflow phihat at height z.
    pub fn phihat(self, z: f64) -> f64 {
        match self {
            Inflow::Mixed(m) => m,
            Inflow::Inverse(zr) => {
                if z > zr {
                    1.0
                } else {
                    0.0
                }
            }
        }
    }
}

/// Volume fraction of the Gray–Thornton layer.
pub const GT_C: f64 = 0.6;

/// A Gray–Thornton layer on `[0, length] x [0, 1]` with `nx x nz` cells: inflow at x = 0,
/// outflow at x = length, walls at z = 0 and z = 1; c = 0.6, T = 1, S0 = 1, gravity (0, -1);
/// initially filled with the inflow state of each height; prepared.
pub fn gray_thornton<const N: usize>(
    profile: Profile,
    inflow: Inflow,
    length: f64,
    nx: usize,
    nz: usize,
    scheme: Scheme,
) -> Box<Segregation<f64, 2, N>> {
    let mut s = boxed::<f64, 2, N>();
    let grid = Grid::new([nx, nz], [0.0, 0.0], [length, 1.0], N).expect("grid");
    let bc: Boundaries<2> = [
        [Boundary::Inflow, Boundary::Outflow],
        [Boundary::Wall, Boundary::Wall],
    ];
    let direction = match profile {
        Profile::Plug => DirectionMode::Gravity,
        Profile::Shear => DirectionMode::Flow,
    };
    s.setup(
        grid,
        bc,
        config(scheme, Phase::Small, [0.0, -1.0], direction),
    )
    .expect("setup");
    for i in 0..grid.len() {
        let [_, z] = grid.center(i);
        let u = match profile {
            Profile::Plug => 1.0,
            Profile::Shear => 2.0 * z,
        };
        s.set_cell(i, GT_C, 1.0, [u, 0.0], GT_C * inflow.phihat(z));
    }
    // The Dirichlet state seen through the x = 0 face (set after set_cell: it uses c).
    grid.for_each_boundary_cell(0, false, |i, _| {
        let z = grid.center(i)[1];
        s.set_inflow(i, GT_C * inflow.phihat(z));
    });
    s.prepare().expect("prepare");
    s
}

/// phihat along column `ix` (bottom to top) of a 2D solver.
pub fn column_profile<const N: usize>(s: &Segregation<f64, 2, N>, ix: usize) -> Vec<f64> {
    let [nx, nz] = s.grid().cells();
    (0..nz)
        .map(|iz| {
            let i = ix + nx * iz;
            s.phi(i) / s.c(i)
        })
        .collect()
}

/// Largest change of phi between two snapshots: the steady-state residual.
pub fn max_change(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// phi of every cell.
pub fn phis<R: Real, const D: usize, const N: usize>(s: &Segregation<R, D, N>) -> Vec<f64> {
    (0..s.len()).map(|i| s.phi(i).to_f64()).collect()
}

/// A deterministic pseudo-random number generator (64-bit LCG): `next` is in [0, 1).
pub struct Lcg(pub u64);
impl Lcg {
    pub fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}
