//! The UART side of the soft-sensor loop, shared by the firmware and the host replay so both
//! run the same bytes through the same code: [`Feeder`] delivers a recorded frame stream tick
//! by tick with optional deterministic fault injection, and [`feed_bytes`] pushes received
//! bytes through the decoder into the sensor.
//!
//! Fault model (each decision is drawn per delivered frame from a SplitMix64 generator seeded
//! by [`Faults::seed`], probabilities in units of 1/65536):
//! * bit flip: one random bit of the frame's wire bytes is inverted (caught by COBS or CRC);
//! * dropped byte: one random byte is removed (caught by COBS or CRC);
//! * duplicate: the frame is delivered twice (caught by the sequence check);
//! * reorder: the frame and the next one swap places (the late one fails the sequence check);
//! * NaN: one velocity value becomes NaN with a valid CRC (caught by the finiteness check);
//! * stall: every `stall_every` ticks the link delivers nothing for `stall_len` ticks, then
//!   everything withheld in one burst (the sensor holds, possibly freezes, then catches up).

use super::estimator::SoftSensor;
use super::frame::{decode_in_place, encode, FrameDecoder, VelocityFrame, FRAME_WIRE_MAX};
use super::SensorReal;
use postcard::experimental::max_size::MaxSize;

/// Fault injection settings; all zero = a clean link.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Faults {
    /// Generator seed.
    pub seed: u64,
    /// Probability per frame of a bit flip, in 1/65536.
    pub bit_flip: u16,
    /// Probability per frame of a dropped byte, in 1/65536.
    pub drop_byte: u16,
    /// Probability per frame of a duplicate, in 1/65536.
    pub duplicate: u16,
    /// Probability per frame of swapping with the next frame, in 1/65536.
    pub reorder: u16,
    /// Probability per frame of a NaN value (with a valid CRC), in 1/65536.
    pub nan: u16,
    /// A stall starts every this many ticks (0 = never).
    pub stall_every: u32,
    /// Length of a stall in ticks.
    pub stall_len: u32,
}

impl Faults {
    /// A clean link (`const`, unlike `Default`).
    pub const NONE: Faults = Faults {
        seed: 0,
        bit_flip: 0,
        drop_byte: 0,
        duplicate: 0,
        reorder: 0,
        nan: 0,
        stall_every: 0,
        stall_len: 0,
    };
    /// The fault profile used by firmware-sim and its host check: every fault kind at a few
    /// percent, and a 4-tick stall every 40 ticks.
    pub const DEMO: Faults = Faults {
        seed: 0x005e_ed0f_fa17,
        bit_flip: 2000,
        drop_byte: 1500,
        duplicate: 2000,
        reorder: 1500,
        nan: 1500,
        stall_every: 40,
        stall_len: 4,
    };
}

/// How many faults of each kind the feeder injected.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct InjectedFaults {
    /// Bit flips.
    pub bit_flips: u32,
    /// Dropped bytes.
    pub dropped_bytes: u32,
    /// Duplicated frames.
    pub duplicates: u32,
    /// Swapped frame pairs.
    pub reorders: u32,
    /// NaN values.
    pub nans: u32,
    /// Ticks without delivery.
    pub stall_ticks: u32,
}

/// SplitMix64 (Steele, Lea & Flood 2014): a tiny, well-mixed, seedable generator; fault
/// decisions need nothing more and the core stays free of extra dependencies.
#[derive(Clone, Copy, Debug)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    /// A generator from a seed.
    pub const fn new(seed: u64) -> Self {
        Self(seed)
    }
    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    /// True with probability `p / 65536`.
    fn chance(&mut self, p: u16) -> bool {
        ((self.next_u64() >> 48) as u16) < p
    }
    /// Uniform in `0..n` (n > 0).
    fn below(&mut self, n: usize) -> usize {
        ((self.next_u64() >> 32) % n as u64) as usize
    }
}

/// Delivers a recorded wire stream one frame per tick, with faults.
pub struct Feeder<'a> {
    stream: &'a [u8],
    pos: usize,
    faults: Faults,
    rng: SplitMix64,
    tick: u32,
    owed: u32,
    /// Injected fault counts.
    pub injected: InjectedFaults,
    work: [u8; FRAME_WIRE_MAX],
    scratch: [u8; VelocityFrame::POSTCARD_MAX_SIZE],
}

impl<'a> Feeder<'a> {
    /// A feeder over `stream` (concatenated wire frames); `const` so it can be a `static`.
    pub const fn new(stream: &'a [u8], faults: Faults) -> Self {
        Self {
            stream,
            pos: 0,
            faults,
            rng: SplitMix64::new(faults.seed),
            tick: 0,
            owed: 0,
            injected: InjectedFaults {
                bit_flips: 0,
                dropped_bytes: 0,
                duplicates: 0,
                reorders: 0,
                nans: 0,
                stall_ticks: 0,
            },
            work: [0; FRAME_WIRE_MAX],
            scratch: [0; VelocityFrame::POSTCARD_MAX_SIZE],
        }
    }

