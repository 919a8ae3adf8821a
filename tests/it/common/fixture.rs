//! Shared test fixture: a small, complete session written through
//! `objloc_core::io::session::SessionWriter` with known values, so tests can compare what any
//! reader (ours or a third party's) decodes.
//!
//! Invariants: every value is a constant or computed from constants here (no clock, no
//! randomness), so two calls write byte-identical files; `Fixture` returns exactly the messages
//! written, with the log time of each equal to its header stamp.

use std::collections::BTreeMap;
use std::path::Path;

use objloc_core::io::msgs::{
    CameraInfo, CompressedImage, GroundTruth, Header, ObjectLabel, Odometry, Pose, PoseStamped,
    RegionOfInterest, TfMessage, TransformStamped, Twist, TwistStamped,
};
use objloc_core::io::session::SessionWriter;

/// First frame stamp: a realistic epoch time with a non-zero nanosecond part, so a reader that
/// mixes up `sec` and `nanosec` shows it.
pub const T0_NS: i64 = 1_700_000_000_123_456_789;
/// Frame period.
pub const FRAME_PERIOD_NS: i64 = 100_000_000;
pub const FRAMES: usize = 3;
pub const WIDTH_PX: u32 = 64;
pub const HEIGHT_PX: u32 = 48;
pub const FX_PX: f64 = 50.0;
pub const FY_PX: f64 = 52.5;
pub const CX_PX: f64 = 32.0;
pub const CY_PX: f64 = 24.0;
/// The coloured rectangle of every frame: x, y, width, height in pixels.
pub const RECT_PX: (u32, u32, u32, u32) = (20, 12, 16, 18);
pub const RECT_RGB: [u8; 3] = [220, 30, 40];
pub const BACKGROUND_RGB: [u8; 3] = [90, 120, 90];
pub const OBJECT: &str = "chair";
pub const CAMERA_FRAME: &str = "camera_optical_frame";
/// `base_link -> camera_optical_frame` rotation for a level camera looking along base +x:
/// the rotation with columns (0,-1,0), (0,0,-1), (1,0,0), i.e. quaternion (-1/2, 1/2, -1/2, 1/2).
pub const MOUNT_ROTATION_XYZW: [f64; 4] = [-0.5, 0.5, -0.5, 0.5];
pub const MOUNT_TRANSLATION_M: [f64; 3] = [0.125, 0.0, 1.25];
pub const CMD_LINEAR_X_MPS: f64 = 0.5;
pub const CMD_ANGULAR_Z_RADPS: f64 = 0.25;

/// Everything the fixture wrote, message by message.
#[derive(Debug, Clone)]
#[allow(
    dead_code,
    reason = "the whole record of what was written; each test reads the parts it checks"
)]
pub struct Fixture {
    /// Header stamp (= log time) of frame k, for each k.
    pub frame_stamps_ns: Vec<i64>,
    /// PNG bytes of frame k.
    pub pngs: Vec<Vec<u8>>,
    pub tf_static: TfMessage,
    pub tf_static_stamp_ns: i64,
    pub camera_info: Vec<CameraInfo>,
    pub odom: Vec<Odometry>,
    pub cmd_vel: TwistStamped,
    /// Frame 0 labelled with `RECT_PX`, frame 1 background; frame 2 unlabelled.
    pub labels: Vec<ObjectLabel>,
    pub ground_truth_pose: Vec<PoseStamped>,
    pub ground_truth: GroundTruth,
    /// Topic -> (message type, count) of every topic written.
    pub topics: BTreeMap<String, (String, usize)>,
}

impl Fixture {
    pub fn message_count(&self) -> usize {
        self.topics.values().map(|(_, n)| n).sum()
    }
}

/// A `WIDTH_PX` x `HEIGHT_PX` RGB PNG: `BACKGROUND_RGB` with a `RECT_RGB` rectangle at `RECT_PX`
/// shifted right by `shift_px`.
pub fn fixture_png(shift_px: u32) -> Vec<u8> {
    let (rx, ry, rw, rh) = RECT_PX;
    let img = image::RgbImage::from_fn(WIDTH_PX, HEIGHT_PX, |x, y| {
        let inside = x >= rx + shift_px && x < rx + shift_px + rw && y >= ry && y < ry + rh;
        image::Rgb(if inside { RECT_RGB } else { BACKGROUND_RGB })
    });
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)
        .expect("PNG encoding to memory cannot fail");
    out.into_inner()
}

