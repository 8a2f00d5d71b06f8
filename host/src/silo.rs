//! Discharge through wall openings (issue 9; model.md 7.6): opening the core's wall sides
//! from a scene's outlets, and the discharge series and summary of a coupled run.
//!
//! Amounts are grain volumes (volume fraction times cell volume): per unit depth in 2D
//! (m^2, rates in m^2/s), in m^3 in 3D; multiply by the grain density for a mass. Rates are
//! averaged over each output interval (the change of the cumulative amount out over the
//! interval), so they do not depend on the step. The fines fraction of the discharge is the
//! small-grain share of what left in the interval.

use crate::error::{Error, Result};
use crate::scene::outlet::Outlet;
use crate::scene::Scene;
use serde::Serialize;
use sieve_core::boundary::{Opening, Openings};
use sieve_core::flow::coupled::Coupled;
use sieve_core::flow::FlowSide;
use sieve_core::geometry::{CutCells, Region};
use sieve_core::Real;
use std::fmt::Write as _;
use std::path::Path;

/// Opens `side` by the validated `outlet`.
pub fn open<R: Real, const D: usize>(side: &mut FlowSide<R, D>, outlet: &Outlet) {
    side.openings = Openings::one(Opening {
        lower: core::array::from_fn(|a| R::from_f64(outlet.lower[a])),
        upper: core::array::from_fn(|a| R::from_f64(outlet.upper[a])),
    });
    side.outlet = outlet.pressure;
}

/// The line a run with an outlet under the implicit pressure prints before it starts: its
/// discharge rate is not converged in the time step, and nothing in the run's own numbers
/// shows it (mass and bounds hold), so the user hears it before trusting a rate (docs/silo.md
/// section 4): +4 to +22 % above the explicit rate on the silo's 5 mm cells at
/// the shipped step (the slow branch it warned of until 2026-12-06 is gone since the outlet's
/// exit speed is part of the step, model.md 5.4). The explicit pressure needs no line since
/// 2026-12-04: its rate is the same at every Courant number to 4e-4 (5 mm cells, W = 0.04 m:
/// 9.358e-3 / 9.355e-3 / 9.354e-3 m^2/s at `flow.courant` 0.4 / 0.2 / 0.1).
fn outlet_rate_caveat(scene: &Scene) -> Option<String> {
    let flow = scene.flow.as_ref()?;
    if !scene.has_outlets() || flow.pressure != crate::scene::PressureKind::Implicit {
        return None;
    }
    Some(format!(
        "warning: {}: flow.pressure = implicit with an outlet: the discharge rate depends on the time step (+4 to +22 % above the explicit rate on the silo's 5 mm cells, docs/silo.md section 4)",
        scene.label
    ))
}

/// An opening fewer cells wide than this drains at a rate the grid sets (docs/silo.md
/// "Narrow orifices", measured on the silo scenes): an orifice in a flat floor with edges
/// along one axis (2D, or a 3D slot from wall to wall) opens between 2 and 3 cells (three
/// grids), one with edges all round (a square in 3D) between 3 and 5 cells (two grids). The
/// hopper's orifice, fed by its walls, drains below 3 cells too, at a rate that on 1 cell is
/// 1.8 times its rate on 2 and 4 cells (2.5 and 2.3 under the member wall rule; docs/silo.md
/// section 3).
pub fn min_outlet_cells(edged_axes: usize) -> f64 {
    if edged_axes >= 2 {
        5.0
    } else {
        3.0
    }
}

/// Orifices narrower than about this many grain diameters arch over and jam at random
/// times in experiments (2D hoppers: To, Lai & Pak 2001; 3D silos: Zuriguel et al. 2005, the
/// mean flow between jams grows without bound as the orifice nears about 5 diameters). The
/// continuum model has no arches and never jams.
pub const JAM_DIAMETERS: f64 = 5.0;

/// The narrowest opening of a scene: `(width [m], solver axis, how many axes the opening
/// has edges along)`, over the open widths of every outlet along the axes where it has edges
/// (a slot from wall to wall has none across the silo's depth).
fn narrowest_opening(scene: &Scene) -> Option<(f64, usize, usize)> {
    match scene.dim {
        2 => narrowest_opening_in::<2>(scene),
        3 => narrowest_opening_in::<3>(scene),
        _ => None,
    }
}

