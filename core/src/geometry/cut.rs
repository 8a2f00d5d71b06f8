//! Cut cells: volume fractions, face apertures, wall fragments and small-cell merging,
//! computed once at set-up from a [`Region`] (issue 8).
//!
//! # What is computed, and how exactly
//!
//! Everything is derived from the signed distance at the cell corners and from its zero
//! crossings on the cell edges (found by an Illinois regula-falsi iteration on the distance
//! itself, so a crossing is exact to round-off for any shape, curved or flat):
//! - the open fraction of an edge is the part on the open side of its crossing;
//! - the aperture of a face (a square in 3D) and the volume fraction of a cell follow from the
//!   divergence theorem applied to the open region with the origin moved to `p`, the mean of
//!   the crossing points of that face or cell. In coordinates `xi` normalised to the unit cell,
//!   `V = (1/D) sum_a [A_low,a p_a + A_high,a (1 - p_a)]`: the wall term
//!   `int (x - p) . n dA` vanishes when the wall is one plane through `p`. So a single straight
//!   (2D) or planar (3D) wall per cell gives volume fractions and apertures **exact to
//!   round-off**, whatever its angle; a curved wall is replaced by the polygon (polyhedron)
//!   through its exact edge crossings: the disc's area converges at second order (measured in
//!   tests/tests/geometry.rs), and a cylinder along a grid axis is exactly the 2D disc times
//!   its length. A cell where two walls meet (a polytope's corner inside the cell) is
//!   approximated in the same way (local error `O(h^D)`, a few cells). A wall feature that
//!   crosses no cell edge (thinner than a cell and between corners) is not seen: resolve
//!   baffles with at least one cell of thickness.
//! - the wall vector of a cell is `W_a = (A_low,a - A_high,a) |face_a|`, its area `|W|` and
//!   normal `W/|W|` (from the open region into the solid). Defined from the apertures, the
//!   closed surface of every cut cell sums to zero: a uniform pressure exerts no net force
//!   (`wall_vector` gives `W` bit-exactly as the face terms are written).
//! - the wall point is the mean edge crossing of the cell (on the wall for a planar cut), the
//!   open centroid is the centroid of the open polygon through the crossings in 2D (exact for
//!   a straight wall) and the mean of the open polyhedron's vertices in 3D (open corners and
//!   crossings: exact for tetrahedra and slabs, an estimate otherwise), and the wall distance
//!   is that centroid's distance to the wall plane, floored at [`WALL_DISTANCE_FLOOR`] `min h`.
//!
//! # Small cells: merging, not redistribution
//!
//! An explicit update divides a face flux by the cell's open volume, so a cell with volume
//! fraction `V` would need a time step `V` times the full cell's. Two cures are common:
//! flux redistribution (Basilisk `embed.h`, AMReX) lets the small cell take only the part of
//! its update it can stand and spreads the rest over its neighbours; cell merging joins each
//! small cell to a full-enough neighbour (its *master*) and updates the pair as one cell of
//! volume `V_group >= small`. We merge, because
//! - **bounds by construction**: a group is one finite volume with uniform state; the modified
//!   flux's bound argument (`0 <= phi <= c`) holds for it unchanged, whereas redistribution
//!   adds a second, non-monotone transfer that can overshoot in the receivers;
//! - **no CFL loss**: the group volume is at least `small` (default 1/2) and the small cell's
//!   extra faces are those with small apertures (a planar wall leaves large apertures only
//!   across the face it merges through), so the group's stable step is that of a cut cell of
//!   volume >= small (see the segregation solver's `stable_dt_embedded`);
//! - **one fixed gather**: `apply_increment` sums the group's increments in cell-index order and
//!   writes back; no scatter, no order that depends on anything else, same bits everywhere.
//!
//! A small cell with no open neighbour of volume `>= small` (an island or a sliver pocket
//! under-resolved by the grid) is **folded into the solid**: its volume becomes 0, its faces
//! close, and the lost volume is reported in [`GeometryStats`] (`removed`, `removed_volume`);
//! the neighbours' wall vectors then include the closed faces, so the identities above still
//! hold. A build never fails because of the grid resolution. A cell whose open fraction is
//! round-off (a wall on a grid line; [`sliver_fraction`]) is solid from the start and is
//! counted there too.

use super::shape::{root, Region};
use crate::grid::Grid;
use crate::real::Real;

/// The wall distance is floored at this fraction of the smallest cell width: the viscous wall
/// flux divides by it, and a tiny cut cell's centroid may lie arbitrarily close to the wall.
pub const WALL_DISTANCE_FLOOR: f64 = 0.1;

/// Default merging threshold: cells with `0 < volume < 1/2` are merged.
pub const DEFAULT_SMALL: f64 = 0.5;

