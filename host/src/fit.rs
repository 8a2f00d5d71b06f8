//! `sieve fit`: fits the segregation rate S0 of a frozen-flow scene so that re-segregation of
//! the bed completes at a target time (model.md 7.4: the inversely graded shear cell,
//! ~700 s in the experiment of May et al. 2010), per grid.
//!
//! **Definition.** Re-segregation completes at the segregation time of `sieve run`: the first
//! time the mixing index Psi falls below the threshold (default the scene's
//! `run.psi_threshold`, 0.05) after having been at or above it (an inversely graded bed starts
//! at Psi = 0, mixes, then re-segregates), linearly interpolated between samples taken every
//! `target / 500`. Why this and not the end of the sheared layer: with S0 = 1 the shear and
//! sqrt(T) decay within ~3 mm of the top plate, only that layer re-segregates and Psi stalls
//! near 0.25-0.34 (measured), so "Psi within 5 % of its plateau" would fit a fast, partial
//! process that is not what the experiment calls complete (the whole bed re-segregated).
//! With larger S0 the slowly creeping zone below the sheared layer (T ~ 1e-13 m^2/s^2, set by
//! the creep floor of the flow's `flow.t_min`) re-segregates too and Psi falls to a plateau of
//! ~0.004 (smearing by the varying c), well below 0.05, so the threshold crossing is a sharp,
//! well-defined event. Caveat: the fitted S0 therefore depends on the quasi-static T, i.e. on
//! the regularisation `flow.t_min`; report it with the fit.
//!
//! **Method.** Per grid the flow is spun up and frozen once ([`crate::flow::spin_up`]); every
//! evaluation re-initialises only the segregation solver with a new S0. With a frozen flow the
//! segregation flux is linear in S0, so the segregation time is ~1/S0: a secant method on
//! `ln t(S0) - ln target` over `ln S0` (first step with slope -1) converges in a few
//! evaluations. An S0 whose bed has not re-segregated by `4 target` is multiplied by 4 (at most
//! 8 times); if no S0 reaches the target the level reports "not reached" and no number.

use crate::data::{Profiles, SegregationTimer, SeriesRow, Snapshot};
use crate::error::{Error, Result};
use crate::flow::{hand_over_frozen, spin_up, Frozen};
use crate::output::{num, plot, write_file, Staging};
use crate::run::{load, with_flow_solvers, FlowJob};
use crate::scene::{self, Equations, Fields, Scene};
use serde::Serialize;
use sieve_core::flow::Flow;
use sieve_core::{diagnose, Real, Segregation};
use std::fmt::Write;
use std::path::PathBuf;
use std::time::Instant;

/// Options of `sieve fit`.
#[derive(Debug, Clone)]
pub struct FitOptions {
    /// Target segregation time \[s\].
    pub target: f64,
    /// Cells along the vertical axis per grid.
    pub levels: Vec<usize>,
    /// Psi threshold (default: the scene's `run.psi_threshold`).
    pub threshold: Option<f64>,
    /// Relative tolerance on the segregation time.
    pub tolerance: f64,
    /// Output directory.
    pub out: Option<PathBuf>,
    /// No per-evaluation lines.
    pub quiet: bool,
}

/// One evaluation of the secant method.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Evaluation {
    /// S0 [s^2/m].
    pub s0: f64,
    /// Segregation time (null if not reached by `4 target`).
    pub segregation_time: Option<f64>,
    /// Segregation steps.
    pub steps: u64,
}

/// The fit on one grid.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct LevelFit {
    /// Cells along the vertical axis.
    pub level: usize,
    /// Cells per axis.
    pub cells: Vec<usize>,
    /// Fitted S0 (null if the target could not be reached).
    pub s0: Option<f64>,
    /// Segregation time with the fitted S0 (null if not reached).
    pub segregation_time: Option<f64>,
    /// `segregation_time / target - 1`.
    pub relative_error: Option<f64>,
    /// Whether |relative_error| <= tolerance.
    pub converged: bool,
    /// Flow steps to the steady state (once per grid).
    pub flow_steps_to_steady: u64,
    /// Cells of the spin-up grid.
    pub flow_cells: Vec<usize>,
    /// All evaluations, in order.
    pub evaluations: Vec<Evaluation>,
    /// Wall time of the level \[s\].
    pub wall_seconds: f64,
    /// Why there is no S0, if there is none.
    pub note: Option<String>,
}

