//! Training a model: the configuration of both heads, the examples of labelled sessions, and
//! growing, stopping, pruning and packaging a head (one tree or a forest) into a [`Model`].
//!
//! Invariants: the same sessions and configuration give the same model bit for bit, for any
//! thread count (the trees' own invariants; metrics are summed in example order); a model this
//! writes passes [`Model::load`]'s checks.

use rayon::prelude::*;

use crate::learn::dataset::{Augment, ExampleParams, ExampleSet, LoadedSession, build_examples};
use crate::learn::features::FeatureSpec;
use crate::learn::model::{
    ExampleCounts, MODEL_VERSION, MODEL_VERSION_ONE_TREE, Model, ModelError, SessionHash,
    ThirdCount, TrainingMetadata,
};
use crate::learn::tree::{
    Examples, ForestParams, Metrics, Third, Tree, TreeError, TreeParams, fit_forest,
    mean_probability, metrics,
};

/// How to train.
#[derive(Debug, Clone, PartialEq)]
pub struct TrainConfig {
    /// The channels of the tile head's histograms.
    pub features: FeatureSpec,
    /// Side of a square tile, px, for both heads; must lie in [`TILE_PX_RANGE`].
    pub tile_px: u32,
    /// Radius in tiles of the tile head's neighbourhood histogram (0 = the tile alone); a model
    /// loads only with at most [`MAX_CONTEXT_TILES`].
    pub context_tiles: u32,
    /// Shift between the tile head's extra training grids, px, in 1..=`tile_px`.
    pub train_stride_px: u32,
    /// Photometric variants of the shifted grids' frames, for both heads.
    pub augment: Augment,
    /// Seed of the stratified shuffle into thirds, for both heads.
    pub seed: u64,
    /// Train on the labels of this object only (None: every label).
    pub object: Option<String>,
    /// Tree growth and smoothing settings, for both heads.
    pub tree: TreeParams,
    /// The tile head's trees (the region head is always one tree).
    pub forest: ForestParams,
    /// How to train the region head (None: no region head; `predict` then writes the tile
    /// head's maps).
    pub region: Option<RegionConfig>,
}

/// What the region head's examples differ in; the tile size, seed, labels and tree options
/// are the tile head's.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RegionConfig {
    /// The channels of the region head's histograms.
    pub features: FeatureSpec,
    /// Radius in tiles of the region head's neighbourhood histogram (0 = the tile alone).
    pub context_tiles: u32,
    /// Shift between the region head's extra training grids, px, in 1..=`tile_px`.
    pub train_stride_px: u32,
}

/// hsv, the mean histogram of the 5 x 5 tiles around, shifted grids every 2 px: the best
/// tile AUC against rectangle labels of what was measured, and the steadiest across seeds
/// (docs/tree.md, "Tour AUC and the 0.95 target").
impl Default for RegionConfig {
    fn default() -> Self {
        Self {
            features: FeatureSpec::HSV,
            context_tiles: 2,
            train_stride_px: 2,
        }
    }
}

/// The defaults of `objloc train` for a ground robot's sessions: rgb332 features (they fuse
/// best, docs/fuser.md), 8 px tiles, shifted grids every 4 px, seed 0, every label (a posed
/// capture's channels and light variants: `learn::defaults`).
impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            features: FeatureSpec::RGB332,
            tile_px: 8,
            context_tiles: 0,
            train_stride_px: 4,
            augment: Augment::None,
            seed: 0,
            object: None,
            tree: TreeParams::default(),
            forest: ForestParams::single(),
            region: Some(RegionConfig::default()),
        }
    }
}

impl TrainConfig {
    /// The configuration of the region head as a head of its own (None: no region head).
    pub fn region_config(&self) -> Option<TrainConfig> {
        self.region.map(|r| TrainConfig {
            features: r.features,
            context_tiles: r.context_tiles,
            train_stride_px: r.train_stride_px,
            region: None,
            forest: ForestParams::single(),
            ..self.clone()
        })
    }

