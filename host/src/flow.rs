//! The solved granular flow of a scene (model.md 2, 4; `model.equations = "frozen-flow"` or
//! `"coupled"`): building `sieve_core::flow::Flow` from a validated scene, spinning it up to a
//! steady state and freezing it, the coupled time loop, and the horizontally averaged flow
//! profiles (u_x(z), T(z), sqrt(T)/shear rate) the plots show.
//!
//! **Model only what the scene needs.** A frozen-flow scene that is periodic in x and whose
//! initial data (c, T, u, phi) do not depend on x has an x-independent flow, so the flow is spun
//! up on [`SPIN_UP_COLUMNS`] columns and every row is replicated to the full grid (shown equal to
//! 2e-11 against a full 2D run by `tests/tests/flow_shear_cell.rs`); `flow.spin_up = "full"`
//! turns this off. The segregation then runs on the full grid with the frozen fields. Such a
//! flow between walls in z has `c u_z = 0` exactly at steady state, so the frozen `u_z` (the
//! bed's unfinished compaction when the residual test stops the spin-up) is set to 0: the
//! segregation transport then keeps `phi <= c` on the frozen `c`.

use crate::coupled_steps::{CoupledSteps, WholeSteps};
use crate::data::{
    output_times, FlowSummary, LoopStats, Profiles, SegregationTimer, SeriesRow, Snapshot,
};
use crate::error::{Error, Result};
use crate::scene::validate::{FlowModel, WallSlip};
use crate::scene::{
    solver_errors, Equations, Fields, Fill, FrameKind, MergedWallsKind, PressureKind, Scene,
    SpinUp, StressKind,
};
use crate::step_psi::{Sample, StepPsi};
use sieve_core::closure::Packing;
use sieve_core::flow::coupled::{Coupled, CouplingConfig, Mode};
use sieve_core::flow::{
    CutWall, Flow, FlowBoundaries, FlowConfig, FlowDiagnostics, FlowSide, MemberKept, MergedWalls,
    PressureMode, Slip, Stress,
};
use sieve_core::fork::Serial;
use sieve_core::frame::{Frame, Rotation};
use sieve_core::{Boundary, Grid, Real, Segregation};
use std::time::Instant;

/// The line a run that names `flow.merged_walls` prints before it starts where the rule it
/// asked for does not apply (model.md 5.4, "The wall term of a merged cell"): without cut
/// cells there is no merged cell (either rule); a cut wall turning in the lab frame and the
/// objective stress keep each member's own term ("master"). Said (and kept in summary.json's
/// `warnings`), not refused: the run is the `"member"` run. The default says nothing.
pub fn merged_walls_caveat(scene: &Scene) -> Option<String> {
    let fm = scene.flow.as_ref()?;
    if !fm.merged_walls_given {
        return None;
    }
    let rule = fm.merged_walls.name();
    let moving = scene
        .frame
        .as_ref()
        .is_some_and(|f| f.kind == FrameKind::Lab && f.omega != 0.0);
    let why = if scene.geometry.is_none() {
        "the scene has no cut cells, so no merged cell"
    } else {
        // the core's own answer to "does the rule apply here" (the step asks the same)
        match merged_walls(fm.merged_walls).on_master(stress(fm.stress), moving) {
            Ok(_) => return None,
            Err(MemberKept::MovingWall) => {
                "the cut wall turns in the lab frame, and a moving wall keeps each merged cell's own wall term"
            }
            Err(MemberKept::ObjectiveStress) => {
                "flow.stress = objective keeps each merged cell's own wall term"
            }
        }
    };
    Some(format!(
        "warning: {}: flow.merged_walls = {rule} has no effect here: {why} (model.md 5.4)",
        scene.label
    ))
}

/// The core's stress for the scene's word.
fn stress(k: StressKind) -> Stress {
    match k {
        StressKind::Spec => Stress::Spec,
        StressKind::Objective => Stress::Objective,
    }
}

/// The core's merged-wall rule for the scene's word.
fn merged_walls(k: MergedWallsKind) -> MergedWalls {
    match k {
        MergedWallsKind::Member => MergedWalls::Member,
        MergedWallsKind::Master => MergedWalls::Master,
    }
}

/// Columns of the x-reduced spin-up grid (periodic x needs a few cells for the stencils).
pub const SPIN_UP_COLUMNS: usize = 4;

fn boundaries<R: Real, const D: usize>(scene: &Scene, fm: &FlowModel) -> FlowBoundaries<R, D> {
    core::array::from_fn(|a| {
        core::array::from_fn(|side| match scene.boundaries[a][side] {
            Boundary::Periodic => FlowSide::periodic(),
            Boundary::Outflow => FlowSide::outflow(),
            // Rejected by validation; a resting no-slip wall keeps this total.
            Boundary::Inflow | Boundary::Wall => {
                let w = &fm.walls[a][side];
                let mut s = FlowSide::wall(match w.slip {
                    WallSlip::NoSlip => Slip::NoSlip,
                    WallSlip::Slip => Slip::Slip,
                    WallSlip::Friction { tan, .. } => Slip::Friction(R::from_f64(tan)),
                });
                s.velocity = core::array::from_fn(|b| R::from_f64(w.velocity[b]));
                if let Some(o) = &w.outlet {
                    crate::silo::open(&mut s, o);
                }
                s
            }
        })
    })
}

