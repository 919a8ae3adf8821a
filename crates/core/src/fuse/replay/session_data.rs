//! Pass 1 of the replay: everything of a session but the pixels, read and validated.

use std::collections::BTreeMap;

use crate::io::msgs::GroundTruth;
use crate::io::msgs::iso_from_pose;
use crate::io::session::{At, MessageMeta, Role, SessionMsg, SessionReader, TimedMsg};
use crate::types::geometry::{Camera, Iso3, iso_from_parts};
use crate::types::lens::{Distortion, Rectifier, camera_changes};

use super::tf::{TfError, TfTree};
use super::*;
use crate::types::track::PoseTrack;

/// How far a quaternion's squared length may be from 1 before it is named: tf2's own test
/// (it refuses transforms beyond it).
pub const UNIT_QUATERNION_TOLERANCE: f64 = 0.01;

/// A command's forward or turn speed beyond this (m/s, rad/s) is garbage, not motion: the
/// motion model would spread its uncertainty over kilometres (a /cmd_vel of 1e20 m/s once
/// overflowed the floor map's cell index).
pub const MAX_COMMAND_SPEED: f64 = 100.0;

/// A pose further than this from its frame's origin (metres, any axis) is garbage: no frame on
/// Earth reaches it (UTM northings stay below 1e7 m). An /odom pose 1e300 m away made the
/// default bounds a grid of 2^64 cells, refused with saturated numbers and no topic.
pub const MAX_POSITION_M: f64 = 1e8;

/// The pose as a transform, or why it cannot be used: not finite, a zero quaternion, or
/// beyond [`MAX_POSITION_M`].
fn usable_pose(pose: &crate::io::msgs::Pose) -> Result<Iso3, String> {
    let iso = iso_from_pose(pose).ok_or("pose is not finite or has a zero quaternion")?;
    match pose.position.iter().position(|v| v.abs() > MAX_POSITION_M) {
        None => Ok(iso),
        Some(axis) => Err(format!(
            "position {} = {:e} m is beyond {MAX_POSITION_M:e} m of the origin, further than any frame on Earth",
            ["x", "y", "z"][axis],
            pose.position[axis]
        )),
    }
}

/// Margin around the camera positions for the default bounds, metres.
pub const DEFAULT_BOUNDS_MARGIN_M: f64 = 0.25;
/// Smallest side of the default bounds in x and y, metres (the paper's 4 m grid).
pub const DEFAULT_MIN_SIDE_M: f64 = 4.0;

/// One camera frame of the session, before its pixels are decoded.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameRef {
    /// The frame's message in the reader, to decode its pixels from.
    pub meta: MessageMeta,
    /// Topic the frame came on.
    pub topic: String,
    /// MCAP log time, ns since the Unix epoch (the replay's order).
    pub log_time_ns: u64,
    /// Header stamp (exposure time), ns since the Unix epoch; the frame's pose is taken at it.
    pub stamp_ns: i64,
}

/// Everything of a session but the pixels, validated.
#[derive(Debug, Clone)]
pub struct SessionData {
    /// The session file, as messages name it.
    pub path: String,
    /// Pinhole intrinsics from CameraInfo (one camera per session).
    pub camera: Camera,
    /// The lens distortion of the recorded images (CameraInfo `d`; zero for none).
    pub distortion: Distortion,
    /// The remap of a recorded image to the pinhole image of `camera`, when distorted: every
    /// frame is rectified as it is decoded, so the rest of the replay sees a pinhole camera.
    pub rectifier: Option<Rectifier>,
    /// CameraInfo's frame id; the mount is the transform to this frame.
    pub camera_frame_id: String,
    /// The transforms of /tf_static and /tf: the camera mount at a stamp is
    /// [`SessionData::mount_at`].
    pub tf: TfTree,
    /// The odometry's child frame (the robot's base), from the first /odom message.
    pub base_frame_id: Option<String>,
    /// The mount when /tf_static holds a single transform that does not name the camera's
    /// frame (older bags): taken to be the mount.
    pub lone_mount: Option<Iso3>,
    /// (stamp, odom_from_base) at the frames' and the commands' stamps (what /odom gives
    /// there, interpolated as [`PoseTrack::at`] does; see [`PoseTrack::sampled_at`]), sorted.
    pub odom: PoseTrack,
    /// (stamp, v m/s, w rad/s), sorted by stamp.
    pub commands: Vec<(i64, f64, f64)>,
    /// The camera frames, in (log time, channel id, sequence) order.
    pub frames: Vec<FrameRef>,
    /// (stamp, odom_from_base) from /ground_truth/pose at the same stamps as `odom`, sorted;
    /// empty unless simulated.
    pub ground_truth_poses: PoseTrack,
    /// The true object boxes from /ground_truth/objects, when recorded.
    pub ground_truth: Option<GroundTruth>,
    /// Problems of pass 1 that left the rest usable, one line each.
    pub warnings: Vec<String>,
}

