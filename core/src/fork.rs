//! Fork-join: how a host runs one loop of the core on several threads and gets the serial
//! bits (docs/parallel.md, "The coupled flow on threads").
//!
//! The core stays single-threaded and `unsafe`-free: it never spawns anything. A loop that
//! may run in parts cuts its *output* into disjoint chunks (`split_at_mut`, so the borrow
//! checker proves they do not overlap), packs each chunk with the read-only data it needs into
//! an item, and hands the items to a [`Fork`], which calls the same closure on every item, in
//! any order and on any thread, and returns when all are done. The host implements [`Fork`]
//! with its thread pool; [`Serial`] is the plain loop.
//!
//! Why the bits do not depend on the number of parts: every element of an output is computed
//! by the same arithmetic whichever chunk holds it, and a sum is cut only at [`sum::BLOCK`]
//! boundaries into the block partials of the serial blocked sum, folded in block order by one
//! thread ([`sum::fold`]). So [`Fork::parts`] is a hint on how many chunks to cut, never an
//! input of the result; `tests/tests/flow_threads.rs` asserts equal state bits for 1 to 4
//! parts after every step, `tests/tests/flow_cg.rs` equal solves for 1 to 5 parts.

use core::marker::PhantomData;
use core::ops::Range;

use crate::hot::{Baseline, HotLoop, Isa};
use crate::real::Real;
use crate::sum::{self, BLOCK};

/// The most parts a loop is cut into (a fixed bound keeps the item lists on the stack).
pub const MAX_PARTS: usize = 64;

/// Ranges of a loop cut into parts.
pub type Cuts = heapless::Vec<Range<usize>, MAX_PARTS>;

/// Runs the items of one loop, possibly several at once, and returns when all are done.
pub trait Fork: Sync {
    /// The instruction set this fork's hot loops are compiled for ([`crate::hot`],
    /// docs/simd.md): a type, so that a step generic over the fork runs every hot loop of its
    /// stages (the flow's solves, the segregation's percolation and prepare) at that width,
    /// whichever way it reaches them ([`Self::hot`] or `Self::Isa` as a type parameter).
    /// Every choice gives the same bits.
    type Isa: Isa;

    /// How many parts a loop should be cut into (at least 1): the number of workers. The
    /// results never depend on it.
    fn parts(&self) -> usize;

    /// Calls `f` once on every item of `items`, in any order, on any thread.
    fn each<T: Send, F: Fn(&mut T) + Sync>(&self, items: &mut [T], f: F);

    /// Elements per worker below which a loop runs on the caller's thread ([`worth`]).
    /// Tests lower it to cut small grids in odd places.
    fn min_per_part(&self) -> usize {
        MIN_PER_PART
    }

    /// Runs one hot loop compiled for [`Self::Isa`].
    #[inline(always)]
    fn hot<H: HotLoop>(&self, hot: H) -> H::Out {
        Self::Isa::run(hot)
    }
}

/// A closure as a [`HotLoop`]: its body is compiled into the runner that calls it when the
/// closure and the functions it calls are `#[inline(always)]`. `FnMut`, not `FnOnce`: calling
/// a borrowing closure through `FnOnce` goes through a shim of the standard library that is
/// not inlined, and the loop would stay at the baseline (seen in the profile).
pub struct Call<F>(pub F);

impl<T, F: FnMut() -> T> HotLoop for Call<F> {
    type Out = T;
    #[inline(always)]
    fn run(mut self) -> T {
        (self.0)()
    }
}

/// The plain loop: one part, the caller's thread.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Serial;

impl Fork for Serial {
    type Isa = Baseline;

    fn parts(&self) -> usize {
        1
    }

    fn each<T: Send, F: Fn(&mut T) + Sync>(&self, items: &mut [T], f: F) {
        for item in items {
            f(item);
        }
    }
}

/// The plain loop at the instruction set `I`: one part, the caller's thread (what
/// `Segregation::prepare_on::<I>` runs its cut passes on).
pub struct SerialAt<I>(PhantomData<fn() -> I>);

impl<I> SerialAt<I> {
    /// The fork (a zero-sized value).
    pub const fn new() -> Self {
        Self(PhantomData)
    }
}

impl<I> Default for SerialAt<I> {
    fn default() -> Self {
        Self::new()
    }
}

impl<I: Isa> Fork for SerialAt<I> {
    type Isa = I;

    fn parts(&self) -> usize {
        1
    }

    fn each<T: Send, F: Fn(&mut T) + Sync>(&self, items: &mut [T], f: F) {
        for item in items {
            f(item);
        }
    }
}

