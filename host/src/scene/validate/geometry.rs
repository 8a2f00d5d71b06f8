//! `[geometry]`: walls that are not grid faces (issue 8; docs/geometry.md). The container
//! (a drum, a square drum, a drum with one baffle, a hopper) is described in the scene and
//! turned into cut cells by the core (`sieve_core::geometry`) once at set-up.
//!
//! Conventions, as in the core's builders: the horizontal axis is x, the vertical the last
//! axis (z); angles are given in degrees, counter-clockwise from +x towards +z. In 3D every
//! shape is a prism along y (the drum axis of model.md 7.5: horizontal, gravity along z); the
//! box faces in y close it (walls: end walls; periodic: an axial slice).
//!
//! A geometry runs the segregation solver on cut cells for prescribed scenes, and the flow
//! and the segregation on cut cells for coupled scenes (`Flow::set_geometry`,
//! `Coupled::new_embedded`; the cut wall takes the wall law of the box's `z_low` side, at rest:
//! containers turn through a rotating `[frame]`). A frozen flow with a geometry is refused.
//! No silent fallback to the box.

use super::{axis_names, vector, Problems};
use crate::error::Error;
use crate::scene::SceneFile;
use serde::Deserialize;
use sieve_core::geometry::Region;
use sieve_core::Real;

/// `[geometry]` as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GeometrySpec {
    /// "drum", "square-drum", "drum-baffle" or "hopper".
    pub shape: ShapeKind,
    /// Centre of the drum \[m\], one entry per axis (default: the centre of the box); the y
    /// entry of a 3D scene is ignored (the drum is a prism along y). Hopper: the x entry is
    /// the outlet's centre.
    pub center: Option<Vec<f64>>,
    /// Drum radius \[m\] ("drum", "drum-baffle").
    pub radius: Option<f64>,
    /// Half the side of the square drum \[m\] ("square-drum").
    pub half_width: Option<f64>,
    /// Square drum: its turn \[deg\]; drum-baffle: the polar angle of the baffle's foot \[deg\].
    pub angle: Option<f64>,
    /// How far the baffle reaches into the drum from its wall \[m\].
    pub baffle_length: Option<f64>,
    /// Thickness of the baffle plate \[m\] (at least one cell: thinner features are not seen).
    pub baffle_thickness: Option<f64>,
    /// Height of the hopper's outlet \[m\].
    pub outlet_z: Option<f64>,
    /// Width of the hopper's outlet \[m\].
    pub outlet_width: Option<f64>,
    /// Angle of the hopper walls from the vertical \[deg\].
    pub hopper_angle: Option<f64>,
    /// Merging threshold: cut cells with an open fraction below it join a neighbour
    /// (docs/geometry.md); default 0.5, allowed [0, 1).
    pub small: Option<f64>,
}

/// The container shapes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ShapeKind {
    /// A circular drum.
    Drum,
    /// A square drum, possibly turned.
    SquareDrum,
    /// A circular drum with one flat baffle standing on its wall.
    DrumBaffle,
    /// A wedge hopper between the box's x walls.
    Hopper,
}

impl ShapeKind {
    /// The name as written in a scene file.
    pub fn name(self) -> &'static str {
        match self {
            ShapeKind::Drum => "drum",
            ShapeKind::SquareDrum => "square-drum",
            ShapeKind::DrumBaffle => "drum-baffle",
            ShapeKind::Hopper => "hopper",
        }
    }
}

/// A validated geometry. Lengths in m, angles in radians, `center` in solver axis order.
#[derive(Debug, Clone, PartialEq)]
pub struct Geometry {
    /// Which shape.
    pub shape: ShapeKind,
    /// Centre (solver axis order); hopper: x is the outlet's centre.
    pub center: Vec<f64>,
    /// Radius (drum, drum-baffle) or half-width (square drum); 0 for the hopper.
    pub size: f64,
    /// Square drum: turn; drum-baffle: polar angle of the baffle; hopper: wall angle from
    /// the vertical \[rad\].
    pub angle: f64,
    /// Baffle length and thickness \[m\] (drum-baffle).
    pub baffle: (f64, f64),
    /// Hopper outlet height and half-width \[m\].
    pub outlet: (f64, f64),
    /// The box's x range (the hopper's vertical walls).
    pub x_range: (f64, f64),
    /// The box's range on the vertical axis (where the hopper's outlet channel ends).
    pub z_range: (f64, f64),
    /// Merging threshold.
    pub small: f64,
}

