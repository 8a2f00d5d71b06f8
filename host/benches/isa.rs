//! The segregation step at each instruction-set level of the run-time dispatch (issue 12,
//! "Speed on one core first"; host/src/isa.rs, docs/simd.md), beside the plain C loop of
//! core/benches/c/column_a.c, in one run.
//!
//! Cases: the 2D 256 x 256 shear cell of core/benches/segregation_step.rs (`step_2d`, modified
//! flux, f64 and f32; 100 steps per round) and column a of docs/model.md 7.1a (6400 cells,
//! Courant 0.9, to t = 0.5; f64, the uniform fast path and the general five-array loop), each
//! at `baseline` (the binary's own target features) and at every wider level this CPU has.
//! Prints cell updates per second (best of the rounds, round robin so that a passing load
//! hits all alike), the ratio to the baseline, and whether every level ends on the baseline's
//! state hash (it must: same bits).
//!
//! The point is the portable binary:
//! `RUSTFLAGS="-C target-cpu=x86-64" CARGO_TARGET_DIR=target-portable cargo bench -p sieve --bench isa`
//! (the baseline is then SSE2); `cargo bench -p sieve --bench isa` in the default (native) build
//! shows the local CPU's own compile for comparison. The C loop is compiled here with `cc -O3`
//! and `cc -O3 -march=native`, always `-ffp-contract=off` (Rust never contracts).

use sieve::isa::{advance_to_at, step_at, Level};
use sieve_core::{
    state_hash, Boundary, DirectionMode, Grid, Phase, Real, Scheme, Segregation, SegregationConfig,
};
use std::process::Command;
use std::time::Instant;

const SIDE: usize = 256;
const N2: usize = SIDE * SIDE;
const STEPS_2D: u64 = 100;
const CELLS: usize = 6400;
const ROUNDS: usize = 11;

/// A zeroed solver on the heap, built on a thread with a large stack (a 256 x 256 f64 solver
/// is more than the main thread's stack may take as a temporary).
fn boxed<R: Real, const D: usize, const N: usize>() -> Box<Segregation<R, D, N>> {
    std::thread::Builder::new()
        .stack_size(512 << 20)
        .spawn(|| Box::new(Segregation::<R, D, N>::zeroed()))
        .expect("spawn")
        .join()
        .expect("join")
}

/// The shear cell of `step_2d`: periodic x, walls z, u = (2z - 1, 0), c = 0.64, inversely
/// graded.
fn shear_cell<R: Real>(s: &mut Segregation<R, 2, N2>) {
    let grid = Grid::new([SIDE, SIDE], [R::ZERO; 2], [R::ONE; 2], N2).unwrap();
    let mut cfg = SegregationConfig::new();
    cfg.scheme = Scheme::Modified;
    cfg.phase = Phase::Small;
    cfg.direction = DirectionMode::Flow;
    let bc = [[Boundary::Periodic; 2], [Boundary::Wall; 2]];
    s.setup(grid, bc, cfg).unwrap();
    let c = R::from_f64(0.64);
    for i in 0..N2 {
        let z = grid.center(i)[1];
        let u = [R::TWO * z - R::ONE, R::ZERO];
        let phi = if z > R::HALF { c } else { R::ZERO };
        s.set_cell(i, c, R::ONE, u, phi);
    }
    s.prepare().unwrap();
}

/// Column a (the setup of core/benches/column_a_vs_c.rs); `general` forces the five-array loop.
fn column_a(s: &mut Segregation<f64, 1, CELLS>, general: bool) {
    let grid = Grid::new([CELLS], [0.0], [1.0], CELLS).unwrap();
    let mut cfg = SegregationConfig::new();
    cfg.scheme = Scheme::Modified;
    cfg.phase = Phase::Small;
    cfg.courant = 0.9;
    cfg.gravity = [-1.0];
    cfg.direction = DirectionMode::Gravity;
    s.setup(grid, [[Boundary::Wall; 2]], cfg).unwrap();
    for i in 0..CELLS {
        let u = if general && i == CELLS / 3 { -0.0 } else { 0.0 };
        s.set_cell(i, 0.64, 1.0, [u], 0.32);
    }
    s.prepare().unwrap();
    assert_eq!(s.uniform_axes(), [!general]);
}

/// One case at one level: its best time, cell updates and final state hash.
struct Run {
    case: &'static str,
    level: Level,
    updates: f64,
    best: f64,
    hash: u64,
}

impl Run {
    fn rate(&self) -> f64 {
        self.updates / self.best
    }
}

trait Case {
    fn name(&self) -> &'static str;
    /// Sets the case up afresh, runs it at `level`; returns (seconds, cell updates, hash).
    fn once(&mut self, level: Level) -> (f64, f64, u64);
}

struct Shear<R: Real> {
    name: &'static str,
    s: Box<Segregation<R, 2, N2>>,
}

impl<R: Real> Case for Shear<R> {
    fn name(&self) -> &'static str {
        self.name
    }
    fn once(&mut self, level: Level) -> (f64, f64, u64) {
        shear_cell(&mut self.s);
        let dt = self.s.stable_dt();
        let t0 = Instant::now();
        for _ in 0..STEPS_2D {
            step_at(level, &mut self.s, std::hint::black_box(dt));
        }
        let took = t0.elapsed().as_secs_f64();
        (took, (N2 as u64 * STEPS_2D) as f64, state_hash(&*self.s))
    }
}

