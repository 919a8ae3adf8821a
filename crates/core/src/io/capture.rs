//! Posed captures as they come: the pose files of structure-from-motion and multi-view
//! datasets, read into one list of posed images for the importer.
//!
//! Formats: NeRF / instant-ngp / nerfstudio `transforms.json`, COLMAP models (`cameras.txt` +
//! `images.txt`, or `cameras.bin` + `images.bin`), LLFF `poses_bounds.npy`, IDR / NeuS
//! `cameras.npz` (a projection matrix per view), and TUM trajectories (read by
//! [`crate::io::import`]).
//!
//! Invariants: every pose comes out as `world_from_camera` with OpenCV camera axes (x right,
//! y down, z forward) in the capture's own world frame and units; every intrinsic set is a
//! pinhole K plus radial-tangential distortion, for the image files as they are on disk
//! (models that cannot be represented so are refused); every error names the file and the
//! line, frame or entry at fault.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use thiserror::Error;

use crate::types::geometry::{Camera, Iso3};
use crate::types::lens::Distortion;

/// Why a pose file cannot be read.
#[derive(Debug, Error)]
pub enum CaptureError {
    /// The file cannot be read.
    #[error("{path}: {source}", path = path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The reason.
        #[source]
        source: std::io::Error,
    },
    /// A line of a text file is malformed.
    #[error("{path}:{line}: {what}", path = path.display())]
    Line {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        what: String,
    },
    /// An entry (a frame, a camera, an array) is malformed.
    #[error("{path}: {entry}: {what}", path = path.display())]
    Entry {
        /// The file.
        path: PathBuf,
        /// The entry, e.g. `frames[3]` or `camera 2`.
        entry: String,
        /// What is wrong.
        what: String,
    },
    /// The file as a whole is not of the format.
    #[error("{path}: {what}", path = path.display())]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
}

/// Intrinsics of one image: the pinhole camera and its lens distortion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    /// Pinhole K and image size.
    pub camera: Camera,
    /// Radial-tangential distortion (zero for none).
    pub distortion: Distortion,
}

/// One image of a capture with its pose and intrinsics.
#[derive(Debug, Clone, PartialEq)]
pub struct PosedImage {
    /// The image file.
    pub path: PathBuf,
    /// Camera pose in the capture's world, OpenCV camera axes.
    pub world_from_camera: Iso3,
    /// Intrinsics for the file as it is.
    pub intrinsics: Intrinsics,
}

fn read_text(path: &Path) -> Result<String, CaptureError> {
    std::fs::read_to_string(path).map_err(|source| CaptureError::Io {
        path: path.into(),
        source,
    })
}

fn read_bytes(path: &Path) -> Result<Vec<u8>, CaptureError> {
    std::fs::read(path).map_err(|source| CaptureError::Io {
        path: path.into(),
        source,
    })
}

/// A pose from a rotation matrix and a translation, refusing non-rotations (det or
/// orthogonality off by more than 1e-3) and non-finite values.
fn pose_from_matrix(r: &Matrix3<f64>, t: &Vector3<f64>) -> Result<Iso3, String> {
    if !r.iter().chain(t.iter()).all(|v| v.is_finite()) {
        return Err("pose has a value that is not finite".into());
    }
    let err = (r.transpose() * r - Matrix3::identity()).abs().max();
    if err > 1e-3 || (r.determinant() - 1.0).abs() > 1e-3 {
        return Err(format!(
            "rotation is not orthonormal with det +1 (off by {err:.2e}, det {:.4})",
            r.determinant()
        ));
    }
    let rot = Rotation3::from_matrix(r);
    Ok(Iso3::from_parts(
        Translation3::from(*t),
        UnitQuaternion::from_rotation_matrix(&rot),
    ))
}

/// Pixel size of an image file, from its header.
pub fn image_size(path: &Path) -> Result<(u32, u32), CaptureError> {
    image::ImageReader::open(path)
        .map_err(|source| CaptureError::Io {
            path: path.into(),
            source,
        })?
        .with_guessed_format()
        .map_err(|source| CaptureError::Io {
            path: path.into(),
            source,
        })?
        .into_dimensions()
        .map_err(|e| CaptureError::Invalid {
            path: path.into(),
            what: format!("image does not decode: {e}"),
        })
}

fn intrinsics(
    width: u32,
    height: u32,
    k: [f64; 4],
    distortion: Distortion,
) -> Result<Intrinsics, String> {
    let [fx, fy, cx, cy] = k;
    let camera = Camera::from_k(width, height, [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0])
        .ok_or_else(|| {
            format!("intrinsics fx {fx}, fy {fy}, cx {cx}, cy {cy} at {width} x {height} are not a camera")
        })?;
    let d = distortion;
    if ![d.k1, d.k2, d.k3, d.p1, d.p2].iter().all(|v| v.is_finite()) {
        return Err("distortion coefficients must be finite".into());
    }
    Ok(Intrinsics { camera, distortion })
}

/// The image file a pose file names: as given, or with one of the image extensions added
/// when the name has none that exists (nerfstudio and instant-ngp write both).
fn resolve_image(dir: &Path, name: &str) -> Option<PathBuf> {
    let p = dir.join(name);
    if p.is_file() {
        return Some(p);
    }
    ["png", "jpg", "jpeg", "PNG", "JPG", "JPEG"]
        .iter()
        .map(|e| dir.join(format!("{name}.{e}")))
        .find(|p| p.is_file())
}

mod colmap;
mod idr;
mod llff;
mod nerf;
mod npy;

pub use colmap::read_colmap;
pub use idr::read_idr;
pub use llff::read_llff;
pub use nerf::read_nerf;
