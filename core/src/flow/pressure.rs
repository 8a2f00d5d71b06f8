//! Implicit pressure of the flow (model.md 5.3 stage 2, implicit mode; 5.4).
//!
//! # Why
//! The explicit forward-backward pressure is stable only for `a_s dt / h < 1`, and the sound
//! speed of a dense granular bed (`a_s ~ 10 m/s`, growing like `g(c)` towards `c_rcp`) is some
//! 300 times its flow speed in a slow drum. The implicit pressure takes the acoustic coupling
//! `c -> p -> u -> c` within the step, so only the advective and free-fall terms of the
//! Courant rule remain ([`super::Flow::stable_dt`]).
//!
//! # The scheme (one linear solve per step, before the transport)
//! - The pressure is linearised about the state at the start of the step,
//!   `p^{n+1} = p^n + a_s^2 (c^{n+1} - c^n)` with `a_s^2 = dp/dc` at fixed `T`
//!   ([`crate::closure::sound_speed_squared`], at `max(a_s^2, a_floor^2)`).
//! - Each face velocity is the end-of-step one, `u_f = (u_L + u_R)/2 + dt F_f(p^{n+1}) / c_f`,
//!   with the *same* compact face force `F_f` as the explicit step (hydrostatic wall ghosts,
//!   fade weight `w`, the frame's body force), so a bed in discrete lithostatic balance has
//!   `u_f = 0` and no increment at all. The mass flux is `c_up u_f`.
//! - Eliminating `c^{n+1}` and `u_f` gives, per cell (content units, open volume `V`),
//!   `V dp / a_s^2 + (dt/h)^2 sum_f alpha_f w_f (c_up/c_f)_f (dp_i - dp_j) = -(dt/h) sum_f
//!   alpha_f F_f^0` with `F^0` the face fluxes at `p^n`: symmetric positive definite (the
//!   upwind side of each face is lagged from `F^0`), solved by [`super::cg`]. An outlet opening
//!   with `p = 0` on its face moves grains out with the cell's velocity plus `dt` times the
//!   cell's half of the outlet face force over `c` (what the momentum update gives the cell);
//!   its ghost mirrors the cell (`p_ghost = -p`, so `dp_ghost = -dp`), which adds
//!   `(dt/h)^2 alpha w` to its cell's diagonal (Dirichlet `dp = 0` on the face).
//! - `p = max(p^n + dp, 0)` then drives both the transport's face velocities (stage 1, whose
//!   conservative limiters act on those final fluxes: mass to round-off and
//!   `0 <= c <= c_max` by construction) and the momentum update (stage 2, the same face
//!   forces). The clamp at 0 is where the linearisation would put tension into an expanding
//!   loose cell, which the closure cannot produce.
//!
//! The solve starts from `dp = 0` every step, so a restored checkpoint keeps its bits; `dp`
//! lives in the face-flux array of axis 0, which the transport rewrites before reading.

use super::cg::{Preconditioner, Stencil, Stop};
use super::reach::Reach;
use super::step::moves_mass;
use super::{Flow, FlowSide, OutletPressure};
use crate::boundary::Boundary;
use crate::closure;
use crate::fork::Fork;
use crate::real::Real;
use crate::segregation::flux::transport as upwind;

/// How stage 2 of the flow step advances the pressure (model.md 5.3, 5.4).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum PressureMode {
    /// Forward-backward: `p` from the new `c` after the transport. Cheap per step, but held
    /// to the acoustic limit `a_s dt / h < 1`.
    #[default]
    Explicit,
    /// One linearised SPD solve per step for the pressure increment (module docs): no
    /// acoustic limit; the step is held by the advective and free-fall terms only.
    Implicit,
}

impl PressureMode {
    /// The scene-file name: `"explicit"` or `"implicit"`.
    pub fn name(self) -> &'static str {
        match self {
            PressureMode::Explicit => "explicit",
            PressureMode::Implicit => "implicit",
        }
    }
}