fn config<R: Real, const D: usize>(scene: &Scene, fm: &FlowModel) -> FlowConfig<R, D> {
    let mut cfg = FlowConfig::new(scene.flow_material(fm));
    cfg.gravity = core::array::from_fn(|a| R::from_f64(scene.gravity[a]));
    cfg.courant = R::from_f64(fm.courant);
    cfg.t_min = R::from_f64(fm.t_min);
    // never below what the precision can reach (as the core's default); `cg_tolerance` sets
    // every system unless the pressure has its own
    let floor = R::EPSILON * R::from_f64(64.0);
    if let Some(tol) = fm.cg_tolerance {
        cfg.cg_tolerance = R::from_f64(tol).max(floor);
        cfg.cg_tolerance_pressure = cfg.cg_tolerance;
    }
    if let Some(tol) = fm.cg_tolerance_pressure {
        cfg.cg_tolerance_pressure = R::from_f64(tol).max(floor);
    }
    // Only faded faces (next to a nearly empty cell) feel it: no effect on a filled box.
    cfg.free_surface_push = true;
    cfg.pressure = match fm.pressure {
        PressureKind::Explicit => PressureMode::Explicit,
        PressureKind::Implicit => PressureMode::Implicit,
    };
    cfg.stress = stress(fm.stress);
    cfg.merged_walls = merged_walls(fm.merged_walls);
    // A rotating frame (docs/frames.md): the grid turns with the container; validation
    // allows it with a coupled flow only and checks the centre, axis and rate.
    if let Some(fr) = scene
        .frame
        .as_ref()
        .filter(|f| f.kind == FrameKind::Rotating)
    {
        cfg.frame = Frame::Rotating(Rotation {
            omega: R::from_f64(fr.omega),
            center: core::array::from_fn(|a| R::from_f64(fr.center[a])),
            axis: fr.axis,
        });
    }
    cfg
}

/// Columns of the spin-up grid: [`SPIN_UP_COLUMNS`] if the scene is 2D, periodic in x, wider
/// than that, allows it (`flow.spin_up = "auto"`) and its initial fields do not depend on x;
/// else the full width.
pub fn spin_up_columns(scene: &Scene, fields: &Fields) -> usize {
    let nx = scene.cells[0];
    let fm = scene.flow.as_ref();
    let allowed = scene.dim == 2
        && nx > SPIN_UP_COLUMNS
        && scene.boundaries[0] == [Boundary::Periodic; 2]
        && fm.is_some_and(|f| f.spin_up == SpinUp::Auto && f.equations == Equations::FrozenFlow);
    if !allowed {
        return nx;
    }
    let same_row = |v: &[f64]| v.chunks(nx).all(|row| row.iter().all(|&x| x == row[0]));
    let x_free = same_row(&fields.c)
        && same_row(&fields.t)
        && same_row(&fields.phi)
        && fields.u.iter().all(|u| same_row(u));
    if x_free {
        SPIN_UP_COLUMNS
    } else {
        nx
    }
}

/// Sets up `flow` on the full grid (`columns = nx`) or on `columns` columns, with the scene's
/// initial fields (row-wise when reduced) and, with back-coupling on, the packing limits of the
/// initial phihat; prepares it.
fn setup<R: Real, const D: usize, const N: usize>(
    flow: &mut Flow<R, D, N>,
    scene: &Scene,
    fields: &Fields,
    columns: usize,
) -> Result<()> {
    let fm = scene
        .flow
        .as_ref()
        .ok_or_else(|| Error::failure("no flow in scene"))?;
    let mut cells: [usize; D] = core::array::from_fn(|a| scene.cells[a]);
    cells[0] = columns;
    let nx = scene.cells[0];
    let extent: [R; D] = core::array::from_fn(|a| R::from_f64(scene.upper[a] - scene.lower[a]));
    let lower: [R; D] = core::array::from_fn(|a| R::from_f64(scene.lower[a]));
    let grid =
        Grid::new(cells, lower, extent, N).map_err(|e| solver_errors::grid_error(scene, &e))?;
    flow.setup(grid, boundaries(scene, fm), config(scene, fm))
        .map_err(|e| solver_errors::flow_error(scene, &e))?;
    let mat = scene.flow_material::<R>(fm);
    let pk = fm.back_coupling.packing();
    for i in 0..grid.len() {
        // The full-grid cell with the same row (x-independent data when reduced).
        let src = if columns == nx {
            i
        } else {
            i % columns + nx * (i / columns)
        };
        let c = fields.c[src];
        let u: [R; D] = core::array::from_fn(|a| R::from_f64(fields.u[a][src]));
        flow.set_cell(i, R::from_f64(c), u, R::from_f64(fields.t[src]));
        if pk != Packing::Constant {
            let (rcp, rlp) = pk.limits(&mat, R::from_f64(fields.phi[src] / c));
            flow.set_packing(i, rcp, rlp);
        }
    }
    flow.prepare()
        .map_err(|e| solver_errors::flow_error(scene, &e))
}

