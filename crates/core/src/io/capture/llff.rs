//! LLFF `poses_bounds.npy`: N x 17 float64, each row a 3 x 5 matrix (row-major) whose
//! columns are the camera's image-down, image-right and backward axes in the world, its
//! centre, and (height, width, focal), then the near and far bounds.
//!
//! Invariants: row i belongs to the i-th image of the folder in string order (LLFF sorts
//! names as strings: 1, 10, 11, ..., 2); the principal point is the image centre; the focal
//! length is scaled when the files are not the height x width the poses were made for.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Vector3};

use super::npy::parse_npy;
use super::{CaptureError, PosedImage, image_size, intrinsics, pose_from_matrix, read_bytes};
use crate::types::lens::Distortion;

/// The image files of `dir` (png, jpg, jpeg) sorted by name as strings.
pub(super) fn sorted_images(dir: &Path) -> Result<Vec<PathBuf>, CaptureError> {
    let rd = std::fs::read_dir(dir).map_err(|source| CaptureError::Io {
        path: dir.into(),
        source,
    })?;
    let mut files: Vec<PathBuf> = rd
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| ["png", "jpg", "jpeg"].contains(&e.to_ascii_lowercase().as_str()))
        })
        .collect();
    files.sort();
    Ok(files)
}

/// Reads `poses_bounds.npy` for the images in `images_dir`.
pub fn read_llff(path: &Path, images_dir: &Path) -> Result<Vec<PosedImage>, CaptureError> {
    let a = parse_npy(path, "poses_bounds", &read_bytes(path)?)?;
    if a.shape.len() != 2 || a.shape[1] != 17 {
        return Err(CaptureError::Invalid {
            path: path.into(),
            what: format!("shape {:?}, expected (N, 17)", a.shape),
        });
    }
    let images = sorted_images(images_dir)?;
    if images.len() != a.shape[0] {
        return Err(CaptureError::Invalid {
            path: path.into(),
            what: format!(
                "{} poses for {} images in {} (rows follow the images' names in string order)",
                a.shape[0],
                images.len(),
                images_dir.display()
            ),
        });
    }
    let mut out = Vec::with_capacity(images.len());
    for (i, (row, image)) in a.data.chunks_exact(17).zip(images).enumerate() {
        let entry = |what: String| CaptureError::Entry {
            path: path.into(),
            entry: format!("row {i} ({})", image.display()),
            what,
        };
        let m = |r: usize, c: usize| row[r * 5 + c];
        // OpenCV camera-to-world: [right, down, forward] = [c1, c0, -c2].
        let r = Matrix3::from_fn(|r, c| match c {
            0 => m(r, 1),
            1 => m(r, 0),
            _ => -m(r, 2),
        });
        let t = Vector3::new(m(0, 3), m(1, 3), m(2, 3));
        let world_from_camera = pose_from_matrix(&r, &t).map_err(entry)?;
        let (h, w, f) = (m(0, 4), m(1, 4), m(2, 4));
        let (fw, fh) = image_size(&image)?;
        if !(w > 0.0 && h > 0.0) {
            return Err(entry(format!(
                "image size {w} x {h} in the pose is not positive"
            )));
        }
        let (sx, sy) = (f64::from(fw) / w, f64::from(fh) / h);
        let k = [f * sx, f * sy, f64::from(fw) / 2.0, f64::from(fh) / 2.0];
        let intrinsics = intrinsics(fw, fh, k, Distortion::default()).map_err(entry)?;
        out.push(PosedImage {
            path: image,
            world_from_camera,
            intrinsics,
        });
    }
    Ok(out)
}
