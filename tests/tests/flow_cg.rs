//! The implicit solver of the flow (core/src/flow/cg.rs) and the blocked sums it uses
//! (core/src/sum.rs).
//!
//! Solver: conjugate gradients preconditioned by exact solves along the vertical grid lines,
//! switching to an aggregation multigrid V-cycle when the lines converge slowly. In 1D the
//! line preconditioner is the inverse of A, so CG must stop after one iteration; in 2D and 3D
//! (periodic and not) every preconditioner must solve A x = b to the requested residual for
//! strongly anisotropic, widely varying coefficients (the yield viscosity of a cold bed spans
//! many orders of magnitude), with closed faces and decoupled cells (embedded walls), and the
//! V-cycle must take out the long-range horizontal coupling the lines leave.
//!
//! Sums: the blocked sum must equal a compensated (double-double) reference within the
//! bound of recursive summation for its tree, and must give the same bits when the array is
//! split into chunks at block boundaries (what a threaded driver does).

use crate::common::thread_links::ThreadLinks;
use proptest::prelude::*;
use sieve::isa::Level;
use sieve::pool::Pool;
use sieve_core::flow::cg::{solve_on, workspace_len, Preconditioner, Scratch, Stencil, Stop};
use sieve_core::flow::cycle_slab::{Fine, Plan};
use sieve_core::fork::{Fork, Serial};
use sieve_core::sum;
use sieve_core::{Grid, Real};

const N: usize = 4096;

/// A deterministic pseudo-random sequence in [0, 1).
fn lcg(seed: &mut u64) -> f64 {
    *seed = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    (*seed >> 11) as f64 / (1u64 << 53) as f64
}

/// A linear system `diag + faces` on a grid.
struct System<const D: usize> {
    grid: Grid<f64, D>,
    periodic: [bool; D],
    kf: Box<[[f64; N]; D]>,
    diag: Vec<f64>,
    b: Vec<f64>,
}

/// What a solve did: iterations, the recursive residual, the true `|A x - b| / |b|`
/// (recomputed independently; it sits above the recursive one by the round-off of the
/// recursion, which grows with the condition number), and the solution.
struct Outcome {
    iterations: u32,
    recursive: f64,
    residual: f64,
    x: Vec<f64>,
}

impl<const D: usize> System<D> {
    fn solve(&self, pc: Preconditioner, room: usize) -> Outcome {
        self.solve_on(&Serial, pc, room, 3000)
    }

    fn solve_on<F: Fork>(&self, fork: &F, pc: Preconditioner, room: usize, max: u32) -> Outcome {
        let st = Stencil {
            grid: &self.grid,
            periodic: self.periodic,
            kf: &self.kf,
        };
        let n = self.grid.len();
        let mut x = vec![0.0; N];
        let mut v = vec![vec![0.0; N]; 7];
        let mut coarse = vec![0.0; room];
        let [r, p, ap, pre, line, tmp, part] = &mut v[..] else {
            unreachable!()
        };
        let res = solve_on(
            fork,
            &st,
            &self.diag,
            &self.b,
            &mut x,
            Scratch {
                r,
                p,
                ap,
                pre,
                line,
                tmp,
                coarse: &mut coarse,
                part,
            },
            Stop {
                relative: 1e-10,
                floor: 0.0,
                max_iterations: max,
                preconditioner: pc,
            },
        );
        let mut ax = vec![0.0; N];
        st.apply(&self.diag, &x, &mut ax);
        let (mut rr, mut bb) = (0.0, 0.0);
        for i in 0..n {
            rr += (ax[i] - self.b[i]).powi(2);
            bb += self.b[i] * self.b[i];
        }
        Outcome {
            iterations: res.iterations,
            recursive: res.relative_residual,
            residual: (rr / bb).sqrt(),
            x,
        }
    }

    fn full(&self, pc: Preconditioner) -> Outcome {
        self.solve(pc, workspace_len(self.grid.cells()))
    }
}

/// Random coefficients: 10 decades, 1000 times stronger along the last axis.
fn random_system<const D: usize>(cells: [usize; D], periodic: [bool; D], seed: u64) -> System<D> {
    let grid = Grid::new(cells, [0.0; D], [1.0; D], N).unwrap();
    let n = grid.len();
    let mut s = seed;
    let mut kf = Box::new([[0.0f64; N]; D]);
    for (a, k) in kf.iter_mut().enumerate() {
        for v in k[..n].iter_mut() {
            let scale = if a + 1 == D { 1e3 } else { 1.0 };
            *v = scale * 10f64.powf(10.0 * lcg(&mut s) - 5.0);
        }
    }
    let diag = (0..N).map(|_| 1e-3 + lcg(&mut s)).collect();
    let b = (0..N).map(|_| lcg(&mut s) - 0.5).collect();
    System {
        grid,
        periodic,
        kf,
        diag,
        b,
    }
}

/// A spread-out cold bed: a layer `nx x nz` whose yield viscosity couples it horizontally
/// and vertically (`k` ~ 1e4 x the mass term, growing with depth), the vertical velocity
/// of a collapse front. The lines take out the vertical coupling only.
fn layer(nx: usize, nz: usize, periodic: bool, seed: u64) -> System<2> {
    let grid = Grid::new([nx, nz], [0.0; 2], [1.0; 2], N).unwrap();
    let mut s = seed;
    let mut kf = Box::new([[0.0f64; N]; 2]);
    let mut diag = vec![0.0; N];
    let mut b = vec![0.0; N];
    for i in 0..grid.len() {
        let depth = (nz - grid.coords(i)[1]) as f64;
        for a in 0..2 {
            kf[a][i] = 1e4 * depth * (0.5 + lcg(&mut s));
        }
        diag[i] = 0.5 + lcg(&mut s);
        b[i] = lcg(&mut s) - 0.5;
    }
    System {
        grid,
        periodic: [periodic, false],
        kf,
        diag,
        b,
    }
}

