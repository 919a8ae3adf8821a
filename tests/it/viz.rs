//! Rerun output of the fuser and the trainer, checked with Rerun's own tools (the pinned Python
//! rerun-sdk's `rerun rrd verify | print | compare`): the file loads, holds the documented
//! entity paths and archetypes, stamps frames with the session's MCAP log times, and two
//! replays give equal recordings.
//!
//! Invariants: the Python tools come from the venv tests/interop.rs creates (target/pyenv, or
//! `$OBJLOC_PYENV`; same requirements file, same stamp and lock), so the two test files share
//! one install. Expected values are written out by hand or come from the session file, never
//! from the code under test.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use common::pyenv::{repo_dir, run_checked};
use objloc::viz::fuse::{FuseViz, VizOptions};
use objloc::viz::{self, Target, VizArgs};
use objloc_core::fuse::replay::{FuseOptions, Observer, replay};
use objloc_core::io::session::{SessionReader, Topics};
use objloc_core::learn::model::Model;

/// The venv's `rerun` CLI (the venv is created on first use, see tests/common/pyenv.rs).
fn rerun_cli() -> PathBuf {
    common::pyenv::python().with_file_name("rerun")
}

fn rerun(args: &[&std::ffi::OsStr]) -> Output {
    run_checked(Command::new(rerun_cli()).args(args)).unwrap_or_else(|e| panic!("{e}"))
}

