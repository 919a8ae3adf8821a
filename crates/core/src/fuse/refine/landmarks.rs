//! Landmarks for pose refinement: detection clusters in an image, the rays through them, the
//! objects placed where the rays of several frames meet, and how well a set of rays meets
//! (the rollback check).
//!
//! Invariants: pure functions of their inputs; rays are kept in frame order and chosen per
//! frame by distance, ties to the first.

use nalgebra::{Matrix2, Matrix2x3, Matrix3, Point3, SymmetricEigen, Vector3};

use crate::fuse::grid::TileEvidence;
use crate::types::geometry::{Camera, Iso3};

/// Tiles whose evidence is at least this (odds ratio e^3 = 20 against the prior) are
/// detections.
pub const DETECTION_DELTA: f32 = 3.0;
/// Standard deviation of a cluster's centroid about its landmark's projection, horizontally
/// and vertically, pixels (measured 1-3 px and 2-8 px across the shipped tours' views; the
/// vertical spread comes from legs and shadows).
pub const SIGMA_U_PX: f64 = 3.0;
/// Vertical counterpart of [`SIGMA_U_PX`], pixels.
pub const SIGMA_V_PX: f64 = 8.0;
/// A cluster further than this from a landmark's predicted position is not its sighting.
pub const GATE_PX: f64 = 64.0;
/// A ray passing further than this from an object's centroid is not a sighting of it.
pub const GATE_M: f64 = 0.35;
/// A ray missing its landmark by more than this (chi-square with 2 degrees of freedom,
/// 99.7 %) is dropped from it.
pub const MAX_RAY_CHI2: f64 = 11.8;
/// Smallest eigenvalue of the rays' normal matrix for a landmark to be placed: rays from
/// at least 15 degrees apart (1 - cos 15 deg = 0.034).
pub const MIN_RAY_SPREAD: f64 = 0.034;

/// Clusters of detection tiles (8-connected), each as its evidence-weighted centroid in
/// pixels, in row-major order of their first tile. Linking across gaps would join a chair's
/// legs to its seat, but it also merged two chairs standing one behind the other in the
/// two-chairs tour, whose merged centroid then pulled the pose 0.1 rad off.
pub fn detection_clusters(ev: &TileEvidence) -> Vec<[f64; 2]> {
    detections(ev).iter().map(|d| d.centroid_px).collect()
}

/// One 8-connected group of detection tiles ([`DETECTION_DELTA`]) in an image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Detection {
    /// Evidence-weighted centroid of its tiles' centres, pixels (u, v).
    pub centroid_px: [f64; 2],
    /// Min corner (u, v) of the box around its tiles, pixels (a tile's edge).
    pub box_min_px: [f64; 2],
    /// Max corner (u, v) of that box, pixels.
    pub box_max_px: [f64; 2],
    /// Whether a tile of it lies in the first or last row or column of tiles: the object may
    /// run past the image's edge, so the box's centre is not its projection.
    pub at_border: bool,
}

impl Detection {
    /// Centre of the box, pixels (u, v).
    pub fn box_centre_px(&self) -> [f64; 2] {
        [
            0.5 * (self.box_min_px[0] + self.box_max_px[0]),
            0.5 * (self.box_min_px[1] + self.box_max_px[1]),
        ]
    }
}

/// The groups of detection tiles in `ev`, in row-major order of their first tile.
pub fn detections(ev: &TileEvidence) -> Vec<Detection> {
    let tile = f64::from(ev.tile_px);
    let (rows, cols) = (ev.rows, ev.cols);
    let hot = |t: usize| ev.delta[t] >= DETECTION_DELTA;
    let mut seen = vec![false; rows * cols];
    let mut out = Vec::new();
    for start in 0..rows * cols {
        if seen[start] || !hot(start) {
            continue;
        }
        seen[start] = true;
        let mut stack = vec![start];
        let (mut w, mut su, mut sv) = (0.0f64, 0.0f64, 0.0f64);
        let (mut lo, mut hi) = ([usize::MAX; 2], [0usize; 2]);
        while let Some(t) = stack.pop() {
            let (r, c) = (t / cols, t % cols);
            let d = f64::from(ev.delta[t]);
            w += d;
            su += d * (c as f64 + 0.5) * tile;
            sv += d * (r as f64 + 0.5) * tile;
            lo = [lo[0].min(c), lo[1].min(r)];
            hi = [hi[0].max(c), hi[1].max(r)];
            for nr in r.saturating_sub(1)..=(r + 1).min(rows - 1) {
                for nc in c.saturating_sub(1)..=(c + 1).min(cols - 1) {
                    let n = nr * cols + nc;
                    if !seen[n] && hot(n) {
                        seen[n] = true;
                        stack.push(n);
                    }
                }
            }
        }
        out.push(Detection {
            centroid_px: [su / w, sv / w],
            box_min_px: [lo[0] as f64 * tile, lo[1] as f64 * tile],
            box_max_px: [(hi[0] + 1) as f64 * tile, (hi[1] + 1) as f64 * tile],
            at_border: lo[0] == 0 || lo[1] == 0 || hi[0] + 1 == cols || hi[1] + 1 == rows,
        });
    }
    out
}

