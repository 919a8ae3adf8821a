//! Frames, poses and the pinhole camera: pure math, no I/O.
//!
//! Conventions (REP 103/105): `odom` is the fixed world frame, z up; `base_link` has x
//! forward, y left, z up; `camera_optical_frame` has z forward, x right, y down. A transform
//! named `a_from_b` maps coordinates in frame b to frame a. Image pixel (u, v) has its centre
//! at (u + 0.5, v + 0.5) in continuous image coordinates, matching ROS CameraInfo K.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// A rigid 3D transform (rotation, then translation in metres); named `a_from_b` when it maps
/// coordinates in frame b to frame a.
pub type Iso3 = Isometry3<f64>;

/// Pose from a translation and a quaternion (x, y, z, w); `None` if a value is not finite or
/// the quaternion is degenerate.
pub fn iso_from_parts(t: [f64; 3], q_xyzw: [f64; 4]) -> Option<Iso3> {
    if !t.iter().chain(q_xyzw.iter()).all(|v| v.is_finite()) {
        return None;
    }
    let q = nalgebra::Quaternion::new(q_xyzw[3], q_xyzw[0], q_xyzw[1], q_xyzw[2]);
    let norm = q.norm();
    if norm.is_nan() || norm <= 1e-9 {
        return None;
    }
    Some(Iso3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_quaternion(q),
    ))
}

/// A planar robot pose in `odom`: position (x, y) and heading about z.
pub fn iso_from_xy_yaw(x: f64, y: f64, yaw: f64) -> Iso3 {
    Iso3::from_parts(
        Translation3::new(x, y, 0.0),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
    )
}

/// Heading (rotation about z) of a pose, radians in (-pi, pi].
pub fn yaw_of(iso: &Iso3) -> f64 {
    let r = iso.rotation.to_rotation_matrix();
    let m = r.matrix();
    m[(1, 0)].atan2(m[(0, 0)])
}

/// An angle wrapped into (-pi, pi]. (The simulator's recordings depend on this formula bit
/// for bit.)
pub fn wrap_angle(a: f64) -> f64 {
    use std::f64::consts::PI;
    let w = (a + PI).rem_euclid(2.0 * PI) - PI;
    if w <= -PI { w + 2.0 * PI } else { w }
}

/// The `base_link -> camera_optical_frame` mount: camera at `position` in base_link, looking
/// along base_link +x, pitched down by `pitch_down_rad`.
pub fn camera_mount(position: [f64; 3], pitch_down_rad: f64) -> Iso3 {
    // Columns: optical x (right) = -y_base, optical y (down) = -z_base, optical z = +x_base.
    let base_from_optical_level = Rotation3::from_matrix_unchecked(Matrix3::new(
        0.0, 0.0, 1.0, //
        -1.0, 0.0, 0.0, //
        0.0, -1.0, 0.0,
    ));
    let pitch = Rotation3::from_axis_angle(&Vector3::y_axis(), pitch_down_rad);
    let r = pitch * base_from_optical_level;
    Iso3::from_parts(
        Translation3::new(position[0], position[1], position[2]),
        UnitQuaternion::from_rotation_matrix(&r),
    )
}

/// Linear interpolation of position and slerp of rotation; `s` in [0, 1].
pub fn interpolate(a: &Iso3, b: &Iso3, s: f64) -> Iso3 {
    let t = a.translation.vector.lerp(&b.translation.vector, s);
    let r = a.rotation.slerp(&b.rotation, s);
    Iso3::from_parts(Translation3::from(t), r)
}

/// A distortion-free pinhole camera.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Camera {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Horizontal focal length, pixels (`K[0]`); positive.
    pub fx: f64,
    /// Vertical focal length, pixels (`K[4]`); positive.
    pub fy: f64,
    /// Principal point, u in continuous image coordinates (pixel centres at +0.5), pixels (`K[2]`).
    pub cx: f64,
    /// Principal point, v in continuous image coordinates, pixels (`K[5]`).
    pub cy: f64,
}

impl Camera {
    /// From a K matrix (row-major, as in CameraInfo); `None` unless width, height and focal
    /// lengths are positive and finite and the principal point lies within an image's size
    /// of the image.
    pub fn from_k(width: u32, height: u32, k: [f64; 9]) -> Option<Self> {
        let c = Self {
            width,
            height,
            fx: k[0],
            fy: k[4],
            cx: k[2],
            cy: k[5],
        };
        // The principal point within an image's size of the image: a camera whose axis
        // meets the image plane farther out (cx 1e9 from a garbage field) sees nothing the
        // grid holds, and the replay only said so at the end.
        let (w, h) = (f64::from(width), f64::from(height));
        let ok = c.width > 0
            && c.height > 0
            && [c.fx, c.fy, c.cx, c.cy].iter().all(|v| v.is_finite())
            && c.fx > 0.0
            && c.fy > 0.0
            && (-w..=2.0 * w).contains(&c.cx)
            && (-h..=2.0 * h).contains(&c.cy);
        ok.then_some(c)
    }

