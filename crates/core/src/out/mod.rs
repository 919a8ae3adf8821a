//! Observers' products: the fuse report ([`report`]), its evaluation against ground truth
//! ([`eval`]) or against label rectangles ([`rects`]), and what the viewer shows, computed without it ([`view`]).
//!
//! May import: [`crate::types`], [`crate::io`], [`crate::learn`], [`crate::fuse`].

pub mod eval;
pub mod rects;
pub mod report;
pub mod view;
