//! Stopping a run early without losing it: SIGINT/SIGTERM and numerical failure.
//!
//! A signal only sets a flag (signal-hook; nothing else is safe in a handler). The step loops
//! poll it between steps (or between bounded chunks of steps, [`crate::run::time_loop`]), and
//! check after each chunk that the time step, the clock and the state are finite. Either way
//! the loop ends with a [`Stop`] instead of an error, so `sieve run` still writes summary.json
//! (status "interrupted" or "failed"), final.csv of the state it stopped at and everything
//! written so far, and commits DIR: a run that fails keeps what it wrote (docs/outputs.md).
//!
//! A second SIGINT/SIGTERM while the first is being handled ends the process at once with
//! the conventional code (130/143); a later run into the same DIR removes what that leaves.
//! Without [`install`] (the library used from tests or other programs) nothing is ever
//! pending.

use crate::error::Error;
use sieve_core::{Real, Segregation};
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, OnceLock};

/// The signal that asked the run to stop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Signal {
    /// SIGINT (Ctrl-C): exit code 130.
    Int,
    /// SIGTERM (`kill`, a batch system's time limit): exit code 143.
    Term,
}

impl Signal {
    /// The signal's number.
    pub fn number(self) -> i32 {
        match self {
            Signal::Int => signal_hook::consts::SIGINT,
            Signal::Term => signal_hook::consts::SIGTERM,
        }
    }
    /// Its name.
    pub fn name(self) -> &'static str {
        match self {
            Signal::Int => "SIGINT",
            Signal::Term => "SIGTERM",
        }
    }
    /// The shell's convention: 128 + the signal number.
    pub fn exit_code(self) -> i32 {
        128 + self.number()
    }
}

struct Flags {
    /// The number of the first signal received (0: none).
    first: Arc<AtomicUsize>,
    /// Set on any signal: a second one terminates at once.
    any: Arc<AtomicBool>,
}

static FLAGS: OnceLock<Flags> = OnceLock::new();

/// Installs the SIGINT and SIGTERM handlers (once; later calls do nothing).
pub fn install() -> std::io::Result<()> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    use signal_hook::flag;
    if FLAGS.get().is_some() {
        return Ok(());
    }
    let flags = Flags {
        first: Arc::new(AtomicUsize::new(0)),
        any: Arc::new(AtomicBool::new(false)),
    };
    for sig in [SIGINT, SIGTERM] {
        // Registered first, so it sees the flag as it was before this signal: the second
        // signal exits, the first only sets the flags below.
        flag::register_conditional_shutdown(sig, 128 + sig, Arc::clone(&flags.any))?;
        flag::register(sig, Arc::clone(&flags.any))?;
        flag::register_usize(sig, Arc::clone(&flags.first), sig as usize)?;
    }
    let _ = FLAGS.set(flags);
    Ok(())
}

/// The signal received, if any (the first one counts).
pub fn pending() -> Option<Signal> {
    let n = FLAGS.get()?.first.load(Ordering::Relaxed) as i32;
    match n {
        0 => None,
        n if n == signal_hook::consts::SIGTERM => Some(Signal::Term),
        _ => Some(Signal::Int),
    }
}

/// For loops that cannot keep a partial result (the flow spin-up, converge, fit, record): an
/// error that exits with the signal's code, nothing written.
pub fn check(what: &str) -> crate::error::Result<()> {
    match pending() {
        Some(sig) => Err(Error::Interrupted {
            code: sig.exit_code(),
            message: format!(
                "interrupted by {} during {what}; nothing written",
                sig.name()
            ),
        }),
        None => Ok(()),
    }
}

/// Why a loop stopped before its end time.
#[derive(Debug, Clone, PartialEq)]
pub enum Reason {
    /// A signal.
    Signal(Signal),
    /// A non-finite time step, clock or state value.
    NonFinite {
        /// `dt`, `t`, `phi`, `c`, `T`, `u_x`, ..., or the flow's fields (`flow c`, `flow p`, ...).
        field: String,
        /// The cell (solver order), if the field is a cell field.
        cell: Option<usize>,
        /// Its integer coordinates per axis.
        coords: Vec<usize>,
        /// The value (NaN, inf, or a non-positive time step).
        value: f64,
    },
    /// The core refused to go on (its message, in words).
    Core(String),
}

/// Where and why a loop stopped.
#[derive(Debug, Clone, PartialEq)]
pub struct Stop {
    /// Why.
    pub reason: Reason,
    /// Simulated time reached \[s\].
    pub t: f64,
    /// Steps taken.
    pub step: u64,
}

impl Stop {
    /// `"interrupted"` or `"failed"`: the `status` of summary.json.
    pub fn status(&self) -> &'static str {
        match self.reason {
            Reason::Signal(_) => "interrupted",
            _ => "failed",
        }
    }

    /// One line: what happened, where.
    pub fn describe(&self) -> String {
        match &self.reason {
            Reason::Signal(s) => format!(
                "interrupted by {} at t = {} s, step {}",
                s.name(),
                num(self.t),
                self.step
            ),
            Reason::NonFinite {
                field,
                cell,
                coords,
                value,
            } => {
                let at = match cell {
                    Some(c) => format!(" in cell {c} {coords:?}"),
                    None => String::new(),
                };
                format!(
                    "the run failed numerically at step {} (t = {} s): {field} = {value}{at}",
                    self.step,
                    num(self.t)
                )
            }
            Reason::Core(m) => format!(
                "the run failed numerically at step {} (t = {} s): {m}",
                self.step,
                num(self.t)
            ),
        }
    }

    /// The error `sieve` exits with; `dir` is where the partial output was committed.
    pub fn error(&self, dir: Option<&Path>) -> Error {
        let kept = match dir {
            Some(d) => format!("partial output kept in {}", d.display()),
            None => "nothing written".into(),
        };
        match self.reason {
            Reason::Signal(sig) => Error::Interrupted {
                code: sig.exit_code(),
                message: format!("{}; {kept}", self.describe()),
            },
            Reason::NonFinite { .. } => Error::Numerical(format!(
                "{}; {kept}; check the scene's values (grid extent, gravity, s0, velocities) or lower numerics.courant",
                self.describe()
            )),
            Reason::Core(_) => Error::Numerical(format!("{}; {kept}", self.describe())),
        }
    }
}

