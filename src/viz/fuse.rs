//! The fuser in Rerun: an [`Observer`] that streams each replay step (robot pose and
//! trajectories, camera frame and tile probabilities, pyramids, the belief grid, objects,
//! projections and plots). Entity paths are listed in docs/rerun.md.
//!
//! Invariants: everything logged is a function of the replay step and the grid (no clock, no
//! randomness, cells and tiles visited in index order), stamped on the `log_time` timeline
//! with the frame's MCAP log time and on `frame` with its index; session-wide things (camera
//! mount, intrinsics, ground-truth boxes) are static. Observing never changes the replay.
//! The replay's thread copies each step (and summarises the grid at snapshots); one logging
//! thread encodes and logs every message in replay order, at most [`QUEUED_FRAMES`] behind.

use rerun::RecordingStream;

use super::images::{log_frame_and_probs, step_frame};
use super::{TIMELINE_FRAME, TIMELINE_LOG_TIME, VizError, log_err};
use objloc_core::fuse::grid::{Grid, GridSpec};
use objloc_core::fuse::objects::Object;
use objloc_core::fuse::refine::Verdict;
use objloc_core::fuse::replay::{FrameStep, Observer, ObserverError, SessionData};
use objloc_core::io::msgs::iso_from_pose;
use objloc_core::out::view::{
    GridSummary, centroid_error_m, is_snapshot, pyramids, snapshots_within, summarize_grid,
    verdict_rgb, viridis,
};
use objloc_core::types::geometry::{Camera, Iso3, yaw_of};

/// Cells of `world/grid` per snapshot, at most. The simulated room tours show 40 000-50 000
/// cells above 0.5; a real capture's fitted grid (200 cells a side) showed 540 000, most of
/// them the cones behind the object: 8.7 MB a snapshot, a 168 MB recording of a 12.7 MB
/// session (docs/scale.md).
pub const GRID_MAX_CELLS: usize = 100_000;

/// What the fuse stream shows.
#[derive(Debug, Clone, PartialEq)]
pub struct VizOptions {
    /// Cells shown in `world/grid`: posterior above this...
    pub grid_min_posterior: f32,
    /// ...and seen by at least this many frames...
    pub grid_min_views: u16,
    /// ...at most this many of them in one snapshot, the most probable.
    pub grid_max_cells: usize,
    /// Tiles whose pyramid is drawn in `world/pyramids`.
    pub pyramid_min_p: f32,
    /// Length of the drawn pyramids along the optical axis, metres.
    pub pyramid_depth_m: f64,
}

impl Default for VizOptions {
    fn default() -> Self {
        Self {
            grid_min_posterior: 0.5,
            grid_min_views: 2,
            grid_max_cells: GRID_MAX_CELLS,
            pyramid_min_p: 0.5,
            pyramid_depth_m: 3.0,
        }
    }
}

const TRUTH_RGB: [u8; 3] = [255, 140, 0];
const ESTIMATE_RGB: [u8; 3] = [0, 200, 255];
const ODOM_RGB: [u8; 3] = [220, 220, 220];
/// The final objects' boxes; a weaker instance's (less certain) in [`WEAKER_RGB`].
const FINAL_RGB: [u8; 3] = [0, 120, 255];
const WEAKER_RGB: [u8; 3] = [200, 100, 255];
/// The refined trajectory: green, beside odometry's grey and the truth's orange.
const REFINED_RGB: [u8; 3] = [60, 200, 90];

