//! Scene files: the TOML schema, loading (built-in name or path), `--set` overrides, and
//! deserialisation with the path of any offending key.
//!
//! Axis names: a 1D scene has the single, vertical axis `z`; 2D scenes have `x` (horizontal)
//! and `z` (vertical); 3D scenes `x`, `y`, `z`. Array keys (`grid.cells`, `gravity`,
//! `initial.u`, ...) list one entry per axis in that order. Expressions see `x`, `y`, `z`
//! (axes a scene does not have are 0).

pub mod builtin;
pub mod expr;
pub mod outlet;
pub mod schema_errors;
pub mod solver_errors;
pub mod validate;

use crate::error::{Error, Result};
use serde::Deserialize;
use sieve_core::{Boundary, Phase, Scheme, Transport};

pub use validate::frame::{FrameKind, FrameModel, FrameSpec};
pub use validate::geometry::{Geometry, GeometrySpec, ShapeKind};
pub use validate::{Fields, Scene};

/// A scene file as written, before validation. Unknown keys are errors.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    /// Scene name (also the default output directory `runs/<name>`).
    pub name: String,
    /// One-line description (shown by `sieve scenes`).
    #[serde(default)]
    pub description: String,
    /// Number of space dimensions, 1, 2 or 3.
    pub dim: i64,
    /// Which equations run and in which precision.
    #[serde(default)]
    pub model: ModelSpec,
    /// The box and its cells.
    pub grid: GridSpec,
    /// Numerical scheme.
    #[serde(default)]
    pub numerics: NumericsSpec,
    /// Material constants.
    pub material: MaterialSpec,
    /// Gravity, segregation direction, source of T.
    pub physics: PhysicsSpec,
    /// Initial (and, for prescribed scenes, fixed) fields.
    pub initial: InitialSpec,
    /// Boundary kinds per axis and inflow state.
    #[serde(default)]
    pub boundary: BoundarySpec,
    /// End time, output interval, diagnostics.
    pub run: RunSpec,
    /// Numerics of the granular flow (only with `model.equations` other than "prescribed").
    pub flow: Option<FlowSpec>,
    /// A container with walls that are not grid faces (cut cells; 2D and 3D).
    pub geometry: Option<GeometrySpec>,
    /// The frame of reference of a turning container.
    pub frame: Option<FrameSpec>,
    /// Which fields the VTK snapshots hold, how often, compressed or not.
    pub output: Option<OutputSpec>,
}

/// `[output]`: thinning and compression of the VTK snapshots (`fields/state_NNNN.vti`).
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputSpec {
    /// Arrays written: any of "phihat", "phi", "c", "T", "u", "p", "volume" [default: all the
    /// scene has]; phihat and c are always written (the pictures are drawn from them).
    pub fields: Option<Vec<String>>,
    /// Write a snapshot at every `vtk_every`-th output time (the first and the last always).
    pub vtk_every: Option<i64>,
    /// zlib-compress the arrays (vtkZLibDataCompressor).
    #[serde(default)]
    pub compress: bool,
}

/// `[model]`.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelSpec {
    /// Which equations run.
    #[serde(default)]
    pub equations: Equations,
    /// Floating-point type of the solver.
    #[serde(default)]
    pub precision: Precision,
    /// Back-coupling of the packing limits to phihat (model.md 4); only with a flow.
    pub back_coupling: Option<BackCoupling>,
}

/// Back-coupling of the packing limits `c_rcp(phihat)`, `c_rlp(phihat)` (model.md 4).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum BackCoupling {
    /// One-way coupling: the constants phi_rcp, phi_rlp.
    #[default]
    Off,
    /// The analytic R -> 0 bound.
    R0,
    /// The degree-5 fit for R = 1/2.
    Half,
}

