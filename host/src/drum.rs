//! What a process engineer reads off a rotating drum (issue 8; model.md 7.5), measured from
//! the run's own VTK snapshots after the run (so a resumed run measures the same; `sieve
//! converge` measures the same snapshots kept in memory):
//!
//! * the **circulation centre**: the point of the dense bed with the lowest time-averaged lab
//!   speed (the eye of the bed's recirculation), over the last revolution;
//! * **radial profiles** of phihat (and c) about that centre and about the drum axis, at the
//!   last output: a core of fines shows as phihat falling with r;
//! * the **dynamic angle of repose** of the free surface (a straight line fitted to the lab
//!   surface over the central 60 % of the drum's width, averaged over the window);
//! * the **flowing-layer thickness**: the depth below the surface, along its normal through
//!   the point above the drum axis, at which the time-averaged velocity along the slope
//!   turns from downhill (the flowing layer) to uphill (the bed turning with the drum);
//! * the **relative kinetic energy** of the flow against the drum's rigid rotation, in units
//!   of the bed's solid-body energy, and the **share of it in loose cells** (below the random
//!   loose packing): a free surface that runs obliquely to the grid lines leaves a staircase
//!   of partly filled cells that slide over the bed and throw off dust, and this share says
//!   how much of the flow a run puts there (docs/tumbler.md, "Where the anisotropy lives").
//!
//! The grid turns with the drum (rotating frame, model.md 2.5), so every snapshot is first
//! mapped into the lab: position `o + Rot(omega t)(x - o)`, velocity
//! `Rot(omega t)(u + omega e_y x (x - o))`, and binned on a lab grid of the solver's cells.
//! A lab-frame drum is the same map with a zero angle. A 3D drum (a prism along y, periodic or
//! between end walls) is read as its axial mean cross-section first ([`axial_mean`]); scenes
//! without a circular drum get nothing.

pub use crate::data::{DrumSummary, RadialBin};
use crate::error::Result;
use crate::output::vtk::{read_vti, Vti};
use crate::scene::{Scene, ShapeKind};
use std::fmt::Write as _;
use std::path::Path;

/// c that marks the free surface and the dense bed: half the bed's packing.
const DENSE: f64 = 0.3;

/// A snapshot mapped into the lab and binned on the lab grid (the solver's cells).
struct LabField {
    /// Per lab cell: c, phihat, lab velocity (x, z); NaN where no grain cell landed.
    c: Vec<f64>,
    phihat: Vec<f64>,
    v: Vec<[f64; 2]>,
}

/// The lab grid: the solver's cells, axes x and z (2D).
#[derive(Clone, Copy)]
struct LabGrid {
    n: [usize; 2],
    origin: [f64; 2],
    h: [f64; 2],
}

impl LabGrid {
    fn of(v: &Vti) -> Self {
        Self {
            n: [v.cells[0], v.cells[2]],
            origin: [v.origin[0], v.origin[2]],
            h: [v.spacing[0], v.spacing[2]],
        }
    }
    fn center(&self, i: usize) -> [f64; 2] {
        let (ix, iz) = (i % self.n[0], i / self.n[0]);
        [
            self.origin[0] + (ix as f64 + 0.5) * self.h[0],
            self.origin[1] + (iz as f64 + 0.5) * self.h[1],
        ]
    }
    fn index(&self, p: [f64; 2]) -> Option<usize> {
        let ix = ((p[0] - self.origin[0]) / self.h[0]).floor();
        let iz = ((p[1] - self.origin[1]) / self.h[1]).floor();
        (ix >= 0.0 && iz >= 0.0 && (ix as usize) < self.n[0] && (iz as usize) < self.n[1])
            .then(|| ix as usize + self.n[0] * iz as usize)
    }
    /// Cells of the grid; saturating, so that a damaged file's absurd extents match no array
    /// (found by `tests/tests/fuzz_readers.rs`: the product overflowed).
    fn len(&self) -> usize {
        self.n[0].saturating_mul(self.n[1])
    }
}

