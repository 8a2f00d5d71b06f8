//! Frames of reference (model.md 2, "rotating container"; 7.5): the lab frame, or a frame
//! that turns with a rigid rotation, in which a drum and its grid are at rest and the body
//! forces change instead.
//!
//! In a frame rotating with angular velocity `omega` about an axis through `center`, the
//! momentum equation of model.md 2 gains, per unit volume fraction,
//! - the **rotating gravity** `g(t) = Rot(-omega t) g_lab`: a vector fixed in the lab turns
//!   backwards in the frame (the frames coincide at t = 0);
//! - the **centrifugal** acceleration `-Omega x (Omega x r) = omega^2 r_perp`, where `r_perp` is
//!   the part of `x - center` in the rotation plane: a potential force, so it enters the compact
//!   face forces beside gravity and a bed in relative equilibrium stays in exact discrete balance;
//! - the **Coriolis** acceleration `-2 Omega x u`: it turns the velocity in the rotation plane at
//!   the rate `2 omega` without changing its length. The flow applies it as the exact rotation
//!   of each cell's momentum by the angle `-2 omega dt` (not a forward-Euler increment, which
//!   would gain energy every step), so it puts no limit on the time step.
//!
//! The segregation driver sees gravity only (`g(t)`): percolation is driven by gravity in the
//! lab, and a change of frame must not change the physics.
//!
//! Orientation: the rotation plane is spanned by two grid axes `(p, q)`: `(0, 1)` in 2D (the
//! axis of rotation is normal to the plane); in 3D the rotation axis is the grid axis `axis` and
//! `(p, q)` follow cyclically (`axis = 1`: `(2, 0)`). `omega > 0` turns `p` towards `q`
//! (counter-clockwise in a 2D picture with x to the right and z up).

use crate::real::Real;

/// A rigid rotation: angular velocity, a point on the axis, and (3D) the grid axis it is
/// parallel to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rotation<R, const D: usize> {
    /// Angular velocity (rad/s); positive turns axis `p` towards axis `q` (module docs).
    pub omega: R,
    /// A point on the rotation axis (its coordinate along the axis is ignored).
    pub center: [R; D],
    /// The grid axis the rotation axis is parallel to (3D only; ignored in 2D).
    pub axis: usize,
}

/// Why a frame or rotation is not usable.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameError {
    /// Rotation needs two dimensions at least.
    Dimension,
    /// `omega` or `center` is not finite.
    NotFinite,
    /// The rotation axis is not a grid axis.
    Axis,
}

impl core::fmt::Display for FrameError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Dimension => write!(f, "a rotation needs a 2D or 3D grid"),
            Self::NotFinite => write!(f, "the rotation rate and centre must be finite numbers"),
            Self::Axis => write!(f, "the rotation axis must be 0 (x), 1 (y) or 2 (z)"),
        }
    }
}

impl<R: Real, const D: usize> Rotation<R, D> {
    /// A rotation at `omega` about an axis through `center` (parallel to grid axis `axis` in 3D).
    pub fn new(omega: R, center: [R; D], axis: usize) -> Result<Self, FrameError> {
        let r = Self {
            omega,
            center,
            axis,
        };
        r.validate()?;
        Ok(r)
    }

    /// Checks dimension, finiteness and the axis.
    pub fn validate(&self) -> Result<(), FrameError> {
        if D < 2 {
            return Err(FrameError::Dimension);
        }
        if !self.omega.is_finite() || self.center.iter().any(|x| !x.is_finite()) {
            return Err(FrameError::NotFinite);
        }
        if D == 3 && self.axis >= 3 {
            return Err(FrameError::Axis);
        }
        Ok(())
    }

    /// The grid axes `(p, q)` spanning the rotation plane (module docs).
    #[inline]
    pub fn plane(&self) -> (usize, usize) {
        if D == 3 {
            ((self.axis + 1) % 3, (self.axis + 2) % 3)
        } else {
            (0, 1)
        }
    }

    /// Whether grid axis `a` lies in the rotation plane.
    #[inline]
    pub fn in_plane(&self, a: usize) -> bool {
        let (p, q) = self.plane();
        a == p || a == q
    }

