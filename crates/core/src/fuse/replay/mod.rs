//! Deterministic replay of one session into the belief grid: the fuser's event loop.
//!
//! Pass 1 reads everything but pixels (intrinsics, the camera mount, /odom, /cmd_vel, ground
//! truth) so that every frame's pose can be interpolated from the odometry around its stamp.
//! Pass 2 walks the frames in (log_time, channel id, sequence) order: blur the belief by the
//! commands executed since the previous frame, classify the frame's tiles, integrate them.
//! With pose refinement each frame is first localised against the landmarks of the frames
//! before it and the floor they saw ([`crate::fuse::refine`], [`crate::fuse::floor`]); a localised frame
//! is not blurred. After a refined pass (and its check) every pose may be solved again over
//! the whole replay and the frames fused again at those poses (`smoothing.rs`): kept only when
//! that pass passes its tests, and shown to observers only then.
//! Observers (Rerun, the report) see each step; they cannot change it.
//!
//! Invariants: no clock, no randomness, no unordered iteration: the same session, model and
//! options give a bit-identical grid on every run and thread count. Problems that leave the
//! rest usable (a frame with no pose, a NaN odometry message) are warnings naming the file,
//! topic and log time; problems that make the result meaningless are errors.

mod check;
mod fit;
mod fuser;
mod pass;
mod prepare;
mod session_data;
mod smoothing;
#[cfg(test)]
mod tests;
mod tf;

pub use check::{ROLLBACK_TOLERANCE, RefinementCheck};
pub use fit::{
    FITTED_CELLS_LONGEST_SIDE, Fitted, SessionFit, axes_convergence, fit_to_session, view_bounds,
};
pub use fuser::Fuser;
pub use pass::CORRECTION_RETENTION;
pub use session_data::{
    DEFAULT_BOUNDS_MARGIN_M, DEFAULT_MIN_SIDE_M, FrameRef, SessionData, load_session,
};
pub use smoothing::Smoothing;
pub use tf::{MAX_CHAIN, TfError, TfTree};

use check::check_refinement;
use pass::{Pass, Prior, run_pass};
use prepare::{Context, Prepared, floor_params, prepare, step_image};

use thiserror::Error;

use crate::fuse::grid::{Budget, Grid, GridError, GridSpec, GridStorage};
use crate::fuse::locate::{View, ray_centre};
use crate::fuse::motion::{BlurMode, Segment};
use crate::fuse::objects::{Object, ObjectParams, find_objects_with_cells};
use crate::fuse::refine::Correction;
use crate::io::session::{At, EncodedMedia, SessionError, SessionReader};
use crate::types::geometry::Iso3;
use crate::types::image::Rgb8;
use crate::types::probs::{FrameClassifier, TileProbs};

/// Why a replay failed; each names the session file and, where known, the topic and log time.
#[derive(Debug, Error)]
pub enum ReplayError {
    /// Opening, reading or decoding the session failed.
    #[error(transparent)]
    Session(#[from] SessionError),
    /// The session makes the result meaningless (no CameraInfo, a changing camera, no mount, ...).
    #[error("{at}: {what}")]
    Invalid {
        /// Where in the session: file, and topic and log time when known.
        at: At,
        /// What is wrong, one line.
        what: String,
    },
    /// The grid cannot be built from the options and the session.
    #[error("{path}: grid: {source}")]
    Grid {
        /// The session file.
        path: String,
        /// Why the grid was refused.
        #[source]
        source: GridError,
    },
    /// No frame has both a pose and the camera, so nothing could be fused.
    #[error(
        "{path}: no frame could be fused ({frames} frame(s) in the session, none with a pose and camera)"
    )]
    NothingFused {
        /// The session file.
        path: String,
        /// Frames in the session.
        frames: usize,
    },
    /// A frame's pixels do not decode.
    #[error("{at}: {source}")]
    Frame {
        /// Where the frame is in the session.
        at: At,
        /// Why its pixels do not decode.
        #[source]
        source: crate::io::session::FrameError,
    },
    /// An observer (the viewer, a report writer) failed; its error is the source.
    #[error("{at}: observer failed")]
    Observer {
        /// The frame being observed, or only the file before the first frame.
        at: At,
        /// The observer's own error.
        #[source]
        source: ObserverError,
    },
}

