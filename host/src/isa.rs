//! Run-time dispatch of the hot loops (the segregation step's, the coupled and flow steps')
//! to the widest vector unit of the machine (issue 12, docs/simd.md).
//!
//! A portable x86-64 binary is compiled for SSE2; the step's loops then run about half as fast
//! as in a binary compiled for the local CPU. The core stays free of `unsafe` and compiled at
//! the crate's features: it runs each hot loop through an [`Isa`] type parameter
//! ([`Segregation::step_on`]) or through the fork of the coupled and flow steps, whose type
//! names the instruction set ([`AtLevel`], [`on_level!`](crate::on_level)), and this
//! module supplies runners whose `run` calls a `#[target_feature]` function into which the loop
//! (`#[inline(always)]`) is compiled. The level is chosen once per process: the `SIEVE_ISA`
//! environment variable (`auto`, the default; `baseline`; `avx2`; `avx512`), checked against
//! what the CPU has.
//!
//! Same bits on every level: the loops are the same IEEE additions, multiplications,
//! divisions, square roots and exact maxima in the same order. Rust never contracts `a*b+c`
//! into an FMA (with or without the `fma` feature), and the core's sums have a fixed order, so
//! the wider code computes lane by lane what the SSE2 code computes (host/tests/isa.rs
//! compares the state hashes level by level).

use crate::error::{Error, Result};
use sieve_core::fork::Fork;
use sieve_core::geometry::CutCells;
pub use sieve_core::hot::Baseline;
use sieve_core::hot::{HotLoop, Isa};
use sieve_core::{Real, Segregation};
use std::marker::PhantomData;
use std::sync::OnceLock;

/// An instruction-set level of the step's hot loops.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Level {
    /// The binary's own target features (SSE2 in a portable x86-64 build).
    Baseline,
    /// x86-64-v3: AVX2 (256-bit vectors).
    Avx2,
    /// x86-64-v4: AVX-512 F/BW/CD/DQ/VL (512-bit vectors).
    Avx512,
}

impl Level {
    /// The name `SIEVE_ISA` takes.
    pub fn name(self) -> &'static str {
        match self {
            Level::Baseline => "baseline",
            Level::Avx2 => "avx2",
            Level::Avx512 => "avx512",
        }
    }

    /// Whether this CPU can run the level.
    pub fn available(self) -> bool {
        match self {
            Level::Baseline => true,
            #[cfg(target_arch = "x86_64")]
            Level::Avx2 => x86::has_v3(),
            #[cfg(target_arch = "x86_64")]
            Level::Avx512 => x86::has_v4(),
            #[cfg(not(target_arch = "x86_64"))]
            Level::Avx2 | Level::Avx512 => false,
        }
    }

    /// The widest level this CPU runs.
    pub fn widest() -> Level {
        [Level::Avx512, Level::Avx2]
            .into_iter()
            .find(|l| l.available())
            .unwrap_or(Level::Baseline)
    }
}

/// The level `SIEVE_ISA` asks for (`None`: unset or `auto`): exit 2 for an unknown name or a
/// level this CPU does not have.
pub fn requested(value: Option<&str>) -> Result<Level> {
    let level = match value.map(str::trim) {
        None | Some("") | Some("auto") => return Ok(Level::widest()),
        Some("baseline") => Level::Baseline,
        Some("avx2") => Level::Avx2,
        Some("avx512") => Level::Avx512,
        Some(other) => {
            return Err(Error::range(
                "environment",
                "SIEVE_ISA",
                other,
                "auto, baseline, avx2 or avx512",
            ))
        }
    };
    if !level.available() {
        return Err(Error::at(
            "environment",
            "SIEVE_ISA",
            format!(
                "{} is not supported by this CPU (it runs up to {})",
                level.name(),
                Level::widest().name()
            ),
        ));
    }
    Ok(level)
}

static LEVEL: OnceLock<Level> = OnceLock::new();

/// Fixes the level from `SIEVE_ISA` (the binary calls this at start-up, so a bad value exits 2
/// before any work). Later calls return the level fixed first.
pub fn init() -> Result<Level> {
    if let Some(l) = LEVEL.get() {
        return Ok(*l);
    }
    let level = requested(std::env::var("SIEVE_ISA").ok().as_deref())?;
    Ok(*LEVEL.get_or_init(|| level))
}