/// The whole fit.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Fit {
    /// Scene name.
    pub scene: String,
    /// Target time \[s\].
    pub target_time: f64,
    /// Psi threshold.
    pub psi_threshold: f64,
    /// Relative tolerance.
    pub tolerance: f64,
    /// The definition of "re-segregation completes".
    pub definition: String,
    /// flow.t_min of the scene (the fit depends on the quasi-static T it sets).
    pub flow_t_min: f64,
    /// One row per grid.
    pub levels: Vec<LevelFit>,
}

struct FitJob<'a> {
    scene: &'a Scene,
    fields: &'a Fields,
    target: f64,
    threshold: f64,
    tolerance: f64,
    quiet: bool,
}

struct LevelOutcome {
    fit: LevelFit,
    psi: Vec<SeriesRow>,
    profiles: Profiles,
}

/// Steps between two looks at the interrupt flag while a fit advances to its next sample.
const FIT_CHUNK_STEPS: u64 = 10_000;

/// Runs the segregation with `s0` on the frozen flow until Psi crosses the threshold or
/// `t_max`; returns (segregation time, steps, Psi samples).
#[allow(clippy::too_many_arguments)]
fn evaluate<R: Real, const D: usize, const N: usize>(
    s: &mut Segregation<R, D, N>,
    scene: &Scene,
    fields: &Fields,
    frozen: &Frozen,
    s0: f64,
    threshold: f64,
    target: f64,
    t_max: f64,
) -> Result<(Option<f64>, u64, Vec<SeriesRow>)> {
    let mut sc = scene.clone();
    sc.s0 = s0;
    load(s, &sc, fields)?;
    hand_over_frozen(s, &sc, fields, frozen)?;
    // Refused before stepping if the window `4 target` at this S0's stable step would take more
    // cell updates than a run may (a target of 1e308 s once stepped for ever).
    let dt = s.stable_dt().to_f64();
    let steps = (t_max / dt).ceil();
    if let Err(cell_steps) = crate::estimate::cell_steps(steps, scene.len(), &scene.limits) {
        return Err(Error::range(
            "command line",
            "--target-time",
            target,
            &format!(
                "a target whose window of 4 x target takes at most {} cell updates (this one: {} at the stable step {} s with S0 = {s0:.3e}; the scene's re-segregation time sets a sensible target)",
                crate::text::approx(scene.limits.max_cell_steps),
                crate::text::approx(cell_steps),
                crate::text::approx(dt),
            ),
        ));
    }
    let mut timer = SegregationTimer::new(threshold);
    let every = target / 500.0;
    let mut rows = Vec::new();
    let mut k = 0u64;
    loop {
        crate::interrupt::check("sieve fit")?;
        let t = (k as f64 * every).min(t_max);
        // In chunks, so that a signal is seen within a chunk of steps, not only per sample.
        while s.time().to_f64() < t && s.advance_to(R::from_f64(t), FIT_CHUNK_STEPS) > 0 {
            crate::interrupt::check("sieve fit")?;
        }
        let d = diagnose(s);
        let psi = d.psi.to_f64();
        rows.push(SeriesRow {
            t,
            psi,
            mass: d.mass_small.to_f64(),
            overshoot_max: d.overshoot.to_f64(),
            undershoot_max: d.undershoot.to_f64(),
        });
        timer.sample(t, psi);
        if timer.time().is_some() || t >= t_max {
            return Ok((timer.time(), s.steps(), rows));
        }
        k += 1;
    }
}

