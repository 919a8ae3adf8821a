//! Learning the tile classifier: features of a tile ([`features`]), training examples from
//! labelled frames ([`dataset`]), the probability trees ([`tree`]) and the model file with its
//! two heads ([`model`]).
//!
//! May import: [`crate::types`] and, for reading labelled sessions and writing model files,
//! [`crate::io`].

pub mod dataset;
pub mod features;
pub mod model;
pub mod tree;
