//! A smoother over the whole replay: every frame's planar pose correction and every object's
//! position solved together, under the motion model's covariance between consecutive frames,
//! the frames' detections of the objects, and the floor where it placed a frame.
//!
//! Why: the filter ([`super::refine`]) fixes each landmark from the first views that see it,
//! so an early frame's odometry error goes into the landmark whole and every later frame is
//! aligned to it (docs/fuser.md, "A smoother over the whole replay": the bin on a shelf's
//! 5 %/3 % tour, its landmark 0.29 m off after two views and the object 0.38 m off). An
//! offline replay can weigh every view against every other.
//!
//! The problem is least squares in the corrections e_k = (dx, dy, dyaw) of /odom (the
//! refinement's parameters, in `odom`) and the objects' points: a link from frame k-1 to k
//! says e_k is e_{k-1} carried along /odom's displacement (a heading error turns it), up to
//! the motion model's covariance; a detection says where the object projects, up to the
//! refinement's pixel sigmas (Huber-weighted); a frame the floor placed keeps the filter's
//! correction within [`ANCHOR_SIGMA_M`] / [`ANCHOR_SIGMA_RAD`]. The normal equations are an
//! arrow: block-tridiagonal in the frames, dense in the few objects, solved by eliminating
//! the frames (cost linear in the frames).
//!
//! Invariants: a pure function of its inputs; frame 0 is held at its /odom pose (it anchors
//! the frame of reference, as in the replay); every sum in a fixed order; each step is kept
//! only when it lowers the cost.

use nalgebra::{DMatrix, DVector, Matrix3, Matrix3xX, Vector2, Vector3};

use super::landmarks::{Landmark, associate, project};
use super::{SIGMA_U_PX, SIGMA_V_PX, apply};
use crate::types::geometry::{Camera, Iso3, wrap_angle, yaw_of};

/// How closely a frame the floor placed keeps the filter's correction, metres (x and y).
/// Measured (docs/fuser.md): 0.02 m let the two-chairs tours drift off what their floor says
/// (the wide set 5 low-noise tours worse than /odom against 2); 0.01 m keeps them.
pub const ANCHOR_SIGMA_M: f64 = 0.01;
/// The same for the heading, radians.
pub const ANCHOR_SIGMA_RAD: f64 = 0.01;
/// Detections further than this many sigmas from where the object projects count linearly
/// (Huber): a cluster that merged two objects, a shadow.
pub const HUBER_SIGMAS: f64 = 2.0;
/// Times the detections are paired with the objects again at the current estimate.
pub const ROUNDS: usize = 4;
/// Gauss-Newton steps per round, at most.
pub const ITERATIONS: usize = 15;
/// Prior standard deviation of the odometry's speed and turn scale errors (fractions): a
/// wheel-radius or track-width miscalibration turns every frame by a share of its turns,
/// which the links alone would read as noise and spread over the frames (measured:
/// docs/fuser.md, "A smoother over the whole replay").
pub const CALIBRATION_SIGMA: f64 = 0.05;

/// What the smoother needs of one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct SmoothFrame {
    /// /odom's robot pose (odom_from_base).
    pub odometry: Iso3,
    /// The camera mount (base_from_camera).
    pub mount: Iso3,
    /// Detection cluster centres, rectified pixels.
    pub clusters: Vec<[f64; 2]>,
    /// The correction (dx, dy, dyaw in `odom`) to start from: the filter's.
    pub start: Vector3<f64>,
    /// Covariance of the motion from the previous frame to this one (x, y, yaw in `odom`;
    /// m^2, rad^2); unused for frame 0.
    pub link_cov: Matrix3<f64>,
    /// Whether the floor placed the frame (its `start` is then a measurement).
    pub floor_placed: bool,
}

