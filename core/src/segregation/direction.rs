//! Segregation direction from the velocity field (model.md section 3) and the shear rate used
//! to derive T from a measured velocity (model.md section 2, last relation).

use crate::boundary::{Boundaries, Boundary};
use crate::grid::Grid;
use crate::real::Real;

use super::eigen3;
pub use super::eigen3::symmetric_eigen_3;

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
///
/// This is [`segregation_normal`] normalised; the solver uses that one directly.
pub fn segregation_direction<R: Real, const D: usize>(
    g: &[[R; D]; D],
    u: &[R; D],
    fallback: [R; D],
) -> [R; D] {
    let (mut m, mm) = segregation_normal(g, u, fallback);
    if mm != R::ONE {
        let len = mm.sqrt();
        m.iter_mut().for_each(|x| *x = *x / len);
    }
    m
}

/// The segregation direction of [`segregation_direction`] as a normal `m` of any length,
/// with `m . m`: `d_s = +-m / |m|`. `S = -S0 sqrt(T) (g . d_s) d_s` (model.md 3) is even and
/// of degree 0 in `d_s`, so the solver uses `S = -S0 sqrt(T) (g . m) m / (m . m)` and never
/// normalises: in 2D that saves the square roots of the normalisation (three of the five per
/// cell on the soft sensor's Cortex-M4F, where `sqrtf` is a ~66-instruction software routine).
///
/// In 2D `m` is the closed form of `direction_2d` with `2 <= m . m <= 4`; in 3D `e_max +-
/// e_min` of `normals_3d` with `m . m = 2` to round-off; in 1D and where the shear vanishes
/// (`fallback`, a unit vector) `m` is a unit vector and `m . m` is returned as exactly 1, so
/// that dividing by it changes no bit.
#[inline]
pub fn segregation_normal<R: Real, const D: usize>(
    g: &[[R; D]; D],
    u: &[R; D],
    fallback: [R; D],
) -> ([R; D], R) {
    match D {
        1 => {
            let mut d = [R::ZERO; D];
            d[0] = R::ONE;
            (d, R::ONE)
        }
        2 => {
            let k = [
                [g[0][0] + g[0][0], g[0][1] + g[1][0]],
                [g[1][0] + g[0][1], g[1][1] + g[1][1]],
            ];
            match direction_2d(k, [u[0], u[1]], [fallback[0], fallback[1]]) {
                Some(m) => {
                    let mut out = [R::ZERO; D];
                    out[0] = m[0];
                    out[1] = m[1];
                    (out, m[0] * m[0] + m[1] * m[1])
                }
                None => (fallback, R::ONE),
            }
        }
        _ => {
            let k = strain_entries(g).map(|x| [x]);
            let u3 = [[u[0].to_f64()], [u[1].to_f64()], [u[2].to_f64()]];
            let f3 = [
                fallback[0].to_f64(),
                fallback[1].to_f64(),
                fallback[2].to_f64(),
            ];
            let (mut m, mut mm) = ([[0.0]; 3], [0.0]);
            normals_3d::<1>(&k, &u3, f3, &mut m, &mut mm);
            let mut out = [R::ZERO; D];
            for a in 0..3 {
                out[a] = R::from_f64(m[a][0]);
            }
            (out, R::from_f64(mm[0]))
        }
    }
}

/// 2D closed form, one square root. For `k = [[a, b], [b, d]]` the principal axes are at angle
/// theta with `tan 2 theta = 2b / (a - d)`; the planes of largest shear are at `theta +- pi/4`,
/// so one of their normals `n1 = (cos phi, sin phi)` has `2 phi = 2 theta + pi/2`:
/// `cos 2phi = -b / r`, `sin 2phi = (a - d) / 2r`, `r = sqrt(((a - d)/2)^2 + b^2)`. The other
/// is `n2 = (-sin phi, cos phi)`.
///
/// The half-angle identities give `n1` without further roots, up to a factor:
/// `(1 + cos 2phi, sin 2phi) = 2 cos phi n1` and `(sin 2phi, 1 - cos 2phi) = 2 sin phi n1`.
/// The first is taken for `cos 2phi >= 0`, the second otherwise, so `1 +- cos 2phi` never
/// cancels and `m1 . m1 = 2 (1 + |cos 2phi|)` lies in [2, 4] (the sign of the factor does not
/// matter: `d_s` is defined up to sign). `m2 = (-m1_y, m1_x)` has the same length.
///
/// Which normal is more nearly orthogonal to `u`: the smaller of `|m1 . u|` and `|m2 . u|`
/// (equal lengths, so no normalisation). A tie, `| |m1.u| - |m2.u| | <= eps (|m1.u| + |m2.u|)`,
/// needs no `|u|` either: `m1 _|_ m2` gives `|m1.u|^2 + |m2.u|^2 = |m|^2 |u|^2`, so the right
/// side is `eps |m| |u|` up to a factor in [1, sqrt 2]: the relative round-off level of the
/// dot products. u = 0 is always a tie, resolved towards `fallback`.
#[inline]
fn direction_2d<R: Real>(k: [[R; 2]; 2], u: [R; 2], fallback: [R; 2]) -> Option<[R; 2]> {
    let (a, b, d) = (k[0][0], k[0][1], k[1][1]);
    let half_diff = (a - d) * R::HALF;
    let r = (half_diff * half_diff + b * b).sqrt();
    if !(r > R::EPSILON * (a.abs() + b.abs() + d.abs())) || r == R::ZERO {
        return None;
    }
    let (m1, m2) = shear_normals(-(b / r), half_diff / r);
    Some(more_orthogonal(m1, m2, u, fallback))
}

