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
//!   the frame period is [`SUBSTEPS_PER_FRAME`] stable estimator substeps (measured on the
//!   clean velocity, rounded down to two significant digits) and the frames cover `run.t_end`
//!   (at most [`MAX_DEFAULT_FRAMES`]).
//!
//! A "coupled" scene is rejected: its velocity evolves with the segregation, so there is no
//! fixed field to sample (sampling the coupled run at frame times would be the extension).

use super::record::{RecordReport, Writer};
use super::scene::coarsen;
use super::ESTIMATOR_CAPACITY;
use crate::data::FlowSummary;
use crate::error::{Error, Result};
use crate::run::{FlowJob, SolverJob};
use crate::scene::validate::{Direction, Temperature};
use crate::scene::{Equations, Fields, Scene};
use sieve_core::flow::Flow;
use sieve_core::segregation::direction::shear_rate_squared;
use sieve_core::sensor::{Region, SensorConfig, SoftSensor, VelocityFrame};
use sieve_core::{diagnose, Boundary, Real, Segregation};

/// Heating prefactor a, eta0 [m] and eps0 [1/m] of the glass beads of model.md 7.4: the
/// soft sensor's T-from-shear constants for scenes that give T instead.
const HEATING: f64 = 1.5;
const ETA0: f64 = 1.3e-4;
const EPS0: f64 = 1477.15;

/// Default frame period in stable estimator substeps (with the budget of 4 substeps per tick
/// this leaves room for the noise, which raises the measured shear and so T).
pub const SUBSTEPS_PER_FRAME: f64 = 2.0;

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
    /// Frame period [s]; `None`: [`SUBSTEPS_PER_FRAME`] stable estimator substeps.
    pub period: Option<f64>,
    /// Frames; `None`: enough to cover `run.t_end` (at most [`MAX_DEFAULT_FRAMES`]).
    pub frames: Option<u32>,
    /// Substep budget per tick written into the configuration.
    pub max_substeps: u16,
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
            max_substeps: 4,
        }
    }
}

/// What a catalogue recording did.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneRecordReport {
    /// Frames, bytes, final truth psi.
    pub record: RecordReport,
    /// Frame period [s].
    pub period: f64,
    /// Truth grid.
    pub truth_cells: [usize; 2],
    /// Stable substep of the estimator with the clean velocity [s].
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
    if let Some(fm) = &scene.flow {
        if fm.equations == Equations::Coupled {
            return Err(Error::range(
                &scene.label,
                "model.equations",
                "\"coupled\"",
                "\"prescribed\" or \"frozen-flow\" (the recorder samples a fixed velocity field; a coupled flow changes with the segregation)",
            ));
        }
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
    if scene.flow.is_some() {
        crate::run::with_flow_solvers(scene.precision, scene.dim, job)
    } else {
        crate::run::with_solver(scene.precision, scene.dim, job)
    }
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

/// The stable substep of the soft sensor (f32, the firmware's estimator) with the clean
/// sensor velocity: one tick of a tiny period, then its Courant step.
fn estimator_dt(cfg: &SensorConfig<f32>, clean: &[f32]) -> Result<f64> {
    let mut probe = cfg.clone();
    probe.tick_period = 1e-6;
    probe.max_substeps = 1;
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
    Ok(sensor.segregation().stable_dt() as f64)
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
        initial_phihat: f(initial),
        inflow_phihat: f(inflow_phihat),
        diffusion: f(scene.diffusion),
        courant: 0.5,
        tick_period: 1.0,
        max_period_factor: 2.0,
        max_substeps: opts.max_substeps,
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
    let dt = estimator_dt(&cfg, &clean)?;
    let period = match opts.period {
        Some(p) => p,
        None if dt.is_finite() && dt < f32::MAX as f64 => round_down_2(SUBSTEPS_PER_FRAME * dt),
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
    // Frames and truth.
    let mut writer = Writer::new(opts.sensor, period, sigma, opts.seed).map_err(fail)?;
    let mut final_psi = 0.0;
    for k in 1..=frames {
        crate::interrupt::check("sieve record")?;
        writer
            .frame(k, |ix, iz| [sx[ix + ns[0] * iz], sz[ix + ns[0] * iz]])
            .map_err(fail)?;
        let target = R::from_f64(k as f64 * period);
        let cap = 1u64 << 24;
        if s.advance_to(target, cap) >= cap {
            return Err(fail(format!(
                "the truth did not reach t = {} s in {cap} steps",
                k as f64 * period
            )));
        }
        let d = diagnose(s);
        final_psi = d.psi.to_f64();
        let coarse = coarsen(
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
        writer
            .truth(k, s.time().to_f64(), final_psi, &coarse)
            .map_err(fail)?;
    }
    let (bytes, stream_bytes) = writer
        .finish(
            cfg,
            &scene.name,
            opts.noise,
            opts.seed,
            [nf[0] as u16, nf[1] as u16],
        )
        .map_err(fail)?;
    let report = SceneRecordReport {
        record: RecordReport {
            frames,
            stream_bytes,
            file_bytes: bytes.len(),
            final_truth_psi: final_psi,
        },
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn period_rounding() {
        assert_eq!(round_down_2(0.0376), 0.037);
        assert!((round_down_2(0.1449) - 0.14).abs() < 1e-15);
    }
}
