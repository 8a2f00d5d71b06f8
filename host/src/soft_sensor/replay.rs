//! Replay: the firmware's soft-sensor loop on the host, compared with the recorded truth.

use super::check;
use super::scene::coarsen;
use super::ESTIMATOR_CAPACITY;
use sieve_core::sensor::feeder::{feed_bytes, Faults, Feeder, InjectedFaults};
use sieve_core::sensor::frame::FRAME_WIRE_MAX;
use sieve_core::sensor::kinematic::Kinematic;
use sieve_core::sensor::recording::TruthRecord;
use sieve_core::sensor::{alarm, Counters, FrameDecoder, SensorConfig, SoftSensor, WireCounters};
use std::io::Write;
use std::path::Path;

/// How to replay.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ReplayOptions {
    /// Fault injection in the feeder (`Faults::default()` = clean; `Faults::DEMO` is what
    /// firmware-sim's faulted pass uses).
    pub faults: Faults,
}

/// One tick of the replay.
#[derive(Clone, Debug, PartialEq)]
pub struct ReplayRow {
    /// Tick index.
    pub tick: u32,
    /// Last accepted sequence number.
    pub seq: u32,
    /// Estimator time \[s\].
    pub time: f32,
    /// Estimated psi.
    pub psi: f32,
    /// Truth psi at the estimator's time.
    pub psi_truth: f32,
    /// Truth psi at the estimator's time, measured on the estimator's grid (the truth's phi
    /// and c averaged onto its cells).
    pub psi_truth_estimator_grid: f32,
    /// Mean |phihat_est - phihat_truth| over the coarse truth grid.
    pub l1: f64,
    /// Health bits.
    pub health: u8,
    /// Alarm bits.
    pub alarms: u8,
    /// Substeps taken.
    pub substeps: u16,
    /// Region means.
    pub regions: Vec<f32>,
    /// Largest |c_est - c_truth| over the coarse truth grid (the estimator's carried c
    /// against the truth's c, both averaged onto the coarse grid).
    pub c_err: f64,
    /// Mean |c_est - c_truth| over the coarse truth grid.
    pub c_l1: f64,
    /// What had left the estimator's box (grains, small grains; per unit depth).
    pub out_est: [f64; 2],
    /// What had left the truth's box (grains, small grains; per unit depth).
    pub out_truth: [f64; 2],
    /// Fines fraction of the estimator's outflow this tick (0 if none).
    pub outflow_fines: f32,
    /// Fines fraction of the estimator's outflow over its window (0 if none).
    pub outflow_fines_window: f32,
    /// Predicted time until the outlet fines fraction leaves the band \[s\] (0: out of it now,
    /// infinity: no exit predicted).
    pub off_spec_in: f32,
}

/// Result of a replay.
#[derive(Clone, Debug, PartialEq)]
pub struct ReplayReport {
    /// Scene name from the recording.
    pub scene: String,
    /// Per-tick rows (ticks whose estimator time has a truth record).
    pub rows: Vec<ReplayRow>,
    /// Largest |psi_est - psi_truth|.
    pub max_psi_error: f64,
    /// Largest |psi_est - psi_truth| with the truth's psi measured on the estimator's grid:
    /// the error an estimator of that resolution can be held to (docs/soft-sensor.md).
    pub max_psi_error_estimator_grid: f64,
    /// Largest L1 of phihat.
    pub max_l1: f64,
    /// Mean L1 of phihat.
    pub mean_l1: f64,
    /// Ticks run.
    pub ticks: u32,
    /// Estimator counters.
    pub counters: Counters,
    /// Decoder counters.
    pub wire: WireCounters,
    /// Injected faults.
    pub injected: InjectedFaults,
    /// Final lag \[s\].
    pub lag: f32,
    /// Relative change of the small-phase mass over the run (f64 sum). The estimator never
    /// clamps phi, so in a closed box this is f32 round-off only (about 1e-7 per step at
    /// most); open boundaries add their inflow and outflow. Relative to the total grain
    /// volume when the box starts without small grains.
    pub mass_drift: f64,
    /// What the estimator's books do not account for, relative as `mass_drift`: the change
    /// of its small-grain volume plus what it let out through outlets and open sides (the
    /// carried transport's books, `SoftSensor::outflow_total`) plus what its percolation
    /// moved across inflow and outflow sides (`Segregation::side_books`). f32 round-off
    /// whatever crosses the box, where `mass_drift` counts the exchange too.
    pub mass_unbooked: f64,
    /// Final state hash (as printed by firmware-sim).
    pub final_state_hash: u64,
    /// Largest |c_est - c_truth| on the coarse grid over the run.
    pub max_c_error: f64,
    /// Mean over the run of the mean |c_est - c_truth| on the coarse grid.
    pub mean_c_error: f64,
    /// The outflow against the truth's discharge, if the truth's box discharged.
    pub outflow: Option<OutflowAccuracy>,
    /// The fines alarms and the off-spec prediction against the truth, if it discharged.
    pub off_spec: Option<OffSpec>,
}

