//! Validation of a deserialised scene file into a [`Scene`] the solver can run, and the
//! evaluation of its analytic fields on the grid ([`Fields`]). Every failure is an input error
//! naming the file, the key and the allowed range.

use super::expr::{Expr, Vars};
use super::{
    BackCoupling, DirectionSpec, Equations, ExactKind, ExprSrc, FlowWallSpec, Precision, SceneFile,
    SpinUp, TemperatureSpec, WallKind,
};
use crate::error::{Error, Result};
use sieve_core::{Boundary, Phase, Scheme};

/// Compiled cell capacity for each dimension (index `dim - 1`): 65536 cells in 1D, 512 x 512
/// in 2D, 64^3 in 3D.
pub const CAPACITY: [usize; 3] = [65536, 262_144, 262_144];
/// Largest number of cells along one axis.
pub const MAX_AXIS_CELLS: usize = 65536;

/// Physical axis index (0 = x, 1 = y, 2 = z) of each solver axis, per dimension.
pub fn physical_axes(dim: usize) -> &'static [usize] {
    match dim {
        1 => &[2],
        2 => &[0, 2],
        _ => &[0, 1, 2],
    }
}

/// Names of the solver axes of a `dim`-dimensional scene.
pub fn axis_names(dim: usize) -> Vec<&'static str> {
    physical_axes(dim)
        .iter()
        .map(|&p| ["x", "y", "z"][p])
        .collect()
}

/// Segregation direction.
#[derive(Debug, Clone, PartialEq)]
pub enum Direction {
    /// Along gravity.
    Gravity,
    /// From the velocity gradient.
    Flow,
    /// A fixed vector (solver axis order).
    Fixed(Vec<f64>),
}

/// Source of T.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Temperature {
    /// As given by `initial.T`.
    Given,
    /// From the shear rate of the prescribed velocity.
    Shear {
        /// heating prefactor a
        heating: f64,
        /// eta0 [m]
        eta0: f64,
        /// eps0 [1/m]
        eps0: f64,
    },
}

/// The flow keeps `c <= (1 - FLOW_MARGIN) c_rcp` (`sieve_core::flow::FlowConfig::margin`).
pub const FLOW_MARGIN: f64 = 1e-3;

/// Tangential condition of one flow wall side.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum WallSlip {
    /// u_B = u_W.
    NoSlip,
    /// Zero tangential stress.
    Slip,
    /// Partial slip: `tan(phi_w)` and the angle in degrees.
    Friction {
        /// tan(phi_w)
        tan: f64,
        /// phi_w [deg]
        degrees: f64,
    },
}

/// One side of the box for the flow (only meaningful on wall sides).
#[derive(Debug, Clone, PartialEq)]
pub struct WallSide {
    /// Tangential condition.
    pub slip: WallSlip,
    /// Wall velocity, solver axis order (normal component 0).
    pub velocity: Vec<f64>,
    /// An opening in the wall (grains leave through it).
    pub outlet: Option<super::outlet::Outlet>,
}

/// The validated flow part of a scene (`model.equations` other than "prescribed").
#[derive(Debug, Clone, PartialEq)]
pub struct FlowModel {
    /// FrozenFlow or Coupled.
    pub equations: Equations,
    /// Back-coupling of the packing limits.
    pub back_coupling: BackCoupling,
    /// eta0 [m].
    pub eta0: f64,
    /// lambda0 [m].
    pub lambda0: f64,
    /// eps0 [1/m].
    pub eps0: f64,
    /// T0 [m^2/s^2].
    pub t0: f64,
    /// phi_rlp.
    pub phi_rlp: f64,
    /// Heating prefactor a.
    pub heating: f64,
    /// Wall conditions `[low, high]` per solver axis.
    pub walls: Vec<[WallSide; 2]>,
    /// Steady-state tolerance [1/s].
    pub steady_tolerance: f64,
    /// Least flow steps before the steady test counts.
    pub min_steps: u64,
    /// Most flow steps to steady state.
    pub max_steps: u64,
    /// T floor of the transport coefficients.
    pub t_min: f64,
    /// Flow Courant number.
    pub courant: f64,
    /// Spin-up policy.
    pub spin_up: SpinUp,
}

