//! Work and precision of sieve against the simplest fast alternative, in the same run
//! (issue 12, "Speed on one core first"): segregation column a of docs/model.md 7.1a on 6400
//! cells at Courant 0.9 to t = 0.5, run by `Segregation::advance_to` and by a plain C loop of
//! the same scheme (core/benches/c/column_a.c, compiled here with `cc -O2`, `-O3` (the portable
//! target) and `-O3 -march=native` (the local CPU, which sieve's own build uses:
//! .cargo/config.toml), always `-ffp-contract=off` as Rust never contracts). Prints cell updates per second, the L1 error of phihat against the exact
//! solution and a checksum of the final bits for both, and their ratio. A ratio holds on a
//! noisy machine; an absolute rate does not.
//!
//! Three sieve rows: the step as scenes run it (uniform coefficients detected: q streamed
//! alone), the general five-array loop on the same column (forced by writing one cell's
//! velocity as -0.0, which changes no face velocity), the f32 step, and the f64 step without
//! the flush of vanishing fractions (docs/model.md 5.6), which the C loop does not have: that
//! row's final bits must equal the C loop's.
//!
//! `cargo bench -p sieve-core --bench column_a_vs_c` (needs `cc`; without it the C row is
//! skipped with a note).

use sieve_core::exact::ColumnA;
use sieve_core::{
    Boundary, DirectionMode, Grid, Phase, Real, Scheme, Segregation, SegregationConfig,
};
use std::path::PathBuf;
use std::process::Command;
use std::time::Instant;

const CELLS: usize = 6400;
const COURANT: f64 = 0.9;
const T_END: f64 = 0.5;
const REPEATS: usize = 21;

type Column<R> = Segregation<R, 1, CELLS>;

fn column<R: Real>(s: &mut Column<R>, general: bool, flush: bool) {
    let grid = Grid::new([CELLS], [R::ZERO], [R::ONE], CELLS).unwrap();
    let mut cfg = SegregationConfig::new();
    cfg.scheme = Scheme::Modified;
    cfg.phase = Phase::Small;
    cfg.courant = R::from_f64(COURANT);
    cfg.gravity = [-R::ONE];
    cfg.direction = DirectionMode::Gravity;
    if !flush {
        cfg.flush_below = R::ZERO;
    }
    s.setup(grid, [[Boundary::Wall; 2]], cfg).unwrap();
    let c = R::from_f64(0.64);
    for i in 0..CELLS {
        let u = if general && i == CELLS / 3 {
            -R::ZERO
        } else {
            R::ZERO
        };
        s.set_cell(i, c, R::ONE, [u], c * R::HALF);
    }
    s.prepare().unwrap();
    assert_eq!(s.uniform_axes(), [!general]);
}

struct Row {
    name: String,
    steps: u64,
    seconds: f64,
    l1: f64,
    checksum: u64,
}

impl Row {
    fn rate(&self) -> f64 {
        CELLS as f64 * self.steps as f64 / self.seconds
    }
}

fn l1_and_checksum(q: impl Fn(usize) -> f64) -> (f64, u64) {
    let exact = ColumnA {
        s: 1.0,
        m: 0.5,
        height: 1.0,
    };
    let h = 1.0 / CELLS as f64;
    let (mut l1, mut sum) = (0.0, 0u64);
    for i in 0..CELLS {
        let (z0, z1) = (i as f64 * h, (i + 1) as f64 * h);
        l1 += (q(i) / 0.64 - exact.phihat_cell_average(z0, z1, T_END)).abs() * h;
        sum = sum.wrapping_mul(1099511628211).wrapping_add(q(i).to_bits());
    }
    (l1, sum)
}

/// One contender: runs the whole column once per call, keeps its best time.
trait Contender {
    fn run_once(&mut self) -> Result<(), String>;
    fn row(&self) -> Row;
}

struct Sieve<R: Real> {
    name: &'static str,
    general: bool,
    flush: bool,
    s: Box<Column<R>>,
    steps: u64,
    best: f64,
}

impl<R: Real> Sieve<R> {
    fn new(name: &'static str, general: bool, flush: bool) -> Self {
        Self {
            name,
            general,
            flush,
            s: Box::default(),
            steps: 0,
            best: f64::INFINITY,
        }
    }
}

impl<R: Real> Contender for Sieve<R> {
    fn run_once(&mut self) -> Result<(), String> {
        column(&mut self.s, self.general, self.flush);
        let t0 = Instant::now();
        self.steps = self
            .s
            .advance_to(std::hint::black_box(R::from_f64(T_END)), u64::MAX);
        self.best = self.best.min(t0.elapsed().as_secs_f64());
        Ok(())
    }
    fn row(&self) -> Row {
        let (l1, checksum) = l1_and_checksum(|i| self.s.phi(i).to_f64());
        Row {
            name: self.name.into(),
            steps: self.steps,
            seconds: self.best,
            l1,
            checksum,
        }
    }
}

/// The C loop, compiled once; each call runs the executable for one timed run.
struct CLoop {
    opt: &'static str,
    flags: &'static [&'static str],
    exe: PathBuf,
    last: Option<Row>,
    best: f64,
}

