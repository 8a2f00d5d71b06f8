//! The principal axes of a symmetric 3 x 3 matrix by cyclic Jacobi rotations, for many
//! matrices side by side (model.md 3: the 3D segregation direction needs the principal axes
//! of the strain rate in every cell).
//!
//! Why lanes: one matrix at a time is a chain of dependent divisions and square roots (then
//! libm's inline `sqrtsd`, which no loop vectorises), and it was 37 % of a 3D silo step.
//! Here every matrix of a block takes the same [`FIXED_SWEEPS`] sweeps without branches
//! (selects only) and the square roots are Newton iterations on `[1, 2]` (multiply and
//! subtract), so the compiler runs the lanes in vector registers. A matrix that has not
//! converged after them goes on alone with the convergence test. Each lane's arithmetic does
//! not depend on the other lanes, so a cell's bits do not depend on the block it is in (nor on
//! a thread's share of the grid), and the single-matrix [`symmetric_eigen_3`] is the same
//! arithmetic with one lane.

/// Sweeps every matrix of a block takes before the first convergence test. Measured with a
/// Python prototype of these rotations on 20,000 random symmetric matrices (a third nearly 2D, a fifth nearly a simple shear): the
/// test of [`symmetric_eigen_3`] is first met after 2 sweeps for 0.4 %, after 3 for 63 % and
/// after 4 for 37 %. The extra sweep of those that converged after 3 rotates by round-off.
pub const FIXED_SWEEPS: usize = 4;

/// Sweeps before a matrix counts as not converging.
const MAX_SWEEPS: usize = 24;

/// Converged when the squared off-diagonal part is at most this fraction of the squared
/// matrix (an off-diagonal part below 1e-15 of the matrix).
const TOLERANCE: f64 = 1e-30;

/// `L` symmetric matrices, one per lane, with the rotations applied so far.
#[derive(Clone, Copy)]
pub struct Lanes<const L: usize> {
    /// The diagonal `a00, a11, a22`: the eigenvalues once converged.
    pub diag: [[f64; L]; 3],
    /// The off-diagonal `a01, a02, a12`.
    pub off: [[f64; L]; 3],
    /// The rotations' product `v[row][column]`: the eigenvectors are its columns.
    pub v: [[[f64; L]; 3]; 3],
}

impl<const L: usize> Lanes<L> {
    /// The matrices `[a00, a11, a22, a01, a02, a12]` (lane by lane), no rotation yet.
    #[inline(always)]
    pub fn new(k: &[[f64; L]; 6]) -> Self {
        let mut v = [[[0.0; L]; 3]; 3];
        for (i, row) in v.iter_mut().enumerate() {
            row[i] = [1.0; L];
        }
        Self {
            diag: [k[0], k[1], k[2]],
            off: [k[3], k[4], k[5]],
            v,
        }
    }

    /// `sweeps` cyclic sweeps on every lane, the rotations in the order (0,1), (0,2), (1,2).
    #[inline(always)]
    pub fn sweeps(&mut self, sweeps: usize) {
        for _ in 0..sweeps {
            // (p, q, r) and where a_pq, a_rp, a_rq live in `off`.
            self.rotate(0, 1, 0, 1, 2);
            self.rotate(0, 2, 1, 0, 2);
            self.rotate(1, 2, 2, 0, 1);
        }
    }

    /// Whether lane `l` has converged, `a01^2 + a02^2 + a12^2 <= TOLERANCE * total`, with
    /// `total` the squared entries of the matrix before the rotations (they keep it).
    #[inline(always)]
    pub fn converged(&self, l: usize, total: f64) -> bool {
        let o = self.off.map(|x| x[l]);
        o[0] * o[0] + o[1] * o[1] + o[2] * o[2] <= TOLERANCE * total
    }

    /// Lane `l` alone, sweeping until it converges (`true`) or `MAX_SWEEPS` sweeps in all
    /// have been made (`false`), after the `done` it has had.
    pub fn finish(&mut self, l: usize, total: f64, done: usize) -> bool {
        let mut one = Lanes::<1> {
            diag: self.diag.map(|x| [x[l]]),
            off: self.off.map(|x| [x[l]]),
            v: self.v.map(|row| row.map(|x| [x[l]])),
        };
        let mut converged = one.converged(0, total);
        for _ in done..MAX_SWEEPS {
            if converged {
                break;
            }
            one.sweeps(1);
            converged = one.converged(0, total);
        }
        for a in 0..3 {
            self.diag[a][l] = one.diag[a][0];
            self.off[a][l] = one.off[a][0];
            for b in 0..3 {
                self.v[a][b][l] = one.v[a][b][0];
            }
        }
        converged
    }

