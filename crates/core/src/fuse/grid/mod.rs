//! The belief: a world-aligned 3D grid in `odom` of per-cell evidence that part of the object
//! occupies the cell, and the paper's Bayes update of it from one frame. Stored in blocks of
//! 8 x 8 x 8 cells ([`blocks`]): a dense grid stores every block, a sparse one only the blocks
//! a view or the motion blur has reached, so a building-sized volume costs what its views
//! touch. Both are this one type, updated by the same code, and hold the same values.
//!
//! Invariants: cell (i, j, k) has its min corner at `origin_m + voxel_size_m * (i, j, k)` and
//! flat index `(i * ny + j) * nz + k` (C order, as the `.npy` export and the report's object
//! cells); a cell holds its evidence, log-odds above the prior's (so a cell no frame has
//! reached holds exactly 0, stored or not), and its log-odds are `prior_log_odds() +
//! evidence` in f32; an update touches exactly the cells whose centres lie in front of the
//! camera within the range limit and project into a tile of the image, each cell
//! independently, so the result is bit-identical for any number of threads and whichever
//! blocks are stored. No I/O.

mod access;
pub mod blocks;
pub mod convolve;
mod project;
#[cfg(test)]
mod reference;
#[cfg(test)]
mod tests;
mod update;

use rayon::prelude::*;
use thiserror::Error;

use crate::types::geometry::{Camera, Iso3};
pub use access::for_each_cell;
pub use blocks::BLOCK;
use blocks::{BLOCK_CELLS, Layout, block_dims, cell_offset};
use project::Projector;

/// Largest grid objloc allocates, all buffers counted: 4 GiB keeps a 24 GiB machine safe with
/// room for the rest. A dense grid beyond it is refused before anything is allocated; a
/// sparse one stops the replay with [`GridError::Allocation`] when its stored blocks would
/// exceed it.
pub const MAX_GRID_BYTES: u64 = 4 << 30;

/// Largest `.npy` the grid is exported to (`fuse --grid`), bytes: as much as the grid itself
/// may take. The export is written a slab at a time, so this bounds the file, not memory.
pub const MAX_EXPORT_BYTES: u64 = MAX_GRID_BYTES;

/// Bytes a cell of a dense grid costs with the log-odds blur: evidence f32, views u16 and the
/// blur's f32 output.
pub const BYTES_PER_CELL: u64 = 4 + 2 + 4;

/// Bytes a stored cell of a sparse grid costs with the log-odds blur, as measured: the peak
/// resident memory per stored cell of the 200-stop tour in 100 x 100 x 4 m at 2 cm was 18.3 to
/// 18.7 bytes (26 to 150 million cells stored; docs/scale.md). Besides the dense grid's
/// buffers, the blur's output also holds the blocks it tries around the stored ones (up to
/// half as many again) and the views are copied when a blur re-orders the blocks.
pub const SPARSE_BYTES_PER_CELL: u64 = 19;

/// Bytes a blur in f64 (probability, observation) adds a cell: its f64 input and output (the
/// output over the blocks tried, for a sparse grid).
pub const F64_BLUR_BYTES_PER_CELL: u64 = 8 + 8;

/// `--grid-storage auto` stores a grid densely up to this many cells (blocks rounded up; 320
/// MiB at [`BYTES_PER_CELL`]) and sparsely beyond: every room-sized grid is dense.
pub const AUTO_DENSE_MAX_CELLS: usize = 1 << 25;

/// The smallest prior probability (and 1 less the largest) a grid takes: a prior nearer 0 or
/// 1 underflows in the probability blur, where the prior's probability is subtracted from
/// every cell's (1e-9: about 21 in log-odds, far beyond any classifier's base rate).
pub const MIN_PRIOR: f64 = 1e-9;

/// Evidence (log-odds) of a magnitude below this is 0 after a blur: 2^-20, a likelihood ratio
/// within 1e-6 of 1 and two f32 steps of a log-odds near the prior's (magnitude 4 to 8, where
/// a step is 4.8e-7), so flushing moves a cell's log-odds by at most that. Without it the
/// blur's tails would reach one more kernel width every blur, in values that mean nothing.
pub const FLUSH_EVIDENCE: f32 = 1.0 / (1u32 << 20) as f32;

