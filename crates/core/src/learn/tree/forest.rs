//! A forest of the paper's trees: each grown on a random half of the training third, each node
//! splitting on a random subset of the features, each stopped and pruned on the whole test and
//! pruning thirds like the paper's tree; the forest's probability is the trees' mean.
//!
//! Why (docs/tree.md, "A forest for captures"): one pruned tree gives a tile one of a few
//! hundred leaf values and ranks tiles of a real capture coarsely; averaging trees that saw
//! different examples and features ranks them finer and varies less with the light.
//!
//! Invariants: every draw comes from SplitMix64 seeded by the forest's seed and the tree's
//! index, keyed by the example's index or the node's index, never by the order of work, so the
//! same examples and seed give the same trees bit for bit for any thread count; a forest of
//! one tree is not randomised at all (it is [`fit`]'s tree).

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::fit::{fit, fit_randomised};
use super::{Examples, FitReport, Tree, TreeError, TreeParams};
use crate::types::rng::SplitMix64;

/// How many trees and how each is randomised.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ForestParams {
    /// Trees averaged (1: the paper's single tree, not randomised).
    pub trees: u32,
    /// Share of the training third each tree grows on, in (0, 1].
    pub sample_fraction: f64,
    /// Features each node chooses its split among, drawn per node: the square root of the
    /// feature count, rounded up, when None.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub split_features: Option<usize>,
}

/// The paper's single tree.
impl Default for ForestParams {
    fn default() -> Self {
        Self::single()
    }
}

impl ForestParams {
    /// One tree, every example and feature: the paper's classifier.
    pub fn single() -> Self {
        Self {
            trees: 1,
            sample_fraction: 1.0,
            split_features: None,
        }
    }

    /// `trees` trees, each on half the training third, the square root of the features at each
    /// node (what `train` gives a posed capture: docs/tree.md).
    pub fn random(trees: u32) -> Self {
        Self {
            trees,
            sample_fraction: 0.5,
            split_features: None,
        }
    }

    /// `trees` trees: [`ForestParams::random`], or the paper's single tree for 1 (or 0).
    pub fn with_trees(trees: u32) -> Self {
        if trees > 1 {
            Self::random(trees)
        } else {
            Self::single()
        }
    }

    /// Features per split for `n_features` features (at least 1, at most all).
    pub fn split_features_of(&self, n_features: usize) -> usize {
        let k = self
            .split_features
            .unwrap_or_else(|| (n_features as f64).sqrt().ceil() as usize);
        k.clamp(1, n_features.max(1))
    }
}

/// The draws that make one tree of a forest differ from the others.
#[derive(Debug, Clone, Copy)]
pub struct Randomise {
    /// Seeds which training examples the tree keeps.
    sample_seed: u64,
    /// Seeds which features each node may split on.
    feature_seed: u64,
    /// Share of the training third kept.
    sample_fraction: f64,
    /// Features each node may split on.
    split_features: usize,
}

impl Randomise {
    /// The draws of tree `index` of a forest seeded by `seed`, for `n_features` features.
    pub fn new(seed: u64, index: u32, params: &ForestParams, n_features: usize) -> Self {
        let mut rng =
            SplitMix64::new(seed ^ (u64::from(index) + 1).wrapping_mul(0xD6E8_FEB8_6659_FD93));
        Self {
            sample_seed: rng.next_u64(),
            feature_seed: rng.next_u64(),
            sample_fraction: params.sample_fraction,
            split_features: params.split_features_of(n_features),
        }
    }

    /// Whether the tree grows on training example `i` (independent draws: about
    /// `sample_fraction` of them).
    pub fn keeps(&self, i: usize) -> bool {
        let h = keyed(self.sample_seed, i as u64);
        ((h >> 11) as f64) * (1.0 / (1u64 << 53) as f64) < self.sample_fraction
    }

    /// The features node `node` may split on: `split_features` of the `n_features`, drawn by
    /// a partial Fisher-Yates shuffle. A drawn feature may be constant among the node's
    /// examples (most bins of a sparse tile histogram are 0 deep in a tree), so a node's
    /// usable draw is often smaller and a node may stay a leaf that another draw would split:
    /// shallower, more varied trees than scikit-learn's forest, which draws until it holds
    /// enough varying features. Both were measured (docs/tree.md, "A forest for captures");
    /// this draw located the objects of the sessions with 3D truth better.
    pub fn features(&self, node: u32, n_features: usize) -> Vec<bool> {
        let mut rng = SplitMix64::new(keyed(self.feature_seed, u64::from(node)));
        let mut order: Vec<usize> = (0..n_features).collect();
        let k = self.split_features.min(n_features);
        for i in 0..k {
            let j = i + rng.below((n_features - i) as u64) as usize;
            order.swap(i, j);
        }
        let mut allowed = vec![false; n_features];
        for &f in &order[..k] {
            allowed[f] = true;
        }
        allowed
    }
}

/// A well-mixed value of (`seed`, `key`): the SplitMix64 output at position `key` of the
/// stream seeded by `seed`.
fn keyed(seed: u64, key: u64) -> u64 {
    SplitMix64::new(seed.wrapping_add(key.wrapping_mul(0x9E37_79B9_7F4A_7C15))).next_u64()
}

