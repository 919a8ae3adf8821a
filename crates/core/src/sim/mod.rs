//! The simulator: renders a scene from a robot that rotates and drives between stops, and
//! records the session (frames, camera info, labels, /cmd_vel, /odom, ground truth) through
//! [`crate::io::session::SessionWriter`] like any recorder.
//!
//! Invariants: the output is a pure function of (scene, options): stamps start at
//! [`START_NS`], randomness comes from seeded streams only (robot speeds and camera jitter on
//! separate streams), rendering is thread-count independent, so the same inputs give a
//! byte-identical file. `odom` is the room frame: the robot starts with odometry = truth.

pub mod head;
pub mod render;
pub mod robot;
pub mod scene;

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use nalgebra::{Translation3, UnitQuaternion, Vector3};
use thiserror::Error;

use crate::io::msgs::pose_from_iso;
use crate::io::msgs::{
    CameraInfo, CompressedImage, GroundTruth, Header, ObjectLabel, Odometry, Pose, PoseStamped,
    RegionOfInterest, Twist, TwistStamped,
};
use crate::io::session::{SessionError, SessionWriter, Topics};
use crate::types::geometry::wrap_angle;
use crate::types::geometry::{Camera, Iso3, camera_mount, iso_from_xy_yaw};
use crate::types::image::encode_png;
use crate::types::lens::Distortion;
pub use render::{FrameJitter, Rendered, Renderer};
pub use robot::{Event, Pose2, Rng, SpeedNoise, Stop};
pub use scene::{BUILTIN_SCENES, Scene, Shape};

/// First stamp of every simulated session: 2023-11-14T22:13:20Z.
pub const START_NS: i64 = 1_700_000_000_000_000_000;
/// An instance needs this many visible pixels to get a label rectangle (a person would not
/// box a sliver).
pub const MIN_LABEL_PIXELS: usize = 16;
/// Frame id of the fixed world frame: the room, z up, floor at z = 0.
pub const ODOM_FRAME: &str = "odom";
/// Frame id of the robot body: x forward, y left, z up.
pub const BASE_FRAME: &str = "base_link";
/// Frame id of the camera: optical axes, z forward, x right, y down.
pub const CAMERA_FRAME: &str = "camera_optical_frame";

/// Seeds of the independent random streams (xor-ed with the user's seed).
const ROBOT_STREAM: u64 = 0x726F_626F_7400_0001;
const CAMERA_STREAM: u64 = 0x6361_6D65_7261_0002;
/// Relative sigma of the per-frame exposure gain and of the red/blue white-balance gains.
const EXPOSURE_SIGMA: f64 = 0.06;
const WHITE_BALANCE_SIGMA: f64 = 0.03;

/// Why a simulated session could not be recorded.
#[derive(Debug, Error)]
pub enum SimError {
    /// A scene does not parse or validate.
    #[error("scene {name}: {what}")]
    Scene {
        /// The built-in scene's name or the scene file's path.
        name: String,
        /// The parse or validation message (it names the field).
        what: String,
    },
    /// No built-in scene has that name.
    #[error("unknown scene {name:?}; built-in scenes are {}", BUILTIN_SCENES.join(", "))]
    UnknownScene {
        /// The name asked for.
        name: String,
    },
    /// A scene file could not be read, or a frame dump written.
    #[error("{path}: {source}")]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// Boxed: a session error carries an MCAP error and the place it happened.
    #[error(transparent)]
    Session(Box<SessionError>),
    /// A rendered frame could not be encoded as PNG.
    #[error("frame {index} (stamp {stamp_ns} ns): cannot encode PNG: {what}")]
    Encode {
        /// Index of the frame (its stop) in the session.
        index: usize,
        /// The frame's stamp, ns since the Unix epoch.
        stamp_ns: i64,
        /// The encoder's message.
        what: String,
    },
    /// The options do not fit the scene (a tour of under 2 stops, more frames than train views).
    #[error("{0}")]
    Options(String),
}

impl From<SessionError> for SimError {
    fn from(e: SessionError) -> Self {
        Self::Session(Box::new(e))
    }
}

/// What kind of session to record.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Kind {
    /// A few labelled views of the object plus background frames without it.
    Train,
    /// Circle the object, one frame per stop, labels from ground truth.
    Tour,
}

