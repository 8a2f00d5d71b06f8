//! A cold bed at rest (model.md 5.8): the packing of a run of cells along the body force
//! that is in the step's own discrete balance, so a scene can start from a settled fill
//! instead of a uniform one (which is over-compressed at its top and expands on release).
//!
//! The balance is the compact one of the flow step (model.md 5.3): on every face inside the
//! run `(p_lower - p_upper) / h = b (c_lower + c_upper) / 2` with `b = |g|`, and on the free
//! surface above the run's top cell the push of its own pressure `p / h` against half its
//! weight, `p_top = b h c_top / 2`. With `T = 0` the pressure is the yield pressure alone,
//! whose inverse is explicit ([`crate::closure::yield_packing`]), so each cell's pressure
//! solves a quadratic: no iteration, the same bits on every machine.

use crate::closure::yield_packing;
use crate::real::Real;

/// Pressure `p >= 0` with `p = a + k c(p)`, `c` the yield packing of `(c_rcp, c_rlp, t0)`,
/// `a >= 0`, `k > 0`: the positive root of
/// `p^2 / c_rcp + p (t0 - a / c_rcp - k) - (a t0 + k t0 c_rlp) = 0` (its constant term is
/// negative, so there is exactly one), in the form that does not cancel.
fn balanced_pressure<R: Real>(a: R, k: R, c_rcp: R, c_rlp: R, t0: R) -> R {
    let qa = R::ONE / c_rcp;
    let qb = t0 - a / c_rcp - k;
    let qc = a * t0 + k * t0 * c_rlp; // minus the constant term, >= 0
    let root = (qb * qb + R::from_f64(4.0) * qa * qc).sqrt();
    if qb >= R::ZERO {
        R::TWO * qc / (qb + root)
    } else {
        (root - qb) / (R::TWO * qa)
    }
}

/// Replaces `c` (one run of bed cells along the body force, `c[0]` the top cell under a free
/// surface or a wall, `c[n - 1]` the lowest) by the cold rest state: `b_h = |g| h` (body
/// acceleration times the cell size along it), `t0` the material's yield temperature scale,
/// `c_rcp`, `c_rlp` each cell's packing limits. The top cell holds `p = b_h c / 2`, each cell
/// below `p = p_above + b_h (c_above + c) / 2`; `c` is `c_rlp` at zero load and stays below
/// `c_rcp` (the caller checks it against the flow's `c_max`). The run's grain volume is what
/// the balance gives, not what `c` held before.
///
/// # Panics
/// Never: extra entries of `c_rcp`/`c_rlp` are ignored, and cells of `c` beyond them are left
/// as they are.
pub fn settle_run<R: Real>(b_h: R, t0: R, c_rcp: &[R], c_rlp: &[R], c: &mut [R]) {
    let k = R::HALF * b_h;
    // the known part of the cell's pressure: `p_above + k c_above` (0 under the surface)
    let mut a = R::ZERO;
    for ((ci, &rcp), &rlp) in c.iter_mut().zip(c_rcp).zip(c_rlp) {
        let p = balanced_pressure(a, k, rcp, rlp, t0);
        *ci = yield_packing(p, rcp, rlp, t0);
        a = p + k * *ci;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::closure::yield_pressure;

    /// The settled run is in the compact balance to round-off, packs monotonically downwards
    /// from just above `c_rlp`, and matches the continuous profile
    /// `b (z_s - z) = (p - p_s)/c_rcp + T0 (1 - c_rlp/c_rcp) ln((p + T0 c_rlp)/(p_s + T0 c_rlp))`
    /// at the floor to O(h).
    #[test]
    fn settled_run_is_in_discrete_balance() {
        let (t0, rcp, rlp, g) = (1.5, 0.64, 0.4, 9.81);
        for n in [80usize, 160, 320] {
            let h = 0.4 / n as f64;
            let (rcps, rlps) = ([rcp; 320], [rlp; 320]);
            let mut c = [0.6f64; 320];
            settle_run(g * h, t0, &rcps[..n], &rlps[..n], &mut c[..n]);
            let p = |i: usize| yield_pressure(c[i], rcp, rlp, t0);
            assert!((p(0) - g * h * c[0] / 2.0).abs() <= 1e-14 * p(0).max(1.0));
            for i in 1..n {
                let f = (p(i) - p(i - 1)) / h - g * (c[i] + c[i - 1]) / 2.0;
                assert!(f.abs() < 1e-11, "face {i}: {f}");
                assert!(c[i] > c[i - 1]);
            }
            assert!(
                c[0] > rlp && c[0] < rlp + 0.01 && c[n - 1] < rcp,
                "{} {}",
                c[0],
                c[n - 1]
            );
            // continuous: depth 0.4 m under p_s = 0
            let pf = p(n - 1) + g * h * c[n - 1] / 2.0; // pressure at the floor face
            let depth = pf / rcp + t0 * (1.0 - rlp / rcp) * libm::log((pf + t0 * rlp) / (t0 * rlp));
            assert!(
                (depth / g - 0.4).abs() < 2e-4 * (80.0 / n as f64),
                "n {n}: {}",
                depth / g
            );
        }
    }

    /// A load too small to matter and one that is huge: the root stays finite and the packing
    /// in `[c_rlp, c_rcp)`.
    #[test]
    fn balanced_pressure_extremes() {
        for (a, k) in [(0.0, 1e-30), (0.0, 1e-3), (1e6, 1e-3), (1e12, 10.0)] {
            let p: f64 = balanced_pressure(a, k, 0.64, 0.4, 1.5);
            let c = yield_packing(p, 0.64, 0.4, 1.5);
            assert!(p.is_finite() && p >= a, "{a} {k}: {p}");
            assert!((0.4..0.64).contains(&c), "{a} {k}: {c}");
            let f32p: f32 = balanced_pressure(a as f32, k as f32, 0.64, 0.4, 1.5);
            assert!(f32p.is_finite() && f32p >= a as f32);
        }
    }
}
