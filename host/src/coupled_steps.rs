//! How a coupled run steps (docs/parallel.md, "A coupled scene under mpirun"): the run
//! loop ([`crate::flow::coupled_loop_with`]) is written once against [`CoupledSteps`]; the
//! whole grid in this process ([`WholeSteps`]: the serial step, its solves on a thread pool
//! with `--threads`) and the slabs of an MPI run (`crate::rank_coupled`, the `mpi` feature)
//! answer it. The decision whether a step may be taken at all ([`plan_step`]) is a pure
//! function of values every rank holds, so every rank takes it alike without a message.

use crate::error::{Error, Result};
use crate::interrupt::Reason;
use crate::step_psi::{Sample, StepPsi};
use sieve_core::flow::coupled::{Coupled, CoupledTotals};
use sieve_core::flow::coupled_slab::SlabRecord;
use sieve_core::flow::FlowCounters;
use sieve_core::fork::Serial;
use sieve_core::sum::{FixedSum, Whole};
use sieve_core::Real;

/// What the coupled run loop asks of its stepper. `cpl` is the run of record: the state the
/// loop writes its outputs, checkpoints and summary from, current after [`Self::sync`].
pub trait CoupledSteps<R: Real, const D: usize, const N: usize> {
    /// One step toward `target` ([`plan_step`] with the run's first stable step `first`):
    /// the stable step, and `Err` with the reason the run stops if it was not taken or
    /// failed. With `sample` (the segregation timer's threshold), a step that was taken is
    /// sampled ([`Self::sampled`]) before anything else happens, so that on an MPI run
    /// every rank takes part in its sums.
    fn step_toward(
        &mut self,
        cpl: &mut Coupled<'_, R, D, N>,
        target: R,
        first: f64,
        sample: Option<f64>,
    ) -> (R, std::result::Result<(), Reason>);

