//! The links a slab of `sieve_core::flow::cycle_slab` and `cg_slab` needs, over MPI ranks
//! that own slabs of rows in rank order from the floor up: rows to the rank above and below,
//! halo swaps, gathers, and sums with the serial bits ([`crate::rank_sum::reduce_across`]).
//! With it, the flow's conjugate gradients run across ranks with the serial iterations and
//! bits (docs/parallel.md, "The CG on slabs"; checked by `mpi_check --cg`).
//!
//! Messages carry f64 (an f32 value widens and narrows back exactly). Every wait but the
//! gathers' polls with short sleeps, as the run's halos do, so that a waiting rank leaves the
//! CPU to the one it waits for on a machine with more ranks than cores.

use crate::parallel_mpi::{narrow, receive_politely, send_widened, wait_politely, widen};
use mpi::datatype::PartitionMut;
use mpi::traits::*;
use sieve_core::flow::cycle_slab::Links;
use sieve_core::Real;
use std::ops::Range;

/// Tags of the rows sent up and down (apart from the run's 40-45, the sums' 46-47 and the
/// line pipelines' 48-49).
const TAG_UP: i32 = 50;
const TAG_DOWN: i32 = 51;

/// The links of this rank's slab.
pub struct RankLinks<'c, C> {
    comm: &'c C,
    rank: usize,
    size: usize,
    /// The fine cells each rank owns (global indices, in rank order): the parts of a sum.
    parts: Vec<Range<usize>>,
}

impl<'c, C: Communicator> RankLinks<'c, C> {
    /// The links of this rank of `comm`; `parts[r]` are the fine cells rank `r` owns.
    pub fn new(comm: &'c C, parts: Vec<Range<usize>>) -> Self {
        Self {
            comm,
            rank: comm.rank() as usize,
            size: comm.size() as usize,
            parts,
        }
    }
}

impl<R: Real, C: Communicator> Links<R> for RankLinks<'_, C> {
    fn send_up(&mut self, row: &[R]) {
        send_widened(self.comm, self.rank + 1, TAG_UP, row);
    }

    fn send_down(&mut self, row: &[R]) {
        send_widened(self.comm, self.rank - 1, TAG_DOWN, row);
    }

    fn receive_below(&mut self, row: &mut [R]) {
        let mut w = vec![0.0; row.len()];
        receive_politely(self.comm, self.rank - 1, TAG_UP, &mut w);
        narrow(&w, row);
    }

    fn receive_above(&mut self, row: &mut [R]) {
        let mut w = vec![0.0; row.len()];
        receive_politely(self.comm, self.rank + 1, TAG_DOWN, &mut w);
        narrow(&w, row);
    }

    fn swap(&mut self, bottom: &[R], top: &[R], below: &mut [R], above: &mut [R]) {
        let (comm, rank) = (self.comm, self.rank);
        let (has_below, has_above) = (rank > 0, rank + 1 < self.size);
        let (wb, wt) = (widen(bottom), widen(top));
        let (mut rb, mut ra) = (vec![0.0; below.len()], vec![0.0; above.len()]);
        mpi::request::scope(|sc| {
            // both sends go out before either receive waits: no order of the ranks deadlocks
            let down = has_below.then(|| {
                comm.process_at_rank(rank as i32 - 1)
                    .immediate_send_with_tag(sc, &wb[..], TAG_DOWN)
            });
            let up = has_above.then(|| {
                comm.process_at_rank(rank as i32 + 1)
                    .immediate_send_with_tag(sc, &wt[..], TAG_UP)
            });
            if has_below {
                receive_politely(comm, rank - 1, TAG_UP, &mut rb);
            }
            if has_above {
                receive_politely(comm, rank + 1, TAG_DOWN, &mut ra);
            }
            for s in [down, up].into_iter().flatten() {
                wait_politely(s);
            }
        });
        if has_below {
            narrow(&rb, below);
        }
        if has_above {
            narrow(&ra, above);
        }
    }

    fn gather(&mut self, own: &[R], all: &mut [R]) {
        let len = own.len() as i32;
        let mut counts = vec![0i32; self.size];
        self.comm.all_gather_into(&len, &mut counts[..]);
        let displs: Vec<i32> = counts
            .iter()
            .scan(0, |at, &c| {
                let d = *at;
                *at += c;
                Some(d)
            })
            .collect();
        let w = widen(own);
        let mut wa = vec![0.0; all.len()];
        {
            let mut part = PartitionMut::new(&mut wa[..], &counts[..], &displs[..]);
            self.comm.all_gather_varcount_into(&w[..], &mut part);
        }
        narrow(&wa, all);
    }

    fn sum(&mut self, own: &[R]) -> R {
        let start = self.parts[self.rank].start;
        crate::rank_sum::reduce_across(self.comm, &self.parts, |i| own[i - start])
    }
}
