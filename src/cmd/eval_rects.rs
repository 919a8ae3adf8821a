//! `objloc eval` for a session without ground truth: each report's objects scored against the
//! label rectangles (triangulated centre, error as a fraction of the size, frames whose
//! rectangle contains the located centre).

use super::say;

use std::collections::BTreeMap;

use anyhow::Context;

use objloc_core::fuse::replay::load_session;
use objloc_core::io::msgs::RegionOfInterest;
use objloc_core::io::session::{SessionMsg, SessionReader};
use objloc_core::learn::model::Model;
use objloc_core::out::rects::{RectCamera, RectScore, RectView, score};

use super::eval::{Args, read_report};

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

pub fn run(reader: &SessionReader, args: &Args) -> anyhow::Result<()> {
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
    let mut scores: Vec<(String, RectScore, Option<f64>)> = Vec::new();
    for path in &args.reports {
        let report = read_report(path)?;
        let object = args.object.clone().or_else(|| {
            Model::load(std::path::Path::new(&report.model))
                .ok()
                .and_then(|m| m.metadata.object)
        });
        if let Some(o) = object.as_ref().filter(|o| !rects.contains_key(*o)) {
            let names = rects.keys().cloned().collect();
            anyhow::bail!(
                "{session}: no label rectangle names object {o:?} (the labels name: {}); pass --object NAME",
                super::names_or_none(&names)
            );
        }
        let candidates: Vec<[f64; 3]> = report.objects.iter().map(|o| o.centroid_m).collect();
        let auc = tile_auc(&report, args, object.as_deref());
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
            let mut s = score(name, &cam, &views, &candidates);
            s.object = format!("{name} ({} objects located)", candidates.len());
            scores.push((path.display().to_string(), s, auc));
        }
    }
    if args.json {
        let json: Vec<_> = scores
            .iter()
            .map(|(r, s, auc)| serde_json::json!({"report": r, "score": s, "tile_auc": auc}))
            .collect();
        say!("{}", serde_json::to_string_pretty(&json)?);
    } else {
        say!("{session}: no ground truth; scored against the label rectangles");
        for (r, s, auc) in &scores {
            print_score(r, s);
            match auc {
                Some(a) => {
                    say!("  tile ROC AUC of the fuser's evidence (the tile head): {a:.4}")
                }
                None => {
                    say!("  tile ROC AUC: n/a (the report's model file is absent or changed)")
                }
            }
        }
    }
    Ok(())
}

/// The tile ROC AUC of the report's model's tile head (the fuser's evidence) against the
/// session's rectangles of `object`; None when the model file is gone or no longer the one
/// the report was fused with, or a class is missing.
fn tile_auc(
    report: &objloc_core::out::report::Report,
    args: &Args,
    object: Option<&str>,
) -> Option<f64> {
    let path = std::path::Path::new(&report.model);
    let same = objloc_core::out::report::file_sha256(path).ok()? == report.model_sha256;
    let model = Model::load(path).ok().filter(|_| same)?;
    let topics = args.topics.topics().ok()?;
    let session =
        objloc_core::learn::dataset::load_session(&args.session, topics, object, true).ok()?;
    let pred = model.predict_session(&session, &|| {}).ok()?;
    pred.tile_labelled?.roc_auc
}

fn print_score(report: &str, s: &RectScore) {
    say!("{report}: {}", s.object);
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
