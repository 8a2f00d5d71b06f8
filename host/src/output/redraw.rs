//! The pictures of a run, drawn from its files only (`summary.json`, `series.csv`,
//! `fields/series.pvd` with its `.vti` snapshots, `profiles.csv` for flow scenes): `sieve run`
//! calls this on its staging directory, and `sieve plot DIR` on a finished run, so both draw
//! the same pictures from the same data.
//!
//! Written into the plots directory:
//! - `psi.png`: Psi(t) with the threshold, the relative mass drift and the bound violations;
//! - 1D: `phihat_profiles.png`, at most [`plot::MAX_FRAMES_1D`] output times;
//! - 2D (3D: the mid-plane y slice, `phihat_midplane_*`): `phihat_NNNN.png` at up to
//!   [`plot::MAX_FRAMES_MAP`] output times and `phihat.gif`, an animation over every output
//!   time (at most [`plot::MAX_FRAMES_GIF`], evenly spread); empty cells grey;
//! - flow scenes: `flow_velocity.png`, `flow_temperature.png`, `flow_shear_ratio.png`.

use super::plot::{self, Curve, MapGrid};
use super::vtk::{read_vti, Vti};
use crate::data::{Profiles, SeriesRow};
use crate::error::{Error, Result};
use crate::silo::DischargeRow;
use std::path::{Path, PathBuf};

/// Reads `series.csv` (header [`super::csv::SERIES_HEADER`]).
pub fn read_series(path: &Path) -> Result<Vec<SeriesRow>> {
    let text = crate::read::text(path, crate::read::MAX_FILE)?;
    let mut lines = text.lines();
    let header = lines.next().unwrap_or_default();
    if header != super::csv::SERIES_HEADER {
        return Err(Error::failure(format!(
            "{}: unexpected header `{header}` (expected `{}`)",
            path.display(),
            super::csv::SERIES_HEADER
        )));
    }
    let rows: Vec<SeriesRow> = lines
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l
                .split(',')
                .map(|x| x.trim().parse().unwrap_or(f64::NAN))
                .collect();
            if v.len() < 5 {
                return Err(Error::failure(format!(
                    "{}: short row `{l}`",
                    path.display()
                )));
            }
            Ok(SeriesRow {
                t: v[0],
                psi: v[1],
                mass: v[2],
                overshoot_max: v[3],
                undershoot_max: v[4],
            })
        })
        .collect::<Result<_>>()?;
    // sieve writes the rows in time order: a time that is not a number or runs backwards is
    // a damaged file (and would stretch the time axis past what the plots can draw).
    let mut last = 0.0f64;
    for (k, r) in rows.iter().enumerate() {
        if !(r.t.is_finite() && r.t >= last) {
            return Err(Error::failure(format!(
                "{}: row {}: t = {} does not follow {last} (times must be finite and in order); the file is damaged",
                path.display(),
                k + 1,
                r.t
            )));
        }
        last = r.t;
    }
    Ok(rows)
}

/// Header of `profiles.csv` (flow scenes): horizontally averaged profiles at the end of the
/// run; `shear_ratio` is sqrt(T)/|du_x/dz| over sqrt(a eta0/eps0) (NaN where T <= 1e-12).
pub const PROFILES_HEADER: &str = "z,u_x,T,shear_rate,shear_ratio";

/// Writes `profiles.csv`.
pub fn write_profiles(path: &Path, p: &Profiles) -> Result<()> {
    use std::fmt::Write;
    let ratio = plot::shear_ratio(p);
    let mut s = String::from(PROFILES_HEADER);
    s.push('\n');
    for k in 0..p.z.len() {
        let _ = writeln!(
            s,
            "{},{},{},{},{}",
            super::num(p.z[k]),
            super::num(p.u[k]),
            super::num(p.t[k]),
            super::num(p.shear[k]),
            super::num(ratio[k])
        );
    }
    super::write_file(path, s.as_bytes())
}

