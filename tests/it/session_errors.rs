//! Bad input through `objloc inspect` (the binary): every kind of damage ends in either a
//! readable partial summary with a warning (exit 0) or exactly one stderr line
//! `error: ...` naming the file and, where a message is to blame, its topic and log time
//! (exit 1); never a panic (exit 101), a signal or a hang.
//!
//! Invariants: inputs are built here from constants (`common::fixture`, an LCG for noise
//! images), so every run sees the same bytes; expected messages are hand-written strings.

use std::collections::BTreeMap;
use std::ffi::OsStr;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use objloc_core::io::msgs::{
    CompressedImage, Header, Odometry, Pose, RosMessage, Twist, schema_text,
};
use objloc_core::io::session::SessionWriter;

use crate::common::fixture::{T0_NS, fixture_png, write_fixture_session};
use crate::common::{Run, objloc_bounded};

/// Runs `objloc inspect [--json] PATH`, failing the test if it does not end within
/// `HANG_LIMIT`.
fn inspect(path: &Path, json: bool) -> Run {
    let mut args = vec![OsStr::new("inspect")];
    if json {
        args.push(OsStr::new("--json"));
    }
    args.push(path.as_os_str());
    objloc_bounded(&args)
}

/// Exit 1, nothing on stdout, exactly one stderr line starting `error: ` that names the file
/// and holds every string in `needles`.
fn assert_one_line_error(run: &Run, path: &Path, needles: &[&str]) -> String {
    assert_eq!(
        run.code,
        Some(1),
        "{}: exit {:?}, stderr:\n{}",
        path.display(),
        run.code,
        run.stderr
    );
    assert_eq!(run.stdout, "", "{}", path.display());
    let lines: Vec<&str> = run.stderr.lines().collect();
    assert_eq!(
        lines.len(),
        1,
        "{}: not one line:\n{}",
        path.display(),
        run.stderr
    );
    let line = lines[0];
    assert!(line.starts_with("error: "), "{line}");
    assert!(
        line.contains(&path.display().to_string()),
        "file not named: {line}"
    );
    for n in needles {
        // Once: a cause is not repeated by the error chain.
        assert_eq!(line.matches(n).count(), 1, "{n:?} not once in: {line}");
    }
    println!("{line}");
    line.to_owned()
}

/// One channel of a hand-built MCAP.
struct Chan {
    topic: &'static str,
    schema_name: &'static str,
    schema_encoding: &'static str,
    message_encoding: &'static str,
    schema: Vec<u8>,
}

impl Chan {
    /// A well-formed session channel for `M`.
    fn ros<M: RosMessage>(topic: &'static str) -> Self {
        Self {
            topic,
            schema_name: M::TYPE,
            schema_encoding: "ros2msg",
            message_encoding: "cdr",
            schema: schema_text(M::TYPE).unwrap_or_default().into_bytes(),
        }
    }
}

/// Writes an MCAP (profile ros2, chunked, with summary) holding `messages`: (channel index,
/// log time, payload).
fn write_raw_mcap(path: &Path, channels: &[Chan], messages: &[(usize, u64, Vec<u8>)]) {
    let file = std::fs::File::create(path).unwrap();
    let mut w = mcap::WriteOptions::new()
        .profile("ros2")
        .create(BufWriter::new(file))
        .unwrap();
    let ids: Vec<u16> = channels
        .iter()
        .map(|c| {
            let schema_id = w
                .add_schema(c.schema_name, c.schema_encoding, &c.schema)
                .unwrap();
            w.add_channel(schema_id, c.topic, c.message_encoding, &BTreeMap::new())
                .unwrap()
        })
        .collect();
    for (seq, (chan, log_time, data)) in messages.iter().enumerate() {
        let header = mcap::records::MessageHeader {
            channel_id: ids[*chan],
            sequence: seq as u32,
            log_time: *log_time,
            publish_time: *log_time,
        };
        w.write_to_known_channel(&header, data).unwrap();
    }
    w.finish().unwrap();
}

const T1_NS: u64 = T0_NS as u64 + 100_000_000;
/// `fmt_ns` of T1_NS, as errors print it.
const T1_TEXT: &str = "at log time 1700000000.223456789 s";

