//! Inflow/outflow and 3D smoke tests of the flow (model.md 2 boundary conditions; the same
//! code for D = 1, 2, 3).

use sieve_core::closure::Material;
use sieve_core::flow::{Flow, FlowConfig, FlowSide, Slip};
use sieve_core::Grid;
use sieve_tests::run_big;

/// A 1D channel without gravity, empty at t = 0, fed at x = 0 with the dilute state
/// (c, u, T) = (0.3, 0.1 m/s, 0), free outflow at x = 0.1 m: after 3 flow-through times it
/// carries exactly the inflow state, and the mass balance closes.
#[test]
fn channel_fills_with_the_inflow_state() {
    run_big(|| {
        const N: usize = 50;
        let grid = Grid::new([N], [0.0], [0.1], N).unwrap();
        let mut cfg = FlowConfig::new(Material::glass_beads());
        cfg.gravity = [0.0];
        let mut flow: Box<Flow<f64, 1, N>> = Box::new(Flow::zeroed());
        let inflow = FlowSide::inflow(0.3, [0.1], 0.0);
        flow.setup(grid, [[inflow, FlowSide::outflow()]], cfg)
            .unwrap();
        flow.prepare().unwrap();
        let h = 0.1 / N as f64;
        let mut fed = 0.0;
        let mut left = 0.0;
        while flow.time() < 3.0 {
            let dt = flow.stable_dt().min(2e-3);
            // what leaves through the outflow face in this step (upwind, interior state)
            left += dt * flow.c(N - 1) * flow.velocity(N - 1)[0].max(0.0);
            flow.step(dt);
            fed += dt * 0.3 * 0.1;
        }
        let mass: f64 = (0..N).map(|i| flow.c(i) * h).sum();
        let balance = (mass - (fed - left)).abs() / fed;
        let worst_c = (0..N).map(|i| (flow.c(i) - 0.3).abs()).fold(0.0, f64::max);
        let worst_u = (0..N)
            .map(|i| (flow.velocity(i)[0] - 0.1).abs())
            .fold(0.0, f64::max);
        println!("balance {balance:.1e}, |c - 0.3| {worst_c:.1e}, |u - 0.1| {worst_u:.1e}");
        assert!(balance < 1e-12, "{balance}");
        assert!(worst_c < 1e-6 && worst_u < 1e-6, "{worst_c} {worst_u}");
    });
}

/// The dilute column of `flow_settling` in 3D (4 x 4 x 16 cells, friction walls): no NaN,
/// mass to round-off, x-y symmetric, settles.
#[test]
fn column_settles_in_3d() {
    run_big(|| {
        const N: usize = 4 * 4 * 16;
        let l = 0.01;
        let grid = Grid::new([4, 4, 16], [0.0; 3], [l, l, 0.04], N).unwrap();
        let mut cfg = FlowConfig::new(Material::glass_beads());
        cfg.t_min = 1e-10;
        let wall = FlowSide::wall(Slip::Friction(0.2));
        let mut flow: Box<Flow<f64, 3, N>> = Box::new(Flow::zeroed());
        flow.setup(grid, [[wall, wall]; 3], cfg).unwrap();
        for i in 0..N {
            flow.set_cell(i, 0.3, [0.0; 3], 0.0);
        }
        flow.prepare().unwrap();
        let m0 = flow.diagnostics().mass;
        let mut peak: f64 = 0.0;
        while flow.time() < 0.4 {
            flow.step(flow.stable_dt());
            peak = peak.max(flow.diagnostics().max_speed);
        }
        let d = flow.diagnostics();
        let finite = (0..N).all(|i| {
            let u = flow.velocity(i);
            [
                flow.c(i),
                flow.temperature(i),
                flow.pressure(i),
                u[0],
                u[1],
                u[2],
            ]
            .iter()
            .all(|x| x.is_finite())
        });
        // the four columns at the corners of the 4 x 4 cross-section carry the same state
        let corner = |ix: usize, iy: usize, iz: usize| flow.c(grid.index([ix, iy, iz]));
        let asym = (0..16)
            .map(|iz| (corner(0, 0, iz) - corner(3, 3, iz)).abs())
            .fold(0.0, f64::max);
        println!(
            "3D: mass {:.1e}, max c/c_rcp {:.4}, |u| peak {peak:.2e} -> {:.2e}, asymmetry {asym:.1e}",
            (d.mass - m0) / m0,
            d.max_packing,
            d.max_speed
        );
        assert!(finite);
        assert!(((d.mass - m0) / m0).abs() < 1e-13);
        assert!(d.max_packing < 0.999 + 1e-12);
        assert!(
            peak > 0.2 && d.max_speed < 1e-2 * peak,
            "{peak} {}",
            d.max_speed
        );
        assert!(asym < 1e-10, "{asym}");
    });
}
