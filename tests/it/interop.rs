//! Interop with tools we did not write: sessions written by objloc must read in the Python
//! `mcap` and `mcap-ros2-support` readers and convert with Rerun's `rerun mcap convert`;
//! sessions written by the Python `rosbags` package and the real rosbag2 bags in shared/ must
//! read in objloc.
//!
//! Invariants: the Python tools run from a venv that these tests create themselves
//! (target/pyenv, or `$OBJLOC_PYENV`) from tests/py/requirements.txt, exactly once per
//! requirements hash: a stamp file holds the hash, a file lock keeps two test processes from
//! installing at once, and a `OnceLock` does the same for the threads of one. Expected values
//! come from `common::fixture` (what objloc wrote) or are written out here by hand, never
//! from the code under test.

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::Command;

use objloc_core::io::msgs::{GroundTruth, ObjectLabel, RosMessage, schema_text};
use objloc_core::io::session::{SessionMsg, SessionReader, Topics};
use serde_json::{Value, json};

use crate::common::fixture::{
    CAMERA_FRAME, CMD_ANGULAR_Z_RADPS, CMD_LINEAR_X_MPS, FRAMES, HEIGHT_PX, MOUNT_ROTATION_XYZW,
    MOUNT_TRANSLATION_M, OBJECT, RECT_PX, T0_NS, WIDTH_PX, write_fixture_session,
};
use crate::common::pyenv::{
    REQUIREMENTS, STAMP_FILE, ensure_pyenv, py_json, rerun_cli, run_checked, sha256_hex,
};
use crate::common::{objloc, ok, repo_dir};

/// `objloc inspect --json PATH`, which must succeed.
fn inspect_json(path: &Path) -> Value {
    let text = ok(&objloc(
        &[
            OsStr::new("inspect"),
            OsStr::new("--json"),
            path.as_os_str(),
        ],
        &[],
    ));
    serde_json::from_str(&text).expect("inspect --json prints JSON")
}

fn at<'a>(v: &'a Value, pointer: &str) -> &'a Value {
    v.pointer(pointer)
        .unwrap_or_else(|| panic!("no {pointer} in {v}"))
}

/// JSON equality where numbers may differ by one unit in the last place: serde_json (without
/// its `float_roundtrip` feature, which this crate does not enable) parses some shortest-repr
/// floats to the neighbouring f64, e.g. "0.9987502603949663" to 0.9987502603949664.
fn json_same(a: &Value, b: &Value) -> bool {
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => match (x.as_f64(), y.as_f64()) {
            (Some(x), Some(y)) if x.is_finite() && y.is_finite() => {
                x == y || (x.signum() == y.signum() && x.to_bits().abs_diff(y.to_bits()) <= 1)
            }
            _ => x == y,
        },
        (Value::Array(x), Value::Array(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(x, y)| json_same(x, y))
        }
        (Value::Object(x), Value::Object(y)) => {
            x.len() == y.len()
                && x.iter()
                    .all(|(k, v)| y.get(k).is_some_and(|w| json_same(v, w)))
        }
        _ => a == b,
    }
}

macro_rules! assert_json {
    ($got:expr, $want:expr $(, $($msg:tt)+)?) => {{
        let (got, want): (&Value, &Value) = (&$got, &$want);
        assert!(json_same(got, want), "got {got}\nwant {want} {}", format_args!("" $(, $($msg)+)?));
    }};
}

/// Field lines of a .msg text: comments and blank lines dropped, whitespace collapsed.
fn field_lines(msg: &str) -> Vec<String> {
    msg.lines()
        .map(|l| l.split('#').next().unwrap_or_default())
        .map(|l| l.split_whitespace().collect::<Vec<_>>().join(" "))
        .filter(|l| !l.is_empty())
        .collect()
}

#[test]
fn schema_files_match_the_definitions_objloc_writes() {
    let cases: [(&str, &str, &[&str]); 2] = [
        (
            "ObjectLabel.msg",
            ObjectLabel::TYPE,
            &[
                "std_msgs/Header header",
                "string object",
                "sensor_msgs/RegionOfInterest[] regions",
            ],
        ),
        (
            "GroundTruth.msg",
            GroundTruth::TYPE,
            &[
                "std_msgs/Header header",
                "string[] object",
                "geometry_msgs/Pose[] box_center",
                "geometry_msgs/Vector3[] box_size",
            ],
        ),
    ];
    for (file, type_name, fields) in cases {
        let path = repo_dir().join("schemas/objloc_msgs/msg").join(file);
        let text = std::fs::read_to_string(&path).expect("schema file exists");
        assert_eq!(field_lines(&text), fields, "{}", path.display());
        // The schema objloc writes into MCAP: its own definition is the part before the first
        // dependency separator.
        let written = schema_text(type_name).expect("objloc defines the type");
        let own = written.split(&"=".repeat(80)).next().unwrap_or_default();
        assert_eq!(field_lines(own), fields, "{type_name} as objloc writes it");
    }
}

