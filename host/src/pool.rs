//! The thread pool behind the core's fork-join loops ([`sieve_core::fork`]): the coupled
//! flow's linear solves on `--threads` workers with the serial bits (docs/parallel.md, "The
//! coupled flow on threads").
//!
//! A CG iteration forks a few times over the grid; a scoped spawn and join costs ~90 us
//! here, a pool's fork a few us, so the workers live as long as the run (rayon's pool: the
//! established engine, and safe code on our side).

use rayon::prelude::*;
use sieve_core::fork::{self, Fork};

/// `parts` workers for the loops of one run.
pub struct Pool {
    pool: rayon::ThreadPool,
    parts: usize,
    min: usize,
}

impl Pool {
    /// A pool of `threads` workers (1 to [`fork::MAX_PARTS`]: a loop is never cut into more
    /// parts), or `None` if the system refuses the threads.
    pub fn new(threads: usize) -> Option<Self> {
        let threads = threads.clamp(1, fork::MAX_PARTS);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|k| format!("sieve-fork-{k}"))
            .build()
            .ok()?;
        Some(Self {
            pool,
            parts: threads,
            min: fork::MIN_PER_PART,
        })
    }

    /// The pool, cutting loops down to `min` elements a part (tests: small grids cut in
    /// odd places; the bits do not depend on it).
    pub fn cutting_down_to(self, min: usize) -> Self {
        Self { min, ..self }
    }

    /// Runs `f` on one of the pool's workers (the caller waits): a loop forked from there
    /// runs its first part on that worker instead of waking a thread for it.
    pub fn install<T: Send>(&self, f: impl FnOnce() -> T + Send) -> T {
        self.pool.install(f)
    }
}

impl Fork for Pool {
    type Isa = sieve_core::hot::Baseline;

    fn parts(&self) -> usize {
        self.parts
    }

    fn each<T: Send, F: Fn(&mut T) + Sync>(&self, items: &mut [T], f: F) {
        // `install` runs inline when called from one of this pool's workers.
        self.pool
            .install(|| items.par_iter_mut().with_max_len(1).for_each(&f));
    }

    fn min_per_part(&self) -> usize {
        self.min
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The pool runs every item exactly once, from inside and outside the pool, and the
    /// threaded sums it drives have the serial bits.
    #[test]
    fn every_item_once_and_the_serial_sums() {
        let pool = Pool::new(3).expect("threads");
        let mut v: Vec<f64> = (0..100_000usize)
            .map(|i| ((i * 7919) % 1000) as f64 * 1e-3 - 0.4)
            .collect();
        let w: Vec<f64> = (0..100_000usize)
            .map(|i| ((i * 104_729) % 997) as f64 * 1e-2)
            .collect();
        let mut partials = vec![0.0; v.len()];
        let serial = sieve_core::sum::dot(&v, &w);
        assert_eq!(
            fork::dot(&pool, &v, &w, &mut partials).to_bits(),
            serial.to_bits()
        );
        let inside = pool.install(|| fork::dot(&pool, &v, &w, &mut partials));
        assert_eq!(inside.to_bits(), serial.to_bits());
        fork::chunks(&pool, &mut v, 1, |start, c| {
            for (k, x) in c.iter_mut().enumerate() {
                *x = (start + k) as f64;
            }
        });
        assert!(v.iter().enumerate().all(|(i, x)| *x == i as f64));
    }
}