/// How to record a simulated session.
#[derive(Debug, Clone, PartialEq)]
pub struct SimOptions {
    /// Train or tour session.
    pub kind: Kind,
    /// Seed of every random stream (robot speeds, camera jitter): same seed, same file.
    pub seed: u64,
    /// Object views of a train session.
    pub frames: usize,
    /// Stops of a tour.
    pub stops: usize,
    /// How the executed speeds stray from the commanded ones.
    pub speed_noise: SpeedNoise,
    /// Also write every frame as PNG (and a copy with the label rectangles) here.
    pub dump_frames: Option<PathBuf>,
}

impl SimOptions {
    /// Options of `kind` with `seed` and the defaults: 3 train frames, 8 tour stops, the default
    /// speed noise, no frame dump.
    pub fn new(kind: Kind, seed: u64) -> Self {
        Self {
            kind,
            seed,
            frames: 3,
            stops: 8,
            speed_noise: SpeedNoise::default(),
            dump_frames: None,
        }
    }
}

/// What a recording wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordStats {
    /// The session file written.
    pub path: PathBuf,
    /// Camera frames written.
    pub frames: usize,
    /// Messages written, all topics together.
    pub messages: usize,
}

/// A built-in scene by name.
pub fn builtin_scene(name: &str) -> Result<Scene, SimError> {
    let text =
        scene::builtin_json(name).ok_or_else(|| SimError::UnknownScene { name: name.into() })?;
    Scene::from_json(text).map_err(|what| SimError::Scene {
        name: name.into(),
        what,
    })
}

/// A scene file (JSON, see `schemas/scene.md`).
pub fn load_scene(path: &Path) -> Result<Scene, SimError> {
    let text = std::fs::read_to_string(path).map_err(|source| SimError::Io {
        path: path.into(),
        source,
    })?;
    Scene::from_json(&text).map_err(|what| SimError::Scene {
        name: path.display().to_string(),
        what,
    })
}

/// The stops of a session: the first is where the robot starts.
pub fn plan_stops(scene: &Scene, opts: &SimOptions) -> Result<Vec<Stop>, SimError> {
    let p = &scene.path;
    let facing = |bearing_rad: f64, distance_m: f64| Pose2 {
        x_m: p.target_m[0] + distance_m * bearing_rad.cos(),
        y_m: p.target_m[1] + distance_m * bearing_rad.sin(),
        yaw_rad: wrap_angle(bearing_rad + PI),
    };
    match opts.kind {
        Kind::Tour => {
            if opts.stops < 2 {
                return Err(SimError::Options(format!(
                    "a tour needs at least 2 stops, got {}",
                    opts.stops
                )));
            }
            // Stops 360 / N degrees apart round the circle (the expression as it always was:
            // recordings stay byte for byte), or spanning the arc end to end.
            let n = opts.stops as f64;
            let start = p.tour_start_deg.to_radians();
            let bearing = |i: usize| match p.tour_arc_deg {
                Some(arc) => start + arc.to_radians() * i as f64 / (n - 1.0),
                None => start + 2.0 * PI * i as f64 / n,
            };
            let approach = p.tour_start_distance_m.map(|d| Stop {
                pose: facing(start, d),
                background: false,
            });
            Ok(approach
                .into_iter()
                .chain((0..opts.stops).map(|i| Stop {
                    pose: facing(bearing(i), p.tour_radius_m),
                    background: false,
                }))
                .collect())
        }
        Kind::Train => {
            if opts.frames == 0 || opts.frames > p.train_views.len() {
                return Err(SimError::Options(format!(
                    "scene {} has {} train views; --frames must be 1 to {}, got {}",
                    scene.name,
                    p.train_views.len(),
                    p.train_views.len(),
                    opts.frames
                )));
            }
            let views = p.train_views[..opts.frames].iter().map(|v| Stop {
                pose: facing(v.bearing_deg.to_radians(), v.distance_m),
                background: false,
            });
            let background = p.background_stops.iter().map(|s| Stop {
                pose: Pose2 {
                    x_m: s.x_m,
                    y_m: s.y_m,
                    yaw_rad: wrap_angle(s.yaw_deg.to_radians()),
                },
                background: true,
            });
            Ok(views.chain(background).collect())
        }
    }
}

