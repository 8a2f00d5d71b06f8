//! Matrix-free conjugate gradients for the implicit stages of the flow, preconditioned by an
//! aggregation multigrid V-cycle whose finest smoother is an exact solve along the grid lines
//! of the last (vertical) axis.
//!
//! The operator is `A x = diag x + sum_faces k_f (x_L - x_R)` (added to the left cell,
//! subtracted from the right one): a weighted graph Laplacian of the grid plus a positive
//! diagonal, so A is symmetric positive definite whenever `diag > 0` and `k_f >= 0`.
//! Boundary conditions enter through `diag` and the right-hand side (Dirichlet) or not at all
//! (zero flux); periodic faces are the wrap-around faces, stored at the last cell of a line.
//! Every dot product and norm is a blocked sum of [`crate::sum`]: its bits depend only on the
//! data, and its eight independent accumulators run at the speed of memory.
//!
//! # Why a line smoother
//! The stiffness of these systems is vertical first: the yield viscosity of a cold bed grows
//! with the lithostatic pressure, and the layers of a sheared bed couple through it. With a
//! Jacobi (diagonal) preconditioner the spin-up of the 7.4 shear cell took ~160 CG
//! iterations per system. Block Jacobi with one block per vertical grid line (the tridiagonal
//! part of A along the last axis plus A's full diagonal, factored once per solve by the
//! Thomas algorithm) is exact in 1D and takes the vertical coupling out of the iteration.
//! Rows of a line are processed together across the other axes, so both sweeps vectorise.
//!
//! # Why multigrid on top
//! What the lines leave is the horizontal coupling, and in a spreading collapse or a drum the
//! dense bed is a long horizontal layer whose yield viscosity couples it over its whole
//! length: block Jacobi alone needed ~25 iterations per system there, growing with the
//! length. The V-cycle removes the long-range part on coarse grids:
//! - coarse grids aggregate 2 cells per axis (2^D per coarse cell; an odd last cell stays
//!   alone; axes of one cell are left as they are), down to one cell;
//! - the coarse operator is the Galerkin product `P^T A P` with piecewise-constant `P`, which
//!   for this operator is again `diag + faces`: the coarse diagonal is the sum of the fine
//!   diagonals of the aggregate, a coarse face coefficient the sum of the fine faces it
//!   covers (faces inside an aggregate drop out). It stays SPD for any coefficients, needs no
//!   geometry, and a closed face (`k_f = 0`) stays closed, so a decoupled solid cell stays
//!   decoupled; a near-singular bed (tiny `diag`, huge `k_f`) gets its slow modes from the
//!   coarse levels, whose diagonal still holds the exact total mass of the aggregate;
//! - smoothing: on the finest grid the line solve above, damped (`0.8 M^-1`), before and
//!   after the coarse correction; on coarse grids damped Jacobi (`2/3 D^-1`, vectorised face
//!   loops: a Gauss-Seidel sweep there is a chain of dependent divisions and cost more than
//!   the whole fine level); on the coarsest grid (one cell, or the coarsest that fits the
//!   workspace) two symmetric Gauss-Seidel sweeps. Each smoother pair is the same operator
//!   (or adjoint), every smoother is convergent, and the coarse correction is not
//!   over-scaled, so the V-cycle is symmetric positive definite and CG applies unchanged.
//!   (An over-correction by 1.5, which aggregation methods often use, saved iterations when
//!   CG started with the V-cycle but made CG stall after a switch from the lines: it is
//!   not safely positive definite.)
//! - 1D grids and grids with one cell on every horizontal axis use the line solve alone: it
//!   is exact there.
//!
//! # When
//! A V-cycle costs about 2.5 line-preconditioned iterations (two more products and a line
//! solve on the fine grid, the coarse levels). Measured on the real systems: column collapse
//! 160 x 32 (0.03 s after release), lines 8.9 / 9.0 / 8.2 iterations per step for u_x / u_z /
//! T, V-cycle 5.4 / 5.3 / 5.5, so the lines are faster; shear-cell spin-up on 80 x 80 from
//! rest, lines 74 / 89 / 21, V-cycle 17 / 27 / 8. [`solve`] therefore starts with the lines
//! and switches when their observed convergence rate predicts a long solve
//! ([`Preconditioner::Auto`]).
//!
//! Allocation-free: the coarse levels live in the caller's workspace ([`Scratch::coarse`],
//! [`workspace_len`]); if it is short, fewer levels are used.

use crate::fork::{self, Call, Fork};
use crate::grid::Grid;
use crate::real::Real;
use core::ops::Range;

/// Damping of the finest smoother (the line solve): `omega M^-1`. Below 1 so that the
/// line-Jacobi smoother is convergent for any coefficients (`2 M / omega - A` is positive
/// definite), which keeps the V-cycle SPD; 0.8 was the fastest of 0.8 and 1.0 on the
/// shear-cell spin-up.
pub(crate) const OMEGA: f64 = 0.8;
/// Damping of the Jacobi smoother of the coarse levels.
pub(crate) const OMEGA_COARSE: f64 = 2.0 / 3.0;
/// Symmetric Gauss-Seidel sweeps on the coarsest level.
const COARSEST_SWEEPS: u32 = 2;
/// Iterations between two checks of the convergence rate of the line preconditioner.
pub(crate) const PROBE: u32 = 4;
/// Switch to multigrid if the line preconditioner predicts more iterations than this: a
/// V-cycle costs about 2.5 line-preconditioned iterations and needed ~5 per system where
/// the lines needed 9 (column collapse) to 80 (shear-cell spin-up on 80 x 80).
pub(crate) const LONG: f64 = 12.0;

/// Which preconditioner [`solve`] uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Preconditioner {
    /// Lines first, multigrid if the lines converge slowly (see [`solve`]).
    Auto,
    /// Vertical line solves only (block Jacobi).
    Lines,
    /// The multigrid V-cycle from the first iteration (lines where it cannot coarsen).
    Multigrid,
}

/// The static structure of the operator: grid, which axes wrap, and the face coefficients
/// `kf[a][i]` of the face between cell `i` and its `+a` neighbour (the wrap face at the last
/// cell of a periodic line; ignored at the last cell otherwise).
#[derive(Clone, Copy)]
pub struct Stencil<'a, R: Real, const D: usize, const N: usize> {
    /// The grid.
    pub grid: &'a Grid<R, D>,
    /// Axes with periodic wrap faces.
    pub periodic: [bool; D],
    /// Face coefficients.
    pub kf: &'a [[R; N]; D],
}

