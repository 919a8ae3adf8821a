//! CPU ray caster for scenes: yawed boxes, vertical cylinders, spheres inside a room; Lambert
//! shading with one directional light, an ambient term and cast shadows; procedural textures;
//! per-frame exposure and white-balance jitter and per-pixel sensor noise.
//!
//! Invariants: every pixel is a pure function of (scene, camera pose, [`FrameJitter`], pixel
//! index): rows are rendered in parallel but share no state and no random stream, so the
//! output is bit-identical for any number of threads. The object-id buffer records which
//! named object instance the primary ray hit, so labels come from visible pixels only.

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use super::scene::{Material, Primitive, Scene, Shape, Texture};
use crate::types::geometry::{Camera, Iso3};
use crate::types::lens::{Distortion, undistorted_pixel};

/// Rays start this far off a surface so they do not hit it again.
const SURFACE_EPS_M: f64 = 1e-6;
/// Standard deviation of the per-pixel sensor noise, in display levels of 255.
const SENSOR_NOISE_LEVELS: f64 = 1.6;

/// Per-frame camera response: exposure gain, white-balance gains and the noise seed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameJitter {
    /// Gain on linear radiance, all channels (1 = neutral).
    pub exposure: f64,
    /// Further gains on linear radiance per channel (r, g, b); 1 = neutral.
    pub white_balance: [f64; 3],
    /// Seed of the frame's per-pixel sensor noise.
    pub noise_seed: u64,
}

impl FrameJitter {
    /// Unit gains and noise seed 0 (the sensor noise is still added, from that seed).
    pub const NEUTRAL: FrameJitter = FrameJitter {
        exposure: 1.0,
        white_balance: [1.0; 3],
        noise_seed: 0,
    };
}

/// A rendered frame: RGB8 row-major, and per pixel the id of the object instance hit
/// (0 = none, otherwise an index + 1 into [`Renderer::instances`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Rendered {
    /// Image width, pixels (the scene camera's).
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Pixels, row-major, R G B per pixel; `len() == width * height * 3`.
    pub rgb: Vec<u8>,
    /// Per pixel, row-major: the instance id the primary ray hit (0 = none).
    pub ids: Vec<u16>,
}

/// A named object instance of the scene.
#[derive(Debug, Clone, PartialEq)]
pub struct Instance {
    /// Name of the object (the primitives' `object`).
    pub object: String,
    /// Which copy of the object (the primitives' `instance`).
    pub instance: u32,
}

#[derive(Debug, Clone, Copy)]
enum Prim {
    /// World-from-local is rotation by yaw about z then translation to `center`.
    Box {
        center: Vector3<f64>,
        half: Vector3<f64>,
        cos_yaw: f64,
        sin_yaw: f64,
    },
    Cylinder {
        base: Vector3<f64>,
        radius: f64,
        height: f64,
    },
    Sphere {
        center: Vector3<f64>,
        radius: f64,
    },
}

#[derive(Debug, Clone, Copy)]
struct Surface {
    /// Linear albedo.
    albedo: [f64; 3],
    texture: Texture,
}

#[derive(Debug, Clone, Copy)]
struct Item {
    prim: Prim,
    surface: Surface,
    /// 0 = not part of a named object.
    id: u16,
}

/// Items culled together by one bounding sphere.
#[derive(Debug, Clone)]
struct Group {
    center: Vector3<f64>,
    radius: f64,
    items: Vec<Item>,
}

struct Hit {
    t: f64,
    normal: Vector3<f64>,
    /// Point in the primitive's own frame, for textures that follow the object.
    local: Vector3<f64>,
    surface: Surface,
    id: u16,
}

