//! firmware-sim: the sieve soft sensor as Cortex-M4F firmware (QEMU mps2-an386, semihosting
//! output, `-icount shift=0` so that time counts instructions) and, built for the host, the
//! same loop as a debugging program.
//!
//! Output (greppable): `est ...` estimate lines with the wire frame in hex, per-pass work and
//! fault counters, `final_state_hash=0x...` (clean pass), `faulted_state_hash=0x...`
//! (`Faults::DEMO`), then the budget probes and (firmware) `ram_*` and `stack_used`.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

mod app;

#[cfg(not(target_os = "none"))]
fn main() {
    struct Host;
    impl app::Platform for Host {
        fn line(&mut self, args: core::fmt::Arguments<'_>) {
            println!("{args}");
        }
        fn instructions(&mut self) -> u64 {
            0
        }
    }
    let mut state = Box::new(app::State::new());
    let ok = app::run(&mut Host, &mut state);
    std::process::exit(if ok { 0 } else { 1 });
}

#[cfg(target_os = "none")]
mod target;
