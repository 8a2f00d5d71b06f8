//! Noise in the measured shear (docs/soft-sensor.md "Noise in the measured shear").
//!
//! The estimator derives T from `kappa : kappa` of the measured velocity (model.md 2.3). Noise
//! of variance `sigma^2` in every frame adds, on average, `G sigma_f^2` to `kappa : kappa`,
//! where `sigma_f^2` is the variance the noise keeps after the filter (the EMA over frames
//! and the 1-2-1 passes) and `G` the gain of the bilinear map and the estimator's
//! differences. In a creeping bed that term is all there is, and it is far larger than the
//! bed's own shear (the frozen-flow shear cell at 5 % noise segregated twice too fast). The
//! estimator subtracts it, `T ~ max(kappa:kappa - G sigma_f^2, 0)`
//! ([`crate::Segregation::set_shear_noise`]).
//!
//! `sigma^2` is measured on every accepted frame after its outlier clean-up, before any
//! smoothing: the second difference `r = v_j - (v_{j-1} + v_{j+1}) / 2` along each sensor
//! axis vanishes on a linear profile and has variance `1.5 sigma^2` for white noise, so the
//! median of `r^2` over the frame, divided by `1.5` and by the median of chi-square with one
//! degree of freedom (0.45494), estimates `sigma^2`. The raw frame, not the filtered field:
//! there the noise is `1 / sqrt(e)` times larger against the flow's own curvature (`e` is
//! what the EMA leaves of a frame's noise variance, 0.01 at the shear cell's weight 0.02),
//! so shear bands and an orifice, whose residuals hold signal, stay a minority the median
//! ignores. The estimator keeps an EMA of these estimates and `e` itself (both in snapshots)
//! and subtracts `G e sigma^2`. Frame noise is taken as independent from frame to frame; noise
//! correlated in time is reduced less by the EMA than `e` says, so the term then falls short
//! (an under-correction: T as without it), never beyond.
//!
//! `G` is an exact sum over the filter's and the map's linear weights, computed once by
//! [`NoiseModel::configure`] (the 1-2-1 passes run on unit impulses); the median is taken
//! from a histogram of quarter octaves (fixed memory, comparisons and integer bins only),
//! interpolated inside its bin.

use super::estimator::{axis_weights, smooth_121};
use super::{SensorReal, MAX_SENSOR_SIDE};

/// Quarter octaves per octave of the histogram.
const SUB: usize = 4;
/// Octaves below 16 (the largest normalised residual kept apart; larger ones share the top
/// bin): 2^-44 of the largest squared speed is below any noise an f32 frame carries.
const OCTAVES: usize = 48;
const BINS: usize = SUB * OCTAVES;
/// Median of the chi-square distribution with one degree of freedom.
const CHI2_1_MEDIAN: f64 = 0.454_936_423_119_572_7;

/// The filter's and the map's noise gain of one sensor configuration.
#[derive(Clone, Copy, Debug)]
pub(super) struct NoiseModel<R> {
    /// Mean over the estimator cells of `kappa : kappa` per unit noise variance of the
    /// smoothed sensor field's input (both velocity components): `2 (A_x B_z + B_x A_z)`.
    kk_gain: R,
}

/// What unit white noise on the nodes of one sensor axis becomes over the estimator cells:
/// the mean variance of the mapped value (`B`) and of its difference quotient (`A`).
struct AxisFactors<R> {
    value: R,
    slope: R,
}

fn axis_factors<R: SensorReal>(
    ns: usize,
    ne: usize,
    periodic: bool,
    passes: u8,
    h: R,
) -> AxisFactors<R> {
    let mut f = AxisFactors {
        value: R::ZERO,
        slope: R::ZERO,
    };
    // The mapped value of cell `i` for the smoothed impulse `col` (interleaved, component 0).
    let mapped = |col: &[R], i: usize| {
        let (x0, x1, t) = axis_weights::<R>(i, ne, ns, periodic);
        col[2 * x0] + t * (col[2 * x1] - col[2 * x0])
    };
    for k in 0..ns {
        // The column k of the smoothing: the filter run on a unit impulse at node k.
        let mut col = [R::ZERO; 2 * MAX_SENSOR_SIDE];
        col[2 * k] = R::ONE;
        for _ in 0..passes {
            smooth_121(&mut col[..2 * ns], [ns, 1], 0, periodic);
        }
        for i in 0..ne {
            let v = mapped(&col, i);
            f.value += v * v;
            if ne >= 2 {
                // The estimator's difference quotient of cell i (`velocity_gradient_at`).
                let (lo, hi, width) = if i > 0 && i + 1 < ne {
                    (i - 1, i + 1, R::TWO)
                } else if periodic {
                    ((i + ne - 1) % ne, (i + 1) % ne, R::TWO)
                } else if i == 0 {
                    (0, 1, R::ONE)
                } else {
                    (i - 1, i, R::ONE)
                };
                let d = (mapped(&col, hi) - mapped(&col, lo)) / (width * h);
                f.slope += d * d;
            }
        }
    }
    let n = R::from_u32(ne as u32);
    f.value = f.value / n;
    f.slope = f.slope / n;
    f
}

impl<R: SensorReal> NoiseModel<R> {
    /// No correction (an unconfigured sensor).
    pub(super) const fn zeroed() -> Self {
        Self { kk_gain: R::ZERO }
    }

