//! `sieve converge`: runs a scene on a sequence of grids and tabulates the errors of phihat at
//! `t_end` (L1, L2, Linf) with observed orders and wall times, a work-precision table, and the
//! scene's readouts (Psi at `t_end`; the flow's largest speed and temperature; a silo's
//! discharge rate and fines fractions; a drum's angle of repose, flowing layer and fines core)
//! on every grid with their grid error from the three finest ([`crate::grid_error`]).
//!
//! A level `L` is the number of cells along the vertical (last) axis; the other axes keep the
//! scene's cell aspect (`cells_a = L * cells_a / cells_last`). The reference is the exact
//! solution where the scene names one (`run.exact = "column-a"`: exact cell averages at
//! `t_end`), else the finest level restricted to each coarser grid by mass-weighted averaging
//! (`phihat = sum phi / sum c` over the fine cells of a coarse cell), which needs nested grids.
//! Norms: `L1 = sum |e| |C|`, `L2 = sqrt(sum e^2 |C|)`, `Linf = max |e|`. Scenes with cut
//! cells (drums, hoppers) compare readouts only: their cells' open volumes differ from grid
//! to grid, so a cell-by-cell restriction of phihat would compare different volumes.

use crate::data::{DrumSummary, FlowSummary, LoopStats, Snapshot};
use crate::error::{Error, Result};
use crate::grid_error::{self, Behaviour, Estimate};
use crate::output::{num, write_file, Staging};
use crate::run::{load, time_loop, SolverJob};
use crate::scene::{self, Fields, Scene};
use serde::Serialize;
use sieve_core::{Real, Segregation};
use std::fmt::Write;
use std::path::PathBuf;
use std::time::Instant;

/// Options of `sieve converge`.
#[derive(Debug, Clone)]
pub struct ConvergeOptions {
    /// Cells along the vertical axis, one run per level.
    pub levels: Vec<usize>,
    /// Output directory for converge.csv / converge.json.
    pub out: Option<PathBuf>,
    /// No progress bars.
    pub quiet: bool,
}

/// One row of the table.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct LevelRow {
    /// Cells along the vertical axis.
    pub level: usize,
    /// Cells per axis.
    pub cells: Vec<usize>,
    /// L1 error (None for the finest level when it is the reference).
    pub l1: Option<f64>,
    /// L2 error.
    pub l2: Option<f64>,
    /// Linf error.
    pub linf: Option<f64>,
    /// Observed L1 order against the previous level.
    pub order_l1: Option<f64>,
    /// Observed L2 order.
    pub order_l2: Option<f64>,
    /// Observed Linf order.
    pub order_linf: Option<f64>,
    /// Steps taken.
    pub steps: u64,
    /// Wall time of the level (set-up and time stepping, no output) \[s\].
    pub wall_seconds: f64,
}

/// The whole study.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Study {
    /// Scene name.
    pub scene: String,
    /// Face flux.
    pub scheme: String,
    /// Quantity compared.
    pub quantity: String,
    /// What the errors are measured against.
    pub reference: String,
    /// End time.
    pub t_end: f64,
    /// One row per level, coarse to fine.
    pub levels: Vec<LevelRow>,
    /// The scene's readouts on every level and their grid error.
    pub readouts: Vec<ReadoutRow>,
}

/// One readout of the scene on every level.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct ReadoutRow {
    /// Its key in summary.json (`psi_final`, `flow.outlet.steady_rate`, ...).
    pub name: String,
    /// Its value per level, coarse to fine (`None` where a level does not have it, e.g. a
    /// segregation time not reached).
    pub values: Vec<Option<f64>>,
    /// What the three finest levels say about its grid error.
    pub estimate: Estimate,
}

struct LevelRun {
    phi: Vec<f64>,
    c: Vec<f64>,
    steps: u64,
    readouts: Vec<(&'static str, f64)>,
}

/// The snapshots a drum's readouts are measured from ([`crate::drum`]), kept in memory as the
/// bytes `sieve run` writes and reads back, so that the readouts are the run's.
struct DrumWindow<'a> {
    scene: &'a Scene,
    volume: Option<Vec<f64>>,
    kept: Vec<(f64, crate::output::vtk::Vti)>,
    /// Output times of the run, for `[output] vtk_every` (a run measures only the snapshots
    /// it writes).
    outputs: usize,
}

