//! Sums whose bits depend only on the data and on one fixed constant, [`BLOCK`]: never on the
//! order in which a driver visits the data, on the number of threads or ranks, or on the
//! compiler's choice of vector width.
//!
//! # The scheme
//! The index range `0..n` is cut into blocks of [`BLOCK`] terms (the last one may be short).
//! Inside a block, term `i` goes to lane `i % LANES` of [`LANES`] independent accumulators,
//! each summed in index order; the lanes are combined in a fixed tree
//! `((l0 + l1) + (l2 + l3)) + ((l4 + l5) + (l6 + l7))`, giving the block's partial sum. The
//! partials are then added in block order, starting from 0 ([`fold`]).
//!
//! Why lanes: a plain `s += x[i]` loop is a chain of dependent additions and runs at one add
//! per floating-point latency (4 cycles here); eight independent chains fill the pipeline
//! and the vector units, so a dot product runs at memory speed (the conjugate-gradient loops
//! of the flow, [`crate::flow::cg`], were dominated by such chains). Rust never reassociates
//! floating-point sums, so the lanes are spelled out and the bits are the same whatever the
//! target's vector width.
//!
//! Why blocks: a threaded or distributed driver splits the cells into chunks. If every chunk
//! boundary is a multiple of [`BLOCK`] (a grid row of a subdomain decomposition along the last
//! axis is, when rows are padded to blocks), each chunk computes exactly the block partials
//! of the serial sum ([`block_partials`]) and one place folds them in block order: the same
//! bits for 1, 2 or 64 workers. `tests/tests/flow_cg.rs` asserts it.
//!
//! Cut anywhere: a distributed driver whose parts are whole grid rows cannot choose its cuts
//! (a row of 29 or 58 cells is no multiple of [`BLOCK`]), and a part may be shorter than a
//! block. The serial bits survive any cut, with two small exchanges: a block that begins in
//! one part and ends in later ones is summed by the part where it begins, which borrows the
//! missing terms (at most `BLOCK - 1`) from the parts after it ([`lent`], [`borrowed`],
//! [`cut_partials`]); and the fold of the partials in block order runs along the parts, each
//! continuing from the running total of the parts before it ([`fold_from`]). The terms are
//! the serial terms (each part computes its own products), so each block is the serial
//! block, and the fold is the serial fold: the same bits as [`reduce`] over `0..n`, for any
//! number and placement of cuts, at the price of one message of at most `BLOCK - 1` terms per
//! cut and a chain of one number through the parts (docs/parallel.md).
//!
//! # Against an exact accumulator
//! An exact (superaccumulator, xsum) or binned (ReproBLAS) sum is independent of *any* order
//! and decomposition, not only of splits at block boundaries, and correctly rounded. Its
//! price is a split of every term into chunks of a wide integer accumulator (xsum reports
//! 2-5x a plain sum at best; the big accumulator needs ~70 words for f64), and it cannot use
//! the lanes of a vector unit without the same blocking. The flow's CG takes three of these
//! sums per iteration over arrays that stay in cache, so their cost is the cost of the
//! solver; the blocked sum costs what a plain vectorised loop costs. Its error is that of
//! ordinary floating-point summation with depth `BLOCK / LANES + 2 + blocks` (bound in
//! [`error_bound`]), far below the solver's tolerance. Where a driver cannot align its
//! chunks to blocks, the block partials (a few per thousand terms) are what should go into
//! an exact accumulator: the hybrid keeps the fast inner loop.

use crate::real::Real;

/// Independent accumulators inside a block.
pub const LANES: usize = 8;
/// Terms per block: the only constant the bits depend on (a multiple of [`LANES`]).
pub const BLOCK: usize = 256;

/// The fixed combination tree of the lanes.
#[inline(always)]
pub fn combine<R: Real>(l: &[R; LANES]) -> R {
    ((l[0] + l[1]) + (l[2] + l[3])) + ((l[4] + l[5]) + (l[6] + l[7]))
}

/// `sum_i term(i)` over `0..n` by the blocked scheme of the module docs. `term` is called once
/// per index, in increasing order, so it may update the data it reads (fused loops: the
/// conjugate-gradient update `x += alpha p; r -= alpha A p` returns `r_i^2`).
#[inline(always)]
pub fn reduce<R: Real>(n: usize, mut term: impl FnMut(usize) -> R) -> R {
    let mut total = R::ZERO;
    let mut start = 0;
    while start < n {
        let end = (start + BLOCK).min(n);
        total += block(start, end, &mut term);
        start = end;
    }
    total
}

