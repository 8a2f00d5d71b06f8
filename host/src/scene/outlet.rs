//! `outlet = { ... }` of a flow wall side (`[boundary.flow] z_low = { ..., outlet = {...} }`):
//! an opening in the wall through which grains leave freely (issue 9; the core mechanism is
//! `sieve_core::boundary::Openings` and the outlet ghost of `sieve_core::flow::FlowSide`).
//!
//! ```toml
//! z_low = { wall = "friction", friction_angle = 30.0, outlet = { center = 0.0725, width = 0.02 } }
//! ```
//! `center` and `width` are one number per tangential axis of the side (a number in 2D; in
//! 3D `[x, y]` for a z side, `[x, z]` for a y side, `[y, z]` for an x side), in metres;
//! `pressure = "zero"` (default: `p = 0` outside) or `"zero-gradient"`.

use crate::error::{Error, Result};
use serde::Deserialize;
use sieve_core::flow::OutletPressure;

/// One number or one per tangential axis.
#[derive(Debug, Clone)]
pub enum Coords {
    /// A number (2D).
    One(f64),
    /// One per tangential axis.
    Many(Vec<f64>),
}

// A hand-written visitor instead of `#[serde(untagged)]`: a wrong type then says what is
// allowed instead of "data did not match any variant of untagged enum Coords".
impl<'de> Deserialize<'de> for Coords {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        struct V;
        impl<'de> serde::de::Visitor<'de> for V {
            type Value = Coords;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a number or a list of numbers, one per axis along the side")
            }
            fn visit_f64<E>(self, v: f64) -> std::result::Result<Coords, E> {
                Ok(Coords::One(v))
            }
            fn visit_i64<E>(self, v: i64) -> std::result::Result<Coords, E> {
                Ok(Coords::One(v as f64))
            }
            fn visit_u64<E>(self, v: u64) -> std::result::Result<Coords, E> {
                Ok(Coords::One(v as f64))
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                mut seq: A,
            ) -> std::result::Result<Coords, A::Error> {
                let mut v = Vec::new();
                while let Some(x) = seq.next_element::<f64>()? {
                    v.push(x);
                }
                Ok(Coords::Many(v))
            }
        }
        d.deserialize_any(V)
    }
}

impl Coords {
    fn values(&self) -> Vec<f64> {
        match self {
            Coords::One(v) => vec![*v],
            Coords::Many(v) => v.clone(),
        }
    }
}

/// Ghost pressure of an outlet as written.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PressureSpec {
    /// p = 0 on the orifice face (the ghost mirrors the cell's pressure).
    #[default]
    Zero,
    /// p_ghost = p_cell.
    ZeroGradient,
}

/// `outlet = { center, width, pressure }` as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutletSpec {
    /// Centre of the opening along the tangential axes \[m\].
    pub center: Coords,
    /// Width of the opening along the tangential axes \[m\].
    pub width: Coords,
    /// Ghost pressure.
    #[serde(default)]
    pub pressure: PressureSpec,
}

/// A validated outlet: the box `lower..upper` in solver axis order (the side's own axis 0).
#[derive(Debug, Clone, PartialEq)]
pub struct Outlet {
    /// Lower corner \[m\].
    pub lower: Vec<f64>,
    /// Upper corner \[m\].
    pub upper: Vec<f64>,
    /// Ghost pressure.
    pub pressure: OutletPressure,
    /// Open length (2D) or area (3D) of the opening [m, m^2].
    pub size: f64,
}

/// Validates `spec` for the side of solver axis `axis` of a `dim`-dimensional box
/// `lower..upper` (solver axis order); `key` names the side in messages.
pub fn validate(
    l: &str,
    key: &str,
    spec: &OutletSpec,
    axis: usize,
    dim: usize,
    lower: &[f64],
    upper: &[f64],
) -> Result<Outlet> {
    let key = format!("{key}.outlet");
    if dim < 2 {
        return Err(Error::at(
            l,
            &key,
            "outlets need a 2D or 3D scene (a 1D side has no extent)",
        ));
    }
    let names = super::validate::axis_names(dim);
    let tangential: Vec<usize> = (0..dim).filter(|&b| b != axis).collect();
    let along = tangential
        .iter()
        .map(|&b| names[b])
        .collect::<Vec<_>>()
        .join(", ");
    let (centre, width) = (spec.center.values(), spec.width.values());
    for (what, v) in [("center", &centre), ("width", &width)] {
        if v.len() != tangential.len() {
            return Err(Error::at(
                l,
                &format!("{key}.{what}"),
                format!(
                    "needs {} number(s), one per axis along the side ({along})",
                    tangential.len()
                ),
            ));
        }
    }
    let mut out = Outlet {
        lower: vec![0.0; dim],
        upper: vec![0.0; dim],
        pressure: match spec.pressure {
            PressureSpec::Zero => OutletPressure::Zero,
            PressureSpec::ZeroGradient => OutletPressure::ZeroGradient,
        },
        size: 1.0,
    };
    for (k, &b) in tangential.iter().enumerate() {
        let (c, w) = (centre[k], width[k]);
        let (lo, hi) = (c - 0.5 * w, c + 0.5 * w);
        // An opening narrower than round-off of the side's coordinates would be a box of zero
        // extent: accepted, it would drain nothing and say nothing.
        let round_off = 16.0 * f64::EPSILON * lower[b].abs().max(upper[b].abs());
        if !(w.is_finite() && w > round_off) {
            return Err(Error::range(
                l,
                &format!("{key}.width"),
                w,
                &format!("width > {round_off:.1e} [m] (round-off of the side's coordinates)"),
            ));
        }
        if !(c.is_finite() && lo >= lower[b] - 1e-12 && hi <= upper[b] + 1e-12) {
            return Err(Error::range(
                l,
                &format!("{key}.center"),
                c,
                &format!(
                    "the opening center +- width/2 inside the side: {} <= {} +- {}/2 <= {} along {}",
                    lower[b], c, w, upper[b], names[b]
                ),
            ));
        }
        out.lower[b] = lo;
        out.upper[b] = hi;
        out.size *= w;
    }
    Ok(out)
}