/// The fused product (one pass per line, core/src/flow/cg.rs `Stencil::product`) gives the
/// same bits as the face-by-face passes it replaced, for `A x` and `b - A x`, on 1D, 2D and
/// 3D grids with every combination of periodic axes, lines of 1, 2, 3 and more cells, and
/// signed zeros in `x` (a fused pass that skipped a term by adding 0 would flip `-0`).
#[test]
fn fused_product_has_the_face_by_face_bits() {
    fn check<const D: usize>(cells: [usize; D], periodic: [bool; D], seed: u64) {
        let mut sys = random_system(cells, periodic, seed);
        let mut s = seed ^ 0x9e37;
        let mut x: Vec<f64> = (0..N).map(|_| lcg(&mut s) - 0.5).collect();
        for (i, v) in x.iter_mut().enumerate().take(sys.grid.len()) {
            if i % 7 == 3 {
                *v = -0.0;
            }
        }
        // some closed faces and some zero diagonal entries
        for i in (0..sys.grid.len()).step_by(5) {
            sys.kf[0][i] = 0.0;
            sys.diag[i] = 0.0;
        }
        let st = Stencil {
            grid: &sys.grid,
            periodic: sys.periodic,
            kf: &sys.kf,
        };
        let n = sys.grid.len();
        let (mut fused, mut faces) = (vec![0.0; N], vec![0.0; N]);
        st.apply(&sys.diag, &x, &mut fused);
        st.product_by_faces(&sys.diag, &x, &x, &mut faces, false);
        for i in 0..n {
            assert_eq!(
                fused[i].to_bits(),
                faces[i].to_bits(),
                "A x, {cells:?} {periodic:?} cell {i}"
            );
        }
        st.residual(&sys.diag, &sys.b, &x, &mut fused);
        st.product_by_faces(&sys.diag, &sys.b, &x, &mut faces, true);
        for i in 0..n {
            assert_eq!(
                fused[i].to_bits(),
                faces[i].to_bits(),
                "b - A x, {cells:?} {periodic:?} cell {i}"
            );
        }
    }
    for n0 in [1, 2, 3, 17] {
        for p0 in [false, true] {
            check([n0], [p0], 1);
            for p1 in [false, true] {
                check([n0, 9], [p0, p1], 2);
                check([n0, 2], [p0, p1], 3);
                check([n0, 1], [p0, p1], 4);
                for p2 in [false, true] {
                    check([n0, 5, 6], [p0, p1, p2], 5);
                    check([n0, 2, 1], [p0, p1, p2], 6);
                    check([n0, 1, 3], [p0, p1, p2], 7);
                }
            }
        }
    }
}

/// The same iterations, residual and solution bits as `serial` (`at` names the case).
fn assert_same_solve(t: &Outcome, serial: &Outcome, at: &str) {
    assert_eq!(t.iterations, serial.iterations, "{at}");
    assert_eq!(t.recursive.to_bits(), serial.recursive.to_bits(), "{at}");
    let first = (0..t.x.len()).find(|&i| t.x[i].to_bits() != serial.x[i].to_bits());
    assert_eq!(first, None, "{at}: first differing cell");
}

/// The threaded solve (core/src/fork.rs: products and coarse residuals cut between lines,
/// sums cut at block boundaries, vector updates element by element) gives the serial bits for 2 to 5 parts, cut down to
/// 64 cells a part: the same iterations, residual and solution, with the lines alone and with
/// the V-cycle, periodic or not, in 2D and 3D (the first 40 iterations of the random systems,
/// which need a thousand; the cold layer to convergence).
#[test]
fn threaded_solves_have_the_serial_bits() {
    fn check<const D: usize>(sys: &System<D>, what: &str, max: u32) {
        let room = workspace_len(sys.grid.cells());
        for pc in [
            Preconditioner::Lines,
            Preconditioner::Multigrid,
            Preconditioner::Auto,
        ] {
            let serial = sys.solve_on(&Serial, pc, room, max);
            assert!(serial.iterations > 0, "{what} {pc:?}");
            for parts in 2..=5 {
                let pool = Pool::new(parts).expect("threads").cutting_down_to(64);
                let t = pool.install(|| sys.solve_on(&pool, pc, room, max));
                assert_same_solve(&t, &serial, &format!("{what} {pc:?} {parts} parts"));
            }
        }
    }
    check(
        &random_system([61, 67], [false, false], 7),
        "2D 61 x 67",
        40,
    );
    check(
        &random_system([64, 64], [true, false], 8),
        "2D 64 x 64 periodic",
        40,
    );
    check(
        &random_system([13, 17, 18], [false, true, false], 9),
        "3D 13 x 17 x 18",
        40,
    );
    let layer = layer(48, 85, false, 10);
    check(&layer, "cold layer 48 x 85", 400);
    assert!(layer.full(Preconditioner::Multigrid).residual < 1e-9);
}

/// The solves' hot loops run at every vector width this CPU has (host/src/isa.rs
/// `AtLevel`, `on_level!`, docs/simd.md): the products, line solves and sums compiled for AVX2 or AVX-512
/// give the bits of the baseline, on one thread and on three.
#[test]
fn solves_at_every_vector_width_have_the_serial_bits() {
    fn check<const D: usize>(sys: &System<D>, what: &str, max: u32) {
        let room = workspace_len(sys.grid.cells());
        let pool = Pool::new(3).expect("threads").cutting_down_to(64);
        for pc in [Preconditioner::Lines, Preconditioner::Multigrid] {
            let serial = sys.solve_on(&Serial, pc, room, max);
            assert!(serial.iterations > 0, "{what} {pc:?}");
            for level in [Level::Baseline, Level::Avx2, Level::Avx512] {
                if !level.available() {
                    eprintln!("note: this CPU has no {}: not compared", level.name());
                    continue;
                }
                let one = sieve::on_level!(level, &Serial, |f| sys.solve_on(f, pc, room, max));
                let three = pool
                    .install(|| sieve::on_level!(level, &pool, |f| sys.solve_on(f, pc, room, max)));
                for (t, threads) in [(one, 1usize), (three, 3usize)] {
                    let at = format!("{what} {pc:?} {} on {threads}", level.name());
                    assert_same_solve(&t, &serial, &at);
                }
            }
        }
    }
    check(
        &random_system([61, 67], [false, true], 11),
        "2D 61 x 67 periodic",
        40,
    );
    check(
        &random_system([13, 17, 18], [true, false, false], 12),
        "3D 13 x 17 x 18",
        40,
    );
}

