//! Hot loops as values, and the instruction sets that run them (docs/simd.md).
//!
//! The core has no `unsafe` and is compiled at the crate's target features. A host that
//! finds a wider vector unit at run time (sieve's host/src/isa.rs) cannot recompile the core,
//! but it can compile a *loop* again: a loop packaged as a [`HotLoop`] value whose `run` is
//! `#[inline(always)]` is compiled into whichever function calls it, at that function's
//! target features. So the core hands its hottest loops to an [`Isa`] (the segregation step,
//! as a type parameter: [`crate::Segregation::step_on`]) or to a [`crate::fork::Fork`] (the
//! coupled and flow steps: the fork's type names its instruction set, `Fork::Isa`, and
//! [`crate::fork::Fork::hot`] runs a loop with it), and the host's runner calls them inside a
//! `#[target_feature]` function.
//!
//! Same bits at every width: the loops are the same IEEE additions, multiplications,
//! divisions, square roots and exact maxima in the same order. Rust never contracts `a*b+c`
//! into an FMA, and every sum has a fixed order ([`crate::sum`]), so a vector lane computes
//! exactly what the scalar code computes.

/// One hot loop, packaged as a value so that an [`Isa`] can run it inside a function of its
/// choosing. `run` is `#[inline(always)]` in every implementation: the loop is compiled into
/// the caller, at the caller's target features.
pub trait HotLoop {
    /// What the loop returns.
    type Out;
    /// Runs the loop.
    fn run(self) -> Self::Out;
}

/// The instruction set hot loops are compiled for. [`Baseline`] is the crate's own target
/// features; a host supplies wider runners whose `run` calls a `#[target_feature]` function
/// into which the loop is inlined. Every runner gives the same bits.
pub trait Isa {
    /// Runs `hot`, compiled for this instruction set.
    fn run<H: HotLoop>(hot: H) -> H::Out;
}

/// The crate's own target features: each hot loop one out-of-line function, the code the
/// loops had before they were values.
pub struct Baseline;

impl Isa for Baseline {
    #[inline(never)]
    fn run<H: HotLoop>(hot: H) -> H::Out {
        hot.run()
    }
}
