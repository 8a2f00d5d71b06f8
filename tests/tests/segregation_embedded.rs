//! The segregation solver on cut cells (core/src/segregation/embedded.rs, issue 8).
//!
//! A disc drum at rest (u = 0, T = 1, c = 0.6, S0 = 1, gravity -z) from a mixed start
//! segregates under gravity: fines and total mass to round-off over every step, 0 <= phi <= c
//! exactly in every open cell (cells down to 1e-6 of a cell included), the stable step within
//! a stated factor of the box step, fines at the bottom at the end (Psi falls, the fines'
//! centre of mass below the bed's), bit-identical reruns. With no walls the embedded step
//! gives the box step's bits. A drum with a baffle and diffusion, and a 3D drum slice, keep
//! mass and bounds too.

use sieve_core::geometry::{CutCells, Region};
use sieve_core::{
    diagnose, diagnose_embedded, state_hash, Boundaries, Boundary, Grid, Phase, Real, Scheme,
    Segregation, SegregationConfig,
};

const N: usize = 1 << 14;

/// Round-off allowance for a mass after `steps` steps: each step may move the sum by a few
/// ulps (the group update rounds `q + sum(dq) / V_G` once per group).
fn round_off(steps: u64) -> f64 {
    4.0 * f64::EPSILON * steps as f64
}

fn boxed<T: Send + 'static>(make: fn() -> T) -> Box<T> {
    std::thread::Builder::new()
        .stack_size(256 << 20)
        .spawn(move || Box::new(make()))
        .expect("spawn")
        .join()
        .expect("builder thread")
}

type Seg2 = Segregation<f64, 2, N>;
type Geo2 = CutCells<f64, 2, N>;

/// The drum of the tests: radius 0.3 in the unit box, centred so that the 64 x 64 grid has
/// cut cells below 1e-6 of a cell (found by tests/tests/geometry.rs).
const CENTRE: [f64; 2] = [0.500731, 0.500377];
const RADIUS: f64 = 0.3;

fn config(phase: Phase, diffusion: f64) -> SegregationConfig<f64, 2> {
    let mut cfg = SegregationConfig::new();
    cfg.phase = phase;
    cfg.s0 = 1.0;
    cfg.gravity = [0.0, -1.0];
    cfg.diffusion = diffusion;
    cfg
}

/// A drum at rest, mixed (phihat = 1/2), on n x n cells.
fn drum(n: usize, region: &Region<f64, 2>, phase: Phase, diffusion: f64) -> (Box<Seg2>, Box<Geo2>) {
    let mut s = boxed(Seg2::zeroed);
    let mut g = boxed(Geo2::zeroed);
    let grid = Grid::new([n, n], [0.0, 0.0], [1.0, 1.0], N).unwrap();
    g.build(&grid, region, [false, false], 0.5).unwrap();
    s.setup(grid, [[Boundary::Wall; 2]; 2], config(phase, diffusion))
        .unwrap();
    for i in 0..grid.len() {
        s.set_cell(i, 0.6, 1.0, [0.0, 0.0], 0.3);
    }
    s.prepare_embedded(&g).unwrap();
    (s, g)
}

/// Checks 0 <= phi <= c in every open cell, exactly; returns the number of open cells
/// with volume below 1e-3 that were checked.
fn assert_bounds(s: &Seg2, g: &Geo2, step: u64) -> usize {
    let mut tiny = 0;
    for i in 0..s.len() {
        if g.is_solid(i) {
            continue;
        }
        let (phi, c) = (s.phi(i), s.c(i));
        assert!(
            phi >= 0.0 && phi <= c,
            "step {step}: cell {i} (V = {:e}) phi = {phi:e} outside [0, {c}]",
            g.volume(i)
        );
        if g.volume(i) < 1e-3 {
            tiny += 1;
        }
    }
    tiny
}

/// Heights of the centres of mass of the fines and of the bed (open-volume weighted).
fn centres_of_mass(s: &Seg2, g: &Geo2) -> (f64, f64) {
    let (mut zf, mut mf, mut zb, mut mb) = (0.0, 0.0, 0.0, 0.0);
    for i in 0..s.len() {
        let z = g.open_centroid(i)[1];
        let v = g.volume(i);
        zf += z * s.phi(i) * v;
        mf += s.phi(i) * v;
        zb += z * s.c(i) * v;
        mb += s.c(i) * v;
    }
    (zf / mf, zb / mb)
}

