//! Segregation direction from the velocity field (model.md section 3) and the shear rate used
//! to derive T from a measured velocity (model.md section 2, last relation).

use crate::boundary::{Boundaries, Boundary};
use crate::grid::Grid;
use crate::real::Real;
use nalgebra::{Matrix3, SymmetricEigen};

/// Velocity gradient `G[i][j] = d_j u_i` at cell `i`: central differences inside, one-sided
/// next to non-periodic boundaries, wrapped across periodic ones.
pub fn velocity_gradient<R: Real, const D: usize, const N: usize>(
    grid: &Grid<R, D>,
    bc: &Boundaries<D>,
    u: &[[R; N]; D],
    i: usize,
) -> [[R; D]; D] {
    velocity_gradient_at(grid, bc, u, i, grid.coords(i))
}

/// [`velocity_gradient`] with the integer coordinates of cell `i` already known.
pub fn velocity_gradient_at<R: Real, const D: usize, const N: usize>(
    grid: &Grid<R, D>,
    bc: &Boundaries<D>,
    u: &[[R; N]; D],
    i: usize,
    coords: [usize; D],
) -> [[R; D]; D] {
    let mut g = [[R::ZERO; D]; D];
    let h = grid.spacing();
    let cells = grid.cells();
    let mut s = 1;
    for j in 0..D {
        let n = cells[j];
        let stride = s;
        s *= n;
        if n < 2 {
            continue;
        }
        let s = stride;
        let cj = coords[j];
        let periodic = bc[j][0] == Boundary::Periodic;
        let (lo, hi, width) = if cj > 0 && cj + 1 < n {
            (i - s, i + s, R::TWO)
        } else if periodic {
            let lo = if cj == 0 { i + (n - 1) * s } else { i - s };
            let hi = if cj + 1 == n { i - (n - 1) * s } else { i + s };
            (lo, hi, R::TWO)
        } else if cj == 0 {
            (i, i + s, R::ONE)
        } else {
            (i - s, i, R::ONE)
        };
        for (gi, ui) in g.iter_mut().zip(u.iter()) {
            gi[j] = (ui[hi] - ui[lo]) / (width * h[j]);
        }
    }
    g
}

/// `kappa : kappa = sum_ij (d_j u_i)^2`, the squared shear rate of model.md section 2.
pub fn shear_rate_squared<R: Real, const D: usize>(g: &[[R; D]; D]) -> R {
    let mut s = R::ZERO;
    for row in g {
        for &x in row {
            s += x * x;
        }
    }
    s
}

/// Unit segregation direction `d_s` from the velocity gradient `g` at velocity `u`
/// (model.md 3): the normal of the plane of largest shear, `(e_max +- e_min)/sqrt 2`, the one
/// more nearly orthogonal to `u`. Where the shear vanishes, `fallback` (the gravity direction)
/// is returned; where both normals are equally orthogonal to `u` (u = 0 in a shear band), the
/// one closer to `fallback` is taken, so the choice does not depend on the sign of the shear.
pub fn segregation_direction<R: Real, const D: usize>(
    g: &[[R; D]; D],
    u: &[R; D],
    fallback: [R; D],
) -> [R; D] {
    match D {
        1 => {
            let mut d = [R::ZERO; D];
            d[0] = R::ONE;
            d
        }
        2 => {
            let k = [
                [g[0][0] + g[0][0], g[0][1] + g[1][0]],
                [g[1][0] + g[0][1], g[1][1] + g[1][1]],
            ];
            match direction_2d(k, [u[0], u[1]], [fallback[0], fallback[1]]) {
                Some(d) => {
                    let mut out = [R::ZERO; D];
                    out[0] = d[0];
                    out[1] = d[1];
                    out
                }
                None => fallback,
            }
        }
        _ => {
            let m = Matrix3::from_fn(|r, c| (g[r][c] + g[c][r]).to_f64());
            let u3 = [u[0].to_f64(), u[1].to_f64(), u[2].to_f64()];
            let f3 = [
                fallback[0].to_f64(),
                fallback[1].to_f64(),
                fallback[2].to_f64(),
            ];
            match direction_3d(m, u3, f3) {
                Some(d) => {
                    let mut out = [R::ZERO; D];
                    for a in 0..3 {
                        out[a] = R::from_f64(d[a]);
                    }
                    out
                }
                None => fallback,
            }
        }
    }
}