/// The partial sum of the block `start..end` (`start` a multiple of [`BLOCK`], `end - start`
/// at most [`BLOCK`]).
#[inline(always)]
pub fn block<R: Real>(start: usize, end: usize, term: &mut impl FnMut(usize) -> R) -> R {
    let mut l = [R::ZERO; LANES];
    let mut i = start;
    while i + LANES <= end {
        for (k, lk) in l.iter_mut().enumerate() {
            *lk += term(i + k);
        }
        i += LANES;
    }
    for (k, lk) in l.iter_mut().enumerate().take(end - i) {
        *lk += term(i + k);
    }
    combine(&l)
}

/// The block partials of `term` over `start..end` into `out` (one per block; `start` a
/// multiple of [`BLOCK`]): what one worker of a threaded driver computes for its chunk.
/// Returns the number of partials written. [`fold`] of all chunks' partials, in block order,
/// is bit-identical to [`reduce`] over the whole range. (The aligned case of
/// [`cut_partials`]: a chunk that ends at a block boundary or at the end borrows nothing.)
pub fn block_partials<R: Real>(
    start: usize,
    end: usize,
    term: impl FnMut(usize) -> R,
    out: &mut [R],
) -> usize {
    debug_assert!(start % BLOCK == 0, "chunks must start at a block boundary");
    cut_partials(start, end, end, term, &[], out)
}

/// Adds block partials in order, from 0: the last stage of [`reduce`].
pub fn fold<R: Real>(partials: &[R]) -> R {
    fold_from(R::ZERO, partials)
}

/// `((prefix + p0) + p1) + ...`: [`fold`] continued from the running total of the partials
/// before these (`fold_from(0, p)` is `fold(p)`, bit for bit: `0 + p0` is `p0`). Parts of a sum
/// cut anywhere pass the total along: each folds its own partials from the total of the
/// parts before it, and the last one holds the serial sum.
pub fn fold_from<R: Real>(prefix: R, partials: &[R]) -> R {
    let mut total = prefix;
    for p in partials {
        total += *p;
    }
    total
}

/// The first index of the first block that begins at or after `i`.
fn block_start_from(i: usize) -> usize {
    i.div_ceil(BLOCK) * BLOCK
}

/// The terms at the head of the part `start..end` that belong to a block begun in an earlier
/// part (0 when `start` is a block boundary): the part hands these, in index order, to the
/// part where that block begins, which sums the block ([`cut_partials`]).
pub fn lent(start: usize, end: usize) -> usize {
    block_start_from(start).min(end) - start.min(end)
}

/// The terms past `end` that the part `start..end` of a sum over `0..n` needs to complete the
/// last block that begins in it: the [`lent`] terms of the parts after it, concatenated in
/// part order (0 if no block begins in it or its last block ends inside it).
pub fn borrowed(start: usize, end: usize, n: usize) -> usize {
    let first = block_start_from(start);
    if first >= end {
        return 0;
    }
    let last = first + (end - 1 - first) / BLOCK * BLOCK;
    (last + BLOCK).min(n).saturating_sub(end)
}

/// How many blocks begin in `start..end`: the partials [`cut_partials`] writes.
pub fn blocks_begun(start: usize, end: usize) -> usize {
    (block_start_from(end) - block_start_from(start).min(block_start_from(end))) / BLOCK
}

/// The partials of the blocks that begin in the part `start..end` of a sum over `0..n`, cut at
/// any point (module docs): `term(i)` for the part's own indices, called in increasing order
/// from the first block boundary in the part; `borrowed` holds the [`borrowed`] terms past
/// `end` (a shorter slice reads as zeros there, which no driver should rely on). Writes
/// [`blocks_begun`] partials into `out` and returns that number. [`fold_from`] of them,
/// continued part after part, is bit-identical to [`reduce`] over `0..n`.
pub fn cut_partials<R: Real>(
    start: usize,
    end: usize,
    n: usize,
    mut term: impl FnMut(usize) -> R,
    borrowed: &[R],
    out: &mut [R],
) -> usize {
    let mut k = 0;
    let mut s = block_start_from(start);
    while s < end {
        let e = (s + BLOCK).min(n);
        let partial = if e <= end {
            block(s, e, &mut term)
        } else {
            block(s, e, &mut |i: usize| {
                if i < end {
                    term(i)
                } else {
                    borrowed.get(i - end).copied().unwrap_or(R::ZERO)
                }
            })
        };
        if let Some(o) = out.get_mut(k) {
            *o = partial;
        }
        k += 1;
        s = e;
    }
    k
}

