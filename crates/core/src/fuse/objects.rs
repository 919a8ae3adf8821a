//! Objects from the belief: confident cells grouped into 26-connected components.
//!
//! A fixed posterior threshold (0.5) fails: a cell on one positive pyramid that no other view
//! contradicts already sits far above 0.5, so whole pyramids survive as blobs far from the
//! object. What sets the object apart is that every view that saw it agrees: its evidence
//! (log-odds above the prior) is near the sum of all its views' positive evidence, while a
//! cell where only some pyramids cross collects much less. So the rule is relative to the
//! grid's strongest evidence: components grow by hysteresis from seeds at `seed_fraction` of
//! the peak through cells at `grow_fraction` of it, among cells seen by at least `min_views`
//! frames. Being relative, it does not depend on the classifier's calibration or on the
//! number of frames. The defaults were chosen by measurement on the shipped tours (see
//! docs/fuser.md).
//!
//! Invariants: pure function of the grid's cells (not of which blocks it stores);
//! components are found in flat index order, so the output order is deterministic. No I/O.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::fuse::grid::blocks::{BLOCK, BLOCK_CELLS, cell_offset};
use crate::fuse::grid::{Grid, for_each_cell, sigmoid};

/// The rule that turns the belief into objects (see the module doc): hysteresis on evidence
/// relative to the grid's peak, among cells seen often enough.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ObjectParams {
    /// Frames that must have seen a cell before it can belong to an object.
    pub min_views: u16,
    /// Evidence (log-odds above the prior), as a fraction of the grid's highest, that a
    /// component must reach somewhere.
    pub seed_fraction: f32,
    /// Evidence, as a fraction of the grid's highest, every cell of a component must have.
    pub grow_fraction: f32,
    /// Components with fewer cells are dropped as noise. 4 (was 8 until 2026-12-02): a 15 cm
    /// duck seen from 1.3-1.6 m holds 6 cells at the grow fraction of its peak; measured on
    /// the shipped, held-out-style and foreign tours, no component of 4-7 cells became a
    /// spurious object (docs/fuser.md, Objects).
    pub min_cells: usize,
    /// A component whose centroid lies inside the bounding box of a larger one is a
    /// fragment of it (a chair's legs below its seat), not an object of its own.
    #[serde(default = "yes")]
    pub merge_nested: bool,
}

fn yes() -> bool {
    true
}

impl Default for ObjectParams {
    fn default() -> Self {
        Self {
            min_views: 4,
            seed_fraction: 0.75,
            grow_fraction: 0.7,
            min_cells: 4,
            merge_nested: true,
        }
    }
}

/// One located object.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Object {
    /// The object's location in `odom`, metres: along each axis, the midpoint between the
    /// `EXTENT_TRIM` and 1 - `EXTENT_TRIM` quantiles of the object's probability mass (the
    /// centre of its extent, robust to a stray cell at an end). Not the mean: the mean of a
    /// faithful chair (seat, back, four thin legs) lies 0.11 m from the centre of the chair's
    /// box, towards the heavy back; see docs/fuser.md for the measurement.
    pub centroid_m: [f64; 3],
    /// Probability-weighted mean of the object's cell centres in `odom`, metres (its centre
    /// of mass). Pose refinement and nesting use this: it is where the views' rays meet.
    pub mass_centroid_m: [f64; 3],
    /// Min corner of the axis-aligned box around the object's cells (their faces), `odom`, metres.
    pub bbox_min_m: [f64; 3],
    /// Max corner of that box, `odom`, metres.
    pub bbox_max_m: [f64; 3],
    /// Grid cells in the object (at least [`ObjectParams::min_cells`]).
    pub cells: usize,
    /// Highest posterior probability among its cells, in [0, 1].
    pub peak_probability: f64,
    /// Mean posterior probability of its cells, in [0, 1]; times `cells`, the object's probability
    /// mass (objects are sorted by it).
    pub mean_probability: f64,
    /// Highest log-odds in the component (probabilities saturate at 1 in print).
    pub peak_log_odds: f64,
    /// Set when `centroid_m` is the centre triangulated from the boxes of the object's
    /// detections rather than the centre of its extent (a session without /cmd_vel, or
    /// `--locate detections`: [`crate::fuse::locate`]); how the rays met.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub from_detections: Option<crate::fuse::locate::RayCentre>,
    /// The centre of the extent that `from_detections` replaced, metres.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extent_centre_m: Option<[f64; 3]>,
    /// Why the detections did not locate the object when they were asked to (the location
    /// is then the extent's centre).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub not_from_detections: Option<String>,
}

