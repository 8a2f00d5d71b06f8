//! `[frame]`: the frame of reference of a turning container (model.md 2, "rotating
//! container"; 7.5; docs/frames.md). `kind = "lab"` (default) or `"rotating"`; `rev_per_s` is
//! the drum's speed in revolutions per second, positive counter-clockwise in the x-z picture
//! (x to the right, z up) in 2D and, about a y axis, in 3D; about an x (z) axis in 3D, positive
//! turns y towards z (x towards y).
//!
//! What runs today: the rotating frame with a solved, coupled flow (turning gravity,
//! centrifugal and Coriolis forces in the flow, the turning gravity in the segregation) in a
//! box; the lab frame with a turning cut-cell wall (a `[geometry]`, coupled flow; the wall moves
//! at `omega x (x - centre)`). A turning lab frame without a geometry is refused (a box's
//! walls cannot turn on the grid), as is a rotating frame without a flow
//! (nothing would turn but gravity) or with a frozen flow (a turning frame has no steady state).

use super::{vector, Problems};
use crate::error::Error;
use crate::scene::{Equations, SceneFile};
use serde::Deserialize;
use sieve_core::Boundary;

/// `[frame]` as written.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrameSpec {
    /// "lab" (default) or "rotating".
    pub kind: Option<FrameKind>,
    /// Drum speed [rev/s]; positive counter-clockwise (module docs). Default 0.
    pub rev_per_s: Option<f64>,
    /// A point on the rotation axis \[m\], one entry per axis (default: the geometry's centre,
    /// else the box centre).
    pub center: Option<Vec<f64>>,
    /// 3D only: the grid axis of the rotation, "x", "y" or "z" (default "y"; "y" with a
    /// geometry, whose prisms run along y).
    pub axis: Option<String>,
}

/// The frame kinds.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FrameKind {
    /// Grid at rest in the lab; a drum wall would move.
    #[default]
    Lab,
    /// Grid and drum turn together; gravity turns, centrifugal and Coriolis forces act.
    Rotating,
}

/// A validated frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameModel {
    /// Lab or rotating.
    pub kind: FrameKind,
    /// Speed as written [rev/s].
    pub rev_per_s: f64,
    /// Angular velocity in the core's convention (`sieve_core::frame::Rotation::omega`,
    /// turning the first axis of its plane towards the second) [rad/s].
    pub omega: f64,
    /// A point on the axis (solver axis order).
    pub center: Vec<f64>,
    /// Grid axis of the rotation (3D; 1 in 2D, meaning normal to the x-z plane).
    pub axis: usize,
}

/// Largest |rev_per_s| accepted.
pub const MAX_REV_PER_S: f64 = 10.0;

/// Checks `[frame]`. `center` is the geometry's centre (if any), `box_` the grid box.
pub(super) fn check(
    p: &mut Problems,
    l: &str,
    f: &SceneFile,
    dim: usize,
    geometry_center: Option<&[f64]>,
    box_: Option<(&[f64], &[f64])>,
    boundaries: Option<&[[Boundary; 2]]>,
) -> Option<FrameModel> {
    let spec = f.frame.as_ref()?;
    if dim < 2 {
        p.push(Error::range(
            l,
            "frame",
            format!("a {dim}D scene"),
            "2D and 3D scenes only",
        ));
        return None;
    }
    let mut ok = true;
    let kind = spec.kind.unwrap_or_default();
    let rev = spec.rev_per_s.unwrap_or(0.0);
    if !(rev.is_finite() && rev.abs() <= MAX_REV_PER_S) {
        ok = false;
        p.push(Error::range(
            l,
            "frame.rev_per_s",
            rev,
            &format!("-{MAX_REV_PER_S} <= rev_per_s <= {MAX_REV_PER_S} [rev/s] (positive counter-clockwise, x right, z up)"),
        ));
    }
    let axis = match (dim, spec.axis.as_deref()) {
        (2, None) => 1,
        (2, Some(a)) => {
            ok = false;
            p.push(Error::range(
                l,
                "frame.axis",
                format!("{a:?}"),
                "nothing in 2D (the axis is normal to the x-z plane); \"x\", \"y\" or \"z\" in 3D",
            ));
            1
        }
        (_, None) => 1,
        (_, Some(a)) => match ["x", "y", "z"].iter().position(|n| *n == a) {
            Some(1) => 1,
            Some(k) if geometry_center.is_none() => k,
            Some(_) => {
                ok = false;
                p.push(Error::range(
                    l,
                    "frame.axis",
                    format!("{a:?}"),
                    "\"y\" with a [geometry] (its drums are prisms along y)",
                ));
                1
            }
            None => {
                ok = false;
                p.push(Error::range(
                    l,
                    "frame.axis",
                    format!("{a:?}"),
                    "\"x\", \"y\" or \"z\"",
                ));
                1
            }
        },
    };
    let equations = f.model.equations;
    let turning = rev != 0.0;
    match kind {
        FrameKind::Rotating if equations == Equations::Prescribed => {
            ok = false;
            p.push(Error::at(
                l,
                "frame.kind",
                "\"rotating\" only with a solved flow: allowed with model.equations = \"coupled\" (a prescribed scene has no forces to turn)",
            ));
        }
        FrameKind::Rotating if equations == Equations::FrozenFlow => {
            ok = false;
            p.push(Error::at(
                l,
                "frame.kind",
                "\"rotating\" has no steady flow to freeze: allowed with model.equations = \"coupled\"",
            ));
        }
        // the lab frame turns a drum's cut-cell wall (docs/frames.md); a box cannot turn
        FrameKind::Lab
            if turning && (geometry_center.is_none() || equations != Equations::Coupled) =>
        {
            ok = false;
            p.push(Error::range(
                l,
                "frame.rev_per_s",
                rev,
                "0 in the lab frame without a [geometry] and model.equations = \"coupled\" (only a cut-cell wall can turn on the lab's grid): turn the container with frame.kind = \"rotating\"",
            ));
        }
        _ => {}
    }
    let (lower, upper) = box_?;
    let center = match (&spec.center, geometry_center) {
        (Some(v), _) => p.ok(vector(l, "frame.center", v, dim)),
        (None, Some(c)) => Some(c.to_vec()),
        (None, None) => Some((0..dim).map(|a| 0.5 * (lower[a] + upper[a])).collect()),
    };
    let center = center?;
    if kind == FrameKind::Rotating {
        if let Some(b) = boundaries {
            let plane: Vec<usize> = if dim == 2 {
                vec![0, 1]
            } else {
                (0..3).filter(|&a| a != axis).collect()
            };
            for a in plane {
                if b[a][0] == Boundary::Periodic {
                    ok = false;
                    p.push(Error::at(
                        l,
                        "frame.kind",
                        format!("\"rotating\" with a periodic axis {} in the rotation plane: allowed only with walls or outflow there (the centrifugal force is not periodic)", super::axis_names(dim)[a]),
                    ));
                }
            }
        }
    }
    let omega = std::f64::consts::TAU * rev;
    // the core turns the first axis of its plane towards the second: (z, x) about y in 3D,
    // which is clockwise in the x-z picture, so the sign flips there (2D: (x, z), as written)
    let omega = if dim == 3 && axis == 1 { -omega } else { omega };
    ok.then_some(FrameModel {
        kind,
        rev_per_s: rev,
        omega,
        center,
        axis,
    })
}