impl SessionData {
    /// The camera mount (base_from_camera) at `stamp_ns`: the chain from the odometry's
    /// child frame to the camera's frame (see [`TfTree`]), or why there is none.
    pub fn mount_at(&self, stamp_ns: i64) -> Result<Iso3, TfError> {
        self.tf
            .mount(
                self.base_frame_id.as_deref(),
                &self.camera_frame_id,
                stamp_ns,
            )
            .or_else(|e| self.lone_mount.ok_or(e))
    }

    /// Pose of base_link in odom at `stamp_ns`, interpolated; `None` when the odometry does
    /// not reach within [`crate::types::track::POSE_TOLERANCE_NS`] of it.
    pub fn odom_at(&self, stamp_ns: i64) -> Option<Iso3> {
        self.odom.at(stamp_ns)
    }

    /// Pose of base_link from /ground_truth/pose at `stamp_ns`, as [`SessionData::odom_at`].
    pub fn ground_truth_at(&self, stamp_ns: i64) -> Option<Iso3> {
        self.ground_truth_poses.at(stamp_ns)
    }

    /// Default grid bounds: the box around every camera position, padded by
    /// [`DEFAULT_BOUNDS_MARGIN_M`] and widened to at least [`DEFAULT_MIN_SIDE_M`] in x and y;
    /// z from the floor (0) to 0.5 m above the highest camera. A robot that looks at an object
    /// from several sides (the method's premise) has the object inside this box.
    pub fn default_bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for f in &self.frames {
            if let Some(p) = self.odom_at(f.stamp_ns) {
                let Ok(mount) = self.mount_at(f.stamp_ns) else {
                    continue;
                };
                let c = (p * mount).translation.vector;
                for a in 0..3 {
                    lo[a] = lo[a].min(c[a]);
                    hi[a] = hi[a].max(c[a]);
                }
            }
        }
        if !lo[0].is_finite() {
            return None;
        }
        for a in 0..2 {
            lo[a] -= DEFAULT_BOUNDS_MARGIN_M;
            hi[a] += DEFAULT_BOUNDS_MARGIN_M;
            let side = hi[a] - lo[a];
            if side < DEFAULT_MIN_SIDE_M {
                let grow = (DEFAULT_MIN_SIDE_M - side) / 2.0;
                lo[a] -= grow;
                hi[a] += grow;
            }
        }
        let top = hi[2] + 0.5;
        Some(([lo[0], lo[1], 0.0], [hi[0], hi[1], top]))
    }
}

/// What pass 1 collects, message by message.
#[derive(Default)]
struct Collected {
    warnings: Vec<String>,
    /// Raw frames recorded `mono8` (grey).
    mono_frames: usize,
    /// Per topic, the quaternions that are not of unit length: count, and the first's place
    /// and length (normalised and used, and said once per topic).
    unnormalised: BTreeMap<String, (usize, At, f64)>,
    camera: Option<(Camera, Distortion, String)>,
    /// (parent, child, parent_from_child) from /tf_static.
    transforms: Vec<(String, String, Iso3)>,
    /// (parent, child, stamp, parent_from_child) from /tf.
    dynamic: Vec<(String, String, i64, Iso3)>,
    /// The first /odom message's child frame.
    base_frame_id: Option<String>,
    odom: Vec<(i64, Iso3)>,
    commands: Vec<(i64, f64, f64)>,
    frames: Vec<FrameRef>,
    gt_poses: Vec<(i64, Iso3)>,
    ground_truth: Option<GroundTruth>,
}

impl Collected {
    /// Notes a quaternion `xyzw` of `topic` whose length is off 1 by more than tf2 allows
    /// (it refuses them; here they are normalised, and said).
    fn check_unit(&mut self, topic: &str, at: &At, xyzw: [f64; 4]) {
        let len = xyzw.iter().map(|v| v * v).sum::<f64>().sqrt();
        if len.is_finite() && len > 0.0 && (len * len - 1.0).abs() > UNIT_QUATERNION_TOLERANCE {
            self.unnormalised
                .entry(topic.to_owned())
                .or_insert((0, at.clone(), len))
                .0 += 1;
        }
    }

