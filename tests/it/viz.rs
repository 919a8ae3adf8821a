//! Rerun output of the fuser and the trainer, through the binary (`objloc fuse ... --save` and
//! `objloc train ... --save`), checked with Rerun's own tools (the pinned Python rerun-sdk's
//! `rerun rrd verify | compare` and its RRD reader, in tests/py/rrd_contents.py): the file
//! loads, holds the documented entity paths and archetypes, stamps frames with the session's
//! MCAP log times, and two runs give equal recordings.
//!
//! Invariants: the Python tools come from the venv `common::pyenv` creates (target/pyenv, or
//! `$OBJLOC_PYENV`), shared with the interop tests. Expected values are written out by hand
//! or come from the session file or the fuse report, never from the code under test.

use std::ffi::OsStr;
use std::path::Path;
use std::process::{Command, Output};
use std::time::Instant;

use serde_json::Value;

use crate::common::pyenv::{py_json, rerun_cli, run_checked, sha256_hex};
use crate::common::{json, objloc, ok, p, train};

/// `rerun rrd SUBCOMMAND FILES...`, which must succeed.
fn rerun_rrd(subcommand: &str, files: &[&Path]) -> Output {
    run_checked(
        Command::new(rerun_cli())
            .args(["rrd", subcommand])
            .args(files),
    )
    .unwrap_or_else(|e| panic!("{e}"))
}

/// Fuses the chair tour with `model` and `extra` flags, saving the Rerun recording to `rrd`
/// and the report beside it; returns the report.
fn fuse_to_rrd(model: &Path, rrd: &Path, extra: &[&str]) -> Value {
    fuse_to_rrd_env(model, rrd, extra, &[])
}

fn fuse_to_rrd_env(model: &Path, rrd: &Path, extra: &[&str], envs: &[(&str, &str)]) -> Value {
    let report = rrd.with_extension("json");
    let mut args = vec![
        "fuse",
        "recordings/chair-tour.mcap",
        "--model",
        p(model),
        "--report",
        p(&report),
        "--save",
        p(rrd),
    ];
    args.extend_from_slice(extra);
    let text = ok(&objloc(&args, envs));
    // The recording was closed and renamed into place, and said so.
    assert!(
        text.contains(&format!("rerun recording: {}", rrd.display())),
        "{text}"
    );
    assert!(rrd.exists());
    assert!(!rrd.with_extension("rrd.partial").exists());
    json(&report)
}

/// Per entity of an .rrd: static or not, its columns, and its `log_time` / `frame` values.
fn rrd_entities(rrd: &Path) -> Value {
    py_json(
        "rrd_contents.py",
        &[OsStr::new("--entities"), rrd.as_os_str()],
    )
}

fn columns(v: &Value, entity: &str) -> Vec<String> {
    let e = v
        .get(entity)
        .unwrap_or_else(|| panic!("no entity {entity} in the recording"));
    e["columns"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c.as_str().unwrap().to_owned())
        .collect()
}

fn u64s(v: &Value) -> Vec<u64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_u64().unwrap())
        .collect()
}

/// The PNG files of the chair tour's frames (see [`pngs_of`]).
fn session_pngs() -> Vec<Vec<u8>> {
    pngs_of("recordings/chair-tour.mcap")
}

/// The PNG files of a session's frames, in file order, cut out of its CompressedImage
/// messages with the mcap crate (the PNG signature to the end of the CDR payload, where the
/// `data` field ends), not with objloc's reader.
fn pngs_of(session: &str) -> Vec<Vec<u8>> {
    const PNG_SIGNATURE: &[u8] = b"\x89PNG\r\n\x1a\n";
    let bytes = std::fs::read(session).unwrap();
    mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| m.unwrap())
        .filter(|m| m.channel.topic == "/camera/image/compressed")
        .map(|m| {
            let at = m
                .data
                .windows(PNG_SIGNATURE.len())
                .position(|w| w == PNG_SIGNATURE)
                .expect("a PNG in the frame");
            m.data[at..].to_vec()
        })
        .collect()
}

