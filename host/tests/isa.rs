//! Run-time SIMD dispatch (issue 12, host/src/isa.rs, docs/simd.md): every instruction-set
//! level gives the baseline's bits.
//!
//! In process: one solver stepped at `baseline` and copies stepped at every wider level this
//! CPU has, one step at a time; after every step the state hash, the flushed-mass counter and
//! the bound maxima must agree to the bit, and a failure names the first step and cell. The
//! cases cover the three fluxes, diffusion, inflow/outflow, periodic and wall boundaries, the
//! large phase, compensated updates, flushed cells (docs/model.md 5.6), 1D, 2D and 3D, f32 and
//! the percolation step. Through the CLI: `SIEVE_ISA=baseline` and `SIEVE_ISA=auto` write the
//! same files byte for byte, and a bad `SIEVE_ISA` exits 2 with one line.
//!
//! On a CPU without AVX2 only the baseline runs and the comparisons are trivial; the test says
//! so on stderr. In the default (native) build the baseline is itself wide code; the portable
//! build (`RUSTFLAGS="-C target-cpu=x86-64"`) compares SSE2 against AVX2 and AVX-512 code.

use crate::common::run_env;
use sieve::isa::{self, Avx2, Avx512, Level};
use sieve_core::segregation::{Baseline, Isa, SegregationConfig};
use sieve_core::{
    state_hash, Boundaries, Boundary, DirectionMode, Grid, Phase, Real, Scheme, Segregation,
    TemperatureMode,
};
use std::path::Path;

const N: usize = 1024;

/// The wider levels this CPU runs (each is compared against the baseline).
fn wide_levels() -> Vec<Level> {
    let v: Vec<Level> = [Level::Avx2, Level::Avx512]
        .into_iter()
        .filter(|l| l.available())
        .collect();
    if v.is_empty() {
        eprintln!("note: this CPU has no AVX2: only the baseline runs");
    }
    v
}

/// A smooth, nowhere-symmetric field in [0, 1) from the cell index.
fn wiggle(i: usize, k: f64) -> f64 {
    let x = i as f64 * 0.618_033_988_75 * k;
    x - x.floor()
}

/// Fills every cell: c in [0.45, 0.6] (some empty cells), phi in [0, c] with the top rows far
/// below the flush floor, T given (ignored where T comes from the shear), inflow 0.5 c.
fn fill<R: Real, const D: usize>(
    s: &mut Segregation<R, D, N>,
    u: impl Fn(&Grid<R, D>, usize) -> [R; D],
) {
    let g = *s.grid();
    for i in 0..g.len() {
        let c = if i % 97 == 5 {
            0.0
        } else {
            0.45 + 0.15 * wiggle(i, 1.0)
        };
        let top = g.coords(i)[D - 1] + 3 >= g.cells()[D - 1];
        let phi = match i % 13 {
            _ if top => 1e-250 * (1.0 + wiggle(i, 5.0)),
            1 => c,
            2 => 0.0,
            _ => c * wiggle(i, 3.0),
        };
        let t = 1e-3 * (1.0 + wiggle(i, 7.0));
        let c = R::from_f64(c);
        s.set_cell(i, c, R::from_f64(t), u(&g, i), R::from_f64(phi).min(c));
        s.set_inflow(i, R::HALF * c);
    }
}

struct Case {
    scheme: Scheme,
    phase: Phase,
    compensated: bool,
    diffusion: f64,
    shear_t: bool,
    bc_y: Boundary,
}

fn config<R: Real, const D: usize>(case: &Case) -> SegregationConfig<R, D> {
    let mut cfg = SegregationConfig::new();
    cfg.scheme = case.scheme;
    cfg.phase = case.phase;
    cfg.compensated = case.compensated;
    cfg.diffusion = R::from_f64(case.diffusion);
    cfg.s0 = R::from_f64(0.3);
    let mut gravity = [R::ZERO; D];
    gravity[D - 1] = R::from_f64(-9.81);
    cfg.gravity = gravity;
    if case.shear_t {
        cfg.direction = DirectionMode::Flow;
        cfg.temperature = TemperatureMode::FromShear {
            heating: R::from_f64(1.5),
            eta0: R::from_f64(1e-3),
            eps0: R::from_f64(10.0),
        };
    }
    cfg
}