/// A steady flow, frozen ([`crate::data::Frozen`]: a checkpoint keeps the same fields).
pub use crate::data::Frozen;

fn diag_f64<R: Real>(d: &FlowDiagnostics<R>) -> FlowDiagnostics<f64> {
    FlowDiagnostics {
        mass: d.mass.to_f64(),
        max_packing: d.max_packing.to_f64(),
        t_min: d.t_min.to_f64(),
        t_max: d.t_max.to_f64(),
        max_speed: d.max_speed.to_f64(),
        kinetic_energy: d.kinetic_energy.to_f64(),
        residual: d.residual.to_f64(),
    }
}

/// The flow block of summary.json: the flow's own diagnostics and counters, the scene's
/// flow model and how the bed was filled.
fn summary_of<R: Real, const D: usize, const N: usize>(
    flow: &Flow<R, D, N>,
    fm: &FlowModel,
    fill: Fill,
    seconds: f64,
    to_steady: Option<u64>,
    clipped: f64,
) -> FlowSummary {
    let d = diag_f64(&flow.diagnostics());
    FlowSummary {
        equations: fm.equations.name().into(),
        back_coupling: fm.back_coupling.name().into(),
        pressure: flow.config().pressure.name().into(),
        stress: flow.config().stress.name().into(),
        merged_walls: flow
            .has_geometry()
            .then(|| fm.merged_walls.name().to_string()),
        fill: fill.name().into(),
        flow_steps_to_steady: to_steady,
        flow_steps: flow.steps(),
        cg_iterations: flow.cg_iterations(),
        flow_time: flow.time().to_f64(),
        flow_seconds: seconds,
        flow_cells: flow.grid().cells().to_vec(),
        max_packing: d.max_packing,
        t_min: d.t_min,
        t_max: d.t_max,
        max_speed: d.max_speed,
        kinetic_energy: d.kinetic_energy,
        residual: d.residual,
        steady_tolerance: fm.steady_tolerance,
        clipped_mass: clipped,
        outlet: None,
    }
}

/// Spins the flow up from the scene's initial fields until its residual is below
/// `flow.steady_tolerance` (after at least `flow.min_steps` steps), on the reduced grid if the
/// scene allows it ([`spin_up_columns`]), and returns it frozen on the full grid.
pub fn spin_up<R: Real, const D: usize, const N: usize>(
    flow: &mut Flow<R, D, N>,
    scene: &Scene,
    fields: &Fields,
) -> Result<Frozen> {
    let fm = scene
        .flow
        .as_ref()
        .ok_or_else(|| Error::failure("no flow in scene"))?;
    let start = Instant::now();
    let columns = spin_up_columns(scene, fields);
    setup(flow, scene, fields, columns)?;
    let tol = R::from_f64(fm.steady_tolerance);
    loop {
        // Nothing of a spin-up is kept: a signal ends it with nothing written.
        crate::interrupt::check("the flow spin-up")?;
        let dt = flow.stable_dt().to_f64();
        if let Some(reason) =
            crate::interrupt::bad_dt(dt).or_else(|| crate::interrupt::scan_flow(flow))
        {
            let stop = crate::interrupt::Stop {
                reason,
                t: flow.time().to_f64(),
                step: flow.steps(),
            };
            return Err(stop.error(None));
        }
        let stable = flow.stable_dt();
        crate::on_level!(crate::isa::level(), &Serial, |f| flow.step_on(stable, f));
        let k = flow.steps();
        if k >= fm.min_steps && flow.residual() < tol {
            break;
        }
        if k >= fm.max_steps {
            return Err(Error::failure(format!(
                "{}: the flow did not reach steady state in flow.max_steps = {} steps (t = {:.4e} s, residual {:.3e} 1/s > flow.steady_tolerance = {}): raise flow.max_steps or flow.steady_tolerance",
                scene.label,
                fm.max_steps,
                flow.time().to_f64(),
                flow.residual().to_f64(),
                fm.steady_tolerance
            )));
        }
    }
    let steps = flow.steps();
    let summary = summary_of(
        flow,
        fm,
        scene.fill,
        start.elapsed().as_secs_f64(),
        Some(steps),
        0.0,
    );
    let n = scene.len();
    let nx = scene.cells[0];
    // An x-independent flow between walls in z has c u_z = 0 exactly at steady state
    // (continuity d_z(c u_z) = 0 with u_z = 0 at the walls); what is left of u_z is the bed's
    // unfinished compaction, which would move phi against a frozen c (phi > c). Drop it.
    let drop_vertical = columns < nx && scene.boundaries[D - 1] == [Boundary::Wall; 2];
    let src = |i: usize| {
        if columns == nx {
            i
        } else {
            columns * (i / nx)
        }
    };
    Ok(Frozen {
        c: (0..n).map(|i| flow.c(src(i)).to_f64()).collect(),
        t: (0..n).map(|i| flow.temperature(src(i)).to_f64()).collect(),
        p: (0..n).map(|i| flow.pressure(src(i)).to_f64()).collect(),
        u: (0..D)
            .map(|a| {
                (0..n)
                    .map(|i| {
                        if drop_vertical && a == D - 1 {
                            0.0
                        } else {
                            flow.velocity(src(i))[a].to_f64()
                        }
                    })
                    .collect()
            })
            .collect(),
        summary,
    })
}