impl<R: Real, const D: usize, const N: usize> Stencil<'_, R, D, N> {
    /// `out = A x` with the diagonal `diag`.
    pub fn apply(&self, diag: &[R], x: &[R], out: &mut [R]) {
        self.product::<false>(diag, x, x, out);
    }

    /// `out = b - A x`.
    pub fn residual(&self, diag: &[R], b: &[R], x: &[R], out: &mut [R]) {
        self.product::<true>(diag, b, x, out);
    }

    /// [`Self::apply`] on the threads of `fork` (the same bits).
    pub fn apply_on<F: Fork>(&self, fork: &F, diag: &[R], x: &[R], out: &mut [R]) {
        self.product_on::<false, F>(fork, diag, x, x, out);
    }

    /// [`Self::residual`] on the threads of `fork` (the same bits).
    pub fn residual_on<F: Fork>(&self, fork: &F, diag: &[R], b: &[R], x: &[R], out: &mut [R]) {
        self.product_on::<true, F>(fork, diag, b, x, out);
    }

    /// `out = A x`, or `out = b - A x` if `RES`. Line by line along axis 0, each output
    /// value built in a register in one pass: the diagonal, then per axis the face to `+a`,
    /// the face from `-a`, the wrap faces, in exactly the order (and so with exactly the
    /// bits) of a face-by-face loop. (Adding the faces to the line one axis at a time, as
    /// before, loaded and stored every output value five times in 2D; the fused pass is
    /// ~2x faster and the product is a third of a coupled step, see
    /// docs/implicit-pressure.md "where the time goes". `product_by_faces` keeps the
    /// face-by-face order as the parity reference of the tests.)
    fn product<const RES: bool>(&self, diag: &[R], b: &[R], x: &[R], out: &mut [R]) {
        let n = self.grid.len();
        self.product_lines::<RES>(diag, b, x, 0, &mut out[..n]);
    }

    /// [`Self::product`] on the threads of `fork`, cut between lines along axis 0 (each
    /// output value is built by the same arithmetic in any chunk: the serial bits).
    fn product_on<const RES: bool, F: Fork>(
        &self,
        fork: &F,
        diag: &[R],
        b: &[R],
        x: &[R],
        out: &mut [R],
    ) {
        let n = self.grid.len();
        let n0 = self.grid.cells()[0];
        fork::chunks(fork, &mut out[..n], n0, |start, o| {
            fork.hot(Call(
                #[inline(always)]
                || self.product_lines::<RES>(diag, b, x, start / n0, o),
            ));
        });
    }

    /// `out = A x` (or `b - A x`) on the whole lines along axis 0 that `out` covers, the
    /// first being line `first` (`out` starts at cell `first * n0`). Inlined into the runner
    /// of [`Fork::hot`], as are the line solves below.
    #[inline(always)]
    fn product_lines<const RES: bool>(
        &self,
        diag: &[R],
        b: &[R],
        x: &[R],
        first: usize,
        out: &mut [R],
    ) {
        let kf: [&[R]; D] = core::array::from_fn(|a| &self.kf[a][..]);
        let strides: [usize; D] = core::array::from_fn(|a| self.grid.stride(a));
        product_lines::<RES, R, D>(
            (self.grid.cells(), strides, self.periodic),
            kf,
            (diag, b, x),
            first,
            out,
        );
    }

    /// The product of [`Self::product`] as a face-by-face pass per axis over each line (the
    /// order the fused pass reproduces): the parity reference of the tests.
    #[doc(hidden)]
    pub fn product_by_faces(&self, diag: &[R], b: &[R], x: &[R], out: &mut [R], res: bool) {
        let cells = self.grid.cells();
        let n0 = cells[0];
        let lines: usize = cells[1..].iter().product();
        let mut k = [0usize; D];
        // `o += v` or `o -= v`
        let add = |o: &mut R, v: R| {
            if res {
                *o -= v;
            } else {
                *o += v;
            }
        };
        for line in 0..lines {
            let i0 = line * n0;
            let o = &mut out[i0..i0 + n0];
            let (xs, ds) = (&x[i0..i0 + n0], &diag[i0..i0 + n0]);
            if res {
                let bs = &b[i0..i0 + n0];
                for j in 0..n0 {
                    o[j] = bs[j] - ds[j] * xs[j];
                }
            } else {
                for j in 0..n0 {
                    o[j] = ds[j] * xs[j];
                }
            }
            if n0 > 1 {
                let kf = &self.kf[0][i0..i0 + n0];
                for j in 0..n0 - 1 {
                    add(&mut o[j], kf[j] * (xs[j] - xs[j + 1]));
                }
                for j in 1..n0 {
                    add(&mut o[j], kf[j - 1] * (xs[j] - xs[j - 1]));
                }
                if self.periodic[0] {
                    let f = kf[n0 - 1];
                    add(&mut o[n0 - 1], f * (xs[n0 - 1] - xs[0]));
                    add(&mut o[0], f * (xs[0] - xs[n0 - 1]));
                }
            }
            for a in 1..D {
                let c = cells[a];
                if c < 2 {
                    continue;
                }
                let s = self.grid.stride(a);
                let kf = &self.kf[a];
                if k[a] + 1 < c {
                    let (kh, xh) = (&kf[i0..i0 + n0], &x[i0 + s..i0 + s + n0]);
                    for j in 0..n0 {
                        add(&mut o[j], kh[j] * (xs[j] - xh[j]));
                    }
                }
                if k[a] > 0 {
                    let (kl, xl) = (&kf[i0 - s..i0 - s + n0], &x[i0 - s..i0 - s + n0]);
                    for j in 0..n0 {
                        add(&mut o[j], kl[j] * (xs[j] - xl[j]));
                    }
                }
                if self.periodic[a] {
                    let span = (c - 1) * s;
                    if k[a] + 1 == c {
                        let (kh, xh) = (&kf[i0..i0 + n0], &x[i0 - span..i0 - span + n0]);
                        for j in 0..n0 {
                            add(&mut o[j], kh[j] * (xs[j] - xh[j]));
                        }
                    }
                    if k[a] == 0 {
                        let (kl, xl) = (
                            &kf[i0 + span..i0 + span + n0],
                            &x[i0 + span..i0 + span + n0],
                        );
                        for j in 0..n0 {
                            add(&mut o[j], kl[j] * (xs[j] - xl[j]));
                        }
                    }
                }
            }
            next_line(&mut k, &cells);
        }
    }

    /// `m = diag + sum of the adjacent face coefficients`: A's diagonal, and the line
    /// preconditioner's before its factor ([`super::line_slab`] takes it from here). (A
    /// periodic axis of one cell has a wrap face from the cell to itself, which A does not
    /// see.)
    #[inline(always)]
    pub fn diagonal(&self, diag: &[R], m: &mut [R]) {
        let n = self.grid.len();
        m[..n].copy_from_slice(&diag[..n]);
        for a in 0..D {
            if self.grid.cells()[a] < 2 {
                continue;
            }
            let fb = self.grid.face_blocks(a);
            let s = fb.stride;
            for b in 0..fb.blocks {
                let l0 = b * fb.block_stride;
                for j in l0..l0 + fb.block_len {
                    m[j] += self.kf[a][j];
                    m[j + s] += self.kf[a][j];
                }
            }
            if self.periodic[a] {
                self.grid.for_each_boundary_cell(a, true, |last, first| {
                    m[last] += self.kf[a][last];
                    m[first] += self.kf[a][last];
                });
            }
        }
    }

    /// Factors the line preconditioner `M = L D L^T`: M is A's diagonal plus A's couplings
    /// along the last axis (without a periodic wrap face), tridiagonal on each vertical line.
    /// Writes `inv_d = 1 / D` and the multipliers `l` (`l[i] = k / d` of the face below cell
    /// `i`; 0 on the bottom row).
    #[inline(always)]
    pub fn line_factor(&self, diag: &[R], inv_d: &mut [R], l: &mut [R]) {
        let n = self.grid.len();
        let s = self.grid.stride(D - 1);
        let k = &self.kf[D - 1];
        let d = &mut inv_d[..n];
        self.diagonal(diag, d);
        l[..s].fill(R::ZERO);
        for row in (s..n).step_by(s) {
            let (below, here) = d.split_at_mut(row);
            let (db, dh) = (&below[row - s..], &mut here[..s]);
            factor_row(dh, &mut l[row..row + s], db, &k[row - s..row]);
        }
        for x in d.iter_mut() {
            *x = R::ONE / *x;
        }
    }

    /// `z = M^-1 r` with the factor of [`Self::line_factor`]: forward and backward sweeps row
    /// by row.
    #[inline(always)]
    pub fn precondition(&self, inv_d: &[R], l: &[R], r: &[R], z: &mut [R]) {
        let n = self.grid.len();
        let s = self.grid.stride(D - 1);
        let z = &mut z[..n];
        z[..s].copy_from_slice(&r[..s]);
        for row in (s..n).step_by(s) {
            let (below, here) = z.split_at_mut(row);
            let (zb, zh) = (&below[row - s..], &mut here[..s]);
            forward_row(zh, Some(&r[row..row + s]), &l[row..row + s], zb);
        }
        self.line_backward(inv_d, l, z);
    }

    /// `z = M^-1 z` in place.
    #[inline(always)]
    fn line_solve(&self, inv_d: &[R], l: &[R], z: &mut [R]) {
        let n = self.grid.len();
        let s = self.grid.stride(D - 1);
        let z = &mut z[..n];
        for row in (s..n).step_by(s) {
            let (below, here) = z.split_at_mut(row);
            let (zb, zh) = (&below[row - s..], &mut here[..s]);
            forward_row(zh, None, &l[row..row + s], zb);
        }
        self.line_backward(inv_d, l, z);
    }

    /// The diagonal scaling and the backward sweep of the line solve (one pass).
    #[inline(always)]
    fn line_backward(&self, inv_d: &[R], l: &[R], z: &mut [R]) {
        let n = self.grid.len();
        let s = self.grid.stride(D - 1);
        let z = &mut z[..n];
        for (x, w) in z[n - s..].iter_mut().zip(&inv_d[n - s..n]) {
            *x *= *w;
        }
        for row in (s..n).step_by(s).rev() {
            let (below, here) = z.split_at_mut(row);
            let (zb, zh) = (&mut below[row - s..], &here[..s]);
            backward_row(zb, zh, &l[row..row + s], &inv_d[row - s..row]);
        }
    }
}