/// What a build found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GeometryStats<R> {
    /// Total open volume `sum V_i |C|` after folding (m^D).
    pub open_volume: R,
    /// Cells with `0 < V < 1` (after folding).
    pub cut: usize,
    /// Cells merged into a master.
    pub merged: usize,
    /// Cells folded into the solid: round-off slivers ([`sliver_fraction`]) and small cells
    /// with no open neighbour of volume `>= small`.
    pub removed: usize,
    /// Their open volume (m^D), lost to the solid.
    pub removed_volume: R,
    /// Smallest positive volume fraction of a remaining cell (1 if there is none below 1).
    pub min_volume: R,
    /// Smallest group volume fraction of a master (>= small unless no cell reaches it).
    pub min_group_volume: R,
}

impl<R: Real> GeometryStats<R> {
    const fn zero() -> Self {
        Self {
            open_volume: R::ZERO,
            cut: 0,
            merged: 0,
            removed: 0,
            removed_volume: R::ZERO,
            min_volume: R::ONE,
            min_group_volume: R::ONE,
        }
    }
}

/// Why cut cells cannot be built.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GeometryError {
    /// The grid needs more cells than the capacity.
    Capacity {
        /// cells needed
        cells: usize,
        /// compiled capacity
        capacity: usize,
    },
    /// Only 1, 2 and 3 dimensions are supported.
    Dimension,
    /// The merging threshold is not in `[0, 1)`.
    Small,
    /// The signed distance is NaN at a corner of this cell.
    NonFinite {
        /// cell index
        cell: usize,
    },
    /// No cell is open.
    NoOpenCell,
}

impl core::fmt::Display for GeometryError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            GeometryError::Capacity { cells, capacity } => {
                write!(f, "{cells} cells exceed the capacity {capacity}")
            }
            GeometryError::Dimension => write!(f, "cut cells need 1, 2 or 3 dimensions"),
            GeometryError::Small => write!(f, "the merging threshold must be in [0, 1)"),
            GeometryError::NonFinite { cell } => {
                write!(f, "the signed distance is NaN at a corner of cell {cell}")
            }
            GeometryError::NoOpenCell => write!(f, "the geometry leaves no open cell"),
        }
    }
}

/// One cell edge: its open fraction and the normalised position `t` of its crossing.
#[derive(Clone, Copy)]
struct Edge<R> {
    open: R,
    cross: Option<R>,
}

/// Volume fractions, apertures, walls and the merge map of a grid, for up to `N` cells.
#[derive(Clone, Debug)]
pub struct CutCells<R: Real, const D: usize, const N: usize> {
    grid: Grid<R, D>,
    periodic: [bool; D],
    small: R,
    vol: [R; N],
    /// Aperture of the high face of each cell along each axis.
    ap: [[R; N]; D],
    /// Aperture of the low box face (used at the first cell of a line on non-periodic axes).
    ap_box_low: [[R; N]; D],
    /// Wall vector `(A_low - A_high) |face|` per axis.
    wall: [[R; N]; D],
    wall_area: [R; N],
    wall_dist: [R; N],
    wall_point: [[R; N]; D],
    centroid: [[R; N]; D],
    group_vol: [R; N],
    master: [u32; N],
    /// Bit `2a` (`2a + 1`): the low (high) neighbour along axis `a` is merged into this cell.
    merged: [u8; N],
    stats: GeometryStats<R>,
}

impl<R: Real, const D: usize, const N: usize> Default for CutCells<R, D, N> {
    fn default() -> Self {
        Self::zeroed()
    }
}

impl<R: Real, const D: usize, const N: usize> CutCells<R, D, N> {
    /// An empty geometry on a one-cell grid; `const` so it can live in a `static`.
    pub const fn zeroed() -> Self {
        Self {
            grid: Grid::unit(),
            periodic: [false; D],
            small: R::ZERO,
            vol: [R::ZERO; N],
            ap: [[R::ZERO; N]; D],
            ap_box_low: [[R::ZERO; N]; D],
            wall: [[R::ZERO; N]; D],
            wall_area: [R::ZERO; N],
            wall_dist: [R::ZERO; N],
            wall_point: [[R::ZERO; N]; D],
            centroid: [[R::ZERO; N]; D],
            group_vol: [R::ZERO; N],
            master: [0; N],
            merged: [0; N],
            stats: GeometryStats::zero(),
        }
    }

    /// No walls: every volume and aperture 1, no merging.
    pub fn full(&mut self, grid: &Grid<R, D>) -> Result<GeometryStats<R>, GeometryError> {
        self.build(grid, &Region::new(), [false; D], R::ZERO)
    }

