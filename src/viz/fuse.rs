//! The fuser in Rerun: an [`Observer`] that streams each replay step (robot pose and
//! trajectories, camera frame and tile probabilities, pyramids, the belief grid, objects,
//! projections and plots). Entity paths are listed in docs/rerun.md.
//!
//! Invariants: everything logged is a function of the replay step and the grid (no clock, no
//! randomness, cells and tiles visited in index order), stamped on the `log_time` timeline
//! with the frame's MCAP log time and on `frame` with its index; session-wide things (camera
//! mount, intrinsics, ground-truth boxes) are static. Observing never changes the replay.

use nalgebra::Point3;
use rerun::RecordingStream;

use super::{TIMELINE_FRAME, TIMELINE_LOG_TIME, VizError, log_err, viridis};
use objloc_core::fuse::grid::{Grid, sigmoid};
use objloc_core::fuse::objects::Object;
use objloc_core::fuse::refine::Verdict;
use objloc_core::fuse::replay::{FrameStep, Observer, SessionData};
use objloc_core::types::probs::TileProbs;
use objloc_core::types::image::Rgb8;
use objloc_core::types::geometry::{Camera, Iso3, yaw_of};
use objloc_core::io::msgs::iso_from_pose;
use rayon::prelude::*;

/// What the fuse stream shows.
#[derive(Debug, Clone, PartialEq)]
pub struct VizOptions {
    /// Cells shown in `world/grid`: posterior above this...
    pub grid_min_posterior: f32,
    /// ...and seen by at least this many frames.
    pub grid_min_views: u16,
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
            pyramid_min_p: 0.5,
            pyramid_depth_m: 3.0,
        }
    }
}

const TRUTH_RGB: [u8; 3] = [255, 140, 0];
const ESTIMATE_RGB: [u8; 3] = [0, 200, 255];
const ODOM_RGB: [u8; 3] = [220, 220, 220];
/// The refined trajectory: green, beside odometry's grey and the truth's orange.
const REFINED_RGB: [u8; 3] = [60, 200, 90];

/// Trajectory entities, drawn in `world` coordinates under the moving `world/robot`; the
/// refined ones exist only when refining.
const ODOMETRY_TRACK: &str = "world/robot/odometry";
const TRUTH_TRACK: &str = "world/robot/ground_truth";
const REFINED_TRACKS: [&str; 2] = ["world/robot/refined", "world/robot/refined/frames"];
/// Rerun's implicit frame of the `world` entity.
const WORLD_FRAME: &str = "tf#/world";
/// One line per refined frame: the verdict and its numbers; the rollback, when it happens.
const VERDICT_LOG: &str = "refinement";

/// Colour of a frame's refinement verdict on the refined track: green when the pose was
/// measured, grey without evidence, yellow/orange when the correction was refused, red when
/// rolled back (visible at a glance).
pub fn verdict_rgb(v: Verdict) -> [u8; 3] {
    match v {
        Verdict::Accepted => [60, 200, 90],
        Verdict::Insignificant => [150, 220, 160],
        Verdict::NoEvidence => [150, 150, 150],
        Verdict::Ambiguous => [240, 220, 40],
        Verdict::Gated => [255, 150, 30],
        Verdict::RolledBack => [230, 30, 30],
    }
}

/// Streams a replay to a recording.
pub struct FuseViz {
    rec: RecordingStream,
    options: VizOptions,
    /// Refined robot positions of the frames so far (empty unless refining).
    refined_track: Vec<[f32; 3]>,
    /// The colour of each refined position's verdict.
    refined_colors: Vec<rerun::Color>,
    /// The first frame's position: it anchors the refined trajectory, which starts there
    /// although that frame carries no correction.
    first_position: Option<[f32; 3]>,
}

impl FuseViz {
    pub fn new(rec: RecordingStream, options: VizOptions) -> Self {
        Self {
            rec,
            options,
            refined_track: Vec::new(),
            refined_colors: Vec::new(),
            first_position: None,
        }
    }
}

