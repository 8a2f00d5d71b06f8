//! The soft-sensor loop, independent of the platform: the same code runs on the emulated
//! Cortex-M4F and on the host.

use core::fmt::Arguments;
use sieve_core::sensor::feeder::{feed_bytes, Faults, Feeder};
use sieve_core::sensor::frame::{encode, ESTIMATE_BODY_MAX, ESTIMATE_WIRE_MAX, FRAME_WIRE_MAX};
use sieve_core::sensor::recording::Recording;
use sieve_core::sensor::{Estimate, FrameDecoder, SoftSensor, TickProfile, WireCounters};

/// Estimator capacity: a 32 x 32 grid.
pub const CELLS: usize = 1024;
/// Print every this many ticks' estimate frame (all of them would flood semihosting).
const PRINT_EVERY: u32 = 25;
/// Estimate body scratch: postcard bound of an [`Estimate`].
const ESTIMATE_BODY: usize = ESTIMATE_BODY_MAX;

/// The recording embedded at build time (see build.rs).
pub static RECORDING: &[u8] = include_bytes!(env!("SIEVE_RECORDING_PATH"));

/// What the loop needs from the platform.
pub trait Platform {
    /// Prints one line.
    fn line(&mut self, args: Arguments<'_>);
    /// Executed instructions since start (0 where not measurable).
    fn instructions(&mut self) -> u64;
}

/// The loop's state, in one place so the firmware can keep it in a `static`.
pub struct State {
    /// The estimator.
    pub sensor: SoftSensor<f32, CELLS>,
    /// The UART decoder.
    pub decoder: FrameDecoder<FRAME_WIRE_MAX>,
    /// The simulated UART (recording + faults).
    pub feeder: Feeder<'static>,
}

impl State {
    /// The initial state (`const`: it lives in RAM from reset, nothing built on the stack).
    pub const fn new() -> Self {
        Self {
            sensor: SoftSensor::new(),
            decoder: FrameDecoder::new(),
            feeder: Feeder::new(&[], Faults::NONE),
        }
    }
}

/// Work statistics of one pass.
#[derive(Default)]
struct Stats {
    ticks: u32,
    substeps: u64,
    instr: u64,
    max_instr: u64,
    max_tick: u32,
    /// Instructions in the feeder callback: UART bytes, decoding, validation, filtering.
    feed: u64,
    /// Instructions in the phases of `finish_tick`, summed over the pass.
    phases: TickProfile,
    /// Ticks that mapped a new frame (ran `prepare_velocity`).
    mapped: u32,
    /// Largest measured tick over the cost model's cycles for its substeps, in permille.
    max_over_model: u64,
    /// Ticks whose measured instructions exceeded the cost model.
    ticks_over_model: u32,
    /// Largest instructions of one tick's fixed estimator part (map, prepare, estimate).
    max_fixed: u64,
    /// Largest mean instructions of one substep within a tick.
    max_substep: u64,
    /// Largest instructions per decoded frame of one tick's feed (UART, decode, filter).
    max_feed_frame: u64,
}

macro_rules! out {
    ($p:expr, $($t:tt)*) => { $p.line(format_args!($($t)*)) };
}

/// Runs the clean pass and the faulted pass over the embedded recording and prints the
/// results; returns false if the recording cannot be used.
pub fn run(p: &mut impl Platform, s: &mut State) -> bool {
    let rec = match Recording::parse(RECORDING) {
        Ok(r) => r,
        Err(e) => {
            out!(p, "error=recording {:?}", e);
            return false;
        }
    };
    let cfg = &rec.header.config;
    let cells = cfg.cell_count() as u64;
    out!(
        p,
        "recording scene={} cells={}x{} sensor={}x{} frames={} stream_bytes={} period={}",
        rec.header.scene.as_str(),
        cfg.cells[0],
        cfg.cells[1],
        cfg.sensor[0],
        cfg.sensor[1],
        rec.header.frames,
        rec.stream.len(),
        cfg.tick_period
    );
    for (label, faults) in [("clean", Faults::NONE), ("faulted", Faults::DEMO)] {
        if let Err(e) = s.sensor.configure(cfg) {
            out!(p, "error=configuration {:?}", e);
            return false;
        }
        s.decoder.counters = WireCounters::default();
        s.feeder.reset(rec.stream, faults);
        let mut st = Stats::default();
        let mut frames_before = 0u32;
        while !s.feeder.done() {
            let t0 = p.instructions();
            let (sensor, decoder) = (&mut s.sensor, &mut s.decoder);
            s.feeder.tick(|chunk| feed_bytes(sensor, decoder, chunk));
            let t1 = p.instructions();
            let (e, prof) = s.sensor.finish_tick_profiled(&mut || p.instructions());
            let dt = p.instructions() - t0;
            st.max_fixed = st.max_fixed.max(prof.map + prof.prepare + prof.estimate);
            if e.substeps > 0 {
                st.max_substep = st.max_substep.max(prof.substeps / e.substeps as u64);
            }
            st.phases.map += prof.map;
            st.phases.prepare += prof.prepare;
            st.phases.substeps += prof.substeps;
            st.phases.estimate += prof.estimate;
            st.mapped += (prof.prepare > 0) as u32;
            st.feed += t1 - t0;
            st.ticks += 1;
            st.substeps += e.substeps as u64;
            st.instr += dt;
            // The configuration's cost model of this tick (one cycle per instruction):
            // the fixed part plus its substeps. It caps the substeps, so it must not be
            // below what the tick really executed.
            let b = &cfg.budget;
            // Frames the tick decoded (good or not): what the estimator's cap counted.
            let w = s.decoder.counters;
            let seen = w.decoded + w.overflow + w.framing + w.crc + w.decode;
            let frames = seen - frames_before;
            frames_before = seen;
            st.max_feed_frame = st.max_feed_frame.max((t1 - t0) / frames.max(1) as u64);
            let grid = cfg.estimator_grid();
            let model = b.fixed_frames(grid, cfg.sensor_points(), frames)
                + e.substeps as u64 * b.substep(grid);
            let permille = dt * 1000 / model.max(1);
            st.max_over_model = st.max_over_model.max(permille);
            st.ticks_over_model += (dt > model) as u32;
            if dt > st.max_instr {
                st.max_instr = dt;
                st.max_tick = e.tick;
            }
            if e.tick % PRINT_EVERY == 0 {
                print_estimate(p, label, &e, dt);
            }
        }
        let per_cell_substep = if st.substeps > 0 {
            st.instr / (cells * st.substeps)
        } else {
            0
        };
        out!(
            p,
            "pass={} ticks={} substeps={} instr_total={} instr_mean_tick={} (feed+decode+filter {}, map+prepare_velocity+substeps+estimate {}) instr_max_tick={} (tick {}) instr_per_cell_substep_full_tick={}",
            label,
            st.ticks,
            st.substeps,
            st.instr,
            st.instr / st.ticks.max(1) as u64,
            st.feed / st.ticks.max(1) as u64,
            (st.instr - st.feed) / st.ticks.max(1) as u64,
            st.max_instr,
            st.max_tick,
            per_cell_substep
        );
        // Per cell: feed+decode+filter and the estimate per tick, the mapping and
        // prepare_velocity per mapped tick, the substeps per substep.
        let per = |x: u64, n: u64| x / (cells * n.max(1));
        let ticks = st.ticks as u64;
        out!(
            p,
            "profile pass={} per_cell: feed+decode+filter={} map={} prepare_velocity={} substep={} estimate={} (per tick: {} mapped, {} substeps)",
            label,
            per(st.feed, ticks),
            per(st.phases.map, st.mapped as u64),
            per(st.phases.prepare, st.mapped as u64),
            per(st.phases.substeps, st.substeps),
            per(st.phases.estimate, ticks),
            st.mapped,
            st.substeps
        );
        // The worst parts of any tick against the cost model's (CycleBudget): the fixed
        // estimator part (map, prepare_velocity, estimate), the feed of one frame, one
        // substep; and every whole tick against the model for its frames and substeps.
        let b = &cfg.budget;
        let grid = cfg.estimator_grid();
        let points = cfg.sensor_points();
        out!(
            p,
            "cost_model pass={} worst fixed={} (model {}) feed_frame={} (model {}) substep={} (model {}) budget_cycles={} substep_cap={} max_tick_over_model={}.{:03} ticks_over_model={}",
            label,
            st.max_fixed,
            b.fixed(grid, 0),
            st.max_feed_frame,
            b.per_point as u64 * points as u64,
            st.max_substep,
            b.substep(grid),
            b.cycles,
            cfg.substep_cap(),
            st.max_over_model / 1000,
            st.max_over_model % 1000,
            st.ticks_over_model
        );
        let w = s.decoder.counters;
        let c = s.sensor.counters();
        let inj = s.feeder.injected;
        out!(
            p,
            "injected pass={} bit_flips={} dropped_bytes={} duplicates={} reorders={} nans={} stall_ticks={}",
            label, inj.bit_flips, inj.dropped_bytes, inj.duplicates, inj.reorders, inj.nans, inj.stall_ticks
        );
        out!(
            p,
            "faults pass={} decoded={} overflow={} framing={} crc={} decode={} dims={} non_finite={} range={} seq={} outliers={} stale_ticks={} frozen_ticks={} budget_limited={} lost_periods={} phi_excursions={} lag={}",
            label, w.decoded, w.overflow, w.framing, w.crc, w.decode, c.dims, c.non_finite, c.range,
            c.seq, c.outliers, c.stale_ticks, c.frozen_ticks, c.budget_limited, c.lost_periods,
            c.phi_excursions, s.sensor.lag()
        );
        let h = s.sensor.state_hash();
        if faults == Faults::NONE {
            out!(p, "final_state_hash=0x{:016x}", h);
        } else {
            out!(p, "faulted_state_hash=0x{:016x}", h);
        }
    }
    // Budget probes after the hashes (they change the state): the estimate alone, then a
    // held tick (substeps with the last velocity + the estimate), so the substep cost per
    // cell is their difference over the substeps.
    let t0 = p.instructions();
    let e0 = s.sensor.estimate();
    let t1 = p.instructions();
    let e1 = s.sensor.finish_tick();
    let t2 = p.instructions();
    let est = t1 - t0;
    let held = t2 - t1;
    let sub = e1.substeps.max(1) as u64;
    out!(
        p,
        "budget estimate_instr={} held_tick_instr={} held_substeps={} instr_per_cell_substep={} (psi {})",
        est,
        held,
        e1.substeps,
        held.saturating_sub(est) / (cells * sub),
        e0.psi
    );
    // Cost of one f32 square root through core's `Real::sqrt` (libm; prepare_velocity calls
    // it about five times per cell).
    let mut acc = 0.0f32;
    let t0 = p.instructions();
    for k in 0..SQRT_PROBE {
        acc += <f32 as sieve_core::Real>::sqrt(core::hint::black_box(1.0 + k as f32 * 0.37));
    }
    let t1 = p.instructions();
    out!(
        p,
        "budget sqrtf_instr={} (mean of {} calls, sum {})",
        (t1 - t0) / SQRT_PROBE as u64,
        SQRT_PROBE,
        acc
    );
    true
}

/// Calls in the square-root probe.
const SQRT_PROBE: u32 = 1024;

fn print_estimate(p: &mut impl Platform, label: &str, e: &Estimate, instr: u64) {
    let mut body = [0u8; ESTIMATE_BODY];
    let mut wire = [0u8; ESTIMATE_WIRE_MAX];
    let n = encode(e, &mut body, &mut wire).unwrap_or(0);
    let mut hex = [0u8; 2 * ESTIMATE_WIRE_MAX];
    const DIGITS: &[u8; 16] = b"0123456789abcdef";
    for (k, b) in wire[..n].iter().enumerate() {
        hex[2 * k] = DIGITS[(b >> 4) as usize];
        hex[2 * k + 1] = DIGITS[(b & 15) as usize];
    }
    let hex = core::str::from_utf8(&hex[..2 * n]).unwrap_or("");
    out!(
        p,
        "est pass={} tick={} seq={} psi={:.4} phihat=[{:.3},{:.3}] alarms={:#x} health={:#x} substeps={} instr={} wire={}",
        label, e.tick, e.seq, e.psi, e.phihat_min, e.phihat_max, e.alarms, e.health, e.substeps, instr, hex
    );
}
