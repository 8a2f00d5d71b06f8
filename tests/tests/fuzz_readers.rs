//! Fuzzing every reader of files and bytes (issue 10, "Hostile files"): the recording reader
//! and replay, the snapshot (`.vti`) reader with the drum readouts, the scene TOML reader (parse, deserialise, validate, evaluate), expressions,
//! and the sensor frame decoder (COBS + CRC + postcard) feeding the estimator. Each gets
//! arbitrary input and structure-aware mutations of valid input (a valid recording with a
//! header field changed and its CRC recomputed, truncated, frames duplicated, bits flipped; a
//! built-in scene with one value replaced), and must never panic, never allocate from an
//! unchecked size (an unbounded size aborts the process, which fails the run) and answer
//! with one line per problem.
//!
//! The case count is `SIEVE_FUZZ_CASES` (default 2000 per property, a few seconds in the
//! `test` profile); the large runs reported in docs/soft-sensor.md set it to 100000 or more.

use proptest::prelude::*;
use proptest::test_runner::Config;
use sieve::scene::{self, builtin, expr::Expr, ExprSrc, Scene as SceneSpec};
use sieve::soft_sensor::{record_to_bytes, replay_bytes, RecordOptions, ReplayOptions, Scene};
use sieve_core::sensor::frame::{encode, FRAME_WIRE_MAX};
use sieve_core::sensor::recording::{write_recording, Recording, RecordingHeader, TruthRecord};
use sieve_core::sensor::{FrameDecoder, SoftSensor, VelocityFrame};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::OnceLock;

fn config() -> Config {
    let cases = std::env::var("SIEVE_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(2000);
    Config {
        cases,
        ..Config::default()
    }
}

/// A small valid recording: shear cell, 8 x 8 estimator, 4 x 4 sensor, 12 frames.
fn base() -> &'static [u8] {
    static B: OnceLock<Vec<u8>> = OnceLock::new();
    B.get_or_init(|| {
        let mut o = RecordOptions::new(Scene::ShearCell);
        o.frames = 12;
        o.estimator_cells = [8, 8];
        o.truth_cells = [16, 16];
        o.sensor = [4, 4];
        record_to_bytes(&o).expect("record").0
    })
}

/// An error message must be one non-empty line.
fn one_line(e: &str) -> Result<(), TestCaseError> {
    prop_assert!(!e.is_empty());
    prop_assert!(!e.contains('\n'), "several lines: {e}");
    Ok(())
}

/// Replays counted: [refused, replayed] (printed with `--nocapture` every 20,000 inputs, so
/// a long run shows that the mutations reach the replay itself, not only the checks).
static REPLAYS: [AtomicUsize; 2] = [AtomicUsize::new(0), AtomicUsize::new(0)];

/// Replays `bytes`: either a clean refusal in one line, or a report with finite numbers.
fn replay_ok(bytes: &[u8]) -> Result<(), TestCaseError> {
    let r = replay_bytes(bytes, &ReplayOptions::default());
    let n = REPLAYS[r.is_ok() as usize].fetch_add(1, Ordering::Relaxed) + 1;
    if n % 20_000 == 0 {
        eprintln!(
            "fuzz replay: {} refused, {} replayed",
            REPLAYS[0].load(Ordering::Relaxed),
            REPLAYS[1].load(Ordering::Relaxed)
        );
    }
    match r {
        Err(e) => one_line(&e),
        Ok(r) => {
            prop_assert!(r.max_psi_error.is_finite(), "{}", r.max_psi_error);
            prop_assert!(r.max_l1.is_finite() && r.mass_drift.is_finite());
            Ok(())
        }
    }
}

/// A float that hurts: NaN, infinities, zero, signs, extremes, or any bits.
fn nasty_f32() -> impl Strategy<Value = f32> {
    prop_oneof![
        Just(f32::NAN),
        Just(f32::INFINITY),
        Just(f32::NEG_INFINITY),
        Just(0.0f32),
        Just(-1.0f32),
        Just(1e30f32),
        Just(1e-30f32),
        Just(f32::MAX),
        Just(f32::MIN_POSITIVE),
        any::<f32>(),
        (0.0f32..2.0),
    ]
}

