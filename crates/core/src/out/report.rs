//! The fuse report: JSON whose schema is `schemas/report.schema.json`.
//!
//! Invariants: everything but `timing_ms` is a pure function of the session, model and
//! options (so two replays' reports differ only in timing); `grid.sha256` hashes the grid's
//! contents ([`crate::fuse::grid::Grid::sha256_hex`]), whether it is stored dense or sparse;
//! `origin_m` is the min corner of cell (0, 0, 0).

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::fuse::grid::{GridStorage, Region};
use crate::fuse::objects::Object;
use crate::fuse::replay::{FrameSummary, FuseOptions, Outcome, RefinementCheck};

/// 2: objects carry `mass_centroid_m`, and `centroid_m` is the centre of the object's
/// extent (in version 1 it was the mass centroid).
pub const REPORT_VERSION: u32 = 2;

/// The final belief grid: its geometry, prior and a hash of its contents.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GridReport {
    /// Cells along x, y and z: [nx, ny, nz], each at least 1.
    pub dims: [usize; 3],
    /// Edge of a cubic cell, m.
    pub voxel_size_m: f64,
    /// Min corner of cell (0, 0, 0) in `odom`, m; cell (i, j, k) has min corner origin + voxel *
    /// (i, j, k).
    pub origin_m: [f64; 3],
    /// Prior probability of every cell, strictly inside (0, 1): where each cell's belief starts.
    pub prior: f64,
    /// SHA-256 of the grid's contents: for each 8 x 8 x 8 block (ascending block index) with
    /// a non-zero evidence or view, the block index (u64), its evidence (log-odds above the
    /// prior's, f32) and views (u16), little-endian (`Grid::sha256_hex`). Equal for a dense
    /// and a sparse grid holding the same cells. (Before 2026-12-03, the log-odds in C order.)
    pub sha256: String,
    /// How the grid was stored: `dense` (every block) or `sparse` (the blocks the views and
    /// the blur reached); absent from older reports (dense).
    #[serde(default)]
    pub storage: Option<GridStorage>,
    /// Cells in stored blocks (8 x 8 x 8 each, counted whole).
    #[serde(default)]
    pub stored_cells: u64,
    /// The cells `fuse --grid` writes: the box of the stored blocks (the whole grid when
    /// dense), and the min corner of its first cell.
    #[serde(default)]
    pub export: Option<GridExport>,
}

/// Where the `.npy` of `fuse --grid` lies in the grid.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GridExport {
    /// Cell (i, j, k) of the grid that is the array's [0, 0, 0].
    pub first_cell: [usize; 3],
    /// The array's shape: cells along x, y, z (all 0 when nothing is stored).
    pub dims: [usize; 3],
    /// Min corner of the array's cell [0, 0, 0] in `odom`, m: `origin_m + voxel_size_m *
    /// first_cell`.
    pub origin_m: [f64; 3],
}

impl GridExport {
    /// The export of `region` of a grid with min corner `origin_m` and cells of
    /// `voxel_size_m`.
    pub fn new(region: &Region, origin_m: [f64; 3], voxel_size_m: f64) -> Self {
        Self {
            first_cell: region.first_cell,
            dims: region.dims,
            origin_m: std::array::from_fn(|a| {
                origin_m[a] + voxel_size_m * region.first_cell[a] as f64
            }),
        }
    }
}

