//! Defaults that fit the session: what a replay uses where the user left a choice open, and
//! why. A ground robot's session (it has /cmd_vel) keeps every default as it is. A session
//! without commands (a hand-held, arm or structure-from-motion capture) has no motion to
//! predict: no motion model, no pose refinement (unless asked), no floor term (the camera is
//! not a robot's fixed mount above a floor), no search for weaker instances (unless asked),
//! and, unless bounds are given, a grid around where the cameras look, in the session's own
//! units.
//!
//! Invariants: a pure function of the options and pass 1's data (deterministic); a choice the
//! user made (`fit` false) is never overridden; every override is stated as one line.

use crate::types::geometry::Iso3;
use nalgebra::Vector3;

use super::*;

/// Cells along the longest side of a grid whose voxel the session chooses.
pub const FITTED_CELLS_LONGEST_SIDE: f64 = 200.0;

/// Which of the options the session may choose (the user left them at their defaults).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub struct SessionFit {
    /// The bounds (when `bounds_m` is None).
    pub bounds: bool,
    /// The voxel size (when the bounds are the session's).
    pub voxel: bool,
    /// Pose refinement and its floor term.
    pub refinement: bool,
    /// Where objects' locations come from ([`Locate`]); reports written before it existed
    /// read as not chosen.
    #[serde(default)]
    pub locate: bool,
    /// Whether to search the final grid for weaker instances
    /// ([`crate::fuse::objects::ObjectParams::weaker_instances`]); reports written before it
    /// existed read as not chosen.
    #[serde(default)]
    pub weaker_instances: bool,
}

impl SessionFit {
    /// Everything left to the session.
    pub const ALL: Self = Self {
        bounds: true,
        voxel: true,
        refinement: true,
        locate: true,
        weaker_instances: true,
    };
}

/// The options fitted to a session, and one line per choice made for it.
#[derive(Debug, Clone, PartialEq)]
pub struct Fitted {
    /// The options the replay uses.
    pub options: FuseOptions,
    /// What the session changed and why, for the report and stdout.
    pub choices: Vec<String>,
}

/// Fits `options` to the session read in pass 1.
pub fn fit_to_session(options: &FuseOptions, data: &SessionData) -> Fitted {
    let mut out = options.clone();
    let mut choices = Vec::new();
    if !data.commands.is_empty() {
        return Fitted {
            options: out,
            choices,
        };
    }
    choices.push(
        "no motion model: the session has no /cmd_vel, so nothing predicts or blurs the motion \
         between frames"
            .to_owned(),
    );
    if options.fit.refinement && out.refine_poses {
        out.refine_poses = false;
        choices.push(
            "no pose refinement: without /cmd_vel there is no motion model to search under \
             (ask with --refine-poses)"
                .to_owned(),
        );
    }
    if out.refine_poses && out.refine_floor {
        out.refine_floor = false;
        choices.push(
            "no floor term: without /cmd_vel the camera is not a ground robot's fixed mount"
                .to_owned(),
        );
    }
    if options.fit.locate && out.locate == Locate::Extent {
        out.locate = Locate::Detections;
        choices.push(
            "object locations triangulated from their detections' boxes: without /cmd_vel no \
             floor closes the grid below the object, and cells hidden under it in every view \
             keep its evidence (--locate extent for the centre of the extent)"
                .to_owned(),
        );
    }
    if options.fit.weaker_instances && out.objects.weaker_instances {
        out.objects.weaker_instances = false;
        choices.push(
            "no search for weaker instances: on captures it found false positives, not twins \
             (robot sessions taken as captures, perturbed: 4 spurious objects in 12 tours; \
             docs/fuser.md, Objects; ask with --weaker-instances)"
                .to_owned(),
        );
    }
    if options.fit.bounds && options.bounds_m.is_none() {
        match view_bounds(data) {
            Some((lo, hi)) => {
                out.bounds_m = Some((lo, hi));
                let mut line = format!(
                    "grid around where the cameras look (where their optical axes converge): \
                     bounds ({:.4}, {:.4}, {:.4})..({:.4}, {:.4}, {:.4}) (--bounds to choose)",
                    lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]
                );
                if options.fit.voxel {
                    let longest = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
                    out.voxel_size_m = longest / FITTED_CELLS_LONGEST_SIDE;
                    line += &format!(
                        ", voxel {:.4e} session units for {FITTED_CELLS_LONGEST_SIDE} cells on \
                         the longest side (--voxel to choose)",
                        out.voxel_size_m
                    );
                }
                choices.push(line);
            }
            None => choices.push(
                "grid from the camera positions: the optical axes do not converge in front of \
                 the cameras"
                    .to_owned(),
            ),
        }
    }
    Fitted {
        options: out,
        choices,
    }
}