/// A ray in `odom` through a detection cluster's centroid, from the frame it was seen in.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sighting {
    /// Index of the fused frame (0-based) the cluster was seen in.
    pub frame: usize,
    /// Where the ray starts: the camera centre in `odom`, metres.
    pub origin_m: Vector3<f64>,
    /// Unit direction.
    pub direction: Vector3<f64>,
}

/// The rays through a frame's detection clusters seen from `odom_from_camera`.
pub fn sightings(
    frame: usize,
    clusters: &[[f64; 2]],
    camera: &Camera,
    odom_from_camera: &Iso3,
) -> Vec<Sighting> {
    clusters
        .iter()
        .map(|[u, v]| Sighting {
            frame,
            origin_m: odom_from_camera.translation.vector,
            direction: odom_from_camera.rotation * camera.ray(*u, *v),
        })
        .collect()
}

/// Distance from `p` to the ray's line, metres (behind the origin counts as far).
fn ray_distance(s: &Sighting, p: &Vector3<f64>) -> f64 {
    let d = p - s.origin_m;
    let along = d.dot(&s.direction);
    if along <= 0.0 {
        return f64::INFINITY;
    }
    (d - s.direction * along).norm()
}

/// Of `sightings` (in frame order), the one passing closest to `c` per frame, within `gate_m`,
/// with its distance (ties to the first ray of a frame).
fn closest_per_frame<'a>(
    c: &Vector3<f64>,
    sightings: &'a [Sighting],
    gate_m: f64,
) -> Vec<(f64, &'a Sighting)> {
    closest_per_recent_frame(c, sightings, gate_m, usize::MAX)
}

/// Of `sightings` (in frame order), the one passing closest to `c` per frame within `gate_m`,
/// for the last `max_frames` frames that have one, in frame order (ties to the first ray of a
/// frame), found by scanning back from the newest ray, so that its cost does not grow with
/// the frames before them.
fn closest_per_recent_frame<'a>(
    c: &Vector3<f64>,
    sightings: &'a [Sighting],
    gate_m: f64,
    max_frames: usize,
) -> Vec<(f64, &'a Sighting)> {
    let mut chosen: Vec<(f64, &Sighting)> = Vec::new();
    for s in sightings.iter().rev() {
        let d = ray_distance(s, c);
        // A NaN distance (a degenerate ray) is left out too.
        if d.is_nan() || d > gate_m {
            continue;
        }
        let full = chosen.len() == max_frames;
        match chosen.last_mut() {
            // `<=`: scanning backwards, the earlier of two equal rays comes later.
            Some(last) if last.1.frame == s.frame => {
                if d <= last.0 {
                    *last = (d, s);
                }
            }
            _ if full => break,
            _ => chosen.push((d, s)),
        }
    }
    chosen.reverse();
    chosen
}

/// Frames whose rays place a landmark, at most: the most recent that saw it. A replay's cost
/// per frame would otherwise grow with every frame before it (the rays are gathered and
/// triangulated again at each frame, and a ray that misfits is dropped one at a time): a
/// 5 000-frame tour spent 62 % of its time here and replayed at 27 frames/s against 100 for
/// 1 000 frames. The recent rays were cast from poses placed like the frame being localised.
/// Every tour of the accuracy sets has at most a few dozen frames, so none is affected.
pub const MAX_LANDMARK_FRAMES: usize = 100;