/// The smoothed corrections per frame (frame 0's is zero) and the objects' points.
#[derive(Debug, Clone, PartialEq)]
pub struct Smoothed {
    /// Per frame: (dx, dy, dyaw) of /odom, in `odom`.
    pub corrections: Vec<Vector3<f64>>,
    /// Per object: its point in `odom`, metres.
    pub objects_m: Vec<Vector3<f64>>,
    /// Detections paired with an object in the last round.
    pub observations: usize,
    /// The cost (half the sum of squared whitened residuals) at the start and at the end.
    pub cost: [f64; 2],
    /// The odometry's speed and turn scale errors solved for (fractions; z unused).
    pub calibration: Vector3<f64>,
    /// The largest squared whitened residual of one link (3 dof), and its frame: how far
    /// the solution strays from what the motion model allows between two frames.
    pub max_link_chi2: (f64, usize),
}

impl SmoothFrame {
    fn camera_pose(&self, e: &Vector3<f64>) -> Iso3 {
        apply(&self.odometry, e.x, e.y, e.z) * self.mount
    }
}

/// The robot pose `odometry` corrected by `e` (dx, dy, dyaw in `odom`).
pub fn corrected(odometry: &Iso3, e: &Vector3<f64>) -> Iso3 {
    apply(odometry, e.x, e.y, e.z)
}

/// The correction (dx, dy, dyaw) that takes `odometry` to `pose`.
pub fn correction_of(odometry: &Iso3, pose: &Iso3) -> Vector3<f64> {
    let d = pose.translation.vector - odometry.translation.vector;
    Vector3::new(d.x, d.y, wrap_angle(yaw_of(pose) - yaw_of(odometry)))
}

/// The correction at frame k carried from frame k-1's along /odom's displacement `dp`
/// between them: a heading error turns the displacement.
fn carried(prev: &Vector3<f64>, dp: &Vector2<f64>) -> Vector3<f64> {
    let (s, c) = prev.z.sin_cos();
    let turned = Vector2::new(c * dp.x - s * dp.y, s * dp.x + c * dp.y) - dp;
    Vector3::new(prev.x + turned.x, prev.y + turned.y, prev.z)
}

/// The state: corrections of frames 1.. and the objects' points.
#[derive(Clone)]
struct State {
    e: Vec<Vector3<f64>>,
    objects: Vec<Vector3<f64>>,
}

impl State {
    /// The odometry's speed and turn scale errors (fractions; the third is unused): the
    /// last of `objects`.
    fn cal(&self) -> Vector3<f64> {
        self.objects.last().copied().unwrap_or_else(Vector3::zeros)
    }
    fn corr(&self, k: usize) -> Vector3<f64> {
        if k == 0 {
            Vector3::zeros()
        } else {
            self.e[k - 1]
        }
    }
}

/// One residual block: its whitened value and its Jacobians by the variables it reads.
struct Term {
    r: Vector3<f64>,
    /// (variable, Jacobian); a variable is a frame (1..) or an object (frames + j).
    jac: Vec<(usize, Matrix3<f64>)>,
}

struct Problem<'a> {
    frames: &'a [SmoothFrame],
    camera: &'a Camera,
    whiten: Vec<Matrix3<f64>>,
    anchor_whiten: Matrix3<f64>,
    /// Per frame: (object, cluster) pairs.
    pairs: Vec<Vec<(usize, usize)>>,
    /// Whether the odometry's scale errors are solved for.
    calibrate: bool,
}

const STEP: f64 = 1e-6;

