//! Diagnostics of model.md section 6: phase masses, bound violations, mixing entropy and index,
//! segregation time, and the state hash.

use crate::geometry::CutCells;
use crate::hash::Fnv64;
use crate::real::Real;
use crate::segregation::Segregation;

/// One snapshot of the diagnostics. Sums run in cell order (deterministic).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Diagnostics<R> {
    /// Mass of the small phase, `sum phi |C|`.
    pub mass_small: R,
    /// Mass of all grains, `sum c |C|`.
    pub mass_total: R,
    /// `max(0, phi - c)` over cells.
    pub overshoot: R,
    /// `max(0, -phi)` over cells.
    pub undershoot: R,
    /// Mixing entropy `E = sum e(phihat) c |C|`.
    pub entropy: R,
    /// Entropy of the perfectly mixed state with the same amounts.
    pub entropy_mixed: R,
    /// Mixing index `Psi = (E - E_seg)/(E_mix - E_seg)`, 1 mixed, 0 segregated (`E_seg = 0`).
    pub psi: R,
    /// Smallest and largest phihat over non-empty cells.
    pub phihat_min: R,
    /// see `phihat_min`
    pub phihat_max: R,
}

/// `e(x) = -x ln x - (1-x) ln(1-x)` with `0 ln 0 = 0`; the argument is clamped to [0, 1] so a
/// state that a naive scheme pushed out of bounds still has a finite entropy.
pub fn mixing_entropy_density<R: Real>(x: R) -> R {
    let x = x.max(R::ZERO).min(R::ONE);
    let term = |y: R| if y > R::ZERO { -(y * y.ln()) } else { R::ZERO };
    term(x) + term(R::ONE - x)
}

/// Computes the diagnostics of the current state.
///
/// `E_seg` is the entropy of the ideal fully segregated state, 0: every grain in a pure region.
/// A discrete state carries a thin interface and so keeps Psi slightly above 0.
pub fn diagnose<R: Real, const D: usize, const N: usize>(
    s: &Segregation<R, D, N>,
) -> Diagnostics<R> {
    let vol = s.grid().cell_volume();
    let vacuum = s.config().vacuum;
    let mut mass_small = R::ZERO;
    let mut mass_total = R::ZERO;
    let mut overshoot = R::ZERO;
    let mut undershoot = R::ZERO;
    let mut entropy = R::ZERO;
    let mut phihat_min = R::ONE;
    let mut phihat_max = R::ZERO;
    for i in 0..s.len() {
        let (phi, c) = (s.phi(i), s.c(i));
        mass_small += phi;
        mass_total += c;
        overshoot = overshoot.max(phi - c);
        undershoot = undershoot.max(-phi);
        if c > vacuum {
            let ph = phi / c;
            phihat_min = phihat_min.min(ph);
            phihat_max = phihat_max.max(ph);
            entropy += mixing_entropy_density(ph) * c;
        }
    }
    mass_small *= vol;
    mass_total *= vol;
    entropy *= vol;
    let mixed = if mass_total > R::ZERO {
        mixing_entropy_density(mass_small / mass_total) * mass_total
    } else {
        R::ZERO
    };
    let psi = if mixed > R::ZERO {
        entropy / mixed
    } else {
        R::ZERO
    };
    Diagnostics {
        mass_small,
        mass_total,
        overshoot,
        undershoot,
        entropy,
        entropy_mixed: mixed,
        psi,
        phihat_min,
        phihat_max,
    }
}

/// [`diagnose`] on cut cells: every sum weighs cell `i` by its open volume fraction
/// `V_i` (model.md 6 with `|C_i|` the open volume), solid cells count for nothing and are
/// left out of the bounds and the phihat range. Merged cells hold their master's state, so
/// a group counts with its whole volume.
pub fn diagnose_embedded<R: Real, const D: usize, const N: usize>(
    s: &Segregation<R, D, N>,
    geo: &CutCells<R, D, N>,
) -> Diagnostics<R> {
    let vol = s.grid().cell_volume();
    let vacuum = s.config().vacuum;
    let mut mass_small = R::ZERO;
    let mut mass_total = R::ZERO;
    let mut overshoot = R::ZERO;
    let mut undershoot = R::ZERO;
    let mut entropy = R::ZERO;
    let mut phihat_min = R::ONE;
    let mut phihat_max = R::ZERO;
    for i in 0..s.len() {
        let v = geo.volume(i);
        if v == R::ZERO {
            continue;
        }
        let (phi, c) = (s.phi(i), s.c(i));
        mass_small += phi * v;
        mass_total += c * v;
        overshoot = overshoot.max(phi - c);
        undershoot = undershoot.max(-phi);
        if c > vacuum {
            let ph = phi / c;
            phihat_min = phihat_min.min(ph);
            phihat_max = phihat_max.max(ph);
            entropy += mixing_entropy_density(ph) * c * v;
        }
    }
    mass_small *= vol;
    mass_total *= vol;
    entropy *= vol;
    let mixed = if mass_total > R::ZERO {
        mixing_entropy_density(mass_small / mass_total) * mass_total
    } else {
        R::ZERO
    };
    let psi = if mixed > R::ZERO {
        entropy / mixed
    } else {
        R::ZERO
    };
    Diagnostics {
        mass_small,
        mass_total,
        overshoot,
        undershoot,
        entropy,
        entropy_mixed: mixed,
        psi,
        phihat_min,
        phihat_max,
    }
}

/// 64-bit FNV-1a of the little-endian bytes of the whole state: extents (u32), time, then
/// phi, c, T and each velocity component over the active cells. Independent of the compiled
/// capacity, so a run hashes the same whichever capacity hosted it.
pub fn state_hash<R: Real, const D: usize, const N: usize>(s: &Segregation<R, D, N>) -> u64 {
    let mut h = Fnv64::new();
    for n in s.grid().cells() {
        h.write_u32(n as u32);
    }
    s.time().hash_into(&mut h);
    let n = s.len();
    for i in 0..n {
        s.phi(i).hash_into(&mut h);
    }
    for i in 0..n {
        s.c(i).hash_into(&mut h);
    }
    for i in 0..n {
        s.temperature(i).hash_into(&mut h);
    }
    for a in 0..D {
        for i in 0..n {
            s.velocity(i)[a].hash_into(&mut h);
        }
    }
    h.finish()
}

/// Records when the mixing index first falls below a threshold, interpolating linearly
/// between samples (model.md 6, segregation time).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SegregationClock<R> {
    threshold: R,
    last: Option<(R, R)>,
    crossed: Option<R>,
}

impl<R: Real> SegregationClock<R> {
    /// A clock for `Psi < threshold`.
    pub fn new(threshold: R) -> Self {
        Self {
            threshold,
            last: None,
            crossed: None,
        }
    }
    /// The threshold.
    pub fn threshold(&self) -> R {
        self.threshold
    }
    /// Feeds one sample `(t, psi)`; samples must come in time order.
    pub fn sample(&mut self, t: R, psi: R) {
        if self.crossed.is_none() && psi < self.threshold {
            self.crossed = Some(match self.last {
                Some((t0, p0)) if p0 > psi => t0 + (t - t0) * (p0 - self.threshold) / (p0 - psi),
                _ => t,
            });
        }
        self.last = Some((t, psi));
    }
    /// The segregation time, if reached.
    pub fn time(&self) -> Option<R> {
        self.crossed
    }
}