/// A share of a fork's workers: `parts` of them, at the fork's instruction set. What the
/// loops of one of several concurrent items run on (two velocity solves side by side each
/// get half the workers); with one part they run on the item's own thread. The bits do not
/// depend on it, as for any fork.
pub struct Share<'a, F> {
    fork: &'a F,
    parts: usize,
}

impl<'a, F: Fork> Share<'a, F> {
    /// `parts` (at least 1) of `fork`'s workers.
    pub fn new(fork: &'a F, parts: usize) -> Self {
        Self {
            fork,
            parts: parts.max(1),
        }
    }
}

impl<F: Fork> Fork for Share<'_, F> {
    type Isa = F::Isa;

    fn parts(&self) -> usize {
        self.parts
    }

    fn each<T: Send, G: Fn(&mut T) + Sync>(&self, items: &mut [T], f: G) {
        self.fork.each(items, f);
    }

    fn min_per_part(&self) -> usize {
        self.fork.min_per_part()
    }
}

/// Cuts `0..n` into at most `parts` consecutive ranges whose inner boundaries are multiples
/// of `unit`, as even as whole units allow (at least one range; no empty one unless `n == 0`).
pub fn cuts(n: usize, parts: usize, unit: usize) -> Cuts {
    let unit = unit.max(1);
    let units = n.div_ceil(unit);
    let parts = parts.clamp(1, MAX_PARTS).min(units.max(1));
    let mut out = Cuts::new();
    let mut start = 0;
    for p in 0..parts {
        // the first `units % parts` parts take one unit more
        let take = units / parts + usize::from(p < units % parts);
        let end = (start + take * unit).min(n);
        let _ = out.push(start..end); // at most MAX_PARTS pushes
        start = end;
    }
    out
}

/// Elements per worker below which a loop runs on the caller's thread: waking a pool's
/// worker for a fork costs microseconds (an empty fork between busy workers 0.09 us,
/// `host/benches/fork.rs`), a pass over 2,048 cells about as much.
pub const MIN_PER_PART: usize = 8 * BLOCK;

/// Whether a loop of `n` elements is worth cutting: more than one worker and at least
/// [`Fork::min_per_part`] elements each. Decides only the speed, never the bits.
pub fn worth<F: Fork>(fork: &F, n: usize) -> bool {
    fork.parts() > 1 && n >= fork.min_per_part().max(1) * fork.parts()
}

/// Splits `s` at the boundaries of `cuts` (which cover `0..s.len()` in order).
pub fn split<'a, T>(mut s: &'a mut [T], cuts: &Cuts) -> heapless::Vec<&'a mut [T], MAX_PARTS> {
    let mut out = heapless::Vec::new();
    for c in cuts {
        let (mine, rest) = core::mem::take(&mut s).split_at_mut(c.len());
        let _ = out.push(mine); // as many as cuts
        s = rest;
    }
    out
}

/// `f(start, chunk)` for chunks of `out` that start at multiples of `unit`: an element-wise
/// loop (each output element written from shared inputs) on the fork's workers, or
/// `f(0, out)` on the caller's thread when `out` is not [`worth`] cutting (the same bits:
/// each element is written by the same arithmetic in any chunk).
pub fn chunks<T: Send, F: Fork>(
    fork: &F,
    out: &mut [T],
    unit: usize,
    f: impl Fn(usize, &mut [T]) + Sync,
) {
    if worth(fork, out.len()) {
        each_chunk(fork, out, unit, f);
    } else {
        f(0, out);
    }
}

/// [`chunks`] cut whatever the length (the caller decided it is worth it).
fn each_chunk<T: Send, F: Fork>(
    fork: &F,
    out: &mut [T],
    unit: usize,
    f: impl Fn(usize, &mut [T]) + Sync,
) {
    let cuts = cuts(out.len(), fork.parts(), unit);
    let mut items: heapless::Vec<(usize, &mut [T]), MAX_PARTS> = heapless::Vec::new();
    for (c, chunk) in cuts.iter().zip(split(out, &cuts)) {
        let _ = items.push((c.start, chunk));
    }
    fork.each(&mut items, |(start, chunk)| f(*start, chunk));
}

