//! Recording the host's scene catalogue: any 2D scene (built-in name or TOML file) whose model
//! is "prescribed" or "frozen-flow".
//!
//! * **Truth**: the scene's own run, with the same machinery as `sieve run` ([`crate::run::load`],
//!   and for a frozen flow [`crate::flow::spin_up`] + [`crate::flow::hand_over_frozen`]), on the
//!   scene's grid and in its precision, stepped to each frame time `k * period` (the last step
//!   of each period shortened to land on it). After each frame the truth's psi (full grid) and
//!   its phihat averaged onto the sensor grid are stored.
//! * **Frames**: the velocity of the truth (the prescribed field or the frozen flow; fixed in
//!   time) averaged over the truth cells whose centres lie in each sensor cell (a PIV
//!   interrogation window), plus Gaussian noise of standard deviation `noise * max|u|` on each
//!   component, independent per point and frame.
//! * **Sensor configuration** (what the firmware runs with), from the scene: extent, boundary
//!   kinds, gravity, diffusion; c = the scene's c if uniform, else the mean of the (frozen) c
//!   field (noted); initial phihat = small-phase mass / total mass (the format carries one
//!   value: a layered start such as an inversely graded bed is started *mixed* by the soft
//!   sensor, noted); inflow phihat = the mean over the inflow cells. The soft sensor derives T
//!   from the measured shear, `T = a eta0/eps0 kappa:kappa` (model.md 2): with a solved flow
//!   or `temperature = "shear"` it takes S0, a, eta0, eps0 of the material as they are; with
//!   `temperature = "given"` it takes the glass beads' a, eta0, eps0 (model.md 7.4) and
//!   rescales S0 so that `S0' sqrt(a eta0/eps0) <gammadot> = S0 <sqrt(T)>` (means over cells):
//!   exact for uniform T and uniform shear such as `gray-thornton-shear` and the idealised
//!   shear cells. A scene without shear and with given T cannot be represented (its sensor
//!   T would be 0) and is rejected.
//! * **Defaults**: estimator 32 x 32, sensor 8 x 8, 5 % noise, budget 4 substeps per tick;
//!   the frame period is [`COURANT_STEPS_PER_FRAME`] Courant steps of the estimator's combined
//!   rate (measured on the clean velocity, rounded down to two significant digits) and the frames cover `run.t_end`
//!   (at most [`MAX_DEFAULT_FRAMES`]).
//!
//! A "coupled" scene (issue 9, e.g. `silo`) is recorded by `record_coupled`: the truth is
//! the coupled run itself, sampled at every frame time; see there.

use super::record::{RecordReport, Writer};
use super::scene::{coarsen, psi_on_grid};
use super::ESTIMATOR_CAPACITY;
use crate::data::FlowSummary;
use crate::error::{Error, Result};
use crate::run::{FlowJob, SolverJob};
use crate::scene::validate::{Direction, Temperature};
use crate::scene::{Equations, Fields, Scene};
use sieve_core::flow::Flow;
use sieve_core::segregation::direction::shear_rate_squared;
use sieve_core::sensor::{CycleBudget, Region, SensorConfig, SoftSensor, VelocityFrame};
use sieve_core::{diagnose, Boundary, Real, Segregation};

/// Heating prefactor a, eta0 [m] and eps0 [1/m] of the glass beads of model.md 7.4: the
/// soft sensor's T-from-shear constants for scenes that give T instead.
const HEATING: f64 = 1.5;
const ETA0: f64 = 1.3e-4;
const EPS0: f64 = 1477.15;

/// Default frame period in Courant steps of the estimator's combined rate
/// (`Segregation::stable_dt`: velocity plus segregation speed over the cell size at the
/// configuration's courant 0.5), about the time the fastest grains take to cross one
/// estimator cell: frames that resolve the flow's changes cell by cell. (Until 2026-12-07 this
/// was also the estimator's substep; it now takes longer ones, `SoftSensor::stable_dt`, so a
/// default frame costs about one substep, not two.)
pub const COURANT_STEPS_PER_FRAME: f64 = 2.0;

/// Most frames of a default recording (about 10 MB with an 8 x 8 sensor).
pub const MAX_DEFAULT_FRAMES: u32 = 20_000;

/// How to record a catalogue scene (the truth grid is the scene's `grid.cells`).
#[derive(Clone, Debug, PartialEq)]
pub struct SceneRecordOptions {
    /// Estimator grid of the sensor configuration (at most 1024 cells).
    pub estimator_cells: [u16; 2],
    /// Sensor grid (x, z), at most 16 x 16; also the grid of the stored truth phihat.
    pub sensor: [u8; 2],
    /// Velocity noise: standard deviation relative to the largest speed of the scene.
    pub noise: f64,
    /// Noise seed.
    pub seed: u64,
    /// Frame period \[s\]; `None`: [`COURANT_STEPS_PER_FRAME`] Courant steps of the estimator.
    pub period: Option<f64>,
    /// Frames; `None`: enough to cover `run.t_end` (at most [`MAX_DEFAULT_FRAMES`]).
    pub frames: Option<u32>,
    /// Clock of the CPU the tick budget is for \[Hz\] ([`super::DEFAULT_CPU_HZ`]).
    pub cpu_hz: f64,
    /// Share of every tick period the CPU grants the sensor, in (0, 1].
    pub cpu_share: f64,
}

impl Default for SceneRecordOptions {
    fn default() -> Self {
        Self {
            estimator_cells: [32, 32],
            sensor: [8, 8],
            noise: 0.05,
            seed: 1,
            period: None,
            frames: None,
            cpu_hz: super::DEFAULT_CPU_HZ,
            cpu_share: 1.0,
        }
    }
}