    /// Takes one decoded message (`meta` in the reader).
    fn take(&mut self, m: TimedMsg, meta: MessageMeta, at: At) -> Result<(), ReplayError> {
        match &m.msg {
            SessionMsg::TfStatic(tf) | SessionMsg::Tf(tf) => {
                for t in &tf.transforms {
                    self.check_unit(&m.topic, &at, t.rotation_xyzw);
                }
            }
            SessionMsg::Odom(o) => self.check_unit(&m.topic, &at, o.pose.orientation_xyzw),
            _ => {}
        }
        match m.msg {
            SessionMsg::CameraInfo(ci) => self.take_camera(&ci, at)?,
            SessionMsg::TfStatic(tf) => {
                for t in tf.transforms {
                    let iso = transform_iso(&t, &at)?;
                    self.transforms
                        .push((t.header.frame_id, t.child_frame_id, iso));
                }
            }
            SessionMsg::Tf(tf) => {
                for t in tf.transforms {
                    let iso = transform_iso(&t, &at)?;
                    let stamp = t.header.stamp_ns;
                    self.dynamic
                        .push((t.header.frame_id, t.child_frame_id, stamp, iso));
                }
            }
            SessionMsg::Odom(o) => match usable_pose(&o.pose) {
                Ok(p) => {
                    if self.base_frame_id.is_none() {
                        self.base_frame_id = Some(o.child_frame_id.clone());
                    }
                    self.odom.push((o.header.stamp_ns, p));
                }
                Err(why) => self.warnings.push(format!("{at}: {why}; message skipped")),
            },
            SessionMsg::CmdVel(c) => {
                let (v, w) = (c.twist.linear[0], c.twist.angular[2]);
                if !(v.is_finite() && w.is_finite()) {
                    self.warnings
                        .push(format!("{at}: twist is not finite; command skipped"));
                } else if v.abs() > MAX_COMMAND_SPEED || w.abs() > MAX_COMMAND_SPEED {
                    self.warnings.push(format!(
                        "{at}: twist {v} m/s, {w} rad/s is beyond any ground robot's ({MAX_COMMAND_SPEED} m/s or rad/s); command skipped"
                    ));
                } else {
                    self.commands.push((c.header.stamp_ns, v, w));
                }
            }
            SessionMsg::Frame(f) => {
                if let crate::io::session::FramePixels::Raw(img) = &f.pixels {
                    self.mono_frames += usize::from(img.encoding == "mono8");
                }
                self.frames.push(FrameRef {
                    meta,
                    topic: m.topic.clone(),
                    log_time_ns: m.log_time_ns,
                    stamp_ns: f.stamp_ns,
                })
            }
            SessionMsg::GroundTruthPose(p) => match usable_pose(&p.pose) {
                Ok(iso) => self.gt_poses.push((p.header.stamp_ns, iso)),
                Err(why) => self.warnings.push(format!("{at}: {why}; message skipped")),
            },
            SessionMsg::GroundTruthObjects(g) => self.ground_truth = Some(g),
            SessionMsg::Label(_) => {}
        }
        Ok(())
    }

    /// Takes one CameraInfo: the first sets the camera; later ones must agree with it to
    /// [`crate::types::lens::CAMERA_TOLERANCE_PX`] (calibrations decomposed per view differ by
    /// rounding).
    /// Warnings about the frames a model may see wrongly: raw `mono8` frames (read as grey
    /// RGB, so a model trained on colour tells objects by brightness alone: an explorer's
    /// mono8 copy of the chair tour found nothing and said nothing), and a frame id that is
    /// the camera's link with its optical frame below it (a driver's misconfiguration: the
    /// mount then turns every ray, and the same copy found nothing either).
    fn frame_warnings(&self, path: &str, camera_frame_id: &str) -> Vec<String> {
        let mut out = Vec::new();
        if self.mono_frames > 0 {
            out.push(format!(
                "{path}: {} of {} frames are mono8 (grey): a model trained on colour frames sees their brightness alone and may find nothing",
                self.mono_frames,
                self.frames.len()
            ));
        }
        let optical_below = self
            .transforms
            .iter()
            .map(|(p, ch, _)| (p, ch))
            .chain(self.dynamic.iter().map(|(p, ch, _, _)| (p, ch)))
            .find(|(p, ch)| *p == camera_frame_id && ch.contains("optical"));
        if let Some((_, child)) = optical_below
            && !camera_frame_id.contains("optical")
        {
            out.push(format!(
                "{path}: the frames are in {camera_frame_id:?}, but the transforms put the optical frame {child:?} below it: is the images' frame_id the camera's link rather than its optical frame (z forward, x right, y down)?"
            ));
        }
        out
    }

