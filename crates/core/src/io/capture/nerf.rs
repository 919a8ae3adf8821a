//! NeRF / instant-ngp / nerfstudio `transforms.json`: camera-to-world matrices in OpenGL axes
//! (x right, y up, z backward), intrinsics shared at the top level or per frame.
//!
//! Invariants: frames come out sorted by image path; a per-frame key overrides the top-level
//! one; intrinsics are scaled when the image file is not the `w` x `h` they were given for.

use std::path::Path;

use serde_json::Value;

use super::{
    CaptureError, Intrinsics, PosedImage, image_size, intrinsics, pose_from_matrix, read_text,
    resolve_image,
};
use crate::types::lens::Distortion;
use nalgebra::{Matrix3, Vector3};

/// Reads `transforms.json`; image paths are relative to its folder.
pub fn read_nerf(path: &Path) -> Result<Vec<PosedImage>, CaptureError> {
    let text = read_text(path)?;
    let root: Value = serde_json::from_str(&text).map_err(|e| CaptureError::Line {
        path: path.into(),
        line: e.line(),
        what: format!("not JSON: {e}"),
    })?;
    let frames = root
        .get("frames")
        .and_then(Value::as_array)
        .ok_or_else(|| CaptureError::Invalid {
            path: path.into(),
            what: "no `frames` array".into(),
        })?;
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut out = Vec::with_capacity(frames.len());
    for (i, f) in frames.iter().enumerate() {
        let entry = |what: String| CaptureError::Entry {
            path: path.into(),
            entry: format!("frames[{i}]"),
            what,
        };
        let name = f
            .get("file_path")
            .and_then(Value::as_str)
            .ok_or_else(|| entry("no `file_path`".into()))?;
        let image = resolve_image(dir, name)
            .ok_or_else(|| entry(format!("image {name:?} not found in {}", dir.display())))?;
        if let Some(j) = out.iter().position(|o: &PosedImage| o.path == image) {
            return Err(entry(format!(
                "image {name:?} is also frames[{j}]'s: one pose per image"
            )));
        }
        let world_from_camera = nerf_pose(f).map_err(entry)?;
        let size = image_size(&image)?;
        let intrinsics = nerf_intrinsics(&root, f, size).map_err(entry)?;
        out.push(PosedImage {
            path: image,
            world_from_camera,
            intrinsics,
        });
    }
    out.sort_by(|a, b| a.path.cmp(&b.path));
    Ok(out)
}

/// The frame's `transform_matrix` as OpenCV camera-to-world.
fn nerf_pose(f: &Value) -> Result<crate::types::geometry::Iso3, String> {
    let m = f
        .get("transform_matrix")
        .and_then(Value::as_array)
        .filter(|rows| rows.len() >= 3)
        .ok_or("no 4 x 4 `transform_matrix`")?;
    let mut r = Matrix3::zeros();
    let mut t = Vector3::zeros();
    for (row, values) in m.iter().take(3).enumerate() {
        let v: Vec<f64> = values
            .as_array()
            .map(|a| a.iter().filter_map(Value::as_f64).collect())
            .unwrap_or_default();
        if v.len() != 4 {
            return Err(format!(
                "`transform_matrix` row {row} does not hold 4 numbers"
            ));
        }
        for c in 0..3 {
            // OpenGL to OpenCV camera axes: y and z flip.
            r[(row, c)] = if c == 0 { v[c] } else { -v[c] };
        }
        t[row] = v[3];
    }
    pose_from_matrix(&r, &t)
}

/// A key of the frame, or of the file's top level; present but not a number is an error
/// (`"k1": "x"` dropped the distortion silently).
fn key(root: &Value, f: &Value, k: &str) -> Result<Option<f64>, String> {
    match f.get(k).or_else(|| root.get(k)) {
        None | Some(Value::Null) => Ok(None),
        Some(v) => v
            .as_f64()
            .map(Some)
            .ok_or_else(|| format!("`{k}` is {v}, not a number")),
    }
}

