//! `summary.json`: what ran, how fast, and the diagnostics scripts compare.

use super::write_file;
use crate::error::{Error, Result};
use serde::Serialize;
use std::path::Path;

/// Comparison with a closed-form solution at `t_end`.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct ExactComparison {
    /// Which solution (`column-a`).
    pub kind: String,
    /// L1 norm of the error of phihat against exact cell averages, `sum |e| |C|`.
    pub l1_phihat: f64,
    /// Exact Psi at t_end.
    pub psi_exact: f64,
    /// Exact segregation time for the scene's threshold.
    pub segregation_time_exact: f64,
}

/// The contents of `summary.json`.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Summary {
    /// Scene name.
    pub scene: String,
    /// Scene file (or `scenes/<name>.toml` for a built-in).
    pub scene_file: String,
    /// Face flux.
    pub scheme: String,
    /// Tracked phase.
    pub phase: String,
    /// Solver float type.
    pub precision: String,
    /// Number of dimensions.
    pub dims: usize,
    /// Cells per axis (axis order of the scene: z in 1D; x, z in 2D; x, y, z in 3D).
    pub cells: Vec<usize>,
    /// Total number of cells.
    pub cell_count: usize,
    /// Steps taken.
    pub steps: u64,
    /// Stable time step (all steps but the ones landing on output times).
    pub dt: f64,
    /// Smallest / largest / last stable time step stepped with [s] (coupled scenes: the flow's
    /// and the segregation's common step varies; null when nothing moves).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dt_min: Option<f64>,
    /// See `dt_min`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dt_max: Option<f64>,
    /// See `dt_min`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dt_last: Option<f64>,
    /// Courant number.
    pub courant: f64,
    /// End time.
    pub t_end: f64,
    /// Output interval.
    pub output_interval: f64,
    /// Wall time of the whole run, set-up and outputs included [s].
    pub wall_seconds: f64,
    /// Wall time of the time stepping alone [s].
    pub stepping_seconds: f64,
    /// `steps * cells / stepping_seconds`.
    pub cell_updates_per_second: f64,
    /// Small-phase mass at t = 0, `sum phi |C|`.
    pub mass_initial: f64,
    /// Small-phase mass at t_end.
    pub mass_final: f64,
    /// `|mass_final - mass_initial| / mass_initial` (0 if there is no mass). Scenes with inflow
    /// or outflow exchange mass through the boundary, so this is not a conservation error there.
    pub mass_rel_drift: f64,
    /// Largest `phi - c` over cells and output times (0 if never above).
    pub overshoot_max: f64,
    /// Largest `-phi` over cells and output times (0 if never below).
    pub undershoot_max: f64,
    /// Mixing index at t = 0.
    pub psi_initial: f64,
    /// Mixing index at t_end.
    pub psi_final: f64,
    /// First time Psi < psi_threshold after Psi was >= psi_threshold (null if not reached).
    pub segregation_time: Option<f64>,
    /// Threshold of the segregation time.
    pub psi_threshold: f64,
    /// 64-bit FNV-1a hash of the final state (`sieve_core::state_hash`), 16 hex digits.
    pub state_hash: String,
    /// Comparison with the closed-form solution, if the scene has one.
    pub exact: Option<ExactComparison>,
    /// Flow diagnostics, for scenes that solve a flow (absent for prescribed scenes).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub flow: Option<crate::data::FlowSummary>,
    /// The container on cut cells, for scenes with a `[geometry]`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub geometry: Option<crate::data::GeometrySummary>,
    /// The frame of reference, for scenes with a `[frame]`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub frame: Option<crate::data::FrameSummary>,
}

impl Summary {
    /// Writes pretty JSON.
    pub fn write(&self, path: &Path) -> Result<()> {
        let mut text = serde_json::to_string_pretty(self).map_err(Error::failure)?;
        text.push('\n');
        write_file(path, text.as_bytes())
    }
}
