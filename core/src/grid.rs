//! Equidistant Cartesian grids of `D` dimensions with run-time extents.
//!
//! Storage capacity is a compile-time constant of the solver (`N` cells); the extents chosen at
//! run time must fit in it. Cells are numbered x fastest: `i = ix + nx (iy + ny iz)`, so a line
//! along x is contiguous and lines along y and z are contiguous blocks of faces: the face loops
//! of the step are straight slices the compiler vectorises.

use crate::real::Real;

/// The three axes by index; axis 0 is x.
pub const AXIS_NAMES: [&str; 3] = ["x", "y", "z"];

/// A box `[origin, origin + extent]` split into `cells[a]` equal cells along each axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grid<R: Real, const D: usize> {
    cells: [usize; D],
    origin: [R; D],
    spacing: [R; D],
}

/// Why a grid cannot be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GridError {
    /// An axis has no cells.
    EmptyAxis(usize),
    /// The box has zero or negative (or non-finite) length along an axis.
    BadExtent(usize),
    /// More cells than the compiled capacity.
    TooManyCells {
        /// cells asked for
        cells: usize,
        /// compiled capacity
        capacity: usize,
    },
}

impl<R: Real, const D: usize> Grid<R, D> {
    /// One unit cell per axis: a placeholder for statically initialised solvers.
    pub const fn unit() -> Self {
        Self {
            cells: [1; D],
            origin: [R::ZERO; D],
            spacing: [R::ONE; D],
        }
    }

    /// A grid of `cells` over the box `origin .. origin + extent`, checked against `capacity`.
    pub fn new(
        cells: [usize; D],
        origin: [R; D],
        extent: [R; D],
        capacity: usize,
    ) -> Result<Self, GridError> {
        let mut spacing = [R::ONE; D];
        let mut total: usize = 1;
        for a in 0..D {
            if cells[a] == 0 {
                return Err(GridError::EmptyAxis(a));
            }
            if !(extent[a] > R::ZERO) || !extent[a].is_finite() || !origin[a].is_finite() {
                return Err(GridError::BadExtent(a));
            }
            spacing[a] = extent[a] / R::from_usize(cells[a]);
            total = total.saturating_mul(cells[a]);
        }
        if total > capacity {
            return Err(GridError::TooManyCells {
                cells: total,
                capacity,
            });
        }
        Ok(Self {
            cells,
            origin,
            spacing,
        })
    }

    /// The slab of `rows` cells along the last axis whose first row is row `first` of this
    /// grid (negative or past the end for the halo rows of a subdomain, docs/parallel.md):
    /// the same spacing to the bit (a new [`Self::new`] would divide a new extent and could
    /// round it differently), the origin moved by `first` rows. `rows` must not be 0.
    pub fn slab(&self, first: i64, rows: usize) -> Self {
        let mut g = *self;
        g.cells[D - 1] = rows;
        g.origin[D - 1] += R::from_f64(first as f64) * self.spacing[D - 1];
        g
    }
    /// Cells along each axis.
    #[inline]
    pub fn cells(&self) -> [usize; D] {
        self.cells
    }
    /// Total number of cells.
    #[inline]
    pub fn len(&self) -> usize {
        self.cells.iter().product()
    }
    /// Always false: a grid has at least one cell.
    #[inline]
    pub fn is_empty(&self) -> bool {
        false
    }
    /// Cell width along each axis.
    #[inline]
    pub fn spacing(&self) -> [R; D] {
        self.spacing
    }
    /// Lower corner of the box.
    #[inline]
    pub fn origin(&self) -> [R; D] {
        self.origin
    }
    /// Cell volume |C| (length in 1D, area in 2D).
    #[inline]
    pub fn cell_volume(&self) -> R {
        let mut v = R::ONE;
        for h in self.spacing {
            v *= h;
        }
        v
    }
    /// Distance in the flat index between neighbours along `axis`.
    #[inline]
    pub fn stride(&self, axis: usize) -> usize {
        self.cells[..axis].iter().product()
    }
    /// Index of cell `i` along `axis`.
    #[inline]
    pub fn coord(&self, i: usize, axis: usize) -> usize {
        (i / self.stride(axis)) % self.cells[axis]
    }
    /// Integer coordinates of cell `i`.
    #[inline]
    pub fn coords(&self, i: usize) -> [usize; D] {
        let mut c = [0; D];
        for (a, ca) in c.iter_mut().enumerate() {
            *ca = self.coord(i, a);
        }
        c
    }
    /// Flat index of integer coordinates.
    #[inline]
    pub fn index(&self, coords: [usize; D]) -> usize {
        let mut i = 0;
        for a in (0..D).rev() {
            i = i * self.cells[a] + coords[a];
        }
        i
    }
    /// Centre of cell `i`.
    #[inline]
    pub fn center(&self, i: usize) -> [R; D] {
        let mut x = self.origin;
        for (a, xa) in x.iter_mut().enumerate() {
            *xa += (R::from_usize(self.coord(i, a)) + R::HALF) * self.spacing[a];
        }
        x
    }
    /// The flat index range structure of the interior faces along `axis`: `blocks` blocks,
    /// block `b` holding left cells `b * block_stride .. b * block_stride + block_len`, each
    /// with its right neighbour at `+ stride`.
    #[inline]
    pub fn face_blocks(&self, axis: usize) -> FaceBlocks {
        let stride = self.stride(axis);
        let n = self.cells[axis];
        let block_stride = stride * n;
        FaceBlocks {
            stride,
            block_len: stride * (n - 1),
            block_stride,
            blocks: self.len() / block_stride,
        }
    }
    /// Calls `f(left, right)` for every interior face along `axis`, block by block in
    /// [`Self::face_blocks`] order (the order of every face loop, so sums over faces keep
    /// their bits). For loops that are not hot; the hot kernels slice the blocks themselves.
    #[inline]
    pub fn for_each_interior_face(&self, axis: usize, mut f: impl FnMut(usize, usize)) {
        let fb = self.face_blocks(axis);
        for b in 0..fb.blocks {
            let l0 = b * fb.block_stride;
            for l in l0..l0 + fb.block_len {
                f(l, l + fb.stride);
            }
        }
    }

    /// Iterates over the cells of the boundary plane at the low (`high = false`) or high end of
    /// `axis`; calls `f(cell, opposite_cell)` where `opposite_cell` is the cell at the other end
    /// of the same grid line (the periodic neighbour).
    #[inline]
    pub fn for_each_boundary_cell(&self, axis: usize, high: bool, mut f: impl FnMut(usize, usize)) {
        let fb = self.face_blocks(axis);
        let span = fb.block_len; // distance from the first to the last cell of a line
        for b in 0..fb.blocks {
            let first = b * fb.block_stride;
            for j in first..first + fb.stride {
                if high {
                    f(j + span, j)
                } else {
                    f(j, j + span)
                }
            }
        }
    }
}

/// Interior face layout along one axis (see [`Grid::face_blocks`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FaceBlocks {
    /// Flat distance between a face's left and right cell.
    pub stride: usize,
    /// Number of contiguous left cells in a block.
    pub block_len: usize,
    /// Flat distance between the starts of consecutive blocks.
    pub block_stride: usize,
    /// Number of blocks.
    pub blocks: usize,
}
