//! The paper's probability decision tree: binary threshold splits on continuous features
//! chosen by information gain, growth stopped by the test third, top-down pruning on the
//! pruning third, leaves that return an m-estimate of the fraction of positive training
//! examples.
//!
//! Invariants: training is single-threaded and every choice has a fixed tie-break (lowest
//! feature, then lowest threshold, then lowest node index), so the same examples give the
//! same tree bit for bit; every leaf probability lies strictly inside (0, 1) (it is smoothed
//! toward the base rate, never clipped); node 0 is the root and children have larger indices
//! than their parent (so a tree read from a file cannot loop).
//!
//! Performance measure for growth and pruning: **log-loss**, not accuracy. With base rates of
//! 0.0002-0.007 a tree that says "no" everywhere is already 99.3-99.98% accurate, so accuracy
//! barely moves when a split finds the object; log-loss scores the probabilities themselves,
//! which is what the Bayesian fuser consumes.
//!
//! Layout: this file holds the examples, the tree and its checks, the settings and the
//! metrics; `search` finds a node's best split, `fit` grows, stops and prunes the tree,
//! `forest` grows several randomised trees whose mean is the probability.

mod counts;
mod fit;
mod forest;
mod search;

use std::cmp::Ordering;

use serde::{Deserialize, Serialize};
use thiserror::Error;

pub use counts::CountTree;
pub use fit::fit;
pub use forest::{ForestParams, fit_forest, mean_probability};

/// Which third of the examples an example belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
pub enum Third {
    /// Grows the tree; its fraction of positives is the base rate (0 in `split.npy`).
    Train = 0,
    /// Stops growth and chooses how far it is cut back (1 in `split.npy`).
    Test = 1,
    /// Decides the top-down pruning (2 in `split.npy`).
    Prune = 2,
}

/// Sparse examples with integer feature counts: feature value = count / `denom`.
/// Example i has the (feature, count) pairs `entries[offsets[i]..offsets[i + 1]]`, features
/// strictly increasing, counts > 0; absent features are 0.
#[derive(Debug, Clone, Default)]
pub struct Examples {
    /// Features per example; every entry's feature is below it.
    pub n_features: usize,
    /// Largest possible count (the value 1.0).
    pub denom: u16,
    /// Start of each example's entries in `entries`, then the end: `len() + 1` values from 0.
    pub offsets: Vec<u32>,
    /// The (feature, count) entries of all examples, one example after another.
    pub entries: Vec<(u16, u16)>,
    /// Whether each example is positive (for tiles: lies fully inside a label rectangle).
    pub labels: Vec<bool>,
    /// The third each example belongs to.
    pub thirds: Vec<Third>,
}

/// Appends the non-zero (feature, count) entries of dense `counts` to `out`, in feature
/// order. Branch-free: every entry is written and the cursor moves on only past a non-zero
/// count, since whether a bin is zero is close to random and a branch mispredicts (this was
/// a tenth of training).
pub fn push_nonzero(counts: &[u16], out: &mut Vec<(u16, u16)>) {
    let start = out.len();
    out.resize(start + counts.len(), (0, 0));
    let mut k = start;
    for (f, &c) in counts.iter().enumerate() {
        out[k] = (f as u16, c);
        k += usize::from(c > 0);
    }
    out.truncate(k);
}

impl Examples {
    /// No examples yet, of `n_features` features with counts out of `denom`.
    pub fn new(n_features: usize, denom: u16) -> Self {
        Self {
            n_features,
            denom,
            offsets: vec![0],
            ..Self::default()
        }
    }

    /// Number of examples.
    pub fn len(&self) -> usize {
        self.labels.len()
    }

    /// Whether there are no examples.
    pub fn is_empty(&self) -> bool {
        self.labels.is_empty()
    }

    /// Adds one example from its dense counts.
    pub fn push_dense(&mut self, counts: &[u16], label: bool, third: Third) {
        push_nonzero(counts, &mut self.entries);
        self.offsets.push(self.entries.len() as u32);
        self.labels.push(label);
        self.thirds.push(third);
    }

    /// Adds one example from its non-zero (feature, count) entries in feature order.
    pub fn push_sparse(&mut self, entries: &[(u16, u16)], label: bool, third: Third) {
        debug_assert!(entries.windows(2).all(|w| w[0].0 < w[1].0));
        self.entries.extend_from_slice(entries);
        self.offsets.push(self.entries.len() as u32);
        self.labels.push(label);
        self.thirds.push(third);
    }

