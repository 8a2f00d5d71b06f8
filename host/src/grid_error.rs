//! The grid error of one scalar readout (a discharge rate, Psi at `t_end`) from its values on
//! three grids: the observed order, the Richardson-extrapolated value and the grid
//! convergence index of the finest grid, by the procedure of Celik et al. (2008), "Procedure
//! for estimation and reporting of uncertainty due to discretization in CFD applications",
//! J. Fluids Eng. 130, 078001 (docs/outputs.md, "Readouts on a sequence of grids").
//!
//! Why a readout and not only a field: a process engineer's number is the discharge rate or
//! the fines fraction of the outflow, and that can converge (or not) quite differently from
//! the phihat field it is computed from.

use serde::Serialize;

/// Safety factor of the grid convergence index for a three-grid study (Roache; Celik et al.).
pub const GCI_SAFETY: f64 = 1.25;

/// Differences this small relative to the values are round-off: the readout no longer
/// changes with the grid.
const ROUND_OFF: f64 = 1e-12;

/// How the three finest values behave under refinement.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Behaviour {
    /// The differences keep their sign and shrink: an order and an extrapolation exist.
    Converging,
    /// The differences keep their sign but do not shrink: the grids are not in the
    /// asymptotic range (or the readout diverges); no extrapolation.
    NotShrinking,
    /// The differences change sign: no order; the spread of the three values is the
    /// estimate of the error.
    Oscillating,
    /// The three values agree to round-off.
    Converged,
    /// Fewer than three grids gave the value.
    TooFewGrids,
}

impl Behaviour {
    /// The word in tables and CSV files.
    pub fn name(self) -> &'static str {
        match self {
            Self::Converging => "converging",
            Self::NotShrinking => "not_shrinking",
            Self::Oscillating => "oscillating",
            Self::Converged => "converged",
            Self::TooFewGrids => "too_few_grids",
        }
    }
}

/// What three grids say about a readout.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Estimate {
    /// How the values behave.
    pub behaviour: Behaviour,
    /// Observed order of convergence `p` (converging or not shrinking; negative when the
    /// differences grow).
    pub order: Option<f64>,
    /// Richardson-extrapolated value `f1 + (f1 - f2) / (r21^p - 1)` (converging only).
    pub extrapolated: Option<f64>,
    /// Estimated error of the finest grid's value: `|f1 - extrapolated|` when converging,
    /// the spread `max - min` of the three values when oscillating, 0 when converged.
    pub error_finest: Option<f64>,
    /// Grid convergence index of the finest grid, `1.25 |(f1 - f2) / f1| / (r21^p - 1)`: a
    /// relative error band (converging only).
    pub gci_finest: Option<f64>,
    /// How the next-coarser three grids behave (four grids or more): the check that the
    /// finest three are in the asymptotic range.
    pub coarser_behaviour: Option<Behaviour>,
    /// The observed order of the next-coarser three grids.
    pub coarser_order: Option<f64>,
    /// Whether the grids are shown to be in the asymptotic range, where the extrapolation and
    /// the GCI hold: the finest three converge (or agree to round-off) and the next-coarser
    /// three do the same at an order within [`ORDER_AGREEMENT`] of theirs. `None` with fewer
    /// than four grids, or when the finest three do not converge (no order to check).
    pub asymptotic: Option<bool>,
}

/// Two observed orders agree when they differ by at most this fraction of the larger one. A
/// power law gives the same order from every three grids; a readout whose order drifts by more
/// than a quarter between two overlapping triples is not yet a power law of h.
pub const ORDER_AGREEMENT: f64 = 0.25;

/// The estimate from `(cells along an axis, value)` pairs of any number of grids, coarse to
/// fine or in any order: the three finest are used, and with four or more the next-coarser
/// three check that they are in the asymptotic range. Grids are compared by their cell counts
/// along one axis, so `h` is proportional to `1 / cells`; the refinement ratios may differ.
pub fn estimate(grids: &[(usize, f64)]) -> Estimate {
    let mut g: Vec<(usize, f64)> = grids
        .iter()
        .copied()
        .filter(|&(n, f)| n > 0 && f.is_finite())
        .collect();
    g.sort_by_key(|&(n, _)| n);
    g.dedup_by_key(|&mut (n, _)| n);
    let k = g.len();
    if k < 3 {
        return three(&g);
    }
    let finest = three(&g[k - 3..]);
    if k == 3 {
        return finest;
    }
    let coarser = three(&g[k - 4..k - 1]);
    let asymptotic = match (finest.behaviour, finest.order) {
        (Behaviour::Converged, _) => Some(coarser.behaviour == Behaviour::Converged),
        (Behaviour::Converging, Some(p)) => Some(
            coarser.behaviour == Behaviour::Converging
                && coarser
                    .order
                    .is_some_and(|q| (p - q).abs() <= ORDER_AGREEMENT * p.max(q)),
        ),
        _ => None,
    };
    Estimate {
        coarser_behaviour: Some(coarser.behaviour),
        coarser_order: coarser.order,
        asymptotic,
        ..finest
    }
}