/// `sum_i x_i`.
pub fn sum<R: Real>(x: &[R]) -> R {
    reduce(x.len(), |i| x[i])
}

/// `sum_i a_i b_i` over the common length (the bits of `reduce(n, |i| a[i] * b[i])`, written
/// with chunked slices so that no index is checked in the loop). Inlined, so that a wider
/// runner ([`crate::hot`]) compiles it at its width.
#[inline(always)]
pub fn dot<R: Real>(a: &[R], b: &[R]) -> R {
    let n = a.len().min(b.len());
    let mut total = R::ZERO;
    for (ab, bb) in a[..n].chunks(BLOCK).zip(b[..n].chunks(BLOCK)) {
        let mut l = [R::ZERO; LANES];
        let (ac, bc) = (ab.chunks_exact(LANES), bb.chunks_exact(LANES));
        let (ar, br) = (ac.remainder(), bc.remainder());
        for (x, y) in ac.zip(bc) {
            for k in 0..LANES {
                l[k] += x[k] * y[k];
            }
        }
        for (k, (x, y)) in ar.iter().zip(br).enumerate() {
            l[k] += *x * *y;
        }
        total += combine(&l);
    }
    total
}

/// The conjugate-gradient update `x += alpha p; r -= alpha q`, returning `sum r_i^2` with the
/// bits of [`reduce`] (one pass over the four vectors). Inlined, as [`dot`].
#[inline(always)]
pub fn update<R: Real>(alpha: R, p: &[R], q: &[R], x: &mut [R], r: &mut [R]) -> R {
    let n = x.len().min(r.len()).min(p.len()).min(q.len());
    let mut total = R::ZERO;
    let blocks = x[..n]
        .chunks_mut(BLOCK)
        .zip(r[..n].chunks_mut(BLOCK))
        .zip(p[..n].chunks(BLOCK).zip(q[..n].chunks(BLOCK)));
    for ((xb, rb), (pb, qb)) in blocks {
        let mut l = [R::ZERO; LANES];
        let mut xc = xb.chunks_exact_mut(LANES);
        let mut rc = rb.chunks_exact_mut(LANES);
        let (pc, qc) = (pb.chunks_exact(LANES), qb.chunks_exact(LANES));
        let (pr, qr) = (pc.remainder(), qc.remainder());
        for ((xs, rs), (ps, qs)) in xc.by_ref().zip(rc.by_ref()).zip(pc.zip(qc)) {
            for k in 0..LANES {
                xs[k] += alpha * ps[k];
                rs[k] -= alpha * qs[k];
                l[k] += rs[k] * rs[k];
            }
        }
        let (xr, rr) = (xc.into_remainder(), rc.into_remainder());
        for k in 0..xr.len() {
            xr[k] += alpha * pr[k];
            rr[k] -= alpha * qr[k];
            l[k] += rr[k] * rr[k];
        }
        total += combine(&l);
    }
    total
}

/// Sums in cell order over a grid that may be cut into subdomains: what a step asks for the
/// few running sums whose serial bits feed its results (a guard's total, the discharge of a
/// side along the cut). On the whole grid ([`Whole`]) `part` runs once over every cell;
/// a subdomain continues the running sum of the subdomains before it over its own cells and
/// hands it on (`crate::flow::slab::Slab`), so the total has the serial bits.
pub trait InOrder<R> {
    /// Whether the grid is whole (nothing cut): the caller may then skip a sum it knows is
    /// empty, which a subdomain may not (every subdomain takes part in every sum).
    fn whole(&self) -> bool;

    /// Sums over all cells in cell order, starting from `start` (the same values on every
    /// subdomain): `part(s)` continues the serial running sums `s` over the cells this
    /// subdomain counts and returns them; the result is the serial sums' bits. `K` sums
    /// walked together travel together: one message per neighbour, not `K`.
    fn sums_in_order<const K: usize>(
        &mut self,
        start: [R; K],
        part: impl FnOnce([R; K]) -> [R; K],
    ) -> [R; K];

    /// One sum in cell order ([`Self::sums_in_order`] of one value).
    #[inline(always)]
    fn sum_in_order(&mut self, start: R, part: impl FnOnce(R) -> R) -> R {
        let [total] = self.sums_in_order([start], |[s]| [part(s)]);
        total
    }
}