fn odometry(stamp_ns: i64) -> Odometry {
    Odometry {
        header: Header::new(stamp_ns, "odom"),
        child_frame_id: "base_link".into(),
        pose: Pose::default(),
        pose_covariance: [0.0; 36],
        twist: Twist::default(),
        twist_covariance: [0.0; 36],
    }
}

fn image(stamp_ns: i64, data: Vec<u8>) -> CompressedImage {
    CompressedImage {
        header: Header::new(stamp_ns, "camera_optical_frame"),
        format: "png".into(),
        data,
    }
}

#[test]
fn not_an_mcap_file() {
    let dir = tempfile::tempdir().unwrap();
    for (name, bytes) in [
        ("text.mcap", b"objloc session? no\n".to_vec()),
        ("empty.mcap", Vec::new()),
        ("half_magic.mcap", b"\x89MCA".to_vec()),
    ] {
        let path = dir.path().join(name);
        std::fs::write(&path, &bytes).unwrap();
        let line = assert_one_line_error(&inspect(&path, false), &path, &["not an MCAP file"]);
        assert!(line.contains("89 4d 43 41 50 30 0d 0a"), "{line}");
    }
    let missing = dir.path().join("missing.mcap");
    assert_one_line_error(&inspect(&missing, false), &missing, &["No such file"]);
}