/// When the outlet fines fraction leaves the band `[lo, hi]`: truth, estimator alarm and the
/// estimator's predictions (issue 9, "time to the next off-spec event").
#[derive(Clone, Debug, PartialEq)]
pub struct OffSpec {
    /// The band of the configuration.
    pub band: [f32; 2],
    /// Estimator time of the first row whose truth window fraction is out of the band (the
    /// truth's windows as in [`OutflowAccuracy`]: where it discharged at least 1 % of its
    /// largest window), if it leaves.
    pub truth_leaves: Option<f64>,
    /// Estimator time of the first row with a fines alarm raised.
    pub alarm: Option<f64>,
    /// Predictions made before the truth left: (time of the prediction, predicted time of
    /// leaving = time + `off_spec_in`) for every row with a finite prediction.
    pub predictions: Vec<(f64, f64)>,
}

impl OffSpec {
    /// The last prediction made at least `lead` seconds before the truth left, as (time of
    /// the prediction, predicted leaving time - true leaving time).
    pub fn error_at_lead(&self, lead: f64) -> Option<(f64, f64)> {
        let t = self.truth_leaves?;
        self.predictions
            .iter()
            .rev()
            .find(|p| p.0 <= t - lead)
            .map(|p| (p.0, p.1 - t))
    }
}

/// The truth's window fractions against the band, the first alarm and the predictions.
fn off_spec(rows: &[ReplayRow], w: usize, band: [f32; 2]) -> Option<OffSpec> {
    let last = rows.last()?;
    if !(last.out_truth[0] > 0.0) {
        return None;
    }
    let band64 = [band[0] as f64, band[1] as f64];
    let truth_leaves =
        crate::silo::first_off_spec(rows.len(), |k| rows[k].out_truth, w, [0.0; 2], band64)
            .map(|k| rows[k].time as f64);
    let alarm = rows
        .iter()
        .find(|r| r.alarms & (alarm::FINES_LOW | alarm::FINES_HIGH) != 0)
        .map(|r| r.time as f64);
    let until = truth_leaves.unwrap_or(f64::INFINITY);
    let predictions = rows
        .iter()
        .filter(|r| (r.time as f64) < until && r.off_spec_in.is_finite())
        .map(|r| (r.time as f64, r.time as f64 + r.off_spec_in as f64))
        .collect();
    Some(OffSpec {
        band,
        truth_leaves,
        alarm,
        predictions,
    })
}

