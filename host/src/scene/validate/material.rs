//! `[numerics]` and `[material]`: Courant number in (0, 1) (model.md 5), s0 >= 0, remixing
//! diffusivity >= 0, 0 < phi_rcp <= 1 (model.md 2, 3), grain diameter in (0, 1] m.

use super::{finite, Problems};
use crate::error::Error;
use crate::scene::{MaterialSpec, NumericsSpec};

/// Checks `numerics.courant`.
pub(super) fn courant(p: &mut Problems, l: &str, n: &NumericsSpec) -> Option<f64> {
    let courant = p.ok(finite(l, "numerics.courant", n.courant))?;
    if !(courant > 0.0 && courant < 1.0) {
        p.push(Error::range(
            l,
            "numerics.courant",
            courant,
            "0 < courant < 1",
        ));
        return None;
    }
    Some(courant)
}

/// Checks `material.grain_diameter` (optional): a length in (0, 1] m (a boulder of a
/// metre is no grain of a granular flow; the bound keeps the warnings' numbers finite).
pub(super) fn grain_diameter(p: &mut Problems, l: &str, m: &MaterialSpec) -> Option<f64> {
    let d = m.grain_diameter?;
    if !(d > 0.0 && d <= 1.0) {
        p.push(Error::range(
            l,
            "material.grain_diameter",
            d,
            "a grain diameter 0 < d <= 1 [m]",
        ));
        return None;
    }
    Some(d)
}

/// Validated segregation material: `(s0, diffusion, phi_rcp)`.
pub(super) fn check(p: &mut Problems, l: &str, m: &MaterialSpec) -> Option<(f64, f64, f64)> {
    let s0 = p.ok(finite(l, "material.s0", m.s0)).and_then(|s0| {
        if s0 < 0.0 {
            p.push(Error::range(l, "material.s0", s0, "s0 >= 0"));
            None
        } else {
            Some(s0)
        }
    });
    let diffusion = p
        .ok(finite(l, "material.diffusion", m.diffusion))
        .and_then(|d| {
            if d < 0.0 {
                p.push(Error::range(l, "material.diffusion", d, "diffusion >= 0"));
                None
            } else {
                Some(d)
            }
        });
    let phi_rcp = p
        .ok(finite(l, "material.phi_rcp", m.phi_rcp))
        .and_then(|r| {
            if !(r > 0.0 && r <= 1.0) {
                p.push(Error::range(l, "material.phi_rcp", r, "0 < phi_rcp <= 1"));
                None
            } else {
                Some(r)
            }
        });
    Some((s0?, diffusion?, phi_rcp?))
}
