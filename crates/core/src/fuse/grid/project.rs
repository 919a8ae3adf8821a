//! The frame update on blocked storage: which cells a frame's tiles reach (centre in front of
//! the camera, within the range limit, projecting into a tile), which blocks that needs that
//! are not stored yet, and the update of the stored ones.
//!
//! Invariants: whether a cell is updated, and by which tile, is decided by the same
//! arithmetic for every cell whatever is stored (`hit`), so a sparse grid and a dense one are
//! updated alike; the frustum bounds (the region, the column spans) only skip cells that
//! cannot pass that test, with margins against rounding; slot 0 is never written.

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use super::blocks::{BLOCK, BLOCK_CELLS, Layout};
use super::{GridError, GridSpec, TileEvidence};
use crate::types::geometry::{Camera, Iso3};

/// Cells added on each side of a column's computed span (see [`column_span`]).
const SPAN_MARGIN: f64 = 2.0;

/// One frame's view of the grid: the camera, its tiles' evidence and the region it can reach.
pub(super) struct Projector<'a> {
    spec: GridSpec,
    camera_from_odom: Iso3,
    step_k: Vector3<f64>,
    cam: Camera,
    tile: f64,
    /// `1 / tile` when that is exact (a power-of-two tile): `u * inv_tile` is then `u / tile`
    /// bit for bit, and saves two of the three divisions of every cell in view.
    inv_tile: Option<f64>,
    u_max: f64,
    v_max: f64,
    max_depth_m: f64,
    delta: &'a [f32],
    cols: usize,
    /// Cells (i, j, k) the frustum can reach: a box, `lo..hi` on each axis.
    lo: [usize; 3],
    hi: [usize; 3],
    /// Span of cells `k_lo..k_hi` of each column of the box, x-major; empty when none.
    spans: Vec<(u32, u32)>,
}

impl<'a> Projector<'a> {
    /// The frame seen from `camera_from_odom`; cells deeper than `max_depth_m` (metres along
    /// the optical axis; infinite for no limit) are out of its reach. [`GridError::Columns`]
    /// when its plan (8 bytes a column of the box it can reach) would exceed `max_bytes`.
    pub(super) fn new(
        spec: &GridSpec,
        camera_from_odom: &Iso3,
        camera: &Camera,
        ev: &'a TileEvidence,
        max_depth_m: f64,
        max_bytes: u64,
    ) -> Result<Self, GridError> {
        let tile = f64::from(ev.tile_px);
        let mut p = Self {
            spec: *spec,
            camera_from_odom: *camera_from_odom,
            step_k: camera_from_odom.rotation.to_rotation_matrix()
                * Vector3::new(0.0, 0.0, spec.voxel_size_m),
            cam: *camera,
            tile,
            inv_tile: ev.tile_px.is_power_of_two().then(|| 1.0 / tile),
            u_max: ev.cols as f64 * tile,
            v_max: ev.rows as f64 * tile,
            max_depth_m,
            delta: &ev.delta,
            cols: ev.cols,
            lo: [0; 3],
            hi: [0; 3],
            spans: Vec::new(),
        };
        (p.lo, p.hi) = p.reach();
        let columns = ((p.hi[0] - p.lo[0]) * (p.hi[1] - p.lo[1])) as u64;
        let needed = columns * std::mem::size_of::<(u32, u32)>() as u64;
        if needed > max_bytes {
            return Err(GridError::Columns {
                columns,
                needed_mib: needed >> 20,
                limit_mib: max_bytes >> 20,
            });
        }
        p.spans = p.column_spans();
        Ok(p)
    }

    /// The box of cells that can lie in the frustum: with a range limit, the cells around the
    /// pyramid from the eye to the image's corners at the limit's depth (one cell of margin);
    /// without one, the grid.
    fn reach(&self) -> ([usize; 3], [usize; 3]) {
        let dims = self.spec.dims;
        let whole = ([0; 3], dims);
        if !self.max_depth_m.is_finite() {
            return whole;
        }
        let odom_from_camera = self.camera_from_odom.inverse();
        let c = &self.cam;
        let d = self.max_depth_m;
        let corner = |u: f64, v: f64| {
            odom_from_camera * Point3::new((u - c.cx) / c.fx * d, (v - c.cy) / c.fy * d, d)
        };
        let pts = [
            odom_from_camera * Point3::origin(),
            corner(0.0, 0.0),
            corner(self.u_max, 0.0),
            corner(0.0, self.v_max),
            corner(self.u_max, self.v_max),
        ];
        let (mut lo, mut hi) = ([0; 3], [0; 3]);
        for a in 0..3 {
            let to_cell = |x: f64| (x - self.spec.origin_m[a]) / self.spec.voxel_size_m - 0.5;
            let min = pts.iter().map(|p| p[a]).fold(f64::INFINITY, f64::min);
            let max = pts.iter().map(|p| p[a]).fold(f64::NEG_INFINITY, f64::max);
            if !(min.is_finite() && max.is_finite()) {
                return whole;
            }
            let n = dims[a] as f64;
            lo[a] = (to_cell(min).floor() - 1.0).clamp(0.0, n) as usize;
            hi[a] = (to_cell(max).floor() + 2.0).clamp(0.0, n) as usize;
        }
        (lo, hi)
    }

