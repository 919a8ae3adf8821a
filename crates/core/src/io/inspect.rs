//! Summary of a session file: what `objloc inspect` prints. Reads, never writes.
//!
//! Invariants: works on any ROS 2 MCAP, session or not: topics without a session role are
//! counted, not decoded; missing session topics are listed, not fatal; damage that leaves the
//! rest readable (a truncated tail) is a warning with how much was read; every frame of a
//! session topic is decoded, and the first that does not decode is an error. Memory does not
//! grow with the payloads: messages are decoded one at a time and frames checked in batches
//! of [`DECODE_BATCH`]. `--quick` ([`summarize_quick`]) reads only the summary section.
//!
//! Layout: one scan decodes the session-role messages, then the frames are decoded again
//! for the pixel check, then each warning has its own check over what the scan found,
//! applied in a fixed order (so the warnings print in that order).

use std::path::Path;

use rayon::prelude::*;
use serde::Serialize;

use crate::io::session::{
    MessageMeta, Role, SessionError, SessionMsg, SessionReader, Topics, fmt_ns,
};
use crate::types::geometry::Camera;
use crate::types::lens::{Distortion, camera_changes};

/// One channel of the file, as `objloc inspect` lists it.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct TopicSummary {
    /// Topic name, e.g. `/odom`.
    pub topic: String,
    /// Schema name as written in the file, e.g. `nav_msgs/msg/Odometry` (JSON key `type`).
    #[serde(rename = "type")]
    pub type_name: String,
    /// Message encoding of the channel, e.g. `cdr`.
    pub message_encoding: String,
    /// Messages on the channel (0 for a channel declared but never written to).
    pub count: usize,
    /// The session role of this topic (`odom`, `camera_info`, ...), if any.
    pub role: Option<String>,
    /// Earliest log time on the channel, ns since the Unix epoch; `None` without messages.
    pub first_log_time_ns: Option<u64>,
    /// Latest log time on the channel, ns since the Unix epoch; `None` without messages.
    pub last_log_time_ns: Option<u64>,
}

/// Size and format of a session's first frame.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct ImageSummary {
    /// Frame width, pixels.
    pub width: u32,
    /// Frame height, pixels.
    pub height: u32,
    /// Format in words, e.g. `png` or `raw rgb8` (see [`crate::io::session::Frame::encoding`]).
    pub encoding: String,
}

/// Everything `objloc inspect` reports on one file; `--json` prints it serialised.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Summary {
    /// The file, as given.
    pub path: String,
    /// MCAP header profile, e.g. `ros2`; empty if the file declares none.
    pub profile: String,
    /// MCAP header library: what wrote the file, e.g. `objloc 0.1.0`.
    pub library: String,
    /// Size of the file, bytes.
    pub file_bytes: u64,
    /// Bytes from the start of the file that were read as intact records: the whole file but
    /// its closing magic (8 bytes) when it is intact, less when it is truncated or damaged.
    pub bytes_intact: u64,
    /// Messages in the file, on every topic.
    pub messages: usize,
    /// Earliest log time, ns since the Unix epoch; `None` without messages.
    pub start_ns: Option<u64>,
    /// Latest log time, ns since the Unix epoch; `None` without messages.
    pub end_ns: Option<u64>,
    /// `end_ns - start_ns`, seconds; 0 without messages.
    pub duration_s: f64,
    /// One row per channel, sorted by topic.
    pub topics: Vec<TopicSummary>,
    /// Camera frames, compressed and raw together.
    pub frames: usize,
    /// Size and format of the first frame; `None` without frames.
    pub image: Option<ImageSummary>,
    /// Pinhole intrinsics from the first CameraInfo; `None` if absent or not a valid pinhole.
    pub intrinsics: Option<Camera>,
    /// Frames (label stamps) with at least one region, of any object: two objects boxed in
    /// one frame count once, as `record import` counts them.
    pub labelled_frames: usize,
    /// Frames whose labels have no region: marked as showing none of their objects.
    pub background_frames: usize,
    /// Objects boxed in at least one label, sorted, each once.
    pub objects_labelled: Vec<String>,
    /// Whether the file holds any ground truth (true poses or true object boxes).
    pub ground_truth: bool,
    /// Object names of the ground-truth boxes, in order of first appearance.
    pub ground_truth_objects: Vec<String>,
    /// Session topics (by role) with no message in this file.
    pub missing_topics: Vec<String>,
    /// Problems that leave the file readable, one line each, in a fixed order.
    pub warnings: Vec<String>,
}

