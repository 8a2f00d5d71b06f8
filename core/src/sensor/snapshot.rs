//! Snapshots: the estimator state as postcard items plus a CRC-32, restored bit-identically.
//!
//! Layout (format 6): `postcard(SnapshotHeader)` (since format 5 with the latched fines
//! alarms, their persistence counters, the trend ring's length and head and the last
//! off-spec prediction, so a restored sensor raises and clears its alarms on the same ticks
//! as an uninterrupted one; since format 6 with the frames' noise variance and the share of
//! it the velocity's EMA keeps, from which T's noise term is derived), then `cells` values of the carried volume
//! fraction `c`, `cells` values of the tracked phase fraction `q` (phi for `Phase::Small`,
//! c - phi for `Phase::Large`: the solver's own state, written and restored with
//! `set_tracked`, so either phase round-trips bit-exactly), `cells` values of the rounding
//! error the compensated updates carry per cell, `2 cells` face coefficients `k` (x, then z),
//! `2 * sensor points` values of the smoothed sensor velocity and `2 * outflow_window`
//! values of the outflow window, `2 * outflow_window` values of the trend ring (estimator
//! time, outlet fines fraction) of the off-spec prediction (each a postcard `R`: fixed-width IEEE bits), then the CRC-32
//! of everything before it (4 bytes little endian). Items are written and read one by one,
//! so no buffer of the size of the state is needed besides the output itself.
//!
//! c is state since the estimator carries it (issue 9). The face coefficients `k = S/c` are
//! stored because the carried transport rescales them to each new c, which a fresh `prepare`
//! would round differently. u on the estimator grid and T are not stored: restore maps the
//! stored sensor field again and calls `prepare_velocity`, which computes them with the same
//! operations in the same order, so they come out bit-identical. Nothing is clamped: q is
//! restored as stored.

use super::estimator::{Counters, SoftSensor};
use super::{alarm, crc32, SensorReal, MAX_FRAME_VALUES, MAX_OUTFLOW_WINDOW};
use crate::hash::Fnv64;
use postcard::ser_flavors::Flavor;
use serde::{Deserialize, Serialize};

/// Snapshot format version.
pub const SNAPSHOT_VERSION: u16 = 6;

/// How far outside [0, c] a stored tracked fraction may be. The estimator carries c with the
/// same face fluxes as phi, so phi stays in [0, c] up to the sub-ulp carry of its compensated
/// updates; anything beyond this is not a state it produces, and is refused.
pub const SNAPSHOT_PHI_SLACK: f64 = 0.05;

/// Upper bound of a snapshot's size for capacity `N` (f64 values, generous header).
pub const fn snapshot_capacity(n: usize) -> usize {
    256 + 8 * (5 * n + MAX_FRAME_VALUES + 4 * MAX_OUTFLOW_WINDOW)
}

#[derive(Serialize, Deserialize)]
struct SnapshotHeader<R> {
    version: u16,
    /// Bytes per real (4 or 8): an f32 snapshot cannot restore an f64 sensor.
    real_size: u8,
    config_hash: u64,
    cells: u32,
    sensor_values: u32,
    time: R,
    steps: u64,
    have_velocity: bool,
    last_seq: u32,
    covered: u32,
    stale: u32,
    lag: R,
    tick: u32,
    counters: Counters,
    out_head: u16,
    out_total: [R; 2],
    fines_state: u8,
    fines_runs: [u16; 3],
    trend_len: u16,
    trend_head: u16,
    off_spec_in: Option<R>,
    /// Since format 6: the frames' noise variance and the share the EMA keeps (`noise.rs`).
    noise: [R; 2],
}

/// Why a snapshot was refused (the state is then unchanged).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SnapshotError {
    /// The output buffer is too small.
    BufferTooSmall,
    /// Shorter than a CRC, or the CRC does not match.
    Crc,
    /// Not decodable, or trailing bytes.
    Decode,
    /// Another format version or real type.
    Version,
    /// Taken with another configuration (or c field).
    Config,
    /// A value is non-finite, or the tracked fraction is far outside [0, c] (see
    /// [`SNAPSHOT_PHI_SLACK`]).
    Value,
}

/// A postcard flavor that hashes instead of storing: the configuration hash costs no buffer.
struct HashFlavor(Fnv64);

impl Flavor for HashFlavor {
    type Output = u64;
    fn try_push(&mut self, data: u8) -> postcard::Result<()> {
        self.0.write(&[data]);
        Ok(())
    }
    fn finalize(self) -> postcard::Result<u64> {
        Ok(self.0.finish())
    }
}

