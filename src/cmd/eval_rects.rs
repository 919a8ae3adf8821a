//! `objloc eval` for a session without ground truth: each report's objects scored against the
//! label rectangles (triangulated centre, error as a fraction of the size, frames whose
//! rectangle contains the located centre).

use super::say;

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::Context;

use objloc_core::fuse::replay::load_session;
use objloc_core::io::msgs::RegionOfInterest;
use objloc_core::io::session::{SessionMsg, SessionReader};
use objloc_core::learn::model::Model;
use objloc_core::out::rects::{RectCamera, RectScore, RectView, score};
use objloc_core::out::report::{Report, file_sha256};

use super::eval::{Args, read_report_of};

/// Rectangles per object: (stamp, rectangles) in session order.
type Rects = BTreeMap<String, Vec<(i64, Vec<RegionOfInterest>)>>;

fn read_rects(reader: &SessionReader) -> anyhow::Result<Rects> {
    let mut out = Rects::new();
    for m in reader.messages() {
        if let SessionMsg::Label(l) = m.context("reading labels")?.msg
            && !l.regions.is_empty()
        {
            out.entry(l.object)
                .or_default()
                .push((l.header.stamp_ns, l.regions));
        }
    }
    Ok(out)
}

pub fn run(reader: &SessionReader, args: &Args, session_sha256: &str) -> anyhow::Result<()> {
    let session = args.session.display();
    let rects = read_rects(reader)?;
    if rects.is_empty() {
        anyhow::bail!(
            "{session}: no {} message and no label rectangles on {}: nothing to score against",
            reader.topics().ground_truth_objects,
            reader.topics().labels
        );
    }
    let data = load_session(reader).with_context(|| format!("eval {session}"))?;
    let cam = RectCamera {
        camera: data.camera,
        distortion: data.distortion,
    };
    // (report, score, tile AUC, objects the report located)
    let mut scores: Vec<(String, RectScore, Option<f64>, usize)> = Vec::new();
    for path in &args.reports {
        let report = read_report_of(path, args, session_sha256)?;
        let model = report_model(&report, path);
        let object = match (&args.object, &model) {
            (Some(o), _) => Some(o.clone()),
            (None, Some(m)) => m.metadata.object.clone(),
            (None, None) => Some(only_object(&rects, &report, path)?),
        };
        if let Some(o) = object.as_ref().filter(|o| !rects.contains_key(*o)) {
            let names = rects.keys().cloned().collect();
            anyhow::bail!(
                "{session}: no label rectangle names object {o:?} (the labels name: {}); pass --object NAME",
                super::names_or_none(&names)
            );
        }
        let candidates: Vec<[f64; 3]> = report.objects.iter().map(|o| o.centroid_m).collect();
        let auc = model
            .as_ref()
            .and_then(|m| tile_auc(m, args, object.as_deref()));
        for (name, frames) in &rects {
            if object.as_ref().is_some_and(|o| o != name) {
                continue;
            }
            let views: Vec<RectView> = frames
                .iter()
                .filter_map(|(stamp_ns, regions)| {
                    let pose = data.odom_at(*stamp_ns)? * data.mount_at(*stamp_ns).ok()?;
                    // Several rectangles of one object in a frame: the first one, the object.
                    regions.first().map(|roi| RectView {
                        stamp_ns: *stamp_ns,
                        odom_from_camera: pose,
                        roi: *roi,
                    })
                })
                .collect();
            let s = score(name, &cam, &views, &candidates);
            scores.push((path.display().to_string(), s, auc, candidates.len()));
        }
    }
    if args.json {
        let json: Vec<_> = scores
            .iter()
            .map(|(r, s, auc, n)| {
                serde_json::json!({"report": r, "score": s, "objects_located": n, "tile_auc": auc})
            })
            .collect();
        say!("{}", serde_json::to_string_pretty(&json)?);
    } else {
        say!("{session}: no ground truth; scored against the label rectangles");
        for (r, s, auc, n) in &scores {
            print_score(r, s, *n);
            match auc {
                Some(a) => {
                    say!("  tile ROC AUC of the fuser's evidence (the tile head): {a:.4}")
                }
                None => {
                    say!(
                        "  tile ROC AUC: n/a (the report's model file is absent or changed, here and beside the report)"
                    )
                }
            }
        }
    }
    Ok(())
}