/// Reads `path` and summarises it. Fails only on damage that makes the file unreadable or on
/// a session-role message that does not decode.
pub fn summarize(path: &Path, topics: Topics) -> Result<Summary, SessionError> {
    let reader = SessionReader::open(path, topics)?;
    summarize_reader(&reader)
}

/// Summarises an open session: its topics, frames, labels and ground truth, and what looks
/// wrong with it.
pub fn summarize_reader(reader: &SessionReader) -> Result<Summary, SessionError> {
    let topics = reader.topics();
    let mut warnings = reader.warnings.clone();
    warnings.extend(backwards_warnings(reader));
    let mut scan = scan(reader)?;
    warnings.append(&mut scan.warnings);
    check_frames_decode(reader, &scan.frames)?;
    warnings.extend(size_mismatch_warning(&scan));
    warnings.extend(other_size_warning(&scan));
    warnings.extend(unposed_warning(&scan, topics));
    warnings.extend(orphan_label_warning(&scan));

    let mut objects_labelled: Vec<String> = scan
        .labels
        .iter()
        .filter(|l| l.labelled)
        .map(|l| l.object.clone())
        .collect();
    objects_labelled.sort();
    objects_labelled.dedup();

    let (start_ns, end_ns) = reader.time_range_ns().unzip();
    Ok(Summary {
        path: reader.path().display().to_string(),
        profile: reader.profile.clone(),
        library: reader.library.clone(),
        file_bytes: reader.file_len,
        bytes_intact: reader.bytes_intact,
        messages: usize::try_from(reader.message_count()).unwrap_or(usize::MAX),
        start_ns,
        end_ns,
        duration_s: match (start_ns, end_ns) {
            (Some(a), Some(b)) => (b - a) as f64 * 1e-9,
            _ => 0.0,
        },
        topics: topic_rows(reader),
        frames: scan.frame_stamps.len(),
        labelled_frames: scan.labelled_stamps().len(),
        background_frames: scan.background_stamps().len(),
        missing_topics: missing_topics(topics, |t| reader.count(t), !scan.frame_stamps.is_empty()),
        image: scan.image,
        intrinsics: scan.intrinsics,
        objects_labelled,
        ground_truth: scan.gt_present,
        ground_truth_objects: scan.gt_objects,
        warnings,
    })
}

/// One row per channel, sorted by topic: message count and first and last log time.
fn topic_rows(reader: &SessionReader) -> Vec<TopicSummary> {
    let topics = reader.topics();
    let mut topic_rows: Vec<TopicSummary> = reader
        .channels()
        .values()
        .map(|c| {
            let stats = reader.channel_stats(c.id);
            let count = stats.map_or(0, |s| usize::try_from(s.count).unwrap_or(usize::MAX));
            let (first, last) = stats
                .map(|s| (s.first_log_time_ns, s.last_log_time_ns))
                .unzip();
            TopicSummary {
                topic: c.topic.clone(),
                type_name: c.schema_name.clone(),
                message_encoding: c.message_encoding.clone(),
                count,
                role: topics.role_of(&c.topic).map(|r| r.key().to_owned()),
                first_log_time_ns: first,
                last_log_time_ns: last,
            }
        })
        .collect();
    topic_rows.sort_by(|a, b| a.topic.cmp(&b.topic));
    topic_rows
}