/// The cameras' poses in `odom` (optical frame), one per frame with a pose.
fn camera_poses(data: &SessionData) -> Vec<Iso3> {
    data.frames
        .iter()
        .filter_map(|f| Some(data.odom_at(f.stamp_ns)? * data.mount_at(f.stamp_ns).ok()?))
        .collect()
}

pub use crate::types::geometry::axes_convergence;

/// The region the cameras look at: the box around what each camera's image covers at the
/// depth of the axes' convergence point (its four corners' rays there), each side at least
/// half the longest.
pub fn view_bounds(data: &SessionData) -> Option<([f64; 3], [f64; 3])> {
    let cameras = camera_poses(data);
    let p = axes_convergence(&cameras)?;
    let cam = &data.camera;
    let (w, h) = (f64::from(cam.width), f64::from(cam.height));
    let mut lo = p;
    let mut hi = p;
    for c in &cameras {
        let depth = (c.rotation * Vector3::z()).dot(&(p - c.translation.vector));
        if depth <= 0.0 {
            continue;
        }
        for (u, v) in [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h)] {
            let x = (u - cam.cx) / cam.fx * depth;
            let y = (v - cam.cy) / cam.fy * depth;
            let q = c * nalgebra::Point3::new(x, y, depth);
            lo = lo.inf(&q.coords);
            hi = hi.sup(&q.coords);
        }
    }
    let longest = (hi - lo).max();
    for a in 0..3 {
        let grow = (longest / 2.0 - (hi[a] - lo[a])).max(0.0) / 2.0;
        lo[a] -= grow;
        hi[a] += grow;
    }
    (longest > 0.0 && longest.is_finite()).then_some((lo.into(), hi.into()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, Translation3, UnitQuaternion};

    /// A camera at `eye` looking at `target` (OpenCV axes: z forward).
    fn look_at(eye: [f64; 3], target: [f64; 3]) -> Iso3 {
        let (e, t) = (Point3::from(eye), Point3::from(target));
        // face_towards puts +z along the direction; any roll will do here.
        let r = UnitQuaternion::face_towards(&(t - e), &Vector3::new(0.0, 0.0, 1.0));
        Iso3::from_parts(Translation3::from(e.coords), r)
    }

    #[test]
    fn axes_converge_on_the_point_they_look_at() {
        let target = [0.3, -0.2, 0.5];
        let cams: Vec<Iso3> = [[4.0, 0.0, 2.0], [0.0, 4.0, 3.0], [-3.0, -3.0, 1.0]]
            .iter()
            .map(|e| look_at(*e, target))
            .collect();
        let p = axes_convergence(&cams).unwrap();
        assert!((p - Vector3::from(target)).norm() < 1e-9, "{p}");
        // Looking away: the point lies behind every camera.
        let away: Vec<Iso3> = [[4.0, 0.0, 2.0], [0.0, 4.0, 3.0]]
            .iter()
            .map(|e| look_at(*e, [2.0 * e[0], 2.0 * e[1], 2.0 * e[2]]))
            .collect();
        assert_eq!(axes_convergence(&away), None);
        // Parallel axes: no point.
        let parallel = vec![
            look_at([0.0, 0.0, 0.0], [1.0, 0.0, 0.0]),
            look_at([0.0, 1.0, 0.0], [1.0, 1.0, 0.0]),
        ];
        assert_eq!(axes_convergence(&parallel), None);
    }
}