/// What a catalogue recording did.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneRecordReport {
    /// Frames, bytes, final truth psi.
    pub record: RecordReport,
    /// Frame period \[s\].
    pub period: f64,
    /// Truth grid.
    pub truth_cells: [usize; 2],
    /// Stable substep of the estimator with the clean velocity \[s\].
    pub estimator_dt: f64,
    /// S0 written into the sensor configuration.
    pub sensor_s0: f64,
    /// c written into the sensor configuration.
    pub c: f64,
    /// Where the sensor configuration departs from the scene (one line each).
    pub notes: Vec<String>,
    /// The frozen flow's summary (frozen-flow scenes).
    pub flow: Option<FlowSummary>,
}

/// Checks that `scene` can be recorded: 2D, model "prescribed" or "frozen-flow", a truth grid
/// whose axes fit the recording header.
pub fn check(scene: &Scene) -> Result<()> {
    if scene.dim != 2 {
        return Err(Error::range(
            &scene.label,
            "dim",
            scene.dim,
            "2 (the soft sensor estimates a 2D x-z field)",
        ));
    }
    if scene.geometry.is_some() || scene.frame.is_some() {
        return Err(Error::range(
            &scene.label,
            "geometry",
            "a container or a rotating frame",
            "a box scene without [geometry] and [frame] (the soft sensor's estimator is a box in the lab frame)",
        ));
    }
    if scene.cells.iter().any(|&n| n > u16::MAX as usize) {
        return Err(Error::range(
            &scene.label,
            "grid.cells",
            format!("{:?}", scene.cells),
            "at most 65535 cells per axis for a recording",
        ));
    }
    Ok(())
}

/// Records a validated scene: runs its truth on a solver thread and returns the recording
/// bytes and the report. Input errors (exit 2) name the scene file and the key.
pub fn record_scene(
    scene: &Scene,
    fields: &Fields,
    opts: &SceneRecordOptions,
) -> Result<(Vec<u8>, SceneRecordReport)> {
    check(scene)?;
    let job = RecordJob {
        scene,
        fields,
        opts,
    };
    crate::run::with_scene_solvers(scene, job)
}

struct RecordJob<'a> {
    scene: &'a Scene,
    fields: &'a Fields,
    opts: &'a SceneRecordOptions,
}

impl SolverJob for RecordJob<'_> {
    type Output = (Vec<u8>, SceneRecordReport);
    fn run<R: Real, const D: usize, const N: usize>(
        self,
        s: &mut Segregation<R, D, N>,
    ) -> Result<Self::Output> {
        crate::run::load(s, self.scene, self.fields)?;
        record_loop(s, self.scene, self.fields, self.opts, None)
    }
}

impl FlowJob for RecordJob<'_> {
    type Output = (Vec<u8>, SceneRecordReport);
    fn run<R: Real, const D: usize, const N: usize>(
        self,
        s: &mut Segregation<R, D, N>,
        f: &mut Flow<R, D, N>,
    ) -> Result<Self::Output> {
        crate::run::load(s, self.scene, self.fields)?;
        if self.scene.flow.as_ref().map(|m| m.equations) == Some(Equations::Coupled) {
            return record_coupled(s, f, self.scene, self.fields, self.opts);
        }
        let frozen = crate::flow::spin_up(f, self.scene, self.fields)?;
        crate::flow::hand_over_frozen(s, self.scene, self.fields, &frozen)?;
        record_loop(s, self.scene, self.fields, self.opts, Some(frozen.summary))
    }
}

fn spread(v: &[f64]) -> (f64, f64) {
    v.iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        })
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// Rounds down to two significant digits (a readable frame period).
fn round_down_2(x: f64) -> f64 {
    let e = 10f64.powf(x.log10().floor() - 1.0);
    ((x / e).floor() * e).max(f64::MIN_POSITIVE)
}

/// Largest difference between a sensor point and its 3 x 3 neighbours in the clean field
/// (wrapped on periodic axes): what the median filter must leave alone.
fn profile_step(u: [&[f64]; 2], ns: [usize; 2], periodic: [bool; 2]) -> f64 {
    let mut step: f64 = 0.0;
    for iz in 0..ns[1] {
        for ix in 0..ns[0] {
            for dz in -1i64..=1 {
                for dx in -1i64..=1 {
                    let nb = |c: usize, d: i64, len: usize, per: bool| -> Option<usize> {
                        let k = c as i64 + d;
                        if (0..len as i64).contains(&k) {
                            Some(k as usize)
                        } else if per {
                            Some(k.rem_euclid(len as i64) as usize)
                        } else {
                            None
                        }
                    };
                    let (Some(jx), Some(jz)) = (
                        nb(ix, dx, ns[0], periodic[0]),
                        nb(iz, dz, ns[1], periodic[1]),
                    ) else {
                        continue;
                    };
                    for comp in u {
                        step = step.max((comp[ix + ns[0] * iz] - comp[jx + ns[0] * jz]).abs());
                    }
                }
            }
        }
    }
    step
}

/// The cycle budget of a `period` tick for `cfg`'s grids ([`super::cpu_budget`]); refused in
/// one line if it does not cover the fixed part of a tick and one substep.
fn budget_for(
    cfg: &SensorConfig<f32>,
    opts: &SceneRecordOptions,
    period: f64,
    label: &str,
) -> Result<CycleBudget> {
    let budget = super::cpu_budget(opts.cpu_hz, opts.cpu_share, period);
    let (grid, cells, points) = (cfg.estimator_grid(), cfg.cell_count(), cfg.sensor_points());
    if budget.substeps(grid, points) == 0 {
        return Err(Error::at(
            label,
            "",
            format!(
                "a {period} s tick on a {} MHz CPU at share {} gives the sensor {} cycles, less than the fixed part of a tick ({}) plus one substep ({}) of a {}-cell estimator with {} sensor points: lower --rate, the estimator or sensor grid, or raise --cpu-mhz / --cpu-share",
                opts.cpu_hz / 1e6,
                opts.cpu_share,
                budget.cycles,
                budget.fixed(grid, points),
                budget.substep(grid),
                cells,
                points
            ),
        ));
    }
    Ok(budget)
}