fn yaw_quaternion_xyzw(yaw_rad: f64) -> [f64; 4] {
    [0.0, 0.0, (yaw_rad / 2.0).sin(), (yaw_rad / 2.0).cos()]
}

/// The base_link pose of frame k in odom: 0.25 m forward per frame, 0.125 m left, 0.1 rad of yaw.
pub fn odom_pose(k: usize) -> Pose {
    Pose {
        position: [0.25 * k as f64, 0.125 * k as f64, 0.0],
        orientation_xyzw: yaw_quaternion_xyzw(0.1 * k as f64),
    }
}

/// Header stamp (= log time) of frame k: `T0_NS` plus k frame periods.
pub fn frame_stamp_ns(k: usize) -> i64 {
    T0_NS + k as i64 * FRAME_PERIOD_NS
}

/// The fixture camera's intrinsics, stamped at frame k.
pub fn camera_info(k: usize) -> CameraInfo {
    CameraInfo::pinhole(
        Header::new(frame_stamp_ns(k), CAMERA_FRAME),
        WIDTH_PX,
        HEIGHT_PX,
        FX_PX,
        FY_PX,
        CX_PX,
        CY_PX,
    )
}

/// The `/tf_static` mount `base_link -> camera_optical_frame` at `T0_NS`: the fixture's
/// rotation and the given translation.
pub fn mount(translation_m: [f64; 3]) -> TfMessage {
    TfMessage {
        transforms: vec![TransformStamped {
            header: Header::new(T0_NS, "base_link"),
            child_frame_id: CAMERA_FRAME.to_owned(),
            translation: translation_m,
            rotation_xyzw: MOUNT_ROTATION_XYZW,
        }],
    }
}

/// A `/cmd_vel` command at `T0_NS`: forward speed and yaw rate.
pub fn cmd_vel(v_mps: f64, w_radps: f64) -> TwistStamped {
    TwistStamped {
        header: Header::new(T0_NS, "base_link"),
        twist: Twist {
            linear: [v_mps, 0.0, 0.0],
            angular: [0.0, 0.0, w_radps],
        },
    }
}

/// Frame k's label of `OBJECT`: the rectangle `RECT_PX` on frame 0, none (a background frame)
/// on any other.
pub fn label(k: usize) -> ObjectLabel {
    let (rx, ry, rw, rh) = RECT_PX;
    let regions = if k == 0 {
        vec![RegionOfInterest {
            x_offset: rx,
            y_offset: ry,
            height: rh,
            width: rw,
            do_rectify: false,
        }]
    } else {
        Vec::new()
    };
    ObjectLabel {
        header: Header::new(frame_stamp_ns(k), CAMERA_FRAME),
        object: OBJECT.to_owned(),
        regions,
    }
}

