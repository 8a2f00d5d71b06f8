//! Bit-reproducibility of the soft sensor (issue 4, item 10): golden f32 state hashes of a
//! deterministic replay, and the recording that firmware-sim embeds with the hashes the
//! emulated firmware must print. Run in debug and release (`cargo test --release`): the
//! constants are the same.
//!
//! To regenerate after an intended change: `SIEVE_BLESS=1 cargo test -p sieve-tests --test
//! suite sensor_golden::`, then update the constants below from the printed values.

use sieve::soft_sensor::{
    record_to_bytes, replay_bytes, RecordOptions, ReplayOptions, ReplayReport, Scene,
};
use sieve_core::sensor::feeder::Faults;
use std::path::PathBuf;

/// The recording firmware-sim embeds: shear cell, truth and estimator 32 x 32, sensor 8 x 8
/// (4x coarser), 5 % noise, 100 frames of 10 ms.
fn firmware_options() -> RecordOptions {
    RecordOptions {
        frames: 100,
        ..RecordOptions::new(Scene::ShearCell)
    }
}

fn recordings_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../firmware-sim/recordings")
}

/// Short replay (40 frames, 16 x 16, sensor 4 x 4) with pinned hashes.
const SHORT_CLEAN: u64 = 0x553d_604c_a90b_6763;
const SHORT_FAULTED: u64 = 0x6c55_ad3a_35f4_2389;

#[test]
fn short_replay_golden_hash() {
    let opts = RecordOptions {
        frames: 40,
        truth_cells: [16, 16],
        estimator_cells: [16, 16],
        sensor: [4, 4],
        ..RecordOptions::new(Scene::ShearCell)
    };
    let (bytes, _) = record_to_bytes(&opts).unwrap();
    let clean = replay_bytes(&bytes, &ReplayOptions::default()).unwrap();
    let faulted = replay_bytes(
        &bytes,
        &ReplayOptions {
            faults: Faults::DEMO,
        },
    )
    .unwrap();
    println!(
        "short clean=0x{:016x} faulted=0x{:016x}",
        clean.final_state_hash, faulted.final_state_hash
    );
    // Replaying twice gives the same bits (no hidden state, no allocation-order effects).
    let again = replay_bytes(&bytes, &ReplayOptions::default()).unwrap();
    assert_eq!(again.final_state_hash, clean.final_state_hash);
    assert_ne!(clean.final_state_hash, faulted.final_state_hash);
    if std::env::var("SIEVE_BLESS").is_err() {
        assert_eq!(
            clean.final_state_hash, SHORT_CLEAN,
            "clean 0x{:016x}",
            clean.final_state_hash
        );
        assert_eq!(
            faulted.final_state_hash, SHORT_FAULTED,
            "faulted 0x{:016x}",
            faulted.final_state_hash
        );
    }
}

/// Replays `bytes` clean and with the demo faults, and checks that
/// `firmware-sim/recordings/NAME.rec` and `NAME.golden` equal `bytes` and the two replays'
/// hashes (written instead with `SIEVE_BLESS=1`); returns the golden text and the replays.
fn committed_equal(name: &str, bytes: &[u8]) -> (String, ReplayReport, ReplayReport) {
    let clean = replay_bytes(bytes, &ReplayOptions::default()).unwrap();
    let faulted = replay_bytes(
        bytes,
        &ReplayOptions {
            faults: Faults::DEMO,
        },
    )
    .unwrap();
    let golden = format!(
        "final_state_hash=0x{:016x}\nfaulted_state_hash=0x{:016x}\n",
        clean.final_state_hash, faulted.final_state_hash
    );
    let dir = recordings_dir();
    let (rec, gold) = (
        dir.join(format!("{name}.rec")),
        dir.join(format!("{name}.golden")),
    );
    if std::env::var("SIEVE_BLESS").is_ok() {
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(&rec, bytes).unwrap();
        std::fs::write(&gold, &golden).unwrap();
    }
    let committed = std::fs::read(&rec).expect("committed recording");
    assert!(
        committed == bytes,
        "{name}.rec differs from the recorder's output"
    );
    assert_eq!(std::fs::read_to_string(&gold).unwrap(), golden);
    (golden, clean, faulted)
}

