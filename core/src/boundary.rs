//! What happens at each face of the box (model.md sections 2 and 5).

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
