//! VTK XML ImageData (`.vti`) snapshots with appended little-endian Float64 cell data, raw or
//! zlib-compressed, and the `.pvd` collection that gives ParaView their times. 1D columns
//! become a line of cells along z, 2D scenes an image in the x-z plane, 3D scenes a volume.
//!
//! Compressed snapshots (`[output] compress = true`, `--compress`) use VTK's standard
//! `compressor="vtkZLibDataCompressor"` with `header_type="UInt64"`: each array is one zlib
//! block preceded by the header `[1, n, n, c]` (blocks, uncompressed block size, size of the
//! last block, compressed size; UInt64 little-endian), as ParaView and VTK's
//! vtkXMLImageDataReader read it (docs/outputs.md).

use super::write_file;
use crate::data::Snapshot;
use crate::error::Result;
use crate::scene::validate::physical_axes;
use crate::scene::Scene;
use std::fmt::Write;
use std::ops::Range;
use std::path::Path;

/// Writes one snapshot as `.vti`: the cell arrays of `[output] fields` among phihat, phi, c,
/// T, the vector u, for scenes that solve a flow the pressure p, for scenes with a geometry
/// the open volume fraction; zlib-compressed if `[output] compress`.
pub fn write_vti(path: &Path, scene: &Scene, snap: &Snapshot) -> Result<()> {
    write_file(path, &vti_bytes(scene, snap))
}

/// The bytes of [`write_vti`].
pub fn vti_bytes(scene: &Scene, snap: &Snapshot) -> Vec<u8> {
    piece_bytes(scene, snap, 0..scene.cells[scene.dim - 1])
}

/// The extent (VTK point indices per physical axis) of rows `rows` of the last scene axis
/// (the axis the MPI ranks split, docs/parallel.md); the whole grid for all rows.
fn extent(scene: &Scene, rows: &Range<usize>) -> [usize; 6] {
    let mut e = [0usize; 6];
    let axes = physical_axes(scene.dim);
    for (a, &p) in axes.iter().enumerate() {
        e[2 * p + 1] = scene.cells[a];
    }
    let p = axes[scene.dim - 1];
    e[2 * p] = rows.start;
    e[2 * p + 1] = rows.end;
    e
}

fn extent_text(e: &[usize; 6]) -> String {
    format!("{} {} {} {} {} {}", e[0], e[1], e[2], e[3], e[4], e[5])
}

/// Origin and spacing per physical axis (absent axes: 0 and 1).
fn placement(scene: &Scene) -> ([f64; 3], [f64; 3]) {
    let mut origin = [0.0f64; 3];
    let mut spacing = [1.0f64; 3];
    let h = scene.spacing();
    for (a, &p) in physical_axes(scene.dim).iter().enumerate() {
        origin[p] = scene.lower[a];
        spacing[p] = h[a];
    }
    (origin, spacing)
}

/// The cell arrays a snapshot writes, `(name, components, values)` in file order: those of
/// `[output] fields` among phihat, phi, c, T, u, p (scenes that solve a flow) and volume
/// (scenes with a geometry).
fn cell_arrays<'a>(
    scene: &Scene,
    snap: &'a Snapshot,
    phihat: &'a [f64],
    u: &'a [f64],
) -> Vec<(&'static str, usize, &'a [f64])> {
    let out = &scene.output;
    let mut arrays = Vec::new();
    for (name, comps, data) in [
        ("phihat", 1, Some(phihat)),
        ("phi", 1, Some(&snap.phi[..])),
        ("c", 1, Some(&snap.c[..])),
        ("T", 1, Some(&snap.temp[..])),
        ("u", 3, Some(u)),
        // scenes that solve a flow
        ("p", 1, snap.p.as_deref()),
        // Scenes with a geometry: the open volume fraction (0 = solid; threshold it at > 0 in
        // ParaView to hide the container's walls).
        ("volume", 1, snap.volume.as_deref()),
    ] {
        if let Some(d) = data {
            if out.has(name) {
                arrays.push((name, comps, d));
            }
        }
    }
    arrays
}