/// Hands the frozen flow to the segregation solver (set up by [`crate::run::load`]) keeping
/// each cell's initial composition `phihat = phi / c` (new `phi = phihat c_flow`), and
/// prepares it; the clock starts at 0.
pub fn hand_over_frozen<R: Real, const D: usize, const N: usize>(
    seg: &mut Segregation<R, D, N>,
    scene: &Scene,
    fields: &Fields,
    frozen: &Frozen,
) -> Result<()> {
    for i in 0..scene.len() {
        let c = frozen.c[i];
        let phihat = (fields.phi[i] / fields.c[i]).clamp(0.0, 1.0);
        let u: [R; D] = core::array::from_fn(|a| R::from_f64(frozen.u[a][i]));
        let c_r = R::from_f64(c);
        seg.set_cell(
            i,
            c_r,
            R::from_f64(frozen.t[i]),
            u,
            (R::from_f64(phihat) * c_r).min(c_r),
        );
    }
    seg.prepare().map_err(|e| {
        Error::failure(format!(
            "{}: the segregation solver rejected the frozen flow: {e}",
            scene.label
        ))
    })
}

/// What the coupled loop measured beyond the segregation series.
pub struct CoupledStats {
    /// Segregation-side statistics.
    pub stats: LoopStats,
    /// Flow block.
    pub summary: FlowSummary,
    /// The discharge series (scenes with outlets).
    pub discharge: Option<crate::silo::DischargeSeries>,
}

/// Coupled mode: flow and segregation on the full grid with a common step (the last step
/// before an output time shortened to land on it), packing back-coupled if switched on.
/// `on_output(k, t, seg, flow)` is called at every output time. A signal or a non-finite value
/// ends it with an error; `sieve run` uses [`coupled_loop_until_stop`] to keep the partial run.
pub fn coupled_loop<R: Real, const D: usize, const N: usize>(
    flow: &mut Flow<R, D, N>,
    seg: &mut Segregation<R, D, N>,
    scene: &Scene,
    fields: &Fields,
    geo: Option<&sieve_core::geometry::CutCells<R, D, N>>,
    progress: &crate::progress::Progress,
    on_output: impl FnMut(usize, f64, &Segregation<R, D, N>, &Flow<R, D, N>) -> Result<()>,
) -> Result<CoupledStats> {
    let cs = coupled_loop_until_stop(flow, seg, scene, fields, geo, progress, on_output)?;
    match &cs.stats.stop {
        Some(stop) => Err(stop.error(None)),
        None => Ok(cs),
    }
}

/// [`coupled_loop`] that ends early, with `stats.stop` set, on a signal, a non-finite time
/// step or state (checked after every step: one pass over the cells, small next to a flow
/// step) or a step the core refuses.
pub fn coupled_loop_until_stop<R: Real, const D: usize, const N: usize>(
    flow: &mut Flow<R, D, N>,
    seg: &mut Segregation<R, D, N>,
    scene: &Scene,
    fields: &Fields,
    geo: Option<&sieve_core::geometry::CutCells<R, D, N>>,
    progress: &crate::progress::Progress,
    on_output: impl FnMut(usize, f64, &Segregation<R, D, N>, &Flow<R, D, N>) -> Result<()>,
) -> Result<CoupledStats> {
    coupled_loop_with(flow, seg, scene, fields, geo, progress, None, on_output)
}