    /// Computes everything for `region` on `grid`. `periodic[a]`: axis `a` wraps (the wrap
    /// face is evaluated at the high end of the box); `small` in `[0, 1)`: cells below this
    /// volume fraction are merged (0: no merging). Deterministic: the same input gives the
    /// same bits.
    pub fn build(
        &mut self,
        grid: &Grid<R, D>,
        region: &Region<R, D>,
        periodic: [bool; D],
        small: R,
    ) -> Result<GeometryStats<R>, GeometryError> {
        if D == 0 || D > 3 {
            return Err(GeometryError::Dimension);
        }
        let n = grid.len();
        if n > N {
            return Err(GeometryError::Capacity {
                cells: n,
                capacity: N,
            });
        }
        if !(small >= R::ZERO && small < R::ONE) {
            return Err(GeometryError::Small);
        }
        self.grid = *grid;
        self.periodic = periodic;
        self.small = small;

        // 1. apertures of the high faces (and of the low box faces)
        for i in 0..n {
            let j = grid.coords(i);
            for a in 0..D {
                let mut jh = j;
                jh[a] += 1;
                self.ap[a][i] = self.face(region, jh, a, i)?;
                self.ap_box_low[a][i] = if j[a] == 0 && !periodic[a] {
                    self.face(region, j, a, i)?
                } else {
                    R::ZERO
                };
            }
        }
        // 2. volume fractions, wall points, open centroids
        for i in 0..n {
            self.cell_volume(region, i)?;
        }
        // 3. solid cells close their faces (a face may keep a sliver of aperture when the
        //    polygon of a neighbouring cell rounds to zero volume); so do the round-off slivers
        //    a wall lying on a grid line leaves open (`sliver_fraction`), which are solid
        let mut stats = GeometryStats::<R>::zero();
        let cell_volume = grid.cell_volume();
        let sliver = sliver_fraction(grid);
        for i in 0..n {
            let v = self.vol[i];
            if v < sliver {
                if v > R::ZERO {
                    stats.removed += 1;
                    stats.removed_volume += v * cell_volume;
                    self.vol[i] = R::ZERO;
                }
                self.close_faces(i);
            }
        }
        // 4. small cells without a master are folded into the solid; the candidate set of a
        //    small cell never contains a small cell, so folding does not cascade
        for i in 0..n {
            let v = self.vol[i];
            if v > R::ZERO && v < small && self.candidates(i).is_none() {
                stats.removed += 1;
                stats.removed_volume += v * cell_volume;
                self.vol[i] = R::ZERO;
                self.close_faces(i);
            }
        }
        // 5. walls from the final apertures
        let h = grid.spacing();
        let mut hmin = h[0];
        for &ha in h.iter() {
            hmin = hmin.min(ha);
        }
        let floor = R::from_f64(WALL_DISTANCE_FLOOR) * hmin;
        for i in 0..n {
            let mut w2 = R::ZERO;
            for a in 0..D {
                let wa = (self.aperture_low(a, i) - self.ap[a][i]) * self.face_area(a);
                self.wall[a][i] = wa;
                w2 += wa * wa;
            }
            let area = w2.sqrt();
            self.wall_area[i] = area;
            self.wall_dist[i] = if area > R::ZERO {
                // distance of the open centroid from the wall plane, positive on the open side
                let mut s = R::ZERO;
                for a in 0..D {
                    s += (self.wall_point[a][i] - self.centroid[a][i]) * (self.wall[a][i] / area);
                }
                s.max(floor)
            } else {
                R::ZERO
            };
        }
        // 6. merge map
        for i in 0..n {
            self.master[i] = i as u32;
            self.merged[i] = 0;
        }
        for i in 0..n {
            let v = self.vol[i];
            if v > R::ZERO && v < small {
                let (m, a, high) = self.candidates(i).expect("folded above");
                self.master[i] = m as u32;
                // seen from the master, i is across the opposite face
                self.merged[m] |= 1 << (2 * a + usize::from(!high));
                stats.merged += 1;
            }
        }
        // 7. group volumes (gathered in cell-index order) and statistics
        for i in 0..n {
            self.group_vol[i] = self.group_sum(i, &self.vol);
        }
        for i in 0..n {
            let m = self.master[i] as usize;
            if m != i {
                self.group_vol[i] = self.group_vol[m];
            }
        }
        let mut open = R::ZERO;
        let mut any_open = false;
        for i in 0..n {
            let v = self.vol[i];
            open += v;
            if v > R::ZERO {
                any_open = true;
                if v < R::ONE {
                    stats.cut += 1;
                    stats.min_volume = stats.min_volume.min(v);
                }
                if self.master[i] as usize == i {
                    stats.min_group_volume = stats.min_group_volume.min(self.group_vol[i]);
                }
            }
        }
        if !any_open {
            return Err(GeometryError::NoOpenCell);
        }
        stats.open_volume = open * cell_volume;
        self.stats = stats;
        Ok(stats)
    }

    // ---------------------------------------------------------------- construction helpers

