//! Wire types and the byte-level codec of the soft sensor.
//!
//! Wire format of every message (velocity frames in, estimates out):
//!
//! ```text
//! COBS( postcard( Packet { body: postcard(message) as bytes, crc: CRC-32(body) } ) ) 0x00
//! ```
//!
//! postcard writes the body as a varint length plus the bytes and the CRC as a varint u32;
//! COBS removes every zero so `0x00` delimits messages on a byte stream (UART). The decoder
//! ([`FrameDecoder`]) reassembles chunks with postcard's `CobsAccumulator`, checks the CRC,
//! then deserialises the body; every failure is counted by cause and never panics (the
//! property tests feed random and mutated bytes).

use super::{MAX_FRAME_VALUES, MAX_REGIONS};
use postcard::accumulator::{CobsAccumulator, FeedResult};
use postcard::experimental::max_size::MaxSize;
use serde::{de::DeserializeOwned, Deserialize, Serialize};

/// One measured velocity field on the sensor grid.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VelocityFrame {
    /// Sequence number; must advance (frame `k` covers the `k`-th period), in serial-number
    /// order: it may wrap past `u32::MAX` to 0 (see `estimator::seq_after`).
    pub seq: u32,
    /// Sensor timestamp of the end of the period \[s\] (informative only; time is advanced by
    /// `period`, so a drifting f32 clock cannot make runs irreproducible).
    pub time: f32,
    /// Time this frame stands for \[s\]; the tick advances exactly this much.
    pub period: f32,
    /// Sensor points along x.
    pub nx: u8,
    /// Sensor points along z.
    pub nz: u8,
    /// Velocities, interleaved `(u_x, u_z)` per point, x fastest: `2 nx nz` values [m/s].
    pub u: heapless::Vec<f32, MAX_FRAME_VALUES>,
}

impl VelocityFrame {
    /// An empty frame (no points), for static buffers.
    pub const fn empty() -> Self {
        Self {
            seq: 0,
            time: 0.0,
            period: 0.0,
            nx: 0,
            nz: 0,
            u: heapless::Vec::new(),
        }
    }
}

// Written by hand: postcard's MaxSize derive knows heapless 0.7 only. The bound is the sum of
// the worst cases: u32 varint 5, two f32 8, two u8 2, length varint 2, values 4 each.
impl MaxSize for VelocityFrame {
    const POSTCARD_MAX_SIZE: usize = 5 + 8 + 2 + 2 + 4 * MAX_FRAME_VALUES;
}

/// What the soft sensor reports after each tick.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Estimate {
    /// Sequence number of the last accepted frame (0 if none).
    pub seq: u32,
    /// Tick counter.
    pub tick: u32,
    /// Simulated time of the estimator \[s\].
    pub time: f32,
    /// Mixing index psi (1 mixed, 0 segregated), model.md 6.
    pub psi: f32,
    /// Smallest phihat over non-empty cells.
    pub phihat_min: f32,
    /// Largest phihat over non-empty cells.
    pub phihat_max: f32,
    /// Mean phihat (c-weighted) in each named region, in configuration order; the outlet
    /// region's value is the fines fraction of the discharge.
    pub regions: heapless::Vec<f32, MAX_REGIONS>,
    /// Alarm bits, see [`super::alarm`].
    pub alarms: u8,
    /// Health bits, see [`super::health`].
    pub health: u8,
    /// Substeps taken this tick.
    pub substeps: u16,
    /// Accumulated simulated-time shortfall (budget limits, frozen or lost periods) \[s\].
    pub lag: f32,
    /// Grain volume that left the box this tick (per unit depth, m^2 in 2D): the
    /// estimator's own outlet, outflow and inflow face fluxes (negative if more came in).
    pub outflow: f32,
    /// Fines fraction of what left this tick (small-grain volume over grain volume of the
    /// outflow); 0 if nothing left.
    pub outflow_fines: f32,
    /// Fines fraction of what left over the last `outflow_window` ticks; 0 if nothing left.
    pub outflow_fines_window: f32,
    /// Predicted time until the outlet fines fraction leaves the band `fines_band` \[s\]:
    /// 0 while it is out of the band (or a fines alarm is raised), `f32::INFINITY` when no
    /// exit is predicted (its trend is flat or heads into the band, or fewer than 3 ticks of
    /// outflow are known). See `SoftSensor` ("Off-spec prediction").
    pub off_spec_in: f32,
}

impl MaxSize for Estimate {
    const POSTCARD_MAX_SIZE: usize = 5 + 5 + 4 * 4 + 1 + 4 * MAX_REGIONS + 2 + 3 + 4 + 4 * 4;
}

/// The CRC envelope inside the COBS frame.
#[derive(Serialize, Deserialize)]
struct Packet<'a> {
    #[serde(borrow)]
    body: &'a [u8],
    crc: u32,
}

/// Worst-case encoded size on the wire of a message whose postcard body is at most `body`
/// bytes: envelope (length varint 3 + CRC varint 5), COBS overhead (1 per 254) and delimiter.
pub const fn wire_max(body: usize) -> usize {
    let packet = body + 3 + 5;
    packet + packet / 254 + 2
}