/// Writes the fixture session to `path` (through `path.partial`, renamed by `finish`).
pub fn write_fixture_session(path: &Path) -> Fixture {
    let frame_stamps_ns: Vec<i64> = (0..FRAMES).map(frame_stamp_ns).collect();
    let pngs: Vec<Vec<u8>> = (0..FRAMES).map(|k| fixture_png(4 * k as u32)).collect();
    let tf_static_stamp_ns = T0_NS;
    let tf_static = mount(MOUNT_TRANSLATION_M);
    let camera_info: Vec<CameraInfo> = (0..FRAMES).map(camera_info).collect();
    let mut pose_covariance = [0.0; 36];
    pose_covariance[0] = 0.01;
    pose_covariance[35] = 0.02;
    let odom: Vec<Odometry> = frame_stamps_ns
        .iter()
        .enumerate()
        .map(|(k, &s)| Odometry {
            header: Header::new(s, "odom"),
            child_frame_id: "base_link".to_owned(),
            pose: odom_pose(k),
            pose_covariance,
            twist: Twist {
                linear: [CMD_LINEAR_X_MPS, 0.0, 0.0],
                angular: [0.0, 0.0, CMD_ANGULAR_Z_RADPS],
            },
            twist_covariance: [0.0; 36],
        })
        .collect();
    let cmd_vel = cmd_vel(CMD_LINEAR_X_MPS, CMD_ANGULAR_Z_RADPS);
    let labels: Vec<ObjectLabel> = (0..2).map(label).collect();
    // Ground truth differs from odometry by a known drift of 1/64 m per frame in y.
    let ground_truth_pose: Vec<PoseStamped> = frame_stamps_ns
        .iter()
        .enumerate()
        .map(|(k, &s)| {
            let mut pose = odom_pose(k);
            pose.position[1] += k as f64 / 64.0;
            PoseStamped {
                header: Header::new(s, "odom"),
                pose,
            }
        })
        .collect();
    let ground_truth = GroundTruth {
        header: Header::new(T0_NS, "odom"),
        object: vec![OBJECT.to_owned(), "table".to_owned()],
        box_center: vec![
            Pose {
                position: [3.0, 0.5, 0.45],
                orientation_xyzw: [0.0, 0.0, 0.0, 1.0],
            },
            Pose {
                position: [2.5, -1.5, 0.375],
                orientation_xyzw: yaw_quaternion_xyzw(0.5),
            },
        ],
        box_size: vec![[0.5, 0.5, 0.9], [1.5, 0.75, 0.75]],
    };

    let fail =
        |e: objloc_core::io::session::SessionError| -> ! { panic!("fixture write failed: {e}") };
    let mut w = SessionWriter::create(path).unwrap_or_else(|e| fail(e));
    // Written in stamp order, as a recorder would.
    w.write("/tf_static", tf_static_stamp_ns, &tf_static)
        .unwrap_or_else(|e| fail(e));
    w.write("/cmd_vel", T0_NS, &cmd_vel)
        .unwrap_or_else(|e| fail(e));
    w.write("/ground_truth/objects", T0_NS, &ground_truth)
        .unwrap_or_else(|e| fail(e));
    for k in 0..FRAMES {
        let s = frame_stamps_ns[k];
        w.write("/odom", s, &odom[k]).unwrap_or_else(|e| fail(e));
        w.write("/ground_truth/pose", s, &ground_truth_pose[k])
            .unwrap_or_else(|e| fail(e));
        w.write("/camera/camera_info", s, &camera_info[k])
            .unwrap_or_else(|e| fail(e));
        let img = CompressedImage {
            header: Header::new(s, CAMERA_FRAME),
            format: "png".to_owned(),
            data: pngs[k].clone(),
        };
        w.write("/camera/image/compressed", s, &img)
            .unwrap_or_else(|e| fail(e));
        if let Some(l) = labels.get(k) {
            w.write("/labels", s, l).unwrap_or_else(|e| fail(e));
        }
    }
    w.finish().unwrap_or_else(|e| fail(e));

    let n = FRAMES;
    let topics: BTreeMap<String, (String, usize)> = [
        ("/tf_static", "tf2_msgs/msg/TFMessage", 1),
        ("/cmd_vel", "geometry_msgs/msg/TwistStamped", 1),
        ("/ground_truth/objects", "objloc_msgs/msg/GroundTruth", 1),
        ("/odom", "nav_msgs/msg/Odometry", n),
        ("/ground_truth/pose", "geometry_msgs/msg/PoseStamped", n),
        ("/camera/camera_info", "sensor_msgs/msg/CameraInfo", n),
        (
            "/camera/image/compressed",
            "sensor_msgs/msg/CompressedImage",
            n,
        ),
        ("/labels", "objloc_msgs/msg/ObjectLabel", labels.len()),
    ]
    .into_iter()
    .map(|(t, ty, c)| (t.to_owned(), (ty.to_owned(), c)))
    .collect();

    Fixture {
        frame_stamps_ns,
        pngs,
        tf_static,
        tf_static_stamp_ns,
        camera_info,
        odom,
        cmd_vel,
        labels,
        ground_truth_pose,
        ground_truth,
        topics,
    }
}
