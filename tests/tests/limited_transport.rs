//! The limited carried transport (`Transport::Limited`, core/src/segregation/limited.rs,
//! docs/model.md 5.7) against exact solutions: a smooth phihat carried by prescribed face
//! mass fluxes (`Segregation::carry_mass_fluxes`, no percolation: S0 = 0) through a uniform
//! flow in a periodic 1D box and a uniform diagonal flow in a periodic 2D box (one period: the
//! exact solution is the initial profile), and a solid-body rotation in a walled 2D box
//! (exact: the rotated profile). Observed orders of the L1 error: the donor rule about 1,
//! the limited face value about 2 (van Leer flattens the extrema a little). Mass to
//! round-off and 0 <= phi <= c exactly after every step are asserted on the way.

use crate::common::boxed;
use sieve_core::segregation::MassFluxes;
use sieve_core::{Boundary, Grid, Segregation, SegregationConfig, Transport};
use std::f64::consts::PI;

const N1: usize = 1024;
const N2: usize = 128 * 128;

/// Per-run result: L1 error of phihat against the exact solution, worst bound violation,
/// relative drift of the small-grain mass.
#[derive(Debug, Clone, Copy)]
struct Run {
    l1: f64,
    violation: f64,
    drift: f64,
}

fn config<const D: usize>() -> SegregationConfig<f64, D> {
    let mut cfg = SegregationConfig::new();
    cfg.s0 = 0.0;
    cfg
}

/// Checks the bounds and returns (worst violation, small mass).
fn bounds_and_mass<const D: usize, const N: usize>(s: &Segregation<f64, D, N>) -> (f64, f64) {
    let n = s.grid().len();
    let mut worst = 0.0f64;
    let mut mass = 0.0;
    for i in 0..n {
        let (phi, c) = (s.phi(i), s.c(i));
        assert!(phi.is_finite() && c.is_finite());
        worst = worst.max(-phi).max(phi - c);
        mass += phi;
    }
    (worst, mass)
}

/// phihat(x) on [0, 1): smooth, periodic, in [0.1, 0.9].
fn wave(x: f64) -> f64 {
    0.5 + 0.4 * (2.0 * PI * x).sin()
}

/// A uniform flow along x in a periodic 1D box of `n` cells, Courant number `nu`, carried
/// for one period.
fn uniform_1d(n: usize, nu: f64, transport: Transport) -> Run {
    let mut s = boxed::<f64, 1, N1>();
    let grid = Grid::new([n], [0.0], [1.0], N1).unwrap();
    s.setup(grid, [[Boundary::Periodic; 2]], config()).unwrap();
    s.set_transport(transport);
    let c = 0.6;
    let exact: Vec<f64> = (0..n).map(|i| wave((i as f64 + 0.5) / n as f64)).collect();
    for (i, e) in exact.iter().enumerate() {
        s.set_cell(i, c, 0.0, [0.0], c * e);
    }
    s.prepare().unwrap();
    let faces = Box::new([[nu * c; N1]; 1]);
    let low = Box::new([[0.0; N1]; 1]);
    let m0 = bounds_and_mass(&*s).1;
    let steps = (n as f64 / nu).round() as usize;
    let mut violation = 0.0f64;
    for _ in 0..steps {
        s.carry_mass_fluxes(MassFluxes {
            faces: &faces,
            low: &low,
            open: [[false; 2]],
        });
        violation = violation.max(bounds_and_mass(&*s).0);
    }
    let m = bounds_and_mass(&*s).1;
    let l1 = (0..n)
        .map(|i| (s.phi(i) / s.c(i) - exact[i]).abs())
        .sum::<f64>()
        / n as f64;
    Run {
        l1,
        violation,
        drift: (m - m0).abs() / m0,
    }
}

/// Face amounts of a discretely divergence-free 2D flow from a stream function `psi(x, z)`
/// at the cell corners (u_x = d psi / dz, u_z = -d psi / dx), times `dt c / h`, on an
/// `n x n` box [0, 1]^2; boundary faces get what the stream function gives (0 where it is
/// constant along the side).
fn stream_fluxes(n: usize, dt: f64, c: f64, psi: impl Fn(f64, f64) -> f64) -> Box<[[f64; N2]; 2]> {
    let h = 1.0 / n as f64;
    let mut f = Box::new([[0.0; N2]; 2]);
    for k in 0..n {
        for i in 0..n {
            let l = k * n + i;
            // x-face at x = (i + 1) h between z = k h and (k + 1) h
            let x = (i + 1) as f64 * h;
            let ux = (psi(x, (k + 1) as f64 * h) - psi(x, k as f64 * h)) / h;
            f[0][l] = dt * c * ux / h;
            // z-face at z = (k + 1) h between x = i h and (i + 1) h
            let z = (k + 1) as f64 * h;
            let uz = -(psi((i + 1) as f64 * h, z) - psi(i as f64 * h, z)) / h;
            f[1][l] = dt * c * uz / h;
        }
    }
    f
}