/// Reads `profiles.csv` back; `ratio_theory` is 1 so that the stored ratio is plotted as is.
fn read_profiles(path: &Path) -> Result<Profiles> {
    let text = crate::read::text(path, crate::read::MAX_FILE)?;
    let mut p = Profiles {
        ratio_theory: 1.0,
        ..Profiles::default()
    };
    let mut ratio = Vec::new();
    for l in text.lines().skip(1).filter(|l| !l.trim().is_empty()) {
        let v: Vec<f64> = l
            .split(',')
            .map(|x| x.trim().parse().unwrap_or(f64::NAN))
            .collect();
        if v.len() < 5 {
            return Err(Error::failure(format!(
                "{}: short row `{l}`",
                path.display()
            )));
        }
        p.z.push(v[0]);
        p.u.push(v[1]);
        p.t.push(v[2]);
        ratio.push(v[4]);
    }
    // Plotted through shear_ratio(): T^(1/2) / shear / 1 = the stored ratio.
    p.shear = ratio
        .iter()
        .zip(&p.t)
        .map(|(&r, &t)| {
            if r.is_finite() && r > 0.0 {
                t.sqrt() / r
            } else {
                0.0
            }
        })
        .collect();
    Ok(p)
}

/// `(t, file)` entries of a `.pvd`.
fn read_pvd(path: &Path) -> Result<Vec<(f64, String)>> {
    let text = crate::read::text(path, crate::read::MAX_FILE)?;
    let get = |tag: &str, key: &str| -> Option<String> {
        let start = tag.find(&format!("{key}=\""))? + key.len() + 2;
        let end = tag[start..].find('"')? + start;
        Some(tag[start..end].to_string())
    };
    Ok(text
        .split('<')
        .filter(|t| t.starts_with("DataSet "))
        .filter_map(|t| Some((get(t, "timestep")?.parse().ok()?, get(t, "file")?)))
        .collect())
}

/// phihat with empty cells (c <= [`plot::VACUUM`]) as NaN, on the x-z plane (3D: the
/// mid-plane y slice `ny / 2`).
fn masked_plane(v: &Vti, path: &Path) -> Result<Vec<f64>> {
    let (Some(phihat), Some(c)) = (v.array("phihat"), v.array("c")) else {
        return Err(Error::failure(format!(
            "{}: a .vti without phihat or c",
            path.display()
        )));
    };
    let [nx, ny, nz] = v.cells;
    // One value per cell, or the file lies about its grid (a hostile extent once indexed out
    // of bounds); the arrays are bounded by the file's size, so this bounds the grid too.
    let n = nx.checked_mul(ny).and_then(|m| m.checked_mul(nz));
    if n.is_none_or(|n| phihat.len() != n || c.len() != n) {
        return Err(Error::failure(format!(
            "{}: a .vti whose arrays ({} phihat, {} c values) do not match its grid of {nx} x {ny} x {nz} cells",
            path.display(),
            phihat.len(),
            c.len()
        )));
    }
    // Cut cells: the solid (open volume 0) is drawn white and told apart from empty cells
    // (grey), so the container's outline shows in every map (issue 8).
    let volume = v.array("volume").filter(|a| Some(a.len()) == n);
    let iy = ny / 2;
    let mut out = Vec::with_capacity(nx * nz);
    for iz in 0..nz {
        for ix in 0..nx {
            let i = ix + nx * (iy + ny * iz);
            out.push(if volume.is_some_and(|vol| vol[i] <= 0.0) {
                plot::SOLID_CELL
            } else if c[i] > plot::VACUUM {
                phihat[i]
            } else {
                f64::NAN
            });
        }
    }
    Ok(out)
}