/// The outlet fines fraction of the estimator against the truth's discharge (issue 9).
#[derive(Clone, Debug, PartialEq)]
pub struct OutflowAccuracy {
    /// Window \[ticks\] of the compared fines fractions (the configuration's `outflow_window`).
    pub window: usize,
    /// Largest |fines fraction of what left in a window, estimator - truth| over the windows
    /// ending at each tick in which the truth discharged at least 1 % of its largest window.
    pub max_window_error: f64,
    /// Mean of the same over those windows.
    pub mean_window_error: f64,
    /// Windows compared.
    pub windows: usize,
    /// Of those, windows in which the estimator let nothing out (its fraction is undefined
    /// there and counts as 0 in `max_window_error`: the first window of a silo, before the
    /// first frame that moves arrives).
    pub silent_windows: usize,
    /// `max_window_error` over the windows in which the estimator let something out.
    pub max_window_error_flowing: f64,
    /// Fines fraction of everything that left, estimator and truth.
    pub total_fines: [f64; 2],
    /// Grain volume that left, estimator and truth (per unit depth).
    pub total_out: [f64; 2],
}

/// Fines fractions of the windows ending at each row (cumulative differences over `w`
/// rows), compared where the truth discharged at least 1 % of its largest window.
fn outflow_accuracy(rows: &[ReplayRow], w: usize) -> Option<OutflowAccuracy> {
    let last = rows.last()?;
    if !(last.out_truth[0] > 0.0) {
        return None;
    }
    let w = w.max(1);
    let diff = |k: usize, f: fn(&ReplayRow) -> [f64; 2]| -> [f64; 2] {
        let a = f(&rows[k]);
        let b = if k >= w { f(&rows[k - w]) } else { [0.0, 0.0] };
        [a[0] - b[0], a[1] - b[1]]
    };
    let largest = (0..rows.len())
        .map(|k| diff(k, |r| r.out_truth)[0])
        .fold(0.0, f64::max);
    let frac = |d: [f64; 2]| {
        if d[0] > 0.0 {
            (d[1] / d[0]).clamp(0.0, 1.0)
        } else {
            0.0
        }
    };
    let (mut max, mut sum, mut count) = (0.0f64, 0.0, 0usize);
    let (mut silent, mut max_flowing) = (0usize, 0.0f64);
    for k in 0..rows.len() {
        let t = diff(k, |r| r.out_truth);
        if t[0] < 0.01 * largest {
            continue;
        }
        let est = diff(k, |r| r.out_est);
        let e = (frac(est) - frac(t)).abs();
        max = max.max(e);
        if est[0] > 0.0 {
            max_flowing = max_flowing.max(e);
        } else {
            silent += 1;
        }
        sum += e;
        count += 1;
    }
    Some(OutflowAccuracy {
        window: w,
        max_window_error: max,
        mean_window_error: sum / count.max(1) as f64,
        windows: count,
        silent_windows: silent,
        max_window_error_flowing: max_flowing,
        total_fines: [frac(last.out_est), frac(last.out_truth)],
        total_out: [last.out_est[0], last.out_truth[0]],
    })
}

