//! COLMAP sparse models: `cameras.txt` + `images.txt` or `cameras.bin` + `images.bin` (the
//! text files win when both are there). Images hold world-to-camera poses (quaternion w x y
//! z, translation) in OpenCV axes; cameras are one of COLMAP's models.
//!
//! Invariants: images come out sorted by name; camera models that are not a pinhole with
//! radial-tangential distortion (fisheye, thin prism, FOV, FULL_OPENCV's rational terms) are
//! refused naming the camera.

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use super::{CaptureError, Intrinsics, PosedImage, intrinsics, read_bytes, read_text};
use crate::types::geometry::Iso3;
use crate::types::lens::Distortion;

/// COLMAP's model names by id, with their parameter counts.
const MODELS: [(&str, usize); 11] = [
    ("SIMPLE_PINHOLE", 3),
    ("PINHOLE", 4),
    ("SIMPLE_RADIAL", 4),
    ("RADIAL", 5),
    ("OPENCV", 8),
    ("OPENCV_FISHEYE", 8),
    ("FULL_OPENCV", 12),
    ("FOV", 5),
    ("SIMPLE_RADIAL_FISHEYE", 4),
    ("RADIAL_FISHEYE", 5),
    ("THIN_PRISM_FISHEYE", 12),
];

/// A camera's intrinsics from its COLMAP model and parameters.
fn camera_intrinsics(model: &str, w: u32, h: u32, p: &[f64]) -> Result<Intrinsics, String> {
    let z = Distortion::default();
    let (k, d) = match (model, p) {
        ("SIMPLE_PINHOLE", [f, cx, cy]) => ([*f, *f, *cx, *cy], z),
        ("PINHOLE", [fx, fy, cx, cy]) => ([*fx, *fy, *cx, *cy], z),
        ("SIMPLE_RADIAL", [f, cx, cy, k1]) => ([*f, *f, *cx, *cy], Distortion { k1: *k1, ..z }),
        ("RADIAL", [f, cx, cy, k1, k2]) => (
            [*f, *f, *cx, *cy],
            Distortion {
                k1: *k1,
                k2: *k2,
                ..z
            },
        ),
        // OpenCV's order, as CameraInfo's plumb_bob d: k1, k2, p1, p2, k3.
        ("OPENCV", [fx, fy, cx, cy, k1, k2, p1, p2]) => (
            [*fx, *fy, *cx, *cy],
            Distortion::from_plumb_bob(&[*k1, *k2, *p1, *p2]),
        ),
        ("FULL_OPENCV", [fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6])
            if [*k4, *k5, *k6] == [0.0; 3] =>
        {
            (
                [*fx, *fy, *cx, *cy],
                Distortion::from_plumb_bob(&[*k1, *k2, *p1, *p2, *k3]),
            )
        }
        _ => {
            return Err(format!(
                "camera model {model} with {} parameters cannot be represented: objloc reads pinhole cameras with radial-tangential distortion (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV with k4 = k5 = k6 = 0)",
                p.len()
            ));
        }
    };
    intrinsics(w, h, k, d)
}

/// A COLMAP image: world-to-camera quaternion and translation, its camera, its name.
struct Image {
    q_wxyz: [f64; 4],
    t: [f64; 3],
    camera: u32,
    name: String,
}

fn camera_from_world(img: &Image) -> Result<Iso3, String> {
    let [w, x, y, z] = img.q_wxyz;
    let q = Quaternion::new(w, x, y, z);
    if q.norm().is_nan() || q.norm() <= 1e-9 || !img.t.iter().all(|v| v.is_finite()) {
        return Err("pose is not finite or has a zero quaternion".into());
    }
    let rot = UnitQuaternion::from_quaternion(q);
    let t = Vector3::new(img.t[0], img.t[1], img.t[2]);
    Ok(Iso3::from_parts(t.into(), rot).inverse())
}

