//! Vanishing fractions never become subnormal numbers (issue 12, docs/model.md 5.6).
//!
//! The exact column of model.md 7.1a run far past its segregation time: the cells the small
//! grains leave lose about half their content per step (Courant 0.5), so without the flush
//! their phi passes 2^-1022 (subnormal, up to 100x slower arithmetic) after ~1,000 steps and
//! underflows to 0 later. With the default `flush_below = 2^-800` no cell ever holds a
//! subnormal, the mass in the cells plus the flushed mass is the initial mass to round-off,
//! and every cell that never came near the floor has the same bits as without the flush.

use crate::common::{boxed, config, Column, N1};
use sieve_core::{
    diagnose, Boundaries, Boundary, DirectionMode, Grid, Phase, Real, Scheme, Segregation,
};

const CELLS: usize = 100;
const STEPS: usize = 2500;

fn column(phase: Phase, flush_below: f64) -> Box<Segregation<f64, 1, N1>> {
    let mut s = boxed::<f64, 1, N1>();
    let grid = Grid::new([CELLS], [0.0], [1.0], N1).expect("grid");
    let bc: Boundaries<1> = [[Boundary::Wall; 2]];
    let mut cfg = config(Scheme::Modified, phase, [-1.0], DirectionMode::Gravity);
    cfg.flush_below = flush_below;
    s.setup(grid, bc, cfg).expect("setup");
    for i in 0..CELLS {
        let z = grid.center(i)[0];
        let c = Column::A.c(z);
        s.set_cell(i, c, Column::A.t(z), [0.0], c * 0.5);
    }
    s.prepare().expect("prepare");
    s
}

fn subnormal_cells(s: &Segregation<f64, 1, N1>) -> usize {
    (0..s.len())
        .filter(|&i| s.tracked_fraction(i).is_subnormal())
        .count()
}

#[test]
fn default_floor_is_two_to_the_minus_800() {
    assert_eq!(f64::FLUSH_BELOW, 2f64.powi(-800));
    assert_eq!(f32::FLUSH_BELOW, 0.0, "f32: off (docs/model.md 5.6)");
}

#[test]
fn vanishing_fractions_are_flushed_and_accounted_for() {
    for phase in [Phase::Small, Phase::Large] {
        let mut on = column(phase, f64::FLUSH_BELOW);
        let mut off = column(phase, 0.0);
        let m0 = diagnose(&*on).mass_small;
        let dt = on.stable_dt();
        let (mut seen_off, mut first_off) = (0usize, None);
        for step in 0..STEPS {
            on.step(dt);
            off.step(dt);
            assert_eq!(subnormal_cells(&on), 0, "{phase:?}: step {step}");
            // Flushed every FLUSH_EVERY = 8 steps; this column halves a vanishing fraction
            // per step, so nothing lingers below 2^-800 * 2^-8.
            for i in 0..CELLS {
                let q = on.tracked_fraction(i);
                assert!(
                    q == 0.0 || q.abs() >= 2f64.powi(-808),
                    "{phase:?} cell {i}: {q:e}"
                );
            }
            let k = subnormal_cells(&off);
            if k > 0 && first_off.is_none() {
                first_off = Some(step);
            }
            seen_off = seen_off.max(k);
        }
        // The case is a real one: without the flush the column does hold subnormals.
        println!("{phase:?}: without the flush, subnormal cells from step {first_off:?}, up to {seen_off}");
        assert!(
            seen_off > 0,
            "{phase:?}: the test never produced a subnormal"
        );

        // Mass: in the cells plus flushed = initial, to round-off. The column's own round-off
        // over 2,500 steps is ~2e-13 with or without the flush; the flush adds nothing to it.
        let m = diagnose(&*on).mass_small;
        let m_off = diagnose(&*off).mass_small;
        let flushed = on.flushed_small_mass();
        let drift = (m + flushed - m0).abs() / m0;
        let drift_off = (m_off - m0).abs() / m0;
        let gap = (m + flushed - m_off).abs() / m0;
        println!("{phase:?}: flushed {flushed:e} (mass {m0}), drift {drift:e} (without flush {drift_off:e}), gap {gap:e}");
        assert!(
            drift < 1e-12 && drift_off < 1e-12,
            "{phase:?}: drift {drift:e} / {drift_off:e}"
        );
        assert!(
            gap <= 2.0 * f64::EPSILON,
            "{phase:?}: flushed run's mass differs by {gap:e}"
        );
        assert!(flushed != 0.0, "{phase:?}: nothing was flushed");
        let sign = if phase == Phase::Small { 1.0 } else { -1.0 };
        assert!(
            sign * flushed > 0.0,
            "{phase:?}: flushed small mass has the wrong sign"
        );
        // At most one floor per cell and step, one cell volume each.
        let bound = f64::FLUSH_BELOW * (CELLS * STEPS) as f64 / CELLS as f64;
        assert!(flushed.abs() <= bound, "{phase:?}: {flushed:e} > {bound:e}");

        // Cells far above the floor carry the same bits with and without the flush: a
        // neighbour's 2^-800 cannot move a fraction of order one.
        let mut compared = 0;
        for i in 0..CELLS {
            let (a, b) = (on.tracked_fraction(i), off.tracked_fraction(i));
            if b.abs() > 2f64.powi(-700) {
                assert_eq!(
                    a.to_bits(),
                    b.to_bits(),
                    "{phase:?} cell {i}: {a:e} vs {b:e}"
                );
                compared += 1;
            }
        }
        assert!(compared >= CELLS / 2, "{phase:?}: compared {compared}");
    }
}

#[test]
fn a_short_run_is_untouched_by_the_flush() {
    // Column-a to t = 1.5 on 200 cells (the golden run) never comes near 2^-800.
    let mut on = column(Phase::Small, f64::FLUSH_BELOW);
    on.advance_to(1.5, u64::MAX);
    assert_eq!(on.flushed_small_mass(), 0.0);
}
