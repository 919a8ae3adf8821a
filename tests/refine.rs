//! Pose refinement at the process boundary: sessions recorded with a known turn bias (the
//! robot turns 3 % more than its odometry says, and nothing else is noisy) and with exact
//! odometry, fused with and without `--refine-poses`, scored by `objloc eval --json`.
//!
//! Refinement runs as shipped (objects and floor) and with `--no-floor` (objects only).
//! Tolerances (docs/fuser.md has the measurements behind them):
//!
//! * turn bias, objects and floor: the chair within 0.06 m and the refined ATE below 0.08 m
//!   (measured 0.029 and 0.035 m; 0.175 m and ATE 0.256 m without refinement);
//! * turn bias, objects only: the chair within 0.12 m with at least a quarter of the error
//!   gone (measured 0.103 m) and the ATE below odometry's;
//! * exact odometry, objects only: no pose moves more than 0.03 m or 1.5 degrees (measured:
//!   no correction passes the significance threshold, so nothing moves);
//! * exact odometry, objects and floor: no pose moves more than 0.06 m or 1.5 degrees
//!   (measured 0.048 m and 0.6 degrees: a forward-looking camera pins the floor around the
//!   object better than its own position, so a frame can pivot a fraction of a degree about
//!   the floor 3 m ahead, moving the robot a few centimetres and the rays through the
//!   object hardly at all); in both, the chair is not worse than without refinement.
//!
//! Invariants: every test writes into its own temporary directory; the model is trained by
//! the binary from recordings/chair-train.mcap.

mod common;

use std::f64::consts::PI;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use common::pyenv::repo_dir;
use serde_json::Value;

fn objloc(args: &[&str], envs: &[(&str, &str)]) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_objloc"));
    cmd.current_dir(repo_dir()).args(args);
    for (k, v) in envs {
        cmd.env(k, v);
    }
    cmd.output().expect("run objloc")
}

fn ok(out: &Output) -> String {
    assert!(
        out.status.success(),
        "exit {:?}\n--- stdout\n{}\n--- stderr\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn p(path: &Path) -> &str {
    path.to_str().expect("utf-8 temp path")
}

fn json(path: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(path).expect("read")).expect("JSON")
}

/// The chair tour of the shipped recordings (seed 2) with no random speed noise and the
/// given turn bias.
fn record(dir: &Path, turn_bias: &str) -> PathBuf {
    let out = dir.join(format!("tour{turn_bias}.mcap"));
    ok(&objloc(
        &[
            "record",
            "sim",
            "--scene",
            "chair",
            "--kind",
            "tour",
            "--seed",
            "2",
            "--speed-noise",
            "0,0",
            "--turn-bias",
            turn_bias,
            "-o",
            p(&out),
        ],
        &[],
    ));
    out
}

fn train(dir: &Path) -> PathBuf {
    let model = dir.join("chair.json");
    ok(&objloc(
        &[
            "train",
            "recordings/chair-train.mcap",
            "-o",
            p(&model),
            "--save",
            p(&dir.join("train.rrd")),
        ],
        &[],
    ));
    model
}

/// How a session is fused.
#[derive(Clone, Copy, PartialEq)]
enum Mode {
    Odometry,
    Refined,
    RefinedNoFloor,
}

/// Fuses `session` and returns the report and its evaluation.
fn fuse_and_eval(session: &Path, model: &Path, mode: Mode, threads: &str) -> (Value, Value) {
    let name = format!(
        "{}-{}-{threads}",
        session.file_stem().unwrap().to_string_lossy(),
        match mode {
            Mode::Odometry => "odometry",
            Mode::Refined => "refined",
            Mode::RefinedNoFloor => "refined-no-floor",
        }
    );
    let report = session.with_file_name(format!("{name}.json"));
    let mut args = vec![
        "fuse",
        p(session),
        "--model",
        p(model),
        "--report",
        p(&report),
    ];
    match mode {
        Mode::Odometry => args.push("--no-refine-poses"),
        Mode::Refined => args.push("--refine-poses"),
        Mode::RefinedNoFloor => args.extend(["--refine-poses", "--no-floor"]),
    }
    ok(&objloc(&args, &[("RAYON_NUM_THREADS", threads)]));
    let out = ok(&objloc(
        &["eval", p(session), "--report", p(&report), "--json"],
        &[],
    ));
    let evals: Value = serde_json::from_str(&out).expect("eval JSON");
    (json(&report), evals[0].clone())
}

fn chair_error(eval: &Value) -> f64 {
    let m = eval["matches"].as_array().expect("matches");
    assert_eq!(m.len(), 1, "{eval}");
    assert!(eval["spurious"].as_array().unwrap().is_empty(), "{eval}");
    m[0]["error_m"].as_f64().unwrap()
}

