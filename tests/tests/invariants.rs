//! Invariants of the segregation step and of the face fluxes: mass conservation to round-off,
//! mirror symmetry under flipping gravity, consistency of every numerical flux, the closed-form
//! Godunov flux against its definition, and phase independence of the modified scheme.

use crate::common;

use crate::common::{boxed, column, column_with_gravity, config, phis, Column, N1};
use proptest::prelude::*;
use sieve_core::segregation::flux;
use sieve_core::{diagnose, Boundary, DirectionMode, Grid, Phase, Scheme, Segregation};

/// 2D capacity of the shear-cell tests (64 x 64).
const N_CELL: usize = 4096;

/// The idealised shear cell (model.md 7.3) on the unit square: periodic in x, walls at z = 0
/// and 1, c = 0.64, u = (2z - 1, 0), T = 1, direction from the flow, gravity (0, `gz`);
/// inversely graded start (small grains above z = 1/2), optionally mirrored in z.
fn shear_cell(
    scheme: Scheme,
    phase: Phase,
    gz: f64,
    mirrored: bool,
) -> Box<Segregation<f64, 2, N_CELL>> {
    let n = 64;
    let mut s = boxed::<f64, 2, N_CELL>();
    let grid = Grid::new([n, n], [0.0, 0.0], [1.0, 1.0], N_CELL).unwrap();
    let bc = [[Boundary::Periodic; 2], [Boundary::Wall; 2]];
    s.setup(
        grid,
        bc,
        config(scheme, phase, [0.0, gz], DirectionMode::Flow),
    )
    .unwrap();
    for i in 0..grid.len() {
        let [x, z] = grid.center(i);
        // The mirror image of height z is 1 - z; the x-dependence keeps the test from being 1D.
        let zm = if mirrored { 1.0 - z } else { z };
        let phihat = if zm > 0.5 + 0.1 * (6.0 * x).sin() {
            1.0
        } else {
            0.0
        };
        s.set_cell(i, 0.64, 1.0, [2.0 * zm - 1.0, 0.0], 0.64 * phihat);
    }
    s.prepare().unwrap();
    s
}

/// Round-off bound of the small-phase mass drift after `steps` steps (see `bounds.rs`,
/// `check_run`, for the derivation): n N (2D^2 + 1) eps c_max |C| + 2 N^2 eps c_max |C|.
fn mass_bound<const D: usize, const N: usize>(s: &Segregation<f64, D, N>) -> f64 {
    let n = s.len() as f64;
    let c_max = (0..s.len()).map(|i| s.c(i)).fold(0.0, f64::max);
    let dd = D as f64;
    f64::EPSILON
        * c_max
        * s.grid().cell_volume()
        * n
        * (s.steps() as f64 * (2.0 * dd * dd + 1.0) + 2.0 * n)
}

#[test]
fn mass_is_conserved_to_round_off() {
    for scheme in Scheme::ALL {
        for phase in [Phase::Small, Phase::Large] {
            let mut s = column::<f64>(Column::B, 400, scheme, phase);
            let m0 = diagnose(&*s).mass_small;
            s.advance_to(2.0, u64::MAX);
            let drift = (diagnose(&*s).mass_small - m0).abs();
            let bound = mass_bound(&*s);
            println!(
                "column-b 400 cells {} {phase:?}: |mass drift| {drift:.3e} (relative {:.3e}), bound {bound:.3e}, {} steps",
                scheme.name(),
                drift / m0,
                s.steps()
            );
            assert!(drift <= bound, "drift {drift:e} > {bound:e}");

            let mut s = shear_cell(scheme, phase, -1.0, false);
            let m0 = diagnose(&*s).mass_small;
            s.advance_to(1.0, u64::MAX);
            let drift = (diagnose(&*s).mass_small - m0).abs();
            let bound = mass_bound(&*s);
            println!(
                "shear cell 64x64 {} {phase:?}: |mass drift| {drift:.3e} (relative {:.3e}), bound {bound:.3e}, {} steps",
                scheme.name(),
                drift / m0,
                s.steps()
            );
            assert!(drift <= bound, "drift {drift:e} > {bound:e}");
        }
    }
}

