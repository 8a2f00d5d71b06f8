//! The recording file: configuration, the exact byte stream a sensor UART would deliver, and
//! the ground truth alongside. Parsed without allocation so the firmware reads the same file
//! (embedded with `include_bytes!`) that the host replays.
//!
//! | offset | size | content |
//! |---|---|---|
//! | 0 | 8 | magic `SIEVEREC` |
//! | 8 | 4 | format version, u32 LE (= [`RECORDING_VERSION`]) |
//! | 12 | 4 | header length `H`, u32 LE |
//! | 16 | H | postcard [`RecordingHeader`] (configuration f32, scene, noise, seed, ...) |
//! | 16+H | 4 | stream length `S`, u32 LE |
//! | 20+H | S | frame stream: concatenated wire frames (COBS, see [`super::frame`]) |
//! | 20+H+S | 4 | truth length `T`, u32 LE |
//! | 24+H+S | T | concatenated postcard [`TruthRecord`]s, one per frame |
//! | 24+H+S+T | 4 | CRC-32 of all bytes before it, u32 LE |

use super::config::SensorConfig;
use super::{crc32, MAX_SENSOR_POINTS};
use serde::{Deserialize, Serialize};

/// File magic.
pub const RECORDING_MAGIC: [u8; 8] = *b"SIEVEREC";
/// Current format version.
pub const RECORDING_VERSION: u32 = 7;

/// What the recording says about itself.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RecordingHeader {
    /// Soft-sensor configuration the recording is meant for (f32: the firmware's type).
    pub config: SensorConfig<f32>,
    /// Scene name.
    pub scene: heapless::String<32>,
    /// Relative velocity noise (standard deviation / largest speed).
    pub noise: f32,
    /// Seed of the noise generator.
    pub seed: u64,
    /// Frames in the stream (before fault injection).
    pub frames: u32,
    /// Cells of the truth simulation (x, z).
    pub truth_cells: [u16; 2],
    /// Cells of the coarse truth phihat field stored per frame (x, z).
    pub truth_coarse: [u16; 2],
}

/// Ground truth at the end of one frame period.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TruthRecord {
    /// Frame sequence number.
    pub seq: u32,
    /// Truth time \[s\].
    pub time: f32,
    /// Mixing index of the truth.
    pub psi: f32,
    /// phihat of the truth averaged onto the coarse grid (x fastest).
    pub phihat: heapless::Vec<f32, MAX_SENSOR_POINTS>,
    /// c of the truth averaged onto the coarse grid (x fastest): what the estimator's
    /// carried c is compared with (format 3).
    pub c: heapless::Vec<f32, MAX_SENSOR_POINTS>,
    /// Grain volume and small-grain volume that had left the truth's box by this time (per
    /// unit depth; 0 for a closed box), for the outflow fines fraction (format 3).
    pub discharged: [f32; 2],
    /// Mixing index of the truth averaged onto the estimator's grid (format 6): Psi of a sharp
    /// interface depends on the cells it is measured in, and this is the one an estimator on
    /// that grid can reach.
    pub psi_estimator_grid: f32,
}

impl TruthRecord {
    /// Appends the postcard encoding of this record to `out` (a writer callback); returns
    /// false if the record does not fit the 2 KiB scratch.
    pub fn encode_into(&self, mut out: impl FnMut(&[u8])) -> bool {
        let mut buf = [0u8; 8 + 5 + 2 * (2 + 4 * super::MAX_SENSOR_POINTS) + 8 + 8 + 4];
        match postcard::to_slice(self, &mut buf) {
            Ok(b) => {
                out(b);
                true
            }
            Err(_) => false,
        }
    }
}

/// A parsed recording: views into the file bytes.
#[derive(Clone, Debug)]
pub struct Recording<'a> {
    /// The header.
    pub header: RecordingHeader,
    /// The wire byte stream.
    pub stream: &'a [u8],
    /// The truth records (decode with [`Recording::truth`]).
    pub truth_bytes: &'a [u8],
}

/// Why a recording cannot be read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RecordingError {
    /// Wrong magic.
    Magic,
    /// Unknown version.
    Version,
    /// Truncated or inconsistent lengths.
    Truncated,
    /// CRC mismatch.
    Crc,
    /// Header not decodable.
    Header,
}

fn take<'a>(b: &'a [u8], at: &mut usize, n: usize) -> Result<&'a [u8], RecordingError> {
    let end = at.checked_add(n).ok_or(RecordingError::Truncated)?;
    let s = b.get(*at..end).ok_or(RecordingError::Truncated)?;
    *at = end;
    Ok(s)
}

fn take_u32(b: &[u8], at: &mut usize) -> Result<u32, RecordingError> {
    let s = take(b, at, 4)?;
    Ok(u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
}

impl<'a> Recording<'a> {
    /// Parses and checks a recording.
    pub fn parse(b: &'a [u8]) -> Result<Self, RecordingError> {
        let mut at = 0;
        if take(b, &mut at, 8)? != RECORDING_MAGIC {
            return Err(RecordingError::Magic);
        }
        if take_u32(b, &mut at)? != RECORDING_VERSION {
            return Err(RecordingError::Version);
        }
        let hl = take_u32(b, &mut at)? as usize;
        let hb = take(b, &mut at, hl)?;
        let sl = take_u32(b, &mut at)? as usize;
        let stream = take(b, &mut at, sl)?;
        let tl = take_u32(b, &mut at)? as usize;
        let truth_bytes = take(b, &mut at, tl)?;
        let body_end = at;
        let crc = take_u32(b, &mut at)?;
        if at != b.len() {
            return Err(RecordingError::Truncated);
        }
        if crc32(&b[..body_end]) != crc {
            return Err(RecordingError::Crc);
        }
        let header = postcard::from_bytes(hb).map_err(|_| RecordingError::Header)?;
        Ok(Self {
            header,
            stream,
            truth_bytes,
        })
    }

    /// Iterates over the truth records (stops at the first undecodable one).
    pub fn truth(&self) -> impl Iterator<Item = TruthRecord> + 'a {
        let mut rest = self.truth_bytes;
        core::iter::from_fn(move || {
            if rest.is_empty() {
                return None;
            }
            let (t, next) = postcard::take_from_bytes::<TruthRecord>(rest).ok()?;
            rest = next;
            Some(t)
        })
    }
}

/// Writes a recording through `write` (chunks in file order); `truth` is the concatenation
/// of postcard-encoded [`TruthRecord`]s. The header is encoded in `scratch`.
pub fn write_recording<E>(
    header: &RecordingHeader,
    stream: &[u8],
    truth: &[u8],
    scratch: &mut [u8],
    mut write: impl FnMut(&[u8]) -> Result<(), E>,
    on_encode_error: E,
) -> Result<(), E> {
    let hb = match postcard::to_slice(header, scratch) {
        Ok(h) => h,
        Err(_) => return Err(on_encode_error),
    };
    let mut digest = super::CRC32.digest();
    let mut emit = |bytes: &[u8]| {
        digest.update(bytes);
        write(bytes)
    };
    emit(&RECORDING_MAGIC)?;
    emit(&RECORDING_VERSION.to_le_bytes())?;
    emit(&(hb.len() as u32).to_le_bytes())?;
    emit(hb)?;
    emit(&(stream.len() as u32).to_le_bytes())?;
    emit(stream)?;
    emit(&(truth.len() as u32).to_le_bytes())?;
    emit(truth)?;
    let crc = digest.finalize();
    write(&crc.to_le_bytes())
}
