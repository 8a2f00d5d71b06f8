//! A resting bed with a jump in c and a free surface over empty cells (issue 3 hard cases):
//! it adjusts, comes to rest and must not creep afterwards; no NaN anywhere, mass conserved,
//! c < c_rcp. Glass beads of model.md 7.4 in a 0.05 m box, walls with friction 30 deg.

use sieve_core::closure::Material;
use sieve_core::flow::{Flow, FlowConfig, FlowSide, Slip};
use sieve_core::{Grid, Real};
use sieve_tests::run_big;

const N: usize = 400;

struct Record {
    mass_error: f64,
    max_packing: f64,
    nonfinite: bool,
    /// max |u| over the bed in the window [t_quiet, t_end]
    late_speed: f64,
    /// displacement of the centre of mass (z) over the window
    late_drift: f64,
    early_speed: f64,
}

fn pile<R: Real>(t_quiet: f64, t_end: f64) -> Record {
    let mut flow: Box<Flow<R, 2, N>> = Box::new(Flow::zeroed());
    let n = 20;
    let l = R::from_f64(0.05);
    let grid = Grid::new([n, n], [R::ZERO; 2], [l, l], N).unwrap();
    let cfg = FlowConfig::new(Material::glass_beads());
    let wall = FlowSide::wall(Slip::Friction(R::from_f64(30f64.to_radians().tan())));
    flow.setup(grid, [[wall, wall], [wall, wall]], cfg).unwrap();
    for i in 0..grid.len() {
        let [ix, iz] = grid.coords(i);
        // bed in the lower half, denser on the left: a jump in c of 0.015 at mid-width
        let c = if iz >= n / 2 {
            0.0
        } else if ix < n / 2 {
            0.60
        } else {
            0.585
        };
        flow.set_cell(i, R::from_f64(c), [R::ZERO; 2], R::ZERO);
    }
    flow.prepare().unwrap();
    let vol = grid.cell_volume().to_f64();
    let m0 = flow.diagnostics().mass.to_f64();
    let centre = |f: &Flow<R, 2, N>| {
        (0..grid.len())
            .map(|i| f.c(i).to_f64() * vol * grid.center(i)[1].to_f64())
            .sum::<f64>()
            / m0
    };
    let mut rec = Record {
        mass_error: 0.0,
        max_packing: 0.0,
        nonfinite: false,
        late_speed: 0.0,
        late_drift: 0.0,
        early_speed: 0.0,
    };
    let mut z_quiet = None;
    while flow.time().to_f64() < t_end {
        flow.step(flow.stable_dt());
        let d = flow.diagnostics();
        rec.mass_error = rec.mass_error.max((d.mass.to_f64() - m0).abs() / m0);
        rec.max_packing = rec.max_packing.max(d.max_packing.to_f64());
        for i in 0..grid.len() {
            let u = flow.velocity(i);
            let v = [flow.c(i), flow.temperature(i), flow.pressure(i), u[0], u[1]];
            rec.nonfinite |= v.iter().any(|x| !x.is_finite());
        }
        if flow.time().to_f64() < t_quiet {
            rec.early_speed = rec.early_speed.max(d.max_speed.to_f64());
        } else {
            rec.late_speed = rec.late_speed.max(d.max_speed.to_f64());
            let z = centre(&flow);
            let z0 = *z_quiet.get_or_insert(z);
            rec.late_drift = rec.late_drift.max((z - z0).abs());
        }
    }
    println!(
        "{}: mass {:.1e}, max c/c_rcp {:.5}, |u| early {:.2e}, late {:.2e}, drift {:.2e} m, steps {}",
        R::NAME,
        rec.mass_error,
        rec.max_packing,
        rec.early_speed,
        rec.late_speed,
        rec.late_drift,
        flow.steps()
    );
    rec
}

#[test]
fn bed_with_jump_and_free_surface_comes_to_rest_and_does_not_creep() {
    run_big(|| {
        let r = pile::<f64>(0.3, 1.5);
        assert!(!r.nonfinite);
        assert!(r.mass_error < 1e-13, "{}", r.mass_error);
        assert!(r.max_packing < 0.999 + 1e-12);
        // after the adjustment (|u| up to 3e-2 m/s) only the creep of the regularised yield
        // viscosity (T_min = 1e-14) is left: measured 4.1e-6 m/s, centre of mass drift 2.8e-6 m
        // over 1.2 s (1e-4 of the bed height)
        assert!(r.early_speed > 1e-2, "{}", r.early_speed);
        assert!(r.late_speed < 1e-5, "late speed {}", r.late_speed);
        assert!(r.late_drift < 5e-6, "drift {}", r.late_drift);
    });
}

#[test]
fn bed_with_jump_f32_stays_finite() {
    run_big(|| {
        let r = pile::<f32>(0.3, 0.6);
        assert!(!r.nonfinite);
        assert!(r.mass_error < 1e-5, "{}", r.mass_error);
        assert!(r.max_packing < 0.999 + 1e-6);
        assert!(r.late_speed < 1e-3, "late speed {}", r.late_speed);
    });
}