/// The drum a scene describes, if it is a circular drum (2D, or 3D along y): axis in the
/// x-z plane, radius, omega.
struct Drum {
    axis: [f64; 2],
    radius: f64,
    /// Rate of the grid's rotation (0 in the lab frame, whose grid is at rest).
    omega: f64,
    /// The drum's own rate in either frame (the averaging window is one revolution).
    turn: f64,
}

impl Drum {
    /// One revolution [s] (infinite if the drum does not turn).
    fn period(&self) -> f64 {
        if self.turn != 0.0 {
            std::f64::consts::TAU / self.turn.abs()
        } else {
            f64::INFINITY
        }
    }
}

fn drum_of(scene: &Scene) -> Option<Drum> {
    let g = scene.geometry.as_ref()?;
    if !matches!(g.shape, ShapeKind::Drum) || g.center.len() != scene.dim {
        return None;
    }
    let axis = match scene.dim {
        2 => [g.center[0], g.center[1]],
        3 => [g.center[0], g.center[2]],
        _ => return None,
    };
    let turn = scene
        .frame
        .as_ref()
        .map_or(0.0, |f| std::f64::consts::TAU * f.rev_per_s);
    let rotating = scene
        .frame
        .as_ref()
        .is_some_and(|f| f.kind == crate::scene::FrameKind::Rotating);
    Some(Drum {
        axis,
        radius: g.size,
        omega: if rotating { turn } else { 0.0 },
        turn,
    })
}

/// The axial mean of a 3D snapshot (cells `nx x ny x nz`, y along the drum's axis) as a
/// one-cell-deep snapshot: per (x, z) column, c is the mean over the open volume, phihat and u
/// the means weighted by the grains (c times open volume), so a slice that holds few grains
/// (beside an end wall the bed is thinner) counts in proportion to them. A 2D snapshot is
/// returned as it is. `None` if an array is missing or has the wrong length.
pub fn axial_mean(v: Vti) -> Option<Vti> {
    let [nx, ny, nz] = v.cells;
    if ny <= 1 {
        return Some(v);
    }
    // saturating: absurd extents (a damaged file) match no array
    let n = nx.saturating_mul(ny).saturating_mul(nz);
    let (c, phihat, u) = (v.array("c")?, v.array("phihat")?, v.array("u")?);
    if c.len() != n || phihat.len() != n || u.len() != n.saturating_mul(3) {
        return None;
    }
    let volume = v.array("volume").filter(|vol| vol.len() == n);
    let m = nx * nz;
    let (mut cm, mut ph, mut um, mut vm) =
        (vec![0.0; m], vec![0.0; m], vec![0.0; 3 * m], vec![0.0; m]);
    for iz in 0..nz {
        for ix in 0..nx {
            let j = ix + nx * iz;
            let (mut vol_sum, mut cv, mut pv, mut uv) = (0.0, 0.0, 0.0, [0.0; 3]);
            for iy in 0..ny {
                let i = ix + nx * (iy + ny * iz);
                let vol = volume.map_or(1.0, |vol| vol[i]);
                let w = c[i] * vol;
                vol_sum += vol;
                cv += w;
                pv += w * phihat[i];
                for k in 0..3 {
                    uv[k] += w * u[3 * i + k];
                }
            }
            vm[j] = vol_sum / ny as f64;
            if vol_sum > 0.0 {
                cm[j] = cv / vol_sum;
            }
            if cv > 0.0 {
                ph[j] = pv / cv;
                for k in 0..3 {
                    um[3 * j + k] = uv[k] / cv;
                }
            }
        }
    }
    let mut arrays = vec![
        ("c".to_string(), 1, cm),
        ("phihat".to_string(), 1, ph),
        ("u".to_string(), 3, um),
    ];
    if volume.is_some() {
        arrays.push(("volume".to_string(), 1, vm));
    }
    Some(Vti {
        cells: [nx, 1, nz],
        origin: v.origin,
        spacing: [v.spacing[0], v.spacing[1] * ny as f64, v.spacing[2]],
        t: v.t,
        arrays,
    })
}

