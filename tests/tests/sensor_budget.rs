//! The soft sensor's cycle budget and its fines alarms (issue 9, "The soft sensor on the
//! silo"): the substep cap is the cost model's `floor((cycles - fixed) / substep)`, exact in
//! integers; a tick takes what the stable step asks for up to that cap; the budget of a
//! 168 MHz Cortex-M4F at 10 Hz lets `shear-cell-mixed` (16 x 16 sensor, 5 % noise) keep up
//! where the old cap of 4 substeps fell 1.7 s behind; the fines alarms latch with persistence
//! and hysteresis, and the off-spec prediction extrapolates the outflow fraction's trend.

use sieve::soft_sensor::{
    cpu_budget, record_scene, replay_bytes, replay_bytes_with, ReplayOptions, Scene,
    SceneRecordOptions, DEFAULT_CPU_HZ,
};
use sieve_core::sensor::{alarm, health, CycleBudget, SoftSensor, VelocityFrame};

const N: usize = 1024;

/// The cap by hand: 32 x 32 estimator, 16 x 16 sensor, 168 MHz at 10 Hz.
#[test]
fn cap_is_the_cost_model_floor() {
    const G: [usize; 2] = [32, 32];
    let b = CycleBudget::CORTEX_M4F.with_clock(168e6, 0.1, 1.0);
    assert_eq!(b.cycles, 16_800_000);
    // per tick + per cell + per point; per substep + per cell + per boundary face (2 (32 + 32)).
    let fixed = 4_000 + 580 * 1024 + 1520 * 256;
    let substep = 1_000 + 575 * 1024 + 310 * 128;
    assert_eq!(b.fixed(G, 256), fixed);
    assert_eq!(b.substep(G), substep);
    // (16,800,000 - 987,040) / 629,480 = 25.12
    assert_eq!(b.substeps(G, 256), 25);
    // Exactly k substeps' worth gives k; one cycle less gives k - 1.
    for k in [1u64, 2, 7, 25] {
        let exact = CycleBudget {
            cycles: (fixed + k * substep) as u32,
            ..b
        };
        assert_eq!(exact.substeps(G, 256), k as u16);
        let short = CycleBudget {
            cycles: exact.cycles - 1,
            ..b
        };
        assert_eq!(short.substeps(G, 256), k as u16 - 1);
    }
    // A burst of 3 frames pays for 2 more decodes out of the substeps.
    assert_eq!(
        b.substeps_frames(G, 256, 3),
        ((16_800_000 - 4_000 - 580 * 1024 - 3 * 1520 * 256) / substep) as u16
    );
    // The same cells in a long thin estimator cost more: more boundary faces per substep.
    assert_eq!(b.substep([8, 128]), 1_000 + 575 * 1024 + 310 * 272);
    assert!(b.substeps([8, 128], 256) < b.substeps(G, 256));
    // Nothing left after the fixed part: no substep, and the configuration is refused.
    let starved = CycleBudget {
        cycles: fixed as u32,
        ..b
    };
    assert_eq!(starved.substeps(G, 256), 0);
    let mut cfg = Scene::ShearCell.sensor_config([32, 32], [16, 16], 0.05, 0.1, starved);
    assert!(cfg.validate(N).is_err());
    cfg.budget = b;
    assert_eq!(cfg.substep_cap(), 25);
    cfg.validate(N).unwrap();
    // The host's helper is the same model: the firmware recording's 100 Hz budget affords
    // the one substep its ticks need.
    assert_eq!(cpu_budget(DEFAULT_CPU_HZ, 1.0, 0.01).cycles, 1_680_000);
    assert_eq!(cpu_budget(DEFAULT_CPU_HZ, 1.0, 0.01).substeps(G, 64), 1);
    assert_eq!(CycleBudget::for_substeps(3, 1024).substeps(G, 256), 3);
    // A hostile configuration's largest coefficients and grids saturate, never wrap (a
    // wrapped sum would read as a cheap tick) and never panic.
    let huge = CycleBudget {
        cycles: u32::MAX,
        per_tick: u32::MAX,
        per_cell: u32::MAX,
        per_point: u32::MAX,
        per_substep: u32::MAX,
        per_cell_substep: u32::MAX,
        per_face_substep: u32::MAX,
    };
    let g = [usize::from(u16::MAX); 2];
    assert_eq!(huge.fixed_frames(g, 255 * 255, u32::MAX), u64::MAX);
    assert_eq!(huge.substep([usize::MAX, usize::MAX]), u64::MAX);
    assert_eq!(huge.substeps_frames(g, 255 * 255, u32::MAX), 0);
}