/// `sum_i a_i b_i` with the bits of [`sum::dot`], the blocks shared out among the workers.
/// `partials` holds at least `n / BLOCK + 1` values (scratch).
pub fn dot<R: Real, F: Fork>(fork: &F, a: &[R], b: &[R], partials: &mut [R]) -> R {
    let n = a.len().min(b.len());
    if !worth(fork, n) {
        return fork.hot(Call(
            #[inline(always)]
            || sum::dot(a, b),
        ));
    }
    let nb = n.div_ceil(BLOCK);
    each_chunk(fork, &mut partials[..nb], 1, |first, p| {
        fork.hot(Call(
            #[inline(always)]
            || {
                for (k, pk) in p.iter_mut().enumerate() {
                    let s = (first + k) * BLOCK;
                    let e = (s + BLOCK).min(n);
                    // one block of the serial sum: `0 + its lane tree`, exactly what the serial
                    // loop adds to its running total
                    *pk = sum::dot(&a[s..e], &b[s..e]);
                }
            },
        ))
    });
    sum::fold(&partials[..nb])
}

/// `out_i = new(i, out_i)` for every element: an element-wise pass, cut among the workers
/// when [`worth`] it, each part a hot loop ([`Fork::hot`]). The same bits in any part.
pub fn set<R: Real, F: Fork>(fork: &F, out: &mut [R], new: impl Fn(usize, R) -> R + Sync) {
    chunks(fork, out, 1, |start, chunk| {
        fork.hot(Call(
            #[inline(always)]
            || {
                for (k, v) in chunk.iter_mut().enumerate() {
                    *v = new(start + k, *v);
                }
            },
        ))
    });
}

/// `out_i = new(i, out_i)` for every element, then `sum_i w_i out_i` with `w = with` (or `out`
/// itself when `None`), in the bits of [`sum::dot`]: one fused pass on the caller's thread
/// when `out` is not [`worth`] cutting, else the element-wise pass and [`dot`] on the
/// workers. `partials` as for [`dot`].
pub fn set_and_dot<R: Real, F: Fork>(
    fork: &F,
    out: &mut [R],
    with: Option<&[R]>,
    new: impl Fn(usize, R) -> R + Sync,
    partials: &mut [R],
) -> R {
    let n = out.len();
    if !worth(fork, n) {
        return fork.hot(Call(
            #[inline(always)]
            || match with {
                None => sum::reduce(n, |i| {
                    out[i] = new(i, out[i]);
                    out[i] * out[i]
                }),
                Some(w) => sum::reduce(n, |i| {
                    out[i] = new(i, out[i]);
                    w[i] * out[i]
                }),
            },
        ));
    }
    set(fork, out, new);
    match with {
        None => dot(fork, out, out, partials),
        Some(w) => dot(fork, w, out, partials),
    }
}

/// The conjugate-gradient update `x += alpha p; r -= alpha q`, returning `sum r_i^2` with the
/// bits of [`sum::update`], on the fork's workers. `partials` as for [`dot`].
pub fn update<R: Real, F: Fork>(
    fork: &F,
    alpha: R,
    p: &[R],
    q: &[R],
    x: &mut [R],
    r: &mut [R],
    partials: &mut [R],
) -> R {
    let n = x.len().min(r.len()).min(p.len()).min(q.len());
    if !worth(fork, n) {
        return fork.hot(Call(
            #[inline(always)]
            || sum::update(alpha, p, q, x, r),
        ));
    }
    let nb = n.div_ceil(BLOCK);
    let cuts = cuts(n, fork.parts(), BLOCK);
    let block_cuts: Cuts = cuts
        .iter()
        .map(|c| c.start / BLOCK..c.end.div_ceil(BLOCK))
        .collect();
    type Item<'a, R> = (usize, &'a mut [R], &'a mut [R], &'a mut [R]);
    let mut items: heapless::Vec<Item<'_, R>, MAX_PARTS> = heapless::Vec::new();
    let parts = split(&mut x[..n], &cuts)
        .into_iter()
        .zip(split(&mut r[..n], &cuts))
        .zip(split(&mut partials[..nb], &block_cuts));
    for (c, ((xc, rc), pc)) in cuts.iter().zip(parts) {
        let _ = items.push((c.start, xc, rc, pc));
    }
    fork.each(&mut items, |(start, xc, rc, pc)| {
        fork.hot(Call(
            #[inline(always)]
            || {
                let blocks = xc.chunks_mut(BLOCK).zip(rc.chunks_mut(BLOCK));
                for (k, (xb, rb)) in blocks.enumerate() {
                    let s = *start + k * BLOCK;
                    let e = s + xb.len();
                    pc[k] = sum::update(alpha, &p[s..e], &q[s..e], xb, rb);
                }
            },
        ))
    });
    drop(items);
    sum::fold(&partials[..nb])
}
