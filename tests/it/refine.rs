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
//! * repeating floor (0.6 m checkers), exact odometry, default options: the fused ATE at
//!   most 0.02 m (/odom's is 0; measured 0.000 m with the two seeds of
//!   scripts/measure_sessions.py's repeating set, the floor dropped as not fitting);
//! * the independent renderer's sessions (`../shared/foreign`, skipped where absent), default
//!   options: every frame after the first carries a verdict, a rollback happens exactly when
//!   the rule says, and at least 9 of the 12 tours have the right count with every object
//!   within 0.12 m (measured 9: the 5 %/3 % kettle tours and the 5 %/3 % two-vases seed-0 tour
//!   miss; docs/fuser.md).
//!
//! Invariants: every test writes into its own temporary directory; the model is trained by
//! the binary from recordings/chair-train.mcap (the foreign test from each scene's own
//! training session).

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use serde_json::{Value, json};

use crate::common::{json, objloc, ok, p, repo_dir, train};

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
    let flags: &[&str] = match mode {
        Mode::Odometry => &["--no-refine-poses"],
        Mode::Refined => &["--refine-poses"],
        Mode::RefinedNoFloor => &["--refine-poses", "--no-floor"],
    };
    let (report, eval, _) = fuse_then_eval(
        session,
        model,
        &report,
        flags,
        &[("RAYON_NUM_THREADS", threads)],
    );
    (report, eval)
}

