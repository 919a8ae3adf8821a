//! `train`'s second round on posed captures: the first model's own replay of each training
//! session locates the object, and up to [`MAX_VIEWS`] of the frames nobody labelled get the
//! rectangle of its cells projected into them (objloc-core's `fuse::relabel`), so the tile
//! head learns the object from every side the capture saw instead of from the three frames a
//! person drew (issue #18: "more views of the object").
//!
//! A wrong object would teach the wrong tiles, so the round runs only where every labelled
//! frame holds one rectangle (the model's object alone) and the replay finds exactly one
//! object whose projection matches each of them (IoU at least [`MIN_LABEL_IOU`]) and whose
//! centre no frame labelled as background shows; its model is kept only when its own replay
//! of every such session
//! again finds exactly one object, with its centre inside every labelled rectangle (the
//! labels are the only truth a capture has), and no farther than the first model's from the
//! centre those rectangles triangulate (`eval`'s score). Otherwise the first model stands, and
//! stdout says which and why. What these tests cannot see is a second model that is a few
//! centimetres worse by a measure the three labels do not give (measured in docs/tree.md,
//! "More views"); `--no-more-views` keeps the first round's.

use std::collections::BTreeMap;

use objloc_core::fuse::relabel::{PixelRect, camera_from_odom, iou, object_rectangle};
use objloc_core::fuse::replay::{FuseOptions, Outcome, replay};
use objloc_core::io::msgs::RegionOfInterest;
use objloc_core::io::session::{IndexScope, SessionReader, Topics};
use objloc_core::learn::dataset::{ExtraLabel, LoadedSession, load_session_with};
use objloc_core::learn::model::Model;
use objloc_core::out::rects::{RectCamera, RectView, projects_inside, score};
use objloc_core::types::lens::distorted_pixel;

/// Most frames one session adds: more cost features and fitting time in proportion and
/// repeat what the others show.
pub const MAX_VIEWS: usize = 16;

/// Least overlap of the located object's projection with each labelled rectangle (the
/// usual detection threshold): below it the replay located something else, or the labels
/// and the poses disagree.
pub const MIN_LABEL_IOU: f64 = 0.5;

/// Where the first model located the object in a session that has a round (None: no round).
pub type FirstCentre = Option<[f64; 3]>;

/// The training sessions again, each with the frames its located object labels added (or
/// as it was, when the round cannot label it), the centre the first model located in each
/// that has a round (None: no round), and one line per session saying which.
pub fn more_views(
    model: &Model,
    sessions: &[LoadedSession],
    topics: &Topics,
    object: Option<&str>,
) -> anyhow::Result<(Vec<LoadedSession>, Vec<FirstCentre>, Vec<String>)> {
    let mut out = Vec::with_capacity(sessions.len());
    let mut rounds = Vec::with_capacity(sessions.len());
    let mut lines = Vec::new();
    for s in sessions {
        let round = match locate(model, s, topics)? {
            Ok((o, worst)) => views(&o, s).map(|v| (v, worst, o.objects[0].centroid_m)),
            Err(why) => Err(why),
        };
        match round {
            Ok((extra, worst, centre)) => {
                let more = load_session_with(&s.path, topics.clone(), object, true, &extra)?;
                lines.push(format!(
                    "{}: the object its replay locates (IoU at least {worst:.2} with each labelled rectangle) labels {} more frame(s) for a second round",
                    s.path.display(),
                    more.frames.len().saturating_sub(s.frames.len())
                ));
                out.push(more);
                rounds.push(Some(centre));
            }
            Err(why) => {
                lines.push(format!(
                    "{}: no second round ({why}); the labelled frames alone",
                    s.path.display()
                ));
                out.push(s.clone());
                rounds.push(None);
            }
        }
    }
    Ok((out, rounds, lines))
}

/// Whether the second round's `model` still finds exactly one object in every session that
/// had a round (`sessions`: as the first round read them, labelled frames only; `rounds`:
/// the first model's centre in each), its centre inside every labelled rectangle and no
/// farther than the first model's from the centre the labelled rectangles triangulate (what
/// `eval` scores a capture by; [`closer_to_the_labels`]). Ok: what stdout adds about that
/// distance; Err: the line that says why not.
pub fn second_round_holds(
    model: &Model,
    sessions: &[LoadedSession],
    rounds: &[FirstCentre],
    topics: &Topics,
) -> anyhow::Result<Result<String, String>> {
    let mut said = Vec::new();
    for (s, first) in sessions
        .iter()
        .zip(rounds)
        .filter_map(|(s, r)| r.map(|c| (s, c)))
    {
        let outcome = match replay_once(model, &reopen(s, topics)?) {
            Ok(o) => o,
            Err(why) => return Ok(Err(format!("{}: with its model {why}", s.path.display()))),
        };
        for f in &s.frames {
            let labelled: Vec<&RegionOfInterest> = f.regions.iter().flatten().collect();
            if !labelled.is_empty() && !centre_inside(&outcome, f.stamp_ns, &labelled) {
                return Ok(Err(format!(
                    "{}: with its model the located centre falls outside the labelled rectangle at stamp {} ns",
                    s.path.display(),
                    f.stamp_ns
                )));
            }
        }
        match closer_to_the_labels(&outcome, s, first) {
            Ok(line) => said.push(line),
            Err(line) => return Ok(Err(format!("{}: {line}", s.path.display()))),
        }
    }
    Ok(Ok(said.join("; ")))
}