/// Trajectory entities, drawn in `world` coordinates under the moving `world/robot`; the
/// refined ones exist only when refining.
const ODOMETRY_TRACK: &str = "world/robot/odometry";
const TRUTH_TRACK: &str = "world/robot/ground_truth";
const REFINED_TRACKS: [&str; 2] = ["world/robot/refined", "world/robot/refined/frames"];
/// Rerun's implicit frame of the `world` entity.
const WORLD_FRAME: &str = "tf#/world";
/// Most snapshots a replay logs of what grows with the replay (the whole grid with its
/// projections and entropy; the trajectories so far): every frame's up to this many frames,
/// then every k-th frame's and the last's. A grid snapshot costs more than fusing a frame
/// (a million cells summarised, a few hundred kB logged) and a trajectory grows with the
/// frames, so a long replay streamed all of them every frame took twice its replay time and
/// wrote 0.4 MB a frame. The viewer shows the latest snapshot at any time; the robot, the
/// camera frame, the pyramids, the objects and the plots stay per frame.
const SNAPSHOTS: usize = 50;
/// ...and fewer for a big grid: the snapshots together summarise about this many stored
/// cells. Grids of up to 0.5 M stored cells keep all 50, a foreign room's (0.7 M) 35, the
/// 200-stop tour's (0.9 M) 27, the held-out tiled floor (2.0 M) 12; a real capture's fitted grid
/// (5-8 M cells, 40-80 frames) gets 3-5. A snapshot there costs the replay 20-40 ms
/// (summarising every cell, then logging 100 000 of them), more than a frame's fusion, on a
/// machine the replay already keeps busy: at 100 M cells (12-16 snapshots) the milk carton's
/// stream took 1.6x its replay, at 50 M 1.35x, at 25 M 1.25-1.3x (docs/scale.md).
const SNAPSHOT_CELLS: usize = 25_000_000;
/// One line per refined frame: the verdict and its numbers; the rollback, when it happens.
const VERDICT_LOG: &str = "refinement";
/// Frames the replay may run ahead of the logging thread: enough to smooth out a snapshot
/// (a grid summary takes longer to log than a frame), few enough that the queued frames'
/// images and summaries stay a few MB.
const QUEUED_FRAMES: usize = 2;

/// Streams a replay to a recording. The replay's thread only copies what a frame shows (and,
/// at a snapshot, summarises the grid, which changes with the next frame); encoding and
/// logging run on a thread of their own, so they overlap the replay's next frame instead of
/// adding to it (the replay's parallel parts leave a core idle between them). That one thread
/// logs everything, static data included, in replay order, so the recording holds the same
/// rows whatever the timing.
pub struct FuseViz {
    rec: RecordingStream,
    options: VizOptions,
    worker: Option<Worker>,
}

/// The logging thread and the queue to it.
struct Worker {
    queue: std::sync::mpsc::SyncSender<Message>,
    handle: std::thread::JoinHandle<Result<(), VizError>>,
}

/// What the replay hands the logging thread.
enum Message {
    Start(Box<StartMessage>),
    Frame(Box<FrameMessage>),
    Rollback,
    /// The poses were solved again over the whole replay; the frames come again.
    Smoothed,
    /// The objects of the final grid (with any weaker instances, which the frames' lists
    /// do not look for).
    Final(Vec<Object>),
}

/// What is static in the recording.
struct StartMessage {
    /// The camera's mount, when it does not move.
    static_mount: Option<Iso3>,
    /// Whether the session has a ground-truth track.
    truth_track: bool,
    spec: GridSpec,
    truth_boxes: Option<rerun::Boxes3D>,
}

/// One frame, owned: the step, and what the logger cannot compute without the session or
/// the grid as they were at this frame.
struct FrameMessage {
    step: FrameStep,
    snapshot: Option<Snapshot>,
    centroid_error_m: Option<f64>,
}

/// What grows with the replay, at a snapshot frame.
struct Snapshot {
    grid: GridSummary,
    spec: GridSpec,
    odometry_track: Vec<[f32; 3]>,
    truth_track: Option<Vec<[f32; 3]>>,
}

/// The logging side: the recording and what it has logged so far.
struct Logger {
    rec: RecordingStream,
    options: VizOptions,
    camera: Camera,
    /// The mount moves (a pan-tilt head, /tf): logged with each frame.
    dynamic_mount: bool,
    /// Refined robot positions of the frames so far (empty unless refining).
    refined_track: Vec<[f32; 3]>,
    /// The colour of each refined position's verdict.
    refined_colors: Vec<rerun::Color>,
    /// The first frame's position: it anchors the refined trajectory, which starts there
    /// although that frame carries no correction.
    first_position: Option<[f32; 3]>,
    /// Where a pass shown again logs its plots, under each plot's own entity ("" for the
    /// replay's first pass): two passes at the same times on one series would draw a zigzag,
    /// as series of their own they compare frame by frame.
    pass_suffix: &'static str,
}

