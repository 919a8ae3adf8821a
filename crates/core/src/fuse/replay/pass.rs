//! One pass over the prepared frames: localise (when refining), blur, integrate, observe.

use std::collections::BTreeMap;

use crate::fuse::floor::{FloorMap, FloorParams, FloorPatch};
use crate::fuse::grid::Grid;
use crate::fuse::motion::{Segment, segments_between};
use crate::fuse::objects::{Object, ObjectParams, find_objects};
use crate::fuse::refine::{
    Correction, Localisation, MIN_FLOOR_FIT, Sighting, TotalGate, Verdict, landmarks,
    motion_covariance, propagate, refine, sightings,
};
use crate::types::geometry::{Iso3, yaw_of};

use super::prepare::prepare_ahead;
use super::*;

/// One pass over the prepared frames: its grid, the poses it fused with, the floor's state.
pub(super) struct Pass {
    pub(super) fuser: Fuser,
    pub(super) poses: Vec<Iso3>,
    pub(super) per_frame: Vec<FrameSummary>,
    /// Every frame's floor at the poses this pass fused it with and at /odom's, when the
    /// floor term is used: what the check of the refinement compares (built frame by frame,
    /// so that no pass holds every frame's patch).
    pub(super) floor_check: Option<FloorCheck>,
}

/// The floor of every frame, mapped at the fused poses and at /odom's.
pub(super) struct FloorCheck {
    pub(super) fused: FloorMap,
    pub(super) odometry: FloorMap,
}

/// Margin of the check's map of the floor at the fused poses beyond /odom's reach, metres:
/// its cells must not depend on where the refined poses end (they are known only then), so
/// it is laid out from /odom's poses, this much wider. A correction beyond it would leave
/// part of a frame's floor off the map; refinement's gate keeps corrections far below it
/// (the largest on every session set: 0.7 m, a diverged replay that the check rolls back).
pub const FLOOR_CHECK_MARGIN_M: f64 = 3.0;

/// The floor map's extent for `poses` (x, y), `extra_m` beyond the floor term's reach.
fn floor_bounds(
    poses: impl Iterator<Item = Iso3>,
    fp: &FloorParams,
    extra_m: f64,
) -> ([f64; 2], [f64; 2]) {
    let reach = fp.max_range_m + 1.0 + extra_m;
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in poses {
        let t = p.translation.vector;
        lo = [lo[0].min(t.x - reach), lo[1].min(t.y - reach)];
        hi = [hi[0].max(t.x + reach), hi[1].max(t.y + reach)];
    }
    (lo, hi)
}

/// What a pass carries from frame to frame when it refines poses.
struct Tracker {
    /// Rays through the detections of the frames fused so far.
    pub(super) seen: Vec<Sighting>,
    pub(super) floor_map: Option<FloorMap>,
    /// Covariance of /odom's error since the first frame (the total correction's gate).
    pub(super) total_cov: nalgebra::Matrix3<f64>,
    /// Floor patches made ahead of their frames (at most
    /// [`super::prepare::PREPARE_CHUNK`]), by frame index.
    pub(super) floor_ahead: BTreeMap<usize, FloorPatch>,
    /// The objects found after the last frame fused (the fuse's own rule): the next frame
    /// localises against them once the rule's view count is reached, instead of finding
    /// them again in the same grid.
    pub(super) last_objects: Vec<Object>,
}

/// What a pass without localisation takes from a pass before it.
#[derive(Clone, Copy)]
pub(super) enum Prior<'a> {
    /// The refined pass this one replaces at /odom: its frames carry its corrections, those
    /// it had accepted as [`Verdict::RolledBack`].
    RolledBack(&'a Pass),
    /// The pass whose poses the smoother solved again: its frames carry its corrections as
    /// they were and are fused, unblurred, at `poses` (each was solved against the whole
    /// replay).
    Smoothed(&'a Pass, &'a [Iso3]),
}