/// A fused frame of a session without lens distortion goes to Rerun as the session's own
/// file, byte for byte (no decoding and encoding again).
fn assert_frames_are_the_sessions_pngs(rrd: &Path) {
    let chunks = py_json("rrd_contents.py", &[rrd]);
    let mut logged: Vec<Value> = chunks
        .as_array()
        .unwrap()
        .iter()
        .filter(|c| c["entity"] == "/world/robot/camera/image")
        .flat_map(|c| {
            c["columns"]["EncodedImage:blob"]
                .as_array()
                .unwrap()
                .clone()
        })
        .collect();
    let mut want: Vec<Value> = session_pngs()
        .iter()
        .map(|p| serde_json::json!([{"len": p.len(), "sha256": sha256_hex(p)}]))
        .collect();
    assert_eq!(want.len(), 8);
    // Chunks may come in any order (see above): compare as sets of rows.
    let key = |v: &Value| v.to_string();
    logged.sort_by_key(key);
    want.sort_by_key(key);
    // A pass shown again (a kept smoothing, a rollback) logs the same frames again.
    logged.dedup();
    assert_eq!(logged, want);
    let media: Vec<&Value> = chunks
        .as_array()
        .unwrap()
        .iter()
        .filter(|c| c["entity"] == "/world/robot/camera/image")
        .filter_map(|c| c["columns"].get("EncodedImage:media_type"))
        .collect();
    assert!(!media.is_empty());
    for m in media {
        for row in m.as_array().unwrap() {
            assert_eq!(row, &serde_json::json!(["image/png"]), "{m}");
        }
    }
}