impl FuseViz {
    pub fn new(rec: RecordingStream, options: VizOptions) -> Self {
        Self {
            rec,
            options,
            worker: None,
        }
    }

    /// Logs the final grid's objects (`Outcome::objects`), once the replay is done.
    pub fn final_objects(&mut self, objects: &[Object]) -> Result<(), VizError> {
        self.send(Message::Final(objects.to_vec()))
    }

    /// Waits for the logging thread to log every frame handed to it; its error, if it had
    /// one. Call before the stream is finished.
    pub fn finish(mut self) -> Result<(), VizError> {
        match self.worker.take() {
            Some(w) => join(w),
            None => Ok(()),
        }
    }

    /// Hands `message` to the logging thread; the thread's error when it has stopped.
    fn send(&mut self, message: Message) -> Result<(), VizError> {
        let Some(w) = &self.worker else {
            return Err(VizError::Log("the logging thread is not running".into()));
        };
        if w.queue.send(message).is_ok() {
            return Ok(());
        }
        // The thread only stops early on an error: report it.
        match self.worker.take().map(join) {
            Some(Err(e)) => Err(e),
            _ => Err(VizError::Log("the logging thread stopped".into())),
        }
    }
}

impl Drop for FuseViz {
    /// A replay that failed drops its observer: the thread is stopped before the stream is
    /// abandoned (its error, if any, is the failed replay's consequence, not news).
    fn drop(&mut self) {
        if let Some(w) = self.worker.take() {
            let _ = join(w);
        }
    }
}

/// Closes the queue and waits for the thread to drain it.
fn join(w: Worker) -> Result<(), VizError> {
    drop(w.queue);
    w.handle
        .join()
        .unwrap_or_else(|_| Err(VizError::Log("the logging thread panicked".into())))
}

fn translation_rotation(iso: &Iso3) -> ([f32; 3], rerun::Quaternion) {
    let t = iso.translation.vector;
    let q = iso.rotation.quaternion().coords; // (x, y, z, w)
    (
        [t.x as f32, t.y as f32, t.z as f32],
        rerun::Quaternion::from_xyzw([q.x as f32, q.y as f32, q.z as f32, q.w as f32]),
    )
}

fn transform(iso: &Iso3) -> rerun::Transform3D {
    let (t, q) = translation_rotation(iso);
    rerun::Transform3D::from_translation_rotation(t, q)
}

fn position(iso: &Iso3) -> [f32; 3] {
    translation_rotation(iso).0
}

fn track_until(track: &[(i64, Iso3)], stamp_ns: i64) -> Vec<[f32; 3]> {
    track
        .iter()
        .take_while(|(t, _)| *t <= stamp_ns)
        .map(|(_, p)| position(p))
        .collect()
}

/// Ground-truth boxes: centres, half sizes, rotations, labels.
fn truth_boxes(data: &SessionData) -> Option<rerun::Boxes3D> {
    let gt = data.ground_truth.as_ref()?;
    let mut centers = Vec::new();
    let mut halves = Vec::new();
    let mut rots = Vec::new();
    let mut labels = Vec::new();
    for ((name, pose), size) in gt.object.iter().zip(&gt.box_center).zip(&gt.box_size) {
        let Some(iso) = iso_from_pose(pose) else {
            continue;
        };
        let (t, q) = translation_rotation(&iso);
        centers.push(t);
        halves.push([
            size[0] as f32 / 2.0,
            size[1] as f32 / 2.0,
            size[2] as f32 / 2.0,
        ]);
        rots.push(q);
        labels.push(format!("{name} (truth)"));
    }
    Some(
        rerun::Boxes3D::from_centers_and_half_sizes(centers, halves)
            .with_quaternions(rots)
            .with_labels(labels)
            .with_colors([rerun::Color::from_rgb(
                TRUTH_RGB[0],
                TRUTH_RGB[1],
                TRUTH_RGB[2],
            )]),
    )
}

