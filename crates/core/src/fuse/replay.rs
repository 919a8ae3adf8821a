//! Deterministic replay of one session into the belief grid: the fuser's event loop.
//!
//! Pass 1 reads everything but pixels (intrinsics, the camera mount, /odom, /cmd_vel, ground
//! truth) so that every frame's pose can be interpolated from the odometry around its stamp.
//! Pass 2 walks the frames in (log_time, channel id, sequence) order: blur the belief by the
//! commands executed since the previous frame, classify the frame's tiles, integrate them.
//! With pose refinement each frame is first localised against the landmarks of the frames
//! before it and the floor they saw ([`crate::fuse::refine`], [`crate::fuse::floor`]); a localised frame
//! is not blurred.
//! Observers (Rerun, the report) see each step; they cannot change it.
//!
//! Invariants: no clock, no randomness, no unordered iteration: the same session, model and
//! options give a bit-identical grid on every run and thread count. Problems that leave the
//! rest usable (a frame with no pose, a NaN odometry message) are warnings naming the file,
//! topic and log time; problems that make the result meaningless are errors.

use nalgebra::Point3;
use thiserror::Error;

use crate::fuse::floor::{FloorMap, FloorParams, FloorPatch, floor_patch};
use crate::fuse::grid::{Grid, GridError, GridSpec, TileEvidence, logit};
use crate::fuse::motion::{BlurMode, Blurrer, Segment, segments_between};
use crate::fuse::objects::{Object, ObjectParams, find_objects, find_objects_with_cells};
use crate::fuse::refine::{
    Consistency, Correction, DETECTION_DELTA, MIN_FLOOR_FIT, Sighting, TotalGate, Verdict,
    detection_clusters, landmarks, motion_covariance, propagate, refine, sightings,
};
use crate::io::msgs::GroundTruth;
use crate::io::session::{At, Role, SessionError, SessionMsg, SessionReader, fmt_ns};
use crate::types::image::Rgb8;
use crate::types::track::PoseTrack;
use crate::types::probs::{FrameClassifier, TileProbs};
use crate::types::geometry::{Camera, Iso3, iso_from_parts, yaw_of};
use crate::io::msgs::iso_from_pose;


#[derive(Debug, Error)]
pub enum ReplayError {
    #[error(transparent)]
    Session(#[from] SessionError),
    #[error("{at}: {what}")]
    Invalid { at: At, what: String },
    #[error("{path}: grid: {source}")]
    Grid {
        path: String,
        #[source]
        source: GridError,
    },
    #[error(
        "{path}: no frame could be fused ({frames} frame(s) in the session, none with a pose and camera)"
    )]
    NothingFused { path: String, frames: usize },
}

/// How to fuse.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FuseOptions {
    /// (min, max) corners in `odom`, metres; `None` = derived from the trajectory.
    pub bounds_m: Option<([f64; 3], [f64; 3])>,
    pub voxel_size_m: f64,
    /// Prior probability of a cell; `None` = the classifier's base rate.
    pub prior: Option<f64>,
    /// Translational speed noise, m/s (paper: sigma_v).
    pub sigma_v_mps: f64,
    /// Rotational speed noise, rad/s (paper: sigma_w).
    pub sigma_w_radps: f64,
    pub blur: BlurMode,
    /// Optional clamp of cell probabilities after each update, e.g. (0.001, 0.999).
    pub clamp: Option<(f64, f64)>,
    pub objects: ObjectParams,
    /// Where frame poses come from: /odom (the default, what a robot has) or the simulator's
    /// /ground_truth/pose (to tell odometry error apart from classifier error).
    pub poses: PoseSource,
    /// Localise each frame against the belief before fusing it (see [`crate::fuse::refine`]). On by
    /// default: measured on held-out-style tours at the default speed noise it takes the
    /// sessions with every object within 0.12 m from 4 to 12 of 12 (docs/fuser.md). With both
    /// sigmas 0 (odometry declared exact) it corrects nothing, and the grid is bit for bit the
    /// plain replay's.
    pub refine_poses: bool,
    /// When refining, also align each frame's view of the floor to the floor seen so far
    /// (see [`crate::fuse::floor`]). Absent from reports written before it existed, which did not.
    #[serde(default)]
    pub refine_floor: bool,
}

#[derive(
    Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "kebab-case")]
pub enum PoseSource {
    Odometry,
    GroundTruth,
}

impl Default for FuseOptions {
    fn default() -> Self {
        Self {
            bounds_m: None,
            voxel_size_m: 0.04,
            prior: None,
            sigma_v_mps: 0.01,
            sigma_w_radps: 0.01,
            blur: BlurMode::LogOdds,
            clamp: None,
            objects: ObjectParams::default(),
            poses: PoseSource::Odometry,
            refine_poses: true,
            refine_floor: true,
        }
    }
}

impl FuseOptions {
    /// The options as the replay applies them: with both speed-noise sigmas 0 the odometry is
    /// declared exact, so there is no motion model to search under and refinement is off
    /// (the replay is then the paper's, bit for bit).
    pub fn normalised(&self) -> FuseOptions {
        let noisy = self.sigma_v_mps > 0.0 || self.sigma_w_radps > 0.0;
        FuseOptions {
            refine_poses: self.refine_poses && noisy,
            ..self.clone()
        }
    }
}

/// Margin around the camera positions for the default bounds, metres.
pub const DEFAULT_BOUNDS_MARGIN_M: f64 = 0.25;
/// Smallest side of the default bounds in x and y, metres (the paper's 4 m grid).
pub const DEFAULT_MIN_SIDE_M: f64 = 4.0;

