//! The scene key `numerics.transport` (docs/model.md 5.7): `"donor"` (default) or
//! `"limited"`, the face value of phihat in the carried transport of coupled runs. Any other
//! value, or `"limited"` in a scene that does not run the coupled model, exits 2 with one
//! line naming the file, the key and what is allowed. The limited transport reaches the
//! solver (another state hash than the donor rule on the same coupled drum), keeps the bounds
//! exactly and the mass to round-off, and reruns bit for bit.

use crate::common::run_in;
use std::path::Path;

fn refused(args: &[&str], allowed: &str) {
    let d = tempfile::tempdir().unwrap();
    let (code, err) = run_in(d.path(), args);
    assert_eq!(code, 2, "{args:?}: {err}");
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 1, "{args:?}: one line expected:\n{err}");
    assert!(lines[0].starts_with("error: scenes/"), "{}", lines[0]);
    assert!(lines[0].contains("numerics.transport"), "{}", lines[0]);
    assert!(lines[0].contains(allowed), "{}", lines[0]);
    assert!(
        !d.path().join("runs").exists(),
        "a refused run wrote output"
    );
}

#[test]
fn bad_transport_values_exit_2_with_one_line() {
    refused(
        &[
            "run",
            "tumbler",
            "--quiet",
            "--t-end",
            "0.01",
            "--set",
            "numerics.transport=\"muscl\"",
        ],
        "`donor` or `limited`",
    );
    refused(
        &["run", "tumbler", "--quiet", "--set", "numerics.transport=2"],
        "`donor` or `limited`",
    );
    // a prescribed scene has no carried transport
    refused(
        &[
            "run",
            "column-a",
            "--quiet",
            "--set",
            "numerics.transport=\"limited\"",
        ],
        "model.equations = \"coupled\"",
    );
}

fn drum(dir: &Path, out: &str, transport: &str) -> serde_json::Value {
    let (code, err) = run_in(
        dir,
        &[
            "run",
            "tumbler",
            "--quiet",
            "--cells",
            "18",
            "--t-end",
            "0.3",
            "--set",
            "frame.rev_per_s=1.5",
            "--set",
            &format!("numerics.transport=\"{transport}\""),
            "--out",
            out,
        ],
    );
    assert_eq!(code, 0, "{err}");
    serde_json::from_str(&std::fs::read_to_string(dir.join(out).join("summary.json")).unwrap())
        .unwrap()
}

#[test]
fn limited_transport_reaches_the_coupled_drum_and_keeps_bounds_and_bits() {
    let d = tempfile::tempdir().unwrap();
    let donor = drum(d.path(), "donor", "donor");
    let limited = drum(d.path(), "limited", "limited");
    let again = drum(d.path(), "again", "limited");
    for s in [&donor, &limited] {
        assert!(s["mass_rel_drift"].as_f64().unwrap().abs() < 1e-12);
        assert_eq!(s["overshoot_max"].as_f64().unwrap(), 0.0);
        assert_eq!(s["undershoot_max"].as_f64().unwrap(), 0.0);
    }
    assert_ne!(donor["state_hash"], limited["state_hash"]);
    assert_eq!(limited["state_hash"], again["state_hash"]);
}
