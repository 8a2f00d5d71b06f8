//! `mpirun -np K target/release/examples/mpi_check SCENE [KEY=VALUE ...]`: runs the scene's
//! segregation to its end time on K MPI ranks (one subdomain each, the driver of `sieve run`
//! under mpirun) and serially on rank 0, and exits 0 if the state hashes are the same, 1 if
//! not (docs/parallel.md, `.ci/mpi-check`).
//!
//! `mpi_check --same-vti A B` (no mpirun): reads two snapshots (`.vti`, or `.pvti` with its
//! pieces, which must cover the grid exactly once) and exits 0 if they hold the same grid,
//! time and arrays to the bit, 1 if not.
//!
//! `mpirun -np K target/release/examples/mpi_check --sums`: dot products over vectors cut
//! among the K ranks at row boundaries (rows of 1 to 1000 cells, parts shorter than a sum
//! block, empty parts, f64 and f32) by `sieve::rank_sum::reduce_across`, each against the
//! serial `sum::reduce` on every rank: exits 0 if all have the serial bits, 1 if not; then
//! times one distributed sum of 2^20 terms against the serial one.
//!
//! `mpirun -np K target/release/examples/mpi_check --lines`: the flow's line preconditioner
//! on random systems (2D and 3D, periodic and not, coefficients over 10 decades) cut into
//! K slabs of rows, evenly and unevenly, its columns in 1 and 4 pieces, by
//! `sieve::rank_lines`, against the serial factor and solve: exits 0 if every rank's pivots,
//! multipliers and `z` have the serial bits, 1 if not.
//!
//! `mpirun -np K target/release/examples/mpi_check --cg`: conjugate gradients on random
//! systems and a cold bed (2D and 3D, periodic across, the lines, the V-cycle and the
//! automatic switch) on K slabs of rows aligned to 2 and 8 rows, by
//! `sieve_core::flow::cg_slab` over `sieve::rank_links`, against the serial solve: exits 0
//! if every rank's iterations, residual and solution have the serial bits, 1 if not; then
//! times one 128 x 128 solve against the serial one. `--cg-time SIZE` times one cold bed of
//! SIZE x SIZE (at most 512) the same way.
//!
//! `mpirun -np K target/release/examples/mpi_check --flow`: the flow's step on K slabs of
//! rows (`sieve_core::flow::slab` over `sieve::rank_links`: a collapsing column and random
//! states in 2D with the explicit and the implicit pressure, a collapse in 3D) against the serial steps on every rank: exits 0 if after
//! every step every state array of every rank's rows, the step, the residual and the CG
//! iterations have the serial bits, 1 if not (naming the first step, array and cell that
//! differ); then times the steps of a 64 x 64 collapse against the serial ones.
//!
//! `mpirun -np K target/release/examples/mpi_check --coupled`: the same for the coupled step
//! (`sieve_core::flow::coupled_slab`: percolation, flow, carried transport and back-coupled
//! packing of a mixed collapse and random coupled states in 2D, explicit and implicit
//! pressure, and a 3D collapse): every state array of the flow and the segregation, the
//! step, the flush counter and the guard's total after every step. `--coupled-time SIZE
//! [alone]` times a SIZE x SIZE collapse (16 to 128) on the slabs against the serial steps
//! (or alone, for profiles).
//!
//! Needs the `mpi` feature (OpenMPI: `apt-get install libopenmpi-dev openmpi-bin libclang-dev`).

use sieve::output::vtk::read_vti;
use std::path::Path;

fn same_vti(a: &str, b: &str) -> Result<String, String> {
    let x = read_vti(Path::new(a)).map_err(|e| e.to_string())?;
    let y = read_vti(Path::new(b)).map_err(|e| e.to_string())?;
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    if x.cells != y.cells
        || bits(&x.origin) != bits(&y.origin)
        || bits(&x.spacing) != bits(&y.spacing)
    {
        return Err(format!(
            "{a} and {b}: different grids ({:?} / {:?} cells)",
            x.cells, y.cells
        ));
    }
    if x.t.to_bits() != y.t.to_bits() {
        return Err(format!("{a} and {b}: times {} and {}", x.t, y.t));
    }
    if x.arrays.len() != y.arrays.len() {
        return Err(format!(
            "{a} and {b}: {} and {} arrays",
            x.arrays.len(),
            y.arrays.len()
        ));
    }
    for ((n, c, v), (m, d, w)) in x.arrays.iter().zip(&y.arrays) {
        if n != m || c != d || bits(v) != bits(w) {
            let at = v
                .iter()
                .zip(w)
                .position(|(p, q)| p.to_bits() != q.to_bits());
            return Err(format!(
                "{a} and {b}: array {n} / {m} differs (first at value {at:?})"
            ));
        }
    }
    let n: usize = x.cells.iter().product();
    Ok(format!(
        "{a} = {b}: {n} cells, {} arrays, t = {}",
        x.arrays.len(),
        x.t
    ))
}

/// A value in [0, 1) from a 64-bit LCG (the same sequence on every rank).
fn lcg(s: &mut u64) -> f64 {
    *s = s
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    (*s >> 11) as f64 / (1u64 << 53) as f64
}