/// A scene prepared for rendering: world-space primitives, culling groups, linear colours.
#[derive(Debug, Clone)]
pub struct Renderer {
    camera: Camera,
    /// The lens: each pixel of the distorted image traces the ray of its undistorted point.
    distortion: Option<Distortion>,
    groups: Vec<Group>,
    room_half: Vector3<f64>,
    room_height: f64,
    floor: Surface,
    ceiling: Surface,
    walls: [Surface; 4],
    light_dir: Vector3<f64>,
    light_intensity: f64,
    ambient: f64,
    instances: Vec<Instance>,
}

fn surface(m: &Material) -> Surface {
    // Scene colours are display values; shading happens in (gamma 2) linear light.
    Surface {
        albedo: m.color.map(|c| c * c),
        texture: m.texture,
    }
}

fn v3(a: [f64; 3]) -> Vector3<f64> {
    Vector3::new(a[0], a[1], a[2])
}

impl Renderer {
    /// Prepares `scene`; primitives of `exclude_object` are left out (background frames).
    pub fn new(scene: &Scene, exclude_object: Option<&str>) -> Self {
        let c = &scene.camera;
        let camera = Camera::with_hfov(c.width, c.height, c.hfov_deg.to_radians());
        let mut instances: Vec<Instance> = Vec::new();
        // Group key -> group index, in first-appearance order so the layout is deterministic.
        let mut keys: Vec<String> = Vec::new();
        let mut groups: Vec<Vec<Item>> = Vec::new();
        for (i, p) in scene.primitives.iter().enumerate() {
            if exclude_object.is_some() && p.object.as_deref() == exclude_object {
                continue;
            }
            let item = Item {
                prim: prim_of(&p.shape),
                surface: surface(&p.material),
                id: instance_id(&mut instances, p),
            };
            let key = group_key(p, i);
            match keys.iter().position(|k| *k == key) {
                Some(g) => groups[g].push(item),
                None => {
                    keys.push(key);
                    groups.push(vec![item]);
                }
            }
        }
        let r = &scene.room;
        Self {
            camera,
            groups: groups.into_iter().map(bounded_group).collect(),
            room_half: Vector3::new(r.size_m[0] * 0.5, r.size_m[1] * 0.5, 0.0),
            room_height: r.size_m[2],
            floor: surface(&r.floor),
            ceiling: surface(&r.ceiling),
            walls: [
                surface(&r.walls[0]),
                surface(&r.walls[1]),
                surface(&r.walls[2]),
                surface(&r.walls[3]),
            ],
            light_dir: v3(scene.light.direction).normalize(),
            light_intensity: scene.light.intensity,
            ambient: scene.light.ambient,
            instances,
            distortion: c.distortion.filter(|d| !d.is_zero()),
        }
    }

    /// The lens distortion of the renders, if the scene's camera has one.
    pub fn distortion(&self) -> Option<&Distortion> {
        self.distortion.as_ref()
    }

    /// The pinhole camera of the scene's camera spec (fx = fy, principal point at the centre),
    /// before any lens distortion.
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// Named object instances; id `k` in [`Rendered::ids`] is `instances()[k - 1]`.
    pub fn instances(&self) -> &[Instance] {
        &self.instances
    }

    /// Renders the view of a camera at `odom_from_optical`.
    pub fn render(&self, odom_from_optical: &Iso3, jitter: &FrameJitter) -> Rendered {
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        let origin = odom_from_optical.translation.vector;
        let rot = odom_from_optical.rotation;
        let mut rgb = vec![0u8; w * h * 3];
        let mut ids = vec![0u16; w * h];
        let gains = [0, 1, 2].map(|c| jitter.exposure * jitter.white_balance[c]);
        rgb.par_chunks_mut(w * 3)
            .zip(ids.par_chunks_mut(w))
            .enumerate()
            .for_each(|(y, (row_rgb, row_ids))| {
                for x in 0..w {
                    let (u, v) = (x as f64 + 0.5, y as f64 + 0.5);
                    let (u, v) = match &self.distortion {
                        Some(d) => undistorted_pixel(&self.camera, d, u, v),
                        None => (u, v),
                    };
                    let dir = rot * self.camera.ray(u, v);
                    let (radiance, id) = self.shade(&origin, &dir);
                    row_ids[x] = id;
                    let pixel = (y * w + x) as u64;
                    for c in 0..3 {
                        let display = (radiance[c] * gains[c]).max(0.0).sqrt() * 255.0;
                        let noise = gaussian_hash(jitter.noise_seed, pixel * 3 + c as u64);
                        let v = display + noise * SENSOR_NOISE_LEVELS;
                        row_rgb[x * 3 + c] = v.round().clamp(0.0, 255.0) as u8;
                    }
                }
            });
        Rendered {
            width: self.camera.width,
            height: self.camera.height,
            rgb,
            ids,
        }
    }