/// A 2D shear layer on 37 x 23 cells (x periodic).
fn shear_2d<R: Real>(case: &Case) -> Segregation<R, 2, N> {
    let mut s = Segregation::<R, 2, N>::zeroed();
    let grid = Grid::new(
        [37, 23],
        [R::ZERO; 2],
        [R::from_f64(0.037), R::from_f64(0.023)],
        N,
    )
    .unwrap();
    let bc: Boundaries<2> = [[Boundary::Periodic; 2], [case.bc_y; 2]];
    s.setup(grid, bc, config(case)).unwrap();
    fill(&mut s, |g, i| {
        let [x, y] = g.center(i).map(|v| v.to_f64());
        [
            R::from_f64(0.02 * (y / 0.023).powi(2) + 1e-3 * (x * 170.0).sin()),
            R::from_f64(1e-3 * (x * 170.0).cos() * (y * 137.0).sin()),
        ]
    });
    s.prepare().unwrap();
    s
}

/// A 3D box on 9 x 7 x 11 cells: inflow at x = 0, outflow at x = 1, walls elsewhere.
fn box_3d(case: &Case) -> Segregation<f64, 3, N> {
    let mut s = Segregation::<f64, 3, N>::zeroed();
    let grid = Grid::new([9, 7, 11], [0.0; 3], [0.09, 0.07, 0.11], N).unwrap();
    let bc: Boundaries<3> = [
        [Boundary::Inflow, Boundary::Outflow],
        [Boundary::Periodic; 2],
        [Boundary::Wall; 2],
    ];
    s.setup(grid, bc, config(case)).unwrap();
    fill(&mut s, |g, i| {
        let [x, y, z] = g.center(i);
        [
            0.01 + 0.02 * z,
            1e-3 * (x * 90.0).sin(),
            -1e-3 * (y * 70.0).cos(),
        ]
    });
    s.prepare().unwrap();
    s
}

/// 1D column: 200 cells, walls, the uniform fast path when `uniform`, else the general loop.
fn column(uniform: bool) -> Segregation<f64, 1, N> {
    let mut s = Segregation::<f64, 1, N>::zeroed();
    let grid = Grid::new([200], [0.0], [1.0], N).unwrap();
    let mut cfg = SegregationConfig::new();
    cfg.gravity = [-1.0];
    s.setup(grid, [[Boundary::Wall; 2]], cfg).unwrap();
    for i in 0..200 {
        // -0.0 changes no face velocity but makes the coefficients non-uniform
        // (core/benches/column_a_vs_c.rs)
        let u = if !uniform && i == 66 { -0.0 } else { 0.0 };
        s.set_cell(i, 0.64, 1.0, [u], 0.64 * wiggle(i, 1.0));
    }
    s.prepare().unwrap();
    assert_eq!(s.uniform_axes(), [uniform]);
    s
}

/// Where `a` and `b` first differ, in words.
fn difference<R: Real, const D: usize>(
    a: &Segregation<R, D, N>,
    b: &Segregation<R, D, N>,
    step: usize,
    what: &str,
) -> String {
    for i in 0..a.len() {
        if a.phi(i).to_bits_u64() != b.phi(i).to_bits_u64()
            || a.carry(i).to_bits_u64() != b.carry(i).to_bits_u64()
        {
            return format!(
                "{what}: first divergence at step {step}, cell {i} {:?}: phi {:e} (baseline) vs {:e}",
                a.grid().coords(i),
                a.phi(i).to_f64(),
                b.phi(i).to_f64()
            );
        }
    }
    format!("{what}: first divergence at step {step} in the clock or counters")
}

fn same<R: Real, const D: usize>(a: &Segregation<R, D, N>, b: &Segregation<R, D, N>) -> bool {
    state_hash(a) == state_hash(b)
        && a.steps() == b.steps()
        && a.flushed_tracked().to_bits_u64() == b.flushed_tracked().to_bits_u64()
        && a.tracked_excess().map(|x| x.to_bits_u64())
            == b.tracked_excess().map(|x| x.to_bits_u64())
}