    fn corner(&self, j: [usize; D]) -> [R; D] {
        let o = self.grid.origin();
        let h = self.grid.spacing();
        let mut x = o;
        for a in 0..D {
            x[a] = o[a] + R::from_usize(j[a]) * h[a];
        }
        x
    }

    fn dist(&self, region: &Region<R, D>, x: [R; D], cell: usize) -> Result<R, GeometryError> {
        let d = region.distance(x);
        if d.partial_cmp(&R::ZERO).is_none() {
            return Err(GeometryError::NonFinite { cell });
        }
        Ok(d)
    }

    /// The edge from corner `j` along axis `b`.
    fn edge(
        &self,
        region: &Region<R, D>,
        j: [usize; D],
        b: usize,
        cell: usize,
    ) -> Result<Edge<R>, GeometryError> {
        let x0 = self.corner(j);
        let mut j1 = j;
        j1[b] += 1;
        let x1 = self.corner(j1);
        let d0 = self.dist(region, x0, cell)?;
        let d1 = self.dist(region, x1, cell)?;
        let (o0, o1) = (d0 <= R::ZERO, d1 <= R::ZERO);
        if o0 && o1 {
            return Ok(Edge {
                open: R::ONE,
                cross: None,
            });
        }
        if !o0 && !o1 {
            return Ok(Edge {
                open: R::ZERO,
                cross: None,
            });
        }
        let t = if d0 == R::ZERO {
            R::ZERO
        } else {
            let at = |t: R| {
                let mut x = x0;
                x[b] = x0[b] + t * (x1[b] - x0[b]);
                region.distance(x)
            };
            root(at, d0, d1)
        };
        Ok(Edge {
            open: if o0 { t } else { R::ONE - t },
            cross: Some(t),
        })
    }

    /// Open fraction of the face normal to `a` whose lowest corner is `j`.
    fn face(
        &self,
        region: &Region<R, D>,
        j: [usize; D],
        a: usize,
        cell: usize,
    ) -> Result<R, GeometryError> {
        Ok(match D {
            1 => {
                if self.dist(region, self.corner(j), cell)? <= R::ZERO {
                    R::ONE
                } else {
                    R::ZERO
                }
            }
            2 => self.edge(region, j, 1 - a, cell)?.open,
            _ => {
                let (b, c) = match a {
                    0 => (1, 2),
                    1 => (0, 2),
                    _ => (0, 1),
                };
                let mut jc = j;
                jc[c] += 1;
                let mut jb = j;
                jb[b] += 1;
                let b0 = self.edge(region, j, b, cell)?;
                let b1 = self.edge(region, jc, b, cell)?;
                let c0 = self.edge(region, j, c, cell)?;
                let c1 = self.edge(region, jb, c, cell)?;
                let mut sum = [R::ZERO; 2];
                let mut count = 0usize;
                for (e, fixed, along) in [
                    (b0, R::ZERO, 0),
                    (b1, R::ONE, 0),
                    (c0, R::ZERO, 1),
                    (c1, R::ONE, 1),
                ] {
                    if let Some(t) = e.cross {
                        sum[along] += t;
                        sum[1 - along] += fixed;
                        count += 1;
                    }
                }
                let p = if count > 0 {
                    let k = R::from_usize(count);
                    [sum[0] / k, sum[1] / k]
                } else {
                    [R::HALF, R::HALF]
                };
                let area = (c0.open * p[0]
                    + c1.open * (R::ONE - p[0])
                    + (b0.open * p[1] + b1.open * (R::ONE - p[1])))
                    * R::HALF;
                area.max(R::ZERO).min(R::ONE)
            }
        })
    }

