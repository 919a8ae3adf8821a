//! The trained tile classifier as a file: versioned JSON with the feature spec, tile size,
//! tree (or forest), the fuser's prior (`base_rate`) and how it was trained; plus per-frame
//! prediction. A model has two heads: its own tree or forest (the tile head, the fuser's
//! evidence) and, nested, the region head that `predict` answers with (see
//! [`Model::region`]). Training one: [`crate::learn::training`].
//!
//! Invariants: a model that loads has version [`MODEL_VERSION`] (a forest) or
//! [`MODEL_VERSION_ONE_TREE`] (one tree, no `trees`), a feature kind whose bin count equals
//! every tree's feature count, a tile size in [`TILE_PX_RANGE`], a base rate strictly inside
//! (0, 1) and trees that pass [`Tree::validate`], so `predict` cannot panic on it; the same
//! holds for the region head, whose tile size is the model's. Saving
//! goes through `write_atomic`; the JSON holds no clock value, so the same training inputs
//! give the same bytes.

use std::path::{Path, PathBuf};

use image::ImageEncoder;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::learn::dataset::{Augment, LoadedSession, TILE_PX_RANGE};
use crate::learn::features::{
    FeatureSpec, bin_planes, for_each_tile_histogram, tile_histograms, whole_tiles, with_context,
};
use crate::learn::tree::{
    CountTree, FitReport, ForestParams, Metrics, Tree, TreeError, TreeParams, mean_probability,
    metrics,
};
use crate::types::image::Rgb8;
use crate::types::probs::{FrameClassifier, TileProbs};

/// 3: the tile head may be a forest (`trees` beside `tree`). A model of one tree is still
/// written as version 2, which objloc read before forests (so it reads such models as
/// before) and which refuses a forest's file instead of reading its first tree alone.
pub const MODEL_VERSION: u32 = 3;
/// The version of a model whose tile head is one tree. 2: the model may carry a region head
/// (`region`), the tree `predict` answers with.
pub const MODEL_VERSION_ONE_TREE: u32 = 2;
/// Largest neighbourhood radius a model may ask for (a 9 x 9 window of tiles).
pub const MAX_CONTEXT_TILES: u32 = 4;

/// Why a model cannot be loaded, saved, trained or used for prediction.
#[derive(Debug, Error)]
pub enum ModelError {
    /// Reading or writing a file failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// The file is not JSON of a model's layout (or the model does not serialize).
    #[error("{}: not a model file: {source}", path.display())]
    Json {
        /// The file.
        path: PathBuf,
        /// The JSON error.
        #[source]
        source: serde_json::Error,
    },
    /// The file's `version` is neither [`MODEL_VERSION`] nor [`MODEL_VERSION_ONE_TREE`].
    #[error("{}: model version {found} is not supported (this objloc reads versions {MODEL_VERSION_ONE_TREE} and {MODEL_VERSION}); retrain with `objloc train`", path.display())]
    Version {
        /// The model file.
        path: PathBuf,
        /// The version found, or `(none)`.
        found: String,
    },
    /// An inconsistent spec (feature kind, tile size, context radius, base rate, region head), or
    /// frames of different sizes in a session to predict.
    #[error("{}: {what}", path.display())]
    Spec {
        /// The model file, or the session when predicting.
        path: PathBuf,
        /// What is wrong, in words.
        what: String,
    },
    /// The tree (the tile head's or the region head's) fails [`Tree::validate`].
    #[error("{}: invalid tree: {source}", path.display())]
    Tree {
        /// The model file.
        path: PathBuf,
        /// The invariant the tree breaks.
        #[source]
        source: TreeError,
    },
    /// Examples could not be built from the sessions.
    #[error(transparent)]
    Dataset(#[from] crate::learn::dataset::DatasetError),
    /// The tree could not be fitted to the examples.
    #[error("training failed: {0}")]
    Fit(TreeError),
    /// No training examples: no session has a labelled frame.
    #[error("no labelled frames in {sessions} session(s): nothing to train on")]
    NoExamples {
        /// Sessions read.
        sessions: usize,
    },
    /// No training tile is positive: the label rectangles are all smaller than a tile.
    #[error(
        "none of the {examples} training tiles is positive (fully inside a label rectangle): nothing to learn; labelled rectangles must be at least one tile ({tile_px} px) wide and high"
    )]
    NoPositives {
        /// Tiles in the training third.
        examples: usize,
        /// The tile side, px.
        tile_px: u32,
    },
}