/// One structural change of a valid recording (applied before the CRC is recomputed).
#[derive(Clone, Debug)]
enum Mutation {
    TruthCoarse([u16; 2]),
    TruthCells([u16; 2]),
    Cells([u16; 2]),
    Sensor([u8; 2]),
    Real(usize, f32),
    Substeps(u16),
    Hold(u16),
    Region([u16; 2], [u16; 2], Option<u8>),
    Frames(u32),
    TruthValue(usize, usize, f32),
    TruthDrop(usize),
    TruthDup(usize),
    TruthPsi(usize, f32),
    StreamDupFrame(usize),
    StreamCut(usize),
    StreamFlip(usize, u8),
    StreamInsert(usize, Vec<u8>),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        any::<[u16; 2]>().prop_map(Mutation::TruthCoarse),
        (0u16..40, 0u16..40).prop_map(|(a, b)| Mutation::TruthCoarse([a, b])),
        any::<[u16; 2]>().prop_map(Mutation::TruthCells),
        any::<[u16; 2]>().prop_map(Mutation::Cells),
        (0u16..40, 0u16..40).prop_map(|(a, b)| Mutation::Cells([a, b])),
        any::<[u8; 2]>().prop_map(Mutation::Sensor),
        (0usize..20, nasty_f32()).prop_map(|(i, v)| Mutation::Real(i, v)),
        any::<u16>().prop_map(Mutation::Substeps),
        any::<u16>().prop_map(Mutation::Hold),
        (any::<[u16; 2]>(), any::<[u16; 2]>(), any::<Option<u8>>())
            .prop_map(|(l, h, o)| Mutation::Region(l, h, o)),
        any::<u32>().prop_map(Mutation::Frames),
        (any::<usize>(), any::<usize>(), nasty_f32())
            .prop_map(|(k, i, v)| Mutation::TruthValue(k, i, v)),
        any::<usize>().prop_map(Mutation::TruthDrop),
        any::<usize>().prop_map(Mutation::TruthDup),
        (any::<usize>(), nasty_f32()).prop_map(|(k, v)| Mutation::TruthPsi(k, v)),
        any::<usize>().prop_map(Mutation::StreamDupFrame),
        any::<usize>().prop_map(Mutation::StreamCut),
        (any::<usize>(), 0u8..8).prop_map(|(i, b)| Mutation::StreamFlip(i, b)),
        (
            any::<usize>(),
            proptest::collection::vec(any::<u8>(), 1..64)
        )
            .prop_map(|(i, v)| Mutation::StreamInsert(i, v)),
    ]
}

fn apply(
    h: &mut RecordingHeader,
    truth: &mut Vec<TruthRecord>,
    stream: &mut Vec<u8>,
    m: &Mutation,
) {
    let c = &mut h.config;
    match m {
        Mutation::TruthCoarse(v) => h.truth_coarse = *v,
        Mutation::TruthCells(v) => h.truth_cells = *v,
        Mutation::Cells(v) => c.cells = *v,
        Mutation::Sensor(v) => c.sensor = *v,
        Mutation::Real(i, v) => {
            let v = *v;
            match i % 20 {
                0 => c.extent[0] = v,
                1 => c.extent[1] = v,
                2 => c.s0 = v,
                3 => c.eta0 = v,
                4 => c.eps0 = v,
                5 => c.heating = v,
                6 => c.gravity[0] = v,
                7 => c.gravity[1] = v,
                8 => c.c = v,
                9 => c.initial_phihat = v,
                10 => c.inflow_phihat = v,
                11 => c.diffusion = v,
                12 => c.courant = v,
                13 => c.tick_period = v,
                14 => c.max_period_factor = v,
                15 => c.reject_speed = v,
                16 => c.outlier_tol = v,
                17 => c.smoothing = v,
                18 => c.psi_alarm = v,
                _ => h.noise = v,
            }
        }
        Mutation::Substeps(v) => c.budget.cycles = *v as u32 * 1024,
        Mutation::Hold(v) => c.hold_ticks = *v,
        Mutation::Region(lo, hi, o) => {
            let _ = c
                .regions
                .push(sieve_core::sensor::Region::new("fuzz", *lo, *hi));
            c.outlet = *o;
        }
        Mutation::Frames(v) => h.frames = *v,
        Mutation::TruthValue(k, i, v) => {
            if !truth.is_empty() {
                let n = truth.len();
                let t = &mut truth[k % n];
                if !t.phihat.is_empty() {
                    let m = t.phihat.len();
                    t.phihat[i % m] = *v;
                }
            }
        }
        Mutation::TruthDrop(k) => {
            if !truth.is_empty() {
                let n = truth.len();
                truth.remove(k % n);
            }
        }
        Mutation::TruthDup(k) => {
            if !truth.is_empty() {
                let n = truth.len();
                let t = truth[k % n].clone();
                truth.insert(k % n, t);
            }
        }
        Mutation::TruthPsi(k, v) => {
            if !truth.is_empty() {
                let n = truth.len();
                // both mixing indices of a record (format 6)
                if k % 2 == 0 {
                    truth[k % n].psi = *v;
                } else {
                    truth[k % n].psi_estimator_grid = *v;
                }
            }
        }
        Mutation::StreamDupFrame(k) => {
            // Frames end with 0x00: copy the k-th one in place.
            let ends: Vec<usize> = stream
                .iter()
                .enumerate()
                .filter(|(_, &b)| b == 0)
                .map(|(i, _)| i + 1)
                .collect();
            if !ends.is_empty() {
                let j = k % ends.len();
                let start = if j == 0 { 0 } else { ends[j - 1] };
                let f = stream[start..ends[j]].to_vec();
                stream.splice(ends[j]..ends[j], f);
            }
        }
        Mutation::StreamCut(k) => {
            let n = stream.len();
            stream.truncate(k % (n + 1));
        }
        Mutation::StreamFlip(i, b) => {
            if !stream.is_empty() {
                let n = stream.len();
                stream[i % n] ^= 1 << b;
            }
        }
        Mutation::StreamInsert(i, v) => {
            let n = stream.len();
            stream.splice(i % (n + 1)..i % (n + 1), v.iter().copied());
        }
    }
}