/// Steps `start` at the baseline and at every wide level one step at a time (40.5 stable
/// steps, the last shortened), comparing after each; then once more in chunks through
/// `advance_to_at`. Returns the number of steps.
fn same_bits<R: Real, const D: usize>(start: &Segregation<R, D, N>, what: &str) -> usize {
    let t_end = R::from_f64(40.5) * start.stable_dt();
    let mut steps = 0;
    for level in wide_levels() {
        let what = format!("{what}, {}", level.name());
        let (mut a, mut b) = (start.clone(), start.clone());
        steps = 0;
        while a.time() < t_end {
            steps += 1;
            let na = isa::advance_to_at(Level::Baseline, &mut a, t_end, 1);
            let nb = isa::advance_to_at(level, &mut b, t_end, 1);
            assert_eq!((na, nb), (1, 1), "{what}");
            assert!(same(&a, &b), "{}", difference(&a, &b, steps, &what));
        }
        let mut c = start.clone();
        isa::advance_to_at(level, &mut c, R::from_f64(7.25) * start.stable_dt(), 5);
        isa::advance_to_at(level, &mut c, t_end, u64::MAX);
        assert!(
            same(&a, &c),
            "{}",
            difference(&a, &c, steps, &format!("{what}, in chunks"))
        );
        // and it moved: the comparison is not of two untouched states
        assert_ne!(state_hash(&a), state_hash(start), "{what}: nothing moved");
    }
    steps
}

const MODIFIED_WALLS: Case = Case {
    scheme: Scheme::Modified,
    phase: Phase::Small,
    compensated: false,
    diffusion: 0.0,
    shear_t: true,
    bc_y: Boundary::Wall,
};

#[test]
fn two_d_every_flux_and_boundary_same_bits() {
    let cases = [
        MODIFIED_WALLS,
        Case {
            diffusion: 1e-7,
            bc_y: Boundary::Periodic,
            ..MODIFIED_WALLS
        },
        Case {
            scheme: Scheme::Godunov,
            diffusion: 1e-7,
            ..MODIFIED_WALLS
        },
        Case {
            scheme: Scheme::Upwind,
            phase: Phase::Large,
            bc_y: Boundary::Periodic,
            ..MODIFIED_WALLS
        },
        Case {
            compensated: true,
            shear_t: false,
            ..MODIFIED_WALLS
        },
    ];
    for (k, case) in cases.iter().enumerate() {
        let s = shear_2d::<f64>(case);
        let steps = same_bits(&s, &format!("2D f64 case {k}"));
        assert!(steps == 0 || steps >= 40, "{steps} steps");
    }
    // the flush ran and was counted in the first case (phi = 1e-250 cells)
    let mut a = shear_2d::<f64>(&cases[0]);
    let t = 40.5 * a.stable_dt();
    a.advance_to(t, u64::MAX);
    assert!(a.flushed_tracked() > 0.0 && a.flushed_tracked() < 1e-240);
}

#[test]
fn f32_three_d_and_one_d_same_bits() {
    let s = shear_2d::<f32>(&Case {
        diffusion: 1e-7,
        ..MODIFIED_WALLS
    });
    same_bits(&s, "2D f32");
    let s = box_3d(&Case {
        shear_t: false,
        diffusion: 1e-6,
        ..MODIFIED_WALLS
    });
    same_bits(&s, "3D inflow/outflow");
    same_bits(&column(true), "1D uniform fast path");
    same_bits(&column(false), "1D general loop");
}