fn projection(
    rec: &RecordingStream,
    path: &str,
    v: &[f32],
    w: usize,
    h: usize,
) -> Result<(), VizError> {
    let max = v.iter().copied().fold(0f32, f32::max).max(1e-6);
    let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    let img = rerun::DepthImage::from_data_type_and_bytes(
        bytes,
        [w as u32, h as u32],
        rerun::ChannelDatatype::F32,
    )
    .with_meter(1.0)
    .with_colormap(rerun::components::Colormap::Viridis)
    .with_depth_range([0.0, f64::from(max)]);
    rec.log(path, &img).map_err(log_err)
}

/// Declares `entity`'s data to be in the `world` entity's frame (statically).
fn in_world_frame(rec: &RecordingStream, entity: &str) -> Result<(), VizError> {
    rec.log_static(entity, &rerun::CoordinateFrame::new(WORLD_FRAME))
        .map_err(log_err)
}

impl FuseViz {
    /// What is static, as the logging thread logs it first.
    fn start_message(data: &SessionData, grid: &Grid) -> StartMessage {
        // A mount that moves (a pan-tilt head, /tf) is logged with each frame instead.
        let static_mount = if data.tf.is_dynamic() {
            None
        } else {
            data.frames
                .first()
                .and_then(|f| data.mount_at(f.stamp_ns).ok())
        };
        StartMessage {
            static_mount,
            truth_track: !data.ground_truth_poses.is_empty(),
            spec: grid.spec,
            truth_boxes: truth_boxes(data),
        }
    }

    /// The frame as the logging thread needs it: a copy of the step; at a snapshot, the grid
    /// summarised and the tracks so far.
    fn message(&self, data: &SessionData, step: &FrameStep, grid: &Grid) -> FrameMessage {
        let wanted = snapshots_within(SNAPSHOT_CELLS, grid.stored_cells(), SNAPSHOTS);
        let snapshot = is_snapshot(step.index, step.frames, wanted).then(|| {
            let stamp = step.frame.stamp_ns;
            let o = &self.options;
            Snapshot {
                grid: summarize_grid(
                    grid,
                    o.grid_min_posterior,
                    o.grid_min_views,
                    o.grid_max_cells,
                ),
                spec: grid.spec,
                odometry_track: track_until(data.odom.poses(), stamp),
                truth_track: (!data.ground_truth_poses.is_empty())
                    .then(|| track_until(data.ground_truth_poses.poses(), stamp)),
            }
        });
        FrameMessage {
            step: step.clone(),
            snapshot,
            centroid_error_m: centroid_error_m(&step.objects, data),
        }
    }
}

impl Logger {
    fn handle(&mut self, message: Message) -> Result<(), VizError> {
        match message {
            Message::Start(m) => self.start(&m),
            Message::Frame(m) => self.frame(&m),
            Message::Rollback => self.rollback(),
            Message::Smoothed => self.smoothed(),
            Message::Final(objects) => self.final_objects(&objects),
        }
    }

    /// The final objects, static: what the replay answers, whichever frame is shown.
    fn final_objects(&self, objects: &[Object]) -> Result<(), VizError> {
        let rgb = |o: &Object| {
            let c = if o.weaker_instance.is_some() {
                WEAKER_RGB
            } else {
                FINAL_RGB
            };
            rerun::Color::from_rgb(c[0], c[1], c[2])
        };
        let boxes = rerun::Boxes3D::from_mins_and_sizes(
            objects.iter().map(|b| b.bbox_min_m.map(|x| x as f32)),
            objects
                .iter()
                .map(|b| [0, 1, 2].map(|a| (b.bbox_max_m[a] - b.bbox_min_m[a]) as f32)),
        )
        .with_labels(
            objects
                .iter()
                .enumerate()
                .map(|(i, o)| match o.weaker_instance {
                    Some(f) => format!("object {i} (a weaker instance: peak {f:.2} of the grid's)"),
                    None => format!("object {i}"),
                }),
        )
        .with_colors(objects.iter().map(rgb));
        self.rec
            .log_static("world/objects/final", &boxes)
            .map_err(log_err)
    }