/// Cuts `bytes` at every `step`-th offset and checks each cut file: exit 0 with a truncation
/// warning and at most `total` messages, the count never falling as the cut moves later; or a
/// one-line error. Returns (cuts read partially, cuts refused, most messages read).
fn check_truncations(dir: &Path, bytes: &[u8], step: usize, total: u64) -> (usize, usize, u64) {
    let path = dir.join("cut.mcap");
    let (mut partial, mut refused, mut last_count) = (0, 0, 0u64);
    for cut in (0..bytes.len()).step_by(step) {
        std::fs::write(&path, &bytes[..cut]).unwrap();
        let run = inspect(&path, true);
        match run.code {
            Some(0) => {
                let s: serde_json::Value = serde_json::from_str(&run.stdout)
                    .unwrap_or_else(|e| panic!("cut at {cut}: {e}"));
                let n = s["messages"].as_u64().unwrap();
                assert!(n <= total, "cut at {cut}: {n} messages");
                assert!(
                    n >= last_count,
                    "cut at {cut}: {n} messages after {last_count}"
                );
                last_count = n;
                let warned = s["warnings"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .any(|w| w.as_str().unwrap().starts_with("file is truncated"));
                assert!(
                    warned,
                    "cut at {cut} of {}: no truncation warning: {s}",
                    bytes.len()
                );
                assert!(
                    run.stderr.contains("warning: file is truncated"),
                    "cut at {cut}"
                );
                assert_eq!(
                    s["bytes_intact"].as_u64().map(|b| b <= cut as u64),
                    Some(true)
                );
                partial += 1;
            }
            _ => {
                assert_one_line_error(&run, &path, &[]);
                refused += 1;
            }
        }
    }
    (partial, refused, last_count)
}

#[test]
fn truncated_at_every_97th_byte() {
    let dir = tempfile::tempdir().unwrap();
    let full = dir.path().join("full.mcap");
    let fx = write_fixture_session(&full);
    let bytes = std::fs::read(&full).unwrap();
    let (partial, refused, most) = check_truncations(dir.path(), &bytes, 97, 17);
    assert_eq!(fx.message_count(), 17);
    // Cut 0 cannot be an MCAP; every cut past the magic and header reads partially.
    assert_eq!(refused, 1, "{partial} partial");
    assert_eq!(partial + refused, bytes.len().div_ceil(97));
    // The fixture is one chunk: a cut after it (in the summary) keeps all 17 messages.
    assert_eq!(most, 17);
}

/// 96 x 64 RGB noise from a fixed LCG: PNG barely compresses it, so a few frames fill the
/// writer's 256 KiB chunks.
fn noise_png(seed: u32) -> Vec<u8> {
    let mut state = seed.wrapping_mul(2_654_435_761).wrapping_add(1);
    let img = image::RgbImage::from_fn(96, 64, |_, _| {
        let mut px = [0u8; 3];
        for c in &mut px {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            *c = (state >> 24) as u8;
        }
        image::Rgb(px)
    });
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    out.into_inner()
}

const BIG_FRAMES: usize = 40;

/// A session of BIG_FRAMES noise frames (+ /odom each), several chunks long.
fn write_multi_chunk_session(path: &Path) {
    let mut w = SessionWriter::create(path).unwrap();
    for k in 0..BIG_FRAMES {
        let stamp = T0_NS + k as i64 * 100_000_000;
        w.write("/odom", stamp, &odometry(stamp)).unwrap();
        w.write(
            "/camera/image/compressed",
            stamp,
            &image(stamp, noise_png(k as u32)),
        )
        .unwrap();
    }
    w.finish().unwrap();
}

#[test]
fn truncated_multi_chunk_session_keeps_whole_chunks() {
    let dir = tempfile::tempdir().unwrap();
    let full = dir.path().join("big.mcap");
    write_multi_chunk_session(&full);
    let bytes = std::fs::read(&full).unwrap();
    let summary = mcap::Summary::read(&bytes)
        .unwrap()
        .expect("writer adds a summary");
    let mut chunks = summary.chunk_indexes.clone();
    chunks.sort_by_key(|c| c.chunk_start_offset);
    assert!(chunks.len() >= 3, "{} chunks", chunks.len());
    let total = 2 * BIG_FRAMES as u64;
    let (partial, refused, _) = check_truncations(dir.path(), &bytes, 9973, total);
    assert_eq!(refused, 1);
    assert!(partial > 20, "{partial}");

    // A cut inside chunk i keeps exactly the messages of chunks 0..i; one at its end adds chunk
    // i's, and after the last chunk nothing is lost.
    let cut_path = dir.path().join("cut.mcap");
    let count_at = |cut: u64| -> u64 {
        std::fs::write(&cut_path, &bytes[..cut as usize]).unwrap();
        let run = inspect(&cut_path, true);
        assert_eq!(run.code, Some(0), "cut at {cut}: {}", run.stderr);
        let s: serde_json::Value = serde_json::from_str(&run.stdout).unwrap();
        s["messages"].as_u64().unwrap()
    };
    let mut before = 0;
    for c in &chunks {
        let mid = count_at(c.chunk_start_offset + c.chunk_length / 2);
        assert_eq!(
            mid, before,
            "cut inside the chunk at {}",
            c.chunk_start_offset
        );
        let end = count_at(c.chunk_start_offset + c.chunk_length);
        assert!(
            end > before,
            "chunk at {} added no message",
            c.chunk_start_offset
        );
        before = end;
    }
    assert_eq!(before, total);
}

/// Byte offset of the compressed records inside the chunk record at `chunk_start`: opcode (1),
/// record length (8), message start and end time (8 + 8), uncompressed size (8), uncompressed
/// CRC (4), compression name (4 + len), records length (8).
fn chunk_records_offset(bytes: &[u8], chunk_start: usize) -> usize {
    let name_len_at = chunk_start + 1 + 8 + 8 + 8 + 8 + 4;
    let name_len =
        u32::from_le_bytes(bytes[name_len_at..name_len_at + 4].try_into().unwrap()) as usize;
    name_len_at + 4 + name_len + 8
}

#[test]
fn chunk_crc_mismatch_is_one_line_naming_the_last_good_message() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("flipped.mcap");
    write_multi_chunk_session(&path);
    let mut bytes = std::fs::read(&path).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let mut chunks = summary.chunk_indexes.clone();
    chunks.sort_by_key(|c| c.chunk_start_offset);
    // Damage the second chunk, so the first one's messages were read before it.
    let second = &chunks[1];
    let first_end_ns = chunks[0].message_end_time;
    let records_at = chunk_records_offset(&bytes, second.chunk_start_offset as usize);
    let flip_at = records_at + second.compressed_size as usize / 2;
    bytes[flip_at] ^= 0x5a;
    std::fs::write(&path, &bytes).unwrap();
    let line = assert_one_line_error(
        &inspect(&path, false),
        &path,
        &[
            "topic /camera/image/compressed",
            &format!(
                "at log time {}",
                objloc_core::io::session::fmt_ns(first_end_ns)
            ),
            "damaged data after byte",
        ],
    );
    assert!(
        line.to_lowercase().contains("crc") || line.contains("zstd"),
        "{line}"
    );
}

