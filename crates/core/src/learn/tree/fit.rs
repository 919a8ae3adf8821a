//! Tree fitting: best-first growth on the training third, stopped and cut back by the test
//! third, then top-down pruning on the pruning third (the paper's procedure; see [`fit`]).
//!
//! Invariants: single-threaded apart from the split search (whose result does not depend on
//! the thread count); every tie has a fixed break (largest gain, then lowest node index), so
//! the same examples give the same tree bit for bit.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use super::forest::Randomise;
use super::search::{Candidate, SplitSearch};
use super::{Examples, FitReport, Node, Split, Third, Tree, TreeError, TreeParams};

/// Summed log-loss of `n` examples with `pos` positives all given probability `p`.
#[inline]
fn summed_logloss(n: u32, pos: u32, p: f64) -> f64 {
    weighted_logloss(n as f64, pos as f64, p)
}

/// [`summed_logloss`] for fractional (pseudo-)counts.
#[inline]
pub(super) fn weighted_logloss(n: f64, pos: f64, p: f64) -> f64 {
    let mut s = 0.0;
    if pos > 0.0 {
        s -= pos * p.ln();
    }
    if n > pos {
        s -= (n - pos) * (1.0 - p).ln();
    }
    s
}

/// A node while the tree grows: its examples by third (until no longer needed), their
/// counts, the split made and the best split found.
#[derive(Debug, Default)]
struct Work {
    idx: [Vec<u32>; 3],
    /// (n, pos) per third.
    counts: [(u32, u32); 3],
    split: Option<(Candidate, u32, u32)>,
    best: Option<Candidate>,
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

/// Leaf probabilities: the m-estimate toward the base rate, mixed with the base rate.
struct LeafModel {
    /// Base rate of the training third, kept inside (0, 1).
    prior: f64,
    m: f64,
    mix: f64,
}

impl LeafModel {
    /// The leaf model for a training third with `pos_train` positives of `n_train` (> 0).
    fn new(n_train: u32, pos_train: u32, params: &TreeParams) -> Self {
        let prior = pos_train as f64 / n_train as f64;
        // With no positive (or no negative) training example the prior would be 0 or 1; keep
        // every probability inside (0, 1) with a half-example pseudo-count instead.
        let prior = prior.clamp(
            0.5 / (n_train as f64 + 1.0),
            1.0 - 0.5 / (n_train as f64 + 1.0),
        );
        Self {
            prior,
            m: params.m_estimate.max(f64::MIN_POSITIVE),
            mix: params.base_mix.clamp(0.0, 1.0),
        }
    }

    /// Probability of a leaf holding the training examples of `w`.
    fn p(&self, w: &Work) -> f64 {
        let (n, pos) = w.counts[Third::Train as usize];
        (1.0 - self.mix) * m_estimate(n, pos, self.prior, self.m) + self.mix * self.prior
    }

    /// Summed log-loss of the examples of `third` at `w` were `w` a leaf.
    fn loss(&self, w: &Work, third: Third) -> f64 {
        let (n, pos) = w.counts[third as usize];
        summed_logloss(n, pos, self.p(w))
    }
}

/// Grows a tree on the training third best-first (largest total information gain first),
/// tracking the test third's log-loss after every expansion; growth stops when
/// `params.patience` expansions in a row bring no new best, and the tree is cut back to the
/// expansion count with the best test log-loss. Then the paper's pruning runs top-down on the
/// pruning third: each node, from the root, is condensed into a leaf, and the condensation is
/// kept when the pruning third's log-loss does not get worse (ties prune: the smaller tree
/// wins); otherwise the node is restored and its children are tried. Each grown leaf adds
/// `params.prune_pseudo` examples at its training fraction to the pruning third (why: at
/// the pruning counts in `prune`).
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
    fit_randomised(ex, params, None)
}

