//! Domain decomposition on threads (issue 12, docs/parallel.md): the same bits for 1, 2, 3 and
//! 4 threads.
//!
//! In process: a serial solver and the threaded driver ([`sieve::parallel::Driver`]) take the
//! same steps one at a time, and after every step the state hash (core/src/hash.rs), the
//! flushed-mass counter and the bound maxima must agree to the bit; a failure names the first
//! step and the first cell (with its coordinates) where the two differ. The grids have row
//! counts that no thread count divides (23, 11), a periodic split axis (the first and last
//! subdomains are neighbours), inflow, diffusion, T and direction from the velocity gradient
//! (halo 2), compensated updates, the large phase, and cells that are flushed (docs/model.md
//! 5.6). Through the CLI: `--threads 1` and `--threads 3` write the same files byte for byte.

use crate::common::run_in;
use sieve::parallel::Driver;
use sieve_core::geometry::{CutCells, Primitive, Region};
use sieve_core::segregation::SegregationConfig;
use sieve_core::{
    state_hash, Boundaries, Boundary, DirectionMode, Grid, Phase, Scheme, Segregation,
    TemperatureMode,
};
use std::path::{Path, PathBuf};

const N: usize = 1024;
type Solver = Segregation<f64, 2, N>;
type Solver3 = Segregation<f64, 3, N>;

/// A smooth, nowhere-symmetric field in [0, 1) from the cell index (so every cell differs).
fn wiggle(i: usize, k: f64) -> f64 {
    let x = i as f64 * 0.618_033_988_75 * k;
    x - x.floor()
}

/// Fills `s`: c in [0.45, 0.6] (a few empty cells), phi in [0, c] with some cells far below
/// the flush floor, velocity `u(i)`, T given.
fn fill<const D: usize>(
    s: &mut Segregation<f64, D, N>,
    u: impl Fn(&Grid<f64, D>, usize) -> [f64; D],
) {
    let g = *s.grid();
    for i in 0..g.len() {
        let c = if i % 97 == 5 {
            0.0
        } else {
            0.45 + 0.15 * wiggle(i, 1.0)
        };
        // the top three rows: fines far below the flush floor 2^-800 (the fines sink, so
        // the top row stays that small until the first flush)
        let top = g.coords(i)[D - 1] + 3 >= g.cells()[D - 1];
        let phi = match i % 13 {
            _ if top => 1e-250 * (1.0 + wiggle(i, 5.0)),
            1 => c,
            2 => 0.0,
            _ => c * wiggle(i, 3.0),
        };
        let t = 1e-3 * (1.0 + wiggle(i, 7.0));
        s.set_cell(i, c, t, u(&g, i), phi.min(c));
        s.set_inflow(i, 0.5 * c);
    }
}

/// Where two solvers first differ, in words (step, cell, coordinates, values).
fn first_difference<const D: usize>(
    a: &Segregation<f64, D, N>,
    b: &Segregation<f64, D, N>,
    step: usize,
    what: &str,
) -> String {
    for i in 0..a.len() {
        if a.phi(i).to_bits() != b.phi(i).to_bits() || a.carry(i).to_bits() != b.carry(i).to_bits()
        {
            return format!(
                "{what}: first divergence at step {step}, cell {i} {:?}: phi {:e} (serial) vs {:e} (threads)",
                a.grid().coords(i),
                a.phi(i),
                b.phi(i)
            );
        }
    }
    format!(
        "{what}: first divergence at step {step} in the clock or counters: t {:e} vs {:e}, flushed {:e} vs {:e}, excess {:?} vs {:?}, side books {:?} vs {:?}",
        a.time(),
        b.time(),
        a.flushed_tracked(),
        b.flushed_tracked(),
        a.tracked_excess(),
        b.tracked_excess(),
        a.small_mass_out_through_sides(),
        b.small_mass_out_through_sides()
    )
}

/// Steps `serial` and a copy driven by `threads` threads one step at a time to `t_end`
/// (the last step shortened, as in a run), comparing after every step. Returns the steps.
fn same_bits<const D: usize>(serial: &Segregation<f64, D, N>, threads: usize, what: &str) -> usize {
    same_bits_on(serial, None, threads, what)
}

