//! The floor as a second landmark for pose refinement: what a frame shows of the floor,
//! mapped into `odom` by the poses of the frames fused so far, and how well a candidate pose
//! lays a new frame's floor onto that map.
//!
//! A camera at a fixed mount on a ground robot sees the floor plane (z = 0 in `base_link`)
//! through the lower part of every image, so each pixel below the horizon has a floor point
//! fixed in `base_link`, whatever the robot's pose. A frame is reduced once to a *patch*:
//! mean colour over local floor cells of `cell_m` (large enough to average out fine texture
//! such as wood grain, which would alias); a candidate planar pose moves the patch into
//! `odom`, where the *map* (the same cells, accumulated from earlier frames) says what colour
//! the floor there had. Unlike a single object, the floor around it constrains all three of
//! (x, y, yaw): the edges of a rug, the shadows of furniture, the slow variation of the
//! boards.
//!
//! Pixels that are not floor (the object, furniture, walls) land on floor points behind
//! them, differently from every view: their cells disagree across views, so the map keeps a
//! per-cell variance and every residual is weighted by it, and residuals are truncated.
//!
//! Invariants: pure functions of their inputs, no I/O; sums in a fixed order (pixels row by
//! row, cells in index order), so results do not depend on threads.

use nalgebra::{Point3, Vector3};

use crate::types::geometry::{Camera, Iso3, yaw_of};
use crate::types::image::Rgb8;

/// Settings of the floor term. The defaults were chosen by a sweep over 20 sessions (shipped
/// and held-out-style tours, docs/fuser.md "The floor"): cells of 0.15-0.20 m lose the rug's
/// edges, 0.05 m gains little for twice the cost; a weight of 0.03-0.05 leaves drift in,
/// 0.2-0.4 lowers the trajectory error without changing the object errors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FloorParams {
    /// Side of a floor cell, metres (patch and map).
    pub cell_m: f64,
    /// Floor points further than this from the camera are not used (their pixels cover too
    /// much floor to place them, and the far floor is mostly hidden by furniture).
    pub max_range_m: f64,
    /// Pixels a patch cell needs to be used.
    pub min_pixels: u32,
    /// Colour noise of a cell mean (per channel, 0..1 scale) beyond what the map's own
    /// spread says.
    pub sigma_colour: f64,
    /// Residuals are truncated at this many sigmas.
    pub truncate_sigmas: f64,
    /// Weight of the floor term against the motion prior (cells are not independent: their
    /// errors share the pose).
    pub weight: f64,
}

impl Default for FloorParams {
    fn default() -> Self {
        Self {
            cell_m: 0.07,
            max_range_m: 4.0,
            min_pixels: 4,
            sigma_colour: 0.02,
            truncate_sigmas: 3.0,
            weight: 0.2,
        }
    }
}

/// [`FloorMap::score_every_above`] compares its running sum with the bound every this many
/// cells (a comparison per cell costs more than the cells it saves).
const BOUND_CHECK_CELLS: usize = 16;

/// One frame's floor: cells in `base_link` floor coordinates with their mean colour.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FloorPatch {
    /// Centroid of the cell's floor points, (x, y) in `base_link`, metres.
    pub points_m: Vec<[f64; 2]>,
    /// Mean colour, channels in 0..1.
    pub colour: Vec<[f32; 3]>,
    /// Pixels averaged.
    pub pixels: Vec<u32>,
}

impl FloorPatch {
    /// Number of floor cells in the patch (the length of each of its vectors).
    pub fn len(&self) -> usize {
        self.points_m.len()
    }
    /// Whether the patch has no cell: the frame shows no usable floor.
    pub fn is_empty(&self) -> bool {
        self.points_m.is_empty()
    }
}

/// Images of more pixels than this are sampled every k-th pixel in u and v (k the square
/// root of how many times more, rounded down): a floor cell of 7 cm spans hundreds of pixels
/// of a 1080 x 1920 frame near the robot, and the patch averages them. Up to 640 x 512 every
/// pixel counts (all our simulated and foreign sessions).
pub const FLOOR_FULL_PIXELS: u64 = 640 * 512;

/// The pixel step of [`floor_patch`] for an image of `width` x `height`.
pub fn floor_pixel_step(width: u32, height: u32) -> usize {
    let ratio = (u64::from(width) * u64::from(height)) as f64 / FLOOR_FULL_PIXELS as f64;
    ratio.sqrt().floor().max(1.0) as usize
}