impl BackCoupling {
    /// "off", "r0" or "half".
    pub fn name(self) -> &'static str {
        match self {
            BackCoupling::Off => "off",
            BackCoupling::R0 => "r0",
            BackCoupling::Half => "half",
        }
    }

    /// The core's packing switch.
    pub fn packing(self) -> sieve_core::closure::Packing {
        use sieve_core::closure::Packing;
        match self {
            BackCoupling::Off => Packing::Constant,
            BackCoupling::R0 => Packing::BoundR0,
            BackCoupling::Half => Packing::FitHalf,
        }
    }
}

/// `initial.fill`: how the bed's packing is set.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Fill {
    /// c as `initial.c` gives it.
    #[default]
    Given,
    /// The bed (cells where `initial.c` is at least the flow's free-surface threshold) at
    /// rest: each run of bed cells along gravity packed in the flow step's discrete balance
    /// under its own weight, cold (model.md 5.8); phihat as `initial.phi / initial.c` gives it.
    Settled,
}

impl Fill {
    /// "given" or "settled".
    pub fn name(self) -> &'static str {
        match self {
            Fill::Given => "given",
            Fill::Settled => "settled",
        }
    }
}

/// Which equations a scene runs.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Equations {
    /// Only the segregation equation; u, c and T are prescribed by the scene.
    #[default]
    Prescribed,
    /// The flow (model.md 2) is solved until steady, then frozen while segregation goes on.
    FrozenFlow,
    /// Flow and segregation advance together with a common time step.
    Coupled,
}

impl Equations {
    /// "prescribed", "frozen-flow" or "coupled".
    pub fn name(self) -> &'static str {
        match self {
            Equations::Prescribed => "prescribed",
            Equations::FrozenFlow => "frozen-flow",
            Equations::Coupled => "coupled",
        }
    }
}

/// Floating-point type of the solver.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    /// 64-bit.
    #[default]
    F64,
    /// 32-bit.
    F32,
}

impl Precision {
    /// "f64" or "f32".
    pub fn name(self) -> &'static str {
        match self {
            Precision::F64 => "f64",
            Precision::F32 => "f32",
        }
    }
}

/// `[grid]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridSpec {
    /// Cells per axis.
    pub cells: Vec<i64>,
    /// Lower corner of the box \[m\].
    pub lower: Vec<f64>,
    /// Upper corner of the box \[m\].
    pub upper: Vec<f64>,
}

/// `[numerics]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NumericsSpec {
    /// Face flux: modified (default), godunov, upwind.
    #[serde(default)]
    pub scheme: Scheme,
    /// Tracked phase: small (default) or large.
    #[serde(default)]
    pub phase: Phase,
    /// Courant number, 0 < C < 1.
    #[serde(default = "default_courant")]
    pub courant: f64,
    /// Face value of phihat in the carried transport of coupled runs: donor (default) or
    /// limited (second order, bounded; docs/model.md 5.7).
    #[serde(default, deserialize_with = "transport_name")]
    pub transport: Transport,
}

impl Default for NumericsSpec {
    fn default() -> Self {
        Self {
            scheme: Scheme::default(),
            phase: Phase::default(),
            courant: default_courant(),
            transport: Transport::default(),
        }
    }
}

/// `numerics.transport` by name; anything else (a number, a table, another word) is refused
/// naming the allowed values.
fn transport_name<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> std::result::Result<Transport, D::Error> {
    struct Name;
    impl serde::de::Visitor<'_> for Name {
        type Value = Transport;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("one of the words `donor` or `limited`")
        }
        fn visit_str<E: serde::de::Error>(self, v: &str) -> std::result::Result<Transport, E> {
            Transport::ALL
                .into_iter()
                .find(|t| t.name() == v)
                .ok_or_else(|| E::unknown_variant(v, &["donor", "limited"]))
        }
    }
    d.deserialize_str(Name)
}

fn default_courant() -> f64 {
    0.5
}