/// [`fit`], with `randomise` (a forest's tree): growth sees only the training examples
/// [`Randomise::keeps`] (all of them if it keeps none), its leaves smooth toward their rate,
/// and each node splits on the features [`Randomise::features`] draws for it (a draw may
/// hold features that are constant at the node: docs/tree.md, "A forest for captures", for
/// why); the test and pruning thirds are whole, so every tree is stopped and pruned on the
/// same examples as the paper's.
pub fn fit_randomised(
    ex: &Examples,
    params: &TreeParams,
    randomise: Option<&Randomise>,
) -> Result<(Tree, FitReport), TreeError> {
    check_examples(ex)?;
    let mut root = root_work(ex, randomise);
    if randomise.is_some() && root.counts[Third::Train as usize].0 == 0 {
        // A tiny training third whose draw kept nothing: the tree grows on all of it.
        root = root_work(ex, None);
    }
    let (n_train, pos_train) = root.counts[Third::Train as usize];
    if n_train == 0 {
        return Err(TreeError::NoTrainingExamples);
    }
    let leaf = LeafModel::new(n_train, pos_train, params);
    let mut growth = Growth::start(ex, root, &leaf, randomise.copied());
    growth.run(ex, params, &leaf);
    let expansions_tried = growth.expanded.len();
    growth.cut_back();

    let denom = ex.denom as f64;
    let mut tree = compact(&growth.nodes, ex.n_features, denom, &|w: &Work| leaf.p(w));
    let nodes_grown = tree.nodes.len();
    let depth_grown = tree.depth();
    prune(&mut tree, &growth.nodes, params.prune_pseudo);
    let tree = compact_tree(&tree);
    let report = FitReport {
        base_rate: pos_train as f64 / n_train as f64,
        expansions_tried,
        expansions_kept: growth.best_at,
        nodes_grown,
        depth_grown,
        nodes_pruned: tree.nodes.len(),
        depth_pruned: tree.depth(),
        test_logloss_curve: growth.curve,
    };
    Ok((tree, report))
}

/// Refuses examples with a feature or a count outside their declared ranges.
fn check_examples(ex: &Examples) -> Result<(), TreeError> {
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
    Ok(())
}

/// The root's work node: every example, by third (of the training third, those `randomise`
/// keeps).
fn root_work(ex: &Examples, randomise: Option<&Randomise>) -> Work {
    let mut root = Work::default();
    for i in 0..ex.len() {
        let t = ex.thirds[i] as usize;
        if t == Third::Train as usize && randomise.is_some_and(|r| !r.keeps(i)) {
            continue;
        }
        root.idx[t].push(i as u32);
        root.counts[t].0 += 1;
        root.counts[t].1 += ex.labels[i] as u32;
    }
    root
}

/// Best-first growth: the work nodes so far, the queue of expandable ones, and the test
/// third's log-loss after each expansion.
struct Growth {
    search: SplitSearch,
    /// A forest tree's draws (None: the paper's tree, every feature at every node).
    randomise: Option<Randomise>,
    nodes: Vec<Work>,
    heap: BinaryHeap<Queued>,
    /// Test-third examples (for the mean log-loss).
    n_test: u32,
    /// Summed test-third log-loss of the tree as grown so far.
    test_loss: f64,
    /// Mean test log-loss after each expansion count (index 0 = root only).
    curve: Vec<f64>,
    best_loss: f64,
    /// The expansion count with the best test log-loss.
    best_at: usize,
    /// Expanded nodes, in expansion order.
    expanded: Vec<u32>,
}

impl Growth {
    /// Growth that has the root alone, its best split queued.
    fn start(
        ex: &Examples,
        mut root: Work,
        leaf: &LeafModel,
        randomise: Option<Randomise>,
    ) -> Self {
        let mut search = SplitSearch::new(ex.n_features, ex.denom, randomise.is_none());
        let allowed = randomise.map(|r| r.features(0, ex.n_features));
        root.best = search.best(ex, &root.idx[0], root.counts[0], allowed.as_deref());
        let mut heap = BinaryHeap::new();
        if let Some(c) = root.best {
            heap.push(Queued {
                gain: c.gain,
                node: 0,
            });
        }
        let (n_test, _) = root.counts[Third::Test as usize];
        let test_loss = leaf.loss(&root, Third::Test);
        let mut growth = Self {
            search,
            randomise,
            nodes: vec![root],
            heap,
            n_test,
            test_loss,
            curve: Vec::new(),
            best_loss: test_loss,
            best_at: 0,
            expanded: Vec::new(),
        };
        growth.curve.push(growth.mean_test_loss());
        growth
    }