/// The whole grid, nothing cut: every sum in order is the serial loop (and the flow's
/// [`crate::flow::reach::Reach`] of the grid alone).
#[derive(Clone, Copy, Debug, Default)]
pub struct Whole;

impl<R> InOrder<R> for Whole {
    #[inline(always)]
    fn whole(&self) -> bool {
        true
    }

    #[inline(always)]
    fn sums_in_order<const K: usize>(
        &mut self,
        start: [R; K],
        part: impl FnOnce([R; K]) -> [R; K],
    ) -> [R; K] {
        part(start)
    }
}

/// Fractional bits of [`FixedSum`]: a term is cut to a multiple of `2^-FIXED_FRAC`.
pub const FIXED_FRAC: u32 = 80;

/// `2^FIXED_FRAC`, exact in f32 and f64.
const FIXED_ONE: f64 = (1u128 << FIXED_FRAC) as f64;

/// A book kept in fixed point: an `i128` count of `2^-80`. Each term is cut once to that grid
/// (towards zero, so by less than `2^-80 ~ 8e-25` in absolute value), and the cut terms add
/// as integers, exactly. So the total depends on neither the order of the terms nor how
/// they are grouped: a subdomain books its own faces and a driver merges the books of any
/// number of threads or ranks, in any order, to the same bits (the last resort of the module
/// docs, used where terms arrive a few at a time from everywhere: the amounts that cross a
/// box's open sides, `Segregation::side_books`). Terms and totals up to `2^47 ~ 1.4e14` in
/// size are exact; beyond, a term or the total saturates at that size instead of wrapping
/// around (and only then does the order of additions matter again).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FixedSum(i128);

impl FixedSum {
    /// The empty book.
    pub const ZERO: Self = FixedSum(0);

    /// Adds `x`, cut to a multiple of `2^-80` towards zero (a NaN adds 0).
    #[inline]
    pub fn add<R: Real>(&mut self, x: R) {
        // `x * 2^80` is exact (a power of two, far from overflow for the terms booked here).
        let units = (x * R::from_f64(FIXED_ONE)).trunc_to_i128();
        self.0 = self.0.saturating_add(units);
    }

    /// Adds another book (exactly: merging in any order gives the same bits, below the
    /// saturation of the type docs).
    #[inline]
    pub fn merge(&mut self, other: FixedSum) {
        self.0 = self.0.saturating_add(other.0);
    }

    /// The total, rounded once to the nearest f64.
    pub fn to_f64(self) -> f64 {
        self.0 as f64 / FIXED_ONE
    }

    /// The raw count of `2^-80` as its low and high 64 bits (messages, checkpoints).
    pub fn to_words(self) -> [u64; 2] {
        let bits = self.0 as u128;
        [bits as u64, (bits >> 64) as u64]
    }

    /// A book from [`Self::to_words`].
    pub fn from_words(w: [u64; 2]) -> Self {
        FixedSum((u128::from(w[0]) | (u128::from(w[1]) << 64)) as i128)
    }

    /// Per-side books (axis by axis, low then high) as words, two per book: what a rank's
    /// message and a checkpoint carry.
    pub fn words_of(books: &[[FixedSum; 2]]) -> impl Iterator<Item = u64> + '_ {
        books.iter().flatten().flat_map(|b| b.to_words())
    }

    /// The per-side books of [`Self::words_of`]; words missing at the end read as 0 (callers
    /// check the length: a checkpoint's entry, a rank's own message).
    pub fn sides_from_words<const D: usize>(w: &[u64]) -> [[FixedSum; 2]; D] {
        let word = |k: usize| w.get(k).copied().unwrap_or(0);
        let book = |k: usize| FixedSum::from_words([word(2 * k), word(2 * k + 1)]);
        core::array::from_fn(|a| [book(2 * a), book(2 * a + 1)])
    }
}

/// A bound on `|reduce(x) - sum x|` for `n` terms: `gamma_k sum |x_i|` with
/// `gamma_k = k u / (1 - k u)`, `u = EPSILON / 2` and `k` the longest chain of additions a
/// term passes through (lane, tree, fold). The classical bound of recursive summation
/// (Higham, Accuracy and Stability of Numerical Algorithms, 4.2) applied to that tree.
pub fn error_bound<R: Real>(n: usize, sum_abs: R) -> R {
    let blocks = n.div_ceil(BLOCK).max(1);
    let k = BLOCK / LANES + 3 + blocks;
    let ku = R::from_usize(k) * R::EPSILON * R::HALF;
    ku / (R::ONE - ku) * sum_abs
}
