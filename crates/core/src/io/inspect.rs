//! Summary of a session file: what `objloc inspect` prints. Reads, never writes.
//!
//! Invariants: works on any ROS 2 MCAP, session or not: topics without a session role are
//! counted, not decoded; missing session topics are listed, not fatal; damage that leaves the
//! rest readable (a truncated tail) is a warning with how much was read; every frame of a
//! session topic is decoded, and the first that does not decode is an error.

use std::collections::BTreeMap;
use std::path::Path;

use rayon::prelude::*;
use serde::Serialize;

use crate::io::session::{Frame, Role, SessionError, SessionMsg, SessionReader, Topics, fmt_ns};
use crate::types::geometry::Camera;

#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct TopicSummary {
    pub topic: String,
    #[serde(rename = "type")]
    pub type_name: String,
    pub message_encoding: String,
    pub count: usize,
    /// The session role of this topic (`odom`, `camera_info`, ...), if any.
    pub role: Option<String>,
    pub first_log_time_ns: Option<u64>,
    pub last_log_time_ns: Option<u64>,
}

#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct ImageSummary {
    pub width: u32,
    pub height: u32,
    pub encoding: String,
}

#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Summary {
    pub path: String,
    pub profile: String,
    pub library: String,
    pub file_bytes: u64,
    pub bytes_intact: u64,
    pub messages: usize,
    pub start_ns: Option<u64>,
    pub end_ns: Option<u64>,
    pub duration_s: f64,
    pub topics: Vec<TopicSummary>,
    pub frames: usize,
    pub image: Option<ImageSummary>,
    pub intrinsics: Option<Camera>,
    pub labelled_frames: usize,
    pub background_frames: usize,
    pub objects_labelled: Vec<String>,
    pub ground_truth: bool,
    pub ground_truth_objects: Vec<String>,
    /// Session topics (by role) with no message in this file.
    pub missing_topics: Vec<String>,
    pub warnings: Vec<String>,
}

/// Reads `path` and summarises it. Fails only on damage that makes the file unreadable or on
/// a session-role message that does not decode.
pub fn summarize(path: &Path, topics: Topics) -> Result<Summary, SessionError> {
    let reader = SessionReader::open(path, topics)?;
    summarize_reader(&reader)
}

