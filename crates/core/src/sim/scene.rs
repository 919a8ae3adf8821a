//! Scene files: the room, lights, camera mount, primitives (with the object each belongs to)
//! and the robot's path, as JSON (schema in `schemas/scene.md`).
//!
//! Invariants: a [`Scene`] that passed [`Scene::validate`] has finite, positive sizes, colours
//! in [0, 1], and at least one primitive of its `target` object, so the renderer and the path
//! planner never meet a degenerate value. Unknown JSON fields are errors (typos do not pass
//! silently).

use serde::{Deserialize, Serialize};

/// Built-in scene names, in the order `objloc record sim --help` lists them.
pub const BUILTIN_SCENES: [&str; 3] = ["chair", "bottle", "two-chairs"];

/// A built-in scene by name, or `None`.
pub fn builtin_json(name: &str) -> Option<&'static str> {
    match name {
        "chair" => Some(include_str!("scenes/chair.json")),
        "bottle" => Some(include_str!("scenes/bottle.json")),
        "two-chairs" => Some(include_str!("scenes/two-chairs.json")),
        _ => None,
    }
}

/// A scene file: room, light, camera, robot, primitives and path (`schemas/scene.md`); lengths
/// metres, angles degrees, colours display RGB in [0, 1], coordinates in `odom`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// Scene name, used in messages.
    pub name: String,
    /// The object that train sessions label and remove for background frames.
    pub target: String,
    /// The room around everything: its size and surface materials.
    pub room: Room,
    /// The directional light and the ambient term.
    pub light: Light,
    /// The camera: image size, field of view and mount on the robot.
    pub camera: CameraSpec,
    /// The robot's nominal command speeds.
    pub robot: RobotSpec,
    /// Every shape in the room, of the named objects and of the furniture.
    pub primitives: Vec<Primitive>,
    /// Where the robot goes in train and tour sessions.
    pub path: PathSpec,
}

/// An axis-aligned room centred on the odom origin in x and y, floor at z = 0.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Room {
    /// Full extents [x, y, z] in metres.
    pub size_m: [f64; 3],
    /// Material of the floor (z = 0); its texture is evaluated in `odom`.
    pub floor: Material,
    /// Material of the ceiling (z = `size_m[2]`).
    pub ceiling: Material,
    /// Walls at x min, x max, y min, y max.
    pub walls: [Material; 4],
}

/// The lighting: one directional light casting shadows, plus an ambient term.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Light {
    /// Direction from the scene towards the light (any length), in odom.
    pub direction: [f64; 3],
    /// Radiance scale of the directional light.
    pub intensity: f64,
    /// Radiance that reaches every surface, shadowed or not.
    pub ambient: f64,
}

/// The robot's camera: a pinhole with fx = fy, principal point at the image centre.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    /// Image width, pixels, 1 to 4096 (the built-ins use 256).
    pub width: u32,
    /// Image height, pixels, 1 to 4096 (the built-ins use 240).
    pub height: u32,
    /// Horizontal field of view, degrees, in (1, 170).
    pub hfov_deg: f64,
    /// Camera position in base_link.
    pub mount_m: [f64; 3],
    /// Downward pitch of the optical axis from base_link +x, degrees (it looks along +x at 0).
    pub pitch_down_deg: f64,
    /// A pan-tilt head that sweeps the camera while the robot moves (published on /tf); none:
    /// the camera is fixed (/tf_static only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pan_tilt: Option<PanTiltSpec>,
    /// Lens distortion of the rendered images (OpenCV radial-tangential, written as
    /// CameraInfo `d`); none: an ideal pinhole.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distortion: Option<crate::types::lens::Distortion>,
}

/// A pan-tilt head: pan about base_link z and tilt about its y, sinusoidal in time.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PanTiltSpec {
    /// Pan amplitude, degrees, in [0, 90): pan(t) = amplitude sin(2 pi t / period).
    pub pan_amplitude_deg: f64,
    /// Tilt amplitude, degrees, in [0, 45): tilt(t) = amplitude cos(2 pi t / period).
    pub tilt_amplitude_deg: f64,
    /// Period of the sweep, seconds (> 0).
    pub period_s: f64,
}

/// The robot's nominal speeds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotSpec {
    /// Nominal speed of drive commands, m/s (> 0).
    pub drive_speed_m_s: f64,
    /// Nominal speed of rotate commands, rad/s (> 0).
    pub turn_speed_rad_s: f64,
}

