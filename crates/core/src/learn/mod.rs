//! Learning the tile classifier: features of a tile ([`features`]), training examples from
//! labelled frames ([`dataset`]), the probability trees ([`tree`]) and the model file with its
//! two heads ([`model`]), training a model ([`training`]), and the defaults that follow the
//! kind of training session ([`defaults`]).
//!
//! May import: [`crate::types`] and, for reading labelled sessions and writing model files,
//! [`crate::io`].

pub mod dataset;
pub mod defaults;
pub mod features;
pub mod model;
pub mod training;
pub mod tree;