/// Reduces an image to its floor patch (see the module doc), leaving out the pixels for
/// which `not_floor(u, v)` holds (those the classifier takes for the object).
pub fn floor_patch(
    img: &Rgb8,
    camera: &Camera,
    base_from_camera: &Iso3,
    params: &FloorParams,
    not_floor: impl Fn(u32, u32) -> bool,
) -> FloorPatch {
    let cell = params.cell_m;
    let reach = params.max_range_m;
    // Local cells cover x in [-reach, reach], y in [-reach, reach] around base_link.
    let n = (2.0 * reach / cell).ceil() as usize + 1;
    let mut acc = vec![[0.0f64; 6]; n * n];
    let origin = base_from_camera.translation.vector;
    if origin.z <= 0.0 || img.width == 0 {
        return FloorPatch::default();
    }
    let step = floor_pixel_step(img.width, img.height);
    // A pixel's ray in base_link is R (x, y, 1) with x, y its normalised image coordinates:
    // linear in x along a row, so a row costs a product per pixel, not a rotation and a norm.
    let r = base_from_camera.rotation.to_rotation_matrix().into_inner();
    let (c0, c1, c2): (Vector3<f64>, Vector3<f64>, Vector3<f64>) =
        (r.column(0).into(), r.column(1).into(), r.column(2).into());
    let us: Vec<(u32, f64)> = (0..img.width)
        .step_by(step)
        .map(|u| (u, (f64::from(u) + 0.5 - camera.cx) / camera.fx))
        .collect();
    let (x_first, x_last) = (us[0].1, us[us.len() - 1].1);
    for v in (0..img.height).step_by(step) {
        let y = (f64::from(v) + 0.5 - camera.cy) / camera.fy;
        let row = c1 * y + c2;
        // z is linear along the row: no pixel of it looks down when neither end does.
        if row.z + c0.z * x_first >= 0.0 && row.z + c0.z * x_last >= 0.0 {
            continue;
        }
        for &(u, x) in &us {
            let ray = row + c0 * x;
            let norm2 = x * x + y * y + 1.0;
            // The unit ray's z at most -1e-6 (the pixel looks down), then the floor point
            // within `reach` of the camera: t |ray| <= reach, with hit = origin + ray t.
            if ray.z >= 0.0 || ray.z * ray.z <= 1e-12 * norm2 {
                continue;
            }
            let t = -origin.z / ray.z;
            if t * t * norm2 > reach * reach || not_floor(u, v) {
                continue;
            }
            let (hx, hy) = (origin.x + ray.x * t, origin.y + ray.y * t);
            let (fx, fy) = ((hx + reach) / cell, (hy + reach) / cell);
            // Negated so that NaN is rejected; truncation is the floor of these
            // non-negative values.
            if !(fx >= 0.0 && fy >= 0.0) || fx as usize >= n || fy as usize >= n {
                continue;
            }
            let a = &mut acc[fy as usize * n + fx as usize];
            let px = img.pixel(u, v);
            a[0] += hx;
            a[1] += hy;
            a[2] += f64::from(px[0]) / 255.0;
            a[3] += f64::from(px[1]) / 255.0;
            a[4] += f64::from(px[2]) / 255.0;
            a[5] += 1.0;
        }
    }
    let mut patch = FloorPatch::default();
    for a in &acc {
        if a[5] >= f64::from(params.min_pixels) {
            let k = 1.0 / a[5];
            patch.points_m.push([a[0] * k, a[1] * k]);
            patch
                .colour
                .push([(a[2] * k) as f32, (a[3] * k) as f32, (a[4] * k) as f32]);
            patch.pixels.push(a[5] as u32);
        }
    }
    patch
}

/// [`FloorMap::disagreement`] of the floor `patches` seen at their poses.
pub fn disagreement(patches: &[(&FloorPatch, &Iso3)], params: FloorParams) -> f64 {
    let reach = params.max_range_m + 1.0;
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for (_, pose) in patches {
        let t = pose.translation.vector;
        lo = [lo[0].min(t.x - reach), lo[1].min(t.y - reach)];
        hi = [hi[0].max(t.x + reach), hi[1].max(t.y + reach)];
    }
    if !lo[0].is_finite() {
        return 0.0;
    }
    let mut map = FloorMap::new(lo, hi, params);
    for (patch, pose) in patches {
        map.add(patch, pose);
    }
    map.disagreement()
}