/// `--sums`: returns the exit code.
fn sums() -> i32 {
    use mpi::traits::*;
    use sieve::rank_sum::reduce_across;
    use sieve_core::sum;
    let Some(universe) = mpi::initialize() else {
        eprintln!("mpi_check --sums: MPI is already initialised");
        return 1;
    };
    let world = universe.world();
    let (rank, size) = (world.rank() as usize, world.size() as usize);
    let mut bad = 0i32;
    let mut cases = 0;
    // (cells per row, rows, seed of the cuts: 0 = rows shared evenly, else random row cuts
    // with empty parts)
    let shapes = [
        (29, 100, 0),
        (58, 200, 0),
        (29, 8, 0),
        (1, 7, 0),
        (256, 9, 0),
        (1000, 3, 0),
        (29, 100, 1),
        (1, 1000, 2),
        (7, 300, 3),
        (29, 1, 4),
    ];
    for (w, rows, seed) in shapes {
        let n = w * rows;
        let mut s = 0x5eed ^ (n as u64) ^ (seed << 32);
        // 12 decades, mixed signs: the order of additions shows in the bits
        let x: Vec<f64> = (0..n)
            .map(|_| (lcg(&mut s) - 0.4) * 10f64.powf(12.0 * lcg(&mut s) - 6.0))
            .collect();
        let y: Vec<f64> = (0..n).map(|_| lcg(&mut s) - 0.5).collect();
        let mut cuts: Vec<usize> = if seed == 0 {
            (0..=size).map(|r| r * rows / size * w).collect()
        } else {
            let mut c: Vec<usize> = (0..size - 1)
                .map(|_| (lcg(&mut s) * (rows + 1) as f64) as usize * w)
                .collect();
            c.push(0);
            c.push(n);
            c.sort_unstable();
            c
        };
        cuts[size] = n;
        let parts: Vec<_> = cuts.windows(2).map(|c| c[0]..c[1]).collect();
        let serial = sum::reduce(n, |i| x[i] * y[i]);
        let across = reduce_across(&world, &parts, |i| x[i] * y[i]);
        let xf: Vec<f32> = x.iter().map(|v| *v as f32).collect();
        let serial32 = sum::reduce(n, |i| xf[i] * y[i] as f32);
        let across32 = reduce_across(&world, &parts, |i| xf[i] * y[i] as f32);
        cases += 2;
        if across.to_bits() != serial.to_bits() || across32.to_bits() != serial32.to_bits() {
            bad += 1;
            eprintln!(
                "mpi_check --sums: rank {rank}: {rows} rows of {w}, parts {parts:?}: {across:e} / {across32:e} against the serial {serial:e} / {serial32:e}"
            );
        }
    }
    // the cost of the exchanges: one sum of 2^20 terms on rows of 1000 cells
    let n = 1 << 20;
    let x: Vec<f64> = (0..n).map(|i| 1.0 + (i % 7) as f64 * 1e-3).collect();
    let cuts: Vec<usize> = (0..=size).map(|r| r * (n / 1000) / size * 1000).collect();
    let mut parts: Vec<_> = cuts.windows(2).map(|c| c[0]..c[1]).collect();
    parts[size - 1].end = n;
    let reps = 200;
    world.barrier();
    let t = std::time::Instant::now();
    let mut across = 0.0;
    for _ in 0..reps {
        across = reduce_across(&world, &parts, |i| x[i] * x[i]);
    }
    let t_across = t.elapsed().as_secs_f64() / reps as f64;
    let t = std::time::Instant::now();
    let mut serial = 0.0;
    for _ in 0..reps {
        serial = std::hint::black_box(sum::dot(&x, &x));
    }
    let t_serial = t.elapsed().as_secs_f64() / reps as f64;
    if across.to_bits() != serial.to_bits() {
        bad += 1;
    }
    let all_bad = {
        let mut total = 0i32;
        world.all_reduce_into(&bad, &mut total, mpi::collective::SystemOperation::sum());
        total
    };
    if rank == 0 {
        println!(
            "mpi_check --sums: {cases} sums on {size} ranks, {}; 2^20 terms: {:.1} us across the ranks, {:.1} us serially on one",
            if all_bad == 0 { "all with the serial bits" } else { "SOME DIFFERENT" },
            t_across * 1e6,
            t_serial * 1e6
        );
    }
    drop(universe);
    i32::from(all_bad != 0)
}

/// Cells a check's system may have.
const N: usize = 16384;

/// Cells of the larger systems `--cg-time` times.
const N_TIMED: usize = 1 << 18;

/// A linear system `diag + faces` (`cg::Stencil`'s operator) on a grid of at most `M` cells.
struct System<const D: usize, const M: usize = N> {
    grid: sieve_core::Grid<f64, D>,
    kf: Box<[[f64; M]; D]>,
    diag: Vec<f64>,
    b: Vec<f64>,
}

/// Random coefficients over 10 decades, 1000 times stronger along the last axis; or (`cold`)
/// a cold bed whose coupling grows with the depth (~1e4 times the mass term), on which the
/// line preconditioner converges slowly.
fn random_system<const D: usize, const M: usize>(
    cells: [usize; D],
    seed: u64,
    cold: bool,
) -> System<D, M> {
    let grid = sieve_core::Grid::<f64, D>::new(cells, [0.0; D], [1.0; D], M).expect("grid");
    let n = grid.len();
    let mut r = seed;
    let mut kf = vec![[0.0f64; M]; D].into_boxed_slice();
    for (a, k) in kf.iter_mut().enumerate() {
        for (i, v) in k[..n].iter_mut().enumerate() {
            let scale = if a + 1 == D { 1e3 } else { 1.0 };
            *v = if cold {
                1e4 * (cells[D - 1] - grid.coords(i)[D - 1]) as f64 * (0.5 + lcg(&mut r))
            } else {
                scale * 10f64.powf(10.0 * lcg(&mut r) - 5.0)
            };
        }
    }
    let kf: Box<[[f64; M]; D]> = kf.try_into().expect("D arrays");
    let lo = if cold { 0.5 } else { 1e-3 };
    let diag: Vec<f64> = (0..n).map(|_| lo + lcg(&mut r)).collect();
    let b: Vec<f64> = (0..n).map(|_| lcg(&mut r) - 0.5).collect();
    System { grid, kf, diag, b }
}