/// A landmark: a point in `odom` and the covariance of its position (m^2).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Landmark {
    /// Position of the landmark in `odom`, metres.
    pub position_m: Vector3<f64>,
    /// Covariance of `position_m` (x, y, z in `odom`), m^2; symmetric, positive semi-definite.
    pub covariance_m2: Matrix3<f64>,
}

/// Places each object (given by its centroid in the belief) as a landmark: the weighted
/// least-squares point of the rays that saw it, at most one per frame (the one passing
/// closest, within [`GATE_M`]) and from the last [`MAX_LANDMARK_FRAMES`] frames that saw it. A ray's sideways error is weighted by the horizontal pixel
/// sigma, its up-down error by the vertical one, both scaled by the range to the centroid
/// and the focal length, so the landmark's covariance comes out in metres. Objects seen from
/// too narrow a spread of directions (fewer than two frames, or rays within 15 degrees) are
/// left out.
pub fn landmarks(
    object_centroids: &[[f64; 3]],
    sightings: &[Sighting],
    focal_px: f64,
) -> Vec<Landmark> {
    let mut out = Vec::new();
    for c in object_centroids {
        let c = Vector3::new(c[0], c[1], c[2]);
        let mut chosen = closest_per_recent_frame(&c, sightings, GATE_M, MAX_LANDMARK_FRAMES);
        // Rays that disagree with the rest (a cluster that merged two objects, a shadow) are
        // dropped one at a time, worst first, until every ray fits.
        loop {
            if chosen.len() < 2 {
                break;
            }
            let Some(lm) = triangulate(&chosen, &c, focal_px) else {
                break;
            };
            let worst = chosen
                .iter()
                .enumerate()
                .map(|(k, (_, s))| (ray_chi2(s, &lm.position_m, &c, focal_px), k))
                .max_by(|a, b| a.0.total_cmp(&b.0).then(b.1.cmp(&a.1)));
            match worst {
                Some((chi2, k)) if chi2 > MAX_RAY_CHI2 => {
                    chosen.remove(k);
                }
                // A point the rays agree on but far from the object they were chosen for is
                // two rays of different things crossing by chance.
                _ if (lm.position_m - c).norm() > GATE_M => break,
                _ => {
                    out.push(lm);
                    break;
                }
            }
        }
    }
    out
}

/// How well the rays through the frames' detections meet, one point per object: for each
/// object, the ray of each frame passing closest to it (within a gate) is kept, the kept rays
/// are triangulated, and each frame with detections scores its ray's chi-square against the
/// point (capped at [`MAX_RAY_CHI2`], which is also what a frame without a ray near the object
/// scores).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Consistency {
    /// Objects triangulated.
    pub objects: usize,
    /// Frame-object pairs scored.
    pub rays: usize,
    /// Their mean capped chi-square (2 degrees of freedom).
    pub mean_chi2: f64,
}

impl Consistency {
    /// The consistency of `sightings` (several frames' rays) about the objects at `seeds`,
    /// each ray within `gate_m` of a seed a candidate for it.
    pub fn of(seeds: &[[f64; 3]], sightings: &[Sighting], focal_px: f64, gate_m: f64) -> Self {
        let frames: Vec<usize> = {
            let mut f: Vec<usize> = sightings.iter().map(|s| s.frame).collect();
            f.dedup();
            f
        };
        let (mut objects, mut rays, mut sum) = (0, 0, 0.0);
        for c in seeds {
            let c = Vector3::new(c[0], c[1], c[2]);
            let chosen = closest_per_frame(&c, sightings, gate_m);
            let Some(lm) = triangulate(&chosen, &c, focal_px) else {
                continue;
            };
            objects += 1;
            for f in &frames {
                let chi2 = chosen
                    .iter()
                    .find(|(_, s)| s.frame == *f)
                    .map_or(MAX_RAY_CHI2, |(_, s)| {
                        ray_chi2(s, &lm.position_m, &c, focal_px).min(MAX_RAY_CHI2)
                    });
                rays += 1;
                sum += chi2;
            }
        }
        Consistency {
            objects,
            rays,
            mean_chi2: if rays > 0 { sum / rays as f64 } else { 0.0 },
        }
    }

    /// Whether these rays meet worse than `other`'s (by more than the rollback tolerance).
    pub fn worse_than(&self, other: &Consistency) -> bool {
        self.mean_chi2 > other.mean_chi2 * (1.0 + crate::fuse::replay::ROLLBACK_TOLERANCE) + 1e-9
    }
}

