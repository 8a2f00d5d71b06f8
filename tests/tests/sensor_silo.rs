//! The soft sensor on a discharging silo (issue 9; model.md 7.6, 8): `sieve record` of the
//! coupled `silo` scene (the truth is the coupled run; frames are its velocity at every frame
//! time), replayed by the f32 estimator, whose walls carry the silo's orifice as an opening
//! and whose c is carried with the measured flow.
//!
//! A short, coarse silo so that it runs in seconds: 15 x 50 truth (~10 mm cells), orifice
//! 0.04 m (it drains from the start on this grid since the outlet's `p = 0` sits on the
//! orifice face, docs/silo.md section 4), 1.5 s at 10 Hz (55 % out), 5 % noise, estimator
//! 8 x 28, sensor 2 x 7 (4x coarser). Measured (2026-12-04): outflow fines fraction over 1 s
//! windows within 0.014 of the truth's over the 14 windows in which the estimator let
//! something out (the first, before a moving frame arrives, is silent), fines fraction of all
//! that left 0.499 against 0.487, no cell with phi outside [0, c]; the estimator lets out 66 %
//! of what the truth discharges (its 2 x 7 sensor averages the orifice jet with the slow bed
//! beside it) and its carried c drifts from the truth's by up to 0.26 (mean 0.064).

use sieve::soft_sensor::{
    record_scene, replay_bytes, replay_bytes_with, ReplayOptions, SceneRecordOptions,
};

/// The short silo's recording (its checks below run once): `sieve record` of a coupled run is
/// the slow part of these tests, so the replays here and in sensor_kinematic.rs share it.
pub fn coarse_silo() -> &'static [u8] {
    static RECORDING: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
    RECORDING.get_or_init(record_coarse_silo)
}

/// The recording options of these tests: 5 % noise, seed 1, a 168 MHz Cortex-M4F's budget.
fn silo_options(
    estimator_cells: [u16; 2],
    sensor: [u8; 2],
    period: f64,
    frames: Option<u32>,
) -> SceneRecordOptions {
    SceneRecordOptions {
        estimator_cells,
        sensor,
        noise: 0.05,
        seed: 1,
        period: Some(period),
        frames,
        cpu_hz: sieve::soft_sensor::DEFAULT_CPU_HZ,
        cpu_share: 1.0,
    }
}

