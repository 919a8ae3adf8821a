//! Preparing a replay: the session read, the options checked against it, and every frame
//! that can be fused classified once (with its detections, when refining; floor patches are
//! made by the pass, a few frames ahead of their use).

use crate::fuse::floor::{FloorParams, FloorPatch, floor_patch};
use crate::fuse::grid::{GridError, GridSpec, TileEvidence, logit};
use crate::fuse::refine::{DETECTION_DELTA, detection_clusters};
use crate::io::session::{At, SessionMsg, SessionReader, fmt_ns};
use crate::types::geometry::Iso3;
use crate::types::image::Rgb8;
use crate::types::probs::{FrameClassifier, TileProbs};

use super::*;

/// A frame that will be fused: its reference, its /odom pose and its tile probabilities.
pub(super) struct Prepared {
    pub(super) frame: FrameRef,
    pub(super) odometry: Iso3,
    /// The camera mount at the frame's stamp (base_from_camera).
    pub(super) mount: Iso3,
    pub(super) probs: TileProbs,
    /// Its detection clusters (pixels), when refining.
    pub(super) clusters: Vec<[f64; 2]>,
}

/// Everything a pass over the frames needs, read and classified once.
pub(super) struct Context<'a> {
    pub(super) reader: &'a SessionReader,
    pub(super) data: SessionData,
    pub(super) spec: GridSpec,
    pub(super) prior: f64,
    pub(super) prepared: Vec<Prepared>,
    pub(super) warnings: Vec<String>,
    /// The caller's options fitted to the session: what every pass uses.
    pub(super) options: FuseOptions,
    /// What the session chose and why.
    pub(super) choices: Vec<String>,
}

impl Context<'_> {
    pub(super) fn grid_err(&self, source: GridError) -> ReplayError {
        ReplayError::Grid {
            path: self.data.path.clone(),
            source,
        }
    }

    pub(super) fn observer_err(&self, fr: Option<&FrameRef>, source: ObserverError) -> ReplayError {
        ReplayError::Observer {
            at: match fr {
                Some(fr) => self.reader.at(Some(&fr.topic), fr.log_time_ns),
                None => At {
                    path: self.reader.path().to_owned(),
                    topic: None,
                    log_time_ns: None,
                },
            },
            source,
        }
    }
}

/// Reads the session, checks the options against it, and classifies every frame that can be
/// fused (the detection clusters too, when refining).
pub(super) fn prepare<'a>(
    reader: &'a SessionReader,
    classifier: &dyn FrameClassifier,
    options: &FuseOptions,
    observers: &mut [&mut dyn Observer],
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
    let fit::Fitted { options, choices } = fit::fit_to_session(options, &data);
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
        options: options.clone(),
        choices,
    };
    classify_frames(&mut ctx, classifier, &options, observers)?;
    if ctx.prepared.is_empty() {
        return Err(ReplayError::NothingFused {
            path: ctx.data.path.clone(),
            frames: ctx.data.frames.len(),
        });
    }
    Ok(ctx)
}

/// Frames decoded and classified at once: enough to keep both cores busy, few enough that
/// memory does not grow with the session (eight 1080 x 1920 frames are 50 MB).
pub const PREPARE_CHUNK: usize = 8;

/// Every frame that can be fused, classified once; frames without a pose or going back in
/// time are skipped with a warning. Frames are classified in parallel chunks of
/// [`PREPARE_CHUNK`] and kept in session order: each is a pure function of its frame, so the
/// result is the same as one at a time.
pub(super) fn classify_frames(
    ctx: &mut Context<'_>,
    classifier: &dyn FrameClassifier,
    options: &FuseOptions,
    observers: &mut [&mut dyn Observer],
) -> Result<(), ReplayError> {
    use rayon::prelude::*;
    let todo = fusable_frames(ctx);
    let total = todo.len();
    for chunk in todo.chunks(PREPARE_CHUNK) {
        for o in observers.iter_mut() {
            o.on_progress(Stage::Classify, ctx.prepared.len(), total);
        }
        let shared: &Context<'_> = ctx;
        let done: Vec<Result<Prepared, ReplayError>> = chunk
            .par_iter()
            .map(|t| prepare_frame(shared, classifier, options, t))
            .collect();
        for p in done {
            ctx.prepared.push(p?);
        }
    }
    Ok(())
}

