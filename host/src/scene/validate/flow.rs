//! The solved flow (`model.equations = "frozen-flow" | "coupled"`, model.md 2, 4): keys that
//! exist only with a flow, the flow material (eta0, lambda0, eps0, T0, phi_rlp < phi_rcp < 1),
//! `[boundary.flow]` wall laws and `[flow]` numerics.

use super::{axis_names, vector, FlowModel, Problems, WallSide, WallSlip};
use crate::error::{Error, Result};
use crate::scene::{FlowWallSpec, SceneFile, WallKind};
use sieve_core::Boundary;

/// A prescribed scene must not set the keys of a solved flow.
pub(super) fn only_with_flow(p: &mut Problems, l: &str, f: &SceneFile) {
    let only = |key: &str| {
        Error::at(
            l,
            key,
            "only with a flow: allowed with model.equations = \"frozen-flow\" or \"coupled\"",
        )
    };
    if f.model.back_coupling.is_some() {
        p.push(only("model.back_coupling"));
    }
    if f.flow.is_some() {
        p.push(only("flow"));
    }
    if f.boundary.flow.is_some() {
        p.push(only("boundary.flow"));
    }
    for (key, v) in [
        ("material.lambda0", f.material.lambda0),
        ("material.T0", f.material.t0),
        ("material.phi_rlp", f.material.phi_rlp),
    ] {
        if v.is_some() {
            p.push(only(key));
        }
    }
}

fn positive(l: &str, key: &str, v: Option<f64>, unit: &str) -> Result<f64> {
    let v = v.ok_or_else(|| {
        Error::at(
            l,
            key,
            "required with a solved flow (model.equations = \"frozen-flow\" or \"coupled\")",
        )
    })?;
    if !(v.is_finite() && v > 0.0) {
        return Err(Error::range(
            l,
            key,
            v,
            &format!("a finite number > 0 {unit}"),
        ));
    }
    Ok(v)
}

fn wall_side(
    l: &str,
    key: &str,
    spec: Option<&FlowWallSpec>,
    kind: Boundary,
    axis: usize,
    dim: usize,
    extent: Option<(&[f64], &[f64])>,
) -> Result<WallSide> {
    let mut side = WallSide {
        slip: WallSlip::NoSlip,
        velocity: vec![0.0; dim],
        outlet: None,
    };
    let Some(spec) = spec else {
        return Ok(side);
    };
    if kind != Boundary::Wall {
        return Err(Error::at(
            l,
            key,
            format!(
                "given but this side is {:?}: allowed only on \"wall\" sides",
                format!("{kind:?}").to_lowercase()
            ),
        ));
    }
    let wall = spec.wall.unwrap_or(if spec.friction_angle.is_some() {
        WallKind::Friction
    } else {
        WallKind::NoSlip
    });
    side.slip = match (wall, spec.friction_angle) {
        (WallKind::NoSlip, None) => WallSlip::NoSlip,
        (WallKind::Slip, None) => WallSlip::Slip,
        (WallKind::Friction, Some(deg)) => {
            if !(deg.is_finite() && (0.0..=90.0).contains(&deg)) {
                return Err(Error::range(
                    l,
                    &format!("{key}.friction_angle"),
                    deg,
                    "0 <= friction_angle <= 90 [deg] (0 = slip, 90 = no-slip)",
                ));
            }
            if deg == 90.0 {
                WallSlip::NoSlip
            } else {
                WallSlip::Friction {
                    tan: libm::tan(deg.to_radians()),
                    degrees: deg,
                }
            }
        }
        (WallKind::Friction, None) => {
            return Err(Error::at(
                l,
                &format!("{key}.friction_angle"),
                "required with wall = \"friction\": allowed 0..=90 [deg]",
            ))
        }
        (_, Some(_)) => {
            return Err(Error::at(
                l,
                &format!("{key}.friction_angle"),
                "only with wall = \"friction\" (then 0 <= friction_angle <= 90 [deg])",
            ))
        }
    };
    if let Some(v) = &spec.velocity {
        let v = vector(l, &format!("{key}.velocity"), v, dim)?;
        if v[axis] != 0.0 {
            return Err(Error::range(
                l,
                &format!("{key}.velocity[{axis}]"),
                v[axis],
                "0: walls move tangentially only",
            ));
        }
        side.velocity = v;
    }
    if let (Some(o), Some((lower, upper))) = (&spec.outlet, extent) {
        side.outlet = Some(crate::scene::outlet::validate(
            l, key, o, axis, dim, lower, upper,
        )?);
    }
    Ok(side)
}

