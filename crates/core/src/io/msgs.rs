//! The ROS 2 message types of a session, their CDR encoding and their `ros2msg` schema text.
//!
//! Invariants: field order and types match the upstream ROS 2 definitions exactly (Humble and
//! later), so payloads interoperate with rosbag2, Foxglove and Rerun; schema text is the main
//! definition followed by every dependency once, each after a line of 80 `=` and
//! `MSG: pkg/Type` (no `/msg/`: that is how rosbag2 writes it, and Rerun resolves field types
//! such as `std_msgs/Header` only against names of that form).

use std::collections::BTreeSet;

use crate::io::cdr::{CdrError, CdrReader, CdrWriter};

/// `std_msgs/Header`, with the stamp held as nanoseconds since the epoch.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Header {
    /// `stamp` as ns since the epoch, `sec * 1e9 + nanosec`; negative before 1970.
    pub stamp_ns: i64,
    /// Coordinate frame the data is associated with, e.g. `odom` or `camera_optical_frame`.
    pub frame_id: String,
}

/// Splits nanoseconds into `builtin_interfaces/Time` (sec may be negative, nanosec in [0, 1e9)).
pub fn ns_to_time(ns: i64) -> (i32, u32) {
    let sec = ns.div_euclid(1_000_000_000);
    let nsec = ns.rem_euclid(1_000_000_000);
    (
        sec.clamp(i32::MIN as i64, i32::MAX as i64) as i32,
        nsec as u32,
    )
}

/// Joins `builtin_interfaces/Time` into ns since the epoch; the inverse of [`ns_to_time`].
pub fn time_to_ns(sec: i32, nanosec: u32) -> i64 {
    i64::from(sec) * 1_000_000_000 + i64::from(nanosec)
}

impl Header {
    /// A header stamped `stamp_ns` (ns since the epoch) in frame `frame_id`.
    pub fn new(stamp_ns: i64, frame_id: &str) -> Self {
        Self {
            stamp_ns,
            frame_id: frame_id.to_owned(),
        }
    }
    fn encode(&self, w: &mut CdrWriter) {
        let (sec, nsec) = ns_to_time(self.stamp_ns);
        w.i32(sec);
        w.u32(nsec);
        w.string(&self.frame_id);
    }
    fn decode(r: &mut CdrReader) -> Result<Self, CdrError> {
        let sec = r.i32("header.stamp.sec")?;
        let nanosec = r.u32("header.stamp.nanosec")?;
        if nanosec >= 1_000_000_000 {
            return Err(CdrError::OutOfRange {
                what: "header.stamp.nanosec",
                value: u64::from(nanosec),
                rule: "not below 1e9 as builtin_interfaces/Time requires",
            });
        }
        let frame_id = r.string("header.frame_id")?;
        Ok(Self {
            stamp_ns: time_to_ns(sec, nanosec),
            frame_id,
        })
    }
}

/// `geometry_msgs/Pose`: position in metres, orientation as a unit quaternion [x, y, z, w].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Position [x, y, z] of the pose's origin in the parent frame, metres.
    pub position: [f64; 3],
    /// Orientation in the parent frame, unit quaternion [x, y, z, w]; identity [0, 0, 0, 1].
    pub orientation_xyzw: [f64; 4],
}

impl Default for Pose {
    fn default() -> Self {
        Self {
            position: [0.0; 3],
            orientation_xyzw: [0.0, 0.0, 0.0, 1.0],
        }
    }
}

impl Pose {
    fn encode(&self, w: &mut CdrWriter) {
        w.f64_array(&self.position);
        w.f64_array(&self.orientation_xyzw);
    }
    fn decode(r: &mut CdrReader) -> Result<Self, CdrError> {
        Ok(Self {
            position: r.f64_array("pose.position")?,
            orientation_xyzw: r.f64_array("pose.orientation")?,
        })
    }
}

/// `geometry_msgs/Twist`: linear m/s, angular rad/s.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Twist {
    /// Linear velocity [x, y, z], m/s.
    pub linear: [f64; 3],
    /// Angular velocity about [x, y, z], rad/s.
    pub angular: [f64; 3],
}

