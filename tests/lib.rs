//! Integration tests of sieve live in `tests/tests/*.rs`; this library is empty.
