//! Correctly rounded square roots for `sieve-core` (docs/simd.md, "Square roots").
//!
//! `libm::sqrt` on x86-64 is an inline-assembly `sqrtsd`: the legacy SSE encoding, whatever
//! the function it is inlined into. The host compiles the core's hot loops again inside
//! AVX-512 functions (host/src/isa.rs); there a legacy SSE instruction after wide vector code
//! pays an SSE/AVX transition on every call. Measured on these machines: 165 ns per `sqrtsd`
//! in such a loop against 2.1 ns for `vsqrtsd`, which made the 3D silo's `sqrt(T)` loop
//! (3,000 cells) a quarter of its step.
//!
//! Here the square root is the SSE2 *intrinsic*, which the compiler lowers to its own
//! square-root operation: `sqrtsd` in baseline code, `vsqrtsd` (or a vector `vsqrtpd` where a
//! loop vectorises) inside a function with AVX enabled. Every one of them is the IEEE 754
//! square root, correctly rounded, so the bits are those of `libm::sqrt` (tested below for
//! zeros, subnormals, infinities, NaN and negatives). Other targets (the Cortex-M4F firmware)
//! keep `libm`.
#![no_std]

/// `sqrt(x)` in `f64`, correctly rounded (IEEE 754).
#[inline(always)]
pub fn sqrt(x: f64) -> f64 {
    #[cfg(target_arch = "x86_64")]
    {
        use core::arch::x86_64::{_mm_cvtsd_f64, _mm_set_sd, _mm_sqrt_pd};
        // SAFETY: SSE2 is part of the x86-64 baseline, so these intrinsics exist on every
        // x86-64 CPU; they read and write registers only.
        #[allow(unsafe_code)]
        unsafe {
            _mm_cvtsd_f64(_mm_sqrt_pd(_mm_set_sd(x)))
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        libm::sqrt(x)
    }
}

/// `sqrt(x)` in `f32`, correctly rounded (IEEE 754).
#[inline(always)]
pub fn sqrtf(x: f32) -> f32 {
    #[cfg(target_arch = "x86_64")]
    {
        use core::arch::x86_64::{_mm_cvtss_f32, _mm_set_ss, _mm_sqrt_ps};
        // SAFETY: as in `sqrt`: SSE is part of the x86-64 baseline.
        #[allow(unsafe_code)]
        unsafe {
            _mm_cvtss_f32(_mm_sqrt_ps(_mm_set_ss(x)))
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        libm::sqrtf(x)
    }
}

#[cfg(test)]
mod tests {
    use super::{sqrt, sqrtf};

    /// A fixed-seed xorshift: bit patterns over the whole range, reproducible.
    fn bits(mut s: u64) -> impl FnMut() -> u64 {
        move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        }
    }

    #[test]
    fn f64_matches_libm_bit_for_bit() {
        let special = [
            0.0,
            -0.0,
            f64::MIN_POSITIVE,
            f64::from_bits(1),
            f64::from_bits(0x000f_ffff_ffff_ffff),
            1.0,
            2.0,
            f64::MAX,
            f64::INFINITY,
            -f64::INFINITY,
            -1.0,
            f64::NAN,
        ];
        let mut next = bits(0x9e37_79b9_7f4a_7c15);
        let random = (0..200_000).map(|_| f64::from_bits(next()));
        let mut checked = 0;
        for x in special.into_iter().chain(random) {
            let (ours, theirs) = (sqrt(x), libm::sqrt(x));
            assert!(
                ours.to_bits() == theirs.to_bits() || (ours.is_nan() && theirs.is_nan()),
                "sqrt({x:e}) = {ours:e}, libm {theirs:e}"
            );
            checked += 1;
        }
        assert_eq!(checked, 200_012);
    }

    #[test]
    fn f32_matches_libm_bit_for_bit() {
        // Every f32 with a nonnegative sign (2^31 values) would take seconds in a debug
        // build; every 997th pattern crosses every binade, subnormals included.
        let mut checked = 0u64;
        for b in (0..=u32::MAX).step_by(997) {
            let x = f32::from_bits(b);
            let (ours, theirs) = (sqrtf(x), libm::sqrtf(x));
            assert!(
                ours.to_bits() == theirs.to_bits() || (ours.is_nan() && theirs.is_nan()),
                "sqrtf({x:e}) = {ours:e}, libm {theirs:e}"
            );
            checked += 1;
        }
        assert!(checked > 4_300_000);
    }
}