impl<R: Real, const D: usize, const N: usize> Flow<R, D, N> {
    /// Sets `p` to the implicit `p^{n+1}` of the step of length `dt` (module docs).
    pub(super) fn implicit_pressure<F: Fork, Re: Reach<R, D, N>>(
        &mut self,
        dt: R,
        fork: &F,
        reach: &mut Re,
    ) {
        let n = self.grid.len();
        let h = self.grid.spacing();
        let grid = self.grid;
        let vac = self.cfg.vacuum;
        let emb = self.walls.on;
        let mat = self.cfg.material;
        // p^n from the current c and T (the packing limits may have changed since the last
        // step: back-coupling).
        self.pressures();
        let a2_floor = self.sound_floor(dt);
        for i in 0..n {
            let v = self.mass_factor(i);
            let a2 = closure::sound_speed_squared(
                &mat,
                self.c_eff(i),
                self.t[i],
                self.c_rcp[i],
                self.c_rlp[i],
            );
            let a2 = a2.max(a2_floor);
            self.diag[i] = v / a2;
            self.rhs[i] = R::ZERO;
            // p^n, c^n and a_s^2 kept for `consistent_pressure` in the spare solve set,
            // which only the viscous stage's side-by-side solves use, after it (the transport
            // with embedded walls takes the main set's `ap`, `p` and `rhs` as its increment
            // scratch)
            self.spare.diag[i] = self.p[i];
            self.spare.diag2[i] = self.c[i];
            self.spare.rhs[i] = a2;
        }
        let own = reach.owned(n);
        let vnorm = reach.sum_in_order(R::ZERO, |mut sum| {
            for i in own {
                let v = self.mass_factor(i);
                sum += v * v;
            }
            sum
        });
        for a in 0..D {
            let lam = dt / h[a];
            let kk = lam * lam;
            self.kf[a][..n].fill(R::ZERO);
            let fb = grid.face_blocks(a);
            let s = fb.stride;
            for b in 0..fb.blocks {
                let l0 = b * fb.block_stride;
                for l in l0..l0 + fb.block_len {
                    self.pressure_face(a, l, l + s, dt, vac);
                }
            }
            let (lo, hi) = (self.bc[a][0], self.bc[a][1]);
            grid.for_each_boundary_cell(a, true, |last, first| {
                if hi.kind == Boundary::Periodic {
                    return self.pressure_face(a, last, first, dt, vac);
                }
                let ap = if emb {
                    self.walls.ap_hi[a][last]
                } else {
                    R::ONE
                };
                let f = ap * self.high_flux(a, last, first, &hi, dt);
                let k = ap * self.outlet_velocity(a, last, true, &hi, dt).1;
                self.rhs[last] -= lam * f;
                self.diag[last] += kk * k;
            });
            if moves_mass(&lo) {
                grid.for_each_boundary_cell(a, false, |first, _| {
                    let ap = if emb {
                        self.walls.ap_lo[a][first]
                    } else {
                        R::ONE
                    };
                    let f = ap * self.low_flux(a, first, &lo, dt);
                    let k = ap * self.outlet_velocity(a, first, false, &lo, dt).1;
                    self.rhs[first] += lam * f;
                    self.diag[first] += kk * k;
                });
            }
            for l in 0..n {
                self.kf[a][l] *= kk;
            }
        }
        // The residual is a content change per cell: stop at 1e-3 of a full cell's content
        // times the relative tolerance when the right-hand side is smaller (near rest).
        let floor = R::from_f64(1e-3) * vnorm.sqrt();
        let st = Stencil {
            grid: &self.grid,
            periodic: self.periodic(),
            kf: &self.kf,
        };
        // The increment lives in `flux[0]`: the transport's first pass rewrites every entry
        // of it before reading any, so it is free here (and the flow keeps its size per cell).
        let dp = &mut self.flux[0];
        dp[..n].fill(R::ZERO);
        // `inflow` is free until the transport's first pass.
        let res = reach.solve(
            fork,
            &st,
            &self.diag,
            &self.rhs,
            dp,
            self.solve.scratch(&mut self.inflow),
            Stop {
                relative: self.cfg.cg_tolerance_pressure,
                floor,
                max_iterations: self.cfg.cg_max_iterations,
                preconditioner: Preconditioner::Auto,
            },
        );
        self.last_pressure_cg = res.iterations;
        self.cg_iterations += u64::from(res.iterations);
        for i in 0..n {
            self.p[i] = (self.p[i] + self.flux[0][i]).max(R::ZERO);
        }
    }

