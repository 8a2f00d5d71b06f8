//! What happens at each face of the box (model.md sections 2 and 5).

use crate::grid::Grid;
use crate::real::Real;
use serde::{Deserialize, Serialize};

/// The kind of one side of the box.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Boundary {
    /// Solid wall: no transport and no segregation flux across it.
    #[default]
    Wall,
    /// Dirichlet inflow: the flux of the prescribed state (the per-cell ghost value).
    Inflow,
    /// Free outflow: the flux of the interior state (zero-gradient ghost).
    Outflow,
    /// Periodic: the box wraps; must be set on both sides of the axis.
    Periodic,
}

/// The boundary kinds of the low and high side of every axis.
pub type Boundaries<const D: usize> = [[Boundary; 2]; D];

/// Checks that periodic sides come in pairs; returns the first offending axis.
pub fn check_periodic_pairs<const D: usize>(bc: &Boundaries<D>) -> Result<(), usize> {
    for (a, sides) in bc.iter().enumerate() {
        if (sides[0] == Boundary::Periodic) != (sides[1] == Boundary::Periodic) {
            return Err(a);
        }
    }
    Ok(())
}

/// Most openings one side of the box can carry.
pub const MAX_OPENINGS: usize = 2;

/// An opening (outlet) in a wall side: the box `lower..upper` in the coordinates tangential
/// to the side (the entries of the side's own normal axis are ignored). Grains leave through
/// it freely (model.md 2, "outflow (silo orifice)"); see [`crate::flow`] for the ghost state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Opening<R, const D: usize> {
    /// Lower corner (m).
    pub lower: [R; D],
    /// Upper corner (m).
    pub upper: [R; D],
}

/// The openings of one wall side (at most [`MAX_OPENINGS`], not overlapping).
///
/// A boundary face is open by the **fraction of its area** that lies in an opening, not by
/// whether its centre does: the open area, and with it the discharge, then varies
/// continuously with the opening's width and position instead of jumping by whole cells
/// (a 0.02 m orifice on 5 mm cells is 4 cells wide wherever it sits). A partly open face
/// carries that fraction of the outlet's flux and `1 -` it of the wall's (every boundary
/// flux of the flow and of the segregation is linear in it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Openings<R, const D: usize> {
    list: [Opening<R, D>; MAX_OPENINGS],
    len: usize,
}

impl<R: Real, const D: usize> Openings<R, D> {
    /// No opening (a closed wall).
    pub const fn none() -> Self {
        Self {
            list: [Opening {
                lower: [R::ZERO; D],
                upper: [R::ZERO; D],
            }; MAX_OPENINGS],
            len: 0,
        }
    }

    /// One opening.
    pub fn one(opening: Opening<R, D>) -> Self {
        let mut o = Self::none();
        o.list[0] = opening;
        o.len = 1;
        o
    }

    /// Adds an opening; `Err` if there are already [`MAX_OPENINGS`] or its corners are not
    /// finite and ordered (`lower <= upper` on every axis).
    pub fn push(&mut self, opening: Opening<R, D>) -> Result<(), &'static str> {
        if self.len == MAX_OPENINGS {
            return Err("too many openings on one side");
        }
        for a in 0..D {
            let (lo, hi) = (opening.lower[a], opening.upper[a]);
            if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
                return Err("opening corners must be finite with lower <= upper");
            }
        }
        self.list[self.len] = opening;
        self.len += 1;
        Ok(())
    }

    /// True if the side is closed.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The openings.
    pub fn as_slice(&self) -> &[Opening<R, D>] {
        &self.list[..self.len]
    }

    /// Open fraction in `[0, 1]` of the boundary face of cell `i` whose normal is `axis`: the
    /// overlap of the face with the openings over the face area (the product of the overlaps
    /// along the tangential axes; 1 in 1D, where a side is a point).
    pub fn fraction(&self, grid: &Grid<R, D>, axis: usize, i: usize) -> R {
        if self.len == 0 {
            return R::ZERO;
        }
        let h = grid.spacing();
        let x0 = grid.origin();
        let mut total = R::ZERO;
        for o in self.as_slice() {
            let mut f = R::ONE;
            for b in 0..D {
                if b == axis {
                    continue;
                }
                let lo = x0[b] + R::from_usize(grid.coord(i, b)) * h[b];
                let hi = lo + h[b];
                let overlap = (hi.min(o.upper[b]) - lo.max(o.lower[b])).max(R::ZERO);
                f *= (overlap / h[b]).min(R::ONE);
            }
            total += f;
        }
        total.min(R::ONE)
    }
}
