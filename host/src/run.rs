//! Builds the core solver from a validated scene and runs the time loop.
//!
//! The solver `Segregation<R, D, N>` is a large value (tens of MB in 2D/3D). It is built only on
//! a dedicated thread whose stack is sized for it ([`with_solver`]), never on the main thread
//! and never boxed through the stack. A menu of compiled capacities (`N` per dimension, see
//! [`CAPACITY`](crate::scene::validate::CAPACITY)) times two precisions is dispatched by
//! generic functions; a grid smaller than the capacity uses only its first cells.

use crate::data::{output_times, LoopStats, SegregationTimer, SeriesRow, Snapshot};
use crate::error::{Error, Result};
use crate::scene::validate::{Direction, Temperature};
use crate::scene::{solver_errors, Fields, Precision, Scene};
use sieve_core::flow::Flow;
use sieve_core::geometry::CutCells;
use sieve_core::segregation::SegregationConfig;
use sieve_core::sum::FixedSum;
use sieve_core::{DirectionMode, Grid, Real, Segregation, TemperatureMode};
use std::time::Instant;

const CAP_1D: usize = crate::scene::validate::CAPACITY[0];
const CAP_2D: usize = crate::scene::validate::CAPACITY[1];
const CAP_3D: usize = crate::scene::validate::CAPACITY[2];

/// Work done with a solver of some precision, dimension and capacity.
pub trait SolverJob: Send {
    /// What the job returns.
    type Output: Send;
    /// Runs the job on a zeroed solver.
    fn run<R: Real, const D: usize, const N: usize>(
        self,
        s: &mut Segregation<R, D, N>,
    ) -> Result<Self::Output>;
}

/// Runs `job` on a solver of the given precision and dimension, on its own thread.
pub fn with_solver<J: SolverJob>(precision: Precision, dim: usize, job: J) -> Result<J::Output> {
    match (precision, dim) {
        (Precision::F64, 1) => on_solver_thread::<f64, 1, CAP_1D, J>(job),
        (Precision::F64, 2) => on_solver_thread::<f64, 2, CAP_2D, J>(job),
        (Precision::F64, 3) => on_solver_thread::<f64, 3, CAP_3D, J>(job),
        (Precision::F32, 1) => on_solver_thread::<f32, 1, CAP_1D, J>(job),
        (Precision::F32, 2) => on_solver_thread::<f32, 2, CAP_2D, J>(job),
        (Precision::F32, 3) => on_solver_thread::<f32, 3, CAP_3D, J>(job),
        _ => Err(Error::failure(format!(
            "no solver compiled for dim = {dim}"
        ))),
    }
}

fn on_solver_thread<R: Real, const D: usize, const N: usize, J: SolverJob>(
    job: J,
) -> Result<J::Output> {
    // The value is built in place on this stack; twice its size leaves room for a copy an
    // unoptimised build may make, plus ordinary frames.
    let stack = std::mem::size_of::<Segregation<R, D, N>>() * 2 + (64 << 20);
    std::thread::scope(|scope| {
        let handle = std::thread::Builder::new()
            .name("sieve-solver".into())
            .stack_size(stack)
            .spawn_scoped(scope, move || {
                let mut s = Segregation::<R, D, N>::zeroed();
                job.run(&mut s)
            })
            .map_err(|e| Error::failure(format!("cannot start the solver thread: {e}")))?;
        handle
            .join()
            .map_err(|_| Error::failure("the solver thread panicked"))?
    })
}

/// Work done with a segregation solver and a flow solver of the same precision, dimension and
/// capacity (scenes that solve a flow).
pub trait FlowJob: Send {
    /// What the job returns.
    type Output: Send;
    /// Runs the job on zeroed solvers.
    fn run<R: Real, const D: usize, const N: usize>(
        self,
        s: &mut Segregation<R, D, N>,
        f: &mut Flow<R, D, N>,
    ) -> Result<Self::Output>;
}

/// Runs `job` on a segregation and a flow solver, on their own thread (see [`with_solver`]).
pub fn with_flow_solvers<J: FlowJob>(
    precision: Precision,
    dim: usize,
    job: J,
) -> Result<J::Output> {
    match (precision, dim) {
        (Precision::F64, 1) => on_flow_thread::<f64, 1, CAP_1D, J>(job),
        (Precision::F64, 2) => on_flow_thread::<f64, 2, CAP_2D, J>(job),
        (Precision::F64, 3) => on_flow_thread::<f64, 3, CAP_3D, J>(job),
        (Precision::F32, 1) => on_flow_thread::<f32, 1, CAP_1D, J>(job),
        (Precision::F32, 2) => on_flow_thread::<f32, 2, CAP_2D, J>(job),
        (Precision::F32, 3) => on_flow_thread::<f32, 3, CAP_3D, J>(job),
        _ => Err(Error::failure(format!(
            "no solver compiled for dim = {dim}"
        ))),
    }
}

/// Runs `job` on the solvers the scene declares (model only what a scene needs): the coupled
/// flow and segregation when it has a flow, the segregation solver alone otherwise.
pub fn with_scene_solvers<O: Send, J: SolverJob<Output = O> + FlowJob<Output = O>>(
    scene: &Scene,
    job: J,
) -> Result<O> {
    if scene.flow.is_some() {
        with_flow_solvers(scene.precision, scene.dim, job)
    } else {
        with_solver(scene.precision, scene.dim, job)
    }
}