/// Worst-case wire size of a velocity frame.
pub const FRAME_WIRE_MAX: usize = wire_max(VelocityFrame::POSTCARD_MAX_SIZE);
/// Worst-case wire size of an estimate.
pub const ESTIMATE_WIRE_MAX: usize = wire_max(Estimate::POSTCARD_MAX_SIZE);
/// Largest postcard body of an [`Estimate`] (the scratch `encode` needs for it).
pub const ESTIMATE_BODY_MAX: usize = Estimate::POSTCARD_MAX_SIZE;

/// Why encoding failed (a buffer too small).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EncodeError;

/// Encodes `msg` for the wire into `out` using `scratch` for the postcard body; returns the
/// number of bytes written (including the trailing `0x00`).
pub fn encode<T: Serialize>(
    msg: &T,
    scratch: &mut [u8],
    out: &mut [u8],
) -> Result<usize, EncodeError> {
    let body = postcard::to_slice(msg, scratch).map_err(|_| EncodeError)?;
    let packet = Packet {
        crc: super::crc32(body),
        body,
    };
    let wire = postcard::to_slice_cobs(&packet, out).map_err(|_| EncodeError)?;
    Ok(wire.len())
}

/// Decodes one complete wire message (with or without its trailing `0x00`) in place; the
/// same checks as [`FrameDecoder`] without reassembly.
pub fn decode_in_place<T: DeserializeOwned>(buf: &mut [u8]) -> Result<T, Reject> {
    let packet: Packet<'_> = postcard::from_bytes_cobs(buf).map_err(|_| Reject::Framing)?;
    if super::crc32(packet.body) != packet.crc {
        return Err(Reject::Crc);
    }
    postcard::from_bytes(packet.body).map_err(|_| Reject::Decode)
}

/// Why a frame was rejected. Each cause has its own counter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reject {
    /// The accumulator overflowed before a delimiter (garbage or a lost delimiter).
    Overflow,
    /// COBS or envelope decoding failed (corrupted framing, empty frame).
    Framing,
    /// CRC mismatch.
    Crc,
    /// CRC fine but the body is not a valid message (version skew, truncated).
    Decode,
    /// Sensor grid dimensions or value count differ from the configuration.
    Dims,
    /// A NaN or infinite value.
    NonFinite,
    /// A value outside its range (speed above the reject limit, bad period).
    Range,
    /// The sequence number does not advance (duplicate or reordered frame).
    Seq,
}

/// Counters of the byte-level rejection causes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct WireCounters {
    /// Messages decoded (CRC and body fine).
    pub decoded: u32,
    /// [`Reject::Overflow`]
    pub overflow: u32,
    /// [`Reject::Framing`]
    pub framing: u32,
    /// [`Reject::Crc`]
    pub crc: u32,
    /// [`Reject::Decode`]
    pub decode: u32,
}

/// Reassembles messages from byte chunks (as read from a UART) and decodes them. `BUF` is the
/// largest encoded message it accepts (use [`FRAME_WIRE_MAX`]).
pub struct FrameDecoder<const BUF: usize> {
    acc: CobsAccumulator<BUF>,
    /// Counters per cause.
    pub counters: WireCounters,
}

impl<const BUF: usize> Default for FrameDecoder<BUF> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const BUF: usize> FrameDecoder<BUF> {
    /// An empty decoder.
    pub const fn new() -> Self {
        Self {
            acc: CobsAccumulator::new(),
            counters: WireCounters {
                decoded: 0,
                overflow: 0,
                framing: 0,
                crc: 0,
                decode: 0,
            },
        }
    }

    /// Consumes bytes up to and including the next delimiter (or all of `input`). Returns the
    /// decoded message or the cause of rejection if a message ended, and the unconsumed rest.
    /// Call again with the rest until it is empty.
    pub fn feed<'a, T: DeserializeOwned>(
        &mut self,
        input: &'a [u8],
    ) -> (Option<Result<T, Reject>>, &'a [u8]) {
        let (result, rest) = match self.acc.feed_ref::<Packet<'_>>(input) {
            FeedResult::Consumed => (None, &input[input.len()..]),
            FeedResult::OverFull(rest) => (Some(Err(Reject::Overflow)), rest),
            FeedResult::DeserError(rest) => (Some(Err(Reject::Framing)), rest),
            FeedResult::Success { data, remaining } => {
                let r = if super::crc32(data.body) != data.crc {
                    Err(Reject::Crc)
                } else {
                    postcard::from_bytes::<T>(data.body).map_err(|_| Reject::Decode)
                };
                (Some(r), remaining)
            }
        };
        if let Some(r) = &result {
            let c = &mut self.counters;
            match r {
                Ok(_) => bump(&mut c.decoded),
                Err(Reject::Overflow) => bump(&mut c.overflow),
                Err(Reject::Framing) => bump(&mut c.framing),
                Err(Reject::Crc) => bump(&mut c.crc),
                Err(_) => bump(&mut c.decode),
            }
        }
        (result, rest)
    }
}

/// Counts without ever panicking (wraps after 2^32 events, which a report can tell).
#[inline]
pub(crate) fn bump(c: &mut u32) {
    *c = c.wrapping_add(1);
}