/// [`narrowest_opening`] in `D` dimensions. An outlet is open where its box meets the open
/// region of the scene's cut-cell walls (a hopper's floor outlet spans the floor; its wedges
/// leave the orifice channel): along each tangential axis `b` the width is the longest open
/// run on lines along `b` through the outlet (one per cell row across it in 3D), located as
/// the cut cells locate the walls; the opening has edges along `b` where that run ends inside
/// the box side.
fn narrowest_opening_in<const D: usize>(scene: &Scene) -> Option<(f64, usize, usize)> {
    let region = scene
        .geometry
        .as_ref()
        .map_or_else(Region::<f64, D>::new, |g| g.region::<f64, D>());
    let h = |b: usize| (scene.upper[b] - scene.lower[b]) / scene.cells[b] as f64;
    let tol = |b: usize| 1e-9 * (scene.upper[b] - scene.lower[b]);
    let mut widths: Vec<(f64, usize, usize)> = Vec::new();
    let walls = scene.flow.iter().flat_map(|f| f.walls.iter().enumerate());
    for (a, sides) in walls {
        for (high, side) in sides.iter().enumerate() {
            let Some(o) = &side.outlet else { continue };
            let face = if high == 1 {
                scene.upper[a]
            } else {
                scene.lower[a]
            };
            let mut edged = Vec::new();
            for b in (0..D).filter(|&b| b != a && o.upper[b] > o.lower[b]) {
                // lines along b: one in 2D, in 3D one per cell row of the outlet across the
                // third axis c, at the rows' centres
                let across = (0..D).find(|&c| c != a && c != b);
                let rows = across.map_or(1, |c| {
                    ((o.upper[c] - o.lower[c]) / h(c)).round().max(1.0) as usize
                });
                let pieces = ((o.upper[b] - o.lower[b]) / h(b)).ceil().max(1.0) as usize;
                let mut best = (0.0, 0.0);
                for k in 0..rows {
                    let mut x0 = [0.0; D];
                    x0[a] = face;
                    x0[b] = o.lower[b];
                    if let Some(c) = across {
                        let row = (o.upper[c] - o.lower[c]) / rows as f64;
                        x0[c] = o.lower[c] + (k as f64 + 0.5) * row;
                    }
                    let run = region.longest_open_run(x0, b, o.upper[b] - o.lower[b], pieces);
                    if run.1 > best.1 {
                        best = run;
                    }
                }
                let (start, width) = (o.lower[b] + best.0, best.1);
                if width > 0.0
                    && (start > scene.lower[b] + tol(b) || start + width < scene.upper[b] - tol(b))
                {
                    edged.push((width, b));
                }
            }
            let n = edged.len();
            widths.extend(edged.into_iter().map(|(w, b)| (w, b, n)));
        }
    }
    widths.into_iter().min_by(|a, b| a.0.total_cmp(&b.0))
}

/// The lines a run of a scene with an outlet prints before it starts, when its discharge
/// cannot be trusted as the process's: an orifice narrower than [`min_outlet_cells`] cells
/// (the rate is the grid's), one narrower than [`JAM_DIAMETERS`] grains
/// (`material.grain_diameter`: real grains would jam), and the implicit pressure's caveat
/// (`outlet_rate_caveat`). The run goes on: each is a judgement the user may overrule.
pub fn outlet_caveats(scene: &Scene) -> Vec<String> {
    let mut lines = Vec::new();
    if let Some((w, b, edged_axes)) = narrowest_opening(scene) {
        let (l, axis) = (
            &scene.label,
            crate::scene::validate::axis_names(scene.dim)[b],
        );
        let length = scene.upper[b] - scene.lower[b];
        let h = length / scene.cells[b] as f64;
        let least = min_outlet_cells(edged_axes);
        // (a width of exactly `least` cells, give or take the round-off of its edges, passes)
        if w < least * h * (1.0 - 1e-9) {
            lines.push(format!(
                "warning: {l}: the outlet is {:.2} cells wide ({} on {} cells along {axis}): below {least} cells{} the grid, not the grains, sets its discharge rate (an orifice in a flat floor barely opens; docs/silo.md \"Narrow orifices\"); refine the grid to at least {} cells along {axis}",
                w / h,
                mm(w),
                mm(h),
                if edged_axes >= 2 { " (an orifice with edges all round)" } else { "" },
                (length * least / w * (1.0 - 1e-9)).ceil(),
            ));
        }
        if let Some(d) = scene.grain_diameter {
            if w < JAM_DIAMETERS * d {
                lines.push(format!(
                    "warning: {l}: the outlet is {:.1} grain diameters wide ({}, material.grain_diameter = {}): real grains arch over and jam orifices narrower than about {JAM_DIAMETERS} diameters; the model never jams, so its discharge is what would flow if no arch formed (docs/silo.md \"Narrow orifices\")",
                    w / d,
                    mm(w),
                    mm(d),
                ));
            }
        }
    }
    lines.extend(outlet_rate_caveat(scene));
    lines
}