/// A validated scene: every number finite and in range, every expression compiled.
#[derive(Debug, Clone)]
pub struct Scene {
    /// File label used in messages.
    pub label: String,
    /// Scene name.
    pub name: String,
    /// Description.
    pub description: String,
    /// Dimension 1..=3.
    pub dim: usize,
    /// Solver precision.
    pub precision: Precision,
    /// Cells per solver axis.
    pub cells: Vec<usize>,
    /// Lower corner (solver axis order).
    pub lower: Vec<f64>,
    /// Upper corner.
    pub upper: Vec<f64>,
    /// Face flux.
    pub scheme: Scheme,
    /// Tracked phase.
    pub phase: Phase,
    /// Courant number.
    pub courant: f64,
    /// S0.
    pub s0: f64,
    /// Remixing diffusivity.
    pub diffusion: f64,
    /// Upper bound of c.
    pub phi_rcp: f64,
    /// Gravity (solver axis order).
    pub gravity: Vec<f64>,
    /// Segregation direction.
    pub direction: Direction,
    /// Source of T.
    pub temperature: Temperature,
    /// Boundary kinds `[low, high]` per solver axis.
    pub boundaries: Vec<[Boundary; 2]>,
    /// c(x).
    pub c: Expr,
    /// T(x) (unused with `temperature = "shear"`).
    pub t: Option<Expr>,
    /// u components (solver axis order).
    pub u: Vec<Expr>,
    /// phi(x, c).
    pub phi: Expr,
    /// Inflow phi(x, c), if a side is inflow.
    pub inflow_phi: Option<Expr>,
    /// End time.
    pub t_end: f64,
    /// Output interval.
    pub output_interval: f64,
    /// Psi threshold of the segregation time.
    pub psi_threshold: f64,
    /// Closed-form solution, if any.
    pub exact: Option<ExactKind>,
    /// The flow model, if the scene solves one.
    pub flow: Option<FlowModel>,
}

/// The fields of a scene evaluated at the cell centres (f64, solver cell order).
#[derive(Debug, Clone, Default)]
pub struct Fields {
    /// c per cell.
    pub c: Vec<f64>,
    /// T per cell (0 if derived from shear).
    pub t: Vec<f64>,
    /// Velocity per solver axis, per cell.
    pub u: Vec<Vec<f64>>,
    /// phi per cell.
    pub phi: Vec<f64>,
    /// Inflow phi per cell (only cells on an inflow side are meaningful).
    pub inflow: Vec<f64>,
}

fn finite(label: &str, key: &str, v: f64) -> Result<f64> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(Error::range(label, key, v, "a finite number"))
    }
}

fn vector(label: &str, key: &str, v: &[f64], dim: usize) -> Result<Vec<f64>> {
    if v.len() != dim {
        return Err(Error::range(
            label,
            key,
            format!("{v:?}"),
            &format!(
                "{dim} numbers, one per axis ({})",
                axis_names(dim).join(", ")
            ),
        ));
    }
    for (i, &x) in v.iter().enumerate() {
        finite(label, &format!("{key}[{i}]"), x)?;
    }
    Ok(v.to_vec())
}