impl Twist {
    fn encode(&self, w: &mut CdrWriter) {
        w.f64_array(&self.linear);
        w.f64_array(&self.angular);
    }
    fn decode(r: &mut CdrReader) -> Result<Self, CdrError> {
        Ok(Self {
            linear: r.f64_array("twist.linear")?,
            angular: r.f64_array("twist.angular")?,
        })
    }
}

/// `sensor_msgs/RegionOfInterest`: a pixel rectangle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RegionOfInterest {
    /// Leftmost pixel column of the region (0 if it includes the image's left edge).
    pub x_offset: u32,
    /// Topmost pixel row of the region (0 if it includes the image's top edge).
    pub y_offset: u32,
    /// Height of the region, pixels.
    pub height: u32,
    /// Width of the region, pixels.
    pub width: u32,
    /// Whether a rectified region should be computed from this raw one; objloc writes false.
    pub do_rectify: bool,
}

impl RegionOfInterest {
    fn encode(&self, w: &mut CdrWriter) {
        w.u32(self.x_offset);
        w.u32(self.y_offset);
        w.u32(self.height);
        w.u32(self.width);
        w.bool(self.do_rectify);
    }
    fn decode(r: &mut CdrReader) -> Result<Self, CdrError> {
        Ok(Self {
            x_offset: r.u32("roi.x_offset")?,
            y_offset: r.u32("roi.y_offset")?,
            height: r.u32("roi.height")?,
            width: r.u32("roi.width")?,
            do_rectify: r.bool("roi.do_rectify")?,
        })
    }
}

/// A ROS 2 message this crate reads and writes.
pub trait RosMessage: Sized {
    /// Full type name, `pkg/msg/Type`.
    const TYPE: &'static str;
    /// Appends the message's fields to `w`, in the order of the ROS 2 definition.
    fn encode_body(&self, w: &mut CdrWriter);
    /// Reads the message's fields from `r`; [`RosMessage::from_cdr`] checks what is left.
    fn decode_body(r: &mut CdrReader) -> Result<Self, CdrError>;

    /// The message as a `CDR_LE` payload, encapsulation header included.
    fn to_cdr(&self) -> Vec<u8> {
        let mut w = CdrWriter::new();
        self.encode_body(&mut w);
        w.finish()
    }
    /// Decodes a whole CDR payload; bytes left over beyond padding are a schema mismatch.
    fn from_cdr(payload: &[u8]) -> Result<Self, CdrError> {
        let mut r = CdrReader::new(payload)?;
        let v = Self::decode_body(&mut r)?;
        r.finish(Self::TYPE)?;
        Ok(v)
    }
    /// The `ros2msg` schema text with dependency blocks.
    fn schema_text() -> String {
        schema_text(Self::TYPE).unwrap_or_default()
    }
}

/// `sensor_msgs/CompressedImage`: one camera frame as an image file (PNG or JPEG).
#[derive(Debug, Clone, PartialEq)]
pub struct CompressedImage {
    /// Acquisition time of the image; `frame_id` is the camera's optical frame.
    pub header: Header,
    /// Compression format, e.g. `png` or `jpeg` (objloc reads those two).
    pub format: String,
    /// The compressed image file's bytes.
    pub data: Vec<u8>,
}

impl RosMessage for CompressedImage {
    const TYPE: &'static str = "sensor_msgs/msg/CompressedImage";
    fn encode_body(&self, w: &mut CdrWriter) {
        self.header.encode(w);
        w.string(&self.format);
        w.bytes(&self.data);
    }
    fn decode_body(r: &mut CdrReader) -> Result<Self, CdrError> {
        Ok(Self {
            header: Header::decode(r)?,
            format: r.string("format")?,
            data: r.bytes("data")?.to_vec(),
        })
    }
}

/// `sensor_msgs/Image`: an uncompressed image.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Acquisition time of the image; `frame_id` is the camera's optical frame.
    pub header: Header,
    /// Image height, pixels (number of rows).
    pub height: u32,
    /// Image width, pixels (number of columns).
    pub width: u32,
    /// Pixel encoding, e.g. `rgb8`, `bgr8` or `mono8` (names from `sensor_msgs/image_encodings`).
    pub encoding: String,
    /// Whether multi-byte channel values are big endian: 1 if so, 0 if not.
    pub is_bigendian: u8,
    /// Length of one row, bytes (at least width x bytes per pixel).
    pub step: u32,
    /// The pixels, row by row from the top: `step * height` bytes.
    pub data: Vec<u8>,
}

