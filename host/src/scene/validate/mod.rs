//! Validation of a deserialised scene file into a [`Scene`] the solver can run, and the
//! evaluation of its analytic fields on the grid ([`Fields`]). Every failure is an input error
//! naming the file, the key and the allowed range, and validation reports **every** problem of
//! a file in one go, one line each ([`Problems`]), not only the first.
//!
//! One file per section of the scene file: `grid` (`[grid]`), `material` (`[numerics]`,
//! `[material]`), `physics` (`[physics]`), `boundary` (`[boundary]`), `initial`
//! (`[initial]` and the evaluated fields), `run` (`[run]`, `exact`), `flow` (the solved
//! flow: its material, `[boundary.flow]`, `[flow]`). This file holds the validated types and
//! puts the sections together.

mod boundary;
mod fill;
mod flow;
pub mod frame;
pub mod geometry;
mod grid;
mod initial;
pub mod limits;
mod material;
pub mod output;
mod physics;
mod problems;
mod run;

pub use problems::Problems;
pub use run::fines_band_ok;

use super::expr::Expr;
use super::{
    BackCoupling, Equations, ExactKind, Fill, MergedWallsKind, Precision, PressureKind, SceneFile,
    SpinUp, StressKind,
};
use crate::error::{Error, Result};
use sieve_core::closure::Material;
use sieve_core::real::Real;
use sieve_core::{Boundary, Phase, Scheme, Transport};

