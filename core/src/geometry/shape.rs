//! Solid shapes as signed distances, combined without allocation (issue 8, model.md 7.5).
//!
//! Convention: the signed distance is `< 0` in the OPEN region (where grains may be) and `> 0`
//! in the solid; a point at distance exactly 0 counts as open. A [`Region`] starts "all open"
//! and applies up to [`Region::CAPACITY`] `(Op, Primitive)` pairs left to right with min/max:
//! the result is not the exact Euclidean distance away from the surface, but its zero level
//! set is exact, which is all [`super::CutCells`] needs (it locates the zero crossings on the
//! cell edges).

use crate::real::Real;

/// One plane `{x : (x - point) . normal = 0}`; the half-space `(x - point) . normal <= 0` is
/// its inside (open side), `normal` points out of it (into the solid).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane<R, const D: usize> {
    /// A point on the plane.
    pub point: [R; D],
    /// The normal, pointing to the outside (unit after [`Primitive::normalized`]).
    pub normal: [R; D],
}

/// A convex polytope: the intersection of up to [`Convex::CAPACITY`] half-spaces (a slab, a
/// rotated square, a baffle plate).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Convex<R, const D: usize> {
    planes: [Plane<R, D>; 6],
    len: usize,
}

impl<R: Real, const D: usize> Convex<R, D> {
    /// Most half-spaces in one polytope.
    pub const CAPACITY: usize = 6;

    /// The polytope of the given planes; `None` if there are none or more than
    /// [`Self::CAPACITY`].
    pub fn new(planes: &[Plane<R, D>]) -> Option<Self> {
        if planes.is_empty() || planes.len() > Self::CAPACITY {
            return None;
        }
        let mut out = [Plane {
            point: [R::ZERO; D],
            normal: [R::ZERO; D],
        }; 6];
        out[..planes.len()].copy_from_slice(planes);
        Some(Self {
            planes: out,
            len: planes.len(),
        })
    }

    /// The planes.
    pub fn planes(&self) -> &[Plane<R, D>] {
        &self.planes[..self.len]
    }
}

/// A basic shape; its distance is negative inside it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Primitive<R, const D: usize> {
    /// A disc (2D), sphere (3D) or segment (1D).
    Ball {
        /// centre
        center: [R; D],
        /// radius
        radius: R,
    },
    /// In 3D an infinite circular cylinder along grid axis `axis` through `center`; in 1D
    /// and 2D the same as a [`Primitive::Ball`].
    Cylinder {
        /// a point on the axis
        center: [R; D],
        /// radius
        radius: R,
        /// grid axis the cylinder runs along (3D only)
        axis: usize,
    },
    /// `(x - point) . normal <= 0`; `normal` points into the outside and is normalised when
    /// the primitive enters a [`Region`].
    HalfSpace {
        /// a point on the bounding plane
        point: [R; D],
        /// outward normal
        normal: [R; D],
    },
    /// The intersection of up to six half-spaces.
    Convex(Convex<R, D>),
}

/// How a primitive combines with the region built so far.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Op {
    /// Open where both are open: `max(d, d_p)`.
    Intersect,
    /// Open where either is open: `min(d, d_p)`.
    Union,
    /// Open where the region is open and the primitive is not: `max(d, -d_p)`.
    Subtract,
}

fn dot<R: Real, const D: usize>(a: &[R; D], b: &[R; D]) -> R {
    let mut s = R::ZERO;
    for k in 0..D {
        s += a[k] * b[k];
    }
    s
}

fn normalized<R: Real, const D: usize>(v: [R; D]) -> [R; D] {
    let n = dot(&v, &v).sqrt();
    let mut out = v;
    if n > R::ZERO {
        out.iter_mut().for_each(|x| *x = *x / n);
    }
    out
}

fn plane_distance<R: Real, const D: usize>(p: &Plane<R, D>, x: &[R; D]) -> R {
    let mut s = R::ZERO;
    for k in 0..D {
        s += (x[k] - p.point[k]) * p.normal[k];
    }
    s
}

impl<R: Real, const D: usize> Primitive<R, D> {
    /// The same shape with unit plane normals (a zero normal stays zero).
    pub fn normalized(self) -> Self {
        match self {
            Primitive::HalfSpace { point, normal } => Primitive::HalfSpace {
                point,
                normal: normalized(normal),
            },
            Primitive::Convex(mut c) => {
                for p in c.planes[..c.len].iter_mut() {
                    p.normal = normalized(p.normal);
                }
                Primitive::Convex(c)
            }
            other => other,
        }
    }

