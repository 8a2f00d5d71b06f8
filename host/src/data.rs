//! The run's plain data: what the time loops measure and what the outputs write (series rows,
//! loop statistics, snapshots of the state, the flow block of summary.json, flow profiles).
//!
//! A leaf below `run`, `flow` and `output`: the loops fill these types, the writers read them,
//! and neither side imports the other (data flows one way, scene -> state -> step ->
//! diagnostics -> output).

use crate::scene::Scene;
use serde::Serialize;
use sieve_core::{Boundary, Real, Segregation, SegregationClock};
use std::time::Duration;

/// One row of `series.csv`: diagnostics at an output time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SeriesRow {
    /// Time.
    pub t: f64,
    /// Mixing index Psi.
    pub psi: f64,
    /// Mass of the small phase, sum phi |C|.
    pub mass: f64,
    /// max(0, phi - c) over cells.
    pub overshoot_max: f64,
    /// max(0, -phi) over cells.
    pub undershoot_max: f64,
}

/// What the time loop measured.
#[derive(Debug, Clone, Default)]
pub struct LoopStats {
    /// Steps taken.
    pub steps: u64,
    /// Wall time of the stepping alone (no diagnostics, no output).
    pub stepping: Duration,
    /// One row per output time, t = 0 first.
    pub series: Vec<SeriesRow>,
    /// Segregation time (see [`SegregationTimer`]).
    pub segregation_time: Option<f64>,
    /// The stable time step of the prepared state.
    pub dt: f64,
    /// The solver's running bound violations `(max(phi - c), max(-phi))` over every cell after
    /// every step ([`sieve_core::Segregation::bound_violations`]), not only at output times.
    pub every_step: (f64, f64),
    /// Small-phase mass flushed to zero as vanishing fractions
    /// ([`sieve_core::Segregation::flushed_small_mass`], docs/model.md 5.6).
    pub flushed: f64,
    /// Small-phase mass that left through each inflow or outflow side of the box, net, as
    /// (solver axis, side 0 low / 1 high, mass)
    /// ([`sieve_core::Segregation::small_mass_out_through_sides`]); empty without such sides.
    pub sides_out: Vec<(usize, usize, f64)>,
    /// Why the loop stopped before its end time (a signal, a non-finite value); None if it
    /// ran to the end. Set only by the `*_until_stop` loops (host/src/interrupt.rs).
    pub stop: Option<crate::interrupt::Stop>,
    /// Smallest, largest and last stable time step actually stepped with (the steps shortened
    /// to land on an output time not counted); `None` before any step or when nothing moves.
    pub dt_taken: Option<[f64; 3]>,
}

impl LoopStats {
    /// Records a stable step `dt` taken.
    pub fn took_dt(&mut self, dt: f64) {
        self.dt_taken = Some(match self.dt_taken {
            None => [dt, dt, dt],
            Some([lo, hi, _]) => [lo.min(dt), hi.max(dt), dt],
        });
    }
}

impl LoopStats {
    /// Largest overshoot over all cells, steps and output times.
    pub fn overshoot_max(&self) -> f64 {
        self.series
            .iter()
            .map(|r| r.overshoot_max)
            .fold(self.every_step.0, f64::max)
    }
    /// Largest undershoot over all cells, steps and output times.
    pub fn undershoot_max(&self) -> f64 {
        self.series
            .iter()
            .map(|r| r.undershoot_max)
            .fold(self.every_step.1, f64::max)
    }
    /// Records the solver's running bound violations at the end of a loop.
    pub fn record_bounds<R: Real, const D: usize, const N: usize>(
        &mut self,
        s: &Segregation<R, D, N>,
    ) {
        let (above, below) = s.bound_violations();
        self.every_step = (above.to_f64().max(0.0), below.to_f64().max(0.0));
        self.flushed = s.flushed_small_mass().to_f64();
        let out = s.small_mass_out_through_sides();
        self.sides_out.clear();
        for (a, kinds) in s.boundaries().iter().enumerate() {
            for (side, kind) in kinds.iter().enumerate() {
                if matches!(kind, Boundary::Inflow | Boundary::Outflow) {
                    self.sides_out.push((a, side, out[a][side].to_f64()));
                }
            }
        }
    }

    /// The net small-phase mass out through all inflow and outflow sides, summed in axis and
    /// side order.
    pub fn mass_out_through_sides(&self) -> f64 {
        self.sides_out.iter().map(|e| e.2).sum()
    }
}

