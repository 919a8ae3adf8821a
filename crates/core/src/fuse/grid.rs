//! The belief: a dense, world-aligned 3D grid in `odom` of per-cell log-odds (f32) that part
//! of the object occupies the cell, and the paper's Bayes update of it from one frame.
//!
//! Invariants: cell (i, j, k) has its min corner at `origin_m + voxel_size_m * (i, j, k)` and
//! lives at flat index `(i * ny + j) * nz + k` (C order, as the `.npy` export); every cell
//! starts at the prior's log-odds; an update touches exactly the cells whose centres project
//! into a tile of the image in front of the camera, each cell independently, so the result
//! is bit-identical for any number of threads. No I/O.

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;
use thiserror::Error;

use crate::types::geometry::{Camera, Iso3};

/// Largest grid objloc allocates, all buffers counted: 4 GiB keeps a 24 GiB machine safe with
/// room for the rest; a request beyond it is refused before anything is allocated.
pub const MAX_GRID_BYTES: u64 = 4 << 30;

/// Bytes one cell costs: log-odds f32, views u16, a frame's evidence f32, and the blur's two
/// f64 scratch buffers.
pub const BYTES_PER_CELL: u64 = 4 + 2 + 4 + 8 + 8;

/// Why a grid cannot be built from its options; checked before anything is allocated.
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
    /// The grid's buffers would need more than [`MAX_GRID_BYTES`].
    #[error(
        "a grid of {nx} x {ny} x {nz} cells would need {needed_mib} MiB, over the limit of {limit_mib} MiB; use a larger --voxel or smaller --bounds"
    )]
    TooLarge {
        /// Cells along x the bounds need at this voxel size.
        nx: u64,
        /// Cells along y.
        ny: u64,
        /// Cells along z.
        nz: u64,
        /// Memory the grid would take ([`BYTES_PER_CELL`] per cell), MiB, rounded up.
        needed_mib: u64,
        /// [`MAX_GRID_BYTES`] in MiB.
        limit_mib: u64,
    },
    /// The prior probability is not strictly between 0 and 1.
    #[error("prior {prior} must lie strictly between 0 and 1")]
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

impl GridSpec {
    /// The smallest grid of `voxel_size_m` cells covering [min, max]; refused before
    /// allocating when it would need more than [`MAX_GRID_BYTES`].
    pub fn from_bounds(min: [f64; 3], max: [f64; 3], voxel_size_m: f64) -> Result<Self, GridError> {
        if !(voxel_size_m.is_finite() && voxel_size_m > 0.0) {
            return Err(GridError::Voxel { voxel_size_m });
        }
        if !(0..3).all(|a| min[a].is_finite() && max[a].is_finite() && min[a] < max[a]) {
            return Err(GridError::Bounds { min, max });
        }
        let n = |a: usize| ((max[a] - min[a]) / voxel_size_m - 1e-9).ceil().max(1.0);
        let (nx, ny, nz) = (n(0), n(1), n(2));
        let cells = nx * ny * nz;
        let needed = cells * BYTES_PER_CELL as f64;
        if needed > MAX_GRID_BYTES as f64 {
            return Err(GridError::TooLarge {
                nx: nx as u64,
                ny: ny as u64,
                nz: nz as u64,
                needed_mib: (needed / f64::from(1u32 << 20)).ceil() as u64,
                limit_mib: MAX_GRID_BYTES >> 20,
            });
        }
        Ok(Self {
            origin_m: min,
            voxel_size_m,
            dims: [nx as usize, ny as usize, nz as usize],
        })
    }

