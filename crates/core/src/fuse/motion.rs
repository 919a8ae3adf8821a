//! Motion uncertainty (paper section 3.2): the commands executed between two frames blur the
//! belief. A drive of duration t spreads it along the heading with sigma = sigma_v * t; a turn
//! spreads it in angle about the robot's vertical axis with sigma = sigma_w * t.
//!
//! Invariants: deterministic quadrature (fixed sample offsets and Gaussian weights, no random
//! sampling); each output cell is computed on its own from the old grid, so results are
//! bit-identical for any thread count; a sigma of 0 leaves the grid untouched, bit for bit;
//! the world outside the grid is taken to be at the prior. Every blur averages the offset
//! from the prior (evidence, or the probability's or likelihood ratio's offset), so a region
//! at the prior stays exactly at the prior, and values that round below
//! [`FLUSH_EVIDENCE`] become 0: a dense and a sparse grid are blurred alike (the grid's
//! [`crate::fuse::grid::convolve`] applies the kernels defined here). No I/O.

use rayon::prelude::*;

use crate::fuse::grid::convolve::{ColumnKernel, Sample, convolve};
use crate::fuse::grid::{FLUSH_EVIDENCE, Grid, GridError, GridSpec, sigmoid};

/// What the blur averages.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "kebab-case")]
pub enum BlurMode {
    /// The paper: convolve probabilities. Caps accumulated evidence: a cell at log-odds 50
    /// beside cells at the prior falls to a few units after one blur.
    Probability,
    /// Convolve log-odds: keeps the weight of evidence, so earlier views are not forgotten.
    LogOdds,
    /// Leave the belief alone and spread each new frame's evidence over that frame's pose
    /// uncertainty since the first frame (which anchors the frame of reference), averaging
    /// likelihood ratios.
    Observation,
}

/// Samples cover +-4 sigma; beyond that a Gaussian weighs under 3.4e-4 of its peak.
const SPAN_SIGMAS: f64 = 4.0;
/// Samples per sigma of a wide Gaussian in the rotation blur.
const SAMPLES_PER_SIGMA: f64 = 2.0;
/// Bound on samples per side, so a huge sigma cannot make the blur unbounded in time.
const MAX_SAMPLES_PER_SIDE: usize = 256;

/// One constant command between two instants, from /cmd_vel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    /// Start of the segment, ns (the /cmd_vel header stamp clock).
    pub start_ns: i64,
    /// End of the segment, ns (same clock), after `start_ns`.
    pub end_ns: i64,
    /// Nominal forward speed, m/s.
    pub v_mps: f64,
    /// Nominal turn rate, rad/s.
    pub w_radps: f64,
}

impl Segment {
    /// Length of the segment, seconds.
    pub fn duration_s(&self) -> f64 {
        (self.end_ns - self.start_ns) as f64 * 1e-9
    }
}

/// The pieces of the commands `(stamp_ns, v, w)` (each held until the next) that fall in
/// (from_ns, to_ns]. Commands must be sorted by stamp.
pub fn segments_between(commands: &[(i64, f64, f64)], from_ns: i64, to_ns: i64) -> Vec<Segment> {
    let mut out = Vec::new();
    for (i, &(t0, v, w)) in commands.iter().enumerate() {
        let t1 = commands.get(i + 1).map_or(i64::MAX, |c| c.0);
        let (a, b) = (t0.max(from_ns), t1.min(to_ns));
        if b > a && (v != 0.0 || w != 0.0) {
            out.push(Segment {
                start_ns: a,
                end_ns: b,
                v_mps: v,
                w_radps: w,
            });
        }
    }
    out
}

/// Samples each side of a Gaussian of `sigma_m` (arc length) for the rotation blur: one a
/// cell apart while the Gaussian is narrow, at most [`SAMPLES_PER_SIGMA`] per sigma once it is
/// wide (bilinear interpolation between samples smooths finer than that anyway), so the cost
/// of a blur does not grow with the radius.
fn samples_per_side(sigma_m: f64, voxel: f64) -> usize {
    let by_cell = (SPAN_SIGMAS * sigma_m / voxel).ceil();
    let by_sigma = (SPAN_SIGMAS * SAMPLES_PER_SIGMA).ceil();
    (by_cell.min(by_sigma) as usize).min(MAX_SAMPLES_PER_SIDE)
}