/// Maps snapshot `v` into the lab (module docs) on `grid`: each lab cell takes the solver cell
/// that lies under its centre at the snapshot's time (a pull, so no lab cell is left out).
fn lab_field(v: &Vti, grid: LabGrid, drum: &Drum) -> Option<LabField> {
    let (c, phihat, u) = (v.array("c")?, v.array("phihat")?, v.array("u")?);
    let n = grid.len();
    if c.len() != n || phihat.len() != n || u.len() != n.saturating_mul(3) {
        return None;
    }
    // a volume array of the wrong length is ignored, as in `axial_mean` (indexing it panicked
    // on a damaged snapshot: found by `tests/tests/fuzz_readers.rs`)
    let volume = v.array("volume").filter(|vol| vol.len() == n);
    let (s, co) = (drum.omega * v.t).sin_cos();
    let mut out = LabField {
        c: vec![f64::NAN; n],
        phihat: vec![f64::NAN; n],
        v: vec![[f64::NAN; 2]; n],
    };
    for j in 0..n {
        let p = grid.center(j);
        let q = [p[0] - drum.axis[0], p[1] - drum.axis[1]];
        // back into the turning grid: Rot(-omega t)
        let x = [co * q[0] + s * q[1], -s * q[0] + co * q[1]];
        let Some(i) = grid.index([drum.axis[0] + x[0], drum.axis[1] + x[1]]) else {
            continue;
        };
        if volume.is_some_and(|vol| vol[i] <= 0.0) {
            continue; // solid
        }
        let xi = grid.center(i);
        let r = [xi[0] - drum.axis[0], xi[1] - drum.axis[1]];
        // omega e_y x r with x to the right and z up: a positive omega turns x towards z.
        let w = [
            u[3 * i] - drum.omega * r[1],
            u[3 * i + 2] + drum.omega * r[0],
        ];
        out.c[j] = c[i];
        out.phihat[j] = phihat[i];
        out.v[j] = [co * w[0] - s * w[1], s * w[0] + co * w[1]];
    }
    Some(out)
}

/// Surface height of lab column `ix` (the top of the highest dense cell), if the column holds
/// grains.
fn surface(grid: LabGrid, f: &LabField, ix: usize) -> Option<f64> {
    (0..grid.n[1]).rev().find_map(|iz| {
        let c = f.c[ix + grid.n[0] * iz];
        (c >= DENSE).then(|| grid.origin[1] + (iz as f64 + 1.0) * grid.h[1])
    })
}

/// Least-squares slope and intercept of the surface over the central 60 % of the drum.
fn surface_line(grid: LabGrid, f: &LabField, drum: &Drum) -> Option<(f64, f64)> {
    let pts: Vec<(f64, f64)> = (0..grid.n[0])
        .filter_map(|ix| {
            let x = grid.origin[0] + (ix as f64 + 0.5) * grid.h[0] - drum.axis[0];
            (x.abs() <= 0.6 * drum.radius)
                .then(|| surface(grid, f, ix).map(|z| (x, z - drum.axis[1])))
                .flatten()
        })
        .collect();
    if pts.len() < 3 {
        return None;
    }
    let n = pts.len() as f64;
    let (mx, mz) = pts
        .iter()
        .fold((0.0, 0.0), |(a, b), p| (a + p.0 / n, b + p.1 / n));
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxz: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - mz)).sum();
    let b = sxz / sxx;
    Some((b, mz - b * mx))
}

