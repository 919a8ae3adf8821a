//! TUM RGB-D trajectories (`timestamp tx ty tz qx qy qz qw`, camera in world) and the
//! matching of a folder of images to them.
//!
//! Invariants: stamps are parsed exactly (decimal seconds to ns, no float rounding); a
//! trajectory's stamps strictly increase; an image is posed by interpolation at most
//! [`MAX_EXTRAPOLATION_NS`] beyond the trajectory's ends.

use std::path::{Path, PathBuf};

use super::{Frame, ImportError, line_error, list_images};
use crate::io::capture::CaptureError;
use crate::io::capture::Intrinsics;
use crate::types::geometry::{Iso3, iso_from_parts};
use crate::types::track::PoseTrack;

/// An image stamp may lie this far outside the trajectory's time span.
pub const MAX_EXTRAPOLATION_NS: i64 = crate::types::track::POSE_TOLERANCE_NS;

/// How a TUM import paired images with trajectory lines.
#[derive(Debug, Clone, PartialEq)]
pub enum Matching {
    /// Every file name is decimal seconds within the trajectory: each image posed at its stamp.
    FileNameStamps,
    /// Image i (in natural file-name order: `frame_2` before `frame_10`) took line i.
    InOrder,
    /// The names are numbers but do not all fall within the trajectory's time span (frame
    /// numbers, not times): matched in order as [`Matching::InOrder`], and this says why.
    InOrderNotStamps(String),
    /// Most file names are decimal seconds within the trajectory and were posed at their
    /// stamps; these images (names, in file order), before its first pose or after its last
    /// (frames structure-from-motion did not register), were left out.
    FileNameStampsWithout(Vec<String>),
}

/// The frames of a TUM import: the images of `images_dir`, stamped by their names when every
/// name is decimal seconds within the trajectory (posed by interpolation, in stamp order),
/// else matched to the trajectory's lines in natural file-name order; and how.
pub(super) fn tum_frames(
    trajectory: &Path,
    images_dir: &Path,
    intrinsics: Intrinsics,
) -> Result<(Vec<Frame>, Matching, Option<String>), ImportError> {
    let text = std::fs::read_to_string(trajectory).map_err(|source| {
        ImportError::File(CaptureError::Io {
            path: trajectory.into(),
            source,
        })
    })?;
    let traj = parse_trajectory(trajectory, &text)?;
    let images = list_images(images_dir)?;
    let (posed, matching) = pose_images(trajectory, images_dir, &traj, &images)?;
    let mut frames: Vec<Frame> = posed
        .into_iter()
        .map(|(path, stamp_ns, world_from_camera)| Frame {
            path,
            stamp_ns,
            world_from_camera,
            intrinsics,
        })
        .collect();
    // Names that are stamps go in time order, however they are spelt (`0.5` and `1.25`).
    frames.sort_by_key(|f| f.stamp_ns);
    let note = match matching {
        Matching::FileNameStamps | Matching::FileNameStampsWithout(_) => {
            bridged_note(&traj, &frames)
        }
        _ => None,
    };
    Ok((frames, matching, note))
}

/// A gap between trajectory lines wider than this many times the median spacing (and than
/// [`MIN_GAP_NOTED_NS`]) is noted when images are posed inside it.
const GAP_FACTOR: i64 = 5;
/// ... and wider than this.
const MIN_GAP_NOTED_NS: i64 = 500_000_000;

/// A note when frames are posed by interpolation across a gap in the trajectory much wider
/// than its usual spacing (frames structure-from-motion did not register in mid-sequence):
/// a straight line and a uniform turn across seconds of a hand-held camera's motion.
fn bridged_note(traj: &[TrajectoryPose], frames: &[Frame]) -> Option<String> {
    let mut spacing: Vec<i64> = traj
        .windows(2)
        .map(|w| w[1].stamp_ns - w[0].stamp_ns)
        .collect();
    spacing.sort_unstable();
    let median = *spacing.get(spacing.len() / 2)?;
    let wide = (GAP_FACTOR.saturating_mul(median)).max(MIN_GAP_NOTED_NS);
    let gap_of = |t: i64| {
        let i = traj.partition_point(|p| p.stamp_ns <= t);
        (i > 0 && i < traj.len() && traj[i - 1].stamp_ns != t)
            .then(|| traj[i].stamp_ns - traj[i - 1].stamp_ns)
    };
    let gaps: Vec<i64> = frames
        .iter()
        .filter_map(|f| gap_of(f.stamp_ns))
        .filter(|&g| g > wide)
        .collect();
    let longest = *gaps.iter().max()?;
    Some(format!(
        "{} image(s) are posed by interpolating across gaps in the trajectory of up to {:.1} s (its lines are usually {:.3} s apart): a straight line and an even turn across the gap, which a hand-held camera rarely moves along (frames structure-from-motion did not register?)",
        gaps.len(),
        longest as f64 * 1e-9,
        median as f64 * 1e-9
    ))
}

