//! The smoother's place in the replay: after the filter's pass (and its check), every pose
//! solved again over the whole replay ([`crate::fuse::refine::smooth`]), the frames fused
//! again at those poses, and that pass kept only when (1) it finds as many objects as the
//! pass it would replace, (2) every smoothed pose passes the filter's total gate against
//! /odom, and (3) a second solution with the odometry's speed and turn scale errors among
//! the unknowns puts every object within [`MAX_CALIBRATION_DISAGREEMENT_M`] of the first.
//!
//! Why these: the smoothed poses are fitted to the same detections any check of rays would
//! compare, so they cannot be shown worse that way. What a wrong solution does show is a grid
//! whose objects fall apart or multiply (measured, docs/fuser.md: a mug tour that lost both
//! mugs, a duck tour that gained a spurious one), poses the speed noise cannot explain, or
//! objects that move when a miscalibrated odometry is allowed for (a robot turning 3 % more
//! than /odom says: the first solution put a chair 0.33 m off, the second 0.03 m). Otherwise
//! the filter's pass stands, and the report says why.
//!
//! Guards 2 and 3 need no grid and are checked first: when either fails, the frames are not
//! fused again.
//!
//! Invariants: pure in the replay's context and the pass; no pass is shown to observers
//! before it is kept.

use nalgebra::Vector3;

use crate::fuse::motion::segments_between;
use crate::fuse::objects::find_objects;
use crate::fuse::refine::smooth::{SmoothFrame, corrected, correction_of, smooth};
use crate::fuse::refine::{GATE_CHI2, GATE_SIGMA_SCALE, TotalGate, motion_covariance, propagate};
use crate::types::geometry::{Iso3, wrap_angle, yaw_of};

use super::pass::{Pass, Prior, run_pass};
use super::*;

/// What the smoother did, as the report gives it (`refinement.smoothing`).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Smoothing {
    /// Whether the replay's poses are the smoother's.
    pub kept: bool,
    /// Why, in words.
    pub reason: String,
    /// Frames the floor had placed (held to the filter's correction).
    pub floor_placed: usize,
    /// Detections paired with an object in the solution.
    pub observations: usize,
    /// Objects the pass it would replace found, and the smoothed pass; the second is `None`
    /// when the smoothed poses failed guard 2 or 3, which need no grid, so the frames were not
    /// fused at them (that pass costs as much as the filter's).
    pub objects: (usize, Option<usize>),
    /// Half the sum of squared whitened residuals, at the filter's poses and at the
    /// smoother's.
    pub cost: [f64; 2],
    /// Largest move of a frame from the filter's pose, metres and degrees.
    pub max_move_m: f64,
    /// Largest turn of a frame from the filter's pose, degrees.
    pub max_turn_deg: f64,
    /// The largest chi-square of a smoothed pose against /odom under the filter's total gate
    /// (3 dof; the gate is [`GATE_CHI2`] at [`GATE_SIGMA_SCALE`] times the sigmas), and its
    /// frame.
    pub worst_gate_chi2: f64,
    /// The frame of `worst_gate_chi2`.
    pub worst_gate_frame: usize,
    /// The largest chi-square of one link between consecutive frames (3 dof), and the later
    /// frame of it.
    pub max_link_chi2: f64,
    /// The frame of `max_link_chi2`.
    pub max_link_frame: usize,
    /// The odometry's speed and turn scale errors the smoother solved for (fractions: 0.03 is
    /// a robot that turns 3 % more than /odom says).
    pub odometry_scale_error: [f64; 2],
    /// How far apart (largest, metres) the objects lie solved with and without those scale
    /// errors among the unknowns; over [`MAX_CALIBRATION_DISAGREEMENT_M`] the smoothing is
    /// not kept.
    pub calibration_disagreement_m: f64,
}

/// The largest distance between an object solved with and without the odometry's scale
/// errors among the unknowns at which the smoothing is kept (docs/fuser.md: a robot that
/// turns 3 % more than /odom says put a bin 0.22 m off without them, 0.05 m with them; on
/// tours of random speed noise the two agree within a few centimetres).
pub const MAX_CALIBRATION_DISAGREEMENT_M: f64 = 0.05;

