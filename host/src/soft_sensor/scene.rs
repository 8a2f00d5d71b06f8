//! The two legacy recorder scenes: fixed, hand-written prescribed flows with the ground-truth
//! simulation (the core solver on the truth grid with the exact velocity, T from the shear)
//! and the sensor configuration that goes with them. They predate the host's scene catalogue
//! and are kept under names of their own (`idealised-shear-cell`, `gray-thornton-sensor`) so
//! they cannot be confused with the catalogue's `shear-cell` (the flow shear cell) and
//! `gray-thornton-shear`; firmware-sim's recording `shear-cell.rec` is the first of them
//! (its stored scene name stays `shear-cell` so the file is reproduced byte for byte). Every
//! other scene is recorded by [`super::catalogue`].

use sieve_core::sensor::{CycleBudget, Region, SensorConfig};
use sieve_core::{
    Boundary, DirectionMode, Grid, Phase, Real, Scheme, Segregation, SegregationConfig,
    TemperatureMode,
};

/// Capacity of the truth solver (up to 64 x 64 cells).
pub const TRUTH_CAPACITY: usize = 4096;

/// Truth solver type: f64, boxed by the caller (it is about 400 KiB).
pub type Truth = Segregation<f64, 2, TRUTH_CAPACITY>;

/// Heating prefactor a, eta0 and eps0 of the glass beads of model.md 7.4 (T from shear).
const HEATING: f64 = 1.5;
const ETA0: f64 = 1.3e-4;
const EPS0: f64 = 1477.15;
const G: f64 = 9.81;

/// The legacy recorder scenes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scene {
    /// Idealised shear cell (model.md 7.3): 0.025 m box, periodic x, walls in z, c = 0.64,
    /// `u_x = 0.0007 + 0.0048 z / 0.025`, |S| = 0.025 m/s, mixed start (phihat 0.5).
    ShearCell,
    /// Gray–Thornton simple shear (model.md 7.2): x in [0, 2] downstream, z in [0, 1],
    /// `u_x = 2 z`, c = 0.64, inflow phihat 0.6 at x = 0, free outflow at x = 2, walls in z,
    /// |S| = 0.5, mixed start (phihat 0.6).
    GrayThornton,
}

impl Scene {
    /// Both legacy scenes.
    pub const ALL: [Scene; 2] = [Scene::ShearCell, Scene::GrayThornton];

