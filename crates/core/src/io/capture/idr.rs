//! IDR / NeuS `cameras.npz`: per view i a 4 x 4 `world_mat_i` = [P; 0 0 0 1], P = K [R | t]
//! the projection of the calibrated images (the `scale_mat_i` normalisation is not used: the
//! session keeps the calibration's world units).
//!
//! Invariants: view i belongs to the i-th image of the folder in name order; K and R come from
//! an RQ decomposition with a positive diagonal of K and det R = +1; `crop` says which part of
//! the calibrated image the files hold (they are that region, scaled to the file's size).

use std::path::Path;

use nalgebra::{Matrix3, Vector3};

use super::llff::sorted_images;
use super::npy::parse_npz;
use super::{CaptureError, PosedImage, image_size, intrinsics, pose_from_matrix, read_bytes};
use crate::types::lens::Distortion;

/// K (upper triangular, K[2][2] = 1, positive diagonal) and R (det +1) with M = s K R for some
/// scale s.
pub(super) fn rq(m: &Matrix3<f64>) -> Option<(Matrix3<f64>, Matrix3<f64>)> {
    // Row reduction from the bottom: r3 along the third row, r2 the part of the second row
    // orthogonal to it, r1 likewise; K holds the coefficients.
    let m = if m.determinant() < 0.0 { -m } else { *m };
    let (m1, m2, m3) = (
        m.row(0).transpose(),
        m.row(1).transpose(),
        m.row(2).transpose(),
    );
    let k22 = m3.norm();
    let r3 = m3 / k22;
    let k12 = m2.dot(&r3);
    let r2u = m2 - r3 * k12;
    let k11 = r2u.norm();
    let r2 = r2u / k11;
    let (k02, k01) = (m1.dot(&r3), m1.dot(&r2));
    let r1u = m1 - r3 * k02 - r2 * k01;
    let k00 = r1u.norm();
    let r1 = r1u / k00;
    if !(k00 > 0.0 && k11 > 0.0 && k22 > 0.0) {
        return None;
    }
    let k = Matrix3::new(k00, k01, k02, 0.0, k11, k12, 0.0, 0.0, k22) / k22;
    let r = Matrix3::from_rows(&[r1.transpose(), r2.transpose(), r3.transpose()]);
    Some((k, r))
}

/// Reads `cameras.npz` for the images in `images_dir`; `crop` = (x0, y0, width, height) of the
/// calibrated image that the files hold, if they are a crop of it.
pub fn read_idr(
    path: &Path,
    images_dir: &Path,
    crop: Option<[f64; 4]>,
) -> Result<Vec<PosedImage>, CaptureError> {
    let arrays = parse_npz(path, &read_bytes(path)?)?;
    let images = sorted_images(images_dir)?;
    let mut out = Vec::with_capacity(images.len());
    for (i, image) in images.into_iter().enumerate() {
        let key = format!("world_mat_{i}");
        let entry = |what: String| CaptureError::Entry {
            path: path.into(),
            entry: key.clone(),
            what,
        };
        let a = arrays
            .iter()
            .find(|(k, _)| *k == key)
            .map(|(_, a)| a)
            .ok_or_else(|| entry(format!("missing for image {}", image.display())))?;
        if a.shape != [4, 4] && a.shape != [3, 4] {
            return Err(entry(format!("shape {:?}, expected (4, 4)", a.shape)));
        }
        let p = |r: usize, c: usize| a.data[r * 4 + c];
        let m = Matrix3::from_fn(p);
        let (k, r) = rq(&m).ok_or_else(|| entry("not a projection (singular)".into()))?;
        // P = s K [R | t]: t = (K^-1 P[:, 3]) / s, s = M's third row's norm with M's sign.
        let s = m.row(2).norm() * m.determinant().signum();
        let kinv = k.try_inverse().ok_or_else(|| entry("singular K".into()))?;
        let t = kinv * Vector3::new(p(0, 3), p(1, 3), p(2, 3)) / s;
        let centre = -r.transpose() * t;
        let world_from_camera = pose_from_matrix(&r.transpose(), &centre).map_err(entry)?;
        let (fw, fh) = image_size(&image)?;
        let [x0, y0, cw, ch] = crop.unwrap_or([0.0, 0.0, f64::from(fw), f64::from(fh)]);
        let (sx, sy) = (f64::from(fw) / cw, f64::from(fh) / ch);
        let kk = [
            k[(0, 0)] * sx,
            k[(1, 1)] * sy,
            (k[(0, 2)] - x0) * sx,
            (k[(1, 2)] - y0) * sy,
        ];
        if k[(0, 1)].abs() > 1e-6 * k[(0, 0)] {
            return Err(entry(format!("skew {} cannot be represented", k[(0, 1)])));
        }
        let intrinsics = intrinsics(fw, fh, kk, Distortion::default()).map_err(entry)?;
        out.push(PosedImage {
            path: image,
            world_from_camera,
            intrinsics,
        });
    }
    if let Some(extra) = arrays
        .iter()
        .filter(|(k, _)| k.starts_with("world_mat_"))
        .find(|(k, _)| k[10..].parse::<usize>().is_ok_and(|i| i >= out.len()))
    {
        return Err(CaptureError::Entry {
            path: path.into(),
            entry: extra.0.clone(),
            what: format!(
                "no image for it in {} ({} images)",
                images_dir.display(),
                out.len()
            ),
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    #[test]
    fn rq_recovers_k_and_r_up_to_scale() {
        let k = Matrix3::new(900.0, 0.0, 320.0, 0.0, 910.0, 240.0, 0.0, 0.0, 1.0);
        let r = *Rotation3::from_euler_angles(0.3, -0.2, 1.1).matrix();
        for s in [2.5, -0.7] {
            let (k2, r2) = rq(&(k * r * s)).unwrap();
            assert!((k2 - k).abs().max() < 1e-9, "{k2}");
            assert!((r2 - r).abs().max() < 1e-12, "{r2}");
        }
    }
}
