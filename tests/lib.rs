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