    /// Camera with a given horizontal field of view, principal point at the image centre.
    pub fn with_hfov(width: u32, height: u32, hfov_rad: f64) -> Self {
        let fx = f64::from(width) / 2.0 / (hfov_rad / 2.0).tan();
        Self {
            width,
            height,
            fx,
            fy: fx,
            cx: f64::from(width) / 2.0,
            cy: f64::from(height) / 2.0,
        }
    }

    /// Continuous image coordinates of a point in the optical frame; `None` behind the camera.
    #[inline]
    pub fn project(&self, p: &Point3<f64>) -> Option<(f64, f64)> {
        if p.z <= 1e-9 {
            return None;
        }
        Some((self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy))
    }

    /// Unit ray in the optical frame through continuous image coordinates (u, v).
    pub fn ray(&self, u: f64, v: f64) -> Vector3<f64> {
        Vector3::new((u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0).normalize()
    }
}

/// The point nearest to every optical axis in the least-squares sense; `None` when the axes
/// are (nearly) parallel or the point lies behind more than half of the cameras.
pub fn axes_convergence(cameras: &[Iso3]) -> Option<Vector3<f64>> {
    let fit = axes_fit(cameras)?;
    (2 * fit.in_front > cameras.len()).then_some(fit.point)
}

/// How the cameras' optical axes (+z) meet: the least-squares point nearest to all of them
/// and how well it fits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxesFit {
    /// The point nearest to every axis (as lines, in front of the cameras or not).
    pub point: Vector3<f64>,
    /// Cameras that have the point in front of them.
    pub in_front: usize,
    /// Root mean square distance of the axes from the point.
    pub rms_miss: f64,
    /// Median distance of the cameras from the point.
    pub median_distance: f64,
}

/// [`AxesFit`] of `cameras`; `None` for fewer than two or (nearly) parallel axes.
pub fn axes_fit(cameras: &[Iso3]) -> Option<AxesFit> {
    let mut a = Matrix3::zeros();
    let mut b = Vector3::zeros();
    for c in cameras {
        let d = c.rotation * Vector3::z();
        let m = Matrix3::identity() - d * d.transpose();
        a += m;
        b += m * c.translation.vector;
    }
    let eig = a.symmetric_eigen().eigenvalues;
    // Parallel axes leave one direction unconstrained: its eigenvalue is ~0.
    if cameras.len() < 2 || eig.min() < 1e-3 * eig.max() {
        return None;
    }
    let p = a.try_inverse()? * b;
    let mut in_front = 0;
    let mut miss2 = 0.0;
    let mut distances = Vec::with_capacity(cameras.len());
    for c in cameras {
        let d = c.rotation * Vector3::z();
        let to_p = p - c.translation.vector;
        in_front += usize::from(d.dot(&to_p) > 0.0);
        miss2 += (to_p - d * d.dot(&to_p)).norm_squared();
        distances.push(to_p.norm());
    }
    distances.sort_by(f64::total_cmp);
    Some(AxesFit {
        point: p,
        in_front,
        rms_miss: (miss2 / cameras.len() as f64).sqrt(),
        median_distance: distances[distances.len() / 2],
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx_eq::close;

    mod approx_eq {
        pub fn close(a: f64, b: f64) -> bool {
            (a - b).abs() < 1e-9
        }
    }

    #[test]
    fn mount_looks_along_base_x() {
        let m = camera_mount([0.0, 0.0, 1.0], 0.0);
        // optical z axis -> base +x; optical x -> base -y; optical y -> base -z
        let z = m.rotation * Vector3::z();
        let x = m.rotation * Vector3::x();
        let y = m.rotation * Vector3::y();
        assert!(close(z.x, 1.0) && close(x.y, -1.0) && close(y.z, -1.0));
        let p = m * Point3::new(0.0, 0.0, 2.0);
        assert!(close(p.x, 2.0) && close(p.z, 1.0));
    }

    #[test]
    fn pitch_down_tilts_forward_axis_below_horizon() {
        let m = camera_mount([0.0, 0.0, 1.0], 0.2);
        let z = m.rotation * Vector3::z();
        assert!(close(z.z, -(0.2f64).sin()), "{z}");
    }

    #[test]
    fn project_and_ray_are_inverse() {
        let c = Camera::with_hfov(256, 240, 1.0);
        let r = c.ray(40.5, 200.25);
        let (u, v) = c.project(&Point3::from(r * 3.0)).unwrap();
        assert!(close(u, 40.5) && close(v, 200.25));
        assert!(c.project(&Point3::new(0.0, 0.0, -1.0)).is_none());
    }

    #[test]
    fn yaw_roundtrip_and_bad_quaternion() {
        let p = iso_from_xy_yaw(1.0, 2.0, 2.5);
        assert!(close(yaw_of(&p), 2.5));
        assert!(iso_from_parts([0.0; 3], [0.0; 4]).is_none());
        assert!(iso_from_parts([f64::NAN, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]).is_none());
        let q = p.rotation.quaternion();
        let back = iso_from_parts(p.translation.vector.into(), [q.i, q.j, q.k, q.w]).unwrap();
        assert!((back.translation.vector - p.translation.vector).norm() < 1e-12);
    }
}