    /// Starts over on `stream` with `faults` (in place: no 4 KiB temporary on the stack).
    pub fn reset(&mut self, stream: &'a [u8], faults: Faults) {
        self.stream = stream;
        self.pos = 0;
        self.faults = faults;
        self.rng = SplitMix64::new(faults.seed);
        self.tick = 0;
        self.owed = 0;
        self.injected = InjectedFaults::default();
    }

    /// True once every frame was delivered.
    pub fn done(&self) -> bool {
        self.pos >= self.stream.len() && self.owed == 0
    }

    fn next_frame(&mut self) -> Option<&'a [u8]> {
        let rest = self.stream.get(self.pos..)?;
        if rest.is_empty() {
            return None;
        }
        let len = rest
            .iter()
            .position(|&b| b == 0)
            .map_or(rest.len(), |z| z + 1);
        self.pos += len;
        Some(&rest[..len])
    }

    /// Delivers this tick's bytes through `emit` (zero or more chunks).
    pub fn tick(&mut self, mut emit: impl FnMut(&[u8])) {
        let t = self.tick;
        self.tick = self.tick.wrapping_add(1);
        let f = self.faults;
        // A stall never covers a whole cycle, so the stream always drains.
        let stall = f.stall_len.min(f.stall_every.saturating_sub(1));
        if f.stall_every > 0 && t % f.stall_every >= f.stall_every - stall {
            if self.pos < self.stream.len() {
                self.owed += 1;
                self.injected.stall_ticks += 1;
            }
            return;
        }
        let count = 1 + core::mem::take(&mut self.owed);
        let mut k = 0;
        while k < count {
            let Some(frame) = self.next_frame() else {
                break;
            };
            k += 1;
            if self.rng.chance(f.reorder) {
                if let Some(next) = self.next_frame() {
                    self.injected.reorders += 1;
                    k += 1;
                    self.deliver(next, &mut emit);
                    self.deliver(frame, &mut emit);
                    continue;
                }
            }
            self.deliver(frame, &mut emit);
            if self.rng.chance(f.duplicate) {
                self.injected.duplicates += 1;
                self.deliver(frame, &mut emit);
            }
        }
    }

    /// Applies the byte-level faults to one frame and emits it in UART-sized chunks.
    fn deliver(&mut self, frame: &[u8], emit: &mut impl FnMut(&[u8])) {
        let f = self.faults;
        let mut len = frame.len().min(self.work.len());
        self.work[..len].copy_from_slice(&frame[..len]);
        if self.rng.chance(f.nan) && self.poison(frame, len).map(|n| len = n).is_some() {
            self.injected.nans += 1;
        }
        if self.rng.chance(f.bit_flip) && len > 0 {
            let at = self.rng.below(len * 8);
            self.work[at / 8] ^= 1 << (at % 8);
            self.injected.bit_flips += 1;
        }
        if self.rng.chance(f.drop_byte) && len > 1 {
            let at = self.rng.below(len);
            self.work.copy_within(at + 1..len, at);
            len -= 1;
            self.injected.dropped_bytes += 1;
        }
        for chunk in self.work[..len].chunks(64) {
            emit(chunk);
        }
    }

    /// Re-encodes the frame in `work[..len]` with one velocity value replaced by NaN; returns
    /// the new length, or None if the frame does not decode (then it is left as it was).
    fn poison(&mut self, original: &[u8], len: usize) -> Option<usize> {
        // Decoding in place destroys `work`; restore it from the original on failure.
        let mut frame: VelocityFrame = match decode_in_place::<VelocityFrame>(&mut self.work[..len])
        {
            Ok(f) if !f.u.is_empty() => f,
            _ => {
                self.work[..len].copy_from_slice(&original[..len]);
                return None;
            }
        };
        let at = self.rng.below(frame.u.len());
        frame.u[at] = f32::NAN;
        encode(&frame, &mut self.scratch, &mut self.work).ok()
    }
}

/// Pushes received bytes through the decoder into the sensor: every complete message is
/// submitted as a frame; byte-level rejections are counted by the decoder and flagged in the
/// sensor's tick health.
pub fn feed_bytes<R: SensorReal, const N: usize, const BUF: usize>(
    sensor: &mut SoftSensor<R, N>,
    decoder: &mut FrameDecoder<BUF>,
    bytes: &[u8],
) {
    let mut window = bytes;
    while !window.is_empty() {
        let (res, rest) = decoder.feed::<VelocityFrame>(window);
        window = rest;
        match res {
            Some(Ok(frame)) => {
                let _ = sensor.submit(&frame);
            }
            Some(Err(r)) => sensor.count_reject(r),
            None => {}
        }
    }
}
