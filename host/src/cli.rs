//! The command line (clap derive) and the dispatch of its commands.

use crate::converge::{self, ConvergeOptions};
use crate::error::{Error, Result};
use crate::estimate;
use crate::run::{self, RunOptions};
use crate::scene::{self, builtin};
use crate::soft_sensor;
use clap::{Args, Parser, Subcommand, ValueEnum};
use std::path::PathBuf;

/// sieve: size segregation in bi-disperse granular flows.
#[derive(Debug, Parser)]
#[command(name = "sieve", version, about, long_about = None)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// The commands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// List the built-in scenes, one per line: name, dimension, description.
    Scenes,
    /// Run a scene and write summary.json, series.csv, final.csv, fields/ and plots/ to DIR.
    Run(RunArgs),
    /// Run a scene on several grids and print a work-precision table (errors, orders, times)
    /// and the scene's readouts per grid with their grid error (order, extrapolated value,
    /// GCI); draws converge.png (error against cell size and wall time) and readouts.png.
    Converge(ConvergeArgs),
    /// Redraw the pictures of a finished run DIR (into DIR/plots) from its files:
    /// summary.json, series.csv, fields/*.vti, profiles.csv.
    Plot(PlotArgs),
    /// Fit S0 of a frozen-flow scene so that re-segregation completes at a target time, per
    /// grid (the flow is spun up and frozen once per grid); writes fit.csv, fit.json, plots/.
    Fit(FitArgs),
    /// Write the velocity frames a sensor would see from a scene, with the truth alongside.
    Record(RecordArgs),
    /// Run the soft sensor over a recording: estimate-against-truth error and state hash.
    Replay(ReplayArgs),
    /// Run a scene for every combination of `--set key=v1,v2,...` values, each into
    /// DIR/run-NNNN, plus a table of their summaries (sweep.csv, sweep.json) and sweep.png.
    Sweep(SweepArgs),
}

/// Arguments of `sieve sweep`.
#[derive(Debug, Args)]
#[command(after_help = "\
Combinations are numbered from 0 with the first swept key varying slowest (`--list` prints \
them). On a cluster, run one combination per Slurm array task: \
`sbatch --array=0-N-1 --wrap 'sieve sweep SCENE --set ... --out DIR'` (the task index comes \
from SLURM_ARRAY_TASK_ID), then `sieve sweep SCENE --set ... --out DIR --collect` once all \
tasks have finished.")]
pub struct SweepArgs {
    /// Built-in scene name or path to a scene TOML file.
    pub scene: String,
    /// A scene key and its values, e.g. --set material.s0=0.5,1,2 (repeatable; one value is a
    /// fixed override for every run; commas inside [ ], ( ) or quotes do not split).
    #[arg(long = "set", value_name = "KEY=V1,V2,...")]
    pub set: Vec<String>,
    /// Sweep directory [default: runs/{scene}-sweep].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Runs at once [default: the number of cores].
    #[arg(long, short = 'j', value_name = "N")]
    pub jobs: Option<usize>,
    /// Print the combinations (index, key=value ...) and run nothing.
    #[arg(long)]
    pub list: bool,
    /// Run only combination I (a Slurm array task) and write no table [default: the
    /// environment's SLURM_ARRAY_TASK_ID, except with --list and --collect].
    #[arg(long, value_name = "I")]
    pub task: Option<usize>,
    /// Run nothing; build the table and the plot from the runs in DIR.
    #[arg(long, conflicts_with_all = ["list", "task"])]
    pub collect: bool,
    /// Summary value drawn against the first swept key in sweep.png (a summary.json key;
    /// nested ones dotted, e.g. flow.max_packing).
    #[arg(long, value_name = "KEY", default_value = "psi_final")]
    pub plot: String,
    /// Fit y = A (x - x0)^n to the --plot value against the first swept key with numeric
    /// values, one fit per curve: `power` (n fitted; at least 4 values) or `power:N` (n = N
    /// given; at least 3), e.g. --plot flow.outlet.steady_rate --fit power:1.5 for Beverloo's
    /// law of a silo's orifice width (printed, in sweep.json and drawn in sweep.png).
    #[arg(long, value_name = "MODEL")]
    pub fit: Option<String>,
    /// No per-run lines on stderr.
    #[arg(long, short)]
    pub quiet: bool,
}

/// Arguments of `sieve plot`.
#[derive(Debug, Args)]
pub struct PlotArgs {
    /// A run directory written by `sieve run` (e.g. runs/shear-cell-inverse).
    pub dir: PathBuf,
}