/// Disagreement of one ray with a landmark at `p`: its sideways and up-down misses, in
/// pixels at the range of `centre`, over their sigmas, squared and summed.
fn ray_chi2(s: &Sighting, p: &Vector3<f64>, centre: &Vector3<f64>, focal_px: f64) -> f64 {
    let Some((h, v)) = across_axes(&s.direction) else {
        return f64::INFINITY;
    };
    let miss = p - s.origin_m;
    let range = (centre - s.origin_m).norm().max(0.1);
    let eh = h.dot(&miss) * focal_px / range / SIGMA_U_PX;
    let ev = v.dot(&miss) * focal_px / range / SIGMA_V_PX;
    eh * eh + ev * ev
}

/// Unit vectors across a ray: level (sideways) and the one completing them (up-down). A
/// vertical ray (a camera looking straight down) has no level direction; any pair across it
/// serves, so x stands in for the vertical (else one such ray dropped the whole landmark).
fn across_axes(d: &Vector3<f64>) -> Option<(Vector3<f64>, Vector3<f64>)> {
    let h = d
        .cross(&Vector3::z())
        .try_normalize(1e-9)
        .or_else(|| d.cross(&Vector3::x()).try_normalize(1e-9))?;
    Some((h, d.cross(&h)))
}

/// The weighted least-squares point of `rays` and its covariance; `None` when they are too
/// few or too close to parallel.
fn triangulate(
    rays: &[(f64, &Sighting)],
    centre: &Vector3<f64>,
    focal_px: f64,
) -> Option<Landmark> {
    let mut spread = Matrix3::zeros();
    let mut info = Matrix3::zeros();
    let mut b = Vector3::zeros();
    for (_, s) in rays {
        let d = s.direction;
        spread += Matrix3::identity() - d * d.transpose();
        let (h, v) = across_axes(&d)?;
        let range = (centre - s.origin_m).norm().max(0.1);
        let wh = (focal_px / (range * SIGMA_U_PX)).powi(2);
        let wv = (focal_px / (range * SIGMA_V_PX)).powi(2);
        let m = h * h.transpose() * wh + v * v.transpose() * wv;
        info += m;
        b += m * s.origin_m;
    }
    if rays.len() < 2 || SymmetricEigen::new(spread).eigenvalues.min() < MIN_RAY_SPREAD {
        return None;
    }
    let cov = info.try_inverse()?;
    Some(Landmark {
        position_m: cov * b,
        covariance_m2: cov,
    })
}

pub(super) fn project(
    camera: &Camera,
    camera_from_odom: &Iso3,
    p: &Vector3<f64>,
) -> Option<[f64; 2]> {
    camera
        .project(&(camera_from_odom * Point3::from(*p)))
        .map(|(u, v)| [u, v])
}

/// Information (inverse covariance, 1/pixels^2) of where `lm` appears from `camera_from_odom`: its position's
/// covariance pushed through the projection, plus the detection's own spread.
pub(super) fn image_covariance(
    lm: &Landmark,
    camera: &Camera,
    camera_from_odom: &Iso3,
) -> Option<Matrix2<f64>> {
    let p = camera_from_odom * Point3::from(lm.position_m);
    if p.z <= 1e-9 {
        return None;
    }
    let r = camera_from_odom.rotation.to_rotation_matrix();
    let dproj = Matrix2x3::new(
        camera.fx / p.z,
        0.0,
        -camera.fx * p.x / (p.z * p.z),
        0.0,
        camera.fy / p.z,
        -camera.fy * p.y / (p.z * p.z),
    );
    let j = dproj * r.matrix();
    let s = j * lm.covariance_m2 * j.transpose()
        + Matrix2::new(SIGMA_U_PX.powi(2), 0.0, 0.0, SIGMA_V_PX.powi(2));
    s.try_inverse()
}

