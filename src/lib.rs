//! objloc: learn to locate an object in 3D from a sequence of camera images.
//!
//! Data flows one way: [`session`] (MCAP <-> typed ROS 2 messages) -> [`replay`] (a
//! deterministic event loop over one session) -> the fuser state ([`features`] -> [`tree`] ->
//! [`geometry`] -> [`grid`] + [`motion`]) -> observers ([`viz`] for Rerun, [`report`],
//! [`eval`]). The fuser core takes typed values and returns state: no files, no clock.
//! [`sim`] renders and drives a robot and writes through [`session`] like any recorder.

// Errors here carry the file, topic, log time and the numbers involved, so some exceed
// clippy's 128-byte budget for `Err`; they are built only on the failure path, where the copy
// costs nothing that matters.
#![allow(clippy::result_large_err)]

pub mod cdr;
pub mod dataset;
pub mod eval;
pub mod features;
pub mod floor;
pub mod geometry;
pub mod grid;
pub mod import;
pub mod inspect;
pub mod model;
pub mod motion;
pub mod msgs;
pub mod npy;
pub mod objects;
pub mod output;
pub mod refine;
pub mod replay;
pub mod report;
pub mod rng;
pub mod session;
pub mod sim;
pub mod tree;
pub mod viz;
