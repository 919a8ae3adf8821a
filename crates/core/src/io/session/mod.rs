//! Sessions: ROS 2 MCAP files <-> typed messages. The only module that touches MCAP.
//!
//! Invariants: messages come out in (log_time, channel id, sequence) order whatever order the
//! file holds them in; a truncated file yields every message of the whole chunks before the
//! damage plus a warning (like `mcap recover`); every error names the file, and where known the
//! topic and log time. Reading holds a chunk index and a few decompressed chunks, not the file and
//! not an index of every message.

mod reader;
mod writer;

pub use reader::{
    ChannelInfo, ChannelStats, IndexScope, MessageMeta, Ordered, PayloadAt, SessionReader,
    SummarySection, read_summary_section,
};
pub use writer::SessionWriter;

use std::fmt;
use std::path::PathBuf;

use thiserror::Error;

use crate::io::cdr::CdrError;
use crate::io::msgs::{
    CameraInfo, CompressedImage, GroundTruth, Image, ObjectLabel, Odometry, PoseStamped,
    RosMessage, TfMessage, TwistStamped,
};
use crate::types::image::Rgb8;

/// Largest image objloc decodes, in pixels per side; anything larger is refused before
/// allocating (a corrupt header can declare 100000 x 100000).
pub const MAX_IMAGE_SIDE_PX: u32 = 8192;

/// Topic names of a session's roles; bags from real robots often use other names.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Topics {
    /// Camera frames as `sensor_msgs/msg/CompressedImage` (PNG or JPEG).
    pub compressed_image: String,
    /// Camera frames as raw `sensor_msgs/msg/Image`, for bags without compressed frames.
    pub image: String,
    /// Camera intrinsics, `sensor_msgs/msg/CameraInfo`.
    pub camera_info: String,
    /// Static transforms, `tf2_msgs/msg/TFMessage`, among them the camera mount.
    pub tf_static: String,
    /// Transforms that change over time, `tf2_msgs/msg/TFMessage` (a pan-tilt head, an
    /// arm); absent from files written before it existed, which had none.
    #[serde(default = "default_tf")]
    pub tf: String,
    /// The robot's pose and velocity from odometry, `nav_msgs/msg/Odometry`.
    pub odom: String,
    /// Velocity commands to the robot, `geometry_msgs/msg/TwistStamped`.
    pub cmd_vel: String,
    /// Object boxes drawn on frames, `objloc_msgs/msg/ObjectLabel`.
    pub labels: String,
    /// The robot's true pose, `geometry_msgs/msg/PoseStamped` (simulation only).
    pub ground_truth_pose: String,
    /// The objects' true boxes, `objloc_msgs/msg/GroundTruth` (simulation only).
    pub ground_truth_objects: String,
    /// Roles whose topic the user named ([`Topics::with_overrides`]): a file must have each,
    /// of its type. A default name may be absent (a capture has no /cmd_vel); a name typed by
    /// hand that is absent is a mistake, which would otherwise pass for a missing role.
    #[serde(skip)]
    pub named: Vec<Role>,
}

fn default_tf() -> String {
    "/tf".into()
}

impl Default for Topics {
    fn default() -> Self {
        Self {
            compressed_image: "/camera/image/compressed".into(),
            image: "/camera/image".into(),
            camera_info: "/camera/camera_info".into(),
            tf_static: "/tf_static".into(),
            tf: default_tf(),
            odom: "/odom".into(),
            cmd_vel: "/cmd_vel".into(),
            labels: "/labels".into(),
            ground_truth_pose: "/ground_truth/pose".into(),
            ground_truth_objects: "/ground_truth/objects".into(),
            named: Vec::new(),
        }
    }
}

/// The role a topic plays in a session.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Role {
    /// Camera frames, compressed (PNG or JPEG).
    CompressedImage,
    /// Camera frames, raw pixels.
    Image,
    /// Camera intrinsics.
    CameraInfo,
    /// Static transforms, among them the camera mount.
    TfStatic,
    /// Transforms over time (a moving camera mount).
    Tf,
    /// Odometry: the robot's pose over time.
    Odom,
    /// Velocity commands.
    CmdVel,
    /// Object labels of frames.
    Labels,
    /// The robot's true pose (simulation only).
    GroundTruthPose,
    /// The objects' true boxes (simulation only).
    GroundTruthObjects,
}