    /// The gain of a sensor grid `ns`, an estimator grid `ne` with spacings `h`, the periodic
    /// axes and the filter's passes.
    pub(super) fn configure(
        ns: [usize; 2],
        ne: [usize; 2],
        periodic: [bool; 2],
        passes: u8,
        h: [R; 2],
    ) -> Self {
        let x = axis_factors::<R>(ns[0], ne[0], periodic[0], passes, h[0]);
        let z = axis_factors::<R>(ns[1], ne[1], periodic[1], passes, h[1]);
        Self {
            kk_gain: R::TWO * (x.slope * z.value + x.value * z.slope),
        }
    }

    /// The expected `kappa : kappa` that noise of variance `variance` on the sensor field's
    /// input gives the estimator's gradients after the 1-2-1 passes and the map.
    pub(super) fn shear_noise(&self, variance: R) -> R {
        variance * self.kk_gain
    }
}

/// The noise variance of one cleaned, unsmoothed frame `v` (interleaved, x fastest, `ns`
/// points): the bias-corrected median of the squared second differences over 1.5 (module
/// docs); 0 without interior points or on a frame at rest.
pub(super) fn frame_variance<R: SensorReal>(v: &[R], ns: [usize; 2]) -> R {
    let (nx, nz) = (ns[0], ns[1]);
    let mut vmax = R::ZERO;
    for &x in &v[..2 * nx * nz] {
        vmax = vmax.max(x.abs());
    }
    if !(vmax > R::ZERO && vmax.is_finite()) {
        return R::ZERO;
    }
    let scale = R::ONE / (vmax * vmax);
    let mut hist = [0u16; BINS];
    let mut count = 0u32;
    let at = |x: usize, z: usize, c: usize| v[2 * (x + nx * z) + c];
    for z in 0..nz {
        for x in 0..nx {
            for c in 0..2 {
                let here = at(x, z, c);
                if x >= 1 && x + 1 < nx {
                    let r = here - R::HALF * (at(x - 1, z, c) + at(x + 1, z, c));
                    hist[bin(r * r * scale)] += 1;
                    count += 1;
                }
                if z >= 1 && z + 1 < nz {
                    let r = here - R::HALF * (at(x, z - 1, c) + at(x, z + 1, c));
                    hist[bin(r * r * scale)] += 1;
                    count += 1;
                }
            }
        }
    }
    if count == 0 {
        return R::ZERO;
    }
    // The bin holding the median, the sample of rank (count - 1) / 2 (0-based; halfway
    // between the two middle ones for an even count), interpolated inside the bin with each
    // sample at the middle of its share of the bin's counts.
    let twice = count - 1; // twice the median's rank
    let mut below = 0u32;
    let mut b = 0;
    while 2 * (below + u32::from(hist[b])) <= twice && b + 1 < BINS {
        below += u32::from(hist[b]);
        b += 1;
    }
    let frac = R::from_u32((twice + 1).saturating_sub(2 * below))
        / R::from_u32(2 * u32::from(hist[b]).max(1));
    let (octave, sub) = (b / SUB, b % SUB);
    // 2^(octave - OCTAVES + 4), exactly.
    let base = R::from_f64(f64::from_bits(
        ((1023 + octave as u64 + 4) - OCTAVES as u64) << 52,
    ));
    let q = base * (R::ONE + (R::from_u32(sub as u32) + frac) / R::from_u32(SUB as u32));
    // The sample median of so skewed a distribution lies above the population's by about
    // 3 / count (simulated: 9 % for 32 residuals, 1 % for 256).
    let bias = R::ONE + R::from_u32(3) / R::from_u32(count);
    q * vmax * vmax / (R::from_f64(1.5 * CHI2_1_MEDIAN) * bias)
}

/// Quarter-octave bin of `q >= 0` (normalised by the largest squared speed): octave from the
/// binary exponent, quarter from the two leading mantissa bits; below range into bin 0,
/// above into the top bin.
fn bin<R: SensorReal>(q: R) -> usize {
    if q <= R::ZERO {
        return 0;
    }
    let (exp, quarter) = q.octave_quarter();
    let octave = exp + OCTAVES as i32 - 4;
    if octave < 0 {
        0
    } else if octave >= OCTAVES as i32 {
        BINS - 1
    } else {
        octave as usize * SUB + quarter as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bins_are_quarter_octaves() {
        // 1.0 is octave 0 of the normalised range, i.e. bin (OCTAVES - 4) * SUB.
        let one = (OCTAVES - 4) * SUB;
        assert_eq!(bin(1.0f64), one);
        assert_eq!(bin(1.24f64), one);
        assert_eq!(bin(1.25f64), one + 1);
        assert_eq!(bin(1.99f64), one + 3);
        assert_eq!(bin(2.0f64), one + 4);
        assert_eq!(bin(0.5f64), one - 4);
        assert_eq!(bin(0.0f64), 0);
        assert_eq!(bin(1e-30f64), 0);
        assert_eq!(bin(1e30f64), BINS - 1);
        // f32 bins the same values alike.
        for q in [1.0f32, 1.24, 1.25, 1.99, 2.0, 0.5, 3e-7, 0.0, 1e-30, 1e30] {
            assert_eq!(bin(q), bin(q as f64), "{q}");
        }
    }
}
