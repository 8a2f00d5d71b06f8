//! Run guards (issue 10, "Never hang"): what a run will cost, estimated before it starts, and
//! refused (exit code 2) when it is absurd.
//!
//! * **Steps.** The explicit time step of model.md 5 (`dt = C / max rate`) is known once the
//!   solver is prepared; `t_end / dt` steps follow. `s0 = 1e12`, `|u| = 1e10`, `T = 1e300`,
//!   `diffusion = 1e300`, a `1e-12` grid or `t_end = 1e30` give 1e14..1e300 steps: a run that
//!   never ends and prints nothing. The first step is taken and timed, then the estimate is
//!   checked against [`Limits::max_steps`] and [`Limits::max_cell_steps`], and the message gives
//!   the hours at the rate just measured. For the flow (coupled scenes) the first step is
//!   usually the largest one (the bed starts at rest), so the estimate is a lower bound.
//! * **Output bytes.** Outputs x arrays x cells x 8 bytes (raw Float64 VTK) plus the CSV files,
//!   against [`Limits::max_output`] and the free space of the file system that receives DIR
//!   (a 512 x 512 run with `output_interval = 3e-5` wrote 8 GB in 30 s until the disk was full).
//!
//! The defaults are chosen so that every built-in scene at its default and at the grids the
//! README quotes runs untouched (the largest, `shear-cell --grid 80x80 --t-end 700`, is 1.1e5
//! steps and 7.1e8 cell-steps; the 25 s tumbler 2.3e5 steps and 2.7e8 cell-steps), while a run
//! that would take more than about half an hour of segregation stepping at the measured
//! 8e7 cell updates/s (or a day of coupled flow at ~1e6) is refused with the numbers.

use crate::error::{Error, Result};
use crate::scene::Scene;
use crate::text::num;
use std::path::Path;

pub use crate::scene::validate::limits::{Limits, MAX_CELL_STEPS, MAX_OUTPUT, MAX_STEPS};

/// Estimated steps of a run from its first stable time step: `t_end / dt` plus one shortened
/// step per output time. Non-finite or non-positive `dt` (a failed state: the NaN guard's
/// business) and `dt` above `t_end` give just the output steps.
pub fn steps(scene: &Scene, dt: f64) -> f64 {
    let outputs = (scene.t_end / scene.output_interval).ceil().max(1.0);
    if dt.is_finite() && dt > 0.0 {
        (scene.t_end / dt).ceil() + outputs
    } else {
        outputs
    }
}

/// Cell updates of `steps` steps on `cells` cells: `Ok` when within `limits.max_cell_steps`,
/// `Err` with the number when above it. The one comparison that `sieve run` ([`check_steps`])
/// and `sieve fit` refuse by; a NaN is refused too (it is not within any limit).
pub fn cell_steps(steps: f64, cells: usize, limits: &Limits) -> std::result::Result<f64, f64> {
    let n = steps * cells as f64;
    if n <= limits.max_cell_steps {
        Ok(n)
    } else {
        Err(n)
    }
}

/// Refuses a run whose first stable step `dt` asks for more steps or cell updates than the
/// scene's limits; `seconds_per_step` (the measured first step) turns the estimate into hours.
pub fn check_steps(scene: &Scene, dt: f64, seconds_per_step: f64) -> Result<()> {
    if dt == 0.0 {
        // A rate that overflowed (s0 = 1e308: S = inf) gives dt = C / inf = 0: zero-length
        // steps for ever.
        return Err(Error::at(
            &scene.label,
            "run.t_end",
            "the stable time step is 0 (a segregation, transport or diffusion rate overflowed): check material.s0, material.diffusion, initial.u, initial.T and grid.upper",
        ));
    }
    let n = steps(scene, dt);
    let cells = scene.len() as f64;
    let lim = scene.limits;
    // n is finite or +inf (t_end is finite and positive, dt too): no NaN reaches this
    let within = self::cell_steps(n, scene.len(), &lim);
    let cell_steps = within.unwrap_or_else(|n| n);
    let (flag, limit) = if n > lim.max_steps {
        ("--max-steps", lim.max_steps)
    } else if within.is_err() {
        ("--max-cell-steps", lim.max_cell_steps)
    } else {
        return Ok(());
    };
    let hours = n * seconds_per_step.max(0.0) / 3600.0;
    let rate = if seconds_per_step > 0.0 {
        format!(
            "~{} h at the measured {} cell updates/s",
            short(hours),
            short(cells / seconds_per_step)
        )
    } else {
        "too long to time".into()
    };
    Err(Error::at(
        &scene.label,
        "run.t_end",
        format!(
            "t_end = {} with a stable time step of {} would take {} steps ({} cell updates, {rate}), above {flag} = {}: {} (or check grid.upper, material.s0, material.diffusion, initial.u and initial.T, which set the time step)",
            num(scene.t_end),
            crate::text::approx(dt),
            short(n),
            short(cell_steps),
            num(limit),
            if lim.flags {
                format!("raise {flag} or shorten run.t_end")
            } else {
                format!("shorten run.t_end or use fewer cells (`sieve run` takes {flag} to raise the limit)")
            },
        ),
    ))
}