    /// Name stored in recordings. `shear-cell` for the idealised shear cell: the name
    /// firmware-sim's committed recording carries (changing it would change those bytes).
    pub fn name(self) -> &'static str {
        match self {
            Scene::ShearCell => "shear-cell",
            Scene::GrayThornton => "gray-thornton-sensor",
        }
    }

    /// Name on the command line (`sieve record NAME`), distinct from every catalogue scene.
    pub fn cli_name(self) -> &'static str {
        match self {
            Scene::ShearCell => "idealised-shear-cell",
            Scene::GrayThornton => "gray-thornton-sensor",
        }
    }

    /// Parses a command-line name (as printed by [`Scene::cli_name`]).
    pub fn from_name(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|sc| sc.cli_name() == s)
    }

    /// Box size (x, z) \[m\].
    pub fn extent(self) -> [f64; 2] {
        match self {
            Scene::ShearCell => [0.025, 0.025],
            Scene::GrayThornton => [2.0, 1.0],
        }
    }

    /// The prescribed velocity at a point.
    pub fn velocity(self, _x: f64, z: f64) -> [f64; 2] {
        match self {
            Scene::ShearCell => [0.0007 + 0.0048 * z / 0.025, 0.0],
            Scene::GrayThornton => [2.0 * z, 0.0],
        }
    }

    /// Largest speed (the reference of the relative noise level).
    pub fn max_speed(self) -> f64 {
        match self {
            Scene::ShearCell => 0.0055,
            Scene::GrayThornton => 2.0,
        }
    }

    /// Uniform shear rate of the prescribed flow [1/s].
    fn shear_rate(self) -> f64 {
        match self {
            Scene::ShearCell => 0.0048 / 0.025,
            Scene::GrayThornton => 2.0,
        }
    }

    /// Target segregation speed |S| [m/s].
    fn segregation_speed(self) -> f64 {
        match self {
            Scene::ShearCell => 0.025,
            Scene::GrayThornton => 0.5,
        }
    }

    /// S0 such that `S0 sqrt(T) |g| = |S|` with `T = a eta0/eps0 gammadot^2`.
    pub fn s0(self) -> f64 {
        let sqrt_t = (HEATING * ETA0 / EPS0).sqrt() * self.shear_rate();
        self.segregation_speed() / (sqrt_t * G)
    }

    /// Boundaries.
    pub fn boundaries(self) -> [[Boundary; 2]; 2] {
        match self {
            Scene::ShearCell => [
                [Boundary::Periodic, Boundary::Periodic],
                [Boundary::Wall, Boundary::Wall],
            ],
            Scene::GrayThornton => [
                [Boundary::Inflow, Boundary::Outflow],
                [Boundary::Wall, Boundary::Wall],
            ],
        }
    }

    /// Initial (and inflow) phihat.
    pub fn initial_phihat(self) -> f64 {
        match self {
            Scene::ShearCell => 0.5,
            Scene::GrayThornton => 0.6,
        }
    }

    /// Default frame period \[s\] (one stable substep of a 32 x 32 estimator in the clean case).
    pub fn default_period(self) -> f64 {
        0.01
    }

    /// Default number of frames (long enough to segregate / reach the steady state).
    pub fn default_frames(self) -> u32 {
        match self {
            Scene::ShearCell => 150,
            Scene::GrayThornton => 300,
        }
    }

    /// The sensor configuration for an estimator of `cells` and a sensor grid of `sensor`
    /// points, with input handling tuned to the noise level `noise` (relative to the largest
    /// speed) and the frame `period`.
    pub fn sensor_config(
        self,
        cells: [u16; 2],
        sensor: [u8; 2],
        noise: f64,
        period: f64,
        budget: CycleBudget,
    ) -> SensorConfig<f32> {
        let e = self.extent();
        let umax = self.max_speed();
        let sigma = noise * umax;
        // A linear profile differs from its neighbourhood median by up to one sensor spacing
        // times the shear rate at the walls; spikes beyond that plus 6 sigma are outliers.
        let profile_step = self.shear_rate() * e[1] / sensor[1] as f64;
        let (nx, nz) = (cells[0], cells[1]);
        let q = (nz / 4).max(1);
        let (regions, outlet) = match self {
            Scene::ShearCell => (
                vec![
                    Region::new("bottom", [0, 0], [nx, q]),
                    Region::new("top", [0, nz - q], [nx, nz]),
                ],
                None,
            ),
            Scene::GrayThornton => (
                vec![
                    Region::new("outlet", [nx - 1, 0], [nx, nz]),
                    Region::new("bottom", [0, 0], [nx, q]),
                    Region::new("top", [0, nz - q], [nx, nz]),
                ],
                Some(0),
            ),
        };
        let f = |x: f64| x as f32;
        let mut cfg = SensorConfig {
            cells,
            extent: [f(e[0]), f(e[1])],
            bc: self.boundaries(),
            sensor,
            s0: f(self.s0()),
            eta0: f(ETA0),
            eps0: f(EPS0),
            heating: f(HEATING),
            gravity: [0.0, f(-G)],
            c: 0.64,
            fill_level: f(e[1]),
            initial_phihat: f(self.initial_phihat()),
            inflow_phihat: f(self.initial_phihat()),
            diffusion: 0.0,
            courant: 0.5,
            tick_period: f(period),
            max_period_factor: 2.0,
            budget,
            hold_ticks: 5,
            reject_speed: f(3.0 * umax),
            outlier_tol: f(6.0 * sigma + profile_step + 1e-3 * umax),
            // Smoothing only when there is noise to average. The EMA lags a change of the flow
            // by about 1/smoothing = 50 frames (0.5 s): right for these steady flows, to be
            // shortened for flows that change faster. Tuned on the accuracy table (README):
            // noise in u_z advects phi directly and noise in the gradient inflates T.
            smoothing: if noise > 0.0 { 0.02 } else { 1.0 },
            spatial_passes: if noise > 0.0 { 2 } else { 0 },
            track_large: false,
            regions: Default::default(),
            outlet,
            psi_alarm: 0.3,
            fines_band: [0.4, 0.8],
            fines_hysteresis: 0.01,
            alarm_persist: 3,
            openings: Default::default(),
            outflow_window: 10,
            noise_term: 0.0,
        };
        for r in regions {
            // At most MAX_REGIONS (4) are defined above.
            let _ = cfg.regions.push(r);
        }
        cfg
    }

    /// The truth solver on a `cells` grid with the exact velocity, in its initial state.
    pub fn truth(self, cells: [u16; 2]) -> Result<Box<Truth>, String> {
        let e = self.extent();
        let grid = Grid::new(
            [cells[0] as usize, cells[1] as usize],
            [0.0; 2],
            e,
            TRUTH_CAPACITY,
        )
        .map_err(|err| format!("truth grid: {err}"))?;
        let cfg = SegregationConfig {
            scheme: Scheme::Modified,
            phase: Phase::Small,
            s0: self.s0(),
            gravity: [0.0, -G],
            direction: DirectionMode::Flow,
            temperature: TemperatureMode::FromShear {
                heating: HEATING,
                eta0: ETA0,
                eps0: EPS0,
            },
            diffusion: 0.0,
            courant: 0.5,
            vacuum: f64::VACUUM,
            compensated: false,
            flush_below: f64::FLUSH_BELOW,
        };
        let mut t: Box<Truth> = Box::default();
        t.setup(grid, self.boundaries(), cfg)
            .map_err(|err| format!("truth setup: {err}"))?;
        let c = 0.64;
        let ph = self.initial_phihat();
        for i in 0..grid.len() {
            let x = grid.center(i);
            t.set_cell(i, c, 0.0, self.velocity(x[0], x[1]), ph * c);
            t.set_inflow(i, ph * c);
        }
        t.prepare().map_err(|err| format!("truth prepare: {err}"))?;
        Ok(t)
    }
}

