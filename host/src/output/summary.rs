//! `summary.json`: what ran, how fast, and the diagnostics scripts compare.

use super::write_file;
use crate::error::{Error, Result};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::Path;

/// Comparison with a closed-form solution at `t_end`.
#[derive(Debug, Clone, Default, Serialize, PartialEq)]
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

/// Where and why a run stopped before `t_end` (`stopped` in summary.json).
#[derive(Debug, Clone, Default, Serialize, PartialEq)]
pub struct Stopped {
    /// One line, as printed on stderr.
    pub reason: String,
    /// Simulated time reached \[s\].
    pub t: f64,
    /// Steps taken (a non-finite value is detected after this step).
    pub step: u64,
    /// `SIGINT` or `SIGTERM` (interrupted runs).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub signal: Option<String>,
    /// The field that is not finite: `dt`, `t`, `phi`, `c`, `T`, `u_x`, ..., `flow c`, ...
    #[serde(skip_serializing_if = "Option::is_none")]
    pub field: Option<String>,
    /// The cell (solver order) and its integer coordinates per axis.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cell: Option<usize>,
    /// Integer coordinates of `cell` per axis.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub coords: Option<Vec<usize>>,
}

impl Stopped {
    /// The summary of a loop's stop.
    pub fn of(stop: &crate::interrupt::Stop) -> Self {
        use crate::interrupt::Reason;
        let mut s = Self {
            reason: stop.describe(),
            t: stop.t,
            step: stop.step,
            signal: None,
            field: None,
            cell: None,
            coords: None,
        };
        match &stop.reason {
            Reason::Signal(sig) => s.signal = Some(sig.name().into()),
            Reason::NonFinite {
                field,
                cell,
                coords,
                ..
            } => {
                s.field = Some(field.clone());
                s.cell = *cell;
                s.coords = cell.map(|_| coords.clone());
            }
            Reason::Core(_) => {}
        }
        s
    }
}

/// The contents of `summary.json`.
#[derive(Debug, Clone, Default, Serialize, PartialEq)]
pub struct Summary {
    /// `"complete"`: ran to `t_end` (or until a silo emptied); `"interrupted"`: stopped by
    /// SIGINT/SIGTERM; `"failed"`: stopped by a non-finite time step or state. The files of a
    /// stopped run hold what was computed up to `stopped.t` (final.csv: the state there).
    pub status: String,
    /// Where and why the run stopped early (absent when complete).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stopped: Option<Stopped>,
    /// Scene name.
    pub scene: String,
    /// Scene file (or `scenes/<name>.toml` for a built-in).
    pub scene_file: String,
    /// What changed the scene file for this run, in the order applied: the `--set`
    /// overrides and the options that set scene keys (`--grid`, `--t-end`, ...), each as
    /// `key=value` (empty for a run without them or one started by a library caller).
    pub overrides: Vec<String>,
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
    /// Smallest / largest / last stable time step stepped with \[s\] (coupled scenes: the flow's
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
    /// Wall time of the whole run, set-up and outputs included \[s\].
    pub wall_seconds: f64,
    /// Wall time of the time stepping alone \[s\].
    pub stepping_seconds: f64,
    /// `steps * cells / stepping_seconds`.
    pub cell_updates_per_second: f64,
    /// Small-phase mass at t = 0, `sum phi |C|`.
    pub mass_initial: f64,
    /// Small-phase mass at t_end.
    pub mass_final: f64,
    /// Small-phase mass set to zero as vanishing fractions (below 2^-800 in f64, so
    /// subnormal numbers never slow the run; docs/model.md 5.6); counted in the drift.
    pub mass_flushed: f64,
    /// Small-phase mass that left through the scene's outlets and open sides, net (what came in
    /// through an inflow side counts negative), booked face by face and step by step: the
    /// coupled run's outlets (`flow.outlet.out_small`) plus the inflow and outflow sides of the
    /// segregation step (`mass_out_sides`); 0 for closed boxes.
    pub mass_out: f64,
    /// Per inflow or outflow side of the box (`x_low`, ..., `z_high`), the small-phase mass
    /// that left through it, net (negative where more came in than left); absent for scenes
    /// without such sides. Booked exactly (fixed point) and merged the same way for any
    /// number of threads or ranks.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub mass_out_sides: BTreeMap<String, f64>,
    /// `|mass_final + mass_flushed + mass_out - mass_initial| / mass_initial` (0 if there is no
    /// mass): what the books do not account for, so round-off for every scene, open sides
    /// and outlets included.
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
    /// Drum readouts (circulation centre, radial profiles, angle of repose, flowing layer),
    /// for 2D circular drums.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub drum: Option<crate::data::DrumSummary>,
    /// The warning lines the run printed (before it started: narrow orifices, the implicit
    /// pressure with an outlet; at the end: broken bounds), as printed, so that a run read
    /// later, or one of a sweep, still says what it was warned of (absent when none).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
}

impl Summary {
    /// Writes pretty JSON.
    pub fn write(&self, path: &Path) -> Result<()> {
        let mut text = serde_json::to_string_pretty(self).map_err(Error::failure)?;
        text.push('\n');
        write_file(path, text.as_bytes())
    }
}