/// What an observer's failure carries: its own typed error, boxed, so the chain is kept.
pub type ObserverError = Box<dyn std::error::Error + Send + Sync>;

/// How to fuse.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FuseOptions {
    /// (min, max) corners in `odom`, metres; `None` = derived from the trajectory.
    pub bounds_m: Option<([f64; 3], [f64; 3])>,
    /// Edge length of a grid cell, metres (default 0.04).
    pub voxel_size_m: f64,
    /// Prior probability of a cell; `None` = the classifier's base rate.
    pub prior: Option<f64>,
    /// Translational speed noise, m/s (paper: sigma_v).
    pub sigma_v_mps: f64,
    /// Rotational speed noise, rad/s (paper: sigma_w).
    pub sigma_w_radps: f64,
    /// What the motion blur averages (default [`BlurMode::LogOdds`]).
    pub blur: BlurMode,
    /// Optional clamp of cell probabilities after each update, e.g. (0.001, 0.999).
    pub clamp: Option<(f64, f64)>,
    /// How objects are found in the belief.
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
    /// Where an object's location comes from: the centre of its extent in the grid, or the
    /// centre triangulated from its detections' boxes ([`crate::fuse::locate`]; the session
    /// chooses it when the grid has no floor below the object). Reports written before it
    /// existed read as the extent.
    #[serde(default)]
    pub locate: Locate,
    /// Which of these the session may choose (see [`fit_to_session`]); reports written before
    /// it existed read as choosing nothing.
    #[serde(default)]
    pub fit: SessionFit,
    /// The range limit of a frame's update: it stops at the depth where a tile's footprint
    /// exceeds this many cells (beyond, one tile's value covers a wall of cells and locates
    /// nothing; see [`crate::fuse::grid::max_depth_m`]); None for no limit. Default
    /// [`DEFAULT_MAX_FOOTPRINT_VOXELS`]; absent from reports written before it existed, which
    /// had no limit.
    #[serde(default)]
    pub max_footprint_voxels: Option<f64>,
    /// Which blocks of the grid are stored (default auto: dense for a room-sized grid, sparse
    /// for a larger one); the grid's values do not depend on it.
    #[serde(default)]
    pub grid_storage: GridStorage,
    /// When refining, solve every pose again over the whole replay after the filter's pass
    /// ([`crate::fuse::refine::smooth`]) and keep those poses when their grid finds as many
    /// objects. On by default; reports written before it existed read as off.
    #[serde(default)]
    pub smooth_poses: bool,
}

/// Where an object's location (`centroid_m`) comes from (`fuse --locate`).
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Default,
    serde::Serialize,
    serde::Deserialize,
    clap::ValueEnum,
)]
#[serde(rename_all = "kebab-case")]
pub enum Locate {
    /// The centre of the object's extent in the grid (the default for a ground robot's
    /// session, whose grid starts at the floor the object stands on).
    #[default]
    Extent,
    /// The centre triangulated from the boxes of its detections, one per frame that sees it
    /// whole; the extent's centre where they do not agree on one (fewer than three frames,
    /// rays from one direction, a point outside the object).
    Detections,
}

/// The default range limit ([`FuseOptions::max_footprint_voxels`]): a tile's update stops
/// where its footprint exceeds this many cells.
pub const DEFAULT_MAX_FOOTPRINT_VOXELS: f64 = 8.0;

/// Where the replay takes the robot poses of frames from (`--poses`).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "kebab-case")]
pub enum PoseSource {
    /// /odom: the robot's dead reckoning (the default, what a real robot has).
    Odometry,
    /// The simulator's /ground_truth/pose; an error for a session that lacks it.
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
            locate: Locate::Extent,
            fit: SessionFit::ALL,
            max_footprint_voxels: Some(DEFAULT_MAX_FOOTPRINT_VOXELS),
            grid_storage: GridStorage::Auto,
            smooth_poses: true,
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
            smooth_poses: self.smooth_poses && self.refine_poses && noisy,
            ..self.clone()
        }
    }
}

