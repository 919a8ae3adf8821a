//! Observers' products: the fuse report ([`report`]) and its evaluation against ground truth
//! ([`eval`]).
//!
//! May import: [`crate::types`], [`crate::io`], [`crate::learn`], [`crate::fuse`].

pub mod eval;
pub mod report;