/// `x.floor()` without the libm call the baseline x86-64 target makes for it (it has no
/// rounding instruction); the blurs take two per sample per column. Equal to `floor` for every
/// finite value below 2^52 in magnitude (the rest go to `floor` itself); at -0.0 it gives
/// +0.0, which the callers treat alike (a cell index of 0 and a weight of 0).
#[inline]
fn floor_fast(x: f64) -> f64 {
    if x.abs() < 4.0e15 {
        let t = x as i64 as f64;
        if t > x { t - 1.0 } else { t }
    } else {
        // Huge, infinite or NaN.
        x.floor()
    }
}

/// Normalised Gaussian weights at offsets `k * spacing`, k = -n..=n.
fn gaussian_weights(n: usize, spacing: f64, sigma: f64) -> Vec<f64> {
    let w: Vec<f64> = (-(n as i64)..=n as i64)
        .map(|k| {
            let s = k as f64 * spacing;
            (-0.5 * (s / sigma) * (s / sigma)).exp()
        })
        .collect();
    let sum: f64 = w.iter().sum();
    w.into_iter().map(|x| x / sum).collect()
}

/// The drive's kernel: a Gaussian of `sigma_m` along a direction in x and y, sampled a whole
/// cell apart along the direction's major axis, bilinear across it.
pub(crate) struct Translate {
    major_x: bool,
    slope: f64,
    n: usize,
    weights: Vec<f64>,
}

impl Translate {
    /// Along the unit direction `dir_xy` with standard deviation `sigma_m`; None when the
    /// blur is the identity (sigma 0, or below one sample).
    pub(crate) fn new(spec: &GridSpec, dir_xy: [f64; 2], sigma_m: f64) -> Option<Self> {
        let norm = dir_xy[0].hypot(dir_xy[1]);
        if !(sigma_m > 0.0 && sigma_m.is_finite() && norm > 1e-12) {
            return None;
        }
        let (dx, dy) = (dir_xy[0] / norm, dir_xy[1] / norm);
        // Step one whole cell along the major axis; the minor axis moves by a fraction.
        let major_x = dx.abs() >= dy.abs();
        let (major, minor) = if major_x { (dx, dy) } else { (dy, dx) };
        let spacing_m = spec.voxel_size_m / major.abs();
        let n = ((SPAN_SIGMAS * sigma_m / spacing_m).ceil() as usize).min(MAX_SAMPLES_PER_SIDE);
        (n > 0).then(|| Self {
            major_x,
            slope: minor / major,
            n,
            weights: gaussian_weights(n, spacing_m, sigma_m),
        })
    }
}

impl ColumnKernel for Translate {
    fn reach_cells(&self, _lo: [usize; 2], _hi: [usize; 2]) -> [usize; 2] {
        // Whole cells along the major axis; across it the slope's fraction and the bilinear
        // neighbour.
        let minor = (self.n as f64 * self.slope.abs()).ceil() as usize + 1;
        if self.major_x {
            [self.n, minor]
        } else {
            [minor, self.n]
        }
    }

    fn samples(&self, i: usize, j: usize, out: &mut Vec<([i64; 2], f64)>) {
        let n = self.n;
        for (s, &w) in self.weights.iter().enumerate() {
            let k = s as f64 - n as f64;
            let minor_pos = if self.major_x { j as f64 } else { i as f64 } - k * self.slope;
            let m0 = floor_fast(minor_pos);
            let f = minor_pos - m0;
            let major_pos = if self.major_x { i as i64 } else { j as i64 } - (k as i64);
            for (m, wm) in [(m0 as i64, 1.0 - f), (m0 as i64 + 1, f)] {
                if wm == 0.0 {
                    continue;
                }
                let c = if self.major_x {
                    [major_pos, m]
                } else {
                    [m, major_pos]
                };
                out.push((c, w * wm));
            }
        }
    }
}