/// Reads the model in `model_dir`; image names are relative to `images_dir`.
pub fn read_colmap(model_dir: &Path, images_dir: &Path) -> Result<Vec<PosedImage>, CaptureError> {
    let (cams_txt, imgs_txt) = (model_dir.join("cameras.txt"), model_dir.join("images.txt"));
    let (cameras, images, imgs_path) = if cams_txt.is_file() && imgs_txt.is_file() {
        (cameras_txt(&cams_txt)?, images_txt(&imgs_txt)?, imgs_txt)
    } else {
        let (cb, ib) = (model_dir.join("cameras.bin"), model_dir.join("images.bin"));
        if !(cb.is_file() && ib.is_file()) {
            return Err(CaptureError::Invalid {
                path: model_dir.into(),
                what: "no cameras.txt + images.txt nor cameras.bin + images.bin".into(),
            });
        }
        (cameras_bin(&cb)?, images_bin(&ib)?, ib)
    };
    let mut out = Vec::with_capacity(images.len());
    for img in images {
        let entry = |what: String| CaptureError::Entry {
            path: imgs_path.clone(),
            entry: format!("image {:?}", img.name),
            what,
        };
        let intr = *cameras
            .get(&img.camera)
            .ok_or_else(|| entry(format!("camera {} is not in the model", img.camera)))?;
        let path = images_dir.join(&img.name);
        if !path.is_file() {
            return Err(entry(format!("not found in {}", images_dir.display())));
        }
        let world_from_camera = camera_from_world(&img).map_err(entry)?;
        out.push(PosedImage {
            path,
            world_from_camera,
            intrinsics: intr,
        });
    }
    out.sort_by(|a, b| a.path.cmp(&b.path));
    Ok(out)
}

/// The non-comment lines of a COLMAP text file with their 1-based numbers.
fn lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
}

fn numbers(fields: &[&str]) -> Option<Vec<f64>> {
    fields.iter().map(|f| f.parse().ok()).collect()
}

fn cameras_txt(path: &Path) -> Result<BTreeMap<u32, Intrinsics>, CaptureError> {
    let text = read_text(path)?;
    let mut out = BTreeMap::new();
    for (line, l) in lines(&text) {
        let err = |what: String| CaptureError::Line {
            path: path.into(),
            line,
            what,
        };
        let f: Vec<&str> = l.split_whitespace().collect();
        let (Some(id), Some(model), Some(w), Some(h)) = (
            f.first().and_then(|s| s.parse().ok()),
            f.get(1),
            f.get(2).and_then(|s| s.parse().ok()),
            f.get(3).and_then(|s| s.parse().ok()),
        ) else {
            return Err(err(
                "expected `CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]`".into()
            ));
        };
        let p = numbers(&f[4..]).ok_or_else(|| err("a parameter is not a number".into()))?;
        if out
            .insert(id, camera_intrinsics(model, w, h, &p).map_err(err)?)
            .is_some()
        {
            return Err(err(format!("CAMERA_ID {id} is defined twice")));
        }
    }
    Ok(out)
}

fn images_txt(path: &Path) -> Result<Vec<Image>, CaptureError> {
    let text = read_text(path)?;
    let mut out = Vec::new();
    // Each image takes two lines: its pose, then its 2D points (skipped, possibly empty,
    // so the pose lines are found by their field count).
    let mut expect_pose = true;
    // IMAGE_ID and NAME -> the line that first gave them.
    let (mut ids, mut names) = (BTreeMap::new(), BTreeMap::new());
    for (line, l) in text.lines().enumerate().map(|(i, l)| (i + 1, l.trim())) {
        if l.starts_with('#') {
            continue;
        }
        let f: Vec<&str> = l.split_whitespace().collect();
        let err = |what: String| CaptureError::Line {
            path: path.into(),
            line,
            what,
        };
        if !expect_pose {
            // X Y POINT3D_ID triples: a file without these lines read every second image
            // as points and dropped it.
            if !f.len().is_multiple_of(3) || numbers(&f).is_none() {
                return Err(err(format!(
                    "expected the POINTS2D line of the image above (`X Y POINT3D_ID` triples, or empty), found {} fields: images.txt takes two lines per image",
                    f.len()
                )));
            }
            expect_pose = true;
            continue;
        }
        if l.is_empty() {
            continue;
        }
        if f.len() < 10 {
            return Err(err(
                "expected `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`".into(),
            ));
        }
        let v = numbers(&f[1..8]).ok_or_else(|| err("a pose value is not a number".into()))?;
        let camera = f[8]
            .parse()
            .map_err(|_| err("CAMERA_ID is not a number".into()))?;
        let name = f[9..].join(" ");
        if let Some(first) = ids.insert(f[0].to_owned(), line) {
            return Err(err(format!("IMAGE_ID {} is also on line {first}", f[0])));
        }
        if let Some(first) = names.insert(name.clone(), line) {
            return Err(err(format!("image {name:?} is also on line {first}")));
        }
        out.push(Image {
            q_wxyz: [v[0], v[1], v[2], v[3]],
            t: [v[4], v[5], v[6]],
            camera,
            name,
        });
        expect_pose = false;
    }
    Ok(out)
}