/// `objloc fuse SESSION --model MODEL --report REPORT FLAGS...` in the environment `envs`,
/// then `objloc eval` of the report: (report, the session's evaluation, fuse's stdout).
fn fuse_then_eval(
    session: &Path,
    model: &Path,
    report: &Path,
    flags: &[&str],
    envs: &[(&str, &str)],
) -> (Value, Value, String) {
    let mut args = vec![
        "fuse",
        p(session),
        "--model",
        p(model),
        "--report",
        p(report),
    ];
    args.extend_from_slice(flags);
    let stdout = ok(&objloc(&args, envs));
    let out = ok(&objloc(
        &["eval", p(session), "--report", p(report), "--json"],
        &[],
    ));
    let evals: Value = serde_json::from_str(&out).expect("eval JSON");
    (json(report), evals[0].clone(), stdout)
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
    let (objects_report, objects_only) = fuse_and_eval(&tour, &model, Mode::RefinedNoFloor, "2");
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
    // The objects alone see the bias as bearing errors: the trajectory improves, the chair
    // hardly (measured 2026-12-03: 0.169 m against 0.166 m plain, ATE 0.164 against 0.256 m;
    // 0.168 against 0.175 m before the extent's quantiles were interpolated, and 0.103 m with
    // the refinement before the total gate and the higher MIN_GAIN, docs/fuser.md). Within
    // a quarter of a cell of the plain replay, not better: what one object cannot observe.
    assert!(
        e_objects <= e_plain + 0.01 && objects_ate < odom_ate,
        "objects only: chair {e_objects} m (plain {e_plain}), ATE {objects_ate} m (odometry {odom_ate} m)"
    );
    // With the floor behind most frames the smoother's poses agree with and without the
    // odometry's scale errors among the unknowns, and are kept; objects only, the two
    // solutions put the chair 0.30 m apart (0.33 m off without the scales, 0.03 m with
    // them), so the filter's poses stand (docs/fuser.md, "A smoother over the whole replay").
    assert_eq!(refined["poses"], "refined, smoothed over the whole replay");
    let objects_smoothing = &objects_report["refinement"]["smoothing"];
    assert_eq!(
        objects_smoothing["kept"],
        json!(false),
        "{objects_smoothing}"
    );
    // Rejected by the calibration check, which needs no grid: the frames were not fused
    // again at the smoothed poses, so there is no second count.
    assert!(
        objects_smoothing["calibration_disagreement_m"]
            .as_f64()
            .unwrap()
            > 0.05,
        "{objects_smoothing}"
    );
    assert_eq!(
        objects_smoothing["objects"],
        json!([1, null]),
        "{objects_smoothing}"
    );
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
    // Every correction had the floor behind it: none rests on the detections alone. Objects
    // only, every applied correction does, and the check lists exactly those frames.
    assert_eq!(report["refinement"]["detections_only"], json!([]));
    let applied_at: Vec<u64> = objects_report["per_frame"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|f| f["correction"]["applied"] == true)
        .map(|f| f["index"].as_u64().unwrap())
        .collect();
    assert!(!applied_at.is_empty(), "{objects_report}");
    assert_eq!(
        objects_report["refinement"]["detections_only"],
        json!(applied_at)
    );
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

/// Speed noises set far wider than the robot's (5 %/3 % typed as 0.05/0.03 instead of the
/// 0.015/0.009 of a 0.3 m/s, 0.3 rad/s robot): the search then reaches poses that move the
/// frame's floor off the map, where it scores as an average fit. Before the floor had to keep
/// half its overlap, frame 1 of the shipped drift tour jumped 1.5 m on one floor cell, the
/// poses ended 4.9 m and 37 degrees from /odom, and the chair was found 2.3 m away, all
/// approved by the end check. Measured now 0.65 m at most and the chair within 0.06 m.
#[test]
fn wide_speed_noises_do_not_move_frames_off_the_floor_map() {
    let dir = tempfile::tempdir().unwrap();
    let model = train(dir.path());
    let session = repo_dir().join("recordings/chair-tour-drift.mcap");
    let report = dir.path().join("wide.json");
    ok(&objloc(
        &[
            "fuse",
            p(&session),
            "--model",
            p(&model),
            "--report",
            p(&report),
            "--no-rerun",
            "--sigma-v",
            "0.05",
            "--sigma-w",
            "0.03",
        ],
        &[],
    ));
    let out = ok(&objloc(
        &["eval", p(&session), "--report", p(&report), "--json"],
        &[],
    ));
    let evals: Value = serde_json::from_str(&out).expect("eval JSON");
    let e = chair_error(&evals[0]);
    assert!(e < 0.1, "chair {e} m off");
    let (moved, _) = largest_move(&json(&report));
    assert!(moved < 1.0, "a pose moved {moved} m from /odom");
}

/// Exact odometry over a checkered floor (a repeating pattern the floor term could lock onto
/// a period off): refinement must leave the trajectory where /odom has it.
#[test]
fn a_repeating_floor_does_not_move_exact_odometry() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("chair.json");
    let scene = repo_dir().join("scripts/heldout/chair-checker-floor.json");
    let record = |kind: &str, seed: &str, extra: &[&str]| {
        let out = dir.path().join(format!("{kind}.mcap"));
        crate::common::record_scene_file(&scene, kind, seed, &out, extra);
        out
    };
    let train_session = record("train", "11", &[]);
    ok(&objloc(
        &["train", p(&train_session), "-o", p(&model), "--no-rerun"],
        &[],
    ));
    let tour = record("tour", "31", &["--speed-noise", "0,0"]);
    let (report, eval) = fuse_and_eval(&tour, &model, Mode::Refined, "2");
    let (odom_ate, fused_ate) = ate(&eval);
    assert!(odom_ate < 1e-9, "exact odometry: {odom_ate}");
    assert!(
        fused_ate <= odom_ate + 0.02,
        "fused ATE {fused_ate} m: {report:?}"
    );
}

