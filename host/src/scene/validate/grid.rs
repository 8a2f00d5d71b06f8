//! `[grid]`: cells per axis within the compiled capacity, a box with upper > lower.

use super::{axis_names, vector, Problems, CAPACITY, MAX_AXIS_CELLS, MAX_COORDINATE};
use crate::error::Error;
use crate::scene::GridSpec;

/// Validated `[grid]`.
pub(super) struct GridBox {
    pub cells: Vec<usize>,
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
}

/// Checks `[grid]` of a `dim`-dimensional scene.
pub(super) fn check(p: &mut Problems, l: &str, g: &GridSpec, dim: usize) -> Option<GridBox> {
    let mut cells = None;
    if g.cells.len() != dim {
        p.push(Error::range(
            l,
            "grid.cells",
            format!("{:?}", g.cells),
            &format!(
                "{dim} integers, one per axis ({})",
                axis_names(dim).join(", ")
            ),
        ));
    } else {
        let mut ok = true;
        for (i, &n) in g.cells.iter().enumerate() {
            if !(1..=MAX_AXIS_CELLS as i64).contains(&n) {
                ok = false;
                p.push(Error::range(
                    l,
                    &format!("grid.cells[{i}]"),
                    n,
                    &format!("integer 1..={MAX_AXIS_CELLS}"),
                ));
            }
        }
        if ok {
            let c: Vec<usize> = g.cells.iter().map(|&n| n as usize).collect();
            let total: usize = c.iter().product();
            let cap = CAPACITY[dim - 1];
            if total > cap {
                p.push(Error::range(
                    l,
                    "grid.cells",
                    format!("{c:?} ({total} cells)"),
                    &format!("at most {cap} cells in {dim}D (the compiled capacity)"),
                ));
            } else {
                cells = Some(c);
            }
        }
    }
    let lower = p.ok(vector(l, "grid.lower", &g.lower, dim));
    let upper = p.ok(vector(l, "grid.upper", &g.upper, dim));
    let (lower, upper) = (lower?, upper?);
    let mut boxed = true;
    for a in 0..dim {
        if !(upper[a] > lower[a]) {
            boxed = false;
            p.push(Error::range(
                l,
                &format!("grid.upper[{a}]"),
                upper[a],
                &format!("a number > grid.lower[{a}] = {}", lower[a]),
            ));
        }
    }
    for a in 0..dim {
        // what the plots can draw (`output::plot::unplottable`): a finite span, not lost
        // against the coordinates' magnitude, within MAX_COORDINATE
        let mag = lower[a].abs().max(upper[a].abs());
        let key = if upper[a].abs() >= lower[a].abs() {
            "grid.upper"
        } else {
            "grid.lower"
        };
        let value = if key == "grid.upper" {
            upper[a]
        } else {
            lower[a]
        };
        if mag > MAX_COORDINATE {
            boxed = false;
            p.push(Error::range(
                l,
                &format!("{key}[{a}]"),
                value,
                &format!("-{MAX_COORDINATE:e} to {MAX_COORDINATE:e} in m (the plots' range)"),
            ));
        } else if boxed && upper[a] - lower[a] < 1e-15 * mag {
            boxed = false;
            p.push(Error::range(
                l,
                &format!("grid.upper[{a}]"),
                upper[a],
                &format!(
                    "at least grid.lower[{a}] + 1e-15 x {mag:e} in m (a box the plots can tell from a point)"
                ),
            ));
        }
    }
    (boxed).then_some(())?;
    Some(GridBox {
        cells: cells?,
        lower,
        upper,
    })
}