    fn shade(&self, origin: &Vector3<f64>, dir: &Vector3<f64>) -> ([f64; 3], u16) {
        let hit = self.closest_object(origin, dir, f64::INFINITY);
        let hit = match hit {
            Some(h) => h,
            None => match self.room_hit(origin, dir) {
                Some(h) => h,
                None => return ([0.0; 3], 0),
            },
        };
        let p = origin + dir * hit.t;
        // Surfaces seen from behind (inside a primitive) shade like their front.
        let n = if hit.normal.dot(dir) > 0.0 {
            -hit.normal
        } else {
            hit.normal
        };
        let cos = n.dot(&self.light_dir);
        let mut direct = 0.0;
        if cos > 0.0 {
            let start = p + n * 1e-4;
            if !self.occluded(&start, &self.light_dir) {
                direct = self.light_intensity * cos;
            }
        }
        let tex = texture_factor(&hit.surface.texture, &hit.local);
        let light = (self.ambient + direct) * tex;
        (hit.surface.albedo.map(|a| a * light), hit.id)
    }

    fn closest_object(&self, o: &Vector3<f64>, d: &Vector3<f64>, t_max: f64) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut best_t = t_max;
        for g in &self.groups {
            if !sphere_may_hit(o, d, &g.center, g.radius, best_t) {
                continue;
            }
            for it in &g.items {
                if let Some((t, normal, local)) = intersect(&it.prim, o, d, best_t) {
                    best_t = t;
                    best = Some(Hit {
                        t,
                        normal,
                        local,
                        surface: it.surface,
                        id: it.id,
                    });
                }
            }
        }
        best
    }

    fn occluded(&self, o: &Vector3<f64>, d: &Vector3<f64>) -> bool {
        self.groups.iter().any(|g| {
            sphere_may_hit(o, d, &g.center, g.radius, f64::INFINITY)
                && g.items
                    .iter()
                    .any(|it| intersect(&it.prim, o, d, f64::INFINITY).is_some())
        })
    }

    /// The room seen from inside: the nearest of the six planes the ray leaves through.
    fn room_hit(&self, o: &Vector3<f64>, d: &Vector3<f64>) -> Option<Hit> {
        let mut best: Option<(f64, usize)> = None;
        let bounds = [
            (0, -self.room_half.x, 0usize),
            (0, self.room_half.x, 1),
            (1, -self.room_half.y, 2),
            (1, self.room_half.y, 3),
            (2, 0.0, 4),
            (2, self.room_height, 5),
        ];
        for (axis, plane, face) in bounds {
            if d[axis].abs() < 1e-12 {
                continue;
            }
            let t = (plane - o[axis]) / d[axis];
            if t > SURFACE_EPS_M && best.is_none_or(|(bt, _)| t < bt) {
                best = Some((t, face));
            }
        }
        let (t, face) = best?;
        let mut normal = Vector3::zeros();
        let axis = face / 2;
        normal[axis] = if face % 2 == 0 { 1.0 } else { -1.0 };
        let surface = match face {
            4 => self.floor,
            5 => self.ceiling,
            f => self.walls[f],
        };
        Some(Hit {
            t,
            normal,
            local: o + d * t,
            surface,
            id: 0,
        })
    }
}