impl<'a> DrumWindow<'a> {
    fn new(scene: &'a Scene, volume: Option<Vec<f64>>) -> Self {
        Self {
            scene,
            volume,
            kept: Vec::new(),
            outputs: crate::data::output_times(scene.t_end, scene.output_interval).len(),
        }
    }

    /// Keeps the snapshot of output `k` at time `t` if a run writes it (drums only; `snap`
    /// is taken only then), dropping those no later window needs.
    fn keep(&mut self, k: usize, t: f64, snap: impl FnOnce() -> Snapshot) -> Result<()> {
        let Some(from) = crate::drum::needed_from(self.scene, t) else {
            return Ok(());
        };
        if !self.scene.output.writes(k, self.outputs) {
            return Ok(());
        }
        self.kept.retain(|(tk, _)| *tk >= from);
        let mut snap = snap();
        snap.volume = self.volume.clone();
        let bytes = crate::output::vtk::vti_bytes(self.scene, &snap);
        let vti = crate::output::vtk::vti_from_bytes(&bytes, "snapshot")?;
        self.kept.push((t, vti));
        Ok(())
    }

    fn summary(self) -> Option<DrumSummary> {
        let t_last = self.kept.last()?.0;
        let t0 = crate::drum::window_start(self.scene, t_last)?;
        let window = self
            .kept
            .into_iter()
            .filter(|(t, _)| *t >= t0)
            .map(|(_, v)| v)
            .collect();
        crate::drum::analyse_snapshots(self.scene, t_last, window)
    }
}

/// The readouts of a finished level, under their summary.json keys: what `sieve run` of the
/// same grid reports, from the same statistics.
fn readouts(
    stats: &LoopStats,
    flow: Option<&FlowSummary>,
    drum: Option<&DrumSummary>,
) -> Vec<(&'static str, f64)> {
    let mut r = Vec::new();
    if let Some(last) = stats.series.last() {
        r.push(("psi_final", last.psi));
    }
    if let Some(t) = stats.segregation_time {
        r.push(("segregation_time", t));
    }
    if let Some(f) = flow {
        r.push(("flow.max_speed", f.max_speed));
        r.push(("flow.t_max", f.t_max));
        r.push(("flow.kinetic_energy", f.kinetic_energy));
        if let Some(o) = &f.outlet {
            r.extend([
                ("flow.outlet.out", o.out),
                ("flow.outlet.steady_rate", o.steady_rate),
                ("flow.outlet.steady_fines_fraction", o.steady_fines_fraction),
                ("flow.outlet.final_fines_fraction", o.final_fines_fraction),
                ("flow.outlet.stagnant_fraction", o.stagnant_fraction),
                ("flow.outlet.band_phihat", o.band_phihat),
                ("flow.outlet.core_phihat", o.core_phihat),
                ("flow.outlet.off_spec_time", o.off_spec_time),
                ("flow.outlet.on_spec_fraction", o.on_spec_fraction),
            ]);
        }
    }
    if let Some(d) = drum {
        r.extend([
            ("drum.angle_of_repose_deg", d.angle_of_repose_deg),
            ("drum.flowing_layer_thickness", d.flowing_layer_thickness),
            ("drum.centre_phihat", d.centre_phihat),
            ("drum.centre_speed", d.centre_speed),
            ("drum.relative_kinetic_energy", d.relative_kinetic_energy),
            ("drum.loose_share", d.loose_share),
        ]);
    }
    // a value the level does not have (no steady window yet, no surface to fit) is NaN in
    // the summary: left out here, `-` in the table
    r.retain(|(_, v)| v.is_finite());
    r
}

fn level_run<R: Real, const D: usize, const N: usize>(
    s: &Segregation<R, D, N>,
    stats: &LoopStats,
    flow: Option<&FlowSummary>,
    drum: DrumWindow<'_>,
) -> LevelRun {
    let n = s.len();
    LevelRun {
        phi: (0..n).map(|i| s.phi(i).to_f64()).collect(),
        c: (0..n).map(|i| s.c(i).to_f64()).collect(),
        steps: stats.steps,
        readouts: readouts(stats, flow, drum.summary().as_ref()),
    }
}

struct ConvergeJob<'a> {
    scene: &'a Scene,
    fields: &'a Fields,
}