/// One random system's line solve on the ranks' slabs against the serial one; the number of
/// arrays that differ on this rank.
fn line_case<const D: usize, C: mpi::traits::Communicator>(
    world: &C,
    cells: [usize; D],
    periodic: [bool; D],
    uneven: bool,
    segments: usize,
    seed: u64,
) -> i32 {
    use sieve_core::flow::cg::Stencil;
    let (rank, size) = (world.rank() as usize, world.size() as usize);
    let System { grid, kf, diag, b } = random_system::<D, N>(cells, seed, false);
    let n = grid.len();
    let s = grid.stride(D - 1);
    let st = Stencil {
        grid: &grid,
        periodic,
        kf: &kf,
    };
    let (mut inv_d, mut l, mut z) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    st.line_factor(&diag, &mut inv_d, &mut l);
    st.precondition(&inv_d, &l, &b, &mut z);
    // this rank's rows: even shares, or the lower ranks one row each (at least one row each)
    let rows = n / s;
    let edge = |k: usize| {
        if uneven {
            if k < size {
                k
            } else {
                rows
            }
        } else {
            k * rows / size
        }
    };
    let (a, e) = (edge(rank) * s, edge(rank + 1) * s);
    let mut m = vec![0.0; n];
    st.diagonal(&diag, &mut m);
    let mut d = m[a..e].to_vec();
    let mut ls = vec![f64::NAN; e - a];
    let kb: Vec<f64> = (a..e)
        .map(|i| if i >= s { kf[D - 1][i - s] } else { f64::NAN })
        .collect();
    sieve::rank_lines::factor_across(world, s, segments, &mut d, &mut ls, &kb);
    let mut zs = vec![f64::NAN; e - a];
    sieve::rank_lines::solve_across(world, s, segments, &d, &ls, &b[a..e], &mut zs);
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    let mut bad = 0;
    for (what, mine, serial) in [
        ("pivots", &d, &inv_d),
        ("multipliers", &ls, &l),
        ("z", &zs, &z),
    ] {
        if bits(mine) != bits(&serial[a..e]) {
            bad += 1;
            eprintln!("mpi_check --lines: rank {rank}: {cells:?} periodic {periodic:?}, rows {}..{}, {segments} pieces: {what} differ", a / s, e / s);
        }
    }
    bad
}

/// `--lines`: returns the exit code.
fn lines() -> i32 {
    use mpi::traits::*;
    let Some(universe) = mpi::initialize() else {
        eprintln!("mpi_check --lines: MPI is already initialised");
        return 1;
    };
    let world = universe.world();
    let mut bad = 0i32;
    let mut cases = 0;
    for (seed, uneven, segments) in [(1, false, 1), (2, false, 4), (3, true, 4), (4, true, 1)] {
        for periodic in [false, true] {
            bad += line_case(&world, [13, 31], [periodic, false], uneven, segments, seed);
            bad += line_case(
                &world,
                [29, 9],
                [periodic, periodic],
                uneven,
                segments,
                seed,
            );
            bad += line_case(
                &world,
                [5, 4, 19],
                [periodic, false, periodic],
                uneven,
                segments,
                seed,
            );
            cases += 3;
        }
    }
    let mut all_bad = 0i32;
    world.all_reduce_into(&bad, &mut all_bad, mpi::collective::SystemOperation::sum());
    if world.rank() == 0 {
        println!(
            "mpi_check --lines: {cases} line solves on {} ranks, {}",
            world.size(),
            if all_bad == 0 {
                "pivots, multipliers and z with the serial bits"
            } else {
                "SOME DIFFERENT"
            }
        );
    }
    drop(universe);
    i32::from(all_bad != 0)
}

/// The first row of every rank's slab: rows shared evenly, each start rounded down to a
/// multiple of `align` (a power of two; at least one row each).
fn slab_starts(rows: usize, ranks: usize, align: usize) -> Vec<usize> {
    let mut starts: Vec<usize> = (0..ranks)
        .map(|k| k * rows / ranks / align * align)
        .collect();
    starts.dedup();
    starts
}

/// The rows of a grid of `cells` cells cut evenly among the ranks at even rows (the slabs'
/// first rows) and this rank's links to its neighbours.
fn cut_rows<'c, C: mpi::traits::Communicator>(
    world: &'c C,
    rows: usize,
    cells: usize,
    what: &str,
) -> (Vec<usize>, sieve::rank_links::RankLinks<'c, C>) {
    let size = world.size() as usize;
    let plane = cells / rows;
    let starts = slab_starts(rows, size, 2);
    assert_eq!(starts.len(), size, "{what}: every rank needs rows");
    let parts: Vec<_> = (0..size)
        .map(|k| starts[k] * plane..starts.get(k + 1).map_or(rows, |&e| e) * plane)
        .collect();
    (starts, sieve::rank_links::RankLinks::new(world, parts))
}

