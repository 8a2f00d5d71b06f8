//! Embedded (cut-cell) walls of the flow: what the step needs of a [`CutCells`] geometry,
//! copied once at set-up, and the wall law on the cut wall fragment (model.md 2).
//!
//! # Why a copy, not a reference
//! [`Flow::step`] keeps its signature and box scenes keep their bits and their speed: with no
//! geometry loaded every stage runs its box code path (the embedded branches are taken once per
//! stage, not per face). The copy costs `3 + 3 D` arrays of `N` on the host; the firmware does
//! not use [`Flow`].
//!
//! # The discretisation (content units)
//! A cell of open volume fraction `V` (0 = solid, 1 = full) holds the content `V c` (and
//! `V c u`, `V c T`) per full-cell volume. Every face term of the box scheme is multiplied by
//! the face's open aperture `alpha`, every cell term (mass, dissipation) by `V`:
//! - transport: face fluxes `alpha F`; the limiters compare a cell's in- and outflow with its
//!   room `V (c_max - c)` and content `V c`; the update goes through the merge groups;
//! - pressure and gravity: each face's compact force `alpha F_f / 2` per side, the cell force per
//!   volume is the group's sum over its group volume; the cut wall fragment is a hydrostatic
//!   ghost like the box wall (zero face force), so the compact lithostatic balance of a resting
//!   bed holds face by face next to a curved wall too;
//! - viscosity: `kf = alpha eta_f / h^2`, mass term `V c / dt`, and the wall fragment adds the
//!   Dirichlet term `eta A / (d |C|)` (area `A`, distance `d` from the cell centre to the
//!   fragment's plane; the box wall term `2 eta / h^2` is the case `A = h^(D-1)`, `d = h/2`)
//!   towards the boundary velocity `u_B` of [`Flow::wall_law`] (whose friction branch also
//!   lowers `eta` to the drag that gives `p tan(phi_w)`), computed from the
//!   lagged velocity, so each velocity component is still one SPD system while the wall's own
//!   normal acts. By the divergence identity `A n = sum_a (alpha_low - alpha_high) h^(D-1) e_a`
//!   the discrete operator is exact on linear fields: a rigid rotation with `u_B` the rigid
//!   velocity at the Dirichlet point `x_c + d n` is reproduced without error by the viscous
//!   stage (for uniform `eta`);
//! - temperature: `kf = a alpha lambda_f / h^2`, `V` in the mass and dissipation terms, no flux
//!   through the cut wall (`d_n T = 0`); the heating includes the dissipation `eta A / (d |C|)
//!   |u_B - u|^2` of the wall term.
//!
//! # Small cells: merging
//! A cut cell with `V < small` is merged into a master (its [`CutCells::master`]); the group
//! (volume `>= small`, 1/2 by default) is one cell for the explicit stages: face fluxes and
//! forces are summed over the group and divided by the group volume, and the members copy the
//! master's state. Faces inside a group carry no mass. The implicit stages (no stability
//! limit) solve on the cells, and a member keeps its own solution for the rest of the step
//! (its wall flux and heating); the next transport update takes the group's state from the
//! master again; which row takes a member's wall term there is [`MergedWalls`]' choice.
//! Averaging the group after each implicit solve (content-conservative) was tried and
//! dropped: the mean of a linear field over a group is not its value at the master's centre,
//! which breaks the exactness above and tripled the rigid-rotation error of the drum (1.3e-2 against 4.4e-3 on 32 x 32, tests/tests/flow_drum.rs). With a moving wall
//! (lab frame) the master's momentum is handed to a member with the wall's rigid motion
//! between their centres added ([`Flow::carry_rigid_offsets`]), so a rigid rotation passes
//! the group update unchanged (a plain copy put every member `omega h` off it each step, and
//! the implicit solve's correction heated the wall ring). Mass is conserved to
//! round-off either way (c never leaves the group rule); momentum and `c T` are not conserved
//! quantities next to a wall anyway. The time step is the box rule over the open cells
//! ([`Flow::stable_dt`]): no tiny cell enters it, and the limiters keep `0 <= c <= c_max` of
//! every group whatever its volume.

use super::{Flow, Slip};
use crate::geometry::CutCells;
use crate::grid::Grid;
use crate::real::Real;
use core::ops::Range;

/// Which cell of a merge group takes the wall term of a merged cut cell (model.md 5.4, "The
/// wall term of a merged cell"). Why a choice: a member a sliver of a cell thick, pinned to
/// the wall by its own term, holds its master back through their shared face as a wall a
/// whole cell away would; with the wall exactly on the grid line the sliver is solid and the
/// master's own face is the wall, half a cell away. On the hopper the member rule's rate steps
/// by 3 % between the two and lies 10 % above the converged rate on 10 mm cells; the master
/// rule has no step and is within 2.3 % of it from 5 mm cells on (docs/silo.md section 7), so
/// it is the default.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum MergedWalls {
    /// Each cell takes its own fragment's term (the default until 2026-12-05).
    Member,
    /// A member's fragment acts on its master, at the master's distance to the fragment's
    /// plane, for resting walls under the model's stress; a moving wall and the objective
    /// stress keep [`Self::Member`] (their per-cell terms are exact on the rigid rotation).
    #[default]
    Master,
}