impl SolverJob for ConvergeJob<'_> {
    type Output = LevelRun;
    fn run<R: Real, const D: usize, const N: usize>(
        self,
        s: &mut Segregation<R, D, N>,
    ) -> Result<LevelRun> {
        load(s, self.scene, self.fields)?;
        let geo = crate::embedded::build(s, self.scene)?;
        let geo = geo.as_deref();
        if let Some(g) = geo {
            crate::embedded::prepare(s, self.scene, g)?;
        }
        let bar = crate::progress::Progress::hidden();
        let mut drum = DrumWindow::new(self.scene, geo.map(crate::embedded::volumes));
        // Same output stops as `sieve run`, so a level reproduces the run of that grid.
        let stats = time_loop(s, self.scene, &bar, geo, |k, t, s| {
            drum.keep(k, t, || Snapshot::of(s, self.scene))
        })?;
        Ok(level_run(s, &stats, None, drum))
    }
}

impl crate::run::FlowJob for ConvergeJob<'_> {
    type Output = LevelRun;
    fn run<R: Real, const D: usize, const N: usize>(
        self,
        s: &mut Segregation<R, D, N>,
        f: &mut sieve_core::flow::Flow<R, D, N>,
    ) -> Result<LevelRun> {
        use crate::scene::Equations;
        load(s, self.scene, self.fields)?;
        // a container: coupled scenes only (validation refuses a frozen flow with one)
        let geo = crate::embedded::build(s, self.scene)?;
        let bar = crate::progress::Progress::hidden();
        let coupled = self.scene.flow.as_ref().map(|m| m.equations) == Some(Equations::Coupled);
        let mut drum = DrumWindow::new(self.scene, geo.as_deref().map(crate::embedded::volumes));
        if coupled {
            let cs = crate::flow::coupled_loop(
                f,
                s,
                self.scene,
                self.fields,
                geo.as_deref(),
                &bar,
                // the drum readouts read c, phihat and u: the pressure is not taken
                |k, t, s, _| drum.keep(k, t, || Snapshot::of(s, self.scene)),
            )?;
            Ok(level_run(s, &cs.stats, Some(&cs.summary), drum))
        } else {
            let frozen = crate::flow::spin_up(f, self.scene, self.fields)?;
            crate::flow::hand_over_frozen(s, self.scene, self.fields, &frozen)?;
            let stats = time_loop(s, self.scene, &bar, None, |_, _, _| Ok(()))?;
            Ok(level_run(s, &stats, Some(&frozen.summary), drum))
        }
    }
}

fn cells_for(level: usize, base: &[usize], label: &str) -> Result<Vec<usize>> {
    let last = *base.last().unwrap_or(&1);
    base.iter()
        .map(|&b| {
            // a hostile level must not overflow (a panic with overflow checks, a wrong
            // aspect without); no axis holds more cells than `grid.cells` allows anyway
            let max = crate::scene::validate::MAX_AXIS_CELLS;
            let Some(product) = level.checked_mul(b).filter(|_| level <= max) else {
                return Err(Error::range(
                    label,
                    "--levels",
                    level,
                    &format!("integer 1..={max} (cells along the vertical axis)"),
                ));
            };
            if !product.is_multiple_of(last) {
                Err(Error::at(
                    label,
                    "--levels",
                    format!(
                        "level {level} does not keep the cell aspect {base:?}: allowed multiples of {}",
                        last / gcd(last, b)
                    ),
                ))
            } else {
                Ok(product / last)
            }
        })
        .collect()
}

/// A level's bad input or numerical failure, saying which level: a grid can be too coarse
/// for the scene (a drum of fewer than two cells of radius, an orifice narrower than a cell).
fn on_level(e: Error, level: usize, cells: &[usize]) -> Error {
    let say = |m: String| format!("{m} (on level {level}, {} cells)", cells_text(cells));
    match e {
        Error::Input(m) => Error::Input(say(m)),
        Error::Numerical(m) => Error::Numerical(say(m)),
        e => e,
    }
}

fn gcd(a: usize, b: usize) -> usize {
    if b == 0 {
        a
    } else {
        gcd(b, a % b)
    }
}

fn norms(err: &[f64], vol: f64) -> (f64, f64, f64) {
    let l1 = err.iter().map(|e| e.abs()).sum::<f64>() * vol;
    let l2 = (err.iter().map(|e| e * e).sum::<f64>() * vol).sqrt();
    let linf = err.iter().fold(0.0f64, |m, e| m.max(e.abs()));
    (l1, l2, linf)
}

