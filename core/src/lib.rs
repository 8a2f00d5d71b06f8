//! # sieve-core
//!
//! Size segregation in bi-disperse granular flows (see `docs/model.md`): finite volumes on
//! static structured grids, generic over `f32`/`f64`, with no standard library, no allocator
//! and no `unsafe`. Memory is fixed at compile time by const generics (`D` dimensions, `N`
//! cells of capacity) and a step allocates nothing, so the same code runs in the desktop CLI,
//! in tests and in Cortex-M4F firmware, with bit-identical results.
//!
//! Data flows one way: grid + boundaries + configuration ([`segregation::Segregation::setup`])
//! -> fields -> [`segregation::Segregation::prepare`] -> [`segregation::Segregation::step`]
//! -> [`diagnostics`].
#![no_std]
#![forbid(unsafe_code)]

pub mod boundary;
pub mod closure;
pub mod decomp;
pub mod diagnostics;
pub mod exact;
pub mod flow;
pub mod fork;
pub mod frame;
pub mod geometry;
pub mod grid;
pub mod hash;
pub mod hot;
mod messages;
pub mod real;
pub mod segregation;
pub mod sensor;
pub mod sum;

pub use boundary::{Boundaries, Boundary};
pub use diagnostics::{
    add_psi_sums, diagnose, diagnose_embedded, diagnose_fields, diagnose_with_terms, entropy_term,
    psi_floor, psi_of_sums, psi_sums_start, state_hash, Diagnostics, PsiOf, SegregationClock,
    PSI_SUMS,
};
pub use grid::Grid;
pub use real::Real;
pub use segregation::{
    DirectionMode, Phase, Scheme, Segregation, SegregationConfig, SetupError, TemperatureMode,
    Transport,
};