/// Why a member keeps its own wall term although [`MergedWalls::Master`] was asked for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MemberKept {
    /// The cut wall moves (a drum turning in the lab frame).
    MovingWall,
    /// The objective stress (model.md 2.6).
    ObjectiveStress,
}

impl MergedWalls {
    /// Whether a member's fragment acts on its master under this rule, for a wall that moves
    /// or not and the given stress: `Ok(true)` for the master rule where it applies,
    /// `Ok(false)` for the member rule, `Err` with the reason where the master rule was asked
    /// for but the member keeps its term. The step and the host's pre-run warning both ask
    /// this one question.
    pub fn on_master(self, stress: super::Stress, wall_moves: bool) -> Result<bool, MemberKept> {
        match self {
            MergedWalls::Member => Ok(false),
            MergedWalls::Master if wall_moves => Err(MemberKept::MovingWall),
            MergedWalls::Master if stress == super::Stress::Objective => {
                Err(MemberKept::ObjectiveStress)
            }
            MergedWalls::Master => Ok(true),
        }
    }
}

/// What the cut wall does: its tangential law and its (rigid) motion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CutWall<R, const D: usize> {
    /// Tangential condition (model.md 2): no-slip, slip, or friction `tan(phi_w)`.
    pub slip: Slip<R>,
    /// Angular velocity (rad/s) of a rigid rotation of the wall in the plane of the axes
    /// `plane[0] -> plane[1]` (counter-clockwise positive): `u_W = omega x (x - center)`.
    /// 0 for a resting wall.
    pub omega: R,
    /// Centre of the rotation.
    pub center: [R; D],
    /// The rotation plane (two different axes; ignored if `omega == 0`).
    pub plane: [usize; 2],
}

impl<R: Real, const D: usize> CutWall<R, D> {
    /// A resting wall with the given tangential condition.
    pub fn resting(slip: Slip<R>) -> Self {
        Self {
            slip,
            omega: R::ZERO,
            center: [R::ZERO; D],
            plane: [0, 1 % D.max(1)],
        }
    }
    /// A wall rotating rigidly with `omega` (rad/s) about `center` in the plane of the first
    /// two axes (the drum of model.md 7.5 in the lab frame).
    pub fn rotating(slip: Slip<R>, omega: R, center: [R; D]) -> Self {
        Self {
            slip,
            omega,
            center,
            plane: [0, 1 % D.max(1)],
        }
    }
}

/// The geometry the flow step needs, copied from [`CutCells`] (module docs).
#[derive(Clone, Debug)]
pub(super) struct Walls<R: Real, const D: usize, const N: usize> {
    /// Geometry loaded: the embedded code paths run.
    pub on: bool,
    /// Any merged cell (else the group passes are skipped).
    pub merged: bool,
    pub wall: CutWall<R, D>,
    /// Open volume fraction `V`.
    pub vol: [R; N],
    /// Group volume at a master (the cell's own volume if unmerged), 0 at solid cells.
    pub gvol: [R; N],
    /// Master of each cell (itself unless merged).
    pub master: [u32; N],
    /// Aperture of the high / low face along each axis (box faces included).
    pub ap_hi: [[R; N]; D],
    pub ap_lo: [[R; N]; D],
    /// Wall coefficient `A / (d |C|)` (1/m^2), 0 where the cell has no wall fragment.
    pub wall_k: [R; N],
    /// Distance `d` of the Dirichlet point `x_c + d n` from the cell centre.
    pub wall_d: [R; N],
    /// Unit wall normal (open -> solid).
    pub normal: [[R; N]; D],
    /// A merged cell's master's distance `d_M` to the cell's wall fragment's plane, for
    /// [`MergedWalls::Master`]; 0 where the cell is no member with a fragment, or its master
    /// lies no farther from the plane than the member's `d` (then the member keeps its term).
    pub master_d: [R; N],
    /// Rows a merge group spans along the last axis beyond its first (0, 1 or 2: a master
    /// with members below and above), of the whole grid: what deepens a slab's halo
    /// ([`super::slab::halo_rows`]).
    pub rows_spanned: usize,
}

impl<R: Real, const D: usize, const N: usize> Walls<R, D, N> {
    pub const fn zeroed() -> Self {
        let z = [R::ZERO; N];
        Self {
            on: false,
            merged: false,
            wall: CutWall {
                slip: Slip::NoSlip,
                omega: R::ZERO,
                center: [R::ZERO; D],
                plane: [0, 0],
            },
            vol: z,
            gvol: z,
            master: [0; N],
            ap_hi: [z; D],
            ap_lo: [z; D],
            wall_k: z,
            wall_d: z,
            master_d: z,
            normal: [z; D],
            rows_spanned: 0,
        }
    }