impl Scene {
    /// Validates a scene file read from `label`.
    pub fn validate(label: &str, f: SceneFile) -> Result<Self> {
        let l = label;
        if !(1..=3).contains(&f.dim) {
            return Err(Error::range(l, "dim", f.dim, "1, 2 or 3"));
        }
        // The name becomes the directory runs/<name>: keep it a plain file name.
        let name_ok = !f.name.is_empty()
            && !f.name.starts_with('.')
            && f.name
                .chars()
                .all(|ch| ch.is_ascii_alphanumeric() || matches!(ch, '-' | '_' | '.'));
        if !name_ok {
            return Err(Error::range(
                l,
                "name",
                format!("{:?}", f.name),
                "letters, digits, '-', '_' and '.' (not first)",
            ));
        }
        let dim = f.dim as usize;
        let has_flow = f.model.equations != Equations::Prescribed;
        if !has_flow {
            let only = |key: &str| {
                Error::at(
                    l,
                    key,
                    "only with a flow: allowed with model.equations = \"frozen-flow\" or \"coupled\"",
                )
            };
            if f.model.back_coupling.is_some() {
                return Err(only("model.back_coupling"));
            }
            if f.flow.is_some() {
                return Err(only("flow"));
            }
            if f.boundary.flow.is_some() {
                return Err(only("boundary.flow"));
            }
            for (key, v) in [
                ("material.lambda0", f.material.lambda0),
                ("material.T0", f.material.t0),
                ("material.phi_rlp", f.material.phi_rlp),
            ] {
                if v.is_some() {
                    return Err(only(key));
                }
            }
        }
        // Grid.
        if f.grid.cells.len() != dim {
            return Err(Error::range(
                l,
                "grid.cells",
                format!("{:?}", f.grid.cells),
                &format!(
                    "{dim} integers, one per axis ({})",
                    axis_names(dim).join(", ")
                ),
            ));
        }
        let mut cells = Vec::with_capacity(dim);
        for (i, &n) in f.grid.cells.iter().enumerate() {
            if !(1..=MAX_AXIS_CELLS as i64).contains(&n) {
                return Err(Error::range(
                    l,
                    &format!("grid.cells[{i}]"),
                    n,
                    &format!("integer 1..={MAX_AXIS_CELLS}"),
                ));
            }
            cells.push(n as usize);
        }
        let total: usize = cells.iter().product();
        let cap = CAPACITY[dim - 1];
        if total > cap {
            return Err(Error::range(
                l,
                "grid.cells",
                format!("{:?} ({total} cells)", cells),
                &format!("at most {cap} cells in {dim}D (the compiled capacity)"),
            ));
        }
        let lower = vector(l, "grid.lower", &f.grid.lower, dim)?;
        let upper = vector(l, "grid.upper", &f.grid.upper, dim)?;
        for a in 0..dim {
            if !(upper[a] > lower[a]) {
                return Err(Error::range(
                    l,
                    &format!("grid.upper[{a}]"),
                    upper[a],
                    &format!("a number > grid.lower[{a}] = {}", lower[a]),
                ));
            }
        }
        // Numerics.
        let courant = finite(l, "numerics.courant", f.numerics.courant)?;
        if !(courant > 0.0 && courant < 1.0) {
            return Err(Error::range(
                l,
                "numerics.courant",
                courant,
                "0 < courant < 1",
            ));
        }
        // Material.
        let m = &f.material;
        let s0 = finite(l, "material.s0", m.s0)?;
        if s0 < 0.0 {
            return Err(Error::range(l, "material.s0", s0, "s0 >= 0"));
        }
        let diffusion = finite(l, "material.diffusion", m.diffusion)?;
        if diffusion < 0.0 {
            return Err(Error::range(
                l,
                "material.diffusion",
                diffusion,
                "diffusion >= 0",
            ));
        }
        let phi_rcp = finite(l, "material.phi_rcp", m.phi_rcp)?;
        if !(phi_rcp > 0.0 && phi_rcp <= 1.0) {
            return Err(Error::range(
                l,
                "material.phi_rcp",
                phi_rcp,
                "0 < phi_rcp <= 1",
            ));
        }
        // Physics.
        let gravity = vector(l, "physics.gravity", &f.physics.gravity, dim)?;
        let direction = match &f.physics.direction {
            DirectionSpec::Name(n) if n == "gravity" => Direction::Gravity,
            DirectionSpec::Name(n) if n == "flow" => Direction::Flow,
            DirectionSpec::Name(n) => {
                return Err(Error::range(
                    l,
                    "physics.direction",
                    format!("{n:?}"),
                    "\"gravity\", \"flow\" or a vector of one number per axis",
                ))
            }
            DirectionSpec::Vector(v) => {
                let v = vector(l, "physics.direction", v, dim)?;
                if v.iter().all(|&x| x == 0.0) {
                    return Err(Error::range(
                        l,
                        "physics.direction",
                        format!("{v:?}"),
                        "a non-zero vector",
                    ));
                }
                Direction::Fixed(v)
            }
        };
        if has_flow {
            if direction != Direction::Flow {
                return Err(Error::range(
                    l,
                    "physics.direction",
                    match &f.physics.direction {
                        DirectionSpec::Name(n) => format!("{n:?}"),
                        DirectionSpec::Vector(v) => format!("{v:?}"),
                    },
                    "\"flow\" with a solved flow (model.equations)",
                ));
            }
            if f.physics.temperature != TemperatureSpec::Given {
                return Err(Error::range(
                    l,
                    "physics.temperature",
                    "\"shear\"",
                    "\"given\" with a solved flow (T comes from the flow)",
                ));
            }
        }
        let temperature = match f.physics.temperature {
            TemperatureSpec::Given => Temperature::Given,
            TemperatureSpec::Shear => {
                let heating = finite(l, "material.heating", m.heating)?;
                if heating < 0.0 {
                    return Err(Error::range(l, "material.heating", heating, "heating >= 0"));
                }
                let eta0 = m.eta0.ok_or_else(|| {
                    Error::at(
                        l,
                        "material.eta0",
                        "required with physics.temperature = \"shear\"",
                    )
                })?;
                let eps0 = m.eps0.ok_or_else(|| {
                    Error::at(
                        l,
                        "material.eps0",
                        "required with physics.temperature = \"shear\"",
                    )
                })?;
                if !(eta0.is_finite() && eta0 >= 0.0) {
                    return Err(Error::range(l, "material.eta0", eta0, "eta0 >= 0 [m]"));
                }
                if !(eps0.is_finite() && eps0 > 0.0) {
                    return Err(Error::range(l, "material.eps0", eps0, "eps0 > 0 [1/m]"));
                }
                Temperature::Shear {
                    heating,
                    eta0,
                    eps0,
                }
            }
        };
        // Boundaries, in solver axis order; a side the scene does not have is an error.
        let b = &f.boundary;
        let by_name = [("x", b.x), ("y", b.y), ("z", b.z)];
        let names = axis_names(dim);
        let mut boundaries = Vec::with_capacity(dim);
        for (name, kinds) in by_name {
            if kinds.is_some() && !names.contains(&name) {
                return Err(Error::at(
                    l,
                    &format!("boundary.{name}"),
                    format!(
                        "a {dim}D scene has no axis {name}: allowed boundary keys {}",
                        names.join(", ")
                    ),
                ));
            }
        }
        for name in &names {
            let kinds = by_name
                .iter()
                .find(|(n, _)| n == name)
                .and_then(|(_, k)| *k)
                .unwrap_or([Boundary::Wall; 2]);
            if (kinds[0] == Boundary::Periodic) != (kinds[1] == Boundary::Periodic) {
                return Err(Error::range(
                    l,
                    &format!("boundary.{name}"),
                    format!("{kinds:?}").to_lowercase(),
                    "periodic on both sides or on neither",
                ));
            }
            boundaries.push(kinds);
        }
        let has_inflow = boundaries.iter().flatten().any(|&k| k == Boundary::Inflow);
        let inflow_phi = match (&b.inflow, has_inflow) {
            (Some(i), true) => Some(Expr::compile(l, "boundary.inflow.phi", &i.phi, true)?),
            (None, true) => {
                return Err(Error::at(
                    l,
                    "boundary.inflow.phi",
                    "required: a side is \"inflow\"",
                ))
            }
            (Some(_), false) => {
                return Err(Error::at(
                    l,
                    "boundary.inflow",
                    "given but no side is \"inflow\"",
                ))
            }
            (None, false) => None,
        };
        // Initial fields.
        let c = Expr::compile(l, "initial.c", &f.initial.c, false)?;
        let t = match (&f.initial.t, temperature) {
            (Some(t), _) => Some(Expr::compile(l, "initial.T", t, false)?),
            // A solved flow starts cold unless the scene says otherwise.
            (None, Temperature::Given) if has_flow => {
                Some(Expr::compile(l, "initial.T", &ExprSrc::Number(0.0), false)?)
            }
            (None, Temperature::Given) => {
                return Err(Error::at(
                    l,
                    "initial.T",
                    "required with physics.temperature = \"given\"",
                ))
            }
            (None, Temperature::Shear { .. }) => None,
        };
        let u = match &f.initial.u {
            None => vec![Expr::compile(l, "initial.u", &ExprSrc::Number(0.0), false)?; dim],
            Some(v) if v.len() != dim => {
                return Err(Error::range(
                    l,
                    "initial.u",
                    format!("{} entries", v.len()),
                    &format!("{dim} expressions, one per axis ({})", names.join(", ")),
                ))
            }
            Some(v) => v
                .iter()
                .enumerate()
                .map(|(i, e)| Expr::compile(l, &format!("initial.u[{i}]"), e, false))
                .collect::<Result<_>>()?,
        };
        let phi = Expr::compile(l, "initial.phi", &f.initial.phi, true)?;
        // Run.
        let r = &f.run;
        let t_end = finite(l, "run.t_end", r.t_end)?;
        if !(t_end > 0.0) {
            return Err(Error::range(l, "run.t_end", t_end, "t_end > 0"));
        }
        let output_interval = finite(l, "run.output_interval", r.output_interval)?;
        if !(output_interval > 0.0) {
            return Err(Error::range(
                l,
                "run.output_interval",
                output_interval,
                "output_interval > 0",
            ));
        }
        if t_end / output_interval > 100_000.0 {
            return Err(Error::range(
                l,
                "run.output_interval",
                output_interval,
                &format!("at most 100000 outputs: output_interval >= {}", t_end / 1e5),
            ));
        }
        let psi_threshold = finite(l, "run.psi_threshold", r.psi_threshold)?;
        if !(psi_threshold > 0.0 && psi_threshold < 1.0) {
            return Err(Error::range(
                l,
                "run.psi_threshold",
                psi_threshold,
                "0 < psi_threshold < 1",
            ));
        }
        let flow = if has_flow {
            Some(validate_flow(
                l,
                &f,
                dim,
                phi_rcp,
                &boundaries,
                (&lower, &upper),
            )?)
        } else {
            None
        };
        let scene = Scene {
            flow,
            label: label.to_string(),
            name: f.name,
            description: f.description,
            dim,
            precision: f.model.precision,
            cells,
            lower,
            upper,
            scheme: f.numerics.scheme,
            phase: f.numerics.phase,
            courant,
            s0,
            diffusion,
            phi_rcp,
            gravity,
            direction,
            temperature,
            boundaries,
            c,
            t,
            u,
            phi,
            inflow_phi,
            t_end,
            output_interval,
            psi_threshold,
            exact: r.exact,
        };
        if scene.exact == Some(ExactKind::ColumnA) {
            scene.check_column_a()?;
        }
        Ok(scene)
    }

