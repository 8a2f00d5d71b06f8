//! Recording: truth simulation + simulated velocity sensor -> recording file.

use super::scene::{coarsen, psi_on_grid, Scene};
use sieve_core::diagnose;
use sieve_core::sensor::frame::{encode, FRAME_WIRE_MAX};
use sieve_core::sensor::recording::{write_recording, RecordingHeader, TruthRecord};
use sieve_core::sensor::{VelocityFrame, MAX_SENSOR_POINTS};
use sieve_core::Real;
use std::path::Path;

/// What to record.
#[derive(Clone, Debug, PartialEq)]
pub struct RecordOptions {
    /// Scene.
    pub scene: Scene,
    /// Truth grid (x, z), at most 64 x 64.
    pub truth_cells: [u16; 2],
    /// Estimator grid written into the sensor configuration (at most 1024 cells for the
    /// firmware).
    pub estimator_cells: [u16; 2],
    /// Sensor grid (x, z), at most 16 x 16; also the grid of the stored truth phihat.
    pub sensor: [u8; 2],
    /// Velocity noise: standard deviation relative to the scene's largest speed.
    pub noise: f64,
    /// Noise seed.
    pub seed: u64,
    /// Frame period \[s\] (1 / rate).
    pub period: f64,
    /// Number of frames.
    pub frames: u32,
    /// Clock of the CPU the tick budget is for \[Hz\] ([`super::DEFAULT_CPU_HZ`]).
    pub cpu_hz: f64,
    /// Share of every tick period the CPU grants the sensor, in (0, 1].
    pub cpu_share: f64,
}

impl RecordOptions {
    /// Defaults of a scene: truth and estimator 32 x 32, sensor 8 x 8 (4x coarser), 5 %
    /// noise, seed 1, the scene's period and length, the whole of a 168 MHz Cortex-M4F.
    pub fn new(scene: Scene) -> Self {
        Self {
            scene,
            truth_cells: [32, 32],
            estimator_cells: [32, 32],
            sensor: [8, 8],
            noise: 0.05,
            seed: 1,
            period: scene.default_period(),
            frames: scene.default_frames(),
            cpu_hz: super::DEFAULT_CPU_HZ,
            cpu_share: 1.0,
        }
    }
}

/// Summary of a recording.
#[derive(Clone, Debug, PartialEq)]
pub struct RecordReport {
    /// Frames written.
    pub frames: u32,
    /// Bytes of the frame stream.
    pub stream_bytes: usize,
    /// Bytes of the whole file.
    pub file_bytes: usize,
    /// Truth psi at the end.
    pub final_truth_psi: f64,
}

/// SplitMix64 + Box–Muller with the core's libm functions, so a recording is the same on
/// every platform. (The host crate carries no RNG dependency; this is the reference
/// SplitMix64 of the core's fault feeder.)
struct Noise {
    rng: sieve_core::sensor::feeder::SplitMix64,
    spare: Option<f64>,
}

impl Noise {
    fn new(seed: u64) -> Self {
        Self {
            rng: sieve_core::sensor::feeder::SplitMix64::new(seed),
            spare: None,
        }
    }
    fn uniform(&mut self) -> f64 {
        // 53 random bits in (0, 1].
        ((self.rng.next_u64() >> 11) as f64 + 1.0) / (1u64 << 53) as f64
    }
    fn gaussian(&mut self) -> f64 {
        if let Some(s) = self.spare.take() {
            return s;
        }
        let r = (-2.0 * Real::ln(self.uniform())).sqrt();
        let a = 2.0 * core::f64::consts::PI * self.uniform();
        self.spare = Some(r * Real::sin(a));
        r * Real::cos(a)
    }
}

/// Builds a recording frame by frame: the noisy velocity frames (wire bytes) and the truth
/// records, in the order the legacy recorder has always produced them (frame `k`, then the
/// truth at the end of period `k`), so the same inputs give the same bytes.
pub(super) struct Writer {
    ns: [usize; 2],
    sensor: [u8; 2],
    period: f64,
    sigma: f64,
    noise: Noise,
    stream: Vec<u8>,
    truth_bytes: Vec<u8>,
    scratch: Vec<u8>,
    wire: Vec<u8>,
    frames: u32,
}

