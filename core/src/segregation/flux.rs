//! Numerical face fluxes of the segregation flux (model.md section 5), as pure functions of the
//! states on the two sides of one face. They know nothing of grids.
//!
//! Conventions: the tracked phase fraction is `q` (phi for the small phase, psi = c - phi for
//! the large one). On each side the physical normal flux is `f(q) = -k q (c - q)` with
//! `k = a / c`, `a = S . n` (the segregation velocity along the face normal, sign already chosen
//! for the tracked phase). `k >= 0` makes `f` convex with its minimum at `c/2`; `k <= 0` concave.

use crate::real::Real;
use serde::{Deserialize, Serialize};

/// Which numerical segregation flux the step uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Scheme {
    /// Modified Godunov flux: each side keeps its own c and T. Keeps 0 <= phi <= c.
    #[default]
    Modified,
    /// Classical Godunov flux of one flux function with face-averaged c and T (comparison only).
    Godunov,
    /// Upwind (Murman-Roe) flux with face-averaged c and T (comparison only).
    Upwind,
}

impl Scheme {
    /// All schemes, in the order they are documented.
    pub const ALL: [Scheme; 3] = [Scheme::Modified, Scheme::Godunov, Scheme::Upwind];
    /// Lower-case name, as in scene files and the CLI.
    pub fn name(self) -> &'static str {
        match self {
            Scheme::Modified => "modified",
            Scheme::Godunov => "godunov",
            Scheme::Upwind => "upwind",
        }
    }
}

/// The physical segregation flux of one side, `f(q) = -k q (c - q)`.
#[inline(always)]
pub fn physical<R: Real>(q: R, c: R, k: R) -> R {
    -(k * q * (c - q))
}

/// Modified Godunov flux (model.md 5) between side L `(ql, cl, kl)` and side R `(qr, cr, kr)`.
///
/// Convex faces (both k >= 0): `max{ f_L(max{q_L, c_L/2}), f_R(min{q_R, c_R/2}) }`;
/// concave faces (both k <= 0): `min{ f_L(min{q_L, c_L/2}), f_R(max{q_R, c_R/2}) }`;
/// faces where the sides drift apart or together (signs differ): 0.
/// With equal coefficients on both sides it is the classical Godunov flux.
#[inline(always)]
pub fn modified<R: Real>(ql: R, cl: R, kl: R, qr: R, cr: R, kr: R) -> R {
    let hl = cl * R::HALF;
    let hr = cr * R::HALF;
    if kl >= R::ZERO && kr >= R::ZERO {
        let a = physical(ql.max(hl), cl, kl);
        let b = physical(qr.min(hr), cr, kr);
        a.max(b)
    } else if kl <= R::ZERO && kr <= R::ZERO {
        let a = physical(ql.min(hl), cl, kl);
        let b = physical(qr.max(hr), cr, kr);
        a.min(b)
    } else {
        R::ZERO
    }
}

/// Classical Godunov flux of the single flux function `f(q) = -k q (c - q)` (face-averaged
/// coefficients), in closed form for the quadratic.
#[inline(always)]
pub fn godunov<R: Real>(ql: R, qr: R, c: R, k: R) -> R {
    modified(ql, c, k, qr, c, k)
}

/// Upwind flux of `f(q) = -k q (c - q)`: upwind in the Roe speed, which for the quadratic is
/// exactly `f'((q_L + q_R)/2) = -k (c - q_L - q_R)`.
#[inline(always)]
pub fn upwind<R: Real>(ql: R, qr: R, c: R, k: R) -> R {
    // Written with (q_L + q_R) so that mirroring L and R gives the same bits.
    let speed = -(k * (c - (ql + qr)));
    if speed >= R::ZERO {
        physical(ql, c, k)
    } else {
        physical(qr, c, k)
    }
}

/// Reference Godunov flux for any flux function, from its definition: the minimum of `f` over
/// `[q_L, q_R]` if `q_L <= q_R`, else the maximum over `[q_R, q_L]`. The extremum is searched
/// at the end points and at `interior_extremum` if it lies inside. Used to test the fast forms.
pub fn godunov_reference<R: Real>(f: impl Fn(R) -> R, ql: R, qr: R, interior_extremum: R) -> R {
    let (lo, hi) = if ql <= qr { (ql, qr) } else { (qr, ql) };
    let mut best = f(ql);
    let mut consider = |v: R| {
        if ql <= qr {
            best = best.min(v)
        } else {
            best = best.max(v)
        }
    };
    consider(f(qr));
    if interior_extremum > lo && interior_extremum < hi {
        consider(f(interior_extremum));
    }
    best
}

/// Transport flux `q u.n` upwind in the face velocity `un` (the average of the two cells).
#[inline(always)]
pub fn transport<R: Real>(ql: R, qr: R, un: R) -> R {
    un.max(R::ZERO) * ql + un.min(R::ZERO) * qr
}