    /// Total number of cells.
    pub fn len(&self) -> usize {
        self.cells.iter().product()
    }

    /// Always false: a scene has at least one cell.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Cell width per solver axis.
    pub fn spacing(&self) -> Vec<f64> {
        (0..self.dim)
            .map(|a| (self.upper[a] - self.lower[a]) / self.cells[a] as f64)
            .collect()
    }

    /// Centre of cell `i` as a physical point (x, y, z), unused axes 0.
    pub fn center(&self, i: usize) -> [f64; 3] {
        let h = self.spacing();
        let mut p = [0.0; 3];
        let mut rest = i;
        for (a, &phys) in physical_axes(self.dim).iter().enumerate() {
            let k = rest % self.cells[a];
            rest /= self.cells[a];
            // Same operation order as sieve_core::Grid::center.
            p[phys] = self.lower[a] + (k as f64 + 0.5) * h[a];
        }
        p
    }

    /// True if cell `i` lies on an inflow side.
    pub fn on_inflow_side(&self, i: usize) -> bool {
        let mut rest = i;
        for a in 0..self.dim {
            let k = rest % self.cells[a];
            rest /= self.cells[a];
            let [lo, hi] = self.boundaries[a];
            if (k == 0 && lo == Boundary::Inflow)
                || (k + 1 == self.cells[a] && hi == Boundary::Inflow)
            {
                return true;
            }
        }
        false
    }

