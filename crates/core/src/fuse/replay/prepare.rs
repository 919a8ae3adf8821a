//! Preparing a replay: the session read, the options checked against it, and the frames that
//! can be fused listed. The pass classifies them (with their detections, when refining) and
//! makes their floor patches a few frames ahead of their use, from one decode of each frame.
//! A frame's tile probabilities live from its classifying until it is fused (a rolled-back
//! pass classifies it again, to the same values: classifying is a pure function of the
//! pixels); what the end of the replay needs of them (its detection clusters, its detections
//! for `--locate detections`) is kept for the whole replay. When observers
//! want the frames and a frame cannot be shown as recorded (a distorted lens), that decode
//! is kept until the frame is fused, so it is not decoded and rectified a second time.

use crate::fuse::floor::{FloorParams, FloorPatch, floor_patch};
use crate::fuse::grid::{GridError, GridSpec, TileEvidence, logit};
use crate::fuse::refine::{DETECTION_DELTA, Detection, detections};
use crate::io::session::{At, Frame, SessionMsg, SessionReader, fmt_ns};
use crate::types::geometry::Iso3;
use crate::types::image::Rgb8;
use crate::types::probs::{FrameClassifier, TileProbs};

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, OnceLock};

use super::*;

/// A frame that will be fused: its reference, its /odom pose and, once the pass has reached
/// it, its tile probabilities.
pub(super) struct Prepared {
    pub(super) frame: FrameRef,
    pub(super) odometry: Iso3,
    /// The camera mount at the frame's stamp (base_from_camera).
    pub(super) mount: Iso3,
    /// Set once by the first pass, a few frames ahead of the frame's use ([`prepare_ahead`]).
    kept: OnceLock<Kept>,
    /// Its tile probabilities, from classifying until it is fused ([`Prepared::release`]):
    /// a replay holds a few frames' (3.8 kB each at 320 x 240), not every frame's.
    probs: Mutex<Option<Arc<TileProbs>>>,
    /// The frame as decoded for classifying, kept for the observers until it is fused when
    /// [`Context::keep_decoded`] says so (at most [`PREPARE_CHUNK`] frames at once).
    decoded: Mutex<Option<Rgb8>>,
}

/// What the classifier made of a frame that the replay keeps to its end.
#[derive(Default)]
struct Kept {
    /// Its detection clusters (pixels), when refining.
    clusters: Vec<[f64; 2]>,
    /// Its detections, when objects are located from them ([`Locate::Detections`]).
    detections: Vec<Detection>,
}

impl Prepared {
    fn kept(&self) -> &Kept {
        static NONE: Kept = Kept {
            clusters: Vec::new(),
            detections: Vec::new(),
        };
        // The pass classifies every frame before it fuses it, so nothing reads NONE but by
        // mistake.
        self.kept.get().unwrap_or(&NONE)
    }

    /// Its tile probabilities: empty outside the span from its classifying to its fusing.
    pub(super) fn probs(&self) -> Arc<TileProbs> {
        lock(&self.probs).clone().unwrap_or_else(|| {
            Arc::new(TileProbs {
                rows: 0,
                cols: 0,
                tile_px: 1,
                p: Vec::new(),
            })
        })
    }

    /// Drops its tile probabilities once it is fused.
    pub(super) fn release(&self) {
        *lock(&self.probs) = None;
    }

    /// Its detection clusters (pixels), when refining.
    pub(super) fn clusters(&self) -> &[[f64; 2]] {
        &self.kept().clusters
    }

    /// Its detections, when objects are located from them.
    pub(super) fn detections(&self) -> &[Detection] {
        &self.kept().detections
    }
}

/// Everything a pass over the frames needs, read once (frames classified once, by the first
/// pass).
pub(super) struct Context<'a> {
    pub(super) reader: &'a SessionReader,
    pub(super) classifier: &'a dyn FrameClassifier,
    pub(super) data: SessionData,
    pub(super) spec: GridSpec,
    pub(super) prior: f64,
    pub(super) prepared: Vec<Prepared>,
    pub(super) warnings: Vec<String>,
    /// The caller's options fitted to the session: what every pass uses.
    pub(super) options: FuseOptions,
    /// What the session chose and why.
    pub(super) choices: Vec<String>,
    /// Whether a frame's decode is kept for the observers ([`Prepared`]): they want the
    /// frames, and the lens is distorted, so a frame is shown as the pass fused it (decoded
    /// and rectified), not as recorded. Decoding and rectifying a phone frame a second time
    /// was a seventh of what streaming the fruit capture to Rerun added.
    pub(super) keep_decoded: bool,
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