impl FlowJob for FitJob<'_> {
    type Output = LevelOutcome;
    fn run<R: Real, const D: usize, const N: usize>(
        self,
        s: &mut Segregation<R, D, N>,
        f: &mut Flow<R, D, N>,
    ) -> Result<LevelOutcome> {
        let start = Instant::now();
        let scene = self.scene;
        let frozen = spin_up(f, scene, self.fields)?;
        let t_max = 4.0 * self.target;
        let mut evals: Vec<Evaluation> = Vec::new();
        let mut best_rows = Vec::new();
        let mut run =
            |s0: f64, evals: &mut Vec<Evaluation>| -> Result<(Option<f64>, Vec<SeriesRow>)> {
                let (t, steps, rows) = evaluate(
                    s,
                    scene,
                    self.fields,
                    &frozen,
                    s0,
                    self.threshold,
                    self.target,
                    t_max,
                )?;
                if !self.quiet {
                    eprintln!(
                        "  {:?}: S0 = {s0:.6e} -> segregation time {}, {steps} steps",
                        scene.cells,
                        t.map_or_else(|| "not reached".into(), |t| format!("{t:.3} s"))
                    );
                }
                evals.push(Evaluation {
                    s0,
                    segregation_time: t,
                    steps,
                });
                Ok((t, rows))
            };
        // Bracket: raise S0 until the bed re-segregates within t_max.
        let mut s0 = if scene.s0 > 0.0 { scene.s0 } else { 1.0 };
        let mut found = None;
        for _ in 0..=8 {
            let (t, rows) = run(s0, &mut evals)?;
            if let Some(t) = t {
                found = Some((s0, t));
                best_rows = rows;
                break;
            }
            s0 *= 4.0;
        }
        let mut note = None;
        let mut result: Option<(f64, f64)> = None;
        if let Some((s0a, ta)) = found {
            let ln_t = self.target.ln();
            let (mut x0, mut y0) = (s0a.ln(), ta.ln() - ln_t);
            let mut best = (s0a, ta);
            if (ta / self.target - 1.0).abs() > self.tolerance {
                let mut x1 = x0 + y0; // slope -1 (t ~ 1/S0)
                for _ in 0..10 {
                    let (t, rows) = run(x1.exp(), &mut evals)?;
                    let Some(t) = t else {
                        // Too slow to re-segregate by 4 target: double S0.
                        x1 += std::f64::consts::LN_2;
                        continue;
                    };
                    let y1 = t.ln() - ln_t;
                    if (t / self.target - 1.0).abs() < (best.1 / self.target - 1.0).abs() {
                        best = (x1.exp(), t);
                        best_rows = rows;
                    }
                    if (t / self.target - 1.0).abs() <= self.tolerance {
                        break;
                    }
                    let slope = if (y1 - y0).abs() > 0.0 && (x1 - x0).abs() > 0.0 {
                        ((y1 - y0) / (x1 - x0)).min(-0.2)
                    } else {
                        -1.0
                    };
                    let x2 = x1 - y1 / slope;
                    (x0, y0) = (x1, y1);
                    x1 = x2;
                }
            }
            result = Some(best);
        } else {
            note = Some(format!(
                "Psi never fell below {} by t = {} s for S0 up to {:.3e}: target not reachable",
                self.threshold,
                t_max,
                s0 / 4.0
            ));
        }
        let (s0_fit, t_fit) = match result {
            Some((s, t)) => (Some(s), Some(t)),
            None => (None, None),
        };
        let rel = t_fit.map(|t| t / self.target - 1.0);
        let converged = rel.is_some_and(|r| r.abs() <= self.tolerance);
        if !converged && note.is_none() {
            note = Some(format!(
                "no S0 within the tolerance {} after {} evaluations (best shown)",
                self.tolerance,
                evals.len()
            ));
        }
        // Profiles of the frozen flow.
        let snap = Snapshot {
            t: 0.0,
            c: frozen.c.clone(),
            phi: vec![0.0; frozen.c.len()],
            temp: frozen.t.clone(),
            u: (0..frozen.c.len())
                .map(|i| {
                    let mut u = [0.0; 3];
                    for (a, &p) in crate::scene::validate::physical_axes(D).iter().enumerate() {
                        u[p] = frozen.u[a][i];
                    }
                    u
                })
                .collect(),
            p: Some(frozen.p.clone()),
            volume: None,
        };
        Ok(LevelOutcome {
            fit: LevelFit {
                level: 0,
                cells: scene.cells.clone(),
                s0: s0_fit,
                segregation_time: t_fit,
                relative_error: rel,
                converged,
                flow_steps_to_steady: frozen.summary.flow_steps_to_steady.unwrap_or(0),
                flow_cells: frozen.summary.flow_cells.clone(),
                evaluations: evals,
                wall_seconds: start.elapsed().as_secs_f64(),
                note,
            },
            psi: best_rows,
            profiles: crate::flow::profiles(scene, &snap),
        })
    }
}