impl Role {
    /// Every role, in declaration (and `Ord`) order.
    pub const ALL: [Role; 10] = [
        Role::CompressedImage,
        Role::Image,
        Role::CameraInfo,
        Role::TfStatic,
        Role::Tf,
        Role::Odom,
        Role::CmdVel,
        Role::Labels,
        Role::GroundTruthPose,
        Role::GroundTruthObjects,
    ];

    /// The `--topic ROLE=NAME` key of this role.
    pub fn key(self) -> &'static str {
        match self {
            Role::CompressedImage => "compressed_image",
            Role::Image => "image",
            Role::CameraInfo => "camera_info",
            Role::TfStatic => "tf_static",
            Role::Tf => "tf",
            Role::Odom => "odom",
            Role::CmdVel => "cmd_vel",
            Role::Labels => "labels",
            Role::GroundTruthPose => "ground_truth_pose",
            Role::GroundTruthObjects => "ground_truth_objects",
        }
    }

    /// The ROS 2 type, `pkg/msg/Type`, a topic in this role must carry.
    pub fn message_type(self) -> &'static str {
        match self {
            Role::CompressedImage => CompressedImage::TYPE,
            Role::Image => Image::TYPE,
            Role::CameraInfo => CameraInfo::TYPE,
            Role::TfStatic | Role::Tf => TfMessage::TYPE,
            Role::Odom => Odometry::TYPE,
            Role::CmdVel => TwistStamped::TYPE,
            Role::Labels => ObjectLabel::TYPE,
            Role::GroundTruthPose => PoseStamped::TYPE,
            Role::GroundTruthObjects => GroundTruth::TYPE,
        }
    }
}

impl Topics {
    /// The topic name of `role`.
    pub fn get(&self, role: Role) -> &str {
        match role {
            Role::CompressedImage => &self.compressed_image,
            Role::Image => &self.image,
            Role::CameraInfo => &self.camera_info,
            Role::TfStatic => &self.tf_static,
            Role::Tf => &self.tf,
            Role::Odom => &self.odom,
            Role::CmdVel => &self.cmd_vel,
            Role::Labels => &self.labels,
            Role::GroundTruthPose => &self.ground_truth_pose,
            Role::GroundTruthObjects => &self.ground_truth_objects,
        }
    }

    fn get_mut(&mut self, role: Role) -> &mut String {
        match role {
            Role::CompressedImage => &mut self.compressed_image,
            Role::Image => &mut self.image,
            Role::CameraInfo => &mut self.camera_info,
            Role::TfStatic => &mut self.tf_static,
            Role::Tf => &mut self.tf,
            Role::Odom => &mut self.odom,
            Role::CmdVel => &mut self.cmd_vel,
            Role::Labels => &mut self.labels,
            Role::GroundTruthPose => &mut self.ground_truth_pose,
            Role::GroundTruthObjects => &mut self.ground_truth_objects,
        }
    }

    /// The role of `topic`, if it has one.
    pub fn role_of(&self, topic: &str) -> Option<Role> {
        Role::ALL.into_iter().find(|r| self.get(*r) == topic)
    }

    /// Applies `ROLE=TOPIC` overrides, e.g. `odom=/wheel/odometry`.
    pub fn with_overrides<S: AsRef<str>>(mut self, overrides: &[S]) -> Result<Self, String> {
        for o in overrides {
            let o = o.as_ref();
            let (key, topic) = o
                .split_once('=')
                .ok_or_else(|| format!("topic override {o:?} is not ROLE=TOPIC"))?;
            let role = Role::ALL
                .into_iter()
                .find(|r| r.key() == key)
                .ok_or_else(|| {
                    let keys: Vec<_> = Role::ALL.iter().map(|r| r.key()).collect();
                    format!("unknown topic role {key:?}; roles are {}", keys.join(", "))
                })?;
            if topic.is_empty() || topic.chars().any(char::is_whitespace) {
                return Err(format!("topic override {o:?} names no topic (ROLE=/topic)"));
            }
            if self.named.contains(&role) {
                return Err(format!(
                    "role {key:?} is given twice ({key}={} and {o}): which topic to read is not known",
                    self.get_mut(role)
                ));
            }
            *self.get_mut(role) = topic.to_owned();
            self.named.push(role);
        }
        Ok(self)
    }
}