/// `base_link -> camera_optical_frame` of the scene's camera.
pub fn base_from_optical(scene: &Scene) -> Iso3 {
    camera_mount(
        scene.camera.mount_m,
        scene.camera.pitch_down_deg.to_radians(),
    )
}

/// The base_link pose of a planar pose.
pub fn iso_from_pose2(p: &Pose2) -> Iso3 {
    iso_from_xy_yaw(p.x_m, p.y_m, p.yaw_rad)
}

/// One true box per (object, instance), in order of first appearance: the bounding box of all
/// its primitives in the yaw of its first box primitive (0 if it has none).
pub fn ground_truth_boxes(scene: &Scene) -> Vec<(String, Iso3, [f64; 3])> {
    let mut keys: Vec<(String, u32)> = Vec::new();
    for p in &scene.primitives {
        if let Some(o) = &p.object {
            let k = (o.clone(), p.instance);
            if !keys.contains(&k) {
                keys.push(k);
            }
        }
    }
    keys.into_iter()
        .map(|(object, instance)| {
            let prims: Vec<&scene::Primitive> = scene
                .primitives
                .iter()
                .filter(|p| p.object.as_deref() == Some(object.as_str()) && p.instance == instance)
                .collect();
            let yaw = prims
                .iter()
                .find_map(|p| match p.shape {
                    Shape::Box { yaw_deg, .. } => Some(yaw_deg.to_radians()),
                    _ => None,
                })
                .unwrap_or(0.0);
            let (lo, hi) = prims.iter().fold(
                (
                    Vector3::repeat(f64::INFINITY),
                    Vector3::repeat(f64::NEG_INFINITY),
                ),
                |(lo, hi), p| {
                    let (a, b) = render::shape_extent_in_yaw(&p.shape, yaw);
                    (lo.inf(&a), hi.sup(&b))
                },
            );
            let c = (lo + hi) * 0.5;
            let rot = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw);
            let center = rot * c;
            let size = hi - lo;
            (
                object,
                Iso3::from_parts(Translation3::from(center), rot),
                [size.x, size.y, size.z],
            )
        })
        .collect()
}

/// Bounding rectangles of the visible pixels of each instance of `object` with at least
/// [`MIN_LABEL_PIXELS`] pixels, in instance order.
pub fn label_regions(
    rendered: &Rendered,
    renderer: &Renderer,
    object: &str,
) -> Vec<RegionOfInterest> {
    let w = rendered.width as usize;
    renderer
        .instances()
        .iter()
        .enumerate()
        .filter(|(_, inst)| inst.object == object)
        .filter_map(|(k, _)| {
            let id = u16::try_from(k + 1).ok()?;
            let mut count = 0usize;
            let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
            for (i, _) in rendered.ids.iter().enumerate().filter(|(_, v)| **v == id) {
                let (x, y) = (i % w, i / w);
                count += 1;
                x0 = x0.min(x);
                y0 = y0.min(y);
                x1 = x1.max(x);
                y1 = y1.max(y);
            }
            (count >= MIN_LABEL_PIXELS).then(|| RegionOfInterest {
                x_offset: x0 as u32,
                y_offset: y0 as u32,
                width: (x1 - x0 + 1) as u32,
                height: (y1 - y0 + 1) as u32,
                do_rectify: false,
            })
        })
        .collect()
}

/// Draws 1-pixel rectangle outlines (green) on a copy of an RGB8 frame, for --dump-frames.
fn draw_regions(width: u32, height: u32, rgb: &[u8], regions: &[RegionOfInterest]) -> Vec<u8> {
    let mut out = rgb.to_vec();
    let (w, h) = (width as usize, height as usize);
    let mut put = |x: usize, y: usize| {
        if x < w && y < h {
            let i = (y * w + x) * 3;
            out[i..i + 3].copy_from_slice(&[0, 255, 0]);
        }
    };
    for r in regions {
        let (x0, y0) = (r.x_offset as usize, r.y_offset as usize);
        let (x1, y1) = (x0 + r.width as usize - 1, y0 + r.height as usize - 1);
        for x in x0..=x1 {
            put(x, y0);
            put(x, y1);
        }
        for y in y0..=y1 {
            put(x0, y);
            put(x1, y);
        }
    }
    out
}