fn one_odom_session(dir: &Path, name: &str, chan: Chan, payload: Vec<u8>) -> PathBuf {
    let path = dir.join(name);
    let good_image = image(T0_NS, fixture_png(0)).to_cdr();
    write_raw_mcap(
        &path,
        &[
            Chan::ros::<CompressedImage>("/camera/image/compressed"),
            chan,
        ],
        &[(0, T0_NS as u64, good_image), (1, T1_NS, payload)],
    );
    path
}

#[test]
fn wrong_encoding_schema_or_type_on_a_session_topic() {
    let dir = tempfile::tempdir().unwrap();
    let cdr = odometry(T1_NS as i64).to_cdr();
    let cases = [
        (
            "json.mcap",
            Chan {
                topic: "/odom",
                schema_name: "nav_msgs/msg/Odometry",
                schema_encoding: "jsonschema",
                message_encoding: "json",
                schema: b"{\"type\": \"object\"}".to_vec(),
            },
            br#"{"pose": {}}"#.to_vec(),
            "message encoding \"json\" is not supported",
        ),
        (
            "idl.mcap",
            Chan {
                schema_encoding: "ros2idl",
                ..Chan::ros::<Odometry>("/odom")
            },
            cdr.clone(),
            "schema encoding \"ros2idl\" is not supported",
        ),
        (
            "type.mcap",
            Chan {
                schema_name: "geometry_msgs/msg/PoseStamped",
                ..Chan::ros::<Odometry>("/odom")
            },
            cdr,
            "schema is \"geometry_msgs/msg/PoseStamped\" but this topic must carry nav_msgs/msg/Odometry",
        ),
    ];
    for (name, chan, payload, why) in cases {
        let path = one_odom_session(dir.path(), name, chan, payload);
        assert_one_line_error(
            &inspect(&path, false),
            &path,
            &["topic /odom", T1_TEXT, why],
        );
    }
}

#[test]
fn cdr_payload_too_short_or_lying_about_lengths() {
    let dir = tempfile::tempdir().unwrap();
    let mut short = odometry(T1_NS as i64).to_cdr();
    short.truncate(short.len() - 8);
    let path = one_odom_session(
        dir.path(),
        "short.mcap",
        Chan::ros::<Odometry>("/odom"),
        short,
    );
    assert_one_line_error(
        &inspect(&path, false),
        &path,
        &[
            "topic /odom",
            T1_TEXT,
            "cannot decode nav_msgs/msg/Odometry",
            "payload cut short",
        ],
    );

    // A CompressedImage whose data length claims 4e9 bytes: refused, not allocated.
    let mut lying = image(T1_NS as i64, vec![1, 2, 3, 4]).to_cdr();
    let n = lying.len();
    lying[n - 8..n - 4].copy_from_slice(&4_000_000_000u32.to_le_bytes());
    let path = dir.path().join("lying.mcap");
    write_raw_mcap(
        &path,
        &[Chan::ros::<CompressedImage>("/camera/image/compressed")],
        &[
            (0, T0_NS as u64, image(T0_NS, fixture_png(0)).to_cdr()),
            (0, T1_NS, lying),
        ],
    );
    assert_one_line_error(
        &inspect(&path, false),
        &path,
        &[
            "topic /camera/image/compressed",
            T1_TEXT,
            "sequence length 4000000000",
        ],
    );
}

#[test]
fn png_that_does_not_decode() {
    let dir = tempfile::tempdir().unwrap();
    let good = fixture_png(0);
    // Signature and IHDR intact (so the size reads), pixel data garbage.
    let mut broken = good[..33].to_vec();
    broken.extend_from_slice(&[0x00, 0x00, 0x00, 0x10, b'I', b'D', b'A', b'T']);
    broken.extend_from_slice(&[0xde; 20]);
    for (name, second_frame) in [
        ("garbage.mcap", b"not a png".to_vec()),
        ("broken.mcap", broken),
    ] {
        let path = dir.path().join(name);
        write_raw_mcap(
            &path,
            &[Chan::ros::<CompressedImage>("/camera/image/compressed")],
            &[
                (0, T0_NS as u64, image(T0_NS, good.clone()).to_cdr()),
                (0, T1_NS, image(T1_NS as i64, second_frame).to_cdr()),
            ],
        );
        assert_one_line_error(
            &inspect(&path, false),
            &path,
            &["topic /camera/image/compressed", T1_TEXT, "does not decode"],
        );
    }
}

