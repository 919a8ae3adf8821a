//! The split search of tree growth: the best threshold split of a node's training examples
//! by information gain, from per-node (feature, count) histograms.
//!
//! Invariants: the result depends only on the examples, never on the thread count: the
//! histograms are integers summed in any order, and the ranges' winners are taken in feature
//! order with the same strict comparison as one sequential scan (lowest feature, then lowest
//! threshold, wins a tie).

use rayon::prelude::*;

use super::Examples;

/// `n ln n - p ln p - (n-p) ln (n-p)`: n times the entropy (nats) of a node with p positives.
#[inline]
pub(super) fn n_entropy(n: u32, p: u32) -> f64 {
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

/// A threshold split of a node and its information gain (nats times examples).
#[derive(Debug, Clone, Copy)]
pub(super) struct Candidate {
    pub(super) gain: f64,
    pub(super) feature: u16,
    /// Left = count <= lo; lo and hi are neighbouring distinct counts of the node.
    pub(super) lo: u16,
    pub(super) hi: u16,
}

/// Scratch histograms for the split search, reused across nodes: one set per worker.
pub(super) struct SplitSearch {
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
pub(super) const PARALLEL_MIN_EXAMPLES: usize = 16_384;

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

    /// The first best split among `features` (those `allowed`, when given), in (feature,
    /// threshold) order: a later candidate replaces it only with a strictly larger gain.
    fn scan(
        &self,
        features: std::ops::Range<usize>,
        allowed: Option<&[bool]>,
        (w, n, pos): (usize, u32, u32),
    ) -> Option<Candidate> {
        let parent = n_entropy(n, pos);
        let mut best: Option<Candidate> = None;
        // Gains below this are rounding noise of the n ln n sums, not information.
        let min_gain = 1e-9 * (n as f64).max(1.0);
        for f in features {
            let nnz = self.nnz[f];
            if nnz == 0 || allowed.is_some_and(|a| !a[f]) {
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
    /// Scratch for examples of `n_features` features with counts up to `denom`, one set per
    /// worker when `parallel` (a forest's trees grow in parallel instead, each with one set,
    /// so that a forest's scratch is that of as many trees as there are threads).
    pub(super) fn new(n_features: usize, denom: u16, parallel: bool) -> Self {
        let width = denom as usize + 1;
        // Large tiles make every histogram large (256 features x 65 026 counts for 255 px
        // tiles): one set then, as summing and clearing whole sets would cost more than the
        // chunks save.
        let workers = if parallel && n_features * width <= 1 << 22 {
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
    ///
    /// `allowed`: the features this node may split on (a forest's tree draws them per node),
    /// None for all.
    pub(super) fn best(
        &mut self,
        ex: &Examples,
        idx: &[u32],
        (n, pos): (u32, u32),
        allowed: Option<&[bool]>,
    ) -> Option<Candidate> {
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
            let best = s.scan(0..s.nnz.len(), allowed, (w, n, pos));
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
            .map(|k| {
                s.scan(
                    k * per..((k + 1) * per).min(n_features),
                    allowed,
                    (w, n, pos),
                )
            })
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
