//! Evaluation without 3D ground truth, against the label rectangles of a session: the
//! object's centre triangulated from the centres of the rectangles of the frames where it is
//! wholly in view, the located centre's error against it (in the session's units and as a
//! fraction of the object's size), and the frames whose rectangle contains the located
//! centre's projection.
//!
//! Invariants: rectangle centres are undistorted before they become rays and projections are
//! distorted before they are tested, so both live in the recorded image; a rectangle touching
//! the image border is not "wholly in view" and only counts for the containment test; the
//! object's size is the median over the triangulating frames of the rectangle's height at the
//! depth of the triangulated centre (image rows: the camera's vertical, the object's height
//! for an upright camera).

use nalgebra::{Matrix3, Point3, Vector3};

use crate::io::msgs::RegionOfInterest;
use crate::types::geometry::{Camera, Iso3};
use crate::types::lens::{Distortion, distorted_pixel, undistorted_pixel};

/// One labelled view of an object: the camera that took it and the rectangle drawn on it.
#[derive(Debug, Clone, PartialEq)]
pub struct RectView {
    /// Header stamp of the frame, ns since the Unix epoch.
    pub stamp_ns: i64,
    /// Camera pose in the session's world (`odom`), OpenCV optical axes.
    pub odom_from_camera: Iso3,
    /// The rectangle in pixels of the recorded (distorted) image.
    pub roi: RegionOfInterest,
}

/// The camera of the views: intrinsics and lens of the recorded images.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RectCamera {
    /// Pinhole K and image size.
    pub camera: Camera,
    /// Lens distortion of the recorded images.
    pub distortion: Distortion,
}

/// The object's centre from the rectangles.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Triangulated {
    /// Least-squares point nearest to the rays through the rectangles' centres, `odom`.
    pub center: [f64; 3],
    /// Views used (rectangles wholly in view, the point in front of the camera).
    pub views: usize,
    /// Root mean square distance of the rays from the point, session units.
    pub residual_rms: f64,
    /// Largest distance of a ray from the point, session units.
    pub residual_max: f64,
    /// Object size: median rectangle height at the point's depth, session units.
    pub size: f64,
}

/// The located object scored against the rectangles.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RectScore {
    /// The object's name on /labels.
    pub object: String,
    /// Its triangulated centre, or None when fewer than two views have it wholly in view.
    pub triangulated: Option<Triangulated>,
    /// The located centre scored (the fused object nearest the triangulated centre).
    pub located: Option<[f64; 3]>,
    /// Distance from the triangulated centre, session units.
    pub error: Option<f64>,
    /// `error` as a fraction of the triangulated size.
    pub error_fraction: Option<f64>,
    /// Frames with a rectangle of the object.
    pub frames: usize,
    /// Of those, frames whose rectangle holds the object wholly in view (clear of the image's
    /// border): with two or more and no triangulated centre, their rays meet behind the
    /// cameras.
    pub frames_wholly_in_view: usize,
    /// Of those, frames whose rectangle contains the located centre's projection.
    pub frames_inside: usize,
}

impl RectScore {
    /// `frames_inside / frames`, or None without frames or a located centre.
    pub fn inside_fraction(&self) -> Option<f64> {
        (self.frames > 0 && self.located.is_some())
            .then(|| self.frames_inside as f64 / self.frames as f64)
    }
}

fn wholly_in_view(roi: &RegionOfInterest, cam: &Camera) -> bool {
    // In u64: a rectangle of a bad label (x near 2^32) wrapped around and counted as inside.
    let end = |offset: u32, size: u32| u64::from(offset) + u64::from(size);
    roi.x_offset > 0
        && roi.y_offset > 0
        && end(roi.x_offset, roi.width) < u64::from(cam.width)
        && end(roi.y_offset, roi.height) < u64::from(cam.height)
}

/// A ray in `odom`: origin and unit direction.
type Ray = (Vector3<f64>, Vector3<f64>);

