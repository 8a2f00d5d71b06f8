//! `sieve sweep`: the product of `--set key=v1,v2,...` values as independent runs.
//!
//! Each combination is an ordinary `sieve run` in its own run directory (`DIR/run-NNN`), run
//! as a child process of this binary, so a sweep is exactly what a user would get by typing
//! the runs one by one: same validation, same outputs, same bits. Combinations are numbered
//! in a fixed order (the first swept key varies slowest), so a Slurm job array can pick one
//! with its task index (`--task`, or `SLURM_ARRAY_TASK_ID`) and a final `--collect` builds
//! the table from whatever runs exist. The table never depends on how many runs ran at once.

use crate::error::{Error, Result};
use crate::output::{self, plot};
use crate::power_law::{self, Exponent, PowerFit};
use serde_json::{Map, Value};
use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

/// Marker file of a sweep directory: sieve only writes into a directory that is empty or has it.
pub const MARKER: &str = ".sieve-sweep";
/// Most combinations one sweep may have (each is a run directory).
pub const MAX_COMBINATIONS: usize = 10_000;

/// One swept key and its values, in the order given.
#[derive(Debug, Clone, PartialEq)]
pub struct Axis {
    /// Dotted scene key.
    pub key: String,
    /// Values as TOML text.
    pub values: Vec<String>,
}

/// What `sieve sweep` does.
#[derive(Debug, Clone)]
pub struct SweepOptions {
    /// Built-in scene name or scene file.
    pub scene: String,
    /// The swept keys (product of their values).
    pub axes: Vec<Axis>,
    /// Plain `--set key=value` assignments applied to every run (before the swept ones).
    pub fixed: Vec<String>,
    /// The sweep directory.
    pub out: PathBuf,
    /// Runs at once.
    pub jobs: usize,
    /// Run only this combination (Slurm array task).
    pub task: Option<usize>,
    /// Summary value plotted against the first swept key.
    pub plot: String,
    /// A power law fitted to the plotted value against that key (`--fit`), one per curve.
    pub fit: Option<Exponent>,
    /// No per-run lines.
    pub quiet: bool,
}

/// Splits `--set` arguments into swept axes (a value list with a top-level comma) and fixed
/// assignments. Commas inside brackets, parentheses or quotes do not split:
/// `grid.cells=[32,32],[64,64]` is two values.
pub fn parse_sets(sets: &[String]) -> Result<(Vec<Axis>, Vec<String>)> {
    let mut axes: Vec<Axis> = Vec::new();
    let mut fixed = Vec::new();
    for s in sets {
        let Some((key, rhs)) = s.split_once('=') else {
            return Err(Error::input(format!(
                "--set {}: expected KEY=VALUE[,VALUE...], e.g. material.s0=0.5,1,2",
                s
            )));
        };
        let key = key.trim();
        if key.is_empty() {
            return Err(Error::input(format!(
                "--set {}: the key before '=' is empty",
                s
            )));
        }
        let values = split_top_level(rhs)?;
        if values.iter().any(|v| v.trim().is_empty()) {
            return Err(Error::input(format!(
                "--set {}: an empty value in the list; write KEY=V1,V2,...",
                s
            )));
        }
        if values.len() == 1 {
            fixed.push(format!("{key}={}", values[0]));
        } else if axes.iter().any(|a| a.key == key) {
            return Err(Error::input(format!(
                "--set {key}: swept twice; give all its values in one --set"
            )));
        } else {
            axes.push(Axis {
                key: key.to_string(),
                values,
            });
        }
    }
    // A fixed value of a swept key would be overridden by the swept ones without a word.
    for f in &fixed {
        let key = f.split_once('=').map_or(f.as_str(), |(k, _)| k);
        if axes.iter().any(|a| a.key == key) {
            return Err(Error::input(format!(
                "--set {key}: given both a fixed value and swept values; give it in one --set, KEY=V or KEY=V1,V2,..."
            )));
        }
    }
    if combinations(&axes) > MAX_COMBINATIONS {
        // `combinations` saturates: the exact count where it fits in a u128
        let count = axes
            .iter()
            .try_fold(1u128, |n, a| n.checked_mul(a.values.len() as u128))
            .map_or_else(|| "more than 1e38".to_string(), |n| n.to_string());
        return Err(Error::input(format!(
            "--set: {count} combinations; at most {MAX_COMBINATIONS} per sweep (split it into several sweeps)"
        )));
    }
    Ok((axes, fixed))
}