/// The turn's kernel: a Gaussian of `sigma_rad` in angle about a vertical axis, sampled along
/// each cell's arc (see [`samples_per_side`]), bilinear in x and y.
pub(crate) struct Rotate {
    spec: GridSpec,
    center_xy: [f64; 2],
    sigma_rad: f64,
    n_max: usize,
    /// Per sample count n: (weight, sin, cos) of each of the 2n + 1 angles.
    tables: Vec<Vec<(f64, f64, f64)>>,
}

impl Rotate {
    /// About the vertical axis through `center_xy` with standard deviation `sigma_rad`; None
    /// when the blur is the identity (sigma 0).
    pub(crate) fn new(spec: &GridSpec, center_xy: [f64; 2], sigma_rad: f64) -> Option<Self> {
        if !(sigma_rad > 0.0 && sigma_rad.is_finite() && center_xy.iter().all(|c| c.is_finite())) {
            return None;
        }
        // Columns with the same sample count share angles, sines and weights: computed once
        // per count here rather than once per column.
        let (lo, hi) = (spec.origin_m, spec.max_m());
        let r_max = [
            (lo[0], lo[1]),
            (lo[0], hi[1]),
            (hi[0], lo[1]),
            (hi[0], hi[1]),
        ]
        .iter()
        .map(|&(x, y)| (x - center_xy[0]).hypot(y - center_xy[1]))
        .fold(0.0f64, f64::max);
        let n_max = samples_per_side(sigma_rad * r_max, spec.voxel_size_m);
        let tables = (0..=n_max)
            .map(|n| {
                if n == 0 {
                    return Vec::new();
                }
                let spacing = SPAN_SIGMAS * sigma_rad / n as f64;
                gaussian_weights(n, spacing, sigma_rad)
                    .into_iter()
                    .enumerate()
                    .map(|(s, w)| {
                        let (sn, cs) = ((s as f64 - n as f64) * spacing).sin_cos();
                        (w, sn, cs)
                    })
                    .collect()
            })
            .collect();
        Some(Self {
            spec: *spec,
            center_xy,
            sigma_rad,
            n_max,
            tables,
        })
    }
}

impl ColumnKernel for Rotate {
    fn reach_cells(&self, lo: [usize; 2], hi: [usize; 2]) -> [usize; 2] {
        // A rotation keeps a point's radius: a cell at radius r reads points on its circle at
        // most r * min(phi, 2) away (phi = the widest angle; a chord is at most the arc and
        // at most the diameter), each through its bilinear neighbours (within 1.5 cells). So a
        // cell that reads a non-zero source has r at most R + 1.5 v (R: the farthest non-zero
        // cell centre, within a cell of the box's corners) and lies at most
        // min(phi, 2) (R + 2.5 v) + 1.5 v from it: finite for any angle, so however wide a
        // turn, a blur never needs more than the blocks around the non-zero ones.
        let phi = (SPAN_SIGMAS * self.sigma_rad).min(2.0);
        let v = self.spec.voxel_size_m;
        let o = self.spec.origin_m;
        let r_max = [
            (lo[0], lo[1]),
            (lo[0], hi[1]),
            (hi[0], lo[1]),
            (hi[0], hi[1]),
        ]
        .iter()
        .map(|&(x, y)| {
            (o[0] + x as f64 * v - self.center_xy[0]).hypot(o[1] + y as f64 * v - self.center_xy[1])
        })
        .fold(0.0f64, f64::max);
        let d = phi * (r_max + 2.5 * v) + 1.5 * v;
        let cells = (d / v).ceil() + 1.0;
        if cells.is_finite() && cells < 1e15 {
            [cells as usize; 2]
        } else {
            [usize::MAX; 2]
        }
    }