/// A length in mm to two decimals at most, as an orifice is quoted (`10 mm`, `9.67 mm`).
fn mm(x: f64) -> String {
    format!("{} mm", (x * 1e5).round() / 100.0)
}

/// The line `sieve run` prints for a scene with an outlet: what left, the steady rate and
/// fines fraction, and how much of the silo discharged on-spec.
pub fn outlet_line(o: &DischargeSummary, dim: usize) -> String {
    let pct = |x: f64| 100.0 * x / o.mass_initial.max(f64::MIN_POSITIVE);
    let [lo, hi] = o.fines_band;
    let spec = if o.off_spec_time.is_nan() {
        // a run that ended before the silo emptied knows a lower bound only
        format!(
            "on-spec (fines fraction in [{lo:.3}, {hi:.3}]) throughout{}, {:.1} % of the grains",
            if o.emptied { "" } else { " so far" },
            100.0 * o.on_spec_fraction
        )
    } else {
        format!(
            "on-spec (fines fraction in [{lo:.3}, {hi:.3}]) for the first {:.1} % of the grains, off-spec from t = {} s",
            100.0 * o.on_spec_fraction,
            crate::text::approx(o.off_spec_time)
        )
    };
    if !(o.out > 0.0) {
        return format!("outlet: nothing has left yet; {spec}");
    }
    let unit = match dim {
        1 => "m/s",
        2 => "m^2/s",
        _ => "m^3/s",
    };
    // a steady window needs outflow inside it: without one, say so rather than print NaN
    let steady = if o.steady_fines_fraction.is_finite() {
        format!(
            "steady rate {:.4e} {unit} with fines fraction {:.4}",
            o.steady_rate, o.steady_fines_fraction
        )
    } else {
        "no steady window yet".to_string()
    };
    format!(
        "outlet: {:.1} % of the grains out{}, {steady}; {spec}",
        pct(o.out),
        if o.emptied { " (emptied)" } else { "" },
    )
}

/// One row of `discharge.csv`, at an output time.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DischargeRow {
    /// Time \[s\].
    pub t: f64,
    /// Discharge rate over the last output interval, all grains [m^2/s in 2D].
    pub rate: f64,
    /// Discharge rate of the small grains.
    pub rate_small: f64,
    /// Small-grain fraction of what left in the last interval (NaN if nothing left).
    pub fines_fraction: f64,
    /// Grains in the box.
    pub mass: f64,
    /// Small grains in the box.
    pub mass_small: f64,
    /// Grains out so far (all outlets).
    pub out: f64,
    /// Small grains out so far.
    pub out_small: f64,
    /// Mean free-surface height over the columns \[m\] (where c first reaches
    /// [`SURFACE_LEVEL`] from above; 2D/3D; the lower box edge for an empty column).
    pub surface: f64,
    /// Share of the bed (cells with c >= [`DENSE`]) moving slower than [`STAGNANT`] of the
    /// outlet speed: the stagnant zones (model.md 7.6); NaN if nothing flows out.
    pub stagnant: f64,
    /// Mean phihat of the shear band around the stagnant zones (speed between [`STAGNANT`] and
    /// [`FLOWING`] of the outlet speed), where the V-shaped layer of fines grows.
    pub band_phihat: f64,
    /// Mean phihat of the flowing core (speed at least [`FLOWING`] of the outlet speed).
    pub core_phihat: f64,
}

/// Volume fraction of the bed for the zone readouts.
pub const DENSE: f64 = 0.3;
/// Speed, relative to the outlet speed, below which the bed counts as stagnant (issue 9: 1 %).
pub const STAGNANT: f64 = 0.01;
/// Speed, relative to the outlet speed, from which the bed counts as the flowing core.
pub const FLOWING: f64 = 0.1;

/// Volume fraction that marks the free surface.
pub const SURFACE_LEVEL: f64 = 0.2;

