//! Imports a real posed image sequence into a session: the images with their poses and
//! intrinsics from a TUM RGB-D trajectory plus pinhole intrinsics, a NeRF / instant-ngp /
//! nerfstudio `transforms.json`, a COLMAP model, an LLFF `poses_bounds.npy` or an IDR / DTU
//! `cameras.npz`; labels from a CSV (`image,x,y,width,height[,object]`) or a mask folder.
//!
//! Frames: the world frame of the poses becomes `odom`; `base_link` IS the camera, so
//! /tf_static publishes an identity `base_link -> camera_optical_frame` and /odom carries the
//! camera pose (optical centre, OpenCV axes: z forward, x right, y down). The world need not
//! be z-up nor metric. No /cmd_vel is written: the motion between frames is unknown, so the
//! fuser uses no motion model for such a session. Each frame has its own CameraInfo, with the
//! lens distortion as `plumb_bob` `d`.
//!
//! Matching (TUM): images are sorted by file name. If every file stem parses as a decimal
//! number of seconds (TUM's `1305031102.175304.png`), each image is stamped with it and posed
//! by interpolating the trajectory (at most [`tum::MAX_EXTRAPOLATION_NS`] beyond its ends);
//! otherwise image i takes trajectory line i (stamp and pose), and the counts must be equal.
//! Pose files without time (the others) are ordered by file name, numbers compared as numbers
//! (`2.jpg` before `10.jpg`), and stamped [`CAPTURE_PERIOD_NS`] apart from
//! [`CAPTURE_START_NS`].
//!
//! Invariants: every error names the file and line (or image, frame or entry) at fault; the
//! output is written through `.partial` and only renamed when complete.

mod labels;
mod tum;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use image::ImageDecoder;

use thiserror::Error;

pub use labels::{LabelRow, Labels, labels_from_masks, parse_labels};
pub use tum::{MAX_EXTRAPOLATION_NS, Matching, TrajectoryPose, parse_seconds_ns, parse_trajectory};

use crate::io::capture::{CaptureError, Intrinsics, PosedImage};
use crate::io::msgs::pose_from_iso;
use crate::io::msgs::{
    CameraInfo, CompressedImage, Header, ObjectLabel, Odometry, TfMessage, TransformStamped, Twist,
};
use crate::io::session::{SessionError, SessionWriter, Topics};
use crate::types::geometry::{Camera, Iso3};
use crate::types::lens::Distortion;

/// Stamp of the first frame of a capture whose pose file has no time: 1 s after the epoch.
pub const CAPTURE_START_NS: i64 = 1_000_000_000;
/// Spacing of the frames of a capture whose pose file has no time: 0.1 s.
pub const CAPTURE_PERIOD_NS: i64 = 100_000_000;
const IMAGE_EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

/// Why a sequence cannot be imported; each names the file at fault.
#[derive(Debug, Error)]
pub enum ImportError {
    /// A file or folder cannot be read or used: the pose file, trajectory, labels, an image
    /// or a mask, with the line, frame or entry at fault.
    #[error(transparent)]
    File(#[from] CaptureError),
    /// Boxed: a session error carries an MCAP error and the place it happened.
    #[error(transparent)]
    Session(Box<SessionError>),
}

impl From<SessionError> for ImportError {
    fn from(e: SessionError) -> Self {
        Self::Session(Box::new(e))
    }
}

/// Where the poses and intrinsics of the images come from.
#[derive(Debug, Clone, PartialEq)]
pub enum PoseFile {
    /// A TUM trajectory for the images of a folder, with one pinhole camera for all.
    Tum {
        /// The trajectory file.
        trajectory: PathBuf,
        /// The folder of images.
        images: PathBuf,
        /// fx, fy, cx, cy in pixels of the image files.
        camera: [f64; 4],
        /// Lens distortion of the image files (zero for none).
        distortion: Distortion,
    },
    /// NeRF / instant-ngp / nerfstudio `transforms.json` (image paths relative to it).
    Nerf {
        /// The `transforms.json` file.
        transforms: PathBuf,
    },
    /// A COLMAP model folder (`cameras`/`images` as `.txt` or `.bin`).
    Colmap {
        /// The folder holding the model files.
        model: PathBuf,
        /// The folder the model's image names are relative to.
        images: PathBuf,
    },
    /// LLFF `poses_bounds.npy`, one row per image of the folder in string order.
    Llff {
        /// The `.npy` file.
        poses_bounds: PathBuf,
        /// The folder of images.
        images: PathBuf,
    },
    /// IDR / NeuS / DTU `cameras.npz` (`world_mat_i` per image of the folder, in name order).
    Idr {
        /// The `.npz` file.
        cameras: PathBuf,
        /// The folder of images.
        images: PathBuf,
        /// x0, y0, width, height of the calibrated image that the files are a crop of.
        crop: Option<[f64; 4]>,
    },
}

/// What to import and how to label it.
#[derive(Debug, Clone, PartialEq)]
pub struct ImportOptions {
    /// Poses and intrinsics.
    pub poses: PoseFile,
    /// Labels CSV `image,x,y,width,height[,object]`.
    pub labels: Option<PathBuf>,
    /// Folder of masks, one per labelled image, turned into rectangles.
    pub masks: Option<PathBuf>,
    /// Object name written on /labels for rows (and masks) that name none.
    pub object: String,
}

/// What an import wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct ImportStats {
    /// The session written.
    pub path: PathBuf,
    /// Camera frames written.
    pub frames: usize,
    /// Frames with at least one label message.
    pub labelled: usize,
    /// How a TUM import paired images with poses; `None` for the other pose files (their
    /// images are named in the pose file and stamped in natural file-name order).
    pub tum_matching: Option<Matching>,
    /// Frames whose intrinsics carry a lens distortion.
    pub distorted: usize,
    /// What a user should check about the poses and the camera, in words (the imported
    /// session is written all the same).
    pub notes: Vec<String>,
    /// Images whose EXIF orientation asks a viewer to turn or flip them, and the first's
    /// name and what its tag asks (see [`exif_turn`]).
    pub exif_turned: Option<ExifTurned>,
    /// Label rows of images left out of the session
    /// ([`Matching::FileNameStampsWithout`]).
    pub label_rows_left_out: usize,
}

