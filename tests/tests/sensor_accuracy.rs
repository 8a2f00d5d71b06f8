//! Soft sensor against an independent truth (issue 4 item 9, issue 10): the exact solutions of
//! the two recorder scenes, not a run of the segregation solver the sensor itself is made of.
//!
//! Both recorder scenes have constant c (0.64) and a uniform shear, so T, and with it the
//! segregation speed |S| = S0 sqrt(T) |g|, is uniform (the recorder picks S0 so that |S| is
//! the value of model.md 7.3 / 7.2), and the segregation equation of model.md 3 reduces to the
//! Gray-Thornton equation `d_t q + u d_x q - d_z (S q (1 - q)) = 0` for `q = phihat`, whose
//! solutions from a uniform state are shocks (Gray & Thornton 2005; model.md 7.1a, 7.2):
//!
//! * idealised shear cell (7.3; 0.025 m, walls in z, periodic in x, |S| = 0.025 m/s, q0 = 1/2):
//!   the column of 7.1a: pure small grains rise from the floor behind a shock at speed
//!   `S q0`, pure large grains sink from the lid behind one at `S (1 - q0)`; they meet at
//!   `t = L/S = 1 s` and leave the interface at `q0 L`. Psi = max(0, 1 - S t / L).
//! * Gray-Thornton simple shear (7.2; x in [0, 2], z in [0, 1], u = 2 z, |S| = 0.5, inflow and
//!   start q0 = 0.6): each shock is a surface moving with velocity (u(Z), s), i.e.
//!   `Z_t + 2 Z Z_x = s`, from the initial state (Z = s t) and from the inlet corner (the steady
//!   Gray-Thornton shock `Z^2 = s x`): `Z_bottom = min(0.3 t, sqrt(0.3 x))` and
//!   `Z_top = max(1 - 0.2 t, sqrt(1 - 0.2 x))`; they meet at the outlet x = 2 at the height
//!   sqrt(0.6). Psi is the exact entropy of the mixed band over that of the mixed state with the
//!   same amounts (model.md 6, E_seg = 0).
//!
//! Every constant of the exact solutions is written here from model.md; nothing is taken from
//! the solver. The error measures: max over ticks of |psi_est - psi_exact| (psi_exact: model.md 6
//! on the exact cell averages of the estimator grid, the best state a grid can hold), and the
//! mean over ticks of the mean over estimator cells of |phihat_est - exact cell average|.
//! The table of docs/soft-sensor.md ("Accuracy") is read back and every cell asserted.

use crate::readme;

use sieve::soft_sensor::{record_to_bytes, RecordOptions, Scene, ESTIMATOR_CAPACITY};
use sieve_core::diagnostics::mixing_entropy_density;
use sieve_core::sensor::feeder::{feed_bytes, Faults, Feeder};
use sieve_core::sensor::frame::FRAME_WIRE_MAX;
use sieve_core::sensor::recording::Recording;
use sieve_core::sensor::{Counters, FrameDecoder, SoftSensor};

/// Volume fraction of both recorder scenes (model.md 7.3; 7.2 uses a constant c as well).
const C: f64 = 0.64;

/// The exact solution of a recorder scene, from model.md alone.
#[derive(Clone, Copy)]
enum Exact {
    /// Box height L [m], segregation speed |S| [m/s], initial phihat q0.
    Column { l: f64, s: f64, q0: f64 },
    /// Gray-Thornton simple shear u = gamma z on [0, lx] x [0, 1], |S|, inflow/initial q0.
    Shear {
        lx: f64,
        gamma: f64,
        s: f64,
        q0: f64,
    },
}

impl Exact {
    fn of(scene: Scene) -> Self {
        match scene {
            // model.md 7.3: 0.025 m box, |S| = 0.025 m/s; the recorder starts mixed (1/2)
            Scene::ShearCell => Exact::Column {
                l: 0.025,
                s: 0.025,
                q0: 0.5,
            },
            // model.md 7.2: h = 1, u = 2 z, inflow phi = 0.6 c; recorder: x in [0, 2], |S| = 0.5
            Scene::GrayThornton => Exact::Shear {
                lx: 2.0,
                gamma: 2.0,
                s: 0.5,
                q0: 0.6,
            },
        }
    }