    /// Number of cells, nx * ny * nz (the length of every per-cell buffer).
    pub fn cells(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
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
    1.0 / (1.0 + (-l).exp())
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

/// The belief grid.
#[derive(Debug, Clone)]
pub struct Grid {
    /// Where the grid lies in `odom` and how its cells are laid out.
    pub spec: GridSpec,
    /// Prior probability of every cell, in (0, 1); each cell starts at its log-odds.
    pub prior: f64,
    /// Log-odds of each cell.
    pub log_odds: Vec<f32>,
    /// How many frames' pyramids contained each cell's centre (saturating).
    pub views: Vec<u16>,
    /// Optional clamp of the log-odds after each update: (min, max).
    pub clamp: Option<(f32, f32)>,
}

impl Grid {
    /// A grid at the prior everywhere, no views, no clamp; [`GridError::Prior`] unless
    /// 0 < `prior` < 1.
    pub fn new(spec: GridSpec, prior: f64) -> Result<Self, GridError> {
        if !(prior > 0.0 && prior < 1.0) {
            return Err(GridError::Prior { prior });
        }
        let n = spec.cells();
        Ok(Self {
            spec,
            prior,
            log_odds: vec![logit(prior) as f32; n],
            views: vec![0; n],
            clamp: None,
        })
    }

    /// The prior as log-odds, f32 like the cells: the value of a cell no frame has updated.
    pub fn prior_log_odds(&self) -> f32 {
        logit(self.prior) as f32
    }

    /// Posterior probability of each cell, f32, in index order.
    pub fn probabilities(&self) -> Vec<f32> {
        self.log_odds
            .par_iter()
            .map(|&l| sigmoid(f64::from(l)) as f32)
            .collect()
    }

    /// The paper's update for one frame: every cell whose centre lies in front of the camera
    /// and projects into tile (r, c) gets `log-odds += delta[r, c]`.
    ///
    /// Centre projection, not any-overlap: a cell belongs to exactly one tile's pyramid, so
    /// each frame counts once per cell, as the Markov assumption of the update requires. With
    /// any-overlap a cell straddling a tile edge would take the evidence of two or more tiles
    /// of the same image, counting one observation several times, and cells near the camera
    /// (larger than a tile's footprint) would collect the evidence of many tiles.
    ///
    /// Returns the number of cells updated.
    pub fn integrate(
        &mut self,
        camera_from_odom: &Iso3,
        camera: &Camera,
        ev: &TileEvidence,
    ) -> usize {
        let clamp = self.clamp;
        project(
            &self.spec,
            &mut self.log_odds,
            &mut self.views,
            camera_from_odom,
            camera,
            ev,
            |l, d| {
                let mut v = *l + d;
                if let Some((a, b)) = clamp {
                    v = v.clamp(a, b);
                }
                *l = v;
            },
        )
    }

    /// One frame's evidence without applying it: `out[cell]` = the tile's delta for cells in
    /// the frame's pyramids, 0 elsewhere. Counts the view in `views` like [`Grid::integrate`].
    pub fn frame_evidence(
        &mut self,
        camera_from_odom: &Iso3,
        camera: &Camera,
        ev: &TileEvidence,
        out: &mut Vec<f32>,
    ) -> usize {
        out.clear();
        out.resize(self.log_odds.len(), 0.0);
        project(
            &self.spec,
            out,
            &mut self.views,
            camera_from_odom,
            camera,
            ev,
            |o, d| *o = d,
        )
    }

    /// Adds per-cell evidence (log likelihood ratios), then applies the clamp if any.
    pub fn add_evidence(&mut self, evidence: &[f32]) {
        let clamp = self.clamp;
        self.log_odds
            .par_iter_mut()
            .zip(evidence.par_iter())
            .for_each(|(l, &e)| {
                if e != 0.0 {
                    let mut v = *l + e;
                    if let Some((a, b)) = clamp {
                        v = v.clamp(a, b);
                    }
                    *l = v;
                }
            });
    }

    /// SHA-256 of the log-odds bytes (little-endian f32, index order), hex.
    pub fn sha256_hex(&self) -> String {
        use sha2::{Digest, Sha256};
        let mut h = Sha256::new();
        for chunk in self.log_odds.chunks(1 << 16) {
            let bytes: Vec<u8> = chunk.iter().flat_map(|v| v.to_le_bytes()).collect();
            h.update(&bytes);
        }
        crate::types::digest::hex(&h.finalize())
    }
}

/// Calls `apply(values[cell], delta)` for every cell whose centre lies in front of the camera
/// and projects into a tile, and counts the view; returns the number of such cells.
fn project(
    spec: &GridSpec,
    values: &mut [f32],
    views: &mut [u16],
    camera_from_odom: &Iso3,
    camera: &Camera,
    ev: &TileEvidence,
    apply: impl Fn(&mut f32, f32) + Sync,
) -> usize {
    let spec = *spec;
    let [_, ny, nz] = spec.dims;
    let slab = ny * nz;
    if slab == 0 {
        return 0;
    }
    let rot = camera_from_odom.rotation.to_rotation_matrix();
    let step_k: Vector3<f64> = rot * Vector3::new(0.0, 0.0, spec.voxel_size_m);
    let tile = f64::from(ev.tile_px);
    let u_max = ev.cols as f64 * tile;
    let v_max = ev.rows as f64 * tile;
    let cam = *camera;
    let delta = &ev.delta;
    let cols = ev.cols;
    // The frustum's five planes, each as a linear form n . p >= 0 in camera coordinates
    // (p.z > 0 makes `u >= 0` the same as `fx p.x + cx p.z >= 0`, and so on).
    let planes = [
        Vector3::new(0.0, 0.0, 1.0),
        Vector3::new(cam.fx, 0.0, cam.cx),
        Vector3::new(-cam.fx, 0.0, u_max - cam.cx),
        Vector3::new(0.0, cam.fy, cam.cy),
        Vector3::new(0.0, -cam.fy, v_max - cam.cy),
    ];
    values
        .par_chunks_mut(slab)
        .zip(views.par_chunks_mut(slab))
        .enumerate()
        .map(|(i, (lo, views))| {
            let mut updated = 0usize;
            for j in 0..ny {
                let c0 = spec.center(i, j, 0);
                let p0 = camera_from_odom * Point3::new(c0[0], c0[1], c0[2]);
                let row_lo = &mut lo[j * nz..(j + 1) * nz];
                let row_views = &mut views[j * nz..(j + 1) * nz];
                let Some((k_lo, k_hi)) = column_span(&planes, &p0.coords, &step_k, nz) else {
                    continue;
                };
                for k in k_lo..k_hi {
                    let p = p0 + step_k * k as f64;
                    if p.z <= 1e-9 {
                        continue;
                    }
                    // One division per cell, not two: this loop runs for every cell of the
                    // grid in view, hundreds of thousands per frame.
                    let inv_z = 1.0 / p.z;
                    let u = cam.fx * p.x * inv_z + cam.cx;
                    let v = cam.fy * p.y * inv_z + cam.cy;
                    // Negated comparisons also reject NaN.
                    if !(u >= 0.0 && u < u_max && v >= 0.0 && v < v_max) {
                        continue;
                    }
                    let c = (u / tile) as usize;
                    let r = (v / tile) as usize;
                    apply(&mut row_lo[k], delta[r * cols + c]);
                    row_views[k] = row_views[k].saturating_add(1);
                    updated += 1;
                }
            }
            updated
        })
        .sum()
}

/// The cells `k_lo..k_hi` of a column (centres `p0 + k step`, camera coordinates) that can
/// lie inside the frustum, or None when none can. Only a bound: the caller still tests every
/// cell in it exactly as before, so the cells updated (and their values) are the same as
/// testing all `nz`; the span is widened by [`SPAN_MARGIN`] cells each side against rounding,
/// and a plane nearly parallel to the column is not used to narrow it. What it saves is the
/// cells outside the view, most of the grid for a camera inside the room.
fn column_span(
    planes: &[Vector3<f64>; 5],
    p0: &Vector3<f64>,
    step: &Vector3<f64>,
    nz: usize,
) -> Option<(usize, usize)> {
    let (mut lo, mut hi) = (0.0f64, nz as f64);
    for n in planes {
        let a = n.dot(p0);
        let b = n.dot(step);
        // Scale of the terms of b: below it, b is rounding noise and its sign means nothing.
        let scale = n.x.abs() * step.x.abs() + n.y.abs() * step.y.abs() + n.z.abs() * step.z.abs();
        if b.abs() <= 1e-9 * scale {
            continue;
        }
        // a + b k >= 0.
        let k0 = -a / b;
        if b > 0.0 {
            lo = lo.max(k0);
        } else {
            hi = hi.min(k0);
        }
    }
    let lo = (lo.floor() - SPAN_MARGIN).max(0.0);
    let hi = (hi.ceil() + SPAN_MARGIN).min(nz as f64);
    // f64::max/min ignore a NaN bound (a degenerate pose), so neither end is NaN here.
    (lo < hi).then_some((lo as usize, hi as usize))
}

/// Cells added on each side of a column's computed span (see [`column_span`]).
const SPAN_MARGIN: f64 = 2.0;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::types::geometry::{camera_mount, iso_from_xy_yaw};

    /// The update as it was before [`column_span`]: every cell of every column tested.
    fn integrate_every_cell(
        g: &mut Grid,
        camera_from_odom: &Iso3,
        cam: &Camera,
        ev: &TileEvidence,
    ) {
        let spec = g.spec;
        let tile = f64::from(ev.tile_px);
        for idx in 0..spec.cells() {
            let [i, j, k] = spec.ijk(idx);
            let c0 = spec.center(i, j, 0);
            let step_k = camera_from_odom.rotation.to_rotation_matrix()
                * Vector3::new(0.0, 0.0, spec.voxel_size_m);
            let p = camera_from_odom * Point3::new(c0[0], c0[1], c0[2]) + step_k * k as f64;
            if p.z <= 1e-9 {
                continue;
            }
            let inv_z = 1.0 / p.z;
            let u = cam.fx * p.x * inv_z + cam.cx;
            let v = cam.fy * p.y * inv_z + cam.cy;
            if !(u >= 0.0 && u < ev.cols as f64 * tile && v >= 0.0 && v < ev.rows as f64 * tile) {
                continue;
            }
            let (c, r) = ((u / tile) as usize, (v / tile) as usize);
            g.log_odds[idx] += ev.delta[r * ev.cols + c];
            g.views[idx] += 1;
        }
    }

    #[test]
    fn column_spans_skip_only_cells_outside_the_view() {
        // Cameras inside and outside the grid, level, tilted, looking straight down and
        // straight along z (columns parallel to the image planes): the spanned update must
        // change exactly the cells, by exactly the values, of testing every cell.
        let spec = GridSpec::from_bounds([-1.0, -1.0, 0.0], [1.0, 1.0, 1.2], 0.05).unwrap();
        let cam = Camera::with_hfov(64, 48, 1.1);
        let mut rng = crate::types::rng::SplitMix64::new(7);
        let p: Vec<f32> = (0..6 * 8)
            .map(|_| 0.01 + 0.98 * rng.uniform() as f32)
            .collect();
        let ev = TileEvidence::from_probabilities(6, 8, 8, &p, 0.01);
        let mut poses: Vec<Iso3> = vec![
            Iso3::identity(),
            iso_from_xy_yaw(0.0, 0.0, 0.0)
                * camera_mount([0.0, 0.0, 0.5], std::f64::consts::FRAC_PI_2),
            iso_from_xy_yaw(-1.5, 0.2, 0.3) * camera_mount([0.1, 0.0, 0.6], 0.25),
        ];
        for _ in 0..40 {
            let (x, y) = (rng.uniform() * 4.0 - 2.0, rng.uniform() * 4.0 - 2.0);
            let yaw = rng.uniform() * std::f64::consts::TAU;
            let pitch = rng.uniform() * 2.0 - 0.6;
            poses.push(
                iso_from_xy_yaw(x, y, yaw) * camera_mount([0.0, 0.0, rng.uniform() * 1.5], pitch),
            );
        }
        let mut seen = 0;
        for odom_from_camera in &poses {
            let cfo = odom_from_camera.inverse();
            let mut fast = Grid::new(spec, 0.01).unwrap();
            let mut slow = fast.clone();
            let n = fast.integrate(&cfo, &cam, &ev);
            integrate_every_cell(&mut slow, &cfo, &cam, &ev);
            assert_eq!(n, slow.views.iter().filter(|&&v| v > 0).count());
            assert_eq!(fast.views, slow.views, "pose {odom_from_camera}");
            assert!(
                fast.log_odds
                    .iter()
                    .zip(&slow.log_odds)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "pose {odom_from_camera}"
            );
            seen += usize::from(n > 0);
        }
        // Most poses see part of the grid, or the comparison would be vacuous.
        assert!(
            seen > poses.len() / 2,
            "{seen} of {} poses saw the grid",
            poses.len()
        );
    }

    fn small_grid() -> Grid {
        let spec = GridSpec::from_bounds([0.0, -0.5, 0.0], [2.0, 0.5, 1.0], 0.1).unwrap();
        Grid::new(spec, 0.01).unwrap()
    }

    #[test]
    fn spec_dims_and_refusal() {
        let s = GridSpec::from_bounds([0.0; 3], [4.0, 4.0, 4.0], 0.04).unwrap();
        assert_eq!(s.dims, [100, 100, 100]);
        assert_eq!(s.index(1, 2, 3), (100 + 2) * 100 + 3);
        assert_eq!(s.ijk(s.index(7, 8, 9)), [7, 8, 9]);
        let e = GridSpec::from_bounds([0.0; 3], [100.0, 100.0, 100.0], 0.01).unwrap_err();
        match e {
            GridError::TooLarge { nx, needed_mib, .. } => {
                assert_eq!(nx, 10_000);
                assert_eq!(needed_mib, 10_000u64.pow(3) * 26 / (1 << 20) + 1);
            }
            other => panic!("{other:?}"),
        }
        assert!(GridSpec::from_bounds([0.0; 3], [1.0, f64::NAN, 1.0], 0.1).is_err());
        assert!(GridSpec::from_bounds([0.0; 3], [1.0; 3], 0.0).is_err());
    }

    /// One frame, one tile at p = 0.9, a known camera: exactly the cells of that tile's
    /// pyramid change, by exactly logit(0.9) - logit(prior).
    #[test]
    fn one_tile_updates_exactly_its_pyramid() {
        let spec = GridSpec::from_bounds([0.0, -0.5, 0.0], [2.0, 0.5, 1.0], 0.1).unwrap();
        let mut g = Grid::new(spec, 0.0078125).unwrap();
        // Camera at the origin 0.5 m up, looking along +x (level): optical z = odom +x.
        let odom_from_camera = camera_mount([0.0, 0.0, 0.5], 0.0);
        let camera_from_odom = odom_from_camera.inverse();
        // 2 x 2 tiles of 8 px: image 16 x 16, principal point at the centre, fx = 16
        // (each tile spans 0.5 in normalised coordinates).
        let cam = Camera {
            width: 16,
            height: 16,
            fx: 16.0,
            fy: 16.0,
            cx: 8.0,
            cy: 8.0,
        };
        // 2^-7: exactly representable in f32, so tiles at the prior add exactly 0.
        let prior = 0.0078125;
        // Only tile (row 0, col 1) = up and right carries p = 0.9; the others the prior.
        let p = [prior as f32, 0.9, prior as f32, prior as f32];
        let ev = TileEvidence::from_probabilities(2, 2, 8, &p, prior);
        let n = g.integrate(&camera_from_odom, &cam, &ev);
        assert!(n > 0);
        // logit(0.9) - logit(2^-7) = 2.1972246 + 4.8441871, with 0.9 as the f32 the tree returns.
        let expected = (logit(f64::from(0.9f32)) - logit(prior)) as f32;
        assert!((expected - 7.041_412).abs() < 1e-5, "{expected}");
        let base = logit(prior) as f32;
        let mut changed = 0;
        for i in 0..g.spec.dims[0] {
            for j in 0..g.spec.dims[1] {
                for k in 0..g.spec.dims[2] {
                    let c = g.spec.center(i, j, k);
                    // In optical coordinates: z = x_odom, x = -y_odom, y = -(z_odom - 0.5).
                    let (zc, xc, yc) = (c[0], -c[1], -(c[2] - 0.5));
                    let u = 16.0 * xc / zc + 8.0;
                    let v = 16.0 * yc / zc + 8.0;
                    let in_tile = (8.0..16.0).contains(&u) && (0.0..8.0).contains(&v);
                    let l = g.log_odds[g.spec.index(i, j, k)];
                    if in_tile {
                        changed += 1;
                        assert_eq!(l, base + expected, "cell {i},{j},{k} u={u} v={v}");
                    } else {
                        // Other tiles were at the prior: delta exactly 0.
                        assert_eq!(l, base, "cell {i},{j},{k} u={u} v={v}");
                    }
                }
            }
        }
        assert!(changed > 10, "{changed}");
        // Hand check of one cell: centre (1.05, -0.25, 0.75) -> u = 16*0.25/1.05+8 = 11.8,
        // v = 16*(-0.25)/1.05+8 = 4.19: in tile (0, 1).
        let idx = g.spec.index(10, 2, 7);
        let c = g.spec.center(10, 2, 7);
        assert!(
            (c[0] - 1.05).abs() < 1e-12
                && (c[1] + 0.25).abs() < 1e-12
                && (c[2] - 0.75).abs() < 1e-12
        );
        assert_eq!(g.log_odds[idx], base + expected);
        assert_eq!(g.views[idx], 1);
        // A cell behind the camera is untouched.
        let behind = GridSpec::from_bounds([-1.0, -0.5, 0.0], [-0.1, 0.5, 1.0], 0.1).unwrap();
        let mut gb = Grid::new(behind, prior).unwrap();
        assert_eq!(gb.integrate(&camera_from_odom, &cam, &ev), 0);
    }

    /// Two views of a point: the cell holding the point is in both pyramids, and every cell
    /// in both lies near the point.
    #[test]
    fn two_views_intersect_at_the_point() {
        let spec = GridSpec::from_bounds([-1.0, -1.0, 0.0], [1.0, 1.0, 1.0], 0.05).unwrap();
        let mut g = Grid::new(spec, 0.0078125).unwrap();
        // Aimed half a tile (1/16 rad) left of the point and 0.13 m below it, so the point
        // projects into the middle of a tile in both views.
        let target = Point3::new(0.21, 0.11, 0.53);
        let cam = Camera {
            width: 64,
            height: 64,
            fx: 64.0,
            fy: 64.0,
            cx: 32.0,
            cy: 32.0,
        };
        for (x, y) in [(-2.0f64, 0.1f64), (0.2, -2.0)] {
            let yaw = (target.y - y).atan2(target.x - x) + 0.0625;
            let odom_from_base = crate::types::geometry::iso_from_xy_yaw(x, y, yaw);
            let odom_from_camera = odom_from_base * camera_mount([0.0, 0.0, 0.4], 0.0);
            let camera_from_odom = odom_from_camera.inverse();
            let (u, v) = cam.project(&(camera_from_odom * target)).unwrap();
            assert!((u - 36.0).abs() < 1.0 && (v - 28.0).abs() < 1.0, "{u} {v}");
            let (r, c) = ((v / 8.0) as usize, (u / 8.0) as usize);
            let mut p = vec![0.0078125f32; 64];
            p[r * 8 + c] = 0.95;
            let ev = TileEvidence::from_probabilities(8, 8, 8, &p, 0.0078125);
            g.integrate(&camera_from_odom, &cam, &ev);
        }
        let once = (logit(f64::from(0.95f32)) - logit(0.0078125)) as f32;
        let hit = g.prior_log_odds() + once + once;
        let t = g.spec.index(24, 22, 10);
        let c = g.spec.center(24, 22, 10);
        assert!(
            (c[0] - 0.225).abs() < 1e-12
                && (c[1] - 0.125).abs() < 1e-12
                && (c[2] - 0.525).abs() < 1e-12
        );
        assert_eq!(g.log_odds[t], hit);
        let both: Vec<[f64; 3]> = (0..g.spec.cells())
            .filter(|&i| g.log_odds[i] == hit)
            .map(|i| {
                let [a, b, c] = g.spec.ijk(i);
                g.spec.center(a, b, c)
            })
            .collect();
        // Each tile spans 1/8 rad, about 0.28 m at 2.2 m: the shared cells stay within one
        // tile footprint of the point.
        for c in &both {
            let d = ((c[0] - 0.21).powi(2) + (c[1] - 0.11).powi(2) + (c[2] - 0.53).powi(2)).sqrt();
            assert!(d < 0.3, "{c:?} is {d} m from the point");
        }
    }

    #[test]
    fn thread_count_does_not_change_the_result() {
        let run = |threads| {
            crate::types::testing::with_threads(threads, || {
                let mut g = small_grid();
                let cam = Camera::with_hfov(64, 48, 1.0);
                let pose = camera_mount([-0.5, 0.1, 0.6], 0.2).inverse();
                let p: Vec<f32> = (0..48).map(|i| 0.001 + i as f32 / 50.0).collect();
                let ev = TileEvidence::from_probabilities(6, 8, 8, &p, 0.01);
                g.integrate(&pose, &cam, &ev);
                g.sha256_hex()
            })
        };
        assert_eq!(run(1), run(3));
    }
}