/// Segregation time: the first time Psi falls below the threshold, counted only once Psi has
/// been at or above it, so that a bed that starts segregated the wrong way round (Psi = 0,
/// inversely graded) reports when it has re-segregated, not t = 0.
#[derive(Debug, Clone, Copy)]
pub struct SegregationTimer {
    armed: bool,
    clock: SegregationClock<f64>,
    /// A crossing already found (a resumed run: [`Self::crossed`]).
    fixed: Option<f64>,
}

impl SegregationTimer {
    /// A timer for `Psi < threshold`.
    pub fn new(threshold: f64) -> Self {
        Self {
            armed: false,
            clock: SegregationClock::new(threshold),
            fixed: None,
        }
    }
    /// A timer whose crossing is already known (a checkpoint kept it, resolved to the step).
    pub fn crossed(threshold: f64, t: f64) -> Self {
        Self {
            fixed: Some(t),
            ..Self::new(threshold)
        }
    }
    /// Feeds a sample in time order.
    pub fn sample(&mut self, t: f64, psi: f64) {
        if self.fixed.is_some() {
            return;
        }
        if !self.armed && psi >= self.clock.threshold() {
            self.armed = true;
        }
        if self.armed {
            self.clock.sample(t, psi);
        }
    }
    /// The segregation time, if reached.
    pub fn time(&self) -> Option<f64> {
        self.fixed.or(self.clock.time())
    }
}

/// The output times `0, dt_out, 2 dt_out, ..., t_end` (the last one clipped to `t_end`).
pub fn output_times(t_end: f64, interval: f64) -> Vec<f64> {
    let k_max = (t_end / interval * (1.0 - 1e-12)).ceil().max(1.0) as usize;
    (0..=k_max)
        // Rounded to 12 significant digits so that 6 * 0.1 is written as 0.6, not
        // 0.6000000000000001 (a shift of ~1e-16 in the stop time).
        .map(|k| round12(k as f64 * interval).min(t_end))
        .collect()
}

fn round12(x: f64) -> f64 {
    format!("{x:.11e}").parse().unwrap_or(x)
}

/// The state of every cell in f64, physical axis order (x, y, z).
#[derive(Debug, Clone, Default)]
pub struct Snapshot {
    /// Time.
    pub t: f64,
    /// c per cell.
    pub c: Vec<f64>,
    /// phi per cell.
    pub phi: Vec<f64>,
    /// T per cell.
    pub temp: Vec<f64>,
    /// Velocity (ux, uy, uz) per cell; components of absent axes are 0.
    pub u: Vec<[f64; 3]>,
    /// Pressure per cell, for scenes that solve a flow (written as the extra column/array p).
    pub p: Option<Vec<f64>>,
    /// Open volume fraction per cell, for scenes with a geometry (the VTK array `volume`).
    pub volume: Option<Vec<f64>>,
}

impl Snapshot {
    /// `n` cells at rest at time `t`, all with volume fraction `c`, no grains of the tracked
    /// phase and open volume `volume`: a start that synthetic snapshots (tests, fuzzing) fill
    /// in.
    pub fn at_rest(t: f64, n: usize, c: f64, volume: f64) -> Self {
        Snapshot {
            t,
            c: vec![c; n],
            phi: vec![0.0; n],
            temp: vec![0.0; n],
            u: vec![[0.0; 3]; n],
            p: None,
            volume: Some(vec![volume; n]),
        }
    }

    /// Takes the state of `s`.
    pub fn of<R: Real, const D: usize, const N: usize>(
        s: &Segregation<R, D, N>,
        scene: &Scene,
    ) -> Self {
        let n = s.len();
        let axes = crate::scene::validate::physical_axes(D);
        let mut snap = Snapshot {
            t: s.time().to_f64(),
            c: Vec::with_capacity(n),
            phi: Vec::with_capacity(n),
            temp: Vec::with_capacity(n),
            u: Vec::with_capacity(n),
            p: None,
            volume: None,
        };
        debug_assert_eq!(n, scene.len());
        for i in 0..n {
            snap.c.push(s.c(i).to_f64());
            snap.phi.push(s.phi(i).to_f64());
            snap.temp.push(s.temperature(i).to_f64());
            let v = s.velocity(i);
            let mut u = [0.0; 3];
            for (a, &p) in axes.iter().enumerate() {
                u[p] = v[a].to_f64();
            }
            snap.u.push(u);
        }
        snap
    }

    /// phihat = phi / c (0 in empty cells).
    pub fn phihat(&self) -> Vec<f64> {
        self.phi
            .iter()
            .zip(&self.c)
            .map(|(&p, &c)| if c > 1e-6 { p / c } else { 0.0 })
            .collect()
    }