    /// Heights of the lower (pure small below) and upper (pure large above) shocks at `x`, `t`.
    fn shocks(self, x: f64, t: f64) -> (f64, f64, f64) {
        match self {
            Exact::Column { l, s, q0 } => {
                let (lo, hi) = (s * q0 * t, l - s * (1.0 - q0) * t);
                if lo < hi {
                    (lo, hi, q0)
                } else {
                    (q0 * l, q0 * l, q0)
                }
            }
            Exact::Shear { gamma, s, q0, .. } => {
                let (sb, st) = (s * q0, s * (1.0 - q0));
                // Z Z_x gamma = s for the steady branch: Z^2 = 2 s x / gamma
                let lo = (sb * t).min((2.0 * sb * x / gamma).sqrt());
                let hi = (1.0 - st * t).max((1.0 - 2.0 * st * x / gamma).max(0.0).sqrt());
                (lo, hi.max(lo), q0)
            }
        }
    }

    /// Cell average of phihat over [x0, x1] x [z0, z1]: exact in z, `nxs` midpoints in x.
    fn cell_average(self, x: [f64; 2], z: [f64; 2], t: f64, nxs: usize) -> f64 {
        let mut sum = 0.0;
        for k in 0..nxs {
            let xm = x[0] + (k as f64 + 0.5) * (x[1] - x[0]) / nxs as f64;
            let (lo, hi, q0) = self.shocks(xm, t);
            let overlap = |a: f64, b: f64| (b.min(z[1]) - a.max(z[0])).max(0.0);
            sum += overlap(f64::MIN, lo) + q0 * overlap(lo, hi);
        }
        sum / nxs as f64 / (z[1] - z[0])
    }

    /// Psi of the exact solution: E / E_mix with E = c e(q0) (area of the mixed band) and E_mix
    /// of the same amounts mixed (model.md 6).
    fn psi(self, t: f64) -> f64 {
        let (lx, lz) = match self {
            Exact::Column { l, .. } => (1.0, l),
            Exact::Shear { lx, .. } => (lx, 1.0),
        };
        let n = 20_000;
        let (mut band, mut small) = (0.0, 0.0);
        for k in 0..n {
            let x = (k as f64 + 0.5) * lx / n as f64;
            let (lo, hi, q0) = self.shocks(x, t);
            band += (hi - lo) * lx / n as f64;
            small += (lo + q0 * (hi - lo)) * lx / n as f64;
        }
        let q0 = match self {
            Exact::Column { q0, .. } | Exact::Shear { q0, .. } => q0,
        };
        let area = lx * lz;
        let e = C * mixing_entropy_density(q0) * band;
        let e_mix = C * mixing_entropy_density(small / area) * area;
        e / e_mix
    }

    fn extent(self) -> [f64; 2] {
        match self {
            Exact::Column { l, .. } => [l, l],
            Exact::Shear { lx, .. } => [lx, 1.0],
        }
    }
}

struct Accuracy {
    max_psi_error: f64,
    mean_l1: f64,
    ticks: usize,
    first_psi_exact: f64,
    last_psi_exact: f64,
    counters: Counters,
    mass_drift: f64,
}