/// The recording with mutations applied and a valid CRC.
fn mutated(muts: &[Mutation]) -> Vec<u8> {
    let rec = Recording::parse(base()).expect("valid base");
    let mut h = rec.header.clone();
    let mut truth: Vec<TruthRecord> = rec.truth().collect();
    let mut stream = rec.stream.to_vec();
    for m in muts {
        apply(&mut h, &mut truth, &mut stream, m);
    }
    let mut tb = Vec::new();
    for t in &truth {
        assert!(t.encode_into(|b| tb.extend_from_slice(b)));
    }
    let mut out = Vec::new();
    write_recording(
        &h,
        &stream,
        &tb,
        &mut vec![0u8; 4096],
        |b| {
            out.extend_from_slice(b);
            Ok::<(), ()>(())
        },
        (),
    )
    .expect("header fits");
    out
}

/// Raw damage after the CRC: flip, cut, overwrite a length field.
#[derive(Clone, Debug)]
enum Raw {
    Flip(usize, u8),
    Cut(usize),
    Length(usize, u32),
    Append(Vec<u8>),
}

fn raw() -> impl Strategy<Value = Raw> {
    prop_oneof![
        (any::<usize>(), 0u8..8).prop_map(|(i, b)| Raw::Flip(i, b)),
        any::<usize>().prop_map(Raw::Cut),
        (0usize..3, any::<u32>()).prop_map(|(k, v)| Raw::Length(k, v)),
        proptest::collection::vec(any::<u8>(), 1..16).prop_map(Raw::Append),
    ]
}

fn damage(mut b: Vec<u8>, r: &Raw) -> Vec<u8> {
    match r {
        Raw::Flip(i, bit) => {
            let n = b.len();
            b[i % n] ^= 1 << bit;
        }
        Raw::Cut(i) => {
            let n = b.len();
            b.truncate(i % n);
        }
        Raw::Length(k, v) => {
            // Offsets of the three length fields.
            let hl = u32::from_le_bytes(b[12..16].try_into().unwrap()) as usize;
            let sl = u32::from_le_bytes(b[16 + hl..20 + hl].try_into().unwrap()) as usize;
            let at = [12, 16 + hl, 20 + hl + sl][*k];
            b[at..at + 4].copy_from_slice(&v.to_le_bytes());
        }
        Raw::Append(v) => b.extend_from_slice(v),
    }
    b
}