/// One system solved by CG on the ranks' slabs (`sieve_core::flow::cg_slab` with
/// `sieve::rank_links`) against the serial solve on every rank; returns (cases that differ
/// on this rank, seconds on the slabs, seconds serially, iterations).
fn cg_case<const D: usize, const M: usize, C: mpi::traits::Communicator>(
    world: &C,
    sys: &System<D, M>,
    periodic: [bool; D],
    (align, pieces): (usize, Option<usize>),
    pc: sieve_core::flow::cg::Preconditioner,
) -> (i32, f64, f64, u32) {
    use mpi::traits::*;
    use sieve_core::flow::cg::{self, Scratch, Stencil, Stop};
    use sieve_core::flow::cg_slab;
    use sieve_core::flow::cycle_slab::{Fine, Plan};
    let (rank, size) = (world.rank() as usize, world.size() as usize);
    let (grid, n) = (&sys.grid, sys.grid.len());
    let cells = grid.cells();
    let s = grid.stride(D - 1);
    let st = Stencil {
        grid,
        periodic,
        kf: &sys.kf,
    };
    let stop = Stop {
        relative: 1e-10,
        floor: 0.0,
        max_iterations: 500,
        preconditioner: pc,
    };
    let room = cg::workspace_len(cells);
    let mut x = vec![0.0; n];
    let mut v = vec![vec![0.0; n]; 6];
    let mut coarse = vec![0.0; room];
    let t = std::time::Instant::now();
    let serial = {
        let [r, p, ap, pre, line, tmp] = &mut v[..] else {
            unreachable!()
        };
        let sc = Scratch {
            r,
            p,
            ap,
            pre,
            line,
            tmp,
            coarse: &mut coarse,
            part: &mut [],
        };
        cg::solve(&st, &sys.diag, &sys.b, &mut x, sc, stop)
    };
    let serial_time = t.elapsed().as_secs_f64();
    let starts = slab_starts(cells[D - 1], size, align);
    if starts.len() < size {
        eprintln!("mpi_check --cg: {size} ranks do not fit {cells:?} aligned to {align}");
        return (1, 0.0, 0.0, 0);
    }
    let mut plan = Plan::new(cells, periodic, &starts, rank, room).expect("a plan");
    if let Some(m) = pieces {
        plan = plan.with_pieces(m);
    }
    let own = plan.own_range();
    let first = starts[rank] * s;
    let len = plan.padded_len();
    let padded = |src: &[f64], row_below: bool| -> Vec<f64> {
        let mut out = vec![f64::NAN; len];
        plan.pad_from(src, row_below, &mut out);
        out
    };
    let diag = padded(&sys.diag, false);
    let kf: Vec<Vec<f64>> = (0..D)
        .map(|a| padded(&sys.kf[a][..n], a == D - 1))
        .collect();
    let fine = Fine {
        diag: &diag,
        kf: std::array::from_fn(|a| &kf[a][..]),
    };
    let b = padded(&sys.b, false);
    let parts: Vec<std::ops::Range<usize>> = (0..size)
        .map(|k| starts[k] * s..starts.get(k + 1).map_or(n, |&e| e * s))
        .collect();
    let mut links = sieve::rank_links::RankLinks::new(world, parts);
    let mut xs = vec![f64::NAN; len];
    xs[own.clone()].fill(0.0);
    let m = own.len();
    let mut pv: Vec<Vec<f64>> = (0..3).map(|_| vec![f64::NAN; len]).collect();
    let mut ov: Vec<Vec<f64>> = (0..4).map(|_| vec![f64::NAN; m]).collect();
    let mut work = vec![f64::NAN; plan.workspace_len()];
    let [r, p, ap] = &mut pv[..] else {
        unreachable!()
    };
    let [pre, line, tmp, terms] = &mut ov[..] else {
        unreachable!()
    };
    world.barrier();
    let t = std::time::Instant::now();
    let res = cg_slab::solve(
        &plan,
        &mut links,
        &fine,
        &b,
        &mut xs,
        cg_slab::Scratch {
            r,
            p,
            ap,
            pre,
            line,
            tmp,
            terms,
            work: &mut work,
        },
        stop,
    );
    let slab_time = t.elapsed().as_secs_f64();
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    let same = res.iterations == serial.iterations
        && res.relative_residual.to_bits() == serial.relative_residual.to_bits()
        && bits(&xs[own.clone()]) == bits(&x[first..first + m]);
    if !same {
        eprintln!(
            "mpi_check --cg: rank {rank}: {cells:?} periodic {periodic:?} {pc:?}, slabs from {starts:?}: {} iterations, residual {:e}, against the serial {} and {:e}{}",
            res.iterations,
            res.relative_residual,
            serial.iterations,
            serial.relative_residual,
            if bits(&xs[own.clone()]) == bits(&x[first..first + m]) { "" } else { "; x differs" }
        );
    }
    (i32::from(!same), slab_time, serial_time, serial.iterations)
}

/// A cold bed (periodic across) solved with the automatic choice on slabs aligned to 16
/// rows, with whole rows and in the default pieces, and serially: (cases that differ on this
/// rank, [slowest rank's time with whole rows, in pieces, serial time], iterations).
fn timed<const M: usize, C: mpi::traits::Communicator>(
    world: &C,
    sys: &System<2, M>,
) -> (i32, [f64; 3], u32) {
    use mpi::collective::SystemOperation;
    use mpi::traits::*;
    use sieve_core::flow::cg::Preconditioner;
    let (mut bad, mut times, mut iterations) = (0i32, [0.0f64; 3], 0);
    for (k, pieces) in [Some(1), None].into_iter().enumerate() {
        let (b, slab, serial, it) = cg_case(
            world,
            sys,
            [true, false],
            (16, pieces),
            Preconditioner::Auto,
        );
        bad += b;
        world.all_reduce_into(&slab, &mut times[k], SystemOperation::max());
        (times[2], iterations) = (serial, it);
    }
    (bad, times, iterations)
}

/// `--cg-time SIZE`: one cold bed of SIZE x SIZE cells (at most 512) solved on the ranks'
/// slabs (aligned to 16 rows) with whole rows and in the default pieces, and serially, with
/// the automatic choice; prints the times (the slowest rank's) and checks the bits. Returns
/// the exit code.
fn cg_time(size: usize) -> i32 {
    use mpi::traits::*;
    let Some(universe) = mpi::initialize() else {
        eprintln!("mpi_check --cg-time: MPI is already initialised");
        return 1;
    };
    let world = universe.world();
    let size = size.clamp(16, 512);
    let sys = random_system::<2, N_TIMED>([size, size], 3, true);
    let (bad, times, iterations) = timed(&world, &sys);
    let mut all_bad = 0i32;
    world.all_reduce_into(&bad, &mut all_bad, mpi::collective::SystemOperation::sum());
    if world.rank() == 0 {
        println!(
            "mpi_check --cg-time: {size} x {size} cold bed ({iterations} iterations) on {} ranks: {:.1} ms with whole rows, {:.1} ms in pieces, {:.1} ms serially on one; {}",
            world.size(),
            1e3 * times[0],
            1e3 * times[1],
            1e3 * times[2],
            if all_bad == 0 { "the serial bits" } else { "SOME DIFFERENT" }
        );
    }
    drop(universe);
    i32::from(all_bad != 0)
}

