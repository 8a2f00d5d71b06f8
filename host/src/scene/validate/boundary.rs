//! `[boundary]`: a kind per side of each axis the scene has (periodic in pairs), and the
//! inflow state wherever a side is "inflow".

use super::{axis_names, Problems};
use crate::error::Error;
use crate::scene::expr::Expr;
use crate::scene::BoundarySpec;
use sieve_core::Boundary;

/// Validated `[boundary]`: kinds per solver axis and the inflow phi, if any.
pub(super) type Boundaries = (Vec<[Boundary; 2]>, Option<Expr>);

/// Checks `[boundary]` of a `dim`-dimensional scene.
pub(super) fn check(p: &mut Problems, l: &str, b: &BoundarySpec, dim: usize) -> Option<Boundaries> {
    let by_name = [("x", b.x), ("y", b.y), ("z", b.z)];
    let names = axis_names(dim);
    let mut ok = true;
    for (name, kinds) in by_name {
        if kinds.is_some() && !names.contains(&name) {
            ok = false;
            p.push(Error::at(
                l,
                &format!("boundary.{name}"),
                format!(
                    "a {dim}D scene has no axis {name}: allowed boundary keys {}",
                    names.join(", ")
                ),
            ));
        }
    }
    let mut boundaries = Vec::with_capacity(dim);
    for name in &names {
        let kinds = by_name
            .iter()
            .find(|(n, _)| n == name)
            .and_then(|(_, k)| *k)
            .unwrap_or([Boundary::Wall; 2]);
        if (kinds[0] == Boundary::Periodic) != (kinds[1] == Boundary::Periodic) {
            ok = false;
            p.push(Error::range(
                l,
                &format!("boundary.{name}"),
                format!("{kinds:?}").to_lowercase(),
                "periodic on both sides or on neither",
            ));
        }
        boundaries.push(kinds);
    }
    let has_inflow = boundaries.iter().flatten().any(|&k| k == Boundary::Inflow);
    let inflow_phi = match (&b.inflow, has_inflow) {
        (Some(i), true) => {
            let e = p.ok(Expr::compile(l, "boundary.inflow.phi", &i.phi, true));
            ok &= e.is_some();
            e
        }
        (None, true) => {
            ok = false;
            p.push(Error::at(
                l,
                "boundary.inflow.phi",
                "required: a side is \"inflow\"",
            ));
            None
        }
        (Some(_), false) => {
            ok = false;
            p.push(Error::at(
                l,
                "boundary.inflow",
                "given but no side is \"inflow\"",
            ));
            None
        }
        (None, false) => None,
    };
    ok.then_some((boundaries, inflow_phi))
}
