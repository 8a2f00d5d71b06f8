//! Closures of the granular flow model (model.md section 2) and packing limits of binary
//! mixtures (model.md section 4), as small pure functions.
//!
//! Everything here is per cell and per value: no grids, no state. The flow solver
//! ([`crate::flow`]) and the tests call the same functions, so a closure is tested once.
//!
//! Regularisation (documented, deliberate): the yield parts of eta, lambda and eps carry
//! `p_y / p_k ~ 1 / T`, so `eta = eta0 sqrt(T) c g + eta0 p_y / sqrt(T)` diverges as `T -> 0`.
//! [`transport`] evaluates the *transport coefficients* with `T_eff = max(T, T_min)`; the
//! pressure always uses the true `T`. Above `T_min` the values are exactly those of model.md 2.

use crate::real::Real;

/// Material constants of model.md section 2 (and S0 of section 3).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Material<R> {
    /// eta0 (m): viscosity prefactor.
    pub eta0: R,
    /// lambda0 (m): conductivity prefactor.
    pub lambda0: R,
    /// eps0 (1/m): dissipation prefactor.
    pub eps0: R,
    /// T0 (m^2/s^2): yield-pressure scale.
    pub t0: R,
    /// Random close packing of the mono-disperse material.
    pub phi_rcp: R,
    /// Random loose packing of the mono-disperse material.
    pub phi_rlp: R,
    /// Heating prefactor `a` (3/2 in the source model).
    pub heating: R,
    /// Segregation rate S0 (s^2/m) (model.md 3).
    pub s0: R,
}

impl<R: Real> Material<R> {
    /// Glass beads of the shear cell (model.md 7.4): eta0 = 1.3e-4 m, lambda0 = 3.4e-4 m,
    /// eps0 = 1477.15 1/m, T0 = 1.8 m^2/s^2, phi_rlp = 0.5757, phi_rcp = 0.632, a = 3/2, S0 = 1.
    pub fn glass_beads() -> Self {
        Self {
            eta0: R::from_f64(1.3e-4),
            lambda0: R::from_f64(3.4e-4),
            eps0: R::from_f64(1477.15),
            t0: R::from_f64(1.8),
            phi_rcp: R::from_f64(0.632),
            phi_rlp: R::from_f64(0.5757),
            heating: R::from_f64(1.5),
            s0: R::ONE,
        }
    }

    /// Checks that every constant is finite, the prefactors positive and
    /// `0 < phi_rlp < phi_rcp < 1`; returns the name of the first bad one.
    pub fn validate(&self) -> Result<(), &'static str> {
        let pos = |x: R| x.is_finite() && x > R::ZERO;
        for (name, v) in [
            ("eta0", self.eta0),
            ("lambda0", self.lambda0),
            ("eps0", self.eps0),
            ("heating", self.heating),
        ] {
            if !pos(v) {
                return Err(name);
            }
        }
        if !(self.t0.is_finite() && self.t0 >= R::ZERO) {
            return Err("t0");
        }
        if !(self.s0.is_finite() && self.s0 >= R::ZERO) {
            return Err("s0");
        }
        if !(self.phi_rlp > R::ZERO && self.phi_rlp < self.phi_rcp && self.phi_rcp < R::ONE) {
            return Err("packing");
        }
        Ok(())
    }

    /// `tan` of the internal friction angle of steady uniform shear as written in model.md 2:
    /// the shear-to-normal stress ratio `sqrt(eps0 eta0 / a)`.
    pub fn friction_coefficient(&self) -> R {
        (self.eps0 * self.eta0 / self.heating).sqrt()
    }

    /// `sqrt(T) / gammadot` of steady uniform shear, `sqrt(a eta0 / eps0)` (model.md 2).
    pub fn temperature_shear_ratio(&self) -> R {
        (self.heating * self.eta0 / self.eps0).sqrt()
    }
}

/// Compressibility factor `g(c) = 1 / (1 - c / c_rcp)` (model.md 2). Diverges at `c_rcp`; the
/// caller keeps `c < c_rcp` (the flow solver limits c below `(1 - margin) c_rcp`).
#[inline]
pub fn compressibility<R: Real>(c: R, c_rcp: R) -> R {
    R::ONE / (R::ONE - c / c_rcp)
}

/// Kinetic pressure `p_k = c T g(c)`.
#[inline]
pub fn kinetic_pressure<R: Real>(c: R, t: R, c_rcp: R) -> R {
    c * t * compressibility(c, c_rcp)
}

/// Yield pressure `p_y = H(c - c_rlp) T0 (c - c_rlp) g(c)` (0 at or below `c_rlp`).
#[inline]
pub fn yield_pressure<R: Real>(c: R, c_rcp: R, c_rlp: R, t0: R) -> R {
    if c > c_rlp {
        t0 * (c - c_rlp) * compressibility(c, c_rcp)
    } else {
        R::ZERO
    }
}

/// The packing `c >= c_rlp` whose yield pressure is `p >= 0`: the inverse of
/// [`yield_pressure`] above `c_rlp`, `c = (p + T0 c_rlp) / (T0 + p / c_rcp)` (from
/// `p (1 - c / c_rcp) = T0 (c - c_rlp)`). It is `c_rlp` at `p = 0` and tends to `c_rcp` as
/// `p` grows, so a cold bed under any finite load packs below `c_rcp`.
#[inline]
pub fn yield_packing<R: Real>(p: R, c_rcp: R, c_rlp: R, t0: R) -> R {
    (p + t0 * c_rlp) / (t0 + p / c_rcp)
}