/// `--cg`: returns the exit code.
fn conjugate_gradients() -> i32 {
    use mpi::traits::*;
    use sieve_core::flow::cg::Preconditioner;
    let Some(universe) = mpi::initialize() else {
        eprintln!("mpi_check --cg: MPI is already initialised");
        return 1;
    };
    let world = universe.world();
    let (mut bad, mut cases) = (0i32, 0);
    for seed in 1..=2 {
        for pc in [
            Preconditioner::Lines,
            Preconditioner::Multigrid,
            Preconditioner::Auto,
        ] {
            for align in [2, 8] {
                for px in [false, true] {
                    let sys = random_system::<_, N>([24, 40], seed, false);
                    let pieces = Some(1 + seed as usize);
                    bad += cg_case(&world, &sys, [px, false], (align, pieces), pc).0;
                    let sys = random_system::<_, N>([5, 4, 40], seed, false);
                    bad += cg_case(&world, &sys, [px, true, false], (align, pieces), pc).0;
                    let sys = random_system::<_, N>([64, 40], seed, true);
                    bad += cg_case(&world, &sys, [true, false], (align, None), pc).0;
                    cases += 3;
                }
            }
        }
    }
    // one larger solve timed: a cold bed of 128 x 128, the automatic choice, the line
    // pipelines with whole rows and in the default pieces (4)
    let sys = random_system::<_, N>([128, 128], 3, true);
    let (b, times, iterations) = timed(&world, &sys);
    bad += b;
    cases += 2;
    let mut all_bad = 0i32;
    world.all_reduce_into(&bad, &mut all_bad, mpi::collective::SystemOperation::sum());
    if world.rank() == 0 {
        println!(
            "mpi_check --cg: {cases} solves on {} ranks, {}; 128 x 128 cold bed ({iterations} iterations): {:.1} ms across the ranks with whole rows, {:.1} ms in 4 pieces, {:.1} ms serially on one",
            world.size(),
            if all_bad == 0 {
                "iterations, residuals and solutions with the serial bits"
            } else {
                "SOME DIFFERENT"
            },
            1e3 * times[0],
            1e3 * times[1],
            1e3 * times[2]
        );
    }
    drop(universe);
    i32::from(all_bad != 0)
}

/// Capacity of the flows `--flow` steps.
const N_FLOW: usize = 4096;

/// Capacity of the timed coupled runs (`--coupled-time`, up to 128 x 128).
const N_TIME: usize = 16384;

type FlowBox<const D: usize, const M: usize = N_FLOW> = Box<sieve_core::flow::Flow<f64, D, M>>;

/// A prepared flow in a box of friction walls with gravity: a column of `c = 0.6` in the
/// corner below `block`, at rest, or (`seed > 0`) a random state (content from empty to
/// packed, velocities up to 1 m/s); with the implicit pressure if `implicit`.
fn flow_scene<const D: usize>(
    cells: [usize; D],
    h: f64,
    block: [f64; D],
    seed: u64,
    implicit: bool,
) -> FlowBox<D> {
    flow_scene_in(cells, h, block, seed, implicit)
}

/// [`flow_scene`] in a flow of capacity `M`.
fn flow_scene_in<const D: usize, const M: usize>(
    cells: [usize; D],
    h: f64,
    block: [f64; D],
    seed: u64,
    implicit: bool,
) -> FlowBox<D, M> {
    use sieve_core::closure::Material;
    use sieve_core::flow::{Flow, FlowConfig, FlowSide, Slip};
    let mut flow: FlowBox<D, M> = Box::new(Flow::zeroed());
    let grid =
        sieve_core::Grid::new(cells, [0.0; D], cells.map(|c| c as f64 * h), M).expect("grid");
    let mut cfg = FlowConfig::new(Material::glass_beads());
    cfg.free_surface_push = true;
    cfg.gravity[D - 1] = -9.81;
    if implicit {
        cfg.pressure = sieve_core::flow::PressureMode::Implicit;
    }
    let wall = FlowSide::wall(Slip::Friction(0.5));
    flow.setup(grid, [[wall, wall]; D], cfg).expect("setup");
    let c_max = (1.0 - cfg.margin) * cfg.material.phi_rcp;
    let mut state = seed;
    for i in 0..grid.len() {
        let x = grid.center(i);
        let (c, u) = if seed == 0 {
            let inside = (0..D).all(|a| x[a] < block[a]);
            (if inside { 0.6 } else { 0.0 }, [0.0; D])
        } else {
            let c = c_max * lcg(&mut state);
            (c, std::array::from_fn(|_| 2.0 * lcg(&mut state) - 1.0))
        };
        flow.set_cell(i, c, u, 0.0);
    }
    flow.prepare().expect("prepare");
    flow
}