/// Where in a session something happened, for one-line errors.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct At {
    /// The session file.
    pub path: PathBuf,
    /// Topic of the message concerned, if known.
    pub topic: Option<String>,
    /// Log time of the message concerned, ns since the Unix epoch, if known.
    pub log_time_ns: Option<u64>,
}

/// Formats nanoseconds as seconds with all nine decimals.
pub fn fmt_ns(ns: u64) -> String {
    format!("{}.{:09} s", ns / 1_000_000_000, ns % 1_000_000_000)
}

impl fmt::Display for At {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.path.display())?;
        if let Some(t) = &self.topic {
            write!(f, ": topic {t}")?;
        }
        if let Some(ns) = self.log_time_ns {
            write!(f, " at log time {}", fmt_ns(ns))?;
        }
        Ok(())
    }
}

/// The MCAP library's error on one line, for a one-line message: its parser's errors carry
/// a styled backtrace through the crate's source files (terminal escapes, box drawing, the
/// build machine's paths), of which only the innermost error says what is wrong.
/// Other errors keep their causes (an I/O error's "No space left on device"), joined by ": ".
fn one_line(e: &mcap::McapError) -> String {
    let mut text = match e {
        mcap::McapError::Parse(p) => format!("record parse failed: {}", p.root_cause()),
        e => e.to_string(),
    };
    let mut cause = match e {
        mcap::McapError::Parse(_) => None,
        e => std::error::Error::source(e),
    };
    while let Some(c) = cause {
        text.push_str(": ");
        text.push_str(&c.to_string());
        cause = c.source();
    }
    text.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// Why a session could not be read (or written).
#[derive(Debug, Error)]
pub enum SessionError {
    /// Reading, creating, syncing or renaming a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file the operation was on.
        path: PathBuf,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },
    /// The file does not start with the MCAP magic.
    #[error("{}: not an MCAP file (starts with {head:02x?}, expected the MCAP magic 89 4d 43 41 50 30 0d 0a)", path.display())]
    NotMcap {
        /// The file.
        path: PathBuf,
        /// Its first bytes, at most 8.
        head: Vec<u8>,
    },
    /// The MCAP layer failed: a damaged record or chunk on reading, or a write that failed.
    #[error("{at}: {what}: {}", one_line(cause))]
    Mcap {
        /// Where: on reading, the last intact message before the damage.
        at: At,
        /// What was being done or what is damaged, in words.
        what: String,
        /// The MCAP library's error: in the message on one line, not chained as a source
        /// (its own text is a multi-line styled backtrace).
        cause: mcap::McapError,
    },
    /// A session-role message's CDR payload does not decode as the role's type.
    #[error("{at}: cannot decode {type_name}: {source}")]
    Decode {
        /// The message that does not decode.
        at: At,
        /// The type it was decoded as, `pkg/msg/Type`.
        type_name: String,
        /// Why decoding failed.
        #[source]
        source: CdrError,
    },
    /// A session-role topic's schema names another type than the role requires.
    #[error("{at}: schema is {found:?} but this topic must carry {expected}")]
    WrongType {
        /// The message whose channel has the wrong schema.
        at: At,
        /// The type the role requires, `pkg/msg/Type`.
        expected: &'static str,
        /// The schema name the channel declares, as written in the file.
        found: String,
    },
    /// A session-role channel's message encoding is not `cdr`.
    #[error("{at}: message encoding {found:?} is not supported (objloc reads \"cdr\")")]
    Encoding {
        /// The message whose channel has that encoding.
        at: At,
        /// The channel's message encoding, e.g. `json`.
        found: String,
    },
    /// A session-role channel's schema encoding is not `ros2msg`.
    #[error("{at}: schema encoding {found:?} is not supported (objloc reads \"ros2msg\")")]
    SchemaEncoding {
        /// The message whose channel has that schema.
        at: At,
        /// The schema's encoding, e.g. `ros2idl`; empty for a channel without a schema.
        found: String,
    },
    /// Something is inconsistent: a reference to an unknown channel or schema, a frame whose
    /// image does not decode, or (when writing) a stamp before 1970.
    #[error("{at}: {what}")]
    Invalid {
        /// Where the problem is.
        at: At,
        /// What is wrong, in words.
        what: String,
    },
    /// A topic named with `--topic ROLE=TOPIC` is not in the file, or not of the role's type,
    /// or is another role's topic.
    #[error("{path}: --topic {role}={topic}: {what}", path = path.display())]
    NamedTopic {
        /// The session file.
        path: PathBuf,
        /// The role's key, e.g. `cmd_vel`.
        role: &'static str,
        /// The topic named for it.
        topic: String,
        /// What is wrong.
        what: String,
    },
    /// A topic the command needs holds no message.
    #[error("{path}: required topic {topic} ({type_name}) is missing{why}")]
    MissingTopic {
        /// The session file.
        path: PathBuf,
        /// The topic name, or `A or B` when either would do (the two image topics).
        topic: String,
        /// The type the topic must carry, `pkg/msg/Type`.
        type_name: &'static str,
        /// What the reader found wrong with the file, `; ...` (a file cut short holds
        /// fewer topics than it was written with), or empty.
        why: String,
    },
}