/// Runs the fit on every level and writes `fit.csv`, `fit.json` and plots to the output dir.
pub fn fit(spec: &str, sets: &[String], opts: &FitOptions) -> Result<(Fit, PathBuf)> {
    let (base, _) = scene::load(spec, sets)?;
    let fm = base
        .flow
        .as_ref()
        .filter(|m| m.equations == Equations::FrozenFlow);
    let Some(fm) = fm else {
        return Err(Error::at(
            &base.label,
            "model.equations",
            "sieve fit needs a frozen-flow scene: allowed model.equations = \"frozen-flow\"",
        ));
    };
    if !(opts.target.is_finite() && opts.target > 0.0) {
        return Err(Error::range(
            "command line",
            "--target-time",
            opts.target,
            "a time > 0 [s]",
        ));
    }
    let threshold = opts.threshold.unwrap_or(base.psi_threshold);
    if !(threshold > 0.0 && threshold < 1.0) {
        return Err(Error::range(
            "command line",
            "--threshold",
            threshold,
            "0 < threshold < 1",
        ));
    }
    if !(opts.tolerance > 0.0 && opts.tolerance < 1.0) {
        return Err(Error::range(
            "command line",
            "--tolerance",
            opts.tolerance,
            "0 < tolerance < 1",
        ));
    }
    let mut levels = if opts.levels.is_empty() {
        vec![base.cells[base.dim - 1]]
    } else {
        opts.levels.clone()
    };
    levels.sort_unstable();
    levels.dedup();
    let last = base.cells[base.dim - 1];
    let mut loaded = Vec::new();
    for &l in &levels {
        if l == 0 || base.cells.iter().any(|&b| (l * b) % last != 0) {
            return Err(Error::range(
                &base.label,
                "--levels",
                l,
                &format!("positive integers keeping the cell aspect {:?}", base.cells),
            ));
        }
        let cells: Vec<String> = base
            .cells
            .iter()
            .map(|&b| (l * b / last).to_string())
            .collect();
        let mut s = sets.to_vec();
        s.push(format!("grid.cells=[{}]", cells.join(",")));
        loaded.push(scene::load(spec, &s)?);
    }
    let out_dir = opts
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("runs").join(format!("{}-fit", base.name)));
    let staging = Staging::new(&out_dir)?;
    let mut rows = Vec::new();
    let mut psi_curves = Vec::new();
    let mut u_curves = Vec::new();
    let mut t_curves = Vec::new();
    for (&level, (scene, fields)) in levels.iter().zip(&loaded) {
        let job = FitJob {
            scene,
            fields,
            target: opts.target,
            threshold,
            tolerance: opts.tolerance,
            quiet: opts.quiet,
        };
        let mut out = with_flow_solvers(scene.precision, scene.dim, job)?;
        out.fit.level = level;
        let label = format!("{}x{}", scene.cells[0], scene.cells[scene.dim - 1]);
        if let Some(s0) = out.fit.s0 {
            psi_curves.push((
                format!("{label}, S0 = {s0:.4}"),
                out.psi.iter().map(|r| (r.t, r.psi)).collect::<Vec<_>>(),
            ));
        }
        let p = &out.profiles;
        u_curves.push((
            label.clone(),
            p.u.iter().copied().zip(p.z.iter().copied()).collect(),
        ));
        t_curves.push((
            label,
            p.t.iter().copied().zip(p.z.iter().copied()).collect(),
        ));
        rows.push(out.fit);
    }
    let fit = Fit {
        scene: base.name.clone(),
        target_time: opts.target,
        psi_threshold: threshold,
        tolerance: opts.tolerance,
        definition: format!(
            "re-segregation completes when the mixing index Psi first falls below {threshold} after having been >= {threshold} (inversely graded start: Psi = 0, mixes, re-segregates); flow spun up and frozen once per grid; S0 by secant on ln S0"
        ),
        flow_t_min: fm.t_min,
        levels: rows,
    };
    write_file(&staging.path().join("fit.csv"), csv(&fit).as_bytes())?;
    let mut json = serde_json::to_string_pretty(&fit).map_err(Error::failure)?;
    json.push('\n');
    write_file(&staging.path().join("fit.json"), json.as_bytes())?;
    let plots = staging.subdir("plots")?;
    plot::time_curves(
        &plots.join("psi_fit.png"),
        &format!("{}: Psi(t) with the fitted S0", fit.scene),
        &psi_curves,
        threshold,
    )?;
    plot::vertical_curves(
        &plots.join("flow_velocity.png"),
        &format!("{}: mean u_x(z) per grid, frozen after spin-up", fit.scene),
        "u_x [m/s]",
        &u_curves,
        false,
    )?;
    plot::vertical_curves(
        &plots.join("flow_temperature.png"),
        &format!("{}: mean T(z) per grid, frozen after spin-up", fit.scene),
        "T [m^2/s^2]",
        &t_curves,
        true,
    )?;
    let dir = staging.commit()?;
    Ok((fit, dir))
}

