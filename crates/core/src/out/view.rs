//! What the viewer shows, computed without the viewer: whole-grid summaries and projections,
//! tile probabilities at image resolution, the pyramids of the confident tiles, colours (viridis,
//! verdicts) and the recording id. The binary's Rerun observers log these; keeping them here
//! keeps them unit-tested and free of the Rerun SDK.
//!
//! Invariants: pure functions of their inputs; sums in index order, so results do not depend
//! on the thread count.

use nalgebra::Point3;
use rayon::prelude::*;
use sha2::{Digest, Sha256};

use crate::fuse::grid::{BLOCK, BlockCells, Grid, Region, for_each_cell, sigmoid};
use crate::fuse::objects::Object;
use crate::fuse::refine::Verdict;
use crate::fuse::replay::SessionData;
use crate::types::geometry::{Camera, Iso3};
use crate::types::probs::TileProbs;

/// The application id of every recording.
pub const APP_ID: &str = "objloc";

/// Colour of a frame's refinement verdict on the refined track: green when the pose was
/// measured, grey without evidence, yellow/orange when the correction was refused, red when
/// rolled back (visible at a glance).
pub fn verdict_rgb(v: Verdict) -> [u8; 3] {
    match v {
        Verdict::Accepted => [60, 200, 90],
        Verdict::Insignificant => [150, 220, 160],
        Verdict::NoEvidence => [150, 150, 150],
        Verdict::Ambiguous => [240, 220, 40],
        Verdict::Gated => [255, 150, 30],
        Verdict::RolledBack => [230, 30, 30],
    }
}

/// Whole-grid numbers and the cells worth showing, in one pass over the stored blocks.
#[derive(Debug, Clone, PartialEq)]
pub struct GridSummary {
    /// Highest posterior of any cell, in [0, 1].
    pub max_posterior: f64,
    /// Mean binary entropy of a cell, bits.
    pub mean_entropy_bits: f64,
    /// (i, j, k) and posterior of the shown cells, in index order.
    pub cells: Vec<([i32; 3], f32)>,
    /// The cells the projections show: the grid's stored region (the whole grid when dense).
    pub region: Region,
    /// Mean posterior along x (over the grid's whole x): the region's ny x nz, row-major as
    /// an image with z up (row 0 = top z).
    pub along_x: Vec<f32>,
    /// Mean posterior along y (over the grid's whole y): the region's nx wide, nz high, z up.
    pub along_y: Vec<f32>,
    /// Mean posterior along z (over the grid's whole z): the region's nx wide, ny high, y up.
    pub along_z: Vec<f32>,
}

/// Sorts `cells` (index, log-odds or posterior) into index order keeping at most `max_cells`
/// of them: the most probable, ties to the lower index (a total order, so the cut does not
/// depend on how the cells came). The cut comes before the sort: a real capture's fitted
/// grid (200 cells a side) had 540 000 cells above 0.5, most of them the cones behind the
/// object.
fn most_probable_in_index_order(cells: &mut Vec<([i32; 3], f32)>, max_cells: usize) {
    if cells.len() > max_cells {
        if max_cells == 0 {
            cells.clear();
            return;
        }
        // Descending value (never NaN), then ascending index.
        cells.select_nth_unstable_by(max_cells - 1, |a, b| {
            b.1.total_cmp(&a.1).then(a.0.cmp(&b.0))
        });
        cells.truncate(max_cells);
    }
    cells.sort_unstable_by_key(|c| c.0);
}

fn binary_entropy_bits(p: f64) -> f64 {
    let h = |q: f64| if q > 0.0 { -q * q.log2() } else { 0.0 };
    h(p) + h(1.0 - p)
}

/// Log-odds beyond which [`PosteriorTable`] holds a cell at its ends (sigmoid(-20) = 2e-9).
const TABLE_LOG_ODDS_MAX: f64 = 20.0;
/// Table entries per unit of log-odds: linear interpolation between them (and the f32
/// entries) is within 1e-6 of the posterior and 1e-5 bits of the entropy, far below what a
/// plot shows.
const TABLE_STEPS_PER_UNIT: f64 = 128.0;

/// Whether frame `index` of a pass of `frames` frames gets a snapshot of what grows with the
/// replay, when at most about `max_snapshots` are wanted: every frame up to that many
/// frames, then every k-th (k = frames / max_snapshots, rounded up) and always the last, so a
/// pass logs at most `max_snapshots + 1`.
pub fn is_snapshot(index: usize, frames: usize, max_snapshots: usize) -> bool {
    let every = frames.div_ceil(max_snapshots.max(1)).max(1);
    index.is_multiple_of(every) || index + 1 == frames
}

/// How many snapshots [`is_snapshot`] should be asked for when each summarises `cells` cells
/// and all of them together should summarise about `cell_budget`: at most `max_snapshots`,
/// at least 1 (the last frame always gets one too). A snapshot's cost grows with the grid's
/// cells, not with the frame's: a grid fitted to a real capture (8 M cells) costs as much to
/// summarise as fusing two of its frames.
pub fn snapshots_within(cell_budget: usize, cells: usize, max_snapshots: usize) -> usize {
    (cell_budget / cells.max(1)).clamp(1, max_snapshots.max(1))
}