/// Moves a `base_link` floor point into `odom` by a planar robot pose.
#[inline]
fn to_odom(odom_from_base: &Iso3, p: &[f64; 2]) -> [f64; 2] {
    let q = odom_from_base * Point3::new(p[0], p[1], 0.0);
    [q.x, q.y]
}

/// The floor seen so far, in `odom` cells of `cell_m`: per cell, the weighted sums of colour
/// and squared colour (for the mean and the spread across views).
#[derive(Debug, Clone, PartialEq)]
pub struct FloorMap {
    params: FloorParams,
    origin_m: [f64; 2],
    nx: usize,
    ny: usize,
    /// Per cell: weight, then sum of colour (3), then sum of squared colour (3).
    acc: Vec<[f64; 7]>,
    /// Per cell, kept in step with `acc` so that scoring (hundreds of candidate poses per
    /// frame) reads them directly: mean colour (3), variance averaged over channels, and 1;
    /// all zeros where the cell has not been seen, so that a bilinear lookup adds nothing
    /// for it (no weight, no value) without a branch.
    stats: Vec<[f64; 5]>,
    /// Per cell: frames that saw it, and the last frame (1-based) that did.
    seen_by: Vec<(u16, u32)>,
    frames: usize,
}

impl FloorMap {
    /// An empty map covering `min_m`..`max_m` (x, y in `odom`).
    pub fn new(min_m: [f64; 2], max_m: [f64; 2], params: FloorParams) -> Self {
        let nx = ((max_m[0] - min_m[0]) / params.cell_m).ceil().max(1.0) as usize;
        let ny = ((max_m[1] - min_m[1]) / params.cell_m).ceil().max(1.0) as usize;
        Self {
            params,
            origin_m: min_m,
            nx,
            ny,
            acc: vec![[0.0; 7]; nx * ny],
            stats: vec![[0.0; 5]; nx * ny],
            seen_by: vec![(0, 0); nx * ny],
            frames: 0,
        }
    }

    /// Frames added so far.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// Bilinear corners and weights of a point of `odom`.
    #[inline]
    fn corners(&self, p: &[f64; 2]) -> Option<([usize; 4], [f64; 4])> {
        let fx = (p[0] - self.origin_m[0]) / self.params.cell_m - 0.5;
        let fy = (p[1] - self.origin_m[1]) / self.params.cell_m - 0.5;
        self.corners_at(fx, fy)
    }

    /// Bilinear corners and weights at cell-centre coordinates (`fx`, `fy`).
    #[inline]
    fn corners_at(&self, fx: f64, fy: f64) -> Option<([usize; 4], [f64; 4])> {
        // Negated so that NaN is rejected too.
        if !(fx >= 0.0 && fy >= 0.0) {
            return None;
        }
        // Truncation is the floor of these non-negative values, without a libm call (the
        // baseline x86-64 target has no rounding instruction); this is the scorer's inner loop.
        let (x0, y0) = (fx as usize, fy as usize);
        // Not `x0 + 1 >= nx`: a coordinate beyond usize saturates to usize::MAX, and the sum
        // would wrap (a /cmd_vel of 1e20 m/s put the search's candidates there).
        if x0 >= self.nx - 1 || y0 >= self.ny - 1 {
            return None;
        }
        let (sx, sy) = (fx - x0 as f64, fy - y0 as f64);
        let i = y0 * self.nx + x0;
        Some((
            [i, i + 1, i + self.nx, i + self.nx + 1],
            [
                (1.0 - sx) * (1.0 - sy),
                sx * (1.0 - sy),
                (1.0 - sx) * sy,
                sx * sy,
            ],
        ))
    }

