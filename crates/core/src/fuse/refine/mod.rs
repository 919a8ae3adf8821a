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
//! order with ties going to the first: deterministic, candidates scored in parallel and
//! chosen in order, so the thread count cannot matter. Candidates certain to lose stop
//! scoring early (`search`), which changes no choice.
//!
//! A correction is applied only when it raises the score by [`MIN_GAIN`]: smaller ones fit
//! the noise of the detections, and applied they compound into drift.
//!
//! This is a filter: each landmark is fixed from the views before the frame. [`smooth`] solves
//! every pose and landmark again over the whole replay afterwards (the replay decides whether
//! its poses are kept).
//!
//! Invariants: pure functions of their inputs, no I/O; without a landmark seen in the frame
//! or floor seen before, or without a significant gain, the correction is zero.

mod landmarks;
mod search;
pub mod smooth;

pub use landmarks::{
    Consistency, DETECTION_DELTA, Detection, GATE_M, GATE_PX, Landmark, MAX_RAY_CHI2,
    MIN_RAY_SPREAD, SIGMA_U_PX, SIGMA_V_PX, Sighting, detection_clusters, detections, landmarks,
    sightings,
};
pub use search::{MIN_PROMINENCE, MIN_SEPARATION, SCORED_IN_FULL_NATS};

use landmarks::{associate, image_covariance, project};
#[cfg(test)]
use search::separated_margin;
use search::{Found, search};

use nalgebra::{Matrix2, Matrix3, Translation3, UnitQuaternion, Vector2, Vector3};

use crate::fuse::floor::{FloorMap, FloorPatch};
use crate::fuse::motion::Segment;
use crate::types::geometry::{Camera, Iso3, yaw_of};

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

/// Of the frame's floor cells that land on floor the map has seen at the predicted pose, at
/// least this fraction must still land on it at the best pose for the floor term to be used.
/// Cells off the map score as an average fit, so where the frame's floor fits the map worse
/// than average (new light, a rug's edge), a pose that moves the patch off the map scores
/// better than any pose on it: with wide sigmas (`--sigma-v 0.05 --sigma-w 0.03`) the search
/// reached such poses and accepted jumps of 1.5 m on one floor cell, 4.9 m in all on the
/// drift tour, and the end check, seeing less floor to disagree with, approved them.
pub const MIN_FLOOR_OVERLAP_KEPT: f64 = 0.5;

/// A correction is ambiguous when a candidate separated from the best (not its neighbour
/// on the coarse grid) scores within this many nats of it.
pub const AMBIGUITY_MARGIN: f64 = 2.0;

/// A landmark's pairing with a detection may be wrong (a ghost where two frames' false
/// detections crossed, paired with another false detection): its chi-square counts up to
/// this (the 99.7 % point of 2 degrees of freedom), so one wrong pairing cannot outweigh
/// the others and the motion model. Found on `chair-bare-floor` seed 4 (docs/fuser.md): a
/// ghost landmark from two views pulled frame 2 by 5 degrees with a gain of 48 nats.
pub const ANCHOR_CHI2_CAP: f64 = MAX_RAY_CHI2;

/// Smallest standard deviations of the motion model, added to the propagated covariance:
/// they keep it invertible after a frame without motion and let a frame settle within a
/// fraction of a tile of its neighbours.
pub const FLOOR_SIGMA_XY_M: f64 = 0.01;
/// Heading counterpart of [`FLOOR_SIGMA_XY_M`], radians.
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

/// How far below `at_least` a candidate's floor sum must be certain to fall before it stops:
/// far more than the rounding of adding the terms in another order, so a stopped candidate
/// is below `at_least` in exact arithmetic and in the search's.
const ROUNDING_NATS: f64 = 1e-6;

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
    /// The same correction along `odom` y, metres (applied only when `applied`).
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
    /// small means ambiguous. Infinite when there is no other maximum within
    /// [`search::SCORED_IN_FULL_NATS`] of the best (candidates further below are not scored
    /// in full).
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
    /// No correction, not applied: [`Verdict::NoEvidence`], no runner-up (infinite margin).
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
    /// The robot pose /odom gives for the frame (odom_from_base).
    pub odometry: Iso3,
    /// Covariance of /odom's (x, y, yaw) error in `odom` since the first frame (m^2, rad^2),
    /// without the floor sigmas ([`TotalGate::chi2`] adds them).
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