/// [`same_bits`] on cut cells `geo` when given (the serial solver steps with
/// `advance_to_embedded`, the driver's subdomains on their slabs of `geo`).
fn same_bits_on<const D: usize>(
    serial: &Segregation<f64, D, N>,
    geo: Option<&CutCells<f64, D, N>>,
    threads: usize,
    what: &str,
) -> usize {
    let advance = |s: &mut Segregation<f64, D, N>, t: f64, n: u64| match geo {
        Some(g) => s.advance_to_embedded(t, n, g),
        None => s.advance_to(t, n),
    };
    let dt = match geo {
        Some(g) => serial.stable_dt_embedded(g),
        None => serial.stable_dt(),
    };
    let mut a = serial.clone();
    let mut b = serial.clone();
    let driver = Driver::new(&b, geo, threads).unwrap();
    assert_eq!(driver.parts(), threads, "{what}: split into fewer parts");
    let t_end = 40.5 * dt;
    let mut step = 0;
    while a.time() < t_end {
        step += 1;
        let na = advance(&mut a, t_end, 1);
        let nb = driver.advance(&mut b, t_end, 1);
        assert_eq!((na, nb), (1, 1));
        let same = state_hash(&a) == state_hash(&b)
            && a.steps() == b.steps()
            && a.flushed_tracked().to_bits() == b.flushed_tracked().to_bits()
            && a.tracked_excess().map(f64::to_bits) == b.tracked_excess().map(f64::to_bits)
            && a.side_books() == b.side_books();
        assert!(same, "{}", first_difference(&a, &b, step, what));
    }
    // and in chunks of several steps (what the run loop asks for)
    let (mut c, mut d) = (serial.clone(), serial.clone());
    let driver = Driver::new(&d, geo, threads).unwrap();
    let target = 7.25 * dt;
    advance(&mut c, target, 5);
    driver.advance(&mut d, target, 5);
    advance(&mut c, t_end, u64::MAX);
    driver.advance(&mut d, t_end, u64::MAX);
    assert_eq!(state_hash(&c), state_hash(&a), "{what}: chunked serial");
    assert!(
        state_hash(&d) == state_hash(&a)
            && d.flushed_tracked() == a.flushed_tracked()
            && d.side_books() == a.side_books(),
        "{}",
        first_difference(&a, &d, step, &format!("{what}, in chunks"))
    );
    step
}

fn grid2(nx: usize, ny: usize) -> Grid<f64, 2> {
    Grid::new([nx, ny], [0.0, 0.0], [0.037, 0.023], N).unwrap()
}

/// A 2D shear layer (x periodic, walls or periodic in y), T and direction from the velocity
/// gradient: halo 2.
fn shear_2d(bc_y: Boundary, phase: Phase, compensated: bool) -> Solver {
    shear_2d_with(bc_y, phase, compensated, Scheme::Modified)
}

fn shear_2d_with(bc_y: Boundary, phase: Phase, compensated: bool, scheme: Scheme) -> Solver {
    let mut s = Solver::zeroed();
    let mut cfg = SegregationConfig::new();
    cfg.scheme = scheme;
    cfg.gravity = [0.0, -9.81];
    cfg.s0 = 0.3;
    cfg.direction = DirectionMode::Flow;
    cfg.temperature = TemperatureMode::FromShear {
        heating: 1.5,
        eta0: 1e-3,
        eps0: 10.0,
    };
    cfg.diffusion = 1e-7;
    cfg.phase = phase;
    cfg.compensated = compensated;
    let bc: Boundaries<2> = [[Boundary::Periodic; 2], [bc_y; 2]];
    s.setup(grid2(37, 23), bc, cfg).unwrap();
    fill(&mut s, |g, i| {
        let [x, y] = g.center(i);
        [
            0.02 * (y / 0.023).powi(2) + 1e-3 * (x * 170.0).sin(),
            1e-3 * (x * 170.0).cos() * (y * 137.0).sin(),
        ]
    });
    s.prepare().unwrap();
    s
}

