//! Checks of a recording read from a file, before anything is allocated or run (issue 10,
//! "Hostile files").
//!
//! A recording's CRC only proves that the bytes are the ones its writer wrote, not that the
//! writer was sieve: a file with a valid CRC can still carry `truth_coarse = [0, 0]` (which
//! once indexed out of bounds) or `[65535, 65535]` (which once asked for 34 GB). So every size
//! and count of the header is bounded here against the documented capacities
//! ([`MAX_SENSOR_SIDE`], [`ESTIMATOR_CAPACITY`]) before the replay allocates from it, the
//! recorded sensor configuration is checked like a scene file's material and numerics (finite,
//! inside physical ranges, so the estimator cannot be driven to inf/NaN), and every truth
//! record is decoded and checked (finite, phihat in [0, 1], one value per coarse cell), so a
//! NaN truth is an error and never a `max_psi_error = 0`.
//!
//! Every message is one line in the user's words: what is wrong, the field, the allowed range
//! and what to do; the caller puts the file name in front.

use super::ESTIMATOR_CAPACITY;
use sieve_core::sensor::recording::{
    Recording, RecordingError, RecordingHeader, TruthRecord, RECORDING_MAGIC, RECORDING_VERSION,
};
use sieve_core::sensor::{SensorConfig, MAX_SENSOR_POINTS, MAX_SENSOR_SIDE};

/// What to do with a damaged file, appended to the messages of [`parse`].
const DAMAGED: &str = "the recording is damaged: record it again with `sieve record`";

/// Largest substep work per tick accepted from a recording, in substeps of a full
/// [`ESTIMATOR_CAPACITY`] grid: the cap the cycle budget affords
/// ([`SensorConfig::substep_cap`]) times the cells may not exceed this many full-grid
/// substeps. Each substep costs one pass over the estimator grid, so a hostile budget of
/// `u32::MAX` cycles with zero costs (65,535 substeps) would turn a replay of a few thousand
/// frames into hours; a Cortex-M4F at 168 MHz and 10 Hz affords 42 on 32 x 32.
pub const MAX_SUBSTEPS: u16 = 1024;

/// Parses `bytes` as a recording; a failure names the part of the file that is wrong.
pub fn parse(bytes: &[u8]) -> Result<Recording<'_>, String> {
    Recording::parse(bytes).map_err(|e| explain(bytes, e))
}

/// The user's words for a [`RecordingError`], naming the length field that disagrees with the
/// file size when the file is truncated.
fn explain(bytes: &[u8], e: RecordingError) -> String {
    // A file too short to hold the magic is not a recording at all, not a truncated one.
    let e = if e == RecordingError::Truncated && !bytes.starts_with(&RECORDING_MAGIC) {
        RecordingError::Magic
    } else {
        e
    };
    match e {
        RecordingError::Magic => format!(
            "not a sieve recording (it does not start with {:?}); give a file written by `sieve record`",
            core::str::from_utf8(&RECORDING_MAGIC).unwrap_or("SIEVEREC")
        ),
        RecordingError::Version => {
            let v = bytes
                .get(8..12)
                .map(|s| u32::from_le_bytes([s[0], s[1], s[2], s[3]]));
            format!(
                "recording format version {} is not read by this build (allowed {RECORDING_VERSION}); record it again with this sieve",
                v.map_or("?".into(), |v| v.to_string())
            )
        }
        RecordingError::Truncated => truncated(bytes),
        RecordingError::Crc => format!(
            "the file's CRC-32 does not match its contents (corrupt bytes); {DAMAGED}"
        ),
        RecordingError::Header => "the header (sensor configuration, scene name) cannot be decoded although its CRC is valid; it was not written by this sieve: record it again".to_string(),
    }
}

/// Which length field of the layout (recording.rs) runs past the end of the file.
fn truncated(b: &[u8]) -> String {
    let total = b.len();
    let mut at = 12usize;
    for field in ["header length", "stream length", "truth length"] {
        let Some(s) = b.get(at..at + 4) else {
            return format!(
                "the file ends after {total} bytes, before its {field} field; {DAMAGED}"
            );
        };
        let n = u32::from_le_bytes([s[0], s[1], s[2], s[3]]) as usize;
        let left = total - (at + 4);
        if n > left {
            return format!(
                "{field} = {n} bytes, but only {left} bytes follow it in the file (allowed at most {left}); {DAMAGED}"
            );
        }
        at += 4 + n;
    }
    let after = total.saturating_sub(at);
    if after < 4 {
        format!("the file ends before its CRC-32 (the last 4 bytes); {DAMAGED}")
    } else {
        format!(
            "{} bytes follow the CRC-32 at the end of the file (allowed 0); {DAMAGED}",
            after - 4
        )
    }
}