    /// The parameters that build this head's examples.
    pub fn example_params(&self) -> ExampleParams {
        ExampleParams {
            features: self.features,
            tile_px: self.tile_px,
            context_tiles: self.context_tiles,
            train_stride_px: self.train_stride_px,
            seed: self.seed,
            augment: self.augment,
        }
    }
}

/// Metrics of `tree` (with a forest's `more` trees: their mean) on the examples of `third`.
pub fn third_metrics(tree: &Tree, more: &[Tree], ex: &Examples, third: Third) -> Metrics {
    let idx: Vec<usize> = (0..ex.len()).filter(|&i| ex.thirds[i] == third).collect();
    let p: Vec<f64> = idx
        .par_iter()
        .map(|&i| mean_probability(tree, more, |t| t.predict_example(ex, i)))
        .collect();
    let y: Vec<bool> = idx.iter().map(|&i| ex.labels[i]).collect();
    metrics(&p, &y)
}

/// Builds the examples of `sessions` (see [`crate::learn::dataset`]).
pub fn examples(sessions: &[LoadedSession], cfg: &TrainConfig) -> Result<ExampleSet, ModelError> {
    let set = build_examples(sessions, &cfg.example_params())?;
    let (n, pos) = set.examples.third_counts(Third::Train);
    if n == 0 {
        return Err(ModelError::NoExamples {
            sessions: sessions.len(),
        });
    }
    if pos == 0 {
        return Err(ModelError::NoPositives {
            examples: n,
            tile_px: cfg.tile_px,
        });
    }
    Ok(set)
}

/// Grows, stops, prunes and packages the model.
pub fn fit_model(
    sessions: &[LoadedSession],
    set: &ExampleSet,
    cfg: &TrainConfig,
) -> Result<Model, ModelError> {
    let ex = &set.examples;
    let mut grown = fit_forest(ex, &cfg.tree, &cfg.forest, cfg.seed)
        .map_err(ModelError::Fit)?
        .into_iter();
    let Some((tree, mut fit_report)) = grown.next() else {
        return Err(ModelError::Fit(TreeError::NoTrainingExamples));
    };
    let trees: Vec<Tree> = grown.map(|(t, _)| t).collect();
    // A forest's trees each grew on a share of the training third; the fuser's prior is the
    // whole third's rate.
    let (n_train, pos_train) = ex.third_counts(Third::Train);
    fit_report.base_rate = pos_train as f64 / n_train.max(1) as f64;
    let count = |t: Third| {
        let (examples, positives) = ex.third_counts(t);
        ThirdCount {
            examples,
            positives,
        }
    };
    let train_shifted = ThirdCount {
        examples: ex.len() - set.aligned,
        positives: ex.labels[set.aligned..].iter().filter(|&&y| y).count(),
    };
    let metadata = TrainingMetadata {
        seed: cfg.seed,
        sessions: sessions
            .iter()
            .map(|s| SessionHash {
                path: s.path.display().to_string(),
                sha256: s.sha256.clone(),
                warnings: s.warnings.clone(),
            })
            .collect(),
        object: cfg.object.clone(),
        train_stride_px: cfg.train_stride_px,
        augment: cfg.augment,
        tree_params: cfg.tree,
        examples: ExampleCounts {
            train: count(Third::Train),
            train_shifted,
            test: count(Third::Test),
            prune: count(Third::Prune),
            labelled_frames: set.labelled_frames,
        },
        test_metrics: third_metrics(&tree, &trees, ex, Third::Test),
        prune_metrics: third_metrics(&tree, &trees, ex, Third::Prune),
        fit: fit_report,
        forest: (!trees.is_empty()).then_some(cfg.forest),
    };
    Ok(Model {
        version: if trees.is_empty() {
            MODEL_VERSION_ONE_TREE
        } else {
            MODEL_VERSION
        },
        features: cfg.features,
        tile_px: cfg.tile_px,
        context_tiles: cfg.context_tiles,
        base_rate: metadata.fit.base_rate,
        tree,
        trees,
        metadata,
        region: None,
    })
}