// The rows of the line factor and solves. Each is its own function, not a loop inside the
// sweep, for the vectoriser: the rows above and below come from one array (`split_at_mut`),
// and only as separate reference arguments are they known not to overlap (the knowledge
// survives inlining). Inlined into a wider runner (`Fork::hot`) without it, the backward
// sweep stayed scalar: 6x the samples of the native build's separate function (perf,
// docs/simd.md).

/// `l = k / d_below; d -= k l` on one row of the factor.
#[inline(always)]
pub(crate) fn factor_row<R: Real>(dh: &mut [R], lh: &mut [R], db: &[R], kb: &[R]) {
    let s = dh.len();
    let (lh, db, kb) = (&mut lh[..s], &db[..s], &kb[..s]);
    for j in 0..s {
        lh[j] = kb[j] / db[j];
        dh[j] -= kb[j] * lh[j];
    }
}

/// The forward sweep on one row: `z = r + l z_below` (or `z += l z_below` without `r`).
#[inline(always)]
pub(crate) fn forward_row<R: Real>(zh: &mut [R], rh: Option<&[R]>, lh: &[R], zb: &[R]) {
    let s = zh.len();
    let (lh, zb) = (&lh[..s], &zb[..s]);
    match rh {
        Some(rh) => {
            let rh = &rh[..s];
            for j in 0..s {
                zh[j] = rh[j] + lh[j] * zb[j];
            }
        }
        None => {
            for j in 0..s {
                zh[j] += lh[j] * zb[j];
            }
        }
    }
}

/// The backward sweep on one row: `z_below = z_below w_below + l z`.
#[inline(always)]
pub(crate) fn backward_row<R: Real>(zb: &mut [R], zh: &[R], lh: &[R], wb: &[R]) {
    let s = zb.len();
    let (zh, lh, wb) = (&zh[..s], &lh[..s], &wb[..s]);
    for j in 0..s {
        zb[j] = zb[j] * wb[j] + lh[j] * zh[j];
    }
}

/// `out = A x` (or `b - A x`) on the whole lines along axis 0 that `out` covers, the first
/// being line `first` (`out` starts at cell `first * n0`), for a grid of `cells` with face
/// coefficients `kf` and diagonal `diag`: [`Stencil::product`]'s arithmetic on slices, so
/// that a slab of rows with its halo rows ([`super::cycle_slab`]) computes its own rows with
/// the serial bits. Inlined into the runner of [`Fork::hot`], as are the line solves below.
#[inline(always)]
pub(crate) fn product_lines<const RES: bool, R: Real, const D: usize>(
    (cells, strides, periodic): ([usize; D], [usize; D], [bool; D]),
    kf: [&[R]; D],
    (diag, b, x): (&[R], &[R], &[R]),
    first: usize,
    out: &mut [R],
) {
    let n0 = cells[0];
    let lines = out.len() / n0;
    let mut k = line_start(cells, first);
    let empty: &[R] = &[];
    for line in first..first + lines {
        let i0 = line * n0;
        // The faces of the other axes, in the order they are added: per axis the face to
        // `+a` (or the wrap face at the last cell), the face from `-a` (or the wrap face
        // at the first); as (coefficients, neighbour values) of the whole line.
        let mut kt: [&[R]; 6] = [empty; 6];
        let mut xt: [&[R]; 6] = [empty; 6];
        let m = line_faces(
            (cells, strides, periodic),
            kf,
            x,
            (&k, i0, n0),
            &mut kt,
            &mut xt,
        );
        let line_x = &x[i0..i0 + n0];
        let o = &mut out[i0 - first * n0..i0 - first * n0 + n0];
        let (ds, bs) = (&diag[i0..i0 + n0], &b[i0..i0 + n0]);
        let k0 = &kf[0][i0..i0 + n0];
        let lx = LineTerms {
            x: line_x,
            kt: &kt[..m],
            xt: &xt[..m],
        };
        match m {
            0 => lx.interior::<RES, 0>(ds, bs, k0, o),
            1 => lx.interior::<RES, 1>(ds, bs, k0, o),
            2 => lx.interior::<RES, 2>(ds, bs, k0, o),
            3 => lx.interior::<RES, 3>(ds, bs, k0, o),
            4 => lx.interior::<RES, 4>(ds, bs, k0, o),
            5 => lx.interior::<RES, 5>(ds, bs, k0, o),
            _ => lx.interior::<RES, 6>(ds, bs, k0, o),
        }
        // the two end cells of the line (or the only one), with the wrap face of axis 0
        let ends = if n0 > 1 { [0, n0 - 1] } else { [0, 0] };
        for (e, &j) in ends.iter().enumerate() {
            if e == 1 && n0 == 1 {
                break;
            }
            let xj = line_x[j];
            let mut v = if RES { bs[j] - ds[j] * xj } else { ds[j] * xj };
            let mut add = |t: R| {
                if RES {
                    v -= t;
                } else {
                    v += t;
                }
            };
            if n0 > 1 {
                if j + 1 < n0 {
                    add(k0[j] * (xj - line_x[j + 1]));
                }
                if j > 0 {
                    add(k0[j - 1] * (xj - line_x[j - 1]));
                }
                if periodic[0] {
                    let other = if j == 0 { n0 - 1 } else { 0 };
                    add(k0[n0 - 1] * (xj - line_x[other]));
                }
            }
            for t in 0..m {
                add(kt[t][j] * (xj - xt[t][j]));
            }
            o[j] = v;
        }
        next_line(&mut k, &cells);
    }
}

/// The coordinates of the first cell of line `line` along axis 0 (`k[0] = 0`): where a
/// product over a chunk of lines starts counting.
fn line_start<const D: usize>(cells: [usize; D], line: usize) -> [usize; D] {
    let mut k = [0usize; D];
    let mut rest = line;
    for a in 1..D {
        k[a] = rest % cells[a];
        rest /= cells[a];
    }
    k
}

