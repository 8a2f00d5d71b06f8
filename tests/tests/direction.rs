//! Segregation direction from the flow (model.md 3): the normal of the plane of largest shear,
//! checked on simple shears, rotated shears, and 2D/3D solvers in `DirectionMode::Flow`.

use crate::common::{boxed, config};
use sieve_core::segregation::direction::{
    segregation_direction, segregation_normal, symmetric_eigen_3,
};
use sieve_core::{Boundary, DirectionMode, Grid, Phase, Scheme};

/// |a . b| for unit vectors: 1 when parallel or antiparallel (d_s is defined up to sign).
fn alignment<const D: usize>(a: &[f64; D], b: &[f64; D]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>().abs()
}

fn norm<const D: usize>(a: &[f64; D]) -> f64 {
    a.iter().map(|x| x * x).sum::<f64>().sqrt()
}

const SHEAR_RATES: [f64; 4] = [2.0, -3.0, 0.5, 1e-3];

#[test]
fn simple_shear_2d_gives_the_vertical() {
    for a in SHEAR_RATES {
        for z in [0.3, -0.7, 1e-9] {
            // u = (a z, 0): G[i][j] = d_j u_i has only G[0][1] = a.
            let g = [[0.0, a], [0.0, 0.0]];
            let d = segregation_direction(&g, &[a * z, 0.0], [1.0, 0.0]);
            assert!((norm(&d) - 1.0).abs() < 1e-15, "a={a}: |d| = {}", norm(&d));
            assert!(
                alignment(&d, &[0.0, 1.0]) > 1.0 - 1e-15,
                "a={a} z={z}: d = {d:?}"
            );
        }
    }
}

#[test]
fn rotated_shear_2d_gives_the_rotated_normal() {
    // u'(x) = R u(R^T x) has gradient R G R^T; the shear plane turns with it, so d_s = R e_z.
    for k in 0..36 {
        let th = k as f64 * std::f64::consts::PI / 18.0 + 0.05;
        let (s, c) = th.sin_cos();
        let r = [[c, -s], [s, c]];
        for a in SHEAR_RATES {
            let g0 = [[0.0, a], [0.0, 0.0]];
            let mut g = [[0.0; 2]; 2];
            for i in 0..2 {
                for j in 0..2 {
                    for p in 0..2 {
                        for q in 0..2 {
                            g[i][j] += r[i][p] * g0[p][q] * r[j][q];
                        }
                    }
                }
            }
            let z0 = 0.4;
            let u = [r[0][0] * a * z0, r[1][0] * a * z0];
            let d = segregation_direction(&g, &u, [1.0, 0.0]);
            let expected = [-s, c];
            assert!(
                alignment(&d, &expected) > 1.0 - 1e-12,
                "theta={th} a={a}: d = {d:?}, expected +-{expected:?}"
            );
        }
    }
}

/// Rotation matrix from Euler angles (z-y-z).
fn rotation(al: f64, be: f64, ga: f64) -> [[f64; 3]; 3] {
    let rz = |t: f64| {
        let (s, c) = t.sin_cos();
        [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    };
    let (s, c) = be.sin_cos();
    let ry = [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]];
    let mul = |a: [[f64; 3]; 3], b: [[f64; 3]; 3]| {
        let mut m = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                for k in 0..3 {
                    m[i][j] += a[i][k] * b[k][j];
                }
            }
        }
        m
    };
    mul(mul(rz(al), ry), rz(ga))
}

#[test]
fn simple_and_rotated_shear_3d() {
    for a in SHEAR_RATES {
        // u = (a z, 0, 0): eigenvalues of k = G + G^T are a, 0, -a with e_max, e_min =
        // (e_x +- e_z)/sqrt 2; their sum and difference are e_x and e_z; e_z is orthogonal to u.
        let mut g = [[0.0; 3]; 3];
        g[0][2] = a;
        let d = segregation_direction(&g, &[a * 0.3, 0.0, 0.0], [1.0, 0.0, 0.0]);
        assert!((norm(&d) - 1.0).abs() < 1e-14);
        assert!(
            alignment(&d, &[0.0, 0.0, 1.0]) > 1.0 - 1e-12,
            "a={a}: d = {d:?}"
        );
        // Rotated copies.
        for k in 0..10 {
            let r = rotation(0.3 + k as f64, 1.1 * k as f64 + 0.2, 0.7 * k as f64);
            let mut gr = [[0.0; 3]; 3];
            for i in 0..3 {
                for j in 0..3 {
                    gr[i][j] = r[i][0] * a * r[j][2];
                }
            }
            let u = [r[0][0] * a * 0.3, r[1][0] * a * 0.3, r[2][0] * a * 0.3];
            let d = segregation_direction(&gr, &u, [1.0, 0.0, 0.0]);
            let expected = [r[0][2], r[1][2], r[2][2]];
            assert!(
                alignment(&d, &expected) > 1.0 - 1e-10,
                "rotation {k}, a={a}: d = {d:?}, expected +-{expected:?}"
            );
        }
    }
}