/// A training session and the hash of its bytes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SessionHash {
    /// Path of the session, as given to training.
    pub path: String,
    /// Hex SHA-256 of the session file's bytes.
    pub sha256: String,
    /// What reading it said (a truncated file, damage, frames skipped): the model was trained
    /// on what could be read, and says so (absent when nothing was said).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
}

/// Examples of one third and how many of them are positive.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ThirdCount {
    /// Tiles in the third.
    pub examples: usize,
    /// Of them, the tiles lying fully inside a label rectangle.
    pub positives: usize,
}

/// The examples a head was trained on, per third.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ExampleCounts {
    /// Training third of the aligned grid plus the shifted-grid tiles.
    pub train: ThirdCount,
    /// Of `train`, the tiles from shifted grids.
    pub train_shifted: ThirdCount,
    /// Test third (aligned grid only): stops growth and chooses how far it is cut back.
    pub test: ThirdCount,
    /// Pruning third (aligned grid only): decides the top-down pruning.
    pub prune: ThirdCount,
    /// Frames with a label (background frames included) the tiles were cut from.
    pub labelled_frames: usize,
}

/// How a head was trained: its inputs, settings and what fitting did (no clock value).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainingMetadata {
    /// Seed of the stratified shuffle of the aligned-grid tiles into thirds.
    pub seed: u64,
    /// The training sessions, in the order given, with their hashes.
    pub sessions: Vec<SessionHash>,
    /// Labels of this object only (None: every label).
    pub object: Option<String>,
    /// Shift between the extra training grids, px (= `tile_px`: the aligned grid only).
    pub train_stride_px: u32,
    /// How the frames of the shifted grids were altered (absent in older files: none).
    #[serde(default)]
    pub augment: Augment,
    /// The growth and smoothing settings used.
    pub tree_params: TreeParams,
    /// Examples and positives per third.
    pub examples: ExampleCounts,
    /// What growth and pruning did.
    pub fit: FitReport,
    /// The final tree (the forest's mean, for a forest) on the test third.
    pub test_metrics: Metrics,
    /// The same on the pruning third.
    pub prune_metrics: Metrics,
    /// How the forest was grown (absent: one tree, the paper's; `fit` is then its report, and
    /// for a forest its first tree's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub forest: Option<ForestParams>,
}

/// A trained tile classifier as saved in a model file (JSON); see the module doc.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Model {
    /// Model file format version: [`MODEL_VERSION`] for a forest, [`MODEL_VERSION_ONE_TREE`]
    /// for one tree.
    pub version: u32,
    /// The channels of the tile histograms (`rgb332`, `hsv`, `rgb332+texture`, ...).
    pub features: FeatureSpec,
    /// Side of a square tile, px, in [`TILE_PX_RANGE`]; frames are cut into tiles aligned at pixel
    /// (0, 0).
    pub tile_px: u32,
    /// Radius in tiles of the neighbourhood histogram appended to each tile's (0 = none;
    /// absent in models written before it existed).
    #[serde(default)]
    pub context_tiles: u32,
    /// The tile head's probability tree; it reads [`Model::n_features`] features.
    pub tree: Tree,
    /// A forest's further trees, each reading the same features: the head's probability is
    /// the mean of `tree`'s and theirs (empty: the paper's single tree).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub trees: Vec<Tree>,
    /// Fraction of positive training examples: the fuser's prior.
    pub base_rate: f64,
    /// How this head was trained.
    pub metadata: TrainingMetadata,
    /// The region head: a second tree, trained on the same labels with features of the tile's
    /// neighbourhood, that answers the labels' question "is this tile inside the object's
    /// rectangle?" (`predict`'s maps). The outer tree (the tile head) answers "does this tile
    /// show the object?" from the tile's own colours: the evidence the fuser's rays need,
    /// since a ray through a hole in a chair does not meet the chair (docs/tree.md). Same
    /// tile size; a region head has no region head of its own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub region: Option<Box<Model>>,
}