fn frame_jitter(rng: &mut Rng) -> FrameJitter {
    let exposure = 1.0 + EXPOSURE_SIGMA * rng.normal();
    let red = 1.0 + WHITE_BALANCE_SIGMA * rng.normal();
    let blue = 1.0 + WHITE_BALANCE_SIGMA * rng.normal();
    FrameJitter {
        exposure,
        white_balance: [red, 1.0, blue],
        noise_seed: rng.next_u64(),
    }
}

fn pose3(p: &Pose2) -> Pose {
    pose_from_iso(&iso_from_pose2(p))
}

/// Records a simulated session to `out` (via `out.partial`). `progress(done, total)` is
/// called after each frame.
pub fn record(
    scene: &Scene,
    opts: &SimOptions,
    out: &Path,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<RecordStats, SimError> {
    let n = opts.speed_noise;
    if !(n.trans_rel_sigma >= 0.0
        && n.rot_rel_sigma >= 0.0
        && n.trans_rel_sigma < 0.5
        && n.rot_rel_sigma < 0.5)
    {
        return Err(SimError::Options(format!(
            "speed noise {},{} must be fractions in [0, 0.5)",
            n.trans_rel_sigma, n.rot_rel_sigma
        )));
    }
    if n.rot_rel_bias.is_nan() || n.rot_rel_bias.abs() >= 0.5 {
        return Err(SimError::Options(format!(
            "turn bias {} must be a fraction in (-0.5, 0.5)",
            n.rot_rel_bias
        )));
    }
    let stops = plan_stops(scene, opts)?;
    let mut robot_rng = Rng::new(opts.seed ^ ROBOT_STREAM);
    let events = robot::simulate(
        &stops,
        START_NS,
        scene.robot.drive_speed_m_s,
        scene.robot.turn_speed_rad_s,
        opts.speed_noise,
        &mut robot_rng,
    );
    let full = Renderer::new(scene, None);
    let background = Renderer::new(scene, Some(&scene.target));
    if let Some(dir) = &opts.dump_frames {
        std::fs::create_dir_all(dir).map_err(|source| SimError::Io {
            path: dir.clone(),
            source,
        })?;
    }

    let recording = Recording {
        scene,
        opts,
        full: &full,
        background: &background,
        object_names: scene.object_names(),
    };
    let result = recording.write_session(out, &events, progress, stops.len());
    if result.is_err() {
        // An error (unlike a kill) leaves nothing behind: no final file, no partial one.
        let _ = std::fs::remove_file(crate::io::output::partial_path(out));
    }
    result
}

/// What a recording renders with: the scene, the options, and the renderers with and
/// without the target.
struct Recording<'a> {
    scene: &'a Scene,
    opts: &'a SimOptions,
    full: &'a Renderer,
    background: &'a Renderer,
    /// The scene's object names, sorted (the labels of a tour frame).
    object_names: Vec<String>,
}

/// The session being written, and how many messages went into it.
struct Sink {
    writer: SessionWriter,
    topics: Topics,
    messages: usize,
}

/// A frame to take: which stop, when, with or without the target, and where the camera is.
struct Shot {
    index: usize,
    stamp_ns: i64,
    background: bool,
    odom_from_optical: Iso3,
}