/// Runs the binary from the repository root and checks it succeeded.
fn run_objloc(args: &[&std::ffi::OsStr]) {
    let out = Command::new(env!("CARGO_BIN_EXE_objloc"))
        .current_dir(repo_dir())
        .args(args)
        .output()
        .expect("objloc runs");
    assert!(
        out.status.success(),
        "objloc {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

fn trained_model(dir: &Path) -> PathBuf {
    let model = dir.join("chair-model.json");
    run_objloc(&[
        "train".as_ref(),
        repo_dir().join("recordings/chair-train.mcap").as_os_str(),
        "-o".as_ref(),
        model.as_os_str(),
    ]);
    model
}

/// Replays the chair tour with the Rerun observer into `rrd`; returns the MCAP log times of
/// the fused frames.
fn fuse_to_rrd(model: &Path, rrd: &Path) -> Vec<u64> {
    let session = repo_dir().join("recordings/chair-tour.mcap");
    let model = Model::load(model).unwrap();
    let reader = SessionReader::open(&session, Topics::default()).unwrap();
    let args = VizArgs {
        target: Target::Save(rrd.to_owned()),
    };
    let id = viz::recording_id("fuse", &["chair-tour", "test"]);
    let stream = viz::open_stream(
        &args,
        Path::new("unused.rrd"),
        &id,
        Some(viz::fuse_blueprint()),
    )
    .unwrap();
    let mut obs = FuseViz::new(stream.rec.clone(), VizOptions::default());
    let observers: &mut [&mut dyn Observer] = &mut [&mut obs];
    let outcome = replay(&reader, &model, &FuseOptions::default(), observers).unwrap();
    drop(obs);
    assert_eq!(stream.finish().unwrap().as_deref(), Some(rrd));
    assert!(!rrd.with_extension("rrd.partial").exists());
    outcome.per_frame.iter().map(|f| f.log_time_ns).collect()
}

/// Per entity of an .rrd: static or not, its columns, and its `log_time` / `frame` values, read
/// with the rerun-sdk's own RRD reader.
const RRD_ENTITIES_PY: &str = r#"
import sys, json
import pyarrow as pa
from rerun.experimental import RrdReader
out = {}
for chunk in RrdReader(sys.argv[1]).stream():
    b = chunk.to_record_batch()
    e = out.setdefault(chunk.entity_path, {"static": True, "columns": [], "log_time": [], "frame": []})
    e["static"] = e["static"] and chunk.is_static
    for n in b.schema.names:
        if not n.startswith("rerun.controls") and n not in e["columns"]:
            e["columns"].append(n)
    if "log_time" in b.schema.names:
        e["log_time"] += b.column("log_time").cast(pa.int64()).to_pylist()
    if "frame" in b.schema.names:
        e["frame"] += b.column("frame").to_pylist()
for e in out.values():
    e["columns"].sort()
    e["log_time"].sort()
    e["frame"].sort()
json.dump(out, sys.stdout)
"#;

fn rrd_entities(rrd: &Path) -> serde_json::Value {
    let python = rerun_cli().with_file_name("python");
    let out = run_checked(Command::new(python).arg("-c").arg(RRD_ENTITIES_PY).arg(rrd))
        .unwrap_or_else(|e| panic!("{e}"));
    serde_json::from_slice(&out.stdout).unwrap()
}

fn columns(v: &serde_json::Value, entity: &str) -> Vec<String> {
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

#[test]
fn fuse_recording_verifies_holds_the_documented_entities_and_replays_equal() {
    let dir = tempfile::tempdir().unwrap();
    let model = trained_model(dir.path());
    let a = dir.path().join("a.rrd");
    let b = dir.path().join("b.rrd");
    let log_times = fuse_to_rrd(&model, &a);
    // The chair tour's 8 frames, 15.028 s apart from 1700000001 s (recordings/README.md, and
    // the simulator's clock starts at 1.7e9 s + 1 s).
    let want: Vec<u64> = (0..8u64)
        .map(|i| 1_700_000_001_000_000_000 + i * 15_028_000_000)
        .collect();
    assert_eq!(log_times, want);
    fuse_to_rrd(&model, &b);
    rerun(&["rrd".as_ref(), "verify".as_ref(), a.as_os_str()]);
    // Equal, with the `log_time` timeline compared too (rrd compare ignores it by default, so
    // it is checked against the session's log times below).
    rerun(&[
        "rrd".as_ref(),
        "compare".as_ref(),
        a.as_os_str(),
        b.as_os_str(),
    ]);

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
            &["Image:buffer", "Image:format"],
        ),
        ("/world/robot/camera/overlay", &["Image:buffer"]),
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
        ("/plots/max_posterior", &["Scalars:scalars"]),
        ("/plots/mean_entropy_bits", &["Scalars:scalars"]),
    ];
    for (entity, want_cols) in per_frame {
        let cols = columns(&v, entity);
        for c in *want_cols {
            assert!(cols.iter().any(|x| x == c), "{entity} lacks {c}: {cols:?}");
        }
        // Stamped with the MCAP log times and the frame index only: no wall clock, no tick.
        assert!(cols.iter().all(|c| c != "log_tick"), "{entity}: {cols:?}");
        let e = &v[*entity];
        assert_eq!(e["static"], false, "{entity}");
        let lt: Vec<u64> = e["log_time"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_u64().unwrap())
            .collect();
        assert_eq!(lt, want, "{entity} log_time");
        let fr: Vec<u64> = e["frame"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_u64().unwrap())
            .collect();
        assert_eq!(fr, (0..8).collect::<Vec<u64>>(), "{entity} frame");
    }
    // The centroid error is plotted only for frames with an object (unit-tested in
    // src/viz/fuse.rs); whatever frames it has are fused frames.
    if let Some(e) = v.get("/plots/centroid_error_m") {
        assert!(
            e["frame"]
                .as_array()
                .unwrap()
                .iter()
                .all(|f| f.as_u64().unwrap() < 8)
        );
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
    let size_mb = std::fs::metadata(&a).unwrap().len() as f64 / 1e6;
    assert!(size_mb < 50.0, "{size_mb} MB");
}

#[test]
fn a_different_recording_is_not_equal() {
    // Guards the equality check above: compare must fail when the content differs.
    let dir = tempfile::tempdir().unwrap();
    let model = trained_model(dir.path());
    let a = dir.path().join("a.rrd");
    fuse_to_rrd(&model, &a);
    let b = dir.path().join("b.rrd");
    let reader = SessionReader::open(
        &repo_dir().join("recordings/chair-tour.mcap"),
        Topics::default(),
    )
    .unwrap();
    let args = VizArgs {
        target: Target::Save(b.clone()),
    };
    let id = viz::recording_id("fuse", &["chair-tour", "test"]);
    let stream = viz::open_stream(
        &args,
        Path::new("unused.rrd"),
        &id,
        Some(viz::fuse_blueprint()),
    )
    .unwrap();
    let options = VizOptions {
        grid_min_posterior: 0.9,
        ..VizOptions::default()
    };
    let mut obs = FuseViz::new(stream.rec.clone(), options);
    let observers: &mut [&mut dyn Observer] = &mut [&mut obs];
    replay(
        &reader,
        &Model::load(&model).unwrap(),
        &FuseOptions::default(),
        observers,
    )
    .unwrap();
    drop(obs);
    stream.finish().unwrap();
    let out = Command::new(rerun_cli())
        .args(["rrd", "compare"])
        .arg(&a)
        .arg(&b)
        .output()
        .unwrap();
    assert!(!out.status.success(), "compare found different grids equal");
}

#[test]
fn train_recording_has_the_tree_graph_and_frames() {
    let dir = tempfile::tempdir().unwrap();
    let model_path = trained_model(dir.path());
    let model = Model::load(&model_path).unwrap();
    let session = objloc_core::learn::dataset::load_session(
        &repo_dir().join("recordings/chair-train.mcap"),
        Topics::default(),
        None,
        true,
    )
    .unwrap();
    let rrd = dir.path().join("train.rrd");
    let args = VizArgs {
        target: Target::Save(rrd.clone()),
    };
    let stream = viz::open_stream(
        &args,
        Path::new("unused.rrd"),
        &viz::recording_id("train", &["t"]),
        Some(viz::train_blueprint()),
    )
    .unwrap();
    objloc::viz::train::log_tree(&stream.rec, &model).unwrap();
    objloc::viz::train::log_training_frames(&stream.rec, &model, std::slice::from_ref(&session))
        .unwrap();
    stream.finish().unwrap();
    rerun(&["rrd".as_ref(), "verify".as_ref(), rrd.as_os_str()]);
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
}

/// Cost of streaming: replay of the chair tour with and without the Rerun observer
/// (`cargo test --release --test viz timing -- --ignored --nocapture`).
#[test]
#[ignore]
fn timing_with_and_without_rerun() {
    let dir = tempfile::tempdir().unwrap();
    let model = trained_model(dir.path());
    let m = Model::load(&model).unwrap();
    let reader = SessionReader::open(
        &repo_dir().join("recordings/chair-tour.mcap"),
        Topics::default(),
    )
    .unwrap();
    let t0 = std::time::Instant::now();
    replay(&reader, &m, &FuseOptions::default(), &mut []).unwrap();
    let plain = t0.elapsed();
    let t1 = std::time::Instant::now();
    let rrd = dir.path().join("t.rrd");
    fuse_to_rrd(&model, &rrd);
    let with = t1.elapsed();
    let mb = std::fs::metadata(&rrd).unwrap().len() as f64 / 1e6;
    println!(
        "replay {:.3} s, replay + rrd {:.3} s, rrd {mb:.2} MB",
        plain.as_secs_f64(),
        with.as_secs_f64()
    );
}

#[test]
fn refined_replay_streams_the_refined_trajectory_beside_the_robot_in_world_coordinates() {
    let dir = tempfile::tempdir().unwrap();
    let model = trained_model(dir.path());
    let rrd = dir.path().join("refined.rrd");
    let report = dir.path().join("r.json");
    run_objloc(&[
        "fuse".as_ref(),
        "recordings/chair-tour-drift.mcap".as_ref(),
        "--refine-poses".as_ref(),
        "--model".as_ref(),
        model.as_os_str(),
        "--report".as_ref(),
        report.as_os_str(),
        "--save".as_ref(),
        rrd.as_os_str(),
    ]);
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
    // Logged at each frame after the anchoring first one; the last track holds all 8
    // positions, starting at the first frame's, which is /odom's there.
    assert_eq!(
        v["/world/robot/refined"]["frame"].as_array().unwrap().len(),
        7
    );
    let python = rerun_cli().with_file_name("python");
    let out = run_checked(
        Command::new(python)
            .arg(repo_dir().join("tests/py/rrd_contents.py"))
            .arg(&rrd),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let chunks: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
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
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    let first = &report["per_frame"][0]["odom_position_m"];
    for a in 0..2 {
        let got = points[0][a].as_f64().unwrap();
        let want = first[a].as_f64().unwrap();
        assert!((got - want).abs() < 1e-5, "{got} vs {want}");
    }
}