#[test]
fn python_mcap_decodes_every_message_objloc_writes() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fixture.mcap");
    let fx = write_fixture_session(&path);
    let d = py_json("decode_session.py", &[&path]);

    let library = format!("objloc {}", env!("CARGO_PKG_VERSION"));
    assert_eq!(d["header"], json!({"profile": "ros2", "library": library}));
    let schemas = d["schemas"].as_array().unwrap();
    let channels = d["channels"].as_array().unwrap();
    assert_eq!(schemas.len(), 8);
    assert_eq!(channels.len(), 8);
    for c in channels {
        assert_eq!(c["message_encoding"], "cdr", "{c}");
        let schema = schemas
            .iter()
            .find(|s| s["id"] == c["schema_id"])
            .expect("channel schema is listed");
        assert_eq!(schema["encoding"], "ros2msg");
        let topic = c["topic"].as_str().unwrap();
        assert_eq!(
            schema["name"],
            fx.topics[topic].0.as_str(),
            "type of {topic}"
        );
    }
    assert_eq!(d["statistics"]["message_count"], 17);
    assert_eq!(fx.message_count(), 17);

    let msgs = d["messages"].as_array().unwrap();
    assert_eq!(msgs.len(), 17);
    let on = |topic: &str| -> Vec<&Value> { msgs.iter().filter(|m| m["topic"] == topic).collect() };
    for (topic, (_, count)) in &fx.topics {
        let ms = on(topic);
        assert_eq!(ms.len(), *count, "{topic}");
        for (i, m) in ms.iter().enumerate() {
            assert_eq!(m["sequence"], i, "{topic}");
            assert_eq!(m["log_time"], m["publish_time"], "{topic}");
            // log time = header stamp, split as sec + nanosec.
            let header = if topic == "/tf_static" {
                at(m, "/msg/transforms/0/header")
            } else {
                at(m, "/msg/header")
            };
            let log_time = m["log_time"].as_i64().unwrap();
            assert_eq!(header["stamp"]["sec"], log_time / 1_000_000_000, "{topic}");
            assert_eq!(
                header["stamp"]["nanosec"],
                log_time % 1_000_000_000,
                "{topic}"
            );
        }
    }

    // Frames: 100 ms apart from 1700000000.123456789 s.
    let images = on("/camera/image/compressed");
    for (k, m) in images.iter().enumerate() {
        assert_eq!(
            m["log_time"],
            1_700_000_000_123_456_789i64 + 100_000_000 * k as i64
        );
        assert_eq!(at(m, "/msg/header/stamp/sec"), 1_700_000_000);
        assert_eq!(
            at(m, "/msg/header/stamp/nanosec"),
            123_456_789 + 100_000_000 * k as i64
        );
        assert_eq!(at(m, "/msg/header/frame_id"), CAMERA_FRAME);
        assert_eq!(at(m, "/msg/format"), "png");
        assert_eq!(at(m, "/msg/data/len"), fx.pngs[k].len());
        assert_eq!(at(m, "/msg/data/sha256"), sha256_hex(&fx.pngs[k]).as_str());
    }
    assert_eq!(T0_NS, 1_700_000_000_123_456_789);

    for m in on("/camera/camera_info") {
        assert_eq!(at(m, "/msg/width"), WIDTH_PX);
        assert_eq!(at(m, "/msg/height"), HEIGHT_PX);
        assert_eq!(at(m, "/msg/header/frame_id"), CAMERA_FRAME);
        assert_eq!(at(m, "/msg/distortion_model"), "plumb_bob");
        assert_json!(at(m, "/msg/d"), &json!([0.0, 0.0, 0.0, 0.0, 0.0]));
        assert_json!(
            at(m, "/msg/k"),
            &json!([50.0, 0.0, 32.0, 0.0, 52.5, 24.0, 0.0, 0.0, 1.0])
        );
        assert_json!(
            at(m, "/msg/p"),
            &json!([
                50.0, 0.0, 32.0, 0.0, 0.0, 52.5, 24.0, 0.0, 0.0, 0.0, 1.0, 0.0
            ])
        );
    }

    let tf = on("/tf_static")[0];
    assert_eq!(at(tf, "/msg/transforms").as_array().unwrap().len(), 1);
    assert_eq!(at(tf, "/msg/transforms/0/header/frame_id"), "base_link");
    assert_eq!(at(tf, "/msg/transforms/0/child_frame_id"), CAMERA_FRAME);
    assert_json!(
        at(tf, "/msg/transforms/0/transform/translation"),
        &json!({"x": 0.125, "y": 0.0, "z": 1.25})
    );
    assert_json!(
        at(tf, "/msg/transforms/0/transform/rotation"),
        &json!({"x": -0.5, "y": 0.5, "z": -0.5, "w": 0.5})
    );
    assert_eq!(
        (MOUNT_TRANSLATION_M, MOUNT_ROTATION_XYZW),
        ([0.125, 0.0, 1.25], [-0.5, 0.5, -0.5, 0.5])
    );

    let odom = on("/odom");
    for (k, m) in odom.iter().enumerate() {
        let kf = k as f64;
        assert_eq!(at(m, "/msg/header/frame_id"), "odom");
        assert_eq!(at(m, "/msg/child_frame_id"), "base_link");
        assert_json!(
            at(m, "/msg/pose/pose/position"),
            &json!({"x": 0.25 * kf, "y": 0.125 * kf, "z": 0.0})
        );
        // 0.1 rad of yaw per frame, halved as the fixture computes it (not 0.05 * k: it rounds differently).
        let half_yaw = 0.1 * kf / 2.0;
        assert_json!(
            at(m, "/msg/pose/pose/orientation"),
            &json!({"x": 0.0, "y": 0.0, "z": half_yaw.sin(), "w": half_yaw.cos()})
        );
        assert_eq!(at(m, "/msg/pose/covariance/0"), 0.01);
        assert_eq!(at(m, "/msg/pose/covariance/35"), 0.02);
        assert_eq!(at(m, "/msg/pose/covariance").as_array().unwrap().len(), 36);
        assert_eq!(at(m, "/msg/twist/twist/linear/x"), 0.5);
        assert_eq!(at(m, "/msg/twist/twist/angular/z"), 0.25);
    }
    let cmd = on("/cmd_vel")[0];
    assert_eq!(at(cmd, "/msg/header/frame_id"), "base_link");
    assert_json!(
        at(cmd, "/msg/twist"),
        &json!({"linear": {"x": 0.5, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": 0.25}})
    );
    assert_eq!((CMD_LINEAR_X_MPS, CMD_ANGULAR_Z_RADPS), (0.5, 0.25));

    let labels = on("/labels");
    assert_eq!(labels[0]["log_time"], images[0]["log_time"]);
    assert_eq!(labels[1]["log_time"], images[1]["log_time"]);
    assert_eq!(at(labels[0], "/msg/object"), OBJECT);
    assert_json!(
        at(labels[0], "/msg/regions"),
        &json!([{"x_offset": 20, "y_offset": 12, "height": 18, "width": 16, "do_rectify": false}])
    );
    assert_eq!(RECT_PX, (20, 12, 16, 18));
    assert_eq!(at(labels[1], "/msg/object"), OBJECT);
    assert_json!(at(labels[1], "/msg/regions"), &json!([]));

    for (k, m) in on("/ground_truth/pose").iter().enumerate() {
        let kf = k as f64;
        assert_eq!(at(m, "/msg/header/frame_id"), "odom");
        assert_json!(
            at(m, "/msg/pose/position"),
            &json!({"x": 0.25 * kf, "y": 0.125 * kf + kf / 64.0, "z": 0.0})
        );
    }
    let gt = on("/ground_truth/objects")[0];
    assert_eq!(at(gt, "/msg/header/frame_id"), "odom");
    assert_json!(at(gt, "/msg/object"), &json!(["chair", "table"]));
    assert_json!(
        at(gt, "/msg/box_center/0"),
        &json!({"position": {"x": 3.0, "y": 0.5, "z": 0.45}, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}})
    );
    assert_json!(
        at(gt, "/msg/box_center/1/orientation"),
        &json!({"x": 0.0, "y": 0.0, "z": 0.25f64.sin(), "w": 0.25f64.cos()})
    );
    assert_json!(
        at(gt, "/msg/box_size"),
        &json!([{"x": 0.5, "y": 0.5, "z": 0.9}, {"x": 1.5, "y": 0.75, "z": 0.75}])
    );
    assert_eq!(FRAMES, 3);
}

#[test]
fn objloc_reads_a_session_written_by_rosbags() {
    let dir = tempfile::tempdir().unwrap();
    let bag_dir = dir.path().join("rosbags_session");
    let schemas = repo_dir().join("schemas");
    let w = py_json(
        "write_rosbags.py",
        &[schemas.as_os_str(), bag_dir.as_os_str()],
    );
    let mcap = PathBuf::from(w["mcap"].as_str().unwrap());
    assert_eq!(mcap, bag_dir.join("rosbags_session.mcap"));

    let s = inspect_json(&mcap);
    assert_eq!(s["profile"], "ros2");
    assert_eq!(s["library"], "rosbags-0.11.9");
    assert_eq!(s["messages"], 28);
    assert_eq!(s["frames"], 5);
    assert_eq!(s["labelled_frames"], 2);
    assert_eq!(s["background_frames"], 1);
    assert_eq!(s["objects_labelled"], json!(["mug"]));
    assert_eq!(s["ground_truth"], true);
    assert_eq!(s["ground_truth_objects"], json!(["mug"]));
    assert_eq!(s["missing_topics"], json!([]));
    assert_eq!(s["warnings"], json!([]));
    assert_eq!(
        s["image"],
        json!({"width": 32, "height": 24, "encoding": "png"})
    );
    assert_eq!(
        s["intrinsics"],
        json!({"width": 32, "height": 24, "fx": 30.0, "fy": 30.0, "cx": 16.0, "cy": 12.0})
    );
    assert_eq!(s["start_ns"], 1_600_000_000_250_000_000i64);
    assert_eq!(s["end_ns"], 1_600_000_000_650_000_000i64);
    let expected = [
        (
            "/camera/camera_info",
            "sensor_msgs/msg/CameraInfo",
            5,
            Some("camera_info"),
        ),
        (
            "/camera/image/compressed",
            "sensor_msgs/msg/CompressedImage",
            5,
            Some("compressed_image"),
        ),
        (
            "/cmd_vel",
            "geometry_msgs/msg/TwistStamped",
            1,
            Some("cmd_vel"),
        ),
        (
            "/ground_truth/objects",
            "objloc_msgs/msg/GroundTruth",
            1,
            Some("ground_truth_objects"),
        ),
        (
            "/ground_truth/pose",
            "geometry_msgs/msg/PoseStamped",
            5,
            Some("ground_truth_pose"),
        ),
        ("/labels", "objloc_msgs/msg/ObjectLabel", 3, Some("labels")),
        ("/odom", "nav_msgs/msg/Odometry", 5, Some("odom")),
        ("/rosout", "rcl_interfaces/msg/Log", 2, None),
        ("/tf_static", "tf2_msgs/msg/TFMessage", 1, Some("tf_static")),
    ];
    let rows = s["topics"].as_array().unwrap();
    assert_eq!(rows.len(), expected.len());
    for (row, (topic, ty, count, role)) in rows.iter().zip(expected) {
        assert_eq!(row["topic"], topic);
        assert_eq!(row["type"], ty, "{topic}");
        assert_eq!(row["message_encoding"], "cdr", "{topic}");
        assert_eq!(row["count"], count, "{topic}");
        assert_eq!(row["role"], json!(role), "{topic}");
        // And what rosbags says it wrote.
        assert_eq!(
            w["topics"][topic],
            json!({"type": ty, "count": count}),
            "{topic}"
        );
    }

    // The library decodes every session message rosbags serialised, pixels included.
    let reader = SessionReader::open(&mcap, Topics::default()).unwrap();
    let mut frames = 0;
    let mut odom_x_m = Vec::new();
    let mut regions = Vec::new();
    for m in reader.messages() {
        match m.unwrap().msg {
            SessionMsg::Frame(f) => {
                let rgb = f.decode_rgb8().unwrap();
                assert_eq!((rgb.width, rgb.height), (32, 24));
                // The script's rectangle is x 10..18, y 6..15.
                assert_eq!(rgb.pixel(10, 6), [20, 40, 230]);
                assert_eq!(rgb.pixel(17, 14), [20, 40, 230]);
                assert_eq!(rgb.pixel(18, 14), [128, 128, 128]);
                assert_eq!(rgb.pixel(0, 0), [128, 128, 128]);
                frames += 1;
            }
            SessionMsg::Odom(o) => odom_x_m.push(o.pose.position[0]),
            SessionMsg::Label(l) => regions.push(l.regions.len()),
            SessionMsg::TfStatic(tf) => {
                assert_eq!(tf.transforms[0].rotation_xyzw, [-0.5, 0.5, -0.5, 0.5]);
                assert_eq!(tf.transforms[0].child_frame_id, "camera_optical_frame");
            }
            _ => {}
        }
    }
    assert_eq!(frames, 5);
    assert_eq!(odom_x_m, [0.0, 0.03, 0.03 * 2.0, 0.03 * 3.0, 0.03 * 4.0]);
    assert_eq!(regions, [1, 1, 0]);
}

/// Chunks of an rrd (as rrd_contents.py lists them) for `entity` that have column `column`.
fn rrd_column<'a>(chunks: &'a [Value], entity: &str, column: &str) -> Vec<&'a Value> {
    chunks
        .iter()
        .filter(|c| c["entity"] == entity)
        .filter_map(|c| c["columns"].get(column))
        .collect()
}