fn on_flow_thread<R: Real, const D: usize, const N: usize, J: FlowJob>(
    job: J,
) -> Result<J::Output> {
    let stack =
        (std::mem::size_of::<Segregation<R, D, N>>() + std::mem::size_of::<Flow<R, D, N>>()) * 2
            + (64 << 20);
    std::thread::scope(|scope| {
        let handle = std::thread::Builder::new()
            .name("sieve-solver".into())
            .stack_size(stack)
            .spawn_scoped(scope, move || {
                let mut s = Segregation::<R, D, N>::zeroed();
                let mut f = Flow::<R, D, N>::zeroed();
                job.run(&mut s, &mut f)
            })
            .map_err(|e| Error::failure(format!("cannot start the solver thread: {e}")))?;
        handle
            .join()
            .map_err(|_| Error::failure("the solver thread panicked"))?
    })
}

/// Sets up `s` with the scene's grid, boundaries and configuration and fills its cells.
pub fn load<R: Real, const D: usize, const N: usize>(
    s: &mut Segregation<R, D, N>,
    scene: &Scene,
    fields: &Fields,
) -> Result<()> {
    let v = |x: &[f64]| -> [R; D] { core::array::from_fn(|a| R::from_f64(x[a])) };
    let cells: [usize; D] = core::array::from_fn(|a| scene.cells[a]);
    let extent: [R; D] = core::array::from_fn(|a| R::from_f64(scene.upper[a] - scene.lower[a]));
    let grid = Grid::new(cells, v(&scene.lower), extent, N)
        .map_err(|e| solver_errors::grid_error(scene, &e))?;
    let bc: [[sieve_core::Boundary; 2]; D] = core::array::from_fn(|a| scene.boundaries[a]);
    let mut cfg = SegregationConfig::<R, D>::new();
    cfg.scheme = scene.scheme;
    cfg.phase = scene.phase;
    cfg.s0 = R::from_f64(scene.s0);
    cfg.gravity = v(&scene.gravity);
    cfg.direction = match &scene.direction {
        Direction::Gravity => DirectionMode::Gravity,
        Direction::Flow => DirectionMode::Flow,
        Direction::Fixed(d) => DirectionMode::Fixed(v(d)),
    };
    cfg.temperature = match scene.temperature {
        Temperature::Given => TemperatureMode::Given,
        Temperature::Shear {
            heating,
            eta0,
            eps0,
        } => TemperatureMode::FromShear {
            heating: R::from_f64(heating),
            eta0: R::from_f64(eta0),
            eps0: R::from_f64(eps0),
        },
    };
    cfg.diffusion = R::from_f64(scene.diffusion);
    cfg.courant = R::from_f64(scene.courant);
    s.setup(grid, bc, cfg)
        .map_err(|e| solver_errors::setup_error(scene, &e))?;
    s.set_transport(scene.transport);
    for i in 0..scene.len() {
        let u: [R; D] = core::array::from_fn(|a| R::from_f64(fields.u[a][i]));
        s.set_cell(
            i,
            R::from_f64(fields.c[i]),
            R::from_f64(fields.t[i]),
            u,
            R::from_f64(fields.phi[i]),
        );
    }
    // After set_cell: the inflow value is stored for the tracked phase using the cell's c.
    if scene.inflow_phi.is_some() {
        for i in 0..scene.len() {
            if scene.on_inflow_side(i) {
                s.set_inflow(i, R::from_f64(fields.inflow[i]));
            }
        }
    }
    s.prepare()
        .map_err(|e| solver_errors::setup_error(scene, &e))
}

/// Advances `s` from 0 to `scene.t_end`, stopping at every output time to record diagnostics
/// and call `on_output(k, t, s)`. The stepping is timed alone. With cut cells (`geo`, a scene
/// with a geometry) the embedded step, time step and diagnostics run instead of the box's.
/// A signal or a non-finite value ends it with an error ([`crate::interrupt`]); `sieve run`
/// uses [`time_loop_until_stop`] to keep the partial run.
///
/// Run guards (issue 10): the first step is taken alone and timed, and the run is refused
/// ([`crate::estimate::check_steps`]) if `t_end / dt` is absurd. The segregation time is
/// resolved to the step (`resolve_crossing`), not to the output samples.
pub fn time_loop<R: Real, const D: usize, const N: usize>(
    s: &mut Segregation<R, D, N>,
    scene: &Scene,
    progress: &crate::progress::Progress,
    geo: Option<&CutCells<R, D, N>>,
    on_output: impl FnMut(usize, f64, &Segregation<R, D, N>) -> Result<()>,
) -> Result<LoopStats> {
    let stats = time_loop_until_stop(s, scene, progress, geo, on_output)?;
    match &stats.stop {
        Some(stop) => Err(stop.error(None)),
        None => Ok(stats),
    }
}

/// [`time_loop`] that ends early, with `stats.stop` set, on a signal or a non-finite time step,
/// clock or state (checked after every chunk of steps: [`crate::interrupt::after_steps`]).
pub fn time_loop_until_stop<R: Real, const D: usize, const N: usize>(
    s: &mut Segregation<R, D, N>,
    scene: &Scene,
    progress: &crate::progress::Progress,
    geo: Option<&CutCells<R, D, N>>,
    on_output: impl FnMut(usize, f64, &Segregation<R, D, N>) -> Result<()>,
) -> Result<LoopStats> {
    time_loop_with(s, scene, progress, geo, None, on_output)
}