/// Fraction of an object's probability mass left out at each end of each axis when its
/// location is the centre of its extent. Measured against the true box centres of 38 objects
/// in 28 sessions (the shipped tours and 24 held-out-style ones, default options;
/// docs/fuser.md): mean error 0.063 m (worst 0.116) for the mass centroid; for the extent's
/// centre 0.036 m untrimmed (worst 0.101: one stray end cell), 0.036 m at 1 % (worst 0.081),
/// 0.039 m at 2 %, 0.043 m at 3 % (worst 0.081 both).
pub const EXTENT_TRIM: f64 = 0.01;

/// Cell state while labelling.
const NONE: u8 = 0;
const GROW: u8 = 1;
const DONE: u8 = 2;

/// Finds the objects in `grid`, largest probability mass first.
pub fn find_objects(grid: &Grid, params: &ObjectParams) -> Vec<Object> {
    find_objects_with_cells(grid, params)
        .into_iter()
        .map(|(o, _)| o)
        .collect()
}

/// Per stored block (in [`Grid::par_blocks`] order), the highest evidence (log-odds above
/// the prior) of a cell seen by at least `min_views` frames, or 0 when none is above the
/// prior; their maximum is the grid's peak, and a block whose own is below the grow level
/// holds no candidate.
fn block_peaks(grid: &Grid, min_views: u16) -> Vec<f32> {
    // Eight running maxima per block over zipped slices (evidence is never NaN, and a maximum
    // does not depend on the order it is taken in), so the compiler can vectorise the pass:
    // it runs over every stored cell once per frame during pose refinement. Cells outside the
    // grid (a block's pads) and unstored ones hold 0 and no view: they cannot raise it.
    grid.par_blocks()
        .map(|b| {
            let mut lanes = [0.0f32; 8];
            for (v8, e8) in b.views.chunks_exact(8).zip(b.evidence.chunks_exact(8)) {
                for k in 0..8 {
                    let e = if v8[k] >= min_views { e8[k] } else { 0.0 };
                    if e > lanes[k] {
                        lanes[k] = e;
                    }
                }
            }
            lanes.into_iter().fold(0.0f32, f32::max)
        })
        .collect()
}

/// The labelling state of the stored blocks that hold candidate cells (at least the grow
/// level): one state block per such block, found through its slot.
struct States {
    /// State block of each slot, [`NO_STATE`] when it holds no candidate.
    of_slot: Vec<u32>,
    blocks: Vec<[u8; BLOCK_CELLS]>,
}

const NO_STATE: u32 = u32::MAX;

impl States {
    /// The state of cell (i, j, k), None when its block holds no candidate.
    fn at(&mut self, grid: &Grid, i: usize, j: usize, k: usize) -> Option<&mut u8> {
        let s = self.of_slot[grid.slot_at(i, j, k)];
        (s != NO_STATE).then(|| &mut self.blocks[s as usize][cell_offset(i, j, k)])
    }
}

/// A stored block's candidate cells: its slot, first cell, and each candidate's place in the
/// block and whether it is a seed.
type MarkedBlock = (usize, [usize; 3], Vec<(u16, bool)>);