/// The summary.json keys `--plot` may name: the dotted keys (as sweep.csv names its columns)
/// whose value is a number, read off a summary with every optional part present.
pub fn plottable_keys() -> Vec<String> {
    use crate::data::{FlowSummary, FrameSummary};
    use output::summary::{Stopped, Summary};
    let mut s = Summary {
        stopped: Some(Stopped {
            cell: Some(0),
            ..Stopped::default()
        }),
        dt_min: Some(0.0),
        dt_max: Some(0.0),
        dt_last: Some(0.0),
        segregation_time: Some(0.0),
        exact: Some(Default::default()),
        flow: Some(FlowSummary {
            flow_steps_to_steady: Some(0),
            outlet: Some(Default::default()),
            ..FlowSummary::default()
        }),
        geometry: Some(Default::default()),
        frame: Some(FrameSummary {
            period: Some(0.0),
            ..FrameSummary::default()
        }),
        drum: Some(Default::default()),
        ..Summary::default()
    };
    for side in ["x_low", "x_high", "y_low", "y_high", "z_low", "z_high"] {
        s.mass_out_sides.insert(side.into(), 0.0);
    }
    let mut flat = BTreeMap::new();
    flatten("", &serde_json::to_value(&s).unwrap_or_default(), &mut flat);
    flat.into_iter()
        .filter(|(_, v)| v.is_number())
        .map(|(k, _)| k)
        .collect()
}

/// Refuses (exit 2, before any run) a `--plot` key that no summary holds as a number: the plot
/// was silently left out. Lists the keys of its section (`flow.`, ...), or else the top-level
/// keys and the sections.
pub fn check_plot(key: &str) -> Result<()> {
    let keys = plottable_keys();
    if keys.iter().any(|k| k == key) {
        return Ok(());
    }
    let section = key.split_once('.').map(|(s, _)| format!("{s}."));
    let inside: Vec<&str> = keys
        .iter()
        .filter(|k| section.as_deref().is_some_and(|s| k.starts_with(s)))
        .map(String::as_str)
        .collect();
    let allowed = if inside.is_empty() {
        let mut top: Vec<String> = Vec::new();
        for k in &keys {
            let name = match k.split_once('.') {
                Some((s, _)) => format!("{s}.*"),
                None => k.clone(),
            };
            if !top.contains(&name) {
                top.push(name);
            }
        }
        top.join(", ")
    } else {
        inside.join(", ")
    };
    Err(Error::range(
        "command line",
        "--plot",
        key,
        &format!("a number of summary.json: {allowed}"),
    ))
}

/// `--fit MODEL`: `power` (free exponent) or `power:N` (exponent N given, e.g. `power:1.5`,
/// Beverloo's 2D law).
pub fn parse_fit(model: &str) -> Result<Exponent> {
    let allowed = format!(
        "`power` (y = A (x - x0)^n, n fitted) or `power:N` with 0 < N <= {} (n given, e.g. power:1.5 for Beverloo's 2D law)",
        power_law::MAX_EXPONENT
    );
    match model.trim().split_once(':') {
        None if model.trim() == "power" => Ok(Exponent::Free),
        Some((name, n)) if name.trim() == "power" => match n.trim().parse::<f64>() {
            Ok(n) if n > 0.0 && n <= power_law::MAX_EXPONENT => Ok(Exponent::Fixed(n)),
            Ok(_) => Err(Error::range("command line", "--fit", model, &allowed)),
            Err(_) => Err(Error::at(
                "command line",
                "--fit",
                format!(
                    "`{model}`: the exponent after `power:` is not a number; allowed {allowed}"
                ),
            )),
        },
        // Not a number out of range but a model sieve does not know: say so.
        _ => Err(Error::at(
            "command line",
            "--fit",
            format!("`{model}` is not a model sieve fits: allowed {allowed}"),
        )),
    }
}

/// Refuses (exit 2, before any run) a `--fit` that the sweep cannot feed: the fit is of the
/// plotted value against the first swept key with numeric values, so that key must have the
/// points the fit needs.
pub fn check_fit(axes: &[Axis], fit: Exponent) -> Result<()> {
    let need = fit.min_points();
    let first = axes.iter().find(|a| numeric(a).is_some());
    match first {
        Some(a) if a.values.len() >= need => Ok(()),
        Some(a) => Err(Error::input(format!(
            "command line: --fit fits the plotted value against {}, which has {} values; allowed: at least {need} (--set {}=v1,v2,...)",
            a.key,
            a.values.len(),
            a.key
        ))),
        None => Err(Error::input(format!(
            "command line: --fit needs a swept key with numeric values (at least {need}), e.g. --set boundary.flow.z_low.outlet.width=0.03,0.04,0.05,0.06"
        ))),
    }
}

/// The axis's values as numbers, if every one is a number (`--set w=0.03, 0.04`: spaces
/// allowed). The plot and the fit take the first swept key for which this is `Some`.
fn numeric(a: &Axis) -> Option<Vec<f64>> {
    a.values.iter().map(|v| v.trim().parse().ok()).collect()
}

/// Splits at commas outside brackets, parentheses and quotes.
fn split_top_level(s: &str) -> Result<Vec<String>> {
    let mut out = Vec::new();
    let mut depth = 0i64;
    let mut quote: Option<char> = None;
    let mut cur = String::new();
    for ch in s.chars() {
        match (quote, ch) {
            (Some(q), c) if c == q => {
                quote = None;
                cur.push(c);
            }
            (Some(_), c) => cur.push(c),
            (None, '"' | '\'') => {
                quote = Some(ch);
                cur.push(ch);
            }
            (None, '[' | '(' | '{') => {
                depth += 1;
                cur.push(ch);
            }
            (None, ']' | ')' | '}') => {
                depth -= 1;
                cur.push(ch);
            }
            (None, ',') if depth == 0 => out.push(std::mem::take(&mut cur)),
            (None, c) => cur.push(c),
        }
    }
    if depth != 0 || quote.is_some() {
        return Err(Error::input(format!(
            "--set ...={}: unbalanced brackets or quotes in the value list",
            s
        )));
    }
    out.push(cur);
    Ok(out.into_iter().map(|v| v.trim().to_string()).collect())
}