/// Arguments of `sieve record`.
#[derive(Debug, Args)]
#[command(after_help = "\
SCENE is any 2D box scene of the catalogue (see `sieve scenes`) or a scene TOML file: \
prescribed, frozen-flow or coupled (a silo with an outlet, a collapse, a chute; scenes with a \
[geometry] container are not supported yet). The truth is the scene's own run (as `sieve run`; \
a frozen flow is spun up first) on its grid, sampled at every frame; the frames are its velocity \
averaged onto the \
sensor grid plus noise; the sensor configuration (extent, boundaries, c, S0/eta0/eps0/heating, \
gravity, inflow phihat) comes from the scene, with notes on stderr where it departs from it. \
Default period: 2 Courant steps of the estimator (about the time the fastest grains take to cross one estimator cell); default frames: cover run.t_end.\n\n\
Legacy hand-written scenes: idealised-shear-cell (model.md 7.3, firmware-sim's \
recordings/shear-cell.rec: --rate 100 --frames 100) and gray-thornton-sensor; by default 100 Hz, \
150 and 300 frames, truth 32x32.")]
pub struct RecordArgs {
    /// Scene: a 2D built-in box scene (e.g. shear-cell, shear-cell-mixed, gray-thornton-shear,
    /// silo), a scene TOML file, or idealised-shear-cell / gray-thornton-sensor.
    pub scene: String,
    /// Sensor (velocity frame) grid NXxNZ, 2..=16 points per axis.
    #[arg(long = "sensor-grid", value_name = "NXxNZ", default_value = "8x8")]
    pub sensor_grid: String,
    /// Estimator grid NXxNZ written into the sensor configuration, at most 1024 cells (the
    /// firmware's capacity).
    #[arg(long = "estimator-grid", value_name = "NXxNZ", default_value = "32x32")]
    pub estimator_grid: String,
    /// Truth grid NXxNZ [default: the scene's grid.cells; 32x32 for the legacy scenes].
    #[arg(long = "truth-grid", value_name = "NXxNZ")]
    pub truth_grid: Option<String>,
    /// Velocity noise: standard deviation relative to the scene's largest speed.
    #[arg(
        long,
        value_name = "SIGMA",
        default_value_t = 0.05,
        allow_negative_numbers = true
    )]
    pub noise: f64,
    /// Frame rate in Hz, at least 1e-30 and at most what a tick's cycle budget affords
    /// [default: 2 Courant steps of the estimator per frame, about one cell crossing of the fastest grains; 100 for the legacy scenes].
    #[arg(long, value_name = "HZ", allow_negative_numbers = true)]
    pub rate: Option<f64>,
    /// Number of frames [default: cover the scene's run.t_end, at most 20000].
    #[arg(long, value_name = "N")]
    pub frames: Option<u32>,
    /// Noise seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Override any scene key in dotted form, e.g. --set 'initial.phi=c/2' (repeatable;
    /// catalogue scenes only).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Clock of the sensor's CPU in MHz: with the frame period and --cpu-share it sets the
    /// cycle budget of a tick, which caps its substeps (docs/soft-sensor.md "Cycle budget").
    #[arg(
        long = "cpu-mhz",
        value_name = "MHZ",
        default_value_t = 168.0,
        allow_negative_numbers = true
    )]
    pub cpu_mhz: f64,
    /// Share of every tick the CPU grants the sensor, in (0, 1].
    #[arg(
        long = "cpu-share",
        value_name = "SHARE",
        default_value_t = 1.0,
        allow_negative_numbers = true
    )]
    pub cpu_share: f64,
    /// Recording file to write.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
}

/// Arguments of `sieve replay`.
#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// Recording file (from `sieve record` or firmware-sim/recordings/).
    pub file: PathBuf,
    /// Inject firmware-sim's demo faults (bit flips, drops, duplicates, NaNs, stalls).
    #[arg(long)]
    pub faults: bool,
    /// Print every N-th tick.
    #[arg(long, value_name = "N", default_value_t = 10)]
    pub every: usize,
    /// The controller's band for the outlet fines fraction, LO,HI (0 <= LO <= HI <= 1)
    /// [default: the recording's]; it changes the alarms and the off-spec prediction only.
    #[arg(long = "fines-band", value_name = "LO,HI", allow_hyphen_values = true)]
    pub fines_band: Option<String>,
    /// Ticks the fines fraction must stay out of the band before an alarm (and back inside
    /// before it clears) [default: the recording's].
    /// (Signed, so that a negative N gets the range message, not "unexpected argument".)
    #[arg(
        long = "alarm-persist",
        value_name = "N",
        allow_negative_numbers = true,
        value_parser = clap::value_parser!(i64).range(1..=65535)
    )]
    pub alarm_persist: Option<i64>,
    /// Multiply the recorded segregation rate S0 by G (0 < G <= 100), i.e. sqrt(T) from the
    /// measured shear by G: a per-installation calibration of a coarse sensor grid, which
    /// smooths away shear bands (docs/soft-sensor.md "Why the estimator under-segregates").
    /// Unlike --fines-band it changes the estimate (and the state hash).
    #[arg(long = "shear-gain", value_name = "G", allow_negative_numbers = true)]
    pub shear_gain: Option<f64>,
    /// Subtract L times the measured noise's own shear before T is derived from the
    /// measured shear (0 <= L <= 10; the recording's value, 0, otherwise): keeps noisy frames
    /// from heating a creeping bed (docs/soft-sensor.md "Noise in the measured shear").
    /// Changes the estimate (and the state hash).
    #[arg(long = "noise-term", value_name = "L", allow_negative_numbers = true)]
    pub noise_term: Option<f64>,
    /// Weight W of a new frame in the moving average of the measured velocity (1e-38 <= W <= 1;
    /// 1 = no averaging; the recording's value otherwise): the filter a controls engineer
    /// tunes against the sensor's noise and the flow's changes (docs/soft-sensor.md "Sensor
    /// grid, filter and gain on the silo").
    /// Changes the estimate (and the state hash).
    #[arg(long = "smoothing", value_name = "W", allow_negative_numbers = true)]
    pub smoothing: Option<f64>,
    /// Passes P of the 1-2-1 filter over each measured frame (0 <= P <= 8; the recording's
    /// value otherwise): fewer passes keep a narrow jet or shear band that a coarse sensor
    /// sees in one point (docs/soft-sensor.md "Sensor grid, filter and gain on the silo").
    /// Changes the estimate (and the state hash).
    #[arg(
        long = "spatial-passes",
        value_name = "P",
        allow_negative_numbers = true,
        value_parser = clap::value_parser!(i64).range(0..=8)
    )]
    pub spatial_passes: Option<i64>,
    /// Replace the recorded velocity frames by the Nedderman-Tuzun kinematic velocity of a
    /// flat-bottomed silo with kinematic constant B in m, scaled by the discharge rate alone
    /// (a load cell; docs/soft-sensor.md). Silo recordings only.
    #[arg(long, value_name = "B", allow_negative_numbers = true)]
    pub kinematic: Option<f64>,
}

/// Face flux names on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SchemeArg {
    /// Modified Godunov flux (keeps 0 <= phi <= c).
    Modified,
    /// Classical Godunov flux with face-averaged c and T (comparison).
    Godunov,
    /// Upwind flux with face-averaged c and T (comparison).
    Upwind,
}

impl SchemeArg {
    fn name(self) -> &'static str {
        match self {
            SchemeArg::Modified => "modified",
            SchemeArg::Godunov => "godunov",
            SchemeArg::Upwind => "upwind",
        }
    }
}