/// The stable substep of the soft sensor (f32, the firmware's estimator) with the clean
/// sensor velocity, and the Courant step of its combined rate that sets the default frame
/// period ([`COURANT_STEPS_PER_FRAME`]): one tick of a tiny period, then both steps.
fn estimator_dt(cfg: &SensorConfig<f32>, clean: &[f32]) -> Result<(f64, f64)> {
    let mut probe = cfg.clone();
    probe.tick_period = 1e-6;
    probe.budget = CycleBudget::for_substeps(1, probe.cell_count());
    let mut sensor: Box<SoftSensor<f32, ESTIMATOR_CAPACITY>> = Box::default();
    sensor
        .configure(&probe)
        .map_err(|e| Error::failure(format!("sensor configuration: {e}")))?;
    let mut frame = VelocityFrame {
        seq: 1,
        time: 1e-6,
        period: 1e-6,
        nx: cfg.sensor[0],
        nz: cfg.sensor[1],
        u: Default::default(),
    };
    for &v in clean {
        frame
            .u
            .push(v)
            .map_err(|_| Error::failure("frame capacity"))?;
    }
    sensor
        .submit(&frame)
        .map_err(|e| Error::failure(format!("probe frame rejected: {e}")))?;
    sensor.finish_tick();
    Ok((
        sensor.stable_dt() as f64,
        sensor.segregation().stable_dt() as f64,
    ))
}

