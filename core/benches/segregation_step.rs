//! Cell updates per second of `Segregation::step` (issue 2, "Benchmarks and performance goal").
//!
//! Run with `cargo bench -p sieve-core --bench segregation_step`; divan prints items/s, one item
//! being one cell updated by one step. Cases:
//! - `step_1d`: 6400 cells, column b of model.md 7.1 (c falling with height, T = 1, u = 0),
//!   f32 and f64, the three face fluxes;
//! - `step_2d`: 256 x 256 shear cell (periodic x, walls z, u = (2z - 1, 0), T = 1, c = 0.64), the
//!   direction from the flow, f32 and f64, the three face fluxes;
//! - `prepare_2d`: `Segregation::prepare_velocity` on the same 256 x 256 shear cell with the
//!   soft sensor's configuration (direction from the flow, T from the shear rate), f32 and f64:
//!   the per-frame cost of deriving T, the segregation direction and the face coefficients;
//! - `baseline_1d`: the reference, a straight-line loop over plain arrays doing the same
//!   per-face arithmetic as the 1D modified step (face velocity, upwind transport, modified
//!   Godunov flux, flux difference) with nothing else: no boundaries, no per-axis dispatch.
//!
//! - `step_1d_vanishing`: 6400 cells of column a (c = 0.64) whose upper 90 % creeps (T = 1e-6,
//!   so its segregation rate is 1e-3 of the lower part's) and holds subnormal phi = 1e-310,
//!   as the shear cell of model.md 7.4 does after hundreds of seconds; with the flush of
//!   docs/model.md 5.6 (`flush_below` = 2^-800, the default) and without (0): the cost of
//!   subnormal arithmetic and what the flush saves. `step_1d_flush` is `step_1d` (modified,
//!   f64, no subnormals) with and without the flush: what the flush costs where it has
//!   nothing to do.
//!
//! The allocation profiler shows that a step allocates nothing.

use divan::counter::ItemsCount;
use divan::{black_box, Bencher};
use sieve_core::segregation::flux;
use sieve_core::{
    Boundary, DirectionMode, Grid, Phase, Real, Scheme, Segregation, SegregationConfig,
    TemperatureMode,
};

#[global_allocator]
static ALLOC: divan::AllocProfiler = divan::AllocProfiler::system();

fn main() {
    divan::main();
}

const N1: usize = 6400;
const SIDE: usize = 256;
const N2: usize = SIDE * SIDE;

/// A zeroed solver on the heap, built on a thread with a large stack: a 256 x 256 f64 solver
/// holds 5 MiB of arrays, more than the main thread's stack may take as a temporary.
fn boxed<R: Real, const D: usize, const N: usize>() -> Box<Segregation<R, D, N>> {
    std::thread::Builder::new()
        .stack_size(512 << 20)
        .spawn(|| Box::new(Segregation::<R, D, N>::zeroed()))
        .expect("spawn")
        .join()
        .expect("join")
}

/// c of column b: 0.64 at z = 0.05 falling linearly to 0.24 at z = 0.95, constant outside.
fn column_b_c(z: f64) -> f64 {
    0.64 - 0.4 * ((z - 0.05) / 0.9).clamp(0.0, 1.0)
}

fn solver_1d<R: Real>(scheme: Scheme) -> Box<Segregation<R, 1, N1>> {
    let mut s = boxed::<R, 1, N1>();
    let grid = Grid::new([N1], [R::ZERO], [R::ONE], N1).unwrap();
    let mut cfg = SegregationConfig::new();
    cfg.scheme = scheme;
    s.setup(grid, [[Boundary::Wall; 2]], cfg).unwrap();
    for i in 0..N1 {
        let c = R::from_f64(column_b_c(grid.center(i)[0].to_f64()));
        s.set_cell(i, c, R::ONE, [R::ZERO], c * R::HALF);
    }
    s.prepare().unwrap();
    s
}

fn solver_2d<R: Real>(scheme: Scheme) -> Box<Segregation<R, 2, N2>> {
    let mut s = boxed::<R, 2, N2>();
    let grid = Grid::new([SIDE, SIDE], [R::ZERO; 2], [R::ONE; 2], N2).unwrap();
    let mut cfg = SegregationConfig::new();
    cfg.scheme = scheme;
    cfg.phase = Phase::Small;
    cfg.direction = DirectionMode::Flow;
    let bc = [[Boundary::Periodic; 2], [Boundary::Wall; 2]];
    s.setup(grid, bc, cfg).unwrap();
    let c = R::from_f64(0.64);
    for i in 0..N2 {
        let z = grid.center(i)[1];
        let u = [R::TWO * z - R::ONE, R::ZERO];
        // Inversely graded: small grains on top, so the step has real work everywhere.
        let phi = if z > R::HALF { c } else { R::ZERO };
        s.set_cell(i, c, R::ONE, u, phi);
    }
    s.prepare().unwrap();
    s
}

#[divan::bench(types = [f32, f64], args = Scheme::ALL)]
fn step_1d<R: Real>(bencher: Bencher, scheme: Scheme) {
    let mut s = solver_1d::<R>(scheme);
    let dt = s.stable_dt();
    bencher
        .counter(ItemsCount::new(N1))
        .bench_local(|| s.step(black_box(dt)));
}