/// The fuse report (`objloc fuse --report`); schema `schemas/report.schema.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Report {
    /// Report format version: [`REPORT_VERSION`].
    pub report_version: u32,
    /// Version of the objloc that wrote the report.
    pub objloc_version: String,
    /// Path of the replayed session.
    pub session: String,
    /// Hex SHA-256 of the session file.
    pub session_sha256: String,
    /// Path of the model file.
    pub model: String,
    /// Hex SHA-256 of the model file.
    pub model_sha256: String,
    /// Frames fused.
    pub frames: usize,
    /// Frames in the session, fused or not.
    pub frames_in_session: usize,
    /// The fusion options used, fitted to the session (`bounds_m` null = derived from the
    /// trajectory; `prior` null = the model's base rate).
    pub options: FuseOptions,
    /// What the session chose where the options left it free, and why, one line each (empty
    /// for a ground robot's session with the defaults).
    #[serde(default)]
    pub fitted: Vec<String>,
    /// The final belief grid.
    pub grid: GridReport,
    /// Located objects, largest probability mass first (weaker instances after the others).
    pub objects: Vec<Object>,
    /// Flat indices (C order) of the cells of all objects: the thresholded belief.
    pub object_cells: Vec<usize>,
    /// One summary per fused frame, in fusion order: the pose used, the cells updated and the
    /// objects after it.
    pub per_frame: Vec<FrameSummary>,
    /// When poses were refined: the check of the refined replay against /odom, and whether
    /// it was rolled back.
    #[serde(default)]
    pub refinement: Option<RefinementCheck>,
    /// Warnings raised during the replay, for a human reader.
    pub warnings: Vec<String>,
    /// Wall-clock milliseconds per stage: informational, the only field that varies.
    pub timing_ms: BTreeMap<String, f64>,
}

/// `x` to `digits` significant digits, trailing zeros dropped, for a person to read: a fitted
/// voxel of 0.042032799621501124 session units prints as 0.042033, a metric 0.04 as 0.04
/// (the report keeps every digit).
pub fn significant(x: f64, digits: i32) -> String {
    if x == 0.0 || !x.is_finite() {
        return x.to_string();
    }
    let decimals = (digits - 1 - x.abs().log10().floor() as i32).max(0) as usize;
    let s = format!("{x:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_owned()
    } else {
        s
    }
}

/// SHA-256 of a file, hex.
pub fn file_sha256(path: &Path) -> std::io::Result<String> {
    crate::types::digest::sha256_hex_of_reader(std::fs::File::open(path)?)
}

/// A report `fuse` could not have written ([`Report::check`]): what is wrong, in words.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("inconsistent report: {0}")]
pub struct ReportInconsistent(pub String);