/// Mass-weighted restriction of a fine solution to a coarse grid: phihat of each coarse cell.
fn restrict(fine: &LevelRun, fine_cells: &[usize], coarse_cells: &[usize]) -> Vec<f64> {
    let dim = fine_cells.len();
    let n: usize = coarse_cells.iter().product();
    let mut phi = vec![0.0; n];
    let mut c = vec![0.0; n];
    for i in 0..fine.phi.len() {
        let mut rest = i;
        let mut j = 0;
        let mut stride = 1;
        for a in 0..dim {
            let k = rest % fine_cells[a];
            rest /= fine_cells[a];
            j += (k / (fine_cells[a] / coarse_cells[a])) * stride;
            stride *= coarse_cells[a];
        }
        phi[j] += fine.phi[i];
        c[j] += fine.c[i];
    }
    phi.iter()
        .zip(&c)
        .map(|(&p, &c)| if c > 0.0 { p / c } else { 0.0 })
        .collect()
}

fn phihat(r: &LevelRun) -> Vec<f64> {
    r.phi
        .iter()
        .zip(&r.c)
        .map(|(&p, &c)| if c > 1e-6 { p / c } else { 0.0 })
        .collect()
}

/// Column a's default `t_end` (1.5) lies after the shocks meet at `t = H / S` (model.md 7.1a):
/// from then on the exact state is fully segregated and every grid reaches it, so the errors
/// are round-off (1e-14) and the orders meaningless. Without `--t-end` (no `run.t_end` among
/// `sets`) the study then measures at half that time, with a note; with it, a one-line
/// warning. Returns the `t_end` to use, if changed.
fn before_completion(spec: &str, sets: &[String], quiet: bool) -> Result<Option<f64>> {
    let (scene, fields) = scene::load(spec, sets)?;
    let Some(ex) = scene.column_a(&fields) else {
        return Ok(None);
    };
    let done = ex.segregation_time(0.0);
    if scene.t_end < done {
        return Ok(None);
    }
    let given = sets
        .iter()
        .any(|s| s.split('=').next().is_some_and(|k| k.trim() == "run.t_end"));
    if given {
        if !quiet {
            eprintln!(
                "warning: {}: run.t_end = {} is after segregation completes (t = {done}): every grid reaches the fully segregated state, so errors are round-off and orders meaningless; choose --t-end below {done}",
                scene.label, scene.t_end
            );
        }
        return Ok(None);
    }
    let t = done / 2.0;
    if !quiet {
        eprintln!(
            "note: {}: run.t_end = {} is after segregation completes (t = {done}), where every grid reaches the same state; measuring at t_end = {t} instead (give --t-end to choose)",
            scene.label, scene.t_end
        );
    }
    Ok(Some(t))
}