/// Issue #19's bin on a shelf in our simulator, its 5 %/3 % seed-21 tour: 8 stops on a 1.6 m
/// circle, a table hiding the floor. The filter's landmark comes from the first two views and
/// carries frame 1's odometry error; its replay is rolled back to /odom, the bin 0.38 m off.
/// The smoother over the whole replay places it within 0.05 m (measured 0.018 m; docs/fuser.md,
/// "A smoother over the whole replay"), and `--no-smooth` keeps the filter's result.
#[test]
fn the_smoother_places_the_bin_the_filter_loses_on_a_small_circle() {
    let (dir, tour, model) = trained_tour("bin-on-shelf", "21", &[]);
    let fuse = |extra: &[&str]| {
        let report = dir.path().join(format!("r{}.json", extra.len()));
        fuse_in_room(&tour, &model, &report, extra)
    };
    let (report, eval, stdout) = fuse(&[]);
    let sm = &report["refinement"]["smoothing"];
    assert_eq!(sm["kept"], json!(true), "{sm}");
    assert_eq!(sm["objects"], json!([1, 1]), "{sm}");
    assert!(
        stdout.contains("smoothed over the whole replay: "),
        "{stdout}"
    );
    let e = chair_error(&eval);
    assert!(e < 0.05, "bin {e} m off, smoothed");
    assert!(
        eval["poses"]
            .as_str()
            .is_some_and(|s| s.contains("smoothed")),
        "{eval}"
    );
    let (report, eval, _) = fuse(&["--no-smooth"]);
    assert!(report["refinement"].get("smoothing").is_none(), "{report}");
    assert_eq!(report["refinement"]["rolled_back"], json!(true));
    let e = chair_error(&eval);
    assert!(
        e > 0.3,
        "bin {e} m off with the filter alone (measured 0.383)"
    );
}

/// Records a held-out scene's training session (seed 11) and its 5 %/3 % tour of `seed`
/// (with `extra` recording flags) in a fresh directory, and trains on the first: (the
/// directory, the tour, the model).
fn trained_tour(scene: &str, seed: &str, extra: &[&str]) -> (tempfile::TempDir, PathBuf, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let scene = repo_dir().join(format!("scripts/heldout/{scene}.json"));
    let train_session = dir.path().join("train.mcap");
    crate::common::record_scene_file(&scene, "train", "11", &train_session, &[]);
    let tour = dir.path().join("tour.mcap");
    let mut args = vec!["--speed-noise", "0.05,0.03"];
    args.extend_from_slice(extra);
    crate::common::record_scene_file(&scene, "tour", seed, &tour, &args);
    let model = dir.path().join("model.json");
    ok(&objloc(
        &["train", p(&train_session), "-o", p(&model), "--no-rerun"],
        &[],
    ));
    (dir, tour, model)
}

/// Fuses `tour` in the simulated room's bounds with default options and `extra` flags, and
/// evaluates it: (report, eval, stdout).
fn fuse_in_room(
    tour: &Path,
    model: &Path,
    report: &Path,
    extra: &[&str],
) -> (Value, Value, String) {
    let mut flags = vec!["--no-rerun", "--bounds=-3.5,-3.5,0,3.5,3.5,2.5"];
    flags.extend_from_slice(extra);
    fuse_then_eval(tour, model, report, &flags, &[])
}

/// The two-mugs approach scene's 5 %/3 % tour of `seed` (9 stops), fused with default
/// options: (report, eval, stdout).
fn mugs_approach_5_3(seed: &str) -> (Value, Value, String) {
    let (dir, tour, model) = trained_tour("two-mugs-approach", seed, &["--stops", "9"]);
    fuse_in_room(&tour, &model, &dir.path().join("tour.json"), &[])
}

/// The ratios (refined over /odom) of the rays' mean chi-square and of the floor's
/// disagreement in a report's refinement check.
fn check_ratios(chk: &Value) -> (f64, f64) {
    let chi2 = |k: &str| chk[k]["mean_chi2"].as_f64().unwrap();
    let f = &chk["floor_disagreement"];
    (
        chi2("refined_rays") / chi2("odometry_rays"),
        f[0].as_f64().unwrap() / f[1].as_f64().unwrap(),
    )
}

/// After a rollback (and the smoother, which may follow it) the trajectory is /odom's.
fn assert_rolled_back_to_odom(report: &Value, eval: &Value, stdout: &str, reason: &str) {
    let chk = &report["refinement"];
    assert_eq!(chk["rolled_back"], json!(true), "{chk}");
    assert!(stdout.contains("ROLLED BACK to /odom"), "{stdout}");
    let why = chk["reason"].as_str().unwrap_or_default();
    assert!(why.contains(reason), "{chk}");
    let (odom_ate, fused_ate) = ate(eval);
    assert!(
        (fused_ate - odom_ate).abs() < 0.05,
        "{fused_ate} m against /odom's {odom_ate} m"
    );
}