impl Prior<'_> {
    /// Frame `index`'s correction as this pass carries it.
    fn correction(&self, index: usize) -> Option<Correction> {
        match self {
            Prior::RolledBack(r) => r.per_frame.get(index)?.correction.map(|c| match c.outcome {
                Verdict::Accepted => Correction {
                    applied: false,
                    outcome: Verdict::RolledBack,
                    ..c
                },
                _ => c,
            }),
            Prior::Smoothed(r, _) => r.per_frame.get(index)?.correction,
        }
    }
}

/// One pass over the frames, localising each when `options` refine and `prior` is `None`.
pub(super) fn run_pass(
    ctx: &Context<'_>,
    options: &FuseOptions,
    observers: &mut [&mut dyn Observer],
    prior: Option<Prior<'_>>,
) -> Result<Pass, ReplayError> {
    let fuser = Fuser::new(ctx.spec, ctx.prior, options.clone()).map_err(|e| ctx.grid_err(e))?;
    let odometry = || ctx.prepared.iter().map(|p| p.odometry);
    let floor_map = floor_params(options).map(|fp| {
        let (lo, hi) = floor_bounds(odometry(), &fp, 0.0);
        FloorMap::new(lo, hi, fp)
    });
    let floor_check = floor_params(options).map(|fp| {
        let (lo, hi) = floor_bounds(odometry(), &fp, 0.0);
        let (wide_lo, wide_hi) = floor_bounds(odometry(), &fp, FLOOR_CHECK_MARGIN_M);
        FloorCheck {
            fused: FloorMap::new(wide_lo, wide_hi, fp),
            odometry: FloorMap::new(lo, hi, fp),
        }
    });
    let mut pass = Pass {
        fuser,
        poses: Vec::with_capacity(ctx.prepared.len()),
        per_frame: Vec::with_capacity(ctx.prepared.len()),
        floor_check,
    };
    let mut tracker = Tracker {
        seen: Vec::new(),
        floor_map,
        total_cov: nalgebra::Matrix3::zeros(),
        floor_ahead: BTreeMap::new(),
        last_objects: Vec::new(),
    };
    for index in 0..ctx.prepared.len() {
        step(
            ctx,
            options,
            &mut pass,
            &mut tracker,
            index,
            prior,
            observers,
        )?;
    }
    Ok(pass)
}