/// The object-id of primitive `p` (0 when it belongs to no named object), adding its
/// instance to `instances` when it is the first of it.
fn instance_id(instances: &mut Vec<Instance>, p: &Primitive) -> u16 {
    let Some(o) = &p.object else {
        return 0;
    };
    let inst = Instance {
        object: o.clone(),
        instance: p.instance,
    };
    let idx = match instances.iter().position(|x| *x == inst) {
        Some(idx) => idx,
        None => {
            instances.push(inst);
            instances.len() - 1
        }
    };
    u16::try_from(idx + 1).unwrap_or(u16::MAX)
}

/// The culling group of primitive `i`: its object instance, else its named group, else
/// its own.
fn group_key(p: &Primitive, i: usize) -> String {
    match (&p.object, &p.group) {
        (Some(o), _) => format!("object {o} {}", p.instance),
        (None, Some(g)) => format!("group {g}"),
        (None, None) => format!("primitive {i}"),
    }
}

/// A scene shape as the renderer's world-space primitive.
fn prim_of(shape: &Shape) -> Prim {
    match *shape {
        Shape::Box {
            center_m,
            size_m,
            yaw_deg,
        } => {
            let yaw = yaw_deg.to_radians();
            Prim::Box {
                center: v3(center_m),
                half: v3(size_m) * 0.5,
                cos_yaw: yaw.cos(),
                sin_yaw: yaw.sin(),
            }
        }
        Shape::Cylinder {
            base_center_m,
            radius_m,
            height_m,
        } => Prim::Cylinder {
            base: v3(base_center_m),
            radius: radius_m,
            height: height_m,
        },
        Shape::Sphere { center_m, radius_m } => Prim::Sphere {
            center: v3(center_m),
            radius: radius_m,
        },
    }
}

/// A culling group of `items` with the bounding sphere of their bounding boxes.
fn bounded_group(items: Vec<Item>) -> Group {
    let (lo, hi) = items.iter().fold(
        (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        ),
        |(lo, hi), it| {
            let (a, b) = prim_aabb(&it.prim);
            (lo.inf(&a), hi.sup(&b))
        },
    );
    let center = (lo + hi) * 0.5;
    Group {
        center,
        radius: (hi - lo).norm() * 0.5 + 1e-6,
        items,
    }
}

fn prim_aabb(p: &Prim) -> (Vector3<f64>, Vector3<f64>) {
    match *p {
        Prim::Box {
            center,
            half,
            cos_yaw,
            sin_yaw,
        } => {
            let ex = (cos_yaw * half.x).abs() + (sin_yaw * half.y).abs();
            let ey = (sin_yaw * half.x).abs() + (cos_yaw * half.y).abs();
            let e = Vector3::new(ex, ey, half.z);
            (center - e, center + e)
        }
        Prim::Cylinder {
            base,
            radius,
            height,
        } => (
            base - Vector3::new(radius, radius, 0.0),
            base + Vector3::new(radius, radius, height),
        ),
        Prim::Sphere { center, radius } => (
            center - Vector3::repeat(radius),
            center + Vector3::repeat(radius),
        ),
    }
}