    /// Adds a frame's patch at its (final) robot pose.
    pub fn add(&mut self, patch: &FloorPatch, odom_from_base: &Iso3) {
        let this = u32::try_from(self.frames + 1).unwrap_or(u32::MAX);
        for ((p, c), &n) in patch.points_m.iter().zip(&patch.colour).zip(&patch.pixels) {
            let Some((idx, w)) = self.corners(&to_odom(odom_from_base, p)) else {
                continue;
            };
            // Weight by pixels, saturating: a near cell of 200 pixels is not 50 times as
            // trustworthy as a far one of 4 (both are dominated by texture, not noise).
            let wn = f64::from(n).min(16.0);
            for (&i, &wi) in idx.iter().zip(&w) {
                let ww = wi * wn;
                let a = &mut self.acc[i];
                a[0] += ww;
                for ch in 0..3 {
                    let v = f64::from(c[ch]);
                    a[1 + ch] += ww * v;
                    a[4 + ch] += ww * v * v;
                }
                let sb = self.seen_by[i];
                let views = if sb.1 != this {
                    sb.0.saturating_add(1)
                } else {
                    sb.0
                };
                self.seen_by[i] = (views, this);
                self.stats[i] = match self.cell(i) {
                    Some((m, var)) => [m[0], m[1], m[2], var, 1.0],
                    _ => [0.0; 5],
                };
            }
        }
        self.frames += 1;
    }

    /// How much the views disagree about the floor: over the cells two or more frames saw,
    /// the weighted mean of the colour variance across them over the colour noise (each
    /// cell's term capped like a residual). The floor seen at consistent poses has a low
    /// one; misplaced frames raise it.
    pub fn disagreement(&self) -> f64 {
        let s0 = self.params.sigma_colour * self.params.sigma_colour;
        let cap = self.params.truncate_sigmas * self.params.truncate_sigmas;
        let (mut num, mut den) = (0.0, 0.0);
        for (i, sb) in self.seen_by.iter().enumerate() {
            if sb.0 < 2 {
                continue;
            }
            if let Some((_, var)) = self.cell(i) {
                let w = self.acc[i][0];
                num += w * (var / s0).min(cap);
                den += w;
            }
        }
        if den > 0.0 { num / den } else { 0.0 }
    }

    /// Mean colour and variance (averaged over channels) of a cell, if observed.
    #[inline]
    fn cell(&self, i: usize) -> Option<([f64; 3], f64)> {
        let a = &self.acc[i];
        if a[0] < 1.0 {
            return None;
        }
        let k = 1.0 / a[0];
        let m = [a[1] * k, a[2] * k, a[3] * k];
        let var = (0..3)
            .map(|ch| (a[4 + ch] * k - m[ch] * m[ch]).max(0.0))
            .sum::<f64>()
            / 3.0;
        Some((m, var))
    }

    /// The map at a point of `odom`, bilinear over the seen cells: weighted sums of mean
    /// colour (3) and variance, and the seen cells' total weight, if that is at least half.
    #[inline]
    fn lookup(&self, q: &[f64; 2]) -> Option<[f64; 5]> {
        let fx = (q[0] - self.origin_m[0]) / self.params.cell_m - 0.5;
        let fy = (q[1] - self.origin_m[1]) / self.params.cell_m - 0.5;
        self.lookup_cell(fx, fy)
    }

    /// Of the patch's cells that land on floor the map has seen at a robot pose, the
    /// fraction whose colour fits the map's within two sigmas; `None` when none land.
    pub fn fit(&self, patch: &FloorPatch, odom_from_base: &Iso3) -> Option<f64> {
        let s0 = self.params.sigma_colour * self.params.sigma_colour;
        let (mut n, mut good) = (0usize, 0usize);
        for (p, c) in patch.points_m.iter().zip(&patch.colour) {
            let Some(acc) = self.lookup(&to_odom(odom_from_base, p)) else {
                continue;
            };
            let k = 1.0 / acc[4];
            let d2: f64 = (0..3)
                .map(|ch| (f64::from(c[ch]) - acc[ch] * k).powi(2))
                .sum::<f64>()
                / 3.0;
            n += 1;
            if d2 / (s0 + acc[3] * k) <= 4.0 {
                good += 1;
            }
        }
        (n > 0).then(|| good as f64 / n as f64)
    }

    /// Cells of a patch at a robot pose that land on floor the map has seen.
    pub fn overlap(&self, patch: &FloorPatch, odom_from_base: &Iso3) -> usize {
        patch
            .points_m
            .iter()
            .filter(|p| self.lookup(&to_odom(odom_from_base, p)).is_some())
            .count()
    }

