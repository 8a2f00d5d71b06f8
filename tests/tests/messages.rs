//! The core's errors read as sentences (issue 11): each `Display` text is produced here by a
//! real refusal of the public API (not by building the enum by hand), and must say what is
//! wrong in words, not the `Debug` form (`Parameter("gravity")`).

use sieve_core::closure::Material;
use sieve_core::flow::{Flow, FlowConfig, FlowSide};
use sieve_core::sensor::recording::Recording;
use sieve_core::{Boundary, Grid, Segregation, SegregationConfig};

/// No `Debug` residue: no `(`"` pairs, no CamelCase variant names.
fn plain(s: &str) {
    assert!(!s.contains("(\""), "{s}");
    for w in [
        "Parameter",
        "NonFinite",
        "TooManyCells",
        "EmptyAxis",
        "Field {",
    ] {
        assert!(!s.contains(w), "{s}");
    }
}

#[test]
fn grid_errors_name_the_axis_and_the_capacity() {
    let e = Grid::<f64, 2>::new([4, 0], [0.0; 2], [1.0; 2], 64).unwrap_err();
    assert_eq!(e.to_string(), "axis 1 has no cells (need at least 1)");
    let e = Grid::<f64, 1>::new([100], [0.0], [1.0], 64).unwrap_err();
    assert_eq!(
        e.to_string(),
        "100 cells exceed the compiled capacity of 64 cells"
    );
    let e = Grid::<f64, 1>::new([10], [0.0], [-1.0], 64).unwrap_err();
    plain(&e.to_string());
    assert!(e.to_string().contains("upper must be > lower"), "{e}");
}

#[test]
fn segregation_setup_errors_say_what_is_wrong() {
    const N: usize = 16;
    let grid = Grid::<f64, 1>::new([N], [0.0], [1.0], N).unwrap();
    let mut s: Box<Segregation<f64, 1, N>> = Box::new(Segregation::zeroed());
    let mut cfg = SegregationConfig::<f64, 1>::new();
    cfg.gravity = [f64::NAN];
    let e = s.setup(grid, [[Boundary::Wall; 2]], cfg).unwrap_err();
    assert_eq!(e.to_string(), "gravity must be finite");

    let mut cfg = SegregationConfig::<f64, 1>::new();
    cfg.courant = 1.5;
    let e = s.setup(grid, [[Boundary::Wall; 2]], cfg).unwrap_err();
    assert_eq!(e.to_string(), "the Courant number must be in (0, 1)");

    let e = s
        .setup(grid, [[Boundary::Periodic, Boundary::Wall]], cfg_ok())
        .unwrap_err();
    assert_eq!(
        e.to_string(),
        "axis 0 is periodic on one side only (periodic boundaries come in pairs)"
    );

    s.setup(grid, [[Boundary::Wall; 2]], cfg_ok()).unwrap();
    for i in 0..N {
        s.set_cell(i, 0.6, 1.0, [0.0], 0.3);
    }
    s.set_cell(5, 0.6, 1.0, [0.0], 0.7);
    let e = s.prepare().unwrap_err();
    plain(&e.to_string());
    assert!(e.to_string().contains("outside [0, c] in cell 5"), "{e}");
}

fn cfg_ok() -> SegregationConfig<f64, 1> {
    let mut c = SegregationConfig::new();
    c.gravity = [-1.0];
    c
}

#[test]
fn flow_errors_say_what_is_wrong() {
    const N: usize = 8;
    let grid = Grid::<f64, 1>::new([N], [0.0], [0.1], N).unwrap();
    let mut flow: Box<Flow<f64, 1, N>> = Box::new(Flow::zeroed());
    let mut cfg = FlowConfig::new(Material::glass_beads());
    cfg.material.eps0 = -1.0;
    let wall = FlowSide::wall(sieve_core::flow::Slip::NoSlip);
    let e = flow.setup(grid, [[wall, wall]], cfg).unwrap_err();
    assert_eq!(
        e.to_string(),
        "the dissipation rate eps0 must be finite and > 0"
    );
    let mut cfg = FlowConfig::new(Material::glass_beads());
    cfg.courant = 0.9;
    let e = flow.setup(grid, [[wall, wall]], cfg).unwrap_err();
    assert_eq!(
        e.to_string(),
        "the flow's Courant number must be in (0, 1/2]"
    );

    flow.setup(
        grid,
        [[wall, wall]],
        FlowConfig::new(Material::glass_beads()),
    )
    .unwrap();
    for i in 0..N {
        flow.set_cell(i, 0.3, [0.0], 0.0);
    }
    flow.set_cell(3, 0.3, [0.0], -1.0);
    let e = flow.prepare().unwrap_err();
    assert_eq!(
        e.to_string(),
        "the granular temperature T in cell 3 is NaN, infinite or negative"
    );
}

#[test]
fn recording_errors_say_what_is_wrong() {
    let e = Recording::parse(b"definitely not a recording, just text").unwrap_err();
    plain(&e.to_string());
    assert!(e.to_string().contains("recording"), "{e}");
}