    /// The frustum's planes in camera coordinates, each as `n . p + d >= 0`: the four sides
    /// and z > 0 (p.z > 0 makes `u >= 0` the same as `fx p.x + cx p.z >= 0`, and so on), and
    /// the range limit's far plane when there is one.
    fn planes(&self) -> Vec<(Vector3<f64>, f64)> {
        let c = &self.cam;
        let mut planes = vec![
            (Vector3::new(0.0, 0.0, 1.0), 0.0),
            (Vector3::new(c.fx, 0.0, c.cx), 0.0),
            (Vector3::new(-c.fx, 0.0, self.u_max - c.cx), 0.0),
            (Vector3::new(0.0, c.fy, c.cy), 0.0),
            (Vector3::new(0.0, -c.fy, self.v_max - c.cy), 0.0),
        ];
        if self.max_depth_m.is_finite() {
            planes.push((Vector3::new(0.0, 0.0, -1.0), self.max_depth_m));
        }
        planes
    }

    fn column_spans(&self) -> Vec<(u32, u32)> {
        let planes = self.planes();
        let (lo, hi) = (self.lo, self.hi);
        (lo[0]..hi[0])
            .into_par_iter()
            .map(|i| {
                (lo[1]..hi[1])
                    .map(|j| {
                        let p0 = self.column_origin(i, j);
                        match column_span(&planes, &p0.coords, &self.step_k, self.spec.dims[2]) {
                            Some((a, b)) if a.max(lo[2]) < b.min(hi[2]) => {
                                (a.max(lo[2]) as u32, b.min(hi[2]) as u32)
                            }
                            _ => (0, 0),
                        }
                    })
                    .collect::<Vec<_>>()
            })
            .collect::<Vec<_>>()
            .concat()
    }

    /// Centre of cell (i, j, 0) in camera coordinates.
    #[inline]
    fn column_origin(&self, i: usize, j: usize) -> Point3<f64> {
        let c0 = self.spec.center(i, j, 0);
        self.camera_from_odom * Point3::new(c0[0], c0[1], c0[2])
    }

    /// Cells `k_lo..k_hi` of column (i, j) that may be in view, clipped to `k_range`.
    #[inline]
    fn span(&self, i: usize, j: usize, k_range: (usize, usize)) -> (usize, usize) {
        if i < self.lo[0] || i >= self.hi[0] || j < self.lo[1] || j >= self.hi[1] {
            return (0, 0);
        }
        let w = self.hi[1] - self.lo[1];
        let (a, b) = self.spans[(i - self.lo[0]) * w + (j - self.lo[1])];
        (k_range.0.max(a as usize), k_range.1.min(b as usize))
    }

    /// The tile's delta for cell k of the column whose cell 0 is at `p0` (camera
    /// coordinates), or None when its centre is not in front of the camera within range or
    /// does not project into a tile. The one test of the update.
    #[inline]
    fn hit(&self, p0: &Point3<f64>, k: usize) -> Option<f32> {
        let p = p0 + self.step_k * k as f64;
        if p.z <= 1e-9 || p.z > self.max_depth_m {
            return None;
        }
        // One division per cell, not two: this runs for every cell in view.
        let inv_z = 1.0 / p.z;
        let u = self.cam.fx * p.x * inv_z + self.cam.cx;
        let v = self.cam.fy * p.y * inv_z + self.cam.cy;
        // Negated comparisons also reject NaN.
        if !(u >= 0.0 && u < self.u_max && v >= 0.0 && v < self.v_max) {
            return None;
        }
        let (c, r) = match self.inv_tile {
            Some(k) => ((u * k) as usize, (v * k) as usize),
            None => ((u / self.tile) as usize, (v / self.tile) as usize),
        };
        Some(self.delta[r * self.cols + c])
    }