/// `[boundary.flow]`: the wall law of every side, in solver axis order.
fn walls(
    p: &mut Problems,
    l: &str,
    f: &SceneFile,
    dim: usize,
    boundaries: &[[Boundary; 2]],
    extent: Option<(&[f64], &[f64])>,
) -> Option<Vec<[WallSide; 2]>> {
    let names = axis_names(dim);
    let fb = f.boundary.flow.clone().unwrap_or_default();
    let by_name = [
        ("x", &fb.x_low, &fb.x_high),
        ("y", &fb.y_low, &fb.y_high),
        ("z", &fb.z_low, &fb.z_high),
    ];
    let mut ok = true;
    let mut walls = Vec::with_capacity(dim);
    for (name, lo, hi) in by_name {
        match names.iter().position(|n| *n == name) {
            Some(a) => {
                let side = |p: &mut Problems, s: usize, spec: &Option<FlowWallSpec>| {
                    let which = ["low", "high"][s];
                    p.ok(wall_side(
                        l,
                        &format!("boundary.flow.{name}_{which}"),
                        spec.as_ref(),
                        boundaries[a][s],
                        a,
                        dim,
                        extent,
                    ))
                };
                let (low, high) = (side(p, 0, lo), side(p, 1, hi));
                match (low, high) {
                    (Some(low), Some(high)) => walls.push([low, high]),
                    _ => ok = false,
                }
            }
            None if lo.is_some() || hi.is_some() => {
                ok = false;
                p.push(Error::at(
                    l,
                    &format!("boundary.flow.{name}_low"),
                    format!(
                        "a {dim}D scene has no axis {name}: allowed sides of {}",
                        names.join(", ")
                    ),
                ));
            }
            None => {}
        }
    }
    // `walls` was filled in x, y, z order, which is the solver axis order of every dimension.
    ok.then_some(walls)
}