/// Whole-grid numbers and the cells worth showing, in one pass over the grid.
#[derive(Debug, Clone, PartialEq)]
pub struct GridSummary {
    pub max_posterior: f64,
    /// Mean binary entropy of a cell, bits.
    pub mean_entropy_bits: f64,
    /// (i, j, k) and posterior of the shown cells, in index order.
    pub cells: Vec<([i32; 3], f32)>,
    /// Mean posterior along x: ny x nz, row-major as an image with z up (row 0 = top z).
    pub along_x: Vec<f32>,
    /// Mean posterior along y: nx wide, nz high, z up.
    pub along_y: Vec<f32>,
    /// Mean posterior along z: nx wide, ny high, y up.
    pub along_z: Vec<f32>,
}

fn binary_entropy_bits(p: f64) -> f64 {
    let h = |q: f64| if q > 0.0 { -q * q.log2() } else { 0.0 };
    h(p) + h(1.0 - p)
}

pub fn summarize_grid(grid: &Grid, min_posterior: f32, min_views: u16) -> GridSummary {
    let [nx, ny, nz] = grid.spec.dims;
    let mut along_x = vec![0f64; ny * nz];
    let mut along_y = vec![0f64; nx * nz];
    let mut along_z = vec![0f64; nx * ny];
    let mut cells = Vec::new();
    let mut max_l = f32::NEG_INFINITY;
    let mut entropy = 0.0;
    // The transcendental part in parallel, per cell; the sums below stay sequential in index
    // order, so the result does not depend on the thread count.
    // Most cells hold one of few values (the prior, outside every view, comes in long runs
    // along a column), so each column remembers its last value: a pure function of the cell's
    // log-odds either way.
    let mut p_h: Vec<(f64, f64)> = vec![(0.0, 0.0); grid.log_odds.len()];
    p_h.par_chunks_mut(nz.max(1))
        .zip(grid.log_odds.par_chunks(nz.max(1)))
        .for_each(|(out, col)| {
            let mut last: Option<(u32, (f64, f64))> = None;
            for (o, &l) in out.iter_mut().zip(col) {
                *o = match last {
                    Some((bits, v)) if bits == l.to_bits() => v,
                    _ => {
                        let p = sigmoid(f64::from(l));
                        let v = (p, binary_entropy_bits(p));
                        last = Some((l.to_bits(), v));
                        v
                    }
                };
            }
        });
    for i in 0..nx {
        for j in 0..ny {
            for k in 0..nz {
                let idx = grid.spec.index(i, j, k);
                max_l = max_l.max(grid.log_odds[idx]);
                let (p, h) = p_h[idx];
                entropy += h;
                let (rz, ry) = (nz - 1 - k, ny - 1 - j);
                along_x[rz * ny + j] += p;
                along_y[rz * nx + i] += p;
                along_z[ry * nx + i] += p;
                if p as f32 > min_posterior && grid.views[idx] >= min_views {
                    cells.push(([i as i32, j as i32, k as i32], p as f32));
                }
            }
        }
    }
    let n = grid.spec.cells().max(1) as f64;
    let mean = |v: Vec<f64>, d: usize| v.into_iter().map(|s| (s / d as f64) as f32).collect();
    GridSummary {
        max_posterior: sigmoid(f64::from(max_l)),
        mean_entropy_bits: entropy / n,
        cells,
        along_x: mean(along_x, nx),
        along_y: mean(along_y, ny),
        along_z: mean(along_z, nz),
    }
}

/// Tile probabilities as one f32 per image pixel (0 outside whole tiles: "no value").
pub fn upscale(probs: &TileProbs, width: u32, height: u32) -> Vec<f32> {
    let t = probs.tile_px.max(1) as usize;
    let mut out = vec![0f32; width as usize * height as usize];
    for y in 0..height as usize {
        let r = y / t;
        if r >= probs.rows {
            break;
        }
        for x in 0..(width as usize).min(probs.cols * t) {
            out[y * width as usize + x] = probs.p[r * probs.cols + x / t];
        }
    }
    out
}