    /// The run's clock (the stepped state's, which may be ahead of `cpl` until a sync).
    fn time(&self, cpl: &Coupled<'_, R, D, N>) -> R;

    /// After a step that was taken: a non-finite value anywhere (the first field and cell
    /// in the serial order of the scan).
    fn scan(&mut self, cpl: &mut Coupled<'_, R, D, N>) -> Result<Option<Reason>>;

    /// The sample of the last step if it was taken with `sample` (`crate::step_psi`).
    fn sampled(&self) -> Option<Sample>;

    /// Brings `cpl` up to the stepped state (before outputs, checkpoints and the end).
    fn sync(&mut self, cpl: &mut Coupled<'_, R, D, N>) -> Result<()>;
}

/// A coupled run whose stable step has fallen below [`COLLAPSE`] of its first one cannot
/// reach `t_end` (at 1e-9 of a millisecond step, a second takes 1e15 steps): a flow that ran
/// away (the dilute cells of issue 8's loose pressure solve reached 1e51 m/s and steps of
/// 5e-58 s, and the run never ended). Never hang: it stops as failed and keeps what it wrote.
/// A real flow's step moves by a few orders of magnitude at most (a silo's jet, a collapse).
/// `first` is the first stable step, at most `t_end` (a bed at rest may allow any step).
pub(crate) fn collapsed_step(stable: f64, first: f64) -> Option<Reason> {
    (stable < first * COLLAPSE).then(|| {
        Reason::Core(format!(
            "the stable time step fell to {} s, below {COLLAPSE:e} of the run's first step ({} s): the flow ran away and t_end cannot be reached",
            crate::text::approx(stable),
            crate::text::approx(first)
        ))
    })
}

/// See [`collapsed_step`].
const COLLAPSE: f64 = 1e-9;

/// The step to take from `time` toward `target` at the stable step `stable`: the stable
/// step, shortened to land on `target`; `Err` if it is not finite and positive or the
/// stable step collapsed below 1e-9 of the run's first (a flow that ran away).
pub fn plan_step<R: Real>(
    stable: R,
    target: R,
    time: R,
    first: f64,
) -> std::result::Result<R, Reason> {
    let dt = stable.min(target - time);
    match crate::interrupt::bad_dt(dt.to_f64()).or_else(|| collapsed_step(stable.to_f64(), first)) {
        Some(r) => Err(r),
        None => Ok(dt),
    }
}

/// The whole grid in this process: the serial step, its hot loops at the widest vector unit
/// (docs/simd.md) and, with `--threads`, its solves on a pool (the same bits,
/// docs/parallel.md).
pub struct WholeSteps<R> {
    /// The pool of `--threads` (none: one thread).
    pub pool: Option<crate::pool::Pool>,
    /// The vector unit the hot loops run at.
    pub level: crate::isa::Level,
    /// The segregation timer's samples of every cell.
    pub psi: StepPsi<R>,
    /// The last step's sample.
    pub sampled: Option<Sample>,
}

impl<R: Real, const D: usize, const N: usize> CoupledSteps<R, D, N> for WholeSteps<R> {
    fn step_toward(
        &mut self,
        cpl: &mut Coupled<'_, R, D, N>,
        target: R,
        first: f64,
        sample: Option<f64>,
    ) -> (R, std::result::Result<(), Reason>) {
        let stable = cpl.stable_dt();
        let dt = match plan_step(stable, target, cpl.seg.time(), first) {
            Ok(dt) => dt,
            Err(r) => return (stable, Err(r)),
        };
        let level = self.level;
        let stepped = match &self.pool {
            // the step on a worker: its loops fork from inside the pool
            Some(p) => p.install(|| crate::on_level!(level, p, |f| cpl.step_with_on(dt, f))),
            None => crate::on_level!(level, &Serial, |f| cpl.step_with_on(dt, f)),
        };
        let stepped = stepped.map_err(|e| {
            // The core names what it refused; a non-finite cell says more.
            crate::interrupt::scan_segregation(cpl.seg)
                .or_else(|| crate::interrupt::scan_flow(cpl.flow))
                .unwrap_or(Reason::Core(e.to_string()))
        });
        self.sampled = match (sample, &stepped) {
            (Some(threshold), Ok(())) => Some(self.psi.sample(cpl.seg, threshold, &mut Whole)),
            _ => None,
        };
        (stable, stepped)
    }

    fn time(&self, cpl: &Coupled<'_, R, D, N>) -> R {
        cpl.seg.time()
    }

    fn scan(&mut self, cpl: &mut Coupled<'_, R, D, N>) -> Result<Option<Reason>> {
        Ok(crate::interrupt::scan_segregation(cpl.seg)
            .or_else(|| crate::interrupt::scan_flow(cpl.flow)))
    }

    fn sampled(&self) -> Option<Sample> {
        self.sampled
    }

    fn sync(&mut self, _cpl: &mut Coupled<'_, R, D, N>) -> Result<()> {
        Ok(())
    }
}

/// The first row of every rank's slab when a coupled scene of `rows` rows along its last
/// axis runs on `ranks` MPI ranks: the rows shared evenly, each start rounded down to an
/// even row (the V-cycle coarsens pairs of rows across a cut).
pub fn even_starts(rows: usize, ranks: usize) -> Vec<usize> {
    (0..ranks).map(|k| k * rows / ranks / 2 * 2).collect()
}

/// [`even_starts`] where every slab holds at least `depth` rows, the halo's depth (its
/// halo rows must come from one neighbour; `sieve_core::flow::slab::halo_rows`); `None`
/// otherwise, or for no ranks.
pub fn slab_starts(rows: usize, ranks: usize, depth: usize) -> Option<Vec<usize>> {
    if ranks == 0 {
        return None;
    }
    let starts = even_starts(rows, ranks);
    let ends = starts.iter().skip(1).copied().chain([rows]);
    let fits = starts.len() == 1 || starts.iter().zip(ends).all(|(&s, e)| e >= s + depth);
    fits.then_some(starts)
}

/// Bad input: `ranks` ranks for a coupled scene (`file`, `dim` axes) of `rows` rows whose
/// slabs need halos `depth` rows deep, in the user's words (exit 2).
pub fn too_many_ranks(file: &str, dim: usize, rows: usize, ranks: usize, depth: usize) -> Error {
    let axis = crate::scene::validate::axis_names(dim)[dim - 1];
    let why = if depth > sieve_core::flow::slab::HALO {
        "with this scene's merged cut cells "
    } else {
        ""
    };
    Error::range(
        file,
        "mpirun -np",
        ranks,
        &format!(
            "1 to {} ranks for {rows} cells along {axis} (a coupled scene's slabs {why}own at least {depth} rows each, docs/parallel.md)",
            max_ranks(rows, depth)
        ),
    )
}

/// The most ranks a coupled scene of `rows` rows runs on with halos `depth` rows deep
/// ([`slab_starts`]).
pub fn max_ranks(rows: usize, depth: usize) -> usize {
    (1..=rows / depth.max(1))
        .rev()
        .find(|&k| slab_starts(rows, k, depth).is_some())
        .unwrap_or(1)
}

/// A slab's record as the words of a message to rank 0 (every value's f64 bits: an f32
/// value widens and narrows back exactly).
pub fn record_words<R: Real, const D: usize>(r: &SlabRecord<R, D>) -> Vec<u64> {
    let bits = |v: R| v.to_f64().to_bits();
    let sides = |s: &[[R; 2]; D]| s.iter().flatten().map(|&v| bits(v)).collect::<Vec<_>>();
    let f = &r.flow;
    let mut w = vec![bits(f.time), f.steps, bits(f.residual), f.cg_iterations];
    w.extend(f.last_cg.iter().map(|&n| u64::from(n)));
    w.extend(sides(&f.discharged));
    w.extend(sides(&f.discharge_step));
    w.extend([bits(r.time), r.steps, bits(r.excess[0]), bits(r.excess[1])]);
    w.push(bits(r.flushed));
    w.extend(FixedSum::words_of(&r.books));
    w.extend(sides(&r.totals.out_small));
    w.extend(sides(&r.totals.out_total));
    w.push(bits(r.totals.guarded));
    w
}

/// The record of [`record_words`]; `None` if the words are not one record's.
pub fn record_from_words<R: Real, const D: usize>(w: &[u64]) -> Option<SlabRecord<R, D>> {
    // 8 flow counters, 2 x 2D discharges, 5 segregation values, 4D book words, 2 x 2D
    // totals and the guard's
    if w.len() != 8 + 4 * D + 5 + 4 * D + 4 * D + 1 {
        return None;
    }
    let mut words = w.iter().copied();
    let mut word = || words.next().unwrap_or(0);
    let real = |x: u64| R::from_f64(f64::from_bits(x));
    let sides = |word: &mut dyn FnMut() -> u64| -> [[R; 2]; D] {
        core::array::from_fn(|_| [real(word()), real(word())])
    };
    let (time, steps, residual, cg_iterations) = (real(word()), word(), real(word()), word());
    let mut last_cg = [0u32; 4];
    for n in &mut last_cg {
        *n = u32::try_from(word()).ok()?;
    }
    let flow = FlowCounters {
        time,
        steps,
        residual,
        cg_iterations,
        last_cg,
        discharged: sides(&mut word),
        discharge_step: sides(&mut word),
    };
    let (time, steps) = (real(word()), word());
    let excess = [real(word()), real(word())];
    let flushed = real(word());
    let book_words: Vec<u64> = (0..4 * D).map(|_| word()).collect();
    let out_small = sides(&mut word);
    let out_total = sides(&mut word);
    let guarded = real(word());
    Some(SlabRecord {
        flow,
        time,
        steps,
        excess,
        flushed,
        books: FixedSum::sides_from_words(&book_words),
        totals: CoupledTotals {
            out_small,
            out_total,
            guarded,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use sieve_core::flow::slab::HALO;

    #[test]
    fn a_slab_record_survives_its_words_bit_for_bit() {
        let mut books = [[FixedSum::ZERO; 2]; 2];
        books[1][0].add(3.25e-7);
        books[0][1].add(-1.5);
        let r = SlabRecord::<f32, 2> {
            flow: FlowCounters {
                time: 0.125,
                steps: 77,
                residual: 3.0e-5,
                cg_iterations: 1234,
                last_cg: [5, 0, 9, 1],
                discharged: [[0.0, -0.0], [1.5e-3, 2.0]],
                discharge_step: [[0.0, 0.0], [7.0e-9, 0.0]],
            },
            time: 0.125,
            steps: 76,
            excess: [1e-30, 0.0],
            flushed: 2.5e-12,
            books,
            totals: CoupledTotals {
                out_small: [[0.0, 0.0], [4.0e-4, 0.0]],
                out_total: [[0.0, 0.0], [1.4e-3, 0.0]],
                guarded: 1e-20,
            },
        };
        let w = record_words(&r);
        let back = record_from_words::<f32, 2>(&w).unwrap();
        assert_eq!(back, r);
        assert_eq!(back.flow.discharged[0][1].to_bits(), (-0.0f32).to_bits());
        assert_eq!(record_words(&back), w);
        assert!(record_from_words::<f32, 2>(&w[1..]).is_none());
        assert!(record_from_words::<f32, 3>(&w).is_none());
    }

    #[test]
    fn slabs_of_a_coupled_run_start_on_even_rows_and_hold_a_halo_each() {
        assert_eq!(slab_starts(64, 2, HALO), Some(vec![0, 32]));
        assert_eq!(slab_starts(61, 4, HALO), Some(vec![0, 14, 30, 44]));
        assert_eq!(slab_starts(200, 3, HALO), Some(vec![0, 66, 132]));
        assert_eq!(slab_starts(10, 1, HALO), Some(vec![0]));
        // 3 ranks on 10 rows: 0, 2, 6 (the first slab would own 2 rows)
        assert_eq!(slab_starts(10, 3, HALO), None);
        assert_eq!(max_ranks(10, HALO), 2);
        assert_eq!(max_ranks(64, HALO), 16);
        assert_eq!(max_ranks(3, HALO), 1);
        // a drum's halo of 7 rows (merge groups spanning a row): 9 ranks on 64 rows
        assert_eq!(max_ranks(64, 7), 8);
        assert_eq!(slab_starts(64, 9, 7), None);
        let e = too_many_ranks("tumbler.toml", 2, 34, 5, 7).to_string();
        assert_eq!(
            e,
            "tumbler.toml: mpirun -np = 5 is out of range: allowed 1 to 4 ranks for 34 cells along z (a coupled scene's slabs with this scene's merged cut cells own at least 7 rows each, docs/parallel.md)"
        );
        for depth in [HALO, 7, 10] {
            for rows in 1..100 {
                let k = max_ranks(rows, depth);
                let starts = slab_starts(rows, k, depth).unwrap();
                assert!(starts.iter().all(|s| s % 2 == 0), "{rows}: {starts:?}");
            }
        }
    }
}
