//! Pose refinement at the process boundary: sessions recorded with a known turn bias (the
//! robot turns 3 % more than its odometry says, and nothing else is noisy) and with exact
//! odometry, fused with and without `--refine-poses`, scored by `objloc eval --json`.
//!
//! Tolerances (docs/fuser.md has the measurements behind them): with the bias, the chair is
//! found within 0.12 m and with at least a quarter of the error gone (measured 0.101 m,
//! 0.164 m without refinement) and the refined trajectory's ATE is below odometry's; with
//! exact odometry, refinement moves no pose more than 0.03 m or 1.5 degrees (measured: no
//! correction passes the significance threshold, so nothing moves; with the previous
//! classifier one frame moved 0.012 m and 0.8 degrees) and does not worsen the chair.
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

/// Fuses `session` (refined or not) and returns the report and its evaluation.
fn fuse_and_eval(session: &Path, model: &Path, refine: bool, threads: &str) -> (Value, Value) {
    let name = format!(
        "{}-{}-{threads}",
        session.file_stem().unwrap().to_string_lossy(),
        if refine { "refined" } else { "odometry" }
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
    if refine {
        args.push("--refine-poses");
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

#[test]
fn refinement_corrects_a_known_turn_bias() {
    let dir = tempfile::tempdir().unwrap();
    let model = train(dir.path());
    let tour = record(dir.path(), "0.03");
    let (_, plain) = fuse_and_eval(&tour, &model, false, "2");
    let (report, refined) = fuse_and_eval(&tour, &model, true, "2");
    let (e_plain, e_refined) = (chair_error(&plain), chair_error(&refined));
    // Measured 0.164 m without and 0.101 m with refinement (docs/fuser.md). Tolerance: the
    // issue's 0.12 m for realistic noise, and at least a quarter of the error removed.
    assert!(e_plain > 0.15, "the bias should hurt: {e_plain}");
    assert!(
        e_refined < 0.12 && e_refined < 0.75 * e_plain,
        "refined error {e_refined} (plain {e_plain})"
    );
    let t = &refined["trajectory"];
    let (odom_ate, refined_ate) = (
        t["odometry_ate_m"].as_f64().unwrap(),
        t["fused_ate_m"].as_f64().unwrap(),
    );
    assert!(
        refined_ate < odom_ate,
        "ATE {refined_ate} vs odometry {odom_ate}"
    );
    assert_eq!(refined["poses"], "refined");
    // The report carries each frame's correction; the first frame anchors the frame of
    // reference, the second has no landmark yet (one view places none), later ones align,
    // and most of them move (the bias turns every frame further off).
    let frames = report["per_frame"].as_array().unwrap();
    assert!(frames[0]["correction"].is_null());
    assert_eq!(frames[1]["correction"]["anchors"], 0);
    assert!(
        frames[2..]
            .iter()
            .all(|f| f["correction"]["anchors"].as_u64().unwrap() >= 1),
        "{frames:?}"
    );
    let applied = frames
        .iter()
        .filter(|f| f["correction"]["applied"] == true)
        .count();
    assert!(applied >= 4, "{applied} corrections applied: {frames:?}");
    // Same inputs, another thread count: the same refined report.
    let (again, _) = fuse_and_eval(&tour, &model, true, "1");
    assert_eq!(again["per_frame"], report["per_frame"]);
    assert_eq!(again["grid"]["sha256"], report["grid"]["sha256"]);
}

#[test]
fn refinement_leaves_exact_odometry_within_tolerance() {
    let dir = tempfile::tempdir().unwrap();
    let model = train(dir.path());
    let tour = record(dir.path(), "0");
    let (report, refined) = fuse_and_eval(&tour, &model, true, "2");
    let (_, plain) = fuse_and_eval(&tour, &model, false, "2");
    // Odometry is the truth here: every refined pose is compared with it.
    for f in report["per_frame"].as_array().unwrap() {
        let pos = |k: &str| -> Vec<f64> {
            f[k].as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect()
        };
        let (a, b) = (pos("position_m"), pos("odom_position_m"));
        let moved = (a[0] - b[0]).hypot(a[1] - b[1]);
        let d = f["yaw_rad"].as_f64().unwrap() - f["odom_yaw_rad"].as_f64().unwrap();
        let turned = ((d + PI).rem_euclid(2.0 * PI) - PI).to_degrees().abs();
        assert!(
            moved < 0.03 && turned < 1.5,
            "frame {}: {moved} m, {turned} deg",
            f["index"]
        );
    }
    // Measured 0.081 m both without and with refinement: what is left is the classifier's
    // and the fusion's, which refinement must not make worse.
    let (e_plain, e_refined) = (chair_error(&plain), chair_error(&refined));
    assert!(e_plain < 0.1, "{e_plain}");
    assert!(e_refined < e_plain + 0.02, "{e_refined} vs {e_plain}");
}