/// A camera frame as it was recorded: encoded or raw.
#[derive(Debug, Clone, PartialEq)]
pub enum FramePixels {
    /// PNG or JPEG bytes (`format` as in the CompressedImage).
    Encoded {
        /// The CompressedImage `format`, e.g. `png` or `jpeg`.
        format: String,
        /// The compressed image file's bytes.
        data: Vec<u8>,
    },
    /// A raw `sensor_msgs/msg/Image`, as recorded.
    Raw(Image),
}

/// The file formats of a CompressedImage that objloc reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EncodedMedia {
    /// PNG (`image/png`).
    Png,
    /// JPEG (`image/jpeg`).
    Jpeg,
}

impl EncodedMedia {
    /// The format a CompressedImage `format` names (`png`, `jpeg`, or image_transport's
    /// `rgb8; jpeg compressed bgr8` and the like), case aside; None for any other.
    pub fn of_format(format: &str) -> Option<Self> {
        let f = format.to_ascii_lowercase();
        if f.contains("png") {
            Some(Self::Png)
        } else if f.contains("jpeg") || f.contains("jpg") {
            Some(Self::Jpeg)
        } else {
            None
        }
    }

    fn image_format(self) -> image::ImageFormat {
        match self {
            Self::Png => image::ImageFormat::Png,
            Self::Jpeg => image::ImageFormat::Jpeg,
        }
    }
}

/// Whether a JPEG's EXIF orientation, if any, is "as stored" (false when it cannot be read).
fn jpeg_is_upright(data: &[u8]) -> bool {
    use image::ImageDecoder as _;
    image::codecs::jpeg::JpegDecoder::new(std::io::Cursor::new(data))
        .and_then(|mut d| d.orientation())
        .is_ok_and(|o| o == image::metadata::Orientation::NoTransforms)
}

/// Whether a JPEG has an end-of-image marker (FF D9) after its last start-of-scan (FF DA).
/// Neither pair occurs inside entropy-coded data (an FF there is followed by 00 or a restart
/// marker), so a file cut inside its last scan has none after it, whatever comes before (an
/// EXIF thumbnail's own EOI precedes the main image's scans). Bytes after the EOI are allowed.
pub(crate) fn jpeg_is_complete(data: &[u8]) -> bool {
    let has_scan = |bytes: &[u8]| bytes.windows(2).any(|w| w == [0xFF, 0xDA]);
    // Searched from the end, where a whole file's marker is: every frame decoded passes here,
    // and only the bytes after the last EOI (usually none) are searched for a scan.
    match data.windows(2).rposition(|w| w == [0xFF, 0xD9]) {
        Some(eoi) => !has_scan(&data[eoi + 2..]),
        // No end marker: cut short if it has a scan; without one, the decoder's own error
        // says what is wrong.
        None => !has_scan(data),
    }
}

/// One camera frame of a session, from either image topic.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Header stamp, ns since the epoch; labels and poses are matched to the frame by it.
    pub stamp_ns: i64,
    /// Header frame id: the camera's optical frame, e.g. `camera_optical_frame`.
    pub frame_id: String,
    /// The image as recorded, compressed or raw.
    pub pixels: FramePixels,
}

