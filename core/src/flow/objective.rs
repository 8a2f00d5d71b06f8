//! The objective (frame-indifferent) stress, an opt-in extension of the model (model.md 2.6).
//!
//! The model's stress is `sigma = eta grad u` with the heating `a eta kappa:kappa`,
//! `kappa = grad u` (model.md 2). Neither vanishes in a rigid rotation `u = Omega x r`
//! (`kappa` is then antisymmetric, not zero), so a drum turning rigidly in the lab frame is
//! heated (`2 a eta omega^2`) and, where `eta` varies, pushed (docs/frames.md). The objective
//! form uses the symmetric strain rate instead,
//!
//! ```text
//! sigma = eta (grad u + grad u^T),   H = sigma : grad u = eta (kappa:kappa + kappa:kappa^T)
//!                                                      = 2 eta D:D,   D = (kappa + kappa^T)/2
//! ```
//!
//! It is not made deviatoric (a choice: the isotropic part only changes the normal viscous
//! stress under compression, and the plain sum keeps the scheme simple). In simple shear `u_x(z)` it *equals* the spec: `sigma_xz = eta du_x/dz`, and
//! `kappa:kappa^T = kappa_xz kappa_zx = 0`, so `H = eta (du_x/dz)^2`; the shear cell and the
//! chute calibrations (model.md 2.3, 7.4) are unchanged. In a rigid rotation `D = 0`: no
//! stress, no heating.
//!
//! # Discretisation (see `Flow::viscous`)
//! `div(eta grad u^T)` is split into its *normal* part `d_a (eta d_a u_a)` for component `a`
//! and its *cross* parts `d_b (eta d_a u_b)`, `b != a`:
//! - the normal part has the stencil of the component's own implicit operator along its own
//!   axis, so it goes into the implicit solve for free: that face coefficient is doubled
//!   (`2 eta d_a u_a`, also at a box face with a Dirichlet normal velocity);
//! - the cross parts are a lagged explicit face force from the start-of-step velocity:
//!   across a face normal to `b` the flux of component `a` is `eta_f (d_a u_b)_f` with
//!   `(d_a u_b)_f` the mean of the two cells' centred differences (one-sided next to a closed
//!   face or an empty cell). Each face adds to one cell what it takes from the other, so
//!   momentum is conserved face by face.
//! - At a cut wall the wall law's traction `eta (u_B - u) / d` (the spec's `eta grad u . n`)
//!   gets the lagged `eta (grad u)^T n` from the cell's differences (which avoid merge
//!   members where they can, [`derivative_field`]). `u_B` is taken at the
//!   wall point `x + d n`, so for a rigid rotation `(u_B - u) / d = W n` and
//!   `(grad u)^T n = W^T n = -W n`: the traction vanishes, as it must.
//! - At a box face the normal velocity is constant along the face (0 at a wall, the inflow
//!   value), so the cross flux `eta d_a u_n` vanishes there.
//!
//! Why the lagged cross part needs no smaller step: for constant `eta` and a Fourier mode `k`
//! the split update is `(I + dt M) u^{n+1} = (I - dt E) u^n` with
//! `M = eta (|k|^2 I + diag(k_a^2))` (implicit, incl. the doubled normal part) and
//! `E = eta (k k^T - diag(k_a^2))` (explicit, off-diagonal). Its amplification factor tends to
//! the eigenvalues of `-M^{-1} E` as `eta dt` grows, at most 1/3 in 2D (`k_x = k_z`) and 1/2
//! in 3D (`k_x = k_y = k_z`), and is below 1 for every step: the scheme is unconditionally
//! stable. (Keeping the normal part explicit too would give `-k k^T / |k|^2`, eigenvalue
//! -1: a stiff checkerboard that never decays. The doubled coefficient avoids it.) At a cut
//! wall the whole transposed traction is lagged; its coefficient `kw eta d / h` stays below
//! the implicit wall term's `kw eta` since `d < h`: a heuristic bound, not a proof. Measured:
//! the lab drums of tests/tests/flow_objective.rs run at the spec's own `stable_dt` (6,634
//! against 6,628 steps for one revolution) with no sign of growth; they take about twice
//! the CG iterations in the lab frame.
//!
//! The heating is the work of this discrete stress face by face: a face normal to `b` with
//! jumps `du` dissipates `eta_f / h_b^2 sum_a du_a (du_a + h_b (d_a u_b)_f)` (the normal term
//! doubled), a cut wall `kw eta (u_B - u) . ((u_B - u) + d (grad u)^T n)`. Per face it
//! vanishes for a rigid rotation and equals the spec's for `u_x(z)`. A cell's sum is clipped
//! at 0: the continuous `2 eta D:D` is non-negative, the discrete one need not be to round-off
//! or where the centred and face differences disagree.