#[test]
fn two_d_shear_same_bits_for_1_to_4_threads() {
    let s = shear_2d(Boundary::Wall, Phase::Small, false);
    assert_eq!(sieve_core::decomp::halo_width(&s), 2);
    let mut steps = 0;
    for threads in 1..=4 {
        steps = same_bits(&s, threads, &format!("2D walls, {threads} threads"));
    }
    assert!(steps >= 40, "{steps} steps");
    // the flush happened (phi = 1e-250 cells) and was counted
    let mut a = s.clone();
    a.advance_to(40.5 * s.stable_dt(), u64::MAX);
    assert!(a.flushed_tracked() > 0.0 && a.flushed_tracked() < 1e-240);
}

#[test]
fn two_d_periodic_split_axis_large_phase_compensated() {
    for (phase, compensated, scheme) in [
        (Phase::Large, false, Scheme::Modified),
        (Phase::Small, true, Scheme::Modified),
        // the naive fluxes overshoot: the bound maxima must come from owned cells only
        (Phase::Small, false, Scheme::Godunov),
        (Phase::Large, false, Scheme::Upwind),
    ] {
        let s = shear_2d_with(Boundary::Periodic, phase, compensated, scheme);
        for threads in [2, 3, 4] {
            let what = format!("2D periodic y, {phase:?}, {scheme:?}, compensated {compensated}, {threads} threads");
            same_bits(&s, threads, &what);
        }
    }
}

/// Open sides on both axes, the split one included: every subdomain books the faces of its
/// own cells, the driver merges the books, and they equal the serial solver's to the bit after
/// every step (checked in [`same_bits`]); the books close the small phase's mass.
#[test]
fn open_sides_are_booked_with_the_same_bits_on_threads() {
    let mut s = Solver::zeroed();
    let mut cfg = SegregationConfig::new();
    cfg.gravity = [0.0, -9.81];
    cfg.s0 = 0.3;
    cfg.diffusion = 1e-7;
    let bc: Boundaries<2> = [
        [Boundary::Inflow, Boundary::Outflow],
        [Boundary::Outflow, Boundary::Inflow],
    ];
    s.setup(grid2(37, 23), bc, cfg).unwrap();
    fill(&mut s, |g, i| {
        let [x, y] = g.center(i);
        [0.02 + 0.3 * y, -0.01 - 0.2 * x]
    });
    s.prepare().unwrap();
    for threads in 1..=4 {
        same_bits(&s, threads, &format!("2D open sides, {threads} threads"));
    }
    let mass = |s: &Solver| sieve_core::diagnose(s).mass_small;
    let mut a = s.clone();
    a.advance_to(40.5 * s.stable_dt(), u64::MAX);
    let out = a.small_mass_out_through_sides();
    // fines come in at x = 0 and y = top, leave at x = max and y = 0
    assert!(
        out[0][0] < 0.0 && out[0][1] > 0.0 && out[1][0] > 0.0 && out[1][1] < 0.0,
        "{out:?}"
    );
    let net: f64 = out.iter().flatten().sum();
    let gap = mass(&a) + a.flushed_small_mass() + net - mass(&s);
    let scale = mass(&s) + out.iter().flatten().map(|x| x.abs()).sum::<f64>();
    assert!(gap.abs() < 1e-14 * scale, "unbooked {gap:e} of {scale:e}");
    // without the books the same run would miss this much
    assert!(net.abs() > 1e-6 * scale, "net exchange {net:e}");
}

#[test]
fn three_d_same_bits_for_1_to_4_threads() {
    // 9 x 7 x 11: 11 rows; gravity direction and given T (halo 1), inflow at x = 0,
    // outflow at x = 1, periodic in y, walls in z, diffusion.
    let mut s = Solver3::zeroed();
    let mut cfg = SegregationConfig::new();
    cfg.gravity = [0.5, 0.0, -9.81];
    cfg.diffusion = 2e-7;
    let bc: Boundaries<3> = [
        [Boundary::Inflow, Boundary::Outflow],
        [Boundary::Periodic; 2],
        [Boundary::Wall; 2],
    ];
    let g = Grid::new([9, 7, 11], [0.0; 3], [0.009, 0.007, 0.011], N).unwrap();
    s.setup(g, bc, cfg).unwrap();
    fill(&mut s, |g, i| {
        let [_, _, z] = g.center(i);
        [0.01 * z / 0.011, 0.0, 0.0]
    });
    s.prepare().unwrap();
    assert_eq!(sieve_core::decomp::halo_width(&s), 1);
    for threads in 1..=4 {
        same_bits(&s, threads, &format!("3D, {threads} threads"));
    }
    // 11 rows allow 11 parts of halo 1; more are clamped
    assert_eq!(Driver::new(&s, None, 64).unwrap().parts(), 11);
}