/// Compiled cell capacity for each dimension (index `dim - 1`): 65536 cells in 1D, 512 x 512
/// in 2D, 64^3 in 3D.
pub const CAPACITY: [usize; 3] = [65536, 262_144, 262_144];
/// Largest number of cells along one axis.
pub const MAX_AXIS_CELLS: usize = 65536;
/// Largest magnitude of a box corner (`grid.lower`, `grid.upper`) in m: the plots drawn at
/// the end of a run cannot draw an axis past it (`output::plot::MAX_PLOTTABLE`), so a box
/// beyond it is refused before the run instead of after.
pub const MAX_COORDINATE: f64 = 1e150;

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
        /// eta0 \[m\]
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
        /// phi_w \[deg\]
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
    /// eta0 \[m\].
    pub eta0: f64,
    /// lambda0 \[m\].
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
    /// Relative tolerance of the flow's CG solves (`None`: the core's default, 1e-10 in f64).
    pub cg_tolerance: Option<f64>,
    /// Relative tolerance of the implicit pressure solve (`None`: `cg_tolerance`, else the
    /// core's default).
    pub cg_tolerance_pressure: Option<f64>,
    /// Flow Courant number.
    pub courant: f64,
    /// Spin-up policy.
    pub spin_up: SpinUp,
    /// Pressure mode of the flow step.
    pub pressure: PressureKind,
    /// Viscous stress of the flow step.
    pub stress: StressKind,
    /// Which cell of a merge group takes a merged cut cell's wall term.
    pub merged_walls: MergedWallsKind,
    /// Whether the scene file (or `--set`) named `flow.merged_walls`: only a rule asked for
    /// is worth a warning where it has no effect.
    pub merged_walls_given: bool,
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
    /// Face value of the carried transport (coupled runs).
    pub transport: Transport,
    /// S0.
    pub s0: f64,
    /// Remixing diffusivity.
    pub diffusion: f64,
    /// Upper bound of c.
    pub phi_rcp: f64,
    /// Grain diameter \[m\] (`material.grain_diameter`; only for the narrow-orifice warning).
    pub grain_diameter: Option<f64>,
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
    /// How the bed's packing is set (`initial.fill`).
    pub fill: Fill,
    /// Inflow phi(x, c), if a side is inflow.
    pub inflow_phi: Option<Expr>,
    /// End time.
    pub t_end: f64,
    /// Output interval.
    pub output_interval: f64,
    /// Psi threshold of the segregation time.
    pub psi_threshold: f64,
    /// Wall-clock seconds between checkpoints (`run.checkpoint_interval`; none: no
    /// checkpoints; docs/resume.md).
    pub checkpoint_interval: Option<f64>,
    /// The on-spec band of the discharge's fines fraction (`run.fines_band`; scenes with an
    /// outlet; none: the bed's initial fraction +- 0.1, docs/silo.md "On-spec discharge").
    pub fines_band: Option<[f64; 2]>,
    /// Closed-form solution, if any.
    pub exact: Option<ExactKind>,
    /// The flow model, if the scene solves one.
    pub flow: Option<FlowModel>,
    /// The container's walls on cut cells, if any.
    pub geometry: Option<geometry::Geometry>,
    /// The frame of reference, if `[frame]` is given.
    pub frame: Option<frame::FrameModel>,
    /// Run guards (not scene keys: `--max-steps`, `--max-cell-steps`, `--max-output`).
    pub limits: limits::Limits,
    /// `[output]`: which VTK arrays, how often, compressed or not.
    pub output: output::OutputModel,
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
    /// Validates a scene file read from `label`, reporting every problem (one line each, in
    /// the order of the file's sections). A section that depends on an invalid one (e.g. the
    /// per-axis keys on an invalid `dim`) is skipped rather than reported twice.
    pub fn validate(label: &str, f: SceneFile) -> Result<Self> {
        let l = label;
        let mut p = Problems::default();
        let dim = if (1..=3).contains(&f.dim) {
            Some(f.dim as usize)
        } else {
            p.push(Error::range(l, "dim", f.dim, "1, 2 or 3"));
            None
        };
        // The name becomes the directory runs/<name>: keep it a plain file name.
        let name_ok = !f.name.is_empty()
            && !f.name.starts_with('.')
            && f.name
                .chars()
                .all(|ch| ch.is_ascii_alphanumeric() || matches!(ch, '-' | '_' | '.'));
        if !name_ok {
            p.push(Error::range(
                l,
                "name",
                format!("{:?}", f.name),
                "letters, digits, '-', '_' and '.' (not first)",
            ));
        }
        let has_flow = f.model.equations != Equations::Prescribed;
        if !has_flow {
            flow::only_with_flow(&mut p, l, &f);
        }
        if f.numerics.transport != Transport::Donor && f.model.equations != Equations::Coupled {
            // Only a coupled run carries phi on the flow's face mass fluxes.
            p.push(Error::range(
                l,
                "numerics.transport",
                format!("{:?}", f.numerics.transport.name()),
                "\"donor\" unless model.equations = \"coupled\" (\"limited\" acts on the carried transport of coupled runs)",
            ));
        }
        let grid = dim.and_then(|d| grid::check(&mut p, l, &f.grid, d));
        let courant = material::courant(&mut p, l, &f.numerics);
        let mat = material::check(&mut p, l, &f.material);
        let grain_diameter = material::grain_diameter(&mut p, l, &f.material);
        let physics = dim.and_then(|d| physics::check(&mut p, l, &f, d, has_flow));
        let bounds = dim.and_then(|d| boundary::check(&mut p, l, &f.boundary, d));
        let temperature = physics.as_ref().map(|ph| ph.temperature);
        let initial =
            dim.and_then(|d| initial::compile(&mut p, l, &f.initial, d, temperature, has_flow));
        let run = run::check(&mut p, l, &f.run);
        let flow = if has_flow {
            let bc = bounds.as_ref().map(|(b, _)| b.as_slice());
            let extent = grid
                .as_ref()
                .map(|g| (g.lower.as_slice(), g.upper.as_slice()));
            flow::check(&mut p, l, &f, dim, mat.map(|m| m.2), bc, extent)
        } else {
            None
        };
        let grid_box = grid
            .as_ref()
            .map(|g| (g.cells.as_slice(), g.lower.as_slice(), g.upper.as_slice()));
        let geo = dim.and_then(|d| geometry::check(&mut p, l, &f, d, grid_box));
        let frame = dim.and_then(|d| {
            frame::check(
                &mut p,
                l,
                &f,
                d,
                geo.as_ref().map(|g| g.center.as_slice()),
                grid_box.map(|(_, lo, up)| (lo, up)),
                bounds.as_ref().map(|(b, _)| b.as_slice()),
            )
        });
        let fill = fill::check(
            &mut p,
            l,
            &f,
            has_flow,
            physics.as_ref().map(|ph| ph.gravity.as_slice()),
            bounds.as_ref().map(|(b, _)| b.as_slice()),
        );
        let output = output::check(&mut p, l, f.output.as_ref());
        let checkpoint_interval = run::check_checkpoint(&mut p, l, &f.run);
        let fines_band = run::check_fines_band(&mut p, l, &f.run);
        p.finish()?;
        // Every section that gave None recorded a problem, so all are Some here.
        let (
            Some(dim),
            Some(grid),
            Some(courant),
            Some((s0, diffusion, phi_rcp)),
            Some(physics),
            Some((boundaries, inflow_phi)),
            Some(initial),
            Some((t_end, output_interval, psi_threshold)),
        ) = (dim, grid, courant, mat, physics, bounds, initial, run)
        else {
            return Err(Error::failure(format!(
                "{l}: scene validation lost a section without naming the problem"
            )));
        };
        if has_flow && flow.is_none() {
            return Err(Error::failure(format!(
                "{l}: flow validation lost a section without naming the problem"
            )));
        }
        let scene = Scene {
            flow,
            geometry: geo,
            frame,
            label: label.to_string(),
            name: f.name,
            description: f.description,
            dim,
            precision: f.model.precision,
            cells: grid.cells,
            lower: grid.lower,
            upper: grid.upper,
            scheme: f.numerics.scheme,
            phase: f.numerics.phase,
            courant,
            transport: f.numerics.transport,
            s0,
            diffusion,
            phi_rcp,
            grain_diameter,
            gravity: physics.gravity,
            direction: physics.direction,
            temperature: physics.temperature,
            boundaries,
            c: initial.c,
            t: initial.t,
            u: initial.u,
            phi: initial.phi,
            fill,
            inflow_phi,
            t_end,
            output_interval,
            psi_threshold,
            checkpoint_interval,
            fines_band,
            exact: f.run.exact,
            limits: limits::Limits::default(),
            output: output.unwrap_or_default(),
        };
        if scene.exact == Some(ExactKind::ColumnA) {
            scene.check_column_a()?;
        }
        if scene.fines_band.is_some() && !scene.has_outlets() {
            return Err(Error::at(
                l,
                "run.fines_band",
                "the on-spec band of the discharge's fines fraction needs an outlet \
                 (`outlet = { center, width }` on a side of `[boundary.flow]`): remove it",
            ));
        }
        Ok(scene)
    }

    /// True if a wall of the scene's flow has an outlet.
    pub fn has_outlets(&self) -> bool {
        self.flow
            .as_ref()
            .is_some_and(|f| f.walls.iter().flatten().any(|w| w.outlet.is_some()))
    }

    /// The flow's material in the core's form (`fm`: this scene's flow model).
    pub fn flow_material<R: Real>(&self, fm: &FlowModel) -> Material<R> {
        Material {
            eta0: R::from_f64(fm.eta0),
            lambda0: R::from_f64(fm.lambda0),
            eps0: R::from_f64(fm.eps0),
            t0: R::from_f64(fm.t0),
            phi_rcp: R::from_f64(self.phi_rcp),
            phi_rlp: R::from_f64(fm.phi_rlp),
            heating: R::from_f64(fm.heating),
            s0: R::from_f64(self.s0),
        }
    }

    /// "(at x = .., z = ..)": where cell `i` is, for messages.
    pub(super) fn at(&self, i: usize) -> String {
        let pt = self.center(i);
        let coords: Vec<String> = physical_axes(self.dim)
            .iter()
            .map(|&a| format!("{} = {}", ["x", "y", "z"][a], pt[a]))
            .collect();
        format!("(at {})", coords.join(", "))
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
}