/// Built on first use, then shared: the same values every time.
static POSTERIOR_TABLE: std::sync::OnceLock<PosteriorTable> = std::sync::OnceLock::new();

/// Posterior and binary entropy as functions of log-odds, tabulated: the whole-grid
/// projections and the mean entropy of a snapshot need both for every cell (a million
/// cells, three transcendental calls each, cost more than the replay's frame), and a plot
/// needs neither to the last bit. The shown cells and the maximum use the exact sigmoid.
/// f32 pairs, so that the table (41 kB) stays near the first-level cache: a snapshot of a
/// real capture's grid looks it up millions of times at scattered log-odds.
struct PosteriorTable {
    /// (posterior, entropy bits) at log-odds `-MAX + i / STEPS`, the last entry twice (so
    /// that the entry after any index in range exists).
    at: Vec<(f32, f32)>,
}

impl PosteriorTable {
    fn new() -> Self {
        let n = (2.0 * TABLE_LOG_ODDS_MAX * TABLE_STEPS_PER_UNIT) as usize + 1;
        let mut at: Vec<(f32, f32)> = (0..n)
            .map(|i| {
                let l = i as f64 / TABLE_STEPS_PER_UNIT - TABLE_LOG_ODDS_MAX;
                let p = sigmoid(l);
                (p as f32, binary_entropy_bits(p) as f32)
            })
            .collect();
        at.push(at[n - 1]);
        Self { at }
    }

    /// (posterior, entropy bits) of log-odds `l`, interpolated; NaN counts as the bottom end,
    /// log-odds beyond the table as its ends.
    #[inline]
    fn get(&self, l: f32) -> (f64, f64) {
        let last = (self.at.len() - 2) as f64;
        // `max` maps NaN to 0.
        let x = ((f64::from(l) + TABLE_LOG_ODDS_MAX) * TABLE_STEPS_PER_UNIT)
            .max(0.0)
            .min(last);
        let i = x as usize;
        let f = x - i as f64;
        let (a, b) = (self.at[i], self.at[i + 1]);
        let lerp = |u: f32, v: f32| f64::from(u) + f * (f64::from(v) - f64::from(u));
        (lerp(a.0, b.0), lerp(a.1, b.1))
    }
}