/// Fines fraction of what left the truth's box over the `w` rows ending at row `k` (0 if
/// nothing left).
fn truth_window(rows: &[ReplayRow], k: usize, w: usize) -> f64 {
    let a = rows[k].out_truth;
    let b = if k >= w {
        rows[k - w].out_truth
    } else {
        [0.0, 0.0]
    };
    let d = [a[0] - b[0], a[1] - b[1]];
    if d[0] > 0.0 {
        (d[1] / d[0]).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// Replays recording bytes.
pub fn replay_bytes(bytes: &[u8], opts: &ReplayOptions) -> Result<ReplayReport, String> {
    replay_bytes_with(bytes, opts, |_| Ok(()))
}

/// Replays recording bytes with the controller's settings changed by `settings` (e.g. the
/// fines band and the alarm persistence: they change the alarms and the prediction, not the
/// estimate); it may refuse a setting with a message.
pub fn replay_bytes_with(
    bytes: &[u8],
    opts: &ReplayOptions,
    settings: impl FnOnce(&mut SensorConfig<f32>) -> Result<(), String>,
) -> Result<ReplayReport, String> {
    run(bytes, opts, settings, None)
}

/// Replays a recording of a discharging silo without its velocity frames: every tick's frame
/// is the Nedderman-Tuzun kinematic velocity ([`Kinematic`], constant `b` \[m\]) scaled by the
/// discharge rate a load cell under the orifice reads, i.e. the truth's discharge over the
/// previous frame period (causal: the rate of the period that just ended). The truth's
/// discharge is solid volume per unit depth, so the load cell's mass rate is it times
/// `rho_s depth` and the bulk flux it gives back is `rate / c` with the configuration's c;
/// rho_s and depth cancel here (2 500 kg/m^3 and 1 m are used). The recording needs an
/// opening in its floor.
pub fn replay_kinematic(bytes: &[u8], b: f64) -> Result<ReplayReport, String> {
    run(bytes, &ReplayOptions::default(), |_| Ok(()), Some(b))
}

fn run(
    bytes: &[u8],
    opts: &ReplayOptions,
    settings: impl FnOnce(&mut SensorConfig<f32>) -> Result<(), String>,
    kinematic: Option<f64>,
) -> Result<ReplayReport, String> {
    // Everything the replay sizes or indexes by is bounded first (check.rs): a valid CRC
    // does not make a header sane.
    let rec = check::parse(bytes)?;
    check::header(&rec.header)?;
    let truth: Vec<TruthRecord> = check::truth(&rec)?;
    let mut config = rec.header.config.clone();
    settings(&mut config)?;
    let mut sensor: Box<SoftSensor<f32, ESTIMATOR_CAPACITY>> = Box::default();
    sensor
        .configure(&config)
        .map_err(|e| format!("config: {e}"))?;
    let mut decoder: Box<FrameDecoder<FRAME_WIRE_MAX>> = Box::default();
    let mut feeder = Box::new(Feeder::new(rec.stream, opts.faults));
    let cfg = config;
    let period = cfg.tick_period as f64;
    let nf = [cfg.cells[0] as usize, cfg.cells[1] as usize];
    let nc = [
        rec.header.truth_coarse[0] as usize,
        rec.header.truth_coarse[1] as usize,
    ];
    let mass = |s: &SoftSensor<f32, ESTIMATOR_CAPACITY>| -> f64 {
        let g = s.segregation();
        (0..g.len()).map(|i| g.phi(i) as f64).sum()
    };
    let mass0 = mass(&sensor);
    let mut rows = Vec::new();
    let mut tick = 0u32;
    const DENSITY: f64 = 2500.0;
    const DEPTH: f64 = 1.0;
    let source = match kinematic {
        None => None,
        Some(b) => {
            let o = cfg
                .openings
                .iter()
                .find(|o| o.axis == 1 && !o.high)
                .ok_or("--kinematic needs a recording with an opening in its floor (a silo)")?;
            let k = Kinematic::new(
                cfg.extent[0] as f64,
                cfg.extent[1] as f64,
                o.lower as f64,
                o.upper as f64,
                b,
                cfg.sensor,
                DENSITY,
                cfg.c as f64,
                DEPTH,
            )
            .map_err(|e| format!("kinematic source: {e:?} (B = {b} m)"))?;
            Some(Box::new(k))
        }
    };
    // The firmware loop: one tick per frame period; the feeder's bytes of the tick go through
    // the decoder into the sensor, then the tick ends. Runs until the stream is delivered.
    // With the kinematic source: one tick per truth record, its frame from the rate alone.
    loop {
        if let Some(k) = &source {
            let n = tick as usize;
            if n >= truth.len() {
                break;
            }
            let before = |m: usize| {
                if m == 0 {
                    0.0
                } else {
                    truth[m - 1].discharged[0] as f64
                }
            };
            // The solid volume that left over the previous period, as a mass rate.
            let volume = if n == 0 {
                0.0
            } else {
                before(n) - before(n - 1)
            };
            let mass_rate = volume.max(0.0) / period * DENSITY * DEPTH;
            let f = k.frame(
                tick + 1,
                (n + 1) as f32 * cfg.tick_period,
                cfg.tick_period,
                k.bulk_flux(mass_rate),
            );
            let _ = sensor.submit(&f);
        } else {
            if feeder.done() {
                break;
            }
            feeder.tick(|chunk| feed_bytes(&mut *sensor, &mut *decoder, chunk));
        }
        let e = sensor.finish_tick();
        // Compare with the truth at the estimator's own time (the frame periods it has
        // simulated), so lost or late periods show up as error, not as a shifted index.
        let covered = (e.time as f64 / period).round() as usize;
        if let Some(t) = covered.checked_sub(1).and_then(|k| truth.get(k)) {
            let est = coarsen(|i| sensor.phihat(i) as f64, nf, nc);
            let l1 = est
                .iter()
                .zip(&t.phihat)
                .map(|(a, &b)| (a - b as f64).abs())
                .sum::<f64>()
                / est.len().max(1) as f64;
            let seg = sensor.segregation();
            let est_c = coarsen(|i| seg.c(i) as f64, nf, nc);
            let (mut c_err, mut c_l1) = (0.0f64, 0.0f64);
            for (a, &b) in est_c.iter().zip(&t.c) {
                let d = (a - b as f64).abs();
                c_err = c_err.max(d);
                c_l1 += d;
            }
            c_l1 /= est_c.len().max(1) as f64;
            let out = sensor.outflow_total();
            rows.push(ReplayRow {
                tick,
                seq: e.seq,
                time: e.time,
                psi: e.psi,
                psi_truth: t.psi,
                psi_truth_estimator_grid: t.psi_estimator_grid,
                l1,
                health: e.health,
                alarms: e.alarms,
                substeps: e.substeps,
                regions: e.regions.to_vec(),
                c_err,
                c_l1,
                out_est: [out[0] as f64, out[1] as f64],
                out_truth: [t.discharged[0] as f64, t.discharged[1] as f64],
                outflow_fines: e.outflow_fines,
                outflow_fines_window: e.outflow_fines_window,
                off_spec_in: e.off_spec_in,
            });
        }
        if !e.psi.is_finite() {
            return Err(format!(
                "the estimate became non-finite at tick {tick} (psi = {}): the recorded configuration is outside what the f32 estimator can integrate; record it again with smaller s0, gravity or speeds",
                e.psi
            ));
        }
        tick += 1;
    }
    // `f64::max` drops NaN: a NaN error must stay visible, never become a 0.
    let nan_max = |a: f64, b: f64| {
        if a.is_nan() || b.is_nan() {
            f64::NAN
        } else {
            a.max(b)
        }
    };
    let max_psi_error = rows
        .iter()
        .map(|r| (r.psi as f64 - r.psi_truth as f64).abs())
        .fold(0.0, nan_max);
    let max_psi_error_estimator_grid = rows
        .iter()
        .map(|r| (r.psi as f64 - r.psi_truth_estimator_grid as f64).abs())
        .fold(0.0, nan_max);
    let max_l1 = rows.iter().map(|r| r.l1).fold(0.0, nan_max);
    let mean_l1 = rows.iter().map(|r| r.l1).sum::<f64>() / rows.len().max(1) as f64;
    let max_c_error = rows.iter().map(|r| r.c_err).fold(0.0, nan_max);
    let mean_c_error = rows.iter().map(|r| r.c_l1).sum::<f64>() / rows.len().max(1) as f64;
    let outflow = outflow_accuracy(&rows, cfg.outflow_window as usize);
    let off_spec = off_spec(&rows, cfg.outflow_window as usize, cfg.fines_band);
    let mass1 = mass(&sensor);
    if !(mass1.is_finite() && max_psi_error.is_finite() && max_l1.is_finite()) {
        return Err(format!(
            "the replay produced a non-finite result (mass {mass1}, max_psi_error {max_psi_error}, max_l1 {max_l1}): the recorded configuration is outside what the f32 estimator can integrate; record it again"
        ));
    }
    // Relative to the initial small-grain mass; a box that starts without small grains
    // (initial_phihat = 0) has none to be relative to, so its drift is relative to the
    // total grain volume instead (never 0/0 = NaN).
    let grains: f64 = {
        let g = sensor.segregation();
        (0..g.len()).map(|i| g.c(i) as f64).sum()
    };
    let scale = if mass0 > 0.0 {
        mass0
    } else {
        grains.max(f64::MIN_POSITIVE)
    };
    Ok(ReplayReport {
        scene: rec.header.scene.as_str().to_string(),
        rows,
        max_psi_error,
        max_psi_error_estimator_grid,
        max_l1,
        mean_l1,
        ticks: tick,
        counters: *sensor.counters(),
        wire: decoder.counters,
        injected: feeder.injected,
        lag: sensor.lag(),
        mass_drift: (mass1 - mass0) / scale,
        mass_unbooked: {
            let g = sensor.segregation();
            let vol = g.grid().cell_volume() as f64;
            let sides: f64 = g
                .small_mass_out_through_sides()
                .iter()
                .flatten()
                .map(|&x| x as f64)
                .sum();
            let carried = sensor.outflow_total()[1] as f64;
            ((mass1 - mass0) * vol + sides + carried) / (scale * vol)
        },
        final_state_hash: sensor.state_hash(),
        max_c_error,
        mean_c_error,
        outflow,
        off_spec,
    })
}

/// Replays a recording file: the soft sensor (f32, firmware loop) against the truth.
pub fn replay(path: &Path, opts: &ReplayOptions) -> Result<ReplayReport, String> {
    replay_with(path, opts, |_| Ok(()))
}

/// [`replay`] with the controller's settings changed (see [`replay_bytes_with`]).
pub fn replay_with(
    path: &Path,
    opts: &ReplayOptions,
    settings: impl FnOnce(&mut SensorConfig<f32>) -> Result<(), String>,
) -> Result<ReplayReport, String> {
    let bytes = crate::read::bytes(path, crate::read::MAX_FILE)
        .map_err(|e| format!("cannot read the recording: {e}"))?;
    replay_bytes_with(&bytes, opts, settings)
}

/// Prints the error over time (every `every`-th tick and the last) and the summary lines in
/// the same `key=value` format as firmware-sim.
pub fn print_report(r: &ReplayReport, every: usize, out: &mut impl Write) -> std::io::Result<()> {
    writeln!(out, "scene={}", r.scene)?;
    writeln!(
        out,
        "{:>6} {:>6} {:>8} {:>8} {:>8} {:>9} {:>8} {:>6} {:>5} {:>8} {:>8} {:>8} {:>8} {:>6} {:>8}",
        "tick",
        "seq",
        "time",
        "psi",
        "truth",
        "psi_err",
        "L1",
        "health",
        "subst",
        "c_err",
        "out_fin",
        "out_win",
        "tru_win",
        "alarms",
        "offspec"
    )?;
    let n = r.rows.len();
    let w = r.outflow.as_ref().map_or(1, |o| o.window);
    for (k, row) in r.rows.iter().enumerate() {
        if k % every.max(1) == 0 || k + 1 == n {
            writeln!(
                out,
                "{:>6} {:>6} {:>8.3} {:>8.4} {:>8.4} {:>9.5} {:>8.5} {:>#6x} {:>5} {:>8.5} {:>8.5} {:>8.5} {:>8.5} {:>#6x} {:>8.3}",
                row.tick,
                row.seq,
                row.time,
                row.psi,
                row.psi_truth,
                row.psi - row.psi_truth,
                row.l1,
                row.health,
                row.substeps,
                row.c_err,
                row.outflow_fines,
                row.outflow_fines_window,
                truth_window(&r.rows, k, w),
                row.alarms,
                row.off_spec_in
            )?;
        }
    }
    writeln!(out, "max_psi_error={:.5}", r.max_psi_error)?;
    writeln!(
        out,
        "max_psi_error_estimator_grid={:.5}",
        r.max_psi_error_estimator_grid
    )?;
    writeln!(out, "max_l1={:.5} mean_l1={:.5}", r.max_l1, r.mean_l1)?;
    writeln!(
        out,
        "max_c_error={:.5} mean_c_error={:.5}",
        r.max_c_error, r.mean_c_error
    )?;
    if let Some(o) = &r.outflow {
        writeln!(
            out,
            "outflow_fines_error: window={} ticks max={:.5} mean={:.5} windows={} silent={} max_flowing={:.5} total_fines est={:.5} truth={:.5} out est={:.5e} truth={:.5e}",
            o.window,
            o.max_window_error,
            o.mean_window_error,
            o.windows,
            o.silent_windows,
            o.max_window_error_flowing,
            o.total_fines[0],
            o.total_fines[1],
            o.total_out[0],
            o.total_out[1]
        )?;
    }
    if let Some(o) = &r.off_spec {
        let t = |x: Option<f64>| x.map_or("never".to_string(), |v| format!("{v:.3}"));
        let lead = |l: f64| {
            o.error_at_lead(l).map_or("none".to_string(), |(at, err)| {
                format!("{err:+.3} s (made at {at:.3})")
            })
        };
        writeln!(
            out,
            "off_spec: band=[{}, {}] truth_leaves={} first_alarm={} prediction_error lead_2s={} lead_1s={} lead_0.5s={}",
            o.band[0],
            o.band[1],
            t(o.truth_leaves),
            t(o.alarm),
            lead(2.0),
            lead(1.0),
            lead(0.5)
        )?;
    }
    let c = &r.counters;
    let w = &r.wire;
    writeln!(
        out,
        "faults: decoded={} overflow={} framing={} crc={} decode={} dims={} non_finite={} range={} seq={} outliers={} stale_ticks={} frozen_ticks={} budget_limited={} lost_periods={} phi_excursions={}",
        w.decoded, w.overflow, w.framing, w.crc, w.decode, c.dims, c.non_finite, c.range, c.seq,
        c.outliers, c.stale_ticks, c.frozen_ticks, c.budget_limited, c.lost_periods, c.phi_excursions
    )?;
    writeln!(
        out,
        "ticks={} lag={:.6} mass_unbooked={:.3e} mass_drift={:.3e}",
        r.ticks, r.lag, r.mass_unbooked, r.mass_drift
    )?;
    writeln!(out, "final_state_hash=0x{:016x}", r.final_state_hash)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A row with cumulative outflows (grains, small grains) of the estimator and the truth.
    fn row(tick: u32, est: [f64; 2], truth: [f64; 2]) -> ReplayRow {
        ReplayRow {
            tick,
            seq: tick + 1,
            time: (tick + 1) as f32 * 0.1,
            psi: 1.0,
            psi_truth: 1.0,
            psi_truth_estimator_grid: 1.0,
            l1: 0.0,
            health: 0,
            alarms: 0,
            substeps: 1,
            regions: Vec::new(),
            c_err: 0.0,
            c_l1: 0.0,
            out_est: est,
            out_truth: truth,
            outflow_fines: 0.0,
            outflow_fines_window: 0.0,
            off_spec_in: f32::INFINITY,
        }
    }

    #[test]
    fn a_window_in_which_the_estimator_let_nothing_out_is_counted_as_silent() {
        // Window of 1 tick. Truth: 1.0 of grains per tick at fines 0.5, 0.5, 0.8. Estimator:
        // nothing in the first tick, then 1.0 at fines 0.5 and 0.6.
        let rows = [
            row(0, [0.0, 0.0], [1.0, 0.5]),
            row(1, [1.0, 0.5], [2.0, 1.0]),
            row(2, [2.0, 1.1], [3.0, 1.8]),
        ];
        let o = outflow_accuracy(&rows, 1).unwrap();
        assert_eq!(o.windows, 3);
        assert_eq!(o.silent_windows, 1);
        // The silent window's fraction counts as 0: error 0.5 in `max`; `max_flowing` is
        // the last window's |0.6 - 0.8|.
        assert!((o.max_window_error - 0.5).abs() < 1e-12);
        assert!((o.max_window_error_flowing - 0.2).abs() < 1e-12);
        assert!((o.mean_window_error - 0.7 / 3.0).abs() < 1e-12);
    }
}
