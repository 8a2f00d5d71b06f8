//! Matrix-free conjugate gradients for the implicit stages of the flow, preconditioned by
//! exact solves along the grid lines of the last (vertical) axis.
//!
//! The operator is `A x = diag x + sum_faces k_f (x_L - x_R)` (added to the left cell,
//! subtracted from the right one): a weighted graph Laplacian of the grid plus a positive
//! diagonal, so A is symmetric positive definite whenever `diag > 0` and `k_f >= 0`.
//! Boundary conditions enter through `diag` and the right-hand side (Dirichlet) or not at all
//! (zero flux); periodic faces are the wrap-around faces, stored at the last cell of a line.
//! Sums run in cell order: the result is deterministic.
//!
//! # Why a line preconditioner
//! The stiffness of these systems is vertical: the yield viscosity of a cold bed grows with
//! the lithostatic pressure, and the layers of a sheared bed couple through it. With a Jacobi
//! (diagonal) preconditioner the spin-up of the 7.4 shear cell took ~160 CG iterations per
//! system (2.5 million in all on 4 x 80 cells, half the run time). Block Jacobi with one block
//! per vertical grid line (the tridiagonal part of A along the last axis plus A's full
//! diagonal, factored once per solve by the Thomas algorithm) is exact in 1D and takes the
//! vertical coupling out of the iteration; what remains is the horizontal coupling. The
//! factor stays symmetric positive definite (each row is diagonally dominant with a positive
//! mass term), so CG applies unchanged. Rows of a line are processed together across the
//! other axes, so both sweeps vectorise.

use crate::grid::Grid;
use crate::real::Real;

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
        let n = self.grid.len();
        for i in 0..n {
            out[i] = diag[i] * x[i];
        }
        for a in 0..D {
            let fb = self.grid.face_blocks(a);
            let s = fb.stride;
            let kf = &self.kf[a];
            for b in 0..fb.blocks {
                let l0 = b * fb.block_stride;
                let len = fb.block_len;
                // Two passes (left cells, then right cells) keep each loop free of a
                // read-after-write dependency, so it vectorises.
                {
                    let (o, xl, xr, k) = (
                        &mut out[l0..l0 + len],
                        &x[l0..l0 + len],
                        &x[l0 + s..l0 + s + len],
                        &kf[l0..l0 + len],
                    );
                    for j in 0..len {
                        o[j] += k[j] * (xl[j] - xr[j]);
                    }
                }
                {
                    let (o, xl, xr, k) = (
                        &mut out[l0 + s..l0 + s + len],
                        &x[l0..l0 + len],
                        &x[l0 + s..l0 + s + len],
                        &kf[l0..l0 + len],
                    );
                    for j in 0..len {
                        o[j] += k[j] * (xr[j] - xl[j]);
                    }
                }
            }
            if self.periodic[a] {
                self.grid.for_each_boundary_cell(a, true, |last, first| {
                    let f = kf[last] * (x[last] - x[first]);
                    out[last] += f;
                    out[first] -= f;
                });
            }
        }
    }

    /// `m = diag + sum of the adjacent face coefficients`: A's diagonal.
    fn diagonal(&self, diag: &[R], m: &mut [R]) {
        let n = self.grid.len();
        m[..n].copy_from_slice(&diag[..n]);
        for a in 0..D {
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
            let (lh, kb) = (&mut l[row..row + s], &k[row - s..row]);
            for j in 0..s {
                lh[j] = kb[j] / db[j];
                dh[j] -= kb[j] * lh[j];
            }
        }
        for x in d.iter_mut() {
            *x = R::ONE / *x;
        }
    }

    /// `z = M^-1 r` with the factor of [`Self::line_factor`]: forward and backward sweeps row
    /// by row.
    pub fn precondition(&self, inv_d: &[R], l: &[R], r: &[R], z: &mut [R]) {
        let n = self.grid.len();
        let s = self.grid.stride(D - 1);
        let z = &mut z[..n];
        z[..s].copy_from_slice(&r[..s]);
        for row in (s..n).step_by(s) {
            let (below, here) = z.split_at_mut(row);
            let (zb, zh) = (&below[row - s..], &mut here[..s]);
            let (rh, lh) = (&r[row..row + s], &l[row..row + s]);
            for j in 0..s {
                zh[j] = rh[j] + lh[j] * zb[j];
            }
        }
        for (x, w) in z.iter_mut().zip(&inv_d[..n]) {
            *x *= *w;
        }
        for row in (s..n).step_by(s).rev() {
            let (below, here) = z.split_at_mut(row);
            let (zb, zh) = (&mut below[row - s..], &here[..s]);
            let lh = &l[row..row + s];
            for j in 0..s {
                zb[j] += lh[j] * zh[j];
            }
        }
    }
}