    /// phihat for the maps of a scene with a geometry: NaN (drawn as masked, not as
    /// phihat = 0) in solid cells (open volume 0) and in empty cells (c <= 1e-6, the
    /// solver's vacuum); as [`Self::phihat`] without a geometry.
    pub fn phihat_masked(&self) -> Vec<f64> {
        let Some(vol) = &self.volume else {
            return self.phihat();
        };
        self.phi
            .iter()
            .zip(&self.c)
            .zip(vol)
            .map(|((&p, &c), &v)| if v > 0.0 && c > 1e-6 { p / c } else { f64::NAN })
            .collect()
    }
}

/// The `geometry` block of summary.json (scenes with cut cells).
#[derive(Debug, Clone, Default, Serialize, PartialEq)]
pub struct GeometrySummary {
    /// "drum", "square-drum", "drum-baffle" or "hopper".
    pub shape: String,
    /// Open volume of the container on the grid, `sum V_i |C|` [m^2 in 2D, m^3 in 3D].
    pub open_volume: f64,
    /// Open volume over the box's volume.
    pub open_fraction: f64,
    /// Cells with an open fraction strictly between 0 and 1.
    pub cut_cells: usize,
    /// Small cut cells merged into a neighbour.
    pub merged_cells: usize,
    /// Slivers with no neighbour to merge with, folded into the solid.
    pub removed_cells: usize,
    /// Their open volume, lost to the solid [m^2 / m^3].
    pub removed_volume: f64,
    /// Smallest open fraction of a remaining cell.
    pub min_volume_fraction: f64,
    /// Smallest open fraction of a merged group (>= small).
    pub min_group_volume: f64,
    /// The merging threshold.
    pub small: f64,
}

/// The `frame` block of summary.json (scenes with `[frame]`).
#[derive(Debug, Clone, Default, Serialize, PartialEq)]
pub struct FrameSummary {
    /// "lab" or "rotating".
    pub kind: String,
    /// Speed [rev/s], positive counter-clockwise (x right, z up).
    pub rev_per_s: f64,
    /// Angular speed 2 pi rev_per_s [rad/s].
    pub omega: f64,
    /// Seconds per revolution (null at rest).
    pub period: Option<f64>,
    /// A point on the rotation axis (solver axis order) \[m\].
    pub center: Vec<f64>,
    /// Psi at every whole revolution `t = k period` reached by the run (k = 0, 1, ...),
    /// interpolated linearly between output samples: exact where the output interval divides
    /// the period (the built-in tumblers), an interpolation otherwise. Empty at rest.
    pub psi_per_revolution: Vec<f64>,
}

/// Psi at `t = k period` for k = 0, 1, ... up to the last sample, linear between samples.
pub fn psi_per_revolution(series: &[SeriesRow], period: f64) -> Vec<f64> {
    let mut out = Vec::new();
    let (Some(first), Some(last)) = (series.first(), series.last()) else {
        return out;
    };
    if !(period.is_finite() && period > 0.0) {
        return out;
    }
    // at most one value per sample: a period shorter than the output interval says nothing more
    let revolutions = ((last.t - first.t) / period)
        .floor()
        .min(series.len() as f64);
    for k in 0..=(revolutions as usize) {
        let t = first.t + k as f64 * period;
        let j = series.partition_point(|r| r.t < t);
        let psi = match (j.checked_sub(1).and_then(|i| series.get(i)), series.get(j)) {
            (_, Some(b)) if b.t == t => b.psi,
            (Some(a), Some(b)) => a.psi + (b.psi - a.psi) * (t - a.t) / (b.t - a.t),
            (Some(a), None) => a.psi,
            (None, Some(b)) => b.psi,
            (None, None) => break,
        };
        out.push(psi);
    }
    out
}

/// A steady flow, frozen, on the full grid (solver cell order): what a frozen-flow run
/// hands over to the segregation ([`crate::flow::hand_over_frozen`]) and what its
/// checkpoints keep ([`crate::checkpoint::put_frozen`]), so a resumed run skips the spin-up.
#[derive(Debug, Clone)]
pub struct Frozen {
    /// c per cell.
    pub c: Vec<f64>,
    /// T per cell.
    pub t: Vec<f64>,
    /// p per cell.
    pub p: Vec<f64>,
    /// Velocity per solver axis, per cell.
    pub u: Vec<Vec<f64>>,
    /// The flow block (without the segregation part).
    pub summary: FlowSummary,
}