/// A `.vti` of the cells of rows `rows` of the last scene axis, whose arrays `snap` holds
/// (only those rows' cells): one piece of a parallel snapshot ([`pvti_bytes`]), extent in
/// global indices (WholeExtent is the piece's own, so the file is also a valid image on its
/// own). All rows give the serial snapshot, byte for byte.
pub fn piece_bytes(scene: &Scene, snap: &Snapshot, rows: Range<usize>) -> Vec<u8> {
    let (origin, spacing) = placement(scene);
    let extent = extent_text(&extent(scene, &rows));
    let phihat = snap.phihat();
    let u: Vec<f64> = snap.u.iter().flatten().copied().collect();
    let out = &scene.output;
    let arrays = cell_arrays(scene, snap, &phihat, &u);
    // The data blocks first: with compression the offsets depend on the compressed sizes.
    let blocks: Vec<Vec<u8>> = arrays
        .iter()
        .map(|(_, _, data)| {
            let mut raw = Vec::with_capacity(8 * data.len());
            for x in data.iter() {
                raw.extend_from_slice(&x.to_le_bytes());
            }
            if out.compress {
                compressed_block(&raw)
            } else {
                let mut b = Vec::with_capacity(8 + raw.len());
                b.extend_from_slice(&(raw.len() as u64).to_le_bytes());
                b.extend_from_slice(&raw);
                b
            }
        })
        .collect();
    let compressor = if out.compress {
        " compressor=\"vtkZLibDataCompressor\""
    } else {
        ""
    };
    let mut xml = String::new();
    let _ = writeln!(xml, "<?xml version=\"1.0\"?>");
    let _ = writeln!(
        xml,
        "<VTKFile type=\"ImageData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\"{compressor}>"
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
    let vectors = if out.has("u") { " Vectors=\"u\"" } else { "" };
    let _ = writeln!(xml, "      <CellData Scalars=\"phihat\"{vectors}>");
    let mut offset = 0usize;
    for ((name, comps, _), block) in arrays.iter().zip(&blocks) {
        let _ = writeln!(
            xml,
            "        <DataArray type=\"Float64\" Name=\"{name}\" NumberOfComponents=\"{comps}\" format=\"appended\" offset=\"{offset}\"/>"
        );
        offset += block.len();
    }
    let _ = writeln!(xml, "      </CellData>\n    </Piece>\n  </ImageData>");
    let _ = write!(xml, "  <AppendedData encoding=\"raw\">\n   _");
    let mut bytes = xml.into_bytes();
    bytes.reserve(offset + 64);
    for b in &blocks {
        bytes.extend_from_slice(b);
    }
    bytes.extend_from_slice(b"\n  </AppendedData>\n</VTKFile>\n");
    bytes
}

/// One array as a single zlib block with its UInt64 header `[1, n, n, c]`.
fn compressed_block(raw: &[u8]) -> Vec<u8> {
    use flate2::write::ZlibEncoder;
    use std::io::Write as _;
    let mut enc = ZlibEncoder::new(Vec::new(), flate2::Compression::default());
    // Writing into a Vec cannot fail.
    let _ = enc.write_all(raw);
    let z = enc.finish().unwrap_or_default();
    let mut b = Vec::with_capacity(32 + z.len());
    for v in [1u64, raw.len() as u64, raw.len() as u64, z.len() as u64] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b.extend_from_slice(&z);
    b
}

/// Decompresses the blocks of one array of a `vtkZLibDataCompressor` file starting at `data`
/// (UInt64 header); `None` if it is corrupt or claims more than 1 GiB.
fn zlib_array(data: &[u8]) -> Option<Vec<u8>> {
    use std::io::Read as _;
    let word = |i: usize| -> Option<u64> {
        Some(u64::from_le_bytes(
            data.get(8 * i..8 * i + 8)?.try_into().ok()?,
        ))
    };
    let blocks = usize::try_from(word(0)?).ok()?;
    let block_size = word(1)?;
    let last = word(2)?;
    // bound every size before allocating: at most 1 GiB per array
    if blocks > 1 << 20 || block_size > 1 << 30 {
        return None;
    }
    let mut at = 8 * (3 + blocks);
    let mut out = Vec::new();
    for b in 0..blocks {
        let c = usize::try_from(word(3 + b)?).ok()?;
        let z = data.get(at..at.checked_add(c)?)?;
        let expect = if b + 1 == blocks && last != 0 {
            last
        } else {
            block_size
        };
        let mut dec = flate2::read::ZlibDecoder::new(z).take(expect);
        let before = out.len();
        dec.read_to_end(&mut out).ok()?;
        if (out.len() - before) as u64 != expect {
            return None;
        }
        at += c;
    }
    Some(out)
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

/// The `.pvti` of a parallel snapshot (docs/parallel.md): the whole grid's extent, origin and
/// spacing, the cell arrays of `snap` (any piece: every piece has the same arrays), and one
/// `(rows of the last scene axis, file relative to the .pvti)` entry per piece.
pub fn pvti_bytes(scene: &Scene, snap: &Snapshot, pieces: &[(Range<usize>, String)]) -> Vec<u8> {
    let (origin, spacing) = placement(scene);
    let whole = extent_text(&extent(scene, &(0..scene.cells[scene.dim - 1])));
    let phihat = snap.phihat();
    let u: Vec<f64> = snap.u.iter().flatten().copied().collect();
    let arrays = cell_arrays(scene, snap, &phihat, &u);
    let mut xml = String::new();
    let _ = writeln!(xml, "<?xml version=\"1.0\"?>");
    let _ = writeln!(
        xml,
        "<VTKFile type=\"PImageData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">"
    );
    let _ = writeln!(
        xml,
        "  <PImageData WholeExtent=\"{whole}\" GhostLevel=\"0\" Origin=\"{} {} {}\" Spacing=\"{} {} {}\">",
        origin[0], origin[1], origin[2], spacing[0], spacing[1], spacing[2]
    );
    let vectors = if scene.output.has("u") {
        " Vectors=\"u\""
    } else {
        ""
    };
    let _ = writeln!(xml, "    <PCellData Scalars=\"phihat\"{vectors}>");
    for (name, comps, _) in &arrays {
        let _ = writeln!(
            xml,
            "      <PDataArray type=\"Float64\" Name=\"{name}\" NumberOfComponents=\"{comps}\"/>"
        );
    }
    let _ = writeln!(xml, "    </PCellData>");
    for (rows, file) in pieces {
        let _ = writeln!(
            xml,
            "    <Piece Extent=\"{}\" Source=\"{file}\"/>",
            extent_text(&extent(scene, rows))
        );
    }
    let _ = writeln!(xml, "  </PImageData>\n</VTKFile>");
    xml.into_bytes()
}

/// Writes [`pvti_bytes`].
pub fn write_pvti(
    path: &Path,
    scene: &Scene,
    snap: &Snapshot,
    pieces: &[(Range<usize>, String)],
) -> Result<()> {
    write_file(path, &pvti_bytes(scene, snap, pieces))
}

/// A `.vti` written by [`write_vti`], read back (for `sieve plot`): the grid in physical axis
/// order (x, y, z; 1 cell on absent axes), the time, and the named cell arrays.
#[derive(Debug, Clone)]
pub struct Vti {
    /// Cells per physical axis.
    pub cells: [usize; 3],
    /// Lower corner per physical axis.
    pub origin: [f64; 3],
    /// Cell width per physical axis.
    pub spacing: [f64; 3],
    /// Time of the snapshot.
    pub t: f64,
    /// `(name, components, values)` in file order.
    pub arrays: Vec<(String, usize, Vec<f64>)>,
}

impl Vti {
    /// The values of array `name`, if present.
    pub fn array(&self, name: &str) -> Option<&[f64]> {
        self.arrays
            .iter()
            .find(|(n, _, _)| n == name)
            .map(|(_, _, v)| v.as_slice())
    }
}

/// The value of attribute `key="..."` in `tag`.
fn attr<'a>(tag: &'a str, key: &str) -> Option<&'a str> {
    let start = tag.find(&format!(" {key}=\""))? + key.len() + 3;
    let end = tag[start..].find('"')? + start;
    Some(&tag[start..end])
}