impl Geometry {
    /// The open region of the core for a `D`-dimensional grid (`D` = the scene's dim).
    pub fn region<R: Real, const D: usize>(&self) -> Region<R, D> {
        let c: [R; D] = core::array::from_fn(|a| R::from_f64(self.center[a]));
        let r = R::from_f64;
        match self.shape {
            ShapeKind::Drum => Region::drum(c, r(self.size)),
            ShapeKind::SquareDrum => Region::square_drum(c, r(self.size), r(self.angle)),
            ShapeKind::DrumBaffle => Region::drum_with_baffle(
                c,
                r(self.size),
                r(self.angle),
                r(self.baffle.0),
                r(self.baffle.1),
            ),
            ShapeKind::Hopper => Region::hopper(
                r(self.x_range.0),
                r(self.x_range.1),
                r(self.center[0]),
                r(self.outlet.0),
                r(self.outlet.1),
                r(self.angle),
            ),
        }
    }

    /// Whether each cell of the scene's grid may hold grains: some corner of it is open (the
    /// cut cells of the core give such a cell a positive volume unless it is a sliver they
    /// fold into the solid). The initial fields are checked, and set, only there.
    pub fn open_cells(
        &self,
        dim: usize,
        cells: &[usize],
        lower: &[f64],
        upper: &[f64],
    ) -> Vec<bool> {
        match dim {
            2 => open_cells::<2>(&self.region::<f64, 2>(), cells, lower, upper),
            3 => open_cells::<3>(&self.region::<f64, 3>(), cells, lower, upper),
            _ => vec![true; cells.iter().product()],
        }
    }

    /// The outline in the x-z plane as polylines (for the phihat maps).
    pub fn outline(&self, dim: usize) -> Vec<Vec<(f64, f64)>> {
        let z = dim - 1;
        let (cx, cz) = (self.center[0], self.center[z]);
        let circle = |r: f64| -> Vec<(f64, f64)> {
            (0..=256)
                .map(|k| {
                    let t = k as f64 / 256.0 * std::f64::consts::TAU;
                    (cx + r * t.cos(), cz + r * t.sin())
                })
                .collect()
        };
        match self.shape {
            ShapeKind::Drum => vec![circle(self.size)],
            ShapeKind::SquareDrum => {
                let (s, c) = self.angle.sin_cos();
                let h = self.size;
                let corner = |a: f64, b: f64| (cx + h * (a * c - b * s), cz + h * (a * s + b * c));
                vec![vec![
                    corner(1.0, 1.0),
                    corner(-1.0, 1.0),
                    corner(-1.0, -1.0),
                    corner(1.0, -1.0),
                    corner(1.0, 1.0),
                ]]
            }
            ShapeKind::DrumBaffle => {
                let (s, c) = self.angle.sin_cos();
                let (len, w) = (self.baffle.0, self.baffle.1 / 2.0);
                let at = |r: f64, t: f64| (cx + r * c - t * s, cz + r * s + t * c);
                let r = self.size;
                vec![
                    circle(r),
                    vec![at(r, w), at(r - len, w), at(r - len, -w), at(r, -w)],
                ]
            }
            ShapeKind::Hopper => {
                let (oz, hw) = self.outlet;
                let (x0, x1) = self.x_range;
                let t = self.angle.tan();
                let (xl, xr) = (cx - hw, cx + hw);
                // the inclined walls rise from the outlet edges until they meet the box walls
                vec![
                    vec![(x0, oz + (xl - x0) / t), (xl, oz), (xl, self.z_range.0)],
                    vec![(x1, oz + (x1 - xr) / t), (xr, oz), (xr, self.z_range.0)],
                ]
            }
        }
    }
}