fn opt(x: Option<f64>) -> String {
    x.map_or_else(String::new, num)
}

/// fit.csv: `level,cells,s0,segregation_time,relative_error,converged,evaluations,flow_steps_to_steady,wall_seconds`.
pub fn csv(fit: &Fit) -> String {
    let mut s = String::from(
        "level,cells,s0,segregation_time,relative_error,converged,evaluations,flow_steps_to_steady,wall_seconds\n",
    );
    for r in &fit.levels {
        let cells: Vec<String> = r.cells.iter().map(|c| c.to_string()).collect();
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{},{}",
            r.level,
            cells.join("x"),
            opt(r.s0),
            opt(r.segregation_time),
            opt(r.relative_error),
            r.converged,
            r.evaluations.len(),
            r.flow_steps_to_steady,
            num(r.wall_seconds)
        );
    }
    s
}

/// The table printed on stdout.
pub fn table(fit: &Fit) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# {}: S0 fitted to a segregation time of {} s",
        fit.scene, fit.target_time
    );
    let _ = writeln!(s, "# definition: {}", fit.definition);
    let _ = writeln!(
        s,
        "{:>6} {:>9} {:>13} {:>12} {:>9} {:>5} {:>11} {:>8}",
        "level", "cells", "S0 [s^2/m]", "t_seg [s]", "rel_err", "evals", "flow_steps", "wall_s"
    );
    for r in &fit.levels {
        let cells: Vec<String> = r.cells.iter().map(|c| c.to_string()).collect();
        let _ = writeln!(
            s,
            "{:>6} {:>9} {:>13} {:>12} {:>9} {:>5} {:>11} {:>8.2}",
            r.level,
            cells.join("x"),
            r.s0.map_or_else(|| "NOT REACHED".into(), |v| format!("{v:.6}")),
            r.segregation_time
                .map_or_else(|| "-".into(), |v| format!("{v:.3}")),
            r.relative_error
                .map_or_else(|| "-".into(), |v| format!("{v:+.2e}")),
            r.evaluations.len(),
            r.flow_steps_to_steady,
            r.wall_seconds
        );
        if let Some(n) = &r.note {
            let _ = writeln!(s, "#   {}: {n}", cells.join("x"));
        }
    }
    s
}