/// `steps` steps of the flow `make` builds on this rank's slab of rows (the ranks cut the
/// rows evenly at even rows) and serially, compared after every step; returns (1 if this
/// rank saw a difference, seconds of the slab steps, seconds of the serial ones).
fn flow_case<const D: usize, C: mpi::traits::Communicator>(
    world: &C,
    make: &dyn Fn() -> FlowBox<D>,
    steps: usize,
    what: &str,
) -> (i32, f64, f64) {
    use sieve_core::flow::slab::{load_slab, Slab};
    use sieve_core::fork::Serial;
    let (rank, size) = (world.rank() as usize, world.size() as usize);
    let mut whole = make();
    let (starts, mut links) = cut_rows(world, whole.grid().cells()[D - 1], whole.len(), what);
    let mut flow: FlowBox<D> = Box::new(sieve_core::flow::Flow::zeroed());
    let plan = match load_slab(&*whole, &starts, rank, &mut *flow) {
        Ok(p) => p,
        Err(e) => {
            eprintln!("mpi_check --flow: {what}: rank {rank}: {e}");
            return (1, 0.0, 0.0);
        }
    };
    let mut memory = vec![0.0; plan.memory_len()];
    let mut slab = Slab::new(&plan, &mut links, &mut memory);
    let (own, global) = (plan.owned_cells(), plan.global_cells());
    let (mut on_slabs, mut serial) = (0.0, 0.0);
    for step in 1..=steps {
        let t = std::time::Instant::now();
        let dt = whole.stable_dt();
        whole.step(dt);
        serial += t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        let dt_slab = flow.stable_dt_reaching(&mut slab);
        flow.step_reaching(dt_slab, &Serial, &mut slab);
        on_slabs += t.elapsed().as_secs_f64();
        let mut first = None;
        if dt_slab.to_bits() != dt.to_bits() {
            first = Some("the step".to_string());
        }
        whole.for_each_state_array(|name, all| {
            flow.for_each_state_array(|mine_name, mine| {
                if first.is_some() || mine_name != name {
                    return;
                }
                let (m, a) = (&mine[own.clone()], &all[global.clone()]);
                if let Some(j) = (0..m.len()).find(|&j| m[j].to_bits() != a[j].to_bits()) {
                    first = Some(format!("{name} at cell {}", global.start + j));
                }
            });
        });
        if first.is_none() && flow.last_cg_iterations() != whole.last_cg_iterations() {
            first = Some("the CG iterations".into());
        }
        if first.is_none() && flow.residual().to_bits() != whole.residual().to_bits() {
            first = Some("the residual".into());
        }
        if let Some(f) = first {
            eprintln!("mpi_check --flow: {what} on {size} ranks: rank {rank} left the serial run at step {step}: {f}");
            return (1, on_slabs, serial);
        }
    }
    (0, on_slabs, serial)
}

/// The ranks' verdict: how many saw a difference, and the slowest rank's seconds.
fn across<C: mpi::traits::Communicator>(world: &C, bad: i32, seconds: f64) -> (i32, f64) {
    use mpi::collective::{CommunicatorCollectives, SystemOperation};
    let (mut all_bad, mut slowest) = (0i32, 0.0f64);
    world.all_reduce_into(&bad, &mut all_bad, SystemOperation::sum());
    world.all_reduce_into(&seconds, &mut slowest, SystemOperation::max());
    (all_bad, slowest)
}

/// `--flow`: returns the exit code.
fn flow_slabs() -> i32 {
    slab_cases(
        "--flow",
        "every state array, step, residual and CG count",
        |world, _, make: &dyn Fn() -> FlowBox<2>, steps, what| flow_case(world, make, steps, what),
        |world, make: &dyn Fn() -> FlowBox<3>, steps, what| flow_case(world, make, steps, what),
    )
}

/// The flows of `--flow` and `--coupled` on this rank's slab, by `case_2d` and `case_3d` (the
/// random states' seed, the scene, its steps and its name; each returns what
/// [`flow_case`] does): a collapse for 120 steps and 4 random states of 4 steps, each with
/// the explicit and the implicit pressure, a 3D collapse for 40 steps, and a 64 x 64
/// collapse timed over 50. Prints the verdict on rank 0 and returns the exit code.
fn slab_cases<C2, C3>(flag: &str, compared: &str, case_2d: C2, case_3d: C3) -> i32
where
    C2: Fn(
        &mpi::topology::SimpleCommunicator,
        u64,
        &dyn Fn() -> FlowBox<2>,
        usize,
        &str,
    ) -> (i32, f64, f64),
    C3: Fn(
        &mpi::topology::SimpleCommunicator,
        &dyn Fn() -> FlowBox<3>,
        usize,
        &str,
    ) -> (i32, f64, f64),
{
    use mpi::traits::*;
    let Some(universe) = mpi::initialize() else {
        eprintln!("mpi_check {flag}: MPI is already initialised");
        return 1;
    };
    let world = universe.world();
    let mut bad = 0;
    for implicit in [false, true] {
        let collapse = || flow_scene([20, 24], 0.005, [0.05, 0.09], 0, implicit);
        bad += case_2d(&world, 0, &collapse, 120, "2D collapse").0;
        for seed in 1..=4 {
            let random = || flow_scene([12, 24], 0.005, [0.0; 2], seed, implicit);
            bad += case_2d(&world, seed, &random, 4, "2D random state").0;
        }
    }
    let collapse_3d = || flow_scene([6, 5, 16], 0.005, [0.015, 0.02, 0.06], 0, false);
    bad += case_3d(&world, &collapse_3d, 40, "3D collapse").0;
    let timed = || flow_scene([64, 64], 0.0025, [0.08, 0.12], 0, false);
    let (b, slabs, serial) = case_2d(&world, 0, &timed, 50, "64 x 64 collapse");
    let (all_bad, slowest) = across(&world, bad + b, slabs);
    if world.rank() == 0 {
        println!(
            "mpi_check {flag}: 13 runs (explicit and implicit pressure) on {} ranks, {}; 64 x 64 collapse: {:.2} ms per step across the ranks, {:.2} ms serially on one",
            world.size(),
            if all_bad == 0 {
                format!("{compared} with the serial bits after every step")
            } else {
                "SOME DIFFERENT".into()
            },
            1e3 * slowest / 50.0,
            1e3 * serial / 50.0
        );
    }
    drop(universe);
    i32::from(all_bad != 0)
}

type SegBox<const D: usize, const M: usize = N_FLOW> = Box<sieve_core::Segregation<f64, D, M>>;