impl FrameClassifier for Model {
    fn classify(&self, img: &Rgb8) -> TileProbs {
        self.predict(img)
    }
    fn base_rate(&self) -> f64 {
        self.base_rate
    }
}

impl Model {
    /// Reads a model file and checks it: version, feature spec, tile size, context radius, base
    /// rate, tree and region head (the module's invariants).
    pub fn load(path: &Path) -> Result<Model, ModelError> {
        let bytes = std::fs::read(path).map_err(|source| ModelError::Io {
            path: path.to_owned(),
            source,
        })?;
        let json = |source| ModelError::Json {
            path: path.to_owned(),
            source,
        };
        // The version is checked before the layout, so an old or future file says so instead
        // of naming a missing field.
        let value: serde_json::Value = serde_json::from_slice(&bytes).map_err(json)?;
        // A fuse report in the model's place is a mix-up of files, not an old model.
        if value.get("report_version").is_some() && value.get("version").is_none() {
            return Err(ModelError::Spec {
                path: path.to_owned(),
                what: "is a fuse report, not a model (`objloc train -o` writes models)".into(),
            });
        }
        match value.get("version").and_then(|v| v.as_u64()) {
            Some(v) if v == MODEL_VERSION as u64 || v == MODEL_VERSION_ONE_TREE as u64 => {}
            other => {
                return Err(ModelError::Version {
                    path: path.to_owned(),
                    found: other.map_or_else(|| "(none)".to_owned(), |v| v.to_string()),
                });
            }
        }
        for head in [Some(&value), value.get("region")].into_iter().flatten() {
            if let Some(f) = head.get("features")
                && let Err(e) = serde_json::from_value::<FeatureSpec>(f.clone())
            {
                return Err(ModelError::Spec {
                    path: path.to_owned(),
                    what: e.to_string(),
                });
            }
        }
        let model: Model = serde_json::from_value(value).map_err(json)?;
        model.check().map_err(|e| match e {
            Ok(what) => ModelError::Spec {
                path: path.to_owned(),
                what,
            },
            Err(source) => ModelError::Tree {
                path: path.to_owned(),
                source,
            },
        })?;
        Ok(model)
    }

    /// Err(Ok(what)) for a spec mismatch, Err(Err(_)) for a broken tree.
    fn check(&self) -> Result<(), Result<String, TreeError>> {
        if !TILE_PX_RANGE.contains(&self.tile_px) {
            return Err(Ok(format!(
                "tile size {} px is outside {}..={} px",
                self.tile_px,
                TILE_PX_RANGE.start(),
                TILE_PX_RANGE.end()
            )));
        }
        if self.context_tiles > MAX_CONTEXT_TILES {
            return Err(Ok(format!(
                "context radius {} tiles is over {MAX_CONTEXT_TILES}",
                self.context_tiles
            )));
        }
        if self.version == MODEL_VERSION_ONE_TREE && !self.trees.is_empty() {
            return Err(Ok(format!(
                "version {MODEL_VERSION_ONE_TREE} is a single tree's, but the model holds {} more",
                self.trees.len()
            )));
        }
        if self.version == MODEL_VERSION && self.trees.is_empty() {
            return Err(Ok(format!(
                "version {MODEL_VERSION} is a forest's, but the model holds one tree"
            )));
        }
        let grown = self.metadata.forest.map_or(1, |f| f.trees as usize);
        if grown != 1 + self.trees.len() {
            return Err(Ok(format!(
                "the metadata says {grown} tree(s) were grown, the model holds {}",
                1 + self.trees.len()
            )));
        }
        for (k, tree) in std::iter::once(&self.tree).chain(&self.trees).enumerate() {
            if tree.n_features != self.n_features() {
                return Err(Ok(format!(
                    "tree {k} has {} features but feature spec {:?} (context {} tiles) has {}",
                    tree.n_features,
                    self.features.name(),
                    self.context_tiles,
                    self.n_features()
                )));
            }
            tree.validate().map_err(|e| match k {
                0 => Err(e),
                // The forest's further trees are named by their index.
                _ => Ok(format!("tree {k}: {e}")),
            })?;
        }
        if !(self.base_rate > 0.0 && self.base_rate < 1.0) {
            return Err(Ok(format!(
                "base rate {} is not strictly between 0 and 1",
                self.base_rate
            )));
        }
        if let Some(region) = &self.region {
            let prefix =
                |e: Result<String, TreeError>| e.map(|what| format!("region head: {what}"));
            if region.region.is_some() {
                return Err(Ok("region head: has a region head of its own".to_owned()));
            }
            if region.version != MODEL_VERSION_ONE_TREE || !region.trees.is_empty() {
                return Err(Ok(format!(
                    "region head: version {} with {} tree(s); a region head is one tree, version {MODEL_VERSION_ONE_TREE}",
                    region.version,
                    1 + region.trees.len()
                )));
            }
            if region.tile_px != self.tile_px {
                return Err(Ok(format!(
                    "region head: tile size {} px differs from the model's {} px",
                    region.tile_px, self.tile_px
                )));
            }
            region.check().map_err(prefix)?;
        }
        Ok(())
    }