fn record_loop<R: Real, const D: usize, const N: usize>(
    s: &mut Segregation<R, D, N>,
    scene: &Scene,
    fields: &Fields,
    opts: &SceneRecordOptions,
    flow: Option<FlowSummary>,
) -> Result<(Vec<u8>, SceneRecordReport)> {
    let label = &scene.label;
    let fail = |e: String| Error::failure(format!("{label}: {e}"));
    let nf = [scene.cells[0], scene.cells[1]];
    let n = nf[0] * nf[1];
    let ns = [opts.sensor[0] as usize, opts.sensor[1] as usize];
    let ne = [
        opts.estimator_cells[0] as usize,
        opts.estimator_cells[1] as usize,
    ];
    let periodic = [
        scene.boundaries[0][0] == Boundary::Periodic,
        scene.boundaries[1][0] == Boundary::Periodic,
    ];
    let extent = [
        scene.upper[0] - scene.lower[0],
        scene.upper[1] - scene.lower[1],
    ];
    // The truth's own fields (after the flow hand-over for frozen-flow scenes).
    let ux: Vec<f64> = (0..n).map(|i| s.velocity(i)[0].to_f64()).collect();
    let uz: Vec<f64> = (0..n).map(|i| s.velocity(i)[D - 1].to_f64()).collect();
    let c: Vec<f64> = (0..n).map(|i| s.c(i).to_f64()).collect();
    let phi: Vec<f64> = (0..n).map(|i| s.phi(i).to_f64()).collect();
    let temp: Vec<f64> = (0..n).map(|i| s.temperature(i).to_f64()).collect();
    let umax = ux
        .iter()
        .zip(&uz)
        .map(|(a, b)| a.hypot(*b))
        .fold(0.0, f64::max);
    if !(umax > 0.0) {
        return Err(Error::at(
            label,
            "initial.u",
            "zero everywhere: the soft sensor measures a flow; allowed: a scene with a moving (sheared) velocity field",
        ));
    }
    let mut notes = Vec::new();
    // Sensor velocity: the truth velocity averaged over each sensor cell.
    let sx = coarsen(|i| ux[i], nf, ns);
    let sz = coarsen(|i| uz[i], nf, ns);
    // Material of the sensor's T-from-shear.
    // sqrt(kappa:kappa) per cell, differenced as the solver does
    let gamma: Vec<f64> = (0..n)
        .map(|i| shear_rate_squared(&s.velocity_gradient(i)).to_f64().sqrt())
        .collect();
    let (heating, eta0, eps0, s0) = match (&scene.flow, scene.temperature) {
        (Some(fm), _) => (fm.heating, fm.eta0, fm.eps0, scene.s0),
        (
            None,
            Temperature::Shear {
                heating,
                eta0,
                eps0,
            },
        ) => (heating, eta0, eps0, scene.s0),
        (None, Temperature::Given) => {
            let g_mean = mean(&gamma);
            if !(g_mean > 0.0) {
                return Err(Error::at(
                    label,
                    "initial.u",
                    "has no shear: the soft sensor derives T from the measured shear rate (model.md 2), so with physics.temperature = \"given\" it needs a sheared velocity field",
                ));
            }
            let sqrt_t: Vec<f64> = temp.iter().map(|t| t.max(0.0).sqrt()).collect();
            let s0 = scene.s0 * mean(&sqrt_t) / ((HEATING * ETA0 / EPS0).sqrt() * g_mean);
            let (tlo, thi) = spread(&temp);
            let (glo, ghi) = spread(&gamma);
            notes.push(format!(
                "T is given ({tlo:.4e}..{thi:.4e} m^2/s^2): the soft sensor derives T from the measured shear with the glass beads' a, eta0, eps0 and S0 = {s0:.6e} (S0 sqrt(T) matched at the mean shear rate {g_mean:.4e} 1/s{})",
                if thi - tlo > 1e-9 * thi.abs() || ghi - glo > 1e-6 * ghi.abs() {
                    "; T or the shear rate is not uniform, so only on average"
                } else {
                    ""
                }
            ));
            (HEATING, ETA0, EPS0, s0)
        }
    };
    if scene.direction != Direction::Flow {
        notes.push(format!(
            "the scene segregates along {:?}; the soft sensor takes the direction from the measured flow",
            scene.direction
        ));
    }
    // c: uniform or the mean.
    let (clo, chi) = spread(&c);
    let c_sensor = if chi - clo <= 1e-12 * chi {
        chi
    } else {
        let m = mean(&c);
        notes.push(format!(
            "c is not uniform ({clo:.4}..{chi:.4}): the sensor configuration takes its mean {m:.4}"
        ));
        m
    };
    // Initial phihat: small mass / total mass; inflow phihat: the mean over inflow cells.
    let phihat: Vec<f64> = phi
        .iter()
        .zip(&c)
        .map(|(p, c)| if *c > 0.0 { p / c } else { 0.0 })
        .collect();
    let initial = (phi.iter().sum::<f64>() / c.iter().sum::<f64>()).clamp(0.0, 1.0);
    let (plo, phi_hi) = spread(&phihat);
    if phi_hi - plo > 1e-9 {
        notes.push(format!(
            "the initial phihat is not uniform ({plo:.3}..{phi_hi:.3}): the soft sensor starts from its mean {initial:.4} (the recording carries one initial phihat), so it misses the initial layering"
        ));
    }
    let inflow: Vec<f64> = (0..n)
        .filter(|&i| scene.on_inflow_side(i) && fields.c[i] > 0.0)
        .map(|i| fields.inflow[i] / fields.c[i])
        .collect();
    let inflow_phihat = if inflow.is_empty() {
        initial
    } else {
        mean(&inflow).clamp(0.0, 1.0)
    };
    // Configuration.
    let sigma = opts.noise * umax;
    let step = profile_step([&sx, &sz], ns, periodic);
    let (ne0, ne1) = (opts.estimator_cells[0], opts.estimator_cells[1]);
    let q = (ne1 / 4).max(1);
    let bc = [scene.boundaries[0], scene.boundaries[1]];
    let f = |x: f64| x as f32;
    let mut cfg = SensorConfig {
        cells: opts.estimator_cells,
        extent: [f(extent[0]), f(extent[1])],
        bc,
        sensor: opts.sensor,
        s0: f(s0),
        eta0: f(eta0),
        eps0: f(eps0),
        heating: f(heating),
        gravity: [f(scene.gravity[0]), f(scene.gravity[1])],
        c: f(c_sensor),
        fill_level: f(extent[1]),
        initial_phihat: f(initial),
        inflow_phihat: f(inflow_phihat),
        diffusion: f(scene.diffusion),
        courant: 0.5,
        tick_period: 1.0,
        max_period_factor: 2.0,
        // The budget of a 1 s tick until the period is known (below).
        budget: super::cpu_budget(opts.cpu_hz, opts.cpu_share, 1.0),
        hold_ticks: 5,
        reject_speed: f(3.0 * umax),
        outlier_tol: f(6.0 * sigma + step + 1e-3 * umax),
        // As the legacy scenes: an EMA over about 50 frames for these steady flows, two 1-2-1
        // passes against the gradient noise (which inflates T).
        smoothing: if opts.noise > 0.0 { 0.02 } else { 1.0 },
        spatial_passes: if opts.noise > 0.0 { 2 } else { 0 },
        track_large: false,
        regions: Default::default(),
        outlet: None,
        psi_alarm: 0.3,
        fines_band: [0.4, 0.8],
        fines_hysteresis: 0.01,
        alarm_persist: 3,
        openings: Default::default(),
        outflow_window: 10,
        noise_term: 0.0,
    };
    if ne0 == 0 || ne1 == 0 {
        return Err(Error::range(
            "command line",
            "--estimator-grid",
            format!("{ne0}x{ne1}"),
            "at least 1 cell per axis, at most 1024 cells (32x32)",
        ));
    }
    let mut regions = Vec::new();
    if bc[0][1] == Boundary::Outflow {
        regions.push(Region::new("outlet", [ne0 - 1, 0], [ne0, ne1]));
        cfg.outlet = Some(0);
    }
    regions.push(Region::new("bottom", [0, 0], [ne0, q]));
    regions.push(Region::new("top", [0, ne1 - q], [ne0, ne1]));
    for r in regions {
        // At most 3 of MAX_REGIONS (4).
        let _ = cfg.regions.push(r);
    }
    cfg.validate(ESTIMATOR_CAPACITY).map_err(|e| {
        Error::at(
            label,
            "",
            format!(
                "cannot make a sensor configuration from this scene ({e}; the estimator holds at most {ESTIMATOR_CAPACITY} cells)"
            ),
        )
    })?;
    // Period and frames.
    let clean: Vec<f32> = (0..ns[0] * ns[1])
        .flat_map(|i| [sx[i] as f32, sz[i] as f32])
        .collect();
    let (dt, courant_dt) = estimator_dt(&cfg, &clean)?;
    let period = match opts.period {
        Some(p) => p,
        None if courant_dt.is_finite() && courant_dt < f32::MAX as f64 => {
            round_down_2(COURANT_STEPS_PER_FRAME * courant_dt)
        }
        None => scene.output_interval,
    };
    let frames = match opts.frames {
        Some(k) => k,
        None => {
            let k = (scene.t_end / period).ceil().max(1.0);
            if k > MAX_DEFAULT_FRAMES as f64 {
                notes.push(format!(
                    "run.t_end = {} s needs {k} frames of {period} s: recording the first {MAX_DEFAULT_FRAMES} (--frames or --rate to choose)",
                    scene.t_end
                ));
            }
            k.min(MAX_DEFAULT_FRAMES as f64) as u32
        }
    };
    cfg.tick_period = f(period);
    cfg.budget = budget_for(&cfg, opts, period, label)?;
    // The truth's step is fixed (its flow is prescribed or frozen): a frame longer than
    // `cap` of them is refused before stepping, not after (a 1e-30 Hz rate stepped 90 s).
    let cap = 1u64 << 24;
    let truth_dt = s.stable_dt().to_f64();
    if period / truth_dt >= cap as f64 {
        let why = format!(
            "its truth takes steps of {truth_dt:.4e} s, at most {cap} a frame (frames of at most {:.4e} s)",
            cap as f64 * truth_dt
        );
        return Err(match opts.period {
            Some(_) => Error::range(
                "command line",
                "--rate",
                1.0 / period,
                &format!(
                    "HZ > {:.4e} for this scene: {why}",
                    1.0 / (cap as f64 * truth_dt)
                ),
            ),
            None => fail(format!("a frame of {period} s is too long: {why}")),
        });
    }
    // Frames and truth.
    let mut writer = Writer::new(opts.sensor, period, sigma, opts.seed).map_err(fail)?;
    let mut final_psi = 0.0;
    for k in 1..=frames {
        crate::interrupt::check("sieve record")?;
        writer
            .frame(k, |ix, iz| [sx[ix + ns[0] * iz], sz[ix + ns[0] * iz]])
            .map_err(fail)?;
        let target = R::from_f64(k as f64 * period);
        if s.advance_to(target, cap) >= cap {
            return Err(fail(format!(
                "the truth did not reach t = {} s in {cap} steps",
                k as f64 * period
            )));
        }
        let (psi, psi_ne, coarse, coarse_c) = truth_on_sensor(s, nf, ns, ne);
        final_psi = psi;
        writer
            .truth(
                k,
                s.time().to_f64(),
                final_psi,
                psi_ne,
                &coarse,
                &coarse_c,
                [0.0, 0.0],
            )
            .map_err(fail)?;
    }
    let (bytes, record) = finish(writer, cfg, scene, opts, nf, frames, final_psi)?;
    let report = SceneRecordReport {
        record,
        period,
        truth_cells: nf,
        estimator_dt: dt,
        sensor_s0: s0,
        c: c_sensor,
        notes,
        flow,
    };
    Ok((bytes, report))
}

