//! Where an object is when the grid cannot bound it: the centre triangulated from the boxes
//! of its detections, one ray per frame, as a surveyor would from the labelled rectangles.
//!
//! Why: the belief is a visual hull. A ground robot's grid starts at the floor, so the hull of
//! an object standing on it is closed below; a hand-held or arm camera looks down at the
//! object from above in every view, and the cells under the object are hidden behind it in
//! all of them, so they keep its evidence and the hull grows a cone downwards (the milk
//! carton of `../shared/realdata`: the extent's centre 15 % of its size below the centre
//! triangulated from its rectangles). The centre of a detection's box is the projection of
//! (nearly) the same point in every view, whatever the hull does behind the object.
//!
//! Invariants: a pure function of the frames' detections and poses; frames in order, ties to
//! the first; each frame's ray chosen around where the chosen rays meet (first the extent's
//! centre); a box touching the image border is never used (the object may run past it);
//! a [`NotTriangulated`] reason rather than a guess when fewer than [`MIN_RAYS`] frames agree, when their
//! directions span less than [`MIN_SPREAD_DEG`], when they do not meet
//! ([`MAX_RMS_MISS_FRACTION`]), or when they meet outside the object's own box in the grid.

use nalgebra::{Matrix3, Vector3};

use crate::fuse::objects::Object;
use crate::fuse::refine::Detection;
use crate::types::geometry::{Camera, Iso3};

/// Frames that must see the object wholly (a box clear of the border) to triangulate it.
pub const MIN_RAYS: usize = 3;
/// Largest angle between two of the kept rays must reach this, degrees: rays from nearly one
/// direction place the point along them no better than the hull does.
pub const MIN_SPREAD_DEG: f64 = 10.0;
/// A ray whose miss distance exceeds this many times the median miss is dropped (worst
/// first, one at a time): a box that merged the object with its neighbour, a false detection.
pub const OUTLIER_FACTOR: f64 = 3.0;
/// The kept rays must meet: their rms miss at most this fraction of the diagonal of the
/// object's box in the grid. Measured on `../shared/realdata`: the apple 2.8 %, the milk
/// carton 2.4 %, the banana 8.5 % (its model also fires on the apple it curves around), the
/// DTU house 15.6 % (it runs past the image in every view, and the boxes clear of the border
/// are pieces of it, whose centres are not the house's).
pub const MAX_RMS_MISS_FRACTION: f64 = 0.1;

/// An object's centre triangulated from its detections.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RayCentre {
    /// The point nearest every kept ray (least squares), in `odom`, the session's units.
    pub centre_m: [f64; 3],
    /// Frames whose box was kept (one ray each).
    pub rays: usize,
    /// Root mean square of the kept rays' distances from the point, the session's units.
    pub rms_miss_m: f64,
    /// Largest angle between two kept rays, degrees.
    pub spread_deg: f64,
    /// Times the rays were chosen again around where the previous choice met and the centre
    /// moved (0: the first choice, around the extent's centre, stood). Absent in reports
    /// written before the choice was repeated.
    #[serde(default)]
    pub rechosen: usize,
    /// The centre the first choice gave, when it was chosen again (`rechosen` > 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub first_choice_centre_m: Option<[f64; 3]>,
}

/// One fused frame as the triangulation sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct View {
    /// The camera pose the frame was fused with.
    pub odom_from_camera: Iso3,
    /// Its detections (rectified pixels, the fused camera's).
    pub detections: Vec<Detection>,
}

/// Why an object's detections did not give its centre (the report and stdout say which).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NotTriangulated {
    /// Too few frames see the object wholly.
    #[error("{rays} frame(s) see it wholly, fewer than {MIN_RAYS}")]
    FewRays {
        /// Rays left.
        rays: usize,
    },
    /// The rays are (nearly) parallel.
    #[error("its {rays} rays are parallel")]
    Parallel {
        /// Rays left.
        rays: usize,
    },
    /// The rays come from nearly one direction.
    #[error("its {rays} rays span {spread_deg:.1} deg, under {MIN_SPREAD_DEG} deg")]
    Narrow {
        /// Rays kept.
        rays: usize,
        /// Largest angle between two of them, degrees.
        spread_deg: f64,
    },
    /// The rays meet outside the object's box in the grid.
    #[error("its {rays} rays meet outside the object's box")]
    Outside {
        /// Rays kept.
        rays: usize,
    },
    /// The rays do not meet.
    #[error(
        "its {rays} rays miss each other by {rms_percent:.1} % of its box's diagonal (rms), over the limit of {} %",
        MAX_RMS_MISS_FRACTION * 100.0
    )]
    Miss {
        /// Rays kept.
        rays: usize,
        /// Their rms miss, percent of the diagonal of the object's box.
        rms_percent: f64,
    },
}

