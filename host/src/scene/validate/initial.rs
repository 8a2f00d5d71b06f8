//! `[initial]`: the expressions of c, T, u and phi, and their values at the cell centres
//! ([`Fields`]) with the ranges the solver needs: `0 < c <= phi_rcp` (strictly below
//! `(1 - FLOW_MARGIN) phi_rcp` with a solved flow, model.md 2), `T >= 0`, `0 <= phi <= c`,
//! all finite. A bad field is reported once per key, at its first bad cell.

use super::{axis_names, Fields, Problems, Scene, Temperature, FLOW_MARGIN};
use crate::error::{Error, Result};
use crate::scene::expr::{Expr, Vars};
use crate::scene::{ExactKind, ExprSrc, Fill, InitialSpec};

/// The compiled initial expressions: c, T (None when derived from shear), u per axis, phi.
pub(super) struct Initial {
    pub c: Expr,
    pub t: Option<Expr>,
    pub u: Vec<Expr>,
    pub phi: Expr,
}

/// Compiles `[initial]`. `temperature` is None when `[physics]` was invalid (then a missing
/// `initial.T` is not reported: whether it is needed is unknown).
pub(super) fn compile(
    p: &mut Problems,
    l: &str,
    init: &InitialSpec,
    dim: usize,
    temperature: Option<Temperature>,
    has_flow: bool,
) -> Option<Initial> {
    let c = p.ok(Expr::compile(l, "initial.c", &init.c, false));
    let t = match (&init.t, temperature) {
        (Some(t), _) => p.ok(Expr::compile(l, "initial.T", t, false)).map(Some),
        // A solved flow starts cold unless the scene says otherwise.
        (None, Some(Temperature::Given)) if has_flow => p
            .ok(Expr::compile(l, "initial.T", &ExprSrc::Number(0.0), false))
            .map(Some),
        (None, Some(Temperature::Given)) => {
            p.push(Error::at(
                l,
                "initial.T",
                "required with physics.temperature = \"given\"",
            ));
            None
        }
        (None, _) => Some(None),
    };
    let u = match &init.u {
        None => p
            .ok(Expr::compile(l, "initial.u", &ExprSrc::Number(0.0), false))
            .map(|z| vec![z; dim]),
        Some(v) if v.len() != dim => {
            p.push(Error::range(
                l,
                "initial.u",
                format!("{} entries", v.len()),
                &format!(
                    "{dim} expressions, one per axis ({})",
                    axis_names(dim).join(", ")
                ),
            ));
            None
        }
        Some(v) => {
            let us: Vec<Option<Expr>> = v
                .iter()
                .enumerate()
                .map(|(i, e)| p.ok(Expr::compile(l, &format!("initial.u[{i}]"), e, false)))
                .collect();
            us.into_iter().collect()
        }
    };
    let phi = p.ok(Expr::compile(l, "initial.phi", &init.phi, true));
    Some(Initial {
        c: c?,
        t: t?,
        u: u?,
        phi: phi?,
    })
}