impl Report {
    /// The report of a replay's `outcome` fused with `options`; `session` and `model` are paths,
    /// the hashes hex SHA-256 of their files.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        outcome: &Outcome,
        options: &FuseOptions,
        session: &str,
        session_sha256: String,
        model: &str,
        model_sha256: String,
        timing_ms: BTreeMap<String, f64>,
    ) -> Self {
        let g = &outcome.grid;
        Self {
            report_version: REPORT_VERSION,
            objloc_version: env!("CARGO_PKG_VERSION").to_owned(),
            session: session.to_owned(),
            session_sha256,
            model: model.to_owned(),
            model_sha256,
            frames: outcome.frames_fused,
            frames_in_session: outcome.data.frames.len(),
            options: options.clone(),
            fitted: outcome.choices.clone(),
            grid: GridReport {
                dims: g.spec.dims,
                voxel_size_m: g.spec.voxel_size_m,
                origin_m: g.spec.origin_m,
                prior: g.prior,
                sha256: g.sha256_hex(),
                storage: Some(g.storage()),
                stored_cells: g.stored_cells() as u64,
                export: Some(GridExport::new(
                    &g.occupied_region(),
                    g.spec.origin_m,
                    g.spec.voxel_size_m,
                )),
            },
            objects: outcome.objects.clone(),
            object_cells: outcome.object_cells.clone(),
            per_frame: outcome.per_frame.clone(),
            refinement: outcome.refinement.clone(),
            warnings: outcome.warnings.clone(),
            timing_ms,
        }
    }

    /// Whether the report is one `fuse` could have written, and what is wrong when not: a
    /// grid within fuse's limits, object cells inside it (ascending, each once), frames in
    /// order and within the session, unverified frames among them. What reads a report
    /// (`eval`) checks this first, so an edited or damaged one is an error, not a silently
    /// wrong score.
    pub fn check(&self) -> Result<(), ReportInconsistent> {
        let cells = self.check_grid().map_err(ReportInconsistent)?;
        self.check_cells_and_frames(cells)
            .map_err(ReportInconsistent)
    }

    /// The grid's checks; its nominal cell count.
    fn check_grid(&self) -> Result<u64, String> {
        let g = &self.grid;
        let not_a_grid = || format!("grid.dims {:?} is not a grid fuse can make", g.dims);
        if g.dims.contains(&0) {
            return Err(not_a_grid());
        }
        // fuse's own limit: the block table (4 bytes a block) within MAX_GRID_BYTES.
        let blocks = g
            .dims
            .iter()
            .try_fold(1u64, |n, &d| n.checked_mul(d.div_ceil(8) as u64))
            .filter(|&b| b.saturating_mul(4) <= crate::fuse::grid::MAX_GRID_BYTES)
            .ok_or_else(not_a_grid)?;
        let cells = g.dims.iter().map(|&d| d as u64).product::<u64>();
        let finite_grid = g.voxel_size_m.is_finite()
            && g.voxel_size_m > 0.0
            && g.origin_m.iter().all(|x| x.is_finite());
        if !(finite_grid && g.prior > 0.0 && g.prior < 1.0) {
            return Err(format!(
                "grid voxel {} m, origin {:?}, prior {}: not a grid's",
                g.voxel_size_m, g.origin_m, g.prior
            ));
        }
        // Stored blocks are counted whole, so they may reach past the grid's far faces.
        if g.stored_cells > blocks * 512 {
            return Err(format!(
                "grid.stored_cells {} exceeds the {} cells of a {:?} grid's blocks",
                g.stored_cells,
                blocks * 512,
                g.dims
            ));
        }
        Ok(cells)
    }

    /// The object cells' and the frames' checks, in a grid of `cells` cells.
    fn check_cells_and_frames(&self, cells: u64) -> Result<(), String> {
        if let Some(c) = self.object_cells.iter().find(|&&c| c as u64 >= cells) {
            return Err(format!(
                "object_cells holds cell {c}, outside the {cells} cells of a {:?} grid",
                self.grid.dims
            ));
        }
        if let Some(w) = self.object_cells.windows(2).find(|w| w[1] <= w[0]) {
            return Err(format!(
                "object_cells holds cell {} after {}: not ascending, each once",
                w[1], w[0]
            ));
        }
        let n = self.frames_in_session;
        let mut last: Option<usize> = None;
        for f in &self.per_frame {
            if f.index >= n {
                return Err(format!(
                    "per_frame index {} is beyond the session's {n} frames",
                    f.index
                ));
            }
            if let Some(l) = last.filter(|&l| f.index <= l) {
                return Err(format!(
                    "per_frame index {} after {l}: frames out of order",
                    f.index
                ));
            }
            last = Some(f.index);
        }
        let fused: Vec<usize> = self.per_frame.iter().map(|f| f.index).collect();
        let unverified = self.refinement.iter().flat_map(|r| &r.detections_only);
        if let Some(i) = unverified
            .into_iter()
            .find(|i| fused.binary_search(i).is_err())
        {
            return Err(format!(
                "refinement.detections_only names frame {i}, which per_frame does not hold"
            ));
        }
        Ok(())
    }

    /// Writes the report as pretty-printed JSON to `w`, without holding the text (a
    /// 5 000-frame report is 6.6 MB of it); an error if it does not serialize.
    pub fn write_json(&self, w: &mut dyn std::io::Write) -> std::io::Result<()> {
        serde_json::to_writer_pretty(w, self).map_err(std::io::Error::from)
    }
}

#[cfg(test)]
mod tests {
    use super::significant;

    #[test]
    fn numbers_print_to_a_few_significant_digits() {
        assert_eq!(significant(0.042032799621501124, 5), "0.042033");
        assert_eq!(significant(0.04, 5), "0.04");
        assert_eq!(significant(2.9561e-2, 5), "0.029561");
        assert_eq!(significant(-0.0123456, 3), "-0.0123");
        assert_eq!(significant(12.5, 5), "12.5");
        assert_eq!(significant(123456.0, 5), "123456");
        assert_eq!(significant(0.0, 5), "0");
    }
}