/// One line along axis 0 of [`Stencil::product`]: its values and the `M` face terms of the
/// other axes (coefficients and neighbour values over the line).
/// The faces of axes `1..D` of the line of `n0` cells that starts at `i0` (coordinates `k`),
/// in the order a face-by-face product adds them: per axis the face to `+a` (or the wrap face
/// at the last cell), the face from `-a` (or the wrap face at the first), each as the line's
/// coefficients and neighbour values. Returns how many (at most 6) it wrote into `kt`, `xt`.
/// Shared by the fine product and the coarse levels' residual, so both keep the same order.
#[inline(always)]
fn line_faces<'a, R, const D: usize>(
    (cells, strides, periodic): ([usize; D], [usize; D], [bool; D]),
    kf: [&'a [R]; D],
    x: &'a [R],
    (k, i0, n0): (&[usize; D], usize, usize),
    kt: &mut [&'a [R]; 6],
    xt: &mut [&'a [R]; 6],
) -> usize {
    let mut m = 0;
    for a in 1..D {
        let c = cells[a];
        if c < 2 {
            continue;
        }
        let (s, kf) = (strides[a], kf[a]);
        let span = (c - 1) * s;
        if k[a] + 1 < c {
            (kt[m], xt[m]) = (&kf[i0..i0 + n0], &x[i0 + s..i0 + s + n0]);
            m += 1;
        }
        if k[a] > 0 {
            (kt[m], xt[m]) = (&kf[i0 - s..i0 - s + n0], &x[i0 - s..i0 - s + n0]);
            m += 1;
        }
        if periodic[a] && k[a] + 1 == c {
            (kt[m], xt[m]) = (&kf[i0..i0 + n0], &x[i0 - span..i0 - span + n0]);
            m += 1;
        }
        if periodic[a] && k[a] == 0 {
            (kt[m], xt[m]) = (
                &kf[i0 + span..i0 + span + n0],
                &x[i0 + span..i0 + span + n0],
            );
            m += 1;
        }
    }
    m
}

struct LineTerms<'a, R> {
    x: &'a [R],
    kt: &'a [&'a [R]],
    xt: &'a [&'a [R]],
}

impl<R: Real> LineTerms<'_, R> {
    /// The interior cells `1..n0-1` of the line (both axis-0 faces present): diagonal, face
    /// to `+0`, face from `-0`, then the `M` other faces, in that order. `M` is a constant so
    /// the term loop unrolls and the cell loop vectorises.
    #[inline(always)]
    fn interior<const RES: bool, const M: usize>(&self, ds: &[R], bs: &[R], k0: &[R], o: &mut [R]) {
        let n0 = self.x.len();
        if n0 < 3 {
            return;
        }
        let len = n0 - 2;
        let xc = &self.x[1..n0 - 1];
        let (xr, xl) = (&self.x[2..n0], &self.x[..len]);
        let (kr, kl) = (&k0[1..n0 - 1], &k0[..len]);
        let (ds, bs) = (&ds[1..n0 - 1], &bs[1..n0 - 1]);
        let o = &mut o[1..n0 - 1];
        let kt: [&[R]; M] = core::array::from_fn(|t| &self.kt[t][1..n0 - 1]);
        let xt: [&[R]; M] = core::array::from_fn(|t| &self.xt[t][1..n0 - 1]);
        for j in 0..len {
            let xj = xc[j];
            let mut v = if RES { bs[j] - ds[j] * xj } else { ds[j] * xj };
            let t0 = kr[j] * (xj - xr[j]);
            let t1 = kl[j] * (xj - xl[j]);
            if RES {
                v -= t0;
                v -= t1;
            } else {
                v += t0;
                v += t1;
            }
            for t in 0..M {
                let f = kt[t][j] * (xj - xt[t][j]);
                if RES {
                    v -= f;
                } else {
                    v += f;
                }
            }
            o[j] = v;
        }
    }
}

impl<R: Real> LineTerms<'_, R> {
    /// [`Self::interior`] for the coarse operators' residual `b - adiag x + sum_f k_f x_nb`.
    #[inline(always)]
    fn interior_sum<const M: usize>(&self, ds: &[R], bs: &[R], k0: &[R], o: &mut [R]) {
        let n0 = self.x.len();
        if n0 < 3 {
            return;
        }
        let len = n0 - 2;
        let xc = &self.x[1..n0 - 1];
        let (xr, xl) = (&self.x[2..n0], &self.x[..len]);
        let (kr, kl) = (&k0[1..n0 - 1], &k0[..len]);
        let (ds, bs) = (&ds[1..n0 - 1], &bs[1..n0 - 1]);
        let o = &mut o[1..n0 - 1];
        let kt: [&[R]; M] = core::array::from_fn(|t| &self.kt[t][1..n0 - 1]);
        let xt: [&[R]; M] = core::array::from_fn(|t| &self.xt[t][1..n0 - 1]);
        for j in 0..len {
            let mut v = bs[j] - ds[j] * xc[j];
            v += kr[j] * xr[j];
            v += kl[j] * xl[j];
            for t in 0..M {
                v += kt[t][j] * xt[t][j];
            }
            o[j] = v;
        }
    }
}

/// Most levels of a hierarchy (2^32 cells would be needed to exhaust it).
const MAX_LEVELS: usize = 32;

/// Cells per axis of the level below: 2 fine cells per coarse cell, an odd last one alone.
fn coarser<const D: usize>(cells: [usize; D]) -> [usize; D] {
    let mut c = cells;
    for x in c.iter_mut() {
        *x = x.div_ceil(2);
    }
    c
}

pub(crate) fn strides<const D: usize>(cells: [usize; D]) -> [usize; D] {
    let mut s = [1; D];
    for a in 1..D {
        s[a] = s[a - 1] * cells[a - 1];
    }
    s
}

/// Workspace ([`Scratch::coarse`]) of the full multigrid hierarchy of a grid with `cells`:
/// `D + 3` values per coarse cell (diagonal, `D` face coefficients, solution, right-hand
/// side) plus one vector of the first coarse level; in 2D about `1.9 n`, in 3D `0.9 n`.
pub fn workspace_len<const D: usize>(cells: [usize; D]) -> usize {
    Levels::new(cells, usize::MAX).storage()
}

/// Calls `f(i, k)` for every cell `i` with its coordinates `k`, in index order (`forward`) or
/// in reverse.
#[inline(always)]
pub(crate) fn for_each_cell<const D: usize>(
    cells: [usize; D],
    forward: bool,
    mut f: impl FnMut(usize, &[usize; D]),
) {
    let n0 = cells[0];
    let lines: usize = cells[1..].iter().product();
    let mut k = [0usize; D];
    if forward {
        let mut i = 0;
        for _ in 0..lines {
            for k0 in 0..n0 {
                k[0] = k0;
                f(i, &k);
                i += 1;
            }
            next_line(&mut k, &cells);
        }
    } else {
        for a in 0..D {
            k[a] = cells[a] - 1;
        }
        let mut i = n0 * lines;
        for _ in 0..lines {
            for k0 in (0..n0).rev() {
                i -= 1;
                k[0] = k0;
                f(i, &k);
            }
            for a in 1..D {
                if k[a] > 0 {
                    k[a] -= 1;
                    break;
                }
                k[a] = cells[a] - 1;
            }
        }
    }
}