/// Arguments of `sieve run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// Built-in scene name or path to a scene TOML file [default: shear-cell-inverse].
    pub scene: Option<String>,
    /// Output directory [default: runs/{scene name}].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Face flux (overrides numerics.scheme).
    #[arg(long, value_enum)]
    pub scheme: Option<SchemeArg>,
    /// N cells on every axis (overrides grid.cells).
    #[arg(long, value_name = "N", conflicts_with = "grid")]
    pub cells: Option<u64>,
    /// Cells per axis as NXxNY or NXxNYxNZ, e.g. 128x64 (overrides grid.cells).
    #[arg(long, value_name = "NXxNY[xNZ]")]
    pub grid: Option<String>,
    /// End time (overrides run.t_end).
    #[arg(long = "t-end", value_name = "T", allow_negative_numbers = true)]
    pub t_end: Option<String>,
    /// Courant number, 0 < C < 1 (overrides numerics.courant).
    #[arg(long, value_name = "C", allow_negative_numbers = true)]
    pub cfl: Option<String>,
    /// Override any scene key in dotted form, e.g. --set material.s0=2 (repeatable; applied
    /// before the options above).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// No progress bar and no closing line.
    #[arg(long, short)]
    pub quiet: bool,
    /// VTK arrays to write, comma separated, among phihat, phi, c, T, u, p, volume (phihat
    /// and c always; overrides output.fields).
    #[arg(long, value_name = "NAME,NAME,...", value_delimiter = ',')]
    pub fields: Vec<String>,
    /// Write a VTK snapshot at every N-th output time only (the first and last always;
    /// overrides output.vtk_every).
    #[arg(long = "vtk-every", value_name = "N")]
    pub vtk_every: Option<String>,
    /// zlib-compress the VTK arrays (vtkZLibDataCompressor; overrides output.compress).
    #[arg(long)]
    pub compress: bool,
    /// Refuse a run estimated (t_end / first stable dt) to need more time steps than this.
    #[arg(long = "max-steps", value_name = "N", value_parser = estimate::parse_count, default_value = "1e8")]
    pub max_steps: f64,
    /// Refuse a run estimated to need more cell updates (steps x cells) than this.
    #[arg(long = "max-cell-steps", value_name = "N", value_parser = estimate::parse_count, default_value = "1e11")]
    pub max_cell_steps: f64,
    /// Refuse a run estimated to write more than this (bytes; suffixes k, M, G, T: 500M, 8G).
    #[arg(long = "max-output", value_name = "BYTES", value_parser = estimate::parse_bytes, default_value = "4G")]
    pub max_output: f64,
    /// Write a checkpoint every SECONDS of wall-clock time into .DIR.checkpoint beside the
    /// output directory (overrides run.checkpoint_interval; docs/resume.md).
    #[arg(long = "checkpoint-interval", value_name = "SECONDS")]
    pub checkpoint_interval: Option<String>,
    /// Continue the unfinished run into DIR from its last checkpoint; the scene and its
    /// overrides come from the checkpoint (SCENE and --set, if given, must be the same).
    #[arg(long, value_name = "DIR", conflicts_with = "out")]
    pub resume: Option<PathBuf>,
    /// Threads for the segregation step of box scenes, 1 to 1024, with the same bits as one
    /// [default: all cores on grids of 65,536 cells or more, else 1; docs/parallel.md].
    /// (Parsed as a signed number so that `-1` gets the range message, not "unexpected argument".)
    #[arg(
        long,
        value_name = "N",
        allow_negative_numbers = true,
        value_parser = clap::value_parser!(i64).range(1..=1024)
    )]
    pub threads: Option<i64>,
}

/// Arguments of `sieve converge`.
#[derive(Debug, Args)]
pub struct ConvergeArgs {
    /// Built-in scene name or path to a scene TOML file.
    pub scene: String,
    /// Cells along the vertical axis, comma separated, e.g. 50,100,200,400.
    #[arg(long, value_name = "N,N,...", value_delimiter = ',', required = true)]
    pub levels: Vec<usize>,
    /// Face flux (overrides numerics.scheme).
    #[arg(long, value_enum)]
    pub scheme: Option<SchemeArg>,
    /// End time of every level (overrides run.t_end), e.g. 0.5 for column-a before the
    /// shocks meet.
    #[arg(long = "t-end", value_name = "T", allow_negative_numbers = true)]
    pub t_end: Option<String>,
    /// Output directory for converge.csv, converge.json and readouts.csv [default:
    /// runs/{scene}-converge].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Override any scene key in dotted form (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// No per-level lines on stderr.
    #[arg(long, short)]
    pub quiet: bool,
}

/// Arguments of `sieve fit`.
#[derive(Debug, Args)]
pub struct FitArgs {
    /// Built-in scene name or path to a scene TOML file (model.equations = "frozen-flow").
    pub scene: String,
    /// Target segregation time in s.
    #[arg(
        long = "target-time",
        value_name = "T",
        default_value_t = 700.0,
        allow_negative_numbers = true
    )]
    pub target_time: f64,
    /// Cells along the vertical axis, comma separated [default: the scene's grid].
    #[arg(long, value_name = "N,N,...", value_delimiter = ',')]
    pub levels: Vec<usize>,
    /// Psi threshold of "re-segregated" [default: the scene's run.psi_threshold].
    #[arg(long, value_name = "PSI", allow_negative_numbers = true)]
    pub threshold: Option<f64>,
    /// Relative tolerance on the segregation time.
    #[arg(
        long,
        value_name = "REL",
        default_value_t = 0.01,
        allow_negative_numbers = true
    )]
    pub tolerance: f64,
    /// Output directory [default: runs/{scene}-fit].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Override any scene key in dotted form (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// No per-evaluation lines on stderr.
    #[arg(long, short)]
    pub quiet: bool,
}

/// Parses the command line; a usage error is one line on stderr and exit code 2 (issue 10,
/// "Messages": no usage block, no `-- -1` tip, what the user typed echoed short). `--help`
/// and `--version` print as clap prints them and exit 0.
pub fn parse_args() -> Cli {
    use clap::error::ErrorKind;
    match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) if matches!(e.kind(), ErrorKind::DisplayHelp | ErrorKind::DisplayVersion) => {
            e.exit()
        }
        Err(e) => {
            eprintln!("error: {}", clap_line(&e));
            std::process::exit(2)
        }
    }
}

