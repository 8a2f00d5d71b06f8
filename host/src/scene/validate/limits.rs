//! The run guards' limits (issue 10, "Never hang"): how many steps, cell updates and output
//! bytes a run may be estimated to need before it is refused with exit code 2. Not scene keys:
//! the command line sets them (`--max-steps`, `--max-cell-steps`, `--max-output`); the
//! estimates and the reasons for the defaults are in `host/src/estimate.rs`.

/// Limits a user can raise on the command line (`--max-steps`, `--max-cell-steps`,
/// `--max-output`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    /// Largest estimated number of time steps.
    pub max_steps: f64,
    /// Largest estimated number of cell updates (steps x cells).
    pub max_cell_steps: f64,
    /// Largest estimated output size \[bytes\].
    pub max_output: f64,
    /// Whether the command that runs takes the flags that raise these (`sieve run`); other
    /// commands (`converge`, `sweep`, `fit`) use the defaults, and their refusals must not
    /// tell the user to raise a flag the command does not have.
    pub flags: bool,
}

/// Default `--max-steps`: 1e8 steps (430 x the longest built-in run, the 25 s tumbler).
pub const MAX_STEPS: f64 = 1e8;
/// Default `--max-cell-steps`: 1e11 cell updates (~20 min of segregation stepping at 8e7/s).
pub const MAX_CELL_STEPS: f64 = 1e11;
/// Default `--max-output`: 4 GB (200 outputs of a 512 x 512 flow scene).
pub const MAX_OUTPUT: f64 = 4e9;

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_steps: MAX_STEPS,
            max_cell_steps: MAX_CELL_STEPS,
            max_output: MAX_OUTPUT,
            flags: false,
        }
    }
}