    /// The exact column-a solution needs a 1D wall-bounded column with constant c, T and
    /// phihat, no velocity and gravity pointing down.
    fn check_column_a(&self) -> Result<()> {
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

    /// The exact column-a solution of this scene (see [`Scene::check_column_a`]).
    pub fn column_a(&self, fields: &Fields) -> Option<sieve_core::exact::ColumnA<f64>> {
        if self.exact != Some(ExactKind::ColumnA) {
            return None;
        }
        let t = fields.t[0];
        Some(sieve_core::exact::ColumnA {
            s: self.s0 * t.sqrt() * self.gravity[0].abs(),
            m: fields.phi[0] / fields.c[0],
            height: self.upper[0] - self.lower[0],
        })
    }

    /// Evaluates c, T, u, phi and the inflow phi at every cell centre and checks their ranges:
    /// `0 < c <= phi_rcp`, `T >= 0`, `0 <= phi <= c`, all finite.
    pub fn evaluate_fields(&self) -> Result<Fields> {
        let n = self.len();
        let l = &self.label;
        let mut vars = Vars::new();
        let mut f = Fields {
            c: Vec::with_capacity(n),
            t: Vec::with_capacity(n),
            u: vec![Vec::with_capacity(n); self.dim],
            phi: Vec::with_capacity(n),
            inflow: Vec::with_capacity(n),
        };
        let names = axis_names(self.dim);
        let c_flow_max = (1.0 - FLOW_MARGIN) * self.phi_rcp;
        let at = |p: [f64; 3]| {
            let coords: Vec<String> = physical_axes(self.dim)
                .iter()
                .map(|&a| format!("{} = {}", ["x", "y", "z"][a], p[a]))
                .collect();
            format!("(at {})", coords.join(", "))
        };
        for i in 0..n {
            let p = self.center(i);
            let c = self.c.eval(&mut vars, p, 0.0, l, "initial.c")?;
            if self.flow.is_some() && !(c > 0.0 && c < c_flow_max) {
                return Err(Error::range(
                    l,
                    "initial.c",
                    format!("{c} {}", at(p)),
                    &format!(
                        "0 < c < c_rcp strictly with a solved flow: c < (1 - {FLOW_MARGIN}) material.phi_rcp = {c_flow_max}"
                    ),
                ));
            }
            if !(c > 0.0 && c <= self.phi_rcp) {
                return Err(Error::range(
                    l,
                    "initial.c",
                    format!("{c} {}", at(p)),
                    &format!("0 < c <= material.phi_rcp = {}", self.phi_rcp),
                ));
            }
            let t = match &self.t {
                Some(e) if self.temperature == Temperature::Given => {
                    e.eval(&mut vars, p, c, l, "initial.T")?
                }
                _ => 0.0,
            };
            if !(t >= 0.0 && t.is_finite()) {
                return Err(Error::range(
                    l,
                    "initial.T",
                    format!("{t} {}", at(p)),
                    "a finite T >= 0",
                ));
            }
            for (a, e) in self.u.iter().enumerate() {
                let key = format!("initial.u[{a}]");
                let v = e.eval(&mut vars, p, c, l, &key)?;
                if !v.is_finite() {
                    return Err(Error::range(
                        l,
                        &key,
                        format!("{v} {}", at(p)),
                        &format!("a finite velocity along {}", names[a]),
                    ));
                }
                f.u[a].push(v);
            }
            let phi = self.phi.eval(&mut vars, p, c, l, "initial.phi")?;
            if !(phi >= 0.0 && phi <= c) {
                return Err(Error::range(
                    l,
                    "initial.phi",
                    format!("{phi} {}", at(p)),
                    &format!("0 <= phi <= c = {c}"),
                ));
            }
            let inflow = match &self.inflow_phi {
                Some(e) if self.on_inflow_side(i) => {
                    let v = e.eval(&mut vars, p, c, l, "boundary.inflow.phi")?;
                    if !(v >= 0.0 && v <= c) {
                        return Err(Error::range(
                            l,
                            "boundary.inflow.phi",
                            format!("{v} {}", at(p)),
                            &format!("0 <= phi <= c = {c}"),
                        ));
                    }
                    v
                }
                _ => 0.0,
            };
            f.c.push(c);
            f.t.push(t);
            f.phi.push(phi);
            f.inflow.push(inflow);
        }
        if self.exact == Some(ExactKind::ColumnA) {
            let m0 = f.phi[0] / f.c[0];
            if f.phi.iter().zip(&f.c).any(|(p, c)| p / c != m0) {
                return Err(Error::at(
                    l,
                    "run.exact",
                    "\"column-a\" needs a constant phihat = initial.phi / initial.c",
                ));
            }
        }
        Ok(f)
    }
}

fn positive(l: &str, key: &str, v: Option<f64>, unit: &str) -> Result<f64> {
    let v = v.ok_or_else(|| {
        Error::at(
            l,
            key,
            "required with a solved flow (model.equations = \"frozen-flow\" or \"coupled\")",
        )
    })?;
    if !(v.is_finite() && v > 0.0) {
        return Err(Error::range(
            l,
            key,
            v,
            &format!("a finite number > 0 {unit}"),
        ));
    }
    Ok(v)
}

fn wall_side(
    l: &str,
    key: &str,
    spec: Option<&FlowWallSpec>,
    kind: sieve_core::Boundary,
    axis: usize,
    dim: usize,
    (box_lower, box_upper): (&[f64], &[f64]),
) -> Result<WallSide> {
    let mut side = WallSide {
        slip: WallSlip::NoSlip,
        velocity: vec![0.0; dim],
        outlet: None,
    };
    let Some(spec) = spec else {
        return Ok(side);
    };
    if kind != sieve_core::Boundary::Wall {
        return Err(Error::at(
            l,
            key,
            format!(
                "given but this side is {:?}: allowed only on \"wall\" sides",
                format!("{kind:?}").to_lowercase()
            ),
        ));
    }
    let wall = spec.wall.unwrap_or(if spec.friction_angle.is_some() {
        WallKind::Friction
    } else {
        WallKind::NoSlip
    });
    side.slip = match (wall, spec.friction_angle) {
        (WallKind::NoSlip, None) => WallSlip::NoSlip,
        (WallKind::Slip, None) => WallSlip::Slip,
        (WallKind::Friction, Some(deg)) => {
            if !(deg.is_finite() && (0.0..=90.0).contains(&deg)) {
                return Err(Error::range(
                    l,
                    &format!("{key}.friction_angle"),
                    deg,
                    "0 <= friction_angle <= 90 [deg] (0 = slip, 90 = no-slip)",
                ));
            }
            if deg == 90.0 {
                WallSlip::NoSlip
            } else {
                WallSlip::Friction {
                    tan: libm::tan(deg.to_radians()),
                    degrees: deg,
                }
            }
        }
        (WallKind::Friction, None) => {
            return Err(Error::at(
                l,
                &format!("{key}.friction_angle"),
                "required with wall = \"friction\": allowed 0..=90 [deg]",
            ))
        }
        (_, Some(_)) => {
            return Err(Error::at(
                l,
                &format!("{key}.friction_angle"),
                "only with wall = \"friction\" (then 0 <= friction_angle <= 90 [deg])",
            ))
        }
    };
    if let Some(v) = &spec.velocity {
        let v = vector(l, &format!("{key}.velocity"), v, dim)?;
        if v[axis] != 0.0 {
            return Err(Error::range(
                l,
                &format!("{key}.velocity[{axis}]"),
                v[axis],
                "0: walls move tangentially only",
            ));
        }
        side.velocity = v;
    }
    if let Some(o) = &spec.outlet {
        side.outlet = Some(super::outlet::validate(
            l, key, o, axis, dim, box_lower, box_upper,
        )?);
    }
    Ok(side)
}

fn validate_flow(
    l: &str,
    f: &SceneFile,
    dim: usize,
    phi_rcp: f64,
    boundaries: &[[sieve_core::Boundary; 2]],
    extent: (&[f64], &[f64]),
) -> Result<FlowModel> {
    let m = &f.material;
    let eta0 = positive(l, "material.eta0", m.eta0, "[m]")?;
    let lambda0 = positive(l, "material.lambda0", m.lambda0, "[m]")?;
    let eps0 = positive(l, "material.eps0", m.eps0, "[1/m]")?;
    let heating = positive(l, "material.heating", Some(m.heating), "")?;
    let t0 = m.t0.ok_or_else(|| {
        Error::at(
            l,
            "material.T0",
            "required with a solved flow (model.equations = \"frozen-flow\" or \"coupled\")",
        )
    })?;
    if !(t0.is_finite() && t0 >= 0.0) {
        return Err(Error::range(l, "material.T0", t0, "T0 >= 0 [m^2/s^2]"));
    }
    if !(phi_rcp < 1.0) {
        return Err(Error::range(
            l,
            "material.phi_rcp",
            phi_rcp,
            "0 < phi_rcp < 1 with a solved flow",
        ));
    }
    let phi_rlp = positive(l, "material.phi_rlp", m.phi_rlp, "")?;
    if !(phi_rlp < phi_rcp) {
        return Err(Error::range(
            l,
            "material.phi_rlp",
            phi_rlp,
            &format!("0 < phi_rlp < material.phi_rcp = {phi_rcp}"),
        ));
    }
    if boundaries
        .iter()
        .flatten()
        .any(|&k| k == sieve_core::Boundary::Inflow)
    {
        return Err(Error::at(
            l,
            "boundary",
            "\"inflow\" sides are not supported with a solved flow yet: allowed wall, outflow, periodic",
        ));
    }
    let names = axis_names(dim);
    let fb = f.boundary.flow.clone().unwrap_or_default();
    let by_name = [
        ("x", &fb.x_low, &fb.x_high),
        ("y", &fb.y_low, &fb.y_high),
        ("z", &fb.z_low, &fb.z_high),
    ];
    let mut walls = Vec::with_capacity(dim);
    for (name, lo, hi) in by_name {
        match names.iter().position(|n| *n == name) {
            Some(a) => walls.push([
                wall_side(
                    l,
                    &format!("boundary.flow.{name}_low"),
                    lo.as_ref(),
                    boundaries[a][0],
                    a,
                    dim,
                    extent,
                )?,
                wall_side(
                    l,
                    &format!("boundary.flow.{name}_high"),
                    hi.as_ref(),
                    boundaries[a][1],
                    a,
                    dim,
                    extent,
                )?,
            ]),
            None if lo.is_some() || hi.is_some() => {
                return Err(Error::at(
                    l,
                    &format!("boundary.flow.{name}_low"),
                    format!(
                        "a {dim}D scene has no axis {name}: allowed sides of {}",
                        names.join(", ")
                    ),
                ))
            }
            None => {}
        }
    }
    // `walls` was filled in x, y, z order, which is the solver axis order of every dimension.
    let fs = f.flow.clone().unwrap_or_default();
    let steady_tolerance = positive(
        l,
        "flow.steady_tolerance",
        Some(fs.steady_tolerance.unwrap_or(1e-3)),
        "[1/s]",
    )?;
    let t_min = positive(
        l,
        "flow.t_min",
        Some(fs.t_min.unwrap_or(1e-14)),
        "[m^2/s^2]",
    )?;
    let courant = fs.courant.unwrap_or(0.4);
    if !(courant.is_finite() && courant > 0.0 && courant <= 0.5) {
        return Err(Error::range(
            l,
            "flow.courant",
            courant,
            "0 < courant <= 0.5",
        ));
    }
    let min_steps = fs.min_steps.unwrap_or(50);
    if !(0..=100_000_000).contains(&min_steps) {
        return Err(Error::range(
            l,
            "flow.min_steps",
            min_steps,
            "0..=100000000",
        ));
    }
    let max_steps = fs.max_steps.unwrap_or(200_000);
    if !(1..=100_000_000).contains(&max_steps) || max_steps < min_steps {
        return Err(Error::range(
            l,
            "flow.max_steps",
            max_steps,
            &format!("flow.min_steps = {min_steps} <= max_steps <= 100000000"),
        ));
    }
    Ok(FlowModel {
        equations: f.model.equations,
        back_coupling: f.model.back_coupling.unwrap_or_default(),
        eta0,
        lambda0,
        eps0,
        t0,
        phi_rlp,
        heating,
        walls,
        steady_tolerance,
        min_steps: min_steps as u64,
        max_steps: max_steps as u64,
        t_min,
        courant,
        spin_up: fs.spin_up.unwrap_or_default(),
    })
}