/// The initial c of a coupled scene as the soft sensor's configuration: a bed of one c below
/// a free surface (every cell either within 0.1 % of the largest c or below 1e-6 of it, the
/// full cells below the empty ones) gives that c and the fill level (the bed's volume over the
/// box width); anything else its mean c over the whole box (noted).
fn bed_of(c: &[f64], nf: [usize; 2], extent: [f64; 2], notes: &mut Vec<String>) -> (f64, f64) {
    let (lo, hi) = spread(c);
    if hi - lo <= 1e-12 * hi {
        return (hi, extent[1]);
    }
    let full = |v: f64| v >= 0.999 * hi;
    let empty = |v: f64| v <= 1e-6 * hi;
    let layered = (0..nf[0]).all(|ix| {
        let mut seen_empty = false;
        (0..nf[1]).all(|iz| {
            let v = c[ix + nf[0] * iz];
            if empty(v) {
                seen_empty = true;
                true
            } else {
                full(v) && !seen_empty
            }
        })
    });
    if layered {
        let dx = extent[0] / nf[0] as f64;
        let dz = extent[1] / nf[1] as f64;
        let volume: f64 = c.iter().filter(|v| full(**v)).map(|v| v * dx * dz).sum();
        let level = volume / (hi * extent[0]);
        notes.push(format!(
            "c is a bed of {hi:.4} filled to {level:.4} m: the sensor configuration starts from that fill level (then carries c with the measured flow)"
        ));
        (hi, level)
    } else {
        let m = mean(c);
        notes.push(format!(
            "c is not uniform ({lo:.4}..{hi:.4}) and not a bed below a free surface: the sensor configuration takes its mean {m:.4}"
        ));
        (m, extent[1])
    }
}

/// Records a coupled scene (issue 9). The truth is the coupled run, as `sieve run` runs it
/// ([`crate::flow::coupled_loop`]), with its output times at the frame times: at each frame
/// time it stores the truth's psi, phihat and c on the sensor grid and the grains and small
/// grains that had left the box (initial minus present amounts: the coupled run conserves
/// both to round-off, docs/silo.md), and frame `k + 1` is the truth's velocity at the time of
/// frame `k` (the measurement at the start of the period it covers), averaged c-weighted over
/// each sensor cell (a PIV window sees grains only; 0 where there are none) plus Gaussian
/// noise of `noise` times that frame's largest sensor speed. The sensor configuration: the
/// scene's box, wall kinds and openings (the flow's outlets, through which the estimator's
/// grains leave), the material's a, eta0, eps0 and S0, the initial bed ([`bed_of`]), mixed
/// start, a temporal smoothing of a few frames (the flow changes), and a substep budget that
/// fits the fastest frame (the cap of 4 would hold back a discharge at 10 Hz). Default frame
/// period: the scene's output interval.
/// Closes a catalogue recording: the file's bytes (header with `cfg`, frames, truth) and
/// what was written, for both kinds of truth (prescribed or frozen, coupled).
fn finish(
    writer: Writer,
    cfg: SensorConfig<f32>,
    scene: &Scene,
    opts: &SceneRecordOptions,
    truth_cells: [usize; 2],
    frames: u32,
    final_truth_psi: f64,
) -> Result<(Vec<u8>, RecordReport)> {
    let (bytes, stream_bytes) = writer
        .finish(
            cfg,
            &scene.name,
            opts.noise,
            opts.seed,
            [truth_cells[0] as u16, truth_cells[1] as u16],
        )
        .map_err(|e| Error::failure(format!("{}: {e}", scene.label)))?;
    let record = RecordReport {
        frames,
        stream_bytes,
        file_bytes: bytes.len(),
        final_truth_psi,
    };
    Ok((bytes, record))
}