/// An image, its stamp (ns) and its camera pose in the trajectory's world.
type PosedImage = (PathBuf, i64, Iso3);

/// One trajectory line: camera pose in the world frame at a stamp.
#[derive(Debug, Clone, PartialEq)]
pub struct TrajectoryPose {
    /// Stamp of the pose, ns since the Unix epoch (TUM's decimal seconds, exactly).
    pub stamp_ns: i64,
    /// Camera (optical centre, OpenCV axes) in the trajectory's world frame.
    pub world_from_camera: Iso3,
    /// 1-based line of the file it came from.
    pub line: usize,
}

/// Parses decimal seconds (`1305031102.175304`, `12`, `-0.5`) into nanoseconds exactly; a
/// whole number of 17 to 19 digits is nanoseconds already (`1700000000500000000`: ROS
/// stamps, as frames extracted from a bag are named), since as seconds it would lie
/// thousands of millennia ahead.
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
    if !body.contains('.') && (17..=19).contains(&int.len()) && digits(int) {
        let ns: i64 = int.parse().ok()?;
        return Some(if neg { -ns } else { ns });
    }
    if !digits(int) || !digits(frac) || frac.len() > 9 || int.len() > 10 {
        return None;
    }
    let sec: i64 = if int.is_empty() { 0 } else { int.parse().ok()? };
    let frac_ns: i64 = if frac.is_empty() {
        0
    } else {
        format!("{frac:0<9}").parse().ok()?
    };
    // Checked: ten digits of seconds reach past i64 nanoseconds (an image named
    // `9999999999.jpg`).
    let ns = sec.checked_mul(1_000_000_000)?.checked_add(frac_ns)?;
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
        let err = |what: String| line_error(path, line, what);
        // Spaces as TUM writes them; commas as some exporters do, where an empty field is
        // one (`1.0,0,,0,...` has nine fields, not eight).
        let fields: Vec<&str> = if content.contains(',') {
            content.split(',').map(str::trim).collect()
        } else {
            content.split_whitespace().collect()
        };
        if fields.len() != 8 {
            return Err(err(format!(
                "expected 8 fields `timestamp tx ty tz qx qy qz qw`, found {}",
                fields.len()
            )));
        }
        let stamp_ns = parse_seconds_ns(fields[0]).ok_or_else(|| {
            err(format!(
                "timestamp {:?} is neither decimal seconds nor whole nanoseconds",
                fields[0]
            ))
        })?;
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
        return Err(ImportError::File(CaptureError::Invalid {
            path: path.into(),
            what: "trajectory has no poses".into(),
        }));
    }
    Ok(out)
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

/// (image, stamp, pose) per image posed (in the order of `images`), and how they were
/// matched. Numeric names are stamps when every one falls within the trajectory, or when
/// most do and the others lie beyond its ends (left out, said by the matching); otherwise,
/// when there are as many images as lines, they are frame numbers (`1.jpg` ... `43.jpg`
/// against a trajectory timed 0 ... 42) and the images are matched in order, saying so;
/// with a different count the error says both why the stamps fail and that the counts
/// differ.
fn pose_images(
    trajectory: &Path,
    images_dir: &Path,
    traj: &[TrajectoryPose],
    images: &[PathBuf],
) -> Result<(Vec<PosedImage>, Matching), ImportError> {
    let stems: Option<Vec<i64>> = images
        .iter()
        .map(|p| {
            p.file_stem()
                .and_then(|s| s.to_str())
                .and_then(parse_seconds_ns)
        })
        .collect();
    let mut matching = Matching::InOrder;
    if let Some(stamps) = stems {
        match posed_by_stamps(traj, images, &stamps) {
            Ok((posed, without)) if without.is_empty() => {
                return Ok((posed, Matching::FileNameStamps));
            }
            Ok((posed, without)) => return Ok((posed, Matching::FileNameStampsWithout(without))),
            // Neither way works: say both, since which one the user meant is not known.
            Err(e) if images.len() != traj.len() => {
                return Err(ImportError::File(CaptureError::Invalid {
                    path: trajectory.into(),
                    what: format!(
                        "the image names are numbers but not its times ({e}), and images cannot be matched to its lines in order either: {} poses for {} images in {}",
                        traj.len(),
                        images.len(),
                        images_dir.display()
                    ),
                }));
            }
            Err(e) => {
                matching = Matching::InOrderNotStamps(format!(
                    "the file names are numbers but not the trajectory's times ({e}): images matched to its lines in order"
                ));
            }
        }
    }
    if images.len() != traj.len() {
        // The name that is not a time, when others are: one stray file switches the matching.
        let is_time = |p: &&PathBuf| {
            p.file_stem()
                .and_then(|s| s.to_str())
                .and_then(parse_seconds_ns)
                .is_some()
        };
        let stray = images
            .iter()
            .find(|p| !is_time(p))
            .filter(|_| images.iter().any(|p| is_time(&p)))
            .map(|p| format!(": {} is not a time", super::name_of(p)))
            .unwrap_or_default();
        return Err(ImportError::File(CaptureError::Invalid {
            path: trajectory.into(),
            what: format!(
                "{} poses for {} images in {} (file names are not timestamps{stray}, so images are matched to lines in order)",
                traj.len(),
                images.len(),
                images_dir.display()
            ),
        }));
    }
    // `frame_01` and `frame_1` are one number: which the camera wrote first, and so which
    // line is whose, cannot be told.
    let numbers = |p: &PathBuf| {
        super::natural_key(&super::name_of(p))
            .into_iter()
            .map(|(kind, n, text)| (kind, n, if kind == 0 { String::new() } else { text }))
            .collect::<Vec<_>>()
    };
    if let Some(w) = images.windows(2).find(|w| numbers(&w[0]) == numbers(&w[1])) {
        return Err(ImportError::File(CaptureError::Invalid {
            path: images_dir.into(),
            what: format!(
                "{} and {} are the same name in natural order, so which of the trajectory's lines each takes cannot be told: rename one",
                super::name_of(&w[0]),
                super::name_of(&w[1])
            ),
        }));
    }
    let posed = images
        .iter()
        .zip(traj)
        .map(|(p, t)| (p.clone(), t.stamp_ns, t.world_from_camera))
        .collect();
    Ok((posed, matching))
}