    fn start(&self, m: &StartMessage) -> Result<(), VizError> {
        let rec = &self.rec;
        rec.log_static("world", &rerun::ViewCoordinates::RIGHT_HAND_Z_UP())
            .map_err(log_err)?;
        if let Some(mount) = &m.static_mount {
            rec.log_static("world/robot/camera", &transform(mount))
                .map_err(log_err)?;
        }
        // The trajectories live beside the robot they trace (`world/robot/...`) but are in
        // world coordinates: each declares the `world` entity's frame as its own, so the
        // robot's moving transform does not carry them along.
        let truth = m.truth_track.then_some(TRUTH_TRACK);
        for track in std::iter::once(ODOMETRY_TRACK).chain(truth) {
            in_world_frame(rec, track)?;
        }
        let c = &self.camera;
        rec.log_static(
            "world/robot/camera",
            &rerun::Pinhole::from_focal_length_and_resolution(
                [c.fx as f32, c.fy as f32],
                [c.width as f32, c.height as f32],
            )
            .with_principal_point([c.cx as f32, c.cy as f32])
            .with_image_plane_distance(0.5),
        )
        .map_err(log_err)?;
        let lo = m.spec.origin_m;
        let hi = m.spec.max_m();
        rec.log_static(
            "world/grid/bounds",
            &rerun::Boxes3D::from_mins_and_sizes(
                [[lo[0] as f32, lo[1] as f32, lo[2] as f32]],
                [[
                    (hi[0] - lo[0]) as f32,
                    (hi[1] - lo[1]) as f32,
                    (hi[2] - lo[2]) as f32,
                ]],
            )
            .with_colors([rerun::Color::from_rgb(120, 120, 120)]),
        )
        .map_err(log_err)?;
        if let Some(b) = &m.truth_boxes {
            rec.log_static("world/objects/truth", b).map_err(log_err)?;
        }
        Ok(())
    }

    fn frame(&mut self, m: &FrameMessage) -> Result<(), VizError> {
        let (rec, step) = (&self.rec, &m.step);
        rec.set_time(
            TIMELINE_LOG_TIME,
            rerun::TimeCell::from_timestamp_nanos_since_epoch(
                step.frame.log_time_ns.min(i64::MAX as u64) as i64,
            ),
        );
        rec.set_time_sequence(TIMELINE_FRAME, step.index as i64);
        self.tracks(step, m.snapshot.as_ref())?;
        self.refinement(step, m.snapshot.is_some())?;
        log_frame_and_probs(
            &self.rec,
            "world/robot/camera",
            &step_frame(&step.image)?,
            step.image.size(),
            &step.probs,
        )?;
        self.pyramids(step)?;
        if let Some(s) = &m.snapshot {
            self.grid(&s.grid, &s.spec)?;
            self.plot("plots/mean_entropy_bits", s.grid.mean_entropy_bits)?;
        }
        self.objects(step, m.centroid_error_m)
    }

    /// The robot's pose and the /odom and true tracks up to the frame.
    fn tracks(&self, step: &FrameStep, snapshot: Option<&Snapshot>) -> Result<(), VizError> {
        let rec = &self.rec;
        rec.log("world/robot", &transform(&step.odom_from_base))
            .map_err(log_err)?;
        if self.dynamic_mount {
            let mount = step.odom_from_base.inverse() * step.odom_from_camera;
            rec.log("world/robot/camera", &transform(&mount))
                .map_err(log_err)?;
        }
        let Some(snapshot) = snapshot else {
            return Ok(());
        };
        rec.log(
            ODOMETRY_TRACK,
            &rerun::LineStrips3D::new([snapshot.odometry_track.clone()]).with_colors([
                rerun::Color::from_rgb(ODOM_RGB[0], ODOM_RGB[1], ODOM_RGB[2]),
            ]),
        )
        .map_err(log_err)?;
        if let Some(truth) = &snapshot.truth_track {
            rec.log(
                TRUTH_TRACK,
                &rerun::LineStrips3D::new([truth.clone()]).with_colors([rerun::Color::from_rgb(
                    TRUTH_RGB[0],
                    TRUTH_RGB[1],
                    TRUTH_RGB[2],
                )]),
            )
            .map_err(log_err)?;
        }

        Ok(())
    }