/// The 3D direction's eigen-solve (cyclic Jacobi): on random symmetric matrices over twelve
/// decades, with repeated and nearly repeated eigenvalues, `K v = lambda v` to 1e-14 of the
/// matrix, orthonormal eigenvectors to 1e-14, the trace kept; the bits the same on a rerun.
#[test]
fn jacobi_eigen_3_is_accurate_on_random_and_degenerate_matrices() {
    let mut seed = 0x9e3779b97f4a7c15u64;
    let mut next = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    let mut cases: Vec<[[f64; 3]; 3]> = vec![
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        [[2.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 2.0]],
        [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]],
        [
            [1.0, 1e-9, 0.0],
            [1e-9, 1.0, 1e-9],
            [0.0, 1e-9, 1.0 + 1e-12],
        ],
    ];
    for k in 0..2000 {
        let scale = 10f64.powi(k % 13 - 6);
        let (a, b, c, d, e, f) = (next(), next(), next(), next(), next(), next());
        cases.push([[a, b, c], [b, d, e], [c, e, f]].map(|r| r.map(|x| x * scale)));
        // a rotated diagonal with two equal eigenvalues
        let r = rotation(next() * 3.0, next() * 3.0, next() * 3.0);
        let l = [a, a, d];
        cases.push(core::array::from_fn(|i| {
            core::array::from_fn(|j| (0..3).map(|m| r[i][m] * l[m] * r[j][m]).sum::<f64>())
        }));
    }
    let mut worst = [0.0f64; 2];
    for m in &cases {
        let (values, v) = symmetric_eigen_3(*m).expect("converges");
        assert_eq!(symmetric_eigen_3(*m), Some((values, v)), "rerun");
        let size = m.iter().flatten().fold(0.0f64, |s, x| s.max(x.abs()));
        for j in 0..3 {
            for i in 0..3 {
                let kv: f64 = (0..3).map(|l| m[i][l] * v[l][j]).sum();
                worst[0] = worst[0].max((kv - values[j] * v[i][j]).abs() / size);
            }
            for l in 0..3 {
                let dot: f64 = (0..3).map(|i| v[i][j] * v[i][l]).sum();
                let want = if j == l { 1.0 } else { 0.0 };
                worst[1] = worst[1].max((dot - want).abs());
            }
        }
        let trace = m[0][0] + m[1][1] + m[2][2];
        assert!((values.iter().sum::<f64>() - trace).abs() <= 1e-14 * 3.0 * size);
    }
    assert!(worst[0] < 1e-14, "residual {:e}", worst[0]);
    assert!(worst[1] < 1e-14, "orthonormality {:e}", worst[1]);
    assert_eq!(
        symmetric_eigen_3([[f64::NAN, 0.0, 0.0], [0.0; 3], [0.0; 3]]),
        None
    );
    assert_eq!(
        symmetric_eigen_3([[f64::INFINITY, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0; 3]]),
        None
    );
}

#[test]
fn no_shear_falls_back() {
    let fallback = [0.0, 0.0, -1.0];
    assert_eq!(
        segregation_direction(&[[0.0; 3]; 3], &[1.0, 2.0, 3.0], fallback),
        fallback
    );
    assert_eq!(
        segregation_direction(&[[0.0; 2]; 2], &[1.0, 0.0], [0.0, -1.0]),
        [0.0, -1.0]
    );
}