/// Bounding box of a primitive in a frame yawed by `yaw` about z (for ground-truth boxes).
pub fn shape_extent_in_yaw(shape: &Shape, yaw: f64) -> (Vector3<f64>, Vector3<f64>) {
    let (c, s) = (yaw.cos(), yaw.sin());
    // frame-from-world rotation by -yaw
    let to_frame = |p: Vector3<f64>| Vector3::new(c * p.x + s * p.y, -s * p.x + c * p.y, p.z);
    match *shape {
        Shape::Box {
            center_m,
            size_m,
            yaw_deg,
        } => {
            let (bc, bs) = (yaw_deg.to_radians().cos(), yaw_deg.to_radians().sin());
            let h = v3(size_m) * 0.5;
            let mut lo = Vector3::repeat(f64::INFINITY);
            let mut hi = Vector3::repeat(f64::NEG_INFINITY);
            for sx in [-1.0, 1.0] {
                for sy in [-1.0, 1.0] {
                    for sz in [-1.0, 1.0] {
                        let (lx, ly) = (sx * h.x, sy * h.y);
                        let world = v3(center_m)
                            + Vector3::new(bc * lx - bs * ly, bs * lx + bc * ly, sz * h.z);
                        let f = to_frame(world);
                        lo = lo.inf(&f);
                        hi = hi.sup(&f);
                    }
                }
            }
            (lo, hi)
        }
        Shape::Cylinder {
            base_center_m,
            radius_m,
            height_m,
        } => {
            let b = to_frame(v3(base_center_m));
            (
                b - Vector3::new(radius_m, radius_m, 0.0),
                b + Vector3::new(radius_m, radius_m, height_m),
            )
        }
        Shape::Sphere { center_m, radius_m } => {
            let cf = to_frame(v3(center_m));
            (
                cf - Vector3::repeat(radius_m),
                cf + Vector3::repeat(radius_m),
            )
        }
    }
}

#[inline]
fn sphere_may_hit(
    o: &Vector3<f64>,
    d: &Vector3<f64>,
    c: &Vector3<f64>,
    r: f64,
    t_max: f64,
) -> bool {
    let oc = c - o;
    let tc = oc.dot(d);
    let dist2 = oc.norm_squared() - tc * tc;
    if dist2 > r * r {
        return false;
    }
    // Sphere wholly behind the origin or beyond the current best hit.
    tc + r > 0.0 && tc - r < t_max
}

/// A ray as the intersection tests take it: origin, unit direction, and the distance
/// beyond which hits do not count.
#[derive(Clone, Copy)]
struct Ray<'a> {
    o: &'a Vector3<f64>,
    d: &'a Vector3<f64>,
    t_max: f64,
}

/// (t, outward normal, point in the primitive's own frame) of a ray hit.
type Crossing = (f64, Vector3<f64>, Vector3<f64>);

/// Nearest intersection with t in (eps, t_max): (t, outward normal, local point).
#[inline]
fn intersect(p: &Prim, o: &Vector3<f64>, d: &Vector3<f64>, t_max: f64) -> Option<Crossing> {
    let ray = Ray { o, d, t_max };
    match *p {
        Prim::Box {
            center,
            half,
            cos_yaw,
            sin_yaw,
        } => intersect_box(&center, &half, (cos_yaw, sin_yaw), ray),
        Prim::Sphere { center, radius } => intersect_sphere(&center, radius, ray),
        Prim::Cylinder {
            base,
            radius,
            height,
        } => intersect_cylinder(&base, radius, height, ray),
    }
}