/// Localises (when refining), fuses and observes frame `index`; with a `prior` the frame
/// carries that pass's correction instead, fused at /odom or at the smoothed pose.
fn step(
    ctx: &Context<'_>,
    options: &FuseOptions,
    pass: &mut Pass,
    tracker: &mut Tracker,
    index: usize,
    prior: Option<Prior<'_>>,
    observers: &mut [&mut dyn Observer],
) -> Result<(), ReplayError> {
    let p = &ctx.prepared[index];
    let data = &ctx.data;
    let floor = ready_frame(ctx, options, tracker, index)?;
    let mut floor_unfit = false;
    let correction = match (index.checked_sub(1), prior) {
        (Some(prev), None) if options.refine_poses => {
            let (c, unfit) = localise_frame(ctx, options, pass, tracker, index, prev, &floor);
            floor_unfit = unfit;
            Some(c)
        }
        (_, Some(Prior::Smoothed(_, poses))) => {
            pass.poses.push(poses[index]);
            prior.and_then(|r| r.correction(index))
        }
        _ => {
            pass.poses.push(p.odometry);
            prior.and_then(|r| r.correction(index))
        }
    };
    let odom_from_base = pass.poses[index];
    if options.refine_poses {
        tracker.seen.extend(sightings(
            index,
            p.clusters(),
            &data.camera,
            &(odom_from_base * p.mount),
        ));
    }
    // A frame whose pose was measured (corrected, or found where it was predicted) is not
    // blurred: the measurement replaces the motion model's spread.
    let localised = matches!(prior, Some(Prior::Smoothed(..)))
        || (options.refine_poses && correction.is_some_and(|c| c.outcome.measured()));
    // The floor maps take this frame's floor while the grid fuses it and the objects are
    // found: neither side reads what the other writes, and each computes the same whichever
    // thread runs it (the maps' updates are serial and would leave a core idle).
    let map = tracker.floor_map.as_mut().filter(|_| !floor_unfit);
    let check = pass.floor_check.as_mut();
    let (fuser, poses) = (&mut pass.fuser, &pass.poses);
    let (fused, ()) = rayon::join(
        || {
            let segments = fuse_one(fuser, data, &ctx.prepared, poses, index, localised)?;
            Ok((
                segments,
                find_objects(&fuser.grid, &options.objects.per_frame()),
            ))
        },
        || add_floor(map, check, &floor, &odom_from_base, &p.odometry),
    );
    drop(floor);
    let (segments, objects) = fused.map_err(|e| ctx.grid_err(e))?;
    if options.refine_poses {
        tracker.last_objects.clone_from(&objects);
    }
    let cells_updated = pass.fuser.last_cells_updated;
    let max_probability = max_probability(&pass.fuser.grid);
    for o in observers.iter_mut() {
        o.on_progress(Stage::Fuse, index + 1, ctx.prepared.len());
    }
    if observers.iter().any(|o| o.wants_steps()) {
        let fr = &p.frame;
        let step = FrameStep {
            index,
            frame: fr.clone(),
            odom_from_camera: odom_from_base * p.mount,
            odom_from_base,
            odometry: p.odometry,
            correction,
            image: step_image(ctx.reader, data, p)?,
            probs: TileProbs::clone(&p.probs()),
            segments,
            cells_updated,
            objects: objects.clone(),
            max_probability,
            frames: ctx.prepared.len(),
        };
        for o in observers.iter_mut().filter(|o| o.wants_steps()) {
            o.on_frame(data, &step, &pass.fuser.grid)
                .map_err(|e| ctx.observer_err(Some(fr), e))?;
        }
    }
    pass.per_frame.push(summary(
        p,
        index,
        &odom_from_base,
        correction,
        cells_updated,
        max_probability,
        objects,
    ));
    // Nothing after this frame reads its probabilities; a later pass classifies it again.
    p.release();
    Ok(())
}

/// Adds a frame's floor, fused at `fused_at`, to the map the search uses (`map`: none when the
/// floor term is off, dropped, or the frame's floor did not fit) and to both maps of the
/// refinement's check (the second at the frame's /odom pose).
fn add_floor(
    map: Option<&mut FloorMap>,
    check: Option<&mut FloorCheck>,
    floor: &FloorPatch,
    fused_at: &Iso3,
    odometry: &Iso3,
) {
    if let Some(map) = map {
        map.add(floor, fused_at);
    }
    if let Some(check) = check {
        check.fused.add(floor, fused_at);
        check.odometry.add(floor, odometry);
    }
}

/// Makes frame `index` ready to fuse: classified, with the next frames ([`prepare_ahead`]),
/// when it is not yet; returns its floor patch when the floor term is used (empty
/// otherwise).
fn ready_frame(
    ctx: &Context<'_>,
    options: &FuseOptions,
    tracker: &mut Tracker,
    index: usize,
) -> Result<FloorPatch, ReplayError> {
    let fp = floor_params(options);
    prepare_ahead(ctx, index, fp.as_ref(), &mut tracker.floor_ahead)?;
    Ok(tracker.floor_ahead.remove(&index).unwrap_or_default())
}

