//! The line preconditioner of [`super::cg`] on a slab of whole rows of a grid cut along its
//! lines (the last axis), with the serial bits: what the coupled flow under mpirun needs when
//! the ranks own slabs of rows, as the segregation's do (docs/parallel.md, "Not done").
//!
//! Each vertical line is a tridiagonal solve (Thomas algorithm) from the floor up (factor,
//! forward sweep) and back down (backward sweep), and every column of a row is independent of
//! the others. So a slab continues the factor and the forward sweep from the last row of the
//! slab below it and hands its own top row up, and continues the backward sweep from the
//! first row of the slab above and hands its own bottom row down. Each cell sees exactly the
//! serial operations in the serial order, so the bits are the serial bits for any cut.
//!
//! The sweeps are sequential along the lines, so a cut alone would leave each slab waiting
//! for the whole slab below. Every function here works on a range of columns (`cols`, indices
//! within a row), so a driver can pipeline a wavefront: the slab below hands up its first
//! column segment while it sweeps the next, and with `m` segments on `K` slabs the sweep
//! takes about `(m + K - 1) / m` of a perfectly shared one.
//!
//! Layout: the slab's arrays hold its rows one after the other (row `i`, column `j` at
//! `i s + j`); messages between slabs are whole rows of `s` values, of which only `cols` are
//! read or meant.

use super::cg::{backward_row, factor_row, forward_row};
use crate::real::Real;
use core::ops::Range;

/// `cols` within a row of `s` cells (empty if reversed).
fn clamp(cols: Range<usize>, s: usize) -> Range<usize> {
    let end = cols.end.min(s);
    cols.start.min(end)..end
}

/// The rows of `len` values of `s` cells each (a partial last row is left out).
fn rows(len: usize, s: usize) -> usize {
    len.checked_div(s).unwrap_or(0)
}

/// The factor `M = L D L^T` on the slab's columns `cols`: `d` holds M's diagonal on the
/// slab's rows (A's diagonal, [`super::cg::Stencil::diagonal`]) and becomes the pivots;
/// `k_below[i s + j]` is the vertical coupling of the face below row `i`; `below` is the
/// pivot row of the slab below (its `d` after this call), `None` on the bottom slab. Writes
/// the multipliers `l` (0 on the grid's bottom row). The pivots are inverted afterwards
/// ([`invert_pivots`]), once the slab above has the top row.
pub fn factor<R: Real>(
    s: usize,
    cols: Range<usize>,
    d: &mut [R],
    l: &mut [R],
    k_below: &[R],
    below: Option<&[R]>,
) {
    let m = rows(d.len().min(l.len()), s);
    let c = clamp(cols, s);
    for i in 0..m {
        let at = i * s;
        let (done, here) = d.split_at_mut(at);
        let dh = &mut here[c.clone()];
        let lh = &mut l[at + c.start..at + c.end];
        let kb = &k_below[at + c.start..at + c.end];
        match (i, below) {
            (0, None) => lh.fill(R::ZERO),
            (0, Some(db)) => factor_row(dh, lh, &db[c.clone()], kb),
            _ => factor_row(dh, lh, &done[at - s + c.start..at - s + c.end], kb),
        }
    }
}

/// `d = 1 / d`: the factor's last pass, as the serial factor ends.
pub fn invert_pivots<R: Real>(d: &mut [R]) {
    for x in d.iter_mut() {
        *x = R::ONE / *x;
    }
}

/// The forward sweep on the slab's columns `cols`: `z = r + l z_below` row by row (in place,
/// `z += l z_below`, when `r` is `None`), continuing from `below`, the slab below's top row of
/// `z` after its sweep; on the bottom slab (`None`) the first row is `r` itself (in place:
/// left as it is), as in the serial sweep.
pub fn forward<R: Real>(
    s: usize,
    cols: Range<usize>,
    l: &[R],
    r: Option<&[R]>,
    z: &mut [R],
    below: Option<&[R]>,
) {
    let m = rows(z.len().min(l.len()), s);
    let c = clamp(cols, s);
    for i in 0..m {
        let at = i * s;
        let (done, here) = z.split_at_mut(at);
        let zh = &mut here[c.clone()];
        let rh = r.map(|r| &r[at + c.start..at + c.end]);
        let lh = &l[at + c.start..at + c.end];
        match (i, below) {
            (0, None) => {
                if let Some(rh) = rh {
                    zh.copy_from_slice(rh);
                }
            }
            (0, Some(zb)) => forward_row(zh, rh, lh, &zb[c.clone()]),
            _ => forward_row(zh, rh, lh, &done[at - s + c.start..at - s + c.end]),
        }
    }
}

/// The backward sweep with the diagonal scaling on the slab's columns `cols`, continuing
/// from `above`: the slab above's bottom row of `z` after its sweep and its multipliers `l`
/// on that row; on the top slab (`None`) the top row is scaled by its inverted pivots, as the
/// serial sweep starts.
pub fn backward<R: Real>(
    s: usize,
    cols: Range<usize>,
    inv_d: &[R],
    l: &[R],
    z: &mut [R],
    above: Option<(&[R], &[R])>,
) {
    let m = rows(z.len().min(l.len()).min(inv_d.len()), s);
    if m == 0 {
        return;
    }
    let c = clamp(cols, s);
    let top = (m - 1) * s;
    match above {
        None => {
            for (x, w) in z[top + c.start..top + c.end]
                .iter_mut()
                .zip(&inv_d[top + c.start..top + c.end])
            {
                *x *= *w;
            }
        }
        Some((za, la)) => backward_row(
            &mut z[top + c.start..top + c.end],
            &za[c.clone()],
            &la[c.clone()],
            &inv_d[top + c.start..top + c.end],
        ),
    }
    for i in (1..m).rev() {
        let at = i * s;
        let (below, here) = z.split_at_mut(at);
        backward_row(
            &mut below[at - s + c.start..at - s + c.end],
            &here[c.clone()],
            &l[at + c.start..at + c.end],
            &inv_d[at - s + c.start..at - s + c.end],
        );
    }
}