/// Total pressure `p = p_k + p_y`.
#[inline]
pub fn pressure<R: Real>(m: &Material<R>, c: R, t: R, c_rcp: R, c_rlp: R) -> R {
    kinetic_pressure(c, t, c_rcp) + yield_pressure(c, c_rcp, c_rlp, m.t0)
}

/// Squared wave speed `dp/dc` at fixed T: `T (g + c g^2 / c_rcp)` plus, above `c_rlp`,
/// `T0 (g + (c - c_rlp) g^2 / c_rcp)` (using `dg/dc = g^2 / c_rcp`). This is the speed the
/// explicit pressure step must resolve (acoustic CFL, see [`crate::flow`]).
#[inline]
pub fn sound_speed_squared<R: Real>(m: &Material<R>, c: R, t: R, c_rcp: R, c_rlp: R) -> R {
    let g = compressibility(c, c_rcp);
    let dg = g * g / c_rcp;
    let mut a2 = t * (g + c * dg);
    if c > c_rlp {
        a2 += m.t0 * (g + (c - c_rlp) * dg);
    }
    a2
}

/// Transport coefficients of one cell (model.md 2), evaluated at `T_eff = max(T, T_min)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transport<R> {
    /// Viscosity `eta = eta_k (1 + p_y/p_k)` (m^2/s per unit density).
    pub eta: R,
    /// Conductivity `lambda = lam_k (1 + p_y/p_k)`.
    pub lambda: R,
    /// Dissipation rate `eps = eps_k (1 + p_y/p_k)` (1/s); the sink is `eps c T`.
    pub eps: R,
}

/// `eta`, `lambda` and `eps` of model.md 2 at `T_eff = max(T, t_min)`.
///
/// Written as `eta = eta0 c g s + eta0 p_y / s` with `s = sqrt(T_eff)` (the same expression,
/// since `eta_k p_y / p_k = eta0 p_y / s`), which has no `0/0` where `c -> 0` or `T -> 0`.
/// Likewise `eps = eps0 g s + eps0 p_y / (c s)` (`p_y > 0` implies `c > c_rlp > 0`).
/// `t_min > 0` is required for finite values at `T = 0`.
#[inline]
pub fn transport<R: Real>(
    m: &Material<R>,
    c: R,
    t: R,
    c_rcp: R,
    c_rlp: R,
    t_min: R,
) -> Transport<R> {
    let s = t.max(t_min).sqrt();
    let g = compressibility(c, c_rcp);
    let py = yield_pressure(c, c_rcp, c_rlp, m.t0);
    let cgs = c * g * s;
    let yield_over_s = py / s;
    let eps = if py > R::ZERO {
        m.eps0 * (g * s + yield_over_s / c)
    } else {
        m.eps0 * g * s
    };
    Transport {
        eta: m.eta0 * (cgs + yield_over_s),
        lambda: m.lambda0 * (cgs + yield_over_s),
        eps,
    }
}

/// Which packing limits the flow uses (model.md 4): the constants, or back-coupled to the
/// local relative small-grain fraction `phihat`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Packing {
    /// `c_rcp = phi_rcp`, `c_rlp = phi_rlp` everywhere (one-way coupling).
    #[default]
    Constant,
    /// Analytic upper bound for radius ratio R -> 0.
    BoundR0,
    /// Degree-5 fit for R = 1/2.
    FitHalf,
}

/// `min( phi / (1 - x), phi / (x + (1 - x) phi) )`: the R -> 0 bound of model.md 4 for the
/// mono-disperse packing `phi` at relative small fraction `x = phihat` (x clamped to [0, 1]).
#[inline]
pub fn packing_bound_r0<R: Real>(x: R, phi: R) -> R {
    let x = x.max(R::ZERO).min(R::ONE);
    let b = phi / (x + (R::ONE - x) * phi);
    if x < R::ONE {
        (phi / (R::ONE - x)).min(b)
    } else {
        b
    }
}

/// The R = 1/2 fit of model.md 4:
/// `p(x, z) = -0.4903 x^5 + 1.2388 x^4 - 0.9450 x^3 + 0.0434 x^2 + 0.1531 x + z`
/// (Horner form; x clamped to [0, 1]).
#[inline]
pub fn packing_fit_half<R: Real>(x: R, phi: R) -> R {
    let x = x.max(R::ZERO).min(R::ONE);
    let k = |v: f64| R::from_f64(v);
    ((((k(-0.4903) * x + k(1.2388)) * x + k(-0.9450)) * x + k(0.0434)) * x + k(0.1531)) * x + phi
}

impl Packing {
    /// `(c_rcp, c_rlp)` at relative small fraction `phihat` for the material.
    #[inline]
    pub fn limits<R: Real>(self, m: &Material<R>, phihat: R) -> (R, R) {
        match self {
            Packing::Constant => (m.phi_rcp, m.phi_rlp),
            Packing::BoundR0 => (
                packing_bound_r0(phihat, m.phi_rcp),
                packing_bound_r0(phihat, m.phi_rlp),
            ),
            Packing::FitHalf => (
                packing_fit_half(phihat, m.phi_rcp),
                packing_fit_half(phihat, m.phi_rlp),
            ),
        }
    }
}