    /// The refined positions so far, as a line and as points coloured by their verdicts.
    fn log_refined_track(&self) -> Result<(), VizError> {
        let color = rerun::Color::from_rgb(REFINED_RGB[0], REFINED_RGB[1], REFINED_RGB[2]);
        self.rec
            .log(
                REFINED_TRACKS[0],
                &rerun::LineStrips3D::new([self.refined_track.clone()]).with_colors([color]),
            )
            .map_err(log_err)?;
        self.rec
            .log(
                REFINED_TRACKS[1],
                &rerun::Points3D::new(self.refined_track.clone())
                    .with_colors(self.refined_colors.clone())
                    .with_radii([0.03]),
            )
            .map_err(log_err)
    }

    /// The refined track (each position coloured by its verdict), the verdict's text line and
    /// the correction's plots.
    fn refinement(&mut self, step: &FrameStep, snapshot: bool) -> Result<(), VizError> {
        let t = step.odom_from_base.translation.vector;
        let here = [t.x as f32, t.y as f32, t.z as f32];
        if self.first_position.is_none() {
            self.first_position = Some(here);
        }
        if let Some(c) = &step.correction {
            if self.refined_track.is_empty() {
                for track in REFINED_TRACKS {
                    in_world_frame(&self.rec, track)?;
                }
                if let Some(first) = self.first_position.filter(|_| step.index > 0) {
                    self.refined_track.push(first);
                }
            }
            if self.refined_colors.len() < self.refined_track.len() {
                // The anchor frame: measured by definition.
                let [r, g, b] = verdict_rgb(Verdict::Accepted);
                self.refined_colors.push(rerun::Color::from_rgb(r, g, b));
            }
            self.refined_track.push(here);
            let [r, g, b] = verdict_rgb(c.outcome);
            self.refined_colors.push(rerun::Color::from_rgb(r, g, b));
            if snapshot {
                self.log_refined_track()?;
            }
            // Applied from the detections alone: the end check cannot verify it (docs/fuser.md).
            let alone = c.applied && c.floor_cells == 0;
            let level = match c.outcome {
                Verdict::Accepted if alone => rerun::TextLogLevel::WARN,
                Verdict::Accepted | Verdict::Insignificant | Verdict::NoEvidence => {
                    rerun::TextLogLevel::INFO
                }
                Verdict::Ambiguous | Verdict::Gated => rerun::TextLogLevel::WARN,
                Verdict::RolledBack => rerun::TextLogLevel::ERROR,
            };
            self.rec.log(
                VERDICT_LOG,
                &rerun::TextLog::new(format!(
                    "frame {}: {}{} (gain {:.1}, {} landmark(s), {} floor cells, total chi-square {:.1})",
                    step.index,
                    c.outcome.label(),
                    if alone { ", from the detections alone (unverified)" } else { "" },
                    c.gain,
                    c.anchors,
                    c.floor_cells,
                    c.total_chi2
                ))
                .with_level(level)
                .with_color(rerun::Color::from_rgb(r, g, b)),
            )
            .map_err(log_err)?;
            let o = step.odometry.translation.vector;
            self.plot("plots/correction_m", (t - o).xy().norm())?;
            self.plot(
                "plots/correction_deg",
                yaw_of(&(step.odometry.inverse() * step.odom_from_base)).to_degrees(),
            )?;
            self.plot("counts/landmarks", c.anchors as f64)?;
            self.plot("counts/floor_cells", c.floor_cells as f64)?;
        }
        Ok(())
    }