/// Misses below this fraction of the object's half-diagonal are never outliers: a box's
/// centre is quantised to half a tile, and a camera that stood still gives the same ray
/// many times, whose equal small misses would otherwise pull the median under every other
/// ray's (2 % of the diagonal: under the misses the real captures' rays show, 2.4 % and more).
pub const MISS_FLOOR_FRACTION: f64 = 0.04;

/// Times the rays are chosen again, at most, around the point the previous choice
/// triangulated (the first choice is made around the extent's centre). The bound keeps a
/// choice that alternates between two sets of rays from looping.
pub const MAX_RESELECTIONS: usize = 5;

/// The centre of `object` triangulated from the centres of its detections' boxes in `views`;
/// see the module doc and [`NotTriangulated`] for when it is not.
///
/// Each view's ray is the one passing nearest a seed: first the centre of the object's
/// extent, then the point the chosen rays meet at, until the choice gives the same centre
/// again (at most [`MAX_RESELECTIONS`] times). Why: where the hull is much larger than the
/// object (the banana of `../shared/realdata`: a hull 2.2 x 2.4 x 1.4 of the capture's units)
/// its centre lies off the object, and in views where the object's detections split in two
/// (a weak stalk, a body in two groups) the piece nearest that centre is not its box. A
/// choice that then fails to triangulate keeps the previous centre.
pub fn ray_centre(
    object: &Object,
    views: &[View],
    camera: &Camera,
) -> Result<RayCentre, NotTriangulated> {
    let first = ray_centre_around(object, views, camera, Vector3::from(object.centroid_m))?;
    let (mut best, mut rechosen) = (first, 0);
    for _ in 0..MAX_RESELECTIONS {
        match ray_centre_around(object, views, camera, Vector3::from(best.centre_m)) {
            Ok(again) if again != best => {
                best = again;
                rechosen += 1;
            }
            _ => break,
        }
    }
    if rechosen > 0 {
        best.rechosen = rechosen;
        best.first_choice_centre_m = Some(first.centre_m);
    }
    Ok(best)
}

/// [`ray_centre`] with each view's ray chosen once, as the one passing nearest `seed`.
fn ray_centre_around(
    object: &Object,
    views: &[View],
    camera: &Camera,
    seed: Vector3<f64>,
) -> Result<RayCentre, NotTriangulated> {
    let lo = Vector3::from(object.bbox_min_m);
    let hi = Vector3::from(object.bbox_max_m);
    // A ray is a sighting of the object when it passes within the object's half-diagonal of
    // its extent's centre: the hull is larger than the object, never smaller.
    let gate = 0.5 * (hi - lo).norm();
    let mut rays: Vec<(Vector3<f64>, Vector3<f64>)> = views
        .iter()
        .filter_map(|v| nearest_ray(v, camera, &seed, gate))
        .collect();
    loop {
        if rays.len() < MIN_RAYS {
            return Err(NotTriangulated::FewRays { rays: rays.len() });
        }
        let x = nearest_point(&rays).ok_or(NotTriangulated::Parallel { rays: rays.len() })?;
        let miss: Vec<f64> = rays.iter().map(|(o, d)| distance(&x, o, d)).collect();
        let (worst, worst_miss) = miss.iter().enumerate().fold(
            (0, f64::NEG_INFINITY),
            |a, (k, &m)| if m > a.1 { (k, m) } else { a },
        );
        if worst_miss > (OUTLIER_FACTOR * median(&miss)).max(MISS_FLOOR_FRACTION * gate) {
            rays.remove(worst);
            continue;
        }
        let spread_deg = spread(&rays).to_degrees();
        let inside = (0..3).all(|a| x[a] >= lo[a] && x[a] <= hi[a]);
        let rms = (miss.iter().map(|m| m * m).sum::<f64>() / miss.len() as f64).sqrt();
        let n = rays.len();
        if spread_deg < MIN_SPREAD_DEG {
            return Err(NotTriangulated::Narrow {
                rays: n,
                spread_deg,
            });
        }
        if !inside {
            return Err(NotTriangulated::Outside { rays: n });
        }
        // A NaN miss (a degenerate box or pose) is refused too.
        if rms.is_nan() || rms > MAX_RMS_MISS_FRACTION * 2.0 * gate {
            return Err(NotTriangulated::Miss {
                rays: n,
                rms_percent: 100.0 * rms / (2.0 * gate),
            });
        }
        return Ok(RayCentre {
            centre_m: [x.x, x.y, x.z],
            rays: rays.len(),
            rms_miss_m: rms,
            spread_deg,
            rechosen: 0,
            first_choice_centre_m: None,
        });
    }
}

