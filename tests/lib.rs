//! Integration tests of sieve live in `tests/tests/*.rs`; this library holds what several of
//! them share without being part of any test.

/// Runs `f` on a thread with a stack of `mib` MiB and waits for it (propagating a panic): the
/// flow and segregation solvers are large values (fixed-size arrays), built on the stack.
pub fn run_with_stack<F: FnOnce() + Send + 'static>(mib: usize, f: F) {
    std::thread::Builder::new()
        .stack_size(mib << 20)
        .spawn(f)
        .unwrap()
        .join()
        .unwrap();
}

/// [`run_with_stack`] with 64 MiB, enough for the solvers of the flow tests.
pub fn run_big<F: FnOnce() + Send + 'static>(f: F) {
    run_with_stack(64, f);
}

/// A [`sieve_core::fork::Fork`] for tests: `parts` scoped threads per loop (a spawn per item:
/// slow, but real threads), cutting loops of any length down to `min` elements per part, so
/// that small grids are cut in odd places.
#[derive(Clone, Copy, Debug)]
pub struct Threads {
    /// Parts per loop.
    pub parts: usize,
    /// Elements per part below which a loop stays on the caller's thread.
    pub min: usize,
}

impl sieve_core::fork::Fork for Threads {
    fn parts(&self) -> usize {
        self.parts
    }

    fn each<T: Send, F: Fn(&mut T) + Sync>(&self, items: &mut [T], f: F) {
        std::thread::scope(|s| {
            for item in items.iter_mut() {
                let f = &f;
                s.spawn(move || f(item));
            }
        });
    }

    fn min_per_part(&self) -> usize {
        self.min
    }
}
