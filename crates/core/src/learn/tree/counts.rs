//! A tree compiled for prediction on a tile's integer bin counts: each split's "count / denom
//! <= threshold" becomes "count <= the largest count that passes it", found with the same f64
//! comparison, so every tile reaches the leaf [`Tree::predict_counts`] reaches, bit for bit.
//!
//! Why: the fuser classifies every tile of every frame, a capture's forest 16 times a tile;
//! the f64 division and the `Option<Split>` walk per node were a sixth of a real capture's
//! replay (perf of the fruit capture with its forest). Invariant: built from a tree that
//! passed [`Tree::validate`] (children after their node, features in range).

use super::Tree;

/// A node of a [`CountTree`]: a split, or a leaf when `feature` is [`LEAF`].
#[derive(Debug, Clone, Copy)]
struct CountNode {
    feature: u16,
    /// Counts up to this go left (-1: none does).
    max_left: i32,
    left: u32,
    right: u32,
    p: f64,
}

/// `feature` of a leaf.
const LEAF: u16 = u16::MAX;

/// A [`Tree`] for integer counts out of one `denom`.
#[derive(Debug, Clone)]
pub struct CountTree {
    nodes: Vec<CountNode>,
}

impl CountTree {
    /// `tree` for counts out of `denom` (value = count / denom, as [`Tree::predict_counts`]).
    pub fn new(tree: &Tree, denom: f64) -> Self {
        let nodes = tree
            .nodes
            .iter()
            .map(|n| match &n.split {
                None => CountNode {
                    feature: LEAF,
                    max_left: 0,
                    left: 0,
                    right: 0,
                    p: n.p,
                },
                Some(s) => CountNode {
                    feature: s.feature,
                    max_left: largest_count_left(s.threshold, denom),
                    left: s.left,
                    right: s.right,
                    p: n.p,
                },
            })
            .collect();
        Self { nodes }
    }

    /// The probability of the leaf `counts` reach.
    #[inline]
    pub fn predict(&self, counts: &[u16]) -> f64 {
        let mut i = 0usize;
        loop {
            let n = &self.nodes[i];
            if n.feature == LEAF {
                return n.p;
            }
            i = if i32::from(counts[n.feature as usize]) <= n.max_left {
                n.left as usize
            } else {
                n.right as usize
            };
        }
    }
}

/// The largest count c in 0..=u16::MAX with `c / denom <= threshold` in f64, the comparison
/// [`Tree::predict_counts`] makes (-1 when even 0 fails it). c / denom grows with c, so the
/// counts that pass are 0..=c.
fn largest_count_left(threshold: f64, denom: f64) -> i32 {
    let passes = |c: i32| (c as f64 / denom) <= threshold;
    let top = i32::from(u16::MAX);
    let mut c = (threshold * denom).floor().clamp(-1.0, top as f64) as i32;
    while c < top && passes(c + 1) {
        c += 1;
    }
    while c >= 0 && !passes(c) {
        c -= 1;
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::learn::tree::{Node, Split};
    use crate::types::rng::SplitMix64;

    /// A tree of `depth` levels of splits on random features (of 3) at `threshold(k)`.
    fn tree(depth: u32, threshold: &dyn Fn(usize) -> f64) -> Tree {
        fn grow(
            nodes: &mut Vec<Node>,
            depth: u32,
            threshold: &dyn Fn(usize) -> f64,
            rng: &mut SplitMix64,
        ) -> u32 {
            let me = nodes.len();
            nodes.push(Node {
                p: rng.uniform() * 0.98 + 0.01,
                n_train: 1,
                pos_train: 0,
                split: None,
            });
            if depth > 0 {
                let (feature, t) = (rng.below(3) as u16, threshold(me));
                let left = grow(nodes, depth - 1, threshold, rng);
                let right = grow(nodes, depth - 1, threshold, rng);
                nodes[me].split = Some(Split {
                    feature,
                    threshold: t,
                    left,
                    right,
                });
            }
            me as u32
        }
        let mut nodes = Vec::new();
        grow(&mut nodes, depth, threshold, &mut SplitMix64::new(4));
        Tree {
            n_features: 3,
            nodes,
        }
    }

    /// Every count vector reaches the leaf the f64 walk reaches: thresholds as fitting writes
    /// them ((lo + hi) / 2 / denom), arbitrary ones, ones exactly on a count, and ones below
    /// 0 and above 1.
    #[test]
    fn counts_reach_the_leaf_the_f64_walk_reaches() {
        for denom in [64.0, 100.0, 255.0] {
            let d = denom as i32;
            let kinds: [&dyn Fn(usize) -> f64; 4] = [
                &|k| ((k % 7) as f64 * 9.0 + (k % 7) as f64 * 9.0 + 1.0) / 2.0 / denom,
                &|k| (k as f64 * 0.137).fract(),
                &|k| (k % 11) as f64 * 5.0 / denom,
                &|k| if k % 2 == 0 { -0.5 } else { 1.5 },
            ];
            for threshold in kinds {
                let t = tree(5, threshold);
                let fast = CountTree::new(&t, denom);
                let mut rng = SplitMix64::new(d as u64);
                for _ in 0..2_000 {
                    let counts: Vec<u16> = (0..3).map(|_| rng.below(d as u64 + 1) as u16).collect();
                    assert_eq!(fast.predict(&counts), t.predict_counts(&counts, denom));
                }
            }
        }
    }

    #[test]
    fn the_largest_count_left_of_a_threshold() {
        // (3 + 4) / 2 / 8 = 0.4375: counts 0..=3 go left.
        assert_eq!(largest_count_left(0.4375, 8.0), 3);
        // Exactly on a count: that count goes left.
        assert_eq!(largest_count_left(0.5, 8.0), 4);
        assert_eq!(largest_count_left(-0.1, 8.0), -1);
        assert_eq!(largest_count_left(2.0, 8.0), 16);
        assert_eq!(largest_count_left(1e9, 8.0), i32::from(u16::MAX));
        // 0.1 * 10 is not exactly 1 in f64 arithmetic; the f64 comparison decides.
        assert_eq!(largest_count_left(0.1, 10.0), i32::from(1.0 / 10.0 <= 0.1));
    }
}