/// One camera frame of the session, before its pixels are decoded.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameRef {
    /// Index into the reader's raw messages.
    pub raw_index: usize,
    pub topic: String,
    pub log_time_ns: u64,
    pub stamp_ns: i64,
}

/// Everything of a session but the pixels, validated.
#[derive(Debug, Clone)]
pub struct SessionData {
    pub path: String,
    pub camera: Camera,
    pub camera_frame_id: String,
    /// base_link -> camera optical frame, from /tf_static.
    pub base_from_camera: Iso3,
    /// (stamp, odom_from_base), sorted by stamp.
    pub odom: PoseTrack,
    /// (stamp, v m/s, w rad/s), sorted by stamp.
    pub commands: Vec<(i64, f64, f64)>,
    pub frames: Vec<FrameRef>,
    pub ground_truth_poses: PoseTrack,
    pub ground_truth: Option<GroundTruth>,
    pub warnings: Vec<String>,
}

impl SessionData {
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
                let c = (p * self.base_from_camera).translation.vector;
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

/// Pass 1: reads and validates everything but pixels.
pub fn load_session(reader: &SessionReader) -> Result<SessionData, ReplayError> {
    reader.require(Role::CameraInfo)?;
    reader.require(Role::TfStatic)?;
    reader.require(Role::Odom)?;
    reader.require_frames()?;
    let path = reader.path().display().to_string();
    let mut warnings: Vec<String> = reader.warnings.clone();
    let mut camera: Option<(Camera, String)> = None;
    let mut transforms = Vec::new();
    let mut odom: Vec<(i64, Iso3)> = Vec::new();
    let mut commands = Vec::new();
    let mut frames = Vec::new();
    let mut gt_poses = Vec::new();
    let mut ground_truth = None;
    for (raw_index, raw) in reader.raw_messages().iter().enumerate() {
        let Some(m) = reader.decode(raw)? else {
            continue;
        };
        let at = || reader.at(Some(&m.topic), m.log_time_ns);
        match m.msg {
            SessionMsg::CameraInfo(ci) => {
                let cam = Camera::from_info(&ci).ok_or_else(|| ReplayError::Invalid {
                    at: at(),
                    what: format!(
                        "CameraInfo is not a usable pinhole camera (width {}, height {}, K {:?})",
                        ci.width, ci.height, ci.k
                    ),
                })?;
                match &camera {
                    None => camera = Some((cam, ci.header.frame_id.clone())),
                    Some((c, _)) if *c != cam => {
                        return Err(ReplayError::Invalid {
                            at: at(),
                            what: "CameraInfo changes during the session; objloc fuses one camera"
                                .into(),
                        });
                    }
                    Some(_) => {}
                }
            }
            SessionMsg::TfStatic(tf) => {
                for t in tf.transforms {
                    let iso = iso_from_parts(t.translation, t.rotation_xyzw).ok_or_else(|| {
                        ReplayError::Invalid {
                            at: at(),
                            what: format!(
                                "transform {} -> {} is not finite or has a zero quaternion",
                                t.header.frame_id, t.child_frame_id
                            ),
                        }
                    })?;
                    transforms.push((t.header.frame_id, t.child_frame_id, iso));
                }
            }
            SessionMsg::Odom(o) => match iso_from_pose(&o.pose) {
                Some(p) => odom.push((o.header.stamp_ns, p)),
                None => warnings.push(format!(
                    "{}: pose is not finite or has a zero quaternion; message skipped",
                    at()
                )),
            },
            SessionMsg::CmdVel(c) => {
                let (v, w) = (c.twist.linear[0], c.twist.angular[2]);
                if v.is_finite() && w.is_finite() {
                    commands.push((c.header.stamp_ns, v, w));
                } else {
                    warnings.push(format!("{}: twist is not finite; command skipped", at()));
                }
            }
            SessionMsg::Frame(f) => frames.push(FrameRef {
                raw_index,
                topic: m.topic.clone(),
                log_time_ns: m.log_time_ns,
                stamp_ns: f.stamp_ns,
            }),
            SessionMsg::GroundTruthPose(p) => {
                if let Some(iso) = iso_from_pose(&p.pose) {
                    gt_poses.push((p.header.stamp_ns, iso));
                }
            }
            SessionMsg::GroundTruthObjects(g) => ground_truth = Some(g),
            SessionMsg::Label(_) => {}
        }
    }
    let (camera, camera_frame_id) = camera.ok_or_else(|| ReplayError::Invalid {
        at: At {
            path: reader.path().to_owned(),
            topic: Some(reader.topics().camera_info.clone()),
            log_time_ns: None,
        },
        what: "no CameraInfo".into(),
    })?;
    // The mount: the transform to the camera's frame; a bag with a single static transform
    // is taken to mean that one.
    let mount = transforms
        .iter()
        .find(|(_, child, _)| *child == camera_frame_id)
        .or_else(|| (transforms.len() == 1).then(|| &transforms[0]))
        .map(|(_, _, iso)| *iso)
        .ok_or_else(|| ReplayError::Invalid {
            at: At {
                path: reader.path().to_owned(),
                topic: Some(reader.topics().tf_static.clone()),
                log_time_ns: None,
            },
            what: format!(
                "no transform to the camera frame {camera_frame_id:?} (have: {})",
                transforms
                    .iter()
                    .map(|(p, c, _)| format!("{p} -> {c}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        })?;
    if odom.windows(2).any(|w| w[1].0 < w[0].0) {
        warnings.push(format!(
            "{path}: {} stamps go backwards; poses sorted by stamp",
            reader.topics().odom
        ));
    }

    commands.sort_by_key(|(t, _, _)| *t);

    Ok(SessionData {
        path,
        camera,
        camera_frame_id,
        base_from_camera: mount,
        odom: PoseTrack::new(odom),
        commands,
        frames,
        ground_truth_poses: PoseTrack::new(gt_poses),
        ground_truth,
        warnings,
    })
}

/// One fused frame, as observers see it.
#[derive(Debug, Clone)]
pub struct FrameStep {
    /// 0-based count of fused frames.
    pub index: usize,
    pub frame: FrameRef,
    /// The camera and robot poses the frame was fused with (refined, when refining).
    pub odom_from_camera: Iso3,
    pub odom_from_base: Iso3,
    /// The robot pose /odom gives for the frame.
    pub odometry: Iso3,
    /// The pose correction, when refining.
    pub correction: Option<Correction>,
    pub image: Rgb8,
    pub probs: TileProbs,
    /// Commands blurred into the belief before this frame.
    pub segments: Vec<Segment>,
    /// Objects found after this frame (the fuse's own rule).
    pub objects: Vec<Object>,
    pub cells_updated: usize,
}

/// Sees the replay; cannot change it.
pub trait Observer {
    fn on_start(&mut self, _data: &SessionData, _grid: &Grid) -> anyhow::Result<()> {
        Ok(())
    }
    fn on_frame(
        &mut self,
        _data: &SessionData,
        _step: &FrameStep,
        _grid: &Grid,
    ) -> anyhow::Result<()> {
        Ok(())
    }
    /// The refined pass just seen is rolled back; the frames come again, fused at /odom.
    fn on_rollback(&mut self, _data: &SessionData) -> anyhow::Result<()> {
        Ok(())
    }
}

/// The result of a replay.
#[derive(Debug)]
pub struct Outcome {
    pub data: SessionData,
    pub grid: Grid,
    pub objects: Vec<Object>,
    /// Flat indices of the final objects' cells, ascending.
    pub object_cells: Vec<usize>,
    pub frames_fused: usize,
    /// Per fused frame: stamp and objects after it.
    pub per_frame: Vec<FrameSummary>,
    pub warnings: Vec<String>,
    /// The check of the refined poses against /odom, when refining.
    pub refinement: Option<RefinementCheck>,
}

#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FrameSummary {
    pub index: usize,
    pub stamp_ns: i64,
    pub log_time_ns: u64,
    /// Robot pose the frame was fused with (refined, when refining).
    pub position_m: [f64; 3],
    pub yaw_rad: f64,
    /// Robot pose from /odom.
    pub odom_position_m: [f64; 3],
    pub odom_yaw_rad: f64,
    /// The correction refinement applied (none when not refining).
    pub correction: Option<Correction>,
    pub cells_updated: usize,
    pub max_probability: f64,
    pub objects: Vec<Object>,
}

/// The fuser state: grid, blur scratch and options. Takes typed values, returns state.
pub struct Fuser {
    pub grid: Grid,
    pub options: FuseOptions,
    blurrer: Blurrer,
    /// Pose variance accumulated since the first frame (for [`BlurMode::Observation`]):
    /// heading, rad^2, and position, m^2.
    heading_var_rad2: f64,
    position_var_m2: f64,
    evidence: Vec<f32>,
    /// Cells the last [`Fuser::integrate`] updated.
    pub last_cells_updated: usize,
}

impl Fuser {
    pub fn new(spec: GridSpec, prior: f64, options: FuseOptions) -> Result<Self, GridError> {
        let mut grid = Grid::new(spec, prior)?;
        if let Some((lo, hi)) = options.clamp {
            if !(lo > 0.0 && hi < 1.0 && lo < hi) {
                return Err(GridError::Clamp { lo, hi });
            }
            grid.clamp = Some((logit(lo) as f32, logit(hi) as f32));
        }
        Ok(Self {
            grid,
            options,
            blurrer: Blurrer::default(),
            heading_var_rad2: 0.0,
            position_var_m2: 0.0,
            evidence: Vec::new(),
            last_cells_updated: 0,
        })
    }

    /// Blurs the belief by one command segment; `odom_from_base` is the pose at its start.
    pub fn blur(&mut self, seg: &Segment, odom_from_base: &Iso3) {
        let t = seg.duration_s();
        if self.options.blur == BlurMode::Observation {
            // The belief stays; the uncertainty is carried to the next frame's evidence.
            if seg.v_mps != 0.0 {
                self.position_var_m2 += (self.options.sigma_v_mps * t).powi(2);
            }
            if seg.w_radps != 0.0 {
                self.heading_var_rad2 += (self.options.sigma_w_radps * t).powi(2);
            }
            return;
        }
        if seg.v_mps != 0.0 {
            let yaw = yaw_of(odom_from_base);
            self.blurrer.translate(
                &mut self.grid,
                [yaw.cos(), yaw.sin()],
                self.options.sigma_v_mps * t,
                self.options.blur,
            );
        }
        if seg.w_radps != 0.0 {
            let c = odom_from_base.translation.vector;
            self.blurrer.rotate(
                &mut self.grid,
                [c.x, c.y],
                self.options.sigma_w_radps * t,
                self.options.blur,
            );
        }
    }

    /// Drops the pose uncertainty accumulated for [`BlurMode::Observation`]: the next frame's
    /// pose has been measured against the belief.
    pub fn forget_motion(&mut self) {
        self.heading_var_rad2 = 0.0;
        self.position_var_m2 = 0.0;
    }

    /// Integrates one frame's tile probabilities seen from `odom_from_camera`.
    /// `odom_from_base` is the robot's pose, the centre of heading uncertainty.
    pub fn integrate(
        &mut self,
        odom_from_camera: &Iso3,
        odom_from_base: &Iso3,
        camera: &Camera,
        probs: &TileProbs,
    ) -> usize {
        let ev = TileEvidence::from_probabilities(
            probs.rows,
            probs.cols,
            probs.tile_px,
            &probs.p,
            self.grid.prior,
        );
        let camera_from_odom = odom_from_camera.inverse();
        if self.options.blur != BlurMode::Observation {
            return self.grid.integrate(&camera_from_odom, camera, &ev);
        }
        let n = self
            .grid
            .frame_evidence(&camera_from_odom, camera, &ev, &mut self.evidence);
        let c = odom_from_base.translation.vector;
        self.blurrer.spread_evidence(
            &self.grid.spec,
            &mut self.evidence,
            [c.x, c.y],
            self.heading_var_rad2.sqrt(),
            self.position_var_m2.sqrt(),
        );
        self.grid.add_evidence(&self.evidence);
        n
    }
}

/// A frame that will be fused: its reference, its /odom pose and its tile probabilities.
struct Prepared {
    frame: FrameRef,
    odometry: Iso3,
    probs: TileProbs,
    /// The frame's floor, when refining with the floor.
    floor: FloorPatch,
    /// Its detection clusters (pixels), when refining.
    clusters: Vec<[f64; 2]>,
}

/// Everything a pass over the frames needs, read and classified once.
struct Context<'a> {
    reader: &'a SessionReader,
    data: SessionData,
    spec: GridSpec,
    prior: f64,
    prepared: Vec<Prepared>,
    warnings: Vec<String>,
}

/// Replays `reader` with `classifier` into a grid, telling `observers` each step.
///
/// With pose refinement the replay is checked afterwards: when its poses explain the
/// frames' detections worse than /odom's do ([`crate::fuse::refine::Consistency`]), it is rolled
/// back: replayed at the /odom poses, the observers seeing the second pass after
/// [`Observer::on_rollback`], and every frame it had corrected marked
/// [`Verdict::RolledBack`].
pub fn replay(
    reader: &SessionReader,
    classifier: &dyn FrameClassifier,
    options: &FuseOptions,
    observers: &mut [&mut dyn Observer],
) -> Result<Outcome, ReplayError> {
    let options = &options.normalised();
    let ctx = prepare(reader, classifier, options)?;
    for o in observers.iter_mut() {
        o.on_start(
            &ctx.data,
            &Grid::new(ctx.spec, ctx.prior).map_err(|e| ctx.grid_err(e))?,
        )
        .map_err(|e| ctx.observer_err(None, &e))?;
    }
    let first = run_pass(&ctx, options, observers, None)?;
    let mut refinement = None;
    let last = if options.refine_poses {
        let check = check_refinement(&ctx, &first);
        let roll = check.rolled_back;
        refinement = Some(check);
        if roll {
            for o in observers.iter_mut() {
                o.on_rollback(&ctx.data)
                    .map_err(|e| ctx.observer_err(None, &e))?;
            }
            let plain = FuseOptions {
                refine_poses: false,
                ..options.clone()
            };
            run_pass(&ctx, &plain, observers, Some(&first))?
        } else {
            first
        }
    } else {
        first
    };
    Ok(finish(ctx, last, refinement))
}

impl Context<'_> {
    fn grid_err(&self, source: GridError) -> ReplayError {
        ReplayError::Grid {
            path: self.data.path.clone(),
            source,
        }
    }

    fn observer_err(&self, fr: Option<&FrameRef>, e: &anyhow::Error) -> ReplayError {
        ReplayError::Invalid {
            at: match fr {
                Some(fr) => self.reader.at(Some(&fr.topic), fr.log_time_ns),
                None => At {
                    path: self.reader.path().to_owned(),
                    topic: None,
                    log_time_ns: None,
                },
            },
            what: format!("observer failed: {e:#}"),
        }
    }
}

/// Reads the session, checks the options against it, and classifies every frame that can be
/// fused (the floor patch and detection clusters too, when refining).
fn prepare<'a>(
    reader: &'a SessionReader,
    classifier: &dyn FrameClassifier,
    options: &FuseOptions,
) -> Result<Context<'a>, ReplayError> {
    let mut data = load_session(reader)?;
    if options.poses == PoseSource::GroundTruth {
        if data.ground_truth_poses.is_empty() {
            return Err(ReplayError::Invalid {
                at: At {
                    path: reader.path().to_owned(),
                    topic: Some(reader.topics().ground_truth_pose.clone()),
                    log_time_ns: None,
                },
                what: "--poses ground-truth asks for poses this session does not have".into(),
            });
        }
        data.odom = data.ground_truth_poses.clone();
    }
    let warnings = data.warnings.clone();
    let (lo, hi) = match options.bounds_m {
        Some(b) => b,
        None => data
            .default_bounds()
            .ok_or_else(|| ReplayError::NothingFused {
                path: data.path.clone(),
                frames: data.frames.len(),
            })?,
    };
    let grid_err = |source| ReplayError::Grid {
        path: data.path.clone(),
        source,
    };
    let spec = GridSpec::from_bounds(lo, hi, options.voxel_size_m).map_err(grid_err)?;
    let prior = options.prior.unwrap_or_else(|| classifier.base_rate());
    // Checked before the frames are read, so a bad option fails fast.
    Fuser::new(spec, prior, options.clone()).map_err(grid_err)?;
    let mut ctx = Context {
        reader,
        data,
        spec,
        prior,
        prepared: Vec::new(),
        warnings,
    };
    classify_frames(&mut ctx, classifier, options)?;
    if ctx.prepared.is_empty() {
        return Err(ReplayError::NothingFused {
            path: ctx.data.path.clone(),
            frames: ctx.data.frames.len(),
        });
    }
    Ok(ctx)
}

/// Every frame that can be fused, classified once; frames without a pose or going back in
/// time are skipped with a warning.
fn classify_frames(
    ctx: &mut Context<'_>,
    classifier: &dyn FrameClassifier,
    options: &FuseOptions,
) -> Result<(), ReplayError> {
    let reader = ctx.reader;
    let floor_params = floor_params(options);
    for fr in &ctx.data.frames {
        let at = || reader.at(Some(&fr.topic), fr.log_time_ns);
        let Some(odometry) = ctx.data.odom_at(fr.stamp_ns) else {
            ctx.warnings.push(format!(
                "{}: no {} pose within 50 ms of stamp {}; frame skipped",
                at(),
                reader.topics().odom,
                fmt_ns(fr.stamp_ns.max(0) as u64)
            ));
            continue;
        };
        if ctx
            .prepared
            .last()
            .is_some_and(|p| fr.stamp_ns < p.frame.stamp_ns)
        {
            ctx.warnings.push(format!(
                "{}: frame stamp goes backwards; frame skipped",
                at()
            ));
            continue;
        }
        let image = decode_frame(reader, &ctx.data, fr)?;
        let probs = classifier.classify(&image);
        let floor = match &floor_params {
            Some(fp) => {
                // The object is not floor: its detections (the tiles the landmarks use) are
                // left out; they would pull the pose by their own projection onto the
                // floor behind the object, which differs from every view (measured: the
                // largest move of exact odometry falls from 0.060 to 0.048 m).
                let t = probs.tile_px.max(1);
                let min_logit = logit(ctx.prior) + f64::from(DETECTION_DELTA);
                let not_floor = |u: u32, v: u32| {
                    let (r, c) = ((v / t) as usize, (u / t) as usize);
                    r < probs.rows
                        && c < probs.cols
                        && logit(f64::from(probs.p[r * probs.cols + c])) >= min_logit
                };
                floor_patch(
                    &image,
                    &ctx.data.camera,
                    &ctx.data.base_from_camera,
                    fp,
                    not_floor,
                )
            }
            None => FloorPatch::default(),
        };
        let clusters = if options.refine_poses {
            detection_clusters(&TileEvidence::from_probabilities(
                probs.rows,
                probs.cols,
                probs.tile_px,
                &probs.p,
                ctx.prior,
            ))
        } else {
            Vec::new()
        };
        ctx.prepared.push(Prepared {
            frame: fr.clone(),
            odometry,
            probs,
            floor,
            clusters,
        });
    }
    Ok(())
}

/// One pass over the prepared frames: its grid, the poses it fused with, the floor's state.
struct Pass {
    fuser: Fuser,
    poses: Vec<Iso3>,
    per_frame: Vec<FrameSummary>,
    /// The frame from which the floor term was dropped (it no longer fit), if it was.
    floor_dropped_at: Option<usize>,
}

/// What a pass carries from frame to frame when it refines poses.
struct Tracker {
    /// Rays through the detections of the frames fused so far.
    seen: Vec<Sighting>,
    floor_map: Option<FloorMap>,
    /// Frames whose floor did not fit the map (see [`MAX_FLOOR_FAILURES`]).
    floor_failures: usize,
    /// Covariance of /odom's error since the first frame (the total correction's gate).
    total_cov: nalgebra::Matrix3<f64>,
}

/// A replay stops using the floor once this many frames' floors did not fit the map at
/// their best pose ([`crate::fuse::refine::MIN_FLOOR_FIT`]): the camera is then not looking at a
/// floor but at furniture, a counter or a wall in front of it. One such frame alone is
/// common on our own tours (a table in view, a frame close to the object); two were not seen
/// on any of them (docs/fuser.md).
pub const MAX_FLOOR_FAILURES: usize = 2;

/// One pass over the frames; `rolled_back` is the refined pass this one replaces at /odom,
/// whose corrections its frames carry as [`Verdict::RolledBack`] (those it had accepted).
fn run_pass(
    ctx: &Context<'_>,
    options: &FuseOptions,
    observers: &mut [&mut dyn Observer],
    rolled_back: Option<&Pass>,
) -> Result<Pass, ReplayError> {
    let fuser = Fuser::new(ctx.spec, ctx.prior, options.clone()).map_err(|e| ctx.grid_err(e))?;
    let floor_map = floor_params(options).map(|fp| {
        let reach = fp.max_range_m + 1.0;
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for p in &ctx.prepared {
            let t = p.odometry.translation.vector;
            lo = [lo[0].min(t.x - reach), lo[1].min(t.y - reach)];
            hi = [hi[0].max(t.x + reach), hi[1].max(t.y + reach)];
        }
        FloorMap::new(lo, hi, fp)
    });
    let mut pass = Pass {
        fuser,
        poses: Vec::with_capacity(ctx.prepared.len()),
        per_frame: Vec::with_capacity(ctx.prepared.len()),
        floor_dropped_at: None,
    };
    let mut tracker = Tracker {
        seen: Vec::new(),
        floor_map,
        floor_failures: 0,
        total_cov: nalgebra::Matrix3::zeros(),
    };
    for index in 0..ctx.prepared.len() {
        let undone = rolled_back
            .and_then(|r| r.per_frame.get(index))
            .and_then(|f| f.correction)
            .map(|c| match c.outcome {
                Verdict::Accepted => Correction {
                    applied: false,
                    outcome: Verdict::RolledBack,
                    ..c
                },
                _ => c,
            });
        step(
            ctx,
            options,
            &mut pass,
            &mut tracker,
            index,
            undone,
            observers,
        )?;
    }
    Ok(pass)
}

/// Localises (when refining), fuses and observes frame `index`; `undone` is the correction
/// of a rolled-back pass the frame carries instead (it is fused at /odom).
#[allow(clippy::too_many_arguments)]
fn step(
    ctx: &Context<'_>,
    options: &FuseOptions,
    pass: &mut Pass,
    tracker: &mut Tracker,
    index: usize,
    undone: Option<Correction>,
    observers: &mut [&mut dyn Observer],
) -> Result<(), ReplayError> {
    let p = &ctx.prepared[index];
    let data = &ctx.data;
    let mut floor_unfit = false;
    let correction = match index.checked_sub(1) {
        Some(prev) if options.refine_poses => {
            let segs: Vec<(Segment, Iso3)> = segments_between(
                &data.commands,
                ctx.prepared[prev].frame.stamp_ns,
                p.frame.stamp_ns,
            )
            .into_iter()
            .map(|seg| (seg, data.odom_at(seg.start_ns).unwrap_or(p.odometry)))
            .collect();
            tracker.total_cov = propagate(
                tracker.total_cov,
                &segs,
                options.sigma_v_mps,
                options.sigma_w_radps,
            );
            let (c, predicted) = localise(
                &pass.fuser.grid,
                data,
                options,
                &ctx.prepared,
                &pass.poses,
                &tracker.seen,
                index,
                tracker.floor_map.as_ref(),
                &TotalGate {
                    odometry: p.odometry,
                    covariance: tracker.total_cov,
                },
            );
            pass.poses.push(c.apply(&predicted));
            if tracker.floor_map.is_some() && c.floor_fit.is_some_and(|f| f[0] < MIN_FLOOR_FIT) {
                // Nor is it added to the map: what it shows is not the floor the map holds.
                floor_unfit = true;
                tracker.floor_failures += 1;
                if tracker.floor_failures >= MAX_FLOOR_FAILURES {
                    tracker.floor_map = None;
                    pass.floor_dropped_at = Some(index);
                }
            }
            Some(c)
        }
        _ => {
            pass.poses.push(p.odometry);
            undone
        }
    };
    let odom_from_base = pass.poses[index];
    if options.refine_poses {
        tracker.seen.extend(sightings(
            index,
            &p.clusters,
            &data.camera,
            &(odom_from_base * data.base_from_camera),
        ));
    }
    if let Some(map) = tracker.floor_map.as_mut().filter(|_| !floor_unfit) {
        map.add(&p.floor, &odom_from_base);
    }
    // A frame whose pose was measured (corrected, or found where it was predicted) is not
    // blurred: the measurement replaces the motion model's spread.
    let localised = options.refine_poses && correction.is_some_and(|c| c.outcome.measured());
    let segments = fuse_one(
        &mut pass.fuser,
        data,
        &ctx.prepared,
        &pass.poses,
        index,
        localised,
    );
    let objects = find_objects(&pass.fuser.grid, &options.objects);
    let cells_updated = pass.fuser.last_cells_updated;
    if !observers.is_empty() {
        let fr = &p.frame;
        let step = FrameStep {
            index,
            frame: fr.clone(),
            odom_from_camera: odom_from_base * data.base_from_camera,
            odom_from_base,
            odometry: p.odometry,
            correction,
            image: decode_frame(ctx.reader, data, fr)?,
            probs: p.probs.clone(),
            segments,
            cells_updated,
            objects: objects.clone(),
        };
        for o in observers.iter_mut() {
            o.on_frame(data, &step, &pass.fuser.grid)
                .map_err(|e| ctx.observer_err(Some(fr), &e))?;
        }
    }
    pass.per_frame.push(summary(
        p,
        index,
        &odom_from_base,
        correction,
        cells_updated,
        &pass.fuser.grid,
        objects,
    ));
    Ok(())
}

fn summary(
    p: &Prepared,
    index: usize,
    odom_from_base: &Iso3,
    correction: Option<Correction>,
    cells_updated: usize,
    grid: &Grid,
    objects: Vec<Object>,
) -> FrameSummary {
    let max_l = grid
        .log_odds
        .iter()
        .copied()
        .fold(f32::NEG_INFINITY, f32::max);
    let base = odom_from_base.translation.vector;
    let odo = p.odometry.translation.vector;
    FrameSummary {
        index,
        stamp_ns: p.frame.stamp_ns,
        log_time_ns: p.frame.log_time_ns,
        position_m: [base.x, base.y, base.z],
        yaw_rad: yaw_of(odom_from_base),
        odom_position_m: [odo.x, odo.y, odo.z],
        odom_yaw_rad: yaw_of(&p.odometry),
        correction,
        cells_updated,
        max_probability: crate::fuse::grid::sigmoid(f64::from(max_l)),
        objects,
    }
}

/// Compares how well the refined poses and the /odom poses explain the frames: the rays
/// through every frame's detections, gathered per final object and triangulated, and the
/// floor the frames saw (when the floor term was used to the end).
fn check_refinement(ctx: &Context<'_>, pass: &Pass) -> RefinementCheck {
    let data = &ctx.data;
    let objects = find_objects(&pass.fuser.grid, &pass.fuser.options.objects);
    let seeds: Vec<[f64; 3]> = objects.iter().map(|o| o.mass_centroid_m).collect();
    let odometry: Vec<Iso3> = ctx.prepared.iter().map(|p| p.odometry).collect();
    // The /odom rays may pass as far from the refined objects as the poses differ.
    let moved_m = pass
        .poses
        .iter()
        .zip(&odometry)
        .map(|(a, b)| (a.translation.vector - b.translation.vector).xy().norm())
        .fold(0.0, f64::max);
    let rays = |poses: &[Iso3]| -> Vec<Sighting> {
        ctx.prepared
            .iter()
            .zip(poses)
            .enumerate()
            .flat_map(|(i, (p, pose))| {
                sightings(
                    i,
                    &p.clusters,
                    &data.camera,
                    &(pose * data.base_from_camera),
                )
            })
            .collect()
    };
    let gate = crate::fuse::refine::GATE_M + moved_m;
    let refined = Consistency::of(&seeds, &rays(&pass.poses), data.camera.fx, gate);
    let odom = Consistency::of(&seeds, &rays(&odometry), data.camera.fx, gate);
    let floor = floor_params(&pass.fuser.options)
        .filter(|_| pass.floor_dropped_at.is_none())
        .map(|fp| {
            let disagreement = |poses: &[Iso3]| {
                let patches: Vec<(&FloorPatch, &Iso3)> =
                    ctx.prepared.iter().map(|p| &p.floor).zip(poses).collect();
                crate::fuse::floor::disagreement(&patches, fp)
            };
            [disagreement(&pass.poses), disagreement(&odometry)]
        });
    // Each kind of evidence can be worse at the refined poses while the other is better: on
    // a tour whose /odom drift is a turn about the object, the rays meet as well at /odom, and
    // only the floor shows the drift. A replay is rolled back when one is worse and the other
    // no better.
    let rays_worse = refined.worse_than(&odom);
    let rays_better = odom.worse_than(&refined);
    let floor_worse = floor.is_some_and(|[r, o]| r > o * (1.0 + ROLLBACK_TOLERANCE));
    let floor_better = floor.is_some_and(|[r, o]| o > r * (1.0 + ROLLBACK_TOLERANCE));
    let rolled_back =
        pass.poses != odometry && ((rays_worse && !floor_better) || (floor_worse && !rays_better));
    RefinementCheck {
        refined_rays: refined,
        odometry_rays: odom,
        floor_disagreement: floor,
        floor_dropped_at: pass.floor_dropped_at,
        rolled_back,
        reason: if !rolled_back {
            None
        } else if rays_worse {
            Some(format!(
                "the refined poses explain the detections worse than /odom (mean ray chi-square {:.2} against {:.2})",
                refined.mean_chi2, odom.mean_chi2
            ))
        } else {
            floor.map(|[r, o]| {
                format!("the floor seen at the refined poses disagrees with itself more than at /odom ({r:.3} against {o:.3})")
            })
        },
    }
}

/// How much worse (relative) the refined replay may explain the floor than /odom before it
/// is rolled back.
pub const ROLLBACK_TOLERANCE: f64 = 0.05;

/// The check of a refined replay against /odom, as the report gives it.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RefinementCheck {
    /// Rays through the detections at the refined poses, per final object.
    pub refined_rays: Consistency,
    /// The same rays at the /odom poses.
    pub odometry_rays: Consistency,
    /// Mean disagreement of the floor across views (variance over the colour noise), at the
    /// refined and at the /odom poses; absent when the floor term was not used to the end.
    pub floor_disagreement: Option<[f64; 2]>,
    /// The frame from which the floor term was dropped because the floor no longer fit.
    pub floor_dropped_at: Option<usize>,
    /// Whether the replay fell back to /odom.
    pub rolled_back: bool,
    /// Why, in words.
    pub reason: Option<String>,
}