#[test]
fn image_size_differing_from_camera_info_is_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("size.mcap");
    let mut w = SessionWriter::create(&path).unwrap();
    let info = objloc_core::io::msgs::CameraInfo::pinhole(
        Header::new(T0_NS, "camera_optical_frame"),
        640,
        480,
        500.0,
        500.0,
        320.0,
        240.0,
    );
    w.write("/camera/camera_info", T0_NS, &info).unwrap();
    w.write(
        "/camera/image/compressed",
        T0_NS,
        &image(T0_NS, fixture_png(0)),
    )
    .unwrap();
    w.finish().unwrap();
    let run = inspect(&path, false);
    assert_eq!(run.code, Some(0), "{}", run.stderr);
    assert!(
        run.stdout
            .contains("warning: frames are 64 x 48 but CameraInfo says 640 x 480"),
        "{}",
        run.stdout
    );
}

/// A CameraInfo that changes mid-session: `inspect` warns once, naming what changed and when
/// (found by fuzzing: it said nothing, and fuse's error printed values that were equal).
#[test]
fn a_camera_info_that_changes_is_a_warning_naming_the_change() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("camera.mcap");
    let mut w = SessionWriter::create(&path).unwrap();
    let info = |fy: f64, k3: f64| {
        let mut ci = objloc_core::io::msgs::CameraInfo::pinhole(
            Header::new(T0_NS, "camera_optical_frame"),
            64,
            48,
            50.0,
            fy,
            32.0,
            24.0,
        );
        ci.distortion_model = "plumb_bob".into();
        ci.d = vec![0.0, 0.0, 0.0, 0.0, k3];
        ci
    };
    // Within the rounding tolerance, then a new k3 (warned), then a new fy (not again).
    for (k, (fy, k3)) in [(50.0, 0.0), (50.01, 0.0), (50.0, 1e-6), (51.0, 0.0)]
        .into_iter()
        .enumerate()
    {
        let t = T0_NS + k as i64 * 1_000_000_000;
        w.write("/camera/camera_info", t, &info(fy, k3)).unwrap();
        w.write("/camera/image/compressed", t, &image(t, fixture_png(0)))
            .unwrap();
    }
    w.finish().unwrap();
    let run = inspect(&path, false);
    assert_eq!(run.code, Some(0), "{}", run.stderr);
    let warned: Vec<&str> = run
        .stdout
        .lines()
        .filter(|l| l.contains("CameraInfo changes"))
        .collect();
    assert_eq!(
        warned,
        vec![format!(
            "warning: /camera/camera_info at {}: CameraInfo changes (k3 0 -> 0.000001); fuse takes one camera and refuses this session",
            objloc_core::io::session::fmt_ns((T0_NS + 2_000_000_000) as u64)
        )],
        "{}",
        run.stdout
    );
}

/// Every command that reads a truncated session says so on stderr, as fuse does (train,
/// predict and eval said nothing and went on with the part they could read).
#[test]
fn train_predict_and_eval_warn_of_a_truncated_session() {
    use crate::common::{objloc, ok, p, repo_dir};
    let dir = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(repo_dir().join("recordings/chair-train.mcap")).unwrap();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 3 / 4]).unwrap();
    let model = dir.path().join("m.json");
    let out = dir.path().join("pred");
    let report = dir.path().join("r.json");
    let runs: [Vec<&str>; 4] = [
        vec!["train", p(&cut), "-o", p(&model), "--no-rerun"],
        vec![
            "predict",
            p(&cut),
            "--model",
            p(&model),
            "--out",
            p(&out),
            "--no-rerun",
        ],
        vec![
            "fuse",
            p(&cut),
            "--model",
            p(&model),
            "--report",
            p(&report),
            "--no-rerun",
        ],
        vec!["eval", p(&cut), "--report", p(&report)],
    ];
    for args in runs {
        let run = objloc(&args, &[]);
        ok(&run);
        let err = String::from_utf8_lossy(&run.stderr);
        assert!(
            err.lines()
                .any(|l| l.starts_with("warning:") && l.contains("truncated")),
            "{}: {err}",
            args[0]
        );
    }
}