/// Column a with a creeping, subnormal upper part (see the module doc).
fn solver_1d_vanishing(flush_below: f64) -> Box<Segregation<f64, 1, N1>> {
    let mut s = boxed::<f64, 1, N1>();
    let grid = Grid::new([N1], [0.0], [1.0], N1).unwrap();
    let mut cfg = SegregationConfig::new();
    cfg.flush_below = flush_below;
    s.setup(grid, [[Boundary::Wall; 2]], cfg).unwrap();
    for i in 0..N1 {
        let z = grid.center(i)[0];
        let (t, phi) = if z < 0.1 { (1.0, 0.32) } else { (1e-6, 1e-310) };
        s.set_cell(i, 0.64, t, [0.0], phi);
    }
    s.prepare().unwrap();
    s
}

#[divan::bench(args = [2f64.powi(-800), 0.0])]
fn step_1d_vanishing(bencher: Bencher, flush_below: f64) {
    let mut s = solver_1d_vanishing(flush_below);
    let dt = s.stable_dt();
    bencher
        .counter(ItemsCount::new(N1))
        .bench_local(|| s.step(black_box(dt)));
}

#[divan::bench(args = [2f64.powi(-800), 0.0])]
fn step_1d_flush(bencher: Bencher, flush_below: f64) {
    let mut s = solver_1d::<f64>(Scheme::Modified);
    let mut cfg = *s.config();
    cfg.flush_below = flush_below;
    let grid = *s.grid();
    let cells: Vec<_> = (0..N1).map(|i| (s.c(i), s.phi(i))).collect();
    s.setup(grid, [[Boundary::Wall; 2]], cfg).unwrap();
    for (i, (c, phi)) in cells.into_iter().enumerate() {
        s.set_cell(i, c, 1.0, [0.0], phi);
    }
    s.prepare().unwrap();
    let dt = s.stable_dt();
    bencher
        .counter(ItemsCount::new(N1))
        .bench_local(|| s.step(black_box(dt)));
}

#[divan::bench(types = [f32, f64], args = Scheme::ALL)]
fn step_2d<R: Real>(bencher: Bencher, scheme: Scheme) {
    let mut s = solver_2d::<R>(scheme);
    let dt = s.stable_dt();
    bencher
        .counter(ItemsCount::new(N2))
        .bench_local(|| s.step(black_box(dt)));
}

#[divan::bench(types = [f32, f64])]
fn prepare_2d<R: Real>(bencher: Bencher) {
    let mut s = boxed::<R, 2, N2>();
    let grid = Grid::new([SIDE, SIDE], [R::ZERO; 2], [R::ONE; 2], N2).unwrap();
    let mut cfg = SegregationConfig::new();
    cfg.direction = DirectionMode::Flow;
    // Glass beads of model.md 7.4, a = 3/2 (as the soft sensor).
    cfg.temperature = TemperatureMode::FromShear {
        heating: R::from_f64(1.5),
        eta0: R::from_f64(1.3e-4),
        eps0: R::from_f64(1477.15),
    };
    let bc = [[Boundary::Periodic; 2], [Boundary::Wall; 2]];
    s.setup(grid, bc, cfg).unwrap();
    let c = R::from_f64(0.64);
    for i in 0..N2 {
        let [x, z] = grid.center(i);
        // A shear cell with a gentle wobble, so that no gradient component is trivially zero.
        let w = R::from_f64(0.05) * (R::from_f64(std::f64::consts::TAU) * x).sin();
        let u = [R::TWO * z - R::ONE + w, w * z];
        s.set_cell(i, c, R::ZERO, u, c * R::HALF);
    }
    s.prepare().unwrap();
    bencher
        .counter(ItemsCount::new(N2))
        .bench_local(|| black_box(&mut *s).prepare_velocity().unwrap());
}

/// Plain arrays of the 1D problem (column b, u = 0, S = 1 up, small phase: k = 1/c).
struct Arrays<R> {
    q: Vec<R>,
    c: Vec<R>,
    k: Vec<R>,
    u: Vec<R>,
    flux: Vec<R>,
}

impl<R: Real> Arrays<R> {
    fn new() -> Self {
        let h = 1.0 / N1 as f64;
        let c: Vec<R> = (0..N1)
            .map(|i| R::from_f64(column_b_c((i as f64 + 0.5) * h)))
            .collect();
        Self {
            q: c.iter().map(|&c| c * R::HALF).collect(),
            k: c.iter().map(|&c| R::ONE / c).collect(),
            u: vec![R::ZERO; N1],
            flux: vec![R::ZERO; N1 - 1],
            c,
        }
    }

    /// One step: every face flux once, then each cell takes the difference of its two faces.
    #[inline(never)]
    fn step(&mut self, lambda: R) {
        let n = self.q.len();
        let (q, c, k, u) = (&self.q[..n], &self.c[..n], &self.k[..n], &self.u[..n]);
        let flux = &mut self.flux[..n - 1];
        for j in 0..n - 1 {
            let un = (u[j] + u[j + 1]) * R::HALF;
            let f = flux::transport(q[j], q[j + 1], un)
                + flux::modified(q[j], c[j], k[j], q[j + 1], c[j + 1], k[j + 1]);
            flux[j] = f * lambda;
        }
        let q = &mut self.q[..n];
        q[0] -= flux[0];
        for j in 1..n - 1 {
            q[j] += flux[j - 1] - flux[j];
        }
        q[n - 1] += flux[n - 2];
    }
}

#[divan::bench(types = [f32, f64])]
fn baseline_1d<R: Real>(bencher: Bencher) {
    let mut a = Arrays::<R>::new();
    // Courant 0.5 with |S| = 1 and h = 1/6400, as in step_1d.
    let lambda = R::HALF;
    bencher
        .counter(ItemsCount::new(N1))
        .bench_local(|| a.step(black_box(lambda)));
}