    /// The pyramids of the frame's confident tiles.
    fn pyramids(&self, step: &FrameStep) -> Result<(), VizError> {
        let (rec, o) = (&self.rec, &self.options);
        let strips = pyramids(
            &self.camera,
            &step.odom_from_camera,
            &step.probs,
            o.pyramid_min_p,
            o.pyramid_depth_m,
        );
        let colors: Vec<rerun::Color> = strips
            .iter()
            .map(|(_, p)| {
                let [r, g, b] = viridis(*p);
                rerun::Color::from_rgb(r, g, b)
            })
            .collect();
        rec.log(
            "world/pyramids",
            &rerun::LineStrips3D::new(strips.into_iter().map(|(s, _)| s))
                .with_colors(colors)
                .with_radii([rerun::Radius::new_ui_points(0.75)]),
        )
        .map_err(log_err)?;

        Ok(())
    }

    /// The belief's shown cells and its three projections; returns the summary.
    fn grid(&self, s: &GridSummary, spec: &GridSpec) -> Result<(), VizError> {
        let (rec, o) = (&self.rec, &self.options);
        let v = spec.voxel_size_m as f32;
        let origin = spec.origin_m;
        let (idx, vals): (Vec<[i32; 3]>, Vec<f32>) = s.cells.iter().copied().unzip();
        rec.log(
            "world/grid",
            &rerun::VoxelGridMap::new(idx, [v, v, v])
                .with_values(vals)
                .with_translation([origin[0] as f32, origin[1] as f32, origin[2] as f32])
                .with_colormap(rerun::components::Colormap::Viridis)
                .with_value_range([f64::from(o.grid_min_posterior), 1.0]),
        )
        .map_err(log_err)?;
        // Of the stored region: the whole grid when dense.
        let [nx, ny, nz] = s.region.dims;
        if nx * ny * nz > 0 {
            projection(rec, "projections/x", &s.along_x, ny, nz)?;
            projection(rec, "projections/y", &s.along_y, nx, nz)?;
            projection(rec, "projections/z", &s.along_z, nx, ny)?;
        }
        Ok(())
    }

    /// The objects found after the frame and the whole-grid plots.
    fn objects(&self, step: &FrameStep, centroid_error_m: Option<f64>) -> Result<(), VizError> {
        let rec = &self.rec;
        let objects = &step.objects;
        let boxes = rerun::Boxes3D::from_mins_and_sizes(
            objects.iter().map(|b| b.bbox_min_m.map(|x| x as f32)),
            objects
                .iter()
                .map(|b| [0, 1, 2].map(|a| (b.bbox_max_m[a] - b.bbox_min_m[a]) as f32)),
        )
        .with_labels(objects.iter().enumerate().map(|(i, b)| {
            format!(
                "object {i}: {} cells, peak p {:.3}",
                b.cells, b.peak_probability
            )
        }))
        .with_colors([rerun::Color::from_rgb(
            ESTIMATE_RGB[0],
            ESTIMATE_RGB[1],
            ESTIMATE_RGB[2],
        )]);
        rec.log("world/objects/estimated", &boxes)
            .map_err(log_err)?;
        rec.log(
            "world/objects/centroids",
            &rerun::Points3D::new(objects.iter().map(|b| b.centroid_m.map(|x| x as f32)))
                .with_colors([rerun::Color::from_rgb(
                    ESTIMATE_RGB[0],
                    ESTIMATE_RGB[1],
                    ESTIMATE_RGB[2],
                )])
                .with_radii([rerun::Radius::new_ui_points(6.0)]),
        )
        .map_err(log_err)?;

        // The located centres on the frame (rectified, so the pinhole projects them), to see
        // at a glance whether the frame's rectangle holds them.
        let camera_from_odom = step.odom_from_camera.inverse();
        let located: Vec<[f32; 2]> = objects
            .iter()
            .filter_map(|o| {
                let q = camera_from_odom * nalgebra::Point3::from(o.centroid_m);
                self.camera.project(&q).map(|(u, v)| [u as f32, v as f32])
            })
            .collect();
        rec.log(
            "world/robot/camera/located",
            &rerun::Points2D::new(located)
                .with_colors([rerun::Color::from_rgb(
                    ESTIMATE_RGB[0],
                    ESTIMATE_RGB[1],
                    ESTIMATE_RGB[2],
                )])
                .with_radii([rerun::Radius::new_ui_points(8.0)]),
        )
        .map_err(log_err)?;

        self.plot("plots/max_posterior", step.max_probability)?;
        self.plot("counts/cells_updated", step.cells_updated as f64)?;
        self.plot("counts/objects", objects.len() as f64)?;
        if let Some(e) = centroid_error_m {
            self.plot("plots/centroid_error_m", e)?;
        }
        Ok(())
    }
}

