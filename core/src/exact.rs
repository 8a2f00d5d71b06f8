//! Closed-form solutions used to verify the solver (tests, `sieve converge`).

use crate::real::Real;

/// Segregation column with constant c and T (model.md 7.1a) of height `height`, walls at both
/// ends, initial relative fraction `m` of small grains everywhere, segregation velocity `s > 0`
/// pointing up.
///
/// With `G(x) = -s x (1 - x)` the phihat flux, two shocks leave the walls: the lower one (pure
/// small below, `m` above) rises at `s m`, the upper one (`m` below, pure large above) falls at
/// `s (1 - m)`; they meet at `t* = height / s` at `z = m height`, where a stationary shock stays.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ColumnA<R> {
    /// segregation velocity |S| = S0 sqrt(T) |g|
    pub s: R,
    /// initial phihat
    pub m: R,
    /// column height
    pub height: R,
}

impl<R: Real> ColumnA<R> {
    /// Time at which the two shocks meet (full segregation).
    pub fn meeting_time(&self) -> R {
        self.height / self.s
    }
    /// Height of the lower shock (top of the pure-small layer) at time `t`.
    pub fn lower_shock(&self, t: R) -> R {
        (self.s * self.m * t).min(self.m * self.height)
    }
    /// Height of the upper shock (bottom of the pure-large layer) at time `t`.
    pub fn upper_shock(&self, t: R) -> R {
        (self.height - self.s * (R::ONE - self.m) * t).max(self.m * self.height)
    }
    /// phihat at height `z` and time `t` (the value on a shock is its upper state).
    pub fn phihat(&self, z: R, t: R) -> R {
        if z < self.lower_shock(t) {
            R::ONE
        } else if z < self.upper_shock(t) {
            self.m
        } else {
            R::ZERO
        }
    }
    /// Average of phihat over the cell `[z0, z1]` at time `t` (for cell-average errors).
    pub fn phihat_cell_average(&self, z0: R, z1: R, t: R) -> R {
        let lo = self.lower_shock(t);
        let hi = self.upper_shock(t);
        let overlap = |a: R, b: R| (b.min(z1) - a.max(z0)).max(R::ZERO);
        (overlap(R::ZERO.min(z0), lo) + self.m * overlap(lo, hi)) / (z1 - z0)
    }
    /// Mixing index `Psi(t) = max(0, 1 - s t / height)`: only the mixed middle layer carries
    /// entropy, and it shrinks at `s m + s (1 - m) = s`.
    pub fn psi(&self, t: R) -> R {
        (R::ONE - self.s * t / self.height).max(R::ZERO)
    }
    /// Time at which Psi falls below `threshold`.
    pub fn segregation_time(&self, threshold: R) -> R {
        (R::ONE - threshold) * self.height / self.s
    }
}

/// Steady Gray–Thornton segregation in a layer of depth `depth` fed at x = 0 with a mixed inflow
/// of relative fraction `m` (model.md 7.2), segregation velocity `s` (upward for the large
/// phase), depth-averaged downstream speed `mean_speed`. Method of characteristics for
/// `u(z) dphihat/dx + d/dz(-s phihat (1 - phihat)) = 0` with no-flux top and bottom.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GrayThornton<R> {
    /// segregation velocity |S|
    pub s: R,
    /// inflow phihat
    pub m: R,
    /// layer depth h
    pub depth: R,
    /// depth-averaged downstream speed
    pub mean_speed: R,
    /// true: simple shear `u = 2 mean z / h`; false: plug flow `u = mean`
    pub shear: bool,
}

impl<R: Real> GrayThornton<R> {
    /// Downstream distance at which the two shocks meet: `L = mean h / s` for both plug and
    /// simple shear flow (the lower shock rises with `dz/dx = s m / u`, the upper one falls
    /// with `dz/dx = -s (1 - m) / u`).
    pub fn full_segregation_distance(&self) -> R {
        self.mean_speed * self.depth / self.s
    }
    /// Height of the separating shock downstream of full segregation, from the flux of small
    /// grains: `m h` in plug flow, `h sqrt(m)` in simple shear.
    pub fn separating_height(&self) -> R {
        if self.shear {
            self.depth * self.m.sqrt()
        } else {
            self.depth * self.m
        }
    }
    /// Height of the lower shock (top of the pure-small layer) at distance `x`.
    pub fn lower_shock(&self, x: R) -> R {
        let x = x.min(self.full_segregation_distance());
        if self.shear {
            // z dz = (s m h / (2 mean)) dx
            (self.s * self.m * self.depth * x / self.mean_speed).sqrt()
        } else {
            self.s * self.m * x / self.mean_speed
        }
    }
    /// Height of the upper shock (bottom of the pure-large layer) at distance `x`.
    pub fn upper_shock(&self, x: R) -> R {
        let x = x.min(self.full_segregation_distance());
        let fall = self.s * (R::ONE - self.m) * x / self.mean_speed;
        if self.shear {
            (self.depth * self.depth - fall * self.depth)
                .max(R::ZERO)
                .sqrt()
        } else {
            self.depth - fall
        }
    }
}
