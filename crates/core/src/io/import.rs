//! Imports a real image sequence into a session: a directory of images, a TUM RGB-D
//! trajectory (`timestamp tx ty tz qx qy qz qw`, camera poses in the world frame), pinhole
//! intrinsics, and optional CSV labels (`image,x,y,width,height`).
//!
//! Frames: the world frame of the trajectory becomes `odom`; `base_link` IS the camera, so
//! /tf_static publishes an identity `base_link -> camera_optical_frame` and /odom carries the
//! TUM camera pose (TUM poses are of the optical centre, z forward, x right, y down). The
//! world of a TUM trajectory need not be z-up. No /cmd_vel is written: the motion is unknown.
//!
//! Matching: images are sorted by file name. If every file stem parses as a decimal number of
//! seconds (TUM's `1305031102.175304.png`), each image is stamped with it and posed by
//! interpolating the trajectory (at most [`MAX_EXTRAPOLATION_NS`] beyond its ends);
//! otherwise image i takes trajectory line i (stamp and pose), and the counts must be equal.
//!
//! Invariants: every error names the file and line (or image) at fault; the output is written
//! through `.partial` and only renamed when complete.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use thiserror::Error;

use crate::io::msgs::pose_from_iso;
use crate::io::msgs::{
    CameraInfo, CompressedImage, Header, ObjectLabel, Odometry, RegionOfInterest, TfMessage,
    TransformStamped, Twist,
};
use crate::io::session::{SessionError, SessionWriter, Topics};
use crate::types::geometry::{Iso3, iso_from_parts};
use crate::types::track::PoseTrack;

/// An image stamp may lie this far outside the trajectory's time span.
pub const MAX_EXTRAPOLATION_NS: i64 = crate::types::track::POSE_TOLERANCE_NS;
const IMAGE_EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

#[derive(Debug, Error)]
pub enum ImportError {
    #[error("{path}: {source}", path = path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}:{line}: {what}", path = path.display())]
    Line {
        path: PathBuf,
        line: usize,
        what: String,
    },
    #[error("{path}: {what}", path = path.display())]
    Invalid { path: PathBuf, what: String },
    /// Boxed: a session error carries an MCAP error and the place it happened.
    #[error(transparent)]
    Session(Box<SessionError>),
}

impl From<SessionError> for ImportError {
    fn from(e: SessionError) -> Self {
        Self::Session(Box::new(e))
    }
}

/// One trajectory line: camera pose in the world frame at a stamp.
#[derive(Debug, Clone, PartialEq)]
pub struct TrajectoryPose {
    pub stamp_ns: i64,
    pub world_from_camera: Iso3,
    pub line: usize,
}

/// Parses decimal seconds (`1305031102.175304`, `12`, `-0.5`) into nanoseconds exactly.
pub fn parse_seconds_ns(s: &str) -> Option<i64> {
    let (neg, body) = match s.strip_prefix('-') {
        Some(b) => (true, b),
        None => (false, s),
    };
    let (int, frac) = body.split_once('.').unwrap_or((body, ""));
    if int.is_empty() && frac.is_empty() {
        return None;
    }
    let digits = |t: &str| t.bytes().all(|b| b.is_ascii_digit());
    if !digits(int) || !digits(frac) || frac.len() > 9 || int.len() > 10 {
        return None;
    }
    let sec: i64 = if int.is_empty() { 0 } else { int.parse().ok()? };
    let frac_ns: i64 = if frac.is_empty() {
        0
    } else {
        format!("{frac:0<9}").parse().ok()?
    };
    let ns = sec * 1_000_000_000 + frac_ns;
    Some(if neg { -ns } else { ns })
}