/// Number of combinations (1 for no axes).
pub fn combinations(axes: &[Axis]) -> usize {
    axes.iter()
        .map(|a| a.values.len())
        .fold(1usize, |n, k| n.saturating_mul(k))
}

/// The values of combination `index`: the first axis varies slowest.
pub fn combination(axes: &[Axis], index: usize) -> Vec<(String, String)> {
    let mut rest = index;
    let mut picks = vec![0usize; axes.len()];
    for (j, a) in axes.iter().enumerate().rev() {
        picks[j] = rest % a.values.len();
        rest /= a.values.len();
    }
    axes.iter()
        .zip(picks)
        .map(|(a, k)| (a.key.clone(), a.values[k].clone()))
        .collect()
}

/// The run directory of combination `index`.
pub fn run_dir(out: &Path, index: usize) -> PathBuf {
    out.join(format!("run-{index:04}"))
}

/// `--list`: one line per combination, `index<TAB>key=value ...`.
pub fn list(axes: &[Axis]) -> String {
    let mut s = String::new();
    for i in 0..combinations(axes) {
        let c = combination(axes, i);
        let kv: Vec<String> = c.iter().map(|(k, v)| format!("{k}={v}")).collect();
        s.push_str(&format!("{i}\t{}\n", kv.join(" ")));
    }
    s
}

/// Creates the sweep directory, or accepts it if it is empty or was written by a sweep. Never
/// the current directory or one of its parents (as `sieve run --out`). A whole sweep holds the
/// directory's lock (a second sweep into it is refused); the tasks of a Slurm job array run
/// side by side in one directory, so a task (`lock = false`) takes only its run's own lock.
fn prepare_dir(out: &Path, lock: bool) -> Result<Option<output::target::Lock>> {
    output::target::refuse_ancestor(out)?;
    let parent = output::target::parent_of(out);
    std::fs::create_dir_all(&parent).map_err(|e| Error::io(&parent, e))?;
    let held = if lock {
        Some(output::target::Lock::take(out)?)
    } else {
        None
    };
    if out.exists() {
        if !out.is_dir() {
            return Err(Error::input(format!(
                "{}: --out exists and is not a directory; choose another --out",
                out.display()
            )));
        }
        let empty = std::fs::read_dir(out)
            .map_err(|e| Error::io(out, e))?
            .next()
            .is_none();
        if !empty && !out.join(MARKER).is_file() {
            return Err(Error::input(format!(
                "{}: exists and was not written by sieve sweep; choose another --out or move its contents",
                out.display()
            )));
        }
    }
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    output::write_file_atomically(
        &out.join(MARKER),
        format!("sieve {} sweep\n", env!("CARGO_PKG_VERSION")).as_bytes(),
    )?;
    Ok(held)
}

/// How one run ended.
#[derive(Debug, Clone)]
struct Outcome {
    index: usize,
    code: i32,
    seconds: f64,
    first_error: String,
    /// Warning lines the run printed (they stay in its log and its summary's `warnings`).
    warnings: usize,
}

/// Runs combination `index` as `sieve run` in a child process; its stderr goes to
/// `DIR/run-NNNN.log`.
fn run_one(opts: &SweepOptions, index: usize) -> Result<Outcome> {
    let exe = std::env::current_exe().map_err(|e| Error::failure(format!("sieve binary: {e}")))?;
    let dir = run_dir(&opts.out, index);
    let log_path = opts.out.join(format!("run-{index:04}.log"));
    let log = std::fs::File::create(&log_path).map_err(|e| Error::io(&log_path, e))?;
    let mut cmd = Command::new(exe);
    cmd.arg("run").arg(&opts.scene);
    for s in &opts.fixed {
        cmd.arg("--set").arg(s);
    }
    for (k, v) in combination(&opts.axes, index) {
        cmd.arg("--set").arg(format!("{k}={v}"));
    }
    cmd.arg("--out").arg(&dir).arg("--quiet");
    cmd.stdin(Stdio::null()).stdout(Stdio::null()).stderr(log);
    let start = Instant::now();
    let status = cmd
        .status()
        .map_err(|e| Error::failure(format!("cannot start sieve run: {e}")))?;
    let mut text = String::new();
    if let Ok(mut f) = std::fs::File::open(&log_path) {
        let _ = f.by_ref().take(4096).read_to_string(&mut text);
    }
    // A clean run's log is empty: keep only logs that say something.
    if status.success() && text.is_empty() {
        let _ = std::fs::remove_file(&log_path);
    }
    // The summary keeps every warning line; the log's first 4 KB may not (a run that wrote
    // no summary is counted from its log).
    let warnings = summary_warnings(&dir.join("summary.json"))
        .unwrap_or_else(|| text.lines().filter(|l| l.starts_with("warning:")).count());
    Ok(Outcome {
        index,
        code: status.code().unwrap_or(-1),
        seconds: start.elapsed().as_secs_f64(),
        first_error: text.lines().next().unwrap_or("").to_string(),
        warnings,
    })
}