impl Problem<'_> {
    fn n(&self) -> usize {
        self.frames.len()
    }

    fn link(&self, k: usize, s: &State, jacobians: bool) -> Term {
        let (from, to) = (&self.frames[k - 1].odometry, &self.frames[k].odometry);
        let dp = (to.translation.vector - from.translation.vector).xy();
        let dyaw = wrap_angle(yaw_of(to) - yaw_of(from));
        let w = &self.whiten[k - 1];
        // The odometry's scale errors (`cal`: speed and turn, fractions) move the frame by
        // that share of /odom's displacement and turn.
        let res = |a: &Vector3<f64>, b: &Vector3<f64>, cal: &Vector3<f64>| {
            let mut r =
                b - carried(a, &dp) - Vector3::new(cal.x * dp.x, cal.x * dp.y, cal.y * dyaw);
            r.z = wrap_angle(r.z);
            w * r
        };
        let (a, b, cal) = (s.corr(k - 1), s.corr(k), s.cal());
        let r = res(&a, &b, &cal);
        let mut jac = Vec::new();
        if jacobians {
            jac.push((k, *w));
            let (mut ja, mut jc) = (Matrix3::zeros(), Matrix3::zeros());
            for i in 0..3 {
                let mut d = Vector3::zeros();
                d[i] = STEP;
                ja.set_column(i, &((res(&(a + d), &b, &cal) - r) / STEP));
                jc.set_column(i, &((res(&a, &b, &(cal + d)) - r) / STEP));
            }
            if k > 1 {
                jac.push((k - 1, ja));
            }
            if self.calibrate {
                jac.push((self.n() + s.objects.len() - 1, jc));
            }
        }
        Term { r, jac }
    }

    /// The prior on the odometry's scale errors: zero, within [`CALIBRATION_SIGMA`].
    fn calibration(&self, s: &State) -> Term {
        let w = Matrix3::from_diagonal(&Vector3::new(
            1.0 / CALIBRATION_SIGMA,
            1.0 / CALIBRATION_SIGMA,
            1.0,
        ));
        Term {
            r: w * s.cal(),
            jac: vec![(self.n() + s.objects.len() - 1, w)],
        }
    }

    fn anchor(&self, k: usize, s: &State) -> Term {
        let d = s.corr(k) - self.frames[k].start;
        let d = Vector3::new(d.x, d.y, wrap_angle(d.z));
        Term {
            r: self.anchor_whiten * d,
            jac: vec![(k, self.anchor_whiten)],
        }
    }

    /// A detection's whitened miss (z = 0), Huber-weighted; `None` behind the camera.
    fn detection(&self, k: usize, j: usize, c: usize, s: &State, jacobians: bool) -> Option<Term> {
        let f = &self.frames[k];
        let cl = f.clusters[c];
        let res = |e: &Vector3<f64>, l: &Vector3<f64>| -> Option<Vector3<f64>> {
            let p = project(self.camera, &f.camera_pose(e).inverse(), l)?;
            Some(Vector3::new(
                (p[0] - cl[0]) / SIGMA_U_PX,
                (p[1] - cl[1]) / SIGMA_V_PX,
                0.0,
            ))
        };
        let (e, l) = (s.corr(k), s.objects[j]);
        let r = res(&e, &l)?;
        let norm = r.norm();
        let scale = if norm <= HUBER_SIGMAS {
            1.0
        } else {
            (HUBER_SIGMAS / norm).sqrt()
        };
        let mut jac = Vec::new();
        if jacobians {
            let (mut je, mut jl) = (Matrix3::zeros(), Matrix3::zeros());
            for i in 0..3 {
                let mut d = Vector3::zeros();
                d[i] = STEP;
                je.set_column(i, &((res(&(e + d), &l)? - r) / STEP * scale));
                jl.set_column(i, &((res(&e, &(l + d))? - r) / STEP * scale));
            }
            if k > 0 {
                jac.push((k, je));
            }
            jac.push((self.n() + j, jl));
        }
        Some(Term { r: r * scale, jac })
    }

    /// Every term at `s`, in a fixed order: links, anchors, detections.
    fn terms(&self, s: &State, jacobians: bool) -> Vec<Term> {
        let mut out = Vec::new();
        for k in 1..self.n() {
            out.push(self.link(k, s, jacobians));
            if self.frames[k].floor_placed {
                out.push(self.anchor(k, s));
            }
        }
        if self.calibrate {
            out.push(self.calibration(s));
        }
        for (k, pairs) in self.pairs.iter().enumerate() {
            for &(j, c) in pairs {
                out.extend(self.detection(k, j, c, s, jacobians));
            }
        }
        out
    }

    fn cost(&self, s: &State) -> f64 {
        self.terms(s, false)
            .iter()
            .map(|t| 0.5 * t.r.norm_squared())
            .sum()
    }
}

