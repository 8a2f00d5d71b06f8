//! The coupled flow on threads (issue 12; core/src/fork.rs, docs/parallel.md "The coupled
//! flow on threads"): a silo discharge, a hopper of cut cells and the 3D silo between
//! friction walls give the same state, bit for bit, after every step, whether the linear
//! solves' loops run on one thread or are cut into 2, 3 or 4 parts on the pool of `sieve run
//! --threads` (host/src/pool.rs; cut down to 64 cells a part, so that these small grids are
//! cut in odd places), and at every vector width the CPU has (host/src/isa.rs). A difference
//! names the first step where the two runs part.

use crate::silo_common::{discharge_on, Spec, N};
use sieve::isa::Level;
use sieve_core::flow::coupled::Coupled;
use sieve_core::fork::{Fork, Serial};

/// FNV-1a over the bits of everything a step carries forward.
fn state_bits<const D: usize>(cpl: &Coupled<'_, f64, D, N>) -> u64 {
    let mut h: u64 = 0xcbf29ce484222325;
    let mut eat = |v: f64| {
        for b in v.to_bits().to_le_bytes() {
            h = (h ^ u64::from(b)).wrapping_mul(0x100000001b3);
        }
    };
    for i in 0..cpl.flow.len() {
        for v in [
            cpl.flow.c(i),
            cpl.flow.temperature(i),
            cpl.flow.pressure(i),
            cpl.seg.c(i),
            cpl.seg.phi(i),
        ] {
            eat(v);
        }
        for v in cpl.flow.velocity(i) {
            eat(v);
        }
    }
    eat(cpl.seg.time());
    h
}

/// The state bits after every step of `spec` on `fork`, and the CG iterations.
fn run<const D: usize, F: Fork>(spec: Spec<D>, fork: &F) -> (Vec<u64>, u64) {
    let mut bits = Vec::new();
    let mut iterations = 0;
    discharge_on(
        spec,
        fork,
        |c| iterations = c.flow.cg_iterations(),
        |c| bits.push(state_bits(c)),
    );
    (bits, iterations)
}

fn check<const D: usize>(spec: Spec<D>, what: &str) {
    let (serial, iterations) = run(spec, &Serial);
    assert!(
        serial.len() >= 20 && iterations > 100,
        "{what}: {} steps, {iterations} CG iterations",
        serial.len()
    );
    for parts in 2..=4 {
        let pool = sieve::pool::Pool::new(parts)
            .expect("threads")
            .cutting_down_to(64);
        let (threaded, _) = pool.install(|| run(spec, &pool));
        let first = serial.iter().zip(&threaded).position(|(a, b)| a != b);
        assert_eq!(
            first, None,
            "{what}, {parts} parts: the first step that differs"
        );
        assert_eq!(threaded.len(), serial.len(), "{what}, {parts} parts: steps");
    }
    // Every stage's hot loops at every vector width this CPU has (`Fork::Isa`,
    // docs/simd.md): the percolation, the carried transport, the prepare, the flow's
    // transport and solves compiled for AVX2 or AVX-512 give the serial bits, on one thread
    // and on two parts. (In a build for the local CPU every level is that CPU's code; the
    // comparison bites in a portable build, as docs/simd.md runs it.)
    let pool = sieve::pool::Pool::new(2)
        .expect("threads")
        .cutting_down_to(64);
    for level in [Level::Baseline, Level::Avx2, Level::Avx512] {
        if !level.available() {
            eprintln!("note: this CPU has no {}: not compared", level.name());
            continue;
        }
        let (one, _) = sieve::on_level!(level, &Serial, |f| run(spec, f));
        let (two, _) = pool.install(|| sieve::on_level!(level, &pool, |f| run(spec, f)));
        for (bits, on) in [(one, "1 thread"), (two, "2 parts")] {
            let first = serial.iter().zip(&bits).position(|(a, b)| a != b);
            let at = format!("{what}, {} on {on}", level.name());
            assert_eq!(first, None, "{at}: the first step that differs");
            assert_eq!(bits.len(), serial.len(), "{at}: steps");
        }
    }
}

fn silo<const D: usize>(cells: [usize; D], depth: f64, hopper: Option<f64>, t_end: f64) -> Spec<D> {
    Spec {
        cells,
        height: 0.5,
        depth,
        fill: 0.4,
        orifice: 0.04,
        hopper,
        hopper_z: 0.01,
        t_end,
        every: t_end,
    }
}

#[test]
fn a_silo_discharge_has_the_serial_bits_on_threads() {
    sieve_tests::run_big(|| check(silo([29, 100], 0.0, None, 0.003), "silo 29 x 100"));
}

#[test]
fn a_hopper_of_cut_cells_has_the_serial_bits_on_threads() {
    sieve_tests::run_big(|| check(silo([30, 50], 0.0, Some(30.0), 0.005), "hopper 30 x 50"));
}

#[test]
fn a_3d_silo_has_the_serial_bits_on_threads() {
    sieve_tests::run_big(|| check(silo([15, 4, 30], 0.04, None, 0.005), "3D silo 15 x 4 x 30"));
}