/// Psi (docs/model.md 6) of a truth on an `nf` grid seen at the resolution of an `nc` grid
/// over the same box: phi and c averaged onto the `nc` cells by the overlap of each fine
/// cell with each coarse one (exact for any ratio), then the core's sums of those averages
/// (the entropy over cells with `c > vacuum`, the amounts over all). It is what an estimator
/// on `nc` cells can be held to: Psi of a sharp interface depends on the cells it is
/// measured in (docs/soft-sensor.md, "How much of the 0.063").
pub fn psi_on_grid(
    phi: impl Fn(usize) -> f64,
    c: impl Fn(usize) -> f64,
    nf: [usize; 2],
    nc: [usize; 2],
    vacuum: f64,
) -> f64 {
    // Per axis: (coarse cell, weight) of fine cell i; the weight is the overlap over the
    // coarse cell's length, in units of 1 / (nf nc) of the box.
    let overlaps = |a: usize| -> Vec<Vec<(usize, f64)>> {
        let (nfa, nca) = (nf[a], nc[a]);
        (0..nfa)
            .map(|i| {
                let (lo, hi) = (i * nca, (i + 1) * nca);
                (lo / nfa..=(hi - 1) / nfa)
                    .filter_map(|k| {
                        let o = hi.min((k + 1) * nfa) - lo.max(k * nfa);
                        (o > 0).then(|| (k, o as f64 / nfa as f64))
                    })
                    .collect()
            })
            .collect()
    };
    let (ox, oz) = (overlaps(0), overlaps(1));
    let mut ps = vec![0.0; nc[0] * nc[1]];
    let mut cs = vec![0.0; nc[0] * nc[1]];
    for iz in 0..nf[1] {
        for ix in 0..nf[0] {
            let i = ix + nf[0] * iz;
            let (p, ci) = (phi(i), c(i));
            for &(kz, wz) in &oz[iz] {
                for &(kx, wx) in &ox[ix] {
                    let k = kx + nc[0] * kz;
                    ps[k] += wx * wz * p;
                    cs[k] += wx * wz * ci;
                }
            }
        }
    }
    let entropy: f64 = ps
        .iter()
        .zip(&cs)
        .map(|(&p, &ci)| sieve_core::entropy_term(p, ci, vacuum))
        .sum();
    let (small, total): (f64, f64) = (ps.iter().sum(), cs.iter().sum());
    let mixed = if total > 0.0 {
        sieve_core::diagnostics::mixing_entropy_density(small / total) * total
    } else {
        0.0
    };
    if mixed > 0.0 {
        entropy / mixed
    } else {
        0.0
    }
}