/// Calls `f(fine, coarse)` for every line along axis 0 with the index of its first cell and
/// the index of the coarse cell that holds that first cell (coarse strides `sc`).
#[inline(always)]
fn for_each_line<const D: usize>(
    cells: [usize; D],
    sc: &[usize; D],
    mut f: impl FnMut(usize, usize),
) {
    let lines: usize = cells[1..].iter().product();
    let mut k = [0usize; D];
    for line in 0..lines {
        f(line * cells[0], parent(&k, sc));
        next_line(&mut k, &cells);
    }
}

/// `coarse[parent(i)] += fine[i]` over the cells of `cells` (restriction, `P^T`). Inlined
/// into a hot loop ([`Fork::hot`]) at each call.
#[inline(always)]
pub(crate) fn restrict<R: Real, const D: usize>(
    cells: [usize; D],
    sc: &[usize; D],
    fine: &[R],
    coarse: &mut [R],
) {
    let n0 = cells[0];
    for_each_line(cells, sc, |i0, j0| {
        let (f, c) = (&fine[i0..i0 + n0], &mut coarse[j0..j0 + n0.div_ceil(2)]);
        let pairs = f.chunks_exact(2);
        if let [last] = pairs.remainder() {
            c[n0 / 2] += *last;
        }
        for (cj, fp) in c.iter_mut().zip(pairs) {
            *cj += fp[0];
            *cj += fp[1];
        }
    });
}

/// `fine[i] += coarse[parent(i)]` (prolongation, `P`). Inlined into a hot loop.
#[inline(always)]
pub(crate) fn prolong<R: Real, const D: usize>(
    cells: [usize; D],
    sc: &[usize; D],
    coarse: &[R],
    fine: &mut [R],
) {
    let n0 = cells[0];
    for_each_line(cells, sc, |i0, j0| {
        let (f, c) = (&mut fine[i0..i0 + n0], &coarse[j0..j0 + n0.div_ceil(2)]);
        let mut pairs = f.chunks_exact_mut(2);
        for (fp, cj) in pairs.by_ref().zip(c) {
            fp[0] += *cj;
            fp[1] += *cj;
        }
        if let [last] = pairs.into_remainder() {
            *last += c[n0 / 2];
        }
    });
}

/// Index of the coarse cell holding fine coordinates `k` (coarse strides `sc`).
#[inline(always)]
fn parent<const D: usize>(k: &[usize; D], sc: &[usize; D]) -> usize {
    let mut j = 0;
    for a in 0..D {
        j += (k[a] >> 1) * sc[a];
    }
    j
}

/// The shapes of a multigrid hierarchy (level 0 is the fine grid).
#[derive(Clone, Copy)]
pub(crate) struct Levels<const D: usize> {
    pub(crate) cells: [[usize; D]; MAX_LEVELS],
    pub(crate) n: [usize; MAX_LEVELS],
    pub(crate) count: usize,
}

impl<const D: usize> Levels<D> {
    /// Coarsens to one cell, or as far as the storage fits in `room`.
    pub(crate) fn new(fine: [usize; D], room: usize) -> Self {
        let mut lv = Self {
            cells: [fine; MAX_LEVELS],
            n: [0; MAX_LEVELS],
            count: 1,
        };
        lv.n[0] = fine.iter().product();
        while lv.count < MAX_LEVELS && lv.n[lv.count - 1] > 1 {
            let c = coarser(lv.cells[lv.count - 1]);
            let mut next = lv;
            next.cells[lv.count] = c;
            next.n[lv.count] = c.iter().product();
            next.count += 1;
            if next.storage() > room {
                break;
            }
            lv = next;
        }
        lv
    }

    fn coarse_cells(&self) -> usize {
        self.n[1..self.count].iter().sum()
    }

    /// Operators and vectors of the coarse levels, plus one shared vector of level 1.
    pub(crate) fn storage(&self) -> usize {
        if self.count < 2 {
            0
        } else {
            (D + 3) * self.coarse_cells() + self.n[1]
        }
    }

    /// Offset of level `l`'s operator block (full diagonal, then `D` face arrays) in the
    /// operator part of the workspace.
    pub(crate) fn op_offset(&self, l: usize) -> usize {
        (D + 1) * self.n[1..l].iter().sum::<usize>()
    }

    /// Where level `l`'s right-hand side lives in the V-cycle's work (after the operators);
    /// during set-up it holds the level's mass diagonal.
    pub(crate) fn rhs_slot(&self, l: usize) -> Range<usize> {
        let x = 2 * self.n[1..l].iter().sum::<usize>();
        x + self.n[l]..x + 2 * self.n[l]
    }

    /// The hierarchy below level `from` as one of its own: its level 0 is level `from - 1`
    /// of this one (`from >= 1`), so its level 1 is level `from`. What a slab of rows solves
    /// whole on every rank once its levels are gathered ([`super::cycle_slab`]).
    pub(crate) fn below(&self, from: usize) -> Self {
        let mut lv = Self::new(self.cells[from - 1], usize::MAX);
        lv.count = self.count + 1 - from;
        lv
    }

    /// Builds levels `2..count` from level 1's operator (at the start of `ops`) and mass
    /// diagonal (in `work`'s right-hand side slot of level 1): the masses restricted level by
    /// level, each level's Galerkin operator from the one above.
    pub(crate) fn coarsen_from_first<R: Real>(
        &self,
        periodic: [bool; D],
        ops: &mut [R],
        work: &mut [R],
    ) {
        for l in 1..self.count - 1 {
            let (here, below) = work.split_at_mut(self.rhs_slot(l + 1).start);
            let m = &mut below[..self.n[l + 1]];
            m.fill(R::ZERO);
            restrict(
                self.cells[l],
                &strides(self.cells[l + 1]),
                &here[self.rhs_slot(l)],
                m,
            );
            let (done, next) = ops.split_at_mut(self.op_offset(l + 1));
            let op = Op::at(&done[self.op_offset(l)..], self.cells[l], periodic);
            op.galerkin(self.cells[l + 1], &work[self.rhs_slot(l + 1)], next);
        }
    }
}

/// One grid's operator `A x = adiag x - sum_f k_f x_nb` with its full diagonal and face
/// coefficients as slices (the coarse levels, and the fine level during set-up).
#[derive(Clone, Copy)]
pub(crate) struct Op<'a, R, const D: usize> {
    pub(crate) cells: [usize; D],
    pub(crate) strides: [usize; D],
    pub(crate) periodic: [bool; D],
    pub(crate) adiag: &'a [R],
    pub(crate) kf: [&'a [R]; D],
}

impl<'a, R: Real, const D: usize> Op<'a, R, D> {
    /// The operator stored at `block` (full diagonal, then the face arrays) for `cells`.
    fn at(block: &'a [R], cells: [usize; D], periodic: [bool; D]) -> Self {
        let n: usize = cells.iter().product();
        Self {
            cells,
            strides: strides(cells),
            periodic,
            adiag: &block[..n],
            kf: core::array::from_fn(|a| &block[(1 + a) * n..(2 + a) * n]),
        }
    }

    /// `sum_f k_f x_nb` over the faces of cell `i` (coordinates `k`).
    #[inline(always)]
    fn neighbours(&self, x: &[R], i: usize, k: &[usize; D]) -> R {
        let mut sx = R::ZERO;
        for a in 0..D {
            let c = self.cells[a];
            if c < 2 {
                continue;
            }
            let (s, kf) = (self.strides[a], self.kf[a]);
            if k[a] > 0 {
                sx += kf[i - s] * x[i - s];
            } else if self.periodic[a] {
                let last = i + (c - 1) * s;
                sx += kf[last] * x[last];
            }
            if k[a] + 1 < c {
                sx += kf[i] * x[i + s];
            } else if self.periodic[a] {
                sx += kf[i] * x[i - (c - 1) * s];
            }
        }
        sx
    }