/// Grows the forest's trees (in parallel; each tree is the same whatever the thread count),
/// in index order, each with what its fit did.
pub fn fit_forest(
    ex: &Examples,
    params: &TreeParams,
    forest: &ForestParams,
    seed: u64,
) -> Result<Vec<(Tree, FitReport)>, TreeError> {
    if forest.trees <= 1 {
        return Ok(vec![fit(ex, params)?]);
    }
    (0..forest.trees)
        .into_par_iter()
        .map(|t| {
            let r = Randomise::new(seed, t, forest, ex.n_features);
            fit_randomised(ex, params, Some(&r))
        })
        .collect()
}

/// The forest's probability for a tile: the mean of its trees' (`tree` first, then `more`),
/// summed in that order.
pub fn mean_probability<T>(tree: &T, more: &[T], leaf_p: impl Fn(&T) -> f64) -> f64 {
    if more.is_empty() {
        return leaf_p(tree);
    }
    let sum = more.iter().fold(leaf_p(tree), |s, t| s + leaf_p(t));
    sum / (1 + more.len()) as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::learn::tree::Third;

    /// Examples whose label is whether feature 0's count exceeds 4 (out of 8), with 3 noise
    /// features; thirds dealt round-robin.
    fn examples(n: usize) -> Examples {
        let mut ex = Examples::new(4, 8);
        let mut rng = SplitMix64::new(5);
        for i in 0..n {
            let counts: Vec<u16> = (0..4).map(|_| rng.below(9) as u16).collect();
            let third = [Third::Train, Third::Test, Third::Prune][i % 3];
            ex.push_dense(&counts, counts[0] > 4, third);
        }
        ex
    }

    #[test]
    fn a_tree_keeps_about_its_share_of_the_examples_the_same_ones_each_time() {
        let p = ForestParams::random(4);
        let r = Randomise::new(7, 2, &p, 10);
        let kept: Vec<usize> = (0..10_000).filter(|&i| r.keeps(i)).collect();
        assert!((4_800..5_200).contains(&kept.len()), "{}", kept.len());
        let again = Randomise::new(7, 2, &p, 10);
        assert_eq!(
            kept,
            (0..10_000).filter(|&i| again.keeps(i)).collect::<Vec<_>>()
        );
        let other = Randomise::new(7, 3, &p, 10);
        let shared = kept.iter().filter(|&&i| other.keeps(i)).count();
        // Independent halves share about a quarter.
        assert!((2_300..2_700).contains(&shared), "{shared}");
    }

    #[test]
    fn each_node_may_split_on_the_square_root_of_the_features() {
        let p = ForestParams::random(4);
        assert_eq!(p.split_features_of(330), 19);
        assert_eq!(p.split_features_of(256), 16);
        assert_eq!(p.split_features_of(1), 1);
        let r = Randomise::new(1, 0, &p, 330);
        let a = r.features(5, 330);
        assert_eq!(a.iter().filter(|&&x| x).count(), 19);
        assert_eq!(a, r.features(5, 330));
        assert_ne!(a, r.features(6, 330));
    }

    /// The forest's path with every example and every feature at every node grows the
    /// paper's tree: the draws are all that path changes. (`train --tree-sample-fraction 1
    /// --split-features 1000`: the largest fraction it takes keeps every example, and more
    /// features than there are is all of them.)
    #[test]
    fn a_draw_of_everything_grows_the_papers_tree() {
        let ex = examples(900);
        let params = TreeParams::default();
        let paper = fit(&ex, &params).unwrap().0;
        let everything = ForestParams {
            trees: 2,
            sample_fraction: 1.0,
            split_features: Some(1000),
        };
        assert_eq!(everything.split_features_of(4), 4);
        let r = Randomise::new(5, 1, &everything, 4);
        assert!((0..900).all(|i| r.keeps(i)));
        let all = fit_randomised(&ex, &params, Some(&r)).unwrap().0;
        assert_eq!(all, paper);
        assert!(paper.nodes.len() > 1);
        // A forest of one is that tree too, not randomised.
        let one = fit_forest(&ex, &params, &ForestParams::random(1), 3).unwrap();
        assert_eq!(one[0].0, paper);
    }

    #[test]
    fn a_forest_is_the_same_for_any_thread_count() {
        let ex = examples(3_000);
        let params = TreeParams::default();
        let forest = ForestParams::random(6);
        let on = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| fit_forest(&ex, &params, &forest, 11).unwrap())
        };
        let (a, b) = (on(1), on(3));
        assert_eq!(a.len(), 6);
        for ((ta, _), (tb, _)) in a.iter().zip(&b) {
            assert_eq!(ta, tb);
        }
        // The trees differ: they saw different halves and features.
        assert!(a.windows(2).any(|w| w[0].0 != w[1].0));
        // Each is still a classifier of feature 0: a clear positive scores above a negative.
        for (t, _) in &a {
            let p_pos = t.predict_counts(&[8, 0, 0, 0], 8.0);
            let p_neg = t.predict_counts(&[0, 8, 8, 8], 8.0);
            assert!(p_pos > p_neg, "{p_pos} {p_neg}");
        }
    }

    #[test]
    fn the_forests_probability_is_its_trees_mean() {
        let leaf = |p: f64| Tree {
            n_features: 1,
            nodes: vec![crate::learn::tree::Node {
                p,
                n_train: 1,
                pos_train: 0,
                split: None,
            }],
        };
        let (a, b, c) = (leaf(0.1), leaf(0.4), leaf(0.7));
        let p = |t: &Tree| t.predict_counts(&[0], 1.0);
        assert_eq!(mean_probability(&a, &[], p), 0.1);
        let m = mean_probability(&a, &[b, c], p);
        assert!((m - 0.4).abs() < 1e-15, "{m}");
    }
}