/// Outlets narrower than this many sensor spacings get no 1-2-1 pass: the filter averages
/// three points, so it spreads a jet that fewer points see over the walls beside it.
/// Measured on the full-size silo (docs/soft-sensor.md "Sensor grid, filter and gain on the
/// silo"): the pass raised the largest outflow window error with the outlet 1.1 and 2.2
/// spacings wide and lowered it at 3.3 and 4.4.
const PASS_MIN_OUTLET_POINTS: f64 = 3.0;

/// The 1-2-1 passes over the frames of a coupled recording: one where the frames are noisy,
/// the sensor has at least 8 points on both axes and every outlet (`outlet_points`, the
/// narrowest one in sensor spacings) spans at least [`PASS_MIN_OUTLET_POINTS`]; none
/// otherwise. On a coarser sensor one pass spreads the orifice jet over the silo's width
/// (the full-size silo's 4 x 14 sensor: 76 % of the truth's grains out with it, 98.6 %
/// without); on 16 points across a 0.04 m orifice it cuts the noise of the measured shear.
fn coupled_passes(noise: f64, ns: [usize; 2], outlet_points: Option<f64>) -> u8 {
    let enough_points = ns[0].min(ns[1]) >= 8;
    let wide_outlets = outlet_points.is_none_or(|w| w >= PASS_MIN_OUTLET_POINTS);
    u8::from(noise > 0.0 && enough_points && wide_outlets)
}

