//! The implicit solver of the flow (core/src/flow/cg.rs): conjugate gradients preconditioned by
//! exact solves along the vertical grid lines. In 1D the preconditioner is the inverse of A,
//! so CG must stop after one iteration; in 2D and 3D (periodic and not) it must solve A x = b
//! to the requested residual for strongly anisotropic, widely varying coefficients (the
//! yield viscosity of a cold bed spans many orders of magnitude).

use proptest::prelude::*;
use sieve_core::flow::cg::{solve, Scratch, Stencil, Stop};
use sieve_core::Grid;

const N: usize = 512;

/// A deterministic pseudo-random sequence in [0, 1).
fn lcg(seed: &mut u64) -> f64 {
    *seed = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    (*seed >> 11) as f64 / (1u64 << 53) as f64
}

/// Solves a random system to a recursive residual of 1e-10 and returns (iterations, the true
/// `|A x - b| / |b|`, recomputed independently; it sits above 1e-10 by the round-off of the
/// recursion, which grows with the condition number, here up to ~1e10).
fn random_system<const D: usize>(cells: [usize; D], periodic: [bool; D], seed: u64) -> (u32, f64) {
    let grid = Grid::new(cells, [0.0; D], [1.0; D], N).unwrap();
    let n = grid.len();
    let mut s = seed;
    let mut kf = [[0.0f64; N]; D];
    for (a, k) in kf.iter_mut().enumerate() {
        for v in k[..n].iter_mut() {
            // 10 decades of coefficient, stronger along the last axis
            let scale = if a + 1 == D { 1e3 } else { 1.0 };
            *v = scale * 10f64.powf(10.0 * lcg(&mut s) - 5.0);
        }
    }
    let diag: Vec<f64> = (0..N).map(|_| 1e-3 + lcg(&mut s)).collect();
    let b: Vec<f64> = (0..N).map(|_| lcg(&mut s) - 0.5).collect();
    let st = Stencil {
        grid: &grid,
        periodic,
        kf: &kf,
    };
    let mut x = vec![0.0; N];
    let (mut r, mut p, mut ap, mut pre, mut line) = (
        vec![0.0; N],
        vec![0.0; N],
        vec![0.0; N],
        vec![0.0; N],
        vec![0.0; N],
    );
    let res = solve(
        &st,
        &diag,
        &b,
        &mut x,
        Scratch {
            r: &mut r,
            p: &mut p,
            ap: &mut ap,
            pre: &mut pre,
            line: &mut line,
        },
        Stop {
            relative: 1e-10,
            floor: 0.0,
            max_iterations: 2000,
        },
    );
    let mut ax = vec![0.0; N];
    st.apply(&diag, &x, &mut ax);
    let (mut rr, mut bb) = (0.0, 0.0);
    for i in 0..n {
        rr += (ax[i] - b[i]).powi(2);
        bb += b[i] * b[i];
    }
    assert!(
        res.iterations < 2000 && res.relative_residual <= 1e-10,
        "{res:?}"
    );
    (res.iterations, (rr / bb).sqrt())
}

#[test]
fn line_preconditioner_is_exact_in_1d() {
    for seed in 1..20 {
        let (it, rel) = random_system([200], [false], seed);
        // one iteration is the exact solve; a second one polishes its round-off
        assert!(it <= 2, "seed {seed}: {it} iterations");
        assert!(rel < 1e-8, "seed {seed}: residual {rel}");
    }
}

#[test]
fn periodic_vertical_lines_still_converge_in_1d() {
    // The wrap face is left out of the line factor, so a periodic line needs a few iterations.
    let (it, rel) = random_system([200], [true], 3);
    assert!(it <= 10, "{it} iterations");
    assert!(rel < 1e-8, "residual {rel}");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]
    #[test]
    fn solves_2d_and_3d_systems(seed in 1u64..1_000_000, px: bool, pz: bool) {
        let (it, rel) = random_system([16, 32], [px, pz], seed);
        prop_assert!(rel < 1e-7, "2D residual {} after {} iterations", rel, it);
        let (it, rel) = random_system([8, 4, 16], [px, false, pz], seed);
        prop_assert!(rel < 1e-7, "3D residual {} after {} iterations", rel, it);
    }
}
