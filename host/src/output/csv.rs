//! `series.csv` (diagnostics per output time) and `final.csv` (the final state per cell).

use super::{num, write_file};
use crate::data::{SeriesRow, Snapshot};
use crate::error::Result;
use crate::scene::Scene;
use std::fmt::Write;
use std::path::Path;

/// Header of `series.csv` (a contract: scripts rely on it).
pub const SERIES_HEADER: &str = "t,psi,mass,overshoot_max,undershoot_max";
/// Header of `final.csv` (a contract: scripts rely on it).
pub const FINAL_HEADER: &str = "x,y,z,c,phi,phihat,T,ux,uy,uz";

/// Writes one row per output time.
pub fn write_series(path: &Path, rows: &[SeriesRow]) -> Result<()> {
    let mut s = String::with_capacity(64 * (rows.len() + 1));
    s.push_str(SERIES_HEADER);
    s.push('\n');
    for r in rows {
        let _ = writeln!(
            s,
            "{},{},{},{},{}",
            num(r.t),
            num(r.psi),
            num(r.mass),
            num(r.overshoot_max),
            num(r.undershoot_max)
        );
    }
    write_file(path, s.as_bytes())
}

/// `final.csv` of a scene that solves a flow: [`FINAL_HEADER`] plus the pressure `p`.
pub const FINAL_HEADER_FLOW: &str = "x,y,z,c,phi,phihat,T,ux,uy,uz,p";

/// Writes one row per cell (solver cell order, x fastest); absent axes are 0. With a pressure
/// (flow scenes) the header is [`FINAL_HEADER_FLOW`]; scenes with a geometry add the open
/// volume fraction of each cell as a last column `volume` (0 = solid).
pub fn write_final(path: &Path, scene: &Scene, snap: &Snapshot) -> Result<()> {
    let phihat = snap.phihat();
    let mut s = String::with_capacity(120 * (snap.c.len() + 1));
    s.push_str(if snap.p.is_some() {
        FINAL_HEADER_FLOW
    } else {
        FINAL_HEADER
    });
    if snap.volume.is_some() {
        s.push_str(",volume");
    }
    s.push('\n');
    for i in 0..snap.c.len() {
        let p = scene.center(i);
        let u = snap.u[i];
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{},{},{}",
            num(p[0]),
            num(p[1]),
            num(p[2]),
            num(snap.c[i]),
            num(snap.phi[i]),
            num(phihat[i]),
            num(snap.temp[i]),
            num(u[0]),
            num(u[1]),
            num(u[2])
        );
        if let Some(p) = &snap.p {
            s.pop();
            let _ = writeln!(s, ",{}", num(p[i]));
        }
        if let Some(v) = &snap.volume {
            s.pop();
            let _ = writeln!(s, ",{}", num(v[i]));
        }
    }
    write_file(path, s.as_bytes())
}
