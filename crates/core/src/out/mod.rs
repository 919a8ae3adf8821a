//! Observers' products: the fuse report ([`report`]), its evaluation against ground truth
//! ([`eval`]), and what the viewer shows, computed without it ([`view`]).
//!
//! May import: [`crate::types`], [`crate::io`], [`crate::learn`], [`crate::fuse`].

pub mod eval;
pub mod report;
pub mod view;