impl Writer {
    /// A writer for a `sensor` grid, frame `period` [s], noise standard deviation `sigma`
    /// [m/s] and noise `seed`.
    pub(super) fn new(sensor: [u8; 2], period: f64, sigma: f64, seed: u64) -> Result<Self, String> {
        let ns = [sensor[0] as usize, sensor[1] as usize];
        if ns[0] * ns[1] > MAX_SENSOR_POINTS || ns[0] == 0 || ns[1] == 0 {
            return Err(format!("sensor grid {ns:?} exceeds 16 x 16"));
        }
        if !(period > 0.0 && sigma >= 0.0) {
            return Err("period must be > 0 and noise >= 0".into());
        }
        Ok(Self {
            ns,
            sensor,
            period,
            sigma,
            noise: Noise::new(seed),
            stream: Vec::new(),
            truth_bytes: Vec::new(),
            scratch: vec![0u8; FRAME_WIRE_MAX],
            wire: vec![0u8; FRAME_WIRE_MAX],
            frames: 0,
        })
    }

    /// Sets the noise standard deviation [m/s] of the following frames (a coupled truth's
    /// speeds change over the run).
    pub(super) fn set_sigma(&mut self, sigma: f64) {
        self.sigma = sigma.max(0.0);
    }

    /// Frame `k` (1-based): the clean velocity `clean(ix, iz)` at each sensor point (x
    /// fastest) plus Gaussian noise on each component.
    pub(super) fn frame(
        &mut self,
        k: u32,
        clean: impl Fn(usize, usize) -> [f64; 2],
    ) -> Result<(), String> {
        let mut frame = VelocityFrame {
            seq: k,
            time: (k as f64 * self.period) as f32,
            period: self.period as f32,
            nx: self.sensor[0],
            nz: self.sensor[1],
            u: Default::default(),
        };
        for iz in 0..self.ns[1] {
            for ix in 0..self.ns[0] {
                for uc in clean(ix, iz) {
                    let v = (uc + self.sigma * self.noise.gaussian()) as f32;
                    frame.u.push(v).map_err(|_| "frame capacity")?;
                }
            }
        }
        let n = encode(&frame, &mut self.scratch, &mut self.wire).map_err(|_| "frame encoding")?;
        self.stream.extend_from_slice(&self.wire[..n]);
        self.frames = k;
        Ok(())
    }

    /// The truth at the end of period `k`: its time, psi (on its own grid and on the
    /// estimator's: [`super::scene::psi_on_grid`]), phihat and c on the sensor grid, and what
    /// had left its box (grains, small grains).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn truth(
        &mut self,
        k: u32,
        time: f64,
        psi: f64,
        psi_estimator_grid: f64,
        coarse: &[f64],
        coarse_c: &[f64],
        discharged: [f64; 2],
    ) -> Result<(), String> {
        let mut rec = TruthRecord {
            seq: k,
            time: time as f32,
            psi: psi as f32,
            phihat: Default::default(),
            c: Default::default(),
            discharged: [discharged[0] as f32, discharged[1] as f32],
            psi_estimator_grid: psi_estimator_grid as f32,
        };
        for &v in coarse {
            rec.phihat.push(v as f32).map_err(|_| "truth capacity")?;
        }
        for &v in coarse_c {
            rec.c.push(v as f32).map_err(|_| "truth capacity")?;
        }
        if !rec.encode_into(|b| self.truth_bytes.extend_from_slice(b)) {
            return Err("truth encoding".into());
        }
        Ok(())
    }

    /// The recording file bytes and the stream length.
    pub(super) fn finish(
        self,
        config: sieve_core::sensor::SensorConfig<f32>,
        scene: &str,
        noise: f64,
        seed: u64,
        truth_cells: [u16; 2],
    ) -> Result<(Vec<u8>, usize), String> {
        // The header holds 32 bytes of name: longer names are cut at a char boundary.
        let mut name = sieve_core::sensor::heapless::String::new();
        for ch in scene.chars() {
            if name.push(ch).is_err() {
                break;
            }
        }
        let header = RecordingHeader {
            config,
            scene: name,
            noise: noise as f32,
            seed,
            frames: self.frames,
            truth_cells,
            truth_coarse: [self.sensor[0] as u16, self.sensor[1] as u16],
        };
        let mut out = Vec::new();
        let mut hscratch = vec![0u8; 4096];
        write_recording(
            &header,
            &self.stream,
            &self.truth_bytes,
            &mut hscratch,
            |b| {
                out.extend_from_slice(b);
                Ok::<(), String>(())
            },
            "header encoding".to_string(),
        )?;
        Ok((out, self.stream.len()))
    }
}