/// Merge groups of `geo` whose cells the split into `parts` parts puts in different
/// subdomains (the case the cut-cell halo's [`sieve_core::decomp::GROUP_REACH`] is for).
fn groups_across_cuts(geo: &CutCells<f64, 2, N>, parts: usize) -> usize {
    let [nx, rows] = geo.grid().cells();
    let part = |i: usize| {
        let r = i / nx;
        (0..parts)
            .position(|k| sieve_core::decomp::owned_rows(rows, parts, k).contains(&r))
            .unwrap()
    };
    (0..geo.len())
        .filter(|&i| !geo.is_solid(i) && part(geo.master(i)) != part(i))
        .count()
}

/// Cut cells on threads (docs/parallel.md): a drum in the 37 x 23 shear layer (x periodic,
/// walls in y), placed for each split so that the sliver cells of its bottom lie in the last
/// row of the first subdomain and merge (threshold 1/2) into the row above, across the cut;
/// stepped by the serial embedded step and by the driver on 2 to 5 threads: the same bits
/// after every step, with T and the direction from the velocity gradient (halo 2 + 2) and
/// with given T along gravity (halo 1 + 2), flushes included. With a halo of the box step's
/// width only, the bits differ (the test can fail).
#[test]
fn cut_cells_same_bits_on_threads() {
    let h = 0.023 / 23.0;
    let radius = 0.006;
    for gradient in [true, false] {
        let mut s = shear_2d(Boundary::Wall, Phase::Small, false);
        if !gradient {
            let mut cfg = *s.config();
            cfg.direction = DirectionMode::Gravity;
            cfg.temperature = TemperatureMode::Given;
            let (grid, bc) = (*s.grid(), *s.boundaries());
            let mut t = Solver::zeroed();
            t.setup(grid, bc, cfg).unwrap();
            fill(&mut t, |_, _| [0.0, 0.0]);
            s = t;
        }
        let halo = sieve_core::decomp::halo_width_cut(&s);
        assert_eq!(
            halo,
            sieve_core::decomp::GROUP_REACH + if gradient { 2 } else { 1 }
        );
        let most = sieve_core::decomp::max_parts(23, halo);
        for threads in 2..=most.min(5) {
            let cut = sieve_core::decomp::owned_rows(23, threads, 0).end;
            let bottom = (cut - 1) as f64 * h + 0.63 * h;
            let drum = Region::drum([0.0185, bottom + radius], radius);
            // a channel one row and two slivers high: the slivers above and below merge into
            // the middle row, whose groups then span three rows across the cut
            let (lo, hi) = (
                (cut - 1) as f64 * h + 0.7 * h,
                (cut + 1) as f64 * h + 0.3 * h,
            );
            let channel = Region::new()
                .intersect(Primitive::HalfSpace {
                    point: [0.0, lo],
                    normal: [0.0, -1.0],
                })
                .intersect(Primitive::HalfSpace {
                    point: [0.0, hi],
                    normal: [0.0, 1.0],
                });
            for (shape, region) in [("drum", &drum), ("channel", &channel)] {
                let mut geo = CutCells::<f64, 2, N>::zeroed();
                geo.build(s.grid(), region, [true, false], 0.5).unwrap();
                let mut a = s.clone();
                // (no inflow boundary here; the group means could put c below fill's inflow)
                for i in 0..a.len() {
                    a.set_inflow(i, 0.0);
                }
                a.prepare_embedded(&geo).unwrap();
                let across = groups_across_cuts(&geo, threads);
                assert!(across > 0, "{threads} parts: no group across a cut");
                let what = format!(
                "{shape}, gradient {gradient}, {threads} threads ({across} merged cells across cuts)"
            );
                same_bits_on(&a, Some(&geo), threads, &what);
                if threads == 2 && shape == "drum" {
                    let dt = a.stable_dt_embedded(&geo);
                    a.advance_to_embedded(40.5 * dt, u64::MAX, &geo);
                    assert!(a.flushed_tracked() > 0.0, "nothing was flushed");
                }
            }
        }
    }
}