impl CLoop {
    fn build(opt: &'static str, flags: &'static [&'static str]) -> Result<Self, String> {
        let src = concat!(env!("CARGO_MANIFEST_DIR"), "/benches/c/column_a.c");
        let exe = std::env::temp_dir().join(format!(
            "sieve-column-a-c{}{}-{}",
            opt.trim_start_matches('-'),
            flags.len(),
            std::process::id()
        ));
        let cc = Command::new("cc")
            .args([opt, "-std=c11", "-ffp-contract=off"])
            .args(flags)
            .arg("-o")
            .arg(&exe)
            .arg(src)
            .arg("-lm")
            .status()
            .map_err(|e| format!("cc: {e}"))?;
        if !cc.success() {
            return Err(format!("cc failed on {src}"));
        }
        Ok(Self {
            opt,
            flags,
            exe,
            last: None,
            best: f64::INFINITY,
        })
    }
}

impl Drop for CLoop {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.exe);
    }
}

impl Contender for CLoop {
    fn run_once(&mut self) -> Result<(), String> {
        let out = Command::new(&self.exe)
            .args([
                CELLS.to_string(),
                COURANT.to_string(),
                T_END.to_string(),
                "1".into(),
            ])
            .output()
            .map_err(|e| format!("{}: {e}", self.exe.display()))?;
        let text = String::from_utf8_lossy(&out.stdout);
        let f: Vec<&str> = text.split_whitespace().collect();
        if f.len() != 5 {
            return Err(format!("unexpected output of the C loop: {text:?}"));
        }
        let num = |i: usize| f[i].parse::<f64>().map_err(|e| format!("{}: {e}", f[i]));
        self.best = self.best.min(num(2)?);
        self.last = Some(Row {
            name: format!("plain C loop, cc {} {}", self.opt, self.flags.join(" ")),
            steps: f[1].parse().map_err(|e| format!("{e}"))?,
            seconds: self.best,
            l1: num(3)?,
            checksum: f[4].parse().map_err(|e| format!("{e}"))?,
        });
        Ok(())
    }
    fn row(&self) -> Row {
        let r = self.last.as_ref().expect("run_once succeeded");
        Row {
            name: r.name.clone(),
            steps: r.steps,
            seconds: self.best,
            l1: r.l1,
            checksum: r.checksum,
        }
    }
}

fn main() {
    let mut sieve: Vec<Box<dyn Contender>> = vec![
        Box::new(Sieve::<f64>::new(
            "sieve f64 (uniform fast path)",
            false,
            true,
        )),
        Box::new(Sieve::<f64>::new("sieve f64 (general loop)", true, true)),
        Box::new(Sieve::<f32>::new(
            "sieve f32 (uniform fast path)",
            false,
            true,
        )),
        Box::new(Sieve::<f64>::new(
            "sieve f64, subnormal flush off",
            false,
            false,
        )),
    ];
    let mut c: Vec<Box<dyn Contender>> = Vec::new();
    // sieve's own build uses the local CPU (.cargo/config.toml), so the C loop is also built
    // for it; -O2 / -O3 alone are the portable baseline.
    let builds: [(&str, &[&str]); 3] = [("-O2", &[]), ("-O3", &[]), ("-O3", &["-march=native"])];
    for (opt, flags) in builds {
        match CLoop::build(opt, flags) {
            Ok(l) => c.push(Box::new(l)),
            Err(e) => println!("C loop {opt} skipped: {e}"),
        }
    }
    // Round robin: every contender runs once per round, so a load that comes and goes on a
    // shared machine hits all of them alike; each keeps its best round.
    for _ in 0..REPEATS {
        for x in sieve.iter_mut().chain(c.iter_mut()) {
            if let Err(e) = x.run_once() {
                println!("{e}");
                return;
            }
        }
    }
    println!("column a, {CELLS} cells, Courant {COURANT}, t = {T_END}; best of {REPEATS} rounds\n");
    println!(
        "{:<36} {:>6} {:>14} {:>12} {:>22}",
        "", "steps", "cell-updates/s", "L1 error", "checksum of final phi"
    );
    let rows: Vec<Row> = sieve.iter().map(|x| x.row()).collect();
    let c_rows: Vec<Row> = c.iter().map(|x| x.row()).collect();
    for r in rows.iter().chain(&c_rows) {
        println!(
            "{:<36} {:>6} {:>14.3e} {:>12.4e} {:>22}",
            r.name,
            r.steps,
            r.rate(),
            r.l1,
            r.checksum
        );
    }
    let Some(fastest) = c_rows.iter().max_by(|a, b| a.rate().total_cmp(&b.rate())) else {
        return;
    };
    println!();
    for r in &rows {
        println!(
            "{}: {:.2}x the rate of the faster C loop ({})",
            r.name,
            r.rate() / fastest.rate(),
            fastest.name
        );
    }
    // The C loop has no flush of vanishing fractions (docs/model.md 5.6); without it sieve
    // does the C loop's arithmetic exactly.
    let same = rows[3].checksum == fastest.checksum;
    println!(
        "f64 final state without the flush {} the C loop's bit for bit",
        if same { "equals" } else { "differs from" }
    );
}