/// Reads the series' snapshot at `path`, whose grid must be the series' own (`cells`, set by
/// the first snapshot): the pictures of a series share one grid, and a snapshot of another
/// grid (a damaged extent, a `series.pvd` naming another run's file) once indexed the
/// animation's first grid out of bounds.
fn snapshot(path: &Path, cells: &mut Option<[usize; 3]>) -> Result<Vti> {
    let v = read_vti(path)?;
    let first = *cells.get_or_insert(v.cells);
    if v.cells != first {
        let [a, b, c] = v.cells;
        let [d, e, f] = first;
        return Err(Error::failure(format!(
            "{}: a snapshot of {a} x {b} x {c} cells in a series of {d} x {e} x {f} (damaged, or series.pvd names another run's file)",
            path.display()
        )));
    }
    Ok(v)
}

/// Redraws every picture of the run in `run` into `plots` (which must exist); returns the
/// file names written.
pub fn redraw(run: &Path, plots: &Path) -> Result<Vec<String>> {
    let summary_path = run.join("summary.json");
    let text = crate::read::text(&summary_path, crate::read::MAX_FILE)?;
    let summary: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| Error::failure(format!("{}: {e}", summary_path.display())))?;
    let name = summary["scene"].as_str().unwrap_or("run").to_string();
    let threshold = summary["psi_threshold"].as_f64().unwrap_or(0.05);
    let dims = summary["dims"].as_u64().unwrap_or(1) as usize;
    let t_end = summary["t_end"].as_f64().unwrap_or(f64::NAN);
    let mut written = Vec::new();

    let series = read_series(&run.join("series.csv"))?;
    plot::psi(
        &plots.join("psi.png"),
        &series,
        threshold,
        &format!("{name}: mixing index, mass drift, bound violations"),
    )?;
    written.push("psi.png".to_string());

    let fields = run.join("fields");
    let entries = read_pvd(&fields.join("series.pvd"))?;
    let n = entries.len();
    if dims == 1 {
        let plan = plot::frame_indices(n, plot::MAX_FRAMES_1D);
        let mut curves = Vec::with_capacity(plan.len());
        let mut geometry = None;
        let mut cells = None;
        for &k in &plan {
            let path = fields.join(&entries[k].1);
            let v = snapshot(&path, &mut cells)?;
            geometry.get_or_insert_with(|| (v.cells[2], v.origin[2], v.spacing[2]));
            curves.push((v.t, masked_plane(&v, &path)?));
        }
        if let Some((nz, z0, h)) = geometry {
            let z: Vec<f64> = (0..nz).map(|i| z0 + (i as f64 + 0.5) * h).collect();
            plot::profiles(
                &plots.join("phihat_profiles.png"),
                &format!("{name}: phihat profiles"),
                &z,
                (z0, z0 + nz as f64 * h),
                &curves,
            )?;
            written.push("phihat_profiles.png".into());
        }
    } else if n > 0 {
        let stills = plot::frame_indices(n, plot::MAX_FRAMES_MAP);
        let anim = plot::frame_indices(n, plot::MAX_FRAMES_GIF);
        let (prefix, what) = if dims == 3 {
            ("phihat_midplane", "phihat, mid-plane y slice")
        } else {
            ("phihat", "phihat")
        };
        let mut gif: Option<plot::Animation> = None;
        let gif_name = format!("{prefix}.gif");
        let mut cells = None;
        for k in 0..n {
            let (still, framed) = (stills.contains(&k), anim.contains(&k));
            if !still && !framed {
                continue;
            }
            let path = fields.join(&entries[k].1);
            let v = snapshot(&path, &mut cells)?;
            let grid = MapGrid {
                cells: (v.cells[0], v.cells[2]),
                x: (v.origin[0], v.origin[0] + v.cells[0] as f64 * v.spacing[0]),
                z: (v.origin[2], v.origin[2] + v.cells[2] as f64 * v.spacing[2]),
                labels: ("x".into(), "z".into()),
            };
            let values = masked_plane(&v, &path)?;
            let title = format!(
                "{name}: {what} at t = {} (output {k} of {})",
                super::num(v.t),
                n - 1
            );
            if still {
                let file = format!("{prefix}_{k:04}.png");
                plot::colour_map(&plots.join(&file), &title, &grid, &values)?;
                written.push(file);
            }
            if framed {
                if gif.is_none() {
                    // 0.25 s per frame; the last frame of a GIF shows until it loops.
                    gif = Some(plot::Animation::new(&plots.join(&gif_name), grid, 25)?);
                }
                if let Some(g) = gif.as_mut() {
                    g.frame(&title, &values)?;
                }
            }
        }
        if gif.is_some() {
            written.push(gif_name);
        }
    }

    let radial = run.join("radial.csv");
    if radial.exists() {
        let curves = read_radial(&radial)?;
        if !curves.is_empty() {
            plot::xy_curves(
                &plots.join("radial.png"),
                &format!(
                    "{name}: phihat about the circulation centre and the drum axis, t = {}",
                    super::num(t_end)
                ),
                "distance r [mm] (ring midpoint)",
                "mean phihat of the dense cells (c >= 0.3)",
                &curves,
                &[],
            )?;
            written.push("radial.png".into());
        }
    }

    // Scenes with an outlet (issue 9): the discharge curves.
    let discharge = run.join("discharge.csv");
    if discharge.exists() {
        let rows = crate::silo::read_csv(&discharge)?;
        // the on-spec band (docs/silo.md "On-spec discharge"), if the summary has a sane one
        let b = &summary["flow"]["outlet"]["fines_band"];
        let band = match (b[0].as_f64(), b[1].as_f64()) {
            (Some(lo), Some(hi)) => {
                Some([lo, hi]).filter(|&b| crate::scene::validate::fines_band_ok(b))
            }
            _ => None,
        };
        written.extend(discharge_plots(&rows, plots, &name, dims, band)?);
    }

    let profiles = run.join("profiles.csv");
    if profiles.exists() {
        let p = read_profiles(&profiles)?;
        plot::flow_profiles(plots, &name, &format!("t = {}", super::num(t_end)), &p)?;
        written.extend(
            [
                "flow_velocity.png",
                "flow_temperature.png",
                "flow_shear_ratio.png",
            ]
            .map(String::from),
        );
    }
    Ok(written)
}

