//! The segregation timer's sample of a coupled step (the timer itself is `StepTimer` in
//! `crate::flow`): Psi of the step's `phi` and `c`, or, where a floor under it proves that it
//! cannot cross the threshold, the fields held instead, evaluated only if the next sample
//! crosses (then within that sample: every subdomain decides alike from the same sums, so
//! no rank waits for another's word). Its sums run in cell order over the cells this process owns, continued from the
//! subdomains before it (`sieve_core::sum::InOrder`): on the whole grid that is the serial
//! loop, on the slabs of an MPI run one message of seven values per neighbour instead of
//! every cell's `phi` and `c` to rank 0 (docs/parallel.md, "A coupled scene under mpirun").
//! Either way the Psi has the serial bits ([`sieve_core::add_psi_sums`]).

use sieve_core::sum::InOrder;
use sieve_core::{add_psi_sums, psi_of_sums, psi_sums_start, PsiOf, Real, Segregation};
use std::ops::Range;

/// The sample of a step ([`StepPsi::sample`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Sample {
    /// Psi of the step.
    Psi {
        /// Psi of the step.
        psi: f64,
        /// Where `psi` is below the threshold (or NaN) and the sample before was held, the
        /// held one's Psi (the crossing interpolates from it).
        held: Option<f64>,
    },
    /// A floor under its Psi is at or above the threshold: the step cannot cross, its fields
    /// are held.
    Held,
}

/// The fields of the latest sampled step and of the held one, over the owned cells.
pub struct StepPsi<R> {
    /// The owned cells in the stepped solver's numbering.
    own: Range<usize>,
    /// The cells of the whole grid (the floor's round-off bound counts them all).
    cells: usize,
    /// `[phi, c]` of the latest step, and of the held one.
    fields: [Vec<R>; 2],
    held: [Vec<R>; 2],
    /// The last sample was held.
    holding: bool,
    /// The open volume fractions of the owned cut cells (`None`: a box).
    volume: Option<Vec<R>>,
    vacuum: R,
    cell_volume: R,
}

impl<R: Real> StepPsi<R> {
    /// Samples of the cells `own` of a solver configured as `seg`, in a grid of `cells`
    /// cells; `volume`: the open volume fractions of those cells (`None`: a box).
    pub fn new<const D: usize, const N: usize>(
        seg: &Segregation<R, D, N>,
        own: Range<usize>,
        cells: usize,
        volume: Option<&[R]>,
    ) -> Self {
        Self {
            own,
            cells,
            fields: [Vec::new(), Vec::new()],
            held: [Vec::new(), Vec::new()],
            holding: false,
            volume: volume.map(<[R]>::to_vec),
            vacuum: seg.config().vacuum,
            cell_volume: seg.grid().cell_volume(),
        }
    }

    /// The sample of `seg`'s owned cells against `threshold`, its sums continued across the
    /// subdomains by `sums` (collective: every subdomain samples its own step).
    pub fn sample<const D: usize, const N: usize>(
        &mut self,
        seg: &Segregation<R, D, N>,
        threshold: f64,
        sums: &mut impl InOrder<R>,
    ) -> Sample {
        let [phi, c] = &mut self.fields;
        phi.clear();
        phi.extend(self.own.clone().map(|i| seg.phi(i)));
        c.clear();
        c.extend(self.own.clone().map(|i| seg.c(i)));
        if self.psi(PsiOf::Floor, false, sums) >= threshold {
            core::mem::swap(&mut self.fields, &mut self.held);
            self.holding = true;
            return Sample::Held;
        }
        let psi = self.psi(PsiOf::Value, false, sums);
        let crossing = !(psi >= threshold);
        let held = (self.holding && crossing).then(|| self.psi(PsiOf::Value, true, sums));
        self.holding = false;
        Sample::Psi { psi, held }
    }

    /// Psi (`of`) of the latest or the `held` fields.
    fn psi(&self, of: PsiOf, held: bool, sums: &mut impl InOrder<R>) -> f64 {
        let [phi, c] = if held { &self.held } else { &self.fields };
        let vol = self.volume.as_deref();
        let total = sums.sums_in_order(psi_sums_start(), |s| {
            add_psi_sums(s, of, phi, c, vol, self.vacuum)
        });
        psi_of_sums(total, of, self.cells, self.cell_volume).to_f64()
    }
}