/// Parses a TUM trajectory; `#` starts a comment, blank lines are skipped.
pub fn parse_trajectory(path: &Path, text: &str) -> Result<Vec<TrajectoryPose>, ImportError> {
    let mut out: Vec<TrajectoryPose> = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let content = raw.split('#').next().unwrap_or("").trim();
        if content.is_empty() {
            continue;
        }
        let err = |what: String| ImportError::Line {
            path: path.into(),
            line,
            what,
        };
        let fields: Vec<&str> = content.split_whitespace().collect();
        if fields.len() != 8 {
            return Err(err(format!(
                "expected 8 fields `timestamp tx ty tz qx qy qz qw`, found {}",
                fields.len()
            )));
        }
        let stamp_ns = parse_seconds_ns(fields[0])
            .ok_or_else(|| err(format!("timestamp {:?} is not decimal seconds", fields[0])))?;
        let mut v = [0.0f64; 7];
        for (k, f) in fields[1..].iter().enumerate() {
            v[k] = f
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| err(format!("field {} ({f:?}) is not a finite number", k + 2)))?;
        }
        let world_from_camera = iso_from_parts([v[0], v[1], v[2]], [v[3], v[4], v[5], v[6]])
            .ok_or_else(|| err("quaternion has zero length".into()))?;
        if let Some(prev) = out.last()
            && stamp_ns <= prev.stamp_ns
        {
            return Err(err(format!(
                "timestamp {} is not after the previous line's ({})",
                fields[0],
                crate::io::session::fmt_ns(prev.stamp_ns.max(0) as u64)
            )));
        }
        out.push(TrajectoryPose {
            stamp_ns,
            world_from_camera,
            line,
        });
    }
    if out.is_empty() {
        return Err(ImportError::Invalid {
            path: path.into(),
            what: "trajectory has no poses".into(),
        });
    }
    Ok(out)
}

/// Label rows by image file name, in file order: `Some(roi)` for a box, `None` for a
/// background row (empty box). A first line starting with `image` is a header.
pub type Labels = BTreeMap<String, Vec<(usize, Option<RegionOfInterest>)>>;

pub fn parse_labels(path: &Path, text: &str) -> Result<Labels, ImportError> {
    let mut out: Labels = BTreeMap::new();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let content = raw.trim();
        if content.is_empty()
            || content.starts_with('#')
            || (line == 1 && content.starts_with("image"))
        {
            continue;
        }
        let err = |what: String| ImportError::Line {
            path: path.into(),
            line,
            what,
        };
        let fields: Vec<&str> = content.split(',').map(str::trim).collect();
        if fields.len() != 5 {
            return Err(err(format!(
                "expected 5 columns `image,x,y,width,height`, found {}",
                fields.len()
            )));
        }
        if fields[0].is_empty() {
            return Err(err("image name is empty".into()));
        }
        let roi = if fields[1..].iter().all(|f| f.is_empty()) {
            None
        } else {
            let mut v = [0u32; 4];
            for (k, f) in fields[1..].iter().enumerate() {
                v[k] = f.parse().map_err(|_| {
                    err(format!(
                        "column {} ({f:?}) is not a whole number of pixels",
                        k + 2
                    ))
                })?;
            }
            if v[2] == 0 || v[3] == 0 {
                return Err(err(format!("box {} x {} is empty", v[2], v[3])));
            }
            Some(RegionOfInterest {
                x_offset: v[0],
                y_offset: v[1],
                width: v[2],
                height: v[3],
                do_rectify: false,
            })
        };
        out.entry(fields[0].to_owned())
            .or_default()
            .push((line, roi));
    }
    Ok(out)
}

#[derive(Debug, Clone, PartialEq)]
pub struct ImportOptions {
    pub images: PathBuf,
    pub trajectory: PathBuf,
    /// fx, fy, cx, cy in pixels.
    pub camera: [f64; 4],
    pub labels: Option<PathBuf>,
    /// Object name written on /labels.
    pub object: String,
}

#[derive(Debug, Clone, PartialEq)]
pub struct ImportStats {
    pub path: PathBuf,
    pub frames: usize,
    pub labelled: usize,
    pub timestamps_from_names: bool,
}