    /// Velocity of the rigid rotation at `x`: `Omega x (x - center)`.
    pub fn velocity(&self, x: [R; D]) -> [R; D] {
        let mut v = [R::ZERO; D];
        if D < 2 {
            return v;
        }
        let (p, q) = self.plane();
        v[p] = -self.omega * (x[q] - self.center[q]);
        v[q] = self.omega * (x[p] - self.center[p]);
        v
    }

    /// `v` turned by `angle` in the rotation plane (components along the axis unchanged).
    pub fn turn(&self, v: [R; D], angle: R) -> [R; D] {
        if D < 2 {
            return v;
        }
        let (s, c) = (angle.sin(), angle.cos());
        turn_by(v, self.plane(), s, c)
    }

    /// `x` turned by `angle` about the axis (positions: about `center`).
    pub fn turn_point(&self, x: [R; D], angle: R) -> [R; D] {
        let mut r = x;
        for a in 0..D {
            r[a] -= self.center[a];
        }
        let mut out = self.turn(r, angle);
        for a in 0..D {
            out[a] += self.center[a];
        }
        out
    }

    /// Centrifugal acceleration `omega^2 (x - center)_perp` along grid axis `a` at coordinate
    /// `xa` (it depends on that coordinate only).
    #[inline]
    pub fn centrifugal(&self, a: usize, xa: R) -> R {
        if self.in_plane(a) {
            self.omega * self.omega * (xa - self.center[a])
        } else {
            R::ZERO
        }
    }
}

/// `v` turned in the plane `(p, q)` by the angle whose sine and cosine are `s`, `c`.
#[inline]
pub fn turn_by<R: Real, const D: usize>(v: [R; D], (p, q): (usize, usize), s: R, c: R) -> [R; D] {
    let mut out = v;
    out[p] = c * v[p] - s * v[q];
    out[q] = s * v[p] + c * v[q];
    out
}

/// The frame the equations are solved in.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum Frame<R, const D: usize> {
    /// The lab frame: gravity fixed, no fictitious forces.
    #[default]
    Lab,
    /// A frame turning with the rotation: rotating gravity, centrifugal and Coriolis forces.
    Rotating(Rotation<R, D>),
}

impl<R: Real, const D: usize> Frame<R, D> {
    /// Gravity at time `t` as seen in this frame (`g_lab` in the lab frame).
    pub fn gravity(&self, g_lab: [R; D], t: R) -> [R; D] {
        match self {
            Frame::Lab => g_lab,
            Frame::Rotating(r) => r.turn(g_lab, -(r.omega * t)),
        }
    }

    /// The rotation of the frame, if it turns.
    pub fn rotation(&self) -> Option<&Rotation<R, D>> {
        match self {
            Frame::Lab => None,
            Frame::Rotating(r) => Some(r),
        }
    }

    /// Velocity, in this frame, of a wall that turns rigidly with `wall` in the lab (a drum
    /// shell): `(Omega_wall - Omega_frame) x (x - center)`. Zero for a drum in its own rotating
    /// frame. Both rotations must share the axis (checked by the caller's set-up).
    pub fn wall_velocity(&self, wall: &Rotation<R, D>, x: [R; D]) -> [R; D] {
        let mut rel = *wall;
        if let Frame::Rotating(r) = self {
            rel.omega = wall.omega - r.omega;
        }
        rel.velocity(x)
    }

    /// A point of this frame at time `t`, in lab coordinates (the frames coincide at t = 0):
    /// what a user compares across frames (e.g. the position of the fines core).
    pub fn to_lab(&self, x: [R; D], t: R) -> [R; D] {
        match self {
            Frame::Lab => x,
            Frame::Rotating(r) => r.turn_point(x, r.omega * t),
        }
    }

    /// A velocity of this frame at point `x` and time `t`, as a lab velocity at the lab point
    /// (turned, plus the frame's own velocity there).
    pub fn velocity_to_lab(&self, x: [R; D], u: [R; D], t: R) -> [R; D] {
        match self {
            Frame::Lab => u,
            Frame::Rotating(r) => {
                let xl = r.turn_point(x, r.omega * t);
                let ul = r.turn(u, r.omega * t);
                let vf = r.velocity(xl);
                let mut out = ul;
                for a in 0..D {
                    out[a] += vf[a];
                }
                out
            }
        }
    }
}