    /// Adds the group sums of the per-cell content increments `dq` (per full-cell volume,
    /// members gathered into their master in cell order) divided by the group volume to the
    /// masters' `q`; members then copy their master. `dq` is overwritten; solid cells keep `q`.
    pub fn apply_increment(&self, n: usize, q: &mut [R], dq: &mut [R]) {
        if self.merged {
            for i in 0..n {
                let m = self.master[i] as usize;
                if m != i {
                    dq[m] += dq[i];
                }
            }
        }
        for i in 0..n {
            let gv = self.gvol[i];
            if self.master[i] as usize == i && gv > R::ZERO {
                q[i] += dq[i] / gv;
            }
        }
        self.copy_to_members(n, q);
    }

    /// Replaces the values of every merge group by their open-volume-weighted mean
    /// (`acc` is scratch): the group's content `sum V q` is kept. Used on the initial state.
    pub fn group_mean(&self, n: usize, q: &mut [R], acc: &mut [R]) {
        if !self.merged {
            return;
        }
        for i in 0..n {
            acc[i] = self.vol[i] * q[i];
        }
        for i in 0..n {
            let m = self.master[i] as usize;
            if m != i {
                acc[m] += acc[i];
            }
        }
        for i in 0..n {
            let m = self.master[i] as usize;
            if m == i && self.gvol[i] > self.vol[i] {
                q[i] = acc[i] / self.gvol[i];
            }
        }
        self.copy_to_members(n, q);
    }

    /// Members take their master's value.
    pub fn copy_to_members(&self, n: usize, q: &mut [R]) {
        if !self.merged {
            return;
        }
        for i in 0..n {
            let m = self.master[i] as usize;
            if m != i {
                q[i] = q[m];
            }
        }
    }

    /// Members' values added to their master's (in cell order) and zeroed: a source booked per
    /// cell becomes the group's.
    pub fn gather_to_masters(&self, n: usize, q: &mut [R]) {
        if self.add_members_to_masters(n, q) {
            for i in 0..n {
                if self.master[i] as usize != i {
                    q[i] = R::ZERO;
                }
            }
        }
    }

    /// Members' values summed into their master (in cell order), then copied back.
    pub fn group_sum(&self, n: usize, q: &mut [R]) {
        if self.add_members_to_masters(n, q) {
            self.copy_to_members(n, q);
        }
    }

    /// Adds each member's value to its master's, in cell order; false without merging.
    fn add_members_to_masters(&self, n: usize, q: &mut [R]) -> bool {
        if !self.merged {
            return false;
        }
        for i in 0..n {
            let m = self.master[i] as usize;
            if m != i {
                q[m] += q[i];
            }
        }
        true
    }

    /// The rows of `global`'s walls whose cells are `span` (a slab and its halo rows,
    /// [`super::slab::load_slab`]): every value the global one, so the owned cells step with
    /// the serial bits. A member whose master lies outside `span` becomes a cell of its own,
    /// and a master keeps its global group volume with members outside: both only in the
    /// outermost halo row and its group, whose values a slab's step gets wrong anyway
    /// ([`super::slab::halo_rows`]).
    pub fn load_rows<const M: usize>(&mut self, global: &Walls<R, D, M>, span: Range<usize>) {
        self.on = global.on;
        self.merged = global.merged;
        self.wall = global.wall;
        self.rows_spanned = global.rows_spanned;
        let off = span.start;
        for (i, g) in span.clone().enumerate() {
            self.vol[i] = global.vol[g];
            self.wall_k[i] = global.wall_k[g];
            self.wall_d[i] = global.wall_d[g];
            for a in 0..D {
                self.ap_hi[a][i] = global.ap_hi[a][g];
                self.ap_lo[a][i] = global.ap_lo[a][g];
                self.normal[a][i] = global.normal[a][g];
            }
            let m = global.master[g] as usize;
            if span.contains(&m) {
                self.master[i] = (m - off) as u32;
                self.gvol[i] = global.gvol[g];
                self.master_d[i] = global.master_d[g];
            } else {
                self.master[i] = i as u32;
                self.gvol[i] = global.vol[g];
                self.master_d[i] = R::ZERO;
            }
        }
    }

    /// `V` for the mass terms of the implicit systems: a solid cell counts as a full empty
    /// cell (a decoupled row with zero right-hand side), so the operator stays definite.
    #[inline(always)]
    pub fn mass_volume(&self, i: usize) -> R {
        let v = self.vol[i];
        if v > R::ZERO {
            v
        } else {
            R::ONE
        }
    }