/// The ray through the centre of the view's box (clear of the border) passing nearest to
/// `seed`, if one passes within `gate`: (origin, unit direction) in `odom`.
fn nearest_ray(
    view: &View,
    camera: &Camera,
    seed: &Vector3<f64>,
    gate: f64,
) -> Option<(Vector3<f64>, Vector3<f64>)> {
    let origin = view.odom_from_camera.translation.vector;
    let mut best: Option<(f64, Vector3<f64>)> = None;
    for d in view.detections.iter().filter(|d| !d.at_border) {
        let [u, v] = d.box_centre_px();
        let dir = view.odom_from_camera.rotation * camera.ray(u, v);
        // Behind the camera is not a sighting.
        if (seed - origin).dot(&dir) <= 0.0 {
            continue;
        }
        let miss = distance(seed, &origin, &dir);
        if miss <= gate && best.is_none_or(|(m, _)| miss < m) {
            best = Some((miss, dir));
        }
    }
    best.map(|(_, dir)| (origin, dir))
}

/// Distance from `x` to the line through `origin` along the unit `dir`.
fn distance(x: &Vector3<f64>, origin: &Vector3<f64>, dir: &Vector3<f64>) -> f64 {
    let r = x - origin;
    (r - dir * r.dot(dir)).norm()
}

/// The point nearest every line in the least-squares sense; `None` when they are parallel.
fn nearest_point(rays: &[(Vector3<f64>, Vector3<f64>)]) -> Option<Vector3<f64>> {
    let mut a = Matrix3::zeros();
    let mut b = Vector3::zeros();
    for (o, d) in rays {
        let p = Matrix3::identity() - d * d.transpose();
        a += p;
        b += p * o;
    }
    a.try_inverse().map(|inv| inv * b)
}

/// Median of a non-empty slice (the mean of the middle two for an even count).
fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

