//! Pose refinement: before a frame is fused, localise it against what earlier frames saw
//! (Markov localisation, which the paper points to, in a window around the prediction).
//!
//! The prediction is the previous frame's refined pose moved by the odometry increment since,
//! so a correction carries forward as in any localiser; the first frame anchors the frame of
//! reference. Candidates are planar corrections (dx, dy, dyaw) of the prediction, each scored
//! by
//!
//! * the motion model: a Gaussian whose covariance is propagated through the commands since
//!   the previous frame (speed error sigma_v * t along the heading, turn error sigma_w * t,
//!   and the sideways error a heading error causes on later translations), times
//! * the likelihood of the frame's detections given the landmarks: each object of the belief
//!   is a landmark, placed where the rays through its detections in earlier frames meet; a
//!   candidate pose predicts where each landmark appears in this frame, and the detection
//!   seen there is Gaussian about that point; times
//! * (unless `fuse --no-floor`) the likelihood of the frame's view of the floor given the
//!   floor the earlier frames saw ([`crate::fuse::floor`]). One object fixes a frame's bearing
//!   but not where around the object the robot stands; the floor around it fixes all three
//!   of (x, y, yaw), from the second frame on.
//!
//! Why landmarks triangulated from detections and not the belief's cells: measured on the
//! shipped tours with true poses, the centroid of an object's detections in each view is the
//! projection of one 3D point to within 1-3 pixels across views (the centroid of the object's
//! visible colour), while the belief's own shape is 5-15 pixels off in every view (its hull
//! is bloated along the earlier views' rays, and the chair's shadow and thin legs differ).
//! Aligning to the belief's shape pulled even exact poses 0.1-0.5 m off over a tour; aligning
//! to triangulated centroids moves them by 1-3 pixels' worth per frame (up to 0.08 m over the
//! chair tour). docs/fuser.md has the numbers.
//!
//! What one object can and cannot fix: its image position fixes the bearing, its height in
//! the image (weakly) the range; sliding around the object while turning to keep it in view
//! is unobservable from the object alone, which is what the floor term is for.
//!
//! The search is a fixed grid in the motion model's whitened coordinates (+-3 sigma in 9 steps
//! per axis) followed by finer 3x3x3 grids around the best candidate, evaluated in a fixed
//! order with ties going to the first: deterministic, and sequential (a few landmarks make
//! each candidate cheap), so the thread count cannot matter.
//!
//! A correction is applied only when it raises the score by [`MIN_GAIN`]: smaller ones fit
//! the noise of the detections, and applied they compound into drift.
//!
//! Invariants: pure functions of their inputs, no I/O; without a landmark seen in the frame
//! or floor seen before, or without a significant gain, the correction is zero.

use nalgebra::{
    Matrix2, Matrix2x3, Matrix3, Point3, SymmetricEigen, Translation3, UnitQuaternion, Vector2,
    Vector3,
};

use rayon::prelude::*;

use crate::fuse::floor::{FloorMap, FloorPatch};
use crate::fuse::grid::TileEvidence;
use crate::fuse::motion::Segment;
use crate::types::geometry::{Camera, Iso3, yaw_of};

/// Tiles whose evidence is at least this (odds ratio e^3 = 20 against the prior) are
/// detections.
pub const DETECTION_DELTA: f32 = 3.0;
/// Standard deviation of a cluster's centroid about its landmark's projection, horizontally
/// and vertically, pixels (measured 1-3 px and 2-8 px across the shipped tours' views; the
/// vertical spread comes from legs and shadows).
pub const SIGMA_U_PX: f64 = 3.0;
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

/// Smallest gain in score (log-likelihood plus log prior, nats) for a correction to be
/// applied. Measured: with exact odometry the best correction gains 0-0.8 (it fits the 1-3 px
/// noise of the detection centroids), with real drift 3-40; applying the small ones only
/// compounds that noise into drift along the direction one object cannot observe (exact
/// odometry: ATE 0.048 m applied, 0.004 m gated).
pub const MIN_GAIN: f64 = 0.75;

/// Chi-square (3 degrees of freedom) a frame's total correction against /odom may reach:
/// the 99 % point, for a speed noise up to [`GATE_SIGMA_SCALE`] times the sigmas. Beyond it
/// the correction is more than the speed noise can explain since the first frame, whatever
/// each step looked like.
pub const GATE_CHI2: f64 = 11.34;

/// The gate allows for speed noise up to this many times what `--sigma-v/-w` say: the default
/// sigmas (0.01) sit between the 1 %/0.6 % and the 5 %/3 % noise of the simulated tours
/// (0.003 and 0.015 at 0.3 m/s and 0.5 rad/s), and a gate at the sigmas themselves stopped
/// true corrections on the 5 %/3 % tours (docs/fuser.md).
pub const GATE_SIGMA_SCALE: f64 = 2.0;

/// Fraction of a frame's floor cells that must fit the map (within 2 sigmas) at the best
/// pose for the floor term to be used for that frame.
pub const MIN_FLOOR_FIT: f64 = 0.85;

/// A correction is ambiguous when a candidate separated from the best (not its neighbour
/// on the coarse grid) scores within this many nats of it.
pub const AMBIGUITY_MARGIN: f64 = 2.0;

/// Smallest standard deviations of the motion model, added to the propagated covariance:
/// they keep it invertible after a frame without motion and let a frame settle within a
/// fraction of a tile of its neighbours.
pub const FLOOR_SIGMA_XY_M: f64 = 0.01;
pub const FLOOR_SIGMA_YAW_RAD: f64 = 0.005;