/// How many images carry an EXIF orientation other than "as stored", the first's name, and
/// what its tag asks of a viewer.
pub type ExifTurned = (usize, String, &'static str);

/// One image to write: its file, stamp, camera pose and intrinsics.
#[derive(Debug, Clone, PartialEq)]
struct Frame {
    path: PathBuf,
    stamp_ns: i64,
    world_from_camera: Iso3,
    intrinsics: Intrinsics,
}

fn list_images(dir: &Path) -> Result<Vec<PathBuf>, ImportError> {
    let io = |source| {
        ImportError::File(CaptureError::Io {
            path: dir.into(),
            source,
        })
    };
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(io)? {
        let p = entry.map_err(io)?.path();
        let ext = p
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .unwrap_or_default();
        if p.is_file() && IMAGE_EXTENSIONS.contains(&ext.as_str()) {
            files.push(p);
        }
    }
    // Natural order (`frame_2` before `frame_10`), as the other importers: a TUM trajectory
    // matched to images in order pairs line i with the i-th frame a camera wrote, and plain
    // string order put `frame_10` second (42 of 43 images of an unpadded capture on the
    // wrong pose, silently).
    files.sort_by_cached_key(|p| natural_key(&name_of(p)));
    if files.is_empty() {
        return Err(ImportError::File(CaptureError::Invalid {
            path: dir.into(),
            what: "no .png/.jpg/.jpeg images".into(),
        }));
    }
    Ok(files)
}

/// Sort key comparing runs of digits as numbers: `IMG_2` before `IMG_10`.
fn natural_key(name: &str) -> Vec<(u8, u64, String)> {
    let mut key = Vec::new();
    let mut rest = name;
    while !rest.is_empty() {
        let digits = rest.bytes().take_while(u8::is_ascii_digit).count();
        let (run, tail) = if digits > 0 {
            rest.split_at(digits)
        } else {
            rest.split_at(
                rest.find(|c: char| c.is_ascii_digit())
                    .unwrap_or(rest.len()),
            )
        };
        key.push(match run.parse::<u64>() {
            Ok(n) if digits > 0 => (0, n, run.to_owned()),
            _ => (1, 0, run.to_owned()),
        });
        rest = tail;
    }
    key
}

/// The frames of a pose file without time, in natural file-name order, stamped at a fixed
/// period.
fn capture_frames(mut images: Vec<PosedImage>) -> Vec<Frame> {
    images.sort_by_cached_key(|p| natural_key(&name_of(&p.path)));
    images
        .into_iter()
        .enumerate()
        .map(|(i, p)| Frame {
            path: p.path,
            stamp_ns: CAPTURE_START_NS + i as i64 * CAPTURE_PERIOD_NS,
            world_from_camera: p.world_from_camera,
            intrinsics: p.intrinsics,
        })
        .collect()
}

/// The frames to write and, for a TUM import, how images were matched to poses and what
/// to note about the trajectory.
type Framed = (Vec<Frame>, Option<Matching>, Option<String>);

/// [`Framed`] of the pose file.
fn frames(poses: &PoseFile) -> Result<Framed, ImportError> {
    use crate::io::capture::{read_colmap, read_idr, read_llff, read_nerf};
    let posed = match poses {
        PoseFile::Tum {
            trajectory,
            images,
            camera,
            distortion,
        } => {
            let first = list_images(images)?;
            let size = crate::io::capture::image_size(&first[0])?;
            let intrinsics = tum_intrinsics(trajectory, *camera, *distortion, size)?;
            let (frames, matching, note) = tum::tum_frames(trajectory, images, intrinsics)?;
            return Ok((frames, Some(matching), note));
        }
        PoseFile::Nerf { transforms } => read_nerf(transforms)?,
        PoseFile::Colmap { model, images } => read_colmap(model, images)?,
        PoseFile::Llff {
            poses_bounds,
            images,
        } => read_llff(poses_bounds, images)?,
        PoseFile::Idr {
            cameras,
            images,
            crop,
        } => read_idr(cameras, images, *crop)?,
    };
    Ok((capture_frames(posed), None, None))
}

/// The `--camera` intrinsics of a TUM import, refused unless a pinhole camera.
fn tum_intrinsics(
    trajectory: &Path,
    camera: [f64; 4],
    distortion: Distortion,
    (width, height): (u32, u32),
) -> Result<Intrinsics, ImportError> {
    let [fx, fy, cx, cy] = camera;
    // Typed by hand, so checked against the images: a principal point outside them is
    // intrinsics for another image size (or in another order), and every ray would be off.
    if !(cx > 0.0 && cx < f64::from(width) && cy > 0.0 && cy < f64::from(height)) {
        return Err(ImportError::File(CaptureError::Invalid {
            path: trajectory.into(),
            what: format!(
                "--camera {fx},{fy},{cx},{cy}: the principal point ({cx}, {cy}) lies outside the {width} x {height} images: intrinsics for another image size, or not in the order FX,FY,CX,CY?"
            ),
        }));
    }
    let d = distortion.to_plumb_bob();
    let lens = crate::io::msgs::MAX_DISTORTION_COEFFICIENT;
    Camera::from_k(width, height, [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0])
        .filter(|_| crate::io::msgs::lens_coefficients_plausible(&d))
        .map(|camera| Intrinsics { camera, distortion })
        .ok_or_else(|| {
            ImportError::File(CaptureError::Invalid {
                path: trajectory.into(),
                what: format!(
                    "--camera {fx},{fy},{cx},{cy} on {width} x {height} images: focal lengths must \
                 be positive and all finite, the principal point within an image's size of the \
                 image (and the distortion's coefficients at most {lens} in size)"
                ),
            })
        })
}

/// Imports the sequence into `out` (via `out.partial`); `progress(done, total)` per frame.
pub fn import(
    opts: &ImportOptions,
    out: &Path,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<ImportStats, ImportError> {
    let (frames, tum_matching, trajectory_note) = frames(&opts.poses)?;
    check_stamps(&frames)?;
    let left_out = match &tum_matching {
        Some(Matching::FileNameStampsWithout(names)) => names.as_slice(),
        _ => &[],
    };
    let (labels, rows_left_out) = read_labels(opts, &frames, left_out)?;
    let result = write_session(opts, out, &frames, labels.as_ref(), progress);
    if result.is_err() {
        // An error leaves nothing behind: no final file, no partial one.
        let _ = std::fs::remove_file(crate::io::output::partial_path(out));
    }
    result.map(|(path, labelled, exif_turned)| ImportStats {
        path,
        frames: frames.len(),
        labelled,
        tum_matching,
        distorted: frames
            .iter()
            .filter(|f| !f.intrinsics.distortion.is_zero())
            .count(),
        notes: camera_note(opts, &frames)
            .into_iter()
            .chain(trajectory_note)
            .chain(pose_notes(&frames))
            .chain(labels.as_ref().and_then(|l| scale_note(&l.1, &frames)))
            .collect(),
        exif_turned,
        label_rows_left_out: rows_left_out,
    })
}

/// Side of the corner every box may lie within, pixels, on images whose sides are at least
/// four times as long, before a note asks whether the boxes are percentages or fractions.
const SCALE_NOTE_PX: u32 = 100;

/// A note when every labelled box lies within the first [`SCALE_NOTE_PX`] pixels of much
/// larger images: labelling tools export boxes as percentages of the image (Label Studio)
/// or fractions (YOLO), which read as pixels put every box in the top-left corner.
fn scale_note(labels: &Labels, frames: &[Frame]) -> Option<String> {
    let c = &frames.first()?.intrinsics.camera;
    let boxes: Vec<&crate::io::msgs::RegionOfInterest> = labels
        .values()
        .flatten()
        .filter_map(|r| r.roi.as_ref())
        .collect();
    let small = c.width.min(c.height) >= 4 * SCALE_NOTE_PX
        && !boxes.is_empty()
        && boxes.iter().all(|r| {
            let end = |o: u32, n: u32| u64::from(o) + u64::from(n);
            end(r.x_offset, r.width) <= u64::from(SCALE_NOTE_PX)
                && end(r.y_offset, r.height) <= u64::from(SCALE_NOTE_PX)
        });
    small.then(|| {
        format!(
            "every labelled box lies within the first {SCALE_NOTE_PX} x {SCALE_NOTE_PX} pixels of the {} x {} images: are the labels percentages or fractions of the image (as labelling tools export them) rather than pixels?",
            c.width, c.height
        )
    })
}

/// Farthest a typed principal point may lie from the image's centre, as a fraction of the
/// image's size along that axis, before a note asks whether the intrinsics are for these
/// images: a camera's is within a few per cent; `--camera` for images twice as large puts
/// it near the far edge, for images half as large near a quarter.
const MAX_PRINCIPAL_OFFSET: f64 = 0.2;

/// A note when `--camera`'s principal point lies far from the images' centre (a TUM import;
/// the other pose files carry their own calibration).
fn camera_note(opts: &ImportOptions, frames: &[Frame]) -> Option<String> {
    let PoseFile::Tum { .. } = opts.poses else {
        return None;
    };
    let c = &frames.first()?.intrinsics.camera;
    let (w, h) = (f64::from(c.width), f64::from(c.height));
    let off = ((c.cx - w / 2.0).abs() / w).max((c.cy - h / 2.0).abs() / h);
    (off > MAX_PRINCIPAL_OFFSET).then(|| {
        format!(
            "--camera's principal point ({}, {}) lies {:.0} % of the image's size from the centre of the {} x {} images (a camera's is within a few per cent): are the intrinsics for images of this size, not for a scaled copy of them (scaling the images by s scales fx, fy, cx and cy by s)?",
            c.cx,
            c.cy,
            100.0 * off,
            c.width,
            c.height,
        )
    })
}

/// Most the cameras' optical axes may miss the point nearest all of them (rms, as a fraction
/// of the cameras' median distance from it), and least fraction of the cameras that must
/// face it, before a capture's poses are questioned. Measured: the real captures of
/// `../shared/realdata` 0.001-0.12, all facing; 90 simulated sessions taken as captures
/// (`scripts/measure_sim_captures.py`) at most 0.73, at least 0.52 facing (training
/// sessions, most of whose frames look away from the object on purpose; tours at most 0.5);
/// the fruit capture's poses inverted (world-to-camera) 0.82 with 0.54 facing, its
/// quaternions read w first 0.82 with 0.86 facing.
const MAX_AXES_MISS: f64 = 0.75;
const MIN_AXES_IN_FRONT: f64 = 0.5;

/// What a user should check about the poses, in words: OpenGL camera axes (y up, z back)
/// where OpenCV's (x right, y down, z forward) were due, when the cameras' +z axes meet behind
/// them but their -z axes meet in front; otherwise axes that meet nowhere in front of most
/// cameras, as inverted poses or quaternions in another order give. A capture around an
/// object converges; a camera driving forward converges neither way and gets no note.
fn pose_notes(frames: &[Frame]) -> Vec<String> {
    use crate::types::geometry::{axes_convergence, axes_fit};
    let poses: Vec<Iso3> = frames.iter().map(|f| f.world_from_camera).collect();
    if poses.len() < 3 {
        return Vec::new();
    }
    let flip = nalgebra::UnitQuaternion::from_axis_angle(
        &nalgebra::Vector3::x_axis(),
        std::f64::consts::PI,
    );
    let flipped: Vec<Iso3> = poses.iter().map(|p| p * flip).collect();
    if axes_convergence(&poses).is_none() && axes_convergence(&flipped).is_some() {
        return vec![
            "the cameras' optical axes (+z) do not meet in front of them, but their -z axes do: \
             are the poses in OpenGL camera axes (y up, z back)? A TUM trajectory and COLMAP \
             hold OpenCV axes (x right, y down, z forward)"
                .to_owned(),
        ];
    }
    let Some(fit) = axes_fit(&poses) else {
        return Vec::new();
    };
    let in_front = fit.in_front as f64 / poses.len() as f64;
    let miss = fit.rms_miss / fit.median_distance.max(f64::MIN_POSITIVE);
    if in_front >= MIN_AXES_IN_FRONT && miss <= MAX_AXES_MISS {
        return Vec::new();
    }
    vec![format!(
        "the cameras' optical axes do not meet around one place in front of them ({} of {} cameras face the point nearest all of them, and the axes miss it by {miss:.2} times the cameras' distance from it, rms): are the poses camera-to-world (as TUM and NeRF files hold them, not world-to-camera as COLMAP's images.txt), with quaternions in x y z w order? A capture around an object meets; a camera that does not circle one place may ignore this",
        fit.in_front,
        poses.len()
    )]
}

/// The labels from the CSV or the masks (with the file they came from), checked to name
/// only imported images.
fn read_labels(
    opts: &ImportOptions,
    frames: &[Frame],
    left_out: &[String],
) -> Result<(Option<(PathBuf, Labels)>, usize), ImportError> {
    let labels = match (&opts.labels, &opts.masks) {
        (Some(p), _) => {
            let text = std::fs::read_to_string(p).map_err(|source| {
                ImportError::File(CaptureError::Io {
                    path: p.clone(),
                    source,
                })
            })?;
            (p.clone(), parse_labels(p, &text)?)
        }
        (None, Some(dir)) => {
            let sized: Vec<(PathBuf, (u32, u32))> = frames
                .iter()
                .map(|f| {
                    let c = &f.intrinsics.camera;
                    (f.path.clone(), (c.width, c.height))
                })
                .collect();
            (dir.clone(), labels_from_masks(dir, &sized)?)
        }
        (None, None) => return Ok((None, 0)),
    };
    let names: Vec<String> = frames.iter().map(|f| name_of(&f.path)).collect();
    let mut resolved = Labels::new();
    let mut rows_left_out = 0;
    for (name, rows) in labels.1 {
        if frame_named(left_out, &name).is_ok() {
            rows_left_out += rows.len();
            continue;
        }
        let frame = frame_named(&names, &name).map_err(|stems| {
            let place = images_place(&opts.poses).display();
            ImportError::File(CaptureError::Line {
                path: labels.0.clone(),
                line: rows.first().map_or(0, |r| r.line),
                what: if stems > 1 {
                    format!("image {name:?} names {stems} images of {place} by their stem; name one with its extension")
                } else {
                    format!("image {name:?} is not in {place}")
                },
            })
        })?;
        resolved.entry(frame.to_owned()).or_default().extend(rows);
    }
    // Rows of one image named two ways (`rgb/1.png`, `1.png`) in the file's order.
    for rows in resolved.values_mut() {
        rows.sort_by_key(|r| r.line);
    }
    Ok((Some((labels.0, resolved)), rows_left_out))
}

/// The imported image a labels row names: its file name, or a path ending in it (`rgb/1.png`,
/// as TUM RGB-D's lists name frames), or the one image whose name differs only in case
/// (`IMG_1.JPG`) or whose stem is the row's name or its stem (`1`, or `1.jpg` for images
/// converted to `1.png`). Err: how many images have that stem (0, or several).
fn frame_named<'a>(names: &'a [String], label: &str) -> Result<&'a str, usize> {
    let last = label.rsplit(['/', '\\']).next().unwrap_or(label);
    if let Some(n) = names.iter().find(|n| *n == label || *n == last) {
        return Ok(n);
    }
    let only = |hits: Vec<&'a String>| match hits.as_slice() {
        [n] => Ok(n.as_str()),
        many => Err(many.len()),
    };
    let found = only(
        names
            .iter()
            .filter(|n| n.eq_ignore_ascii_case(last))
            .collect(),
    );
    if found.is_ok() {
        return found;
    }
    fn stem(n: &str) -> Option<&str> {
        Path::new(n).file_stem().and_then(|s| s.to_str())
    }
    let same = |wanted: &str| -> Vec<&'a String> {
        names
            .iter()
            .filter(|n| stem(n).is_some_and(|s| s.eq_ignore_ascii_case(wanted)))
            .collect()
    };
    match only(same(last)) {
        Err(0) => only(same(stem(last).unwrap_or(last))),
        other => other,
    }
}