/// Two mugs reached after a 3 m approach, 5 %/3 % speed noise, tour seed 6: the refined
/// replay explains both the rays (+4.0 %) and the floor (+4.4 %) worse than /odom, each within
/// the 5 % tolerance, and its trajectory is 0.36 m off against /odom's 0.13 m. Together the
/// two are beyond it, so the replay is rolled back and says why (docs/fuser.md, "Two small
/// signals that agree"): /odom's result, not a worse one presented as a correction.
#[test]
fn a_replay_both_signals_call_a_little_worse_is_rolled_back() {
    let (report, eval, stdout) = mugs_approach_5_3("6");
    assert_rolled_back_to_odom(&report, &eval, &stdout, "both the detections and the floor");
    let (rays, floor) = check_ratios(&report["refinement"]);
    assert!(
        rays > 1.0 && rays <= 1.05 && floor > 1.0 && floor <= 1.05,
        "{rays} {floor}"
    );
    assert!(rays * floor > 1.05, "{rays} {floor}");
}

/// The same scene's seed-4 tour: all six applied corrections rest on one mug's rays alone (the
/// floor never fits), each turning the robot the same way; the rays then meet far better than
/// at /odom (0.52 against 7.65) because the poses were fitted to them, while the floor, which
/// none of them used, disagrees 6.7 % more and the trajectory is 0.395 m off against 0.144 m.
/// Rays most corrections were fitted to cannot overrule the floor: rolled back.
#[test]
fn rays_the_corrections_were_fitted_to_cannot_overrule_the_floor() {
    let (report, eval, stdout) = mugs_approach_5_3("4");
    assert_rolled_back_to_odom(
        &report,
        &eval,
        &stdout,
        "most corrections were fitted to them",
    );
    let (rays, floor) = check_ratios(&report["refinement"]);
    assert!(rays < 1.0 / 1.05 && floor > 1.05, "{rays} {floor}");
    let frames = report["per_frame"].as_array().unwrap();
    let alone = frames
        .iter()
        .filter(|f| f["correction"]["outcome"] == "rolled-back")
        .count();
    assert!(
        alone >= 4,
        "the corrections are marked rolled back: {frames:?}"
    );
    // The smoother, started from /odom after the rollback, finds a second object and is not
    // kept: what stands is /odom's poses, and stdout says so, not "the filter's".
    assert!(
        stdout.contains("of /odom's poses, so they stand"),
        "{stdout}"
    );
}

/// Where the foreign sessions are (`../shared/foreign/sessions` beside the checkout).
fn foreign_dir() -> Option<PathBuf> {
    let d = repo_dir().join("../shared/foreign/sessions");
    d.join("manifest.json").exists().then_some(d)
}

