//! The fuser: the deterministic replay of one session ([`replay`], the only module here that
//! reads a session) driving the state it updates: the belief grid ([`grid`]), the motion
//! model's blur ([`motion`]), pose refinement against landmarks ([`refine`]) and the floor
//! ([`floor`]), the objects found in the belief ([`objects`]) and, where the grid cannot
//! bound them, their centres triangulated from their detections ([`locate`]); and the
//! rectangles a located object projects to in a session's frames ([`relabel`]).
//!
//! May import: [`crate::types`], [`crate::learn`] and (the replay only) [`crate::io`].
//! No clock, no unseeded randomness, no unordered iteration.

pub mod floor;
pub mod grid;
pub mod locate;
pub mod motion;
pub mod objects;
pub mod refine;
pub mod relabel;
pub mod replay;