#[test]
fn rerun_converts_an_objloc_session_to_rrd() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fixture.mcap");
    let fx = write_fixture_session(&path);
    let rrd = dir.path().join("fixture.rrd");
    let out = run_checked(
        Command::new(rerun_cli())
            .args(["mcap", "convert"])
            .arg(&path)
            .arg("-o")
            .arg(&rrd),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let stderr = String::from_utf8_lossy(&out.stderr);
    // Rerun skips (and logs as ERROR) a channel whose ros2msg schema it cannot resolve.
    assert!(
        !stderr.contains("ERROR"),
        "rerun mcap convert complained:\n{stderr}"
    );

    let chunks_json = py_json("rrd_contents.py", &[&rrd]);
    let chunks = chunks_json.as_array().unwrap();

    // Every session topic arrives as data, not only as channel metadata.
    for topic in fx.topics.keys() {
        let has_data = chunks.iter().any(|c| {
            c["entity"] == topic.as_str()
                && c["columns"].as_object().unwrap().keys().any(|k| {
                    !k.starts_with("Mcap") && !k.starts_with("message_") && k != "ros2_timestamp"
                })
        });
        assert!(has_data, "no data for {topic} in the rrd");
    }

    let stamps: Vec<i64> = fx.frame_stamps_ns.clone();
    let blobs = rrd_column(chunks, "/camera/image/compressed", "EncodedImage:blob");
    assert_eq!(blobs.len(), 1);
    let want: Vec<Value> = fx
        .pngs
        .iter()
        .map(|p| json!([{"len": p.len(), "sha256": sha256_hex(p)}]))
        .collect();
    assert_eq!(blobs[0], &Value::Array(want));
    let times = rrd_column(chunks, "/camera/image/compressed", "message_log_time");
    assert_eq!(times, [&json!(stamps)]);

    let k = rrd_column(chunks, "/camera/camera_info", "Pinhole:image_from_camera");
    // Rerun stores the 3x3 matrix column-major.
    let one = json!([[50.0, 0.0, 0.0, 0.0, 52.5, 0.0, 32.0, 24.0, 1.0]]);
    assert_eq!(k, [&json!([one, one, one])]);
    let res = rrd_column(chunks, "/camera/camera_info", "Pinhole:resolution");
    assert_eq!(
        res,
        [&json!([[[64.0, 48.0]], [[64.0, 48.0]], [[64.0, 48.0]]])]
    );
    let parent = rrd_column(chunks, "/camera/camera_info", "Pinhole:parent_frame");
    assert_eq!(
        parent,
        [&json!([[CAMERA_FRAME], [CAMERA_FRAME], [CAMERA_FRAME]])]
    );

    assert_eq!(
        rrd_column(chunks, "/tf_static", "Transform3D:translation"),
        [&json!([[[0.125, 0.0, 1.25]]])]
    );
    assert_eq!(
        rrd_column(chunks, "/tf_static", "Transform3D:quaternion"),
        [&json!([[[-0.5, 0.5, -0.5, 0.5]]])]
    );
    assert_eq!(
        rrd_column(chunks, "/tf_static", "Transform3D:parent_frame"),
        [&json!([["base_link"]])]
    );
    assert_eq!(
        rrd_column(chunks, "/tf_static", "Transform3D:child_frame"),
        [&json!([[CAMERA_FRAME]])]
    );
}