fn finish(ctx: Context<'_>, pass: Pass, refinement: Option<RefinementCheck>) -> Outcome {
    let grid = pass.fuser.grid;
    let options = pass.fuser.options;
    let with_cells = find_objects_with_cells(&grid, &options.objects);
    let mut object_cells: Vec<usize> = with_cells
        .iter()
        .flat_map(|(_, c)| c.iter().copied())
        .collect();
    object_cells.sort_unstable();
    let objects = with_cells.into_iter().map(|(o, _)| o).collect();
    Outcome {
        frames_fused: ctx.prepared.len(),
        data: ctx.data,
        object_cells,
        grid,
        objects,
        per_frame: pass.per_frame,
        warnings: ctx.warnings,
        refinement,
    }
}

/// Decodes a frame and checks its size against CameraInfo.
fn decode_frame(
    reader: &SessionReader,
    data: &SessionData,
    fr: &FrameRef,
) -> Result<Rgb8, ReplayError> {
    let at = || reader.at(Some(&fr.topic), fr.log_time_ns);
    let raw = &reader.raw_messages()[fr.raw_index];
    let frame = match reader.decode(raw)?.map(|m| m.msg) {
        Some(SessionMsg::Frame(f)) => f,
        _ => {
            return Err(ReplayError::Invalid {
                at: at(),
                what: "not a frame".into(),
            });
        }
    };
    let image = frame
        .decode_rgb8()
        .map_err(|what| ReplayError::Invalid { at: at(), what })?;
    if (image.width, image.height) != (data.camera.width, data.camera.height) {
        return Err(ReplayError::Invalid {
            at: at(),
            what: format!(
                "image is {} x {} but CameraInfo says {} x {}",
                image.width, image.height, data.camera.width, data.camera.height
            ),
        });
    }
    Ok(image)
}

