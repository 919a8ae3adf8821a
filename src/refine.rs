//! Pose refinement: localise each frame against the belief before fusing it (Markov
//! localisation, which the paper points to, restricted to a window around odometry).
//!
//! The candidate poses are planar corrections (dx, dy, dyaw) of the robot pose predicted by
//! odometry. Each is scored by its log prior under the motion model (Gaussian with the spread
//! the commands since the last frame imply) plus how well the frame's tile evidence agrees
//! with the belief: the belief-weighted mean of the evidence of the tiles the strongest cells
//! project into. The search is a fixed coarse grid followed by finer grids around the best
//! candidate, so it is deterministic; candidates are scored in parallel and the best is
//! chosen by (score, candidate index), so the result does not depend on the thread count.
//!
//! Invariants: pure function of its inputs, no I/O; with an empty belief (nothing to align
//! to) the correction is zero.

use nalgebra::{Point3, Translation3, UnitQuaternion, Vector3};
use rayon::prelude::*;

use crate::geometry::{Camera, Iso3};
use crate::grid::{Grid, TileEvidence};
use crate::objects::{ObjectParams, find_objects_with_cells};

/// How many of the strongest cells the score looks at: enough to cover an object's visual
/// hull at 4 cm, few enough to score hundreds of candidates in milliseconds.
pub const MAX_ANCHOR_CELLS: usize = 4096;

/// The correction chosen for one frame.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Correction {
    /// Added to the predicted position in `odom`, metres.
    pub dx_m: f64,
    pub dy_m: f64,
    /// Added to the predicted heading, radians (about the robot's vertical axis).
    pub dyaw_rad: f64,
    /// Score of the chosen candidate minus the score of no correction.
    pub gain: f64,
    /// Cells of the belief the frame was aligned to.
    pub anchors: usize,
}

impl Correction {
    pub const ZERO: Correction = Correction {
        dx_m: 0.0,
        dy_m: 0.0,
        dyaw_rad: 0.0,
        gain: 0.0,
        anchors: 0,
    };

    /// Applies the correction to a robot pose in `odom`.
    pub fn apply(&self, odom_from_base: &Iso3) -> Iso3 {
        apply(odom_from_base, self.dx_m, self.dy_m, self.dyaw_rad)
    }
}

fn apply(odom_from_base: &Iso3, dx: f64, dy: f64, dyaw: f64) -> Iso3 {
    let rot = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), dyaw) * odom_from_base.rotation;
    let t = odom_from_base.translation.vector + Vector3::new(dx, dy, 0.0);
    Iso3::from_parts(Translation3::from(t), rot)
}

/// The belief cells a frame is aligned to: the cells of the objects found so far, as (centre
/// in odom, evidence). Aligning to located objects rather than to raw evidence matters early
/// on: a single view's evidence is a set of pyramids, which a new view can be turned to
/// overlap in many ways, while the intersection of several views is a compact hull.
pub fn anchors(grid: &Grid, params: &ObjectParams) -> Vec<([f64; 3], f32)> {
    let prior = grid.prior_log_odds();
    let mut cells: Vec<(f32, usize)> = find_objects_with_cells(grid, params)
        .into_iter()
        .flat_map(|(_, cells)| cells)
        .map(|i| (grid.log_odds[i] - prior, i))
        .collect();
    // Strongest first, index breaking ties: a total order, so the cut is reproducible.
    cells.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    cells.truncate(MAX_ANCHOR_CELLS);
    cells
        .into_iter()
        .map(|(e, i)| {
            let [a, b, c] = grid.spec.ijk(i);
            (grid.spec.center(a, b, c), e)
        })
        .collect()
}

/// Tile evidence interpolated between tile centres at continuous tile coordinates (x, y),
/// clamped at the border. Interpolating, rather than taking the tile a point falls in, makes
/// the score change smoothly within a tile, so the best alignment is the centred one instead
/// of anywhere on a tile-wide plateau.
fn bilinear(ev: &TileEvidence, x: f64, y: f64) -> f64 {
    let (cols, rows) = (ev.cols as f64, ev.rows as f64);
    let x = x.clamp(0.0, cols - 1.0);
    let y = y.clamp(0.0, rows - 1.0);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (c0, r0) = (x0 as usize, y0 as usize);
    let (c1, r1) = ((c0 + 1).min(ev.cols - 1), (r0 + 1).min(ev.rows - 1));
    let at = |r: usize, c: usize| f64::from(ev.delta[r * ev.cols + c]);
    (1.0 - fy) * ((1.0 - fx) * at(r0, c0) + fx * at(r0, c1))
        + fy * ((1.0 - fx) * at(r1, c0) + fx * at(r1, c1))
}

