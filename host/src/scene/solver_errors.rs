//! The core's refusals in the scene's words: a `GridError`, `SetupError` or `FlowError` becomes
//! one line `file: key: message`, with the scene key the user edits (e.g. `physics.gravity`,
//! `numerics.courant`) and, for a bad cell, its position. The message itself is the core's
//! `Display` text (`core/src/messages.rs`); validation catches most of these first, so they
//! mostly show for values the solver derives (the frozen flow, a coupled hand-over).

use super::Scene;
use crate::error::Error;
use sieve_core::flow::FlowError;
use sieve_core::grid::GridError;
use sieve_core::SetupError;

/// The scene key a named configuration number comes from.
fn parameter_key(name: &str) -> &'static str {
    match name {
        "s0" => "material.s0",
        "diffusion" => "material.diffusion",
        "gravity" => "physics.gravity",
        "direction" => "physics.direction",
        "temperature" | "heating" => "material.heating",
        "eta0" => "material.eta0",
        "lambda0" => "material.lambda0",
        "eps0" => "material.eps0",
        "t0" => "material.T0",
        "packing" => "material.phi_rlp",
        "courant" => "flow.courant",
        "t_min" => "flow.t_min",
        "wall friction" => "boundary.flow",
        "inflow state" | "boundary state" => "boundary",
        _ => "",
    }
}

/// `(x, y, z)` of a cell, named for the scene's axes.
fn at_cell(scene: &Scene, cell: usize) -> String {
    if cell >= scene.len() {
        return String::new();
    }
    let p = scene.center(cell);
    let names = ["x", "y", "z"];
    let axes = super::validate::physical_axes(scene.dim);
    let parts: Vec<String> = axes
        .iter()
        .map(|&a| format!("{} = {}", names[a], p[a]))
        .collect();
    format!(" (cell centre {})", parts.join(", "))
}

/// A grid the core refused.
pub fn grid_error(scene: &Scene, e: &GridError) -> Error {
    let key = match e {
        GridError::TooManyCells { .. } | GridError::EmptyAxis(_) => "grid.cells",
        GridError::BadExtent(_) => "grid.upper",
    };
    Error::at(&scene.label, key, e)
}

/// A segregation set-up or field the core refused.
pub fn setup_error(scene: &Scene, e: &SetupError) -> Error {
    let (key, cell) = match *e {
        SetupError::Capacity { .. } => ("grid.cells", None),
        SetupError::UnpairedPeriodic { .. } => ("boundary", None),
        SetupError::Courant => ("numerics.courant", None),
        SetupError::Parameter(name) => (parameter_key(name), None),
        SetupError::NonFinite { cell, .. }
        | SetupError::NegativeVolumeFraction { cell }
        | SetupError::NegativeTemperature { cell }
        | SetupError::PhiOutOfRange { cell } => ("initial", Some(cell)),
        SetupError::InflowOutOfRange { cell } => ("boundary.inflow.phi", Some(cell)),
    };
    let place = cell.map_or(String::new(), |c| at_cell(scene, c));
    Error::at(&scene.label, key, format!("{e}{place}"))
}

/// A flow set-up or field the core refused.
pub fn flow_error(scene: &Scene, e: &FlowError) -> Error {
    let (key, cell) = match *e {
        FlowError::Capacity => ("grid.cells", None),
        FlowError::UnpairedPeriodic(_) => ("boundary", None),
        FlowError::Parameter(name) => (parameter_key(name), None),
        FlowError::Field { cell, .. } => ("initial", Some(cell)),
    };
    let place = cell.map_or(String::new(), |c| at_cell(scene, c));
    Error::at(&scene.label, key, format!("{e}{place}"))
}
