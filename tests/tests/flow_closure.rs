//! Closures of model.md 2 and packing limits of model.md 4 against hand-computed values
//! (glass beads of model.md 7.4 at c = 0.6, T = 1e-6; numbers from the formulas by hand).

use sieve_core::closure::{
    compressibility, kinetic_pressure, packing_bound_r0, packing_fit_half, pressure,
    sound_speed_squared, transport, yield_pressure, Material, Packing,
};

fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * b.abs().max(1e-300)
}

const C: f64 = 0.6;
const T: f64 = 1e-6;

#[test]
fn pressures_and_compressibility() {
    let m = Material::<f64>::glass_beads();
    // g = 1 / (1 - 0.6/0.632) = 0.632/0.032 = 19.75
    assert!(close(compressibility(C, m.phi_rcp), 19.75, 1e-13));
    // p_k = c T g = 0.6 * 1e-6 * 19.75
    assert!(close(kinetic_pressure(C, T, m.phi_rcp), 1.185e-5, 1e-13));
    // p_y = T0 (c - c_rlp) g = 1.8 * 0.0243 * 19.75
    assert!(close(
        yield_pressure(C, m.phi_rcp, m.phi_rlp, m.t0),
        0.863865,
        1e-12
    ));
    assert!(close(
        pressure(&m, C, T, m.phi_rcp, m.phi_rlp),
        0.863865 + 1.185e-5,
        1e-12
    ));
    // no yield pressure at or below c_rlp
    assert_eq!(yield_pressure(0.5, m.phi_rcp, m.phi_rlp, m.t0), 0.0);
    assert_eq!(yield_pressure(m.phi_rlp, m.phi_rcp, m.phi_rlp, m.t0), 0.0);
}

#[test]
fn transport_coefficients_match_the_model_formulas() {
    let m = Material::<f64>::glass_beads();
    let tr = transport(&m, C, T, m.phi_rcp, m.phi_rlp, 1e-14);
    // eta = eta0 sqrt(T) c g (1 + p_y/p_k), likewise lambda, eps = eps0 sqrt(T) g (1 + p_y/p_k)
    assert!(close(tr.eta, 0.1123039905, 1e-9), "{}", tr.eta);
    assert!(close(tr.lambda, 0.293718129, 1e-9), "{}", tr.lambda);
    assert!(close(tr.eps, 2126792.814962498, 1e-9), "{}", tr.eps);
    // eta / eps = c eta0 / eps0 exactly (the identity the implicit T stage relies on)
    assert!(close(tr.eta / tr.eps, C * m.eta0 / m.eps0, 1e-13));
}

#[test]
fn temperature_floor_regularises_only_below_t_min() {
    let m = Material::<f64>::glass_beads();
    let t_min = 1e-10;
    let at_zero = transport(&m, C, 0.0, m.phi_rcp, m.phi_rlp, t_min);
    let at_floor = transport(&m, C, t_min, m.phi_rcp, m.phi_rlp, t_min);
    assert_eq!(at_zero, at_floor);
    assert!(at_zero.eta.is_finite() && at_zero.eta > 0.0);
    // yield viscosity eta0 p_y / sqrt(T_min) dominates: 1.3e-4 * 0.863865 / 1e-5
    assert!(close(
        at_zero.eta,
        1.3e-4 * 0.863865 / 1e-5 + 1.3e-4 * 0.6 * 19.75 * 1e-5,
        1e-12
    ));
    // empty, cold cell: finite and zero-ish, no 0/0
    let empty = transport(&m, 0.0, 0.0, m.phi_rcp, m.phi_rlp, t_min);
    assert_eq!(empty.eta, 0.0);
    assert!(empty.eps.is_finite());
    // f32 gives the same to its precision
    let m32 = Material::<f32>::glass_beads();
    let t32 = transport(&m32, 0.6, 1e-6, m32.phi_rcp, m32.phi_rlp, 1e-14);
    assert!(close(f64::from(t32.eta), 0.1123039905, 2e-5));
}

#[test]
fn sound_speed_is_dp_dc() {
    let m = Material::<f64>::glass_beads();
    let a2 = sound_speed_squared(&m, C, T, m.phi_rcp, m.phi_rlp);
    assert!(close(a2, 62.5461713125, 1e-10), "{a2}");
    let dp = (pressure(&m, C + 1e-7, T, m.phi_rcp, m.phi_rlp)
        - pressure(&m, C - 1e-7, T, m.phi_rcp, m.phi_rlp))
        / 2e-7;
    assert!(close(a2, dp, 1e-7));
}

#[test]
fn steady_shear_relations() {
    let m = Material::<f64>::glass_beads();
    // mu = sqrt(eps0 eta0 / a), sqrt(T)/gammadot = sqrt(a eta0 / eps0)
    assert!(close(m.friction_coefficient(), 0.3577983603465319, 1e-12));
    assert!(close(
        m.temperature_shear_ratio(),
        3.6333313510462565e-4,
        1e-12
    ));
}

#[test]
fn packing_limits() {
    let (rcp, rlp) = (0.632, 0.5757);
    // end points are the mono-disperse packings
    for f in [packing_bound_r0::<f64>, packing_fit_half::<f64>] {
        assert!(close(f(0.0, rcp), rcp, 1e-15));
        assert!(close(f(1.0, rcp), rcp, 1e-12));
    }
    // R -> 0 bound at phihat = 0.3: min(0.632/0.7, 0.632/(0.3 + 0.7*0.632)) = 0.632/0.7424
    assert!(close(packing_bound_r0(0.3, rcp), 0.8512931034482759, 1e-13));
    assert!(close(packing_bound_r0(0.3, rlp), 0.8189305680023897, 1e-13));
    // R = 1/2 fit at 0.3: p(0.3) - z = 0.033163851
    assert!(close(packing_fit_half(0.3, rcp), 0.665163851, 1e-12));
    assert!(close(packing_fit_half(0.3, rlp), 0.608863851, 1e-12));
    // the bound peaks at phihat = (1 - phi)/(2 - phi) with value phi (2 - phi) < 1
    let x = (1.0 - rcp) / (2.0 - rcp);
    assert!(close(packing_bound_r0(x, rcp), rcp * (2.0 - rcp), 1e-12));
    let m = Material::<f64>::glass_beads();
    assert_eq!(Packing::Constant.limits(&m, 0.3), (rcp, rlp));
    let (a, b) = Packing::FitHalf.limits(&m, 0.3);
    assert!(close(a, 0.665163851, 1e-12) && close(b, 0.608863851, 1e-12));
    // back-coupled limits keep c_rlp < c_rcp over the whole range
    for k in 0..=100 {
        let x = f64::from(k) / 100.0;
        for p in [Packing::BoundR0, Packing::FitHalf] {
            let (a, b) = p.limits(&m, x);
            assert!(b < a && a < 1.0, "{p:?} {x}");
        }
    }
}