/// The percolation step (no transport) through the runners directly.
#[test]
fn percolation_step_same_bits() {
    let start = shear_2d::<f64>(&Case {
        diffusion: 1e-7,
        ..MODIFIED_WALLS
    });
    let dt = start.stable_dt();
    let mut a = start.clone();
    for _ in 0..30 {
        a.step_percolation_on::<Baseline>(dt);
    }
    assert_ne!(state_hash(&a), state_hash(&start));
    let run = |f: fn(&mut Segregation<f64, 2, N>, f64)| {
        let mut b = start.clone();
        for _ in 0..30 {
            f(&mut b, dt);
        }
        b
    };
    fn on<I: Isa>(s: &mut Segregation<f64, 2, N>, dt: f64) {
        s.step_percolation_on::<I>(dt)
    }
    let mut b = start.clone();
    for _ in 0..30 {
        b.step_percolation(dt);
    }
    assert!(same(&a, &b), "step_percolation is the baseline");
    for level in wide_levels() {
        let b = match level {
            Level::Avx2 => run(on::<Avx2>),
            _ => run(on::<Avx512>),
        };
        assert!(same(&a, &b), "{}", difference(&a, &b, 30, level.name()));
    }
}

#[test]
fn sieve_isa_values() {
    assert_eq!(isa::requested(Some("baseline")).unwrap(), Level::Baseline);
    assert_eq!(isa::requested(None).unwrap(), Level::widest());
    assert_eq!(isa::requested(Some("auto")).unwrap(), Level::widest());
    for level in [Level::Avx2, Level::Avx512] {
        let r = isa::requested(Some(level.name()));
        assert_eq!(r.is_ok(), level.available(), "{r:?}");
        if let Err(e) = r {
            assert_eq!(e.exit_code(), 2);
        }
    }
    let e = isa::requested(Some("sse9")).unwrap_err();
    assert_eq!(e.exit_code(), 2);
    assert!(e.to_string().contains("SIEVE_ISA"), "{e}");
}

