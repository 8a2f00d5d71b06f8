//! The soft sensor carries c with the same face mass fluxes that move phi (issue 9; model.md
//! 8): `Segregation::carry_own_velocity` on random, strongly compressive velocity fields keeps
//! `0 <= q <= c` exactly and conserves both phases up to what leaves the box; with the packing
//! cap it also keeps `c <= cap` exactly (and without it the same fields pile c far above);
//! the catalogue replay of `shear-cell-mixed` that used to count 2,008 cells outside `[0, c]`
//! (30 frames, the defaults of `sieve record`) counts none, and `gray-thornton-shear` replays
//! within the accuracy docs/soft-sensor.md states ("A packing cap on the carried c").

use sieve::soft_sensor::{record_scene, replay_bytes, ReplayOptions, SceneRecordOptions};
use sieve_core::boundary::Boundary;
use sieve_core::grid::Grid;
use sieve_core::sensor::feeder::SplitMix64;
use sieve_core::{
    DirectionMode, Phase, Real, Scheme, Segregation, SegregationConfig, TemperatureMode,
};

const N: usize = 1024;

fn uniform(rng: &mut SplitMix64) -> f64 {
    (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64
}

/// A 24 x 20 box with the given sides, random c in [0, 0.64] with empty cells, random
/// phihat with exact 0 and 1, and a random velocity of up to 1 m/s (far from
/// divergence-free), T from the shear and the direction from the flow as in the sensor.
fn solver<R: Real>(bc: [[Boundary; 2]; 2], phase: Phase, seed: u64) -> Box<Segregation<R, 2, N>> {
    let mut s: Box<Segregation<R, 2, N>> = Box::default();
    let grid = Grid::new(
        [24, 20],
        [R::ZERO; 2],
        [R::from_f64(0.12), R::from_f64(0.1)],
        N,
    )
    .unwrap();
    let cfg = SegregationConfig {
        scheme: Scheme::Modified,
        phase,
        s0: R::from_f64(0.2),
        gravity: [R::ZERO, R::from_f64(-9.81)],
        direction: DirectionMode::Flow,
        temperature: TemperatureMode::FromShear {
            heating: R::from_f64(1.5),
            eta0: R::from_f64(1.75e-3),
            eps0: R::from_f64(126.984),
        },
        diffusion: R::ZERO,
        courant: R::HALF,
        vacuum: R::VACUUM,
        flush_below: R::ZERO,
        compensated: true,
    };
    s.setup(grid, bc, cfg).unwrap();
    let mut rng = SplitMix64::new(seed);
    for i in 0..grid.len() {
        let c = match rng.next_u64() % 8 {
            0 => 0.0,
            1 => 0.64,
            _ => 0.64 * uniform(&mut rng),
        };
        let ph = match rng.next_u64() % 6 {
            0 => 0.0,
            1 => 1.0,
            _ => uniform(&mut rng),
        };
        let u = [2.0 * uniform(&mut rng) - 1.0, 2.0 * uniform(&mut rng) - 1.0];
        let (c, ph) = (R::from_f64(c), R::from_f64(ph));
        s.set_cell(
            i,
            c,
            R::ZERO,
            [R::from_f64(u[0]), R::from_f64(u[1])],
            (ph * c).min(c),
        );
        s.set_inflow(i, R::from_f64(0.3) * c);
    }
    s.prepare().unwrap();
    s
}

fn masses<R: Real>(s: &Segregation<R, 2, N>) -> [f64; 2] {
    let v = s.grid().cell_volume().to_f64();
    let mut m = [0.0; 2];
    for i in 0..s.len() {
        m[0] += s.c(i).to_f64() * v;
        m[1] += s.phi(i).to_f64() * v;
    }
    m
}

/// Steps percolation + carried transport (with the packing cap `cap` if given) and checks
/// bounds and mass after every step; returns the worst relative mass error and the largest c.
fn run<R: Real>(
    bc: [[Boundary; 2]; 2],
    phase: Phase,
    seed: u64,
    open: bool,
    cap: Option<f64>,
) -> (f64, f64) {
    let mut s = solver::<R>(bc, phase, seed);
    let cap_r = cap.map(R::from_f64);
    let mut c_max = 0.0f64;
    let m0 = masses(&*s);
    let mut out = [0.0f64; 2];
    let dt = s.stable_dt();
    let mut worst = 0.0f64;
    for _ in 0..60 {
        s.step_percolation(dt);
        let d = s.carry_own_velocity(dt, R::from_f64(0.3), cap_r, |axis, high, i| {
            // an orifice in the floor: x in [0.04, 0.08] (cells 8..16 of 24)
            let ix = i % 24;
            if open && axis == 1 && !high && (8..16).contains(&ix) {
                R::ONE
            } else {
                R::ZERO
            }
        });
        for a in 0..2 {
            for side in 0..2 {
                out[0] += d.total[a][side].to_f64();
                out[1] += d.small[a][side].to_f64();
            }
        }
        // only the round-off of the percolation stage is moved into the carry
        assert!(d.guarded.to_f64().abs() <= 1e-9, "{:?}", d.guarded);
        for i in 0..s.len() {
            let (q, c) = (s.tracked_fraction(i), s.c(i));
            assert!(q >= R::ZERO && q <= c, "cell {i}: q {q:?} c {c:?}");
            assert!(c.is_finite());
            if let Some(cap) = cap_r {
                assert!(c <= cap, "cell {i}: c {c:?} above the cap {cap:?}");
            }
            c_max = c_max.max(c.to_f64());
        }
        let m = masses(&*s);
        // The percolation flux crosses inflow and outflow sides too (their ghost states,
        // model.md 3.4), which the carried discharge does not book: there only the grains.
        let open_sides = bc
            .iter()
            .flatten()
            .any(|&b| b == Boundary::Inflow || b == Boundary::Outflow);
        for k in 0..if open_sides { 1 } else { 2 } {
            let e = (m[k] + out[k] - m0[k]).abs() / m0[k];
            worst = worst.max(e);
        }
    }
    (worst, c_max)
}

#[test]
fn carried_transport_keeps_bounds_exactly_and_conserves_mass() {
    use Boundary::*;
    let cases = [
        ([[Periodic, Periodic], [Wall, Wall]], false),
        ([[Wall, Wall], [Wall, Wall]], true),
        ([[Inflow, Outflow], [Wall, Wall]], false),
        ([[Outflow, Inflow], [Outflow, Wall]], true),
    ];
    for (k, (bc, open)) in cases.into_iter().enumerate() {
        for phase in [Phase::Small, Phase::Large] {
            let (e64, _) = run::<f64>(bc, phase, 11 + k as u64, open, None);
            let (e32, _) = run::<f32>(bc, phase, 11 + k as u64, open, None);
            println!("{bc:?} open={open} {phase:?}: mass error f64 {e64:.2e}, f32 {e32:.2e}");
            assert!(e64 < 1e-13, "{bc:?} {phase:?}: f64 {e64}");
            assert!(e32 < 2e-5, "{bc:?} {phase:?}: f32 {e32}");
        }
    }
}

/// The packing cap on the same random fields (c in [0, 0.64], velocities up to 1 m/s, far
/// from divergence-free): `c <= 0.64` in every cell after every step, exactly, in f64 and f32,
/// with `0 <= q <= c` and both phases conserved as without the cap; without the cap the same
/// runs pile c to well above it, so the assertion can fail.
#[test]
fn packing_cap_holds_exactly_and_conserves_mass() {
    use Boundary::*;
    let cap = 0.64;
    let cases = [
        ([[Periodic, Periodic], [Wall, Wall]], false),
        ([[Wall, Wall], [Wall, Wall]], true),
        ([[Inflow, Outflow], [Wall, Wall]], false),
        ([[Outflow, Inflow], [Outflow, Wall]], true),
    ];
    for (k, (bc, open)) in cases.into_iter().enumerate() {
        for phase in [Phase::Small, Phase::Large] {
            let seed = 31 + k as u64;
            let (e64, c64) = run::<f64>(bc, phase, seed, open, Some(cap));
            let (e32, c32) = run::<f32>(bc, phase, seed, open, Some(cap));
            let (_, free) = run::<f64>(bc, phase, seed, open, None);
            println!(
                "{bc:?} open={open} {phase:?}: capped mass error f64 {e64:.2e}, f32 {e32:.2e}; \
                 max c {c64} / {c32}; without the cap {free:.3}"
            );
            assert!(e64 < 1e-13, "{bc:?} {phase:?}: f64 {e64}");
            assert!(e32 < 2e-5, "{bc:?} {phase:?}: f32 {e32}");
            assert!(c64 <= cap && c32 <= cap as f32 as f64);
            assert!(
                free > 0.8,
                "{bc:?} {phase:?}: the fields do not compress ({free})"
            );
        }
    }
}

/// `sieve record shear-cell-mixed --frames 30` (5 % noise, 8 x 8 sensor, 32 x 32 estimator)
/// then `sieve replay`: 2,008 cell excursions before c was carried, none now; the estimate
/// stays as accurate as it was (max |psi error| 0.029 before, 0.028 carried and capped). The
/// bed sits at 0.64; the cap (5 % above) bounds c from above, the drift within stays 0.008.
#[test]
fn shear_cell_mixed_replay_has_no_phi_excursions() {
    let (scene, fields) = sieve::scene::load("shear-cell-mixed", &[]).expect("scene");
    let opts = SceneRecordOptions {
        frames: Some(30),
        ..SceneRecordOptions::default()
    };
    let (bytes, _) = record_scene(&scene, &fields, &opts).expect("record");
    let r = replay_bytes(&bytes, &ReplayOptions::default()).expect("replay");
    println!(
        "excursions {}, max psi error {}, max c error {}",
        r.counters.phi_excursions, r.max_psi_error, r.max_c_error
    );
    assert_eq!(r.counters.phi_excursions, 0);
    assert!(r.max_psi_error < 0.03, "{}", r.max_psi_error);
    // The truth's c is uniform (0.64); the carried c follows the noisy measured flow.
    assert!(r.max_c_error < 0.02, "{}", r.max_c_error);
    assert!(r.mass_drift.abs() < 1e-6, "{}", r.mass_drift);
}

/// `sieve record gray-thornton-shear` (defaults: 200 x 100 truth, 32 x 32 estimator, 8 x 8
/// sensor, 5 % noise, 534 frames over 8 s) then `sieve replay`, with the packing cap: max |psi
/// error| 0.0631 (0.083 carried without the cap), mean L1 of phihat 0.0140 (0.0306), carried c
/// against the truth's max 0.132 / mean 0.031 (0.24 / 0.057). The same scene with the truth on
/// the estimator's 32 x 32 grid replays at 0.022 (0.0019 without noise; 0.044 against the
/// 200 x 100 truth without noise): the rest of the gap to 0.05 is the first-order
/// 32 x 32 estimator against a fine truth, not the sensor (docs/soft-sensor.md). Against the
/// 200 x 100 truth measured on the estimator's 32 x 32 cells (the recording's
/// `psi_estimator_grid`, format 6) the error is 0.0491: Psi of the Gray-Thornton shocks on
/// 3 cm cells is up to 0.014 above Psi on the truth's own cells, and no estimator on that
/// grid can see below it.
///
/// On the M4F's own clock (168 MHz): at the 66.7 Hz default frame rate the worst-case cost
/// model (docs/soft-sensor.md "Cycle budget") affords 2 substeps a tick, and since each
/// substep's transport and percolation take their own Courant limits (2026-12-07) no tick
/// needs more (before, 122 of 534 needed 3 and lagged; the accuracy was measured at twice
/// the clock).
#[test]
fn gray_thornton_shear_replays_within_the_stated_accuracy() {
    let replay = |sets: &[String], cpu_hz: f64| {
        let (scene, fields) = sieve::scene::load("gray-thornton-shear", sets).expect("scene");
        let opts = SceneRecordOptions {
            cpu_hz,
            ..Default::default()
        };
        let (bytes, _) = record_scene(&scene, &fields, &opts).expect("record");
        replay_bytes(&bytes, &ReplayOptions::default()).expect("replay")
    };
    let r = replay(&[], sieve::soft_sensor::DEFAULT_CPU_HZ);
    assert_eq!(r.counters.budget_limited, 0);
    assert_eq!(r.lag, 0.0);
    println!(
        "200x100 truth: max psi error {} ({} on the estimator's grid), mean L1 {}, c error {} / {}",
        r.max_psi_error, r.max_psi_error_estimator_grid, r.mean_l1, r.max_c_error, r.mean_c_error
    );
    assert_eq!(r.counters.phi_excursions, 0);
    assert!(r.max_psi_error < 0.068, "{}", r.max_psi_error);
    // issue 9's 0.05, at the resolution the estimator has
    assert!(
        r.max_psi_error_estimator_grid < 0.05,
        "{}",
        r.max_psi_error_estimator_grid
    );
    assert!(r.max_psi_error_estimator_grid < r.max_psi_error - 0.01);
    // the truth's Psi on the estimator's cells is never below its Psi on its own cells
    for row in &r.rows {
        assert!(
            row.psi_truth_estimator_grid >= row.psi_truth - 1e-6,
            "t = {}: {} < {}",
            row.time,
            row.psi_truth_estimator_grid,
            row.psi_truth
        );
    }
    assert!(r.mean_l1 < 0.016, "{}", r.mean_l1);
    // the box exchanges fines through its inflow and outflow sides (19 % more by the end),
    // and the estimator's books close its mass to f32 round-off (measured -6.3e-7)
    assert!(r.mass_drift > 0.1, "{}", r.mass_drift);
    assert!(r.mass_unbooked.abs() < 5e-6, "{}", r.mass_unbooked);
    assert!(r.max_c_error < 0.15, "{}", r.max_c_error);
    assert!(r.mean_c_error < 0.035, "{}", r.mean_c_error);
    let coarse = replay(
        &["grid.cells=[32,32]".to_string()],
        sieve::soft_sensor::DEFAULT_CPU_HZ,
    );
    println!("32x32 truth: max psi error {}", coarse.max_psi_error);
    assert!(coarse.max_psi_error < 0.03, "{}", coarse.max_psi_error);
}
