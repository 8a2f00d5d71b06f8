//! Progress of a time loop (issue 10, "Never hang"): a bar on a terminal, and, when stderr is
//! not a terminal (a batch job, a pipe, CI), plain lines so that a long run is never silent:
//!
//! ```text
//! progress: column-a: t = 4.1e-1 of 1 (41 %), step 10251, elapsed 12 s, eta 17 s
//! ```
//!
//! Nothing is printed during the first [`INTERVAL`] seconds (short runs stay quiet, as
//! before); after that a line every [`INTERVAL`] seconds and at every new 10 % of `t_end`
//! (at most one a second). `--quiet` prints nothing. `SIEVE_PROGRESS_SECONDS` sets the
//! interval (0: a line at every new 10 % from the start; used by the tests).

use indicatif::ProgressBar;
use std::cell::Cell;
use std::time::{Duration, Instant};

/// Seconds between progress lines (and before the first).
pub const INTERVAL: f64 = 10.0;

/// A progress display: a bar, lines, or nothing.
#[derive(Debug)]
pub struct Progress {
    bar: Option<ProgressBar>,
    lines: Option<Lines>,
    t_end: f64,
}

#[derive(Debug)]
struct Lines {
    label: String,
    t_end: f64,
    interval: Duration,
    start: Instant,
    last: Cell<Instant>,
    decile: Cell<u64>,
}

impl Progress {
    /// Shows nothing.
    pub fn hidden() -> Self {
        Self {
            bar: None,
            lines: None,
            t_end: 1.0,
        }
    }

    /// A bar on a terminal, lines otherwise, nothing when `quiet`; `t_end` is the time the
    /// loop runs to.
    pub fn new(quiet: bool, label: &str, t_end: f64) -> Self {
        use std::io::IsTerminal;
        if quiet {
            return Self::hidden();
        }
        if std::io::stderr().is_terminal() {
            let bar = ProgressBar::new(1000);
            if let Ok(style) = indicatif::ProgressStyle::with_template(
                "{prefix} [{bar:40}] {percent:>3}% {elapsed_precise} eta {eta}",
            ) {
                bar.set_style(style.progress_chars("=> "));
            }
            bar.set_prefix(label.to_string());
            return Self {
                bar: Some(bar),
                lines: None,
                t_end,
            };
        }
        let interval = std::env::var("SIEVE_PROGRESS_SECONDS")
            .ok()
            .and_then(|s| s.parse::<f64>().ok())
            .filter(|s| s.is_finite() && *s >= 0.0)
            .unwrap_or(INTERVAL);
        let now = Instant::now();
        Self {
            bar: None,
            lines: Some(Lines {
                label: label.to_string(),
                t_end,
                interval: Duration::from_secs_f64(interval),
                start: now,
                last: Cell::new(now),
                decile: Cell::new(0),
            }),
            t_end,
        }
    }

    /// The loop has reached time `t` after `steps` steps.
    pub fn update(&self, t: f64, steps: u64) {
        if let Some(bar) = &self.bar {
            bar.set_position(permille(t, self.t_end));
        }
        if let Some(l) = &self.lines {
            l.update(t, steps);
        }
    }

    /// Removes the bar (lines stay).
    pub fn finish_and_clear(&self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }
}

fn permille(t: f64, t_end: f64) -> u64 {
    if t_end > 0.0 && t.is_finite() {
        ((t / t_end).clamp(0.0, 1.0) * 1000.0) as u64
    } else {
        0
    }
}

impl Lines {
    fn update(&self, t: f64, steps: u64) {
        let now = Instant::now();
        let elapsed = now - self.start;
        let frac = if self.t_end > 0.0 {
            (t / self.t_end).clamp(0.0, 1.0)
        } else {
            1.0
        };
        let decile = (frac * 10.0).floor() as u64;
        let since = now - self.last.get();
        let new_decile = decile > self.decile.get();
        let due = if self.interval.is_zero() {
            new_decile
        } else {
            elapsed >= self.interval
                && (since >= self.interval || (new_decile && since >= Duration::from_secs(1)))
        };
        if !due {
            return;
        }
        self.last.set(now);
        self.decile.set(decile);
        let el = elapsed.as_secs_f64();
        let eta = if frac > 0.0 {
            format!("{:.0} s", el * (1.0 - frac) / frac)
        } else {
            "unknown".into()
        };
        eprintln!(
            "progress: {}: t = {} of {} ({:.0} %), step {steps}, elapsed {el:.0} s, eta {eta}",
            self.label,
            crate::text::num(t),
            crate::text::num(self.t_end),
            frac * 100.0
        );
    }
}