impl RosMessage for Image {
    const TYPE: &'static str = "sensor_msgs/msg/Image";
    fn encode_body(&self, w: &mut CdrWriter) {
        self.header.encode(w);
        w.u32(self.height);
        w.u32(self.width);
        w.string(&self.encoding);
        w.u8(self.is_bigendian);
        w.u32(self.step);
        w.bytes(&self.data);
    }
    fn decode_body(r: &mut CdrReader) -> Result<Self, CdrError> {
        Ok(Self {
            header: Header::decode(r)?,
            height: r.u32("height")?,
            width: r.u32("width")?,
            encoding: r.string("encoding")?,
            is_bigendian: r.u8("is_bigendian")?,
            step: r.u32("step")?,
            data: r.bytes("data")?.to_vec(),
        })
    }
}

/// `sensor_msgs/CameraInfo`: the calibration of the camera that took the frames.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraInfo {
    /// Acquisition time of the matching image; `frame_id` is the camera's optical frame.
    pub header: Header,
    /// Image height the camera was calibrated at, pixels.
    pub height: u32,
    /// Image width the camera was calibrated at, pixels.
    pub width: u32,
    /// Model of `d`, e.g. `plumb_bob` (k1, k2, t1, t2, k3) or `rational_polynomial`.
    pub distortion_model: String,
    /// Distortion parameters; their number and meaning depend on `distortion_model`.
    pub d: Vec<f64>,
    /// Row-major 3x3 intrinsics [fx 0 cx; 0 fy cy; 0 0 1].
    pub k: [f64; 9],
    /// Row-major 3x3 rectification rotation (stereo cameras); identity for a monocular one.
    pub r: [f64; 9],
    /// Row-major 3x4 projection [fx' 0 cx' Tx; 0 fy' cy' Ty; 0 0 1 0] of the rectified image.
    pub p: [f64; 12],
    /// Horizontal binning factor; 0 or 1 means no subsampling.
    pub binning_x: u32,
    /// Vertical binning factor; 0 or 1 means no subsampling.
    pub binning_y: u32,
    /// Part of the full-resolution image that was captured; all zeros means the whole image.
    pub roi: RegionOfInterest,
}