/// What one frame's localisation needs.
#[derive(Clone, Copy)]
pub struct Localisation<'a> {
    /// The objects seen before, placed where their rays met.
    pub landmarks: &'a [Landmark],
    /// The frame's detection clusters, pixels.
    pub clusters: &'a [[f64; 2]],
    /// The camera and its mount on the robot.
    pub camera: &'a Camera,
    /// The mount: pose of the camera optical frame in `base_link` (base_from_camera).
    pub base_from_camera: &'a Iso3,
    /// The predicted robot pose (odom_from_base) and the motion model's covariance about it
    /// (x, y, yaw).
    pub predicted: &'a Iso3,
    /// The motion model's covariance about `predicted` (x, y, yaw in `odom`; m^2, rad^2).
    pub cov: &'a Matrix3<f64>,
    /// The floor map and the frame's floor patch, when the floor term is used.
    pub floor: Option<(&'a FloorMap, &'a FloorPatch)>,
    /// The total correction's gate, when the frame has odometry to be held to.
    pub gate: Option<&'a TotalGate>,
}

/// Each landmark pairing's term of a candidate's score, nats (at least zero; the score
/// subtracts it): half its capped chi-square in the image, at the candidate camera pose.
fn anchor_terms(
    q: &Localisation<'_>,
    pairs: &[(usize, usize)],
    infos: &[Matrix2<f64>],
    camera_from_odom: &Iso3,
) -> Vec<f64> {
    pairs
        .iter()
        .zip(infos)
        .map(|(&(i, j), info)| {
            let r2 = match project(q.camera, camera_from_odom, &q.landmarks[i].position_m) {
                Some(p) => {
                    let e = Vector2::new(p[0] - q.clusters[j][0], p[1] - q.clusters[j][1]);
                    (e.transpose() * info * e)[(0, 0)]
                }
                // Behind the camera: as bad as the gate, so the score stays finite.
                None => (GATE_PX / SIGMA_U_PX).powi(2),
            };
            0.5 * r2.min(ANCHOR_CHI2_CAP)
        })
        .collect()
}