/// Line strips of the pyramids of tiles with p > `min_p`: four edges from the eye and the far
/// rectangle at `depth_m` along the optical axis, in odom, with each tile's probability.
pub fn pyramids(
    camera: &Camera,
    odom_from_camera: &Iso3,
    probs: &TileProbs,
    min_p: f32,
    depth_m: f64,
) -> Vec<(Vec<[f32; 3]>, f32)> {
    let eye = odom_from_camera.translation.vector;
    let eye = [eye.x as f32, eye.y as f32, eye.z as f32];
    let t = f64::from(probs.tile_px);
    let far = |u: f64, v: f64| {
        let r = camera.ray(u, v);
        let p = odom_from_camera * Point3::from(r * (depth_m / r.z));
        [p.x as f32, p.y as f32, p.z as f32]
    };
    let mut out = Vec::new();
    for r in 0..probs.rows {
        for c in 0..probs.cols {
            let p = probs.p[r * probs.cols + c];
            if p.is_nan() || p <= min_p {
                continue;
            }
            let (u0, v0) = (c as f64 * t, r as f64 * t);
            let corners = [
                far(u0, v0),
                far(u0 + t, v0),
                far(u0 + t, v0 + t),
                far(u0, v0 + t),
            ];
            for k in corners {
                out.push((vec![eye, k], p));
            }
            let mut rect = corners.to_vec();
            rect.push(corners[0]);
            out.push((rect, p));
        }
    }
    out
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

/// Distance from the first (most massive) object's centroid to the nearest true box centre.
pub fn centroid_error_m(objects: &[Object], data: &SessionData) -> Option<f64> {
    let o = objects.first()?;
    let gt = data.ground_truth.as_ref()?;
    gt.box_center
        .iter()
        .map(|c| {
            let d: f64 = (0..3)
                .map(|a| (o.centroid_m[a] - c.position[a]).powi(2))
                .sum();
            d.sqrt()
        })
        .min_by(f64::total_cmp)
}

pub(crate) fn depth_image(p: Vec<f32>, width: u32, height: u32) -> rerun::DepthImage {
    let bytes: Vec<u8> = p.iter().flat_map(|v| v.to_le_bytes()).collect();
    rerun::DepthImage::from_data_type_and_bytes(bytes, [width, height], rerun::ChannelDatatype::F32)
        .with_meter(1.0)
        .with_colormap(rerun::components::Colormap::Viridis)
        .with_depth_range([0.0, 1.0])
}

/// Viridis RGBA overlay: alpha grows with p so that confident tiles tint the frame.
pub fn overlay_rgba(p: &[f32]) -> Vec<u8> {
    let mut out = Vec::with_capacity(p.len() * 4);
    for &v in p {
        let [r, g, b] = viridis(v);
        let a = if v > 0.0 {
            (40.0 + 180.0 * v.clamp(0.0, 1.0)).round() as u8
        } else {
            0
        };
        out.extend_from_slice(&[r, g, b, a]);
    }
    out
}

/// Logs a frame, its tile probabilities (hoverable f32) and a viridis overlay under `base`.
pub(crate) fn log_frame_and_probs(
    rec: &RecordingStream,
    base: &str,
    image: &Rgb8,
    probs: &TileProbs,
) -> Result<(), VizError> {
    rec.log(
        format!("{base}/image"),
        &rerun::Image::from_rgb24(image.data.clone(), [image.width, image.height]),
    )
    .map_err(log_err)?;
    let p = upscale(probs, image.width, image.height);
    rec.log(
        format!("{base}/overlay"),
        &rerun::Image::from_rgba32(overlay_rgba(&p), [image.width, image.height])
            .with_draw_order(10.0),
    )
    .map_err(log_err)?;
    rec.log(
        format!("{base}/probability"),
        &depth_image(p, image.width, image.height),
    )
    .map_err(log_err)?;
    Ok(())
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

fn scalar(rec: &RecordingStream, path: &str, v: f64) -> Result<(), VizError> {
    rec.log(path, &rerun::Scalars::single(v)).map_err(log_err)
}

/// Declares `entity`'s data to be in the `world` entity's frame (statically).
fn in_world_frame(rec: &RecordingStream, entity: &str) -> Result<(), VizError> {
    rec.log_static(entity, &rerun::CoordinateFrame::new(WORLD_FRAME))
        .map_err(log_err)
}

impl FuseViz {
    fn start(&mut self, data: &SessionData, grid: &Grid) -> Result<(), VizError> {
        let rec = &self.rec;
        rec.log_static("world", &rerun::ViewCoordinates::RIGHT_HAND_Z_UP())
            .map_err(log_err)?;
        rec.log_static("world/robot/camera", &transform(&data.base_from_camera))
            .map_err(log_err)?;
        // The trajectories live beside the robot they trace (`world/robot/...`) but are in
        // world coordinates: each declares the `world` entity's frame as its own, so the
        // robot's moving transform does not carry them along.
        let truth = (!data.ground_truth_poses.is_empty()).then_some(TRUTH_TRACK);
        for track in std::iter::once(ODOMETRY_TRACK).chain(truth) {
            in_world_frame(rec, track)?;
        }
        let c = &data.camera;
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
        let lo = grid.spec.origin_m;
        let hi = grid.spec.max_m();
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
        if let Some(b) = truth_boxes(data) {
            rec.log_static("world/objects/truth", &b).map_err(log_err)?;
        }
        Ok(())
    }

    fn frame(&mut self, data: &SessionData, step: &FrameStep, grid: &Grid) -> Result<(), VizError> {
        let rec = &self.rec;
        let o = &self.options;
        rec.set_time(
            TIMELINE_LOG_TIME,
            rerun::TimeCell::from_timestamp_nanos_since_epoch(
                step.frame.log_time_ns.min(i64::MAX as u64) as i64,
            ),
        );
        rec.set_time_sequence(TIMELINE_FRAME, step.index as i64);

        rec.log("world/robot", &transform(&step.odom_from_base))
            .map_err(log_err)?;
        let stamp = step.frame.stamp_ns;
        rec.log(
            ODOMETRY_TRACK,
            &rerun::LineStrips3D::new([track_until(data.odom.poses(), stamp)]).with_colors([
                rerun::Color::from_rgb(ODOM_RGB[0], ODOM_RGB[1], ODOM_RGB[2]),
            ]),
        )
        .map_err(log_err)?;
        if !data.ground_truth_poses.is_empty() {
            rec.log(
                TRUTH_TRACK,
                &rerun::LineStrips3D::new([track_until(data.ground_truth_poses.poses(), stamp)])
                    .with_colors([rerun::Color::from_rgb(
                        TRUTH_RGB[0],
                        TRUTH_RGB[1],
                        TRUTH_RGB[2],
                    )]),
            )
            .map_err(log_err)?;
        }

        let t = step.odom_from_base.translation.vector;
        let here = [t.x as f32, t.y as f32, t.z as f32];
        if self.first_position.is_none() {
            self.first_position = Some(here);
        }
        if let Some(c) = &step.correction {
            if self.refined_track.is_empty() {
                for track in REFINED_TRACKS {
                    in_world_frame(rec, track)?;
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
            let color = rerun::Color::from_rgb(REFINED_RGB[0], REFINED_RGB[1], REFINED_RGB[2]);
            rec.log(
                REFINED_TRACKS[0],
                &rerun::LineStrips3D::new([self.refined_track.clone()]).with_colors([color]),
            )
            .map_err(log_err)?;
            rec.log(
                REFINED_TRACKS[1],
                &rerun::Points3D::new(self.refined_track.clone())
                    .with_colors(self.refined_colors.clone())
                    .with_radii([0.03]),
            )
            .map_err(log_err)?;
            let level = match c.outcome {
                Verdict::Accepted | Verdict::Insignificant | Verdict::NoEvidence => {
                    rerun::TextLogLevel::INFO
                }
                Verdict::Ambiguous | Verdict::Gated => rerun::TextLogLevel::WARN,
                Verdict::RolledBack => rerun::TextLogLevel::ERROR,
            };
            rec.log(
                VERDICT_LOG,
                &rerun::TextLog::new(format!(
                    "frame {}: {} (gain {:.1}, {} landmark(s), {} floor cells, total chi-square {:.1})",
                    step.index,
                    c.outcome.label(),
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
            scalar(rec, "plots/correction_m", (t - o).xy().norm())?;
            scalar(
                rec,
                "plots/correction_deg",
                yaw_of(&(step.odometry.inverse() * step.odom_from_base)).to_degrees(),
            )?;
            scalar(rec, "counts/landmarks", c.anchors as f64)?;
            scalar(rec, "counts/floor_cells", c.floor_cells as f64)?;
        }
        log_frame_and_probs(rec, "world/robot/camera", &step.image, &step.probs)?;

        let strips = pyramids(
            &data.camera,
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

        let s = summarize_grid(grid, o.grid_min_posterior, o.grid_min_views);
        let v = grid.spec.voxel_size_m as f32;
        let origin = grid.spec.origin_m;
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
        let [nx, ny, nz] = grid.spec.dims;
        projection(rec, "projections/x", &s.along_x, ny, nz)?;
        projection(rec, "projections/y", &s.along_y, nx, nz)?;
        projection(rec, "projections/z", &s.along_z, nx, ny)?;

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

        scalar(rec, "plots/max_posterior", s.max_posterior)?;
        scalar(rec, "plots/mean_entropy_bits", s.mean_entropy_bits)?;
        scalar(rec, "counts/cells_updated", step.cells_updated as f64)?;
        scalar(rec, "counts/objects", objects.len() as f64)?;
        if let Some(e) = centroid_error_m(objects, data) {
            scalar(rec, "plots/centroid_error_m", e)?;
        }
        Ok(())
    }
}

impl Observer for FuseViz {
    fn on_start(&mut self, data: &SessionData, grid: &Grid) -> anyhow::Result<()> {
        Ok(self.start(data, grid)?)
    }
    fn on_frame(
        &mut self,
        data: &SessionData,
        step: &FrameStep,
        grid: &Grid,
    ) -> anyhow::Result<()> {
        Ok(self.frame(data, step, grid)?)
    }
    fn on_rollback(&mut self, _data: &SessionData) -> anyhow::Result<()> {
        // The frames come again at /odom, logged over the refined pass at the same times; the
        // refined track restarts with each frame's verdict (rolled-back frames red).
        self.refined_track.clear();
        self.refined_colors.clear();
        self.rec
            .log(
                VERDICT_LOG,
                &rerun::TextLog::new(
                    "ROLLED BACK: the refined poses explained the frames worse than /odom; the replay is fused again at /odom",
                )
                .with_level(rerun::TextLogLevel::ERROR),
            )
            .map_err(log_err)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use objloc_core::fuse::grid::{GridSpec, logit};
    use objloc_core::types::geometry::iso_from_xy_yaw;

    #[test]
    fn upscale_repeats_tiles_and_leaves_partial_edges_empty() {
        let probs = TileProbs {
            rows: 1,
            cols: 2,
            tile_px: 2,
            p: vec![0.25, 0.75],
        };
        // 5 x 3 image: tiles cover x 0..4, y 0..2; column 4 and row 2 stay 0.
        let up = upscale(&probs, 5, 3);
        assert_eq!(
            up,
            vec![
                0.25, 0.25, 0.75, 0.75, 0.0, 0.25, 0.25, 0.75, 0.75, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
            ]
        );
    }

    #[test]
    fn pyramid_of_the_centre_tile_reaches_the_depth_along_the_axis() {
        // 4 x 4 image, fx = fy = 2, centre (2, 2): the tile (1, 1) of 2 px spans u, v in [2, 4],
        // so its far corners at depth 3 are x, y in {0, 3} (x = (u - 2) / 2 * 3).
        let camera = Camera {
            width: 4,
            height: 4,
            fx: 2.0,
            fy: 2.0,
            cx: 2.0,
            cy: 2.0,
        };
        let probs = TileProbs {
            rows: 2,
            cols: 2,
            tile_px: 2,
            p: vec![0.1, 0.2, 0.3, 0.9],
        };
        let s = pyramids(&camera, &Iso3::identity(), &probs, 0.5, 3.0);
        assert_eq!(
            s.len(),
            5,
            "one tile above 0.5: 4 edges + the far rectangle"
        );
        assert_eq!(s[0].0, vec![[0.0, 0.0, 0.0], [0.0, 0.0, 3.0]]);
        assert_eq!(s[2].0[1], [3.0, 3.0, 3.0]);
        assert_eq!(s[4].0.len(), 5);
        assert_eq!(s[4].0[0], s[4].0[4]);
        assert!(s.iter().all(|(_, p)| *p == 0.9));
        // Moved 1 m along x in odom: every point moves with it.
        let moved = pyramids(&camera, &iso_from_xy_yaw(1.0, 0.0, 0.0), &probs, 0.5, 3.0);
        assert_eq!(moved[2].0[1], [4.0, 3.0, 3.0]);
    }

    #[test]
    fn grid_summary_projections_entropy_and_shown_cells() {
        let spec = GridSpec {
            origin_m: [0.0; 3],
            voxel_size_m: 1.0,
            dims: [2, 1, 2],
        };
        let mut grid = Grid::new(spec, 0.5).unwrap();
        // Cell (1, 0, 1) at p = 0.8 seen twice; cell (0, 0, 0) at p = 0.8 seen once.
        let hi = logit(0.8) as f32;
        let a = spec.index(1, 0, 1);
        let b = spec.index(0, 0, 0);
        grid.log_odds[a] = hi;
        grid.views[a] = 2;
        grid.log_odds[b] = hi;
        grid.views[b] = 1;
        let s = summarize_grid(&grid, 0.5, 2);
        assert_eq!(s.cells, vec![([1, 0, 1], 0.8)]);
        assert!((s.max_posterior - 0.8).abs() < 1e-6);
        // H(0.8) = 0.7219 bits, H(0.5) = 1: mean over 4 cells (2 * 0.7219 + 2) / 4.
        assert!(
            (s.mean_entropy_bits - 0.860_964).abs() < 1e-5,
            "{}",
            s.mean_entropy_bits
        );
        // Along z (x wide, y high): x = 0 -> (0.8 + 0.5) / 2, x = 1 -> (0.5 + 0.8) / 2.
        assert!(s.along_z.iter().all(|v| (v - 0.65).abs() < 1e-6));
        // Along y (x wide, z up): top row is k = 1: [0.5, 0.8]; bottom k = 0: [0.8, 0.5].
        let want = [0.5, 0.8, 0.8, 0.5];
        assert!(
            s.along_y
                .iter()
                .zip(want)
                .all(|(v, w)| (v - w).abs() < 1e-6),
            "{:?}",
            s.along_y
        );
        // Along x (y wide = 1, z up): k = 1 -> (0.5 + 0.8) / 2, k = 0 -> (0.8 + 0.5) / 2.
        assert!(s.along_x.iter().all(|v| (v - 0.65).abs() < 1e-6));
    }

    #[test]
    fn overlay_alpha_grows_with_p_and_empty_pixels_are_clear() {
        let o = overlay_rgba(&[0.0, 1.0]);
        assert_eq!(o, vec![68, 1, 84, 0, 253, 231, 37, 220]);
    }
}