    /// Rows spanned by the largest merge group along the last axis of `grid` beyond its
    /// first: a member is a face neighbour of its master, so a group reaches one row below
    /// its master, one above, or both.
    fn spanned_rows(&self, grid: &Grid<R, D>) -> usize {
        let (n, s) = (grid.len(), grid.stride(D - 1));
        let mut most = 0;
        for m in 0..n {
            if self.master[m] as usize == m {
                let below = m >= s && self.master[m - s] as usize == m;
                let above = m + s < n && self.master[m + s] as usize == m;
                most = most.max(usize::from(below) + usize::from(above));
            }
        }
        most
    }

    /// Wall velocity at the Dirichlet point `x_c + d n` of cell `i`, whose centre is `x`
    /// (as the whole grid places it: [`Flow::home_center`], so that a slab's are the whole
    /// grid's to the bit). The caller checks [`Self::turns`] first (`Flow::wall_velocity`
    /// does): a wall at rest moves at `[0; D]` exactly, not at the signed zeros that
    /// `omega = 0` gives here.
    fn wall_velocity(&self, x: [R; D], i: usize) -> [R; D] {
        let mut x = x;
        let d = self.wall_d[i];
        for (a, xa) in x.iter_mut().enumerate() {
            *xa += d * self.normal[a][i];
        }
        self.turn(core::array::from_fn(|k| x[k] - self.wall.center[k]))
    }

    /// Whether the wall moves: a rotation in a plane (`omega != 0`, two axes or more).
    #[inline(always)]
    pub fn turns(&self) -> bool {
        self.wall.omega != R::ZERO && D >= 2
    }

    /// `omega x v` for a vector `v` in the rotation plane (0 off it): the rigid motion's
    /// velocity of a point `v` from the centre, or the difference between two points'.
    #[inline(always)]
    fn turn(&self, v: [R; D]) -> [R; D] {
        let mut u = [R::ZERO; D];
        let w = &self.wall;
        let [a, b] = w.plane;
        u[a] = -(w.omega * v[b]);
        u[b] = w.omega * v[a];
        u
    }

    /// Whether the cut wall moves and cells are merged: then a merge group carries the wall's
    /// rigid motion across its members ([`Flow::carry_rigid_offsets`]).
    #[inline(always)]
    pub fn rigid_groups(&self) -> bool {
        self.merged && self.turns()
    }

    /// The wall's rigid motion `u_R = omega x (x - center)` at a cell centre `x` (0 for a
    /// resting wall).
    pub fn rigid_velocity(&self, x: [R; D]) -> [R; D] {
        if !self.turns() {
            return [R::ZERO; D];
        }
        self.turn(core::array::from_fn(|k| x[k] - self.wall.center[k]))
    }

    /// `u_R(x_j) - u_R(x_i)` of the wall's rigid motion `u_R = omega x (x - center)` between
    /// two cell centres (0 off the rotation plane).
    pub fn rigid_offset(&self, xj: [R; D], xi: [R; D]) -> [R; D] {
        self.turn(core::array::from_fn(|k| xj[k] - xi[k]))
    }
}

impl<R: Real, const D: usize, const N: usize> Flow<R, D, N> {
    /// Loads an embedded wall (cut cells, [`CutCells`], built on this flow's grid) with its
    /// tangential law and motion. Call after [`Flow::setup`] and before the cells are set;
    /// [`Flow::prepare`] then empties solid cells and gives every merge group its
    /// content-weighted mean state. The box sides keep their own conditions (a box face
    /// closed by the geometry carries nothing).
    pub fn set_geometry(
        &mut self,
        cut: &CutCells<R, D, N>,
        wall: CutWall<R, D>,
    ) -> Result<(), super::FlowError> {
        self.load_walls(cut, wall, false)
    }

    /// The same geometry rounded to whole cells (a *staircase*: a cell is open iff its open
    /// volume fraction is at least 1/2, a face is open iff both its cells are, box faces iff
    /// their cell is), with the wall fragments the divergence identity gives the rounded
    /// apertures. Kept to show what cut cells buy (tests/tests/flow_drum.rs): the staircase
    /// wall is not rotation-invariant, so a drum's solid-body rotation pushes mass through its
    /// steps and the bed near the wall is dragged or slips.
    pub fn set_staircase_geometry(
        &mut self,
        cut: &CutCells<R, D, N>,
        wall: CutWall<R, D>,
    ) -> Result<(), super::FlowError> {
        self.load_walls(cut, wall, true)
    }

