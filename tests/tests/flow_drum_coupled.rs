//! The coupled flow and segregation in a drum with cut-cell walls (issue 8): a half-filled
//! drum of glass beads (model.md 7.4, S0 = 1, wall friction 11 deg, back-coupling R = 1/2),
//! mixed start, turning at 1 rev/s in its own frame (model.md 7.5). The small grains ride on
//! the flow's aperture-weighted face mass fluxes group by group
//! (`Segregation::carry_mass_fluxes_embedded`): both phases to round-off, 0 <= phi <= c
//! exactly in every cell after every step (cut cells and merged cells included), the
//! segregation's c equal to the flow's, bit-identical reruns.

use crate::drum_common::{half_drum, HalfDrum};
use sieve_core::closure::{Material, Packing};
use sieve_core::diagnostics::diagnose_embedded;
use sieve_core::flow::coupled::{Coupled, CouplingConfig, Mode};
use sieve_core::flow::FlowConfig;
use sieve_tests::run_big;

const N: usize = 1024;

struct Outcome {
    small_drift: f64,
    total_drift: f64,
    worst_over: f64,
    worst_under: f64,
    c_mismatch: f64,
    max_speed: f64,
    hash: u64,
}

fn drum(steps: usize) -> Outcome {
    let mut cfg = FlowConfig::new(Material::glass_beads());
    cfg.free_surface_push = true;
    let HalfDrum {
        grid,
        mut flow,
        mut seg,
        cut,
    } = half_drum::<N>(cfg);
    for i in 0..grid.len() {
        let z = grid.center(i)[1];
        let c = if z < 0.05 && !cut.is_solid(i) {
            0.6
        } else {
            0.0
        };
        flow.set_cell(i, c, [0.0; 2], 0.0);
        seg.set_cell(i, c, 0.0, [0.0; 2], 0.5 * c);
    }
    let mut cc = CouplingConfig::new(Mode::Coupled);
    cc.packing = Packing::FitHalf;
    let mut cpl = Coupled::new_embedded(&mut flow, &mut seg, cc, &cut).unwrap();
    let d0 = diagnose_embedded(cpl.seg, &cut);
    let total0: f64 = (0..grid.len()).map(|i| cpl.seg.c(i) * cut.volume(i)).sum();
    let mut o = Outcome {
        small_drift: 0.0,
        total_drift: 0.0,
        worst_over: 0.0,
        worst_under: 0.0,
        c_mismatch: 0.0,
        max_speed: 0.0,
        hash: 0,
    };
    for _ in 0..steps {
        cpl.step().unwrap();
        for i in 0..grid.len() {
            let (phi, c) = (cpl.seg.phi(i), cpl.seg.c(i));
            assert!(phi.is_finite() && c.is_finite());
            o.worst_over = o.worst_over.max(phi - c);
            o.worst_under = o.worst_under.max(-phi);
            o.c_mismatch = o.c_mismatch.max((c - cpl.flow.c(i)).abs());
        }
        o.max_speed = o.max_speed.max(cpl.flow.diagnostics().max_speed);
    }
    let d = diagnose_embedded(cpl.seg, &cut);
    o.small_drift = (d.mass_small - d0.mass_small).abs() / d0.mass_small;
    let total: f64 = (0..grid.len()).map(|i| cpl.seg.c(i) * cut.volume(i)).sum();
    o.total_drift = (total - total0).abs() / total0;
    o.hash = sieve_core::state_hash(cpl.seg);
    o
}

#[test]
fn coupled_half_drum_on_cut_cells_keeps_both_phases_and_the_bounds() {
    run_big(|| {
        let o = drum(400);
        println!(
            "coupled half drum, 24 x 24, 1 rev/s, 400 steps: small-grain drift {:.1e}, grains {:.1e}, max(phi - c) {:.1e}, max(-phi) {:.1e}, |c_seg - c_flow| {:.1e}, max speed {:.2e} m/s",
            o.small_drift, o.total_drift, o.worst_over, o.worst_under, o.c_mismatch, o.max_speed
        );
        assert!(o.small_drift < 1e-12, "{}", o.small_drift);
        assert!(o.total_drift < 1e-12, "{}", o.total_drift);
        assert!(o.worst_over <= 0.0 && o.worst_under <= 0.0);
        assert!(o.c_mismatch < 1e-12, "{}", o.c_mismatch);
        assert!(o.max_speed > 0.0);
        let again = drum(400);
        assert_eq!(o.hash, again.hash);
    });
}