/// Belief-weighted mean tile evidence of `anchors` seen from `odom_from_camera`; anchors
/// outside the image count as evidence 0.
fn agreement(
    anchors: &[([f64; 3], f32)],
    odom_from_camera: &Iso3,
    camera: &Camera,
    ev: &TileEvidence,
) -> f64 {
    let camera_from_odom = odom_from_camera.inverse();
    let tile = f64::from(ev.tile_px);
    let (u_max, v_max) = (ev.cols as f64 * tile, ev.rows as f64 * tile);
    let (mut sum, mut w_sum) = (0.0f64, 0.0f64);
    for (c, w) in anchors {
        let w = f64::from(*w);
        w_sum += w;
        let p = camera_from_odom * Point3::new(c[0], c[1], c[2]);
        if p.z <= 1e-9 {
            continue;
        }
        let u = camera.fx * p.x / p.z + camera.cx;
        let v = camera.fy * p.y / p.z + camera.cy;
        if u >= 0.0 && u < u_max && v >= 0.0 && v < v_max {
            sum += w * bilinear(ev, u / tile - 0.5, v / tile - 0.5);
        }
    }
    if w_sum > 0.0 { sum / w_sum } else { 0.0 }
}

/// Finds the correction of `predicted` (odom_from_base) that best explains the frame's
/// evidence `ev` against `grid`, given heading and position standard deviations of the motion
/// since the last frame.
#[allow(clippy::too_many_arguments)]
pub fn refine(
    grid: &Grid,
    params: &ObjectParams,
    camera: &Camera,
    base_from_camera: &Iso3,
    predicted: &Iso3,
    ev: &TileEvidence,
    sigma_yaw_rad: f64,
    sigma_xy_m: f64,
) -> Correction {
    let anchors = anchors(grid, params);
    if anchors.is_empty() || !(sigma_yaw_rad > 0.0 || sigma_xy_m > 0.0) {
        return Correction::ZERO;
    }
    let score = |dx: f64, dy: f64, dyaw: f64| -> f64 {
        let pose = apply(predicted, dx, dy, dyaw) * base_from_camera;
        let prior_yaw = if sigma_yaw_rad > 0.0 {
            (dyaw / sigma_yaw_rad).powi(2)
        } else {
            0.0
        };
        let prior_xy = if sigma_xy_m > 0.0 {
            (dx * dx + dy * dy) / (sigma_xy_m * sigma_xy_m)
        } else {
            0.0
        };
        agreement(&anchors, &pose, camera, ev) - 0.5 * (prior_yaw + prior_xy)
    };
    let base_score = score(0.0, 0.0, 0.0);
    // Coarse grid over +-3 sigma, then three rounds of a 3x3x3 grid at half the step around
    // the best so far.
    let span_yaw = 3.0 * sigma_yaw_rad;
    let span_xy = 3.0 * sigma_xy_m;
    let (n_yaw, n_xy) = (
        if span_yaw > 0.0 { 6 } else { 0 },
        if span_xy > 0.0 { 3 } else { 0 },
    );
    let mut step_yaw = if n_yaw > 0 {
        span_yaw / n_yaw as f64
    } else {
        0.0
    };
    let mut step_xy = if n_xy > 0 { span_xy / n_xy as f64 } else { 0.0 };
    let mut best = (base_score, 0.0, 0.0, 0.0);
    let mut centre = (0.0, 0.0, 0.0);
    for round in 0..4 {
        let (ny, nxy) = if round == 0 {
            (n_yaw as i64, n_xy as i64)
        } else {
            (i64::from(n_yaw > 0), i64::from(n_xy > 0))
        };
        let mut cands = Vec::new();
        for a in -ny..=ny {
            for i in -nxy..=nxy {
                for j in -nxy..=nxy {
                    cands.push((
                        centre.0 + i as f64 * step_xy,
                        centre.1 + j as f64 * step_xy,
                        centre.2 + a as f64 * step_yaw,
                    ));
                }
            }
        }
        let scored: Vec<(f64, usize)> = cands
            .par_iter()
            .enumerate()
            .map(|(k, &(dx, dy, dyaw))| (score(dx, dy, dyaw), k))
            .collect();
        // Highest score, lowest index on ties: the same choice on any thread count.
        if let Some(&(s, k)) = scored
            .iter()
            .max_by(|a, b| a.0.total_cmp(&b.0).then(b.1.cmp(&a.1)))
            && s > best.0
        {
            best = (s, cands[k].0, cands[k].1, cands[k].2);
        }
        centre = (best.1, best.2, best.3);
        step_yaw /= 2.0;
        step_xy /= 2.0;
    }
    Correction {
        dx_m: best.1,
        dy_m: best.2,
        dyaw_rad: best.3,
        gain: best.0 - base_score,
        anchors: anchors.len(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{camera_mount, iso_from_xy_yaw};
    use crate::grid::GridSpec;

    fn params() -> ObjectParams {
        ObjectParams {
            min_views: 0,
            ..ObjectParams::default()
        }
    }

    /// A belief with one hot block, a camera that saw it from a pose off by a known yaw: the
    /// refinement recovers the yaw to within a fraction of a tile's angle.
    #[test]
    fn recovers_a_known_heading_error() {
        let spec = GridSpec::from_bounds([-1.0, -1.0, 0.0], [1.0, 1.0, 1.0], 0.04).unwrap();
        let mut g = Grid::new(spec, 0.01).unwrap();
        let prior = g.prior_log_odds();
        for i in 0..spec.cells() {
            let [a, b, c] = spec.ijk(i);
            let p = spec.center(a, b, c);
            if p[0].abs() < 0.1 && p[1].abs() < 0.1 && (p[2] - 0.5).abs() < 0.2 {
                g.log_odds[i] = prior + 20.0;
            }
        }
        let cam = Camera::with_hfov(256, 240, 1.05);
        let mount = camera_mount([0.0, 0.0, 0.5], 0.0);
        let truth = iso_from_xy_yaw(-2.5, 0.0, 0.0);
        // The tiles the block covers, seen from the true pose.
        let (rows, cols) = (30, 32);
        let mut p = vec![0.005f32; rows * cols];
        let cam_from_odom = (truth * mount).inverse();
        for i in 0..spec.cells() {
            if g.log_odds[i] > prior {
                let [a, b, c] = spec.ijk(i);
                let q = spec.center(a, b, c);
                if let Some((u, v)) = cam.project(&(cam_from_odom * Point3::new(q[0], q[1], q[2])))
                    && u >= 0.0
                    && v >= 0.0
                    && u < 256.0
                    && v < 240.0
                {
                    p[(v / 8.0) as usize * cols + (u / 8.0) as usize] = 0.95;
                }
            }
        }
        let ev = TileEvidence::from_probabilities(rows, cols, 8, &p, 0.01);
        // Odometry believes the robot is turned 0.08 rad (4.6 degrees) to the left.
        let predicted = iso_from_xy_yaw(-2.5, 0.0, 0.08);
        let c = refine(&g, &params(), &cam, &mount, &predicted, &ev, 0.06, 0.02);
        assert!((c.dyaw_rad + 0.08).abs() < 0.02, "{c:?}");
        assert!(c.gain > 0.0);
        let fixed = c.apply(&predicted);
        assert!(crate::geometry::yaw_of(&fixed).abs() < 0.02);
        // With exact odometry the correction stays within the same tolerance of zero.
        let c0 = refine(&g, &params(), &cam, &mount, &truth, &ev, 0.06, 0.02);
        assert!(
            c0.dyaw_rad.abs() < 0.02 && c0.dx_m.abs() < 0.03 && c0.dy_m.abs() < 0.03,
            "{c0:?}"
        );
    }

    #[test]
    fn empty_belief_means_no_correction() {
        let spec = GridSpec::from_bounds([-1.0; 3], [1.0; 3], 0.1).unwrap();
        let g = Grid::new(spec, 0.01).unwrap();
        let cam = Camera::with_hfov(64, 48, 1.0);
        let ev = TileEvidence::from_probabilities(6, 8, 8, &[0.5; 48], 0.01);
        let c = refine(
            &g,
            &params(),
            &cam,
            &Iso3::identity(),
            &Iso3::identity(),
            &ev,
            0.1,
            0.1,
        );
        assert_eq!(c, Correction::ZERO);
    }
}