/// clap's message folded into one line: the error and its useful tips, without the usage
/// block, the "For more information" line and the `-- VALUE` tip.
pub fn clap_line(e: &clap::Error) -> String {
    use clap::error::ErrorKind;
    if e.kind() == ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand {
        return "no command given: use one of scenes, run, converge, plot, fit, record, replay, sweep (see `sieve --help`)".into();
    }
    let text = e.render().to_string();
    let mut parts: Vec<String> = Vec::new();
    for line in text.lines() {
        let l = line.trim();
        if l.is_empty()
            || l.starts_with("Usage:")
            || l.starts_with("For more information")
            || l.contains("as a value, use '--")
            || (!parts.is_empty() && line.starts_with("  ") && l.starts_with("sieve "))
        {
            continue;
        }
        parts.push(l.trim_start_matches("error: ").to_string());
    }
    let mut line = parts.join("; ");
    if !line.contains("--help") {
        line.push_str(" (see `sieve --help`)");
    }
    crate::text::shorten(&line)
}

/// `--grid NXxNY[xNZ]` as a TOML array.
/// A number given for `flag`: finite and `ok`, else exit 2 in one line naming the flag, the
/// value and what is `allowed`.
fn number_in(flag: &str, value: f64, ok: impl Fn(f64) -> bool, allowed: &str) -> Result<()> {
    if value.is_finite() && ok(value) {
        Ok(())
    } else {
        Err(Error::range("command line", flag, value, allowed))
    }
}

fn grid_array(grid: &str) -> Result<String> {
    let parts: Vec<&str> = grid.split(['x', 'X']).collect();
    let ok = !parts.is_empty()
        && parts.len() <= 3
        && parts
            .iter()
            .all(|p| !p.is_empty() && p.bytes().all(|b| b.is_ascii_digit()));
    if !ok {
        return Err(Error::input(format!(
            "--grid {grid}: expected cells per axis as NXxNY[xNZ], e.g. 128x64"
        )));
    }
    // Checked here: past 2^63 the number is no TOML integer, and the scene would be blamed
    // for a list it cannot read.
    let max = scene::validate::MAX_AXIS_CELLS;
    if parts
        .iter()
        .any(|p| !p.parse::<usize>().is_ok_and(|n| (1..=max).contains(&n)))
    {
        return Err(Error::range(
            "command line",
            "--grid",
            grid,
            &format!("1..={max} cells per axis, NXxNY[xNZ]"),
        ));
    }
    Ok(format!("[{}]", parts.join(",")))
}

/// The overrides of `sieve run` as `key=value` assignments, `--set` first.
fn run_overrides(a: &RunArgs, spec: &str) -> Result<Vec<String>> {
    let mut sets = a.set.clone();
    if let Some(s) = a.scheme {
        sets.push(format!("numerics.scheme=\"{}\"", s.name()));
    }
    if let Some(n) = a.cells {
        // One entry per axis: the dimension comes from the scene (after --set dim=...).
        let dim = scene_dim(spec, &a.set)?;
        sets.push(format!(
            "grid.cells=[{}]",
            vec![n.to_string(); dim].join(",")
        ));
    }
    if let Some(g) = &a.grid {
        sets.push(format!("grid.cells={}", grid_array(g)?));
    }
    if let Some(t) = &a.t_end {
        sets.push(format!("run.t_end={t}"));
    }
    if let Some(c) = &a.cfl {
        sets.push(format!("numerics.courant={c}"));
    }
    if !a.fields.is_empty() {
        use crate::scene::validate::output::ARRAYS;
        if a.fields.iter().any(|f| !ARRAYS.contains(&f.trim())) {
            return Err(Error::range(
                "command line",
                "--fields",
                a.fields.join(","),
                &format!("names among {}, comma separated", ARRAYS.join(", ")),
            ));
        }
        let quoted: Vec<String> = a.fields.iter().map(|f| format!("{:?}", f.trim())).collect();
        sets.push(format!("output.fields=[{}]", quoted.join(",")));
    }
    if let Some(n) = &a.vtk_every {
        sets.push(format!("output.vtk_every={n}"));
    }
    if a.compress {
        sets.push("output.compress=true".into());
    }
    if let Some(x) = &a.checkpoint_interval {
        sets.push(format!("run.checkpoint_interval={x}"));
    }
    Ok(sets)
}

fn scene_dim(spec: &str, sets: &[String]) -> Result<usize> {
    let src = scene::locate(spec)?;
    let mut table = scene::parse_table(&src.label, &src.text)?;
    for s in sets {
        scene::apply_set(&src.label, &mut table, s)?;
    }
    match table.get("dim").and_then(|d| d.as_integer()) {
        Some(d @ 1..=3) => Ok(d as usize),
        other => Err(Error::range(
            &src.label,
            "dim",
            other.map_or("missing".into(), |d| d.to_string()),
            "1, 2 or 3",
        )),
    }
}