fn list_images(dir: &Path) -> Result<Vec<PathBuf>, ImportError> {
    let io = |source| ImportError::Io {
        path: dir.into(),
        source,
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
    files.sort_by(|a, b| a.file_name().cmp(&b.file_name()));
    if files.is_empty() {
        return Err(ImportError::Invalid {
            path: dir.into(),
            what: "no .png/.jpg/.jpeg images".into(),
        });
    }
    Ok(files)
}

/// The camera pose at `stamp_ns` by interpolation (across any interval: a trajectory may be
/// sparse by design), at most [`MAX_EXTRAPOLATION_NS`] beyond its ends; or why not.
fn pose_at(traj: &[TrajectoryPose], stamp_ns: i64) -> Result<Iso3, String> {
    let track = PoseTrack::new(
        traj.iter()
            .map(|p| (p.stamp_ns, p.world_from_camera))
            .collect(),
    );
    track
        .interpolated(stamp_ns)
        .ok_or_else(|| match (traj.first(), traj.last()) {
            (Some(first), Some(last)) => format!(
                "stamp {} is outside the trajectory ({} to {}) by more than 50 ms",
                crate::io::session::fmt_ns(stamp_ns.max(0) as u64),
                crate::io::session::fmt_ns(first.stamp_ns.max(0) as u64),
                crate::io::session::fmt_ns(last.stamp_ns.max(0) as u64)
            ),
            _ => "empty trajectory".into(),
        })
}

/// Imports the sequence into `out` (via `out.partial`); `progress(done, total)` per frame.
pub fn import(
    opts: &ImportOptions,
    out: &Path,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<ImportStats, ImportError> {
    check_camera(opts)?;
    let read = |p: &Path| {
        std::fs::read_to_string(p).map_err(|source| ImportError::Io {
            path: p.into(),
            source,
        })
    };
    let traj = parse_trajectory(&opts.trajectory, &read(&opts.trajectory)?)?;
    let labels = match &opts.labels {
        Some(p) => Some((p.clone(), parse_labels(p, &read(p)?)?)),
        None => None,
    };
    let images = list_images(&opts.images)?;
    if let Some((lp, l)) = &labels {
        check_labels_name_images(opts, &images, lp, l)?;
    }
    let (posed, timestamps_from_names) = pose_images(opts, &traj, &images)?;
    check_stamps(&images, &posed)?;

    let result = write_session(opts, out, &images, &posed, labels.as_ref(), progress);
    if result.is_err() {
        // An error leaves nothing behind: no final file, no partial one.
        let _ = std::fs::remove_file(crate::io::output::partial_path(out));
    }
    result.map(|(path, labelled)| ImportStats {
        path,
        frames: images.len(),
        labelled,
        timestamps_from_names,
    })
}

/// File name of `p` as text (lossy), or empty.
fn name_of(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Refuses intrinsics that are not a pinhole camera.
fn check_camera(opts: &ImportOptions) -> Result<(), ImportError> {
    let [fx, fy, cx, cy] = opts.camera;
    if !(fx > 0.0
        && fy > 0.0
        && fx.is_finite()
        && fy.is_finite()
        && cx.is_finite()
        && cy.is_finite())
    {
        return Err(ImportError::Invalid {
            path: opts.trajectory.clone(),
            what: format!(
                "--camera {fx},{fy},{cx},{cy}: focal lengths must be positive and all finite"
            ),
        });
    }
    Ok(())
}

/// Refuses label rows (of file `lp`) for an image that is not among `images`.
fn check_labels_name_images(
    opts: &ImportOptions,
    images: &[PathBuf],
    lp: &Path,
    labels: &Labels,
) -> Result<(), ImportError> {
    let names: Vec<String> = images.iter().map(|p| name_of(p)).collect();
    if let Some((name, rows)) = labels.iter().find(|(n, _)| !names.contains(n)) {
        return Err(ImportError::Line {
            path: lp.into(),
            line: rows.first().map_or(0, |r| r.0),
            what: format!("image {name:?} is not in {}", opts.images.display()),
        });
    }
    Ok(())
}

/// (stamp, pose) per image, and whether the stamps came from the file names (else image i
/// took trajectory line i).
fn pose_images(
    opts: &ImportOptions,
    traj: &[TrajectoryPose],
    images: &[PathBuf],
) -> Result<(Vec<(i64, Iso3)>, bool), ImportError> {
    let stems: Option<Vec<i64>> = images
        .iter()
        .map(|p| {
            p.file_stem()
                .and_then(|s| s.to_str())
                .and_then(parse_seconds_ns)
        })
        .collect();
    let Some(stamps) = stems else {
        if images.len() != traj.len() {
            return Err(ImportError::Invalid {
                path: opts.trajectory.clone(),
                what: format!(
                    "{} poses for {} images in {} (file names are not timestamps, so images are matched to lines in order)",
                    traj.len(),
                    images.len(),
                    opts.images.display()
                ),
            });
        }
        let posed = traj
            .iter()
            .map(|t| (t.stamp_ns, t.world_from_camera))
            .collect();
        return Ok((posed, false));
    };
    let posed = images
        .iter()
        .zip(&stamps)
        .map(|(p, s)| {
            pose_at(traj, *s)
                .map(|pose| (*s, pose))
                .map_err(|what| ImportError::Invalid {
                    path: p.clone(),
                    what,
                })
        })
        .collect::<Result<_, _>>()?;
    Ok((posed, true))
}

/// Refuses image stamps that do not increase or that lie before 1970.
fn check_stamps(images: &[PathBuf], posed: &[(i64, Iso3)]) -> Result<(), ImportError> {
    if let Some(w) = posed.windows(2).position(|w| w[1].0 <= w[0].0) {
        return Err(ImportError::Invalid {
            path: images[w + 1].clone(),
            what: "timestamp is not after the previous image's".into(),
        });
    }
    if posed[0].0 < 0 {
        return Err(ImportError::Invalid {
            path: images[0].clone(),
            what: "stamps before 1970 cannot be MCAP log times".into(),
        });
    }
    Ok(())
}

fn write_session(
    opts: &ImportOptions,
    out: &Path,
    images: &[PathBuf],
    posed: &[(i64, Iso3)],
    labels: Option<&(PathBuf, Labels)>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<(PathBuf, usize), ImportError> {
    let [fx, fy, cx, cy] = opts.camera;
    let topics = Topics::default();
    let mut writer = SessionWriter::create(out)?;
    let first_ns = posed[0].0;
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
    for (k, (path, (stamp_ns, pose))) in images.iter().zip(posed).enumerate() {
        let bytes = std::fs::read(path).map_err(|source| ImportError::Io {
            path: path.clone(),
            source,
        })?;
        let img = image::load_from_memory(&bytes)
            .map_err(|e| ImportError::Invalid {
                path: path.clone(),
                what: format!("image does not decode: {e}"),
            })?
            .into_rgb8();
        let (w, h) = img.dimensions();
        let png = crate::types::image::encode_png(w, h, img.as_raw()).map_err(|what| {
            ImportError::Invalid {
                path: path.clone(),
                what,
            }
        })?;
        let odom = Odometry {
            header: Header::new(*stamp_ns, "odom"),
            child_frame_id: "base_link".into(),
            pose: pose_from_iso(pose),
            pose_covariance: [0.0; 36],
            twist: Twist::default(),
            twist_covariance: [0.0; 36],
        };
        writer.write(&topics.odom, *stamp_ns, &odom)?;
        let header = Header::new(*stamp_ns, "camera_optical_frame");
        writer.write(
            &topics.compressed_image,
            *stamp_ns,
            &CompressedImage {
                header: header.clone(),
                format: "png".into(),
                data: png,
            },
        )?;
        writer.write(
            &topics.camera_info,
            *stamp_ns,
            &CameraInfo::pinhole(header.clone(), w, h, fx, fy, cx, cy),
        )?;
        if let Some((lp, l)) = labels
            && let Some(rows) = l.get(&name_of(path))
        {
            let mut regions = Vec::new();
            for (line, roi) in rows {
                if let Some(r) = roi {
                    if u64::from(r.x_offset) + u64::from(r.width) > u64::from(w)
                        || u64::from(r.y_offset) + u64::from(r.height) > u64::from(h)
                    {
                        return Err(ImportError::Line {
                            path: lp.clone(),
                            line: *line,
                            what: format!(
                                "box x {} y {} {} x {} leaves the {w} x {h} image",
                                r.x_offset, r.y_offset, r.width, r.height
                            ),
                        });
                    }
                    regions.push(*r);
                }
            }
            let label = ObjectLabel {
                header: header.clone(),
                object: opts.object.clone(),
                regions,
            };
            writer.write(&topics.labels, *stamp_ns, &label)?;
            labelled += 1;
        }
        progress(k + 1, images.len());
    }
    let path = writer.finish()?;
    Ok((path, labelled))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seconds_parse_exactly() {
        assert_eq!(
            parse_seconds_ns("1305031102.175304"),
            Some(1_305_031_102_175_304_000)
        );
        assert_eq!(parse_seconds_ns("12"), Some(12_000_000_000));
        assert_eq!(parse_seconds_ns("-0.5"), Some(-500_000_000));
        assert_eq!(parse_seconds_ns("frame_001"), None);
        assert_eq!(parse_seconds_ns("."), None);
        assert_eq!(parse_seconds_ns("1.0000000001"), None);
    }

    #[test]
    fn trajectory_errors_name_the_line() {
        let p = Path::new("traj.txt");
        let t = parse_trajectory(p, "# tum\n1.0 0 0 0 0 0 0 1\n\n2.5 1 2 3 0 0 0 2 # c\n").unwrap();
        assert_eq!(t.len(), 2);
        assert_eq!((t[1].stamp_ns, t[1].line), (2_500_000_000, 4));
        assert!((t[1].world_from_camera.translation.y - 2.0).abs() < 1e-12);
        let e = parse_trajectory(p, "1.0 0 0 0 0 0 0 1\n2.0 0 0 x 0 0 0 1\n").unwrap_err();
        assert_eq!(
            e.to_string(),
            "traj.txt:2: field 4 (\"x\") is not a finite number"
        );
        let e = parse_trajectory(p, "1.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 0 1\n").unwrap_err();
        assert!(
            e.to_string()
                .starts_with("traj.txt:2: timestamp 1.0 is not after"),
            "{e}"
        );
        let e = parse_trajectory(p, "1.0 0 0 0 0 0 0 0\n").unwrap_err();
        assert_eq!(e.to_string(), "traj.txt:1: quaternion has zero length");
    }

    #[test]
    fn labels_parse_boxes_and_background_rows() {
        let p = Path::new("l.csv");
        let l = parse_labels(
            p,
            "image,x,y,width,height\na.png,1,2,30,40\nb.png,,,,\na.png,5,5,2,2\n",
        )
        .unwrap();
        assert_eq!(l["a.png"].len(), 2);
        assert_eq!(
            l["a.png"][0].1.map(|r| (r.x_offset, r.height)),
            Some((1, 40))
        );
        assert_eq!(l["b.png"], vec![(3, None)]);
        let e = parse_labels(p, "a.png,1,2,0,4\n").unwrap_err();
        assert_eq!(e.to_string(), "l.csv:1: box 0 x 4 is empty");
    }

    #[test]
    fn interpolates_between_lines() {
        let p = Path::new("t");
        let t = parse_trajectory(p, "1.0 0 0 0 0 0 0 1\n2.0 2 0 0 0 0 0 1\n").unwrap();
        let mid = pose_at(&t, 1_250_000_000).unwrap();
        assert!((mid.translation.x - 0.5).abs() < 1e-12);
        assert!(pose_at(&t, 2_040_000_000).is_ok());
        assert!(pose_at(&t, 2_060_000_000).is_err());
    }
}