/// The two radial profiles of `radial.csv` (drum.rs) as curves (r in mm, phihat), empty
/// rings left out.
fn read_radial(path: &Path) -> Result<Vec<plot::Curve>> {
    let text = crate::read::text(path, crate::read::MAX_FILE)?;
    let bad = |line: usize| {
        Error::failure(format!(
            "{}: line {line}: not a radial profile row",
            path.display()
        ))
    };
    let mut curves: Vec<plot::Curve> = Vec::new();
    for (k, line) in text.lines().enumerate().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 6 {
            return Err(bad(k + 1));
        }
        let num = |s: &str| s.parse::<f64>().map_err(|_| bad(k + 1));
        let (lo, hi, phihat) = (num(f[1])?, num(f[2])?, num(f[4])?);
        let label = if f[0] == "centre" {
            "about the circulation centre"
        } else {
            "about the drum axis"
        };
        if curves.last().is_none_or(|c| c.0 != label) {
            curves.push((label.into(), Vec::new()));
        }
        if phihat.is_finite() {
            if let Some(c) = curves.last_mut() {
                c.1.push((500.0 * (lo + hi), phihat));
            }
        }
    }
    curves.retain(|c| !c.1.is_empty());
    Ok(curves)
}

/// `sieve plot DIR`: redraws the pictures of the finished run in `dir` into `dir/plots`,
/// replacing the old ones atomically.
pub fn replot(dir: &Path) -> Result<(PathBuf, Vec<String>)> {
    if !dir.join("summary.json").is_file() {
        return Err(Error::Input(format!(
            "{}: not a finished run directory (no summary.json)",
            dir.display()
        )));
    }
    let staging = super::Staging::new(&dir.join("plots"))?;
    let written = redraw(dir, staging.path())?;
    let target = staging.commit()?;
    Ok((target, written))
}