fn open_cells<const D: usize>(
    region: &Region<f64, D>,
    cells: &[usize],
    lower: &[f64],
    upper: &[f64],
) -> Vec<bool> {
    let n: usize = cells.iter().product();
    let h: Vec<f64> = (0..D)
        .map(|a| (upper[a] - lower[a]) / cells[a] as f64)
        .collect();
    (0..n)
        .map(|i| {
            let mut k = [0usize; D];
            let mut rest = i;
            for a in 0..D {
                k[a] = rest % cells[a];
                rest /= cells[a];
            }
            (0..1usize << D).any(|corner| {
                let x: [f64; D] =
                    core::array::from_fn(|a| lower[a] + (k[a] + ((corner >> a) & 1)) as f64 * h[a]);
                region.is_open(x)
            })
        })
        .collect()
}

fn positive(p: &mut Problems, l: &str, key: &str, v: Option<f64>, needed: &str) -> Option<f64> {
    match v {
        None => {
            p.push(Error::at(
                l,
                key,
                format!("required with geometry.shape = \"{needed}\": allowed a length > 0 [m]"),
            ));
            None
        }
        Some(x) if !(x.is_finite() && x > 0.0) => {
            p.push(Error::range(l, key, x, "a finite length > 0 [m]"));
            None
        }
        Some(x) => Some(x),
    }
}

fn degrees(p: &mut Problems, l: &str, key: &str, v: Option<f64>, lo: f64, hi: f64) -> Option<f64> {
    let v = v.unwrap_or(0.0);
    if v.is_finite() && v >= lo && v <= hi {
        Some(v.to_radians())
    } else {
        p.push(Error::range(
            l,
            key,
            v,
            &format!("{lo} <= {key} <= {hi} [deg]"),
        ));
        None
    }
}