/// Runs the study and writes `converge.csv` and `converge.json` to the output directory.
pub fn converge(spec: &str, sets: &[String], opts: &ConvergeOptions) -> Result<(Study, PathBuf)> {
    let mut sets = sets.to_vec();
    if let Some(t) = before_completion(spec, &sets, opts.quiet)? {
        sets.push(format!("run.t_end={t}"));
    }
    let sets = &sets[..];
    let (base, _) = scene::load(spec, sets)?;
    // cut cells: readouts only (module docs)
    let fields_compared = base.geometry.is_none();
    let mut levels = opts.levels.clone();
    levels.sort_unstable();
    levels.dedup();
    if levels.is_empty() || levels[0] == 0 {
        return Err(Error::at(
            &base.label,
            "--levels",
            "allowed: a list of positive integers",
        ));
    }
    let grids: Vec<Vec<usize>> = levels
        .iter()
        .map(|&l| cells_for(l, &base.cells, &base.label))
        .collect::<Result<_>>()?;
    let exact = base.exact.is_some();
    let finest = grids.last().cloned().unwrap_or_default();
    if !exact {
        if levels.len() < 2 {
            let why = if fields_compared {
                "without an exact solution the finest level is the reference: give at least 2 levels"
            } else {
                "a study compares levels: give at least 2 levels (3 for an order of convergence)"
            };
            return Err(Error::at(&base.label, "--levels", why));
        }
        for (l, g) in levels.iter().zip(&grids) {
            if fields_compared && g.iter().zip(&finest).any(|(c, f)| f % c != 0) {
                return Err(Error::at(
                    &base.label,
                    "--levels",
                    format!(
                        "level {l} is not nested in the finest level {}: allowed divisors of it",
                        levels.last().copied().unwrap_or(0)
                    ),
                ));
            }
        }
    }
    // Validate every level before running any, so bad input fails fast with code 2.
    let mut scenes = Vec::with_capacity(levels.len());
    for g in &grids {
        let mut s = sets.to_vec();
        s.push(format!(
            "grid.cells=[{}]",
            g.iter()
                .map(|c| c.to_string())
                .collect::<Vec<_>>()
                .join(",")
        ));
        scenes.push(s);
    }
    let mut loaded = Vec::with_capacity(levels.len());
    for ((s, l), g) in scenes.iter().zip(&levels).zip(&grids) {
        loaded.push(scene::load(spec, s).map_err(|e| on_level(e, *l, g))?);
    }
    let out_dir = opts
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("runs").join(format!("{}-converge", base.name)));
    let staging = Staging::new(&out_dir)?;
    let mut runs = Vec::with_capacity(levels.len());
    for (scene, fields) in &loaded {
        let start = Instant::now();
        let job = ConvergeJob { scene, fields };
        let level = scene.cells[scene.dim - 1];
        let r = crate::run::with_scene_solvers(scene, job)
            .map_err(|e| on_level(e, level, &scene.cells))?;
        let secs = start.elapsed().as_secs_f64();
        if !opts.quiet {
            eprintln!("level {:?}: {} steps, {:.3} s", scene.cells, r.steps, secs);
        }
        runs.push((r, secs));
    }
    let mut rows: Vec<LevelRow> = Vec::with_capacity(levels.len());
    for (idx, ((scene, fields), (run, secs))) in loaded.iter().zip(&runs).enumerate() {
        let vol: f64 = scene.spacing().iter().product();
        let computed = phihat(run);
        let reference: Option<Vec<f64>> = if let Some(ex) = scene.column_a(fields) {
            let h = scene.spacing()[0];
            Some(
                (0..scene.len())
                    .map(|i| ex.phihat_cell_average(i as f64 * h, (i + 1) as f64 * h, scene.t_end))
                    .collect(),
            )
        } else if fields_compared && idx + 1 < levels.len() {
            Some(restrict(&runs[levels.len() - 1].0, &finest, &scene.cells))
        } else {
            None
        };
        let errs = reference.map(|r| {
            let e: Vec<f64> = computed.iter().zip(&r).map(|(a, b)| a - b).collect();
            norms(&e, vol)
        });
        let order = |prev: Option<f64>, cur: Option<f64>| -> Option<f64> {
            let prev_level = rows.last()?.level as f64;
            match (prev, cur) {
                (Some(p), Some(c)) if p > 0.0 && c > 0.0 => {
                    Some((p / c).ln() / (levels[idx] as f64 / prev_level).ln())
                }
                _ => None,
            }
        };
        let prev = rows.last().map(|r| (r.l1, r.l2, r.linf));
        let (l1, l2, linf) = match errs {
            Some((a, b, c)) => (Some(a), Some(b), Some(c)),
            None => (None, None, None),
        };
        let row = LevelRow {
            level: levels[idx],
            cells: scene.cells.clone(),
            l1,
            l2,
            linf,
            order_l1: order(prev.and_then(|p| p.0), l1),
            order_l2: order(prev.and_then(|p| p.1), l2),
            order_linf: order(prev.and_then(|p| p.2), linf),
            steps: run.steps,
            wall_seconds: *secs,
        };
        rows.push(row);
    }
    let errors: Vec<f64> = rows.iter().filter_map(|r| r.l1).collect();
    if !opts.quiet && !errors.is_empty() && errors.iter().all(|&e| e < 1e-12) {
        eprintln!(
            "warning: {}: every L1 error is below 1e-12 at t_end = {}: the grids reach the same final state (fully segregated or steady), so these orders say nothing about accuracy; choose an earlier --t-end",
            base.label, base.t_end
        );
    }
    let loaded_cell_sizes: Vec<f64> = loaded.iter().map(|(s, _)| s.spacing()[s.dim - 1]).collect();
    let level_runs: Vec<&LevelRun> = runs.iter().map(|(r, _)| r).collect();
    let study = Study {
        scene: base.name.clone(),
        scheme: base.scheme.name().into(),
        quantity: "phihat at t_end".into(),
        reference: if exact {
            "exact solution column-a (cell averages)".into()
        } else if !fields_compared {
            "none: cut cells, whose open volumes differ between grids (readouts only)".into()
        } else {
            format!(
                "finest level {} (mass-weighted restriction)",
                levels[levels.len() - 1]
            )
        },
        t_end: base.t_end,
        levels: rows,
        readouts: readout_rows(&levels, &level_runs),
    };
    write_file(&staging.path().join("converge.csv"), csv(&study).as_bytes())?;
    write_file(
        &staging.path().join("readouts.csv"),
        readouts_csv(&study).as_bytes(),
    )?;
    if fields_compared {
        draw(
            &study,
            &loaded_cell_sizes,
            &staging.path().join("converge.png"),
        )?;
    }
    if !study.readouts.is_empty() {
        draw_readouts(
            &study,
            &loaded_cell_sizes,
            &staging.path().join("readouts.png"),
        )?;
    }
    let mut json = serde_json::to_string_pretty(&study).map_err(Error::failure)?;
    json.push('\n');
    write_file(&staging.path().join("converge.json"), json.as_bytes())?;
    let dir = staging.commit()?;
    Ok((study, dir))
}