impl Recording<'_> {
    /// Writes the session: the static transform and the ground-truth boxes, then every
    /// event of the timeline in order, a frame rendered at each stop.
    fn write_session(
        &self,
        out: &Path,
        events: &[Event],
        progress: &mut dyn FnMut(usize, usize),
        total_frames: usize,
    ) -> Result<RecordStats, SimError> {
        let mut sink = Sink {
            topics: Topics::default(),
            writer: SessionWriter::create(out)?,
            messages: 0,
        };
        sink.write_statics(self.scene)?;
        let mut camera_rng = Rng::new(self.opts.seed ^ CAMERA_STREAM);
        let mut frames = 0usize;
        for ev in events {
            match ev {
                Event::CmdVel {
                    stamp_ns,
                    linear_m_s,
                    angular_rad_s,
                } => sink.write_cmd_vel(*stamp_ns, *linear_m_s, *angular_rad_s)?,
                Event::Pose {
                    stamp_ns,
                    nominal,
                    truth,
                    linear_m_s,
                    angular_rad_s,
                } => {
                    sink.write_poses(*stamp_ns, nominal, truth, *linear_m_s, *angular_rad_s)?;
                    sink.write_head(self.scene, *stamp_ns)?;
                }
                Event::Frame {
                    stamp_ns,
                    index,
                    background,
                    nominal,
                    truth,
                } => {
                    sink.write_poses(*stamp_ns, nominal, truth, 0.0, 0.0)?;
                    sink.write_head(self.scene, *stamp_ns)?;
                    let jitter = frame_jitter(&mut camera_rng);
                    let shot = Shot {
                        index: *index,
                        stamp_ns: *stamp_ns,
                        background: *background,
                        odom_from_optical: iso_from_pose2(truth)
                            * head::mount_at(self.scene, *stamp_ns),
                    };
                    self.write_frame(&mut sink, &shot, &jitter)?;
                    frames += 1;
                    progress(frames, total_frames);
                }
            }
        }
        let path = sink.writer.finish()?;
        Ok(RecordStats {
            path,
            frames,
            messages: sink.messages,
        })
    }

    /// Renders one frame and its labels and writes them (and dumps them when asked to).
    fn write_frame(
        &self,
        sink: &mut Sink,
        shot: &Shot,
        jitter: &FrameJitter,
    ) -> Result<(), SimError> {
        let renderer = if shot.background {
            self.background
        } else {
            self.full
        };
        let rendered = renderer.render(&shot.odom_from_optical, jitter);
        let png = encode_png(rendered.width, rendered.height, &rendered.rgb).map_err(|what| {
            SimError::Encode {
                index: shot.index,
                stamp_ns: shot.stamp_ns,
                what,
            }
        })?;
        let header = Header::new(shot.stamp_ns, CAMERA_FRAME);
        let labels = self.labels(&rendered, renderer, &header);
        if let Some(dir) = &self.opts.dump_frames {
            dump_frame(dir, shot.index, &rendered, &png, &labels)?;
        }
        sink.write_frame(
            &header,
            png,
            self.full.camera(),
            self.full.distortion(),
            &labels,
        )
    }

    /// The labels of a rendered frame: the target's on a train session, every object's on
    /// a tour.
    fn labels(
        &self,
        rendered: &Rendered,
        renderer: &Renderer,
        header: &Header,
    ) -> Vec<ObjectLabel> {
        let target = &self.scene.target;
        match self.opts.kind {
            Kind::Train => vec![ObjectLabel {
                header: header.clone(),
                object: target.clone(),
                regions: label_regions(rendered, renderer, target),
            }],
            Kind::Tour => self
                .object_names
                .iter()
                .map(|o| ObjectLabel {
                    header: header.clone(),
                    object: o.clone(),
                    regions: label_regions(rendered, renderer, o),
                })
                .collect(),
        }
    }
}

impl Sink {
    /// Writes what holds for the whole session: the camera mount (or, with a pan-tilt
    /// head, its fixed link) on /tf_static and the ground-truth boxes.
    fn write_statics(&mut self, scene: &Scene) -> Result<(), SimError> {
        let tf = head::static_transforms(scene);
        self.writer.write(&self.topics.tf_static, START_NS, &tf)?;
        let boxes = ground_truth_boxes(scene);
        let gt = GroundTruth {
            header: Header::new(START_NS, ODOM_FRAME),
            object: boxes.iter().map(|b| b.0.clone()).collect(),
            box_center: boxes.iter().map(|b| pose_from_iso(&b.1)).collect(),
            box_size: boxes.iter().map(|b| b.2).collect(),
        };
        self.writer
            .write(&self.topics.ground_truth_objects, START_NS, &gt)?;
        self.messages += 2;
        Ok(())
    }

    /// Writes a /cmd_vel command.
    fn write_cmd_vel(
        &mut self,
        stamp_ns: i64,
        linear_m_s: f64,
        angular_rad_s: f64,
    ) -> Result<(), SimError> {
        let msg = TwistStamped {
            header: Header::new(stamp_ns, BASE_FRAME),
            twist: Twist {
                linear: [linear_m_s, 0.0, 0.0],
                angular: [0.0, 0.0, angular_rad_s],
            },
        };
        self.writer.write(&self.topics.cmd_vel, stamp_ns, &msg)?;
        self.messages += 1;
        Ok(())
    }