/// One shape of the scene with its material, and the named object it belongs to, if any.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Primitive {
    /// The named object this primitive is part of; `None` for furniture and clutter.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub object: Option<String>,
    /// Which copy of `object` (two identical chairs are instances 0 and 1).
    #[serde(default)]
    pub instance: u32,
    /// Primitives sharing a group are culled together (a table and its legs); named objects
    /// are grouped by (object, instance) regardless.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub group: Option<String>,
    /// Geometry and placement, in `odom`.
    pub shape: Shape,
    /// Colour and texture; the texture follows the primitive's own frame.
    pub material: Material,
}

/// A primitive's geometry in `odom` (JSON `kind`: box, cylinder or sphere).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Shape {
    /// A box rotated by `yaw_deg` about the vertical through its centre.
    Box {
        /// Centre of the box in `odom`, metres.
        center_m: [f64; 3],
        /// Full edge lengths along the box's own axes, metres (> 0).
        size_m: [f64; 3],
        /// Rotation about the vertical, degrees, counter-clockwise (default 0).
        #[serde(default)]
        yaw_deg: f64,
    },
    /// A vertical cylinder standing on `base_center_m`.
    Cylinder {
        /// Centre of the bottom face in `odom`, metres.
        base_center_m: [f64; 3],
        /// Radius, metres (> 0).
        radius_m: f64,
        /// Height above the base, metres (> 0).
        height_m: f64,
    },
    /// A sphere around `center_m`.
    Sphere {
        /// Centre in `odom`, metres.
        center_m: [f64; 3],
        /// Radius, metres (> 0).
        radius_m: f64,
    },
}

/// A surface's look: display colour times a procedural texture.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Material {
    /// Albedo as display RGB in [0, 1].
    pub color: [f64; 3],
    /// Albedo pattern over the surface (default flat).
    #[serde(default)]
    pub texture: Texture,
}

/// A procedural factor on the albedo (JSON `kind`), evaluated in the primitive's own frame
/// (the room's surfaces in `odom`).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Texture {
    /// Uniform: the colour as it is (the default).
    #[default]
    Flat,
    /// Two-octave value noise with feature size `scale_m`; albedo varies by +-`amount`.
    Noise {
        /// Feature size of the noise, metres (> 0).
        scale_m: f64,
        /// The albedo varies by a factor within 1 +- this.
        amount: f64,
    },
    /// Bands of width period/2 along `axis` (0 = x, 1 = y, 2 = z), darkened by `amount`.
    Stripes {
        /// Length of one light and one dark band together, metres (> 0).
        period_m: f64,
        /// Local axis along which the bands alternate: 0 = x, 1 = y, 2 = z.
        axis: u8,
        /// Darkening of the dark bands: their albedo is times (1 - amount).
        amount: f64,
    },
    /// Rings around the primitive's local vertical axis, warped by noise.
    Wood {
        /// Radial spacing of the rings, metres (> 0).
        ring_period_m: f64,
        /// Darkening of the late-wood bands and the grain, as a fraction of the albedo.
        amount: f64,
    },
    /// Squares of side period/2 in the local x-y plane, alternate ones darkened by `amount`.
    Checker {
        /// Side of a light and a dark square together, metres (> 0).
        period_m: f64,
        /// Darkening of the dark squares: their albedo is times (1 - amount).
        amount: f64,
    },
    /// Concentric bands of width period/2 about the local vertical axis (a round rug's
    /// bands, centred on the room for the room's floor), alternate ones darkened by `amount`.
    Rings {
        /// Radial width of a light and a dark band together, metres (> 0).
        period_m: f64,
        /// Darkening of the dark bands: their albedo is times (1 - amount).
        amount: f64,
    },
}

/// Where the robot goes. Bearings are measured in odom from +x, counter-clockwise.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PathSpec {
    /// The point the robot circles and faces, in odom (x, y).
    pub target_m: [f64; 2],
    /// Distance of the robot (base_link) from `target_m` on a tour.
    pub tour_radius_m: f64,
    /// Bearing of the first tour stop as seen from the target.
    pub tour_start_deg: f64,
    /// The tour's stops span this arc from `tour_start_deg` (first and last stop at its ends)
    /// instead of the whole circle (absent: the circle, its stops 360 / N degrees apart).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tour_arc_deg: Option<f64>,
    /// The tour's first frame is taken this far from the target, at `tour_start_deg`, before
    /// the robot drives in to the circle (as the foreign renderer's tours do; absent: the tour
    /// starts on the circle).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tour_start_distance_m: Option<f64>,
    /// Train viewpoints: the robot stands at this bearing and distance, facing the target.
    pub train_views: Vec<View>,
    /// Background stops of train sessions (target object removed).
    pub background_stops: Vec<StopPose>,
}