/// A little-endian reader over a binary model file that names the file on a short read.
struct Bin<'a> {
    path: &'a Path,
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Bin<'a> {
    fn new(path: &'a Path, bytes: &'a [u8]) -> Self {
        Self { path, bytes, at: 0 }
    }
}

impl Bin<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8], CaptureError> {
        let end = self.at.checked_add(n).filter(|e| *e <= self.bytes.len());
        let Some(end) = end else {
            return Err(CaptureError::Invalid {
                path: self.path.into(),
                what: format!("truncated at byte {} (needed {n} more)", self.at),
            });
        };
        let s = &self.bytes[self.at..end];
        self.at = end;
        Ok(s)
    }
    fn u64(&mut self) -> Result<u64, CaptureError> {
        let b = self.take(8)?;
        Ok(u64::from_le_bytes(b.try_into().unwrap_or([0; 8])))
    }
    fn i32(&mut self) -> Result<i32, CaptureError> {
        let b = self.take(4)?;
        Ok(i32::from_le_bytes(b.try_into().unwrap_or([0; 4])))
    }
    fn f64(&mut self) -> Result<f64, CaptureError> {
        let b = self.take(8)?;
        Ok(f64::from_le_bytes(b.try_into().unwrap_or([0; 8])))
    }
    fn name(&mut self) -> Result<String, CaptureError> {
        let rest = &self.bytes[self.at..];
        let n = rest
            .iter()
            .position(|&b| b == 0)
            .ok_or_else(|| CaptureError::Invalid {
                path: self.path.into(),
                what: format!("image name at byte {} is not terminated", self.at),
            })?;
        let s = String::from_utf8_lossy(&rest[..n]).into_owned();
        self.at += n + 1;
        Ok(s)
    }
    /// A count that must fit in what is left of the file at `per` bytes each.
    fn count(&mut self, per: usize) -> Result<usize, CaptureError> {
        let n = self.u64()?;
        let left = (self.bytes.len() - self.at) as u64;
        if n.saturating_mul(per as u64) > left {
            return Err(CaptureError::Invalid {
                path: self.path.into(),
                what: format!("count {n} at byte {} exceeds the file", self.at - 8),
            });
        }
        Ok(n as usize)
    }
}

fn cameras_bin(path: &Path) -> Result<BTreeMap<u32, Intrinsics>, CaptureError> {
    let bytes = read_bytes(path)?;
    let mut b = Bin::new(path, &bytes);
    let mut out = BTreeMap::new();
    for _ in 0..b.count(24)? {
        let id = b.i32()?;
        let model_id = b.i32()?;
        let (w, h) = (b.u64()?, b.u64()?);
        let entry = |what: String| CaptureError::Entry {
            path: path.into(),
            entry: format!("camera {id}"),
            what,
        };
        let (model, n) = usize::try_from(model_id)
            .ok()
            .and_then(|m| MODELS.get(m))
            .copied()
            .ok_or_else(|| entry(format!("unknown model id {model_id}")))?;
        let p = (0..n).map(|_| b.f64()).collect::<Result<Vec<_>, _>>()?;
        let (w, h) = (
            u32::try_from(w).map_err(|_| entry(format!("width {w}")))?,
            u32::try_from(h).map_err(|_| entry(format!("height {h}")))?,
        );
        let id = u32::try_from(id).map_err(|_| entry("negative id".into()))?;
        out.insert(id, camera_intrinsics(model, w, h, &p).map_err(entry)?);
    }
    Ok(out)
}

