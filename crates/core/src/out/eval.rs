//! Scoring a fuse report against ground truth: object matching, centroid errors, missed and
//! spurious objects, voxel IoU, and the error after each frame.
//!
//! Invariants: pure functions of the report and the true boxes; matching is greedy by
//! distance over all pairs sorted by (distance, truth index, object index), so it is
//! deterministic. No I/O.

use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use crate::fuse::grid::GridSpec;
use crate::fuse::objects::Object;
use crate::io::msgs::GroundTruth;
use crate::io::msgs::iso_from_pose;
use crate::out::report::Report;
use crate::types::geometry::Iso3;
use crate::types::track::PoseTrack;

/// An estimate farther than this from a true box's centre (or than half the box's diagonal,
/// if larger) cannot be that box.
pub const MATCH_GATE_M: f64 = 0.5;

/// One true box of a GroundTruth message.
#[derive(Debug, Clone, PartialEq)]
pub struct TrueBox {
    /// Pose of the box's centre and axes in `odom`.
    pub odom_from_box: Iso3,
    /// Full edge lengths, metres.
    pub size_m: [f64; 3],
}

impl TrueBox {
    fn contains(&self, p: [f64; 3]) -> bool {
        let q = self.odom_from_box.inverse() * Point3::new(p[0], p[1], p[2]);
        (0..3).all(|a| q[a].abs() <= self.size_m[a] / 2.0)
    }

    fn volume_m3(&self) -> f64 {
        self.size_m.iter().product()
    }

    /// Axis-aligned bounds in `odom` of the box's eight corners.
    fn aabb_m(&self) -> ([f64; 3], [f64; 3]) {
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for corner in 0..8u8 {
            let h = |a: usize| {
                let s = if corner & (1 << a) == 0 { -0.5 } else { 0.5 };
                s * self.size_m[a]
            };
            let q = self.odom_from_box * Point3::new(h(0), h(1), h(2));
            for a in 0..3 {
                lo[a] = lo[a].min(q[a]);
                hi[a] = hi[a].max(q[a]);
            }
        }
        (lo, hi)
    }
}

/// One true object instance: the boxes of one name that touch each other (a kettle's body,
/// spout and handle; a chair is one box). Its centre is the volume-weighted centroid of its
/// boxes, which is a single box's centre.
#[derive(Debug, Clone, PartialEq)]
pub struct TrueObject {
    /// Object name of its boxes, e.g. `chair`.
    pub name: String,
    /// Its boxes (at least one), in GroundTruth order.
    pub boxes: Vec<TrueBox>,
}

impl TrueObject {
    /// The true centre in `odom`, m: the volume-weighted mean of its boxes' centres.
    pub fn center_m(&self) -> [f64; 3] {
        let total: f64 = self.boxes.iter().map(TrueBox::volume_m3).sum();
        let mut c = [0.0; 3];
        for b in &self.boxes {
            let w = if total > 0.0 {
                b.volume_m3() / total
            } else {
                1.0 / self.boxes.len() as f64
            };
            let t = b.odom_from_box.translation.vector;
            for a in 0..3 {
                c[a] += w * t[a];
            }
        }
        c
    }

    /// Whether point `p` (`odom`, m) lies inside one of its boxes (faces included).
    pub fn contains(&self, p: [f64; 3]) -> bool {
        self.boxes.iter().any(|b| b.contains(p))
    }

    /// Axis-aligned bounds in `odom` of all its boxes.
    pub fn aabb_m(&self) -> ([f64; 3], [f64; 3]) {
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for b in &self.boxes {
            let (l, h) = b.aabb_m();
            for a in 0..3 {
                lo[a] = lo[a].min(l[a]);
                hi[a] = hi[a].max(h[a]);
            }
        }
        (lo, hi)
    }

    fn gate_m(&self) -> f64 {
        let (lo, hi) = self.aabb_m();
        let d = (0..3).map(|a| (hi[a] - lo[a]).powi(2)).sum::<f64>().sqrt() / 2.0;
        d.max(MATCH_GATE_M)
    }
}

