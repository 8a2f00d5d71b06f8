//! `mpirun -np K target/release/examples/mpi_check SCENE [KEY=VALUE ...]`: runs the scene's
//! segregation to its end time on K MPI ranks (one subdomain each, the driver of `sieve run`
//! under mpirun) and serially on rank 0, and exits 0 if the state hashes are the same, 1 if
//! not (docs/parallel.md, `.ci/mpi-check`).
//!
//! `mpi_check --same-vti A B` (no mpirun): reads two snapshots (`.vti`, or `.pvti` with its
//! pieces, which must cover the grid exactly once) and exits 0 if they hold the same grid,
//! time and arrays to the bit, 1 if not.
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
