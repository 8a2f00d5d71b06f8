//! The hopper (issue 9, model.md 7.6): the 2D silo with a wedge hopper at the bottom, walls
//! inclined 30 deg from the vertical as cut cells (`Region::hopper`, docs/geometry.md), the
//! orifice at the apex, coupled flow and segregation on the cut cells with the outlet.
//!
//! What must hold: grains and fines in the hopper plus what left equal the initial amounts to
//! round-off (open-volume weighted); 0 <= phi <= c exactly in every cell, cut and merged
//! cells included, after every step; no NaN; a granular steady rate; mass flow against the
//! flat silo's funnel flow: a 30 deg hopper has no stagnant zones (speed below 1 % of the
//! outlet speed) where the flat silo of the same orifice on the same cells has its dead
//! corners, and what leaves keeps the bed's composition longer.

use crate::silo_common::{coarse_2d, discharge, Spec};
use sieve_tests::run_big;

/// The coarse silo of `silo_common`, sampled every 0.1 s.
fn spec(hopper: Option<f64>, t_end: f64) -> Spec<2> {
    coarse_2d(hopper, t_end, 0.1)
}

#[test]
fn hopper_discharges_exactly_in_mass_flow_against_the_flat_silo() {
    run_big(|| {
        let h = discharge(spec(Some(30.0), 1.2));
        let sm = h.series.summary();
        assert!(!h.nonfinite);
        assert!(sm.mass_error < 1e-13, "{sm:?}");
        assert!(sm.mass_small_error < 1e-13, "{sm:?}");
        assert!(h.carried_error < 1e-13, "{}", h.carried_error);
        assert!(h.over <= 0.0 && h.under <= 0.0, "{} {}", h.over, h.under);
        // the flat silo of the same orifice on the same cells (it opens after ~0.5 s)
        let f = discharge(spec(None, 2.5));
        let (r1, r2) = (h.rate_in(0.4, 0.8), h.rate_in(0.8, 1.2));
        let rf = f.rate_in(1.5, 2.5);
        let stagnant_h = (4..=12)
            .map(|k| h.at(0.1 * f64::from(k)).stagnant)
            .fold(0.0, f64::max);
        let stagnant_f = (15..=25)
            .map(|k| f.at(0.1 * f64::from(k)).stagnant)
            .fold(f64::INFINITY, f64::min);
        let (ffh, fff) = (h.fines_in(0.4, 1.2), f.fines_in(1.5, 2.5));
        println!(
            "hopper: rate {r1:.4e} / {r2:.4e} m^2/s over [0.4, 0.8] / [0.8, 1.2] s, fines fraction {ffh:.4}, stagnant share <= {stagnant_h:.4}; flat silo: {rf:.4e} m^2/s over [1.5, 2.5] s (hopper x{:.2}), fines fraction {fff:.4}, stagnant share >= {stagnant_f:.4}",
            0.5 * (r1 + r2) / rf
        );
        // granular: constant while the bed is high
        assert!(r1 > 5e-3, "{r1}");
        assert!((r2 / r1 - 1.0).abs() < 0.1, "{r1} {r2}");
        // mass flow: no dead zones in the hopper, dead corners in the flat silo
        assert!(stagnant_f > 0.005, "{stagnant_f}");
        assert!(stagnant_h < 0.2 * stagnant_f, "{stagnant_h} {stagnant_f}");
        // mass flow discharges the bed as it is (first in, first out): the fines fraction of
        // the discharge stays at the bed's 1/2, nearer than the funnel flow's
        assert!((ffh - 0.5).abs() < 0.01, "{ffh}");
        assert!((ffh - 0.5).abs() < (fff - 0.5).abs(), "{ffh} {fff}");
    });
}
