//! Lens distortion (OpenCV's radial-tangential model, ROS CameraInfo `plumb_bob`) and the
//! rectification of a distorted image to the ideal pinhole camera with the same K; and what
//! makes two CameraInfos the same camera ([`camera_changes`]).
//!
//! Every stage after the replay's decoding sees rectified frames and a pinhole camera, so the
//! fuser, the pose refinement, the evaluation and the viewer honour the distortion alike; the
//! pixel coordinates of labels are moved with the same map.
//!
//! Invariants: a zero distortion is the identity, bit for bit (nothing is resampled); the
//! undistortion of a point inverts the distortion to within 1e-9 of normalised coordinates
//! inside the image for |k| of a real lens (fixed-point iterations, a fixed count).

use crate::types::geometry::Camera;
use crate::types::image::Rgb8;

/// Radial-tangential distortion of normalised image coordinates: k1, k2, p1, p2, k3.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct Distortion {
    /// Radial coefficients of r^2, r^4, r^6.
    pub k1: f64,
    /// Radial coefficient of r^4.
    pub k2: f64,
    /// Radial coefficient of r^6 (fifth in CameraInfo's `d`).
    pub k3: f64,
    /// Tangential coefficients.
    pub p1: f64,
    /// Second tangential coefficient: x moves by `p2 (r^2 + 2 x^2)`, y by `2 p2 x y`.
    pub p2: f64,
}

/// Fixed-point iterations of the undistortion (converged far beyond f64 rounding for
/// distortions of real lenses within their images).
const UNDISTORT_ITERATIONS: usize = 20;

impl Distortion {
    /// From CameraInfo's `d` for `plumb_bob` / `rational_polynomial`'s first five (k1, k2,
    /// p1, p2, k3); missing trailing values are 0.
    pub fn from_plumb_bob(d: &[f64]) -> Self {
        let at = |i: usize| d.get(i).copied().unwrap_or(0.0);
        Self {
            k1: at(0),
            k2: at(1),
            p1: at(2),
            p2: at(3),
            k3: at(4),
        }
    }

    /// CameraInfo's `d` (k1, k2, p1, p2, k3).
    pub fn to_plumb_bob(&self) -> Vec<f64> {
        vec![self.k1, self.k2, self.p1, self.p2, self.k3]
    }

    /// Whether every coefficient is 0.
    pub fn is_zero(&self) -> bool {
        [self.k1, self.k2, self.k3, self.p1, self.p2]
            .iter()
            .all(|v| *v == 0.0)
    }

    /// The distorted normalised coordinates of ideal ones (x, y) = (X/Z, Y/Z).
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
        (xd, yd)
    }

    /// The ideal normalised coordinates whose distortion is (xd, yd).
    pub fn undistort(&self, xd: f64, yd: f64) -> (f64, f64) {
        let (mut x, mut y) = (xd, yd);
        for _ in 0..UNDISTORT_ITERATIONS {
            let r2 = x * x + y * y;
            let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
            let dx = 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
            let dy = self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
            x = (xd - dx) / radial;
            y = (yd - dy) / radial;
        }
        (x, y)
    }
}