    /// One Gauss-Seidel sweep for `A x = b`, in index order or in reverse.
    fn gauss_seidel(&self, b: &[R], x: &mut [R], forward: bool) {
        for_each_cell(self.cells, forward, |i, k| {
            let sx = self.neighbours(x, i, k);
            x[i] = (b[i] + sx) / self.adiag[i];
        });
    }

    /// `out = b - A x`, line by line along axis 0 with each value built in a register, in
    /// the order of the face-by-face passes it replaced (so with their bits): `b - adiag x`,
    /// then per axis the face to `+a`, the face from `-a`, the wrap faces; cut between lines
    /// on the threads of `fork` (the same bits as one pass).
    fn residual_on<F: Fork>(&self, fork: &F, b: &[R], x: &[R], out: &mut [R]) {
        let n: usize = self.cells.iter().product();
        let n0 = self.cells[0];
        fork::chunks(fork, &mut out[..n], n0, |start, o| {
            fork.hot(Call(
                #[inline(always)]
                || self.residual_lines(b, x, start / n0, o),
            ));
        });
    }

    /// `out = b - A x` on the whole lines along axis 0 that `out` covers, the first being
    /// line `first`.
    #[inline(always)]
    pub(crate) fn residual_lines(&self, b: &[R], x: &[R], first: usize, out: &mut [R]) {
        let cells = self.cells;
        let n0 = cells[0];
        let lines = out.len() / n0;
        let mut k = line_start(cells, first);
        let empty: &[R] = &[];
        let k0 = self.kf[0];
        for line in first..first + lines {
            let i0 = line * n0;
            let mut kt: [&[R]; 6] = [empty; 6];
            let mut xt: [&[R]; 6] = [empty; 6];
            let m = line_faces(
                (cells, self.strides, self.periodic),
                self.kf,
                x,
                (&k, i0, n0),
                &mut kt,
                &mut xt,
            );
            let (xs, bs, ds) = (&x[i0..i0 + n0], &b[i0..i0 + n0], &self.adiag[i0..i0 + n0]);
            let kl = &k0[i0..i0 + n0];
            let o = &mut out[i0 - first * n0..i0 - first * n0 + n0];
            let lt = LineTerms {
                x: xs,
                kt: &kt[..m],
                xt: &xt[..m],
            };
            match m {
                0 => lt.interior_sum::<0>(ds, bs, kl, o),
                1 => lt.interior_sum::<1>(ds, bs, kl, o),
                2 => lt.interior_sum::<2>(ds, bs, kl, o),
                3 => lt.interior_sum::<3>(ds, bs, kl, o),
                4 => lt.interior_sum::<4>(ds, bs, kl, o),
                5 => lt.interior_sum::<5>(ds, bs, kl, o),
                _ => lt.interior_sum::<6>(ds, bs, kl, o),
            }
            let ends = if n0 > 1 { [0, n0 - 1] } else { [0, 0] };
            for (e, &j) in ends.iter().enumerate() {
                if e == 1 && n0 == 1 {
                    break;
                }
                let mut v = bs[j] - ds[j] * xs[j];
                if n0 > 1 {
                    if j + 1 < n0 {
                        v += kl[j] * xs[j + 1];
                    }
                    if j > 0 {
                        v += kl[j - 1] * xs[j - 1];
                    }
                    if self.periodic[0] {
                        let other = if j == 0 { n0 - 1 } else { 0 };
                        v += kl[n0 - 1] * xs[other];
                    }
                }
                for t in 0..m {
                    v += kt[t][j] * xt[t][j];
                }
                o[j] = v;
            }
            next_line(&mut k, &cells);
        }
    }

    /// Writes the Galerkin operator `P^T A P` of piecewise-constant aggregation into `block`
    /// (the coarse level's full diagonal and face arrays; `cc` its cells, `mass` its mass
    /// diagonal, the sum of the fine one over each aggregate): a face joining two aggregates
    /// becomes (part of) a coarse face, a face inside one drops out. The full diagonal is
    /// assembled as mass plus coarse faces, never as the fine full diagonals minus the inner
    /// faces: with a yield viscosity 1e10 times the mass term that difference would cancel
    /// to round-off, and could leave a closed aggregate with a diagonal of the wrong sign.
    fn galerkin(&self, cc: [usize; D], mass: &[R], block: &mut [R]) {
        let nc: usize = cc.iter().product();
        let block = &mut block[..(D + 1) * nc];
        let (ad, faces) = block.split_at_mut(nc);
        let mut fa = faces.chunks_exact_mut(nc);
        let mut faces: [&mut [R]; D] = core::array::from_fn(|_| fa.next().unwrap_or_default());
        self.aggregate_faces(false, cc, &mut faces);
        ad.copy_from_slice(&mass[..nc]);
        let faces: [&[R]; D] = faces.map(|f| &*f);
        assemble_diagonal(cc, self.periodic, faces, ad);
    }

    /// The coarse face coefficients of [`Self::galerkin`] (`faces[a]`, one per coarse cell
    /// of `cc`): the sum, in cell order, of the fine faces that join two aggregates.
    /// `top_inside`: the last row along the last axis is not the grid's last (a slab of
    /// rows cut below the next slab, [`super::cycle_slab`]), so its faces to the row above
    /// join two aggregates as an interior row's do.
    pub(crate) fn aggregate_faces(
        &self,
        top_inside: bool,
        cc: [usize; D],
        faces: &mut [&mut [R]; D],
    ) {
        let sc = strides(cc);
        for f in faces.iter_mut() {
            f.fill(R::ZERO);
        }
        for_each_cell(self.cells, true, |i, k| {
            let j = parent(k, &sc);
            for a in 0..D {
                if self.cells[a] < 2 && !(top_inside && a == D - 1) {
                    continue;
                }
                let crosses = if k[a] + 1 < self.cells[a] || (top_inside && a == D - 1) {
                    k[a] & 1 == 1
                } else {
                    self.periodic[a] && cc[a] > 1
                };
                if crosses {
                    faces[a][j] += self.kf[a][i];
                }
            }
        });
    }
}

/// The full diagonal of a Galerkin operator: `ad` holds the mass diagonal and becomes mass
/// plus the coarse faces `faces` at both their cells, added in cell order (the order, and
/// so the bits, of every caller: the serial hierarchy and a slab with its halo rows).
pub(crate) fn assemble_diagonal<R: Real, const D: usize>(
    cc: [usize; D],
    periodic: [bool; D],
    faces: [&[R]; D],
    ad: &mut [R],
) {
    let sc = strides(cc);
    for_each_cell(cc, true, |j, k| {
        for a in 0..D {
            if cc[a] < 2 {
                continue;
            }
            let other = if k[a] + 1 < cc[a] {
                j + sc[a]
            } else if periodic[a] {
                j - (cc[a] - 1) * sc[a]
            } else {
                continue;
            };
            let f = faces[a][j];
            ad[j] += f;
            ad[other] += f;
        }
    });
}

/// Scratch vectors of one solve (each at least the grid length, except `coarse`).
pub struct Scratch<'a, R> {
    /// residual
    pub r: &'a mut [R],
    /// search direction
    pub p: &'a mut [R],
    /// A p
    pub ap: &'a mut [R],
    /// inverse pivots of the line preconditioner
    pub pre: &'a mut [R],
    /// multipliers of the line preconditioner
    pub line: &'a mut [R],
    /// the fine residual of the multigrid smoother
    pub tmp: &'a mut [R],
    /// the coarse levels of the multigrid preconditioner: [`workspace_len`] values for the
    /// full hierarchy; a shorter slice gives fewer levels (empty: line preconditioner only).
    pub coarse: &'a mut [R],
    /// the threaded sums' block partials: the grid length, or empty for a solve that runs
    /// on one thread ([`fork::Serial`]).
    pub part: &'a mut [R],
}

