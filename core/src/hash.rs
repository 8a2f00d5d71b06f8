//! FNV-1a, 64 bit: the state hash used by golden tests, summaries and the firmware.
//!
//! Chosen because it is trivial, needs no tables (cheap on a Cortex-M) and is stable by
//! definition: the same bytes give the same hash on every platform and in every build.

/// Incremental FNV-1a 64-bit hasher.
#[derive(Clone, Copy, Debug)]
pub struct Fnv64(u64);

impl Default for Fnv64 {
    fn default() -> Self {
        Self::new()
    }
}

impl Fnv64 {
    const OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
    const PRIME: u64 = 0x0000_0100_0000_01b3;

    /// A fresh hasher.
    pub const fn new() -> Self {
        Self(Self::OFFSET)
    }
    /// Feeds bytes.
    #[inline]
    pub fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 ^= b as u64;
            self.0 = self.0.wrapping_mul(Self::PRIME);
        }
    }
    /// Feeds a u32 as 4 little-endian bytes (sizes are hashed as u32, never usize).
    #[inline]
    pub fn write_u32(&mut self, x: u32) {
        self.write(&x.to_le_bytes());
    }
    /// The hash so far.
    pub const fn finish(&self) -> u64 {
        self.0
    }
}
