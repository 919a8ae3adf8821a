//! model: placeholder.