/// The two solvers of a coupled scene as the driver of a coupled run: the flow set up for
/// the scene, the coupling of its model, the cut-cell walls if it has them, and the state of
/// the checkpoint `resumed` restored (`resumed` names the one `ck` holds, or a follower's of
/// an MPI run). Every rank of an MPI run builds the same run, bit for bit.
pub fn coupled_start<'a, R: Real, const D: usize, const N: usize>(
    flow: &'a mut Flow<R, D, N>,
    seg: &'a mut Segregation<R, D, N>,
    scene: &Scene,
    fields: &Fields,
    geo: Option<&'a sieve_core::geometry::CutCells<R, D, N>>,
    resumed: Option<&crate::checkpoint::Entries>,
) -> Result<Coupled<'a, R, D, N>> {
    let fm = scene
        .flow
        .as_ref()
        .ok_or_else(|| Error::failure("no flow in scene"))?;
    setup(flow, scene, fields, scene.cells[0])?;
    let mut cc = CouplingConfig::new(Mode::Coupled);
    cc.packing = fm.back_coupling.packing();
    cc.steady_tolerance = R::from_f64(fm.steady_tolerance);
    let fail = |e| Error::failure(format!("{}: coupled step failed: {e}", scene.label));
    let mut cpl = match geo {
        Some(g) => {
            // The container's wall: the law of the box's floor (z_low); at rest in the
            // rotating frame, turning at omega about the frame's axis in the lab frame
            // (docs/frames.md).
            let floor = boundaries::<R, D>(scene, fm)[D - 1][0];
            let mut wall = CutWall::resting(floor.slip);
            if let Some(fr) = scene
                .frame
                .as_ref()
                .filter(|f| f.kind == FrameKind::Lab && f.omega != 0.0)
            {
                let rot = Rotation::<R, D> {
                    omega: R::from_f64(fr.omega),
                    center: core::array::from_fn(|a| R::from_f64(fr.center[a])),
                    axis: fr.axis,
                };
                let (p, q) = rot.plane();
                wall = CutWall {
                    slip: floor.slip,
                    omega: rot.omega,
                    center: rot.center,
                    plane: [p, q],
                };
            }
            flow.set_geometry(g, wall)
                .map_err(|e| solver_errors::flow_error(scene, &e))?;
            Coupled::new_embedded(flow, seg, cc, g).map_err(fail)?
        }
        None => Coupled::new(flow, seg, cc).map_err(fail)?,
    };
    if let Some(e) = resumed {
        use crate::checkpoint as cp;
        cp::restore_flow(e, cpl.flow)?;
        cp::restore_segregation(e, cpl.seg)?;
        cpl.resume(cp::totals(e)?).map_err(fail)?;
    }
    Ok(cpl)
}

/// [`coupled_loop_until_stop`] with checkpoints (`sieve run`; [`crate::checkpoint`]): resumes
/// from the session's checkpoint if it has one, and writes one whenever the session says it
/// is due (between steps; the step sequence does not depend on where a run was interrupted).
/// Rank 0 of an MPI run steps on the ranks' slabs (`crate::rank_coupled`), every other
/// process on its whole grid ([`WholeSteps`]).
#[allow(clippy::too_many_arguments)]
pub fn coupled_loop_with<R: Real, const D: usize, const N: usize>(
    flow: &mut Flow<R, D, N>,
    seg: &mut Segregation<R, D, N>,
    scene: &Scene,
    fields: &Fields,
    geo: Option<&sieve_core::geometry::CutCells<R, D, N>>,
    progress: &crate::progress::Progress,
    ckpt: Option<&mut crate::checkpoint::Session>,
    on_output: impl FnMut(usize, f64, &Segregation<R, D, N>, &Flow<R, D, N>) -> Result<()>,
) -> Result<CoupledStats> {
    let mut start = Start::default();
    let mut resumed = None;
    if let Some(ck) = ckpt.as_deref() {
        if let (Some(e), Some(p)) = (ck.resumed(), ck.progress(scene)?) {
            resumed = Some(e);
            start = Start {
                stats: Some(p.stats),
                first: p.next,
                flow_seconds: p.flow_seconds,
                discharge: p.discharge,
            };
        }
    }
    let mut cpl = coupled_start(flow, seg, scene, fields, geo, resumed).map_err(|w| {
        match (resumed, ckpt.as_deref()) {
            (Some(_), Some(ck)) => ck.incompatible(w),
            _ => w,
        }
    })?;
    let looped = Loop {
        scene,
        geo,
        progress,
        ckpt,
        start,
    };
    #[cfg(feature = "mpi")]
    if crate::parallel_mpi::world().is_some_and(|(rank, _)| rank == 0) {
        return crate::rank_coupled::lead(&mut cpl, scene, |cpl, steps| {
            looped.run(cpl, steps, on_output)
        });
    }
    let n = cpl.seg.len();
    let mut steps = WholeSteps {
        // `--threads`: the flow's linear solves on a pool (the same bits, docs/parallel.md)
        pool: crate::parallel::flow_pool(scene),
        level: crate::isa::level(),
        psi: StepPsi::new(cpl.seg, 0..n, n, geo.map(|g| g.volumes())),
        sampled: None,
    };
    looped.run(&mut cpl, &mut steps, on_output)
}

/// Where a coupled run's loop starts: a resumed run's statistics, next output, flow time
/// and discharge rows (a fresh run's defaults).
#[derive(Default)]
struct Start {
    stats: Option<LoopStats>,
    first: usize,
    flow_seconds: f64,
    discharge: Option<Vec<crate::silo::DischargeRow>>,
}

/// The coupled run loop's fixed arguments ([`coupled_loop_with`]).
struct Loop<'s, 'c, R: Real, const D: usize, const N: usize> {
    scene: &'s Scene,
    geo: Option<&'s sieve_core::geometry::CutCells<R, D, N>>,
    progress: &'s crate::progress::Progress,
    ckpt: Option<&'c mut crate::checkpoint::Session>,
    start: Start,
}