    /// Log-likelihood (up to a constant, times the term's weight) of a patch at a candidate
    /// robot pose. Cells of the patch that fall where the map has not seen the floor count
    /// as an average fit, so that moving the patch off the map is neither rewarded nor
    /// punished.
    pub fn score(&self, patch: &FloorPatch, odom_from_base: &Iso3) -> f64 {
        self.score_every(patch, odom_from_base, 1)
    }

    /// [`FloorMap::score`] from every `stride`-th cell of the patch, scaled to the whole
    /// patch's count: a cheaper estimate for a coarse search.
    pub fn score_every(&self, patch: &FloorPatch, odom_from_base: &Iso3, stride: usize) -> f64 {
        self.score_every_above(patch, odom_from_base, stride, f64::NEG_INFINITY)
    }

    /// [`FloorMap::score_every`] when it is at least `at_least`; otherwise it may stop early
    /// and return a value below `at_least` that is at least the score. Every cell adds a term
    /// of at most zero, so the running sum, scaled as the result is, bounds the result from
    /// above: a pose search skips most of the cells of the candidates that cannot win.
    pub fn score_every_above(
        &self,
        patch: &FloorPatch,
        odom_from_base: &Iso3,
        stride: usize,
        at_least: f64,
    ) -> f64 {
        let stride = stride.max(1);
        let s0 = self.params.sigma_colour * self.params.sigma_colour;
        let cap = self.params.truncate_sigmas * self.params.truncate_sigmas;
        // The pose and the map's cell coordinates folded into one affine map from a patch
        // point to map cell-centre coordinates: the scorer's inner loop runs hundreds of
        // thousands of times per frame, and this leaves it no division but the two a
        // residual needs.
        let inv_cell = 1.0 / self.params.cell_m;
        let (sin, cos) = yaw_of(odom_from_base).sin_cos();
        let t: Vector3<f64> = odom_from_base.translation.vector;
        let (a, b) = (cos * inv_cell, sin * inv_cell);
        let ox = (t.x - self.origin_m[0]) * inv_cell - 0.5;
        let oy = (t.y - self.origin_m[1]) * inv_cell - 0.5;
        let count = patch.points_m.len();
        let bound_factor = count as f64 / count.div_ceil(stride).max(1) as f64 * self.params.weight;
        let mut sum = 0.0;
        let mut used = 0usize;
        for (p, c) in patch.points_m.iter().zip(&patch.colour).step_by(stride) {
            used += 1;
            let fx = a * p[0] - b * p[1] + ox;
            let fy = b * p[0] + a * p[1] + oy;
            let mut r2 = 1.0;
            if let Some(acc) = self.lookup_cell(fx, fy) {
                let k = 1.0 / acc[4];
                let d2: f64 = (0..3)
                    .map(|ch| (f64::from(c[ch]) - acc[ch] * k).powi(2))
                    .sum::<f64>()
                    * (1.0 / 3.0);
                r2 = (d2 / (s0 + acc[3] * k)).min(cap);
            }
            sum -= 0.5 * r2;
            if used.is_multiple_of(BOUND_CHECK_CELLS) && sum * bound_factor < at_least {
                return sum * bound_factor;
            }
        }
        if used > 0 {
            // Exactly 1 for stride 1, so the full score is unchanged bit for bit.
            sum *= count as f64 / used as f64;
        }
        sum * self.params.weight
    }

