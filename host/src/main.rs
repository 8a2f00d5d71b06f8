//! The `sieve` binary.
fn main() {}