/// Pairs each landmark visible from `odom_from_camera` with the nearest cluster within
/// [`GATE_PX`], closest pairs first, each cluster used once.
pub(super) fn associate(
    landmarks: &[Landmark],
    clusters: &[[f64; 2]],
    camera: &Camera,
    odom_from_camera: &Iso3,
) -> Vec<(usize, usize)> {
    let camera_from_odom = odom_from_camera.inverse();
    let mut pairs = Vec::new();
    for (i, l) in landmarks.iter().enumerate() {
        let Some(p) = project(camera, &camera_from_odom, &l.position_m) else {
            continue;
        };
        for (j, c) in clusters.iter().enumerate() {
            let dist = (p[0] - c[0]).hypot(p[1] - c[1]);
            if dist <= GATE_PX {
                pairs.push((dist, i, j));
            }
        }
    }
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let mut used_l = vec![false; landmarks.len()];
    let mut used_c = vec![false; clusters.len()];
    let mut out = Vec::new();
    for (_, i, j) in pairs {
        if !used_l[i] && !used_c[j] {
            used_l[i] = true;
            used_c[j] = true;
            out.push((i, j));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The forward scan `closest_per_frame` was before the backward one: per frame the
    /// closest ray within `gate_m`, ties to the first.
    fn forward_scan<'a>(
        c: &Vector3<f64>,
        sightings: &'a [Sighting],
        gate_m: f64,
    ) -> Vec<(f64, &'a Sighting)> {
        let mut chosen: Vec<(f64, &Sighting)> = Vec::new();
        for s in sightings {
            let d = ray_distance(s, c);
            // A NaN distance (a degenerate ray) is left out too.
            if d.is_nan() || d > gate_m {
                continue;
            }
            match chosen.last_mut() {
                Some(last) if last.1.frame == s.frame => {
                    if d < last.0 {
                        *last = (d, s);
                    }
                }
                _ => chosen.push((d, s)),
            }
        }
        chosen
    }

    /// Scanning back from the newest ray chooses what the forward scan chooses, ties and
    /// all, cut to the last frames: rays of 30 frames towards points about a centre, two or
    /// three a frame (some equally close, some outside the gate, some frames without one).
    #[test]
    fn the_recent_rays_are_the_tail_of_all_rays() {
        let c = Vector3::new(2.0, 0.5, 0.4);
        let mut rays = Vec::new();
        for frame in 0..30usize {
            let origin = Vector3::new(-1.0, frame as f64 * 0.1 - 1.5, 0.3);
            let offsets: &[f64] = match frame % 4 {
                0 => &[0.05, -0.05, 0.2],
                1 => &[0.9],
                2 => &[0.1, 0.03],
                _ => &[0.02, 0.02, -0.3],
            };
            for &o in offsets {
                let target = c + Vector3::new(0.0, o, 0.0);
                rays.push(Sighting {
                    frame,
                    origin_m: origin,
                    direction: (target - origin).normalize(),
                });
            }
        }
        let all = forward_scan(&c, &rays, GATE_M);
        assert_eq!(
            all.len(),
            22,
            "frames 1, 5, 9, ... have no ray within the gate"
        );
        let same = |a: &[(f64, &Sighting)], b: &[(f64, &Sighting)]| {
            a.len() == b.len()
                && a.iter()
                    .zip(b)
                    .all(|(x, y)| x.0 == y.0 && std::ptr::eq(x.1, y.1))
        };
        for m in [0, 1, 5, 21, 22, 40] {
            let recent = closest_per_recent_frame(&c, &rays, GATE_M, m);
            let tail = &all[all.len().saturating_sub(m)..];
            assert!(same(&recent, tail), "max_frames {m}");
        }
        // Equal distances keep the first ray of the frame, as the forward scan does.
        let frame3 = all.iter().find(|(_, s)| s.frame == 3).unwrap();
        let first_of_3 = rays.iter().find(|s| s.frame == 3).unwrap();
        assert!(std::ptr::eq(frame3.1, first_of_3));
    }

    /// A ray straight down still has two unit axes across it, orthogonal to it and to each
    /// other; a level ray's first axis is level.
    #[test]
    fn axes_across_vertical_and_level_rays() {
        for d in [-Vector3::z(), Vector3::z(), Vector3::new(0.6, 0.0, -0.8)] {
            let (h, v) = across_axes(&d).unwrap();
            for (a, b) in [(h, d), (v, d), (h, v)] {
                assert!(a.dot(&b).abs() < 1e-12, "{d:?}");
            }
            assert!((h.norm() - 1.0).abs() < 1e-12 && (v.norm() - 1.0).abs() < 1e-12);
        }
        let (h, _) = across_axes(&Vector3::new(0.6, 0.0, -0.8)).unwrap();
        assert!(h.z.abs() < 1e-12);
    }
}
