//! The replay against a stand-in classifier on a session written here, message by message:
//! every number below is a hand-computed Bayes update in odds form.

use super::*;
use crate::fuse::grid::logit;
use crate::io::msgs::{
    CameraInfo, CompressedImage, Header, Odometry, Pose, TfMessage, TransformStamped, Twist,
};
use crate::io::session::{SessionWriter, Topics};
use crate::types::geometry::camera_mount;

/// Every tile the same probability, whatever the image: the grid then holds exactly the
/// number of views times the tile's log-likelihood ratio.
struct Constant(f32);

impl FrameClassifier for Constant {
    fn classify(&self, img: &Rgb8) -> TileProbs {
        let (rows, cols) = ((img.height / 8) as usize, (img.width / 8) as usize);
        TileProbs {
            rows,
            cols,
            tile_px: 8,
            p: vec![self.0; rows * cols],
        }
    }
    fn base_rate(&self) -> f64 {
        0.2
    }
}

/// A 64 x 48 camera 1 m up, looking along +x, at the origin for `frames` frames 1 s apart;
/// no /cmd_vel (nothing to blur or refine).
fn session(path: &std::path::Path, frames: i64) -> SessionReader {
    session_with_distortion(path, frames, &[])
}

/// [`session`] with plumb_bob distortion `d` in CameraInfo (none when empty).
fn session_with_distortion(path: &std::path::Path, frames: i64, d: &[f64]) -> SessionReader {
    session_of(path, frames, d, "base_link")
}

/// [`session_with_distortion`] whose /odom moves `odom_child` (the mount is on base_link).
fn session_of(path: &std::path::Path, frames: i64, d: &[f64], odom_child: &str) -> SessionReader {
    let mut w = SessionWriter::create(path).unwrap();
    let t = Topics::default();
    let start = 1_000_000_000;
    let mount = camera_mount([0.0, 0.0, 1.0], 0.0);
    let q = mount.rotation.quaternion();
    let v = mount.translation.vector;
    let tf = TfMessage {
        transforms: vec![TransformStamped {
            header: Header::new(start, "base_link"),
            child_frame_id: "camera".into(),
            translation: [v.x, v.y, v.z],
            rotation_xyzw: [q.i, q.j, q.k, q.w],
        }],
    };
    w.write(&t.tf_static, start, &tf).unwrap();
    let png = crate::types::image::encode_png(64, 48, &vec![90u8; 64 * 48 * 3]).unwrap();
    for k in 0..frames {
        let stamp = start + k * 1_000_000_000;
        let odom = Odometry {
            header: Header::new(stamp, "odom"),
            child_frame_id: odom_child.into(),
            pose: Pose {
                position: [0.0; 3],
                orientation_xyzw: [0.0, 0.0, 0.0, 1.0],
            },
            pose_covariance: [0.0; 36],
            twist: Twist::default(),
            twist_covariance: [0.0; 36],
        };
        w.write(&t.odom, stamp, &odom).unwrap();
        let header = Header::new(stamp, "camera");
        let mut info = CameraInfo::pinhole(header.clone(), 64, 48, 40.0, 40.0, 32.0, 24.0);
        if !d.is_empty() {
            info.d = d.to_vec();
        }
        w.write(&t.camera_info, stamp, &info).unwrap();
        let image = CompressedImage {
            header,
            format: "png".into(),
            data: png.clone(),
        };
        w.write(&t.compressed_image, stamp, &image).unwrap();
    }
    let path = w.finish().unwrap();
    SessionReader::open(&path, Topics::default()).unwrap()
}

#[test]
fn each_view_adds_the_tiles_log_likelihood_ratio_to_the_cells_it_sees() {
    let dir = tempfile::tempdir().unwrap();
    let reader = session(&dir.path().join("s.mcap"), 3);
    let options = FuseOptions {
        bounds_m: Some(([-1.0, -1.0, 0.0], [3.0, 1.0, 2.0])),
        voxel_size_m: 0.1,
        ..FuseOptions::default()
    };
    let out = replay(&reader, &Constant(0.6), &options, &mut []).unwrap();
    assert_eq!(out.frames_fused, 3);
    // No /cmd_vel: the session chose no refinement, and says so.
    assert!(!out.options.refine_poses);
    assert!(
        out.choices
            .iter()
            .any(|c| c.starts_with("no pose refinement"))
    );
    let g = &out.grid;
    let prior = logit(0.2);
    // Odds form: posterior log-odds = prior + views x (logit(0.6) - logit(0.2)).
    let step = logit(0.6) - prior;
    // A cell 2 m ahead on the optical axis (x = 2.05, y = 0.05, z = 1.05) is seen 3 times; a
    // cell behind the camera (x = -0.95) never.
    let ahead = g.spec.index(30, 10, 10);
    let behind = g.spec.index(0, 10, 10);
    assert_eq!(g.views_at(ahead), 3);
    assert!((f64::from(g.log_odds_at(ahead)) - (prior + 3.0 * step)).abs() < 1e-5);
    assert_eq!(g.views_at(behind), 0);
    assert!((f64::from(g.log_odds_at(behind)) - prior).abs() < 1e-6);
    // A classifier at the prior leaves the grid at the prior: evidence is relative.
    let flat = replay(&reader, &Constant(0.2), &options, &mut []).unwrap();
    // (0.2 as f32 is 3e-9 off 0.2: a delta of 2e-8.)
    assert!((0..flat.grid.spec.cells()).all(|i| flat.grid.evidence_at(i).abs() < 1e-6));
    assert!(flat.objects.is_empty());
}

