//! Checkpoints and `sieve run --resume DIR` (issue 10, docs/resume.md).
//!
//! A long run (a tumbler for many revolutions, a silo until empty) writes, every
//! `run.checkpoint_interval` seconds of wall-clock time, everything its next step depends on:
//! the solvers' persistent arrays and clocks (`for_each_state_array`, `counters`, the coupled
//! totals, the frozen flow), the loop's progress (next output index, steps, the series rows,
//! the discharge rows, the stable step) and the identity of the run (the scene text and its
//! overrides, a fingerprint of the validated scene and its initial fields, the sieve build).
//! Derived data is not stored but re-derived exactly as the run derives it (face
//! coefficients by `prepare`, the segregation timer by replaying the series, the VTK
//! collection from the output times). A resumed run therefore ends with the same bits as an
//! uninterrupted one; `host/tests/resume.rs` kills runs with SIGKILL and compares.
//!
//! **Where.** Next to the target DIR, in `.DIR.checkpoint/` (never a `.DIR.tmp-*` name, so the
//! clean-up of staging debris after a SIGKILL leaves it alone): `checkpoint.bin` plus
//! `fields/state_KKKK.vti` (under mpirun `fields/state_KKKK.pvti` and its pieces
//! `state_KKKK_R.vti`), hard links (copies across file systems) of the snapshots written so
//! far, so that outputs written before a kill survive the loss of the staging directory. A
//! finished run removes it after DIR is committed; a fresh run into DIR refuses (exit 2) while
//! it holds a checkpoint.
//!
//! **Format** (little endian): `SIEVECKP`, format version (u32), number of entries (u32),
//! entries in ascending name order `name_len (u8), name, tag (u8), count (u64), payload`, and
//! a CRC-64/XZ of all
//! preceding bytes. Tags: 1 u64, 2 f64 (raw bits), 3 f64 array, 4 u64 array, 5 UTF-8 text.
//! Floats are stored as their bits (f32 solvers widen exactly). Written atomically: a
//! temporary file in the same directory (`.checkpoint.XXXXXX.part`, six ASCII letters or
//! digits), `fsync`, rename, `fsync` of the directory; the kept VTK files are `fsync`ed
//! before. A SIGKILL during the write leaves the temporary file, which is never read (the
//! checkpoint is `checkpoint.bin` only). The reader checks the size of the file, the
//! checksum, and every count against the bytes left before it allocates; any damage is one
//! line, exit 2.
//!
//! **Removal: names recorded, never patterns.** A name pattern cannot tell sieve's file from
//! a user's of the same shape, so sieve removes a temporary file only under the name a
//! checkpoint recorded for it: each checkpoint stores (`part.next`) the name the next write
//! will use, drawn before that file exists; `--resume` removes that one file if it is a
//! regular file that begins as a checkpoint does (`SIEVECKP`, or the start of it: a file a
//! user put under that name since holds something else and stays), and the resumed run
//! writes under it again. That name is derived from a
//! CRC-64 of the checkpoint's other entries, so the same state always encodes to the same
//! bytes (a random name was once the only difference between two checkpoints of one state);
//! it is random when the derived name is the current write's or already exists, and a write
//! never replaces a file (`create_new`; a random name if the recorded one is taken). The
//! temporary file of a run's first checkpoint is recorded nowhere: a kill during that write
//! leaves it, and the clean-up keeps the directory with a note. (The kept snapshots in
//! `fields/`, a directory sieve creates, are still recognised by their names.)

use crate::data::{output_times, FlowSummary, Frozen, LoopStats, SeriesRow};
use crate::error::{Error, Result};
use crate::scene::{Fields, Scene};
use sieve_core::flow::coupled::CoupledTotals;
use sieve_core::flow::{Flow, FlowCounters};
use sieve_core::sum::FixedSum;
use sieve_core::{Real, Segregation};
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// First bytes of a checkpoint file.
pub const MAGIC: &[u8; 8] = b"SIEVECKP";
/// Version of the layout.
pub const FORMAT: u32 = 1;
/// Largest checkpoint file read (16 GiB, every reader's bound: a 3D flow at the compiled
/// capacity is ~0.5 GB).
pub const MAX_FILE: u64 = crate::read::MAX_FILE;
/// Most entries in a file.
pub const MAX_ENTRIES: u32 = 100_000;
/// File name of the state inside the checkpoint directory.
pub const STATE_FILE: &str = "checkpoint.bin";

const CRC: crc::Crc<u64> = crc::Crc::<u64>::new(&crc::CRC_64_XZ);

/// One stored value.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// An unsigned integer.
    U64(u64),
    /// A float (stored as its bits).
    F64(f64),
    /// Floats (stored as bits).
    F64s(Vec<f64>),
    /// Unsigned integers.
    U64s(Vec<u64>),
    /// UTF-8 text.
    Text(String),
}

/// The named values of a checkpoint, in name order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Entries(pub BTreeMap<String, Value>);

impl Entries {
    /// Stores `v` under `name`.
    pub fn put(&mut self, name: impl Into<String>, v: Value) {
        self.0.insert(name.into(), v);
    }

    fn missing(name: &str, what: &str) -> Error {
        Error::Input(format!("entry `{name}` is missing or is not {what}"))
    }

    /// An integer entry.
    pub fn u64(&self, name: &str) -> Result<u64> {
        match self.0.get(name) {
            Some(Value::U64(x)) => Ok(*x),
            _ => Err(Self::missing(name, "an integer")),
        }
    }

    /// A float entry.
    pub fn f64(&self, name: &str) -> Result<f64> {
        match self.0.get(name) {
            Some(Value::F64(x)) => Ok(*x),
            _ => Err(Self::missing(name, "a number")),
        }
    }

    /// A float array of exactly `len` values.
    pub fn f64s(&self, name: &str, len: usize) -> Result<&[f64]> {
        match self.0.get(name) {
            Some(Value::F64s(v)) if v.len() == len => Ok(v),
            _ => Err(Self::missing(name, &format!("{len} numbers"))),
        }
    }

    /// A float array of any length.
    pub fn f64s_any(&self, name: &str) -> Result<&[f64]> {
        match self.0.get(name) {
            Some(Value::F64s(v)) => Ok(v),
            _ => Err(Self::missing(name, "a list of numbers")),
        }
    }

    /// An integer array of exactly `len` values.
    pub fn u64s(&self, name: &str, len: usize) -> Result<&[u64]> {
        match self.0.get(name) {
            Some(Value::U64s(v)) if v.len() == len => Ok(v),
            _ => Err(Self::missing(name, &format!("{len} integers"))),
        }
    }

    /// A text entry.
    pub fn text(&self, name: &str) -> Result<&str> {
        match self.0.get(name) {
            Some(Value::Text(t)) => Ok(t),
            _ => Err(Self::missing(name, "text")),
        }
    }
}

/// Encodes entries (module docs).
pub fn encode(e: &Entries) -> Vec<u8> {
    let mut out = Vec::new();
    encode_to(e, &mut |b| out.extend_from_slice(b));
    let crc = CRC.checksum(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    out
}

/// CRC-64 of [`encode`]'s bytes before the checksum (the one it appends), computed without
/// building them.
fn entries_sum(e: &Entries) -> u64 {
    let mut d = CRC.digest();
    encode_to(e, &mut |b| d.update(b));
    d.finalize()
}

/// Hands the bytes of [`encode`] before the checksum to `out`, in order.
fn encode_to(e: &Entries, out: &mut impl FnMut(&[u8])) {
    out(MAGIC);
    out(&FORMAT.to_le_bytes());
    out(&(e.0.len() as u32).to_le_bytes());
    for (name, v) in &e.0 {
        let name = &name.as_bytes()[..name.len().min(255)];
        out(&[name.len() as u8]);
        out(name);
        let (tag, count) = match v {
            Value::U64(_) => (1u8, 1usize),
            Value::F64(_) => (2, 1),
            Value::F64s(x) => (3, x.len()),
            Value::U64s(x) => (4, x.len()),
            Value::Text(t) => (5, t.len()),
        };
        out(&[tag]);
        out(&(count as u64).to_le_bytes());
        match v {
            Value::U64(x) => out(&x.to_le_bytes()),
            Value::F64(x) => out(&x.to_bits().to_le_bytes()),
            Value::F64s(x) => x.iter().for_each(|x| out(&x.to_bits().to_le_bytes())),
            Value::U64s(x) => x.iter().for_each(|x| out(&x.to_le_bytes())),
            Value::Text(t) => out(t.as_bytes()),
        }
    }
}

/// A cursor over the bytes of a checkpoint that never reads past the end.
struct Cursor<'a> {
    b: &'a [u8],
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], String> {
        if n > self.b.len() {
            return Err(format!(
                "truncated at {what} ({n} bytes needed, {} left)",
                self.b.len()
            ));
        }
        let (head, tail) = self.b.split_at(n);
        self.b = tail;
        Ok(head)
    }
    fn u8(&mut self, what: &str) -> Result<u8, String> {
        Ok(self.take(1, what)?[0])
    }
    fn u32(&mut self, what: &str) -> Result<u32, String> {
        let b = self.take(4, what)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn u64(&mut self, what: &str) -> Result<u64, String> {
        let b = self.take(8, what)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(u64::from_le_bytes(a))
    }
    /// `count` items of `size` bytes, checked against what is left before anything is
    /// allocated.
    fn items(&mut self, count: u64, size: usize, what: &str) -> Result<&'a [u8], String> {
        let n = usize::try_from(count)
            .ok()
            .and_then(|c| c.checked_mul(size))
            .filter(|&n| n <= self.b.len())
            .ok_or_else(|| {
                format!(
                    "{what}: {count} items do not fit in the {} bytes left",
                    self.b.len()
                )
            })?;
        self.take(n, what)
    }
}