proptest! {
    #![proptest_config(config())]

    /// Arbitrary bytes, and arbitrary bytes behind a valid magic and version.
    #[test]
    fn recording_arbitrary_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..2000), magic in any::<bool>()) {
        let mut b = bytes;
        if magic {
            let mut head = b"SIEVEREC\x02\0\0\0".to_vec();
            head.extend_from_slice(&b);
            b = head;
        }
        replay_ok(&b)?;
    }

    /// A valid recording, restructured with a valid CRC, then possibly damaged raw.
    #[test]
    fn recording_structure_aware(muts in proptest::collection::vec(mutation(), 1..4), dmg in proptest::option::of(raw())) {
        let mut b = mutated(&muts);
        if let Some(r) = &dmg {
            b = damage(b, r);
        }
        replay_ok(&b)?;
    }

    /// Wire frames: arbitrary bytes in arbitrary chunks, and valid frames damaged; every
    /// decoded frame goes on into the estimator (`submit` validates it).
    #[test]
    fn frame_decoder_and_estimator(bytes in proptest::collection::vec(any::<u8>(), 0..3000),
                                   chunk in 1usize..400,
                                   seqs in proptest::collection::vec(any::<u32>(), 1..6),
                                   vals in proptest::collection::vec(nasty_f32(), 1..40),
                                   flips in proptest::collection::vec((any::<usize>(), 0u8..8), 0..4),
                                   cut in any::<usize>()) {
        let mut stream = bytes;
        let mut scratch = vec![0u8; FRAME_WIRE_MAX];
        let mut wire = vec![0u8; FRAME_WIRE_MAX];
        for &seq in &seqs {
            let mut f = VelocityFrame { seq, time: 0.01, period: 0.01, nx: 4, nz: 4, u: Default::default() };
            for k in 0..32 {
                let _ = f.u.push(if k < vals.len() { vals[k] } else { 0.001 });
            }
            let n = encode(&f, &mut scratch, &mut wire).expect("fits");
            let mut w = wire[..n].to_vec();
            for &(i, b) in &flips {
                let m = w.len();
                w[i % m] ^= 1 << b;
            }
            w.truncate(1 + cut % w.len());
            stream.extend_from_slice(&w);
        }
        let rec = Recording::parse(base()).expect("valid");
        let mut s: Box<SoftSensor<f32, 1024>> = Box::default();
        s.configure(&rec.header.config).expect("config");
        let mut d: Box<FrameDecoder<FRAME_WIRE_MAX>> = Box::default();
        for piece in stream.chunks(chunk) {
            let mut rest = piece;
            while !rest.is_empty() {
                let (r, next) = d.feed::<VelocityFrame>(rest);
                rest = next;
                if let Some(Ok(f)) = r {
                    let _ = s.submit(&f);
                }
            }
            let e = s.finish_tick();
            prop_assert!(e.psi.is_finite());
        }
    }

    /// Arbitrary text, and text from the expression alphabet, as a scene expression.
    #[test]
    fn expressions(text in "\\PC{0,300}", tokens in proptest::collection::vec(prop_oneof![
            Just("x"), Just("z"), Just("c"), Just("pi"), Just("1"), Just("2.5"), Just("1e308"), Just("0"),
            Just("+"), Just("-"), Just("*"), Just("/"), Just("^"), Just("%"), Just("("), Just(")"), Just(","),
            Just("<"), Just("=="), Just("&&"), Just("!"), Just("\""), Just("if("), Just("math::sin("),
            Just("math::pow("), Just("min("), Just("math::ln("), Just(" "), Just("true"), Just(";"), Just("a = 1")
        ], 0..400)) {
        let mut vars = sieve::scene::expr::Vars::new();
        for t in [text, tokens.concat()] {
            match Expr::compile("f.toml", "initial.phi", &ExprSrc::Text(t), true) {
                Err(e) => one_line(&e.to_string())?,
                Ok(e) => {
                    if let Err(e) = e.eval(&mut vars, [0.1, 0.2, 0.3], 0.5, "f.toml", "initial.phi") {
                        one_line(&e.to_string())?;
                    }
                }
            }
        }
    }

    /// Arbitrary text as a scene file.
    #[test]
    fn scene_arbitrary_text(text in "\\PC{0,400}", toml_ish in "[a-z_.=\\[\\]\"0-9 \\n\\-+e]{0,400}") {
        for t in [text, toml_ish] {
            scene_ok(&t)?;
        }
    }

    /// A built-in scene with one number replaced by a hostile value (or a value of another
    /// type), as the scene reader and validator see it.
    #[test]
    fn scene_mutated_values(which in any::<usize>(), at in any::<usize>(), value in prop_oneof![
            Just("nan".to_string()), Just("inf".to_string()), Just("-inf".to_string()), Just("0".to_string()),
            Just("-1".to_string()), Just("1e308".to_string()), Just("1e-308".to_string()), Just("-0.0".to_string()),
            Just("4294967296".to_string()), Just("9223372036854775807".to_string()), Just("\"z\"".to_string()),
            Just("\"1/0\"".to_string()), Just("[]".to_string()), Just("true".to_string()), Just("{}".to_string()),
            any::<f64>().prop_map(|v| format!("{v:e}")), (0u32..100000).prop_map(|v| v.to_string())
        ]) {
        let names = builtin::names();
        let b = builtin::find(names[which % names.len()]).expect("built-in");
        let text = replace_number(b.toml, at, &value);
        scene_ok(&text)?;
    }

    /// A built-in scene with one quoted value (a one-of word such as `fill = "given"`, or an
    /// expression) replaced by a value of any type: the refusal names what is allowed
    /// (schema_errors.rs) and never panics.
    #[test]
    fn scene_mutated_words(which in any::<usize>(), at in any::<usize>(), value in prop_oneof![
            Just("1".to_string()), Just("-2.5".to_string()), Just("nan".to_string()), Just("true".to_string()),
            Just("[]".to_string()), Just("[[1]]".to_string()), Just("{a = 1}".to_string()), Just("{}".to_string()),
            Just("1979-05-27".to_string()), Just("\"\"".to_string()), Just("\"\\u007f\"".to_string()),
            "[a-z\\-]{0,12}".prop_map(|w| format!("\"{w}\"")),
            "\\PC{0,60}".prop_map(|w| format!("{w:?}"))
        ]) {
        let names = builtin::names();
        let b = builtin::find(names[which % names.len()]).expect("built-in");
        let text = replace_quoted(b.toml, at, &value);
        scene_ok(&text)?;
        let label = "fuzz.toml";
        if let Err(e) = scene::parse_table(label, &text).and_then(|t| scene::deserialize(label, t)) {
            let line = e.to_string();
            prop_assert_eq!(line.lines().count(), 1, "{}", line);
            prop_assert!(!line.contains("unit variant") && !line.contains("untagged"), "{}", line);
        }
    }
}