/// Why a grid cannot be built from its options, or grow; checked before allocating.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum GridError {
    /// The bounds are not finite, or min is not below max on every axis.
    #[error("bounds min {min:?} must be below max {max:?} on every axis, all finite")]
    Bounds {
        /// Requested min corner in `odom`, metres.
        min: [f64; 3],
        /// Requested max corner in `odom`, metres.
        max: [f64; 3],
    },
    /// The voxel size is not positive and finite.
    #[error("voxel size {voxel_size_m} m must be positive and finite")]
    Voxel {
        /// Requested cell edge length, metres.
        voxel_size_m: f64,
    },
    /// A dense grid's buffers would need more than [`MAX_GRID_BYTES`].
    #[error(
        "a dense grid of {nx} x {ny} x {nz} cells would need {needed_mib} MiB, over the limit of {limit_mib} MiB; use --grid-storage sparse, a larger --voxel or smaller --bounds"
    )]
    TooLarge {
        /// Cells along x the bounds need at this voxel size.
        nx: u64,
        /// Cells along y.
        ny: u64,
        /// Cells along z.
        nz: u64,
        /// Memory the grid would take, MiB, rounded up.
        needed_mib: u64,
        /// [`MAX_GRID_BYTES`] in MiB.
        limit_mib: u64,
    },
    /// Even the table of blocks (4 bytes a block) would exceed [`MAX_GRID_BYTES`].
    #[error(
        "a grid of {nx} x {ny} x {nz} cells needs {needed_mib} MiB for its table of blocks alone, over the limit of {limit_mib} MiB; use a larger --voxel or smaller --bounds"
    )]
    BlockTable {
        /// Cells along x.
        nx: u64,
        /// Cells along y.
        ny: u64,
        /// Cells along z.
        nz: u64,
        /// Memory the table would take, MiB, rounded up.
        needed_mib: u64,
        /// [`MAX_GRID_BYTES`] in MiB.
        limit_mib: u64,
    },
    /// One frame's plan of its update (a span of cells per column it can reach) would exceed
    /// the grid's limit: a frame without a range limit on a building-sized grid.
    #[error(
        "one frame can reach {columns} columns of cells, {needed_mib} MiB to plan its update, over the limit of {limit_mib} MiB; keep a range limit (--max-footprint), or use a larger --voxel or smaller --bounds"
    )]
    Columns {
        /// Columns of cells the frame's box reaches.
        columns: u64,
        /// Bytes of the plan, in MiB.
        needed_mib: u64,
        /// [`MAX_GRID_BYTES`] in MiB.
        limit_mib: u64,
    },
    /// A sparse grid's stored blocks would exceed its limit.
    #[error(
        "the sparse grid of {nx} x {ny} x {nz} cells would need {needed_mib} MiB to store the {cells} cells its views and blur have reached, over the limit of {limit_mib} MiB; use a larger --voxel, smaller --bounds or a smaller --max-footprint"
    )]
    Allocation {
        /// Cells along x.
        nx: u64,
        /// Cells along y.
        ny: u64,
        /// Cells along z.
        nz: u64,
        /// Cells the stored blocks would hold.
        cells: u64,
        /// Memory they and the table would take, MiB, rounded up.
        needed_mib: u64,
        /// The limit in MiB.
        limit_mib: u64,
    },
    /// The `.npy` export of the grid's stored region would exceed the export limit.
    #[error(
        "the grid's stored region is {a} x {b} x {c} cells ({first_cell:?} on, of the {nx} x {ny} x {nz} grid), {needed_mib} MiB as float32, over the export limit of {limit_mib} MiB; fuse with smaller --bounds or a larger --voxel to export it",
        a = .dims[0], b = .dims[1], c = .dims[2]
    )]
    Export {
        /// The region's first cell (i, j, k).
        first_cell: [usize; 3],
        /// Its cells along x, y, z.
        dims: [usize; 3],
        /// Cells of the grid along x.
        nx: u64,
        /// Cells along y.
        ny: u64,
        /// Cells along z.
        nz: u64,
        /// Bytes of the export, MiB, rounded up.
        needed_mib: u64,
        /// The limit in MiB.
        limit_mib: u64,
    },
    /// The prior probability is outside [`MIN_PRIOR`, 1 - `MIN_PRIOR`].
    #[error("prior {prior} must lie within [1e-9, 1 - 1e-9]")]
    Prior {
        /// The requested prior probability.
        prior: f64,
    },
    /// The probability clamp does not satisfy 0 < lo < hi < 1.
    #[error("clamp bounds {lo} and {hi} must satisfy 0 < lo < hi < 1")]
    Clamp {
        /// Requested lower bound, probability.
        lo: f64,
        /// Requested upper bound, probability.
        hi: f64,
    },
}