fn radial(grid: LabGrid, f: &LabField, about: [f64; 2], width: f64, r_max: f64) -> Vec<RadialBin> {
    let bins = (r_max / width).ceil().max(1.0) as usize;
    let mut sums = vec![(0usize, 0.0, 0.0); bins];
    for i in 0..grid.len() {
        if !(f.c[i] >= DENSE) {
            continue;
        }
        let x = grid.center(i);
        let r = ((x[0] - about[0]).powi(2) + (x[1] - about[1]).powi(2)).sqrt();
        let k = (r / width) as usize;
        if k < bins {
            sums[k].0 += 1;
            sums[k].1 += f.phihat[i];
            sums[k].2 += f.c[i];
        }
    }
    sums.iter()
        .enumerate()
        .map(|(k, &(n, p, c))| RadialBin {
            r_lo: k as f64 * width,
            r_hi: (k + 1) as f64 * width,
            cells: n,
            phihat: if n > 0 { p / n as f64 } else { f64::NAN },
            c: if n > 0 { c / n as f64 } else { f64::NAN },
        })
        .collect()
}

/// The drum readouts of a finished run from its snapshots `entries` (time, file in `fields`);
/// `None` for scenes that are not circular drums or whose snapshots lack c, phihat or u.
pub fn analyse(
    scene: &Scene,
    fields: &Path,
    entries: &[(f64, String)],
) -> Result<Option<DrumSummary>> {
    let Some(&(t_last, _)) = entries.last() else {
        return Ok(None);
    };
    let Some(t0) = window_start(scene, t_last) else {
        return Ok(None);
    };
    let mut window = Vec::new();
    for (_, file) in entries.iter().filter(|(t, _)| *t >= t0) {
        window.push(read_vti(&fields.join(file))?);
    }
    Ok(analyse_snapshots(scene, t_last, window))
}

/// Where the window of a drum's readouts starts if the last snapshot is at `t_last`: one
/// revolution before it, or at `t_last / 2` if the run is shorter than a revolution. `None`
/// if the scene is not a circular drum.
pub fn window_start(scene: &Scene, t_last: f64) -> Option<f64> {
    let period = drum_of(scene)?.period();
    Some(if period <= t_last {
        t_last - period
    } else {
        t_last / 2.0
    })
}

/// Snapshots before this time lie outside the window of every `t_last >= t` (a caller that
/// keeps snapshots as a run goes may drop them): one revolution before `t` once a revolution
/// has passed (until then the window may still start at 0), `t / 2` for a drum that does
/// not turn.
pub fn needed_from(scene: &Scene, t: f64) -> Option<f64> {
    let period = drum_of(scene)?.period();
    Some(if period.is_infinite() {
        t / 2.0
    } else if t >= period {
        t - period
    } else {
        0.0
    })
}

