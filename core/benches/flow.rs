//! Cost of the flow model on the shear cell of model.md 7.4 at 80 x 80 (issue 3, Performance).
//!
//! Run with `cargo bench -p sieve-core --bench flow`. Cases:
//! - `flow_step_80`: one `Flow::step` (transport, pressure, 2 implicit velocity solves, implicit
//!   temperature solve) from a state 400 steps into the spin-up, f64 and f32;
//! - `frozen_segregation_step_80`: one segregation step on the frozen flow (what 700 s of
//!   re-segregation costs per step once the flow is frozen), f64.
//!
//! The projection to 700 s (steps to steady state x flow step + 700 s / segregation dt x
//! segregation step) is printed by `shear_cell_projection` in the report of issue 3; the
//! allocation profiler shows that neither step allocates.

use divan::Bencher;
use sieve_core::closure::Material;
use sieve_core::flow::{Flow, FlowConfig, FlowSide};
use sieve_core::{Boundary, DirectionMode, Grid, Real, Segregation, SegregationConfig};

#[global_allocator]
static ALLOC: divan::AllocProfiler = divan::AllocProfiler::system();

fn main() {
    divan::main();
}

const SIDE: usize = 80;
const N: usize = SIDE * SIDE;

/// Runs `f` on a thread with a large stack (the solvers are built by value before boxing).
fn big<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> T {
    std::thread::Builder::new()
        .stack_size(512 << 20)
        .spawn(f)
        .expect("spawn")
        .join()
        .expect("join")
}

/// The 80 x 80 shear cell, `warm` steps into its spin-up from rest.
fn shear_cell<R: Real>(warm: usize) -> Box<Flow<R, 2, N>> {
    big(move || {
        let mut flow = Box::new(Flow::<R, 2, N>::zeroed());
        let l = R::from_f64(0.025);
        let grid = Grid::new([SIDE, SIDE], [R::ZERO; 2], [l, l], N).expect("grid");
        let bottom = FlowSide::moving_wall([R::from_f64(0.0007), R::ZERO]);
        let top = FlowSide::moving_wall([R::from_f64(0.0055), R::ZERO]);
        let px = FlowSide::periodic();
        flow.setup(
            grid,
            [[px, px], [bottom, top]],
            FlowConfig::new(Material::glass_beads()),
        )
        .expect("setup");
        for i in 0..N {
            flow.set_cell(i, R::from_f64(0.6), [R::ZERO; 2], R::ZERO);
        }
        flow.prepare().expect("prepare");
        for _ in 0..warm {
            flow.step(flow.stable_dt());
        }
        flow
    })
}

#[divan::bench(types = [f64, f32], sample_count = 20, sample_size = 5)]
fn flow_step_80<R: Real>(bencher: Bencher) {
    let mut flow = shear_cell::<R>(400);
    let dt = flow.stable_dt();
    bencher.bench_local(|| flow.step(dt));
}

#[divan::bench(sample_count = 20, sample_size = 50)]
fn frozen_segregation_step_80(bencher: Bencher) {
    let flow = shear_cell::<f64>(400);
    let mut seg = big(|| Box::new(Segregation::<f64, 2, N>::zeroed()));
    let mut cfg = SegregationConfig::new();
    cfg.gravity = [0.0, -9.81];
    cfg.direction = DirectionMode::Flow;
    let bc = [[Boundary::Periodic; 2], [Boundary::Wall; 2]];
    seg.setup(*flow.grid(), bc, cfg).expect("setup");
    for i in 0..N {
        let c = flow.c(i);
        let z = flow.grid().coords(i)[1];
        seg.set_cell(
            i,
            c,
            flow.temperature(i),
            flow.velocity(i),
            if z >= SIDE / 2 { c } else { 0.0 },
        );
    }
    seg.prepare().expect("prepare");
    let dt = seg.stable_dt();
    bencher.bench_local(|| seg.step(dt));
}
