//! Parallel VTK snapshots (docs/parallel.md, "MPI: sieve run under mpirun"), without MPI:
//! the pieces `sieve run` writes on each rank and the `.pvti` naming them read back as the
//! serial `.vti`, value for value, for 1D, 2D and 3D grids split into 1, 2, 3 and 5 parts
//! (uneven remainders); one piece of all rows is the serial file byte for byte; a `.pvti`
//! whose pieces overlap or leave a gap is refused. `.ci/mpi-check` checks the same on real
//! `mpirun` runs.

use sieve::data::Snapshot;
use sieve::output::vtk::{piece_bytes, pvti_bytes, read_vti, vti_bytes, Vti};
use sieve::scene::validate::physical_axes;
use sieve::scene::{Fields, Scene};
use sieve_core::decomp::owned_rows;
use std::path::Path;

/// A snapshot of the scene's initial fields at t = 0.25, with a pressure so that the
/// optional array is covered too.
fn snapshot(scene: &Scene, fields: &Fields) -> Snapshot {
    let n = scene.len();
    let u = (0..n)
        .map(|i| {
            let mut u = [0.0; 3];
            for (a, &p) in physical_axes(scene.dim).iter().enumerate() {
                u[p] = fields.u[a][i];
            }
            u
        })
        .collect();
    Snapshot {
        t: 0.25,
        c: fields.c.clone(),
        phi: fields.phi.clone(),
        temp: fields.t.clone(),
        u,
        p: Some((0..n).map(|i| 1.0 + i as f64 / 7.0).collect()),
        volume: None,
    }
}

/// The cells of rows `rows` of the last axis.
fn rows_of(s: &Snapshot, plane: usize, rows: &std::ops::Range<usize>) -> Snapshot {
    let r = rows.start * plane..rows.end * plane;
    Snapshot {
        t: s.t,
        c: s.c[r.clone()].to_vec(),
        phi: s.phi[r.clone()].to_vec(),
        temp: s.temp[r.clone()].to_vec(),
        u: s.u[r.clone()].to_vec(),
        p: s.p.as_ref().map(|p| p[r.clone()].to_vec()),
        volume: None,
    }
}

fn assert_same(a: &Vti, b: &Vti, what: &str) {
    assert_eq!(a.cells, b.cells, "{what}: cells");
    assert_eq!(a.origin, b.origin, "{what}: origin");
    assert_eq!(a.spacing, b.spacing, "{what}: spacing");
    assert_eq!(a.t.to_bits(), b.t.to_bits(), "{what}: time");
    assert_eq!(a.arrays.len(), b.arrays.len(), "{what}: arrays");
    for ((n, c, v), (m, d, w)) in a.arrays.iter().zip(&b.arrays) {
        assert_eq!((n, c), (m, d), "{what}");
        let bits = |x: &[f64]| x.iter().map(|y| y.to_bits()).collect::<Vec<_>>();
        assert!(bits(v) == bits(w), "{what}: array {n} differs");
    }
}

/// Writes the pieces of `parts` parts and their .pvti into `dir`; returns the .pvti's path
/// and its text.
fn write_parts(
    dir: &Path,
    scene: &Scene,
    snap: &Snapshot,
    parts: usize,
) -> (std::path::PathBuf, String) {
    let rows = scene.cells[scene.dim - 1];
    let plane = scene.len() / rows;
    let mut pieces = Vec::new();
    for k in 0..parts {
        let r = owned_rows(rows, parts, k);
        let name = format!("state_0001_{k}.vti");
        std::fs::write(
            dir.join(&name),
            piece_bytes(scene, &rows_of(snap, plane, &r), r.clone()),
        )
        .unwrap();
        pieces.push((r, name));
    }
    let text = String::from_utf8(pvti_bytes(scene, snap, &pieces)).unwrap();
    let path = dir.join("state_0001.pvti");
    std::fs::write(&path, &text).unwrap();
    (path, text)
}

#[test]
fn pieces_read_back_as_the_serial_snapshot() {
    let box3d = concat!(env!("CARGO_MANIFEST_DIR"), "/../.ci/mpi-box-3d.toml");
    let cases: [(&str, Vec<String>); 3] = [
        ("column-a", vec![]),
        ("gray-thornton-plug", vec!["grid.cells=[12,11]".into()]),
        (box3d, vec!["output.compress=true".into()]),
    ];
    for (name, sets) in cases {
        let (scene, fields) = sieve::scene::load(name, &sets).unwrap();
        let snap = snapshot(&scene, &fields);
        let tmp = tempfile::tempdir().unwrap();
        let serial = tmp.path().join("serial.vti");
        let bytes = vti_bytes(&scene, &snap);
        let rows = scene.cells[scene.dim - 1];
        // one piece of every row is the serial file, byte for byte
        assert!(
            piece_bytes(&scene, &snap, 0..rows) == bytes,
            "{name}: one piece"
        );
        std::fs::write(&serial, &bytes).unwrap();
        let want = read_vti(&serial).unwrap();
        assert_eq!(want.arrays.len(), 6, "{name}: phihat, phi, c, T, u, p");
        for parts in [1, 2, 3, 5] {
            let dir = tmp.path().join(format!("p{parts}"));
            std::fs::create_dir(&dir).unwrap();
            let (pvti, _) = write_parts(&dir, &scene, &snap, parts);
            let got = read_vti(&pvti).unwrap();
            assert_same(&got, &want, &format!("{name}, {parts} pieces"));
        }
    }
}

#[test]
fn overlapping_or_missing_pieces_are_refused() {
    let (scene, fields) =
        sieve::scene::load("gray-thornton-plug", &["grid.cells=[12,11]".into()]).unwrap();
    let snap = snapshot(&scene, &fields);
    let tmp = tempfile::tempdir().unwrap();
    let (pvti, text) = write_parts(tmp.path(), &scene, &snap, 3);
    assert!(read_vti(&pvti).is_ok());
    // rows 3..7 of piece 1 claimed as 2..6: row 2 twice, row 6 never
    let shifted = text.replace("Extent=\"0 12 0 0 3 7\"", "Extent=\"0 12 0 0 2 6\"");
    assert_ne!(shifted, text, "the .pvti names rows 3..7");
    std::fs::write(&pvti, &shifted).unwrap();
    let e = read_vti(&pvti).unwrap_err().to_string();
    assert!(e.contains("exactly once"), "{e}");
    // a piece left out
    let missing: String = text
        .lines()
        .filter(|l| !l.contains("state_0001_2.vti"))
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(&pvti, &missing).unwrap();
    let e = read_vti(&pvti).unwrap_err().to_string();
    assert!(e.contains("0 times"), "{e}");
    // a piece of another size than its extent says
    let wrong = text.replace("Extent=\"0 12 0 0 3 7\"", "Extent=\"0 12 0 0 3 8\"");
    std::fs::write(&pvti, &wrong).unwrap();
    let e = read_vti(&pvti).unwrap_err().to_string();
    assert!(e.contains("cells, its extent says"), "{e}");
}