/// [`analyse`] of snapshots in memory: those of the window ([`window_start`]) in time order,
/// the last at `t_last` (`sieve converge` keeps them instead of writing files).
pub fn analyse_snapshots(scene: &Scene, t_last: f64, window: Vec<Vti>) -> Option<DrumSummary> {
    let drum = drum_of(scene)?;
    let t0 = window_start(scene, t_last)?;
    let loose = loose_below(scene);
    let mut grid = None;
    let mut fields_in = Vec::with_capacity(window.len());
    let mut energies = Vec::with_capacity(window.len());
    for v in window {
        energies.push(energy(&v, &drum, loose)?);
        let v = axial_mean(v)?;
        let g = *grid.get_or_insert_with(|| LabGrid::of(&v));
        fields_in.push(lab_field(&v, g, &drum)?);
    }
    let (Some(grid), Some(last)) = (grid, fields_in.last()) else {
        return None;
    };
    let n = grid.len();
    // Time averages per lab cell over the snapshots where grains were there.
    let mut speed = vec![0.0; n];
    let mut vel = vec![[0.0; 2]; n];
    let mut dense = vec![0usize; n];
    for f in &fields_in {
        for i in 0..n {
            if f.c[i] >= DENSE {
                dense[i] += 1;
                speed[i] += (f.v[i][0].powi(2) + f.v[i][1].powi(2)).sqrt();
                vel[i][0] += f.v[i][0];
                vel[i][1] += f.v[i][1];
            }
        }
    }
    let samples = fields_in.len();
    let hmax = grid.h[0].max(grid.h[1]);
    // The circulation centre: dense in every snapshot, at least two cells inside the wall.
    let centre = (0..n)
        .filter(|&i| dense[i] == samples)
        .filter(|&i| {
            let x = grid.center(i);
            let r = ((x[0] - drum.axis[0]).powi(2) + (x[1] - drum.axis[1]).powi(2)).sqrt();
            r <= drum.radius - 2.0 * hmax
        })
        .min_by(|&a, &b| speed[a].total_cmp(&speed[b]));
    let centre = centre?;
    let centre_xz = grid.center(centre);
    // Angle of repose: mean over the window of the fitted surface slopes.
    let slopes: Vec<f64> = fields_in
        .iter()
        .filter_map(|f| surface_line(grid, f, &drum).map(|(b, _)| b))
        .collect();
    let angle = if slopes.is_empty() {
        f64::NAN
    } else {
        slopes.iter().map(|b| b.atan().to_degrees()).sum::<f64>() / slopes.len() as f64
    };
    let thickness = surface_line(grid, last, &drum).map_or(f64::NAN, |(b, a)| {
        // Down the inward normal from the surface point above the axis; downhill tangent.
        let norm = (1.0 + b * b).sqrt();
        let normal = [b / norm, -1.0 / norm];
        let downhill = if b >= 0.0 {
            [-1.0 / norm, -b / norm]
        } else {
            [1.0 / norm, b / norm]
        };
        let start = [drum.axis[0], drum.axis[1] + a];
        let step = 0.25 * grid.h[0].min(grid.h[1]);
        let mut seen_downhill = false;
        let mut depth = 0.0;
        while depth < 2.0 * drum.radius {
            let p = [start[0] + depth * normal[0], start[1] + depth * normal[1]];
            if let Some(i) = grid.index(p) {
                if dense[i] > 0 {
                    let m = dense[i] as f64;
                    let along = (vel[i][0] * downhill[0] + vel[i][1] * downhill[1]) / m;
                    if along > 0.0 {
                        seen_downhill = true;
                    } else if seen_downhill {
                        return depth;
                    }
                }
            }
            depth += step;
        }
        f64::NAN
    });
    let (relative_kinetic_energy, loose_share) = kinetic_energy(&energies);
    let width = (drum.radius / 10.0).max(hmax);
    Some(DrumSummary {
        window: [t0, t_last],
        samples,
        circulation_centre: [centre_xz[0] - drum.axis[0], centre_xz[1] - drum.axis[1]],
        centre_speed: speed[centre] / samples as f64,
        centre_phihat: last.phihat[centre],
        angle_of_repose_deg: angle,
        flowing_layer_thickness: thickness,
        relative_kinetic_energy,
        loose_share,
        radial_about_centre: radial(grid, last, centre_xz, width, drum.radius),
        radial_about_axis: radial(grid, last, drum.axis, width, drum.radius),
    })
}

/// The c below which a cell counts as loose: the flow material's random loose packing (no
/// yield stress below it), or half the bed's packing ([`DENSE`]) for a scene without a flow.
fn loose_below(scene: &Scene) -> f64 {
    scene.flow.as_ref().map_or(DENSE, |f| f.phi_rlp)
}

