//! Training in Rerun: the decision tree as a graph (split feature and threshold at inner
//! nodes, probability and counts at leaves; a forest's first tree, its maps the forest's mean)
//! and the labelled training frames with their
//! rectangles and predicted tile probabilities: the tile head's (the fuser's evidence) and,
//! when the model has one, the region head's (`predict`'s probs.npy).
//!
//! Invariants: nodes are logged in index order with ids `n<index>`; frames on the `frame`
//! timeline in session order (sessions in command-line order) and on `log_time` with their
//! MCAP log time. No clock, no randomness.

use rerun::RecordingStream;

use super::images::{depth_image, encoded_jpeg, log_frame_and_probs};
use super::{TIMELINE_FRAME, TIMELINE_LOG_TIME, VizError, log_err};
use objloc_core::learn::dataset::LoadedSession;
use objloc_core::learn::model::Model;
use objloc_core::out::view::viridis;

/// Node labels of the tree, index order: "bin 12 (hue ...) > 0.0312?" at inner nodes,
/// "p 0.873, 120/137" at leaves.
pub fn node_labels(model: &Model) -> Vec<String> {
    model
        .tree
        .nodes
        .iter()
        .map(|n| match &n.split {
            Some(s) => format!(
                "{} > {:.4}?\nn {}",
                model.describe_feature(s.feature as usize),
                s.threshold,
                n.n_train
            ),
            None => format!("p {:.3}\n{}/{}", n.p, n.pos_train, n.n_train),
        })
        .collect()
}

/// Edges parent -> child, the `> threshold` (right) child labelled first... in index order.
pub fn edges(model: &Model) -> Vec<(String, String)> {
    let mut out = Vec::new();
    for (i, n) in model.tree.nodes.iter().enumerate() {
        if let Some(s) = &n.split {
            out.push((format!("n{i}"), format!("n{}", s.left)));
            out.push((format!("n{i}"), format!("n{}", s.right)));
        }
    }
    out
}

/// Logs the tree (static) under `tree`.
pub fn log_tree(rec: &RecordingStream, model: &Model) -> Result<(), VizError> {
    let ids: Vec<String> = (0..model.tree.nodes.len())
        .map(|i| format!("n{i}"))
        .collect();
    let colors: Vec<rerun::Color> = model
        .tree
        .nodes
        .iter()
        .map(|n| {
            if n.split.is_some() {
                rerun::Color::from_rgb(180, 180, 180)
            } else {
                let [r, g, b] = viridis(n.p as f32);
                rerun::Color::from_rgb(r, g, b)
            }
        })
        .collect();
    rec.log_static(
        "tree",
        &rerun::GraphNodes::new(ids)
            .with_labels(node_labels(model))
            .with_colors(colors),
    )
    .map_err(log_err)?;
    rec.log_static(
        "tree",
        &rerun::GraphEdges::new(edges(model)).with_directed_edges(),
    )
    .map_err(log_err)?;
    Ok(())
}

/// Logs every labelled frame of `sessions` with its rectangles and the model's tile
/// probabilities, one step of `frame` each: a person's rectangles (those of the frames
/// `labelled`, session by session) in green, those the located object gave the other frames
/// (`train`'s second round) in orange.
pub fn log_training_frames(
    rec: &RecordingStream,
    model: &Model,
    sessions: &[LoadedSession],
    labelled: &[LoadedSession],
) -> Result<(), VizError> {
    let mut index = 0i64;
    for (i, s) in sessions.iter().enumerate() {
        let by_person: std::collections::BTreeSet<i64> = labelled
            .get(i)
            .map(|l| l.frames.iter().map(|f| f.stamp_ns).collect())
            .unwrap_or_default();
        for f in &s.frames {
            let Some(regions) = &f.regions else { continue };
            let person = by_person.contains(&f.stamp_ns);
            rec.set_time(
                TIMELINE_LOG_TIME,
                rerun::TimeCell::from_timestamp_nanos_since_epoch(
                    f.log_time_ns.min(i64::MAX as u64) as i64,
                ),
            );
            rec.set_time_sequence(TIMELINE_FRAME, index);
            index += 1;
            log_frame_and_probs(
                rec,
                "train/frame",
                &encoded_jpeg(&f.image)?,
                (f.image.width, f.image.height),
                &model.predict(&f.image),
            )?;
            if let Some(region) = &model.region {
                let p = region.predict(&f.image);
                rec.log(
                    "train/frame/region_probability",
                    &depth_image(&p, f.image.width, f.image.height),
                )
                .map_err(log_err)?;
            }
            rec.log(
                "train/frame/labels",
                &rerun::Boxes2D::from_mins_and_sizes(
                    regions
                        .iter()
                        .map(|r| [r.x_offset as f32, r.y_offset as f32]),
                    regions.iter().map(|r| [r.width as f32, r.height as f32]),
                )
                .with_colors([if person {
                    rerun::Color::from_rgb(0, 255, 0)
                } else {
                    rerun::Color::from_rgb(255, 160, 0)
                }])
                .with_draw_order(20.0),
            )
            .map_err(log_err)?;
            rec.log(
                "train/session",
                &rerun::TextDocument::new(format!(
                    "{} ({} label rectangles{})",
                    s.path.display(),
                    regions.len(),
                    if person {
                        ""
                    } else {
                        ", drawn by the object the first round's replay located"
                    }
                )),
            )
            .map_err(log_err)?;
        }
    }
    Ok(())
}
