//! The 3D direction from the flow in lanes (core/src/segregation/eigen3.rs): the prepare's
//! pass 1 solves 16 cells' eigenproblems side by side. Each cell must get the bits of the
//! single-cell `segregation_normal` whatever block or thread part it falls in, on every
//! vector width, and the directions must be the principal-axis normals of model.md 3.

use crate::common::{boxed, config, Lcg};
use sieve::isa::Level;
use sieve_core::fork::Serial;
use sieve_core::segregation::direction::{
    segregation_direction, segregation_normal, velocity_gradient,
};
use sieve_core::{Boundaries, Boundary, DirectionMode, Grid, Phase, Scheme, Segregation};

const N: usize = 512;

fn dot(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `k_a = S_a / c` of model.md 3 for one cell, the per-cell way (velocity gradient,
/// `segregation_normal`, then S), as the prepare's pass 2 computes it.
fn per_cell(
    s: &Segregation<f64, 3, N>,
    u: &[[f64; N]; 3],
    bc: &Boundaries<3>,
    i: usize,
) -> [f64; 3] {
    let gravity = s.config().gravity;
    let gdir = gravity.map(|x| x / dot(&gravity, &gravity).sqrt());
    let g = velocity_gradient(s.grid(), bc, u, i);
    let (d, dd) = segregation_normal(&g, &[u[0][i], u[1][i], u[2][i]], gdir);
    let s_mag = -(s.config().s0 * s.temperature(i).sqrt() * dot(&gravity, &d) / dd);
    let c = s.c(i);
    d.map(|da| {
        if c > s.config().vacuum {
            s_mag * da / c
        } else {
            0.0
        }
    })
}

/// The state of the test: velocities with a still block (the fallback), a still layer inside
/// a shear (ties towards gravity), simple shears along each axis pair and random cells.
fn fill(s: &mut Segregation<f64, 3, N>, grid: &Grid<f64, 3>, seed: u64) -> [[f64; N]; 3] {
    let mut rng = Lcg(seed);
    let mut u = [[0.0; N]; 3];
    for i in 0..grid.len() {
        let [x, y, z] = grid.coords(i);
        let ui = if x < 2 && y < 2 && z < 2 || z == 3 {
            [0.0; 3]
        } else if x == 1 {
            [0.4 * z as f64, 0.0, 0.0]
        } else if y == 2 {
            [0.0, 0.0, 0.3 * x as f64 - 0.2]
        } else {
            [
                rng.next() - 0.5,
                0.5 * (rng.next() - 0.5),
                0.3 * (rng.next() - 0.5),
            ]
        };
        for a in 0..3 {
            u[a][i] = ui[a];
        }
        let c = if rng.next() < 0.1 {
            0.0
        } else {
            0.6 * rng.next()
        };
        s.set_cell(i, c, rng.next(), ui, 0.4 * c);
    }
    u
}

#[test]
fn lanes_give_each_cell_the_single_cell_bits() {
    // Cell counts that are not multiples of the 16 lanes, one-cell lines, walls and periodic
    // sides; a tilted gravity, so that the fallback is not an axis.
    let grids: [([usize; 3], Boundaries<3>); 4] = [
        (
            [7, 5, 3],
            [
                [Boundary::Wall; 2],
                [Boundary::Periodic; 2],
                [Boundary::Wall; 2],
            ],
        ),
        ([4, 4, 5], [[Boundary::Periodic; 2]; 3]),
        ([1, 1, 17], [[Boundary::Wall; 2]; 3]),
        (
            [3, 11, 6],
            [
                [Boundary::Wall; 2],
                [Boundary::Wall; 2],
                [Boundary::Outflow; 2],
            ],
        ),
    ];
    let gravity = [0.2, -0.1, -0.95];
    let pool = sieve::pool::Pool::new(3)
        .expect("threads")
        .cutting_down_to(8);
    let (mut checked, mut fallbacks) = (0, 0);
    for (g, (cells, bc)) in grids.into_iter().enumerate() {
        let cfg = config(Scheme::Modified, Phase::Small, gravity, DirectionMode::Flow);
        let grid = Grid::new(cells, [0.0; 3], [0.1, 0.07, 0.13], N).unwrap();
        let mut s = boxed::<f64, 3, N>();
        s.setup(grid, bc, cfg).unwrap();
        let u = fill(&mut s, &grid, 29 + g as u64);
        s.prepare().unwrap();
        let want: Vec<[u64; 3]> = (0..grid.len())
            .map(|i| per_cell(&s, &u, &bc, i).map(f64::to_bits))
            .collect();
        let got = |s: &Segregation<f64, 3, N>| -> Vec<[u64; 3]> {
            (0..grid.len())
                .map(|i| [0, 1, 2].map(|a| s.face_coefficient(a, i).to_bits()))
                .collect()
        };
        let first = |bits: &[[u64; 3]]| want.iter().zip(bits).position(|(a, b)| a != b);
        assert_eq!(
            first(&got(&s)),
            None,
            "grid {cells:?}: the first cell that differs"
        );
        // Cut among 3 parts of at least 8 cells (blocks start inside a part), at every
        // vector width this CPU has.
        for level in [Level::Baseline, Level::Avx2, Level::Avx512] {
            if !level.available() {
                continue;
            }
            sieve::on_level!(level, &Serial, |f| s.prepare_with(f)).unwrap();
            assert_eq!(
                first(&got(&s)),
                None,
                "grid {cells:?}, {}, 1 thread",
                level.name()
            );
            pool.install(|| sieve::on_level!(level, &pool, |f| s.prepare_with(f)))
                .unwrap();
            assert_eq!(
                first(&got(&s)),
                None,
                "grid {cells:?}, {}, 3 parts",
                level.name()
            );
        }
        let gdir = gravity.map(|x| x / dot(&gravity, &gravity).sqrt());
        for i in 0..grid.len() {
            let gr = velocity_gradient(&grid, &bc, &u, i);
            let d = segregation_direction(&gr, &[u[0][i], u[1][i], u[2][i]], gdir);
            assert!((dot(&d, &d) - 1.0).abs() < 1e-15, "cell {i}: unit");
            fallbacks += usize::from(d == gdir);
        }
        checked += grid.len();
    }
    assert_eq!(checked, 105 + 80 + 17 + 198);
    // The still blocks and layers with still neighbours: the fallback path is taken.
    assert!(fallbacks >= 4, "{fallbacks} fallback cells");
}

/// The normal from lanes on shears of known axes: `u = a (z, 0, 0)` rotated by 24 rotations
/// has its shear plane normal along the rotated z axis (model.md 3), to 1e-13; a shear with
/// the flow along the normal of the other plane picks that other plane.
#[test]
fn rotated_simple_shears_give_their_shear_plane() {
    let mut rng = Lcg(5);
    for k in 0..24 {
        let (al, be, ga) = (6.3 * rng.next(), 3.1 * rng.next(), 6.3 * rng.next());
        let rz = |t: f64| {
            [
                [t.cos(), -t.sin(), 0.0],
                [t.sin(), t.cos(), 0.0],
                [0.0, 0.0, 1.0],
            ]
        };
        let ry = [
            [be.cos(), 0.0, be.sin()],
            [0.0, 1.0, 0.0],
            [-be.sin(), 0.0, be.cos()],
        ];
        let mul = |a: [[f64; 3]; 3], b: [[f64; 3]; 3]| {
            let mut m = [[0.0; 3]; 3];
            for i in 0..3 {
                for j in 0..3 {
                    m[i][j] = (0..3).map(|l| a[i][l] * b[l][j]).sum();
                }
            }
            m
        };
        let r = mul(mul(rz(al), ry), rz(ga));
        let a = 10f64.powi(k % 9 - 4);
        // G = a r_x r_z^T: velocity along r_x, varying along r_z.
        let g: [[f64; 3]; 3] =
            core::array::from_fn(|i| core::array::from_fn(|j| a * r[i][0] * r[j][2]));
        let col = |j: usize| [r[0][j], r[1][j], r[2][j]];
        let d = segregation_direction(&g, &col(0).map(|x| 0.3 * a * x), [0.0, 0.0, -1.0]);
        assert!(dot(&d, &col(2)).abs() > 1.0 - 1e-13, "rotation {k}: {d:?}");
        let (m, mm) = segregation_normal(&g, &col(0), [0.0, 0.0, -1.0]);
        assert!((mm - 2.0).abs() < 1e-14, "rotation {k}: m . m = {mm}");
        assert!((dot(&m, &m) - mm).abs() < 1e-14);
    }
}

/// An empty cell has no segregation velocity (model.md 3.2): pass 1 solves no direction for
/// it, so a shear in the empty part of a box (T given and 1 there, or from that shear) must
/// not limit the step; only its transport `|u| / h` does. The grains below are at rest with
/// T = 0. With the empty cells' directions counted the step would be `h / |g|` at most.
#[test]
fn empty_cells_have_no_segregation_velocity() {
    fn check<const D: usize>(cells: [usize; D], from_shear: bool) {
        let mut cfg = config(
            Scheme::Modified,
            Phase::Small,
            core::array::from_fn(|a| if a + 1 == D { -1.0 } else { 0.0 }),
            DirectionMode::Flow,
        );
        if from_shear {
            cfg.temperature = sieve_core::TemperatureMode::FromShear {
                heating: 1.5,
                eta0: 1.0,
                eps0: 1.0,
            };
        }
        let h = 0.1;
        let grid = Grid::new(cells, [0.0; D], cells.map(|n| n as f64 * h), N).unwrap();
        let mut s = boxed::<f64, D, N>();
        s.setup(grid, [[Boundary::Wall; 2]; D], cfg).unwrap();
        let nz = cells[D - 1];
        let mut umax: f64 = 0.0;
        for i in 0..grid.len() {
            let z = grid.coords(i)[D - 1];
            if z < nz / 2 {
                s.set_cell(i, 0.5, 0.0, [0.0; D], 0.25);
            } else {
                // a simple shear u_0 = 0.3 (z - nz/2) h, no grains (still next to the
                // grains, so that their T from the shear stays 0)
                let mut u = [0.0; D];
                u[0] = 0.3 * (z - nz / 2) as f64 * h;
                umax = umax.max(u[0]);
                s.set_cell(i, 0.0, 1.0, u, 0.0);
            }
        }
        s.prepare().unwrap();
        let want = cfg.courant / (umax / h);
        let got = s.stable_dt();
        assert!(
            (got - want).abs() <= 1e-14 * want,
            "{D}D, T from the shear {from_shear}: stable dt {got}, want {want} (|u| / h alone)"
        );
    }
    check::<2>([6, 8], false);
    check::<2>([6, 8], true);
    check::<3>([5, 3, 8], false);
    check::<3>([5, 3, 8], true);
}