    /// Writes the odometry (nominal) pose with its twist, and the true pose.
    fn write_poses(
        &mut self,
        stamp_ns: i64,
        nominal: &Pose2,
        truth: &Pose2,
        linear_m_s: f64,
        angular_rad_s: f64,
    ) -> Result<(), SimError> {
        let odom = Odometry {
            header: Header::new(stamp_ns, ODOM_FRAME),
            child_frame_id: BASE_FRAME.into(),
            pose: pose3(nominal),
            pose_covariance: [0.0; 36],
            twist: Twist {
                linear: [linear_m_s, 0.0, 0.0],
                angular: [0.0, 0.0, angular_rad_s],
            },
            twist_covariance: [0.0; 36],
        };
        self.writer.write(&self.topics.odom, stamp_ns, &odom)?;
        let gt = PoseStamped {
            header: Header::new(stamp_ns, ODOM_FRAME),
            pose: pose3(truth),
        };
        self.writer
            .write(&self.topics.ground_truth_pose, stamp_ns, &gt)?;
        self.messages += 2;
        Ok(())
    }

    /// Writes the pan-tilt head's joint on /tf at `stamp_ns`, when the camera has a head.
    fn write_head(&mut self, scene: &Scene, stamp_ns: i64) -> Result<(), SimError> {
        if let Some(tf) = head::dynamic_transforms(scene, stamp_ns) {
            self.writer.write(&self.topics.tf, stamp_ns, &tf)?;
            self.messages += 1;
        }
        Ok(())
    }

    /// Writes a frame's image, its camera info and its labels.
    fn write_frame(
        &mut self,
        header: &Header,
        png: Vec<u8>,
        camera: &Camera,
        distortion: Option<&Distortion>,
        labels: &[ObjectLabel],
    ) -> Result<(), SimError> {
        let stamp_ns = header.stamp_ns;
        self.writer.write(
            &self.topics.compressed_image,
            stamp_ns,
            &CompressedImage {
                header: header.clone(),
                format: "png".into(),
                data: png,
            },
        )?;
        let mut info = CameraInfo::pinhole(
            header.clone(),
            camera.width,
            camera.height,
            camera.fx,
            camera.fy,
            camera.cx,
            camera.cy,
        );
        if let Some(d) = distortion {
            info.d = d.to_plumb_bob();
        }
        self.writer
            .write(&self.topics.camera_info, stamp_ns, &info)?;
        for l in labels {
            self.writer.write(&self.topics.labels, stamp_ns, l)?;
        }
        self.messages += 2 + labels.len();
        Ok(())
    }
}

