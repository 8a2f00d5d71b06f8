//! `[run]`: end time, output interval (at most 100,000 outputs), the Psi threshold of the
//! segregation time (model.md 6), and the closed-form comparison a scene may name
//! (`exact = "column-a"`, model.md 7.1a).

use super::{finite, Fields, Problems, Scene, Temperature};
use crate::error::{Error, Result};
use crate::scene::RunSpec;
use sieve_core::Boundary;

/// Validated `[run]`: `(t_end, output_interval, psi_threshold)`.
pub(super) fn check(p: &mut Problems, l: &str, r: &RunSpec) -> Option<(f64, f64, f64)> {
    let t_end = p.ok(finite(l, "run.t_end", r.t_end)).and_then(|t| {
        if t > 0.0 {
            Some(t)
        } else {
            p.push(Error::range(l, "run.t_end", t, "t_end > 0"));
            None
        }
    });
    let interval = p
        .ok(finite(l, "run.output_interval", r.output_interval))
        .and_then(|dt| {
            if dt > 0.0 {
                Some(dt)
            } else {
                p.push(Error::range(
                    l,
                    "run.output_interval",
                    dt,
                    "output_interval > 0",
                ));
                None
            }
        });
    if let (Some(t_end), Some(dt)) = (t_end, interval) {
        if t_end / dt > 100_000.0 {
            p.push(Error::range(
                l,
                "run.output_interval",
                dt,
                &format!(
                    "at most 100000 outputs: output_interval >= {}",
                    crate::text::approx(t_end / 1e5)
                ),
            ));
        }
    }
    let psi_threshold = p
        .ok(finite(l, "run.psi_threshold", r.psi_threshold))
        .and_then(|x| {
            if x > 0.0 && x < 1.0 {
                Some(x)
            } else {
                p.push(Error::range(
                    l,
                    "run.psi_threshold",
                    x,
                    "0 < psi_threshold < 1",
                ));
                None
            }
        });
    Some((t_end?, interval?, psi_threshold?))
}

/// Whether `[low, high]` is a fines band a scene may declare: `0 <= low < high <= 1` (NaN
/// fails). Also what `sieve plot` accepts from a summary.json.
pub fn fines_band_ok([lo, hi]: [f64; 2]) -> bool {
    0.0 <= lo && lo < hi && hi <= 1.0
}

/// Validated `run.fines_band` (`0 <= low < high <= 1`); None if absent (or wrong: the
/// problem is recorded).
pub(super) fn check_fines_band(p: &mut Problems, l: &str, r: &RunSpec) -> Option<[f64; 2]> {
    let [lo, hi] = r.fines_band?;
    if fines_band_ok([lo, hi]) {
        return Some([lo, hi]);
    }
    p.push(Error::at(
        l,
        "",
        format!(
            "run.fines_band = [{}, {}] is out of range: allowed [low, high] with \
             0 <= low < high <= 1, the fines fraction of the discharge that is on-spec",
            crate::text::approx(lo),
            crate::text::approx(hi)
        ),
    ));
    None
}

/// Longest allowed `run.checkpoint_interval` [s] (about 30 years).
pub const MAX_CHECKPOINT_INTERVAL: f64 = 1e9;

/// Validated `run.checkpoint_interval` (wall-clock seconds, `0 < x <= 1e9`); None if absent
/// (or wrong: the problem is recorded).
pub(super) fn check_checkpoint(p: &mut Problems, l: &str, r: &RunSpec) -> Option<f64> {
    let x = r.checkpoint_interval?;
    let max = MAX_CHECKPOINT_INTERVAL;
    if x.is_finite() && x > 0.0 && x <= max {
        Some(x)
    } else {
        p.push(Error::range(
            l,
            "run.checkpoint_interval",
            x,
            &format!("wall-clock seconds between checkpoints, 0 < checkpoint_interval <= {max:e} (omit it for no checkpoints)"),
        ));
        None
    }
}

impl Scene {
    /// The exact column-a solution needs a 1D wall-bounded column with constant c, T and
    /// phihat, no velocity and gravity pointing down.
    pub(super) fn check_column_a(&self) -> Result<()> {
        let bad = |why: &str| {
            Err(Error::at(
                &self.label,
                "run.exact",
                format!("\"column-a\" needs {why}"),
            ))
        };
        if self.dim != 1 {
            return bad("dim = 1");
        }
        if self.boundaries[0] != [Boundary::Wall; 2] {
            return bad("walls at both ends");
        }
        if !(self.gravity[0] < 0.0) {
            return bad("gravity < 0");
        }
        if self.temperature != Temperature::Given || self.diffusion != 0.0 {
            return bad("a given T and no diffusion");
        }
        let constants = [Some(&self.c), self.t.as_ref(), Some(&self.u[0])];
        if constants
            .iter()
            .any(|e| e.is_none_or(|e| e.constant().is_none()))
        {
            return bad("constant numbers for initial.c, initial.T and initial.u");
        }
        Ok(())
    }

    /// The exact column-a solution of this scene (see `Scene::check_column_a`).
    pub fn column_a(&self, fields: &Fields) -> Option<sieve_core::exact::ColumnA<f64>> {
        if self.exact != Some(crate::scene::ExactKind::ColumnA) {
            return None;
        }
        let t = fields.t[0];
        Some(sieve_core::exact::ColumnA {
            s: self.s0 * t.sqrt() * self.gravity[0].abs(),
            m: fields.phi[0] / fields.c[0],
            height: self.upper[0] - self.lower[0],
        })
    }
}