fn images_bin(path: &Path) -> Result<Vec<Image>, CaptureError> {
    let bytes = read_bytes(path)?;
    let mut b = Bin::new(path, &bytes);
    let mut out = Vec::new();
    for _ in 0..b.count(64)? {
        let _id = b.i32()?;
        let q = [b.f64()?, b.f64()?, b.f64()?, b.f64()?];
        let t = [b.f64()?, b.f64()?, b.f64()?];
        let camera = b.i32()?;
        let name = b.name()?;
        let points = b.count(24)?;
        b.take(points * 24)?;
        out.push(Image {
            q_wxyz: q,
            t,
            camera: u32::try_from(camera).map_err(|_| CaptureError::Entry {
                path: path.into(),
                entry: format!("image {name:?}"),
                what: format!("camera id {camera}"),
            })?,
            name,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The same one-image model as text and as binary gives the same pose and intrinsics;
    /// the identity world-to-camera with t = (0, 0, 2) puts the camera at z = -2.
    #[test]
    fn text_and_binary_models_agree() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::write(d.join("a.png"), b"").unwrap();
        std::fs::write(
            d.join("cameras.txt"),
            "# c\n1 OPENCV 640 480 500 501 320 240 0.1 -0.01 0.001 0.002\n",
        )
        .unwrap();
        std::fs::write(d.join("images.txt"), "# i\n1 1 0 0 0 0 0 2 1 a.png\n\n").unwrap();
        let txt = read_colmap(d, d).unwrap();
        assert_eq!(txt.len(), 1);
        let c = txt[0].world_from_camera.translation.vector;
        assert!((c - Vector3::new(0.0, 0.0, -2.0)).norm() < 1e-12);
        assert_eq!(txt[0].intrinsics.distortion.k1, 0.1);
        assert_eq!(txt[0].intrinsics.camera.fy, 501.0);
        let bin_dir = tempfile::tempdir().unwrap();
        let b = bin_dir.path();
        let mut cams = Vec::new();
        cams.extend(1u64.to_le_bytes());
        cams.extend(1i32.to_le_bytes());
        cams.extend(4i32.to_le_bytes());
        cams.extend(640u64.to_le_bytes());
        cams.extend(480u64.to_le_bytes());
        for v in [500.0f64, 501.0, 320.0, 240.0, 0.1, -0.01, 0.001, 0.002] {
            cams.extend(v.to_le_bytes());
        }
        std::fs::write(b.join("cameras.bin"), cams).unwrap();
        let mut imgs = Vec::new();
        imgs.extend(1u64.to_le_bytes());
        imgs.extend(1i32.to_le_bytes());
        for v in [1.0f64, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0] {
            imgs.extend(v.to_le_bytes());
        }
        imgs.extend(1i32.to_le_bytes());
        imgs.extend(b"a.png\0");
        imgs.extend(0u64.to_le_bytes());
        std::fs::write(b.join("images.bin"), imgs).unwrap();
        let bin = read_colmap(b, d).unwrap();
        assert_eq!(bin, txt);
        // A fisheye camera is refused naming it.
        std::fs::write(
            d.join("cameras.txt"),
            "1 OPENCV_FISHEYE 640 480 500 500 320 240 0 0 0 0\n",
        )
        .unwrap();
        let e = read_colmap(d, d).unwrap_err().to_string();
        assert!(
            e.contains("cameras.txt:1") && e.contains("OPENCV_FISHEYE"),
            "{e}"
        );
    }

    /// Two lines per image: without the POINTS2D lines every second image was read as
    /// points and dropped; an image or camera given twice was taken silently.
    #[test]
    fn images_without_points_lines_and_duplicates_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        for n in ["a.png", "b.png"] {
            std::fs::write(d.join(n), b"").unwrap();
        }
        let cams = "1 PINHOLE 640 480 500 500 320 240\n";
        let err = |cameras: &str, images: &str| {
            std::fs::write(d.join("cameras.txt"), cameras).unwrap();
            std::fs::write(d.join("images.txt"), images).unwrap();
            read_colmap(d, d)
                .map(|v| v.len())
                .map_err(|e| e.to_string())
        };
        let ok = "1 1 0 0 0 0 0 2 1 a.png\n1.5 2.5 -1 3 4 7\n2 1 0 0 0 0 0 2 1 b.png\n\n";
        assert_eq!(err(cams, ok), Ok(2));
        let no_points = "1 1 0 0 0 0 0 2 1 a.png\n2 1 0 0 0 0 0 2 1 b.png\n";
        let e = err(cams, no_points).unwrap_err();
        assert!(
            e.contains("images.txt:2") && e.contains("found 10 fields"),
            "{e}"
        );
        let same_name = "1 1 0 0 0 0 0 2 1 a.png\n\n2 1 0 0 0 0 0 2 1 a.png\n\n";
        let e = err(cams, same_name).unwrap_err();
        assert!(
            e.contains("images.txt:3") && e.contains("also on line 1"),
            "{e}"
        );
        let same_id = "1 1 0 0 0 0 0 2 1 a.png\n\n1 1 0 0 0 0 0 2 1 b.png\n\n";
        let e = err(cams, same_id).unwrap_err();
        assert!(e.contains("IMAGE_ID 1 is also on line 1"), "{e}");
        let e = err(&format!("{cams}1 PINHOLE 640 480 100 100 320 240\n"), ok).unwrap_err();
        assert!(
            e.contains("cameras.txt:2") && e.contains("defined twice"),
            "{e}"
        );
    }
}