/// `[material]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    /// Segregation rate S0 [s^2/m].
    pub s0: f64,
    /// Remixing diffusivity D >= 0 [m^2/s].
    #[serde(default)]
    pub diffusion: f64,
    /// Random close packing of one grain size: upper bound of c.
    #[serde(default = "default_phi_rcp")]
    pub phi_rcp: f64,
    /// Heating prefactor a (for `temperature = "shear"`).
    #[serde(default = "default_heating")]
    pub heating: f64,
    /// eta0 \[m\] (for `temperature = "shear"`).
    pub eta0: Option<f64>,
    /// eps0 [1/m] (for `temperature = "shear"` and the flow).
    pub eps0: Option<f64>,
    /// lambda0 \[m\] (flow: conductivity prefactor).
    pub lambda0: Option<f64>,
    /// T0 [m^2/s^2] (flow: yield-pressure scale).
    #[serde(rename = "T0")]
    pub t0: Option<f64>,
    /// Random loose packing of one grain size (flow).
    pub phi_rlp: Option<f64>,
    /// Grain diameter d \[m\], Beverloo's `d` (model.md 7.6): no equation uses it; a scene
    /// with an outlet warns when the orifice is narrower than a few diameters.
    pub grain_diameter: Option<f64>,
}

fn default_phi_rcp() -> f64 {
    0.64
}
fn default_heating() -> f64 {
    1.5
}

/// `[physics]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PhysicsSpec {
    /// Gravity vector [m/s^2], one entry per axis.
    pub gravity: Vec<f64>,
    /// Segregation direction: "gravity", "flow" or a vector.
    #[serde(default)]
    pub direction: DirectionSpec,
    /// Source of T: "given" (initial.T) or "shear" (from the velocity gradient).
    #[serde(default)]
    pub temperature: TemperatureSpec,
}

/// Segregation direction as written.
#[derive(Debug, Clone)]
pub enum DirectionSpec {
    /// "gravity" or "flow".
    Name(String),
    /// A fixed vector, one entry per axis.
    Vector(Vec<f64>),
}

impl Default for DirectionSpec {
    fn default() -> Self {
        DirectionSpec::Name("gravity".into())
    }
}

/// Source of the granular temperature.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TemperatureSpec {
    /// T from `initial.T`.
    #[default]
    Given,
    /// `T = heating eta0 / eps0 kappa:kappa` from the prescribed velocity.
    Shear,
}

/// An analytic expression, written as a TOML string or a plain number.
#[derive(Debug, Clone)]
pub enum ExprSrc {
    /// A constant.
    Number(f64),
    /// An expression in x, y, z (and c where allowed).
    Text(String),
}

// Hand-written visitors instead of `#[serde(untagged)]`: a wrong type then says what is
// allowed instead of "data did not match any variant".
impl<'de> Deserialize<'de> for ExprSrc {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl serde::de::Visitor<'_> for V {
            type Value = ExprSrc;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a number or an expression string such as \"0.5 * c\"")
            }
            fn visit_f64<E>(self, v: f64) -> Result<ExprSrc, E> {
                Ok(ExprSrc::Number(v))
            }
            fn visit_i64<E>(self, v: i64) -> Result<ExprSrc, E> {
                Ok(ExprSrc::Number(v as f64))
            }
            fn visit_u64<E>(self, v: u64) -> Result<ExprSrc, E> {
                Ok(ExprSrc::Number(v as f64))
            }
            fn visit_str<E>(self, v: &str) -> Result<ExprSrc, E> {
                Ok(ExprSrc::Text(v.to_string()))
            }
        }
        d.deserialize_any(V)
    }
}

impl<'de> Deserialize<'de> for DirectionSpec {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> serde::de::Visitor<'de> for V {
            type Value = DirectionSpec;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("\"gravity\", \"flow\" or a vector of one number per axis")
            }
            fn visit_str<E>(self, v: &str) -> Result<DirectionSpec, E> {
                Ok(DirectionSpec::Name(v.to_string()))
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                mut seq: A,
            ) -> Result<DirectionSpec, A::Error> {
                let mut v = Vec::new();
                while let Some(x) = seq.next_element::<f64>()? {
                    v.push(x);
                }
                Ok(DirectionSpec::Vector(v))
            }
        }
        d.deserialize_any(V)
    }
}