/// Pixel (u, v) of the distorted image seen by `camera` with `d`, for the pixel (u, v) of the
/// ideal pinhole image (continuous coordinates).
pub fn distorted_pixel(camera: &Camera, d: &Distortion, u: f64, v: f64) -> (f64, f64) {
    let (x, y) = ((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy);
    let (xd, yd) = d.distort(x, y);
    (camera.fx * xd + camera.cx, camera.fy * yd + camera.cy)
}

/// The ideal pinhole pixel of a distorted image's pixel (continuous coordinates).
pub fn undistorted_pixel(camera: &Camera, d: &Distortion, u: f64, v: f64) -> (f64, f64) {
    let (xd, yd) = ((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy);
    let (x, y) = d.undistort(xd, yd);
    (camera.fx * x + camera.cx, camera.fy * y + camera.cy)
}

/// A precomputed remap from the distorted image to the ideal pinhole image of the same K and
/// size: for each output pixel, the source pixel's four bilinear neighbours and weights.
#[derive(Debug, Clone)]
pub struct Rectifier {
    width: u32,
    height: u32,
    /// Per output pixel: top-left source index (or u32::MAX outside the source) and the
    /// fractional offsets, as weights in 1/256.
    taps: Vec<(u32, u8, u8)>,
}

impl Rectifier {
    /// The remap for `camera` with distortion `d`.
    pub fn new(camera: &Camera, d: &Distortion) -> Self {
        let (w, h) = (camera.width, camera.height);
        let mut taps = Vec::with_capacity(w as usize * h as usize);
        for v in 0..h {
            for u in 0..w {
                // Pixel centres at +0.5 (geometry's convention); the source's at +0.5 too.
                let (su, sv) = distorted_pixel(camera, d, f64::from(u) + 0.5, f64::from(v) + 0.5);
                let (fx, fy) = (su - 0.5, sv - 0.5);
                let inside = fx >= 0.0
                    && fy >= 0.0
                    && fx < f64::from(w.saturating_sub(1))
                    && fy < f64::from(h.saturating_sub(1));
                if !inside {
                    taps.push((u32::MAX, 0, 0));
                    continue;
                }
                // Non-negative: truncation is the floor.
                let (x0, y0) = (fx as u32, fy as u32);
                let ax = ((fx - f64::from(x0)) * 256.0).min(255.0) as u8;
                let ay = ((fy - f64::from(y0)) * 256.0).min(255.0) as u8;
                taps.push((y0 * w + x0, ax, ay));
            }
        }
        Self {
            width: w,
            height: h,
            taps,
        }
    }

    /// The rectified image of `img` (which must have the camera's size); pixels whose source
    /// lies outside the distorted image are black.
    pub fn apply(&self, img: &Rgb8) -> Rgb8 {
        use rayon::prelude::*;
        let w = self.width as usize;
        let mut data = vec![0u8; self.taps.len() * 3];
        // Rows in parallel: each output pixel depends on the source alone.
        data.par_chunks_mut(w.max(1) * 3)
            .zip(self.taps.par_chunks(w.max(1)))
            .for_each(|(row, taps)| {
                for (o, &(i, ax, ay)) in row.chunks_exact_mut(3).zip(taps) {
                    if i == u32::MAX {
                        continue;
                    }
                    let i = i as usize * 3;
                    let (ax, ay) = (u32::from(ax), u32::from(ay));
                    for (c, out) in o.iter_mut().enumerate() {
                        let p = |k: usize| u32::from(img.data[k + c]);
                        let top = p(i) * (256 - ax) + p(i + 3) * ax;
                        let bottom = p(i + w * 3) * (256 - ax) + p(i + w * 3 + 3) * ax;
                        *out = ((top * (256 - ay) + bottom * ay + 32768) >> 16) as u8;
                    }
                }
            });
        Rgb8 {
            width: self.width,
            height: self.height,
            data,
        }
    }
}

/// Largest difference of fx, fy, cx or cy (pixels) between two CameraInfos taken as the same
/// camera (calibrations decomposed per view differ by rounding).
pub const CAMERA_TOLERANCE_PX: f64 = 0.05;

/// What differs between two cameras, each as `name old -> new`, or None when they are the
/// same camera: the size and distortion exactly, the intrinsics within
/// [`CAMERA_TOLERANCE_PX`].
pub fn camera_changes(a: (&Camera, &Distortion), b: (&Camera, &Distortion)) -> Option<String> {
    let (c0, d0) = a;
    let (c1, d1) = b;
    let mut out = Vec::new();
    if (c0.width, c0.height) != (c1.width, c1.height) {
        out.push(format!(
            "{} x {} -> {} x {}",
            c0.width, c0.height, c1.width, c1.height
        ));
    }
    // (name, value, tolerance): intrinsics may differ by rounding, distortion may not.
    let t = CAMERA_TOLERANCE_PX;
    let values = |c: &Camera, d: &Distortion| {
        [
            ("fx", c.fx, t),
            ("fy", c.fy, t),
            ("cx", c.cx, t),
            ("cy", c.cy, t),
            ("k1", d.k1, 0.0),
            ("k2", d.k2, 0.0),
            ("p1", d.p1, 0.0),
            ("p2", d.p2, 0.0),
            ("k3", d.k3, 0.0),
        ]
    };
    for ((name, x, tol), (_, y, _)) in values(c0, d0).into_iter().zip(values(c1, d1)) {
        // A NaN on either side is a change too.
        if (x - y).abs() > tol || (x - y).is_nan() {
            out.push(format!("{name} {x} -> {y}"));
        }
    }
    (!out.is_empty()).then(|| out.join(", "))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A change names what changed, and only that: a focal length beyond the rounding
    /// tolerance and a distortion coefficient, not the centre that moved within it.
    #[test]
    fn a_camera_change_names_the_values_that_changed() {
        let a = Camera::with_hfov(256, 240, 1.0);
        let b = Camera {
            fy: a.fy + 0.5,
            cx: a.cx + 0.5 * CAMERA_TOLERANCE_PX,
            ..a
        };
        let none = Distortion::default();
        let d = Distortion { k3: 1e-6, ..none };
        assert_eq!(
            camera_changes((&a, &none), (&b, &d)),
            Some(format!("fy {} -> {}, k3 0 -> 0.000001", a.fy, a.fy + 0.5))
        );
        let c = Camera { width: 128, ..a };
        assert_eq!(
            camera_changes((&a, &d), (&c, &d)),
            Some("256 x 240 -> 128 x 240".into())
        );
        assert_eq!(
            camera_changes((&a, &d), (&b, &d)),
            Some(format!("fy {} -> {}", a.fy, a.fy + 0.5))
        );
        let same = Camera {
            cx: a.cx + 0.5 * CAMERA_TOLERANCE_PX,
            ..a
        };
        assert_eq!(camera_changes((&a, &d), (&same, &d)), None);
    }

    #[test]
    fn undistortion_inverts_distortion_over_the_image() {
        // The fruit capture's phone lens (docs: realdata/README).
        let d = Distortion {
            k1: -0.002425,
            k2: -0.021258,
            k3: 0.0,
            p1: 0.011019,
            p2: 0.009578,
        };
        let cam = Camera::from_k(
            605,
            806,
            [627.8, 0.0, 318.8, 0.0, 616.5, 395.3, 0.0, 0.0, 1.0],
        )
        .unwrap();
        for (u, v) in [(0.0, 0.0), (604.0, 805.0), (300.0, 400.0), (10.0, 790.0)] {
            let (iu, iv) = undistorted_pixel(&cam, &d, u, v);
            let (bu, bv) = distorted_pixel(&cam, &d, iu, iv);
            assert!(
                (bu - u).abs() < 1e-6 && (bv - v).abs() < 1e-6,
                "{u},{v} -> {bu},{bv}"
            );
        }
        // Hand-computed: x = 0.5, y = 0 with k1 = 0.1 only: r^2 = 0.25, x_d = 0.5 * 1.025.
        let k1 = Distortion {
            k1: 0.1,
            ..Distortion::default()
        };
        assert_eq!(k1.distort(0.5, 0.0), (0.5125, 0.0));
        assert!(Distortion::from_plumb_bob(&[]).is_zero());
        assert_eq!(Distortion::from_plumb_bob(&k1.to_plumb_bob()), k1);
    }

    #[test]
    fn zero_distortion_rectifies_to_the_same_image() {
        let cam = Camera::with_hfov(8, 6, 1.0);
        let img = Rgb8 {
            width: 8,
            height: 6,
            data: (0..8 * 6 * 3).map(|i| (i * 5 % 256) as u8).collect(),
        };
        let out = Rectifier::new(&cam, &Distortion::default()).apply(&img);
        // Interior pixels map to themselves exactly; the last row and column fall outside the
        // bilinear support and are black.
        for v in 0..5u32 {
            for u in 0..7u32 {
                assert_eq!(out.pixel(u, v), img.pixel(u, v), "({u}, {v})");
            }
        }
    }
}