fn dump_frame(
    dir: &Path,
    index: usize,
    rendered: &Rendered,
    png: &[u8],
    labels: &[ObjectLabel],
) -> Result<(), SimError> {
    let io = |path: PathBuf| move |source| SimError::Io { path, source };
    let path = dir.join(format!("frame_{index:03}.png"));
    crate::io::output::write_atomic(&path, png).map_err(io(path.clone()))?;
    let regions: Vec<RegionOfInterest> = labels
        .iter()
        .flat_map(|l| l.regions.iter().copied())
        .collect();
    let boxed = draw_regions(rendered.width, rendered.height, &rendered.rgb, &regions);
    let boxed_png =
        encode_png(rendered.width, rendered.height, &boxed).map_err(|what| SimError::Encode {
            index,
            stamp_ns: 0,
            what,
        })?;
    let path = dir.join(format!("frame_{index:03}_labels.png"));
    crate::io::output::write_atomic(&path, &boxed_png).map_err(io(path.clone()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chair_ground_truth_box_is_the_chair() {
        let s = builtin_scene("chair").unwrap();
        let boxes = ground_truth_boxes(&s);
        assert_eq!(boxes.len(), 1);
        let (name, pose, size) = &boxes[0];
        assert_eq!(name, "chair");
        // Seat 0.45 square, back 0.05 thick at local x -0.2: x from -0.225 to 0.225; legs to
        // the floor; back top at 0.71 + 0.235 = 0.945.
        // The scene file rounds the rotated leg positions to 0.1 mm.
        assert!(
            (size[0] - 0.45).abs() < 1e-4 && (size[1] - 0.45).abs() < 1e-4,
            "{size:?}"
        );
        assert!((size[2] - 0.945).abs() < 1e-9, "{size:?}");
        assert!((pose.translation.z - 0.4725).abs() < 1e-9);
        assert!((crate::types::geometry::yaw_of(pose) - 20f64.to_radians()).abs() < 1e-9);
    }

    #[test]
    fn tour_stops_face_the_target_at_the_radius() {
        let s = builtin_scene("chair").unwrap();
        let stops = plan_stops(&s, &SimOptions::new(Kind::Tour, 1)).unwrap();
        assert_eq!(stops.len(), 8);
        for st in &stops {
            let (dx, dy) = (
                s.path.target_m[0] - st.pose.x_m,
                s.path.target_m[1] - st.pose.y_m,
            );
            assert!((dx.hypot(dy) - s.path.tour_radius_m).abs() < 1e-9);
            assert!(wrap_angle(dy.atan2(dx) - st.pose.yaw_rad).abs() < 1e-9);
        }
        let train = plan_stops(&s, &SimOptions::new(Kind::Train, 1)).unwrap();
        assert_eq!(train.iter().filter(|s| !s.background).count(), 3);
        assert_eq!(train.iter().filter(|s| s.background).count(), 18);
    }

    /// The foreign renderer's tour shape: a first frame 3 m out, then stops spanning a 180
    /// degree arc end to end (8 stops: 180 / 7 degrees apart), all facing the target.
    #[test]
    fn an_approach_and_an_arc() {
        let mut s = builtin_scene("chair").unwrap();
        s.path.tour_start_distance_m = Some(3.0);
        s.path.tour_arc_deg = Some(180.0);
        s.validate().unwrap();
        let stops = plan_stops(&s, &SimOptions::new(Kind::Tour, 1)).unwrap();
        assert_eq!(stops.len(), 9);
        let [tx, ty] = s.path.target_m;
        let polar = |st: &Stop| {
            let (dx, dy) = (st.pose.x_m - tx, st.pose.y_m - ty);
            assert!(wrap_angle(dy.atan2(dx) + PI - st.pose.yaw_rad).abs() < 1e-9);
            (dx.hypot(dy), dy.atan2(dx))
        };
        let start = s.path.tour_start_deg.to_radians();
        let (d0, b0) = polar(&stops[0]);
        assert!((d0 - 3.0).abs() < 1e-9 && wrap_angle(b0 - start).abs() < 1e-9);
        for (i, st) in stops[1..].iter().enumerate() {
            let (d, b) = polar(st);
            assert!((d - s.path.tour_radius_m).abs() < 1e-9);
            let want = start + PI * i as f64 / 7.0;
            assert!(
                wrap_angle(b - want).abs() < 1e-9,
                "stop {i}: {b} against {want}"
            );
        }
        // A start inside the circle, or outside the room, is refused.
        s.path.tour_start_distance_m = Some(1.0);
        assert!(s.validate().unwrap_err().contains("tour_start_distance_m"));
        s.path.tour_start_distance_m = Some(30.0);
        assert!(s.validate().unwrap_err().contains("outside the room"));
    }

    #[test]
    fn label_is_the_bounding_rectangle_of_visible_pixels() {
        let s = builtin_scene("chair").unwrap();
        let r = Renderer::new(&s, None);
        let mut rendered = Rendered {
            width: 4,
            height: 3,
            rgb: vec![0; 36],
            ids: vec![0; 12],
        };
        assert!(label_regions(&rendered, &r, "chair").is_empty());
        // 16 pixels are needed; a 4 x 3 image cannot reach it, so test on a larger buffer.
        rendered.width = 10;
        rendered.height = 10;
        rendered.ids = vec![0; 100];
        for y in 2..6 {
            for x in 3..7 {
                rendered.ids[y * 10 + x] = 1;
            }
        }
        let regions = label_regions(&rendered, &r, "chair");
        assert_eq!(regions.len(), 1);
        assert_eq!(
            (
                regions[0].x_offset,
                regions[0].y_offset,
                regions[0].width,
                regions[0].height
            ),
            (3, 2, 4, 4)
        );
        rendered.ids[23] = 0;
        assert!(label_regions(&rendered, &r, "chair").is_empty());
    }
}