/// A header field out of range.
fn field(name: &str, value: impl core::fmt::Display, allowed: &str) -> String {
    format!(
        "header field {name} = {value} is out of range: allowed {allowed}; the recording was not written by this sieve or is damaged: record it again"
    )
}

/// Bounds every size and count of the header before the replay allocates from it, and checks
/// the recorded sensor configuration as a scene's material and numerics are checked.
pub fn header(h: &RecordingHeader) -> Result<(), String> {
    let nc = h.truth_coarse;
    for (a, &n) in nc.iter().enumerate() {
        if n == 0 || n as usize > MAX_SENSOR_SIDE {
            return Err(field(
                &format!("truth_coarse[{a}]"),
                format!("{} (truth_coarse = [{}, {}])", n, nc[0], nc[1]),
                &format!("1 to {MAX_SENSOR_SIDE} cells per axis (at most {MAX_SENSOR_POINTS} cells, the stored truth's capacity)"),
            ));
        }
    }
    for (a, &n) in h.truth_cells.iter().enumerate() {
        if n == 0 {
            return Err(field(
                &format!("truth_cells[{a}]"),
                n,
                "at least 1 cell per axis",
            ));
        }
    }
    if !(h.noise.is_finite() && h.noise >= 0.0) {
        return Err(field("noise", h.noise, "a finite value >= 0"));
    }
    config(&h.config)
}

/// The recorded sensor configuration: the core's own checks (which name the field), then the
/// physical ranges that keep the f32 estimator finite. The ranges are wide (orders of
/// magnitude around the glass beads of model.md 7.4 and laboratory boxes); what they exclude
/// is what overflows f32 in `S0 sqrt(T) |g|` or in the stable step.
pub fn config(c: &SensorConfig<f32>) -> Result<(), String> {
    let n = c.cells[0] as usize * c.cells[1] as usize;
    if c.cells[0] == 0 || c.cells[1] == 0 || n > ESTIMATOR_CAPACITY {
        return Err(field(
            "config.cells",
            format!("[{}, {}]", c.cells[0], c.cells[1]),
            &format!("at least 1 cell per axis and at most {ESTIMATOR_CAPACITY} cells (the estimator's compiled capacity, 32 x 32)"),
        ));
    }
    for a in 0..2 {
        let s = c.sensor[a] as usize;
        if s == 0 || s > MAX_SENSOR_SIDE {
            return Err(field(
                &format!("config.sensor[{a}]"),
                s,
                &format!("1 to {MAX_SENSOR_SIDE} points per axis"),
            ));
        }
    }
    let within = |name: &str, x: f32, lo: f32, hi: f32, unit: &str| -> Result<(), String> {
        if x.is_finite() && x >= lo && x <= hi {
            Ok(())
        } else {
            Err(field(
                &format!("config.{name}"),
                x,
                &format!("{lo:e} to {hi:e}{unit}"),
            ))
        }
    };
    within("extent[0]", c.extent[0], 1e-6, 1e4, " m")?;
    within("extent[1]", c.extent[1], 1e-6, 1e4, " m")?;
    within("s0", c.s0, 0.0, 1e9, " s^2/m")?;
    within("eta0", c.eta0, 0.0, 1.0, " m")?;
    within("eps0", c.eps0, 1e-6, 1e9, " 1/m")?;
    within("heating", c.heating, 0.0, 1e3, "")?;
    within("gravity[0]", c.gravity[0], -1e3, 1e3, " m/s^2")?;
    within("gravity[1]", c.gravity[1], -1e3, 1e3, " m/s^2")?;
    within("c", c.c, 1e-3, 1.0, "")?;
    within("fill_level", c.fill_level, 1e-9, 1e6, " m")?;
    within("initial_phihat", c.initial_phihat, 0.0, 1.0, "")?;
    within("inflow_phihat", c.inflow_phihat, 0.0, 1.0, "")?;
    within("diffusion", c.diffusion, 0.0, 1e3, " m^2/s")?;
    if !(c.courant.is_finite() && c.courant > 0.0 && c.courant < 1.0) {
        return Err(field("config.courant", c.courant, "0 < courant < 1"));
    }
    within("tick_period", c.tick_period, 1e-6, 1e4, " s")?;
    within("max_period_factor", c.max_period_factor, 1.0, 1e3, "")?;
    within("reject_speed", c.reject_speed, 1e-9, 1e6, " m/s")?;
    within("outlier_tol", c.outlier_tol, 1e-12, 1e6, " m/s")?;
    if !(c.smoothing.is_finite() && c.smoothing > 0.0 && c.smoothing <= 1.0) {
        return Err(field("config.smoothing", c.smoothing, "0 < smoothing <= 1"));
    }
    let cap = c.substep_cap() as usize;
    if cap == 0 || cap * c.cell_count() > MAX_SUBSTEPS as usize * ESTIMATOR_CAPACITY {
        let b = &c.budget;
        return Err(field(
            "config.budget",
            format!(
                "{} cycles per tick at {} + {} per cell + {} per sensor point, and {} + {} per cell + {} per boundary face per substep ({cap} substeps of {} cells)",
                b.cycles,
                b.per_tick,
                b.per_cell,
                b.per_point,
                b.per_substep,
                b.per_cell_substep,
                b.per_face_substep,
                c.cell_count()
            ),
            &format!("a budget that affords 1 to {MAX_SUBSTEPS} substeps of {ESTIMATOR_CAPACITY} cells per tick"),
        ));
    }
    within("psi_alarm", c.psi_alarm, -1.0, 2.0, "")?;
    within("fines_band[0]", c.fines_band[0], -1.0, 2.0, "")?;
    within("fines_band[1]", c.fines_band[1], -1.0, 2.0, "")?;
    // The rest (periodic pairs, regions, outlet index) by the core, which names it.
    c.validate(ESTIMATOR_CAPACITY)
        .map_err(|e| format!("header field config: {e}; the recording was not written by this sieve or is damaged: record it again"))
}