    /// Floor of `a_s^2` in the pressure system at the step `dt`. It keeps the diagonal
    /// finite where `a_s = 0` (empty or cold loose cells, whose pressure does not depend on
    /// c); a cell whose sound crosses less than 1e-6 of a cell per step has no acoustic
    /// coupling worth solving for.
    pub(super) fn sound_floor(&self, dt: R) -> R {
        let h = self.grid.spacing();
        let mut hmin = h[0];
        for hh in h.iter().take(D) {
            hmin = hmin.min(*hh);
        }
        R::from_f64(1e-12) * (hmin / dt) * (hmin / dt)
    }

    /// After the transport, in the cells the free surface fades (`c < surface`): the
    /// pressure of the momentum update (stage 2) is at most the linearised equation of state
    /// at the content the transport actually left there, `p_c = max(p^n + a_s^2 (c^{n+1} -
    /// c^n), 0)`, blended by the fade weight `w = min(1, c^{n+1} / surface)`:
    /// `p = p^{n+1} - (1 - w) max(p^{n+1} - p_c, 0)`. Cells with `c >= surface` (`w = 1`)
    /// keep `p^{n+1} = p^n + dp` of the solve bit for bit.
    ///
    /// Why: `p^n + dp` is the pressure of the content the linear system *predicted*, and the
    /// system assumes a donor can give any amount; over the free surface it cannot, and the
    /// donor limiter lets through what the donor holds. On the 64 x 64 tumbler at pressure
    /// tolerance 1e-6 (t = 0.599 s) a cell of c = 1.7e-11 got `dp = 4.4e-7` from the solve
    /// (`a_s^2 = 5.0e-2`), the pressure of a predicted content of 8.7e-6, while its donor below
    /// held 1.9e-8 and the limiter let 1.8e-8 in. Its free-surface push `(1 - w) p / h` then
    /// drove that content with the pressure of a cell 500 times fuller: 28 m/s in one step;
    /// the viscous heating raised `T` and `a_s^2` with it, so the next increments grew (`T`
    /// 5e-2 -> 6.5 -> 88 -> 3e5 in four steps) and the run blew up (1e51 m/s, steps of
    /// 5e-58 s). At tolerance 1e-10 the same mismatch gave a 0.7 m/s kick (t = 0.605 s): the
    /// loose solve only made the predicted inflow larger. With `p <= p_c ~ a_s^2 c^{n+1}`
    /// (`~ T c` in a dilute cell) the push accelerates a faded cell by at most `~ T / h` plus
    /// `w p^{n+1} / (h c) <= p^{n+1} / (h surface)`, whatever the solve returned.
    ///
    /// Why not in the dense bed: there the transport falls short of the prediction where the
    /// receiver limiter stops a packed cell at `c_max`, and `p^n + dp` is then the pressure
    /// that holds the packing (tried: `p_c` in every cell let the tumbler's bed fall freely,
    /// 6.6 m/s after 0.7 s, with the limiters blocking its mass).
    pub(super) fn consistent_pressure(&mut self) {
        let n = self.grid.len();
        let surface = self.cfg.surface;
        // p^n, c^n and a_s^2 as `implicit_pressure` kept them
        let (p0, c0, a2) = (&self.spare.diag, &self.spare.diag2, &self.spare.rhs);
        for i in 0..n {
            let fade = R::ONE - (self.c[i] / surface).min(R::ONE);
            if fade > R::ZERO {
                let pc = (p0[i] + a2[i] * (self.c[i] - c0[i])).max(R::ZERO);
                let excess = (self.p[i] - pc).max(R::ZERO);
                self.p[i] -= fade * excess;
            }
        }
    }

