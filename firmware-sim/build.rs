//! Embeds the recording (default `recordings/shear-cell.rec`, override with the environment
//! variable `SIEVE_RECORDING=/path/to/file`) and, for the embedded target, puts `memory.x` on
//! the linker search path.

use std::path::PathBuf;

fn main() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets it"));
    println!("cargo:rerun-if-env-changed=SIEVE_RECORDING");
    let rec = match std::env::var("SIEVE_RECORDING") {
        Ok(p) if !p.is_empty() => PathBuf::from(p),
        _ => manifest.join("recordings").join("shear-cell.rec"),
    };
    let rec = rec.canonicalize().unwrap_or_else(|e| {
        panic!("recording {}: {e}", rec.display());
    });
    println!("cargo:rerun-if-changed={}", rec.display());
    println!("cargo:rustc-env=SIEVE_RECORDING_PATH={}", rec.display());

    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        let out = PathBuf::from(std::env::var("OUT_DIR").expect("cargo sets it"));
        std::fs::copy(manifest.join("memory.x"), out.join("memory.x")).expect("copy memory.x");
        println!("cargo:rustc-link-search={}", out.display());
        println!("cargo:rerun-if-changed=memory.x");
    }
}