fn nerf_intrinsics(root: &Value, f: &Value, file: (u32, u32)) -> Result<Intrinsics, String> {
    let fisheye = f
        .get("is_fisheye")
        .or_else(|| root.get("is_fisheye"))
        .and_then(Value::as_bool)
        .unwrap_or(false);
    let model = f
        .get("camera_model")
        .or_else(|| root.get("camera_model"))
        .and_then(Value::as_str)
        .unwrap_or("OPENCV");
    if fisheye || model.contains("FISHEYE") || model == "EQUIRECTANGULAR" {
        return Err(format!(
            "camera model {model:?} (fisheye {fisheye}) cannot be represented: objloc reads pinhole cameras with radial-tangential distortion"
        ));
    }
    if key(root, f, "k4")?.is_some_and(|k| k != 0.0) {
        return Err("distortion k4 is set: objloc reads k1, k2, k3, p1, p2 only".into());
    }
    let (fw, fh) = (f64::from(file.0), f64::from(file.1));
    let w = key(root, f, "w")?.unwrap_or(fw);
    let h = key(root, f, "h")?.unwrap_or(fh);
    let angle_x = key(root, f, "camera_angle_x")?;
    let fl_x = key(root, f, "fl_x")?.or_else(|| angle_x.map(|a| 0.5 * w / (0.5 * a).tan()));
    let fl_x = fl_x.ok_or("no `fl_x` or `camera_angle_x`")?;
    let angle_y = key(root, f, "camera_angle_y")?;
    let fl_y = key(root, f, "fl_y")?
        .or_else(|| angle_y.map(|a| 0.5 * h / (0.5 * a).tan()))
        .unwrap_or(fl_x);
    let cx = key(root, f, "cx")?.unwrap_or(w / 2.0);
    let cy = key(root, f, "cy")?.unwrap_or(h / 2.0);
    // Intrinsics given for w x h; the file may be a downscaled copy.
    let (sx, sy) = (fw / w, fh / h);
    let d = Distortion {
        k1: key(root, f, "k1")?.unwrap_or(0.0),
        k2: key(root, f, "k2")?.unwrap_or(0.0),
        k3: key(root, f, "k3")?.unwrap_or(0.0),
        p1: key(root, f, "p1")?.unwrap_or(0.0),
        p2: key(root, f, "p2")?.unwrap_or(0.0),
    };
    intrinsics(file.0, file.1, [fl_x * sx, fl_y * sy, cx * sx, cy * sy], d)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A camera 4 units up the world z axis looking down (OpenGL: its z axis, backward,
    /// points up): in OpenCV axes it looks along world -z, its y (down) along world -y.
    #[test]
    fn opengl_matrix_becomes_an_opencv_pose_and_intrinsics_fall_back() {
        let f: Value = serde_json::json!({
            "file_path": "a",
            "transform_matrix": [[1, 0, 0, 0.5], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]
        });
        let pose = nerf_pose(&f).unwrap();
        let forward = pose.rotation * Vector3::z();
        let down = pose.rotation * Vector3::y();
        assert!((forward - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-12);
        assert!((down - Vector3::new(0.0, -1.0, 0.0)).norm() < 1e-12);
        assert_eq!(pose.translation.vector, Vector3::new(0.5, 0.0, 4.0));
        // camera_angle_x only, for 200 x 100 intrinsics, and a file of half that size.
        let root = serde_json::json!({"camera_angle_x": 2.0 * (0.5f64).atan(), "w": 200, "h": 100});
        let k = nerf_intrinsics(&root, &f, (100, 50)).unwrap();
        // fl_x = 0.5 * 200 / 0.5 = 200 at full size, 100 at half; fl_y falls back to fl_x.
        assert!((k.camera.fx - 100.0).abs() < 1e-9 && (k.camera.fy - 100.0).abs() < 1e-9);
        assert!((k.camera.cx - 50.0).abs() < 1e-9 && (k.camera.cy - 25.0).abs() < 1e-9);
        let fish = serde_json::json!({"fl_x": 100, "is_fisheye": true});
        assert!(nerf_intrinsics(&fish, &f, (100, 50)).is_err());
        // A coefficient that is not a number is named, not taken as 0.
        let k1 = serde_json::json!({"fl_x": 100, "k1": "x"});
        let e = nerf_intrinsics(&k1, &f, (100, 50)).unwrap_err();
        assert_eq!(e, "`k1` is \"x\", not a number");
    }
}