/// The scene, its fields, the output directory and the checkpoint options of `sieve run`
/// (with `--resume DIR`: the checkpoint's scene, or the given one if it is the same).
fn run_setup(a: &RunArgs) -> Result<(scene::Scene, scene::Fields, PathBuf, run::ResumeOptions)> {
    use crate::checkpoint::{SceneSource, Stored};
    let source = |spec: &str| -> Result<SceneSource> {
        let src = scene::locate(spec)?;
        Ok(SceneSource {
            label: src.label,
            text: src.text,
            sets: run_overrides(a, spec)?,
        })
    };
    let Some(dir) = &a.resume else {
        let spec = a
            .scene
            .clone()
            .unwrap_or_else(|| builtin::DEFAULT_SCENE.into());
        let src = source(&spec)?;
        let (scene, fields) = src.load()?;
        let out = a
            .out
            .clone()
            .unwrap_or_else(|| PathBuf::from("runs").join(&scene.name));
        let resume = run::ResumeOptions {
            source: Some(src),
            resume: None,
        };
        return Ok((scene, fields, out, resume));
    };
    let stored = Stored::open(dir)?;
    let given = a.scene.is_some()
        || !a.set.is_empty()
        || a.scheme.is_some()
        || a.cells.is_some()
        || a.grid.is_some()
        || a.t_end.is_some()
        || a.cfl.is_some();
    let src = if given {
        // checked against the checkpoint's scene when the run starts
        source(a.scene.as_deref().unwrap_or(builtin::DEFAULT_SCENE))?
    } else {
        let mut src = stored.source()?;
        if let Some(x) = &a.checkpoint_interval {
            src.sets.push(format!("run.checkpoint_interval={x}"));
        }
        src
    };
    let (scene, fields) = src.load()?;
    #[cfg(feature = "mpi")]
    let quiet = a.quiet || crate::parallel_mpi::is_follower(); // under mpirun rank 0 says it
    #[cfg(not(feature = "mpi"))]
    let quiet = a.quiet;
    if !quiet {
        let e = &stored.entries;
        eprintln!(
            "sieve: resuming {} ({}) from its checkpoint at t = {} after {} steps",
            dir.display(),
            scene.name,
            e.f64("seg.time").map_or("?".into(), |t| format!("{t:.6e}")),
            e.u64("progress.steps")
                .map_or("?".into(), |n| n.to_string()),
        );
    }
    let resume = run::ResumeOptions {
        source: Some(src),
        resume: Some(stored),
    };
    Ok((scene, fields, dir.clone(), resume))
}

/// `sieve run` (under mpirun on every rank: [`crate::parallel_mpi`]).
fn run_command(a: &RunArgs) -> Result<()> {
    let (mut scene, fields, out, resume) = run_setup(a)?;
    scene.limits = estimate::Limits {
        max_steps: a.max_steps,
        max_cell_steps: a.max_cell_steps,
        max_output: a.max_output,
        flags: true,
    };
    #[cfg(feature = "mpi")]
    {
        // `mpirun -np K sieve run`: refused scenes end every rank before anything is built;
        // the ranks > 0 serve rank 0's run (docs/parallel.md)
        crate::parallel_mpi::check_scope(&scene)?;
        if crate::parallel_mpi::is_follower() {
            return crate::mpi_jobs::follow(&scene, &fields, resume.resume.as_ref());
        }
        if let (Some(n), Some((_, k)), false) = (a.threads, crate::parallel_mpi::world(), a.quiet) {
            eprintln!("note: --threads {n}: under mpirun each of the {k} ranks steps its rows on one thread");
        }
    }
    crate::parallel::request_threads(a.threads.and_then(|n| usize::try_from(n).ok()));
    let summary = run::run_scene_with(
        &scene,
        &fields,
        &RunOptions {
            out: out.clone(),
            quiet: a.quiet,
        },
        resume,
    )?;
    if !a.quiet {
        crate::outln!(
            "{}: {} steps on {:?} cells in {:.3} s ({:.3e} cell updates/s); psi_final = {:.4}, segregation_time = {}; wrote {}",
            summary.scene,
            summary.steps,
            summary.cells,
            summary.wall_seconds,
            summary.cell_updates_per_second,
            summary.psi_final,
            summary
                .segregation_time
                .map_or_else(|| "not reached".into(), |t| format!("{t:.4}")),
            out.display()
        )?;
        if let Some(f) = &summary.flow {
            crate::outln!(
                "flow ({}, back_coupling {}): {} flow steps on {:?} cells in {:.3} s (t = {:.4e} s), max c/c_rcp = {:.4}, T in [{:.3e}, {:.3e}], residual {:.3e} 1/s",
                f.equations,
                f.back_coupling,
                f.flow_steps,
                f.flow_cells,
                f.flow_seconds,
                f.flow_time,
                f.max_packing,
                f.t_min,
                f.t_max,
                f.residual
            )?;
            if let Some(o) = &f.outlet {
                crate::outln!("{}", crate::silo::outlet_line(o, summary.cells.len()))?;
            }
        }
        if let Some(d) = &summary.drum {
            crate::outln!("{}", crate::drum::line(d))?;
        }
    }
    Ok(())
}