/// The normal equations, arrow-shaped: frames 1..n (block-tridiagonal), then the objects.
struct Normal {
    /// Frame blocks: diagonal d[i] and super-diagonal e[i] = H(i, i+1), i over frames 1..
    d: Vec<Matrix3<f64>>,
    e: Vec<Matrix3<f64>>,
    /// H(frame i, object j), per frame a row of object blocks.
    b: Vec<Vec<Matrix3<f64>>>,
    /// H(object a, object b).
    c: DMatrix<f64>,
    gp: Vec<Vector3<f64>>,
    gl: DVector<f64>,
}

impl Normal {
    fn new(frames: usize, objects: usize) -> Self {
        let p = frames - 1;
        Self {
            d: vec![Matrix3::zeros(); p],
            e: vec![Matrix3::zeros(); p.saturating_sub(1)],
            b: vec![vec![Matrix3::zeros(); objects]; p],
            c: DMatrix::zeros(3 * objects, 3 * objects),
            gp: vec![Vector3::zeros(); p],
            gl: DVector::zeros(3 * objects),
        }
    }

    /// Adds a term: J^T J into H, J^T r into g; `frames` tells frame variables from objects.
    fn add(&mut self, t: &Term, frames: usize) {
        for (va, ja) in &t.jac {
            let g = ja.transpose() * t.r;
            if *va < frames {
                self.gp[va - 1] += g;
            } else {
                let mut rows = self.gl.fixed_rows_mut::<3>(3 * (va - frames));
                rows += g;
            }
            for (vb, jb) in &t.jac {
                let h = ja.transpose() * jb;
                match (*va < frames, *vb < frames) {
                    (true, true) if va == vb => self.d[va - 1] += h,
                    (true, true) if vb == &(va + 1) => self.e[va - 1] += h,
                    (true, true) => {}
                    (true, false) => self.b[va - 1][vb - frames] += h,
                    (false, false) => {
                        let (a, b) = (3 * (va - frames), 3 * (vb - frames));
                        let mut blk = self.c.fixed_view_mut::<3, 3>(a, b);
                        blk += h;
                    }
                    (false, true) => {}
                }
            }
        }
    }

    /// Solves (H + lambda diag(H)) x = -g; `None` when singular.
    fn solve(&self, lambda: f64) -> Option<(Vec<Vector3<f64>>, DVector<f64>)> {
        let p = self.d.len();
        let m3 = self.gl.len();
        let damp = |mut h: Matrix3<f64>| {
            for i in 0..3 {
                h[(i, i)] += lambda * h[(i, i)] + 1e-12;
            }
            h
        };
        // Right-hand sides per frame: [-g | B] (1 + 3M columns); forward elimination of the
        // block-tridiagonal frames, then back substitution: Y = A^-1 [-g | B].
        let cols = 1 + m3;
        let rhs: Vec<Matrix3xX<f64>> = (0..p)
            .map(|i| {
                let mut r = Matrix3xX::zeros(cols);
                r.fixed_view_mut::<3, 1>(0, 0).copy_from(&(-self.gp[i]));
                for (j, blk) in self.b[i].iter().enumerate() {
                    r.fixed_view_mut::<3, 3>(0, 1 + 3 * j).copy_from(blk);
                }
                r
            })
            .collect();
        let mut dinv: Vec<Matrix3<f64>> = Vec::with_capacity(p);
        let mut rp: Vec<Matrix3xX<f64>> = Vec::with_capacity(p);
        for i in 0..p {
            let mut di = damp(self.d[i]);
            let mut ri = rhs[i].clone();
            if i > 0 {
                let et = self.e[i - 1].transpose();
                di -= et * dinv[i - 1] * self.e[i - 1];
                ri -= et * dinv[i - 1] * &rp[i - 1];
            }
            dinv.push(di.try_inverse()?);
            rp.push(ri);
        }
        let mut y: Vec<Matrix3xX<f64>> = vec![Matrix3xX::zeros(cols); p];
        for i in (0..p).rev() {
            let mut ri = rp[i].clone();
            if i + 1 < p {
                ri -= self.e[i] * &y[i + 1];
            }
            y[i] = dinv[i] * ri;
        }
        // Objects: (C - B^T A^-1 B) dl = -gl - B^T A^-1 (-g), then the frames.
        let mut s = self.c.clone();
        for i in 0..m3 {
            s[(i, i)] += lambda * s[(i, i)] + 1e-12;
        }
        let mut rl = -self.gl.clone();
        for (row, yi) in self.b.iter().zip(&y) {
            let bt = btrans(row);
            s -= &bt * yi.columns(1, m3);
            rl -= &bt * yi.column(0);
        }
        let dl = s.cholesky()?.solve(&rl);
        let dp = y
            .iter()
            .map(|yi| {
                let v = yi.column(0) - yi.columns(1, m3) * &dl;
                Vector3::new(v[0], v[1], v[2])
            })
            .collect();
        Some((dp, dl))
    }
}

