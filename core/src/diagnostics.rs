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
    diagnose_with_terms(s, |i| entropy_term(s.phi(i), s.c(i), s.config().vacuum))
}

/// The entropy term [`diagnose`] adds for one cell: `e(phi / c) c` where `c > vacuum`, else 0
/// (model.md 6). Its two `libm` logarithms are most of what a diagnosis costs.
#[inline(always)]
pub fn entropy_term<R: Real>(phi: R, c: R, vacuum: R) -> R {
    if c > vacuum {
        mixing_entropy_density(phi / c) * c
    } else {
        R::ZERO
    }
}

/// [`diagnose`] with cell `i`'s entropy term given by `term(i)`, which must equal
/// [`entropy_term`] of the cell: a driver may evaluate the terms on several threads
/// beforehand, and since every sum still runs in cell order the result has [`diagnose`]'s
/// bits.
pub fn diagnose_with_terms<R: Real, const D: usize, const N: usize>(
    s: &Segregation<R, D, N>,
    term: impl Fn(usize) -> R,
) -> Diagnostics<R> {
    let mut tally = Tally::new(s.config().vacuum);
    for i in 0..s.len() {
        tally.add(s.phi(i), s.c(i), |x| x, || term(i));
    }
    tally.finish(s.grid().cell_volume())
}

/// [`diagnose`] on cut cells: every sum weighs cell `i` by its open volume fraction
/// `V_i` (model.md 6 with `|C_i|` the open volume), solid cells count for nothing and are
/// left out of the bounds and the phihat range. Merged cells hold their master's state, so
/// a group counts with its whole volume.
pub fn diagnose_embedded<R: Real, const D: usize, const N: usize>(
    s: &Segregation<R, D, N>,
    geo: &CutCells<R, D, N>,
) -> Diagnostics<R> {
    let mut tally = Tally::new(s.config().vacuum);
    for i in 0..s.len() {
        let v = geo.volume(i);
        if v != R::ZERO {
            let (phi, c) = (s.phi(i), s.c(i));
            tally.add(phi, c, |x| x * v, || mixing_entropy_density(phi / c) * c);
        }
    }
    tally.finish(s.grid().cell_volume())
}

/// [`diagnose`] (`volume = None`) or [`diagnose_embedded`] (`volume` = the open volume
/// fractions) of a copied state: `phi` and `c` per cell as [`Segregation::phi`] and
/// [`Segregation::c`] returned them, `vacuum` and `cell_volume` of the solver's configuration
/// and grid. The same operations in the same order: the same bits. A driver that evaluates
/// Psi only when it must ([`psi_floor`]) keeps the fields of a step here.
pub fn diagnose_fields<R: Real>(
    phi: &[R],
    c: &[R],
    volume: Option<&[R]>,
    vacuum: R,
    cell_volume: R,
) -> Diagnostics<R> {
    tally_fields(Tally::new(vacuum), phi, c, volume, value_term).finish(cell_volume)
}

/// Which Psi the continued sums of [`add_psi_sums`] add up: the evaluated one
/// ([`diagnose_fields`]) or the floor under it ([`psi_floor`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PsiOf {
    /// Psi itself: two `libm` logarithms per cell.
    Value,
    /// The floor under Psi: a few multiplications per cell.
    Floor,
}

/// How many values [`add_psi_sums`] carries from one piece of the fields to the next.
pub const PSI_SUMS: usize = 7;

/// The running sums of Psi before the first cell (for [`add_psi_sums`]).
pub fn psi_sums_start<R: Real>() -> [R; PSI_SUMS] {
    Tally::new(R::ZERO).words()
}

/// Continues the running sums `sums` of Psi (or of its floor, `of`) over the next piece of
/// the fields in cell order (`phi`, `c`, `volume`, `vacuum` as [`diagnose_fields`] takes
/// them). A grid cut into subdomains continues the sums of the subdomains before it over its
/// own cells and hands them on (`crate::sum::InOrder::sums_in_order`, one message of
/// [`PSI_SUMS`] values): [`psi_of_sums`] of the last piece's sums has the bits of
/// [`diagnose_fields`]' / [`psi_floor`]'s Psi of the whole grid, which are these same sums
/// over one piece. What a driver of many ranks sends instead of the fields themselves.
pub fn add_psi_sums<R: Real>(
    sums: [R; PSI_SUMS],
    of: PsiOf,
    phi: &[R],
    c: &[R],
    volume: Option<&[R]>,
    vacuum: R,
) -> [R; PSI_SUMS] {
    let tally = Tally::from_words(vacuum, sums);
    // one loop per term, each as simple as the serial one
    match of {
        PsiOf::Value => tally_fields(tally, phi, c, volume, value_term),
        PsiOf::Floor => tally_fields(tally, phi, c, volume, floor_term),
    }
    .words()
}

/// Psi (or its floor, `of`) of the running sums over all `cells` cells of the grid
/// ([`add_psi_sums`]); `cell_volume` of the grid.
pub fn psi_of_sums<R: Real>(sums: [R; PSI_SUMS], of: PsiOf, cells: usize, cell_volume: R) -> R {
    let psi = Tally::from_words(R::ZERO, sums).finish(cell_volume).psi;
    match of {
        PsiOf::Value => psi,
        PsiOf::Floor => lowered(psi, cells),
    }
}

/// The entropy term of a cell of Psi (called where `c > vacuum`).
#[inline(always)]
fn value_term<R: Real>(phi: R, c: R) -> R {
    mixing_entropy_density(phi / c) * c
}