/// Boxes of one name closer than this (between their axis-aligned bounds) are parts of one
/// instance.
pub const PART_TOUCH_M: f64 = 0.01;

/// The true object instances of a GroundTruth message: boxes with invalid poses are skipped;
/// boxes of the same name whose bounds touch (within [`PART_TOUCH_M`]) are one instance.
/// Instances are ordered by their first box.
pub fn true_objects(gt: &GroundTruth) -> Vec<TrueObject> {
    let boxes: Vec<(String, TrueBox)> = gt
        .object
        .iter()
        .zip(&gt.box_center)
        .zip(&gt.box_size)
        .filter_map(|((name, pose), size)| {
            Some((
                name.clone(),
                TrueBox {
                    odom_from_box: iso_from_pose(pose)?,
                    size_m: *size,
                },
            ))
        })
        .collect();
    // Union-find over touching boxes of one name; parents point to lower indices, so each
    // group's root is its first box.
    let mut parent: Vec<usize> = (0..boxes.len()).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    let bounds: Vec<_> = boxes.iter().map(|(_, b)| b.aabb_m()).collect();
    for i in 0..boxes.len() {
        for j in 0..i {
            let touch = (0..3).all(|a| {
                bounds[i].0[a] <= bounds[j].1[a] + PART_TOUCH_M
                    && bounds[j].0[a] <= bounds[i].1[a] + PART_TOUCH_M
            });
            if boxes[i].0 == boxes[j].0 && touch {
                let (ri, rj) = (root(&mut parent, i), root(&mut parent, j));
                let (lo, hi) = (ri.min(rj), ri.max(rj));
                parent[hi] = lo;
            }
        }
    }
    let mut out: Vec<(usize, TrueObject)> = Vec::new();
    for (i, (name, b)) in boxes.into_iter().enumerate() {
        let r = root(&mut parent, i);
        match out.iter_mut().find(|(k, _)| *k == r) {
            Some((_, o)) => o.boxes.push(b),
            None => out.push((
                r,
                TrueObject {
                    name,
                    boxes: vec![b],
                },
            )),
        }
    }
    out.into_iter().map(|(_, o)| o).collect()
}

/// A located object matched to a true object.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Match {
    /// Index of the true object, in [`true_objects`] order.
    pub truth_index: usize,
    /// The true object's name.
    pub name: String,
    /// Index of the located object in the report's `objects` (or a frame's).
    pub object_index: usize,
    /// Distance from `centroid_m` to the true centre, m: the localisation error; at most the match
    /// gate ([`MATCH_GATE_M`] or half the true bounds' diagonal).
    pub error_m: f64,
    /// The object's location (the centre of its extent) in `odom`, m.
    pub centroid_m: [f64; 3],
    /// The true object's centre in `odom`, m.
    pub truth_center_m: [f64; 3],
    /// Distance from the object's mass centroid (the probability-weighted mean of its cells,
    /// `mass_centroid_m`) to the true centre. The true centre is that of the true bounding
    /// box, which for a chair lies 0.11 m from its centre of mass (docs/fuser.md), so this
    /// says how far the mean would have missed. Matching and every target use `error_m`.
    #[serde(default)]
    pub mass_centroid_error_m: f64,
}

impl Match {
    /// `chair: located at (x, y, z) m, true centre (x, y, z) m, error e m`.
    pub fn describe(&self) -> String {
        let [x, y, z] = self.centroid_m;
        let [tx, ty, tz] = self.truth_center_m;
        format!(
            "{}: located at ({x:.3}, {y:.3}, {z:.3}) m, true centre ({tx:.3}, {ty:.3}, {tz:.3}) m, error {:.3} m (mass centroid: {:.3} m)",
            self.name, self.error_m, self.mass_centroid_error_m
        )
    }
}