#[test]
fn flow_mode_solvers_segregate_vertically_in_shear_cells() {
    // 2D shear cell: periodic x, walls z, u = (2z - 1, 0) (opposite plates), T = 1, S0 = 1,
    // gravity (0, -1): S = -S0 sqrt(T) (g . d) d = (0, 1) in every cell, including the middle
    // row where u changes sign.
    const N: usize = 1024;
    let mut s = boxed::<f64, 2, N>();
    let grid = Grid::new([16, 16], [0.0, 0.0], [1.0, 1.0], N).unwrap();
    let cfg = config(
        Scheme::Modified,
        Phase::Small,
        [0.0, -1.0],
        DirectionMode::Flow,
    );
    s.setup(grid, [[Boundary::Periodic; 2], [Boundary::Wall; 2]], cfg)
        .unwrap();
    for i in 0..grid.len() {
        let z = grid.center(i)[1];
        s.set_cell(i, 0.64, 1.0, [2.0 * z - 1.0, 0.0], 0.32);
    }
    s.prepare().unwrap();
    for i in 0..grid.len() {
        let v = s.segregation_velocity(i);
        assert!(
            v[0].abs() < 1e-15 && (v[1] - 1.0).abs() < 1e-15,
            "cell {i}: S = {v:?}"
        );
    }

    // 3D shear cell with walls on the four sides: u = (2z - 1, 0, 0), gravity (0, 0, -1).
    let mut s = boxed::<f64, 3, N>();
    let grid = Grid::new([8, 6, 8], [0.0; 3], [1.0; 3], N).unwrap();
    let cfg = config(
        Scheme::Modified,
        Phase::Small,
        [0.0, 0.0, -1.0],
        DirectionMode::Flow,
    );
    s.setup(grid, [[Boundary::Wall; 2]; 3], cfg).unwrap();
    for i in 0..grid.len() {
        let z = grid.center(i)[2];
        s.set_cell(i, 0.64, 1.0, [2.0 * z - 1.0, 0.0, 0.0], 0.32);
    }
    s.prepare().unwrap();
    for i in 0..grid.len() {
        let v = s.segregation_velocity(i);
        assert!(
            v[0].abs() < 1e-12 && v[1].abs() < 1e-12 && (v[2] - 1.0).abs() < 1e-12,
            "cell {i}: S = {v:?}"
        );
    }
}

/// Reversing the flow (u -> -u, so G -> -G) swaps e_max and e_min, which leaves the pair of
/// candidate normals, their angles to u, and hence d_s unchanged (up to sign): the segregation
/// must not depend on which way the plates move.
///
/// Fails on the 2D closed form where u = 0 but the shear does not vanish (the middle row of a
/// shear cell with opposite plates, odd row count): both candidates are then orthogonal to u
/// and the tie goes to the one whose form depends on the sign of the shear. For u = (1 - 2z, 0)
/// the middle row gets d_s = e_x, so S = 0 there, and the modified flux (zero on the S = 0 side)
/// turns that row into a wall for segregation: the column segregates as two separate halves
/// (phihat bottom to top 1,1,1,1,0,0,0,0,0.5,1,1,1,1,0,0,0,0 at t = 3 on 17 rows) instead of one.
#[test]
fn reversing_the_flow_keeps_the_direction() {
    // Direction function: u = 0 exactly, shear rate of either sign.
    for a in SHEAR_RATES {
        let g = [[0.0, a], [0.0, 0.0]];
        let neg = [[0.0, -a], [0.0, 0.0]];
        let d1 = segregation_direction(&g, &[0.0, 0.0], [0.0, -1.0]);
        let d2 = segregation_direction(&neg, &[0.0, 0.0], [0.0, -1.0]);
        assert!(
            alignment(&d1, &d2) > 1.0 - 1e-12,
            "a={a}: d(G) = {d1:?}, d(-G) = {d2:?}"
        );
    }
    // Solver: 17 rows, u = +-(2z - 1, 0); the middle row has u = 0.
    const N: usize = 1024;
    let mut cols = Vec::new();
    for sign in [1.0, -1.0] {
        let mut s = boxed::<f64, 2, N>();
        let grid = Grid::new([4, 17], [0.0, 0.0], [1.0, 1.0], N).unwrap();
        let cfg = config(
            Scheme::Modified,
            Phase::Small,
            [0.0, -1.0],
            DirectionMode::Flow,
        );
        s.setup(grid, [[Boundary::Periodic; 2], [Boundary::Wall; 2]], cfg)
            .unwrap();
        for i in 0..grid.len() {
            let z = grid.center(i)[1];
            s.set_cell(i, 0.64, 1.0, [sign * (2.0 * z - 1.0), 0.0], 0.32);
        }
        s.prepare().unwrap();
        for i in 0..grid.len() {
            let v = s.segregation_velocity(i);
            assert!(
                (v[1] - 1.0).abs() < 1e-15,
                "sign {sign}, cell {i}: S = {v:?}"
            );
        }
        s.advance_to(3.0, u64::MAX);
        cols.push((0..17).map(|iz| s.phi(4 * iz)).collect::<Vec<_>>());
    }
    assert_eq!(cols[0], cols[1]);
}