/// 2D closed form. For `k = [[a, b], [b, d]]` the principal axes are at angle theta with
/// `tan 2 theta = 2b / (a - d)`; the planes of largest shear are at `theta +- pi/4`. Their
/// normals follow from the half-angle formulas, so only square roots are needed.
fn direction_2d<R: Real>(k: [[R; 2]; 2], u: [R; 2], fallback: [R; 2]) -> Option<[R; 2]> {
    let (a, b, d) = (k[0][0], k[0][1], k[1][1]);
    let half_diff = (a - d) * R::HALF;
    let r = (half_diff * half_diff + b * b).sqrt();
    if !(r > R::EPSILON * (a.abs() + b.abs() + d.abs())) || r == R::ZERO {
        return None;
    }
    // Double angle of the shear-plane normal: 2 phi = 2 theta + pi/2.
    let cos2 = -(b / r);
    let sin2 = half_diff / r;
    let cos1 = ((R::ONE + cos2) * R::HALF).max(R::ZERO).sqrt();
    let mut sin1 = ((R::ONE - cos2) * R::HALF).max(R::ZERO).sqrt();
    if sin2 < R::ZERO {
        sin1 = -sin1;
    }
    let n1 = [cos1, sin1];
    let n2 = [-sin1, cos1];
    let dot = |n: [R; 2], v: [R; 2]| (n[0] * v[0] + n[1] * v[1]).abs();
    let speed = (u[0] * u[0] + u[1] * u[1]).sqrt();
    let (dot1, dot2) = (dot(n1, u), dot(n2, u));
    Some(if (dot1 - dot2).abs() <= R::EPSILON * speed {
        if dot(n2, fallback) > dot(n1, fallback) {
            n2
        } else {
            n1
        }
    } else if dot2 < dot1 {
        n2
    } else {
        n1
    })
}

/// 3D: a bounded symmetric eigen-solve (nalgebra, at most 64 sweeps).
fn direction_3d(k: Matrix3<f64>, u: [f64; 3], fallback: [f64; 3]) -> Option<[f64; 3]> {
    let scale = k.amax();
    if !(scale > 0.0) {
        return None;
    }
    let eig = SymmetricEigen::try_new(k / scale, 1e-14, 64)?;
    let (mut imax, mut imin) = (0, 0);
    for i in 1..3 {
        if eig.eigenvalues[i] > eig.eigenvalues[imax] {
            imax = i;
        }
        if eig.eigenvalues[i] < eig.eigenvalues[imin] {
            imin = i;
        }
    }
    if !(eig.eigenvalues[imax] - eig.eigenvalues[imin] > 1e-12) {
        return None;
    }
    let emax = eig.eigenvectors.column(imax);
    let emin = eig.eigenvectors.column(imin);
    let plus = (emax + emin).normalize();
    let minus = (emax - emin).normalize();
    let dot =
        |v: &nalgebra::Vector3<f64>, w: [f64; 3]| (v[0] * w[0] + v[1] * w[1] + v[2] * w[2]).abs();
    let speed = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt();
    let (dp, dm) = (dot(&plus, u), dot(&minus, u));
    let best = if (dp - dm).abs() <= f64::EPSILON * speed {
        if dot(&minus, fallback) > dot(&plus, fallback) {
            minus
        } else {
            plus
        }
    } else if dm < dp {
        minus
    } else {
        plus
    };
    Some([best[0], best[1], best[2]])
}
