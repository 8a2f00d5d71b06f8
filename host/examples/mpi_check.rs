//! `mpirun -np K target/release/examples/mpi_check SCENE [KEY=VALUE ...]`: runs the scene's
//! segregation to its end time on K MPI ranks (one subdomain each) and serially on rank 0,
//! and exits 0 if the state hashes are the same, 1 if not (docs/parallel.md, `.ci/mpi-check`).
//! Needs the `mpi` feature (OpenMPI: `apt-get install libopenmpi-dev openmpi-bin libclang-dev`).

fn main() {
    let mut args = std::env::args().skip(1);
    let name = args.next().unwrap_or_else(|| "shear-cell-inverse".into());
    let sets: Vec<String> = args.collect();
    let (scene, fields) = match sieve::scene::load(&name, &sets) {
        Ok(x) => x,
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(2);
        }
    };
    match sieve::parallel_mpi::check_scene(&scene, &fields) {
        Ok(c) if c.hash == 0 && c.serial == 0 => {} // not rank 0
        Ok(c) => {
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
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(1);
        }
    }
}