/// One fused frame, as observers see it.
#[derive(Debug, Clone)]
pub struct FrameStep {
    /// 0-based count of fused frames.
    pub index: usize,
    /// The session's frame: topic, stamps and raw message index.
    pub frame: FrameRef,
    /// The camera and robot poses the frame was fused with (refined, when refining).
    pub odom_from_camera: Iso3,
    /// The robot pose the frame was fused with (odom_from_base; refined, when refining).
    pub odom_from_base: Iso3,
    /// The robot pose /odom gives for the frame.
    pub odometry: Iso3,
    /// The pose correction, when refining.
    pub correction: Option<Correction>,
    /// The frame's pixels: as recorded where they can be shown as they are.
    pub image: StepImage,
    /// The classifier's tile probabilities for the frame.
    pub probs: TileProbs,
    /// Commands blurred into the belief before this frame.
    pub segments: Vec<Segment>,
    /// Objects found after this frame (the fuse's own rule).
    pub objects: Vec<Object>,
    /// Grid cells the frame's evidence updated (centres projecting into a tile).
    pub cells_updated: usize,
    /// Highest cell probability in the grid after the frame, in [0, 1].
    pub max_probability: f64,
    /// Frames in this pass: the step with `index + 1 == frames` is the last.
    pub frames: usize,
}

/// A fused frame's pixels, as an observer gets them.
#[derive(Debug, Clone, PartialEq)]
pub enum StepImage {
    /// The PNG or JPEG file the session recorded, of CameraInfo's size, with no lens
    /// distortion to remove: the pixels the pass fused, shown without decoding.
    Encoded {
        /// Its format.
        media: EncodedMedia,
        /// The file's bytes.
        bytes: Vec<u8>,
        /// Width, pixels (CameraInfo's).
        width: u32,
        /// Height, pixels (CameraInfo's).
        height: u32,
    },
    /// Decoded (and rectified, for a distorted lens): raw images, other formats, and
    /// sessions whose frames are undistorted before they are fused.
    Decoded(Rgb8),
}

impl StepImage {
    /// Width and height, pixels.
    pub fn size(&self) -> (u32, u32) {
        match self {
            Self::Encoded { width, height, .. } => (*width, *height),
            Self::Decoded(img) => (img.width, img.height),
        }
    }
}

/// Sees the replay; cannot change it.
pub trait Observer {
    /// Called once before the first frame, with the session and a grid at the prior.
    fn on_start(&mut self, _data: &SessionData, _grid: &Grid) -> Result<(), ObserverError> {
        Ok(())
    }
    /// Called after each frame is fused, with the grid as it now is.
    fn on_frame(
        &mut self,
        _data: &SessionData,
        _step: &FrameStep,
        _grid: &Grid,
    ) -> Result<(), ObserverError> {
        Ok(())
    }
    /// The refined pass just seen is rolled back; the frames come again, fused at /odom.
    fn on_rollback(&mut self, _data: &SessionData) -> Result<(), ObserverError> {
        Ok(())
    }
    /// The poses of the pass just seen were solved again over the whole replay and kept; the
    /// frames come again, fused at them.
    fn on_smoothed(&mut self, _data: &SessionData) -> Result<(), ObserverError> {
        Ok(())
    }
    /// Whether [`Observer::on_frame`] is wanted: building a [`FrameStep`] reads the frame
    /// again (and decodes it when it cannot be handed over as recorded), which an observer
    /// of progress alone does not need.
    fn wants_steps(&self) -> bool {
        true
    }
    /// `done` of `total` frames through `stage` (every frame, whatever `wants_steps` says).
    fn on_progress(&mut self, _stage: Stage, _done: usize, _total: usize) {}
}

/// A stage of the replay, for progress.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// Classifying (the first pass, a few frames ahead) and fusing the frames: once per
    /// pass, twice after a rollback.
    Fuse,
}