impl<R: Real, const D: usize, const N: usize> Loop<'_, '_, R, D, N> {
    /// Steps `cpl` with `steps` to every output time (or a stop), writes the outputs and
    /// checkpoints, and sums up.
    fn run<S: CoupledSteps<R, D, N>>(
        self,
        cpl: &mut Coupled<'_, R, D, N>,
        steps: &mut S,
        mut on_output: impl FnMut(usize, f64, &Segregation<R, D, N>, &Flow<R, D, N>) -> Result<()>,
    ) -> Result<CoupledStats> {
        let Self {
            scene,
            geo,
            progress,
            mut ckpt,
            start,
        } = self;
        let fm = scene
            .flow
            .as_ref()
            .ok_or_else(|| Error::failure("no flow in scene"))?;
        let times = output_times(scene.t_end, scene.output_interval);
        let resumed = start.stats.is_some();
        let mut stats = start.stats.unwrap_or_else(|| LoopStats {
            dt: cpl.stable_dt().to_f64(),
            ..Default::default()
        });
        let (first, mut flow_seconds) = (start.first, start.flow_seconds);
        let mut discharge = scene.has_outlets().then(|| match start.discharge {
            Some(rows) => crate::silo::DischargeSeries::from_rows(rows),
            None => crate::silo::DischargeSeries::default(),
        });
        let threshold = scene.psi_threshold;
        let mut timer = StepTimer::start(threshold, &stats, cpl.seg, geo, resumed);
        let mut checked = false;
        'outputs: for (k, &t) in times.iter().enumerate().skip(first) {
            let target = R::from_f64(t);
            let start = Instant::now();
            while steps.time(cpl) < target {
                let t0 = Instant::now();
                // Psi after every step until it crosses: the segregation time resolved to
                // the step, not to the output samples (evaluated only where it can cross)
                let sample = timer.time().is_none().then_some(threshold);
                let (stable, stepped) =
                    steps.step_toward(cpl, target, stats.dt.min(scene.t_end), sample);
                if stepped.is_ok() {
                    stats.steps += 1;
                    stats.took_dt(stable.to_f64());
                }
                let reason = match stepped {
                    Err(r) => Some(r),
                    Ok(()) => match crate::interrupt::pending() {
                        Some(sig) => Some(crate::interrupt::Reason::Signal(sig)),
                        None => steps.scan(cpl)?,
                    },
                };
                if let Some(reason) = reason {
                    steps.sync(cpl)?;
                    stats.stop = Some(crate::interrupt::Stop {
                        reason,
                        t: cpl.seg.time().to_f64(),
                        step: stats.steps,
                    });
                    let el = start.elapsed();
                    stats.stepping += el;
                    flow_seconds += el.as_secs_f64();
                    break 'outputs;
                }
                if !checked {
                    // Run guard (issue 10): refuse an absurd t_end / dt before it runs for
                    // days; the first coupled step of a bed at rest is among the largest, so
                    // this errs low.
                    checked = true;
                    crate::estimate::check_steps(
                        scene,
                        stable.to_f64(),
                        t0.elapsed().as_secs_f64(),
                    )?;
                }
                if let Some(s) = steps.sampled() {
                    let t = steps.time(cpl).to_f64();
                    timer.sample_step(t, s);
                }
                if let Some(ck) = ckpt.as_deref_mut().filter(|c| c.due()) {
                    steps.sync(cpl)?;
                    let mut at = crate::checkpoint::Progress {
                        next: k,
                        stats: stats.clone(),
                        flow_seconds: flow_seconds + start.elapsed().as_secs_f64(),
                        discharge: discharge.as_ref().map(|d| d.rows.clone()),
                    };
                    at.stats.segregation_time = timer.time();
                    at.stats.stepping += start.elapsed();
                    ck.save(&at, |e| {
                        crate::checkpoint::put_segregation(e, cpl.seg);
                        crate::checkpoint::put_flow(e, cpl.flow);
                        crate::checkpoint::put_totals(e, &cpl.totals());
                    })?;
                }
                if stats.steps.is_multiple_of(256) {
                    progress.update(steps.time(cpl).to_f64(), stats.steps);
                }
            }
            steps.sync(cpl)?;
            let el = start.elapsed();
            stats.stepping += el;
            flow_seconds += el.as_secs_f64();
            let d = match geo {
                Some(g) => sieve_core::diagnose_embedded(cpl.seg, g),
                None => sieve_core::diagnose(cpl.seg),
            };
            let row = SeriesRow {
                t,
                psi: d.psi.to_f64(),
                mass: d.mass_small.to_f64(),
                overshoot_max: d.overshoot.to_f64(),
                undershoot_max: d.undershoot.to_f64(),
            };
            // a held sample is the last step's, whose state this row's Psi is
            timer.sample(t, row.psi, Some(row.psi));
            stats.series.push(row);
            on_output(k, t, cpl.seg, cpl.flow)?;
            if let Some(d) = discharge.as_mut() {
                d.sample_in(t, cpl, geo);
                if d.emptied {
                    break; // until empty (or t_end)
                }
            }
        }
        stats.segregation_time = timer.time();
        stats.record_bounds(cpl.seg);
        let clipped = cpl.guarded_mass().to_f64();
        let mut summary = summary_of(cpl.flow, fm, scene.fill, flow_seconds, None, clipped);
        summary.outlet = discharge.as_ref().map(|d| d.summary_with(scene.fines_band));
        Ok(CoupledStats {
            stats,
            summary,
            discharge,
        })
    }
}