/// A time in the shortest form that reads back to the same f64 (as `output::num`; this
/// module stays below `data` and `output` in the import graph, host/tests/house.rs).
fn num(x: f64) -> String {
    let a = x.abs();
    if x == 0.0 || (1e-4..1e15).contains(&a) || !x.is_finite() {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

/// The velocity component of solver axis `a` (the scene's axes: z in 1D; x, z in 2D).
fn velocity_name(dim: usize, a: usize) -> &'static str {
    match (dim, a) {
        (1, _) => "u_z",
        (2, 1) | (3, 2) => "u_z",
        (3, 1) => "u_y",
        _ => "u_x",
    }
}

/// The segregation velocity component of solver axis `a`.
fn segregation_name(dim: usize, a: usize) -> &'static str {
    match velocity_name(dim, a) {
        "u_x" => "segregation velocity S_x",
        "u_y" => "segregation velocity S_y",
        _ => "segregation velocity S_z",
    }
}

/// The first non-finite value of the segregation state, in cell order, then field order.
pub fn scan_segregation<R: Real, const D: usize, const N: usize>(
    s: &Segregation<R, D, N>,
) -> Option<Reason> {
    if s.all_finite() {
        // the common case, without the search's per-cell bookkeeping (on 512 x 512 cells
        // the search took 3.8 % of a 2-thread run in perf; this pass saves 0.15-0.2 s of 3.3)
        return None;
    }
    for i in 0..s.len() {
        let u = s.velocity(i);
        // The segregation velocity too: an overflowing S0 g sqrt(T) leaves phi finite but
        // frozen (a NaN rate reads as "nothing moves").
        let seg = s.segregation_velocity(i);
        let found = [("phi", s.phi(i)), ("c", s.c(i)), ("T", s.temperature(i))]
            .into_iter()
            .chain(u.iter().enumerate().map(|(a, &v)| (velocity_name(D, a), v)))
            .chain(
                seg.iter()
                    .enumerate()
                    .map(|(a, &v)| (segregation_name(D, a), v)),
            )
            .find(|(_, v)| !v.is_finite());
        if let Some((field, v)) = found {
            return Some(Reason::NonFinite {
                field: field.into(),
                cell: Some(i),
                coords: s.grid().coords(i).to_vec(),
                value: v.to_f64(),
            });
        }
    }
    None
}

/// The first non-finite value of the flow's state (c, T, p, u).
pub fn scan_flow<R: Real, const D: usize, const N: usize>(
    f: &sieve_core::flow::Flow<R, D, N>,
) -> Option<Reason> {
    // the common case first, one branch-free pass (after every coupled step: 0.8 % of the
    // silo's run time as a search)
    let finite = |v: R| v.is_finite();
    let all = (0..f.len()).fold(true, |ok, i| {
        let u = f.velocity(i);
        let cell = finite(f.c(i)) & finite(f.temperature(i)) & finite(f.pressure(i));
        u.iter().fold(ok & cell, |ok, &v| ok & finite(v))
    });
    if all {
        return None;
    }
    for i in 0..f.len() {
        let u = f.velocity(i);
        let found = [
            ("flow c", f.c(i)),
            ("flow T", f.temperature(i)),
            ("flow p", f.pressure(i)),
        ]
        .into_iter()
        .chain(u.iter().enumerate().map(|(a, &v)| (velocity_name(D, a), v)))
        .find(|(_, v)| !v.is_finite());
        if let Some((field, v)) = found {
            return Some(Reason::NonFinite {
                field: field.into(),
                cell: Some(i),
                coords: f.grid().coords(i).to_vec(),
                value: v.to_f64(),
            });
        }
    }
    None
}

/// A time step that cannot advance the clock: not finite, or not positive.
pub fn bad_dt(dt: f64) -> Option<Reason> {
    (!(dt.is_finite() && dt > 0.0)).then(|| Reason::NonFinite {
        field: "dt".into(),
        cell: None,
        coords: Vec::new(),
        value: dt,
    })
}

/// The checks after a chunk of segregation steps: a signal, then the step and clock, then
/// the state (one pass over the cells: cheap next to the chunk's steps).
pub fn after_steps<R: Real, const D: usize, const N: usize>(
    s: &Segregation<R, D, N>,
    dt: f64,
    step: u64,
) -> Option<Stop> {
    let t = s.time().to_f64();
    let reason = pending()
        .map(Reason::Signal)
        .or_else(|| bad_dt(dt))
        .or_else(|| {
            (!t.is_finite()).then(|| Reason::NonFinite {
                field: "t".into(),
                cell: None,
                coords: Vec::new(),
                value: t,
            })
        })
        .or_else(|| scan_segregation(s))?;
    Some(Stop { reason, t, step })
}