/// A warning per topic whose log times go backwards.
fn backwards_warnings(reader: &SessionReader) -> impl Iterator<Item = String> + '_ {
    reader.backwards.iter().map(|(topic, t, prev)| {
        format!(
            "timestamps go backwards on {topic}: log time {} after {}",
            fmt_ns(*t),
            fmt_ns(*prev)
        )
    })
}

/// A label message as the scan saw it.
struct LabelSeen {
    stamp_ns: i64,
    log_time_ns: u64,
    /// It boxes the object (otherwise it marks a background frame).
    labelled: bool,
    object: String,
}

impl Scan {
    /// Stamps of frames with a region of any object, each once.
    fn labelled_stamps(&self) -> std::collections::BTreeSet<i64> {
        self.labels
            .iter()
            .filter(|l| l.labelled)
            .map(|l| l.stamp_ns)
            .collect()
    }

    /// Stamps of frames whose labels all have no region, each once.
    fn background_stamps(&self) -> std::collections::BTreeSet<i64> {
        let labelled = self.labelled_stamps();
        self.labels
            .iter()
            .map(|l| l.stamp_ns)
            .filter(|t| !labelled.contains(t))
            .collect()
    }
}

/// A frame of another size than the first: its topic, log time and size.
type OtherSize = (String, u64, (u32, u32));

/// What one pass over the session-role messages found.
#[derive(Default)]
struct Scan {
    /// (header stamp, log time) of every frame, in replay order.
    frame_stamps: Vec<(i64, u64)>,
    /// Header stamps of every odometry message, sorted.
    odom_stamps: Vec<i64>,
    /// The first frame's size and encoding.
    image: Option<ImageSummary>,
    /// From the first CameraInfo.
    intrinsics: Option<Camera>,
    /// Image size of the last CameraInfo.
    info_size: Option<(u32, u32)>,
    /// The first usable CameraInfo's camera and distortion, and whether a later one was
    /// seen to differ (warned once).
    first_camera: Option<(Camera, Distortion)>,
    camera_changed: bool,
    labels: Vec<LabelSeen>,
    /// Ground-truth object names, in first-appearance order.
    gt_objects: Vec<String>,
    gt_present: bool,
    /// Every frame's message, for the decode check.
    frames: Vec<MessageMeta>,
    /// Frames of another size than the first: how many, and the first of them.
    other_size: (usize, Option<OtherSize>),
    /// Warnings about single messages, in replay order.
    warnings: Vec<String>,
}

impl Scan {
    /// Warns (once) when a CameraInfo differs from the first usable one: `fuse` refuses such
    /// a session, so `inspect` says which values change, and when.
    fn check_camera(&mut self, ci: &crate::io::msgs::CameraInfo, topic: &str, log_time_ns: u64) {
        let (Some(cam), Ok(d)) = (Camera::from_info(ci), Distortion::from_info(ci)) else {
            return;
        };
        let Some(first) = &self.first_camera else {
            self.first_camera = Some((cam, d));
            return;
        };
        if self.camera_changed {
            return;
        }
        if let Some(what) = camera_changes((&first.0, &first.1), (&cam, &d)) {
            self.camera_changed = true;
            self.warnings.push(format!(
                "{topic} at {}: CameraInfo changes ({what}); fuse takes one camera and refuses this session",
                fmt_ns(log_time_ns)
            ));
        }
    }
}

