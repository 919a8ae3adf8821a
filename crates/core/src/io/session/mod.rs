//! Sessions: ROS 2 MCAP files <-> typed messages. The only module that touches MCAP.
//!
//! Invariants: messages come out in (log_time, channel id, sequence) order whatever order the
//! file holds them in; a truncated file yields every message before the damage plus a warning
//! (like `mcap recover`); every error names the file, and where known the topic and log time.

mod reader;
mod writer;

pub use reader::{ChannelInfo, RawMessage, SessionReader};
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
    pub compressed_image: String,
    pub image: String,
    pub camera_info: String,
    pub tf_static: String,
    pub odom: String,
    pub cmd_vel: String,
    pub labels: String,
    pub ground_truth_pose: String,
    pub ground_truth_objects: String,
}

impl Default for Topics {
    fn default() -> Self {
        Self {
            compressed_image: "/camera/image/compressed".into(),
            image: "/camera/image".into(),
            camera_info: "/camera/camera_info".into(),
            tf_static: "/tf_static".into(),
            odom: "/odom".into(),
            cmd_vel: "/cmd_vel".into(),
            labels: "/labels".into(),
            ground_truth_pose: "/ground_truth/pose".into(),
            ground_truth_objects: "/ground_truth/objects".into(),
        }
    }
}

/// The role a topic plays in a session.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Role {
    CompressedImage,
    Image,
    CameraInfo,
    TfStatic,
    Odom,
    CmdVel,
    Labels,
    GroundTruthPose,
    GroundTruthObjects,
}

impl Role {
    pub const ALL: [Role; 9] = [
        Role::CompressedImage,
        Role::Image,
        Role::CameraInfo,
        Role::TfStatic,
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
            Role::Odom => "odom",
            Role::CmdVel => "cmd_vel",
            Role::Labels => "labels",
            Role::GroundTruthPose => "ground_truth_pose",
            Role::GroundTruthObjects => "ground_truth_objects",
        }
    }

    pub fn message_type(self) -> &'static str {
        match self {
            Role::CompressedImage => CompressedImage::TYPE,
            Role::Image => Image::TYPE,
            Role::CameraInfo => CameraInfo::TYPE,
            Role::TfStatic => TfMessage::TYPE,
            Role::Odom => Odometry::TYPE,
            Role::CmdVel => TwistStamped::TYPE,
            Role::Labels => ObjectLabel::TYPE,
            Role::GroundTruthPose => PoseStamped::TYPE,
            Role::GroundTruthObjects => GroundTruth::TYPE,
        }
    }
}

impl Topics {
    pub fn get(&self, role: Role) -> &str {
        match role {
            Role::CompressedImage => &self.compressed_image,
            Role::Image => &self.image,
            Role::CameraInfo => &self.camera_info,
            Role::TfStatic => &self.tf_static,
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
            *self.get_mut(role) = topic.to_owned();
        }
        Ok(self)
    }
}

/// Where in a session something happened, for one-line errors.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct At {
    pub path: PathBuf,
    pub topic: Option<String>,
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

/// Why a session could not be read (or written).
#[derive(Debug, Error)]
pub enum SessionError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: not an MCAP file (starts with {head:02x?}, expected the MCAP magic 89 4d 43 41 50 30 0d 0a)", path.display())]
    NotMcap { path: PathBuf, head: Vec<u8> },
    #[error("{at}: {what}: {source}")]
    Mcap {
        at: At,
        what: String,
        #[source]
        source: mcap::McapError,
    },
    #[error("{at}: cannot decode {type_name}: {source}")]
    Decode {
        at: At,
        type_name: String,
        #[source]
        source: CdrError,
    },
    #[error("{at}: schema is {found:?} but this topic must carry {expected}")]
    WrongType {
        at: At,
        expected: &'static str,
        found: String,
    },
    #[error("{at}: message encoding {found:?} is not supported (objloc reads \"cdr\")")]
    Encoding { at: At, found: String },
    #[error("{at}: schema encoding {found:?} is not supported (objloc reads \"ros2msg\")")]
    SchemaEncoding { at: At, found: String },
    #[error("{at}: {what}")]
    Invalid { at: At, what: String },
    #[error("{path}: required topic {topic} ({type_name}) is missing")]
    MissingTopic {
        path: PathBuf,
        topic: String,
        type_name: &'static str,
    },
}

/// A camera frame as it was recorded: encoded or raw.
#[derive(Debug, Clone, PartialEq)]
pub enum FramePixels {
    /// PNG or JPEG bytes (`format` as in the CompressedImage).
    Encoded {
        format: String,
        data: Vec<u8>,
    },
    Raw(Image),
}

#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    pub stamp_ns: i64,
    pub frame_id: String,
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
    Size { width: u32, height: u32 },
    /// A CompressedImage format other than PNG and JPEG.
    #[error("compressed format {0:?} is not read (objloc reads png and jpeg)")]
    Format(String),
    /// A raw Image encoding objloc does not read.
    #[error("raw encoding {0:?} is not read (rgb8, bgr8, rgba8, bgra8, mono8 are)")]
    Encoding(String),
    /// A raw Image row step shorter than a row.
    #[error("step {step} is less than width {width} x {channels} bytes")]
    Step {
        step: usize,
        width: usize,
        channels: usize,
    },
    /// A raw Image with fewer bytes than its size needs.
    #[error("raw image of {width} x {height} ({encoding}) needs {needed} bytes, has {have}")]
    Length {
        width: usize,
        height: usize,
        encoding: String,
        needed: usize,
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
                let f = format.to_ascii_lowercase();
                let fmt = if f.contains("png") {
                    image::ImageFormat::Png
                } else if f.contains("jpeg") || f.contains("jpg") {
                    image::ImageFormat::Jpeg
                } else {
                    return Err(FrameError::Format(format.clone()));
                };
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
    if img.data.len() < step * (h - 1) + w * channels {
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
    Frame(Frame),
    CameraInfo(Box<CameraInfo>),
    TfStatic(TfMessage),
    Odom(Box<Odometry>),
    CmdVel(TwistStamped),
    Label(ObjectLabel),
    GroundTruthPose(PoseStamped),
    GroundTruthObjects(GroundTruth),
}

/// One message in replay order, with where it came from.
#[derive(Debug, Clone, PartialEq)]
pub struct TimedMsg {
    pub log_time_ns: u64,
    pub topic: String,
    pub msg: SessionMsg,
}