/// The `flow.outlet` block of summary.json.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct DischargeSummary {
    /// Grains in the box at t = 0.
    pub mass_initial: f64,
    /// Small grains in the box at t = 0.
    pub mass_small_initial: f64,
    /// Grains out at the end.
    pub out: f64,
    /// Small grains out at the end.
    pub out_small: f64,
    /// max over output times of |in box + out - initial| / initial, all grains (flow's c).
    pub mass_error: f64,
    /// The same for the small grains (carried transport).
    pub mass_small_error: f64,
    /// The steady window: from when 10 % of the grains have left to when 50 % have (or to
    /// the end of the run if fewer left; from its start if fewer than 10 % left, so a silo
    /// that never opens reads a rate of 0) \[s\]. \[0, 0\] when the run ends at the output
    /// where the tenth has left: no window yet.
    pub steady_window: [f64; 2],
    /// Mean discharge rate over the steady window; NaN without one (a rate of 0 there
    /// would read as a closed orifice).
    pub steady_rate: f64,
    /// Small-grain fraction of the discharge over the steady window.
    pub steady_fines_fraction: f64,
    /// Small-grain fraction of the discharge in the last output interval with outflow.
    pub final_fines_fraction: f64,
    /// The zones at the end of the steady window ([`DischargeRow`]): the stagnant share of
    /// the bed, and phihat in the shear band around the stagnant zones (the V-shaped layer of
    /// fines, model.md 7.6) and in the flowing core.
    pub stagnant_fraction: f64,
    /// See [`Self::stagnant_fraction`].
    pub band_phihat: f64,
    /// See [`Self::stagnant_fraction`].
    pub core_phihat: f64,
    /// True if the run stopped because the discharge ended: the box is empty (< 1e-3 of the
    /// grains left), or more than half has left and the rate fell below 1e-3 of its peak
    /// (a flat floor keeps a resting heap beside the orifice: the stagnant corners).
    pub emptied: bool,
    /// The band of the discharge's fines fraction that is on-spec: `run.fines_band`, or the
    /// bed's initial fines fraction +- [`DEFAULT_BAND_HALF_WIDTH`] (within [0, 1]).
    pub fines_band: [f64; 2],
    /// The end of the first output interval whose discharge has a fines fraction outside the
    /// band \[s\] (NaN: none until the end of the run). Intervals that discharge less than
    /// [`TRICKLE`] of the largest interval's amount are not judged: a trickle's fraction is
    /// not what the process receives.
    pub off_spec_time: f64,
    /// Share of the initial grains that left before that interval: how much of the silo
    /// discharges on-spec (all that left by the end of the run if it never left the band,
    /// a lower bound when the run ends before the silo is empty).
    pub on_spec_fraction: f64,
}

/// The first window of a discharge whose fines fraction lies outside `[lo, hi]`: `cum(k)` is
/// `[grains, fines]` out by sample `k` of `n`, the window ending at `k` spans `window`
/// samples (from `before` for the first ones), and windows that discharge nothing or less
/// than [`TRICKLE`] of the largest window are not judged. Returns the index of the window's
/// last sample. One rule for a run's on-spec readout (windows of one output interval from
/// the first sample) and for the replay's truth (`crate::soft_sensor`, windows of
/// `outflow_window` ticks from nothing).
pub fn first_off_spec(
    n: usize,
    cum: impl Fn(usize) -> [f64; 2],
    window: usize,
    before: [f64; 2],
    [lo, hi]: [f64; 2],
) -> Option<usize> {
    let w = window.max(1);
    let diff = |k: usize| {
        let [a, a_small] = cum(k);
        let [b, b_small] = if k >= w { cum(k - w) } else { before };
        [a - b, a_small - b_small]
    };
    let largest = (0..n).map(|k| diff(k)[0]).fold(0.0, f64::max);
    (0..n).find(|&k| {
        let [dq, ds] = diff(k);
        dq > 0.0 && dq >= TRICKLE * largest && !(lo..=hi).contains(&(ds / dq))
    })
}

/// Half width of the default on-spec band about the bed's initial fines fraction.
pub const DEFAULT_BAND_HALF_WIDTH: f64 = 0.1;

/// Share of the largest interval's discharge below which an interval is not judged on-spec
/// or off-spec.
pub const TRICKLE: f64 = 0.01;

/// The discharge series of a coupled run.
#[derive(Debug, Clone, Default)]
pub struct DischargeSeries {
    /// One row per output time.
    pub rows: Vec<DischargeRow>,
    initial: [f64; 2],
    errors: [f64; 2],
    peak: f64,
    /// See [`DischargeSummary::emptied`].
    pub emptied: bool,
}

