//! What one flow step, or one coupled step, needs from beyond its own cells: the halo rows of
//! a neighbour, the other subdomains' share of a sum or a maximum, and the implicit solves over
//! the whole grid (docs/parallel.md, "The flow on slabs", "The coupled step on slabs").
//!
//! The steps ([`super::Flow::step_reaching`], [`super::coupled::Coupled::step_with_reaching`])
//! are written once. They ask a [`Reach`] at the few places where a value depends on cells
//! they do not own; [`Whole`], the grid alone, answers from the grid itself and compiles to
//! the serial step with its bits (every call is an identity or the serial solve). A slab of
//! rows answers through its neighbours ([`super::slab::Slab`]), so the same steps on slabs
//! have the serial bits.

use super::cg::{self, Scratch, Solve, Stencil, Stop};
use crate::fork::Fork;
use crate::real::Real;
use crate::sum::InOrder;
use core::ops::Range;

/// The flow step's view past its own cells. Every method is collective on a cut grid: every
/// subdomain calls it at the same point of the step, in the same order.
/// Its sums in cell order ([`InOrder`]) are the ones the segregation's carried transport
/// asks for too; on the whole grid ([`InOrder::whole`]) the step may also take the paths that
/// split the work between threads.
pub trait Reach<R: Real, const D: usize, const N: usize>: InOrder<R> {
    /// The cells this subdomain owns, of the `n` local ones: sums and maxima run over them.
    fn owned(&self, n: usize) -> Range<usize>;

    /// Overwrites the halo rows of `field` (a per-cell array of the local grid) with the
    /// values their owners hold.
    fn refresh(&mut self, field: &mut [R]);

    /// The largest of every subdomain's `x` (exact: a maximum does not round).
    fn max(&mut self, x: R) -> R;

    /// Solves `A x = b` ([`cg::solve_on`]) for the whole grid: on return the owned cells of
    /// `x` hold the serial solution's bits and its halo rows the neighbours'.
    #[allow(clippy::too_many_arguments)]
    fn solve<F: Fork>(
        &mut self,
        fork: &F,
        st: &Stencil<'_, R, D, N>,
        diag: &[R],
        b: &[R],
        x: &mut [R],
        sc: Scratch<'_, R>,
        stop: Stop<R>,
    ) -> Solve<R>;
}

/// The grid alone: nothing is cut, every answer comes from the grid itself (its sums in
/// order are the serial loops: [`crate::sum::Whole`]).
pub use crate::sum::Whole;

impl<R: Real, const D: usize, const N: usize> Reach<R, D, N> for Whole {
    #[inline(always)]
    fn owned(&self, n: usize) -> Range<usize> {
        0..n
    }

    #[inline(always)]
    fn refresh(&mut self, _field: &mut [R]) {}

    #[inline(always)]
    fn max(&mut self, x: R) -> R {
        x
    }

    #[inline(always)]
    fn solve<F: Fork>(
        &mut self,
        fork: &F,
        st: &Stencil<'_, R, D, N>,
        diag: &[R],
        b: &[R],
        x: &mut [R],
        sc: Scratch<'_, R>,
        stop: Stop<R>,
    ) -> Solve<R> {
        cg::solve_on(fork, st, diag, b, x, sc, stop)
    }
}