/// Every readout any level has, in the order the levels report them, with its values per
/// level and the grid error of the three finest.
fn readout_rows(levels: &[usize], runs: &[&LevelRun]) -> Vec<ReadoutRow> {
    let mut names: Vec<&'static str> = Vec::new();
    for r in runs {
        for (name, _) in &r.readouts {
            if !names.contains(name) {
                names.push(name);
            }
        }
    }
    names
        .into_iter()
        .map(|name| {
            let values: Vec<Option<f64>> = runs
                .iter()
                .map(|r| r.readouts.iter().find(|(n, _)| *n == name).map(|(_, v)| *v))
                .collect();
            let pairs: Vec<(usize, f64)> = levels
                .iter()
                .zip(&values)
                .filter_map(|(&l, v)| Some((l, (*v)?)))
                .collect();
            ReadoutRow {
                name: name.into(),
                values,
                estimate: grid_error::estimate(&pairs),
            }
        })
        .collect()
}

/// readouts.csv: one row per readout, its value on every level (columns `level_L`), then what
/// the three finest say, `behaviour,order,extrapolated,error_finest,gci_finest`, and the
/// check by the next-coarser three, `coarser_behaviour,coarser_order,asymptotic` (`yes`, `no`,
/// empty: fewer than four levels, or no order to check).
pub fn readouts_csv(study: &Study) -> String {
    let mut s = String::from("readout");
    for r in &study.levels {
        let _ = write!(s, ",level_{}", r.level);
    }
    s.push_str(",behaviour,order,extrapolated,error_finest,gci_finest");
    s.push_str(",coarser_behaviour,coarser_order,asymptotic\n");
    for r in &study.readouts {
        s.push_str(&r.name);
        for v in &r.values {
            let _ = write!(s, ",{}", opt(*v));
        }
        let e = &r.estimate;
        let _ = writeln!(
            s,
            ",{},{},{},{},{},{},{},{}",
            e.behaviour.name(),
            opt(e.order),
            opt(e.extrapolated),
            opt(e.error_finest),
            opt(e.gci_finest),
            e.coarser_behaviour.map_or("", Behaviour::name),
            opt(e.coarser_order),
            yes_no(e.asymptotic),
        );
    }
    s
}

/// readouts.png: every readout against the vertical cell size, with its extrapolated value.
fn draw_readouts(study: &Study, h: &[f64], path: &std::path::Path) -> Result<()> {
    let panels: Vec<crate::output::plot::ReadoutPanel> = study
        .readouts
        .iter()
        .map(|r| {
            let e = &r.estimate;
            crate::output::plot::ReadoutPanel {
                name: r.name.clone(),
                points: h
                    .iter()
                    .zip(&r.values)
                    .filter_map(|(&h, v)| Some((h, (*v)?)))
                    .collect(),
                extrapolated: e.extrapolated,
                caption: match (e.order, e.gci_finest) {
                    (Some(p), Some(g)) => {
                        format!(
                            "{}, order {p:.2}, GCI {:.2} %",
                            e.behaviour.name(),
                            100.0 * g
                        )
                    }
                    (Some(p), None) => format!("{}, order {p:.2}", e.behaviour.name()),
                    _ => e.behaviour.name().into(),
                } + if e.asymptotic == Some(false) {
                    " (not shown asymptotic)"
                } else {
                    ""
                },
            }
        })
        .collect();
    crate::output::plot::readouts(
        path,
        &format!(
            "{}: readouts at t_end = {} on every level (orange: extrapolated to h = 0)",
            study.scene,
            num(study.t_end)
        ),
        &panels,
    )
}