#[test]
fn flipping_gravity_mirrors_a_column() {
    // Mirror image of column b: c and T of height 1 - z, gravity +1. For the modified and the
    // Godunov flux the mirrored face fluxes are the exact negatives of the original ones (k
    // flips sign exactly, the convex and concave formulas are negatives of each other) and each
    // cell adds its two face terms in swapped order, which IEEE addition does not notice: the
    // states agree bit for bit. The upwind flux evaluates its Roe speed -k (c - q_L - q_R) with
    // q_L and q_R swapped, which rounds differently: there the agreement is to round-off.
    for scheme in Scheme::ALL {
        for phase in [Phase::Small, Phase::Large] {
            let n = 200;
            let mut down = column::<f64>(Column::B, n, scheme, phase);
            let mut up = boxed::<f64, 1, N1>();
            let grid = *down.grid();
            let mut cfg = *down.config();
            cfg.gravity = [1.0];
            up.setup(grid, *down.boundaries(), cfg).unwrap();
            for i in 0..n {
                let j = n - 1 - i;
                up.set_cell(i, down.c(j), down.temperature(j), [0.0], down.phi(j));
            }
            up.prepare().unwrap();
            down.advance_to(0.7, u64::MAX);
            up.advance_to(0.7, u64::MAX);
            let mut worst = 0.0f64;
            for i in 0..n {
                let (a, b) = (down.phi(i), up.phi(n - 1 - i));
                worst = worst.max((a - b).abs());
                if scheme != Scheme::Upwind {
                    assert_eq!(
                        a.to_bits(),
                        b.to_bits(),
                        "{scheme:?} {phase:?} cell {i}: {a} vs {b}"
                    );
                }
            }
            println!(
                "column b {} {phase:?}: mirror max |phi difference| {worst:.3e}",
                scheme.name()
            );
            assert!(
                worst <= 1e-14,
                "{scheme:?} {phase:?}: mirror differs by {worst:e}"
            );
        }
    }
}

#[test]
fn flipping_gravity_mirrors_a_shear_cell() {
    // In 2D a cell sums four face terms, and mirroring changes the order in which the two z
    // terms meet the x terms, so agreement is to round-off, not bit-exact (measured: 1e-16).
    for phase in [Phase::Small, Phase::Large] {
        let mut down = shear_cell(Scheme::Modified, phase, -1.0, false);
        let mut up = shear_cell(Scheme::Modified, phase, 1.0, true);
        down.advance_to(0.5, u64::MAX);
        up.advance_to(0.5, u64::MAX);
        let [nx, nz] = down.grid().cells();
        let mut worst = 0.0f64;
        for i in 0..nx * nz {
            let (ix, iz) = (i % nx, i / nx);
            let j = ix + nx * (nz - 1 - iz);
            worst = worst.max((down.phi(i) - up.phi(j)).abs());
        }
        println!("shear cell {phase:?}: mirror max |phi difference| {worst:.3e}");
        assert!(worst <= 1e-14, "mirror symmetry broken by {worst:e}");
    }
}

/// `h sum |a_i - b_i|`, the L1 distance of two states on a grid of `n` cells of the unit box.
fn l1_distance(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum::<f64>() / a.len() as f64
}

/// Round-off allowance for two runs of the same scheme that differ only in rounding. The
/// scheme is conservative and monotone under the Courant condition, hence L1-contractive
/// (Crandall–Tartar): rounding added in one step is never amplified later, so the L1 distance
/// grows at most by the rounding of one step, a few ulps of c per cell, `4 eps c_max`, per step.
/// The maximum norm has no such bound: shocks collect the differences of both sides into one
/// cell (measured up to 9e-12 in f64 after 1200 steps), so it is only reported.
fn rounding_l1_bound(steps: u64, eps: f64, c_max: f64) -> f64 {
    steps as f64 * 4.0 * eps * c_max
}

#[test]
fn modified_scheme_is_phase_independent() {
    // Tracking phi (convex flux) or psi = c - phi (concave flux) solves the same problem: the
    // modified flux of psi is minus the one of phi, so the runs differ by rounding only.
    for col in [Column::A, Column::B, Column::C, Column::D] {
        let mut small = column::<f64>(col, 400, Scheme::Modified, Phase::Small);
        let mut large = column::<f64>(col, 400, Scheme::Modified, Phase::Large);
        small.advance_to(1.5, u64::MAX);
        large.advance_to(1.5, u64::MAX);
        let (a, b) = (phis(&*small), phis(&*large));
        let (l1, max) = (l1_distance(&a, &b), common::max_change(&a, &b));
        let bound = rounding_l1_bound(small.steps(), f64::EPSILON, 0.64);
        println!(
            "{col:?}: phi(small) vs phi(large): L1 {l1:.3e} (bound {bound:.3e}), max {max:.3e}"
        );
        assert!(l1 <= bound, "{col:?}: phases differ by {l1:e} in L1");
        assert!(max < 1e-10, "{col:?}: phases differ by {max:e} in one cell");
    }
    let mut small = shear_cell(Scheme::Modified, Phase::Small, -1.0, false);
    let mut large = shear_cell(Scheme::Modified, Phase::Large, -1.0, false);
    small.advance_to(0.5, u64::MAX);
    large.advance_to(0.5, u64::MAX);
    let (a, b) = (phis(&*small), phis(&*large));
    let (l1, max) = (l1_distance(&a, &b), common::max_change(&a, &b));
    let bound = rounding_l1_bound(small.steps(), f64::EPSILON, 0.64);
    println!(
        "shear cell: phi(small) vs phi(large): L1 {l1:.3e} (bound {bound:.3e}), max {max:.3e}"
    );
    assert!(
        l1 <= bound && max < 1e-10,
        "shear cell: phases differ by {l1:e} (L1), {max:e}"
    );
}

