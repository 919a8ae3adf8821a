//! The camera mount at a stamp: the chain of transforms from the robot's base frame (the
//! odometry's child frame) to the camera's frame, from /tf_static and /tf, with tf2's
//! semantics: a static edge holds at all times; a dynamic edge is interpolated between its
//! samples (position linearly, rotation by slerp) and never extrapolated beyond
//! [`crate::types::track::POSE_TOLERANCE_NS`] past its first or last sample.
//!
//! Invariants: each child frame has one parent (tf2's tree; a later static transform of the
//! same child replaces an earlier one, dynamic samples of a child accumulate); lookups are
//! pure and deterministic (ordered maps); a chain longer than [`MAX_CHAIN`] is a loop.

use std::collections::BTreeMap;

use crate::types::geometry::Iso3;
use crate::types::track::PoseTrack;

/// Most edges between the base and the camera before a chain is taken to be a loop.
pub const MAX_CHAIN: usize = 64;

/// Why the tree gives no transform at a stamp.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TfError {
    /// No transform names the frame as its child.
    #[error("no transform to {frame:?}")]
    NoTransform {
        /// The frame looked up.
        frame: String,
    },
    /// The frame's chain of parents ends before the base.
    #[error("{frame:?} is not connected to {base:?} (its chain ends at {root:?})")]
    NotConnected {
        /// The frame looked up.
        frame: String,
        /// The base asked for.
        base: String,
        /// Where the chain of parents ends.
        root: String,
    },
    /// A moving edge has no sample near the stamp.
    #[error(
        "{parent} -> {child} has no sample within 50 ms of stamp {stamp_ns} ns (tf2 does not \
         extrapolate)"
    )]
    NoSample {
        /// The edge's parent frame.
        parent: String,
        /// The edge's child frame.
        child: String,
        /// The stamp looked up, ns since the epoch.
        stamp_ns: i64,
    },
    /// The parents form a loop.
    #[error("the transforms above {frame:?} form a loop")]
    Loop {
        /// The frame looked up.
        frame: String,
    },
}

/// Stamped samples of one edge: (stamp ns, parent_from_child).
type Samples = Vec<(i64, Iso3)>;

/// How a child frame hangs from its parent.
#[derive(Debug, Clone)]
enum Edge {
    /// parent_from_child, at all times.
    Static(String, Iso3),
    /// parent_from_child over time.
    Dynamic(String, PoseTrack),
}

/// The transform tree of a session.
#[derive(Debug, Clone, Default)]
pub struct TfTree {
    edges: BTreeMap<String, Edge>,
}

impl TfTree {
    /// The tree of static transforms (parent, child, parent_from_child) and dynamic samples
    /// (parent, child, stamp, parent_from_child). A child with both is dynamic.
    pub fn new(
        statics: &[(String, String, Iso3)],
        dynamic: &[(String, String, i64, Iso3)],
    ) -> Self {
        let mut edges = BTreeMap::new();
        for (parent, child, iso) in statics {
            edges.insert(child.clone(), Edge::Static(parent.clone(), *iso));
        }
        let mut samples: BTreeMap<&str, (&str, Samples)> = BTreeMap::new();
        for (parent, child, stamp, iso) in dynamic {
            samples
                .entry(child)
                .or_insert((parent, Vec::new()))
                .1
                .push((*stamp, *iso));
        }
        for (child, (parent, track)) in samples {
            edges.insert(
                child.to_owned(),
                Edge::Dynamic(parent.to_owned(), PoseTrack::new(track)),
            );
        }
        Self { edges }
    }

    /// Whether any edge changes over time.
    pub fn is_dynamic(&self) -> bool {
        self.edges.values().any(|e| matches!(e, Edge::Dynamic(..)))
    }

    /// The parent of `frame`, if it has one.
    pub fn parent(&self, frame: &str) -> Option<&str> {
        self.edges.get(frame).map(|e| match e {
            Edge::Static(p, _) | Edge::Dynamic(p, _) => p.as_str(),
        })
    }