    /// The rotation in the plane (p, q) that zeroes `a_pq` of every lane; `r` is the third
    /// axis, `pq`, `rp`, `rq` the places of `a_pq`, `a_rp`, `a_rq` in `off`.
    ///
    /// `t = tan` of its angle is the smaller root of `t^2 + 2 theta t - 1 = 0`,
    /// `theta = tau / w`, `tau = a_qq - a_pp`, `w = 2 a_pq`: `t = sgn(tau w) / (|theta| +
    /// sqrt(theta^2 + 1))`. With `mu = min(|tau|, |w|) / max(|tau|, |w|)` and `sigma =
    /// sqrt(1 + mu^2)` in `[1, sqrt 2]` this is `mu / (1 + sigma)` where `|tau| >= |w|` and
    /// `1 / (mu + sigma)` elsewhere: no overflow or underflow at any scale, `|t| <= 1`, and
    /// both square roots (`sigma` and `cos = 1 / sqrt(1 + t^2)`) are of numbers in `[1, 2]`.
    #[inline(always)]
    fn rotate(&mut self, p: usize, q: usize, pq: usize, rp: usize, rq: usize) {
        for l in 0..L {
            let (app, aqq, apq) = (self.diag[p][l], self.diag[q][l], self.off[pq][l]);
            let tau = aqq - app;
            let w = apq + apq;
            let (at, aw) = (tau.abs(), w.abs());
            let tau_larger = at >= aw;
            let (lo, hi) = if tau_larger { (aw, at) } else { (at, aw) };
            // hi = 0 only where apq = 0, whose rotation is the identity (t = 0 below).
            let mu = lo / if hi > 0.0 { hi } else { 1.0 };
            let sigma = sqrt_1_2(1.0 + mu * mu);
            let size = if tau_larger {
                mu / (1.0 + sigma)
            } else {
                1.0 / (mu + sigma)
            };
            let negative = (tau < 0.0) != (w < 0.0);
            let signed = if negative { -size } else { size };
            let t = if apq == 0.0 { 0.0 } else { signed };
            let c = rsqrt_1_2(1.0 + t * t);
            let s = t * c;
            self.diag[p][l] = app - t * apq;
            self.diag[q][l] = aqq + t * apq;
            self.off[pq][l] = 0.0;
            let (arp, arq) = (self.off[rp][l], self.off[rq][l]);
            self.off[rp][l] = c * arp - s * arq;
            self.off[rq][l] = s * arp + c * arq;
            for row in self.v.iter_mut() {
                let (vp, vq) = (row[p][l], row[q][l]);
                row[p][l] = c * vp - s * vq;
                row[q][l] = s * vp + c * vq;
            }
        }
    }
}

/// `1 / sqrt(x)` for `x` in `[1, 2]`: a quadratic start (least squares on Chebyshev nodes,
/// relative error below 3.3e-3) and three Newton steps `y (3/2 - x y^2 / 2)`, each squaring
/// the error (1.6e-5, 3.9e-10, then round-off: a few units in the last place). Multiplies
/// and adds only, so it vectorises and gives the same bits on every platform.
#[inline(always)]
pub fn rsqrt_1_2(x: f64) -> f64 {
    let mut y = 1.580_647_74 + x * (-0.731_917_85 + x * 0.148_149_85);
    for _ in 0..3 {
        y = y * (1.5 - 0.5 * x * y * y);
    }
    y
}

/// `sqrt(x)` for `x` in `[1, 2]`, as `x / sqrt(x)` ([`rsqrt_1_2`]).
#[inline(always)]
fn sqrt_1_2(x: f64) -> f64 {
    x * rsqrt_1_2(x)
}

/// The squared entries of a symmetric matrix `[a00, a11, a22, a01, a02, a12]`, row by row.
#[inline(always)]
pub fn squared_entries(d: [f64; 3], o: [f64; 3]) -> f64 {
    let rows = [[d[0], o[0], o[1]], [o[0], d[1], o[2]], [o[1], o[2], d[2]]];
    let mut s = 0.0;
    for row in rows {
        for x in row {
            s += x * x;
        }
    }
    s
}

/// Eigenvalues and orthonormal eigenvectors (the columns of the matrix returned) of a
/// symmetric 3 x 3 matrix `k` (its upper triangle is read) by cyclic Jacobi rotations
/// (model.md 3: the principal axes of the strain rate), or `None` if `k` is not finite or the
/// off-diagonal part does not fall below 1e-15 of the matrix in 24 sweeps.
///
/// Why Jacobi: a fixed sequence of plane rotations, and the eigenvectors stay orthonormal to
/// round-off by construction even where two eigenvalues coincide. The arithmetic is that of
/// a block's lane (`Lanes`), so the bits are those of the solver's cells and the same on
/// every platform.
pub fn symmetric_eigen_3(k: [[f64; 3]; 3]) -> Option<([f64; 3], [[f64; 3]; 3])> {
    let entries = [k[0][0], k[1][1], k[2][2], k[0][1], k[0][2], k[1][2]];
    let total = squared_entries(
        [entries[0], entries[1], entries[2]],
        [entries[3], entries[4], entries[5]],
    );
    if !total.is_finite() {
        return None;
    }
    let mut a = Lanes::<1>::new(&entries.map(|x| [x]));
    a.sweeps(FIXED_SWEEPS);
    if !a.finish(0, total, FIXED_SWEEPS) {
        return None;
    }
    Some((a.diag.map(|x| x[0]), a.v.map(|row| row.map(|x| x[0]))))
}