#[test]
fn refinement_on_another_renderers_rooms_is_checked_and_rolled_back_by_its_rule() {
    let Some(dir_in) = foreign_dir() else {
        crate::common::say_skipped("no ../shared/foreign/sessions on this machine");
        return;
    };
    let manifest = json(&dir_in.join("manifest.json"));
    let sessions = manifest["sessions"].as_array().unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let mut good = 0;
    let mut tours = 0;
    let mut unverified = 0;
    for s in sessions.iter().filter(|s| s["kind"] == "tour") {
        let file = s["file"].as_str().unwrap();
        let train_file = format!("{}-train-s{}.mcap", s["scene"].as_str().unwrap(), s["seed"]);
        let model = tmp.path().join(train_file.replace(".mcap", ".json"));
        if !model.exists() {
            ok(&objloc(
                &[
                    "train",
                    p(&dir_in.join(&train_file)),
                    "-o",
                    p(&model),
                    "--no-rerun",
                ],
                &[],
            ));
        }
        let b = &s["room_bounds"];
        let bounds: Vec<String> = b["min"]
            .as_array()
            .unwrap()
            .iter()
            .chain(b["max"].as_array().unwrap())
            .map(|v| v.to_string())
            .collect();
        let rep = tmp.path().join(file.replace(".mcap", ".json"));
        let out = ok(&objloc(
            &[
                "fuse",
                p(&dir_in.join(file)),
                "--model",
                p(&model),
                &format!("--bounds={}", bounds.join(",")),
                "--report",
                p(&rep),
                "--no-rerun",
            ],
            &[],
        ));
        let report = json(&rep);
        let frames = report["per_frame"].as_array().unwrap();
        assert!(frames[0]["correction"].is_null());
        assert!(
            frames[1..]
                .iter()
                .all(|f| f["correction"]["outcome"].is_string()),
            "{file}: {frames:?}"
        );
        // The rule: one kind of evidence worse (by 5 %) at the refined poses, the other no
        // better, or both worse and together (the product of the ratios) by 5 %; without the
        // floor to the end, the rays decide.
        let chk = &report["refinement"];
        let (r, o) = (
            chk["refined_rays"]["mean_chi2"].as_f64().unwrap(),
            chk["odometry_rays"]["mean_chi2"].as_f64().unwrap(),
        );
        let floor = chk["floor_disagreement"]
            .as_array()
            .map(|a| (a[0].as_f64().unwrap(), a[1].as_f64().unwrap()));
        // Rays that more than half the applied corrections (accepted, or rolled back since)
        // were fitted to alone cannot overrule the floor.
        let was_applied = |f: &&Value| {
            f["correction"]["outcome"] == "accepted" || f["correction"]["outcome"] == "rolled-back"
        };
        let applied: Vec<&Value> = frames.iter().filter(was_applied).collect();
        let fitted = applied
            .iter()
            .filter(|f| f["correction"]["floor_cells"] == 0)
            .count();
        let rays_fitted = 2 * fitted > applied.len();
        let rays_worse = r > o * 1.05 + 1e-9;
        let rays_better = !rays_fitted && o > r * 1.05 + 1e-9;
        let (fw, fb) = floor.map_or((false, false), |(fr, fo)| (fr > fo * 1.05, fo > fr * 1.05));
        let moved = frames.iter().any(|f| {
            f["correction"]["outcome"] == "accepted" || f["correction"]["outcome"] == "rolled-back"
        });
        let both = floor.is_some_and(|(fr, fo)| fr > fo && r > o && fr * r > fo * o * 1.05);
        let expect = moved && ((rays_worse && !fb) || (fw && !rays_better) || both);
        assert_eq!(chk["rolled_back"], expect, "{file}: {chk}");
        // Corrections that rest on the detections alone are listed, and said to be unchecked.
        let alone: Vec<u64> = frames
            .iter()
            .filter(|f| f["correction"]["applied"] == true && f["correction"]["floor_cells"] == 0)
            .map(|f| f["index"].as_u64().unwrap())
            .collect();
        if expect {
            assert_eq!(chk["detections_only"], json!([]), "{file}: {chk}");
            assert!(!out.contains("UNVERIFIED:"), "{file}: {out}");
        } else {
            assert_eq!(chk["detections_only"], json!(alone), "{file}: {chk}");
            assert_eq!(
                out.contains("UNVERIFIED:"),
                !alone.is_empty(),
                "{file}: {out}"
            );
            unverified += usize::from(!alone.is_empty());
        }
        assert_eq!(
            out.contains("ROLLED BACK to /odom"),
            expect,
            "{file}: {out}"
        );
        let eval = ok(&objloc(
            &["eval", p(&dir_in.join(file)), "--report", p(&rep), "--json"],
            &[],
        ));
        let e: Value = serde_json::from_str(&eval).unwrap();
        let e = &e[0];
        let within = e["matches"]
            .as_array()
            .unwrap()
            .iter()
            .all(|m| m["error_m"].as_f64().unwrap() <= 0.12);
        if within
            && e["missed"].as_array().unwrap().is_empty()
            && e["spurious"].as_array().unwrap().is_empty()
        {
            good += 1;
        }
        tours += 1;
    }
    assert_eq!(tours, 12);
    // Measured 2026-12-04: 7 of the 12 tours have such frames (the kettle s1's, the vases'
    // and the duck's); the replay is deterministic, so any other count is a change.
    assert_eq!(
        unverified, 7,
        "tours with corrections from the detections alone"
    );
    assert!(
        good >= 9,
        "{good} of {tours} foreign tours with the right count, every object within 0.12 m"
    );
}