/// The ray through a pixel of the recorded image.
fn ray(cam: &RectCamera, pose: &Iso3, u: f64, v: f64) -> Ray {
    let (iu, iv) = undistorted_pixel(&cam.camera, &cam.distortion, u, v);
    let d = pose.rotation * cam.camera.ray(iu, iv);
    (pose.translation.vector, d.normalize())
}

/// Triangulates the object from the views that have it wholly in view.
pub fn triangulate(cam: &RectCamera, views: &[RectView]) -> Option<Triangulated> {
    let rays: Vec<(&RectView, Ray)> = views
        .iter()
        .filter(|v| wholly_in_view(&v.roi, &cam.camera))
        .map(|v| {
            let r = &v.roi;
            let u = f64::from(r.x_offset) + f64::from(r.width) / 2.0;
            let y = f64::from(r.y_offset) + f64::from(r.height) / 2.0;
            (v, ray(cam, &v.odom_from_camera, u, y))
        })
        .collect();
    let mut a = Matrix3::zeros();
    let mut b = Vector3::zeros();
    for (_, (o, d)) in &rays {
        let m = Matrix3::identity() - d * d.transpose();
        a += m;
        b += m * o;
    }
    if rays.len() < 2 {
        return None;
    }
    let p = a.try_inverse()? * b;
    let dist = |(o, d): &Ray| {
        let w = p - o;
        (w - d * w.dot(d)).norm()
    };
    let residuals: Vec<f64> = rays.iter().map(|(_, r)| dist(r)).collect();
    let mut sizes: Vec<f64> = rays
        .iter()
        .filter_map(|(v, _)| {
            let depth = (v.odom_from_camera.inverse() * Point3::from(p)).z;
            (depth > 0.0).then(|| f64::from(v.roi.height) * depth / cam.camera.fy)
        })
        .collect();
    sizes.sort_by(f64::total_cmp);
    let size = *sizes.get(sizes.len() / 2)?;
    let n = residuals.len() as f64;
    Some(Triangulated {
        center: p.into(),
        views: sizes.len(),
        residual_rms: (residuals.iter().map(|r| r * r).sum::<f64>() / n).sqrt(),
        residual_max: residuals.iter().copied().fold(0.0, f64::max),
        size,
    })
}

/// Whether `p` (in `odom`) projects into the rectangle of view `v`.
pub fn projects_inside(cam: &RectCamera, v: &RectView, p: [f64; 3]) -> bool {
    let q = v.odom_from_camera.inverse() * Point3::from(p);
    let Some((u, y)) = cam.camera.project(&q) else {
        return false;
    };
    let (du, dv) = distorted_pixel(&cam.camera, &cam.distortion, u, y);
    let r = &v.roi;
    du >= f64::from(r.x_offset)
        && du <= f64::from(r.x_offset) + f64::from(r.width)
        && dv >= f64::from(r.y_offset)
        && dv <= f64::from(r.y_offset) + f64::from(r.height)
}