/// The entropy term of a cell of the floor under Psi (called where `c > vacuum`).
#[inline(always)]
fn floor_term<R: Real>(phi: R, c: R) -> R {
    // 4 ln 2 = 2.7725887..., rounded down
    let k = R::from_f64(2.772588);
    let x = (phi / c).max(R::ZERO).min(R::ONE);
    k * (x * (R::ONE - x)) * c
}

/// The floor's sum `lb` over `n` cells lowered by its round-off bound ([`psi_floor`]).
fn lowered<R: Real>(lb: R, n: usize) -> R {
    let n = R::from_usize(n);
    let margin = R::from_f64(4.0) * (n + R::from_f64(16.0)) * R::EPSILON;
    if margin < R::ONE {
        lb - lb * margin
    } else {
        R::ZERO
    }
}

/// A floor under the mixing index Psi that [`diagnose_fields`] returns for the same
/// arguments, without a logarithm per cell: `e(x) >= 4 ln 2 x (1 - x)` on [0, 1] (the binary
/// entropy in bits is at least `4 x (1 - x)`), summed in the same cell order with the same
/// masses, then lowered by `4 (n + 16) eps` of itself, more than the round-off of the two
/// sums of `n` positive terms and of the per-cell terms (one `libm` log is within an ulp).
/// So `psi_floor >= threshold` proves that the evaluated Psi is `>= threshold` too. A NaN in
/// `phi` or `c` makes a mass NaN and both Psi and the floor 0 (the clamps of
/// [`mixing_entropy_density`] take NaN to 0): a driver scans for non-finite values before it
/// samples (the run loops do). A floor of a well-mixed state is ~0.9 of Psi,
/// far above a segregation threshold of 0.05; it costs a few multiplications per cell
/// where Psi costs two `libm` logarithms.
pub fn psi_floor<R: Real>(
    phi: &[R],
    c: &[R],
    volume: Option<&[R]>,
    vacuum: R,
    cell_volume: R,
) -> R {
    let sums = add_psi_sums(psi_sums_start(), PsiOf::Floor, phi, c, volume, vacuum);
    psi_of_sums(sums, PsiOf::Floor, phi.len().min(c.len()), cell_volume)
}

/// `tally` continued over the fields with the entropy term `term(phi, c)` of a cell (called
/// where `c > vacuum` only).
fn tally_fields<R: Real>(
    mut tally: Tally<R>,
    phi: &[R],
    c: &[R],
    volume: Option<&[R]>,
    term: impl Fn(R, R) -> R,
) -> Tally<R> {
    let n = phi.len().min(c.len());
    let (phi, c) = (&phi[..n], &c[..n]);
    match volume {
        None => {
            for (&p, &ci) in phi.iter().zip(c) {
                tally.add(p, ci, |x| x, || term(p, ci));
            }
        }
        Some(vol) => {
            for ((&p, &ci), &v) in phi.iter().zip(c).zip(vol) {
                if v != R::ZERO {
                    tally.add(p, ci, |x| x * v, || term(p, ci));
                }
            }
        }
    }
    tally
}

/// The running sums of [`diagnose`] in cell order (one pass, deterministic), shared by the
/// box and the cut-cell diagnostics; `weigh` applies a cell's open volume fraction.
struct Tally<R> {
    vacuum: R,
    mass_small: R,
    mass_total: R,
    overshoot: R,
    undershoot: R,
    entropy: R,
    phihat_min: R,
    phihat_max: R,
}

impl<R: Real> Tally<R> {
    fn new(vacuum: R) -> Self {
        Self {
            vacuum,
            mass_small: R::ZERO,
            mass_total: R::ZERO,
            overshoot: R::ZERO,
            undershoot: R::ZERO,
            entropy: R::ZERO,
            phihat_min: R::ONE,
            phihat_max: R::ZERO,
        }
    }

    /// The running sums as values, in a fixed order (what a subdomain hands on).
    fn words(&self) -> [R; PSI_SUMS] {
        [
            self.mass_small,
            self.mass_total,
            self.overshoot,
            self.undershoot,
            self.entropy,
            self.phihat_min,
            self.phihat_max,
        ]
    }

    /// The tally of `words` ([`Self::words`]) with the empty-cell threshold `vacuum`.
    fn from_words(vacuum: R, w: [R; PSI_SUMS]) -> Self {
        let [mass_small, mass_total, overshoot, undershoot, entropy, phihat_min, phihat_max] = w;
        Self {
            vacuum,
            mass_small,
            mass_total,
            overshoot,
            undershoot,
            entropy,
            phihat_min,
            phihat_max,
        }
    }

    /// Adds a cell; `entropy()` (its `e(phi / c) c`) is called only where `c > vacuum`.
    #[inline(always)]
    fn add(&mut self, phi: R, c: R, weigh: impl Fn(R) -> R, entropy: impl FnOnce() -> R) {
        self.mass_small += weigh(phi);
        self.mass_total += weigh(c);
        self.overshoot = self.overshoot.max(phi - c);
        self.undershoot = self.undershoot.max(-phi);
        if c > self.vacuum {
            let ph = phi / c;
            self.phihat_min = self.phihat_min.min(ph);
            self.phihat_max = self.phihat_max.max(ph);
            self.entropy += weigh(entropy());
        }
    }

    /// Scales the sums by the cell volume and forms Psi (model.md 6).
    fn finish(self, vol: R) -> Diagnostics<R> {
        let mass_small = self.mass_small * vol;
        let mass_total = self.mass_total * vol;
        let entropy = self.entropy * vol;
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
            overshoot: self.overshoot,
            undershoot: self.undershoot,
            entropy,
            entropy_mixed: mixed,
            psi,
            phihat_min: self.phihat_min,
            phihat_max: self.phihat_max,
        }
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
