//! What a fork of the coupled flow's loops costs and where it pays (issue 12; core/src/fork.rs,
//! host/src/pool.rs, docs/parallel.md "The coupled flow on threads"), in one run:
//!
//! - the fork and join of an empty loop on the pool (2 parts), from a pool worker as in a run;
//! - the operator product (`Stencil::apply_on`) and the CG update with its sum
//!   (`fork::update`) of a 2D 5-point system on square grids of 4,096 to 262,144 cells,
//!   serial and cut into 2 parts on the pool: time per pass (best of the rounds) and the
//!   speed-up, and whether the outputs have the same bits (they must).
//!
//! `cargo bench -p sieve --bench fork`. The crossover is where `fork::MIN_PER_PART` belongs.

use sieve::pool::Pool;
use sieve_core::flow::cg::Stencil;
use sieve_core::fork::{self, Fork, Serial};
use sieve_core::Grid;
use std::time::Instant;

const N: usize = 512 * 512;
const ROUNDS: usize = 9;

fn lcg(s: &mut u64) -> f64 {
    *s = s
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    (*s >> 11) as f64 / (1u64 << 53) as f64
}

/// Best time per call of `f` over the rounds, `reps` calls a round, in microseconds.
fn best(reps: usize, mut f: impl FnMut()) -> f64 {
    let mut b = f64::MAX;
    for _ in 0..ROUNDS {
        let t = Instant::now();
        for _ in 0..reps {
            f();
        }
        b = b.min(t.elapsed().as_secs_f64() * 1e6 / reps as f64);
    }
    b
}

fn main() {
    let pool = Pool::new(2).expect("threads").cutting_down_to(1);
    let empty = pool.install(|| {
        let mut items = [0u64; 2];
        best(20_000, || {
            fork::chunks(&pool, &mut items, 1, |_, c| c[0] += 1);
        })
    });
    println!("fork and join of an empty 2-part loop on the pool: {empty:.2} us");
    // The same fork after the caller worked alone for a while (a flow stage between two
    // solves): the idle worker may have gone to sleep, and the fork then waits for its wake-up.
    for gap_us in [10u64, 50, 200, 1000] {
        let gap = std::time::Duration::from_micros(gap_us);
        let mut worst = 0.0f64;
        let mut total = 0.0;
        let reps = (2_000_000 / (gap_us as usize + 20)).min(5000);
        pool.install(|| {
            let mut items = [0u64; 2];
            for _ in 0..reps {
                let t = Instant::now();
                while t.elapsed() < gap {
                    std::hint::spin_loop();
                }
                let t = Instant::now();
                fork::chunks(&pool, &mut items, 1, |_, c| c[0] += 1);
                let dt = t.elapsed().as_secs_f64() * 1e6;
                worst = worst.max(dt);
                total += dt;
            }
        });
        println!(
            "  after {gap_us} us of serial work: {:.2} us mean, {worst:.0} us worst",
            total / reps as f64
        );
    }
    let mut kf = vec![[0.0f64; N]; 2];
    let mut s = 7;
    for k in kf.iter_mut() {
        for v in k.iter_mut() {
            *v = 1.0 + lcg(&mut s);
        }
    }
    let kf: Box<[[f64; N]; 2]> = kf.into_boxed_slice().try_into().expect("two axes");
    let diag: Vec<f64> = (0..N).map(|_| 4.0 + lcg(&mut s)).collect();
    let x: Vec<f64> = (0..N).map(|_| lcg(&mut s) - 0.5).collect();
    println!("| cells | product serial [us] | 2 parts | speed-up | update serial [us] | 2 parts | speed-up | same bits |");
    println!("|---|---|---|---|---|---|---|---|");
    for side in [64usize, 128, 256, 512] {
        let grid = Grid::new([side, side], [0.0; 2], [1.0; 2], N).expect("grid");
        let n = grid.len();
        let st = Stencil {
            grid: &grid,
            periodic: [false; 2],
            kf: &kf,
        };
        let reps = (4_000_000 / n).max(4);
        let (p1, l1, a1, z1) = time(&Serial, &st, &diag, &x, reps);
        let (p2, l2, a2, z2) = pool.install(|| time(&pool, &st, &diag, &x, reps));
        let same = a1
            .iter()
            .chain(&z1)
            .zip(a2.iter().chain(&z2))
            .all(|(u, v)| u.to_bits() == v.to_bits());
        println!(
            "| {side} x {side} | {p1:.1} | {p2:.1} | {:.2}x | {l1:.1} | {l2:.1} | {:.2}x | {same} |",
            p1 / p2,
            l1 / l2
        );
    }
}

/// Best times per pass [us] of the product and of the CG update on `fork`, and their outputs.
fn time<F: Fork>(
    fork: &F,
    st: &Stencil<'_, f64, 2, N>,
    diag: &[f64],
    x: &[f64],
    reps: usize,
) -> (f64, f64, Vec<f64>, Vec<f64>) {
    let n = st.grid.len();
    let (mut a, mut z, mut part) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    let tp = best(reps, || st.apply_on(fork, diag, x, &mut a));
    // x += alpha p, r -= alpha q from the same start on every fork (a few thousand passes of
    // 1e-9: the values stay finite and normal)
    let mut r = x[..n].to_vec();
    let tu = best(reps, || {
        std::hint::black_box(fork::update(
            fork,
            1e-9,
            &x[..n],
            &diag[..n],
            &mut z,
            &mut r,
            &mut part,
        ));
    });
    (tp, tu, a, z)
}