impl Scene {
    /// Evaluates c, T, u, phi and the inflow phi at every cell centre and checks their ranges:
    /// `0 < c <= phi_rcp`, `T >= 0`, `0 <= phi <= c`, all finite. Reports every key that is
    /// out of range somewhere (at its first bad cell), one line each.
    pub fn evaluate_fields(&self) -> Result<Fields> {
        let n = self.len();
        let l = &self.label;
        let mut p = Problems::default();
        let mut vars = Vars::new();
        let mut f = Fields {
            c: Vec::with_capacity(n),
            t: Vec::with_capacity(n),
            u: vec![Vec::with_capacity(n); self.dim],
            phi: Vec::with_capacity(n),
            inflow: Vec::with_capacity(n),
        };
        let names = axis_names(self.dim);
        let c_flow_max = (1.0 - FLOW_MARGIN) * self.phi_rcp;
        // An expression that fails to evaluate (or a value out of range) is recorded once per
        // key; the cell gets a harmless placeholder so that the other keys are still checked.
        let mut eval = |p: &mut Problems, e: &Expr, pt: [f64; 3], c: f64, key: &str| match e
            .eval(&mut vars, pt, c, l, key)
        {
            Ok(v) => Some(v),
            Err(err) => {
                p.push_once(key, err);
                None
            }
        };
        // With a geometry only cells that may hold grains are evaluated; the others stay empty.
        let open = self
            .geometry
            .as_ref()
            .map(|g| g.open_cells(self.dim, &self.cells, &self.lower, &self.upper));
        for i in 0..n {
            if open.as_ref().is_some_and(|o| !o[i]) {
                f.c.push(0.0);
                f.t.push(0.0);
                f.phi.push(0.0);
                f.inflow.push(0.0);
                f.u.iter_mut().for_each(|u| u.push(0.0));
                continue;
            }
            let pt = self.center(i);
            let c = eval(&mut p, &self.c, pt, 0.0, "initial.c");
            let c_ok = match c {
                Some(c) if self.flow.is_some() && !(c > 0.0 && c < c_flow_max) => {
                    p.push_once(
                        "initial.c",
                        Error::range(
                            l,
                            "initial.c",
                            format!("{c} {}", self.at(i)),
                            &format!(
                                "0 < c < c_rcp strictly with a solved flow: c < (1 - {FLOW_MARGIN}) material.phi_rcp = {c_flow_max}"
                            ),
                        ),
                    );
                    None
                }
                Some(c) if !(c > 0.0 && c <= self.phi_rcp) => {
                    p.push_once(
                        "initial.c",
                        Error::range(
                            l,
                            "initial.c",
                            format!("{c} {}", self.at(i)),
                            &format!("0 < c <= material.phi_rcp = {}", self.phi_rcp),
                        ),
                    );
                    None
                }
                other => other,
            };
            // Later checks need a c; a bad one is already reported.
            let c = c_ok.unwrap_or(self.phi_rcp);
            let t = match &self.t {
                Some(e) if self.temperature == Temperature::Given => {
                    eval(&mut p, e, pt, c, "initial.T").unwrap_or(0.0)
                }
                _ => 0.0,
            };
            if !(t >= 0.0 && t.is_finite()) {
                p.push_once(
                    "initial.T",
                    Error::range(
                        l,
                        "initial.T",
                        format!("{t} {}", self.at(i)),
                        "a finite T >= 0",
                    ),
                );
            }
            for (a, e) in self.u.iter().enumerate() {
                let key = format!("initial.u[{a}]");
                let v = eval(&mut p, e, pt, c, &key).unwrap_or(0.0);
                if !v.is_finite() {
                    p.push_once(
                        &key,
                        Error::range(
                            l,
                            &key,
                            format!("{v} {}", self.at(i)),
                            &format!("a finite velocity along {}", names[a]),
                        ),
                    );
                }
                f.u[a].push(v);
            }
            let phi = eval(&mut p, &self.phi, pt, c, "initial.phi").unwrap_or(0.0);
            if c_ok.is_some() && !(phi >= 0.0 && phi <= c) {
                p.push_once(
                    "initial.phi",
                    Error::range(
                        l,
                        "initial.phi",
                        format!("{phi} {}", self.at(i)),
                        &format!("0 <= phi <= c = {c}"),
                    ),
                );
            }
            let inflow = match &self.inflow_phi {
                Some(e) if self.on_inflow_side(i) => {
                    let v = eval(&mut p, e, pt, c, "boundary.inflow.phi").unwrap_or(0.0);
                    if c_ok.is_some() && !(v >= 0.0 && v <= c) {
                        p.push_once(
                            "boundary.inflow.phi",
                            Error::range(
                                l,
                                "boundary.inflow.phi",
                                format!("{v} {}", self.at(i)),
                                &format!("0 <= phi <= c = {c}"),
                            ),
                        );
                    }
                    v
                }
                _ => 0.0,
            };
            f.c.push(c);
            f.t.push(t);
            f.phi.push(phi);
            f.inflow.push(inflow);
        }
        if self.fill == Fill::Settled && p.is_empty() {
            self.settle(&mut f, &mut p);
        }
        if self.exact == Some(ExactKind::ColumnA) && p.is_empty() {
            let m0 = f.phi[0] / f.c[0];
            if f.phi.iter().zip(&f.c).any(|(p, c)| p / c != m0) {
                p.push(Error::at(
                    l,
                    "run.exact",
                    "\"column-a\" needs a constant phihat = initial.phi / initial.c",
                ));
            }
        }
        p.finish()?;
        Ok(f)
    }
}