/// Fraction of the accumulated correction (refined pose against odometry) a frame carries
/// to the next. Below 1 so that what one object cannot observe (sliding around it) does
/// not random-walk: measured on a 200-frame chair tour, carrying all of it took the refined
/// trajectory 1.4 m and 30 degrees off (ATE 0.94 m against odometry's 0.17 m); at 0.95 the
/// refined ATE is odometry's and the object error falls from 0.31 to 0.22 m, while the
/// 8-frame tours change by at most 0.01-0.02 m (docs/fuser.md).
pub const CORRECTION_RETENTION: f64 = 0.95;

/// The correction frame `prev` carries forward, as a transform of `odom`:
/// [`CORRECTION_RETENTION`] of its heading and position offsets from odometry; `None` when
/// its pose is the odometry's, so that a replay that corrected nothing fuses at the odometry
/// poses bit for bit (`pose * odometry^-1` and a product with the identity both round).
fn carried_correction(prepared: &[Prepared], poses: &[Iso3], prev: usize) -> Option<Iso3> {
    if poses[prev] == prepared[prev].odometry {
        return None;
    }
    let full = poses[prev] * prepared[prev].odometry.inverse();
    Some(Iso3::from_parts(
        nalgebra::Translation3::from(full.translation.vector * CORRECTION_RETENTION),
        nalgebra::UnitQuaternion::from_axis_angle(
            &nalgebra::Vector3::z_axis(),
            yaw_of(&full) * CORRECTION_RETENTION,
        ),
    ))
}