/// `[initial]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InitialSpec {
    /// Volume fraction c(x, y, z).
    pub c: ExprSrc,
    /// Granular temperature T(x, y, z) [m^2/s^2]; required unless `temperature = "shear"`.
    #[serde(rename = "T")]
    pub t: Option<ExprSrc>,
    /// Velocity components [m/s], one per axis; default 0.
    pub u: Option<Vec<ExprSrc>>,
    /// Small-phase fraction phi(x, y, z, c).
    pub phi: ExprSrc,
    /// "given" (default) or "settled" (the bed at rest under its weight; flow scenes).
    pub fill: Option<Fill>,
}

/// `[flow]`: numerics of the granular flow.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FlowSpec {
    /// Frozen flow: steady when the residual max |du|/(dt max(|u|, u_ref)) < this [1/s].
    pub steady_tolerance: Option<f64>,
    /// Least flow steps before the steady test counts.
    pub min_steps: Option<i64>,
    /// Most flow steps to reach the steady state.
    pub max_steps: Option<i64>,
    /// Temperature floor of the transport coefficients [m^2/s^2].
    pub t_min: Option<f64>,
    /// Relative tolerance of the flow's CG solves, 1e-14 <= tol <= 1e-3 (default 1e-10).
    pub cg_tolerance: Option<f64>,
    /// Relative tolerance of the implicit pressure solve alone, 1e-14 <= tol <= 1e-3
    /// (default: `cg_tolerance` if given, else the core's default).
    pub cg_tolerance_pressure: Option<f64>,
    /// Courant number of the flow, 0 < C <= 0.5.
    pub courant: Option<f64>,
    /// "auto" (default): spin the flow up on 4 columns and replicate when the scene is
    /// periodic in x and its initial data do not depend on x; "full": always the whole grid.
    pub spin_up: Option<SpinUp>,
    /// "explicit" (default): forward-backward pressure, acoustic time-step limit;
    /// "implicit": one pressure solve per step, no acoustic limit (docs/implicit-pressure.md).
    pub pressure: Option<PressureKind>,
    /// "spec" (default): the model's stress `eta grad u`; "objective": `eta (grad u +
    /// grad u^T)`, equal in simple shear, zero in a rigid rotation (model.md 2.6,
    /// docs/frames.md).
    pub stress: Option<StressKind>,
    /// "master" (default): a member's fragment acts on its master; "member": each merged
    /// cut cell takes its own wall fragment's term, the rule before 2026-12-05 (model.md
    /// 5.4, docs/silo.md section 7).
    pub merged_walls: Option<MergedWallsKind>,
}

/// Which cell of a merge group takes a merged cut cell's wall term (model.md 5.4).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MergedWallsKind {
    /// The member's own row.
    Member,
    /// The master's row, at the master's distance to the fragment.
    #[default]
    Master,
}

impl MergedWallsKind {
    /// The name in a scene file and in summary.json.
    pub fn name(self) -> &'static str {
        match self {
            MergedWallsKind::Member => "member",
            MergedWallsKind::Master => "master",
        }
    }
}

/// The viscous stress of the flow (model.md 2, 2.6).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StressKind {
    /// The model's `eta grad u`, heating `eta kappa:kappa`.
    #[default]
    Spec,
    /// The frame-indifferent `eta (grad u + grad u^T)`, heating `2 eta D:D`.
    Objective,
}

/// How the flow advances its pressure (model.md 5.3, 5.4).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PressureKind {
    /// Forward-backward, held to `a_s dt / h < 1`.
    #[default]
    Explicit,
    /// Linearised implicit pressure solve per step.
    Implicit,
}

/// Where the frozen flow is spun up.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SpinUp {
    /// 4 columns if the scene allows it (x-periodic, x-independent data), else full.
    #[default]
    Auto,
    /// The whole grid.
    Full,
}