/// The 3M x 3 transpose of a frame's row of object blocks.
fn btrans(row: &[Matrix3<f64>]) -> DMatrix<f64> {
    let mut out = DMatrix::zeros(3 * row.len(), 3);
    for (j, blk) in row.iter().enumerate() {
        out.fixed_view_mut::<3, 3>(3 * j, 0)
            .copy_from(&blk.transpose());
    }
    out
}

/// Solves the smoother from the frames' starting corrections and `objects_m` (the filter's
/// objects); `None` for fewer than two frames, no object, or a singular system.
pub fn smooth(
    frames: &[SmoothFrame],
    objects_m: &[Vector3<f64>],
    camera: &Camera,
    calibrate: bool,
) -> Option<Smoothed> {
    let n = frames.len();
    if n < 2 || objects_m.is_empty() {
        return None;
    }
    let whiten = frames[1..]
        .iter()
        .map(|f| f.link_cov.cholesky().and_then(|c| c.l().try_inverse()))
        .collect::<Option<Vec<_>>>()?;
    let anchor_whiten = Matrix3::from_diagonal(&Vector3::new(
        1.0 / ANCHOR_SIGMA_M,
        1.0 / ANCHOR_SIGMA_M,
        1.0 / ANCHOR_SIGMA_RAD,
    ));
    let mut s = State {
        e: frames[1..].iter().map(|f| f.start).collect(),
        objects: objects_m
            .iter()
            .copied()
            .chain(std::iter::once(Vector3::zeros()))
            .collect(),
    };
    let mut problem = Problem {
        frames,
        camera,
        whiten,
        anchor_whiten,
        pairs: Vec::new(),
        calibrate,
    };
    let mut first_cost = None;
    let mut cost = 0.0;
    for _ in 0..ROUNDS {
        problem.pairs = pair(frames, &s, camera);
        cost = problem.cost(&s);
        first_cost.get_or_insert(cost);
        let mut lambda = 1e-4;
        for _ in 0..ITERATIONS {
            let mut normal = Normal::new(n, s.objects.len());
            for t in problem.terms(&s, true) {
                normal.add(&t, n);
            }
            let Some((dp, dl)) = normal.solve(lambda) else {
                lambda *= 10.0;
                continue;
            };
            let mut next = s.clone();
            for (e, d) in next.e.iter_mut().zip(&dp) {
                *e += d;
            }
            for (j, o) in next.objects.iter_mut().enumerate() {
                *o += Vector3::new(dl[3 * j], dl[3 * j + 1], dl[3 * j + 2]);
            }
            let next_cost = problem.cost(&next);
            if next_cost < cost {
                let done = cost - next_cost < 1e-9 * cost.max(1.0);
                (s, cost) = (next, next_cost);
                lambda = (lambda * 0.3).max(1e-9);
                if done {
                    break;
                }
            } else {
                lambda *= 10.0;
                if lambda > 1e6 {
                    break;
                }
            }
        }
    }
    let max_link_chi2 = (1..n)
        .map(|k| (problem.link(k, &s, false).r.norm_squared(), k))
        .fold((0.0, 0), |a, b| if b.0 > a.0 { b } else { a });
    Some(Smoothed {
        max_link_chi2,
        corrections: (0..n).map(|k| s.corr(k)).collect(),
        objects_m: s.objects[..objects_m.len()].to_vec(),
        calibration: s.cal(),
        observations: problem.pairs.iter().map(Vec::len).sum(),
        cost: [first_cost.unwrap_or(cost), cost],
    })
}

