//! The fuse report: JSON whose schema is `schemas/report.schema.json`.
//!
//! Invariants: everything but `timing_ms` is a pure function of the session, model and
//! options (so two replays' reports differ only in timing); `grid.sha256` hashes the grid's
//! log-odds bytes; `origin_m` is the min corner of cell (0, 0, 0).

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::fuse::objects::Object;
use crate::fuse::replay::{FrameSummary, FuseOptions, Outcome, RefinementCheck};

/// 2: objects carry `mass_centroid_m`, and `centroid_m` is the centre of the object's
/// extent (in version 1 it was the mass centroid).
pub const REPORT_VERSION: u32 = 2;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GridReport {
    pub dims: [usize; 3],
    pub voxel_size_m: f64,
    pub origin_m: [f64; 3],
    pub prior: f64,
    /// SHA-256 of the log-odds as little-endian f32 in C order.
    pub sha256: String,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Report {
    pub report_version: u32,
    pub objloc_version: String,
    pub session: String,
    pub session_sha256: String,
    pub model: String,
    pub model_sha256: String,
    /// Frames fused.
    pub frames: usize,
    pub frames_in_session: usize,
    pub options: FuseOptions,
    pub grid: GridReport,
    pub objects: Vec<Object>,
    /// Flat indices (C order) of the cells of all objects: the thresholded belief.
    pub object_cells: Vec<usize>,
    pub per_frame: Vec<FrameSummary>,
    /// When poses were refined: the check of the refined replay against /odom, and whether
    /// it was rolled back.
    #[serde(default)]
    pub refinement: Option<RefinementCheck>,
    pub warnings: Vec<String>,
    /// Wall-clock milliseconds per stage: informational, the only field that varies.
    pub timing_ms: BTreeMap<String, f64>,
}

/// SHA-256 of a file, hex.
pub fn file_sha256(path: &Path) -> std::io::Result<String> {
    Ok(crate::types::digest::sha256_hex(&std::fs::read(path)?))
}

impl Report {
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
            grid: GridReport {
                dims: g.spec.dims,
                voxel_size_m: g.spec.voxel_size_m,
                origin_m: g.spec.origin_m,
                prior: g.prior,
                sha256: g.sha256_hex(),
            },
            objects: outcome.objects.clone(),
            object_cells: outcome.object_cells.clone(),
            per_frame: outcome.per_frame.clone(),
            refinement: outcome.refinement.clone(),
            warnings: outcome.warnings.clone(),
            timing_ms,
        }
    }

    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_default()
    }
}