/// Nearest hit of a box of half extents `half` at `center`, yawed by the angle whose
/// (cosine, sine) is `yaw`.
#[inline]
fn intersect_box(
    center: &Vector3<f64>,
    half: &Vector3<f64>,
    (cos_yaw, sin_yaw): (f64, f64),
    ray: Ray,
) -> Option<Crossing> {
    let Ray { o, d, t_max } = ray;
    let rel = o - center;
    // local-from-world: rotate by -yaw
    let lo = Vector3::new(
        cos_yaw * rel.x + sin_yaw * rel.y,
        -sin_yaw * rel.x + cos_yaw * rel.y,
        rel.z,
    );
    let ld = Vector3::new(
        cos_yaw * d.x + sin_yaw * d.y,
        -sin_yaw * d.x + cos_yaw * d.y,
        d.z,
    );
    let mut t_near = f64::NEG_INFINITY;
    let mut t_far = f64::INFINITY;
    let mut axis_near = 0;
    let mut sign_near = 0.0;
    for a in 0..3 {
        if ld[a].abs() < 1e-15 {
            if lo[a].abs() > half[a] {
                return None;
            }
            continue;
        }
        let inv = 1.0 / ld[a];
        let t1 = (-half[a] - lo[a]) * inv;
        let t2 = (half[a] - lo[a]) * inv;
        let (ta, tb, s) = if t1 < t2 {
            (t1, t2, -1.0)
        } else {
            (t2, t1, 1.0)
        };
        if ta > t_near {
            t_near = ta;
            axis_near = a;
            sign_near = s;
        }
        t_far = t_far.min(tb);
    }
    if t_near > t_far || t_near <= SURFACE_EPS_M || t_near >= t_max {
        return None;
    }
    let mut ln = Vector3::zeros();
    ln[axis_near] = sign_near;
    let normal = Vector3::new(
        cos_yaw * ln.x - sin_yaw * ln.y,
        sin_yaw * ln.x + cos_yaw * ln.y,
        ln.z,
    );
    Some((t_near, normal, lo + ld * t_near))
}

/// Nearest hit of a sphere (from outside, or from inside on its far side).
#[inline]
fn intersect_sphere(center: &Vector3<f64>, radius: f64, ray: Ray) -> Option<Crossing> {
    let Ray { o, d, t_max } = ray;
    let oc = o - center;
    let b = oc.dot(d);
    let c = oc.norm_squared() - radius * radius;
    let disc = b * b - c;
    if disc < 0.0 {
        return None;
    }
    let sq = disc.sqrt();
    let t = if -b - sq > SURFACE_EPS_M {
        -b - sq
    } else {
        -b + sq
    };
    if t <= SURFACE_EPS_M || t >= t_max {
        return None;
    }
    let local = oc + d * t;
    Some((t, local / radius, local))
}

/// Nearest hit of a vertical cylinder standing on `base`: its side or one of its caps.
#[inline]
fn intersect_cylinder(base: &Vector3<f64>, radius: f64, height: f64, ray: Ray) -> Option<Crossing> {
    let Ray { o, d, t_max } = ray;
    let rel = o - base;
    let mut best: Option<(f64, Vector3<f64>)> = None;
    // Side: |(rel + d t).xy| = radius.
    let a = d.x * d.x + d.y * d.y;
    if a > 1e-15 {
        let b = rel.x * d.x + rel.y * d.y;
        let c = rel.x * rel.x + rel.y * rel.y - radius * radius;
        let disc = b * b - a * c;
        if disc >= 0.0 {
            let sq = disc.sqrt();
            for t in [(-b - sq) / a, (-b + sq) / a] {
                let z = rel.z + d.z * t;
                if t > SURFACE_EPS_M && t < t_max && (0.0..=height).contains(&z) {
                    let q = rel + d * t;
                    best = Some((t, Vector3::new(q.x, q.y, 0.0) / radius));
                    break;
                }
            }
        }
    }
    // Caps.
    if d.z.abs() > 1e-15 {
        for (zc, nz) in [(0.0, -1.0), (height, 1.0)] {
            let t = (zc - rel.z) / d.z;
            let limit = best.map_or(t_max, |(bt, _)| bt);
            if t > SURFACE_EPS_M && t < limit {
                let q = rel + d * t;
                if q.x * q.x + q.y * q.y <= radius * radius {
                    best = Some((t, Vector3::new(0.0, 0.0, nz)));
                }
            }
        }
    }
    best.map(|(t, n)| (t, n, rel + d * t))
}