/// The frames that can be fused, with their /odom pose and camera mount, in session order;
/// the others are skipped with a warning.
fn fusable_frames(ctx: &mut Context<'_>) -> Vec<(FrameRef, Iso3, Iso3)> {
    let reader = ctx.reader;
    let mut todo: Vec<(FrameRef, Iso3, Iso3)> = Vec::new();
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
        let mount = match ctx.data.mount_at(fr.stamp_ns) {
            Ok(m) => m,
            Err(why) => {
                ctx.warnings
                    .push(format!("{}: no camera mount: {why}; frame skipped", at()));
                continue;
            }
        };
        if todo.last().is_some_and(|p| fr.stamp_ns < p.0.stamp_ns) {
            ctx.warnings.push(format!(
                "{}: frame stamp goes backwards; frame skipped",
                at()
            ));
            continue;
        }
        todo.push((fr.clone(), odometry, mount));
    }
    todo
}

/// One frame decoded and classified, with its detection clusters when refining (its floor
/// patch is made by the pass that uses it: [`floor_patch_of`]).
fn prepare_frame(
    ctx: &Context<'_>,
    classifier: &dyn FrameClassifier,
    options: &FuseOptions,
    (fr, odometry, mount): &(FrameRef, Iso3, Iso3),
) -> Result<Prepared, ReplayError> {
    let image = decode_frame(ctx.reader, &ctx.data, fr)?;
    let probs = classifier.classify(&image);
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
    Ok(Prepared {
        frame: fr.clone(),
        odometry: *odometry,
        mount: *mount,
        probs,
        clusters,
    })
}

/// The floor patch of a prepared frame: decoded again, so that a replay holds the patches
/// of the frames it is fusing, not of the whole session (a patch is ~40 kB, most of what a
/// frame kept: 1000 frames held 40 MB, growing with the session); decoding costs ~1 % of a
/// refined replay. The object is not floor: its detections (the tiles the landmarks use)
/// are left out; they would pull the pose by their own projection onto the floor behind the
/// object, which differs from every view (measured: the largest move of exact odometry
/// falls from 0.060 to 0.048 m).
pub(super) fn floor_patch_of(
    ctx: &Context<'_>,
    p: &Prepared,
    fp: &FloorParams,
) -> Result<FloorPatch, ReplayError> {
    let image = decode_frame(ctx.reader, &ctx.data, &p.frame)?;
    let probs = &p.probs;
    let t = probs.tile_px.max(1);
    let min_logit = logit(ctx.prior) + f64::from(DETECTION_DELTA);
    // Decided once per tile, not per pixel (a logarithm per pixel was a tenth of the patch's
    // time at 1080 x 1920).
    let object_tiles: Vec<bool> = probs
        .p
        .iter()
        .map(|&q| logit(f64::from(q)) >= min_logit)
        .collect();
    let not_floor = |u: u32, v: u32| {
        let (r, c) = ((v / t) as usize, (u / t) as usize);
        r < probs.rows && c < probs.cols && object_tiles[r * probs.cols + c]
    };
    Ok(floor_patch(
        &image,
        &ctx.data.camera,
        &p.mount,
        fp,
        not_floor,
    ))
}

/// Decodes a frame, checks its size against CameraInfo and rectifies it when the lens is
/// distorted.
pub(super) fn decode_frame(
    reader: &SessionReader,
    data: &SessionData,
    fr: &FrameRef,
) -> Result<Rgb8, ReplayError> {
    let at = || reader.at(Some(&fr.topic), fr.log_time_ns);
    let raw = &reader.index()[fr.raw_index];
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
        .map_err(|source| ReplayError::Frame { at: at(), source })?;
    let image = match &data.rectifier {
        Some(r) if (image.width, image.height) == (data.camera.width, data.camera.height) => {
            r.apply(&image)
        }
        _ => image,
    };
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

/// The floor term's settings, when refining with the floor.
pub(super) fn floor_params(options: &FuseOptions) -> Option<FloorParams> {
    (options.refine_poses && options.refine_floor).then(FloorParams::default)
}
