//! Shared values below every stage: planar and 3D geometry, the camera model, a seeded RNG.
//!
//! May import: nothing of the crate (only external crates).

pub mod geometry;
pub mod rng;