/// Scratch vectors of one solve (each at least the grid length).
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
}

/// Outcome of one solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Solve<R> {
    /// Iterations used.
    pub iterations: u32,
    /// Final `|r| / |b|` (Euclidean).
    pub relative_residual: R,
}

fn dot<R: Real>(a: &[R], b: &[R]) -> R {
    let mut s = R::ZERO;
    for (x, y) in a.iter().zip(b) {
        s += *x * *y;
    }
    s
}

/// Solves `A x = b` by line-preconditioned CG from the initial guess in `x`, until
/// `|r| <= relative max(|b|, floor)` or `max_iterations` ([`Stop`]). `floor` is an absolute scale of the
/// right-hand side (e.g. `|diag| u_ref`): without it a component that is ~0 everywhere (the
/// vertical velocity of a shear flow) would be solved to a relative accuracy it does not need.
/// Allocation-free; the scratch is overwritten.
pub fn solve<R: Real, const D: usize, const N: usize>(
    st: &Stencil<'_, R, D, N>,
    diag: &[R],
    b: &[R],
    x: &mut [R],
    sc: Scratch<'_, R>,
    stop: Stop<R>,
) -> Solve<R> {
    let (tol, floor, max_iter) = (stop.relative, stop.floor, stop.max_iterations);
    let n = st.grid.len();
    let (b, x) = (&b[..n], &mut x[..n]);
    let (r, p, ap, pre, line) = (
        &mut sc.r[..n],
        &mut sc.p[..n],
        &mut sc.ap[..n],
        &mut sc.pre[..n],
        &mut sc.line[..n],
    );
    st.line_factor(diag, pre, line);
    st.apply(diag, x, ap);
    for i in 0..n {
        r[i] = b[i] - ap[i];
    }
    let bnorm = dot(b, b).sqrt();
    if bnorm == R::ZERO {
        x.fill(R::ZERO);
        return Solve {
            iterations: 0,
            relative_residual: R::ZERO,
        };
    }
    let target = tol * bnorm.max(floor);
    let mut rr = dot(r, r);
    if rr.sqrt() <= target {
        return Solve {
            iterations: 0,
            relative_residual: rr.sqrt() / bnorm,
        };
    }
    st.precondition(pre, line, r, p);
    let mut rz = dot(r, p);
    let mut it = 0;
    while it < max_iter {
        it += 1;
        st.apply(diag, p, ap);
        let pap = dot(p, ap);
        if !(pap > R::ZERO) {
            break; // breakdown (only with an exact solution or a broken operator)
        }
        let alpha = rz / pap;
        rr = R::ZERO;
        for i in 0..n {
            x[i] += alpha * p[i];
            r[i] -= alpha * ap[i];
            rr += r[i] * r[i];
        }
        if rr.sqrt() <= target {
            break;
        }
        // z = M^-1 r into `ap` (free until the next product)
        st.precondition(pre, line, r, ap);
        let rz_new = dot(r, ap);
        let beta = rz_new / rz;
        rz = rz_new;
        for i in 0..n {
            p[i] = ap[i] + beta * p[i];
        }
    }
    Solve {
        iterations: it,
        relative_residual: rr.sqrt() / bnorm,
    }
}