impl DischargeSeries {
    /// Samples the state of `cpl` at time `t` (a box scene).
    pub fn sample<R: Real, const D: usize, const N: usize>(
        &mut self,
        t: f64,
        cpl: &Coupled<'_, R, D, N>,
    ) {
        self.sample_in(t, cpl, None);
    }

    /// Samples the state of `cpl` at time `t`; `geo` = the cut cells of a container (the
    /// hopper): the small grains in the box are then weighed by the open volume of each cell,
    /// as the flow's own mass is (model.md 6), else a cut cell's phi would count as if the
    /// whole cell were open (1.6 % of the fines on the coarse hopper).
    pub fn sample_in<R: Real, const D: usize, const N: usize>(
        &mut self,
        t: f64,
        cpl: &Coupled<'_, R, D, N>,
        geo: Option<&CutCells<R, D, N>>,
    ) {
        let fd = cpl.flow.diagnostics();
        let mass = fd.mass.to_f64();
        let mass_small = match geo {
            Some(g) => sieve_core::diagnose_embedded(cpl.seg, g),
            None => sieve_core::diagnose(cpl.seg),
        }
        .mass_small
        .to_f64();
        let sum = |s: [[R; 2]; D]| s.iter().flatten().map(|v| v.to_f64()).sum::<f64>();
        let out = sum(cpl.flow.discharged());
        let out_small = sum(cpl.discharged_small());
        let [stagnant, band_phihat, core_phihat] = zones(cpl);
        let (rate, rate_small, fines_fraction) = match self.rows.last() {
            Some(p) if t > p.t => {
                let (dq, ds) = (out - p.out, out_small - p.out_small);
                let frac = if dq > 0.0 { ds / dq } else { f64::NAN };
                ((dq) / (t - p.t), ds / (t - p.t), frac)
            }
            _ => (0.0, 0.0, f64::NAN),
        };
        self.push(DischargeRow {
            t,
            rate,
            rate_small,
            fines_fraction,
            mass,
            mass_small,
            out,
            out_small,
            surface: surface_height(cpl),
            stagnant,
            band_phihat,
            core_phihat,
        });
    }

    /// The series of these rows, as if each had been sampled in turn (a resumed run,
    /// [`crate::checkpoint`]: every running value is a function of the rows).
    pub fn from_rows(rows: Vec<DischargeRow>) -> Self {
        let mut s = Self::default();
        for r in rows {
            s.push(r);
        }
        s
    }

    /// Appends a row and updates the initial amounts, the mass errors, the peak rate and the
    /// emptied flag.
    fn push(&mut self, r: DischargeRow) {
        if self.rows.is_empty() {
            self.initial = [r.mass + r.out, r.mass_small + r.out_small];
        }
        let [m0, s0] = self.initial;
        self.errors[0] =
            self.errors[0].max((r.mass + r.out - m0).abs() / m0.max(f64::MIN_POSITIVE));
        self.errors[1] =
            self.errors[1].max((r.mass_small + r.out_small - s0).abs() / s0.max(f64::MIN_POSITIVE));
        self.rows.push(r);
        self.peak = self.peak.max(r.rate);
        if r.mass < 1e-3 * m0 || (r.out > 0.5 * m0 && r.rate < 1e-3 * self.peak) {
            self.emptied = true;
        }
    }

    /// The summary values with the default on-spec band.
    pub fn summary(&self) -> DischargeSummary {
        self.summary_with(None)
    }