/// Where the grid is and how fine.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GridSpec {
    /// Min corner of cell (0, 0, 0) in `odom`, metres.
    pub origin_m: [f64; 3],
    /// Edge length of a (cubic) cell, metres; positive and finite.
    pub voxel_size_m: f64,
    /// Cells along x, y, z (nx, ny, nz); each at least 1 from [`GridSpec::from_bounds`].
    pub dims: [usize; 3],
}

fn mib(bytes: f64) -> u64 {
    (bytes / f64::from(1u32 << 20)).ceil() as u64
}

/// [`GridError::Voxel`] unless the voxel size is positive and finite.
pub fn check_voxel(voxel_size_m: f64) -> Result<(), GridError> {
    if voxel_size_m.is_finite() && voxel_size_m > 0.0 {
        Ok(())
    } else {
        Err(GridError::Voxel { voxel_size_m })
    }
}

/// [`GridError::Bounds`] unless `min` is below `max` on every axis, all finite.
pub fn check_bounds(min: [f64; 3], max: [f64; 3]) -> Result<(), GridError> {
    if (0..3).all(|a| min[a].is_finite() && max[a].is_finite() && min[a] < max[a]) {
        Ok(())
    } else {
        Err(GridError::Bounds { min, max })
    }
}

/// [`GridError::Prior`] unless [`MIN_PRIOR`] <= `prior` <= 1 - [`MIN_PRIOR`].
pub fn check_prior(prior: f64) -> Result<(), GridError> {
    if (MIN_PRIOR..=1.0 - MIN_PRIOR).contains(&prior) {
        Ok(())
    } else {
        Err(GridError::Prior { prior })
    }
}

impl GridSpec {
    /// The smallest grid of `voxel_size_m` cells covering [min, max]; refused when even its
    /// table of blocks would need more than [`MAX_GRID_BYTES`] (whether its cells fit is for
    /// [`Grid::with_storage`] to say).
    pub fn from_bounds(min: [f64; 3], max: [f64; 3], voxel_size_m: f64) -> Result<Self, GridError> {
        check_voxel(voxel_size_m)?;
        check_bounds(min, max)?;
        let n = |a: usize| ((max[a] - min[a]) / voxel_size_m - 1e-9).ceil().max(1.0);
        let (nx, ny, nz) = (n(0), n(1), n(2));
        let blocks: f64 = [nx, ny, nz]
            .iter()
            .map(|d| (d / BLOCK as f64).ceil())
            .product();
        let table = blocks * 4.0;
        if table > MAX_GRID_BYTES as f64 {
            return Err(GridError::BlockTable {
                nx: nx as u64,
                ny: ny as u64,
                nz: nz as u64,
                needed_mib: mib(table),
                limit_mib: MAX_GRID_BYTES >> 20,
            });
        }
        Ok(Self {
            origin_m: min,
            voxel_size_m,
            dims: [nx as usize, ny as usize, nz as usize],
        })
    }