    /// One interior (or wrap) face `(l, r)` along `a` of the pressure system: its coefficient
    /// `alpha w c_up / c_f` into `kf[a][l]` (times `(dt/h)^2` later) and `-(dt/h) alpha F^0`
    /// into the right-hand sides of its cells.
    #[inline(always)]
    fn pressure_face(&mut self, a: usize, l: usize, r: usize, dt: R, vac: R) {
        let (cl, cr) = (self.c[l], self.c[r]);
        let cf = (cl + cr) * R::HALF;
        let (ff, w) = self.implicit_face_force(a, l, r);
        let uf = self.implicit_face_velocity(a, l, r, dt, ff, vac);
        let ap = if self.walls.on {
            self.transport_aperture(a, l, r)
        } else {
            R::ONE
        };
        let k = if cf > vac {
            // the lagged upwind side (the mean at a face at rest)
            let cup = if uf > R::ZERO {
                cl
            } else if uf < R::ZERO {
                cr
            } else {
                cf
            };
            w * cup / cf
        } else {
            R::ZERO
        };
        let f = ap * upwind(cl, cr, uf);
        let lam = dt / self.grid.spacing()[a];
        self.kf[a][l] = ap * k;
        self.rhs[l] -= lam * f;
        self.rhs[r] += lam * f;
    }

    /// The face force of the implicit face velocity and its weight: the compact force of
    /// [`Self::face_force`]; with [`super::FlowConfig::free_surface_push`] unfaded (`w = 1`).
    /// Why unfaded: the push is the finite-volume form of `p = 0` on a free-surface face, and
    /// for the dual volume of such a face that is the full compact force
    /// `(p_L - p_R)/h + b c_f` with the empty side's `p ~ 0`: it vanishes when the surface
    /// cell holds the hydrostatic half-cell pressure `p = c |b| h / 2`, so the free surface
    /// is in exact balance and its pressure coupling is inside the solve. Faded, the push
    /// would act on the cells only, one step behind the mass flux, and the surface cells
    /// chatter at the long implicit steps (measured: 8e-2 m/s on a collapse deposit at rest).
    #[inline(always)]
    pub(super) fn implicit_face_force(&self, a: usize, l: usize, r: usize) -> (R, R) {
        let b = self.face_body(a, l);
        let (cl, cr) = (self.c[l], self.c[r]);
        if self.cfg.free_surface_push {
            let h = self.grid.spacing()[a];
            (
                (self.p[l] - self.p[r]) / h + b * (cl + cr) * R::HALF,
                R::ONE,
            )
        } else {
            self.face_force(a, b, cl, self.p[l], cr, self.p[r])
        }
    }

    /// End-of-step face velocity `(u_L + u_R)/2 + dt (F_f / c_f + s_f)` of the face `(l, r)`
    /// along `a` with its compact force `ff` (0 acceleration towards an empty face). `s_f`
    /// is the viscous share ([`super::FlowConfig::viscous_share`]): the smaller of the two
    /// cells' accelerations of the last step from the stress and the transport (all but
    /// pressure and gravity) when they agree in sign, else 0. Why: the stage that holds a
    /// bed against gravity (the viscous one) runs after the transport; without `s_f` every
    /// face of a friction-held bed moves with `dt` times the force the stress balances, and
    /// every face of a steady accelerating jet (the silo's orifice) with `dt` times the
    /// force the inertia balances. Why the smaller of two that agree: under a loose surface
    /// cell held by the stress, the dense cell below changes by ~0, and a mean would put the
    /// surface cell's hold on a balanced face (a bed in a box then creeps at 4e-2 m/s).
    #[inline(always)]
    pub(super) fn implicit_face_velocity(
        &self,
        a: usize,
        l: usize,
        r: usize,
        dt: R,
        ff: R,
        vac: R,
    ) -> R {
        let cf = (self.c[l] + self.c[r]) * R::HALF;
        let um = (self.u[a][l] + self.u[a][r]) * R::HALF;
        if cf > vac {
            let mut f = ff / cf;
            if self.holds() {
                if let Some(share) = minmod(self.hold[a][l], self.hold[a][r]) {
                    f += share;
                }
            }
            um + dt * f
        } else {
            um
        }
    }

