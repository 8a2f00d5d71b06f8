//! Cost of the flow model: the shear cell of model.md 7.4 at 80 x 80 (issue 3, Performance)
//! and the column collapse on 1 mm cells, 160 x 32 (issue 8, Speed).
//!
//! `cargo bench -p sieve-core --bench flow` runs the divan benchmarks:
//! - `flow_step_80`: one `Flow::step` (transport, pressure, 2 implicit velocity solves, implicit
//!   temperature solve) from a state 400 steps into the shear-cell spin-up, f64 and f32;
//! - `collapse_step_160x32`: one step of the column collapse 0.02 s after release (the block
//!   is spreading: the stiff, long horizontal systems of issue 8), f64;
//! - `frozen_segregation_step_80`: one segregation step on the frozen flow (what 700 s of
//!   re-segregation costs per step once the flow is frozen), f64.
//!
//! `FLOW_REPORT=1 [FLOW_T=0.03] cargo bench -p sieve-core --bench flow` instead prints, for the
//! collapse (to `FLOW_T`) and the first 0.002 s of the 80 x 80 shear-cell spin-up: steps, CG
//! iterations per step and per system, CPU time per step and per simulated second (this
//! thread's, from /proc: the machine is shared), and the time-step limits (the acoustic
//! Courant step taken against the advective step an implicit pressure would allow).
//!
//! The allocation profiler shows that no step allocates.

use std::time::Instant;

use divan::Bencher;
use sieve_core::closure::{self, Material};
use sieve_core::flow::{Flow, FlowConfig, FlowSide, Slip};
use sieve_core::{Boundary, DirectionMode, Grid, Real, Segregation, SegregationConfig};

#[global_allocator]
static ALLOC: divan::AllocProfiler = divan::AllocProfiler::system();

fn main() {
    if std::env::var_os("FLOW_REPORT").is_some() {
        report();
    } else {
        divan::main();
    }
}

const SIDE: usize = 80;
const N: usize = SIDE * SIDE;
const NC: usize = 160 * 32;

/// Runs `f` on a thread with a large stack (the solvers are built by value before boxing).
fn big<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> T {
    std::thread::Builder::new()
        .stack_size(512 << 20)
        .spawn(f)
        .expect("spawn")
        .join()
        .expect("join")
}

/// The `cells` shear cell (0.025 m square, x-periodic), `warm` steps into its spin-up from rest.
fn shear_cell<R: Real, const M: usize>(cells: [usize; 2], warm: usize) -> Box<Flow<R, 2, M>> {
    big(move || {
        let mut flow = Box::new(Flow::<R, 2, M>::zeroed());
        let l = R::from_f64(0.025);
        let grid = Grid::new(cells, [R::ZERO; 2], [l, l], M).expect("grid");
        let bottom = FlowSide::moving_wall([R::from_f64(0.0007), R::ZERO]);
        let top = FlowSide::moving_wall([R::from_f64(0.0055), R::ZERO]);
        let px = FlowSide::periodic();
        flow.setup(
            grid,
            [[px, px], [bottom, top]],
            FlowConfig::new(Material::glass_beads()),
        )
        .expect("setup");
        for i in 0..grid.len() {
            flow.set_cell(i, R::from_f64(0.6), [R::ZERO; 2], R::ZERO);
        }
        flow.prepare().expect("prepare");
        for _ in 0..warm {
            flow.step(flow.stable_dt());
        }
        flow
    })
}

/// The column collapse of `scenes/column-collapse.toml` on 1 mm cells (flow only): a block
/// a = H = 0.02 m at c = 0.6 against the left wall of a 0.16 x 0.032 m box, friction walls of
/// 30 deg, free-surface push; advanced to `t0`.
fn collapse(t0: f64) -> Box<Flow<f64, 2, NC>> {
    big(move || {
        let mut flow = Box::new(Flow::<f64, 2, NC>::zeroed());
        let grid = Grid::new([160, 32], [0.0; 2], [0.16, 0.032], NC).expect("grid");
        let mut cfg = FlowConfig::new(Material::glass_beads());
        cfg.free_surface_push = true;
        let wall = FlowSide::wall(Slip::Friction(30f64.to_radians().tan()));
        flow.setup(grid, [[wall, wall], [wall, wall]], cfg)
            .expect("setup");
        for i in 0..grid.len() {
            let [x, z] = grid.center(i);
            let c = if x < 0.02 && z < 0.02 { 0.6 } else { 1e-9 };
            flow.set_cell(i, c, [0.0; 2], 0.0);
        }
        flow.prepare().expect("prepare");
        flow.advance_to(t0, u64::MAX);
        flow
    })
}