    /// The non-zero (feature, count) entries of example i, features strictly increasing.
    pub fn sparse(&self, i: usize) -> &[(u16, u16)] {
        &self.entries[self.offsets[i] as usize..self.offsets[i + 1] as usize]
    }

    /// Count of `feature` in example i (0 when absent).
    pub fn count(&self, i: usize, feature: u16) -> u16 {
        let s = self.sparse(i);
        match s.binary_search_by_key(&feature, |&(f, _)| f) {
            Ok(k) => s[k].1,
            Err(_) => 0,
        }
    }

    /// Dense feature values (count / denom) of example i.
    pub fn dense_values(&self, i: usize) -> Vec<f32> {
        let mut v = vec![0f32; self.n_features];
        for &(f, c) in self.sparse(i) {
            v[f as usize] = (c as f64 / self.denom as f64) as f32;
        }
        v
    }

    /// (examples, positives) in `third`.
    pub fn third_counts(&self, third: Third) -> (usize, usize) {
        let mut n = 0;
        let mut pos = 0;
        for (l, t) in self.labels.iter().zip(&self.thirds) {
            if *t == third {
                n += 1;
                pos += *l as usize;
            }
        }
        (n, pos)
    }
}

/// A node's test of one feature against a threshold, and its two children.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Split {
    /// Index of the feature tested, below the tree's `n_features`.
    pub feature: u16,
    /// Go left when the feature value (a fraction in [0, 1]) is <= threshold. Always the
    /// midpoint between two neighbouring distinct training values.
    pub threshold: f64,
    /// Node index of the child for values <= `threshold` (larger than this node's).
    pub left: u32,
    /// Node index of the child for values > `threshold` (larger than this node's).
    pub right: u32,
}

/// One node of a [`Tree`]: a leaf, or a split with two children.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Node {
    /// Probability of the positive class when this node is (or is condensed into) a leaf.
    pub p: f64,
    /// Training examples reaching this node, and how many were positive.
    pub n_train: u32,
    /// Of `n_train`, the positives.
    pub pos_train: u32,
    /// The node's test and children; None for a leaf.
    pub split: Option<Split>,
}

/// A probability tree: node 0 is the root and every child comes after its parent (see
/// [`Tree::validate`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Tree {
    /// Features an example has; every split's feature is below it.
    pub n_features: usize,
    /// The nodes, root first; fitted trees are in pre-order.
    pub nodes: Vec<Node>,
}

/// Why a tree (read from a file) or a set of examples is refused.
#[derive(Debug, Error, PartialEq)]
pub enum TreeError {
    /// The tree has no nodes.
    #[error("tree has no nodes")]
    Empty,
    /// A child index is not after its node, or is past the last node.
    #[error("node {node}: child {child} is not after it and before {len}")]
    BadChild {
        /// Index of the node.
        node: usize,
        /// The child index it names.
        child: u32,
        /// Number of nodes.
        len: usize,
    },
    /// A split tests a feature the tree does not have.
    #[error("node {node}: feature {feature} is not below the {n_features} features")]
    BadFeature {
        /// Index of the node.
        node: usize,
        /// The feature it tests.
        feature: u16,
        /// The tree's feature count.
        n_features: usize,
    },
    /// A node's probability is not strictly inside (0, 1) (or is NaN).
    #[error("node {node}: probability {p} is not strictly between 0 and 1")]
    BadProbability {
        /// Index of the node.
        node: usize,
        /// The probability.
        p: f64,
    },
    /// A split's threshold is NaN or infinite.
    #[error("node {node}: threshold {threshold} is not finite")]
    BadThreshold {
        /// Index of the node.
        node: usize,
        /// The threshold.
        threshold: f64,
    },
    /// No example is in the training third.
    #[error("no training examples")]
    NoTrainingExamples,
    /// An entry's feature is not below `n_features`, a count exceeds `denom`, or `denom` is 0.
    #[error(
        "{n_entries} feature entries for {n_features} features with denominator {denom}: an entry is out of range"
    )]
    BadExamples {
        /// Entries of all examples.
        n_entries: usize,
        /// The declared feature count.
        n_features: usize,
        /// The declared largest count (the value 1.0).
        denom: u16,
    },
}