    /// The camera mount `base_from_camera` at `stamp_ns`: the chain up to `base`; failing
    /// that, a lone transform to the camera whatever its parent (older bags name another
    /// parent than the odometry's child). A longer chain that misses the base is not a mount:
    /// a head's joint missing from /tf must not pass for a fixed mount.
    pub fn mount(&self, base: Option<&str>, camera: &str, stamp_ns: i64) -> Result<Iso3, TfError> {
        self.lookup(base, camera, stamp_ns).or_else(|e| {
            let lone_edge = self
                .parent(camera)
                .is_some_and(|p| self.parent(p).is_none());
            if base.is_some() && lone_edge {
                self.lookup(None, camera, stamp_ns)
            } else {
                Err(e)
            }
        })
    }

    /// `base_from_frame` at `stamp_ns`: the chain up from `frame` to `base` (or to the root
    /// of its tree when `base` is None), or why not.
    pub fn lookup(&self, base: Option<&str>, frame: &str, stamp_ns: i64) -> Result<Iso3, TfError> {
        let mut out = Iso3::identity();
        let mut at = frame;
        for _ in 0..MAX_CHAIN {
            if Some(at) == base {
                return Ok(out);
            }
            let Some(edge) = self.edges.get(at) else {
                return match base {
                    None if at != frame => Ok(out),
                    None => Err(TfError::NoTransform {
                        frame: frame.into(),
                    }),
                    Some(b) => Err(TfError::NotConnected {
                        frame: frame.into(),
                        base: b.into(),
                        root: at.into(),
                    }),
                };
            };
            let (parent, parent_from_child) = match edge {
                Edge::Static(p, iso) => (p.as_str(), *iso),
                Edge::Dynamic(p, track) => (
                    p.as_str(),
                    track
                        .interpolated(stamp_ns)
                        .ok_or_else(|| TfError::NoSample {
                            parent: p.clone(),
                            child: at.into(),
                            stamp_ns,
                        })?,
                ),
            };
            out = parent_from_child * out;
            at = parent;
        }
        Err(TfError::Loop {
            frame: frame.into(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    fn yaw(rad: f64, t: [f64; 3]) -> Iso3 {
        Iso3::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), rad),
        )
    }

    #[test]
    fn a_pan_joint_between_static_links_is_interpolated_and_not_extrapolated() {
        let s = |p: &str, c: &str, iso| (p.to_owned(), c.to_owned(), iso);
        let statics = [
            s("base_link", "pan_base", yaw(0.0, [0.1, 0.0, 0.5])),
            s("pan_link", "camera", yaw(0.0, [0.0, 0.0, 0.05])),
        ];
        let d = |t: i64, a: f64| {
            (
                "pan_base".to_owned(),
                "pan_link".to_owned(),
                t,
                yaw(a, [0.0; 3]),
            )
        };
        let tree = TfTree::new(&statics, &[d(1_000, 0.0), d(1_000_000_000 + 1_000, 1.0)]);
        assert!(tree.is_dynamic());
        // Halfway: pan 0.5 rad; the camera 5 cm above the pan joint, which is at (0.1, 0, 0.5).
        let m = tree
            .lookup(Some("base_link"), "camera", 500_001_000)
            .unwrap();
        assert!((m.rotation.angle() - 0.5).abs() < 1e-12);
        assert!((m.translation.vector - Vector3::new(0.1, 0.0, 0.55)).norm() < 1e-12);
        // 40 ms past the last sample: held; 60 ms: refused.
        assert!(
            tree.lookup(Some("base_link"), "camera", 1_040_001_000)
                .is_ok()
        );
        let e = tree
            .lookup(Some("base_link"), "camera", 1_060_001_000)
            .unwrap_err();
        assert!(matches!(e, TfError::NoSample { ref parent, .. } if parent == "pan_base"));
        assert!(e.to_string().contains("does not extrapolate"), "{e}");
        // Without a base: the root of the chain.
        let r = tree.lookup(None, "camera", 1_000).unwrap();
        assert!((r.translation.vector - Vector3::new(0.1, 0.0, 0.55)).norm() < 1e-12);
        assert!(tree.lookup(Some("odom"), "camera", 1_000).is_err());
    }
}