/// Why a frame's pixels cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum FrameError {
    /// The encoded bytes are not an image (or not a complete one).
    #[error("image does not decode: {0}")]
    Decode(#[from] image::ImageError),
    /// Reading the encoded bytes' header failed.
    #[error("image does not decode: {0}")]
    Header(#[from] std::io::Error),
    /// A side is 0 or beyond [`MAX_IMAGE_SIDE_PX`].
    #[error(
        "image of {width} x {height} pixels refused (each side must be 1 to {MAX_IMAGE_SIDE_PX})"
    )]
    Size {
        /// Width the image declares, pixels.
        width: u32,
        /// Height the image declares, pixels.
        height: u32,
    },
    /// A JPEG without its end-of-image marker after its last scan: cut short (a decoder
    /// fills the missing part with grey and says nothing).
    #[error("JPEG of {bytes} bytes ends inside its image data (no end-of-image marker): truncated")]
    TruncatedJpeg {
        /// The file's length, bytes.
        bytes: usize,
    },
    /// A CompressedImage format other than PNG and JPEG.
    #[error("compressed format {0:?} is not read (objloc reads png and jpeg)")]
    Format(String),
    /// A raw Image encoding objloc does not read.
    #[error("raw encoding {0:?} is not read (rgb8, bgr8, rgba8, bgra8, mono8 are)")]
    Encoding(String),
    /// A raw Image row step shorter than a row.
    #[error("step {step} is less than width {width} x {channels} bytes")]
    Step {
        /// Row length the image declares, bytes.
        step: usize,
        /// Image width, pixels.
        width: usize,
        /// Bytes per pixel of the encoding (1, 3 or 4).
        channels: usize,
    },
    /// A raw Image with fewer bytes than its size needs.
    #[error("raw image of {width} x {height} ({encoding}) needs {needed} bytes, has {have}")]
    Length {
        /// Image width, pixels.
        width: usize,
        /// Image height, pixels.
        height: usize,
        /// The raw encoding, e.g. `rgb8`.
        encoding: String,
        /// Bytes the declared size takes, `step * height`.
        needed: usize,
        /// Bytes the message holds.
        have: usize,
    },
}

impl Frame {
    /// Width and height without decoding the pixels.
    pub fn dimensions(&self) -> Result<(u32, u32), FrameError> {
        match &self.pixels {
            FramePixels::Encoded { data, .. } => {
                Ok(image::ImageReader::new(std::io::Cursor::new(data))
                    .with_guessed_format()?
                    .into_dimensions()?)
            }
            FramePixels::Raw(img) => Ok((img.width, img.height)),
        }
    }

    /// The format in words, e.g. `png` or `raw rgb8`.
    pub fn encoding(&self) -> String {
        match &self.pixels {
            FramePixels::Encoded { format, .. } => format.clone(),
            FramePixels::Raw(img) => format!("raw {}", img.encoding),
        }
    }

    /// The recorded image file, when it is a PNG or JPEG file that its `format` names (its
    /// bytes say so too) and shows its pixels as stored: what a viewer can show without it
    /// being decoded and encoded again. None for raw images, anything else, and a JPEG whose
    /// EXIF orientation asks a viewer to turn it (objloc classifies the stored pixels, which
    /// is also what structure-from-motion tools pose, so a viewer that honoured the tag would
    /// show another picture than the one fused).
    pub fn encoded_file(&self) -> Option<(EncodedMedia, &[u8])> {
        match &self.pixels {
            FramePixels::Encoded { format, data } => {
                let media = EncodedMedia::of_format(format)?;
                let upright = match media {
                    EncodedMedia::Png => true,
                    EncodedMedia::Jpeg => jpeg_is_upright(data),
                };
                (upright && image::guess_format(data).ok() == Some(media.image_format()))
                    .then_some((media, data.as_slice()))
            }
            FramePixels::Raw(_) => None,
        }
    }

    /// Decodes to RGB8. Sizes beyond [`MAX_IMAGE_SIDE_PX`] are refused before allocating.
    pub fn decode_rgb8(&self) -> Result<Rgb8, FrameError> {
        let (w, h) = self.dimensions()?;
        if w == 0 || h == 0 || w > MAX_IMAGE_SIDE_PX || h > MAX_IMAGE_SIDE_PX {
            return Err(FrameError::Size {
                width: w,
                height: h,
            });
        }
        match &self.pixels {
            FramePixels::Encoded { format, data } => {
                let named = EncodedMedia::of_format(format)
                    .ok_or_else(|| FrameError::Format(format.clone()))?;
                // The bytes say what they are: a PNG whose `format` says jpeg (a recorder's
                // mislabel) was refused as a truncated JPEG.
                let media = match image::guess_format(data) {
                    Ok(image::ImageFormat::Png) => EncodedMedia::Png,
                    Ok(image::ImageFormat::Jpeg) => EncodedMedia::Jpeg,
                    _ => named,
                };
                if media == EncodedMedia::Jpeg && !jpeg_is_complete(data) {
                    return Err(FrameError::TruncatedJpeg { bytes: data.len() });
                }
                let fmt = media.image_format();
                let img = image::load_from_memory_with_format(data, fmt)?.into_rgb8();
                Ok(Rgb8 {
                    width: img.width(),
                    height: img.height(),
                    data: img.into_raw(),
                })
            }
            FramePixels::Raw(img) => raw_to_rgb8(img),
        }
    }
}

