//! The floating-point trait the whole core is generic over (`f32` and `f64`).
//!
//! Every transcendental goes through `libm` so that results are bit-identical on every
//! target (host x86-64, Cortex-M4F firmware) and independent of which features other crates
//! in the build enable. Square roots come from the workspace crate `sieve-sqrt`: correctly
//! rounded like libm's (the same bits), but the compiler's own instruction on x86-64, so a hot
//! loop compiled for AVX does not pay an SSE/AVX transition per call (docs/simd.md). The trait
//! is deliberately small: it is what the model needs.

use core::fmt::Debug;
use core::ops::{Add, AddAssign, Div, Mul, MulAssign, Neg, Sub, SubAssign};

use crate::hash::Fnv64;

/// A real number type the solver can run in.
pub trait Real:
    Copy
    + Default
    + Debug
    + PartialOrd
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + SubAssign
    + MulAssign
    + Send
    + Sync
    + 'static
{
    /// 0
    const ZERO: Self;
    /// 1
    const ONE: Self;
    /// 1/2
    const HALF: Self;
    /// 2
    const TWO: Self;
    /// -1
    const NEG_ONE: Self;
    /// Default [`crate::segregation::SegregationConfig::flush_below`]: tracked fractions
    /// smaller than this are set to zero after each update. f64: 2^-800 (about 1.5e-241), far
    /// enough above the subnormal range (below 2^-1022) that products with any flux
    /// coefficient stay normal; f32: 0 (off), see docs/model.md 5.6.
    const FLUSH_BELOW: Self;
    /// Default volume fraction below which a cell counts as empty (1e-6).
    const VACUUM: Self;
    /// Largest finite value.
    const MAX: Self;
    /// Machine epsilon.
    const EPSILON: Self;
    /// Name used in summaries ("f32" / "f64").
    const NAME: &'static str;

    /// Conversion from f64 (rounds to nearest for f32).
    fn from_f64(x: f64) -> Self;
    /// Exact widening to f64.
    fn to_f64(self) -> f64;
    /// Conversion of a count (exact for the grid sizes used here).
    fn from_usize(n: usize) -> Self {
        Self::from_f64(n as f64)
    }
    /// Correctly rounded square root.
    fn sqrt(self) -> Self;
    /// Natural logarithm (libm).
    fn ln(self) -> Self;
    /// Exponential (libm).
    fn exp(self) -> Self;
    /// Sine (libm).
    fn sin(self) -> Self;
    /// Cosine (libm).
    fn cos(self) -> Self;
    /// Power (libm).
    fn powf(self, e: Self) -> Self;
    /// Absolute value.
    fn abs(self) -> Self;
    /// True unless NaN or infinite.
    fn is_finite(self) -> bool;
    /// Feeds the little-endian bytes into a hash; `-0.0` is canonicalised to `+0.0`.
    fn hash_into(self, h: &mut Fnv64);
    /// Bit pattern widened to u64 (f32 bits in the low half), for serialisation.
    fn to_bits_u64(self) -> u64;
    /// Conversion to an integer, truncating towards zero, saturating at the ends of `i128`,
    /// NaN to 0 (Rust's `as`: the same on every target; [`crate::sum::FixedSum`]).
    fn trunc_to_i128(self) -> i128;

    /// Larger of two values (the second if either is NaN-free and equal).
    #[inline(always)]
    fn max(self, other: Self) -> Self {
        if self > other {
            self
        } else {
            other
        }
    }
    /// Smaller of two values.
    #[inline(always)]
    fn min(self, other: Self) -> Self {
        if self < other {
            self
        } else {
            other
        }
    }
}

macro_rules! impl_real {
    ($t:ty, $name:literal, $flush:expr, $sqrt:path, $ln:path, $exp:path, $sin:path, $cos:path, $pow:path, $abs:path) => {
        impl Real for $t {
            const ZERO: Self = 0.0;
            const ONE: Self = 1.0;
            const HALF: Self = 0.5;
            const TWO: Self = 2.0;
            const NEG_ONE: Self = -1.0;
            const VACUUM: Self = 1e-6;
            const FLUSH_BELOW: Self = $flush;
            const MAX: Self = <$t>::MAX;
            const EPSILON: Self = <$t>::EPSILON;
            const NAME: &'static str = $name;
            #[inline(always)]
            fn from_f64(x: f64) -> Self {
                x as $t
            }
            #[inline(always)]
            fn to_f64(self) -> f64 {
                self as f64
            }
            #[inline(always)]
            fn trunc_to_i128(self) -> i128 {
                self as i128
            }
            #[inline(always)]
            fn sqrt(self) -> Self {
                $sqrt(self)
            }
            #[inline(always)]
            fn ln(self) -> Self {
                $ln(self)
            }
            #[inline(always)]
            fn exp(self) -> Self {
                $exp(self)
            }
            #[inline(always)]
            fn sin(self) -> Self {
                $sin(self)
            }
            #[inline(always)]
            fn cos(self) -> Self {
                $cos(self)
            }
            #[inline(always)]
            fn powf(self, e: Self) -> Self {
                $pow(self, e)
            }
            #[inline(always)]
            fn abs(self) -> Self {
                $abs(self)
            }
            #[inline(always)]
            fn is_finite(self) -> bool {
                <$t>::is_finite(self)
            }
            #[inline]
            fn hash_into(self, h: &mut Fnv64) {
                // x + 0.0 maps -0.0 to +0.0 and leaves every other value unchanged.
                h.write(&(self + 0.0).to_le_bytes());
            }
            #[inline]
            fn to_bits_u64(self) -> u64 {
                self.to_bits() as u64
            }
        }
    };
}

impl_real!(
    f64,
    "f64",
    f64::from_bits(223u64 << 52), // 2^-800
    sieve_sqrt::sqrt,
    libm::log,
    libm::exp,
    libm::sin,
    libm::cos,
    libm::pow,
    libm::fabs
);
impl_real!(
    f32,
    "f32",
    0.0,
    sieve_sqrt::sqrtf,
    libm::logf,
    libm::expf,
    libm::sinf,
    libm::cosf,
    libm::powf,
    libm::fabsf
);