/// The segregation timer of a coupled run, sampled after every step (the segregation time
/// resolved to the step) without evaluating Psi (two `libm` logarithms per cell, 5 % of
/// the silo's run time) at steps where it cannot cross. The stepper takes a floor under a
/// step's Psi ([`sieve_core::psi_floor`], a few multiplications per cell); at or above the
/// threshold that sample cannot cross, and all the timer keeps of such a sample is that it
/// arms the timer and is the `last` one the crossing interpolates from. So the stepper holds
/// its fields ([`Sample::Held`], `crate::step_psi`), evaluated (the bits of `diagnose`) only
/// if the next sample may cross; a later sample that cannot cross replaces it. The timer sees
/// the same samples with the same Psi wherever it matters: the same segregation time to the
/// bit (docs/implicit-pressure.md, "Where the time goes").
struct StepTimer {
    timer: SegregationTimer,
    threshold: f64,
    /// The time of the held sample (held by the stepper).
    pending: Option<f64>,
}

impl StepTimer {
    /// The timer a run starts with: `stats` holds a resumed run's output rows and, when it
    /// had crossed, the step-resolved time its checkpoint kept. Resumed before the crossing,
    /// the restored state is sampled as the step it is: the uninterrupted run's last sample
    /// was that step, not the last output row, and a crossing in the first step after the
    /// resume interpolates from it (docs/resume.md).
    fn start<R: Real, const D: usize, const N: usize>(
        threshold: f64,
        stats: &LoopStats,
        seg: &Segregation<R, D, N>,
        geo: Option<&sieve_core::geometry::CutCells<R, D, N>>,
        resumed: bool,
    ) -> Self {
        let mut timer = SegregationTimer::new(threshold);
        for r in &stats.series {
            timer.sample(r.t, r.psi);
        }
        if let Some(t) = stats.segregation_time {
            // resumed after the crossing: the step-resolved time the checkpoint kept
            timer = SegregationTimer::crossed(threshold, t);
        }
        if resumed && timer.time().is_none() {
            // evaluated at once: a held sample would have been evaluated before it mattered
            let psi = match geo {
                Some(g) => sieve_core::diagnose_embedded(seg, g),
                None => sieve_core::diagnose(seg),
            };
            timer.sample(seg.time().to_f64(), psi.psi.to_f64());
        }
        Self {
            timer,
            threshold,
            pending: None,
        }
    }

    fn time(&self) -> Option<f64> {
        self.timer.time()
    }

    /// A sample whose Psi is evaluated; `held`: the held sample's Psi, evaluated where this
    /// one may cross.
    fn sample(&mut self, t: f64, psi: f64, held: Option<f64>) {
        if let Some(tp) = self.pending.take() {
            if let (false, Some(h)) = (psi >= self.threshold, held) {
                // this one may cross (or is NaN): the held sample first, as it came
                self.timer.sample(tp, h);
            }
        }
        self.timer.sample(t, psi);
    }

    /// The sample of a step at time `t` (the stepper's [`Sample`]).
    fn sample_step(&mut self, t: f64, sample: Sample) {
        match sample {
            Sample::Held => self.pending = Some(t),
            Sample::Psi { psi, held } => self.sample(t, psi, held),
        }
    }
}

/// The profiles of a snapshot.
pub fn profiles(scene: &Scene, snap: &Snapshot) -> Profiles {
    let dim = scene.dim;
    let nz = scene.cells[dim - 1];
    let per_row = scene.len() / nz;
    let hz = scene.spacing()[dim - 1];
    // physical component: u_x in 2D/3D, u_z in 1D
    let comp = if dim == 1 { 2 } else { 0 };
    let mean = |f: &dyn Fn(usize) -> f64, k: usize| {
        (0..per_row).map(|j| f(j + per_row * k)).sum::<f64>() / per_row as f64
    };
    let u: Vec<f64> = (0..nz).map(|k| mean(&|i| snap.u[i][comp], k)).collect();
    let t: Vec<f64> = (0..nz).map(|k| mean(&|i| snap.temp[i], k)).collect();
    let z: Vec<f64> = (0..nz)
        .map(|k| scene.lower[dim - 1] + (k as f64 + 0.5) * hz)
        .collect();
    let fm = scene.flow.as_ref();
    let wall_u = |side: usize| -> Option<f64> {
        let fm = fm?;
        if dim == 1 || scene.boundaries[dim - 1][side] != Boundary::Wall {
            return None;
        }
        match fm.walls[dim - 1][side].slip {
            WallSlip::NoSlip => Some(fm.walls[dim - 1][side].velocity[0]),
            _ => None,
        }
    };
    let shear = (0..nz)
        .map(|k| {
            let (below, wb) = if k == 0 {
                match wall_u(0) {
                    Some(w) => (w, 0.5),
                    None => (u[0], 0.0),
                }
            } else {
                (u[k - 1], 1.0)
            };
            let (above, wa) = if k + 1 == nz {
                match wall_u(1) {
                    Some(w) => (w, 0.5),
                    None => (u[k], 0.0),
                }
            } else {
                (u[k + 1], 1.0)
            };
            let width = (wb + wa) * hz;
            if width > 0.0 {
                ((above - below) / width).abs()
            } else {
                0.0
            }
        })
        .collect();
    Profiles {
        z,
        u,
        t,
        shear,
        ratio_theory: fm.map_or(f64::NAN, |f| (f.heating * f.eta0 / f.eps0).sqrt()),
    }
}