/// A train viewpoint: the robot stands here, facing `target_m`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct View {
    /// Bearing of the robot seen from `target_m`, degrees, counter-clockwise from `odom` +x.
    pub bearing_deg: f64,
    /// Distance of base_link from `target_m`, metres (> 0).
    pub distance_m: f64,
}

/// A background stop of train sessions: a planar pose in `odom`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StopPose {
    /// Position along `odom` x, metres.
    pub x_m: f64,
    /// Position along `odom` y, metres.
    pub y_m: f64,
    /// Heading, degrees, counter-clockwise from `odom` +x.
    pub yaw_deg: f64,
}

impl Scene {
    /// Parses a scene file's JSON and validates it; the error is serde's or [`Scene::validate`]'s
    /// message.
    pub fn from_json(text: &str) -> Result<Self, String> {
        let scene: Scene = serde_json::from_str(text).map_err(|e| e.to_string())?;
        scene.validate()?;
        Ok(scene)
    }

    /// Names of the objects in the scene, sorted, each once.
    pub fn object_names(&self) -> Vec<String> {
        let mut names: Vec<String> = self
            .primitives
            .iter()
            .filter_map(|p| p.object.clone())
            .collect();
        names.sort();
        names.dedup();
        names
    }

    /// Checks every number the renderer and planner rely on; the message names the field.
    pub fn validate(&self) -> Result<(), String> {
        self.validate_room()?;
        self.validate_light()?;
        self.validate_camera()?;
        if !positive(&[self.robot.drive_speed_m_s, self.robot.turn_speed_rad_s]) {
            return Err(format!(
                "robot.drive_speed_m_s {} and robot.turn_speed_rad_s {} must be positive",
                self.robot.drive_speed_m_s, self.robot.turn_speed_rad_s
            ));
        }
        self.validate_primitives()?;
        self.validate_path()
    }

    /// Checks the room's size and every material's colour and texture (the primitives' too).
    fn validate_room(&self) -> Result<(), String> {
        if !positive(&self.room.size_m) {
            return Err(format!(
                "room.size_m {:?} must be positive",
                self.room.size_m
            ));
        }
        let mats = [&self.room.floor, &self.room.ceiling]
            .into_iter()
            .chain(self.room.walls.iter())
            .map(|m| ("room", m))
            .chain(self.primitives.iter().map(|p| ("primitive", &p.material)));
        for (what, m) in mats {
            if !m.color.iter().all(|c| (0.0..=1.0).contains(c)) {
                return Err(format!("{what} colour {:?} must lie in [0, 1]", m.color));
            }
            let ok = match m.texture {
                Texture::Flat => true,
                Texture::Noise { scale_m, amount } => positive(&[scale_m]) && finite(&[amount]),
                Texture::Stripes {
                    period_m,
                    axis,
                    amount,
                } => positive(&[period_m]) && axis < 3 && finite(&[amount]),
                Texture::Wood {
                    ring_period_m,
                    amount,
                } => positive(&[ring_period_m]) && finite(&[amount]),
                Texture::Checker { period_m, amount } | Texture::Rings { period_m, amount } => {
                    positive(&[period_m]) && finite(&[amount])
                }
            };
            if !ok {
                return Err(format!(
                    "{what} texture {:?} needs positive sizes and axis 0..2",
                    m.texture
                ));
            }
        }
        Ok(())
    }

    /// Checks the light's direction and radiance.
    fn validate_light(&self) -> Result<(), String> {
        let l = &self.light;
        let dir_len = l.direction.iter().map(|x| x * x).sum::<f64>().sqrt();
        let radiance_ok = l.intensity.is_finite()
            && l.ambient.is_finite()
            && l.intensity >= 0.0
            && l.ambient >= 0.0;
        if !finite(&l.direction) || dir_len < 1e-9 || !radiance_ok {
            return Err(format!(
                "light.direction {:?} must be finite and non-zero, light.intensity {} and light.ambient {} finite and non-negative",
                l.direction, l.intensity, l.ambient
            ));
        }
        Ok(())
    }

