//! The uniform-coefficient fast path of the segregation step (issue 12, "model only what a
//! scene needs") changes loads, not arithmetic: a column whose c, T, k and u are uniform runs
//! the q-only face loop, and the same column with one cell's velocity written as -0.0 instead
//! of +0.0 (the same physics: every face velocity is still +0) runs the general five-array
//! loop. Both must agree bit for bit, step by step, in 1D and 2D, for every flux and phase.

use crate::common::{boxed, config, Column, N1, N2};
use sieve_core::{state_hash, Boundary, DirectionMode, Grid, Phase, Real, Scheme, Segregation};

const STEPS: usize = 400;

fn column_1d(
    scheme: Scheme,
    phase: Phase,
    minus_zero_at: Option<usize>,
) -> Box<Segregation<f64, 1, N1>> {
    let cells = 200;
    let mut s = boxed::<f64, 1, N1>();
    let grid = Grid::new([cells], [0.0], [1.0], N1).expect("grid");
    let cfg = config(scheme, phase, [-1.0], DirectionMode::Gravity);
    s.setup(grid, [[Boundary::Wall; 2]], cfg).expect("setup");
    for i in 0..cells {
        let z = grid.center(i)[0];
        let c = Column::A.c(z);
        let u = if Some(i) == minus_zero_at { -0.0 } else { 0.0 };
        s.set_cell(i, c, Column::A.t(z), [u], c * 0.5);
    }
    s.prepare().expect("prepare");
    s
}

/// Column a standing in a 2D box, 40 x 50, periodic in x; mixed below, fines on top above.
fn column_2d<R: Real>(scheme: Scheme, minus_zero_at: Option<usize>) -> Box<Segregation<R, 2, N2>> {
    let mut s = boxed::<R, 2, N2>();
    let grid = Grid::new([40, 50], [R::ZERO; 2], [R::ONE; 2], N2).expect("grid");
    let cfg = config(scheme, Phase::Small, [0.0, -1.0], DirectionMode::Gravity);
    let bc = [[Boundary::Periodic; 2], [Boundary::Wall; 2]];
    s.setup(grid, bc, cfg).expect("setup");
    let c = R::from_f64(0.64);
    for i in 0..grid.len() {
        let [x, z] = grid.center(i);
        let phi = if z.to_f64() > 0.3 + 0.2 * x.to_f64() {
            c
        } else {
            c * R::HALF
        };
        let u = if Some(i) == minus_zero_at {
            -R::ZERO
        } else {
            R::ZERO
        };
        s.set_cell(i, c, R::ONE, [u, R::ZERO], phi);
    }
    s.prepare().expect("prepare");
    s
}

fn assert_same_run<R: Real, const D: usize, const N: usize>(
    fast: &mut Segregation<R, D, N>,
    general: &mut Segregation<R, D, N>,
    what: &str,
) {
    let dt = fast.stable_dt();
    assert_eq!(
        dt.to_bits_u64(),
        general.stable_dt().to_bits_u64(),
        "{what}: dt"
    );
    let h0 = state_hash(fast);
    for step in 0..STEPS {
        fast.step(dt);
        general.step(dt);
        let (a, b) = (state_hash(fast), state_hash(general));
        if a != b {
            let cell = (0..fast.len()).find(|&i| {
                fast.tracked_fraction(i).to_bits_u64() != general.tracked_fraction(i).to_bits_u64()
            });
            panic!("{what}: fast and general paths diverge at step {step}, first cell {cell:?}");
        }
    }
    assert_ne!(h0, state_hash(fast), "{what}: the state must evolve");
    assert_eq!(
        fast.bound_violations(),
        (R::ZERO, R::ZERO),
        "{what}: 0 <= phi <= c"
    );
}

#[test]
fn uniform_column_takes_the_fast_path_with_the_general_bits_1d() {
    for scheme in Scheme::ALL {
        for phase in [Phase::Small, Phase::Large] {
            let mut fast = column_1d(scheme, phase, None);
            let mut general = column_1d(scheme, phase, Some(77));
            assert_eq!(fast.uniform_axes(), [true], "{scheme:?}");
            assert_eq!(
                general.uniform_axes(),
                [false],
                "{scheme:?}: -0.0 is another bit pattern"
            );
            assert_same_run(
                &mut *fast,
                &mut *general,
                &format!("1D {scheme:?} {phase:?}"),
            );
        }
    }
}

#[test]
fn uniform_column_takes_the_fast_path_with_the_general_bits_2d() {
    for scheme in Scheme::ALL {
        let mut fast = column_2d::<f64>(scheme, None);
        let mut general = column_2d::<f64>(scheme, Some(1234));
        assert_eq!(fast.uniform_axes(), [true, true]);
        assert_eq!(
            general.uniform_axes(),
            [false, true],
            "u_x differs, u_z does not"
        );
        assert_same_run(&mut *fast, &mut *general, &format!("2D f64 {scheme:?}"));
        let mut fast = column_2d::<f32>(scheme, None);
        let mut general = column_2d::<f32>(scheme, Some(1234));
        assert_same_run(&mut *fast, &mut *general, &format!("2D f32 {scheme:?}"));
    }
}