#[test]
fn drum_at_rest_segregates_with_mass_and_bounds_kept() {
    let n = 64;
    let (mut s, g) = drum(n, &Region::drum(CENTRE, RADIUS), Phase::Small, 0.0);
    let st = g.stats();
    println!("drum 64^2: {st:?}");
    assert!(st.min_volume < 1e-6);
    let d0 = diagnose_embedded(&*s, &*g);
    let exact_mass = 0.6 * st.open_volume;
    assert!((d0.mass_total - exact_mass).abs() < 1e-13 * exact_mass);
    assert!(
        (d0.psi - 1.0).abs() < 1e-12,
        "mixed start: Psi = {}",
        d0.psi
    );
    let dt = s.stable_dt_embedded(&g);
    let t_end = 2.0;
    let mut psi = vec![d0.psi];
    let (mut worst_small, mut worst_total): (f64, f64) = (0.0, 0.0);
    let mut tiny_checked = 0;
    while s.time() < t_end {
        let step = dt.min(t_end - s.time());
        s.step_embedded(step, &g);
        let d = diagnose_embedded(&*s, &*g);
        worst_small = worst_small.max((d.mass_small - d0.mass_small).abs() / d0.mass_small);
        worst_total = worst_total.max((d.mass_total - d0.mass_total).abs() / d0.mass_total);
        tiny_checked += assert_bounds(&s, &g, s.steps());
        if s.steps() % 16 == 0 {
            psi.push(d.psi);
        }
    }
    let d = diagnose_embedded(&*s, &*g);
    psi.push(d.psi);
    let (zf, zb) = centres_of_mass(&s, &g);
    let (above, below) = s.bound_violations();
    println!(
        "{} steps of {dt:.4e}: mass drift fines {worst_small:.2e}, total {worst_total:.2e}; Psi {:.4} -> {:.4}; \
         centre of mass fines {zf:.4} vs bed {zb:.4}; phihat {:.3e}..{:.6}; excess {above:e} {below:e}",
        s.steps(),
        psi[0],
        d.psi,
        d.phihat_min,
        d.phihat_max
    );
    assert!(
        worst_small < round_off(s.steps()),
        "fines mass drift {worst_small}"
    );
    assert_eq!(worst_total, 0.0, "c never changes");
    assert!(tiny_checked > 0);
    assert_eq!((above, below), (0.0, 0.0));
    // Psi falls (sampled every 16 steps) and ends well segregated
    for w in psi.windows(2) {
        assert!(w[1] <= w[0] + 1e-12, "Psi rose: {psi:?}");
    }
    assert!(d.psi < 0.25, "final Psi {}", d.psi);
    // fines at the bottom: their centre of mass below the bed's by a good part of the radius
    assert!(zb - zf > 0.1 * RADIUS, "fines {zf} vs bed {zb}");
    // the lowest open cell is full of fines, the highest one empty of them
    let lowest = (0..s.len())
        .filter(|&i| g.volume(i) > 0.5)
        .min_by(|&a, &b| g.open_centroid(a)[1].total_cmp(&g.open_centroid(b)[1]))
        .unwrap();
    let highest = (0..s.len())
        .filter(|&i| g.volume(i) > 0.5)
        .max_by(|&a, &b| g.open_centroid(a)[1].total_cmp(&g.open_centroid(b)[1]))
        .unwrap();
    assert!(s.phi(lowest) / s.c(lowest) > 0.999);
    assert!(s.phi(highest) / s.c(highest) < 1e-3);
}

#[test]
fn tiny_cells_do_not_shrink_the_time_step() {
    for n in [32, 64, 128] {
        let (s, g) = drum(n, &Region::drum(CENTRE, RADIUS), Phase::Small, 0.0);
        let (box_dt, cut_dt) = (s.stable_dt(), s.stable_dt_embedded(&g));
        let st = g.stats();
        println!(
            "n = {n}: box dt {box_dt:.6e}, cut-cell dt {cut_dt:.6e} (ratio {:.4}); smallest cell {:.2e}, smallest group {:.3}",
            cut_dt / box_dt,
            st.min_volume,
            st.min_group_volume
        );
        // The stated factor: never below 0.8 of the box step, whatever the smallest cell.
        assert!(cut_dt >= 0.8 * box_dt, "n = {n}: {cut_dt} vs {box_dt}");
        assert!(cut_dt <= box_dt * (1.0 + 1e-12));
        assert!(st.min_volume < 1e-3 || n != 64);
    }
}