/// What exactly three grids (sorted, distinct) say; fewer say `TooFewGrids`.
fn three(g: &[(usize, f64)]) -> Estimate {
    let none = Estimate {
        behaviour: Behaviour::TooFewGrids,
        order: None,
        extrapolated: None,
        error_finest: None,
        gci_finest: None,
        coarser_behaviour: None,
        coarser_order: None,
        asymptotic: None,
    };
    let [(n3, f3), (n2, f2), (n1, f1)] = match g {
        [a, b, c] => [*a, *b, *c],
        _ => return none,
    };
    // 1 = finest, 3 = coarsest; h_k ~ 1 / n_k
    let (r21, r32) = (n1 as f64 / n2 as f64, n2 as f64 / n3 as f64);
    let (e21, e32) = (f2 - f1, f3 - f2);
    let scale = f1.abs().max(f2.abs()).max(f3.abs()).max(f64::MIN_POSITIVE);
    if e21.abs() <= ROUND_OFF * scale && e32.abs() <= ROUND_OFF * scale {
        return Estimate {
            behaviour: Behaviour::Converged,
            error_finest: Some(0.0),
            ..none
        };
    }
    let spread = f1.max(f2).max(f3) - f1.min(f2).min(f3);
    if e21 * e32 <= 0.0 {
        // a sign change, or one difference exactly zero and the other not
        return Estimate {
            behaviour: Behaviour::Oscillating,
            error_finest: Some(spread),
            ..none
        };
    }
    let Some(p) = observed_order(r21, r32, e32 / e21) else {
        return Estimate {
            behaviour: Behaviour::NotShrinking,
            error_finest: Some(spread),
            ..none
        };
    };
    if p <= 0.0 {
        return Estimate {
            behaviour: Behaviour::NotShrinking,
            order: Some(p),
            error_finest: Some(spread),
            ..none
        };
    }
    let rp = r21.powf(p);
    let extrapolated = (rp * f1 - f2) / (rp - 1.0);
    Estimate {
        behaviour: Behaviour::Converging,
        order: Some(p),
        extrapolated: Some(extrapolated),
        error_finest: Some((f1 - extrapolated).abs()),
        gci_finest: (f1 != 0.0).then(|| GCI_SAFETY * ((f1 - f2) / f1).abs() / (rp - 1.0)),
        ..none
    }
}