    /// Blocks of the frustum's box holding at least one cell the frame updates that `layout`
    /// does not store, ascending.
    pub(super) fn new_blocks(&self, layout: &Layout) -> Vec<u32> {
        let (lo, hi) = (self.lo, self.hi);
        if (0..3).any(|a| lo[a] >= hi[a]) {
            return Vec::new();
        }
        let (b_lo, b_hi) = (lo.map(|x| x / BLOCK), hi.map(|x| x.div_ceil(BLOCK)));
        (b_lo[0]..b_hi[0])
            .into_par_iter()
            .map(|bi| {
                let mut found = Vec::new();
                for bj in b_lo[1]..b_hi[1] {
                    for bk in b_lo[2]..b_hi[2] {
                        let block = layout.block_index([bi, bj, bk]);
                        if layout.table[block] == 0 && self.block_is_hit([bi, bj, bk]) {
                            found.push(block as u32);
                        }
                    }
                }
                found
            })
            .collect::<Vec<_>>()
            .concat()
    }

    /// Whether any cell of block `b` is updated (stops at the first).
    fn block_is_hit(&self, b: [usize; 3]) -> bool {
        let k_range = (b[2] * BLOCK, ((b[2] + 1) * BLOCK).min(self.spec.dims[2]));
        for i in b[0] * BLOCK..((b[0] + 1) * BLOCK).min(self.spec.dims[0]) {
            for j in b[1] * BLOCK..((b[1] + 1) * BLOCK).min(self.spec.dims[1]) {
                let (k_lo, k_hi) = self.span(i, j, k_range);
                if k_lo >= k_hi {
                    continue;
                }
                let p0 = self.column_origin(i, j);
                if (k_lo..k_hi).any(|k| self.hit(&p0, k).is_some()) {
                    return true;
                }
            }
        }
        false
    }

    /// Calls `apply(value, delta)` for every updated cell of every stored block (`values` and
    /// `views` laid out by `layout`) and counts the view; returns the number of such cells.
    pub(super) fn apply(
        &self,
        layout: &Layout,
        values: &mut [f32],
        views: &mut [u16],
        apply: impl Fn(&mut f32, f32) + Sync,
    ) -> usize {
        let dims = self.spec.dims;
        let (b_lo, b_hi) = (
            self.lo.map(|x| x / BLOCK),
            self.hi.map(|x| x.div_ceil(BLOCK)),
        );
        values
            .par_chunks_mut(BLOCK_CELLS)
            .zip(views.par_chunks_mut(BLOCK_CELLS))
            .zip(layout.blocks.par_iter())
            .skip(1)
            .map(|((vals, views), &block)| {
                let b = layout.block_coords(block);
                if (0..3).any(|a| b[a] < b_lo[a] || b[a] >= b_hi[a]) {
                    return 0;
                }
                let k_range = (b[2] * BLOCK, ((b[2] + 1) * BLOCK).min(dims[2]));
                let mut updated = 0;
                for a in 0..BLOCK.min(dims[0] - b[0] * BLOCK) {
                    for c in 0..BLOCK.min(dims[1] - b[1] * BLOCK) {
                        let (i, j) = (b[0] * BLOCK + a, b[1] * BLOCK + c);
                        let (k_lo, k_hi) = self.span(i, j, k_range);
                        if k_lo >= k_hi {
                            continue;
                        }
                        let p0 = self.column_origin(i, j);
                        let base = (a * BLOCK + c) * BLOCK;
                        for k in k_lo..k_hi {
                            if let Some(d) = self.hit(&p0, k) {
                                let o = base + k % BLOCK;
                                apply(&mut vals[o], d);
                                views[o] = views[o].saturating_add(1);
                                updated += 1;
                            }
                        }
                    }
                }
                updated
            })
            .sum()
    }
}

/// The cells `k_lo..k_hi` of a column (centres `p0 + k step`, camera coordinates) that can
/// lie inside the frustum (`planes`, each `n . p + d >= 0`), or None when none can. Only a
/// bound: the update still tests every cell in it, so the cells updated (and their values)
/// are the same as testing all `nz`; the span is widened by [`SPAN_MARGIN`] cells each side
/// against rounding, and a plane nearly parallel to the column is not used to narrow it.
/// What it saves is the cells outside the view, most of the grid for a camera inside it.
fn column_span(
    planes: &[(Vector3<f64>, f64)],
    p0: &Vector3<f64>,
    step: &Vector3<f64>,
    nz: usize,
) -> Option<(usize, usize)> {
    let (mut lo, mut hi) = (0.0f64, nz as f64);
    for (n, d) in planes {
        let a = n.dot(p0) + d;
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