/// Averages a per-cell field of an `nf` grid onto an `nc` grid (each fine cell goes to the
/// coarse cell containing its centre).
pub fn coarsen(field: impl Fn(usize) -> f64, nf: [usize; 2], nc: [usize; 2]) -> Vec<f64> {
    let mut sum = vec![0.0; nc[0] * nc[1]];
    let mut cnt = vec![0u32; nc[0] * nc[1]];
    for iz in 0..nf[1] {
        for ix in 0..nf[0] {
            let cx = ix * nc[0] / nf[0];
            let cz = iz * nc[1] / nf[1];
            sum[cx + nc[0] * cz] += field(ix + nf[0] * iz);
            cnt[cx + nc[0] * cz] += 1;
        }
    }
    sum.iter()
        .zip(&cnt)
        .map(|(s, &n)| if n > 0 { s / n as f64 } else { 0.0 })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Psi of a field with a sharp interface (`phihat` 1 below `z < edge`, 0 above) on an
    /// `nf` grid with c = 0.6, seen on `nc` cells.
    fn layered(nf: [usize; 2], nc: [usize; 2], edge: f64) -> f64 {
        let phi = |i: usize| {
            let z = ((i / nf[0]) as f64 + 0.5) / nf[1] as f64;
            if z < edge {
                0.6
            } else {
                0.0
            }
        };
        psi_on_grid(phi, |_| 0.6, nf, nc, 1e-6)
    }

    #[test]
    fn psi_on_grid_sees_an_interface_at_the_coarse_resolution() {
        // the same grid: a fully segregated field has Psi 0, a mixed one 1
        assert_eq!(layered([8, 8], [8, 8], 0.5), 0.0);
        let mixed = psi_on_grid(|_| 0.3, |_| 0.6, [8, 8], [8, 8], 1e-6);
        assert!((mixed - 1.0).abs() < 1e-12, "{mixed}");
        // an interface on a coarse face stays sharp; one inside a coarse cell is mixed
        // there: 40 fine rows, the edge after row 20 (a face of 4 coarse rows) or row 15
        assert_eq!(layered([10, 40], [5, 4], 0.5), 0.0);
        let inside = layered([10, 40], [5, 4], 15.0 / 40.0);
        // the coarse row 10..20 holds 5 of 10 fine rows of fines: phihat 1/2 in a quarter
        // of the box, Psi = (1/4 e(1/2)) / e(3/8)
        let e = |h: f64| -h * h.ln() - (1.0 - h) * (1.0 - h).ln();
        let want = 0.25 * e(0.5) / e(0.375);
        assert!((inside - want).abs() < 1e-12, "{inside} vs {want}");
        // a ratio that is not an integer (200 -> 32 and 100 -> 32, as the catalogue's
        // gray-thornton-shear): the overlaps keep the amounts, so a uniform field stays at 1
        let uniform = psi_on_grid(|_| 0.15, |_| 0.6, [200, 100], [32, 32], 1e-6);
        assert!((uniform - 1.0).abs() < 1e-12, "{uniform}");
        // and an interface at z = 0.5 (a coarse face of 32 rows at 16) stays sharp
        assert!(layered([20, 100], [4, 32], 0.5) < 1e-12);
    }
}
