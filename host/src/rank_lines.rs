//! The flow's line preconditioner across MPI ranks that own slabs of whole rows, with the
//! serial bits (`sieve_core::flow::line_slab`): the factor and the forward sweep climb the
//! ranks, the backward sweep descends them, each rank continuing from its neighbour's
//! boundary row. The columns go in `segments` pieces, so that the rank above starts on the
//! first piece while this one sweeps the next (a wavefront): with `m` pieces on `K` ranks a
//! sweep takes about `(m + K - 1) / m` of a perfectly shared one. The second of the three
//! parts the coupled flow under mpirun needs (docs/parallel.md, "Not done").

use crate::parallel_mpi::send_widened as send;
use mpi::traits::*;
use sieve_core::flow::line_slab;
use sieve_core::Real;
use std::ops::Range;

/// Tags of the rows handed up and down (apart from the run's, 40-45, and the sums', 46-47).
const TAG_UP: i32 = 48;
const TAG_DOWN: i32 = 49;

/// The column pieces of a row of `s` cells.
fn pieces(s: usize, segments: usize) -> Vec<Range<usize>> {
    let m = segments.clamp(1, s.max(1));
    (0..m).map(|k| k * s / m..(k + 1) * s / m).collect()
}

/// Receives a piece of a row from `from` into `row[c]` (waiting politely, as the halos do).
fn receive<C: Communicator>(comm: &C, from: usize, tag: i32, row: &mut [f64], c: &Range<usize>) {
    crate::parallel_mpi::receive_politely(comm, from, tag, &mut row[c.clone()]);
}

/// The first index of the last whole row of `len` values.
fn last_row(len: usize, s: usize) -> usize {
    (len / s.max(1)).saturating_sub(1) * s
}

/// The piece `c` of a row widened by [`send`], back in `R`, into the same piece of `out`.
fn narrow<R: Real>(row: &[f64], c: &Range<usize>, out: &mut [R]) {
    crate::parallel_mpi::narrow(&row[c.clone()], &mut out[c.clone()]);
}

/// The rank below and the rank above this one (ranks own slabs from the floor up, in rank
/// order; a rank with no rows passes the rows through unchanged, so it must not be one:
/// every rank owns at least one row).
fn neighbours<C: Communicator>(comm: &C) -> (Option<usize>, Option<usize>) {
    let (rank, size) = (comm.rank() as usize, comm.size() as usize);
    (rank.checked_sub(1), (rank + 1 < size).then_some(rank + 1))
}

/// The line factor of this rank's slab (rows of `s` cells): `d` in: the preconditioner's
/// diagonal; out: the inverted pivots. `k_below` the couplings of the faces below each row
/// (the first row's from the rank below). Writes the multipliers `l`. Collective.
pub fn factor_across<R: Real, C: Communicator>(
    comm: &C,
    s: usize,
    segments: usize,
    d: &mut [R],
    l: &mut [R],
    k_below: &[R],
) {
    let (below, above) = neighbours(comm);
    let mut row = vec![0.0f64; s];
    let mut db = vec![R::ZERO; s];
    let top = last_row(d.len(), s);
    for c in pieces(s, segments) {
        if let Some(b) = below {
            receive(comm, b, TAG_UP, &mut row, &c);
            narrow(&row, &c, &mut db);
        }
        let db = below.map(|_| &db[..]);
        line_slab::factor(s, c.clone(), d, l, k_below, db);
        if let Some(a) = above {
            send(comm, a, TAG_UP, &d[top + c.start..top + c.end]);
        }
    }
    line_slab::invert_pivots(d);
}

/// `z = M^-1 r` on this rank's slab with the factor of [`factor_across`]. Collective.
pub fn solve_across<R: Real, C: Communicator>(
    comm: &C,
    s: usize,
    segments: usize,
    inv_d: &[R],
    l: &[R],
    r: &[R],
    z: &mut [R],
) {
    let (below, above) = neighbours(comm);
    let mut row = vec![0.0f64; s];
    let mut row_l = vec![0.0f64; s];
    let (mut zn, mut ln) = (vec![R::ZERO; s], vec![R::ZERO; s]);
    let top = last_row(z.len(), s);
    for c in pieces(s, segments) {
        if let Some(b) = below {
            receive(comm, b, TAG_UP, &mut row, &c);
            narrow(&row, &c, &mut zn);
        }
        let zb = below.map(|_| &zn[..]);
        line_slab::forward(s, c.clone(), l, Some(r), z, zb);
        if let Some(a) = above {
            send(comm, a, TAG_UP, &z[top + c.start..top + c.end]);
        }
    }
    for c in pieces(s, segments) {
        if let Some(a) = above {
            receive(comm, a, TAG_DOWN, &mut row, &c);
            receive(comm, a, TAG_DOWN, &mut row_l, &c);
            narrow(&row, &c, &mut zn);
            narrow(&row_l, &c, &mut ln);
        }
        let za = above.map(|_| (&zn[..], &ln[..]));
        line_slab::backward(s, c.clone(), inv_d, l, z, za);
        if let Some(b) = below {
            send(comm, b, TAG_DOWN, &z[c.clone()]);
            send(comm, b, TAG_DOWN, &l[c.clone()]);
        }
    }
}