impl Tree {
    /// Checks the invariants a loaded tree must satisfy before it is walked.
    pub fn validate(&self) -> Result<(), TreeError> {
        if self.nodes.is_empty() {
            return Err(TreeError::Empty);
        }
        let len = self.nodes.len();
        for (i, n) in self.nodes.iter().enumerate() {
            if !(n.p > 0.0 && n.p < 1.0) {
                return Err(TreeError::BadProbability { node: i, p: n.p });
            }
            if let Some(s) = &n.split {
                for child in [s.left, s.right] {
                    if child as usize <= i || child as usize >= len {
                        return Err(TreeError::BadChild {
                            node: i,
                            child,
                            len,
                        });
                    }
                }
                if s.feature as usize >= self.n_features {
                    return Err(TreeError::BadFeature {
                        node: i,
                        feature: s.feature,
                        n_features: self.n_features,
                    });
                }
                if !s.threshold.is_finite() {
                    return Err(TreeError::BadThreshold {
                        node: i,
                        threshold: s.threshold,
                    });
                }
            }
        }
        Ok(())
    }

    /// Leaf index reached by an example whose feature values are given by `value`.
    #[inline]
    pub fn leaf_of(&self, value: impl Fn(usize) -> f64) -> usize {
        let mut i = 0usize;
        while let Some(s) = &self.nodes[i].split {
            i = if value(s.feature as usize) <= s.threshold {
                s.left as usize
            } else {
                s.right as usize
            };
        }
        i
    }

    /// Probability for dense integer counts (value = count / denom).
    #[inline]
    pub fn predict_counts(&self, counts: &[u16], denom: f64) -> f64 {
        self.nodes[self.leaf_of(|f| counts[f] as f64 / denom)].p
    }

    /// Probability for example i of `ex`.
    pub fn predict_example(&self, ex: &Examples, i: usize) -> f64 {
        let d = ex.denom as f64;
        self.nodes[self.leaf_of(|f| ex.count(i, f as u16) as f64 / d)].p
    }

    /// Number of leaves (nodes without a split).
    pub fn leaves(&self) -> usize {
        self.nodes.iter().filter(|n| n.split.is_none()).count()
    }

    /// Edges on the longest root-to-leaf path.
    pub fn depth(&self) -> usize {
        let mut depth = vec![0usize; self.nodes.len()];
        let mut max = 0;
        for i in 0..self.nodes.len() {
            if let Some(s) = &self.nodes[i].split {
                for c in [s.left, s.right] {
                    depth[c as usize] = depth[i] + 1;
                    max = max.max(depth[i] + 1);
                }
            }
        }
        max
    }

    /// Split nodes in breadth-first order from the root (the most important splits first).
    pub fn splits_breadth_first(&self) -> Vec<usize> {
        let mut out = Vec::new();
        let mut queue = std::collections::VecDeque::from([0usize]);
        while let Some(i) = queue.pop_front() {
            if let Some(s) = &self.nodes[i].split {
                out.push(i);
                queue.push_back(s.left as usize);
                queue.push_back(s.right as usize);
            }
        }
        out
    }
}

/// Growth and smoothing settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TreeParams {
    /// m of the m-estimate (pos + m * prior) / (n + m) of every leaf.
    pub m_estimate: f64,
    /// Growth stops after this many best-first expansions without a new best test log-loss.
    pub patience: usize,
    /// Hard cap on expansions (a guard; the test third normally stops growth long before).
    pub max_expansions: usize,
    /// Pseudo-examples per grown leaf added to the pruning third, distributed as that leaf's
    /// training examples (0 = the bare pruning third). See [`fit`] for why.
    #[serde(default)]
    pub prune_pseudo: f64,
    /// Weight of the base rate mixed into every leaf: p = (1 - w) * m-estimate + w * base
    /// rate (0 = the bare m-estimate). See [`fit`] for why.
    #[serde(default)]
    pub base_mix: f64,
}

impl Default for TreeParams {
    fn default() -> Self {
        Self {
            m_estimate: 2.0,
            patience: 32,
            max_expansions: 4096,
            prune_pseudo: 2.0,
            base_mix: 0.05,
        }
    }
}