/// Brightness factor of a texture at a local point (1 = plain albedo).
fn texture_factor(t: &Texture, p: &Vector3<f64>) -> f64 {
    match *t {
        Texture::Flat => 1.0,
        Texture::Noise { scale_m, amount } => {
            let q = p / scale_m;
            let n =
                0.65 * value_noise(&q) + 0.35 * value_noise(&(q * 2.03 + Vector3::repeat(17.1)));
            1.0 + amount * (2.0 * n - 1.0)
        }
        Texture::Stripes {
            period_m,
            axis,
            amount,
        } => {
            let s = (p[usize::from(axis.min(2))] / period_m).rem_euclid(1.0);
            if s < 0.5 { 1.0 } else { 1.0 - amount }
        }
        Texture::Wood {
            ring_period_m,
            amount,
        } => {
            // Rings around the local y axis, stretched along it like planks, warped by noise.
            let warp = value_noise(&Vector3::new(p.x * 4.0, p.y * 0.7, p.z * 4.0));
            let r = (p.x * p.x + p.z * p.z).sqrt() / ring_period_m + 3.0 * warp;
            let ring = r.rem_euclid(1.0);
            // A sharp dark late-wood band in each ring.
            let band = if ring < 0.25 { 1.0 - ring * 4.0 } else { 0.0 };
            1.0 - amount * (0.35 * warp + 0.65 * band)
        }
        Texture::Checker { period_m, amount } => {
            let a = (p.x / period_m).rem_euclid(1.0) < 0.5;
            let b = (p.y / period_m).rem_euclid(1.0) < 0.5;
            if a == b { 1.0 } else { 1.0 - amount }
        }
        Texture::Rings { period_m, amount } => {
            let r = (p.x * p.x + p.y * p.y).sqrt() / period_m;
            if r.rem_euclid(1.0) < 0.5 {
                1.0
            } else {
                1.0 - amount
            }
        }
    }
}