proptest! {
    #![proptest_config(config())]

    /// The silo with a settled fill (model.md 5.8) and one number replaced by a hostile value:
    /// the settling runs on whatever the validator lets through (gravity, T0, the packing
    /// limits, the grid) and never panics or lets a non-finite c out.
    #[test]
    fn settled_scene_mutated_values(at in any::<usize>(), value in prop_oneof![
            Just("nan".to_string()), Just("inf".to_string()), Just("0".to_string()),
            Just("-1".to_string()), Just("1e308".to_string()), Just("1e-308".to_string()),
            Just("1e6".to_string()), Just("-1e6".to_string()), Just("0.6399".to_string()),
            any::<f64>().prop_map(|v| format!("{v:e}")), (0u32..1000).prop_map(|v| v.to_string())
        ]) {
        let b = builtin::find("silo").expect("built-in");
        let settled = b.toml.replace("phi = \"c / 2\"", "phi = \"c / 2\"\nfill = \"settled\"");
        prop_assert!(settled.contains("fill = \"settled\""));
        let text = replace_number(&settled, at, &value);
        scene_ok(&text)?;
        let label = "fuzz.toml";
        if let Ok(s) = scene::parse_table(label, &text)
            .and_then(|t| scene::deserialize(label, t))
            .and_then(|f| SceneSpec::validate(label, f))
        {
            if s.len() <= 4096 {
                if let Ok(f) = s.evaluate_fields() {
                    prop_assert!(f.c.iter().all(|c| c.is_finite() && *c > 0.0), "{text}");
                }
            }
        }
    }
}

