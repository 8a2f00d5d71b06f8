//! What limits a coupled step with the implicit pressure (issue 8, speed; model.md 5.4,
//! docs/implicit-pressure.md "Time step"): dust thrown off a free surface does not, and
//! neither does the segregation's transport term (phi rides on the flow's limited face mass
//! fluxes, `segregation/carried.rs`). The percolation stage takes equal sub-steps within a
//! longer flow step. Asserted on a half-filled drum of glass beads on cut cells turning at
//! 1 rev/s in its own frame (the 24 x 24 drum of `flow_drum_coupled.rs`, implicit pressure),
//! with a grain of dust (c = 1e-9) flying at 5 m/s through the empty half: the flow's step
//! is the same bits with and without the dust; the coupled step is longer than the
//! segregation's full Courant limit (223 of 300 steps) and within 8 percolation limits (50
//! steps take percolation sub-steps); over 300 steps both
//! phases keep their mass to round-off, `0 <= phi <= c` exactly, `c <= c_max`, `T >= 0`,
//! no NaN; a rerun gives the same bits.

use crate::drum_common::{half_drum, HalfDrum};
use sieve_core::closure::{Material, Packing};
use sieve_core::diagnostics::diagnose_embedded;
use sieve_core::flow::coupled::{Coupled, CouplingConfig, Mode, PERCOLATION_SUBSTEPS};
use sieve_core::flow::{Flow, FlowConfig, PressureMode};
use sieve_core::geometry::CutCells;
use sieve_core::segregation::Segregation;
use sieve_tests::run_big;

const N: usize = 1024;

struct Outcome {
    small_drift: f64,
    total_drift: f64,
    worst_over: f64,
    worst_under: f64,
    worst_packing: f64,
    min_t: f64,
    /// steps whose length exceeded the segregation's full Courant limit
    beyond_transport: usize,
    /// steps whose percolation took more than one sub-step
    substepped: usize,
    mean_dt: f64,
    hash: u64,
}

/// The flow, the segregation solver and the drum's cut cells of one run.
type Drum = (
    Box<Flow<f64, 2, N>>,
    Box<Segregation<f64, 2, N>>,
    Box<CutCells<f64, 2, N>>,
);

fn setup(dust: bool) -> Drum {
    let mut cfg = FlowConfig::new(Material::glass_beads());
    cfg.free_surface_push = true;
    cfg.pressure = PressureMode::Implicit;
    let HalfDrum {
        grid,
        mut flow,
        mut seg,
        cut,
    } = half_drum::<N>(cfg);
    // the dust: one open cell high in the empty half
    let speck = grid.index([12, 19]);
    assert!(!cut.is_solid(speck));
    for i in 0..grid.len() {
        let z = grid.center(i)[1];
        let (c, u) = if z < 0.05 && !cut.is_solid(i) {
            (0.6, [0.0; 2])
        } else if dust && i == speck {
            (1e-9, [5.0, 3.0])
        } else {
            (0.0, [0.0; 2])
        };
        flow.set_cell(i, c, u, 1e-4);
        seg.set_cell(i, c, 1e-4, u, 0.5 * c);
    }
    (flow, seg, cut)
}

fn run(steps: usize) -> Outcome {
    let (mut flow, mut seg, cut) = setup(true);
    let mut cc = CouplingConfig::new(Mode::Coupled);
    cc.packing = Packing::FitHalf;
    let mut cpl = Coupled::new_embedded(&mut flow, &mut seg, cc, &cut).unwrap();
    let n = cpl.flow.len();
    let d0 = diagnose_embedded(cpl.seg, &cut);
    let total0: f64 = (0..n).map(|i| cpl.seg.c(i) * cut.volume(i)).sum();
    let mut o = Outcome {
        small_drift: 0.0,
        total_drift: 0.0,
        worst_over: 0.0,
        worst_under: 0.0,
        worst_packing: 0.0,
        min_t: f64::MAX,
        beyond_transport: 0,
        substepped: 0,
        mean_dt: 0.0,
        hash: 0,
    };
    for _ in 0..steps {
        let dt = cpl.stable_dt();
        let full = cpl.seg.stable_dt_embedded(&cut);
        let perc = cpl.seg.stable_dt_percolation_embedded(&cut);
        assert!(dt <= cpl.flow.stable_dt() && dt <= PERCOLATION_SUBSTEPS as f64 * perc);
        o.beyond_transport += usize::from(dt > full);
        o.substepped += usize::from(dt > perc);
        o.mean_dt += dt / steps as f64;
        cpl.step_with(dt).unwrap();
        for i in 0..n {
            let (phi, c) = (cpl.seg.phi(i), cpl.seg.c(i));
            let t = cpl.flow.temperature(i);
            assert!(
                phi.is_finite() && c.is_finite() && t.is_finite(),
                "cell {i}"
            );
            o.worst_over = o.worst_over.max(phi - c);
            o.worst_under = o.worst_under.max(-phi);
            o.worst_packing = o.worst_packing.max(cpl.flow.c(i) / cpl.flow.packing(i).0);
            o.min_t = o.min_t.min(t);
        }
    }
    let d = diagnose_embedded(cpl.seg, &cut);
    o.small_drift = (d.mass_small - d0.mass_small).abs() / d0.mass_small;
    let total: f64 = (0..n).map(|i| cpl.seg.c(i) * cut.volume(i)).sum();
    o.total_drift = (total - total0).abs() / total0;
    o.hash = sieve_core::state_hash(cpl.seg);
    o
}

#[test]
fn dust_does_not_hold_the_flow_step() {
    run_big(|| {
        let (mut a, _, _) = setup(true);
        let (mut b, _, _) = setup(false);
        a.prepare().unwrap();
        b.prepare().unwrap();
        let (with, without) = (a.stable_dt(), b.stable_dt());
        println!("flow step with dust at 5 m/s {with:e} s, without {without:e} s");
        assert_eq!(with.to_bits(), without.to_bits());
        // counted, the dust would hold it below 0.4 h / (|u_x| + |u_z|) = 2.3e-4 s
        assert!(with > 1e-3, "{with}");
    });
}

#[test]
fn coupled_step_outruns_the_transport_limit_and_keeps_the_invariants() {
    run_big(|| {
        let o = run(300);
        println!(
            "implicit drum 24 x 24, 1 rev/s, dust at 5 m/s, 300 steps: mean dt {:.3e} s, {} steps beyond the segregation's transport limit, {} with percolation sub-steps; fines drift {:.1e}, grains {:.1e}, max(phi - c) {:.1e}, max(-phi) {:.1e}, max c/c_rcp {:.4}, min T {:.1e}",
            o.mean_dt, o.beyond_transport, o.substepped, o.small_drift, o.total_drift,
            o.worst_over, o.worst_under, o.worst_packing, o.min_t
        );
        assert!(o.beyond_transport > 0);
        assert!(o.substepped > 0);
        assert!(o.small_drift < 1e-12, "{}", o.small_drift);
        assert!(o.total_drift < 1e-12, "{}", o.total_drift);
        assert!(o.worst_over <= 0.0 && o.worst_under <= 0.0);
        assert!(o.worst_packing < 1.0, "{}", o.worst_packing);
        assert!(o.min_t >= 0.0);
        assert_eq!(o.hash, run(300).hash);
    });
}