/// Reference 2D direction: the principal axes of `k = G + G^T` by `atan2` (accurate to
/// round-off at any angle), the shear-plane normals at `theta +- pi/4`, and the selection rule
/// of model.md 3 with the tie test of the former closed form (unit normals, `eps |u|`).
fn direction_2d_reference(g: &[[f64; 2]; 2], u: [f64; 2], fallback: [f64; 2]) -> [f64; 2] {
    let (a, b, d) = (2.0 * g[0][0], g[0][1] + g[1][0], 2.0 * g[1][1]);
    let r = (((a - d) * 0.5).powi(2) + b * b).sqrt();
    if !(r > f64::EPSILON * (a.abs() + b.abs() + d.abs())) || r == 0.0 {
        return fallback;
    }
    let phi = 0.5 * (2.0 * b).atan2(a - d) + std::f64::consts::FRAC_PI_4;
    let (sin1, cos1) = phi.sin_cos();
    let (n1, n2) = ([cos1, sin1], [-sin1, cos1]);
    let dot = |n: [f64; 2], v: [f64; 2]| (n[0] * v[0] + n[1] * v[1]).abs();
    let speed = (u[0] * u[0] + u[1] * u[1]).sqrt();
    let (dot1, dot2) = (dot(n1, u), dot(n2, u));
    if (dot1 - dot2).abs() <= f64::EPSILON * speed {
        if dot(n2, fallback) > dot(n1, fallback) {
            n2
        } else {
            n1
        }
    } else if dot2 < dot1 {
        n2
    } else {
        n1
    }
}

/// The solver's unnormalised normal m gives the same `(g . m) m / (m . m)` as the unit
/// direction `(g . d) d` of the reference, for random gradients and velocities
/// (shear rates over ten decades, u = 0 ties included), in f64 and f32.
#[test]
fn root_free_2d_normal_matches_the_reference() {
    let mut state = 0x9e37_79b9_7f4a_7c15_u64;
    let mut rand = move || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    let grav = [0.3, -0.95];
    let fallback = [grav[0] / norm(&grav), grav[1] / norm(&grav)];
    for case in 0..20_000 {
        let scale = 10f64.powf(5.0 * rand());
        let g = [
            [scale * rand(), scale * rand()],
            [scale * rand(), scale * rand()],
        ];
        let u = if case % 10 == 0 {
            [0.0, 0.0]
        } else {
            [rand(), rand()]
        };
        let d = direction_2d_reference(&g, u, fallback);
        let project = |m: [f64; 2], mm: f64| {
            let gm = grav[0] * m[0] + grav[1] * m[1];
            [gm * m[0] / mm, gm * m[1] / mm]
        };
        let want = project(d, 1.0);
        let (m, mm) = segregation_normal(&g, &u, fallback);
        let got = project(m, mm);
        for a in 0..2 {
            assert!(
                (got[a] - want[a]).abs() < 1e-14,
                "case {case}: g={g:?} u={u:?}: {got:?} vs {want:?}"
            );
        }
        // The public unit direction is the same line.
        let unit = segregation_direction(&g, &u, fallback);
        assert!((norm(&unit) - 1.0).abs() < 1e-15);
        assert!(alignment(&unit, &d) > 1.0 - 1e-14, "case {case}");
        // f32: the same up to f32 rounding.
        let g32 = g.map(|row| row.map(|x| x as f32));
        let u32 = u.map(|x| x as f32);
        let (m32, mm32) = segregation_normal(&g32, &u32, fallback.map(|x| x as f32));
        let got32 = project(m32.map(f64::from), f64::from(mm32));
        let want32 = project(
            direction_2d_reference(&g32.map(|r| r.map(f64::from)), u32.map(f64::from), fallback),
            1.0,
        );
        for a in 0..2 {
            assert!(
                (got32[a] - want32[a]).abs() < 1e-5,
                "f32 case {case}: g={g32:?} u={u32:?}: {got32:?} vs {want32:?}"
            );
        }
    }
}