    /// Writes the model as pretty-printed JSON with a final newline, atomically.
    pub fn save(&self, path: &Path) -> Result<(), ModelError> {
        let mut text = serde_json::to_string_pretty(self).map_err(|source| ModelError::Json {
            path: path.to_owned(),
            source,
        })?;
        text.push('\n');
        crate::io::output::write_atomic(path, text.as_bytes()).map_err(|source| ModelError::Io {
            path: path.to_owned(),
            source,
        })
    }

    /// Probability per tile of a frame, row-major, tiles aligned at pixel (0,0), partial edge
    /// tiles dropped.
    pub fn predict(&self, img: &Rgb8) -> TileProbs {
        let denom = (self.tile_px * self.tile_px) as f64;
        let trees = self.count_trees(denom);
        let probability = |h: &[u16]| mean_probability(&trees[0], &trees[1..], |t| t.predict(h));
        if self.context_tiles == 0 {
            // Each tile's histogram is needed once: streamed, not kept for the frame.
            let mut p = Vec::new();
            for_each_tile_histogram(
                &bin_planes(img, self.features),
                img.width,
                img.height,
                self.features.bins(),
                self.tile_px,
                |h| p.push(probability(h) as f32),
            );
            return TileProbs {
                rows: whole_tiles(img.height, 0, self.tile_px),
                cols: whole_tiles(img.width, 0, self.tile_px),
                tile_px: self.tile_px,
                p,
            };
        }
        let h = with_context(
            tile_histograms(img, self.features, self.tile_px, 0, 0),
            self.context_tiles,
        );
        let p = (0..h.rows * h.cols)
            .map(|t| probability(h.tile(t)) as f32)
            .collect();
        TileProbs {
            rows: h.rows,
            cols: h.cols,
            tile_px: self.tile_px,
            p,
        }
    }

    /// The head's trees compiled for tile counts out of `denom`, `tree` first.
    fn count_trees(&self, denom: f64) -> Vec<CountTree> {
        std::iter::once(&self.tree)
            .chain(&self.trees)
            .map(|t| CountTree::new(t, denom))
            .collect()
    }

    /// Features the tree reads: the tile's histogram, then the neighbourhood's if any.
    pub fn n_features(&self) -> usize {
        crate::learn::features::feature_count(self.features, self.context_tiles)
    }

    /// A tree feature in words, e.g. "bin 96 (red 96-127, ...)" or, for the neighbourhood
    /// half, "bin 96 within 1 tile around (red 96-127, ...)".
    pub fn describe_feature(&self, feature: usize) -> String {
        let bins = self.features.bins();
        if feature < bins {
            format!("bin {feature}: {}", self.features.describe_bin(feature))
        } else {
            let b = feature - bins;
            let r = self.context_tiles;
            format!(
                "bin {b} within {r} tile{} around: {}",
                if r == 1 { "" } else { "s" },
                self.features.describe_bin(b)
            )
        }
    }