/// Where the imported images are: their folder, or the pose file that names them.
fn images_place(poses: &PoseFile) -> &Path {
    match poses {
        PoseFile::Tum { images, .. }
        | PoseFile::Colmap { images, .. }
        | PoseFile::Llff { images, .. }
        | PoseFile::Idr { images, .. } => images,
        PoseFile::Nerf { transforms } => transforms,
    }
}

/// The error of line `line` (1-based) of a text input.
fn line_error(path: &Path, line: usize, what: String) -> ImportError {
    ImportError::File(CaptureError::Line {
        path: path.into(),
        line,
        what,
    })
}

/// File name of `p` as text (lossy), or empty.
fn name_of(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Refuses image stamps that do not increase or that lie before 1970.
fn check_stamps(frames: &[Frame]) -> Result<(), ImportError> {
    if let Some(w) = frames
        .windows(2)
        .position(|w| w[1].stamp_ns <= w[0].stamp_ns)
    {
        return Err(ImportError::File(CaptureError::Invalid {
            path: frames[w + 1].path.clone(),
            what: "timestamp is not after the previous image's".into(),
        }));
    }
    if frames.first().is_some_and(|f| f.stamp_ns < 0) {
        return Err(ImportError::File(CaptureError::Invalid {
            path: frames[0].path.clone(),
            what: "stamps before 1970 cannot be MCAP log times".into(),
        }));
    }
    Ok(())
}

/// The image file as PNG bytes and its size.
/// The image file as the CompressedImage will carry it, with its format and size: a JPEG
/// as it is (a camera's own bytes, a fraction of a PNG's size; it decodes to the same
/// pixels every time), anything else decoded and written as an 8-bit RGB PNG.
fn encoded_of(path: &Path) -> Result<Encoded, ImportError> {
    let invalid = |what: String| {
        ImportError::File(CaptureError::Invalid {
            path: path.into(),
            what,
        })
    };
    let bytes = std::fs::read(path).map_err(|source| {
        ImportError::File(CaptureError::Io {
            path: path.into(),
            source,
        })
    })?;
    let undecodable = |e: image::ImageError| invalid(format!("image does not decode: {e}"));
    let mut decoder = image::ImageReader::new(std::io::Cursor::new(&bytes))
        .with_guessed_format()
        .map_err(|e| invalid(format!("image does not decode: {e}")))?
        .into_decoder()
        .map_err(undecodable)?;
    let turn = exif_turn(decoder.orientation().ok());
    let img = image::DynamicImage::from_decoder(decoder).map_err(undecodable)?;
    let (w, h) = (img.width(), img.height());
    if bytes.starts_with(&[0xFF, 0xD8, 0xFF]) {
        if !crate::io::session::jpeg_is_complete(&bytes) {
            let cut = crate::io::session::FrameError::TruncatedJpeg { bytes: bytes.len() };
            return Err(invalid(cut.to_string()));
        }
        return Ok(("jpeg", bytes, w, h, turn));
    }
    let rgb = img.into_rgb8();
    let png = crate::types::image::encode_png(w, h, rgb.as_raw()).map_err(invalid)?;
    Ok(("png", png, w, h, turn))
}

/// An image file as a frame carries it: format, bytes, width and height as stored, and what
/// its EXIF orientation asks of a viewer ([`exif_turn`]).
type Encoded = (&'static str, Vec<u8>, u32, u32, Option<&'static str>);

/// What an EXIF orientation tag asks a viewer to do to the stored pixels, or None when
/// nothing (no tag, or "as stored"). objloc, like structure-from-motion tools (COLMAP reads
/// pixels as stored, so that one camera's intrinsics hold for every frame), uses the stored
/// pixels: poses, intrinsics and labels must all refer to them, and a rectangle drawn in a
/// viewer that turned the photo would not.
fn exif_turn(orientation: Option<image::metadata::Orientation>) -> Option<&'static str> {
    use image::metadata::Orientation as O;
    match orientation? {
        O::NoTransforms => None,
        O::Rotate90 => Some("turn 90 degrees clockwise"),
        O::Rotate180 => Some("turn 180 degrees"),
        O::Rotate270 => Some("turn 90 degrees counter-clockwise"),
        O::FlipHorizontal => Some("mirror left to right"),
        O::FlipVertical => Some("mirror top to bottom"),
        O::Rotate90FlipH => Some("turn 90 degrees clockwise and mirror"),
        O::Rotate270FlipH => Some("turn 90 degrees counter-clockwise and mirror"),
    }
}