/// Reads the session, checks the options against it, and lists the frames that can be fused
/// (the pass classifies them: [`prepare_ahead`]).
pub(super) fn prepare<'a>(
    reader: &'a SessionReader,
    classifier: &'a dyn FrameClassifier,
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
        classifier,
        data,
        spec,
        prior,
        prepared: Vec::new(),
        warnings,
        options: options.clone(),
        choices,
        keep_decoded: false,
    };
    ctx.prepared = fusable_frames(&mut ctx)
        .into_iter()
        .map(|(frame, odometry, mount)| Prepared {
            frame,
            odometry,
            mount,
            kept: OnceLock::new(),
            probs: Mutex::new(None),
            decoded: Mutex::new(None),
        })
        .collect();
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

/// The frames that can be fused, with their /odom pose and camera mount, in session order;
/// the others are skipped with a warning.
fn fusable_frames(ctx: &mut Context<'_>) -> Vec<(FrameRef, Iso3, Iso3)> {
    let reader = ctx.reader;
    let mut todo: Vec<(FrameRef, Iso3, Iso3)> = Vec::new();
    for fr in &ctx.data.frames {
        let at = || reader.at(Some(&fr.topic), fr.log_time_ns);
        let Some(odometry) = ctx.data.odom_at(fr.stamp_ns) else {
            ctx.warnings.push(format!(
                "{}: no {} pose within 50 ms of stamp {} (nor two around it at most 250 ms apart); frame skipped",
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

/// Makes frame `index` ready to fuse: classified (with its detection clusters when refining)
/// and, when `floor` is given and `floor_ahead` lacks it, its floor patch made. Frames are
/// prepared [`PREPARE_CHUNK`] at a time in parallel from `index` on, each decoded once for
/// both; each is a pure function of its frame, so the result does not depend on the chunking
/// or the threads. A floor patch is made by the pass that uses it, not kept for the whole
/// session (a patch is ~40 kB: 1000 frames held 40 MB); a frame classified by an earlier
/// pass is decoded again for it.
pub(super) fn prepare_ahead(
    ctx: &Context<'_>,
    index: usize,
    floor: Option<&FloorParams>,
    floor_ahead: &mut BTreeMap<usize, FloorPatch>,
) -> Result<(), ReplayError> {
    use rayon::prelude::*;
    let wants_patch = |i: usize| floor.is_some() && !floor_ahead.contains_key(&i);
    let ready = ctx
        .prepared
        .get(index)
        .is_none_or(|p| lock(&p.probs).is_some());
    if ready && !wants_patch(index) {
        return Ok(());
    }
    let end = (index + PREPARE_CHUNK).min(ctx.prepared.len());
    let todo: Vec<(usize, bool)> = (index..end).map(|i| (i, wants_patch(i))).collect();
    let made: Vec<Result<Option<FloorPatch>, ReplayError>> = todo
        .par_iter()
        .map(|&(i, patch)| prepare_frame(ctx, &ctx.prepared[i], floor.filter(|_| patch)))
        .collect();
    for (&(i, _), m) in todo.iter().zip(made) {
        if let Some(patch) = m? {
            floor_ahead.insert(i, patch);
        }
    }
    Ok(())
}

/// One frame decoded (when it is not classified yet or `floor` asks for its patch),
/// classified once, and its floor patch when `floor` is given.
fn prepare_frame(
    ctx: &Context<'_>,
    p: &Prepared,
    floor: Option<&FloorParams>,
) -> Result<Option<FloorPatch>, ReplayError> {
    let held = lock(&p.probs).clone();
    if held.is_some() && floor.is_none() {
        return Ok(None);
    }
    let image = decode_frame(ctx.reader, &ctx.data, &p.frame)?;
    let probs = held.unwrap_or_else(|| Arc::new(ctx.classifier.classify(&image)));
    p.kept.get_or_init(|| kept_of(ctx, &probs));
    *lock(&p.probs) = Some(Arc::clone(&probs));
    let patch = floor.map(|fp| floor_patch_of(ctx, &image, &probs, &p.mount, fp));
    if ctx.keep_decoded {
        *lock(&p.decoded) = Some(image);
    }
    Ok(patch)
}

/// What the replay keeps of a frame's probabilities: its detection clusters when refining,
/// its detections when objects are located from them.
fn kept_of(ctx: &Context<'_>, probs: &TileProbs) -> Kept {
    let refine = ctx.options.refine_poses;
    let locate = ctx.options.locate == Locate::Detections;
    if !refine && !locate {
        return Kept::default();
    }
    let all = detections(&TileEvidence::from_probabilities(
        probs.rows,
        probs.cols,
        probs.tile_px,
        &probs.p,
        ctx.prior,
    ));
    Kept {
        clusters: if refine {
            all.iter().map(|d| d.centroid_px).collect()
        } else {
            Vec::new()
        },
        detections: if locate { all } else { Vec::new() },
    }
}

/// The slot's guard: a panic elsewhere while it was held left nothing half-written in it.
fn lock<T>(slot: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    slot.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// The floor patch of a decoded frame with its tile probabilities. The object is not floor:
/// its detections (the tiles the landmarks use) are left out; they would pull the pose by
/// their own projection onto the floor behind the object, which differs from every view
/// (measured: the largest move of exact odometry falls from 0.060 to 0.048 m).
fn floor_patch_of(
    ctx: &Context<'_>,
    image: &Rgb8,
    probs: &TileProbs,
    mount: &Iso3,
    fp: &FloorParams,
) -> FloorPatch {
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
    floor_patch(image, &ctx.data.camera, mount, fp, not_floor)
}

/// A frame's message, decoded from the session (its pixels still as recorded).
fn read_frame(reader: &SessionReader, fr: &FrameRef) -> Result<Frame, ReplayError> {
    match reader.decode(&fr.meta)?.map(|m| m.msg) {
        Some(SessionMsg::Frame(f)) => Ok(f),
        _ => Err(ReplayError::Invalid {
            at: reader.at(Some(&fr.topic), fr.log_time_ns),
            what: "not a frame".into(),
        }),
    }
}

/// A fused frame's pixels for the observers: the recorded PNG or JPEG file as it is when
/// there is no lens distortion to remove and its size is CameraInfo's (what the pass fused),
/// else the decode kept by [`prepare_frame`] or, without one, decoded like [`decode_frame`].
/// Showing a frame then costs no decoding and no encoding.
pub(super) fn step_image(
    reader: &SessionReader,
    data: &SessionData,
    p: &Prepared,
) -> Result<StepImage, ReplayError> {
    if let Some(image) = lock(&p.decoded).take() {
        return Ok(StepImage::Decoded(image));
    }
    let fr = &p.frame;
    let frame = read_frame(reader, fr)?;
    let size = (data.camera.width, data.camera.height);
    if data.rectifier.is_none()
        && let Some((media, bytes)) = frame.encoded_file()
        && frame.dimensions().ok() == Some(size)
    {
        return Ok(StepImage::Encoded {
            media,
            bytes: bytes.to_vec(),
            width: size.0,
            height: size.1,
        });
    }
    decoded(reader, data, fr, &frame).map(StepImage::Decoded)
}

/// Decodes a frame, checks its size against CameraInfo and rectifies it when the lens is
/// distorted.
pub(super) fn decode_frame(
    reader: &SessionReader,
    data: &SessionData,
    fr: &FrameRef,
) -> Result<Rgb8, ReplayError> {
    decoded(reader, data, fr, &read_frame(reader, fr)?)
}

/// [`decode_frame`] of a frame's message already read.
fn decoded(
    reader: &SessionReader,
    data: &SessionData,
    fr: &FrameRef,
    frame: &Frame,
) -> Result<Rgb8, ReplayError> {
    let at = || reader.at(Some(&fr.topic), fr.log_time_ns);
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