/// The result of a replay.
#[derive(Debug)]
pub struct Outcome {
    /// The session as pass 1 read it.
    pub data: SessionData,
    /// The final belief.
    pub grid: Grid,
    /// Objects found in the final belief, largest probability mass first (weaker instances after the others).
    pub objects: Vec<Object>,
    /// Flat indices of the final objects' cells, ascending.
    pub object_cells: Vec<usize>,
    /// Frames fused into the grid (those with a pose and the camera).
    pub frames_fused: usize,
    /// Per fused frame: stamp and objects after it.
    pub per_frame: Vec<FrameSummary>,
    /// Problems that left the rest usable, one line each naming file, topic and log time.
    pub warnings: Vec<String>,
    /// The check of the refined poses against /odom, when refining.
    pub refinement: Option<RefinementCheck>,
    /// The options the replay used: the caller's, fitted to the session.
    pub options: FuseOptions,
    /// What the session chose for the caller and why ([`fit_to_session`]), one line each.
    pub choices: Vec<String>,
}

/// One fused frame in brief, as the report keeps it.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FrameSummary {
    /// 0-based count of fused frames.
    pub index: usize,
    /// The frame's header stamp, ns since the Unix epoch.
    pub stamp_ns: i64,
    /// The frame's MCAP log time, ns since the Unix epoch.
    pub log_time_ns: u64,
    /// Robot pose the frame was fused with (refined, when refining).
    pub position_m: [f64; 3],
    /// Heading of that pose about z in `odom`, radians in (-pi, pi].
    pub yaw_rad: f64,
    /// Robot pose from /odom.
    pub odom_position_m: [f64; 3],
    /// Heading of the /odom pose about z, radians in (-pi, pi].
    pub odom_yaw_rad: f64,
    /// The correction refinement applied (none when not refining).
    pub correction: Option<Correction>,
    /// Grid cells the frame's evidence updated.
    pub cells_updated: usize,
    /// Highest cell probability in the grid after the frame, in [0, 1].
    pub max_probability: f64,
    /// Objects found after the frame (the fuse's own rule).
    pub objects: Vec<Object>,
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
    let mut ctx = prepare(reader, classifier, &options.normalised())?;
    ctx.keep_decoded = ctx.data.rectifier.is_some() && observers.iter().any(|o| o.wants_steps());
    let options = &ctx.options.clone();
    for o in observers.iter_mut() {
        // An empty sparse grid: the same cells as the pass's fresh one, none allocated.
        let fresh = Grid::with_storage(ctx.spec, ctx.prior, GridStorage::Sparse, Budget::default())
            .map_err(|e| ctx.grid_err(e))?;
        o.on_start(&ctx.data, &fresh)
            .map_err(|e| ctx.observer_err(None, e))?;
    }
    let first = run_pass(&ctx, options, observers, None)?;
    let mut refinement = None;
    let mut last = if options.refine_poses {
        let check = check_refinement(&ctx, &first);
        let roll = check.rolled_back;
        refinement = Some(check);
        if roll {
            for o in observers.iter_mut() {
                o.on_rollback(&ctx.data)
                    .map_err(|e| ctx.observer_err(None, e))?;
            }
            let plain = FuseOptions {
                refine_poses: false,
                ..options.clone()
            };
            run_pass(&ctx, &plain, observers, Some(Prior::RolledBack(&first)))?
        } else {
            first
        }
    } else {
        first
    };
    if options.refine_poses && options.smooth_poses {
        let rolled_back = refinement.as_ref().is_some_and(|c| c.rolled_back);
        let (kept, report) = smoothing::smooth_pass(&ctx, options, &last, rolled_back)?;
        if let Some(check) = refinement.as_mut() {
            check.smoothing = report;
        }
        if let Some(smoothed) = kept {
            last = show_smoothed(&ctx, options, observers, &last, smoothed)?;
        }
    }
    Ok(finish(ctx, last, refinement))
}

/// Shows the kept smoothed pass to the observers that want steps (fused again with them:
/// the same frames at the same poses give the same grid), or takes it as it is.
fn show_smoothed(
    ctx: &Context<'_>,
    options: &FuseOptions,
    observers: &mut [&mut dyn Observer],
    filtered: &Pass,
    smoothed: Pass,
) -> Result<Pass, ReplayError> {
    for o in observers.iter_mut() {
        o.on_smoothed(&ctx.data)
            .map_err(|e| ctx.observer_err(None, e))?;
    }
    if !observers.iter().any(|o| o.wants_steps()) {
        return Ok(smoothed);
    }
    let plain = FuseOptions {
        refine_poses: false,
        ..options.clone()
    };
    run_pass(
        ctx,
        &plain,
        observers,
        Some(Prior::Smoothed(filtered, &smoothed.poses)),
    )
}