/// The discharge pictures of a run with an outlet: `discharge.png` (the rate of all grains
/// and of the fines against time over the mass left in the silo) and `outflow_fines.png`
/// (the fines fraction of what left in each output interval: the number a controller wants,
/// issue 9). `dims` picks the unit (grain volume per unit depth in 2D). Rows before the
/// first outflow have no fines fraction and are left out of that curve; a run where nothing
/// has left yet draws only `discharge.png`. `band`: the on-spec band of the fines fraction
/// (`flow.outlet.fines_band`), drawn as its two edges. Returns the names of the files written.
pub fn discharge_plots(
    rows: &[DischargeRow],
    dir: &Path,
    name: &str,
    dims: usize,
    band: Option<[f64; 2]>,
) -> Result<Vec<String>> {
    let (q, m) = if dims == 3 {
        ("m^3", "m^3")
    } else {
        ("m^2", "m^2 (per unit depth)")
    };
    let curve = |label: &str, f: fn(&DischargeRow) -> f64, skip_first: bool| -> Curve {
        let pts = rows
            .iter()
            .skip(usize::from(skip_first))
            .map(|r| (r.t, f(r)))
            .filter(|p| p.1.is_finite())
            .collect();
        (label.to_string(), pts)
    };
    // a rate is the mean over the interval ending at its row: the first row has none
    let rates = [
        curve("all grains", |r| r.rate, true),
        curve("fines", |r| r.rate_small, true),
    ];
    let left = [
        curve("all grains", |r| r.mass, false),
        curve("fines", |r| r.mass_small, false),
    ];
    let mut written = Vec::new();
    plot::stacked_curves(
        &dir.join("discharge.png"),
        &format!("{name}: discharge rate and what is left in the silo"),
        "t [s]",
        &[
            (&format!("discharge rate [{q}/s]"), &rates),
            (&format!("left in the silo [{m}]"), &left),
        ],
    )?;
    written.push("discharge.png".to_string());
    let mut fines = vec![curve(
        "fines fraction of the discharge",
        |r| r.fines_fraction,
        true,
    )];
    if let (Some([lo, hi]), Some(first), Some(last)) = (band, rows.first(), rows.last()) {
        for (edge, v) in [("low", lo), ("high", hi)] {
            fines.push((
                format!("on-spec band, {edge} edge ({v:.3})"),
                vec![(first.t, v), (last.t, v)],
            ));
        }
    }
    if !fines[0].1.is_empty() {
        plot::stacked_curves(
            &dir.join("outflow_fines.png"),
            &format!("{name}: fines fraction of what leaves the outlet (per output interval)"),
            "t [s]",
            &[("fines fraction of the discharge", &fines)],
        )?;
        written.push("outflow_fines.png".to_string());
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 3 x 1 x 1 snapshot: a solid cell, an empty one, a filled one.
    fn snapshot(volume: Option<Vec<f64>>) -> Vti {
        let mut arrays = vec![
            ("phihat".to_string(), 1, vec![0.0, 0.0, 0.25]),
            ("c".to_string(), 1, vec![0.0, 0.0, 0.6]),
        ];
        if let Some(v) = volume {
            arrays.push(("volume".to_string(), 1, v));
        }
        Vti {
            cells: [3, 1, 1],
            origin: [0.0; 3],
            spacing: [1.0; 3],
            t: 0.0,
            arrays,
        }
    }

    #[test]
    fn the_solid_of_a_container_is_told_apart_from_empty_cells() {
        let v = masked_plane(&snapshot(Some(vec![0.0, 1.0, 0.4])), Path::new("t.vti")).unwrap();
        assert_eq!(v[0], plot::SOLID_CELL);
        assert!(v[1].is_nan(), "empty cell: {}", v[1]);
        assert_eq!(v[2], 0.25);
        // Without cut cells there is no solid: empty stays empty.
        let v = masked_plane(&snapshot(None), Path::new("t.vti")).unwrap();
        assert!(v[0].is_nan() && v[1].is_nan());
        // A volume array that does not match the grid is ignored, not indexed.
        let v = masked_plane(&snapshot(Some(vec![0.0])), Path::new("t.vti")).unwrap();
        assert!(v[0].is_nan());
    }
}