/// The smoother's poses for `pass` and its report; `None` when there is nothing to smooth
/// (fewer than two frames, no object, a singular system).
fn smoothed_poses(
    ctx: &Context<'_>,
    options: &FuseOptions,
    pass: &Pass,
    objects: &[Object],
) -> Option<(Vec<Iso3>, Smoothing)> {
    let data = &ctx.data;
    // Per frame, the commands since the previous frame with the /odom pose at each start.
    let segments: Vec<Vec<_>> = ctx
        .prepared
        .iter()
        .enumerate()
        .map(|(k, p)| match k.checked_sub(1) {
            None => Vec::new(),
            Some(prev) => segments_between(
                &data.commands,
                ctx.prepared[prev].frame.stamp_ns,
                p.frame.stamp_ns,
            )
            .into_iter()
            .map(|seg| (seg, data.odom_at(seg.start_ns).unwrap_or(p.odometry)))
            .collect(),
        })
        .collect();
    let frames: Vec<SmoothFrame> = ctx
        .prepared
        .iter()
        .zip(&segments)
        .enumerate()
        .map(|(k, (p, segs))| SmoothFrame {
            odometry: p.odometry,
            mount: p.mount,
            clusters: p.clusters().to_vec(),
            start: correction_of(&p.odometry, &pass.poses[k]),
            link_cov: motion_covariance(segs, options.sigma_v_mps, options.sigma_w_radps),
            floor_placed: k > 0
                && pass.per_frame[k]
                    .correction
                    .is_some_and(|c| c.floor_cells > 0),
        })
        .collect();
    let seeds: Vec<Vector3<f64>> = objects
        .iter()
        .map(|o| Vector3::from(o.mass_centroid_m))
        .collect();
    let s = smooth(&frames, &seeds, &data.camera, false)?;
    // The same with the odometry's speed and turn scale errors among the unknowns: where the
    // two place the objects apart, the detections cannot tell a drift from a miscalibrated
    // odometry, and neither solution is to be trusted.
    let calibrated = smooth(&frames, &seeds, &data.camera, true)?;
    let disagreement_m = s
        .objects_m
        .iter()
        .zip(&calibrated.objects_m)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    let poses: Vec<Iso3> = frames
        .iter()
        .zip(&s.corrections)
        .map(|(f, e)| corrected(&f.odometry, e))
        .collect();
    // The filter's total gate, frame by frame: the smoothed poses must stay within what the
    // speed noise allows against /odom, as every accepted correction must.
    let mut total_cov = nalgebra::Matrix3::zeros();
    let mut worst_gate = (0usize, 0.0f64);
    for (k, (f, pose)) in frames.iter().zip(&poses).enumerate().skip(1) {
        total_cov = propagate(
            total_cov,
            &segments[k],
            options.sigma_v_mps,
            options.sigma_w_radps,
        );
        let chi2 = TotalGate {
            odometry: f.odometry,
            covariance: total_cov,
        }
        .chi2(pose);
        if chi2 > worst_gate.1 {
            worst_gate = (k, chi2);
        }
    }
    let (mut max_move_m, mut max_turn) = (0.0f64, 0.0f64);
    for (a, b) in poses.iter().zip(&pass.poses) {
        max_move_m = max_move_m.max((a.translation.vector - b.translation.vector).xy().norm());
        max_turn = max_turn.max(wrap_angle(yaw_of(a) - yaw_of(b)).abs());
    }
    let report = Smoothing {
        kept: false,
        reason: String::new(),
        floor_placed: frames.iter().filter(|f| f.floor_placed).count(),
        observations: s.observations,
        objects: (0, None),
        cost: s.cost,
        max_move_m,
        max_turn_deg: max_turn.to_degrees(),
        worst_gate_chi2: worst_gate.1,
        worst_gate_frame: worst_gate.0,
        max_link_chi2: s.max_link_chi2.0,
        max_link_frame: s.max_link_chi2.1,
        odometry_scale_error: [calibrated.calibration.x, calibrated.calibration.y],
        calibration_disagreement_m: disagreement_m,
    };
    Some((poses, report))
}

/// Solves the poses of `pass` again over the whole replay and fuses the frames at them
/// (shown to no observer); returns that pass when it is kept, and the report either way
/// (`None` when there was nothing to smooth). `rolled_back`: `pass` is the replay fused again
/// at /odom after the check, so a refusal leaves /odom's poses, not the filter's.
pub(super) fn smooth_pass(
    ctx: &Context<'_>,
    options: &FuseOptions,
    pass: &Pass,
    rolled_back: bool,
) -> Result<(Option<Pass>, Option<Smoothing>), ReplayError> {
    let whose = if rolled_back {
        "/odom's"
    } else {
        "the filter's"
    };
    // The landmarks are the objects the filter localised against; the count is the final
    // rule's (with its weaker instances), what the replay reports.
    let landmarks = find_objects(&pass.fuser.grid, &options.objects.per_frame());
    let before = find_objects(&pass.fuser.grid, &options.objects).len();
    let Some((poses, mut report)) = smoothed_poses(ctx, options, pass, &landmarks) else {
        return Ok((None, None));
    };
    let gate = GATE_CHI2 * GATE_SIGMA_SCALE * GATE_SIGMA_SCALE;
    let in_gate = report.worst_gate_chi2 <= gate;
    let agreed = report.calibration_disagreement_m <= MAX_CALIBRATION_DISAGREEMENT_M;
    report.objects = (before, None);
    if !agreed {
        report.reason = format!(
            "not kept: solved with the odometry's speed and turn scale errors among the unknowns ({:+.3}, {:+.3}) an object lies {:.3} m from where it lies without them (over {MAX_CALIBRATION_DISAGREEMENT_M} m): the detections cannot tell drift from a miscalibrated odometry, so {whose} poses stand",
            report.odometry_scale_error[0],
            report.odometry_scale_error[1],
            report.calibration_disagreement_m
        );
        return Ok((None, Some(report)));
    }
    if !in_gate {
        report.reason = format!(
            "not kept: frame {} would lie outside the motion model's gate against /odom (chi-square {:.1} > {gate:.1}), so {whose} poses stand",
            report.worst_gate_frame, report.worst_gate_chi2
        );
        return Ok((None, Some(report)));
    }
    let plain = FuseOptions {
        refine_poses: false,
        ..options.clone()
    };
    let again = run_pass(ctx, &plain, &mut [], Some(Prior::Smoothed(pass, &poses)))?;
    let found = find_objects(&again.fuser.grid, &options.objects).len();
    report.objects = (before, Some(found));
    report.kept = found == before;
    report.reason = if report.kept {
        format!(
            "every pose solved again against every frame's detections of the {found} object(s) and the motion model, {} frame(s) held where the floor placed them",
            report.floor_placed
        )
    } else {
        format!(
            "not kept: fused at the smoothed poses the grid holds {found} object(s) against the {before} of {whose} poses, so they stand"
        )
    };
    Ok((report.kept.then_some(again), Some(report)))
}