/// Whether the second model's located centre (`outcome`) is no farther than the first
/// model's (`first`) from the object's centre triangulated from the labelled rectangles of
/// `s`, said with both distances as a fraction of the object's size (Ok also when fewer than
/// two rectangles have the object wholly in view: there is nothing to compare).
///
/// Measured on sim and foreign tours taken as captures, trained on three of their own frames
/// (docs/tree.md, "No farther from the labels"): it turns away 6 of the 13 rounds that made a
/// tour worse against the 3D truth and none of the 30 that made one better; on their
/// photometrically perturbed copy 3 of 12 and 4 of 36 (the three labels triangulate worse).
fn closer_to_the_labels(
    outcome: &Outcome,
    s: &LoadedSession,
    first: [f64; 3],
) -> Result<String, String> {
    let data = &outcome.data;
    let cam = RectCamera {
        camera: data.camera,
        distortion: data.distortion,
    };
    let views: Vec<RectView> = s
        .frames
        .iter()
        .filter_map(|f| {
            let pose = camera_from_odom(data, f.stamp_ns)?;
            let roi = *f.regions.as_ref()?.first()?;
            Some(RectView {
                stamp_ns: f.stamp_ns,
                odom_from_camera: pose.inverse(),
                roi,
            })
        })
        .collect();
    // `eval`'s score of each centre alone: its distance from the triangulated centre as a
    // fraction of the object's size.
    let off = |c: [f64; 3]| {
        score("", &cam, &views, &[c])
            .error_fraction
            .map(|f| 100.0 * f)
    };
    let (Some(before), Some(after)) = (off(first), off(outcome.objects[0].centroid_m)) else {
        return Ok("(fewer than two of them hold the object wholly in view: no distance from where they put it to compare)".into());
    };
    // Two decimals: a second model a hair farther must not read as "1.2 %, farther than
    // 1.2 %".
    let at = s.path.display();
    if after <= before {
        Ok(format!(
            "and no farther from where they put it in {at} ({after:.2} % of the object's size, the first model's {before:.2} %)"
        ))
    } else {
        Err(format!(
            "with its model the located centre is {after:.2} % of the object's size from where the labelled rectangles put it, farther than the first model's {before:.2} %"
        ))
    }
}

/// The session replayed with `model`, when it finds exactly one object; or why not (said on
/// stdout: a training session need not replay, it may lack the camera or the poses).
fn replay_once(model: &Model, reader: &SessionReader) -> Result<Outcome, String> {
    let outcome = replay(reader, model, &FuseOptions::default(), &mut [])
        .map_err(|e| format!("it does not replay: {e}"))?;
    if outcome.objects.len() != 1 {
        return Err(format!(
            "the replay finds {} objects, not one",
            outcome.objects.len()
        ));
    }
    Ok(outcome)
}

/// The session's reader, opened again; failing is the outer error: `train` read the file a
/// moment ago, and stops.
fn reopen(s: &LoadedSession, topics: &Topics) -> anyhow::Result<SessionReader> {
    Ok(SessionReader::open_scoped(
        &s.path,
        topics.clone(),
        IndexScope::Roles,
    )?)
}

/// The session replayed with `model`, when every labelled frame holds one rectangle, the
/// replay finds exactly one object that overlaps each by [`MIN_LABEL_IOU`] and no frame
/// labelled as background shows its centre, with the least IoU; or why not (inner error).
fn locate(
    model: &Model,
    s: &LoadedSession,
    topics: &Topics,
) -> anyhow::Result<Result<(Outcome, f64), String>> {
    if let Some(f) = s
        .frames
        .iter()
        .find(|f| f.regions.as_ref().is_some_and(|r| r.len() > 1))
    {
        return Ok(Err(format!(
            "the frame at stamp {} ns holds {} rectangles: a round would label one object only",
            f.stamp_ns,
            f.regions.as_ref().map_or(0, Vec::len)
        )));
    }
    // Cheap before a replay: a session whose every frame is labelled has nothing to add.
    let reader = reopen(s, topics)?;
    let frames = reader.count(&topics.compressed_image) + reader.count(&topics.image);
    if frames <= s.frames.len() {
        return Ok(Err("every frame of the session is labelled already".into()));
    }
    let outcome = match replay_once(model, &reader) {
        Ok(o) => o,
        Err(why) => return Ok(Err(why)),
    };
    let mut worst = f64::INFINITY;
    for f in &s.frames {
        let Some(regions) = &f.regions else { continue };
        let labelled: Vec<&RegionOfInterest> = regions.iter().collect();
        if labelled.is_empty() {
            if centre_in_view(&outcome, f.stamp_ns) {
                return Ok(Err(format!(
                    "the located object's centre is in view in the frame at stamp {} ns, labelled as background",
                    f.stamp_ns
                )));
            }
            continue;
        }
        let found = rectangle(&outcome, f.stamp_ns).map_or(0.0, |r| {
            labelled
                .iter()
                .map(|l| iou(&r, &pixel_rect(l)))
                .fold(0.0, f64::max)
        });
        worst = worst.min(found);
    }
    if worst.is_infinite() {
        return Ok(Err(
            "no labelled rectangle to check the located object against".into(),
        ));
    }
    if worst < MIN_LABEL_IOU {
        return Ok(Err(format!(
            "the located object overlaps a labelled rectangle by IoU {worst:.3} only, under {MIN_LABEL_IOU}"
        )));
    }
    Ok(Ok((outcome, worst)))
}