fn three(s: &str) -> Option<[f64; 3]> {
    let v: Vec<f64> = s
        .split_whitespace()
        .map(|x| x.parse().ok())
        .collect::<Option<_>>()?;
    (v.len() == 3).then(|| [v[0], v[1], v[2]])
}

/// Reads a `.vti` of [`write_vti`] (appended little-endian Float64, raw or zlib, UInt64
/// headers), or a `.pvti` of [`write_pvti`] with its pieces assembled into the whole grid
/// ([`read_pvti`]).
pub fn read_vti(path: &Path) -> Result<Vti> {
    if path.extension().is_some_and(|e| e == "pvti") {
        return read_pvti(path);
    }
    let bytes = crate::read::bytes(path, crate::read::MAX_FILE)?;
    vti_from_bytes(&bytes, &path.display().to_string())
}

/// The bytes of a `.vti` of [`vti_bytes`] read back (what [`read_vti`] reads from a file);
/// `name` names them in errors.
pub fn vti_from_bytes(bytes: &[u8], name: &str) -> Result<Vti> {
    use crate::error::Error;
    let bad = |why: &str| Error::failure(format!("{name}: not a sieve .vti file: {why}"));
    let marker = b"<AppendedData encoding=\"raw\">";
    let at = bytes
        .windows(marker.len())
        .position(|w| w == marker)
        .ok_or_else(|| bad("no raw appended data"))?;
    let header = std::str::from_utf8(&bytes[..at]).map_err(|_| bad("header is not UTF-8"))?;
    let underscore = bytes[at..]
        .iter()
        .position(|&b| b == b'_')
        .ok_or_else(|| bad("no '_' before the data"))?;
    let data = &bytes[at + underscore + 1..];
    let image = header
        .split('<')
        .find(|t| t.starts_with("ImageData "))
        .ok_or_else(|| bad("no ImageData"))?;
    let ext: Vec<usize> = attr(image, "WholeExtent")
        .ok_or_else(|| bad("no WholeExtent"))?
        .split_whitespace()
        .map(|x| x.parse().unwrap_or(0))
        .collect();
    if ext.len() != 6 {
        return Err(bad("WholeExtent needs 6 numbers"));
    }
    // Point extents: an absent axis has extent 0..0 (one point, no cell width) yet one layer
    // of cell data.
    // Checked: a hostile file's reversed extent once underflowed (a panic).
    let width = |a: usize| ext[2 * a + 1].checked_sub(ext[2 * a]).map(|w| w.max(1));
    let (Some(c0), Some(c1), Some(c2)) = (width(0), width(1), width(2)) else {
        return Err(bad("WholeExtent has an upper bound below its lower bound"));
    };
    let cells = [c0, c1, c2];
    let origin = attr(image, "Origin")
        .and_then(three)
        .ok_or_else(|| bad("no Origin"))?;
    let spacing = attr(image, "Spacing")
        .and_then(three)
        .ok_or_else(|| bad("no Spacing"))?;
    let t = header
        .find("Name=\"TimeValue\"")
        .and_then(|i| {
            let rest = &header[i..];
            let s = rest.find('>')? + 1;
            let e = rest[s..].find('<')? + s;
            rest[s..e].trim().parse().ok()
        })
        .ok_or_else(|| bad("no TimeValue"))?;
    let compressed = header.contains("compressor=\"vtkZLibDataCompressor\"");
    let mut arrays = Vec::new();
    for tag in header.split('<').filter(|t| t.starts_with("DataArray ")) {
        if attr(tag, "format") != Some("appended") {
            continue;
        }
        let name = attr(tag, "Name").ok_or_else(|| bad("DataArray without Name"))?;
        let comps: usize = attr(tag, "NumberOfComponents")
            .and_then(|c| c.parse().ok())
            .unwrap_or(1);
        let offset: usize = attr(tag, "offset")
            .and_then(|c| c.parse().ok())
            .ok_or_else(|| bad("DataArray without offset"))?;
        let unzipped;
        let raw = if compressed {
            unzipped = data
                .get(offset..)
                .and_then(zlib_array)
                .ok_or_else(|| bad("corrupt zlib block"))?;
            &unzipped[..]
        } else {
            // Offsets and lengths come from the file: checked sums, sliced only within the file.
            let start = offset
                .checked_add(8)
                .ok_or_else(|| bad("offset out of range"))?;
            let len_bytes = data
                .get(offset..start)
                .ok_or_else(|| bad("truncated data"))?;
            let len = u64::from_le_bytes(len_bytes.try_into().map_err(|_| bad("length"))?);
            usize::try_from(len)
                .ok()
                .and_then(|l| start.checked_add(l))
                .and_then(|end| data.get(start..end))
                .ok_or_else(|| bad("truncated data"))?
        };
        let values = raw
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8])))
            .collect();
        arrays.push((name.to_string(), comps, values));
    }
    Ok(Vti {
        cells,
        origin,
        spacing,
        t,
        arrays,
    })
}

