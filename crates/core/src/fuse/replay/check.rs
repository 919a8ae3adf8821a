//! The check of a refined replay against /odom, and the rule that rolls it back.

use crate::fuse::objects::find_objects;
use crate::fuse::refine::{Consistency, Sighting, sightings};
use crate::types::geometry::Iso3;

use super::*;

/// Compares how well the refined poses and the /odom poses explain the frames: the rays
/// through every frame's detections, gathered per final object and triangulated, and the
/// floor the frames saw (with the floor term).
pub(super) fn check_refinement(ctx: &Context<'_>, pass: &Pass) -> RefinementCheck {
    let data = &ctx.data;
    let objects = find_objects(&pass.fuser.grid, &pass.fuser.options.objects.per_frame());
    let seeds: Vec<[f64; 3]> = objects.iter().map(|o| o.mass_centroid_m).collect();
    let odometry: Vec<Iso3> = ctx.prepared.iter().map(|p| p.odometry).collect();
    // The /odom rays may pass as far from the refined objects as the poses differ.
    let moved_m = pass
        .poses
        .iter()
        .zip(&odometry)
        .map(|(a, b)| (a.translation.vector - b.translation.vector).xy().norm())
        .fold(0.0, f64::max);
    let rays = |poses: &[Iso3]| -> Vec<Sighting> {
        ctx.prepared
            .iter()
            .zip(poses)
            .enumerate()
            .flat_map(|(i, (p, pose))| sightings(i, p.clusters(), &data.camera, &(pose * p.mount)))
            .collect()
    };
    let gate = crate::fuse::refine::GATE_M + moved_m;
    let refined = Consistency::of(&seeds, &rays(&pass.poses), data.camera.fx, gate);
    let odom = Consistency::of(&seeds, &rays(&odometry), data.camera.fx, gate);
    let floor = pass
        .floor_check
        .as_ref()
        .map(|c| [c.fused.disagreement(), c.odometry.disagreement()]);
    // Each kind of evidence can be worse at the refined poses while the other is better: on
    // a tour whose /odom drift is a turn about the object, the rays meet as well at /odom, and
    // only the floor shows the drift. A replay is rolled back when one is worse and the other
    // no better.
    let rays_worse = refined.worse_than(&odom);
    let rays_better = odom.worse_than(&refined);
    let floor_worse = floor.is_some_and(|[r, o]| r > o * (1.0 + ROLLBACK_TOLERANCE));
    let floor_better = floor.is_some_and(|[r, o]| o > r * (1.0 + ROLLBACK_TOLERANCE));
    let rolled_back =
        pass.poses != odometry && ((rays_worse && !floor_better) || (floor_worse && !rays_better));
    // A rolled-back replay is fused at /odom: none of its corrections stands.
    let detections_only = if rolled_back {
        Vec::new()
    } else {
        pass.per_frame
            .iter()
            .filter(|f| {
                f.correction
                    .is_some_and(|c| c.applied && c.floor_cells == 0)
            })
            .map(|f| f.index)
            .collect()
    };
    RefinementCheck {
        refined_rays: refined,
        odometry_rays: odom,
        floor_disagreement: floor,
        detections_only,
        rolled_back,
        smoothing: None,
        reason: if !rolled_back {
            None
        } else if rays_worse {
            Some(format!(
                "the refined poses explain the detections worse than /odom (mean ray chi-square {:.2} against {:.2})",
                refined.mean_chi2, odom.mean_chi2
            ))
        } else {
            floor.map(|[r, o]| {
                format!("the floor seen at the refined poses disagrees with itself more than at /odom ({r:.3} against {o:.3})")
            })
        },
    }
}

/// How much worse (relative) the refined replay may explain the floor than /odom before it
/// is rolled back.
pub const ROLLBACK_TOLERANCE: f64 = 0.05;

/// The check of a refined replay against /odom, as the report gives it.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RefinementCheck {
    /// Rays through the detections at the refined poses, per final object.
    pub refined_rays: Consistency,
    /// The same rays at the /odom poses.
    pub odometry_rays: Consistency,
    /// Mean disagreement of the floor across views (variance over the colour noise), at the
    /// refined and at the /odom poses; absent without the floor term (`--no-floor`).
    pub floor_disagreement: Option<[f64; 2]>,
    /// Frames whose applied correction came from the detections alone (no floor cell): the
    /// rays this check compares are the evidence those poses were fitted to, so it cannot
    /// show them worse than /odom. Empty when rolled back. Measured on 48 simulated tours
    /// (docs/fuser.md): 3 of the 4 replays refinement made worse had such frames (the fourth,
    /// two-chairs 8, had the floor behind every correction).
    #[serde(default)]
    pub detections_only: Vec<usize>,
    /// Whether the replay fell back to /odom.
    pub rolled_back: bool,
    /// What the smoother over the whole replay did after this check (with
    /// [`FuseOptions::smooth_poses`]); absent from reports written before it existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub smoothing: Option<super::Smoothing>,
    /// Why, in words.
    pub reason: Option<String>,
}