/// Records the scene's noisy frames (the recorder's truth run is not used) and runs the
/// firmware's loop over them (as `sieve replay` does), comparing every tick with the exact
/// solution at the estimator's own time.
fn run(scene: Scene, estimator: [u16; 2], sensor: [u8; 2], noise: f64) -> Accuracy {
    let opts = RecordOptions {
        sensor,
        noise,
        // the recorder's own truth run is ignored here: keep it small
        truth_cells: [16, 16],
        estimator_cells: estimator,
        ..RecordOptions::new(scene)
    };
    let (bytes, _) = record_to_bytes(&opts).expect("record");
    let rec = Recording::parse(&bytes).expect("recording");
    let mut est: Box<SoftSensor<f32, ESTIMATOR_CAPACITY>> = Box::default();
    // The table measures the estimator against the exact solutions with 4 substeps a tick
    // (what it was written with): a 168 MHz Cortex-M4F at these 100 Hz frames affords only 1
    // with the 16 x 16 sensor (its decoding eats the budget, docs/soft-sensor.md "Cycle
    // budget"), which would measure the budget, not the accuracy.
    let mut cfg = rec.header.config.clone();
    cfg.budget = sieve_core::sensor::CycleBudget::for_substeps(4, cfg.cell_count());
    est.configure(&cfg).expect("configuration");
    let mut decoder: Box<FrameDecoder<FRAME_WIRE_MAX>> = Box::default();
    let mut feeder = Box::new(Feeder::new(rec.stream, Faults::default()));
    let exact = Exact::of(scene);
    let [lx, lz] = exact.extent();
    let (nx, nz) = (estimator[0] as usize, estimator[1] as usize);
    let (hx, hz) = (lx / nx as f64, lz / nz as f64);
    let mass = |s: &SoftSensor<f32, ESTIMATOR_CAPACITY>| -> f64 {
        let g = s.segregation();
        (0..g.len()).map(|i| g.phi(i) as f64).sum()
    };
    let mass0 = mass(&est);
    let mut a = Accuracy {
        max_psi_error: 0.0,
        mean_l1: 0.0,
        ticks: 0,
        first_psi_exact: f64::NAN,
        last_psi_exact: f64::NAN,
        counters: Counters::default(),
        mass_drift: 0.0,
    };
    while !feeder.done() {
        feeder.tick(|chunk| feed_bytes(&mut *est, &mut *decoder, chunk));
        let e = est.finish_tick();
        let t = e.time as f64;
        // the exact solution projected onto the estimator grid (cell averages): the best a
        // 32 x 32 state can hold; its Psi is that of model.md 6 on these cells
        let mut l1 = 0.0;
        let (mut ent, mut small) = (0.0, 0.0);
        for iz in 0..nz {
            for ix in 0..nx {
                let x = [ix as f64 * hx, (ix + 1) as f64 * hx];
                let z = [iz as f64 * hz, (iz + 1) as f64 * hz];
                let q = exact.cell_average(x, z, t, 8);
                l1 += (est.phihat(ix + nx * iz) as f64 - q).abs();
                ent += mixing_entropy_density(q);
                small += q;
            }
        }
        let cells = (nx * nz) as f64;
        let psi = ent / (mixing_entropy_density(small / cells) * cells);
        a.max_psi_error = a.max_psi_error.max((e.psi as f64 - psi).abs());
        a.mean_l1 += l1 / (nx * nz) as f64;
        if a.ticks == 0 {
            a.first_psi_exact = psi;
        }
        a.last_psi_exact = psi;
        a.ticks += 1;
    }
    a.mean_l1 /= a.ticks.max(1) as f64;
    a.counters = *est.counters();
    a.mass_drift = (mass(&est) - mass0) / mass0;
    a
}

/// The exact solutions themselves: the column's Psi = 1 - t, mass of the small grains and the
/// Gray-Thornton steady shocks (model.md 7.2: they meet at the outlet at z = sqrt(0.6)).
#[test]
fn exact_solutions_are_what_model_md_says() {
    let col = Exact::of(Scene::ShearCell);
    for t in [0.0f64, 0.25, 0.5, 0.9, 1.0, 1.4] {
        let want = (1.0 - t).max(0.0);
        assert!((col.psi(t) - want).abs() < 1e-12, "{t}: {}", col.psi(t));
        // small-grain mass of the column stays q0 L (cell averages over 32 rows)
        let m: f64 = (0..32)
            .map(|k| {
                let h = 0.025 / 32.0;
                col.cell_average([0.0, 1.0], [k as f64 * h, (k + 1) as f64 * h], t, 1) * h
            })
            .sum();
        assert!((m - 0.5 * 0.025).abs() < 1e-15, "{t}: {m}");
    }
    let gt = Exact::of(Scene::GrayThornton);
    let (lo, hi, _) = gt.shocks(2.0, 100.0);
    assert!((lo - 0.6f64.sqrt()).abs() < 1e-15 && (hi - lo).abs() < 1e-15);
    // before the inlet's influence arrives, a column of 7.1a (shocks at 0.3 t and 1 - 0.2 t)
    let (lo, hi, _) = gt.shocks(1.9, 1.0);
    assert!(
        (lo - 0.3).abs() < 1e-15 && (hi - 0.8).abs() < 1e-15,
        "{lo} {hi}"
    );
    assert!((gt.psi(0.0) - 1.0).abs() < 1e-12);
}