/// Decodes every session-role message in replay order; fails on the first that does not
/// decode (frames: only their size is read here).
fn scan(reader: &SessionReader) -> Result<Scan, SessionError> {
    let mut s = Scan::default();
    for meta in reader.ordered() {
        let meta = meta?;
        let Some(m) = reader.decode(&meta)? else {
            continue;
        };
        match m.msg {
            SessionMsg::Frame(f) => {
                // Every frame's size from its header (no decode): fuse refuses a session
                // whose frames change size, and train took such a frame silently.
                let (w, h) = f.dimensions().map_err(|e| SessionError::Invalid {
                    at: reader.at(Some(&m.topic), m.log_time_ns),
                    what: e.to_string(),
                })?;
                match &s.image {
                    None => {
                        s.image = Some(ImageSummary {
                            width: w,
                            height: h,
                            encoding: f.encoding(),
                        })
                    }
                    Some(first) if (first.width, first.height) != (w, h) => {
                        s.other_size.0 += 1;
                        s.other_size
                            .1
                            .get_or_insert((m.topic.clone(), m.log_time_ns, (w, h)));
                    }
                    Some(_) => {}
                }
                s.frame_stamps.push((f.stamp_ns, m.log_time_ns));
                s.frames.push(meta);
            }
            SessionMsg::CameraInfo(ci) => {
                s.info_size = Some((ci.width, ci.height));
                s.check_camera(&ci, &m.topic, m.log_time_ns);
                if s.intrinsics.is_none() {
                    s.intrinsics = Camera::from_info(&ci);
                    if s.intrinsics.is_none() {
                        s.warnings.push(format!(
                            "{} at {}: CameraInfo K is not a valid pinhole camera",
                            m.topic,
                            fmt_ns(m.log_time_ns)
                        ));
                    }
                }
            }
            SessionMsg::Odom(o) => s.odom_stamps.push(o.header.stamp_ns),
            SessionMsg::Label(l) => s.labels.push(LabelSeen {
                stamp_ns: l.header.stamp_ns,
                log_time_ns: m.log_time_ns,
                labelled: !l.regions.is_empty(),
                object: l.object,
            }),
            SessionMsg::GroundTruthObjects(g) => {
                s.gt_present = true;
                for o in g.object {
                    if !s.gt_objects.contains(&o) {
                        s.gt_objects.push(o);
                    }
                }
            }
            SessionMsg::GroundTruthPose(_) => s.gt_present = true,
            SessionMsg::TfStatic(_) | SessionMsg::Tf(_) | SessionMsg::CmdVel(_) => {}
        }
    }
    s.odom_stamps.sort_unstable();
    Ok(s)
}

/// Frames decoded at once by the pixel check: enough to keep every core busy, few enough
/// that memory stays flat whatever the session's length.
pub const DECODE_BATCH: usize = 64;

/// Fails on the first frame, in replay order, whose image does not decode; `frames` are
/// the frames' messages in the reader.
fn check_frames_decode(reader: &SessionReader, frames: &[MessageMeta]) -> Result<(), SessionError> {
    // Every frame must decode: one corrupt PNG would otherwise surface only deep inside train
    // or fuse. Batches run in order and each keeps its results in order, so the first failure
    // in replay order is reported, whatever the thread count.
    for batch in frames.chunks(DECODE_BATCH) {
        let failures: Vec<Result<(), SessionError>> =
            batch.par_iter().map(|m| check_frame(reader, m)).collect();
        if let Some(e) = failures.into_iter().find_map(Result::err) {
            return Err(e);
        }
    }
    Ok(())
}

/// Loads the frame `meta` and decodes its image (then drops it).
fn check_frame(reader: &SessionReader, meta: &MessageMeta) -> Result<(), SessionError> {
    let Some(m) = reader.decode(meta)? else {
        return Ok(());
    };
    if let SessionMsg::Frame(f) = m.msg {
        f.decode_rgb8().map_err(|e| SessionError::Invalid {
            at: reader.at(Some(&m.topic), m.log_time_ns),
            what: e.to_string(),
        })?;
    }
    Ok(())
}

/// Warns when frames differ in size from the first.
fn other_size_warning(scan: &Scan) -> Option<String> {
    let (n, Some((topic, log_time_ns, (w, h)))) = &scan.other_size else {
        return None;
    };
    let first = scan.image.as_ref()?;
    Some(format!(
        "{topic} at {}: {n} frame(s) differ in size from the first frame's {} x {} (this one {w} x {h}); fuse refuses such a session",
        fmt_ns(*log_time_ns),
        first.width,
        first.height
    ))
}