/// Checkpoints of a segregation loop: the session, and what else the checkpoint must hold
/// (the frozen flow of a frozen-flow scene).
pub type Checkpoints<'a> = (
    &'a mut crate::checkpoint::Session,
    &'a dyn Fn(&mut crate::checkpoint::Entries),
);

/// [`time_loop`] with checkpoints ([`crate::checkpoint`]): the solver has been restored by
/// the caller; the loop continues from the checkpoint's next output with its statistics, and
/// writes a checkpoint between chunks of steps whenever the session says it is due.
pub fn time_loop_with<R: Real, const D: usize, const N: usize>(
    s: &mut Segregation<R, D, N>,
    scene: &Scene,
    progress: &crate::progress::Progress,
    geo: Option<&CutCells<R, D, N>>,
    ckpt: Option<Checkpoints<'_>>,
    on_output: impl FnMut(usize, f64, &Segregation<R, D, N>) -> Result<()>,
) -> Result<LoopStats> {
    let serial = Workers {
        stepper: None,
        threads: 1,
    };
    time_loop_driven(s, scene, progress, geo, ckpt, serial, on_output)
}

/// `advance_to` of a run on subdomains ([`crate::parallel::Driver::advance`]).
pub type Stepper<'a, R, const D: usize, const N: usize> =
    &'a dyn Fn(&mut Segregation<R, D, N>, R, u64) -> u64;

/// Who does a run loop's work: its `stepper` (`None`: `advance_to` on this thread) and the
/// threads its box diagnoses take ([`crate::parallel::diagnose_on`]).
pub struct Workers<'a, R: Real, const D: usize, const N: usize> {
    /// Takes the steps in place of `advance_to`.
    pub stepper: Option<Stepper<'a, R, D, N>>,
    /// Threads of the diagnoses (1: serial).
    pub threads: usize,
}

/// [`time_loop_driven`] on the threads `sieve run --threads` asks for
/// ([`crate::parallel::driver_for`]; one thread, or a scene the threads do not run, steps
/// serially).
fn threaded_time_loop<R: Real, const D: usize, const N: usize>(
    s: &mut Segregation<R, D, N>,
    scene: &Scene,
    progress: &crate::progress::Progress,
    geo: Option<&CutCells<R, D, N>>,
    ckpt: Option<Checkpoints<'_>>,
    quiet: bool,
    on_output: impl FnMut(usize, f64, &Segregation<R, D, N>) -> Result<()>,
) -> Result<LoopStats> {
    // `mpirun -np K sieve run` (the `mpi` feature): rank 0 steps on the ranks instead
    #[cfg(feature = "mpi")]
    if let Some(d) = crate::parallel_mpi::driver_for(s, geo)? {
        let step = move |s: &mut _, t, n| d.advance(s, t, n);
        // the other ranks step with rank 0, but its diagnoses stay on one thread
        let ranks = Workers {
            stepper: Some(&step),
            threads: 1,
        };
        return time_loop_driven(s, scene, progress, geo, ckpt, ranks, on_output);
    }
    let driver = crate::parallel::driver_for(s, geo, scene, quiet)?;
    let step = driver
        .as_ref()
        .map(|d| move |s: &mut _, t, n| d.advance(s, t, n));
    let workers = Workers {
        stepper: step.as_ref().map(|f| f as Stepper<'_, R, D, N>),
        threads: driver.as_ref().map_or(1, |d| d.parts()),
    };
    time_loop_driven(s, scene, progress, geo, ckpt, workers, on_output)
}

/// [`time_loop_with`] whose steps are taken by `workers.stepper` (`--threads`, mpirun)
/// instead of `advance_to`: the same steps and bits, so nothing else in the loop changes;
/// the box diagnoses run on `workers.threads` threads (the same bits).
pub fn time_loop_driven<R: Real, const D: usize, const N: usize>(
    s: &mut Segregation<R, D, N>,
    scene: &Scene,
    progress: &crate::progress::Progress,
    geo: Option<&CutCells<R, D, N>>,
    mut ckpt: Option<Checkpoints<'_>>,
    workers: Workers<'_, R, D, N>,
    mut on_output: impl FnMut(usize, f64, &Segregation<R, D, N>) -> Result<()>,
) -> Result<LoopStats> {
    let Workers { stepper, threads } = workers;
    let mut diagnoser = Diagnoser::new(threads);
    let times = output_times(scene.t_end, scene.output_interval);
    let dt = geo
        .map_or_else(|| s.stable_dt(), |g| s.stable_dt_embedded(g))
        .to_f64();
    let resumed = match &ckpt {
        Some((ck, _)) => ck.progress(scene)?,
        None => None,
    };
    let (mut stats, first) = match resumed {
        Some(p) => (p.stats, p.next),
        None => (
            LoopStats {
                dt,
                ..LoopStats::default()
            },
            0,
        ),
    };
    if dt < R::MAX.to_f64() {
        // the segregation step is fixed by the prepared state (model.md 5)
        stats.took_dt(dt);
    }
    let mut timer = SegregationTimer::new(scene.psi_threshold);
    for r in &stats.series {
        timer.sample(r.t, r.psi);
    }
    if let Some(t) = stats.segregation_time {
        // resumed after the crossing: the step-resolved time the checkpoint kept
        timer = SegregationTimer::crossed(scene.psi_threshold, t);
    }
    // Bounded chunks keep the progress moving on large grids; the step sequence is the
    // same as one call (advance_to only shortens the step that lands on the target), so a
    // checkpoint between chunks resumes onto the same steps.
    let chunk = (4_000_000 / scene.len()).max(1) as u64;
    let mut checked = false;
    let advance = |s: &mut Segregation<R, D, N>, target: R, n: u64| match (stepper, geo) {
        (Some(d), _) => d(s, target, n),
        (None, Some(g)) => crate::isa::advance_to_embedded(s, target, n, g),
        (None, None) => crate::isa::advance_to(s, target, n),
    };
    if dt == 0.0 {
        // Nothing would ever move the clock: refused before the start (exit 2), not a
        // numerical failure.
        crate::estimate::check_steps(scene, dt, 0.0)?;
    }
    // The prepared state first: a non-finite coefficient stops the run before any step.
    stats.stop = crate::interrupt::after_steps(s, stats.dt, 0);
    'outputs: for (k, &t) in times.iter().enumerate().skip(first) {
        if stats.stop.is_some() {
            break;
        }
        let target = R::from_f64(t);
        // Until Psi has crossed, keep what is needed to replay this interval step by step.
        let before = (timer.time().is_none() && k > 0).then(|| Checkpoint::of(s, timer));
        while s.time() < target {
            let start = Instant::now();
            stats.steps += advance(s, target, if checked { chunk } else { 1 });
            let took = start.elapsed();
            stats.stepping += took;
            if !checked {
                checked = true;
                crate::estimate::check_steps(scene, dt, took.as_secs_f64())?;
            }
            progress.update(s.time().to_f64(), stats.steps);
            // The step the chunk took (the prepared state's: constant over the run).
            if let Some(stop) = crate::interrupt::after_steps(s, stats.dt, stats.steps) {
                stats.stop = Some(stop);
                break 'outputs;
            }
            if let Some((ck, extra)) = ckpt.as_mut().filter(|(c, _)| c.due()) {
                let mut at = crate::checkpoint::Progress {
                    next: k,
                    stats: stats.clone(),
                    ..Default::default()
                };
                at.stats.segregation_time = timer.time();
                ck.save(&at, |e| {
                    crate::checkpoint::put_segregation(e, s);
                    extra(e);
                })?;
            }
        }
        let d = diagnoser.of(s, geo);
        let row = SeriesRow {
            t,
            psi: d.psi.to_f64(),
            mass: d.mass_small.to_f64(),
            overshoot_max: d.overshoot.to_f64(),
            undershoot_max: d.undershoot.to_f64(),
        };
        timer.sample(t, row.psi);
        if let Some(cp) = before {
            if timer.time().is_some() {
                timer = resolve_crossing(s, cp, target, geo, &mut diagnoser, advance);
            }
        }
        stats.series.push(row);
        on_output(k, t, s)?;
    }
    stats.segregation_time = timer.time();
    stats.record_bounds(s);
    Ok(stats)
}