/// Marks the candidate cells (seen by `min_views`, evidence at least `grow_e`) [`GROW`];
/// returns their states and the seeds (evidence at least `seed_e`), flat indices ascending.
/// `peaks` are [`block_peaks`]: blocks below `grow_e` are not visited.
fn mark(
    grid: &Grid,
    peaks: &[f32],
    min_views: u16,
    grow_e: f32,
    seed_e: f32,
) -> (States, Vec<usize>) {
    let marked: Vec<MarkedBlock> = grid
        .par_blocks()
        .zip(peaks.par_iter())
        .filter(|&(_, &peak)| peak >= grow_e)
        .filter_map(|(b, _)| {
            let mut cells = Vec::new();
            for_each_cell(&b, |o, _| {
                let (v, e) = (b.views[o], b.evidence[o]);
                if v >= min_views && e >= grow_e {
                    cells.push((o as u16, e >= seed_e));
                }
            });
            (!cells.is_empty()).then_some((b.slot, b.first_cell, cells))
        })
        .collect();
    let mut states = States {
        of_slot: vec![NO_STATE; grid.slots()],
        blocks: Vec::with_capacity(marked.len()),
    };
    let mut seeds = Vec::new();
    for (slot, first, cells) in marked {
        states.of_slot[slot] = states.blocks.len() as u32;
        let mut st = [NONE; BLOCK_CELLS];
        for (o, seed) in cells {
            let o = usize::from(o);
            st[o] = GROW;
            if seed {
                let [a, b, c] = [o / (BLOCK * BLOCK), (o / BLOCK) % BLOCK, o % BLOCK];
                seeds.push(grid.spec.index(first[0] + a, first[1] + b, first[2] + c));
            }
        }
        states.blocks.push(st);
    }
    seeds.sort_unstable();
    (states, seeds)
}

/// Like [`find_objects`], with each object's member cells (flat indices, ascending).
pub fn find_objects_with_cells(grid: &Grid, params: &ObjectParams) -> Vec<(Object, Vec<usize>)> {
    let spec = grid.spec;
    let peaks = block_peaks(grid, params.min_views);
    let max_e = peaks.iter().copied().fold(0.0f32, f32::max);
    if max_e <= 0.0 {
        return Vec::new();
    }
    let (seed_e, grow_e) = (params.seed_fraction * max_e, params.grow_fraction * max_e);
    // Seeds in flat index order: components are found in index order, whichever blocks are
    // stored.
    let (mut states, seeds) = mark(grid, &peaks, params.min_views, grow_e, seed_e);
    let [nx, ny, nz] = spec.dims;
    let mut objects = Vec::new();
    let mut stack = Vec::new();
    let mut members = Vec::new();
    for &seed in &seeds {
        let [i, j, k] = spec.ijk(seed);
        match states.at(grid, i, j, k) {
            Some(st) if *st == GROW => *st = DONE,
            _ => continue,
        }
        stack.push(seed);
        members.clear();
        while let Some(idx) = stack.pop() {
            members.push(idx);
            let [i, j, k] = spec.ijk(idx);
            for di in -1i64..=1 {
                for dj in -1i64..=1 {
                    for dk in -1i64..=1 {
                        let (a, b, c) = (i as i64 + di, j as i64 + dj, k as i64 + dk);
                        if a < 0
                            || b < 0
                            || c < 0
                            || a >= nx as i64
                            || b >= ny as i64
                            || c >= nz as i64
                        {
                            continue;
                        }
                        let (a, b, c) = (a as usize, b as usize, c as usize);
                        if let Some(st) = states.at(grid, a, b, c)
                            && *st == GROW
                        {
                            *st = DONE;
                            stack.push(spec.index(a, b, c));
                        }
                    }
                }
            }
        }
        if members.len() < params.min_cells {
            continue;
        }
        members.sort_unstable();
        objects.push((summarize(grid, &members), members.clone()));
    }
    if params.merge_nested {
        // Until nothing merges: a merge grows a box, and a component kept before it (its
        // centroid outside the smaller box then) may lie inside the grown one.
        loop {
            let before = objects.len();
            objects = merge_nested(grid, objects);
            if objects.len() == before {
                break;
            }
        }
    }
    // Instances of one object have similar sizes: a component this much smaller than the
    // largest is a speck of false evidence, not an instance (see MIN_RELATIVE_CELLS).
    let largest = objects.iter().map(|(o, _)| o.cells).max().unwrap_or(0);
    objects.retain(|(o, _)| o.cells * MIN_RELATIVE_CELLS_INV >= largest);
    objects.sort_by(|(a, _), (b, _)| {
        let ma = a.mean_probability * a.cells as f64;
        let mb = b.mean_probability * b.cells as f64;
        mb.total_cmp(&ma)
    });
    objects
}