/// The segregation of a coupled run on `flow`'s grid (the direction from the flow, fines in
/// the upper half or, with `seed > 0`, at random fractions), coupled with back-coupled
/// packing limits and a flush floor of 1e-9 (so that the flush runs at the cuts).
fn coupled_scene<const D: usize, const M: usize>(
    flow: &sieve_core::flow::Flow<f64, D, M>,
    seed: u64,
) -> (SegBox<D, M>, sieve_core::flow::coupled::CouplingConfig<f64>) {
    use sieve_core::flow::coupled::{CouplingConfig, Mode};
    use sieve_core::segregation::{DirectionMode, SegregationConfig};
    let grid = *flow.grid();
    let mut cfg = SegregationConfig::new();
    cfg.s0 = 0.2;
    cfg.gravity[D - 1] = -9.81;
    cfg.direction = DirectionMode::Flow;
    cfg.flush_below = 1e-9;
    let mut seg: SegBox<D, M> = Box::new(sieve_core::Segregation::zeroed());
    seg.setup(grid, [[sieve_core::Boundary::Wall; 2]; D], cfg)
        .expect("segregation setup");
    let rows = grid.cells()[D - 1];
    let mut state = seed;
    for i in 0..grid.len() {
        let c = flow.c(i);
        let fines = match seed {
            0 if grid.coord(i, D - 1) >= rows / 2 => 0.7,
            0 => 0.2,
            _ => lcg(&mut state),
        };
        seg.set_cell(i, c, flow.temperature(i), flow.velocity(i), fines * c);
    }
    let mut coupling = CouplingConfig::new(Mode::Coupled);
    coupling.packing = sieve_core::closure::Packing::FitHalf;
    (seg, coupling)
}

/// [`flow_case`] for the coupled step (flow and segregation, `Coupled::step_with_reaching`):
/// every state array of both solvers, the step, the flush counter and the guard's total
/// compared after every step (the slabs alone, for timing and profiles, without `compare`);
/// returns (1 if this rank saw a difference, seconds of the slab
/// steps, seconds of the serial ones).
fn coupled_case<const D: usize, const M: usize, C: mpi::traits::Communicator>(
    world: &C,
    seed: u64,
    make: &dyn Fn() -> FlowBox<D, M>,
    steps: usize,
    what: &str,
    compare: bool,
) -> (i32, f64, f64) {
    use sieve_core::flow::coupled::Coupled;
    use sieve_core::flow::coupled_slab::load_coupled_slab;
    use sieve_core::flow::slab::Slab;
    use sieve_core::fork::Serial;
    let (rank, size) = (world.rank() as usize, world.size() as usize);
    let mut flow_all = make();
    let (mut seg_all, coupling) = coupled_scene(&flow_all, seed);
    let mut whole = Coupled::new(&mut flow_all, &mut seg_all, coupling).expect("coupled");
    let rows = whole.flow.grid().cells()[D - 1];
    let (starts, mut links) = cut_rows(world, rows, whole.flow.len(), what);
    let mut flow: FlowBox<D, M> = Box::new(sieve_core::flow::Flow::zeroed());
    let mut seg: SegBox<D, M> = Box::new(sieve_core::Segregation::zeroed());
    let plan = match load_coupled_slab(&whole, &starts, rank, &mut flow, &mut seg, None) {
        Ok(p) => p,
        Err(e) => {
            eprintln!("mpi_check --coupled: {what}: rank {rank}: {e}");
            return (1, 0.0, 0.0);
        }
    };
    let mut memory = vec![0.0; plan.memory_len()];
    let mut slab = Slab::new(&plan, &mut links, &mut memory);
    let mut cpl = match Coupled::on_slab(&mut flow, &mut seg, whole.slab_start(), None, &mut slab) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("mpi_check --coupled: {what}: rank {rank}: {e}");
            return (1, 0.0, 0.0);
        }
    };
    let (own, global) = (plan.owned_cells(), plan.global_cells());
    let (mut on_slabs, mut serial) = (0.0, 0.0);
    for step in 1..=steps {
        if !compare {
            // timing alone (`--coupled-time`): the slabs' steps, nothing serial
            let t = std::time::Instant::now();
            let dt = cpl.stable_dt_reaching(&mut slab);
            let ok = cpl.step_with_reaching(dt, &Serial, &mut slab).is_ok();
            on_slabs += t.elapsed().as_secs_f64();
            if !ok {
                return (1, on_slabs, serial);
            }
            continue;
        }
        let t = std::time::Instant::now();
        let dt = whole.stable_dt();
        let ok_whole = whole.step_with(dt).is_ok();
        serial += t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        let dt_slab = cpl.stable_dt_reaching(&mut slab);
        let ok_slab = cpl.step_with_reaching(dt_slab, &Serial, &mut slab).is_ok();
        on_slabs += t.elapsed().as_secs_f64();
        let mut first = None;
        if !(ok_whole && ok_slab) {
            first = Some(format!(
                "a refused step (serial {ok_whole}, slab {ok_slab})"
            ));
        } else if dt_slab.to_bits() != dt.to_bits() {
            first = Some("the step".to_string());
        }
        let mut compare = |name: &str, mine: &[f64], all: &[f64]| {
            let (m, a) = (&mine[own.clone()], &all[global.clone()]);
            if let (None, Some(j)) = (
                &first,
                (0..m.len()).find(|&j| m[j].to_bits() != a[j].to_bits()),
            ) {
                first = Some(format!("{name} at cell {}", global.start + j));
            }
        };
        whole.flow.for_each_state_array(|name, all| {
            cpl.flow.for_each_state_array(|n, mine| {
                if n == name {
                    compare(name, mine, all);
                }
            });
        });
        whole.seg.for_each_state_array(|name, all| {
            cpl.seg.for_each_state_array(|n, mine| {
                if n == name {
                    compare(name, mine, all);
                }
            });
        });
        let counters = |c: &Coupled<'_, f64, D, M>| {
            [c.seg.flushed_tracked(), c.guarded_mass()].map(f64::to_bits)
        };
        if first.is_none() && counters(&cpl) != counters(&whole) {
            first = Some("the flush counter or the guard's total".into());
        }
        if let Some(f) = first {
            eprintln!("mpi_check --coupled: {what} on {size} ranks: rank {rank} left the serial run at step {step}: {f}");
            return (1, on_slabs, serial);
        }
    }
    (0, on_slabs, serial)
}