impl<R> Scratch<'_, R> {
    /// The same arrays for one more solve (a caller that solves several systems in turn on
    /// one set of scratch).
    pub fn reborrow(&mut self) -> Scratch<'_, R> {
        Scratch {
            r: self.r,
            p: self.p,
            ap: self.ap,
            pre: self.pre,
            line: self.line,
            tmp: self.tmp,
            coarse: self.coarse,
            part: self.part,
        }
    }
}

/// Stopping rule of one solve: `|r| <= relative max(|b|, floor)` or `max_iterations`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stop<R> {
    /// Relative residual target.
    pub relative: R,
    /// Absolute scale of the right-hand side (see [`solve`]).
    pub floor: R,
    /// Iteration cap.
    pub max_iterations: u32,
    /// Preconditioner ([`Preconditioner::Auto`] unless comparing).
    pub preconditioner: Preconditioner,
}

/// Outcome of one solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Solve<R> {
    /// Iterations used.
    pub iterations: u32,
    /// Final `|r| / |b|` (Euclidean).
    pub relative_residual: R,
}

/// The preconditioner of one solve: the line factor, and once switched on, the Galerkin
/// hierarchy.
struct Precond<'s, 'a, R: Real, const D: usize, const N: usize, F> {
    fork: &'s F,
    part: &'s mut [R],
    st: &'s Stencil<'a, R, D, N>,
    diag: &'s [R],
    pre: &'s mut [R],
    line: &'s [R],
    coarse: &'s mut [R],
    tmp: &'s mut [R],
    cyc: Cycle<R, D>,
}

/// What a V-cycle on the coarse levels needs.
#[derive(Clone, Copy)]
pub(crate) struct Cycle<R, const D: usize> {
    pub(crate) levels: Levels<D>,
    pub(crate) periodic: [bool; D],
    pub(crate) omega_c: R,
}

impl<'s, 'a, R: Real, const D: usize, const N: usize, F: Fork> Precond<'s, 'a, R, D, N, F> {
    fn new(
        (fork, part): (&'s F, &'s mut [R]),
        st: &'s Stencil<'a, R, D, N>,
        diag: &'s [R],
        pre: &'s mut [R],
        line: &'s mut [R],
        tmp: &'s mut [R],
        coarse: &'s mut [R],
    ) -> Self {
        fork.hot(Call(
            #[inline(always)]
            || st.line_factor(diag, pre, line),
        ));
        Self {
            fork,
            part,
            st,
            diag,
            pre,
            line,
            coarse,
            tmp,
            cyc: Cycle {
                levels: Levels::new(st.grid.cells(), 0),
                periodic: st.periodic,
                omega_c: R::from_f64(OMEGA_COARSE),
            },
        }
    }

    /// Whether multigrid can help: not on a grid of vertical lines (the line solve is exact
    /// there), not without workspace.
    fn can_coarsen(&self) -> bool {
        let cells = self.st.grid.cells();
        !cells[..D - 1].iter().all(|&c| c == 1) && Levels::new(cells, self.coarse.len()).count > 1
    }

    /// Builds the hierarchy and damps the line smoother.
    fn multigrid(&mut self) {
        let st = self.st;
        let cells = st.grid.cells();
        self.cyc.levels = Levels::new(cells, self.coarse.len());
        let lv = self.cyc.levels;
        if lv.count < 2 {
            return;
        }
        let n = st.grid.len();
        let (ops, work) = self.coarse.split_at_mut(lv.op_offset(lv.count));
        // The mass diagonal of every level, restricted level by level into the right-hand
        // side slots of the V-cycle (free until the first cycle).
        {
            let m1 = &mut work[lv.rhs_slot(1)];
            m1.fill(R::ZERO);
            restrict(cells, &strides(lv.cells[1]), &self.diag[..n], m1);
        }
        let fine = Op {
            cells,
            strides: strides(cells),
            periodic: st.periodic,
            adiag: &self.diag[..n], // not used by `galerkin`
            kf: core::array::from_fn(|a| &st.kf[a][..n]),
        };
        fine.galerkin(lv.cells[1], &work[lv.rhs_slot(1)], ops);
        lv.coarsen_from_first(st.periodic, ops, work);
        let omega = R::from_f64(OMEGA);
        for w in self.pre[..n].iter_mut() {
            *w *= omega;
        }
    }

    /// `z = B r`, returns `r . z` (blocked sum).
    fn apply(&mut self, r: &[R], z: &mut [R]) -> R {
        let (st, fork) = (self.st, self.fork);
        let n = st.grid.len();
        let (r, z) = (&r[..n], &mut z[..n]);
        let lv = self.cyc.levels;
        let factor = (&self.pre[..], self.line);
        // z = M^-1 r: the lines alone, or the V-cycle's pre-smoothing from 0 (then `pre`
        // holds omega, so z = omega M^-1 r)
        fork.hot(Call(
            #[inline(always)]
            || st.precondition(factor.0, factor.1, r, z),
        ));
        if lv.count < 2 {
            return fork::dot(fork, r, z, self.part);
        }
        let cells = lv.cells[0];
        let (n1, sc) = (lv.n[1], strides(lv.cells[1]));
        let (ops, work) = self.coarse.split_at_mut(lv.op_offset(lv.count));
        let ops: &[R] = ops;
        let tmp = &mut self.tmp[..n];
        st.residual_on(fork, self.diag, r, z, tmp);
        {
            let b1 = &mut work[n1..2 * n1];
            b1.fill(R::ZERO);
            let tmp: &[R] = tmp;
            fork.hot(Call(
                #[inline(always)]
                || restrict(cells, &sc, tmp, b1),
            ));
        }
        self.cyc.vcycle(fork, ops, 1, work);
        let coarse: &[R] = &work[..n1];
        fork.hot(Call(
            #[inline(always)]
            || prolong(cells, &sc, coarse, z),
        ));
        // post-smoothing: z += omega M^-1 (r - A z), with r . z on the way
        st.residual_on(fork, self.diag, r, z, tmp);
        fork.hot(Call(
            #[inline(always)]
            || st.line_solve(factor.0, factor.1, tmp),
        ));
        let tmp: &[R] = tmp;
        fork::set_and_dot(fork, z, Some(r), |i, zi| zi + tmp[i], self.part)
    }
}