use super::Flow;
use crate::grid::Grid;
use crate::real::Real;

/// Which viscous stress the flow uses (model.md 2, 2.6; [`super::FlowConfig::stress`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Stress {
    /// The model's `sigma = eta grad u`, heating `eta kappa:kappa` (default; every scene and
    /// golden is computed with it).
    #[default]
    Spec,
    /// `sigma = eta (grad u + grad u^T)`, heating `2 eta D:D`: the same as the spec in simple
    /// shear, zero in a rigid rotation (frame-indifferent; see the module docs).
    Objective,
}

impl Stress {
    /// The scene-file name: `"spec"` or `"objective"`.
    pub fn name(self) -> &'static str {
        match self {
            Stress::Spec => "spec",
            Stress::Objective => "objective",
        }
    }
}

/// Fills `out[i] = d f / d x_axis` at every cell: centred, one-sided where one neighbour is
/// unusable (outside the box, behind a closed face, empty), 0 where both are. Exact for a
/// linear field either way. `ap` = the cut-cell apertures (low, high) along `axis` and the
/// merge map, if any: a merge member (a small cut cell, [`crate::geometry::CutCells::master`])
/// is used only when neither neighbour along the axis is a whole cell of its own, since its
/// velocity is the implicit solve's answer on a row weighted by its tiny volume (a 5e-23
/// sliver behind a 1.2e-7 aperture on the 32 x 32 drum was off the rigid rotation by 1e-2
/// of omega R, and the centred difference through it heated its neighbour to 30x the bulk's
/// T; tests/tests/flow_objective.rs). One-sided differences stay exact on a rigid rotation.
#[allow(clippy::too_many_arguments)]
fn derivative_field<R: Real, const D: usize>(
    grid: &Grid<R, D>,
    periodic: bool,
    ap: Option<(&[R], &[R], &[u32])>,
    c: &[R],
    vac: R,
    f: &[R],
    axis: usize,
    out: &mut [R],
) {
    let na = grid.cells()[axis];
    let s = grid.stride(axis);
    let h = grid.spacing()[axis];
    let (inv, inv2) = (R::ONE / h, R::ONE / (R::TWO * h));
    for (i, o) in out[..grid.len()].iter_mut().enumerate() {
        let k = grid.coord(i, axis);
        let hi = if k + 1 < na {
            Some(i + s)
        } else if periodic {
            Some(i + s - s * na)
        } else {
            None
        };
        let lo = if k > 0 {
            Some(i - s)
        } else if periodic {
            Some(i + s * (na - 1))
        } else {
            None
        };
        let member = |j: usize| match ap {
            Some((_, _, m)) => m[j] as usize != j,
            None => false,
        };
        let open = |j: usize, a: R| a > R::ZERO && c[j] > vac;
        let (al, ah) = match ap {
            Some((l, r, _)) => (l[i], r[i]),
            None => (R::ONE, R::ONE),
        };
        let lo = lo.filter(|&j| open(j, al));
        let hi = hi.filter(|&j| open(j, ah));
        // prefer neighbours that are not merge members (module docs)
        let pick = |o: Option<usize>| o.filter(|&j| !member(j));
        let (glo, ghi) = (pick(lo), pick(hi));
        let (lo, hi) = if glo.is_some() || ghi.is_some() {
            (glo, ghi)
        } else {
            (lo, hi)
        };
        *o = match (lo, hi) {
            (Some(l), Some(r)) => (f[r] - f[l]) * inv2,
            (Some(l), None) => (f[i] - f[l]) * inv,
            (None, Some(r)) => (f[r] - f[i]) * inv,
            (None, None) => R::ZERO,
        };
    }
}

impl<R: Real, const D: usize, const N: usize> Flow<R, D, N> {
    /// `out = d u_b / d x_axis` of the field `u` (`prev`: the start-of-step velocity).
    fn fill_derivative(&mut self, prev: bool, b: usize, axis: usize) {
        let per = self.periodic()[axis];
        let ap = if self.walls.on {
            Some((
                &self.walls.ap_lo[axis][..],
                &self.walls.ap_hi[axis][..],
                &self.walls.master[..],
            ))
        } else {
            None
        };
        let f = if prev { &self.u_prev[b] } else { &self.u[b] };
        derivative_field(
            &self.grid,
            per,
            ap,
            &self.c,
            self.cfg.vacuum,
            f,
            axis,
            &mut self.solve.ap,
        );
    }

