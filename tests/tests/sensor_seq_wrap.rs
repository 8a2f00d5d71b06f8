//! Frame sequence numbers that wrap past `u32::MAX` (issue 10): a sensor that counts for
//! 2^32 frames (497 days at 100 Hz) wraps to 0. With a plain `>` every later frame was
//! rejected as old and the estimator froze for good; with serial-number order (RFC 1982) the
//! run across the wrap is the same, bit for bit, as a run that never wraps.

use sieve::soft_sensor::Scene;
use sieve_core::sensor::{health, seq_after, Reject, SoftSensor, VelocityFrame};

const N: usize = 1024;

/// The shear-cell velocity on the 8 x 8 sensor grid; the wiggle depends on the frame's
/// position `k` in the run, not on its sequence number, so two runs that number the same
/// frames differently see the same velocities.
fn frame(seq: u32, k: u32) -> VelocityFrame {
    let period = 0.01f32;
    let mut f = VelocityFrame {
        seq,
        time: k as f32 * period,
        period,
        nx: 8,
        nz: 8,
        u: Default::default(),
    };
    for iz in 0..8 {
        for _ix in 0..8 {
            let z = (iz as f64 + 0.5) * 0.025 / 8.0;
            let wiggle = 1e-5 * (((k as usize * 7 + iz) % 5) as f64 - 2.0);
            f.u.push((0.0007 + 0.0048 * z / 0.025 + wiggle) as f32)
                .unwrap();
            f.u.push(0.0).unwrap();
        }
    }
    f
}

fn sensor() -> Box<SoftSensor<f32, N>> {
    let cfg = Scene::ShearCell.sensor_config(
        [32, 32],
        [8, 8],
        0.05,
        0.01,
        sieve_core::sensor::CycleBudget::for_substeps(4, 1024),
    );
    let mut s: Box<SoftSensor<f32, N>> = Box::default();
    s.configure(&cfg).unwrap();
    s
}

/// Runs `frames` frames numbered `first, first+1, ...` (wrapping), one per tick; returns the
/// sensor and whether any tick froze.
fn run(first: u32, frames: u32) -> (Box<SoftSensor<f32, N>>, bool) {
    let mut s = sensor();
    let mut froze = false;
    for k in 0..frames {
        let seq = first.wrapping_add(k);
        s.submit(&frame(seq, k))
            .unwrap_or_else(|r| panic!("frame {k} (seq {seq}) rejected: {r:?}"));
        let e = s.finish_tick();
        froze |= e.health & health::FROZEN != 0;
        assert_eq!(e.seq, seq);
    }
    (s, froze)
}

#[test]
fn serial_number_order_at_the_wrap() {
    assert!(seq_after(1, 0));
    assert!(seq_after(0, u32::MAX));
    assert!(seq_after(3, u32::MAX - 2));
    assert!(!seq_after(u32::MAX, 0));
    assert!(!seq_after(7, 7));
    assert!(seq_after(i32::MAX as u32, 0));
    // Half the circle away is not "after" in either direction (RFC 1982 leaves it undefined;
    // here it is old, so a garbage seq cannot claim 2^31 lost periods).
    assert!(!seq_after(1 << 31, 0));
    assert!(!seq_after(0, 1 << 31));
}

#[test]
fn a_run_across_the_wrap_equals_a_run_that_never_wraps() {
    let frames = 40;
    let (plain, froze_plain) = run(1, frames);
    // Frames u32::MAX - 19 ..= u32::MAX, then 0 ..= 19.
    let (wrapped, froze_wrapped) = run(u32::MAX - 19, frames);
    assert!(!froze_plain && !froze_wrapped, "the estimator froze");
    for s in [&plain, &wrapped] {
        let c = s.counters();
        assert_eq!(c.accepted, frames, "{c:?}");
        assert_eq!((c.seq, c.lost_periods), (0, 0), "{c:?}");
    }
    assert_eq!(plain.lag().to_bits(), wrapped.lag().to_bits());
    let (a, b) = (plain.segregation(), wrapped.segregation());
    assert_eq!(a.time().to_bits(), b.time().to_bits());
    assert!(a.time() > 0.39 && a.time() < 0.41, "{}", a.time());
    for i in 0..a.len() {
        assert_eq!(a.phi(i).to_bits(), b.phi(i).to_bits(), "cell {i}");
    }
}

#[test]
fn duplicates_and_gaps_across_the_wrap() {
    let mut s = sensor();
    s.submit(&frame(u32::MAX - 1, 0)).unwrap();
    s.finish_tick();
    // Three periods (u32::MAX, 0, 1) are lost between u32::MAX - 1 and 2.
    s.submit(&frame(2, 1)).unwrap();
    s.finish_tick();
    assert_eq!(s.counters().lost_periods, 3);
    // A duplicate and a frame from before the wrap are old.
    assert_eq!(s.submit(&frame(2, 2)), Err(Reject::Seq));
    assert_eq!(s.submit(&frame(u32::MAX, 2)), Err(Reject::Seq));
    assert_eq!(s.counters().seq, 2);
    s.submit(&frame(3, 2)).unwrap();
    let e = s.finish_tick();
    assert_eq!(e.seq, 3);
    assert_eq!(e.health & health::FROZEN, 0);
}