fn write_session(
    opts: &ImportOptions,
    out: &Path,
    frames: &[Frame],
    labels: Option<&(PathBuf, Labels)>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<(PathBuf, usize, Option<ExifTurned>), ImportError> {
    let topics = Topics::default();
    let mut turned: Option<ExifTurned> = None;
    let mut writer = SessionWriter::create(out)?;
    let first_ns = frames[0].stamp_ns;
    let tf = TfMessage {
        transforms: vec![TransformStamped {
            header: Header::new(first_ns, "base_link"),
            child_frame_id: "camera_optical_frame".into(),
            translation: [0.0; 3],
            rotation_xyzw: [0.0, 0.0, 0.0, 1.0],
        }],
    };
    writer.write(&topics.tf_static, first_ns, &tf)?;
    let mut labelled = 0;
    for (k, f) in frames.iter().enumerate() {
        let (format, data, w, h, turn) = encoded_of(&f.path)?;
        if let Some(turn) = turn {
            let first = turned.get_or_insert_with(|| (0, name_of(&f.path), turn));
            first.0 += 1;
        }
        let c = &f.intrinsics.camera;
        if (w, h) != (c.width, c.height) {
            // Intrinsics for the photo as a viewer turns it are the likely cause.
            let hint = match turn {
                Some(t) if (h, w) == (c.width, c.height) => format!(
                    " (its EXIF orientation asks a viewer to {t}; objloc uses the pixels as stored, so give the intrinsics of the stored image)"
                ),
                _ => String::new(),
            };
            return Err(ImportError::File(CaptureError::Invalid {
                path: f.path.clone(),
                what: format!(
                    "image is {w} x {h} but its intrinsics are for {} x {}{hint}",
                    c.width, c.height
                ),
            }));
        }
        let stamp_ns = f.stamp_ns;
        let odom = Odometry {
            header: Header::new(stamp_ns, "odom"),
            child_frame_id: "base_link".into(),
            pose: pose_from_iso(&f.world_from_camera),
            pose_covariance: [0.0; 36],
            twist: Twist::default(),
            twist_covariance: [0.0; 36],
        };
        writer.write(&topics.odom, stamp_ns, &odom)?;
        let header = Header::new(stamp_ns, "camera_optical_frame");
        let image = CompressedImage {
            header: header.clone(),
            format: format.into(),
            data,
        };
        writer.write(&topics.compressed_image, stamp_ns, &image)?;
        writer.write(
            &topics.camera_info,
            stamp_ns,
            &camera_info(&header, &f.intrinsics),
        )?;
        if let Some((lp, l)) = labels
            && let Some(rows) = l.get(&name_of(&f.path))
        {
            for label in frame_labels(opts, lp, rows, &header, (w, h))? {
                writer.write(&topics.labels, stamp_ns, &label)?;
            }
            labelled += 1;
        }
        progress(k + 1, frames.len());
    }
    let path = writer.finish()?;
    Ok((path, labelled, turned))
}

/// CameraInfo of one frame: K, and the distortion as `plumb_bob` d (empty when none).
fn camera_info(header: &Header, i: &Intrinsics) -> CameraInfo {
    let c = &i.camera;
    let mut info = CameraInfo::pinhole(header.clone(), c.width, c.height, c.fx, c.fy, c.cx, c.cy);
    if !i.distortion.is_zero() {
        info.distortion_model = "plumb_bob".into();
        info.d = i.distortion.to_plumb_bob();
    }
    info
}

/// One label message per object named by a frame's rows (in name order), each with its
/// rectangles; a background row gives a message without rectangles.
fn frame_labels(
    opts: &ImportOptions,
    lp: &Path,
    rows: &[LabelRow],
    header: &Header,
    (w, h): (u32, u32),
) -> Result<Vec<ObjectLabel>, ImportError> {
    let mut by_object: BTreeMap<&str, Vec<_>> = BTreeMap::new();
    for row in rows {
        let object = row.object.as_deref().unwrap_or(&opts.object);
        let regions = by_object.entry(object).or_default();
        let Some(mut r) = row.roi else { continue };
        // A box reaching at most a pixel past the edge is the labeller's rounding (a
        // sub-pixel edge at 605.001 rounded outward, an inclusive last column): clipped.
        let past = |o: u32, n: u32, size: u32| {
            (u64::from(o) + u64::from(n)).saturating_sub(u64::from(size))
        };
        if past(r.x_offset, r.width, w) == 1 && r.width > 1 {
            r.width -= 1;
        }
        if past(r.y_offset, r.height, h) == 1 && r.height > 1 {
            r.height -= 1;
        }
        if u64::from(r.x_offset) + u64::from(r.width) > u64::from(w)
            || u64::from(r.y_offset) + u64::from(r.height) > u64::from(h)
        {
            return Err(ImportError::File(CaptureError::Line {
                path: lp.into(),
                line: row.line,
                what: format!(
                    "box x {} y {} {} x {} leaves the {w} x {h} image",
                    r.x_offset, r.y_offset, r.width, r.height
                ),
            }));
        }
        regions.push(r);
    }
    Ok(by_object
        .into_iter()
        .map(|(object, regions)| ObjectLabel {
            header: header.clone(),
            object: object.to_owned(),
            regions,
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A hand-held orbit of cameras around an object away from the world's origin (as
    /// structure-from-motion places it: COLMAP's origin is a camera's), as frames (OpenCV
    /// axes).
    fn orbit(n: usize) -> Vec<Frame> {
        (0..n)
            .map(|k| {
                let a = k as f64 / n as f64 * std::f64::consts::TAU;
                // A hand-held orbit: radius, height and aim vary from frame to frame.
                let r = 2.0 + 0.3 * (3.0 * a).sin();
                let centre = nalgebra::Vector3::new(1.5, 2.5, 0.3);
                let eye =
                    nalgebra::Point3::new(r * a.cos(), r * a.sin(), 0.4 + 0.4 * (k % 3) as f64)
                        + centre;
                let aim =
                    nalgebra::Point3::new(0.05 * (2.0 * a).cos(), 0.05 * a.sin(), 0.0) + centre;
                // z towards the aim, y down (world z up).
                let view = nalgebra::Isometry3::look_at_rh(
                    &eye,
                    &aim,
                    &nalgebra::Vector3::new(0.0, 0.0, -1.0),
                );
                // look_at_rh looks along -z: turn about y so +z looks at the target.
                let turn = nalgebra::UnitQuaternion::from_axis_angle(
                    &nalgebra::Vector3::y_axis(),
                    std::f64::consts::PI,
                );
                Frame {
                    path: format!("{k}.png").into(),
                    stamp_ns: k as i64,
                    world_from_camera: view.inverse() * turn,
                    intrinsics: Intrinsics {
                        camera: Camera::from_k(
                            100,
                            100,
                            [80.0, 0.0, 50.0, 0.0, 80.0, 50.0, 0.0, 0.0, 1.0],
                        )
                        .unwrap(),
                        distortion: Distortion::default(),
                    },
                }
            })
            .collect()
    }

    /// Poses around an object raise no question; the same inverted (world-to-camera), or with
    /// their quaternions read w first, or in OpenGL axes, each get the note that names it.
    #[test]
    fn poses_that_meet_nowhere_are_questioned() {
        let good = orbit(12);
        for f in &good {
            let z = f.world_from_camera.rotation * nalgebra::Vector3::z();
            let c = nalgebra::Vector3::new(1.5, 2.5, 0.3);
            let to_object = (c - f.world_from_camera.translation.vector).normalize();
            assert!(z.dot(&to_object) > 0.99, "{z}");
        }
        assert!(pose_notes(&good).is_empty(), "{:?}", pose_notes(&good));
        let with = |g: &dyn Fn(&Iso3) -> Iso3| -> Vec<String> {
            let frames: Vec<Frame> = good
                .iter()
                .map(|f| Frame {
                    world_from_camera: g(&f.world_from_camera),
                    ..f.clone()
                })
                .collect();
            pose_notes(&frames)
        };
        let inverted = with(&|p| p.inverse());
        assert!(
            inverted[0].contains("are the poses camera-to-world"),
            "{inverted:?}"
        );
        let w_first = with(&|p| {
            let q = p.rotation.quaternion();
            let (x, y, z, w) = (q.i, q.j, q.k, q.w);
            // The file's x y z w read as w x y z.
            let read =
                nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(x, y, z, w));
            Iso3::from_parts(p.translation, read)
        });
        assert!(
            w_first[0].contains("quaternions in x y z w order"),
            "{w_first:?}"
        );
        let flip = nalgebra::UnitQuaternion::from_axis_angle(
            &nalgebra::Vector3::x_axis(),
            std::f64::consts::PI,
        );
        let gl = with(&|p| p * flip);
        assert!(gl[0].contains("OpenGL camera axes"), "{gl:?}");
    }

    /// A 16 x 8 JPEG, with an EXIF segment carrying orientation `tag` when given.
    fn jpeg_with_orientation(tag: Option<u8>) -> Vec<u8> {
        let mut bytes = Vec::new();
        let pixels: Vec<u8> = (0..16 * 8 * 3).map(|i| (i * 7 % 256) as u8).collect();
        image::codecs::jpeg::JpegEncoder::new(&mut bytes)
            .encode(&pixels, 16, 8, image::ExtendedColorType::Rgb8)
            .unwrap();
        let Some(tag) = tag else { return bytes };
        // APP1: "Exif\0\0", a big-endian TIFF header, one IFD entry 0x0112 (SHORT, 1 value).
        let mut app1 = b"Exif\0\0MM\0\x2a\0\0\0\x08\0\x01\x01\x12\0\x03\0\0\0\x01\0".to_vec();
        app1.extend_from_slice(&[tag, 0, 0, 0, 0, 0, 0]);
        let len = (app1.len() + 2) as u16;
        let mut out = bytes[..2].to_vec();
        out.extend_from_slice(&[0xFF, 0xE1]);
        out.extend_from_slice(&len.to_be_bytes());
        out.extend_from_slice(&app1);
        out.extend_from_slice(&bytes[2..]);
        out
    }

    /// A phone photo's EXIF orientation is read and said; its pixels are kept as stored.
    #[test]
    fn an_exif_orientation_is_read_and_the_pixels_kept_as_stored() {
        let dir = tempfile::tempdir().unwrap();
        for (tag, turn) in [
            (None, None),
            (Some(1), None),
            (Some(6), Some("turn 90 degrees clockwise")),
            (Some(3), Some("turn 180 degrees")),
        ] {
            let path = dir.path().join("p.jpg");
            let bytes = jpeg_with_orientation(tag);
            std::fs::write(&path, &bytes).unwrap();
            let (format, data, w, h, got) = encoded_of(&path).unwrap();
            assert_eq!((format, w, h, got), ("jpeg", 16, 8, turn), "tag {tag:?}");
            assert_eq!(data, bytes);
        }
    }

    /// A labels row names its image by file name, by a path ending in it, or by its name
    /// without the extension when that is unique; nothing else.
    #[test]
    fn a_label_names_its_image_by_name_path_or_unique_stem() {
        let names: Vec<String> = ["1305031102.175304.png", "a.jpg", "b.jpg", "b.png"]
            .into_iter()
            .map(String::from)
            .collect();
        let found = |l: &str| frame_named(&names, l);
        assert_eq!(found("a.jpg"), Ok("a.jpg"));
        assert_eq!(
            found("rgb/1305031102.175304.png"),
            Ok("1305031102.175304.png")
        );
        assert_eq!(found("C:\\shots\\a.jpg"), Ok("a.jpg"));
        assert_eq!(found("1305031102.175304"), Ok("1305031102.175304.png"));
        assert_eq!(found("./a"), Ok("a.jpg"));
        // Another case, another extension (images converted to PNG): the one image of that
        // stem.
        assert_eq!(found("A.JPG"), Ok("a.jpg"));
        assert_eq!(found("a.png"), Ok("a.jpg"));
        // Two images share the stem b.
        assert_eq!(found("b"), Err(2));
        assert_eq!(found("b.gif"), Err(2));
        assert_eq!(found("c.jpg"), Err(0));
    }

    #[test]
    fn names_sort_with_numbers_as_numbers() {
        let mut v = vec![
            "10.jpg",
            "2.jpg",
            "1.jpg",
            "IMG_10.png",
            "IMG_9.png",
            "a.png",
        ];
        v.sort_by_key(|n| natural_key(n));
        assert_eq!(
            v,
            [
                "1.jpg",
                "2.jpg",
                "10.jpg",
                "IMG_9.png",
                "IMG_10.png",
                "a.png"
            ]
        );
    }

    #[test]
    fn a_frame_gets_one_label_per_object() {
        let rows = parse_labels(
            Path::new("l.csv"),
            "a.png,1,1,2,2,mug\na.png,5,5,2,2\na.png,3,3,2,2,mug\n",
        )
        .unwrap();
        let opts = ImportOptions {
            poses: PoseFile::Nerf {
                transforms: "t.json".into(),
            },
            labels: None,
            masks: None,
            object: "object".into(),
        };
        let h = Header::new(1, "cam");
        let l = frame_labels(&opts, Path::new("l.csv"), &rows["a.png"], &h, (10, 10)).unwrap();
        let got: Vec<(&str, usize)> = l
            .iter()
            .map(|m| (m.object.as_str(), m.regions.len()))
            .collect();
        assert_eq!(got, [("mug", 2), ("object", 1)]);
        // A pixel past the edge is clipped; two are an error.
        let l = frame_labels(&opts, Path::new("l.csv"), &rows["a.png"], &h, (6, 6)).unwrap();
        let r = l[1].regions[0];
        assert_eq!((r.x_offset, r.y_offset, r.width, r.height), (5, 5, 1, 1));
        let e = frame_labels(&opts, Path::new("l.csv"), &rows["a.png"], &h, (5, 5)).unwrap_err();
        assert_eq!(
            e.to_string(),
            "l.csv:2: box x 5 y 5 2 x 2 leaves the 5 x 5 image"
        );
    }
}