/// Decodes a checkpoint; the error says what is wrong in a few words.
pub fn decode(bytes: &[u8]) -> Result<Entries, String> {
    if bytes.len() < MAGIC.len() + 16 {
        return Err(format!("too short ({} bytes)", bytes.len()));
    }
    if &bytes[..MAGIC.len()] != MAGIC {
        return Err("not a sieve checkpoint (wrong magic bytes)".into());
    }
    let (body, tail) = bytes.split_at(bytes.len() - 8);
    let mut crc = [0u8; 8];
    crc.copy_from_slice(tail);
    if CRC.checksum(body) != u64::from_le_bytes(crc) {
        return Err("checksum mismatch (the file is damaged)".into());
    }
    let mut c = Cursor {
        b: &body[MAGIC.len()..],
    };
    let format = c.u32("format")?;
    if format != FORMAT {
        return Err(format!(
            "format version {format}, this sieve reads {FORMAT}"
        ));
    }
    let count = c.u32("entry count")?;
    if count > MAX_ENTRIES {
        return Err(format!("{count} entries (at most {MAX_ENTRIES})"));
    }
    let mut e = Entries::default();
    for _ in 0..count {
        let len = c.u8("name length")? as usize;
        let name = std::str::from_utf8(c.take(len, "name")?)
            .map_err(|_| "an entry name is not UTF-8".to_string())?
            .to_string();
        let tag = c.u8("type")?;
        let n = c.u64("count")?;
        let scalar = |n: u64| {
            if n == 1 {
                Ok(())
            } else {
                Err(format!("entry `{name}`: a scalar with count {n}"))
            }
        };
        let words = |b: &[u8]| -> Vec<u64> {
            b.chunks_exact(8)
                .map(|w| {
                    let mut a = [0u8; 8];
                    a.copy_from_slice(w);
                    u64::from_le_bytes(a)
                })
                .collect()
        };
        let v = match tag {
            1 => {
                scalar(n)?;
                Value::U64(c.u64(&name)?)
            }
            2 => {
                scalar(n)?;
                Value::F64(f64::from_bits(c.u64(&name)?))
            }
            3 => Value::F64s(
                words(c.items(n, 8, &name)?)
                    .into_iter()
                    .map(f64::from_bits)
                    .collect(),
            ),
            4 => Value::U64s(words(c.items(n, 8, &name)?)),
            5 => Value::Text(
                std::str::from_utf8(c.items(n, 1, &name)?)
                    .map_err(|_| format!("entry `{name}` is not UTF-8"))?
                    .to_string(),
            ),
            t => return Err(format!("entry `{name}` has unknown type {t}")),
        };
        // Names strictly ascending (as written): one canonical encoding, no duplicates.
        if e.0.last_key_value().is_some_and(|(last, _)| *last >= name) {
            return Err(format!("entry `{name}` is out of order or repeated"));
        }
        e.0.insert(name, v);
    }
    if !c.b.is_empty() {
        return Err(format!("{} stray bytes after the last entry", c.b.len()));
    }
    Ok(e)
}

/// The checkpoint directory of target `dir`: `.NAME.checkpoint` beside it.
pub fn dir_of(target: &Path) -> PathBuf {
    let name = target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "run".into());
    let parent = match target.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    parent.join(format!(".{name}.checkpoint"))
}

/// Name of the VTK snapshot of output `k` (as `sieve run` writes it).
pub fn snapshot_name(k: usize) -> String {
    format!("state_{k:04}.vti")
}

/// Name of the parallel VTK snapshot of output `k` (as `sieve run` writes it under mpirun).
pub fn pvti_name(k: usize) -> String {
    format!("state_{k:04}.pvti")
}

/// Name of rank `rank`'s piece of the parallel snapshot of output `k` (beside the `.pvti`).
pub fn piece_name(k: usize, rank: usize) -> String {
    format!("state_{k:04}_{rank}.vti")
}

/// The files of output `k`: its `.vti`, or (with `pieces` > 0) its `.pvti` and the pieces.
fn snapshot_files(k: usize, pieces: usize) -> Vec<String> {
    if pieces == 0 {
        return vec![snapshot_name(k)];
    }
    std::iter::once(pvti_name(k))
        .chain((0..pieces).map(|r| piece_name(k, r)))
        .collect()
}

/// The sieve build: the package version and a CRC-64 of the running executable, so that a
/// checkpoint is never continued by a build whose numerics may differ.
pub fn build_id() -> String {
    let exe = std::env::current_exe()
        .ok()
        .and_then(|p| std::fs::read(p).ok())
        .map_or(0, |b| CRC.checksum(&b));
    format!("sieve {} build {exe:016x}", env!("CARGO_PKG_VERSION"))
}

/// Fingerprint of a validated scene and its initial fields (the checkpoint interval, which
/// does not change the result, left out).
pub fn fingerprint(scene: &Scene, fields: &Fields) -> u64 {
    let mut s = scene.clone();
    s.checkpoint_interval = None;
    let mut d = CRC.digest();
    d.update(format!("{s:?}").as_bytes());
    for v in [&fields.c, &fields.t, &fields.phi, &fields.inflow]
        .into_iter()
        .chain(fields.u.iter())
    {
        d.update(&(v.len() as u64).to_le_bytes());
        for x in v {
            d.update(&x.to_bits().to_le_bytes());
        }
    }
    d.finalize()
}

/// Where a run's scene came from: what `--resume` needs to rebuild it.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneSource {
    /// Label of the scene in messages (file path or `scenes/<name>.toml`).
    pub label: String,
    /// The TOML text as the run read it.
    pub text: String,
    /// The `--set` overrides, in order (options such as `--grid` as their `key=value`).
    pub sets: Vec<String>,
}

impl SceneSource {
    /// Resolves the scene as `scene::load` does, from the stored text.
    pub fn load(&self) -> Result<(Scene, Fields)> {
        crate::scene::resolve(&self.label, &self.text, &self.sets)
    }
}

/// The (length, CRC) of an output whose snapshot was thinned away (`[output] vtk_every`).
const NOT_WRITTEN: (u64, u64) = (u64::MAX, u64::MAX);

/// A kept snapshot: the (length, CRC-64) of its file and, for a `.pvti` written under
/// mpirun, of its pieces in rank order (none for a `.vti`).
#[derive(Debug, Clone, PartialEq)]
struct Kept {
    file: (u64, u64),
    pieces: Vec<(u64, u64)>,
}

impl Kept {
    const THINNED: Kept = Kept {
        file: NOT_WRITTEN,
        pieces: Vec::new(),
    };
}

/// A checkpoint read back from disk, verified against its kept files.
#[derive(Debug, Clone)]
pub struct Stored {
    /// The checkpoint directory.
    pub dir: PathBuf,
    /// Its entries.
    pub entries: Entries,
}

/// One line about a checkpoint that cannot be used (exit 2).
fn refuse(dir: &Path, why: impl std::fmt::Display) -> Error {
    Error::Input(format!(
        "{}: cannot resume: {why}",
        dir.join(STATE_FILE).display()
    ))
}

impl Stored {
    /// Reads and checks the checkpoint of target `target` (exit 2 with one line if there is
    /// none or it is damaged).
    pub fn open(target: &Path) -> Result<Self> {
        // `dir_of` needs the run's own name: without one (`/`, `..`) it would look in `.`
        if target.file_name().is_none() {
            return Err(Error::Input(format!(
                "{}: --resume takes the --out DIR of the checkpointed run, a path that ends in its name (not `/`, `.` or `..`), e.g. --resume runs/NAME",
                target.display()
            )));
        }
        let dir = dir_of(target);
        let path = dir.join(STATE_FILE);
        if let Err(e) = std::fs::metadata(&path) {
            return Err(Error::Input(format!(
                "{}: --resume: no checkpoint at {} ({e}): resume needs a run started with --checkpoint-interval (or run.checkpoint_interval) that has written one; start it afresh with --out",
                target.display(),
                path.display()
            )));
        }
        // Bounded, regular files only: a FIFO there once blocked the open for ever (no signal
        // handler runs meanwhile), a file larger than memory aborted the allocation.
        let bytes = crate::read::bytes(&path, MAX_FILE)?;
        let entries = decode(&bytes).map_err(|why| refuse(&dir, why))?;
        Ok(Self { dir, entries })
    }

    /// The scene the checkpointed run was started with.
    pub fn source(&self) -> Result<SceneSource> {
        let e = &self.entries;
        let n = e.u64("scene.sets").map_err(|w| refuse(&self.dir, w))?;
        let sets = (0..n.min(u64::from(MAX_ENTRIES)))
            .map(|i| e.text(&format!("scene.set.{i}")).map(str::to_string))
            .collect::<Result<Vec<_>>>()
            .map_err(|w| refuse(&self.dir, w))?;
        Ok(SceneSource {
            label: e
                .text("scene.label")
                .map_err(|w| refuse(&self.dir, w))?
                .into(),
            text: e
                .text("scene.text")
                .map_err(|w| refuse(&self.dir, w))?
                .into(),
            sets,
        })
    }