fn raw_to_rgb8(img: &Image) -> Result<Rgb8, FrameError> {
    let (w, h) = (img.width as usize, img.height as usize);
    let channels = match img.encoding.as_str() {
        "rgb8" | "bgr8" => 3,
        "rgba8" | "bgra8" => 4,
        "mono8" => 1,
        other => return Err(FrameError::Encoding(other.to_owned())),
    };
    let step = img.step as usize;
    if step < w * channels {
        return Err(FrameError::Step {
            step,
            width: w,
            channels,
        });
    }
    // The last row may lack its padding; more than `step * height` bytes is a wrong size or
    // encoding (rgb bytes under a mono8 header read as a third of the picture, silently).
    let least = step
        .saturating_mul(h.saturating_sub(1))
        .saturating_add(w * channels);
    if img.data.len() < least || img.data.len() > step.saturating_mul(h) {
        return Err(FrameError::Length {
            width: w,
            height: h,
            encoding: img.encoding.clone(),
            needed: step * h,
            have: img.data.len(),
        });
    }
    let mut data = Vec::with_capacity(w * h * 3);
    for y in 0..h {
        let row = &img.data[y * step..y * step + w * channels];
        for px in row.chunks_exact(channels) {
            let rgb = match img.encoding.as_str() {
                "rgb8" | "rgba8" => [px[0], px[1], px[2]],
                "bgr8" | "bgra8" => [px[2], px[1], px[0]],
                _ => [px[0], px[0], px[0]],
            };
            data.extend_from_slice(&rgb);
        }
    }
    Ok(Rgb8 {
        width: img.width,
        height: img.height,
        data,
    })
}

/// A decoded session message, by role. The large fixed-size messages are boxed so that the
/// enum stays small as it moves through the replay.
#[derive(Debug, Clone, PartialEq)]
pub enum SessionMsg {
    /// A camera frame, from the compressed or the raw image topic.
    Frame(Frame),
    /// Camera intrinsics.
    CameraInfo(Box<CameraInfo>),
    /// Static transforms, among them the camera mount.
    TfStatic(TfMessage),
    /// Transforms over time.
    Tf(TfMessage),
    /// An odometry pose and twist.
    Odom(Box<Odometry>),
    /// A velocity command.
    CmdVel(TwistStamped),
    /// The label of one object in one frame.
    Label(ObjectLabel),
    /// The robot's true pose (simulation only).
    GroundTruthPose(PoseStamped),
    /// The objects' true boxes (simulation only).
    GroundTruthObjects(GroundTruth),
}

/// One message in replay order, with where it came from.
#[derive(Debug, Clone, PartialEq)]
pub struct TimedMsg {
    /// MCAP log time, ns since the Unix epoch.
    pub log_time_ns: u64,
    /// Topic it was recorded on.
    pub topic: String,
    /// The decoded message.
    pub msg: SessionMsg,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(format: &str, data: Vec<u8>) -> Frame {
        Frame {
            stamp_ns: 0,
            frame_id: String::new(),
            pixels: FramePixels::Encoded {
                format: format.into(),
                data,
            },
        }
    }

    #[test]
    fn a_recorded_file_is_handed_over_only_when_its_format_and_bytes_agree() {
        let png = crate::types::image::encode_png(2, 1, &[255, 0, 0, 0, 0, 255]).unwrap();
        let f = frame("png", png.clone());
        assert_eq!(f.encoded_file(), Some((EncodedMedia::Png, png.as_slice())));
        // image_transport's compressed formats name the codec after a semicolon.
        let f = frame("rgb8; png compressed bgr8", png.clone());
        assert_eq!(f.encoded_file().map(|e| e.0), Some(EncodedMedia::Png));
        // Bytes that are not what the format says, or a format objloc does not read: decoded
        // (and refused) the usual way, never shown as something they are not.
        assert_eq!(frame("jpeg", png.clone()).encoded_file(), None);
        assert_eq!(frame("webp", png).encoded_file(), None);
        assert_eq!(frame("png", b"not an image".to_vec()).encoded_file(), None);
        let raw = Frame {
            stamp_ns: 0,
            frame_id: String::new(),
            pixels: FramePixels::Raw(crate::io::msgs::Image {
                header: crate::io::msgs::Header {
                    stamp_ns: 0,
                    frame_id: String::new(),
                },
                height: 1,
                width: 1,
                encoding: "rgb8".into(),
                is_bigendian: 0,
                step: 3,
                data: vec![1, 2, 3],
            }),
        };
        assert_eq!(raw.encoded_file(), None);
    }