/// Scores the located centres (`candidates`, e.g. the fused objects) of `object` against its
/// rectangles: the candidate nearest the triangulated centre (or the first, when it cannot be
/// triangulated) is the located one.
pub fn score(
    object: &str,
    cam: &RectCamera,
    views: &[RectView],
    candidates: &[[f64; 3]],
) -> RectScore {
    let triangulated = triangulate(cam, views);
    let dist = |a: &[f64; 3], b: &[f64; 3]| (Vector3::from(*a) - Vector3::from(*b)).norm();
    let located = match &triangulated {
        Some(t) => candidates
            .iter()
            .min_by(|a, b| dist(a, &t.center).total_cmp(&dist(b, &t.center)))
            .copied(),
        None => candidates.first().copied(),
    };
    let error = located
        .zip(triangulated.as_ref())
        .map(|(l, t)| dist(&l, &t.center));
    let error_fraction = error.zip(triangulated.as_ref()).map(|(e, t)| e / t.size);
    let frames_inside = located.map_or(0, |l| {
        views.iter().filter(|v| projects_inside(cam, v, l)).count()
    });
    RectScore {
        object: object.to_owned(),
        triangulated,
        located,
        error,
        error_fraction,
        frames: views.len(),
        frames_wholly_in_view: views
            .iter()
            .filter(|v| wholly_in_view(&v.roi, &cam.camera))
            .count(),
        frames_inside,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    /// A rectangle whose end passes 2^32 is not in view (in u32 it wrapped to 39 and was).
    #[test]
    fn a_rectangle_past_u32_is_not_wholly_in_view() {
        let cam = Camera::with_hfov(256, 240, 1.0);
        let roi = |x: u32, w: u32| RegionOfInterest {
            x_offset: x,
            y_offset: 10,
            width: w,
            height: 50,
            do_rectify: false,
        };
        assert!(wholly_in_view(&roi(10, 50), &cam));
        assert!(!wholly_in_view(&roi(u32::MAX - 10, 50), &cam));
        assert!(!wholly_in_view(&roi(206, 50), &cam));
        assert!(wholly_in_view(&roi(205, 50), &cam));
    }

    /// A camera at `eye` looking at the origin, OpenCV axes, y down towards -z of the world.
    fn look_at_origin(eye: [f64; 3]) -> Iso3 {
        let e = Vector3::from(eye);
        let z = (-e).normalize();
        let x = z.cross(&Vector3::z()).normalize();
        let y = z.cross(&x);
        let r = nalgebra::Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
        Iso3::from_parts(
            Translation3::from(e),
            UnitQuaternion::from_rotation_matrix(&r),
        )
    }

    #[test]
    fn rectangles_around_a_known_box_triangulate_its_centre_and_size() {
        let cam = RectCamera {
            camera: Camera::with_hfov(640, 480, 1.0),
            distortion: Distortion {
                k1: -0.05,
                p1: 0.002,
                ..Distortion::default()
            },
        };
        // A 0.2 (wide) x 0.3 (tall) object at (0.1, -0.2, 0.15): rectangles of its centre's
        // projection, 0.3 tall at the centre's depth, from four sides.
        let centre = Vector3::new(0.1, -0.2, 0.15);
        let views: Vec<RectView> = [
            [3.0, 0.0, 1.0],
            [0.0, 3.0, 1.5],
            [-3.0, 0.5, 1.0],
            [0.5, -3.0, 2.0],
        ]
        .iter()
        .enumerate()
        .map(|(i, eye)| {
            let pose = look_at_origin(*eye);
            let q = pose.inverse() * Point3::from(centre);
            let (u, v) = cam.camera.project(&q).unwrap();
            let (du, dv) = distorted_pixel(&cam.camera, &cam.distortion, u, v);
            let h = 0.3 * cam.camera.fy / q.z;
            let w = 0.2 * cam.camera.fx / q.z;
            RectView {
                stamp_ns: i as i64,
                odom_from_camera: pose,
                roi: RegionOfInterest {
                    x_offset: (du - w / 2.0) as u32,
                    y_offset: (dv - h / 2.0) as u32,
                    width: w as u32,
                    height: h as u32,
                    do_rectify: false,
                },
            }
        })
        .collect();
        let t = triangulate(&cam, &views).unwrap();
        assert_eq!(t.views, 4);
        // Whole-pixel rectangles: the centre within a pixel's footprint (~5 mm at 3 m).
        assert!(
            (Vector3::from(t.center) - centre).norm() < 0.01,
            "{:?}",
            t.center
        );
        assert!((t.size - 0.3).abs() < 0.01, "{}", t.size);
        let s = score("box", &cam, &views, &[[2.0, 2.0, 2.0], [0.12, -0.2, 0.15]]);
        assert_eq!(s.located, Some([0.12, -0.2, 0.15]));
        assert!((s.error.unwrap() - 0.02).abs() < 0.01);
        assert_eq!((s.frames, s.frames_inside), (4, 4));
        let far = score("box", &cam, &views, &[[0.1, -0.2, 1.0]]);
        assert_eq!(far.frames_inside, 0);
    }
}