#[test]
fn reruns_are_bit_identical() {
    let run = || {
        let (mut s, g) = drum(
            48,
            &Region::drum_with_baffle(CENTRE, RADIUS, -0.7, 0.1, 0.05),
            Phase::Large,
            1e-3,
        );
        s.advance_to_embedded(0.25, u64::MAX, &g);
        // preparing again (as a coupled driver does every step) changes no bit
        let before = state_hash(&*s);
        s.prepare_embedded(&g).unwrap();
        assert_eq!(state_hash(&*s), before);
        s.advance_to_embedded(0.5, u64::MAX, &g);
        (state_hash(&*s), s.steps())
    };
    let (a, b) = (run(), run());
    println!(
        "rerun hashes {:#018x} / {:#018x} after {} steps",
        a.0, b.0, a.1
    );
    assert_eq!(a, b);
}

#[test]
fn baffle_drum_with_diffusion_keeps_mass_and_bounds() {
    for phase in [Phase::Small, Phase::Large] {
        let (mut s, g) = drum(
            48,
            &Region::drum_with_baffle(CENTRE, RADIUS, -0.7, 0.1, 0.05),
            phase,
            2e-3,
        );
        let d0 = diagnose_embedded(&*s, &*g);
        let dt = s.stable_dt_embedded(&g);
        for k in 0..300 {
            s.step_embedded(dt, &g);
            assert_bounds(&s, &g, k);
        }
        let d = diagnose_embedded(&*s, &*g);
        let drift = (d.mass_small - d0.mass_small).abs() / d0.mass_small;
        println!(
            "baffle, {phase:?}, D = 2e-3: 300 steps of {dt:.3e}, fines mass drift {drift:.2e}, Psi {:.4} -> {:.4}",
            d0.psi, d.psi
        );
        assert!(drift < round_off(300));
        assert!(d.psi < 0.9 * d0.psi);
    }
}

/// A 2D box scene with shear, varying c and T, diffusion, periodic or inflow/outflow in x.
fn box_scene(s: &mut Seg2, scheme: Scheme, phase: Phase, inflow: bool) {
    let (nx, nz) = (40, 24);
    let grid = Grid::new([nx, nz], [0.0, 0.0], [2.0, 1.0], N).unwrap();
    let xbc = if inflow {
        [Boundary::Inflow, Boundary::Outflow]
    } else {
        [Boundary::Periodic; 2]
    };
    let bc: Boundaries<2> = [xbc, [Boundary::Wall; 2]];
    let mut cfg = config(phase, 1e-3);
    cfg.scheme = scheme;
    s.setup(grid, bc, cfg).unwrap();
    for i in 0..grid.len() {
        let [x, z] = grid.center(i);
        let c = 0.3 + 0.3 * z;
        let phi = c * (0.5 + 0.4 * (3.0 * x).sin() * (z - 0.5));
        s.set_cell(i, c, 0.5 + z, [0.2 + z, 0.0], phi);
        if inflow && grid.coord(i, 0) == 0 {
            s.set_inflow(i, 0.7 * c);
        }
    }
    s.prepare().unwrap();
}

#[test]
fn without_walls_the_embedded_step_gives_the_box_step_bits() {
    for (scheme, phase, inflow) in [
        (Scheme::Modified, Phase::Small, false),
        (Scheme::Modified, Phase::Large, true),
        (Scheme::Godunov, Phase::Small, true),
        (Scheme::Upwind, Phase::Large, false),
    ] {
        let mut a = boxed(Seg2::zeroed);
        let mut b = boxed(Seg2::zeroed);
        let mut g = boxed(Geo2::zeroed);
        box_scene(&mut a, scheme, phase, inflow);
        box_scene(&mut b, scheme, phase, inflow);
        let periodic = [!inflow, false];
        g.build(a.grid(), &Region::new(), periodic, 0.5).unwrap();
        b.prepare_embedded(&g).unwrap();
        let dt = a.stable_dt();
        let rel = (b.stable_dt_embedded(&g) - dt).abs() / dt;
        assert!(rel < 1e-15, "dt differs by {rel}");
        for _ in 0..80 {
            a.step(dt);
            b.step_embedded(dt, &g);
        }
        let (ha, hb) = (state_hash(&*a), state_hash(&*b));
        println!("{scheme:?} {phase:?} inflow={inflow}: box {ha:#018x}, embedded {hb:#018x}");
        assert_eq!(ha, hb);
        let (da, db) = (diagnose(&*a), diagnose_embedded(&*b, &*g));
        assert_eq!(da.mass_small.to_bits(), db.mass_small.to_bits());
        // the open sides' books of the cut-cell step are the box step's
        assert_eq!(a.side_books(), b.side_books());
        let out = b.small_mass_out_through_sides();
        assert_eq!(out[0][0] < 0.0, inflow, "{out:?}");
        assert_eq!(da.psi.to_bits(), db.psi.to_bits());
    }
}