/// The `flow` block of summary.json.
#[derive(Debug, Clone, Default, Serialize, PartialEq)]
pub struct FlowSummary {
    /// "frozen-flow" or "coupled".
    pub equations: String,
    /// "off", "r0" or "half".
    pub back_coupling: String,
    /// How the flow advanced its pressure: "explicit" or "implicit" (`flow.pressure`).
    pub pressure: String,
    /// The flow's viscous stress: "spec" or "objective" (`flow.stress`, model.md 2.6).
    pub stress: String,
    /// With cut cells: which cell of a merge group took a merged cell's wall term,
    /// "member" or "master" (`flow.merged_walls`, model.md 5.4); absent without.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub merged_walls: Option<String>,
    /// How the bed was filled: "given" or "settled" (`initial.fill`, model.md 5.8).
    pub fill: String,
    /// Flow steps to the steady state (frozen-flow; null when coupled).
    pub flow_steps_to_steady: Option<u64>,
    /// Flow steps in total.
    pub flow_steps: u64,
    /// Conjugate-gradient iterations of all implicit solves (velocity components and T).
    pub cg_iterations: u64,
    /// Physical time of the flow solve \[s\] (spin-up time when frozen).
    pub flow_time: f64,
    /// Wall time of the flow solve \[s\].
    pub flow_seconds: f64,
    /// Cells of the grid the flow was solved on (the spin-up grid when reduced).
    pub flow_cells: Vec<usize>,
    /// max c / c_rcp over cells (< 1 by construction).
    pub max_packing: f64,
    /// Smallest T over cells [m^2/s^2].
    pub t_min: f64,
    /// Largest T over filled cells [m^2/s^2].
    pub t_max: f64,
    /// Largest speed over filled cells [m/s].
    pub max_speed: f64,
    /// Kinetic energy sum c |u|^2 / 2 |C| (per unit grain density).
    pub kinetic_energy: f64,
    /// Steady-state residual of the last flow step [1/s].
    pub residual: f64,
    /// Steady-state tolerance [1/s].
    pub steady_tolerance: f64,
    /// Tracked-phase volume lifted into [0, c] by the round-off guard of the carried
    /// transport (coupled; 0 when the percolation stage keeps the bounds exactly, and when
    /// frozen). phi is no longer clipped: it rides on the flow's mass fluxes.
    pub clipped_mass: f64,
    /// Discharge through wall outlets (scenes with outlets; [`crate::silo`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub outlet: Option<crate::silo::DischargeSummary>,
}

/// Horizontally averaged flow profiles over the vertical (last) axis.
#[derive(Debug, Clone, Default)]
pub struct Profiles {
    /// Cell-centre heights.
    pub z: Vec<f64>,
    /// Mean horizontal velocity u_x (the vertical velocity in 1D).
    pub u: Vec<f64>,
    /// Mean T.
    pub t: Vec<f64>,
    /// |d u_x / d z| (central differences; one-sided to a wall's velocity).
    pub shear: Vec<f64>,
    /// sqrt(a eta0 / eps0): sqrt(T)/shear of steady uniform shear (model.md 2).
    pub ratio_theory: f64,
}

/// Drum readouts (`drum.rs`, issue 8): the `drum` block of summary.json.
/// One ring of a radial profile (`drum.rs`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RadialBin {
    /// Inner radius \[m\].
    pub r_lo: f64,
    /// Outer radius \[m\].
    pub r_hi: f64,
    /// Dense cells (c >= 0.3) whose centre lies in the ring.
    pub cells: usize,
    /// Mean phihat of those cells (NaN if none).
    pub phihat: f64,
    /// Mean c of those cells (NaN if none).
    pub c: f64,
}

/// The `drum` block of summary.json.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct DrumSummary {
    /// Time window of the averages \[s\] (the last revolution, or the second half of the run
    /// if it is shorter than one revolution).
    pub window: [f64; 2],
    /// Snapshots in the window.
    pub samples: usize,
    /// Circulation centre in the lab, relative to the drum axis \[m\] (x, z).
    pub circulation_centre: [f64; 2],
    /// Its time-averaged lab speed [m/s].
    pub centre_speed: f64,
    /// Its phihat at the last output.
    pub centre_phihat: f64,
    /// Dynamic angle of repose of the free surface \[deg\], mean over the window.
    pub angle_of_repose_deg: f64,
    /// Flowing-layer thickness \[m\] (NaN if the velocity along the slope never turns).
    pub flowing_layer_thickness: f64,
    /// Window mean of the kinetic energy relative to the drum's rigid rotation, in units of
    /// the bed's solid-body kinetic energy (NaN if the drum does not turn).
    pub relative_kinetic_energy: f64,
    /// Share of that energy (summed over the window) in loose cells, `c < phi_rlp`: a free
    /// surface's partly filled cells and the dust above it (NaN if nothing moves).
    pub loose_share: f64,
    /// phihat about the circulation centre, at the last output.
    pub radial_about_centre: Vec<RadialBin>,
    /// phihat about the drum axis, at the last output.
    pub radial_about_axis: Vec<RadialBin>,
}