/// Most pieces and values a `.pvti` may claim (a hostile file must not allocate without
/// bound): 2^16 pieces, 2^30 values per array.
const PVTI_MAX_PIECES: usize = 1 << 16;
const PVTI_MAX_VALUES: usize = 1 << 30;

/// Reads a `.pvti` of [`write_pvti`]: every piece (a `.vti` beside it) read by [`read_vti`]
/// and placed by its extent. Refused unless the pieces cover every cell of the whole extent
/// exactly once, agree on the time and hold the same arrays: so a `sieve run` under mpirun
/// reads back as the serial run's snapshot, value for value (`.ci/mpi-check`).
pub fn read_pvti(path: &Path) -> Result<Vti> {
    use crate::error::Error;
    let text = crate::read::text(path, crate::read::MAX_FILE)?;
    let bad =
        |why: String| Error::failure(format!("{}: not a sieve .pvti file: {why}", path.display()));
    let numbers = |s: &str| -> Option<[usize; 6]> {
        let v: Vec<usize> = s
            .split_whitespace()
            .map(|x| x.parse().ok())
            .collect::<Option<_>>()?;
        let e: [usize; 6] = v.try_into().ok()?;
        (0..3).all(|a| e[2 * a] <= e[2 * a + 1]).then_some(e)
    };
    let image = text
        .split('<')
        .find(|t| t.starts_with("PImageData "))
        .ok_or_else(|| bad("no PImageData".into()))?;
    let whole = attr(image, "WholeExtent")
        .and_then(numbers)
        .ok_or_else(|| bad("no valid WholeExtent".into()))?;
    let origin = attr(image, "Origin")
        .and_then(three)
        .ok_or_else(|| bad("no Origin".into()))?;
    let spacing = attr(image, "Spacing")
        .and_then(three)
        .ok_or_else(|| bad("no Spacing".into()))?;
    // cells per axis: an absent axis (extent 0 0) holds one layer of cells
    let width = |e: &[usize; 6], a: usize| (e[2 * a + 1] - e[2 * a]).max(1);
    let cells = [width(&whole, 0), width(&whole, 1), width(&whole, 2)];
    let total = cells
        .iter()
        .try_fold(1usize, |n, &c| n.checked_mul(c))
        .filter(|&n| n <= PVTI_MAX_VALUES)
        .ok_or_else(|| bad("WholeExtent too large".into()))?;
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut covered = vec![0u8; total];
    let mut arrays: Vec<(String, usize, Vec<f64>)> = Vec::new();
    let mut t = None;
    let pieces: Vec<&str> = text
        .split('<')
        .filter(|t| t.starts_with("Piece "))
        .collect();
    if pieces.is_empty() || pieces.len() > PVTI_MAX_PIECES {
        return Err(bad(format!("{} pieces", pieces.len())));
    }
    for tag in pieces {
        let ext = attr(tag, "Extent")
            .and_then(numbers)
            .ok_or_else(|| bad("a Piece without a valid Extent".into()))?;
        let source = attr(tag, "Source").ok_or_else(|| bad("a Piece without Source".into()))?;
        // a piece is a plain .vti beside the .pvti (no nesting, no other directory)
        if source.ends_with(".pvti") || source.contains("..") || source.starts_with('/') {
            return Err(bad(format!("piece {source} is not a .vti beside it")));
        }
        let inside = (0..3).all(|a| {
            whole[2 * a] <= ext[2 * a]
                && ext[2 * a + 1] <= whole[2 * a + 1]
                && (ext[2 * a] < ext[2 * a + 1] || whole[2 * a] == whole[2 * a + 1])
        });
        if !inside {
            return Err(bad(format!(
                "piece {source}: extent outside the whole extent"
            )));
        }
        let v = read_vti(&dir.join(source))?;
        let pc = [width(&ext, 0), width(&ext, 1), width(&ext, 2)];
        if v.cells != pc {
            return Err(bad(format!(
                "piece {source}: {:?} cells, its extent says {pc:?}",
                v.cells
            )));
        }
        if t.is_some_and(|t: f64| t.to_bits() != v.t.to_bits()) {
            return Err(bad(format!(
                "piece {source}: time {} differs from the first piece's",
                v.t
            )));
        }
        t = Some(v.t);
        if arrays.is_empty() {
            arrays = v
                .arrays
                .iter()
                .map(|(n, c, _)| (n.clone(), *c, vec![0.0; total * c]))
                .collect();
        }
        if v.arrays.len() != arrays.len() {
            return Err(bad(format!(
                "piece {source}: other arrays than the first piece"
            )));
        }
        let o = [ext[0] - whole[0], ext[2] - whole[2], ext[4] - whole[4]];
        let n = pc[0] * pc[1] * pc[2];
        for l in 0..n {
            let (i, j, k) = (l % pc[0], (l / pc[0]) % pc[1], l / (pc[0] * pc[1]));
            let g = (o[0] + i) + cells[0] * ((o[1] + j) + cells[1] * (o[2] + k));
            covered[g] = covered[g].saturating_add(1);
        }
        for ((name, comps, whole_values), (pname, pcomps, values)) in
            arrays.iter_mut().zip(&v.arrays)
        {
            if name != pname || comps != pcomps || values.len() != n * *comps {
                return Err(bad(format!("piece {source}: array {pname} does not match")));
            }
            for l in 0..n {
                let (i, j, k) = (l % pc[0], (l / pc[0]) % pc[1], l / (pc[0] * pc[1]));
                let g = (o[0] + i) + cells[0] * ((o[1] + j) + cells[1] * (o[2] + k));
                whole_values[g * *comps..(g + 1) * *comps]
                    .copy_from_slice(&values[l * *comps..(l + 1) * *comps]);
            }
        }
    }
    if let Some(g) = covered.iter().position(|&c| c != 1) {
        return Err(bad(format!(
            "the pieces cover cell {g} {} times (every cell exactly once expected)",
            covered[g]
        )));
    }
    Ok(Vti {
        cells,
        origin,
        spacing,
        t: t.unwrap_or(0.0),
        arrays,
    })
}
