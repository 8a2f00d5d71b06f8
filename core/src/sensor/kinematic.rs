//! A velocity source for a silo with no camera: the Nedderman-Tuzun kinematic model, scaled
//! by the measured discharge rate (issue 9, "The soft sensor on the silo").
//!
//! In a flat-bottomed silo the downward velocity v(x, z) (z up from the orifice) obeys
//! `dv/dz = B d2v/dx2` with B the kinematic constant (about 2-3 grain diameters) and zero flux
//! through the walls (`dv/dx = 0` at x = 0 and x = L); the horizontal velocity is
//! `u = B dv/dx` (towards the orifice) (Nedderman & Tuzun 1979). With the orifice
//! `[a, b]` as the source, `v(x, 0) = Q/(b - a)` on it and 0 beside it, the solution is the
//! cosine series
//!
//! ```text
//! v(x, z) = Q/L + sum_{n >= 1} A_n cos(k_n x) exp(-B k_n^2 z),   k_n = n pi / L,
//! A_n = 2 Q (sin(k_n b) - sin(k_n a)) / (k_n L (b - a))
//! ```
//!
//! whose mean over the width is `Q/L` at every height: the bulk flux through every level is
//! the orifice's Q exactly (mass balance, the n = 0 term alone). Q is the bulk volume flux per
//! unit depth, from a load cell's mass rate: `Q = mdot / (rho_s c depth)`.
//!
//! The shape depends on the geometry only; the rate scales it. [`Kinematic::new`] evaluates
//! the shape at the sensor points once (`MAX_TERMS` cosines and exponentials per point, f64
//! through libm, the same bits everywhere), and [`Kinematic::frame`] multiplies it by Q: a
//! frame costs two multiplications per value. Fixed capacity, no allocation.

use super::frame::VelocityFrame;
use super::{MAX_FRAME_VALUES, MAX_SENSOR_SIDE};

/// Cosine terms of the series. The slowest-decaying neglected term at height z is
/// `exp(-B (MAX_TERMS pi / L)^2 z)`: below 1e-6 of the mean once `z > 14 L^2 / (B (MAX_TERMS
/// pi)^2)`, about 1.6 mm for L = 0.15 m and B = 3 mm; the sensor's first row is higher.
pub const MAX_TERMS: usize = 256;

/// Why a kinematic source cannot be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KinematicError {
    /// The width, height or B is not finite and positive, or the sensor grid is empty or
    /// larger than 16 x 16.
    Geometry,
    /// The orifice is not a non-empty part of `[0, L]`.
    Orifice,
    /// The density, c or depth of the mass-to-volume conversion is not finite and positive.
    Material,
}

/// The Nedderman-Tuzun velocity of a flat-bottomed silo on a sensor grid, per unit bulk flux.
#[derive(Clone, Debug)]
pub struct Kinematic {
    /// Sensor points per axis (centres of a grid over `[0, L] x [0, H]`, x fastest).
    n: [u8; 2],
    /// `(u_x, u_z)` per sensor point for a bulk flux Q = 1 m^2/s, interleaved.
    shape: [f32; MAX_FRAME_VALUES],
    /// `1 / (rho_s c depth)`: the bulk flux per unit depth of one kg/s.
    per_kg: f64,
}

impl Kinematic {
    /// The shape for a silo of width `width` and height `height` \[m\] (the box of the
    /// estimator), orifice `[lower, upper]` on the floor, kinematic constant `b` \[m\], on a
    /// sensor grid of `sensor` points; `density` [kg/m^3] of the grains, bulk `c` and `depth`
    /// \[m\] for the conversion of the load cell's mass rate.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        width: f64,
        height: f64,
        lower: f64,
        upper: f64,
        b: f64,
        sensor: [u8; 2],
        density: f64,
        c: f64,
        depth: f64,
    ) -> Result<Self, KinematicError> {
        let pos = |x: f64| x.is_finite() && x > 0.0;
        if !(pos(width) && pos(height) && pos(b))
            || sensor
                .iter()
                .any(|&s| s == 0 || s as usize > MAX_SENSOR_SIDE)
        {
            return Err(KinematicError::Geometry);
        }
        if !(lower.is_finite() && upper.is_finite() && 0.0 <= lower && lower < upper)
            || upper > width
        {
            return Err(KinematicError::Orifice);
        }
        if !(pos(density) && pos(c) && c <= 1.0 && pos(depth)) {
            return Err(KinematicError::Material);
        }
        let (nx, nz) = (sensor[0] as usize, sensor[1] as usize);
        let mut shape = [0.0f32; MAX_FRAME_VALUES];
        for iz in 0..nz {
            let z = (iz as f64 + 0.5) * height / nz as f64;
            for ix in 0..nx {
                let x = (ix as f64 + 0.5) * width / nx as f64;
                let (v, dv) = series(x, z, width, lower, upper, b);
                let at = 2 * (ix + nx * iz);
                shape[at] = (b * dv) as f32;
                shape[at + 1] = -v as f32;
            }
        }
        Ok(Self {
            n: sensor,
            shape,
            per_kg: 1.0 / (density * c * depth),
        })
    }

    /// The bulk volume flux per unit depth [m^2/s] of a load cell's mass rate [kg/s].
    pub fn bulk_flux(&self, mass_rate: f64) -> f64 {
        mass_rate * self.per_kg
    }

    /// The frame of a bulk flux `q` [m^2/s per unit depth] (e.g. [`Self::bulk_flux`]).
    pub fn frame(&self, seq: u32, time: f32, period: f32, q: f64) -> VelocityFrame {
        let m = 2 * self.n[0] as usize * self.n[1] as usize;
        let mut u = heapless::Vec::new();
        for &s in &self.shape[..m] {
            // At most MAX_FRAME_VALUES values: cannot overflow.
            let _ = u.push((s as f64 * q) as f32);
        }
        VelocityFrame {
            seq,
            time,
            period,
            nx: self.n[0],
            nz: self.n[1],
            u,
        }
    }
}

/// `(v, dv/dx)` of the series at `(x, z)` for Q = 1, width `l`, orifice `[a, b0]`, constant
/// `b`. Terms are summed from n = 1 up in a fixed order; a term below 1e-18 of the mean ends
/// the sum (the rest decays faster still).
pub fn series(x: f64, z: f64, l: f64, a: f64, b0: f64, b: f64) -> (f64, f64) {
    let pi = core::f64::consts::PI;
    let w = b0 - a;
    let mut v = 1.0 / l;
    let mut dv = 0.0;
    for n in 1..=MAX_TERMS {
        let k = n as f64 * pi / l;
        let decay = libm::exp(-b * k * k * z);
        if decay < 1e-18 {
            break;
        }
        let an = 2.0 * (libm::sin(k * b0) - libm::sin(k * a)) / (k * l * w);
        v += an * libm::cos(k * x) * decay;
        dv -= an * k * libm::sin(k * x) * decay;
    }
    (v, dv)
}