/// `[boundary.flow.<side>]`: the tangential condition of a flow wall.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FlowWallSpec {
    /// "no-slip" (default), "slip" or "friction".
    pub wall: Option<WallKind>,
    /// Wall friction angle \[deg\] in [0, 90] (with `wall = "friction"`; 0 = slip, 90 = no-slip).
    pub friction_angle: Option<f64>,
    /// Tangential wall velocity [m/s], one entry per axis (normal entry 0).
    pub velocity: Option<Vec<f64>>,
    /// An opening (outlet) in the wall ([`outlet`]).
    pub outlet: Option<outlet::OutletSpec>,
}

/// Tangential condition of a flow wall.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum WallKind {
    /// u_B = u_W.
    #[default]
    NoSlip,
    /// Zero tangential stress.
    Slip,
    /// Partial slip by the wall friction angle.
    Friction,
}

/// `[boundary.flow]`: flow wall conditions per side (`x_low`, `x_high`, ..., `z_high`).
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FlowBoundarySpec {
    /// Low x side.
    pub x_low: Option<FlowWallSpec>,
    /// High x side.
    pub x_high: Option<FlowWallSpec>,
    /// Low y side.
    pub y_low: Option<FlowWallSpec>,
    /// High y side.
    pub y_high: Option<FlowWallSpec>,
    /// Low z side (bottom).
    pub z_low: Option<FlowWallSpec>,
    /// High z side (top).
    pub z_high: Option<FlowWallSpec>,
}

/// `[boundary]`: `[low, high]` kinds per axis (default wall), inflow state.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoundarySpec {
    /// Axis x.
    pub x: Option<[Boundary; 2]>,
    /// Axis y.
    pub y: Option<[Boundary; 2]>,
    /// Axis z.
    pub z: Option<[Boundary; 2]>,
    /// Dirichlet state at inflow sides.
    pub inflow: Option<InflowSpec>,
    /// Flow wall conditions (only with a flow).
    pub flow: Option<FlowBoundarySpec>,
}

/// `[boundary.inflow]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InflowSpec {
    /// phi(x, y, z, c) of the inflowing material (c is the boundary cell's).
    pub phi: ExprSrc,
}

/// `[run]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunSpec {
    /// End time \[s\].
    pub t_end: f64,
    /// Time between outputs \[s\].
    pub output_interval: f64,
    /// Segregation time = first time Psi < threshold (after Psi was >= threshold).
    #[serde(default = "default_psi_threshold")]
    pub psi_threshold: f64,
    /// A closed-form solution of this scene.
    pub exact: Option<ExactKind>,
    /// Wall-clock seconds between checkpoints of `sieve run` (none: no checkpoints).
    pub checkpoint_interval: Option<f64>,
    /// `[low, high]` of the discharge's fines fraction that is on-spec (scenes with an
    /// outlet; none: the bed's initial fraction +- 0.1).
    pub fines_band: Option<[f64; 2]>,
}

fn default_psi_threshold() -> f64 {
    0.05
}

/// Closed-form solutions a scene can name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ExactKind {
    /// `sieve_core::exact::ColumnA`.
    ColumnA,
}

/// The source of a scene: its label in messages (file path) and its text.
#[derive(Debug, Clone)]
pub struct Source {
    /// File name used in messages (`scenes/<name>.toml` for built-ins).
    pub label: String,
    /// TOML text.
    pub text: String,
}

