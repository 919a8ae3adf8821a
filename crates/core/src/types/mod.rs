//! Shared values below every stage: planar and 3D geometry, the camera model and its lens
//! distortion, decoded
//! images, hex digests, tile probabilities, pose tracks, a seeded RNG, a sort of cell indices.
//!
//! May import: nothing of the crate (only external crates).

pub mod digest;
pub mod geometry;
pub mod image;
pub mod lens;
pub mod probs;
pub mod rng;
pub mod sort;
#[cfg(test)]
pub mod testing;
pub mod track;