fn finish(ctx: Context<'_>, pass: Pass, refinement: Option<RefinementCheck>) -> Outcome {
    let grid = pass.fuser.grid;
    let with_cells = find_objects_with_cells(&grid, &ctx.options.objects);
    let at_edges = if ctx.options.bounds_m.is_none() {
        objects_at_default_edges(&ctx.data.path, &grid.spec, &with_cells)
    } else {
        Vec::new()
    };
    let mut object_cells: Vec<usize> = with_cells
        .iter()
        .flat_map(|(_, c)| c.iter().copied())
        .collect();
    object_cells.sort_unstable();
    let mut objects: Vec<Object> = with_cells.into_iter().map(|(o, _)| o).collect();
    if ctx.options.locate == Locate::Detections {
        locate_from_detections(&ctx, &pass.poses, &mut objects);
    }
    let mut warnings = ctx.warnings;
    warnings.extend(at_edges);
    // Frames "fused" into a grid none of their views reaches leave it at the prior: say why
    // nothing was found instead of reporting an empty grid as a result.
    if !pass.per_frame.is_empty() && pass.per_frame.iter().all(|f| f.cells_updated == 0) {
        warnings.push(format!(
            "{}: no frame's view reached a cell of the grid (bounds {:?}..{:?}): are the bounds outside what the camera sees?",
            ctx.data.path,
            grid.spec.origin_m,
            grid.spec.max_m()
        ));
    }
    Outcome {
        frames_fused: ctx.prepared.len(),
        data: ctx.data,
        object_cells,
        grid,
        objects,
        per_frame: pass.per_frame,
        warnings,
        refinement,
        options: ctx.options,
        choices: ctx.choices,
    }
}

/// A warning for each object with cells in the outermost layer of a side or the top of the
/// default grid (the box of the camera positions: an object against a wall, beyond where the
/// robot drove, can run past it, and its extent and location are then cut at the side). The
/// floor is where objects stand, so the bottom is not a side.
fn objects_at_default_edges(
    path: &str,
    spec: &GridSpec,
    objects: &[(Object, Vec<usize>)],
) -> Vec<String> {
    let (lo, hi) = (spec.origin_m, spec.max_m());
    let mut out = Vec::new();
    for (k, (_, cells)) in objects.iter().enumerate() {
        // (axis, at its upper end) of each side an object cell lies on.
        let mut sides = std::collections::BTreeSet::new();
        for &c in cells {
            for (a, (i, n)) in spec.ijk(c).into_iter().zip(spec.dims).enumerate() {
                if a < 2 && i == 0 {
                    sides.insert((a, false));
                }
                if i + 1 == n {
                    sides.insert((a, true));
                }
            }
        }
        if sides.is_empty() {
            continue;
        }
        let named: Vec<String> = sides
            .iter()
            .map(|&(a, upper)| {
                let v = if upper { hi[a] } else { lo[a] };
                format!("{} = {v:.2}", ["x", "y", "z"][a])
            })
            .collect();
        out.push(format!(
            "{path}: object {k} reaches the edge of the default grid ({}): it may run past it, and its extent and location are then cut there (the default grid is the box of the camera positions plus {DEFAULT_BOUNDS_MARGIN_M} m; --bounds to widen it)",
            named.join(", ")
        ));
    }
    out
}

/// Replaces each object's location by the centre triangulated from its detections' boxes at
/// the poses the frames were fused with, where the rays agree on one ([`ray_centre`]).
fn locate_from_detections(ctx: &Context<'_>, poses: &[Iso3], objects: &mut [Object]) {
    let views: Vec<View> = ctx
        .prepared
        .iter()
        .zip(poses)
        .map(|(p, pose)| View {
            odom_from_camera: pose * p.mount,
            detections: p.detections().to_vec(),
        })
        .collect();
    for o in objects.iter_mut() {
        match ray_centre(o, &views, &ctx.data.camera) {
            Ok(rc) => {
                o.extent_centre_m = Some(o.centroid_m);
                o.centroid_m = rc.centre_m;
                o.from_detections = Some(rc);
            }
            Err(why) => o.not_from_detections = Some(why.to_string()),
        }
    }
}