    /// Volume fraction, wall point and open-centroid estimate of cell `i` from the stored
    /// apertures and the edge crossings.
    fn cell_volume(&mut self, region: &Region<R, D>, i: usize) -> Result<(), GeometryError> {
        let j = self.grid.coords(i);
        let mut cross_sum = [R::ZERO; D];
        let mut crossings = 0usize;
        let mut vert_sum = [R::ZERO; D];
        let mut vertices = 0usize;
        // corners
        for k in 0..(1usize << D) {
            let mut jc = j;
            let mut xi = [R::ZERO; D];
            for a in 0..D {
                if k >> a & 1 == 1 {
                    jc[a] += 1;
                    xi[a] = R::ONE;
                }
            }
            if self.dist(region, self.corner(jc), i)? <= R::ZERO {
                for a in 0..D {
                    vert_sum[a] += xi[a];
                }
                vertices += 1;
            }
        }
        // edges: along b, offset by the bits of k on the other axes
        for b in 0..D {
            for k in 0..(1usize << D) {
                if k >> b & 1 == 1 {
                    continue;
                }
                let mut jc = j;
                let mut xi = [R::ZERO; D];
                for a in 0..D {
                    if k >> a & 1 == 1 {
                        jc[a] += 1;
                        xi[a] = R::ONE;
                    }
                }
                if let Some(t) = self.edge(region, jc, b, i)?.cross {
                    xi[b] = t;
                    for a in 0..D {
                        cross_sum[a] += xi[a];
                        vert_sum[a] += xi[a];
                    }
                    crossings += 1;
                    vertices += 1;
                }
            }
        }
        let p = if crossings > 0 {
            let k = R::from_usize(crossings);
            let mut p = cross_sum;
            p.iter_mut().for_each(|x| *x = *x / k);
            p
        } else {
            [R::HALF; D]
        };
        let mut v = R::ZERO;
        for a in 0..D {
            v += self.aperture_low(a, i) * p[a] + self.ap[a][i] * (R::ONE - p[a]);
        }
        v = (v / R::from_usize(D)).max(R::ZERO).min(R::ONE);
        self.vol[i] = v;
        let lo = self.corner(j);
        let h = self.grid.spacing();
        let exact = if D == 2 && crossings > 0 {
            self.polygon_centroid(region, j, i)?
        } else {
            None
        };
        for a in 0..D {
            self.wall_point[a][i] = lo[a] + p[a] * h[a];
            let c = match exact {
                Some(c) => c[a],
                None if vertices > 0 => vert_sum[a] / R::from_usize(vertices),
                None => R::HALF,
            };
            self.centroid[a][i] = lo[a] + c * h[a];
        }
        Ok(())
    }

    /// 2D: the centroid (normalised coordinates) of the open polygon of cell `i` with lowest
    /// corner `j`, walking the cell boundary counter-clockwise through the open corners and
    /// the edge crossings; `None` for a degenerate polygon.
    fn polygon_centroid(
        &self,
        region: &Region<R, D>,
        j: [usize; D],
        i: usize,
    ) -> Result<Option<[R; 2]>, GeometryError> {
        let at = |dx: usize, dz: usize| {
            let mut jc = j;
            let s: &mut [usize] = &mut jc;
            s[0] += dx;
            s[1] += dz;
            jc
        };
        // each side: its first corner, then the lowest corner and the axis of its edge (the
        // crossing lies between the side's two corners whichever way the edge runs)
        let sides = [
            ((0, 0), (0, 0), 0),
            ((1, 0), (1, 0), 1),
            ((1, 1), (0, 1), 0),
            ((0, 1), (0, 0), 1),
        ];
        let mut poly = [[R::ZERO; 2]; 8];
        let mut len = 0;
        for ((cx, cz), (ex, ez), axis) in sides {
            if self.dist(region, self.corner(at(cx, cz)), i)? <= R::ZERO {
                poly[len] = [R::from_usize(cx), R::from_usize(cz)];
                len += 1;
            }
            if let Some(t) = self.edge(region, at(ex, ez), axis, i)?.cross {
                let mut v = [R::from_usize(ex), R::from_usize(ez)];
                v[axis] = t;
                poly[len] = v;
                len += 1;
            }
        }
        let (mut a2, mut cx, mut cz) = (R::ZERO, R::ZERO, R::ZERO);
        for k in 0..len {
            let (p, q) = (poly[k], poly[(k + 1) % len]);
            let cross = p[0] * q[1] - q[0] * p[1];
            a2 += cross;
            cx += (p[0] + q[0]) * cross;
            cz += (p[1] + q[1]) * cross;
        }
        if !(a2 > R::EPSILON) {
            return Ok(None);
        }
        let three_a2 = R::from_usize(3) * a2;
        Ok(Some([cx / three_a2, cz / three_a2]))
    }

    fn close_faces(&mut self, i: usize) {
        let cells = self.grid.cells();
        for a in 0..D {
            self.ap[a][i] = R::ZERO;
            let ja = self.grid.coord(i, a);
            if ja > 0 {
                self.ap[a][i - self.grid.stride(a)] = R::ZERO;
            } else if self.periodic[a] {
                self.ap[a][i + (cells[a] - 1) * self.grid.stride(a)] = R::ZERO;
            } else {
                self.ap_box_low[a][i] = R::ZERO;
            }
        }
    }

    /// The master of small cell `i`: `(neighbour, axis, high side)` among open faces to a
    /// neighbour with volume `>= small`, most opposite to the wall normal (largest
    /// `-sign W_a`), ties to the lowest index.
    fn candidates(&self, i: usize) -> Option<(usize, usize, bool)> {
        let mut best: Option<(usize, usize, bool)> = None;
        let mut best_score = R::ZERO;
        for a in 0..D {
            let w = (self.aperture_low(a, i) - self.ap[a][i]) * self.face_area(a);
            for high in [false, true] {
                let open = if high {
                    self.ap[a][i]
                } else {
                    self.aperture_low(a, i)
                };
                let Some(nb) = self.neighbour(i, a, high) else {
                    continue;
                };
                if !(open > R::ZERO) || nb == i || !(self.vol[nb] >= self.small) {
                    continue;
                }
                let score = if high { -w } else { w };
                let better = match best {
                    None => true,
                    Some((b, _, _)) => score > best_score || (score == best_score && nb < b),
                };
                if better {
                    best = Some((nb, a, high));
                    best_score = score;
                }
            }
        }
        best
    }

