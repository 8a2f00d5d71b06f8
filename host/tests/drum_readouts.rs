//! The drum readouts (host/src/drum.rs, issue 8) on a synthetic drum whose answers are known by
//! construction: in the lab, a bed below a surface tilted at 30 deg through the drum axis, a
//! flowing layer 8 mm thick sliding downhill, and below it grains turning rigidly
//! (counter-clockwise) about the eye C, which lies at the layer's foot: above C they move
//! downhill with the layer, below it uphill with the drum. Fines within 12 mm of C. The snapshots are written in the drum's
//! rotating frame (as the solver writes them) at 1 rev/s over one revolution, so the readouts
//! must undo the rotation to find C, the 30 deg, the 8 mm and the core.

use sieve::data::Snapshot;
use sieve::output::vtk::write_vti;
use std::f64::consts::{PI, TAU};

const ANGLE: f64 = 30.0;
const LAYER: f64 = 0.008;
/// The eye: 5 mm right of the axis, one layer thickness below the surface, in the lab.
const CENTRE: [f64; 2] = [
    0.005 + LAYER * 0.5, // x_s + LAYER sin 30
    0.005 * 0.577_350_269_189_625_8 - LAYER * 0.866_025_403_784_438_6, // z_s - LAYER cos 30
];
const CORE: f64 = 0.012;

struct Lab {
    slope: f64,
}

impl Lab {
    /// Depth below the surface z = slope x (relative to the axis), along its normal.
    fn depth(&self, p: [f64; 2]) -> f64 {
        (self.slope * p[0] - p[1]) / (1.0 + self.slope * self.slope).sqrt()
    }
    fn c(&self, p: [f64; 2]) -> f64 {
        if self.depth(p) > 0.0 {
            0.6
        } else {
            1e-9
        }
    }
    fn phihat(&self, p: [f64; 2]) -> f64 {
        let r = ((p[0] - CENTRE[0]).powi(2) + (p[1] - CENTRE[1]).powi(2)).sqrt();
        if r < CORE {
            1.0
        } else {
            0.0
        }
    }
    fn velocity(&self, p: [f64; 2]) -> [f64; 2] {
        let n = (1.0 + self.slope * self.slope).sqrt();
        let d = self.depth(p);
        if d < 0.0 {
            [0.0, 0.0]
        } else if d < LAYER {
            // downhill along the surface (it rises to the right), faster at the top
            let s = 0.05 * (1.0 - d / LAYER) + 0.01;
            [-s / n, -s * self.slope / n]
        } else {
            // rigid rotation about C, counter-clockwise
            let w = 2.0;
            [-w * (p[1] - CENTRE[1]), w * (p[0] - CENTRE[0])]
        }
    }
}

/// Writes one revolution of the constructed drum (11 snapshots at 1 rev/s) for `scene`, 2D or
/// 3D (a prism along y: every slice the same, except that `empty_slice` holds no grains),
/// in the drum's rotating frame, and returns the entries `analyse` reads.
fn write_revolution(
    scene: &sieve::scene::Scene,
    fields: &std::path::Path,
    empty_slice: Option<usize>,
) -> Vec<(f64, String)> {
    let g = scene.geometry.clone().expect("geometry");
    let three = scene.dim == 3;
    let (ax, az) = if three { (0, 2) } else { (0, 1) };
    let (axis, omega) = ([g.center[ax], g.center[az]], TAU * 1.0);
    let lab = Lab {
        slope: (ANGLE * PI / 180.0).tan(),
    };
    let h = scene.spacing();
    let n = scene.len();
    let (nx, ny) = (scene.cells[0], if three { scene.cells[1] } else { 1 });
    let mut entries = Vec::new();
    for k in 0..=10 {
        let t = 0.1 * k as f64;
        let (s, co) = (omega * t).sin_cos();
        let mut snap = Snapshot::at_rest(t, n, 0.0, 1.0);
        for i in 0..n {
            let (ix, iy, iz) = (i % nx, (i / nx) % ny, i / (nx * ny));
            let r = [
                scene.lower[ax] + (ix as f64 + 0.5) * h[ax] - axis[0],
                scene.lower[az] + (iz as f64 + 0.5) * h[az] - axis[1],
            ];
            if r[0].hypot(r[1]) > g.size {
                snap.volume.as_mut().unwrap()[i] = 0.0;
                snap.c[i] = 1e-9;
                continue;
            }
            if empty_slice == Some(iy) {
                snap.c[i] = 1e-9;
                continue;
            }
            let p = [co * r[0] - s * r[1], s * r[0] + co * r[1]];
            let c = lab.c(p);
            let v = lab.velocity(p);
            // back into the turning frame: Rot(-omega t) v - omega e_y x r
            let w = [co * v[0] + s * v[1], -s * v[0] + co * v[1]];
            snap.c[i] = c;
            snap.phi[i] = c * lab.phihat(p);
            snap.u[i] = [w[0] + omega * r[1], 0.0, w[1] - omega * r[0]];
        }
        let name = format!("state_{k:04}.vti");
        write_vti(&fields.join(&name), scene, &snap).expect("vti");
        entries.push((t, name));
    }
    entries
}

