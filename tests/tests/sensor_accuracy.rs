//! Soft sensor against a truth simulation (issue 4, item 9): the same core solver on the truth
//! grid with the exact velocity; the sensor sees a coarser, noisy velocity field.

use sieve::soft_sensor::{record_to_bytes, replay_bytes, RecordOptions, ReplayOptions, Scene};

fn run(
    scene: Scene,
    sensor: [u8; 2],
    noise: f64,
    truth: [u16; 2],
) -> sieve::soft_sensor::ReplayReport {
    let opts = RecordOptions {
        sensor,
        noise,
        truth_cells: truth,
        estimator_cells: truth,
        ..RecordOptions::new(scene)
    };
    let (bytes, _) = record_to_bytes(&opts).expect("record");
    replay_bytes(&bytes, &ReplayOptions::default()).expect("replay")
}

#[test]
fn shear_cell_4x_coarser_5pct_noise_psi_within_005() {
    let r = run(Scene::ShearCell, [8, 8], 0.05, [32, 32]);
    let first = &r.rows[0];
    let last = r.rows.last().unwrap();
    println!(
        "shear cell: max psi err {:.4}, mean L1 {:.4}, psi {:.3} -> {:.3} (truth {:.3})",
        r.max_psi_error, r.mean_l1, first.psi, last.psi, last.psi_truth
    );
    assert_eq!(r.rows.len(), 150);
    // The run really segregates: psi falls from about 1 to well below 0.5.
    assert!(
        first.psi_truth > 0.9 && last.psi_truth < 0.4,
        "{first:?} {last:?}"
    );
    assert!(r.max_psi_error < 0.05, "max psi error {}", r.max_psi_error);
    assert!(r.mean_l1 < 0.1, "mean L1 {}", r.mean_l1);
    assert_eq!(r.counters.accepted, 150);
    // Noise makes the measured flow slightly compressive, so phi leaves [0, c] a little in
    // places; nothing clamps it, so the mass is conserved to f32 round-off (the truth
    // conserves it exactly).
    println!(
        "mass drift {:e}, phi excursions {}",
        r.mass_drift, r.counters.phi_excursions
    );
    assert!(r.mass_drift.abs() < 1e-5, "mass drift {}", r.mass_drift);
    assert_eq!(r.counters.budget_limited, 0);
}

#[test]
fn gray_thornton_4x_coarser_5pct_noise_psi_within_005() {
    let r = run(Scene::GrayThornton, [8, 8], 0.05, [32, 32]);
    let last = r.rows.last().unwrap();
    println!(
        "gray-thornton: max psi err {:.4}, mean L1 {:.4}, final psi {:.3} (truth {:.3}), outlet {:?}",
        r.max_psi_error, r.mean_l1, last.psi, last.psi_truth, last.regions
    );
    assert_eq!(r.rows.len(), 300);
    assert!(last.psi_truth < 0.8, "{last:?}");
    assert!(r.max_psi_error < 0.05, "max psi error {}", r.max_psi_error);
    assert!(r.mean_l1 < 0.1, "mean L1 {}", r.mean_l1);
}

/// The README table: max |psi error| over the run against noise and sensor resolution.
/// Truth and estimator grids 32 x 32 (sensor 16, 8, 4 points per side = 2x, 4x, 8x coarser)
/// and 16 x 16 (sensor 16, 8, 4 = 1x, 2x, 4x coarser). Run with `--nocapture` to see it.
#[test]
fn accuracy_table() {
    for scene in [Scene::ShearCell, Scene::GrayThornton] {
        for truth in [[16u16, 16], [32, 32]] {
            println!(
                "\n{} truth/estimator {}x{}: max |psi error| (mean L1 phihat)",
                scene.name(),
                truth[0],
                truth[1]
            );
            println!("{:>8} {:>18} {:>18} {:>18}", "noise", "16x16", "8x8", "4x4");
            for noise in [0.0, 0.02, 0.05, 0.10] {
                let mut line = format!("{:>7.0}%", noise * 100.0);
                for s in [16u8, 8, 4] {
                    let r = run(scene, [s, s], noise, truth);
                    line += &format!("  {:>7.4} ({:.4})", r.max_psi_error, r.mean_l1);
                    if noise <= 0.05 && s == 8 && truth == [32, 32] {
                        assert!(r.max_psi_error < 0.05, "{} {s} {noise}", scene.name());
                    }
                }
                println!("{line}");
            }
        }
    }
}