    fn samples(&self, i: usize, j: usize, out: &mut Vec<([i64; 2], f64)>) {
        let spec = &self.spec;
        let voxel = spec.voxel_size_m;
        let c = spec.center(i, j, 0);
        let (rx, ry) = (c[0] - self.center_xy[0], c[1] - self.center_xy[1]);
        // Samples a cell apart along the arc at this radius.
        let n = samples_per_side(self.sigma_rad * rx.hypot(ry), voxel).min(self.n_max);
        if n == 0 {
            out.push(([i as i64, j as i64], 1.0));
            return;
        }
        for &(w, sn, cs) in &self.tables[n] {
            // Source of the value that the rotation by phi carries here.
            let sx = self.center_xy[0] + cs * rx + sn * ry;
            let sy = self.center_xy[1] - sn * rx + cs * ry;
            let fx = (sx - spec.origin_m[0]) / voxel - 0.5;
            let fy = (sy - spec.origin_m[1]) / voxel - 0.5;
            let (x0, y0) = (floor_fast(fx), floor_fast(fy));
            let (ax, ay) = (fx - x0, fy - y0);
            for (ci, wx) in [(x0 as i64, 1.0 - ax), (x0 as i64 + 1, ax)] {
                for (cj, wy) in [(y0 as i64, 1.0 - ay), (y0 as i64 + 1, ay)] {
                    let ww = w * wx * wy;
                    if ww != 0.0 {
                        out.push(([ci, cj], ww));
                    }
                }
            }
        }
    }
}

/// Scratch space reused across blurs, so a replay allocates it once.
#[derive(Debug, Default)]
pub struct Blurrer {
    blocks: Vec<u32>,
    out32: Vec<f32>,
    src64: Vec<f64>,
    out64: Vec<f64>,
}

impl Blurrer {
    /// A log-odds blur: the kernel applied to the evidence (log-odds above the prior's) in
    /// f32, the grid's own type (no conversion passes, half the memory traffic of f64).
    pub(crate) fn log_odds_blur(
        &mut self,
        grid: &mut Grid,
        kernel: &dyn ColumnKernel,
    ) -> Result<(), GridError> {
        convolve(
            &grid.spec,
            &grid.layout,
            &grid.evidence,
            kernel,
            FLUSH_EVIDENCE,
            &|slots| grid.check_budget(slots),
            &mut self.blocks,
            &mut self.out32,
        )?;
        grid.adopt_evidence(&mut self.blocks, &mut self.out32)
    }

    /// The paper's blur: the kernel applied to the probabilities, in f64 (f32 cannot hold
    /// 1 - 1e-10), as their offset from the prior's, so that a region at the prior stays
    /// there exactly; written back as evidence, ln(p) - ln(1 - p) less the prior's log-odds
    /// (averages of f64 probabilities never leave [min prob, 1 - 2^-53], so the log-odds stay
    /// within +-37).
    fn probability_blur(
        &mut self,
        grid: &mut Grid,
        kernel: &dyn ColumnKernel,
    ) -> Result<(), GridError> {
        let prior = grid.prior_log_odds();
        let p0 = sigmoid(f64::from(prior));
        self.src64.resize(grid.evidence.len(), 0.0);
        self.src64
            .par_iter_mut()
            .zip(grid.evidence.par_iter())
            .for_each(|(q, &e)| *q = sigmoid(f64::from(prior + e)) - p0);
        convolve(
            &grid.spec,
            &grid.layout,
            &self.src64,
            kernel,
            0.0,
            &|slots| grid.check_budget(slots),
            &mut self.blocks,
            &mut self.out64,
        )?;
        self.out32.resize(self.out64.len(), 0.0);
        self.out32
            .par_iter_mut()
            .zip(self.out64.par_iter())
            .for_each(|(e, &q)| {
                let p = (p0 + q).clamp(f64::MIN_POSITIVE, 1.0 - f64::EPSILON / 2.0);
                let l = p.ln() - (-p).ln_1p();
                *e = ((l - f64::from(prior)) as f32).flushed(FLUSH_EVIDENCE);
            });
        grid.adopt_evidence(&mut self.blocks, &mut self.out32)
    }

    fn blur(
        &mut self,
        grid: &mut Grid,
        kernel: Option<&dyn ColumnKernel>,
        mode: BlurMode,
    ) -> Result<(), GridError> {
        match kernel {
            None => Ok(()),
            Some(k) if mode == BlurMode::Probability => self.probability_blur(grid, k),
            Some(k) => self.log_odds_blur(grid, k),
        }
    }