/// A count for a message: two significant digits in exponent form above 1e4.
fn short(x: f64) -> String {
    if x.is_finite() && x.abs() >= 1e4 {
        format!("{x:.1e}")
    } else if x.is_finite() && x.abs() >= 10.0 {
        format!("{x:.0}")
    } else {
        format!("{x:.2}")
    }
}

/// Number of output times of a run (t = 0 included).
pub fn outputs(scene: &Scene) -> f64 {
    (scene.t_end / scene.output_interval * (1.0 - 1e-12))
        .ceil()
        .max(1.0)
        + 1.0
}

/// Estimated bytes a run writes: per output time one `.vti` with `arrays` Float64 components
/// per cell (phihat, phi, c, T, u = 7; + p with a flow; + volume with a geometry) and a
/// `.pvd` line; `final.csv` (about 25 bytes per number); `series.csv`; the pictures (a bounded
/// number of PNGs and a GIF frame per output time, each bounded by the picture size).
pub fn output_bytes(scene: &Scene) -> f64 {
    let cells = scene.len() as f64;
    let n_out = outputs(scene);
    let frames = fields_bytes(scene) + n_out * 100.0;
    let final_csv = cells * 11.0 * 25.0;
    let series = n_out * 120.0;
    // a GIF frame of at most 800 x 800 pixels (1 byte each) per output time, 12 PNGs
    let plots = n_out * 0.64e6_f64.min(cells * 64.0) + 12.0 * 0.5e6;
    frames + final_csv + series + plots
}

/// Estimated bytes of the `.vti` files of a run (the bulk of a large run's output).
/// Compression is not counted (an upper bound); thinning is.
pub fn fields_bytes(scene: &Scene) -> f64 {
    let cells = scene.len() as f64;
    let out = &scene.output;
    let (mut comps_total, mut arrays) = (0.0, 0.0);
    for (name, comps, present) in [
        ("phihat", 1.0, true),
        ("phi", 1.0, true),
        ("c", 1.0, true),
        ("T", 1.0, true),
        ("u", 3.0, true),
        ("p", 1.0, scene.flow.is_some()),
        ("volume", 1.0, scene.geometry.is_some()),
    ] {
        if present && out.has(name) {
            comps_total += comps;
            arrays += 1.0;
        }
    }
    let n = outputs(scene) as usize;
    let written = (0..n).filter(|&k| out.writes(k, n)).count() as f64;
    // XML: ~350 bytes plus ~150 per array tag; each array: its 8-byte length, then 8 bytes
    // per value (measured: 801 header bytes with 3 arrays)
    written * (350.0 + 158.0 * arrays + comps_total * 8.0 * cells)
}

/// Refuses a run whose estimated output exceeds `--max-output` or the free space on the file
/// system of `out` (its nearest existing ancestor).
pub fn check_output(scene: &Scene, out: &Path) -> Result<()> {
    let bytes = output_bytes(scene);
    let n_out = outputs(scene);
    let what = format!(
        "{} outputs of {} cells would write about {}",
        short(n_out),
        scene.len(),
        bytes_text(bytes)
    );
    let fix = "raise run.output_interval or coarsen grid.cells";
    if bytes > scene.limits.max_output {
        return Err(Error::at(
            &scene.label,
            "run.output_interval",
            format!(
                "{what}, above --max-output = {}: {fix}{}",
                bytes_text(scene.limits.max_output),
                if scene.limits.flags {
                    ", or raise --max-output"
                } else {
                    " (`sieve run` takes --max-output to raise the limit)"
                }
            ),
        ));
    }
    if let Some(free) = free_space(out) {
        if bytes > free as f64 {
            return Err(Error::at(
                &scene.label,
                "run.output_interval",
                format!(
                    "{what}, but only {} are free where {} is written: {fix}, or write elsewhere with --out",
                    bytes_text(free as f64),
                    out.display()
                ),
            ));
        }
    }
    Ok(())
}

/// Free bytes on the file system of `path`'s nearest existing ancestor (`None` if unknown).
pub fn free_space(path: &Path) -> Option<u64> {
    let abs = if path.is_absolute() {
        path.to_path_buf()
    } else {
        std::env::current_dir().ok()?.join(path)
    };
    let mut p = abs.as_path();
    loop {
        if p.exists() {
            return fs4::available_space(p).ok();
        }
        p = p.parent()?;
    }
}