/// A component with fewer than 1/`MIN_RELATIVE_CELLS_INV` of the largest one's cells is
/// dropped: one object's instances differ in size by less (a partly seen vase still has a
/// good fraction of its twin's cells), false evidence gathers in specks.
pub const MIN_RELATIVE_CELLS_INV: usize = 50;

/// A component with at most 1/`FRAGMENT_RATIO` of a larger one's cells is merged into it
/// when its centroid lies within `FRAGMENT_MARGIN_CELLS` cells of that one's box, or below
/// the box within its footprint: two instances of one object have similar sizes and keep
/// apart however close they stand.
pub const FRAGMENT_RATIO: usize = 5;
/// How far, in cells, beside a larger component's box a fragment's centroid may lie (see
/// [`FRAGMENT_RATIO`]).
///
/// 5 since 2026-12-04 (eleventh session; 3 before): a chair's 2 368-cell piece 4.3 cells
/// beside its 18 335-cell body was a spurious object in a tour taken as a capture; on every
/// robot set the final objects and grids are the same either way (docs/fuser.md, Objects).
pub const FRAGMENT_MARGIN_CELLS: f64 = 5.0;

/// Merges every component whose centroid lies inside the bounding box of a larger one into
/// it. Objects do not nest, so such a component is a fragment cut off by the grow
/// threshold: on the drift tour with refined poses the chair came out as its seat and back
/// plus two clusters of legs, inside the chair's box, counted as two spurious objects. Two
/// objects side by side or one above the other keep their own boxes and stay apart. Larger
/// first (ties: lowest first cell), one pass (the caller repeats it until nothing merges):
/// deterministic.
fn merge_nested(grid: &Grid, mut objects: Vec<(Object, Vec<usize>)>) -> Vec<(Object, Vec<usize>)> {
    let voxel = grid.spec.voxel_size_m;
    objects.sort_by(|(a, ma), (b, mb)| b.cells.cmp(&a.cells).then(ma[0].cmp(&mb[0])));
    let mut kept: Vec<(Object, Vec<usize>)> = Vec::with_capacity(objects.len());
    for (o, members) in objects {
        let within = |k: &Object, a: usize, margin: f64| {
            o.mass_centroid_m[a] >= k.bbox_min_m[a] - margin
                && o.mass_centroid_m[a] <= k.bbox_max_m[a] + margin
        };
        let inside = |k: &Object| {
            if (0..3).all(|a| within(k, a, 0.0)) {
                return true;
            }
            // A much smaller component may also sit just beside the box (a piece of a
            // chair's back cut off by the grow threshold) or anywhere below it, inside its
            // footprint (legs cut off under the seat).
            let margin = FRAGMENT_MARGIN_CELLS * voxel;
            o.cells * FRAGMENT_RATIO <= k.cells
                && within(k, 0, margin)
                && within(k, 1, margin)
                && o.mass_centroid_m[2] <= k.bbox_max_m[2] + margin
        };
        match kept.iter_mut().find(|(k, _)| inside(k)) {
            Some((k, km)) => {
                km.extend_from_slice(&members);
                km.sort_unstable();
                *k = summarize(grid, km);
            }
            None => kept.push((o, members)),
        }
    }
    kept
}

fn summarize(grid: &Grid, members: &[usize]) -> Object {
    let spec = grid.spec;
    let v = spec.voxel_size_m;
    let (mut w, mut c) = (0.0, [0.0; 3]);
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    let mut peak_l = f64::NEG_INFINITY;
    // Probability mass per cell index along each axis, for the extent's quantiles: a
    // histogram, not a sort (objects of 10^5 cells are summarised after every frame).
    let mut along: [Vec<f64>; 3] = std::array::from_fn(|a| vec![0.0; spec.dims[a]]);
    for &idx in members {
        let ijk = spec.ijk(idx);
        let centre = spec.center(ijk[0], ijk[1], ijk[2]);
        let l = f64::from(grid.log_odds_at(idx));
        let p = sigmoid(l);
        peak_l = peak_l.max(l);
        w += p;
        for a in 0..3 {
            c[a] += p * centre[a];
            lo[a] = lo[a].min(centre[a] - v / 2.0);
            hi[a] = hi[a].max(centre[a] + v / 2.0);
            along[a][ijk[a]] += p;
        }
    }
    let centroid_m = std::array::from_fn(|a| {
        let (q_lo, q_hi) = weighted_quantiles(&along[a], w, EXTENT_TRIM);
        spec.origin_m[a] + v * 0.5 * (q_lo + q_hi)
    });
    Object {
        centroid_m,
        mass_centroid_m: [c[0] / w, c[1] / w, c[2] / w],
        bbox_min_m: lo,
        bbox_max_m: hi,
        cells: members.len(),
        peak_probability: sigmoid(peak_l),
        mean_probability: w / members.len() as f64,
        peak_log_odds: peak_l,
        from_detections: None,
        extent_centre_m: None,
        not_from_detections: None,
    }
}