/// Runs the parsed command line.
pub fn execute(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Scenes => {
            for b in builtin::BUILTINS {
                // Schema only: listing needs no field evaluation.
                let src = scene::locate(b.name)?;
                let f = scene::deserialize(&src.label, scene::parse_table(&src.label, &src.text)?)?;
                crate::outln!("{}\t{}D\t{}", f.name, f.dim, f.description)?;
            }
            Ok(())
        }
        Command::Run(a) => {
            #[cfg(feature = "mpi")]
            if crate::parallel_mpi::launch()? {
                let r = run_command(&a);
                return crate::parallel_mpi::finish(r);
            }
            run_command(&a)
        }
        Command::Record(a) => record(&a),
        Command::Fit(a) => {
            let (fit, dir) = crate::fit::fit(
                &a.scene,
                &a.set,
                &crate::fit::FitOptions {
                    target: a.target_time,
                    levels: a.levels.clone(),
                    threshold: a.threshold,
                    tolerance: a.tolerance,
                    out: a.out.clone(),
                    quiet: a.quiet,
                },
            )?;
            crate::out!("{}", crate::fit::table(&fit))?;
            if !a.quiet {
                crate::outln!("wrote {}", dir.display())?;
            }
            Ok(())
        }
        Command::Replay(a) => {
            let opts = soft_sensor::ReplayOptions {
                faults: if a.faults {
                    soft_sensor::Faults::DEMO
                } else {
                    soft_sensor::Faults::NONE
                },
            };
            let band = match &a.fines_band {
                None => None,
                Some(s) => {
                    let v: Vec<f32> = s
                        .split(',')
                        .map(|x| x.trim().parse::<f32>().unwrap_or(f32::NAN))
                        .collect();
                    if v.len() != 2 || !(0.0 <= v[0] && v[0] <= v[1] && v[1] <= 1.0) {
                        return Err(Error::range(
                            "command line",
                            "--fines-band",
                            s,
                            "LO,HI with 0 <= LO <= HI <= 1",
                        ));
                    }
                    Some([v[0], v[1]])
                }
            };
            if let Some(g) = a.shear_gain {
                number_in("--shear-gain", g, |g| g > 0.0 && g <= 100.0, "0 < G <= 100")?;
            }
            if let Some(l) = a.noise_term {
                number_in(
                    "--noise-term",
                    l,
                    |l| (0.0..=10.0).contains(&l),
                    "0 <= L <= 10",
                )?;
            }
            if let Some(w) = a.smoothing {
                // the sensor keeps W as a 32-bit float: below ~1e-45 it would be 0, and the
                // recording's configuration blamed
                let allowed = "1e-38 <= W <= 1 (1: no averaging)";
                number_in("--smoothing", w, |w| (1e-38..=1.0).contains(&w), allowed)?;
            }
            if let Some(b) = a.kinematic {
                number_in("--kinematic", b, |b| b > 0.0 && b <= 1.0, "0 < B <= 1 m")?;
                if a.faults
                    || a.fines_band.is_some()
                    || a.alarm_persist.is_some()
                    || a.shear_gain.is_some()
                    || a.noise_term.is_some()
                    || a.smoothing.is_some()
                    || a.spatial_passes.is_some()
                {
                    return Err(Error::at(
                        "command line",
                        "--kinematic",
                        "--kinematic replays the rate alone: it takes no --faults, --fines-band, --alarm-persist, --shear-gain, --noise-term, --smoothing or --spatial-passes",
                    ));
                }
                let bytes = std::fs::read(&a.file).map_err(|e| {
                    Error::at(
                        &a.file.display().to_string(),
                        "",
                        format!("cannot read the recording: {e}"),
                    )
                })?;
                let report = soft_sensor::replay_kinematic(&bytes, b)
                    .map_err(|e| Error::at(&a.file.display().to_string(), "", e))?;
                return crate::stdout::checked(soft_sensor::print_report(
                    &report,
                    a.every.max(1),
                    &mut std::io::stdout(),
                ));
            }
            // The replay's messages say what is wrong with the file; the file goes in front.
            let report = soft_sensor::replay_with(&a.file, &opts, |c| {
                if let Some(b) = band {
                    c.fines_band = b;
                    // The recorded hysteresis, narrowed to fit a narrow band.
                    c.fines_hysteresis = c.fines_hysteresis.min(0.5 * (b[1] - b[0]));
                }
                if let Some(n) = a.alarm_persist.and_then(|n| u16::try_from(n).ok()) {
                    c.alarm_persist = n;
                }
                if let Some(g) = a.shear_gain {
                    // S = S0 sqrt(T) (model.md 3.1): a gain on sqrt(T) is a gain on S0.
                    c.s0 *= g as f32;
                }
                if let Some(l) = a.noise_term {
                    c.noise_term = l as f32;
                }
                if let Some(w) = a.smoothing {
                    c.smoothing = w as f32;
                }
                if let Some(p) = a.spatial_passes.and_then(|p| u8::try_from(p).ok()) {
                    c.spatial_passes = p;
                }
                Ok(())
            })
            .map_err(|e| Error::at(&a.file.display().to_string(), "", e))?;
            crate::stdout::checked(soft_sensor::print_report(
                &report,
                a.every.max(1),
                &mut std::io::stdout(),
            ))
        }
        Command::Sweep(a) => sweep(&a),
        Command::Plot(a) => {
            let (dir, written) = crate::output::redraw::replot(&a.dir)?;
            crate::outln!("{}: {}", dir.display(), written.join(", "))?;
            Ok(())
        }
        Command::Converge(a) => {
            let mut sets = a.set.clone();
            if let Some(s) = a.scheme {
                sets.push(format!("numerics.scheme=\"{}\"", s.name()));
            }
            if let Some(t) = &a.t_end {
                sets.push(format!("run.t_end={t}"));
            }
            let (study, dir) = converge::converge(
                &a.scene,
                &sets,
                &ConvergeOptions {
                    levels: a.levels.clone(),
                    out: a.out.clone(),
                    quiet: a.quiet,
                },
            )?;
            crate::out!("{}", converge::table(&study))?;
            if !a.quiet {
                crate::outln!("wrote {}", dir.display())?;
            }
            Ok(())
        }
    }
}

/// The Slurm array index of this task (`SLURM_ARRAY_TASK_ID`), if the variable is set; a
/// value that is not an index is refused naming the variable (clap named `--task`, which the
/// user never typed).
fn slurm_task() -> Result<Option<usize>> {
    let Some(v) = std::env::var_os("SLURM_ARRAY_TASK_ID") else {
        return Ok(None);
    };
    let v = v.to_string_lossy();
    v.trim().parse().map(Some).map_err(|_| {
        Error::input(format!(
            "environment variable SLURM_ARRAY_TASK_ID = {v:?} is not a task index: allowed a whole number from 0 (the combinations of `sieve sweep --list`); unset it, or pass --task I"
        ))
    })
}