    /// A raw image's bytes must fit its declared size: the last row may lack its padding,
    /// but rgb bytes under a mono8 header (three times the bytes) were read as a third of
    /// the picture without a word.
    #[test]
    fn a_raw_image_with_more_bytes_than_its_size_is_refused() {
        let img = |encoding: &str, step: u32, data: Vec<u8>| crate::io::msgs::Image {
            header: crate::io::msgs::Header {
                stamp_ns: 0,
                frame_id: String::new(),
            },
            height: 2,
            width: 2,
            encoding: encoding.into(),
            is_bigendian: 0,
            step,
            data,
        };
        let grey = raw_to_rgb8(&img("mono8", 2, vec![1, 2, 3, 4])).unwrap();
        assert_eq!(grey.data, vec![1, 1, 1, 2, 2, 2, 3, 3, 3, 4, 4, 4]);
        // Padded rows of 4 bytes, the last one unpadded: 6 bytes.
        let padded = raw_to_rgb8(&img("mono8", 4, vec![1, 2, 0, 0, 3, 4])).unwrap();
        assert_eq!(padded.data, grey.data);
        let err = raw_to_rgb8(&img("mono8", 2, vec![7; 12])).unwrap_err();
        assert_eq!(
            err.to_string(),
            "raw image of 2 x 2 (mono8) needs 4 bytes, has 12"
        );
        assert!(raw_to_rgb8(&img("mono8", 2, vec![7; 3])).is_err());
    }

    /// A JPEG of 8 x 8 grey pixels with an EXIF APP1 segment whose orientation tag is
    /// `orientation` (1: as stored, 6: turn 90 degrees clockwise), after the SOI marker.
    fn jpeg_with_orientation(orientation: u16) -> Vec<u8> {
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new(&mut jpeg)
            .encode(&[128u8; 8 * 8 * 3], 8, 8, image::ExtendedColorType::Rgb8)
            .unwrap();
        // TIFF header (little-endian, IFD at 8), one IFD entry: 0x0112 SHORT x 1.
        let mut tiff = b"II*\0\x08\0\0\0".to_vec();
        tiff.extend_from_slice(&1u16.to_le_bytes());
        tiff.extend_from_slice(&0x0112u16.to_le_bytes());
        tiff.extend_from_slice(&3u16.to_le_bytes());
        tiff.extend_from_slice(&1u32.to_le_bytes());
        tiff.extend_from_slice(&orientation.to_le_bytes());
        tiff.extend_from_slice(&[0, 0, 0, 0, 0, 0]);
        let mut app1 = vec![0xFF, 0xE1];
        app1.extend_from_slice(&u16::try_from(2 + 6 + tiff.len()).unwrap().to_be_bytes());
        app1.extend_from_slice(b"Exif\0\0");
        app1.extend_from_slice(&tiff);
        let mut out = jpeg[..2].to_vec();
        out.extend_from_slice(&app1);
        out.extend_from_slice(&jpeg[2..]);
        out
    }

    #[test]
    fn a_png_labelled_jpeg_decodes_as_the_png_it_is() {
        let pixels: Vec<u8> = (0..8 * 4 * 3).map(|i| (i * 11 % 256) as u8).collect();
        let png = crate::types::image::encode_png(8, 4, &pixels).unwrap();
        let rgb = frame("jpeg", png.clone()).decode_rgb8().unwrap();
        assert_eq!(rgb.data, pixels);
        // Bytes that are neither are refused.
        let e = frame("png", b"not an image".to_vec())
            .decode_rgb8()
            .unwrap_err();
        assert!(e.to_string().starts_with("image does not decode"), "{e}");
    }