    /// A checkpoint whose contents do not fit the scene (exit 2, one line).
    pub fn incompatible(&self, why: Error) -> Error {
        refuse(&self.dir, why)
    }

    /// Refuses (exit 2) a checkpoint of another build or of another scene.
    pub fn check_identity(&self, scene: &Scene, fields: &Fields) -> Result<()> {
        let e = &self.entries;
        let build = e.text("build").map_err(|w| refuse(&self.dir, w))?;
        let ours = build_id();
        if build != ours {
            return Err(refuse(
                &self.dir,
                format!("it was written by {build}, this is {ours}: finish it with that build, or start afresh with --out"),
            ));
        }
        let fp = e
            .u64("scene.fingerprint")
            .map_err(|w| refuse(&self.dir, w))?;
        if fp != fingerprint(scene, fields) {
            return Err(refuse(
                &self.dir,
                format!("the scene differs from the one the run was started with ({}{}): give --resume alone, or start afresh with --out", self.source()?.label, self.source()?.sets.iter().map(|s| format!(" --set {s}")).collect::<String>()),
            ));
        }
        Ok(())
    }
}

/// The temporary file of [`write_durably`] in the checkpoint directory: this prefix,
/// [`PART_RANDOM`] ASCII letters or digits (tempfile's random part), this suffix.
const PART_PREFIX: &str = ".checkpoint.";
/// See [`PART_PREFIX`].
const PART_SUFFIX: &str = ".part";
/// See [`PART_PREFIX`].
const PART_RANDOM: usize = 6;

/// True for exactly the names [`write_durably`] gives its temporary files (a recorded name
/// is checked with it before it is used: a damaged checkpoint cannot name `../x`).
fn is_part_name(name: &str) -> bool {
    name.strip_prefix(PART_PREFIX)
        .and_then(|r| r.strip_suffix(PART_SUFFIX))
        .is_some_and(|r| r.len() == PART_RANDOM && r.bytes().all(|b| b.is_ascii_alphanumeric()))
}

/// A fresh random name of [`is_part_name`]'s pattern (std's randomly keyed hasher and the
/// clock as the randomness: the name is recorded, not guessed, so it need not be secret).
fn new_part_name() -> String {
    use std::hash::{BuildHasher, Hasher};
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u128(
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos()),
    );
    part_name(h.finish())
}

/// The name of [`is_part_name`]'s pattern whose letters and digits are the low base-62
/// digits of `x`.
fn part_name(mut x: u64) -> String {
    const DIGITS: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789";
    let mut name = String::from(PART_PREFIX);
    for _ in 0..PART_RANDOM {
        name.push(char::from(DIGITS[(x % DIGITS.len() as u64) as usize]));
        x /= DIGITS.len() as u64;
    }
    name.push_str(PART_SUFFIX);
    name
}

/// Removes the temporary file `name` from the checkpoint directory `dir` if it is a regular
/// file (a symbolic link is not followed) that begins as a checkpoint does: the one a
/// checkpoint recorded for the write after it, left by a SIGKILL during that write. A file
/// that took the recorded name after it was recorded and holds anything else is a user's
/// and stays. Best effort (such a file is never read as a checkpoint: the checkpoint is
/// `checkpoint.bin` only). True if it was removed.
fn remove_part(dir: &Path, name: &str) -> bool {
    let path = dir.join(name);
    is_part_name(name)
        && std::fs::symlink_metadata(&path).is_ok_and(|m| m.is_file())
        && begins_as_a_checkpoint(&path)
        && std::fs::remove_file(&path).is_ok()
}

/// True if the file's first bytes are [`MAGIC`], or the start of it (a write killed before
/// its first eight bytes reached the disk: empty or shorter).
fn begins_as_a_checkpoint(path: &Path) -> bool {
    crate::read::head(path, MAGIC.len() as u64).is_ok_and(|head| MAGIC.starts_with(&head))
}

/// True for the names of the snapshots a checkpoint keeps in its `fields/` ([`snapshot_name`],
/// [`pvti_name`], [`piece_name`]): `state_` digits (`_` digits) `.vti` or `.pvti`.
fn is_snapshot_name(name: &str) -> bool {
    let Some(rest) = name.strip_prefix("state_") else {
        return false;
    };
    let Some(stem) = rest
        .strip_suffix(".pvti")
        .or_else(|| rest.strip_suffix(".vti"))
    else {
        return false;
    };
    let digits = |t: &str| !t.is_empty() && t.bytes().all(|b| b.is_ascii_digit());
    match stem.split_once('_') {
        Some((k, r)) => digits(k) && digits(r),
        None => digits(stem),
    }
}

/// Removes a checkpoint directory's own files (the state file, the temporary file `part` its
/// checkpoint recorded, the kept snapshots in `fields/`) and then the directories if they
/// are empty. Anything else (a file sieve did not write) is left where it is, with its
/// directory; the returned message says so. Never follows a symbolic link.
fn remove_checkpoint_dir(dir: &Path, part: Option<&str>) -> Result<Option<String>> {
    let fields = dir.join("fields");
    if let Ok(entries) = std::fs::read_dir(&fields) {
        for entry in entries.flatten() {
            let name = entry.file_name();
            let ours = name.to_str().is_some_and(is_snapshot_name)
                && entry.file_type().is_ok_and(|t| t.is_file());
            if ours {
                let path = entry.path();
                std::fs::remove_file(&path).map_err(|e| Error::io(&path, e))?;
            }
        }
        let _ = std::fs::remove_dir(&fields);
    }
    let state = dir.join(STATE_FILE);
    if std::fs::symlink_metadata(&state).is_ok_and(|m| m.is_file()) {
        std::fs::remove_file(&state).map_err(|e| Error::io(&state, e))?;
    }
    if let Some(name) = part {
        remove_part(dir, name);
    }
    if !dir.exists() || std::fs::remove_dir(dir).is_ok() {
        return Ok(None);
    }
    Ok(Some(format!(
        "note: {} kept: it holds files sieve did not write",
        dir.display()
    )))
}

/// A new temporary file in `dir` with a random name of [`is_part_name`]'s pattern (when the
/// recorded name is taken).
fn part_file(dir: &Path) -> std::io::Result<tempfile::NamedTempFile> {
    tempfile::Builder::new()
        .prefix(PART_PREFIX)
        .rand_bytes(PART_RANDOM)
        .suffix(PART_SUFFIX)
        .tempfile_in(dir)
}

/// Writes `bytes` to `path` atomically and durably: temporary file `part` beside it (the name
/// the checkpoint on disk recorded; a random one if that is taken), fsync, rename, fsync of
/// the directory.
fn write_durably(path: &Path, bytes: &[u8], part: &str) -> Result<()> {
    let dir = path.parent().unwrap_or(Path::new("."));
    let named = dir.join(part);
    let opened = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&named);
    match opened {
        Ok(mut file) => {
            let done = file
                .write_all(bytes)
                .and_then(|()| file.sync_all())
                .and_then(|()| std::fs::rename(&named, path));
            if let Err(e) = done {
                let _ = std::fs::remove_file(&named); // created above: sieve's own
                return Err(Error::io(path, e));
            }
            sync_dir(dir);
            return Ok(());
        }
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
        Err(e) => return Err(Error::io(&named, e)),
    }
    let mut tmp = part_file(dir).map_err(|e| Error::io(dir, e))?;
    tmp.write_all(bytes).map_err(|e| Error::io(tmp.path(), e))?;
    tmp.as_file().sync_all().map_err(|e| Error::io(path, e))?;
    tmp.persist(path).map_err(|e| Error::io(path, e.error))?;
    sync_dir(dir);
    Ok(())
}

/// fsync of a directory (its entries); best effort (not every file system supports it).
fn sync_dir(dir: &Path) {
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
}

/// Links (or, across file systems, copies) `src` to `dst`, replacing `dst`.
fn link_or_copy(src: &Path, dst: &Path) -> Result<()> {
    let _ = std::fs::remove_file(dst);
    if std::fs::hard_link(src, dst).is_err() {
        std::fs::copy(src, dst).map_err(|e| Error::io(dst, e))?;
    }
    Ok(())
}

/// CRC-64 and length of a file.
fn file_sum(path: &Path) -> Result<(u64, u64)> {
    let b = crate::read::bytes(path, MAX_FILE)?;
    Ok((b.len() as u64, CRC.checksum(&b)))
}