#[test]
fn modified_equals_godunov_where_c_and_t_are_uniform() {
    // Column a has uniform c and T: the modified flux is then the classical Godunov flux; the
    // naive scheme only rebuilds k from face averages (a rounding difference).
    let mut modified = column::<f64>(Column::A, 400, Scheme::Modified, Phase::Small);
    let mut godunov = column::<f64>(Column::A, 400, Scheme::Godunov, Phase::Small);
    modified.advance_to(1.5, u64::MAX);
    godunov.advance_to(1.5, u64::MAX);
    let d = common::max_change(&phis(&*modified), &phis(&*godunov));
    println!("column a: max |phi(modified) - phi(godunov)| = {d:.3e}");
    assert!(d < 1e-13, "modified and godunov differ by {d:e}");
}

#[test]
fn f32_and_f64_columns_agree() {
    // The f32 run is the f64 run plus f32 rounding (of the data and of every step); by the L1
    // contraction above the difference stays within 4 eps_f32 c_max per step in L1.
    let mut a = column_with_gravity::<f32>(Column::D, 400, Scheme::Modified, Phase::Large, -1.0);
    let mut b = column_with_gravity::<f64>(Column::D, 400, Scheme::Modified, Phase::Large, -1.0);
    a.advance_to(1.5, u64::MAX);
    b.advance_to(1.5, u64::MAX);
    let (pa, pb) = (phis(&*a), phis(&*b));
    let l1 = l1_distance(&pa, &pb);
    let bound = rounding_l1_bound(b.steps(), f32::EPSILON as f64, 0.6);
    println!(
        "column d: phi(f32) vs phi(f64): L1 {l1:.3e} (bound {bound:.3e}), max {:.3e}",
        common::max_change(&pa, &pb)
    );
    assert!(l1 <= bound, "f32 and f64 differ by {l1:e} in L1");
}

// ---------------------------------------------------------------------------------------------
// Face fluxes
// ---------------------------------------------------------------------------------------------

/// A side of a face: (q, c, k) with q in [0, c] and k of either sign.
fn side() -> impl Strategy<Value = (f64, f64, f64)> {
    (0.0..=0.64f64, 0.0..=1.0f64, -5.0..5.0f64).prop_map(|(c, x, k)| (c * x, c, k))
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2048, ..ProptestConfig::default() })]

    /// F(q, q) = f(q) for every numerical flux when both sides carry the same coefficients.
    #[test]
    fn fluxes_are_consistent((q, c, k) in side(), un in -3.0..3.0f64) {
        let f = flux::physical(q, c, k);
        prop_assert_eq!(flux::modified(q, c, k, q, c, k), f);
        prop_assert_eq!(flux::godunov(q, q, c, k), f);
        prop_assert_eq!(flux::upwind(q, q, c, k), f);
        prop_assert_eq!(flux::transport(q, q, un), q * un);
    }

    /// The closed-form Godunov flux of the quadratic equals the definition (min over [qL, qR]
    /// or max over [qR, qL]), to the rounding of f near its extremum: computed f(c/2) need not
    /// be the smallest computed value, by a few ulps of |k| c^2 / 4.
    #[test]
    fn godunov_closed_form_matches_definition(
        (ql, c, k) in side(),
        y in 0.0..=1.0f64,
    ) {
        let qr = c * y;
        let f = |q: f64| flux::physical(q, c, k);
        let reference = flux::godunov_reference(f, ql, qr, c / 2.0);
        let tol = 4.0 * f64::EPSILON * k.abs() * c * c;
        prop_assert!((flux::godunov(ql, qr, c, k) - reference).abs() <= tol);
        // The modified flux with equal sides is the same Godunov flux.
        prop_assert!((flux::modified(ql, c, k, qr, c, k) - reference).abs() <= tol);
    }

    /// The modified flux is monotone (non-decreasing in q_L, non-increasing in q_R), which with
    /// the Courant condition makes the scheme keep 0 <= phi <= c; and it is zero at faces whose
    /// sides segregate in opposite directions.
    #[test]
    fn modified_flux_is_monotone(
        (ql, cl, kl) in side(),
        (qr, cr, kr) in side(),
        dl in 0.0..=1.0f64,
        dr in 0.0..=1.0f64,
    ) {
        let f = flux::modified(ql, cl, kl, qr, cr, kr);
        let ql2 = ql + (cl - ql) * dl; // larger q_L, still <= c_L
        let qr2 = qr + (cr - qr) * dr; // larger q_R
        prop_assert!(flux::modified(ql2, cl, kl, qr, cr, kr) >= f);
        prop_assert!(flux::modified(ql, cl, kl, qr2, cr, kr) <= f);
        if (kl > 0.0 && kr < 0.0) || (kl < 0.0 && kr > 0.0) {
            prop_assert_eq!(f, 0.0);
        }
        // Nothing crosses into or out of a pure cell against its own segregation.
        prop_assert_eq!(flux::modified(cl, cl, kl.abs(), qr, cr, kr.abs()).min(0.0), 0.0);
    }
}