#[test]
fn line_preconditioner_is_exact_in_1d() {
    for seed in 1..20 {
        let o = random_system([200], [false], seed).full(Preconditioner::Auto);
        // one iteration is the exact solve; a second one polishes its round-off
        assert!(
            o.iterations <= 2,
            "seed {seed}: {} iterations",
            o.iterations
        );
        assert!(o.residual < 1e-8, "seed {seed}: residual {}", o.residual);
    }
}

#[test]
fn periodic_vertical_lines_still_converge_in_1d() {
    // The wrap face is left out of the line factor, so a periodic line needs a few iterations.
    let o = random_system([200], [true], 3).full(Preconditioner::Auto);
    assert!(o.iterations <= 10, "{} iterations", o.iterations);
    assert!(o.residual < 1e-8, "residual {}", o.residual);
}

/// The V-cycle removes the long-range horizontal coupling of a bed. Measured (lines /
/// V-cycle / auto): 64 x 16: 164 / 33 / 36; 128 x 16: 246 / 42 / 45 (periodic 232 / 41 / 45);
/// 255 x 16: 377 / 56 / 59. Unscaled piecewise-constant aggregation still grows with the
/// width, but slowly; `Auto` switches after a few line iterations.
#[test]
fn multigrid_takes_out_the_horizontal_coupling() {
    for (nx, periodic) in [(64, false), (128, false), (128, true), (255, false)] {
        let sys = layer(nx, 16, periodic, 7);
        let lines = sys.full(Preconditioner::Lines);
        let mg = sys.full(Preconditioner::Multigrid);
        let auto = sys.full(Preconditioner::Auto);
        eprintln!(
            "{nx} x 16 periodic {periodic}: lines {} multigrid {} auto {} iterations",
            lines.iterations, mg.iterations, auto.iterations
        );
        for o in [&lines, &mg, &auto] {
            assert!(o.recursive <= 1e-10 && o.residual < 1e-8, "{}", o.residual);
        }
        assert!(mg.iterations <= 60, "multigrid {}", mg.iterations);
        assert!(
            lines.iterations >= 3 * mg.iterations,
            "lines {} vs multigrid {}",
            lines.iterations,
            mg.iterations
        );
        assert!(
            auto.iterations <= mg.iterations + 16,
            "auto {}",
            auto.iterations
        );
        // the same solution either way, to the solver tolerance
        let scale = mg.x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (p, q) in lines.x.iter().zip(&mg.x) {
            assert!((p - q).abs() <= 1e-7 * scale);
        }
    }
}

/// Closed faces (k = 0) around solid cells with a tiny diagonal, as embedded walls produce:
/// the aggregates mix solid and open cells, and the hierarchy must stay SPD. The solid cells
/// satisfy their own equation `diag x = b` to the solver tolerance (x itself is only
/// determined to `tol |b| / diag`).
#[test]
fn decoupled_cells_stay_decoupled() {
    let mut sys = layer(96, 24, false, 11);
    let g = sys.grid;
    let solid = |i: usize| {
        let [x, z] = g.coords(i);
        let (dx, dz) = (x as f64 - 48.0, z as f64 - 24.0);
        dx * dx + dz * dz < 100.0 || (x + z) % 7 == 0
    };
    for i in 0..g.len() {
        if solid(i) {
            sys.diag[i] = 1e-9;
            sys.kf[0][i] = 0.0;
            sys.kf[1][i] = 0.0;
            if g.coords(i)[0] > 0 {
                sys.kf[0][i - 1] = 0.0;
            }
            if g.coords(i)[1] > 0 {
                sys.kf[1][i - 96] = 0.0;
            }
        }
    }
    for pc in [
        Preconditioner::Lines,
        Preconditioner::Multigrid,
        Preconditioner::Auto,
    ] {
        let o = sys.full(pc);
        eprintln!("{pc:?}: {} iterations", o.iterations);
        assert!(o.residual < 1e-8, "{pc:?}: {}", o.residual);
        let bnorm = sys.b[..g.len()].iter().map(|v| v * v).sum::<f64>().sqrt();
        for i in (0..g.len()).filter(|&i| solid(i)) {
            let r = sys.b[i] - sys.diag[i] * o.x[i];
            assert!(r.abs() <= 1e-9 * bnorm, "{pc:?} cell {i}: {r}");
        }
    }
}

/// A short workspace gives fewer levels, not a failure; an empty one the lines alone.
#[test]
fn short_workspace_degrades_gracefully() {
    let sys = layer(128, 16, false, 5);
    let full = workspace_len([128, 16]);
    // 2D: (D + 3) values per coarse cell plus one level-1 vector, about 1.9 n
    assert!(full <= 2 * 128 * 16, "{full}");
    // none; one coarse level (64 x 8: 5 x 512 + 512); two; all
    let its: Vec<u32> = [0, 3072, 3712, full]
        .into_iter()
        .map(|room| {
            let o = sys.solve(Preconditioner::Multigrid, room);
            eprintln!("workspace {room}: {} iterations", o.iterations);
            assert!(o.residual < 1e-8);
            o.iterations
        })
        .collect();
    assert!(its[1] < its[0] && its[3] < its[0], "{its:?}");
}