/// The diagnostics of the current state: the cut cells' ([`sieve_core::diagnose_embedded`])
/// or the box's, the latter's entropy terms on a pool of the run's threads
/// ([`crate::parallel::diagnose_on`], the same bits). The pool and the terms' buffer live as
/// long as the loop: the step-by-step replay of [`resolve_crossing`] diagnoses after every
/// step, where a thread spawn and a buffer per call would cost as much as the step.
struct Diagnoser<R> {
    pool: Option<crate::pool::Pool>,
    terms: Vec<R>,
}

impl<R: Real> Diagnoser<R> {
    fn new(threads: usize) -> Self {
        Self {
            pool: (threads > 1)
                .then(|| crate::pool::Pool::new(threads))
                .flatten(),
            terms: Vec::new(),
        }
    }

    fn of<const D: usize, const N: usize>(
        &mut self,
        s: &Segregation<R, D, N>,
        geo: Option<&CutCells<R, D, N>>,
    ) -> sieve_core::Diagnostics<R> {
        match geo {
            Some(g) => sieve_core::diagnose_embedded(s, g),
            None => crate::parallel::diagnose_on(s, self.pool.as_ref(), &mut self.terms),
        }
    }
}

/// The state at the start of an output interval, exact to the bit (tracked fraction and
/// compensation carry per cell, the clock), and the segregation timer as it was then.
struct Checkpoint<R> {
    q: Vec<R>,
    carry: Vec<R>,
    time: R,
    steps: u64,
    /// The flushed-mass counter (docs/model.md 5.6): a replay must not count a flush twice.
    flushed: R,
    /// The open sides' books (`Segregation::side_books`): nor must it book a face twice.
    books: Vec<[FixedSum; 2]>,
    timer: SegregationTimer,
}

impl<R: Real> Checkpoint<R> {
    fn of<const D: usize, const N: usize>(
        s: &Segregation<R, D, N>,
        timer: SegregationTimer,
    ) -> Self {
        Self {
            q: (0..s.len()).map(|i| s.tracked_fraction(i)).collect(),
            carry: (0..s.len()).map(|i| s.carry(i)).collect(),
            time: s.time(),
            steps: s.steps(),
            flushed: s.flushed_tracked(),
            books: s.side_books().to_vec(),
            timer,
        }
    }
}