/// `pose` moved by the `carried` correction, if any.
fn moved(carried: Option<&Iso3>, pose: &Iso3) -> Iso3 {
    carried.map_or(*pose, |c| c * pose)
}

/// Localises frame `index` against the landmarks before it is fused (see
/// [`crate::fuse::refine`]); `poses` holds the poses of the frames before it, `seen` the rays
/// through their detections. Returns the correction and the pose it corrects (the previous
/// frame's pose moved by the odometry increment since).
#[allow(clippy::too_many_arguments)]
fn localise(
    grid: &Grid,
    data: &SessionData,
    options: &FuseOptions,
    prepared: &[Prepared],
    poses: &[Iso3],
    seen: &[Sighting],
    index: usize,
    floor_map: Option<&FloorMap>,
    gate: &TotalGate,
) -> (Correction, Iso3) {
    let clusters = &prepared[index].clusters;
    let prev = index - 1;
    let p = &prepared[index];
    // Motion since the previous frame, each segment with its start pose moved by the
    // correction carried from the previous frame (its heading turns speed error sideways).
    let drift = carried_correction(prepared, poses, prev);
    let segments: Vec<(Segment, Iso3)> = segments_between(
        &data.commands,
        prepared[prev].frame.stamp_ns,
        p.frame.stamp_ns,
    )
    .into_iter()
    .map(|seg| {
        let pose = moved(
            drift.as_ref(),
            &data.odom_at(seg.start_ns).unwrap_or(p.odometry),
        );
        (seg, pose)
    })
    .collect();
    let cov = motion_covariance(&segments, options.sigma_v_mps, options.sigma_w_radps);
    // The belief's objects, requiring only as many views as there have been frames, tell
    // which rays belong together.
    let params = ObjectParams {
        min_views: options
            .objects
            .min_views
            .min(u16::try_from(index).unwrap_or(u16::MAX)),
        ..options.objects
    };
    let centroids: Vec<[f64; 3]> = find_objects(grid, &params)
        .into_iter()
        .map(|o| o.mass_centroid_m)
        .collect();
    let predicted = moved(drift.as_ref(), &p.odometry);
    let correction = refine(
        &landmarks(&centroids, seen, data.camera.fx),
        clusters,
        &data.camera,
        &data.base_from_camera,
        &predicted,
        &cov,
        floor_map.map(|m| (m, &p.floor)),
        Some(gate),
    );
    (correction, predicted)
}