fn pixel_rect(r: &RegionOfInterest) -> PixelRect {
    PixelRect {
        x_px: r.x_offset,
        y_px: r.y_offset,
        width_px: r.width,
        height_px: r.height,
    }
}

/// The located object's centre in the frame at `stamp_ns` as recorded, if in front of it.
fn centre_px(outcome: &Outcome, stamp_ns: i64) -> Option<(f64, f64)> {
    let data = &outcome.data;
    let c = outcome.objects[0].centroid_m;
    camera_from_odom(data, stamp_ns)
        .and_then(|pose| {
            data.camera
                .project(&(pose * nalgebra::Point3::new(c[0], c[1], c[2])))
        })
        .map(|(u, v)| distorted_pixel(&data.camera, &data.distortion, u, v))
}

/// Whether the frame at `stamp_ns` shows the located object's centre.
fn centre_in_view(outcome: &Outcome, stamp_ns: i64) -> bool {
    let cam = &outcome.data.camera;
    centre_px(outcome, stamp_ns).is_some_and(|(u, v)| {
        (0.0..f64::from(cam.width)).contains(&u) && (0.0..f64::from(cam.height)).contains(&v)
    })
}

/// Whether the located object's centre, seen in the frame at `stamp_ns`, lies inside one
/// of the `labelled` rectangles (as `eval` counts a frame "inside").
fn centre_inside(outcome: &Outcome, stamp_ns: i64, labelled: &[&RegionOfInterest]) -> bool {
    let data = &outcome.data;
    let cam = RectCamera {
        camera: data.camera,
        distortion: data.distortion,
    };
    let Some(camera_from_odom) = camera_from_odom(data, stamp_ns) else {
        return false;
    };
    let centre = outcome.objects[0].centroid_m;
    labelled.iter().any(|roi| {
        let view = RectView {
            stamp_ns,
            odom_from_camera: camera_from_odom.inverse(),
            roi: **roi,
        };
        projects_inside(&cam, &view, centre)
    })
}

/// The located object's rectangle in the session's frame at `stamp_ns`, if it sees it.
fn rectangle(outcome: &Outcome, stamp_ns: i64) -> Option<PixelRect> {
    let data = &outcome.data;
    let pose = camera_from_odom(data, stamp_ns)?;
    let cells = &outcome.object_cells;
    object_rectangle(
        &data.camera,
        &data.distortion,
        &pose,
        &outcome.grid.spec,
        cells,
    )
}

/// The rectangles the located object gives the frames of `s` without a label, evenly
/// spread over the session (at most [`MAX_VIEWS`]); or why there are none.
fn views(outcome: &Outcome, s: &LoadedSession) -> Result<BTreeMap<i64, ExtraLabel>, String> {
    let labelled: std::collections::BTreeSet<i64> = s.frames.iter().map(|f| f.stamp_ns).collect();
    let seen: Vec<(i64, PixelRect)> = outcome
        .data
        .frames
        .iter()
        .filter(|f| !labelled.contains(&f.stamp_ns))
        .filter_map(|f| rectangle(outcome, f.stamp_ns).map(|r| (f.stamp_ns, r)))
        .collect();
    if seen.is_empty() {
        return Err("no unlabelled frame sees the located object".into());
    }
    let n = seen.len().min(MAX_VIEWS);
    Ok((0..n)
        .map(|i| {
            let (stamp_ns, r) = seen[i * seen.len() / n];
            let roi = |x: i64, y: i64, w: i64, h: i64| RegionOfInterest {
                x_offset: x.max(0) as u32,
                y_offset: y.max(0) as u32,
                width: (w + x.min(0)).max(0) as u32,
                height: (h + y.min(0)).max(0) as u32,
                do_rectify: false,
            };
            let (x, y) = (i64::from(r.x_px), i64::from(r.y_px));
            let (w, h) = (i64::from(r.width_px), i64::from(r.height_px));
            // The located object may lack thin parts (a chair's legs, cut by the object
            // rule's grow level): round its box, as far again as the box is wide and high
            // in all, no tile is taught as background.
            let label = ExtraLabel {
                regions: vec![roi(x, y, w, h)],
                unsure: vec![roi(x - w / 2, y - h / 2, 2 * w, 2 * h)],
            };
            (stamp_ns, label)
        })
        .collect())
}