impl Logger {
    /// The frames come again at the smoothed poses, logged over the pass before at the same
    /// times (their plots on series of their own); the refined track restarts.
    fn smoothed(&mut self) -> Result<(), VizError> {
        self.pass_suffix = "/smoothed";
        self.repass(
            "SMOOTHED: every pose was solved again over the whole replay and kept (its grid finds as many objects); the replay is fused again at those poses",
            rerun::TextLogLevel::INFO,
        )
    }
    /// The frames come again at /odom, logged over the refined pass at the same times (their
    /// plots on series of their own); the refined track restarts with each frame's verdict
    /// (rolled-back frames red).
    fn rollback(&mut self) -> Result<(), VizError> {
        self.pass_suffix = "/rolled_back";
        self.repass(
            "ROLLED BACK: the refined poses explained the frames worse than /odom; the replay is fused again at /odom",
            rerun::TextLogLevel::ERROR,
        )
    }
    /// A plot's value for the frame, on the series of the pass being shown.
    fn plot(&self, path: &str, v: f64) -> Result<(), VizError> {
        self.rec
            .log(
                format!("{path}{}", self.pass_suffix),
                &rerun::Scalars::single(v),
            )
            .map_err(log_err)
    }

    /// A pass shown again: the refined track restarts and the verdict log says why.
    fn repass(&mut self, why: &str, level: &str) -> Result<(), VizError> {
        self.refined_track.clear();
        self.refined_colors.clear();
        self.rec
            .log(VERDICT_LOG, &rerun::TextLog::new(why).with_level(level))
            .map_err(log_err)
    }
}

impl Observer for FuseViz {
    fn on_start(&mut self, data: &SessionData, grid: &Grid) -> Result<(), ObserverError> {
        let mut logger = Logger {
            rec: self.rec.clone(),
            options: self.options.clone(),
            camera: data.camera,
            dynamic_mount: data.tf.is_dynamic(),
            refined_track: Vec::new(),
            refined_colors: Vec::new(),
            first_position: None,
            pass_suffix: "",
        };
        let (queue, inbox) = std::sync::mpsc::sync_channel::<Message>(QUEUED_FRAMES);
        let handle = std::thread::Builder::new()
            .name("objloc-viz".into())
            .spawn(move || {
                for message in inbox {
                    logger.handle(message)?;
                }
                Ok(())
            })
            .map_err(|e| VizError::Log(format!("cannot start the logging thread: {e}")))?;
        self.worker = Some(Worker { queue, handle });
        let start = Self::start_message(data, grid);
        Ok(self.send(Message::Start(Box::new(start)))?)
    }
    fn on_frame(
        &mut self,
        data: &SessionData,
        step: &FrameStep,
        grid: &Grid,
    ) -> Result<(), ObserverError> {
        let message = self.message(data, step, grid);
        Ok(self.send(Message::Frame(Box::new(message)))?)
    }
    fn on_rollback(&mut self, _data: &SessionData) -> Result<(), ObserverError> {
        Ok(self.send(Message::Rollback)?)
    }
    fn on_smoothed(&mut self, _data: &SessionData) -> Result<(), ObserverError> {
        Ok(self.send(Message::Smoothed)?)
    }
}