    /// Checks the camera's image size, field of view and mount.
    fn validate_camera(&self) -> Result<(), String> {
        let c = &self.camera;
        if c.width == 0 || c.height == 0 || c.width > 4096 || c.height > 4096 {
            return Err(format!(
                "camera {} x {} must be 1 to 4096 pixels a side",
                c.width, c.height
            ));
        }
        let camera_ok = c.hfov_deg > 1.0
            && c.hfov_deg < 170.0
            && finite(&c.mount_m)
            && c.pitch_down_deg.is_finite();
        if !camera_ok {
            return Err(format!(
                "camera hfov_deg {} must be in (1, 170), mount and pitch finite",
                c.hfov_deg
            ));
        }
        if let Some(h) = &c.pan_tilt
            && !((0.0..90.0).contains(&h.pan_amplitude_deg)
                && (0.0..45.0).contains(&h.tilt_amplitude_deg)
                && h.period_s > 0.0
                && h.period_s.is_finite())
        {
            return Err(format!(
                "camera pan_tilt: pan amplitude {} must be in [0, 90), tilt amplitude {} in \
                 [0, 45) degrees, period {} s above 0",
                h.pan_amplitude_deg, h.tilt_amplitude_deg, h.period_s
            ));
        }
        Ok(())
    }

    /// Checks every primitive's shape and object name, and that the target has a primitive.
    fn validate_primitives(&self) -> Result<(), String> {
        for (i, p) in self.primitives.iter().enumerate() {
            let ok = match p.shape {
                Shape::Box {
                    center_m,
                    size_m,
                    yaw_deg,
                } => finite(&center_m) && positive(&size_m) && yaw_deg.is_finite(),
                Shape::Cylinder {
                    base_center_m,
                    radius_m,
                    height_m,
                } => finite(&base_center_m) && positive(&[radius_m, height_m]),
                Shape::Sphere { center_m, radius_m } => finite(&center_m) && positive(&[radius_m]),
            };
            if !ok {
                return Err(format!(
                    "primitive {i} has a non-finite or non-positive size: {:?}",
                    p.shape
                ));
            }
            if p.object.as_deref() == Some("") {
                return Err(format!("primitive {i} has an empty object name"));
            }
        }
        if !self
            .primitives
            .iter()
            .any(|p| p.object.as_deref() == Some(self.target.as_str()))
        {
            return Err(format!("target object {:?} has no primitive", self.target));
        }
        Ok(())
    }

    /// Checks the tour circle, the train views and the background stops.
    fn validate_path(&self) -> Result<(), String> {
        let path = &self.path;
        if !finite(&path.target_m)
            || !positive(&[path.tour_radius_m])
            || !path.tour_start_deg.is_finite()
        {
            return Err(
                "path target_m, tour_radius_m and tour_start_deg must be finite, radius positive"
                    .into(),
            );
        }
        if !path
            .tour_arc_deg
            .is_none_or(|a| a.is_finite() && a > 0.0 && a <= 360.0)
            || !path
                .tour_start_distance_m
                .is_none_or(|d| d.is_finite() && d > path.tour_radius_m)
        {
            return Err(format!(
                "path.tour_arc_deg {:?} must lie in (0, 360] and path.tour_start_distance_m {:?} beyond tour_radius_m {}",
                path.tour_arc_deg, path.tour_start_distance_m, path.tour_radius_m
            ));
        }
        if path.train_views.is_empty()
            || !path
                .train_views
                .iter()
                .all(|v| v.bearing_deg.is_finite() && positive(&[v.distance_m]))
        {
            return Err("path.train_views needs at least one view with a positive distance".into());
        }
        if !path
            .background_stops
            .iter()
            .all(|s| finite(&[s.x_m, s.y_m, s.yaw_deg]))
        {
            return Err("path.background_stops must be finite".into());
        }
        self.validate_path_in_room()
    }

