//! The real captures of `../shared/realdata` (skipped where absent) imported with the
//! committed labels as a user would (recordings/realdata/README.md), then trained, fused with
//! defaults and scored against the rectangles: the session without /cmd_vel gets its
//! defaults fitted (no motion model, no refinement, a grid around where the cameras look)
//! and says so, the distortion of the phone capture is written, and the located centre is
//! where the rectangles say (the measured values of docs/realdata.md, with their margins).

use std::path::{Path, PathBuf};

use crate::common::{json, objloc, ok, p, repo_dir};

fn realdata() -> Option<PathBuf> {
    let d = repo_dir().join("../shared/realdata");
    if d.is_dir() {
        Some(d)
    } else {
        crate::common::say_skipped("no ../shared/realdata on this machine");
        None
    }
}

/// `objloc fuse` of `tour` with `model` and default options, its report to `report`: stdout.
fn fuse_with_defaults(tour: &Path, model: &Path, report: &Path) -> String {
    let args = [
        "fuse",
        p(tour),
        "--model",
        p(model),
        "--report",
        p(report),
        "--no-rerun",
    ];
    ok(&objloc(&args, &[]))
}

/// The located centre's error in percent of the object's size, as `objloc eval` prints it.
fn error_percent(ev: &str) -> f64 {
    ev.split(" % of the size")
        .next()
        .and_then(|s| s.rsplit(' ').next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no error fraction in {ev}"))
}

#[test]
fn the_phone_capture_imports_with_its_distortion_and_two_objects_per_frame() {
    let Some(r) = realdata() else { return };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("fruit.mcap");
    let labels = repo_dir().join("recordings/realdata/fruit/labels.csv");
    let nerf = r.join("fruit/transforms.json");
    let args = [
        "record",
        "import",
        "--nerf",
        p(&nerf),
        "--labels",
        p(&labels),
        "-o",
        p(&out),
    ];
    let run = objloc(&args, &[]);
    let stdout = String::from_utf8_lossy(&run.stdout).to_string();
    ok(&run);
    assert!(stdout.contains("(81 frames, 81 labelled)"), "{stdout}");
    assert!(
        stdout.contains("81 frames carry lens distortion"),
        "{stdout}"
    );
    let inspect = ok(&objloc(&["inspect", p(&out)], &[]));
    assert!(inspect.contains("/labels"), "{inspect}");
    // The phone's JPEGs are carried as they are, not re-encoded.
    assert!(inspect.contains("605 x 806 jpeg"), "{inspect}");
}

#[test]
fn the_milk_carton_is_located_inside_its_rectangles_with_fitted_defaults() {
    let Some(r) = realdata() else { return };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let llff = r.join("milk/poses_bounds.npy");
    let images = r.join("milk/images");
    let import = |labels: &str, flag: &str, out: &str| {
        let o = d.join(out);
        ok(&objloc(
            &[
                "record",
                "import",
                "--llff",
                p(&llff),
                "--images",
                p(&images),
                "--object",
                "milk",
                flag,
                labels,
                "-o",
                p(&o),
            ],
            &[],
        ));
        o
    };
    let lab = repo_dir().join("recordings/realdata/milk/train-labels.csv");
    let train = import(p(&lab), "--labels", "train.mcap");
    // The tour's rectangles come from the masks, as `--masks` turns them into rectangles.
    let tour = import(p(&r.join("milk/images_mask")), "--masks", "tour.mcap");
    let model = d.join("milk.json");
    ok(&objloc(
        &["train", p(&train), "-o", p(&model), "--no-rerun"],
        &[],
    ));
    // An imported capture has no /cmd_vel: the capture's channels and light variants.
    let m = json(&model);
    assert_eq!(m["features"], "rgb332+hs");
    assert_eq!(m["metadata"]["augment"], "light");
    let report = d.join("r.json");
    let out = fuse_with_defaults(&tour, &model, &report);
    assert!(
        out.contains("fitted to the session: no pose refinement"),
        "{out}"
    );
    let rep = json(&report);
    assert_eq!(rep["options"]["refine_poses"], false);
    // Motion model, refinement, locations, weaker instances, grid.
    assert_eq!(
        rep["fitted"].as_array().unwrap().len(),
        5,
        "{}",
        rep["fitted"]
    );
    assert_eq!(rep["options"]["objects"]["weaker_instances"], false);
    // No floor under the carton: its location is triangulated from its detections' boxes, in
    // nearly every one of the 43 frames (it is wholly in view in each; measured 39 with the
    // capture's training defaults (a forest of 16 trees), 42 with one tree, 43 with rgb332
    // alone): at least 90 % of them.
    assert_eq!(rep["options"]["locate"], "detections");
    let rays = rep["objects"][0]["from_detections"]["rays"]
        .as_u64()
        .unwrap();
    assert!((39..=43).contains(&rays), "{rays} rays");
    assert!(
        out.contains(&format!("located from {rays} frames' detection boxes")),
        "{out}"
    );
    let dims: Vec<u64> = rep["grid"]["dims"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap())
        .collect();
    assert_eq!(dims.iter().max(), Some(&200), "{dims:?}");
    assert!(dims.iter().all(|n| *n >= 100), "{dims:?}");
    assert_eq!(rep["objects"].as_array().unwrap().len(), 1);
    let ev = ok(&objloc(&["eval", p(&tour), "--report", p(&report)], &[]));
    assert!(
        ev.contains("inside the rectangle in 43 of 43 frames"),
        "{ev}"
    );
    // Measured 0.866 (`objloc predict` gives the same; the target of 0.93 is not met: the
    // rectangles hold white background, docs/realdata.md).
    let auc: f64 = ev
        .split("tile ROC AUC of the fuser's evidence (the tile head): ")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no tile AUC in {ev}"));
    assert!((0.8..1.0).contains(&auc), "{ev}");
    let frac = error_percent(&ev);
    // Measured 1.7 % (docs/realdata.md; 14.7 % at the extent's centre, the hull's cone under
    // the carton); the target is 8 %.
    assert!(frac < 8.0, "{ev}");
}

/// The banana of the phone capture, curved round the apple: its detections fall apart in
/// many frames (a weak stalk and tip), so each frame's ray is chosen again around where the
/// rays meet, not only around the hull's centre (10.5 % of its size from where the
/// rectangles put it when chosen once; docs/realdata.md).
#[test]
fn the_banana_is_located_within_the_target_from_three_labelled_frames() {
    let Some(r) = realdata() else { return };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let nerf = r.join("fruit/transforms.json");
    let import = |labels: &str, out: &str| {
        let o = d.join(out);
        let lab = repo_dir().join("recordings/realdata/fruit").join(labels);
        ok(&objloc(
            &[
                "record",
                "import",
                "--nerf",
                p(&nerf),
                "--labels",
                p(&lab),
                "-o",
                p(&o),
            ],
            &[],
        ));
        o
    };
    let train = import("train-labels.csv", "train.mcap");
    let tour = import("labels.csv", "tour.mcap");
    let model = d.join("banana.json");
    ok(&objloc(
        &[
            "train",
            p(&train),
            "--object",
            "banana",
            "-o",
            p(&model),
            "--no-rerun",
        ],
        &[],
    ));
    let report = d.join("r.json");
    let out = fuse_with_defaults(&tour, &model, &report);
    let rep = json(&report);
    assert_eq!(rep["objects"].as_array().unwrap().len(), 1, "{out}");
    assert!(rep["objects"][0]["from_detections"].is_object(), "{out}");
    // The first choice, around the hull's centre, did not stand, and both say so.
    assert!(
        rep["objects"][0]["from_detections"]["rechosen"].as_u64() >= Some(1),
        "{out}"
    );
    assert!(out.contains("its rays chosen again"), "{out}");
    let ev = ok(&objloc(
        &[
            "eval",
            p(&tour),
            "--report",
            p(&report),
            "--object",
            "banana",
        ],
        &[],
    ));
    // Measured 79 of 81 and 6.9 %; the targets are 95 % and 8 %.
    let inside: u32 = ev
        .split("inside the rectangle in ")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no rectangle count in {ev}"));
    assert!(inside >= 77, "{ev}");
    assert!(ev.contains(&format!("{inside} of 81 frames")), "{ev}");
    let frac = error_percent(&ev);
    assert!(frac < 8.0, "{ev}");
}