/// The [`GridSummary`] of `grid`; the cells shown have a posterior above `min_posterior` and were
/// seen by at least `min_views` frames, at most `max_cells` of them (the most probable by
/// log-odds: the f32 posterior is 1 for every cell above log-odds 17).
/// Cells outside the stored blocks are at the prior and count as such.
pub fn summarize_grid(
    grid: &Grid,
    min_posterior: f32,
    min_views: u16,
    max_cells: usize,
) -> GridSummary {
    let region = grid.occupied_region();
    let [w, h, d] = region.dims;
    let table = POSTERIOR_TABLE.get_or_init(PosteriorTable::new);
    let at_prior = table.get(grid.prior_log_odds());
    // Slabs of x blocks in block order, summarised in parallel a fixed number at a time and
    // combined in slab order: the grouping does not depend on the thread count, so neither
    // do the sums.
    let blocks: Vec<BlockCells<'_>> = grid.blocks_in_order().collect();
    let slabs: Vec<&[BlockCells<'_>]> = blocks
        .chunk_by(|a, b| a.first_cell[0] == b.first_cell[0])
        .collect();
    // along_x is summed transposed (z fastest, as the cells are stored) and turned into
    // its image layout once at the end.
    let mut along_x_t = vec![0f64; h * d];
    let mut along_y = vec![0f64; w * d];
    let mut along_z = vec![0f64; w * h];
    let mut hist = vec![0u64; SHOWN_BINS];
    let mut max_e = f32::NEG_INFINITY;
    let mut entropy = 0.0;
    // The slabs' sums are reused from batch to batch: a fresh h x d buffer per slab (a
    // quarter of a MB on a real capture's grid) was mapped, zeroed and unmapped each time.
    let mut pool: Vec<SlabSummary> = Vec::new();
    for batch in slabs.chunks(SUMMARY_SLABS) {
        pool.resize_with(batch.len().max(pool.len()), SlabSummary::default);
        pool.par_iter_mut()
            .zip(batch.par_iter())
            .for_each(|(part, slab)| {
                summarize_slab(
                    part,
                    grid,
                    slab,
                    &region,
                    at_prior,
                    min_posterior,
                    min_views,
                );
            });
        for part in pool.iter_mut().take(batch.len()) {
            max_e = max_e.max(part.max_e);
            entropy += part.entropy;
            for (a, v) in along_x_t.iter_mut().zip(&part.along_x_t) {
                *a += v;
            }
            let x0 = part.first_x - region.first_cell[0];
            for col in 0..part.width {
                for rz in 0..d {
                    along_y[rz * w + x0 + col] = part.along_y_t[col * d + rz];
                }
                for ry in 0..h {
                    along_z[ry * w + x0 + col] = part.along_z_t[col * h + ry];
                }
            }
            for (a, v) in hist.iter_mut().zip(&part.hist) {
                *a += u64::from(*v);
            }
        }
    }
    let mut along_x = vec![0f64; h * d];
    for jy in 0..h {
        for rz in 0..d {
            along_x[rz * h + jy] = along_x_t[jy * d + rz];
        }
    }
    let cells = shown_cells(grid, &slabs, &hist, min_posterior, min_views, max_cells);
    if !grid.is_fully_stored() {
        max_e = max_e.max(0.0);
    }
    let [nx, ny, nz] = grid.spec.dims;
    let n = grid.spec.cells().max(1) as f64;
    // The sums hold each stored cell's difference from the prior's value.
    let mean = |v: Vec<f64>, len: usize| {
        v.into_iter()
            .map(|s| ((len as f64 * at_prior.0 + s) / len as f64) as f32)
            .collect()
    };
    GridSummary {
        max_posterior: sigmoid(f64::from(grid.prior_log_odds() + max_e)),
        mean_entropy_bits: (n * at_prior.1 + entropy) / n,
        cells,
        region,
        along_x: mean(along_x, nx),
        along_y: mean(along_y, ny),
        along_z: mean(along_z, nz),
    }
}

/// Slabs of x blocks per parallel batch of [`summarize_grid`].
const SUMMARY_SLABS: usize = 8;

/// A [`GridSummary`]'s sums over one slab of x blocks (`width` columns from `first_x`),
/// each the cells' difference from the prior's value, laid out with the cells' fastest axis
/// fastest (so that a column of cells adds to consecutive entries): `along_x_t[jy * d + rz]`,
/// `along_y_t[col * d + rz]`, `along_z_t[col * h + ry]`.
#[derive(Default)]
struct SlabSummary {
    first_x: usize,
    width: usize,
    max_e: f32,
    entropy: f64,
    along_x_t: Vec<f64>,
    along_y_t: Vec<f64>,
    along_z_t: Vec<f64>,
    /// The cells that may be shown, counted by their log-odds ([`shown_bin`]).
    hist: Vec<u32>,
}

/// Fills `s` with the sums of `slab` (whatever `s` held before).
fn summarize_slab(
    s: &mut SlabSummary,
    grid: &Grid,
    slab: &[BlockCells<'_>],
    region: &Region,
    at_prior: (f64, f64),
    min_posterior: f32,
    min_views: u16,
) {
    let [_, h, d] = region.dims;
    let first_x = slab.first().map_or(0, |b| b.first_cell[0]);
    let width = slab.first().map_or(0, |b| b.extent[0]);
    let table = POSTERIOR_TABLE.get_or_init(PosteriorTable::new);
    let prior = grid.prior_log_odds();
    let near_threshold = near_threshold(min_posterior);
    let zeroed = |v: &mut Vec<f64>, len: usize| {
        v.clear();
        v.resize(len, 0.0);
    };
    s.first_x = first_x;
    s.width = width;
    s.max_e = f32::NEG_INFINITY;
    s.entropy = 0.0;
    zeroed(&mut s.along_x_t, h * d);
    zeroed(&mut s.along_y_t, width * d);
    zeroed(&mut s.along_z_t, width * h);
    s.hist.clear();
    s.hist.resize(SHOWN_BINS, 0);
    let [_, j0, k0] = region.first_cell;
    for b in slab {
        let [bi, bj, bk] = b.first_cell;
        // rz = d - 1 - (k - k0) runs down as k runs up the column: reversed below.
        let top = d - (bk - k0);
        for a in 0..b.extent[0] {
            let col = bi + a - first_x;
            for c in 0..b.extent[1] {
                let jy = bj + c - j0;
                let base = (a * BLOCK + c) * BLOCK;
                let evidence = &b.evidence[base..base + b.extent[2]];
                let ys = &mut s.along_y_t[col * d + top - evidence.len()..col * d + top];
                let xs = &mut s.along_x_t[jy * d + top - evidence.len()..jy * d + top];
                let (mut sum_p, mut sum_h) = (0.0, 0.0);
                for ((&ev, y), x) in evidence
                    .iter()
                    .zip(ys.iter_mut().rev())
                    .zip(xs.iter_mut().rev())
                {
                    s.max_e = s.max_e.max(ev);
                    let (p, hb) = table.get(prior + ev);
                    let p = p - at_prior.0;
                    sum_p += p;
                    sum_h += hb - at_prior.1;
                    *y += p;
                    *x += p;
                }
                s.along_z_t[col * h + h - 1 - jy] += sum_p;
                s.entropy += sum_h;
                for (e, &ev) in evidence.iter().enumerate() {
                    let l = prior + ev;
                    if l > near_threshold && b.views[base + e] >= min_views {
                        s.hist[shown_bin(l, near_threshold)] += 1;
                    }
                }
            }
        }
    }
}

/// Bins of [`shown_bin`]: a snapshot counts the cells it may show by log-odds first, then
/// collects only those of the bins that hold the most probable `max_cells`. A real capture's
/// grid has 1.5-2.2 M cells above 0.5, and pushing, sorting and cutting all of them was half
/// of a snapshot's time on the replay's thread.
const SHOWN_BINS: usize = 4096;
/// Bins per unit of log-odds above the threshold (the last bin takes everything beyond).
const SHOWN_BINS_PER_UNIT: f32 = 64.0;

/// The bin of log-odds `l` above `near_threshold`: non-decreasing in `l`.
#[inline]
fn shown_bin(l: f32, near_threshold: f32) -> usize {
    (((l - near_threshold) * SHOWN_BINS_PER_UNIT) as usize).min(SHOWN_BINS - 1)
}

/// The cells to show, in index order: of the cells above `min_posterior` seen by at least
/// `min_views` frames (counted by log-odds in `hist`), the `max_cells` of the highest
/// log-odds, ties to the lower index, with their posteriors. Exactly those
/// [`most_probable_in_index_order`] picks from all of them: only cells of a lower bin than
/// at least `max_cells` others, so of lower log-odds, are left out.
fn shown_cells(
    grid: &Grid,
    slabs: &[&[BlockCells<'_>]],
    hist: &[u64],
    min_posterior: f32,
    min_views: u16,
    max_cells: usize,
) -> Vec<([i32; 3], f32)> {
    let prior = grid.prior_log_odds();
    let near_threshold = near_threshold(min_posterior);
    // The lowest bin whose cells and those above reach max_cells (0: every candidate).
    let mut above = 0u64;
    let mut first_bin = 0;
    for (bin, &n) in hist.iter().enumerate().rev() {
        above += n;
        if above >= max_cells as u64 {
            first_bin = bin;
            break;
        }
    }
    let parts: Vec<Vec<([i32; 3], f32)>> = slabs
        .par_iter()
        .map(|slab| {
            let mut out = Vec::new();
            for b in slab.iter() {
                for_each_cell(b, |o, [a, c, e]| {
                    let l = prior + b.evidence[o];
                    if l.is_nan() || l <= near_threshold || b.views[o] < min_views {
                        return;
                    }
                    let bin = shown_bin(l, near_threshold);
                    // Above the first bin the margin is passed (see `near_threshold`).
                    let shown = bin > 0 || sigmoid(f64::from(l)) as f32 > min_posterior;
                    if bin >= first_bin && shown {
                        let [i, j, k] = b.first_cell;
                        out.push(([(i + a) as i32, (j + c) as i32, (k + e) as i32], l));
                    }
                });
            }
            out
        })
        .collect();
    let mut cells = Vec::with_capacity(parts.iter().map(Vec::len).sum());
    for part in parts {
        cells.extend(part);
    }
    most_probable_in_index_order(&mut cells, max_cells);
    for c in &mut cells {
        c.1 = sigmoid(f64::from(c.1)) as f32;
    }
    cells
}

/// Log-odds below which no cell's posterior exceeds `min_posterior`: its logit less a
/// margin for the rounding of the logit and of the f32 casts. A cell of log-odds at least
/// one [`shown_bin`] above it is certainly above `min_posterior` (1/64 > the margin).
fn near_threshold(min_posterior: f32) -> f32 {
    (crate::fuse::grid::logit(f64::from(min_posterior)) - 1e-3) as f32
}

/// Tile probabilities as one f32 per image pixel (0 outside whole tiles: "no value").
pub fn upscale(probs: &TileProbs, width: u32, height: u32) -> Vec<f32> {
    let layout = [probs.rows, probs.cols, probs.tile_px as usize];
    upscale_tiles(&probs.p, layout, width, height, 0.0)
}

/// One value per image pixel of `width` x `height` from one per tile: `values` row-major
/// over `[rows, cols, tile_px]` (tiles of `tile_px` pixels a side), `outside` where no
/// whole tile covers the pixel (or `values` is short).
pub fn upscale_tiles<T: Copy>(
    values: &[T],
    [rows, cols, tile_px]: [usize; 3],
    width: u32,
    height: u32,
    outside: T,
) -> Vec<T> {
    let t = tile_px.max(1);
    let w = width as usize;
    let mut out = vec![outside; w * height as usize];
    let covered = w.min(cols * t);
    for y in 0..height as usize {
        let r = y / t;
        if r >= rows {
            break;
        }
        // The first pixel row of a row of tiles is built, the others are copies of it (a
        // camera's 1140 x 855 frame took 5 ms pixel by pixel).
        let (done, rest) = out.split_at_mut(y * w);
        let row = &mut rest[..covered];
        if y % t == 0 {
            for (x, v) in row.iter_mut().enumerate() {
                *v = values.get(r * cols + x / t).copied().unwrap_or(outside);
            }
        } else {
            row.copy_from_slice(&done[(y - 1) * w..(y - 1) * w + covered]);
        }
    }
    out
}

/// Line strips of the pyramids of tiles with p > `min_p`: four edges from the eye and the far
/// rectangle at `depth_m` along the optical axis, in odom, with each tile's probability.
pub fn pyramids(
    camera: &Camera,
    odom_from_camera: &Iso3,
    probs: &TileProbs,
    min_p: f32,
    depth_m: f64,
) -> Vec<(Vec<[f32; 3]>, f32)> {
    let eye = odom_from_camera.translation.vector;
    let eye = [eye.x as f32, eye.y as f32, eye.z as f32];
    let t = f64::from(probs.tile_px);
    let far = |u: f64, v: f64| {
        let r = camera.ray(u, v);
        let p = odom_from_camera * Point3::from(r * (depth_m / r.z));
        [p.x as f32, p.y as f32, p.z as f32]
    };
    let mut out = Vec::new();
    for r in 0..probs.rows {
        for c in 0..probs.cols {
            let p = probs.p[r * probs.cols + c];
            if p.is_nan() || p <= min_p {
                continue;
            }
            let (u0, v0) = (c as f64 * t, r as f64 * t);
            let corners = [
                far(u0, v0),
                far(u0 + t, v0),
                far(u0 + t, v0 + t),
                far(u0, v0 + t),
            ];
            for k in corners {
                out.push((vec![eye, k], p));
            }
            let mut rect = corners.to_vec();
            rect.push(corners[0]);
            out.push((rect, p));
        }
    }
    out
}

/// Distance from the first (most massive) object's centroid to the nearest true box centre.
pub fn centroid_error_m(objects: &[Object], data: &SessionData) -> Option<f64> {
    let o = objects.first()?;
    let gt = data.ground_truth.as_ref()?;
    gt.box_center
        .iter()
        .map(|c| {
            let d: f64 = (0..3)
                .map(|a| (o.centroid_m[a] - c.position[a]).powi(2))
                .sum();
            d.sqrt()
        })
        .min_by(f64::total_cmp)
}

/// Viridis RGBA overlay: alpha grows with p so that confident tiles tint the frame.
pub fn overlay_rgba(p: &[f32]) -> Vec<u8> {
    let mut out = Vec::with_capacity(p.len() * 4);
    for &v in p {
        let [r, g, b] = viridis(v);
        let a = if v > 0.0 {
            (40.0 + 180.0 * v.clamp(0.0, 1.0)).round() as u8
        } else {
            0
        };
        out.extend_from_slice(&[r, g, b, a]);
    }
    out
}

/// [`overlay_rgba`] of [`upscale`]`(probs, width, height)`, computed per tile: the same
/// bytes, with one colour per tile rather than per pixel (the fuse stream draws it for
/// every frame).
pub fn overlay_rgba_of_tiles(probs: &TileProbs, width: u32, height: u32) -> Vec<u8> {
    let tile_rgba: Vec<[u8; 4]> = probs
        .p
        .iter()
        .map(|&v| {
            let rgba = overlay_rgba(&[v]);
            [rgba[0], rgba[1], rgba[2], rgba[3]]
        })
        .collect();
    let outside = {
        let o = overlay_rgba(&[0.0]);
        [o[0], o[1], o[2], o[3]]
    };
    // Spread row by row ([`upscale_tiles`]): a camera's 1140 x 855 frame took 7 ms pixel by
    // pixel, as long as fusing a tenth of it.
    let layout = [probs.rows, probs.cols, probs.tile_px as usize];
    upscale_tiles(&tile_rgba, layout, width, height, outside).into_flattened()
}

/// Viridis (perceptually uniform), sampled at 9 points and interpolated linearly.
const VIRIDIS: [[f32; 3]; 9] = [
    [68.0, 1.0, 84.0],
    [71.0, 44.0, 122.0],
    [59.0, 81.0, 139.0],
    [44.0, 113.0, 142.0],
    [33.0, 144.0, 141.0],
    [39.0, 173.0, 129.0],
    [92.0, 200.0, 99.0],
    [170.0, 220.0, 50.0],
    [253.0, 231.0, 37.0],
];

/// Viridis colour of `t` in [0, 1] (clamped; NaN maps to 0).
pub fn viridis(t: f32) -> [u8; 3] {
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
    let x = t * (VIRIDIS.len() - 1) as f32;
    let i = (x.floor() as usize).min(VIRIDIS.len() - 2);
    let f = x - i as f32;
    let (a, b) = (VIRIDIS[i], VIRIDIS[i + 1]);
    [0, 1, 2].map(|c| (a[c] + (b[c] - a[c]) * f).round() as u8)
}

/// A recording id from the inputs that determine the recording's content: `kind` names the
/// command, `parts` are e.g. the session and model SHA-256 and the options as JSON.
pub fn recording_id(kind: &str, parts: &[&str]) -> String {
    let mut h = Sha256::new();
    h.update(kind.as_bytes());
    for p in parts {
        // Length-prefixed so that ("ab", "c") and ("a", "bc") differ.
        h.update((p.len() as u64).to_le_bytes());
        h.update(p.as_bytes());
    }
    let hex = crate::types::digest::hex(&h.finalize()[..16]);
    format!("{APP_ID}-{kind}-{hex}")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fuse::grid::{GridSpec, logit};
    use crate::types::geometry::iso_from_xy_yaw;

    #[test]
    fn upscale_repeats_tiles_and_leaves_partial_edges_empty() {
        let probs = TileProbs {
            rows: 1,
            cols: 2,
            tile_px: 2,
            p: vec![0.25, 0.75],
        };
        // 5 x 3 image: tiles cover x 0..4, y 0..2; column 4 and row 2 stay 0.
        let up = upscale(&probs, 5, 3);
        assert_eq!(
            up,
            vec![
                0.25, 0.25, 0.75, 0.75, 0.0, 0.25, 0.25, 0.75, 0.75, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
            ]
        );
    }

    #[test]
    fn pyramid_of_the_centre_tile_reaches_the_depth_along_the_axis() {
        // 4 x 4 image, fx = fy = 2, centre (2, 2): the tile (1, 1) of 2 px spans u, v in [2, 4],
        // so its far corners at depth 3 are x, y in {0, 3} (x = (u - 2) / 2 * 3).
        let camera = Camera {
            width: 4,
            height: 4,
            fx: 2.0,
            fy: 2.0,
            cx: 2.0,
            cy: 2.0,
        };
        let probs = TileProbs {
            rows: 2,
            cols: 2,
            tile_px: 2,
            p: vec![0.1, 0.2, 0.3, 0.9],
        };
        let s = pyramids(&camera, &Iso3::identity(), &probs, 0.5, 3.0);
        assert_eq!(
            s.len(),
            5,
            "one tile above 0.5: 4 edges + the far rectangle"
        );
        assert_eq!(s[0].0, vec![[0.0, 0.0, 0.0], [0.0, 0.0, 3.0]]);
        assert_eq!(s[2].0[1], [3.0, 3.0, 3.0]);
        assert_eq!(s[4].0.len(), 5);
        assert_eq!(s[4].0[0], s[4].0[4]);
        assert!(s.iter().all(|(_, p)| *p == 0.9));
        // Moved 1 m along x in odom: every point moves with it.
        let moved = pyramids(&camera, &iso_from_xy_yaw(1.0, 0.0, 0.0), &probs, 0.5, 3.0);
        assert_eq!(moved[2].0[1], [4.0, 3.0, 3.0]);
    }

    /// The shown cells, counted by log-odds and collected from the bins that hold the most
    /// probable, are exactly those a sort of every candidate by log-odds picks: with more
    /// candidates than the cut, ties at the cut (equal log-odds; posteriors that round to 1
    /// in f32, ranked by their log-odds), cells seen too few times, a grid whose sides are not
    /// whole blocks, and a cut that keeps everything.
    #[test]
    fn shown_cells_are_the_most_probable_of_every_candidate() {
        let spec = GridSpec {
            origin_m: [0.0; 3],
            voxel_size_m: 1.0,
            dims: [19, 13, 22],
        };
        let mut grid = Grid::new(spec, 0.02).unwrap();
        let prior = grid.prior_log_odds();
        let mut candidates = Vec::new();
        let mut state = 12345u64;
        for i in 0..19 {
            for j in 0..13 {
                for k in 0..22 {
                    state = state
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    let r = (state >> 33) as u32;
                    // Log-odds -6..40: many saturated (p = 1 in f32), many equal.
                    let l = match r % 4 {
                        0 => 25.0 + (r % 3) as f32,
                        1 => (r % 460) as f32 / 10.0 - 6.0,
                        2 => 1.5,
                        _ => -2.0,
                    };
                    let views = (r >> 8) as u16 % 4;
                    grid.set_cell(spec.index(i, j, k), l - prior, views)
                        .unwrap();
                    let l = prior + (l - prior);
                    if views >= 2 && sigmoid(f64::from(l)) as f32 > 0.5 {
                        candidates.push(([i as i32, j as i32, k as i32], l));
                    }
                }
            }
        }
        assert!(candidates.len() > 1500, "{}", candidates.len());
        for max_cells in [0, 1, 7, 300, 1000, candidates.len(), 100_000] {
            let mut want = candidates.clone();
            most_probable_in_index_order(&mut want, max_cells);
            for c in &mut want {
                c.1 = sigmoid(f64::from(c.1)) as f32;
            }
            let got = summarize_grid(&grid, 0.5, 2, max_cells).cells;
            assert_eq!(got, want, "max_cells {max_cells}");
        }
    }

    #[test]
    fn grid_summary_projections_entropy_and_shown_cells() {
        let spec = GridSpec {
            origin_m: [0.0; 3],
            voxel_size_m: 1.0,
            dims: [2, 1, 2],
        };
        let mut grid = Grid::new(spec, 0.5).unwrap();
        // Cell (1, 0, 1) at p = 0.8 seen twice; cell (0, 0, 0) at p = 0.8 seen once.
        let hi = logit(0.8) as f32;
        let a = spec.index(1, 0, 1);
        let b = spec.index(0, 0, 0);
        // The prior 0.5 is log-odds 0: evidence and log-odds are the same.
        grid.set_cell(a, hi, 2).unwrap();
        grid.set_cell(b, hi, 1).unwrap();
        let s = summarize_grid(&grid, 0.5, 2, usize::MAX);
        assert_eq!(s.cells, vec![([1, 0, 1], 0.8)]);
        assert!((s.max_posterior - 0.8).abs() < 1e-6);
        // H(0.8) = 0.7219 bits, H(0.5) = 1: mean over 4 cells (2 * 0.7219 + 2) / 4.
        assert!(
            (s.mean_entropy_bits - 0.860_964).abs() < 1e-5,
            "{}",
            s.mean_entropy_bits
        );
        // Along z (x wide, y high): x = 0 -> (0.8 + 0.5) / 2, x = 1 -> (0.5 + 0.8) / 2.
        assert!(s.along_z.iter().all(|v| (v - 0.65).abs() < 1e-6));
        // Along y (x wide, z up): top row is k = 1: [0.5, 0.8]; bottom k = 0: [0.8, 0.5].
        let want = [0.5, 0.8, 0.8, 0.5];
        assert!(
            s.along_y
                .iter()
                .zip(want)
                .all(|(v, w)| (v - w).abs() < 1e-6),
            "{:?}",
            s.along_y
        );
        // Along x (y wide = 1, z up): k = 1 -> (0.5 + 0.8) / 2, k = 0 -> (0.8 + 0.5) / 2.
        assert!(s.along_x.iter().all(|v| (v - 0.65).abs() < 1e-6));
    }

    #[test]
    fn a_capped_summary_keeps_the_most_probable_cells_in_index_order() {
        // Out of index order, as the slabs' blocks hand them over.
        let cells = vec![
            ([2, 0, 0], 0.55),
            ([0, 1, 0], 0.7),
            ([0, 0, 0], 0.6),
            ([1, 0, 0], 0.7),
            ([0, 0, 1], 0.9),
        ];
        let kept = |max: usize| {
            let mut c = cells.clone();
            most_probable_in_index_order(&mut c, max);
            c
        };
        assert_eq!(
            kept(5),
            vec![
                ([0, 0, 0], 0.6),
                ([0, 0, 1], 0.9),
                ([0, 1, 0], 0.7),
                ([1, 0, 0], 0.7),
                ([2, 0, 0], 0.55)
            ]
        );
        // 0.9, then the two at 0.7: all three kept, in index order.
        assert_eq!(
            kept(3),
            vec![([0, 0, 1], 0.9), ([0, 1, 0], 0.7), ([1, 0, 0], 0.7)]
        );
        // A tie at the cut goes to the lower index.
        assert_eq!(kept(2), vec![([0, 0, 1], 0.9), ([0, 1, 0], 0.7)]);
        assert!(kept(0).is_empty());
    }

    #[test]
    fn the_slabbed_summary_is_the_cell_by_cell_one() {
        use crate::fuse::grid::{Budget, GridStorage};
        // 19 x 13 x 11 cells: three slabs of x blocks (8, 8 and 3 columns), blocks cut at the
        // far faces. Dense with every cell set, and sparse with only the cells of x >= 9
        // set (its region then starts at x = 8).
        let spec = GridSpec {
            origin_m: [0.0; 3],
            voxel_size_m: 1.0,
            dims: [19, 13, 11],
        };
        for (storage, from_x) in [(GridStorage::Dense, 0), (GridStorage::Sparse, 9)] {
            let mut grid = Grid::with_storage(spec, 0.1, storage, Budget::default()).unwrap();
            for idx in 0..spec.cells() {
                if spec.ijk(idx)[0] >= from_x {
                    let e = ((idx * 37) % 23) as f32 * 0.5 - 3.0;
                    grid.set_cell(idx, e, (idx % 4) as u16).unwrap();
                }
            }
            let s = summarize_grid(&grid, 0.5, 2, usize::MAX);
            let r = s.region;
            assert_eq!(r.first_cell, [from_x / 8 * 8, 0, 0], "{storage:?}");
            let [nx, ny, nz] = spec.dims;
            let (w, h) = (r.dims[0], r.dims[1]);
            let (mut along_z, mut along_x) = (vec![0f64; w * h], vec![0f64; ny * nz]);
            let (mut cells, mut ent, mut max_p) = (Vec::new(), 0.0, 0.0f64);
            for idx in 0..spec.cells() {
                let [i, j, k] = spec.ijk(idx);
                let p = sigmoid(f64::from(grid.log_odds_at(idx)));
                ent += binary_entropy_bits(p);
                max_p = max_p.max(p);
                along_x[(nz - 1 - k) * ny + j] += p / nx as f64;
                if i >= r.first_cell[0] {
                    along_z[(h - 1 - j) * w + i - r.first_cell[0]] += p / nz as f64;
                }
                if p as f32 > 0.5 && grid.views_at(idx) >= 2 {
                    cells.push(([i as i32, j as i32, k as i32], p as f32));
                }
            }
            assert_eq!(s.cells, cells, "{storage:?}");
            assert!((s.mean_entropy_bits - ent / spec.cells() as f64).abs() < 1e-5);
            assert!((s.max_posterior - max_p).abs() < 1e-12);
            let close = |a: &[f32], b: &[f64]| {
                a.len() == b.len()
                    && a.iter()
                        .zip(b)
                        .all(|(a, b)| (f64::from(*a) - b).abs() < 1e-5)
            };
            assert!(close(&s.along_z, &along_z), "{storage:?}");
            assert!(close(&s.along_x, &along_x), "{storage:?}");
        }
    }

    #[test]
    fn posterior_table_is_within_plot_precision_of_the_exact_values() {
        let t = PosteriorTable::new();
        for i in -2000..=2000 {
            let l = i as f32 * 0.0237;
            let p = sigmoid(f64::from(l));
            let (tp, th) = t.get(l);
            assert!((tp - p).abs() < 1e-6, "p at {l}: {tp} vs {p}");
            assert!((th - binary_entropy_bits(p)).abs() < 1e-5, "h at {l}");
        }
        let ends = |e: (f32, f32)| (f64::from(e.0), f64::from(e.1));
        assert_eq!(t.get(f32::NAN), ends(t.at[0]));
        assert_eq!(t.get(f32::NEG_INFINITY), ends(t.at[0]));
        assert!(t.at[0].0 < 3e-9 && t.at[0].1 < 1e-7);
        assert_eq!(t.get(-100.0).0, f64::from(t.at[0].0));
        assert_eq!(t.get(100.0), (1.0, f64::from(t.at[t.at.len() - 1].1)));
        assert_eq!(t.get(f32::INFINITY).0, 1.0);
    }

    #[test]
    fn snapshots_are_every_frame_then_every_kth_and_the_last() {
        let picked = |frames: usize| -> Vec<usize> {
            (0..frames)
                .filter(|&i| is_snapshot(i, frames, 100))
                .collect()
        };
        assert_eq!(picked(8), (0..8).collect::<Vec<_>>());
        assert_eq!(picked(100).len(), 100);
        // 250 frames: k = 3, so 0, 3, ..., 249 (84 of them), and 249 is also the last.
        let p = picked(250);
        assert_eq!(p.len(), 84);
        assert_eq!((p[1], p[83]), (3, 249));
        // 1001 frames: k = 11: 0, 11, ..., 990 (91) and the last, 1000.
        let p = picked(1001);
        assert_eq!(p.len(), 92);
        assert_eq!(*p.last().unwrap(), 1000);
        assert!(picked(100_000).len() <= 101);
    }

    #[test]
    fn a_bigger_grid_gets_fewer_snapshots_down_to_one() {
        // 64 M cells among grids of 1 M (the simulated rooms), 8 M (a real capture's fitted
        // grid) and 100 M cells (more than the budget), at most 50.
        assert_eq!(snapshots_within(64_000_000, 1_000_000, 50), 50);
        assert_eq!(snapshots_within(64_000_000, 8_000_000, 50), 8);
        assert_eq!(snapshots_within(64_000_000, 100_000_000, 50), 1);
        assert_eq!(snapshots_within(64_000_000, 0, 50), 50);
        // 43 frames, 8 snapshots asked for: every 6th frame and the last.
        let n = snapshots_within(64_000_000, 8_000_000, 50);
        let picked: Vec<usize> = (0..43).filter(|&i| is_snapshot(i, 43, n)).collect();
        assert_eq!(picked, vec![0, 6, 12, 18, 24, 30, 36, 42]);
    }

    #[test]
    fn upscaled_rows_are_those_of_a_pixel_by_pixel_lookup() {
        // 3 x 2 tiles of 3 px in a 10 x 11 image: a partial tile column (x 9) and rows 9-10
        // below the tiles stay at the default.
        let values: Vec<u8> = vec![1, 2, 3, 4, 5, 6];
        let up = upscale_tiles(&values, [3, 2, 3], 10, 11, 0);
        let mut want = vec![0u8; 10 * 11];
        for y in 0..9 {
            for x in 0..6 {
                want[y * 10 + x] = values[(y / 3) * 2 + x / 3];
            }
        }
        assert_eq!(up, want);
        assert_eq!(
            (up[0], up[8 * 10 + 5], up[5 * 10 + 3], up[9 * 10]),
            (1, 6, 4, 0)
        );
    }

    #[test]
    fn the_tile_overlay_is_the_pixel_overlay() {
        // 2 x 3 tiles of 4 px in an image 10 px wide and 9 high: a partial tile column and
        // row outside whole tiles.
        let probs = TileProbs {
            rows: 2,
            cols: 2,
            tile_px: 4,
            p: vec![0.1, 0.9, 0.5, 0.0],
        };
        assert_eq!(
            overlay_rgba_of_tiles(&probs, 10, 9),
            overlay_rgba(&upscale(&probs, 10, 9))
        );
    }

    #[test]
    fn overlay_alpha_grows_with_p_and_empty_pixels_are_clear() {
        let o = overlay_rgba(&[0.0, 1.0]);
        assert_eq!(o, vec![68, 1, 84, 0, 253, 231, 37, 220]);
    }
    #[test]
    fn viridis_ends_and_middle() {
        assert_eq!(viridis(0.0), [68, 1, 84]);
        assert_eq!(viridis(1.0), [253, 231, 37]);
        assert_eq!(viridis(0.5), [33, 144, 141]);
        // Halfway between samples 0 and 1: (68+71)/2 = 69.5 -> 70, (1+44)/2 = 22.5 -> 23.
        assert_eq!(viridis(0.0625), [70, 23, 103]);
        assert_eq!(viridis(-3.0), viridis(0.0));
        assert_eq!(viridis(f32::NAN), viridis(0.0));
    }

    #[test]
    fn recording_id_depends_on_every_part() {
        let a = recording_id("fuse", &["ab", "c"]);
        assert_eq!(a, recording_id("fuse", &["ab", "c"]));
        assert_ne!(a, recording_id("fuse", &["a", "bc"]));
        assert_ne!(a, recording_id("train", &["ab", "c"]));
        assert!(a.starts_with("objloc-fuse-"));
        assert_eq!(a.len(), "objloc-fuse-".len() + 32);
    }
}