/// The rosbag2 bags recorded by rosbag2's own tests (shared/thirdparty/rosbag2), or None
/// (with a message) where ../shared is absent.
fn rosbag2_bags() -> Option<Vec<PathBuf>> {
    let dir = repo_dir().join("../shared/thirdparty/rosbag2");
    if !dir.is_dir() {
        crate::common::say_skipped(&format!("no {} on this machine", dir.display()));
        return None;
    }
    let mut bags: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension() == Some(OsStr::new("mcap")))
        .collect();
    bags.sort();
    Some(bags)
}

#[test]
fn inspect_summarises_real_rosbag2_bags() {
    let Some(bags) = rosbag2_bags() else { return };
    let names: Vec<_> = bags
        .iter()
        .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    assert_eq!(
        names,
        [
            "bag_with_topics_and_service_events.mcap",
            "cdr_test_0.mcap",
            "only_topics.mcap",
            "talker.mcap"
        ]
    );
    let all_missing = json!([
        "/camera/camera_info",
        "/tf_static",
        "/odom",
        "/cmd_vel",
        "/labels",
        "/ground_truth/pose",
        "/ground_truth/objects",
        "/camera/image/compressed (or /camera/image)"
    ]);
    for bag in &bags {
        let truth = py_json("mcap_topics.py", &[bag]);
        let s = inspect_json(bag);
        let name = bag.display();
        assert_eq!(s["profile"], truth["profile"], "{name}");
        assert_eq!(s["library"], truth["library"], "{name}");
        assert_eq!(s["messages"], truth["messages"], "{name}");
        assert_eq!(s["frames"], 0, "{name}");
        assert_eq!(s["missing_topics"], all_missing, "{name}");
        let truth_topics = truth["topics"].as_object().unwrap();
        let rows = s["topics"].as_array().unwrap();
        assert_eq!(rows.len(), truth_topics.len(), "{name}");
        for row in rows {
            let topic = row["topic"].as_str().unwrap();
            let t = &truth_topics[topic];
            assert_eq!(row["type"], t["type"], "{name} {topic}");
            assert_eq!(
                row["message_encoding"], t["message_encoding"],
                "{name} {topic}"
            );
            assert_eq!(row["count"], t["count"], "{name} {topic}");
            assert_eq!(row["role"], Value::Null, "{name} {topic}");
        }
    }
    // Known by hand for one bag, independently of both readers.
    let talker = inspect_json(&bags[3]);
    let counts: Vec<(String, u64)> = talker["topics"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| {
            (
                r["topic"].as_str().unwrap().to_owned(),
                r["count"].as_u64().unwrap(),
            )
        })
        .collect();
    assert_eq!(
        counts,
        [
            ("/parameter_events".to_owned(), 0),
            ("/rosout".to_owned(), 10),
            ("/topic".to_owned(), 10)
        ]
    );
}

/// Creates a venv from nothing in a temporary directory (slow: downloads the wheels).
/// Run with `cargo test --release --test it interop::pyenv -- --ignored`.
#[test]
#[ignore]
fn pyenv_is_created_from_scratch() {
    let dir = tempfile::tempdir().unwrap();
    let venv = dir.path().join("pyenv");
    let python = ensure_pyenv(&venv).unwrap_or_else(|e| panic!("{e}"));
    let out = run_checked(Command::new(&python).args([
        "-c",
        "import importlib.metadata as m; print(' '.join(m.version(p) for p in \
         ['mcap', 'mcap-ros2-support', 'rosbags', 'rerun-sdk']))",
    ]))
    .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(
        String::from_utf8_lossy(&out.stdout).trim(),
        "1.6.0 0.6.0 0.11.9 0.36.3"
    );
    let req = std::fs::read(repo_dir().join(REQUIREMENTS)).unwrap();
    assert_eq!(
        std::fs::read_to_string(venv.join(STAMP_FILE)).unwrap(),
        sha256_hex(&req)
    );
    // A second call finds the stamp and does not run pip again.
    let again = ensure_pyenv(&venv).unwrap();
    assert_eq!(again, python);
}
