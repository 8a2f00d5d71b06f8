//! Walls that are not grid faces (issue 8): embedded boundaries as cut cells on the static
//! Cartesian grid.
//!
//! [`shape`] describes the open region by a signed distance (`< 0` open, `> 0` solid) built
//! from balls, cylinders, half-spaces and convex polytopes; [`cut`] turns it, once at set-up,
//! into per-cell volume fractions, per-face apertures, wall fragments and a small-cell merge
//! map, in fixed-capacity arrays. Geometry knows nothing of physics: the solvers weigh their
//! face fluxes by the apertures and divide by the (group) volumes.

pub mod cut;
pub mod shape;

pub use cut::{
    sliver_fraction, CutCells, GeometryError, GeometryStats, DEFAULT_SMALL, WALL_DISTANCE_FLOOR,
};
pub use shape::{Convex, Op, Plane, Primitive, Region, RegionFull};