impl<R: Real, const D: usize> Cycle<R, D> {
    /// Level `l >= 1`: `x_l = V b_l` with `work = [x_l | b_l | coarser levels... | shared]`.
    pub(crate) fn vcycle<F: Fork>(&self, fork: &F, ops: &[R], l: usize, work: &mut [R]) {
        let lv = &self.levels;
        let n = lv.n[l];
        let (xb, rest) = work.split_at_mut(2 * n);
        let (x, b) = xb.split_at_mut(n);
        let op = Op::at(&ops[lv.op_offset(l)..], lv.cells[l], self.periodic);
        if l + 1 == lv.count {
            x.fill(R::ZERO);
            for _ in 0..COARSEST_SWEEPS {
                op.gauss_seidel(b, x, true);
                op.gauss_seidel(b, x, false);
            }
            return;
        }
        let (nc, sc) = (lv.n[l + 1], strides(lv.cells[l + 1]));
        // Jacobi smoothing (vectorised face loops; the shared vector holds the residual):
        // x = w D^-1 b from 0, then the residual goes down, then x += w D^-1 (b - A x).
        let shared = rest.len() - lv.n[1];
        let w = self.omega_c;
        let (b, d): (&[R], &[R]) = (b, op.adiag);
        fork::set(fork, x, |i, _| w * b[i] / d[i]);
        {
            let (deeper, t) = rest.split_at_mut(shared);
            op.residual_on(fork, b, x, t);
            let bc = &mut deeper[nc..2 * nc];
            bc.fill(R::ZERO);
            let t: &[R] = &t[..n];
            fork.hot(Call(
                #[inline(always)]
                || restrict(op.cells, &sc, t, bc),
            ));
        }
        self.vcycle(fork, ops, l + 1, rest);
        let coarse: &[R] = &rest[..nc];
        fork.hot(Call(
            #[inline(always)]
            || prolong(op.cells, &sc, coarse, x),
        ));
        let t = &mut rest[shared..];
        op.residual_on(fork, b, x, t);
        let t: &[R] = t;
        fork::set(fork, x, |i, xi| xi + w * t[i] / d[i]);
    }
}

/// `z = B r` once, with the preconditioner [`solve`] starts with (the lines) or, if
/// `multigrid` and the grid can coarsen in `sc.coarse`, the one it switches to; returns
/// `r . z`. The serial reference of the slab preconditioner's tests
/// ([`super::cycle_slab`]).
#[doc(hidden)]
pub fn precondition_once<R: Real, const D: usize, const N: usize>(
    st: &Stencil<'_, R, D, N>,
    diag: &[R],
    r: &[R],
    z: &mut [R],
    sc: Scratch<'_, R>,
    multigrid: bool,
) -> R {
    let fork = &fork::Serial;
    let mut pc = Precond::new(
        (fork, sc.part),
        st,
        diag,
        sc.pre,
        sc.line,
        sc.tmp,
        sc.coarse,
    );
    if multigrid && pc.can_coarsen() {
        pc.multigrid();
    }
    pc.apply(r, z)
}

/// Solves `A x = b` by preconditioned CG (module docs) from the initial guess in `x`, until
/// `|r| <= relative max(|b|, floor)` or `max_iterations` ([`Stop`]). `floor` is an absolute
/// scale of the right-hand side (e.g. `|diag| u_ref`): without it a component that is ~0
/// everywhere (the vertical velocity of a shear flow) would be solved to a relative accuracy
/// it does not need. Allocation-free; the scratch is overwritten.
///
/// With [`Preconditioner::Auto`] the solve starts with the line preconditioner alone, the
/// cheapest per iteration and enough for most systems of a step. Every 4 iterations it
/// extrapolates the residual decay of the last 4; if that predicts more than 12 further
/// iterations, it builds the multigrid hierarchy and restarts CG from the current iterate. The
/// decision depends only on the data, so the bits do not change from run to run.
pub fn solve<R: Real, const D: usize, const N: usize>(
    st: &Stencil<'_, R, D, N>,
    diag: &[R],
    b: &[R],
    x: &mut [R],
    sc: Scratch<'_, R>,
    stop: Stop<R>,
) -> Solve<R> {
    solve_on(&fork::Serial, st, diag, b, x, sc, stop)
}

/// [`solve`] with its fine-grid loops on the threads of `fork`: the products, the sums and
/// the vector updates, and the coarse levels' residuals and smoothing. The line solves stay
/// on the caller's thread: a vertical line is a recurrence from floor to lid, and the lines
/// of a row-major array cannot be cut into slices; sweeping column blocks into scratch and
/// copying them back cost 0.38x - 1.09x the serial sweep on 2 threads (64 x 64 to 512 x 512,
/// docs/parallel.md). Restriction, prolongation and the coarsest sweeps stay there too.
/// The same bits for any number of parts (module [`crate::fork`]); a `Scratch::part`
/// shorter than the grid runs the serial solve.
pub fn solve_on<R: Real, const D: usize, const N: usize, F: Fork>(
    fork: &F,
    st: &Stencil<'_, R, D, N>,
    diag: &[R],
    b: &[R],
    x: &mut [R],
    sc: Scratch<'_, R>,
    stop: Stop<R>,
) -> Solve<R> {
    let n = st.grid.len();
    if fork.parts() > 1 && sc.part.len() < n {
        return solve_on(&fork::Serial, st, diag, b, x, sc, stop);
    }
    let (tol, floor, max_iter) = (stop.relative, stop.floor, stop.max_iterations);
    let (b, x) = (&b[..n], &mut x[..n]);
    let (r, p, ap) = (&mut sc.r[..n], &mut sc.p[..n], &mut sc.ap[..n]);
    let part = &mut *sc.part;
    let bnorm = fork::dot(fork, b, b, part).sqrt();
    if bnorm == R::ZERO {
        x.fill(R::ZERO);
        return Solve {
            iterations: 0,
            relative_residual: R::ZERO,
        };
    }
    st.apply_on(fork, diag, x, ap);
    let mut rr = {
        let ap: &[R] = ap;
        fork::set_and_dot(fork, r, None, |i, _| b[i] - ap[i], part)
    };
    let target = tol * bnorm.max(floor);
    if rr.sqrt() <= target {
        return Solve {
            iterations: 0,
            relative_residual: rr.sqrt() / bnorm,
        };
    }
    let mut pc = Precond::new((fork, part), st, diag, sc.pre, sc.line, sc.tmp, sc.coarse);
    let mut probe = match stop.preconditioner {
        _ if !pc.can_coarsen() => u32::MAX,
        Preconditioner::Lines => u32::MAX,
        Preconditioner::Multigrid => 0,
        Preconditioner::Auto => PROBE,
    };
    let (mut r0, long) = (rr.sqrt(), R::from_f64(LONG));
    if probe == 0 {
        pc.multigrid();
    }
    let mut rz = pc.apply(r, p);
    let mut it = 0;
    while it < max_iter {
        it += 1;
        st.apply_on(fork, diag, p, ap);
        let pap = fork::dot(fork, p, ap, pc.part);
        if !(pap > R::ZERO) {
            break; // breakdown (only with an exact solution or a broken operator)
        }
        let alpha = rz / pap;
        rr = fork::update(fork, alpha, p, ap, x, r, pc.part);
        let rn = rr.sqrt();
        if rn <= target {
            break;
        }
        if it == probe {
            // iterations still needed at the rate of the last window: ln(target/|r|) / ln(rate)
            let rate = (rn / r0).ln() / R::from_usize(PROBE as usize);
            (probe, r0) = (probe + PROBE, rn);
            if rate >= R::ZERO || (target / rn).ln() / rate > long {
                probe = u32::MAX;
                pc.multigrid();
                let rz_new = pc.apply(r, p);
                rz = rz_new;
                continue;
            }
        }
        // z = B r into `ap` (free until the next product)
        let rz_new = pc.apply(r, ap);
        let beta = rz_new / rz;
        rz = rz_new;
        let ap: &[R] = ap;
        fork::set(fork, p, |i, pi| ap[i] + beta * pi);
    }
    Solve {
        iterations: it,
        relative_residual: rr.sqrt() / bnorm,
    }
}

/// Steps the line index `k` (axes 1 and up; axis 0 runs along the line) to the next line in
/// memory order: the odometer every line loop of this module walks.
#[inline(always)]
fn next_line<const D: usize>(k: &mut [usize; D], cells: &[usize; D]) {
    for a in 1..D {
        k[a] += 1;
        if k[a] < cells[a] {
            return;
        }
        k[a] = 0;
    }
}