/// How many lines the summary at `path` lists under `warnings` (0 when it has none); `None`
/// when there is no readable summary.
fn summary_warnings(path: &Path) -> Option<usize> {
    let v: Value = serde_json::from_str(&std::fs::read_to_string(path).ok()?).ok()?;
    Some(
        v.get("warnings")
            .and_then(Value::as_array)
            .map_or(0, Vec::len),
    )
}

/// Runs the sweep (or one task of it) and, when every combination ran, writes the table.
/// Returns the number of failed runs.
pub fn sweep(opts: &SweepOptions) -> Result<usize> {
    let n = combinations(&opts.axes);
    if let Some(t) = opts.task {
        if t >= n {
            return Err(Error::input(format!(
                "--task {t} (or SLURM_ARRAY_TASK_ID) is out of range: allowed 0..={} for {n} combinations (see --list)",
                n - 1
            )));
        }
    }
    let _lock = prepare_dir(&opts.out, opts.task.is_none())?;
    let indices: Vec<usize> = match opts.task {
        Some(t) => vec![t],
        None => (0..n).collect(),
    };
    let next = AtomicUsize::new(0);
    let finished = AtomicUsize::new(0);
    let outcomes = Mutex::new(Vec::<Result<Outcome>>::new());
    let jobs = opts.jobs.clamp(1, indices.len().max(1));
    std::thread::scope(|s| {
        for _ in 0..jobs {
            s.spawn(|| loop {
                let k = next.fetch_add(1, Ordering::Relaxed);
                let Some(&index) = indices.get(k) else { break };
                let r = run_one(opts, index);
                let k = finished.fetch_add(1, Ordering::Relaxed) + 1;
                if !opts.quiet {
                    report_line(opts, index, (k, indices.len()), &r);
                }
                outcomes.lock().unwrap_or_else(|e| e.into_inner()).push(r);
            });
        }
    });
    let mut outcomes = outcomes.into_inner().unwrap_or_else(|e| e.into_inner());
    let failed_to_start = outcomes.iter().find_map(|r| r.as_ref().err().cloned());
    if let Some(e) = failed_to_start {
        return Err(e);
    }
    let mut done: Vec<Outcome> = outcomes.drain(..).filter_map(|r| r.ok()).collect();
    done.sort_by_key(|o| o.index);
    let failed = done.iter().filter(|o| o.code != 0).count();
    if opts.task.is_none() {
        collect(opts)?;
    }
    Ok(failed)
}

fn report_line(opts: &SweepOptions, index: usize, (k, n): (usize, usize), r: &Result<Outcome>) {
    let kv: Vec<String> = combination(&opts.axes, index)
        .iter()
        .map(|(k, v)| format!("{k}={v}"))
        .collect();
    let kv = kv.join(" ");
    let line = match r {
        Ok(o) if o.code == 0 && o.warnings > 0 => format!(
            "sweep: [{k}/{n}] run-{index:04} ({kv}) done in {:.1} s with {} warning{} (run-{index:04}.log, summary.json)",
            o.seconds,
            o.warnings,
            if o.warnings == 1 { "" } else { "s" }
        ),
        Ok(o) if o.code == 0 => format!(
            "sweep: [{k}/{n}] run-{index:04} ({kv}) done in {:.1} s",
            o.seconds
        ),
        Ok(o) => format!(
            "sweep: [{k}/{n}] run-{index:04} ({kv}) failed (exit {}): {}",
            o.code, o.first_error
        ),
        Err(e) => format!("sweep: run-{index:04}: {e}"),
    };
    // what the user typed, echoed short (a huge value is clipped like in every message)
    eprintln!("{}", crate::text::shorten(&line));
}

/// Flattens a summary to `dotted.key -> value` for numbers, strings, booleans and null;
/// arrays of numbers become `a;b;c`.
fn flatten(prefix: &str, v: &Value, out: &mut BTreeMap<String, Value>) {
    match v {
        Value::Object(m) => {
            for (k, x) in m {
                let key = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                flatten(&key, x, out);
            }
        }
        Value::Array(a) => {
            let parts: Vec<String> = a.iter().map(cell).collect();
            out.insert(prefix.to_string(), Value::String(parts.join(";")));
        }
        other => {
            out.insert(prefix.to_string(), other.clone());
        }
    }
}