/// A column of discharge.csv: its name and how to read it from a row.
type DischargeColumn = (&'static str, fn(&crate::silo::DischargeRow) -> f64);

/// The loop's progress at a checkpoint (everything but the solvers).
#[derive(Debug, Clone, Default)]
pub struct Progress {
    /// Index of the next output to write (the outputs before it are done and kept).
    pub next: usize,
    /// The loop's statistics so far (series rows, steps, stepping time, the stable step).
    pub stats: LoopStats,
    /// Wall time of the flow so far (coupled).
    pub flow_seconds: f64,
    /// Discharge rows so far (scenes with outlets).
    pub discharge: Option<Vec<crate::silo::DischargeRow>>,
}

/// The checkpoints of one `sieve run`: when to write, where, and the checkpoint it resumes.
#[derive(Debug)]
pub struct Session {
    dir: PathBuf,
    interval: Option<Duration>,
    last: Instant,
    build: String,
    source: SceneSource,
    fingerprint: u64,
    fields_src: PathBuf,
    /// The snapshots already kept in `dir/fields`.
    kept: Vec<Kept>,
    resumed: Option<Entries>,
    written: u64,
    /// Snapshot writes in flight ([`crate::output::writer`]): a checkpoint keeps copies of
    /// the snapshots written before it, so it waits for them first.
    writes: Option<std::sync::Arc<crate::output::writer::Pending>>,
    /// Name of the temporary file of the next write, and whether the checkpoint on disk
    /// records it (only then may a clean-up remove a file of that name).
    part: (String, bool),
}

impl Session {
    /// A session for a run into `target` whose snapshots are written to `fields_src`.
    /// Without an interval it never writes. A fresh run (`resume = None`) refuses a target
    /// whose checkpoint directory holds a checkpoint, and removes one that holds none (a run
    /// killed before its first checkpoint): sieve's own files only.
    pub fn new(
        target: &Path,
        scene: &Scene,
        fields: &Fields,
        source: SceneSource,
        fields_src: PathBuf,
        resume: Option<Stored>,
    ) -> Result<Self> {
        let dir = dir_of(target);
        let interval = scene.checkpoint_interval.map(Duration::from_secs_f64);
        let mut s = Self {
            interval,
            last: Instant::now(),
            build: if interval.is_some() || resume.is_some() {
                build_id()
            } else {
                String::new()
            },
            source,
            fingerprint: fingerprint(scene, fields),
            fields_src,
            kept: Vec::new(),
            resumed: None,
            written: 0,
            writes: None,
            part: (new_part_name(), false),
            dir,
        };
        match resume {
            Some(stored) => {
                stored.check_identity(scene, fields)?;
                // a run killed while it wrote the checkpoint after this one left the
                // temporary file this one recorded (one writer: a Session exists on rank 0
                // only under mpirun); the next write uses that name again
                if let Some(name) = stored
                    .entries
                    .text("part.next")
                    .ok()
                    .filter(|n| is_part_name(n))
                {
                    remove_part(&s.dir, name);
                    s.part = (name.to_string(), true);
                }
                s.adopt(stored.entries)?;
            }
            None => {
                if s.dir.join(STATE_FILE).exists() {
                    return Err(Error::Input(format!(
                        "{}: holds a checkpoint of an unfinished run into {}: continue it with `sieve run --resume {}`, or delete that directory to start afresh",
                        s.dir.display(),
                        target.display(),
                        target.display()
                    )));
                }
                if let Some(note) = remove_checkpoint_dir(&s.dir, None)? {
                    eprintln!("{note}");
                }
            }
        }
        Ok(s)
    }

    /// Checks the kept snapshots of a resumed checkpoint and puts them into the new staging
    /// directory (the outputs written before the interruption, byte for byte).
    fn adopt(&mut self, e: Entries) -> Result<()> {
        let bad = |w: Error| refuse(&self.dir, w);
        let n = e.u64("progress.next").map_err(bad)? as usize;
        let lens = e.u64s("kept.len", n).map_err(bad)?;
        let sums = e.u64s("kept.crc", n).map_err(bad)?;
        // Pieces per output (0: a `.vti`; P: a `.pvti` and P pieces, written under mpirun);
        // absent when every kept output is a `.vti`.
        let zeros = vec![0; n];
        let pieces = match e.0.contains_key("kept.pieces") {
            true => e.u64s("kept.pieces", n).map_err(bad)?,
            false => &zeros[..],
        };
        let total = pieces
            .iter()
            .try_fold(0u64, |a, &p| a.checked_add(p))
            .filter(|&t| t <= u64::from(MAX_ENTRIES))
            .ok_or_else(|| refuse(&self.dir, "kept.pieces: too many pieces"))?
            as usize;
        let (piece_lens, piece_sums) = match total {
            0 => (&[][..], &[][..]),
            _ => (
                e.u64s("kept.piece.len", total).map_err(bad)?,
                e.u64s("kept.piece.crc", total).map_err(bad)?,
            ),
        };
        std::fs::create_dir_all(&self.fields_src).map_err(|e| Error::io(&self.fields_src, e))?;
        let mut at = 0;
        for k in 0..n {
            let p = pieces[k] as usize;
            if (lens[k], sums[k]) == NOT_WRITTEN && p == 0 {
                self.kept.push(Kept::THINNED);
                continue;
            }
            let want = std::iter::once((lens[k], sums[k])).chain(
                piece_lens[at..at + p]
                    .iter()
                    .copied()
                    .zip(piece_sums[at..at + p].iter().copied()),
            );
            at += p;
            let mut got = Vec::with_capacity(p + 1);
            for (name, want) in snapshot_files(k, p).into_iter().zip(want) {
                let src = self.dir.join("fields").join(&name);
                let sum = file_sum(&src).map_err(|_| {
                    refuse(
                        &self.dir,
                        format!("the kept snapshot {} is missing", src.display()),
                    )
                })?;
                if sum != want {
                    return Err(refuse(
                        &self.dir,
                        format!("the kept snapshot {} is damaged", src.display()),
                    ));
                }
                link_or_copy(&src, &self.fields_src.join(&name))?;
                got.push(sum);
            }
            self.kept.push(Kept {
                file: got[0],
                pieces: got[1..].to_vec(),
            });
        }
        self.resumed = Some(e);
        Ok(())
    }

    /// The checkpoint being resumed, if any.
    pub fn resumed(&self) -> Option<&Entries> {
        self.resumed.as_ref()
    }

    /// A resumed checkpoint whose contents do not fit the scene (exit 2, one line).
    pub fn incompatible(&self, why: Error) -> Error {
        refuse(&self.dir, why)
    }

    /// The file name of kept output `k` in the VTK collection (`state_KKKK.vti`, or
    /// `state_KKKK.pvti` if it was written under mpirun); `None` if it is not kept (thinned
    /// away, or not yet written).
    pub fn kept_name(&self, k: usize) -> Option<String> {
        match self.kept.get(k)? {
            Kept { file, pieces } if pieces.is_empty() && *file == NOT_WRITTEN => None,
            Kept { pieces, .. } if pieces.is_empty() => Some(snapshot_name(k)),
            _ => Some(pvti_name(k)),
        }
    }

    /// Makes every checkpoint wait for the snapshot writes in flight (`sieve run` writes its
    /// snapshots on a writer thread).
    pub fn after_writes(&mut self, writes: std::sync::Arc<crate::output::writer::Pending>) {
        self.writes = Some(writes);
    }

    /// Checkpoints written by this session.
    pub fn written(&self) -> u64 {
        self.written
    }

    /// True when a checkpoint is due (the interval has passed since the last one or since the
    /// start).
    pub fn due(&self) -> bool {
        self.interval.is_some_and(|i| self.last.elapsed() >= i)
    }

    /// The progress of the resumed loop (None for a fresh run), with the output times checked
    /// against the scene.
    pub fn progress(&self, scene: &Scene) -> Result<Option<Progress>> {
        let Some(e) = &self.resumed else {
            return Ok(None);
        };
        let bad = |w: Error| refuse(&self.dir, w);
        let next = e.u64("progress.next").map_err(bad)? as usize;
        let times = output_times(scene.t_end, scene.output_interval);
        if next > times.len() {
            return Err(refuse(
                &self.dir,
                format!("progress.next = {next} is past the last output"),
            ));
        }
        let col = |c: &str| e.f64s(&format!("series.{c}"), next).map_err(bad);
        let (t, psi, mass, over, under) = (
            col("t")?,
            col("psi")?,
            col("mass")?,
            col("overshoot_max")?,
            col("undershoot_max")?,
        );
        let series = (0..next)
            .map(|k| SeriesRow {
                t: t[k],
                psi: psi[k],
                mass: mass[k],
                overshoot_max: over[k],
                undershoot_max: under[k],
            })
            .collect();
        let stepping = e.f64("progress.stepping_seconds").map_err(bad)?;
        // Optional entries: a crossing already found, the time steps taken so far.
        let segregation_time = e.f64("progress.segregation_time").ok();
        let dt_taken = e
            .f64s("progress.dt_taken", 3)
            .ok()
            .map(|d| [d[0], d[1], d[2]]);
        let stats = LoopStats {
            steps: e.u64("progress.steps").map_err(bad)?,
            stepping: Duration::try_from_secs_f64(stepping).unwrap_or_default(),
            series,
            segregation_time,
            dt: e.f64("progress.dt").map_err(bad)?,
            dt_taken,
            ..LoopStats::default()
        };
        let discharge = match e.u64("discharge.rows") {
            Ok(rows) => {
                let rows = rows as usize;
                let c = |n: &str| e.f64s(&format!("discharge.{n}"), rows).map_err(bad);
                let cols = [
                    c("t")?,
                    c("rate")?,
                    c("rate_small")?,
                    c("fines_fraction")?,
                    c("mass")?,
                    c("mass_small")?,
                    c("out")?,
                    c("out_small")?,
                    c("surface")?,
                    c("stagnant")?,
                    c("band_phihat")?,
                    c("core_phihat")?,
                ];
                Some(
                    (0..rows)
                        .map(|k| crate::silo::DischargeRow {
                            t: cols[0][k],
                            rate: cols[1][k],
                            rate_small: cols[2][k],
                            fines_fraction: cols[3][k],
                            mass: cols[4][k],
                            mass_small: cols[5][k],
                            out: cols[6][k],
                            out_small: cols[7][k],
                            surface: cols[8][k],
                            stagnant: cols[9][k],
                            band_phihat: cols[10][k],
                            core_phihat: cols[11][k],
                        })
                        .collect(),
                )
            }
            Err(_) => None,
        };
        Ok(Some(Progress {
            next,
            stats,
            flow_seconds: e.f64("progress.flow_seconds").map_err(bad)?,
            discharge,
        }))
    }

    /// Writes a checkpoint: the kept snapshots first (linked and fsynced), then the state
    /// file atomically. `solvers` adds the solver state ([`put_segregation`], [`put_flow`],
    /// ...).
    pub fn save(&mut self, progress: &Progress, solvers: impl FnOnce(&mut Entries)) -> Result<()> {
        if let Some(w) = &self.writes {
            w.wait()?;
        }
        let fields = self.dir.join("fields");
        std::fs::create_dir_all(&fields).map_err(|e| Error::io(&fields, e))?;
        for k in self.kept.len()..progress.next {
            let names = if self.fields_src.join(snapshot_name(k)).exists() {
                snapshot_files(k, 0)
            } else if self.fields_src.join(pvti_name(k)).exists() {
                // under mpirun: the .pvti and every rank's piece (all written before the
                // output command returned on rank 0)
                let pieces = (0..)
                    .take_while(|&r| self.fields_src.join(piece_name(k, r)).exists())
                    .count();
                if pieces == 0 {
                    return Err(Error::failure(format!(
                        "{}: no pieces beside it",
                        self.fields_src.join(pvti_name(k)).display()
                    )));
                }
                snapshot_files(k, pieces)
            } else {
                // thinned away ([output] vtk_every): nothing to keep
                self.kept.push(Kept::THINNED);
                continue;
            };
            let mut sums = Vec::with_capacity(names.len());
            for name in &names {
                let dst = fields.join(name);
                link_or_copy(&self.fields_src.join(name), &dst)?;
                if let Ok(f) = std::fs::File::open(&dst) {
                    let _ = f.sync_all();
                }
                sums.push(file_sum(&dst)?);
            }
            self.kept.push(Kept {
                file: sums[0],
                pieces: sums[1..].to_vec(),
            });
        }
        sync_dir(&fields);
        let mut e = Entries::default();
        e.put("build", Value::Text(self.build.clone()));
        e.put("scene.label", Value::Text(self.source.label.clone()));
        e.put("scene.text", Value::Text(self.source.text.clone()));
        e.put("scene.sets", Value::U64(self.source.sets.len() as u64));
        for (i, s) in self.source.sets.iter().enumerate() {
            e.put(format!("scene.set.{i}"), Value::Text(s.clone()));
        }
        e.put("scene.fingerprint", Value::U64(self.fingerprint));
        let next = progress.next;
        e.put("progress.next", Value::U64(next as u64));
        let kept = &self.kept[..next];
        e.put(
            "kept.len",
            Value::U64s(kept.iter().map(|k| k.file.0).collect()),
        );
        e.put(
            "kept.crc",
            Value::U64s(kept.iter().map(|k| k.file.1).collect()),
        );
        if kept.iter().any(|k| !k.pieces.is_empty()) {
            // a .pvti and its pieces (under mpirun): a serial run's checkpoint has no such
            // entries
            let pieces = || kept.iter().flat_map(|k| &k.pieces);
            e.put(
                "kept.pieces",
                Value::U64s(kept.iter().map(|k| k.pieces.len() as u64).collect()),
            );
            e.put(
                "kept.piece.len",
                Value::U64s(pieces().map(|p| p.0).collect()),
            );
            e.put(
                "kept.piece.crc",
                Value::U64s(pieces().map(|p| p.1).collect()),
            );
        }
        let st = &progress.stats;
        e.put("progress.steps", Value::U64(st.steps));
        e.put(
            "progress.stepping_seconds",
            Value::F64(st.stepping.as_secs_f64()),
        );
        e.put("progress.dt", Value::F64(st.dt));
        if let Some(t) = st.segregation_time {
            e.put("progress.segregation_time", Value::F64(t));
        }
        if let Some(d) = st.dt_taken {
            e.put("progress.dt_taken", Value::F64s(d.to_vec()));
        }
        e.put("progress.flow_seconds", Value::F64(progress.flow_seconds));
        let col = |f: fn(&SeriesRow) -> f64| Value::F64s(st.series.iter().map(f).collect());
        e.put("series.t", col(|r| r.t));
        e.put("series.psi", col(|r| r.psi));
        e.put("series.mass", col(|r| r.mass));
        e.put("series.overshoot_max", col(|r| r.overshoot_max));
        e.put("series.undershoot_max", col(|r| r.undershoot_max));
        if let Some(rows) = &progress.discharge {
            e.put("discharge.rows", Value::U64(rows.len() as u64));
            let cols: [DischargeColumn; 12] = [
                ("t", |r| r.t),
                ("rate", |r| r.rate),
                ("rate_small", |r| r.rate_small),
                ("fines_fraction", |r| r.fines_fraction),
                ("mass", |r| r.mass),
                ("mass_small", |r| r.mass_small),
                ("out", |r| r.out),
                ("out_small", |r| r.out_small),
                ("surface", |r| r.surface),
                ("stagnant", |r| r.stagnant),
                ("band_phihat", |r| r.band_phihat),
                ("core_phihat", |r| r.core_phihat),
            ];
            for (name, f) in cols {
                e.put(
                    format!("discharge.{name}"),
                    Value::F64s(rows.iter().map(f).collect()),
                );
            }
        }
        solvers(&mut e);
        // the name of the next write's temporary file, recorded before that file exists:
        // drawn from the checkpoint's own entries (the same entries, the same bytes: no
        // randomness in the file), random as before if that name is this write's or is taken
        let free =
            |n: &String| *n != self.part.0 && std::fs::symlink_metadata(self.dir.join(n)).is_err();
        let next = Some(part_name(entries_sum(&e)))
            .filter(free)
            .or_else(|| std::iter::repeat_with(new_part_name).find(free))
            .unwrap_or_default();
        e.put("part.next", Value::Text(next.clone()));
        write_durably(&self.dir.join(STATE_FILE), &encode(&e), &self.part.0)?;
        self.part = (next, true);
        self.written += 1;
        self.last = Instant::now();
        Ok(())
    }

    /// After DIR has been committed: the checkpoint is no longer needed.
    pub fn finish(self) -> Result<()> {
        let part = self.part.1.then_some(self.part.0.as_str());
        if let Some(note) = remove_checkpoint_dir(&self.dir, part)? {
            eprintln!("{note}");
        }
        Ok(())
    }
}

/// Stores the segregation solver's state under `seg.*`.
pub fn put_segregation<R: Real, const D: usize, const N: usize>(
    e: &mut Entries,
    s: &Segregation<R, D, N>,
) {
    s.for_each_state_array(|name, v| {
        e.put(
            format!("seg.{name}"),
            Value::F64s(v.iter().map(|x| x.to_f64()).collect()),
        )
    });
    e.put("seg.time", Value::F64(s.time().to_f64()));
    e.put("seg.steps", Value::U64(s.steps()));
    e.put("seg.flushed", Value::F64(s.flushed_tracked().to_f64()));
    let books = FixedSum::words_of(&s.side_books()).collect();
    e.put("seg.side_books", Value::U64s(books));
    e.put(
        "seg.excess",
        Value::F64s(s.tracked_excess().iter().map(|x| x.to_f64()).collect()),
    );
    e.put(
        "seg.gravity",
        Value::F64s(s.config().gravity.iter().map(|x| x.to_f64()).collect()),
    );
}

/// Restores what [`put_segregation`] stored into a solver set up from the same scene. The
/// gravity is set only if it differs (a rotating frame turns it), which clears `prepared`:
/// the caller prepares after (the coupled driver's `resume` does).
pub fn restore_segregation<R: Real, const D: usize, const N: usize>(
    e: &Entries,
    s: &mut Segregation<R, D, N>,
) -> Result<()> {
    let n = s.len();
    let mut failed = None;
    s.for_each_state_array_mut(|name, v| match e.f64s(&format!("seg.{name}"), n) {
        Ok(x) => v.iter_mut().zip(x).for_each(|(v, &x)| *v = R::from_f64(x)),
        Err(err) => failed = failed.take().or(Some(err)),
    });
    if let Some(err) = failed {
        return Err(err);
    }
    let ex = e.f64s("seg.excess", 2)?;
    s.set_tracked_excess([R::from_f64(ex[0]), R::from_f64(ex[1])]);
    s.set_clock(R::from_f64(e.f64("seg.time")?), e.u64("seg.steps")?);
    s.set_flushed_tracked(R::from_f64(e.f64("seg.flushed")?));
    let w = e.u64s("seg.side_books", 4 * D)?;
    s.set_side_books(FixedSum::sides_from_words(w));
    let g = e.f64s("seg.gravity", D)?;
    let g: [R; D] = core::array::from_fn(|a| R::from_f64(g[a]));
    if g != s.config().gravity {
        s.set_gravity(g);
    }
    Ok(())
}

fn sides<R: Real, const D: usize>(x: &[[R; 2]; D]) -> Value {
    Value::F64s(x.iter().flatten().map(|v| v.to_f64()).collect())
}

fn get_sides<R: Real, const D: usize>(e: &Entries, name: &str) -> Result<[[R; 2]; D]> {
    let v = e.f64s(name, 2 * D)?;
    Ok(core::array::from_fn(|a| {
        [R::from_f64(v[2 * a]), R::from_f64(v[2 * a + 1])]
    }))
}

/// Stores the flow solver's state under `flow.*`.
pub fn put_flow<R: Real, const D: usize, const N: usize>(e: &mut Entries, f: &Flow<R, D, N>) {
    f.for_each_state_array(|name, v| {
        e.put(
            format!("flow.{name}"),
            Value::F64s(v.iter().map(|x| x.to_f64()).collect()),
        )
    });
    let k = f.counters();
    e.put("flow.time", Value::F64(k.time.to_f64()));
    e.put("flow.steps", Value::U64(k.steps));
    e.put("flow.residual", Value::F64(k.residual.to_f64()));
    e.put("flow.cg_iterations", Value::U64(k.cg_iterations));
    e.put(
        "flow.last_cg",
        Value::U64s(k.last_cg.iter().map(|&x| u64::from(x)).collect()),
    );
    e.put("flow.discharged", sides(&k.discharged));
    e.put("flow.discharge_step", sides(&k.discharge_step));
}

/// Restores what [`put_flow`] stored into a flow set up and prepared from the same scene.
pub fn restore_flow<R: Real, const D: usize, const N: usize>(
    e: &Entries,
    f: &mut Flow<R, D, N>,
) -> Result<()> {
    let n = f.len();
    let mut failed = None;
    f.for_each_state_array_mut(|name, v| match e.f64s(&format!("flow.{name}"), n) {
        Ok(x) => v.iter_mut().zip(x).for_each(|(v, &x)| *v = R::from_f64(x)),
        Err(err) => failed = failed.take().or(Some(err)),
    });
    if let Some(err) = failed {
        return Err(err);
    }
    let cg = e.u64s("flow.last_cg", 4)?;
    let last_cg: [u32; 4] = core::array::from_fn(|i| u32::try_from(cg[i]).unwrap_or(u32::MAX));
    f.restore_counters(FlowCounters {
        time: R::from_f64(e.f64("flow.time")?),
        steps: e.u64("flow.steps")?,
        residual: R::from_f64(e.f64("flow.residual")?),
        cg_iterations: e.u64("flow.cg_iterations")?,
        last_cg,
        discharged: get_sides::<R, D>(e, "flow.discharged")?,
        discharge_step: get_sides::<R, D>(e, "flow.discharge_step")?,
    });
    Ok(())
}

/// Stores the coupled driver's totals under `coupled.*`.
pub fn put_totals<R: Real, const D: usize>(e: &mut Entries, t: &CoupledTotals<R, D>) {
    e.put("coupled.out_small", sides(&t.out_small));
    e.put("coupled.out_total", sides(&t.out_total));
    e.put("coupled.guarded", Value::F64(t.guarded.to_f64()));
}

/// The totals [`put_totals`] stored.
pub fn totals<R: Real, const D: usize>(e: &Entries) -> Result<CoupledTotals<R, D>> {
    Ok(CoupledTotals {
        out_small: get_sides::<R, D>(e, "coupled.out_small")?,
        out_total: get_sides::<R, D>(e, "coupled.out_total")?,
        guarded: R::from_f64(e.f64("coupled.guarded")?),
    })
}

/// Stores a frozen flow under `frozen.*`.
pub fn put_frozen(e: &mut Entries, fr: &Frozen) {
    e.put("frozen.c", Value::F64s(fr.c.clone()));
    e.put("frozen.T", Value::F64s(fr.t.clone()));
    e.put("frozen.p", Value::F64s(fr.p.clone()));
    for (a, u) in fr.u.iter().enumerate() {
        e.put(format!("frozen.u{a}"), Value::F64s(u.clone()));
    }
    let s = &fr.summary;
    e.put("frozen.equations", Value::Text(s.equations.clone()));
    e.put("frozen.back_coupling", Value::Text(s.back_coupling.clone()));
    e.put("frozen.pressure", Value::Text(s.pressure.clone()));
    e.put("frozen.stress", Value::Text(s.stress.clone()));
    if let Some(m) = &s.merged_walls {
        e.put("frozen.merged_walls", Value::Text(m.clone()));
    }
    e.put("frozen.fill", Value::Text(s.fill.clone()));
    e.put(
        "frozen.flow_steps_to_steady",
        Value::U64s(s.flow_steps_to_steady.into_iter().collect()),
    );
    e.put("frozen.flow_steps", Value::U64(s.flow_steps));
    e.put("frozen.cg_iterations", Value::U64(s.cg_iterations));
    e.put(
        "frozen.flow_cells",
        Value::U64s(s.flow_cells.iter().map(|&c| c as u64).collect()),
    );
    e.put(
        "frozen.numbers",
        Value::F64s(vec![
            s.flow_time,
            s.flow_seconds,
            s.max_packing,
            s.t_min,
            s.t_max,
            s.max_speed,
            s.kinetic_energy,
            s.residual,
            s.steady_tolerance,
            s.clipped_mass,
        ]),
    );
}

/// The frozen flow [`put_frozen`] stored, for a scene of `n` cells in `dim` dimensions.
pub fn frozen(e: &Entries, n: usize, dim: usize) -> Result<Frozen> {
    let v = |name: &str| e.f64s(name, n).map(<[f64]>::to_vec);
    let x = e.f64s("frozen.numbers", 10)?;
    let steady = match e.0.get("frozen.flow_steps_to_steady") {
        Some(Value::U64s(s)) if s.len() <= 1 => s.first().copied(),
        _ => {
            return Err(Entries::missing(
                "frozen.flow_steps_to_steady",
                "0 or 1 integer",
            ))
        }
    };
    let cells = match e.0.get("frozen.flow_cells") {
        Some(Value::U64s(c)) if c.len() == dim => c.iter().map(|&c| c as usize).collect(),
        _ => {
            return Err(Entries::missing(
                "frozen.flow_cells",
                "one integer per axis",
            ))
        }
    };
    Ok(Frozen {
        c: v("frozen.c")?,
        t: v("frozen.T")?,
        p: v("frozen.p")?,
        u: (0..dim)
            .map(|a| v(&format!("frozen.u{a}")))
            .collect::<Result<_>>()?,
        summary: FlowSummary {
            equations: e.text("frozen.equations")?.into(),
            back_coupling: e.text("frozen.back_coupling")?.into(),
            // (checkpoints written before the pressure modes: explicit)
            pressure: e.text("frozen.pressure").unwrap_or("explicit").into(),
            // (checkpoints written before the stress choice: the spec's)
            stress: e.text("frozen.stress").unwrap_or("spec").into(),
            merged_walls: e.text("frozen.merged_walls").ok().map(str::to_string),
            // (checkpoints written before the settled fill: as given)
            fill: e.text("frozen.fill").unwrap_or("given").into(),
            flow_steps_to_steady: steady,
            flow_steps: e.u64("frozen.flow_steps")?,
            cg_iterations: e.u64("frozen.cg_iterations")?,
            flow_time: x[0],
            flow_seconds: x[1],
            flow_cells: cells,
            max_packing: x[2],
            t_min: x[3],
            t_max: x[4],
            max_speed: x[5],
            kinetic_energy: x[6],
            residual: x[7],
            steady_tolerance: x[8],
            clipped_mass: x[9],
            outlet: None,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Writes `text` to `dir/name`, replacing (not changing) any file there: the checkpoint's
    /// files are hard links to the staging directory's.
    fn put(dir: &Path, name: &str, text: &str) {
        let p = dir.join(name);
        let _ = std::fs::remove_file(&p);
        std::fs::write(p, text).unwrap();
    }

    /// A session of the small scene column-a into `target`, its snapshots in `fields_src`.
    fn session(target: &Path, fields_src: &Path, resume: Option<Stored>) -> Result<Session> {
        let src = crate::scene::locate("column-a").unwrap();
        let source = SceneSource {
            label: src.label,
            text: src.text,
            sets: vec!["run.checkpoint_interval=1".into()],
        };
        let (scene, fields) = source.load().unwrap();
        assert_eq!(scene.checkpoint_interval, Some(1.0));
        Session::new(
            target,
            &scene,
            &fields,
            source,
            fields_src.to_path_buf(),
            resume,
        )
    }

    /// The recorded temporary file goes only when it holds the start of a checkpoint (what a
    /// kill during the write leaves, from nothing to all but the end); a file a user put
    /// under that name keeps, and so does a directory or a link of that name.
    #[test]
    fn a_recorded_part_is_removed_only_if_it_begins_as_a_checkpoint() {
        let d = tempfile::tempdir().unwrap();
        let name = part_name(12345);
        let path = d.path().join(&name);
        let mut whole = encode(&Entries::default());
        whole.extend_from_slice(b"and more");
        for cut in [0, 1, 3, 8, 9, whole.len()] {
            std::fs::write(&path, &whole[..cut]).unwrap();
            assert!(remove_part(d.path(), &name), "{cut} bytes of a checkpoint");
            assert!(!path.exists());
        }
        for users in [&b"the user's"[..], b"SIEVECKQ", b"xSIEVECKP", b"SIEVE\n"] {
            std::fs::write(&path, users).unwrap();
            assert!(!remove_part(d.path(), &name), "{users:?}");
            assert_eq!(std::fs::read(&path).unwrap(), users);
        }
        std::fs::remove_file(&path).unwrap();
        std::fs::create_dir(&path).unwrap();
        assert!(!remove_part(d.path(), &name) && path.is_dir());
        std::fs::remove_dir(&path).unwrap();
        #[cfg(unix)]
        {
            let target = d.path().join("target");
            std::fs::write(&target, MAGIC).unwrap();
            std::os::unix::fs::symlink(&target, &path).unwrap();
            assert!(!remove_part(d.path(), &name));
            assert!(target.exists() && path.symlink_metadata().is_ok());
        }
        // a name a damaged checkpoint could record is never used
        std::fs::write(d.path().join("x"), MAGIC).unwrap();
        assert!(!remove_part(d.path(), "x"));
    }

    #[test]
    fn kept_pieces_round_trip_through_the_encoding() {
        let mut e = Entries::default();
        e.put("kept.len", Value::U64s(vec![10, u64::MAX, 7]));
        e.put("kept.crc", Value::U64s(vec![1, u64::MAX, 2]));
        e.put("kept.pieces", Value::U64s(vec![0, 0, 3]));
        e.put("kept.piece.len", Value::U64s(vec![100, 101, 0]));
        e.put("kept.piece.crc", Value::U64s(vec![u64::MAX - 1, 0, 42]));
        let bytes = encode(&e);
        let back = decode(&bytes).unwrap();
        assert_eq!(back, e);
        assert_eq!(back.u64s("kept.pieces", 3).unwrap(), &[0, 0, 3]);
        assert_eq!(back.u64s("kept.piece.len", 3).unwrap(), &[100, 101, 0]);
        assert_eq!(encode(&back), bytes);
    }

    /// A checkpoint that keeps a `.vti`, a thinned output and a `.pvti` with two pieces (a
    /// serial run resumed under mpirun keeps both kinds), written by `save` and resumed
    /// without MPI: the entries, the links, the names; then a piece of the wrong length, of
    /// the wrong CRC, or missing is refused in one line naming it.
    /// A checkpoint keeps the snapshots written before it, so it waits for the writer
    /// thread: a snapshot still being written when the checkpoint is due is kept (without the
    /// wait it would not exist yet and count as thinned), and a failed write fails the
    /// checkpoint instead of leaving one that lacks the snapshot.
    #[test]
    fn a_checkpoint_waits_for_the_snapshot_writes_in_flight() {
        use crate::output::writer::Pending;
        let d = tempfile::tempdir().unwrap();
        let (target, stage) = (d.path().join("run"), d.path().join("stage"));
        std::fs::create_dir_all(&stage).unwrap();
        let mut s = session(&target, &stage, None).unwrap();
        let writes = std::sync::Arc::new(Pending::default());
        s.after_writes(writes.clone());
        writes.begin();
        let progress = Progress {
            next: 1,
            ..Progress::default()
        };
        std::thread::scope(|sc| {
            let (w, dir) = (writes.clone(), stage.clone());
            sc.spawn(move || {
                std::thread::sleep(std::time::Duration::from_millis(200));
                put(&dir, "state_0000.vti", "snapshot 0, written late");
                w.done(Ok(()));
            });
            s.save(&progress, |_| {}).unwrap();
        });
        assert_eq!(s.kept_name(0).as_deref(), Some("state_0000.vti"));
        let stored = Stored::open(&target).unwrap();
        let len = "snapshot 0, written late".len() as u64;
        assert_eq!(stored.entries.u64s("kept.len", 1).unwrap(), &[len]);

        // a write that failed: the next checkpoint fails with its message
        let target2 = d.path().join("run2");
        let mut s2 = session(&target2, &stage, None).unwrap();
        let failed = std::sync::Arc::new(Pending::default());
        failed.begin();
        failed.done(Err(Error::failure("stage/state_0001.vti: no space left")));
        s2.after_writes(failed);
        let e = s2.save(&progress, |_| {}).unwrap_err();
        assert!(e.to_string().contains("no space left"), "{e}");
        assert_eq!(s2.written(), 0);
    }

    #[test]
    fn kept_pvti_pieces_are_saved_checked_and_linked() {
        let d = tempfile::tempdir().unwrap();
        let target = d.path().join("run");
        let stage = d.path().join("stage");
        std::fs::create_dir_all(&stage).unwrap();
        put(&stage, "state_0000.vti", "serial snapshot 0");
        put(&stage, "state_0002.pvti", "<VTKFile type=\"PImageData\"/>");
        put(&stage, "state_0002_0.vti", "piece of rank 0");
        put(&stage, "state_0002_1.vti", "piece of rank 1, longer");
        let mut s = session(&target, &stage, None).unwrap();
        let progress = Progress {
            next: 3,
            ..Progress::default()
        };
        s.save(&progress, |_| {}).unwrap();
        assert_eq!(s.written(), 1);

        let stored = Stored::open(&target).unwrap();
        let e = &stored.entries;
        let sum = |t: &str| (t.len() as u64, CRC.checksum(t.as_bytes()));
        let vti = sum("serial snapshot 0");
        let pvti = sum("<VTKFile type=\"PImageData\"/>");
        let (p0, p1) = (sum("piece of rank 0"), sum("piece of rank 1, longer"));
        assert_eq!(e.u64s("kept.len", 3).unwrap(), &[vti.0, u64::MAX, pvti.0]);
        assert_eq!(e.u64s("kept.crc", 3).unwrap(), &[vti.1, u64::MAX, pvti.1]);
        assert_eq!(e.u64s("kept.pieces", 3).unwrap(), &[0, 0, 2]);
        assert_eq!(e.u64s("kept.piece.len", 2).unwrap(), &[p0.0, p1.0]);
        assert_eq!(e.u64s("kept.piece.crc", 2).unwrap(), &[p0.1, p1.1]);

        // resumed into a new staging directory: the kept files linked, the names as written,
        // the stale temporary file the checkpoint recorded removed and nothing else
        let ckdir = dir_of(&target);
        let recorded = e.text("part.next").unwrap().to_string();
        put(&ckdir, &recorded, "SIEVECKP half");
        put(&ckdir, "notes.txt", "the user's");
        let stage2 = d.path().join("stage2");
        let r = session(&target, &stage2, Some(stored)).unwrap();
        assert!(!ckdir.join(&recorded).exists());
        assert_eq!(
            std::fs::read_to_string(ckdir.join("notes.txt")).unwrap(),
            "the user's"
        );
        assert_eq!(r.kept_name(0).as_deref(), Some("state_0000.vti"));
        assert_eq!(r.kept_name(1), None);
        assert_eq!(r.kept_name(2).as_deref(), Some("state_0002.pvti"));
        assert_eq!(r.kept_name(3), None);
        let mut names: Vec<String> = std::fs::read_dir(&stage2)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(
            names,
            [
                "state_0000.vti",
                "state_0002.pvti",
                "state_0002_0.vti",
                "state_0002_1.vti"
            ]
        );
        assert_eq!(
            std::fs::read_to_string(stage2.join("state_0002_1.vti")).unwrap(),
            "piece of rank 1, longer"
        );

        // a damaged or missing piece: exit 2 (Error::Input), one line naming the piece
        let kept = dir_of(&target).join("fields");
        let refused = |needle: &str| {
            let stage3 = d.path().join("stage3");
            let stored = Stored::open(&target).unwrap();
            match session(&target, &stage3, Some(stored)) {
                Err(Error::Input(m)) => {
                    assert_eq!(m.lines().count(), 1, "{m}");
                    assert!(m.contains("checkpoint.bin: cannot resume"), "{m}");
                    assert!(m.contains("state_0002_1.vti"), "{m}");
                    assert!(m.contains(needle), "{m}");
                }
                other => panic!("{needle}: {other:?}"),
            }
        };
        put(&kept, "state_0002_1.vti", "piece of rank 1, longer!"); // length
        refused("is damaged");
        put(&kept, "state_0002_1.vti", "piece of rank 1, LONGER"); // same length, CRC
        refused("is damaged");
        std::fs::remove_file(kept.join("state_0002_1.vti")).unwrap();
        refused("is missing");
        // repaired: it resumes again
        put(&kept, "state_0002_1.vti", "piece of rank 1, longer");
        let stored = Stored::open(&target).unwrap();
        assert!(session(&target, &d.path().join("stage4"), Some(stored)).is_ok());

        // piece entries that do not add up (the CRC of the file recomputed): refused
        let state = dir_of(&target).join(STATE_FILE);
        let good = std::fs::read(&state).unwrap();
        let mut e = decode(&good).unwrap();
        e.put("kept.piece.len", Value::U64s(vec![p0.0]));
        std::fs::write(&state, encode(&e)).unwrap();
        let stored = Stored::open(&target).unwrap();
        match session(&target, &d.path().join("stage5"), Some(stored)) {
            Err(Error::Input(m)) => assert!(m.contains("kept.piece.len"), "{m}"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn only_sieves_own_temporary_files_are_removed() {
        assert!(is_part_name(".checkpoint.aZ09xY.part"));
        for name in [
            ".checkpoint.aZ09x.part",   // 5
            ".checkpoint.aZ09xYz.part", // 7
            ".checkpoint.aZ-9xY.part",
            ".checkpoint.aZ09xY.part~",
            "checkpoint.aZ09xY.part",
            ".checkpoint.aZ09xY.bin",
            ".checkpoint.äZ09x.part",
            "checkpoint.bin",
            "../.checkpoint.aZ09xY.part",
        ] {
            assert!(!is_part_name(name), "{name}");
        }
        let d = tempfile::tempdir().unwrap();
        let dir = d.path();
        put(
            dir,
            ".checkpoint.Ab12Cd.part",
            "SIEVECKP and half a checkpoint",
        );
        put(dir, "notes.txt", "the user's");
        assert!(remove_part(dir, ".checkpoint.Ab12Cd.part"));
        assert!(!dir.join(".checkpoint.Ab12Cd.part").exists());
        // not a name of the pattern, a directory, a symbolic link: not files sieve wrote
        assert!(!remove_part(dir, "notes.txt"));
        std::fs::create_dir_all(dir.join(".checkpoint.Dir123.part")).unwrap();
        assert!(!remove_part(dir, ".checkpoint.Dir123.part"));
        std::os::unix::fs::symlink("notes.txt", dir.join(".checkpoint.Link12.part")).unwrap();
        assert!(!remove_part(dir, ".checkpoint.Link12.part"));
        assert!(dir.join(".checkpoint.Link12.part").exists());
        assert_eq!(
            std::fs::read_to_string(dir.join("notes.txt")).unwrap(),
            "the user's"
        );
        assert!(!remove_part(&dir.join("absent"), ".checkpoint.Ab12Cd.part"));
    }

    /// A user's file whose name has the temporary files' pattern survives a resume and the
    /// end of the resumed run (once every file of that pattern was removed on resume): only
    /// the name a checkpoint recorded goes.
    #[test]
    fn a_users_file_of_the_temporary_pattern_survives_a_resume() {
        let d = tempfile::tempdir().unwrap();
        let (target, stage) = (d.path().join("run"), d.path().join("stage"));
        std::fs::create_dir_all(&stage).unwrap();
        put(&stage, "state_0000.vti", "snapshot 0");
        let progress = Progress {
            next: 1,
            ..Progress::default()
        };
        let mut s = session(&target, &stage, None).unwrap();
        s.save(&progress, |_| {}).unwrap();
        s.save(&progress, |_| {}).unwrap();
        let ck = dir_of(&target);
        // two writes, nothing left beside the state but the kept snapshot
        let mut names: Vec<String> = std::fs::read_dir(&ck)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(names, [STATE_FILE, "fields"]);
        let stored = Stored::open(&target).unwrap();
        let recorded = stored.entries.text("part.next").unwrap().to_string();
        assert!(is_part_name(&recorded), "{recorded}");
        let users = ".checkpoint.Ab12Cd.part";
        assert_ne!(recorded, users);
        put(&ck, users, "the user's");
        put(
            &ck,
            &recorded,
            "SIEVECKP, half written when the run was killed",
        );
        let mut r = session(&target, &d.path().join("stage2"), Some(stored)).unwrap();
        assert!(!ck.join(&recorded).exists(), "the recorded .part is left");
        assert_eq!(
            std::fs::read_to_string(ck.join(users)).unwrap(),
            "the user's"
        );
        // the resumed run writes under the recorded name again, records a new one, and at
        // its end removes its own files only
        r.save(&progress, |_| {}).unwrap();
        let again = Stored::open(&target).unwrap();
        assert_ne!(again.entries.text("part.next").unwrap(), recorded);
        r.finish().unwrap();
        assert!(!ck.join(STATE_FILE).exists() && !ck.join("fields").exists());
        assert_eq!(
            std::fs::read_to_string(ck.join(users)).unwrap(),
            "the user's"
        );

        // write_durably: the recorded name, or a random one when that is taken
        let path = d.path().join(STATE_FILE);
        write_durably(&path, b"abc", ".checkpoint.Ab12Cd.part").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"abc");
        assert_eq!(std::fs::read_dir(d.path()).unwrap().count(), 4);
        put(d.path(), ".checkpoint.Taken1.part", "the user's");
        write_durably(&path, b"def", ".checkpoint.Taken1.part").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"def");
        let taken = d.path().join(".checkpoint.Taken1.part");
        assert_eq!(std::fs::read_to_string(taken).unwrap(), "the user's");
        for _ in 0..200 {
            assert!(is_part_name(&new_part_name()));
        }
    }

    /// Two sessions that save the same state write the same bytes (once `part.next` was drawn
    /// at random, so no two checkpoint files were alike), and one session's successive
    /// checkpoints still record different names.
    #[test]
    fn the_same_state_makes_the_same_checkpoint_bytes() {
        let d = tempfile::tempdir().unwrap();
        let stage = d.path().join("stage");
        std::fs::create_dir_all(&stage).unwrap();
        put(&stage, "state_0000.vti", "snapshot 0");
        let (one, two) = (d.path().join("one"), d.path().join("two"));
        let mut a = session(&one, &stage, None).unwrap();
        let mut b = session(&two, &stage, None).unwrap();
        let state = |t: &Path| std::fs::read(dir_of(t).join(STATE_FILE)).unwrap();
        let mut recorded = Vec::new();
        for steps in [10, 20] {
            let progress = Progress {
                next: 1,
                stats: LoopStats {
                    steps,
                    ..LoopStats::default()
                },
                ..Progress::default()
            };
            a.save(&progress, |_| {}).unwrap();
            b.save(&progress, |_| {}).unwrap();
            // (not assert_eq: a failure would print two kilobytes of numbers)
            let same = state(&one) == state(&two);
            assert!(same, "the checkpoints at {steps} steps differ");
            let stored = Stored::open(&one).unwrap();
            let next = stored.entries.text("part.next").unwrap().to_string();
            assert!(is_part_name(&next), "{next}");
            recorded.push(next);
        }
        assert_ne!(recorded[0], recorded[1]);
        // the derived name taken (by a user's file, say): a random one is recorded instead,
        // and the file is left as it was
        let mut c = session(&d.path().join("three"), &stage, None).unwrap();
        let progress = Progress {
            next: 1,
            stats: LoopStats {
                steps: 10,
                ..LoopStats::default()
            },
            ..Progress::default()
        };
        let ck = dir_of(&d.path().join("three"));
        std::fs::create_dir_all(&ck).unwrap();
        put(&ck, &recorded[0], "the user's");
        c.save(&progress, |_| {}).unwrap();
        let stored = Stored::open(&d.path().join("three")).unwrap();
        let next = stored.entries.text("part.next").unwrap();
        assert!(is_part_name(next) && next != recorded[0], "{next}");
        let users = std::fs::read_to_string(ck.join(&recorded[0])).unwrap();
        assert_eq!(users, "the user's");
    }

    #[test]
    fn removing_the_checkpoint_directory_keeps_what_sieve_did_not_write() {
        for name in ["state_0001.vti", "state_0012.pvti", "state_0002_3.vti"] {
            assert!(is_snapshot_name(name), "{name}");
        }
        for name in [
            "state_.vti",
            "state_1_.vti",
            "state_a.vti",
            "state_0001.vtk",
            "s_0001.vti",
        ] {
            assert!(!is_snapshot_name(name), "{name}");
        }
        let d = tempfile::tempdir().unwrap();
        let fill = |dir: &Path| {
            std::fs::create_dir_all(dir.join("fields")).unwrap();
            for name in [
                STATE_FILE,
                ".checkpoint.Ab12Cd.part",
                "fields/state_0000.vti",
                "fields/state_0001.pvti",
                "fields/state_0001_0.vti",
            ] {
                std::fs::write(dir.join(name), "SIEVECKP, sieve's").unwrap();
            }
        };
        // only sieve's files: the directory goes
        let own = d.path().join(".a.checkpoint");
        fill(&own);
        assert_eq!(
            remove_checkpoint_dir(&own, Some(".checkpoint.Ab12Cd.part")).unwrap(),
            None
        );
        assert!(!own.exists());
        assert_eq!(remove_checkpoint_dir(&own, None).unwrap(), None);
        // a user's files beside them: those stay, with their directories, and a note says so
        let mixed = d.path().join(".b.checkpoint");
        fill(&mixed);
        std::fs::write(mixed.join("notes.txt"), "the user's").unwrap();
        std::fs::write(mixed.join("fields/plot.png"), "the user's").unwrap();
        let note = remove_checkpoint_dir(&mixed, Some(".checkpoint.Ab12Cd.part"))
            .unwrap()
            .unwrap();
        assert!(note.contains(".b.checkpoint"), "{note}");
        assert!(!mixed.join(STATE_FILE).exists());
        assert!(!mixed.join(".checkpoint.Ab12Cd.part").exists());
        assert!(!mixed.join("fields/state_0001_0.vti").exists());
        assert_eq!(
            std::fs::read_to_string(mixed.join("notes.txt")).unwrap(),
            "the user's"
        );
        assert_eq!(
            std::fs::read_to_string(mixed.join("fields/plot.png")).unwrap(),
            "the user's"
        );
        // no checkpoint records a temporary file (a run killed during its first one): kept
        let unrecorded = d.path().join(".c.checkpoint");
        fill(&unrecorded);
        assert!(remove_checkpoint_dir(&unrecorded, None).unwrap().is_some());
        assert!(unrecorded.join(".checkpoint.Ab12Cd.part").exists());
    }
}
