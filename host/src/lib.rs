//! sieve: the desktop command-line front end of `sieve-core`.