/// Each frame's detections paired with the objects where they project at `s` (the
/// refinement's rule: nearest cluster within its gate, closest pairs first).
fn pair(frames: &[SmoothFrame], s: &State, camera: &Camera) -> Vec<Vec<(usize, usize)>> {
    let lms: Vec<Landmark> = s.objects[..s.objects.len() - 1]
        .iter()
        .map(|&position_m| Landmark {
            position_m,
            covariance_m2: Matrix3::zeros(),
        })
        .collect();
    frames
        .iter()
        .enumerate()
        .map(|(k, f)| associate(&lms, &f.clusters, camera, &f.camera_pose(&s.corr(k))))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::types::geometry::{camera_mount, iso_from_xy_yaw};

    fn camera() -> Camera {
        Camera {
            fx: 250.0,
            fy: 250.0,
            cx: 160.0,
            cy: 120.0,
            width: 320,
            height: 240,
        }
    }

    /// A robot on a circle of `radius` round `object`, facing it, `stops` frames.
    fn circle(object: Vector3<f64>, radius: f64, stops: usize) -> Vec<Iso3> {
        (0..stops)
            .map(|k| {
                let a = 0.5 * k as f64;
                let (x, y) = (object.x + radius * a.cos(), object.y + radius * a.sin());
                iso_from_xy_yaw(x, y, a + std::f64::consts::PI)
            })
            .collect()
    }

    /// Frames seeing `object` exactly from the `truth` poses, whose /odom drifted by
    /// `drift` per frame (a heading error growing along the tour).
    fn frames(truth: &[Iso3], object: Vector3<f64>, drift: f64, cov: f64) -> Vec<SmoothFrame> {
        let mount = camera_mount([0.0, 0.0, 0.5], 0.2);
        let mut odo = Vec::new();
        for (k, t) in truth.iter().enumerate() {
            let e = Vector3::new(
                -drift * k as f64,
                0.5 * drift * k as f64,
                0.3 * drift * k as f64,
            );
            odo.push(corrected(t, &(-e)));
        }
        truth
            .iter()
            .zip(&odo)
            .map(|(t, o)| {
                let p = project(&camera(), &(t * mount).inverse(), &object).unwrap();
                SmoothFrame {
                    odometry: *o,
                    mount,
                    clusters: vec![[p[0], p[1]]],
                    start: Vector3::zeros(),
                    link_cov: Matrix3::from_diagonal(&Vector3::new(cov, cov, cov)),
                    floor_placed: false,
                }
            })
            .collect()
    }

    /// /odom drifts (a heading error growing along the tour) while every detection is exact:
    /// the smoother cannot know the drift exactly (frames moved round the object, each still
    /// facing it, cost only odometry, which is what drifted), but the object must come back
    /// and the frames closer than /odom. Measured: the object 0.020 m off (the filter's start
    /// 0.102 m), the frames 0.087 m off on average (/odom 0.117 m).
    #[test]
    fn a_drifted_circle_is_pulled_back_onto_its_object() {
        let object = Vector3::new(1.0, 0.5, 0.6);
        let truth = circle(object, 1.6, 8);
        let f = frames(&truth, object, 0.03, 0.03f64.powi(2));
        let start = object + Vector3::new(0.08, -0.06, 0.02);
        let s = smooth(&f, &[start], &camera(), false).unwrap();
        assert_eq!(s.observations, 8);
        assert!(s.cost[1] < 0.5 * s.cost[0], "{:?}", s.cost);
        let miss = (s.objects_m[0] - object).norm();
        assert!(miss < 0.03, "object {miss} m off");
        assert_eq!(s.corrections[0], Vector3::zeros());
        let mean = |poses: &mut dyn Iterator<Item = Iso3>| {
            poses
                .zip(&truth)
                .map(|(p, t)| (p.translation.vector - t.translation.vector).norm())
                .sum::<f64>()
                / truth.len() as f64
        };
        let odom = mean(&mut f.iter().map(|fr| fr.odometry));
        let smoothed = mean(
            &mut f
                .iter()
                .zip(&s.corrections)
                .map(|(fr, e)| corrected(&fr.odometry, e)),
        );
        assert!(
            smoothed < 0.85 * odom,
            "frames {smoothed} m off on average, /odom {odom} m"
        );
    }

    /// A robot that turns 3 % more than its odometry says (a track-width error), detections
    /// exact, 12 stops: the smoother reads most of the turn scale from the detections and
    /// puts the object back. Measured: turn scale 0.025, speed scale 0.006, the object 0.019 m
    /// off (the filter's start 0.10 m). Not all of it: with one object and frame 0 fixed, a
    /// tour a little larger or smaller about frame 0's camera fits the detections nearly as
    /// well, and the scales' prior pulls towards none.
    #[test]
    fn a_turn_bias_is_read_as_the_odometry_scale() {
        let object = Vector3::new(1.0, 0.5, 0.6);
        let truth = circle(object, 1.6, 12);
        let mut f = frames(&truth, object, 0.0, 0.005f64.powi(2));
        // Dead reckoning from frame 0 with each true turn read 1/1.03 of its size.
        let mut odo = truth[0];
        for k in 1..truth.len() {
            let rel = truth[k - 1].inverse() * truth[k];
            let (t, yaw) = (rel.translation.vector, yaw_of(&rel));
            odo *= iso_from_xy_yaw(t.x, t.y, yaw / 1.03);
            f[k].odometry = odo;
        }
        let start = object + Vector3::new(0.08, -0.06, 0.0);
        let s = smooth(&f, &[start], &camera(), true).unwrap();
        assert!(
            (0.02..0.035).contains(&s.calibration.y),
            "{:?}",
            s.calibration
        );
        assert!(s.calibration.x.abs() < 0.01, "{:?}", s.calibration);
        let miss = (s.objects_m[0] - object).norm();
        assert!(miss < 0.025, "object {miss} m off");
    }

    #[test]
    fn exact_odometry_and_exact_detections_stay_where_they_are() {
        let object = Vector3::new(-0.5, 2.0, 0.4);
        let truth = circle(object, 2.0, 6);
        let f = frames(&truth, object, 0.0, 0.01f64.powi(2));
        let s = smooth(&f, &[object], &camera(), false).unwrap();
        assert!(s.cost[0] < 1e-12 && s.cost[1] < 1e-12, "{:?}", s.cost);
        for e in &s.corrections {
            assert!(e.norm() < 1e-9, "{e:?}");
        }
    }

    #[test]
    fn a_floor_placed_frame_keeps_its_correction() {
        let object = Vector3::new(1.0, 0.5, 0.6);
        let truth = circle(object, 1.6, 5);
        let mut f = frames(&truth, object, 0.0, 0.05f64.powi(2));
        // Frame 2 says the floor put it 5 cm off where its detection puts it.
        f[2].floor_placed = true;
        f[2].start = Vector3::new(0.05, 0.0, 0.0);
        let s = smooth(&f, &[object], &camera(), false).unwrap();
        assert!(
            (s.corrections[2].x - 0.05).abs() < 0.01,
            "{:?}",
            s.corrections[2]
        );
        // The others are held by their detections and the links.
        assert!(s.corrections[4].norm() < 0.05, "{:?}", s.corrections[4]);
    }

    #[test]
    fn too_little_to_smooth() {
        let object = Vector3::new(1.0, 0.5, 0.6);
        let f = frames(&circle(object, 1.6, 1), object, 0.0, 1e-4);
        assert!(smooth(&f, &[object], &camera(), false).is_none());
        let f = frames(&circle(object, 1.6, 3), object, 0.0, 1e-4);
        assert!(smooth(&f, &[], &camera(), false).is_none());
    }

    #[test]
    fn carrying_a_heading_error_turns_the_displacement() {
        let e = carried(
            &Vector3::new(0.1, 0.0, std::f64::consts::FRAC_PI_2),
            &Vector2::new(1.0, 0.0),
        );
        assert!((e - Vector3::new(0.1 - 1.0, 1.0, std::f64::consts::FRAC_PI_2)).norm() < 1e-12);
    }
}