    /// Sum of `x` over the group of master `i` in cell-index order; `x[i]` alone for a cell
    /// without merged neighbours.
    fn group_sum(&self, i: usize, x: &[R]) -> R {
        let mask = self.merged[i];
        if mask == 0 {
            return x[i];
        }
        let (idx, len) = self.group_members(i, mask);
        let mut s = R::ZERO;
        for &k in &idx[..len] {
            s += x[k];
        }
        s
    }

    /// Master `i` and its merged neighbours, in increasing index.
    fn group_members(&self, i: usize, mask: u8) -> ([usize; 7], usize) {
        let mut idx = [0usize; 7];
        idx[0] = i;
        let mut len = 1;
        for a in 0..D {
            for high in [false, true] {
                if mask >> (2 * a + usize::from(high)) & 1 == 1 {
                    if let Some(nb) = self.neighbour(i, a, high) {
                        idx[len] = nb;
                        len += 1;
                    }
                }
            }
        }
        // insertion sort (at most 7 entries)
        for k in 1..len {
            let mut m = k;
            while m > 0 && idx[m - 1] > idx[m] {
                idx.swap(m - 1, m);
                m -= 1;
            }
        }
        (idx, len)
    }

    /// The cut cells of a subdomain (docs/parallel.md, [`crate::decomp`]): rows
    /// `first .. first + rows` of `global` along its last axis, copied cell by cell, so that
    /// every aperture, volume and group is the global one to the bit. The last axis must not
    /// wrap unless the slab is the whole grid (a group across the wrap would list its members
    /// in another order). A group that reaches past the slab keeps the members inside; a cell
    /// merged into a master outside it becomes a cell of its own. Both happen only in the
    /// outermost rows, which a subdomain's halo makes wide enough that no owned cell sees them.
    /// The low aperture of the first row is the high aperture of the global row below it.
    pub fn load_slab<const M: usize>(
        &mut self,
        global: &CutCells<R, D, M>,
        first: usize,
        rows: usize,
    ) -> Result<(), GeometryError> {
        let last = D - 1;
        let grid = global.grid.slab(first as i64, rows);
        let n = grid.len();
        if n > N {
            return Err(GeometryError::Capacity {
                cells: n,
                capacity: N,
            });
        }
        let whole = first == 0 && rows == global.grid.cells()[last];
        if first + rows > global.grid.cells()[last] || (global.periodic[last] && !whole) {
            return Err(GeometryError::Dimension);
        }
        let plane = n / rows.max(1);
        let off = first * plane;
        self.grid = grid;
        self.periodic = global.periodic;
        self.small = global.small;
        self.stats = global.stats;
        for i in 0..n {
            let g = off + i;
            self.vol[i] = global.vol[g];
            for a in 0..D {
                self.ap[a][i] = global.ap[a][g];
                self.ap_box_low[a][i] = global.ap_box_low[a][g];
                self.wall[a][i] = global.wall[a][g];
                self.wall_point[a][i] = global.wall_point[a][g];
                self.centroid[a][i] = global.centroid[a][g];
            }
            if i < plane && first > 0 {
                // the low face of the first row is the high face of the row below it
                self.ap_box_low[last][i] = global.ap[last][g - plane];
            }
            self.wall_area[i] = global.wall_area[g];
            self.wall_dist[i] = global.wall_dist[g];
            self.group_vol[i] = global.group_vol[g];
            let m = global.master[g] as usize;
            let mut merged = global.merged[g];
            if (off..off + n).contains(&m) {
                self.master[i] = (m - off) as u32;
            } else {
                self.master[i] = i as u32;
                self.group_vol[i] = global.vol[g];
            }
            // members beyond the slab's first or last row stay outside
            let row = i / plane;
            if whole && self.periodic[last] {
                // the whole wrapped axis: every member is inside
            } else if row == 0 {
                merged &= !(1 << (2 * last));
            }
            if row + 1 == rows && !(whole && self.periodic[last]) {
                merged &= !(1 << (2 * last + 1));
            }
            self.merged[i] = merged;
        }
        Ok(())
    }

    // ---------------------------------------------------------------- accessors