/// Decodes and checks every truth record: one per frame at most, each with one finite phihat
/// in [0, 1] per coarse cell, finite time and both psi in [0, 1]. A small tolerance admits the
/// f32 round-off of a coarsened truth.
pub fn truth(rec: &Recording<'_>) -> Result<Vec<TruthRecord>, String> {
    let h = &rec.header;
    let cells = h.truth_coarse[0] as usize * h.truth_coarse[1] as usize;
    let tol = 1e-4f32;
    let unit = |x: f32| x.is_finite() && x >= -tol && x <= 1.0 + tol;
    let mut out = Vec::new();
    let mut rest = rec.truth_bytes;
    while !rest.is_empty() {
        let k = out.len() + 1;
        let (t, next) = postcard::take_from_bytes::<TruthRecord>(rest).map_err(|_| {
            format!(
                "truth record {k} cannot be decoded ({} bytes left in the truth section); {DAMAGED}",
                rest.len()
            )
        })?;
        rest = next;
        if t.phihat.len() != cells {
            return Err(format!(
                "truth record {k} has {} phihat values, the header's truth_coarse = [{}, {}] needs {cells}; {DAMAGED}",
                t.phihat.len(),
                h.truth_coarse[0],
                h.truth_coarse[1]
            ));
        }
        if !t.time.is_finite() {
            return Err(format!(
                "truth record {k} has time = {} (allowed: finite); {DAMAGED}",
                t.time
            ));
        }
        if !unit(t.psi) {
            return Err(format!(
                "truth record {k} has psi = {} (allowed 0 to 1, the mixing index of model.md 6); {DAMAGED}",
                t.psi
            ));
        }
        if !unit(t.psi_estimator_grid) {
            return Err(format!(
                "truth record {k} has psi_estimator_grid = {} (allowed 0 to 1, the mixing index of model.md 6); {DAMAGED}",
                t.psi_estimator_grid
            ));
        }
        if let Some((i, v)) = t.phihat.iter().enumerate().find(|(_, &v)| !unit(v)) {
            return Err(format!(
                "truth record {k} has phihat[{i}] = {v} (allowed 0 to 1); {DAMAGED}"
            ));
        }
        if t.c.len() != cells {
            return Err(format!(
                "truth record {k} has {} c values, the header's truth_coarse = [{}, {}] needs {cells}; {DAMAGED}",
                t.c.len(),
                h.truth_coarse[0],
                h.truth_coarse[1]
            ));
        }
        if let Some((i, v)) = t.c.iter().enumerate().find(|(_, &v)| !unit(v)) {
            return Err(format!(
                "truth record {k} has c[{i}] = {v} (allowed 0 to 1); {DAMAGED}"
            ));
        }
        if let Some(v) = t
            .discharged
            .iter()
            .find(|v| !(v.is_finite() && v.abs() <= 1e6))
        {
            return Err(format!(
                "truth record {k} has discharged = {v} (allowed: finite, at most 1e6 m^2); {DAMAGED}"
            ));
        }
        out.push(t);
    }
    Ok(out)
}