/// What growth and pruning did, for the train table and the model metadata.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FitReport {
    /// Fraction of the training third's examples that are positive, in [0, 1]: the base rate the
    /// leaves are smoothed toward, and the model's `base_rate`.
    pub base_rate: f64,
    /// Expansions made before the test third stopped growth, and the count kept (the one
    /// with the best test log-loss).
    pub expansions_tried: usize,
    /// Of those, the expansions kept: the count with the best test log-loss.
    pub expansions_kept: usize,
    /// Nodes of the grown tree (after cutting back, before pruning).
    pub nodes_grown: usize,
    /// Depth of the grown tree: edges on its longest root-to-leaf path.
    pub depth_grown: usize,
    /// Nodes of the final tree, after pruning.
    pub nodes_pruned: usize,
    /// Depth of the final tree, after pruning.
    pub depth_pruned: usize,
    /// Mean log-loss of the test third after each kept expansion count (index 0 = root only).
    pub test_logloss_curve: Vec<f64>,
}

/// Quality of probabilities against labels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Metrics {
    /// Examples scored.
    pub n: usize,
    /// Of them, the positives.
    pub positives: usize,
    /// Fraction correct when p >= 0.5 means positive.
    pub accuracy: f64,
    /// Mean negative log-likelihood (nats).
    pub log_loss: f64,
    /// Area under the ROC curve; None without both classes.
    pub roc_auc: Option<f64>,
}

/// Accuracy, mean log-loss and ROC AUC of probabilities `p` against labels `y`, paired up to the
/// shorter (accuracy and log-loss 0 when empty).
pub fn metrics(p: &[f64], y: &[bool]) -> Metrics {
    let n = p.len().min(y.len());
    let mut correct = 0usize;
    let mut loss = 0.0;
    let mut positives = 0usize;
    for (&pi, &yi) in p.iter().zip(y) {
        correct += ((pi >= 0.5) == yi) as usize;
        loss -= if yi { pi.ln() } else { (1.0 - pi).ln() };
        positives += yi as usize;
    }
    let nf = n.max(1) as f64;
    Metrics {
        n,
        positives,
        accuracy: correct as f64 / nf,
        log_loss: loss / nf,
        roc_auc: roc_auc(p, y),
    }
}

/// ROC AUC = Mann-Whitney U / (pos * neg), ties counted half.
pub fn roc_auc(p: &[f64], y: &[bool]) -> Option<f64> {
    let mut order: Vec<usize> = (0..p.len().min(y.len())).collect();
    order.sort_by(|&a, &b| p[a].total_cmp(&p[b]).then(a.cmp(&b)));
    let (mut pos, mut neg) = (0f64, 0f64);
    let mut rank_sum = 0f64;
    let mut k = 0;
    while k < order.len() {
        let mut j = k;
        while j < order.len() && p[order[j]].total_cmp(&p[order[k]]) == Ordering::Equal {
            j += 1;
        }
        // Average 1-based rank of the tied run k..j.
        let avg = (k + 1 + j) as f64 / 2.0;
        for &i in &order[k..j] {
            if y[i] {
                pos += 1.0;
                rank_sum += avg;
            } else {
                neg += 1.0;
            }
        }
        k = j;
    }
    if pos == 0.0 || neg == 0.0 {
        return None;
    }
    Some((rank_sum - pos * (pos + 1.0) / 2.0) / (pos * neg))
}

#[cfg(test)]
mod tests {
    use super::fit::weighted_logloss;
    use super::search::{PARALLEL_MIN_EXAMPLES, n_entropy};
    use super::*;

    fn one_feature(values: &[(u16, bool, Third)]) -> Examples {
        let mut ex = Examples::new(2, 4);
        for &(v, y, t) in values {
            ex.push_dense(&[v, 4 - v], y, t);
        }
        ex
    }

    #[test]
    fn auc_by_hand() {
        assert_eq!(
            roc_auc(&[0.1, 0.4, 0.35, 0.8], &[false, false, true, true]),
            Some(0.75)
        );
        // A tie between a positive and a negative counts half: (1 + 0.5) / 2.
        assert_eq!(roc_auc(&[0.2, 0.5, 0.5], &[false, false, true]), Some(0.75));
        assert_eq!(roc_auc(&[0.2, 0.5], &[true, true]), None);
    }

    #[test]
    fn metrics_by_hand() {
        let m = metrics(&[0.9, 0.2], &[true, false]);
        assert_eq!(m.accuracy, 1.0);
        let expected = -(0.9f64.ln() + 0.8f64.ln()) / 2.0;
        assert!((m.log_loss - expected).abs() < 1e-15);
    }

    #[test]
    fn entropy_gain_by_hand() {
        // 4 examples, 2 positive: 4 ln 4 - 2 ln 2 - 2 ln 2 = 4 ln 2.
        assert!((n_entropy(4, 2) - 4.0 * 2f64.ln()).abs() < 1e-12);
        assert_eq!(n_entropy(5, 0), 0.0);
    }