    /// Mean test-third log-loss of the tree as grown so far (0 without test examples).
    fn mean_test_loss(&self) -> f64 {
        if self.n_test > 0 {
            self.test_loss / self.n_test as f64
        } else {
            0.0
        }
    }

    /// Expands the queued node of largest gain, again and again, until the test third (or the
    /// expansion cap) stops growth.
    fn run(&mut self, ex: &Examples, params: &TreeParams, leaf: &LeafModel) {
        while let Some(Queued { node, .. }) = self.heap.pop() {
            if self.expanded.len() >= params.max_expansions
                || self.expanded.len() - self.best_at >= params.patience
            {
                break;
            }
            let Some(c) = self.nodes[node as usize].best else {
                continue;
            };
            self.expand(ex, node, c, leaf);
        }
    }

    /// Splits `node` by `c`, queues its children, and records the test log-loss.
    fn expand(&mut self, ex: &Examples, node: u32, c: Candidate, leaf: &LeafModel) {
        let parent = std::mem::take(&mut self.nodes[node as usize].idx);
        let (mut left, mut right) = partition(ex, &parent, c);
        // The training examples are needed no longer once the children are scored; the test
        // and pruning ones only as counts.
        let li = self.nodes.len() as u32;
        for (k, w) in [&mut left, &mut right].into_iter().enumerate() {
            let allowed = self
                .randomise
                .map(|r| r.features(li + k as u32, ex.n_features));
            w.best = self
                .search
                .best(ex, &w.idx[0], w.counts[0], allowed.as_deref());
            if w.best.is_none() {
                w.idx = Default::default();
            }
        }
        self.test_loss += leaf.loss(&left, Third::Test) + leaf.loss(&right, Third::Test)
            - leaf.loss(&self.nodes[node as usize], Third::Test);
        for (k, w) in [left, right].into_iter().enumerate() {
            if let Some(b) = w.best {
                self.heap.push(Queued {
                    gain: b.gain,
                    node: li + k as u32,
                });
            }
            self.nodes.push(w);
        }
        self.nodes[node as usize].split = Some((c, li, li + 1));
        self.expanded.push(node);
        self.curve.push(self.mean_test_loss());
        // A new best must beat the old by more than rounding noise.
        if self.test_loss < self.best_loss - 1e-12 * self.best_loss.abs() {
            self.best_loss = self.test_loss;
            self.best_at = self.expanded.len();
        }
    }

    /// Undoes the expansions made after the one with the best test log-loss.
    fn cut_back(&mut self) {
        for &node in &self.expanded[self.best_at..] {
            self.nodes[node as usize].split = None;
        }
        self.curve.truncate(self.best_at + 1);
    }
}

/// The two children of a node split by `c`: its examples of every third, by side.
fn partition(ex: &Examples, parent: &[Vec<u32>; 3], c: Candidate) -> (Work, Work) {
    let mut left = Work::default();
    let mut right = Work::default();
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
    (left, right)
}

/// The paper's top-down pruning of a compacted grown tree on the pruning third, each grown
/// leaf topped up with `pseudo` examples at its training fraction.
fn prune(tree: &mut Tree, nodes: &[Work], pseudo: f64) {
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
        collect_counts(nodes, 0, &mut 0, &mut map, pseudo.max(0.0));
        map
    };
    let prune_loss = |i: usize, p: f64| {
        let (n, pos) = prune_counts[i];
        weighted_logloss(n, pos, p)
    };
    prune_top_down(tree, 0, &prune_loss);
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