    fn take_camera(&mut self, ci: &crate::io::msgs::CameraInfo, at: At) -> Result<(), ReplayError> {
        let invalid = |what: String| ReplayError::Invalid {
            at: at.clone(),
            what,
        };
        let cam = Camera::from_info(ci).ok_or_else(|| {
            invalid(format!(
                "CameraInfo is not a usable pinhole camera (width {}, height {}, K {:?})",
                ci.width, ci.height, ci.k
            ))
        })?;
        let d = Distortion::from_info(ci).map_err(|e| invalid(e.to_string()))?;
        match &self.camera {
            None => self.camera = Some((cam, d, ci.header.frame_id.clone())),
            Some((c, d0, _)) => {
                if let Some(what) = camera_changes((c, d0), (&cam, &d)) {
                    return Err(invalid(format!(
                        "CameraInfo changes during the session ({what}); objloc fuses one camera"
                    )));
                }
            }
        }
        Ok(())
    }

    /// Static transforms as tf2 takes them: a later one of the same child replaces an earlier
    /// one (said, when they differ), and parents that loop are refused.
    fn check_static_transforms(&mut self, reader: &SessionReader) -> Result<(), ReplayError> {
        let topic = &reader.topics().tf_static;
        let mut last: BTreeMap<&str, (&str, &Iso3)> = BTreeMap::new();
        let mut replaced: Vec<&str> = Vec::new();
        for (parent, child, iso) in &self.transforms {
            if let Some((p, prev)) = last.insert(child, (parent, iso))
                && (p != parent || (prev.to_homogeneous() - iso.to_homogeneous()).amax() > 1e-9)
                && !replaced.contains(&child.as_str())
            {
                replaced.push(child);
            }
        }
        for child in replaced {
            let (parent, iso) = last[child];
            let t = iso.translation.vector;
            self.warnings.push(format!(
                "{}: topic {topic}: {child} is given different transforms; the last one, from \
                 {parent} at ({:.3}, {:.3}, {:.3}) m, is used, as tf2 does",
                reader.path().display(),
                t.x,
                t.y,
                t.z
            ));
        }
        let tree = TfTree::new(&self.transforms, &[]);
        for child in last.keys() {
            if let Err(TfError::Loop { .. }) = tree.lookup(None, child, 0) {
                return Err(ReplayError::Invalid {
                    at: At {
                        path: reader.path().to_owned(),
                        topic: Some(topic.clone()),
                        log_time_ns: None,
                    },
                    what: format!(
                        "the parents of {child:?} form a loop ({}): tf2 refuses such a tree",
                        loop_text(&last, child)
                    ),
                });
            }
        }
        Ok(())
    }

    /// The warning for a static camera mount that no transform links to the frame /odom
    /// moves (the mount then stands in unlinked), if it is so.
    fn unlinked_mount(
        &self,
        reader: &SessionReader,
        tf: &TfTree,
        camera_frame_id: &str,
        first_stamp_ns: i64,
    ) -> Option<String> {
        let base = self.base_frame_id.as_ref()?;
        if tf.is_dynamic()
            || tf
                .lookup(Some(base), camera_frame_id, first_stamp_ns)
                .is_ok()
        {
            return None;
        }
        let path = reader.path().display();
        let tf_static = &reader.topics().tf_static;
        Some(
            match (tf.parent(camera_frame_id), self.transforms.first()) {
                (Some(parent), _) => format!(
                    "{path}: the camera mount is taken from {parent} -> {camera_frame_id} on \
                 {tf_static}, but /odom moves {base:?}, which no transform connects to it (a \
                 moving mount's /tf missing?)"
                ),
                // The lone transform stands in, though it names neither frame.
                (None, Some((p, child, _))) => format!(
                    "{path}: the camera mount is taken from the only transform on {tf_static}, \
                 {p} -> {child}, though the camera's frame is {camera_frame_id:?} and /odom \
                 moves {base:?}: check the frames"
                ),
                (None, None) => format!("{path}: no transform on {tf_static} names the camera"),
            },
        )
    }