    /// The training table: examples per third, tree size before and after pruning, test
    /// metrics and the top splits in words.
    pub fn summary_table(&self) -> String {
        let mut s = String::from(
            "tile head (the tile's own colours: the fuser's evidence, tile_probs.npy)\n",
        );
        s.push_str(&self.head_table(true));
        if let Some(region) = &self.region {
            s.push_str(
                "\nregion head (the tile and its neighbourhood: inside the labelled rectangle? predict's probs.npy)\n",
            );
            s.push_str(&region.head_table(false));
        }
        s
    }

    /// One head's table; `fuser_head`: this head's base rate is the fuser's prior.
    fn head_table(&self, fuser_head: bool) -> String {
        use std::fmt::Write;
        let m = &self.metadata;
        let e = &m.examples;
        let mut s = String::new();
        let context = if self.context_tiles > 0 {
            format!(" + {} tiles around", self.context_tiles)
        } else {
            String::new()
        };
        let _ = writeln!(
            s,
            "features {}{context} | tile {} px | train stride {} px | seed {} | {} labelled frames",
            self.features.name(),
            self.tile_px,
            m.train_stride_px,
            m.seed,
            e.labelled_frames
        );
        let _ = writeln!(
            s,
            "{:<26} {:>9} {:>9} {:>10}",
            "examples", "tiles", "positive", "rate"
        );
        let rows = [
            ("train (aligned + shifted)", e.train),
            ("  of which shifted grids", e.train_shifted),
            ("test", e.test),
            ("prune", e.prune),
        ];
        for (name, c) in rows {
            let rate = c.positives as f64 / c.examples.max(1) as f64;
            let _ = writeln!(
                s,
                "{name:<26} {:>9} {:>9} {rate:>10.6}",
                c.examples, c.positives
            );
        }
        if let Some(forest) = &m.forest {
            let _ = writeln!(
                s,
                "forest of {} trees, each grown on {:.0} % of the training tiles, splitting on {} of {} features drawn per node; probability = their mean (the first tree below, the metrics the forest's)",
                1 + self.trees.len(),
                100.0 * forest.sample_fraction,
                forest.split_features_of(self.n_features()),
                self.n_features()
            );
        }
        let f = &m.fit;
        let _ = writeln!(
            s,
            "growth: {} best-first expansions tried, {} kept (best test log-loss); m-estimate m = {}",
            f.expansions_tried, f.expansions_kept, m.tree_params.m_estimate
        );
        let _ = writeln!(s, "{:<26} {:>9} {:>9}", "tree", "nodes", "depth");
        let _ = writeln!(
            s,
            "{:<26} {:>9} {:>9}",
            "before pruning", f.nodes_grown, f.depth_grown
        );
        let _ = writeln!(
            s,
            "{:<26} {:>9} {:>9}",
            "after pruning", f.nodes_pruned, f.depth_pruned
        );
        let _ = writeln!(
            s,
            "{:<26} {:>9} {:>9} {:>9}",
            if m.forest.is_some() {
                "final forest on"
            } else {
                "final tree on"
            },
            "accuracy",
            "log-loss",
            "ROC AUC"
        );
        for (name, t) in [
            ("test third", &m.test_metrics),
            ("pruning third", &m.prune_metrics),
        ] {
            let auc = t
                .roc_auc
                .map_or_else(|| "n/a".to_owned(), |a| format!("{a:.4}"));
            let _ = writeln!(
                s,
                "{name:<26} {:>9.5} {:>9.5} {auc:>9}",
                t.accuracy, t.log_loss
            );
        }
        if fuser_head {
            let _ = writeln!(s, "base rate (fuser prior) {:.6}", self.base_rate);
        }
        let _ = writeln!(s, "top splits:");
        for line in self.top_splits(5) {
            let _ = writeln!(s, "  {line}");
        }
        s
    }