/// The objects located after one fused frame, scored against the truth.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameEval {
    /// 0-based count of fused frames (the report's `per_frame` index).
    pub index: usize,
    /// Header stamp of the frame, ns since the Unix epoch.
    pub stamp_ns: i64,
    /// Objects located after this frame.
    pub objects: usize,
    /// Of them, those matched to a true object.
    pub matched: usize,
    /// Mean localisation error of the matches, m (None: no match).
    pub mean_error_m: Option<f64>,
    /// Largest localisation error of the matches, m (None: no match).
    pub max_error_m: Option<f64>,
    /// What pose refinement did with the frame (absent when not refining, and for the first
    /// frame, which anchors the frame of reference).
    #[serde(default)]
    pub refinement: Option<crate::fuse::refine::Verdict>,
    /// Whether the applied correction came from the detections alone (no floor): nothing
    /// but the rays it was fitted to supports it.
    #[serde(default)]
    pub detections_only: bool,
}

/// A fuse report scored against ground truth (what `objloc eval --json` prints).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Evaluation {
    /// Path of the evaluated report.
    pub report: String,
    /// Where the report's frame poses came from: "odometry", "refined" or "ground-truth".
    pub poses: String,
    /// The matched objects, in true-object order.
    pub matches: Vec<Match>,
    /// Names of the true objects no located object matched.
    pub missed: Vec<String>,
    /// Locations (`centroid_m`, `odom`, m) of located objects that matched no true object.
    pub spurious: Vec<[f64; 3]>,
    /// IoU in [0, 1] of the objects' cells against the cells whose centres lie in a true box (0
    /// when both are empty).
    pub voxel_iou: f64,
    /// The score after each fused frame, in fusion order.
    pub per_frame: Vec<FrameEval>,
    /// Trajectory error at the fused frames, when the session has true poses.
    pub trajectory: Option<TrajectoryError>,
    /// Why the refined replay was rolled back to /odom, if it was.
    #[serde(default)]
    pub rolled_back: Option<String>,
}

/// Absolute trajectory error (TUM RGB-D style RMSE of positions) at the fused frames, of the
/// /odom poses and of the poses the frames were fused with (the same unless refined). No
/// alignment: odometry and truth share `odom`, where both start at the same pose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrajectoryError {
    /// Fused frames with a true pose: the RMSEs' sample count (at least 1).
    pub frames: usize,
    /// RMSE of the positions the replay was given (/odom; the truth itself with `--poses
    /// ground-truth`, so 0 there) against the true ones, m.
    pub odometry_ate_m: f64,
    /// RMSE of the positions the frames were fused with against the true ones, m.
    pub fused_ate_m: f64,
    /// Largest position error of /odom at a frame.
    pub odometry_max_m: f64,
}

/// The trajectory error of `report`'s frames against the `truth` track (looked up at each
/// frame's stamp like the replay's poses).
pub fn trajectory_error(report: &Report, truth: &PoseTrack) -> Option<TrajectoryError> {
    let pairs: Vec<(f64, f64)> = report
        .per_frame
        .iter()
        .filter_map(|f| {
            let t: [f64; 3] = truth.at(f.stamp_ns)?.translation.vector.into();
            Some((dist(f.odom_position_m, t), dist(f.position_m, t)))
        })
        .collect();
    if pairs.is_empty() {
        return None;
    }
    let n = pairs.len() as f64;
    let rmse = |sq: f64| (sq / n).sqrt();
    Some(TrajectoryError {
        frames: pairs.len(),
        odometry_ate_m: rmse(pairs.iter().map(|p| p.0 * p.0).sum()),
        fused_ate_m: rmse(pairs.iter().map(|p| p.1 * p.1).sum()),
        odometry_max_m: pairs.iter().map(|p| p.0).fold(0.0, f64::max),
    })
}