#[divan::bench(types = [f64, f32], sample_count = 20, sample_size = 5)]
fn flow_step_80<R: Real>(bencher: Bencher) {
    let mut flow = shear_cell::<R, N>([SIDE, SIDE], 400);
    let dt = flow.stable_dt();
    bencher.bench_local(|| flow.step(dt));
}

#[divan::bench(sample_count = 20, sample_size = 5)]
fn collapse_step_160x32(bencher: Bencher) {
    let mut flow = collapse(0.02);
    let dt = flow.stable_dt();
    bencher.bench_local(|| flow.step(dt));
}

#[divan::bench(sample_count = 20, sample_size = 50)]
fn frozen_segregation_step_80(bencher: Bencher) {
    let flow = shear_cell::<f64, N>([SIDE, SIDE], 400);
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

/// Steps, per-system iterations and seconds of a flow advanced by `advance`.
struct Tally {
    steps: u64,
    iterations: [u64; 4],
    seconds: f64,
    simulated: f64,
    /// Sums of the taken step and of the advective step `C / max sum (|u_a| / h_a + sqrt(g/h))`.
    dt_sum: f64,
    dt_adv_sum: f64,
}

fn run<const M: usize>(flow: &mut Flow<f64, 2, M>, t_end: f64) -> Tally {
    let mut t = Tally {
        steps: 0,
        iterations: [0; 4],
        seconds: 0.0,
        simulated: 0.0,
        dt_sum: 0.0,
        dt_adv_sum: 0.0,
    };
    let t0 = flow.time();
    let h = flow.grid().spacing();
    let courant = flow.config().courant;
    let g = flow.config().gravity;
    while flow.time() < t_end {
        let dt = flow.stable_dt().min(t_end - flow.time());
        let mut rate: f64 = 0.0;
        for i in 0..flow.len() {
            let u = flow.velocity(i);
            let r: f64 = (0..2)
                .map(|a| u[a].abs() / h[a] + (g[a].abs() / h[a]).sqrt())
                .sum();
            rate = rate.max(r);
        }
        let start = cpu_ns();
        flow.step(dt);
        t.seconds += (cpu_ns() - start) as f64 * 1e-9;
        t.steps += 1;
        t.dt_sum += dt;
        t.dt_adv_sum += courant / rate;
        for (s, k) in t.iterations.iter_mut().zip(flow.last_cg_iterations()) {
            *s += u64::from(k);
        }
    }
    t.simulated = flow.time() - t0;
    t
}

/// CPU time of this thread in ns (the machine is shared: wall time would count the others).
fn cpu_ns() -> u64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse().ok())
        .unwrap_or_else(|| Instant::now().elapsed().as_nanos() as u64)
}

fn print(name: &str, t: &Tally) {
    let s = t.steps as f64;
    println!(
        "{name}: {} steps, CG/step {:.1} (u_x {:.1}, u_z {:.1}, T {:.1}), {:.3} s CPU, \
         {:.1} s per simulated s, {:.0} us/step; mean dt {:.2e} s, advective dt {:.2e} s ({:.1}x)",
        t.steps,
        t.iterations.iter().sum::<u64>() as f64 / s,
        t.iterations[0] as f64 / s,
        t.iterations[1] as f64 / s,
        t.iterations[3] as f64 / s,
        t.seconds,
        t.seconds / t.simulated,
        1e6 * t.seconds / s,
        t.dt_sum / s,
        t.dt_adv_sum / s,
        t.dt_adv_sum / t.dt_sum,
    );
}

fn report() {
    let t_end: f64 = std::env::var("FLOW_T")
        .map(|s| s.parse().expect("FLOW_T"))
        .unwrap_or(0.03);
    let mut flow = collapse(0.0);
    let t = big(move || {
        let t = run(&mut flow, t_end);
        let d = flow.diagnostics();
        println!(
            "  collapse state: KE {:.6e}, mass {:.15e}",
            d.kinetic_energy, d.mass
        );
        t
    });
    print(&format!("collapse 160x32 to {t_end} s"), &t);
    let mut flow = shear_cell::<f64, N>([SIDE, SIDE], 0);
    let t = big(move || run(&mut flow, 0.002));
    print("shear cell 80x80 spin-up to 0.002 s", &t);
    let m = Material::<f64>::glass_beads();
    let a2 = closure::sound_speed_squared(&m, 0.6, 0.0, m.phi_rcp, m.phi_rlp);
    println!("sound speed at c = 0.6, T = 0: {:.2} m/s", a2.sqrt());
}