/// Keeps every step's image, and the session's rectifier.
#[derive(Default)]
struct Images(Vec<StepImage>, Option<crate::types::lens::Rectifier>);

impl Observer for Images {
    fn on_frame(
        &mut self,
        data: &SessionData,
        step: &FrameStep,
        _grid: &Grid,
    ) -> Result<(), ObserverError> {
        self.0.push(step.image.clone());
        self.1.clone_from(&data.rectifier);
        Ok(())
    }
}

#[test]
fn observers_get_the_recorded_file_unless_the_frame_is_undistorted_first() {
    let dir = tempfile::tempdir().unwrap();
    let png = crate::types::image::encode_png(64, 48, &vec![90u8; 64 * 48 * 3]).unwrap();
    let options = FuseOptions {
        bounds_m: Some(([-1.0, -1.0, 0.0], [3.0, 1.0, 2.0])),
        voxel_size_m: 0.1,
        ..FuseOptions::default()
    };
    let plain = session(&dir.path().join("plain.mcap"), 2);
    let mut seen = Images::default();
    replay(&plain, &Constant(0.6), &options, &mut [&mut seen]).unwrap();
    let want = StepImage::Encoded {
        media: EncodedMedia::Png,
        bytes: png,
        width: 64,
        height: 48,
    };
    assert_eq!(seen.0, vec![want.clone(), want]);
    // With a distorted lens the pass fuses the undistorted pixels, and that is what is shown.
    let distorted =
        session_with_distortion(&dir.path().join("d.mcap"), 2, &[0.3, 0.05, 0.0, 0.0, 0.0]);
    let mut seen = Images::default();
    replay(&distorted, &Constant(0.6), &options, &mut [&mut seen]).unwrap();
    assert_eq!(seen.0.len(), 2);
    for img in &seen.0 {
        let StepImage::Decoded(rgb) = img else {
            panic!("a distorted frame was handed over as recorded");
        };
        assert_eq!((rgb.width, rgb.height), (64, 48));
        // The decode kept from classifying: the recorded card rectified, as fused.
        let card = Rgb8 {
            width: 64,
            height: 48,
            data: vec![90u8; 64 * 48 * 3],
        };
        let want = seen.1.as_ref().expect("a distorted lens").apply(&card);
        assert_eq!(rgb, &want);
        let black = want.data.chunks(3).filter(|p| p == &[0, 0, 0]).count();
        assert!(
            black > 0 && want.data[(24 * 64 + 32) * 3] == 90,
            "{black} black"
        );
    }
}

#[test]
fn a_mount_that_no_transform_links_to_the_odom_frame_is_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let linked = load_session(&session(&dir.path().join("a.mcap"), 2)).unwrap();
    assert!(
        !linked.warnings.iter().any(|w| w.contains("camera mount")),
        "{:?}",
        linked.warnings
    );
    let path = dir.path().join("b.mcap");
    let data = load_session(&session_of(&path, 2, &[], "base_footprint")).unwrap();
    let said: Vec<&String> = data
        .warnings
        .iter()
        .filter(|w| w.contains("camera mount"))
        .collect();
    assert_eq!(said.len(), 1, "{:?}", data.warnings);
    assert_eq!(
        *said[0],
        format!(
            "{}: the camera mount is taken from base_link -> camera on /tf_static, but /odom \
             moves \"base_footprint\", which no transform connects to it (a moving mount's \
             /tf missing?)",
            path.display()
        )
    );
}

/// An object with cells in the outermost x layer and the top layer of a 10 x 10 x 5 grid of
/// 0.1 m from (-0.5, -0.5, 0) is said to reach those two sides, with their coordinates; one
/// standing on the bottom layer only is not (the floor is where objects stand).
#[test]
fn objects_reaching_the_default_grids_sides_are_named_with_the_sides() {
    let spec = GridSpec::from_bounds([-0.5, -0.5, 0.0], [0.5, 0.5, 0.5], 0.1).unwrap();
    assert_eq!(spec.dims, [10, 10, 5]);
    let object = Object::cube([0.0; 3], 0.0);
    let at_side = vec![spec.index(9, 4, 2), spec.index(4, 4, 4)];
    let on_floor = vec![spec.index(4, 4, 0), spec.index(5, 5, 1)];
    let said = objects_at_default_edges(
        "s.mcap",
        &spec,
        &[(object.clone(), on_floor), (object, at_side)],
    );
    assert_eq!(said.len(), 1, "{said:?}");
    assert!(
        said[0].starts_with(
            "s.mcap: object 1 reaches the edge of the default grid (x = 0.50, z = 0.50): it may run past it"
        ),
        "{said:?}"
    );
}