/// Warns when the frames' size is not the one CameraInfo gives.
fn size_mismatch_warning(scan: &Scan) -> Option<String> {
    let (img, (w, h)) = (scan.image.as_ref()?, scan.info_size?);
    ((img.width, img.height) != (w, h)).then(|| {
        format!(
            "frames are {} x {} but CameraInfo says {w} x {h}",
            img.width, img.height
        )
    })
}

/// Warns about frames with no odometry pose close enough in time to pose them.
fn unposed_warning(scan: &Scan, topics: &Topics) -> Option<String> {
    let unposed: Vec<&(i64, u64)> = scan
        .frame_stamps
        .iter()
        .filter(|(stamp, _)| !crate::types::track::covered(&scan.odom_stamps, *stamp))
        .collect();
    let (_, lt) = unposed.first()?;
    Some(format!(
        "{} frame(s) have no {} pose within 50 ms, nor two around them at most 250 ms apart (first at log time {})",
        unposed.len(),
        topics.odom,
        fmt_ns(*lt)
    ))
}

/// Warns about labels that name no frame (no frame has their stamp).
fn orphan_label_warning(scan: &Scan) -> Option<String> {
    let mut frame_set: Vec<i64> = scan.frame_stamps.iter().map(|(s, _)| *s).collect();
    frame_set.sort_unstable();
    let orphan: Vec<&LabelSeen> = scan
        .labels
        .iter()
        .filter(|l| frame_set.binary_search(&l.stamp_ns).is_err())
        .collect();
    let first = orphan.first()?;
    Some(format!(
        "{} label(s) have no frame with the same stamp (first at log time {})",
        orphan.len(),
        fmt_ns(first.log_time_ns)
    ))
}

/// Session topics (by role) with no message; the two image roles count as one, and /tf is
/// not missed (only a moving camera mount needs it, and /tf_static names the mount).
fn missing_topics(topics: &Topics, count: impl Fn(&str) -> usize, has_frames: bool) -> Vec<String> {
    Role::ALL
        .into_iter()
        .filter(|r| !matches!(r, Role::Image | Role::CompressedImage | Role::Tf))
        .filter(|r| count(topics.get(*r)) == 0)
        .map(|r| topics.get(r).to_owned())
        .chain((!has_frames).then(|| format!("{} (or {})", topics.compressed_image, topics.image)))
        .collect()
}

impl Summary {
    /// Human-readable report, as `objloc inspect` prints it.
    pub fn to_text(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let _ = writeln!(s, "file:       {} ({} bytes)", self.path, self.file_bytes);
        let _ = writeln!(
            s,
            "profile:    {}    library: {}",
            if self.profile.is_empty() {
                "(none)"
            } else {
                &self.profile
            },
            self.library
        );
        let _ = writeln!(
            s,
            "messages:   {}    start {}    end {}    duration {:.3} s",
            self.messages,
            self.start_ns.map(fmt_ns).unwrap_or_else(|| "-".into()),
            self.end_ns.map(fmt_ns).unwrap_or_else(|| "-".into()),
            self.duration_s
        );
        s.push_str(&topic_table(&self.topics));
        let _ = writeln!(s, "frames:     {}", self.frames);
        if let Some(i) = &self.image {
            let _ = writeln!(s, "image:      {} x {} {}", i.width, i.height, i.encoding);
        }
        if let Some(c) = &self.intrinsics {
            let _ = writeln!(
                s,
                "intrinsics: fx {:.2} fy {:.2} cx {:.2} cy {:.2} ({} x {})",
                c.fx, c.fy, c.cx, c.cy, c.width, c.height
            );
        }
        let _ = writeln!(
            s,
            "labels:     {} labelled frame(s){}, {} background frame(s)",
            self.labelled_frames,
            if self.objects_labelled.is_empty() {
                String::new()
            } else {
                format!(" of {}", self.objects_labelled.join(", "))
            },
            self.background_frames
        );
        let _ = writeln!(
            s,
            "ground truth: {}",
            if self.ground_truth {
                if self.ground_truth_objects.is_empty() {
                    "yes".to_owned()
                } else {
                    format!("yes ({})", self.ground_truth_objects.join(", "))
                }
            } else {
                "no".to_owned()
            }
        );
        if !self.missing_topics.is_empty() {
            let _ = writeln!(
                s,
                "missing session topics: {}",
                self.missing_topics.join(", ")
            );
        }
        for w in &self.warnings {
            let _ = writeln!(s, "warning: {w}");
        }
        s
    }
}