    fn load_walls(
        &mut self,
        cut: &CutCells<R, D, N>,
        wall: CutWall<R, D>,
        staircase: bool,
    ) -> Result<(), super::FlowError> {
        use super::FlowError::Parameter;
        let grid = self.grid;
        let n = grid.len();
        if !(wall.omega.is_finite() && wall.center.iter().all(|x| x.is_finite())) {
            return Err(Parameter("cut wall motion"));
        }
        if wall.omega != R::ZERO
            && (D < 2 || wall.plane[0] == wall.plane[1] || wall.plane.iter().any(|&a| a >= D))
        {
            return Err(Parameter("cut wall rotation plane"));
        }
        if let Slip::Friction(tan) = wall.slip {
            if !(tan.is_finite() && tan >= R::ZERO) {
                return Err(Parameter("cut wall friction"));
            }
        }
        let h = grid.spacing();
        let cell = grid.cell_volume();
        let w = &mut self.walls;
        w.wall = wall;
        w.merged = false;
        let open = |v: R| v >= R::HALF;
        for i in 0..n {
            let v = cut.volume(i);
            if staircase {
                w.vol[i] = if open(v) { R::ONE } else { R::ZERO };
                w.master[i] = i as u32;
                w.gvol[i] = w.vol[i];
            } else {
                w.vol[i] = v;
                let m = cut.master(i);
                w.master[i] = m as u32;
                w.merged |= m != i;
                w.gvol[i] = if m == i { cut.group_volume(i) } else { R::ZERO };
            }
        }
        for a in 0..D {
            let s = grid.stride(a);
            let na = grid.cells()[a];
            for i in 0..n {
                let (lo, hi) = if staircase {
                    let k = grid.coord(i, a);
                    let me = open(cut.volume(i));
                    let per = self.bc[a][0].kind == crate::boundary::Boundary::Periodic;
                    // interior and wrap faces: both cells open; box faces: the cell open
                    let up = if k + 1 < na {
                        open(cut.volume(i + s))
                    } else {
                        !per || open(cut.volume(i + s - s * na))
                    };
                    let down = if k > 0 {
                        open(cut.volume(i - s))
                    } else {
                        !per || open(cut.volume(i + s * (na - 1)))
                    };
                    let f = |b: bool| if b { R::ONE } else { R::ZERO };
                    (f(me && down), f(me && up))
                } else {
                    (cut.aperture_low(a, i), cut.aperture(a, i))
                };
                w.ap_lo[a][i] = lo;
                w.ap_hi[a][i] = hi;
            }
        }
        for i in 0..n {
            // wall fragment: A n = sum_a (alpha_low - alpha_high) |face_a| e_a
            let mut an = [R::ZERO; D];
            let mut area2 = R::ZERO;
            for a in 0..D {
                an[a] = (w.ap_lo[a][i] - w.ap_hi[a][i]) * (cell / h[a]);
                area2 += an[a] * an[a];
            }
            let (area, nrm, d, master_d) = if staircase {
                let area = area2.sqrt();
                let mut nrm = [R::ZERO; D];
                let mut d = R::ZERO;
                if area > R::ZERO && w.vol[i] > R::ZERO {
                    for a in 0..D {
                        nrm[a] = an[a] / area;
                        // the plane through the mid-points of the closed faces
                        d = d.max(R::HALF * h[a] * nrm[a].abs());
                    }
                }
                // a staircase merges nothing
                (area, nrm, d, R::ZERO)
            } else {
                let nrm = cut.wall_normal(i);
                let d = cut.wall_distance(i);
                let m = w.master[i] as usize;
                let mut master_d = R::ZERO;
                if m != i {
                    // n . (x_wall - x_master): the plane through the fragment's point
                    let pt = cut.wall_point(i);
                    let xm = grid.center(m);
                    let mut plane = R::ZERO;
                    for a in 0..D {
                        plane += nrm[a] * pt[a];
                    }
                    let mut dm = plane;
                    for a in 0..D {
                        dm -= xm[a] * nrm[a];
                    }
                    // a master on the wall's far side (not met in practice) keeps the
                    // member's term
                    if dm > d {
                        master_d = dm;
                    }
                }
                (cut.wall_area(i), nrm, d, master_d)
            };
            if area > R::ZERO && w.vol[i] > R::ZERO && d > R::ZERO {
                w.wall_k[i] = area / (d * cell);
                w.wall_d[i] = d;
                w.master_d[i] = master_d;
                for a in 0..D {
                    w.normal[a][i] = nrm[a];
                }
            } else {
                w.wall_k[i] = R::ZERO;
                w.wall_d[i] = R::ZERO;
                w.master_d[i] = R::ZERO;
                for a in 0..D {
                    w.normal[a][i] = R::ZERO;
                }
            }
        }
        w.rows_spanned = w.spanned_rows(&grid);
        w.on = true;
        self.prepared = false;
        Ok(())
    }

    /// The open volume of cell `i` in the mass terms of the implicit systems (1 without an
    /// embedded wall; see [`Walls::mass_volume`]).
    #[inline(always)]
    pub(super) fn mass_factor(&self, i: usize) -> R {
        if self.walls.on {
            self.walls.mass_volume(i)
        } else {
            R::ONE
        }
    }

    /// Removes the embedded wall: back to the box scheme.
    pub fn clear_geometry(&mut self) {
        self.walls.on = false;
        self.walls.merged = false;
        self.prepared = false;
    }

    /// Whether an embedded wall is loaded.
    pub fn has_geometry(&self) -> bool {
        self.walls.on
    }