fn record_coupled<R: Real, const D: usize, const N: usize>(
    s: &mut Segregation<R, D, N>,
    f: &mut Flow<R, D, N>,
    scene: &Scene,
    fields: &Fields,
    opts: &SceneRecordOptions,
) -> Result<(Vec<u8>, SceneRecordReport)> {
    let label = &scene.label;
    let fail = |e: String| Error::failure(format!("{label}: {e}"));
    let fm = scene
        .flow
        .as_ref()
        .ok_or_else(|| Error::failure("no flow in scene"))?;
    let nf = [scene.cells[0], scene.cells[1]];
    let n = nf[0] * nf[1];
    let ns = [opts.sensor[0] as usize, opts.sensor[1] as usize];
    let ne = [
        opts.estimator_cells[0] as usize,
        opts.estimator_cells[1] as usize,
    ];
    let extent = [
        scene.upper[0] - scene.lower[0],
        scene.upper[1] - scene.lower[1],
    ];
    let mut notes = Vec::new();
    let c0: Vec<f64> = (0..n).map(|i| s.c(i).to_f64()).collect();
    let (c_sensor, fill) = bed_of(&c0, nf, extent, &mut notes);
    let phi0: f64 = (0..n).map(|i| s.phi(i).to_f64()).sum();
    let initial = (phi0 / c0.iter().sum::<f64>()).clamp(0.0, 1.0);
    let period = opts.period.unwrap_or(scene.output_interval);
    let frames = match opts.frames {
        Some(k) => k,
        None => (scene.t_end / period)
            .ceil()
            .clamp(1.0, MAX_DEFAULT_FRAMES as f64) as u32,
    };
    let (ne0, ne1) = (opts.estimator_cells[0], opts.estimator_cells[1]);
    if ne0 == 0 || ne1 == 0 {
        return Err(Error::range(
            "command line",
            "--estimator-grid",
            format!("{ne0}x{ne1}"),
            "at least 1 cell per axis, at most 1024 cells (32x32)",
        ));
    }
    let f32_ = |x: f64| x as f32;
    let bc = [scene.boundaries[0], scene.boundaries[1]];
    let mut cfg = SensorConfig {
        cells: opts.estimator_cells,
        extent: [f32_(extent[0]), f32_(extent[1])],
        bc,
        sensor: opts.sensor,
        s0: f32_(scene.s0),
        eta0: f32_(fm.eta0),
        eps0: f32_(fm.eps0),
        heating: f32_(fm.heating),
        gravity: [f32_(scene.gravity[0]), f32_(scene.gravity[1])],
        c: f32_(c_sensor),
        fill_level: f32_(fill),
        initial_phihat: f32_(initial),
        inflow_phihat: f32_(initial),
        diffusion: f32_(scene.diffusion),
        courant: 0.5,
        tick_period: f32_(period),
        max_period_factor: 2.0,
        budget: super::cpu_budget(opts.cpu_hz, opts.cpu_share, period),
        hold_ticks: 5,
        reject_speed: 1.0,
        outlier_tol: 1.0,
        // The flow changes over a discharge, so no moving average: on the full-size silo
        // (5 % noise, 10 Hz) an EMA of weight 0.3 lags the draining flow and made the outflow
        // fines error and the map worse on every sensor grid measured. The 1-2-1 passes are
        // set below, once the outlets are known (`coupled_passes`). docs/soft-sensor.md
        // "Sensor grid, filter and gain on the silo".
        smoothing: 1.0,
        spatial_passes: coupled_passes(opts.noise, ns, None),
        track_large: false,
        regions: Default::default(),
        outlet: None,
        psi_alarm: 0.3,
        // the product's specification where the scene declares one (`run.fines_band`, the
        // band of the run's on-spec readout), else an alarm on the fines-rich end only
        fines_band: scene.fines_band.map_or([0.4, 0.8], |b| b.map(f32_)),
        fines_hysteresis: 0.01,
        alarm_persist: 3,
        openings: Default::default(),
        outflow_window: 10,
        noise_term: 0.0,
    };
    // The flow's outlets as openings of the estimator's walls; the estimator cells just
    // inside the first one are the "outlet" region.
    let mut outlet_region = None;
    for (a, sides) in fm.walls.iter().enumerate().take(2) {
        for (side, w) in sides.iter().enumerate() {
            if let Some(o) = &w.outlet {
                let t = 1 - a;
                let (lo, hi) = (o.lower[t] - scene.lower[t], o.upper[t] - scene.lower[t]);
                cfg.openings
                    .push(sieve_core::sensor::SensorOpening {
                        axis: a as u8,
                        high: side == 1,
                        lower: f32_(lo.max(0.0)),
                        upper: f32_(hi.min(extent[t])),
                    })
                    .map_err(|_| {
                        Error::at(
                            label,
                            "boundary.flow",
                            "more than 2 outlets: the soft sensor takes at most 2",
                        )
                    })?;
                if outlet_region.is_none() {
                    let ne = [ne0 as f64, ne1 as f64];
                    let k0 = ((lo / extent[t] * ne[t]).floor().max(0.0) as u16)
                        .min(opts.estimator_cells[t] - 1);
                    let k1 = ((hi / extent[t] * ne[t]).ceil() as u16)
                        .clamp(k0 + 1, opts.estimator_cells[t]);
                    let at = if side == 1 {
                        opts.estimator_cells[a] - 1
                    } else {
                        0
                    };
                    let mut lo_c = [0u16; 2];
                    let mut hi_c = [0u16; 2];
                    lo_c[t] = k0;
                    hi_c[t] = k1;
                    lo_c[a] = at;
                    hi_c[a] = at + 1;
                    outlet_region = Some(Region::new("outlet", lo_c, hi_c));
                }
            }
        }
    }
    // The 1-2-1 pass only where every outlet spans enough sensor points to keep its jet.
    let outlet_points = cfg
        .openings
        .iter()
        .map(|o| {
            let t = 1 - o.axis as usize;
            f64::from(o.upper - o.lower) * ns[t] as f64 / extent[t]
        })
        .reduce(f64::min);
    cfg.spatial_passes = coupled_passes(opts.noise, ns, outlet_points);
    if let Some(w) = outlet_points.filter(|_| cfg.spatial_passes == 0) {
        if coupled_passes(opts.noise, ns, None) > 0 {
            notes.push(format!(
                "no 1-2-1 pass over the frames: the outlet spans {w:.1} sensor spacings, and the pass (3 points wide) would spread its jet (`sieve replay --spatial-passes 1` to compare; docs/soft-sensor.md \"Sensor grid, filter and gain on the silo\")"
            ));
        }
    }
    // A discharge's fines-rich end comes from shear bands along the stagnant zones, a few
    // grains wide: a sensor with few points across the outlet's wall smooths them away
    // (docs/soft-sensor.md "Sensor grid, filter and gain on the silo": largest window error
    // 0.35 / 0.27 / 0.22 with 4 / 8 / 16 points across the full silo).
    if let Some(o) = cfg.openings.first() {
        let across = ns[1 - o.axis as usize];
        if across < 16 {
            notes.push(format!(
                "{across} sensor points across the outlet's wall: the shear bands along the stagnant zones fall between them, so the estimate follows the mixed discharge but not its fines-rich end (about 16 points across follow it better; docs/soft-sensor.md \"Sensor grid, filter and gain on the silo\")"
            ));
        }
    }
    let q = (ne1 / 4).max(1);
    if let Some(r) = outlet_region {
        let _ = cfg.regions.push(r);
        cfg.outlet = Some(0);
    }
    let _ = cfg.regions.push(Region::new("bottom", [0, 0], [ne0, q]));
    let _ = cfg
        .regions
        .push(Region::new("top", [0, ne1 - q], [ne0, ne1]));
    // The truth: the coupled run with its outputs at the frame times.
    let mut truth_scene = scene.clone();
    truth_scene.t_end = frames as f64 * period;
    truth_scene.output_interval = period;
    let vol = s.grid().cell_volume().to_f64();
    let mass = |s: &Segregation<R, D, N>| -> [f64; 2] {
        let mut m = [0.0; 2];
        for i in 0..s.len() {
            m[0] += s.c(i).to_f64() * vol;
            m[1] += s.phi(i).to_f64() * vol;
        }
        m
    };
    let m0 = mass(s);
    let mut writer = Writer::new(opts.sensor, period, 0.0, opts.seed).map_err(fail)?;
    let mut written = 0u32;
    let mut final_psi = 0.0;
    let (mut umax, mut step_max) = (0.0f64, 0.0f64);
    let mut fastest: Vec<f32> = Vec::new();
    let periodic = [
        bc[0][0] == Boundary::Periodic,
        bc[1][0] == Boundary::Periodic,
    ];
    let bar = crate::progress::Progress::hidden();
    crate::flow::coupled_loop(f, s, &truth_scene, fields, None, &bar, |k, t, seg, _| {
        crate::interrupt::check("sieve record")?;
        if k >= 1 {
            let (psi, psi_ne, coarse, coarse_c) = truth_on_sensor(seg, nf, ns, ne);
            final_psi = psi;
            let m = mass(seg);
            writer
                .truth(
                    k as u32,
                    t,
                    final_psi,
                    psi_ne,
                    &coarse,
                    &coarse_c,
                    [m0[0] - m[0], m0[1] - m[1]],
                )
                .map_err(fail)?;
            written = k as u32;
        }
        if (k as u32) < frames {
            // c-weighted mean velocity per sensor cell: momentum over grains.
            let cu =
                |a: usize| coarsen(|i| seg.c(i).to_f64() * seg.velocity(i)[a].to_f64(), nf, ns);
            let cc = coarsen(|i| seg.c(i).to_f64(), nf, ns);
            let (mx, mz) = (cu(0), cu(D - 1));
            let mean_u = |m: &[f64]| -> Vec<f64> {
                m.iter()
                    .zip(&cc)
                    .map(|(m, c)| if *c > 1e-6 { m / c } else { 0.0 })
                    .collect()
            };
            let (sx, sz) = (mean_u(&mx), mean_u(&mz));
            let top = sx
                .iter()
                .zip(&sz)
                .map(|(a, b)| a.hypot(*b))
                .fold(0.0, f64::max);
            if top > umax {
                umax = top;
                fastest = (0..ns[0] * ns[1])
                    .flat_map(|i| [sx[i] as f32, sz[i] as f32])
                    .collect();
            }
            step_max = step_max.max(profile_step([&sx, &sz], ns, periodic));
            writer.set_sigma(opts.noise * top);
            writer
                .frame(k as u32 + 1, |ix, iz| {
                    [sx[ix + ns[0] * iz], sz[ix + ns[0] * iz]]
                })
                .map_err(fail)?;
        }
        Ok(())
    })?;
    if written < frames {
        notes.push(format!(
            "the discharge ended at t = {} s: {written} of {frames} frames recorded",
            written as f64 * period
        ));
    }
    // Input limits and the budget from the fastest frame.
    let sigma = opts.noise * umax;
    cfg.reject_speed = f32_(3.0 * umax + 6.0 * sigma).max(1e-6);
    cfg.outlier_tol = f32_(6.0 * sigma + step_max + 1e-3 * umax).max(1e-9);
    cfg.validate(ESTIMATOR_CAPACITY).map_err(|e| {
        Error::at(
            label,
            "",
            format!(
                "cannot make a sensor configuration from this scene ({e}; the estimator holds at most {ESTIMATOR_CAPACITY} cells)"
            ),
        )
    })?;
    let dt = if fastest.is_empty() {
        f64::INFINITY
    } else {
        estimator_dt(&cfg, &fastest)?.0
    };
    cfg.budget = budget_for(&cfg, opts, period, label)?;
    if dt.is_finite() && dt > 0.0 {
        // Room for the noise, which raises the measured speeds and shear.
        let need = (1.5 * period / dt).ceil().clamp(1.0, 1024.0) as u16;
        let cap = cfg.substep_cap();
        if need > cap {
            notes.push(format!(
                "the fastest frame needs {need} substeps of {dt:.3e} s per {period} s tick; the cycle budget ({} cycles) affords {cap}: such ticks are budget-limited (lag)",
                cfg.budget.cycles
            ));
        }
    }
    let (bytes, record) = finish(writer, cfg, scene, opts, nf, written.min(frames), final_psi)?;
    let report = SceneRecordReport {
        record,
        period,
        truth_cells: nf,
        estimator_dt: dt,
        sensor_s0: scene.s0,
        c: c_sensor,
        notes,
        flow: None,
    };
    Ok((bytes, report))
}

