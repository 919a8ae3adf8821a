//! replay: placeholder.