/// Localises frame `index` (refining; `prev` is the frame before it): propagates the total
/// gate's covariance, searches and applies the verdict. Returns
/// the correction and whether the frame's floor did not fit (then it is not added to the map).
fn localise_frame(
    ctx: &Context<'_>,
    options: &FuseOptions,
    pass: &mut Pass,
    tracker: &mut Tracker,
    index: usize,
    prev: usize,
    floor: &FloorPatch,
) -> (Correction, bool) {
    let p = &ctx.prepared[index];
    let data = &ctx.data;
    let mut floor_unfit = false;
    let segs: Vec<(Segment, Iso3)> = segments_between(
        &data.commands,
        ctx.prepared[prev].frame.stamp_ns,
        p.frame.stamp_ns,
    )
    .into_iter()
    .map(|seg| (seg, data.odom_at(seg.start_ns).unwrap_or(p.odometry)))
    .collect();
    tracker.total_cov = propagate(
        tracker.total_cov,
        &segs,
        options.sigma_v_mps,
        options.sigma_w_radps,
    );
    let gate = TotalGate {
        odometry: p.odometry,
        covariance: tracker.total_cov,
    };
    let (c, predicted) = localise(ctx, options, pass, tracker, index, &gate, floor);
    pass.poses.push(c.apply(&predicted));
    // A frame whose floor does not fit is aligned to the objects alone, and its floor is not
    // added to the map: what it shows is not the floor the map holds. The next frame's floor
    // is tried again (see `MIN_FLOOR_FIT`).
    if tracker.floor_map.is_some() && c.floor_fit.is_some_and(|f| f[0] < MIN_FLOOR_FIT) {
        floor_unfit = true;
    }
    (c, floor_unfit)
}

/// Highest cell probability of `grid`, in [0, 1].
fn max_probability(grid: &Grid) -> f64 {
    crate::fuse::grid::sigmoid(f64::from(grid.max_log_odds()))
}

fn summary(
    p: &Prepared,
    index: usize,
    odom_from_base: &Iso3,
    correction: Option<Correction>,
    cells_updated: usize,
    max_probability: f64,
    objects: Vec<Object>,
) -> FrameSummary {
    let base = odom_from_base.translation.vector;
    let odo = p.odometry.translation.vector;
    FrameSummary {
        index,
        stamp_ns: p.frame.stamp_ns,
        log_time_ns: p.frame.log_time_ns,
        position_m: [base.x, base.y, base.z],
        yaw_rad: yaw_of(odom_from_base),
        odom_position_m: [odo.x, odo.y, odo.z],
        odom_yaw_rad: yaw_of(&p.odometry),
        correction,
        cells_updated,
        max_probability,
        objects,
    }
}

/// Fraction of the accumulated correction (refined pose against odometry) a frame carries
/// to the next. Below 1 so that what one object cannot observe (sliding around it) does
/// not random-walk: measured on a 200-frame chair tour, carrying all of it took the refined
/// trajectory 1.4 m and 30 degrees off (ATE 0.94 m against odometry's 0.17 m); at 0.95 the
/// refined ATE is odometry's and the object error falls from 0.31 to 0.22 m, while the
/// 8-frame tours change by at most 0.01-0.02 m (docs/fuser.md).
pub const CORRECTION_RETENTION: f64 = 0.95;

/// The correction frame `prev` carries forward, as a transform of `odom`:
/// [`CORRECTION_RETENTION`] of its heading and position offsets from odometry; `None` when
/// its pose is the odometry's, so that a replay that corrected nothing fuses at the odometry
/// poses bit for bit (`pose * odometry^-1` and a product with the identity both round).
fn carried_correction(prepared: &[Prepared], poses: &[Iso3], prev: usize) -> Option<Iso3> {
    if poses[prev] == prepared[prev].odometry {
        return None;
    }
    let full = poses[prev] * prepared[prev].odometry.inverse();
    Some(Iso3::from_parts(
        nalgebra::Translation3::from(full.translation.vector * CORRECTION_RETENTION),
        nalgebra::UnitQuaternion::from_axis_angle(
            &nalgebra::Vector3::z_axis(),
            yaw_of(&full) * CORRECTION_RETENTION,
        ),
    ))
}

/// `pose` moved by the `carried` correction, if any.
fn moved(carried: Option<&Iso3>, pose: &Iso3) -> Iso3 {
    carried.map_or(*pose, |c| c * pose)
}