/// The normals `m1`, `m2` of the two planes of largest shear from `cos 2phi`, `sin 2phi`, by
/// the half-angle identities of [`direction_2d`] (equal lengths).
#[inline(always)]
fn shear_normals<R: Real>(cos2: R, sin2: R) -> ([R; 2], [R; 2]) {
    let m1 = if cos2 >= R::ZERO {
        [R::ONE + cos2, sin2]
    } else {
        [sin2, R::ONE - cos2]
    };
    (m1, [-m1[1], m1[0]])
}

/// Of `m1` and `m2` (equal lengths), the one more nearly orthogonal to `u`; a tie within the
/// dot products' round-off goes towards `fallback` ([`direction_2d`]). Selects only.
#[inline(always)]
fn more_orthogonal<R: Real>(m1: [R; 2], m2: [R; 2], u: [R; 2], fallback: [R; 2]) -> [R; 2] {
    let dot = |n: [R; 2], v: [R; 2]| (n[0] * v[0] + n[1] * v[1]).abs();
    let (dot1, dot2) = (dot(m1, u), dot(m2, u));
    let tie = (dot1 - dot2).abs() <= R::EPSILON * (dot1 + dot2);
    let pick_m2 = if tie {
        dot(m2, fallback) > dot(m1, fallback)
    } else {
        dot2 < dot1
    };
    if pick_m2 {
        m2
    } else {
        m1
    }
}

/// `out[i] = (u[i + s] - u[i - s]) / w` for the cells `s..n - s` (`n = out.len()`), the
/// central difference of [`velocity_gradient_at`] along an axis of stride `s` with
/// `w = 2 h`; the other cells are left alone. A straight loop that vectorises.
#[inline(always)]
pub(crate) fn central_difference<R: Real>(out: &mut [R], u: &[R], s: usize, w: R) {
    let n = out.len().min(u.len());
    if n <= 2 * s {
        return;
    }
    let m = n - 2 * s;
    let (lo, hi) = (&u[..m], &u[2 * s..2 * s + m]);
    for ((o, &a), &b) in out[s..s + m].iter_mut().zip(lo).zip(hi) {
        *o = (b - a) / w;
    }
}

/// First part of [`direction_2d`] over arrays: from the gradient `(g00, g10, g01, g11)` of
/// each cell (in `x0, x1, x2, x3`) the entries `a = 2 g00`, `b = g01 + g10`, `d = 2 g11` of
/// `k = g + g^T` and `r^2 = ((a - d)/2)^2 + b^2`, in their place. Vectorises.
#[inline(always)]
pub(crate) fn normal_2d_parts<R: Real>(x0: &mut [R], x1: &mut [R], x2: &mut [R], x3: &mut [R]) {
    let n = x0.len().min(x1.len()).min(x2.len()).min(x3.len());
    let (x0, x1, x2, x3) = (&mut x0[..n], &mut x1[..n], &mut x2[..n], &mut x3[..n]);
    for i in 0..n {
        let (g00, g10, g01, g11) = (x0[i], x1[i], x2[i], x3[i]);
        let (a, b, d) = (g00 + g00, g01 + g10, g11 + g11);
        let half_diff = (a - d) * R::HALF;
        (x0[i], x1[i], x2[i], x3[i]) = (a, b, d, half_diff * half_diff + b * b);
    }
}

/// The rest of [`direction_2d`] and [`segregation_normal`] over arrays, without branches
/// (selects only: vectorises): from `a, b` (in `m`), `d` and `r` of each cell and its
/// velocity `u`, the normal `m` (into `m`) and `m . m` (into `r`); `fallback` and 1 where
/// the shear vanishes. The same operations as the per-cell functions: the same bits.
#[inline(always)]
pub(crate) fn normal_2d_finish<R: Real>(
    m: [&mut [R]; 2],
    d: &[R],
    r: &mut [R],
    u: [&[R]; 2],
    fallback: [R; 2],
) {
    let [m0, m1] = m;
    let n = m0.len().min(m1.len()).min(d.len()).min(r.len());
    let n = n.min(u[0].len()).min(u[1].len());
    let (m0, m1, d, r) = (&mut m0[..n], &mut m1[..n], &d[..n], &mut r[..n]);
    let (u0, u1) = (&u[0][..n], &u[1][..n]);
    for i in 0..n {
        let (a, b, d, r_i) = (m0[i], m1[i], d[i], r[i]);
        let half_diff = (a - d) * R::HALF;
        let sheared = r_i > R::EPSILON * (a.abs() + b.abs() + d.abs()) && r_i != R::ZERO;
        let (p, q) = shear_normals(-(b / r_i), half_diff / r_i);
        let best = more_orthogonal(p, q, [u0[i], u1[i]], fallback);
        let (out, mm) = if sheared {
            (best, best[0] * best[0] + best[1] * best[1])
        } else {
            (fallback, R::ONE)
        };
        (m0[i], m1[i], r[i]) = (out[0], out[1], mm);
    }
}