#[test]
fn row_sums_fold_to_the_same_bits_for_any_split() {
    use sieve_core::decomp::{owned_rows, RowSums};
    let s = shear_2d(Boundary::Wall, Phase::Small, false);
    let rows = s.grid().cells()[1];
    let plane = s.grid().cells()[0];
    let fold = |parts: usize| {
        let mut total = RowSums::ZERO;
        for k in 0..parts {
            let mut partial = Vec::new();
            RowSums::of_rows(&s, owned_rows(rows, parts, k), plane, |r| partial.push(r));
            partial.into_iter().for_each(|r| total.add(r));
        }
        total
    };
    let one = fold(1);
    for parts in [2, 3, 5, 23] {
        let p = fold(parts);
        assert_eq!(
            [p.small, p.total, p.entropy].map(f64::to_bits),
            [one.small, one.total, one.entropy].map(f64::to_bits),
            "{parts} parts"
        );
    }
    // and the serial diagnostics within the blocked sum's error bound
    let d = sieve_core::diagnose(&s);
    let vol = s.grid().cell_volume();
    let abs: f64 = (0..s.len()).map(|i| s.phi(i).abs()).sum();
    let bound = sieve_core::sum::error_bound(s.len(), abs) * 2.0 + 1e-300;
    assert!((one.small * vol - d.mass_small).abs() <= bound * vol);
    assert!(
        (one.psi() - d.psi).abs() < 1e-12,
        "{} vs {}",
        one.psi(),
        d.psi
    );
}

// ---- the CLI: --threads 1 and --threads 3 write the same files ----

/// summary.json without the wall-clock timings (the only values that may differ).
fn summary_without_timings(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("summary.json")).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let o = v.as_object_mut().unwrap();
    for k in [
        "wall_seconds",
        "stepping_seconds",
        "cell_updates_per_second",
    ] {
        assert!(o.remove(k).is_some(), "summary.json has no {k}");
    }
    if let Some(f) = o.get_mut("flow").and_then(|f| f.as_object_mut()) {
        f.remove("flow_seconds");
    }
    v
}

fn data_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for top in ["", "fields"] {
        for e in std::fs::read_dir(dir.join(top)).unwrap() {
            let p = e.unwrap().path();
            let name = p.file_name().unwrap();
            if p.is_file() && name != "summary.json" && name != ".sieve-run" {
                out.push(p.strip_prefix(dir).unwrap().to_path_buf());
            }
        }
    }
    out.sort();
    out
}

/// Runs `args` on 1 and 3 threads; asserts the same files and summary, which it returns.
fn same_outputs(args: &[&str]) -> serde_json::Value {
    let d = tempfile::tempdir().unwrap();
    for (threads, out) in [("1", "one"), ("3", "three")] {
        let mut a = vec!["run"];
        a.extend_from_slice(args);
        a.extend_from_slice(&["--threads", threads, "--out", out, "-q"]);
        let (code, err) = run_in(d.path(), &a);
        assert_eq!(code, 0, "{args:?} --threads {threads}: {err}");
        assert!(err.is_empty(), "{args:?} --threads {threads}: {err}");
    }
    let (a, b) = (d.path().join("one"), d.path().join("three"));
    let files = data_files(&a);
    assert_eq!(files, data_files(&b), "{args:?}: different files");
    assert!(files.iter().any(|f| f.ends_with("final.csv")));
    assert!(files.iter().any(|f| f.ends_with("series.csv")));
    for f in &files {
        assert!(
            std::fs::read(a.join(f)).unwrap() == std::fs::read(b.join(f)).unwrap(),
            "{args:?}: {} differs between 1 and 3 threads",
            f.display()
        );
    }
    let summary = summary_without_timings(&a);
    assert_eq!(summary, summary_without_timings(&b), "{args:?}");
    summary
}