    /// Velocity through an opening of the boundary face of cell `i` (side `high` of axis
    /// `a`), and the coefficient `open w` of its pressure coupling: in explicit mode the
    /// cell's velocity (and 0); in implicit mode the cell's end-of-step velocity from its
    /// half of the outlet face force, `u_i + dt (F_open / (2 c_i) + s_i)` (`s_i` the cell's
    /// share, [`super::FlowConfig::viscous_share`]) with the outlet ghost
    /// `(c_i, p_ghost)`, and `open w` if the face holds `p = 0` (ghost `-p_i`) and moves
    /// grains out (a Dirichlet `dp = 0` on the face).
    pub(super) fn outlet_velocity(
        &self,
        a: usize,
        i: usize,
        high: bool,
        side: &FlowSide<R, D>,
        dt: R,
    ) -> (R, R) {
        let u = self.u[a][i];
        let ci = self.c[i];
        let opening = side.kind == Boundary::Wall && !side.openings.is_empty();
        if self.cfg.pressure == super::PressureMode::Explicit || !opening || ci <= self.cfg.vacuum {
            return (u, R::ZERO);
        }
        let open = self.open_fraction(a, high, i);
        if open == R::ZERO {
            return (u, R::ZERO);
        }
        let (push, share, w) = self.outlet_push(a, i, high, side);
        let mut v = u + dt * push;
        if self.holds() {
            v += dt * share;
        }
        let out = if high { v > R::ZERO } else { v < R::ZERO };
        let k = if out && side.outlet == OutletPressure::Zero {
            open * w
        } else {
            R::ZERO
        };
        (v, k)
    }

    /// What the implicit step adds per unit step to the exit speed of cell `i` behind an open
    /// face, and the face's Dirichlet weight: `(F_open / (2 c_i), s_i, w)`. The push is the
    /// cell's own half of the outlet face force, as the momentum update gives it (the other
    /// half belongs to the ghost): the full force would double the outlet's push against the
    /// explicit mode, where the outflow leaves with the cell's velocity. `s_i` is the cell's
    /// share, as on an interior face (the ghost mirrors the cell; 0 unless
    /// [`Self::holds`]): without it the outflow leaves `dt` times the acceleration the stress
    /// and the transport balance faster than the cell moves (the implicit silo's rate grew
    /// with dt). One place for [`Self::outlet_velocity`] and the step's outlet bound.
    pub(super) fn outlet_push(
        &self,
        a: usize,
        i: usize,
        high: bool,
        side: &FlowSide<R, D>,
    ) -> (R, R, R) {
        let (f, w) = self.outlet_face_force(a, i, high, side);
        let share = if self.holds() {
            self.hold[a][i]
        } else {
            R::ZERO
        };
        (R::HALF * f / self.c[i], share, w)
    }
}

/// The smaller in size of `a` and `b` when both are nonzero with the same sign, else `None`
/// (the viscous share of [`Flow::implicit_face_velocity`]; `None` rather than 0 so that a
/// face without a share keeps its bits, signed zeros included).
#[inline(always)]
fn minmod<R: Real>(a: R, b: R) -> Option<R> {
    if a > R::ZERO && b > R::ZERO {
        Some(a.min(b))
    } else if a < R::ZERO && b < R::ZERO {
        Some(a.max(b))
    } else {
        None
    }
}
