//! VTK XML ImageData (`.vti`) snapshots with raw appended little-endian Float64 cell data, and
//! the `.pvd` collection that gives ParaView their times. 1D columns become a line of cells
//! along z, 2D scenes an image in the x-z plane, 3D scenes a volume.

use super::write_file;
use crate::data::Snapshot;
use crate::error::Result;
use crate::scene::validate::physical_axes;
use crate::scene::Scene;
use std::fmt::Write;
use std::path::Path;

/// Writes one snapshot as `.vti`: cell arrays c, phi, phihat, T, the vector u, for scenes
/// that solve a flow the pressure p, for scenes with a geometry the open volume fraction.
pub fn write_vti(path: &Path, scene: &Scene, snap: &Snapshot) -> Result<()> {
    let mut cells = [0usize; 3];
    let mut origin = [0.0f64; 3];
    let mut spacing = [1.0f64; 3];
    let h = scene.spacing();
    for (a, &p) in physical_axes(scene.dim).iter().enumerate() {
        cells[p] = scene.cells[a];
        origin[p] = scene.lower[a];
        spacing[p] = h[a];
    }
    let extent = format!("0 {} 0 {} 0 {}", cells[0], cells[1], cells[2]);
    let phihat = snap.phihat();
    let u: Vec<f64> = snap.u.iter().flatten().copied().collect();
    let mut arrays: Vec<(&str, usize, &[f64])> = vec![
        ("phihat", 1, &phihat),
        ("phi", 1, &snap.phi),
        ("c", 1, &snap.c),
        ("T", 1, &snap.temp),
        ("u", 3, &u),
    ];
    if let Some(p) = &snap.p {
        arrays.push(("p", 1, p));
    }
    // Scenes with a geometry: the open volume fraction (0 = solid; threshold it at > 0 in
    // ParaView to hide the container's walls).
    if let Some(v) = &snap.volume {
        arrays.push(("volume", 1, v));
    }
    let mut xml = String::new();
    let _ = writeln!(xml, "<?xml version=\"1.0\"?>");
    let _ = writeln!(
        xml,
        "<VTKFile type=\"ImageData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">"
    );
    let _ = writeln!(
        xml,
        "  <ImageData WholeExtent=\"{extent}\" Origin=\"{} {} {}\" Spacing=\"{} {} {}\">",
        origin[0], origin[1], origin[2], spacing[0], spacing[1], spacing[2]
    );
    let _ = writeln!(
        xml,
        "    <FieldData>\n      <DataArray type=\"Float64\" Name=\"TimeValue\" NumberOfTuples=\"1\" format=\"ascii\">{}</DataArray>\n    </FieldData>",
        snap.t
    );
    let _ = writeln!(xml, "    <Piece Extent=\"{extent}\">");
    let _ = writeln!(xml, "      <CellData Scalars=\"phihat\" Vectors=\"u\">");
    let mut offset = 0usize;
    for (name, comps, data) in &arrays {
        let _ = writeln!(
            xml,
            "        <DataArray type=\"Float64\" Name=\"{name}\" NumberOfComponents=\"{comps}\" format=\"appended\" offset=\"{offset}\"/>"
        );
        offset += 8 + 8 * data.len();
    }
    let _ = writeln!(xml, "      </CellData>\n    </Piece>\n  </ImageData>");
    let _ = write!(xml, "  <AppendedData encoding=\"raw\">\n   _");
    let mut bytes = xml.into_bytes();
    bytes.reserve(offset + 64);
    for (_, _, data) in &arrays {
        bytes.extend_from_slice(&((8 * data.len()) as u64).to_le_bytes());
        for x in data.iter() {
            bytes.extend_from_slice(&x.to_le_bytes());
        }
    }
    bytes.extend_from_slice(b"\n  </AppendedData>\n</VTKFile>\n");
    write_file(path, &bytes)
}

/// Writes the `.pvd` collection of `(time, file name relative to the .pvd)` entries.
pub fn write_pvd(path: &Path, entries: &[(f64, String)]) -> Result<()> {
    let mut xml = String::new();
    let _ = writeln!(xml, "<?xml version=\"1.0\"?>");
    let _ = writeln!(
        xml,
        "<VTKFile type=\"Collection\" version=\"1.0\" byte_order=\"LittleEndian\">\n  <Collection>"
    );
    for (t, file) in entries {
        let _ = writeln!(
            xml,
            "    <DataSet timestep=\"{t}\" group=\"\" part=\"0\" file=\"{file}\"/>"
        );
    }
    let _ = writeln!(xml, "  </Collection>\n</VTKFile>");
    write_file(path, xml.as_bytes())
}