    /// Signed distance: negative inside the shape (exact for balls, cylinders and half-spaces;
    /// for a polytope the largest plane distance, exact on its surface and inside).
    pub fn distance(&self, x: &[R; D]) -> R {
        match self {
            Primitive::Ball { center, radius } => {
                let mut s = R::ZERO;
                for k in 0..D {
                    let d = x[k] - center[k];
                    s += d * d;
                }
                s.sqrt() - *radius
            }
            Primitive::Cylinder {
                center,
                radius,
                axis,
            } => {
                let mut s = R::ZERO;
                for k in 0..D {
                    if D == 3 && k == *axis {
                        continue;
                    }
                    let d = x[k] - center[k];
                    s += d * d;
                }
                s.sqrt() - *radius
            }
            Primitive::HalfSpace { point, normal } => plane_distance(
                &Plane {
                    point: *point,
                    normal: *normal,
                },
                x,
            ),
            Primitive::Convex(c) => {
                let mut d = -R::MAX;
                for p in c.planes() {
                    d = d.max(plane_distance(p, x));
                }
                d
            }
        }
    }
}

/// Why a region cannot take another primitive.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RegionFull;

/// The open region: "all open", then up to eight `(Op, Primitive)` applied left to right.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Region<R, const D: usize> {
    ops: [(Op, Primitive<R, D>); 8],
    len: usize,
}

impl<R: Real, const D: usize> Default for Region<R, D> {
    fn default() -> Self {
        Self::new()
    }
}

impl<R: Real, const D: usize> Region<R, D> {
    /// Most primitives in one region.
    pub const CAPACITY: usize = 8;

    /// Everything open (no walls but the box).
    pub const fn new() -> Self {
        Self {
            ops: [(
                Op::Union,
                Primitive::Ball {
                    center: [R::ZERO; D],
                    radius: R::ZERO,
                },
            ); 8],
            len: 0,
        }
    }

    /// Appends `(op, primitive)` (normalised); fails when the region is full.
    pub fn push(&mut self, op: Op, primitive: Primitive<R, D>) -> Result<(), RegionFull> {
        if self.len == Self::CAPACITY {
            return Err(RegionFull);
        }
        self.ops[self.len] = (op, primitive.normalized());
        self.len += 1;
        Ok(())
    }

    /// Builder form of [`Self::push`]. Panics beyond [`Self::CAPACITY`] primitives (a
    /// programming error at set-up, never in a step).
    #[track_caller]
    pub fn with(mut self, op: Op, primitive: Primitive<R, D>) -> Self {
        self.push(op, primitive)
            .expect("Region holds at most 8 primitives");
        self
    }
    /// `self` intersected with `p`.
    #[track_caller]
    pub fn intersect(self, p: Primitive<R, D>) -> Self {
        self.with(Op::Intersect, p)
    }
    /// `self` united with `p`.
    #[track_caller]
    pub fn union(self, p: Primitive<R, D>) -> Self {
        self.with(Op::Union, p)
    }
    /// `self` minus `p` (p becomes solid).
    #[track_caller]
    pub fn subtract(self, p: Primitive<R, D>) -> Self {
        self.with(Op::Subtract, p)
    }

    /// The `(op, primitive)` list.
    pub fn ops(&self) -> &[(Op, Primitive<R, D>)] {
        &self.ops[..self.len]
    }

    /// True if no primitive was added (the whole box is open).
    pub fn is_all_open(&self) -> bool {
        self.len == 0
    }

    /// Signed distance of the region, `< 0` open, `> 0` solid; `-R::MAX` with no primitive.
    pub fn distance(&self, x: [R; D]) -> R {
        let mut d = -R::MAX;
        for (op, p) in self.ops() {
            let dp = p.distance(&x);
            d = match op {
                Op::Intersect => d.max(dp),
                Op::Union => d.min(dp),
                Op::Subtract => d.max(-dp),
            };
        }
        d
    }

    /// True where `distance(x) <= 0`.
    pub fn is_open(&self, x: [R; D]) -> bool {
        self.distance(x) <= R::ZERO
    }