fn record_coarse_silo() -> Vec<u8> {
    let sets: Vec<String> = [
        "grid.cells=[15,50]",
        "boundary.flow.z_low.outlet.width=0.04",
        "run.t_end=1.5",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let (scene, fields) = sieve::scene::load("silo", &sets).expect("scene");
    let opts = silo_options([8, 28], [2, 7], 0.1, None);
    let (bytes, report) = record_scene(&scene, &fields, &opts).expect("record");
    assert_eq!(report.record.frames, 15);
    // The budget is a 168 MHz Cortex-M4F's at 10 Hz (it affords far more substeps than the
    // fastest frame needs), and the estimator starts from the silo's bed (c 0.6 to 0.4 m).
    assert!(report
        .notes
        .iter()
        .any(|n| n.contains("filled to 0.4000 m")));
    assert!((report.c - 0.6).abs() < 1e-12);
    // and it is told that 2 points across cannot follow the fines-rich end of a discharge
    assert!(
        report
            .notes
            .iter()
            .any(|n| n.contains("2 sensor points across the outlet's wall")),
        "{:?}",
        report.notes
    );
    bytes
}

/// The recorder's 1-2-1 pass: none across an outlet narrower than 3 sensor spacings (the
/// 0.04 m orifice on 8 points across the 0.145 m silo spans 2.2), one across a 0.06 m orifice
/// (3.3): docs/soft-sensor.md "Sensor grid, filter and gain on the silo".
#[test]
fn no_filter_pass_across_a_narrow_outlet() {
    for (width, says) in [
        ("0.04", Some("the outlet spans 2.2 sensor spacings")),
        ("0.06", None),
    ] {
        let sets = [
            "grid.cells=[15,50]".to_string(),
            format!("boundary.flow.z_low.outlet.width={width}"),
        ];
        let (scene, fields) = sieve::scene::load("silo", &sets).expect("scene");
        let opts = silo_options([16, 28], [8, 14], 0.05, Some(3));
        let (bytes, report) = record_scene(&scene, &fields, &opts).expect("record");
        let note = report.notes.iter().find(|n| n.contains("no 1-2-1 pass"));
        match says {
            Some(s) => assert!(note.is_some_and(|n| n.contains(s)), "{:?}", report.notes),
            None => assert!(note.is_none(), "{:?}", report.notes),
        }
        // the recording carries the choice: its configuration has the pass or not, and
        // replaying it with the other setting changes the estimate
        let mut recorded = None;
        let base = replay_bytes_with(&bytes, &ReplayOptions::default(), |c| {
            recorded = Some(c.spatial_passes);
            Ok(())
        })
        .expect("replay");
        let passes = u8::from(says.is_none());
        assert_eq!(recorded, Some(passes), "{width}");
        let other = replay_bytes_with(&bytes, &ReplayOptions::default(), |c| {
            c.spatial_passes = 1 - passes;
            Ok(())
        })
        .expect("replay");
        assert_ne!(other.final_state_hash, base.final_state_hash, "{width}");
    }
}

#[test]
fn outlet_fines_fraction_of_a_discharging_silo() {
    let bytes = coarse_silo();
    let r = replay_bytes(bytes, &ReplayOptions::default()).expect("replay");
    let o = r.outflow.as_ref().expect("the truth discharged");
    println!(
        "outflow fines error max {:.5} mean {:.5} over {} windows of {} ticks; total fines est {:.5} truth {:.5}; out est {:.4e} truth {:.4e}; c error max {:.4} mean {:.4}; psi error {:.5}; budget limited {}",
        o.max_window_error,
        o.mean_window_error,
        o.windows,
        o.window,
        o.total_fines[0],
        o.total_fines[1],
        o.total_out[0],
        o.total_out[1],
        r.max_c_error,
        r.mean_c_error,
        r.max_psi_error,
        r.counters.budget_limited
    );
    // Issue 9's goal: the outlet fines fraction within 0.05 over the whole discharge. The
    // truth drains from its first steps (since the outlet's p = 0 sits on the orifice face),
    // before the first frame that moves reaches the estimator: in that first window the
    // estimator lets nothing out, its fraction is undefined and counts as 0 (an error of the
    // truth's whole fraction, ~0.5), so the goal is asserted over the windows that flow.
    println!(
        "silent windows {}, largest error over the others {:.5}",
        o.silent_windows, o.max_window_error_flowing
    );
    assert!(o.windows >= 14, "{}", o.windows);
    assert!(o.silent_windows <= 1, "{}", o.silent_windows);
    assert!(
        o.max_window_error_flowing < 0.05,
        "{}",
        o.max_window_error_flowing
    );
    assert!(
        (o.total_fines[0] - o.total_fines[1]).abs() < 0.02,
        "{:?}",
        o.total_fines
    );
    // Both discharged, and a mixed bed's discharge is close to its fines fraction 1/2.
    assert!(o.total_out[0] > 0.0 && o.total_out[1] > 0.0);
    // The packing cap vents at the orifice (docs/soft-sensor.md, step 0 of the cap): the
    // 2 x 7 sensor measures the jet too slow and too wide, and the excess that piled up above
    // the orifice used to go back into the bed. Measured: 64.4 % of the truth's grains out
    // since coupled recordings have no moving average and no 1-2-1 pass on a sensor under
    // 8 points across (55.7 % with them, 26 % when the cap sent the excess into the bed).
    assert!(
        o.total_out[0] > 0.6 * o.total_out[1],
        "estimator let out {:e} of the truth's {:e}",
        o.total_out[0],
        o.total_out[1]
    );
    assert!((o.total_fines[1] - 0.5).abs() < 0.05, "{:?}", o.total_fines);
    // What left is booked: the estimator's fines in the bed and out of it close to f32
    // round-off while its bed drains.
    println!(
        "mass drift {:e}, unbooked {:e}",
        r.mass_drift, r.mass_unbooked
    );
    assert!(r.mass_drift < -0.1, "{}", r.mass_drift);
    assert!(r.mass_unbooked.abs() < 5e-6, "{}", r.mass_unbooked);
    // Bounds by construction, nothing held back by the budget.
    assert_eq!(r.counters.phi_excursions, 0);
    assert_eq!(r.counters.budget_limited, 0);
    // The carried c follows the measured flow; how far it drifts is reported, and bounded
    // here at what was measured with some room (0.041 mean).
    assert!(r.mean_c_error < 0.1, "{}", r.mean_c_error);
    // The replay is deterministic.
    let again = replay_bytes(bytes, &ReplayOptions::default()).expect("replay");
    assert_eq!(again.final_state_hash, r.final_state_hash);
}