/// A 2D run: `n x n` cells on [0, 1]^2 with boundaries `bc`, initial phihat `init`, the
/// stream function `psi`, `steps` steps of `dt`, exact phihat `exact` at the end.
#[allow(clippy::too_many_arguments)]
fn run_2d(
    n: usize,
    bc: Boundary,
    transport: Transport,
    init: impl Fn(f64, f64) -> f64,
    psi: impl Fn(f64, f64) -> f64,
    dt: f64,
    steps: usize,
    exact: impl Fn(f64, f64) -> f64,
) -> Run {
    let mut s = boxed::<f64, 2, N2>();
    let grid = Grid::new([n, n], [0.0; 2], [1.0; 2], N2).unwrap();
    s.setup(grid, [[bc; 2]; 2], config()).unwrap();
    s.set_transport(transport);
    let c = 0.6;
    for i in 0..grid.len() {
        let x = grid.center(i);
        s.set_cell(i, c, 0.0, [0.0; 2], c * init(x[0], x[1]));
    }
    s.prepare().unwrap();
    let faces = stream_fluxes(n, dt, c, psi);
    let low = Box::new([[0.0; N2]; 2]);
    let m0 = bounds_and_mass(&*s).1;
    let mut violation = 0.0f64;
    for _ in 0..steps {
        s.carry_mass_fluxes(MassFluxes {
            faces: &faces,
            low: &low,
            open: [[matches!(bc, Boundary::Inflow | Boundary::Outflow); 2]; 2],
        });
        violation = violation.max(bounds_and_mass(&*s).0);
    }
    let m = bounds_and_mass(&*s).1;
    let l1 = (0..grid.len())
        .map(|i| {
            let x = grid.center(i);
            (s.phi(i) / s.c(i) - exact(x[0], x[1])).abs()
        })
        .sum::<f64>()
        / grid.len() as f64;
    Run {
        l1,
        violation,
        drift: (m - m0).abs() / m0,
    }
}

/// A uniform flow along (1, 1/2) in a periodic box, Courant 0.4 along x and 0.2 along z,
/// for one unit of time: the profile (period 1 in x, 1/2 in z) is back where it started.
fn diagonal(n: usize, transport: Transport) -> Run {
    let (ux, uz) = (1.0, 0.5);
    let h = 1.0 / n as f64;
    let dt = 0.4 * h / ux;
    let steps = (1.0 / dt).round() as usize;
    let init = |x: f64, z: f64| 0.5 + 0.2 * (2.0 * PI * x).sin() + 0.2 * (4.0 * PI * z).cos();
    // a uniform flow's stream function is not periodic: the face amounts are set directly
    let mut s = boxed::<f64, 2, N2>();
    let grid = Grid::new([n, n], [0.0; 2], [1.0; 2], N2).unwrap();
    s.setup(grid, [[Boundary::Periodic; 2]; 2], config())
        .unwrap();
    s.set_transport(transport);
    let c = 0.6;
    for i in 0..grid.len() {
        let x = grid.center(i);
        s.set_cell(i, c, 0.0, [0.0; 2], c * init(x[0], x[1]));
    }
    s.prepare().unwrap();
    let mut faces = Box::new([[0.0; N2]; 2]);
    faces[0][..n * n].fill(dt * c * ux / h);
    faces[1][..n * n].fill(dt * c * uz / h);
    let low = Box::new([[0.0; N2]; 2]);
    let m0 = bounds_and_mass(&*s).1;
    let mut violation = 0.0f64;
    for _ in 0..steps {
        s.carry_mass_fluxes(MassFluxes {
            faces: &faces,
            low: &low,
            open: [[false; 2]; 2],
        });
        violation = violation.max(bounds_and_mass(&*s).0);
    }
    let m = bounds_and_mass(&*s).1;
    let t = steps as f64 * dt;
    let l1 = (0..grid.len())
        .map(|i| {
            let x = grid.center(i);
            (s.phi(i) / s.c(i) - init(x[0] - ux * t, x[1] - uz * t)).abs()
        })
        .sum::<f64>()
        / grid.len() as f64;
    Run {
        l1,
        violation,
        drift: (m - m0).abs() / m0,
    }
}

