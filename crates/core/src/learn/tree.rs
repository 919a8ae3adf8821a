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

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use rayon::prelude::*;

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Which third of the examples an example belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
pub enum Third {
    Train = 0,
    Test = 1,
    Prune = 2,
}

/// Sparse examples with integer feature counts: feature value = count / `denom`.
/// Example i has the (feature, count) pairs `entries[offsets[i]..offsets[i + 1]]`, features
/// strictly increasing, counts > 0; absent features are 0.
#[derive(Debug, Clone, Default)]
pub struct Examples {
    pub n_features: usize,
    /// Largest possible count (the value 1.0).
    pub denom: u16,
    pub offsets: Vec<u32>,
    pub entries: Vec<(u16, u16)>,
    pub labels: Vec<bool>,
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
    pub fn new(n_features: usize, denom: u16) -> Self {
        Self {
            n_features,
            denom,
            offsets: vec![0],
            ..Self::default()
        }
    }

    pub fn len(&self) -> usize {
        self.labels.len()
    }

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

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Split {
    pub feature: u16,
    /// Go left when the feature value (a fraction in [0, 1]) is <= threshold. Always the
    /// midpoint between two neighbouring distinct training values.
    pub threshold: f64,
    pub left: u32,
    pub right: u32,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Node {
    /// Probability of the positive class when this node is (or is condensed into) a leaf.
    pub p: f64,
    /// Training examples reaching this node, and how many were positive.
    pub n_train: u32,
    pub pos_train: u32,
    pub split: Option<Split>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Tree {
    pub n_features: usize,
    pub nodes: Vec<Node>,
}

#[derive(Debug, Error, PartialEq)]
pub enum TreeError {
    #[error("tree has no nodes")]
    Empty,
    #[error("node {node}: child {child} is not after it and before {len}")]
    BadChild { node: usize, child: u32, len: usize },
    #[error("node {node}: feature {feature} is not below the {n_features} features")]
    BadFeature {
        node: usize,
        feature: u16,
        n_features: usize,
    },
    #[error("node {node}: probability {p} is not strictly between 0 and 1")]
    BadProbability { node: usize, p: f64 },
    #[error("node {node}: threshold {threshold} is not finite")]
    BadThreshold { node: usize, threshold: f64 },
    #[error("no training examples")]
    NoTrainingExamples,
    #[error(
        "{n_entries} feature entries for {n_features} features with denominator {denom}: an entry is out of range"
    )]
    BadExamples {
        n_entries: usize,
        n_features: usize,
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
    pub base_rate: f64,
    /// Expansions made before the test third stopped growth, and the count kept (the one
    /// with the best test log-loss).
    pub expansions_tried: usize,
    pub expansions_kept: usize,
    pub nodes_grown: usize,
    pub depth_grown: usize,
    pub nodes_pruned: usize,
    pub depth_pruned: usize,
    /// Mean log-loss of the test third after each kept expansion count (index 0 = root only).
    pub test_logloss_curve: Vec<f64>,
}

/// `n ln n - p ln p - (n-p) ln (n-p)`: n times the entropy (nats) of a node with p positives.
#[inline]
fn n_entropy(n: u32, p: u32) -> f64 {
    #[inline]
    fn xlx(x: u32) -> f64 {
        if x == 0 {
            0.0
        } else {
            let x = x as f64;
            x * x.ln()
        }
    }
    xlx(n) - xlx(p) - xlx(n - p)
}

/// Summed log-loss of `n` examples with `pos` positives all given probability `p`.
#[inline]
fn summed_logloss(n: u32, pos: u32, p: f64) -> f64 {
    weighted_logloss(n as f64, pos as f64, p)
}

/// [`summed_logloss`] for fractional (pseudo-)counts.
#[inline]
fn weighted_logloss(n: f64, pos: f64, p: f64) -> f64 {
    let mut s = 0.0;
    if pos > 0.0 {
        s -= pos * p.ln();
    }
    if n > pos {
        s -= (n - pos) * (1.0 - p).ln();
    }
    s
}

#[derive(Debug, Clone, Copy)]
struct Candidate {
    gain: f64,
    feature: u16,
    /// Left = count <= lo; lo and hi are neighbouring distinct counts of the node.
    lo: u16,
    hi: u16,
}

#[derive(Debug, Default)]
struct Work {
    idx: [Vec<u32>; 3],
    /// (n, pos) per third.
    counts: [(u32, u32); 3],
    split: Option<(Candidate, u32, u32)>,
    best: Option<Candidate>,
}

/// Scratch histograms for the split search, reused across nodes: one set per worker.
struct SplitSearch {
    width: usize,
    parts: Vec<Scratch>,
}

/// (feature, count) histograms of examples and positives, and per-feature non-zero counts.
struct Scratch {
    hist_n: Vec<u32>,
    hist_pos: Vec<u32>,
    nnz: Vec<u32>,
    nnz_pos: Vec<u32>,
}

/// Nodes with at least this many training examples are searched by every worker: the root
/// of the region head's 300 k examples took most of a single-threaded fit. Below it the
/// split into chunks costs more than it saves.
const PARALLEL_MIN_EXAMPLES: usize = 16_384;

impl Scratch {
    fn new(n_features: usize, width: usize) -> Self {
        Self {
            hist_n: vec![0; n_features * width],
            hist_pos: vec![0; n_features * width],
            nnz: vec![0; n_features],
            nnz_pos: vec![0; n_features],
        }
    }

    fn add_examples(&mut self, ex: &Examples, idx: &[u32], w: usize) {
        for &i in idx {
            let y = ex.labels[i as usize] as u32;
            for &(f, c) in ex.sparse(i as usize) {
                let k = f as usize * w + c as usize;
                self.hist_n[k] += 1;
                self.hist_pos[k] += y;
                self.nnz[f as usize] += 1;
                self.nnz_pos[f as usize] += y;
            }
        }
    }

    /// Zeroes what `idx` touched (cheap for small nodes).
    fn reset_touched(&mut self, ex: &Examples, idx: &[u32], w: usize) {
        for &i in idx {
            for &(f, c) in ex.sparse(i as usize) {
                let k = f as usize * w + c as usize;
                self.hist_n[k] = 0;
                self.hist_pos[k] = 0;
                self.nnz[f as usize] = 0;
                self.nnz_pos[f as usize] = 0;
            }
        }
    }

    /// Adds `other` into `self` and zeroes `other` (whole arrays: for large nodes).
    fn absorb(&mut self, other: &mut Scratch) {
        for (a, b) in [
            (&mut self.hist_n, &mut other.hist_n),
            (&mut self.hist_pos, &mut other.hist_pos),
            (&mut self.nnz, &mut other.nnz),
            (&mut self.nnz_pos, &mut other.nnz_pos),
        ] {
            for (x, y) in a.iter_mut().zip(b.iter_mut()) {
                *x += *y;
                *y = 0;
            }
        }
    }

    fn clear(&mut self) {
        self.hist_n.fill(0);
        self.hist_pos.fill(0);
        self.nnz.fill(0);
        self.nnz_pos.fill(0);
    }

    /// The first best split among `features`, in (feature, threshold) order: a later
    /// candidate replaces it only with a strictly larger gain.
    fn scan(
        &self,
        features: std::ops::Range<usize>,
        w: usize,
        n: u32,
        pos: u32,
    ) -> Option<Candidate> {
        let parent = n_entropy(n, pos);
        let mut best: Option<Candidate> = None;
        // Gains below this are rounding noise of the n ln n sums, not information.
        let min_gain = 1e-9 * (n as f64).max(1.0);
        for f in features {
            let nnz = self.nnz[f];
            if nnz == 0 {
                continue;
            }
            let mut ln = n - nnz;
            let mut lp = pos - self.nnz_pos[f];
            let mut prev = 0u16;
            let row = f * w;
            for c in 1..w {
                let cn = self.hist_n[row + c];
                if cn == 0 {
                    continue;
                }
                if ln > 0 {
                    let gain = parent - n_entropy(ln, lp) - n_entropy(n - ln, pos - lp);
                    if gain > min_gain && best.is_none_or(|b| gain > b.gain) {
                        best = Some(Candidate {
                            gain,
                            feature: f as u16,
                            lo: prev,
                            hi: c as u16,
                        });
                    }
                }
                ln += cn;
                lp += self.hist_pos[row + c];
                prev = c as u16;
            }
        }
        best
    }
}

impl SplitSearch {
    fn new(n_features: usize, denom: u16) -> Self {
        let width = denom as usize + 1;
        // Large tiles make every histogram large (256 features x 65 026 counts for 255 px
        // tiles): one set then, as summing and clearing whole sets would cost more than the
        // chunks save.
        let workers = if n_features * width <= 1 << 22 {
            rayon::current_num_threads().clamp(1, 8)
        } else {
            1
        };
        Self {
            width,
            parts: (0..workers)
                .map(|_| Scratch::new(n_features, width))
                .collect(),
        }
    }

    /// Best split of the node holding training examples `idx`: every threshold between
    /// neighbouring distinct values is scored. Counts are small integers, so a per-node
    /// histogram over (feature, count) replaces sorting; only non-zero entries are touched
    /// (zeros are implied by n - nnz), which is what makes sparse histograms cheap.
    ///
    /// A large node is split among the workers: each builds the histograms of a chunk of
    /// examples, they are summed (integers: the same for any split), and each scans a range
    /// of features; the ranges' winners are taken in feature order with the same strict
    /// comparison as one scan, so the result is the same for any thread count.
    fn best(&mut self, ex: &Examples, idx: &[u32], n: u32, pos: u32) -> Option<Candidate> {
        if n < 2 || pos == 0 || pos == n {
            return None;
        }
        let w = self.width;
        let workers = if idx.len() >= PARALLEL_MIN_EXAMPLES {
            self.parts.len()
        } else {
            1
        };
        if workers == 1 {
            let s = &mut self.parts[0];
            s.add_examples(ex, idx, w);
            let best = s.scan(0..s.nnz.len(), w, n, pos);
            s.reset_touched(ex, idx, w);
            return best;
        }
        let chunk = idx.len().div_ceil(workers);
        self.parts[..workers]
            .par_iter_mut()
            .zip(idx.par_chunks(chunk))
            .for_each(|(s, part)| s.add_examples(ex, part, w));
        let (first, rest) = self.parts.split_at_mut(1);
        for other in &mut rest[..workers - 1] {
            first[0].absorb(other);
        }
        let s = &first[0];
        let n_features = s.nnz.len();
        let per = n_features.div_ceil(workers);
        let winners: Vec<Option<Candidate>> = (0..workers)
            .into_par_iter()
            .map(|k| s.scan(k * per..((k + 1) * per).min(n_features), w, n, pos))
            .collect();
        first[0].clear();
        winners.into_iter().flatten().fold(None, |best, c| {
            if best.is_none_or(|b: Candidate| c.gain > b.gain) {
                Some(c)
            } else {
                best
            }
        })
    }
}

/// Heap entry: largest gain first, then lowest node index.
struct Queued {
    gain: f64,
    node: u32,
}
impl PartialEq for Queued {
    fn eq(&self, o: &Self) -> bool {
        self.cmp(o) == Ordering::Equal
    }
}
impl Eq for Queued {}
impl PartialOrd for Queued {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Queued {
    fn cmp(&self, o: &Self) -> Ordering {
        self.gain
            .total_cmp(&o.gain)
            .then_with(|| o.node.cmp(&self.node))
    }
}

fn m_estimate(n: u32, pos: u32, prior: f64, m: f64) -> f64 {
    (pos as f64 + m * prior) / (n as f64 + m)
}

/// Grows a tree on the training third best-first (largest total information gain first),
/// tracking the test third's log-loss after every expansion; growth stops when
/// `params.patience` expansions in a row bring no new best, and the tree is cut back to the
/// expansion count with the best test log-loss. Then the paper's pruning runs top-down on the
/// pruning third: each node, from the root, is condensed into a leaf, and the condensation is
/// kept when the pruning third's log-loss does not get worse (ties prune: the smaller tree
/// wins); otherwise the node is restored and its children are tried. Each grown leaf adds
/// `params.prune_pseudo` examples at its training fraction to the pruning third (why: at
/// the `prune_counts` below).
///
/// Leaf probability: `(1 - base_mix) * (pos + m * base_rate) / (n + m) + base_mix *
/// base_rate`. The m-estimate alone puts a pure-negative leaf of 60 000 training tiles at
/// 6e-8, i.e. -10 in log-odds against the object from one tile; when the object's cell
/// projects into a background tile (its edge, a pose a few pixels off), that one view
/// outweighs two positive ones. On bottle-tour the object vanished from the grid. The mix
/// reads as "a tile's class says nothing about the cell one time in twenty" and bounds a
/// tile's evidence against the object at ln(base_mix) = -3.0 for the default, while keeping
/// every background tile below the base rate (evidence against, unlike a fixed floor) and
/// the leaves' order (AUC unchanged).
pub fn fit(ex: &Examples, params: &TreeParams) -> Result<(Tree, FitReport), TreeError> {
    let denom_ok = ex
        .entries
        .iter()
        .all(|&(f, c)| (f as usize) < ex.n_features && c <= ex.denom);
    if !denom_ok || ex.denom == 0 {
        return Err(TreeError::BadExamples {
            n_entries: ex.entries.len(),
            n_features: ex.n_features,
            denom: ex.denom,
        });
    }
    let mut root = Work::default();
    for i in 0..ex.len() {
        let t = ex.thirds[i] as usize;
        root.idx[t].push(i as u32);
        root.counts[t].0 += 1;
        root.counts[t].1 += ex.labels[i] as u32;
    }
    let (n_train, pos_train) = root.counts[Third::Train as usize];
    if n_train == 0 {
        return Err(TreeError::NoTrainingExamples);
    }
    let prior = pos_train as f64 / n_train as f64;
    // With no positive (or no negative) training example the prior would be 0 or 1; keep
    // every probability inside (0, 1) with a half-example pseudo-count instead.
    let prior = prior.clamp(
        0.5 / (n_train as f64 + 1.0),
        1.0 - 0.5 / (n_train as f64 + 1.0),
    );
    let m = params.m_estimate.max(f64::MIN_POSITIVE);
    let mix = params.base_mix.clamp(0.0, 1.0);
    let leaf_p = |w: &Work| {
        let (n, pos) = w.counts[Third::Train as usize];
        (1.0 - mix) * m_estimate(n, pos, prior, m) + mix * prior
    };
    let loss_of = |w: &Work, third: Third| {
        let (n, pos) = w.counts[third as usize];
        summed_logloss(n, pos, leaf_p(w))
    };

    let mut search = SplitSearch::new(ex.n_features, ex.denom);
    root.best = search.best(ex, &root.idx[0], n_train, pos_train);
    let mut nodes = vec![root];
    let mut heap = BinaryHeap::new();
    if let Some(c) = nodes[0].best {
        heap.push(Queued {
            gain: c.gain,
            node: 0,
        });
    }
    let (n_test, _) = nodes[0].counts[Third::Test as usize];
    let mean = |s: f64| if n_test > 0 { s / n_test as f64 } else { 0.0 };
    let mut test_loss = loss_of(&nodes[0], Third::Test);
    let mut curve = vec![mean(test_loss)];
    let mut best_loss = test_loss;
    let mut best_at = 0usize;
    let mut expanded: Vec<u32> = Vec::new();
    while let Some(Queued { node, .. }) = heap.pop() {
        if expanded.len() >= params.max_expansions || expanded.len() - best_at >= params.patience {
            break;
        }
        let Some(c) = nodes[node as usize].best else {
            continue;
        };
        let mut left = Work::default();
        let mut right = Work::default();
        let parent = std::mem::take(&mut nodes[node as usize].idx);
        for (t, part) in parent.iter().enumerate() {
            for &i in part {
                let y = ex.labels[i as usize] as u32;
                let w = if ex.count(i as usize, c.feature) <= c.lo {
                    &mut left
                } else {
                    &mut right
                };
                w.idx[t].push(i);
                w.counts[t].0 += 1;
                w.counts[t].1 += y;
            }
        }
        // The training examples are needed no longer once the children are scored; the test
        // and pruning ones only as counts.
        for w in [&mut left, &mut right] {
            let (n, pos) = w.counts[0];
            w.best = search.best(ex, &w.idx[0], n, pos);
            if w.best.is_none() {
                w.idx = Default::default();
            }
        }
        test_loss += loss_of(&left, Third::Test) + loss_of(&right, Third::Test)
            - loss_of(&nodes[node as usize], Third::Test);
        let li = nodes.len() as u32;
        for (k, w) in [left, right].into_iter().enumerate() {
            if let Some(b) = w.best {
                heap.push(Queued {
                    gain: b.gain,
                    node: li + k as u32,
                });
            }
            nodes.push(w);
        }
        nodes[node as usize].split = Some((c, li, li + 1));
        expanded.push(node);
        curve.push(mean(test_loss));
        // A new best must beat the old by more than rounding noise.
        if test_loss < best_loss - 1e-12 * best_loss.abs() {
            best_loss = test_loss;
            best_at = expanded.len();
        }
    }
    let expansions_tried = expanded.len();
    for &node in &expanded[best_at..] {
        nodes[node as usize].split = None;
    }
    curve.truncate(best_at + 1);

    let denom = ex.denom as f64;
    let mut tree = compact(&nodes, ex.n_features, denom, &leaf_p);
    let nodes_grown = tree.nodes.len();
    let depth_grown = tree.depth();

    // Pruning third counts per compacted node, for the top-down condensation, each grown
    // leaf topped up with `prune_pseudo` examples distributed as its training examples.
    // Why: the pruning third of a small object holds about ten positives, so whether a
    // region of feature space keeps its split hangs on whether one of them happens to fall
    // there. Measured on bottle-train (rgb332): a split holding 17 of 20 training and 4 of 5
    // test examples positive was condensed because its only pruning examples were 2
    // negatives, and test log-loss went from 0.0016 to 0.0069 (AUC 0.9998 -> 0.82). With the
    // pseudo-examples a condensation must be carried by the pruning data against the
    // training evidence, not by an empty cell; in a well-populated region two examples change
    // nothing.
    let prune_counts = {
        let mut map = vec![(0f64, 0f64); tree.nodes.len()];
        collect_counts(&nodes, 0, &mut 0, &mut map, params.prune_pseudo.max(0.0));
        map
    };
    let prune_loss = |i: usize, p: f64| {
        let (n, pos) = prune_counts[i];
        weighted_logloss(n, pos, p)
    };
    prune_top_down(&mut tree, 0, &prune_loss);
    let tree = compact_tree(&tree);
    let report = FitReport {
        base_rate: pos_train as f64 / n_train as f64,
        expansions_tried,
        expansions_kept: best_at,
        nodes_grown,
        depth_grown,
        nodes_pruned: tree.nodes.len(),
        depth_pruned: tree.depth(),
        test_logloss_curve: curve,
    };
    Ok((tree, report))
}

/// Pre-order renumbering of the reachable work nodes into a [`Tree`].
fn compact(nodes: &[Work], n_features: usize, denom: f64, leaf_p: &dyn Fn(&Work) -> f64) -> Tree {
    fn go(
        nodes: &[Work],
        i: usize,
        out: &mut Vec<Node>,
        denom: f64,
        leaf_p: &dyn Fn(&Work) -> f64,
    ) -> u32 {
        let me = out.len() as u32;
        let w = &nodes[i];
        let (n, pos) = w.counts[Third::Train as usize];
        out.push(Node {
            p: leaf_p(w),
            n_train: n,
            pos_train: pos,
            split: None,
        });
        if let Some((c, l, r)) = w.split {
            let left = go(nodes, l as usize, out, denom, leaf_p);
            let right = go(nodes, r as usize, out, denom, leaf_p);
            out[me as usize].split = Some(Split {
                feature: c.feature,
                threshold: (c.lo as f64 + c.hi as f64) / 2.0 / denom,
                left,
                right,
            });
        }
        me
    }
    let mut out = Vec::new();
    go(nodes, 0, &mut out, denom, leaf_p);
    Tree {
        n_features,
        nodes: out,
    }
}

/// Pruning-third (n, pos) of work nodes in the same pre-order as [`compact`], with `pseudo`
/// examples per leaf at the leaf's training fraction; returns node `i`'s counts.
fn collect_counts(
    nodes: &[Work],
    i: usize,
    next: &mut usize,
    out: &mut [(f64, f64)],
    pseudo: f64,
) -> (f64, f64) {
    let me = *next;
    *next += 1;
    let counts = match nodes[i].split {
        Some((_, l, r)) => {
            let a = collect_counts(nodes, l as usize, next, out, pseudo);
            let b = collect_counts(nodes, r as usize, next, out, pseudo);
            (a.0 + b.0, a.1 + b.1)
        }
        None => {
            let (n, pos) = nodes[i].counts[Third::Prune as usize];
            let (n_train, pos_train) = nodes[i].counts[Third::Train as usize];
            let q = if n_train > 0 {
                pos_train as f64 / n_train as f64
            } else {
                0.0
            };
            (n as f64 + pseudo, pos as f64 + pseudo * q)
        }
    };
    out[me] = counts;
    counts
}

fn subtree_loss(tree: &Tree, i: usize, loss: &dyn Fn(usize, f64) -> f64) -> f64 {
    match &tree.nodes[i].split {
        None => loss(i, tree.nodes[i].p),
        Some(s) => {
            subtree_loss(tree, s.left as usize, loss) + subtree_loss(tree, s.right as usize, loss)
        }
    }
}

fn prune_top_down(tree: &mut Tree, i: usize, loss: &dyn Fn(usize, f64) -> f64) {
    let Some(s) = tree.nodes[i].split.clone() else {
        return;
    };
    let as_subtree = subtree_loss(tree, i, loss);
    let as_leaf = loss(i, tree.nodes[i].p);
    // "Does not get worse", with rounding noise of the summation counted as equal.
    if as_leaf <= as_subtree + 1e-12 * as_subtree.abs() {
        tree.nodes[i].split = None;
    } else {
        prune_top_down(tree, s.left as usize, loss);
        prune_top_down(tree, s.right as usize, loss);
    }
}

/// Drops nodes no longer reachable from the root, renumbering in pre-order.
fn compact_tree(tree: &Tree) -> Tree {
    fn go(tree: &Tree, i: usize, out: &mut Vec<Node>) -> u32 {
        let me = out.len() as u32;
        let mut node = tree.nodes[i].clone();
        node.split = None;
        out.push(node);
        if let Some(s) = &tree.nodes[i].split {
            let left = go(tree, s.left as usize, out);
            let right = go(tree, s.right as usize, out);
            out[me as usize].split = Some(Split {
                left,
                right,
                ..s.clone()
            });
        }
        me
    }
    let mut out = Vec::new();
    go(tree, 0, &mut out);
    Tree {
        n_features: tree.n_features,
        nodes: out,
    }
}

/// Quality of probabilities against labels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Metrics {
    pub n: usize,
    pub positives: usize,
    /// Fraction correct when p >= 0.5 means positive.
    pub accuracy: f64,
    /// Mean negative log-likelihood (nats).
    pub log_loss: f64,
    /// Area under the ROC curve; None without both classes.
    pub roc_auc: Option<f64>,
}

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