    /// Number of cells, nx * ny * nz.
    pub fn cells(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    /// Cells in whole blocks: the cells rounded up to blocks on each axis.
    pub fn padded_cells(&self) -> usize {
        block_dims(self.dims).iter().product::<usize>() * BLOCK_CELLS
    }

    /// Flat index of cell (i, j, k): `(i * ny + j) * nz + k` (C order).
    #[inline]
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        (i * self.dims[1] + j) * self.dims[2] + k
    }

    /// (i, j, k) of a flat index.
    #[inline]
    pub fn ijk(&self, idx: usize) -> [usize; 3] {
        let nz = self.dims[2];
        let ny = self.dims[1];
        [idx / (ny * nz), (idx / nz) % ny, idx % nz]
    }

    /// Centre of cell (i, j, k) in `odom`, metres.
    #[inline]
    pub fn center(&self, i: usize, j: usize, k: usize) -> [f64; 3] {
        let v = self.voxel_size_m;
        [
            self.origin_m[0] + (i as f64 + 0.5) * v,
            self.origin_m[1] + (j as f64 + 0.5) * v,
            self.origin_m[2] + (k as f64 + 0.5) * v,
        ]
    }

    /// Max corner of the grid, metres.
    pub fn max_m(&self) -> [f64; 3] {
        let v = self.voxel_size_m;
        [
            self.origin_m[0] + self.dims[0] as f64 * v,
            self.origin_m[1] + self.dims[1] as f64 * v,
            self.origin_m[2] + self.dims[2] as f64 * v,
        ]
    }
}

/// Log-odds ln(p / (1 - p)) of a probability p; infinite at 0 and 1.
pub fn logit(p: f64) -> f64 {
    (p / (1.0 - p)).ln()
}

/// Probability 1 / (1 + e^-l) of log-odds `l`, in [0, 1]; the inverse of [`logit`].
pub fn sigmoid(l: f64) -> f64 {
    // Above 38, exp(-l) < 2^-54 and 1 + exp(-l) rounds to 1: the formula gives exactly 1.0,
    // without the exp (cells of an object that fills a capture's grid sit far above it, and
    // an object's summary takes this of each of its cells after every frame).
    if l >= SIGMOID_ONE_FROM {
        return 1.0;
    }
    1.0 / (1.0 + (-l).exp())
}

/// Log-odds from which [`sigmoid`]'s formula rounds to exactly 1.0 in f64 (with margin).
const SIGMOID_ONE_FROM: f64 = 40.0;

/// Depth (metres along the optical axis) beyond which a tile's footprint, `depth * tile_px /
/// f` with the smaller focal length, exceeds `footprint_voxels` cells: where a frame's update
/// stops. Infinite without a limit.
pub fn max_depth_m(
    camera: &Camera,
    tile_px: u32,
    voxel_size_m: f64,
    footprint_voxels: Option<f64>,
) -> f64 {
    match footprint_voxels {
        Some(n) => n * voxel_size_m * camera.fx.min(camera.fy) / f64::from(tile_px.max(1)),
        None => f64::INFINITY,
    }
}

/// A frame's evidence per tile, already in the odds-ratio form of the paper:
/// `delta = logit(p) - logit(prior)`, so that `log-odds' = log-odds + delta`.
#[derive(Debug, Clone, PartialEq)]
pub struct TileEvidence {
    /// Whole tiles down the image.
    pub rows: usize,
    /// Whole tiles across the image.
    pub cols: usize,
    /// Side of a square tile, pixels: tile (r, c) covers pixels u in [c, c + 1) * tile_px and
    /// v in [r, r + 1) * tile_px.
    pub tile_px: u32,
    /// Row-major, `delta[r * cols + c]`.
    pub delta: Vec<f32>,
}

impl TileEvidence {
    /// From tile probabilities (row-major) against `prior`. Probabilities are expected
    /// strictly inside (0, 1) (the tree's leaves are smoothed); one at 0 or 1 would be an
    /// infinite update, so it is held at the nearest representable f32 odds instead.
    pub fn from_probabilities(
        rows: usize,
        cols: usize,
        tile_px: u32,
        p: &[f32],
        prior: f64,
    ) -> Self {
        let lp = logit(prior);
        let delta = p
            .iter()
            .map(|&pi| {
                let pi = f64::from(pi).clamp(f64::from(f32::MIN_POSITIVE), 1.0 - f64::EPSILON);
                (logit(pi) - lp) as f32
            })
            .collect();
        Self {
            rows,
            cols,
            tile_px,
            delta,
        }
    }
}