fn data_files(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for top in ["", "fields"] {
        let Ok(entries) = std::fs::read_dir(dir.join(top)) else {
            continue;
        };
        for e in entries {
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

/// The arguments of `sieve run SCENE --grid G --t-end T --threads 1 --out OUT -q`.
fn run_args<'a>(scene: &'a str, grid: &'a str, t_end: &'a str, out: &'a str) -> [&'a str; 11] {
    [
        "run",
        scene,
        "--grid",
        grid,
        "--t-end",
        t_end,
        "--threads",
        "1",
        "--out",
        out,
        "-q",
    ]
}

/// `sieve run` of `scene` at `SIEVE_ISA=baseline` and `auto` writes the same data files.
fn same_files_at_baseline_and_auto(d: &Path, scene: &str, grid: &str, t_end: &str) {
    let args = |out| run_args(scene, grid, t_end, out);
    let (code, _, err) = run_env(d, &args("base"), &[("SIEVE_ISA", "baseline")]);
    assert_eq!(code, 0, "{scene}: {err}");
    let (code, _, err) = run_env(d, &args("auto"), &[("SIEVE_ISA", "auto")]);
    assert_eq!(code, 0, "{scene}: {err}");
    let (a, b) = (d.join("base"), d.join("auto"));
    let files = data_files(&a);
    assert!(files.iter().any(|f| f.ends_with("final.csv")), "{files:?}");
    assert_eq!(files, data_files(&b));
    for f in &files {
        assert!(
            std::fs::read(a.join(f)).unwrap() == std::fs::read(b.join(f)).unwrap(),
            "{scene}: {} differs between SIEVE_ISA=baseline and auto",
            f.display()
        );
    }
    for out in [a, b] {
        std::fs::remove_dir_all(out).unwrap();
    }
}

/// The segregation step (gray-thornton-plug), the same on cut cells (drum-settling), and the
/// coupled flow in a box (column-collapse) and on cut cells (tumbler), whose steps dispatch
/// through `AtLevel` (`Fork::Isa`).
#[test]
fn cli_same_files_at_every_level_and_bad_values() {
    let d = tempfile::tempdir().unwrap();
    same_files_at_baseline_and_auto(d.path(), "gray-thornton-plug", "60x31", "0.2");
    same_files_at_baseline_and_auto(d.path(), "drum-settling", "32x32", "0.2");
    same_files_at_baseline_and_auto(d.path(), "column-collapse", "48x12", "0.05");
    same_files_at_baseline_and_auto(d.path(), "tumbler", "32x32", "0.2");
    let args = |out| run_args("gray-thornton-plug", "60x31", "0.2", out);
    for bad in ["sse9", "AVX2 please"] {
        let (code, _, err) = run_env(d.path(), &args("bad"), &[("SIEVE_ISA", bad)]);
        assert_eq!(code, 2, "{bad}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{bad}: {err}");
        assert!(err.contains("SIEVE_ISA"), "{bad}: {err}");
    }
}

/// A 1D column (the fused one-axis update of core/src/segregation/step.rs: no increment
/// array, the flux read twice) against the same column as a 1 x n 2D grid (walls in x: zero
/// x fluxes, so the general two-axis update adds exactly the same terms in the same order),
/// stepped with the same dt at every level: the same phi bit for bit, for the three fluxes,
/// diffusion, inflow/outflow and periodic ends, uniform and varying coefficients.
#[test]
fn fused_one_d_update_equals_the_general_update() {
    const M: usize = 150;
    let cases = [
        (Scheme::Modified, 0.0, [Boundary::Wall; 2], true),
        (Scheme::Modified, 0.0, [Boundary::Wall; 2], false),
        (
            Scheme::Godunov,
            1e-4,
            [Boundary::Inflow, Boundary::Outflow],
            false,
        ),
        (Scheme::Upwind, 1e-4, [Boundary::Periodic; 2], false),
        (
            Scheme::Modified,
            1e-4,
            [Boundary::Outflow, Boundary::Inflow],
            true,
        ),
    ];
    for (k, (scheme, diffusion, ends, uniform)) in cases.into_iter().enumerate() {
        let mut cfg1 = SegregationConfig::<f64, 1>::new();
        let mut cfg2 = SegregationConfig::<f64, 2>::new();
        cfg1.scheme = scheme;
        cfg2.scheme = scheme;
        cfg1.diffusion = diffusion;
        cfg2.diffusion = diffusion;
        cfg1.gravity = [-1.0];
        cfg2.gravity = [0.0, -1.0];
        let mut a = Segregation::<f64, 1, N>::zeroed();
        let mut b = Segregation::<f64, 2, N>::zeroed();
        a.setup(Grid::new([M], [0.0], [1.0], N).unwrap(), [ends], cfg1)
            .unwrap();
        b.setup(
            Grid::new([1, M], [0.0; 2], [0.01, 1.0], N).unwrap(),
            [[Boundary::Wall; 2], ends],
            cfg2,
        )
        .unwrap();
        for i in 0..M {
            let c = if uniform {
                0.6
            } else {
                0.45 + 0.15 * wiggle(i, 1.0)
            };
            let u = if uniform {
                0.0
            } else {
                0.3 * wiggle(i, 2.0) - 0.1
            };
            let phi = c * wiggle(i, 3.0);
            a.set_cell(i, c, 1.0, [u], phi);
            b.set_cell(i, c, 1.0, [0.0, u], phi);
            a.set_inflow(i, 0.5 * c);
            b.set_inflow(i, 0.5 * c);
        }
        a.prepare().unwrap();
        b.prepare().unwrap();
        assert_eq!(a.uniform_axes(), [uniform], "case {k}");
        let dt = a.stable_dt().min(b.stable_dt());
        let levels = std::iter::once(Level::Baseline).chain(wide_levels());
        for level in levels {
            let (mut a, mut b) = (a.clone(), b.clone());
            for step in 1..=60 {
                isa::step_at(level, &mut a, dt);
                isa::step_at(level, &mut b, dt);
                for i in 0..M {
                    assert!(
                        a.phi(i).to_bits() == b.phi(i).to_bits(),
                        "case {k}, {}: step {step}, cell {i}: phi {:e} (1D) vs {:e} (1 x n)",
                        level.name(),
                        a.phi(i),
                        b.phi(i)
                    );
                }
            }
            assert_eq!(a.tracked_excess(), b.tracked_excess(), "case {k}");
            assert_eq!(a.flushed_tracked(), b.flushed_tracked(), "case {k}");
        }
    }
}