/// Largest angle between two of the rays' directions, radians.
fn spread(rays: &[(Vector3<f64>, Vector3<f64>)]) -> f64 {
    let mut min_cos = 1.0f64;
    for (i, (_, a)) in rays.iter().enumerate() {
        for (_, b) in &rays[i + 1..] {
            min_cos = min_cos.min(a.dot(b));
        }
    }
    min_cos.clamp(-1.0, 1.0).acos()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::types::geometry::{camera_mount, iso_from_xy_yaw};
    use nalgebra::Point3;

    /// A detection whose box is centred on the projection of `p` (a 3 x 3-tile box of 8 px).
    fn box_at(cam: &Camera, odom_from_camera: &Iso3, p: Vector3<f64>) -> Detection {
        let (u, v) = cam
            .project(&(odom_from_camera.inverse() * Point3::from(p)))
            .unwrap();
        Detection {
            centroid_px: [u, v],
            box_min_px: [u - 12.0, v - 12.0],
            box_max_px: [u + 12.0, v + 12.0],
            at_border: false,
        }
    }

    /// A level camera 0.5 m up on a circle of 2 m about the origin at angle `a`, facing it.
    fn pose_at(a: f64) -> Iso3 {
        let (x, y) = (2.0 * a.cos(), 2.0 * a.sin());
        iso_from_xy_yaw(x, y, (-y).atan2(-x)) * camera_mount([0.0, 0.0, 0.5], 0.0)
    }

    fn object(centroid: [f64; 3], half: f64) -> Object {
        Object::cube(centroid, half)
    }

    /// Six cameras on a circle 2 m from a point, 1.2 m up, pitched down at it: every box is
    /// centred on the point's projection, so the rays meet exactly at the point, whatever the
    /// hull's own (here deliberately low) extent centre says.
    #[test]
    fn boxes_centred_on_a_point_triangulate_to_it() {
        let cam = Camera::with_hfov(256, 240, 1.05);
        let target = Vector3::new(0.3, -0.2, 0.5);
        let views: Vec<View> = (0..6)
            .map(|k| {
                let a = f64::from(k) * 0.9;
                let (x, y) = (target.x + 2.0 * a.cos(), target.y + 2.0 * a.sin());
                let yaw = (target.y - y).atan2(target.x - x);
                let pitch = (1.2f64 - target.z).atan2(2.0);
                let pose = iso_from_xy_yaw(x, y, yaw) * camera_mount([0.0, 0.0, 1.2], pitch);
                View {
                    detections: vec![box_at(&cam, &pose, target)],
                    odom_from_camera: pose,
                }
            })
            .collect();
        // The hull's extent centre 0.2 m below the point (the downward cone).
        let hull = object([0.3, -0.2, 0.3], 0.4);
        let rc = ray_centre(&hull, &views, &cam).unwrap();
        let err = (Vector3::from(rc.centre_m) - target).norm();
        assert!(err < 1e-9, "{rc:?}");
        assert_eq!(rc.rays, 6);
        assert!(rc.rms_miss_m < 1e-9);
        // The widest pair: cameras 2.7 rad apart around the circle (e.g. 1.8 and 4.5 rad),
        // both pitched down by t = atan(0.7 / 2): cos = cos^2 t cos 2.7 + sin^2 t.
        let t = 0.7f64.atan2(2.0);
        let want = (t.cos().powi(2) * 2.7f64.cos() + t.sin().powi(2)).acos();
        assert!((rc.spread_deg - want.to_degrees()).abs() < 1e-9, "{rc:?}");
        assert!((rc.spread_deg - 134.13).abs() < 0.01, "{rc:?}");
    }

    /// A seventh view whose box sits on something else 0.3 m to the side is dropped; a box at
    /// the border is never used; two views are too few.
    #[test]
    fn outliers_border_boxes_and_too_few_views() {
        let cam = Camera::with_hfov(256, 240, 1.05);
        let target = Vector3::new(0.0, 0.0, 0.5);
        let mut views: Vec<View> = (0..6)
            .map(|k| {
                let pose = pose_at(f64::from(k) * 0.5);
                View {
                    detections: vec![box_at(&cam, &pose, target)],
                    odom_from_camera: pose,
                }
            })
            .collect();
        let pose = pose_at(3.5);
        let side = pose.rotation * Vector3::x() * 0.3;
        views.push(View {
            detections: vec![box_at(&cam, &pose, target + side)],
            odom_from_camera: pose,
        });
        let rc = ray_centre(&object([0.0, 0.0, 0.5], 0.5), &views, &cam).unwrap();
        assert_eq!(rc.rays, 6, "{rc:?}");
        assert!(
            (Vector3::from(rc.centre_m) - target).norm() < 1e-9,
            "{rc:?}"
        );
        // Boxes at the border are not sightings.
        let mut bordered = views.clone();
        for v in &mut bordered[2..] {
            v.detections[0].at_border = true;
        }
        assert_eq!(
            ray_centre(&object([0.0, 0.0, 0.5], 0.5), &bordered, &cam),
            Err(NotTriangulated::FewRays { rays: 2 })
        );
        // Rays that do not meet: every box 0.1 m off the point, alternately left and right,
        // misses it by 0.1 m, a sixth of the 0.6 m diagonal of a 0.3 m box (the limit is a
        // tenth); the same boxes meet well enough for a 1.0 m box.
        let scattered: Vec<View> = (0..6)
            .map(|k| {
                let pose = pose_at(f64::from(k) * 0.5);
                let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
                let off = pose.rotation * Vector3::x() * (0.1 * sign);
                View {
                    detections: vec![box_at(&cam, &pose, target + off)],
                    odom_from_camera: pose,
                }
            })
            .collect();
        let why = ray_centre(&object([0.0, 0.0, 0.5], 0.15), &scattered, &cam).unwrap_err();
        match why {
            // A sixth of the diagonal, give or take the lines' geometry.
            NotTriangulated::Miss {
                rays: 6,
                rms_percent,
            } => {
                assert!(rms_percent > 12.0 && rms_percent < 20.0, "{why}")
            }
            _ => panic!("{why:?}"),
        }
        assert!(why.to_string().contains("rays miss each other by"), "{why}");
        let loose = ray_centre(&object([0.0, 0.0, 0.5], 0.5), &scattered, &cam).unwrap();
        assert!(
            loose.rms_miss_m > 0.05 && loose.rms_miss_m < 0.1,
            "{loose:?}"
        );
    }

    /// Eight views of a point; in three of them a second detection lies on the ray through
    /// the hull's centre, 0.25 m to the side of the point, where a single choice around that
    /// centre takes it. Chosen again around where the first rays meet, every view gives the
    /// point's own box, and the rays meet exactly at it.
    #[test]
    fn rays_are_chosen_again_around_where_they_meet() {
        let cam = Camera::with_hfov(256, 240, 1.05);
        let target = Vector3::new(0.0, 0.0, 0.5);
        let beside = Vector3::new(0.0, 0.25, 0.5);
        let views: Vec<View> = (0..8)
            .map(|k| {
                let pose = pose_at(f64::from(k) * 0.4);
                let mut detections = vec![box_at(&cam, &pose, target)];
                if k % 3 == 1 {
                    detections.push(box_at(&cam, &pose, beside));
                }
                View {
                    detections,
                    odom_from_camera: pose,
                }
            })
            .collect();
        let hull = object([0.0, 0.25, 0.5], 0.5);
        let once = ray_centre_around(&hull, &views, &cam, beside).unwrap();
        let off = (Vector3::from(once.centre_m) - target).norm();
        assert!(off > 0.01, "{once:?}");
        let rc = ray_centre(&hull, &views, &cam).unwrap();
        assert!(
            (Vector3::from(rc.centre_m) - target).norm() < 1e-9,
            "{rc:?} (once: {once:?})"
        );
        assert_eq!(rc.rays, 8);
        assert!(rc.rms_miss_m < 1e-9, "{rc:?}");
        assert!(rc.rechosen >= 1, "{rc:?}");
        assert_eq!(rc.first_choice_centre_m, Some(once.centre_m));
    }

    /// Rays that meet outside the object's box belong to something else: no location.
    #[test]
    fn rays_meeting_outside_the_object_are_not_its_centre() {
        let cam = Camera::with_hfov(256, 240, 1.05);
        let target = Vector3::new(0.0, 0.0, 0.5);
        let views: Vec<View> = (0..4)
            .map(|k| {
                let a = f64::from(k) * 0.6;
                let (x, y) = (2.0 * a.cos(), 2.0 * a.sin());
                let pose = iso_from_xy_yaw(x, y, (-y).atan2(-x)) * camera_mount([0.0; 3], 0.0);
                View {
                    detections: vec![box_at(&cam, &pose, target)],
                    odom_from_camera: pose,
                }
            })
            .collect();
        // An object 0.3 m away whose box (half-size 0.2) misses the point, with a gate (its
        // half-diagonal, 0.35 m) that still admits the rays.
        assert_eq!(
            ray_centre(&object([0.3, 0.0, 0.5], 0.2), &views, &cam),
            Err(NotTriangulated::Outside { rays: 4 })
        );
        assert!(ray_centre(&object([0.1, 0.0, 0.5], 0.2), &views, &cam).is_ok());
    }

    /// A camera that stood still gives one ray many times: ten identical rays and six from
    /// 30 to 60 degrees away, each of those 3 mm off the point. The identical rays' equal
    /// misses are the median; without a floor every other ray was an outlier in turn (and
    /// then too few directions were left). With it all are kept and the point is found.
    #[test]
    fn repeated_rays_do_not_make_the_others_outliers() {
        let cam = Camera::with_hfov(256, 240, 1.05);
        let target = Vector3::new(0.0, 0.0, 0.5);
        let mut views: Vec<View> = (0..10)
            .map(|_| {
                let pose = pose_at(0.0);
                View {
                    detections: vec![box_at(&cam, &pose, target)],
                    odom_from_camera: pose,
                }
            })
            .collect();
        for k in 0..6 {
            let pose = pose_at(0.5 + 0.1 * f64::from(k));
            let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
            let off = pose.rotation * Vector3::x() * (0.003 * sign);
            views.push(View {
                detections: vec![box_at(&cam, &pose, target + off)],
                odom_from_camera: pose,
            });
        }
        let rc = ray_centre(&object([0.0, 0.0, 0.5], 0.15), &views, &cam).unwrap();
        assert_eq!(rc.rays, 16, "{rc:?}");
        assert!(
            (Vector3::from(rc.centre_m) - target).norm() < 0.01,
            "{rc:?}"
        );
    }
}