    /// The face neighbour of `i` across its low or high face along `a` (wrapping on periodic
    /// axes), `None` at a box face.
    pub fn neighbour(&self, i: usize, a: usize, high: bool) -> Option<usize> {
        let n = self.grid.cells()[a];
        let s = self.grid.stride(a);
        let j = self.grid.coord(i, a);
        if high {
            if j + 1 < n {
                Some(i + s)
            } else if self.periodic[a] {
                Some(i - (n - 1) * s)
            } else {
                None
            }
        } else if j > 0 {
            Some(i - s)
        } else if self.periodic[a] {
            Some(i + (n - 1) * s)
        } else {
            None
        }
    }

    /// The grid the geometry was built on.
    pub fn grid(&self) -> &Grid<R, D> {
        &self.grid
    }
    /// Periodic axes.
    pub fn periodic(&self) -> [bool; D] {
        self.periodic
    }
    /// The merging threshold.
    pub fn small(&self) -> R {
        self.small
    }
    /// What the last build found.
    pub fn stats(&self) -> GeometryStats<R> {
        self.stats
    }
    /// Number of cells.
    pub fn len(&self) -> usize {
        self.grid.len()
    }
    /// Never empty.
    pub fn is_empty(&self) -> bool {
        false
    }
    /// Area (m^(D-1)) of a full face normal to axis `a`.
    #[inline]
    pub fn face_area(&self, a: usize) -> R {
        let h = self.grid.spacing();
        let mut s = R::ONE;
        for (b, hb) in h.iter().enumerate() {
            if b != a {
                s *= *hb;
            }
        }
        s
    }
    /// Open volume fraction of cell `i`, in [0, 1].
    #[inline]
    pub fn volume(&self, i: usize) -> R {
        self.vol[i]
    }
    /// All volume fractions (active cells).
    #[inline]
    pub fn volumes(&self) -> &[R] {
        &self.vol[..self.grid.len()]
    }
    /// Open fraction of the high face of cell `i` along axis `a` (to `i + stride(a)`; the box
    /// face or the wrap face at the last cell of a line).
    #[inline]
    pub fn aperture(&self, a: usize, i: usize) -> R {
        self.ap[a][i]
    }
    /// All high-face apertures along axis `a` (active cells).
    #[inline]
    pub fn apertures(&self, a: usize) -> &[R] {
        &self.ap[a][..self.grid.len()]
    }
    /// Open fraction of the low face of cell `i` along axis `a`: the high face of the cell
    /// below (the same stored value: equal to the bit), the wrap face on periodic axes, or
    /// the low box face.
    #[inline]
    pub fn aperture_low(&self, a: usize, i: usize) -> R {
        let s = self.grid.stride(a);
        let j = self.grid.coord(i, a);
        if j > 0 {
            self.ap[a][i - s]
        } else if self.periodic[a] {
            self.ap[a][i + (self.grid.cells()[a] - 1) * s]
        } else {
            self.ap_box_low[a][i]
        }
    }
    /// `W_a = (aperture_low(a, i) - aperture(a, i)) * face_area(a)`, bit for bit: the wall
    /// fragment's area times its normal (m^(D-1)).
    #[inline]
    pub fn wall_vector(&self, i: usize) -> [R; D] {
        let mut w = [R::ZERO; D];
        for (a, wa) in w.iter_mut().enumerate() {
            *wa = self.wall[a][i];
        }
        w
    }
    /// Area of the wall fragment in cell `i` (m^(D-1)), 0 if none.
    #[inline]
    pub fn wall_area(&self, i: usize) -> R {
        self.wall_area[i]
    }
    /// Unit normal of the wall fragment, from the open region into the solid (zero if none).
    #[inline]
    pub fn wall_normal(&self, i: usize) -> [R; D] {
        let area = self.wall_area[i];
        let mut n = [R::ZERO; D];
        if area > R::ZERO {
            for (a, na) in n.iter_mut().enumerate() {
                *na = self.wall[a][i] / area;
            }
        }
        n
    }
    /// Distance from the open centroid to the wall plane, floored at
    /// [`WALL_DISTANCE_FLOOR`] `min h` (0 without a wall).
    #[inline]
    pub fn wall_distance(&self, i: usize) -> R {
        self.wall_dist[i]
    }
    /// A point on the wall fragment (the mean of its edge crossings; the cell centre if none).
    pub fn wall_point(&self, i: usize) -> [R; D] {
        let mut p = [R::ZERO; D];
        for (a, pa) in p.iter_mut().enumerate() {
            *pa = self.wall_point[a][i];
        }
        p
    }
    /// The open centroid: exact for the 2D polygon through the crossings, the mean of the open
    /// vertices in 3D (and for degenerate 2D slivers); the cell centre of a full cell.
    pub fn open_centroid(&self, i: usize) -> [R; D] {
        let mut p = [R::ZERO; D];
        for (a, pa) in p.iter_mut().enumerate() {
            *pa = self.centroid[a][i];
        }
        p
    }
    /// The cell whose state cell `i` shares (itself unless merged).
    #[inline]
    pub fn master(&self, i: usize) -> usize {
        self.master[i] as usize
    }
    /// Volume fraction of `i`'s group (its master plus the cells merged into it); for a
    /// merged cell the group volume of its master.
    #[inline]
    pub fn group_volume(&self, i: usize) -> R {
        self.group_vol[i]
    }
    /// All group volume fractions (active cells).
    #[inline]
    pub fn group_volumes(&self) -> &[R] {
        &self.group_vol[..self.grid.len()]
    }
    /// Master `i` and the cells merged into it, in increasing index (just `i` if none).
    pub fn group(&self, i: usize) -> ([usize; 7], usize) {
        self.group_members(i, self.merged[i])
    }
    /// Volume 0: nothing is stored or moves here.
    #[inline]
    pub fn is_solid(&self, i: usize) -> bool {
        self.vol[i] == R::ZERO
    }
    /// `0 < volume < 1`.
    #[inline]
    pub fn is_cut(&self, i: usize) -> bool {
        self.vol[i] > R::ZERO && self.vol[i] < R::ONE
    }
    /// True if other cells are merged into cell `i` (it is the master of a group of two or
    /// more cells).
    #[inline]
    pub fn has_merged(&self, i: usize) -> bool {
        self.merged[i] != 0
    }
    /// True if cell `i` is merged into another cell.
    #[inline]
    pub fn is_merged(&self, i: usize) -> bool {
        self.master[i] as usize != i
    }