struct Column {
    name: &'static str,
    general: bool,
    s: Box<Segregation<f64, 1, CELLS>>,
}

impl Case for Column {
    fn name(&self) -> &'static str {
        self.name
    }
    fn once(&mut self, level: Level) -> (f64, f64, u64) {
        column_a(&mut self.s, self.general);
        let t0 = Instant::now();
        let steps = advance_to_at(level, &mut self.s, std::hint::black_box(0.5), u64::MAX);
        let took = t0.elapsed().as_secs_f64();
        (took, (CELLS as u64 * steps) as f64, state_hash(&*self.s))
    }
}

/// The C loop of core/benches/c/column_a.c built with `flags`: its best rate over `ROUNDS`
/// runs, or why it could not run.
fn c_loop(flags: &[&str]) -> Result<f64, String> {
    let src = concat!(env!("CARGO_MANIFEST_DIR"), "/../core/benches/c/column_a.c");
    let exe =
        std::env::temp_dir().join(format!("sieve-isa-c{}-{}", flags.len(), std::process::id()));
    let ok = Command::new("cc")
        .args(["-std=c11", "-ffp-contract=off"])
        .args(flags)
        .arg("-o")
        .arg(&exe)
        .arg(src)
        .arg("-lm")
        .status()
        .map_err(|e| format!("cc: {e}"))?
        .success();
    if !ok {
        return Err(format!("cc failed on {src}"));
    }
    let mut best = f64::INFINITY;
    let mut updates = 0.0;
    for _ in 0..ROUNDS {
        let out = Command::new(&exe)
            .args([CELLS.to_string(), "0.9".into(), "0.5".into(), "1".into()])
            .output()
            .map_err(|e| format!("{}: {e}", exe.display()))?;
        let text = String::from_utf8_lossy(&out.stdout);
        let f: Vec<&str> = text.split_whitespace().collect();
        if f.len() != 5 {
            return Err(format!("unexpected output of the C loop: {text:?}"));
        }
        let steps: f64 = f[1].parse().map_err(|e| format!("{e}"))?;
        updates = steps * CELLS as f64;
        best = best.min(f[2].parse::<f64>().map_err(|e| format!("{e}"))?);
    }
    let _ = std::fs::remove_file(&exe);
    Ok(updates / best)
}

fn main() {
    let levels: Vec<Level> = [Level::Baseline, Level::Avx2, Level::Avx512]
        .into_iter()
        .filter(|l| l.available())
        .collect();
    let mut cases: Vec<Box<dyn Case>> = vec![
        Box::new(Shear::<f64> {
            name: "2D shear 256x256 f64",
            s: boxed(),
        }),
        Box::new(Shear::<f32> {
            name: "2D shear 256x256 f32",
            s: boxed(),
        }),
        Box::new(Column {
            name: "column a f64 (uniform)",
            general: false,
            s: boxed(),
        }),
        Box::new(Column {
            name: "column a f64 (general)",
            general: true,
            s: boxed(),
        }),
    ];
    let mut runs: Vec<Run> = Vec::new();
    for case in &cases {
        for &level in &levels {
            runs.push(Run {
                case: case.name(),
                level,
                updates: 0.0,
                best: f64::INFINITY,
                hash: 0,
            });
        }
    }
    for _ in 0..ROUNDS {
        let mut r = runs.iter_mut();
        for case in cases.iter_mut() {
            for &level in &levels {
                let run = r.next().expect("one run per case and level");
                let (took, updates, hash) = case.once(level);
                run.best = run.best.min(took);
                run.updates = updates;
                run.hash = hash;
            }
        }
    }
    let native = cfg!(target_feature = "avx2");
    println!(
        "sieve segregation step by instruction set; binary compiled for {}; best of {ROUNDS} rounds\n",
        if native {
            "AVX2 or wider (target-cpu=native?)"
        } else {
            "baseline x86-64 (portable)"
        }
    );
    println!(
        "{:<26} {:<9} {:>14} {:>12} {:>10}",
        "case", "level", "cell-upd/s", "x baseline", "same bits"
    );
    for case in &cases {
        let of: Vec<&Run> = runs.iter().filter(|r| r.case == case.name()).collect();
        let base = of[0];
        for r in &of {
            println!(
                "{:<26} {:<9} {:>14.3e} {:>12.2} {:>10}",
                r.case,
                r.level.name(),
                r.rate(),
                r.rate() / base.rate(),
                if r.hash == base.hash { "yes" } else { "NO" }
            );
        }
    }
    println!();
    for flags in [&["-O3"][..], &["-O3", "-march=native"][..]] {
        match c_loop(flags) {
            Ok(rate) => {
                println!("plain C loop, cc {:<16} {rate:>14.3e}", flags.join(" "));
                for r in runs.iter().filter(|r| r.case.starts_with("column a")) {
                    println!(
                        "  {} {}: {:.2}x this C loop",
                        r.case,
                        r.level.name(),
                        r.rate() / rate
                    );
                }
            }
            Err(e) => println!("C loop {} skipped: {e}", flags.join(" ")),
        }
    }
    assert!(
        runs.iter().all(|r| {
            let base = runs.iter().find(|b| b.case == r.case).expect("baseline");
            r.hash == base.hash
        }),
        "a level changed the bits"
    );
}