    /// The longest open run on the segment from `x0` along axis `b` over `length >= 0`,
    /// as `(offset of its start from x0, its length)`; `(0, 0)` when the segment is solid.
    /// The segment is cut into `pieces` equal pieces (one per grid cell: a wall crosses each
    /// at most once, where it is located exactly as [`super::CutCells`] locates it on a cell
    /// edge). Measures the open width of an outlet under cut-cell walls (a hopper's orifice).
    pub fn longest_open_run(&self, x0: [R; D], b: usize, length: R, pieces: usize) -> (R, R) {
        let pieces = pieces.max(1);
        let step = length / R::from_usize(pieces);
        let at = |t: R| {
            let mut x = x0;
            x[b] = x0[b] + t;
            self.distance(x)
        };
        let (mut best, mut start, mut run) = ((R::ZERO, R::ZERO), R::ZERO, R::ZERO);
        let mut d0 = at(R::ZERO);
        for k in 0..pieces {
            let s0 = R::from_usize(k) * step;
            let d1 = at(R::from_usize(k + 1) * step);
            let (o0, o1) = (d0 <= R::ZERO, d1 <= R::ZERO);
            let cross = || {
                if d0 == R::ZERO {
                    R::ZERO
                } else {
                    root(|t| at(s0 + t * step), d0, d1) * step
                }
            };
            if o0 && o1 {
                if run == R::ZERO {
                    start = s0;
                }
                run += step;
            } else if o0 {
                if run == R::ZERO {
                    start = s0;
                }
                run += cross();
            } else if o1 {
                let t = cross();
                (start, run) = (s0 + t, step - t);
            }
            if run > best.1 {
                best = (start, run);
            }
            if !o1 {
                run = R::ZERO;
            }
            d0 = d1;
        }
        best
    }

    // ---- builders (the vertical is the last axis, the horizontal axis 0, as in the scenes) ----

    /// A circular drum: a disc in 2D; in 3D an infinite cylinder along y (axis 1), the drum
    /// axis of model.md 7.5 (horizontal, gravity along z). Cut it with half-spaces for end
    /// walls.
    pub fn drum(center: [R; D], radius: R) -> Self {
        Self::new().intersect(Primitive::Cylinder {
            center,
            radius,
            axis: if D == 3 { 1 } else { 0 },
        })
    }

    /// A square drum of half-width `half` about `center`, turned by `angle` (radians,
    /// counter-clockwise from +x towards +z) in the (x, z) plane; a prism along y in 3D.
    /// Panics if D < 2.
    pub fn square_drum(center: [R; D], half: R, angle: R) -> Self {
        assert!(D >= 2, "a square drum needs two dimensions");
        let (s, c) = (angle.sin(), angle.cos());
        let z = D - 1;
        let mut planes = [Plane {
            point: center,
            normal: [R::ZERO; D],
        }; 4];
        // the four outward normals: (c, s), (-s, c), (-c, -s), (s, -c)
        let dirs = [(c, s), (-s, c), (-c, -s), (s, -c)];
        for (p, (nx, nz)) in planes.iter_mut().zip(dirs) {
            p.normal[0] = nx;
            p.normal[z] = nz;
            p.point[0] = center[0] + half * nx;
            p.point[z] = center[z] + half * nz;
        }
        Self::new().intersect(Primitive::Convex(
            Convex::new(&planes).expect("four planes"),
        ))
    }

    /// A circular drum (see [`Self::drum`]) with one flat baffle: a plate of `thickness`
    /// standing on the wall at polar angle `angle` (radians, from +x towards +z, in the
    /// (x, z) plane) and reaching `length` into the drum.
    pub fn drum_with_baffle(center: [R; D], radius: R, angle: R, length: R, thickness: R) -> Self {
        Self::drum(center, radius).subtract(Primitive::Convex(Self::baffle(
            center, radius, angle, length, thickness,
        )))
    }