/// converge.png: the work-precision picture, L1 error against the vertical cell size h (with
/// the observed order of the finest pair) and against wall time.
fn draw(study: &Study, h: &[f64], path: &std::path::Path) -> Result<()> {
    let rows: Vec<(f64, f64, f64)> = study
        .levels
        .iter()
        .zip(h)
        .filter_map(|(r, &h)| Some((h, r.l1?, r.wall_seconds)))
        .collect();
    let order = study.levels.iter().rev().find_map(|r| r.order_l1);
    crate::output::plot::work_precision(
        path,
        &format!(
            "{} ({}): error of {} against {}",
            study.scene, study.scheme, study.quantity, study.reference
        ),
        "L1",
        &rows,
        order,
    )
}

fn yes_no(x: Option<bool>) -> &'static str {
    match x {
        Some(true) => "yes",
        Some(false) => "no",
        None => "",
    }
}

fn opt(x: Option<f64>) -> String {
    x.map_or_else(String::new, num)
}

fn cells_text(c: &[usize]) -> String {
    c.iter()
        .map(|n| n.to_string())
        .collect::<Vec<_>>()
        .join("x")
}

/// converge.csv: header `level,cells,l1,l2,linf,order_l1,order_l2,order_linf,steps,wall_seconds`.
pub fn csv(study: &Study) -> String {
    let mut s =
        String::from("level,cells,l1,l2,linf,order_l1,order_l2,order_linf,steps,wall_seconds\n");
    for r in &study.levels {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{},{},{}",
            r.level,
            cells_text(&r.cells),
            opt(r.l1),
            opt(r.l2),
            opt(r.linf),
            opt(r.order_l1),
            opt(r.order_l2),
            opt(r.order_linf),
            r.steps,
            num(r.wall_seconds)
        );
    }
    s
}