    /// The first `k` splits from the root in words, breadth-first.
    pub fn top_splits(&self, k: usize) -> Vec<String> {
        self.tree
            .splits_breadth_first()
            .into_iter()
            .take(k)
            .filter_map(|i| {
                let node = &self.tree.nodes[i];
                let s = node.split.as_ref()?;
                let right = &self.tree.nodes[s.right as usize];
                let left = &self.tree.nodes[s.left as usize];
                Some(format!(
                    "node {i} (n={}): fraction of pixels in {} > {:.4} -> {} (p={:.4}) else {} (p={:.4})",
                    node.n_train,
                    self.describe_feature(s.feature as usize),
                    s.threshold,
                    s.right,
                    right.p,
                    s.left,
                    left.p
                ))
            })
            .collect()
    }
}

/// Probability maps of every frame of a session, in session order.
#[derive(Debug, Clone)]
pub struct SessionPrediction {
    /// Header stamp of each frame, ns since the Unix epoch: `stamps.npy`.
    pub stamps_ns: Vec<i64>,
    /// The region head's maps ([`Model::region`]; the tile head's without one): `probs.npy`.
    pub maps: Vec<TileProbs>,
    /// The tile head's maps, what the fuser integrates: `tile_probs.npy` (the same as `maps`
    /// for a model without a region head).
    pub tile_maps: Vec<TileProbs>,
    /// Tile metrics of `maps` over the frames that have a label (None: no labelled frame).
    pub labelled: Option<Metrics>,
    /// The same for `tile_maps`.
    pub tile_labelled: Option<Metrics>,
    /// Frames of the session with a label (background frames included).
    pub labelled_frames: usize,
}

impl Model {
    /// Predicts every frame; all frames must share one size (the maps form one array).
    /// `progress` is called once per frame and head as it is done (from worker threads).
    pub fn predict_session(
        &self,
        session: &LoadedSession,
        progress: &(dyn Fn() + Sync),
    ) -> Result<SessionPrediction, ModelError> {
        if let Some(first) = session.frames.first() {
            let size = |f: &crate::learn::dataset::SessionFrame| (f.image.width, f.image.height);
            if let Some(f) = session.frames.iter().find(|f| size(f) != size(first)) {
                return Err(ModelError::Spec {
                    path: session.path.clone(),
                    what: format!(
                        "frame at log time {} is {} x {} px but the first frame is {} x {} px; one probability array needs one frame size",
                        crate::io::session::fmt_ns(f.log_time_ns),
                        f.image.width,
                        f.image.height,
                        first.image.width,
                        first.image.height
                    ),
                });
            }
        }
        let tile_maps: Vec<TileProbs> = session
            .frames
            .par_iter()
            .map(|f| {
                let p = self.predict(&f.image);
                progress();
                p
            })
            .collect();
        let maps: Vec<TileProbs> = match &self.region {
            Some(region) => session
                .frames
                .par_iter()
                .map(|f| {
                    let p = region.predict(&f.image);
                    progress();
                    p
                })
                .collect(),
            None => tile_maps.clone(),
        };
        let labelled_frames = session
            .frames
            .iter()
            .filter(|f| f.regions.is_some())
            .count();
        let score = |maps: &[TileProbs]| {
            let mut p = Vec::new();
            let mut y = Vec::new();
            for (f, m) in session.frames.iter().zip(maps) {
                if let Some(regions) = &f.regions {
                    p.extend(m.p.iter().map(|&v| v as f64));
                    y.extend(crate::learn::dataset::tile_labels(
                        regions, m.rows, m.cols, m.tile_px,
                    ));
                }
            }
            (labelled_frames > 0).then(|| metrics(&p, &y))
        };
        Ok(SessionPrediction {
            stamps_ns: session.frames.iter().map(|f| f.stamp_ns).collect(),
            labelled: score(&maps),
            tile_labelled: score(&tile_maps),
            maps,
            tile_maps,
            labelled_frames,
        })
    }
}