#[test]
fn fuse_recording_verifies_holds_the_documented_entities_and_replays_equal() {
    let dir = tempfile::tempdir().unwrap();
    let model = train(dir.path());
    let a = dir.path().join("a.rrd");
    let b = dir.path().join("b.rrd");
    let report = fuse_to_rrd(&model, &a, &[]);
    let log_times: Vec<u64> = report["per_frame"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["log_time_ns"].as_u64().unwrap())
        .collect();
    // The chair tour's 8 frames, 15.028 s apart from 1700000001 s (recordings/README.md, and
    // the simulator's clock starts at 1.7e9 s + 1 s).
    let want: Vec<u64> = (0..8u64)
        .map(|i| 1_700_000_001_000_000_000 + i * 15_028_000_000)
        .collect();
    assert_eq!(log_times, want);
    // A kept smoothing shows the frames again, fused at the smoothed poses (the viewer's
    // latest-at shows that pass): each per-frame entity of the world and the camera holds
    // every frame once per pass.
    let passes = 1 + usize::from(report["refinement"]["smoothing"]["kept"] == true);
    // (Rows come sorted by time.)
    let want_rows: Vec<u64> = want
        .iter()
        .flat_map(|&t| std::iter::repeat_n(t, passes))
        .collect();
    let want_frames: Vec<u64> = (0..8)
        .flat_map(|f| std::iter::repeat_n(f, passes))
        .collect();
    // On one thread (a chunk cut by the SDK's size of a row once differed between thread
    // counts; src/viz/mod.rs, deterministic_batches).
    fuse_to_rrd_env(&model, &b, &[], &[("RAYON_NUM_THREADS", "1")]);
    rerun_rrd("verify", &[&a]);
    // Equal, with the `log_time` timeline compared too (rrd compare ignores it by default, so
    // it is checked against the session's log times below). Unordered: the chunks are cut by
    // size and row count only (the same rows in the same chunks every run), but the SDK's
    // batcher emits the chunks still pending at the end in an order of its own; Rerun's data
    // model is unordered (`rerun rrd compare --help`).
    run_checked(
        Command::new(rerun_cli())
            .args(["rrd", "compare", "--unordered"])
            .args([&a, &b]),
    )
    .unwrap_or_else(|e| panic!("{e}"));

    let v = rrd_entities(&a);
    let per_frame: &[(&str, &[&str])] = &[
        (
            "/world/robot",
            &["Transform3D:quaternion", "Transform3D:translation"],
        ),
        // Trajectories beside the robot, declared to be in the world's frame.
        (
            "/world/robot/odometry",
            &["LineStrips3D:strips", "CoordinateFrame:frame"],
        ),
        (
            "/world/robot/ground_truth",
            &["LineStrips3D:strips", "CoordinateFrame:frame"],
        ),
        (
            "/world/robot/camera/image",
            &["EncodedImage:blob", "EncodedImage:media_type"],
        ),
        ("/world/robot/camera/overlay", &["EncodedImage:blob"]),
        (
            "/world/robot/camera/probability",
            &[
                "DepthImage:buffer",
                "DepthImage:colormap",
                "DepthImage:meter",
            ],
        ),
        (
            "/world/pyramids",
            &["LineStrips3D:strips", "LineStrips3D:colors"],
        ),
        (
            "/world/grid",
            &[
                "VoxelGridMap:voxel_indices",
                "VoxelGridMap:values",
                "VoxelGridMap:colormap",
            ],
        ),
        (
            "/world/objects/estimated",
            &["Boxes3D:centers", "Boxes3D:half_sizes", "Boxes3D:labels"],
        ),
        ("/projections/x", &["DepthImage:buffer"]),
        ("/projections/y", &["DepthImage:buffer"]),
        ("/projections/z", &["DepthImage:buffer"]),
    ];
    // Plots hold each pass as a series of its own: the first pass's under the plot, a pass
    // shown again under the plot's `smoothed` child (two passes on one series would draw a
    // zigzag between their values at each frame).
    for plot in ["/plots/max_posterior", "/plots/mean_entropy_bits"] {
        let smoothed = format!("{plot}/smoothed");
        let series =
            std::iter::once(plot.to_owned()).chain((passes == 2).then_some(smoothed.clone()));
        for entity in series {
            let cols = columns(&v, &entity);
            assert!(
                cols.iter().any(|x| x == "Scalars:scalars"),
                "{entity}: {cols:?}"
            );
            assert_eq!(u64s(&v[&entity]["log_time"]), want, "{entity} log_time");
            assert_eq!(
                u64s(&v[&entity]["frame"]),
                (0..8).collect::<Vec<u64>>(),
                "{entity} frame"
            );
        }
        if passes == 1 {
            assert!(
                v.get(&smoothed).is_none(),
                "{smoothed} without a kept smoothing"
            );
        }
    }
    for (entity, want_cols) in per_frame {
        let cols = columns(&v, entity);
        for c in *want_cols {
            assert!(cols.iter().any(|x| x == c), "{entity} lacks {c}: {cols:?}");
        }
        // Stamped with the MCAP log times and the frame index only: no wall clock, no tick.
        assert!(cols.iter().all(|c| c != "log_tick"), "{entity}: {cols:?}");
        let e = &v[*entity];
        assert_eq!(e["static"], false, "{entity}");
        assert_eq!(u64s(&e["log_time"]), want_rows, "{entity} log_time");
        assert_eq!(u64s(&e["frame"]), want_frames, "{entity} frame");
    }
    // The centroid error is plotted only for frames with an object and ground truth
    // (`out::view::centroid_error_m` is None otherwise); whatever frames it has are fused
    // frames.
    if let Some(e) = v.get("/plots/centroid_error_m") {
        assert!(u64s(&e["frame"]).iter().all(|f| *f < 8), "{e}");
    }
    for (entity, want_cols) in [
        (
            "/world/robot/camera",
            &[
                "Pinhole:image_from_camera",
                "Pinhole:resolution",
                "Transform3D:translation",
            ][..],
        ),
        (
            "/world/objects/truth",
            &[
                "Boxes3D:centers",
                "Boxes3D:half_sizes",
                "Boxes3D:quaternions",
            ][..],
        ),
        ("/world", &["ViewCoordinates:xyz"][..]),
        // The final grid's objects (with any weaker instances), logged once the replay is
        // done.
        (
            "/world/objects/final",
            &["Boxes3D:centers", "Boxes3D:labels", "Boxes3D:colors"][..],
        ),
    ] {
        let cols = columns(&v, entity);
        for c in want_cols {
            assert!(cols.iter().any(|x| x == c), "{entity} lacks {c}: {cols:?}");
        }
        assert_eq!(v[entity]["static"], true, "{entity}");
        assert!(
            v[entity]["log_time"].as_array().unwrap().is_empty(),
            "{entity}"
        );
    }
    // No recording-properties chunk: it would carry the wall-clock start time.
    assert!(v.get("/__properties").is_none());
    assert_frames_are_the_sessions_pngs(&a);
    let size_mb = std::fs::metadata(&a).unwrap().len() as f64 / 1e6;
    assert!(size_mb < 50.0, "{size_mb} MB");
}

#[test]
fn a_different_recording_is_not_equal() {
    // Guards the equality check above: compare must fail when the content differs. Here the
    // objects grow over less of the grid (the default --grow-fraction is 0.7).
    let dir = tempfile::tempdir().unwrap();
    let model = train(dir.path());
    let a = dir.path().join("a.rrd");
    let ra = fuse_to_rrd(&model, &a, &[]);
    let b = dir.path().join("b.rrd");
    let rb = fuse_to_rrd(&model, &b, &["--grow-fraction", "0.9"]);
    // The difference is real: the located object's extent changed.
    assert_ne!(ra["objects"], rb["objects"]);
    let out = Command::new(rerun_cli())
        .args(["rrd", "compare", "--unordered"])
        .arg(&a)
        .arg(&b)
        .output()
        .unwrap();
    assert!(
        !out.status.success(),
        "compare found different recordings equal"
    );
}