    /// Every place the robot stands (the tour's circle, whose chords it drives; the train
    /// views; the background stops) lies inside the room, which is centred on the origin: a
    /// tour radius of 100 m in a 7 m room rendered the walls from outside without a word.
    fn validate_path_in_room(&self) -> Result<(), String> {
        let path = &self.path;
        let half = [self.room.size_m[0] / 2.0, self.room.size_m[1] / 2.0];
        let inside = |x: f64, y: f64| x.abs() < half[0] && y.abs() < half[1];
        let room = format!(
            "the room spans x and y within +-{} and +-{} m",
            half[0], half[1]
        );
        let [tx, ty] = path.target_m;
        if tx.abs() + path.tour_radius_m >= half[0] || ty.abs() + path.tour_radius_m >= half[1] {
            return Err(format!(
                "path.tour_radius_m {} m round target_m {:?} leaves the room ({room})",
                path.tour_radius_m, path.target_m
            ));
        }
        if let Some(d) = path.tour_start_distance_m {
            let b = path.tour_start_deg.to_radians();
            let (x, y) = (tx + d * b.cos(), ty + d * b.sin());
            if !inside(x, y) {
                return Err(format!(
                    "path.tour_start_distance_m {d} m puts the tour's start at ({x:.2}, {y:.2}) m, outside the room ({room})"
                ));
            }
        }
        for (i, v) in path.train_views.iter().enumerate() {
            let b = v.bearing_deg.to_radians();
            let (x, y) = (tx + v.distance_m * b.cos(), ty + v.distance_m * b.sin());
            if !inside(x, y) {
                return Err(format!(
                    "path.train_views[{i}] stands at ({x:.2}, {y:.2}) m, outside the room ({room})"
                ));
            }
        }
        for (i, st) in path.background_stops.iter().enumerate() {
            if !inside(st.x_m, st.y_m) {
                return Err(format!(
                    "path.background_stops[{i}] at ({}, {}) m is outside the room ({room})",
                    st.x_m, st.y_m
                ));
            }
        }
        Ok(())
    }
}

/// Every value is finite.
fn finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// Every value is finite and above zero.
fn positive(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite() && *x > 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtins_parse_and_name_their_target() {
        for name in BUILTIN_SCENES {
            let s = Scene::from_json(builtin_json(name).unwrap())
                .unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(s.name, name);
            assert_eq!(s.camera.width, 256);
            assert_eq!(s.camera.height, 240);
        }
        let two = Scene::from_json(builtin_json("two-chairs").unwrap()).unwrap();
        assert_eq!(two.object_names(), vec!["chair".to_owned()]);
        let instances: Vec<u32> = two
            .primitives
            .iter()
            .filter(|p| p.object.is_some())
            .map(|p| p.instance)
            .collect();
        assert!(instances.contains(&0) && instances.contains(&1));
    }

    #[test]
    fn validation_names_the_bad_field() {
        let mut s = Scene::from_json(builtin_json("chair").unwrap()).unwrap();
        s.target = "sofa".into();
        assert_eq!(
            s.validate().unwrap_err(),
            "target object \"sofa\" has no primitive"
        );
        let bad = builtin_json("chair")
            .unwrap()
            .replacen("\"hfov_deg\"", "\"hfov\"", 1);
        assert!(
            Scene::from_json(&bad)
                .unwrap_err()
                .contains("unknown field `hfov`")
        );
        // Fields by their names in the file, not Rust's Debug of the struct.
        let mut s = Scene::from_json(builtin_json("chair").unwrap()).unwrap();
        s.robot.drive_speed_m_s = 0.0;
        let e = s.validate().unwrap_err();
        assert!(
            e.starts_with("robot.drive_speed_m_s 0 and robot.turn_speed_rad_s "),
            "{e}"
        );
        let mut s = Scene::from_json(builtin_json("chair").unwrap()).unwrap();
        s.light.direction = [0.0; 3];
        let e = s.validate().unwrap_err();
        assert!(
            e.starts_with("light.direction [0.0, 0.0, 0.0] must be finite and non-zero"),
            "{e}"
        );
    }

    /// The robot must stand inside the room: a 100 m tour radius in the 7 m chair room was
    /// recorded without a word.
    #[test]
    fn a_path_outside_the_room_is_refused() {
        let chair = || Scene::from_json(builtin_json("chair").unwrap()).unwrap();
        let mut s = chair();
        s.path.tour_radius_m = 100.0;
        assert_eq!(
            s.validate().unwrap_err(),
            format!(
                "path.tour_radius_m 100 m round target_m {:?} leaves the room (the room spans x and y within +-3.5 and +-3.5 m)",
                s.path.target_m
            )
        );
        let mut s = chair();
        s.path.train_views[1].distance_m = 9.0;
        assert!(
            s.validate()
                .unwrap_err()
                .starts_with("path.train_views[1] stands at ("),
        );
        let mut s = chair();
        s.path.background_stops[0].x_m = -3.6;
        assert!(
            s.validate()
                .unwrap_err()
                .starts_with("path.background_stops[0] at (-3.6, "),
        );
    }
}
