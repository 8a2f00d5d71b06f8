//! Snapshots: the estimator state as postcard items plus a CRC-32, restored bit-identically.
//!
//! Layout: `postcard(SnapshotHeader)`, then `cells` values of the tracked phase fraction `q`
//! (phi for `Phase::Small`, c - phi for `Phase::Large`: the solver's own state, written and
//! restored with `set_tracked`, so either phase round-trips bit-exactly), `cells` values of the
//! rounding error the compensated updates carry per cell, and `2 * sensor points` values of the smoothed sensor velocity (each a postcard `R`: fixed-width IEEE bits), then
//! the CRC-32 of everything before it (4 bytes little endian). Items are written and read one
//! by one, so no buffer of the size of the state is needed besides the output itself.
//!
//! Derived quantities (u on the estimator grid, T, the segregation coefficients) are not
//! stored: restore maps the stored sensor field again and calls `prepare_velocity`, which
//! computes them with the same operations in the same order, so they come out bit-identical.
//! Nothing is clamped: q is restored as stored.

use super::estimator::{Counters, SoftSensor};
use super::{crc32, SensorReal, MAX_FRAME_VALUES};
use crate::hash::Fnv64;
use postcard::ser_flavors::Flavor;
use serde::{Deserialize, Serialize};

/// Snapshot format version.
pub const SNAPSHOT_VERSION: u16 = 3;

/// How far outside [0, c] a stored tracked fraction may be. The estimator never clamps, so
/// phi may leave [0, c] by round-off and by the compression of a noisy measured velocity (of
/// the order of 1e-4 in the shear cell at 10 % noise); anything beyond this is not a state it
/// produces, and is refused.
pub const SNAPSHOT_PHI_SLACK: f64 = 0.05;

/// Upper bound of a snapshot's size for capacity `N` (f64 values, generous header).
pub const fn snapshot_capacity(n: usize) -> usize {
    256 + 8 * (2 * n + MAX_FRAME_VALUES)
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
    /// FNV-1a of the postcard encoding of the configuration and of the c field.
    pub fn config_hash(&self) -> u64 {
        let mut h = Fnv64::new();
        let cfg = postcard::serialize_with_flavor(&self.cfg, HashFlavor(Fnv64::new())).unwrap_or(0);
        h.write(&cfg.to_le_bytes());
        for i in 0..self.seg.len() {
            self.seg.c(i).hash_into(&mut h);
        }
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
        for i in 0..self.seg.len() {
            put(out, &mut at, &self.seg.tracked_fraction(i))?;
        }
        for i in 0..self.seg.len() {
            put(out, &mut at, &self.seg.carry(i))?;
        }
        for v in &self.vel[..2 * self.cfg.sensor_points()] {
            put(out, &mut at, v)?;
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
        if !h.time.is_finite() || !h.lag.is_finite() {
            return Err(SnapshotError::Value);
        }
        // Pass 1: validate every value without writing.
        let tol = R::from_f64(SNAPSHOT_PHI_SLACK);
        let mut r = rest;
        for i in 0..2 * n + nv {
            let (v, next): (R, _) =
                postcard::take_from_bytes(r).map_err(|_| SnapshotError::Decode)?;
            let bad_q = i < n && (v < -tol || v > self.seg.c(i) + tol);
            // a carry is below half an ulp of q <= 1
            let bad_carry = (n..2 * n).contains(&i) && v.abs() > R::EPSILON;
            if !v.is_finite() || bad_q || bad_carry {
                return Err(SnapshotError::Value);
            }
            r = next;
        }
        if !r.is_empty() {
            return Err(SnapshotError::Decode);
        }
        // Pass 2: write (cannot fail any more): the tracked fractions exactly as stored.
        let mut r = rest;
        for i in 0..n {
            if let Ok((v, next)) = postcard::take_from_bytes::<R>(r) {
                self.seg.set_tracked(i, v);
                r = next;
            }
        }
        for i in 0..n {
            if let Ok((v, next)) = postcard::take_from_bytes::<R>(r) {
                self.seg.set_carry(i, v);
                r = next;
            }
        }
        for k in 0..nv {
            if let Ok((v, next)) = postcard::take_from_bytes::<R>(r) {
                self.vel[k] = v;
                r = next;
            }
        }
        self.have_velocity = h.have_velocity;
        self.last_seq = h.last_seq;
        self.covered = h.covered;
        self.stale = h.stale;
        self.lag = h.lag;
        self.tick = h.tick;
        // Derive u, T and the coefficients again; they depend on u and c only, not on q.
        if self.have_velocity {
            self.map_velocity();
        } else {
            for i in 0..n {
                self.seg.set_velocity(i, [R::ZERO; 2]);
            }
        }
        let ok = self.seg.prepare_velocity().is_ok();
        debug_assert!(ok, "validated velocities must prepare");
        self.counters = h.counters;
        self.seg.set_clock(h.time, h.steps);
        Ok(())
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