    // ---------------------------------------------------------------- updates

    /// Applies an explicit conservative update with merging. `dq[i]` is the increment of cell
    /// `i`'s CONTENT in full-cell units, `d(V q)` (the sum of its aperture-weighted face
    /// fluxes times `dt/h`). Every master gets `q += (sum of dq over its group, in cell-index
    /// order) / group_volume`, then every merged cell copies its master; solid cells are
    /// untouched. A full cell alone (`V = 1`) gets exactly `q + dq`.
    pub fn apply_increment(&self, q: &mut [R], dq: &[R]) {
        let n = self.grid.len();
        for i in 0..n {
            let v = self.vol[i];
            if v == R::ZERO || self.master[i] as usize != i {
                continue;
            }
            let total = self.group_sum(i, dq);
            q[i] += total / self.group_vol[i];
        }
        self.copy_from_masters(q);
    }

    /// Sets every merged cell to its master's value.
    pub fn copy_from_masters(&self, q: &mut [R]) {
        for i in 0..self.grid.len() {
            let m = self.master[i] as usize;
            if m != i {
                q[i] = q[m];
            }
        }
    }

    /// Replaces the state of every group by its volume-weighted mean `sum V_j q_j / V_group`
    /// (content kept to round-off); call once on an initial state so that merged cells agree
    /// with their masters. Groups that are already uniform are left alone, so calling it
    /// again changes no bit; the rounded mean is monotone, so `phi <= c` per cell stays
    /// `phi <= c` per group.
    pub fn average_groups(&self, q: &mut [R]) {
        let n = self.grid.len();
        for i in 0..n {
            let mask = self.merged[i];
            if mask == 0 || self.master[i] as usize != i {
                continue;
            }
            let (idx, len) = self.group_members(i, mask);
            // already uniform: leave it (so that repeated calls change no bit)
            if idx[..len].iter().all(|&k| q[k] == q[i]) {
                continue;
            }
            let mut content = R::ZERO;
            for &k in &idx[..len] {
                content += self.vol[k] * q[k];
            }
            q[i] = content / self.group_vol[i];
        }
        self.copy_from_masters(q);
    }
}

/// Open fractions below this are round-off, not geometry: a wall that lies on a grid line
/// (a hopper's orifice channel on a grid whose spacing divides its width) leaves the cell on
/// its solid side open by about one ulp of its coordinate in cell units, `eps |x| / h` (4 to
/// 27 `f64` ulps, `|x| / h` = 21 and 37, on the 58 x 200 hopper). Such a cell holds no grains
/// worth a cell, yet kept open and merged it let the flow run away there (the 58 x 200 hopper
/// failed at t = 0.277 s with T -> 5e19 in such a cell). The bound is 4 ulps of the largest
/// coordinate of the box in cell units: 3.6e-13 of a cell on a 400-cell `f64` axis, 3e-5 on a
/// 64-cell `f32` one (a drum's smallest true cut there is 1e-4).
pub fn sliver_fraction<R: Real, const D: usize>(grid: &Grid<R, D>) -> R {
    let (o, h, cells) = (grid.origin(), grid.spacing(), grid.cells());
    let mut span = R::ONE;
    for a in 0..D {
        let far = o[a]
            .abs()
            .max((o[a] + R::from_usize(cells[a]) * h[a]).abs());
        span = span.max(far / h[a]);
    }
    R::from_usize(4) * R::EPSILON * span
}