fn cell(v: &Value) -> String {
    match v {
        Value::Null => String::new(),
        Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

/// CSV field quoting: fields with a comma, quote or line break are quoted.
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// The rows of the table: one per combination, `None` where the run has no summary.
type Rows = Vec<(usize, Option<BTreeMap<String, Value>>)>;

fn read_rows(opts: &SweepOptions) -> Result<Rows> {
    let n = combinations(&opts.axes);
    let mut rows = Vec::with_capacity(n);
    for i in 0..n {
        let path = run_dir(&opts.out, i).join("summary.json");
        let row = match std::fs::read_to_string(&path) {
            Ok(text) => {
                let v: Value = serde_json::from_str(&text).map_err(|e| {
                    Error::failure(format!("{}: not a sieve summary: {e}", path.display()))
                })?;
                let mut flat = BTreeMap::new();
                flatten("", &v, &mut flat);
                Some(flat)
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
            Err(e) => return Err(Error::io(&path, e)),
        };
        rows.push((i, row));
    }
    Ok(rows)
}

/// Writes `sweep.csv`, `sweep.json` and `sweep.png` from the run directories that exist.
/// Returns the number of combinations without a summary.
pub fn collect(opts: &SweepOptions) -> Result<usize> {
    let rows = read_rows(opts)?;
    let missing = rows.iter().filter(|(_, r)| r.is_none()).count();
    // Columns: the union of every summary's keys, sorted (summaries of one scene share them).
    let mut columns: Vec<String> = rows
        .iter()
        .filter_map(|(_, r)| r.as_ref())
        .flat_map(|r| r.keys().cloned())
        .collect();
    columns.sort();
    columns.dedup();

    let mut csv = String::from("index,run,status");
    for a in &opts.axes {
        csv.push(',');
        csv.push_str(&csv_field(&a.key));
    }
    for c in &columns {
        csv.push(',');
        csv.push_str(&csv_field(c));
    }
    csv.push('\n');
    let mut json_rows = Vec::new();
    for (i, row) in &rows {
        let status = if row.is_some() { "done" } else { "missing" };
        let mut line = format!("{i},run-{i:04},{status}");
        let mut obj = Map::new();
        obj.insert("index".into(), Value::from(*i));
        obj.insert("run".into(), Value::from(format!("run-{i:04}")));
        obj.insert("status".into(), Value::from(status));
        let mut swept = Map::new();
        for (k, v) in combination(&opts.axes, *i) {
            line.push(',');
            line.push_str(&csv_field(&v));
            swept.insert(k, Value::from(v));
        }
        obj.insert("set".into(), Value::Object(swept));
        for c in &columns {
            line.push(',');
            let v = row.as_ref().and_then(|r| r.get(c));
            line.push_str(&csv_field(&v.map(cell).unwrap_or_default()));
        }
        csv.push_str(&line);
        csv.push('\n');
        if let Some(r) = row {
            obj.insert(
                "summary".into(),
                Value::Object(r.iter().map(|(k, v)| (k.clone(), v.clone())).collect()),
            );
        }
        json_rows.push(Value::Object(obj));
    }
    let mut doc = Map::new();
    doc.insert("scene".into(), Value::from(opts.scene.clone()));
    doc.insert(
        "fixed".into(),
        Value::from(
            opts.fixed
                .iter()
                .map(|s| Value::from(s.clone()))
                .collect::<Vec<_>>(),
        ),
    );
    doc.insert(
        "axes".into(),
        Value::from(
            opts.axes
                .iter()
                .map(|a| {
                    let mut m = Map::new();
                    m.insert("key".into(), Value::from(a.key.clone()));
                    m.insert("values".into(), Value::from(a.values.clone()));
                    Value::Object(m)
                })
                .collect::<Vec<_>>(),
        ),
    );
    doc.insert("runs".into(), Value::from(json_rows));
    let curves = curves(opts, &rows)?;
    let fits = match (opts.fit, &curves) {
        (Some(exponent), Some((ax, curves))) => fit_curves(opts, *ax, curves, exponent)?,
        _ => Vec::new(),
    };
    if opts.fit.is_some() && curves.is_none() {
        crate::outln!(
            "fit: not made: no run's summary.json has a number at {} (sweep.png not drawn either)",
            opts.plot
        )?;
    }
    if let (Some(exponent), Some((ax, _))) = (opts.fit, &curves) {
        doc.insert(
            "fit".into(),
            fits_json(opts, &opts.axes[*ax].key, exponent, &fits),
        );
    }
    let mut text = serde_json::to_string_pretty(&Value::Object(doc)).map_err(Error::failure)?;
    text.push('\n');
    output::write_file_atomically(&opts.out.join("sweep.csv"), csv.as_bytes())?;
    output::write_file_atomically(&opts.out.join("sweep.json"), text.as_bytes())?;
    if let Some((ax, curves)) = &curves {
        draw(opts, *ax, curves, &fits)?;
    }
    draw_psi(opts, &rows)?;
    Ok(missing)
}

/// `sweep_psi.png`: Psi(t) of every run that finished, on one figure, labelled by its swept
/// values (e.g. a tumbler at five speeds, issue 8). Skipped for a single run or more than 12
/// (the figure would be unreadable; each run keeps its own psi.png).
fn draw_psi(opts: &SweepOptions, rows: &Rows) -> Result<()> {
    let done: Vec<usize> = rows
        .iter()
        .filter(|(_, r)| r.is_some())
        .map(|(i, _)| *i)
        .collect();
    if done.len() < 2 || done.len() > 12 {
        return Ok(());
    }
    let mut threshold = 0.05;
    let mut curves = Vec::with_capacity(done.len());
    for &i in &done {
        let dir = run_dir(&opts.out, i);
        let path = dir.join("series.csv");
        let series = crate::output::redraw::read_series(&path)?;
        // A time no run reaches (a damaged file) would leave no axis to draw on: name the file.
        if let Some(r) = series
            .iter()
            .find(|r| !(r.t.is_finite() && r.t.abs() <= plot::MAX_PLOTTABLE))
        {
            return Err(Error::failure(format!(
                "{}: t = {:e} is not a time of a run; sweep_psi.png not drawn",
                path.display(),
                r.t
            )));
        }
        if let Some(t) = rows[i]
            .1
            .as_ref()
            .and_then(|r| r.get("psi_threshold"))
            .and_then(Value::as_f64)
        {
            threshold = t;
        }
        let label = combination(&opts.axes, i)
            .iter()
            .map(|(k, v)| format!("{k}={v}"))
            .collect::<Vec<_>>()
            .join(" ");
        curves.push((label, series.iter().map(|r| (r.t, r.psi)).collect()));
    }
    plot::time_curves(
        &opts.out.join("sweep_psi.png"),
        &format!("{}: mixing index of every run", opts.scene),
        &curves,
        threshold,
    )
}

/// The chosen summary value against the first swept key with numeric values (that key's
/// index and one curve per combination of the other keys, each sorted by x). None when no
/// swept key is numeric or the chosen value is not a number in any run.
fn curves(opts: &SweepOptions, rows: &Rows) -> Result<Option<(usize, Vec<plot::Curve>)>> {
    let Some((ax, xs)) = opts
        .axes
        .iter()
        .enumerate()
        .find_map(|(j, a)| numeric(a).map(|xs| (j, xs)))
    else {
        return Ok(None);
    };
    let others: Vec<Axis> = opts
        .axes
        .iter()
        .enumerate()
        .filter(|&(j, _)| j != ax)
        .map(|(_, a)| a.clone())
        .collect();
    let mut curves: Vec<plot::Curve> = Vec::new();
    for j in 0..combinations(&others) {
        let fixed = combination(&others, j);
        let label = fixed
            .iter()
            .map(|(k, v)| format!("{k}={v}"))
            .collect::<Vec<_>>()
            .join(" ");
        let mut pts = Vec::new();
        for (k, &x) in xs.iter().enumerate() {
            let index = index_of(&opts.axes, ax, k, &fixed);
            let y = rows
                .get(index)
                .and_then(|(_, r)| r.as_ref())
                .and_then(|r| r.get(&opts.plot))
                .and_then(Value::as_f64);
            if let Some(y) = y.filter(|y| y.is_finite()) {
                // A value past any physical one (a damaged summary) leaves no axis to draw on.
                if y.abs() > plot::MAX_PLOTTABLE {
                    return Err(Error::failure(format!(
                        "{}: {} = {y:e} is out of the plottable range; sweep.png not drawn (sweep.csv and sweep.json are written)",
                        run_dir(&opts.out, index).join("summary.json").display(),
                        opts.plot
                    )));
                }
                pts.push((x, y));
            }
        }
        pts.sort_by(|a, b| a.0.total_cmp(&b.0));
        if !pts.is_empty() {
            curves.push((label, pts));
        }
    }
    Ok((!curves.is_empty()).then_some((ax, curves)))
}

/// `sweep.png`: the curves, and each fitted law drawn over its curve's x range.
fn draw(
    opts: &SweepOptions,
    ax: usize,
    curves: &[plot::Curve],
    fits: &[(String, std::result::Result<PowerFit, String>)],
) -> Result<()> {
    let mut fitted = Vec::with_capacity(fits.len());
    for ((_, pts), (label, fit)) in curves.iter().zip(fits) {
        let Ok(f) = fit else {
            // An empty curve keeps the colours of the fits that follow paired with theirs.
            fitted.push((String::new(), Vec::new()));
            continue;
        };
        let (lo, hi) = (pts[0].0, pts[pts.len() - 1].0);
        let line: Vec<(f64, f64)> = (0..=64)
            .map(|k| lo + (hi - lo) * k as f64 / 64.0)
            .map(|x| (x, f.at(x)))
            .filter(|p| p.1.is_finite())
            .collect();
        let name = if label.is_empty() {
            format!("fit: {}", law_text(f))
        } else {
            format!("fit {label}: {}", law_text(f))
        };
        fitted.push((name, line));
    }
    let key = &opts.axes[ax].key;
    plot::xy_curves(
        &opts.out.join("sweep.png"),
        &format!("{}: {} against {key}", opts.scene, opts.plot),
        key,
        &opts.plot,
        curves,
        &fitted,
    )
}

/// `A (x - x0)^n` with the fitted numbers, as the plot legend and the stdout line give it.
fn law_text(f: &PowerFit) -> String {
    let offset = if f.x0 < 0.0 {
        format!("x + {:.4e}", -f.x0)
    } else {
        format!("x - {:.4e}", f.x0)
    };
    format!("{:.4e} ({offset})^{:.4}", f.a, f.n)
}

/// Fits every curve that has the points the law needs; prints one line per curve on stdout
/// (a curve that cannot be fitted says why there, and the sweep goes on: its table is
/// written either way).
fn fit_curves(
    opts: &SweepOptions,
    ax: usize,
    curves: &[plot::Curve],
    exponent: Exponent,
) -> Result<Vec<(String, std::result::Result<PowerFit, String>)>> {
    let key = &opts.axes[ax].key;
    let mut out = Vec::with_capacity(curves.len());
    for (label, pts) in curves {
        let fit = power_law::fit(pts, exponent);
        let at = if label.is_empty() {
            String::new()
        } else {
            format!(" ({label})")
        };
        match &fit {
            Ok(f) => crate::outln!(
                "fit{at}: {} = A ({key} - x0)^n with A = {:.6e}{}, x0 = {:.6e}{}, n = {:.6}{}; largest residual {:.3} % over {} runs",
                opts.plot,
                f.a,
                plus_minus(f.se[0]),
                f.x0,
                plus_minus(f.se[1]),
                f.n,
                match exponent {
                    Exponent::Free => format!("{} (fitted)", plus_minus(f.se[2])),
                    Exponent::Fixed(_) => " (given)".into(),
                },
                100.0 * f.max_residual,
                pts.len()
            )?,
            Err(why) => crate::outln!("fit{at}: {} against {key} not fitted: {why}", opts.plot)?,
        }
        out.push((label.clone(), fit));
    }
    Ok(out)
}

/// ` ± 1.23e-2`: a standard error as the stdout line gives it (`± n/a` when it could not be
/// estimated).
fn plus_minus(se: f64) -> String {
    if se.is_finite() {
        format!(" ± {se:.2e}")
    } else {
        " ± n/a".into()
    }
}

/// sweep.json's `fit`: the law, its x and y, and per curve the constants or why not.
fn fits_json(
    opts: &SweepOptions,
    key: &str,
    exponent: Exponent,
    fits: &[(String, std::result::Result<PowerFit, String>)],
) -> Value {
    let mut m = Map::new();
    m.insert("law".into(), Value::from("y = a (x - x0)^n"));
    m.insert("x".into(), Value::from(key));
    m.insert("y".into(), Value::from(opts.plot.clone()));
    m.insert(
        "exponent".into(),
        match exponent {
            Exponent::Free => Value::from("fitted"),
            Exponent::Fixed(n) => Value::from(n),
        },
    );
    let curves = fits
        .iter()
        .map(|(label, fit)| {
            let mut c = Map::new();
            c.insert("curve".into(), Value::from(label.clone()));
            match fit {
                Ok(f) => {
                    c.insert("a".into(), Value::from(f.a));
                    c.insert("x0".into(), Value::from(f.x0));
                    c.insert("n".into(), Value::from(f.n));
                    c.insert("max_residual".into(), Value::from(f.max_residual));
                    // null when not estimated (serde_json writes NaN as null)
                    c.insert("a_se".into(), Value::from(f.se[0]));
                    c.insert("x0_se".into(), Value::from(f.se[1]));
                    c.insert("n_se".into(), Value::from(f.se[2]));
                }
                Err(why) => {
                    c.insert("error".into(), Value::from(why.clone()));
                }
            }
            Value::Object(c)
        })
        .collect::<Vec<_>>();
    m.insert("curves".into(), Value::from(curves));
    Value::Object(m)
}

/// The index of the combination with value `k` on axis `ax` and the other axes as `fixed`
/// (in axis order without `ax`).
fn index_of(axes: &[Axis], ax: usize, k: usize, fixed: &[(String, String)]) -> usize {
    let mut others = fixed.iter();
    axes.iter().enumerate().fold(0, |index, (j, a)| {
        let pick = if j == ax {
            k
        } else {
            let (_, v) = others.next().expect("one fixed value per other axis");
            a.values
                .iter()
                .position(|x| x == v)
                .expect("value of the axis")
        };
        index * a.values.len() + pick
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `--fit`: the two models, spaces allowed around their parts; an unknown model is named
    /// as such, a bad exponent as out of range.
    #[test]
    fn fit_models_parse_and_say_what_is_wrong() {
        assert_eq!(parse_fit(" power ").unwrap(), Exponent::Free);
        assert_eq!(parse_fit("power : 1.5").unwrap(), Exponent::Fixed(1.5));
        let e = parse_fit("beverloo").unwrap_err().to_string();
        assert!(
            e.contains("`beverloo` is not a model sieve fits: allowed `power`"),
            "{e}"
        );
        let e = parse_fit("powr:1.5").unwrap_err().to_string();
        assert!(e.contains("is not a model"), "{e}");
        let e = parse_fit("power:-1").unwrap_err().to_string();
        assert!(e.contains("= power:-1 is out of range"), "{e}");
        for bad in ["power:", "power:1.5x", "power:nan"] {
            let e = parse_fit(bad).unwrap_err().to_string();
            let says = if bad == "power:nan" {
                "out of range"
            } else {
                "is not a number"
            };
            assert!(e.contains(says), "{bad}: {e}");
        }
    }

    #[test]
    fn value_lists_split_at_top_level_commas_only() {
        let (axes, fixed) = parse_sets(&[
            "grid.cells=[32,32],[64,64]".into(),
            "initial.phi=min(c,0.3),c/2".into(),
            "material.s0=2".into(),
            "numerics.scheme=\"a,b\",\"c\"".into(),
        ])
        .unwrap();
        assert_eq!(axes.len(), 3);
        assert_eq!(axes[0].values, ["[32,32]", "[64,64]"]);
        assert_eq!(axes[1].values, ["min(c,0.3)", "c/2"]);
        assert_eq!(axes[2].values, ["\"a,b\"", "\"c\""]);
        assert_eq!(fixed, ["material.s0=2"]);
    }

    /// The plot and the fit read a swept key as numbers by one rule, spaces allowed, so the
    /// fit is refused up front exactly when the plot would have no numeric key.
    #[test]
    fn a_key_is_numeric_when_every_value_is_a_number() {
        let axis = |v: &[&str]| Axis {
            key: "k".into(),
            values: v.iter().map(|s| s.to_string()).collect(),
        };
        assert_eq!(numeric(&axis(&["0.03", " 0.04 "])), Some(vec![0.03, 0.04]));
        assert_eq!(numeric(&axis(&["[40]", "[80]"])), None);
        assert_eq!(numeric(&axis(&["1", "two"])), None);
        let axes = [axis(&["[40]", "[80]"]), axis(&["1", " 2", "3 "])];
        assert!(check_fit(&axes, Exponent::Fixed(1.5)).is_ok());
        assert!(check_fit(&axes, Exponent::Free).is_err());
    }

    #[test]
    fn combinations_are_numbered_first_key_slowest() {
        let axes = vec![
            Axis {
                key: "a".into(),
                values: vec!["1".into(), "2".into()],
            },
            Axis {
                key: "b".into(),
                values: vec!["x".into(), "y".into(), "z".into()],
            },
        ];
        assert_eq!(combinations(&axes), 6);
        assert_eq!(
            combination(&axes, 4),
            vec![("a".into(), "2".into()), ("b".into(), "y".into())]
        );
        assert_eq!(list(&axes).lines().nth(5), Some("5\ta=2 b=z"));
    }

    #[test]
    fn index_of_inverts_combination() {
        let axes = vec![
            Axis {
                key: "a".into(),
                values: vec!["1".into(), "2".into()],
            },
            Axis {
                key: "b".into(),
                values: vec!["x".into(), "y".into(), "z".into()],
            },
            Axis {
                key: "c".into(),
                values: vec!["p".into(), "q".into()],
            },
        ];
        for i in 0..combinations(&axes) {
            let c = combination(&axes, i);
            for ax in 0..3 {
                let k = axes[ax].values.iter().position(|v| *v == c[ax].1).unwrap();
                let fixed: Vec<_> = c
                    .iter()
                    .enumerate()
                    .filter(|&(j, _)| j != ax)
                    .map(|(_, p)| p.clone())
                    .collect();
                assert_eq!(index_of(&axes, ax, k, &fixed), i);
            }
        }
    }

    #[test]
    fn bad_lists_are_one_line_input_errors() {
        for bad in ["material.s0", "=1,2", "a=1,,2", "a=[1,2", "a=\"x,y"] {
            let e = parse_sets(&[bad.into()]).unwrap_err();
            assert_eq!(e.exit_code(), 2, "{bad}");
            assert_eq!(e.to_string().lines().count(), 1, "{bad}");
        }
        let twice = parse_sets(&["a=1,2".into(), "a=3,4".into()]).unwrap_err();
        assert!(twice.to_string().contains("swept twice"));
        let many: Vec<String> = (0..6).map(|k| format!("k{k}=1,2,3,4,5")).collect();
        assert!(parse_sets(&many)
            .unwrap_err()
            .to_string()
            .contains("15625 combinations"));
    }

    /// The keys `--plot` may name are the numbers of summary.json, nested ones included (a
    /// key missing here would be refused before a sweep).
    #[test]
    fn plottable_keys_are_the_summarys_numbers() {
        let keys = plottable_keys();
        for k in [
            "psi_final",
            "segregation_time",
            "dt_min",
            "mass_out_sides.z_high",
            "exact.l1_phihat",
            "flow.max_packing",
            "flow.flow_steps_to_steady",
            "flow.outlet.steady_rate",
            "geometry.open_fraction",
            "frame.period",
            "drum.angle_of_repose_deg",
            "stopped.t",
        ] {
            assert!(keys.iter().any(|x| x == k), "{k} missing in {keys:?}");
            assert!(check_plot(k).is_ok(), "{k}");
        }
        for k in [
            "scene",
            "state_hash",
            "cells",
            "flow.outlet.emptied",
            "flow.equations",
        ] {
            assert!(!keys.iter().any(|x| x == k), "{k} is no number");
        }
    }
}
