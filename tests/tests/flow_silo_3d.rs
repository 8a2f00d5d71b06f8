//! The 3D silo (issue 9, model.md 7.6): the 2D silo of `flow_silo.rs` given a depth of
//! 0.04 m between two friction walls (30 deg, like the others), the orifice a slot across
//! the whole depth (a rectangle opening in the floor, `sieve_core::boundary::Openings`).
//!
//! What must hold: grains and fines in the silo plus what left equal the initial amounts to
//! round-off; 0 <= phi <= c exactly in every cell after every step; no NaN; a granular
//! discharge (the rate roughly constant while the bed is high); and the side walls' friction
//! slows the discharge per unit depth against the 2D silo on the same cells.

use crate::silo_common::{coarse_3d, discharge, Spec};
use sieve_tests::run_big;

#[test]
fn slot_silo_3d_is_exact_bounded_granular_and_slowed_by_its_side_walls() {
    run_big(|| {
        let s3 = coarse_3d(1.0);
        let o3 = discharge(s3);
        let sm = o3.series.summary();
        assert!(!o3.nonfinite);
        assert!(sm.mass_error < 1e-13, "{sm:?}");
        assert!(sm.mass_small_error < 1e-13, "{sm:?}");
        assert!(o3.carried_error < 1e-13, "{}", o3.carried_error);
        assert!(
            o3.over <= 0.0 && o3.under <= 0.0,
            "{} {}",
            o3.over,
            o3.under
        );
        // the 2D silo on the same cells in x and z
        let o2 = discharge(Spec {
            cells: [15, 30],
            height: s3.height,
            depth: 0.0,
            fill: s3.fill,
            orifice: s3.orifice,
            hopper: None,
            hopper_z: 0.0,
            t_end: s3.t_end,
            every: s3.every,
        });
        // steady windows (sampled every 0.1 s). Since the outlet's p = 0 sits on the orifice
        // face (2026-12-04) both open at once: the 2D silo is 80 % out by 0.7 s, the 3D one
        // 65 % by 0.9 s (before, the 3D slot crept until ~0.6 s)
        let q2 = [o2.rate_in(0.3, 0.5), o2.rate_in(0.5, 0.7)];
        let q3 = [o3.rate_in(0.3, 0.6), o3.rate_in(0.6, 0.9)].map(|q| q / s3.depth);
        let (m2, m3) = (o2.rate_in(0.3, 0.7), o3.rate_in(0.3, 0.9) / s3.depth);
        println!(
            "steady rate per unit depth: 2D {m2:.4e} m^2/s over [0.3, 0.7] s ({:.4e}, {:.4e}), 3D {m3:.4e} over [0.3, 0.9] s ({:.4e}, {:.4e}): side walls {:+.1} %; 3D surface {:.3} -> {:.3} m; onset (1 % out) 2D {:.1} s, 3D {:.1} s",
            q2[0], q2[1], q3[0], q3[1],
            100.0 * (m3 / m2 - 1.0),
            o3.at(0.3).surface,
            o3.at(0.9).surface,
            o2.series.rows.iter().find(|r| r.out > 0.01 * sm.mass_initial / s3.depth).map_or(f64::NAN, |r| r.t),
            o3.series.rows.iter().find(|r| r.out > 0.01 * sm.mass_initial).map_or(f64::NAN, |r| r.t),
        );
        // granular: constant within 10 % while the bed is high (the 3D surface falls from
        // 0.27 to 0.12 m over the window: a liquid's sqrt(h) rate would drop by 35 %)
        for q in [q2, q3] {
            assert!((q[1] / q[0] - 1.0).abs() < 0.1, "{q:?}");
        }
        assert!((o3.at(0.9).surface / o3.at(0.3).surface).sqrt() < 0.85);
        // the friction of the side walls slows the discharge per unit depth (measured -33 %;
        // -22.6 % with the old outlet)
        assert!(m3 < 0.9 * m2 && m3 > 0.5 * m2, "{m3} {m2}");
    });
}