    /// [`FloorMap::lookup`] at cell-centre coordinates (`fx`, `fy`).
    #[inline]
    fn lookup_cell(&self, fx: f64, fy: f64) -> Option<[f64; 5]> {
        let (idx, w) = self.corners_at(fx, fy)?;
        let mut acc = [0.0f64; 5];
        for (&i, &wi) in idx.iter().zip(&w) {
            // An unseen cell is all zeros: it adds +0.0 to sums of non-negative terms, which
            // leaves them as they are, bit for bit.
            for (a, &v) in acc.iter_mut().zip(&self.stats[i]) {
                *a += wi * v;
            }
        }
        (acc[4] >= 0.5).then_some(acc)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::types::geometry::{camera_mount, iso_from_xy_yaw};

    #[test]
    fn a_pixel_lands_where_its_ray_meets_the_floor() {
        // Camera 1.2 m up, pitched down 15 degrees: the image centre sees the floor at
        // 1.2 / tan(15 deg) = 4.478 m ahead.
        let cam = Camera::with_hfov(64, 60, 60f64.to_radians());
        let mount = camera_mount([0.0, 0.0, 1.2], 15f64.to_radians());
        let mut img = Rgb8 {
            width: 64,
            height: 60,
            data: vec![0; 64 * 60 * 3],
        };
        // One bright pixel just below the centre.
        let i = (30 * 64 + 31) * 3;
        img.data[i] = 255;
        let params = FloorParams {
            max_range_m: 6.0,
            min_pixels: 1,
            cell_m: 0.05,
            ..FloorParams::default()
        };
        let patch = floor_patch(&img, &cam, &mount, &params, |_, _| false);
        let (k, _) = patch
            .colour
            .iter()
            .enumerate()
            .find(|(_, c)| c[0] > 0.5)
            .unwrap();
        let ray = mount.rotation * cam.ray(31.5, 30.5);
        let t = -1.2 / ray.z;
        let want = mount.translation.vector + ray * t;
        assert!((patch.points_m[k][0] - want.x).abs() < 1e-9);
        assert!((patch.points_m[k][1] - want.y).abs() < 1e-9);
        // By hand: the pixel centre is half a pixel below the axis, so its ray is
        // 15 deg + atan(0.5 / fy) below level and meets the floor 1.2 / tan of that ahead.
        let depression = 15f64.to_radians() + (0.5 / cam.fy).atan();
        assert!((want.x - 1.2 / depression.tan()).abs() < 0.02, "{want:?}");
        assert!(want.y.abs() < 0.05, "{want:?}");
        // Left out when it is not floor; rows above the horizon never count.
        let without = floor_patch(&img, &cam, &mount, &params, |u, v| (u, v) == (31, 30));
        assert!(without.colour.iter().all(|c| c[0] == 0.0));
        let horizon_row = (cam.cy - cam.fy * 15f64.to_radians().tan()).floor() as usize;
        let below = (horizon_row + 1..60).count() * 64;
        let counted: u32 = patch.pixels.iter().sum();
        assert!(counted as usize <= below, "{counted} > {below}");
    }

    /// The score as the map's own `lookup` gives it, point by point in `odom`.
    fn score_by_lookup(map: &FloorMap, patch: &FloorPatch, pose: &Iso3) -> f64 {
        let p = map.params;
        let (s0, cap) = (p.sigma_colour * p.sigma_colour, p.truncate_sigmas.powi(2));
        let mut sum = 0.0;
        for (q, c) in patch.points_m.iter().zip(&patch.colour) {
            let r2 = map.lookup(&to_odom(pose, q)).map_or(1.0, |acc| {
                let k = 1.0 / acc[4];
                let d2 = (0..3)
                    .map(|ch| (f64::from(c[ch]) - acc[ch] * k).powi(2))
                    .sum::<f64>()
                    / 3.0;
                (d2 / (s0 + acc[3] * k)).min(cap)
            });
            sum -= 0.5 * r2;
        }
        sum * p.weight
    }

    /// A textured floor: 20 x 20 cells 6 cm apart about the origin, colour varying with
    /// position.
    fn textured_patch() -> FloorPatch {
        let points_m: Vec<[f64; 2]> = (0..400)
            .map(|i| {
                [
                    f64::from(i % 20) * 0.06 - 0.6,
                    f64::from(i / 20) * 0.06 - 0.6,
                ]
            })
            .collect();
        let colour = points_m
            .iter()
            .map(|p| [(p[0] + 1.0) as f32 * 0.4, (p[1] + 1.0) as f32 * 0.3, 0.5])
            .collect();
        FloorPatch {
            pixels: vec![8; points_m.len()],
            colour,
            points_m,
        }
    }

    #[test]
    fn the_folded_scorer_agrees_with_point_by_point_lookups() {
        let params = FloorParams::default();
        let mut map = FloorMap::new([-1.0, -1.0], [1.0, 1.0], params);
        // A textured floor, seen from two poses.
        let patch = textured_patch();
        map.add(&patch, &Iso3::identity());
        map.add(
            &patch,
            &crate::types::geometry::iso_from_xy_yaw(0.03, -0.02, 0.05),
        );
        for (x, y, yaw) in [(0.0, 0.0, 0.0), (0.05, -0.04, 0.1), (-0.3, 0.2, -0.7)] {
            let pose = crate::types::geometry::iso_from_xy_yaw(x, y, yaw);
            let want = score_by_lookup(&map, &patch, &pose);
            let got = map.score(&patch, &pose);
            assert!(
                (got - want).abs() <= 1e-9 * want.abs().max(1.0),
                "{got} vs {want}"
            );
        }
    }

    /// A point beyond usize (a pose 1e30 m away) is off the map, not a wrapped index.
    #[test]
    fn points_beyond_any_index_are_off_the_map() {
        let mut map = FloorMap::new([-1.0, -1.0], [1.0, 1.0], FloorParams::default());
        let patch = textured_patch();
        map.add(&patch, &Iso3::identity());
        for q in [
            [1e30, 0.0],
            [0.0, 1e30],
            [f64::INFINITY, 0.0],
            [f64::NAN, 0.0],
        ] {
            assert!(map.lookup(&q).is_none(), "{q:?}");
        }
        let far = iso_from_xy_yaw(1e30, -1e30, 0.3);
        assert_eq!(map.overlap(&patch, &far), 0);
        assert_eq!(
            map.score(&patch, &far),
            -0.5 * patch.len() as f64 * map.params.weight
        );
    }

    #[test]
    fn a_bounded_score_is_exact_above_the_bound_and_stops_below_it() {
        let params = FloorParams::default();
        let mut map = FloorMap::new([-1.0, -1.0], [1.0, 1.0], params);
        let patch = textured_patch();
        map.add(&patch, &Iso3::identity());
        let far = iso_from_xy_yaw(0.3, -0.2, 0.6);
        for stride in [1, 2] {
            let at_home = map.score_every(&patch, &Iso3::identity(), stride);
            let away = map.score_every(&patch, &far, stride);
            assert!(away < at_home - 1.0, "{away} vs {at_home}");
            // At or above the bound: the same number, bit for bit.
            let exact = map.score_every_above(&patch, &Iso3::identity(), stride, at_home);
            assert_eq!(exact.to_bits(), at_home.to_bits());
            // Certain to fall below it: stopped, below the bound, not below the score.
            let stopped = map.score_every_above(&patch, &far, stride, at_home);
            assert!(
                stopped < at_home && stopped >= away - 1e-9,
                "{stopped}, {away}"
            );
            assert_ne!(stopped.to_bits(), away.to_bits(), "it should stop early");
        }
    }

    #[test]
    fn a_strided_score_uses_every_stride_th_cell_scaled_to_the_patch() {
        let params = FloorParams::default();
        let c = params.cell_m;
        let mut map = FloorMap::new([0.0, 0.0], [1.0, 1.0], params);
        // A black floor, seen once at cell centres.
        let centres: Vec<[f64; 2]> = (0..10)
            .flat_map(|i| (0..10).map(move |j| [(i as f64 + 0.5) * c, (j as f64 + 0.5) * c]))
            .collect();
        let floor = FloorPatch {
            colour: vec![[0.0; 3]; centres.len()],
            pixels: vec![16; centres.len()],
            points_m: centres,
        };
        let identity = Iso3::identity();
        map.add(&floor, &identity);
        // Four cells inside the map: black, white, black, white. A black cell fits exactly
        // (residual 0); a white one is off by 1 per channel, far beyond the colour noise, so
        // its squared residual is truncated at `cap`.
        let cap = params.truncate_sigmas * params.truncate_sigmas;
        let points_m = vec![[0.35, 0.35], [0.45, 0.35], [0.55, 0.35], [0.65, 0.35]];
        let black_white = FloorPatch {
            colour: vec![[0.0; 3], [1.0; 3], [0.0; 3], [1.0; 3]],
            pixels: vec![16; 4],
            points_m: points_m.clone(),
        };
        let full = map.score(&black_white, &identity);
        assert!(
            (full - (-0.5 * 2.0 * cap * params.weight)).abs() < 1e-9,
            "{full}"
        );
        assert_eq!(map.score_every(&black_white, &identity, 1), full);
        // Every second cell: the two black ones, scaled by 4 / 2: still 0.
        assert_eq!(map.score_every(&black_white, &identity, 2), 0.0);
        // White first: the two white ones, scaled by 2: twice the full score.
        let white_black = FloorPatch {
            colour: vec![[1.0; 3], [0.0; 3], [1.0; 3], [0.0; 3]],
            ..black_white
        };
        let every_second = map.score_every(&white_black, &identity, 2);
        assert!((every_second - 2.0 * full).abs() < 1e-9, "{every_second}");
    }

    #[test]
    fn the_score_peaks_at_the_pose_the_map_was_built_with() {
        // A synthetic floor: two patches of a checkered rug, seen from one pose; the same
        // patch scores best at that pose and worse 0.2 m or 5 degrees off it.
        let mut patch = FloorPatch::default();
        for ix in 0..30 {
            for iy in -15..15 {
                let (x, y) = (1.0 + f64::from(ix) * 0.1, f64::from(iy) * 0.1);
                let v = if ((x * 2.0).floor() + (y * 2.0).floor()) as i64 % 2 == 0 {
                    0.8
                } else {
                    0.3
                };
                patch.points_m.push([x + 0.05, y + 0.05]);
                patch.colour.push([v, v, v]);
                patch.pixels.push(16);
            }
        }
        let pose = iso_from_xy_yaw(0.3, -0.2, 0.4);
        let mut map = FloorMap::new([-6.0, -6.0], [6.0, 6.0], FloorParams::default());
        map.add(&patch, &pose);
        let at = map.score(&patch, &pose);
        for off in [
            iso_from_xy_yaw(0.5, -0.2, 0.4),
            iso_from_xy_yaw(0.3, 0.0, 0.4),
            iso_from_xy_yaw(0.3, -0.2, 0.4 + 5f64.to_radians()),
        ] {
            assert!(map.score(&patch, &off) < at - 1.0, "{at}");
        }
    }

    /// Fit and disagreement on a hand-made map: a black 10 x 10 cell floor seen twice at the
    /// same pose (no disagreement), then once more with one white cell (variance 0.25 per
    /// channel in that cell's four bilinear corners); a patch of 4 black and 1 white cells
    /// fits 4 of 5 within 2 sigmas.
    #[test]
    fn fit_counts_cells_within_two_sigmas_and_disagreement_needs_two_views() {
        let params = FloorParams::default();
        let c = params.cell_m;
        let centres: Vec<[f64; 2]> = (0..10)
            .flat_map(|i| (0..10).map(move |j| [(i as f64 + 0.5) * c, (j as f64 + 0.5) * c]))
            .collect();
        let black = FloorPatch {
            colour: vec![[0.0; 3]; centres.len()],
            pixels: vec![16; centres.len()],
            points_m: centres.clone(),
        };
        let identity = Iso3::identity();
        let mut map = FloorMap::new([0.0, 0.0], [1.0, 1.0], params);
        map.add(&black, &identity);
        // One view: no cell seen twice, nothing to disagree about.
        assert_eq!(map.disagreement(), 0.0);
        map.add(&black, &identity);
        assert_eq!(map.disagreement(), 0.0);
        let probe = FloorPatch {
            colour: vec![[0.0; 3], [0.0; 3], [0.0; 3], [0.0; 3], [1.0; 3]],
            pixels: vec![16; 5],
            points_m: vec![[0.2, 0.2], [0.3, 0.3], [0.4, 0.4], [0.5, 0.5], [0.6, 0.3]],
        };
        assert_eq!(map.fit(&probe, &identity), Some(0.8));
        // Far off the map: nothing lands.
        assert_eq!(map.fit(&probe, &iso_from_xy_yaw(5.0, 5.0, 0.0)), None);
        // A third view with the black cells white makes them disagree: the capped variance
        // over the colour noise is positive.
        let white = FloorPatch {
            colour: vec![[1.0; 3]; centres.len()],
            ..black
        };
        map.add(&white, &identity);
        let cap = params.truncate_sigmas * params.truncate_sigmas;
        let d = map.disagreement();
        assert!(d > 0.0 && d <= cap, "{d}");
        // The free function builds the map from (patch, pose) pairs: one view, no cell seen
        // twice; the same view twice agrees with itself.
        assert_eq!(disagreement(&[(&white, &identity)], params), 0.0);
        let twice = disagreement(&[(&white, &identity), (&white, &identity)], params);
        assert!(twice.abs() < 1e-9, "{twice}");
    }
}