/// The committed recording is what the recorder produces today, and its replay hashes are the
/// committed golden values that firmware-sim/run.sh checks the emulated firmware against.
#[test]
fn firmware_recording_and_golden_hashes() {
    let (bytes, _) = record_to_bytes(&firmware_options()).unwrap();
    let (golden, clean, faulted) = committed_equal("shear-cell", &bytes);
    // The faulted pass really exercised the fault paths and stayed accurate enough to use.
    let c = faulted.counters;
    let w = faulted.wire;
    println!(
        "{golden}faulted: {c:?} {w:?} {:?} max psi err {}",
        faulted.injected, faulted.max_psi_error
    );
    assert!(w.crc + w.framing + w.overflow > 0);
    assert!(c.seq > 0 && c.non_finite > 0 && c.stale_ticks > 0);
    assert!(clean.max_psi_error < 0.05, "{}", clean.max_psi_error);
    // Faults cost accuracy only through held velocities and lost periods.
    assert!(faulted.max_psi_error < 0.05, "{}", faulted.max_psi_error);
    assert_eq!(
        w.decoded,
        c.accepted + c.non_finite + c.seq + c.dims + c.range
    );
}

/// The silo recording firmware-sim also runs (issue 9: the firmware on the device it is for):
/// the short silo (15 x 50 truth, 0.04 m orifice, 3 s), an 8 x 28 estimator carrying c
/// through the orifice, a 2 x 7 sensor (4x coarser), 5 % noise, 10 Hz, and the M4F budget.
/// Its replays are the golden hashes; the firmware must print the same and keep every tick
/// inside the cost model, whose constant and boundary terms this small grid exercises.
#[test]
fn firmware_silo_recording_and_golden_hashes() {
    let (scene, fields) = sieve::scene::load(
        "silo",
        &[
            "grid.cells=[15,50]".to_string(),
            "boundary.flow.z_low.outlet.width=0.04".to_string(),
            "run.t_end=3".to_string(),
        ],
    )
    .expect("scene");
    let opts = sieve::soft_sensor::SceneRecordOptions {
        estimator_cells: [8, 28],
        sensor: [2, 7],
        period: Some(0.1),
        ..Default::default()
    };
    let bytes = sieve::soft_sensor::record_scene(&scene, &fields, &opts)
        .expect("record")
        .0;
    let (golden, clean, faulted) = committed_equal("silo", &bytes);
    let out = clean
        .outflow
        .as_ref()
        .expect("a silo recording scores its outflow");
    println!(
        "{golden}silo: outflow fines error max {} (flowing {}) mean {}, out est {} truth {}, unbooked {}",
        out.max_window_error,
        out.max_window_error_flowing,
        out.mean_window_error,
        out.total_out[0],
        out.total_out[1],
        clean.mass_unbooked
    );
    assert_eq!(clean.ticks, 30);
    // Nothing budget-limited: the M4F at 10 Hz affords this estimator's substeps.
    assert_eq!(clean.counters.budget_limited, 0);
    assert_eq!(clean.lag, 0.0);
    // The estimator lets grains out through the orifice and books them.
    assert!(
        out.total_out[0] > 0.3 * out.total_out[1],
        "{:?}",
        out.total_out
    );
    assert!(clean.mass_unbooked.abs() < 5e-6, "{}", clean.mass_unbooked);
    assert!(faulted.counters.stale_ticks > 0 || faulted.wire.crc > 0);
}

/// The file-based entry points the CLI wires (`sieve record` / `sieve replay`) round-trip
/// through a file and print the firmware's greppable hash line.
#[test]
fn record_and_replay_files_print_the_golden_line() {
    let path = std::env::temp_dir().join(format!("sieve-sensor-{}.rec", std::process::id()));
    let rep = sieve::soft_sensor::record(&firmware_options(), &path).unwrap();
    assert_eq!(rep.frames, 100);
    assert_eq!(
        std::fs::metadata(&path).unwrap().len() as usize,
        rep.file_bytes
    );
    let r = sieve::soft_sensor::replay(&path, &ReplayOptions::default()).unwrap();
    std::fs::remove_file(&path).unwrap();
    let mut out = Vec::new();
    sieve::soft_sensor::print_report(&r, 10, &mut out).unwrap();
    let text = String::from_utf8(out).unwrap();
    print!("{text}");
    let golden = std::fs::read_to_string(recordings_dir().join("shear-cell.golden")).unwrap();
    let line = golden.lines().next().unwrap();
    assert!(text.lines().any(|l| l == line), "missing {line}");
    // 100 ticks: every 10th printed (0, 10, ..., 90) plus the last (99).
    assert_eq!(
        text.lines()
            .filter(|l| l.trim_start().starts_with(char::is_numeric))
            .count(),
        11
    );
}