    /// The summary values; `band` = `run.fines_band` (None: the default band).
    pub fn summary_with(&self, band: Option<[f64; 2]>) -> DischargeSummary {
        let [m0, s0] = self.initial;
        let band = band.unwrap_or_else(|| {
            let f0 = if m0 > 0.0 { s0 / m0 } else { 0.0 };
            [
                (f0 - DEFAULT_BAND_HALF_WIDTH).max(0.0),
                (f0 + DEFAULT_BAND_HALF_WIDTH).min(1.0),
            ]
        });
        let (off_spec_time, on_spec_out) = self.off_spec(band);
        let last = self.rows.last().copied();
        let start = self
            .rows
            .iter()
            .find(|r| r.out >= 0.1 * m0)
            .or(self.rows.first());
        let end = self
            .rows
            .iter()
            .find(|r| r.out >= 0.5 * m0)
            .or(self.rows.last());
        let zones = end.map_or([f64::NAN; 3], |r| {
            [r.stagnant, r.band_phihat, r.core_phihat]
        });
        let (window, rate, frac) = match (start, end) {
            (Some(a), Some(b)) if b.t > a.t => (
                [a.t, b.t],
                (b.out - a.out) / (b.t - a.t),
                if b.out > a.out {
                    (b.out_small - a.out_small) / (b.out - a.out)
                } else {
                    f64::NAN
                },
            ),
            _ => ([0.0, 0.0], f64::NAN, f64::NAN),
        };
        DischargeSummary {
            mass_initial: m0,
            mass_small_initial: s0,
            out: last.map_or(0.0, |r| r.out),
            out_small: last.map_or(0.0, |r| r.out_small),
            mass_error: self.errors[0],
            mass_small_error: self.errors[1],
            steady_window: window,
            steady_rate: rate,
            steady_fines_fraction: frac,
            final_fines_fraction: self
                .rows
                .iter()
                .rev()
                .find(|r| r.fines_fraction.is_finite())
                .map_or(f64::NAN, |r| r.fines_fraction),
            emptied: self.emptied,
            fines_band: band,
            off_spec_time,
            on_spec_fraction: if m0 > 0.0 { on_spec_out / m0 } else { f64::NAN },
            stagnant_fraction: zones[0],
            band_phihat: zones[1],
            core_phihat: zones[2],
        }
    }

    /// The end time of the first judged interval whose fines fraction lies outside `band`
    /// (NaN if none) and the grains out at its start (all out at the end if none).
    fn off_spec(&self, band: [f64; 2]) -> (f64, f64) {
        let cum = |k: usize| [self.rows[k].out, self.rows[k].out_small];
        // the first sample starts the first interval: its own window is empty, never judged
        let first = self.rows.first().map_or([0.0; 2], |r| [r.out, r.out_small]);
        match first_off_spec(self.rows.len(), cum, 1, first, band) {
            Some(k) => (self.rows[k].t, self.rows[k.saturating_sub(1)].out),
            None => (f64::NAN, self.rows.last().map_or(0.0, |r| r.out)),
        }
    }

    /// `discharge.csv`.
    pub fn csv(&self) -> String {
        let mut s = String::from(
            "t,rate,rate_small,fines_fraction,mass,mass_small,out,out_small,surface_height,stagnant_fraction,band_phihat,core_phihat\n",
        );
        for r in &self.rows {
            let _ = writeln!(
                s,
                "{},{},{},{},{},{},{},{},{},{},{},{}",
                r.t,
                r.rate,
                r.rate_small,
                r.fines_fraction,
                r.mass,
                r.mass_small,
                r.out,
                r.out_small,
                r.surface,
                r.stagnant,
                r.band_phihat,
                r.core_phihat
            );
        }
        s
    }
}

/// The zones of the bed at this moment (model.md 7.6): the share of the dense bed that is
/// stagnant, and the mean phihat of the shear band around the stagnant zones and of the
/// flowing core, by speed relative to the outlet speed (the largest speed of a dense cell
/// beside an open boundary face). NaN where a zone is empty or nothing flows out.
fn zones<R: Real, const D: usize, const N: usize>(cpl: &Coupled<'_, R, D, N>) -> [f64; 3] {
    let f = &cpl.flow;
    let grid = f.grid();
    let n = grid.len();
    let speed = |i: usize| {
        let u = f.velocity(i);
        u.iter()
            .map(|v| v.to_f64() * v.to_f64())
            .sum::<f64>()
            .sqrt()
    };
    let dense = |i: usize| f.c(i).to_f64() >= DENSE;
    let mut outlet = 0.0f64;
    for a in 0..D {
        for high in [false, true] {
            grid.for_each_boundary_cell(a, high, |i, _| {
                if f.open_fraction(a, high, i) > R::ZERO && dense(i) {
                    outlet = outlet.max(speed(i));
                }
            });
        }
    }
    if !(outlet > 0.0) {
        return [f64::NAN; 3];
    }
    let (mut bed, mut still) = (0usize, 0usize);
    let (mut band, mut core) = ((0.0, 0usize), (0.0, 0usize));
    for i in (0..n).filter(|&i| dense(i)) {
        bed += 1;
        let r = speed(i) / outlet;
        let phihat = (cpl.seg.phi(i) / cpl.seg.c(i)).to_f64();
        if r < STAGNANT {
            still += 1;
        } else if r < FLOWING {
            band = (band.0 + phihat, band.1 + 1);
        } else {
            core = (core.0 + phihat, core.1 + 1);
        }
    }
    let mean = |(s, k): (f64, usize)| if k > 0 { s / k as f64 } else { f64::NAN };
    let share = if bed > 0 {
        still as f64 / bed as f64
    } else {
        f64::NAN
    };
    [share, mean(band), mean(core)]
}