impl CameraInfo {
    /// A distortion-free pinhole camera.
    pub fn pinhole(
        header: Header,
        width: u32,
        height: u32,
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
    ) -> Self {
        Self {
            header,
            height,
            width,
            distortion_model: "plumb_bob".to_owned(),
            d: vec![0.0; 5],
            k: [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
            r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p: [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
            binning_x: 0,
            binning_y: 0,
            roi: RegionOfInterest::default(),
        }
    }
}

impl RosMessage for CameraInfo {
    const TYPE: &'static str = "sensor_msgs/msg/CameraInfo";
    fn encode_body(&self, w: &mut CdrWriter) {
        self.header.encode(w);
        w.u32(self.height);
        w.u32(self.width);
        w.string(&self.distortion_model);
        w.f64_seq(&self.d);
        w.f64_array(&self.k);
        w.f64_array(&self.r);
        w.f64_array(&self.p);
        w.u32(self.binning_x);
        w.u32(self.binning_y);
        self.roi.encode(w);
    }
    fn decode_body(r: &mut CdrReader) -> Result<Self, CdrError> {
        Ok(Self {
            header: Header::decode(r)?,
            height: r.u32("height")?,
            width: r.u32("width")?,
            distortion_model: r.string("distortion_model")?,
            d: r.f64_seq("d")?,
            k: r.f64_array("k")?,
            r: r.f64_array("r")?,
            p: r.f64_array("p")?,
            binning_x: r.u32("binning_x")?,
            binning_y: r.u32("binning_y")?,
            roi: RegionOfInterest::decode(r)?,
        })
    }
}

/// `geometry_msgs/TransformStamped`: `child_frame_id` expressed in `header.frame_id`.
#[derive(Debug, Clone, PartialEq)]
pub struct TransformStamped {
    /// Time of the transform; `frame_id` is the parent frame.
    pub header: Header,
    /// The frame the transform places in the parent frame.
    pub child_frame_id: String,
    /// Origin of the child frame in the parent frame [x, y, z], metres.
    pub translation: [f64; 3],
    /// Orientation of the child frame in the parent frame, unit quaternion [x, y, z, w].
    pub rotation_xyzw: [f64; 4],
}

/// `tf2_msgs/TFMessage`: a batch of transforms (on `/tf_static`, fixed ones such as the
/// camera mount).
#[derive(Debug, Clone, PartialEq)]
pub struct TfMessage {
    /// The transforms, each parent-to-child.
    pub transforms: Vec<TransformStamped>,
}

impl RosMessage for TfMessage {
    const TYPE: &'static str = "tf2_msgs/msg/TFMessage";
    fn encode_body(&self, w: &mut CdrWriter) {
        w.len(self.transforms.len());
        for t in &self.transforms {
            t.header.encode(w);
            w.string(&t.child_frame_id);
            w.f64_array(&t.translation);
            w.f64_array(&t.rotation_xyzw);
        }
    }
    fn decode_body(r: &mut CdrReader) -> Result<Self, CdrError> {
        // Smallest TransformStamped: header (4+4+4) + child (4) + 7 f64.
        let n = r.seq_len(16 + 56, "transforms")?;
        let mut transforms = Vec::with_capacity(n);
        for _ in 0..n {
            transforms.push(TransformStamped {
                header: Header::decode(r)?,
                child_frame_id: r.string("child_frame_id")?,
                translation: r.f64_array("transform.translation")?,
                rotation_xyzw: r.f64_array("transform.rotation")?,
            });
        }
        Ok(Self { transforms })
    }
}

/// `nav_msgs/Odometry`: an estimate of the robot's pose and velocity.
#[derive(Debug, Clone, PartialEq)]
pub struct Odometry {
    /// Time of the estimate; `frame_id` is the frame of the pose, e.g. `odom`.
    pub header: Header,
    /// The robot's frame, e.g. `base_link`; the twist is expressed in it.
    pub child_frame_id: String,
    /// Pose of `child_frame_id` in `header.frame_id`.
    pub pose: Pose,
    /// Row-major 6x6 covariance of the pose, over (x, y, z, rotation about x, y, z).
    pub pose_covariance: [f64; 36],
    /// Velocity of the robot, in `child_frame_id`.
    pub twist: Twist,
    /// Row-major 6x6 covariance of the twist, over (linear x, y, z, angular x, y, z).
    pub twist_covariance: [f64; 36],
}

impl RosMessage for Odometry {
    const TYPE: &'static str = "nav_msgs/msg/Odometry";
    fn encode_body(&self, w: &mut CdrWriter) {
        self.header.encode(w);
        w.string(&self.child_frame_id);
        self.pose.encode(w);
        w.f64_array(&self.pose_covariance);
        self.twist.encode(w);
        w.f64_array(&self.twist_covariance);
    }
    fn decode_body(r: &mut CdrReader) -> Result<Self, CdrError> {
        Ok(Self {
            header: Header::decode(r)?,
            child_frame_id: r.string("child_frame_id")?,
            pose: Pose::decode(r)?,
            pose_covariance: r.f64_array("pose.covariance")?,
            twist: Twist::decode(r)?,
            twist_covariance: r.f64_array("twist.covariance")?,
        })
    }
}

/// `geometry_msgs/TwistStamped`: a velocity at a time, as on `/cmd_vel`.
#[derive(Debug, Clone, PartialEq)]
pub struct TwistStamped {
    /// Time of the command; `frame_id` is the frame of the twist, e.g. `base_link`.
    pub header: Header,
    /// The velocity; objloc's commands use linear x (m/s) and angular z (rad/s) only.
    pub twist: Twist,
}

impl RosMessage for TwistStamped {
    const TYPE: &'static str = "geometry_msgs/msg/TwistStamped";
    fn encode_body(&self, w: &mut CdrWriter) {
        self.header.encode(w);
        self.twist.encode(w);
    }
    fn decode_body(r: &mut CdrReader) -> Result<Self, CdrError> {
        Ok(Self {
            header: Header::decode(r)?,
            twist: Twist::decode(r)?,
        })
    }
}

/// `geometry_msgs/PoseStamped`: a pose at a time, as on `/ground_truth/pose`.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseStamped {
    /// Time of the pose; `frame_id` is the frame it is expressed in, e.g. `odom`.
    pub header: Header,
    /// The pose, in `header.frame_id`.
    pub pose: Pose,
}

impl RosMessage for PoseStamped {
    const TYPE: &'static str = "geometry_msgs/msg/PoseStamped";
    fn encode_body(&self, w: &mut CdrWriter) {
        self.header.encode(w);
        self.pose.encode(w);
    }
    fn decode_body(r: &mut CdrReader) -> Result<Self, CdrError> {
        Ok(Self {
            header: Header::decode(r)?,
            pose: Pose::decode(r)?,
        })
    }
}

/// `objloc_msgs/ObjectLabel`: the rectangles drawn around the object in the frame with the
/// same stamp; no regions = a background-only frame.
#[derive(Debug, Clone, PartialEq)]
pub struct ObjectLabel {
    /// Stamp and frame id of the labelled frame (the same as in its image's header).
    pub header: Header,
    /// Name of the object labelled.
    pub object: String,
    /// Pixel rectangles around the object; empty if the frame does not show it.
    pub regions: Vec<RegionOfInterest>,
}

impl RosMessage for ObjectLabel {
    const TYPE: &'static str = "objloc_msgs/msg/ObjectLabel";
    fn encode_body(&self, w: &mut CdrWriter) {
        self.header.encode(w);
        w.string(&self.object);
        w.len(self.regions.len());
        for roi in &self.regions {
            roi.encode(w);
        }
    }
    fn decode_body(r: &mut CdrReader) -> Result<Self, CdrError> {
        let header = Header::decode(r)?;
        let object = r.string("object")?;
        let n = r.seq_len(17, "regions")?;
        let regions = (0..n)
            .map(|_| RegionOfInterest::decode(r))
            .collect::<Result<_, _>>()?;
        Ok(Self {
            header,
            object,
            regions,
        })
    }
}

/// `objloc_msgs/GroundTruth`: true boxes in `odom` (simulation only).
#[derive(Debug, Clone, PartialEq)]
pub struct GroundTruth {
    /// Time of the boxes; `frame_id` is the frame they are in, `odom`.
    pub header: Header,
    /// Object names; `box_center` and `box_size` hold one entry per name, in this order.
    pub object: Vec<String>,
    /// Pose of each box (its centre and axes) in `header.frame_id`, metres.
    pub box_center: Vec<Pose>,
    /// Full edge lengths in metres, along the box's own axes.
    pub box_size: Vec<[f64; 3]>,
}

impl GroundTruth {
    /// What makes the boxes unusable, if anything: arrays of different lengths, a centre or
    /// orientation that is not finite, an edge that is not a positive finite length.
    pub fn problem(&self) -> Option<String> {
        let (n, c, z) = (
            self.object.len(),
            self.box_center.len(),
            self.box_size.len(),
        );
        if n != c || n != z {
            return Some(format!(
                "{n} object names but {c} box centres and {z} box sizes: one of each per object"
            ));
        }
        let bad = (0..n).find(|&i| {
            let p = &self.box_center[i];
            let finite = p
                .position
                .iter()
                .chain(&p.orientation_xyzw)
                .all(|v| v.is_finite());
            !finite || !self.box_size[i].iter().all(|v| v.is_finite() && *v > 0.0)
        })?;
        Some(format!(
            "box {bad} ({:?}) has centre {:?} and size {:?}: the centre must be finite and every edge a positive length",
            self.object[bad], self.box_center[bad].position, self.box_size[bad]
        ))
    }
}

impl RosMessage for GroundTruth {
    const TYPE: &'static str = "objloc_msgs/msg/GroundTruth";
    fn encode_body(&self, w: &mut CdrWriter) {
        self.header.encode(w);
        w.len(self.object.len());
        for s in &self.object {
            w.string(s);
        }
        w.len(self.box_center.len());
        for p in &self.box_center {
            p.encode(w);
        }
        w.len(self.box_size.len());
        for s in &self.box_size {
            w.f64_array(s);
        }
    }
    fn decode_body(r: &mut CdrReader) -> Result<Self, CdrError> {
        let header = Header::decode(r)?;
        let n = r.seq_len(4, "object")?;
        let object = (0..n)
            .map(|_| r.string("object"))
            .collect::<Result<_, _>>()?;
        let n = r.seq_len(56, "box_center")?;
        let box_center = (0..n).map(|_| Pose::decode(r)).collect::<Result<_, _>>()?;
        let n = r.seq_len(24, "box_size")?;
        let box_size = (0..n)
            .map(|_| r.f64_array("box_size"))
            .collect::<Result<_, _>>()?;
        Ok(Self {
            header,
            object,
            box_center,
            box_size,
        })
    }
}

/// Message definitions (comments stripped) of every type above and their dependencies.
const DEFINITIONS: &[(&str, &str)] = &[
    ("builtin_interfaces/msg/Time", "int32 sec\nuint32 nanosec\n"),
    (
        "std_msgs/msg/Header",
        "builtin_interfaces/Time stamp\nstring frame_id\n",
    ),
    (
        "geometry_msgs/msg/Point",
        "float64 x\nfloat64 y\nfloat64 z\n",
    ),
    (
        "geometry_msgs/msg/Vector3",
        "float64 x\nfloat64 y\nfloat64 z\n",
    ),
    (
        "geometry_msgs/msg/Quaternion",
        "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    ),
    (
        "geometry_msgs/msg/Pose",
        "Point position\nQuaternion orientation\n",
    ),
    (
        "geometry_msgs/msg/PoseWithCovariance",
        "Pose pose\nfloat64[36] covariance\n",
    ),
    (
        "geometry_msgs/msg/PoseStamped",
        "std_msgs/Header header\nPose pose\n",
    ),
    (
        "geometry_msgs/msg/Twist",
        "Vector3 linear\nVector3 angular\n",
    ),
    (
        "geometry_msgs/msg/TwistWithCovariance",
        "Twist twist\nfloat64[36] covariance\n",
    ),
    (
        "geometry_msgs/msg/TwistStamped",
        "std_msgs/Header header\nTwist twist\n",
    ),
    (
        "geometry_msgs/msg/Transform",
        "Vector3 translation\nQuaternion rotation\n",
    ),
    (
        "geometry_msgs/msg/TransformStamped",
        "std_msgs/Header header\nstring child_frame_id\nTransform transform\n",
    ),
    (
        "tf2_msgs/msg/TFMessage",
        "geometry_msgs/TransformStamped[] transforms\n",
    ),
    (
        "nav_msgs/msg/Odometry",
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist\n",
    ),
    (
        "sensor_msgs/msg/RegionOfInterest",
        "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n",
    ),
    (
        "sensor_msgs/msg/CompressedImage",
        "std_msgs/Header header\nstring format\nuint8[] data\n",
    ),
    (
        "sensor_msgs/msg/Image",
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data\n",
    ),
    (
        "sensor_msgs/msg/CameraInfo",
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\nfloat64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\nuint32 binning_y\nRegionOfInterest roi\n",
    ),
    (
        "objloc_msgs/msg/ObjectLabel",
        "std_msgs/Header header\nstring object\nsensor_msgs/RegionOfInterest[] regions\n",
    ),
    (
        "objloc_msgs/msg/GroundTruth",
        "std_msgs/Header header\nstring[] object\ngeometry_msgs/Pose[] box_center\ngeometry_msgs/Vector3[] box_size\n",
    ),
];

const PRIMITIVES: &[&str] = &[
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32",
    "uint32", "int64", "uint64", "string", "wstring",
];

fn definition(full_type: &str) -> Option<&'static str> {
    DEFINITIONS
        .iter()
        .find(|(name, _)| *name == full_type)
        .map(|(_, def)| *def)
}

/// The complex field types of a definition as full `pkg/msg/Type` names, in field order.
fn field_types(package: &str, def: &str) -> Vec<String> {
    def.lines()
        .filter_map(|line| line.split_whitespace().next())
        .map(|t| t.split('[').next().unwrap_or(t))
        .filter(|t| !PRIMITIVES.contains(t) && !t.contains('<'))
        .map(|t| match t.split_once('/') {
            Some((pkg, name)) => format!("{pkg}/msg/{}", name.trim_start_matches("msg/")),
            None => format!("{package}/msg/{t}"),
        })
        .collect()
}

/// Full `ros2msg` schema text for `full_type` (`pkg/msg/Type`): its definition, then each
/// dependency once in depth-first order of first use.
pub fn schema_text(full_type: &str) -> Option<String> {
    let mut out = definition(full_type)?.to_owned();
    let mut seen = BTreeSet::new();
    let mut stack: Vec<String> = vec![full_type.to_owned()];
    let mut order = Vec::new();
    while let Some(t) = stack.pop() {
        let package = t.split('/').next().unwrap_or_default().to_owned();
        let def = definition(&t)?;
        let deps = field_types(&package, def);
        for d in deps.into_iter().rev() {
            if seen.insert(d.clone()) {
                order.push(d.clone());
                stack.push(d);
            }
        }
    }
    // `order` holds each dependency once; emit in the order found (stable, deterministic).
    for dep in order {
        out.push_str(&"=".repeat(80));
        out.push('\n');
        out.push_str(&format!("MSG: {}\n", dep.replacen("/msg/", "/", 1)));
        out.push_str(definition(&dep)?);
    }
    Some(out)
}

impl crate::types::geometry::Camera {
    /// From CameraInfo K; `None` unless width, height and focal lengths are positive and finite.
    pub fn from_info(info: &CameraInfo) -> Option<Self> {
        Self::from_k(info.width, info.height, info.k)
    }
}

/// The largest size of a distortion coefficient taken for a lens's: OpenCV calibrations of
/// wide-angle lenses give a few units; 1e6 is a garbage field, and rectifying with it maps
/// every pixel off the image.
pub const MAX_DISTORTION_COEFFICIENT: f64 = 100.0;

/// Whether distortion coefficients can be a lens's: finite, none beyond
/// [`MAX_DISTORTION_COEFFICIENT`] in size (the rule of CameraInfo `d` and of imports).
pub fn lens_coefficients_plausible(d: &[f64]) -> bool {
    d.iter()
        .all(|v| v.is_finite() && v.abs() <= MAX_DISTORTION_COEFFICIENT)
}

/// Why a CameraInfo's distortion cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DistortionError {
    /// A coefficient is NaN or infinite.
    #[error("CameraInfo d {d:?} is not finite")]
    NotFinite {
        /// The coefficients as given.
        d: Vec<f64>,
    },
    /// A coefficient beyond any lens's (a wide-angle lens's are a few units at most).
    #[error(
        "CameraInfo d {d:?} holds a coefficient beyond {MAX_DISTORTION_COEFFICIENT} in size: not a lens's"
    )]
    Implausible {
        /// The coefficients as given.
        d: Vec<f64>,
    },
    /// A model objloc does not represent.
    #[error(
        "CameraInfo distortion model {model:?} with d {d:?} cannot be represented (objloc \
         handles plumb_bob, the OpenCV radial-tangential model)"
    )]
    Unsupported {
        /// `distortion_model` as given.
        model: String,
        /// The coefficients as given.
        d: Vec<f64>,
    },
}