/// `sieve sweep`: list, one Slurm task, collect, or the whole sweep on the local cores.
fn sweep(a: &SweepArgs) -> Result<()> {
    use crate::sweep;
    let (axes, fixed) = sweep::parse_sets(&a.set)?;
    if a.list {
        crate::out!("{}", sweep::list(&axes))?;
        return Ok(());
    }
    sweep::check_plot(&a.plot)?;
    let fit = a.fit.as_deref().map(sweep::parse_fit).transpose()?;
    if let Some(fit) = fit {
        sweep::check_fit(&axes, fit)?;
    }
    // The scene must exist and every combination's keys must apply before anything runs.
    let src = scene::locate(&a.scene)?;
    for i in 0..sweep::combinations(&axes) {
        let mut sets = fixed.clone();
        sets.extend(
            sweep::combination(&axes, i)
                .into_iter()
                .map(|(k, v)| format!("{k}={v}")),
        );
        scene::load(&a.scene, &sets)?;
    }
    let name = scene::deserialize(&src.label, scene::parse_table(&src.label, &src.text)?)?.name;
    let opts = sweep::SweepOptions {
        scene: a.scene.clone(),
        axes,
        fixed,
        out: a
            .out
            .clone()
            .unwrap_or_else(|| PathBuf::from("runs").join(format!("{name}-sweep"))),
        jobs: a.jobs.unwrap_or_else(|| {
            std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get)
        }),
        task: match a.task {
            Some(i) => Some(i),
            // A collect or list job inherits the array's variable when it runs inside the
            // allocation: it is no task (it was refused as `--task` with `--collect`).
            None if a.collect => None,
            None => slurm_task()?,
        },
        plot: a.plot.clone(),
        fit,
        quiet: a.quiet,
    };
    if a.collect {
        let missing = sweep::collect(&opts)?;
        crate::outln!(
            "{}: sweep.csv, sweep.json{}",
            opts.out.display(),
            if missing > 0 {
                format!(" ({missing} combinations have no run yet)")
            } else {
                String::new()
            }
        )?;
        return Ok(());
    }
    let failed = sweep::sweep(&opts)?;
    let n = if opts.task.is_some() {
        1
    } else {
        sweep::combinations(&opts.axes)
    };
    if failed > 0 {
        return Err(Error::failure(format!(
            "{}: {failed} of {n} runs failed (their messages are in run-NNNN.log)",
            opts.out.display()
        )));
    }
    if !a.quiet {
        crate::outln!("{}: {n} runs", opts.out.display())?;
    }
    Ok(())
}

/// `NXxNZ` of `flag` with `lo..=hi` cells per axis.
fn two_axes(flag: &str, value: &str, lo: u64, hi: u64) -> Result<[u64; 2]> {
    let grid = grid_array(value).map_err(|_| {
        Error::input(format!(
            "{flag} {value}: expected NXxNZ with {lo}..={hi} per axis, e.g. 8x8"
        ))
    })?;
    let dims: Vec<u64> = grid
        .trim_matches(['[', ']'])
        .split(',')
        .filter_map(|p| p.parse().ok())
        .collect();
    if dims.len() != 2 || dims.iter().any(|&n| !(lo..=hi).contains(&n)) {
        return Err(Error::range(
            "command line",
            flag,
            value,
            &format!("NXxNZ with {lo}..={hi} per axis"),
        ));
    }
    Ok([dims[0], dims[1]])
}

/// The scenes `sieve record` accepts by name: 2D prescribed and frozen-flow built-ins, then
/// the legacy recorder scenes.
pub fn record_scene_names() -> Vec<String> {
    let mut names: Vec<String> = builtin::BUILTINS
        .iter()
        .filter(|b| {
            scene::parse_table(b.name, b.toml)
                .and_then(|t| scene::deserialize(b.name, t))
                .is_ok_and(|f| f.dim == 2 && f.model.equations != scene::Equations::Coupled)
        })
        .map(|b| b.name.to_string())
        .collect();
    names.extend(
        soft_sensor::Scene::ALL
            .iter()
            .map(|s| s.cli_name().to_string()),
    );
    names
}

/// Lowest `sieve record --rate` in Hz: the recording keeps times and the period as 32-bit
/// floats (frames x period must stay far below f32::MAX = 3.4e38 s).
const MIN_RATE: f64 = 1e-30;

/// `sieve record`: checks the options, records in memory, writes the file atomically.
fn record(a: &RecordArgs) -> Result<()> {
    let sensor = two_axes("--sensor-grid", &a.sensor_grid, 2, 16)?;
    let est = two_axes("--estimator-grid", &a.estimator_grid, 1, 1024)?;
    if est[0] * est[1] > soft_sensor::ESTIMATOR_CAPACITY as u64 {
        return Err(Error::range(
            "command line",
            "--estimator-grid",
            &a.estimator_grid,
            "at most 1024 cells (e.g. 32x32, 64x16): the firmware's capacity",
        ));
    }
    let unit = |x: f64| (0.0..=1.0).contains(&x);
    number_in("--noise", a.noise, unit, "0 <= SIGMA <= 1")?;
    let mhz = |m: f64| (1.0..=10_000.0).contains(&m);
    number_in("--cpu-mhz", a.cpu_mhz, mhz, "1 <= MHZ <= 10000")?;
    let share = |s: f64| s > 0.0 && s <= 1.0;
    number_in("--cpu-share", a.cpu_share, share, "0 < SHARE <= 1")?;
    if let Some(hz) = a.rate {
        // Both ends checked here, naming --rate: a recording keeps times as 32-bit floats,
        // and a tick must afford the estimator's fixed part and one substep (else the
        // sensor configuration or the truth was blamed, after the work).
        let (cpu_hz, grid) = (a.cpu_mhz * 1e6, [est[0] as usize, est[1] as usize]);
        let points = (sensor[0] * sensor[1]) as usize;
        let budget = |hz: f64| soft_sensor::cpu_budget(cpu_hz, a.cpu_share, 1.0 / hz);
        let need = budget(1.0).fixed(grid, points) + budget(1.0).substep(grid);
        let max_hz = cpu_hz * a.cpu_share / need.max(1) as f64;
        number_in(
            "--rate",
            hz,
            |hz| hz >= MIN_RATE && budget(hz).substeps(grid, points) > 0,
            &format!(
                "{MIN_RATE:e} <= HZ <= {max_hz:.4e} (above it a tick cannot afford the {need} cycles of a {}-cell estimator with {points} sensor points on a {} MHz CPU at share {}; --estimator-grid, --sensor-grid, --cpu-mhz and --cpu-share move it)",
                grid[0] * grid[1],
                a.cpu_mhz,
                a.cpu_share
            ),
        )?;
    }
    let period = a.rate.map(|hz| 1.0 / hz);
    if let Some(n) = a.frames {
        if !(1..=100_000).contains(&n) {
            return Err(Error::range("command line", "--frames", n, "1..=100000"));
        }
    }
    // Never over a file sieve did not write (host/src/output/target.rs).
    crate::output::target::claim_file(&a.out, &sieve_core::sensor::recording::RECORDING_MAGIC)?;
    let start = std::time::Instant::now();
    let sensor = [sensor[0] as u8, sensor[1] as u8];
    let estimator_cells = [est[0] as u16, est[1] as u16];
    match soft_sensor::Scene::from_name(&a.scene) {
        Some(legacy) => record_legacy(a, legacy, sensor, estimator_cells, period, start),
        None => record_catalogue(a, sensor, estimator_cells, period, start),
    }
}