/// The exact shear-cell velocity on an 8 x 8 sensor (divergence-free).
fn frame(seq: u32, period: f32) -> VelocityFrame {
    let mut f = VelocityFrame {
        seq,
        time: seq as f32 * period,
        period,
        nx: 8,
        nz: 8,
        u: Default::default(),
    };
    for iz in 0..8 {
        for _ in 0..8 {
            let z = (iz as f64 + 0.5) * 0.025 / 8.0;
            f.u.push((0.0007 + 0.0048 * z / 0.025) as f32).unwrap();
            f.u.push(0.0).unwrap();
        }
    }
    f
}

/// A tick takes ceil(dt / stable dt) substeps up to the cap, and the shortfall is lag.
#[test]
fn tick_takes_what_the_stable_step_asks_up_to_the_cap() {
    let period = 0.5f32;
    let run = |k: u16| {
        let cfg = Scene::ShearCell.sensor_config(
            [32, 32],
            [8, 8],
            0.0,
            period as f64,
            CycleBudget::for_substeps(k, 1024),
        );
        let mut s: Box<SoftSensor<f32, N>> = Box::default();
        s.configure(&cfg).unwrap();
        let e = s.tick(Some(&frame(1, period)));
        let sdt = s.stable_dt();
        (e, sdt, s.lag(), s.state_hash())
    };
    let (free, sdt, lag, h) = run(1000);
    let need = (period as f64 / sdt as f64).ceil() as u16;
    assert!(need > 2, "need {need}");
    assert_eq!(free.substeps, need);
    assert_eq!(free.health & health::BUDGET_LIMITED, 0);
    assert_eq!(lag, 0.0);
    // The same cap twice: the same bits (a model, not a clock).
    assert_eq!(run(1000).3, h);
    let (limited, sdt2, lag2, _) = run(2);
    assert_eq!(limited.substeps, 2);
    assert_ne!(limited.health & health::BUDGET_LIMITED, 0);
    assert_eq!(sdt2, sdt);
    assert_eq!(lag2, period - 2.0 * sdt);
}

fn shear_cell_mixed(cpu_hz: f64) -> Vec<u8> {
    let (scene, fields) = sieve::scene::load("shear-cell-mixed", &[]).expect("scene");
    let opts = SceneRecordOptions {
        estimator_cells: [32, 32],
        sensor: [16, 16],
        noise: 0.05,
        seed: 1,
        period: Some(0.1),
        frames: None,
        cpu_hz,
        cpu_share: 1.0,
    };
    record_scene(&scene, &fields, &opts).expect("record").0
}