/// Half-width of the coarse search, in standard deviations of the motion model.
const SEARCH_SIGMAS: f64 = 3.0;
/// Steps of the coarse search per axis (odd, so that zero correction is a candidate).
const COARSE_STEPS: i32 = 9;
/// Finer 3x3x3 rounds around the best candidate, each at half the previous step.
const FINE_ROUNDS: usize = 4;
/// The coarse round (729 of the ~840 candidates) scores the floor on every second cell of
/// the patch; the fine rounds use every cell. Measured on the 4 shipped and 24
/// held-out-style tours: the same object errors on 25 sessions, three moved by 0.001-0.013 m
/// (mean 0.036 -> 0.037 m, worst unchanged at 0.081 m; mean ATE 0.058 -> 0.053 m), and the
/// chair tour's replay 17-25 % faster. Every third cell lost a session (a chair at 0.153 m).
const COARSE_FLOOR_STRIDE: usize = 2;

/// What refinement did with one frame, and why.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Verdict {
    /// The correction was applied: the frame was fused at the corrected pose.
    Accepted,
    /// Nothing to align to: no landmark paired with a detection and no floor seen before.
    #[default]
    NoEvidence,
    /// The best correction gains less than [`MIN_GAIN`]: it fits noise.
    Insignificant,
    /// Candidates far apart score almost as well as the best ([`AMBIGUITY_MARGIN`]): a
    /// repeating floor, or a landmark that fits two poses.
    Ambiguous,
    /// The pose it gives lies outside the motion model's chi-square gate ([`GATE_CHI2`])
    /// about /odom since the first frame: more correction than the speed noise allows.
    Gated,
    /// Accepted during the replay, then undone: the refined replay explained the frames
    /// worse than /odom did, so the frame was fused at its /odom pose.
    RolledBack,
}

impl Verdict {
    /// Whether the frame's pose was measured: corrected, or found where it was predicted
    /// (then it needs no motion blur either).
    pub fn measured(self) -> bool {
        matches!(self, Verdict::Accepted | Verdict::Insignificant)
    }

    /// One word for tables and plots.
    pub fn label(self) -> &'static str {
        match self {
            Verdict::Accepted => "accepted",
            Verdict::NoEvidence => "no-evidence",
            Verdict::Insignificant => "insignificant",
            Verdict::Ambiguous => "ambiguous",
            Verdict::Gated => "gated",
            Verdict::RolledBack => "rolled-back",
        }
    }
}

/// The correction chosen for one frame, relative to the predicted pose.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Correction {
    /// The best candidate's correction of the predicted position in `odom`, metres (applied
    /// only when `applied`).
    pub dx_m: f64,
    pub dy_m: f64,
    /// ... of the predicted heading, radians (about the robot's vertical axis).
    pub dyaw_rad: f64,
    /// Score (log-likelihood plus log prior) of the chosen candidate minus that of no
    /// correction.
    pub gain: f64,
    /// Landmarks the frame was aligned to (each paired with a detection cluster).
    pub anchors: usize,
    /// Cells of the frame's floor that lay on floor seen before, at the chosen pose (0 when
    /// refining without the floor).
    #[serde(default)]
    pub floor_cells: usize,
    /// Whether the correction was applied (`outcome` is [`Verdict::Accepted`]); when not, the
    /// frame keeps its predicted pose and is treated as not localised.
    #[serde(default)]
    pub applied: bool,
    /// Why it was or was not applied.
    #[serde(default)]
    pub outcome: Verdict,
    /// Chi-square of the candidate pose's total correction against /odom, on the motion
    /// model's covariance propagated from the first frame (3 degrees of freedom).
    #[serde(default)]
    pub total_chi2: f64,
    /// Score of the best candidate separated from the best (coarse search), below the best:
    /// small means ambiguous. Infinite when there is no other maximum.
    #[serde(default = "infinite", with = "finite_or_null")]
    pub runner_up_margin: f64,
    /// Distance from the best to that runner-up, in standard deviations of the motion model.
    #[serde(default)]
    pub runner_up_sigmas: f64,
    /// Fraction of the floor cells that fit the map within 2 sigmas at the candidate pose
    /// and at the predicted pose.
    #[serde(default)]
    pub floor_fit: Option<[f64; 2]>,
}

fn infinite() -> f64 {
    f64::INFINITY
}

/// JSON has no infinity: written as null, read back as infinity.
mod finite_or_null {
    pub fn serialize<S: serde::Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
        if v.is_finite() {
            s.serialize_f64(*v)
        } else {
            s.serialize_none()
        }
    }
    pub fn deserialize<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        let v: Option<f64> = serde::Deserialize::deserialize(d)?;
        Ok(v.unwrap_or(f64::INFINITY))
    }
}

impl Correction {
    pub const ZERO: Correction = Correction {
        dx_m: 0.0,
        dy_m: 0.0,
        dyaw_rad: 0.0,
        gain: 0.0,
        anchors: 0,
        floor_cells: 0,
        applied: false,
        outcome: Verdict::NoEvidence,
        total_chi2: 0.0,
        runner_up_margin: f64::INFINITY,
        runner_up_sigmas: 0.0,
        floor_fit: None,
    };

    /// Applies the correction to a robot pose in `odom`: the heading turns about the robot's
    /// own vertical axis, the position moves in `odom`.
    ///
    /// A correction not applied returns the pose itself (not a product with the identity,
    /// which can flip the sign of a zero).
    pub fn apply(&self, odom_from_base: &Iso3) -> Iso3 {
        if !self.applied {
            return *odom_from_base;
        }
        apply(odom_from_base, self.dx_m, self.dy_m, self.dyaw_rad)
    }
}