/// The observed order `p` for monotone differences with `ratio = e32 / e21` (> 0). With
/// `f = f0 + C h^p` on `h1`, `h2 = r21 h1`, `h3 = r32 h2` the ratio is
/// `g(p) = r21^p (r32^p - 1) / (r21^p - 1)` (Celik et al., eq. 3, without their absolute
/// value, so that a negative order, differences growing, is found too): with equal ratios
/// `p = ln(ratio) / ln(r)`, otherwise `g(p) = ratio` by bisection on `[-10, 20]` (`g` rises
/// with `p`). `None` if the ratio lies outside that range.
fn observed_order(r21: f64, r32: f64, ratio: f64) -> Option<f64> {
    if r21 == r32 {
        let p = ratio.ln() / r21.ln();
        return p.is_finite().then_some(p);
    }
    let g = |p: f64| {
        if p.abs() < 1e-9 {
            r32.ln() / r21.ln() // the limit at p = 0
        } else {
            r21.powf(p) * (r32.powf(p) - 1.0) / (r21.powf(p) - 1.0)
        }
    };
    let (mut lo, mut hi) = (-10.0f64, 20.0f64);
    if !(g(lo) <= ratio && ratio <= g(hi)) {
        return None;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if g(mid) < ratio {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo <= 1e-14 {
            break;
        }
    }
    Some(0.5 * (lo + hi))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64, tol: f64) {
        assert!((a - b).abs() <= tol, "{a} against {b}");
    }

    /// f(h) = f0 + C h^p on three grids gives back p and f0 exactly (to round-off), with
    /// equal and with unequal refinement ratios, from either side.
    #[test]
    fn a_power_law_gives_back_its_order_and_limit() {
        for (p, c) in [(1.0, 0.3), (1.5, -2.0), (2.0, 5.0), (0.82, 1e-2)] {
            for cells in [[25usize, 50, 100], [30, 45, 90], [40, 60, 72]] {
                let f = |n: usize| 1.5 + c * (1.0 / n as f64).powf(p);
                let e = estimate(&cells.map(|n| (n, f(n))));
                assert_eq!(e.behaviour, Behaviour::Converging, "{cells:?} p {p}");
                close(e.order.unwrap(), p, 1e-8);
                close(e.extrapolated.unwrap(), 1.5, 1e-10);
                close(e.error_finest.unwrap(), (f(cells[2]) - 1.5).abs(), 1e-10);
                let gci = e.gci_finest.unwrap();
                let f1 = f(cells[2]);
                close(gci, GCI_SAFETY * (f1 - 1.5).abs() / f1.abs(), 1e-9);
            }
        }
    }

    /// Only the three finest grids count, in any order; non-finite values and repeated
    /// grids are left out.
    #[test]
    fn the_three_finest_in_any_order() {
        let f = |n: usize| 2.0 - 1.0 / (n * n) as f64;
        let e = estimate(&[
            (80, f(80)),
            (10, 99.0),
            (20, f(20)),
            (40, f(40)),
            (5, f64::NAN),
            (40, f(40)),
        ]);
        close(e.order.unwrap(), 2.0, 1e-9);
        close(e.extrapolated.unwrap(), 2.0, 1e-12);
        // the fourth grid (10 cells, 99) breaks the power law: not shown asymptotic
        assert_eq!(e.coarser_behaviour, Some(Behaviour::Oscillating));
        assert_eq!(e.asymptotic, Some(false));
    }

    /// Four grids or more: the next-coarser three check the finest three. A power law passes
    /// on any ratios; `h + h^2 / 2` on 8 / 16 / 32 / 64 cells (orders 1.06 then 1.03) passes;
    /// `h - 4 h^2`, whose terms compete on the coarse grids (orders -0.32 then 0.62), does
    /// not. (A slow drift passes: `h + 10 h^2` gives 1.57 then 1.40, both far from the true
    /// order 1; four grids cannot see that, and the docs say so.)
    #[test]
    fn a_fourth_grid_checks_the_asymptotic_range() {
        for p in [0.82, 1.0, 2.0] {
            for cells in [[10usize, 20, 40, 80], [12, 18, 30, 72]] {
                let f = |n: usize| 0.4 - 3.0 * (1.0 / n as f64).powf(p);
                let e = estimate(&cells.map(|n| (n, f(n))));
                assert_eq!(e.coarser_behaviour, Some(Behaviour::Converging));
                close(e.coarser_order.unwrap(), p, 1e-8);
                assert_eq!(e.asymptotic, Some(true), "p {p} {cells:?}");
            }
        }
        let orders = |c2: f64| {
            let f = |n: usize| 1.0 + 1.0 / n as f64 + c2 / (n * n) as f64;
            let e = estimate(&[8, 16, 32, 64].map(|n| (n, f(n))));
            (e.coarser_order.unwrap(), e.order.unwrap(), e.asymptotic)
        };
        let (coarse, fine, asym) = orders(0.5);
        close(coarse, 1.0632, 1e-4);
        close(fine, 1.0327, 1e-4);
        assert_eq!(asym, Some(true));
        let f = |n: usize| 1.0 + 1.0 / n as f64 - 4.0 / (n * n) as f64;
        let e = estimate(&[8, 16, 32, 64].map(|n| (n, f(n))));
        close(e.order.unwrap(), 0.6215, 1e-4);
        assert_eq!(e.coarser_behaviour, Some(Behaviour::NotShrinking));
        close(e.coarser_order.unwrap(), -0.3219, 1e-4);
        assert_eq!(e.asymptotic, Some(false));
        let (coarse, fine, asym) = orders(10.0);
        close(coarse, 1.5694, 1e-4);
        close(fine, 1.3996, 1e-4);
        assert_eq!(asym, Some(true));
        // three grids only: no check
        let e = estimate(&[(10, 1.0), (20, 1.5), (40, 1.75)]);
        assert_eq!((e.coarser_behaviour, e.asymptotic), (None, None));
        // an oscillating finest triple has no order to check
        let e = estimate(&[(5, 0.0), (10, 1.0), (20, 1.2), (40, 1.1)]);
        assert_eq!(e.behaviour, Behaviour::Oscillating);
        assert_eq!(e.coarser_behaviour, Some(Behaviour::Converging));
        assert_eq!(e.asymptotic, None);
        // agreement to round-off on every grid
        let e = estimate(&[(5, 0.3), (10, 0.3), (20, 0.3), (40, 0.3)]);
        assert_eq!(e.asymptotic, Some(true));
    }

    /// The silo's measured discharge rates (docs/silo.md, section 4). The three coarse grids
    /// (10 / 5 / 2.5 mm) look converging, at order 1.44 towards 1.64e-2; the finer ones show
    /// the sequence turns at 2.5 mm: 2.5 / 1.25 / 0.625 mm converge at order 0.82 towards
    /// 1.38e-2. A three-grid estimate is only as good as the grids are fine.
    #[test]
    fn the_silo_grid_study() {
        let e = estimate(&[(50, 1.2553e-2), (100, 1.4965e-2), (200, 1.5855e-2)]);
        assert_eq!(e.behaviour, Behaviour::Converging);
        close(e.order.unwrap(), 1.438, 1e-3);
        close(e.extrapolated.unwrap(), 1.6375e-2, 1e-6);
        let e = estimate(&[(200, 1.5855e-2), (400, 1.4962e-2), (800, 1.4455e-2)]);
        assert_eq!(e.behaviour, Behaviour::Converging);
        close(e.order.unwrap(), 0.817, 1e-3);
        close(e.extrapolated.unwrap(), 1.3789e-2, 1e-6);
        let e = estimate(&[(100, 1.4965e-2), (200, 1.5855e-2), (400, 1.4962e-2)]);
        assert_eq!(e.behaviour, Behaviour::Oscillating);
        close(e.error_finest.unwrap(), 1.5855e-2 - 1.4962e-2, 1e-12);
        // all five: the finest three converge, but the three before them oscillate, so the
        // study does not show that 2.5 mm is in the asymptotic range (a sixth grid would)
        let all = [
            (50, 1.2553e-2),
            (100, 1.4965e-2),
            (200, 1.5855e-2),
            (400, 1.4962e-2),
            (800, 1.4455e-2),
        ];
        let e = estimate(&all);
        assert_eq!(e.behaviour, Behaviour::Converging);
        close(e.order.unwrap(), 0.817, 1e-3);
        assert_eq!(e.coarser_behaviour, Some(Behaviour::Oscillating));
        assert_eq!(e.asymptotic, Some(false));
        // and the four coarsest: converging at 1.44 from the coarser three is not confirmed
        let e = estimate(&all[..4]);
        assert_eq!(e.behaviour, Behaviour::Oscillating);
        assert_eq!(e.asymptotic, None);
    }

    #[test]
    fn sign_changes_flat_values_and_too_few_grids() {
        let e = estimate(&[(10, 1.0), (20, 1.2), (40, 1.1)]);
        assert_eq!(e.behaviour, Behaviour::Oscillating);
        close(e.error_finest.unwrap(), 0.2, 1e-15);
        assert_eq!(e.order, None);
        let e = estimate(&[(10, 1.0), (20, 1.0), (40, 1.1)]);
        assert_eq!(e.behaviour, Behaviour::Oscillating);
        let e = estimate(&[(10, 0.7), (20, 0.7 + 1e-15), (40, 0.7)]);
        assert_eq!(e.behaviour, Behaviour::Converged);
        assert_eq!(e.error_finest, Some(0.0));
        let e = estimate(&[(10, 1.0), (20, 1.1), (40, 1.3)]);
        assert_eq!(e.behaviour, Behaviour::NotShrinking);
        close(e.order.unwrap(), -1.0, 1e-12);
        assert_eq!(e.extrapolated, None);
        assert_eq!(
            estimate(&[(10, 1.0), (20, 1.1)]).behaviour,
            Behaviour::TooFewGrids
        );
        assert_eq!(estimate(&[]).behaviour, Behaviour::TooFewGrids);
        // unequal ratios: 0.1 from 10 to 15 cells, 0.4 from 15 to 45 is f0 + C h^-0.5
        let e = estimate(&[(10, 1.0), (15, 1.1), (45, 1.5)]);
        assert_eq!(e.behaviour, Behaviour::NotShrinking);
        let f = |n: usize| 3.0 - (1.0 / n as f64).powf(-0.5);
        let e = estimate(&[(10, f(10)), (15, f(15)), (45, f(45))]);
        assert_eq!(e.behaviour, Behaviour::NotShrinking);
        close(e.order.unwrap(), -0.5, 1e-9);
    }
}