/// Psi fell below the threshold somewhere in the interval that just ended: replays it from the
/// checkpoint one step at a time, sampling Psi after every step, and returns the timer fed
/// with those samples: the crossing interpolated between the two steps around it (model.md 6
/// defines the segregation time by Psi, not by the output grid). Interpolating between
/// output samples instead biased it by +0.0127 on column b (100 cells, output every 0.1).
/// The replay takes the same steps from the same bits, so the state at the end is the one the
/// interval produced; its steps and time are not counted twice.
fn resolve_crossing<R: Real, const D: usize, const N: usize>(
    s: &mut Segregation<R, D, N>,
    cp: Checkpoint<R>,
    target: R,
    geo: Option<&CutCells<R, D, N>>,
    diagnoser: &mut Diagnoser<R>,
    advance: impl Fn(&mut Segregation<R, D, N>, R, u64) -> u64,
) -> SegregationTimer {
    #[cfg(debug_assertions)]
    let end_hash = sieve_core::state_hash(s);
    for (i, (&q, &e)) in cp.q.iter().zip(&cp.carry).enumerate() {
        s.set_tracked(i, q);
        s.set_carry(i, e);
    }
    s.set_clock(cp.time, cp.steps);
    s.set_flushed_tracked(cp.flushed);
    s.set_side_books(core::array::from_fn(|a| cp.books[a]));
    let mut timer = cp.timer;
    // Psi after every step until the first crossing; the rest of the interval needs no
    // samples (the timer keeps the first crossing), so it is stepped in one call: the same
    // steps (advance_to only shortens the one that lands on the target), without a Psi
    // evaluation each (on 512 x 512 cells one cost about 7 single-thread steps in perf).
    while s.time() < target && timer.time().is_none() {
        advance(s, target, 1);
        timer.sample(s.time().to_f64(), diagnoser.of(s, geo).psi.to_f64());
    }
    while s.time() < target {
        advance(s, target, 1 << 20);
    }
    #[cfg(debug_assertions)]
    debug_assert_eq!(end_hash, sieve_core::state_hash(s));
    timer
}

/// The progress display of a run: a bar on a terminal, lines otherwise
/// ([`crate::progress::Progress`]).
pub fn progress_bar(quiet: bool, label: &str, t_end: f64) -> crate::progress::Progress {
    crate::progress::Progress::new(quiet, label, t_end)
}

/// Options of `sieve run` that are not scene keys.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Output directory.
    pub out: std::path::PathBuf,
    /// No progress bar.
    pub quiet: bool,
}

/// Checkpoints of `sieve run` ([`crate::checkpoint`]).
#[derive(Debug, Default)]
pub struct ResumeOptions {
    /// Where the scene came from (stored in every checkpoint); without it no checkpoints
    /// are written.
    pub source: Option<crate::checkpoint::SceneSource>,
    /// The checkpoint to continue from (`--resume DIR`).
    pub resume: Option<crate::checkpoint::Stored>,
}

/// What the solver thread of `sieve run` hands back.
struct RunOutcome {
    stats: LoopStats,
    pvd: Vec<(f64, String)>,
    hash: u64,
    exact_l1: Option<f64>,
    flow: Option<crate::data::FlowSummary>,
    profiles: Option<crate::data::Profiles>,
    geometry: Option<crate::data::GeometrySummary>,
    discharge: Option<crate::silo::DischargeSeries>,
    worst: Option<crate::estimate::Violation>,
    ckpt: Option<crate::checkpoint::Session>,
}

struct RunJob<'a> {
    scene: &'a Scene,
    fields: &'a Fields,
    fields_dir: std::path::PathBuf,
    staging: std::path::PathBuf,
    quiet: bool,
    /// The largest bound violation seen at an output time (for the warning line).
    worst: std::cell::Cell<Option<crate::estimate::Violation>>,
    /// Number of output times (the last always gets a snapshot).
    outputs: usize,
    ckpt: Option<crate::checkpoint::Session>,
    /// Writes the snapshots beside the stepping ([`crate::output::writer`]).
    writer: &'a crate::output::writer::Writer,
}

/// The VTK collection entries of the outputs a resumed run kept (written before the
/// interruption): the same names and times the run gave them (a `.pvti` for an output
/// written under mpirun, whether or not this run is).
fn kept_pvd(
    scene: &Scene,
    ckpt: Option<&crate::checkpoint::Session>,
    outputs: usize,
) -> Result<Vec<(f64, String)>> {
    let Some(ck) = ckpt else {
        return Ok(Vec::new());
    };
    let next = ck.progress(scene)?.map_or(0, |p| p.next);
    Ok(output_times(scene.t_end, scene.output_interval)
        .into_iter()
        .take(next)
        .enumerate()
        .filter(|&(k, _)| scene.output.writes(k, outputs))
        .map(|(k, t)| {
            let name = ck
                .kept_name(k)
                .unwrap_or_else(|| crate::checkpoint::snapshot_name(k));
            (t, name)
        })
        .collect())
}

