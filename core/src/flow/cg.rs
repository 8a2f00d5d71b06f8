//! Matrix-free Jacobi-preconditioned conjugate gradients for the implicit stages of the flow.
//!
//! The operator is `A x = diag x + sum_faces k_f (x_L - x_R)` (added to the left cell,
//! subtracted from the right one): a weighted graph Laplacian of the grid plus a positive
//! diagonal, so A is symmetric positive definite whenever `diag > 0` and `k_f >= 0`.
//! Boundary conditions enter through `diag` and the right-hand side (Dirichlet) or not at all
//! (zero flux); periodic faces are the wrap-around faces, stored at the last cell of a line.
//! Sums run in cell order: the result is deterministic.

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

    /// `pre = 1 / (diag + sum of the adjacent face coefficients)`: the inverse of A's diagonal.
    pub fn jacobi(&self, diag: &[R], pre: &mut [R]) {
        let n = self.grid.len();
        pre[..n].copy_from_slice(&diag[..n]);
        for a in 0..D {
            let fb = self.grid.face_blocks(a);
            let s = fb.stride;
            for b in 0..fb.blocks {
                let l0 = b * fb.block_stride;
                for j in l0..l0 + fb.block_len {
                    pre[j] += self.kf[a][j];
                    pre[j + s] += self.kf[a][j];
                }
            }
            if self.periodic[a] {
                self.grid.for_each_boundary_cell(a, true, |last, first| {
                    pre[last] += self.kf[a][last];
                    pre[first] += self.kf[a][last];
                });
            }
        }
        for p in pre[..n].iter_mut() {
            *p = R::ONE / *p;
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
    /// inverse diagonal
    pub pre: &'a mut [R],
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

/// Solves `A x = b` by Jacobi-preconditioned CG from the initial guess in `x`, until
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
    let (r, p, ap, pre) = (
        &mut sc.r[..n],
        &mut sc.p[..n],
        &mut sc.ap[..n],
        &mut sc.pre[..n],
    );
    st.jacobi(diag, pre);
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
    let mut rz = R::ZERO;
    for i in 0..n {
        p[i] = pre[i] * r[i];
        rz += r[i] * p[i];
    }
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
        let mut rz_new = R::ZERO;
        for i in 0..n {
            rz_new += r[i] * r[i] * pre[i];
        }
        let beta = rz_new / rz;
        rz = rz_new;
        for i in 0..n {
            p[i] = pre[i] * r[i] + beta * p[i];
        }
    }
    Solve {
        iterations: it,
        relative_residual: rr.sqrt() / bnorm,
    }
}