/// Records a legacy scene into bytes (see [`record`]).
pub fn record_to_bytes(opts: &RecordOptions) -> Result<(Vec<u8>, RecordReport), String> {
    let scene = opts.scene;
    let ns = [opts.sensor[0] as usize, opts.sensor[1] as usize];
    let mut writer = Writer::new(
        opts.sensor,
        opts.period,
        opts.noise * scene.max_speed(),
        opts.seed,
    )?;
    let config = scene.sensor_config(
        opts.estimator_cells,
        opts.sensor,
        opts.noise,
        opts.period,
        super::cpu_budget(opts.cpu_hz, opts.cpu_share, opts.period),
    );
    config
        .validate(super::ESTIMATOR_CAPACITY)
        .map_err(|e| format!("sensor configuration: {e}"))?;
    let mut truth = scene.truth(opts.truth_cells)?;
    // The truth's step is fixed: a frame longer than `cap` of them is refused before
    // stepping, naming the rate (it was "truth did not reach the frame time", after it).
    let cap = 1u64 << 20;
    let dt = truth.stable_dt();
    if opts.period / dt >= cap as f64 {
        return Err(format!(
            "--rate = {:e} is out of range: allowed HZ > {:.4e} for this scene: its truth takes steps of {dt:.4e} s, at most {cap} a frame",
            1.0 / opts.period,
            1.0 / (cap as f64 * dt)
        ));
    }
    let nf = [opts.truth_cells[0] as usize, opts.truth_cells[1] as usize];
    let e = scene.extent();
    let mut final_psi = 0.0;
    for k in 1..=opts.frames {
        // The sensor measures the flow of period k at its points (cell centres of the sensor
        // grid), with Gaussian noise on each component.
        writer.frame(k, |ix, iz| {
            let x = (ix as f64 + 0.5) * e[0] / ns[0] as f64;
            let z = (iz as f64 + 0.5) * e[1] / ns[1] as f64;
            scene.velocity(x, z)
        })?;
        let steps = truth.advance_to(k as f64 * opts.period, cap);
        if steps >= cap {
            return Err("truth did not reach the frame time".into());
        }
        let d = diagnose(&*truth);
        final_psi = d.psi;
        let coarse = coarsen(|i| truth.phi(i) / truth.c(i), nf, ns);
        let coarse_c = coarsen(|i| truth.c(i), nf, ns);
        let ne = [
            opts.estimator_cells[0] as usize,
            opts.estimator_cells[1] as usize,
        ];
        let psi_ne = psi_on_grid(
            |i| truth.phi(i),
            |i| truth.c(i),
            nf,
            ne,
            truth.config().vacuum,
        );
        // The legacy scenes' truth has no discharge accounting: closed or periodic boxes,
        // except Gray-Thornton, whose outflow the replay does not compare.
        writer.truth(
            k,
            truth.time(),
            d.psi,
            psi_ne,
            &coarse,
            &coarse_c,
            [0.0, 0.0],
        )?;
    }
    let (out, stream_bytes) = writer.finish(
        config,
        scene.name(),
        opts.noise,
        opts.seed,
        opts.truth_cells,
    )?;
    let report = RecordReport {
        frames: opts.frames,
        stream_bytes,
        file_bytes: out.len(),
        final_truth_psi: final_psi,
    };
    Ok((out, report))
}

/// Runs the scene's truth simulation and the simulated sensor and writes the recording to
/// `out` (format: `sieve_core::sensor::recording`).
pub fn record(opts: &RecordOptions, out: &Path) -> Result<RecordReport, String> {
    let (bytes, report) = record_to_bytes(opts)?;
    std::fs::write(out, &bytes).map_err(|e| format!("{}: {e}", out.display()))?;
    Ok(report)
}