impl RunJob<'_> {
    /// Writes the VTK snapshot of output `k` (the pictures are drawn from these files).
    fn output(&self, k: usize, t: f64, snap: Snapshot, pvd: &mut Vec<(f64, String)>) -> Result<()> {
        if let Some(v) = crate::estimate::worst_violation(&snap.phi, &snap.c, t) {
            if self.worst.get().is_none_or(|w| v.amount > w.amount) {
                self.worst.set(Some(v));
            }
        }
        if !self.scene.output.writes(k, self.outputs) {
            return Ok(()); // thinned ([output] vtk_every)
        }
        // under mpirun: one piece per rank and the .pvti naming them
        #[cfg(feature = "mpi")]
        if let Some(name) =
            crate::parallel_mpi::write_snapshot(&self.fields_dir, k, self.scene, &snap)?
        {
            pvd.push((t, name));
            return Ok(());
        }
        let name = format!("state_{k:04}.vti");
        self.writer.write(self.fields_dir.join(&name), snap)?;
        pvd.push((t, name));
        Ok(())
    }

    /// final.csv, the exact comparison and the hash of the final state.
    fn finish<R: Real, const D: usize, const N: usize>(
        &self,
        s: &Segregation<R, D, N>,
        snap: &Snapshot,
    ) -> Result<(u64, Option<f64>)> {
        let scene = self.scene;
        crate::output::csv::write_final(&self.staging.join("final.csv"), scene, snap)?;
        let exact_l1 = scene.column_a(self.fields).map(|ex| {
            let h = scene.spacing()[0];
            snap.phihat()
                .iter()
                .enumerate()
                .map(|(i, &ph)| {
                    let z0 = scene.lower[0] + i as f64 * h;
                    let e = ex.phihat_cell_average(
                        z0 - scene.lower[0],
                        z0 + h - scene.lower[0],
                        snap.t,
                    );
                    (ph - e).abs() * h
                })
                .sum()
        });
        Ok((sieve_core::state_hash(s), exact_l1))
    }
}

impl SolverJob for RunJob<'_> {
    type Output = RunOutcome;
    fn run<R: Real, const D: usize, const N: usize>(
        mut self,
        s: &mut Segregation<R, D, N>,
    ) -> Result<RunOutcome> {
        let scene = self.scene;
        load(s, scene, self.fields)?;
        let geo = crate::embedded::build(s, scene)?;
        let geo = geo.as_deref();
        if let Some(g) = geo {
            crate::embedded::prepare(s, scene, g)?;
        }
        let mut ckpt = self.ckpt.take();
        // c, T and u are fixed here, so the restored ones equal the prepared ones.
        if let Some(ck) = &ckpt {
            if let Some(e) = ck.resumed() {
                crate::checkpoint::restore_segregation(e, s).map_err(|w| ck.incompatible(w))?;
            }
        }
        let volume = geo.map(crate::embedded::volumes);
        let bar = progress_bar(self.quiet, &scene.name, scene.t_end);
        let mut pvd = kept_pvd(scene, ckpt.as_ref(), self.outputs)?;
        let nothing = |_: &mut crate::checkpoint::Entries| {};
        let stats = threaded_time_loop(
            s,
            scene,
            &bar,
            geo,
            ckpt.as_mut().map(|c| (c, &nothing as &dyn Fn(&mut _))),
            self.quiet,
            |k, t, s| {
                let mut snap = Snapshot::of(s, scene);
                snap.volume = volume.clone();
                self.output(k, t, snap, &mut pvd)
            },
        )?;
        bar.finish_and_clear();
        let mut snap = Snapshot::of(s, scene);
        snap.volume = volume.clone();
        let (hash, exact_l1) = self.finish(s, &snap)?;
        Ok(RunOutcome {
            stats,
            pvd,
            hash,
            exact_l1,
            flow: None,
            profiles: None,
            geometry: geo.and_then(|g| crate::embedded::summary(scene, g)),
            discharge: None,
            worst: self.worst.get(),
            ckpt,
        })
    }
}

impl FlowJob for RunJob<'_> {
    type Output = RunOutcome;
    fn run<R: Real, const D: usize, const N: usize>(
        mut self,
        s: &mut Segregation<R, D, N>,
        f: &mut Flow<R, D, N>,
    ) -> Result<RunOutcome> {
        use crate::checkpoint as cp;
        use crate::scene::Equations;
        let scene = self.scene;
        load(s, scene, self.fields)?;
        // A container (coupled scenes only; validation refuses a frozen flow with one).
        let geo = crate::embedded::build(s, scene)?;
        let geo = geo.as_deref();
        let volume = geo.map(crate::embedded::volumes);
        let bar = progress_bar(self.quiet, &scene.name, scene.t_end);
        let mut ckpt = self.ckpt.take();
        let mut pvd = kept_pvd(scene, ckpt.as_ref(), self.outputs)?;
        let equations = scene.flow.as_ref().map(|m| m.equations);
        let mut discharge = None;
        let (stats, summary, p_final) = if equations == Some(Equations::Coupled) {
            // under mpirun the ranks step on one thread each, which the CLI's note says
            #[cfg(feature = "mpi")]
            let ranks = crate::parallel_mpi::world().is_some();
            #[cfg(not(feature = "mpi"))]
            let ranks = false;
            if let (Some(note), false) = (
                crate::parallel::coupled_threads(scene).1,
                self.quiet || ranks,
            ) {
                eprintln!("{note}");
            }
            let cs = crate::flow::coupled_loop_with(
                f,
                s,
                scene,
                self.fields,
                geo,
                &bar,
                ckpt.as_mut(),
                |k, t, s, f| {
                    let mut snap = Snapshot::of(s, scene);
                    snap.p = Some((0..f.len()).map(|i| f.pressure(i).to_f64()).collect());
                    snap.volume = volume.clone();
                    self.output(k, t, snap, &mut pvd)
                },
            )?;
            let p: Vec<f64> = (0..f.len()).map(|i| f.pressure(i).to_f64()).collect();
            discharge = cs.discharge;
            (cs.stats, cs.summary, p)
        } else {
            // A resumed frozen-flow run hands over the checkpoint's frozen flow (no spin-up).
            let resumed = ckpt.as_ref().and_then(|c| c.resumed());
            let frozen = match resumed {
                Some(e) => cp::frozen(e, scene.len(), scene.dim)
                    .map_err(|w| ckpt.as_ref().map_or(w.clone(), |c| c.incompatible(w)))?,
                None => crate::flow::spin_up(f, scene, self.fields)?,
            };
            crate::flow::hand_over_frozen(s, scene, self.fields, &frozen)?;
            if let Some(ck) = &ckpt {
                if let Some(e) = ck.resumed() {
                    cp::restore_segregation(e, s).map_err(|w| ck.incompatible(w))?;
                }
            }
            let keep = |e: &mut cp::Entries| cp::put_frozen(e, &frozen);
            let stats = threaded_time_loop(
                s,
                scene,
                &bar,
                None,
                ckpt.as_mut().map(|c| (c, &keep as &dyn Fn(&mut _))),
                self.quiet,
                |k, t, s| {
                    let mut snap = Snapshot::of(s, scene);
                    snap.p = Some(frozen.p.clone());
                    self.output(k, t, snap, &mut pvd)
                },
            )?;
            (stats, frozen.summary, frozen.p)
        };
        bar.finish_and_clear();
        let mut snap = Snapshot::of(s, scene);
        snap.p = Some(p_final);
        snap.volume = volume.clone();
        let (hash, exact_l1) = self.finish(s, &snap)?;
        Ok(RunOutcome {
            stats,
            pvd,
            hash,
            exact_l1,
            flow: Some(summary),
            profiles: Some(crate::flow::profiles(scene, &snap)),
            geometry: geo.and_then(|g| crate::embedded::summary(scene, g)),
            discharge,
            worst: self.worst.get(),
            ckpt,
        })
    }
}

