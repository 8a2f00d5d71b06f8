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
    const N: usize = 4096;
    let (rank, size) = (world.rank() as usize, world.size() as usize);
    let grid = sieve_core::Grid::<f64, D>::new(cells, [0.0; D], [1.0; D], N).expect("grid");
    let n = grid.len();
    let s = grid.stride(D - 1);
    let mut r = seed;
    let mut kf = Box::new([[0.0f64; N]; D]);
    for (a, k) in kf.iter_mut().enumerate() {
        for v in k[..n].iter_mut() {
            let scale = if a + 1 == D { 1e3 } else { 1.0 };
            *v = scale * 10f64.powf(10.0 * lcg(&mut r) - 5.0);
        }
    }
    let diag: Vec<f64> = (0..N).map(|_| 1e-3 + lcg(&mut r)).collect();
    let b: Vec<f64> = (0..N).map(|_| lcg(&mut r) - 0.5).collect();
    let st = Stencil {
        grid: &grid,
        periodic,
        kf: &kf,
    };
    let (mut inv_d, mut l, mut z) = (vec![0.0; N], vec![0.0; N], vec![0.0; N]);
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
    let mut m = vec![0.0; N];
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