/// What a recording stores of the truth at a frame: its psi (full grid) and its phihat and c
/// averaged onto the sensor grid (`nf` truth cells, `ns` sensor cells; empty cells count as
/// phihat 0).
fn truth_on_sensor<R: Real, const D: usize, const N: usize>(
    s: &Segregation<R, D, N>,
    nf: [usize; 2],
    ns: [usize; 2],
    ne: [usize; 2],
) -> (f64, f64, Vec<f64>, Vec<f64>) {
    let psi = diagnose(s).psi.to_f64();
    let psi_ne = psi_on_grid(
        |i| s.phi(i).to_f64(),
        |i| s.c(i).to_f64(),
        nf,
        ne,
        s.config().vacuum.to_f64(),
    );
    let phihat = coarsen(
        |i| {
            let ci = s.c(i).to_f64();
            if ci > 0.0 {
                s.phi(i).to_f64() / ci
            } else {
                0.0
            }
        },
        nf,
        ns,
    );
    let c = coarsen(|i| s.c(i).to_f64(), nf, ns);
    (psi, psi_ne, phihat, c)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn period_rounding() {
        assert_eq!(round_down_2(0.0376), 0.037);
        assert!((round_down_2(0.1449) - 0.14).abs() < 1e-15);
    }

    /// The pass rule against the silo recordings it was measured on (docs/soft-sensor.md
    /// "Sensor grid, filter and gain on the silo").
    #[test]
    fn passes_only_where_sensor_and_outlet_have_the_points() {
        let points = |w: f64, across: usize| Some(w * across as f64 / 0.145);
        // the catalogue silo: 0.02 m orifice, 8 x 8 sensor (1.1 spacings): no pass
        assert_eq!(coupled_passes(0.05, [8, 8], points(0.02, 8)), 0);
        // 0.04 m: 8 across (2.2) no pass, 16 across (4.4) one
        assert_eq!(coupled_passes(0.05, [8, 14], points(0.04, 8)), 0);
        assert_eq!(coupled_passes(0.05, [16, 16], points(0.04, 16)), 1);
        // 0.06 m on 8 across (3.3): one
        assert_eq!(coupled_passes(0.05, [8, 14], points(0.06, 8)), 1);
        // no outlet: the sensor's points decide; no noise: nothing to filter
        assert_eq!(coupled_passes(0.05, [8, 8], None), 1);
        assert_eq!(coupled_passes(0.05, [4, 14], None), 0);
        assert_eq!(coupled_passes(0.0, [16, 16], points(0.04, 16)), 0);
    }
}