/// The whole scene path short of running: parse, deserialise, validate, the warnings a run
/// prints before it starts, and the fields of small grids (evaluating 262144 cells per case would make the fuzz slow, not safer).
fn scene_ok(text: &str) -> Result<(), TestCaseError> {
    let label = "fuzz.toml";
    let r = scene::parse_table(label, text)
        .and_then(|t| scene::deserialize(label, t))
        .and_then(|f| SceneSpec::validate(label, f))
        .and_then(|s| {
            if s.len() <= 4096 {
                s.evaluate_fields()?;
            }
            Ok(s)
        });
    match r {
        // the lines printed before a run (narrow orifices) read the validated numbers
        Ok(s) => {
            for w in sieve::silo::outlet_caveats(&s) {
                prop_assert!(w.starts_with("warning: fuzz.toml: "), "{w}");
            }
        }
        Err(e) => {
            for line in e.lines() {
                prop_assert!(line.starts_with(label), "{line}");
            }
        }
    }
    Ok(())
}

/// `text` with its `at`-th quoted value after `= ` (modulo their count) replaced by `value`.
fn replace_quoted(text: &str, at: usize, value: &str) -> String {
    let spans: Vec<(usize, usize)> = text
        .match_indices("= \"")
        .filter_map(|(i, _)| {
            let s = i + 2;
            let e = text[s + 1..].find('"')? + s + 2;
            Some((s, e))
        })
        .collect();
    if spans.is_empty() {
        return text.to_string();
    }
    let (s, e) = spans[at % spans.len()];
    format!("{}{}{}", &text[..s], value, &text[e..])
}

/// `text` with its `at`-th number literal of a scene (modulo their count) replaced by `value`.
fn replace_number(text: &str, at: usize, value: &str) -> String {
    replace_literal(text, at, value, |p| {
        matches!(p, b' ' | b'=' | b'[' | b',' | b'-')
    })
}

/// `text` with its `at`-th number (modulo their count) replaced by `value`: a run of digits
/// (with a sign, point or exponent inside) that starts at the text's start or after a byte
/// `after` accepts.
fn replace_literal(text: &str, at: usize, value: &str, after: impl Fn(u8) -> bool) -> String {
    let b = text.as_bytes();
    let mut spans = Vec::new();
    let mut i = 0;
    while i < b.len() {
        let starts = b[i].is_ascii_digit() && (i == 0 || after(b[i - 1]));
        if starts {
            let s = i;
            while i < b.len()
                && (b[i].is_ascii_digit() || matches!(b[i], b'.' | b'e' | b'E' | b'-' | b'+'))
            {
                i += 1;
            }
            spans.push((s, i));
        } else {
            i += 1;
        }
    }
    if spans.is_empty() {
        return text.to_string();
    }
    let (s, e) = spans[at % spans.len()];
    format!("{}{}{}", &text[..s], value, &text[e..])
}

/// A small valid `.vti` of a drum, as `sieve run` writes it (2D tumbler 12 x 12, or the
/// 3D tumbler 8 x 3 x 8, whose drum readouts take the axial mean first), with a flowing
/// half-filled bed so that every readout has something to measure.
fn drum_vti(three: bool) -> &'static (SceneSpec, Vec<u8>) {
    static B: [OnceLock<(SceneSpec, Vec<u8>)>; 2] = [OnceLock::new(), OnceLock::new()];
    B[three as usize].get_or_init(|| {
        let (name, cells) = if three {
            ("tumbler-3d", "[8,3,8]")
        } else {
            ("tumbler", "[12,12]")
        };
        let sets = [format!("grid.cells={cells}"), "run.t_end=1.0".into()];
        let (scene, _) = scene::load(name, &sets).expect("scene");
        let n = scene.len();
        let (nx, nz) = (scene.cells[0], scene.cells[scene.dim - 1]);
        let mut snap = sieve::data::Snapshot::at_rest(1.0, n, 1e-9, 1.0);
        for i in 0..n {
            let (ix, iz) = (i % nx, i / (n / nz));
            if iz < nz / 2 {
                snap.c[i] = 0.58 - 0.01 * (ix % 3) as f64;
                snap.phi[i] = snap.c[i] * (ix as f64 / nx as f64);
                snap.u[i] = [0.01 * iz as f64, 0.0, -0.01 * ix as f64];
            }
            if ix == 0 || ix == nx - 1 {
                snap.volume.as_mut().unwrap()[i] = 0.0;
            }
        }
        let bytes = sieve::output::vtk::vti_bytes(&scene, &snap);
        (scene, bytes)
    })
}