/// Mean over the vertical grid lines of the height where `c` first reaches
/// [`SURFACE_LEVEL`] from above (linear between cell centres).
fn surface_height<R: Real, const D: usize, const N: usize>(cpl: &Coupled<'_, R, D, N>) -> f64 {
    let grid = cpl.flow.grid();
    let cells = grid.cells();
    let nz = cells[D - 1];
    let stride = grid.stride(D - 1);
    let hz = grid.spacing()[D - 1].to_f64();
    let z0 = grid.origin()[D - 1].to_f64();
    let mut total = 0.0;
    for col in 0..stride {
        let c = |k: usize| cpl.flow.c(col + stride * k).to_f64();
        let h = match (0..nz).rev().find(|&k| c(k) >= SURFACE_LEVEL) {
            None => 0.0,
            Some(k) if k + 1 == nz => nz as f64 * hz,
            Some(k) => {
                let (lo, hi) = (c(k), c(k + 1));
                (k as f64 + 0.5 + (lo - SURFACE_LEVEL) / (lo - hi)) * hz
            }
        };
        total += h;
    }
    z0 + total / stride as f64
}

/// Reads `discharge.csv` (as [`DischargeSeries::csv`] writes it) back into rows, for the
/// pictures, which are drawn from the run's files (`sieve plot DIR` redraws them).
pub fn read_csv(path: &Path) -> Result<Vec<DischargeRow>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let bad = |line: usize| {
        Error::failure(format!(
            "{}: line {line}: not a discharge row (12 numbers)",
            path.display()
        ))
    };
    let mut rows = Vec::new();
    for (k, line) in text.lines().enumerate().skip(1) {
        let v = line
            .split(',')
            .map(|s| s.trim().parse::<f64>())
            .collect::<core::result::Result<Vec<f64>, _>>()
            .map_err(|_| bad(k + 1))?;
        let [t, rate, rate_small, fines_fraction, mass, mass_small, out, out_small, surface, stagnant, band_phihat, core_phihat] =
            v[..]
        else {
            return Err(bad(k + 1));
        };
        rows.push(DischargeRow {
            t,
            rate,
            rate_small,
            fines_fraction,
            mass,
            mass_small,
            out,
            out_small,
            surface,
            stagnant,
            band_phihat,
            core_phihat,
        });
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A row with `out` grains (of which `out_small` fines) gone from a bed of 1 (0.5 fines).
    fn row(t: f64, out: f64, out_small: f64) -> DischargeRow {
        DischargeRow {
            t,
            rate: 0.0,
            rate_small: 0.0,
            fines_fraction: f64::NAN,
            mass: 1.0 - out,
            mass_small: 0.5 - out_small,
            out,
            out_small,
            surface: 0.0,
            stagnant: f64::NAN,
            band_phihat: f64::NAN,
            core_phihat: f64::NAN,
        }
    }

    /// The first judged interval outside the band ends the on-spec discharge; a trickle (less
    /// than 1 % of the largest interval) is not judged; a run that never leaves the band is
    /// on-spec for all it let out.
    #[test]
    fn on_spec_until_the_first_judged_interval_outside_the_band() {
        // intervals: 0.2 at 0.5, 0.2 at 0.45, a trickle of 1e-3 at 0.9, 0.2 at 0.62
        let rows = [
            row(0.0, 0.0, 0.0),
            row(1.0, 0.2, 0.1),
            row(2.0, 0.4, 0.19),
            row(3.0, 0.401, 0.1909),
            row(4.0, 0.601, 0.3149),
        ];
        let s = DischargeSeries::from_rows(rows.to_vec());
        let o = s.summary();
        assert_eq!(o.fines_band, [0.4, 0.6]);
        assert_eq!(o.off_spec_time, 4.0);
        assert_eq!(o.on_spec_fraction, 0.401);
        // a narrower band is left at the 0.45 interval, after 0.2 of the grains
        let o = s.summary_with(Some([0.46, 0.55]));
        assert_eq!((o.off_spec_time, o.on_spec_fraction), (2.0, 0.2));
        // a wider one never: all that left, and no time
        let o = s.summary_with(Some([0.3, 0.7]));
        assert!(o.off_spec_time.is_nan());
        assert_eq!(o.on_spec_fraction, 0.601);
        // the line `sieve run` prints; the steady window runs from 10 % out (t = 1) to 50 %
        // (t = 4): (0.601 - 0.2) / 3 with fines (0.3149 - 0.1) / 0.401
        let o = s.summary();
        assert_eq!(
            outlet_line(&o, 2),
            "outlet: 60.1 % of the grains out, steady rate 1.3367e-1 m^2/s with fines fraction \
             0.5359; on-spec (fines fraction in [0.400, 0.600]) for the first 40.1 % of the \
             grains, off-spec from t = 4 s"
        );
        let closed = DischargeSeries::from_rows(vec![row(0.0, 0.0, 0.0), row(1.0, 0.0, 0.0)]);
        assert_eq!(
            outlet_line(&closed.summary(), 3),
            "outlet: nothing has left yet; on-spec (fines fraction in [0.400, 0.600]) \
             throughout so far, 0.0 % of the grains"
        );
        // the trickle alone would be off-spec: judged when it is the largest interval
        let s = DischargeSeries::from_rows(rows[2..4].to_vec());
        assert_eq!(s.summary_with(Some([0.0, 0.5])).off_spec_time, 3.0);
    }

    /// The narrowest opening decides: the hopper's orifice (in `[geometry]`; its floor outlet
    /// spans the whole floor), and a 3D slot's depth as well as its width.
    #[test]
    fn caveats_read_the_narrowest_opening_of_every_kind() {
        let caveats = |name: &str, sets: &[&str]| {
            let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
            let (sc, _) = crate::scene::load(name, &sets).unwrap();
            outlet_caveats(&sc)
        };
        // the defaults: the hopper's 0.04 m on 9.67 mm cells (4.1 cells, 12 d), the 3D slot
        // 6.2 cells across and from wall to wall along y (no edges there: not 4 cells)
        assert!(caveats("hopper", &[]).is_empty());
        assert!(caveats("silo-3d", &[]).is_empty());
        // a slot of 4.1 cells has edges along x alone: resolved as in 2D
        let slot = ["boundary.flow.z_low.outlet.width=[0.04,0.04]"];
        assert!(caveats("silo-3d", &slot).is_empty());
        // a square orifice of 4.1 cells is narrow in 3D (it opens between 3 and 5)
        let w = caveats(
            "silo-3d",
            &[
                "boundary.flow.z_low.outlet.width=[0.04,0.04]",
                "boundary.flow.z_low.outlet.center=[0.0725,0.0725]",
                "grid.upper=[0.145,0.145,0.5]",
                "grid.cells=[15,15,50]",
            ],
        );
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(
            w[0].contains("4.14 cells wide (40 mm on 9.67 mm cells along")
                && w[0].contains("at least 19 cells along"),
            "{w:?}"
        );
        let w = caveats("hopper", &["geometry.outlet_width=0.02"]);
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(
            w[0].contains("2.07 cells wide (20 mm on 9.67 mm cells along x)"),
            "{w:?}"
        );
        // the width is where the outlet meets the open region, not a number of the shape:
        // a floor outlet of 20 mm under the 40 mm channel is 20 mm wide (2.07 cells), one
        // of 145 mm moved right by 30 mm still opens the whole channel (4.14 cells: none),
        // one of 30 mm centred on the channel's right wall (x = 0.0925 m) opens 15 mm of it
        let floor = |c: f64, w: f64| {
            caveats(
                "hopper",
                &[&format!(
                    "boundary.flow.z_low.outlet={{center={c},width={w}}}"
                )],
            )
        };
        let w = floor(0.0725, 0.02);
        assert!(
            w.len() == 1 && w[0].contains("2.07 cells wide (20 mm"),
            "{w:?}"
        );
        assert!(floor(0.0775, 0.135).is_empty());
        let w = floor(0.0925, 0.03);
        assert!(
            w.len() == 2 && w[0].contains("1.55 cells wide (15 mm"),
            "{w:?}"
        );
        assert!(w[1].contains("4.5 grain diameters wide (15 mm"), "{w:?}");
        let w = caveats(
            "silo-3d",
            &["boundary.flow.z_low.outlet.width=[0.06,0.012]"],
        );
        assert_eq!(w.len(), 2, "{w:?}");
        assert!(
            w[0].contains("1.20 cells wide (12 mm on 10 mm cells along y)")
                && w[0].contains("below 5 cells (an orifice with edges all round)")
                && w[0].contains("at least 17 cells along y")
                && w[1].contains("3.6 grain diameters"),
            "{w:?}"
        );
    }
}
