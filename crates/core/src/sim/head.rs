//! The simulated pan-tilt head: where the camera points at a stamp, and the transforms that
//! say so, as a robot with a moving camera publishes them (tf2's split of a chain into a
//! moving joint on /tf and fixed links on /tf_static).
//!
//! Invariants: with no head the mount is [`base_from_optical`] exactly; with one it is
//! `base_from_head(t) * head_from_optical`, the same composition the replay makes from the
//! recorded transforms, so what is rendered is what is published.

use nalgebra::{Rotation3, Translation3, UnitQuaternion, Vector3};

use super::scene::{PanTiltSpec, Scene};
use super::{BASE_FRAME, CAMERA_FRAME, START_NS, base_from_optical};
use crate::io::msgs::{Header, TfMessage, TransformStamped, pose_from_iso};
use crate::types::geometry::{Iso3, camera_mount};

/// Frame id of the head: base_link axes after pan and tilt, at the camera's mount point.
pub const HEAD_FRAME: &str = "camera_head";

/// base_link -> head at `stamp_ns`: the mount point, panned about z, tilted about y.
fn base_from_head(scene: &Scene, head: &PanTiltSpec, stamp_ns: i64) -> Iso3 {
    let t_s = (stamp_ns - START_NS) as f64 * 1e-9;
    let phase = 2.0 * std::f64::consts::PI * t_s / head.period_s;
    let pan = head.pan_amplitude_deg.to_radians() * phase.sin();
    let tilt = head.tilt_amplitude_deg.to_radians() * phase.cos();
    let r = Rotation3::from_axis_angle(&Vector3::z_axis(), pan)
        * Rotation3::from_axis_angle(&Vector3::y_axis(), tilt);
    let [x, y, z] = scene.camera.mount_m;
    Iso3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::from_rotation_matrix(&r),
    )
}

/// head -> camera optical frame: the fixed pitch and optical axes.
fn head_from_optical(scene: &Scene) -> Iso3 {
    camera_mount([0.0; 3], scene.camera.pitch_down_deg.to_radians())
}

/// The camera mount (base_from_optical) at `stamp_ns`.
pub fn mount_at(scene: &Scene, stamp_ns: i64) -> Iso3 {
    match &scene.camera.pan_tilt {
        None => base_from_optical(scene),
        Some(h) => base_from_head(scene, h, stamp_ns) * head_from_optical(scene),
    }
}

fn stamped(parent: &str, child: &str, stamp_ns: i64, iso: &Iso3) -> TransformStamped {
    let v = iso.translation.vector;
    TransformStamped {
        header: Header::new(stamp_ns, parent),
        child_frame_id: child.into(),
        translation: [v.x, v.y, v.z],
        rotation_xyzw: pose_from_iso(iso).orientation_xyzw,
    }
}

/// What /tf_static holds: the whole mount, or with a head its fixed link.
pub fn static_transforms(scene: &Scene) -> TfMessage {
    let t = match &scene.camera.pan_tilt {
        None => stamped(
            BASE_FRAME,
            CAMERA_FRAME,
            START_NS,
            &base_from_optical(scene),
        ),
        Some(_) => stamped(
            HEAD_FRAME,
            CAMERA_FRAME,
            START_NS,
            &head_from_optical(scene),
        ),
    };
    TfMessage {
        transforms: vec![t],
    }
}

/// What /tf holds at `stamp_ns`: the head's joint, or nothing without a head.
pub fn dynamic_transforms(scene: &Scene, stamp_ns: i64) -> Option<TfMessage> {
    let h = scene.camera.pan_tilt.as_ref()?;
    Some(TfMessage {
        transforms: vec![stamped(
            BASE_FRAME,
            HEAD_FRAME,
            stamp_ns,
            &base_from_head(scene, h, stamp_ns),
        )],
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_head_composes_to_the_fixed_mount_at_rest_and_pans_about_z() {
        let mut scene = crate::sim::builtin_scene("chair").unwrap();
        let fixed = mount_at(&scene, START_NS + 123);
        assert_eq!(fixed, base_from_optical(&scene));
        scene.camera.pan_tilt = Some(PanTiltSpec {
            pan_amplitude_deg: 30.0,
            tilt_amplitude_deg: 0.0,
            period_s: 4.0,
        });
        // A quarter period in: pan +30 degrees, so the optical axis turns 30 degrees left.
        let m = mount_at(&scene, START_NS + 1_000_000_000);
        let axis = |m: &Iso3| m.rotation * Vector3::z();
        let (a, b) = (axis(&fixed), axis(&m));
        let yaw = |v: Vector3<f64>| v.y.atan2(v.x);
        assert!((yaw(b) - yaw(a) - 30f64.to_radians()).abs() < 1e-9);
        assert!((m.translation.vector - fixed.translation.vector).norm() < 1e-12);
    }
}