/// The lines a run of `scene` says before it starts (and keeps in summary.json's
/// `warnings`): a run that will go on but whose numbers the user should read with care
/// (narrow orifices, a wall rule that does not apply). Every command that runs a scene
/// (`sieve run`, `sieve record`) says the same lines.
pub fn caveats(scene: &Scene) -> Vec<String> {
    let mut caveats = crate::silo::outlet_caveats(scene);
    caveats.extend(crate::flow::merged_walls_caveat(scene));
    caveats
}

/// `sieve run`: runs a validated scene and writes DIR atomically; returns the summary.
pub fn run_scene(
    scene: &Scene,
    fields: &Fields,
    opts: &RunOptions,
) -> Result<crate::output::summary::Summary> {
    run_scene_with(scene, fields, opts, ResumeOptions::default())
}

/// [`run_scene`] with checkpoints: written every `scene.checkpoint_interval` seconds if
/// `resume.source` is given, and continued from `resume.resume` (`sieve run --resume`).
pub fn run_scene_with(
    scene: &Scene,
    fields: &Fields,
    opts: &RunOptions,
    resume: ResumeOptions,
) -> Result<crate::output::summary::Summary> {
    use crate::output::{self, redraw, summary, Staging};
    let start = Instant::now();
    // Run guard (issue 10): the output must fit the limit and the disk before anything runs.
    crate::estimate::check_output(scene, &opts.out)?;
    // said now, before the run, and kept in summary.json
    let caveats = caveats(scene);
    for w in &caveats {
        eprintln!("{w}");
    }
    let staging = Staging::new(&opts.out)?;
    let fields_dir = staging.subdir("fields")?;
    let plots_dir = staging.subdir("plots")?;
    let overrides = resume
        .source
        .as_ref()
        .map(|s| s.sets.clone())
        .unwrap_or_default();
    let ckpt = match resume.source {
        Some(source) => Some(crate::checkpoint::Session::new(
            &opts.out,
            scene,
            fields,
            source,
            fields_dir.clone(),
            resume.resume,
        )?),
        None => None,
    };
    // The snapshots are written on their own thread while the solver steps on; every one is
    // on disk (or the first error returned) before anything below reads them.
    let out = std::thread::scope(|scope| {
        let (writer, handle) = output::writer::Writer::start(scope, scene)?;
        let mut ckpt = ckpt;
        if let Some(ck) = ckpt.as_mut() {
            ck.after_writes(writer.pending());
        }
        let job = RunJob {
            scene,
            fields,
            fields_dir: fields_dir.clone(),
            staging: staging.path().to_path_buf(),
            quiet: opts.quiet,
            worst: std::cell::Cell::new(None),
            outputs: output_times(scene.t_end, scene.output_interval).len(),
            ckpt,
            writer: &writer,
        };
        let out = with_scene_solvers(scene, job);
        let written = output::writer::finish(writer, handle);
        let out = out?;
        written.map(|()| out)
    })?;
    let stats = &out.stats;
    output::csv::write_series(&staging.path().join("series.csv"), &stats.series)?;
    output::vtk::write_pvd(&fields_dir.join("series.pvd"), &out.pvd)?;
    if let Some(d) = &out.discharge {
        output::write_file(&staging.path().join("discharge.csv"), d.csv().as_bytes())?;
    }
    if let Some(p) = &out.profiles {
        redraw::write_profiles(&staging.path().join("profiles.csv"), p)?;
    }
    // Drum readouts from the snapshots just written (so a resumed run measures the same).
    let drum = crate::drum::analyse(scene, &fields_dir, &out.pvd)?;
    if let Some(d) = &drum {
        output::write_file(
            &staging.path().join("radial.csv"),
            crate::drum::radial_csv(d).as_bytes(),
        )?;
    }
    let first = stats.series.first().copied();
    let last = stats.series.last().copied();
    let mass_initial = first.map_or(0.0, |r| r.mass);
    let mass_final = last.map_or(0.0, |r| r.mass);
    // What left through outlets (booked by the coupled run) and through inflow and outflow
    // sides (booked by the segregation step): the summary's mass balance closes.
    let mass_out = out
        .flow
        .as_ref()
        .and_then(|f| f.outlet.as_ref())
        .map_or(0.0, |o| o.out_small)
        + stats.mass_out_through_sides();
    let axes = crate::scene::validate::axis_names(scene.dim);
    let mass_out_sides = stats
        .sides_out
        .iter()
        .map(|&(a, side, m)| (format!("{}_{}", axes[a], ["low", "high"][side]), m))
        .collect();
    let cells = scene.len();
    let stepping = stats.stepping.as_secs_f64();
    let exact = scene.column_a(fields).map(|ex| summary::ExactComparison {
        kind: "column-a".into(),
        l1_phihat: out.exact_l1.unwrap_or(f64::NAN),
        psi_exact: ex.psi(scene.t_end),
        segregation_time_exact: ex.segregation_time(scene.psi_threshold),
    });
    let stop = stats.stop.as_ref();
    let bounds = crate::estimate::bounds_warning(
        scene,
        stats.overshoot_max(),
        stats.undershoot_max(),
        out.worst,
    );
    let summary = summary::Summary {
        status: stop.map_or("complete", |s| s.status()).into(),
        stopped: stop.map(summary::Stopped::of),
        scene: scene.name.clone(),
        scene_file: scene.label.clone(),
        overrides,
        scheme: scene.scheme.name().into(),
        phase: match scene.phase {
            sieve_core::Phase::Small => "small".into(),
            sieve_core::Phase::Large => "large".into(),
        },
        precision: scene.precision.name().into(),
        dims: scene.dim,
        cells: scene.cells.clone(),
        cell_count: cells,
        steps: stats.steps,
        dt: stats.dt,
        dt_min: stats.dt_taken.map(|d| d[0]),
        dt_max: stats.dt_taken.map(|d| d[1]),
        dt_last: stats.dt_taken.map(|d| d[2]),
        courant: scene.courant,
        t_end: scene.t_end,
        output_interval: scene.output_interval,
        wall_seconds: start.elapsed().as_secs_f64(),
        stepping_seconds: stepping,
        cell_updates_per_second: if stepping > 0.0 {
            stats.steps as f64 * cells as f64 / stepping
        } else {
            0.0
        },
        mass_initial,
        mass_final,
        mass_flushed: stats.flushed,
        mass_out,
        mass_out_sides,
        mass_rel_drift: if mass_initial != 0.0 {
            (mass_final + stats.flushed + mass_out - mass_initial).abs() / mass_initial.abs()
        } else {
            (mass_final + stats.flushed + mass_out - mass_initial).abs()
        },
        overshoot_max: stats.overshoot_max(),
        undershoot_max: stats.undershoot_max(),
        psi_initial: first.map_or(0.0, |r| r.psi),
        psi_final: last.map_or(0.0, |r| r.psi),
        segregation_time: stats.segregation_time,
        psi_threshold: scene.psi_threshold,
        state_hash: format!("{:016x}", out.hash),
        exact,
        flow: out.flow.clone(),
        geometry: out.geometry.clone(),
        frame: scene.frame.as_ref().map(|f| crate::data::FrameSummary {
            kind: match f.kind {
                crate::scene::FrameKind::Lab => "lab".into(),
                crate::scene::FrameKind::Rotating => "rotating".into(),
            },
            rev_per_s: f.rev_per_s,
            omega: std::f64::consts::TAU * f.rev_per_s,
            period: (f.rev_per_s != 0.0).then(|| 1.0 / f.rev_per_s.abs()),
            center: f.center.clone(),
            psi_per_revolution: if f.rev_per_s != 0.0 {
                crate::data::psi_per_revolution(&stats.series, 1.0 / f.rev_per_s.abs())
            } else {
                Vec::new()
            },
        }),
        drum,
        warnings: caveats.into_iter().chain(bounds.clone()).collect(),
    };
    summary.write(&staging.path().join("summary.json"))?;
    if let Some(w) = bounds {
        eprintln!("{w}");
    }
    // The pictures come from the files just written, as `sieve plot DIR` draws them.
    let drawn = output::without_panic(|| redraw::redraw(staging.path(), &plots_dir));
    let Some(stop) = stop else {
        if let Err(e) = drawn {
            // The run is complete: keep it, and say the pictures failed (exit 1).
            let dir = staging.commit()?;
            if let Some(ck) = out.ckpt {
                ck.finish()?;
            }
            return Err(Error::failure(format!(
                "{}: the run is complete but its plots could not be drawn ({e}); its files are kept",
                dir.display()
            )));
        }
        staging.commit()?;
        if let Some(ck) = out.ckpt {
            ck.finish()?;
        }
        return Ok(summary);
    };
    // A stopped run keeps its files even if its (partial, perhaps non-finite) data cannot
    // be drawn, and its checkpoint, so that `--resume DIR` continues it.
    if let Err(e) = drawn {
        eprintln!("warning: {}: plots not drawn: {e}", opts.out.display());
    }
    let dir = staging.commit()?;
    Err(stop.error(Some(&dir)))
}