/// Localises frame `index` against the landmarks before it is fused (see
/// [`crate::fuse::refine`]); `poses` holds the poses of the frames before it, `seen` the rays
/// through their detections. Returns the correction and the pose it corrects (the previous
/// frame's pose moved by the odometry increment since).
fn localise(
    ctx: &Context<'_>,
    options: &FuseOptions,
    pass: &Pass,
    tracker: &Tracker,
    index: usize,
    gate: &TotalGate,
    floor: &FloorPatch,
) -> (Correction, Iso3) {
    let (data, prepared, poses) = (&ctx.data, &ctx.prepared, &pass.poses);
    let clusters = prepared[index].clusters();
    let prev = index - 1;
    let p = &prepared[index];
    // Motion since the previous frame, each segment with its start pose moved by the
    // correction carried from the previous frame (its heading turns speed error sideways).
    let drift = carried_correction(prepared, poses, prev);
    let segments: Vec<(Segment, Iso3)> = segments_between(
        &data.commands,
        prepared[prev].frame.stamp_ns,
        p.frame.stamp_ns,
    )
    .into_iter()
    .map(|seg| {
        let pose = moved(
            drift.as_ref(),
            &data.odom_at(seg.start_ns).unwrap_or(p.odometry),
        );
        (seg, pose)
    })
    .collect();
    let cov = motion_covariance(&segments, options.sigma_v_mps, options.sigma_w_radps);
    // The belief's objects, requiring only as many views as there have been frames, tell
    // which rays belong together.
    let params = ObjectParams {
        min_views: options
            .objects
            .min_views
            .min(u16::try_from(index).unwrap_or(u16::MAX)),
        ..options.objects.per_frame()
    };
    // The grid is the one the previous step found `last_objects` in: with the same rule,
    // the same objects.
    let found;
    let objects = if params == options.objects.per_frame() {
        &tracker.last_objects
    } else {
        found = find_objects(&pass.fuser.grid, &params);
        &found
    };
    let centroids: Vec<[f64; 3]> = objects.iter().map(|o| o.mass_centroid_m).collect();
    let predicted = moved(drift.as_ref(), &p.odometry);
    let correction = refine(&Localisation {
        landmarks: &landmarks(&centroids, &tracker.seen, data.camera.fx),
        clusters,
        camera: &data.camera,
        base_from_camera: &p.mount,
        predicted: &predicted,
        cov: &cov,
        floor: tracker.floor_map.as_ref().map(|m| (m, floor)),
        gate: Some(gate),
    });
    (correction, predicted)
}

/// Blurs by the motion since the previous prepared frame, then integrates frame `index` at
/// `poses[index]`; returns the blurred segments. A `localised` frame is not blurred: its
/// pose was measured against the landmarks, which replaces the motion model's spread (what
/// is left is a few pixels, below a cell at these ranges; measured in docs/fuser.md).
fn fuse_one(
    fuser: &mut Fuser,
    data: &SessionData,
    prepared: &[Prepared],
    poses: &[Iso3],
    index: usize,
    localised: bool,
) -> Result<Vec<Segment>, crate::fuse::grid::GridError> {
    let p = &prepared[index];
    let odom_from_base = poses[index];
    // Motion since the previous frame blurs the belief (nothing before the first one: the
    // first frame anchors the belief). Segment poses come from odometry, moved by this
    // frame's correction.
    let segments = match index.checked_sub(1) {
        Some(_) if localised => {
            fuser.forget_motion();
            Vec::new()
        }
        Some(prev) => segments_between(
            &data.commands,
            prepared[prev].frame.stamp_ns,
            p.frame.stamp_ns,
        ),
        None => Vec::new(),
    };
    // Exactly the identity when the pose is the odometry, so that a replay without
    // refinement is not perturbed by rounding.
    let drift = if odom_from_base == p.odometry {
        Iso3::identity()
    } else {
        odom_from_base * p.odometry.inverse()
    };
    for seg in &segments {
        let pose = drift * data.odom_at(seg.start_ns).unwrap_or(p.odometry);
        fuser.blur(seg, &pose)?;
    }
    let odom_from_camera = odom_from_base * p.mount;
    fuser.last_cells_updated =
        fuser.integrate(&odom_from_camera, &odom_from_base, &data.camera, &p.probs())?;
    Ok(segments)
}