/// Cells whose 3D normals the solver's pass 1 finds side by side ([`normals_3d`]): two
/// AVX-512 registers of f64, so that two independent chains overlap.
pub(crate) const LANES_3D: usize = 16;

/// The strain-rate matrix `k = g + g^T` of a 3D velocity gradient as the six entries
/// `[k00, k11, k22, k01, k02, k12]` that [`normals_3d`] reads (summed in `R`, then widened).
#[inline(always)]
pub(crate) fn strain_entries<R: Real, const D: usize>(g: &[[R; D]; D]) -> [f64; 6] {
    let k = |r: usize, c: usize| (g[r][c] + g[c][r]).to_f64();
    [k(0, 0), k(1, 1), k(2, 2), k(0, 1), k(0, 2), k(1, 2)]
}

/// 3D, `L` cells side by side: from the strain rate `k` ([`strain_entries`], lane by lane)
/// and the velocity `u`, the normal `m = e_max +- e_min` of the plane of largest shear more
/// nearly orthogonal to `u` (model.md 3; `e_max`, `e_min` the principal axes of the largest
/// and smallest eigenvalues, [`eigen3`]) and `m . m` (2 to round-off); where the shear
/// vanishes (eigenvalues within 1e-12 of the largest entry), `k` is not finite or the
/// eigen-solve does not converge, `fallback` and 1.
///
/// `S` is of degree 0 in `m`, so `m` is not normalised (no square root): `e_max + e_min` and
/// `e_max - e_min` have the same length to round-off, and their dot products with `u` are
/// compared as they are. A tie, `|m1.u| - |m2.u|` within `eps sqrt 2 |u|` (the round-off of
/// the unit normals' products, squared: no square root either), goes towards `fallback`, so
/// the choice does not depend on the sign of the shear. Selects only: the lanes vectorise.
#[inline(always)]
pub(crate) fn normals_3d<const L: usize>(
    k: &[[f64; L]; 6],
    u: &[[f64; L]; 3],
    fallback: [f64; 3],
    m: &mut [[f64; L]; 3],
    mm: &mut [f64; L],
) {
    // Scaled by the largest entry (a NaN entry is skipped here and caught by `total`).
    let mut scaled = [[0.0; L]; 6];
    let mut total = [0.0; L];
    let mut fine = [false; L];
    for l in 0..L {
        let scale = k.iter().fold(0.0f64, |s, e| s.max(e[l].abs()));
        let div = if scale > 0.0 { scale } else { 1.0 };
        for (s, e) in scaled.iter_mut().zip(k) {
            s[l] = e[l] / div;
        }
        let e = scaled.map(|s| s[l]);
        total[l] = eigen3::squared_entries([e[0], e[1], e[2]], [e[3], e[4], e[5]]);
        fine[l] = scale > 0.0 && total[l].is_finite();
    }
    let mut a = eigen3::Lanes::new(&scaled);
    a.sweeps(eigen3::FIXED_SWEEPS);
    for l in 0..L {
        if fine[l] && !a.converged(l, total[l]) {
            fine[l] = a.finish(l, total[l], eigen3::FIXED_SWEEPS);
        }
    }
    for l in 0..L {
        let values = a.diag.map(|x| x[l]);
        let column = |j: usize| [a.v[0][j][l], a.v[1][j][l], a.v[2][j][l]];
        let (mut vmax, mut emax) = (values[0], column(0));
        let (mut vmin, mut emin) = (values[0], column(0));
        for (j, &value) in values.iter().enumerate().skip(1) {
            if value > vmax {
                (vmax, emax) = (value, column(j));
            }
            if value < vmin {
                (vmin, emin) = (value, column(j));
            }
        }
        let sheared = vmax - vmin > 1e-12;
        let plus: [f64; 3] = core::array::from_fn(|i| emax[i] + emin[i]);
        let minus: [f64; 3] = core::array::from_fn(|i| emax[i] - emin[i]);
        let ul = u.map(|x| x[l]);
        let dot = |v: [f64; 3], w: [f64; 3]| super::dot(&v, &w);
        let (dp, dm) = (dot(plus, ul).abs(), dot(minus, ul).abs());
        let tie = (dp - dm) * (dp - dm) <= 2.0 * f64::EPSILON * f64::EPSILON * dot(ul, ul);
        let towards_fallback = dot(minus, fallback).abs() > dot(plus, fallback).abs();
        let take_minus = if tie { towards_fallback } else { dm < dp };
        let best = if take_minus { minus } else { plus };
        let ok = fine[l] && sheared;
        for (mi, (&b, &f)) in m.iter_mut().zip(best.iter().zip(&fallback)) {
            mi[l] = if ok { b } else { f };
        }
        mm[l] = if ok { dot(best, best) } else { 1.0 };
    }
}