impl crate::types::lens::Distortion {
    /// The distortion a CameraInfo declares, or why objloc cannot represent it: `plumb_bob`
    /// and `rational_polynomial` (with its k4..k6 zero) are radial-tangential; any model with
    /// all coefficients zero is none.
    pub fn from_info(ci: &CameraInfo) -> Result<Self, DistortionError> {
        if ci.d.iter().all(|v| *v == 0.0) {
            return Ok(Self::default());
        }
        if !ci.d.iter().all(|v| v.is_finite()) {
            return Err(DistortionError::NotFinite { d: ci.d.clone() });
        }
        if !lens_coefficients_plausible(&ci.d) {
            return Err(DistortionError::Implausible { d: ci.d.clone() });
        }
        let model = ci.distortion_model.as_str();
        let radial_tangential = model == "plumb_bob"
            || (model == "rational_polynomial" && ci.d.iter().skip(5).all(|v| *v == 0.0));
        if !radial_tangential || ci.d.len() > 8 {
            return Err(DistortionError::Unsupported {
                model: model.to_owned(),
                d: ci.d.clone(),
            });
        }
        Ok(Self::from_plumb_bob(&ci.d))
    }
}

/// Pose from a ROS `Pose`; `None` if a value is not finite or the quaternion is degenerate.
pub fn iso_from_pose(p: &Pose) -> Option<crate::types::geometry::Iso3> {
    crate::types::geometry::iso_from_parts(p.position, p.orientation_xyzw)
}