    /// The baffle plate of [`Self::drum_with_baffle`] as a polytope (three planes: two faces
    /// and the inner edge; the outer side is closed by the drum wall). Panics if D < 2.
    pub fn baffle(center: [R; D], radius: R, angle: R, length: R, thickness: R) -> Convex<R, D> {
        assert!(D >= 2, "a baffle needs two dimensions");
        let (s, c) = (angle.sin(), angle.cos());
        let z = D - 1;
        let w = thickness * R::HALF;
        let mut radial = [R::ZERO; D];
        radial[0] = c;
        radial[z] = s;
        let mut tangent = [R::ZERO; D];
        tangent[0] = -s;
        tangent[z] = c;
        let at = |r: R, t: R| {
            let mut p = center;
            p[0] += r * c - t * s;
            p[z] += r * s + t * c;
            p
        };
        let neg = |v: [R; D]| {
            let mut o = v;
            o.iter_mut().for_each(|x| *x = -*x);
            o
        };
        let planes = [
            Plane {
                point: at(radius - length, R::ZERO),
                normal: neg(radial),
            },
            Plane {
                point: at(radius, w),
                normal: tangent,
            },
            Plane {
                point: at(radius, -w),
                normal: neg(tangent),
            },
        ];
        Convex::new(&planes).expect("three planes")
    }

    /// A silo with a wedge hopper: open between the vertical walls `x_min <= x <= x_max` and
    /// above two walls inclined at `half_angle` (radians) from the vertical that end at the
    /// outlet, a gap of width `2 outlet_half_width` about `x_center` at height `outlet_z`;
    /// below the outlet a vertical channel of the same width runs down to the box (put an
    /// outflow boundary there). A wedge along y in 3D. Panics if D < 2.
    pub fn hopper(
        x_min: R,
        x_max: R,
        x_center: R,
        outlet_z: R,
        outlet_half_width: R,
        half_angle: R,
    ) -> Self {
        assert!(D >= 2, "a hopper needs two dimensions");
        let z = D - 1;
        let (s, c) = (half_angle.sin(), half_angle.cos());
        let plane = |px: R, pz: R, nx: R, nz: R| {
            let mut point = [R::ZERO; D];
            point[0] = px;
            point[z] = pz;
            let mut normal = [R::ZERO; D];
            normal[0] = nx;
            normal[z] = nz;
            Plane { point, normal }
        };
        let (xl, xr) = (x_center - outlet_half_width, x_center + outlet_half_width);
        let walls = [
            plane(x_min, outlet_z, -R::ONE, R::ZERO),
            plane(x_max, outlet_z, R::ONE, R::ZERO),
        ];
        // each solid wedge: below its inclined wall and outside the outlet channel; the wall
        // through the outlet edge rises at half_angle from the vertical, away from the axis
        let left = [
            plane(xl, outlet_z, c, s),
            plane(xl, outlet_z, R::ONE, R::ZERO),
        ];
        let right = [
            plane(xr, outlet_z, -c, s),
            plane(xr, outlet_z, -R::ONE, R::ZERO),
        ];
        Self::new()
            .intersect(Primitive::Convex(Convex::new(&walls).expect("two planes")))
            .subtract(Primitive::Convex(Convex::new(&left).expect("two planes")))
            .subtract(Primitive::Convex(Convex::new(&right).expect("two planes")))
    }
}

/// Root of `f` on `[0, 1]` with `f(0) = f0`, `f(1) = f1` on opposite sides of zero ("open"
/// meaning `<= 0`): Illinois regula falsi, exact in one step for a linear `f` (a half-space),
/// superlinear otherwise; stops when the estimate no longer moves.
pub(crate) fn root<R: Real>(f: impl Fn(R) -> R, f0: R, f1: R) -> R {
    let (mut a, mut fa, mut b, mut fb) = (R::ZERO, f0, R::ONE, f1);
    let mut side = 0i8;
    let mut t = (a * fb - b * fa) / (fb - fa);
    for _ in 0..100 {
        if !(t > a && t < b) {
            t = (a + b) * R::HALF;
        }
        let ft = f(t);
        if ft == R::ZERO {
            return t;
        }
        if (ft <= R::ZERO) == (fa <= R::ZERO) {
            a = t;
            fa = ft;
            if side == -1 {
                fb *= R::HALF;
            }
            side = -1;
        } else {
            b = t;
            fb = ft;
            if side == 1 {
                fa *= R::HALF;
            }
            side = 1;
        }
        let next = (a * fb - b * fa) / (fb - fa);
        if !(b - a > R::EPSILON) || next == t {
            return if next > a && next < b { next } else { t };
        }
        t = next;
    }
    t
}