#[cfg(test)]
mod tests {
    use super::StepTimer;
    use crate::coupled_steps::collapsed_step;
    use crate::data::{LoopStats, SeriesRow};
    use crate::step_psi::StepPsi;
    use sieve_core::sum::Whole;
    use sieve_core::{Boundary, Grid, Segregation, SegregationConfig};

    /// A timer and the samples of its steps.
    type Run = (StepTimer, StepPsi<f64>);

    fn start(stats: &LoopStats, seg: &Segregation<f64, 1, 8>, resumed: bool) -> Run {
        let timer = StepTimer::start(0.5, stats, seg, None, resumed);
        (timer, StepPsi::new(seg, 0..8, 8, None))
    }

    /// The sample of the step to `seg` at `t`, as the run loop takes it.
    fn sample_of((timer, psi): &mut Run, t: f64, seg: &Segregation<f64, 1, 8>) {
        let s = psi.sample(seg, timer.threshold, &mut Whole);
        timer.sample_step(t, s);
    }

    /// A 1D bed of 8 cells at time `t`, a fraction `s` of the way from mixed (phi = c/2
    /// everywhere) to fully segregated (the fines all in the lower half).
    fn bed(t: f64, s: f64) -> Box<Segregation<f64, 1, 8>> {
        let mut seg = Box::new(Segregation::<f64, 1, 8>::zeroed());
        let grid = Grid::new([8], [0.0], [1.0], 8).unwrap();
        seg.setup(grid, [[Boundary::Wall; 2]], SegregationConfig::new())
            .unwrap();
        for i in 0..8 {
            let target = if i < 4 { 0.6 } else { 0.0 };
            seg.set_cell(i, 0.6, 1.0, [0.0], 0.3 + s * (target - 0.3));
        }
        seg.set_clock(t, 1);
        seg
    }

    #[test]
    fn a_resumed_timer_interpolates_from_the_checkpoints_step() {
        let threshold = 0.5;
        let (mixed, step, crossed) = (bed(0.0, 0.0), bed(0.3, 0.5), bed(0.4, 1.0));
        let psi = |s: &Segregation<f64, 1, 8>| sieve_core::diagnose(s).psi;
        assert!(psi(&mixed) > 0.99 && psi(&step) > threshold && psi(&crossed) < threshold);
        // uninterrupted: the output row at t = 0, then every step
        let mut stats = LoopStats::default();
        stats.series.push(SeriesRow {
            t: 0.0,
            psi: psi(&mixed),
            mass: 0.0,
            overshoot_max: 0.0,
            undershoot_max: 0.0,
        });
        let mut run = start(&stats, &mixed, false);
        sample_of(&mut run, 0.3, &step);
        sample_of(&mut run, 0.4, &crossed);
        let t = run.0.time().expect("crossed");
        assert!(t > 0.3 && t < 0.4, "{t}");
        // killed after the step at t = 0.3 (its checkpoint), resumed: the same time, bit for bit
        let mut resumed = start(&stats, &step, true);
        sample_of(&mut resumed, 0.4, &crossed);
        assert_eq!(resumed.0.time().map(f64::to_bits), Some(t.to_bits()));
        // from the output row alone (the timer before the fix) the crossing moves
        let mut rows_only = start(&stats, &step, false);
        sample_of(&mut rows_only, 0.4, &crossed);
        assert!(
            rows_only.0.time().unwrap() < 0.3,
            "{:?}",
            rows_only.0.time()
        );
    }

    #[test]
    fn a_step_a_billion_times_below_the_first_stops_the_run() {
        // the runaway of issue 8's loose pressure solve: 2.6e-3 s at the start, 1.9e-17 s later
        let r = collapsed_step(1.887e-17, 2.599e-3).expect("a collapsed step");
        assert!(
            format!("{r:?}").contains("t_end cannot be reached"),
            "{r:?}"
        );
        // a silo's jet or a collapse moves the step by orders of magnitude, not nine
        assert!(collapsed_step(2.6e-7, 2.6e-3).is_none());
        assert!(collapsed_step(2.6e-3, 2.6e-3).is_none());
    }
}