#[inline]
fn hash_u64(mut x: u64) -> u64 {
    // SplitMix64 finaliser: cheap, well mixed, and the same on every platform.
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

#[inline]
fn lattice(ix: i64, iy: i64, iz: i64) -> f64 {
    let h = hash_u64(
        (ix as u64).wrapping_mul(0x8DA6_B343)
            ^ (iy as u64).wrapping_mul(0xD816_3841)
            ^ (iz as u64).wrapping_mul(0xCB1A_B31F),
    );
    (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// Smooth value noise in [0, 1] on the integer lattice.
fn value_noise(p: &Vector3<f64>) -> f64 {
    let f = p.map(f64::floor);
    let (ix, iy, iz) = (f.x as i64, f.y as i64, f.z as i64);
    let s = (p - f).map(|t| t * t * (3.0 - 2.0 * t));
    let mut acc = 0.0;
    for dz in 0..2 {
        for dy in 0..2 {
            for dx in 0..2 {
                let w = (if dx == 1 { s.x } else { 1.0 - s.x })
                    * (if dy == 1 { s.y } else { 1.0 - s.y })
                    * (if dz == 1 { s.z } else { 1.0 - s.z });
                acc += w * lattice(ix + dx, iy + dy, iz + dz);
            }
        }
    }
    acc
}

/// Approximately standard normal (Irwin-Hall of four uniforms), keyed by (seed, index).
#[inline]
fn gaussian_hash(seed: u64, index: u64) -> f64 {
    let h = hash_u64(seed ^ hash_u64(index));
    let sum: f64 = (0..4)
        .map(|k| ((h >> (k * 16)) & 0xFFFF) as f64 / 65535.0)
        .sum();
    // Sum of 4 U(0,1): mean 2, variance 4/12.
    (sum - 2.0) * (3.0f64).sqrt()
}

/// Projected point helper for tests and labels: continuous pixel of a world point.
pub fn project_world(
    camera: &Camera,
    odom_from_optical: &Iso3,
    p: &Point3<f64>,
) -> Option<(f64, f64)> {
    camera.project(&(odom_from_optical.inverse() * p))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-9
    }

    #[test]
    fn yawed_box_hit_distance_and_normal() {
        // Unit cube yawed 45 degrees at the origin: its corner points at -x, 1/sqrt2 from centre.
        let yaw = std::f64::consts::FRAC_PI_4;
        let p = Prim::Box {
            center: Vector3::zeros(),
            half: Vector3::repeat(0.5),
            cos_yaw: yaw.cos(),
            sin_yaw: yaw.sin(),
        };
        let o = Vector3::new(-3.0, 0.0, 0.0);
        let (t, n, _) = intersect(&p, &o, &Vector3::x(), f64::INFINITY).unwrap();
        assert!(close(t, 3.0 - 0.5f64.sqrt()), "{t}");
        // Hits the edge between two faces: either face normal has x = -1/sqrt2.
        assert!(close(n.x, -(0.5f64).sqrt()), "{n}");
        // Slightly off the edge, at y = 0.1: face with normal (-1, -1)/sqrt2... t = 3 - (0.7071 - 0.1).
        let o2 = Vector3::new(-3.0, 0.1, 0.0);
        let (t2, _, _) = intersect(&p, &o2, &Vector3::x(), f64::INFINITY).unwrap();
        assert!(close(t2, 3.0 - (0.5f64.sqrt() - 0.1)), "{t2}");
        assert!(intersect(&p, &o, &Vector3::x(), 2.0).is_none());
    }

    #[test]
    fn cylinder_side_and_cap() {
        let p = Prim::Cylinder {
            base: Vector3::new(0.0, 0.0, 1.0),
            radius: 0.5,
            height: 2.0,
        };
        let (t, n, _) = intersect(
            &p,
            &Vector3::new(-2.0, 0.0, 2.0),
            &Vector3::x(),
            f64::INFINITY,
        )
        .unwrap();
        assert!(close(t, 1.5) && close(n.x, -1.0));
        let (t, n, _) = intersect(
            &p,
            &Vector3::new(0.1, 0.0, 5.0),
            &-Vector3::z(),
            f64::INFINITY,
        )
        .unwrap();
        assert!(close(t, 2.0) && close(n.z, 1.0));
        // Passes above the top.
        assert!(
            intersect(
                &p,
                &Vector3::new(-2.0, 0.0, 3.5),
                &Vector3::x(),
                f64::INFINITY
            )
            .is_none()
        );
    }

    #[test]
    fn sphere_hit() {
        let p = Prim::Sphere {
            center: Vector3::new(0.0, 0.0, 5.0),
            radius: 1.0,
        };
        let (t, n, _) = intersect(&p, &Vector3::zeros(), &Vector3::z(), f64::INFINITY).unwrap();
        assert!(close(t, 4.0) && close(n.z, -1.0));
    }

    #[test]
    fn gaussian_hash_has_unit_variance() {
        let n = 20000u64;
        let xs: Vec<f64> = (0..n).map(|i| gaussian_hash(7, i)).collect();
        let mean = xs.iter().sum::<f64>() / n as f64;
        let var = xs.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n as f64;
        assert!(
            mean.abs() < 0.03 && (var - 1.0).abs() < 0.05,
            "{mean} {var}"
        );
    }

    #[test]
    fn yawed_extent_of_box() {
        // A 2 x 1 box yawed 90 degrees, measured in the world frame: 1 wide in x, 2 in y.
        let s = Shape::Box {
            center_m: [1.0, 2.0, 0.5],
            size_m: [2.0, 1.0, 1.0],
            yaw_deg: 90.0,
        };
        let (lo, hi) = shape_extent_in_yaw(&s, 0.0);
        assert!(close(hi.x - lo.x, 1.0) && close(hi.y - lo.y, 2.0) && close(lo.z, 0.0));
        // In its own yaw it is 2 x 1 again.
        let (lo, hi) = shape_extent_in_yaw(&s, std::f64::consts::FRAC_PI_2);
        assert!(close(hi.x - lo.x, 2.0) && close(hi.y - lo.y, 1.0));
    }
}