#[test]
fn readouts_recover_the_constructed_drum() {
    let dir = tempfile::tempdir().expect("tempdir");
    let fields = dir.path();
    let (scene, _) = sieve::scene::load(
        "tumbler",
        &[
            "grid.cells=[64,64]".into(),
            "frame.rev_per_s=1.0".into(),
            "run.t_end=1.0".into(),
            "run.output_interval=0.1".into(),
        ],
    )
    .expect("scene");
    let h = scene.spacing();
    let entries = write_revolution(&scene, fields, None);
    let d = sieve::drum::analyse(&scene, fields, &entries)
        .expect("analyse")
        .expect("a 2D drum with velocities");
    let cell = h[0];
    assert_eq!(d.samples, 11, "one revolution of 0.1 s outputs");
    assert_eq!(d.window, [0.0, 1.0]);
    let miss = (d.circulation_centre[0] - CENTRE[0]).hypot(d.circulation_centre[1] - CENTRE[1]);
    assert!(
        miss <= 1.5 * cell,
        "centre {:?} vs {CENTRE:?} ({miss} m)",
        d.circulation_centre
    );
    assert!(
        d.centre_speed < 2.0 * cell,
        "speed at the centre {}",
        d.centre_speed
    );
    assert_eq!(d.centre_phihat, 1.0);
    assert!(
        (d.angle_of_repose_deg - ANGLE).abs() < 1.5,
        "angle {}",
        d.angle_of_repose_deg
    );
    assert!(
        (d.flowing_layer_thickness - LAYER).abs() <= 1.5 * cell,
        "layer {} vs {LAYER} (cell {cell})",
        d.flowing_layer_thickness
    );
    // The core: pure fines in the first ring about C, none beyond the core radius + a cell.
    let about = &d.radial_about_centre;
    assert_eq!(about[0].phihat, 1.0, "{about:?}");
    for b in about
        .iter()
        .filter(|b| b.r_lo >= CORE + cell && b.cells > 0)
    {
        assert_eq!(b.phihat, 0.0, "ring {b:?}");
    }
    // About the drum axis the core is off-centre: the first ring is not pure.
    assert!(d.radial_about_axis[0].phihat < 1.0);
    // The kinetic energy relative to the drum's rotation, evaluated on the lab cells' centres
    // directly: the readout sums over the turning grid's own cells, so the two agree to the
    // cells at the wall (a fraction of a percent here).
    let (omega, lab) = (
        TAU,
        Lab {
            slope: (ANGLE * PI / 180.0).tan(),
        },
    );
    let (mut rel, mut rigid) = (0.0, 0.0);
    for iz in 0..scene.cells[1] {
        for ix in 0..scene.cells[0] {
            let g = scene.geometry.as_ref().unwrap();
            let q = [
                scene.lower[0] + (ix as f64 + 0.5) * h[0] - g.center[0],
                scene.lower[1] + (iz as f64 + 0.5) * h[1] - g.center[1],
            ];
            if q[0].hypot(q[1]) > g.size {
                continue;
            }
            let (c, v) = (lab.c(q), lab.velocity(q));
            rel += c * ((v[0] + omega * q[1]).powi(2) + (v[1] - omega * q[0]).powi(2));
            rigid += c * omega * omega * (q[0] * q[0] + q[1] * q[1]);
        }
    }
    let expected = rel / rigid;
    assert!(
        (d.relative_kinetic_energy / expected - 1.0).abs() < 0.01,
        "relative kinetic energy {} vs {expected}",
        d.relative_kinetic_energy
    );
    // the constructed bed is dense (c = 0.6 > phi_rlp) up to the surface: only the air's
    // 1e-9 counts as loose
    assert!(d.loose_share < 1e-6, "loose share {}", d.loose_share);
    // the line `sieve run` prints
    let line = sieve::drum::line(&d);
    assert!(
        line.starts_with("drum (0 - 1 s, 11 snapshots): angle of repose "),
        "{line}"
    );
    assert!(
        line.contains(&format!("angle of repose {:.1} deg", d.angle_of_repose_deg)),
        "{line}"
    );
    assert!(line.contains("0 % of it in loose surface cells"), "{line}");
    let mut missing = d.clone();
    missing.flowing_layer_thickness = f64::NAN;
    let line = sieve::drum::line(&missing);
    assert!(line.contains("flowing layer - mm"), "{line}");
    let csv = sieve::drum::radial_csv(&d);
    assert!(
        csv.starts_with("about,r_lo,r_hi,cells,phihat,c\ncentre,0,"),
        "{csv}"
    );
}