/// The level of this process: fixed by [`init`], or (in a library user that never called it)
/// from `SIEVE_ISA`, with the baseline for a value [`init`] would refuse.
pub fn level() -> Level {
    *LEVEL.get_or_init(|| {
        requested(std::env::var("SIEVE_ISA").ok().as_deref()).unwrap_or(Level::Baseline)
    })
}

/// [`Segregation::advance_to`] at `level`: the same steps and bits.
pub fn advance_to_at<R: Real, const D: usize, const N: usize>(
    level: Level,
    s: &mut Segregation<R, D, N>,
    t_end: R,
    max_steps: u64,
) -> u64 {
    crate::with_isa!(level, |I| s.advance_to_on::<I>(t_end, max_steps))
}

/// [`Segregation::advance_to`] at this process's [`level`].
pub fn advance_to<R: Real, const D: usize, const N: usize>(
    s: &mut Segregation<R, D, N>,
    t_end: R,
    max_steps: u64,
) -> u64 {
    advance_to_at(level(), s, t_end, max_steps)
}

/// [`Segregation::advance_to_embedded`] (cut cells) at this process's [`level`]: the same
/// steps and bits.
pub fn advance_to_embedded<R: Real, const D: usize, const N: usize>(
    s: &mut Segregation<R, D, N>,
    t_end: R,
    max_steps: u64,
    geo: &CutCells<R, D, N>,
) -> u64 {
    crate::with_isa!(level(), |I| s
        .advance_to_embedded_on::<I>(t_end, max_steps, geo))
}

/// [`Segregation::step`] at `level`: the same bits.
pub fn step_at<R: Real, const D: usize, const N: usize>(
    level: Level,
    s: &mut Segregation<R, D, N>,
    dt: R,
) {
    crate::with_isa!(level, |I| s.step_on::<I>(dt))
}

/// [`Segregation::step`] at this process's [`level`].
pub fn step<R: Real, const D: usize, const N: usize>(s: &mut Segregation<R, D, N>, dt: R) {
    step_at(level(), s, dt)
}

/// [`Segregation::step_embedded`] (cut cells) at this process's [`level`]: the same bits.
pub fn step_embedded<R: Real, const D: usize, const N: usize>(
    s: &mut Segregation<R, D, N>,
    dt: R,
    geo: &CutCells<R, D, N>,
) {
    crate::with_isa!(level(), |I| s.step_embedded_on::<I>(dt, geo))
}

/// A fork whose hot loops run compiled for `I`: how a coupled or flow step (its solves
/// through [`Fork::hot`], its segregation stages through `Fork::Isa`) reaches the wider
/// vector units. The level is a type, so one step is compiled once per level and the choice
/// is made once per step ([`on_level!`](crate::on_level)), not once per loop. Everything
/// else is the inner fork's.
pub struct AtLevel<'f, F: Fork, I: Isa> {
    fork: &'f F,
    isa: PhantomData<fn() -> I>,
}

impl<'f, F: Fork, I: Isa> AtLevel<'f, F, I> {
    /// `fork` with its hot loops compiled for `I`.
    pub fn new(fork: &'f F) -> Self {
        AtLevel {
            fork,
            isa: PhantomData,
        }
    }
}

impl<F: Fork, I: Isa> Fork for AtLevel<'_, F, I> {
    type Isa = I;

    fn parts(&self) -> usize {
        self.fork.parts()
    }

    fn each<T: Send, G: Fn(&mut T) + Sync>(&self, items: &mut [T], f: G) {
        self.fork.each(items, f)
    }

    fn min_per_part(&self) -> usize {
        self.fork.min_per_part()
    }
}

/// `with_isa!(level, |I| body)`: `body` with the type `I` bound to the runner of `level`
/// ([`Baseline`], [`Avx2`], [`Avx512`]), one monomorphised copy of `body` per level. The one
/// place that maps a level to its runner.
#[macro_export]
macro_rules! with_isa {
    ($level:expr, |$i:ident| $body:expr) => {
        match $level {
            $crate::isa::Level::Baseline => {
                type $i = $crate::isa::Baseline;
                $body
            }
            $crate::isa::Level::Avx2 => {
                type $i = $crate::isa::Avx2;
                $body
            }
            $crate::isa::Level::Avx512 => {
                type $i = $crate::isa::Avx512;
                $body
            }
        }
    };
}

