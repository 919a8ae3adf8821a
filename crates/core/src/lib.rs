//! objloc-core: learn to locate an object in 3D from a sequence of camera images, without a
//! viewer (the `objloc` binary adds the command line and the Rerun observers).
//!
//! The folders are the pipeline, and data flows one way through them:
//!
//! * [`types`]: shared values below everything (geometry, images, pose tracks, tile
//!   probabilities, a seeded RNG); imports nothing of the crate.
//! * [`io`]: MCAP sessions <-> typed ROS 2 messages, importers of real captures, the
//!   inspector, `.npy` and atomic output files; imports [`types`].
//! * [`learn`]: tile features, training examples, the decision trees and the model file;
//!   imports [`types`] (labelled frames come in as typed values).
//! * [`fuse`]: the deterministic replay of one session (the only part of it that reads a
//!   session) driving the fuser state: grid, motion blur, pose refinement against the
//!   landmarks and the floor, objects; imports [`types`], [`io`] and [`learn`].
//! * [`out`]: the report and its evaluation against ground truth; imports all of the above.
//! * [`sim`]: the simulator, a recorder like any other: it writes through [`io`]'s session
//!   writer; imports [`types`] and [`io`].
//!
//! Each folder's `mod.rs` repeats its rule, and `tests/it`'s layout test enforces them.
//! The fuser core takes typed values and returns state: no files, no clock, no viewer.

// Errors here carry the file, topic, log time and the numbers involved, so some exceed
// clippy's 128-byte budget for `Err`; they are built only on the failure path, where the copy
// costs nothing that matters.
#![allow(clippy::result_large_err)]

pub mod fuse;
pub mod io;
pub mod learn;
pub mod out;
pub mod sim;
pub mod types;