/// Reads `bytes` as a `.vti` and, if it reads, measures a drum from it: either a one-line
/// refusal or readouts, never a panic or an unbounded allocation.
fn vti_ok(scene: &SceneSpec, bytes: &[u8]) -> Result<(), TestCaseError> {
    match sieve::output::vtk::vti_from_bytes(bytes, "state_0001.vti") {
        Err(e) => one_line(&e.to_string())?,
        Ok(v) => {
            let _ = sieve::drum::axial_mean(v.clone());
            let t = v.t;
            let _ = sieve::drum::analyse_snapshots(scene, t, vec![v]);
        }
    }
    Ok(())
}

/// The numbers a header edit puts in.
fn nasty_number() -> impl Strategy<Value = String> {
    prop_oneof![
        Just("0".to_string()),
        Just("1".to_string()),
        Just("-1".to_string()),
        Just("4294967296".to_string()),
        Just("18446744073709551615".to_string()),
        Just("99999999999999999999".to_string()),
        Just("1e308".to_string()),
        Just("NaN".to_string()),
        Just("inf".to_string()),
        Just(String::new()),
        (0u64..100_000).prop_map(|v| v.to_string()),
    ]
}

proptest! {
    #![proptest_config(config())]

    /// Snapshot files (`sieve plot`, the drum readouts, a resumed run's snapshots): a valid
    /// `.vti` with one number of its XML header replaced (extents, origin, spacing, time,
    /// component counts, offsets), then possibly damaged raw (a bit flipped, cut short,
    /// bytes appended).
    #[test]
    fn vti_reader_and_drum_readouts(three in any::<bool>(), at in any::<usize>(),
                                   value in nasty_number(), edit in any::<bool>(),
                                   dmg in proptest::option::of((0u8..3, any::<usize>(), 0u8..8))) {
        let (scene, base) = drum_vti(three);
        let head = base.windows(13).position(|w| w == b"<AppendedData").expect("appended");
        let mut b = if edit {
            let text = std::str::from_utf8(&base[..head]).expect("utf-8 header");
            // any number of the XML header: after a quote, a space or a `>`
            let mut b = replace_literal(text, at, &value, |p| !p.is_ascii_alphanumeric())
                .into_bytes();
            b.extend_from_slice(&base[head..]);
            b
        } else {
            base.clone()
        };
        if let Some((kind, i, bit)) = dmg {
            let n = b.len();
            match kind {
                0 => b[i % n] ^= 1 << bit,
                1 => b.truncate(i % n),
                _ => b.extend_from_slice(&[bit; 9]),
            }
        }
        vti_ok(scene, &b)?;
    }

    /// Arbitrary bytes, and arbitrary bytes behind a valid header.
    #[test]
    fn vti_arbitrary_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..3000), header in any::<bool>()) {
        let (scene, base) = drum_vti(false);
        let mut b = Vec::new();
        if header {
            let at = base.windows(13).position(|w| w == b"<AppendedData").expect("appended");
            let under = base[at..].iter().position(|&c| c == b'_').expect("_") + at + 1;
            b.extend_from_slice(&base[..under]);
        }
        b.extend_from_slice(&bytes);
        vti_ok(scene, &b)?;
    }
}

/// The fuzzing above ran: the base recording replays, the built-in scenes load.
#[test]
fn the_fuzz_starts_from_valid_inputs() {
    for three in [false, true] {
        let (scene, bytes) = drum_vti(three);
        let v = sieve::output::vtk::vti_from_bytes(bytes, "base").expect("base snapshot reads");
        let d = sieve::drum::analyse_snapshots(scene, v.t, vec![v]).expect("drum readouts");
        assert!(d.relative_kinetic_energy > 0.0, "{d:?}");
    }
    let r = replay_bytes(base(), &ReplayOptions::default()).expect("base replays");
    assert!(r.rows.len() >= 10, "{}", r.rows.len());
    for name in builtin::names() {
        let b = builtin::find(name).unwrap();
        let t = scene::parse_table(name, b.toml).unwrap();
        let f = scene::deserialize(name, t).unwrap();
        SceneSpec::validate(name, f).unwrap();
    }
    assert_eq!(
        replace_number("a = 12\nb = [3, 4.5e-3]", 2, "X"),
        "a = 12\nb = [3, X]"
    );
}