/// Checks the flow part of a scene. `dim`, `phi_rcp` and `boundaries` are None when their own
/// sections were invalid; the checks that need them are then skipped.
pub(super) fn check(
    p: &mut Problems,
    l: &str,
    f: &SceneFile,
    dim: Option<usize>,
    phi_rcp: Option<f64>,
    boundaries: Option<&[[Boundary; 2]]>,
    extent: Option<(&[f64], &[f64])>,
) -> Option<FlowModel> {
    let m = &f.material;
    let eta0 = p.ok(positive(l, "material.eta0", m.eta0, "[m]"));
    let lambda0 = p.ok(positive(l, "material.lambda0", m.lambda0, "[m]"));
    let eps0 = p.ok(positive(l, "material.eps0", m.eps0, "[1/m]"));
    let heating = p.ok(positive(l, "material.heating", Some(m.heating), ""));
    let t0 = match m.t0 {
        None => {
            p.push(Error::at(
                l,
                "material.T0",
                "required with a solved flow (model.equations = \"frozen-flow\" or \"coupled\")",
            ));
            None
        }
        Some(t0) if !(t0.is_finite() && t0 >= 0.0) => {
            p.push(Error::range(l, "material.T0", t0, "T0 >= 0 [m^2/s^2]"));
            None
        }
        Some(t0) => Some(t0),
    };
    let mut packing_ok = true;
    if let Some(phi_rcp) = phi_rcp {
        if !(phi_rcp < 1.0) {
            packing_ok = false;
            p.push(Error::range(
                l,
                "material.phi_rcp",
                phi_rcp,
                "0 < phi_rcp < 1 with a solved flow",
            ));
        }
    }
    let phi_rlp = p
        .ok(positive(l, "material.phi_rlp", m.phi_rlp, ""))
        .and_then(|rlp| match phi_rcp {
            Some(rcp) if !(rlp < rcp) => {
                p.push(Error::range(
                    l,
                    "material.phi_rlp",
                    rlp,
                    &format!("0 < phi_rlp < material.phi_rcp = {rcp}"),
                ));
                None
            }
            _ => Some(rlp),
        });
    let mut walls_ok = None;
    if let (Some(dim), Some(boundaries)) = (dim, boundaries) {
        if boundaries.iter().flatten().any(|&k| k == Boundary::Inflow) {
            p.push(Error::at(
                l,
                "boundary",
                "\"inflow\" sides are not supported with a solved flow yet: allowed wall, outflow, periodic",
            ));
        } else {
            walls_ok = walls(p, l, f, dim, boundaries, extent);
        }
    }
    let fs = f.flow.clone().unwrap_or_default();
    let steady_tolerance = p.ok(positive(
        l,
        "flow.steady_tolerance",
        Some(fs.steady_tolerance.unwrap_or(1e-3)),
        "[1/s]",
    ));
    let t_min = p.ok(positive(
        l,
        "flow.t_min",
        Some(fs.t_min.unwrap_or(1e-14)),
        "[m^2/s^2]",
    ));
    let cg_tolerance = fs.cg_tolerance;
    let cg_tolerance_pressure = fs.cg_tolerance_pressure;
    let mut tolerances_ok = true;
    for (key, value, max) in [
        ("cg_tolerance", cg_tolerance, "1e-3"),
        ("cg_tolerance_pressure", cg_tolerance_pressure, "1e-3"),
    ] {
        let hi: f64 = max.parse().unwrap_or(0.0);
        if value.is_some_and(|x| !(1e-14..=hi).contains(&x)) {
            tolerances_ok = false;
            p.push(Error::range(
                l,
                &format!("flow.{key}"),
                value.unwrap_or(f64::NAN),
                &format!("1e-14 <= {key} <= {max}"),
            ));
        }
    }
    let courant = fs.courant.unwrap_or(0.4);
    let courant_ok = courant.is_finite() && courant > 0.0 && courant <= 0.5;
    if !courant_ok {
        p.push(Error::range(
            l,
            "flow.courant",
            courant,
            "0 < courant <= 0.5",
        ));
    }
    let min_steps = fs.min_steps.unwrap_or(50);
    let min_ok = (0..=100_000_000).contains(&min_steps);
    if !min_ok {
        p.push(Error::range(
            l,
            "flow.min_steps",
            min_steps,
            "0..=100000000",
        ));
    }
    let max_steps = fs.max_steps.unwrap_or(200_000);
    let max_ok = (1..=100_000_000).contains(&max_steps) && max_steps >= min_steps;
    if !max_ok {
        p.push(Error::range(
            l,
            "flow.max_steps",
            max_steps,
            &format!("flow.min_steps = {min_steps} <= max_steps <= 100000000"),
        ));
    }
    (packing_ok && courant_ok && min_ok && max_ok && tolerances_ok).then_some(())?;
    Some(FlowModel {
        equations: f.model.equations,
        back_coupling: f.model.back_coupling.unwrap_or_default(),
        eta0: eta0?,
        lambda0: lambda0?,
        eps0: eps0?,
        t0: t0?,
        phi_rlp: phi_rlp?,
        heating: heating?,
        walls: walls_ok?,
        steady_tolerance: steady_tolerance?,
        min_steps: min_steps as u64,
        max_steps: max_steps as u64,
        t_min: t_min?,
        cg_tolerance,
        cg_tolerance_pressure,
        courant,
        spin_up: fs.spin_up.unwrap_or_default(),
        pressure: fs.pressure.unwrap_or_default(),
        stress: fs.stress.unwrap_or_default(),
        merged_walls: fs.merged_walls.unwrap_or_default(),
        merged_walls_given: fs.merged_walls.is_some(),
    })
}
