//! Sums over MPI ranks with the bits of the serial sum, whatever rows each rank owns: the
//! blocked sum of `sieve_core::sum` cut at the ranks' boundaries ("Cut anywhere" there). A
//! rank lends the head of its part that belongs to a block begun on an earlier rank to that
//! rank, borrows the tail its own last block needs from the ranks after it, and folds its
//! block partials from the running total of the ranks before it; the last rank's total,
//! broadcast, is every rank's result. What the coupled flow's conjugate-gradient dot
//! products need under mpirun (docs/parallel.md, "Not done"): cuts between grid rows are
//! not block boundaries, and the serial bits are the promise.
//!
//! Cost per sum: at most one message of fewer than `BLOCK` terms per cut, a chain of one
//! number through the ranks (latency grows with the number of ranks), and one broadcast.
//! Every wait polls with short sleeps as the run's halo exchange does, so that a waiting rank
//! leaves the CPU to the one it waits for on a machine with more ranks than cores.

use crate::parallel_mpi::{broadcast_politely, receive_politely, wait_politely};
use mpi::traits::*;
use sieve_core::{sum, Real};
use std::ops::Range;

/// Tags of the lent terms and of the running total (apart from the run's own, 40-45).
const TAG_LENT: i32 = 46;
const TAG_RUNNING: i32 = 47;

/// `sum_i term(i)` over `0..n`, bit-identical to `sum::reduce(n, term)`, on every rank of
/// `comm`. `parts[r]` is the index range rank `r` owns; the parts follow each other in rank
/// order from 0 to `n` (empty ones allowed), and every rank passes the same list. This rank
/// calls `term` for its own indices only, each once, in increasing order. Collective: every
/// rank of `comm` calls it, with the same `parts`.
pub fn reduce_across<R: Real, C: Communicator>(
    comm: &C,
    parts: &[Range<usize>],
    mut term: impl FnMut(usize) -> R,
) -> R {
    let (rank, size) = (comm.rank() as usize, comm.size() as usize);
    debug_assert_eq!(parts.len(), size, "one part per rank");
    debug_assert!(parts.windows(2).all(|w| w[0].end == w[1].start));
    let n = parts.last().map_or(0, |p| p.end);
    let Range { start: a, end: b } = parts[rank].clone();
    // terms travel as f64: an f32 term widens and narrows back exactly
    let lent: Vec<f64> = (a..a + sum::lent(a, b)).map(|i| term(i).to_f64()).collect();
    let owner = (!lent.is_empty())
        .then(|| {
            let begun = a / sum::BLOCK * sum::BLOCK;
            parts.iter().position(|p| p.start <= begun && begun < p.end)
        })
        .flatten();
    let need = sum::borrowed(a, b, n);
    let mut borrowed = vec![0.0f64; need];
    mpi::request::scope(|sc| {
        let send = owner.map(|o| {
            comm.process_at_rank(o as i32)
                .immediate_send_with_tag(sc, &lent[..], TAG_LENT)
        });
        // the ranks after this one lend their heads in order until the block is whole
        let (mut got, mut q) = (0, rank + 1);
        while got < need && q < size {
            let l = sum::lent(parts[q].start, parts[q].end);
            if l > 0 {
                receive_politely(comm, q, TAG_LENT, &mut borrowed[got..got + l]);
            }
            got += l;
            q += 1;
        }
        if let Some(s) = send {
            wait_politely(s);
        }
    });
    let borrowed: Vec<R> = borrowed.into_iter().map(R::from_f64).collect();
    let mut partials = vec![R::ZERO; sum::blocks_begun(a, b)];
    sum::cut_partials(a, b, n, &mut term, &borrowed, &mut partials);
    let mut running = [0.0f64];
    if rank > 0 {
        receive_politely(comm, rank - 1, TAG_RUNNING, &mut running);
    }
    let total = sum::fold_from(R::from_f64(running[0]), &partials);
    running[0] = total.to_f64();
    if rank + 1 < size {
        comm.process_at_rank(rank as i32 + 1)
            .send_with_tag(&running[..], TAG_RUNNING);
    }
    broadcast_politely(comm, size - 1, &mut running);
    R::from_f64(running[0])
}