pub fn summarize_reader(reader: &SessionReader) -> Result<Summary, SessionError> {
    let topics = reader.topics();
    let raw = reader.raw_messages();
    let mut per_channel: BTreeMap<u16, (usize, Option<u64>, Option<u64>)> = BTreeMap::new();
    for m in raw {
        let e = per_channel.entry(m.channel_id).or_insert((0, None, None));
        e.0 += 1;
        e.1 = Some(e.1.map_or(m.log_time_ns, |t: u64| t.min(m.log_time_ns)));
        e.2 = Some(e.2.map_or(m.log_time_ns, |t: u64| t.max(m.log_time_ns)));
    }
    let mut topic_rows: Vec<TopicSummary> = reader
        .channels()
        .values()
        .map(|c| {
            let (count, first, last) = per_channel.get(&c.id).copied().unwrap_or((0, None, None));
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

    let mut warnings = reader.warnings.clone();
    for (topic, t, prev) in &reader.backwards {
        warnings.push(format!(
            "timestamps go backwards on {topic}: log time {} after {}",
            fmt_ns(*t),
            fmt_ns(*prev)
        ));
    }

    let mut frame_stamps: Vec<(i64, u64)> = Vec::new();
    let mut odom_stamps: Vec<i64> = Vec::new();
    let mut image: Option<ImageSummary> = None;
    let mut intrinsics: Option<Camera> = None;
    let mut info_size: Option<(u32, u32)> = None;
    let mut labels: Vec<(i64, u64, bool, String)> = Vec::new();
    let mut gt_objects: Vec<String> = Vec::new();
    let mut gt_present = false;
    let mut frames: Vec<(String, u64, Frame)> = Vec::new();

    for msg in reader.messages() {
        let m = msg?;
        match m.msg {
            SessionMsg::Frame(f) => {
                if image.is_none() {
                    let (w, h) = f.dimensions().map_err(|what| SessionError::Invalid {
                        at: reader.at(Some(&m.topic), m.log_time_ns),
                        what,
                    })?;
                    image = Some(ImageSummary {
                        width: w,
                        height: h,
                        encoding: f.encoding(),
                    });
                }
                frame_stamps.push((f.stamp_ns, m.log_time_ns));
                frames.push((m.topic, m.log_time_ns, f));
            }
            SessionMsg::CameraInfo(ci) => {
                info_size = Some((ci.width, ci.height));
                if intrinsics.is_none() {
                    intrinsics = Camera::from_info(&ci);
                    if intrinsics.is_none() {
                        warnings.push(format!(
                            "{} at {}: CameraInfo K is not a valid pinhole camera",
                            m.topic,
                            fmt_ns(m.log_time_ns)
                        ));
                    }
                }
            }
            SessionMsg::Odom(o) => odom_stamps.push(o.header.stamp_ns),
            SessionMsg::Label(l) => labels.push((
                l.header.stamp_ns,
                m.log_time_ns,
                !l.regions.is_empty(),
                l.object,
            )),
            SessionMsg::GroundTruthObjects(g) => {
                gt_present = true;
                for o in g.object {
                    if !gt_objects.contains(&o) {
                        gt_objects.push(o);
                    }
                }
            }
            SessionMsg::GroundTruthPose(_) => gt_present = true,
            SessionMsg::TfStatic(_) | SessionMsg::CmdVel(_) => {}
        }
    }

    // Every frame must decode: one corrupt PNG would otherwise surface only deep inside train
    // or fuse. The first failure in replay order is reported, whatever the thread count.
    let failures: Vec<Option<String>> = frames
        .par_iter()
        .map(|(_, _, f)| f.decode_rgb8().err())
        .collect();
    if let Some(((topic, log_time_ns, _), what)) = frames
        .iter()
        .zip(failures)
        .find_map(|(frame, e)| e.map(|e| (frame, e)))
    {
        return Err(SessionError::Invalid {
            at: reader.at(Some(topic), *log_time_ns),
            what,
        });
    }
    drop(frames);

    if let (Some(img), Some((w, h))) = (&image, info_size)
        && (img.width, img.height) != (w, h)
    {
        warnings.push(format!(
            "frames are {} x {} but CameraInfo says {w} x {h}",
            img.width, img.height
        ));
    }

    odom_stamps.sort_unstable();
    let unposed: Vec<&(i64, u64)> = frame_stamps
        .iter()
        .filter(|(stamp, _)| !crate::types::track::covered(&odom_stamps, *stamp))
        .collect();
    if let Some((_, lt)) = unposed.first() {
        warnings.push(format!(
            "{} frame(s) have no {} pose within 50 ms (first at log time {})",
            unposed.len(),
            topics.odom,
            fmt_ns(*lt)
        ));
    }

    let mut frame_set: Vec<i64> = frame_stamps.iter().map(|(s, _)| *s).collect();
    frame_set.sort_unstable();
    let orphan: Vec<&(i64, u64, bool, String)> = labels
        .iter()
        .filter(|(s, ..)| frame_set.binary_search(s).is_err())
        .collect();
    if let Some((_, lt, ..)) = orphan.first() {
        warnings.push(format!(
            "{} label(s) have no frame with the same stamp (first at log time {})",
            orphan.len(),
            fmt_ns(*lt)
        ));
    }

    let mut objects_labelled: Vec<String> =
        labels.iter().filter(|l| l.2).map(|l| l.3.clone()).collect();
    objects_labelled.sort();
    objects_labelled.dedup();

    let missing_topics: Vec<String> = Role::ALL
        .into_iter()
        .filter(|r| *r != Role::Image && *r != Role::CompressedImage)
        .filter(|r| reader.count(topics.get(*r)) == 0)
        .map(|r| topics.get(r).to_owned())
        .chain(
            (frame_stamps.is_empty())
                .then(|| format!("{} (or {})", topics.compressed_image, topics.image)),
        )
        .collect();

    let start_ns = raw.first().map(|m| m.log_time_ns);
    let end_ns = raw.last().map(|m| m.log_time_ns);
    Ok(Summary {
        path: reader.path().display().to_string(),
        profile: reader.profile.clone(),
        library: reader.library.clone(),
        file_bytes: reader.file_len,
        bytes_intact: reader.bytes_intact,
        messages: raw.len(),
        start_ns,
        end_ns,
        duration_s: match (start_ns, end_ns) {
            (Some(a), Some(b)) => (b - a) as f64 * 1e-9,
            _ => 0.0,
        },
        topics: topic_rows,
        frames: frame_stamps.len(),
        image,
        intrinsics,
        labelled_frames: labels.iter().filter(|l| l.2).count(),
        background_frames: labels.iter().filter(|l| !l.2).count(),
        objects_labelled,
        ground_truth: gt_present,
        ground_truth_objects: gt_objects,
        missing_topics,
        warnings,
    })
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
        let _ = writeln!(s, "topics:");
        let w = self.topics.iter().map(|t| t.topic.len()).max().unwrap_or(5);
        let tw = self
            .topics
            .iter()
            .map(|t| t.type_name.len())
            .max()
            .unwrap_or(4);
        for t in &self.topics {
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