    /// Open volume fraction of cell `i` (1 without a geometry).
    pub fn open_volume(&self, i: usize) -> R {
        if self.walls.on {
            self.walls.vol[i]
        } else {
            R::ONE
        }
    }

    /// Wall coefficient `A / (d |C|)` of cell `i` (0 if it has no cut wall fragment).
    pub fn wall_coefficient(&self, i: usize) -> R {
        if self.walls.on {
            self.walls.wall_k[i]
        } else {
            R::ZERO
        }
    }

    /// The velocity of the cut wall at the Dirichlet point of cell `i`.
    pub fn wall_velocity(&self, i: usize) -> [R; D] {
        if !self.walls.turns() {
            return [R::ZERO; D];
        }
        self.walls.wall_velocity(self.home_center(i), i)
    }

    /// The wall law of the cut wall fragment of cell `i` (model.md 2) as the Dirichlet-type term
    /// `kw e (u_B - u)` of the viscous stage: the boundary velocity `u_B` and the viscosity-like
    /// drag `e` that replaces `eta` in it, from the velocity at the start of the step (lagged),
    /// the cell's viscosity and pressure. With `t` the tangential part of `u_I - u_W`:
    /// - no-slip: `u_B = u_W`, `e = eta`;
    /// - slip: `u_B = u_W + t` (zero tangential stress; normal component that of the wall),
    ///   `e = eta`;
    /// - friction `tan(phi_w)`: `u_B = u_W`, `e = min(eta, p tan(phi_w) d / |t|)`: the wall
    ///   stress `e |u_W - u| / d` is the no-slip one while that stays below `p tan(phi_w)`
    ///   (stick), else `p tan(phi_w)` at the lagged slip (slide), towards the wall velocity.
    ///
    /// Why a reduced drag and not a Dirichlet value between `u_W` and `u_I` (the rule until
    /// stop 17): with the yield viscosity of a dense bed, `eta dt / (d h)` is huge, the implicit
    /// solve pins the cell to `u_B`, and a `u_B` only `p tan(phi_w) d / eta` away from `u_I`
    /// passes next to none of the friction force (a block sliding on a cut floor was not
    /// braked at all, tests/tests/flow_cut_friction.rs, and the lab-frame drum's wall slid
    /// under a resting bed). The reduced drag gives exactly
    /// `p tan(phi_w)` at the lagged slip, cannot push the bed past the wall's velocity within a
    /// step (it is implicit), and equals the no-slip term where the two branches meet
    /// (`eta |t| / d = p tan(phi_w)`), as the box wall's explicit `Face::Stress` does not need to.
    pub(super) fn wall_law(&self, i: usize) -> ([R; D], R) {
        self.wall_law_on(i, i, self.walls.wall_d[i])
    }

    /// Whether merged cells' wall terms go to their masters in this flow
    /// ([`MergedWalls::on_master`]); asked once per stage, not per cell.
    pub(super) fn walls_on_master(&self) -> bool {
        self.cfg
            .merged_walls
            .on_master(self.cfg.stress, self.walls.wall.omega != R::ZERO)
            .unwrap_or(false)
    }

    /// The wall term of cell `i`'s fragment as the implicit stages book it: `(row, k, u_B,
    /// e)`, the term `k e (u_B - u_row)` in the row of cell `row`. That is `i` itself with its
    /// own `A / (d |C|)`, or with `on_master` ([`Self::walls_on_master`]) a member's master,
    /// with the same area at the master's distance `d_M` to the fragment's plane (`k = A /
    /// (d_M |C|)`) and the wall law evaluated there (a friction wall's stress stays `p
    /// tan(phi_w)`).
    pub(super) fn wall_term(&self, i: usize, on_master: bool) -> (usize, R, [R; D], R) {
        let w = &self.walls;
        let dm = w.master_d[i];
        if on_master && dm > R::ZERO {
            let m = w.master[i] as usize;
            let (ub, e) = self.wall_law_on(i, m, dm);
            return (m, w.wall_k[i] * w.wall_d[i] / dm, ub, e);
        }
        let (ub, e) = self.wall_law(i);
        (i, w.wall_k[i], ub, e)
    }

    /// [`Self::wall_law`] of cell `i`'s fragment acting on cell `row` at distance `d`.
    fn wall_law_on(&self, i: usize, row: usize, d: R) -> ([R; D], R) {
        let w = &self.walls;
        let uw = self.wall_velocity(i);
        let eta = self.eta[row];
        if w.wall.slip == Slip::NoSlip {
            return (uw, eta);
        }
        let mut rel = [R::ZERO; D];
        let mut rn = R::ZERO;
        for a in 0..D {
            rel[a] = self.u_prev[a][row] - uw[a];
            rn += rel[a] * w.normal[a][i];
        }
        let mut t2 = R::ZERO;
        for a in 0..D {
            rel[a] -= rn * w.normal[a][i];
            t2 += rel[a] * rel[a];
        }
        match w.wall.slip {
            Slip::Friction(tan) => {
                let t = t2.sqrt();
                let limit = self.p[row] * tan * d;
                // stick unless the no-slip stress eta t / d exceeds p tan(phi_w)
                let e = if limit >= eta * t { eta } else { limit / t };
                (uw, e)
            }
            _ => {
                let mut ub = uw;
                for a in 0..D {
                    ub[a] += rel[a];
                }
                (ub, eta)
            }
        }
    }
}