/// `--coupled`: returns the exit code.
fn coupled_slabs() -> i32 {
    slab_cases(
        "--coupled",
        "every state array of both solvers, step and counter",
        |world, seed, make: &dyn Fn() -> FlowBox<2>, steps, what| {
            coupled_case(world, seed, make, steps, what, true)
        },
        |world, make: &dyn Fn() -> FlowBox<3>, steps, what| {
            coupled_case(world, 0, make, steps, what, true)
        },
    )
}

/// `--coupled-time SIZE [alone]`: 50 coupled steps of a SIZE x SIZE mixed collapse (16 to
/// 128) on the ranks' slabs, against the serial steps (the bits compared after every step),
/// or on the slabs `alone` (for profiles: `perf record` per rank); prints the slowest rank's
/// time per step and the serial one. Runs on a thread with room for the solvers.
fn coupled_time(size: usize, alone: bool) -> i32 {
    use mpi::traits::*;
    let Some(universe) = mpi::initialize() else {
        eprintln!("mpi_check --coupled-time: MPI is already initialised");
        return 1;
    };
    let size = size.clamp(16, 128);
    let stack = 8 * std::mem::size_of::<sieve_core::flow::Flow<f64, 2, N_TIME>>() + (64 << 20);
    let code = std::thread::scope(|scope| {
        std::thread::Builder::new()
            .stack_size(stack)
            .spawn_scoped(scope, || {
                let world = mpi::topology::SimpleCommunicator::world();
                let h = 0.16 / size as f64;
                let timed = || flow_scene_in::<2, N_TIME>([size, size], h, [0.08, 0.12], 0, false);
                let (b, slabs, serial) =
                    coupled_case(&world, 0, &timed, 50, "timed collapse", !alone);
                let (all_bad, slowest) = across(&world, b, slabs);
                if world.rank() == 0 {
                    println!(
                        "mpi_check --coupled-time: {size} x {size} mixed collapse on {} ranks: {:.3} ms per step across the ranks{}",
                        world.size(),
                        1e3 * slowest / 50.0,
                        if alone {
                            String::new()
                        } else if all_bad == 0 {
                            format!(", {:.3} ms serially on one, the same bits", 1e3 * serial / 50.0)
                        } else {
                            ", SOME DIFFERENT from the serial steps".into()
                        }
                    );
                }
                i32::from(all_bad != 0)
            })
            .expect("a solver thread")
            .join()
            .unwrap_or(1)
    });
    drop(universe);
    code
}

fn main() {
    let mut args = std::env::args().skip(1);
    let name = args.next().unwrap_or_else(|| "shear-cell-inverse".into());
    if name == "--same-vti" {
        let (a, b) = (
            args.next().unwrap_or_default(),
            args.next().unwrap_or_default(),
        );
        match same_vti(&a, &b) {
            Ok(m) => println!("{m}"),
            Err(m) => {
                eprintln!("{m}");
                std::process::exit(1);
            }
        }
        return;
    }
    if name == "--sums" {
        std::process::exit(sums());
    }
    if name == "--lines" {
        std::process::exit(lines());
    }
    if name == "--cg" {
        std::process::exit(conjugate_gradients());
    }
    if name == "--flow" {
        std::process::exit(flow_slabs());
    }
    if name == "--coupled" {
        std::process::exit(coupled_slabs());
    }
    if name == "--coupled-time" {
        let size = args.next().and_then(|a| a.parse().ok()).unwrap_or(64);
        let alone = args.next().as_deref() == Some("alone");
        std::process::exit(coupled_time(size, alone));
    }
    if name == "--cg-time" {
        let size = args.next().and_then(|a| a.parse().ok()).unwrap_or(256);
        std::process::exit(cg_time(size));
    }
    let sets: Vec<String> = args.collect();
    let launched = match sieve::parallel_mpi::launch() {
        Ok(true) => true,
        Ok(false) => {
            eprintln!("mpi_check: run it under mpirun with at least 2 ranks");
            std::process::exit(2);
        }
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(1);
        }
    };
    let result = sieve::scene::load(&name, &sets)
        .and_then(|(scene, fields)| sieve::mpi_jobs::check_scene(&scene, &fields));
    let check = match &result {
        Ok(c) => Ok(Some(c.clone())),
        Err(e) => Err(e.clone()),
    };
    let r = sieve::parallel_mpi::finish(result.map(|_| ()));
    let _ = launched;
    match (check, r) {
        (Ok(Some(c)), Ok(())) if c.hash == 0 && c.serial == 0 => {} // not rank 0
        (Ok(Some(c)), Ok(())) => {
            let same = c.hash == c.serial;
            println!(
                "{name}: {} ranks, {} steps, state hash {:016x}, serial {:016x}: {}",
                c.ranks,
                c.steps,
                c.hash,
                c.serial,
                if same { "same" } else { "DIFFERENT" }
            );
            if !same {
                std::process::exit(1);
            }
        }
        (_, Err(e)) | (Err(e), _) => {
            if !sieve::parallel_mpi::silent() {
                eprintln!("{e}");
            }
            std::process::exit(e.exit_code());
        }
        (Ok(None), Ok(())) => {}
    }
}
