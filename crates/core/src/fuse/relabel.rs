//! Rectangles round a located object in the frames a labeller did not draw: the fused
//! object's cells projected into each frame as recorded (lens distortion applied), their
//! bounding box. Training on them gives the tile head more views of the object than the few
//! a person labelled (issue #18, "more views of the object").
//!
//! Invariants: pure (camera, lens, pose, grid and cells in; a rectangle out); a frame gets a
//! rectangle only when every projected corner of every cell lies in front of the camera,
//! where the lens's radial distortion still grows with the radius (beyond, the model folds
//! back and would put a point far outside the view inside the image), and the box keeps at
//! least [`MIN_INSIDE`] of its area inside the image (it is then clipped to the image and
//! widened to whole pixels). Occlusion is not modelled: an object hidden in a frame still
//! gets its rectangle there.

use nalgebra::Point3;

use crate::fuse::grid::GridSpec;
use crate::fuse::replay::SessionData;
use crate::types::geometry::{Camera, Iso3};
use crate::types::lens::{Distortion, distorted_pixel};

/// A rectangle of whole pixels of a frame as recorded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PixelRect {
    /// Leftmost column.
    pub x_px: u32,
    /// Topmost row.
    pub y_px: u32,
    /// Width, pixels.
    pub width_px: u32,
    /// Height, pixels.
    pub height_px: u32,
}

/// Least fraction of a projected box inside the image for the frame to be labelled by it: a
/// box mostly outside says little about the tiles that are inside.
pub const MIN_INSIDE: f64 = 0.5;

/// Where the session's frame with header stamp `stamp_ns` was taken from: None when its
/// pose or its camera mount is not known.
pub fn camera_from_odom(data: &SessionData, stamp_ns: i64) -> Option<Iso3> {
    let odom_from_base = data.odom_at(stamp_ns)?;
    let mount = data.mount_at(stamp_ns).ok()?;
    Some((odom_from_base * mount).inverse())
}

/// The bounding box, in a frame of `camera` (as recorded: through `lens`) taken from
/// `camera_from_odom`, of the corners of `cells` (flat indices of `spec`); None when a corner
/// lies behind the camera or the box lies mostly outside the image.
pub fn object_rectangle(
    camera: &Camera,
    lens: &Distortion,
    camera_from_odom: &Iso3,
    spec: &GridSpec,
    cells: &[usize],
) -> Option<PixelRect> {
    let half_m = spec.voxel_size_m / 2.0;
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for &idx in cells {
        let [i, j, k] = spec.ijk(idx);
        let c = spec.center(i, j, k);
        for corner in 0..8 {
            let s = |bit: usize| {
                if corner >> bit & 1 == 1 {
                    half_m
                } else {
                    -half_m
                }
            };
            let p = camera_from_odom * Point3::new(c[0] + s(0), c[1] + s(1), c[2] + s(2));
            let (u, v) = camera.project(&p)?;
            if !radially_monotonic(
                lens,
                (u - camera.cx) / camera.fx,
                (v - camera.cy) / camera.fy,
            ) {
                return None;
            }
            let (u, v) = distorted_pixel(camera, lens, u, v);
            lo = [lo[0].min(u), lo[1].min(v)];
            hi = [hi[0].max(u), hi[1].max(v)];
        }
    }
    let (w, h) = (f64::from(camera.width), f64::from(camera.height));
    let area = (hi[0] - lo[0]) * (hi[1] - lo[1]);
    let clipped = (
        [lo[0].max(0.0), lo[1].max(0.0)],
        [hi[0].min(w), hi[1].min(h)],
    );
    let inside = (clipped.1[0] - clipped.0[0]).max(0.0) * (clipped.1[1] - clipped.0[1]).max(0.0);
    if !(area > 0.0 && inside >= MIN_INSIDE * area) {
        return None;
    }
    // Whole pixels the box covers: a tile is positive only when it lies wholly inside.
    let (x0, y0) = (clipped.0[0].floor(), clipped.0[1].floor());
    let (x1, y1) = (clipped.1[0].ceil(), clipped.1[1].ceil());
    Some(PixelRect {
        x_px: x0 as u32,
        y_px: y0 as u32,
        width_px: (x1 - x0) as u32,
        height_px: (y1 - y0) as u32,
    })
}

/// Whether the lens's radial term r (1 + k1 r^2 + k2 r^4 + k3 r^6) still grows at the ideal
/// normalised point (x, y): its derivative 1 + 3 k1 r^2 + 5 k2 r^4 + 7 k3 r^6 is positive.
fn radially_monotonic(lens: &Distortion, x: f64, y: f64) -> bool {
    let r2 = x * x + y * y;
    1.0 + r2 * (3.0 * lens.k1 + r2 * (5.0 * lens.k2 + r2 * 7.0 * lens.k3)) > 0.0
}