    /// Adds `w(l, r)` to both cells of every face along `b` (interior and periodic wrap).
    fn each_face(&mut self, b: usize, mut w: impl FnMut(&Self, usize, usize) -> R, add: bool) {
        let grid = self.grid;
        let periodic = self.periodic()[b];
        let fb = grid.face_blocks(b);
        let s = fb.stride;
        for blk in 0..fb.blocks {
            let l0 = blk * fb.block_stride;
            for l in l0..l0 + fb.block_len {
                let v = w(self, l, l + s);
                self.face_apply(l, l + s, v, add);
            }
            if periodic {
                for first in l0..l0 + s {
                    let last = first + fb.block_len;
                    let v = w(self, last, first);
                    self.face_apply(last, first, v, add);
                }
            }
        }
    }

    /// `add`: heating, `v` to both cells (`inflow`); else a force, `+v` to `l`, `-v` to `r`
    /// (`rhs`).
    #[inline(always)]
    fn face_apply(&mut self, l: usize, r: usize, v: R, add: bool) {
        if add {
            self.inflow[l] += v;
            self.inflow[r] += v;
        } else {
            self.rhs[l] += v;
            self.rhs[r] -= v;
        }
    }

    /// Adds the lagged cross part of `div(eta grad u^T)` for component `comp` (from the
    /// start-of-step velocity `u_prev`) and the cut wall's `eta (grad u)^T n` to the viscous
    /// right-hand side `rhs`; the face coefficients `kf` must hold the viscosity's
    /// (`eta_f ap / h^2`). Uses the CG scratch `ap` and `r` (free before the solve).
    pub(super) fn transposed_force(&mut self, comp: usize) {
        let n = self.grid.len();
        let h = self.grid.spacing();
        let emb = self.walls.on;
        if emb {
            self.solve.r[..n].fill(R::ZERO);
        }
        for b in 0..D {
            // ap = d_comp u_b at the cells
            self.fill_derivative(true, b, comp);
            if b != comp {
                // the normal part (b == comp) is implicit: doubled face coefficient
                let hb = h[b] * R::HALF;
                self.each_face(
                    b,
                    |f, l, r| f.kf[b][l] * hb * (f.solve.ap[l] + f.solve.ap[r]),
                    false,
                );
            }
            if emb {
                for i in 0..n {
                    if self.walls.wall_k[i] > R::ZERO {
                        self.solve.r[i] += self.solve.ap[i] * self.walls.normal[b][i];
                    }
                }
            }
        }
        if emb {
            for i in 0..n {
                let kw = self.walls.wall_k[i];
                if kw > R::ZERO {
                    let e = self.wall_law(i).1;
                    self.rhs[i] += kw * e * self.walls.wall_d[i] * self.solve.r[i];
                }
            }
        }
    }

    /// Adds the objective heating's extra terms to `inflow` (after the spec's): per face
    /// normal to `b` `eta_f / (2 h_b^2) (du_b^2 + h_b sum_{a != b} du_a (d_a u_b)_f)` to each
    /// cell, per cut wall `kw eta (u_B - u) . d (grad u)^T n`, from the new velocity; the sum
    /// is clipped at 0 per cell. Uses the CG scratch `ap` and `r` (free after the solves).
    pub(super) fn objective_heating(&mut self) {
        let n = self.grid.len();
        let h = self.grid.spacing();
        let emb = self.walls.on;
        for b in 0..D {
            // the doubled normal stress: eta_f du_b^2 / h_b^2
            self.each_face(
                b,
                |f, l, r| {
                    let d = f.u[b][r] - f.u[b][l];
                    R::HALF * f.kf[b][l] * (d * d)
                },
                true,
            );
            for a in 0..D {
                if a == b {
                    continue;
                }
                self.fill_derivative(false, b, a);
                let hb = h[b] * R::HALF;
                self.each_face(
                    b,
                    |f, l, r| {
                        let du = f.u[a][r] - f.u[a][l];
                        R::HALF * f.kf[b][l] * (du * (hb * (f.solve.ap[l] + f.solve.ap[r])))
                    },
                    true,
                );
            }
        }
        if emb {
            // r[i] = sum_a (u_B - u)_a sum_b (d_a u_b) n_b at the wall cells
            self.solve.r[..n].fill(R::ZERO);
            for a in 0..D {
                for b in 0..D {
                    self.fill_derivative(false, b, a);
                    for i in 0..n {
                        let kw = self.walls.wall_k[i];
                        if kw > R::ZERO {
                            let ub = self.wall_law(i).0;
                            self.solve.r[i] += (ub[a] - self.u[a][i])
                                * (self.solve.ap[i] * self.walls.normal[b][i]);
                        }
                    }
                }
            }
            for i in 0..n {
                let kw = self.walls.wall_k[i];
                if kw > R::ZERO {
                    let e = self.wall_law(i).1;
                    self.inflow[i] += kw * e * (self.walls.wall_d[i] * self.solve.r[i]);
                }
            }
        }
        for q in self.inflow[..n].iter_mut() {
            *q = q.max(R::ZERO);
        }
    }
}