/// Finds a scene: a built-in name, else a path to a TOML file.
pub fn locate(spec: &str) -> Result<Source> {
    if let Some(b) = builtin::find(spec) {
        return Ok(Source {
            label: format!("scenes/{}.toml", b.name),
            text: b.toml.to_string(),
        });
    }
    let path = std::path::Path::new(spec);
    let what = |m: &str| Err(Error::at(spec, "SCENE", m));
    // Say what the path is rather than "unknown scene" (issue 10, "Messages"): a directory, a
    // device or a missing file each need a different fix.
    match std::fs::metadata(path) {
        Ok(m) if m.is_dir() => {
            return what(
                "is a directory, not a scene file: give a scene TOML file inside it or a built-in name (see `sieve scenes`)",
            )
        }
        Ok(m) if !m.is_file() => {
            return what(
                "is not a regular file (a device, pipe or socket): give a scene TOML file or a built-in name (see `sieve scenes`)",
            )
        }
        Ok(m) if m.len() > MAX_SCENE_BYTES => {
            return Err(Error::range(
                spec,
                "SCENE",
                format!("a file of {} bytes", m.len()),
                &format!("scene files up to {MAX_SCENE_BYTES} bytes (is this a scene file?)"),
            ))
        }
        Ok(_) => {
            let bytes = std::fs::read(path)
                .map_err(|e| Error::at(spec, "", format!("cannot read scene file: {e}")))?;
            let text = String::from_utf8(bytes).map_err(|e| {
                Error::at(
                    spec,
                    "SCENE",
                    format!(
                        "not a text file (invalid UTF-8 at byte {}): a scene file is TOML text",
                        e.utf8_error().valid_up_to()
                    ),
                )
            })?;
            return Ok(Source {
                label: spec.to_string(),
                text,
            });
        }
        Err(e) if e.kind() == std::io::ErrorKind::PermissionDenied => {
            return Err(Error::at(spec, "", format!("cannot read scene file: {e}")))
        }
        Err(_) => {}
    }
    let looks_like_path = spec.contains(['/', '\\']) || spec.ends_with(".toml");
    if looks_like_path {
        return what("no such file: check the path, or give a built-in name (see `sieve scenes`)");
    }
    what(&format!(
        "unknown scene: not a built-in scene (allowed: {}) and no such file in the current directory",
        builtin::names().join(", ")
    ))
}

/// Largest scene file read (bytes): the largest built-in is a few kB; anything above this is
/// not a scene file, and reading it whole would only cost memory.
pub const MAX_SCENE_BYTES: u64 = 1 << 20;

/// Parses TOML text into a table; a syntax error names the line and column.
pub fn parse_table(label: &str, text: &str) -> Result<toml::Table> {
    text.parse::<toml::Table>().map_err(|e| {
        let place = e
            .span()
            .map(|s| {
                let before = &text[..s.start.min(text.len())];
                let line = before.matches('\n').count() + 1;
                let col = before.len() - before.rfind('\n').map_or(0, |p| p + 1) + 1;
                format!("line {line}, column {col}: ")
            })
            .unwrap_or_default();
        Error::at(label, "", format!("malformed TOML: {place}{}", e.message()))
    })
}

/// Applies `key=value` (dotted key; value in TOML syntax, else taken as a string) to `table`.
pub fn apply_set(label: &str, table: &mut toml::Table, assignment: &str) -> Result<()> {
    let (key, raw) = assignment.split_once('=').ok_or_else(|| {
        Error::at(
            label,
            "",
            format!("--set {assignment}: expected key=value, e.g. numerics.courant=0.4"),
        )
    })?;
    let key = key.trim();
    let raw = raw.trim();
    let parts: Vec<&str> = key.split('.').collect();
    if parts.iter().any(|p| p.is_empty()) {
        return Err(Error::at(
            label,
            "",
            format!("--set {assignment}: empty key component"),
        ));
    }
    // TOML syntax first (numbers, arrays, booleans, quoted strings); bare text is a string so
    // that `--set initial.c=0.5*z` works without shell-escaped quotes. A value that parses to
    // more than `v` (a newline and another assignment in it) is text too: its rest was once
    // dropped without a word.
    let value = format!("v = {raw}")
        .parse::<toml::Table>()
        .ok()
        .filter(|t| t.len() == 1)
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(raw.to_string()));
    let mut node = table;
    for (depth, part) in parts[..parts.len() - 1].iter().enumerate() {
        let entry = node
            .entry(part.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        node = match entry {
            toml::Value::Table(t) => t,
            _ => {
                return Err(Error::at(
                    label,
                    &parts[..=depth].join("."),
                    format!(
                        "--set {key}: `{}` is not a table",
                        parts[..=depth].join(".")
                    ),
                ))
            }
        };
    }
    node.insert(parts[parts.len() - 1].to_string(), value);
    Ok(())
}