/// Bytes as "12.3 MB" (decimal units, as `df -H` and `--max-output` read them).
pub fn bytes_text(b: f64) -> String {
    let units = [("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)];
    for (u, f) in units {
        if b >= f {
            return format!("{:.1} {u}", b / f);
        }
    }
    format!("{b:.0} B")
}

/// Parses `--max-output`: bytes with an optional decimal suffix k, M, G, T (`500M`, `8G`,
/// `1e10`).
pub fn parse_bytes(s: &str) -> std::result::Result<f64, String> {
    let t = s.trim();
    let (digits, factor) = match t.char_indices().last() {
        Some((i, c)) if c.is_ascii_alphabetic() && !t.ends_with(['e', 'E']) => {
            let f = match c.to_ascii_uppercase() {
                'K' => 1e3,
                'M' => 1e6,
                'G' => 1e9,
                'T' => 1e12,
                'B' => 1.0,
                _ => return Err(format!("{s}: expected bytes such as 500M, 8G or 1e10")),
            };
            (&t[..i], f)
        }
        _ => (t, 1.0),
    };
    match digits.parse::<f64>() {
        Ok(x) if x.is_finite() && x > 0.0 => Ok(x * factor),
        _ => Err(format!("{s}: expected bytes > 0 such as 500M, 8G or 1e10")),
    }
}

/// Parses `--max-steps` / `--max-cell-steps`: a count > 0 (`1e9`, `200000000`).
pub fn parse_count(s: &str) -> std::result::Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(x) if x.is_finite() && x >= 1.0 => Ok(x),
        _ => Err(format!("{s}: expected a count >= 1 such as 1e9")),
    }
}

/// A break of `0 <= phi <= c` at an output time: how much, where, when.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Violation {
    /// `phi - c` (over) or `-phi` (under), > 0.
    pub amount: f64,
    /// `true` for `phi > c`, `false` for `phi < 0`.
    pub over: bool,
    /// Output time.
    pub t: f64,
    /// Solver cell index.
    pub cell: usize,
}

/// Violations smaller than this are round-off, not a broken bound (phi is a fraction of
/// order 1; the modified flux keeps the bounds exactly).
pub const BOUND_TOLERANCE: f64 = 1e-12;

/// The largest bound violation of a state at time `t` (`None` if within [`BOUND_TOLERANCE`]).
pub fn worst_violation(phi: &[f64], c: &[f64], t: f64) -> Option<Violation> {
    let mut worst: Option<Violation> = None;
    for (i, (&p, &ci)) in phi.iter().zip(c).enumerate() {
        for (amount, over) in [(p - ci, true), (-p, false)] {
            if amount > BOUND_TOLERANCE && worst.is_none_or(|w| amount > w.amount) {
                worst = Some(Violation {
                    amount,
                    over,
                    t,
                    cell: i,
                });
            }
        }
    }
    worst
}

/// The one warning line of a run that broke `0 <= phi <= c` (issue 10: naive fluxes and flows
/// into walls keep running, but say so): the largest violation over every cell and step (the
/// solver's running maxima) and the cell and output time of the largest one seen at an output.
pub fn bounds_warning(
    scene: &Scene,
    overshoot: f64,
    undershoot: f64,
    at_output: Option<Violation>,
) -> Option<String> {
    if !(overshoot > BOUND_TOLERANCE || undershoot > BOUND_TOLERANCE) {
        return None;
    }
    let (amount, what) = if overshoot >= undershoot {
        (overshoot, "phi > c")
    } else {
        (undershoot, "phi < 0")
    };
    let place = at_output.map_or(String::new(), |v| {
        let p = scene.center(v.cell);
        let names = ["x", "y", "z"];
        let axes = crate::scene::validate::physical_axes(scene.dim);
        let at: Vec<String> = axes
            .iter()
            .map(|&a| format!("{} = {}", names[a], crate::text::approx(p[a])))
            .collect();
        format!(
            "; at output times the largest, {} by {}, at t = {} in the cell at {}",
            if v.over { "phi > c" } else { "phi < 0" },
            crate::text::approx(v.amount),
            crate::text::approx(v.t),
            at.join(", ")
        )
    });
    let fix = if scene.scheme == sieve_core::Scheme::Modified {
        "check the scene's velocities at walls and inflows (a prescribed flow into a wall piles up grains beyond c)"
    } else {
        "the godunov and upwind fluxes break the bounds by design (model.md 6); use --scheme modified"
    };
    Some(format!(
        "warning: {}: 0 <= phi <= c broken ({what} by up to {} over all cells and steps{place}): {fix}",
        scene.label,
        crate::text::approx(amount),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The guard `sieve run` and `sieve fit` share: steps x cells against the limit.
    #[test]
    fn cell_steps_refuses_above_the_limit_and_nan() {
        let lim = Limits {
            max_cell_steps: 1e6,
            ..Limits::default()
        };
        assert_eq!(cell_steps(1e3, 1000, &lim), Ok(1e6)); // at the limit: within
        assert_eq!(cell_steps(1001.0, 1000, &lim), Err(1.001e6));
        assert_eq!(cell_steps(f64::INFINITY, 1, &lim), Err(f64::INFINITY));
        assert!(cell_steps(f64::NAN, 1, &lim).is_err_and(f64::is_nan));
    }
}