impl<R: Real, const D: usize, const N: usize> Flow<R, D, N> {
    /// Empties the solid cells and gives each merge group its content-weighted mean state;
    /// with a moving wall the mean of the momentum relative to the wall's rigid motion (taken
    /// at the master), so a bed started in the rigid rotation keeps it exactly.
    pub(super) fn embedded_prepare(&mut self) {
        let n = self.grid.len();
        for i in 0..n {
            if self.walls.vol[i] == R::ZERO {
                self.c[i] = R::ZERO;
                self.e[i] = R::ZERO;
                self.t[i] = R::ZERO;
                for a in 0..D {
                    self.m[a][i] = R::ZERO;
                    self.u[a][i] = R::ZERO;
                }
            }
        }
        let rigid = self.walls.rigid_groups();
        if rigid {
            // momentum relative to the wall's rigid motion taken at each member's master,
            // so that the group mean below is the master's own rigid value
            for i in 0..n {
                let m = self.walls.master[i] as usize;
                if m != i {
                    let off = self
                        .walls
                        .rigid_offset(self.home_center(i), self.home_center(m));
                    for a in 0..D {
                        self.m[a][i] -= self.c[i] * off[a];
                    }
                }
            }
        }
        let w = &self.walls;
        w.group_mean(n, &mut self.c, &mut self.rhs);
        w.group_mean(n, &mut self.e, &mut self.rhs);
        for a in 0..D {
            w.group_mean(n, &mut self.m[a], &mut self.rhs);
        }
        if rigid {
            self.carry_rigid_offsets();
        }
    }

    /// A moving cut wall (lab frame): every member of a merge group takes its master's
    /// momentum *plus* the wall's rigid motion between the two centres,
    /// `m_k = m_M + c (u_R(x_k) - u_R(x_M))`, instead of the master's value alone. Why: a
    /// group is one cell for the explicit stages, and copying the master's velocity to a
    /// member a cell away puts it `omega h` off a rigid rotation every step; the implicit
    /// viscous solve then pulls it back, and the discrete heating of that correction (linear
    /// in it at cut faces) heated the wall ring to 10x the bed's T (docs/frames.md, "The
    /// moving cut wall heated the bed"). With the offset a rigid rotation passes through the
    /// group update unchanged. A resting wall (`omega = 0`: the rotating frame, silos,
    /// hoppers) never calls this: the plain copy, same bits.
    pub(super) fn carry_rigid_offsets(&mut self) {
        let n = self.grid.len();
        for i in 0..n {
            let m = self.walls.master[i] as usize;
            if m != i {
                let off = self
                    .walls
                    .rigid_offset(self.home_center(i), self.home_center(m));
                let c = self.c[i];
                for a in 0..D {
                    self.m[a][i] = self.m[a][m] + c * off[a];
                }
            }
        }
    }

    /// Open aperture of the interior (or wrap) face `(l, r)` along `a` for the transport:
    /// 0 inside a merge group (the group is one cell there).
    #[inline(always)]
    pub(super) fn transport_aperture(&self, a: usize, l: usize, r: usize) -> R {
        let w = &self.walls;
        if w.master[l] == w.master[r] {
            R::ZERO
        } else {
            w.ap_hi[a][l]
        }
    }

    /// Transport limiters in content units (module docs of `walls`): a group's inflow is
    /// scaled so its content cannot pass `V (c_max - c)`, its outflow so it cannot drop below
    /// 0. On entry `inflow` / `diag` hold each cell's in- and outflow (per full cell); on exit
    /// the factors, the same for every member of a group.
    pub(super) fn embedded_limiters(&mut self) {
        let n = self.grid.len();
        let w = &self.walls;
        w.group_sum(n, &mut self.inflow);
        w.group_sum(n, &mut self.diag);
        for i in 0..n {
            let gv = w.gvol[w.master[i] as usize];
            let cmax = (R::ONE - self.cfg.margin) * self.c_rcp[i];
            let room = gv * (cmax - self.c[i]).max(R::ZERO);
            let inflow = self.inflow[i];
            self.inflow[i] = if inflow > room { room / inflow } else { R::ONE };
            let content = super::step::spendable(gv * self.c[i]);
            let outflow = self.diag[i];
            self.diag[i] = if outflow > content {
                content / outflow
            } else {
                R::ONE
            };
        }
    }