/// The ROS `Pose` of a transform.
pub fn pose_from_iso(iso: &crate::types::geometry::Iso3) -> Pose {
    let q = iso.rotation.quaternion();
    Pose {
        position: [iso.translation.x, iso.translation.y, iso.translation.z],
        orientation_xyzw: [q.i, q.j, q.k, q.w],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_and_iso_round_trip() {
        let p = crate::types::geometry::iso_from_xy_yaw(1.0, 2.0, 2.5);
        let back = iso_from_pose(&pose_from_iso(&p)).unwrap();
        assert!((back.translation.vector - p.translation.vector).norm() < 1e-12);
        assert!((back.rotation.angle_to(&p.rotation)).abs() < 1e-12);
    }

    #[test]
    fn odometry_schema_lists_every_dependency_once() {
        let s = schema_text(Odometry::TYPE).unwrap();
        for dep in [
            "std_msgs/Header",
            "builtin_interfaces/Time",
            "geometry_msgs/PoseWithCovariance",
            "geometry_msgs/Pose",
            "geometry_msgs/Point",
            "geometry_msgs/Quaternion",
            "geometry_msgs/TwistWithCovariance",
            "geometry_msgs/Twist",
            "geometry_msgs/Vector3",
        ] {
            assert_eq!(
                s.matches(&format!("MSG: {dep}\n")).count(),
                1,
                "{dep} in\n{s}"
            );
        }
        assert_eq!(s.matches(&"=".repeat(80)).count(), 9);
    }

    #[test]
    fn every_schema_resolves() {
        for (name, _) in DEFINITIONS {
            assert!(schema_text(name).is_some(), "{name}");
        }
    }

    #[test]
    fn odometry_roundtrip_and_layout() {
        let m = Odometry {
            header: Header::new(1_500_000_000, "odom"),
            child_frame_id: "base_link".into(),
            pose: Pose {
                position: [1.0, 2.0, 3.0],
                orientation_xyzw: [0.0, 0.0, 0.0, 1.0],
            },
            pose_covariance: [0.0; 36],
            twist: Twist::default(),
            twist_covariance: [0.0; 36],
        };
        let b = m.to_cdr();
        // sec=1, nanosec=5e8
        assert_eq!(&b[4..8], &1i32.to_le_bytes());
        assert_eq!(&b[8..12], &500_000_000u32.to_le_bytes());
        assert_eq!(Odometry::from_cdr(&b).unwrap(), m);
        // header (4+4+4+5 "odom\0") = 17 -> pad to 20, child (4+10) = 34, pad to 40 for f64.
        // 7 + 36 + 6 + 36 doubles = 85 doubles.
        assert_eq!(b.len(), 4 + 40 + 85 * 8);
    }

    /// ROS requires a stamp's nanosec below 1e9; 1999999999 read as is moved the frame 2 s
    /// later without a word.
    #[test]
    fn a_nanosec_of_a_second_or_more_is_refused() {
        let m = PoseStamped {
            header: Header::new(1_500_000_000, "odom"),
            pose: Pose::default(),
        };
        let mut b = m.to_cdr();
        b[8..12].copy_from_slice(&999_999_999u32.to_le_bytes());
        assert_eq!(
            PoseStamped::from_cdr(&b).unwrap().header.stamp_ns,
            1_999_999_999
        );
        b[8..12].copy_from_slice(&1_999_999_999u32.to_le_bytes());
        assert_eq!(
            PoseStamped::from_cdr(&b).unwrap_err().to_string(),
            "header.stamp.nanosec is 1999999999, not below 1e9 as builtin_interfaces/Time requires"
        );
    }

    #[test]
    fn trailing_bytes_are_a_schema_mismatch() {
        let m = PoseStamped {
            header: Header::new(0, "odom"),
            pose: Pose::default(),
        };
        let mut b = m.to_cdr();
        b.extend_from_slice(&[0; 16]);
        assert!(matches!(
            PoseStamped::from_cdr(&b),
            Err(CdrError::Trailing { .. })
        ));
    }

    #[test]
    fn negative_stamps_split_euclidean() {
        assert_eq!(ns_to_time(-1), (-1, 999_999_999));
        assert_eq!(time_to_ns(-1, 999_999_999), -1);
    }
}