impl<R: SensorReal, const N: usize> SoftSensor<R, N> {
    /// FNV-1a of the postcard encoding of the configuration (c is carried state since issue
    /// 9: the snapshot stores it).
    pub fn config_hash(&self) -> u64 {
        let mut h = Fnv64::new();
        let cfg = postcard::serialize_with_flavor(&self.cfg, HashFlavor(Fnv64::new())).unwrap_or(0);
        h.write(&cfg.to_le_bytes());
        h.finish()
    }

    fn header(&self) -> SnapshotHeader<R> {
        SnapshotHeader {
            version: SNAPSHOT_VERSION,
            real_size: core::mem::size_of::<R>() as u8,
            config_hash: self.config_hash(),
            cells: self.seg.len() as u32,
            sensor_values: 2 * self.cfg.sensor_points() as u32,
            time: self.seg.time(),
            steps: self.seg.steps(),
            have_velocity: self.have_velocity,
            last_seq: self.last_seq,
            covered: self.covered,
            stale: self.stale,
            lag: self.lag,
            tick: self.tick,
            counters: self.counters,
            out_head: self.out_head,
            out_total: self.out_total,
            fines_state: self.fines_state,
            fines_runs: self.fines_runs,
            trend_len: self.trend_len,
            trend_head: self.trend_head,
            off_spec_in: self.off_spec_in,
            noise: [self.noise_variance, self.noise_share],
        }
    }

    /// Writes a snapshot into `out` (at most [`snapshot_capacity`]`(N)` bytes); returns its
    /// length. Take it between ticks.
    pub fn snapshot(&self, out: &mut [u8]) -> Result<usize, SnapshotError> {
        let mut at = 0;
        let put = |bytes: &mut [u8], at: &mut usize, item: &dyn erased::Item| {
            let n = item
                .write(&mut bytes[*at..])
                .ok_or(SnapshotError::BufferTooSmall)?;
            *at += n;
            Ok::<(), SnapshotError>(())
        };
        put(out, &mut at, &self.header())?;
        let n = self.seg.len();
        for i in 0..n {
            put(out, &mut at, &self.seg.c(i))?;
        }
        for i in 0..n {
            put(out, &mut at, &self.seg.tracked_fraction(i))?;
        }
        for i in 0..n {
            put(out, &mut at, &self.seg.carry(i))?;
        }
        for a in 0..2 {
            for i in 0..n {
                put(out, &mut at, &self.seg.face_coefficient(a, i))?;
            }
        }
        for v in &self.vel[..2 * self.cfg.sensor_points()] {
            put(out, &mut at, v)?;
        }
        for o in &self.out_ring[..self.cfg.outflow_window as usize] {
            put(out, &mut at, &o[0])?;
            put(out, &mut at, &o[1])?;
        }
        for s in &self.trend[..self.cfg.outflow_window as usize] {
            put(out, &mut at, &s[0])?;
            put(out, &mut at, &s[1])?;
        }
        let crc = crc32(&out[..at]);
        let end = at + 4;
        if end > out.len() {
            return Err(SnapshotError::BufferTooSmall);
        }
        out[at..end].copy_from_slice(&crc.to_le_bytes());
        Ok(end)
    }