    /// Before the transport update: the scratch vectors that collect the content increments
    /// of c, c T and c u ([`Self::embedded_add_flux`]) are cleared.
    pub(super) fn embedded_begin_update(&mut self) {
        let n = self.grid.len();
        self.rhs[..n].fill(R::ZERO);
        self.solve.r[..n].fill(R::ZERO);
        let dm: [&mut [R; N]; 3] = [&mut self.solve.p, &mut self.solve.ap, &mut self.solve.pre];
        for d in dm.into_iter().take(D) {
            d[..n].fill(R::ZERO);
        }
    }

    /// Books the content increment `dc` (and `dc u`, `dc T`) of cell `i`.
    #[inline(always)]
    pub(super) fn embedded_add_flux(&mut self, i: usize, dc: R, u: [R; D], t: R) {
        self.rhs[i] += dc;
        self.solve.r[i] += dc * t;
        let dm: [&mut [R; N]; 3] = [&mut self.solve.p, &mut self.solve.ap, &mut self.solve.pre];
        for (a, d) in dm.into_iter().enumerate().take(D) {
            d[i] += dc * u[a];
        }
    }

    /// After the transport update: the group sums of the increments over the group volumes
    /// are added (members copy their master).
    pub(super) fn embedded_end_update(&mut self) {
        let n = self.grid.len();
        let w = &self.walls;
        w.apply_increment(n, &mut self.c, &mut self.rhs);
        w.apply_increment(n, &mut self.e, &mut self.solve.r);
        let dm: [&mut [R; N]; 3] = [&mut self.solve.p, &mut self.solve.ap, &mut self.solve.pre];
        for (a, d) in dm.into_iter().enumerate().take(D) {
            w.apply_increment(n, &mut self.m[a], d);
        }
        if self.walls.rigid_groups() {
            self.carry_rigid_offsets();
        }
    }

    /// Pressure + gravity forces (content per full cell in `kf`) summed over each merge group
    /// and divided by its volume: the force per open volume (0 in solid cells).
    pub(super) fn embedded_forces(&mut self) {
        let n = self.grid.len();
        let w = &self.walls;
        for a in 0..D {
            let kf = &mut self.kf[a];
            if w.merged {
                for i in 0..n {
                    let m = w.master[i] as usize;
                    if m != i {
                        kf[m] += kf[i];
                    }
                }
            }
            for i in 0..n {
                let m = w.master[i] as usize;
                if m == i {
                    let gv = w.gvol[i];
                    kf[i] = if gv > R::ZERO { kf[i] / gv } else { R::ZERO };
                }
            }
            w.copy_to_members(n, kf);
        }
    }

    /// Unilateral contact of loose cells with the cut wall, along its own normal, with Coulomb
    /// friction (the box rule of `wall_contact`): a cut cell with `c <= c_rlp` or a nearly
    /// empty inner neighbour (along `-n`) loses the momentum relative to the wall that points
    /// into it, and up to `tan(phi_w)` of that impulse of its tangential momentum.
    pub(super) fn embedded_wall_contact(&mut self) {
        let n = self.grid.len();
        let grid = self.grid;
        for i in 0..n {
            let k = self.walls.wall_k[i];
            let c = self.c[i];
            if !(k > R::ZERO && c > self.cfg.vacuum) {
                continue;
            }
            let uw = self.wall_velocity(i);
            let mut rel = [R::ZERO; D];
            let mut into = R::ZERO;
            // inner neighbour: one cell against the dominant component of the normal
            let (mut ax, mut big) = (0, R::ZERO);
            for a in 0..D {
                let na = self.walls.normal[a][i];
                rel[a] = self.m[a][i] - c * uw[a];
                into += rel[a] * na;
                if na.abs() > big {
                    big = na.abs();
                    ax = a;
                }
            }
            if !(into > R::ZERO) {
                continue;
            }
            let k_ax = grid.coord(i, ax);
            let s = grid.stride(ax);
            let inner = if self.walls.normal[ax][i] > R::ZERO {
                if k_ax > 0 {
                    self.c[i - s]
                } else {
                    R::ZERO
                }
            } else if k_ax + 1 < grid.cells()[ax] {
                self.c[i + s]
            } else {
                R::ZERO
            };
            if !(c <= self.c_rlp[i] || inner < self.cfg.surface) {
                continue;
            }
            let mut t2 = R::ZERO;
            for a in 0..D {
                rel[a] -= into * self.walls.normal[a][i];
                t2 += rel[a] * rel[a];
            }
            let t = t2.sqrt();
            let keep = match self.walls.wall.slip {
                Slip::NoSlip => R::ZERO,
                Slip::Slip => R::ONE,
                Slip::Friction(tan) => {
                    if t > R::ZERO {
                        R::ONE - (tan * into).min(t) / t
                    } else {
                        R::ZERO
                    }
                }
            };
            for a in 0..D {
                self.m[a][i] = c * uw[a] + keep * rel[a];
            }
        }
    }
}