/// Issue 9: at 10 Hz, 16 x 16 sensor, 5 % noise, the cap of 4 substeps fell 1.7 s behind;
/// the budget of a 168 MHz Cortex-M4F affords 25 and the sensor keeps up (measured when
/// written: 9 to 12 substeps a tick, lag 0, max psi error 0.074 against 0.084 with the cap
/// of 4, which also shifts the estimate 1.73 s behind the truth). Since each substep stage
/// keeps its own Courant limit (2026-12-07): at most 11 substeps, 0.0736; the cap of 4 lags
/// 1.57 s at 0.0722, so on this slowly segregating scene the lag is what the cap costs,
/// not the max psi error.
#[test]
fn m4f_budget_keeps_up_with_shear_cell_mixed_at_10_hz() {
    let fast = replay_bytes(&shear_cell_mixed(DEFAULT_CPU_HZ), &ReplayOptions::default()).unwrap();
    assert_eq!(fast.ticks, 30);
    assert_eq!(fast.counters.budget_limited, 0);
    assert_eq!(fast.lag, 0.0);
    let most = fast.rows.iter().map(|r| r.substeps).max().unwrap();
    assert!((5..=25).contains(&most), "{most}");
    assert!(fast.max_psi_error < 0.08, "{}", fast.max_psi_error);
    // 36 MHz affords (3,600,000 - 987,040) / 629,480 = 4 substeps: the old cap.
    let slow = replay_bytes(&shear_cell_mixed(36e6), &ReplayOptions::default()).unwrap();
    println!(
        "168 MHz: most {most}, psi error {}; 36 MHz: lag {}, psi error {}",
        fast.max_psi_error, slow.lag, slow.max_psi_error
    );
    assert!(slow.rows.iter().all(|r| r.substeps <= 4));
    assert_eq!(slow.counters.budget_limited, 30);
    assert!(slow.lag > 1.5, "{}", slow.lag);
    assert!(slow.max_psi_error < 0.08, "{}", slow.max_psi_error);
}

/// The alarms latch: with persistence p a band the fraction is far outside of raises the
/// alarm at the p-th tick with a fraction and keeps it; a band around the fraction never
/// alarms; the prediction is 0 while alarmed. Uses the short silo's outflow.
#[test]
fn fines_alarms_latch_with_persistence() {
    let (scene, fields) = sieve::scene::load(
        "silo",
        &[
            "grid.cells=[15,50]".to_string(),
            "boundary.flow.z_low.outlet.width=0.04".to_string(),
            "run.t_end=1.5".to_string(),
        ],
    )
    .expect("scene");
    let opts = SceneRecordOptions {
        estimator_cells: [8, 28],
        sensor: [2, 7],
        noise: 0.05,
        seed: 1,
        period: Some(0.1),
        frames: None,
        cpu_hz: DEFAULT_CPU_HZ,
        cpu_share: 1.0,
    };
    let bytes = record_scene(&scene, &fields, &opts).expect("record").0;
    let with = |band: [f32; 2], persist: u16| {
        replay_bytes_with(&bytes, &ReplayOptions::default(), |c| {
            c.fines_band = band;
            c.fines_hysteresis = 0.0;
            c.alarm_persist = persist;
            Ok(())
        })
        .unwrap()
    };
    let calm = with([0.3, 0.7], 1);
    assert!(calm.rows.iter().all(|r| r.alarms & alarm::FINES_HIGH == 0));
    assert!(calm.rows.iter().any(|r| r.outflow_fines_window > 0.0));
    // The silo's configuration names an outlet region (the cells above the orifice): before
    // anything left, the alarms watch its mean (about 1/2), then the window's outflow. Every
    // tick is above a band of [0, 0.1], so the alarm rises at the p-th tick.
    assert_eq!(calm.rows[0].tick, 0);
    for p in [1u16, 3] {
        let r = with([0.0, 0.1], p);
        let raised = r
            .rows
            .iter()
            .position(|r| r.alarms & alarm::FINES_HIGH != 0)
            .unwrap();
        assert_eq!(raised, p as usize - 1, "persist {p}");
        assert!(r.rows[raised..]
            .iter()
            .all(|r| r.alarms & alarm::FINES_HIGH != 0 && r.off_spec_in == 0.0));
        assert!(r.rows[..raised]
            .iter()
            .all(|r| r.alarms & (alarm::FINES_HIGH | alarm::FINES_LOW) == 0));
    }
    // The estimate itself does not depend on the band.
    assert_eq!(with([0.0, 0.1], 3).final_state_hash, calm.final_state_hash);
}