/// The topic rows as `objloc inspect` prints them: topic, type, count, encoding and role.
fn topic_table(rows: &[TopicSummary]) -> String {
    use std::fmt::Write;
    let mut s = String::from("topics:\n");
    let w = rows.iter().map(|t| t.topic.len()).max().unwrap_or(5);
    let tw = rows.iter().map(|t| t.type_name.len()).max().unwrap_or(4);
    for t in rows {
        let _ = writeln!(
            s,
            "  {:<w$}  {:<tw$}  {:>6}  {}{}",
            t.topic,
            t.type_name,
            t.count,
            t.message_encoding,
            t.role
                .as_ref()
                .map(|r| format!("  [{r}]"))
                .unwrap_or_default(),
        );
    }
    s
}

/// What the summary section of a file says, as `objloc inspect --quick` reports it: no
/// message is read, so nothing is decoded or checked.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct SectionSummary {
    /// The file, as given.
    pub path: String,
    /// MCAP header profile, e.g. `ros2`; empty if the file declares none.
    pub profile: String,
    /// MCAP header library: what wrote the file.
    pub library: String,
    /// Size of the file, bytes.
    pub file_bytes: u64,
    /// Messages in the file, on every topic (the Statistics record).
    pub messages: u64,
    /// Earliest log time, ns since the Unix epoch; `None` without messages.
    pub start_ns: Option<u64>,
    /// Latest log time, ns since the Unix epoch; `None` without messages.
    pub end_ns: Option<u64>,
    /// `end_ns - start_ns`, seconds; 0 without messages.
    pub duration_s: f64,
    /// One row per channel, sorted by topic (first and last log times are not in the
    /// summary: `null`).
    pub topics: Vec<TopicSummary>,
    /// Messages on the two image topics.
    pub frames: u64,
    /// Chunks in the file.
    pub chunks: u32,
    /// Session topics (by role) with no message in this file.
    pub missing_topics: Vec<String>,
}

/// What `objloc inspect --quick` found: the summary section, or (without a usable one) the
/// full check. Serialised with `"read": "summary_only"` or `"read": "full_scan"`.
#[derive(Debug, Clone, Serialize, PartialEq)]
#[serde(tag = "read", rename_all = "snake_case")]
pub enum QuickSummary {
    /// Read from the summary section only.
    SummaryOnly(SectionSummary),
    /// The file has no usable summary section (none, no Statistics, or truncated): the whole
    /// file was read and checked, as without `--quick`.
    FullScan {
        /// Why the summary section was not used, in words.
        why: String,
        /// The full check's summary.
        #[serde(flatten)]
        summary: Summary,
    },
}

/// Summarises `path` from its summary section when it has a usable one, else by the full
/// check ([`summarize`]).
pub fn summarize_quick(path: &Path, topics: Topics) -> Result<QuickSummary, SessionError> {
    let why = match crate::io::session::read_summary_section(path) {
        Ok(Some(section)) => {
            return Ok(QuickSummary::SummaryOnly(section_summary(
                path, &topics, section,
            )));
        }
        Ok(None) => "the file has no summary section with statistics".to_owned(),
        // The reader's error already says what it is ("FILE: the summary section does not
        // read: ...").
        Err(e) => e.to_string(),
    };
    Ok(QuickSummary::FullScan {
        why,
        summary: summarize(path, topics)?,
    })
}