impl Evaluation {
    /// Largest localisation error over the matches, m (None: no match).
    pub fn max_error_m(&self) -> Option<f64> {
        self.matches.iter().map(|m| m.error_m).reduce(f64::max)
    }
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// Greedy nearest matching: (matches, unmatched truths, unmatched objects).
pub fn match_objects(
    objects: &[Object],
    truth: &[TrueObject],
) -> (Vec<Match>, Vec<usize>, Vec<usize>) {
    let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
    for (t, tr) in truth.iter().enumerate() {
        for (o, ob) in objects.iter().enumerate() {
            let d = dist(ob.centroid_m, tr.center_m());
            if d <= tr.gate_m() {
                pairs.push((d, t, o));
            }
        }
    }
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let mut t_used = vec![false; truth.len()];
    let mut o_used = vec![false; objects.len()];
    let mut matches = Vec::new();
    for (d, t, o) in pairs {
        if t_used[t] || o_used[o] {
            continue;
        }
        t_used[t] = true;
        o_used[o] = true;
        matches.push(Match {
            truth_index: t,
            name: truth[t].name.clone(),
            object_index: o,
            error_m: d,
            centroid_m: objects[o].centroid_m,
            truth_center_m: truth[t].center_m(),
            mass_centroid_error_m: dist(objects[o].mass_centroid_m, truth[t].center_m()),
        });
    }
    matches.sort_by_key(|m| m.truth_index);
    let missed = (0..truth.len()).filter(|&t| !t_used[t]).collect();
    let spurious = (0..objects.len()).filter(|&o| !o_used[o]).collect();
    (matches, missed, spurious)
}

/// IoU of the cells `estimated` (flat indices) against the cells whose centres lie inside a
/// true box.
pub fn voxel_iou(spec: &GridSpec, estimated: &[usize], truth: &[TrueObject]) -> f64 {
    // Only the cells of the boxes' axis-aligned bounds can have their centre inside one: a
    // building-sized grid has billions of cells, an object a few thousand.
    let mut truth_cells = Vec::new();
    for t in truth {
        let (lo, hi) = t.aabb_m();
        let range = |a: usize| {
            let to_cell = |x: f64| (x - spec.origin_m[a]) / spec.voxel_size_m - 0.5;
            let n = spec.dims[a] as f64;
            let first = (to_cell(lo[a]).floor() - 1.0).clamp(0.0, n) as usize;
            let end = (to_cell(hi[a]).ceil() + 2.0).clamp(0.0, n) as usize;
            first..end
        };
        for i in range(0) {
            for j in range(1) {
                for k in range(2) {
                    if t.contains(spec.center(i, j, k)) {
                        truth_cells.push(spec.index(i, j, k));
                    }
                }
            }
        }
    }
    truth_cells.sort_unstable();
    truth_cells.dedup();
    let inter = estimated
        .iter()
        .filter(|i| truth_cells.binary_search(i).is_ok())
        .count();
    let union = estimated.len() + truth_cells.len() - inter;
    if union == 0 {
        0.0
    } else {
        inter as f64 / union as f64
    }
}

/// Scores `report` against the true boxes and, when given, the true track (stamp-sorted
/// positions of base_link in odom).
pub fn evaluate(
    report_name: &str,
    report: &Report,
    truth: &[TrueObject],
    truth_track: &PoseTrack,
) -> Evaluation {
    let (matches, missed, spurious) = match_objects(&report.objects, truth);
    let spec = GridSpec {
        origin_m: report.grid.origin_m,
        voxel_size_m: report.grid.voxel_size_m,
        dims: report.grid.dims,
    };
    let per_frame = report
        .per_frame
        .iter()
        .map(|f| {
            let (m, _, _) = match_objects(&f.objects, truth);
            let errs: Vec<f64> = m.iter().map(|m| m.error_m).collect();
            FrameEval {
                index: f.index,
                stamp_ns: f.stamp_ns,
                objects: f.objects.len(),
                matched: m.len(),
                mean_error_m: (!errs.is_empty())
                    .then(|| errs.iter().sum::<f64>() / errs.len() as f64),
                max_error_m: errs.iter().copied().reduce(f64::max),
                refinement: f.correction.map(|c| c.outcome),
                detections_only: f
                    .correction
                    .is_some_and(|c| c.applied && c.floor_cells == 0),
            }
        })
        .collect();
    let poses = match (report.options.poses, report.options.refine_poses) {
        (crate::fuse::replay::PoseSource::GroundTruth, false) => "ground-truth",
        (crate::fuse::replay::PoseSource::GroundTruth, true) => "ground-truth, refined",
        (crate::fuse::replay::PoseSource::Odometry, false) => "odometry",
        (crate::fuse::replay::PoseSource::Odometry, true) => "refined",
    };
    Evaluation {
        report: report_name.to_owned(),
        poses: {
            let check = report.refinement.as_ref();
            let smoothed = check
                .and_then(|r| r.smoothing.as_ref())
                .is_some_and(|s| s.kept);
            match (check.is_some_and(|r| r.rolled_back), smoothed) {
                (true, false) => "odometry (refinement rolled back)".to_owned(),
                (true, true) => {
                    "odometry (refinement rolled back), smoothed over the whole replay".to_owned()
                }
                (false, true) => format!("{poses}, smoothed over the whole replay"),
                (false, false) => poses.to_owned(),
            }
        },
        matches,
        missed: missed.iter().map(|&t| truth[t].name.clone()).collect(),
        spurious: spurious
            .iter()
            .map(|&o| report.objects[o].centroid_m)
            .collect(),
        voxel_iou: voxel_iou(&spec, &report.object_cells, truth),
        per_frame,
        trajectory: trajectory_error(report, truth_track),
        rolled_back: report
            .refinement
            .as_ref()
            .filter(|r| r.rolled_back)
            .map(|r| r.reason.clone().unwrap_or_default()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::types::geometry::iso_from_xy_yaw;

    fn obj(c: [f64; 3]) -> Object {
        Object {
            cells: 10,
            peak_probability: 0.99,
            mean_probability: 0.9,
            peak_log_odds: 5.0,
            ..Object::cube(c, 0.0)
        }
    }

    #[test]
    fn greedy_matching_pairs_nearest_and_reports_the_rest() {
        let mut b1 = iso_from_xy_yaw(0.0, 0.0, 0.3);
        b1.translation.z = 0.45;
        let mut b2 = iso_from_xy_yaw(1.0, 0.0, 0.0);
        b2.translation.z = 0.45;
        let truth = vec![
            TrueObject {
                name: "chair".into(),
                boxes: vec![TrueBox {
                    odom_from_box: b1,
                    size_m: [0.5, 0.5, 0.9],
                }],
            },
            TrueObject {
                name: "chair".into(),
                boxes: vec![TrueBox {
                    odom_from_box: b2,
                    size_m: [0.5, 0.5, 0.9],
                }],
            },
        ];
        let mut near_first = obj([0.03, 0.04, 0.45]);
        // Its mass centroid is off its location: (0.05, 0.05, 0.45).
        near_first.mass_centroid_m = [0.05, 0.05, 0.45];
        let objects = vec![obj([0.95, 0.0, 0.45]), near_first, obj([3.0, 3.0, 0.5])];
        let (m, missed, spurious) = match_objects(&objects, &truth);
        assert_eq!(m.len(), 2);
        assert_eq!(m[0].object_index, 1);
        assert!((m[0].error_m - 0.05).abs() < 1e-12);
        assert!((m[0].mass_centroid_error_m - 0.05 * 2f64.sqrt()).abs() < 1e-12);
        assert!((m[1].mass_centroid_error_m - 0.05).abs() < 1e-12);
        assert!((m[1].error_m - 0.05).abs() < 1e-12);
        assert!(missed.is_empty());
        assert_eq!(spurious, vec![2]);
        // Containment respects the box's yaw.
        assert!(truth[0].contains([0.2, 0.0, 0.1]));
        assert!(!truth[0].contains([0.0, 0.0, 0.95]));
    }

    /// A kettle of two touching boxes (body 0.2 m cube at the origin, spout 0.1 x 0.05 x 0.05
    /// beside it) and a second kettle far away: two instances; the first's centre is the
    /// volume-weighted mean, (0.008 m^3 * 0 + 0.00025 m^3 * 0.15) / 0.00825 m^3 along x.
    #[test]
    fn touching_boxes_of_one_name_are_one_instance() {
        use crate::io::msgs::{GroundTruth, Header, Pose};
        let pose = |x: f64, y: f64| Pose {
            position: [x, y, 0.5],
            orientation_xyzw: [0.0, 0.0, 0.0, 1.0],
        };
        let gt = GroundTruth {
            header: Header::default(),
            object: vec!["kettle".into(), "kettle".into(), "kettle".into()],
            box_center: vec![pose(0.0, 0.0), pose(0.15, 0.0), pose(2.0, 1.0)],
            box_size: vec![[0.2, 0.2, 0.2], [0.1, 0.05, 0.05], [0.2, 0.2, 0.2]],
        };
        let t = true_objects(&gt);
        assert_eq!(t.len(), 2);
        assert_eq!(t[0].boxes.len(), 2);
        let c = t[0].center_m();
        assert!((c[0] - 0.00025 * 0.15 / 0.00825).abs() < 1e-12, "{c:?}");
        assert!(c[1].abs() < 1e-12 && (c[2] - 0.5).abs() < 1e-12);
        assert_eq!(t[1].center_m(), [2.0, 1.0, 0.5]);
        assert!(t[0].contains([0.18, 0.0, 0.5]) && !t[0].contains([0.18, 0.1, 0.5]));
    }

    #[test]
    fn iou_of_exact_and_half_estimates() {
        let spec = GridSpec::from_bounds([0.0; 3], [1.0; 3], 0.1).unwrap();
        let mut b = iso_from_xy_yaw(0.5, 0.5, 0.0);
        b.translation.z = 0.5;
        // Box of 0.4 m: cells 3..7 on each axis (centres 0.35..0.65) = 64 cells.
        let truth = vec![TrueObject {
            name: "x".into(),
            boxes: vec![TrueBox {
                odom_from_box: b,
                size_m: [0.4, 0.4, 0.4],
            }],
        }];
        let inside: Vec<usize> = (0..spec.cells())
            .filter(|&i| {
                let [a, bb, c] = spec.ijk(i);
                truth[0].contains(spec.center(a, bb, c))
            })
            .collect();
        assert_eq!(inside.len(), 64);
        assert_eq!(voxel_iou(&spec, &inside, &truth), 1.0);
        assert_eq!(voxel_iou(&spec, &inside[..32], &truth), 0.5);
    }

    /// A report of three frames at 1.0, 2.04 and 2.9 s, fused at poses other than /odom's.
    fn three_frame_report() -> crate::out::report::Report {
        use crate::fuse::replay::{FrameSummary, FuseOptions};
        use crate::out::report::{GridReport, REPORT_VERSION, Report};
        let frame = |index: usize, stamp_ns: i64, odom: [f64; 3], used: [f64; 3]| FrameSummary {
            index,
            stamp_ns,
            log_time_ns: stamp_ns as u64,
            position_m: used,
            yaw_rad: 0.0,
            odom_position_m: odom,
            odom_yaw_rad: 0.0,
            correction: None,
            cells_updated: 0,
            max_probability: 0.5,
            objects: Vec::new(),
        };
        Report {
            report_version: REPORT_VERSION,
            objloc_version: "test".into(),
            session: "s".into(),
            session_sha256: String::new(),
            model: "m".into(),
            model_sha256: String::new(),
            frames: 3,
            frames_in_session: 3,
            options: FuseOptions::default(),
            fitted: Vec::new(),
            grid: GridReport {
                dims: [1, 1, 1],
                voxel_size_m: 0.04,
                origin_m: [0.0; 3],
                prior: 0.01,
                sha256: String::new(),
                storage: None,
                stored_cells: 0,
                export: None,
            },
            objects: Vec::new(),
            object_cells: Vec::new(),
            per_frame: vec![
                frame(0, 1_000_000_000, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]),
                // 40 ms after the last true pose: within tolerance, that pose.
                frame(1, 2_040_000_000, [1.3, 0.0, 0.0], [1.0, 0.4, 0.0]),
                // No true pose within 50 ms: not counted.
                frame(2, 2_900_000_000, [9.0, 9.0, 0.0], [9.0, 9.0, 0.0]),
            ],
            refinement: None,
            warnings: Vec::new(),
            timing_ms: Default::default(),
        }
    }

    #[test]
    fn trajectory_error_is_the_rmse_at_the_frames() {
        let report = three_frame_report();
        let truth = PoseTrack::new(vec![
            (1_000_000_000, iso_from_xy_yaw(0.0, 0.0, 0.0)),
            (2_000_000_000, iso_from_xy_yaw(1.0, 0.0, 0.0)),
        ]);
        let t = trajectory_error(&report, &truth).unwrap();
        assert_eq!(t.frames, 2);
        // /odom errors 0 and 0.3: RMSE sqrt(0.09 / 2); fused errors 0 and 0.4: sqrt(0.16 / 2).
        assert!((t.odometry_ate_m - (0.09f64 / 2.0).sqrt()).abs() < 1e-12);
        assert!((t.fused_ate_m - (0.16f64 / 2.0).sqrt()).abs() < 1e-12);
        assert!((t.odometry_max_m - 0.3).abs() < 1e-12);
        assert!(trajectory_error(&report, &PoseTrack::default()).is_none());
    }

    /// Found by fuzzing `eval`: an edited report was scored (IoU 0, exit 0).
    #[test]
    fn report_check_rejects_what_fuse_cannot_write() {
        let report = three_frame_report();
        let why = |r: &Report| r.check().map_err(|e| e.to_string());
        assert_eq!(why(&report), Ok(()));
        let mut bad = report.clone();
        bad.object_cells = vec![0, 1];
        assert_eq!(
            why(&bad),
            Err("inconsistent report: object_cells holds cell 1, outside the 1 cells of a [1, 1, 1] grid".into())
        );
        bad.object_cells = vec![0, 0];
        assert!(
            why(&bad)
                .unwrap_err()
                .ends_with("cell 0 after 0: not ascending, each once")
        );
        let mut bad = report.clone();
        bad.per_frame[2].index = 1;
        assert!(
            why(&bad)
                .unwrap_err()
                .ends_with("per_frame index 1 after 1: frames out of order")
        );
        bad.per_frame[2].index = 3;
        assert!(
            why(&bad)
                .unwrap_err()
                .ends_with("per_frame index 3 is beyond the session's 3 frames")
        );
        let mut bad = report.clone();
        bad.grid.stored_cells = 513;
        assert!(
            why(&bad)
                .unwrap_err()
                .contains("stored_cells 513 exceeds the 512")
        );
        let mut bad = report.clone();
        bad.grid.dims = [1, 0, 1];
        assert!(
            why(&bad)
                .unwrap_err()
                .ends_with("grid.dims [1, 0, 1] is not a grid fuse can make")
        );
        // Beyond fuse's block table (2^30 blocks), and where the product would overflow.
        bad.grid.dims = [8 << 20, 8 << 20, 8];
        assert!(
            why(&bad)
                .unwrap_err()
                .contains("is not a grid fuse can make")
        );
        bad.grid.dims = [usize::MAX, usize::MAX, 1];
        assert!(
            why(&bad)
                .unwrap_err()
                .contains("is not a grid fuse can make")
        );
    }
}