/// Removes the `heatmap_NNNNN.png` files of an earlier run from `dir`: left beside the new
/// maps (of another session, or more frames), they read as this run's. Nothing else in the
/// directory is touched.
fn remove_heatmaps(dir: &Path) -> std::io::Result<()> {
    for entry in std::fs::read_dir(dir)? {
        let path = entry?.path();
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
        let digits = name
            .strip_prefix("heatmap_")
            .and_then(|r| r.strip_suffix(".png"));
        if digits.is_some_and(|d| d.len() == 5 && d.bytes().all(|b| b.is_ascii_digit())) {
            std::fs::remove_file(&path)?;
        }
    }
    Ok(())
}

impl SessionPrediction {
    /// Writes `probs.npy` (float32 frames x rows x cols: the region head's maps),
    /// `tile_probs.npy` (the tile head's, the fuser's evidence), `labels.npy` (int8, same
    /// shape) and `stamps.npy` (int64 ns) into `dir`, and with `heatmaps` a
    /// `heatmap_NNNNN.png` per frame (an earlier run's heatmaps are removed either way).
    pub fn write(
        &self,
        dir: &Path,
        session: &LoadedSession,
        heatmaps: bool,
    ) -> Result<(), ModelError> {
        let io = |path: &Path| {
            let path = path.to_owned();
            move |source| ModelError::Io { path, source }
        };
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        remove_heatmaps(dir).map_err(io(dir))?;
        let (rows, cols) = self.maps.first().map_or((0, 0), |m| (m.rows, m.cols));
        let probs: Vec<f32> = self.maps.iter().flat_map(|m| m.p.iter().copied()).collect();
        let tile_probs: Vec<f32> = self
            .tile_maps
            .iter()
            .flat_map(|m| m.p.iter().copied())
            .collect();
        let npy = |e: crate::io::npy::NpyError| match e {
            crate::io::npy::NpyError::Io { path, source } => ModelError::Io {
                path: path.into(),
                source,
            },
            other => ModelError::Io {
                path: dir.to_owned(),
                source: std::io::Error::other(other.to_string()),
            },
        };
        let mut staged = crate::io::output::Staged::default();
        crate::io::npy::write_staged(
            &mut staged,
            &dir.join("probs.npy"),
            &[self.maps.len(), rows, cols],
            &probs,
        )
        .map_err(npy)?;
        crate::io::npy::write_staged(
            &mut staged,
            &dir.join("tile_probs.npy"),
            &[self.tile_maps.len(), rows, cols],
            &tile_probs,
        )
        .map_err(npy)?;
        // The tile labels beside the maps, so that a map can be scored without the session:
        // 1 inside a labelled rectangle, 0 outside, -1 for every tile of an unlabelled frame.
        let labels: Vec<i8> = session
            .frames
            .iter()
            .zip(&self.maps)
            .flat_map(|(f, m)| match &f.regions {
                Some(regions) => {
                    crate::learn::dataset::tile_labels(regions, m.rows, m.cols, m.tile_px)
                        .into_iter()
                        .map(i8::from)
                        .collect()
                }
                None => vec![-1; m.p.len()],
            })
            .collect();
        crate::io::npy::write_staged(
            &mut staged,
            &dir.join("labels.npy"),
            &[self.maps.len(), rows, cols],
            &labels,
        )
        .map_err(npy)?;
        crate::io::npy::write_staged(
            &mut staged,
            &dir.join("stamps.npy"),
            &[self.stamps_ns.len()],
            &self.stamps_ns,
        )
        .map_err(npy)?;
        if heatmaps {
            for (k, (f, m)) in session.frames.iter().zip(&self.maps).enumerate() {
                let path = dir.join(format!("heatmap_{k:05}.png"));
                let img = m.heatmap(&f.image);
                let mut png = Vec::new();
                image::codecs::png::PngEncoder::new(&mut png)
                    .write_image(
                        &img.data,
                        img.width,
                        img.height,
                        image::ExtendedColorType::Rgb8,
                    )
                    .map_err(|e| ModelError::Io {
                        path: path.clone(),
                        source: std::io::Error::other(e.to_string()),
                    })?;
                staged
                    .write_with(&path, |w| w.write_all(&png))
                    .map_err(io(&path))?;
            }
        }
        // The maps, labels and stamps go into place together, or none does.
        staged.commit().map_err(io(dir))?;
        Ok(())
    }
}