/// `--stdout` gives stdout to the recording: the command's text goes to stderr, so that
/// `objloc fuse ... --stdout | rerun -` gets an .rrd and nothing else (train printed its
/// summary into the stream, fuse and predict appended theirs to it).
#[test]
fn stdout_carries_the_recording_alone() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("m.json");
    let runs: [(&str, Vec<&str>, &str); 3] = [
        (
            "train.rrd",
            vec!["train", "recordings/chair-train.mcap", "-o", p(&model)],
            "model written to",
        ),
        (
            "predict.rrd",
            vec![
                "predict",
                "recordings/chair-tour.mcap",
                "--model",
                p(&model),
            ],
            "tile ROC AUC",
        ),
        (
            "fuse.rrd",
            vec!["fuse", "recordings/chair-tour.mcap", "--model", p(&model)],
            "object 0: at",
        ),
    ];
    let out_dir = dir.path().join("probs");
    let report = dir.path().join("r.json");
    for (name, mut args, text) in runs {
        match args[0] {
            "predict" => args.extend(["--out", p(&out_dir)]),
            "fuse" => args.extend(["--report", p(&report)]),
            _ => {}
        }
        args.push("--stdout");
        let out = objloc(&args, &[]);
        ok(&out);
        let rrd = dir.path().join(name);
        std::fs::write(&rrd, &out.stdout).unwrap();
        assert_eq!(&out.stdout[..4], b"RRF2", "{name}: stdout is not an .rrd");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            stderr.contains(text),
            "{name}: no '{text}' on stderr: {stderr}"
        );
        rerun_rrd("verify", &[&rrd]);
    }
}

#[test]
fn train_recording_has_the_tree_graph_and_frames() {
    let dir = tempfile::tempdir().unwrap();
    train(dir.path());
    let rrd = dir.path().join("chair.rrd");
    rerun_rrd("verify", &[&rrd]);
    let v = rrd_entities(&rrd);
    let cols = columns(&v, "/tree");
    for c in [
        "GraphNodes:node_ids",
        "GraphNodes:labels",
        "GraphEdges:edges",
    ] {
        assert!(cols.iter().any(|x| x == c), "/tree lacks {c}: {cols:?}");
    }
    // recordings/README.md: chair-train has 3 labelled views + 18 background frames, all labelled.
    let frames = v["/train/frame/image"]["frame"].as_array().unwrap().len();
    assert_eq!(frames, 21);
    assert_eq!(
        v["/train/frame/labels"]["frame"].as_array().unwrap().len(),
        21
    );
    // Default models have a region head: its maps beside the tile head's.
    for entity in [
        "/train/frame/probability",
        "/train/frame/region_probability",
    ] {
        assert_eq!(v[entity]["frame"].as_array().unwrap().len(), 21, "{entity}");
        let cols = columns(&v, entity);
        assert!(
            cols.iter().any(|c| c == "DepthImage:buffer"),
            "{entity}: {cols:?}"
        );
    }
    assert_training_frames_are_jpegs_of_the_session(dir.path(), &rrd);
}

/// Every training frame in the recording is a JPEG (encoded by objloc, at quality 80) that
/// `image`'s decoder turns back into one of chair-train's frames, within a few levels.
fn assert_training_frames_are_jpegs_of_the_session(dir: &Path, rrd: &Path) {
    let blob_dir = dir.join("blobs");
    std::fs::create_dir_all(&blob_dir).unwrap();
    let listed = py_json(
        "rrd_contents.py",
        &[
            OsStr::new("--blobs"),
            OsStr::new("/train/frame/image"),
            rrd.as_os_str(),
            blob_dir.as_os_str(),
        ],
    );
    let session: Vec<Vec<u8>> = pngs_of("recordings/chair-train.mcap")
        .iter()
        .map(|png| image::load_from_memory(png).unwrap().to_rgb8().into_raw())
        .collect();
    let blobs = listed.as_array().unwrap();
    assert_eq!(blobs.len(), 21);
    for path in blobs {
        let bytes = std::fs::read(path.as_str().unwrap()).unwrap();
        assert_eq!(&bytes[..3], b"\xff\xd8\xff", "not a JPEG: {path}");
        let rgb = image::load_from_memory_with_format(&bytes, image::ImageFormat::Jpeg)
            .unwrap()
            .to_rgb8();
        assert_eq!(rgb.dimensions(), (256, 240));
        // The session's frame it is closest to: mean absolute error per channel, in levels
        // (3.2 for the first frame at quality 80 with 4:2:0 chroma, 2.2 at 90; the session's
        // next closest frame is 25 levels off, and a broken file further).
        let mean = |want: &Vec<u8>| {
            let sum: u64 = want
                .iter()
                .zip(rgb.as_raw())
                .map(|(&a, &b)| u64::from(a.abs_diff(b)))
                .sum();
            sum as f64 / want.len() as f64
        };
        let best = session.iter().map(mean).fold(f64::INFINITY, f64::min);
        assert!(best < 5.0, "{path}: mean error {best} levels");
    }
}

