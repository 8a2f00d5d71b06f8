//! Flow coupled to segregation (model.md 2-4): the frozen-flow shear cell with an inversely
//! graded bed, and a fully coupled settling column with back-coupled packing limits.

use sieve_core::closure::{Material, Packing};
use sieve_core::flow::coupled::{Coupled, CouplingConfig, Mode};
use sieve_core::flow::{Flow, FlowConfig, FlowSide, Slip};
use sieve_core::segregation::{DirectionMode, Segregation, SegregationConfig};
use sieve_core::{diagnose, Boundary, Grid};
use sieve_tests::run_big;

const NS: usize = 4 * 20;

#[test]
fn frozen_shear_cell_resegregates_only_where_it_shears() {
    run_big(|| {
        let (nx, nz) = (4, 20);
        let l = 0.025;
        let grid = Grid::new([nx, nz], [0.0; 2], [l, l], NS).unwrap();
        let mat = Material::glass_beads();
        let mut flow: Box<Flow<f64, 2, NS>> = Box::new(Flow::zeroed());
        let px = FlowSide::periodic();
        let bottom = FlowSide::moving_wall([0.0007, 0.0]);
        let top = FlowSide::moving_wall([0.0055, 0.0]);
        flow.setup(grid, [[px, px], [bottom, top]], FlowConfig::new(mat))
            .unwrap();
        let mut seg: Box<Segregation<f64, 2, NS>> = Box::new(Segregation::zeroed());
        let mut scfg = SegregationConfig::new();
        scfg.s0 = 1.0;
        scfg.gravity = [0.0, -9.81];
        scfg.direction = DirectionMode::Flow;
        let bc = [[Boundary::Periodic; 2], [Boundary::Wall; 2]];
        seg.setup(grid, bc, scfg).unwrap();
        for i in 0..grid.len() {
            let iz = grid.coords(i)[1];
            flow.set_cell(i, 0.6, [0.0; 2], 0.0);
            // inversely graded: small grains on top
            let phi = if iz >= nz / 2 { 0.6 } else { 0.0 };
            seg.set_cell(i, 0.6, 0.0, [0.0; 2], phi);
        }
        let mut cc = CouplingConfig::new(Mode::Frozen);
        cc.steady_tolerance = 2e-2;
        let mut cpl = Coupled::new(&mut flow, &mut seg, cc).unwrap();
        let steps = cpl.freeze().unwrap();
        let small0 = diagnose(cpl.seg).mass_small;
        cpl.advance_to(20.0, 1_000_000).unwrap();
        let d = diagnose(cpl.seg);
        println!(
            "flow steps to steady {steps}, seg steps {}, small mass error {:.1e}, over/under {:.1e} {:.1e}",
            cpl.seg.steps(),
            (d.mass_small - small0) / small0,
            d.overshoot,
            d.undershoot
        );
        assert!(steps > 50 && steps < 20_000, "{steps}");
        assert!(((d.mass_small - small0) / small0).abs() < 1e-13);
        assert!(d.overshoot <= 1e-15 && d.undershoot <= 1e-15);
        // the top (sheared) rows lost small grains to the rows below; the plug rows near the
        // bottom plate (T ~ 0) kept exactly none
        let row = |k: usize| (0..nx).map(|j| cpl.seg.phi(j + nx * k)).sum::<f64>() / nx as f64;
        println!(
            "phi top {:.4}, phi at mid {:.4}, bottom {:.3e}",
            row(nz - 1),
            row(nz / 2 - 1),
            row(0)
        );
        assert!(row(nz - 1) < 0.5, "{}", row(nz - 1));
        assert!(row(nz / 2 - 1) > 0.05, "{}", row(nz / 2 - 1));
        assert!(row(0) < 1e-6, "{}", row(0));
    });
}

const NC: usize = 32;

#[test]
fn coupled_settling_column_with_back_coupling() {
    run_big(|| {
        let nz = 30;
        let grid = Grid::new([nz], [0.0], [0.06], NC).unwrap();
        let mat = Material::glass_beads();
        let mut flow: Box<Flow<f64, 1, NC>> = Box::new(Flow::zeroed());
        let wall = FlowSide::wall(Slip::NoSlip);
        let mut fcfg = FlowConfig::new(mat);
        fcfg.t_min = 1e-10;
        flow.setup(grid, [[wall, wall]], fcfg).unwrap();
        let mut seg: Box<Segregation<f64, 1, NC>> = Box::new(Segregation::zeroed());
        let mut scfg = SegregationConfig::new();
        scfg.gravity = [-9.81];
        seg.setup(grid, [[Boundary::Wall; 2]], scfg).unwrap();
        for i in 0..nz {
            flow.set_cell(i, 0.3, [0.0], 0.0);
            seg.set_cell(i, 0.3, 0.0, [0.0], 0.15);
        }
        let mut cc = CouplingConfig::new(Mode::Coupled);
        cc.packing = Packing::FitHalf;
        let mut cpl = Coupled::new(&mut flow, &mut seg, cc).unwrap();
        let d0 = diagnose(cpl.seg);
        let m0 = cpl.flow.diagnostics().mass;
        let mut worst_pack: f64 = 0.0;
        let mut k = 0;
        while cpl.seg.time() < 0.5 {
            cpl.step().unwrap();
            k += 1;
            let fd = cpl.flow.diagnostics();
            worst_pack = worst_pack.max(fd.max_packing);
            assert!((0..nz).all(|i| cpl.flow.c(i).is_finite() && cpl.seg.phi(i).is_finite()));
        }
        let d = diagnose(cpl.seg);
        let fd = cpl.flow.diagnostics();
        println!(
            "steps {k}: total mass {:.1e}, small mass {:.1e} (guarded {:.1e}), over/under {:.1e} {:.1e}, c mismatch {:.1e}, max c/c_rcp(phihat) {worst_pack:.4}, |u| {:.1e}",
            (fd.mass - m0) / m0,
            (d.mass_small - d0.mass_small) / d0.mass_small,
            cpl.guarded_mass(),
            d.overshoot,
            d.undershoot,
            cpl.c_mismatch(),
            fd.max_speed
        );
        assert!(((fd.mass - m0) / m0).abs() < 1e-13);
        // phi rides on the flow's own limited mass fluxes: small mass to round-off, bounds
        // exact (no clipping, no guard needed)
        assert_eq!(cpl.guarded_mass(), 0.0);
        assert!(((d.mass_small - d0.mass_small) / d0.mass_small).abs() < 1e-13);
        assert!(d.overshoot <= 0.0 && d.undershoot <= 0.0, "{d:?}");
        assert!(cpl.c_mismatch() < 1e-14, "{}", cpl.c_mismatch());
        assert!(worst_pack < 1.0);
        // the packing limits follow phihat (R = 1/2 fit, peak 0.665 near phihat = 0.4):
        // c_rcp > phi_rcp in mixed cells
        let rcp = (0..nz).map(|i| cpl.flow.packing(i).0).fold(0.0, f64::max);
        assert!(rcp > mat.phi_rcp + 0.02, "{rcp}");
    });
}