    /// The transform tree, checked to give the camera mount: at every stamp when static,
    /// at least somewhere when it moves (frames without one are skipped later).
    fn mount(
        &mut self,
        reader: &SessionReader,
        camera_frame_id: &str,
        first_stamp_ns: i64,
    ) -> Result<(TfTree, Option<Iso3>), ReplayError> {
        self.check_static_transforms(reader)?;
        let tree = TfTree::new(&self.transforms, &self.dynamic);
        let t = &self.transforms;
        let lone = (t.len() == 1 && self.dynamic.is_empty()).then(|| t[0].2);
        let base = self.base_frame_id.as_deref();
        let found = tree.mount(base, camera_frame_id, first_stamp_ns).is_ok();
        if found || lone.is_some() || tree.is_dynamic() {
            return Ok((tree, lone));
        }
        Err(ReplayError::Invalid {
            at: At {
                path: reader.path().to_owned(),
                topic: Some(reader.topics().tf_static.clone()),
                log_time_ns: None,
            },
            what: format!(
                "no transform to the camera frame {camera_frame_id:?} (have: {})",
                t.iter()
                    .map(|(p, c, _)| format!("{p} -> {c}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        })
    }
}

/// A transform as an isometry, or an error naming its frames.
fn transform_iso(t: &crate::io::msgs::TransformStamped, at: &At) -> Result<Iso3, ReplayError> {
    iso_from_parts(t.translation, t.rotation_xyzw).ok_or_else(|| ReplayError::Invalid {
        at: at.clone(),
        what: format!(
            "transform {} -> {} is not finite or has a zero quaternion",
            t.header.frame_id, t.child_frame_id
        ),
    })
}

/// A warning when the command topic is empty but the file carries velocity commands under
/// another name (`/mobile_base/cmd_vel`): the session would be fused as a capture, without
/// a motion model, and only the `fitted` lines on stdout said why.
fn commands_elsewhere(reader: &SessionReader) -> Option<String> {
    let cmd_vel = reader.topics().get(Role::CmdVel);
    if reader.count(cmd_vel) > 0 {
        return None;
    }
    let others = reader.topics_carrying(Role::CmdVel.message_type());
    let first = others.first()?;
    Some(format!(
        "{}: nothing on {cmd_vel}, but velocity commands on {}: fused without a motion model, as a capture (--topic cmd_vel={first} to use them)",
        reader.path().display(),
        others.join(", ")
    ))
}

/// Pass 1: reads and validates everything but pixels.
pub fn load_session(reader: &SessionReader) -> Result<SessionData, ReplayError> {
    reader.require(Role::CameraInfo)?;
    // The camera's mount may come on /tf alone (a bag often misses the latched
    // /tf_static, and with an empty one the same file fused as the original): /tf_static is
    // required only where /tf is empty.
    if reader.count(reader.topics().get(Role::Tf)) == 0 {
        reader.require(Role::TfStatic)?;
    }
    reader.require(Role::Odom)?;
    reader.require_frames()?;
    let path = reader.path().display().to_string();
    let mut c = Collected {
        warnings: reader.warnings.clone(),
        ..Collected::default()
    };
    c.warnings.extend(commands_elsewhere(reader));
    // Messages are decoded one at a time from the reader's chunk cache: a frame's payload is
    // decoded here only for its header (stamp) and CDR check and dropped at once; its pixels
    // are decoded in pass 2, by their place in the file.
    for meta in reader.ordered() {
        let meta = meta?;
        let Some(m) = reader.decode(&meta)? else {
            continue;
        };
        let at = reader.at(Some(&m.topic), m.log_time_ns);
        c.take(m, meta, at)?;
    }
    let (camera, distortion, camera_frame_id) =
        c.camera.clone().ok_or_else(|| ReplayError::Invalid {
            at: At {
                path: reader.path().to_owned(),
                topic: Some(reader.topics().camera_info.clone()),
                log_time_ns: None,
            },
            what: "no CameraInfo".into(),
        })?;
    let first_stamp_ns = c.frames.first().map_or(0, |f| f.stamp_ns);
    let (tf, lone_mount) = c.mount(reader, &camera_frame_id, first_stamp_ns)?;
    c.warnings
        .extend(c.unlinked_mount(reader, &tf, &camera_frame_id, first_stamp_ns));
    let frames_said = c.frame_warnings(&path, &camera_frame_id);
    c.warnings.extend(frames_said);
    if c.odom.windows(2).any(|w| w[1].0 < w[0].0) {
        c.warnings.push(format!(
            "{path}: {} stamps go backwards; poses sorted by stamp",
            reader.topics().odom
        ));
    }
    c.warnings.extend(frame_stamp_warnings(&path, &c.frames));
    for (topic, (n, at, len)) in &c.unnormalised {
        c.warnings.push(format!(
            "{at}: {n} message(s) on {topic} carry a quaternion of length {len:.4} (this one) or otherwise not 1; normalised (tf2 refuses them)"
        ));
    }
    c.commands.sort_by_key(|(t, _, _)| *t);
    // The replay asks the pose tracks only at its frames' stamps and its commands' (where a
    // motion segment starts): kept there alone, they cost per frame and command, not per
    // /odom message.
    let asked: Vec<i64> = c
        .frames
        .iter()
        .map(|f| f.stamp_ns)
        .chain(c.commands.iter().map(|cmd| cmd.0))
        .collect();
    Ok(SessionData {
        path,
        camera,
        distortion,
        rectifier: (!distortion.is_zero()).then(|| Rectifier::new(&camera, &distortion)),
        camera_frame_id,
        tf,
        base_frame_id: c.base_frame_id,
        lone_mount,
        odom: PoseTrack::new(c.odom).sampled_at(&asked),
        commands: c.commands,
        frames: c.frames,
        ground_truth_poses: PoseTrack::new(c.gt_poses).sampled_at(&asked),
        ground_truth: c.ground_truth,
        warnings: c.warnings,
    })
}

/// A header stamp this far from its log time (either way) is not the frame's exposure: a
/// driver that leaves stamps at 0, or a clock in another epoch.
const STAMP_LOG_GAP_WARN_NS: u64 = 60_000_000_000;

/// Warnings about the frames' header stamps, the times their poses are taken at: stamps
/// shared by several frames (all posed alike; a driver that does not fill them writes 0 for
/// every frame) and stamps far from the log time.
fn frame_stamp_warnings(path: &str, frames: &[FrameRef]) -> Vec<String> {
    let mut out = Vec::new();
    let Some(first) = frames.first() else {
        return out;
    };
    let mut stamps: Vec<i64> = frames.iter().map(|f| f.stamp_ns).collect();
    stamps.sort_unstable();
    let shared: Vec<i64> = stamps
        .windows(2)
        .filter(|w| w[0] == w[1])
        .map(|w| w[0])
        .collect();
    if let Some(&t) = shared.first() {
        let n = frames
            .iter()
            .filter(|f| shared.binary_search(&f.stamp_ns).is_ok())
            .count();
        out.push(format!(
            "{path}: topic {}: {n} of {} frames share a header stamp with another (the first: {}), so they are posed alike: are the camera's stamps filled?",
            first.topic,
            frames.len(),
            stamp_text(t)
        ));
    }
    let far: Vec<&FrameRef> = frames
        .iter()
        .filter(|f| {
            i128::from(f.stamp_ns).abs_diff(i128::from(f.log_time_ns))
                > u128::from(STAMP_LOG_GAP_WARN_NS)
        })
        .collect();
    if let Some(f) = far.first() {
        out.push(format!(
            "{path}: topic {}: {} of {} frames have a header stamp more than 60 s from their log time (the first: stamp {} at log time {}); poses are taken at the header stamp",
            first.topic,
            far.len(),
            frames.len(),
            stamp_text(f.stamp_ns),
            crate::io::session::fmt_ns(f.log_time_ns)
        ));
    }
    out
}

/// A header stamp as seconds (negative ones too).
fn stamp_text(stamp_ns: i64) -> String {
    match u64::try_from(stamp_ns) {
        Ok(t) => crate::io::session::fmt_ns(t),
        Err(_) => format!("{stamp_ns} ns"),
    }
}

/// The chain of parents from `child` round its loop, as `a -> b -> a`.
fn loop_text(parents: &BTreeMap<&str, (&str, &Iso3)>, child: &str) -> String {
    let mut seen = vec![child];
    let mut at = child;
    while let Some((p, _)) = parents.get(at) {
        seen.push(p);
        if seen[..seen.len() - 1].contains(p) || seen.len() > super::tf::MAX_CHAIN {
            break;
        }
        at = p;
    }
    seen.iter().rev().copied().collect::<Vec<_>>().join(" -> ")
}