/// Cost of streaming: `objloc fuse` of the chair tour with `--no-rerun` and with the recording
/// saved, wall clock of the whole process (`cargo test --release --test it
/// viz::timing -- --ignored --nocapture`; `cargo bench --bench fuse` gives medians).
#[test]
#[ignore]
fn timing_with_and_without_rerun() {
    let dir = tempfile::tempdir().unwrap();
    let model = train(dir.path());
    let fuse = |rerun: &[&str]| {
        let mut args = vec!["fuse", "recordings/chair-tour.mcap", "--model", p(&model)];
        args.extend_from_slice(rerun);
        let t = Instant::now();
        ok(&objloc(&args, &[]));
        t.elapsed().as_secs_f64()
    };
    let plain = fuse(&["--no-rerun"]);
    let rrd = dir.path().join("t.rrd");
    let with = fuse(&["--save", p(&rrd)]);
    let mb = std::fs::metadata(&rrd).unwrap().len() as f64 / 1e6;
    println!("fuse {plain:.3} s, fuse + rrd {with:.3} s, rrd {mb:.2} MB");
}

#[test]
fn refined_replay_streams_the_refined_trajectory_beside_the_robot_in_world_coordinates() {
    let dir = tempfile::tempdir().unwrap();
    let model = train(dir.path());
    let rrd = dir.path().join("refined.rrd");
    let report = dir.path().join("r.json");
    ok(&objloc(
        &[
            "fuse",
            "recordings/chair-tour-drift.mcap",
            "--refine-poses",
            "--model",
            p(&model),
            "--report",
            p(&report),
            "--save",
            p(&rrd),
        ],
        &[],
    ));
    let v = rrd_entities(&rrd);
    for (entity, want) in [
        ("/world/robot/refined", "LineStrips3D:strips"),
        ("/world/robot/refined/frames", "Points3D:positions"),
        ("/world/robot/odometry", "LineStrips3D:strips"),
        ("/world/robot/ground_truth", "LineStrips3D:strips"),
        ("/plots/correction_m", "Scalars:scalars"),
    ] {
        let cols = columns(&v, entity);
        assert!(cols.iter().any(|c| c == want), "{entity}: {cols:?}");
        if entity.starts_with("/world/robot/") {
            assert!(
                cols.iter().any(|c| c == "CoordinateFrame:frame"),
                "{entity}: {cols:?}"
            );
        }
    }
    // Logged at each frame after the anchoring first one, once per pass shown (a kept
    // smoothing shows the frames again); the last track holds all 8 positions, starting at
    // the first frame's, which is /odom's there.
    let passes = 1 + usize::from(json(&report)["refinement"]["smoothing"]["kept"] == true);
    assert_eq!(
        v["/world/robot/refined"]["frame"].as_array().unwrap().len(),
        7 * passes
    );
    // The plots of a pass shown again are series of their own, so the filter's and the
    // smoother's corrections are compared frame by frame (not drawn over each other).
    assert_eq!(passes, 2, "this tour's smoothing is kept");
    let rows = |e: &str| v.get(e).map_or(0, |x| x["frame"].as_array().unwrap().len());
    assert_eq!(rows("/plots/correction_m"), 7);
    assert_eq!(rows("/plots/correction_m/smoothed"), 7);
    assert_eq!(rows("/plots/max_posterior"), 8);
    assert_eq!(rows("/plots/max_posterior/smoothed"), 8);
    let chunks = py_json("rrd_contents.py", &[&rrd]);
    let last_points = chunks
        .as_array()
        .unwrap()
        .iter()
        .filter(|c| c["entity"] == "/world/robot/refined/frames")
        .filter_map(|c| c["columns"]["Points3D:positions"].as_array())
        .flat_map(|rows| rows.iter())
        .next_back()
        .expect("refined positions")
        .clone();
    let points = last_points.as_array().unwrap();
    assert_eq!(points.len(), 8, "{last_points}");
    let first = &json(&report)["per_frame"][0]["odom_position_m"];
    for a in 0..2 {
        let got = points[0][a].as_f64().unwrap();
        let want = first[a].as_f64().unwrap();
        assert!((got - want).abs() < 1e-5, "{got} vs {want}");
    }
}