fn ate(eval: &Value) -> (f64, f64) {
    let t = &eval["trajectory"];
    (
        t["odometry_ate_m"].as_f64().unwrap(),
        t["fused_ate_m"].as_f64().unwrap(),
    )
}

#[test]
fn refinement_corrects_a_known_turn_bias() {
    let dir = tempfile::tempdir().unwrap();
    let model = train(dir.path());
    let tour = record(dir.path(), "0.03");
    let (_, plain) = fuse_and_eval(&tour, &model, Mode::Odometry, "2");
    let (report, refined) = fuse_and_eval(&tour, &model, Mode::Refined, "2");
    let (_, objects_only) = fuse_and_eval(&tour, &model, Mode::RefinedNoFloor, "2");
    let e_plain = chair_error(&plain);
    assert!(e_plain > 0.15, "the bias should hurt: {e_plain}");
    let (odom_ate, refined_ate) = ate(&refined);
    let e_refined = chair_error(&refined);
    assert!(
        e_refined < 0.06 && refined_ate < 0.08,
        "objects and floor: chair {e_refined} m, ATE {refined_ate} m (odometry {odom_ate} m)"
    );
    let e_objects = chair_error(&objects_only);
    let (_, objects_ate) = ate(&objects_only);
    assert!(
        e_objects < 0.12 && e_objects < 0.75 * e_plain && objects_ate < odom_ate,
        "objects only: chair {e_objects} m (plain {e_plain}), ATE {objects_ate} m (odometry {odom_ate} m)"
    );
    assert_eq!(refined["poses"], "refined");
    // The report carries each frame's correction; the first frame anchors the frame of
    // reference; the second has no landmark yet (one view places none) but the floor of the
    // first; later ones have both, and most of them move (the bias turns every frame
    // further off).
    let frames = report["per_frame"].as_array().unwrap();
    assert!(frames[0]["correction"].is_null());
    assert_eq!(frames[1]["correction"]["anchors"], 0);
    assert!(frames[1]["correction"]["floor_cells"].as_u64().unwrap() > 100);
    assert!(
        frames[2..].iter().all(|f| {
            f["correction"]["anchors"].as_u64().unwrap() >= 1
                && f["correction"]["floor_cells"].as_u64().unwrap() > 100
        }),
        "{frames:?}"
    );
    let applied = frames
        .iter()
        .filter(|f| f["correction"]["applied"] == true)
        .count();
    assert!(applied >= 4, "{applied} corrections applied: {frames:?}");
    // Same inputs, another thread count: the same refined report.
    let (again, _) = fuse_and_eval(&tour, &model, Mode::Refined, "1");
    assert_eq!(again["per_frame"], report["per_frame"]);
    assert_eq!(again["grid"]["sha256"], report["grid"]["sha256"]);
}

/// Largest position (m) and heading (degrees) difference between the poses a report fused
/// with and /odom.
fn largest_move(report: &Value) -> (f64, f64) {
    let (mut moved, mut turned) = (0.0f64, 0.0f64);
    for f in report["per_frame"].as_array().unwrap() {
        let pos = |k: &str| -> Vec<f64> {
            f[k].as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect()
        };
        let (a, b) = (pos("position_m"), pos("odom_position_m"));
        moved = moved.max((a[0] - b[0]).hypot(a[1] - b[1]));
        let d = f["yaw_rad"].as_f64().unwrap() - f["odom_yaw_rad"].as_f64().unwrap();
        turned = turned.max(((d + PI).rem_euclid(2.0 * PI) - PI).to_degrees().abs());
    }
    (moved, turned)
}

#[test]
fn refinement_leaves_exact_odometry_within_tolerance() {
    let dir = tempfile::tempdir().unwrap();
    let model = train(dir.path());
    let tour = record(dir.path(), "0");
    let (_, plain) = fuse_and_eval(&tour, &model, Mode::Odometry, "2");
    let e_plain = chair_error(&plain);
    // Measured 0.103 m (the mass centroid: 0.081 m; the paper's replay blurs the belief after
    // every command even when odometry is exact, and the extent's centre follows the blur):
    // what is left is the classifier's and the fusion's, which refinement must not make worse
    // (refined: 0.012 m).
    assert!(e_plain < 0.12, "{e_plain}");
    // Odometry is the truth here: every refined pose is compared with it.
    for (mode, max_m) in [(Mode::RefinedNoFloor, 0.03), (Mode::Refined, 0.06)] {
        let (report, refined) = fuse_and_eval(&tour, &model, mode, "2");
        let (moved, turned) = largest_move(&report);
        assert!(
            moved < max_m && turned < 1.5,
            "{}: moved {moved} m, turned {turned} deg",
            report["options"]["refine_floor"]
        );
        let e_refined = chair_error(&refined);
        assert!(e_refined < e_plain + 0.02, "{e_refined} vs {e_plain}");
    }
}