/// Checks `[geometry]` of a `dim`-dimensional scene on the box `lower..upper` (None when
/// `[grid]` was invalid: then the box-relative checks are skipped).
pub(super) fn check(
    p: &mut Problems,
    l: &str,
    f: &SceneFile,
    dim: usize,
    grid: Option<(&[usize], &[f64], &[f64])>,
) -> Option<Geometry> {
    let g = f.geometry.as_ref()?;
    let mut ok = true;
    if dim < 2 {
        p.push(Error::range(
            l,
            "geometry",
            format!("a {dim}D scene"),
            "2D and 3D scenes only (the container is drawn in the x-z plane)",
        ));
        return None;
    }
    if f.model.equations == crate::scene::Equations::FrozenFlow {
        ok = false;
        p.push(Error::at(
            l,
            "geometry",
            "not with model.equations = \"frozen-flow\": allowed with \"prescribed\" (segregation on cut cells) or \"coupled\" (flow and segregation on cut cells)",
        ));
    }
    let needs = |kind: ShapeKind| g.shape == kind;
    // keys that belong to another shape are mistakes, not silently ignored
    for (key, given, allowed) in [
        (
            "geometry.radius",
            g.radius.is_some(),
            needs(ShapeKind::Drum) || needs(ShapeKind::DrumBaffle),
        ),
        (
            "geometry.half_width",
            g.half_width.is_some(),
            needs(ShapeKind::SquareDrum),
        ),
        (
            "geometry.angle",
            g.angle.is_some(),
            !needs(ShapeKind::Drum) && !needs(ShapeKind::Hopper),
        ),
        (
            "geometry.baffle_length",
            g.baffle_length.is_some(),
            needs(ShapeKind::DrumBaffle),
        ),
        (
            "geometry.baffle_thickness",
            g.baffle_thickness.is_some(),
            needs(ShapeKind::DrumBaffle),
        ),
        (
            "geometry.outlet_z",
            g.outlet_z.is_some(),
            needs(ShapeKind::Hopper),
        ),
        (
            "geometry.outlet_width",
            g.outlet_width.is_some(),
            needs(ShapeKind::Hopper),
        ),
        (
            "geometry.hopper_angle",
            g.hopper_angle.is_some(),
            needs(ShapeKind::Hopper),
        ),
    ] {
        if given && !allowed {
            ok = false;
            p.push(Error::at(
                l,
                key,
                format!("not a key of geometry.shape = \"{}\"", g.shape.name()),
            ));
        }
    }
    let small = g.small.unwrap_or(sieve_core::geometry::DEFAULT_SMALL);
    if !(small.is_finite() && (0.5..1.0).contains(&small)) {
        ok = false;
        p.push(Error::range(
            l,
            "geometry.small",
            small,
            "0.5 <= small < 1 (open fraction below which a cut cell is merged; below 1/2 tiny cells would hold the flow's time step)",
        ));
    }
    let (cells, lower, upper) = grid?;
    let h_min = (0..dim)
        .map(|a| (upper[a] - lower[a]) / cells[a] as f64)
        .fold(f64::INFINITY, f64::min);
    let center = match &g.center {
        None => Some(
            (0..dim)
                .map(|a| 0.5 * (lower[a] + upper[a]))
                .collect::<Vec<_>>(),
        ),
        Some(v) => p.ok(vector(l, "geometry.center", v, dim)),
    };
    let center = center?;
    let z = dim - 1;
    let inside = |a: usize| center[a] > lower[a] && center[a] < upper[a];
    let centred = g.shape == ShapeKind::Hopper || (inside(0) && inside(z));
    if !centred {
        ok = false;
        p.push(Error::range(
            l,
            "geometry.center",
            format!("{center:?}"),
            &format!(
                "a point inside the box ({} between lower and upper)",
                axis_names(dim).join(", ")
            ),
        ));
    }
    let mut geo = Geometry {
        shape: g.shape,
        center: center.clone(),
        size: 0.0,
        angle: 0.0,
        baffle: (0.0, 0.0),
        outlet: (0.0, 0.0),
        x_range: (lower[0], upper[0]),
        z_range: (lower[z], upper[z]),
        small,
    };
    // the largest radius (half-width) that keeps the container inside the box
    let room = (center[0] - lower[0])
        .min(upper[0] - center[0])
        .min(center[z] - lower[z])
        .min(upper[z] - center[z]);
    match g.shape {
        ShapeKind::Drum | ShapeKind::DrumBaffle => {
            let key = "geometry.radius";
            if let Some(r) = positive(p, l, key, g.radius, g.shape.name()) {
                if centred && r > room {
                    ok = false;
                    p.push(Error::range(
                        l,
                        key,
                        r,
                        &format!("0 < radius <= {room} (the drum must fit in the box)"),
                    ));
                } else if r < 2.0 * h_min {
                    ok = false;
                    p.push(Error::range(
                        l,
                        key,
                        r,
                        &format!("radius >= 2 cells = {} [m]", 2.0 * h_min),
                    ));
                }
                geo.size = r;
            } else {
                ok = false;
            }
            if g.shape == ShapeKind::DrumBaffle {
                geo.angle =
                    degrees(p, l, "geometry.angle", g.angle, -360.0, 360.0).unwrap_or_else(|| {
                        ok = false;
                        0.0
                    });
                let len = positive(
                    p,
                    l,
                    "geometry.baffle_length",
                    g.baffle_length,
                    "drum-baffle",
                );
                let thick = positive(
                    p,
                    l,
                    "geometry.baffle_thickness",
                    g.baffle_thickness,
                    "drum-baffle",
                );
                match (len, thick) {
                    (Some(len), Some(thick)) => {
                        if geo.size > 0.0 && len >= geo.size {
                            ok = false;
                            p.push(Error::range(
                                l,
                                "geometry.baffle_length",
                                len,
                                &format!("0 < baffle_length < geometry.radius = {}", geo.size),
                            ));
                        }
                        if thick < h_min {
                            ok = false;
                            p.push(Error::range(l, "geometry.baffle_thickness", thick, &format!("baffle_thickness >= one cell = {h_min} [m] (a thinner plate crosses no cell edge and is not seen)")));
                        }
                        geo.baffle = (len, thick);
                    }
                    _ => ok = false,
                }
            }
        }
        ShapeKind::SquareDrum => {
            let key = "geometry.half_width";
            geo.angle =
                degrees(p, l, "geometry.angle", g.angle, -360.0, 360.0).unwrap_or_else(|| {
                    ok = false;
                    0.0
                });
            // a turned square needs sqrt(2) more room in the worst case: check its corners
            if let Some(hw) = positive(p, l, key, g.half_width, "square-drum") {
                let (s, c) = geo.angle.sin_cos();
                let reach = hw * (s.abs() + c.abs());
                if centred && reach > room {
                    ok = false;
                    p.push(Error::range(
                        l,
                        key,
                        hw,
                        &format!(
                            "0 < half_width <= {} (the turned square must fit in the box)",
                            room / (s.abs() + c.abs())
                        ),
                    ));
                } else if hw < 2.0 * h_min {
                    ok = false;
                    p.push(Error::range(
                        l,
                        key,
                        hw,
                        &format!("half_width >= 2 cells = {} [m]", 2.0 * h_min),
                    ));
                }
                geo.size = hw;
            } else {
                ok = false;
            }
        }
        ShapeKind::Hopper => {
            let inside = center[0] > lower[0] && center[0] < upper[0];
            if !inside {
                ok = false;
                p.push(Error::range(
                    l,
                    "geometry.center[0]",
                    center[0],
                    &format!(
                        "{} < x < {} (the outlet's centre inside the box)",
                        lower[0], upper[0]
                    ),
                ));
            }
            let oz = match g.outlet_z {
                Some(v) if v.is_finite() && v > lower[z] && v < upper[z] => Some(v),
                Some(v) => {
                    p.push(Error::range(
                        l,
                        "geometry.outlet_z",
                        v,
                        &format!("{} < outlet_z < {} [m]", lower[z], upper[z]),
                    ));
                    None
                }
                None => {
                    p.push(Error::at(l, "geometry.outlet_z", format!("required with geometry.shape = \"hopper\": allowed {} < outlet_z < {} [m]", lower[z], upper[z])));
                    None
                }
            };
            let width = positive(p, l, "geometry.outlet_width", g.outlet_width, "hopper");
            // the room for the outlet is measured from the centre: none to report (a second,
            // nonsensical line) when the centre is refused above
            if let Some(w) = width.filter(|_| inside) {
                let room_x = (center[0] - lower[0]).min(upper[0] - center[0]);
                if w / 2.0 >= room_x || w < h_min {
                    ok = false;
                    p.push(Error::range(
                        l,
                        "geometry.outlet_width",
                        w,
                        &format!(
                            "one cell = {h_min} <= outlet_width < {} [m] (inside the box)",
                            2.0 * room_x
                        ),
                    ));
                }
            }
            let angle = match g.hopper_angle {
                Some(a) if a.is_finite() && a > 0.0 && a < 90.0 => Some(a.to_radians()),
                Some(a) => {
                    p.push(Error::range(
                        l,
                        "geometry.hopper_angle",
                        a,
                        "0 < hopper_angle < 90 [deg] from the vertical",
                    ));
                    None
                }
                None => {
                    p.push(Error::at(l, "geometry.hopper_angle", "required with geometry.shape = \"hopper\": allowed 0 < hopper_angle < 90 [deg] from the vertical"));
                    None
                }
            };
            match (oz, width, angle) {
                (Some(oz), Some(w), Some(a)) => {
                    geo.outlet = (oz, w / 2.0);
                    geo.angle = a;
                }
                _ => ok = false,
            }
        }
    }
    ok.then_some(geo)
}