/// A 3D drum (a prism along y) is read as its axial mean cross-section: four identical slices
/// give the 2D answers, and a slice with no grains (as beside an end wall) changes neither the
/// centre, the angle, the layer nor the core, because phihat and u are weighted by the grains.
#[test]
fn a_3d_drum_is_read_as_its_axial_mean() {
    let load = |name: &str, cells: &str| {
        sieve::scene::load(
            name,
            &[
                format!("grid.cells={cells}"),
                "frame.rev_per_s=1.0".into(),
                "run.t_end=1.0".into(),
                "run.output_interval=0.1".into(),
            ],
        )
        .expect("scene")
        .0
    };
    let flat = load("tumbler", "[48,48]");
    let dir2 = tempfile::tempdir().expect("tempdir");
    let e2 = write_revolution(&flat, dir2.path(), None);
    let d2 = sieve::drum::analyse(&flat, dir2.path(), &e2)
        .expect("analyse")
        .expect("2D drum");
    let deep = load("tumbler-3d", "[48,4,48]");
    for empty in [None, Some(0)] {
        let dir3 = tempfile::tempdir().expect("tempdir");
        let e3 = write_revolution(&deep, dir3.path(), empty);
        let d3 = sieve::drum::analyse(&deep, dir3.path(), &e3)
            .expect("analyse")
            .expect("3D drum");
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * (1.0 + b.abs());
        assert_eq!(d3.samples, d2.samples);
        assert!(
            close(d3.circulation_centre[0], d2.circulation_centre[0])
                && close(d3.circulation_centre[1], d2.circulation_centre[1]),
            "{empty:?}: centre {:?} vs 2D {:?}",
            d3.circulation_centre,
            d2.circulation_centre
        );
        assert!(
            close(d3.angle_of_repose_deg, d2.angle_of_repose_deg),
            "{empty:?}: angle {} vs {}",
            d3.angle_of_repose_deg,
            d2.angle_of_repose_deg
        );
        assert!(
            close(d3.flowing_layer_thickness, d2.flowing_layer_thickness),
            "{empty:?}: layer {} vs {}",
            d3.flowing_layer_thickness,
            d2.flowing_layer_thickness
        );
        assert!(
            (d3.centre_phihat - d2.centre_phihat).abs() < 1e-8,
            "{empty:?}: centre phihat {} vs {}",
            d3.centre_phihat,
            d2.centre_phihat
        );
        // c and the grains' weight scale alike in both sums: the same ratio with or without
        // the empty slice
        assert!(
            close(d3.relative_kinetic_energy, d2.relative_kinetic_energy),
            "{empty:?}: relative kinetic energy {} vs {}",
            d3.relative_kinetic_energy,
            d2.relative_kinetic_energy
        );
        for (a, b) in d3.radial_about_centre.iter().zip(&d2.radial_about_centre) {
            assert_eq!(a.cells, b.cells, "{empty:?}: ring {a:?} vs {b:?}");
            assert!(
                (a.phihat - b.phihat).abs() < 1e-8,
                "{empty:?}: ring {a:?} vs {b:?}"
            );
        }
    }
}