    #[test]
    fn a_jpeg_cut_short_is_refused_not_filled_with_grey() {
        let mut jpeg = Vec::new();
        let pixels: Vec<u8> = (0..32 * 32 * 3).map(|i| (i * 7 % 251) as u8).collect();
        image::codecs::jpeg::JpegEncoder::new(&mut jpeg)
            .encode(&pixels, 32, 32, image::ExtendedColorType::Rgb8)
            .unwrap();
        assert!(frame("jpeg", jpeg.clone()).decode_rgb8().is_ok());
        // Bytes after the end-of-image marker (some cameras pad) are no reason to refuse.
        let mut padded = jpeg.clone();
        padded.extend_from_slice(&[0; 16]);
        assert!(frame("jpeg", padded).decode_rgb8().is_ok());
        // Cut inside the scan: image's decoder alone returns grey pixels without an error.
        let cut = jpeg[..jpeg.len() - 40].to_vec();
        assert!(image::load_from_memory(&cut).is_ok());
        let e = frame("jpeg", cut.clone()).decode_rgb8().unwrap_err();
        assert_eq!(
            e.to_string(),
            format!(
                "JPEG of {} bytes ends inside its image data (no end-of-image marker): truncated",
                cut.len()
            )
        );
        // A thumbnail's end marker before the scans (here in an APP2 segment) does not hide
        // a cut in the main image.
        let thumb = b"\xFF\xD8thumbnail\xFF\xD9";
        let mut with_thumb = jpeg[..2].to_vec();
        with_thumb.extend_from_slice(&[0xFF, 0xE2, 0, 2 + thumb.len() as u8]);
        with_thumb.extend_from_slice(thumb);
        with_thumb.extend_from_slice(&jpeg[2..]);
        assert!(frame("jpeg", with_thumb.clone()).decode_rgb8().is_ok());
        let cut = with_thumb[..with_thumb.len() - 40].to_vec();
        assert!(matches!(
            frame("jpeg", cut).decode_rgb8(),
            Err(FrameError::TruncatedJpeg { .. })
        ));
    }

    #[test]
    fn a_jpeg_a_viewer_would_turn_is_not_handed_over_as_recorded() {
        let upright = jpeg_with_orientation(1);
        assert_eq!(
            frame("jpeg", upright.clone()).encoded_file(),
            Some((EncodedMedia::Jpeg, upright.as_slice()))
        );
        let turned = jpeg_with_orientation(6);
        // The tag is read (the same bytes decode to the same stored pixels either way).
        use image::ImageDecoder as _;
        let o = image::codecs::jpeg::JpegDecoder::new(std::io::Cursor::new(&turned))
            .unwrap()
            .orientation()
            .unwrap();
        assert_eq!(o, image::metadata::Orientation::Rotate90);
        assert_eq!(frame("jpeg", turned).encoded_file(), None);
    }
}

#[cfg(test)]
mod one_line_tests {
    use super::one_line;

    /// An I/O error's cause stays in the line (mcap's own text for it names none).
    #[test]
    fn an_io_error_keeps_its_cause() {
        let e = mcap::McapError::Io(std::io::Error::new(
            std::io::ErrorKind::StorageFull,
            "No space left on device",
        ));
        assert_eq!(
            one_line(&e),
            format!("{e}: No space left on device")
                .split_whitespace()
                .collect::<Vec<_>>()
                .join(" ")
        );
        assert!(
            one_line(&e).ends_with(": No space left on device"),
            "{}",
            one_line(&e)
        );
    }
}

#[cfg(test)]
mod override_tests {
    use super::Topics;

    /// A role named twice, or a role without a topic, is a mistake, not "the last one wins"
    /// (`--topic odom=/ground_truth/pose --topic odom=/odom` read /odom silently).
    #[test]
    fn a_role_named_twice_or_without_a_topic_is_refused() {
        let t = Topics::default()
            .with_overrides(&["odom=/wheel/odom", "cmd_vel=/cmd"])
            .unwrap();
        assert_eq!(
            (t.odom.as_str(), t.cmd_vel.as_str()),
            ("/wheel/odom", "/cmd")
        );
        let e = Topics::default()
            .with_overrides(&["odom=/a", "odom=/b"])
            .unwrap_err();
        assert_eq!(
            e,
            "role \"odom\" is given twice (odom=/a and odom=/b): which topic to read is not known"
        );
        let e = Topics::default().with_overrides(&["odom="]).unwrap_err();
        assert!(e.contains("names no topic"), "{e}");
    }
}