/// Same input, same bits (the sums have a fixed order), with every preconditioner.
#[test]
fn reruns_are_bit_identical() {
    let sys = random_system([24, 40], [true, false], 9);
    for pc in [
        Preconditioner::Lines,
        Preconditioner::Multigrid,
        Preconditioner::Auto,
    ] {
        let (a, b) = (sys.full(pc), sys.full(pc));
        assert_eq!(a.iterations, b.iterations);
        assert!(a
            .x
            .iter()
            .zip(&b.x)
            .all(|(p, q)| p.to_bits() == q.to_bits()));
    }
}

/// The line preconditioner cut into slabs of rows (core/src/flow/line_slab.rs) has the
/// serial bits: pivots, multipliers and `z = M^-1 r`, for slabs of one row up, cuts in every
/// place, and the columns in segments swept slab after slab as a wavefront would (segment
/// by segment up the slabs for the factor and the forward sweep, down for the backward one),
/// in 2D and 3D, periodic and not, with coefficients over 10 decades.
#[test]
fn line_slabs_have_the_serial_bits() {
    use sieve_core::flow::line_slab;
    fn check<const D: usize>(sys: &System<D>, cuts: &[usize], segments: usize, what: &str) {
        let n = sys.grid.len();
        let s = sys.grid.stride(D - 1);
        let st = Stencil {
            grid: &sys.grid,
            periodic: sys.periodic,
            kf: &sys.kf,
        };
        let (mut inv_d, mut l, mut z) = (vec![0.0; N], vec![0.0; N], vec![0.0; N]);
        st.line_factor(&sys.diag, &mut inv_d, &mut l);
        st.precondition(&inv_d, &l, &sys.b, &mut z);
        // the slabs: rows [cuts[k], cuts[k + 1]), each with its own arrays
        let rows = n / s;
        let mut edges: Vec<usize> = cuts.iter().map(|c| c % rows).filter(|&c| c > 0).collect();
        edges.push(0);
        edges.push(rows);
        edges.sort_unstable();
        edges.dedup();
        let slabs: Vec<(usize, usize)> = edges.windows(2).map(|w| (w[0] * s, w[1] * s)).collect();
        let mut m = vec![0.0; N];
        st.diagonal(&sys.diag, &mut m);
        let mut d: Vec<Vec<f64>> = slabs.iter().map(|&(a, b)| m[a..b].to_vec()).collect();
        let mut ls: Vec<Vec<f64>> = slabs.iter().map(|&(a, b)| vec![f64::NAN; b - a]).collect();
        // the face below each row: the coefficient stored at the cell below it (none on the floor)
        let kb: Vec<Vec<f64>> = slabs
            .iter()
            .map(|&(a, b)| {
                (a..b)
                    .map(|i| {
                        if i >= s {
                            sys.kf[D - 1][i - s]
                        } else {
                            f64::NAN
                        }
                    })
                    .collect()
            })
            .collect();
        let seg: Vec<std::ops::Range<usize>> = (0..segments)
            .map(|k| k * s / segments..(k + 1) * s / segments)
            .collect();
        for c in &seg {
            for k in 0..slabs.len() {
                let (done, rest) = d.split_at_mut(k);
                let below = done.last().map(|p| &p[p.len() - s..]);
                line_slab::factor(s, c.clone(), &mut rest[0], &mut ls[k], &kb[k], below);
            }
        }
        for p in d.iter_mut() {
            line_slab::invert_pivots(p);
        }
        let mut zs: Vec<Vec<f64>> = slabs.iter().map(|&(a, b)| vec![f64::NAN; b - a]).collect();
        for c in &seg {
            for k in 0..slabs.len() {
                let (a, b) = slabs[k];
                let (done, rest) = zs.split_at_mut(k);
                let below = done.last().map(|p| &p[p.len() - s..]);
                line_slab::forward(
                    s,
                    c.clone(),
                    &ls[k],
                    Some(&sys.b[a..b]),
                    &mut rest[0],
                    below,
                );
            }
        }
        for c in &seg {
            for k in (0..slabs.len()).rev() {
                let (here, after) = zs.split_at_mut(k + 1);
                let above = after.first().map(|za| (&za[..s], &ls[k + 1][..s]));
                line_slab::backward(s, c.clone(), &d[k], &ls[k], &mut here[k], above);
            }
        }
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let joined = |v: &[Vec<f64>]| v.concat();
        assert_eq!(
            bits(&joined(&d)),
            bits(&inv_d[..n]),
            "{what}: pivots, slabs {slabs:?}"
        );
        assert_eq!(
            bits(&joined(&ls)),
            bits(&l[..n]),
            "{what}: multipliers, slabs {slabs:?}"
        );
        assert_eq!(
            bits(&joined(&zs)),
            bits(&z[..n]),
            "{what}: z, slabs {slabs:?}"
        );
    }
    for (seed, cuts, segments) in [
        (1, vec![], 1),
        (2, vec![1], 1),
        (3, vec![5, 6, 7, 20], 3),
        (4, vec![3, 11, 12, 13, 14, 15, 30], 7),
    ] {
        for periodic in [false, true] {
            let sys = random_system([13, 31], [periodic, periodic], seed);
            check(
                &sys,
                &cuts,
                segments,
                &format!("2D seed {seed} periodic {periodic}"),
            );
            let sys = layer(29, 17, periodic, seed);
            check(&sys, &cuts, segments, &format!("layer seed {seed}"));
            let sys = random_system([5, 4, 19], [periodic, false, periodic], seed);
            check(
                &sys,
                &cuts,
                segments,
                &format!("3D seed {seed} periodic {periodic}"),
            );
        }
    }
}

/// What the slabs solve: the operator and right-hand side of a system, global.
struct Operator<'a, R, const D: usize> {
    cells: [usize; D],
    periodic: [bool; D],
    diag: &'a [R],
    kf: [&'a [R]; D],
    b: &'a [R],
}