    /// Restores a snapshot taken by a sensor with the same configuration. Everything is
    /// checked (CRC, version, configuration hash, value ranges) before anything is written.
    pub fn restore(&mut self, bytes: &[u8]) -> Result<(), SnapshotError> {
        if bytes.len() < 4 {
            return Err(SnapshotError::Crc);
        }
        let (body, tail) = bytes.split_at(bytes.len() - 4);
        let stored = u32::from_le_bytes([tail[0], tail[1], tail[2], tail[3]]);
        if crc32(body) != stored {
            return Err(SnapshotError::Crc);
        }
        let (h, rest): (SnapshotHeader<R>, _) =
            postcard::take_from_bytes(body).map_err(|_| SnapshotError::Decode)?;
        if h.version != SNAPSHOT_VERSION || h.real_size as usize != core::mem::size_of::<R>() {
            return Err(SnapshotError::Version);
        }
        let n = self.seg.len();
        let nv = 2 * self.cfg.sensor_points();
        if h.config_hash != self.config_hash()
            || h.cells as usize != n
            || h.sensor_values as usize != nv
        {
            return Err(SnapshotError::Config);
        }
        let window = self.cfg.outflow_window as usize;
        let sane = h.time.is_finite()
            && h.lag.is_finite()
            && h.out_total[0].is_finite()
            && h.out_total[1].is_finite()
            && (h.out_head as usize) < window
            && matches!(h.fines_state, 0 | alarm::FINES_LOW | alarm::FINES_HIGH)
            && (h.trend_len as usize) <= window
            && (h.trend_head as usize) < window
            && h.off_spec_in.is_none_or(|t| t.is_finite() && t >= R::ZERO)
            && h.noise.iter().all(|&x| x.is_finite() && x >= R::ZERO);
        if !sane {
            return Err(SnapshotError::Value);
        }
        // Pass 1: validate every value without writing (c in [0, 1], q within the slack of
        // [0, 1], carries below an ulp, everything finite).
        let tol = R::from_f64(SNAPSHOT_PHI_SLACK);
        let mut r = rest;
        for i in 0..5 * n + nv + 4 * window {
            let (v, next): (R, _) =
                postcard::take_from_bytes(r).map_err(|_| SnapshotError::Decode)?;
            let bad_c = i < n && !(v >= R::ZERO && v <= R::ONE);
            let bad_q = (n..2 * n).contains(&i) && (v < -tol || v > R::ONE + tol);
            // a carry is below half an ulp of q <= 1 (plus an ulp moved back into [0, c])
            let bad_carry = (2 * n..3 * n).contains(&i) && v.abs() > R::TWO * R::EPSILON;
            if !v.is_finite() || bad_c || bad_q || bad_carry {
                return Err(SnapshotError::Value);
            }
            r = next;
        }
        if !r.is_empty() {
            return Err(SnapshotError::Decode);
        }
        // Pass 2: write (cannot fail any more): every value exactly as stored.
        let mut r = rest;
        for i in 0..n {
            let c = next_value(&mut r);
            self.seg.set_volume_fraction(i, c);
        }
        for i in 0..n {
            let q = next_value(&mut r);
            self.seg.set_tracked(i, q);
        }
        for i in 0..n {
            let e = next_value(&mut r);
            self.seg.set_carry(i, e);
        }
        // The face coefficients are restored after prepare_velocity (below), which would
        // overwrite them: keep where they start.
        let k_bytes = r;
        for _ in 0..2 * n {
            let _: R = next_value(&mut r);
        }
        for k in 0..nv {
            self.vel[k] = next_value(&mut r);
        }
        for k in 0..window {
            self.out_ring[k] = [next_value(&mut r), next_value(&mut r)];
        }
        for k in 0..window {
            self.trend[k] = [next_value(&mut r), next_value(&mut r)];
        }
        self.have_velocity = h.have_velocity;
        self.last_seq = h.last_seq;
        self.covered = h.covered;
        self.stale = h.stale;
        self.lag = h.lag;
        self.tick = h.tick;
        [self.noise_variance, self.noise_share] = h.noise;
        // Derive u, T and the coefficients again; they depend on u and c only, not on q.
        if self.have_velocity {
            self.map_velocity();
        } else {
            for i in 0..n {
                self.seg.set_velocity(i, [R::ZERO; 2]);
            }
        }
        let ok = self.prepare_measured().is_ok();
        debug_assert!(ok, "validated velocities must prepare");
        let mut r = k_bytes;
        for a in 0..2 {
            for i in 0..n {
                let k = next_value(&mut r);
                self.seg.set_face_coefficient(a, i, k);
            }
        }
        self.out_head = h.out_head;
        self.out_total = h.out_total;
        self.fines_state = h.fines_state;
        self.fines_runs = h.fines_runs;
        self.trend_len = h.trend_len;
        self.trend_head = h.trend_head;
        self.off_spec_in = h.off_spec_in;
        self.counters = h.counters;
        self.seg.set_clock(h.time, h.steps);
        Ok(())
    }
}

/// The next value of a validated item stream (0 if it ended: cannot happen after pass 1).
fn next_value<R: SensorReal>(r: &mut &[u8]) -> R {
    match postcard::take_from_bytes::<R>(r) {
        Ok((v, next)) => {
            *r = next;
            v
        }
        Err(_) => R::ZERO,
    }
}

/// Object-safe "serialise into a slice" so one closure writes headers and values.
mod erased {
    use serde::Serialize;
    pub trait Item {
        fn write(&self, out: &mut [u8]) -> Option<usize>;
    }
    impl<T: Serialize> Item for T {
        fn write(&self, out: &mut [u8]) -> Option<usize> {
            postcard::to_slice(self, out).ok().map(|s| s.len())
        }
    }
}
