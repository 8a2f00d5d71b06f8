//! Costs of the domain decomposition on a 2D 512 x 512 shear layer (docs/parallel.md):
//! `cargo run --release -p sieve --example decomp_bench [STEPS]`.
//!
//! Prints, per step, the serial step, the threaded driver with 1, 2 (and 3) threads, and the
//! parts a threaded step adds (halo pack + unpack, the owned-cell bound maxima and flush
//! pass, the copy in and out per chunk), plus the diagnostics: the serial cell-order sums
//! against the row-blocked sums that fold to the same bits for any split. Each figure is
//! the best of 5 repeats (the machine is shared; the best is the least disturbed).

use sieve::parallel::Driver;
use sieve_core::decomp::{self, RowSums, Side, Subdomain};
use sieve_core::segregation::SegregationConfig;
use sieve_core::{Boundary, DirectionMode, Grid, Segregation, TemperatureMode};
use std::time::Instant;

const N: usize = 512 * 512;
type S = Segregation<f64, 2, N>;

fn best(repeats: usize, mut f: impl FnMut()) -> f64 {
    (0..repeats)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .fold(f64::MAX, f64::min)
}

/// CPU seconds of the whole process so far (user + system, all threads; /proc/self/stat).
fn cpu() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let after = stat.rsplit(')').next().unwrap_or("");
    let f: Vec<f64> = after
        .split_whitespace()
        .map(|x| x.parse().unwrap_or(0.0))
        .collect();
    // fields 14 and 15 of the file (utime, stime) are 12 and 13 after the name
    (f.get(11).copied().unwrap_or(0.0) + f.get(12).copied().unwrap_or(0.0)) / 100.0
}

fn build(s: &mut S) {
    let mut cfg = SegregationConfig::new();
    cfg.gravity = [0.0, -9.81];
    cfg.direction = DirectionMode::Flow;
    cfg.temperature = TemperatureMode::FromShear {
        heating: 1.5,
        eta0: 1e-3,
        eps0: 10.0,
    };
    let g = Grid::new([512, 512], [0.0; 2], [0.025, 0.025], N).unwrap();
    s.setup(g, [[Boundary::Periodic; 2], [Boundary::Wall; 2]], cfg)
        .unwrap();
    for i in 0..g.len() {
        let [_, y] = g.center(i);
        let phi = if y > 0.0125 { 0.6 } else { 0.0 };
        s.set_cell(i, 0.6, 0.0, [0.2 * y / 0.025, 0.0], phi);
    }
    s.prepare().unwrap();
}

fn main() {
    let steps: u64 = std::env::args()
        .nth(1)
        .map_or(60, |a| a.parse().expect("STEPS"));
    let stack = std::mem::size_of::<S>() * 6 + (64 << 20);
    std::thread::Builder::new()
        .stack_size(stack)
        .spawn(move || bench(steps))
        .unwrap()
        .join()
        .unwrap();
}

fn bench(steps: u64) {
    let mut global = S::zeroed();
    build(&mut global);
    let cells = global.len() as f64;
    let dt = global.stable_dt();
    let mut s = global.clone();
    let c0 = cpu();
    let serial = best(5, || {
        s.advance_to(s.time() + dt * steps as f64, steps);
    }) / steps as f64;
    let serial_cpu = (cpu() - c0) / (5 * steps) as f64;
    println!("512 x 512, {steps} steps per repeat, best of 5, per step:");
    println!(
        "serial step                {:8.1} us  {:.3e} cell updates/s  (CPU {:.1} us)",
        serial * 1e6,
        cells / serial,
        serial_cpu * 1e6
    );
    for threads in [1, 2, 3] {
        let mut s = global.clone();
        let d = Driver::new(&s, None, threads).unwrap();
        // chunks as the run loop takes them: 4e6 / cells steps per call
        let chunk = (4_000_000 / N).max(1) as u64;
        let c0 = cpu();
        let t = best(5, || {
            let mut left = steps;
            while left > 0 {
                let n = left.min(chunk);
                let target = s.time() + dt * n as f64;
                d.advance(&mut s, target, n);
                left -= n;
            }
        }) / steps as f64;
        let work = (cpu() - c0) / (5 * steps) as f64;
        println!(
            "driver, {threads} thread(s)        {:8.1} us  {:.3e} cell updates/s  speed-up {:.2}  efficiency {:.2}  (CPU {:.1} us, {:.2} of serial)",
            t * 1e6,
            cells / t,
            serial / t,
            serial / t / threads as f64,
            work * 1e6,
            work / serial_cpu
        );
    }
    // the parts of a threaded step, on subdomain 0 of 2 (its high side is a cut)
    let halo = decomp::halo_width(&global);
    let sub = Subdomain::new(global.grid(), global.boundaries(), 2, 0, halo).unwrap();
    let mut local = Box::new(S::zeroed());
    decomp::load_subdomain(&global, &sub, &mut local).unwrap();
    let mut buf = vec![0.0; sub.message_len(Side::High, 1)];
    let reps = 2000;
    let pack = best(5, || {
        for _ in 0..reps {
            decomp::pack(&local, &sub, Side::High, &["q"], &mut buf);
            decomp::unpack(&mut local, &sub, Side::High, &["q"], &buf);
        }
    }) / reps as f64;
    println!(
        "halo pack + unpack, {} rows of 512 (one side) {:6.2} us",
        halo,
        pack * 1e6
    );
    let mut excess = [0.0; 2];
    let mut k = 1;
    let end = best(5, || {
        for _ in 0..100 {
            local.end_owned_step(f64::MIN_POSITIVE, k, &mut excess, |_, _| {});
            k += 1;
        }
    }) / 100.0;
    println!(
        "owned-cell end of step (the flush every 8th; the maxima are the step's), 256 rows {:6.1} us",
        end * 1e6
    );
    let copy = best(5, || {
        decomp::copy_rows(&global, &sub, &mut local, &["q"]);
    });
    println!("copy q in, one subdomain (per chunk) {:6.1} us", copy * 1e6);
    let mut g2 = global.clone();
    let gather = best(5, || {
        decomp::gather_rows(&local, &sub, &mut g2, &["q"]);
    });
    println!(
        "copy q out, one subdomain (per chunk) {:6.1} us",
        gather * 1e6
    );
    // diagnostics: serial sums against row sums
    let mut sink = 0.0;
    let diag = best(5, || {
        for _ in 0..10 {
            sink += sieve_core::diagnose(&global).psi;
        }
    }) / 10.0;
    let rows = best(5, || {
        for _ in 0..10 {
            let mut t = RowSums::ZERO;
            RowSums::of_rows(&global, 0..512, 512, |r| t.add(r));
            sink += t.psi();
        }
    }) / 10.0;
    println!(
        "diagnostics: serial cell-order {:7.1} us, row-blocked (split-independent) {:7.1} us  ({sink:.3})",
        diag * 1e6,
        rows * 1e6
    );
}