/// Each image posed at the stamp its name gives, and the names of those beyond the
/// trajectory's ends, when more than half fall within it and the trajectory has another
/// count of lines than there are images (one from structure-from-motion often lacks the
/// first or last frames); otherwise the first that falls outside is the error.
fn posed_by_stamps(
    traj: &[TrajectoryPose],
    images: &[PathBuf],
    stamps: &[i64],
) -> Result<(Vec<PosedImage>, Vec<String>), ImportError> {
    let mut posed = Vec::with_capacity(images.len());
    let mut without = Vec::new();
    let mut first_error = None;
    for (p, &s) in images.iter().zip(stamps) {
        match pose_at(traj, s) {
            Ok(pose) => posed.push((p.clone(), s, pose)),
            Err(what) => {
                first_error.get_or_insert_with(|| (p.clone(), what));
                without.push(super::name_of(p));
            }
        }
    }
    match first_error {
        // As many images as lines: frame numbers rather than times (the caller matches
        // them in order), unless every one is a time.
        Some((path, what)) if 2 * posed.len() <= images.len() || images.len() == traj.len() => {
            Err(ImportError::File(CaptureError::Invalid { path, what }))
        }
        _ => Ok((posed, without)),
    }
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
        // Past i64 nanoseconds (2262): not a time, rather than an overflow.
        assert_eq!(parse_seconds_ns("9223372036.854775807"), Some(i64::MAX));
        assert_eq!(parse_seconds_ns("9223372036.854775808"), None);
        assert_eq!(parse_seconds_ns("9999999999"), None);
        // Whole nanoseconds, as ROS stamps name frames extracted from a bag.
        assert_eq!(
            parse_seconds_ns("1700000000500000000"),
            Some(1_700_000_000_500_000_000)
        );
        assert_eq!(parse_seconds_ns("9223372036854775808"), None);
        assert_eq!(
            parse_seconds_ns("17000000005000000"),
            Some(17_000_000_005_000_000)
        );
        assert_eq!(parse_seconds_ns("170000000050000"), None);
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
    fn names_of_one_number_cannot_be_matched_in_order() {
        let p = Path::new("t");
        let t = parse_trajectory(p, "1.0 0 0 0 0 0 0 1\n2.0 2 0 0 0 0 0 1\n").unwrap();
        let names = |a: &str, b: &str| vec![PathBuf::from(a), PathBuf::from(b)];
        let dir = Path::new("imgs");
        let e = pose_images(p, dir, &t, &names("frame_01.png", "frame_1.png")).unwrap_err();
        assert!(
            e.to_string()
                .contains("frame_01.png and frame_1.png are the same name in natural order"),
            "{e}"
        );
        let (posed, how) = pose_images(p, dir, &t, &names("frame_1.png", "frame_2.png")).unwrap();
        assert_eq!((posed.len(), how), (2, Matching::InOrder));
        // One stray name among times switches to matching in order; the error names it.
        let three = [
            PathBuf::from("1.0.png"),
            PathBuf::from("1.5.png"),
            PathBuf::from("zz.png"),
        ];
        let e = pose_images(p, dir, &t, &three).unwrap_err().to_string();
        assert!(
            e.contains("2 poses for 3 images") && e.contains("zz.png is not a time"),
            "{e}"
        );
    }

    /// Structure-from-motion left the first and last frames unposed: images named by their
    /// stamps beyond the trajectory's ends are left out and named; with as many images as
    /// lines, or most of them outside, the names are not taken as times.
    #[test]
    fn images_beyond_the_trajectory_are_left_out_when_most_are_within() {
        let p = Path::new("t");
        let t = parse_trajectory(
            p,
            "1.0 0 0 0 0 0 0 1\n2.0 2 0 0 0 0 0 1\n3.0 4 0 0 0 0 0 1\n",
        )
        .unwrap();
        let dir = Path::new("imgs");
        let names: Vec<PathBuf> = ["0.5", "1.0", "1.5", "2.0", "2.5", "9.0"]
            .iter()
            .map(|n| PathBuf::from(format!("{n}.png")))
            .collect();
        let (posed, how) = pose_images(p, dir, &t, &names).unwrap();
        assert_eq!(
            how,
            Matching::FileNameStampsWithout(vec!["0.5.png".into(), "9.0.png".into()])
        );
        let stamps: Vec<i64> = posed.iter().map(|(_, s, _)| *s).collect();
        assert_eq!(
            stamps,
            [1_000_000_000, 1_500_000_000, 2_000_000_000, 2_500_000_000]
        );
        assert!((posed[1].2.translation.x - 1.0).abs() < 1e-12);
        // Half outside: an error naming the first.
        let e = pose_images(p, dir, &t, &names[..2])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("0.5.png") && e.contains("outside the trajectory"),
            "{e}"
        );
        // As many images as lines: frame numbers, matched in order.
        let three: Vec<PathBuf> = names[3..].to_vec();
        let (_, how) = pose_images(p, dir, &t, &three).unwrap();
        assert!(matches!(how, Matching::InOrderNotStamps(_)), "{how:?}");
    }

    /// Frames inside a 3 s hole of a 10 Hz trajectory are noted; frames on its lines, or
    /// between lines the usual spacing apart, are not.
    #[test]
    fn frames_bridging_a_wide_gap_are_noted() {
        let lines: String = (0..10)
            .chain(40..50)
            .map(|k| format!("{}.{} {k} 0 0 0 0 0 1\n", k / 10, k % 10))
            .collect();
        let traj = parse_trajectory(Path::new("t"), &lines).unwrap();
        let frame = |stamp_ns: i64| Frame {
            path: "f.png".into(),
            stamp_ns,
            world_from_camera: Iso3::identity(),
            intrinsics: Intrinsics {
                camera: crate::types::geometry::Camera::with_hfov(8, 8, 1.0),
                distortion: Default::default(),
            },
        };
        let on_lines: Vec<Frame> = [0, 100_000_000, 450_000_000, 4_000_000_000]
            .map(frame)
            .into();
        assert_eq!(bridged_note(&traj, &on_lines), None);
        let in_hole: Vec<Frame> = [2_000_000_000, 2_500_000_000, 4_050_000_000]
            .map(frame)
            .into();
        let note = bridged_note(&traj, &in_hole).unwrap();
        assert!(
            note.starts_with("2 image(s) are posed by interpolating across gaps in the trajectory of up to 3.1 s (its lines are usually 0.100 s apart)"),
            "{note}"
        );
    }

    #[test]
    fn interpolates_between_lines() {
        let p = Path::new("t");
        let t = parse_trajectory(p, "1.0 0 0 0 0 0 0 1\n2.0 2 0 0 0 0 0 1\n").unwrap();
        let mid = pose_at(&t, 1_250_000_000).unwrap();
        assert!((mid.translation.x - 0.5).abs() < 1e-12);
        assert!(pose_at(&t, 2_040_000_000).is_ok());
        assert!(pose_at(&t, 2_060_000_000).is_err());
        // The same trajectory written with commas reads the same.
        let c = parse_trajectory(p, "1.0,0,0,0,0,0,0,1\n2.0, 2, 0, 0, 0, 0, 0, 1\n").unwrap();
        assert_eq!(c, t);
        // An empty field between commas is a field: nine, not eight.
        let e = parse_trajectory(p, "1.0,0,,0,0,0,0,0,1\n").unwrap_err();
        assert_eq!(
            e.to_string(),
            "t:1: expected 8 fields `timestamp tx ty tz qx qy qz qw`, found 9"
        );
    }
}
