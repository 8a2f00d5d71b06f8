//! The soft sensor's entropy table (`sieve_core::sensor::entropy`): every entry is the f32
//! rounding of the libm f64 value, and the interpolation stays within its documented error.

use sieve_core::diagnostics::mixing_entropy_density;
use sieve_core::sensor::entropy::{entropy_density, ENTROPY_INTERVALS, ENTROPY_TABLE};

#[test]
fn table_entries_are_the_rounded_libm_values() {
    for (k, &v) in ENTROPY_TABLE.iter().enumerate() {
        let x = k as f64 / ENTROPY_INTERVALS as f64;
        let want = mixing_entropy_density::<f64>(x) as f32;
        assert_eq!(v.to_bits(), want.to_bits(), "entry {k}: {v} != {want}");
    }
}

#[test]
fn interpolation_is_within_4e_4_and_clamps() {
    let mut worst = 0.0f64;
    for j in 0..=200_000u32 {
        let x = j as f64 / 200_000.0;
        let exact = mixing_entropy_density::<f64>(x);
        worst = worst.max((entropy_density(x as f32) as f64 - exact).abs());
        worst = worst.max((entropy_density(x) - exact).abs());
    }
    println!("largest interpolation error {worst:e}");
    assert!(worst < 4e-4, "{worst}");
    assert_eq!(entropy_density(-0.5f32), 0.0);
    assert_eq!(entropy_density(1.5f32), 0.0);
    assert_eq!(entropy_density(f32::NAN), 0.0);
}