    /// Blurs the belief along the unit direction `dir_xy` (odom x, y) with standard
    /// deviation `sigma_m`; [`GridError::Allocation`] when the blocks it reaches do not fit.
    pub fn translate(
        &mut self,
        grid: &mut Grid,
        dir_xy: [f64; 2],
        sigma_m: f64,
        mode: BlurMode,
    ) -> Result<(), GridError> {
        let k = Translate::new(&grid.spec, dir_xy, sigma_m);
        self.blur(grid, k.as_ref().map(|k| k as &dyn ColumnKernel), mode)
    }

    /// Blurs the belief in angle about the vertical axis through `center_xy` with standard
    /// deviation `sigma_rad`; [`GridError::Allocation`] when the blocks it reaches do not fit.
    pub fn rotate(
        &mut self,
        grid: &mut Grid,
        center_xy: [f64; 2],
        sigma_rad: f64,
        mode: BlurMode,
    ) -> Result<(), GridError> {
        let k = Rotate::new(&grid.spec, center_xy, sigma_rad);
        self.blur(grid, k.as_ref().map(|k| k as &dyn ColumnKernel), mode)
    }

    /// Spreads one frame's evidence (log likelihood ratios per stored cell, laid out like
    /// `grid`, 0 outside the view; from [`Grid::frame_evidence`]) over the pose uncertainty of
    /// that frame: the likelihood ratio of a cell is the expectation of the ratio over the
    /// pose distribution, so it is the ratio, not its logarithm, that is averaged (as its
    /// offset from 1, so that cells the frame did not see stay exactly at 1). Heading
    /// uncertainty `sigma_rad` rotates about `center_xy` (the robot); position uncertainty
    /// `sigma_m` spreads isotropically in x and y. The grid stores the blocks the spread
    /// reaches, and `evidence` is laid out like it afterwards.
    pub fn spread_evidence(
        &mut self,
        grid: &mut Grid,
        evidence: &mut Vec<f32>,
        center_xy: [f64; 2],
        sigma_rad: f64,
        sigma_m: f64,
    ) -> Result<(), GridError> {
        let spec = grid.spec;
        let rotate = Rotate::new(&spec, center_xy, sigma_rad);
        let along_x = Translate::new(&spec, [1.0, 0.0], sigma_m);
        let along_y = Translate::new(&spec, [0.0, 1.0], sigma_m);
        let passes: Vec<&dyn ColumnKernel> = [
            rotate.as_ref().map(|k| k as &dyn ColumnKernel),
            along_x.as_ref().map(|k| k as &dyn ColumnKernel),
            along_y.as_ref().map(|k| k as &dyn ColumnKernel),
        ]
        .into_iter()
        .flatten()
        .collect();
        if passes.is_empty() {
            return Ok(());
        }
        self.src64.resize(evidence.len(), 0.0);
        self.src64
            .par_iter_mut()
            .zip(evidence.par_iter())
            .for_each(|(r, &e)| *r = f64::from(e).exp_m1());
        for k in passes {
            convolve(
                &grid.spec,
                &grid.layout,
                &self.src64,
                k,
                f64::from(FLUSH_EVIDENCE),
                &|slots| grid.check_budget(slots),
                &mut self.blocks,
                &mut self.out64,
            )?;
            grid.adopt_layout(&mut self.blocks, &mut self.out64)?;
            std::mem::swap(&mut self.src64, &mut self.out64);
        }
        evidence.clear();
        evidence.extend(
            self.src64
                .iter()
                .map(|&r| (r.ln_1p() as f32).flushed(FLUSH_EVIDENCE)),
        );
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fuse::grid::logit;

    #[test]
    fn fast_floor_is_floor() {
        let mut rng = crate::types::rng::SplitMix64::new(3);
        let mut xs = vec![
            0.0,
            1.0,
            -1.0,
            0.5,
            -0.5,
            2.999999999,
            -2.000000001,
            1e15,
            -1e15,
            5e15,
            -7e18,
        ];
        xs.extend((0..10_000).map(|_| (rng.uniform() - 0.5) * 400.0));
        for x in xs {
            assert_eq!(floor_fast(x).to_bits(), x.floor().to_bits(), "{x}");
        }
        assert!(floor_fast(f64::NAN).is_nan());
    }
    use crate::fuse::grid::GridSpec;

    fn grid() -> Grid {
        let spec = GridSpec::from_bounds([0.0; 3], [4.0, 4.0, 0.12], 0.04).unwrap();
        Grid::new(spec, 0.01).unwrap()
    }

    /// Mean and standard deviation along a unit direction of the evidence (log-odds over
    /// the prior's).
    fn moments(g: &Grid, dir: [f64; 2], origin: [f64; 2]) -> (f64, f64, f64, f64) {
        // The blur averages the offset from the prior: a far corner cell, which no blur here
        // reaches, stays exactly at the prior (the weights' f32 rounding multiplies 0).
        assert_eq!(g.evidence_at(g.spec.index(0, 0, 1)).to_bits(), 0);
        assert_eq!(g.log_odds_at(g.spec.index(0, 0, 1)), g.prior_log_odds());
        let (mut w, mut m1, mut m2, mut perp2) = (0.0, 0.0, 0.0, 0.0);
        for idx in 0..g.spec.cells() {
            let [i, j, k] = g.spec.ijk(idx);
            if k != 1 {
                continue;
            }
            let c = g.spec.center(i, j, k);
            let e = f64::from(g.evidence_at(idx));
            let (x, y) = (c[0] - origin[0], c[1] - origin[1]);
            let s = x * dir[0] + y * dir[1];
            let t = -x * dir[1] + y * dir[0];
            w += e;
            m1 += e * s;
            m2 += e * s * s;
            perp2 += e * t * t;
        }
        let mean = m1 / w;
        (w, mean, (m2 / w - mean * mean).sqrt(), (perp2 / w).sqrt())
    }

    #[test]
    fn translation_blur_of_a_hot_cell_has_the_right_mean_and_sigma() {
        for dir in [[1.0, 0.0], [0.6, 0.8], [-0.28, 0.96]] {
            let mut g = grid();
            let hot = g.spec.index(50, 50, 1);
            g.set_cell(hot, 10.0, 0).unwrap();
            let c = g.spec.center(50, 50, 1);
            let mut b = Blurrer::default();
            b.translate(&mut g, dir, 0.2, BlurMode::LogOdds).unwrap();
            let (mass, mean, sd, perp) = moments(&g, dir, [c[0], c[1]]);
            // Log-odds blurring conserves the evidence, adds no systematic motion, and spreads
            // it by sigma along the heading; the bilinear step on the minor axis adds at most
            // a fraction of a cell across it.
            assert!((mass - 10.0).abs() < 1e-3, "{dir:?} mass {mass}");
            assert!(mean.abs() < 1e-3, "{dir:?} mean {mean}");
            assert!((sd - 0.2).abs() < 0.2 * 0.02, "{dir:?} sd {sd}");
            assert!(perp < 0.5 * 0.04, "{dir:?} perp {perp}");
        }
    }

    #[test]
    fn rotation_blur_spreads_along_the_arc() {
        let mut g = grid();
        // Hot cell 1 m east of the centre of rotation.
        let hot = g.spec.index(75, 50, 1);
        g.set_cell(hot, 10.0, 0).unwrap();
        let centre = g.spec.center(50, 50, 1);
        let mut b = Blurrer::default();
        b.rotate(&mut g, [centre[0], centre[1]], 0.1, BlurMode::LogOdds)
            .unwrap();
        // Along the arc (tangent = +y at this point) sigma ~ r * 0.1 = 0.1 m.
        let cell = g.spec.center(75, 50, 1);
        let (mass, mean, sd, _) = moments(&g, [0.0, 1.0], [cell[0], cell[1]]);
        // Pull-based bilinear resampling conserves mass only to about a percent.
        assert!((mass - 10.0).abs() < 0.2, "mass {mass}");
        assert!(mean.abs() < 1e-3, "mean {mean}");
        assert!((sd - 0.1).abs() < 0.1 * 0.1, "sd {sd}");
    }

    #[test]
    fn zero_sigma_is_the_identity_bit_for_bit() {
        let mut g = grid();
        for i in 0..g.spec.cells() {
            g.set_cell(i, (i as f32 * 0.37).sin() * 20.0, 1).unwrap();
        }
        let before = g.clone();
        let mut b = Blurrer::default();
        b.translate(&mut g, [1.0, 0.0], 0.0, BlurMode::Probability)
            .unwrap();
        b.rotate(&mut g, [1.0, 1.0], 0.0, BlurMode::Probability)
            .unwrap();
        b.translate(&mut g, [1.0, 0.0], 0.0, BlurMode::LogOdds)
            .unwrap();
        assert_eq!(g.evidence, before.evidence);
        assert_eq!(g.sha256_hex(), before.sha256_hex());
    }

    /// The paper's probability averaging caps evidence: log-odds 50 beside prior cells falls
    /// to a few units after one blur; log-odds averaging keeps the weighted mean.
    #[test]
    fn probability_blur_caps_evidence() {
        let mut g = grid();
        let hot = g.spec.index(50, 50, 1);
        g.set_cell(hot, 50.0 - g.prior_log_odds(), 0).unwrap();
        let mut gl = g.clone();
        let mut b = Blurrer::default();
        b.translate(&mut g, [1.0, 0.0], 0.04, BlurMode::Probability)
            .unwrap();
        b.translate(&mut gl, [1.0, 0.0], 0.04, BlurMode::LogOdds)
            .unwrap();
        // Centre weight of a sigma = 1 cell kernel sampled at whole cells out to 4 sigma:
        // 1 / (1 + 2 (e^-0.5 + e^-2 + e^-4.5 + e^-8)) = 0.398943.
        let w0 = gaussian_weights(4, 0.04, 0.04)[4];
        assert!((w0 - 0.398943).abs() < 1e-6, "{w0}");
        let p = w0 + (1.0 - w0) * 0.01;
        let expect = logit(p);
        assert!(
            (f64::from(g.log_odds_at(hot)) - expect).abs() < 1e-4,
            "{} vs {expect}",
            g.log_odds_at(hot)
        );
        assert!(g.log_odds_at(hot) < 1.0);
        let expect_l = w0 * 50.0 + (1.0 - w0) * f64::from(gl.prior_log_odds());
        assert!((f64::from(gl.log_odds_at(hot)) - expect_l).abs() < 1e-3);
        // Four cells beyond the kernel's reach, both are exactly at the prior.
        let far = g.spec.index(56, 50, 1);
        assert_eq!((g.evidence_at(far), gl.evidence_at(far)), (0.0, 0.0));
    }

    #[test]
    fn segments_cut_commands_to_the_interval() {
        let cmds = [
            (0, 0.0, 0.5),
            (2_000_000_000, 0.3, 0.0),
            (5_000_000_000, 0.0, 0.0),
        ];
        let s = segments_between(&cmds, 1_000_000_000, 4_000_000_000);
        assert_eq!(s.len(), 2);
        assert_eq!(s[0].duration_s(), 1.0);
        assert_eq!(s[0].w_radps, 0.5);
        assert_eq!(s[1].duration_s(), 2.0);
        assert_eq!(s[1].v_mps, 0.3);
        assert!(segments_between(&cmds, 5_000_000_000, 9_000_000_000).is_empty());
    }

    #[test]
    fn blur_is_thread_count_independent() {
        let run = |threads| {
            crate::types::testing::with_threads(threads, || {
                let mut g = grid();
                for i in 0..g.spec.cells() {
                    g.set_cell(i, (i as f32 * 0.011).sin() * 5.0, 0).unwrap();
                }
                let mut b = Blurrer::default();
                b.translate(&mut g, [0.3, 0.7], 0.1, BlurMode::Probability)
                    .unwrap();
                b.rotate(&mut g, [2.0, 1.5], 0.05, BlurMode::LogOdds)
                    .unwrap();
                g.sha256_hex()
            })
        };
        assert_eq!(run(1), run(4));
    }
}