/// The motion model's bound on the total correction: /odom at the frame and the covariance
/// of its error since the first frame (x, y, yaw in `odom`, without the floor).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TotalGate {
    pub odometry: Iso3,
    pub covariance: Matrix3<f64>,
}

impl TotalGate {
    /// Chi-square of `odom_from_base` against /odom (3 degrees of freedom).
    pub fn chi2(&self, odom_from_base: &Iso3) -> f64 {
        let dt = odom_from_base.translation.vector - self.odometry.translation.vector;
        let dyaw =
            crate::types::geometry::wrap_angle(yaw_of(odom_from_base) - yaw_of(&self.odometry));
        let e = Vector3::new(dt.x, dt.y, dyaw);
        let cov = self.covariance
            + Matrix3::from_diagonal(&Vector3::new(
                FLOOR_SIGMA_XY_M.powi(2),
                FLOOR_SIGMA_XY_M.powi(2),
                FLOOR_SIGMA_YAW_RAD.powi(2),
            ));
        match cov.try_inverse() {
            Some(inv) => (e.transpose() * inv * e)[(0, 0)],
            None => f64::INFINITY,
        }
    }
}

fn apply(odom_from_base: &Iso3, dx: f64, dy: f64, dyaw: f64) -> Iso3 {
    let rot = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), dyaw) * odom_from_base.rotation;
    let t = odom_from_base.translation.vector + Vector3::new(dx, dy, 0.0);
    Iso3::from_parts(Translation3::from(t), rot)
}

/// Covariance of the planar pose (x, y, yaw in `odom`) after driving `segments` from a known
/// pose, each given with the robot pose at its start (for the heading). First-order
/// propagation of the paper's motion model: a translation of duration t has speed error
/// sigma_v * t along the heading; a rotation, sigma_w * t in heading; a heading error turns
/// into a sideways error on every later translation. The floor is added at the end.
pub fn motion_covariance(
    segments: &[(Segment, Iso3)],
    sigma_v_mps: f64,
    sigma_w_radps: f64,
) -> Matrix3<f64> {
    let mut cov = propagate(Matrix3::zeros(), segments, sigma_v_mps, sigma_w_radps);
    cov[(0, 0)] += FLOOR_SIGMA_XY_M.powi(2);
    cov[(1, 1)] += FLOOR_SIGMA_XY_M.powi(2);
    cov[(2, 2)] += FLOOR_SIGMA_YAW_RAD.powi(2);
    cov
}

/// `cov` (x, y, yaw in `odom`) carried through `segments` by the motion model (see
/// [`motion_covariance`]), without the floor.
pub fn propagate(
    mut cov: Matrix3<f64>,
    segments: &[(Segment, Iso3)],
    sigma_v_mps: f64,
    sigma_w_radps: f64,
) -> Matrix3<f64> {
    for (seg, pose) in segments {
        let t = seg.duration_s();
        if seg.v_mps != 0.0 {
            let d = seg.v_mps * t;
            let (s, c) = yaw_of(pose).sin_cos();
            let f = Matrix3::new(1.0, 0.0, -d * s, 0.0, 1.0, d * c, 0.0, 0.0, 1.0);
            let sd2 = (sigma_v_mps * t).powi(2);
            let q = Matrix3::new(c * c, c * s, 0.0, c * s, s * s, 0.0, 0.0, 0.0, 0.0) * sd2;
            cov = f * cov * f.transpose() + q;
        }
        if seg.w_radps != 0.0 {
            cov[(2, 2)] += (sigma_w_radps * t).powi(2);
        }
    }
    cov
}

/// Clusters of detection tiles (8-connected), each as its evidence-weighted centroid in
/// pixels, in row-major order of their first tile. Linking across gaps would join a chair's
/// legs to its seat, but it also merged two chairs standing one behind the other in the
/// two-chairs tour, whose merged centroid then pulled the pose 0.1 rad off.
pub fn detection_clusters(ev: &TileEvidence) -> Vec<[f64; 2]> {
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
        while let Some(t) = stack.pop() {
            let (r, c) = (t / cols, t % cols);
            let d = f64::from(ev.delta[t]);
            w += d;
            su += d * (c as f64 + 0.5) * tile;
            sv += d * (r as f64 + 0.5) * tile;
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
        out.push([su / w, sv / w]);
    }
    out
}