/// `sieve record` of a legacy hand-written recorder scene.
fn record_legacy(
    a: &RecordArgs,
    legacy: soft_sensor::Scene,
    sensor: [u8; 2],
    estimator_cells: [u16; 2],
    period: Option<f64>,
    start: std::time::Instant,
) -> Result<()> {
    if !a.set.is_empty() {
        return Err(Error::at(
            "command line",
            "--set",
            format!(
                "{} is a legacy recorder scene without a scene file: --set applies to catalogue scenes",
                a.scene
            ),
        ));
    }
    let mut opts = soft_sensor::RecordOptions::new(legacy);
    opts.sensor = sensor;
    opts.estimator_cells = estimator_cells;
    opts.noise = a.noise;
    opts.seed = a.seed;
    opts.cpu_hz = a.cpu_mhz * 1e6;
    opts.cpu_share = a.cpu_share;
    if let Some(g) = &a.truth_grid {
        let t = two_axes("--truth-grid", g, 1, 64)?;
        opts.truth_cells = [t[0] as u16, t[1] as u16];
        if t[0] * t[1] > soft_sensor::TRUTH_CAPACITY as u64 {
            return Err(Error::range(
                "command line",
                "--truth-grid",
                g,
                "at most 64x64 for the legacy scenes",
            ));
        }
    }
    if let Some(p) = period {
        opts.period = p;
    }
    if let Some(n) = a.frames {
        opts.frames = n;
    }
    let (bytes, report) = soft_sensor::record_to_bytes(&opts).map_err(|e| {
        Error::at(
            "command line",
            "",
            format!("cannot record {}: {e}", a.scene),
        )
    })?;
    crate::output::write_file_atomically(&a.out, &bytes)?;
    crate::outln!(
        "recorded {} frames ({} bytes) of {} to {}; period {} s, truth {}x{}, estimator {}x{}, sensor {}x{}; final truth psi = {:.4}; {:.2} s",
        report.frames,
        report.file_bytes,
        legacy.cli_name(),
        a.out.display(),
        opts.period,
        opts.truth_cells[0],
        opts.truth_cells[1],
        opts.estimator_cells[0],
        opts.estimator_cells[1],
        sensor[0],
        sensor[1],
        report.final_truth_psi,
        start.elapsed().as_secs_f64()
    )?;
    Ok(())
}

/// `sieve record` of a catalogue scene (built-in or TOML file).
fn record_catalogue(
    a: &RecordArgs,
    sensor: [u8; 2],
    estimator_cells: [u16; 2],
    period: Option<f64>,
    start: std::time::Instant,
) -> Result<()> {
    if scene::builtin::find(&a.scene).is_none() && !std::path::Path::new(&a.scene).is_file() {
        return Err(Error::at(
            &a.scene,
            "SCENE",
            format!(
                "unknown recording scene: not a built-in scene or scene file; allowed: {}, or a 2D scene TOML file",
                record_scene_names().join(", ")
            ),
        ));
    }
    let mut sets = a.set.clone();
    if let Some(g) = &a.truth_grid {
        let t = two_axes("--truth-grid", g, 1, 65535)?;
        sets.push(format!("grid.cells=[{},{}]", t[0], t[1]));
    }
    // Dimension and model first: a 3D or coupled scene is refused before its fields are built.
    let dim = scene_dim(&a.scene, &sets)?;
    if dim != 2 {
        return Err(Error::range(
            &scene::locate(&a.scene)?.label,
            "dim",
            dim,
            "2 (the soft sensor estimates a 2D x-z field)",
        ));
    }
    let (sc, fields) = scene::load(&a.scene, &sets)?;
    crate::embedded::refuse(&sc, "sieve record")?;
    for w in crate::run::caveats(&sc) {
        eprintln!("{w}");
    }
    let opts = soft_sensor::SceneRecordOptions {
        estimator_cells,
        sensor,
        noise: a.noise,
        seed: a.seed,
        period,
        frames: a.frames,
        cpu_hz: a.cpu_mhz * 1e6,
        cpu_share: a.cpu_share,
    };
    let (bytes, report) = soft_sensor::record_scene(&sc, &fields, &opts)?;
    crate::output::write_file_atomically(&a.out, &bytes)?;
    for n in &report.notes {
        eprintln!("note: {}: {n}", sc.name);
    }
    if let Some(f) = &report.flow {
        crate::outln!(
            "flow ({}): {} flow steps on {:?} cells in {:.3} s (t = {:.4e} s), frozen; max speed {:.4e} m/s, T in [{:.3e}, {:.3e}]",
            f.equations, f.flow_steps, f.flow_cells, f.flow_seconds, f.flow_time, f.max_speed, f.t_min, f.t_max
        )?;
    }
    let r = &report.record;
    crate::outln!(
        "recorded {} frames ({} bytes) of {} to {}; period {:.4e} s ({:.2} estimator substeps), t = {:.4e} s, truth {}x{}, estimator {}x{}, sensor {}x{}, c = {:.4}, S0 = {:.4e}; final truth psi = {:.4}; {:.2} s",
        r.frames,
        r.file_bytes,
        sc.name,
        a.out.display(),
        report.period,
        report.period / report.estimator_dt,
        report.period * r.frames as f64,
        report.truth_cells[0],
        report.truth_cells[1],
        estimator_cells[0],
        estimator_cells[1],
        sensor[0],
        sensor[1],
        report.c,
        report.sensor_s0,
        r.final_truth_psi,
        start.elapsed().as_secs_f64()
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn cli_is_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn grid_flag_parses() {
        assert_eq!(grid_array("128x64").unwrap(), "[128,64]");
        assert_eq!(grid_array("4x5x6").unwrap(), "[4,5,6]");
        assert!(grid_array("12xx3").is_err());
        assert!(grid_array("a").is_err());
    }
}