#[test]
fn cli_threads_1_and_3_write_the_same_files() {
    // 2D, direction from the flow, x-periodic, 80 x 80 (80 rows: 27/27/26 per thread); 6,400
    // cells, so the diagnoses' entropy terms are cut among the pool's workers too, in the
    // step-by-step replay of the crossing at t = 1.96 s as well
    let s = same_outputs(&["shear-cell-inverse", "--grid", "80x80", "--t-end", "20"]);
    assert!(s["segregation_time"].as_f64().unwrap() > 1.0, "{s}");
    // 2D with inflow and outflow, 61 rows (uneven): the open sides' books close the mass
    let s = same_outputs(&["gray-thornton-plug", "--grid", "60x61", "--t-end", "0.2"]);
    let sides = &s["mass_out_sides"];
    let (x_low, x_high) = (
        sides["x_low"].as_f64().unwrap(),
        sides["x_high"].as_f64().unwrap(),
    );
    // the plug carries u c phihat = 1 x 0.6 x 0.6 per unit height in at x = 0: 0.072 by 0.2 s
    assert!((x_low + 0.072).abs() < 1e-14, "{s}");
    assert!(x_high > 0.0, "{s}");
    assert!(s["mass_rel_drift"].as_f64().unwrap() < 1e-13, "{s}");
}

#[test]
fn cli_threads_cut_cells() {
    // a prescribed scene on cut cells: the drum's subdomains step on their slabs of the cut
    // cells (96 rows: 32 / 32 / 32 per thread, the drum's walls cross every cut)
    let s = same_outputs(&["drum-settling", "--grid", "48x96", "--t-end", "0.6"]);
    assert!(s["segregation_time"].as_f64().unwrap() > 0.3, "{s}");
}

#[test]
fn cli_threads_frozen_flow() {
    // the segregation part of a frozen-flow scene
    same_outputs(&["shear-cell", "--grid", "16x16", "--t-end", "2"]);
}

#[test]
fn cli_threads_coupled_flow() {
    // the coupled flow's linear solves on the pool (host/src/pool.rs), on grids of at least
    // 65,536 cells (below that they stay on one thread, with a note: next test)
    same_outputs(&["column-collapse", "--grid", "640x128", "--t-end", "0.0001"]);
    // cut cells in the rotating frame
    same_outputs(&["tumbler", "--grid", "256x256", "--t-end", "0.001"]);
}

#[test]
fn cli_threads_refusals_and_notes() {
    let d = tempfile::tempdir().unwrap();
    for bad in ["0", "-1", "1025", "1e9", "two"] {
        let (code, err) = run_in(d.path(), &["run", "column-a", "--threads", bad, "-q"]);
        assert_eq!(code, 2, "--threads {bad}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "--threads {bad}: {err}");
        assert!(err.contains("--threads"), "--threads {bad}: {err}");
    }
    // a scene the split does not take (cut cells periodic along the split axis) runs on one
    // thread, with a one-line note
    let note = one_note(
        d.path(),
        &[
            "drum-settling",
            "--set",
            "boundary.z=[\"periodic\",\"periodic\"]",
            "--t-end",
            "0.1",
            "--out",
            "g",
        ],
    );
    assert!(
        note.contains("periodic along their last axis run on one thread"),
        "{note}"
    );
    // a coupled grid below 65,536 cells runs its solves on one thread, with a one-line note
    let note = one_note(
        d.path(),
        &["column-collapse", "--t-end", "0.001", "--out", "c"],
    );
    assert!(
        note.contains("1280 cells runs its solves on one thread"),
        "{note}"
    );
}

/// Runs `sieve run ARGS --threads 2` in `dir`; asserts success and exactly one note on stderr,
/// which it returns.
fn one_note(dir: &Path, args: &[&str]) -> String {
    let mut a = vec!["run"];
    a.extend_from_slice(args);
    a.extend_from_slice(&["--threads", "2"]);
    let (code, err) = run_in(dir, &a);
    assert_eq!(code, 0, "{args:?}: {err}");
    let notes: Vec<&str> = err.lines().filter(|l| l.starts_with("note:")).collect();
    assert_eq!(notes.len(), 1, "{args:?}: {err}");
    notes[0].to_string()
}