/// The report of a summary section.
fn section_summary(
    path: &Path,
    topics: &Topics,
    section: crate::io::session::SummarySection,
) -> SectionSummary {
    let count_of = |id: u16| {
        section
            .channel_message_counts
            .get(&id)
            .copied()
            .unwrap_or(0)
    };
    let topic_count = |topic: &str| -> u64 {
        section
            .channels
            .values()
            .filter(|c| c.topic == topic)
            .map(|c| count_of(c.id))
            .sum()
    };
    let mut rows: Vec<TopicSummary> = section
        .channels
        .values()
        .map(|c| TopicSummary {
            topic: c.topic.clone(),
            type_name: c.schema_name.clone(),
            message_encoding: c.message_encoding.clone(),
            count: usize::try_from(count_of(c.id)).unwrap_or(usize::MAX),
            role: topics.role_of(&c.topic).map(|r| r.key().to_owned()),
            first_log_time_ns: None,
            last_log_time_ns: None,
        })
        .collect();
    rows.sort_by(|a, b| a.topic.cmp(&b.topic));
    let frames = topic_count(&topics.compressed_image) + topic_count(&topics.image);
    let (start_ns, end_ns) = section.time_range_ns.unzip();
    SectionSummary {
        path: path.display().to_string(),
        profile: section.profile.clone(),
        library: section.library.clone(),
        file_bytes: section.file_len,
        messages: section.message_count,
        start_ns,
        end_ns,
        duration_s: section
            .time_range_ns
            .map_or(0.0, |(a, b)| b.saturating_sub(a) as f64 * 1e-9),
        topics: rows,
        frames,
        chunks: section.chunk_count,
        missing_topics: missing_topics(
            topics,
            |t| usize::try_from(topic_count(t)).unwrap_or(usize::MAX),
            frames > 0,
        ),
    }
}

/// The note `inspect --quick` ends its summary-only report with.
pub const SUMMARY_ONLY_NOTE: &str = "read the summary section only (no message decoded or checked; `objloc inspect` without --quick reads and checks every message)";

impl QuickSummary {
    /// Human-readable report, as `objloc inspect --quick` prints it.
    pub fn to_text(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        match self {
            QuickSummary::FullScan { why, summary } => {
                let _ = writeln!(
                    s,
                    "no usable summary section ({why}): read the whole file instead"
                );
                s.push_str(&summary.to_text());
            }
            QuickSummary::SummaryOnly(q) => {
                let _ = writeln!(s, "file:       {} ({} bytes)", q.path, q.file_bytes);
                let profile = if q.profile.is_empty() {
                    "(none)"
                } else {
                    &q.profile
                };
                let _ = writeln!(s, "profile:    {profile}    library: {}", q.library);
                let _ = writeln!(
                    s,
                    "messages:   {}    start {}    end {}    duration {:.3} s",
                    q.messages,
                    q.start_ns.map(fmt_ns).unwrap_or_else(|| "-".into()),
                    q.end_ns.map(fmt_ns).unwrap_or_else(|| "-".into()),
                    q.duration_s
                );
                s.push_str(&topic_table(&q.topics));
                let _ = writeln!(s, "frames:     {}", q.frames);
                let _ = writeln!(s, "chunks:     {}", q.chunks);
                if !q.missing_topics.is_empty() {
                    let _ = writeln!(s, "missing session topics: {}", q.missing_topics.join(", "));
                }
                let _ = writeln!(s, "{SUMMARY_ONLY_NOTE}");
            }
        }
        s
    }

    /// Warnings of the full check (none when the summary section was read).
    pub fn warnings(&self) -> &[String] {
        match self {
            QuickSummary::FullScan { summary, .. } => &summary.warnings,
            QuickSummary::SummaryOnly(_) => &[],
        }
    }
}