/// Intersection over union of two rectangles (0 when either is empty).
pub fn iou(a: &PixelRect, b: &PixelRect) -> f64 {
    let span = |o: u32, l: u32| (f64::from(o), f64::from(o) + f64::from(l));
    let (ax, bx) = (span(a.x_px, a.width_px), span(b.x_px, b.width_px));
    let (ay, by) = (span(a.y_px, a.height_px), span(b.y_px, b.height_px));
    let overlap = |p: (f64, f64), q: (f64, f64)| (p.1.min(q.1) - p.0.max(q.0)).max(0.0);
    let inter = overlap(ax, bx) * overlap(ay, by);
    let area = |r: &PixelRect| f64::from(r.width_px) * f64::from(r.height_px);
    let union = area(a) + area(b) - inter;
    if union > 0.0 { inter / union } else { 0.0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 100 x 100 px camera at the origin looking along +z (f 100 px, centre 50, 50) and one
    /// 0.1 m cell centred 2 m ahead: its near face (z 1.95 m) spans 50 +- 100 * 0.05 / 1.95 =
    /// 47.44..52.56 px, so the box is pixels 47..53.
    fn one_cell_ahead(x_m: f64) -> (Camera, GridSpec, Vec<usize>) {
        let camera = Camera {
            width: 100,
            height: 100,
            fx: 100.0,
            fy: 100.0,
            cx: 50.0,
            cy: 50.0,
        };
        let spec = GridSpec::from_bounds([x_m - 0.05, -0.05, 1.95], [x_m + 0.05, 0.05, 2.05], 0.1)
            .unwrap();
        (camera, spec, vec![0])
    }

    /// The rectangle of [`one_cell_ahead`]`(x_m)` through `lens`, seen from `pose`.
    fn seen(x_m: f64, lens: &Distortion, pose: &Iso3) -> Option<PixelRect> {
        let (camera, spec, cells) = one_cell_ahead(x_m);
        object_rectangle(&camera, lens, pose, &spec, &cells)
    }

    fn ahead(x_m: f64, lens: &Distortion) -> Option<PixelRect> {
        seen(x_m, lens, &Iso3::identity())
    }

    #[test]
    fn a_cell_ahead_gives_the_box_of_its_near_face() {
        let r = ahead(0.0, &Distortion::default()).unwrap();
        assert_eq!((r.x_px, r.y_px, r.width_px, r.height_px), (47, 47, 6, 6));
        // Behind the camera: none.
        let turned = Iso3::rotation(nalgebra::Vector3::new(0.0, std::f64::consts::PI, 0.0));
        assert!(seen(0.0, &Distortion::default(), &turned).is_none());
    }

    #[test]
    fn a_box_mostly_outside_the_image_labels_nothing_and_one_partly_outside_is_clipped() {
        // Centred on the image's right edge (u = 50 + 100 x / 2 = 100 at x = 1 m): about half
        // inside, 47 % by the near face's wider span: none.
        let none = ahead(1.0, &Distortion::default());
        assert!(none.is_none(), "{none:?}");
        // Its far face from 94.88 px, a third of the box past the edge: clipped at 100 px.
        let r = ahead(0.97, &Distortion::default()).unwrap();
        assert_eq!(r.x_px + r.width_px, 100);
        assert_eq!(r.x_px, 94);
    }

    #[test]
    fn barrel_distortion_pulls_the_box_towards_the_centre() {
        // k1 < 0 moves an off-centre point inwards, by x k1 r^2: at x = 0.4 (u = 90 px) and
        // k1 = -0.5, 0.4 * 0.5 * 0.16 = 0.032, 3.2 px.
        let ideal = ahead(0.8, &Distortion::default()).unwrap();
        let barrel = Distortion {
            k1: -0.5,
            ..Distortion::default()
        };
        let r = ahead(0.8, &barrel).unwrap();
        assert!(r.x_px + 2 <= ideal.x_px, "{r:?} {ideal:?}");
        // k1 = -2 folds back beyond r = sqrt(1 / 6) = 0.41: the cell at x = 0.4 (its corners
        // up to 0.44) gives no rectangle, though its folded projection lies in the image.
        let fold = Distortion {
            k1: -2.0,
            ..Distortion::default()
        };
        assert!(ahead(0.8, &fold).is_none());
        let (camera, _, _) = one_cell_ahead(0.8);
        let (u, _) = distorted_pixel(&camera, &fold, 50.0 + 100.0 * 0.44, 50.0);
        assert!((0.0..100.0).contains(&u), "{u}");
    }

    #[test]
    fn iou_of_rectangles() {
        let r = |x_px, y_px, width_px, height_px| PixelRect {
            x_px,
            y_px,
            width_px,
            height_px,
        };
        assert_eq!(iou(&r(0, 0, 10, 10), &r(0, 0, 10, 10)), 1.0);
        // 5 x 10 shared of 100 + 100 - 50.
        assert_eq!(iou(&r(0, 0, 10, 10), &r(5, 0, 10, 10)), 50.0 / 150.0);
        assert_eq!(iou(&r(0, 0, 10, 10), &r(20, 0, 10, 10)), 0.0);
        assert_eq!(iou(&r(0, 0, 0, 0), &r(0, 0, 0, 0)), 0.0);
    }
}