/// Deserialises a table into a [`SceneFile`], naming the dotted path of a bad key in the
/// user's words ([`schema_errors`]).
pub fn deserialize(label: &str, table: toml::Table) -> Result<SceneFile> {
    let root = toml::Value::Table(table);
    // The root is kept for the error message, which quotes what was written (a clone of a few kB
    // once per load).
    serde_path_to_error::deserialize(root.clone())
        .map_err(|e| schema_errors::worded(label, &root, &e))
}

/// Loads a scene: locate, parse, apply overrides in order, deserialise, validate and evaluate
/// its fields on the grid.
pub fn load(spec: &str, sets: &[String]) -> Result<(Scene, Fields)> {
    let src = locate(spec)?;
    resolve(&src.label, &src.text, sets)
}

/// Parses scene text, applies the `--set` overrides in order, deserialises, validates and
/// evaluates the fields (what [`load`] and a checkpoint's stored scene share).
pub fn resolve(label: &str, text: &str, sets: &[String]) -> Result<(Scene, Fields)> {
    let mut table = parse_table(label, text)?;
    let before = table_paths(&table);
    for s in sets {
        apply_set(label, &mut table, s)?;
    }
    let file = deserialize(label, table).map_err(|e| started_by_set(label, e, &before, sets))?;
    let scene = Scene::validate(label, file)?;
    let fields = scene.evaluate_fields()?;
    Ok((scene, fields))
}

/// The dotted paths of every table in `table` (the scene's own, before the overrides).
fn table_paths(table: &toml::Table) -> Vec<String> {
    fn walk(t: &toml::Table, prefix: &str, out: &mut Vec<String>) {
        for (k, v) in t {
            if let toml::Value::Table(inner) = v {
                let path = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                walk(inner, &path, out);
                out.push(path);
            }
        }
    }
    let mut out = Vec::new();
    walk(table, "", &mut out);
    out
}

/// A `--set` into a table the scene does not have starts a new, incomplete one, and serde then
/// says only "missing field `shape`". Say what happened instead: which table is new, which
/// `--set` made it, and what it still needs (a silo's outlet width, say, lives under
/// `boundary.flow`, not under a `[geometry]` the flat silo does not have).
fn started_by_set(label: &str, err: Error, before: &[String], sets: &[String]) -> Error {
    // `deserialize` wrote "label: path: missing field `name`"
    let Error::Input(line) = &err else {
        return err;
    };
    let Some((path, field)) = line
        .strip_prefix(label)
        .and_then(|rest| rest.strip_prefix(": "))
        .and_then(|rest| rest.split_once(": missing field `"))
        .and_then(|(path, rest)| Some((path, rest.split('`').next()?)))
    else {
        return err;
    };
    for set in sets {
        let key = set.split_once('=').map_or(set.as_str(), |(k, _)| k).trim();
        let parts: Vec<&str> = key.split('.').collect();
        // The outermost table on the key's path that the scene did not have, if the missing
        // field is in it.
        let new_table = (1..parts.len())
            .map(|n| parts[..n].join("."))
            .find(|p| !before.contains(p))
            .filter(|t| path == t || path.starts_with(&format!("{t}.")));
        if let Some(table) = new_table {
            return Error::at(
                label,
                "",
                format!(
                    "--set {key}: this scene has no [{table}] table, so the --set starts a new one, which also needs `{field}`: check the key's name against {label}"
                ),
            );
        }
    }
    err
}