impl<const D: usize> System<D> {
    fn operator(&self) -> Operator<'_, f64, D> {
        let n = self.grid.len();
        Operator {
            cells: self.grid.cells(),
            periodic: self.periodic,
            diag: &self.diag[..n],
            kf: std::array::from_fn(|a| &self.kf[a][..n]),
            b: &self.b[..n],
        }
    }
}

/// Runs `job` on every slab of `op` cut at the rows `starts`, each on its own thread, with
/// its plan (the line pipelines in `pieces`), links, padded fine operator and padded
/// right-hand side (core/src/flow/cycle_slab.rs); returns what each slab returned, in slab
/// order. Every padded value a slab is not meant to read (halo rows, other than the faces
/// below its first row) is NaN.
fn on_slabs<R: Real, const D: usize>(
    op: &Operator<'_, R, D>,
    (starts, pieces): (&[usize], usize),
    room: usize,
    job: impl Fn(&Plan<D>, &mut ThreadLinks<R>, &Fine<'_, R, D>, &[R]) -> Vec<R> + Sync,
) -> Vec<Vec<R>> {
    let job = &job;
    std::thread::scope(|scope| {
        let handles: Vec<_> = ThreadLinks::chain(starts.len())
            .into_iter()
            .enumerate()
            .map(|(k, mut links)| {
                scope.spawn(move || {
                    let plan = Plan::new(op.cells, op.periodic, starts, k, room)
                        .unwrap()
                        .with_pieces(pieces);
                    let padded = |src: &[R], row_below: bool| -> Vec<R> {
                        let mut out = vec![R::from_f64(f64::NAN); plan.padded_len()];
                        plan.pad_from(src, row_below, &mut out);
                        out
                    };
                    let diag = padded(op.diag, false);
                    let kf: Vec<Vec<R>> = (0..D).map(|a| padded(op.kf[a], a == D - 1)).collect();
                    let fine = Fine {
                        diag: &diag,
                        kf: std::array::from_fn(|a| &kf[a][..]),
                    };
                    let b = padded(op.b, false);
                    job(&plan, &mut links, &fine, &b)
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    })
}

/// `op` solved from 0 by CG on slabs cut at the rows `starts` (threads, the line pipelines
/// in `pieces`; core/src/flow/cg_slab.rs): each slab's iterations and relative residual, and
/// the solution of the slabs' own cells joined in slab order.
fn solve_on_slabs<R: Real, const D: usize>(
    op: &Operator<'_, R, D>,
    cut: (&[usize], usize),
    room: usize,
    stop: Stop<R>,
) -> (Vec<(u32, R)>, Vec<R>) {
    use sieve_core::flow::cg_slab;
    let nan = R::from_f64(f64::NAN);
    let pieces = on_slabs(op, cut, room, |plan, links, fine, b| {
        let (len, m) = (plan.padded_len(), plan.own_range().len());
        let mut x = vec![nan; len];
        x[plan.own_range()].fill(R::ZERO);
        let mut v: Vec<Vec<R>> = (0..3).map(|_| vec![nan; len]).collect();
        let mut w: Vec<Vec<R>> = (0..4).map(|_| vec![nan; m]).collect();
        let mut work = vec![nan; plan.workspace_len()];
        let [r, p, ap] = &mut v[..] else {
            unreachable!()
        };
        let [pre, line, tmp, terms] = &mut w[..] else {
            unreachable!()
        };
        let sc = cg_slab::Scratch {
            r,
            p,
            ap,
            pre,
            line,
            tmp,
            terms,
            work: &mut work,
        };
        let res = cg_slab::solve(plan, links, fine, b, &mut x, sc, stop);
        let mut out = x[plan.own_range()].to_vec();
        out.push(R::from_usize(res.iterations as usize));
        out.push(res.relative_residual);
        out
    });
    let mut outcomes = Vec::new();
    let mut joined = Vec::new();
    for piece in &pieces {
        let k = piece.len() - 2;
        outcomes.push((piece[k].to_f64() as u32, piece[k + 1]));
        joined.extend_from_slice(&piece[..k]);
    }
    (outcomes, joined)
}

/// The index and values of the first difference in bits of `a` and `b`.
fn first_difference(a: &[f64], b: &[f64]) -> Option<(usize, f64, f64)> {
    (0..a.len().max(b.len())).find_map(|i| {
        let (x, y) = (a.get(i).copied(), b.get(i).copied());
        (x.map(f64::to_bits) != y.map(f64::to_bits))
            .then(|| (i, x.unwrap_or(f64::NAN), y.unwrap_or(f64::NAN)))
    })
}

/// The preconditioner on slabs of rows (core/src/flow/cycle_slab.rs: the line solves as
/// pipelines, the V-cycle's upper levels on the slabs with halo rows, its lower levels
/// gathered) gives `z = B r` with the serial bits, the slabs running as threads (the line
/// pipelines in 1 to 4 column pieces): cuts
/// aligned to 2, 4, 8 and 16 rows and uneven slabs, one slab, 2D and 3D, periodic across,
/// coefficients over 10 decades and a cold bed, full and shortened hierarchies, and the lines
/// alone (where odd cuts are allowed). Every array a slab is not meant to read (halo values
/// other than the faces below, its workspace) starts as NaN.
#[test]
fn slab_preconditioner_has_the_serial_bits() {
    use sieve_core::flow::cg::precondition_once;
    use sieve_core::flow::cycle_slab::{self, PlanError};
    fn check<const D: usize>(sys: &System<D>, starts: &[usize], room: usize, mg: bool, what: &str) {
        let n = sys.grid.len();
        let cells = sys.grid.cells();
        let s: usize = cells[..D - 1].iter().product();
        let st = Stencil {
            grid: &sys.grid,
            periodic: sys.periodic,
            kf: &sys.kf,
        };
        let mut z = vec![0.0; N];
        let mut v = vec![vec![0.0; N]; 6];
        let mut coarse = vec![0.0; room];
        let [r, p, ap, pre, line, tmp] = &mut v[..] else {
            unreachable!()
        };
        let _ = (r, p, ap);
        let rz = precondition_once(
            &st,
            &sys.diag,
            &sys.b,
            &mut z,
            Scratch {
                r: &mut [],
                p: &mut [],
                ap: &mut [],
                pre,
                line,
                tmp,
                coarse: &mut coarse,
                part: &mut [],
            },
            mg,
        );
        assert!(rz.is_finite() && rz > 0.0, "{what}: r . z = {rz}");
        // the line pipelines' column pieces: 1 to 4, by the number of slabs
        let pieces = on_slabs(
            &sys.operator(),
            (starts, 1 + starts.len() % 4),
            room,
            |plan, links, fine, r| {
                let own = plan.own_range();
                let mut z = vec![f64::NAN; plan.padded_len()];
                let m = own.len();
                let (mut pre, mut line, mut tmp) =
                    (vec![f64::NAN; m], vec![f64::NAN; m], vec![f64::NAN; m]);
                let mut work = vec![f64::NAN; plan.workspace_len()];
                cycle_slab::factor(plan, links, fine, &mut pre, &mut line, &mut work);
                let coarsened = mg && plan.can_coarsen();
                if coarsened {
                    cycle_slab::coarsen(plan, links, fine, &mut pre, &mut work);
                }
                cycle_slab::apply(
                    plan,
                    links,
                    fine,
                    (&pre, &line),
                    r,
                    &mut z,
                    &mut tmp,
                    &mut work,
                    coarsened,
                );
                z[own].to_vec()
            },
        );
        if let Some((i, got, want)) = first_difference(&pieces.concat(), &z[..n]) {
            panic!(
                "{what}, slabs from {starts:?}, room {room}, multigrid {mg}: z differs first at \
                 cell {i} (row {}): {got} against the serial {want}",
                i / s
            );
        }
    }
    let full2 = workspace_len([24, 40]);
    for (seed, starts) in [
        (1, vec![0]),
        (2, vec![0, 16]),
        (3, vec![0, 8, 16, 32]),
        (4, vec![0, 4, 12, 20, 28]),
        (5, vec![0, 2, 4, 6, 8, 30]),
        (6, vec![0, 2, 38]),
    ] {
        for px in [false, true] {
            let sys = random_system([24, 40], [px, false], seed);
            for room in [full2, full2 / 8, 0] {
                check(
                    &sys,
                    &starts,
                    room,
                    true,
                    &format!("2D seed {seed} px {px}"),
                );
            }
            check(
                &sys,
                &starts,
                full2,
                false,
                &format!("2D lines seed {seed} px {px}"),
            );
            let sys = layer(29, 40, px, seed);
            check(
                &sys,
                &starts,
                workspace_len([29, 40]),
                true,
                &format!("layer seed {seed}"),
            );
            let sys = random_system([5, 4, 40], [px, true, false], seed);
            let full3 = workspace_len([5, 4, 40]);
            check(
                &sys,
                &starts,
                full3,
                true,
                &format!("3D seed {seed} px {px}"),
            );
        }
    }
    // the lines alone take any cut; the V-cycle refuses odd ones and a cut periodic axis
    let sys = random_system([13, 31], [true, false], 7);
    check(&sys, &[0, 1, 5, 6, 7, 20], 0, false, "2D odd cuts, lines");
    let sys = random_system([1, 31], [false, false], 8);
    check(
        &sys,
        &[0, 3, 17],
        workspace_len([1, 31]),
        true,
        "vertical lines, odd cuts",
    );
    assert_eq!(
        Plan::new([13, 31], [false; 2], &[0, 5], 0, workspace_len([13, 31])).err(),
        Some(PlanError::OddCut)
    );
    assert_eq!(
        Plan::new([13, 32], [false, true], &[0, 16], 0, 0).err(),
        Some(PlanError::PeriodicCut)
    );
    for bad in [&[][..], &[1], &[0, 0], &[0, 31], &[0, 9, 4]] {
        assert_eq!(
            Plan::new([13, 31], [false; 2], bad, 0, 0).err(),
            Some(PlanError::BadCuts),
            "{bad:?}"
        );
    }
}

/// Conjugate gradients on slabs of rows (core/src/flow/cg_slab.rs) take the serial solve's
/// iterations and end with its bits (solution and residual), with the lines, the V-cycle
/// and the switch between them: 1 to 5 slabs on threads, 2D and 3D, periodic across, random
/// coefficients over 10 decades and a cold bed whose lines converge slowly (so the
/// automatic choice switches to the V-cycle mid-solve), a short hierarchy.
#[test]
fn slab_solves_have_the_serial_bits() {
    fn check<const D: usize>(
        sys: &System<D>,
        starts: &[usize],
        pc: Preconditioner,
        room: usize,
        what: &str,
    ) -> u32 {
        let n = sys.grid.len();
        let serial = sys.solve_on(&Serial, pc, room, 400);
        let stop = Stop {
            relative: 1e-10,
            floor: 0.0,
            max_iterations: 400,
            preconditioner: pc,
        };
        let (outcomes, joined) =
            solve_on_slabs(&sys.operator(), (starts, 1 + starts.len() % 4), room, stop);
        for (iterations, residual) in outcomes {
            assert_eq!(
                iterations, serial.iterations,
                "{what}, slabs from {starts:?}: iterations"
            );
            assert_eq!(
                residual.to_bits(),
                serial.recursive.to_bits(),
                "{what}, slabs from {starts:?}: residual"
            );
        }
        if let Some((i, got, want)) = first_difference(&joined, &serial.x[..n]) {
            panic!("{what}, slabs from {starts:?}, {pc:?}: x differs first at cell {i}: {got} against the serial {want}");
        }
        serial.iterations
    }
    let mut switched = 0;
    for (seed, starts) in [
        (1, vec![0]),
        (2, vec![0, 16]),
        (3, vec![0, 8, 16, 32]),
        (4, vec![0, 4, 12, 20, 28]),
        (5, vec![0, 2, 38]),
    ] {
        for pc in [
            Preconditioner::Lines,
            Preconditioner::Multigrid,
            Preconditioner::Auto,
        ] {
            for px in [false, true] {
                let sys = random_system([24, 40], [px, false], seed);
                check(
                    &sys,
                    &starts,
                    pc,
                    workspace_len([24, 40]),
                    &format!("2D seed {seed} px {px}"),
                );
                let sys = random_system([5, 4, 40], [px, true, false], seed);
                check(
                    &sys,
                    &starts,
                    pc,
                    workspace_len([5, 4, 40]) / 4,
                    &format!("3D seed {seed}"),
                );
            }
            // a cold bed: the lines converge slowly, Auto switches to the V-cycle
            let sys = layer(64, 40, true, seed);
            let full = workspace_len([64, 40]);
            let it = check(&sys, &starts, pc, full, &format!("layer seed {seed}"));
            if pc == Preconditioner::Auto {
                let lines = sys
                    .solve_on(&Serial, Preconditioner::Lines, full, 400)
                    .iterations;
                switched += usize::from(it < lines);
            }
        }
    }
    assert!(
        switched >= 3,
        "the automatic choice switched on {switched} of 5 layers"
    );
    // the lines alone, on odd cuts
    let sys = random_system([13, 31], [true, false], 7);
    check(
        &sys,
        &[0, 1, 5, 6, 7, 20],
        Preconditioner::Lines,
        0,
        "2D odd cuts, lines",
    );
}

/// The CG on slabs in f32 (the precision of f32 scenes) takes the serial f32 solve's
/// iterations and ends with its bits: a cold bed and a random 3D system cut into 2 to 5 slabs,
/// lines, V-cycle and the automatic switch.
#[test]
fn slab_solves_in_f32_have_the_serial_bits() {
    use sieve_core::flow::cg::{solve, Solve};
    fn check<const D: usize>(sys: &System<D>, starts: &[usize], pc: Preconditioner) {
        let n = sys.grid.len();
        let cells = sys.grid.cells();
        let grid = Grid::<f32, D>::new(cells, [0.0; D], [1.0; D], N).unwrap();
        let mut kf = vec![[0.0f32; N]; D];
        for a in 0..D {
            for i in 0..n {
                kf[a][i] = sys.kf[a][i] as f32;
            }
        }
        let kf: Box<[[f32; N]; D]> = kf.into_boxed_slice().try_into().unwrap();
        let diag: Vec<f32> = sys.diag[..n].iter().map(|&v| v as f32).collect();
        let b: Vec<f32> = sys.b[..n].iter().map(|&v| v as f32).collect();
        let st = Stencil {
            grid: &grid,
            periodic: sys.periodic,
            kf: &kf,
        };
        let stop = Stop {
            relative: 1e-5f32,
            floor: 0.0,
            max_iterations: 400,
            preconditioner: pc,
        };
        let room = workspace_len(cells);
        let mut x = vec![0.0f32; n];
        let mut v = vec![vec![0.0f32; n]; 6];
        let mut coarse = vec![0.0f32; room];
        let [r, p, ap, pre, line, tmp] = &mut v[..] else {
            unreachable!()
        };
        let serial: Solve<f32> = solve(
            &st,
            &diag,
            &b,
            &mut x,
            Scratch {
                r,
                p,
                ap,
                pre,
                line,
                tmp,
                coarse: &mut coarse,
                part: &mut [],
            },
            stop,
        );
        assert!(
            serial.relative_residual <= 1e-5,
            "{pc:?}: serial residual {}",
            serial.relative_residual
        );
        let op = Operator {
            cells,
            periodic: sys.periodic,
            diag: &diag,
            kf: std::array::from_fn(|a| &kf[a][..n]),
            b: &b,
        };
        let (outcomes, joined) = solve_on_slabs(&op, (starts, 2), room, stop);
        for (iterations, residual) in outcomes {
            assert_eq!(
                iterations, serial.iterations,
                "{pc:?}, slabs from {starts:?}: iterations"
            );
            assert_eq!(
                residual.to_bits(),
                serial.relative_residual.to_bits(),
                "{pc:?}: residual"
            );
        }
        let same = joined
            .iter()
            .zip(&x)
            .all(|(p, q)| p.to_bits() == q.to_bits());
        assert!(
            same && joined.len() == n,
            "{pc:?}, slabs from {starts:?}: x differs"
        );
    }
    for pc in [
        Preconditioner::Lines,
        Preconditioner::Multigrid,
        Preconditioner::Auto,
    ] {
        check(&layer(64, 40, true, 3), &[0, 16], pc);
        check(&layer(64, 40, true, 4), &[0, 4, 12, 20, 28], pc);
        check(
            &random_system([5, 4, 40], [true, true, false], 5),
            &[0, 8, 24],
            pc,
        );
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]
    #[test]
    fn solves_2d_and_3d_systems(seed in 1u64..1_000_000, px: bool, pz: bool) {
        for pc in [Preconditioner::Auto, Preconditioner::Multigrid] {
            let o = random_system([16, 32], [px, pz], seed).full(pc);
            prop_assert!(o.recursive <= 1e-10 && o.iterations < 3000);
            prop_assert!(o.residual < 1e-7, "2D residual {} after {} iterations", o.residual, o.iterations);
            let o = random_system([8, 4, 16], [px, false, pz], seed).full(pc);
            prop_assert!(o.recursive <= 1e-10 && o.iterations < 3000);
            prop_assert!(o.residual < 1e-7, "3D residual {} after {} iterations", o.residual, o.iterations);
            // odd sizes: aggregates of one cell at the ends, periodic lines of 3 and 1
            let o = random_system([5, 3, 7], [px, true, pz], seed).full(pc);
            prop_assert!(o.residual < 1e-7, "odd 3D residual {}", o.residual);
        }
    }

    /// The blocked sum against a double-double reference, within `sum::error_bound`, and
    /// bit-identical when split into chunks at block boundaries.
    #[test]
    fn blocked_sums_are_accurate_and_split_invariant(
        seed in 1u64..1_000_000,
        n in 1usize..3000,
        cuts in proptest::collection::vec(0usize..12, 0..5),
        any_cuts in proptest::collection::vec(0usize..100_000, 0..24),
    ) {
        let mut s = seed;
        // mixed signs and 12 decades: cancellation and swamping
        let x: Vec<f64> = (0..n)
            .map(|_| (lcg(&mut s) - 0.4) * 10f64.powf(12.0 * lcg(&mut s) - 6.0))
            .collect();
        let y: Vec<f64> = (0..n).map(|_| lcg(&mut s) - 0.5).collect();
        let whole = sum::dot(&x, &y);
        // reference: exact products (two-product by splitting) summed in double-double
        let (mut hi, mut lo) = (0.0f64, 0.0f64);
        let mut abs = 0.0;
        for (a, b) in x.iter().zip(&y) {
            let p = a * b;
            abs += p.abs();
            let e = two_product_error(*a, *b, p);
            let (t, err) = two_sum(hi, p);
            hi = t;
            lo += err + e;
        }
        let reference = hi + lo;
        let bound = sum::error_bound(n, abs) + abs * f64::EPSILON; // + the products' rounding
        prop_assert!((whole - reference).abs() <= bound, "{} vs {} (bound {})", whole, reference, bound);
        // chunks at block boundaries: the partials of each chunk, folded in order
        let mut edges: Vec<usize> = cuts.iter().map(|c| (c * sum::BLOCK).min(n)).collect();
        edges.push(0);
        edges.push(n);
        edges.sort_unstable();
        edges.dedup();
        let mut partials = vec![0.0; n.div_ceil(sum::BLOCK)];
        let mut k = 0;
        for w in edges.windows(2) {
            k += sum::block_partials(w[0], w[1], |i| x[i] * y[i], &mut partials[k..]);
        }
        prop_assert_eq!(k, partials.len());
        prop_assert_eq!(sum::fold(&partials).to_bits(), whole.to_bits());
        // cut anywhere (grid rows of any width, parts shorter than a block, empty parts): each
        // part lends its head to the part where that block began, borrows what its last
        // block needs from the parts after it, and folds from the running total before it
        let mut edges: Vec<usize> = any_cuts.iter().map(|c| c % (n + 1)).collect();
        edges.push(0);
        edges.push(n);
        edges.sort_unstable();
        let parts: Vec<(usize, usize)> = edges.windows(2).map(|w| (w[0], w[1])).collect();
        let term = |i: usize| x[i] * y[i];
        let lent: Vec<Vec<f64>> = parts
            .iter()
            .map(|&(a, b)| (a..a + sum::lent(a, b)).map(term).collect())
            .collect();
        let mut total = 0.0;
        let mut begun = 0;
        for (p, &(a, b)) in parts.iter().enumerate() {
            let need = sum::borrowed(a, b, n);
            let from_later: Vec<f64> = lent[p + 1..].iter().flatten().copied().take(need).collect();
            prop_assert_eq!(from_later.len(), need, "part {}..{} of {}", a, b, n);
            let mut out = vec![f64::NAN; sum::blocks_begun(a, b)];
            let k = sum::cut_partials(a, b, n, term, &from_later, &mut out);
            prop_assert_eq!(k, out.len());
            begun += k;
            total = sum::fold_from(total, &out);
        }
        prop_assert_eq!(begun, n.div_ceil(sum::BLOCK));
        prop_assert_eq!(total.to_bits(), whole.to_bits(), "cuts {:?}", edges);
        // every lent term is borrowed by exactly one part: the lent heads cover the blocks'
        // tails, no more
        let lent_total: usize = lent.iter().map(Vec::len).sum();
        let borrowed_total: usize = parts.iter().map(|&(a, b)| sum::borrowed(a, b, n)).sum();
        prop_assert_eq!(lent_total, borrowed_total);
        // the slice kernels are the generic scheme
        prop_assert_eq!(sum::reduce(n, |i| x[i] * y[i]).to_bits(), whole.to_bits());
        let (mut xu, mut ru) = (y.clone(), x.clone());
        let (mut xv, mut rv) = (y.clone(), x.clone());
        let fused = sum::update(0.37, &y, &x, &mut xu, &mut ru);
        let generic = sum::reduce(n, |i| {
            xv[i] += 0.37 * y[i];
            rv[i] -= 0.37 * x[i];
            rv[i] * rv[i]
        });
        prop_assert_eq!(fused.to_bits(), generic.to_bits());
        prop_assert!(xu == xv && ru == rv);
        // f32: against the f64 sum of the same (exactly widened) values
        let xf: Vec<f32> = x.iter().map(|v| *v as f32).collect();
        let sf = sum::sum(&xf);
        let (s64, a64) = xf.iter().fold((0.0f64, 0.0f64), |(s, a), v| (s + f64::from(*v), a + f64::from(v.abs())));
        prop_assert!((f64::from(sf) - s64).abs() <= f64::from(sum::error_bound(n, a64 as f32)) + a64 * 1e-12);
    }
}

/// `a + b = s + e` exactly (Knuth).
fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    let bb = s - a;
    (s, (a - (s - bb)) + (b - bb))
}

/// The rounding error of `p = a * b` (Dekker's split), exact barring over/underflow.
fn two_product_error(a: f64, b: f64, p: f64) -> f64 {
    let split = |v: f64| {
        let c = 134217729.0 * v;
        let h = c - (c - v);
        (h, v - h)
    };
    let (ah, al) = split(a);
    let (bh, bl) = split(b);
    ((ah * bh - p) + ah * bl + al * bh) + al * bl
}