/// A ray in `odom` through a detection cluster's centroid, from the frame it was seen in.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sighting {
    pub frame: usize,
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
/// with its distance.
fn closest_per_frame<'a>(
    c: &Vector3<f64>,
    sightings: &'a [Sighting],
    gate_m: f64,
) -> Vec<(f64, &'a Sighting)> {
    let mut chosen: Vec<(f64, &Sighting)> = Vec::new();
    for s in sightings {
        let d = ray_distance(s, c);
        if d > gate_m {
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

/// A landmark: a point in `odom` and the covariance of its position (m^2).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Landmark {
    pub position_m: Vector3<f64>,
    pub covariance_m2: Matrix3<f64>,
}

/// Places each object (given by its centroid in the belief) as a landmark: the weighted
/// least-squares point of the rays that saw it, at most one per frame (the one passing
/// closest, within [`GATE_M`]). A ray's sideways error is weighted by the horizontal pixel
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
        let mut chosen = closest_per_frame(&c, sightings, GATE_M);
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

/// Unit vectors across a ray: level (sideways) and the one completing them (up-down).
fn across_axes(d: &Vector3<f64>) -> Option<(Vector3<f64>, Vector3<f64>)> {
    let h = d.cross(&Vector3::z()).try_normalize(1e-9)?;
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

fn project(camera: &Camera, camera_from_odom: &Iso3, p: &Vector3<f64>) -> Option<[f64; 2]> {
    camera
        .project(&(camera_from_odom * Point3::from(*p)))
        .map(|(u, v)| [u, v])
}

/// Information (inverse covariance, 1/pixels^2) of where `lm` appears from `camera_from_odom`: its position's
/// covariance pushed through the projection, plus the detection's own spread.
fn image_covariance(
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
fn associate(
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

/// Finds the correction of `predicted` (odom_from_base) that best explains the frame's
/// detection `clusters` given the `landmarks` and the motion model's covariance `cov`
/// (x, y, yaw), and decides whether to apply it: only when it gains [`MIN_GAIN`], no
/// separated candidate comes within [`AMBIGUITY_MARGIN`] of it, and the pose it gives passes
/// the total `gate` (when given).
#[allow(clippy::too_many_arguments)]
pub fn refine(
    landmarks: &[Landmark],
    clusters: &[[f64; 2]],
    camera: &Camera,
    base_from_camera: &Iso3,
    predicted: &Iso3,
    cov: &Matrix3<f64>,
    floor: Option<(&FloorMap, &FloorPatch)>,
    gate: Option<&TotalGate>,
) -> Correction {
    let Some(chol) = nalgebra::Cholesky::new(*cov) else {
        return Correction::ZERO;
    };
    let pairs = associate(landmarks, clusters, camera, &(predicted * base_from_camera));
    let floor = floor.filter(|(map, patch)| map.frames() > 0 && !patch.is_empty());
    if pairs.is_empty() && floor.is_none() {
        return Correction::ZERO;
    }
    let l = chol.l();
    // Each pair's information matrix in pixels, at the predicted pose (the window is small
    // against the range, so it holds over the search).
    let camera_from_predicted = (predicted * base_from_camera).inverse();
    let infos: Vec<Matrix2<f64>> =
        pairs
            .iter()
            .map(|&(i, _)| {
                image_covariance(&landmarks[i], camera, &camera_from_predicted).unwrap_or(
                    Matrix2::new(SIGMA_U_PX.powi(-2), 0.0, 0.0, SIGMA_V_PX.powi(-2)),
                )
            })
            .collect();
    // z: whitened coordinates; the correction is L z and its log prior -|z|^2 / 2.
    let score = |z: &Vector3<f64>, stride: usize, floor: Option<(&FloorMap, &FloorPatch)>| {
        let d = l * z;
        let odom_from_base = apply(predicted, d.x, d.y, d.z);
        let camera_from_odom = (odom_from_base * base_from_camera).inverse();
        let mut log_lik = floor.map_or(0.0, |(map, patch)| {
            map.score_every(patch, &odom_from_base, stride)
        });
        for (&(i, j), info) in pairs.iter().zip(&infos) {
            let r2 = match project(camera, &camera_from_odom, &landmarks[i].position_m) {
                Some(p) => {
                    let e = Vector2::new(p[0] - clusters[j][0], p[1] - clusters[j][1]);
                    (e.transpose() * info * e)[(0, 0)]
                }
                // Behind the camera: as bad as the gate, so the score stays finite.
                None => (GATE_PX / SIGMA_U_PX).powi(2),
            };
            log_lik -= 0.5 * r2;
        }
        log_lik - 0.5 * z.norm_squared()
    };
    let candidate_of = |z: &Vector3<f64>| {
        let d = l * z;
        apply(predicted, d.x, d.y, d.z)
    };
    let mut found = search(|z, stride| score(z, stride, floor));
    // The floor must explain itself: where most of what the camera takes for floor does not
    // fit the map even at the best pose (furniture, walls, a counter in front of the robot),
    // its best pose is not to be trusted; the frame is aligned to the objects alone.
    let floor_fit = floor.and_then(|(map, patch)| {
        Some([
            map.fit(patch, &candidate_of(&found.best_z))?,
            map.fit(patch, predicted)?,
        ])
    });
    let floor_used = floor.is_some() && floor_fit.is_some_and(|f| f[0] >= MIN_FLOOR_FIT);
    if floor.is_some() && !floor_used {
        if pairs.is_empty() {
            return Correction {
                floor_fit,
                ..Correction::ZERO
            };
        }
        found = search(|z, stride| score(z, stride, None));
    }
    let d = l * found.best_z;
    let candidate = candidate_of(&found.best_z);
    let total_chi2 = gate.map_or(0.0, |g| g.chi2(&candidate));
    let outcome = if found.gain < MIN_GAIN {
        Verdict::Insignificant
    } else if found.runner_up_margin < AMBIGUITY_MARGIN {
        Verdict::Ambiguous
    } else if total_chi2 > GATE_CHI2 * GATE_SIGMA_SCALE * GATE_SIGMA_SCALE {
        Verdict::Gated
    } else {
        Verdict::Accepted
    };
    let applied = outcome == Verdict::Accepted;
    let at = if applied { &candidate } else { predicted };
    let used = floor.filter(|_| floor_used);
    Correction {
        dx_m: d.x,
        dy_m: d.y,
        dyaw_rad: d.z,
        gain: found.gain,
        anchors: pairs.len(),
        floor_cells: used.map_or(0, |(map, patch)| map.overlap(patch, at)),
        applied,
        outcome,
        total_chi2,
        runner_up_margin: found.runner_up_margin,
        runner_up_sigmas: found.runner_up_distance,
        floor_fit,
    }
}

/// The outcome of one search: the best candidate in whitened coordinates, its gain over no
/// correction, and how far the best separated local maximum of the coarse round lies below
/// the best.
struct Found {
    best_z: Vector3<f64>,
    gain: f64,
    runner_up_margin: f64,
    /// Whitened distance from the best to that runner-up.
    runner_up_distance: f64,
}

/// The coarse grid in whitened coordinates (+-[`SEARCH_SIGMAS`] in [`COARSE_STEPS`] per
/// axis), then [`FINE_ROUNDS`] finer 3x3x3 grids about the best; `score(z, stride)` scores a
/// candidate with the floor's every `stride`-th cell.
fn search(score: impl Fn(&Vector3<f64>, usize) -> f64 + Sync) -> Found {
    let base_score = score(&Vector3::zeros(), 1);
    let mut best = (base_score, Vector3::zeros());
    let mut runner_up_margin = f64::INFINITY;
    let mut runner_up_distance = 0.0;
    let half = COARSE_STEPS / 2;
    let mut step = SEARCH_SIGMAS / f64::from(half);
    let mut span = half;
    for round in 0..=FINE_ROUNDS {
        let stride = if round == 0 { COARSE_FLOOR_STRIDE } else { 1 };
        let centre = best.1;
        let offsets: Vec<Vector3<f64>> = (-span..=span)
            .flat_map(|a| {
                (-span..=span).flat_map(move |b| {
                    (-span..=span)
                        .map(move |c| Vector3::new(f64::from(a), f64::from(b), f64::from(c)))
                })
            })
            .collect();
        // Scored in parallel (each score is a pure function of its candidate), then chosen
        // in candidate order: strictly better only, so the first of equal candidates wins
        // and the choice does not depend on the thread count.
        let scored: Vec<(f64, Vector3<f64>)> = offsets
            .par_iter()
            .map(|o| {
                let z = centre + o * step;
                (score(&z, stride), z)
            })
            .collect();
        if round == 0 {
            (runner_up_margin, runner_up_distance) =
                separated_margin(&scored, COARSE_STEPS as usize);
        }
        // A strided round compares estimates with each other only; its winner is then
        // scored in full, so that the fine rounds and the gain compare full scores.
        let mut top = if stride > 1 {
            (f64::NEG_INFINITY, centre)
        } else {
            best
        };
        for (s, z) in scored {
            if s > top.0 {
                top = (s, z);
            }
        }
        best = if stride > 1 {
            (score(&top.1, 1), top.1)
        } else {
            top
        };
        span = 1;
        step /= 2.0;
    }
    Found {
        best_z: best.1,
        gain: best.0 - base_score,
        runner_up_margin,
        runner_up_distance,
    }
}

/// A secondary peak of the coarse search counts as a separate mode only when the score dips
/// by at least this many nats between it and any higher candidate (its prominence): ridges
/// (an object alone leaves sliding around it to the prior) and slopes to the grid's edge have
/// none, the periods of a repeating floor pattern do.
pub const MIN_PROMINENCE: f64 = 1.0;

/// ... and lies at least this far from the best, in standard deviations of the motion model
/// (four steps of the coarse grid): nearer peaks are bumps of one mode (measured on the
/// shipped, held-out-style and foreign tours: every such runner-up lay 1.7-2.8 sigmas from
/// the best, and the best was the better pose in all but 4 of 38).
pub const MIN_SEPARATION: f64 = 3.0;

/// How far below the best of a cubic grid of `side`^3 scored candidates (in index order) the
/// best other peak with [`MIN_PROMINENCE`] lies; infinite when there is none. Peaks and their
/// prominences come from merging candidates in descending score order (ties by index) with
/// their 26 neighbours: when two groups meet, the lower group's peak is as prominent as its
/// height above the meeting candidate.
fn separated_margin(scored: &[(f64, Vector3<f64>)], side: usize) -> (f64, f64) {
    let n = side * side * side;
    if scored.len() != n || n == 0 {
        return (f64::INFINITY, 0.0);
    }
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| scored[b].0.total_cmp(&scored[a].0).then(a.cmp(&b)));
    // Union-find over placed candidates; each root remembers its group's peak.
    let mut parent: Vec<usize> = (0..n).collect();
    let mut placed = vec![false; n];
    let peak: Vec<usize> = (0..n).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    let top = scored[order[0]].0;
    let mut runner_up = f64::NEG_INFINITY;
    let mut runner_at = order[0];
    for &i in &order {
        placed[i] = true;
        let (a, b, c) = (i / (side * side), (i / side) % side, i % side);
        for da in -1i64..=1 {
            for db in -1i64..=1 {
                for dc in -1i64..=1 {
                    let (x, y, z) = (a as i64 + da, b as i64 + db, c as i64 + dc);
                    let side_i = side as i64;
                    if (da, db, dc) == (0, 0, 0)
                        || !(0..side_i).contains(&x)
                        || !(0..side_i).contains(&y)
                        || !(0..side_i).contains(&z)
                    {
                        continue;
                    }
                    let j = (x as usize * side + y as usize) * side + z as usize;
                    if !placed[j] {
                        continue;
                    }
                    let (ri, rj) = (root(&mut parent, i), root(&mut parent, j));
                    if ri == rj {
                        continue;
                    }
                    // The lower peak's group joins the higher; the lower peak's prominence is
                    // its height above this candidate, the lowest on the way between them.
                    let (pi, pj) = (peak[ri], peak[rj]);
                    let higher_first = |p: usize, q: usize| {
                        scored[p].0 > scored[q].0 || (scored[p].0 == scored[q].0 && p < q)
                    };
                    let (hi_root, lo_root) = if higher_first(pi, pj) {
                        (ri, rj)
                    } else {
                        (rj, ri)
                    };
                    let lo_peak = peak[lo_root];
                    let far = (scored[lo_peak].1 - scored[order[0]].1).norm() >= MIN_SEPARATION;
                    if far
                        && scored[lo_peak].0 - scored[i].0 >= MIN_PROMINENCE
                        && scored[lo_peak].0 > runner_up
                    {
                        runner_up = scored[lo_peak].0;
                        runner_at = lo_peak;
                    }
                    parent[lo_root] = hi_root;
                }
            }
        }
    }
    (
        top - runner_up,
        (scored[runner_at].1 - scored[order[0]].1).norm(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::types::geometry::{camera_mount, iso_from_xy_yaw};

    fn seg(start_s: f64, end_s: f64, v: f64, w: f64) -> Segment {
        Segment {
            start_ns: (start_s * 1e9) as i64,
            end_ns: (end_s * 1e9) as i64,
            v_mps: v,
            w_radps: w,
        }
    }

    /// A correction that was not applied leaves the pose bit for bit (a default replay that
    /// corrects nothing must fuse exactly at the /odom poses); an applied one moves it.
    #[test]
    fn unapplied_correction_is_the_identity_bit_for_bit() {
        let pose = iso_from_xy_yaw(-0.0, 1.3, -2.9) * camera_mount([0.2, 0.0, 1.2], 0.26);
        let same = Correction::ZERO.apply(&pose);
        assert_eq!(same, pose);
        let (t, u) = (pose.translation.vector, same.translation.vector);
        assert!((0..3).all(|i| t[i].to_bits() == u[i].to_bits()));
        let moved = Correction {
            dx_m: 0.1,
            dyaw_rad: 0.02,
            applied: true,
            ..Correction::ZERO
        }
        .apply(&pose);
        assert!((moved.translation.x - pose.translation.x - 0.1).abs() < 1e-12);
        assert!((yaw_of(&moved) - yaw_of(&pose) - 0.02).abs() < 1e-9);
    }

    /// Rotate 2 s with sigma_w = 0.01 (heading sd 0.02 rad), then drive 1 m along +x in 4 s
    /// with sigma_v = 0.02 (along-track sd 0.08 m): the sideways variance is d^2 * var(yaw)
    /// = 0.0004, the y-yaw covariance d * var(yaw) = 0.0004, plus the floors.
    #[test]
    fn covariance_of_a_turn_then_a_drive() {
        let segs = [
            (seg(0.0, 2.0, 0.0, 0.5), iso_from_xy_yaw(0.0, 0.0, -1.0)),
            (seg(2.0, 6.0, 0.25, 0.0), iso_from_xy_yaw(0.0, 0.0, 0.0)),
        ];
        let cov = motion_covariance(&segs, 0.02, 0.01);
        let fxy = FLOOR_SIGMA_XY_M.powi(2);
        let fyaw = FLOOR_SIGMA_YAW_RAD.powi(2);
        let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
        assert!(close(cov[(0, 0)], 0.08f64.powi(2) + fxy), "{cov}");
        assert!(close(cov[(1, 1)], 0.0004 + fxy), "{cov}");
        assert!(close(cov[(2, 2)], 0.0004 + fyaw), "{cov}");
        assert!(
            close(cov[(1, 2)], 0.0004) && close(cov[(2, 1)], 0.0004),
            "{cov}"
        );
        assert!(close(cov[(0, 1)], 0.0) && close(cov[(0, 2)], 0.0), "{cov}");
        let still = motion_covariance(&[], 0.02, 0.01);
        assert_eq!(still, Matrix3::from_diagonal(&Vector3::new(fxy, fxy, fyaw)));
    }

    /// Two blobs: a 2x1 pair with evidence 4 and 6 (centroid pulled toward the 6), and a
    /// single tile; a tile below the threshold joins neither.
    #[test]
    fn clusters_are_evidence_weighted_centroids() {
        let (rows, cols) = (4, 6);
        let mut delta = vec![-2.0f32; rows * cols];
        delta[cols + 1] = 4.0; // row 1, col 1: centre (12, 12)
        delta[cols + 2] = 6.0; // row 1, col 2: centre (20, 12)
        delta[3 * cols + 5] = 3.5; // row 3, col 5: centre (44, 28)
        delta[cols + 3] = 2.9; // below DETECTION_DELTA, though adjacent
        let ev = TileEvidence {
            rows,
            cols,
            tile_px: 8,
            delta,
        };
        let c = detection_clusters(&ev);
        assert_eq!(c.len(), 2, "{c:?}");
        assert!((c[0][0] - (4.0 * 12.0 + 6.0 * 20.0) / 10.0).abs() < 1e-12);
        assert!((c[0][1] - 12.0).abs() < 1e-12);
        assert_eq!(c[1], [44.0, 28.0]);
    }

    /// Three cameras around a point, each seeing it exactly: the landmark is the point. A
    /// fourth ray, passing within the gate but 0.3 m off (24 px), is dropped. (A smaller
    /// outlier is averaged in: least squares spreads it over all rays until none stands out.)
    #[test]
    fn landmark_is_where_the_rays_meet_and_outliers_are_dropped() {
        let cam = Camera::with_hfov(256, 240, 1.05);
        let mount = camera_mount([0.2, 0.0, 1.2], 0.26);
        let target = Vector3::new(0.1, -0.2, 0.45);
        let mut seen = Vec::new();
        for (k, a) in [0.0f64, 0.8, 1.6, 2.4].iter().enumerate() {
            let (x, y) = (2.8 * a.cos(), 2.8 * a.sin());
            let base = iso_from_xy_yaw(x, y, (-y).atan2(-x));
            let cam_pose = base * mount;
            // The fourth frame's detection is off by 0.3 m sideways at the target.
            let aim = if k == 3 {
                target + (cam_pose.rotation * Vector3::x()) * 0.3
            } else {
                target
            };
            let (u, v) = cam
                .project(&(cam_pose.inverse() * Point3::from(aim)))
                .unwrap();
            seen.extend(sightings(k, &[[u, v]], &cam, &cam_pose));
        }
        let lms = landmarks(&[[0.05, -0.15, 0.4]], &seen, cam.fx);
        assert_eq!(lms.len(), 1);
        let err = (lms[0].position_m - target).norm();
        assert!(err < 1e-6, "landmark {} off by {err}", lms[0].position_m);
        // Rays from a single frame do not place a landmark.
        assert!(landmarks(&[[0.05, -0.15, 0.4]], &seen[..1], cam.fx).is_empty());
    }

    /// A landmark, the camera that saw it from `truth`, and odometry that believes the robot
    /// is elsewhere: the refinement moves the prediction back.
    fn localise_case(predicted: Iso3, cov: Matrix3<f64>) -> (Correction, Iso3) {
        let cam = Camera::with_hfov(256, 240, 1.05);
        let mount = camera_mount([0.2, 0.0, 1.2], 0.26);
        let target = Vector3::new(0.0, 0.0, 0.45);
        let lm = Landmark {
            position_m: target,
            covariance_m2: Matrix3::zeros(),
        };
        let truth = iso_from_xy_yaw(-2.8, 0.0, 0.0);
        let (u, v) = cam
            .project(&((truth * mount).inverse() * Point3::from(target)))
            .unwrap();
        let c = refine(&[lm], &[[u, v]], &cam, &mount, &predicted, &cov, None, None);
        (c, truth)
    }

    /// Odometry believes the robot is turned 0.08 rad (4.6 degrees) to the left; with a
    /// motion model loose in heading and tight in position, the refinement turns it back.
    #[test]
    fn recovers_a_known_heading_error() {
        let cov = Matrix3::from_diagonal(&Vector3::new(0.0001, 0.0001, 0.0025));
        let (c, truth) = localise_case(iso_from_xy_yaw(-2.8, 0.0, 0.08), cov);
        assert!((c.dyaw_rad + 0.08).abs() < 0.005, "{c:?}");
        assert!(c.gain > MIN_GAIN && c.anchors == 1 && c.applied);
        let fixed = c.apply(&iso_from_xy_yaw(-2.8, 0.0, 0.08));
        assert!(yaw_of(&(truth.inverse() * fixed)).abs() < 0.005);
        // Exact odometry: nothing to gain, nothing applied.
        let (c0, _) = localise_case(truth, cov);
        assert!(!c0.applied && c0.gain < MIN_GAIN, "{c0:?}");
        assert_eq!(c0.outcome, Verdict::Insignificant);
        assert_eq!(c0.apply(&truth), truth);
    }

    /// The robot is 0.2 m to the side of where odometry says, heading known well: the
    /// motion model makes the search move the robot rather than turn it.
    #[test]
    fn a_certain_heading_turns_a_bearing_error_into_a_position_correction() {
        let cov = Matrix3::from_diagonal(&Vector3::new(0.0225, 0.0225, 0.0001));
        let (c, _) = localise_case(iso_from_xy_yaw(-2.8, 0.2, 0.0), cov);
        assert!((c.dy_m + 0.2).abs() < 0.03, "{c:?}");
        assert!(c.dyaw_rad.abs() < 0.01, "{c:?}");
    }

    #[test]
    fn nothing_to_align_to_means_no_correction() {
        let cam = Camera::with_hfov(64, 48, 1.0);
        let cov = motion_covariance(&[], 0.1, 0.1);
        let c = refine(
            &[],
            &[[30.0, 20.0]],
            &cam,
            &Iso3::identity(),
            &Iso3::identity(),
            &cov,
            None,
            None,
        );
        assert_eq!(c, Correction::ZERO);
        let lm = Landmark {
            position_m: Vector3::new(0.0, 0.0, 2.0),
            covariance_m2: Matrix3::zeros(),
        };
        // A landmark but no detection near it.
        let c = refine(
            &[lm],
            &[],
            &cam,
            &Iso3::identity(),
            &Iso3::identity(),
            &cov,
            None,
            None,
        );
        assert_eq!(c, Correction::ZERO);
    }

    /// The gate's chi-square by hand: covariance diag(0.01, 0.04, 0.0025) (plus the floors),
    /// /odom at the origin, a pose 0.1 m off in x and 0.05 rad in heading:
    /// 0.1^2 / (0.01 + 1e-4) + 0.05^2 / (0.0025 + 2.5e-5).
    #[test]
    fn total_gate_is_the_chi_square_against_odometry() {
        let gate = TotalGate {
            odometry: Iso3::identity(),
            covariance: Matrix3::from_diagonal(&Vector3::new(0.01, 0.04, 0.0025)),
        };
        let pose = iso_from_xy_yaw(0.1, 0.0, 0.05);
        let want = 0.01 / (0.01 + 1e-4) + 0.0025 / (0.0025 + 2.5e-5);
        assert!(
            (gate.chi2(&pose) - want).abs() < 1e-9,
            "{}",
            gate.chi2(&pose)
        );
        assert!(gate.chi2(&Iso3::identity()).abs() < 1e-12);
        // Headings wrap: a turn of 2 pi is no correction.
        let around = iso_from_xy_yaw(0.0, 0.0, 2.0 * std::f64::consts::PI);
        assert!(gate.chi2(&around) < 1e-9);
    }

    fn cube(side: usize, f: impl Fn(usize, usize, usize) -> f64) -> Vec<(f64, Vector3<f64>)> {
        let mut out = Vec::new();
        for a in 0..side {
            for b in 0..side {
                for c in 0..side {
                    let z = Vector3::new(a as f64, b as f64, c as f64) * 0.75;
                    out.push((f(a, b, c), z));
                }
            }
        }
        out
    }

    /// Two bumps 6 steps apart (4.5 sigmas), the second 1.5 below the first with a dip of 10
    /// between them: separated, margin 1.5. One bump on a slope to the edge: no runner-up.
    /// A ridge of equal-ish values beside the best: too near, and without prominence.
    #[test]
    fn separated_maxima_are_the_prominent_far_peaks() {
        let two = cube(9, |a, b, c| {
            let d1 =
                ((a as f64 - 1.0).powi(2) + (b as f64 - 4.0).powi(2) + (c as f64 - 4.0).powi(2))
                    .sqrt();
            let d2 =
                ((a as f64 - 7.0).powi(2) + (b as f64 - 4.0).powi(2) + (c as f64 - 4.0).powi(2))
                    .sqrt();
            (-10.0 * d1.min(3.0) / 3.0).max(-1.5 - 10.0 * d2.min(3.0) / 3.0)
        });
        let (margin, sigmas) = separated_margin(&two, 9);
        assert!((margin - 1.5).abs() < 1e-9, "{margin}");
        assert!((sigmas - 6.0 * 0.75).abs() < 1e-9, "{sigmas}");
        let slope = cube(9, |a, b, c| -((a + b + c) as f64));
        assert_eq!(separated_margin(&slope, 9).0, f64::INFINITY);
        // A ridge along c at (4, 4): bumps of 0.1 between neighbours, none prominent.
        let ridge = cube(9, |a, b, c| {
            -((a as f64 - 4.0).powi(2) + (b as f64 - 4.0).powi(2)) - 0.1 * (c % 2) as f64
        });
        assert_eq!(separated_margin(&ridge, 9).0, f64::INFINITY);
    }

    /// Rays that meet exactly score 0; with one frame's ray 0.3 m off the point (24 px at
    /// 2.8 m) that frame scores the cap, and a frame without a ray near the object too.
    #[test]
    fn consistency_is_the_mean_capped_ray_chi_square() {
        let cam = Camera::with_hfov(256, 240, 1.05);
        let mount = camera_mount([0.2, 0.0, 1.2], 0.26);
        let target = Vector3::new(0.1, -0.2, 0.45);
        let rays = |off: f64| {
            let mut seen = Vec::new();
            for (k, a) in [0.0f64, 0.8, 1.6, 2.4].iter().enumerate() {
                let (x, y) = (2.8 * a.cos(), 2.8 * a.sin());
                let cam_pose = iso_from_xy_yaw(x, y, (-y).atan2(-x)) * mount;
                let aim = if k == 3 {
                    target + (cam_pose.rotation * Vector3::x()) * off
                } else {
                    target
                };
                let (u, v) = cam
                    .project(&(cam_pose.inverse() * Point3::from(aim)))
                    .unwrap();
                seen.extend(sightings(k, &[[u, v]], &cam, &cam_pose));
            }
            seen
        };
        let seed = [[0.05, -0.15, 0.4]];
        let exact = Consistency::of(&seed, &rays(0.0), cam.fx, GATE_M);
        assert_eq!((exact.objects, exact.rays), (1, 4));
        assert!(exact.mean_chi2 < 1e-9, "{exact:?}");
        let off = Consistency::of(&seed, &rays(0.3), cam.fx, GATE_M);
        assert!(off.worse_than(&exact) && !exact.worse_than(&off), "{off:?}");
        // Gate smaller than the miss: the fourth frame has no ray for the object; it scores
        // the cap, the other three (which then meet exactly) nothing.
        let gated = Consistency::of(&seed, &rays(0.3), cam.fx, 0.2);
        assert!(
            (gated.mean_chi2 - MAX_RAY_CHI2 / 4.0).abs() < 1e-6,
            "{gated:?}"
        );
    }

    #[test]
    fn verdicts_serialise_in_kebab_case_and_say_what_was_measured() {
        let json = serde_json::to_string(&Verdict::RolledBack).unwrap();
        assert_eq!(json, "\"rolled-back\"");
        assert_eq!(Verdict::NoEvidence.label(), "no-evidence");
        assert!(Verdict::Accepted.measured() && Verdict::Insignificant.measured());
        assert!(!Verdict::Gated.measured() && !Verdict::RolledBack.measured());
        // A report without the field (before verdicts) reads as no evidence.
        let old: Correction = serde_json::from_str(
            r#"{"dx_m":0.0,"dy_m":0.0,"dyaw_rad":0.0,"gain":0.0,"anchors":0}"#,
        )
        .unwrap();
        assert_eq!(old.outcome, Verdict::NoEvidence);
        assert_eq!(old.runner_up_margin, f64::INFINITY);
    }
}