/// f32 over a long run: 40,000 steps of a 32 x 32 shear cell (periodic x, walls in z) with a
/// velocity that is slightly compressive (as an interpolated measured field is), run far past
/// segregation so full and empty cells receive fluxes far below ulp(q). Plain updates round
/// those away differently in donor and receiver and the mass drifts systematically; the
/// compensated update (`SegregationConfig::compensated`, used by the soft sensor) carries each
/// rounding error and keeps the drift at the level of one rounding of the total.
/// Measured: plain -1.4e-3, compensated 6.4e-8.
#[test]
fn compensated_updates_keep_f32_mass_over_long_runs() {
    const N: usize = 1024;
    let run = |compensated: bool| -> f64 {
        let mut s = boxed::<f32, 2, N>();
        let grid = Grid::new([32, 32], [0.0, 0.0], [1.0, 1.0], N).unwrap();
        let mut cfg = config::<f32, 2>(
            Scheme::Modified,
            Phase::Small,
            [0.0, -1.0],
            DirectionMode::Flow,
        );
        cfg.compensated = compensated;
        s.setup(grid, [[Boundary::Periodic; 2], [Boundary::Wall; 2]], cfg)
            .unwrap();
        for i in 0..grid.len() {
            let [x, z] = grid.center(i);
            // shear plus a weak compressive wiggle (not divergence-free)
            let u = [
                0.2 + 0.8 * z + 0.01 * (std::f32::consts::TAU * x).sin(),
                0.002 * (std::f32::consts::TAU * z).sin(),
            ];
            s.set_cell(i, 0.6, 0.05, u, 0.3);
        }
        s.prepare().unwrap();
        let mass = |s: &Segregation<f32, 2, N>| -> f64 {
            (0..grid.len()).map(|i| f64::from(s.phi(i))).sum()
        };
        let m0 = mass(&s);
        let dt = s.stable_dt();
        for _ in 0..40_000 {
            s.step(dt);
        }
        (mass(&s) - m0) / m0
    };
    let plain = run(false);
    let compensated = run(true);
    println!("relative mass drift after 40,000 f32 steps: plain {plain:.3e}, compensated {compensated:.3e}");
    assert!(compensated.abs() < 1e-6, "compensated {compensated:e}");
    assert!(
        plain.abs() > 10.0 * compensated.abs().max(1e-9),
        "plain {plain:e} vs compensated {compensated:e}: the case no longer shows the drift"
    );
}

/// `Segregation::all_finite` (the run's check after every chunk of steps) is false exactly
/// when a cell holds a non-finite phi, c, T, velocity or segregation velocity, wherever the
/// cell is; on a clean state it is true.
#[test]
fn all_finite_sees_every_non_finite_field_in_any_cell() {
    let clean = shear_cell(Scheme::Modified, Phase::Small, -1.0, false);
    assert!(clean.all_finite());
    let n = clean.len();
    for i in [0, 1, n / 2 + 7, n - 1] {
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            let mut s = clean.clone();
            s.set_tracked(i, bad);
            assert!(!s.all_finite(), "phi = {bad} in cell {i}");
            let mut s = clean.clone();
            s.set_flow_state(i, bad, [0.0, 0.0]);
            assert!(!s.all_finite(), "T = {bad} in cell {i}");
            let mut s = clean.clone();
            s.set_cell(i, bad, 1.0, [0.0, 0.0], 0.0);
            assert!(!s.all_finite(), "c = {bad} in cell {i}");
            for a in 0..2 {
                let mut s = clean.clone();
                let mut u = [0.0; 2];
                u[a] = bad;
                s.set_flow_state(i, 1.0, u);
                assert!(!s.all_finite(), "u_{a} = {bad} in cell {i}");
            }
        }
    }
}