/// The model the report was fused with: at the path the report names (as typed to `fuse`,
/// so relative to where it ran), else at that path or under its file name beside the report;
/// the first file whose SHA-256 is the report's `model_sha256`. None when none is.
fn report_model(report: &Report, report_path: &Path) -> Option<Model> {
    let named = Path::new(&report.model);
    let beside = report_path.parent().unwrap_or(Path::new(""));
    let mut candidates = vec![named.to_path_buf()];
    if named.is_relative() {
        candidates.push(beside.join(named));
    }
    if let Some(name) = named.file_name() {
        candidates.push(beside.join(name));
    }
    candidates.into_iter().find_map(|c| {
        let same = file_sha256(&c).ok()? == report.model_sha256;
        same.then(|| Model::load(&c).ok())?
    })
}

/// The object to score a report against when its model cannot be found: the labels' only
/// object; with several, scoring every one of them against one report's objects would
/// report errors to objects the model never looked for.
fn only_object(rects: &Rects, report: &Report, report_path: &Path) -> anyhow::Result<String> {
    let mut names = rects.keys();
    match (names.next(), names.next()) {
        (Some(only), None) => Ok(only.clone()),
        _ => anyhow::bail!(
            "{}: its model {} is not there nor beside the report (or has changed), so which object it locates is unknown; pass --object NAME (the labels name: {})",
            report_path.display(),
            report.model,
            super::names_or_none(&rects.keys().cloned().collect())
        ),
    }
}

/// The tile ROC AUC of `model`'s tile head (the fuser's evidence) against the session's
/// rectangles of `object`; None when a class is missing.
fn tile_auc(model: &Model, args: &Args, object: Option<&str>) -> Option<f64> {
    let topics = args.topics.topics().ok()?;
    let session =
        objloc_core::learn::dataset::load_session(&args.session, topics, object, true).ok()?;
    let pred = model.predict_session(&session, &|| {}).ok()?;
    pred.tile_labelled?.roc_auc
}

fn print_score(report: &str, s: &RectScore, located: usize) {
    let plural = if located == 1 { "" } else { "s" };
    say!("{report}: {} ({located} object{plural} located)", s.object);
    match &s.triangulated {
        Some(t) => say!(
            "  triangulated centre ({:.4}, {:.4}, {:.4}) from {} views wholly in view, ray residual rms {:.4} (max {:.4}), size {:.4} (session units)",
            t.center[0],
            t.center[1],
            t.center[2],
            t.views,
            t.residual_rms,
            t.residual_max,
            t.size
        ),
        None if s.frames_wholly_in_view >= 2 => say!(
            "  not triangulated: the rays through the centres of the {} rectangles wholly in view do not meet in front of the cameras (parallel, or meeting behind them: poses in OpenGL camera axes, or world-to-camera?)",
            s.frames_wholly_in_view
        ),
        None => say!("  not triangulated: fewer than 2 frames have the object wholly in view"),
    }
    match (s.located, s.error, s.error_fraction) {
        (Some(l), Some(e), Some(f)) => say!(
            "  located ({:.4}, {:.4}, {:.4}): error {e:.4} = {:.1} % of the size",
            l[0],
            l[1],
            l[2],
            f * 100.0
        ),
        (Some(l), _, _) => say!("  located ({:.4}, {:.4}, {:.4})", l[0], l[1], l[2]),
        _ => say!("  no object located"),
    }
    if let Some(f) = s.inside_fraction() {
        say!(
            "  inside the rectangle in {} of {} frames ({:.1} %)",
            s.frames_inside,
            s.frames,
            f * 100.0
        );
    }
}