#[test]
fn drum_slice_in_3d_keeps_mass_and_bounds() {
    const N3: usize = 24 * 3 * 24;
    let mut s = boxed(Segregation::<f64, 3, N3>::zeroed);
    let mut g = boxed(CutCells::<f64, 3, N3>::zeroed);
    let grid = Grid::new([24, 3, 24], [0.0; 3], [1.0, 0.125, 1.0], N3).unwrap();
    let region = Region::drum([CENTRE[0], 0.0, CENTRE[1]], 0.4);
    let st = g.build(&grid, &region, [false, true, false], 0.5).unwrap();
    let mut bc: Boundaries<3> = [[Boundary::Wall; 2]; 3];
    bc[1] = [Boundary::Periodic; 2];
    let mut cfg = SegregationConfig::new();
    cfg.gravity = [0.0, 0.0, -1.0];
    s.setup(grid, bc, cfg).unwrap();
    for i in 0..grid.len() {
        s.set_cell(i, 0.6, 1.0, [0.0; 3], 0.3);
    }
    s.prepare_embedded(&g).unwrap();
    let d0 = diagnose_embedded(&*s, &*g);
    assert!((d0.mass_total - 0.6 * st.open_volume).abs() < 1e-13 * d0.mass_total);
    let steps = s.advance_to_embedded(1.0, u64::MAX, &g);
    let d = diagnose_embedded(&*s, &*g);
    let drift = (d.mass_small - d0.mass_small).abs() / d0.mass_small;
    println!(
        "3D slice: {st:?}\n{steps} steps, drift {drift:.2e}, Psi {:.4} -> {:.4}, violations {:?}",
        d0.psi,
        d.psi,
        s.bound_violations()
    );
    assert!(drift < round_off(steps));
    assert_eq!(s.bound_violations(), (0.0, 0.0));
    assert!(d.psi < 0.6);
    // the slice stays uniform along the periodic axis
    for i in 0..grid.len() {
        let [ix, _, iz] = grid.coords(i);
        let j = grid.index([ix, 0, iz]);
        assert_eq!(s.phi(i).to_bits(), s.phi(j).to_bits());
    }
}

/// f32 runs too (the firmware's precision): bounds exact, mass to f32 round-off.
#[test]
fn f32_drum_keeps_bounds() {
    let mut s = boxed(Segregation::<f32, 2, N>::zeroed);
    let mut g = boxed(CutCells::<f32, 2, N>::zeroed);
    let grid = Grid::new([48, 48], [0.0f32; 2], [1.0f32; 2], N).unwrap();
    let region = Region::drum([CENTRE[0] as f32, CENTRE[1] as f32], RADIUS as f32);
    g.build(&grid, &region, [false; 2], 0.5).unwrap();
    s.setup(grid, [[Boundary::Wall; 2]; 2], SegregationConfig::new())
        .unwrap();
    for i in 0..grid.len() {
        s.set_cell(i, 0.6, 1.0, [0.0; 2], 0.3);
    }
    s.prepare_embedded(&g).unwrap();
    let d0 = diagnose_embedded(&*s, &*g);
    s.advance_to_embedded(1.0, u64::MAX, &g);
    let d = diagnose_embedded(&*s, &*g);
    let drift = ((d.mass_small - d0.mass_small) / d0.mass_small).abs();
    println!(
        "f32 drum: {} steps, drift {drift:.2e}, Psi {} -> {}",
        s.steps(),
        d0.psi,
        d.psi
    );
    assert_eq!(s.bound_violations(), (0.0, 0.0));
    assert!(drift < 1e-4);
    assert!(d.psi.to_f64() < 0.5);
}
