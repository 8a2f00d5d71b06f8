//! Coulomb friction on a cut wall (model.md 2, `Flow::wall_law`): a dense block sliding on
//! a floor is braked by the stress `p tan(phi_w)`, on a cut floor as on a box floor, however
//! stiff its yield viscosity.
//!
//! The block: glass beads of model.md 7.4 (c = 0.6, cold), 16 mm deep, periodic along x
//! (4 x 24 cells of 1 mm), settled under gravity for 0.2 s and then given u0 = 0.1 m/s along
//! the floor. The yield viscosity of the cold bed glues it into a rigid block, so it slows at
//! `p_w tan(phi_w) / M` (`p_w` the pressure of the floor cell, `M` the block's content per
//! unit floor area) until it stops. Note `p_w` is not the weight `c g H` (0.094 m^2/s^2): the
//! model's yield pressure `p_y = T0 (c - c_rlp) g(c)` of a bed at c = 0.6 is ~0.86 at any
//! depth, so this thin block stops in ~6 ms. The cut floor is the plane `z = 2.4 h` (rows 0
//! and 1 solid, row 2 cut to 0.6 of its height); the box floor is the same bed on the box's
//! bottom face (`Face::Stress`).
//!
//! Why this test: until stop 17 the cut wall's friction was a Dirichlet value only
//! `p tan(phi_w) d / eta` away from the cell's velocity. The implicit solve pins a stiff
//! bed to it, so the wall passed next to none of the friction force: this block kept its
//! speed on the cut floor (deceleration 0.00 m/s^2 against the Coulomb 18.1), and the
//! lab-frame drum's wall slid under a resting bed (angle of repose 0 instead of the rotating
//! frame's 21.5 deg). Measured with `Flow::wall_law`: 18.65 m/s^2 on the cut floor against
//! the Coulomb 18.11 (the floor cell's pressure is lagged a step), 17.71 = 17.71 on the box
//! floor; mass to 1e-15.

use sieve_core::closure::Material;
use sieve_core::flow::{CutWall, Flow, FlowConfig, FlowSide, Slip};
use sieve_core::geometry::{CutCells, Primitive, Region, DEFAULT_SMALL};
use sieve_core::Grid;

const NX: usize = 4;
const NZ: usize = 24;
const N: usize = NX * NZ;
const H: f64 = 1e-3;
const C0: f64 = 0.6;
const U0: f64 = 0.1;
const DEPTH: f64 = 16.0 * H;

type F = Flow<f64, 2, N>;

/// Slides the block for `t` on the cut floor at `z = 2.4 h` (`cut`) or on the box floor at
/// `z = 0`. Returns the block's mean velocity along x (content-weighted), the Coulomb
/// deceleration `p_w tan(phi_w) / M` at the push, and the mass drift.
fn slide(cut: bool, tan: f64, t: f64) -> (f64, f64, f64) {
    let grid = Grid::new([NX, NZ], [0.0; 2], [NX as f64 * H, NZ as f64 * H], N).unwrap();
    let floor = if cut { 2.4 * H } else { 0.0 };
    let mut cfg = FlowConfig::new(Material::glass_beads());
    cfg.t_min = 1e-14;
    let mut flow: Box<F> = Box::new(Flow::zeroed());
    let wall = FlowSide::wall(Slip::Friction(tan));
    flow.setup(grid, [[FlowSide::periodic(); 2], [wall; 2]], cfg)
        .unwrap();
    if cut {
        let mut cc: Box<CutCells<f64, 2, N>> = Box::new(CutCells::zeroed());
        let region = Region::new().intersect(Primitive::HalfSpace {
            point: [0.0, floor],
            normal: [0.0, -1.0],
        });
        cc.build(&grid, &region, [true, false], DEFAULT_SMALL)
            .unwrap();
        flow.set_geometry(&cc, CutWall::resting(Slip::Friction(tan)))
            .unwrap();
    }
    let top = floor + DEPTH;
    for i in 0..grid.len() {
        let z = grid.center(i)[1];
        let c = if z < top && flow.open_volume(i) > 0.0 {
            C0
        } else {
            0.0
        };
        flow.set_cell(i, c, [0.0; 2], 0.0);
    }
    flow.prepare().unwrap();
    let step_to = |flow: &mut F, t_end: f64| {
        while flow.time() < t_end {
            let dt = flow.stable_dt().min(t_end - flow.time());
            flow.step(dt);
        }
    };
    // settle into the lithostatic state, then push the block
    step_to(&mut flow, 0.2);
    for i in 0..grid.len() {
        let (c, temp) = (flow.c(i), flow.temperature(i));
        let u = if c > 0.0 { [U0, 0.0] } else { [0.0; 2] };
        flow.set_cell(i, c, u, temp);
    }
    flow.prepare().unwrap();
    // the Coulomb rate: the floor cell's pressure over the column's content per floor area
    let lowest = (0..NZ).map(|k| k * NX).find(|&i| flow.c(i) > 0.0).unwrap();
    let column: f64 = (0..NZ)
        .map(|k| flow.open_volume(k * NX) * flow.c(k * NX) * H)
        .sum();
    let rate = flow.pressure(lowest) * tan / column;
    let m0 = flow.diagnostics().mass;
    let t0 = flow.time();
    step_to(&mut flow, t0 + t);
    let (mut mu, mut m) = (0.0, 0.0);
    for i in 0..grid.len() {
        let w = flow.open_volume(i) * flow.c(i);
        mu += w * flow.velocity(i)[0];
        m += w;
    }
    (mu / m, rate, (flow.diagnostics().mass - m0).abs() / m0)
}

#[test]
fn a_block_slides_at_the_coulomb_rate_on_a_cut_floor() {
    let tan = 11f64.to_radians().tan();
    let t = 0.002;
    let (u_cut, rate_cut, m_cut) = slide(true, tan, t);
    let (u_box, rate_box, m_box) = slide(false, tan, t);
    let (d_cut, d_box) = ((U0 - u_cut) / t, (U0 - u_box) / t);
    println!(
        "after {t} s: deceleration cut floor {d_cut:.2} m/s^2 (Coulomb {rate_cut:.2}), box \
         floor {d_box:.2} ({rate_box:.2}); mass {m_cut:.1e} / {m_box:.1e}"
    );
    assert!(m_cut < 1e-13 && m_box < 1e-13);
    // still sliding, and braked at the Coulomb rate within 5 %, on either floor
    for (d, rate) in [(d_cut, rate_cut), (d_box, rate_box)] {
        assert!(rate * t < 0.5 * U0);
        assert!((d / rate - 1.0).abs() < 0.05, "deceleration {d} vs {rate}");
    }
}