/// `on_level!(level, fork, |f| body)`: `body` with `f` bound to `fork` at `level`
/// ([`AtLevel`] with the runner of [`with_isa!`](crate::with_isa)).
#[macro_export]
macro_rules! on_level {
    ($level:expr, $fork:expr, |$f:ident| $body:expr) => {{
        let fork = $fork;
        $crate::with_isa!($level, |LevelIsa| {
            let $f = &$crate::isa::AtLevel::<_, LevelIsa>::new(fork);
            $body
        })
    }};
}

/// The x86-64-v3 runner. Only [`Level::Avx2`] selects it, and only when the CPU has it.
pub struct Avx2;
/// The x86-64-v4 runner. Only [`Level::Avx512`] selects it, and only when the CPU has it.
pub struct Avx512;

#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod x86 {
    //! The one place with `unsafe` on the step's path.
    //!
    //! Why it is sound: a `#[target_feature]` function may only run on a CPU with those
    //! features. [`Avx2`] and [`Avx512`] are reached only through [`super::Level`], and a level
    //! is only ever selected after `is_x86_feature_detected!` found every feature its function
    //! enables ([`super::requested`] refuses the rest, [`super::Level::widest`] skips them);
    //! `run` checks again (once per process, cached) and falls back to the plain loop, so even
    //! a direct call on the wrong CPU stays defined behaviour.
    use super::{Avx2, Avx512, HotLoop, Isa};
    use std::sync::OnceLock;

    pub(super) fn has_v3() -> bool {
        static HAS: OnceLock<bool> = OnceLock::new();
        *HAS.get_or_init(|| {
            is_x86_feature_detected!("avx")
                && is_x86_feature_detected!("avx2")
                && is_x86_feature_detected!("bmi1")
                && is_x86_feature_detected!("bmi2")
                && is_x86_feature_detected!("f16c")
                && is_x86_feature_detected!("fma")
                && is_x86_feature_detected!("lzcnt")
                && is_x86_feature_detected!("movbe")
        })
    }

    pub(super) fn has_v4() -> bool {
        static HAS: OnceLock<bool> = OnceLock::new();
        *HAS.get_or_init(|| {
            has_v3()
                && is_x86_feature_detected!("avx512f")
                && is_x86_feature_detected!("avx512bw")
                && is_x86_feature_detected!("avx512cd")
                && is_x86_feature_detected!("avx512dq")
                && is_x86_feature_detected!("avx512vl")
        })
    }

    // `fma` is enabled with the rest of x86-64-v3, but nothing emits it: Rust lowers `a*b+c`
    // to a separate multiply and add (no contraction), and the core never calls `mul_add`.
    #[target_feature(enable = "avx,avx2,bmi1,bmi2,f16c,fma,lzcnt,movbe")]
    #[inline(never)]
    unsafe fn run_v3<H: HotLoop>(hot: H) -> H::Out {
        hot.run()
    }

    #[target_feature(
        enable = "avx,avx2,bmi1,bmi2,f16c,fma,lzcnt,movbe,avx512f,avx512bw,avx512cd,avx512dq,avx512vl"
    )]
    #[inline(never)]
    unsafe fn run_v4<H: HotLoop>(hot: H) -> H::Out {
        hot.run()
    }

    impl Isa for Avx2 {
        #[inline(always)]
        fn run<H: HotLoop>(hot: H) -> H::Out {
            if has_v3() {
                // SAFETY: the CPU has every feature `run_v3` enables (detected just above).
                unsafe { run_v3(hot) }
            } else {
                hot.run()
            }
        }
    }

    impl Isa for Avx512 {
        #[inline(always)]
        fn run<H: HotLoop>(hot: H) -> H::Out {
            if has_v4() {
                // SAFETY: the CPU has every feature `run_v4` enables (detected just above).
                unsafe { run_v4(hot) }
            } else {
                hot.run()
            }
        }
    }
}

#[cfg(not(target_arch = "x86_64"))]
mod other {
    //! No wider unit to dispatch to: the runners are the plain loops.
    use super::{Avx2, Avx512, HotLoop, Isa};

    impl Isa for Avx2 {
        #[inline(never)]
        fn run<H: HotLoop>(hot: H) -> H::Out {
            hot.run()
        }
    }

    impl Isa for Avx512 {
        #[inline(never)]
        fn run<H: HotLoop>(hot: H) -> H::Out {
            hot.run()
        }
    }
}