    #[test]
    fn separable_feature_gives_one_split_at_the_midpoint() {
        use Third::*;
        // Positives have count 3 or 4 of feature 0, negatives 0 or 1: the best threshold lies
        // between counts 1 and 3, i.e. value (1 + 3) / 2 / 4 = 0.5.
        let mut v = Vec::new();
        for t in [Train, Test, Prune] {
            for _ in 0..10 {
                v.push((0, false, t));
                v.push((1, false, t));
            }
            v.push((3, true, t));
            v.push((4, true, t));
        }
        let ex = one_feature(&v);
        let (tree, report) = fit(&ex, &TreeParams::default()).unwrap();
        assert_eq!(tree.nodes.len(), 3);
        let s = tree.nodes[0].split.clone().unwrap();
        // Feature 1 (= 4 - v) separates equally well; feature 0 wins the tie.
        assert_eq!(s.feature, 0);
        assert_eq!(s.threshold, 0.5);
        // Left leaf: 20 negatives, 0 positives; prior = 2 / 22; m = 2; 5 % base rate mixed in.
        let prior = 2.0 / 22.0;
        let left = &tree.nodes[s.left as usize];
        assert_eq!((left.n_train, left.pos_train), (20, 0));
        assert_eq!(left.p, 0.95 * ((2.0 * prior) / (20.0 + 2.0)) + 0.05 * prior);
        let right = &tree.nodes[s.right as usize];
        assert_eq!(
            right.p,
            0.95 * ((2.0 + 2.0 * prior) / (2.0 + 2.0)) + 0.05 * prior
        );
        assert_eq!(report.base_rate, prior);
        assert_eq!(report.expansions_kept, 1);
        assert_eq!(tree.predict_counts(&[1, 3], 4.0), left.p);
        assert_eq!(tree.predict_counts(&[3, 1], 4.0), right.p);
        tree.validate().unwrap();
    }