/// Where the cumulative probability mass along one axis (`mass[i]`: the mass of the cells
/// with index i, summed in member order, so a function of the members) reaches `trim` and
/// `1 - trim` of `total`, in cell-face coordinates (cell i spans [i, i + 1]), each cell's mass
/// spread evenly over it: a position between faces, not a whole cell, so the centre of the
/// extent moves continuously with the belief instead of in half-voxel steps. The extreme
/// occupied faces when rounding keeps the sum below.
fn weighted_quantiles(mass: &[f64], total: f64, trim: f64) -> (f64, f64) {
    let first = mass.iter().position(|m| *m > 0.0).unwrap_or(0);
    let last = mass.iter().rposition(|m| *m > 0.0).unwrap_or(0);
    let (lo_mass, hi_mass) = (trim * total, (1.0 - trim) * total);
    let (mut q_lo, mut q_hi) = (None, None);
    let mut cum = 0.0;
    for (i, &p) in mass.iter().enumerate().skip(first) {
        let before = cum;
        cum += p;
        let at = |target: f64| i as f64 + ((target - before) / p).clamp(0.0, 1.0);
        if q_lo.is_none() && cum >= lo_mass && p > 0.0 {
            q_lo = Some(at(lo_mass));
        }
        if q_hi.is_none() && cum >= hi_mass && p > 0.0 {
            q_hi = Some(at(hi_mass));
            break;
        }
    }
    (
        q_lo.unwrap_or(first as f64),
        q_hi.unwrap_or(last as f64 + 1.0),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fuse::grid::GridSpec;

    type Blob = ([usize; 3], [usize; 3], f32, u16);

    fn grid_with(blobs: &[Blob]) -> Grid {
        grid_stored(blobs, crate::fuse::grid::GridStorage::Dense)
    }

    fn grid_stored(blobs: &[Blob], storage: crate::fuse::grid::GridStorage) -> Grid {
        let spec = GridSpec::from_bounds([0.0; 3], [1.0, 1.0, 1.0], 0.05).unwrap();
        let mut g = Grid::with_storage(spec, 0.01, storage, Default::default()).unwrap();
        for &(lo, hi, e, views) in blobs {
            for i in lo[0]..hi[0] {
                for j in lo[1]..hi[1] {
                    for k in lo[2]..hi[2] {
                        g.set_cell(spec.index(i, j, k), e, views).unwrap();
                    }
                }
            }
        }
        g
    }

    /// A sparse grid stores only the blocks of the blobs (one straddles blocks, one touches
    /// the grid's far faces, which cut its blocks): the same objects, cells and numbers.
    #[test]
    fn sparse_and_dense_grids_give_the_same_objects() {
        use crate::fuse::grid::GridStorage;
        let blobs = [
            ([4, 8, 0], [10, 10, 12], 20.0, 6),
            ([4, 4, 4], [10, 8, 6], 20.0, 6),
            ([5, 5, 0], [7, 7, 3], 19.0, 6),
            ([15, 16, 17], [20, 20, 20], 18.0, 5),
        ];
        let dense = grid_stored(&blobs, GridStorage::Dense);
        let sparse = grid_stored(&blobs, GridStorage::Sparse);
        assert!(sparse.stored_cells() < dense.stored_cells() / 2);
        let params = ObjectParams::default();
        let a = find_objects_with_cells(&dense, &params);
        assert_eq!(a.len(), 2);
        assert_eq!(a, find_objects_with_cells(&sparse, &params));
    }

    #[test]
    fn two_blobs_two_objects_with_centroids() {
        let g = grid_with(&[
            ([2, 2, 2], [5, 5, 5], 20.0, 5),
            ([12, 12, 2], [15, 16, 4], 17.0, 4),
        ]);
        let objs = find_objects(&g, &ObjectParams::default());
        assert_eq!(objs.len(), 2);
        // First blob: 27 cells, centre of cells 2..5 = (3 + 0.5) * 0.05.
        assert_eq!(objs[0].cells, 27);
        for a in 0..3 {
            assert!((objs[0].centroid_m[a] - 0.175).abs() < 1e-9);
            assert!((objs[0].bbox_min_m[a] - 0.10).abs() < 1e-9);
            assert!((objs[0].bbox_max_m[a] - 0.25).abs() < 1e-9);
        }
        assert_eq!(objs[1].cells, 3 * 4 * 2);
        assert!((objs[1].centroid_m[1] - 0.7).abs() < 1e-9);
    }

    #[test]
    fn extent_quantiles_skip_a_stray_end_cell() {
        let close =
            |a: (f64, f64), b: (f64, f64)| (a.0 - b.0).abs() < 1e-9 && (a.1 - b.1).abs() < 1e-9;
        // Ten layers of ten cells at p = 1, then one stray cell at p = 0.5 far out.
        let mut mass = vec![0.0; 50];
        for m in &mut mass[10..20] {
            *m = 10.0;
        }
        mass[40] = 0.5;
        let total = 100.5;
        // 1 % of the mass is 1.005, a tenth of layer 10's 10 (face 10.1005); 99 % is 99.495,
        // 9.495 of layer 19's 10 beyond the 90 before it (face 19.9495).
        let q = weighted_quantiles(&mass, total, 0.01);
        assert!(close(q, (10.1005, 19.9495)), "{q:?}");
        // Untrimmed, the stray cell's far face is the extent's end.
        let q = weighted_quantiles(&mass, total, 0.0);
        assert!(close(q, (10.0, 41.0)), "{q:?}");
        // Mass concentrated at one end moves the quantiles: layers 10-19 of 1 each and 20/7
        // more at layer 19 (total 90/7); 20 % is 18/7, 4/7 into layer 12; 80 % is 72/7, 9/7
        // into layer 19's 27/7, a third of it.
        let mut skew = vec![0.0; 30];
        for m in &mut skew[10..20] {
            *m = 1.0;
        }
        skew[19] += 20.0 / 7.0;
        let total: f64 = skew.iter().sum();
        let q = weighted_quantiles(&skew, total, 0.2);
        assert!(close(q, (12.0 + 4.0 / 7.0, 19.0 + 1.0 / 3.0)), "{q:?}");
    }

    #[test]
    fn a_speck_far_smaller_than_the_object_is_not_an_instance() {
        // A 10 x 10 x 10 object (1000 cells) and, apart from it, a 4-cell speck as strong:
        // 4 * 50 < 1000, dropped; a 20-cell blob (20 * 50 = 1000) is kept as an instance.
        let speck = grid_with(&[
            ([0, 0, 0], [10, 10, 10], 20.0, 6),
            ([15, 15, 15], [17, 17, 16], 20.0, 6),
        ]);
        assert_eq!(find_objects(&speck, &ObjectParams::default()).len(), 1);
        let blob = grid_with(&[
            ([0, 0, 0], [10, 10, 10], 20.0, 6),
            ([15, 15, 15], [20, 17, 17], 20.0, 6),
        ]);
        let objs = find_objects(&blob, &ObjectParams::default());
        assert_eq!(objs.iter().map(|o| o.cells).collect::<Vec<_>>(), [1000, 20]);
    }

    #[test]
    fn single_view_and_weak_blobs_are_not_objects() {
        let g = grid_with(&[
            // Strong but seen by one view only: one pyramid.
            ([2, 2, 2], [5, 5, 5], 20.0, 1),
            // Seen by many but below the grow fraction (8 / 20) everywhere.
            ([10, 10, 10], [14, 14, 14], 8.0, 6),
            // The peak that sets the scale, seen often enough but too small to count: 3 cells.
            ([17, 17, 17], [18, 18, 20], 20.0, 6),
        ]);
        assert!(find_objects(&g, &ObjectParams::default()).is_empty());
    }

    #[test]
    fn a_fragment_inside_a_larger_box_is_merged_and_stacked_objects_are_not() {
        let g = grid_with(&[
            // A chair: back from the floor up (with its back legs) ...
            ([4, 8, 0], [10, 10, 12], 20.0, 6),
            // ... the seat ...
            ([4, 4, 4], [10, 8, 6], 20.0, 6),
            // ... and a front leg below the seat, cut off from it at k = 3: inside the box.
            ([5, 5, 0], [7, 7, 3], 19.0, 6),
        ]);
        let merged = find_objects(&g, &ObjectParams::default());
        assert_eq!(merged.len(), 1);
        assert_eq!(merged[0].cells, 6 * 2 * 12 + 6 * 4 * 2 + 12);
        // Location = centre of the extent, the 1 % and 99 % points of the mass per axis
        // within their layers (faces: cell n spans [n, n + 1]). 1 % of 204 cells is 2.04,
        // 99 % is 201.96. Layers along i 4..=9 hold 32, 38, 38, 32, 32, 32: 4 + 2.04 / 32
        // and 9 + (201.96 - 172) / 32, midpoint 7. Along j 4..=9 (seat 12, leg 6, back 72):
        // 12, 18, 18, 12, 72, 72: 4 + 2.04 / 12 and 9 + (201.96 - 132) / 72. Along k 0..=11:
        // 16, 16, 16, 12, 36, 36, then 12 each: 2.04 / 16 and 11 + (201.96 - 192) / 12. The
        // mass centroid leans towards the heavy back (j: 1554 / 204 = 7.62 cell centres),
        // down to the seat (k: 5.0) and towards the leg's side (i: (192 * 6.5 + 12 * 5.5) /
        // 204). Probabilities are 1 within 6e-7.
        let at = |c: f64| (c + 0.5) * 0.05;
        let mid = |lo: f64, hi: f64| 0.5 * (lo + hi) * 0.05;
        let (loc, mass) = (merged[0].centroid_m, merged[0].mass_centroid_m);
        let want_loc = [
            mid(4.0 + 2.04 / 32.0, 9.0 + 29.96 / 32.0),
            mid(4.0 + 2.04 / 12.0, 9.0 + 69.96 / 72.0),
            mid(2.04 / 16.0, 11.0 + 9.96 / 12.0),
        ];
        assert!((want_loc[0] - 0.35).abs() < 1e-12);
        for (got, want) in loc.iter().zip(want_loc) {
            assert!((got - want).abs() < 1e-6, "{loc:?} {want_loc:?}");
        }
        for (got, want) in mass
            .iter()
            .zip([at(1314.0 / 204.0), at(1554.0 / 204.0), at(5.0)])
        {
            assert!((got - want).abs() < 1e-6, "{mass:?}");
        }
        assert!((merged[0].bbox_min_m[2] - 0.0).abs() < 1e-9);
        let apart = find_objects(
            &g,
            &ObjectParams {
                merge_nested: false,
                ..ObjectParams::default()
            },
        );
        assert_eq!(apart.len(), 2);
        // One box above another (a shelf): neither centroid lies in the other's box.
        let g = grid_with(&[
            ([4, 4, 1], [8, 8, 5], 20.0, 6),
            ([4, 4, 8], [8, 8, 12], 20.0, 6),
        ]);
        assert_eq!(find_objects(&g, &ObjectParams::default()).len(), 2);
    }

    /// Larger first, one pass, leaves a component that lies inside a box only once a smaller
    /// fragment has grown it: a table top A (400 cells, k 8..12), a block B under it (200
    /// cells, k 3..5: too large to be a fragment of A, its centroid below A's box), a leg
    /// piece C (8 cells, k 0..2, in A's footprint: a fragment). B is tested before C and kept;
    /// C then grows A's box down to k = 0, which holds B's centroid. Merging until nothing
    /// merges gives one object, as the rule says it should be whatever the order.
    #[test]
    fn merging_repeats_until_a_grown_box_holds_nothing_more() {
        let g = grid_with(&[
            ([0, 0, 8], [10, 10, 12], 20.0, 6),
            ([0, 0, 3], [10, 10, 5], 20.0, 6),
            ([4, 4, 0], [6, 6, 2], 20.0, 6),
        ]);
        let objs = find_objects(&g, &ObjectParams::default());
        assert_eq!(objs.len(), 1);
        assert_eq!(objs[0].cells, 400 + 200 + 8);
        // One pass alone: A with C, and B apart.
        let one_pass = merge_nested(
            &g,
            find_objects_with_cells(
                &g,
                &ObjectParams {
                    merge_nested: false,
                    ..ObjectParams::default()
                },
            ),
        );
        let mut cells: Vec<usize> = one_pass.iter().map(|(o, _)| o.cells).collect();
        cells.sort_unstable();
        assert_eq!(cells, [200, 408]);
    }

    #[test]
    fn a_small_piece_just_outside_a_box_is_merged_and_a_larger_one_is_not() {
        // A chair (6 x 6 x 12 = 432 cells) and, one cell beyond its box, a piece of its back
        // of 1 x 2 x 4 = 8 cells (centroid 1.5 cells out), cut off by the grow threshold.
        let chair = ([4, 4, 0], [10, 10, 12], 20.0, 6);
        let g = grid_with(&[chair, ([11, 4, 6], [12, 6, 10], 20.0, 6)]);
        let objs = find_objects(&g, &ObjectParams::default());
        assert_eq!(objs.len(), 1);
        assert_eq!(objs[0].cells, 432 + 8);
        // Three cells beyond (centroid 3.5 cells out, within the 5-cell margin): merged too,
        // also when it is no speck (1 x 3 x 4 = 12 cells, 12 * 50 >= 432).
        let g = grid_with(&[chair, ([13, 4, 6], [14, 7, 10], 20.0, 6)]);
        let objs = find_objects(&g, &ObjectParams::default());
        assert_eq!(objs.len(), 1);
        assert_eq!(objs[0].cells, 432 + 12);
        // Five cells beyond (centroid 5.5 cells out): an object of its own once it is no
        // speck; at 8 cells it is one.
        let g = grid_with(&[chair, ([15, 4, 6], [16, 7, 10], 20.0, 6)]);
        assert_eq!(find_objects(&g, &ObjectParams::default()).len(), 2);
        let g = grid_with(&[chair, ([15, 4, 6], [16, 6, 10], 20.0, 6)]);
        assert_eq!(find_objects(&g, &ObjectParams::default()).len(), 1);
        // As close, but 1 x 10 x 12 = 120 cells, over a fifth of the chair: not a fragment.
        let g = grid_with(&[chair, ([11, 2, 0], [12, 12, 12], 20.0, 6)]);
        assert_eq!(find_objects(&g, &ObjectParams::default()).len(), 2);
        // Legs cut off under a seat that floats at k = 8..12: merged however far below;
        // the same piece above the seat is not.
        let seat = ([4, 4, 8], [10, 10, 12], 20.0, 6);
        let leg = ([5, 5, 0], [7, 7, 4], 20.0, 6);
        let g = grid_with(&[seat, leg]);
        assert_eq!(find_objects(&g, &ObjectParams::default()).len(), 1);
        let g = grid_with(&[
            ([4, 4, 0], [10, 10, 4], 20.0, 6),
            ([5, 5, 10], [7, 7, 14], 20.0, 6),
        ]);
        assert_eq!(find_objects(&g, &ObjectParams::default()).len(), 2);
    }

    #[test]
    fn hysteresis_grows_from_the_seed_through_weaker_cells() {
        let g = grid_with(&[
            ([2, 2, 2], [4, 4, 4], 20.0, 5),
            // 14.5 / 20 = 0.725 of the peak: above the grow fraction (0.7), below the seed
            // fraction (0.75).
            ([4, 2, 2], [8, 4, 4], 14.5, 5),
            // Same strength but not connected: no seed of its own, so not an object.
            ([12, 12, 12], [16, 16, 16], 14.5, 5),
        ]);
        let objs = find_objects(&g, &ObjectParams::default());
        assert_eq!(objs.len(), 1);
        assert_eq!(objs[0].cells, 8 + 16);
    }
}
