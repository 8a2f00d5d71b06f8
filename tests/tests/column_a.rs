//! Segregation column 7.1a against its exact solution (`sieve_core::exact::ColumnA`).
//!
//! Set-up (model.md 7.1a): z in [0, 1], walls at both ends, c = 0.64, T = 1, S0 = 1, gravity
//! [-1], so the large grains rise with |S| = 1; initial phi = c/2 (phihat = m = 1/2). Exact:
//! a lower shock (phihat 1 below, 1/2 above) rises at S m = 1/2, an upper shock (1/2 below, 0
//! above) falls at S (1 - m) = 1/2; at t = 0.5 they sit at z = 0.25 and z = 0.75, and they meet
//! at t = 1. The mixing index is Psi(t) = 1 - t.

use crate::common::{centres, column, crossing, observed_order, phihat, Column};
use sieve_core::exact::ColumnA;
use sieve_core::{diagnose, Phase, Real, Scheme, SegregationClock};

const EXACT: ColumnA<f64> = ColumnA {
    s: 1.0,
    m: 0.5,
    height: 1.0,
};

/// L1 error of the phihat cell averages at time `t` on `n` cells.
fn l1_error<R: Real>(n: usize, t: f64) -> f64 {
    let mut s = column::<R>(Column::A, n, Scheme::Modified, Phase::Small);
    s.advance_to(R::from_f64(t), u64::MAX);
    let h = 1.0 / n as f64;
    phihat(&*s)
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let exact = EXACT.phihat_cell_average(i as f64 * h, (i + 1) as f64 * h, t);
            (p - exact).abs() * h
        })
        .sum()
}

#[test]
fn shock_positions_at_half_time() {
    for n in [100, 200, 400, 800] {
        let mut s = column::<f64>(Column::A, n, Scheme::Modified, Phase::Small);
        s.advance_to(0.5, u64::MAX);
        let h = 1.0 / n as f64;
        // phihat falls with height: locate the shocks as the crossings of the mid-values of their
        // two states, (1 + m)/2 = 0.75 and m/2 = 0.25, on the negated (rising) profile.
        let neg: Vec<f64> = phihat(&*s).iter().map(|p| -p).collect();
        let z = centres(n, 1.0);
        let lower = crossing(&z, &neg, -0.75).expect("lower shock");
        let upper = crossing(&z, &neg, -0.25).expect("upper shock");
        println!("n={n}: lower shock {lower:.6} (exact 0.25), upper {upper:.6} (exact 0.75)");
        // Within one cell (measured: 0.02 cells on every level).
        assert!(
            (lower - EXACT.lower_shock(0.5)).abs() < h,
            "n={n}: lower shock at {lower}, exact {}",
            EXACT.lower_shock(0.5)
        );
        assert!(
            (upper - EXACT.upper_shock(0.5)).abs() < h,
            "n={n}: upper shock at {upper}, exact {}",
            EXACT.upper_shock(0.5)
        );
    }
}

#[test]
fn mixing_index_follows_exact_psi() {
    let times = [0.2, 0.4, 0.6, 0.8];
    let mut worst = [0.0f64; 2];
    for (level, n) in [200usize, 400].into_iter().enumerate() {
        let mut s = column::<f64>(Column::A, n, Scheme::Modified, Phase::Small);
        let h = 1.0 / n as f64;
        for t in times {
            s.advance_to(t, u64::MAX);
            let psi = diagnose(&*s).psi;
            let err = (psi - EXACT.psi(t)).abs();
            println!(
                "n={n} t={t}: Psi {psi:.5} exact {:.5} error/h {:.3}",
                EXACT.psi(t),
                err / h
            );
            // Each smeared shock carries the entropy of about half a cell of mixed material
            // (measured: |error| = 1.1 h); allow two cells.
            assert!(
                err < 2.0 * h,
                "n={n}, t={t}: Psi {psi}, exact {}",
                EXACT.psi(t)
            );
            worst[level] = worst[level].max(err);
        }
    }
    assert!(
        worst[1] < 0.6 * worst[0],
        "Psi error does not shrink: {worst:?}"
    );
}

#[test]
fn segregation_time_of_psi_threshold() {
    // Threshold Psi < 0.1: exact time (1 - 0.1) H / S = 0.9.
    let threshold = 0.1;
    for n in [200usize, 400] {
        let mut s = column::<f64>(Column::A, n, Scheme::Modified, Phase::Small);
        let mut clock = SegregationClock::new(threshold);
        clock.sample(0.0, diagnose(&*s).psi);
        while clock.time().is_none() && s.time() < 2.0 {
            s.advance_to(2.0, 1);
            clock.sample(s.time(), diagnose(&*s).psi);
        }
        let t = clock.time().expect("segregated before t = 2");
        let exact = EXACT.segregation_time(threshold);
        let h = 1.0 / n as f64;
        println!("n={n}: segregation time {t:.5}, exact {exact}");
        // dPsi/dt = -S/H = -1, so the Psi error of ~1.1 h becomes a time error of ~1.1 h / S.
        assert!(
            (t - exact).abs() < 2.0 * h,
            "n={n}: segregation time {t}, exact {exact}"
        );
    }
}

#[test]
fn l1_error_converges_at_first_order() {
    let levels = [100usize, 200, 400, 800];
    let h: Vec<f64> = levels.iter().map(|&n| 1.0 / n as f64).collect();
    let e: Vec<f64> = levels.iter().map(|&n| l1_error::<f64>(n, 0.5)).collect();
    // Measured: 4.73e-3, 2.36e-3, 1.18e-3, 5.91e-4 (= 0.47 h: each shock is off by about a
    // quarter of a cell in the L1 sense).
    for (k, (&ek, &hk)) in e.iter().zip(&h).enumerate() {
        assert!(
            ek < hk,
            "level {k}: L1 error {ek} above one cell width {hk}"
        );
        if k > 0 {
            assert!(ek < e[k - 1], "L1 errors do not decrease: {e:?}");
        }
    }
    let order = observed_order(&h, &e);
    println!("L1 errors {e:?}, observed order {order:.4}");
    assert!(
        order > 0.7 && order < 1.3,
        "observed L1 order {order} (errors {e:?})"
    );
}

#[test]
fn single_precision_tracks_double() {
    // The f32 solver solves the same problem: its error against the exact solution is the
    // f64 one plus round-off that stays far below the discretisation error.
    let (e32, e64) = (l1_error::<f32>(400, 0.5), l1_error::<f64>(400, 0.5));
    println!("L1 error at 400 cells: f32 {e32:.6e}, f64 {e64:.6e}");
    assert!((e32 - e64).abs() < 1e-5, "f32 L1 error {e32} vs f64 {e64}");
}