/// The table printed on stdout.
pub fn table(study: &Study) -> String {
    let mut s = String::new();
    let e = |x: Option<f64>| x.map_or_else(|| "-".into(), |v| format!("{v:.4e}"));
    let o = |x: Option<f64>| x.map_or_else(|| "-".into(), |v| format!("{v:.2}"));
    let fields_compared = study
        .levels
        .iter()
        .any(|r| r.l1.is_some() || r.l2.is_some() || r.linf.is_some());
    if fields_compared {
        let _ = writeln!(
            s,
            "# {} scheme={} error of {} against {}",
            study.scene, study.scheme, study.quantity, study.reference
        );
        let _ = writeln!(
            s,
            "{:>7} {:>11} {:>11} {:>11} {:>11} {:>6} {:>6} {:>6} {:>8} {:>9}",
            "level", "cells", "L1", "L2", "Linf", "p_L1", "p_L2", "p_Linf", "steps", "wall_s"
        );
        for r in &study.levels {
            let _ = writeln!(
                s,
                "{:>7} {:>11} {:>11} {:>11} {:>11} {:>6} {:>6} {:>6} {:>8} {:>9.4}",
                r.level,
                cells_text(&r.cells),
                e(r.l1),
                e(r.l2),
                e(r.linf),
                o(r.order_l1),
                o(r.order_l2),
                o(r.order_linf),
                r.steps,
                r.wall_seconds
            );
        }
    } else {
        // no field is compared (cut cells): the levels, without columns of "-"
        let _ = writeln!(
            s,
            "# {} scheme={} fields compared against {}",
            study.scene, study.scheme, study.reference
        );
        let _ = writeln!(
            s,
            "{:>7} {:>11} {:>8} {:>9}",
            "level", "cells", "steps", "wall_s"
        );
        for r in &study.levels {
            let _ = writeln!(
                s,
                "{:>7} {:>11} {:>8} {:>9.4}",
                r.level,
                cells_text(&r.cells),
                r.steps,
                r.wall_seconds
            );
        }
    }
    if study.readouts.is_empty() {
        return s;
    }
    let _ = writeln!(
        s,
        "# readouts per level; grid error from the three finest (Richardson, GCI of the finest); \
         asymptotic: the next-coarser three converge at an order within {:.0} % (its order if not)",
        100.0 * grid_error::ORDER_AGREEMENT
    );
    let _ = write!(s, "{:>34}", "readout");
    for r in &study.levels {
        let _ = write!(s, " {:>11}", r.level);
    }
    let _ = writeln!(
        s,
        " {:>13} {:>6} {:>12} {:>9} {:>10}",
        "behaviour", "order", "extrapolated", "GCI", "asymptotic"
    );
    for r in &study.readouts {
        let _ = write!(s, "{:>34}", r.name);
        for v in &r.values {
            let _ = write!(s, " {:>11}", e(*v));
        }
        let est = &r.estimate;
        let gci = est
            .gci_finest
            .map_or_else(|| "-".into(), |g| format!("{:.2}%", 100.0 * g));
        let asymptotic = match (est.asymptotic, est.coarser_order) {
            (None, _) => "-".to_string(),
            (Some(true), _) => "yes".into(),
            (Some(false), Some(q)) => format!("no ({q:.2})"),
            (Some(false), None) => format!(
                "no ({})",
                est.coarser_behaviour.map_or("-", Behaviour::name)
            ),
        };
        let _ = writeln!(
            s,
            " {:>13} {:>6} {:>12} {:>9} {:>10}",
            est.behaviour.name(),
            o(est.order),
            e(est.extrapolated),
            gci,
            asymptotic
        );
    }
    let unconfirmed: Vec<&str> = study
        .readouts
        .iter()
        .filter(|r| r.estimate.asymptotic == Some(false))
        .map(|r| r.name.as_str())
        .collect();
    if let ([.., a, b], false) = (study.levels.as_slice(), unconfirmed.is_empty()) {
        // one more level at the finest ratio extends the check by one triple
        let next = b.level * b.level / a.level.max(1);
        let _ = writeln!(
            s,
            "# not shown asymptotic: {}; a level of {next} cells would show whether the finest \
             three are (`--levels ...,{},{next}`)",
            unconfirmed.join(", "),
            b.level
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn level(level: usize, l1: Option<f64>) -> LevelRow {
        LevelRow {
            level,
            cells: vec![level, level],
            l1,
            l2: l1,
            linf: l1,
            order_l1: None,
            order_l2: None,
            order_linf: None,
            steps: 10,
            wall_seconds: 0.5,
        }
    }

    /// A study without field errors (cut cells) prints its levels without columns of "-",
    /// and a readout the next-coarser grids do not confirm says so with their order.
    #[test]
    fn the_table_of_a_readouts_only_study() {
        let levels = [8usize, 12, 20, 32];
        let psi = [0.306, 0.235, 0.127, 0.079];
        let pairs: Vec<(usize, f64)> = levels.iter().copied().zip(psi).collect();
        let study = Study {
            scene: "drum".into(),
            scheme: "modified".into(),
            quantity: "phihat at t_end".into(),
            reference: "none: cut cells".into(),
            t_end: 0.5,
            levels: levels.iter().map(|&l| level(l, None)).collect(),
            readouts: vec![ReadoutRow {
                name: "psi_final".into(),
                values: psi.iter().map(|&p| Some(p)).collect(),
                estimate: grid_error::estimate(&pairs),
            }],
        };
        let t = table(&study);
        let lines: Vec<&str> = t.lines().collect();
        assert_eq!(
            lines[1].split_whitespace().collect::<Vec<_>>(),
            ["level", "cells", "steps", "wall_s"],
            "{t}"
        );
        assert_eq!(
            lines[2].split_whitespace().collect::<Vec<_>>(),
            ["8", "8x8", "10", "0.5000"],
            "{t}"
        );
        assert!(!t.contains(" - "), "{t}");
        let row = lines.iter().find(|l| l.contains("psi_final")).unwrap();
        assert!(
            row.contains("converging") && row.ends_with("no (-0.41)"),
            "{row}"
        );
        assert!(
            t.contains("# not shown asymptotic: psi_final; a level of 51 cells"),
            "{t}"
        );
        // with field errors, the error columns are back
        let mut with = study.clone();
        with.levels[0].l1 = Some(0.1);
        assert!(table(&with).lines().nth(1).unwrap().contains("p_Linf"));
    }
}