/// Which blocks a grid stores.
#[derive(
    Debug,
    Clone,
    Copy,
    Default,
    PartialEq,
    Eq,
    serde::Serialize,
    serde::Deserialize,
    clap::ValueEnum,
)]
#[serde(rename_all = "kebab-case")]
pub enum GridStorage {
    /// Every block, allocated up front (refused beyond the limit).
    Dense,
    /// The blocks views and the blur reach, allocated as they do.
    Sparse,
    /// Dense up to [`AUTO_DENSE_MAX_CELLS`], sparse beyond.
    #[default]
    Auto,
}

impl GridStorage {
    /// Dense or sparse for `spec` ([`GridStorage::Auto`] decided).
    pub fn resolve(self, spec: &GridSpec) -> Self {
        match self {
            Self::Auto if spec.padded_cells() <= AUTO_DENSE_MAX_CELLS => Self::Dense,
            Self::Auto => Self::Sparse,
            other => other,
        }
    }
}

/// How much a grid may allocate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Budget {
    /// Largest allocation, bytes, the table of blocks included.
    pub max_bytes: u64,
    /// Whether the blur works in f64 (probability, observation), which costs
    /// [`F64_BLUR_BYTES_PER_CELL`] more a cell (times 1.5 when sparse).
    pub f64_blur: bool,
}

impl Default for Budget {
    fn default() -> Self {
        Self {
            max_bytes: MAX_GRID_BYTES,
            f64_blur: false,
        }
    }
}

impl Budget {
    /// Bytes a stored cell costs with `storage` (dense or sparse).
    pub fn bytes_per_cell(&self, storage: GridStorage) -> f64 {
        let sparse = storage == GridStorage::Sparse;
        let base = if sparse {
            SPARSE_BYTES_PER_CELL
        } else {
            BYTES_PER_CELL
        } as f64;
        let f64_blur = if self.f64_blur {
            F64_BLUR_BYTES_PER_CELL as f64 * if sparse { 1.5 } else { 1.0 }
        } else {
            0.0
        };
        base + f64_blur
    }
}

/// The box of cells `first_cell .. first_cell + dims` (what `fuse --grid` exports).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Region {
    /// Its min cell (i, j, k).
    pub first_cell: [usize; 3],
    /// Cells along x, y, z; all 0 for an empty region.
    pub dims: [usize; 3],
}

/// A stored block as consumers read it.
#[derive(Debug, Clone, Copy)]
pub struct BlockCells<'a> {
    /// Its slot (1 and up; see [`Grid::slot_at`]).
    pub slot: usize,
    /// Cell (i, j, k) of its cell (0, 0, 0).
    pub first_cell: [usize; 3],
    /// Cells of the block inside the grid along x, y, z (8, or fewer at the grid's far faces;
    /// the others are 0).
    pub extent: [usize; 3],
    /// Evidence of its 512 cells, at `(a * 8 + b) * 8 + c` for cell `first_cell + (a, b, c)`.
    pub evidence: &'a [f32],
    /// Views of its cells, in the same order.
    pub views: &'a [u16],
}

/// The belief grid.
#[derive(Debug, Clone)]
pub struct Grid {
    /// Where the grid lies in `odom` and how its cells are laid out.
    pub spec: GridSpec,
    /// Prior probability of every cell, in (0, 1); each cell starts at its log-odds.
    pub prior: f64,
    /// Optional clamp of the log-odds after each update: (min, max).
    pub clamp: Option<(f32, f32)>,
    storage: GridStorage,
    budget: Budget,
    pub(crate) layout: Layout,
    /// Evidence of each stored cell, block after block by slot.
    pub(crate) evidence: Vec<f32>,
    /// How many frames' pyramids contained each stored cell's centre (saturating).
    pub(crate) views: Vec<u16>,
}