    /// A node large enough to be searched in chunks gives the same tree for any thread
    /// count, and a tie between two features in different workers' ranges still goes to the
    /// lower feature, as in one sequential scan.
    #[test]
    fn chunked_search_gives_the_same_tree_for_any_thread_count() {
        let n_features = 40;
        let mut ex = Examples::new(n_features, 16);
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for i in 0..(3 * PARALLEL_MIN_EXAMPLES) {
            let label = next() % 10 == 0;
            let mut counts = vec![0u16; n_features];
            for c in counts.iter_mut() {
                *c = (next() % 17) as u16;
            }
            // Features 5 and 35 (in different ranges for 2, 3 and 4 workers) carry the same
            // signal: identical gains.
            let signal = if label {
                12 + (next() % 5) as u16
            } else {
                (next() % 14) as u16
            };
            counts[5] = signal;
            counts[35] = signal;
            let third = [Third::Train, Third::Test, Third::Prune][i % 3];
            ex.push_dense(&counts, label, third);
        }
        let fit_with = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| fit(&ex, &TreeParams::default()).unwrap().0)
        };
        let one = fit_with(1);
        assert_eq!(one.nodes[0].split.as_ref().unwrap().feature, 5);
        assert!(one.nodes.len() > 3, "{} nodes", one.nodes.len());
        for threads in [2, 3, 4] {
            assert_eq!(fit_with(threads), one, "{threads} threads");
        }
    }

    #[test]
    fn noise_split_is_cut_by_test_or_pruning() {
        use Third::*;
        // Training says count 2 is positive (one example); test and prune say it is not.
        let mut v = Vec::new();
        for t in [Train, Test, Prune] {
            for _ in 0..20 {
                v.push((0, false, t));
            }
            v.push((2, t == Train, t));
            v.push((0, true, t));
        }
        let ex = one_feature(&v);
        let (tree, report) = fit(&ex, &TreeParams::default()).unwrap();
        assert_eq!(report.expansions_tried, 1);
        assert_eq!(report.expansions_kept, 0);
        assert_eq!(tree.nodes.len(), 1);
        // Root leaf: 2 positives of 22, m-estimate toward the same base rate = the base rate.
        assert!((tree.nodes[0].p - 2.0 / 22.0).abs() < 1e-15);
    }

    #[test]
    fn two_stray_pruning_negatives_condense_a_split_only_without_pseudo_examples() {
        use Third::*;
        // A rare object: count 3 is positive in training (10 of 10) and test (3 of 3), but
        // the pruning third happens to hold no positive there, only 2 negatives.
        let mut v = Vec::new();
        v.extend(std::iter::repeat_n((0, false, Train), 10_000));
        v.extend(std::iter::repeat_n((3, true, Train), 10));
        v.extend(std::iter::repeat_n((0, false, Test), 1_000));
        v.extend(std::iter::repeat_n((3, true, Test), 3));
        v.extend(std::iter::repeat_n((0, false, Prune), 1_000));
        v.extend(std::iter::repeat_n((3, false, Prune), 2));
        let ex = one_feature(&v);
        let bare = TreeParams {
            prune_pseudo: 0.0,
            ..TreeParams::default()
        };
        let (tree, report) = fit(&ex, &bare).unwrap();
        assert_eq!(report.nodes_grown, 3);
        // Root as a leaf: 1002 negatives at p ~ 0.001 cost ~1 nat; the split sends the 2 stray
        // negatives to p ~ 0.8 (~3.2 nats): the bare rule condenses it.
        assert_eq!(tree.nodes.len(), 1);
        // Two pseudo-examples per leaf at its training fraction: 2 positives in the right
        // leaf cost ~0.45 nats under the split and ~14 as the root leaf: the split stays.
        let (tree, _) = fit(&ex, &TreeParams::default()).unwrap();
        assert_eq!(tree.nodes.len(), 3);
        let leaf_loss = |n: f64, pos: f64, p: f64| weighted_logloss(n, pos, p);
        let s = tree.nodes[0].split.clone().unwrap();
        let (l, r) = (&tree.nodes[s.left as usize], &tree.nodes[s.right as usize]);
        let as_split = leaf_loss(1_002.0, 0.0, l.p) + leaf_loss(4.0, 2.0, r.p);
        let as_leaf = leaf_loss(1_006.0, 2.0, tree.nodes[0].p);
        assert!(as_split < as_leaf, "{as_split} vs {as_leaf}");
    }

    #[test]
    fn base_rate_mix_bounds_how_far_below_the_base_rate_a_leaf_goes() {
        use Third::*;
        let mut v = Vec::new();
        v.extend(std::iter::repeat_n((0, false, Train), 100_000));
        v.extend(std::iter::repeat_n((3, true, Train), 100));
        for t in [Test, Prune] {
            v.extend(std::iter::repeat_n((0, false, t), 1_000));
            v.extend(std::iter::repeat_n((3, true, t), 10));
        }
        let ex = one_feature(&v);
        let prior = 100.0 / 100_100.0;
        for mix in [0.0, 0.05] {
            let params = TreeParams {
                base_mix: mix,
                ..TreeParams::default()
            };
            let (tree, _) = fit(&ex, &params).unwrap();
            let left = &tree.nodes[tree.nodes[0].split.clone().unwrap().left as usize];
            let m_est = 2.0 * prior / (100_000.0 + 2.0);
            assert!((left.p - ((1.0 - mix) * m_est + mix * prior)).abs() < 1e-18);
            // One such tile moves a cell's log-odds by ln(p / prior) (rare positives): -10.8
            // bare, bounded by ln(0.05) = -3.0 with the mix.
            let evidence = (left.p / prior).ln();
            if mix == 0.0 {
                assert!(evidence < -10.0, "{evidence}");
            } else {
                assert!(
                    evidence > 0.05f64.ln() && evidence < 0.051f64.ln(),
                    "{evidence}"
                );
            }
        }
    }

    #[test]
    fn validate_refuses_loops_and_bad_probabilities() {
        let mut t = Tree {
            n_features: 1,
            nodes: vec![
                Node {
                    p: 0.5,
                    n_train: 1,
                    pos_train: 0,
                    split: Some(Split {
                        feature: 0,
                        threshold: 0.5,
                        left: 0,
                        right: 1,
                    }),
                },
                Node {
                    p: 0.0,
                    n_train: 1,
                    pos_train: 0,
                    split: None,
                },
            ],
        };
        assert_eq!(
            t.validate(),
            Err(TreeError::BadChild {
                node: 0,
                child: 0,
                len: 2
            })
        );
        if let Some(s) = &mut t.nodes[0].split {
            s.left = 1;
        }
        assert_eq!(
            t.validate(),
            Err(TreeError::BadProbability { node: 1, p: 0.0 })
        );
        t.nodes[1].p = 0.1;
        assert_eq!(t.validate(), Ok(()));
    }
}