/// The floor term's settings, when refining with the floor.
fn floor_params(options: &FuseOptions) -> Option<FloorParams> {
    (options.refine_poses && options.refine_floor).then(FloorParams::default)
}

/// Blurs by the motion since the previous prepared frame, then integrates frame `index` at
/// `poses[index]`; returns the blurred segments. A `localised` frame is not blurred: its
/// pose was measured against the landmarks, which replaces the motion model's spread (what
/// is left is a few pixels, below a cell at these ranges; measured in docs/fuser.md).
fn fuse_one(
    fuser: &mut Fuser,
    data: &SessionData,
    prepared: &[Prepared],
    poses: &[Iso3],
    index: usize,
    localised: bool,
) -> Vec<Segment> {
    let p = &prepared[index];
    let odom_from_base = poses[index];
    // Motion since the previous frame blurs the belief (nothing before the first one: the
    // first frame anchors the belief). Segment poses come from odometry, moved by this
    // frame's correction.
    let segments = match index.checked_sub(1) {
        Some(_) if localised => {
            fuser.forget_motion();
            Vec::new()
        }
        Some(prev) => segments_between(
            &data.commands,
            prepared[prev].frame.stamp_ns,
            p.frame.stamp_ns,
        ),
        None => Vec::new(),
    };
    // Exactly the identity when the pose is the odometry, so that a replay without
    // refinement is not perturbed by rounding.
    let drift = if odom_from_base == p.odometry {
        Iso3::identity()
    } else {
        odom_from_base * p.odometry.inverse()
    };
    for seg in &segments {
        let pose = drift * data.odom_at(seg.start_ns).unwrap_or(p.odometry);
        fuser.blur(seg, &pose);
    }
    let odom_from_camera = odom_from_base * data.base_from_camera;
    fuser.last_cells_updated =
        fuser.integrate(&odom_from_camera, &odom_from_base, &data.camera, &p.probs);
    segments
}

/// Position of a point of `odom` in the camera image at `odom_from_camera`, if in front.
pub fn project_point(camera: &Camera, odom_from_camera: &Iso3, p: [f64; 3]) -> Option<(f64, f64)> {
    camera.project(&(odom_from_camera.inverse() * Point3::new(p[0], p[1], p[2])))
}