/// One snapshot's kinetic energies on the solver's own cells (in 3D every cell, before the
/// axial mean, so a thin slice beside an end wall is judged loose or dense by its own c):
/// `[sum c |u - Omega x r|^2 V, sum c |Omega x r|^2 V, the first sum over cells with c <
/// loose]`. The velocity relative to the drum's rigid rotation is `u + (omega - turn) e_y x
/// r`: exactly `u` in the rotating frame, `u - turn e_y x r` in the lab. `None` if an array is
/// missing or has the wrong length.
fn energy(v: &Vti, drum: &Drum, loose: f64) -> Option<[f64; 3]> {
    let [nx, ny, nz] = v.cells;
    let n = nx.saturating_mul(ny).saturating_mul(nz);
    let (c, u) = (v.array("c")?, v.array("u")?);
    if c.len() != n || u.len() != n.saturating_mul(3) {
        return None;
    }
    let volume = v.array("volume").filter(|vol| vol.len() == n);
    let spin = drum.omega - drum.turn;
    let mut sums = [0.0; 3];
    for (i, &ci) in c.iter().enumerate() {
        let (ix, iz) = (i % nx, i / (nx * ny));
        let r = [
            v.origin[0] + (ix as f64 + 0.5) * v.spacing[0] - drum.axis[0],
            v.origin[2] + (iz as f64 + 0.5) * v.spacing[2] - drum.axis[1],
        ];
        let vol = volume.map_or(1.0, |vol| vol[i]);
        if !(ci > 0.0 && vol > 0.0) {
            continue;
        }
        let rel = [u[3 * i] - spin * r[1], u[3 * i + 2] + spin * r[0]];
        let e = ci * (rel[0] * rel[0] + rel[1] * rel[1]) * vol;
        sums[0] += e;
        sums[1] += ci * drum.turn * drum.turn * (r[0] * r[0] + r[1] * r[1]) * vol;
        if ci < loose {
            sums[2] += e;
        }
    }
    Some(sums)
}

/// The window mean of `sum c |u - Omega x r|^2 V / sum c |Omega x r|^2 V` ([`energy`] per
/// snapshot), and the share of the window's summed numerator in loose cells (NaN where a
/// denominator is 0: a drum that does not turn, or one that does not move).
fn kinetic_energy(energies: &[[f64; 3]]) -> (f64, f64) {
    let (mut ratio, mut samples, mut all, mut in_loose) = (0.0, 0usize, 0.0, 0.0);
    for &[rel, rigid, loose] in energies {
        if rigid > 0.0 {
            ratio += rel / rigid;
            samples += 1;
        }
        all += rel;
        in_loose += loose;
    }
    let mean = if samples > 0 {
        ratio / samples as f64
    } else {
        f64::NAN
    };
    let share = if all > 0.0 { in_loose / all } else { f64::NAN };
    (mean, share)
}

/// The line `sieve run` prints for a drum: what a process engineer reads off first (the
/// window, the angle of repose, the flowing layer, the core) and the grid check (the share of
/// the flow in loose surface cells). A value the window did not give reads `-`.
pub fn line(d: &DrumSummary) -> String {
    let num = |v: f64, digits: usize| {
        if v.is_finite() {
            format!("{v:.digits$}")
        } else {
            "-".to_string()
        }
    };
    format!(
        "drum ({} - {} s, {} snapshots): angle of repose {} deg, flowing layer {} mm, circulation centre ({}, {}) mm from the axis with phihat {}; kinetic energy relative to the drum {} of the bed's rigid rotation, {} % of it in loose surface cells (docs/tumbler.md)",
        crate::text::approx(d.window[0]),
        crate::text::approx(d.window[1]),
        d.samples,
        num(d.angle_of_repose_deg, 1),
        num(1e3 * d.flowing_layer_thickness, 1),
        num(1e3 * d.circulation_centre[0], 1),
        num(1e3 * d.circulation_centre[1], 1),
        num(d.centre_phihat, 2),
        num(d.relative_kinetic_energy, 2),
        num(100.0 * d.loose_share, 0),
    )
}

/// `radial.csv`: both radial profiles, one row per ring.
pub fn radial_csv(d: &DrumSummary) -> String {
    let mut s = String::from("about,r_lo,r_hi,cells,phihat,c\n");
    for (about, bins) in [
        ("centre", &d.radial_about_centre),
        ("axis", &d.radial_about_axis),
    ] {
        for b in bins {
            let _ = writeln!(
                s,
                "{about},{},{},{},{},{}",
                crate::output::num(b.r_lo),
                crate::output::num(b.r_hi),
                b.cells,
                crate::output::num(b.phihat),
                crate::output::num(b.c)
            );
        }
    }
    s
}