/// Finds the correction of `predicted` (odom_from_base) that best explains the frame's
/// detection `clusters` given the `landmarks` and the motion model's covariance `cov`
/// (x, y, yaw), and decides whether to apply it: only when it gains [`MIN_GAIN`], no
/// separated candidate comes within [`AMBIGUITY_MARGIN`] of it, and the pose it gives passes
/// the total `gate` (when given).
pub fn refine(q: &Localisation<'_>) -> Correction {
    let Localisation {
        landmarks,
        clusters,
        camera,
        base_from_camera,
        predicted,
        cov,
        floor,
        gate,
    } = *q;
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
    let infos: Vec<Matrix2<f64>> = pairs
        .iter()
        .map(|&(i, _)| pair_information(&landmarks[i], camera, &camera_from_predicted))
        .collect();
    // z: whitened coordinates; the correction is L z and its log prior -|z|^2 / 2. Every
    // term is at most zero, so the floor's share of `at_least` bounds when its sum may stop
    // (search: exact at or above `at_least`).
    let score = |z: &Vector3<f64>,
                 stride: usize,
                 floor: Option<(&FloorMap, &FloorPatch)>,
                 at_least: f64| {
        let d = l * z;
        let odom_from_base = apply(predicted, d.x, d.y, d.z);
        let camera_from_odom = (odom_from_base * base_from_camera).inverse();
        let anchors = anchor_terms(q, &pairs, &infos, &camera_from_odom);
        let prior = 0.5 * z.norm_squared();
        let floor_at_least = at_least + prior + anchors.iter().sum::<f64>() - ROUNDING_NATS;
        let mut log_lik = floor.map_or(0.0, |(map, patch)| {
            map.score_every_above(patch, &odom_from_base, stride, floor_at_least)
        });
        for a in &anchors {
            log_lik -= a;
        }
        log_lik - prior
    };
    let candidate_of = |z: &Vector3<f64>| {
        let d = l * z;
        apply(predicted, d.x, d.y, d.z)
    };
    let mut found = search(|z, stride, at_least| score(z, stride, floor, at_least));
    // The floor must explain itself: where most of what the camera takes for floor does not
    // fit the map even at the best pose (furniture, walls, a counter in front of the robot),
    // its best pose is not to be trusted; the frame is aligned to the objects alone.
    let floor_fit = floor.and_then(|(map, patch)| {
        Some([
            map.fit(patch, &candidate_of(&found.best_z))?,
            map.fit(patch, predicted)?,
        ])
    });
    let overlap_kept = floor.is_some_and(|(map, patch)| {
        let at_predicted = map.overlap(patch, predicted) as f64;
        map.overlap(patch, &candidate_of(&found.best_z)) as f64
            >= MIN_FLOOR_OVERLAP_KEPT * at_predicted
    });
    let floor_used = overlap_kept && floor_fit.is_some_and(|f| f[0] >= MIN_FLOOR_FIT);
    if floor.is_some() && !floor_used {
        if pairs.is_empty() {
            return Correction {
                floor_fit,
                ..Correction::ZERO
            };
        }
        found = search(|z, stride, at_least| score(z, stride, None, at_least));
    }
    let d = l * found.best_z;
    let candidate = candidate_of(&found.best_z);
    let total_chi2 = gate.map_or(0.0, |g| g.chi2(&candidate));
    let outcome = verdict(&found, total_chi2);
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

/// A landmark pair's information matrix in pixels at the camera pose `camera_from_odom`, or
/// the detection noise's alone where the landmark's spread does not project.
fn pair_information(landmark: &Landmark, camera: &Camera, camera_from_odom: &Iso3) -> Matrix2<f64> {
    image_covariance(landmark, camera, camera_from_odom).unwrap_or(Matrix2::new(
        SIGMA_U_PX.powi(-2),
        0.0,
        0.0,
        SIGMA_V_PX.powi(-2),
    ))
}

/// What the search found decides the frame: too small a gain leaves it where it was
/// predicted, a separated candidate close behind makes it ambiguous, a pose beyond the total
/// gate is refused; otherwise the correction is accepted.
fn verdict(found: &Found, total_chi2: f64) -> Verdict {
    if found.gain < MIN_GAIN {
        Verdict::Insignificant
    } else if found.runner_up_margin < AMBIGUITY_MARGIN {
        Verdict::Ambiguous
    } else if total_chi2 > GATE_CHI2 * GATE_SIGMA_SCALE * GATE_SIGMA_SCALE {
        Verdict::Gated
    } else {
        Verdict::Accepted
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fuse::grid::TileEvidence;
    use crate::types::geometry::{camera_mount, iso_from_xy_yaw};
    use nalgebra::Point3;

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
        let c = refine(&Localisation {
            landmarks: &[lm],
            clusters: &[[u, v]],
            camera: &cam,
            base_from_camera: &mount,
            predicted: &predicted,
            cov: &cov,
            floor: None,
            gate: None,
        });
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
        let at_origin = |landmarks: &[Landmark], clusters: &[[f64; 2]]| {
            refine(&Localisation {
                landmarks,
                clusters,
                camera: &cam,
                base_from_camera: &Iso3::identity(),
                predicted: &Iso3::identity(),
                cov: &cov,
                floor: None,
                gate: None,
            })
        };
        assert_eq!(at_origin(&[], &[[30.0, 20.0]]), Correction::ZERO);
        let lm = Landmark {
            position_m: Vector3::new(0.0, 0.0, 2.0),
            covariance_m2: Matrix3::zeros(),
        };
        // A landmark but no detection near it.
        assert_eq!(at_origin(&[lm], &[]), Correction::ZERO);
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

    /// A score that stops early below `at_least` (as the floor's does) finds what scoring
    /// every candidate in full finds: the same best, gain and ambiguity; a separated peak
    /// more than [`search::SCORED_IN_FULL_NATS`] below the best is reported as none.
    #[test]
    fn a_search_that_stops_hopeless_candidates_early_finds_the_same() {
        // Two peaks in whitened coordinates; terms of at most zero, summed one at a time.
        let terms = |z: &Vector3<f64>, second: f64| -> Vec<f64> {
            let d1 = (z - Vector3::new(0.4, -0.3, 0.2)).norm_squared();
            let d2 = (z - Vector3::new(-2.0, 1.5, 0.0)).norm_squared();
            (0..64)
                .map(|k| -(d1.min(d2 + second)) * (1.0 + f64::from(k % 3)) / 128.0)
                .collect()
        };
        for second in [0.5, 1.2, 40.0] {
            let full = |z: &Vector3<f64>, _stride: usize, _at_least: f64| {
                terms(z, second).iter().sum::<f64>() - 0.5 * z.norm_squared()
            };
            let stopping = |z: &Vector3<f64>, _stride: usize, at_least: f64| {
                let prior = 0.5 * z.norm_squared();
                let mut sum = 0.0;
                for t in terms(z, second) {
                    sum += t;
                    if sum - prior < at_least - 1e-6 {
                        return sum - prior;
                    }
                }
                sum - prior
            };
            let (a, b) = (search(full), search(stopping));
            assert_eq!(a.best_z, b.best_z);
            assert_eq!(a.gain.to_bits(), b.gain.to_bits());
            if a.runner_up_margin < search::SCORED_IN_FULL_NATS {
                assert_eq!(a.runner_up_margin.to_bits(), b.runner_up_margin.to_bits());
                assert_eq!(a.runner_up_distance, b.runner_up_distance);
            } else {
                assert!(b.runner_up_margin > search::SCORED_IN_FULL_NATS);
            }
            if second > 10.0 {
                assert_eq!(b.runner_up_margin, f64::INFINITY, "{}", a.runner_up_margin);
            }
        }
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