/// Formats a docs table cell: max |psi error| (mean L1 of phihat).
fn cell(a: &Accuracy) -> String {
    format!("{:.4} ({:.4})", a.max_psi_error, a.mean_l1)
}

/// The table of docs/soft-sensor.md, "Accuracy": 32 x 32 estimator, sensor 16 x 16 / 8 x 8 /
/// 4 x 4 (2x / 4x / 8x coarser), noise 0, 2, 5, 10 % of the top speed, both recorder scenes:
/// every cell (max |psi error| and mean L1) is computed here and asserted to round to the
/// number the document states. Against the exact solution the requirement of issue 4 (4x
/// coarser, 5 % noise: psi within 0.05) is met on the shear cell (0.0495) and missed on
/// Gray-Thornton (0.0550 with the packing cap; 0.0515 carried without it, 0.0557 before c was
/// carried), mostly by the estimator
/// grid's own error (noise-free 0.042 / 0.041); what noise and the coarse sensor add is
/// asserted below 0.02 and to the numbers the document states.
#[test]
fn accuracy_table_of_docs_against_the_exact_solutions() {
    let doc = readme::soft_sensor_doc();
    let table = readme::after(doc, "## Accuracy");
    let scenes = [
        (Scene::ShearCell, "shear cell"),
        (Scene::GrayThornton, "Gray-Thornton shear"),
    ];
    let noises = [0.0, 0.02, 0.05, 0.10];
    let sensors = [16u8, 8, 4];
    // every cell first, then the table as it should read, then the asserts
    let mut results = Vec::new();
    for (scene, label) in scenes {
        for noise in noises {
            let key = format!("{label}, {} %", (noise * 100.0f64).round());
            let cells: Vec<Accuracy> = sensors
                .iter()
                .map(|&s| run(scene, [32, 32], [s, s], noise))
                .collect();
            results.push((scene, noise, key, cells));
        }
    }
    let prose = readme::stated(table, "sensor add", "(Gray-Thornton)", 2);
    for (_, _, key, cells) in &results {
        let line: Vec<String> = cells.iter().map(cell).collect();
        println!("| {key} | {} |", line.join(" | "));
    }
    for (scene, noise, key, cells) in &results {
        let row = readme::table_row(table, &format!("{key} |"));
        let stated = readme::numbers(readme::after(row, " % |"));
        assert_eq!(stated.len(), 6, "{row}");
        for (k, (s, a)) in sensors.iter().zip(cells).enumerate() {
            let name = format!("{key}, sensor {s}x{s}");
            readme::check(
                &format!("{name}: max psi error"),
                a.max_psi_error,
                &stated[2 * k],
            );
            readme::check(&format!("{name}: mean L1"), a.mean_l1, &stated[2 * k + 1]);
            // mass: nothing clamps phi; the shear cell is a closed box (f32 round-off)
            if *scene == Scene::ShearCell {
                assert!(a.mass_drift.abs() < 1e-5, "{name}: mass {}", a.mass_drift);
            }
            assert_eq!(a.counters.budget_limited, 0, "{name}");
            // the share of noise and sensor resolution: against the noise-free estimator
            let clean = &results
                .iter()
                .find(|r| r.0 == *scene && r.1 == 0.0)
                .unwrap()
                .3[k];
            let added = a.max_psi_error - clean.max_psi_error;
            if *s == 8 && *noise <= 0.05 {
                assert!(added < 0.02, "{name}: noise adds {added}");
            }
            if *s == 8 && *noise == 0.05 {
                let which = if *scene == Scene::ShearCell { 0 } else { 1 };
                readme::check(&format!("{name}: added by noise"), added, &prose[which]);
                let frames = match scene {
                    Scene::ShearCell => 150,
                    Scene::GrayThornton => 300,
                };
                assert_eq!((a.ticks, a.counters.accepted), (frames, frames as u32));
                // the run really segregates (exact Psi at the first and last tick)
                assert!(a.first_psi_exact > 0.98, "{}", a.first_psi_exact);
                assert!(a.last_psi_exact < 0.8, "{}", a.last_psi_exact);
            }
        }
    }
}