/// The kinetic-energy readout in the lab frame, where the snapshots are the lab (each lab cell
/// is its own solver cell, so the sums are exact): a bed turning rigidly with the drum plus a
/// slow drift, a loose skin (c = 0.3, below the tumbler material's phi_rlp = 0.5757) sliding
/// downhill over it, and air at rest. The readout must subtract the drum's rotation (the bed's
/// rigid part leaves nothing), weigh by c and the open volume, and put the skin's share apart.
#[test]
fn kinetic_energy_relative_to_the_drum_splits_the_loose_skin_from_the_bed() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (scene, _) = sieve::scene::load(
        "tumbler",
        &[
            "grid.cells=[32,32]".into(),
            "frame.kind=\"lab\"".into(),
            "frame.rev_per_s=0.5".into(),
            "run.t_end=2.0".into(),
            "run.output_interval=0.25".into(),
        ],
    )
    .expect("scene");
    let g = scene.geometry.clone().expect("geometry");
    let (h, n, nx) = (scene.spacing(), scene.len(), scene.cells[0]);
    let omega = TAU * 0.5;
    let (drift, slide) = (0.004, 0.05);
    let (mut bed, mut skin, mut rigid) = (0.0, 0.0, 0.0);
    let mut entries = Vec::new();
    for k in 0..=8 {
        let t = 0.25 * k as f64;
        let mut snap = Snapshot::at_rest(t, n, 1e-9, 0.0);
        for i in 0..n {
            let q = [
                scene.lower[0] + ((i % nx) as f64 + 0.5) * h[0] - g.center[0],
                scene.lower[1] + ((i / nx) as f64 + 0.5) * h[1] - g.center[1],
            ];
            if q[0].hypot(q[1]) > g.size {
                continue;
            }
            // open volume: smaller in a ring near the wall, as cut cells are
            let vol = if q[0].hypot(q[1]) > g.size - h[0] {
                0.5
            } else {
                1.0
            };
            snap.volume.as_mut().unwrap()[i] = vol;
            let turning = [-omega * q[1], omega * q[0]];
            let (c, extra) = if q[1] < 0.0 {
                (0.6, [drift, 0.0])
            } else if q[1] < 0.004 {
                (0.3, [-slide, 0.0])
            } else {
                (1e-9, [-turning[0], -turning[1]]) // air at rest in the lab
            };
            snap.c[i] = c;
            snap.u[i] = [turning[0] + extra[0], 0.0, turning[1] + extra[1]];
            if k == 0 {
                let e = c * (extra[0] * extra[0] + extra[1] * extra[1]) * vol;
                if c >= 0.5757 {
                    bed += e;
                } else {
                    skin += e;
                }
                rigid += c * (turning[0] * turning[0] + turning[1] * turning[1]) * vol;
            }
        }
        let name = format!("state_{k:04}.vti");
        write_vti(&dir.path().join(&name), &scene, &snap).expect("vti");
        entries.push((t, name));
    }
    let d = sieve::drum::analyse(&scene, dir.path(), &entries)
        .expect("analyse")
        .expect("a 2D drum with velocities");
    assert_eq!(d.samples, 9);
    let (ke, share) = ((bed + skin) / rigid, skin / (bed + skin));
    assert!(
        (d.relative_kinetic_energy / ke - 1.0).abs() < 1e-12,
        "relative kinetic energy {} vs {ke}",
        d.relative_kinetic_energy
    );
    assert!(
        (d.loose_share / share - 1.0).abs() < 1e-12,
        "loose share {} vs {share}",
        d.loose_share
    );
    // the skin dominates: 0.3 x 0.05^2 per cell against 0.6 x 0.004^2 in the bed
    assert!(share > 0.5 && share < 1.0, "{share}");
}