/// Solid-body rotation at 1 rev per unit time about the box centre inside r = 0.4 (the
/// stream function is constant outside, so the walls see no flux), a Gaussian hump of
/// phihat at r = 0.2, carried a quarter turn.
fn rotation(n: usize, transport: Transport) -> Run {
    let omega = 2.0 * PI;
    let r0: f64 = 0.4;
    let psi = move |x: f64, z: f64| {
        let r2 = (x - 0.5).powi(2) + (z - 0.5).powi(2);
        -0.5 * omega * r2.min(r0 * r0)
    };
    let hump = |x: f64, z: f64| {
        let d2 = (x - 0.7).powi(2) + (z - 0.5).powi(2);
        0.5 + 0.4 * (-d2 / (0.08f64 * 0.08)).exp()
    };
    let h = 1.0 / n as f64;
    let dt = 0.4 * h / (omega * r0);
    let steps = (0.25 / dt).round() as usize;
    let t = steps as f64 * dt;
    let exact = move |x: f64, z: f64| {
        // rotate back by omega t
        let (c, s) = ((omega * t).cos(), (omega * t).sin());
        let (dx, dz) = (x - 0.5, z - 0.5);
        hump(0.5 + c * dx + s * dz, 0.5 - s * dx + c * dz)
    };
    run_2d(n, Boundary::Wall, transport, hump, psi, dt, steps, exact)
}

fn order(coarse: f64, fine: f64) -> f64 {
    (coarse / fine).log2()
}

fn study(name: &str, runs: &[(usize, Run, Run)]) -> (f64, f64) {
    for (n, d, l) in runs {
        println!(
            "{name} n={n:4}: L1 donor {:.3e}, limited {:.3e} (bounds {:.1e} / {:.1e}, mass drift {:.1e} / {:.1e})",
            d.l1, l.l1, d.violation, l.violation, d.drift, l.drift
        );
        for r in [d, l] {
            assert!(r.violation <= 0.0, "{name} n={n}: bounds broken {r:?}");
            assert!(r.drift < 1e-13, "{name} n={n}: mass drift {r:?}");
        }
    }
    let k = runs.len();
    let od = order(runs[k - 2].1.l1, runs[k - 1].1.l1);
    let ol = order(runs[k - 2].2.l1, runs[k - 1].2.l1);
    println!("{name}: observed order donor {od:.2}, limited {ol:.2}");
    (od, ol)
}

#[test]
fn uniform_flow_1d_limited_is_second_order_donor_first() {
    let runs: Vec<_> = [100, 200, 400]
        .into_iter()
        .map(|n| {
            (
                n,
                uniform_1d(n, 0.4, Transport::Donor),
                uniform_1d(n, 0.4, Transport::Limited),
            )
        })
        .collect();
    let (od, ol) = study("uniform 1D, nu 0.4", &runs);
    assert!((0.85..1.15).contains(&od), "donor order {od}");
    assert!(ol > 1.7, "limited order {ol}");
    assert!(runs[2].2.l1 < 0.1 * runs[2].1.l1);
}

#[test]
fn diagonal_flow_2d_limited_is_second_order_donor_first() {
    let runs: Vec<_> = [32, 64, 128]
        .into_iter()
        .map(|n| {
            (
                n,
                diagonal(n, Transport::Donor),
                diagonal(n, Transport::Limited),
            )
        })
        .collect();
    let (od, ol) = study("diagonal 2D, nu 0.4 / 0.2", &runs);
    assert!((0.8..1.2).contains(&od), "donor order {od}");
    assert!(ol > 1.7, "limited order {ol}");
}

#[test]
fn solid_body_rotation_limited_is_second_order_donor_first() {
    let runs: Vec<_> = [32, 64, 128]
        .into_iter()
        .map(|n| {
            (
                n,
                rotation(n, Transport::Donor),
                rotation(n, Transport::Limited),
            )
        })
        .collect();
    let (od, ol) = study("rotation 2D, quarter turn", &runs);
    assert!(od < 1.2, "donor order {od}");
    assert!(ol > 1.6, "limited order {ol}");
}