#[test]
fn a_column_with_varying_packing_is_not_uniform() {
    let mut s = boxed::<f64, 1, N1>();
    let grid = Grid::new([100], [0.0], [1.0], N1).expect("grid");
    let cfg = config(
        Scheme::Modified,
        Phase::Small,
        [-1.0],
        DirectionMode::Gravity,
    );
    s.setup(grid, [[Boundary::Wall; 2]], cfg).expect("setup");
    for i in 0..100 {
        let z = grid.center(i)[0];
        let c = Column::B.c(z);
        s.set_cell(i, c, Column::B.t(z), [0.0], c * 0.5);
    }
    s.prepare().expect("prepare");
    assert_eq!(s.uniform_axes(), [false]);
}

/// A 1D column of `cells` cells (more than two tiles of the in-place sweep, a tail that is
/// not a whole number of lanes), empty at the bottom so that cells keep emptying past the
/// flush floor, with the given boundaries, Courant 0.9 and optional diffusion.
fn column_1d_long(
    scheme: Scheme,
    bc: [Boundary; 2],
    diffusion: f64,
    minus_zero_at: Option<usize>,
) -> Box<Segregation<f64, 1, N2>> {
    let cells = 1301;
    let mut s = boxed::<f64, 1, N2>();
    let grid = Grid::new([cells], [0.0], [1.0], N2).expect("grid");
    let mut cfg = config(scheme, Phase::Small, [-1.0], DirectionMode::Gravity);
    cfg.courant = 0.9;
    cfg.diffusion = diffusion;
    s.setup(grid, [bc], cfg).expect("setup");
    let c = 0.64;
    for i in 0..cells {
        let z = grid.center(i)[0];
        let u = if Some(i) == minus_zero_at { -0.0 } else { 0.0 };
        // a wave that empties the lowest fifth (flushed there) and fills the top
        let phi = if z < 0.2 {
            c * 1e-3 * z
        } else {
            c * (0.5 + 0.45 * (17.0 * z).sin())
        };
        s.set_cell(i, c, 1.0, [u], phi);
    }
    s.set_inflow(0, 0.25 * c);
    s.set_inflow(cells - 1, 0.75 * c);
    s.prepare().expect("prepare");
    s
}

/// The in-place 1D sweep (f64, uniform coefficients, every cell counted) against the general
/// loop, bit for bit after every step: q, the running bound maxima and the flushed counter,
/// with every boundary kind, with and without diffusion, for the full step and the
/// percolation step.
#[test]
fn in_place_1d_sweep_keeps_the_general_bits() {
    let bcs = [
        [Boundary::Wall; 2],
        [Boundary::Inflow, Boundary::Outflow],
        [Boundary::Outflow, Boundary::Inflow],
        [Boundary::Periodic; 2],
    ];
    let mut flushed_somewhere = false;
    for scheme in Scheme::ALL {
        for bc in bcs {
            for diffusion in [0.0, 2e-4] {
                for percolation in [false, true] {
                    let what = format!("{scheme:?} {bc:?} D = {diffusion} perc {percolation}");
                    let mut fast = column_1d_long(scheme, bc, diffusion, None);
                    let mut general = column_1d_long(scheme, bc, diffusion, Some(611));
                    assert_eq!(fast.uniform_axes(), [true], "{what}");
                    assert_eq!(general.uniform_axes(), [false], "{what}");
                    let dt = fast.stable_dt();
                    for step in 0..700 {
                        if percolation {
                            fast.step_percolation(dt);
                            general.step_percolation(dt);
                        } else {
                            fast.step(dt);
                            general.step(dt);
                        }
                        let cell = (0..fast.len()).find(|&i| {
                            fast.tracked_fraction(i).to_bits()
                                != general.tracked_fraction(i).to_bits()
                        });
                        assert_eq!(cell, None, "{what}: q differs at step {step}");
                        let (a, b) = (fast.tracked_excess(), general.tracked_excess());
                        assert_eq!(
                            a.map(f64::to_bits),
                            b.map(f64::to_bits),
                            "{what}: bound maxima at step {step}"
                        );
                        assert_eq!(
                            fast.flushed_tracked().to_bits(),
                            general.flushed_tracked().to_bits(),
                            "{what}: flushed at step {step}"
                        );
                        assert_eq!(
                            fast.side_books(),
                            general.side_books(),
                            "{what}: side books at step {step}"
                        );
                    }
                    flushed_somewhere |= fast.flushed_tracked() != 0.0;
                }
            }
        }
    }
    assert!(flushed_somewhere, "the flush must be exercised");
}
